//! Which points of a ground-truth *mesh* some training view sees, exactly: the point is in front
//! of the camera and inside its image, and the segment from the camera's centre to it crosses no
//! GT surface. The depth-map rule of [`super::visible_from_views`] (a point counts unless it lies
//! more than the tolerance behind its pixel's depth) is what a point cloud allows; on a mesh it
//! also counts surfaces hidden less than the tolerance (5 cm) behind the one the view sees: the
//! back of a TV screen 5 cm thick, the sides of books pressed together, the bottom of a book on
//! its shelf. No view sees them, so neither re-fusing the GT from the views (the paper's
//! protocol) nor any method can recover them, yet they counted against recall, and on the
//! captures their share decided how far run-to-run noise moved the F-score.

use super::{Projector, REPORT_BATCH};
use crate::mesh::TriangleMesh;
use glam::Vec3;
use i2sdf_data::DataError;
use i2sdf_render::bvh::Bvh;
use rayon::prelude::*;

/// The part of a point's distance from the camera that a surface may lie short of it and still
/// not hide it: float error of a point sampled on a triangle and of the ray's hit on that same
/// triangle (1e-6 relative), and of a neighbour face where the point lies on a box's edge.
const SELF_HIT_SLACK: f32 = 1e-3;

/// Whether some view sees each point of `mesh`'s surface (see the module doc) where its pixel's
/// depth, as in [`super::visible_from_views`], does not hide it either (a sliver behind a
/// silhouette that the pixel shows the foreground of), calling `on_done(k)` as each batch of `k`
/// points is tested.
pub(super) fn seen_on_mesh(
    points: &[[f32; 3]],
    mesh: &TriangleMesh,
    views: &[super::CullingView],
    tolerance: f64,
    on_done: &(dyn Fn(u64) + Sync),
) -> Result<Vec<bool>, DataError> {
    let projectors = Projector::all(views)?;
    let centres: Vec<Vec3> = views.iter().map(|v| v.camera.center().as_vec3()).collect();
    let bvh = Bvh::build(mesh);
    Ok(points
        .par_chunks(REPORT_BATCH)
        .flat_map_iter(|batch| {
            let mut stack = Vec::new();
            let seen: Vec<bool> = batch
                .iter()
                .map(|&p| {
                    let p = Vec3::from(p);
                    projectors.iter().zip(&centres).any(|(proj, &o)| {
                        // The pixel's depth test as for the predicted points too, so that a GT
                        // point counts only where its own copy in an identical prediction would.
                        if !proj.not_hidden(p.into(), tolerance) {
                            return false;
                        }
                        let to = p - o;
                        let dist = to.length();
                        dist > 0.0 && !bvh.occluded(o, to / dist, 0.0, dist * (1.0 - SELF_HIT_SLACK), &mut stack)
                    })
                })
                .collect();
            on_done(batch.len() as u64);
            seen
        })
        .collect())
}
