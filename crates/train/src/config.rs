//! One configuration struct for a training run: read from a TOML file, overridden by
//! `--set key=value` flags, written into the run directory and into checkpoint metadata. Defaults
//! are tuned for the default synthetic room on 2 cores. Unknown keys are errors (a typo in an
//! ablation must not silently run the default).

pub use crate::auto::Auto;
use crate::stage1::schedule::{LossWeights, Schedule, PAPER_BUBBLE_EIKONAL};
pub use crate::stage2::lobe_choice::LobeConfig;
use i2sdf_data::{DataError, Dataset};
pub use i2sdf_model::material_field::{MaterialBackbone, MaterialConfig};
pub use i2sdf_model::{Backbone, ModelConfig};
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    pub train: TrainLoop,
    pub model: ModelConfig,
    pub sampling: SamplingConfig,
    pub loss: LossWeights,
    pub schedule: Schedule,
    pub adaptive: AdaptiveConfig,
    /// Stage 2: materials and emitters.
    pub stage2: Stage2Config,
    /// Stage 2's material fields.
    pub material: MaterialConfig,
    /// Stage 2's choice of a specular lobe per material segment.
    pub lobes: LobeConfig,
    /// Stage 1's per-camera pose correction.
    pub pose: PoseConfig,
    /// What training does for each map the dataset may lack (`crate::maps`).
    pub maps: MapsConfig,
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            train: TrainLoop::default(),
            model: ModelConfig::default(),
            sampling: SamplingConfig::default(),
            loss: LossWeights::default(),
            schedule: Schedule::default(),
            adaptive: AdaptiveConfig::default(),
            stage2: Stage2Config::default(),
            material: MaterialConfig::default(),
            lobes: LobeConfig::default(),
            pose: PoseConfig::default(),
            maps: MapsConfig::default(),
        }
    }
}

/// Where the emitter masks of training come from (`maps.emitter_masks`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EmitterMasks {
    /// The dataset's where it has them, else found from the images (`i2sdf_data::emitter_detect`).
    #[default]
    Auto,
    /// The dataset's, required of every training view.
    Dataset,
    /// Found from the images for every training view, the dataset's ignored.
    Images,
    /// None: no emitter loss in stage 1, no emitters in stage 2.
    Off,
}

/// Where the normal maps of stage 1's normal loss come from (`maps.normals`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Normals {
    /// The dataset's where it has them, else derived from depth where that exists: as good as
    /// the true normals on a synthetic room, where no normal loss lost 0.08 F-score (docs/DATASETS.md,
    /// "Missing maps").
    #[default]
    Auto,
    /// The dataset's, required of every training view.
    Dataset,
    /// Derived from the depth maps for every training view (`i2sdf_data::depth_normals`), the
    /// dataset's ignored.
    Depth,
    /// None: no normal loss.
    Off,
}

/// What training does for each map the dataset may lack; the maps in force are `crate::maps`'.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MapsConfig {
    pub emitter_masks: EmitterMasks,
    pub normals: Normals,
    /// Distance (metres) at which a depth sensor's noise has doubled from its value up close; 0
    /// weighs every depth sample alike. Applies to depth the dataset does not declare exact
    /// (`depth_exact: true` in transforms.json; the built-in rooms without sensor noise and the
    /// paper's release do). Stage 1's depth, bubble and inside terms weigh a sample at distance
    /// z along its ray by 1 / (1 + (z / d)²), normalized to a mean of 1 over each batch: the L1
    /// likelihood of a sensor whose noise grows as σ₀ (1 + (z / d)²), as triangulating sensors'
    /// does (the paper's σ(z) = 0.0029 z² + 0.0033 m has d = 1.07 m). Off by default: with the
    /// eikonal term in the bubble step (the sensor-depth schedule) the far walls need their
    /// samples' full weight: on three phone captures d = 2 m gave F 0.956 / 0.956 / 0.948 (a
    /// 10–30 cm bulge on seed 7's far wall), d = 0 0.954 / 0.955 / 0.960, and 0.966 with
    /// another initialization of seed 7 (docs/results.md, fourteenth and fifteenth sessions).
    pub depth_noise_distance: f32,
    /// The sensor's noise σ₀ up close (metres; 0: none), for depth not declared exact:
    /// eq:bubble tolerates |d| up to σ₀ (1 + (z / d)²) at a depth point, and the inside point
    /// moves that far behind it. Off by default: at 0.009 (the paper's σ at 3 m) it halved seed
    /// 1's outward wall bias but lost F on both captures (0.951 → 0.945, 0.938 → 0.930;
    /// docs/results.md, twelfth session).
    pub depth_noise_sigma: f32,
    /// When (a fraction of stage 1's iterations; 0: never) stage 1 gives depth from the images to
    /// the pixels a depth sensor lost in front of what it sensed: a plane sweep along their rays
    /// against the neighbour views at the poses corrected so far (`i2sdf_data::photo_depth`), each
    /// depth kept where two other views found the same point. What a coarse sensor grid drops as
    /// flying pixels (a lamp pole, chandelier rods, table legs) then gets depth and bubble points.
    /// Late, so that the pose correction (from half of stage 1) has brought the poses within a
    /// fraction of a pixel: the sweep compares single pixels. Exact depth has no such holes.
    pub photo_depth: f32,
    /// Of the depths the sweep finds, drop those the field already explains: where the field's
    /// own render of the pixel lies over 1.1 times as far and matches the pixel's colour within
    /// this mean absolute difference (0: keep every depth). The edge support fills a sensor's
    /// dropped flying pixels with the foreground's depth, halos on pixels that see the
    /// background; a thin object the field lost renders the background's colour instead. On the
    /// seed-1 capture at 0.02 it drops 300 of the 1344 depths whose pixel sees over 5 cm behind
    /// them and 40 of the 1028 right ones (docs/results.md, twentieth session).
    pub photo_depth_explained: f32,
}

impl Default for MapsConfig {
    fn default() -> Self {
        MapsConfig {
            emitter_masks: EmitterMasks::default(),
            normals: Normals::default(),
            depth_noise_distance: 0.0,
            depth_noise_sigma: 0.0,
            photo_depth: 0.75,
            photo_depth_explained: 0.02,
        }
    }
}

/// Which Monte Carlo estimator of eq:render stage 2 fits the materials with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage2Estimator {
    /// Incident radiance traced once per cached pixel (frozen geometry, radiance and emitter
    /// fields), the materials fitted against it: the default.
    Cached,
    /// The paper's: N fresh directions per pixel and iteration, importance-sampled from the
    /// current materials, traced in the SDF every step (slow; the reference).
    Live,
}

/// The re-render loss of stage 2 (per channel, linear radiance).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage2Loss {
    /// The paper's L1: the median over the views that see a point, so a highlight seen in a
    /// minority of them is an outlier it ignores.
    L1,
    /// Squared error over twice the mean surface target (so its slope is 1 at a residual of
    /// that size, like L1's): the mean over views, highlights included.
    L2,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Stage2Config {
    /// Stage-2 iterations.
    pub iterations: u64,
    /// Pixels per iteration.
    pub pixels: usize,
    pub estimator: Stage2Estimator,
    pub loss: Stage2Loss,
    /// Training pixels whose surface point, normal and incident radiance are cached (drawn
    /// uniformly over the training views; 0 = every pixel).
    pub cache_pixels: usize,
    /// Incident-radiance samples per cached pixel.
    pub cache_samples: usize,
    /// Cached pixels whose samples are re-traced each iteration (0: the cache is traced once).
    pub refresh_pixels: usize,
    /// Keep each cached pixel's specular sums at fixed roughness levels instead of its samples
    /// (`surface_cache::SpecularBake`; ρ interpolated between levels): memory and loop time no
    /// longer grow with `cache_samples`.
    pub specular_bake: bool,
    /// Pool each baked pixel's specular sums with nearby pixels whose mirror direction, normal
    /// and position agree within this fraction of each level's lobe width α (δ ≤ κ·α; 0, the
    /// default: each pixel's own samples): `SpecularBake::pooled`. Acts on the bake only
    /// (`specular_bake`; a second copy of the bake while it runs). Off because the noise it removes is what drains Ks on matte surfaces:
    /// pooled at 0.5, glossy Ks comes closer to the truth (0.29 → 0.35 of 0.39 on the default
    /// room) but matte surfaces keep a rough lobe (Ks 0.18) and Kd falls 3 dB (docs/results.md,
    /// seventeenth session).
    pub specular_pool: f32,
    /// Radius (normalized units) within which `specular_pool` looks for those pixels.
    pub specular_pool_radius: f32,
    /// Shade training pixels with the dataset's normal maps where it has them (else the SDF's).
    pub input_normals: bool,
    /// Hits within the box of an emitter's points that no training camera saw are that emitter
    /// (F_e was never trained there: the unseen part of a ceiling panel), whatever F_e says; a
    /// fitted bulb is its sphere either way. On seed 1 it completes the ceiling panel (Kd +2.0 dB
    /// raw, the relit sets +0.7 dB); no room or capture measured lost more than 0.1 dB of any image
    /// figure, though seed 1's capture's ceiling L went ×0.96 → ×0.84 (docs/results.md, eleventh
    /// session). With the emitter's bounding sphere instead of its box it overreached onto
    /// unseen ceiling.
    pub label_unobserved: bool,
    /// An emitter whose points lie on a sphere (a bulb seen from one side) is that sphere,
    /// emitting all round, wherever a ray meets it: in stage 2's fit, the re-render, the relit
    /// sets and the export (`FrozenScene::cast`). The recovered bulb's unseen side, which stage
    /// 1 leaves a non-emitting bulge, is cast through. On the default room and seed 7: Kd +1.2 and
    /// +1.35 dB, the bulb alone relit +1.5 and +1.4 dB (differential); on seed 1 the relit sets
    /// lost 0.3–0.8 dB (docs/results.md).
    pub fit_bulbs: bool,
    /// An emitter whose points lie flat on an axis (a ceiling panel) is the rectangle of their
    /// box at their median plane, emitting towards the room, wherever a ray meets it or meets
    /// the recovered surface within its slab (`i2sdf_model::emitter_panel`): in stage 2's fit,
    /// the re-render, the relit sets and the export, as `fit_bulbs` for bulbs. Kd +0.05 to
    /// +0.39 dB on the exact rooms and the captures, the traced relit sets −0.1 to −0.3 on some
    /// (docs/results.md).
    pub fit_panels: bool,
    /// A bulb's sphere takes the radius its emitter masks give (the median disc of its whole,
    /// unoccluded mask pieces at its centre's depth) instead of its surface fit's, which stage 1's
    /// inflated small bright objects make too large (`emitter_setup::size_bulbs_by_masks`). Needs emitter
    /// masks (given or found) and `fit_bulbs`.
    pub size_bulbs_by_masks: bool,
    /// Lights that no surface carries (stage 1 built no surface for them: a clipped bulb the
    /// depth sensor missed) are triangulated from the pieces of the emitter masks that no
    /// emitter explains, as spheres (`stage2::emitter_triangulation`). Needs emitter masks
    /// (given or found). On the default room's phone capture it recovers the bulb stage 1 lost.
    pub triangulate_emitters: bool,
    /// Radius (normalized units) over which the diffuse irradiance of cached pixels with similar
    /// normals is averaged (0: each pixel's own samples only).
    pub irradiance_radius: f32,
    /// Radius (normalized units) over which the SDF's shading normals are averaged where the
    /// dataset gives no normal map (0: the SDF's gradient at each hit): stage 2's pixels and,
    /// through the bake record, every renderer of the run.
    pub normal_smoothing_radius: f32,
    /// Marching-cubes resolution of the frozen surface baked for the secondary rays (a BVH,
    /// hits refined onto the SDF; 0: sphere-trace every ray).
    pub bake_resolution: usize,
    /// N of the live estimator (the paper's 16).
    pub samples: usize,
    /// Sample the emitters too (one-sample MIS with the BRDF), for both estimators.
    pub emitter_sampling: bool,
    pub lr_grid: f32,
    pub lr_mlp: f32,
    /// Learning rate of log L\[k\].
    pub lr_emission: f32,
    /// The L\[k\] of an emitter the images saw only clipped (LDR without HDR) is estimated from
    /// the light it throws on the room and held (`emission_from_shading`); off: fitted with the
    /// materials from its lower bound, which the re-render cannot tell from a brighter Kd.
    pub emission_from_shading: bool,
    /// Final learning rate as a fraction of the initial one (cosine decay).
    pub lr_final_fraction: f32,
    /// Weight of the smoothness term of eq:material (‖M(x) − M(x+ε)‖₂ per parameter).
    pub smooth: f32,
    /// Weight of the energy term of eq:material ((Kd + Ks − 1)₊).
    pub energy: f32,
    /// ε of the smoothness term, in normalized units.
    pub smooth_epsilon: f32,
    /// Weight of the roughness prior w(Ks)·(ρ − `rho_prior_target`)², w = exp(−lum(Ks)/0.04)
    /// (`losses::material_regularizers`): ρ goes to the target where no highlight shows it.
    pub rho_prior: f32,
    /// The roughness of surfaces without a visible specular lobe.
    pub rho_prior_target: f32,
    /// Fraction of the iterations after which the roughness prior acts: glossy surfaces must
    /// first have found their Ks (the prior would hold a still-small Ks's ρ high).
    pub rho_prior_from: f32,
    /// Number of emitters K, found by K-means as in the paper (0 = automatic: one emitter per
    /// connected piece of marked points that passes the tests below; `stage2::emitter_clusters`).
    pub emitters: usize,
    /// At most this many emitters of the automatic choice (the largest pieces).
    pub max_emitters: usize,
    /// Marked points closer than this are one piece, in normalized units (at least three times
    /// their median spacing).
    pub emitter_link: f32,
    /// Connected pieces of emitter points with less than this fraction of them are dropped.
    pub emitter_min_fraction: f32,
    /// Pieces marked in fewer training views than this are dropped (a hole of the SDF one view
    /// looked through, not a light).
    pub emitter_min_views: usize,
    /// Pieces that the emitter masks of the training views which see them mark less often than
    /// this are dropped (F_e above ½ on a highlight or reflection that only some views see).
    pub emitter_mask_agreement: f32,
    /// F_e above this marks an emitter.
    pub emitter_threshold: f32,
    /// Fit to the dataset's HDR images (× its exposure) where it has them, instead of the LDR ones.
    pub use_hdr: bool,
}

impl Default for Stage2Config {
    fn default() -> Self {
        Stage2Config {
            iterations: 1500,
            pixels: 4096,
            estimator: Stage2Estimator::Cached,
            loss: Stage2Loss::L1,
            cache_pixels: 393_216,
            cache_samples: 128,
            refresh_pixels: 0,
            specular_bake: true,
            specular_pool: 0.0,
            specular_pool_radius: 0.03,
            bake_resolution: 256,
            irradiance_radius: 0.024,
            normal_smoothing_radius: 0.03,
            input_normals: true,
            label_unobserved: true,
            fit_bulbs: true,
            fit_panels: true,
            size_bulbs_by_masks: true,
            triangulate_emitters: true,
            samples: 16,
            emitter_sampling: true,
            lr_grid: 1e-2,
            lr_mlp: 5e-3,
            lr_emission: 5e-2,
            emission_from_shading: true,
            lr_final_fraction: 0.1,
            smooth: 0.05,
            energy: 1.0,
            smooth_epsilon: 0.01,
            rho_prior: 0.05,
            rho_prior_target: 0.9,
            rho_prior_from: 0.5,
            emitters: 0,
            max_emitters: 16,
            emitter_link: 0.05,
            emitter_min_fraction: 0.01,
            emitter_min_views: 2,
            emitter_mask_agreement: 0.75,
            emitter_threshold: 0.5,
            use_hdr: true,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainLoop {
    /// Total stage-1 iterations (the three steps are fractions of it). `"auto"`: 2500, or 5000
    /// where the depth is a sensor's (`TrainConfig::resolve`).
    pub iterations: Auto<u64>,
    /// Rays per iteration.
    pub rays: usize,
    /// Bubble points per iteration in the bubble step.
    pub bubble_points: usize,
    /// Points per iteration for the eikonal term (besides the ray samples).
    pub eikonal_points: usize,
    /// Learning rate of the hash grid (or of the whole MLP backbone) and of the MLPs.
    pub lr_grid: f32,
    pub lr_mlp: f32,
    /// Learning rate of log β (the density's sharpness).
    pub lr_beta: f32,
    /// Final learning rate as a fraction of the initial one (cosine decay after the warm-up).
    pub lr_final_fraction: f32,
    /// Learning-rate warm-up iterations (linear ramp).
    pub lr_warmup: u64,
    pub seed: u64,
    /// Write a checkpoint every this many iterations (and at the end).
    pub checkpoint_every: u64,
    /// Stage 1's snapshots for a time-to-quality curve: at each of these seconds of the stage's
    /// wall time (summed over resumed sessions), the fields as they are then go to
    /// `RUN/snapshots/stage1-SECONDSs/`, a run directory `eval --run` scores. Increasing.
    pub snapshot_seconds: Vec<f32>,
    /// Log losses every this many iterations.
    pub log_every: u64,
    /// Worker threads (0 = all cores).
    pub threads: usize,
    /// Operand precision of stage 1's matrix products: `bf16` (bf16 operands, f32 sums, on AMX
    /// tiles: the same quality as `f32` at equal iterations on the default room, 15 % less time),
    /// `bf16x3` (each operand split in two bf16 parts, three products: ~16-bit mantissas, no
    /// faster than f32 at these widths) or `f32`. The half precisions run where the CPU has AMX
    /// (Intel Xeon since Sapphire Rapids) and fall back to f32 elsewhere, said at the start.
    pub matmul_precision: i2sdf_nn::linalg::MatmulPrecision,
}

impl Default for TrainLoop {
    fn default() -> Self {
        TrainLoop {
            // 2500 iterations with the bubble step from 15 % to the end, and faster MLP and β
            // learning rates: the 5000-iteration defaults' quality in half the time (issue 26,
            // docs/results.md "Stage 1 against the clock"); a sensor's depth takes 5000.
            iterations: Auto::AUTO,
            rays: 1024,
            bubble_points: 1024,
            eikonal_points: 1024,
            lr_grid: 1e-2,
            lr_mlp: 1e-2,
            lr_beta: 2e-2,
            lr_final_fraction: 0.1,
            lr_warmup: 100,
            seed: 0,
            checkpoint_every: 500,
            snapshot_seconds: Vec::new(),
            log_every: 10,
            threads: 0,
            matmul_precision: i2sdf_nn::linalg::MatmulPrecision::Bf16,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SamplingConfig {
    /// Samples per ray after error-bounded upsampling.
    pub samples: usize,
    /// Uniform samples of the first pass.
    pub coarse: usize,
    /// Samples each upsampling round adds; unset: `coarse` again, as VolSDF (and every run
    /// written before the key existed).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub upsample: Option<usize>,
    /// Target bound on the opacity error (VolSDF ε).
    pub epsilon: f32,
    /// Empty-space skipping (`i2sdf_model::occupancy`): an occupancy grid of this many cells a
    /// side over the scene's cube, so that the sampler evaluates the SDF in occupied cells only
    /// and ends each ray at its first solid cell (0: off, every ray sampled over its whole span).
    pub occupancy_resolution: usize,
    /// Iterations between rebuilds of the occupancy grid from the SDF being trained.
    pub occupancy_every: u64,
    /// A cell is free or solid when |SDF| at its centre exceeds its half-diagonal plus this many
    /// β (at least one cell): the Laplace density left out in free space is at most e^{−this}/2β.
    pub occupancy_margin: f32,
}

impl Default for SamplingConfig {
    fn default() -> Self {
        SamplingConfig {
            samples: 32,
            // 64, not 32: the first pass's spacing is what the error bound starts from, and at
            // 32 it missed surface. Seed 1, stage 1 with the defaults: test PSNR 32.30 → 33.43,
            // F 0.972 → 0.977, for 7 % more stage-1 time (issue 26). Rendering a coarse-32 run
            // at 64 alone gave 32.61: most of the gain is in training.
            coarse: 64,
            // Half the first pass: the sampler's time from 25 % to 20 % of a step, at 0.7 cm
            // mean depth and 45 dB colour against a dense reference (issue 12).
            upsample: Some(16),
            epsilon: 0.1,
            occupancy_resolution: 0,
            occupancy_every: 16,
            occupancy_margin: 4.0,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AdaptiveConfig {
    /// Error-guided adaptive sampling of bubble points (false: uniform over depth pixels, the
    /// paper's ablation).
    pub enabled: bool,
    /// Pruning threshold P_min on the depth error, in normalized units. The paper's 0.05 is in its
    /// own normalization (scene within radius ~2.5); ours puts the scene in the unit sphere, so
    /// the same physical threshold is about 0.02.
    pub p_min: f32,
    /// Errors are clamped to this before they become probabilities.
    pub p_max: f32,
    /// The fraction of each batch's rays drawn in proportion to the pixels' last colour error
    /// (the rest uniformly; 0: all uniformly), as Instant-NGP's error maps do: at 2.8 visits a
    /// pixel in stage 1, a thin object's few pixels are otherwise seen too rarely to be built
    /// where no depth marks them (a phone's depth grid misses them).
    pub rgb_rays: f32,
}

impl Default for AdaptiveConfig {
    fn default() -> Self {
        AdaptiveConfig {
            enabled: true,
            p_min: 0.02,
            p_max: 1.0,
            rgb_rays: 0.0,
        }
    }
}

/// Whether stage 1 corrects the training views' poses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseCorrectionMode {
    /// On unless the dataset declares its poses exact (`poses_exact: true` in transforms.json;
    /// the built-in rooms and the paper's release do).
    Auto,
    On,
    Off,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PoseConfig {
    pub correction: PoseCorrectionMode,
    /// Adam learning rate of the rotations (radians).
    pub lr_rotation: f32,
    /// Adam learning rate of the translations (normalized units: the scene's bounding sphere
    /// has radius 1).
    pub lr_translation: f32,
    /// Weight λ of the penalty λ(‖ω‖² + ‖τ‖²) that keeps the corrections small.
    pub regularization: f32,
    /// The fraction of stage 1 after which the poses are corrected (the fields first need a
    /// rough scene to align against).
    pub start: f32,
    /// With depth: every how many iterations the views are aligned to the SDF.
    pub align_every: u64,
    /// With depth: Gauss–Newton rounds per alignment (each on fresh depth points, the SDF held).
    pub align_rounds: u32,
    /// With depth: the fraction of each Gauss–Newton step taken (the surface moves under the
    /// poses while both are learned).
    pub align_damping: f32,
    /// With depth: the weight of the photometric rows of the alignment (LDR colour residuals)
    /// against the depth points' (normalized distances): (σ_depth / σ_colour)²; 0 aligns on
    /// depth alone.
    pub photometric_weight: f32,
    /// Pixels per view of each photometric alignment round (drawn among those whose smoothed
    /// image has a gradient).
    pub photometric_points: u32,
    /// With depth and the correction on: the bubble, inside and smoothness points stay where the
    /// depth maps put them at the *given* poses, while the corrected rays render colour and
    /// depth and are aligned. The SDF is then anchored to the capture's own fusion of its depth,
    /// so that it cannot follow the cameras when they drift together (measured, docs/results.md).
    pub pin_points: bool,
    /// With depth: follow the rendering losses' gradient with Adam (`lr_rotation`,
    /// `lr_translation`), as without depth, instead of aligning each view to the SDF
    /// (`align_*`, `photometric_*`: point-to-plane Gauss–Newton, which at full size moved the
    /// capture's cameras 10–20 cm off). Measured on the two rooms' phone captures: rotations
    /// 0.5° → 0.2°, translations 1.0 → 0.9 cm (docs/results.md).
    pub follow_gradient: bool,
}

impl Default for PoseConfig {
    fn default() -> Self {
        PoseConfig {
            // On where the dataset does not declare its poses exact. On the default room's
            // phone capture (0.5° / 1 cm of noise) following the rendering losses' gradient
            // brought the poses to 0.21° / 0.9 cm, the test views +0.5 dB and the mesh's F
            // 0.945 → 0.948 (docs/results.md); every earlier variant moved them away from the
            // truth.
            correction: PoseCorrectionMode::Auto,
            // Rotations move the image most (0.5° is 2.6 cm at 3 m, against 1 cm); translations
            // at the rotations' rate went 1.0 → 1.3 cm off, at a fifth of it 1.0 → 0.9 cm.
            lr_rotation: 5e-5,
            lr_translation: 1e-5,
            regularization: 1e-3,
            start: 0.5,
            align_every: 10,
            align_rounds: 1,
            align_damping: 0.5,
            // Off: measured on the 80×60 room (docs/results.md, "photometric rows"), 0.01 moved
            // exact cameras 0.5° / 3.7 cm when aligning from 20 % of stage 1, and aligned late
            // against a nearly converged SDF it was no closer than depth alone.
            photometric_weight: 0.0,
            photometric_points: 512,
            pin_points: false,
            follow_gradient: true,
        }
    }
}

/// Stage 1's iterations where `train.iterations` is `"auto"`, and where the depth is a sensor's.
const ITERATIONS: u64 = 2500;
const SENSOR_DEPTH_ITERATIONS: u64 = 5000;

impl TrainConfig {
    /// Fills the `"auto"` settings with what the dataset calls for; given values stay. Depth a
    /// sensor measured (depth maps the dataset does not declare exact, `depth_exact`) takes 5000
    /// stage-1 iterations with the eikonal term kept whole in the bubble step: nothing else holds
    /// the SDF to a distance while eq:bubble pulls it to noisy points, and the longer run gives
    /// back the detail the term costs (two phone captures of the built-in room: F 0.951 → 0.956
    /// and 0.938 → 0.956, walls out of their 2.5 cm bias; each change alone did not help;
    /// docs/results.md, thirteenth session). Exact depth (the term halves the thin objects'
    /// recall there) and no depth keep 2500 iterations and the paper's λ1 = 0 in that step.
    /// Returns what it filled for a sensor's depth, as a line for the user.
    pub fn resolve(&mut self, dataset: &Dataset) -> Option<String> {
        let sensor_depth = !dataset.depth_exact
            && dataset
                .frames
                .iter()
                .any(|f| f.split == i2sdf_data::Split::Train && f.depth.is_some());
        let (iterations, bubble_eikonal) = if sensor_depth {
            (SENSOR_DEPTH_ITERATIONS, 1.0)
        } else {
            (ITERATIONS, PAPER_BUBBLE_EIKONAL)
        };
        let mut filled = Vec::new();
        if self.train.iterations.value().is_none() {
            filled.push(format!("train.iterations = {iterations}"));
        }
        if self.schedule.bubble_eikonal.value().is_none() {
            filled.push(format!("schedule.bubble_eikonal = {bubble_eikonal}"));
        }
        self.train.iterations.resolve(iterations);
        self.schedule.bubble_eikonal.resolve(bubble_eikonal);
        (sensor_depth && !filled.is_empty()).then(|| {
            format!(
                "depth a sensor's (not declared exact): {} (\"auto\"; exact depth: {ITERATIONS} and {PAPER_BUBBLE_EIKONAL})",
                filled.join(", ")
            )
        })
    }

    /// Stage 1's iteration total: the resolved `train.iterations` ([`TrainConfig::resolve`];
    /// 2500 where it was never resolved against a dataset).
    pub fn iterations(&self) -> u64 {
        self.train.iterations.or(ITERATIONS)
    }

    /// Reads a TOML file (if given) and applies `key=value` overrides (dotted keys, TOML values;
    /// a value that does not parse as TOML is taken as a string).
    pub fn load(file: Option<&Path>, overrides: &[String]) -> Result<TrainConfig, DataError> {
        let mut table: toml::Table = match file {
            Some(p) => {
                let text = std::fs::read_to_string(p).map_err(|e| DataError::file(p, format!("cannot read: {e}")))?;
                // Deserializing the text (not the parsed table) keeps the line and key of a value
                // of the wrong type in the message.
                if let Err(e) = toml::from_str::<TrainConfig>(&text) {
                    return Err(file_error(p, &text, &e));
                }
                text.parse()
                    .map_err(|e| DataError::file(p, format!("invalid TOML: {e}")))?
            }
            None => toml::Table::new(),
        };
        for o in overrides {
            apply_override(&mut table, o)?;
            // One override at a time, so a value of the wrong type is blamed on its own --set.
            if let Err(e) = toml::Value::Table(table.clone()).try_into::<TrainConfig>() {
                return Err(DataError::invalid(format!("--set {o}: {}", e.message().trim())));
            }
        }
        let config: TrainConfig = toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| DataError::invalid(format!("--set: {}", e.message().trim())))?;
        // Where a value out of range came from, for the message: the file, --set, or both.
        let what = match (file, overrides.is_empty()) {
            (Some(p), true) => p.display().to_string(),
            (Some(p), false) => format!("{} with --set", p.display()),
            (None, _) => "--set".to_string(),
        };
        config.check().map_err(|m| DataError::invalid(format!("{what}: {m}")))?;
        Ok(config)
    }

    /// Checks every key against its allowed range; the message names the key, its value and the
    /// range (the caller prefixes the file or `--set`).
    pub fn validate(&self) -> Result<(), DataError> {
        self.check().map_err(DataError::invalid)
    }

    fn check(&self) -> Result<(), String> {
        use i2sdf_model::config::check::{int, positive, real};
        const MAX_POINTS: usize = 1 << 20;
        let t = &self.train;
        if let Some(n) = t.iterations.value() {
            int("train.iterations", n, 1, 100_000_000)?;
        }
        int("train.rays", t.rays, 1, MAX_POINTS)?;
        int("train.bubble_points", t.bubble_points, 0, MAX_POINTS)?;
        int("train.eikonal_points", t.eikonal_points, 0, MAX_POINTS)?;
        positive("train.lr_grid", t.lr_grid, 1.0)?;
        positive("train.lr_mlp", t.lr_mlp, 1.0)?;
        positive("train.lr_beta", t.lr_beta, 1.0)?;
        positive("train.lr_final_fraction", t.lr_final_fraction, 1.0)?;
        int("train.lr_warmup", t.lr_warmup, 0, 100_000_000)?;
        int("train.checkpoint_every", t.checkpoint_every, 1, 100_000_000)?;
        for (i, &sec) in t.snapshot_seconds.iter().enumerate() {
            if !(sec > 0.0 && sec < 1e7) || (i > 0 && sec <= t.snapshot_seconds[i - 1]) {
                return Err(format!(
                    "train.snapshot_seconds = {:?}: increasing seconds in (0, 1e7)",
                    t.snapshot_seconds
                ));
            }
        }
        int("train.log_every", t.log_every, 1, 100_000_000)?;
        int("train.threads", t.threads, 0, 1024)?;
        let s = &self.sampling;
        int("sampling.samples", s.samples, 2, 1024)?;
        int("sampling.coarse", s.coarse, 2, 1024)?;
        if let Some(u) = s.upsample {
            int("sampling.upsample", u, 1, 1024)?;
        }
        positive("sampling.epsilon", s.epsilon, 10.0)?;
        if s.occupancy_resolution != 0 {
            int("sampling.occupancy_resolution", s.occupancy_resolution, 8, 512)?;
        }
        int("sampling.occupancy_every", s.occupancy_every as usize, 1, 1_000_000)?;
        real("sampling.occupancy_margin", s.occupancy_margin, 0.0, 100.0)?;
        real("maps.depth_noise_distance", self.maps.depth_noise_distance, 0.0, 1e3)?;
        real("maps.depth_noise_sigma", self.maps.depth_noise_sigma, 0.0, 1.0)?;
        real("maps.photo_depth", self.maps.photo_depth, 0.0, 0.99)?;
        real("maps.photo_depth_explained", self.maps.photo_depth_explained, 0.0, 1.0)?;
        let l = &self.loss;
        for (key, v) in [
            ("loss.rgb", l.rgb),
            ("loss.eikonal", l.eikonal),
            ("loss.depth", l.depth),
            ("loss.normal", l.normal),
            ("loss.smooth", l.smooth),
            ("loss.bubble", l.bubble),
            ("loss.emitter", l.emitter),
            ("loss.inside", l.inside),
        ] {
            real(key, v, 0.0, 1e4)?;
        }
        self.schedule.validate().map_err(|m| format!("schedule: {m}"))?;
        let a = &self.adaptive;
        real("adaptive.p_min", a.p_min, 0.0, 1e3)?;
        real("adaptive.p_max", a.p_max, 0.0, 1e3)?;
        real("adaptive.rgb_rays", a.rgb_rays, 0.0, 0.9)?;
        if a.p_max <= a.p_min {
            return Err(format!(
                "adaptive.p_max = {}: must exceed adaptive.p_min = {}",
                a.p_max, a.p_min
            ));
        }
        let s2 = &self.stage2;
        int("stage2.iterations", s2.iterations, 1, 100_000_000)?;
        int("stage2.pixels", s2.pixels, 1, MAX_POINTS)?;
        int("stage2.cache_pixels", s2.cache_pixels, 0, 1 << 26)?;
        int("stage2.cache_samples", s2.cache_samples, 1, 4096)?;
        int("stage2.refresh_pixels", s2.refresh_pixels, 0, MAX_POINTS)?;
        real("stage2.irradiance_radius", s2.irradiance_radius, 0.0, 0.5)?;
        real("stage2.normal_smoothing_radius", s2.normal_smoothing_radius, 0.0, 0.5)?;
        real("stage2.specular_pool", s2.specular_pool, 0.0, 4.0)?;
        real("stage2.specular_pool_radius", s2.specular_pool_radius, 0.0, 0.5)?;
        if s2.refresh_pixels > 0 && s2.irradiance_radius > 0.0 {
            // The pooled diffuse sums come from the samples traced at the start; refreshed
            // samples would leave them stale (and a resumed run could not rebuild them).
            return Err(format!(
                "stage2.refresh_pixels = {} needs stage2.irradiance_radius = 0 (it is {}): pooled irradiance is computed once",
                s2.refresh_pixels, s2.irradiance_radius
            ));
        }
        if s2.refresh_pixels > 0 && s2.specular_bake {
            return Err(format!(
                "stage2.refresh_pixels = {} needs stage2.specular_bake = false: baked pixels keep no samples to replace",
                s2.refresh_pixels
            ));
        }
        if s2.bake_resolution != 0 {
            int("stage2.bake_resolution", s2.bake_resolution, 16, 1024)?;
        }
        int("stage2.samples", s2.samples, 1, 4096)?;
        positive("stage2.lr_grid", s2.lr_grid, 1.0)?;
        positive("stage2.lr_mlp", s2.lr_mlp, 1.0)?;
        positive("stage2.lr_emission", s2.lr_emission, 1.0)?;
        positive("stage2.lr_final_fraction", s2.lr_final_fraction, 1.0)?;
        real("stage2.smooth", s2.smooth, 0.0, 1e4)?;
        real("stage2.energy", s2.energy, 0.0, 1e4)?;
        positive("stage2.smooth_epsilon", s2.smooth_epsilon, 1.0)?;
        real("stage2.rho_prior", s2.rho_prior, 0.0, 1e4)?;
        real("stage2.rho_prior_target", s2.rho_prior_target, 0.0, 1.0)?;
        real("stage2.rho_prior_from", s2.rho_prior_from, 0.0, 1.0)?;
        int("stage2.emitters", s2.emitters, 0, 64)?;
        int("stage2.max_emitters", s2.max_emitters, 1, 64)?;
        positive("stage2.emitter_link", s2.emitter_link, 2.0)?;
        real("stage2.emitter_min_fraction", s2.emitter_min_fraction, 0.0, 0.5)?;
        int("stage2.emitter_min_views", s2.emitter_min_views, 1, 1_000_000)?;
        real("stage2.emitter_mask_agreement", s2.emitter_mask_agreement, 0.0, 1.0)?;
        real("stage2.emitter_threshold", s2.emitter_threshold, 0.0, 1.0)?;
        if s2.cache_pixels as u64 * s2.cache_samples as u64 > 1 << 27 {
            return Err(format!(
                "stage2.cache_pixels × stage2.cache_samples = {} × {}: at most 2^27 cached samples (4 GiB)",
                s2.cache_pixels, s2.cache_samples
            ));
        }
        let p = &self.pose;
        positive("pose.lr_rotation", p.lr_rotation, 1.0)?;
        positive("pose.lr_translation", p.lr_translation, 1.0)?;
        real("pose.regularization", p.regularization, 0.0, 1e4)?;
        real("pose.start", p.start, 0.0, 1.0)?;
        int("pose.align_every", p.align_every, 1, 1_000_000)?;
        int("pose.align_rounds", p.align_rounds, 1, 100)?;
        positive("pose.align_damping", p.align_damping, 1.0)?;
        real("pose.photometric_weight", p.photometric_weight, 0.0, 1e4)?;
        int("pose.photometric_points", p.photometric_points, 0, 1 << 20)?;
        if p.correction == PoseCorrectionMode::On && !matches!(self.model.backbone, Backbone::HashGrid) {
            return Err(
                "pose.correction = \"on\" needs the hash-grid backbone (model.backbone = \"hash_grid\")".into(),
            );
        }
        self.material.check()?;
        self.lobes.check()?;
        self.model.validate()
    }

    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).expect("config serializes")
    }

    /// The configuration reference of the README: every section with its keys and defaults, one
    /// `[section] key = value, …` paragraph each, wrapped at 100 columns (a test keeps the
    /// README's copy equal to this).
    pub fn reference() -> String {
        let table: toml::Table = toml::from_str(&Self::default().to_toml()).expect("config round-trips");
        let mut out = String::new();
        for (section, keys) in &table {
            let Some(keys) = keys.as_table() else { continue };
            let mut line = format!("[{section}]");
            let items: Vec<String> = keys.iter().map(|(k, v)| format!("{k} = {v}")).collect();
            for (i, item) in items.iter().enumerate() {
                let piece = if i + 1 < items.len() {
                    format!(" {item},")
                } else {
                    format!(" {item}")
                };
                if line.len() + piece.len() > 100 {
                    out += line.trim_end();
                    out.push('\n');
                    line = " ".repeat(section.len() + 2);
                }
                line += &piece;
            }
            out += &line;
            out.push('\n');
        }
        out
    }
}

/// A configuration file's parse or type error with the dotted key and line in front (the first
/// line of the message names what is wrong), then toml's own report with the source line.
fn file_error(path: &Path, text: &str, e: &toml::de::Error) -> DataError {
    let report = e.to_string();
    let Some(span) = e.span() else {
        return DataError::file(path, format!("invalid configuration: {}", report.trim()));
    };
    let start = span.start.min(text.len());
    let line_start = text[..start].rfind('\n').map_or(0, |i| i + 1);
    let line_no = text[..line_start].matches('\n').count() + 1;
    let line = text[line_start..].split('\n').next().unwrap_or("");
    // The section is the last `[name]` header above the line; the key what precedes `=`.
    let section = text[..line_start].lines().rev().find_map(|l| {
        l.trim()
            .strip_prefix('[')?
            .split(']')
            .next()
            .map(|s| s.trim().to_string())
    });
    let key = line.split_once('=').map(|(k, _)| k.trim().to_string());
    let what = match (section, key) {
        (Some(s), Some(k)) => format!("{s}.{k} (line {line_no})"),
        (None, Some(k)) => format!("{k} (line {line_no})"),
        _ => format!("line {line_no}"),
    };
    DataError::file(
        path,
        format!(
            "invalid configuration: {what}: {}\n{}",
            e.message().trim(),
            report.trim()
        ),
    )
}

/// Digits with at most a sign, a point and an exponent: a number as a user types one.
fn looks_numeric(value: &str) -> bool {
    value.chars().any(|c| c.is_ascii_digit())
        && value
            .chars()
            .all(|c| c.is_ascii_digit() || matches!(c, '+' | '-' | '.' | '_' | 'e' | 'E'))
}

fn apply_override(table: &mut toml::Table, o: &str) -> Result<(), DataError> {
    let (key, value) = o
        .split_once('=')
        .ok_or_else(|| DataError::invalid(format!("--set {o}: expected key=value")))?;
    let key = key.trim();
    let value = value.trim();
    let parsed: toml::Value = match format!("v = {value}").parse::<toml::Table>() {
        Ok(mut t) => t.remove("v").expect("key v"),
        // What looks like a number but is not one TOML can hold (an integer past 64 bits) is
        // said as such, not passed on as a string for serde to call "invalid type: string".
        Err(_) if looks_numeric(value) => {
            return Err(DataError::invalid(format!(
                "--set {o}: '{value}' is not a number this key can hold (integers must fit in 64 bits)"
            )))
        }
        Err(_) => toml::Value::String(value.to_string()),
    };
    let parts: Vec<&str> = key.split('.').collect();
    if parts.iter().any(|p| p.is_empty()) {
        return Err(DataError::invalid(format!("--set {o}: bad key '{key}'")));
    }
    let mut cur = table;
    for p in &parts[..parts.len() - 1] {
        let entry = cur
            .entry(p.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        cur = entry
            .as_table_mut()
            .ok_or_else(|| DataError::invalid(format!("--set {o}: '{p}' is not a section")))?;
    }
    cur.insert(parts[parts.len() - 1].to_string(), parsed);
    Ok(())
}

#[cfg(test)]
#[path = "config_tests.rs"]
mod tests;
