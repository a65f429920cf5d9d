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
use i2sdf_data::{DataError, Dataset, Frame, ImageF32, RelightSet, Split};
use i2sdf_edit::{differential_hdr, edit_images, hdr_ldr_images, light_gains, EditSettings, RecoveredScene};
use i2sdf_model::OpenedRun;
use i2sdf_render::ViewRender;
use std::collections::{BTreeMap, HashMap};

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

fn scores(pred: &ImageF32, gt: &ImageF32) -> Result<(Option<f64>, Option<f64>), DataError> {
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
        return Ok(RelightMetrics {
            sets: Some(sets.collect()),
            ..Default::default()
        });
    }
    // Every spec and asset is read before the (long) rendering starts.
    let mut specs = Vec::new();
    for set in &dataset.relight {
        let spec = EditSpec::read(&set.spec)?;
        let assets = spec.load_assets()?;
        specs.push((spec, assets));
    }
    let recovered = RecoveredScene::of_run(run, dataset, options.mesh_resolution)?;
    let volume = options.differential.then_some(&run.config.render);
    let unedited_scene = recovered.edited(&EditSpec::default(), &Default::default());
    let tests: HashMap<Vec<u64>, &Frame> = dataset.split(Split::Test).map(|f| (camera_key(f), f)).collect();
    // Per camera: the unedited render (shared by the relight-only sets, the differential base of
    // the others), the view index its paths were drawn with, and the radiance field's image.
    let mut shared: HashMap<Vec<u64>, (ViewRender, u32)> = HashMap::new();
    let mut captured: HashMap<Vec<u64>, ImageF32> = HashMap::new();
    let (mut all_dp, mut all_ds) = (Vec::new(), Vec::new());
    let (mut all_p, mut all_s) = (Vec::new(), Vec::new());
    let (mut base_p, mut base_s) = (Vec::new(), Vec::new());
    let mut seen_tests = std::collections::HashSet::new();
    let mut sets = BTreeMap::new();
    let mut view = 0u32;
    for (i, (set, (spec, assets))) in dataset.relight.iter().zip(&specs).enumerate() {
        let relight_only = spec.ops.iter().all(|op| matches!(op, EditOp::Relight(_)));
        let own = (!relight_only).then(|| recovered.edited(spec, assets));
        let edited = own.as_ref().unwrap_or(&unedited_scene);
        let gains = light_gains(spec, edited);
        let ones = vec![Vec3::ONE; edited.lights()];
        let (mut p, mut s, mut pu, mut su) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let (mut dp, mut ds) = (Vec::new(), Vec::new());
        for f in &set.frames {
            let key = camera_key(f);
            if !shared.contains_key(&key) && (relight_only || volume.is_some()) {
                let r = recovered.render(&unedited_scene, &f.camera, &options.render, view, on_row);
                shared.insert(key.clone(), (r, view));
                view += 1;
            }
            let own_render = own.as_ref().map(|ed| {
                // The unedited render's paths when there is one (the differential's edited and
                // unedited images then share their noise), else a fresh view index.
                let v = shared.get(&key).map_or_else(
                    || {
                        view += 1;
                        view - 1
                    },
                    |(_, v)| *v,
                );
                recovered.render(ed, &f.camera, &options.render, v, on_row)
            });
            let base = shared.get(&key).map(|(r, _)| r);
            let render = own_render.as_ref().or(base).expect("a render of the edited scene");
            let (_, relit) = edit_images(render, &gains, &recovered.radiometry);
            let (x, y) = scores(&relit, &f.rgb)?;
            p.extend(x);
            s.extend(y);
            if let (Some(volume), Some(base)) = (volume, base) {
                let cap = captured
                    .entry(key.clone())
                    .or_insert_with(|| recovered.captured(&f.camera, volume));
                let d = differential_hdr(cap, render, &gains, base, &recovered.radiometry);
                let (_, ldr) = hdr_ldr_images(&d, render.width, render.height, &recovered.radiometry);
                let (x, y) = scores(&ldr, &f.rgb)?;
                dp.extend(x);
                ds.extend(y);
            }
            if relight_only {
                let (_, plain) = edit_images(render, &ones, &recovered.radiometry);
                let (x, y) = scores(&plain, &f.rgb)?;
                pu.extend(x);
                su.extend(y);
                if let Some(t) = tests.get(&key) {
                    if seen_tests.insert(key) {
                        let (x, y) = scores(&plain, &t.rgb)?;
                        base_p.extend(x);
                        base_s.extend(y);
                    }
                }
            }
        }
        all_dp.extend(&dp);
        all_ds.extend(&ds);
        all_p.extend(&p);
        all_s.extend(&s);
        sets.insert(
            set_name(set, i),
            RelightSetMetrics {
                psnr: mean(&p),
                ssim: mean(&s),
                psnr_unedited: mean(&pu),
                ssim_unedited: mean(&su),
                psnr_differential: mean(&dp),
                ssim_differential: mean(&ds),
                frames: set.frames.len(),
            },
        );
    }
    Ok(RelightMetrics {
        psnr: mean(&all_p),
        ssim: mean(&all_s),
        sets: Some(sets),
        unedited: (!base_p.is_empty()).then(|| ImagePair {
            psnr: mean(&base_p),
            ssim: mean(&base_s),
            frames: base_p.len(),
        }),
        psnr_differential: mean(&all_dp),
        ssim_differential: mean(&all_ds),
    })
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
