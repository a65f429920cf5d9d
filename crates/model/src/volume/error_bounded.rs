//! VolSDF's error-bounded sampler (Yariv et al. 2021, Sec. 3.3 and Alg. 1): per ray, uniform
//! samples, then rounds that bound the opacity error with d* (Theorem 1), bisect β+ and upsample
//! where the bound is large; the final samples drawn from the rendering weights. With an
//! occupancy grid ([`crate::occupancy`]) it samples the occupied stretches only.

use super::{deltas_from_t, sample_piecewise_constant, sample_unit_values, uniform_samples};
use i2sdf_nn::activation::exp_fast;
use rand::Rng;

/// Settings of [`error_bounded_samples`]; the defaults are VolSDF's.
#[derive(Clone, Debug)]
pub struct ErrorBoundedSamplerConfig {
    /// Samples drawn from the final weights (VolSDF `N_samples`).
    pub num_samples: usize,
    /// Samples of the initial uniform pass (`N_samples_eval`).
    pub num_samples_eval: usize,
    /// Samples added by each upsampling round (VolSDF: `N_samples_eval` again).
    pub num_samples_upsample: usize,
    /// Samples of the evaluated set kept besides the final ones (`N_samples_extra`).
    pub num_samples_extra: usize,
    /// Bound ε on the opacity error (`eps`).
    pub eps: f32,
    /// Bisection steps on β+ per round (`beta_iters`).
    pub beta_iters: usize,
    /// Rounds of evaluate/bound/upsample (`max_total_iters`).
    pub max_total_iters: usize,
    /// δ of each ray's last sample in the returned `delta` (VolSDF: 1e10).
    pub last_delta: f32,
}

impl Default for ErrorBoundedSamplerConfig {
    fn default() -> Self {
        ErrorBoundedSamplerConfig {
            num_samples: 64,
            num_samples_eval: 128,
            num_samples_upsample: 128,
            num_samples_extra: 32,
            eps: 0.1,
            beta_iters: 10,
            max_total_iters: 5,
            last_delta: 1e10,
        }
    }
}

/// Packed samples for a batch of rays, ready for [`composite_batch`] once σ is known.
#[derive(Clone, Debug, Default)]
pub struct RaySampleSet {
    pub ray_offsets: Vec<u32>,
    pub t: Vec<f32>,
    pub delta: Vec<f32>,
    /// The β each ray's final samples were drawn with: the model's β where the bound converged,
    /// the last β+ otherwise.
    pub beta_used: Vec<f32>,
    /// Rays whose opacity error bound reached ε at the model's β.
    pub converged: Vec<bool>,
    /// SDF evaluations spent.
    pub sdf_evaluations: usize,
}

/// d* of Theorem 1 (VolSDF): a lower bound on |SDF| inside the interval [t_i, t_{i+1}] of length
/// a with |SDF| = b and c at its ends, zero when the SDF changes sign (a surface may be inside).
pub(super) fn interval_distance_bound(a: f32, d0: f32, d1: f32) -> f32 {
    let same_sign = (d0 > 0.0 && d1 > 0.0) || (d0 < 0.0 && d1 < 0.0);
    if !same_sign {
        return 0.0;
    }
    let (b, c) = (d0.abs(), d1.abs());
    if a * a + b * b <= c * c {
        b
    } else if a * a + c * c <= b * b {
        c
    } else if b + c - a > 0.0 {
        // The height over side a of the triangle with sides a, b, c (Heron).
        let s = 0.5 * (a + b + c);
        let area2 = (s * (s - a) * (s - b) * (s - c)).max(0.0);
        2.0 * area2.sqrt() / a
    } else {
        0.0
    }
}

/// Per-interval error bound of the opacity at β (VolSDF Theorem 1 / `get_error_bound`), written to
/// `bound[i]` for the intervals; returns the maximum. `open[i]` is 1 for an interval the density
/// lives in and 0 for one across cells the occupancy grid found free ([`crate::occupancy`]). With E_i = Σ_{j≤i} e^{−d*_j/β} δ_j² / (4β²)
/// and T_i = exp(−Σ_{j<i} δ_j σ_j), bound_i = (e^{E_i} − 1) T_i, e^{E_i} capped at 1e6 as VolSDF.
///
/// Three passes so that the exponentials (four per interval, evaluated for every bisection step:
/// with libm's scalar `expf` they were half the sampler's time) run as vectorized `exp_fast`:
/// the per-interval terms, their prefix sums, the bounds. `tau` is scratch of the same length.
pub(super) fn opacity_error_bound(
    z: &[f32],
    sdf: &[f32],
    d_star: &[f32],
    open: &[f32],
    beta: f32,
    tau: &mut [f32],
    bound: &mut [f32],
) -> f32 {
    let m = z.len() - 1;
    // Every slice cut to the m intervals, so that the loops carry no bounds checks and vectorize.
    let (z0, z1, sdf, d_star, open) = (&z[..m], &z[1..=m], &sdf[..m], &d_star[..m], &open[..m]);
    let (tau, bound) = (&mut tau[..m], &mut bound[..m]);
    let inv_beta = 1.0 / beta;
    let c = 0.25 * inv_beta * inv_beta;
    for i in 0..m {
        // An interval across free space (open 0) has no density: no optical depth, no error.
        let delta = (z1[i] - z0[i]) * open[i];
        let e = exp_fast(-sdf[i].abs() * inv_beta);
        // laplace_density, branch-free.
        let sigma = if sdf[i] >= 0.0 { 0.5 * e } else { 1.0 - 0.5 * e } * inv_beta;
        tau[i] = delta * sigma;
        bound[i] = exp_fast(-d_star[i] * inv_beta) * delta * delta * c;
    }
    // Prefix sums: `tau[i]` becomes −Σ_{j<i} τ_j, `bound[i]` becomes E_i.
    let (mut integral, mut error) = (0.0f32, 0.0f32);
    for i in 0..m {
        let t = tau[i];
        tau[i] = -integral;
        integral += t;
        error += bound[i];
        bound[i] = error;
    }
    const LN_1E6: f32 = 13.815_511;
    for i in 0..m {
        // ≥ 0 (and NaN to 0, as `f32::max` ignored it before), so that the bits order as floats.
        bound[i] = ((exp_fast(bound[i].min(LN_1E6)) - 1.0) * exp_fast(tau[i])).max(0.0);
    }
    // The maximum as an integer reduction, which vectorizes where a float one does not.
    f32::from_bits(bound.iter().map(|b| b.to_bits()).max().unwrap_or(0))
}

/// The volume-rendering weights of a ray's intervals at β (the Laplace density of the left end
/// over each interval; none over an interval across free space, `open[i]` 0), plus VolSDF's
/// floor of 1e-5 that keeps every interval reachable, written to `weights` (one per interval);
/// `tau` is scratch. Vectorized like [`opacity_error_bound`].
pub(super) fn interval_weights(
    z: &[f32],
    sdf: &[f32],
    open: &[f32],
    beta: f32,
    tau: &mut Vec<f32>,
    weights: &mut Vec<f32>,
) {
    let m = z.len() - 1;
    tau.resize(m, 0.0);
    weights.resize(m, 0.0);
    let (z0, z1, sdf, open) = (&z[..m], &z[1..=m], &sdf[..m], &open[..m]);
    let (tau, weights) = (&mut tau[..m], &mut weights[..m]);
    let inv_beta = 1.0 / beta;
    for i in 0..m {
        let e = exp_fast(-sdf[i].abs() * inv_beta);
        let sigma = if sdf[i] >= 0.0 { 0.5 * e } else { 1.0 - 0.5 * e } * inv_beta;
        tau[i] = sigma * (z1[i] - z0[i]) * open[i];
    }
    // `weights[i]` holds −Σ_{j<i} τ_j for the next pass.
    let mut integral = 0.0f32;
    for i in 0..m {
        weights[i] = -integral;
        integral += tau[i];
    }
    for i in 0..m {
        // T_i (1 − e^{−τ_i}).
        weights[i] = exp_fast(weights[i]) * (1.0 - exp_fast(-tau[i])) + 1e-5;
    }
}

/// One ray's state in the error-bounded sampler. Kept in [`SamplerScratch`] between calls, so
/// that its buffers are reused rather than reallocated every round and every batch.
#[derive(Default)]
pub(super) struct RayState {
    pub(super) z: Vec<f32>,
    pub(super) sdf: Vec<f32>,
    pub(super) beta_plus: f32,
    pub(super) done: bool,
    pub(super) converged: bool,
    /// New sample positions awaiting SDF values, sorted.
    pub(super) pending: Vec<f32>,
    /// The ray's stretches through occupied cells (sorted, disjoint), where it has an occupancy
    /// grid; empty: the whole [near, far] is open.
    pub(super) occupied: Vec<[f32; 2]>,
}

impl RayState {
    /// Per interval of `z`, 1 when the density lives in it (no occupancy, or both ends in the
    /// same occupied stretch) and 0 across free space; into `open`.
    fn open_intervals(&self, open: &mut Vec<f32>) {
        let m = self.z.len().saturating_sub(1);
        open.clear();
        if self.occupied.is_empty() {
            open.resize(m, 1.0);
            return;
        }
        let stretch = |t: f32| {
            let i = self.occupied.partition_point(|iv| iv[1] < t);
            (i < self.occupied.len() && self.occupied[i][0] <= t).then_some(i)
        };
        let Some(&first) = self.z.first() else { return };
        let mut left = stretch(first);
        for i in 0..m {
            let right = stretch(self.z[i + 1]);
            open.push(if left.is_some() && left == right { 1.0 } else { 0.0 });
            left = right;
        }
    }
}

/// Buffers of [`error_bounded_samples_into`], kept by the caller between batches: after the first
/// batch of a given size the sampler allocates nothing.
#[derive(Default)]
pub struct SamplerScratch {
    states: Vec<RayState>,
    points: Vec<[f32; 3]>,
    values: Vec<f32>,
    ray: RayScratch,
}

/// The buffers of one ray's round or final draw, reused ray after ray.
#[derive(Default)]
struct RayScratch {
    d_star: Vec<f32>,
    open: Vec<f32>,
    bound: Vec<f32>,
    tau: Vec<f32>,
    weights: Vec<f32>,
    u: Vec<f32>,
    new_t: Vec<f32>,
    ray_t: Vec<f32>,
    merged_t: Vec<f32>,
    merged_v: Vec<f32>,
}

/// VolSDF's error-bounded sampler (Yariv et al. 2021, Alg. 1) over a batched SDF evaluator:
/// uniform samples; then rounds of: evaluate the new samples, bound the opacity error with d*
/// (Theorem 1), bisect β+ ∈ [β, β+] to the smallest β whose bound is ≤ ε, and, while that β is
/// above the model's, upsample where the bound is large. The final samples are drawn by inverse
/// CDF from the volume-rendering weights at the reached β, plus near, far and
/// `num_samples_extra` of the evaluated samples. Unlike VolSDF, which stops when every ray in the
/// batch converged, each ray stops upsampling as soon as it converged.
///
/// `sdf(points, values)` fills the SDF at world points; it is called once per round with every
/// pending point of the batch. Without an RNG everything is deterministic (evaluation); with one,
/// the initial samples are stratified, the final ones random and the extra ones a random subset
/// (training). This form allocates its buffers; [`error_bounded_samples_into`] reuses them.
#[allow(clippy::too_many_arguments)]
pub fn error_bounded_samples<F, R>(
    config: &ErrorBoundedSamplerConfig,
    origins: &[[f32; 3]],
    directions: &[[f32; 3]],
    near: &[f32],
    far: &[f32],
    beta: f32,
    sdf: F,
    rng: Option<&mut R>,
) -> RaySampleSet
where
    F: FnMut(&[[f32; 3]], &mut [f32]),
    R: Rng + ?Sized,
{
    let mut set = RaySampleSet::default();
    let rays = RayBatchRef {
        origins,
        directions,
        near,
        far,
        occupied: None,
    };
    error_bounded_samples_into(config, &rays, beta, sdf, rng, &mut SamplerScratch::default(), &mut set);
    set
}

/// The rays of one [`error_bounded_samples_into`] call: unit directions, and the interval
/// [near, far] of each.
pub struct RayBatchRef<'a> {
    pub origins: &'a [[f32; 3]],
    pub directions: &'a [[f32; 3]],
    pub near: &'a [f32],
    pub far: &'a [f32],
    /// Each ray's stretches through occupied cells ([`crate::occupancy::OccupancyGrid::intervals`]):
    /// ray r's are `intervals[offsets[r]..offsets[r + 1]]`. The sampler then spends its
    /// evaluations there, gives free space no density, and ends the ray where the last stretch
    /// ends (the grid's cut at a solid cell). A ray with no stretch is sampled over all of
    /// [near, far]. `None`: no grid.
    pub occupied: Option<OccupiedStretches<'a>>,
}

/// The occupied stretches of a batch of rays (see [`RayBatchRef::occupied`]).
#[derive(Clone, Copy)]
pub struct OccupiedStretches<'a> {
    pub offsets: &'a [u32],
    pub intervals: &'a [[f32; 2]],
}

/// [`error_bounded_samples`] into `set` (overwritten), with the caller's buffers.
pub fn error_bounded_samples_into<F, R>(
    config: &ErrorBoundedSamplerConfig,
    rays: &RayBatchRef,
    beta: f32,
    mut sdf: F,
    mut rng: Option<&mut R>,
    scratch: &mut SamplerScratch,
    set: &mut RaySampleSet,
) where
    F: FnMut(&[[f32; 3]], &mut [f32]),
    R: Rng + ?Sized,
{
    let n_rays = rays.origins.len();
    assert!(rays.directions.len() == n_rays && rays.near.len() == n_rays && rays.far.len() == n_rays);
    assert!(config.num_samples_eval >= 2 && beta > 0.0 && config.eps > 0.0);
    let SamplerScratch {
        states,
        points,
        values,
        ray,
    } = scratch;
    init_ray_states(config, rays, beta, rng.as_deref_mut(), states);
    let rounds = config.max_total_iters.max(1);
    let mut evaluations = 0;
    for round in 0..rounds {
        // Evaluate every ray's pending samples in one call.
        pending_points(rays, states, points);
        if points.is_empty() {
            break;
        }
        values.resize(points.len(), 0.0);
        sdf(points, values);
        evaluations += points.len();
        let mut offset = 0;
        let last_round = round + 1 == rounds;
        for state in states.iter_mut().filter(|s| !s.pending.is_empty()) {
            let new_values = &values[offset..offset + state.pending.len()];
            offset += state.pending.len();
            refine_ray::<R>(config, beta, last_round, state, new_values, ray);
        }
        if states.iter().all(|s| s.done) {
            break;
        }
    }
    write_final_samples(config, rays, rng, states, evaluations, ray, set);
}

/// `n` samples spread evenly over the total length of the occupied `stretches` (stratified with
/// an RNG), plus both ends of each stretch, sorted, into `out`.
fn stretch_samples<R: Rng + ?Sized>(stretches: &[[f32; 2]], n: usize, mut rng: Option<&mut R>, out: &mut Vec<f32>) {
    out.clear();
    let total: f32 = stretches.iter().map(|iv| iv[1] - iv[0]).sum();
    for iv in stretches {
        out.push(iv[0]);
        out.push(iv[1]);
    }
    let (mut k, mut before) = (0usize, 0.0f32);
    for i in 0..n {
        let jitter = rng.as_deref_mut().map_or(0.5, |r| r.gen::<f32>());
        let u = (i as f32 + jitter) / n as f32 * total;
        while k + 1 < stretches.len() && before + (stretches[k][1] - stretches[k][0]) < u {
            before += stretches[k][1] - stretches[k][0];
            k += 1;
        }
        out.push((stretches[k][0] + (u - before)).clamp(stretches[k][0], stretches[k][1]));
    }
    out.sort_unstable_by(f32::total_cmp);
}

/// Starts every ray of the batch: `num_samples_eval` uniform samples (stratified with an RNG)
/// pending, and the β+ of Lemma 2.
fn init_ray_states<R: Rng + ?Sized>(
    config: &ErrorBoundedSamplerConfig,
    rays: &RayBatchRef,
    beta: f32,
    mut rng: Option<&mut R>,
    states: &mut Vec<RayState>,
) {
    let n_eval = config.num_samples_eval;
    states.resize_with(rays.origins.len(), RayState::default);
    for (r, state) in states.iter_mut().enumerate() {
        state.z.clear();
        state.sdf.clear();
        state.pending.clear();
        state.occupied.clear();
        if let Some(occ) = &rays.occupied {
            let (a, b) = (occ.offsets[r] as usize, occ.offsets[r + 1] as usize);
            state.occupied.extend_from_slice(&occ.intervals[a..b]);
        }
        if state.occupied.is_empty() {
            state.pending.resize(n_eval, 0.0);
            uniform_samples(rays.near[r], rays.far[r], rng.as_deref_mut(), &mut state.pending);
        } else {
            stretch_samples(&state.occupied, n_eval, rng.as_deref_mut(), &mut state.pending);
        }
        // Lemma 2: this β+ bounds the opacity error by ε whatever the SDF (free space, between
        // stretches, has no density and adds nothing).
        let sum_sq: f32 = state.pending.windows(2).map(|w| (w[1] - w[0]).powi(2)).sum();
        state.beta_plus = (sum_sq / (4.0 * (1.0 + config.eps).ln())).sqrt().max(beta);
        state.done = false;
        state.converged = false;
    }
}

/// The world points of every ray's pending samples, ray after ray, into `points`.
fn pending_points(rays: &RayBatchRef, states: &[RayState], points: &mut Vec<[f32; 3]>) {
    points.clear();
    for (r, state) in states.iter().enumerate() {
        let (o, d) = (rays.origins[r], rays.directions[r]);
        points.extend(
            state
                .pending
                .iter()
                .map(|&t| [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]]),
        );
    }
}

/// One round of one ray, given the SDF at its pending samples: merges them in, bisects β+ and,
/// unless β+ reached the model's β or this is the last round, queues `num_samples_upsample`
/// samples drawn in proportion to the error bound at β+.
fn refine_ray<R: Rng + ?Sized>(
    config: &ErrorBoundedSamplerConfig,
    beta: f32,
    last_round: bool,
    state: &mut RayState,
    new_values: &[f32],
    s: &mut RayScratch,
) {
    merge_sorted(state, new_values, &mut s.merged_t, &mut s.merged_v);
    let m = state.z.len();
    s.d_star.clear();
    s.d_star.extend(
        (0..m - 1).map(|i| interval_distance_bound(state.z[i + 1] - state.z[i], state.sdf[i], state.sdf[i + 1])),
    );
    state.open_intervals(&mut s.open);
    s.bound.resize(m - 1, 0.0);
    s.tau.resize(m - 1, 0.0);
    state.beta_plus = bisect_beta_plus(config, beta, state, s);
    state.converged = state.beta_plus <= beta;
    if state.converged || last_round {
        state.done = true;
        return;
    }
    // Upsample proportionally to the error bound at the current β+.
    opacity_error_bound(
        &state.z,
        &state.sdf,
        &s.d_star,
        &s.open,
        state.beta_plus,
        &mut s.tau,
        &mut s.bound,
    );
    // Nothing upsampled across free space (its bound is the error accumulated before it).
    for (b, o) in s.bound.iter_mut().zip(&s.open) {
        *b *= o;
    }
    s.u.resize(config.num_samples_upsample.max(1), 0.0);
    sample_unit_values::<R>(None, &mut s.u);
    s.new_t.resize(s.u.len(), 0.0);
    sample_piecewise_constant(&state.z, &s.bound, &s.u, &mut s.new_t);
    state.pending.extend_from_slice(&s.new_t);
}

/// Bisection on β ∈ [β_model, β+] for the smallest β whose opacity error bound (with the ray's
/// d* in `s.d_star`) is ≤ ε: the model's β when its own bound already is.
fn bisect_beta_plus(config: &ErrorBoundedSamplerConfig, beta: f32, state: &RayState, s: &mut RayScratch) -> f32 {
    let (z, sdf) = (&state.z, &state.sdf);
    if opacity_error_bound(z, sdf, &s.d_star, &s.open, beta, &mut s.tau, &mut s.bound) <= config.eps {
        return beta;
    }
    let (mut lo, mut hi) = (beta, state.beta_plus);
    for _ in 0..config.beta_iters {
        let mid = 0.5 * (lo + hi);
        if opacity_error_bound(z, sdf, &s.d_star, &s.open, mid, &mut s.tau, &mut s.bound) <= config.eps {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    hi
}

/// Packs every ray's final samples ([`final_ray_samples`]) into `set`, with their deltas.
fn write_final_samples<R: Rng + ?Sized>(
    config: &ErrorBoundedSamplerConfig,
    rays: &RayBatchRef,
    mut rng: Option<&mut R>,
    states: &[RayState],
    evaluations: usize,
    s: &mut RayScratch,
    set: &mut RaySampleSet,
) {
    set.ray_offsets.clear();
    set.ray_offsets.push(0);
    set.t.clear();
    set.beta_used.clear();
    set.converged.clear();
    set.sdf_evaluations = evaluations;
    for (r, state) in states.iter().enumerate() {
        final_ray_samples(config, rays.near[r], rays.far[r], rng.as_deref_mut(), state, s);
        set.t.extend_from_slice(&s.ray_t);
        set.ray_offsets.push(set.t.len() as u32);
        set.beta_used.push(state.beta_plus);
        set.converged.push(state.converged);
    }
    set.delta.clear();
    set.delta.resize(set.t.len(), 0.0);
    deltas_from_t(&set.ray_offsets, &set.t, config.last_delta, &mut set.delta);
    // Free space has no density: a sample's interval stops where its occupied stretch does (and
    // a sample outside every stretch has none). The last sample keeps its `last_delta`.
    for (r, state) in states.iter().enumerate().filter(|(_, st)| !st.occupied.is_empty()) {
        let (a, b) = (set.ray_offsets[r] as usize, set.ray_offsets[r + 1] as usize);
        for i in a..b.saturating_sub(1) {
            let t = set.t[i];
            let k = state.occupied.partition_point(|iv| iv[1] < t);
            set.delta[i] = match state.occupied.get(k) {
                Some(iv) if iv[0] <= t => set.delta[i].min(iv[1] - t),
                _ => 0.0,
            };
        }
    }
}

/// One ray's final samples into `s.ray_t`, sorted: `num_samples` drawn by inverse CDF from the
/// rendering weights at its reached β, its near and far (the ends of its occupied stretches where
/// it has them), and `num_samples_extra` of its evaluated
/// samples (evenly spaced without an RNG, a random subset with one).
fn final_ray_samples<R: Rng + ?Sized>(
    config: &ErrorBoundedSamplerConfig,
    near: f32,
    far: f32,
    mut rng: Option<&mut R>,
    state: &RayState,
    s: &mut RayScratch,
) {
    let m = state.z.len();
    state.open_intervals(&mut s.open);
    interval_weights(
        &state.z,
        &state.sdf,
        &s.open,
        state.beta_plus,
        &mut s.tau,
        &mut s.weights,
    );
    s.u.resize(config.num_samples, 0.0);
    sample_unit_values(rng.as_deref_mut(), &mut s.u);
    let ray_t = &mut s.ray_t;
    ray_t.resize(config.num_samples, 0.0);
    sample_piecewise_constant(&state.z, &s.weights, &s.u, ray_t);
    // With an occupancy grid the ray lives from its first stretch to the end of its last (the cut).
    match (state.occupied.first(), state.occupied.last()) {
        (Some(first), Some(last)) => {
            ray_t.push(first[0]);
            ray_t.push(last[1]);
        }
        _ => {
            ray_t.push(near);
            ray_t.push(far);
        }
    }
    let extra = config.num_samples_extra.min(m);
    match rng {
        Some(rng) => {
            let picks = rand::seq::index::sample(rng, m, extra);
            ray_t.extend(picks.iter().map(|i| state.z[i]));
        }
        None => {
            for j in 0..extra {
                let i = if extra > 1 { j * (m - 1) / (extra - 1) } else { 0 };
                ray_t.push(state.z[i]);
            }
        }
    }
    ray_t.sort_unstable_by(f32::total_cmp);
}

/// Merges the ray's sorted `pending` samples (with `new_values`) into its sorted `z`/`sdf`, in
/// one linear pass through the scratch `mt`/`mv`; `pending` is left empty.
pub(super) fn merge_sorted(state: &mut RayState, new_values: &[f32], mt: &mut Vec<f32>, mv: &mut Vec<f32>) {
    let (z, v, p) = (&state.z, &state.sdf, &state.pending);
    debug_assert!(p.windows(2).all(|w| w[0] <= w[1]));
    mt.clear();
    mv.clear();
    let (mut i, mut j) = (0, 0);
    while i < z.len() || j < p.len() {
        if j == p.len() || (i < z.len() && z[i] <= p[j]) {
            mt.push(z[i]);
            mv.push(v[i]);
            i += 1;
        } else {
            mt.push(p[j]);
            mv.push(new_values[j]);
            j += 1;
        }
    }
    std::mem::swap(&mut state.z, mt);
    std::mem::swap(&mut state.sdf, mv);
    state.pending.clear();
}
