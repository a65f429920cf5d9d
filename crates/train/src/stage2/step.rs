//! One iteration of stage 2 (eq:train2 = L_render + λ_mat L_mat, eq:material): refresh a few
//! pixels' cached samples, draw a batch of pixels and their ε-neighbours through the material
//! field, re-render the surface pixels (eq:render, cached or live) and compare the emitter pixels
//! with L\[k\], add the material regularizers, then backpropagate into the material field and the
//! emissions (held lights excepted) and take an Adam step.

use super::losses::{lobe_terms, material_regularizers, rerender_channel, MaterialPriors};
use super::shading::{shade, shade_backward, trace_incident, IncidentSample, ShadingPoint};
use super::surface_cache::ShadingCache;
use super::{cache_mixture, pixel_rng, refresh_selection, CachedPixel, PixelKind, Stage2, Stage2Stats};
use super::{GROUP_EMISSION, GROUP_GRID, GROUP_MLP};
use crate::config::{Stage2Estimator, Stage2Loss};
use crate::driver::StepOutcome;
use glam::Vec3;
use i2sdf_data::DataError;
use i2sdf_model::material_field::{brdf_of_channels, MATERIAL_CHANNELS};
use i2sdf_render::GgxBrdf;
use rand::Rng;
use rand_pcg::{Pcg32, Pcg64};
use rayon::prelude::*;

/// Batch pixels per parallel task of the re-render terms (each task reduces its own emission
/// gradients, summed after in task order, so the result does not depend on the thread count).
const PIXELS_PER_TASK: usize = 256;

/// What every batch pixel's re-render or emitter term reads.
struct TermInputs<'a> {
    pixels: &'a [CachedPixel],
    cache: &'a ShadingCache,
    held: &'a [bool],
    batch: &'a [usize],
    brdfs: &'a [GgxBrdf],
    /// The live estimator's samples, `samples` per batch pixel (`None`: the cache shades).
    live: Option<&'a [IncidentSample]>,
    samples: usize,
    emission: &'a [Vec3],
    loss: Stage2Loss,
    scale: f32,
    /// The batch's surface and emitter pixel counts (at least 1): each term is their mean.
    n_surface: f32,
    n_emitter: f32,
}

/// The loss terms of one batch.
struct BatchTerms {
    render: f32,
    emitter: f32,
    smooth: f32,
    energy: f32,
    rho_prior: f32,
    lobe: f32,
    loss: f32,
}

impl Stage2 {
    /// One iteration with the iteration's RNG. A non-finite loss or gradient changes nothing.
    pub(super) fn step_with(&mut self, rng: &mut Pcg64) -> Result<StepOutcome<Stage2Stats>, DataError> {
        let c2 = self.config.stage2.clone();
        let it = self.iteration;
        // `[lobes]`: a new fit starts where the last one ends (its score kept for the choice).
        let (fit, local) = self.fit_of(it);
        if local == 0 && fit > 0 {
            self.end_fit(fit - 1);
        }
        self.iteration += 1;
        let b = c2.pixels.min(self.pixels.len().max(1));
        if self.pixels.is_empty() {
            return Err(DataError::failed("stage 2: no training pixel hits the frozen surface"));
        }
        self.refresh_cache(it);
        let batch: Vec<usize> = (0..b).map(|_| rng.gen_range(0..self.pixels.len())).collect();
        let out = self.batch_materials(&batch, rng);
        let brdfs: Vec<GgxBrdf> = out[..b * MATERIAL_CHANNELS]
            .chunks_exact(MATERIAL_CHANNELS)
            .map(brdf_of_channels)
            .collect();
        let live = match c2.estimator {
            Stage2Estimator::Live => Some(self.live_samples(&batch, &brdfs, rng)),
            Stage2Estimator::Cached => None,
        };
        let emission = self.emissions();
        let mut d_out = vec![0.0f32; 2 * b * MATERIAL_CHANNELS];
        let (render, emitter) = self.rerender_terms(&batch, &brdfs, live.as_deref(), &emission, &mut d_out);
        // eq:material (smoothness and energy) and the roughness prior, which acts late in the fit.
        let late = local as f32 >= c2.rho_prior_from * c2.iterations as f32;
        let priors = MaterialPriors {
            smooth: c2.smooth,
            energy: c2.energy,
            rho_prior: if late { c2.rho_prior } else { 0.0 },
            rho_target: c2.rho_prior_target,
        };
        let [smooth, energy, rho_prior] = material_regularizers(&out, b, &priors, &mut d_out);
        let (lobe, lobe_weight) = match &self.lobes {
            Some(l) => {
                let targets = l.batch_targets(fit, &batch);
                let c = &l.config;
                (lobe_terms(&out, b, &targets, c.ks_min, c.weight, &mut d_out), c.weight)
            }
            None => (0.0, 0.0),
        };
        let terms = BatchTerms {
            render,
            emitter,
            smooth,
            energy,
            rho_prior,
            lobe,
            loss: render
                + emitter
                + c2.smooth * smooth
                + c2.energy * energy
                + priors.rho_prior * rho_prior
                + lobe_weight * lobe,
        };
        let finite = terms.loss.is_finite()
            && d_out.iter().all(|v| v.is_finite())
            && self.d_emission.iter().all(|v| v.is_finite());
        let finite = finite && self.update(&d_out, &emission);
        Ok(StepOutcome {
            stats: self.stats(it, fit as u64, &terms),
            finite,
        })
    }

    /// Re-traces some pixels' samples (FIPT's "now and then", every iteration for a few): over
    /// the run each pixel sees several independent sample sets, so the fit averages the
    /// estimator's noise away instead of baking one draw into the materials.
    fn refresh_cache(&mut self, it: u64) {
        let c2 = &self.config.stage2;
        let seed = self.config.train.seed;
        let refresh = refresh_selection(seed, it, self.surface.len(), c2.refresh_pixels);
        if refresh.is_empty() {
            return;
        }
        let frozen = self.frozen();
        let pts: Vec<ShadingPoint> = refresh
            .iter()
            .map(|&j| self.pixels[self.surface[j as usize] as usize].point)
            .collect();
        let mut rngs: Vec<Pcg32> = refresh
            .iter()
            .map(|&j| pixel_rng(seed, self.surface[j as usize] as u64, it + 2))
            .collect();
        let mixture = cache_mixture(&self.fields.emitters, c2.emitter_sampling);
        let m = c2.cache_samples;
        let fresh = trace_incident(
            &frozen,
            &pts,
            m,
            self.scene.normalization.scale as f32,
            &|_| mixture,
            &mut rngs,
        );
        for (k, &j) in refresh.iter().enumerate() {
            let first = j as usize * m;
            self.cache.samples[first..first + m].copy_from_slice(&fresh[k * m..(k + 1) * m]);
        }
    }

    /// The material field at the batch's points x and at x + ε (the smoothness term of
    /// eq:material), in one forward: `2·b` rows of [`MATERIAL_CHANNELS`].
    fn batch_materials(&mut self, batch: &[usize], rng: &mut Pcg64) -> Vec<f32> {
        let b = batch.len();
        let eps = self.config.stage2.smooth_epsilon * self.scene.normalization.scale as f32;
        let mut world: Vec<Vec3> = batch.iter().map(|&i| self.pixels[i].point.position).collect();
        for j in 0..b {
            let d = Vec3::new(rng.gen::<f32>() - 0.5, rng.gen::<f32>() - 0.5, rng.gen::<f32>() - 0.5);
            world.push(world[j] + d.normalize_or_zero() * eps);
        }
        let mut out = vec![0.0f32; 2 * b * MATERIAL_CHANNELS];
        self.material_forward(&world, &mut out);
        out
    }

    /// The re-render term (surface pixels) and the emitter term (emitter pixels not held), as
    /// means over their pixels, pixel-parallel. Their gradients go into the first `b` rows of
    /// `d_out` (materials) and into `self.d_emission`.
    fn rerender_terms(
        &mut self,
        batch: &[usize],
        brdfs: &[GgxBrdf],
        live: Option<&[IncidentSample]>,
        emission: &[Vec3],
        d_out: &mut [f32],
    ) -> (f32, f32) {
        let b = batch.len();
        let n_surface = batch
            .iter()
            .filter(|&&i| matches!(self.pixels[i].kind, PixelKind::Surface { .. }))
            .count()
            .max(1) as f32;
        let n_emitter = (b as f32 - n_surface).max(1.0);
        let inputs = TermInputs {
            pixels: &self.pixels,
            cache: &self.cache,
            held: &self.held_emission,
            batch,
            brdfs,
            live,
            samples: self.config.stage2.samples,
            emission,
            loss: self.config.stage2.loss,
            scale: self.target_scale,
            n_surface,
            n_emitter,
        };
        let k = emission.len();
        let parts: Vec<(f32, f32, Vec<Vec3>)> = d_out[..b * MATERIAL_CHANNELS]
            .par_chunks_mut(MATERIAL_CHANNELS * PIXELS_PER_TASK)
            .enumerate()
            .map(|(chunk, d)| {
                let (mut render, mut emit) = (0.0f32, 0.0f32);
                let mut d_em = vec![Vec3::ZERO; k];
                for (jj, dj) in d.chunks_exact_mut(MATERIAL_CHANNELS).enumerate() {
                    inputs.pixel_terms(chunk * PIXELS_PER_TASK + jj, dj, &mut d_em, &mut render, &mut emit);
                }
                (render, emit, d_em)
            })
            .collect();
        let (mut render, mut emit) = (0.0, 0.0);
        self.d_emission.iter_mut().for_each(|d| *d = Vec3::ZERO);
        for (r, e, d) in parts {
            render += r;
            emit += e;
            for (a, b) in self.d_emission.iter_mut().zip(d) {
                *a += b;
            }
        }
        (render / (3.0 * n_surface), emit / (3.0 * n_emitter))
    }

    /// Backpropagates `d_out` into the material field and takes the Adam step of the material
    /// field and the emissions (held lights' gradients zeroed). False, with every parameter and
    /// moment left as it was, when a parameter gradient is not finite.
    fn update(&mut self, d_out: &[f32], emission: &[Vec3]) -> bool {
        self.fields.material.backward(&mut self.ws, d_out, &mut self.grad);
        // L = exp(raw): dL/draw = dL/dL · L.
        let mut d_raw: Vec<f32> = self
            .d_emission
            .iter()
            .zip(emission)
            .flat_map(|(d, l)| (*d * *l).to_array())
            .collect();
        let ok = self.grad.mlp.iter().all(|v| v.is_finite())
            && self
                .grad
                .grid
                .as_ref()
                .is_none_or(|g| g.values.iter().all(|v| v.is_finite()));
        if !ok {
            self.grad = self.fields.material.new_grad();
            return false;
        }
        self.adam.begin_step();
        let ids = |name: &str| self.adam.group_id(name);
        let (g_grid, g_mlp, g_em) = (ids(GROUP_GRID), ids(GROUP_MLP), ids(GROUP_EMISSION));
        if let (Some(id), Some(grid), Some(gg)) = (g_grid, self.fields.material.grid.as_mut(), self.grad.grid.as_mut())
        {
            let row = grid.config.features_per_level;
            self.adam.update_sparse(id, &mut grid.params, gg, row);
        }
        if let Some(id) = g_mlp {
            self.adam
                .update(id, &mut self.fields.material.mlp.params, &mut self.grad.mlp);
        }
        if let Some(id) = g_em {
            for (d, _) in d_raw.chunks_exact_mut(3).zip(&self.held_emission).filter(|(_, h)| **h) {
                d.fill(0.0);
            }
            self.adam.update(id, &mut self.fields.emitters.log_emission, &mut d_raw);
        }
        true
    }

    fn stats(&self, iteration: u64, fit: u64, t: &BatchTerms) -> Stage2Stats {
        Stage2Stats {
            iteration,
            render: t.render,
            emitter: t.emitter,
            smooth: t.smooth,
            energy: t.energy,
            rho_prior: t.rho_prior,
            lobe: t.lobe,
            fit,
            loss: t.loss,
            emission: self.emissions().iter().map(|e| e.to_array()).collect(),
        }
    }
}

impl TermInputs<'_> {
    /// Batch pixel `j`'s term: a surface pixel's re-render against its target (gradients of its
    /// Kd, Ks, ρ into `dj`, of the emissions into `d_em`), or an emitter pixel's L\[k\] against
    /// its target. A held L\[k\] is not the images' (they saw it clipped): its pixels say nothing.
    #[inline]
    fn pixel_terms(&self, j: usize, dj: &mut [f32], d_em: &mut [Vec3], render: &mut f32, emit: &mut f32) {
        let px = &self.pixels[self.batch[j]];
        let clipped = |c: usize| px.saturated >> c & 1 == 1;
        match px.kind {
            PixelKind::Surface { index } => {
                let n_dot_v = px.point.normal.dot(px.point.view);
                let live = self.live.map(|l| &l[j * self.samples..(j + 1) * self.samples]);
                let brdf = &self.brdfs[j];
                let pred = match live {
                    Some(l) => shade(brdf, n_dot_v, l, self.emission),
                    None => self.cache.shade(index as usize, brdf, n_dot_v, self.emission),
                };
                let mut g = Vec3::ZERO;
                for c in 0..3 {
                    let (l, s) = rerender_channel(self.loss, pred[c], px.target[c], clipped(c), self.scale);
                    *render += l;
                    g[c] = s / (3.0 * self.n_surface);
                }
                let (_, gr) = match live {
                    Some(l) => shade_backward(brdf, n_dot_v, l, self.emission, g, d_em),
                    None => self
                        .cache
                        .shade_backward(index as usize, brdf, n_dot_v, self.emission, g, d_em),
                };
                dj[..3].copy_from_slice(&gr.kd.to_array());
                dj[3..6].copy_from_slice(&gr.ks.to_array());
                dj[6] = gr.rho;
            }
            PixelKind::Emitter(e) if self.held[e as usize] => {}
            PixelKind::Emitter(e) => {
                let pred = self.emission[e as usize];
                for c in 0..3 {
                    let (l, s) = rerender_channel(self.loss, pred[c], px.target[c], clipped(c), self.scale);
                    *emit += l;
                    d_em[e as usize][c] += s / (3.0 * self.n_emitter);
                }
            }
        }
    }
}
