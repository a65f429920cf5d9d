//! Stage 2's differentiable Monte Carlo estimator of the surface colour (paper eq:render):
//!
//! R̂(s) = Σ_k f_r(v, d_k; Kd, Ks, ρ) L_k (N·d_k) / (N p(d_k)),
//!
//! with L_k the incident radiance of eq:radiance: the emission L[index(hit)] when the traced ray
//! hits an emitter, else the frozen radiance field's radiance at the hit. The estimate is split in
//! two parts, because the part that does not depend on the materials is the expensive one:
//!
//! 1. [`trace_incident`] draws directions from a [`DirectionMixture`] at each surface point, traces
//!    them in the frozen SDF and records, per sample, the cosines that f_r depends on, the weight
//!    (N·d)/(N·p(d)) and what arrives (an emitter index, or F_c's linear radiance). The cached
//!    estimator does this once per cached pixel with a fixed mixture; the live estimator (the
//!    paper's) every iteration, importance-sampling the current materials' GGX mixture.
//! 2. [`shade`] / [`shade_backward`] evaluate the sum for given materials and emissions and its
//!    gradient with respect to Kd, Ks, ρ and every L\[k\]. The sampled directions are held fixed in
//!    the backward (the pdf is detached), which keeps the gradient of the expectation unbiased:
//!    ∂/∂θ E_p[f_θ L cos / p] = E_p[∂f_θ/∂θ L cos / p] for any fixed proposal p.

use glam::Vec3;
use i2sdf_data::KdTree;
use i2sdf_model::intrinsic::{FrozenScene, LabelledHit};
use i2sdf_render::{DirectionMixture, GgxBrdf, GgxGrad, Ray};
use rand::Rng;
use rand_pcg::Pcg32;
use rayon::prelude::*;

/// What arrives along one sampled direction, with what f_r needs of it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct IncidentSample {
    pub n_dot_d: f32,
    pub n_dot_h: f32,
    pub d_dot_h: f32,
    /// (N·d) / (N_samples · p(d)): zero for samples below the horizon.
    pub weight: f32,
    /// F_c's linear radiance at the hit (zero for misses and for emitter hits).
    pub radiance: [f32; 3],
    /// The emitter hit, or −1.
    pub emitter: i32,
}

/// A surface point to shade: world position, unit normal (towards free space), unit direction
/// towards the viewer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShadingPoint {
    pub position: Vec3,
    pub normal: Vec3,
    pub view: Vec3,
}

/// Offset of secondary-ray origins along the normal, in world units relative to the scene scale
/// (so they leave the surface the caster found): the same gap the integrator's rays get.
pub const SECONDARY_OFFSET: f32 = i2sdf_model::intrinsic::SURFACE_GAP;

/// Draws `n` directions per point from `mixture_of(i)`, traces them in `frozen` and returns the
/// `points.len() × n` samples (point-major). `rngs[i]` is point i's sampler. `scale` is the
/// scene's normalization scale (world units per normalized unit).
pub fn trace_incident(
    frozen: &FrozenScene,
    points: &[ShadingPoint],
    n: usize,
    scale: f32,
    mixture_of: &(dyn Fn(usize) -> DirectionMixture + Sync),
    rngs: &mut [Pcg32],
) -> Vec<IncidentSample> {
    assert_eq!(points.len(), rngs.len(), "one sampler per point");
    let mut samples = vec![IncidentSample::default(); points.len() * n];
    let mut dirs = vec![Vec3::ZERO; points.len() * n];
    // 1. Directions and their weights.
    samples
        .par_chunks_mut(n)
        .zip(dirs.par_chunks_mut(n))
        .zip(rngs.par_iter_mut())
        .enumerate()
        .for_each(|(i, ((smp, dir), rng))| {
            let p = &points[i];
            let mix = mixture_of(i);
            for (s, d) in smp.iter_mut().zip(dir.iter_mut()) {
                let u: [f32; 3] = [rng.gen(), rng.gen(), rng.gen()];
                *s = IncidentSample {
                    emitter: -1,
                    ..Default::default()
                };
                let Some((wi, pdf)) = mix.sample(p.position, p.normal, p.view, u) else {
                    continue;
                };
                let n_dot_d = p.normal.dot(wi);
                if n_dot_d <= 0.0 || !(pdf > 0.0) || !pdf.is_finite() {
                    continue;
                }
                let h = (p.view + wi).normalize_or_zero();
                *s = IncidentSample {
                    n_dot_d,
                    n_dot_h: p.normal.dot(h),
                    d_dot_h: wi.dot(h),
                    weight: n_dot_d / (pdf * n as f32),
                    radiance: [0.0; 3],
                    emitter: -1,
                };
                *d = wi;
            }
        });
    // 2. Trace the live samples in one batch, then F_c at the non-emitter hits.
    let live: Vec<usize> = (0..samples.len()).filter(|&j| samples[j].weight > 0.0).collect();
    let rays: Vec<Ray> = live
        .iter()
        .map(|&j| {
            let p = &points[j / n];
            Ray::new(
                p.position + p.normal * (SECONDARY_OFFSET * scale),
                dirs[j],
                0.0,
                f32::INFINITY,
            )
        })
        .collect();
    let mut hits: Vec<Option<LabelledHit>> = vec![None; rays.len()];
    frozen.cast(&rays, &mut hits);
    let mut field_samples = Vec::new();
    let (mut field_points, mut field_dirs) = (Vec::new(), Vec::new());
    for (r, (&j, hit)) in rays.iter().zip(live.iter().zip(&hits)) {
        let Some(hit) = hit else {
            continue;
        };
        match hit.emitter {
            Some(k) => samples[j].emitter = k as i32,
            None => {
                field_samples.push(j);
                field_points.push(hit.position);
                field_dirs.push(r.dir);
            }
        }
    }
    let mut radiance = vec![Vec3::ZERO; field_points.len()];
    frozen.surface_radiance(&field_points, &field_dirs, &mut radiance);
    for (&j, l) in field_samples.iter().zip(&radiance) {
        samples[j].radiance = l.to_array();
    }
    samples
}

/// The radiance a sample carries under emissions `emission` (linear RGB per emitter).
#[inline]
fn arriving(s: &IncidentSample, emission: &[Vec3]) -> Vec3 {
    if s.emitter >= 0 {
        emission[s.emitter as usize]
    } else {
        Vec3::from_array(s.radiance)
    }
}

/// R̂ of eq:render for one point: `n_dot_v` is N·v, `samples` its incident samples.
pub fn shade(brdf: &GgxBrdf, n_dot_v: f32, samples: &[IncidentSample], emission: &[Vec3]) -> Vec3 {
    let mut sum = Vec3::ZERO;
    for s in samples {
        if s.weight == 0.0 {
            continue;
        }
        let f = brdf.eval_cosines(n_dot_v, s.n_dot_d, s.n_dot_h, s.d_dot_h);
        sum += f * arriving(s, emission) * s.weight;
    }
    sum
}

/// R̂ and the gradient of ⟨g, R̂⟩ with respect to the material (returned) and to each emission
/// (added to `d_emission`).
pub fn shade_backward(
    brdf: &GgxBrdf,
    n_dot_v: f32,
    samples: &[IncidentSample],
    emission: &[Vec3],
    g: Vec3,
    d_emission: &mut [Vec3],
) -> (Vec3, GgxGrad) {
    let mut sum = Vec3::ZERO;
    let mut grad = GgxGrad::default();
    for s in samples {
        if s.weight == 0.0 {
            continue;
        }
        let l = arriving(s, emission);
        let (f, gs) = brdf.eval_cosines_backward(n_dot_v, s.n_dot_d, s.n_dot_h, s.d_dot_h, g * l * s.weight);
        sum += f * l * s.weight;
        grad.kd += gs.kd;
        grad.ks += gs.ks;
        grad.rho += gs.rho;
        if s.emitter >= 0 {
            d_emission[s.emitter as usize] += g * f * s.weight;
        }
    }
    (sum, grad)
}

/// The diffuse part of a point's samples, Σ w L split into what F_c sends (`field`) and the
/// weight that reaches each emitter (`emit[k]`, to multiply by L\[k\]): R̂ = Kd/π ⊙ (field +
/// Σ emit\[k\] L\[k\]) + the specular part. Averaged over nearby points with similar normals
/// (irradiance is smooth where albedo is not), it is a denoised diffuse estimate.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DiffuseSums {
    pub field: Vec3,
    pub emit: Vec<f32>,
}

impl DiffuseSums {
    pub fn of(samples: &[IncidentSample], emitters: usize) -> Self {
        let mut d = DiffuseSums {
            field: Vec3::ZERO,
            emit: vec![0.0; emitters],
        };
        for s in samples {
            if s.emitter >= 0 {
                d.emit[s.emitter as usize] += s.weight;
            } else {
                d.field += Vec3::from_array(s.radiance) * s.weight;
            }
        }
        d
    }

    /// The mean of `sums` (zeros for none), each with `emitters` emitter weights. The sums
    /// are added in the order given (pooling is bit-reproducible).
    pub(crate) fn mean<'s>(sums: impl IntoIterator<Item = &'s DiffuseSums>, emitters: usize) -> Self {
        let mut acc = DiffuseSums {
            field: Vec3::ZERO,
            emit: vec![0.0; emitters],
        };
        let mut n = 0u32;
        for s in sums {
            acc.field += s.field;
            acc.emit.iter_mut().zip(&s.emit).for_each(|(a, b)| *a += b);
            n += 1;
        }
        let inv = 1.0 / n.max(1) as f32;
        acc.field *= inv;
        acc.emit.iter_mut().for_each(|a| *a *= inv);
        acc
    }

    pub(crate) fn irradiance(&self, emission: &[Vec3]) -> Vec3 {
        self.field + self.emit.iter().zip(emission).map(|(w, l)| *l * *w).sum::<Vec3>()
    }

    /// The diffuse part Kd/π ⊙ E and the gradient of ⟨g, ·⟩ with respect to Kd (returned) and
    /// to each emission (added to `d_emission`).
    pub(crate) fn backward(&self, kd: Vec3, emission: &[Vec3], g: Vec3, d_emission: &mut [Vec3]) -> (Vec3, Vec3) {
        use std::f32::consts::FRAC_1_PI;
        let e = self.irradiance(emission);
        for (d, w) in d_emission.iter_mut().zip(&self.emit) {
            *d += g * kd * (FRAC_1_PI * w);
        }
        (kd * FRAC_1_PI * e, g * e * FRAC_1_PI)
    }
}

/// R̂ with the diffuse part taken from `diffuse` (see [`DiffuseSums`]) and the specular part
/// from the samples; equal to [`shade`] when `diffuse` is the samples' own sums.
pub fn shade_pooled(
    brdf: &GgxBrdf,
    n_dot_v: f32,
    samples: &[IncidentSample],
    emission: &[Vec3],
    diffuse: &DiffuseSums,
) -> Vec3 {
    let spec = GgxBrdf {
        kd: Vec3::ZERO,
        ..*brdf
    };
    brdf.kd * std::f32::consts::FRAC_1_PI * diffuse.irradiance(emission) + shade(&spec, n_dot_v, samples, emission)
}

/// [`shade_pooled`] and its gradient (as [`shade_backward`]).
pub fn shade_pooled_backward(
    brdf: &GgxBrdf,
    n_dot_v: f32,
    samples: &[IncidentSample],
    emission: &[Vec3],
    diffuse: &DiffuseSums,
    g: Vec3,
    d_emission: &mut [Vec3],
) -> (Vec3, GgxGrad) {
    let spec = GgxBrdf {
        kd: Vec3::ZERO,
        ..*brdf
    };
    let (s, mut grad) = shade_backward(&spec, n_dot_v, samples, emission, g, d_emission);
    let (d, kd) = diffuse.backward(brdf.kd, emission, g, d_emission);
    grad.kd = kd;
    (d + s, grad)
}

/// Averages each surface pixel's [`DiffuseSums`] over the surface pixels within `radius` (world)
/// whose normals agree (cos > 0.9): those with `|q − p|² <= radius²` in f32, which a [`KdTree`]
/// of the positions finds, summed in ascending pixel index (the same on every run and thread
/// count). Irradiance varies slowly across a surface while albedo does not, so the diffuse
/// estimate of a pixel borrows the samples of its neighbours (from other views too) — the
/// material fit no longer bakes one noisy draw per pixel into Kd. The bias is the blur of
/// irradiance over the radius (shadow edges soften by about that much).
pub fn pool_diffuse(points: &[ShadingPoint], sums: &[DiffuseSums], radius: f32) -> Vec<DiffuseSums> {
    let positions: Vec<[f32; 3]> = points.iter().map(|p| p.position.to_array()).collect();
    let tree = KdTree::new(&positions);
    // Pixels in the tree's order: consecutive ones share most of their neighbours, which stay in
    // cache (pixels come from many views, in no spatial order). Each result is its own pixel's.
    let order = tree.storage_order();
    let pooled: Vec<DiffuseSums> = order
        .par_iter()
        .map_init(Vec::new, |near, &i| {
            let p = &points[i as usize];
            tree.within(positions[i as usize], radius, near);
            let similar = near.iter().filter(|&&j| points[j].normal.dot(p.normal) > 0.9);
            DiffuseSums::mean(similar.map(|&j| &sums[j]), sums[i as usize].emit.len())
        })
        .collect();
    let mut out = vec![DiffuseSums::default(); points.len()];
    for (&i, d) in order.iter().zip(pooled) {
        out[i as usize] = d;
    }
    out
}

/// Test support: the analytic gradient of ⟨g, R̂⟩ (material `grad`, emissions `d_emission`)
/// against central differences of `loss` with step `h` in every channel of Kd and Ks, in ρ and
/// in every channel of every L[k]; the tolerance is relative, for f32.
#[cfg(test)]
pub(crate) fn check_gradient_by_differences(
    trial: usize,
    brdf: &GgxBrdf,
    emission: &[Vec3],
    grad: &GgxGrad,
    d_emission: &[Vec3],
    h: f32,
    loss: &dyn Fn(&GgxBrdf, &[Vec3]) -> f64,
) {
    let check = |name: &str, analytic: f32, plus: f64, minus: f64| {
        let fd = (plus - minus) / (2.0 * h as f64);
        let tol = 2e-3 + 2e-2 * fd.abs().max(analytic.abs() as f64);
        assert!(
            (fd - analytic as f64).abs() < tol,
            "trial {trial} {name}: analytic {analytic}, finite difference {fd}"
        );
    };
    for c in 0..3 {
        let (mut p, mut m) = (*brdf, *brdf);
        p.kd[c] += h;
        m.kd[c] -= h;
        check("kd", grad.kd[c], loss(&p, emission), loss(&m, emission));
        let (mut p, mut m) = (*brdf, *brdf);
        p.ks[c] += h;
        m.ks[c] -= h;
        check("ks", grad.ks[c], loss(&p, emission), loss(&m, emission));
        for k in 0..emission.len() {
            let (mut ep, mut em) = (emission.to_vec(), emission.to_vec());
            ep[k][c] += h;
            em[k][c] -= h;
            check("emission", d_emission[k][c], loss(brdf, &ep), loss(brdf, &em));
        }
    }
    let (mut p, mut m) = (*brdf, *brdf);
    p.rho += h;
    m.rho -= h;
    check("rho", grad.rho, loss(&p, emission), loss(&m, emission));
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn random_samples(rng: &mut Pcg32, n: usize, emitters: i32) -> (f32, Vec<IncidentSample>) {
        let nv = 0.2 + 0.8 * rng.gen::<f32>();
        let n_vec = Vec3::Z;
        let v = Vec3::new((1.0 - nv * nv).sqrt(), 0.0, nv);
        let samples = (0..n)
            .map(|_| {
                let (a, b): (f32, f32) = (rng.gen::<f32>() * 6.283, rng.gen::<f32>());
                let r = (1.0 - b * b).sqrt();
                let d = Vec3::new(r * a.cos(), r * a.sin(), b.max(0.05));
                let d = d.normalize();
                let h = (v + d).normalize();
                IncidentSample {
                    n_dot_d: n_vec.dot(d),
                    n_dot_h: n_vec.dot(h),
                    d_dot_h: d.dot(h),
                    weight: rng.gen::<f32>() * 0.3,
                    radiance: [rng.gen(), rng.gen(), rng.gen()],
                    emitter: if rng.gen::<f32>() < 0.4 {
                        rng.gen_range(0..emitters)
                    } else {
                        -1
                    },
                }
            })
            .collect();
        (nv, samples)
    }

    /// The estimator's gradient w.r.t. Kd, Ks, ρ and every L[k] matches central differences of
    /// ⟨g, R̂⟩ (f64-free: the step is chosen for f32 and the tolerance is relative).
    #[test]
    fn estimator_gradient_matches_finite_differences() {
        let mut rng = Pcg32::seed_from_u64(11);
        for trial in 0..40 {
            let (nv, samples) = random_samples(&mut rng, 24, 2);
            let brdf = GgxBrdf::new(
                Vec3::new(rng.gen(), rng.gen(), rng.gen()) * 0.8,
                Vec3::new(rng.gen(), rng.gen(), rng.gen()) * 0.5,
                0.15 + 0.8 * rng.gen::<f32>(),
            );
            let emission = vec![Vec3::new(3.0, 2.0, 1.0), Vec3::new(0.5, 8.0, 2.0)];
            let g = Vec3::new(rng.gen::<f32>() - 0.5, rng.gen::<f32>() - 0.5, rng.gen::<f32>() - 0.5);
            let mut d_em = vec![Vec3::ZERO; 2];
            let (value, grad) = shade_backward(&brdf, nv, &samples, &emission, g, &mut d_em);
            assert!((value - shade(&brdf, nv, &samples, &emission)).abs().max_element() < 1e-5);
            let loss = |b: &GgxBrdf, e: &[Vec3]| g.dot(shade(b, nv, &samples, e)) as f64;
            check_gradient_by_differences(trial, &brdf, &emission, &grad, &d_em, 1e-3f32, &loss);
            // The pooled form with the samples' own sums is the same estimator, gradients included.
            let own = DiffuseSums::of(&samples, 2);
            let mut d_em2 = vec![Vec3::ZERO; 2];
            let (v2, g2) = shade_pooled_backward(&brdf, nv, &samples, &emission, &own, g, &mut d_em2);
            assert!((v2 - value).abs().max_element() < 1e-4 * (1.0 + value.abs().max_element()));
            assert!(
                (v2 - shade_pooled(&brdf, nv, &samples, &emission, &own))
                    .abs()
                    .max_element()
                    < 1e-5
            );
            for (a, b) in [
                (g2.kd, grad.kd),
                (g2.ks, grad.ks),
                (d_em2[0], d_em[0]),
                (d_em2[1], d_em[1]),
            ] {
                assert!(
                    (a - b).abs().max_element() < 1e-4 * (1.0 + b.abs().max_element()),
                    "{a} vs {b}"
                );
            }
            assert!((g2.rho - grad.rho).abs() < 1e-4 * (1.0 + grad.rho.abs()));
        }
    }

    /// The pooling's neighbours are exactly those of the distance test it had with its grid,
    /// `(q − p).length_squared() <= r²` on glam vectors, points at exactly the radius included
    /// (positions on a quarter-unit lattice, radius 0.5 and 0.75), and the sums run in index
    /// order: equal, to the bit, to this brute-force pooling.
    #[test]
    fn pooling_matches_brute_force_at_the_radius() {
        let mut rng = Pcg32::seed_from_u64(4);
        let mut positions: Vec<Vec3> = (0..6 * 6 * 6)
            .map(|i| Vec3::new((i % 6) as f32, (i / 6 % 6) as f32, (i / 36) as f32) * 0.25)
            .collect();
        positions.extend((0..400).map(|_| Vec3::new(rng.gen(), rng.gen(), rng.gen()) * 1.5));
        let mut points: Vec<ShadingPoint> = positions
            .into_iter()
            .map(|position| {
                let normal = if rng.gen::<f32>() < 0.8 { Vec3::Y } else { Vec3::X };
                ShadingPoint {
                    position,
                    normal,
                    view: normal,
                }
            })
            .collect();
        points[3].normal = Vec3::new(0.0, 0.9, 0.1).normalize();
        let sums: Vec<DiffuseSums> = (0..points.len())
            .map(|_| DiffuseSums {
                field: Vec3::new(rng.gen(), rng.gen(), rng.gen()),
                emit: vec![rng.gen(), rng.gen()],
            })
            .collect();
        for radius in [0.5f32, 0.75, 0.1] {
            let pooled = pool_diffuse(&points, &sums, radius);
            let r2 = radius * radius;
            let mut at_radius = 0;
            for (i, p) in points.iter().enumerate() {
                let mut similar = Vec::new();
                for (q, s) in points.iter().zip(&sums) {
                    let d2 = (q.position - p.position).length_squared();
                    at_radius += usize::from(d2 == r2);
                    if d2 <= r2 && q.normal.dot(p.normal) > 0.9 {
                        similar.push(s);
                    }
                }
                let acc = DiffuseSums::mean(similar, 2);
                assert_eq!(pooled[i], acc, "pixel {i}, radius {radius}");
            }
            assert!(radius == 0.1 || at_radius > 500, "{at_radius} pairs at radius {radius}");
        }
    }
}
