//! Mesh accuracy, completeness, precision, recall and F-score (the paper's Sec. 6 and supp. Sec.
//! D, as the README's `eval` row lists), on points sampled uniformly by area on both meshes (a GT
//! point cloud, a PLY without faces, gives its points as they are) and culled to what the training
//! views can see: the paper's evaluation re-fuses both meshes from the training views, and the
//! equivalent on points is that a ground-truth point counts where some view sees it (on a GT mesh
//! exactly, by a ray through the mesh: [`seen`]; on a GT point cloud by the views' GT depth), and
//! a predicted point counts unless the GT surface hides it from every view (so floaters in free
//! space still cost precision; see [`visible_from_views`]). A predicted point's distance is taken
//! to the whole GT surface, seen or not: a point on a surface no view sees is still on it.
//! Recall is also reported per GT object and for groups of objects (the thin and suspended ones)
//! at thresholds of their own.

use crate::mesh::TriangleMesh;
use crate::progress::{self, EvalProgress, NoProgress};
use glam::{DMat4, DVec3};
use i2sdf_data::{Camera, DataError, KdTree};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashSet};

mod seen;

/// A training view for visibility culling: the dataset's camera (OpenCV axes, pixel centres at
/// +0.5) with the ground-truth z-depth it sees.
#[derive(Clone, Debug)]
pub struct CullingView {
    pub camera: Camera,
    /// Ground-truth z-depth along the camera's z axis, row-major `height × width`; a non-finite or
    /// non-positive value means no surface (nothing hides points there, no GT point is seen there).
    pub depth: Vec<f32>,
}

/// A view prepared for projection: world-to-camera once, in f64.
struct Projector<'a> {
    view: &'a CullingView,
    w2c: DMat4,
}

impl<'a> Projector<'a> {
    /// One per view, in order; an error names the first view that cannot project.
    fn all(views: &'a [CullingView]) -> Result<Vec<Self>, DataError> {
        views.iter().enumerate().map(|(i, v)| Projector::new(v, i)).collect()
    }

    fn new(view: &'a CullingView, index: usize) -> Result<Self, DataError> {
        let bad = |msg: String| DataError::invalid(format!("culling view {index}: {msg}"));
        let c = &view.camera;
        if view.depth.len() != c.width * c.height {
            return Err(bad(format!(
                "depth has {} pixels, image is {}×{}",
                view.depth.len(),
                c.width,
                c.height
            )));
        }
        c.validate().map_err(bad)?;
        Ok(Projector { view, w2c: c.w2c() })
    }

    /// The point's camera z and the GT depth of the pixel it falls in, when it is in front of the
    /// camera and inside the image.
    fn project(&self, p: [f32; 3]) -> Option<(f64, f32)> {
        let c = self
            .w2c
            .transform_point3(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64));
        if c.z <= 1e-6 {
            return None;
        }
        let cam = &self.view.camera;
        let (u, w) = cam.project_camera_space(c);
        if !(u >= 0.0 && w >= 0.0 && u < cam.width as f64 && w < cam.height as f64) {
            return None;
        }
        // Pixel (i, j) covers [i, i + 1) with its centre at i + 0.5.
        let (i, j) = (u as usize, w as usize);
        Some((c.z, self.view.depth[j * cam.width + i]))
    }

    /// Whether `p` is in this view's image and no more than `tolerance` behind its pixel's GT
    /// depth (a pixel without GT depth hides nothing): the depth rule of both cullings.
    fn not_hidden(&self, p: [f32; 3], tolerance: f64) -> bool {
        self.project(p)
            .is_some_and(|(z, d)| !valid_depth(d) || z <= d as f64 + tolerance)
    }
}

fn valid_depth(d: f32) -> bool {
    d.is_finite() && d > 0.0
}

/// Whether some view sees each point: in front of the camera, inside the image, and not behind
/// that view's GT depth at its pixel by more than `tolerance` (a pixel without GT depth hides
/// nothing).
///
/// For a predicted point it is the paper's re-fusion rule, "no GT surface hides it from every
/// view", so floaters in free space count, and a surface reconstructed up to the tolerance behind
/// the true one is scored by its distance rather than dropped. For the points of a GT point cloud
/// it stands for "some view's depth sees it": the stricter |z − depth| ≤ tolerance differs only
/// where a point lies in front of its pixel's depth by more than the tolerance, which for a point
/// on the GT surface happens only through pixel discretization at silhouettes and grazing angles,
/// where the point is in fact visible. A GT mesh is culled exactly instead (`seen`).
pub fn visible_from_views(points: &[[f32; 3]], views: &[CullingView], tolerance: f64) -> Result<Vec<bool>, DataError> {
    visible_reporting(points, views, tolerance, &|_| {})
}

/// Points per progress report of the sampling, culling and nearest-neighbour steps.
const REPORT_BATCH: usize = 16_384;

/// [`visible_from_views`], calling `on_done(k)` as each batch of `k` points is tested.
fn visible_reporting(
    points: &[[f32; 3]],
    views: &[CullingView],
    tolerance: f64,
    on_done: &(dyn Fn(u64) + Sync),
) -> Result<Vec<bool>, DataError> {
    let projectors = Projector::all(views)?;
    Ok(points
        .par_chunks(REPORT_BATCH)
        .flat_map_iter(|batch| {
            let seen: Vec<bool> = batch
                .iter()
                .map(|&p| projectors.iter().any(|proj| proj.not_hidden(p, tolerance)))
                .collect();
            on_done(batch.len() as u64);
            seen
        })
        .collect())
}

/// `n` points uniformly distributed by area on the mesh (deterministic for a seed), with the face
/// each lies on. Empty for a mesh without area.
pub fn sample_surface(mesh: &TriangleMesh, n: usize, seed: u64) -> (Vec<[f32; 3]>, Vec<u32>) {
    sample_reporting(mesh, n, seed, &|_| {})
}

/// [`sample_surface`], calling `on_done(k)` as each batch of `k` of the `n` points is drawn (all
/// `n` at once for a mesh without area).
fn sample_reporting(
    mesh: &TriangleMesh,
    n: usize,
    seed: u64,
    on_done: &(dyn Fn(u64) + Sync),
) -> (Vec<[f32; 3]>, Vec<u32>) {
    // The areas in parallel, then their running sum in place (the same sums as one loop).
    let mut cdf: Vec<f64> = (0..mesh.num_faces())
        .into_par_iter()
        .map(|f| mesh.face_area(f))
        .collect();
    for i in 1..cdf.len() {
        cdf[i] += cdf[i - 1];
    }
    let total = cdf.last().copied().unwrap_or(0.0);
    if total <= 0.0 || !total.is_finite() || n == 0 {
        on_done(n as u64);
        return (Vec::new(), Vec::new());
    }
    // The uniforms are drawn in one stream (the samples do not depend on the thread count);
    // the searches in the CDF, a cache miss per step on a large mesh, run in parallel.
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let uniforms: Vec<[f64; 3]> = (0..n).map(|_| [rng.gen(), rng.gen(), rng.gen()]).collect();
    uniforms
        .par_chunks(REPORT_BATCH)
        .flat_map_iter(|batch| {
            let drawn: Vec<([f32; 3], u32)> = batch
                .iter()
                .map(|&[u, r1, r2]| {
                    let target = u * total;
                    let f = cdf.partition_point(|&c| c <= target).min(cdf.len() - 1);
                    // Uniform on the triangle: barycentrics (1 − √r1, √r1 (1 − r2), √r1 r2).
                    let s = r1.sqrt();
                    let w = [1.0 - s, s * (1.0 - r2), s * r2];
                    let tri = mesh.triangle(f);
                    let p = std::array::from_fn(|a| {
                        (w[0] * tri[0][a] as f64 + w[1] * tri[1][a] as f64 + w[2] * tri[2][a] as f64) as f32
                    });
                    (p, f as u32)
                })
                .collect();
            on_done(batch.len() as u64);
            drawn
        })
        .unzip()
}

#[derive(Clone, Debug)]
pub struct MeshMetricsOptions {
    /// Points sampled on each mesh before culling.
    pub num_points: usize,
    /// Distance under which a point counts as matched (precision, recall), in scene units.
    pub threshold: f64,
    /// Depth tolerance of the visibility tests; `None` uses `threshold`.
    pub depth_tolerance: Option<f64>,
    pub seed: u64,
    /// Sets of GT objects whose recall is reported together, each at its own thresholds.
    pub object_groups: Vec<ObjectGroup>,
}

/// The distances (scene units: 2 cm and 5 cm in metric scenes) at which thin objects are scored:
/// `geometry.thin_objects` and each object's `recall_2cm` / `recall_5cm`.
pub const THIN_OBJECT_THRESHOLDS: [f64; 2] = [0.02, 0.05];

/// GT objects scored together (e.g. every object tagged `thin`): a missing lamp pole barely moves
/// the global recall, so the objects that matter are measured on their own.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectGroup {
    pub name: String,
    /// Per-face `object_id`s of the GT mesh that belong to the group.
    pub object_ids: Vec<i32>,
    /// Distances (scene units) at which the recall is computed.
    pub thresholds: Vec<f64>,
}

impl Default for MeshMetricsOptions {
    fn default() -> Self {
        MeshMetricsOptions {
            // 1M points on a ~140 m² room: ~1 cm spacing, so that a 2 cm recall is not capped by
            // the sampling density of the predicted mesh.
            num_points: 1_000_000,
            threshold: 0.05,
            depth_tolerance: None,
            seed: 0,
            object_groups: Vec::new(),
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObjectRecall {
    pub object_id: i32,
    /// Fraction of the object's visible GT points within the threshold of the prediction.
    pub recall: Option<f64>,
    /// The same within each of [`THIN_OBJECT_THRESHOLDS`] (2 and 5 cm): what a thin object's
    /// recovery is measured by, whatever the main threshold.
    pub recall_thin: [Option<f64>; 2],
    /// The object's visible GT points.
    pub points: usize,
}

/// The recall of one [`ObjectGroup`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GroupRecall {
    pub name: String,
    /// The group's visible GT points (0 when the GT mesh has no object ids).
    pub points: usize,
    pub thresholds: Vec<f64>,
    /// Fraction of those points within each threshold of the prediction, in the order of
    /// `thresholds`; `None` without points.
    pub recall: Vec<Option<f64>>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MeshMetrics {
    /// Mean distance from predicted points to the GT surface samples.
    pub accuracy: Option<f64>,
    /// Mean distance from GT points to the predicted surface samples.
    pub completeness: Option<f64>,
    pub precision: Option<f64>,
    pub recall: Option<f64>,
    pub fscore: Option<f64>,
    pub threshold: f64,
    /// Points left after culling.
    pub pred_points: usize,
    pub gt_points: usize,
    /// How each mesh's points were culled, in words (the report's `culling`).
    pub culling: String,
    /// Per GT object (when the GT mesh has per-face object ids), sorted by id.
    pub per_object_recall: Vec<ObjectRecall>,
    /// One per `MeshMetricsOptions::object_groups`, in order.
    pub group_recall: Vec<GroupRecall>,
}

fn mean(values: &[f32]) -> Option<f64> {
    (!values.is_empty()).then(|| values.iter().map(|&v| v as f64).sum::<f64>() / values.len() as f64)
}

fn fraction_under(values: &[f32], threshold: f64) -> Option<f64> {
    (!values.is_empty())
        .then(|| values.iter().filter(|&&v| (v as f64) < threshold).count() as f64 / values.len() as f64)
}

/// Compares a predicted mesh with the ground truth. With no views, no culling is done.
pub fn mesh_metrics(
    pred: &TriangleMesh,
    gt: &TriangleMesh,
    views: &[CullingView],
    options: &MeshMetricsOptions,
) -> Result<MeshMetrics, DataError> {
    mesh_metrics_with_progress(pred, gt, views, options, &NoProgress)
}

/// [`mesh_metrics`], reporting its steps to `progress`: sampling surfaces, visibility culling
/// (with views) and nearest neighbours, each counted in points (see [`EvalProgress`]).
pub fn mesh_metrics_with_progress(
    pred: &TriangleMesh,
    gt: &TriangleMesh,
    views: &[CullingView],
    options: &MeshMetricsOptions,
    progress: &dyn EvalProgress,
) -> Result<MeshMetrics, DataError> {
    check_thresholds(options)?;
    let samples = visible_samples(pred, gt, views, options, progress)?;
    let (pred_points, gt_points) = (&samples.pred, &samples.gt);
    progress.step(
        progress::NEAREST_NEIGHBOURS,
        (pred_points.len() + gt_points.len()) as u64,
    );
    let on_answered = |n: usize| progress.inc(n as u64);
    let (pred_tree, gt_tree) = rayon::join(|| KdTree::new(pred_points), || KdTree::new(&samples.gt_all));
    let pred_to_gt = gt_tree.nearest_distances(pred_points, &on_answered);
    let gt_to_pred = pred_tree.nearest_distances(gt_points, &on_answered);
    let t = options.threshold;
    let culling = culling_rule(views.len(), gt.num_faces() == 0, options);
    let mut metrics = MeshMetrics {
        accuracy: None,
        completeness: None,
        precision: None,
        recall: None,
        fscore: None,
        threshold: t,
        pred_points: pred_points.len(),
        gt_points: gt_points.len(),
        culling,
        per_object_recall: Vec::new(),
        group_recall: Vec::new(),
    };
    let gt_ids = gt.face_object_ids.as_deref();
    metrics.group_recall = options
        .object_groups
        .iter()
        .map(|g| group_recall(g, gt_ids, &samples.gt_faces, &gt_to_pred))
        .collect();
    if gt_points.is_empty() {
        return Ok(metrics);
    }
    if pred_points.is_empty() {
        // Nothing predicted where the GT is seen: nothing is recalled; distances are undefined.
        metrics.recall = Some(0.0);
        metrics.fscore = Some(0.0);
    } else {
        metrics.accuracy = mean(&pred_to_gt);
        metrics.completeness = mean(&gt_to_pred);
        metrics.precision = fraction_under(&pred_to_gt, t);
        metrics.recall = fraction_under(&gt_to_pred, t);
        let (p, r) = (metrics.precision.unwrap(), metrics.recall.unwrap());
        metrics.fscore = Some(if p + r > 0.0 { 2.0 * p * r / (p + r) } else { 0.0 });
    }
    if let Some(ids) = &gt.face_object_ids {
        metrics.per_object_recall = per_object_recall(ids, &samples.gt_faces, &gt_to_pred, t);
    }
    Ok(metrics)
}

/// The culling [`mesh_metrics`] applies with `views` training views to a GT mesh or point cloud,
/// in words.
fn culling_rule(views: usize, gt_is_cloud: bool, options: &MeshMetricsOptions) -> String {
    if views == 0 {
        return "none: no training view with GT depth, every sampled point counts".into();
    }
    let tolerance = options.depth_tolerance.unwrap_or(options.threshold);
    let gt = if gt_is_cloud {
        "GT points (a point cloud) where some view's GT depth does not hide them"
    } else {
        "GT points where some view sees them (a ray through the GT mesh) and its pixel's GT depth does not hide them"
    };
    format!(
        "{views} training views: {gt}; predicted points where no GT surface hides them from every view \
         (GT depth, {tolerance} behind the surface allowed); precision against the whole GT surface"
    )
}

/// Refuses a main threshold or an object group's threshold that is not positive and finite.
fn check_thresholds(options: &MeshMetricsOptions) -> Result<(), DataError> {
    if options.threshold <= 0.0 || !options.threshold.is_finite() {
        return Err(DataError::invalid(format!(
            "mesh metrics threshold must be positive, got {}",
            options.threshold
        )));
    }
    for g in &options.object_groups {
        if g.thresholds.iter().any(|t| !(*t > 0.0 && t.is_finite())) {
            return Err(DataError::invalid(format!(
                "object group {}: thresholds must be positive, got {:?}",
                g.name, g.thresholds
            )));
        }
    }
    Ok(())
}

/// The points sampled on both meshes that survive visibility culling, with the GT face of each
/// GT point.
struct VisibleSamples {
    pred: Vec<[f32; 3]>,
    gt: Vec<[f32; 3]>,
    gt_faces: Vec<u32>,
    /// Every GT sample, seen or not: what a predicted point's distance to the GT surface is
    /// measured against (a predicted point on a surface no view sees is on the surface).
    gt_all: Vec<[f32; 3]>,
}

/// Samples `options.num_points` on each mesh and keeps those the views see (all of them without
/// views), reporting the sampling and culling steps. A GT without faces is a point cloud (the
/// release's promised GT): its points are the GT samples as they are, each with face 0 (a point
/// cloud has no per-face object ids, so the faces are never looked up).
fn visible_samples(
    pred: &TriangleMesh,
    gt: &TriangleMesh,
    views: &[CullingView],
    options: &MeshMetricsOptions,
    progress: &dyn EvalProgress,
) -> Result<VisibleSamples, DataError> {
    let tolerance = options.depth_tolerance.unwrap_or(options.threshold);
    let on_done = |n: u64| progress.inc(n);
    let gt_is_cloud = gt.num_faces() == 0;
    let gt_sampled = if gt_is_cloud { 0 } else { options.num_points };
    // The same seed on both meshes: identical meshes give identical samples (distance 0).
    progress.step(progress::SAMPLING, (options.num_points + gt_sampled) as u64);
    let (pred_all, _) = sample_reporting(pred, options.num_points, options.seed, &on_done);
    let (gt_all, gt_faces_all) = if gt_is_cloud {
        (gt.positions.clone(), vec![0; gt.positions.len()])
    } else {
        sample_reporting(gt, options.num_points, options.seed, &on_done)
    };
    let (pred_keep, gt_keep) = if views.is_empty() {
        (vec![true; pred_all.len()], vec![true; gt_all.len()])
    } else {
        progress.step(progress::CULLING, (pred_all.len() + gt_all.len()) as u64);
        let gt_keep = if gt_is_cloud {
            visible_reporting(&gt_all, views, tolerance, &on_done)?
        } else {
            seen::seen_on_mesh(&gt_all, gt, views, tolerance, &on_done)?
        };
        (visible_reporting(&pred_all, views, tolerance, &on_done)?, gt_keep)
    };
    let pred_points: Vec<[f32; 3]> = pred_all
        .iter()
        .zip(&pred_keep)
        .filter(|(_, &k)| k)
        .map(|(p, _)| *p)
        .collect();
    let (gt_points, gt_faces): (Vec<[f32; 3]>, Vec<u32>) = gt_all
        .iter()
        .zip(&gt_faces_all)
        .zip(&gt_keep)
        .filter(|(_, &k)| k)
        .map(|((p, f), _)| (*p, *f))
        .unzip();
    Ok(VisibleSamples {
        pred: pred_points,
        gt: gt_points,
        gt_faces,
        gt_all,
    })
}

/// Per GT object (`ids`: the GT mesh's per-face object ids; every id listed, with or without
/// points): its visible points, and the share of them within `t` and within each of
/// [`THIN_OBJECT_THRESHOLDS`] of the prediction.
fn per_object_recall(ids: &[i32], gt_faces: &[u32], gt_to_pred: &[f32], t: f64) -> Vec<ObjectRecall> {
    // Per object: points, and those matched within t and within each thin threshold.
    let mut per_object: BTreeMap<i32, (usize, [usize; 3])> = BTreeMap::new();
    for id in ids {
        per_object.entry(*id).or_default();
    }
    let [t2, t5] = THIN_OBJECT_THRESHOLDS;
    for (k, &f) in gt_faces.iter().enumerate() {
        let entry = per_object.get_mut(&ids[f as usize]).unwrap();
        entry.0 += 1;
        let d = gt_to_pred[k] as f64;
        for (n, limit) in entry.1.iter_mut().zip([t, t2, t5]) {
            if d < limit {
                *n += 1;
            }
        }
    }
    per_object
        .into_iter()
        .map(|(object_id, (points, [matched, m2, m5]))| {
            let share = |m: usize| (points > 0).then(|| m as f64 / points as f64);
            ObjectRecall {
                object_id,
                recall: share(matched),
                recall_thin: [share(m2), share(m5)],
                points,
            }
        })
        .collect()
}

/// Recall of the GT points (`gt_faces[k]` is the face of point `k`, at distance `gt_to_pred[k]`
/// from the prediction) on the group's objects.
fn group_recall(group: &ObjectGroup, gt_ids: Option<&[i32]>, gt_faces: &[u32], gt_to_pred: &[f32]) -> GroupRecall {
    let members: HashSet<i32> = group.object_ids.iter().copied().collect();
    let distances: Vec<f32> = match gt_ids {
        Some(ids) => gt_faces
            .iter()
            .zip(gt_to_pred)
            .filter(|(f, _)| members.contains(&ids[**f as usize]))
            .map(|(_, d)| *d)
            .collect(),
        None => Vec::new(),
    };
    GroupRecall {
        name: group.name.clone(),
        points: distances.len(),
        thresholds: group.thresholds.clone(),
        recall: group
            .thresholds
            .iter()
            .map(|&t| fraction_under(&distances, t))
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::test_shapes::{box_mesh, concat};
    use glam::Vec3;

    const W: usize = 96;
    const H: usize = 72;

    /// Ground-truth z-depth by brute-force ray casting (Möller–Trumbore) from an OpenCV camera at
    /// `eye` looking at `target`, world up +z.
    fn render_view(gt: &TriangleMesh, eye: [f32; 3], target: [f32; 3]) -> CullingView {
        let (eye, target) = (Vec3::from(eye).as_dvec3(), Vec3::from(target).as_dvec3());
        let camera = Camera {
            lens: Default::default(),
            width: W,
            height: H,
            fx: 40.0,
            fy: 40.0,
            cx: W as f64 / 2.0,
            cy: H as f64 / 2.0,
            c2w: i2sdf_data::camera::look_at(eye, target, DVec3::Z),
        };
        let mut depth = vec![f32::INFINITY; W * H];
        for j in 0..H {
            for i in 0..W {
                // z = 1 in the camera, so t along it is the z-depth.
                let dir = camera.rotation() * camera.pixel_center_dir_cam(i, j);
                let dir = dir.to_array();
                let o = eye.to_array();
                for f in 0..gt.num_faces() {
                    let [a, b, c] = gt.triangle(f).map(|p| p.map(|x| x as f64));
                    let e1: [f64; 3] = std::array::from_fn(|k| b[k] - a[k]);
                    let e2: [f64; 3] = std::array::from_fn(|k| c[k] - a[k]);
                    let p = crate::mesh::cross(dir, e2);
                    let det = crate::mesh::dot(e1, p);
                    if det.abs() < 1e-12 {
                        continue;
                    }
                    let s: [f64; 3] = std::array::from_fn(|k| o[k] - a[k]);
                    let u = crate::mesh::dot(s, p) / det;
                    let q = crate::mesh::cross(s, e1);
                    let v = crate::mesh::dot(dir, q) / det;
                    let t = crate::mesh::dot(e2, q) / det;
                    if u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t > 0.0 {
                        depth[j * W + i] = depth[j * W + i].min(t as f32);
                    }
                }
            }
        }
        CullingView { camera, depth }
    }

    fn room() -> TriangleMesh {
        box_mesh([0.0, 0.0, 0.0], [4.0, 3.0, 2.5])
    }

    fn room_views(gt: &TriangleMesh) -> Vec<CullingView> {
        let eyes = [[1.0, 1.0, 1.2], [3.0, 2.0, 1.5], [2.0, 0.5, 2.0], [3.5, 2.5, 0.8]];
        let targets = [[4.0, 3.0, 0.5], [0.0, 0.0, 1.0], [2.0, 3.0, 0.0], [0.0, 1.0, 2.5]];
        eyes.iter()
            .zip(&targets)
            .map(|(&e, &t)| render_view(gt, e, t))
            .collect()
    }

    fn options() -> MeshMetricsOptions {
        // Dense enough that independent samplings of one surface are within the threshold of each
        // other (200k points on the 59 m² room: ~0.02 spacing).
        MeshMetricsOptions {
            num_points: 200_000,
            ..Default::default()
        }
    }

    fn shifted(mesh: &TriangleMesh, by: [f32; 3]) -> TriangleMesh {
        let mut m = mesh.clone();
        m.positions.iter_mut().for_each(|p| (0..3).for_each(|a| p[a] += by[a]));
        m
    }

    #[test]
    fn sampling_is_uniform_by_area_and_deterministic() {
        // A 1×1 and a 3×1 rectangle side by side: a quarter of the points on the first.
        let mesh = concat(&[
            box_mesh([0.0; 3], [1.0, 1.0, 0.0]),
            box_mesh([1.0, 0.0, 0.0], [4.0, 1.0, 0.0]),
        ]);
        let (points, faces) = sample_surface(&mesh, 40_000, 5);
        let first = points.iter().filter(|p| p[0] < 1.0).count() as f64 / 40_000.0;
        assert!((first - 0.25).abs() < 0.01, "{first}");
        assert!(faces.iter().all(|&f| (f as usize) < mesh.num_faces()));
        assert_eq!(sample_surface(&mesh, 100, 5), sample_surface(&mesh, 100, 5));
        assert!(sample_surface(&TriangleMesh::default(), 10, 0).0.is_empty());
    }

    #[test]
    fn identical_meshes_score_perfectly() {
        let gt = room();
        let views = room_views(&gt);
        let m = mesh_metrics(&gt, &gt, &views, &options()).unwrap();
        assert_eq!(m.fscore, Some(1.0));
        assert_eq!((m.precision, m.recall), (Some(1.0), Some(1.0)));
        assert!(m.accuracy.unwrap() < 1e-6 && m.completeness.unwrap() < 1e-6);
        // Most of the room is seen by the four views, none of it is hidden.
        assert!(m.gt_points > 150_000, "{}", m.gt_points);
        assert_eq!(m.pred_points, m.gt_points);
    }

    /// A GT point cloud (a mesh without faces) is scored as its points: dense points on the room
    /// score the room's mesh perfectly, the same points moved by twice the threshold score zero,
    /// and the points are counted as they are (culled, not resampled).
    #[test]
    fn a_gt_point_cloud_is_scored_as_its_points() {
        let gt = room();
        let views = room_views(&gt);
        let (points, _) = sample_surface(&gt, 200_000, 7);
        let cloud = TriangleMesh {
            positions: points,
            ..Default::default()
        };
        let m = mesh_metrics(&gt, &cloud, &views, &options()).unwrap();
        assert!(m.fscore.unwrap() > 0.99, "{m:?}");
        assert!(m.accuracy.unwrap() < 0.01 && m.completeness.unwrap() < 0.01, "{m:?}");
        assert!(m.gt_points > 150_000 && m.gt_points <= 200_000, "{}", m.gt_points);
        let far = TriangleMesh {
            positions: cloud.positions.iter().map(|p| p.map(|x| x + 0.1)).collect(),
            ..Default::default()
        };
        assert!(m.culling.contains("(a point cloud)"), "{}", m.culling);
        let m = mesh_metrics(&gt, &far, &[], &options()).unwrap();
        assert_eq!(m.gt_points, 200_000, "without views every point counts");
        assert!(m.culling.starts_with("none"), "{}", m.culling);
        assert!(m.recall.unwrap() < 0.25, "{m:?}");
    }

    #[test]
    fn offset_by_twice_the_threshold_scores_zero() {
        // Every wall moved 0.1 = 2 × threshold into the room: all points are 0.1 or more off.
        let gt = room();
        let views = room_views(&gt);
        let pred = box_mesh([0.1, 0.1, 0.1], [3.9, 2.9, 2.4]);
        let m = mesh_metrics(&pred, &gt, &views, &options()).unwrap();
        assert_eq!(m.fscore, Some(0.0));
        let (acc, comp) = (m.accuracy.unwrap(), m.completeness.unwrap());
        assert!(
            (0.1..0.11).contains(&acc) && (0.1..0.15).contains(&comp),
            "{acc} {comp}"
        );
        // A translated copy scores zero as well without culling, as the two rooms' walls are then
        // parallel planes 0.1 apart except near the seams.
        let m = mesh_metrics(&shifted(&gt, [0.1, 0.1, 0.1]), &gt, &[], &options()).unwrap();
        assert!(m.fscore.unwrap() < 0.05, "{:?}", m.fscore);
    }

    #[test]
    fn floater_in_free_space_lowers_precision_only() {
        let gt = room();
        let views = room_views(&gt);
        let floater = box_mesh([1.8, 1.3, 1.0], [2.4, 1.9, 1.6]);
        let pred = concat(&[gt.clone(), floater.clone()]);
        let m = mesh_metrics(&pred, &gt, &views, &options()).unwrap();
        assert_eq!(m.recall, Some(1.0));
        let expected = gt.surface_area() / pred.surface_area();
        let p = m.precision.unwrap();
        assert!(
            (p - expected).abs() < 0.02,
            "precision {p}, floater-free fraction {expected}"
        );
        assert!(m.fscore.unwrap() < 1.0);
    }

    #[test]
    fn surfaces_hidden_from_every_view_are_ignored() {
        let walls = room();
        // A box behind the +x wall, outside the room: no view can see it.
        let hidden = box_mesh([4.5, 1.0, 0.5], [5.5, 2.0, 1.5]);
        let gt = concat(&[walls.clone(), hidden.clone()]);
        let views = room_views(&gt);
        // The GT part is never seen, so missing it costs no recall...
        let m = mesh_metrics(&walls, &gt, &views, &options()).unwrap();
        assert_eq!(m.recall, Some(1.0));
        // ...and a prediction behind the GT walls is not counted against precision.
        let m = mesh_metrics(&gt, &walls, &room_views(&walls), &options()).unwrap();
        assert_eq!(m.precision, Some(1.0));
        // Without culling, both count.
        let m = mesh_metrics(&walls, &gt, &[], &options()).unwrap();
        assert!(m.recall.unwrap() < 0.97);
    }

    /// A screen 3 cm thick, 17 cm in front of a wall: its back faces the wall, so no view sees it,
    /// though it lies within the depth tolerance behind the front every view sees. A prediction
    /// that fills the gap behind the screen with a solid block (what a reconstruction that never
    /// saw the gap does) recalls every point the views see; the back face does not count.
    #[test]
    fn gt_faces_hidden_within_the_tolerance_do_not_count() {
        let mut walls = room();
        walls.face_object_ids = Some(vec![0; 12]);
        let mut screen = box_mesh([1.5, 1.0, 2.30], [2.5, 1.6, 2.33]);
        screen.face_object_ids = Some(vec![5; 12]);
        let gt = concat(&[walls, screen]);
        let mut views = room_views(&gt);
        views.push(render_view(&gt, [2.0, 0.8, 0.4], [2.0, 1.6, 2.5]));
        let block = concat(&[room(), box_mesh([1.5, 1.0, 2.30], [2.5, 1.6, 2.5])]);
        let m = mesh_metrics(&block, &gt, &views, &options()).unwrap();
        let screen = &m.per_object_recall[1];
        assert_eq!((screen.object_id, screen.recall), (5, Some(1.0)), "{screen:?}");
        assert!(m.culling.starts_with("5 training views") && m.culling.contains("a ray through the GT mesh"));
        // At most its front and rims (0.70 of its 1.26 m²) count; the 0.6 m² back does not.
        let unculled = mesh_metrics(&block, &gt, &[], &options()).unwrap().per_object_recall[1].points;
        let counted = screen.points as f64 / unculled as f64;
        assert!(counted < 0.58, "{counted} of the screen's points counted");
        // The GT itself still scores perfectly: a predicted point on the hidden back is on the GT.
        let m = mesh_metrics(&gt, &gt, &views, &options()).unwrap();
        assert_eq!(m.fscore, Some(1.0));
    }

    #[test]
    fn per_object_recall_exposes_a_missing_object() {
        let mut walls = room();
        walls.face_object_ids = Some(vec![0; 12]);
        let mut lamp = box_mesh([1.5, 1.2, 0.8], [1.7, 1.4, 1.6]);
        lamp.face_object_ids = Some(vec![7; 12]);
        let gt = concat(&[walls.clone(), lamp]);
        let views = room_views(&gt);
        let pred = room();
        let m = mesh_metrics(&pred, &gt, &views, &options()).unwrap();
        assert!(m.recall.unwrap() > 0.95, "the global figure barely moves");
        assert_eq!(m.per_object_recall.len(), 2);
        assert_eq!(m.per_object_recall[0].object_id, 0);
        assert_eq!(m.per_object_recall[0].recall, Some(1.0));
        let lamp = &m.per_object_recall[1];
        assert_eq!(lamp.object_id, 7);
        assert!(lamp.points > 0 && lamp.recall == Some(0.0), "{lamp:?}");
        assert_eq!(lamp.recall_thin, [Some(0.0), Some(0.0)]);
        // The lamp 3.5 cm off along each axis: lost at 2 cm, found at 5 cm.
        let mut moved = box_mesh([1.535, 1.235, 0.835], [1.735, 1.435, 1.635]);
        moved.face_object_ids = Some(vec![7; 12]);
        let m = mesh_metrics(&concat(&[room(), moved]), &gt, &views, &options()).unwrap();
        let [r2, r5] = m.per_object_recall[1].recall_thin.map(Option::unwrap);
        assert!(r2 < 0.2 && r5 > 0.8, "recall {r2} at 2 cm, {r5} at 5 cm");
    }

    #[test]
    fn group_recall_scores_its_objects_at_each_threshold() {
        let mut walls = room();
        walls.face_object_ids = Some(vec![0; 12]);
        // Object 7 hangs in the room; object 8 is a box on the floor 0.03 above where the
        // prediction puts it.
        let mut lamp = box_mesh([1.5, 1.2, 0.8], [1.7, 1.4, 1.6]);
        lamp.face_object_ids = Some(vec![7; 12]);
        let mut chest = box_mesh([2.5, 0.5, 0.0], [3.5, 1.5, 0.5]);
        chest.face_object_ids = Some(vec![8; 12]);
        let gt = concat(&[walls, lamp, chest]);
        let pred = concat(&[room(), box_mesh([2.5, 0.5, -0.03], [3.5, 1.5, 0.47])]);
        let group = |name: &str, ids: Vec<i32>| ObjectGroup {
            name: name.into(),
            object_ids: ids,
            thresholds: vec![0.01, 0.05],
        };
        let opts = MeshMetricsOptions {
            object_groups: vec![group("lamp", vec![7]), group("chest", vec![8]), group("none", vec![42])],
            ..options()
        };
        let m = mesh_metrics(&pred, &gt, &room_views(&gt), &opts).unwrap();
        let [lamp, chest, none] = &m.group_recall[..] else {
            panic!("{:?}", m.group_recall)
        };
        assert_eq!(
            (lamp.name.as_str(), lamp.thresholds.clone()),
            ("lamp", vec![0.01, 0.05])
        );
        assert!(lamp.points > 0 && lamp.recall == vec![Some(0.0), Some(0.0)], "{lamp:?}");
        // The chest's top is 0.03 off: missed at 0.01, matched at 0.05 (its sides still match).
        let (at_1cm, at_5cm) = (chest.recall[0].unwrap(), chest.recall[1].unwrap());
        assert!(at_1cm < 0.8 && at_5cm > 0.95, "{chest:?}");
        assert_eq!((none.points, none.recall.clone()), (0, vec![None, None]));

        // The same prediction scores every group perfectly when it is the GT itself.
        let m = mesh_metrics(&gt, &gt, &[], &opts).unwrap();
        assert_eq!(m.group_recall[0].recall, vec![Some(1.0), Some(1.0)]);
        // Without object ids in the GT mesh no group has points.
        let m = mesh_metrics(&pred, &pred, &[], &opts).unwrap();
        assert!(m
            .group_recall
            .iter()
            .all(|g| g.points == 0 && g.recall == vec![None, None]));
        let bad = MeshMetricsOptions {
            object_groups: vec![ObjectGroup {
                thresholds: vec![0.0],
                ..group("lamp", vec![7])
            }],
            ..options()
        };
        assert!(mesh_metrics(&pred, &gt, &[], &bad).is_err());
    }

    #[test]
    fn empty_prediction_and_bad_views() {
        let gt = room();
        let m = mesh_metrics(&TriangleMesh::default(), &gt, &[], &options()).unwrap();
        assert_eq!(
            (m.recall, m.fscore, m.accuracy, m.precision),
            (Some(0.0), Some(0.0), None, None)
        );
        let mut view = room_views(&gt).remove(0);
        view.depth.pop();
        assert!(mesh_metrics(&gt, &gt, &[view], &options()).is_err());
    }
}
