//! Tessellation of every shape into one triangle mesh (the data layer's [`TriangleMesh`]). The
//! path tracer intersects exactly these triangles and the ground-truth PLY holds exactly these
//! triangles, so depth back-projected from any view lies on the written mesh up to f32 rounding.
//! Each triangle remembers its shape (a parallel array: the renderer's surface label), and
//! through it its object, which the PLY writes per face.

use crate::scene::{Geometry, SceneDesc};
use glam::{Quat, Vec3};
use i2sdf_data::{DataError, TriangleMesh};
use std::path::Path;

/// The scene's triangles and, per triangle, the index of the shape it belongs to.
#[derive(Clone, Debug, Default)]
pub struct SceneMesh {
    /// Counter-clockwise seen from outside: the geometric normal is (p1 − p0) × (p2 − p0).
    pub mesh: TriangleMesh,
    /// Index of the scene shape each triangle belongs to.
    pub shape_of: Vec<u32>,
}

impl SceneMesh {
    pub fn from_scene(scene: &SceneDesc) -> Self {
        let mut mesh = SceneMesh::default();
        for (i, s) in scene.shapes.iter().enumerate() {
            mesh.add_geometry(&s.geometry, i as u32);
        }
        mesh
    }

    pub fn vertex(&self, t: usize, k: usize) -> Vec3 {
        self.mesh.vertex(t, k)
    }

    /// The triangles of one shape.
    pub fn shape_faces(&self, shape: u32) -> Vec<u32> {
        (0..self.shape_of.len() as u32)
            .filter(|&t| self.shape_of[t as usize] == shape)
            .collect()
    }

    fn push(&mut self, verts: &[Vec3], tris: &[[u32; 3]], shape: u32) {
        let base = self.mesh.positions.len() as u32;
        self.mesh.positions.extend(verts.iter().map(|v| v.to_array()));
        for t in tris {
            self.mesh.faces.push([t[0] + base, t[1] + base, t[2] + base]);
            self.shape_of.push(shape);
        }
    }

    pub fn add_geometry(&mut self, g: &Geometry, shape: u32) {
        match g {
            Geometry::Box { min, max, yaw_deg } => {
                let (lo, hi) = (Vec3::from(*min), Vec3::from(*max));
                let c = 0.5 * (lo + hi);
                let rot = Quat::from_rotation_y(yaw_deg.to_radians());
                let verts: Vec<Vec3> = (0..8)
                    .map(|i| {
                        let p = Vec3::new(
                            if i & 1 != 0 { hi.x } else { lo.x },
                            if i & 2 != 0 { hi.y } else { lo.y },
                            if i & 4 != 0 { hi.z } else { lo.z },
                        );
                        c + rot * (p - c)
                    })
                    .collect();
                // Faces as quads (outward, counter-clockwise): -x, +x, -y, +y, -z, +z.
                let quads = [
                    [0, 4, 6, 2],
                    [1, 3, 7, 5],
                    [0, 1, 5, 4],
                    [2, 6, 7, 3],
                    [0, 2, 3, 1],
                    [4, 5, 7, 6],
                ];
                let tris: Vec<[u32; 3]> = quads
                    .iter()
                    .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
                    .collect();
                self.push(&verts, &tris, shape);
            }
            Geometry::Sphere {
                center,
                radius,
                subdivisions,
            } => {
                let unit = TriangleMesh::unit_icosphere(*subdivisions);
                let c = Vec3::from(*center);
                let verts: Vec<Vec3> = unit.positions.iter().map(|v| c + *radius * Vec3::from(*v)).collect();
                self.push(&verts, &unit.faces, shape);
            }
            Geometry::Cylinder { a, b, radius, segments } => {
                let (a, b) = (Vec3::from(*a), Vec3::from(*b));
                let axis = (b - a).normalize();
                let frame = i2sdf_render::sampling::Frame::from_normal(axis);
                let n = *segments;
                let mut verts = vec![a, b];
                for k in 0..n {
                    let phi = std::f32::consts::TAU * k as f32 / n as f32;
                    let off = *radius * (phi.cos() * frame.t + phi.sin() * frame.b);
                    verts.push(a + off);
                    verts.push(b + off);
                }
                let mut tris = Vec::new();
                for k in 0..n {
                    let (a0, b0) = (2 + 2 * k, 3 + 2 * k);
                    let (a1, b1) = (2 + 2 * ((k + 1) % n), 3 + 2 * ((k + 1) % n));
                    tris.push([a0, a1, b1]);
                    tris.push([a0, b1, b0]);
                    tris.push([0, a1, a0]);
                    tris.push([1, b0, b1]);
                }
                self.push(&verts, &tris, shape);
            }
            Geometry::Quad { origin, u, v } => {
                let (o, u, v) = (Vec3::from(*origin), Vec3::from(*u), Vec3::from(*v));
                self.push(&[o, o + u, o + u + v, o + v], &[[0, 1, 2], [0, 2, 3]], shape);
            }
        }
    }

    /// Axis-aligned bounds of one shape's triangles.
    pub fn shape_bounds(&self, shape: u32) -> (Vec3, Vec3) {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for (t, &s) in self.shape_of.iter().enumerate() {
            if s == shape {
                for k in 0..3 {
                    lo = lo.min(self.vertex(t, k));
                    hi = hi.max(self.vertex(t, k));
                }
            }
        }
        (lo, hi)
    }

    /// The ground-truth PLY: the mesh with each face's `int object_id`
    /// (`object_of_shape[shape]`, see [`SceneDesc::objects`]), through the data layer's writer.
    pub fn write_ply(&self, path: &Path, object_of_shape: &[i32]) -> Result<(), DataError> {
        if let Some(&s) = self.shape_of.iter().find(|&&s| s as usize >= object_of_shape.len()) {
            return Err(DataError::invalid(format!(
                "writing {}: shape {s} has no object id ({} given)",
                path.display(),
                object_of_shape.len()
            )));
        }
        let mut mesh = self.mesh.clone();
        mesh.face_object_ids = Some(self.shape_of.iter().map(|&s| object_of_shape[s as usize]).collect());
        i2sdf_data::ply::write_ply_with_comment(path, &mesh, "i2sdf synth ground-truth mesh (metres, y up)")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn signed_volume(m: &SceneMesh) -> f32 {
        m.mesh.signed_volume() as f32
    }

    #[test]
    fn closed_shapes_face_outwards_with_the_right_volume() {
        let mut m = SceneMesh::default();
        m.add_geometry(
            &Geometry::Box {
                min: [0.0, 0.0, 0.0],
                max: [1.0, 2.0, 3.0],
                yaw_deg: 30.0,
            },
            0,
        );
        assert!((signed_volume(&m) - 6.0).abs() < 1e-4);
        let mut m = SceneMesh::default();
        m.add_geometry(
            &Geometry::Cylinder {
                a: [0.0, 0.0, 0.0],
                b: [0.0, 2.0, 0.0],
                radius: 1.0,
                segments: 64,
            },
            0,
        );
        let prism = 0.5 * 64.0 * (std::f32::consts::TAU / 64.0).sin() * 2.0;
        assert!((signed_volume(&m) - prism).abs() < 1e-3);
        let mut m = SceneMesh::default();
        m.add_geometry(
            &Geometry::Sphere {
                center: [0.0; 3],
                radius: 1.0,
                subdivisions: 4,
            },
            0,
        );
        let v = signed_volume(&m);
        assert!(v > 4.0 && v < 4.0 * std::f32::consts::PI / 3.0, "{v}");
    }
}
