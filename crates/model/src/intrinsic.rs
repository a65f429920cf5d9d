//! The frozen stage-1 scene as stage 2 and the renderer see it (paper Sec. "Differentiable Monte
//! Carlo Raytracing"), and the adapters that let the one Monte Carlo integrator of
//! `i2sdf_render` re-render it.
//!
//! Stage 2 freezes F_d, F_c and F_e (paper Sec. "Training"). A traced ray's radiance is, by
//! eq:radiance, L[index(trace(r))] when it hits an emitter — F_e(z(x)) above a threshold *and*
//! index(x) some cluster ([`EmitterTable::index`]) — and the radiance field's Ĉ(r) otherwise.
//! Here Ĉ is F_c evaluated at the cast hit (surface rendering of the frozen SDF) rather than
//! volume-rendered along the ray: with a converged, small β the volume weights concentrate at the
//! zero crossing, and one F_c query per ray instead of a hundred is what makes the millions of
//! secondary rays of stage 2 affordable on the CPU.
//!
//! The adapters map the pieces onto the integrator's interfaces: [`FrozenScene`] is the
//! [`Geometry`] (hits labelled 0 for ordinary surfaces, k + 1 for emitter k) and the
//! [`RadianceField`]; [`NeuralMaterial`] is the [`Material`] (the material fields of
//! eq:material's Kd, Ks, ρ); [`emitter_lights`] gives one [`ConeLight`] per emitter with L\[k\].
//! [`rerender_view`] is eq:render: one scattering event at the camera's surface point with
//! next-event estimation to every emitter and BRDF sampling, combined by MIS, the next hit taking
//! L\[k\] or F_c.
//!
//! Radiometry: the integrator works in linear radiance in the units of the input images
//! (docs/results.md, "Stage 2: emitters and materials"); F_c is display-referred (trained on LDR pixels), so its
//! values are linearized by the dataset's transfer ([`Radiometry`]).

pub use crate::baked_surface::BakedSurface;
use crate::emitters::EmitterTable;
use crate::emitters::{on_recovered_bulb, BULB_CLEARANCE};
use crate::material_field::{
    brdf_of_channels, MaterialBackbone, MaterialField, MaterialInferWorkspace, MATERIAL_CHANNELS,
};
use crate::observed::ObservedViews;
use crate::query::SceneQuery;
use crate::raycast::{CastSettings, Hit as CastHit, SdfCaster, CAST_CHUNK};
use crate::renderer::sphere_exit;
use crate::scene::NeuralScene;
use crate::shading_normals::SmoothedNormals;
use glam::{DVec3, Vec3};
use i2sdf_data::{Bounds, Camera, DataError, Radiometry};
use i2sdf_render::{
    render_view, ConeLight, Estimator, Geometry, GgxBrdf, Hit as RenderHit, Integrator, Light, LightSet, Material,
    RadianceField, Ray, Scene, SurfacePoint, ViewRender, ViewSettings,
};
use rayon::prelude::*;
use std::sync::{Arc, Mutex};

/// A ray's first surface hit in the frozen scene, labelled.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LabelledHit {
    /// Distance along the unit direction, world units.
    pub t: f32,
    /// World position.
    pub position: Vec3,
    /// Outward unit normal (∇d/‖∇d‖, towards free space).
    pub normal: Vec3,
    /// The emitter the hit lies on: F_e(z(x)) > threshold and [`EmitterTable::index`] is some
    /// cluster; `None` for ordinary surfaces.
    pub emitter: Option<u32>,
}

/// The frozen stage-1 scene (F_d, F_c, F_e) with its emitter clusters, in world units.
pub struct FrozenScene<'a> {
    pub scene: &'a NeuralScene,
    pub caster: SdfCaster<'a>,
    pub emitters: &'a EmitterTable,
    pub radiometry: Radiometry,
    /// A hit is emitting where F_e(z(x)) exceeds this (F_e is a probability: 0.5).
    pub emitter_threshold: f32,
    /// World units by which each emitter's sphere is enlarged for index(x): traced hits on an
    /// emitter lie a little off the clustered training points (other views, the cast's
    /// tolerance). Default: 2 % of the scene's normalization scale.
    pub index_margin: f64,
    /// When baked: the normal of a BVH hit is the SDF gradient queried again at the refined
    /// hit (what the tracer gives, at the cost of a second SDF + gradient query per hit),
    /// rather than the gradient at the BVH's hit, which lies a fraction of a voxel away (the
    /// default: stage 2's secondary rays use only the hit's position and label).
    pub baked_exact_normals: bool,
    /// The baked surface ([`FrozenScene::bake`]), when baked (shared: a trainer bakes once and
    /// hands it to every `FrozenScene` it makes).
    baked: Option<Arc<BakedSurface>>,
    /// What the training cameras saw ([`FrozenScene::observe`]): where set, a hit inside an
    /// emitter's sphere that no camera saw is that emitter's whatever F_e says (F_e was never
    /// trained there: the far side of a bulb).
    pub observed: Option<Arc<ObservedViews>>,
    /// Query buffers kept between calls, with the networks' transposed weights (the scene is
    /// borrowed, so its weights cannot change while this lives). Why: a re-render makes
    /// thousands of small queries, and allocating, zeroing and transposing for each were about a
    /// tenth of its CPU samples in `perf` (the wall time moved by less than the runs' spread).
    queries: Mutex<Vec<SceneQuery<'a>>>,
}

/// [`FrozenScene::index_margin`] as a fraction of the scene's normalization scale.
pub const INDEX_MARGIN: f64 = 0.02;

/// Points per block of the labelling and field queries (parallel tasks over blocks).
const FROZEN_BLOCK: usize = 4096;

/// A ray without a kept feature ([`HitFeatures::slot`]).
const NO_FEATURE: u32 = u32::MAX;

/// The SDF feature z at the BVH hits of a baked cast that lie inside an emitter's sphere, kept
/// from the Newton step's query for F_e ([`FrozenScene::cast`]).
struct HitFeatures {
    /// Per ray: its row of `z`, or [`NO_FEATURE`].
    slot: Vec<u32>,
    /// `[rows × feature_dim]`.
    z: Vec<f32>,
}

impl HitFeatures {
    fn none(rays: usize) -> Self {
        HitFeatures {
            slot: vec![NO_FEATURE; rays],
            z: Vec::new(),
        }
    }
}

impl<'a> FrozenScene<'a> {
    pub fn new(scene: &'a NeuralScene, emitters: &'a EmitterTable, radiometry: Radiometry) -> Self {
        FrozenScene {
            scene,
            caster: SdfCaster::new(scene, CastSettings::default()),
            emitters,
            radiometry,
            emitter_threshold: 0.5,
            index_margin: INDEX_MARGIN * scene.normalization.scale,
            baked_exact_normals: false,
            baked: None,
            observed: None,
            queries: Mutex::new(Vec::new()),
        }
    }

    /// The frozen scene as stage 2 labels its hits: F_e above `emitter_threshold`, the rays cast
    /// in `baked` where given, and — with `observers` (the training views, where
    /// `stage2.label_unobserved`) and at least one emitter — the unobserved surface inside an
    /// emitter labelled as that emitter ([`FrozenScene::observe`]). Stage 2 and every command on a
    /// trained run ([`crate::opened_run::OpenedRun::frozen`]) build theirs here.
    pub fn labelled(
        scene: &'a NeuralScene,
        emitters: &'a EmitterTable,
        radiometry: Radiometry,
        emitter_threshold: f32,
        baked: Option<Arc<BakedSurface>>,
        observers: Option<&[Camera]>,
    ) -> Self {
        let mut frozen = FrozenScene::new(scene, emitters, radiometry);
        frozen.emitter_threshold = emitter_threshold;
        frozen.set_baked_surface(baked);
        if let Some(cameras) = observers.filter(|_| !emitters.is_empty()) {
            frozen.observe(cameras);
        }
        frozen
    }

    /// Records what `cameras` (the training views) see of the frozen surface, for the emitter
    /// labels ([`FrozenScene::observed`]): one cast per pixel centre (bake first: it is fast).
    pub fn observe(&mut self, cameras: &[Camera]) {
        let none = EmitterTable::new(Vec::new(), &[]);
        let unlabelled = FrozenScene {
            scene: self.scene,
            caster: SdfCaster::new(self.scene, self.caster.settings),
            emitters: &none,
            radiometry: self.radiometry,
            emitter_threshold: self.emitter_threshold,
            index_margin: self.index_margin,
            baked_exact_normals: false,
            baked: self.baked.clone(),
            observed: None,
            queries: Mutex::new(Vec::new()),
        };
        self.observed = Some(Arc::new(ObservedViews::new(&unlabelled, cameras)));
    }

    /// Bakes the frozen SDF for ray casting: its marching-cubes mesh over `bounds` (world units;
    /// each side padded by [`PAD_FRACTION`](crate::sdf_mesh::PAD_FRACTION) at both ends, so walls are not clipped) at
    /// `resolution` samples along the longest side, in the render crate's BVH. From then on
    /// [`FrozenScene::cast`] (and the [`Geometry`] adapter) intersect the BVH first and refine
    /// each hit onto the SDF by one Newton step along the ray (one batched SDF + gradient query
    /// for all hits; the normal is the SDF's gradient there, not the facet's); unbounded rays that
    /// the BVH misses, and rays whose BVH hit does not check out on the SDF (|d| over a voxel, the
    /// ray leaving rather than entering the surface, the refined t outside the ray's segment),
    /// fall back to the sphere tracer. Replaces an earlier bake.
    ///
    /// # Measured (2 shared cores; `examples/bake_cast.rs`)
    /// The real run `/tmp/s2a` (dataset `/tmp/room_new`, a 4.8 × 2.7 × 4.3 m room, scale 3.65,
    /// two emitters): 200k secondary rays from the camera-ray hits of 12 training views, cosine-
    /// distributed about the normal, offset 2e-3 × scale (stage 2's). Traced: 3.8–4.2 s, 48–53k
    /// rays/s. Bake at 256: 5.3–6.3 s (voxel ≈ 2 cm); baked cast 0.49–0.60 s, 340–410k rays/s
    /// (7–8×), of which 0.28 s is the one SDF + gradient query at the hits (0.7 M points/s), the
    /// floor of this design; with `baked_exact_normals` 0.81–0.87 s (230–250k rays/s). Agreement:
    /// no ray that the tracer hits is missed; 38 of its 40 misses (out of steps) hit; 99.44 % of
    /// the common hits lie within 1 cm of the traced hit (median 7e-6 m, p99 4e-3 m), 0.08 %
    /// nearer and 0.47 % farther by more (mostly surfaces under a voxel thin, or near-zero
    /// non-crossings that the tracer's hit_eps takes for hits); 12 labels differ. Normals within
    /// 1 cm: median 0.05°, p99 10.7° (0.02° / 2.5° with `baked_exact_normals`). At 384: bake
    /// 17.8 s, 99.67 % within 1 cm, same speed.
    pub fn bake(&mut self, bounds: &Bounds, resolution: usize) -> Result<(), DataError> {
        self.baked = Some(Arc::new(BakedSurface::new(self.scene, bounds, resolution, 0.0)?));
        Ok(())
    }

    /// Whether [`FrozenScene::bake`] has been called.
    pub fn is_baked(&self) -> bool {
        self.baked.is_some()
    }

    /// The baked surface, to share with other `FrozenScene`s of the same scene.
    pub fn baked_surface(&self) -> Option<Arc<BakedSurface>> {
        self.baked.clone()
    }

    /// The smoothed shading normals of the baked surface, where the run has them
    /// ([`BakedSurface::new`]'s `normal_smoothing`).
    pub fn smoothed_normals(&self) -> Option<&SmoothedNormals> {
        self.baked.as_deref().and_then(BakedSurface::smoothed_normals)
    }

    /// The shading normals at world points on the surface: the SDF's gradient, averaged where
    /// the run's are ([`FrozenScene::smoothed_normals`]) — what the mesh-based renderers and the
    /// export give their vertices.
    pub fn shading_normals(&self, points_world: &[Vec3]) -> Vec<Vec3> {
        let normals: Vec<Vec3> = self
            .sdf_gradient(points_world)
            .into_iter()
            .map(|(_, g)| g.normalize_or_zero())
            .collect();
        match self.smoothed_normals() {
            Some(f) => f.at_points(points_world, &normals, None),
            None => normals,
        }
    }

    /// Uses a surface baked by another `FrozenScene` of the same scene.
    pub fn set_baked_surface(&mut self, baked: Option<Arc<BakedSurface>>) {
        self.baked = baked;
    }

    fn centre(&self) -> Vec3 {
        Vec3::from_array(self.scene.normalization.center.map(|v| v as f32))
    }

    fn scale(&self) -> f32 {
        self.scene.normalization.scale as f32
    }

    /// World points → normalized frame (`[n×3]` flat).
    fn to_normalized(&self, points_world: &[Vec3], out: &mut Vec<f32>) {
        let (c, inv) = (self.centre(), 1.0 / self.scale());
        out.clear();
        out.extend(points_world.iter().flat_map(|p| ((*p - c) * inv).to_array()));
    }

    /// The caster's hits (normalized frame) of world rays.
    fn cast_normalized(&self, rays: &[Ray]) -> Vec<CastHit> {
        let (c, s) = (self.centre(), self.scale());
        let origins: Vec<[f32; 3]> = rays.iter().map(|r| ((r.origin - c) / s).to_array()).collect();
        let dirs: Vec<[f32; 3]> = rays.iter().map(|r| r.dir.to_array()).collect();
        let t_min: Vec<f32> = rays.iter().map(|r| r.t_min / s).collect();
        let t_max: Vec<f32> = rays.iter().map(|r| r.t_max / s).collect();
        let mut hits = vec![CastHit::default(); rays.len()];
        self.caster
            .cast_segments(&origins, &dirs, Some(&t_min), &t_max, &mut hits);
        hits
    }

    /// The unlabelled hits of world rays: the sphere tracer's, or, when baked, the BVH's refined
    /// onto the SDF with the tracer for the rest. With `emitter_features`, the baked cast also
    /// keeps the feature z at the BVH hits inside an emitter's sphere ([`HitFeatures`]).
    fn cast_unlabelled(&self, rays: &[Ray], out: &mut [Option<LabelledHit>], emitter_features: bool) -> HitFeatures {
        match &self.baked {
            None => {
                self.cast_traced(rays, out);
                HitFeatures::none(rays.len())
            }
            Some(b) => self.cast_baked(b, rays, out, emitter_features),
        }
    }

    /// The sphere tracer's hits of world rays, unlabelled.
    fn cast_traced(&self, rays: &[Ray], out: &mut [Option<LabelledHit>]) {
        let s = self.scale();
        let hits = self.cast_normalized(rays);
        for ((o, h), r) in out.iter_mut().zip(&hits).zip(rays) {
            *o = h.hit.then(|| LabelledHit {
                t: h.t * s,
                position: r.origin + h.t * s * r.dir,
                normal: Vec3::from_array(h.normal),
                emitter: None,
            });
        }
    }

    /// The ray's segment as the tracer sees it (world units): from max(t_min, near) to
    /// min(t_max, the bound sphere's exit).
    fn segment(&self, r: &Ray) -> (f32, f32) {
        let (c, s) = (self.centre(), self.scale());
        let cs = &self.caster.settings;
        let o = ((r.origin - c) / s).to_array();
        let exit = sphere_exit(o, r.dir.to_array(), cs.bound_radius) * s;
        (r.t_min.max(cs.near * s), r.t_max.min(exit))
    }

    fn cast_baked(
        &self,
        baked: &BakedSurface,
        rays: &[Ray],
        out: &mut [Option<LabelledHit>],
        emitter_features: bool,
    ) -> HitFeatures {
        // 1. The BVH's closest hits (the triangle and barycentrics kept for smoothed normals).
        let mut bvh_hits = vec![None; rays.len()];
        bvh_hits
            .par_chunks_mut(CAST_CHUNK)
            .zip(rays.par_chunks(CAST_CHUNK))
            .for_each(|(t, rays)| {
                let ray = |i: usize| {
                    let r = &rays[i];
                    let (lo, hi) = self.segment(r);
                    (hi > lo).then_some((r.origin, r.dir, lo, hi))
                };
                baked.bvh.intersect_each(rays.len(), ray, |i, h| t[i] = Some(h));
            });
        let t_bvh: Vec<f32> = bvh_hits.iter().map(|h| h.map_or(f32::NAN, |h| h.t)).collect();
        // 2. One SDF + gradient query at every BVH hit, then one Newton step along the ray. At
        // the hits inside an emitter's sphere the same query keeps the feature z for F_e.
        let idx: Vec<usize> = (0..rays.len()).filter(|&i| !t_bvh[i].is_nan()).collect();
        let points: Vec<Vec3> = idx.iter().map(|&i| rays[i].at(t_bvh[i])).collect();
        let near_emitter: Vec<bool> = points
            .iter()
            .map(|p| emitter_features && self.emitters.index(p.as_dvec3(), self.index_margin).is_some())
            .collect();
        let (mut dg, mut features) = (vec![(0.0f32, Vec3::ZERO); points.len()], HitFeatures::none(rays.len()));
        {
            let (with, without): (Vec<usize>, Vec<usize>) = (0..points.len()).partition(|&j| near_emitter[j]);
            let pick = |js: &[usize]| js.iter().map(|&j| points[j]).collect::<Vec<Vec3>>();
            for (&j, v) in without.iter().zip(self.sdf_gradient(&pick(&without))) {
                dg[j] = v;
            }
            let (dg_with, z) = self.sdf_gradient_feature(&pick(&with));
            for (slot, (&j, v)) in with.iter().zip(dg_with).enumerate() {
                dg[j] = v;
                features.slot[idx[j]] = slot as u32;
            }
            features.z = z;
        }
        let (s, voxel) = (self.scale(), baked.voxel);
        // A ray the BVH misses goes to the tracer only when it is unbounded (a path's next
        // segment): most bounded ones are light samples that reach their light, a fifth of a
        // test-view re-render's rays, and checking them took about half of its time. The bake's
        // measurement (see `bake`) found no ray that the tracer hits and the BVH misses.
        let mut fallback: Vec<bool> = rays
            .iter()
            .zip(&t_bvh)
            .map(|(r, t)| !t.is_nan() || !r.t_max.is_finite())
            .collect();
        for (&i, &(d, g)) in idx.iter().zip(&dg) {
            let r = &rays[i];
            // World distance d·s; the world gradient is the normalized one.
            let (dw, gd) = (d * s, g.dot(r.dir));
            if !(dw.is_finite() && gd < 0.0 && dw.abs() <= voxel) {
                continue;
            }
            let (lo, hi) = self.segment(r);
            let t = (t_bvh[i] - (dw / gd).clamp(-voxel, voxel)).max(lo);
            if t > hi {
                continue;
            }
            out[i] = Some(LabelledHit {
                t,
                position: r.origin + t * r.dir,
                normal: g.normalize_or_zero(),
                emitter: None,
            });
            fallback[i] = false;
        }
        if self.baked_exact_normals {
            let idx: Vec<usize> = (0..rays.len()).filter(|&i| !fallback[i]).collect();
            let points: Vec<Vec3> = idx.iter().map(|&i| out[i].unwrap().position).collect();
            for (&i, (_, g)) in idx.iter().zip(self.sdf_gradient(&points)) {
                out[i].as_mut().unwrap().normal = g.normalize_or_zero();
            }
        }
        if let Some(shading) = &baked.shading {
            // The triangle's smoothed vertex normals interpolated, where that faces the ray's
            // origin (else the SDF's, as stage 2 shades such a point).
            for (i, h) in bvh_hits.iter().enumerate() {
                if let (Some(h), Some(hit), false) = (h, out[i].as_mut(), fallback[i]) {
                    let [a, b, c] = shading.faces[h.triangle as usize].map(|v| shading.vertex_normals[v as usize]);
                    let n = ((1.0 - h.u - h.v) * a + h.u * b + h.v * c).normalize_or_zero();
                    if n.dot(rays[i].dir) < 0.0 {
                        hit.normal = n;
                    }
                }
            }
        }
        // 3. The sphere tracer for the rest (their BVH hit's feature is not theirs).
        let rest: Vec<usize> = (0..rays.len()).filter(|&i| fallback[i]).collect();
        for &i in &rest {
            features.slot[i] = NO_FEATURE;
        }
        if rest.is_empty() {
            return features;
        }
        let rest_rays: Vec<Ray> = rest.iter().map(|&i| rays[i]).collect();
        let mut traced = vec![None; rest.len()];
        self.cast_traced(&rest_rays, &mut traced);
        for (&i, h) in rest.iter().zip(traced) {
            out[i] = h;
        }
        features
    }

    /// Casts world rays (origin, unit direction, t_min, t_max per ray) into the frozen SDF and
    /// labels the hits with their emitter. Batched and rayon-parallel inside (the caster's
    /// chunks, or the baked BVH's ([`FrozenScene::bake`]); the labelling in blocks). F_e is
    /// queried only at hits that some emitter's sphere, enlarged by `index_margin`, contains
    /// (elsewhere index(x) is `None` whatever F_e says), and only when the table has emitters.
    ///
    /// When baked, F_e takes the feature z that the Newton step's query computed at the BVH hit
    /// (a fraction of a voxel before the refined hit) instead of querying the SDF again at the
    /// refined hit: light samples all end on an emitter, and that second query was a fifth of
    /// a test-view re-render's time.
    pub fn cast(&self, rays: &[Ray], out: &mut [Option<LabelledHit>]) {
        self.cast_with_bulbs(rays, out, true)
    }

    /// [`FrozenScene::cast`], with or without the fitted bulbs' step (rays sent on past a
    /// recovered bulb are cast without it: they start outside its clearance ball).
    fn cast_with_bulbs(&self, rays: &[Ray], out: &mut [Option<LabelledHit>], bulbs: bool) {
        assert_eq!(rays.len(), out.len());
        let features = self.cast_unlabelled(rays, out, !self.emitters.is_empty());
        if self.emitters.is_empty() {
            return;
        }
        let mut decided = match bulbs {
            true => self.fitted_bulb_hits(rays, out),
            false => vec![false; rays.len()],
        };
        self.panel_hits(rays, out, &mut decided);
        let (idx, cluster): (Vec<usize>, Vec<u32>) = (0..out.len())
            .filter(|&i| !decided[i])
            .filter_map(|i| {
                let h = out[i].as_ref()?;
                let k = self.emitters.index(h.position.as_dvec3(), self.index_margin)?;
                Some((i, k as u32))
            })
            .unzip();
        let points: Vec<Vec3> = idx.iter().map(|&i| out[i].unwrap().position).collect();
        let mut prob = vec![0.0; points.len()];
        let (kept, queried): (Vec<usize>, Vec<usize>) =
            (0..idx.len()).partition(|&j| features.slot[idx[j]] != NO_FEATURE);
        let fd = self.scene.feature_dim();
        let z: Vec<f32> = kept
            .iter()
            .flat_map(|&j| {
                let slot = features.slot[idx[j]] as usize;
                features.z[slot * fd..(slot + 1) * fd].iter().copied()
            })
            .collect();
        let mut p = vec![0.0; kept.len()];
        self.emitter_prob_of_features(&z, &mut p);
        for (&j, p) in kept.iter().zip(p) {
            prob[j] = p;
        }
        let mut p = vec![0.0; queried.len()];
        self.emitter_prob(&queried.iter().map(|&j| points[j]).collect::<Vec<_>>(), &mut p);
        for (&j, p) in queried.iter().zip(p) {
            prob[j] = p;
        }
        for (((&i, p), k), x) in idx.iter().zip(&prob).zip(cluster).zip(&points) {
            if self.emits(k as usize, *p, *x, self.observed.as_deref()) {
                out[i].as_mut().unwrap().emitter = Some(k);
            }
        }
    }

    /// Whether a surface point `x` within emitter `k`'s index is that emitter: F_e (`p`) above
    /// the threshold, or, where stage 2 labels the unobserved surface (`observed` given), no
    /// training camera sees it and it lies in the box of the emitter's points
    /// ([`crate::emitters::Emitter::may_hold_unseen`]).
    pub fn emits(&self, k: usize, p: f32, x: Vec3, observed: Option<&ObservedViews>) -> bool {
        p > self.emitter_threshold
            || observed.is_some_and(|o| {
                self.emitters.emitters[k].may_hold_unseen(x.as_dvec3(), self.index_margin) && !o.observed(x)
            })
    }

    /// Each emitter with a fitted sphere ([`crate::emitters::Emitter::sphere`]: a bulb seen from
    /// one side) is that sphere, emitting all round: a ray that meets the sphere before any
    /// other surface, or whose hit lies on the recovered bulb (within [`BULB_CLEARANCE`] radii
    /// of the centre, facing away from it, [`on_recovered_bulb`]: the seen side and the unseen side stage 1 left),
    /// hits the sphere and its emitter; one that hits the recovered bulb but misses the sphere
    /// goes on from where it leaves the clearance ball. Returns which hits are decided here
    /// (their label included).
    fn fitted_bulb_hits(&self, rays: &[Ray], out: &mut [Option<LabelledHit>]) -> Vec<bool> {
        let mut decided = vec![false; rays.len()];
        let spheres = self.emitters.bulbs();
        if spheres.is_empty() {
            return decided;
        }
        let mut again = Vec::new();
        for (i, ray) in rays.iter().enumerate() {
            for &(k, c, r) in &spheres {
                let on_bulb = out[i].is_some_and(|h| on_recovered_bulb(c, r, h.position, h.normal));
                match sphere_entry(ray, c, r) {
                    Some(t) if on_bulb || out[i].map_or(true, |h| t < h.t) => {
                        let position = ray.origin + t * ray.dir;
                        out[i] = Some(LabelledHit {
                            t,
                            position,
                            normal: (position - c) / r,
                            emitter: Some(k as u32),
                        });
                        decided[i] = true;
                    }
                    None if on_bulb => {
                        // Past the recovered bulb: from where the ray leaves the clearance ball.
                        let exit = sphere_exit((ray.origin - c).to_array(), ray.dir.to_array(), BULB_CLEARANCE * r);
                        again.push((i, Ray::new(ray.origin, ray.dir, exit.max(ray.t_min), ray.t_max)));
                    }
                    _ => continue,
                }
                break;
            }
        }
        if !again.is_empty() {
            let rays2: Vec<Ray> = again.iter().map(|&(_, r)| r).collect();
            let mut out2 = vec![None; rays2.len()];
            self.cast_with_bulbs(&rays2, &mut out2, false);
            for (&(i, _), h) in again.iter().zip(out2) {
                out[i] = h;
                decided[i] = true;
            }
        }
        decided
    }

    /// Each flat emitter's rectangle ([`crate::emitter_panel`]) stands in for the recovered
    /// surface there: a ray not yet `decided` that meets the nearest panel first, or whose hit
    /// lies on the recovered panel, hits the panel and its emitter (and is then decided).
    fn panel_hits(&self, rays: &[Ray], out: &mut [Option<LabelledHit>], decided: &mut [bool]) {
        let panels = self.emitters.panels();
        if panels.is_empty() {
            return;
        }
        for (i, ray) in rays.iter().enumerate() {
            if decided[i] {
                continue;
            }
            let nearest = (panels.iter())
                .filter_map(|&(k, p)| p.hit(ray, out[i].as_ref(), k as u32))
                .min_by(|a, b| a.t.total_cmp(&b.t));
            if let Some(h) = nearest {
                out[i] = Some(h);
                decided[i] = true;
            }
        }
    }

    /// Runs `f` with a query from the pool ([`FrozenScene::queries`]), returned to it after.
    fn with_query<R>(&self, f: impl FnOnce(&mut SceneQuery<'a>) -> R) -> R {
        let pooled = self.queries.lock().unwrap().pop();
        let mut q = pooled.unwrap_or_else(|| SceneQuery::for_fixed_weights(self.scene));
        let r = f(&mut q);
        self.queries.lock().unwrap().push(q);
        r
    }

    /// Runs `f(query, normalized points of the block, block index range)` over blocks of world
    /// points in parallel, one [`SceneQuery`] per block.
    fn blocks<T: Send>(
        &self,
        points_world: &[Vec3],
        out: &mut [T],
        per_point: usize,
        f: impl Fn(&mut SceneQuery, &[f32], usize, &mut [T]) + Sync,
    ) {
        out[..points_world.len() * per_point]
            .par_chunks_mut(FROZEN_BLOCK * per_point)
            .zip(points_world.par_chunks(FROZEN_BLOCK))
            .enumerate()
            .for_each(|(b, (o, pts))| {
                let mut norm = Vec::new();
                self.to_normalized(pts, &mut norm);
                self.with_query(|q| f(q, &norm, b * FROZEN_BLOCK, o));
            });
    }

    /// Linear radiance (F_c linearized by `radiometry`) leaving world points back along −dir:
    /// F_c with the ray direction as its view direction, as stage 1 trained it (camera ray
    /// directions). `dirs` are unit.
    pub fn surface_radiance(&self, points_world: &[Vec3], dirs: &[Vec3], out: &mut [Vec3]) {
        assert!(dirs.len() == points_world.len() && out.len() >= points_world.len());
        let rm = self.radiometry;
        self.blocks(points_world, out, 1, |q, norm, start, o| {
            let m = o.len();
            let d: Vec<f32> = dirs[start..start + m].iter().flat_map(|d| d.to_array()).collect();
            let mut rgb = vec![0.0; m * 3];
            q.radiance_at(norm, &d, &mut rgb);
            for (o, c) in o.iter_mut().zip(rgb.chunks_exact(3)) {
                *o = Vec3::new(rm.linearize(c[0]), rm.linearize(c[1]), rm.linearize(c[2]));
            }
        });
    }

    /// The SDF (normalized units) and its gradient (the same in either frame) at world points.
    pub fn sdf_gradient(&self, points_world: &[Vec3]) -> Vec<(f32, Vec3)> {
        let mut dg = vec![(0.0f32, Vec3::ZERO); points_world.len()];
        self.blocks(points_world, &mut dg, 1, |q, norm, _, o| {
            let m = o.len();
            let (mut d, mut g) = (vec![0.0; m], vec![0.0; m * 3]);
            q.sdf_gradient(norm, &mut d, &mut g);
            for ((o, d), g) in o.iter_mut().zip(&d).zip(g.chunks_exact(3)) {
                *o = (*d, Vec3::new(g[0], g[1], g[2]));
            }
        });
        dg
    }

    /// F_e(z(x)) (probability) at world points.
    pub fn emitter_prob(&self, points_world: &[Vec3], out: &mut [f32]) {
        let fd = self.scene.feature_dim();
        self.blocks(points_world, out, 1, |q, norm, _, o| {
            let m = o.len();
            let (mut d, mut z, mut g) = (vec![0.0; m], vec![0.0; m * fd], vec![0.0; m * 3]);
            q.sdf_full(norm, &mut d, &mut z, &mut g);
            q.emitter(&z, o);
        });
    }

    /// F_e (probability) of features z already computed (`z`: `[n × feature_dim]`).
    fn emitter_prob_of_features(&self, z: &[f32], out: &mut [f32]) {
        let fd = self.scene.feature_dim();
        out.par_chunks_mut(FROZEN_BLOCK)
            .zip(z.par_chunks(FROZEN_BLOCK * fd))
            .for_each(|(o, z)| self.with_query(|q| q.emitter(z, o)));
    }

    /// The SDF, its gradient and the feature z (`[n × feature_dim]`) at world points.
    fn sdf_gradient_feature(&self, points_world: &[Vec3]) -> (Vec<(f32, Vec3)>, Vec<f32>) {
        let fd = self.scene.feature_dim();
        let mut packed = vec![0.0f32; points_world.len() * (4 + fd)];
        self.blocks(points_world, &mut packed, 4 + fd, |q, norm, _, o| {
            let m = o.len() / (4 + fd);
            let (mut d, mut z, mut g) = (vec![0.0; m], vec![0.0; m * fd], vec![0.0; m * 3]);
            q.sdf_full(norm, &mut d, &mut z, &mut g);
            for (i, row) in o.chunks_exact_mut(4 + fd).enumerate() {
                row[0] = d[i];
                row[1..4].copy_from_slice(&g[i * 3..i * 3 + 3]);
                row[4..].copy_from_slice(&z[i * fd..(i + 1) * fd]);
            }
        });
        let dg = packed
            .chunks_exact(4 + fd)
            .map(|r| (r[0], Vec3::new(r[1], r[2], r[3])))
            .collect();
        let z = packed
            .chunks_exact(4 + fd)
            .flat_map(|r| r[4..].iter().copied())
            .collect();
        (dg, z)
    }

    /// The SDF feature z(x) at world points (`out`: `[n × feature_dim]`), for the FeatureMlp
    /// material backbone.
    pub fn features(&self, points_world: &[Vec3], out: &mut [f32]) {
        let fd = self.scene.feature_dim();
        self.blocks(points_world, out, fd, |q, norm, _, o| {
            let m = o.len() / fd;
            let (mut d, mut g) = (vec![0.0; m], vec![0.0; m * 3]);
            q.sdf_full(norm, &mut d, o, &mut g);
        });
    }
}

/// The frozen SDF as the integrator's geometry: surface label 0 for ordinary surfaces, k + 1 for
/// emitter k (what [`emitter_lights`]' light set maps back to L\[k\]); normals outward.
/// Rays the integrator sends skip this far (× the normalization scale) before they can hit: it
/// offsets secondary rays by [`i2sdf_render::integrator::RAY_EPS`] (0.1 mm), made for exact
/// triangles, while the frozen SDF's surface is only known to the tracer's tolerance — without a
/// gap, light and BRDF rays hit the surface they leave (measured: the re-render of the default
/// room came out 27 % dark, its emitters' share nearly gone). Stage 2's own secondary rays are
/// offset by the same distance along the normal.
pub const SURFACE_GAP: f32 = 2e-3;

impl FrozenScene<'_> {
    fn gapped(&self, rays: &[Ray]) -> Vec<Ray> {
        let gap = SURFACE_GAP * self.scale();
        rays.iter()
            .map(|r| Ray {
                t_min: r.t_min.max(gap),
                ..*r
            })
            .collect()
    }
}

impl Geometry for FrozenScene<'_> {
    fn intersect(&self, rays: &[Ray], hits: &mut [Option<RenderHit>]) {
        let rays = self.gapped(rays);
        let rays = &rays[..];
        let mut labelled = vec![None; rays.len()];
        self.cast(rays, &mut labelled);
        for (o, h) in hits.iter_mut().zip(labelled) {
            *o = h.map(|h| RenderHit {
                t: h.t,
                normal: h.normal,
                surface: h.emitter.map_or(0, |k| k + 1),
                prim: 0,
            });
        }
    }

    /// Shadow rays need no labels: any hit occludes (emitter hits of cone samples go through
    /// `intersect`, as [`i2sdf_render::Visibility::FirstHit`] asks).
    fn occluded(&self, rays: &[Ray], occluded: &mut [bool]) {
        let rays = self.gapped(rays);
        let rays = &rays[..];
        if !self.emitters.bulbs().is_empty() || !self.emitters.panels().is_empty() {
            // A fitted bulb or panel stands in for the recovered one (no emitter labels needed).
            let mut hits = vec![None; rays.len()];
            self.cast_unlabelled(rays, &mut hits, false);
            let mut decided = self.fitted_bulb_hits(rays, &mut hits);
            self.panel_hits(rays, &mut hits, &mut decided);
            for (o, h) in occluded.iter_mut().zip(hits) {
                *o = h.is_some();
            }
            return;
        }
        if self.baked.is_some() {
            let mut hits = vec![None; rays.len()];
            self.cast_unlabelled(rays, &mut hits, false);
            for (o, h) in occluded.iter_mut().zip(hits) {
                *o = h.is_some();
            }
            return;
        }
        for (o, h) in occluded.iter_mut().zip(self.cast_normalized(rays)) {
            *o = h.hit;
        }
    }
}

/// Ĉ of eq:radiance for rays that reach an ordinary surface: F_c at the hit, linearized.
impl RadianceField for FrozenScene<'_> {
    fn radiance_batch(&self, rays: &[Ray], hits: &[RenderHit], out: &mut [Vec3]) {
        let points: Vec<Vec3> = rays.iter().zip(hits).map(|(r, h)| r.at(h.t)).collect();
        let dirs: Vec<Vec3> = rays.iter().map(|r| r.dir).collect();
        self.surface_radiance(&points, &dirs, out);
    }
}

/// The material fields as the integrator's material: world positions → the normalized frame
/// (and z(x) from the frozen SDF for the FeatureMlp backbone) → Kd, Ks, ρ → [`GgxBrdf`].
pub struct NeuralMaterial<'f, 'a> {
    pub field: &'f MaterialField,
    pub frozen: &'f FrozenScene<'a>,
    /// Query workspaces kept between calls (the field is borrowed, so its weights cannot change
    /// while this lives). Why: a path tracer asks for materials once per bounce per batch of
    /// paths, and a fresh workspace zeroed its buffers and transposed the MLP's weights each
    /// time (2–3 % of the edit renderer's time in `perf`).
    workspaces: Mutex<Vec<MaterialInferWorkspace>>,
}

impl<'f, 'a> NeuralMaterial<'f, 'a> {
    pub fn new(field: &'f MaterialField, frozen: &'f FrozenScene<'a>) -> Self {
        NeuralMaterial {
            field,
            frozen,
            workspaces: Mutex::new(Vec::new()),
        }
    }
}

impl Material for NeuralMaterial<'_, '_> {
    fn eval_batch(&self, points: &[SurfacePoint], out: &mut [GgxBrdf]) {
        assert_eq!(points.len(), out.len());
        let world: Vec<Vec3> = points.iter().map(|p| p.position).collect();
        let mut norm = Vec::new();
        self.frozen.to_normalized(&world, &mut norm);
        let features = match self.field.config.backbone {
            MaterialBackbone::FeatureMlp => {
                let mut z = vec![0.0; world.len() * self.frozen.scene.feature_dim()];
                self.frozen.features(&world, &mut z);
                z
            }
            MaterialBackbone::HashGrid => Vec::new(),
        };
        let mut m = vec![0.0; world.len() * MATERIAL_CHANNELS];
        let pooled = self.workspaces.lock().unwrap().pop();
        let mut ws = pooled.unwrap_or_else(MaterialInferWorkspace::for_fixed_weights);
        self.field.infer_with(&norm, &features, &mut ws, &mut m);
        self.workspaces.lock().unwrap().push(ws);
        for (o, c) in out.iter_mut().zip(m.chunks_exact(MATERIAL_CHANNELS)) {
            *o = brdf_of_channels(c);
        }
    }
}

/// One [`ConeLight`] per emitter (its bounding sphere about the centre, world units, and L\[k\]),
/// with surface label k + 1 mapped to emitter k (label 0, ordinary surfaces, emits nothing).
/// Hits labelled k lie within the sphere enlarged by the index margin; those outside the cone are
/// still found by BRDF sampling, whose MIS weight is then 1 (the light pdf there is 0), so the
/// estimate stays unbiased.
pub fn emitter_lights(table: &EmitterTable) -> LightSet {
    let mut labels = vec![None];
    labels.extend((0..table.len() as u32).map(Some));
    LightSet::new(emitter_cone_lights(table), labels)
}

/// The lights of [`emitter_lights`], one [`ConeLight`] per emitter in table order (for light
/// sets that add lights of their own, as the edit renderer's inserted emitters).
pub fn emitter_cone_lights(table: &EmitterTable) -> Vec<Box<dyn Light>> {
    table
        .emitters
        .iter()
        .enumerate()
        .map(|(k, e)| {
            Box::new(ConeLight::new(
                DVec3::from_array(e.centre).as_vec3(),
                e.radius as f32,
                table.emission(k),
            )) as Box<dyn Light>
        })
        .collect()
}

/// Re-renders a view of the intrinsic scene (eq:render with eq:radiance): the camera ray's
/// surface point is shaded with the material fields, one scattering event (max_depth 1), next-
/// event estimation to every emitter and a GGX BRDF sample combined by MIS; the next hit takes
/// L\[k\] on emitter k, else F_c (the last radiance slot of the result). Unbiased estimator. The
/// camera's rays are world-space (`Camera::ray_generator`), as the frozen scene expects.
pub fn rerender_view(
    frozen: &FrozenScene,
    material: &MaterialField,
    cam: &Camera,
    spp: u32,
    seed: u64,
    view: u32,
    on_row: &(dyn Fn() + Sync),
) -> ViewRender {
    let lights = emitter_lights(frozen.emitters);
    let nm = NeuralMaterial::new(material, frozen);
    let scene = Scene {
        geometry: frozen,
        material: &nm,
        lights: &lights,
        radiance_field: Some(frozen),
    };
    let settings = ViewSettings {
        spp,
        seed,
        view,
        integrator: Integrator {
            estimator: Estimator::UNBIASED,
            max_depth: 1,
        },
    };
    render_view(&scene, cam, &settings, on_row)
}

/// Where `ray` enters the sphere (c, r) within its segment (None: it misses it, or starts inside).
fn sphere_entry(ray: &Ray, c: Vec3, r: f32) -> Option<f32> {
    let oc = ray.origin - c;
    let b = oc.dot(ray.dir);
    let disc = b * b - (oc.length_squared() - r * r);
    if disc < 0.0 {
        return None;
    }
    let t = -b - disc.sqrt();
    (t > ray.t_min && t < ray.t_max).then_some(t)
}

#[cfg(test)]
#[path = "intrinsic_tests.rs"]
mod tests;
