//! Evaluating a trained run against its dataset (the paper's Sec. 6 and supp. Sec. D, as the README's `eval` row lists): the mesh of the neural
//! SDF, novel-view, depth and normal metrics on the test views, and mesh metrics against the
//! ground-truth mesh culled by the training views, per GT object and for the thin and suspended
//! objects where the dataset names its objects.

use crate::image_metrics::{depth_l1, normal_angular_l1, psnr, ssim, ImageRef};
use crate::lpips::{Lpips, MIN_SIDE};
use crate::mesh::TriangleMesh;
use crate::mesh_metrics::{mesh_metrics_with_progress, CullingView, MeshMetricsOptions, ObjectGroup};
use crate::progress::{self, EvalProgress, NoProgress};
use crate::report::{
    lpips_too_small_note, no_lpips_note, EvalReport, MeshReport, NovelViewMetrics, ObjectGroupReport, ViewSplitMetrics,
};
use i2sdf_data::dataset::ObjectInfo;
use i2sdf_data::ply::read_ground_truth;
use i2sdf_data::{Bounds, Camera, DataError, Dataset, Frame, Split};
use i2sdf_model::images::{render_volume_view, RenderedView};
use i2sdf_model::renderer::RenderSettings;
use i2sdf_model::{extract_mesh, NeuralScene};

/// The training views with GT depth, as the mesh metrics' visibility test wants them.
pub fn culling_views(dataset: &Dataset) -> Vec<CullingView> {
    dataset
        .split(Split::Train)
        .filter_map(|f| {
            let depth = f.depth.as_ref()?;
            Some(CullingView {
                camera: f.camera.clone(),
                depth: depth.data.clone(),
            })
        })
        .collect()
}

/// Marching-cubes resolution (samples along the scene box's longest side) of the mesh that `eval`
/// scores and `mesh` writes. Why 1024: the cells must be well under the thinnest objects and the
/// 2 cm recall threshold, or the extraction, not the SDF, decides what is found. On the default
/// room (4.8 m long, 5.3 m with the pad) 256 gives 2.1 cm cells, wider than the chandelier's
/// 1.2 cm arms: one trained SDF that holds the arms scored 0.22 recall at 2 cm at 256, 0.44 at 512
/// and 0.55 at 1024 (5 mm cells; measured with the 1 % pad `eval` had before its mesh took
/// [`i2sdf_model::sdf_mesh::PAD_FRACTION`]). The narrow band ([`i2sdf_model::marching_cubes::NarrowBand`]) makes 1024 affordable.
pub const MESH_RESOLUTION: usize = 1024;

/// Options of [`evaluate`].
pub struct EvalOptions {
    pub mesh_resolution: usize,
    pub mesh: MeshMetricsOptions,
    pub render: RenderSettings,
    /// The LPIPS metric for `novel_view.lpips` (`None`: null, with [`no_lpips_note`]).
    pub lpips: Option<std::sync::Arc<Lpips>>,
    /// Whose image metrics: the test views', the training views' or both.
    pub splits: ViewSplits,
    /// A mesh to score instead of extracting one at `mesh_resolution` (world units; `eval
    /// --mesh`).
    pub given_mesh: Option<TriangleMesh>,
}

/// Which views' image metrics an evaluation scores (`eval --split`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ViewSplits {
    /// The test views: `novel_view`, and the depth and normal errors.
    #[default]
    Test,
    /// The training views: `train_view` (how well the field fits what it was trained on).
    Train,
    /// Both.
    Both,
}

impl ViewSplits {
    /// `test`, `train` or `both`.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "test" => Some(ViewSplits::Test),
            "train" => Some(ViewSplits::Train),
            "both" => Some(ViewSplits::Both),
            _ => None,
        }
    }

    pub fn splits(self) -> &'static [Split] {
        match self {
            ViewSplits::Test => &[Split::Test],
            ViewSplits::Train => &[Split::Train],
            ViewSplits::Both => &[Split::Test, Split::Train],
        }
    }
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            mesh_resolution: MESH_RESOLUTION,
            mesh: MeshMetricsOptions::default(),
            render: RenderSettings::default(),
            lpips: None,
            splits: ViewSplits::Test,
            given_mesh: None,
        }
    }
}

fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// Novel-view metrics on the test views: PSNR and SSIM of the colour (and LPIPS with
/// [`view_metrics_with_progress`]); depth L1 (world units) and normal angular L1 where the test
/// views have GT depth and normals. Means over views.
pub fn view_metrics(
    scene: &NeuralScene,
    dataset: &Dataset,
    settings: &RenderSettings,
) -> Result<EvalReport, DataError> {
    view_metrics_with_progress(scene, dataset, settings, None, &[Split::Test], &NoProgress, None)
}

/// [`view_metrics`] of the views of `splits`, with LPIPS when `lpips` is given, reporting the
/// step "test views" (or "training views") to `progress`, counted in views. The test views fill
/// `novel_view` and `geometry`'s depth and normal errors, the training views `train_view` (the
/// paper's figures in brackets, Table 1). LPIPS stays null, with [`lpips_too_small_note`], when a
/// view is smaller than AlexNet takes ([`MIN_SIDE`]). With `test_images`, the radiance field's
/// view of each test view (its image, depth, normals, emitter probability) is kept there as it
/// was scored.
pub fn view_metrics_with_progress(
    scene: &NeuralScene,
    dataset: &Dataset,
    settings: &RenderSettings,
    lpips: Option<&Lpips>,
    splits: &[Split],
    progress: &dyn EvalProgress,
    mut test_images: Option<&mut Vec<(Camera, RenderedView)>>,
) -> Result<EvalReport, DataError> {
    let mut report = EvalReport::default();
    for &split in splits {
        let keep = if split == Split::Test {
            test_images.as_deref_mut()
        } else {
            None
        };
        let (views, too_small) = split_metrics(scene, dataset, split, settings, lpips, progress, keep)?;
        if let Some((w, h)) = too_small {
            let note = lpips_too_small_note(w, h);
            if !report.notes.contains(&note) {
                report.notes.push(note);
            }
        }
        match split {
            Split::Test => {
                report.novel_view = views.images;
                report.geometry.depth_l1 = views.depth_l1;
                report.geometry.normal_angular_l1 = views.normal_angular_l1;
            }
            Split::Train => report.train_view = Some(views),
        }
    }
    Ok(report)
}

/// The radiance field's images, depths and normals of `split`'s views against their ground truth,
/// and the size of a view too small for LPIPS (its figure is then null).
fn split_metrics(
    scene: &NeuralScene,
    dataset: &Dataset,
    split: Split,
    settings: &RenderSettings,
    lpips: Option<&Lpips>,
    progress: &dyn EvalProgress,
    mut keep: Option<&mut Vec<(Camera, RenderedView)>>,
) -> Result<(ViewSplitMetrics, Option<(usize, usize)>), DataError> {
    let (mut p, mut s, mut d, mut n) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut l, mut too_small) = (Vec::new(), None);
    let frames: Vec<&Frame> = dataset.split(split).collect();
    let step = match split {
        Split::Test => progress::TEST_VIEWS,
        Split::Train => progress::TRAIN_VIEWS,
    };
    progress.step(step, frames.len() as u64);
    for f in &frames {
        let v = render_volume_view(scene, settings, &f.camera);
        let (w, h) = (f.camera.width, f.camera.height);
        let pred = ImageRef::new(&v.rgb.data, w, h, 3)?;
        let gt = ImageRef::new(&f.rgb.data, w, h, 3)?;
        if let Some(x) = psnr(pred, gt, None)? {
            p.push(x.min(100.0));
        }
        if let Some(x) = ssim(pred, gt, None)? {
            s.push(x);
        }
        if let Some(lpips) = lpips {
            if w < MIN_SIDE || h < MIN_SIDE {
                too_small = Some((w, h));
            } else {
                l.push(lpips.distance(pred, gt)?);
            }
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
        if let Some(keep) = keep.as_deref_mut() {
            keep.push((f.camera.clone(), v));
        }
        progress.inc(1);
    }
    let metrics = ViewSplitMetrics {
        images: NovelViewMetrics {
            psnr: mean(&p),
            ssim: mean(&s),
            lpips: if too_small.is_some() { None } else { mean(&l) },
        },
        depth_l1: mean(&d),
        normal_angular_l1: mean(&n),
        views: frames.len(),
    };
    Ok((metrics, too_small))
}

/// Objects with any of these tags make up `geometry.thin_objects`.
pub const THIN_OBJECT_TAGS: [&str; 2] = ["thin", "suspended"];
/// Objects with this tag make up `geometry.small_objects` (scored at the thin objects'
/// thresholds).
pub const SMALL_OBJECT_TAGS: [&str; 1] = ["small"];
pub use crate::mesh_metrics::THIN_OBJECT_THRESHOLDS;

/// The recall of the object groups `eval` reports on their own: `geometry.thin_objects` and
/// `geometry.small_objects` (None: the dataset has no object of the group).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GroupReports {
    pub thin: Option<ObjectGroupReport>,
    pub small: Option<ObjectGroupReport>,
}

/// Mesh metrics of `pred` against `gt` (see [`crate::mesh_metrics::mesh_metrics`]), with the
/// per-object recall named and tagged from `objects`, and the recall of the objects tagged thin or
/// suspended and of those tagged small (each `None` when `objects` has none).
pub fn mesh_report(
    pred: &TriangleMesh,
    gt: &TriangleMesh,
    views: &[CullingView],
    objects: &[ObjectInfo],
    options: &MeshMetricsOptions,
) -> Result<(MeshReport, GroupReports), DataError> {
    mesh_report_with_progress(pred, gt, views, objects, options, &NoProgress)
}

/// [`mesh_report`], reporting the steps of [`mesh_metrics_with_progress`] to `progress`.
pub fn mesh_report_with_progress(
    pred: &TriangleMesh,
    gt: &TriangleMesh,
    views: &[CullingView],
    objects: &[ObjectInfo],
    options: &MeshMetricsOptions,
    progress: &dyn EvalProgress,
) -> Result<(MeshReport, GroupReports), DataError> {
    let tagged = |tags: &[&str]| -> Vec<&ObjectInfo> {
        objects
            .iter()
            .filter(|o| o.tags.iter().any(|t| tags.contains(&t.as_str())))
            .collect()
    };
    let groups = [
        ("thin_objects", tagged(&THIN_OBJECT_TAGS)),
        ("small_objects", tagged(&SMALL_OBJECT_TAGS)),
    ];
    let mut options = options.clone();
    let first_group = options.object_groups.len();
    for (name, members) in groups.iter().filter(|(_, m)| !m.is_empty()) {
        options.object_groups.push(ObjectGroup {
            name: (*name).into(),
            object_ids: members.iter().map(|o| o.id).collect(),
            thresholds: THIN_OBJECT_THRESHOLDS.to_vec(),
        });
    }
    let metrics = mesh_metrics_with_progress(pred, gt, views, &options, progress)?;
    let mut report = MeshReport::from(&metrics);
    report.join_objects(objects);
    let mut added = metrics.group_recall[first_group..].iter();
    let mut group = |members: &Vec<&ObjectInfo>| {
        (!members.is_empty()).then(|| {
            let recall = added.next().expect("one recall per group added");
            ObjectGroupReport::new(recall, members.iter().map(|o| o.name.clone()).collect())
        })
    };
    let reports = GroupReports {
        thin: group(&groups[0].1),
        small: group(&groups[1].1),
    };
    Ok((report, reports))
}

/// The whole evaluation of a run: view metrics, and mesh metrics when the dataset has a GT mesh.
/// Returns the report and the extracted mesh (None when `options.given_mesh` was scored).
pub fn evaluate(
    scene: &NeuralScene,
    dataset: &Dataset,
    bounds: &Bounds,
    options: &EvalOptions,
) -> Result<(EvalReport, Option<TriangleMesh>), DataError> {
    evaluate_with_progress(scene, dataset, bounds, options, &NoProgress)
}

/// [`evaluate`], reporting each step to `progress` as it starts and its work as it goes: "test
/// views", "mesh extraction", then with a GT mesh "sampling surfaces", "visibility culling" and
/// "nearest neighbours" (see [`EvalProgress`]).
pub fn evaluate_with_progress(
    scene: &NeuralScene,
    dataset: &Dataset,
    bounds: &Bounds,
    options: &EvalOptions,
    progress: &dyn EvalProgress,
) -> Result<(EvalReport, Option<TriangleMesh>), DataError> {
    evaluate_keeping_test_images(scene, dataset, bounds, options, progress, &mut Vec::new())
}

/// [`evaluate_with_progress`], keeping in `test_images` the radiance field's view of each test
/// camera as it was scored: the relit sets' differential composites start from the same images
/// ([`crate::relight::relight_metrics`]), and `eval --renders` writes them.
pub fn evaluate_keeping_test_images(
    scene: &NeuralScene,
    dataset: &Dataset,
    bounds: &Bounds,
    options: &EvalOptions,
    progress: &dyn EvalProgress,
    test_images: &mut Vec<(Camera, RenderedView)>,
) -> Result<(EvalReport, Option<TriangleMesh>), DataError> {
    // The GT first: a bad one is refused before the views are rendered.
    let gt = dataset.mesh_path.as_ref().map(read_ground_truth).transpose()?;
    // The mesh is extracted while the views are rendered, and the steps are reported as before
    // (the extraction's is then what is left of it). Why: each alone kept the two cores only
    // about 1.7 busy (their serial parts), and together they fill them. A given mesh is scored
    // where it is (the demo's is millions of faces), not copied.
    let (views, extracted) = rayon::join(
        || {
            view_metrics_with_progress(
                scene,
                dataset,
                &options.render,
                options.lpips.as_deref(),
                options.splits.splits(),
                progress,
                Some(test_images),
            )
        },
        || match &options.given_mesh {
            Some(_) => Ok(None),
            None => extract_mesh(scene, bounds, options.mesh_resolution).map(Some),
        },
    );
    let mut report = views?;
    if options.lpips.is_none() {
        report.notes.push(no_lpips_note());
    }
    progress.step(progress::MESH_EXTRACTION, 0);
    let extracted = extracted?;
    let mesh = options
        .given_mesh
        .as_ref()
        .or(extracted.as_ref())
        .expect("given or extracted");
    report.geometry.mesh = match gt {
        Some(gt) => {
            let views = culling_views(dataset);
            let (mesh_report, groups) =
                mesh_report_with_progress(mesh, &gt, &views, &dataset.objects, &options.mesh, progress)?;
            report.geometry.thin_objects = groups.thin;
            report.geometry.small_objects = groups.small;
            mesh_report
        }
        None => MeshReport {
            threshold: Some(options.mesh.threshold),
            ..Default::default()
        },
    };
    Ok((report, extracted))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::test_shapes::{box_mesh, concat};

    fn with_id(mut m: TriangleMesh, id: i32) -> TriangleMesh {
        m.face_object_ids = Some(vec![id; m.num_faces()]);
        m
    }

    fn info(id: i32, name: &str, tags: &[&str]) -> ObjectInfo {
        ObjectInfo {
            id,
            name: name.into(),
            tags: tags.iter().map(|t| t.to_string()).collect(),
        }
    }

    /// A room (object 0), a table (1), a 2 cm pole standing in the air 0.3 under the ceiling (7,
    /// clear of every other surface by more than 5 cm) and, when asked, a suspended globe (9).
    fn scene(pole: bool, globe: bool) -> TriangleMesh {
        let mut parts = vec![
            with_id(box_mesh([0.0; 3], [4.0, 3.0, 2.5]), 0),
            with_id(box_mesh([2.5, 0.5, 0.0], [3.5, 1.5, 0.7]), 1),
        ];
        if pole {
            parts.push(with_id(box_mesh([1.99, 1.49, 1.0], [2.01, 1.51, 2.2]), 7));
        }
        if globe {
            parts.push(with_id(box_mesh([0.9, 1.9, 1.6], [1.1, 2.1, 1.8]), 9));
        }
        concat(&parts)
    }

    fn options() -> MeshMetricsOptions {
        MeshMetricsOptions {
            num_points: 200_000,
            ..Default::default()
        }
    }

    #[test]
    fn a_missing_thin_object_shows_in_thin_recall_not_in_the_global_figure() {
        let gt = scene(true, true);
        let objects = [
            info(0, "room", &["room"]),
            info(1, "table", &["furniture"]),
            info(7, "pole", &["thin"]),
            info(9, "globe", &["suspended"]),
            info(12, "not_in_the_mesh", &["thin"]),
        ];
        // The prediction has the room, the table and the globe, but lost the pole.
        let pred = scene(false, true);
        let (report, groups) = mesh_report(&pred, &gt, &[], &objects, &options()).unwrap();
        assert!(report.recall.unwrap() > 0.99, "{:?}", report.recall);
        assert!(groups.small.is_none());
        let thin = groups.thin.expect("the dataset has thin objects");
        assert_eq!(thin.objects, ["pole", "globe", "not_in_the_mesh"]);
        // The globe (0.24 m²) is recalled, the pole (0.096 m²) is not: about 70 % recalled.
        let (r2, r5) = (thin.recall_2cm.unwrap(), thin.recall_5cm.unwrap());
        assert!(r5 > 0.55 && r5 < 0.8 && r2 <= r5, "{thin:?}");
        assert!(thin.points > 0);

        // Names and tags are joined onto the per-object recall.
        let per_object = report.per_object_recall.unwrap();
        let ids: Vec<i32> = per_object.iter().map(|r| r.object_id).collect();
        assert_eq!(ids, [0, 1, 7, 9]);
        assert_eq!(per_object[2].name.as_deref(), Some("pole"));
        assert_eq!(per_object[2].tags, ["thin"]);
        assert_eq!(per_object[2].recall, Some(0.0));
        assert_eq!(per_object[3].tags, ["suspended"]);

        // Only the pole missing from the thin group: recall 0 at both distances.
        let (_, groups) = mesh_report(&pred, &gt, &[], &objects[..3], &options()).unwrap();
        let thin = groups.thin.unwrap();
        assert_eq!((thin.recall_2cm, thin.recall_5cm), (Some(0.0), Some(0.0)));
        // The GT itself recovers everything.
        let (_, groups) = mesh_report(&gt, &gt, &[], &objects, &options()).unwrap();
        assert_eq!(groups.thin.unwrap().recall_2cm, Some(1.0));
    }

    #[test]
    fn small_objects_are_scored_apart_from_the_thin_ones() {
        let gt = scene(true, true);
        // The globe tagged small: its own group, recalled; the thin group is the lost pole.
        let objects = [
            info(0, "room", &["room"]),
            info(7, "pole", &["thin"]),
            info(9, "globe", &["small"]),
        ];
        let (_, groups) = mesh_report(&scene(false, true), &gt, &[], &objects, &options()).unwrap();
        let (thin, small) = (groups.thin.unwrap(), groups.small.unwrap());
        assert_eq!(
            (thin.objects.as_slice(), small.objects.as_slice()),
            (&["pole".to_string()][..], &["globe".to_string()][..])
        );
        assert_eq!((thin.recall_5cm, small.recall_2cm), (Some(0.0), Some(1.0)));
        // Without the globe in the prediction the small group's recall falls to 0.
        let (_, groups) = mesh_report(&scene(false, false), &gt, &[], &objects, &options()).unwrap();
        assert_eq!(groups.small.unwrap().recall_5cm, Some(0.0));
    }

    #[test]
    fn datasets_without_thin_objects_report_none() {
        let gt = scene(true, false);
        let (report, groups) = mesh_report(&gt, &gt, &[], &[info(0, "room", &["room"])], &options()).unwrap();
        assert!(groups.thin.is_none() && groups.small.is_none());
        let per_object = report.per_object_recall.unwrap();
        assert_eq!(per_object[0].name.as_deref(), Some("room"));
        assert!(per_object[1].name.is_none() && per_object[1].tags.is_empty());
        let (report, groups) = mesh_report(&gt, &gt, &[], &[], &options()).unwrap();
        assert!(groups == GroupReports::default() && report.fscore == Some(1.0));
    }

    /// An untrained scene of two small hash levels over `dataset`'s normalization.
    fn tiny_scene(dataset: &Dataset) -> NeuralScene {
        let config = i2sdf_model::ModelConfig {
            hash_levels: 2,
            hash_log2_table: 10,
            hash_finest_resolution: 16,
            ..Default::default()
        };
        NeuralScene::new(&config, dataset.normalization, 1)
    }

    /// Stand-in LPIPS weights (not the metric): smooth values of both signs, heads ≥ 0.
    fn stand_in_lpips() -> std::sync::Arc<Lpips> {
        let wave = |n: usize, f: f32, a: f32| (0..n).map(|i| a * (f * i as f32).sin()).collect::<Vec<f32>>();
        let specs = crate::lpips::ALEXNET;
        std::sync::Arc::new(Lpips::new(&crate::lpips::LpipsWeights {
            conv_weights: specs
                .iter()
                .map(|s| wave(s.out_channels * s.in_channels * s.kernel * s.kernel, 0.37, 0.05))
                .collect(),
            conv_biases: specs.iter().map(|s| wave(s.out_channels, 0.9, 0.1)).collect(),
            heads: specs.iter().map(|s| vec![0.01; s.out_channels]).collect(),
        }))
    }

    /// With weights and views of at least 31×31 LPIPS is filled and nothing is noted; with
    /// smaller views, or without weights, it is null and a note says why.
    #[test]
    fn lpips_is_filled_with_weights_or_noted_why_not() {
        let settings = RenderSettings::default();
        let lpips = stand_in_lpips();
        for (width, height) in [(40, 32), (24, 18)] {
            let dir = tempfile::tempdir().unwrap();
            let options = i2sdf_data::fixture::FixtureOptions {
                width,
                height,
                train_views: 1,
                test_views: 1,
                ..Default::default()
            };
            i2sdf_data::fixture::write_native(dir.path(), &options);
            let dataset = i2sdf_data::load(dir.path()).unwrap();
            let scene = tiny_scene(&dataset);
            let report = view_metrics_with_progress(
                &scene,
                &dataset,
                &settings,
                Some(&lpips),
                &[Split::Test],
                &NoProgress,
                None,
            )
            .unwrap();
            if width == 40 {
                let v = report.novel_view.lpips.expect("LPIPS with weights");
                assert!(v.is_finite() && v > 0.0, "{v}");
                assert!(report.notes.is_empty(), "{:?}", report.notes);
            } else {
                assert_eq!(report.novel_view.lpips, None);
                assert_eq!(report.notes, [crate::report::lpips_too_small_note(24, 18)]);
                assert!(report.notes[0].contains("24×18") && report.notes[0].contains("31×31"));
            }
            assert!(report.novel_view.psnr.is_some());
            let without = view_metrics(&scene, &dataset, &settings).unwrap();
            assert_eq!((without.novel_view.lpips, without.notes.len()), (None, 0));
        }
    }

    /// Records each step with its total and the units reported done.
    #[derive(Default)]
    struct Recorder(std::sync::Mutex<Vec<(String, u64, u64)>>);

    impl EvalProgress for Recorder {
        fn step(&self, name: &str, total: u64) {
            self.0.lock().unwrap().push((name.to_string(), total, 0));
        }
        fn inc(&self, n: u64) {
            self.0.lock().unwrap().last_mut().expect("inc inside a step").2 += n;
        }
    }

    /// The fixture dataset with a GT mesh (a box around its bounds) and a tiny untrained scene:
    /// every step is named in order, and each counted step reports exactly its total.
    #[test]
    fn evaluate_reports_each_step_with_its_count() {
        let dir = tempfile::tempdir().unwrap();
        i2sdf_data::fixture::write_native(dir.path(), &i2sdf_data::fixture::FixtureOptions::default());
        let mut dataset = i2sdf_data::load(dir.path()).unwrap();
        let gt_path = dir.path().join("gt.ply");
        let b = dataset.bounds;
        crate::write_ply(&gt_path, &box_mesh(b.min.map(|x| x as f32), b.max.map(|x| x as f32))).unwrap();
        dataset.mesh_path = Some(gt_path);
        let scene = tiny_scene(&dataset);
        let options = EvalOptions {
            mesh_resolution: 16,
            mesh: MeshMetricsOptions {
                num_points: 40_000,
                ..Default::default()
            },
            ..Default::default()
        };
        let progress = Recorder::default();
        let (report, _) = evaluate_with_progress(&scene, &dataset, &dataset.bounds, &options, &progress).unwrap();
        assert!(report.geometry.mesh.threshold.is_some());
        assert_eq!(report.notes, [no_lpips_note()], "no LPIPS weights were given");
        let steps = progress.0.into_inner().unwrap();
        let names: Vec<&str> = steps.iter().map(|s| s.0.as_str()).collect();
        assert_eq!(
            names,
            [
                "test views",
                "mesh extraction",
                "sampling surfaces",
                "visibility culling",
                "nearest neighbours"
            ]
        );
        for (name, total, done) in &steps {
            assert_eq!(done, total, "{name}");
        }
        assert_eq!(steps[0].1, 2, "two test views");
        assert_eq!(steps[2].1, 80_000, "points on both meshes");

        // A given mesh is scored instead of an extracted one: the run's own mesh scores the
        // same, the GT box itself perfectly; the test views' images are kept as scored.
        let (mesh, images) = {
            let mut images = Vec::new();
            let (_, mesh) =
                evaluate_keeping_test_images(&scene, &dataset, &dataset.bounds, &options, &NoProgress, &mut images)
                    .unwrap();
            (mesh.expect("extracted"), images)
        };
        assert_eq!(images.len(), 2);
        let given = EvalOptions {
            given_mesh: Some(mesh),
            ..options
        };
        let (same, _) = evaluate(&scene, &dataset, &dataset.bounds, &given).unwrap();
        assert_eq!(same.geometry.mesh, report.geometry.mesh);
        let gt_box = EvalOptions {
            given_mesh: Some(box_mesh(b.min.map(|x| x as f32), b.max.map(|x| x as f32))),
            ..given
        };
        let (perfect, _) = evaluate(&scene, &dataset, &dataset.bounds, &gt_box).unwrap();
        assert_eq!(perfect.geometry.mesh.fscore, Some(1.0));
    }

    /// `--split`: the test views fill `novel_view` and the geometry's depth and normal errors,
    /// the training views `train_view` (each counted), both fill both with the same figures as
    /// alone; and the training views, which the figures come from, are rendered.
    #[test]
    fn each_split_fills_its_own_figures() {
        let dir = tempfile::tempdir().unwrap();
        let fixture = i2sdf_data::fixture::FixtureOptions::default();
        i2sdf_data::fixture::write_native(dir.path(), &fixture);
        let dataset = i2sdf_data::load(dir.path()).unwrap();
        let scene = tiny_scene(&dataset);
        let settings = RenderSettings::default();
        let run = |splits: ViewSplits| {
            let progress = Recorder::default();
            let r = view_metrics_with_progress(&scene, &dataset, &settings, None, splits.splits(), &progress, None)
                .unwrap();
            (r, progress.0.into_inner().unwrap())
        };
        let (test, steps) = run(ViewSplits::Test);
        assert!(test.novel_view.psnr.is_some() && test.geometry.depth_l1.is_some() && test.train_view.is_none());
        assert_eq!(
            steps,
            [(
                "test views".to_string(),
                fixture.test_views as u64,
                fixture.test_views as u64
            )]
        );
        let (train, steps) = run(ViewSplits::Train);
        let t = train.train_view.clone().expect("train_view");
        assert!(train.novel_view.psnr.is_none() && train.geometry.depth_l1.is_none());
        assert_eq!(t.views, fixture.train_views);
        assert!(
            t.images.psnr.is_some() && t.images.ssim.is_some() && t.depth_l1.is_some() && t.normal_angular_l1.is_some()
        );
        assert_eq!(steps[0].0, "training views");
        assert_eq!(steps[0].1, fixture.train_views as u64);
        let (both, _) = run(ViewSplits::Both);
        assert_eq!(both.novel_view, test.novel_view);
        assert_eq!(both.train_view, train.train_view);
        assert_ne!(t.images.psnr, test.novel_view.psnr, "other views, other figures");
        assert_eq!(ViewSplits::parse("val"), None);
    }
}
