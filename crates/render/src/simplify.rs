//! Simplification of the marching-cubes surface to a face budget (meshoptimizer's edge-collapse
//! simplifier, through the `meshopt` bindings), one group of faces at a time: ordinary surface
//! and each emitter apart, their shared borders locked, so a group's faces never collapse across
//! its border and the groups still meet edge to edge afterwards. The glTF export simplifies to
//! its face budget; the edit renderer's recovered surface, which paths are traced in, to an error
//! bound only ([`simplify_labelled`]).

use i2sdf_data::TriangleMesh;
use meshopt::{SimplifyOptions, VertexDataAdapter};

/// Faces kept of each group whatever the budget (an emitter's few faces keep its shape).
const MIN_GROUP_FACES: usize = 64;

/// Simplifies each group of `faces` (indices into `positions`) towards `budget` faces in all,
/// shared out by the groups' sizes, without moving the surface by more than `max_error` (world
/// units). Vertices are only removed, never moved: the result indexes the same `positions`.
pub fn simplify_groups(
    positions: &[[f32; 3]],
    groups: &[Vec<[u32; 3]>],
    budget: usize,
    max_error: f32,
) -> Vec<Vec<[u32; 3]>> {
    let total: usize = groups.iter().map(Vec::len).sum();
    if total <= budget || positions.is_empty() {
        return groups.to_vec();
    }
    let bytes = meshopt::typed_to_bytes(positions);
    let adapter = VertexDataAdapter::new(bytes, 12, 0).expect("12-byte positions");
    groups
        .iter()
        .map(|g| {
            if g.is_empty() {
                return Vec::new();
            }
            let share = (budget as f64 * g.len() as f64 / total as f64).round() as usize;
            let target = share.max(MIN_GROUP_FACES.min(g.len()));
            if target >= g.len() {
                return g.clone();
            }
            let indices: Vec<u32> = g.iter().flatten().copied().collect();
            let out = meshopt::simplify(
                &indices,
                &adapter,
                target * 3,
                max_error,
                SimplifyOptions::LockBorder | SimplifyOptions::Sparse | SimplifyOptions::ErrorAbsolute,
                None,
            );
            out.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect()
        })
        .collect()
}

/// `mesh` simplified as far as `max_error` (world units) allows, each label's faces apart
/// (`labels`: one per face; at least [`MIN_GROUP_FACES`] kept per label): the new mesh, its
/// faces' labels, and for each new vertex its index in `mesh` (vertices are only removed). Flat
/// walls of a marching-cubes mesh collapse to a few large triangles, so a BVH over the result
/// is smaller and its traversal touches less memory.
pub fn simplify_labelled(mesh: &TriangleMesh, labels: &[u32], max_error: f32) -> (TriangleMesh, Vec<u32>, Vec<u32>) {
    assert_eq!(labels.len(), mesh.faces.len(), "one label per face");
    let mut names: Vec<u32> = labels.to_vec();
    names.sort_unstable();
    names.dedup();
    let groups: Vec<Vec<[u32; 3]>> = names
        .iter()
        .map(|&l| {
            mesh.faces
                .iter()
                .zip(labels)
                .filter(|(_, &f)| f == l)
                .map(|(f, _)| *f)
                .collect()
        })
        .collect();
    let groups = simplify_groups(&mesh.positions, &groups, 0, max_error);
    let (kept, groups) = compact(mesh.positions.len(), &groups);
    let mut out = TriangleMesh {
        positions: kept.iter().map(|&v| mesh.positions[v as usize]).collect(),
        ..Default::default()
    };
    let mut out_labels = Vec::new();
    for (g, &l) in groups.iter().zip(&names) {
        out.faces.extend(g);
        out_labels.extend(std::iter::repeat_n(l, g.len()));
    }
    (out, out_labels, kept)
}

/// The vertices the groups still use, in order, and the groups re-indexed into them.
pub fn compact(vertex_count: usize, groups: &[Vec<[u32; 3]>]) -> (Vec<u32>, Vec<Vec<[u32; 3]>>) {
    let mut new_index = vec![u32::MAX; vertex_count];
    let mut kept = Vec::new();
    let remapped = groups
        .iter()
        .map(|g| {
            g.iter()
                .map(|f| {
                    f.map(|v| {
                        let slot = &mut new_index[v as usize];
                        if *slot == u32::MAX {
                            *slot = kept.len() as u32;
                            kept.push(v);
                        }
                        *slot
                    })
                })
                .collect()
        })
        .collect();
    (kept, remapped)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    /// An n×n grid of quads on the plane z = 0 (two triangles each), split into a left and a
    /// right group.
    fn plane(n: usize) -> (Vec<[f32; 3]>, Vec<Vec<[u32; 3]>>) {
        let mut p = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                p.push([i as f32 / n as f32, j as f32 / n as f32, 0.0]);
            }
        }
        let v = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        let mut groups = vec![Vec::new(), Vec::new()];
        for j in 0..n {
            for i in 0..n {
                let g = usize::from(i >= n / 2);
                groups[g].push([v(i, j), v(i + 1, j), v(i + 1, j + 1)]);
                groups[g].push([v(i, j), v(i + 1, j + 1), v(i, j + 1)]);
            }
        }
        (p, groups)
    }

    fn area(p: &[[f32; 3]], faces: &[[u32; 3]]) -> f64 {
        faces
            .iter()
            .map(|f| {
                let [a, b, c] = f.map(|v| glam::Vec3::from(p[v as usize]));
                0.5 * (b - a).cross(c - a).length() as f64
            })
            .sum()
    }

    /// Labelled simplification: each label keeps its area, its faces keep their label, and every
    /// new vertex is the old one it names.
    #[test]
    fn a_labelled_flat_grid_collapses_each_label_apart() {
        let (p, groups) = plane(32);
        let mut mesh = TriangleMesh {
            positions: p.clone(),
            ..Default::default()
        };
        let mut labels = Vec::new();
        for (l, g) in groups.iter().enumerate() {
            mesh.faces.extend(g);
            labels.extend(std::iter::repeat_n(5 * l as u32, g.len()));
        }
        let (out, out_labels, kept) = simplify_labelled(&mesh, &labels, 1e-4);
        assert_eq!(out_labels.len(), out.faces.len());
        assert!(out.faces.len() < mesh.faces.len() / 4, "{} faces", out.faces.len());
        for (v, &k) in out.positions.iter().zip(&kept) {
            assert_eq!(*v, p[k as usize]);
        }
        for (l, g) in groups.iter().enumerate() {
            let faces: Vec<[u32; 3]> = out
                .faces
                .iter()
                .zip(&out_labels)
                .filter(|(_, &x)| x == 5 * l as u32)
                .map(|(f, _)| *f)
                .collect();
            assert!((area(&out.positions, &faces) - area(&p, g)).abs() < 1e-4);
        }
    }

    #[test]
    fn a_flat_grid_collapses_to_the_budget_keeping_each_groups_area_and_the_shared_border() {
        let (p, groups) = plane(32);
        let before: Vec<f64> = groups.iter().map(|g| area(&p, g)).collect();
        let out = simplify_groups(&p, &groups, 400, 1e-4);
        let faces: usize = out.iter().map(Vec::len).sum();
        assert!(faces <= 400 + 2 * MIN_GROUP_FACES, "{faces} faces");
        assert!(faces < groups.iter().map(Vec::len).sum::<usize>() / 4);
        for (g, a) in out.iter().zip(&before) {
            assert!((area(&p, g) - a).abs() < 1e-4, "area {} vs {a}", area(&p, g));
        }
        // the border between the groups (x = 0.5) keeps every vertex on both sides
        let on_border = |g: &Vec<[u32; 3]>| {
            let mut s: Vec<u32> = g
                .iter()
                .flatten()
                .copied()
                .filter(|&v| p[v as usize][0] == 0.5)
                .collect();
            s.sort();
            s.dedup();
            s
        };
        assert_eq!(on_border(&out[0]), on_border(&out[1]));
        assert_eq!(on_border(&out[0]).len(), 33);
    }

    #[test]
    fn compact_keeps_only_used_vertices_in_first_use_order() {
        let groups = vec![vec![[5, 2, 9]], vec![[9, 2, 7]]];
        let (kept, g) = compact(10, &groups);
        assert_eq!(kept, vec![5, 2, 9, 7]);
        assert_eq!(g, vec![vec![[0, 1, 2]], vec![[2, 1, 3]]]);
        // every face still names the same positions
        let m: HashMap<u32, u32> = kept.iter().enumerate().map(|(i, &v)| (i as u32, v)).collect();
        for (a, b) in groups.iter().flatten().zip(g.iter().flatten()) {
            assert_eq!(*a, b.map(|v| m[&v]));
        }
    }
}
