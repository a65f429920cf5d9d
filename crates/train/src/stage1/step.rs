//! One iteration of stage 1 (eq:train1 with eq:traing's geometry terms, in the step of the
//! schedule the iteration falls in): draw a batch of rays and the extra points the geometry terms
//! need, render, evaluate the losses on the rays and on the points, let the PDF maps learn from
//! the depth errors, then backpropagate and update. Every random draw happens in the same order on
//! every run, so a resumed run repeats the uninterrupted one exactly.

use super::losses;
use super::pdf_map::PixelRef;
use super::schedule::{LossWeights, Phase};
use super::{Stage1, StepStats};
use crate::driver::StepOutcome;
use i2sdf_model::occupancy::OccupancyGrid;
use i2sdf_model::renderer::{self, RayGrads};
use rand::Rng;
use rand_pcg::Pcg64;

/// Half-width of the random perturbation ε of the smoothness loss (eq:smooth), normalized units.
const SMOOTH_EPS: f32 = 0.01;

/// How far behind a bubble point, along its ray, the inside point of `loss.inside` lies
/// (normalized units: 2.9 mm at the default room's scale of 3.65 m). Anything thicker than this
/// along the ray has the point inside; a thinner sheet is rarer indoors than a thin pole.
const INSIDE_DEPTH: f32 = 8e-4;

/// Without depth, a ray of the batch gives a surface point (for the bubble and smoothness terms)
/// where its rendered opacity reaches this: it hits something.
const SURFACE_OPACITY: f32 = 0.5;

/// How many of each kind of extra point an iteration drew; they lie in the extra-point buffer in
/// this order, after the rays' samples: `[eikonal | bubble | inside | smooth x | smooth x + ε]`.
#[derive(Clone, Copy, Default)]
struct ExtraCounts {
    eikonal: usize,
    bubble: usize,
    inside: usize,
    smooth: usize,
}

/// The losses' gradients with respect to what the renderer produced per ray.
struct RayGradients {
    rgb: Vec<[f32; 3]>,
    depth: Vec<f32>,
    normal: Vec<[f32; 3]>,
    emitter: Vec<f32>,
}

impl Stage1 {
    /// One iteration with the iteration's RNG. A non-finite loss skips the update.
    pub(super) fn step_with(&mut self, rng: &mut Pcg64) -> StepOutcome<StepStats> {
        let sweep = self.needs_photo_depth().then(|| self.sweep_photo_depth());
        let (phase, w) = self.enter_phase();
        self.draw_rays(rng);
        let t0 = std::time::Instant::now();
        self.refresh_occupancy();
        let rendered = self.rendered_surfaces(&w, rng);
        let (counts, point_depths) = self.draw_extra_points(&w, rendered.as_deref(), rng);
        if rendered.is_none() {
            self.place_samples(rng);
        }
        let t1 = std::time::Instant::now();
        renderer::forward_with_samples(
            &self.scene,
            &self.batch.origin,
            &self.batch.dir,
            &self.extra,
            &mut self.ws,
        );
        let t2 = std::time::Instant::now();

        let mut st = StepStats {
            iteration: self.iteration,
            phase: Some(phase),
            beta: self.scene.beta.value(),
            bubble_points: counts.bubble,
            smooth_pairs: counts.smooth,
            photo_depth: sweep.map(|s| s.0),
            photo_depth_explained: sweep.map(|s| s.1),
            ..Default::default()
        };
        let ray_grads = self.ray_losses(&w, &mut st);
        let (mut d_sdf, mut d_grad) = self.point_losses(&w, counts, &point_depths, &mut st);
        st.loss = w.rgb * st.rgb
            + w.depth * st.depth
            + w.normal * st.normal
            + w.emitter * st.emitter
            + w.eikonal * st.eikonal
            + w.smooth * st.smooth
            + w.bubble * st.bubble
            + w.inside * st.inside;
        st.samples_per_ray = self.ws.n_samples as f32 / self.batch.len().max(1) as f32;
        self.learn_pdf(&mut st);
        self.learn_rgb_errors();

        if !st.loss.is_finite() || !self.ws.out.rgb.iter().all(|v| v.is_finite()) {
            st.skipped = true;
            self.iteration += 1;
            return StepOutcome {
                stats: st,
                finite: false,
            };
        }

        // Backward and update.
        let t3 = std::time::Instant::now();
        let zeros = vec![0.0f32; self.batch.len()];
        renderer::backward(
            &self.scene,
            &mut self.ws,
            &RayGrads {
                rgb: ray_grads.rgb.as_flattened(),
                depth: &ray_grads.depth,
                normal: ray_grads.normal.as_flattened(),
                emitter: &ray_grads.emitter,
                opacity: &zeros,
            },
            &mut d_sdf,
            d_grad.as_flattened_mut(),
            &mut self.grads,
        );
        let t4 = std::time::Instant::now();
        self.apply_adam();
        self.correct_poses(rng);
        let ms = |a: std::time::Instant, b: std::time::Instant| (b - a).as_secs_f32() * 1e3;
        st.ms_sampling = ms(t0, t1);
        st.ms_forward = ms(t1, t2);
        st.ms_losses = ms(t2, t3);
        st.ms_backward = ms(t3, t4);
        st.ms_adam = t4.elapsed().as_secs_f32() * 1e3;
        self.iteration += 1;
        StepOutcome {
            stats: st,
            finite: true,
        }
    }

    /// The schedule's step at this iteration and its loss weights; the PDF maps are built when
    /// the bubble step starts and dropped when the smooth step no longer needs them.
    fn enter_phase(&mut self) -> (Phase, LossWeights) {
        let phase = self.config.schedule.phase(self.iteration, self.config.iterations());
        let w = self.config.schedule.weights(phase, &self.config.loss);
        if w.bubble > 0.0 && self.pdf.is_none() && !self.no_depth {
            self.init_pdf();
        }
        if w.bubble == 0.0 && phase == Phase::Smooth {
            self.pdf = None;
        }
        (phase, w)
    }

    /// Without depth, the surface each ray renders stands in for its depth's: the samples are
    /// placed first and each ray's surface read off them (where its termination density peaks;
    /// detached). `None` with depth, or when no geometry term needs surface points.
    fn rendered_surfaces(&mut self, w: &LossWeights, rng: &mut Pcg64) -> Option<Vec<Option<f32>>> {
        (self.no_depth && (w.bubble > 0.0 || w.smooth > 0.0)).then(|| {
            self.place_samples(rng);
            renderer::rendered_surface_distances(
                &self.scene,
                &self.batch.origin,
                &self.batch.dir,
                &self.ws,
                SURFACE_OPACITY,
            )
        })
    }

    /// With `sampling.occupancy_resolution` set, rebuilds the occupancy grid from the SDF every
    /// `sampling.occupancy_every` iterations (and at the first step of a process, resumed or not).
    fn refresh_occupancy(&mut self) {
        let s = &self.config.sampling;
        if s.occupancy_resolution == 0 {
            return;
        }
        if self.settings.occupancy.is_none() || self.iteration % s.occupancy_every == 0 {
            let grid = OccupancyGrid::for_scene(
                &self.scene,
                s.occupancy_resolution,
                self.settings.bound_radius,
                s.occupancy_margin,
            );
            self.settings.occupancy = Some(std::sync::Arc::new(grid));
        }
    }

    /// Places the batch's samples along its rays (the error-bounded sampler).
    fn place_samples(&mut self, rng: &mut Pcg64) {
        renderer::sample(
            &self.scene,
            &self.settings,
            &self.batch.origin,
            &self.batch.dir,
            &mut self.ws,
            Some(rng),
        );
    }

    /// The surface point of ray `r` of the batch: by its pixel's depth, or rendered.
    fn ray_surface(&self, rendered: Option<&[Option<f32>]>, r: usize) -> Option<[f32; 3]> {
        match rendered {
            Some(distances) => distances[r].map(|t| {
                let (o, d) = (self.batch.origin[r], self.batch.dir[r]);
                [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]]
            }),
            None => {
                self.images[self.batch.image[r] as usize].depth_point(self.batch.pixel[r] as usize, self.pin_points())
            }
        }
    }

    /// Whether the depth points stay at the given poses (`pose.pin_points`, with a correction).
    fn pin_points(&self) -> bool {
        self.config.pose.pin_points && self.poses.is_some()
    }

    /// Fills the extra-point buffer (see [`ExtraCounts`]): uniform points of the box for the
    /// eikonal term; bubble points on the surfaces (drawn from the PDF maps, or the rendered
    /// surfaces without depth) with, given depth, their inside points just behind; pairs x, x + ε
    /// on the batch's surfaces for eq:smooth. Also returns the depth (along its ray) of each
    /// bubble point drawn from the depth maps, for their noise weights; empty otherwise.
    fn draw_extra_points(
        &mut self,
        w: &LossWeights,
        rendered: Option<&[Option<f32>]>,
        rng: &mut Pcg64,
    ) -> (ExtraCounts, Vec<f32>) {
        let mut extra = std::mem::take(&mut self.extra);
        extra.clear();
        let t = &self.config.train;
        let mut counts = ExtraCounts {
            eikonal: t.eikonal_points,
            ..Default::default()
        };
        let mut depths = Vec::new();
        for _ in 0..t.eikonal_points {
            let p: [f32; 3] = [
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
            ];
            extra.extend_from_slice(&p);
        }
        if w.bubble > 0.0 && rendered.is_some() {
            // The rendered surfaces pin the SDF's zero there; no inside points: nothing says
            // where the ray entered a surface.
            for x in (0..self.batch.len())
                .filter_map(|r| self.ray_surface(rendered, r))
                .take(t.bubble_points)
            {
                extra.extend_from_slice(&x);
                counts.bubble += 1;
            }
        } else if w.bubble > 0.0 {
            counts.bubble = self.draw_bubble_points(w, &mut extra, &mut depths, rng);
        }
        counts.inside = if w.inside > 0.0 && rendered.is_none() {
            counts.bubble
        } else {
            0
        };
        if w.smooth > 0.0 {
            let mut pairs: Vec<[f32; 3]> = (0..self.batch.len())
                .filter_map(|r| self.ray_surface(rendered, r))
                .collect();
            pairs.truncate(t.eikonal_points);
            counts.smooth = pairs.len();
            for x in &pairs {
                extra.extend_from_slice(x);
            }
            for x in &pairs {
                let e: [f32; 3] = std::array::from_fn(|_| rng.gen_range(-SMOOTH_EPS..SMOOTH_EPS));
                extra.extend_from_slice(&[x[0] + e[0], x[1] + e[1], x[2] + e[2]]);
            }
        }
        self.extra = extra;
        (counts, depths)
    }

    /// Bubble points drawn by the PDF maps (eq:bubble's error-guided sampling) on the pixels'
    /// depth points, then (with `loss.inside`) a point [`INSIDE_DEPTH`] behind each; each bubble
    /// point's depth along its ray into `depths`. Returns how many bubble points it added.
    fn draw_bubble_points(
        &self,
        w: &LossWeights,
        extra: &mut Vec<f32>,
        depths: &mut Vec<f32>,
        rng: &mut Pcg64,
    ) -> usize {
        let mut picks = Vec::new();
        if let Some(pdf) = &self.pdf {
            pdf.sample(self.config.train.bubble_points, rng, &mut picks);
        }
        let (mut n, pin) = (0, self.pin_points());
        for p in &picks {
            let im = &self.images[p.image as usize];
            if let Some(x) = im.depth_point(p.pixel as usize, pin) {
                extra.extend_from_slice(&x);
                depths.push(im.depth[p.pixel as usize]);
                n += 1;
            }
        }
        if w.inside > 0.0 {
            let sigma = self.noise_sigma();
            for p in &picks {
                let im = &self.images[p.image as usize];
                let pixel = p.pixel as usize;
                if im.surface_point(pixel).is_some() {
                    let t = im.depth[pixel];
                    let behind = INSIDE_DEPTH + sigma.as_ref().map_or(0.0, |sigma| sigma(t));
                    extra.extend_from_slice(&im.point_at(pixel, t + behind, pin));
                }
            }
        }
        n
    }

    /// The losses on the rays (L_rgb, depth, normal, emitter BCE) and the batch's PSNR into `st`;
    /// returns their gradients.
    fn ray_losses(&self, w: &LossWeights, st: &mut StepStats) -> RayGradients {
        let rays = self.batch.len();
        let out = &self.ws.out;
        let pred_rgb: Vec<[f32; 3]> = out.rgb.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
        let pred_n: Vec<[f32; 3]> = out.normal.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
        let mut g = RayGradients {
            rgb: vec![[0.0f32; 3]; rays],
            depth: vec![0.0f32; rays],
            normal: vec![[0.0f32; 3]; rays],
            emitter: vec![0.0f32; rays],
        };
        st.rgb = losses::rgb_l1(&pred_rgb, &self.batch.rgb, w.rgb, &mut g.rgb);
        // Rays without depth get a weight too; depth_l1 skips them, and the mean is over the rest.
        let ray_weights = self.noise_weights(&self.batch.depth, Some(&self.batch.has_depth));
        st.depth = losses::depth_l1(
            &out.depth,
            &self.batch.depth,
            &self.batch.has_depth,
            ray_weights.as_deref(),
            w.depth,
            &mut g.depth,
        );
        st.normal = losses::normal_angular(
            &pred_n,
            &self.batch.normal,
            &self.batch.has_normal,
            w.normal,
            &mut g.normal,
        );
        if self.batch.has_emitter {
            st.emitter = losses::emitter_bce(&out.emitter, &self.batch.emitter, w.emitter, &mut g.emitter);
        }
        let mse: f32 = pred_rgb
            .iter()
            .zip(&self.batch.rgb)
            .map(|(p, q)| (0..3).map(|c| (p[c] - q[c]).powi(2)).sum::<f32>())
            .sum::<f32>()
            / (3 * rays.max(1)) as f32;
        st.psnr = -10.0 * mse.max(1e-10).log10();
        g
    }

    /// The losses on points into `st`: eikonal on every ray sample and the uniform points,
    /// bubble and inside on theirs, eq:smooth on the pairs. Returns their gradients with respect
    /// to each point's SDF value and spatial gradient (laid out as the renderer's workspace).
    fn point_losses(
        &self,
        w: &LossWeights,
        counts: ExtraCounts,
        point_depths: &[f32],
        st: &mut StepStats,
    ) -> (Vec<f32>, Vec<[f32; 3]>) {
        let n_s = self.ws.n_samples;
        let n = self.ws.sdf.len();
        let mut d_sdf = vec![0.0f32; n];
        let mut d_grad = vec![[0.0f32; 3]; n];
        let grads3: &[[f32; 3]] = &self.ws.gradient;
        let ExtraCounts {
            eikonal: n_eik,
            bubble: n_bub,
            inside: n_in,
            smooth: n_smooth,
        } = counts;
        if w.eikonal > 0.0 {
            st.eikonal = losses::eikonal(&grads3[..n_s + n_eik], w.eikonal, &mut d_grad[..n_s + n_eik]);
        }
        let b0 = n_s + n_eik;
        // The bubble points from the depth maps, and the inside points behind the same picks.
        let point_weights = (point_depths.len() == n_bub)
            .then(|| self.noise_weights(point_depths, None))
            .flatten();
        if n_bub > 0 {
            let tolerance = self
                .noise_sigma()
                .filter(|_| point_depths.len() == n_bub)
                .map(|sigma| point_depths.iter().map(|&z| sigma(z)).collect::<Vec<f32>>());
            st.bubble = losses::bubble(
                &self.ws.sdf[b0..b0 + n_bub],
                point_weights.as_deref(),
                tolerance.as_deref(),
                w.bubble,
                &mut d_sdf[b0..b0 + n_bub],
            );
        }
        if n_in > 0 {
            let i0 = b0 + n_bub;
            let weights = point_weights.as_deref().filter(|v| v.len() == n_in);
            st.inside = losses::inside(
                &self.ws.sdf[i0..i0 + n_in],
                weights,
                w.inside,
                &mut d_sdf[i0..i0 + n_in],
            );
        }
        if n_smooth > 0 {
            let s0 = b0 + n_bub + n_in;
            let (ga, gb) = d_grad[s0..s0 + 2 * n_smooth].split_at_mut(n_smooth);
            st.smooth = losses::smoothness(
                &grads3[s0..s0 + n_smooth],
                &grads3[s0 + n_smooth..s0 + 2 * n_smooth],
                w.smooth,
                ga,
                gb,
            );
        }
        (d_sdf, d_grad)
    }

    /// The depth sensor's noise model's weights (`maps.depth_noise_distance`, in force for depth
    /// not declared exact) of depth samples at these distances along their rays (normalized
    /// units), averaging 1 over those `counted` marks; None when it is off.
    fn noise_weights(&self, depths: &[f32], counted: Option<&[bool]>) -> Option<Vec<f32>> {
        let d = self.depth_noise_distance / self.normalization.scale as f32;
        losses::noise_weights(depths, counted, d)
    }

    /// The batch's rays: `adaptive.rgb_rays` of them drawn by the colour error maps (while they
    /// hold any error; until then, and for the rest, uniformly).
    fn draw_rays(&mut self, rng: &mut Pcg64) {
        let n = self.config.train.rays;
        let mut picks = Vec::new();
        if let Some(maps) = &self.rgb_errors {
            maps.sample(
                (n as f32 * self.config.adaptive.rgb_rays).round() as usize,
                rng,
                &mut picks,
            );
        }
        self.batch.sample_uniform(&self.images, n - picks.len(), rng);
        for p in &picks {
            self.batch.push(&self.images, p.image as usize, p.pixel as usize);
        }
    }

    /// The colour error maps learn each ray's mean absolute error over its channels.
    fn learn_rgb_errors(&mut self) {
        let Some(maps) = &mut self.rgb_errors else { return };
        let pred = &self.ws.out.rgb;
        for r in 0..self.batch.len() {
            let gt = self.batch.rgb[r];
            let e = (0..3).map(|c| (pred[3 * r + c] - gt[c]).abs()).sum::<f32>() / 3.0;
            maps.update(
                PixelRef {
                    image: self.batch.image[r],
                    pixel: self.batch.pixel[r],
                },
                e,
            );
        }
    }

    /// The sensor's noise σ(z) = σ₀ (1 + (z / d)²) (`maps.depth_noise_sigma`) as a function of the
    /// distance z along a ray, both in normalized units; None where σ₀ or the noise model is off.
    fn noise_sigma(&self) -> Option<impl Fn(f32) -> f32> {
        let scale = self.normalization.scale as f32;
        let (s0, d) = (
            self.config.maps.depth_noise_sigma / scale,
            self.depth_noise_distance / scale,
        );
        (s0 > 0.0 && d > 0.0).then_some(move |z: f32| s0 * losses::noise_growth(z, d))
    }

    /// The PDF maps learn from this batch's depth errors (Sec. 4.1.2).
    fn learn_pdf(&mut self, st: &mut StepStats) {
        let Some(pdf) = &mut self.pdf else { return };
        if self.config.adaptive.enabled {
            for r in 0..self.batch.len() {
                if self.batch.has_depth[r] {
                    let e = (self.ws.out.depth[r] - self.batch.depth[r]).abs();
                    pdf.update(
                        PixelRef {
                            image: self.batch.image[r],
                            pixel: self.batch.pixel[r],
                        },
                        e,
                    );
                }
            }
        }
        st.pdf_active = pdf.active();
    }
}
