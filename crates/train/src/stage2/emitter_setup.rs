//! The emitters of a fresh stage 2, from the training pixels cast into the frozen SDF
//! ([`super::Stage2::new`]): the points F_e marks, with how many of the views that see them mark
//! them in their masks, clustered into pieces ([`super::emitter_clusters`]); bulbs sized by
//! their masks; and the lights no surface carries, triangulated from the mask pieces no emitter
//! explains ([`super::emitter_triangulation`]).

use super::normalized;
use super::setup::Cast;
use crate::config::Stage2Config;
use crate::stage2::emitter_clusters::{cluster_emitters, fit_sphere, ClusterSettings, MarkedPoints, SPHERE_MAX_RADIUS};
use crate::stage2::emitter_triangulation::{disc_angle, is_compact, mask_radius, triangulate, MaskPiece, Triangulated};
use crate::stage2::targets::TargetView;
use glam::{DVec3, Vec3};
use i2sdf_data::camera::RayGenerator;
use i2sdf_data::Radiometry;
use i2sdf_model::emitter_panel::{Panel, Spread, PANEL_MAX_THICKNESS};
use i2sdf_model::emitters::{Emitter, EmitterTable, BULB_CLEARANCE, UNSEEN_BOX_MARGIN};
use i2sdf_model::intrinsic::{FrozenScene, INDEX_MARGIN};
use i2sdf_model::NeuralScene;
use i2sdf_render::Ray;
use rand_pcg::Pcg64;

/// Per point, how many training views see it and how many of those mark it in their emitter
/// mask: a view sees a point whose projection lands in its image where a cast pixel within one
/// pixel of it hit the surface at the point's distance (within 3 %). A light is marked by every
/// view that sees it; a highlight only by those at its mirror angle.
pub(super) fn seen_by_views(cast: &Cast, views: &[TargetView], points: &[Vec3]) -> Vec<(u32, u32)> {
    // Each view's cast pixels: distance of the hit from the camera (NaN: not cast or no hit).
    let centres: Vec<Vec3> = views.iter().map(|v| v.camera.center().as_vec3()).collect();
    let mut dist: Vec<Vec<f32>> = views.iter().map(|v| vec![f32::NAN; v.rgb.len()]).collect();
    for (j, &o) in cast.hit_idx.iter().enumerate() {
        let (v, p) = cast.order[o];
        dist[v as usize][p as usize] = (cast.points[j] - centres[v as usize]).length();
    }
    points
        .iter()
        .map(|x| {
            let (mut seen, mut masked) = (0u32, 0u32);
            for (v, view) in views.iter().enumerate() {
                let (cam, Some(mask)) = (&view.camera, &view.emitter_mask) else {
                    continue;
                };
                let Some((u, vv, _)) = cam.project(x.as_dvec3()) else {
                    continue;
                };
                if !(u >= 0.0 && vv >= 0.0 && u < cam.width as f64 && vv < cam.height as f64) {
                    continue;
                }
                let (cx, cy) = (u as usize, vv as usize);
                let r = (*x - centres[v]).length();
                let visible = (cy.saturating_sub(1)..(cy + 2).min(cam.height)).any(|y| {
                    (cx.saturating_sub(1)..(cx + 2).min(cam.width))
                        .any(|xx| (dist[v][y * cam.width + xx] - r).abs() <= 0.03 * r)
                });
                if visible {
                    seen += 1;
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
        .map(|c| {
            // The cluster's points in world units, summarized once: their box and, for a
            // panel, their spread.
            let world: Vec<[f64; 3]> = c.members.iter().map(|&m| to_world(points.positions[m])).collect();
            let spread = Spread::of(&world);
            let mut e = Emitter {
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
                bounds: spread.map(|sp| [sp.lo, sp.hi]),
                panel: None,
            };
            // A flat cluster that is no bulb: the rectangle of its points, facing the room's
            // centre, its slab widened by the unseen-surface margin (`emitter_panel`).
            if c2.fit_panels && e.bulb().is_none() {
                let margin = UNSEEN_BOX_MARGIN * INDEX_MARGIN * s;
                e.panel = spread.and_then(|sp| Panel::of_spread(&sp, to_world([0.0; 3]), margin));
                if let (None, Some(spread)) = (e.panel, spread) {
                    let (axis, thickness) = spread.flatness();
                    let axis = ["x", "y", "z"][axis];
                    progress(&format!(
                        "no panel: the cluster at ({:.2}, {:.2}, {:.2}) m is {thickness:.2} as thick along {axis} as across (at most {PANEL_MAX_THICKNESS})",
                        e.centre[0], e.centre[1], e.centre[2]
                    ));
                }
            }
            e
        })
        .collect();
    for (k, e) in list.iter().enumerate() {
        if let Some([x, y, z, r]) = e.sphere {
            progress(&format!(
                "emitter {k}: its points lie on a sphere of radius {r:.3} m about ({x:.2}, {y:.2}, {z:.2}) m"
            ));
        }
        if let Some(p) = e.panel {
            let axis = ["x", "y", "z"][p.axis];
            progress(&format!(
                "emitter {k}: a panel of {:.2} × {:.2} m at {axis} = {:.3} m (its slab ±{:.1} cm), emitting towards {}{axis}",
                p.hi[0] - p.lo[0],
                p.hi[1] - p.lo[1],
                p.offset,
                100.0 * p.depth,
                if p.facing > 0.0 { "+" } else { "−" }
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
                panel: None,
            };
            (emitter, sum.map(|s| ((s / n.max(1) as f64) as f32).max(1e-3)))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

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
