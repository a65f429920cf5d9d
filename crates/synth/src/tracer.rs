//! The ground-truth renderer: a path tracer over the scene triangles with next-event estimation
//! on every emitter at every vertex (spherical emitters sampled by solid angle, others by area),
//! multiple importance sampling (power heuristic) between light and BRDF sampling, Russian
//! roulette, and the supplementary's GGX BRDF (`i2sdf_render`). Unbiased by default; the dataset
//! generator adds path-space regularization of glossy lobes after a diffuse bounce
//! ([`Estimator::DATASET`]), which removes the caustic fireflies of small bright bulbs at a small,
//! documented bias.
//!
//! Radiance is accumulated per emitter: every path ends on exactly one emitter (emitters do not
//! reflect), so the image is linear in each emitter's emission, `L = Σ_k L_k`, and a relit image
//! (emitter k scaled by s_k ⊙ c_k) is `Σ_k s_k c_k ⊙ L_k`, exact and free of extra rendering.
//! Regularization changes BRDFs, never emission, so this holds for either estimator and the relit
//! views are rendered with the same estimator as the originals.

use crate::bvh::Bvh;
use crate::camera::Camera;
use crate::mesh::TriangleMesh;
use crate::scene::{SceneDesc, TextureDesc};
use glam::Vec3;
use i2sdf_render::color::max_channel;
use i2sdf_render::sampling::{power_heuristic, uniform_triangle, Frame};
use i2sdf_render::{BrdfLobe, GgxBrdf};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg32;

/// Most emitters a scene may have (per-emitter radiance is kept for relighting).
pub const MAX_EMITTERS: usize = 8;
/// Bounces whose light and BRDF samples are stratified across a pixel's paths.
pub const STRATIFIED_BOUNCES: usize = 2;
/// Per bounce: triangle choice on area emitters, two for the point on (or direction to) each
/// emitter, lobe choice, two for the direction.
pub type BounceUniforms = [[f32; 6]; STRATIFIED_BOUNCES];

/// Offset of secondary ray origins along the normal (metres); the thinnest parts are 10 mm.
const RAY_EPS: f32 = 1e-4;

/// One emitter: a shape with emission.
#[derive(Clone, Debug)]
pub struct Emitter {
    pub shape: u32,
    pub name: String,
    pub emission: Vec3,
    pub bounds: (Vec3, Vec3),
}

/// Which estimator [`RenderScene::trace`] computes. [`Estimator::UNBIASED`] is the plain path
/// tracer; [`Estimator::DATASET`] is what `i2sdf synth` renders by default.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Estimator {
    /// Path-space regularization (Kaplanyan & Dachsbacher 2013, "Path Space Regularization for
    /// Holistic and Robust Light Transport"; Cycles' "Filter Glossy" in practice): once a path
    /// has scattered off a diffuse lobe, every later vertex uses roughness at least this. Paths
    /// camera → diffuse → glossy → small bright emitter (caustics of the bulb on glossy surfaces)
    /// are found only by BRDF sampling and were the remaining fireflies; with the glossy lobe
    /// widened, next-event estimation takes them over through MIS. What the camera sees directly
    /// and through chains of glossy reflections is untouched; the bias is confined to indirect
    /// light reflected by glossy surfaces onto diffuse ones. `None`: unbiased.
    pub regularize_roughness: Option<f32>,
}

impl Estimator {
    pub const UNBIASED: Estimator = Estimator {
        regularize_roughness: None,
    };
    /// The dataset default: see `regularize_roughness` (the value is chosen in `tracer.rs`'s
    /// tests and the report behind it: bias below the 4×-spp noise, fireflies gone).
    pub const DATASET: Estimator = Estimator {
        regularize_roughness: Some(0.5),
    };
}

pub struct RenderScene {
    pub desc: SceneDesc,
    /// The estimator `trace` computes (unbiased unless set).
    pub estimator: Estimator,
    pub mesh: TriangleMesh,
    pub bvh: Bvh,
    /// Unit geometric normal of each triangle (its winding: outward).
    normals: Vec<Vec3>,
    shape_brdf: Vec<GgxBrdf>,
    shape_texture: Vec<Option<TextureDesc>>,
    shape_emitter: Vec<Option<u8>>,
    pub emitters: Vec<Emitter>,
    /// Bounds of the closed shapes (boxes, spheres, cylinders) that cameras must stay out of.
    pub obstacle_bounds: Vec<(Vec3, Vec3)>,
    /// How next-event estimation samples each emitter (indexed like `emitters`).
    light_samplers: Vec<LightSampler>,
}

/// How next-event estimation picks a point on one emitter.
#[derive(Clone, Debug)]
enum LightSampler {
    /// Uniform by area over the emitter's triangles (quads, boxes, cylinders).
    Area { tris: Vec<u32>, cdf: Vec<f32>, area: f32 },
    /// A tessellated sphere: directions uniform in the cone subtended by its circumscribed sphere
    /// (pbrt's `Sphere::Sample(ref, u)`), then a ray finds the point on the tessellation. Uniform
    /// area sampling wastes the half of the samples that land on the far side and weighs the rest
    /// by cos/d², which close to a small bright bulb was the largest source of variance of the
    /// livingroom (≈45 % of it in direct light alone); the cone pdf is constant over the bulb.
    /// Area sampling of the same triangles is the fallback for points inside the sphere.
    Sphere {
        center: Vec3,
        radius: f32,
        tris: Vec<u32>,
        cdf: Vec<f32>,
        area: f32,
    },
}

/// What a camera ray sees first: the ground-truth annotations of a pixel.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceSample {
    pub t: f32,
    pub position: Vec3,
    /// Geometric normal, flipped to face the ray origin.
    pub normal: Vec3,
    pub shape: u32,
    pub triangle: u32,
    pub emitter: Option<u8>,
    pub brdf: GgxBrdf,
}

/// Sampler state of one pixel: deterministic from (seed, view, pixel), whatever the thread order.
pub fn pixel_rng(seed: u64, view: u32, pixel: u32) -> Pcg32 {
    let key = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ ((view as u64) << 32 | pixel as u64).wrapping_mul(0xD1B5_4A32_D192_ED03);
    Pcg32::seed_from_u64(key)
}

impl RenderScene {
    pub fn new(desc: SceneDesc) -> Self {
        let mesh = TriangleMesh::from_scene(&desc);
        let bvh = Bvh::build(&mesh);
        let normals = (0..mesh.triangles.len())
            .map(|t| {
                (mesh.vertex(t, 1) - mesh.vertex(t, 0))
                    .cross(mesh.vertex(t, 2) - mesh.vertex(t, 0))
                    .normalize_or_zero()
            })
            .collect();
        let mut emitters = Vec::new();
        let mut shape_emitter = Vec::new();
        let mut obstacle_bounds = Vec::new();
        for (i, s) in desc.shapes.iter().enumerate() {
            let bounds = mesh.shape_bounds(i as u32);
            if let Some(e) = s.emission {
                shape_emitter.push(Some(emitters.len() as u8));
                emitters.push(Emitter {
                    shape: i as u32,
                    name: s.name.clone(),
                    emission: Vec3::from(e),
                    bounds,
                });
            } else {
                shape_emitter.push(None);
            }
            if !matches!(s.geometry, crate::scene::Geometry::Quad { .. }) {
                obstacle_bounds.push(bounds);
            }
        }
        let shape_brdf = desc
            .shapes
            .iter()
            .map(|s| {
                let m = &s.material;
                GgxBrdf::new(Vec3::from(m.kd), Vec3::from(m.ks), m.roughness)
            })
            .collect();
        let shape_texture = desc.shapes.iter().map(|s| s.material.texture.clone()).collect();
        let mut light_samplers = Vec::with_capacity(emitters.len());
        for e in &emitters {
            let (mut tris, mut cdf, mut area) = (Vec::new(), Vec::new(), 0.0f32);
            for (t, &s) in mesh.shape_of.iter().enumerate() {
                if s == e.shape {
                    area += mesh.area(t);
                    tris.push(t as u32);
                    cdf.push(area);
                }
            }
            light_samplers.push(match desc.shapes[e.shape as usize].geometry {
                crate::scene::Geometry::Sphere { center, .. } => {
                    // The circumscribed sphere of the tessellation (its vertices lie on the
                    // nominal sphere, up to rounding): the cone must contain every emitting point.
                    let c = Vec3::from(center);
                    let radius = tris
                        .iter()
                        .flat_map(|&t| (0..3).map(move |j| (t as usize, j)))
                        .map(|(t, j)| (mesh.vertex(t, j) - c).length())
                        .fold(0.0f32, f32::max)
                        * (1.0 + 1e-4);
                    LightSampler::Sphere {
                        center: c,
                        radius,
                        tris,
                        cdf,
                        area,
                    }
                }
                _ => LightSampler::Area { tris, cdf, area },
            });
        }
        RenderScene {
            desc,
            estimator: Estimator::UNBIASED,
            mesh,
            bvh,
            normals,
            shape_brdf,
            shape_texture,
            shape_emitter,
            emitters,
            obstacle_bounds,
            light_samplers,
        }
    }

    /// Material at a point of a shape (Kd textured in world space).
    pub fn brdf_at(&self, shape: u32, p: Vec3) -> GgxBrdf {
        let mut b = self.shape_brdf[shape as usize];
        if let Some(tex) = &self.shape_texture[shape as usize] {
            b.kd = tex.kd_at(b.kd, p);
        }
        b
    }

    pub fn surface(&self, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32) -> Option<SurfaceSample> {
        let h = self.bvh.intersect(origin, dir, t_min, t_max)?;
        let shape = self.mesh.shape_of[h.triangle as usize];
        let position = origin + h.t * dir;
        let n = self.normals[h.triangle as usize];
        let normal = if n.dot(dir) > 0.0 { -n } else { n };
        Some(SurfaceSample {
            t: h.t,
            position,
            normal,
            shape,
            triangle: h.triangle,
            emitter: self.shape_emitter[shape as usize],
            brdf: self.brdf_at(shape, position),
        })
    }

    /// Solid-angle density with which next-event estimation from `from` samples the point of
    /// emitter `k` seen at distance `dist` with cosine `cos_light` (for MIS of BRDF samples).
    fn light_pdf(&self, k: u8, from: Vec3, dist: f32, cos_light: f32) -> f32 {
        if cos_light <= 0.0 {
            return 0.0;
        }
        match self.light_cone(k as usize, from) {
            Some((_, _, omc)) => 1.0 / (std::f32::consts::TAU * omc),
            None => dist * dist / (self.light_samplers[k as usize].area() * cos_light),
        }
    }

    /// Estimates the radiance arriving along `(origin, dir)`, adding each emitter's part to
    /// `per_emitter[k]`. `max_depth` counts scattering events; Russian roulette from the 3rd on.
    /// `strata` supplies stratified uniforms for the first [`STRATIFIED_BOUNCES`] bounces (the
    /// rest come from `rng`).
    pub fn trace(
        &self,
        origin: Vec3,
        dir: Vec3,
        rng: &mut Pcg32,
        strata: &BounceUniforms,
        max_depth: u32,
        per_emitter: &mut [Vec3; MAX_EMITTERS],
    ) {
        let mut beta = Vec3::ONE;
        let (mut o, mut d) = (origin, dir);
        let mut brdf_pdf: Option<f32> = None;
        // Whether the path has scattered off a diffuse lobe (regularization starts after it).
        let mut after_diffuse = false;
        for depth in 0..=max_depth {
            let Some(hit) = self.surface(o, d, if depth == 0 { 0.0 } else { RAY_EPS }, f32::INFINITY) else {
                break;
            };
            if let Some(k) = hit.emitter {
                // One-sided emission along the outward (winding) normal.
                let outward = self.normals[hit.triangle as usize];
                let cos_light = -outward.dot(d);
                if cos_light > 0.0 {
                    let w = match brdf_pdf {
                        None => 1.0,
                        Some(pb) => power_heuristic(pb, self.light_pdf(k, o, hit.t, cos_light)),
                    };
                    per_emitter[k as usize] += beta * self.emitters[k as usize].emission * w;
                }
                break;
            }
            if depth == max_depth {
                break;
            }
            let (p, n, wo, mut brdf) = (hit.position, hit.normal, -d, hit.brdf);
            if let (true, Some(rho)) = (after_diffuse, self.estimator.regularize_roughness) {
                brdf.rho = brdf.rho.max(rho);
            }
            let origin_out = p + n * RAY_EPS;
            // Next-event estimation (see `sample_light`).
            let u = if (depth as usize) < STRATIFIED_BOUNCES {
                strata[depth as usize]
            } else {
                [rng.gen(), rng.gen(), rng.gen(), rng.gen(), rng.gen(), rng.gen()]
            };
            // Every emitter gets its own light sample (one shadow ray each; scenes have at most
            // MAX_EMITTERS): choosing one emitter by power left the bulb's contribution, which
            // dominates near it, with selection noise (variance ∝ 1/p − 1 at p ≈ 0.23).
            for k in 0..self.emitters.len() as u8 {
                let Some(ls) = self.sample_light(origin_out, k, u[0], u[1], u[2]) else {
                    continue;
                };
                let cos_x = n.dot(ls.wi);
                if cos_x > 0.0 {
                    let f = brdf.eval(n, wo, ls.wi);
                    if max_channel(f) > 0.0 && self.light_visible(origin_out, &ls) {
                        let w = power_heuristic(ls.pdf, brdf.pdf(n, wo, ls.wi));
                        per_emitter[k as usize] += beta * f * self.emitters[k as usize].emission * (cos_x * w / ls.pdf);
                    }
                }
            }
            // BRDF sampling continues the path.
            let Some(s) = brdf.sample(n, wo, [u[3], u[4], u[5]]) else {
                break;
            };
            beta *= s.weight;
            after_diffuse |= s.lobe == BrdfLobe::Diffuse;
            brdf_pdf = Some(s.pdf);
            o = origin_out;
            d = s.d;
            if depth >= 2 {
                let q = max_channel(beta).min(0.95);
                if rng.gen::<f32>() >= q {
                    break;
                }
                beta /= q;
            }
        }
    }

    /// Next-event estimation's light sample of emitter `k` from `x`: a direction towards it by its
    /// [`LightSampler`] (`u_tri` picks a triangle by area, `u1`, `u2` the point or direction).
    /// `None` when the sample cannot carry light (the back of a one-sided emitter).
    fn sample_light(&self, x: Vec3, k: u8, u_tri: f32, u1: f32, u2: f32) -> Option<LightSample> {
        let k = k as usize;
        if let Some((center, radius, omc)) = self.light_cone(k, x) {
            // Uniform in the cone around x → centre with 1 − cos θ_max = omc (pbrt-v3 §14.2.2),
            // computed from 1 − cos θ so that distant, small cones keep their precision.
            let axis = (center - x).normalize();
            let one_minus_cos = u1 * omc;
            let cos_t = 1.0 - one_minus_cos;
            let sin_t = (one_minus_cos * (2.0 - one_minus_cos)).max(0.0).sqrt();
            let phi = std::f32::consts::TAU * u2;
            let wi = Frame::from_normal(axis).to_world(Vec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t));
            return Some(LightSample {
                emitter: k as u8,
                wi,
                dist: None,
                // The chord through the tessellation starts within the circumscribed sphere.
                max_dist: (center - x).length() + radius,
                pdf: 1.0 / (std::f32::consts::TAU * omc),
            });
        }
        let (tris, cdf, area) = match &self.light_samplers[k] {
            LightSampler::Area { tris, cdf, area } | LightSampler::Sphere { tris, cdf, area, .. } => (tris, cdf, *area),
        };
        let i = cdf.partition_point(|&c| c <= u_tri * area).min(tris.len() - 1);
        let t = tris[i] as usize;
        let (b1, b2) = uniform_triangle(u1, u2);
        let y = self.mesh.vertex(t, 0) * (1.0 - b1 - b2) + self.mesh.vertex(t, 1) * b1 + self.mesh.vertex(t, 2) * b2;
        let to = y - x;
        let dist = to.length();
        let wi = to / dist;
        let cos_y = -self.normals[t].dot(wi);
        if !(cos_y > 0.0) {
            return None;
        }
        Some(LightSample {
            emitter: k as u8,
            wi,
            dist: Some(dist),
            max_dist: dist,
            pdf: dist * dist / (area * cos_y),
        })
    }

    /// The cone that spherical emitter `k` subtends from `x`: (centre, radius, 1 − cos θ_max);
    /// `None` for other emitters and for points inside the sphere (those use area sampling).
    fn light_cone(&self, k: usize, x: Vec3) -> Option<(Vec3, f32, f32)> {
        match &self.light_samplers[k] {
            LightSampler::Sphere { center, radius, .. } => {
                cone_one_minus_cos(x, *center, *radius).map(|omc| (*center, *radius, omc))
            }
            LightSampler::Area { .. } => None,
        }
    }

    /// Whether a light sample's emitter is what `x` sees along it: an unoccluded segment for area
    /// samples; for cone samples, the first surface hit must be the front of that emitter.
    fn light_visible(&self, x: Vec3, ls: &LightSample) -> bool {
        match ls.dist {
            Some(dist) => !self.bvh.occluded(x, ls.wi, 0.0, dist * (1.0 - 1e-4)),
            None => self.bvh.intersect(x, ls.wi, 0.0, ls.max_dist).is_some_and(|h| {
                self.shape_emitter[self.mesh.shape_of[h.triangle as usize] as usize] == Some(ls.emitter)
                    && self.normals[h.triangle as usize].dot(ls.wi) < 0.0
            }),
        }
    }
}

impl LightSampler {
    fn area(&self) -> f32 {
        match self {
            LightSampler::Area { area, .. } | LightSampler::Sphere { area, .. } => *area,
        }
    }
}

/// A next-event estimation sample: the direction to an emitter and its solid-angle pdf. `dist`
/// is the distance to the sampled point for area samples; cone samples find their point by
/// casting the ray.
struct LightSample {
    emitter: u8,
    wi: Vec3,
    dist: Option<f32>,
    /// How far along `wi` the emitter can be (cone samples: the distance to the sphere's centre).
    max_dist: f32,
    pdf: f32,
}

/// 1 − cos θ_max of the cone that the sphere (`center`, `radius`) subtends from `x`, or `None`
/// when `x` is inside it. Written as sin²/(1 + cos) to stay accurate for small cones.
fn cone_one_minus_cos(x: Vec3, center: Vec3, radius: f32) -> Option<f32> {
    let d2 = (center - x).length_squared();
    let r2 = radius * radius;
    if d2 <= r2 * (1.0 + 1e-4) {
        return None;
    }
    let sin2 = r2 / d2;
    Some(sin2 / (1.0 + (1.0 - sin2).sqrt()))
}

/// The rendered buffers of one view. `radiance` holds `emitters` RGB values per pixel (the
/// contribution of each emitter), row-major; the ground-truth maps come from the pixel-centre ray.
pub struct ViewRender {
    pub width: usize,
    pub height: usize,
    pub emitters: usize,
    pub radiance: Vec<Vec3>,
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
        self.radiance
            .chunks(self.emitters)
            .map(|px| px.iter().zip(gains).map(|(l, g)| *l * *g).sum())
            .collect()
    }
}

/// Renders one view, rows in parallel: `spp` stratified jittered paths per pixel plus the
/// pixel-centre ray for the ground-truth maps. `on_row` is called after each row (progress).
pub fn render_view(
    scene: &RenderScene,
    cam: &Camera,
    spp: u32,
    seed: u64,
    view: u32,
    max_depth: u32,
    on_row: &(dyn Fn() + Sync),
) -> ViewRender {
    use rayon::prelude::*;
    let (w, h, ne) = (cam.width, cam.height, scene.emitters.len());
    let strata = (spp as f32).sqrt().floor().max(1.0) as u32;
    let rows: Vec<_> = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut row = RowBuffers::new(w, ne);
            for x in 0..w {
                let pixel = (y * w + x) as u32;
                let mut rng = pixel_rng(seed, view, pixel);
                let mut acc = [Vec3::ZERO; MAX_EMITTERS];
                // Padded stratified sampling (pbrt's StratifiedSampler): each 2D pair of
                // dimensions gets its own jittered grid over the pixel's paths, shuffled
                // independently so that the pairs do not correlate; 1D dimensions get jittered
                // strata. Unbiased: every path's uniforms are still uniformly distributed.
                let pixel_uv = stratified_2d(spp, strata, &mut rng);
                let mut bounce = vec![[[0f32; 6]; STRATIFIED_BOUNCES]; spp as usize];
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
                    let d = cam.ray_dir(x as f32 + jx, y as f32 + jy);
                    scene.trace(cam.position, d, &mut rng, &bounce[s], max_depth, &mut acc);
                }
                for k in 0..ne {
                    row.radiance[x * ne + k] = acc[k] / spp as f32;
                }
                let d = cam.ray_dir(x as f32 + 0.5, y as f32 + 0.5);
                if let Some(hit) = scene.surface(cam.position, d, 0.0, f32::INFINITY) {
                    row.depth[x] = hit.t * d.dot(cam.forward());
                    row.normal[x] = hit.normal;
                    row.emitter_mask[x] = hit.emitter.is_some();
                    row.kd[x] = hit.brdf.kd;
                    row.ks[x] = hit.brdf.ks;
                    row.roughness[x] = hit.brdf.rho;
                } else {
                    row.depth[x] = f32::INFINITY;
                }
            }
            on_row();
            row
        })
        .collect();
    let mut out = ViewRender {
        width: w,
        height: h,
        emitters: ne,
        radiance: Vec::with_capacity(w * h * ne),
        depth: Vec::new(),
        normal: Vec::new(),
        emitter_mask: Vec::new(),
        kd: Vec::new(),
        ks: Vec::new(),
        roughness: Vec::new(),
    };
    for r in rows {
        out.radiance.extend(r.radiance);
        out.depth.extend(r.depth);
        out.normal.extend(r.normal);
        out.emitter_mask.extend(r.emitter_mask);
        out.kd.extend(r.kd);
        out.ks.extend(r.ks);
        out.roughness.extend(r.roughness);
    }
    out
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
    use crate::scene::{CameraRig, Geometry, MaterialDesc, RoomBounds, ShapeDesc};

    fn shape(
        name: &str,
        geometry: Geometry,
        kd: f32,
        ks: f32,
        roughness: f32,
        emission: Option<[f32; 3]>,
    ) -> ShapeDesc {
        ShapeDesc {
            name: name.into(),
            object: None,
            tags: Vec::new(),
            geometry,
            material: MaterialDesc {
                kd: [kd; 3],
                ks: [ks; 3],
                roughness,
                texture: None,
            },
            emission,
        }
    }

    /// A floor and a back wall (kd 0.5, specular `ks`, roughness 0.3) under a spherical emitter
    /// of radiance 1 (radius 0.3, centre 0.6 above the origin) and, to the side, a quad emitter
    /// facing down.
    fn lamp_scene(ks: f32) -> RenderScene {
        let shapes = vec![
            shape(
                "floor",
                Geometry::Quad {
                    origin: [-5.0, 0.0, -5.0],
                    u: [0.0, 0.0, 10.0],
                    v: [10.0, 0.0, 0.0],
                },
                0.5,
                ks,
                0.3,
                None,
            ),
            shape(
                "wall",
                Geometry::Quad {
                    origin: [-5.0, 0.0, -2.0],
                    u: [10.0, 0.0, 0.0],
                    v: [0.0, 3.0, 0.0],
                },
                0.5,
                ks,
                0.3,
                None,
            ),
            shape(
                "bulb",
                Geometry::Sphere {
                    center: [0.0, 0.6, 0.0],
                    radius: 0.3,
                    subdivisions: 4,
                },
                0.0,
                0.0,
                1.0,
                Some([1.0; 3]),
            ),
            shape(
                "panel",
                Geometry::Quad {
                    origin: [2.0, 2.0, -0.5],
                    u: [1.0, 0.0, 0.0],
                    v: [0.0, 0.0, 1.0],
                },
                0.0,
                0.0,
                1.0,
                Some([2.0, 1.0, 0.5]),
            ),
        ];
        RenderScene::new(SceneDesc {
            name: "lamp".into(),
            room: RoomBounds {
                min: [-5.0, 0.0, -5.0],
                max: [5.0, 3.0, 5.0],
            },
            camera: CameraRig {
                fov_x_deg: 60.0,
                eye_height: [1.0, 1.5],
                pitch_deg: [-10.0, 0.0],
            },
            shapes,
        })
    }

    /// Next-event estimation's pdf of a sample equals what `light_pdf` (used to weight BRDF
    /// samples that hit the emitter) says for the same direction, for the cone-sampled sphere and
    /// the area-sampled quad alike: otherwise the MIS weights would not sum to one.
    #[test]
    fn light_sample_pdf_matches_light_pdf() {
        let scene = lamp_scene(0.0);
        let x = Vec3::new(0.4, 1e-4, 0.3);
        let mut rng = Pcg32::seed_from_u64(3);
        let mut checked = [0; 2];
        for _ in 0..2000 {
            for k in 0..2u8 {
                let Some(ls) = scene.sample_light(x, k, rng.gen(), rng.gen(), rng.gen()) else {
                    continue;
                };
                let Some(hit) = scene.surface(x, ls.wi, 0.0, f32::INFINITY) else {
                    continue;
                };
                if hit.emitter != Some(k) || !scene.light_visible(x, &ls) {
                    continue;
                }
                let cos_light = -scene.normals[hit.triangle as usize].dot(ls.wi);
                let pdf = scene.light_pdf(k, x, hit.t, cos_light);
                assert!((pdf / ls.pdf - 1.0).abs() < 1e-3, "emitter {k}: {pdf} vs {}", ls.pdf);
                checked[k as usize] += 1;
            }
        }
        assert!(checked.iter().all(|&c| c > 500), "{checked:?}");
    }

    /// Direct light from a sphere of radiance L onto a Lambertian point below its centre at
    /// distance d is kd · L · (r/d)² (irradiance π L sin²θ_max). The estimate, NEE and BRDF
    /// samples combined by MIS, must agree up to the tessellation (5120 faces: < 0.5 %).
    #[test]
    fn sphere_light_gives_analytic_direct_light() {
        let scene = lamp_scene(0.0);
        // A camera ray from the side onto the floor point below the bulb; one scattering event.
        let target = Vec3::new(0.0, 0.0, 0.0);
        let origin = Vec3::new(-1.5, 0.2, 0.0);
        let dir = (target - origin).normalize();
        let mut rng = Pcg32::seed_from_u64(11);
        let n = 20_000;
        let mut sum = Vec3::ZERO;
        for _ in 0..n {
            let strata = [[0f32; 6]; STRATIFIED_BOUNCES].map(|_| std::array::from_fn(|_| rng.gen()));
            let mut acc = [Vec3::ZERO; MAX_EMITTERS];
            scene.trace(origin, dir, &mut rng, &strata, 1, &mut acc);
            sum += acc[0];
        }
        let estimate = sum.x / n as f32;
        let expected = 0.5 * (0.3f32 / 0.6).powi(2);
        assert!(
            (estimate / expected - 1.0).abs() < 0.01,
            "estimate {estimate} vs analytic {expected}"
        );
    }

    /// Regularization only widens glossy lobes: a scene without specular reflectance renders
    /// bit for bit the same with the dataset's estimator as with the unbiased one, and a glossy
    /// floor and wall do not (the regularized estimator is really in use).
    #[test]
    fn regularization_leaves_diffuse_scenes_unchanged() {
        let cam = Camera::looking(Vec3::new(0.0, 1.2, 2.5), 0.0, -0.35, 24, 16, 60.0);
        let render = |ks: f32, estimator: Estimator| {
            let mut scene = lamp_scene(ks);
            scene.estimator = estimator;
            render_view(&scene, &cam, 8, 1, 0, 8, &|| {}).radiance
        };
        assert_eq!(render(0.0, Estimator::UNBIASED), render(0.0, Estimator::DATASET));
        assert_ne!(render(0.5, Estimator::UNBIASED), render(0.5, Estimator::DATASET));
    }
}
