//! Tests of `intrinsic.rs`: labelled casts, field queries, the render adapters, the re-render and
//! the baked surface. (`Radiometry` and its tests live in `i2sdf_data::radiometry`.)
use super::*;
use crate::emitters::Emitter;
use crate::material_field::MaterialConfig;
use glam::DMat4;
use i2sdf_data::imageio::srgb_to_linear;
use i2sdf_data::Normalization;

/// The tiny inverted sphere, moved and scaled in the world (to exercise the transforms).
fn scene() -> NeuralScene {
    let mut s = crate::scene::tiny_test_scene();
    s.normalization = Normalization {
        center: [1.0, -0.5, 2.0],
        scale: 2.0,
    };
    s
}

/// The tiny scene's field crosses zero beyond the unit sphere in some directions (≈1.05 along
/// +z): trace a little further so that the room is closed.
fn settings() -> CastSettings {
    CastSettings {
        bound_radius: 1.5,
        ..Default::default()
    }
}

fn frozen_scene<'a>(s: &'a NeuralScene, t: &'a EmitterTable) -> FrozenScene<'a> {
    let mut f = FrozenScene::new(s, t, Radiometry::default());
    f.caster = SdfCaster::new(s, settings());
    f
}

fn centre() -> Vec3 {
    Vec3::new(1.0, -0.5, 2.0)
}

fn dirs(n: usize) -> Vec<Vec3> {
    (0..n)
        .map(|i| {
            let (a, b) = (i as f32 * 2.399, (i as f32 + 0.5) / n as f32 * 2.0 - 1.0);
            let r = (1.0 - b * b).sqrt();
            Vec3::new(r * a.cos(), r * a.sin(), b)
        })
        .collect()
}

/// One emitter around where the +y ray from the centre meets the sphere.
fn table(s: &NeuralScene) -> EmitterTable {
    let caster = SdfCaster::new(s, settings());
    let mut h = [CastHit::default()];
    caster.cast(&[[0.0; 3]], &[[0.0, 1.0, 0.0]], &[f32::INFINITY], &mut h);
    assert!(h[0].hit);
    let top = centre() + 2.0 * Vec3::from_array(h[0].point);
    EmitterTable::new(
        vec![Emitter {
            centre: top.as_dvec3().to_array(),
            extent: [0.6, 0.05, 0.6],
            radius: 0.5,
            points: 10,
            sphere: None,
            bounds: None,
            panel: None,
        }],
        &[[4.0, 3.0, 2.0]],
    )
}

fn rays(n: usize) -> Vec<Ray> {
    dirs(n)
        .into_iter()
        .map(|d| Ray::new(centre() + Vec3::new(0.05, 0.0, -0.03), d, 0.0, f32::INFINITY))
        .collect()
}

/// The labelled cast is the caster's hit in world units; with every point F_e-positive
/// (threshold below 0) the labels are exactly index(x) of the table, with the threshold
/// above 1 none; the Geometry adapter's surface labels are label + 1.
#[test]
fn labelled_cast_agrees_with_the_caster_and_the_table() {
    let s = scene();
    let t = table(&s);
    let mut frozen = frozen_scene(&s, &t);
    let rays = rays(500);
    let caster = SdfCaster::new(&s, settings());
    let o: Vec<[f32; 3]> = rays.iter().map(|r| ((r.origin - centre()) / 2.0).to_array()).collect();
    let d: Vec<[f32; 3]> = rays.iter().map(|r| r.dir.to_array()).collect();
    let mut reference = vec![CastHit::default(); rays.len()];
    caster.cast(&o, &d, &vec![f32::INFINITY; rays.len()], &mut reference);
    frozen.emitter_threshold = -1.0;
    let mut hits = vec![None; rays.len()];
    frozen.cast(&rays, &mut hits);
    let mut geo = vec![None; rays.len()];
    frozen.intersect(&rays, &mut geo);
    let mut on_emitter = 0;
    for (i, (h, r)) in hits.iter().zip(&reference).enumerate() {
        let Some(h) = h else {
            assert!(!r.hit);
            continue;
        };
        assert!(r.hit && (h.t - 2.0 * r.t).abs() < 1e-4, "{h:?} vs {r:?}");
        assert!((h.normal - Vec3::from_array(r.normal)).length() < 1e-5);
        assert!((h.position - (centre() + 2.0 * Vec3::from_array(r.point))).length() < 1e-4);
        let want = t.index(h.position.as_dvec3(), frozen.index_margin).map(|k| k as u32);
        assert_eq!(h.emitter, want);
        on_emitter += want.is_some() as usize;
        let g = geo[i].unwrap();
        assert_eq!(g.surface, h.emitter.map_or(0, |k| k + 1));
        // The adapter starts rays SURFACE_GAP later: the same crossing, bracketed anew.
        assert!(
            (g.t - h.t).abs() < 2e-3 && (g.normal - h.normal).length() < 1e-2,
            "{g:?} vs {h:?}"
        );
    }
    assert!(on_emitter > 0 && on_emitter < 100, "{on_emitter} hits on the emitter");
    frozen.emitter_threshold = 1.0;
    frozen.cast(&rays, &mut hits);
    assert!(hits.iter().flatten().all(|h| h.emitter.is_none()));
    // Shadow rays: every ray from inside the closed sphere is blocked, short ones are not.
    let mut occ = vec![false; rays.len()];
    frozen.occluded(&rays, &mut occ);
    assert_eq!(occ, reference.iter().map(|r| r.hit).collect::<Vec<_>>());
    let short: Vec<Ray> = rays.iter().map(|r| Ray { t_max: 0.1, ..*r }).collect();
    frozen.occluded(&short, &mut occ);
    assert!(occ.iter().all(|o| !o));
    // The light set follows the table.
    let lights = emitter_lights(&t);
    assert_eq!(lights.len(), 1);
    let hit = |surface| RenderHit {
        t: 1.0,
        normal: Vec3::Y,
        surface,
        prim: 0,
    };
    assert_eq!(lights.emitter_of(&hit(0)), None);
    assert_eq!(lights.emitter_of(&hit(1)), Some(0));
}

/// The field queries are the scene's queries at the normalized points, linearized; the
/// material adapter is the field's inference at the normalized points (both backbones).
#[test]
fn queries_and_material_match_the_fields() {
    let s = scene();
    let t = table(&s);
    let frozen = FrozenScene::new(&s, &t, Radiometry::default());
    let n = FROZEN_BLOCK + 11;
    let pts: Vec<Vec3> = dirs(n).iter().map(|d| centre() + 1.2 * *d).collect();
    let vd = dirs(n);
    let mut lin = vec![Vec3::ZERO; n];
    frozen.surface_radiance(&pts, &vd, &mut lin);
    let norm: Vec<f32> = pts.iter().flat_map(|p| ((*p - centre()) / 2.0).to_array()).collect();
    let flat_d: Vec<f32> = vd.iter().flat_map(|d| d.to_array()).collect();
    let mut q = SceneQuery::new(&s);
    let mut rgb = vec![0.0; n * 3];
    q.radiance_at(&norm, &flat_d, &mut rgb);
    for (l, c) in lin.iter().zip(rgb.chunks_exact(3)) {
        assert!((l.x - srgb_to_linear(c[0])).abs() < 1e-5 && (l.z - srgb_to_linear(c[2])).abs() < 1e-5);
    }
    let fd = s.feature_dim();
    let mut z = vec![0.0; n * fd];
    frozen.features(&pts, &mut z);
    let (mut d0, mut z0, mut g0) = (vec![0.0; n], vec![0.0; n * fd], vec![0.0; n * 3]);
    q.sdf_full(&norm, &mut d0, &mut z0, &mut g0);
    assert_eq!(z, z0);
    let mut p = vec![0.0; n];
    frozen.emitter_prob(&pts, &mut p);
    let mut p0 = vec![0.0; n];
    q.emitter(&z0, &mut p0);
    assert_eq!(p, p0);
    for backbone in [MaterialBackbone::HashGrid, MaterialBackbone::FeatureMlp] {
        let cfg = MaterialConfig {
            backbone,
            hash_levels: 4,
            hash_log2_table: 10,
            hash_finest_resolution: 64,
            hidden_dim: 16,
            ..Default::default()
        };
        let mut field = MaterialField::new(&cfg, fd, 2);
        field
            .mlp
            .params
            .iter_mut()
            .enumerate()
            .for_each(|(i, v)| *v += 0.05 * (i as f32).sin());
        let nm = NeuralMaterial::new(&field, &frozen);
        let sp: Vec<SurfacePoint> = pts[..300]
            .iter()
            .map(|p| SurfacePoint {
                position: *p,
                normal: Vec3::Y,
                surface: 0,
                prim: 0,
            })
            .collect();
        let mut brdf = vec![GgxBrdf::new(Vec3::ZERO, Vec3::ZERO, 1.0); 300];
        nm.eval_batch(&sp, &mut brdf);
        let mut m = vec![0.0; 300 * MATERIAL_CHANNELS];
        field.infer(&norm[..900], &z[..300 * fd], &mut m);
        for (b, c) in brdf.iter().zip(m.chunks_exact(MATERIAL_CHANNELS)) {
            assert_eq!(b.kd, Vec3::new(c[0], c[1], c[2]));
            assert_eq!((b.ks.y, b.rho), (c[4], c[6]));
        }
    }
}

fn camera() -> Camera {
    let mut c2w = DMat4::IDENTITY;
    c2w.w_axis = centre().as_dvec3().extend(1.0);
    Camera {
        lens: Default::default(),
        width: 8,
        height: 6,
        fx: 6.0,
        fy: 6.0,
        cx: 4.0,
        cy: 3.0,
        c2w,
    }
}

/// A radiance field that is 1 everywhere.
struct White;
impl RadianceField for White {
    fn radiance_batch(&self, _: &[Ray], _: &[RenderHit], out: &mut [Vec3]) {
        out.fill(Vec3::ONE);
    }
}

/// A white furnace through the frozen geometry: inside the closed sphere, no emitters, every
/// secondary ray sees radiance 1, so a diffuse Kd = 0.5 surface reflects exactly 0.5 (cosine
/// sampling: each sample weighs Kd). Then the full re-render with the neural material, F_c
/// and one emitter gives finite, non-negative radiance with the emitter's part where the
/// camera sees it lit.
#[test]
fn rerender_is_a_furnace_and_finite() {
    let s = scene();
    let empty = EmitterTable::new(vec![], &[]);
    let frozen = frozen_scene(&s, &empty);
    let lights = emitter_lights(&empty);
    let grey = i2sdf_render::ConstantMaterial::new(vec![GgxBrdf::new(Vec3::splat(0.5), Vec3::ZERO, 0.8)]);
    let furnace = Scene {
        geometry: &frozen,
        material: &grey,
        lights: &lights,
        radiance_field: Some(&White),
    };
    let settings = ViewSettings {
        spp: 4,
        seed: 1,
        view: 0,
        integrator: Integrator {
            estimator: Estimator::UNBIASED,
            max_depth: 1,
        },
    };
    let r = render_view(&furnace, &camera(), &settings, &|| {});
    assert_eq!(r.emitters, 1);
    assert!(r.depth.iter().all(|d| d.is_finite()), "the room is closed");
    for l in &r.radiance {
        assert!((*l - Vec3::splat(0.5)).abs().max_element() < 1e-3, "{l:?}");
    }
    let t = table(&s);
    let mut frozen = frozen_scene(&s, &t);
    // Every hit F_e-positive: the labels are the table's, so the emitter lights.
    frozen.emitter_threshold = -1.0;
    let field = MaterialField::new(
        &MaterialConfig {
            hash_levels: 4,
            hash_log2_table: 10,
            hash_finest_resolution: 64,
            hidden_dim: 16,
            ..Default::default()
        },
        s.feature_dim(),
        3,
    );
    let rows = std::sync::atomic::AtomicUsize::new(0);
    let on_row = || {
        rows.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    };
    let r = rerender_view(&frozen, &field, &camera(), 4, 7, 0, &on_row);
    assert_eq!(rows.into_inner(), 6);
    assert_eq!((r.width, r.height, r.emitters), (8, 6, 2));
    assert!(r.radiance.iter().all(|l| l.is_finite() && l.min_element() >= 0.0));
    assert!(r.radiance.iter().skip(1).step_by(2).any(|l| l.max_element() > 0.0));
    assert!(
        r.radiance.iter().step_by(2).any(|l| l.max_element() > 0.0),
        "no light from L[0]"
    );
    assert!(
        r.kd.iter().all(|k| (k.x - 0.5).abs() < 0.1),
        "material maps from the field"
    );
    // The emitter's part is linear in L[0] (same seed, same paths); the field's part is not
    // touched by it.
    let mut t2 = t.clone();
    t2.log_emission.iter_mut().for_each(|v| *v += 2f32.ln());
    let mut frozen2 = frozen_scene(&s, &t2);
    frozen2.emitter_threshold = -1.0;
    let r2 = rerender_view(&frozen2, &field, &camera(), 4, 7, 0, &|| {});
    for (px, px2) in r.radiance.chunks(2).zip(r2.radiance.chunks(2)) {
        assert!((px2[0] - 2.0 * px[0]).abs().max_element() <= 1e-4 * (1.0 + px[0].max_element()));
        assert_eq!(px2[1], px[1]);
    }
}

/// World bounds of the tiny scene's room (its surface lies within ≈1.05 normalized units of
/// the centre), `lo`/`hi` normalized.
fn bounds(lo: [f64; 3], hi: [f64; 3]) -> Bounds {
    let c = centre().as_dvec3();
    Bounds {
        min: (c + 2.0 * glam::DVec3::from_array(lo)).to_array(),
        max: (c + 2.0 * glam::DVec3::from_array(hi)).to_array(),
    }
}

/// Rays that the baked BVH itself hits (before any fallback).
fn bvh_hits(f: &FrozenScene, rays: &[Ray]) -> Vec<bool> {
    let b = f.baked.as_ref().unwrap();
    let mut stack = Vec::new();
    rays.iter()
        .map(|r| {
            let (lo, hi) = f.segment(r);
            b.bvh.intersect(r.origin, r.dir, lo, hi, &mut stack).is_some()
        })
        .collect()
}

/// Compares baked hits with the tracer's: same hit/miss and labels, t within `tol` world
/// units, normals within 3°. Returns the 99th percentile of |Δt|.
fn assert_agree(baked: &[Option<LabelledHit>], traced: &[Option<LabelledHit>], tol: f32) -> f32 {
    let mut all = Vec::new();
    for (i, (b, t)) in baked.iter().zip(traced).enumerate() {
        match (b, t) {
            (None, None) => {}
            (Some(b), Some(t)) => {
                all.push((b.t - t.t).abs());
                assert!((b.t - t.t).abs() < tol, "ray {i}: baked {b:?} vs traced {t:?}");
                assert!(
                    b.normal.dot(t.normal) > 3f32.to_radians().cos(),
                    "ray {i}: {b:?} vs {t:?}"
                );
                assert_eq!(b.emitter, t.emitter, "ray {i}: baked {b:?} vs traced {t:?}");
            }
            _ => panic!("ray {i}: baked {b:?} vs traced {t:?}"),
        }
    }
    all.sort_by(f32::total_cmp);
    all[all.len() * 99 / 100]
}

/// Baked casts agree with the tracer's (hits, labels, normals, occlusion) — and they come from
/// the BVH, not the fallback; a bake whose bounds clip the surface leaves a hole through
/// which rays fall back to the tracer and still hit.
#[test]
fn baked_cast_agrees_with_the_tracer() {
    let s = scene();
    let t = table(&s);
    let mut frozen = frozen_scene(&s, &t);
    let mut rays = rays(2000);
    // Secondary-like rays starting just off the surface, and some with a start and an end.
    let mut first = vec![None; rays.len()];
    frozen.cast(&rays, &mut first);
    let more: Vec<Ray> = first
        .iter()
        .zip(dirs(2000).iter().rev())
        .filter_map(|(h, d)| {
            let h = (*h)?;
            let d = if d.dot(h.normal) < 0.0 { -*d } else { *d };
            Some(Ray::new(h.position + 4e-3 * h.normal, d, 0.0, f32::INFINITY))
        })
        .collect();
    assert!(more.len() > 1900);
    rays.extend(more);
    let segments: Vec<Ray> = (0..200)
        .map(|i| Ray {
            t_min: 0.3,
            t_max: 0.5 + 0.01 * i as f32,
            ..rays[i]
        })
        .collect();
    rays.extend(segments);
    let mut baked_scene = frozen_scene(&s, &t);
    assert!(!baked_scene.is_baked());
    baked_scene.bake(&bounds([-1.1; 3], [1.1; 3]), 64).unwrap();
    assert!(baked_scene.is_baked());
    let voxel = baked_scene.baked.as_ref().unwrap().voxel;
    let bvh_hit = bvh_hits(&baked_scene, &rays);
    let from_bvh = bvh_hit.iter().filter(|&&b| b).count();
    // A bounded ray the BVH misses is a miss, without the tracer's check (see `cast_baked`).
    let trusted_miss: Vec<bool> = rays
        .iter()
        .zip(&bvh_hit)
        .map(|(r, &hit)| !hit && r.t_max.is_finite())
        .collect();
    let mut traced = vec![None; rays.len()];
    let mut occ_traced = vec![false; rays.len()];
    // The untrained F_e is ≈ 0.5 everywhere, so a threshold of 0.5 would flip labels on the
    // sub-voxel differences of the hits: no label (threshold 2), the table's index (-1).
    for threshold in [2.0, -1.0] {
        frozen.emitter_threshold = threshold;
        baked_scene.emitter_threshold = threshold;
        frozen.cast(&rays, &mut traced);
        frozen.occluded(&rays, &mut occ_traced);
        // What the tracer hits on the bounded segments that this coarse bake (64) misses: few.
        let lost = traced
            .iter()
            .zip(&trusted_miss)
            .filter(|(h, &m)| m && h.is_some())
            .count();
        assert!(
            lost <= 10,
            "{lost} of 200 segments hit by the tracer and missed by the BVH"
        );
        for (i, _) in trusted_miss.iter().enumerate().filter(|(_, &m)| m) {
            traced[i] = None;
            occ_traced[i] = false;
        }
        let mut baked = vec![None; rays.len()];
        baked_scene.cast(&rays, &mut baked);
        // Grazing secondary rays are the least exact after one Newton step (≈0.3 voxel at
        // worst here); the bulk agrees to far below a voxel (median ≈ 3e-6 world units).
        let p99 = assert_agree(&baked, &traced, 0.35 * voxel);
        assert!(p99 < 0.05 * voxel, "p99 |dt| {p99}, voxel {voxel}");
        let hits = traced.iter().flatten().count();
        assert!(from_bvh as f64 > 0.98 * hits as f64, "{from_bvh} BVH hits of {hits}");
        let labelled = baked.iter().flatten().filter(|h| h.emitter.is_some()).count();
        if threshold < 0.0 {
            assert!(labelled > 10, "{labelled} on the emitter");
        } else {
            assert_eq!(labelled, 0);
        }
        let mut occ = vec![false; rays.len()];
        baked_scene.occluded(&rays, &mut occ);
        assert_eq!(occ, occ_traced);
        let mut geo = vec![None; rays.len()];
        baked_scene.intersect(&rays, &mut geo);
        for (g, h) in geo.iter().zip(&baked) {
            assert_eq!(
                g.map(|g| (g.t, g.surface)),
                h.map(|h| (h.t, h.emitter.map_or(0, |k| k + 1)))
            );
        }
    }
    // A hole: the bake's box stops at x = 0.3 (0.37 padded), so rays from the centre towards
    // +x leave the mesh through its open side and the tracer finds the wall.
    let mut holed = frozen_scene(&s, &t);
    holed.emitter_threshold = -1.0;
    holed.bake(&bounds([-1.1; 3], [0.3, 1.1, 1.1]), 64).unwrap();
    let towards_x: Vec<Ray> = rays[..2000].iter().filter(|r| r.dir.x > 0.8).copied().collect();
    assert!(towards_x.len() > 50);
    assert!(
        bvh_hits(&holed, &towards_x).iter().all(|b| !b),
        "the mesh is open towards +x"
    );
    let (mut a, mut b) = (vec![None; towards_x.len()], vec![None; towards_x.len()]);
    holed.cast(&towards_x, &mut a);
    frozen.cast(&towards_x, &mut b);
    assert!(a.iter().all(|h| h.is_some()));
    assert_eq!(a, b, "fallen back to the tracer: the same hits");
    // Everything else as the tracer, but for the bounded rays that the holed BVH misses.
    let mut all = vec![None; rays.len()];
    holed.cast(&rays, &mut all);
    frozen.cast(&rays, &mut traced);
    for ((h, r), hit) in traced.iter_mut().zip(&rays).zip(bvh_hits(&holed, &rays)) {
        if !hit && r.t_max.is_finite() {
            *h = None;
        }
    }
    assert_agree(&all, &traced, 0.35 * holed.baked.as_ref().unwrap().voxel);
}

/// A bake with smoothed shading normals casts the same hits as the plain bake; its normals are
/// the field's at the hit (the triangle's smoothed vertex normals interpolated), face the rays'
/// origins and differ from the SDF's (the averaging itself is tested in `shading_normals`).
#[test]
fn a_bake_with_smoothed_normals_shades_with_them() {
    let s = scene();
    let t = table(&s);
    let rays = rays(2000);
    let b = bounds([-1.1; 3], [1.1; 3]);
    let mut plain = frozen_scene(&s, &t);
    plain.bake(&b, 64).unwrap();
    assert!(plain.smoothed_normals().is_none());
    let mut smooth = frozen_scene(&s, &t);
    smooth.set_baked_surface(Some(Arc::new(BakedSurface::new(&s, &b, 64, 0.3).unwrap())));
    let field = smooth.smoothed_normals().expect("a field");
    assert_eq!(field.radius(), 0.3);
    let (mut h0, mut h1) = (vec![None; rays.len()], vec![None; rays.len()]);
    plain.cast(&rays, &mut h0);
    smooth.cast(&rays, &mut h1);
    let (mut points, mut raw, mut views, mut got) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut changed = 0;
    for ((a, b), r) in h0.iter().zip(&h1).zip(&rays) {
        let (a, b) = (a.expect("a hit"), b.expect("a hit"));
        assert_eq!((a.t, a.position, a.emitter), (b.t, b.position, b.emitter));
        assert!(b.normal.dot(r.dir) < 0.0, "{b:?} faces away from {r:?}");
        changed += usize::from(a.normal != b.normal);
        points.push(b.position);
        raw.push(a.normal);
        views.push(-r.dir);
        got.push(b.normal);
    }
    assert!(changed > rays.len() / 2, "{changed} normals changed");

    for (q, g) in field.at_points(&points, &raw, Some(&views)).iter().zip(&got) {
        assert!(q.dot(*g) > 3f32.to_radians().cos(), "field {q} vs hit {g}");
    }
}

/// The baked cast's kept features give F_e as a query at the same points would: the joint
/// SDF + gradient + feature query equals the separate ones, and F_e of the kept features equals
/// `emitter_prob` there.
#[test]
fn kept_features_give_the_same_emitter_probability() {
    let s = scene();
    let t = table(&s);
    let f = frozen_scene(&s, &t);
    let points: Vec<Vec3> = dirs(300).iter().map(|d| centre() + 0.9 * *d).collect();
    let (dg, z) = f.sdf_gradient_feature(&points);
    assert_eq!(dg, f.sdf_gradient(&points));
    let fd = s.feature_dim();
    let mut z_alone = vec![0.0; points.len() * fd];
    f.features(&points, &mut z_alone);
    assert_eq!(z, z_alone);
    let (mut from_z, mut queried) = (vec![0.0; points.len()], vec![0.0; points.len()]);
    f.emitter_prob_of_features(&z, &mut from_z);
    f.emitter_prob(&points, &mut queried);
    assert_eq!(from_z, queried);
}

/// An emitter with a fitted sphere (a bulb) is that sphere in the labelled cast: a ray that
/// meets it first hits it (its emitter, the radial normal, the analytic distance); every other
/// ray hits what it hit without the sphere. F_e labels nothing here (threshold above 1).
#[test]
fn a_fitted_bulb_is_its_sphere() {
    let s = scene();
    let c = centre() + Vec3::new(0.3, 0.2, -0.1);
    let r = 0.15f32;
    let table_with = |sphere: Option<[f64; 4]>| {
        EmitterTable::new(
            vec![Emitter {
                centre: c.as_dvec3().to_array(),
                extent: [0.3; 3],
                radius: 0.2,
                points: 10,
                sphere,
                bounds: None,
                panel: None,
            }],
            &[[4.0, 3.0, 2.0]],
        )
    };
    let (bulb, plain) = (
        table_with(Some([c.x as f64, c.y as f64, c.z as f64, r as f64])),
        table_with(None),
    );
    let rays = rays(2000);
    let cast = |t: &EmitterTable| {
        let mut f = frozen_scene(&s, t);
        f.emitter_threshold = 1.0;
        let mut hits = vec![None; rays.len()];
        f.cast(&rays, &mut hits);
        hits
    };
    let (with, without) = (cast(&bulb), cast(&plain));
    let mut on_bulb = 0;
    for ((ray, w), p) in rays.iter().zip(&with).zip(&without) {
        let (w, p) = (w.unwrap(), p.unwrap());
        match sphere_entry(ray, c, r) {
            Some(t) => {
                on_bulb += 1;
                assert!((w.t - t).abs() < 1e-5 && w.emitter == Some(0), "{w:?} against {t}");
                assert!((w.normal - (w.position - c) / r).length() < 1e-5);
                assert!(((w.position - c).length() - r).abs() < 1e-5);
            }
            None => assert_eq!(w, p),
        }
    }
    assert!(on_bulb > 20 && on_bulb < rays.len() / 2, "{on_bulb} rays on the bulb");
}

/// The ray-sphere entry and the clearance ball's exit (the renderer's `sphere_exit`, about the
/// centre): a ray through the centre enters at d − r and leaves at d + r; a ray past the sphere,
/// one that starts inside and one whose segment ends before it have no entry.
#[test]
fn sphere_entry_and_exit() {
    let c = Vec3::new(0.0, 0.0, 5.0);
    let ray = Ray::new(Vec3::ZERO, Vec3::Z, 0.0, f32::INFINITY);
    assert!((sphere_entry(&ray, c, 1.0).unwrap() - 4.0).abs() < 1e-5);
    assert!((sphere_exit((-c).to_array(), [0.0, 0.0, 1.0], 1.0) - 6.0).abs() < 1e-5);
    let past = Ray::new(Vec3::new(2.0, 0.0, 0.0), Vec3::Z, 0.0, f32::INFINITY);
    assert_eq!(sphere_entry(&past, c, 1.0), None);
    let inside = Ray::new(c, Vec3::Z, 0.0, f32::INFINITY);
    assert_eq!(sphere_entry(&inside, c, 1.0), None);
    let short = Ray::new(Vec3::ZERO, Vec3::Z, 0.0, 3.5);
    assert_eq!(sphere_entry(&short, c, 1.0), None);
}

/// A panel inside the recovered sphere, across the +y rays from the centre, facing it: those
/// rays meet the panel (labelled, its normal) before the sphere; the others keep the caster's
/// hit and label; shadow rays stop at the panel too; a ray from above passes.
#[test]
fn a_panel_stands_in_for_the_recovered_surface() {
    let s = scene();
    let lo = [
        centre().x as f64 - 0.3,
        centre().y as f64 + 0.5,
        centre().z as f64 - 0.3,
    ];
    let hi = [
        centre().x as f64 + 0.3,
        centre().y as f64 + 0.52,
        centre().z as f64 + 0.3,
    ];
    let panel = crate::emitter_panel::Panel::of_box([lo, hi], centre().as_dvec3().to_array(), 0.01).unwrap();
    let t = EmitterTable::new(
        vec![Emitter {
            centre: [centre().x as f64, centre().y as f64 + 0.51, centre().z as f64],
            extent: [0.6, 0.02, 0.6],
            radius: 0.45,
            points: 10,
            sphere: None,
            bounds: Some([lo, hi]),
            panel: Some(panel),
        }],
        &[[4.0, 3.0, 2.0]],
    );
    let plain = EmitterTable::new(Vec::new(), &[]);
    let (mut frozen, reference) = (frozen_scene(&s, &t), frozen_scene(&s, &plain));
    // No label from F_e: only the panel's.
    frozen.emitter_threshold = 2.0;
    let rays = rays(400);
    let (mut hits, mut want) = (vec![None; rays.len()], vec![None; rays.len()]);
    frozen.cast(&rays, &mut hits);
    reference.cast(&rays, &mut want);
    let mut on_panel = 0;
    for ((h, w), r) in hits.iter().zip(&want).zip(&rays) {
        let (h, w) = (h.unwrap(), w.unwrap());
        let y = r.origin.y + r.dir.y * (panel.offset as f32 - r.origin.y) / r.dir.y;
        let x = r.origin + r.dir * ((y - r.origin.y) / r.dir.y);
        let crosses = r.dir.y > 0.0 && (x.x - centre().x).abs() < 0.3 && (x.z - centre().z).abs() < 0.3;
        if crosses {
            on_panel += 1;
            assert_eq!(h.emitter, Some(0));
            assert!((h.position.y - panel.offset as f32).abs() < 1e-4 && h.normal == -Vec3::Y);
            assert!(h.t < w.t);
        } else {
            assert_eq!((h.t, h.emitter), (w.t, None), "{r:?}");
        }
    }
    assert!(on_panel > 5 && on_panel < 100, "{on_panel}");
    // Shadow rays: blocked by the panel within their segment, whatever lies past it.
    let up = Ray::new(centre(), Vec3::Y, 0.0, 0.8);
    let side = Ray::new(centre(), Vec3::X, 0.0, 0.8);
    let mut occ = [false; 2];
    frozen.occluded(&[up, side], &mut occ);
    assert_eq!(occ, [true, false]);
    // From above the panel (its back), a ray down meets the sphere's surface as before.
    let down = Ray::new(centre() + Vec3::new(0.0, 0.9, 0.0), -Vec3::Y, 0.0, f32::INFINITY);
    let (mut a, mut b) = ([None], [None]);
    frozen.cast(&[down], &mut a);
    reference.cast(&[down], &mut b);
    assert_eq!(a[0].map(|h| (h.t, h.emitter)), b[0].map(|h| (h.t, h.emitter)));
}
