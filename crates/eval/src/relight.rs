//! Relighting evaluation: each of the dataset's `relight` sets rendered with its edit spec by the
//! edit renderer (path tracing the recovered scene, emitters × the spec's gains) and compared,
//! tone-mapped as the dataset's images, with its ground-truth images. Also what doing nothing
//! scores (the unedited render against the relit truth), and the unedited render against the
//! test images of the same cameras.
//!
//! Sets whose specs only relight share one render per camera: relighting is exact from the
//! per-emitter radiance slots, so only the gains differ. With `volume` set, each set is also
//! scored by differential rendering ([`i2sdf_edit::differential`]): stage 1's radiance field of
//! the camera + the path-traced change, and by its ratio form (the radiance field × the
//! path-traced ratio), from the same renders (and, for a set that edits more than lights, the
//! unedited render of the same paths).
//!
//! Each camera's paths are drawn with a view index fixed by the dataset alone (the order in which
//! the relit sets first show the camera), so a frame's images do not depend on which other
//! frames are rendered: the report, which renders only the first frame of each set through
//! [`score_relit_sets`], shows the images and figures that `eval` scored.

use crate::image_metrics::{psnr, ssim, ImageRef};
use crate::report::{ImagePair, RelightFrameMetrics, RelightMetrics, RelightSetMetrics, RelightSettings};
use glam::Vec3;
use i2sdf_data::edit_spec::{EditOp, EditSpec};
use i2sdf_data::{Camera, DataError, Dataset, EditAssets, Frame, ImageF32, RelightSet, Split};
use i2sdf_edit::{
    composite_hdr, edit_images, hdr_ldr_images, light_gains, Composite, EditSettings, EditedScene, RecoveredScene,
};
use i2sdf_model::renderer::RenderSettings;
use i2sdf_model::OpenedRun;
use i2sdf_render::ViewRender;
use std::collections::{BTreeMap, HashMap, HashSet};

#[derive(Clone, Debug)]
pub struct RelightOptions {
    pub render: EditSettings,
    /// Marching-cubes resolution of the recovered surface.
    pub mesh_resolution: usize,
    /// Also score each set by differential rendering (the run's radiance field with its own
    /// render settings).
    pub differential: bool,
}

impl Default for RelightOptions {
    fn default() -> Self {
        RelightOptions {
            render: EditSettings::default(),
            mesh_resolution: i2sdf_edit::MESH_RESOLUTION,
            differential: false,
        }
    }
}

/// Frames to render: every relit frame (None when the dataset has no relit sets).
pub fn relight_frames(dataset: &Dataset) -> usize {
    dataset.relight.iter().map(|s| s.frames.len()).sum()
}

/// True when `spec` only relights: its frames are the unedited render with gains.
fn relights_only(spec: &EditSpec) -> bool {
    spec.ops.iter().all(|op| matches!(op, EditOp::Relight(_)))
}

/// The rows [`relight_metrics`] path traces (its `on_row` calls, for a progress bar's total):
/// [`rendered_rows`] of the sets' specs.
pub fn relight_rows(dataset: &Dataset, differential: bool) -> Result<usize, DataError> {
    Ok(rendered_rows(&dataset.relight, &read_specs(dataset)?, differential))
}

/// The rows the relit sets' frames cost: one unedited render per camera, shared by the sets that
/// only relight (and, with `differential`, the base of every set's composites), and one render of
/// its own for each frame of a set that edits more than light (what [`RelightEval::score_set`]
/// and [`edited_view`] render). Counting every frame instead made eval's bar stop at a quarter on
/// the built-in rooms, whose four sets share their cameras.
fn rendered_rows(sets: &[RelightSet], specs: &[(EditSpec, EditAssets)], differential: bool) -> usize {
    let mut cameras = HashSet::new();
    let mut rows = 0;
    for (set, (spec, _)) in sets.iter().zip(specs) {
        let relight_only = relights_only(spec);
        for f in &set.frames {
            if (relight_only || differential) && cameras.insert(camera_key(f)) {
                rows += f.camera.height;
            }
            if !relight_only {
                rows += f.camera.height;
            }
        }
    }
    rows
}

/// A camera's identity for sharing renders between sets (exact pose and intrinsics).
fn camera_key(f: &Frame) -> Vec<u64> {
    f.camera.key()
}

fn scores_of(pred: &ImageF32, gt: &ImageF32) -> Result<(Option<f64>, Option<f64>), DataError> {
    let (w, h) = (pred.width, pred.height);
    let p = ImageRef::new(&pred.data, w, h, 3)?;
    let g = ImageRef::new(&gt.data, w, h, 3)?;
    Ok((psnr(p, g, None)?.map(|x| x.min(100.0)), ssim(p, g, None)?))
}

fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// A set's name in the report: its spec's file stem (`set{index}` without one).
pub fn set_name(set: &RelightSet, index: usize) -> String {
    set.spec
        .file_stem()
        .map_or_else(|| format!("set{index}"), |s| s.to_string_lossy().into_owned())
}

/// Every set's spec and assets, read before any (long) rendering starts.
pub fn read_specs(dataset: &Dataset) -> Result<Vec<(EditSpec, EditAssets)>, DataError> {
    dataset
        .relight
        .iter()
        .map(|set| {
            let spec = EditSpec::read(&set.spec)?;
            let assets = spec.load_assets()?;
            Ok((spec, assets))
        })
        .collect()
}

/// The relight section of the report; all null without relit sets. `captured` may hold the
/// radiance field's images of some cameras rendered with the run's render settings (eval's test
/// views), which the differential composites then use instead of rendering them again. `on_row`
/// is called after each rendered row. `prepared`: the recovered scene the sets are traced in,
/// built by the caller (`RecoveredScene::of_run` at `options.mesh_resolution`) beside other
/// work; None builds it here when there is something to render.
///
/// Without emitters (stage 2 found none) nothing is rendered and every figure is null, each set
/// listed with its frame count only: the edit renderer's light comes from the recovered emitters
/// (and any light a spec inserts), so every relit image would be black, and its differential
/// composite the radiance field's image unchanged; scoring those would report numbers that say
/// nothing about relighting. The report says why with
/// [`crate::report::EvalReport::note_no_emitters`].
pub fn relight_metrics<'a>(
    run: &'a OpenedRun,
    dataset: &Dataset,
    options: &RelightOptions,
    prepared: Option<RecoveredScene<'a>>,
    captured: &[(Camera, ImageF32)],
    on_row: &(dyn Fn() + Sync),
) -> Result<RelightMetrics, DataError> {
    if dataset.relight.is_empty() {
        return Ok(RelightMetrics::default());
    }
    if run.stage2()?.emitters.is_empty() {
        return Ok(frame_counts_only(dataset));
    }
    let specs = read_specs(dataset)?;
    let recovered = match prepared {
        Some(r) => r,
        None => RecoveredScene::of_run(run, dataset, options.mesh_resolution)?,
    };
    let scoring = RelitScoring {
        recovered: &recovered,
        volume: options.differential.then_some(&run.config.render),
        settings: &options.render,
        frames_per_set: None,
    };
    let mut renders = SharedRenders::default();
    for (camera, image) in captured {
        renders.insert_captured(camera, image.clone());
    }
    let mut metrics = score_relit_sets(&scoring, dataset, &specs, &mut renders, on_row, &mut |_| {})?;
    metrics.settings = Some(RelightSettings {
        spp: options.render.spp,
        bounces: options.render.bounces,
        seed: options.render.seed,
        mesh_resolution: options.mesh_resolution,
        denoised: options.render.denoise.is_some(),
    });
    Ok(metrics)
}

/// How relit frames are rendered and which are: the recovered scene, the radiance field's
/// settings for differential rendering (None: path traced only), the path tracer's settings,
/// and how many frames of each set (None: all).
pub struct RelitScoring<'r, 'a> {
    pub recovered: &'r RecoveredScene<'a>,
    pub volume: Option<&'r RenderSettings>,
    pub settings: &'r EditSettings,
    pub frames_per_set: Option<usize>,
}

/// One scored relit frame, as it is scored: the path-traced image, the differential and ratio
/// composites (with `volume`), the ground truth and the figures.
pub struct RelitFrame<'f> {
    pub set: usize,
    pub frame: &'f Frame,
    pub traced: &'f ImageF32,
    pub differential: Option<&'f ImageF32>,
    pub ratio: Option<&'f ImageF32>,
    pub figures: &'f RelightFrameMetrics,
}

/// Renders and scores the frames `scoring` selects of every relit set (`specs` from
/// [`read_specs`]), calling `on_frame` with each frame's images. `renders` may already hold
/// renders of some cameras (and keeps those made here, for the caller's other views).
pub fn score_relit_sets(
    scoring: &RelitScoring,
    dataset: &Dataset,
    specs: &[(EditSpec, EditAssets)],
    renders: &mut SharedRenders,
    on_row: &(dyn Fn() + Sync),
    on_frame: &mut dyn FnMut(RelitFrame),
) -> Result<RelightMetrics, DataError> {
    let mut views = HashMap::new();
    for f in dataset.relight.iter().flat_map(|s| &s.frames) {
        let next = views.len() as u32;
        views.entry(camera_key(f)).or_insert(next);
    }
    let mut eval = RelightEval {
        scoring,
        unedited_scene: scoring.recovered.edited(&EditSpec::default(), &Default::default()),
        on_row,
        tests: dataset.split(Split::Test).map(|f| (camera_key(f), f)).collect(),
        views,
        renders,
    };
    let mut baseline = Baseline::default();
    let mut all = SetScores::default();
    let mut sets = BTreeMap::new();
    for (i, (set, (spec, assets))) in dataset.relight.iter().zip(specs).enumerate() {
        let scores = eval.score_set(i, set, spec, assets, &mut baseline, on_frame)?;
        all.relit.extend(&scores.relit);
        all.differential.extend(&scores.differential);
        all.ratio.extend(&scores.ratio);
        sets.insert(set_name(set, i), scores.metrics(set.frames.len()));
    }
    Ok(RelightMetrics {
        psnr: mean(&all.relit.psnr),
        ssim: mean(&all.relit.ssim),
        sets: Some(sets),
        unedited: (!baseline.scores.psnr.is_empty()).then(|| ImagePair {
            psnr: mean(&baseline.scores.psnr),
            ssim: mean(&baseline.scores.ssim),
            frames: baseline.scores.psnr.len(),
        }),
        psnr_differential: mean(&all.differential.psnr),
        ssim_differential: mean(&all.differential.ssim),
        psnr_ratio: mean(&all.ratio.psnr),
        ssim_ratio: mean(&all.ratio.ssim),
        settings: None,
    })
}

/// The metrics without emitters: every set with its frame count and null figures.
fn frame_counts_only(dataset: &Dataset) -> RelightMetrics {
    let sets = dataset.relight.iter().enumerate().map(|(i, set)| {
        let frames = set.frames.len();
        (
            set_name(set, i),
            RelightSetMetrics {
                frames,
                ..Default::default()
            },
        )
    });
    RelightMetrics {
        sets: Some(sets.collect()),
        ..Default::default()
    }
}

/// PSNR and SSIM of the frames scored so far (a frame without a figure adds none).
#[derive(Default)]
struct Scores {
    psnr: Vec<f64>,
    ssim: Vec<f64>,
}

impl Scores {
    fn push(&mut self, (psnr, ssim): (Option<f64>, Option<f64>)) {
        self.psnr.extend(psnr);
        self.ssim.extend(ssim);
    }

    fn extend(&mut self, other: &Scores) {
        self.psnr.extend(&other.psnr);
        self.ssim.extend(&other.ssim);
    }
}

/// A set's scores: its relit images, the unedited render against the same truth (what doing
/// nothing scores, relight-only sets), the differential and ratio composites (with `volume`), and
/// each frame's figures.
#[derive(Default)]
struct SetScores {
    relit: Scores,
    unedited: Scores,
    differential: Scores,
    ratio: Scores,
    per_frame: Vec<RelightFrameMetrics>,
}

impl SetScores {
    fn metrics(&self, frames: usize) -> RelightSetMetrics {
        RelightSetMetrics {
            psnr: mean(&self.relit.psnr),
            ssim: mean(&self.relit.ssim),
            psnr_unedited: mean(&self.unedited.psnr),
            ssim_unedited: mean(&self.unedited.ssim),
            psnr_differential: mean(&self.differential.psnr),
            ssim_differential: mean(&self.differential.ssim),
            psnr_ratio: mean(&self.ratio.psnr),
            ssim_ratio: mean(&self.ratio.ssim),
            frames,
            per_frame: self.per_frame.clone(),
        }
    }
}

/// The unedited render against the test images of the same cameras, each test camera once.
#[derive(Default)]
struct Baseline {
    scores: Scores,
    seen: HashSet<Vec<u64>>,
}

/// Renders of the recovered scene kept per camera (by [`Camera::key`]): the unedited scene's
/// path-traced render with the view index its paths were drawn with (what relight-only sets
/// share, and the differential's base), and the radiance field's image (the differential's
/// captured image). A caller can share them with its own views of the same cameras.
#[derive(Default)]
pub struct SharedRenders {
    unedited: HashMap<Vec<u64>, (ViewRender, u32)>,
    captured: HashMap<Vec<u64>, ImageF32>,
}

impl SharedRenders {
    /// The unedited render of `camera` and its view index; rendered on `view` when there is
    /// none yet.
    pub fn unedited(
        &mut self,
        recovered: &RecoveredScene,
        unedited: &EditedScene,
        camera: &Camera,
        settings: &EditSettings,
        view: u32,
        on_row: &(dyn Fn() + Sync),
    ) -> (&ViewRender, u32) {
        let (r, v) = self
            .unedited
            .entry(camera.key())
            .or_insert_with(|| (recovered.render(unedited, camera, settings, view, on_row), view));
        (r, *v)
    }

    /// The radiance field's image of `camera`, rendered with `volume` when there is none yet.
    pub fn captured(&mut self, recovered: &RecoveredScene, camera: &Camera, volume: &RenderSettings) -> &ImageF32 {
        self.captured
            .entry(camera.key())
            .or_insert_with(|| recovered.captured(camera, volume))
    }

    /// Keeps `image` as the radiance field's image of `camera` (rendered elsewhere with the
    /// same settings).
    pub fn insert_captured(&mut self, camera: &Camera, image: ImageF32) {
        self.captured.insert(camera.key(), image);
    }
}

/// An edited view: the render of the edited scene (None: the unedited render serves, the spec
/// only relights) and the images it gives.
pub struct EditedView {
    pub render: Option<ViewRender>,
    /// Path traced, in the dataset's tone map.
    pub traced: ImageF32,
    /// Stage 1's radiance field + the path-traced change (with a `volume`).
    pub differential: Option<ImageF32>,
    /// Stage 1's radiance field × the path-traced ratio (with a `volume`).
    pub ratio: Option<ImageF32>,
}

/// `camera` seen with an edit: `edited` (None when the spec only relights: the unedited render
/// with `gains` is exact) path traced, and with `scoring.volume` its differential composite.
/// The unedited render is made on `view` when `renders` has none and it is needed (relighting,
/// or the differential's base); the edited scene is rendered on the unedited render's paths when
/// there is one, so their difference carries no noise of its own.
#[allow(clippy::too_many_arguments)]
pub fn edited_view(
    scoring: &RelitScoring,
    unedited: &EditedScene,
    edited: Option<&EditedScene>,
    gains: &[Vec3],
    renders: &mut SharedRenders,
    camera: &Camera,
    view: u32,
    on_row: &(dyn Fn() + Sync),
) -> EditedView {
    let r = scoring.recovered;
    let rm = &r.radiometry;
    let base_view = (edited.is_none() || scoring.volume.is_some())
        .then(|| renders.unedited(r, unedited, camera, scoring.settings, view, on_row).1);
    let own = edited.map(|ed| r.render(ed, camera, scoring.settings, base_view.unwrap_or(view), on_row));
    if let Some(volume) = scoring.volume {
        renders.captured(r, camera, volume);
    }
    let key = camera.key();
    let base = renders.unedited.get(&key).map(|(b, _)| b);
    let render = own.as_ref().or(base).expect("a render of the edited scene");
    let (_, traced) = edit_images(render, gains, rm);
    let (differential, ratio) = match (scoring.volume, base) {
        (Some(_), Some(base)) => {
            let captured = &renders.captured[&key];
            let form = |kind| {
                let hdr = composite_hdr(kind, captured, render, gains, base, rm);
                hdr_ldr_images(&hdr, render.width, render.height, rm).1
            };
            (Some(form(Composite::Differential)), Some(form(Composite::Ratio)))
        }
        _ => (None, None),
    };
    EditedView {
        render: own,
        traced,
        differential,
        ratio,
    }
}

/// What the sets of one evaluation share: how they are rendered, the unedited scene, the test
/// frames by camera, each camera's view index, and the per-camera renders.
struct RelightEval<'s, 'r, 'a> {
    scoring: &'s RelitScoring<'r, 'a>,
    unedited_scene: EditedScene,
    on_row: &'s (dyn Fn() + Sync),
    tests: HashMap<Vec<u64>, &'s Frame>,
    views: HashMap<Vec<u64>, u32>,
    renders: &'s mut SharedRenders,
}

impl RelightEval<'_, '_, '_> {
    /// Renders and scores the selected frames of `set` (number `index`) with its edit. A spec
    /// that only relights reuses the camera's unedited render with its gains (and scores the
    /// unedited image too, feeding `baseline`); any other spec renders its edited scene.
    fn score_set(
        &mut self,
        index: usize,
        set: &RelightSet,
        spec: &EditSpec,
        assets: &EditAssets,
        baseline: &mut Baseline,
        on_frame: &mut dyn FnMut(RelitFrame),
    ) -> Result<SetScores, DataError> {
        let relight_only = relights_only(spec);
        let own = (!relight_only).then(|| self.scoring.recovered.edited(spec, assets));
        let gains = light_gains(spec, own.as_ref().unwrap_or(&self.unedited_scene));
        let rm = &self.scoring.recovered.radiometry;
        let mut scores = SetScores::default();
        let frames = self.scoring.frames_per_set.unwrap_or(usize::MAX);
        for f in set.frames.iter().take(frames) {
            let key = camera_key(f);
            let view = edited_view(
                self.scoring,
                &self.unedited_scene,
                own.as_ref(),
                &gains,
                self.renders,
                &f.camera,
                self.views[&key],
                self.on_row,
            );
            let relit = scores_of(&view.traced, &f.rgb)?;
            scores.relit.push(relit);
            let mut figures = RelightFrameMetrics {
                name: f.name.clone(),
                psnr: relit.0,
                psnr_differential: None,
                psnr_ratio: None,
            };
            if let Some(d) = &view.differential {
                let s = scores_of(d, &f.rgb)?;
                scores.differential.push(s);
                figures.psnr_differential = s.0;
            }
            if let Some(r) = &view.ratio {
                let s = scores_of(r, &f.rgb)?;
                scores.ratio.push(s);
                figures.psnr_ratio = s.0;
            }
            if relight_only {
                let (base, _) = &self.renders.unedited[&key];
                let (_, plain) = edit_images(base, &vec![Vec3::ONE; gains.len()], rm);
                scores.unedited.push(scores_of(&plain, &f.rgb)?);
                if let Some(t) = self.tests.get(&key) {
                    if baseline.seen.insert(key) {
                        baseline.scores.push(scores_of(&plain, &t.rgb)?);
                    }
                }
            }
            on_frame(RelitFrame {
                set: index,
                frame: f,
                traced: &view.traced,
                differential: view.differential.as_ref(),
                ratio: view.ratio.as_ref(),
                figures: &figures,
            });
            scores.per_frame.push(figures);
        }
        Ok(scores)
    }
}
#[cfg(test)]
mod tests {
    use super::*;
    use i2sdf_data::Radiometry;
    use i2sdf_model::intrinsic_io::IntrinsicFields;
    use i2sdf_model::material_field::{MaterialConfig, MaterialField};
    use i2sdf_model::{EmitterTable, InferenceConfig, ModelConfig, NeuralScene};

    /// Sets that only relight share one render per camera; a set that edits more renders each
    /// frame again, and without composites its cameras need no unedited render of their own.
    #[test]
    fn rows_count_each_render_once() {
        let dir = tempfile::tempdir().unwrap();
        i2sdf_data::fixture::write_native(dir.path(), &i2sdf_data::fixture::FixtureOptions::default());
        let dataset = i2sdf_data::load(dir.path()).unwrap();
        let frames: Vec<Frame> = dataset.split(Split::Test).cloned().collect();
        let other: Vec<Frame> = dataset.split(Split::Train).take(1).cloned().collect();
        let h = frames[0].camera.height;
        assert!(frames.len() == 2 && frames.iter().chain(&other).all(|f| f.camera.height == h));
        let set = |frames: &[Frame]| RelightSet {
            spec: dir.path().join("unused.toml"),
            frames: frames.to_vec(),
        };
        let relight = EditSpec {
            ops: vec![EditOp::Relight(i2sdf_data::edit_spec::RelightOp {
                at: [0.0; 3],
                scale: 2.0,
                color: [1.0; 3],
            })],
        };
        let spec = |s: &EditSpec| (s.clone(), EditAssets::default());
        let sets = [set(&frames), set(&frames), set(&other)];
        let specs = [spec(&relight), spec(&relight), spec(&relight)];
        assert_eq!(
            rendered_rows(&sets, &specs, true),
            3 * h,
            "two cameras shared, one more"
        );
        let insert = EditSpec::from_toml_str(
            "[[op]]\nkind = \"insert\"\nsphere = { centre = [0.0, 0.0, 0.0], radius = 0.1 }\n",
            std::path::Path::new("insert.toml"),
        )
        .unwrap();
        let specs = [spec(&relight), spec(&insert), spec(&insert)];
        assert_eq!(rendered_rows(&sets, &specs, true), (3 + 2 + 1) * h);
        assert_eq!(rendered_rows(&sets, &specs, false), (2 + 2 + 1) * h);
    }

    /// Without emitters nothing is rendered (the spec is not even read: it does not exist) and
    /// every figure is null, each set keeping its frame count.
    #[test]
    fn no_emitters_give_null_figures_without_rendering() {
        let dir = tempfile::tempdir().unwrap();
        i2sdf_data::fixture::write_native(dir.path(), &i2sdf_data::fixture::FixtureOptions::default());
        let mut dataset = i2sdf_data::load(dir.path()).unwrap();
        let frames: Vec<Frame> = dataset.split(Split::Test).cloned().collect();
        dataset.relight.push(RelightSet {
            spec: dir.path().join("relight/lamp_dim.toml"),
            frames,
        });
        let config = ModelConfig {
            hash_levels: 2,
            hash_log2_table: 10,
            hash_finest_resolution: 16,
            ..Default::default()
        };
        let scene = NeuralScene::new(&config, dataset.normalization, 1);
        let material = MaterialConfig {
            hash_levels: 2,
            hash_log2_table: 10,
            hash_finest_resolution: 16,
            ..Default::default()
        };
        let fields = IntrinsicFields {
            material: MaterialField::new(&material, scene.feature_dim(), 3),
            emitters: EmitterTable::new(Vec::new(), &[]),
            radiometry: Radiometry::default(),
        };
        let run = OpenedRun {
            dir: i2sdf_model::RunDir::new(dir.path()),
            info: Default::default(),
            scene,
            fields: Some(fields),
            config: InferenceConfig {
                render: Default::default(),
                emitter_threshold: 0.5,
                label_unobserved: false,
                bake_resolution: 0,
            },
            bake: None,
            notes: Vec::new(),
        };
        let rows = std::sync::atomic::AtomicUsize::new(0);
        let on_row = || {
            rows.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        };
        let m = relight_metrics(&run, &dataset, &RelightOptions::default(), None, &[], &on_row).unwrap();
        assert_eq!(rows.into_inner(), 0, "nothing rendered");
        let sets = m.sets.clone().unwrap();
        assert_eq!(sets.keys().collect::<Vec<_>>(), ["lamp_dim"]);
        assert_eq!(
            sets["lamp_dim"],
            RelightSetMetrics {
                frames: 2,
                ..Default::default()
            }
        );
        assert_eq!(
            m,
            RelightMetrics {
                sets: Some(sets),
                ..Default::default()
            }
        );
    }
}
