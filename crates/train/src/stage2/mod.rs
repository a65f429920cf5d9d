//! Stage 2 (paper Sec. "Training", "Training of material and emission fields"): with F_d, F_c
//! and F_e frozen, fit the material fields (Kd, Ks, ρ) and the emissions L\[k\] of the
//! emitters so that the Monte Carlo re-render of eq:render reproduces the training pixels:
//! L₂ = L_render + λ_mat L_mat (eq:material).
//!
//! Frozen geometry means that almost everything the estimator needs is fixed: each training
//! pixel's surface point and normal, and — for directions drawn from a fixed proposal — the
//! secondary hits and what arrives from them (an emitter, or F_c's radiance). They are traced
//! once into a cache ([`Stage2::new`], [`ShadingCache`]: by default each pixel's diffuse sums and
//! its specular sums baked at fixed roughness levels, `surface_cache.rs`); an iteration then
//! costs a material-field forward and backward and the analytic BRDF on the cache. The cached
//! estimator is unbiased for any material: its proposal (cosine + GGX lobes of five roughnesses
//! about the frozen normal + a cone towards each emitter) covers every direction f_r·cos can
//! weigh. The paper's own estimator — N = 16 directions importance-sampled from the current
//! materials' GGX mixture, traced every iteration — is [`crate::config::Stage2Estimator::Live`], the reference
//! the cached fit is checked against.
//!
//! Radiometry (docs/results.md, "Stage 2: emitters and materials"): targets are linear radiance in the units of the
//! input images — LDR pixels linearized by the dataset's transfer, or HDR pixels × the dataset's
//! exposure when `stage2.use_hdr` and the dataset has them. Saturated LDR channels bound the
//! prediction from below only. Pixels that see an emitter are not shaded: their prediction is
//! L\[k\] itself.

use crate::config::{Stage2Estimator, TrainConfig};
use crate::driver::{StepOutcome, TrainStage};
pub mod emission_from_shading;
pub mod emitter_clusters;
mod emitter_setup;
pub mod emitter_triangulation;
pub mod lobe_choice;
pub mod losses;
mod mixture;
mod setup;
pub mod shading;
mod step;
pub mod surface_cache;
pub mod targets;

use emission_from_shading::{estimate_clipped_emission, saturated_emitters};
use glam::Vec3;
use i2sdf_data::{DataError, Radiometry};
use i2sdf_model::emitters::EmitterTable;
use i2sdf_model::intrinsic::{BakedSurface, FrozenScene};
use i2sdf_model::intrinsic_io::IntrinsicFields;
use i2sdf_model::material_field::{
    brdf_of_channels, MaterialBackbone, MaterialField, MaterialGrad, MaterialWorkspace, MATERIAL_CHANNELS,
};
use i2sdf_model::observed::ObservedViews;
use i2sdf_model::{BakeRecord, NeuralScene};
use i2sdf_nn::params::ModuleSlot;
use i2sdf_nn::{Adam, AdamConfig, LrSchedule, Parameters};
use i2sdf_render::GgxBrdf;
use lobe_choice::{feature, FitRole, LobeChoice};
pub use mixture::{cache_mixture, live_mixture};
use rand::{Rng, SeedableRng};
use rand_pcg::{Pcg32, Pcg64};
use rayon::prelude::*;
use serde::Serialize;
use shading::{pool_diffuse, trace_incident, IncidentSample, ShadingPoint};
use std::path::Path;
use std::sync::Arc;
use surface_cache::ShadingCache;
pub use targets::{radiometry, target_views, TargetView, SATURATED};

/// The distance (normalized units) at which `stage2.specular_pool` takes an offset between two
/// pixels as an angle: about what a lobe reflects in a room (half its normalized extent).
const SPECULAR_POOL_PARALLAX: f32 = 0.5;

/// What a cached pixel sees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PixelKind {
    /// An ordinary surface: the `index`-th of the cache ([`ShadingCache`]).
    Surface { index: u32 },
    /// Emitter k, seen directly: its prediction is L\[k\].
    Emitter(u32),
}

#[derive(Clone, Copy, Debug)]
pub struct CachedPixel {
    pub point: ShadingPoint,
    pub target: Vec3,
    pub saturated: u8,
    pub kind: PixelKind,
    /// Training view (index into the views given) and pixel (row-major).
    pub view: u32,
    pub pixel: u32,
}

/// Per-iteration statistics (one JSON object of the log).
#[derive(Clone, Debug, Default, Serialize)]
pub struct Stage2Stats {
    pub iteration: u64,
    /// Mean L1 of the re-render (per channel) over the batch's surface pixels.
    pub render: f32,
    /// Mean L1 of the emitter pixels.
    pub emitter: f32,
    pub smooth: f32,
    pub energy: f32,
    pub rho_prior: f32,
    /// The forced lobes' terms (`[lobes]`; 0 in a fit without them).
    pub lobe: f32,
    /// Which fit of the stage (`[lobes]`: each forced lobe, the defaults, then the last).
    pub fit: u64,
    pub loss: f32,
    /// L\[k\] (linear RGB, image units).
    pub emission: Vec<[f32; 3]>,
}

/// The stage-2 trainer.
pub struct Stage2 {
    pub config: TrainConfig,
    pub scene: NeuralScene,
    pub fields: IntrinsicFields,
    pub pixels: Vec<CachedPixel>,
    pub cache: ShadingCache,
    adam: Adam,
    grad: MaterialGrad,
    d_emission: Vec<Vec3>,
    /// Emitters whose L[k] is held (`stage2.emission_from_shading`): the images saw them only
    /// clipped, so the re-render cannot tell L[k] from Kd (see `emission_from_shading`).
    held_emission: Vec<bool>,
    ws: MaterialWorkspace,
    iteration: u64,
    /// K chosen by the clustering (before small clusters were dropped), for the log.
    pub chosen_k: usize,
    /// log L[k] as initialised from the images (for [`Stage2::restart`]).
    initial_emission: Vec<f32>,
    /// Index in `pixels` of each surface pixel, in cache order.
    surface: Vec<u32>,
    /// Where the frozen surface was baked for ray casting (`stage2.bake_resolution` over the box
    /// of what the training pixels see and the cameras), kept in the checkpoint so that every
    /// command on the run casts the same surface ([`i2sdf_model::OpenedRun::frozen`]).
    pub bake: Option<BakeRecord>,
    /// The frozen surface baked there.
    baked: Option<Arc<BakedSurface>>,
    /// What the training cameras see (`stage2.label_unobserved`): the emitter labels of traced
    /// hits ([`FrozenScene::observed`]).
    observed: Option<Arc<ObservedViews>>,
    /// The mean surface target ([`crate::config::Stage2Loss::L2`]'s scale).
    target_scale: f32,
    /// The choice of a specular lobe per material segment (`[lobes]`; none when off or with the
    /// live estimator, which has no cache to score the fits on).
    lobes: Option<LobeChoice>,
}

/// The surface pixels (cache order) whose samples iteration `it` re-traces: `count` draws of the
/// iteration's own stream, so a resumed run can tell which samples each pixel had.
fn refresh_selection(seed: u64, it: u64, surface: usize, count: usize) -> Vec<u32> {
    if surface == 0 || count == 0 {
        return Vec::new();
    }
    let mut rng = Pcg64::seed_from_u64(seed ^ 0x5245_4652 ^ it.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    (0..count.min(surface))
        .map(|_| rng.gen_range(0..surface as u32))
        .collect()
}

/// The optimizer of a fit: `stage2`'s learning rates × `lr_factor`.
fn new_adam(config: &TrainConfig, material: &MaterialField, emitters: &EmitterTable, lr_factor: f32) -> Adam {
    let c2 = &config.stage2;
    let mut adam = Adam::new(AdamConfig::default());
    let schedule = LrSchedule::WarmupCosine {
        warmup: 50.min(c2.iterations / 10),
        total: c2.iterations,
        min_factor: c2.lr_final_fraction,
    };
    if let Some(g) = &material.grid {
        adam.add_group(GROUP_GRID, g.params.len(), c2.lr_grid * lr_factor, schedule);
    }
    adam.add_group(GROUP_MLP, material.mlp.params.len(), c2.lr_mlp * lr_factor, schedule);
    adam.add_group(
        GROUP_EMISSION,
        emitters.log_emission.len(),
        c2.lr_emission * lr_factor,
        schedule,
    );
    adam
}

const GROUP_GRID: &str = "material_grid";
const GROUP_MLP: &str = "material_mlp";
const GROUP_EMISSION: &str = "emission";

/// The checkpoint tensors of the lobe choice: under the optimizer's prefix, as trainer state
/// that the loaders of the fields (`eval`, `render`, …) skip.
const LOBES_PREFIX: &str = "adam.lobes";

/// The choice of a lobe per segment that `config` asks for, over `pixels` cached pixels.
fn lobe_choice_for(config: &TrainConfig, pixels: usize) -> Option<LobeChoice> {
    (total_iterations(config) > config.stage2.iterations).then(|| LobeChoice::new(config.lobes.clone(), pixels))
}

/// Stage 2's iterations in all: `stage2.iterations` for each fit (`[lobes]`).
pub fn total_iterations(config: &TrainConfig) -> u64 {
    let fits = match config.stage2.estimator {
        Stage2Estimator::Cached => config.lobes.fits(),
        Stage2Estimator::Live => 1,
    };
    config.stage2.iterations * fits
}

/// World → normalized frame.
fn normalized(scene: &NeuralScene, p: Vec3) -> [f32; 3] {
    let n = &scene.normalization;
    let c = Vec3::from_array(n.center.map(|v| v as f32));
    ((p - c) / n.scale as f32).to_array()
}

/// A pixel's own sampler (deterministic whatever the batch or thread).
fn pixel_rng(seed: u64, index: u64, salt: u64) -> Pcg32 {
    Pcg32::seed_from_u64(seed ^ index.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ salt.wrapping_mul(0xD1B5_4A32_D192_ED03))
}

impl Stage2 {
    /// Builds the cache from the frozen `scene` and the training `views`: casts the pixels, clusters
    /// the emitter points into K emitters (or takes `emitters` as given: a resumed run), traces the
    /// incident radiance of every surface pixel. `progress` hears what is being done.
    pub fn new(
        config: TrainConfig,
        scene: NeuralScene,
        views: &[TargetView],
        radiometry: Radiometry,
        given: Option<(MaterialField, EmitterTable)>,
        progress: &dyn Fn(&str),
    ) -> Result<Stage2, DataError> {
        Self::build(config, scene, views, radiometry, given, 0, progress)
    }

    /// [`Stage2::new`] for a run at iteration `resume_at`: each cached pixel's samples are the ones
    /// it had then (its initial ones, or those of its last refresh before `resume_at`).
    fn build(
        config: TrainConfig,
        scene: NeuralScene,
        views: &[TargetView],
        radiometry: Radiometry,
        given: Option<(MaterialField, EmitterTable)>,
        resume_at: u64,
        progress: &dyn Fn(&str),
    ) -> Result<Stage2, DataError> {
        let c2 = config.stage2.clone();
        let seed = config.train.seed;
        // 1. The pixels, cast into the frozen SDF; the surface baked for the secondary rays.
        let mut rng = Pcg64::seed_from_u64(seed ^ 0x5747_4532);
        let cast = setup::cast_training_pixels(&scene, views, radiometry, &c2, &mut rng, progress)?;
        let scale = scene.normalization.scale as f32;
        let bake = setup::bake_record(&cast.points, views, &c2, scale);
        let baked = match &bake {
            Some(b) => {
                progress(&format!("baking the frozen surface at {}³", b.resolution));
                Some(b.bake(&scene)?)
            }
            None => None,
        };
        // 2. Emitters: the surface points F_e marks, clustered (or a resumed run's).
        let fresh = given.is_none();
        let (material, emitters, chosen_k) = match given {
            Some((m, e)) => {
                let k = e.len();
                (m, e, k)
            }
            None => {
                let (emitters, k) =
                    emitter_setup::cluster_new_emitters(&scene, views, radiometry, &cast, &c2, &mut rng, progress);
                let material = MaterialField::new(&config.material, scene.feature_dim(), seed.wrapping_add(17));
                (material, emitters, k)
            }
        };
        // 3. Pixel kinds: emitters by the mask where the dataset has one, else by F_e.
        let observers: Option<Vec<_>> = c2
            .label_unobserved
            .then(|| views.iter().map(|v| v.camera.clone()).collect());
        if observers.is_some() && !emitters.is_empty() {
            progress("finding what the training cameras see (emitter labels of unseen surfaces)");
        }
        let frozen = FrozenScene::labelled(
            &scene,
            &emitters,
            radiometry,
            c2.emitter_threshold,
            baked.clone(),
            observers.as_deref(),
        );
        let observed = frozen.observed.clone();
        let mut cast = cast;
        let on_sphere = setup::recast_through_bulbs(&frozen, &mut cast);
        let pixels = setup::label_pixels(
            &cast,
            &on_sphere,
            views,
            &c2,
            &emitters,
            frozen.index_margin,
            scale,
            frozen.smoothed_normals(),
            progress,
        );
        // 4. Incident radiance of every surface pixel, traced once.
        let (mut cache, own, surface) = setup::trace_cache(&frozen, &pixels, &c2, seed, resume_at, progress);
        drop(frozen);
        let surface_points: Vec<ShadingPoint> = surface.iter().map(|&i| pixels[i as usize].point).collect();
        if let Some(bake) = cache
            .bake
            .as_mut()
            .filter(|_| c2.specular_pool > 0.0 && c2.specular_pool_radius > 0.0)
        {
            progress("pooling the specular sums of pixels that reflect alike");
            *bake = bake.pooled(
                &surface_points,
                c2.specular_pool_radius * scale,
                c2.specular_pool,
                SPECULAR_POOL_PARALLAX * scale,
            );
        }
        let pooled = (c2.irradiance_radius > 0.0).then(|| {
            progress("pooling the diffuse irradiance of nearby pixels");
            pool_diffuse(&surface_points, &own, c2.irradiance_radius * scale)
        });
        // 5. The emission of lights the images saw only clipped, from the light they throw.
        let held_emission = saturated_emitters(&pixels, emitters.len());
        let mut emitters = emitters;
        if fresh && c2.emission_from_shading && held_emission.contains(&true) {
            let widths: Vec<usize> = views.iter().map(|v| v.camera.width).collect();
            let sums = pooled.as_ref().unwrap_or(&own);
            emitters = estimate_clipped_emission(&pixels, sums, &widths, &emitters, &held_emission, progress);
        }
        cache.diffuse = match pooled {
            Some(p) => p,
            None if cache.bake.is_some() => own,
            None => Vec::new(),
        };
        let k = emitters.len();
        let lobes = lobe_choice_for(&config, pixels.len());
        Ok(Stage2 {
            adam: new_adam(&config, &material, &emitters, 1.0),
            grad: material.new_grad(),
            initial_emission: emitters.log_emission.clone(),
            target_scale: setup::mean_surface_target(&pixels),
            held_emission: if c2.emission_from_shading {
                held_emission
            } else {
                vec![false; k]
            },
            config,
            scene,
            fields: IntrinsicFields {
                material,
                emitters,
                radiometry,
            },
            pixels,
            cache,
            d_emission: vec![Vec3::ZERO; k],
            ws: MaterialWorkspace::default(),
            iteration: 0,
            chosen_k,
            surface,
            bake,
            baked,
            observed,
            lobes,
        })
    }

    /// Starts the fit over on the same cache with another configuration (its `[stage2]` loop
    /// and loss settings and its `[material]` section): fresh material fields, the initial
    /// emissions, a fresh optimizer. For ablations and tests: the cache is the expensive part.
    pub fn restart(&mut self, config: TrainConfig) {
        self.lobes = lobe_choice_for(&config, self.pixels.len());
        self.config = config;
        self.iteration = 0;
        self.fresh_fit();
    }

    /// Fresh material fields, the initial emissions and a fresh optimizer (a fit's start).
    fn fresh_fit(&mut self) {
        let config = &self.config;
        self.fields.material = MaterialField::new(
            &config.material,
            self.scene.feature_dim(),
            config.train.seed.wrapping_add(17),
        );
        self.fields.emitters.log_emission = self.initial_emission.clone();
        self.adam = new_adam(config, &self.fields.material, &self.fields.emitters, 1.0);
        self.grad = self.fields.material.new_grad();
    }

    /// The fit (`[lobes]`) that iteration `it` belongs to, and its iteration within it.
    fn fit_of(&self, it: u64) -> (usize, u64) {
        let n = self.config.stage2.iterations;
        match self.lobes {
            Some(_) => ((it / n) as usize, it % n),
            None => (0, it),
        }
    }

    /// Ends fit `fit` of the choice (`[lobes]`): scores it on every cached surface pixel. A forced
    /// fit's score is kept and the next fit starts afresh; at the end of the defaults' fit the
    /// choice is made and the last fit continues its field with a fresh optimizer at
    /// `lobes.last_lr` of the learning rates.
    fn end_fit(&mut self, fit: usize) {
        let Some(mut lobes) = self.lobes.take() else { return };
        let (l1, m) = self.surface_scores();
        let forced = match lobes.role(fit) {
            FitRole::Forced(i) => {
                lobes.record_forced(i, &self.surface, &l1);
                true
            }
            // The last fit never ends here (the stage does).
            FitRole::Defaults | FitRole::Last => {
                let features = self.surface_features(&m);
                lobes.choose_segments(&self.surface, &features, &m, &l1, self.config.train.seed);
                false
            }
        };
        self.lobes = Some(lobes);
        if forced {
            self.fresh_fit();
        } else {
            self.adam = self.fit_adam(fit + 1);
        }
    }

    /// A fresh optimizer for fit `fit`: the last fit of a choice (`[lobes]`) runs at
    /// `lobes.last_lr` of the learning rates.
    fn fit_adam(&self, fit: usize) -> Adam {
        let lr = match &self.lobes {
            Some(l) if l.role(fit) == FitRole::Last => l.config.last_lr,
            _ => 1.0,
        };
        new_adam(&self.config, &self.fields.material, &self.fields.emitters, lr)
    }

    /// The current fit on every cached surface pixel, in cache order: the L1 of its re-render
    /// (mean over RGB), and its materials there (`MATERIAL_CHANNELS` each).
    pub fn surface_scores(&self) -> (Vec<f32>, Vec<f32>) {
        let world: Vec<Vec3> = self
            .surface
            .iter()
            .map(|&i| self.pixels[i as usize].point.position)
            .collect();
        let m = self.materials_at(&world);
        let emission = self.emissions();
        let l1 = self
            .surface
            .par_iter()
            .zip(m.par_chunks_exact(MATERIAL_CHANNELS))
            .enumerate()
            .map(|(j, (&i, o))| {
                let px = &self.pixels[i as usize];
                let nv = px.point.normal.dot(px.point.view);
                (self.cache.shade(j, &brdf_of_channels(o), nv, &emission) - px.target)
                    .abs()
                    .element_sum()
                    / 3.0
            })
            .collect();
        (l1, m)
    }

    /// The segmentation feature ([`lobe_choice::feature`]) of every cached surface pixel (cache
    /// order) under `materials` there (as [`Stage2::surface_scores`] gives them).
    pub fn surface_features(&self, materials: &[f32]) -> Vec<[f32; lobe_choice::FEATURES]> {
        self.surface
            .iter()
            .zip(materials.chunks_exact(MATERIAL_CHANNELS))
            .map(|(&i, o)| {
                let p = &self.pixels[i as usize].point;
                feature(o, p.normal, normalized(&self.scene, p.position))
            })
            .collect()
    }

    /// The choice of a lobe per material segment, where `[lobes]` asks for one.
    pub fn lobes(&self) -> Option<&LobeChoice> {
        self.lobes.as_ref()
    }

    /// A world point in the scene's normalized frame.
    pub fn normalized(&self, p: Vec3) -> [f32; 3] {
        normalized(&self.scene, p)
    }

    /// The materials (`MATERIAL_CHANNELS` each) of the current fit at world points.
    pub fn materials_at(&self, world: &[Vec3]) -> Vec<f32> {
        let (positions, features) = self.material_inputs(world);
        let mut out = vec![0.0; world.len() * MATERIAL_CHANNELS];
        self.fields.material.infer(&positions, &features, &mut out);
        out
    }

    /// Resumes from a stage-2 checkpoint: fields, emitters, optimizer state and iteration; the
    /// cache is rebuilt (it is deterministic given the seed).
    pub fn resume(
        config: TrainConfig,
        scene: NeuralScene,
        views: &[TargetView],
        radiometry: Radiometry,
        checkpoint: &Path,
        progress: &dyn Fn(&str),
    ) -> Result<Stage2, DataError> {
        let (fields, meta0) = IntrinsicFields::load(checkpoint, scene.feature_dim(), &mut [])?;
        let at: u64 = meta0
            .get("iteration")
            .and_then(|v| v.parse().ok())
            .ok_or_else(|| DataError::field(checkpoint, "iteration", "missing or not an integer"))?;
        if fields.material.config != config.material {
            return Err(DataError::invalid(format!(
                "{}: the checkpoint's [material] configuration differs from the run's",
                checkpoint.display()
            )));
        }
        let mut s = Self::build(
            config,
            scene,
            views,
            radiometry,
            Some((fields.material, fields.emitters)),
            at,
            progress,
        )?;
        // The optimizer of the fit the run stopped in (its moments come from the checkpoint).
        s.adam = s.fit_adam(s.fit_of(at).0);
        let (mut loaded, meta) = {
            let Stage2 { adam, scene, lobes, .. } = &mut s;
            let mut slots = vec![ModuleSlot {
                prefix: "adam",
                module: adam as &mut dyn Parameters,
                required: true,
            }];
            if let Some(l) = lobes {
                slots.push(ModuleSlot {
                    prefix: LOBES_PREFIX,
                    module: l as &mut dyn Parameters,
                    required: true,
                });
            }
            IntrinsicFields::load(checkpoint, scene.feature_dim(), &mut slots)?
        };
        // The checkpoint's fields again (the load above filled the optimizer from the same file).
        std::mem::swap(&mut s.fields.material, &mut loaded.material);
        std::mem::swap(&mut s.fields.emitters, &mut loaded.emitters);
        let get = |k: &str| -> Result<u64, DataError> {
            meta.get(k)
                .and_then(|v| v.parse().ok())
                .ok_or_else(|| DataError::field(checkpoint, k, "missing or not an integer"))
        };
        s.iteration = get("iteration")?;
        s.adam.step = get("adam_step")?;
        Ok(s)
    }

    /// The frozen scene with the trainer's emitters, threshold and baked surface.
    pub fn frozen(&self) -> FrozenScene<'_> {
        let mut f = FrozenScene::new(&self.scene, &self.fields.emitters, self.fields.radiometry);
        f.emitter_threshold = self.config.stage2.emitter_threshold;
        f.set_baked_surface(self.baked.clone());
        f.observed = self.observed.clone();
        f
    }

    /// Surface and emitter pixels of the cache.
    pub fn counts(&self) -> (usize, usize) {
        let s = self
            .pixels
            .iter()
            .filter(|p| matches!(p.kind, PixelKind::Surface { .. }))
            .count();
        (s, self.pixels.len() - s)
    }

    /// L\[k\] of each emitter, in linear image units.
    pub fn emissions(&self) -> Vec<Vec3> {
        (0..self.fields.emitters.len())
            .map(|k| self.fields.emitters.emission(k))
            .collect()
    }

    /// What the material field reads at world points: their normalized positions and, for the
    /// FeatureMlp backbone, their z.
    fn material_inputs(&self, world: &[Vec3]) -> (Vec<f32>, Vec<f32>) {
        let positions: Vec<f32> = world.iter().flat_map(|p| normalized(&self.scene, *p)).collect();
        let features = match self.fields.material.config.backbone {
            MaterialBackbone::FeatureMlp => {
                let mut z = vec![0.0; world.len() * self.scene.feature_dim()];
                self.frozen().features(world, &mut z);
                z
            }
            MaterialBackbone::HashGrid => Vec::new(),
        };
        (positions, features)
    }

    /// Material of `n` world points in one forward (kept for the backward).
    fn material_forward(&mut self, world: &[Vec3], out: &mut [f32]) {
        let (positions, features) = self.material_inputs(world);
        self.fields.material.forward(&positions, &features, &mut self.ws, out);
    }

    /// The samples of surface pixel `i` for this step: the cache's, or freshly traced (live).
    fn live_samples(&self, batch: &[usize], brdfs: &[GgxBrdf], rng: &mut Pcg64) -> Vec<IncidentSample> {
        let c2 = &self.config.stage2;
        let frozen = self.frozen();
        let pts: Vec<ShadingPoint> = batch.iter().map(|&i| self.pixels[i].point).collect();
        let mut rngs: Vec<Pcg32> = batch.iter().map(|_| Pcg32::seed_from_u64(rng.gen())).collect();
        let emitters = &self.fields.emitters;
        trace_incident(
            &frozen,
            &pts,
            c2.samples,
            self.scene.normalization.scale as f32,
            &|j| live_mixture(&brdfs[j], emitters, c2.emitter_sampling),
            &mut rngs,
        )
    }
}

impl TrainStage for Stage2 {
    type Stats = Stage2Stats;
    fn key(&self) -> &'static str {
        "stage2"
    }
    fn iteration(&self) -> u64 {
        self.iteration
    }
    fn total(&self) -> u64 {
        total_iterations(&self.config)
    }
    fn pending_pause(&self) -> Option<&'static str> {
        let (fit, local) = self.fit_of(self.iteration);
        (self.lobes.is_some() && fit > 0 && local == 0)
            .then_some("scoring the fit on every training pixel (the choice of a specular lobe per material)")
    }
    fn seed(&self) -> u64 {
        self.config.train.seed ^ 0x5354_4147_4532
    }

    fn step(&mut self, rng: &mut Pcg64) -> Result<StepOutcome<Stage2Stats>, DataError> {
        self.step_with(rng)
    }

    fn is_finite(&self) -> bool {
        self.fields.material.mlp.params.iter().all(|v| v.is_finite())
            && self
                .fields
                .material
                .grid
                .as_ref()
                .is_none_or(|g| g.params.iter().all(|v| v.is_finite()))
            && self.fields.emitters.log_emission.iter().all(|v| v.is_finite())
    }

    fn write_checkpoint(&self, path: &Path) -> Result<(), DataError> {
        let mut meta = vec![
            ("iteration", self.iteration.to_string()),
            ("adam_step", self.adam.step.to_string()),
            ("chosen_k", self.chosen_k.to_string()),
            BakeRecord::meta(self.bake.as_ref()),
        ];
        let mut extra = vec![("adam", &self.adam as &dyn Parameters)];
        if let Some(l) = &self.lobes {
            meta.push(("lobes", l.summary()));
            extra.push((LOBES_PREFIX, l as &dyn Parameters));
        }
        self.fields.save(path, &meta, &extra)
    }
}
