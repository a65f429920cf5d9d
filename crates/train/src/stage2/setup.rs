//! The steps of building stage 2's cache ([`super::Stage2::new`]): the training pixels cast
//! into the frozen SDF, the box the surface is baked over, the emitters clustered from the
//! points F_e marks, each pixel's kind and shading point, and the incident radiance traced once.

use super::{normalized, pixel_rng, refresh_selection, CachedPixel, PixelKind};
use crate::config::Stage2Config;
use crate::stage2::emitter_clusters::{cluster_emitters, fit_sphere, ClusterSettings, MarkedPoints, SPHERE_MAX_RADIUS};
use crate::stage2::emitter_triangulation::{disc_angle, is_compact, mask_radius, triangulate, MaskPiece, Triangulated};
use crate::stage2::shading::{trace_incident, DiffuseSums, ShadingPoint};
use crate::stage2::surface_cache::{ShadingCache, SpecularBake};
use crate::stage2::targets::TargetView;
use glam::{DVec3, Vec3};
use i2sdf_data::camera::RayGenerator;
use i2sdf_data::{DataError, Radiometry};
use i2sdf_model::emitters::{Emitter, EmitterTable, BULB_CLEARANCE};
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

/// Per point, how many training views see it and how many of those mark it in their emitter
/// mask: a view sees a point whose projection lands in its image where a cast pixel within one
/// pixel of it hit the surface at the point's distance (within 3 %). A light is marked by every
/// view that sees it; a highlight only by those at its mirror angle.
pub(super) fn seen_by_views(cast: &Cast, views: &[TargetView], points: &[Vec3]) -> Vec<(u32, u32)> {
    // Each view's cast pixels: distance of the hit from the camera (NaN: not cast or no hit).
    let mut dist: Vec<Vec<f32>> = views.iter().map(|v| vec![f32::NAN; v.rgb.len()]).collect();
    for (j, &o) in cast.hit_idx.iter().enumerate() {
        let (v, p) = cast.order[o];
        let c = views[v as usize].camera.center().as_vec3();
        dist[v as usize][p as usize] = (cast.points[j] - c).length();
    }
    points
        .iter()
        .map(|x| {
            let (mut seen, mut masked) = (0u32, 0u32);
            for (v, view) in views.iter().enumerate() {
                let cam = &view.camera;
                let Some((u, vv, _)) = cam.project(x.as_dvec3()) else {
                    continue;
                };
                if !(u >= 0.0 && vv >= 0.0 && u < cam.width as f64 && vv < cam.height as f64) {
                    continue;
                }
                let (cx, cy) = (u as usize, vv as usize);
                let r = (*x - cam.center().as_vec3()).length();
                let visible = (cy.saturating_sub(1)..(cy + 2).min(cam.height)).any(|y| {
                    (cx.saturating_sub(1)..(cx + 2).min(cam.width))
                        .any(|xx| (dist[v][y * cam.width + xx] - r).abs() <= 0.03 * r)
                });
                if visible {
                    seen += 1;
                    let mask = view.emitter_mask.as_ref().expect("masks");
                    masked += mask[cy * cam.width + cx] as u32;
                }
            }
            (seen, masked)
        })
        .collect()
}

/// K-means on the surface points F_e marks (normalized frame), K chosen unless
/// `stage2.emitters` sets it; each L\[k\] starts at what the images show of it, the mean target
/// of its pixels (a lower bound where they are saturated). Without emitter masks F_e was never
/// trained: no emitters (every traced ray takes F_c's radiance). Returns the table and the K
/// chosen before small clusters were dropped.
pub(super) fn cluster_new_emitters(
    scene: &NeuralScene,
    views: &[TargetView],
    radiometry: Radiometry,
    cast: &Cast,
    c2: &Stage2Config,
    rng: &mut Pcg64,
    progress: &dyn Fn(&str),
) -> (EmitterTable, usize) {
    let has_masks = views.iter().all(|v| v.emitter_mask.is_some());
    let marked: Vec<usize> = (0..cast.hit_idx.len())
        .filter(|&j| cast.emitter_prob[j] > c2.emitter_threshold)
        .collect();
    let mut points = MarkedPoints::default();
    if has_masks {
        for &j in &marked {
            let (v, p) = cast.order[cast.hit_idx[j]];
            let mask = views[v as usize].emitter_mask.as_ref().expect("has_masks");
            points
                .positions
                .push(normalized(scene, cast.points[j]).map(|x| x as f64));
            points.views.push(v);
            points.in_mask.push(mask[p as usize]);
        }
    }
    if has_masks {
        let world: Vec<Vec3> = marked.iter().map(|&j| cast.points[j]).collect();
        points.seen = seen_by_views(cast, views, &world);
    }
    progress(&format!("clustering {} emitter points", points.positions.len()));
    let settings = ClusterSettings {
        k: (c2.emitters > 0).then_some(c2.emitters),
        max_k: c2.max_emitters,
        link: c2.emitter_link as f64,
        min_fraction: c2.emitter_min_fraction as f64,
        min_views: c2.emitter_min_views,
        mask_agreement: c2.emitter_mask_agreement as f64,
        restarts: 4,
        iterations: 100,
    };
    let found = cluster_emitters(&points, &settings, rng);
    let clusters = found.clusters;
    let k = found.k;
    let norm = &scene.normalization;
    let to_world = |c: [f64; 3]| norm.to_world(DVec3::from_array(c)).to_array();
    for piece in &found.left_out {
        let w = to_world(piece.centre);
        progress(&format!(
            "not an emitter: the piece at ({:.2}, {:.2}, {:.2}) m, {}",
            w[0],
            w[1],
            w[2],
            piece.describe(&settings)
        ));
    }
    let s = norm.scale;
    let list: Vec<Emitter> = clusters
        .iter()
        .map(|c| Emitter {
            centre: to_world(c.centre),
            extent: c.extent.map(|e| e * s),
            radius: c.radius * s,
            points: c.members.len(),
            sphere: c2
                .fit_bulbs
                .then(|| fit_sphere(&c.members.iter().map(|&m| points.positions[m]).collect::<Vec<_>>()))
                .flatten()
                .map(|f| {
                    let w = to_world([f[0], f[1], f[2]]);
                    [w[0], w[1], w[2], f[3] * s]
                }),
            bounds: c.members.first().map(|&m0| {
                let first = to_world(points.positions[m0]);
                c.members.iter().fold([first, first], |[lo, hi], &m| {
                    let w = to_world(points.positions[m]);
                    [
                        std::array::from_fn(|a| lo[a].min(w[a])),
                        std::array::from_fn(|a| hi[a].max(w[a])),
                    ]
                })
            }),
        })
        .collect();
    for (k, e) in list.iter().enumerate() {
        if let Some([x, y, z, r]) = e.sphere {
            progress(&format!(
                "emitter {k}: its points lie on a sphere of radius {r:.3} m about ({x:.2}, {y:.2}, {z:.2}) m"
            ));
        }
    }
    let mut sum = vec![[0.0f64; 3]; clusters.len()];
    for (ci, c) in clusters.iter().enumerate() {
        for &m in &c.members {
            let (v, p) = cast.order[cast.hit_idx[marked[m]]];
            let t = views[v as usize].rgb[p as usize];
            for a in 0..3 {
                sum[ci][a] += t[a] as f64 / c.members.len() as f64;
            }
        }
    }
    let mut list = list;
    // The masks' pieces, for sizing the bulbs and for the lights no surface carries.
    let pieces = match has_masks && c2.fit_bulbs && (c2.size_bulbs_by_masks || c2.triangulate_emitters) {
        true => compact_mask_pieces(views),
        false => Vec::new(),
    };
    if has_masks && c2.size_bulbs_by_masks {
        size_bulbs_by_masks(scene, &pieces, &mut list, radiometry, c2, progress);
    }
    let mut init: Vec<[f32; 3]> = sum.iter().map(|s| s.map(|v| (v as f32).max(1e-3))).collect();
    if has_masks && c2.triangulate_emitters && c2.fit_bulbs {
        let kept = EmitterTable::new(list.clone(), &init);
        let small = SPHERE_MAX_RADIUS * s;
        for (e, l) in triangulate_missed_lights(scene, views, &pieces, &kept, small, radiometry, c2) {
            let [x, y, z, r] = e.sphere.expect("a triangulated light is a sphere");
            let centre = DVec3::new(x, y, z);
            let sphere = format!("a sphere of radius {r:.3} m about ({x:.2}, {y:.2}, {z:.2}) m");
            // A small emitter whose points fit no sphere (a rough bulb) takes the one its masks give.
            match kept
                .index(centre, r)
                .filter(|&k| list[k].sphere.is_none() && list[k].radius <= small)
            {
                Some(k) => {
                    progress(&format!(
                        "emitter {k}: its points fit no sphere; its {} mask pixels give {sphere}",
                        e.points
                    ));
                    list[k].sphere = e.sphere;
                    list[k].radius = list[k].radius.max(r);
                }
                None => {
                    progress(&format!(
                        "emitter {}: no surface carries it; triangulated from {} mask pixels: {sphere}",
                        list.len(),
                        e.points
                    ));
                    list.push(e);
                    init.push(l);
                }
            }
        }
    }
    (EmitterTable::new(list, &init), k)
}

/// The compact pieces of every training view's emitter mask ([`is_compact`]), each as the cone
/// of rays of its disc ([`disc_angle`]: clipped where most of its pixels are saturated), and
/// whether it touches its image's border (cut by the frame: smaller than the light's image).
fn compact_mask_pieces(views: &[TargetView]) -> Vec<(MaskPiece, bool)> {
    let mut pieces = Vec::new();
    for (v, view) in views.iter().enumerate() {
        let Some(mask) = &view.emitter_mask else { continue };
        let cam = &view.camera;
        let g = cam.ray_generator();
        for piece in i2sdf_data::emitter_detect::components(mask, cam.width, cam.height) {
            let pixels: Vec<u32> = piece.iter().map(|&p| p as u32).collect();
            if !is_compact(&pixels, cam.width) {
                continue;
            }
            let n = piece.len() as f32;
            let (u, w) = piece.iter().fold((0.0f32, 0.0f32), |(u, w), &p| {
                (u + (p % cam.width) as f32 + 0.5, w + (p / cam.width) as f32 + 0.5)
            });
            let on_border = piece.iter().any(|&p| {
                let (x, y) = (p % cam.width, p / cam.width);
                x == 0 || y == 0 || x + 1 == cam.width || y + 1 == cam.height
            });
            let clipped = 2 * piece.iter().filter(|&&p| view.saturated[p] != 0).count() >= piece.len();
            let solid_angle: f64 = piece
                .iter()
                .map(|&p| pixel_solid_angle(&g, p % cam.width, p / cam.width))
                .sum();
            pieces.push((
                MaskPiece {
                    view: v,
                    origin: cam.center(),
                    dir: g.dir(u / n, w / n).as_dvec3(),
                    angle: disc_angle(piece.len(), solid_angle, clipped),
                    pixels,
                },
                on_border,
            ));
        }
    }
    pieces
}

/// The solid angle (steradians) of pixel (x, y) of a camera: the parallelogram of its rays'
/// directions across it, which holds for any lens model the generator undistorts (pinhole:
/// cos³θ / (fx·fy)).
fn pixel_solid_angle(g: &RayGenerator, x: usize, y: usize) -> f64 {
    let d = |u: f32, v: f32| g.dir(x as f32 + u, y as f32 + v).as_dvec3();
    (d(1.0, 0.5) - d(0.0, 0.5)).cross(d(0.5, 1.0) - d(0.5, 0.0)).length()
}

/// Each bulb whose sphere was fitted to its surface points takes the radius its masks give
/// ([`mask_radius`] over `pieces`, [`compact_mask_pieces`]) where pieces of at least `stage2.emitter_min_views` views, whole (not cut by
/// the frame) and unoccluded (their centroid ray meets no surface before the bulb's clearance
/// ball), pass through it; the centre stays the fit's.
pub(super) fn size_bulbs_by_masks(
    scene: &NeuralScene,
    pieces: &[(MaskPiece, bool)],
    list: &mut [Emitter],
    radiometry: Radiometry,
    c2: &Stage2Config,
    progress: &dyn Fn(&str),
) {
    if !list.iter().any(|e| e.sphere.is_some()) {
        return;
    }
    let pieces: Vec<&MaskPiece> = pieces.iter().filter(|(_, border)| !border).map(|(p, _)| p).collect();
    let rays: Vec<Ray> = pieces
        .iter()
        .map(|p| Ray::new(p.origin.as_vec3(), p.dir.as_vec3(), 0.0, f32::INFINITY))
        .collect();
    let none = EmitterTable::new(Vec::new(), &[]);
    let mut hits = vec![None; rays.len()];
    FrozenScene::new(scene, &none, radiometry).cast(&rays, &mut hits);
    for (k, e) in list.iter_mut().enumerate() {
        let Some([x, y, z, r]) = e.sphere else { continue };
        let c = DVec3::new(x, y, z);
        let whole: Vec<MaskPiece> = pieces
            .iter()
            .zip(&hits)
            .filter(|(p, h)| {
                let depth = (c - p.origin).dot(p.dir);
                h.map_or(true, |h| h.t as f64 >= depth - BULB_CLEARANCE as f64 * r)
            })
            .map(|(&p, _)| p.clone())
            .collect();
        if let Some(from_masks) = mask_radius(&whole, c, r, c2.emitter_min_views) {
            progress(&format!(
                "emitter {k}: its masks give its sphere a radius of {from_masks:.3} m (its points {r:.3} m)"
            ));
            e.sphere = Some([x, y, z, from_masks]);
        }
    }
}

/// A mask piece counts as explained when at least this share of its pixels' hits lie on a
/// clustered emitter.
const EXPLAINED_SHARE: f64 = 0.5;

/// The lights stage 1 built no surface for, triangulated from the pieces of the training
/// views' emitter masks (`all_pieces`, [`compact_mask_pieces`]) that the clustered emitters
/// (`kept`) do not explain
/// ([`emitter_triangulation`](super::emitter_triangulation)), each as a bulb (its sphere set)
/// with its initial L (the mean target of its pieces' pixels). An emitter no larger than
/// `small` (world) whose points fit no sphere (a rough bulb: the second room's capture) explains
/// no piece, so its pieces are triangulated too; the caller gives it the sphere they agree on.
/// A proposal is kept when
/// - the centroid rays of at least `stage2.emitter_mask_agreement` of its pieces meet no
///   surface before it (a light's mirror image in a glossy floor lies behind the floor), and
/// - of the training views that see its centre unoccluded, at least that share mark it in
///   their masks (within a pixel).
fn triangulate_missed_lights(
    scene: &NeuralScene,
    views: &[TargetView],
    all_pieces: &[(MaskPiece, bool)],
    kept: &EmitterTable,
    small: f64,
    radiometry: Radiometry,
    c2: &Stage2Config,
) -> Vec<(Emitter, [f32; 3])> {
    let none = EmitterTable::new(Vec::new(), &[]);
    let frozen = FrozenScene::new(scene, &none, radiometry);
    let cast_all = |rays: &[Ray]| {
        let mut hits = vec![None; rays.len()];
        frozen.cast(rays, &mut hits);
        hits
    };
    // A small emitter whose points fit no sphere explains nothing: its pieces are triangulated.
    let rough_small = |e: &Emitter| e.sphere.is_none() && e.radius <= small;
    // 1. Every mask piece, and which of them no clustered emitter explains.
    let mut pieces = Vec::new();
    for (piece, _) in all_pieces {
        let cam = &views[piece.view].camera;
        let g = cam.ray_generator();
        let pixel_ray = |p: u32| {
            let (x, y) = (
                (p as usize % cam.width) as f32 + 0.5,
                (p as usize / cam.width) as f32 + 0.5,
            );
            Ray::new(g.origin, g.dir(x, y), 0.0, f32::INFINITY)
        };
        let hits = cast_all(&piece.pixels.iter().map(|&p| pixel_ray(p)).collect::<Vec<_>>());
        let explained = hits
            .iter()
            .filter(|h| {
                h.is_some_and(|h| {
                    kept.index(h.position.as_dvec3(), frozen.index_margin)
                        .is_some_and(|k| !rough_small(&kept.emitters[k]))
                })
            })
            .count();
        if (explained as f64) < EXPLAINED_SHARE * piece.pixels.len() as f64 {
            pieces.push(piece.clone());
        }
    }
    if pieces.is_empty() {
        return Vec::new();
    }
    // Where each piece's centroid ray first meets the surface.
    let centroid_rays: Vec<Ray> = pieces
        .iter()
        .map(|p| Ray::new(p.origin.as_vec3(), p.dir.as_vec3(), 0.0, f32::INFINITY))
        .collect();
    let surface_t: Vec<f64> = cast_all(&centroid_rays)
        .iter()
        .map(|h| h.map_or(f64::INFINITY, |h| h.t as f64))
        .collect();
    // 2. Triangulated, each proposal tested against the surface and the other views' masks.
    let agreement = c2.emitter_mask_agreement as f64;
    let clearance = BULB_CLEARANCE as f64;
    let mut accept = |light: &Triangulated| {
        let (c, r) = (light.centre, light.radius);
        // A new light's centre is in free space; a rough bulb's (a small emitter stage 1 built)
        // lies inside its surface. The highlight of a light in a glossy ball triangulates
        // consistently too, to its virtual image half the ball's radius inside it (the second
        // room's chandelier balls).
        let rough_bulb = kept.index(c, r).is_some_and(|k| rough_small(&kept.emitters[k]));
        if !rough_bulb && frozen.sdf_gradient(&[c.as_vec3()])[0].0 < 0.0 {
            return false;
        }
        let in_front = light
            .pieces
            .iter()
            .filter(|&&i| surface_t[i] >= (c - pieces[i].origin).dot(pieces[i].dir) - clearance * r)
            .count();
        if (in_front as f64) < agreement * light.pieces.len() as f64 {
            return false;
        }
        let seen: Vec<(usize, usize, Ray, f64)> = (views.iter().enumerate())
            .filter_map(|(v, view)| {
                let cam = &view.camera;
                let (u, w, _) = cam.project(c)?;
                let (x, y) = (u.floor(), w.floor());
                if x < 0.0 || y < 0.0 || x >= cam.width as f64 || y >= cam.height as f64 {
                    return None;
                }
                let (x, y) = (x as usize, y as usize);
                let o = cam.center();
                let dir = (c - o).normalize().as_vec3();
                Some((
                    v,
                    y * cam.width + x,
                    Ray::new(o.as_vec3(), dir, 0.0, f32::INFINITY),
                    (c - o).length(),
                ))
            })
            .collect();
        let hits = cast_all(&seen.iter().map(|s| s.2).collect::<Vec<_>>());
        let (mut agree, mut seeing) = (0usize, 0usize);
        for ((v, p, _, dist), h) in seen.iter().zip(&hits) {
            if h.is_some_and(|h| (h.t as f64) < dist - clearance * r) {
                continue; // occluded in this view
            }
            let view = &views[*v];
            let Some(mask) = &view.emitter_mask else { continue };
            let w = view.camera.width;
            let (x, y) = (p % w, p / w);
            let marked = (y.saturating_sub(1)..=(y + 1).min(view.camera.height - 1))
                .any(|j| (x.saturating_sub(1)..=(x + 1).min(w - 1)).any(|i| mask[j * w + i]));
            seeing += 1;
            agree += marked as usize;
        }
        seeing >= c2.emitter_min_views && agree as f64 >= agreement * seeing as f64
    };
    let found = triangulate(&pieces, c2.emitter_min_views, &mut accept);
    found
        .iter()
        .map(|light| {
            let (c, r) = (light.centre, light.radius);
            let (mut sum, mut n) = ([0.0f64; 3], 0usize);
            for &i in &light.pieces {
                for &p in &pieces[i].pixels {
                    let t = views[pieces[i].view].rgb[p as usize];
                    for a in 0..3 {
                        sum[a] += t[a] as f64;
                    }
                    n += 1;
                }
            }
            let emitter = Emitter {
                centre: c.to_array(),
                extent: [2.0 * r; 3],
                radius: r,
                points: n,
                sphere: Some([c.x, c.y, c.z, r]),
                bounds: Some([(c - r).to_array(), (c + r).to_array()]),
            };
            (emitter, sum.map(|s| ((s / n.max(1) as f64) as f32).max(1e-3)))
        })
        .collect()
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

    /// A point is seen by a view where a cast pixel beside its projection hit the surface at
    /// its distance, and counted as marked where that view's mask marks its pixel; a point
    /// behind the surface the view hit there, behind the camera, or where the view cast no pixel
    /// is not seen.
    #[test]
    fn views_see_a_point_where_the_cast_hit_it() {
        let camera = i2sdf_data::fixture::cameras(&Default::default())[0].clone();
        let (w, h) = (camera.width, camera.height);
        let c = camera.center().as_vec3();
        // Every pixel of the view cast, hitting a surface at distance 2 from the camera.
        let order: Vec<(u32, u32)> = (0..(w * h) as u32).map(|p| (0, p)).collect();
        let dirs: Vec<Vec3> = (0..w * h)
            .map(|p| {
                let x = camera
                    .backproject_at((p % w) as f64 + 0.5, (p / w) as f64 + 0.5, 1.0)
                    .as_vec3();
                (x - c).normalize()
            })
            .collect();
        let cast = Cast {
            rays: Vec::new(),
            hits: Vec::new(),
            hit_idx: (0..w * h).collect(),
            points: dirs.iter().map(|d| c + 2.0 * *d).collect(),
            emitter_prob: vec![0.0; w * h],
            order,
        };
        let mut mask = vec![false; w * h];
        let (mx, my) = (w / 2, h / 2);
        mask[my * w + mx] = true;
        let view = |mask: Vec<bool>| TargetView {
            camera: camera.clone(),
            rgb: vec![[0.5; 3]; w * h],
            saturated: vec![0; w * h],
            emitter_mask: Some(mask),
            material_mask: None,
            normal: None,
        };
        let on = |px: usize, r: f32| c + r * dirs[px];
        let points = [
            on(my * w + mx, 2.0),        // on the surface, in the mask
            on(my * w + mx + 3, 2.0),    // on the surface, not in the mask
            on(my * w + mx, 2.5),        // behind the surface
            c - 2.0 * dirs[my * w + mx], // behind the camera
        ];
        // View 1 (the same camera) cast no pixel: it cannot tell, and does not count.
        let seen = seen_by_views(&cast, &[view(mask.clone()), view(mask)], &points);
        assert_eq!(seen, [(1, 1), (1, 0), (0, 0), (0, 0)]);
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

    /// A pixel's solid angle is cos³θ / (fx·fy) of a pinhole camera, and the whole frame's is
    /// that of its rectangle of view.
    #[test]
    fn pixels_subtend_their_solid_angle() {
        let (w, h, f) = (40usize, 30usize, 25.0f64);
        let cam = i2sdf_data::Camera::from_opengl_c2w(w, h, f, f, 20.0, 15.0, glam::DMat4::IDENTITY);
        let g = cam.ray_generator();
        for (x, y) in [(20usize, 15usize), (0, 0), (39, 10)] {
            let d = cam.pixel_center_dir_cam(x, y).normalize();
            let cos = d.z.abs();
            let expected = cos * cos * cos / (f * f);
            let got = pixel_solid_angle(&g, x, y);
            assert!(
                (got / expected - 1.0).abs() < 2e-3,
                "({x}, {y}): {got} against {expected}"
            );
        }
        // The frame: 4·asin(sin a · sin b) for half-angles a, b of a rectangle.
        let (a, b) = ((20.0 / f).atan(), (15.0 / f).atan());
        let frame = 4.0 * (a.sin() * b.sin()).asin();
        let sum: f64 = (0..w * h).map(|p| pixel_solid_angle(&g, p % w, p / w)).sum();
        assert!((sum / frame - 1.0).abs() < 1e-3, "{sum} against {frame}");
    }
}
