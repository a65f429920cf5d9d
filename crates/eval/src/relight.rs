//! Relighting evaluation: each of the dataset's `relight` sets rendered with its edit spec by the
//! edit renderer (path tracing the recovered scene, emitters × the spec's gains) and compared,
//! tone-mapped as the dataset's images, with its ground-truth images. Also what doing nothing
//! scores (the unedited render against the relit truth), and the unedited render against the
//! test images of the same cameras.
//!
//! Sets whose specs only relight share one render per camera: relighting is exact from the
//! per-emitter radiance slots, so only the gains differ. With `volume` set, each set is also
//! scored by differential rendering ([`i2sdf_edit::differential`]): stage 1's radiance field of
//! the camera + the path-traced change, from the same renders (and, for a set that edits more
//! than lights, the unedited render of the same paths).

use crate::image_metrics::{psnr, ssim, ImageRef};
use crate::report::{ImagePair, RelightMetrics, RelightSetMetrics};
use glam::Vec3;
use i2sdf_data::edit_spec::{EditOp, EditSpec};
use i2sdf_data::{Camera, DataError, Dataset, EditAssets, Frame, ImageF32, RelightSet, Split};
use i2sdf_edit::{
    differential_hdr, edit_images, hdr_ldr_images, light_gains, EditSettings, EditedScene, RecoveredScene,
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
fn set_name(set: &RelightSet, index: usize) -> String {
    set.spec
        .file_stem()
        .map_or_else(|| format!("set{index}"), |s| s.to_string_lossy().into_owned())
}

/// The relight section of the report; all null without relit sets. `on_row` is called after
/// each rendered row.
///
/// Without emitters (stage 2 found none) nothing is rendered and every figure is null, each set
/// listed with its frame count only: the edit renderer's light comes from the recovered emitters
/// (and any light a spec inserts), so every relit image would be black, and its differential
/// composite the radiance field's image unchanged; scoring those would report numbers that say
/// nothing about relighting. The report says why with
/// [`crate::report::EvalReport::note_no_emitters`].
pub fn relight_metrics(
    run: &OpenedRun,
    dataset: &Dataset,
    options: &RelightOptions,
    on_row: &(dyn Fn() + Sync),
) -> Result<RelightMetrics, DataError> {
    if dataset.relight.is_empty() {
        return Ok(RelightMetrics::default());
    }
    if run.stage2()?.emitters.is_empty() {
        return Ok(frame_counts_only(dataset));
    }
    // Every spec and asset is read before the (long) rendering starts.
    let mut specs = Vec::new();
    for set in &dataset.relight {
        let spec = EditSpec::read(&set.spec)?;
        let assets = spec.load_assets()?;
        specs.push((spec, assets));
    }
    let recovered = RecoveredScene::of_run(run, dataset, options.mesh_resolution)?;
    let mut eval = RelightEval {
        unedited_scene: recovered.edited(&EditSpec::default(), &Default::default()),
        recovered: &recovered,
        volume: options.differential.then_some(&run.config.render),
        settings: &options.render,
        on_row,
        tests: dataset.split(Split::Test).map(|f| (camera_key(f), f)).collect(),
        shared: HashMap::new(),
        captured: HashMap::new(),
        view: 0,
    };
    let mut baseline = Baseline::default();
    let mut all = SetScores::default();
    let mut sets = BTreeMap::new();
    for (i, (set, (spec, assets))) in dataset.relight.iter().zip(&specs).enumerate() {
        let scores = eval.score_set(set, spec, assets, &mut baseline)?;
        all.relit.extend(&scores.relit);
        all.differential.extend(&scores.differential);
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
/// nothing scores, relight-only sets), and the differential composites (with `volume`).
#[derive(Default)]
struct SetScores {
    relit: Scores,
    unedited: Scores,
    differential: Scores,
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
            frames,
        }
    }
}

/// The unedited render against the test images of the same cameras, each test camera once.
#[derive(Default)]
struct Baseline {
    scores: Scores,
    seen: HashSet<Vec<u64>>,
}

/// What the sets of one evaluation share: the recovered scene and its unedited edit, the test
/// frames by camera, and per camera the unedited render (shared by the relight-only sets, the
/// differential base of the others) with the view index its paths were drawn with, and the
/// radiance field's image.
struct RelightEval<'r, 'a> {
    recovered: &'r RecoveredScene<'a>,
    unedited_scene: EditedScene,
    /// The radiance field's render settings when sets are also scored by differential rendering.
    volume: Option<&'r RenderSettings>,
    settings: &'r EditSettings,
    on_row: &'r (dyn Fn() + Sync),
    tests: HashMap<Vec<u64>, &'r Frame>,
    shared: HashMap<Vec<u64>, (ViewRender, u32)>,
    captured: HashMap<Vec<u64>, ImageF32>,
    /// The next unused view index (each render's own paths).
    view: u32,
}

impl RelightEval<'_, '_> {
    /// Renders and scores every frame of `set` with its edit. A spec that only relights reuses
    /// the camera's unedited render with its gains (and scores the unedited image too, feeding
    /// `baseline`); any other spec renders its edited scene.
    fn score_set(
        &mut self,
        set: &RelightSet,
        spec: &EditSpec,
        assets: &EditAssets,
        baseline: &mut Baseline,
    ) -> Result<SetScores, DataError> {
        let relight_only = spec.ops.iter().all(|op| matches!(op, EditOp::Relight(_)));
        let own = (!relight_only).then(|| self.recovered.edited(spec, assets));
        let edited = own.as_ref().unwrap_or(&self.unedited_scene);
        let gains = light_gains(spec, edited);
        let ones = vec![Vec3::ONE; edited.lights()];
        let rm = &self.recovered.radiometry;
        let mut scores = SetScores::default();
        for f in &set.frames {
            let key = camera_key(f);
            if !self.shared.contains_key(&key) && (relight_only || self.volume.is_some()) {
                self.render_unedited(&key, &f.camera);
            }
            let own_render = own.as_ref().map(|ed| self.render_edited(ed, &key, &f.camera));
            let base = self.shared.get(&key).map(|(r, _)| r);
            let render = own_render.as_ref().or(base).expect("a render of the edited scene");
            let (_, relit) = edit_images(render, &gains, rm);
            scores.relit.push(scores_of(&relit, &f.rgb)?);
            if let (Some(volume), Some(base)) = (self.volume, base) {
                let cap = self
                    .captured
                    .entry(key.clone())
                    .or_insert_with(|| self.recovered.captured(&f.camera, volume));
                let d = differential_hdr(cap, render, &gains, base, rm);
                let (_, ldr) = hdr_ldr_images(&d, render.width, render.height, rm);
                scores.differential.push(scores_of(&ldr, &f.rgb)?);
            }
            if relight_only {
                let (_, plain) = edit_images(render, &ones, rm);
                scores.unedited.push(scores_of(&plain, &f.rgb)?);
                if let Some(t) = self.tests.get(&key) {
                    if baseline.seen.insert(key) {
                        baseline.scores.push(scores_of(&plain, &t.rgb)?);
                    }
                }
            }
        }
        Ok(scores)
    }

    /// The unedited render of `camera` (key `key`), on a fresh view index.
    fn render_unedited(&mut self, key: &[u64], camera: &Camera) {
        let r = self
            .recovered
            .render(&self.unedited_scene, camera, self.settings, self.view, self.on_row);
        self.shared.insert(key.to_vec(), (r, self.view));
        self.view += 1;
    }

    /// The render of `edited` from `camera`: on the unedited render's paths when there is one
    /// (the differential's edited and unedited images then share their noise), else on a fresh
    /// view index.
    fn render_edited(&mut self, edited: &EditedScene, key: &[u64], camera: &Camera) -> ViewRender {
        let v = self.shared.get(key).map_or_else(
            || {
                self.view += 1;
                self.view - 1
            },
            |(_, v)| *v,
        );
        self.recovered.render(edited, camera, self.settings, v, self.on_row)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use i2sdf_data::Radiometry;
    use i2sdf_model::intrinsic_io::IntrinsicFields;
    use i2sdf_model::material_field::{MaterialConfig, MaterialField};
    use i2sdf_model::{EmitterTable, InferenceConfig, ModelConfig, NeuralScene};

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
        let m = relight_metrics(&run, &dataset, &RelightOptions::default(), &on_row).unwrap();
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
