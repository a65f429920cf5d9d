//! Which surface points the training cameras saw. F_e, the emitter field, is only trained where
//! a camera looked: on the far side of a bulb (facing the wall it lights) it says "not an
//! emitter" by default, and the wall behind the lamp then received F_c's dim guess instead of
//! L\[k\] (measured on the default room: with ground-truth materials the re-render came out ~30 %
//! dark around the lamp; the bulb's back had F_e ≈ 0.001 at its surface). So an emitter's label
//! also goes to the unobserved surface inside its bounding sphere ([`crate::FrozenScene::cast`]).
//!
//! A point is observed when some training camera sees it: it projects into the image in front
//! of the camera, and the camera's own depth there (its pixel-centre ray cast into the same
//! surface) agrees with the point's depth.

use glam::Vec3;
use i2sdf_data::Camera;
use i2sdf_render::{Geometry, Hit, Ray};
use rayon::prelude::*;

pub struct ObservedViews {
    cameras: Vec<Camera>,
    /// Each camera's world-to-camera transform (inverted once, not per query).
    w2c: Vec<glam::DMat4>,
    /// Per camera, the z-depth of each pixel-centre ray's first hit (∞: none).
    depth: Vec<Vec<f32>>,
}

/// Depth agreement: within this fraction of the depth, and at least [`MIN_TOLERANCE`].
const TOLERANCE: f32 = 0.03;
/// World units (metres in the synthetic rooms).
const MIN_TOLERANCE: f32 = 0.03;

impl ObservedViews {
    /// Casts every pixel centre of every camera into `geometry` (world units).
    pub fn new(geometry: &dyn Geometry, cameras: &[Camera]) -> Self {
        let depth = cameras
            .iter()
            .map(|cam| {
                let g = cam.ray_generator();
                let fwd = g.forward();
                (0..cam.height)
                    .into_par_iter()
                    .flat_map_iter(|y| {
                        let rays: Vec<Ray> = (0..cam.width)
                            .map(|x| Ray::new(g.origin, g.dir(x as f32 + 0.5, y as f32 + 0.5), 0.0, f32::INFINITY))
                            .collect();
                        let mut hits: Vec<Option<Hit>> = vec![None; rays.len()];
                        geometry.intersect(&rays, &mut hits);
                        rays.into_iter()
                            .zip(hits)
                            .map(move |(r, h)| h.map_or(f32::INFINITY, |h| h.t * r.dir.dot(fwd)))
                            .collect::<Vec<_>>()
                    })
                    .collect()
            })
            .collect();
        ObservedViews {
            cameras: cameras.to_vec(),
            w2c: cameras.iter().map(Camera::w2c).collect(),
            depth,
        }
    }

    /// Whether some camera sees the world point `x`.
    pub fn observed(&self, x: Vec3) -> bool {
        let x = x.as_dvec3();
        self.cameras
            .iter()
            .zip(&self.w2c)
            .zip(&self.depth)
            .any(|((cam, w2c), depth)| {
                let pc = w2c.transform_point3(x);
                if pc.z <= 1e-9 {
                    return false;
                }
                let (u, v) = cam.project_camera_space(pc);
                let z = pc.z;
                let (i, j) = (u.floor(), v.floor());
                if z <= 0.0 || i < 0.0 || j < 0.0 || i >= cam.width as f64 || j >= cam.height as f64 {
                    return false;
                }
                let d = depth[j as usize * cam.width + i as usize];
                let z = z as f32;
                (d - z).abs() <= (TOLERANCE * z).max(MIN_TOLERANCE)
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use i2sdf_data::camera::look_at;
    use i2sdf_data::TriangleMesh;
    use i2sdf_render::MeshGeometry;

    /// A camera looking at a sphere sees its near side, not its far side.
    #[test]
    fn the_far_side_of_a_sphere_is_unobserved() {
        let mesh = TriangleMesh::unit_icosphere(4);
        let geo = MeshGeometry::new(&mesh, vec![0; mesh.faces.len()]);
        let cam = Camera {
            lens: Default::default(),
            width: 64,
            height: 64,
            fx: 64.0,
            fy: 64.0,
            cx: 32.0,
            cy: 32.0,
            c2w: look_at(DVec3::new(0.0, 0.0, 4.0), DVec3::ZERO, DVec3::Y),
        };
        let seen = ObservedViews::new(&geo, &[cam]);
        assert!(seen.observed(Vec3::new(0.0, 0.0, 1.0)));
        assert!(seen.observed(Vec3::new(0.5, 0.0, 0.85)));
        assert!(!seen.observed(Vec3::new(0.0, 0.0, -1.0)));
        assert!(!seen.observed(Vec3::new(-0.5, 0.0, -0.85)));
        // Outside the image.
        assert!(!seen.observed(Vec3::new(0.0, 30.0, 0.0)));
    }
}
