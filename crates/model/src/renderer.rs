//! Volume rendering of a [`NeuralScene`] (paper eq:rgb and eq:depth, and the emitter mask of
//! Sec. 4.2), with the backward pass beside the forward: rays → VolSDF error-bounded samples → F_d (distance,
//! feature, gradient) → F_c and F_e → composited colour, depth, normal and emitter probability.
//! Training and inference (`render`, `eval`, PDF-map initialisation) share this one path.
//!
//! Extra points (eikonal, bubble and smoothness points of stage 1) ride in the same SDF batch as
//! the ray samples, so one SDF forward and one SDF backward serve every loss term.

use crate::scene::{NeuralScene, SceneGrads};
use crate::volume::{
    composite_batch, composite_batch_backward, error_bounded_samples_into, laplace_density_backward,
    laplace_density_batch, CompositeGrads, CompositeOutputs, ErrorBoundedSamplerConfig, OccupiedStretches,
    PackedSamples, RayBatchRef, RaySampleSet, SamplerScratch,
};
use i2sdf_nn::sdf::SdfInferWorkspace;
use i2sdf_nn::{MlpWorkspace, SdfWorkspace};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

/// Channels composited per sample: RGB, unit normal, emitter probability.
pub const CHANNELS: usize = 7;

#[derive(Clone, Debug)]
pub struct RenderSettings {
    pub sampler: ErrorBoundedSamplerConfig,
    /// Rays start this far from the camera (normalized units).
    pub near: f32,
    /// Rays end where they leave the sphere of this radius (the scene is inside the unit sphere).
    pub bound_radius: f32,
    /// Empty-space skipping: where set, the sampler spends its evaluations in the grid's
    /// occupied cells only and ends each ray at its first solid cell ([`crate::occupancy`]).
    pub occupancy: Option<std::sync::Arc<crate::occupancy::OccupancyGrid>>,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            sampler: ErrorBoundedSamplerConfig {
                num_samples: 48,
                num_samples_eval: 48,
                num_samples_upsample: 48,
                num_samples_extra: 8,
                max_total_iters: 3,
                ..Default::default()
            },
            near: 0.01,
            bound_radius: 1.0,
            occupancy: None,
        }
    }
}

impl RenderSettings {
    /// The defaults with a run's sampler settings (`[sampling]`: samples after error-bounded
    /// upsampling, uniform samples of the first pass, VolSDF's ε): the mapping training, `render`
    /// and `eval` share, so a view is rendered as the run was trained.
    pub fn with_sampling(samples: usize, coarse: usize, epsilon: f32) -> Self {
        let mut s = RenderSettings::default();
        s.sampler.num_samples = samples;
        s.sampler.num_samples_eval = coarse;
        s.sampler.num_samples_upsample = coarse;
        s.sampler.eps = epsilon;
        s
    }
}

/// Per-ray results of a forward pass.
#[derive(Clone, Debug, Default)]
pub struct RayOutputs {
    /// rays × 3
    pub rgb: Vec<f32>,
    pub depth: Vec<f32>,
    /// rays × 3, Σ w n̂ (not renormalized)
    pub normal: Vec<f32>,
    pub emitter: Vec<f32>,
    pub opacity: Vec<f32>,
}

/// Buffers of one batch, kept between iterations; after [`forward`] they hold every per-sample
/// quantity the backward needs.
#[derive(Default)]
pub struct RenderWorkspace {
    pub samples: RaySampleSet,
    /// Number of ray samples; points `n_samples..` are the extra points.
    pub n_samples: usize,
    /// All points (ray samples, then extra points), flat xyz.
    pub points: Vec<f32>,
    pub sdf: Vec<f32>,
    pub feature: Vec<f32>,
    /// ∇d at every point, flat xyz.
    pub gradient: Vec<[f32; 3]>,
    sigma: Vec<f32>,
    sample_dirs: Vec<f32>,
    radiance_input: Vec<f32>,
    radiance_out: Vec<f32>,
    emitter_out: Vec<f32>,
    channels: Vec<f32>,
    pub weights: Vec<f32>,
    pub out: RayOutputs,
    sdf_ws: SdfWorkspace,
    sampler_chunks: Vec<SamplerChunk>,
    radiance_ws: MlpWorkspace,
    emitter_ws: MlpWorkspace,
    // backward scratch
    grad_sigma: Vec<f32>,
    grad_channels: Vec<f32>,
    grad_radiance_in: Vec<f32>,
    grad_feature: Vec<f32>,
    grad_emitter_out: Vec<f32>,
    grad_radiance_out: Vec<f32>,
    grad_emitter_in: Vec<f32>,
}

/// Distance along the unit ray from `o` to where it leaves the sphere of radius `r`.
pub fn sphere_exit(o: [f32; 3], d: [f32; 3], r: f32) -> f32 {
    let b = o[0] * d[0] + o[1] * d[1] + o[2] * d[2];
    let c = o[0] * o[0] + o[1] * o[1] + o[2] * o[2] - r * r;
    (-b + (b * b - c).max(0.0).sqrt()).max(0.0)
}

/// Renders `origins`/`dirs` (unit directions, normalized frame) and evaluates the SDF at
/// `extra_points` too. With an RNG the samples are stochastic (training); without, deterministic.
pub fn forward<R: Rng + ?Sized>(
    scene: &NeuralScene,
    settings: &RenderSettings,
    origins: &[[f32; 3]],
    dirs: &[[f32; 3]],
    extra_points: &[f32],
    ws: &mut RenderWorkspace,
    rng: Option<&mut R>,
) {
    sample(scene, settings, origins, dirs, ws, rng);
    forward_with_samples(scene, origins, dirs, extra_points, ws);
}

/// Places the samples along the rays (VolSDF's error-bounded sampler, SDF forward only) into
/// `ws.samples`. The samples depend on the SDF but are not differentiated (as in VolSDF).
pub fn sample<R: Rng + ?Sized>(
    scene: &NeuralScene,
    settings: &RenderSettings,
    origins: &[[f32; 3]],
    dirs: &[[f32; 3]],
    ws: &mut RenderWorkspace,
    rng: Option<&mut R>,
) {
    let rays = origins.len();
    let beta = scene.beta.value();
    let near = vec![settings.near; rays];
    let far: Vec<f32> = origins
        .iter()
        .zip(dirs)
        .map(|(o, d)| sphere_exit(*o, *d, settings.bound_radius).max(settings.near * 2.0))
        .collect();
    // The sampler walks its rays one by one between batched SDF calls, so it runs on chunks of
    // rays in parallel (one SDF workspace, sampler scratch and RNG stream per chunk; the streams
    // are drawn from the caller's RNG, so a seeded run stays reproducible for a given thread
    // count). The chunks' buffers live in the workspace: nothing is allocated once warm.
    let chunks = (2 * rayon::current_num_threads()).clamp(1, rays.max(1));
    let per = rays.div_ceil(chunks).max(1);
    let seeds: Option<Vec<u64>> = rng.map(|r| (0..chunks).map(|_| r.gen::<u64>()).collect());
    if ws.sampler_chunks.len() < chunks {
        ws.sampler_chunks.resize_with(chunks, SamplerChunk::default);
    }
    ws.sampler_chunks[..chunks]
        .par_iter_mut()
        .enumerate()
        .for_each(|(c, chunk)| {
            let r = (c * per).min(rays)..((c + 1) * per).min(rays);
            let SamplerChunk {
                sdf_ws,
                scratch,
                set,
                offsets,
                stretches,
                one,
            } = chunk;
            let occupied = settings.occupancy.as_ref().map(|grid| {
                offsets.clear();
                offsets.push(0);
                stretches.clear();
                for i in r.clone() {
                    grid.intervals(origins[i], dirs[i], near[i], far[i], one);
                    stretches.extend_from_slice(one);
                    offsets.push(stretches.len() as u32);
                }
                OccupiedStretches {
                    offsets,
                    intervals: stretches,
                }
            });
            // Distances only, through the inference path (nothing kept for a backward).
            let sdf_eval = |pts: &[[f32; 3]], out: &mut [f32]| {
                scene.sdf.infer(pts.as_flattened(), sdf_ws, out, None, None);
            };
            let mut chunk_rng = seeds.as_ref().map(|s| rand_pcg::Pcg64::seed_from_u64(s[c]));
            let batch = RayBatchRef {
                origins: &origins[r.clone()],
                directions: &dirs[r.clone()],
                near: &near[r.clone()],
                far: &far[r],
                occupied,
            };
            error_bounded_samples_into(
                &settings.sampler,
                &batch,
                beta,
                sdf_eval,
                chunk_rng.as_mut(),
                scratch,
                set,
            );
        });
    // Concatenate the chunks' packed samples.
    let set = &mut ws.samples;
    set.ray_offsets.clear();
    set.ray_offsets.push(0);
    set.t.clear();
    set.delta.clear();
    set.beta_used.clear();
    set.converged.clear();
    set.sdf_evaluations = 0;
    for chunk in &ws.sampler_chunks[..chunks] {
        let r = &chunk.set;
        let base = *set.ray_offsets.last().unwrap();
        set.ray_offsets.extend(r.ray_offsets[1..].iter().map(|o| o + base));
        set.t.extend_from_slice(&r.t);
        set.delta.extend_from_slice(&r.delta);
        set.beta_used.extend_from_slice(&r.beta_used);
        set.converged.extend_from_slice(&r.converged);
        set.sdf_evaluations += r.sdf_evaluations;
    }
}

/// One parallel sampler task's buffers.
#[derive(Default)]
struct SamplerChunk {
    sdf_ws: SdfInferWorkspace,
    scratch: SamplerScratch,
    set: RaySampleSet,
    /// The chunk's rays' occupied stretches (with an occupancy grid), and one ray's.
    offsets: Vec<u32>,
    stretches: Vec<[f32; 2]>,
    one: Vec<[f32; 2]>,
}

/// The differentiable part of [`forward`], at the samples already in `ws.samples`.
pub fn forward_with_samples(
    scene: &NeuralScene,
    origins: &[[f32; 3]],
    dirs: &[[f32; 3]],
    extra_points: &[f32],
    ws: &mut RenderWorkspace,
) {
    let rays = origins.len();
    let beta = scene.beta.value();
    let n_s = ws.samples.t.len();
    let n_e = extra_points.len() / 3;
    let n = n_s + n_e;
    ws.n_samples = n_s;
    // 2. Points: samples, then extra points.
    ws.points.clear();
    ws.sample_dirs.clear();
    for r in 0..rays {
        let (a, b) = (
            ws.samples.ray_offsets[r] as usize,
            ws.samples.ray_offsets[r + 1] as usize,
        );
        let (o, d) = (origins[r], dirs[r]);
        for &t in &ws.samples.t[a..b] {
            ws.points
                .extend_from_slice(&[o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]]);
            ws.sample_dirs.extend_from_slice(&d);
        }
    }
    ws.points.extend_from_slice(extra_points);
    // 3. F_d with its spatial gradient.
    let fdim = scene.feature_dim();
    ws.sdf.resize(n, 0.0);
    ws.feature.resize(n * fdim, 0.0);
    ws.gradient.resize(n, [0.0; 3]);
    scene.sdf.forward_with_gradient(
        &ws.points,
        &mut ws.sdf_ws,
        &mut ws.sdf,
        &mut ws.feature,
        ws.gradient.as_flattened_mut(),
    );
    // 4. Density (eq:density), F_c (the radiance line of eq:sdf, with the normal as VolSDF), F_e.
    ws.sigma.resize(n_s, 0.0);
    laplace_density_batch(&ws.sdf[..n_s], beta, &mut ws.sigma);
    scene.radiance_input(
        &ws.feature[..n_s * fdim],
        &ws.sample_dirs,
        ws.gradient[..n_s].as_flattened(),
        &mut ws.radiance_input,
    );
    ws.radiance_out.resize(n_s * 3, 0.0);
    scene
        .radiance
        .forward(&ws.radiance_input, &mut ws.radiance_ws, &mut ws.radiance_out);
    ws.emitter_out.resize(n_s, 0.0);
    scene
        .emitter
        .forward(&ws.feature[..n_s * fdim], &mut ws.emitter_ws, &mut ws.emitter_out);
    // 5. Channels and compositing (eq:rgb, eq:depth, emitter mask).
    ws.channels.resize(n_s * CHANNELS, 0.0);
    for i in 0..n_s {
        let c = &mut ws.channels[i * CHANNELS..(i + 1) * CHANNELS];
        c[..3].copy_from_slice(&ws.radiance_out[i * 3..i * 3 + 3]);
        let g = &ws.gradient[i];
        let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt().max(1e-8);
        c[3] = g[0] / len;
        c[4] = g[1] / len;
        c[5] = g[2] / len;
        c[6] = ws.emitter_out[i];
    }
    let mut out_channels = vec![0.0f32; rays * CHANNELS];
    ws.out.depth.resize(rays, 0.0);
    ws.out.opacity.resize(rays, 0.0);
    ws.weights.resize(n_s, 0.0);
    composite_batch(
        &PackedSamples {
            ray_offsets: &ws.samples.ray_offsets,
            t: &ws.samples.t,
            delta: &ws.samples.delta,
            sigma: &ws.sigma,
            channels: &ws.channels,
            num_channels: CHANNELS,
        },
        CompositeOutputs {
            channels: &mut out_channels,
            depth: &mut ws.out.depth,
            opacity: &mut ws.out.opacity,
            weights: &mut ws.weights,
        },
    );
    ws.out.rgb.resize(rays * 3, 0.0);
    ws.out.normal.resize(rays * 3, 0.0);
    ws.out.emitter.resize(rays, 0.0);
    for r in 0..rays {
        let c = &out_channels[r * CHANNELS..(r + 1) * CHANNELS];
        ws.out.rgb[r * 3..r * 3 + 3].copy_from_slice(&c[..3]);
        ws.out.normal[r * 3..r * 3 + 3].copy_from_slice(&c[3..6]);
        ws.out.emitter[r] = c[6];
    }
}

/// Per ray, the distance of the sample where the ray's termination density T(t)·σ(t) peaks (the
/// surface the ray renders: the first it meets, where an expected depth would average a thin
/// object with the wall behind it), for rays whose opacity reaches `min_opacity` (else `None`),
/// from the samples [`sample`] placed in `ws`: an SDF inference at them, nothing kept for a
/// backward (the points are detached). Stage 1 takes its smoothness and bubble points there when
/// the dataset has no depth.
pub fn rendered_surface_distances(
    scene: &NeuralScene,
    origins: &[[f32; 3]],
    dirs: &[[f32; 3]],
    ws: &RenderWorkspace,
    min_opacity: f32,
) -> Vec<Option<f32>> {
    let set = &ws.samples;
    let rays = origins.len();
    let n = set.t.len();
    let mut points = Vec::with_capacity(n * 3);
    for r in 0..rays {
        let (o, d) = (origins[r], dirs[r]);
        for &t in &set.t[set.ray_offsets[r] as usize..set.ray_offsets[r + 1] as usize] {
            points.extend_from_slice(&[o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]]);
        }
    }
    const CHUNK: usize = 4096;
    let mut sdf = vec![0.0f32; n];
    sdf.par_chunks_mut(CHUNK)
        .zip(points.par_chunks(CHUNK * 3))
        .for_each_init(SdfInferWorkspace::default, |sws, (out, pts)| {
            scene.sdf.infer(pts, sws, out, None, None)
        });
    let mut sigma = vec![0.0f32; n];
    laplace_density_batch(&sdf, scene.beta.value(), &mut sigma);
    let (mut weights, mut depth, mut opacity) = (vec![0.0f32; n], vec![0.0f32; rays], vec![0.0f32; rays]);
    composite_batch(
        &PackedSamples {
            ray_offsets: &set.ray_offsets,
            t: &set.t,
            delta: &set.delta,
            sigma: &sigma,
            channels: &[],
            num_channels: 0,
        },
        CompositeOutputs {
            channels: &mut [],
            depth: &mut depth,
            opacity: &mut opacity,
            weights: &mut weights,
        },
    );
    (0..rays)
        .map(|r| {
            // The peak of the termination density T(t)·σ(t), not of the weights: a weight is that
            // density times its interval, and the intervals vary tenfold along a ray.
            let range = set.ray_offsets[r] as usize..set.ray_offsets[r + 1] as usize;
            let mut transmittance = 1.0f32;
            let (mut best, mut peak) = (f32::NEG_INFINITY, None);
            for i in range {
                let density = transmittance * sigma[i];
                if density > best {
                    (best, peak) = (density, Some(set.t[i]));
                }
                transmittance -= weights[i];
            }
            peak.filter(|_| opacity[r] >= min_opacity)
        })
        .collect()
}

/// Upstream gradients of a [`forward`]'s per-ray outputs.
pub struct RayGrads<'a> {
    pub rgb: &'a [f32],
    pub depth: &'a [f32],
    pub normal: &'a [f32],
    pub emitter: &'a [f32],
    pub opacity: &'a [f32],
}

/// Backward of [`forward`]: accumulates parameter gradients into `grads`. `d_sdf` and
/// `d_gradient` hold, per point (samples then extra points), the gradients of point-level loss
/// terms (eikonal, bubble, smoothness) w.r.t. d and ∇d; the rendering gradients are added to them
/// here (they are used as scratch and left modified).
pub fn backward(
    scene: &NeuralScene,
    ws: &mut RenderWorkspace,
    ray_grads: &RayGrads,
    d_sdf: &mut [f32],
    d_gradient: &mut [f32],
    grads: &mut SceneGrads,
) {
    let rays = ws.samples.ray_offsets.len() - 1;
    let n_s = ws.n_samples;
    let fdim = scene.feature_dim();
    let beta = scene.beta.value();
    // Compositing backward.
    let mut g_out = vec![0.0f32; rays * CHANNELS];
    for r in 0..rays {
        let g = &mut g_out[r * CHANNELS..(r + 1) * CHANNELS];
        g[..3].copy_from_slice(&ray_grads.rgb[r * 3..r * 3 + 3]);
        g[3..6].copy_from_slice(&ray_grads.normal[r * 3..r * 3 + 3]);
        g[6] = ray_grads.emitter[r];
    }
    ws.grad_sigma.resize(n_s, 0.0);
    ws.grad_channels.resize(n_s * CHANNELS, 0.0);
    composite_batch_backward(
        &PackedSamples {
            ray_offsets: &ws.samples.ray_offsets,
            t: &ws.samples.t,
            delta: &ws.samples.delta,
            sigma: &ws.sigma,
            channels: &ws.channels,
            num_channels: CHANNELS,
        },
        &CompositeGrads {
            channels: &g_out,
            depth: ray_grads.depth,
            opacity: ray_grads.opacity,
        },
        &mut ws.grad_sigma,
        &mut ws.grad_channels,
    );
    // Density backward: dL/dd for the samples and dL/dβ.
    let mut d_sdf_render = vec![0.0f32; n_s];
    // Chained into β's raw parameter (β = β_min + exp(raw)).
    grads.beta[0] +=
        scene.beta.dvalue() * laplace_density_backward(&ws.sdf[..n_s], beta, &ws.grad_sigma, &mut d_sdf_render);
    for i in 0..n_s {
        d_sdf[i] += d_sdf_render[i];
    }
    // F_c backward: into z and ∇d (the normal input).
    ws.grad_radiance_out.resize(n_s * 3, 0.0);
    ws.grad_emitter_out.resize(n_s, 0.0);
    for i in 0..n_s {
        ws.grad_radiance_out[i * 3..i * 3 + 3].copy_from_slice(&ws.grad_channels[i * CHANNELS..i * CHANNELS + 3]);
        ws.grad_emitter_out[i] = ws.grad_channels[i * CHANNELS + 6];
    }
    let w_in = scene.radiance.input_dim();
    ws.grad_radiance_in.resize(n_s * w_in, 0.0);
    scene.radiance.backward(
        &mut ws.radiance_ws,
        &ws.grad_radiance_out,
        &mut grads.radiance,
        Some(&mut ws.grad_radiance_in),
    );
    ws.grad_emitter_in.resize(n_s * fdim, 0.0);
    scene.emitter.backward(
        &mut ws.emitter_ws,
        &ws.grad_emitter_out,
        &mut grads.emitter,
        Some(&mut ws.grad_emitter_in),
    );
    let n = ws.sdf.len();
    ws.grad_feature.clear();
    ws.grad_feature.resize(n * fdim, 0.0);
    let e = scene.direction.output_dim();
    for i in 0..n_s {
        let row = &ws.grad_radiance_in[i * w_in..(i + 1) * w_in];
        let gf = &mut ws.grad_feature[i * fdim..(i + 1) * fdim];
        for k in 0..fdim {
            gf[k] = row[k] + ws.grad_emitter_in[i * fdim + k];
        }
        // ∇d enters F_c raw and the normal channel as n̂ = ∇d/‖∇d‖: dn̂ = (I − n̂n̂ᵀ) d∇d / ‖∇d‖.
        let g = &ws.gradient[i];
        let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt().max(1e-8);
        let nh = [g[0] / len, g[1] / len, g[2] / len];
        let dn = &ws.grad_channels[i * CHANNELS + 3..i * CHANNELS + 6];
        let dot = nh[0] * dn[0] + nh[1] * dn[1] + nh[2] * dn[2];
        for c in 0..3 {
            d_gradient[i * 3 + c] += row[fdim + e + c] + (dn[c] - dot * nh[c]) / len;
        }
    }
    scene.sdf.backward(
        &mut ws.sdf_ws,
        d_sdf,
        Some(&ws.grad_feature),
        Some(d_gradient),
        &mut grads.sdf,
    );
}

/// After [`backward`]: per ray, `Σ ∂L/∂x` and `Σ t ∂L/∂x` over its samples (how the loss moves with
/// the ray's origin and with its direction, the samples' distances t held fixed), from the SDF
/// network's position gradient. `None` when the network keeps no encoding Jacobian (the MLP
/// backbone). What a camera pose correction follows.
pub fn ray_position_gradients(scene: &NeuralScene, ws: &RenderWorkspace) -> Option<Vec<[[f32; 3]; 2]>> {
    let n = ws.sdf.len();
    let mut dx = vec![0.0f32; n * 3];
    scene.sdf.position_gradient(&ws.sdf_ws, &mut dx)?;
    let rays = ws.samples.ray_offsets.len() - 1;
    let mut out = vec![[[0.0f32; 3]; 2]; rays];
    for (r, o) in out.iter_mut().enumerate() {
        let (a, b) = (
            ws.samples.ray_offsets[r] as usize,
            ws.samples.ray_offsets[r + 1] as usize,
        );
        for i in a..b {
            let t = ws.samples.t[i];
            for k in 0..3 {
                o[0][k] += dx[i * 3 + k];
                o[1][k] += t * dx[i * 3 + k];
            }
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn scene() -> NeuralScene {
        let mut s = crate::scene::tiny_test_scene();
        // Break the symmetry of the fresh init so every parameter matters.
        for (i, p) in s.radiance.params.iter_mut().enumerate() {
            *p += 0.01 * ((i as f32) * 0.37).sin();
        }
        s
    }

    /// The scene, settings and two rays of the finite-difference tests.
    fn two_rays() -> (NeuralScene, RenderSettings, [[f32; 3]; 2], [[f32; 3]; 2]) {
        let settings = RenderSettings {
            near: 0.05,
            ..Default::default()
        };
        let o = [[0.1f32, -0.05, 0.0], [-0.2, 0.1, 0.05]];
        let d = [[0.6f32, 0.8, 0.0], [0.0, -0.6, 0.8]];
        (scene(), settings, o, d)
    }

    /// L = Σ a·rgb + b·depth + c·normal + e·emitter + Σ_extra (p·d + q·∇d), a deterministic
    /// scalar of every output.
    fn loss(s: &NeuralScene, samples: &RaySampleSet, o: &[[f32; 3]], d: &[[f32; 3]], extra: &[f32]) -> f64 {
        let mut ws = RenderWorkspace {
            samples: samples.clone(),
            ..Default::default()
        };
        forward_with_samples(s, o, d, extra, &mut ws);
        let mut l = 0.0f64;
        for r in 0..o.len() {
            for c in 0..3 {
                l += (0.3 + 0.1 * c as f64) * ws.out.rgb[r * 3 + c] as f64;
                l += (0.2 - 0.15 * c as f64) * ws.out.normal[r * 3 + c] as f64;
            }
            l += 0.7 * ws.out.depth[r] as f64 + 0.4 * ws.out.emitter[r] as f64;
        }
        let ns = ws.n_samples;
        for j in 0..extra.len() / 3 {
            l += 0.5 * ws.sdf[ns + j] as f64 + 0.25 * ws.gradient[ns + j][1] as f64;
        }
        l
    }

    /// The rays' position gradients against finite differences in the origin and direction,
    /// the samples' t held fixed, on the outputs that depend on the points through d and z alone
    /// (depth and emitter; colour and normal also see ∇d, whose curvature term is left out).
    #[test]
    fn ray_position_gradients_match_finite_differences() {
        let (s, settings, o, d) = two_rays();
        let mut ws = RenderWorkspace::default();
        forward::<rand_pcg::Pcg64>(&s, &settings, &o, &d, &[], &mut ws, None);
        let samples = ws.samples.clone();
        let n = ws.sdf.len();
        let (mut d_sdf, mut d_grad) = (vec![0.0f32; n], vec![0.0f32; n * 3]);
        backward(
            &s,
            &mut ws,
            &RayGrads {
                rgb: &[0.0; 6],
                depth: &[0.7, -0.3],
                normal: &[0.0; 6],
                emitter: &[0.4, 0.9],
                opacity: &[0.0, 0.0],
            },
            &mut d_sdf,
            &mut d_grad,
            &mut SceneGrads::new(&s),
        );
        let g = ray_position_gradients(&s, &ws).expect("hash-grid scene");
        let loss = |o: &[[f32; 3]], d: &[[f32; 3]]| -> f64 {
            let mut ws = RenderWorkspace {
                samples: samples.clone(),
                ..Default::default()
            };
            forward_with_samples(&s, o, d, &[], &mut ws);
            (0.7 * ws.out.depth[0] - 0.3 * ws.out.depth[1] + 0.4 * ws.out.emitter[0] + 0.9 * ws.out.emitter[1]) as f64
        };
        let h = 1e-3f32;
        for r in 0..2 {
            for k in 0..3 {
                for (which, analytic) in [(0, g[r][0][k]), (1, g[r][1][k])] {
                    let (mut op, mut om, mut dp, mut dm) = (o, o, d, d);
                    if which == 0 {
                        op[r][k] += h;
                        om[r][k] -= h;
                    } else {
                        dp[r][k] += h;
                        dm[r][k] -= h;
                    }
                    let numeric = (loss(&op, &dp) - loss(&om, &dm)) / (2.0 * h as f64);
                    let tol = 3e-2 * numeric.abs().max(analytic.abs() as f64) + 2e-3;
                    assert!(
                        (analytic as f64 - numeric).abs() < tol,
                        "ray {r} {} {k}: analytic {analytic} vs numeric {numeric}",
                        ["origin", "direction"][which]
                    );
                }
            }
        }
    }

    #[test]
    fn backward_matches_finite_differences() {
        // The sample positions depend on the SDF but are not differentiated (as in VolSDF), so
        // the finite differences reuse the same samples.
        let (s, settings, o, d) = two_rays();
        let extra = [0.3f32, 0.2, -0.1, -0.4, 0.1, 0.5];
        let mut ws = RenderWorkspace::default();
        forward::<rand_pcg::Pcg64>(&s, &settings, &o, &d, &extra, &mut ws, None);
        let samples = ws.samples.clone();
        let n = ws.sdf.len();
        let ns = ws.n_samples;
        let rgb_g: Vec<f32> = (0..6).map(|k| 0.3 + 0.1 * (k % 3) as f32).collect();
        let nrm_g: Vec<f32> = (0..6).map(|k| 0.2 - 0.15 * (k % 3) as f32).collect();
        let mut d_sdf = vec![0.0f32; n];
        let mut d_grad = vec![0.0f32; n * 3];
        for j in 0..2 {
            d_sdf[ns + j] = 0.5;
            d_grad[(ns + j) * 3 + 1] = 0.25;
        }
        let mut grads = SceneGrads::new(&s);
        backward(
            &s,
            &mut ws,
            &RayGrads {
                rgb: &rgb_g,
                depth: &[0.7, 0.7],
                normal: &nrm_g,
                emitter: &[0.4, 0.4],
                opacity: &[0.0, 0.0],
            },
            &mut d_sdf,
            &mut d_grad,
            &mut grads,
        );
        // Check a spread of parameters of every network, and β: central differences of the loss
        // in the parameter that `slot` selects.
        let h = 1e-3f32;
        let mut checked = 0;
        let mut check = |analytic: f32, slot: fn(&mut NeuralScene) -> &mut [f32], k: usize, what: &str| {
            let (mut a, mut b) = (s.clone(), s.clone());
            slot(&mut a)[k] += h;
            slot(&mut b)[k] -= h;
            let (plus, minus) = (loss(&a, &samples, &o, &d, &extra), loss(&b, &samples, &o, &d, &extra));
            let numeric = (plus - minus) / (2.0 * h as f64);
            let tol = 2e-2 * numeric.abs().max(analytic.abs() as f64) + 2e-3;
            assert!(
                (analytic as f64 - numeric).abs() < tol,
                "{what}: analytic {analytic} vs numeric {numeric}"
            );
            checked += 1;
        };
        fn radiance(sc: &mut NeuralScene) -> &mut [f32] {
            &mut sc.radiance.params
        }
        fn emitter(sc: &mut NeuralScene) -> &mut [f32] {
            &mut sc.emitter.params
        }
        fn sdf_mlp(sc: &mut NeuralScene) -> &mut [f32] {
            &mut sc.sdf.mlp.params
        }
        fn table(sc: &mut NeuralScene) -> &mut [f32] {
            match &mut sc.sdf.encoding {
                i2sdf_nn::SdfEncoding::HashGrid(g) => &mut g.params,
                _ => unreachable!(),
            }
        }
        fn beta(sc: &mut NeuralScene) -> &mut [f32] {
            &mut sc.beta.raw
        }
        for k in (0..s.radiance.params.len()).step_by(97) {
            check(grads.radiance[k], radiance, k, "radiance");
        }
        for k in (0..s.emitter.params.len()).step_by(41) {
            check(grads.emitter[k], emitter, k, "emitter");
        }
        for k in (0..s.sdf.mlp.params.len()).step_by(211) {
            check(grads.sdf.mlp[k], sdf_mlp, k, "sdf mlp");
        }
        // The hash table: the entries with the largest gradients.
        let hg = grads.sdf.hash_grid.as_ref().unwrap();
        let mut idx: Vec<usize> = (0..hg.values.len()).filter(|&k| hg.values[k] != 0.0).collect();
        idx.sort_by(|&x, &y| hg.values[y].abs().total_cmp(&hg.values[x].abs()));
        for &k in idx.iter().take(6) {
            check(hg.values[k], table, k, "hash grid");
        }
        check(grads.beta[0], beta, 0, "beta");
        assert!(checked > 10);
    }

    /// The expected depth and the peak of the termination density (`rendered_surface_distances`) both
    /// lie at the SDF's zero crossing.
    #[test]
    fn rendered_depth_is_the_sdf_zero_crossing() {
        let s = scene();
        let settings = RenderSettings::default();
        let o = [[0.0f32; 3]; 3];
        let d = [[1.0f32, 0.0, 0.0], [0.0, 0.6, 0.8], [0.0, 0.0, -1.0]];
        let mut ws = RenderWorkspace::default();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(0);
        forward(&s, &settings, &o, &d, &[], &mut ws, Some(&mut rng));
        let peaks = rendered_surface_distances(&s, &o, &d, &ws, 0.5);
        assert!(rendered_surface_distances(&s, &o, &d, &ws, 1.01)
            .iter()
            .all(Option::is_none));
        let mut q = crate::SceneQuery::new(&s);
        for r in 0..3 {
            // The initial field is an inverted sphere (free space inside): bisect its zero crossing.
            let at = |t: f32, q: &mut crate::SceneQuery| {
                let mut v = [0.0f32];
                q.sdf(&[t * d[r][0], t * d[r][1], t * d[r][2]], &mut v);
                v[0]
            };
            let (mut lo, mut hi) = (0.0f32, 1.0f32);
            assert!(at(lo, &mut q) > 0.0 && at(hi, &mut q) < 0.0);
            for _ in 0..40 {
                let mid = 0.5 * (lo + hi);
                if at(mid, &mut q) > 0.0 {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            // VolSDF's density puts the expected depth within a few β of the surface.
            let beta = s.beta.value();
            assert!(
                (ws.out.depth[r] - lo).abs() < 3.0 * beta,
                "depth {} vs zero crossing {lo}",
                ws.out.depth[r]
            );
            assert!(ws.out.opacity[r] > 0.99);
            let peak = peaks[r].expect("an opaque ray has a peak");
            assert!((peak - lo).abs() < beta, "peak {peak} vs zero crossing {lo}");
            // Inverted sphere: the surface normal (∇d) points inwards, against the ray.
            let dot: f32 = (0..3).map(|c| ws.out.normal[r * 3 + c] * d[r][c]).sum();
            assert!(dot < -0.8, "normal {:?}", ws.out.normal);
        }
    }
}
