//! Ground-truth geometry consistency of a rendered dataset: depth agrees across views, and the
//! written mesh contains every back-projected depth point.

mod common;

use common::*;
use glam::DVec3;
use i2sdf_synth::RoomPreset;

#[test]
fn depth_from_two_views_agrees_and_lies_on_the_mesh() {
    let tmp = tempfile::tempdir().unwrap();
    let w = render_tiny(tmp.path(), RoomPreset::Livingroom, 7, 6);

    // Cross-view: back-project view a's depth, project into view b, and compare with b's depth
    // interpolated there. On a plane 1/z is affine in pixel coordinates, so bilinear
    // interpolation of 1/z is exact away from edges; occluded points are skipped.
    let mut errors = Vec::new();
    for (ia, ib) in [(0usize, 1usize), (2, 3), (4, 0)] {
        let (a, b) = (&w.views[ia], &w.views[ib]);
        for y in 0..w.height {
            for x in 0..w.width {
                let p = w.back_project(a, x, y);
                let (u, v, z) = w.project(b, p);
                let (fx, fy) = (u - 0.5, v - 0.5);
                if z <= 0.0 || fx < 0.0 || fy < 0.0 || fx >= (w.width - 1) as f64 || fy >= (w.height - 1) as f64 {
                    continue;
                }
                let (x0, y0) = (fx.floor() as usize, fy.floor() as usize);
                let (tx, ty) = (fx - x0 as f64, fy - y0 as f64);
                let inv = |xx: usize, yy: usize| 1.0 / b.depth[yy * w.width + xx] as f64;
                let inv_z = (1.0 - ty) * ((1.0 - tx) * inv(x0, y0) + tx * inv(x0 + 1, y0))
                    + ty * ((1.0 - tx) * inv(x0, y0 + 1) + tx * inv(x0 + 1, y0 + 1));
                let zb = 1.0 / inv_z;
                if zb < z - 0.02 {
                    continue; // hidden from b
                }
                errors.push((zb - z).abs());
            }
        }
    }
    assert!(errors.len() > 2000, "too few overlapping pixels: {}", errors.len());
    errors.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let median = errors[errors.len() / 2];
    assert!(median < 1e-3, "median cross-view depth disagreement {median} m");

    // Every back-projected depth point lies on the written mesh.
    let (verts, faces) = read_ply(&tmp.path().join("mesh.ply"));
    let tris: Vec<[DVec3; 3]> = faces
        .iter()
        .map(|f| [0, 1, 2].map(|k| verts[f[k] as usize].as_dvec3()))
        .collect();
    let boxes: Vec<(DVec3, DVec3)> = tris
        .iter()
        .map(|t| {
            (
                t[0].min(t[1]).min(t[2]) - DVec3::splat(2e-3),
                t[0].max(t[1]).max(t[2]) + DVec3::splat(2e-3),
            )
        })
        .collect();
    let mut worst = 0.0f64;
    for v in &w.views {
        for y in 0..w.height {
            for x in 0..w.width {
                let p = w.back_project(v, x, y);
                let d = tris
                    .iter()
                    .zip(&boxes)
                    .filter(|(_, (lo, hi))| p.cmpge(*lo).all() && p.cmple(*hi).all())
                    .map(|(t, _)| point_triangle_distance(p, t[0], t[1], t[2]))
                    .fold(f64::INFINITY, f64::min);
                worst = worst.max(d);
            }
        }
    }
    assert!(worst < 1e-3, "a depth point is {worst} m from the mesh");
}
