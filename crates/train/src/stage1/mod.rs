//! Stage 1 (paper Sec. 5 "Training of geometry and radiance fields"; supp. B–C): F_d, F_c and F_e
//! trained end to end by volume rendering with L_1 = L_rgb + λ_geo L_geo + λ_emi L_emi (eq:train1),
//! L_geo = λ1 eikonal + λ2 depth + λ3 normal + λ4 smooth + λ5 bubble (eq:traing), over the three steps
//! of [`schedule`], with error-guided adaptive sampling of the bubble points.
//!
//! An iteration: draw rays uniformly over the training pixels; draw the extra points of the point
//! losses (uniform eikonal points, bubble points from the PDF maps, smoothness pairs near the
//! depth surface); one forward of the renderer over rays and points; the losses and their
//! gradients; one backward; Adam. A dataset without depth has no depth loss and no PDF maps: its
//! bubble points and smoothness pairs lie on the surface the batch's rays render (each ray's
//! sample where the termination density peaks, detached), so that neither term goes silently
//! inert. Stage 1 is a [`TrainStage`]: the shared driver seeds each iteration's RNG, skips
//! non-finite steps and writes the checkpoints.

pub mod losses;
pub mod pdf_map;
pub mod photo_depth;
pub mod photometric;
pub mod pose_correction;
pub mod rays;
pub mod schedule;
mod step;

use crate::config::TrainConfig;
use crate::driver::{StepOutcome, TrainStage};
use crate::maps::TrainingMaps;
use crate::resume::{DatasetFingerprint, DATASET_META};
use i2sdf_data::{DataError, Dataset};
use i2sdf_model::poses::{CorrectedView, PoseCorrections};
use i2sdf_model::renderer::{self, RenderSettings, RenderWorkspace};
use i2sdf_model::scene::{GradMut, GroupSpec, LrClass, Update, OPTIMIZER_PREFIX};
use i2sdf_model::{NeuralScene, SceneGrads};
use i2sdf_nn::params::ModuleSlot;
use i2sdf_nn::{Adam, AdamConfig, LrSchedule, Parameters};
use pdf_map::{PdfMaps, PixelRef};
use pose_correction::{surface_offset, AlignPoint, PoseCorrection};
use rand::Rng;
use rand_pcg::Pcg64;
use rays::{train_images, RayBatch, TrainImage};
use schedule::Phase;
use serde::Serialize;
use std::path::Path;

/// The volume renderer's settings of a run: its `[sampling]` section, as stage 1 trained with it
/// (the one mapping that training, `render` and `eval` use).
pub fn render_settings(config: &TrainConfig) -> RenderSettings {
    let s = &config.sampling;
    let mut r = RenderSettings::with_sampling(s.samples, s.coarse, s.epsilon);
    r.sampler.num_samples_upsample = s.upsample.unwrap_or(s.coarse);
    r
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct StepStats {
    pub iteration: u64,
    pub phase: Option<Phase>,
    pub loss: f32,
    pub rgb: f32,
    pub depth: f32,
    pub normal: f32,
    pub emitter: f32,
    pub eikonal: f32,
    pub smooth: f32,
    pub bubble: f32,
    /// `loss.inside`'s hinge on the points just behind the bubble points.
    pub inside: f32,
    /// PSNR of the batch's rendered colours.
    pub psnr: f32,
    pub beta: f32,
    pub samples_per_ray: f32,
    /// Pixels the PDF maps can currently draw from (bubble step).
    pub pdf_active: usize,
    /// Bubble points and smoothness pairs of the step (on the depth surface, or without depth
    /// on the rendered one).
    pub bubble_points: usize,
    pub smooth_pairs: usize,
    /// Pixels the sweep for depth from the images gave a depth, at the step it ran.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub photo_depth: Option<usize>,
    /// Of the depths the sweep found, those dropped as already explained by the field
    /// (`maps.photo_depth_explained`), at the step it ran.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub photo_depth_explained: Option<usize>,
    /// The step produced a non-finite loss and was skipped.
    pub skipped: bool,
    /// Milliseconds spent placing samples (and the extra points), in the render forward, in the
    /// losses (and the PDF maps' update), in the backward, and in Adam (and the pose
    /// correction). Before 2026-12-05 `ms_backward` held the last three together.
    pub ms_sampling: f32,
    pub ms_forward: f32,
    #[serde(default)]
    pub ms_losses: f32,
    pub ms_backward: f32,
    #[serde(default)]
    pub ms_adam: f32,
}

/// One optimizer group's moments, mutably, as the checkpoint tensors `adam.{group}.m` / `.v`
/// (per group, so that groups of optional modules may be missing from a checkpoint).
struct AdamGroupStateMut<'a> {
    m: &'a mut [f32],
    v: &'a mut [f32],
}

impl Parameters for AdamGroupStateMut<'_> {
    fn visit(&self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &[f32])) {
        f(format!("{prefix}.m"), vec![self.m.len()], self.m);
        f(format!("{prefix}.v"), vec![self.v.len()], self.v);
    }
    fn visit_mut(&mut self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &mut [f32])) {
        let len = self.m.len();
        f(format!("{prefix}.m"), vec![len], self.m);
        f(format!("{prefix}.v"), vec![len], self.v);
    }
}

/// The PDF maps' per-pixel values as one checkpoint tensor (`adam.pdf_maps.value`): trainer state
/// like the optimizer's, so under its prefix, which inference loads skip.
struct PdfValues(Vec<f32>);

impl Parameters for PdfValues {
    fn visit(&self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &[f32])) {
        f(format!("{prefix}.value"), vec![self.0.len()], &self.0);
    }
    fn visit_mut(&mut self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &mut [f32])) {
        let len = self.0.len();
        f(format!("{prefix}.value"), vec![len], &mut self.0);
    }
}

/// The largest SDF residual (normalized units, ~7 cm in the default room) a depth point pulls
/// its pose with: beyond it the point is more likely a flying pixel or an unfitted surface.
const POSE_RESIDUAL_CLAMP: f32 = 0.02;
/// Pose alignment: depth points per view in each Gauss–Newton round (how often, how many rounds
/// and how much of each step are `pose.align_*`).
const ALIGN_POINTS: usize = 256;
/// Pixels whose smoothed image changes by less than this per pixel (LDR, largest channel) hold a
/// pose in no direction; they are not drawn for the photometric rows.
const PHOTO_MIN_GRADIENT: f32 = 0.01;

/// The checkpoint's prefix of the pose corrections, and its metadata key saying they are there.
pub const POSE_PREFIX: &str = "adam.pose_correction";
const POSE_META: &str = "pose_correction";

/// The checkpoint's prefix of the PDF maps, and its metadata key saying they are there.
const PDF_PREFIX: &str = "adam.pdf_maps";
const PDF_META: &str = "pdf_maps";
/// The same for the colour error maps (`adaptive.rgb_rays`).
const RGB_PDF_PREFIX: &str = "adam.rgb_error_maps";
const RGB_PDF_META: &str = "rgb_error_maps";
/// The colour error maps keep a pixel's mean absolute LDR error over its channels, 0 below
/// this (a pixel fitted to 2.5/255 is not worth revisiting), clamped to 1. As in the depth maps,
/// a floor keeps the restored block sums exact (see [`Stage1::restore_pdf`]).
const RGB_ERROR_MIN: f32 = 0.01;

/// A training image's frame as the dataset gives it: name, index and camera (world units).
struct GivenView {
    name: String,
    frame: usize,
    camera: i2sdf_data::Camera,
    /// The sensor's low-confidence footprints, for the photometric depth's edge support.
    depth_low: Option<i2sdf_data::ImageF32>,
}

pub struct Stage1 {
    pub config: TrainConfig,
    pub scene: NeuralScene,
    pub iteration: u64,
    images: Vec<TrainImage>,
    /// One group per [`NeuralScene::modules`] entry, in that order.
    adam: Adam,
    specs: Vec<GroupSpec>,
    grads: SceneGrads,
    ws: RenderWorkspace,
    settings: RenderSettings,
    pdf: Option<PdfMaps>,
    /// Every training pixel's last colour error, which `adaptive.rgb_rays` of each batch's rays
    /// are drawn by (None when that is 0).
    rgb_errors: Option<PdfMaps>,
    batch: RayBatch,
    extra: Vec<f32>,
    /// The training views' pose corrections (None: the poses are used as given).
    pub poses: Option<PoseCorrection>,
    /// Per training image: its frame as given (for `RUN/poses.json` and the sweep).
    given_views: Vec<GivenView>,
    normalization: i2sdf_data::Normalization,
    /// The training images' smoothed gradients, made at the first photometric alignment.
    image_gradients: Option<Vec<photometric::ImageGradient>>,
    /// No training pixel has depth: bubble and smoothness points come from the rendered surface.
    no_depth: bool,
    /// The depth sensor's noise model in force (metres; 0: off): `TrainingMaps::depth_noise_distance`.
    depth_noise_distance: f32,
    /// The training data's fingerprint (JSON), kept in every checkpoint so that a resume or a
    /// stage 2 against other data is refused.
    dataset: String,
    /// When the sweep for depth from the images runs (`maps.photo_depth`), and once it ran, the
    /// depths it found (per pixel, image after image; 0: none).
    photo_depth_at: Option<u64>,
    photo_depth: Option<PdfValues>,
}

/// Rays per chunk of the PDF maps' initial render ([`Stage1::init_pdf`]): 4096 with the default
/// networks, fewer for wider SDF networks so that the chunk's workspace stays near the default's
/// (~0.5 GB): the paper's 8 × 256 backbone renders 256 at a time (4096 took ~7 GB beside a
/// training workspace of ~11 GB). Each ray's render is independent of the chunk it is in.
pub fn pdf_init_chunk_rays(config: &TrainConfig) -> usize {
    let sdf = config.model.sdf_network();
    (4096 * 128 / (sdf.hidden_dim * sdf.hidden_layers).max(1)).clamp(64, 4096)
}

impl Stage1 {
    /// A fresh stage 1 on `dataset` with the maps in force `maps` (`TrainingMaps::prepare` of the
    /// dataset and `config`, or a run's own: `TrainingMaps::for_run`).
    pub fn new(dataset: &Dataset, config: TrainConfig, maps: &TrainingMaps) -> Self {
        let scene = NeuralScene::new(&config.model, dataset.normalization, config.train.seed);
        Self::with_scene(dataset, config, scene, maps)
    }

    fn with_scene(dataset: &Dataset, mut config: TrainConfig, mut scene: NeuralScene, maps: &TrainingMaps) -> Self {
        // A run's configuration is resolved already (`run::open_run`); a caller's may say "auto".
        let _ = config.resolve(dataset);
        scene.set_matmul_precision(config.train.matmul_precision);
        let iterations = config.iterations();
        let t = &config.train;
        let schedule = |lr_warmup: u64| LrSchedule::WarmupCosine {
            warmup: lr_warmup,
            total: iterations,
            min_factor: t.lr_final_fraction,
        };
        let mut adam = Adam::new(AdamConfig {
            eps: 1e-15,
            ..Default::default()
        });
        let specs: Vec<GroupSpec> = scene.modules().into_iter().map(|(s, _)| s).collect();
        for (spec, (_, m)) in specs.iter().zip(scene.modules()) {
            let (lr, warmup) = match spec.lr {
                LrClass::Grid => (t.lr_grid, t.lr_warmup),
                LrClass::Mlp => (t.lr_mlp, t.lr_warmup),
                // β has no warm-up: it must sharpen from the first steps.
                LrClass::Beta => (t.lr_beta, 0),
            };
            adam.add_group(&spec.name, m.values().len(), lr, schedule(warmup));
        }
        let settings = render_settings(&config);
        let grads = SceneGrads::new(&scene);
        let fingerprint = serde_json::to_string(&DatasetFingerprint::of(dataset)).expect("serializes");
        let images = train_images(dataset, maps);
        let hash_grid = matches!(config.model.backbone, i2sdf_model::Backbone::HashGrid);
        let centres = images.iter().map(|im| im.origin).collect();
        let poses = PoseCorrection::new(dataset, &config.pose, hash_grid, centres, iterations);
        let given_views = images
            .iter()
            .map(|im| {
                let f = &dataset.frames[im.frame_index];
                GivenView {
                    name: f.name.clone(),
                    frame: im.frame_index,
                    camera: f.camera.clone(),
                    depth_low: f.depth_low.clone(),
                }
            })
            .collect();
        let no_depth = images.iter().all(|im| im.depth.iter().all(|d| *d <= 0.0));
        let photo_depth_at = Self::photo_depth_at(&config, maps.photo_depth, no_depth);
        let rgb_errors = (config.adaptive.rgb_rays > 0.0)
            .then(|| PdfMaps::over_all_pixels(images.iter().map(|im| im.pixels()), RGB_ERROR_MIN, 1.0));
        Stage1 {
            poses,
            given_views,
            normalization: dataset.normalization,
            dataset: fingerprint,
            no_depth,
            photo_depth_at,
            photo_depth: None,
            depth_noise_distance: maps.depth_noise_distance,
            image_gradients: None,
            images,
            adam,
            specs,
            grads,
            ws: RenderWorkspace::default(),
            settings,
            pdf: None,
            rgb_errors,
            batch: RayBatch::default(),
            extra: Vec::new(),
            iteration: 0,
            config,
            scene,
        }
    }

    /// Resumes from a checkpoint written by [`TrainStage::write_checkpoint`], with the maps the run
    /// trained with. Optimizer groups of optional modules that the checkpoint lacks start with
    /// zero moments.
    pub fn resume(
        dataset: &Dataset,
        config: TrainConfig,
        maps: &TrainingMaps,
        checkpoint: &Path,
    ) -> Result<Self, DataError> {
        let (scene, meta) = NeuralScene::load_config(checkpoint)?;
        let mut s = Self::with_scene(dataset, config, scene, maps);
        // The PDF maps of the bubble step: they learn from every batch, so a run resumed inside
        // the step continues with the maps it had, not ones re-initialised from its fields.
        let has_pdf = meta.get(PDF_META).is_some_and(|v| v == "1");
        let pixels: usize = s.images.iter().map(|i| i.pixels()).sum();
        let mut pdf_values = PdfValues(vec![0.0; pixels]);
        let mut rgb_values = PdfValues(vec![0.0; pixels]);
        let has_photo = meta.get(photo_depth::PHOTO_META).is_some_and(|v| v == "1");
        let mut photo_values = PdfValues(vec![0.0; pixels]);
        let has_rgb = s.rgb_errors.is_some();
        {
            let Stage1 {
                scene,
                adam,
                specs,
                poses,
                ..
            } = &mut s;
            let rgb_required = meta.get(RGB_PDF_META).is_some_and(|v| v == "1");
            let prefixes: Vec<String> = specs.iter().map(|g| format!("{OPTIMIZER_PREFIX}{}", g.name)).collect();
            let mut states: Vec<AdamGroupStateMut> = adam
                .groups
                .iter_mut()
                .map(|g| {
                    let (_, m, v) = g.state_mut();
                    AdamGroupStateMut { m, v }
                })
                .collect();
            let mut slots: Vec<ModuleSlot> = prefixes
                .iter()
                .zip(states.iter_mut())
                .zip(specs.iter())
                .map(|((prefix, st), spec)| ModuleSlot {
                    prefix,
                    module: st,
                    required: spec.required,
                })
                .collect();
            if has_pdf {
                slots.push(ModuleSlot {
                    prefix: PDF_PREFIX,
                    module: &mut pdf_values,
                    required: true,
                });
            }
            if has_rgb {
                // A run that started without the maps starts them empty.
                slots.push(ModuleSlot {
                    prefix: RGB_PDF_PREFIX,
                    module: &mut rgb_values,
                    required: rgb_required,
                });
            }
            if has_photo {
                slots.push(ModuleSlot {
                    prefix: photo_depth::PHOTO_PREFIX,
                    module: &mut photo_values,
                    required: true,
                });
            }
            if let Some(p) = poses {
                slots.push(ModuleSlot {
                    prefix: POSE_PREFIX,
                    module: p,
                    required: meta.get(POSE_META).is_some_and(|v| v == "1"),
                });
            }
            scene.load_params(checkpoint, &mut slots)?;
        }
        if has_photo {
            // Before the PDF maps: their pixels are those with depth, the sweep's included.
            s.add_photo_depth(photo_values.0);
        }
        if has_pdf {
            s.pdf = Some(s.restore_pdf(s.empty_pdf(), &pdf_values.0));
        }
        if let Some(maps) = s.rgb_errors.take() {
            s.rgb_errors = Some(s.restore_pdf(maps, &rgb_values.0));
        }
        s.apply_poses();
        let get = |k: &str| -> Result<u64, DataError> {
            meta.get(k)
                .and_then(|v| v.parse().ok())
                .ok_or_else(|| DataError::field(checkpoint, k, "missing or not an integer"))
        };
        s.iteration = get("iteration")?;
        s.adam.step = get("adam_step")?;
        Ok(s)
    }

    pub fn done(&self) -> bool {
        self.iteration >= self.config.iterations()
    }

    /// Will the next step initialise the PDF maps (a pause of a few seconds)?
    pub fn needs_pdf(&self) -> bool {
        let w = self.config.schedule.weights(self.phase(), &self.config.loss);
        w.bubble > 0.0 && self.pdf.is_none() && !self.no_depth
    }

    /// Does the dataset lack depth (bubble and smoothness points from the rendered surface)?
    pub fn without_depth(&self) -> bool {
        self.no_depth
    }

    pub fn phase(&self) -> Phase {
        self.config.schedule.phase(self.iteration, self.config.iterations())
    }

    /// All-zero maps over the pixels with depth.
    fn empty_pdf(&self) -> PdfMaps {
        let c = &self.config.adaptive;
        let valid: Vec<Vec<bool>> = self
            .images
            .iter()
            .map(|im| im.depth.iter().map(|d| *d > 0.0).collect())
            .collect();
        PdfMaps::new(valid, c.p_min, c.p_max)
    }

    /// Every pixel's map value, image after image (what the checkpoint keeps).
    fn pdf_values(&self, pdf: &PdfMaps) -> Vec<f32> {
        let mut out = Vec::with_capacity(self.images.iter().map(|i| i.pixels()).sum());
        for (k, im) in self.images.iter().enumerate() {
            out.extend((0..im.pixels()).map(|p| {
                pdf.value(PixelRef {
                    image: k as u32,
                    pixel: p as u32,
                })
            }));
        }
        out
    }

    /// The empty maps `pdf` (depth or colour) holding `values` (from [`Stage1::pdf_values`]). The
    /// f64 block sums are rebuilt by adding the values in order where the uninterrupted run added
    /// its deltas as they came; they agree exactly: every value is 0 or an f32 in [p_min, p_max],
    /// so every sum and delta is an integer multiple of ulp(p_min) and exact while below 2⁵³ of
    /// them (16.7 M pixels at the defaults p_min = 0.02, p_max = 1; beyond, a block sum may differ
    /// in its last bit).
    fn restore_pdf(&self, mut pdf: PdfMaps, values: &[f32]) -> PdfMaps {
        let mut at = 0;
        for (k, im) in self.images.iter().enumerate() {
            pdf.set_image(k, &values[at..at + im.pixels()]);
            at += im.pixels();
        }
        pdf
    }

    /// Error maps at the end of warm-up (paper Sec. 4.1.2): each training image's depth rendered
    /// on a grid of stride s (≤ ~200k rays in all), and every pixel's error against its own depth
    /// from that render ([`pdf_map::grid_errors`]; an edge is a jump above P_min).
    pub fn init_pdf(&mut self) {
        let mut pdf = self.empty_pdf();
        let c = &self.config.adaptive;
        if c.enabled {
            let total: usize = self.images.iter().map(|i| i.pixels()).sum();
            let stride = ((total as f64 / 200_000.0).sqrt().ceil() as usize).max(1);
            let mut ws = RenderWorkspace::default();
            for (k, im) in self.images.iter().enumerate() {
                let mut pixels = Vec::new();
                for j in (0..im.height).step_by(stride) {
                    for i in (0..im.width).step_by(stride) {
                        pixels.push(j * im.width + i);
                    }
                }
                let mut rendered = Vec::with_capacity(pixels.len());
                for chunk in pixels.chunks(pdf_init_chunk_rays(&self.config)) {
                    let (origins, dirs): (Vec<[f32; 3]>, Vec<[f32; 3]>) = chunk.iter().map(|&p| im.ray(p)).unzip();
                    renderer::forward::<Pcg64>(&self.scene, &self.settings, &origins, &dirs, &[], &mut ws, None);
                    rendered.extend_from_slice(&ws.out.depth[..chunk.len()]);
                }
                let err = pdf_map::grid_errors(im.width, im.height, stride, &rendered, &im.depth, c.p_min);
                pdf.set_image(k, &err);
            }
        } else {
            // Uniform sampling over the depth pixels (the paper's ablation).
            for (k, im) in self.images.iter().enumerate() {
                pdf.set_image(k, &vec![c.p_max; im.pixels()]);
            }
        }
        self.pdf = Some(pdf);
    }

    /// One step of the pose corrections, then the images take the new poses. By default
    /// (`pose.follow_gradient`, and always without depth) the corrections follow the rendering
    /// losses' gradient with Adam ([`renderer::ray_position_gradients`], the samples' t held
    /// fixed). Otherwise, every `pose.align_every` iterations each view is aligned to the SDF like
    /// a depth camera to a fused surface (point-to-plane Gauss–Newton on [`ALIGN_POINTS`] of its
    /// depth points, [`PoseCorrection::align_view`]). The gradient, from a tenth of stage 1 at
    /// 2e-4, once moved the 80×60 room's exact cameras ~10 cm along their view; from half of
    /// stage 1 at 5e-5 (rotations) and 1e-5 (translations) it brings the full-size captures'
    /// poses closer to the truth, where the alignment moved them 10–20 cm off.
    fn correct_poses(&mut self, rng: &mut Pcg64) {
        let Some(poses) = &self.poses else { return };
        if !poses.active(self.iteration) {
            return;
        }
        if !self.no_depth && !self.config.pose.follow_gradient {
            let p = &self.config.pose;
            let (every, rounds, damping) = (p.align_every, p.align_rounds, p.align_damping);
            if self.iteration % every != 0 {
                return;
            }
            for _ in 0..rounds {
                self.align_views(rng, damping);
                self.apply_poses();
            }
        } else {
            let Some(g) = renderer::ray_position_gradients(&self.scene, &self.ws) else {
                return;
            };
            let poses = self.poses.as_mut().expect("checked above");
            for (r, g) in g.iter().enumerate() {
                poses.add_ray_gradient(self.batch.image[r] as usize, self.batch.dir[r], g[0], g[1]);
            }
            poses.step();
            self.apply_poses();
        }
    }

    /// One Gauss–Newton round of every view against the SDF as it stands: [`ALIGN_POINTS`] depth
    /// points per view on its corrected rays (queried in one batch), the scene-wide gap between
    /// them and the zero set, then each view's step ([`PoseCorrection::align_view`]).
    fn align_views(&mut self, rng: &mut Pcg64, damping: f32) {
        if self.poses.is_none() {
            return;
        }
        let mut xs: Vec<f32> = Vec::new();
        let mut offsets: Vec<(usize, [f32; 3])> = Vec::new();
        for (i, im) in self.images.iter().enumerate() {
            let pixels = im.pixels();
            let (mut found, mut tries) = (0, 0);
            while found < ALIGN_POINTS && tries < 8 * ALIGN_POINTS {
                tries += 1;
                let p = rng.gen_range(0..pixels);
                let Some(x) = im.surface_point(p) else { continue };
                let (o, _) = im.ray(p);
                xs.extend_from_slice(&x);
                offsets.push((i, std::array::from_fn(|k| x[k] - o[k])));
                found += 1;
            }
        }
        let n = offsets.len();
        let (mut sdf, mut grad) = (vec![0.0f32; n], vec![0.0f32; 3 * n]);
        i2sdf_model::query::SceneQuery::new(&self.scene).sdf_gradient(&xs, &mut sdf, &mut grad);
        let mut per_view: Vec<Vec<AlignPoint>> = vec![Vec::new(); self.images.len()];
        for (j, &(i, offset)) in offsets.iter().enumerate() {
            per_view[i].push(AlignPoint {
                offset,
                sdf: sdf[j],
                normal: [grad[3 * j], grad[3 * j + 1], grad[3 * j + 2]],
            });
        }
        let offset = surface_offset(&sdf, POSE_RESIDUAL_CLAMP);
        let photo = self.photometric_rows(rng);
        let poses = self.poses.as_mut().expect("checked above");
        for (i, pts) in per_view.iter().enumerate() {
            let rows = photo.get(i).map_or(&[][..], |r| &r[..]);
            poses.align_view_with(i, pts, rows, offset, POSE_RESIDUAL_CLAMP, damping);
        }
        poses.finish_alignment();
    }

    /// The photometric rows of every view ([`photometric`]): `pose.photometric_points` pixels a
    /// view among those with an image gradient, cast into the SDF in one batch, coloured by F_c
    /// along their rays. Empty when the weight is 0. Pixels whose colour is clipped (lights)
    /// carry no gradient the fields can match and are left out.
    fn photometric_rows(&mut self, rng: &mut Pcg64) -> Vec<Vec<photometric::PhotoRow>> {
        let p = &self.config.pose;
        if p.photometric_weight <= 0.0 || p.photometric_points == 0 {
            return Vec::new();
        }
        let want = p.photometric_points as usize;
        if self.image_gradients.is_none() {
            self.image_gradients = Some(self.images.iter().map(photometric::ImageGradient::of).collect());
        }
        let grads = self.image_gradients.as_ref().expect("set above");
        let (mut origins, mut dirs, mut t_max, mut who) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (i, im) in self.images.iter().enumerate() {
            let (mut found, mut tries) = (0, 0);
            while found < want && tries < 8 * want {
                tries += 1;
                let px = rng.gen_range(0..im.pixels());
                if grads[i].strength(px) < PHOTO_MIN_GRADIENT || im.rgb[px].iter().any(|c| *c >= 0.99) {
                    continue;
                }
                let (o, d) = im.ray(px);
                origins.push(o);
                dirs.push(d);
                t_max.push(renderer::sphere_exit(o, d, 1.0));
                who.push((i, px));
                found += 1;
            }
        }
        let n = origins.len();
        let mut hits = vec![i2sdf_model::raycast::Hit::default(); n];
        let near = self.settings.near;
        let cast = i2sdf_model::raycast::CastSettings {
            near,
            ..Default::default()
        };
        i2sdf_model::raycast::SdfCaster::new(&self.scene, cast).cast(&origins, &dirs, &t_max, &mut hits);
        let (mut pts, mut hit_dirs, mut keep) = (Vec::new(), Vec::new(), Vec::new());
        for (k, h) in hits.iter().enumerate() {
            // A ray that starts inside the SDF's solid (early in training, around a camera)
            // "hits" at its start: that point is no surface, and its lever |v| ≈ 0 would give
            // its rows an unbounded Jacobian.
            if h.hit && h.t > 2.0 * near {
                pts.extend_from_slice(&h.point);
                hit_dirs.extend_from_slice(&dirs[k]);
                keep.push(k);
            }
        }
        let mut rgb = vec![0.0f32; pts.len()];
        i2sdf_model::query::SceneQuery::new(&self.scene).radiance_at(&pts, &hit_dirs, &mut rgb);
        let mut rows = vec![Vec::new(); self.images.len()];
        for (j, &k) in keep.iter().enumerate() {
            let (i, px) = who[k];
            let x = [pts[3 * j], pts[3 * j + 1], pts[3 * j + 2]];
            let c = [rgb[3 * j], rgb[3 * j + 1], rgb[3 * j + 2]];
            if let Some(r) = photometric::photometric_rows(&self.images[i], &grads[i], px, x, c) {
                rows[i].extend_from_slice(&r);
            }
        }
        rows
    }

    /// Gives every training image its current pose correction.
    fn apply_poses(&mut self) {
        let Some(poses) = &self.poses else { return };
        for (i, im) in self.images.iter_mut().enumerate() {
            (im.rotation, im.translation) = poses.transform(i);
        }
    }

    /// Adam over every group of the scene, in the order the groups were registered.
    fn apply_adam(&mut self) {
        self.adam.begin_step();
        let groups = self.scene.groups(Some(&mut self.grads));
        for (id, g) in groups.into_iter().enumerate() {
            debug_assert_eq!(self.adam.groups[id].name, g.spec.name);
            match (g.grad.expect("groups with gradients"), g.spec.update) {
                (GradMut::Sparse(hg), Update::SparseRows(row)) => {
                    self.adam.update_sparse(id, g.module.values_mut(), hg, row)
                }
                (GradMut::Dense(grad), _) => self.adam.update(id, g.module.values_mut(), grad),
                (GradMut::Sparse(_), Update::Dense) => unreachable!("a sparse gradient of a dense group"),
            }
        }
    }

    fn checkpoint(&self, path: &Path) -> Result<(), DataError> {
        let pdf = self.pdf.as_ref().map(|p| PdfValues(self.pdf_values(p)));
        let rgb = self.rgb_errors.as_ref().map(|p| PdfValues(self.pdf_values(p)));
        let mut meta = vec![
            ("iteration", self.iteration.to_string()),
            ("adam_step", self.adam.step.to_string()),
            (DATASET_META, self.dataset.clone()),
        ];
        // Adam's own tensors: `adam.{group}.m` / `.v`, what `resume` reads per group.
        let mut extra: Vec<(&str, &dyn Parameters)> = vec![("adam", &self.adam as &dyn Parameters)];
        if let Some(p) = &pdf {
            meta.push((PDF_META, "1".into()));
            extra.push((PDF_PREFIX, p as &dyn Parameters));
        }
        if let Some(p) = &rgb {
            meta.push((RGB_PDF_META, "1".into()));
            extra.push((RGB_PDF_PREFIX, p as &dyn Parameters));
        }
        if let Some(p) = &self.photo_depth {
            meta.push((photo_depth::PHOTO_META, "1".into()));
            extra.push((photo_depth::PHOTO_PREFIX, p as &dyn Parameters));
        }
        if let Some(p) = &self.poses {
            meta.push((POSE_META, "1".into()));
            extra.push((POSE_PREFIX, p as &dyn Parameters));
        }
        self.scene.save_with(path, &meta, &extra)?;
        if let Some(c) = self.pose_corrections() {
            c.write(&path.with_file_name("poses.json"))?;
        }
        Ok(())
    }

    /// The training views' corrected poses in world units, when stage 1 corrects them.
    pub fn pose_corrections(&self) -> Option<PoseCorrections> {
        let poses = self.poses.as_ref()?;
        let views = self
            .given_views
            .iter()
            .enumerate()
            .map(|(i, v)| {
                let given = v.camera.c2w;
                CorrectedView::new(
                    &v.name,
                    v.frame,
                    given,
                    poses.corrected_c2w(i, given, &self.normalization),
                )
            })
            .collect();
        Some(PoseCorrections { views })
    }
}

impl TrainStage for Stage1 {
    type Stats = StepStats;
    fn key(&self) -> &'static str {
        "stage1"
    }
    fn iteration(&self) -> u64 {
        self.iteration
    }
    fn total(&self) -> u64 {
        self.config.iterations()
    }
    fn seed(&self) -> u64 {
        self.config.train.seed
    }
    fn pending_pause(&self) -> Option<&'static str> {
        if self.needs_photo_depth() {
            return Some("sweeping the images for the depth the sensor lost");
        }
        self.needs_pdf().then_some("initialising the error maps")
    }
    fn step(&mut self, rng: &mut Pcg64) -> Result<StepOutcome<StepStats>, DataError> {
        Ok(self.step_with(rng))
    }
    fn is_finite(&self) -> bool {
        self.scene.is_finite()
    }
    fn write_checkpoint(&self, path: &Path) -> Result<(), DataError> {
        self.checkpoint(path)
    }
}
