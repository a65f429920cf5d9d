//! The one indexed triangle mesh of the house: what the synthetic generator tessellates its rooms
//! into (and writes as the ground-truth `mesh.ply`), what marching cubes extracts from a trained
//! SDF, what the mesh metrics compare and what the Monte Carlo renderer's BVH is built over. With
//! the measures the tests and the metrics need (area, enclosed volume, edge manifoldness) and
//! floater removal.

use std::collections::HashMap;

/// An indexed triangle mesh. Faces are counter-clockwise seen from the side their normal points to
/// (right-hand rule on `(b - a) × (c - a)`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriangleMesh {
    pub positions: Vec<[f32; 3]>,
    pub faces: Vec<[u32; 3]>,
    /// One object id per face, when the mesh came with a per-face `object_id` (ground-truth meshes
    /// of datasets that name their objects); `None` otherwise.
    pub face_object_ids: Option<Vec<i32>>,
}

pub fn sub(a: [f32; 3], b: [f32; 3]) -> [f64; 3] {
    [
        a[0] as f64 - b[0] as f64,
        a[1] as f64 - b[1] as f64,
        a[2] as f64 - b[2] as f64,
    ]
}

pub fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

pub fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl TriangleMesh {
    /// An axis-aligned box with outward normals, 12 triangles, no object ids.
    pub fn axis_box(min: [f32; 3], max: [f32; 3]) -> TriangleMesh {
        let corner = |i: u32| {
            [
                if i & 1 != 0 { max[0] } else { min[0] },
                if i & 2 != 0 { max[1] } else { min[1] },
                if i & 4 != 0 { max[2] } else { min[2] },
            ]
        };
        let positions = (0..8).map(corner).collect();
        let quads = [
            [0, 2, 3, 1], // z = min, normal -z
            [4, 5, 7, 6], // z = max, normal +z
            [0, 1, 5, 4], // y = min, normal -y
            [2, 6, 7, 3], // y = max, normal +y
            [0, 4, 6, 2], // x = min, normal -x
            [1, 3, 7, 5], // x = max, normal +x
        ];
        let faces = quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        TriangleMesh {
            positions,
            faces,
            face_object_ids: None,
        }
    }

    /// Concatenates meshes (indices renumbered), keeping object ids when all have them.
    pub fn concat(meshes: &[TriangleMesh]) -> TriangleMesh {
        let mut out = TriangleMesh::default();
        let all_ids = meshes.iter().all(|m| m.face_object_ids.is_some());
        let mut ids = Vec::new();
        for m in meshes {
            let base = out.positions.len() as u32;
            out.positions.extend_from_slice(&m.positions);
            out.faces
                .extend(m.faces.iter().map(|f| [f[0] + base, f[1] + base, f[2] + base]));
            if all_ids {
                ids.extend_from_slice(m.face_object_ids.as_ref().unwrap());
            }
        }
        if all_ids && !meshes.is_empty() {
            out.face_object_ids = Some(ids);
        }
        out
    }

    /// Unit icosphere: the icosahedron with `subdivisions` midpoint subdivisions, projected onto
    /// the sphere; counter-clockwise seen from outside (20·4ⁿ faces). The synthetic rooms' spheres
    /// are exactly these triangles, scaled and moved.
    pub fn unit_icosphere(subdivisions: u32) -> TriangleMesh {
        use glam::Vec3;
        let t = (1.0 + 5f32.sqrt()) / 2.0;
        let mut verts: Vec<Vec3> = [
            [-1.0, t, 0.0],
            [1.0, t, 0.0],
            [-1.0, -t, 0.0],
            [1.0, -t, 0.0],
            [0.0, -1.0, t],
            [0.0, 1.0, t],
            [0.0, -1.0, -t],
            [0.0, 1.0, -t],
            [t, 0.0, -1.0],
            [t, 0.0, 1.0],
            [-t, 0.0, -1.0],
            [-t, 0.0, 1.0],
        ]
        .iter()
        .map(|p| Vec3::from(*p).normalize())
        .collect();
        let mut tris: Vec<[u32; 3]> = vec![
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ];
        for _ in 0..subdivisions {
            let mut mid = HashMap::new();
            let mut midpoint = |a: u32, b: u32, verts: &mut Vec<Vec3>| -> u32 {
                *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    verts.push((verts[a as usize] + verts[b as usize]).normalize());
                    verts.len() as u32 - 1
                })
            };
            let mut next = Vec::with_capacity(tris.len() * 4);
            for [a, b, c] in tris {
                let ab = midpoint(a, b, &mut verts);
                let bc = midpoint(b, c, &mut verts);
                let ca = midpoint(c, a, &mut verts);
                next.extend_from_slice(&[[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
            }
            tris = next;
        }
        TriangleMesh {
            positions: verts.iter().map(|v| v.to_array()).collect(),
            faces: tris,
            face_object_ids: None,
        }
    }

    /// Reverses every face's winding (normals flip: a box seen from inside).
    pub fn flipped(mut self) -> TriangleMesh {
        for f in &mut self.faces {
            f.swap(1, 2);
        }
        self
    }

    /// Vertex `k` of face `face` as a `Vec3` (the renderer's type).
    #[inline]
    pub fn vertex(&self, face: usize, k: usize) -> glam::Vec3 {
        glam::Vec3::from(self.positions[self.faces[face][k] as usize])
    }

    pub fn num_vertices(&self) -> usize {
        self.positions.len()
    }

    pub fn num_faces(&self) -> usize {
        self.faces.len()
    }

    pub fn triangle(&self, face: usize) -> [[f32; 3]; 3] {
        let [a, b, c] = self.faces[face];
        [
            self.positions[a as usize],
            self.positions[b as usize],
            self.positions[c as usize],
        ]
    }

    /// `(b - a) × (c - a)`: twice the area, pointing along the face normal.
    pub fn face_area_vector(&self, face: usize) -> [f64; 3] {
        let [a, b, c] = self.triangle(face);
        cross(sub(b, a), sub(c, a))
    }

    pub fn face_area(&self, face: usize) -> f64 {
        let n = self.face_area_vector(face);
        0.5 * dot(n, n).sqrt()
    }

    pub fn surface_area(&self) -> f64 {
        (0..self.faces.len()).map(|f| self.face_area(f)).sum()
    }

    /// Signed enclosed volume by the divergence theorem: positive when a closed mesh's normals point
    /// outward. Meaningless for an open mesh.
    pub fn signed_volume(&self) -> f64 {
        (0..self.faces.len())
            .map(|f| {
                let [a, b, c] = self.triangle(f);
                let a = [a[0] as f64, a[1] as f64, a[2] as f64];
                dot(a, cross(sub(b, [0.0; 3]), sub(c, [0.0; 3]))) / 6.0
            })
            .sum()
    }

    /// Number of faces using each undirected edge.
    pub fn edge_face_counts(&self) -> HashMap<(u32, u32), u32> {
        let mut counts = HashMap::with_capacity(self.faces.len() * 3 / 2 + 1);
        for face in &self.faces {
            for k in 0..3 {
                let (a, b) = (face[k], face[(k + 1) % 3]);
                *counts.entry((a.min(b), a.max(b))).or_insert(0) += 1;
            }
        }
        counts
    }

    /// Closed 2-manifold edges: every edge is used by exactly two faces, once in each direction
    /// (the latter means the orientation is consistent across the edge).
    pub fn is_watertight_and_consistently_oriented(&self) -> bool {
        let mut directed: HashMap<(u32, u32), u32> = HashMap::with_capacity(self.faces.len() * 3);
        for face in &self.faces {
            for k in 0..3 {
                *directed.entry((face[k], face[(k + 1) % 3])).or_insert(0) += 1;
            }
        }
        directed
            .iter()
            .all(|(&(a, b), &n)| n == 1 && directed.get(&(b, a)) == Some(&1))
    }

    /// Connected components of faces (faces sharing a vertex are connected), as a component index
    /// per face and the number of components.
    pub fn face_components(&self) -> (Vec<u32>, usize) {
        let mut parent: Vec<u32> = (0..self.positions.len() as u32).collect();
        fn find(parent: &mut [u32], mut x: u32) -> u32 {
            while parent[x as usize] != x {
                parent[x as usize] = parent[parent[x as usize] as usize];
                x = parent[x as usize];
            }
            x
        }
        for face in &self.faces {
            let r0 = find(&mut parent, face[0]);
            for &v in &face[1..] {
                let r = find(&mut parent, v);
                if r != r0 {
                    parent[r as usize] = r0;
                }
            }
        }
        let mut component_of_root: HashMap<u32, u32> = HashMap::new();
        let mut labels = Vec::with_capacity(self.faces.len());
        for face in &self.faces {
            let root = find(&mut parent, face[0]);
            let next = component_of_root.len() as u32;
            labels.push(*component_of_root.entry(root).or_insert(next));
        }
        (labels, component_of_root.len())
    }

    /// Drops connected components whose area is below `min_area_fraction` of the largest
    /// component's area (marching-cubes floaters), then unused vertices.
    pub fn remove_small_components(&mut self, min_area_fraction: f64) {
        let (labels, count) = self.face_components();
        if count <= 1 {
            return;
        }
        let mut area = vec![0.0f64; count];
        for (f, &label) in labels.iter().enumerate() {
            area[label as usize] += self.face_area(f);
        }
        let largest = area.iter().cloned().fold(0.0, f64::max);
        let keep_component: Vec<bool> = area.iter().map(|&a| a >= min_area_fraction * largest).collect();
        let keep_face: Vec<bool> = labels.iter().map(|&l| keep_component[l as usize]).collect();
        self.retain_faces(&keep_face);
    }

    /// Keeps the faces whose flag is set, and only the vertices they use (renumbered in order).
    pub fn retain_faces(&mut self, keep_face: &[bool]) {
        assert_eq!(keep_face.len(), self.faces.len());
        let mut new_index = vec![u32::MAX; self.positions.len()];
        let mut positions = Vec::new();
        let mut faces = Vec::new();
        let mut ids = self.face_object_ids.as_ref().map(|_| Vec::new());
        for (f, face) in self.faces.iter().enumerate() {
            if !keep_face[f] {
                continue;
            }
            let mut renumbered = [0u32; 3];
            for k in 0..3 {
                let v = face[k] as usize;
                if new_index[v] == u32::MAX {
                    new_index[v] = positions.len() as u32;
                    positions.push(self.positions[v]);
                }
                renumbered[k] = new_index[v];
            }
            faces.push(renumbered);
            if let (Some(ids), Some(src)) = (ids.as_mut(), self.face_object_ids.as_ref()) {
                ids.push(src[f]);
            }
        }
        self.positions = positions;
        self.faces = faces;
        self.face_object_ids = ids;
    }
}

#[cfg(test)]
mod tests {
    use super::TriangleMesh;

    fn box_mesh(min: [f32; 3], max: [f32; 3]) -> TriangleMesh {
        TriangleMesh::axis_box(min, max)
    }
    fn concat(meshes: &[TriangleMesh]) -> TriangleMesh {
        TriangleMesh::concat(meshes)
    }

    #[test]
    fn box_measures() {
        let m = box_mesh([0.0, 0.0, 0.0], [1.0, 2.0, 3.0]);
        assert!((m.surface_area() - 22.0).abs() < 1e-9);
        assert!((m.signed_volume() - 6.0).abs() < 1e-9);
        assert!(m.is_watertight_and_consistently_oriented());
        assert!(m.edge_face_counts().values().all(|&n| n == 2));
    }

    #[test]
    fn icosphere_is_closed_outward_and_inscribed() {
        let m = TriangleMesh::unit_icosphere(3);
        assert_eq!(m.num_faces(), 20 * 64);
        assert!(m.is_watertight_and_consistently_oriented());
        let v = m.signed_volume();
        assert!(v > 4.0 && v < 4.0 * std::f64::consts::PI / 3.0, "{v}");
        assert!(m
            .positions
            .iter()
            .all(|p| (glam::Vec3::from(*p).length() - 1.0).abs() < 1e-6));
        assert!(m.flipped().signed_volume() < 0.0);
    }

    #[test]
    fn small_components_are_removed() {
        let big = box_mesh([0.0; 3], [1.0; 3]);
        let small = box_mesh([3.0; 3], [3.1; 3]);
        let mut m = concat(&[big.clone(), small]);
        assert_eq!(m.face_components().1, 2);
        m.remove_small_components(0.05);
        assert_eq!((m.num_vertices(), m.num_faces()), (8, 12));
        assert!((m.signed_volume() - 1.0).abs() < 1e-9);
    }
}
