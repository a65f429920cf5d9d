//! The Monte Carlo estimator of the rendering equation (paper eq:render, written once for every
//! physical renderer of the house): a path tracer with next-event estimation on every emitter at
//! every vertex, multiple importance sampling (power heuristic) between light and BRDF sampling,
//! BRDF sampling with the supplementary's GGX mixture (`crate::brdf`), Russian roulette from the
//! third bounce, and optional path-space regularization ([`Estimator`]).
//!
//! It is a wavefront: a batch of paths advances one bounce at a time, and each bounce issues its
//! expensive queries as batches — closest hits of all live paths, the materials of all their
//! hits, the shadow rays of all light samples — through the [`Geometry`], [`Material`] and
//! [`LightSet`] interfaces. A triangle BVH answers them ray by ray; an SDF sphere tracer or a
//! neural material field answers a whole tile at once.
//!
//! Radiance is accumulated per emitter: every path ends on exactly one emitter (emitters do not
//! reflect), so the image is linear in each emitter's emission, L = Σ_k L_k, and a relit image
//! (emitter k scaled by s_k ⊙ c_k) is Σ_k s_k c_k ⊙ L_k, exact and free of extra rendering.
//! Regularization changes BRDFs, never emission, so this holds for either estimator.

use crate::brdf::{BrdfLobe, GgxBrdf};
use crate::color::max_channel;
use crate::geometry::{Geometry, Hit, Ray};
use crate::light::{LightSet, Visibility};
use crate::material::{Material, SurfacePoint};
use crate::sampling::power_heuristic;
use glam::Vec3;
use rand::Rng;
use rand_pcg::Pcg32;

/// Bounces whose light and BRDF samples are stratified across a pixel's paths.
pub const STRATIFIED_BOUNCES: usize = 2;
/// Per bounce: triangle choice on area emitters, two for the point on (or direction to) each
/// emitter, lobe choice, two for the direction.
pub type BounceUniforms = [[f32; 6]; STRATIFIED_BOUNCES];

/// Offset of secondary ray origins along the normal (metres); the thinnest parts are 10 mm.
pub const RAY_EPS: f32 = 1e-4;

/// Which estimator [`Integrator::trace`] computes. [`Estimator::UNBIASED`] is the plain path
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
    /// The dataset default: see `regularize_roughness` (bias below the 4×-spp noise of the
    /// default room, fireflies gone).
    pub const DATASET: Estimator = Estimator {
        regularize_roughness: Some(0.5),
    };
}

/// Radiance leaving non-emitting surfaces, for estimators that end paths there instead of
/// scattering further: stage 2's frozen radiance field F_c (paper eq:radiance: a traced ray's
/// radiance is L\[k\] if it hits emitter k, else the radiance field's Ĉ(r)). Batched like the
/// other interfaces (a field is a network).
pub trait RadianceField: Sync {
    /// `out[i]`: radiance leaving `hits[i]` back along `rays[i]` (towards the ray's origin).
    fn radiance_batch(&self, rays: &[Ray], hits: &[Hit], out: &mut [Vec3]);
}

/// What the integrator renders: geometry, materials and emitters behind their interfaces, and
/// optionally a radiance field that answers for paths reaching a non-emitting surface after
/// `max_depth` scattering events (without one, those paths end there, carrying nothing more).
#[derive(Clone, Copy)]
pub struct Scene<'a> {
    pub geometry: &'a dyn Geometry,
    pub material: &'a dyn Material,
    pub lights: &'a LightSet,
    pub radiance_field: Option<&'a dyn RadianceField>,
}

impl Scene<'_> {
    /// Radiance slots per path or pixel: one per emitter, plus one for the radiance field's
    /// part when there is one (it cannot be attributed to an emitter, so it is not relit).
    pub fn slots(&self) -> usize {
        self.lights.len() + self.radiance_field.is_some() as usize
    }
}

/// One path to trace: its camera ray, the stratified uniforms of its first bounces and its own
/// sampler for the rest (deterministic whatever the batch it is traced in).
#[derive(Clone, Debug)]
pub struct PathStart {
    pub origin: Vec3,
    pub dir: Vec3,
    pub strata: BounceUniforms,
    pub rng: Pcg32,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Integrator {
    pub estimator: Estimator,
    /// Most scattering events per path (Russian roulette ends most paths far earlier).
    pub max_depth: u32,
}

impl Integrator {
    /// Traces `paths`, adding emitter k's part of path `i`'s radiance estimate to
    /// `radiance[i · scene.slots() + k]` (and the radiance field's part, if any, to the last slot).
    pub fn trace(&self, scene: &Scene, paths: &mut [PathStart], radiance: &mut [Vec3]) {
        let ne = scene.slots();
        assert_eq!(
            radiance.len(),
            paths.len() * ne,
            "radiance slots: one per path and emitter"
        );
        let mut wave = Wavefront::new(paths);
        for depth in 0..=self.max_depth {
            if wave.active.is_empty() {
                break;
            }
            wave.intersect_active(scene.geometry, depth);
            wave.end_on_emitters(scene, depth < self.max_depth, radiance, ne);
            if wave.vertices.hits.is_empty() {
                break;
            }
            wave.vertices.eval_materials(&wave.state, scene.material);
            self.sample_vertices(&mut wave, scene.lights, paths, depth);
            wave.shadows.resolve(scene, radiance, ne);
            std::mem::swap(&mut wave.active, &mut wave.next);
        }
        if let Some(field) = scene.radiance_field {
            wave.field.resolve(field, &wave.state, radiance, ne);
        }
    }

    /// Step 4 of a bounce: at every scattering vertex, the light samples (one per emitter:
    /// choosing one by power left the bulb's contribution with selection noise), queued for their
    /// shadow queries, and the BRDF sample that continues the path; the surviving paths go to
    /// `wave.next`.
    #[inline]
    fn sample_vertices(&self, wave: &mut Wavefront, lights: &LightSet, paths: &mut [PathStart], depth: u32) {
        let Wavefront {
            state,
            next,
            vertices,
            shadows,
            ..
        } = wave;
        next.clear();
        shadows.clear();
        for (j, &(i, _)) in vertices.hits.iter().enumerate() {
            let (path, s) = (&mut paths[i as usize], &mut state[i as usize]);
            let vertex = self.vertex(i, &vertices.points[j], vertices.brdfs[j], s);
            let u = bounce_uniforms(path, depth);
            shadows.sample_lights(lights, &vertex, s.beta, [u[0], u[1], u[2]]);
            if continue_path(&vertex, s, &mut path.rng, [u[3], u[4], u[5]], depth) {
                next.push(i);
            }
        }
    }

    /// Path `i`'s scattering vertex at `point`, leaving along `-s.dir`, with its BRDF regularized
    /// once the path has been diffuse (see [`Estimator::regularize_roughness`]).
    #[inline]
    fn vertex(&self, i: u32, point: &SurfacePoint, mut brdf: GgxBrdf, s: &PathState) -> Vertex {
        let n = point.normal;
        if let (true, Some(rho)) = (s.after_diffuse, self.estimator.regularize_roughness) {
            brdf.rho = brdf.rho.max(rho);
        }
        Vertex {
            path: i,
            origin: point.position + n * RAY_EPS,
            n,
            wo: -s.dir,
            brdf,
        }
    }
}

/// A path between bounces.
#[derive(Clone, Copy)]
struct PathState {
    origin: Vec3,
    dir: Vec3,
    beta: Vec3,
    /// Solid-angle pdf of the BRDF sample that produced `dir` (`None` for camera rays: emitters
    /// seen directly get MIS weight 1).
    brdf_pdf: Option<f32>,
    /// Whether the path has scattered off a diffuse lobe (regularization starts after it).
    after_diffuse: bool,
}

/// A scattering vertex as its light and BRDF samples see it.
struct Vertex {
    path: u32,
    /// Where secondary rays start: the surface point offset along `n` by [`RAY_EPS`].
    origin: Vec3,
    /// The shading normal, on the side the path arrived from.
    n: Vec3,
    /// Towards where the path came from.
    wo: Vec3,
    brdf: GgxBrdf,
}

/// A light sample's contribution, waiting for its shadow query.
struct Pending {
    path: u32,
    emitter: u32,
    value: Vec3,
}

/// The state and scratch buffers of one [`Integrator::trace`] call. Every buffer is cleared and
/// refilled at each bounce, so once they have grown nothing is allocated per bounce.
struct Wavefront {
    state: Vec<PathState>,
    /// Paths alive at this bounce, and those that continue to the next.
    active: Vec<u32>,
    next: Vec<u32>,
    /// The bounce's rays of the live paths (in `active`'s order) and their closest hits.
    rays: Vec<Ray>,
    hits: Vec<Option<Hit>>,
    vertices: Vertices,
    shadows: ShadowQueries,
    field: FieldQueries,
}

impl Wavefront {
    fn new(paths: &[PathStart]) -> Self {
        let active: Vec<u32> = (0..paths.len() as u32).collect();
        Wavefront {
            state: paths
                .iter()
                .map(|p| PathState {
                    origin: p.origin,
                    dir: p.dir,
                    beta: Vec3::ONE,
                    brdf_pdf: None,
                    after_diffuse: false,
                })
                .collect(),
            next: Vec::with_capacity(active.len()),
            active,
            rays: Vec::new(),
            hits: Vec::new(),
            vertices: Vertices {
                hits: Vec::new(),
                points: Vec::new(),
                brdfs: Vec::new(),
            },
            shadows: ShadowQueries {
                seg_rays: Vec::new(),
                seg_pending: Vec::new(),
                seg_occluded: Vec::new(),
                first_rays: Vec::new(),
                first_pending: Vec::new(),
                first_hits: Vec::new(),
            },
            field: FieldQueries {
                rays: Vec::new(),
                hits: Vec::new(),
                paths: Vec::new(),
            },
        }
    }

    /// Step 1 of a bounce: the closest hits of every live path (camera rays from their origin,
    /// secondary rays past [`RAY_EPS`]).
    #[inline]
    fn intersect_active(&mut self, geometry: &dyn Geometry, depth: u32) {
        let t_min = if depth == 0 { 0.0 } else { RAY_EPS };
        let state = &self.state;
        self.rays.clear();
        self.rays.extend(self.active.iter().map(|&i| {
            let s = &state[i as usize];
            Ray::new(s.origin, s.dir, t_min, f32::INFINITY)
        }));
        self.hits.clear();
        self.hits.resize(self.rays.len(), None);
        geometry.intersect(&self.rays, &mut self.hits);
    }

    /// Step 2 of a bounce: emission where a path ends on an emitter (MIS-weighted against light
    /// sampling unless the camera sees it directly). The paths on other surfaces scatter when
    /// `scatter` (they go to `self.vertices`), else queue for the radiance field, if any; paths
    /// that escape end.
    #[inline]
    fn end_on_emitters(&mut self, scene: &Scene, scatter: bool, radiance: &mut [Vec3], ne: usize) {
        self.vertices.hits.clear();
        for (j, &i) in self.active.iter().enumerate() {
            let Some(hit) = self.hits[j] else {
                continue;
            };
            let s = &self.state[i as usize];
            if let Some(k) = scene.lights.emitter_of(&hit) {
                if let Some(l) = emission_seen(scene.lights, k, s, &hit) {
                    radiance[i as usize * ne + k] += l;
                }
                continue;
            }
            if scatter {
                self.vertices.hits.push((i, hit));
            } else if scene.radiance_field.is_some() {
                self.field.rays.push(self.rays[j]);
                self.field.hits.push(hit);
                self.field.paths.push(i);
            }
        }
    }
}

/// The emission of emitter `k` that path `s` reaches at `hit`, MIS-weighted against the light
/// sample that could have found it (weight 1 for camera rays); `None` where it emits nothing
/// that way.
#[inline]
fn emission_seen(lights: &LightSet, k: usize, s: &PathState, hit: &Hit) -> Option<Vec3> {
    let light = lights.get(k);
    let le = light.emitted(hit, s.dir);
    if le == Vec3::ZERO {
        return None;
    }
    let w = match s.brdf_pdf {
        None => 1.0,
        Some(pb) => power_heuristic(pb, light.pdf(s.origin, s.dir, hit)),
    };
    Some(s.beta * le * w)
}

/// The uniforms of path `path`'s vertex at `depth`: its stratified ones for the first
/// [`STRATIFIED_BOUNCES`], then six draws of its own sampler.
#[inline]
fn bounce_uniforms(path: &mut PathStart, depth: u32) -> [f32; 6] {
    if (depth as usize) < STRATIFIED_BOUNCES {
        path.strata[depth as usize]
    } else {
        std::array::from_fn(|_| path.rng.gen())
    }
}

/// Continues path `s` from `vertex` by sampling its BRDF with `u` (weight, pdf for MIS at the
/// next emitter hit, new ray), with Russian roulette from the third bounce on (drawing from
/// `rng`). False when the path ends: no sample, or the roulette ended it.
#[inline]
fn continue_path(vertex: &Vertex, s: &mut PathState, rng: &mut Pcg32, u: [f32; 3], depth: u32) -> bool {
    let Some(smp) = vertex.brdf.sample(vertex.n, vertex.wo, u) else {
        return false;
    };
    s.beta *= smp.weight;
    s.after_diffuse |= smp.lobe == BrdfLobe::Diffuse;
    s.brdf_pdf = Some(smp.pdf);
    s.origin = vertex.origin;
    s.dir = smp.d;
    if depth >= 2 {
        let q = max_channel(s.beta).min(0.95);
        if rng.gen::<f32>() >= q {
            return false;
        }
        s.beta /= q;
    }
    true
}

/// The scattering vertices of one bounce, in one batch: path and hit, surface point, BRDF.
struct Vertices {
    hits: Vec<(u32, Hit)>,
    points: Vec<SurfacePoint>,
    brdfs: Vec<GgxBrdf>,
}

impl Vertices {
    /// Step 3 of a bounce: the surface points of every vertex (normal facing the arriving path)
    /// and their materials, in one batch.
    #[inline]
    fn eval_materials(&mut self, state: &[PathState], material: &dyn Material) {
        self.points.clear();
        self.points.extend(self.hits.iter().map(|&(i, hit)| {
            let s = &state[i as usize];
            SurfacePoint {
                position: s.origin + hit.t * s.dir,
                normal: if hit.normal.dot(s.dir) > 0.0 {
                    -hit.normal
                } else {
                    hit.normal
                },
                surface: hit.surface,
                prim: hit.prim,
            }
        }));
        self.brdfs.clear();
        self.brdfs
            .resize(self.points.len(), GgxBrdf::new(Vec3::ZERO, Vec3::ZERO, 1.0));
        material.eval_batch(&self.points, &mut self.brdfs);
    }
}

/// The light samples of one bounce waiting for their shadow queries: free segments to sampled
/// points, and first hits that must be the front of the sampled emitter (cone samples).
struct ShadowQueries {
    seg_rays: Vec<Ray>,
    seg_pending: Vec<Pending>,
    seg_occluded: Vec<bool>,
    first_rays: Vec<Ray>,
    first_pending: Vec<Pending>,
    first_hits: Vec<Option<Hit>>,
}

impl ShadowQueries {
    #[inline]
    fn clear(&mut self) {
        self.seg_rays.clear();
        self.seg_pending.clear();
        self.first_rays.clear();
        self.first_pending.clear();
    }

    /// Next-event estimation at `vertex` (path throughput `beta`): one sample per emitter with the
    /// same uniforms `u`, MIS-weighted against BRDF sampling, queued for its shadow query.
    #[inline]
    fn sample_lights(&mut self, lights: &LightSet, vertex: &Vertex, beta: Vec3, u: [f32; 3]) {
        let (n, wo, brdf) = (vertex.n, vertex.wo, &vertex.brdf);
        for k in 0..lights.len() {
            let Some(ls) = lights.get(k).sample(vertex.origin, u) else {
                continue;
            };
            let cos_x = n.dot(ls.wi);
            if !(cos_x > 0.0) {
                continue;
            }
            let f = brdf.eval(n, wo, ls.wi);
            if !(max_channel(f) > 0.0) {
                continue;
            }
            let w = power_heuristic(ls.pdf, brdf.pdf(n, wo, ls.wi));
            let pending = Pending {
                path: vertex.path,
                emitter: k as u32,
                value: beta * f * ls.radiance * (cos_x * w / ls.pdf),
            };
            match ls.visibility {
                Visibility::Segment(dist) => {
                    self.seg_rays
                        .push(Ray::new(vertex.origin, ls.wi, 0.0, dist * (1.0 - 1e-4)));
                    self.seg_pending.push(pending);
                }
                Visibility::FirstHit(max_dist) => {
                    self.first_rays.push(Ray::new(vertex.origin, ls.wi, 0.0, max_dist));
                    self.first_pending.push(pending);
                }
            }
        }
    }

    /// Step 5 of a bounce: the shadow queries, batched; each unoccluded sample adds its value to
    /// its path's slot of its emitter.
    #[inline]
    fn resolve(&mut self, scene: &Scene, radiance: &mut [Vec3], ne: usize) {
        self.seg_occluded.clear();
        self.seg_occluded.resize(self.seg_rays.len(), true);
        scene.geometry.occluded(&self.seg_rays, &mut self.seg_occluded);
        for (p, &occ) in self.seg_pending.iter().zip(&self.seg_occluded) {
            if !occ {
                radiance[p.path as usize * ne + p.emitter as usize] += p.value;
            }
        }
        self.first_hits.clear();
        self.first_hits.resize(self.first_rays.len(), None);
        scene.geometry.intersect(&self.first_rays, &mut self.first_hits);
        for ((p, h), r) in self.first_pending.iter().zip(&self.first_hits).zip(&self.first_rays) {
            if h.is_some_and(|h| scene.lights.emitter_of(&h) == Some(p.emitter as usize) && h.normal.dot(r.dir) < 0.0) {
                radiance[p.path as usize * ne + p.emitter as usize] += p.value;
            }
        }
    }
}

/// Paths that reached a non-emitting surface after their last scattering event, waiting for the
/// radiance field: their last ray and hit.
struct FieldQueries {
    rays: Vec<Ray>,
    hits: Vec<Hit>,
    paths: Vec<u32>,
}

impl FieldQueries {
    /// The queued paths take the field's radiance at their hit, weight 1 (no other strategy
    /// samples it), in the last slot.
    fn resolve(&self, field: &dyn RadianceField, state: &[PathState], radiance: &mut [Vec3], ne: usize) {
        let mut l = vec![Vec3::ZERO; self.rays.len()];
        field.radiance_batch(&self.rays, &self.hits, &mut l);
        for (&i, l) in self.paths.iter().zip(&l) {
            radiance[i as usize * ne + ne - 1] += state[i as usize].beta * *l;
        }
    }
}

/// Small scenes built from the render crate alone, for the tests of the integrator and the view
/// renderer.
#[cfg(test)]
pub(crate) mod test_scenes {
    use super::*;
    use crate::area_light::AreaLight;
    use crate::constant_material::ConstantMaterial;
    use crate::light::Light;
    use crate::mesh_geometry::MeshGeometry;
    use crate::sphere_light::SphereLight;
    use i2sdf_data::TriangleMesh;

    pub struct OwnedScene {
        pub geometry: MeshGeometry,
        pub material: ConstantMaterial,
        pub lights: LightSet,
    }

    impl OwnedScene {
        pub fn scene(&self) -> Scene<'_> {
            Scene {
                geometry: &self.geometry,
                material: &self.material,
                lights: &self.lights,
                radiance_field: None,
            }
        }
    }

    pub enum Emits {
        No,
        Area(Vec3),
        Sphere(Vec3, Vec3),
    }

    /// Shapes (mesh, BRDF, emission) → one scene, shape i labelled i.
    pub fn build(shapes: Vec<(TriangleMesh, GgxBrdf, Emits)>) -> OwnedScene {
        let mut labels = Vec::new();
        let mut brdfs = Vec::new();
        let meshes: Vec<TriangleMesh> = shapes.iter().map(|s| s.0.clone()).collect();
        for (i, s) in shapes.iter().enumerate() {
            labels.extend(std::iter::repeat_n(i as u32, s.0.faces.len()));
            brdfs.push(s.1);
        }
        let mesh = TriangleMesh::concat(&meshes);
        let mut lights: Vec<Box<dyn Light>> = Vec::new();
        let mut emitter_of = vec![None; shapes.len()];
        for (i, s) in shapes.iter().enumerate() {
            let faces: Vec<u32> = (0..labels.len() as u32)
                .filter(|&t| labels[t as usize] == i as u32)
                .collect();
            match s.2 {
                Emits::No => continue,
                Emits::Area(e) => lights.push(Box::new(AreaLight::new(&mesh, &faces, e))),
                Emits::Sphere(c, e) => lights.push(Box::new(SphereLight::new(&mesh, &faces, c, e))),
            }
            emitter_of[i] = Some(lights.len() as u32 - 1);
        }
        OwnedScene {
            geometry: MeshGeometry::new(&mesh, labels),
            material: ConstantMaterial::new(brdfs),
            lights: LightSet::new(lights, emitter_of),
        }
    }

    pub fn quad(origin: Vec3, u: Vec3, v: Vec3) -> TriangleMesh {
        TriangleMesh {
            positions: vec![origin, origin + u, origin + u + v, origin + v]
                .into_iter()
                .map(|p| p.to_array())
                .collect(),
            faces: vec![[0, 1, 2], [0, 2, 3]],
            face_object_ids: None,
        }
    }

    pub fn sphere(c: Vec3, r: f32, subdivisions: u32) -> TriangleMesh {
        let mut m = TriangleMesh::unit_icosphere(subdivisions);
        m.positions
            .iter_mut()
            .for_each(|p| *p = (c + r * Vec3::from(*p)).to_array());
        m
    }

    pub fn lambert(kd: f32) -> GgxBrdf {
        GgxBrdf::new(Vec3::splat(kd), Vec3::ZERO, 1.0)
    }

    /// A floor and a back wall (kd 0.5, specular `ks`, roughness 0.3) under a spherical emitter
    /// of radiance 1 (radius 0.3, centre 0.6 above the origin) and, to the side, a quad emitter
    /// facing down.
    pub fn lamp(ks: f32) -> OwnedScene {
        let plastic = GgxBrdf::new(Vec3::splat(0.5), Vec3::splat(ks), 0.3);
        let c = Vec3::new(0.0, 0.6, 0.0);
        build(vec![
            (
                quad(Vec3::new(-5.0, 0.0, -5.0), 10.0 * Vec3::Z, 10.0 * Vec3::X),
                plastic,
                Emits::No,
            ),
            (
                quad(Vec3::new(-5.0, 0.0, -2.0), 10.0 * Vec3::X, 3.0 * Vec3::Y),
                plastic,
                Emits::No,
            ),
            (sphere(c, 0.3, 4), lambert(0.0), Emits::Sphere(c, Vec3::ONE)),
            (
                quad(Vec3::new(2.0, 2.0, -0.5), Vec3::X, Vec3::Z),
                lambert(0.0),
                Emits::Area(Vec3::new(2.0, 1.0, 0.5)),
            ),
        ])
    }

    /// A closed box whose walls all emit `le` inwards (reflecting nothing) around a box and a
    /// sphere of Lambertian albedo `kd`.
    pub fn furnace(le: Vec3, kd: f32) -> OwnedScene {
        let room = TriangleMesh::axis_box([-2.0, 0.0, -2.0], [2.0, 3.0, 2.0]).flipped();
        build(vec![
            (room, lambert(0.0), Emits::Area(le)),
            (
                TriangleMesh::axis_box([-0.8, 0.0, -1.2], [0.4, 0.9, -0.3]),
                lambert(kd),
                Emits::No,
            ),
            (sphere(Vec3::new(-0.2, 1.3, -0.8), 0.4, 3), lambert(kd), Emits::No),
            (sphere(Vec3::new(0.8, 0.5, -0.6), 0.3, 2), lambert(kd), Emits::No),
        ])
    }
}

#[cfg(test)]
mod tests {
    use super::test_scenes::*;
    use super::*;
    use rand::SeedableRng;

    fn random_strata(rng: &mut Pcg32) -> BounceUniforms {
        std::array::from_fn(|_| std::array::from_fn(|_| rng.gen()))
    }

    fn trace_many(
        scene: &OwnedScene,
        integrator: Integrator,
        origin: Vec3,
        dir: Vec3,
        n: usize,
        seed: u64,
    ) -> Vec<Vec3> {
        let mut rng = Pcg32::seed_from_u64(seed);
        let mut paths: Vec<PathStart> = (0..n)
            .map(|i| PathStart {
                origin,
                dir,
                strata: random_strata(&mut rng),
                rng: Pcg32::new(seed, i as u64),
            })
            .collect();
        let mut radiance = vec![Vec3::ZERO; n * scene.lights.len()];
        integrator.trace(&scene.scene(), &mut paths, &mut radiance);
        radiance
    }

    /// White furnace of the integrator itself: inside a closed box emitting Le, objects of
    /// albedo 1 reflect everything, so every path's estimate averages to Le whatever it hits;
    /// NEE, MIS weights, light pdfs and Russian roulette must all be right.
    #[test]
    fn white_furnace_every_direction_sees_the_emission() {
        let le = Vec3::new(1.0, 0.5, 2.0);
        let scene = furnace(le, 1.0);
        let integrator = Integrator {
            estimator: Estimator::UNBIASED,
            max_depth: 64,
        };
        let origin = Vec3::new(0.0, 1.2, 1.5);
        let targets = [
            Vec3::new(-0.2, 1.3, -0.8),
            Vec3::new(-0.2, 0.45, -0.75),
            Vec3::new(0.8, 0.5, -0.6),
        ];
        for target in targets {
            let r = trace_many(&scene, integrator, origin, (target - origin).normalize(), 20_000, 7);
            let mean = r.iter().copied().sum::<Vec3>() / r.len() as f32;
            let rel = ((mean - le) / le).abs().max_element();
            assert!(rel < 0.01, "towards {target}: mean {mean} vs Le {le}");
        }
        // Energy loss is detected: albedo 0.5 gives less.
        let grey = furnace(le, 0.5);
        let r = trace_many(&grey, integrator, origin, (targets[0] - origin).normalize(), 4000, 8);
        let mean = r.iter().copied().sum::<Vec3>() / r.len() as f32;
        assert!(mean.x < 0.9 * le.x, "{mean}");
    }

    /// A radiance field that knows the furnace's answer (every surface leaves Le) completes
    /// one-bounce paths: the estimate is Le again, with the field's part in its own slot; without
    /// it, one bounce loses the light of later ones.
    #[test]
    fn radiance_field_answers_for_paths_ending_on_surfaces() {
        struct Uniform(Vec3);
        impl RadianceField for Uniform {
            fn radiance_batch(&self, _: &[Ray], _: &[Hit], out: &mut [Vec3]) {
                out.fill(self.0);
            }
        }
        let le = Vec3::new(1.0, 0.5, 2.0);
        let owned = furnace(le, 1.0);
        let field = Uniform(le);
        let mut scene = owned.scene();
        scene.radiance_field = Some(&field);
        assert_eq!(scene.slots(), 2);
        let integrator = Integrator {
            estimator: Estimator::UNBIASED,
            max_depth: 1,
        };
        // The top of the box, right under the sphere: much of what it sees is an object.
        let origin = Vec3::new(0.0, 1.2, 1.5);
        let dir = (Vec3::new(-0.5, 0.9, -0.5) - origin).normalize();
        let n = 20_000;
        let mut rng = Pcg32::seed_from_u64(2);
        let mut paths: Vec<PathStart> = (0..n)
            .map(|i| PathStart {
                origin,
                dir,
                strata: random_strata(&mut rng),
                rng: Pcg32::new(5, i as u64),
            })
            .collect();
        let mut radiance = vec![Vec3::ZERO; 2 * n];
        integrator.trace(&scene, &mut paths, &mut radiance);
        let total = radiance.iter().copied().sum::<Vec3>() / n as f32;
        let from_field = radiance.iter().skip(1).step_by(2).copied().sum::<Vec3>() / n as f32;
        assert!(((total - le) / le).abs().max_element() < 0.01, "{total} vs {le}");
        assert!(from_field.x > 0.2 * le.x, "the field's part {from_field}");
        let without = trace_many(&owned, integrator, origin, dir, n, 2);
        let without = without.iter().copied().sum::<Vec3>() / n as f32;
        println!("with field {total} (field part {from_field}), without {without}, Le {le}");
        assert!(((total - without) / le).min_element() > 0.2, "{without} vs {total}");
    }

    /// Direct light from a sphere of radiance L onto a Lambertian point below its centre at
    /// distance d is kd · L · (r/d)² (irradiance π L sin²θ_max). The estimate, NEE and BRDF
    /// samples combined by MIS, must agree up to the tessellation (5120 faces: < 0.5 %).
    #[test]
    fn sphere_light_gives_analytic_direct_light() {
        let scene = lamp(0.0);
        let origin = Vec3::new(-1.5, 0.2, 0.0);
        let dir = (Vec3::ZERO - origin).normalize();
        let integrator = Integrator {
            estimator: Estimator::UNBIASED,
            max_depth: 1,
        };
        let n = 20_000;
        let r = trace_many(&scene, integrator, origin, dir, n, 11);
        let estimate = (0..n).map(|i| r[i * 2].x).sum::<f32>() / n as f32;
        let expected = 0.5 * (0.3f32 / 0.6).powi(2);
        assert!(
            (estimate / expected - 1.0).abs() < 0.01,
            "estimate {estimate} vs analytic {expected}"
        );
    }

    /// MIS consistency in the estimator: with only light sampling or only BRDF sampling
    /// contributing for a direct-lighting estimate, the combination is unbiased only if the two
    /// pdfs describe the same densities; a glossy floor under both emitters makes both strategies
    /// matter. Two independent runs of the full estimator agree with each other and the sum of
    /// direct light matches a brute-force BRDF-only estimate (emission hits, weight 1).
    #[test]
    fn mis_combination_matches_brdf_sampling_alone() {
        let scene = lamp(0.4);
        let origin = Vec3::new(-1.2, 0.5, 1.0);
        let dir = (Vec3::new(0.3, 0.0, 0.2) - origin).normalize();
        let integrator = Integrator {
            estimator: Estimator::UNBIASED,
            max_depth: 1,
        };
        let n = 40_000;
        let r = trace_many(&scene, integrator, origin, dir, n, 3);
        let mis: Vec3 = r.iter().copied().sum::<Vec3>() / n as f32;
        // BRDF sampling alone: trace the first bounce by hand with the scene's interfaces.
        let mut rng = Pcg32::seed_from_u64(4);
        let s = scene.scene();
        let hit = crate::geometry::intersect_one(s.geometry, Ray::new(origin, dir, 0.0, f32::INFINITY)).unwrap();
        let p = origin + hit.t * dir;
        let nrm = hit.normal;
        let mut brdf = [lambert(0.0)];
        s.material.eval_batch(
            &[SurfacePoint {
                position: p,
                normal: nrm,
                surface: hit.surface,
                prim: hit.prim,
            }],
            &mut brdf,
        );
        let m = 400_000;
        let mut brute = Vec3::ZERO;
        for _ in 0..m {
            let Some(smp) = brdf[0].sample(nrm, -dir, [rng.gen(), rng.gen(), rng.gen()]) else {
                continue;
            };
            let o = p + nrm * RAY_EPS;
            if let Some(h) = crate::geometry::intersect_one(s.geometry, Ray::new(o, smp.d, RAY_EPS, f32::INFINITY)) {
                if let Some(k) = s.lights.emitter_of(&h) {
                    brute += smp.weight * s.lights.get(k).emitted(&h, smp.d);
                }
            }
        }
        brute /= m as f32;
        let rel = ((mis - brute) / brute).abs().max_element();
        assert!(rel < 0.03, "MIS {mis} vs BRDF sampling alone {brute}");
    }
}
