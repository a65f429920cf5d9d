//! The steps of building stage 2's cache ([`super::Stage2::new`]): the training pixels cast
//! into the frozen SDF, the box the surface is baked over, each pixel's kind and shading point,
//! and the incident radiance traced once. The emitters found on the way: [`super::emitter_setup`].

use super::{pixel_rng, refresh_selection, CachedPixel, PixelKind};
use crate::config::Stage2Config;
use crate::stage2::shading::{trace_incident, DiffuseSums, ShadingPoint};
use crate::stage2::surface_cache::{ShadingCache, SpecularBake};
use crate::stage2::targets::TargetView;
use glam::{DVec3, Vec3};
use i2sdf_data::{DataError, Radiometry};
use i2sdf_model::emitters::{EmitterTable, BULB_CLEARANCE};
use i2sdf_model::intrinsic::{FrozenScene, LabelledHit};
use i2sdf_model::shading_normals::SmoothedNormals;
use i2sdf_model::{BakeRecord, NeuralScene};
use i2sdf_render::Ray;
use rand::seq::SliceRandom;
use rand_pcg::{Pcg32, Pcg64};
use rayon::prelude::*;

/// The cached pixels cast into the frozen SDF.
pub(super) struct Cast {
    /// (view, pixel) of each cast pixel, sorted.
    pub order: Vec<(u32, u32)>,
    pub rays: Vec<Ray>,
    pub hits: Vec<Option<LabelledHit>>,
    /// Indices into `order` of the pixels that hit, their points and F_e there.
    pub hit_idx: Vec<usize>,
    pub points: Vec<Vec3>,
    pub emitter_prob: Vec<f32>,
}

/// A uniform subset of all training pixels (`stage2.cache_pixels`; drawn with `rng`), cast into
/// the frozen SDF, with F_e at their hits.
pub(super) fn cast_training_pixels(
    scene: &NeuralScene,
    views: &[TargetView],
    radiometry: Radiometry,
    c2: &Stage2Config,
    rng: &mut Pcg64,
    progress: &dyn Fn(&str),
) -> Result<Cast, DataError> {
    let total: usize = views.iter().map(|v| v.rgb.len()).sum();
    if total == 0 {
        return Err(DataError::invalid("stage 2: the dataset has no training pixels"));
    }
    let mut order: Vec<(u32, u32)> = views
        .iter()
        .enumerate()
        .flat_map(|(v, view)| (0..view.rgb.len() as u32).map(move |p| (v as u32, p)))
        .collect();
    if c2.cache_pixels > 0 && c2.cache_pixels < total {
        order.shuffle(rng);
        order.truncate(c2.cache_pixels);
        order.sort_unstable();
    }
    progress(&format!("casting {} training pixels into the frozen SDF", order.len()));
    let rays: Vec<Ray> = order
        .iter()
        .map(|&(v, p)| {
            let cam = &views[v as usize].camera;
            let g = cam.ray_generator();
            let (x, y) = (p as usize % cam.width, p as usize / cam.width);
            Ray::new(g.origin, g.dir(x as f32 + 0.5, y as f32 + 0.5), 0.0, f32::INFINITY)
        })
        .collect();
    let no_emitters = EmitterTable::new(Vec::new(), &[]);
    let frozen = FrozenScene::new(scene, &no_emitters, radiometry);
    let mut hits: Vec<Option<LabelledHit>> = vec![None; rays.len()];
    frozen.cast(&rays, &mut hits);
    let hit_idx: Vec<usize> = (0..hits.len()).filter(|&i| hits[i].is_some()).collect();
    let points: Vec<Vec3> = hit_idx.iter().filter_map(|&i| hits[i].map(|h| h.position)).collect();
    let mut emitter_prob = vec![0.0f32; points.len()];
    frozen.emitter_prob(&points, &mut emitter_prob);
    Ok(Cast {
        order,
        rays,
        hits,
        hit_idx,
        points,
        emitter_prob,
    })
}

/// Where to bake the frozen surface for the secondary rays (a BVH over its marching-cubes mesh,
/// hits refined onto the SDF): the box of the surface the training pixels see and the cameras,
/// the dataset's own bounds in effect. None without hits or with `stage2.bake_resolution = 0`.
/// Where some view has no normal map to shade with, the surface's shading normals are smoothed
/// over `stage2.normal_smoothing_radius` (normalized units, `scale` world units each).
pub(super) fn bake_record(points: &[Vec3], views: &[TargetView], c2: &Stage2Config, scale: f32) -> Option<BakeRecord> {
    (c2.bake_resolution > 0 && !points.is_empty()).then(|| {
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for p in points
            .iter()
            .map(|p| p.as_dvec3())
            .chain(views.iter().map(|v| v.camera.center()))
        {
            lo = lo.min(p);
            hi = hi.max(p);
        }
        BakeRecord {
            bounds: i2sdf_data::Bounds {
                min: lo.to_array(),
                max: hi.to_array(),
            },
            resolution: c2.bake_resolution,
            normal_smoothing: smoothing_radius(views, c2) * scale,
        }
    })
}

/// The radius (normalized units) over which the SDF's shading normals are averaged: 0 where
/// every view has a normal map that stage 2 shades with.
pub(super) fn smoothing_radius(views: &[TargetView], c2: &Stage2Config) -> f32 {
    let sdf_normals = views.iter().any(|v| v.normal.is_none() || !c2.input_normals);
    if sdf_normals {
        c2.normal_smoothing_radius
    } else {
        0.0
    }
}

/// The cached rays that meet a bulb's clearance ball, cast again into the labelled scene
/// (`frozen`, the emitters known), so that the cache sees each bulb as every renderer does
/// (`FrozenScene::cast`): on its sphere, with the recovered bulb cast through. Returns, per
/// cached ray, whether it now ends on a bulb's sphere.
pub(super) fn recast_through_bulbs(frozen: &FrozenScene<'_>, cast: &mut Cast) -> Vec<bool> {
    let mut on_sphere = vec![false; cast.rays.len()];
    let bulbs = frozen.emitters.bulbs();
    if bulbs.is_empty() {
        return on_sphere;
    }
    let near = |ray: &Ray| {
        bulbs.iter().any(|&(_, c, r)| {
            let oc = c - ray.origin;
            let t = oc.dot(ray.dir).max(0.0);
            (oc - t * ray.dir).length() < BULB_CLEARANCE * r
        })
    };
    let idx: Vec<usize> = (0..cast.rays.len()).filter(|&i| near(&cast.rays[i])).collect();
    let rays: Vec<Ray> = idx.iter().map(|&i| cast.rays[i]).collect();
    let mut hits = vec![None; rays.len()];
    frozen.cast(&rays, &mut hits);
    for (&i, h) in idx.iter().zip(hits) {
        on_sphere[i] = h.is_some_and(|h| {
            h.emitter.is_some_and(|k| {
                (bulbs.iter()).any(|&(b, c, r)| b == k as usize && ((h.position - c).length() - r).abs() < 1e-3 * r)
            })
        });
        cast.hits[i] = h;
    }
    on_sphere
}

/// Each hit pixel's kind (an emitter by the dataset's mask where it has one, else by F_e; a
/// pixel marked emitter outside every emitter's box is dropped; a surface pixel the dataset's
/// material mask marks non-GGX is dropped too, as no material of the model can reproduce it —
/// the surface still reflects light onto the others) and shading point, whose normal
/// is the dataset's normal map where it has one (an input, as in stage 1's normal loss; sharper
/// than the SDF's gradient at edges), else the SDF's, averaged over
/// `stage2.normal_smoothing_radius` (normalized units; `scale` world units each) by `smoothed`
/// (the baked surface's field) where given.
pub(super) fn label_pixels(
    cast: &Cast,
    on_sphere: &[bool],
    views: &[TargetView],
    c2: &Stage2Config,
    emitters: &EmitterTable,
    index_margin: f64,
    scale: f32,
    smoothed: Option<&SmoothedNormals>,
    progress: &dyn Fn(&str),
) -> Vec<CachedPixel> {
    let mut pixels = Vec::with_capacity(cast.hit_idx.len());
    let mut from_map = Vec::with_capacity(cast.hit_idx.len());
    let (mut given_normals, mut normal_angle) = (0usize, 0.0f64);
    let mut surface = 0u32;
    for (j, &i) in cast.hit_idx.iter().enumerate() {
        let Some(h) = cast.hits[i] else { continue };
        let (v, p) = cast.order[i];
        let view = &views[v as usize];
        let is_emitter = match &view.emitter_mask {
            Some(m) => m[p as usize],
            None => cast.emitter_prob[j] > c2.emitter_threshold,
        };
        if !is_emitter && view.material_mask.as_ref().is_some_and(|m| !m[p as usize]) {
            continue;
        }
        let to_cam = -cast.rays[i].dir;
        let given = view
            .normal
            .as_ref()
            .map(|n| Vec3::from_array(n[p as usize]))
            .filter(|n| c2.input_normals && (n.length() - 1.0).abs() < 0.1);
        if let Some(n) = given {
            given_normals += 1;
            normal_angle += n.normalize().dot(h.normal).abs().min(1.0).acos() as f64;
        }
        let normal = given.map(|n| n.normalize()).unwrap_or(h.normal);
        let normal = if normal.dot(to_cam) < 0.0 { -normal } else { normal };
        let kind = if on_sphere.get(i).copied().unwrap_or(false) {
            // On a bulb's sphere: its emitter where the mask (or F_e) agrees; else the rim of
            // the sphere the images do not show as light, neither emitter nor a surface.
            match (is_emitter, h.emitter) {
                (true, Some(k)) => PixelKind::Emitter(k),
                _ => continue,
            }
        } else if is_emitter {
            match emitters.index(h.position.as_dvec3(), index_margin) {
                Some(k) => PixelKind::Emitter(k as u32),
                None => continue,
            }
        } else {
            surface += 1;
            PixelKind::Surface { index: surface - 1 }
        };
        from_map.push(given.is_some());
        pixels.push(CachedPixel {
            point: ShadingPoint {
                position: h.position,
                normal,
                view: to_cam,
            },
            target: Vec3::from_array(view.rgb[p as usize]),
            saturated: view.saturated[p as usize],
            kind,
            view: v,
            pixel: p,
        });
    }
    let sdf_normal: Vec<bool> = pixels
        .iter()
        .zip(&from_map)
        .map(|(p, &m)| !m && matches!(p.kind, PixelKind::Surface { .. }))
        .collect();
    let radius = smoothing_radius(views, c2) * scale;
    if radius > 0.0 && sdf_normal.contains(&true) {
        progress("smoothing the SDF's shading normals");
        // The baked surface's field, which the renderers shade with too; unbaked, one of the
        // pixels' own points.
        let own;
        let field = match smoothed {
            Some(f) => f,
            None => {
                let (points, normals): (Vec<Vec3>, Vec<Vec3>) = pixels
                    .iter()
                    .zip(&sdf_normal)
                    .filter(|(_, &s)| s)
                    .map(|(p, _)| (p.point.position, p.point.normal))
                    .unzip();
                own = SmoothedNormals::new(&points, normals, radius);
                &own
            }
        };
        let idx: Vec<usize> = (0..pixels.len()).filter(|&i| sdf_normal[i]).collect();
        let pick = |f: fn(&ShadingPoint) -> Vec3| idx.iter().map(|&i| f(&pixels[i].point)).collect::<Vec<Vec3>>();
        let normals = field.at_points(&pick(|p| p.position), &pick(|p| p.normal), Some(&pick(|p| p.view)));
        for (&i, n) in idx.iter().zip(normals) {
            pixels[i].point.normal = n;
        }
    }
    if given_normals > 0 {
        progress(&format!(
            "shading normals of {given_normals} pixels from the dataset's maps (mean {:.1}° from the SDF's)",
            (normal_angle / given_normals as f64).to_degrees()
        ));
    }
    pixels
}

/// The incident radiance of every surface pixel, traced once (in blocks: bounded memory) with
/// the samples each had at iteration `resume_at`: the cache (samples kept, or their specular
/// sums baked), each pixel's own diffuse sums, and the index in `pixels` of each surface pixel
/// (cache order).
pub(super) fn trace_cache(
    frozen: &FrozenScene<'_>,
    pixels: &[CachedPixel],
    c2: &Stage2Config,
    seed: u64,
    resume_at: u64,
    progress: &dyn Fn(&str),
) -> (ShadingCache, Vec<DiffuseSums>, Vec<u32>) {
    let surf: Vec<(usize, ShadingPoint)> = pixels
        .iter()
        .enumerate()
        .filter(|(_, p)| matches!(p.kind, PixelKind::Surface { .. }))
        .map(|(i, p)| (i, p.point))
        .collect();
    let emitters = frozen.emitters;
    let scale = frozen.scene.normalization.scale as f32;
    let m = c2.cache_samples;
    let mut cache = ShadingCache {
        per_pixel: m,
        bake: c2.specular_bake.then(|| SpecularBake::new(emitters.len())),
        ..Default::default()
    };
    let mut own = Vec::with_capacity(surf.len());
    let mixture = super::cache_mixture(emitters, c2.emitter_sampling);
    // Salt of each surface pixel's samples: 1 initially, it + 2 after a refresh at iteration it.
    let mut salt = vec![1u64; surf.len()];
    for it in 0..resume_at {
        for j in refresh_selection(seed, it, surf.len(), c2.refresh_pixels) {
            salt[j as usize] = it + 2;
        }
    }
    const BLOCK: usize = 8192;
    for (b, block) in surf.chunks(BLOCK).enumerate() {
        progress(&format!(
            "tracing incident radiance: {} / {} pixels × {m} samples",
            b * BLOCK,
            surf.len()
        ));
        let pts: Vec<ShadingPoint> = block.iter().map(|(_, p)| *p).collect();
        let mut rngs: Vec<Pcg32> = block
            .iter()
            .enumerate()
            .map(|(j, (i, _))| pixel_rng(seed, *i as u64, salt[b * BLOCK + j]))
            .collect();
        let samples = trace_incident(frozen, &pts, m, scale, &|_| mixture, &mut rngs);
        own.par_extend(samples.par_chunks(m).map(|s| DiffuseSums::of(s, emitters.len())));
        match &mut cache.bake {
            // Baked, the samples are dropped block by block: memory does not grow with m.
            Some(bake) => {
                let nv: Vec<f32> = pts.iter().map(|p| p.normal.dot(p.view)).collect();
                bake.extend(&nv, &samples, m);
            }
            None => cache.samples.extend(samples),
        }
    }
    let surface = surf.iter().map(|(i, _)| *i as u32).collect();
    (cache, own, surface)
}

/// The mean surface target: L2's scale (1 without surface pixels).
pub(super) fn mean_surface_target(pixels: &[CachedPixel]) -> f32 {
    let (sum, n) = pixels
        .iter()
        .filter(|p| matches!(p.kind, PixelKind::Surface { .. }))
        .fold((0.0f64, 0usize), |(s, n), p| {
            (s + p.target.element_sum() as f64 / 3.0, n + 1)
        });
    if sum > 0.0 {
        (sum / n as f64) as f32
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stage2::PixelKind;
    use i2sdf_model::emitters::Emitter;

    /// Three pixels of view 0, each hit at (x, 0, 1) facing the camera, with its label.
    fn three_pixel_cast(hits: [(f32, Option<u32>); 3]) -> Cast {
        let hit = |(x, emitter): (f32, Option<u32>)| LabelledHit {
            t: 1.0,
            position: Vec3::new(x, 0.0, 1.0),
            normal: Vec3::new(0.0, 0.0, -1.0),
            emitter,
        };
        Cast {
            order: vec![(0, 0), (0, 1), (0, 2)],
            rays: vec![Ray::new(Vec3::ZERO, Vec3::Z, 0.0, 10.0); 3],
            hits: hits.map(|h| Some(hit(h))).to_vec(),
            hit_idx: vec![0, 1, 2],
            points: vec![Vec3::ZERO; 3],
            emitter_prob: vec![0.0; 3],
        }
    }

    /// A surface pixel the dataset's material mask marks non-GGX is not fitted; an emitter pixel
    /// is, whatever the mask says (emission is not a material).
    #[test]
    fn material_masked_surface_pixels_are_dropped() {
        let cast = three_pixel_cast([(0.0, None), (0.1, None), (0.2, None)]);
        let emitters = EmitterTable::new(
            vec![Emitter {
                centre: [0.2, 0.0, 1.0],
                extent: [0.1; 3],
                radius: 0.1,
                points: 1,
                sphere: None,
                bounds: None,
                panel: None,
            }],
            &[[1.0; 3]],
        );
        let view = TargetView {
            camera: i2sdf_data::fixture::cameras(&Default::default())[0].clone(),
            rgb: vec![[0.5; 3]; 3],
            saturated: vec![0; 3],
            emitter_mask: Some(vec![false, false, true]),
            material_mask: Some(vec![true, false, false]),
            normal: None,
        };
        let c2 = Stage2Config::default();
        let pixels = label_pixels(&cast, &[], &[view], &c2, &emitters, 0.05, 1.0, None, &|_| {});
        let kinds: Vec<(u32, PixelKind)> = pixels.iter().map(|p| (p.pixel, p.kind)).collect();
        assert_eq!(
            kinds,
            [(0, PixelKind::Surface { index: 0 }), (2, PixelKind::Emitter(0))]
        );
    }

    /// A cached ray that ends on a bulb's sphere is that bulb's emitter pixel where the mask
    /// marks it, and is dropped where it does not (the sphere's rim, neither light nor surface);
    /// the other pixels are labelled as before.
    #[test]
    fn pixels_on_a_bulb_sphere_are_its_light_or_dropped() {
        let cast = three_pixel_cast([(0.0, Some(0)), (0.1, Some(0)), (3.0, None)]);
        let emitters = EmitterTable::new(
            vec![Emitter {
                centre: [0.0, 0.0, 1.1],
                extent: [0.2; 3],
                radius: 0.1,
                points: 1,
                sphere: Some([0.0, 0.0, 1.1, 0.1]),
                bounds: None,
                panel: None,
            }],
            &[[1.0; 3]],
        );
        let view = TargetView {
            camera: i2sdf_data::fixture::cameras(&Default::default())[0].clone(),
            rgb: vec![[0.5; 3]; 3],
            saturated: vec![0; 3],
            emitter_mask: Some(vec![true, false, false]),
            material_mask: None,
            normal: None,
        };
        let c2 = Stage2Config::default();
        let pixels = label_pixels(
            &cast,
            &[true, true, false],
            &[view],
            &c2,
            &emitters,
            0.05,
            1.0,
            None,
            &|_| {},
        );
        let kinds: Vec<(u32, PixelKind)> = pixels.iter().map(|p| (p.pixel, p.kind)).collect();
        assert_eq!(
            kinds,
            [(0, PixelKind::Emitter(0)), (2, PixelKind::Surface { index: 0 })]
        );
    }
}
