//! The ground-truth renderer: an unbiased path tracer over the scene triangles with next-event
//! estimation on the area emitters, multiple importance sampling (power heuristic) between light
//! and BRDF sampling, Russian roulette, and the supplementary's GGX BRDF (`i2sdf_render`).
//!
//! Radiance is accumulated per emitter: every path ends on exactly one emitter (emitters do not
//! reflect), so the image is linear in each emitter's emission, `L = Σ_k L_k`, and a relit image
//! (emitter k scaled by s_k ⊙ c_k) is `Σ_k s_k c_k ⊙ L_k`, exact and free of extra rendering.

use crate::bvh::Bvh;
use crate::camera::Camera;
use crate::mesh::TriangleMesh;
use crate::scene::{SceneDesc, TextureDesc};
use glam::Vec3;
use i2sdf_render::color::{luminance, max_channel};
use i2sdf_render::sampling::{power_heuristic, uniform_triangle};
use i2sdf_render::GgxBrdf;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg32;

/// Most emitters a scene may have (per-emitter radiance is kept for relighting).
pub const MAX_EMITTERS: usize = 8;
/// Bounces whose light and BRDF samples are stratified across a pixel's paths.
pub const STRATIFIED_BOUNCES: usize = 2;
/// Per bounce: light selection, two for the point on the light, lobe choice, two for the direction.
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

pub struct RenderScene {
    pub desc: SceneDesc,
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
    light_tris: Vec<u32>,
    light_cdf: Vec<f32>,
    /// Σ over emitter triangles of area · lum(emission): light selection is proportional to it.
    light_weight_total: f32,
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
        let mut light_tris = Vec::new();
        let mut light_cdf = Vec::new();
        let mut total = 0.0f32;
        for (t, &s) in mesh.shape_of.iter().enumerate() {
            if let Some(k) = shape_emitter[s as usize] {
                total += mesh.area(t) * luminance(emitters[k as usize].emission);
                light_tris.push(t as u32);
                light_cdf.push(total);
            }
        }
        RenderScene {
            desc,
            mesh,
            bvh,
            normals,
            shape_brdf,
            shape_texture,
            shape_emitter,
            emitters,
            obstacle_bounds,
            light_tris,
            light_cdf,
            light_weight_total: total,
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

    /// Solid-angle density with which next-event estimation picks a point seen at distance `dist`
    /// with cosine `cos_light` on emitter `k`: (lum(E_k) / W) · dist² / cos_light.
    fn light_pdf(&self, k: u8, dist: f32, cos_light: f32) -> f32 {
        if cos_light <= 0.0 {
            return 0.0;
        }
        luminance(self.emitters[k as usize].emission) / self.light_weight_total * dist * dist / cos_light
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
                        Some(pb) => power_heuristic(pb, self.light_pdf(k, hit.t, cos_light)),
                    };
                    per_emitter[k as usize] += beta * self.emitters[k as usize].emission * w;
                }
                break;
            }
            if depth == max_depth {
                break;
            }
            let (p, n, wo, brdf) = (hit.position, hit.normal, -d, hit.brdf);
            let origin_out = p + n * RAY_EPS;
            // Next-event estimation: a point on an emitter, chosen by area · luminance.
            let u = if (depth as usize) < STRATIFIED_BOUNCES {
                strata[depth as usize]
            } else {
                [rng.gen(), rng.gen(), rng.gen(), rng.gen(), rng.gen(), rng.gen()]
            };
            let (k, y, ny) = self.sample_light(u[0], u[1], u[2]);
            let to = y - origin_out;
            let dist2 = to.length_squared();
            let dist = dist2.sqrt();
            let wi = to / dist;
            let cos_x = n.dot(wi);
            let cos_y = -ny.dot(wi);
            if cos_x > 0.0 && cos_y > 0.0 {
                let f = brdf.eval(n, wo, wi);
                if max_channel(f) > 0.0 && !self.bvh.occluded(origin_out, wi, 0.0, dist * (1.0 - 1e-4)) {
                    let pl = self.light_pdf(k, dist, cos_y);
                    let w = power_heuristic(pl, brdf.pdf(n, wo, wi));
                    per_emitter[k as usize] += beta * f * self.emitters[k as usize].emission * (cos_x * w / pl);
                }
            }
            // BRDF sampling continues the path.
            let Some(s) = brdf.sample(n, wo, [u[3], u[4], u[5]]) else {
                break;
            };
            beta *= s.weight;
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

    /// A point on an emitter: (emitter, position, outward normal).
    fn sample_light(&self, u_select: f32, u1: f32, u2: f32) -> (u8, Vec3, Vec3) {
        let x = u_select * self.light_weight_total;
        let i = self
            .light_cdf
            .partition_point(|&c| c <= x)
            .min(self.light_tris.len() - 1);
        let t = self.light_tris[i] as usize;
        let (b1, b2) = uniform_triangle(u1, u2);
        let p = self.mesh.vertex(t, 0) * (1.0 - b1 - b2) + self.mesh.vertex(t, 1) * b1 + self.mesh.vertex(t, 2) * b2;
        let k = self.shape_emitter[self.mesh.shape_of[t] as usize].expect("light triangles belong to emitters");
        (k, p, self.normals[t])
    }
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
