//! Evaluating a trained run against its dataset (DESIGN.md "Evaluation"): the mesh of the neural
//! SDF, novel-view, depth and normal metrics on the test views, and mesh metrics against the
//! ground-truth mesh culled by the training views.

use crate::image_metrics::{depth_l1, normal_angular_l1, psnr, ssim, ImageRef};
use crate::marching_cubes::{marching_cubes, McGrid, McOptions};
use crate::mesh::TriangleMesh;
use crate::mesh_metrics::{mesh_metrics, CullingView, MeshMetricsOptions};
use crate::ply::read_ply;
use crate::report::{EvalReport, MeshReport};
use i2sdf_data::{Bounds, DataError, Dataset, Frame, Split};
use i2sdf_model::images::render_view;
use i2sdf_model::renderer::RenderSettings;
use i2sdf_model::{NeuralScene, SceneQuery};

/// Marching cubes over the scene's SDF inside `bounds` (world units, enlarged by 2 %), with
/// `resolution` samples along the longest side; vertices in world units.
pub fn extract_mesh(scene: &NeuralScene, bounds: &Bounds, resolution: usize) -> Result<TriangleMesh, DataError> {
    let norm = &scene.normalization;
    let lo = norm.to_normalized(bounds.min.into());
    let hi = norm.to_normalized(bounds.max.into());
    let pad = (hi - lo) * 0.01;
    let (lo, hi) = (lo - pad, hi + pad);
    let grid = McGrid::cubic(
        [lo.x as f32, lo.y as f32, lo.z as f32],
        [hi.x as f32, hi.y as f32, hi.z as f32],
        resolution,
    )?;
    let mut query = SceneQuery::new(scene);
    let mut flat = Vec::new();
    let mut mesh = marching_cubes(&grid, &McOptions::default(), |pts, out| {
        flat.clear();
        flat.extend(pts.iter().flatten());
        query.sdf(&flat, out);
    })?;
    for p in &mut mesh.positions {
        let w = norm.to_world(glam::DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64));
        *p = [w.x as f32, w.y as f32, w.z as f32];
    }
    Ok(mesh)
}

/// The training views with GT depth, as the mesh metrics' visibility test wants them.
pub fn culling_views(dataset: &Dataset) -> Vec<CullingView> {
    dataset
        .split(Split::Train)
        .filter_map(|f| {
            let depth = f.depth.as_ref()?;
            let c = &f.camera;
            let m = c.c2w;
            let cam_to_world = std::array::from_fn(|r| std::array::from_fn(|col| m.col(col)[r] as f32));
            Some(CullingView {
                fx: c.fx as f32,
                fy: c.fy as f32,
                cx: c.cx as f32,
                cy: c.cy as f32,
                width: c.width,
                height: c.height,
                cam_to_world,
                depth: depth.data.clone(),
            })
        })
        .collect()
}

/// Options of [`evaluate`].
pub struct EvalOptions {
    pub mesh_resolution: usize,
    pub mesh: MeshMetricsOptions,
    pub render: RenderSettings,
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            mesh_resolution: 256,
            mesh: MeshMetricsOptions::default(),
            render: RenderSettings::default(),
        }
    }
}

fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// Novel-view metrics on the test views: PSNR and SSIM of the colour; depth L1 (world units) and
/// normal angular L1 where the test views have GT depth and normals. Means over views.
pub fn view_metrics(
    scene: &NeuralScene,
    dataset: &Dataset,
    settings: &RenderSettings,
) -> Result<EvalReport, DataError> {
    let mut report = EvalReport::default();
    let (mut p, mut s, mut d, mut n) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let test: Vec<&Frame> = dataset.split(Split::Test).collect();
    for f in test {
        let v = render_view(scene, settings, &f.camera);
        let (w, h) = (f.camera.width, f.camera.height);
        let pred = ImageRef::new(&v.rgb.data, w, h, 3)?;
        let gt = ImageRef::new(&f.rgb.data, w, h, 3)?;
        if let Some(x) = psnr(pred, gt, None)? {
            p.push(x.min(100.0));
        }
        if let Some(x) = ssim(pred, gt, None)? {
            s.push(x);
        }
        if let Some(gd) = &f.depth {
            if let Some(x) = depth_l1(&v.depth.data, &gd.data, None)? {
                d.push(x);
            }
        }
        if let Some(gn) = &f.normal {
            if let Some(x) = normal_angular_l1(&v.normal.data, &gn.data, None)? {
                n.push(x);
            }
        }
    }
    report.novel_view.psnr = mean(&p);
    report.novel_view.ssim = mean(&s);
    report.geometry.depth_l1 = mean(&d);
    report.geometry.normal_angular_l1 = mean(&n);
    Ok(report)
}

/// The whole evaluation of a run: view metrics, and mesh metrics when the dataset has a GT mesh.
/// Returns the report and the extracted mesh.
pub fn evaluate(
    scene: &NeuralScene,
    dataset: &Dataset,
    bounds: &Bounds,
    options: &EvalOptions,
) -> Result<(EvalReport, TriangleMesh), DataError> {
    let mut report = view_metrics(scene, dataset, &options.render)?;
    let mesh = extract_mesh(scene, bounds, options.mesh_resolution)?;
    report.geometry.mesh = match &dataset.mesh_path {
        Some(gt_path) => {
            let gt = read_ply(gt_path)?;
            let m = mesh_metrics(&mesh, &gt, &culling_views(dataset), &options.mesh)?;
            MeshReport::from(&m)
        }
        None => MeshReport {
            threshold: Some(options.mesh.threshold),
            ..Default::default()
        },
    };
    Ok((report, mesh))
}
