//! Rendering one view through the [`Integrator`]: the pixel loop (rows in parallel, tiles of
//! paths within a row), stratified sampling of the pixel and of the first bounces, a sampler per
//! pixel that depends only on (seed, view, pixel), per-emitter radiance for exact relighting, and
//! the ground-truth maps of the pixel-centre ray (depth, normal, emitter mask, Kd, Ks, ρ).

use crate::brdf::GgxBrdf;
use crate::color::luminance;
use crate::geometry::{Hit, Ray};
use crate::integrator::{BounceUniforms, Integrator, PathStart, Scene, STRATIFIED_BOUNCES};
use crate::material::SurfacePoint;
use glam::Vec3;
use i2sdf_data::Camera;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg32;

/// Paths traced together (one wavefront): large enough to amortise the batched queries, small
/// enough for the path states to stay in cache. 4096 → 16384 took the default room's stage-2
/// re-render of its 8 test views from 40.9 to 37.8 s (bench ~107 ms): each network query has
/// a fixed cost (workspaces, the MLP's transposed weights) that larger batches share out.
const TILE_PATHS: usize = 16384;

/// What to render of a view.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewSettings {
    pub spp: u32,
    pub seed: u64,
    /// Index of the view (decorrelates the samplers of views rendered with one seed).
    pub view: u32,
    pub integrator: Integrator,
}

/// The rendered buffers of one view. `radiance` holds `emitters` RGB values per pixel (the
/// contribution of each emitter, and last the radiance field's where the scene has one: see
/// [`Scene::slots`]), row-major; the ground-truth maps come from the pixel-centre
/// ray. Pixels that see nothing have infinite depth and zero maps.
pub struct ViewRender {
    pub width: usize,
    pub height: usize,
    pub emitters: usize,
    pub radiance: Vec<Vec3>,
    /// Per pixel and slot, as `radiance`: the variance of the luminance of the pixel's mean,
    /// estimated from its paths (s²/n; an overestimate under the stratified sampling), which
    /// steers the denoiser ([`crate::denoise`]).
    pub variance: Vec<f32>,
    pub depth: Vec<f32>,
    pub normal: Vec<Vec3>,
    pub emitter_mask: Vec<bool>,
    pub kd: Vec<Vec3>,
    pub ks: Vec<Vec3>,
    pub roughness: Vec<f32>,
}

impl ViewRender {
    /// HDR image with emitter k's emission multiplied by `gains[k]` (all ones: the scene as is).
    pub fn hdr(&self, gains: &[Vec3]) -> Vec<Vec3> {
        assert_eq!(gains.len(), self.emitters, "one gain per emitter");
        if self.emitters == 0 {
            // A scene without emitters (or radiance field) is black.
            return vec![Vec3::ZERO; self.width * self.height];
        }
        self.radiance
            .chunks(self.emitters)
            .map(|px| px.iter().zip(gains).map(|(l, g)| *l * *g).sum())
            .collect()
    }
}

/// Sampler state of one pixel: deterministic from (seed, view, pixel), whatever the thread order.
pub fn pixel_rng(seed: u64, view: u32, pixel: u32) -> Pcg32 {
    let key = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ ((view as u64) << 32 | pixel as u64).wrapping_mul(0xD1B5_4A32_D192_ED03);
    Pcg32::seed_from_u64(key)
}

/// Renders one view, rows in parallel: `spp` stratified jittered paths per pixel plus the
/// pixel-centre ray for the ground-truth maps. `on_row` is called after each row (progress).
pub fn render_view(scene: &Scene, cam: &Camera, settings: &ViewSettings, on_row: &(dyn Fn() + Sync)) -> ViewRender {
    use rayon::prelude::*;
    let (w, h, ne) = (cam.width, cam.height, scene.slots());
    let gen = cam.ray_generator();
    let spp = settings.spp.max(1);
    let strata = (spp as f32).sqrt().floor().max(1.0) as u32;
    let pixels_per_tile = (TILE_PATHS / spp as usize).max(1);
    let rows: Vec<RowBuffers> = (0..h)
        .into_par_iter()
        .with_max_len(1)
        .map(|y| {
            let mut row = RowBuffers::new(w, ne);
            let mut paths = Vec::with_capacity(pixels_per_tile * spp as usize);
            let mut radiance = Vec::new();
            for x0 in (0..w).step_by(pixels_per_tile) {
                let x1 = (x0 + pixels_per_tile).min(w);
                paths.clear();
                for x in x0..x1 {
                    let mut rng = pixel_rng(settings.seed, settings.view, (y * w + x) as u32);
                    // Padded stratified sampling (pbrt's StratifiedSampler): each 2D pair of
                    // dimensions gets its own jittered grid over the pixel's paths, shuffled
                    // independently so that the pairs do not correlate; 1D dimensions get
                    // jittered strata. Unbiased: every path's uniforms are still uniform.
                    let pixel_uv = stratified_2d(spp, strata, &mut rng);
                    let mut bounce: Vec<BounceUniforms> = vec![[[0f32; 6]; STRATIFIED_BOUNCES]; spp as usize];
                    for b in 0..STRATIFIED_BOUNCES {
                        let (sel, light, lobe, dir) = (
                            stratified_1d(spp, &mut rng),
                            stratified_2d(spp, strata, &mut rng),
                            stratified_1d(spp, &mut rng),
                            stratified_2d(spp, strata, &mut rng),
                        );
                        for s in 0..spp as usize {
                            bounce[s][b] = [sel[s], light[s][0], light[s][1], lobe[s], dir[s][0], dir[s][1]];
                        }
                    }
                    for s in 0..spp as usize {
                        let [jx, jy] = pixel_uv[s];
                        paths.push(PathStart {
                            origin: gen.origin,
                            dir: gen.dir(x as f32 + jx, y as f32 + jy),
                            strata: bounce[s],
                            // Each path its own stream: the wavefront consumes samples path by
                            // path in whatever order bounces interleave.
                            rng: Pcg32::new(rng.gen(), rng.gen()),
                        });
                    }
                }
                radiance.clear();
                radiance.resize(paths.len() * ne, Vec3::ZERO);
                settings.integrator.trace(scene, &mut paths, &mut radiance);
                for x in x0..x1 {
                    let first = (x - x0) * spp as usize;
                    for k in 0..ne {
                        let paths = (first..first + spp as usize).map(|p| radiance[p * ne + k]);
                        let sum: Vec3 = paths.clone().sum();
                        let mean = sum / spp as f32;
                        row.radiance[x * ne + k] = mean;
                        if spp > 1 {
                            let (l, n) = (luminance(mean), spp as f32);
                            let ss: f32 = paths.map(|c| (luminance(c) - l).powi(2)).sum();
                            row.variance[x * ne + k] = ss / (n - 1.0) / n;
                        }
                    }
                }
            }
            ground_truth_row(scene, &gen, y, &mut row);
            on_row();
            row
        })
        .collect();
    let mut out = ViewRender {
        width: w,
        height: h,
        emitters: ne,
        radiance: Vec::with_capacity(w * h * ne),
        variance: Vec::with_capacity(w * h * ne),
        depth: Vec::with_capacity(w * h),
        normal: Vec::with_capacity(w * h),
        emitter_mask: Vec::with_capacity(w * h),
        kd: Vec::with_capacity(w * h),
        ks: Vec::with_capacity(w * h),
        roughness: Vec::with_capacity(w * h),
    };
    for r in rows {
        out.radiance.extend(r.radiance);
        out.variance.extend(r.variance);
        out.depth.extend(r.depth);
        out.normal.extend(r.normal);
        out.emitter_mask.extend(r.emitter_mask);
        out.kd.extend(r.kd);
        out.ks.extend(r.ks);
        out.roughness.extend(r.roughness);
    }
    out
}

/// The annotations of one row from its pixel-centre rays, batched like the paths.
fn ground_truth_row(scene: &Scene, gen: &i2sdf_data::camera::RayGenerator, y: usize, row: &mut RowBuffers) {
    let w = row.depth.len();
    let rays: Vec<Ray> = (0..w)
        .map(|x| Ray::new(gen.origin, gen.dir(x as f32 + 0.5, y as f32 + 0.5), 0.0, f32::INFINITY))
        .collect();
    let mut hits: Vec<Option<Hit>> = vec![None; w];
    scene.geometry.intersect(&rays, &mut hits);
    let seen: Vec<(usize, Hit)> = hits.iter().enumerate().filter_map(|(x, h)| h.map(|h| (x, h))).collect();
    let points: Vec<SurfacePoint> = seen
        .iter()
        .map(|&(x, hit)| {
            let d = rays[x].dir;
            SurfacePoint {
                position: rays[x].at(hit.t),
                normal: if hit.normal.dot(d) > 0.0 {
                    -hit.normal
                } else {
                    hit.normal
                },
                surface: hit.surface,
                prim: hit.prim,
            }
        })
        .collect();
    let mut brdfs = vec![GgxBrdf::new(Vec3::ZERO, Vec3::ZERO, 1.0); points.len()];
    scene.material.eval_batch(&points, &mut brdfs);
    row.depth.fill(f32::INFINITY);
    for ((&(x, hit), p), b) in seen.iter().zip(&points).zip(&brdfs) {
        row.depth[x] = hit.t * rays[x].dir.dot(gen.forward());
        row.normal[x] = p.normal;
        row.emitter_mask[x] = scene.lights.emitter_of(&hit).is_some();
        row.kd[x] = b.kd;
        row.ks[x] = b.ks;
        row.roughness[x] = b.rho;
    }
}

/// `n` jittered 1D strata in random order.
fn stratified_1d(n: u32, rng: &mut Pcg32) -> Vec<f32> {
    let mut v: Vec<f32> = (0..n)
        .map(|k| ((k as f32 + rng.gen::<f32>()) / n as f32).min(1.0 - f32::EPSILON))
        .collect();
    shuffle(&mut v, rng);
    v
}

/// `n` points of a jittered `strata`×`strata` grid (uniform points beyond strata²), in random order.
fn stratified_2d(n: u32, strata: u32, rng: &mut Pcg32) -> Vec<[f32; 2]> {
    let mut v: Vec<[f32; 2]> = (0..n)
        .map(|k| {
            if k < strata * strata {
                let (i, j) = (k % strata, k / strata);
                [
                    ((i as f32 + rng.gen::<f32>()) / strata as f32).min(1.0 - f32::EPSILON),
                    ((j as f32 + rng.gen::<f32>()) / strata as f32).min(1.0 - f32::EPSILON),
                ]
            } else {
                [rng.gen(), rng.gen()]
            }
        })
        .collect();
    shuffle(&mut v, rng);
    v
}

fn shuffle<T>(v: &mut [T], rng: &mut Pcg32) {
    for i in (1..v.len()).rev() {
        v.swap(i, rng.gen_range(0..=i));
    }
}

struct RowBuffers {
    radiance: Vec<Vec3>,
    variance: Vec<f32>,
    depth: Vec<f32>,
    normal: Vec<Vec3>,
    emitter_mask: Vec<bool>,
    kd: Vec<Vec3>,
    ks: Vec<Vec3>,
    roughness: Vec<f32>,
}

impl RowBuffers {
    fn new(w: usize, ne: usize) -> Self {
        RowBuffers {
            radiance: vec![Vec3::ZERO; w * ne],
            variance: vec![0.0; w * ne],
            depth: vec![0.0; w],
            normal: vec![Vec3::ZERO; w],
            emitter_mask: vec![false; w],
            kd: vec![Vec3::ZERO; w],
            ks: vec![Vec3::ZERO; w],
            roughness: vec![0.0; w],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::integrator::test_scenes::*;
    use crate::integrator::Estimator;
    use glam::{DMat4, DVec3};

    fn camera(eye: Vec3, target: Vec3, w: usize, h: usize) -> Camera {
        let f = 0.5 * w as f64 / (30f64.to_radians()).tan();
        Camera {
            lens: Default::default(),
            width: w,
            height: h,
            fx: f,
            fy: f,
            cx: 0.5 * w as f64,
            cy: 0.5 * h as f64,
            c2w: i2sdf_data::camera::look_at(eye.as_dvec3(), target.as_dvec3(), DVec3::Y),
        }
    }

    fn settings(spp: u32, estimator: Estimator) -> ViewSettings {
        ViewSettings {
            spp,
            seed: 1,
            view: 0,
            integrator: Integrator {
                estimator,
                max_depth: 8,
            },
        }
    }

    /// The white furnace through the whole view renderer: every pixel ≈ Le, the image mean
    /// within 1 %, and the objects fill a good part of the view.
    #[test]
    fn white_furnace_view() {
        let le = Vec3::new(1.0, 0.5, 2.0);
        let scene = furnace(le, 1.0);
        let cam = camera(Vec3::new(0.0, 1.2, 1.5), Vec3::new(0.0, 0.9, -1.0), 24, 18);
        let mut s = settings(64, Estimator::UNBIASED);
        s.integrator.max_depth = 64;
        let r = render_view(&scene.scene(), &cam, &s, &|| {});
        let hdr = r.hdr(&[Vec3::ONE]);
        let mean = hdr.iter().copied().sum::<Vec3>() / hdr.len() as f32;
        assert!(((mean - le) / le).abs().max_element() < 0.01, "{mean}");
        let worst = hdr
            .iter()
            .map(|p| ((*p - le) / le).abs().max_element())
            .fold(0.0, f32::max);
        assert!(worst < 0.25, "a pixel deviates by {worst}");
        assert!(r.emitter_mask.iter().filter(|m| !**m).count() > hdr.len() / 5);
    }

    /// Regularization only widens glossy lobes: a scene without specular reflectance renders
    /// bit for bit the same with the dataset's estimator as with the unbiased one, and a glossy
    /// floor and wall do not (the regularized estimator is really in use).
    #[test]
    fn regularization_leaves_diffuse_scenes_unchanged() {
        let cam = camera(Vec3::new(0.0, 1.2, 2.5), Vec3::new(0.0, 0.27, 0.0), 24, 16);
        let render = |ks: f32, estimator: Estimator| {
            let scene = lamp(ks);
            render_view(&scene.scene(), &cam, &settings(8, estimator), &|| {}).radiance
        };
        assert_eq!(render(0.0, Estimator::UNBIASED), render(0.0, Estimator::DATASET));
        assert_ne!(render(0.5, Estimator::UNBIASED), render(0.5, Estimator::DATASET));
    }

    /// Deterministic per pixel whatever the tiling, and the ground-truth maps match the scene:
    /// z-depth of the floor seen straight down, its normal and material, emitters masked.
    #[test]
    fn maps_and_determinism() {
        let scene = lamp(0.2);
        let mut cam = camera(Vec3::new(0.0, 2.0, 1.0), Vec3::new(0.0, 0.0, 1.0), 16, 12);
        // Straight down (look_at with up = Y is degenerate here): x right, y down the image = −z.
        cam.c2w = DMat4::from_cols(
            DVec3::X.extend(0.0),
            DVec3::Z.extend(0.0),
            (-DVec3::Y).extend(0.0),
            DVec3::new(1.0, 2.0, 1.0).extend(1.0),
        );
        let a = render_view(&scene.scene(), &cam, &settings(4, Estimator::DATASET), &|| {});
        let b = render_view(&scene.scene(), &cam, &settings(4, Estimator::DATASET), &|| {});
        assert_eq!(a.radiance, b.radiance);
        let c = cam.width * (cam.height / 2) + cam.width / 2;
        assert!((a.depth[c] - 2.0).abs() < 1e-5, "{}", a.depth[c]);
        assert_eq!(a.normal[c], Vec3::Y);
        assert_eq!(
            (a.kd[c], a.ks[c], a.roughness[c]),
            (Vec3::splat(0.5), Vec3::splat(0.2), 0.3)
        );
        assert!(!a.emitter_mask[c]);
        // Relighting is linear: turning an emitter off removes exactly its part.
        let full = a.hdr(&[Vec3::ONE, Vec3::ONE]);
        let off = a.hdr(&[Vec3::ONE, Vec3::ZERO]);
        let only = a.hdr(&[Vec3::ZERO, Vec3::ONE]);
        for i in 0..full.len() {
            assert!((full[i] - off[i] - only[i]).abs().max_element() < 1e-5);
        }
    }
}
