//! Small emitters that stage 1 left without a surface, found from the emitter masks alone.
//!
//! Stage 2's emitters are the surface points F_e marks ([`super::emitter_clusters`]), so a light
//! needs a surface. A bulb whose pixels are clipped and which the depth sensor does not measure
//! may get none: on the default room's phone capture (a 20 cm bulb, 2×2 samples of a 40×30
//! depth grid, every one on its silhouette and dropped as low-confidence) the rays of its pixels
//! went through to the corner walls, F_e marked pieces of those walls that moved from view to
//! view, and stage 2 dropped them as reflections: no bulb, and every relit set that uses it was
//! dark.
//!
//! The masks still see the light. In each view its mask is a small disc whose centroid ray
//! passes through the light's centre, so the mask pieces that no emitter explains (most of
//! their pixels hit no emitter's sphere) are triangulated: every pair of pieces from two views
//! proposes the point nearest both centroid rays; the proposal that the most views' pieces pass
//! within their own disc radius of wins, its centre is refined by least squares over those
//! rays and its radius is the median of their disc radii at its distance. Such a light becomes a
//! bulb (its `sphere`), which every renderer treats as the sphere it is
//! (`FrozenScene::cast`). A proposal is only kept when the caller's test accepts it (in
//! `setup`: the pieces' rays meet no surface before it, which rejects a light's mirror image
//! behind a glossy floor, and the views that see its centre mark it in their masks); its pieces
//! are set aside either way.

use glam::{DMat3, DVec3};

/// One connected piece of a view's emitter mask, as a cone of rays.
#[derive(Clone, Debug)]
pub struct MaskPiece {
    pub view: usize,
    /// The camera centre (world).
    pub origin: DVec3,
    /// Unit direction through the piece's centroid (world).
    pub dir: DVec3,
    /// Angular radius of the disc of the piece's area (radians).
    pub angle: f64,
    /// Its pixels (row-major indices in its view).
    pub pixels: Vec<u32>,
}

/// A light triangulated from mask pieces: centre and radius (world units), and the pieces
/// (indices into the input) that agree on it.
#[derive(Clone, Debug, PartialEq)]
pub struct Triangulated {
    pub centre: DVec3,
    pub radius: f64,
    pub pieces: Vec<usize>,
}

/// Two centroid rays closer than this sine of their angle are too nearly parallel to triangulate
/// (about 3°: the built-in rooms' cameras see a light from 10–60° apart).
const MIN_PAIR_SINE: f64 = 0.05;

/// How much farther than its disc radius a piece's ray may pass from a proposed centre: a
/// partly occluded or partly found mask shifts its centroid by up to a radius.
const INLIER_RADII: f64 = 1.0;

/// The disc radius (world) of `piece` at the depth of `c`, and the distance of `c` from its
/// centroid ray; None when `c` is behind its camera.
fn ray_fit(piece: &MaskPiece, c: DVec3) -> Option<(f64, f64)> {
    let v = c - piece.origin;
    let t = v.dot(piece.dir);
    (t > 0.0).then(|| (piece.angle * t, (v - t * piece.dir).length()))
}

/// The point nearest both rays (the midpoint of their common perpendicular) and the distance
/// between them there; None when nearly parallel or when the point is behind either camera.
fn nearest_point(a: &MaskPiece, b: &MaskPiece) -> Option<(DVec3, f64)> {
    let w = a.origin - b.origin;
    let (d1, d2) = (a.dir, b.dir);
    let cos = d1.dot(d2);
    let sin2 = 1.0 - cos * cos;
    if sin2 < MIN_PAIR_SINE * MIN_PAIR_SINE {
        return None;
    }
    let (p, q) = (d1.dot(w), d2.dot(w));
    let t1 = (cos * q - p) / sin2;
    let t2 = (q - cos * p) / sin2;
    if t1 <= 0.0 || t2 <= 0.0 {
        return None;
    }
    let (x1, x2) = (a.origin + t1 * d1, b.origin + t2 * d2);
    Some(((x1 + x2) * 0.5, (x1 - x2).length()))
}

/// The pieces (among `live`) whose rays pass within [`INLIER_RADII`] disc radii of `c`.
fn inliers(pieces: &[MaskPiece], live: &[usize], c: DVec3) -> Vec<usize> {
    live.iter()
        .copied()
        .filter(|&i| ray_fit(&pieces[i], c).is_some_and(|(r, d)| d <= INLIER_RADII * r.max(1e-9)))
        .collect()
}

fn distinct_views(pieces: &[MaskPiece], set: &[usize]) -> usize {
    let mut views: Vec<usize> = set.iter().map(|&i| pieces[i].view).collect();
    views.sort_unstable();
    views.dedup();
    views.len()
}

/// The point nearest all the rays of `set` in the least-squares sense (Σ of squared
/// perpendicular distances), and the median disc radius there. None when degenerate.
fn refine(pieces: &[MaskPiece], set: &[usize]) -> Option<(DVec3, f64)> {
    let (mut a, mut b) = (DMat3::ZERO, DVec3::ZERO);
    for &i in set {
        let d = pieces[i].dir;
        let p = DMat3::IDENTITY - DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += p;
        b += p * pieces[i].origin;
    }
    if a.determinant().abs() < 1e-9 {
        return None;
    }
    let c = a.inverse() * b;
    let mut radii: Vec<f64> = set
        .iter()
        .filter_map(|&i| ray_fit(&pieces[i], c).map(|(r, _)| r))
        .collect();
    if radii.len() != set.len() {
        return None;
    }
    radii.sort_by(f64::total_cmp);
    Some((c, radii[radii.len() / 2]))
}

/// The lights that the pieces agree on, best first: each from the pieces of at least `min_views`
/// views that pass within their disc radius of one point, and accepted by `accept`. A proposal's pieces are set aside whether it is accepted or not, so each
/// piece serves one proposal.
pub fn triangulate(
    pieces: &[MaskPiece],
    min_views: usize,
    accept: &mut dyn FnMut(&Triangulated) -> bool,
) -> Vec<Triangulated> {
    let mut live: Vec<usize> = (0..pieces.len()).collect();
    let mut found = Vec::new();
    loop {
        // The pair whose proposal gathers pieces from the most views (then the most pixels).
        let mut best: Option<((usize, usize), Vec<usize>)> = None;
        for (x, &i) in live.iter().enumerate() {
            for &j in &live[x + 1..] {
                if pieces[i].view == pieces[j].view {
                    continue;
                }
                let Some((c, gap)) = nearest_point(&pieces[i], &pieces[j]) else {
                    continue;
                };
                let (ri, rj) = (ray_fit(&pieces[i], c), ray_fit(&pieces[j], c));
                let (Some((ri, _)), Some((rj, _))) = (ri, rj) else {
                    continue;
                };
                if gap > INLIER_RADII * (ri + rj) {
                    continue;
                }
                let set = inliers(pieces, &live, c);
                let score = |s: &[usize]| {
                    let px: usize = s.iter().map(|&k| pieces[k].pixels.len()).sum();
                    (distinct_views(pieces, s), px)
                };
                if best.as_ref().is_none_or(|(_, b)| score(&set) > score(b)) {
                    best = Some(((i, j), set));
                }
            }
        }
        let Some((_, set)) = best else { break };
        if distinct_views(pieces, &set) < min_views.max(2) {
            break;
        }
        // Refined on its inliers, whose set is taken again about the refined centre.
        let Some((c, _)) = refine(pieces, &set) else { break };
        let mut members = inliers(pieces, &live, c);
        if members.len() < 2 {
            members = set.clone();
        }
        let Some((centre, radius)) = refine(pieces, &members) else {
            break;
        };
        let light = Triangulated {
            centre,
            radius,
            pieces: members.clone(),
        };
        // Its pieces, and any other whose ray passes through the light (small pieces of its
        // rim, whose own disc is too small for the inlier test), are set aside.
        live.retain(|&i| {
            !members.contains(&i)
                && !set.contains(&i)
                && !ray_fit(&pieces[i], centre).is_some_and(|(ri, d)| d <= radius + ri)
        });
        if distinct_views(pieces, &members) >= min_views.max(2) && accept(&light) {
            found.push(light);
        }
    }
    found
}

/// The radius (world) that the masks give a bulb whose surface fit put its centre at `c` with
/// radius `r`: the median disc radius, at the depth of `c`, of the `pieces` whose centroid rays
/// pass within `r` of it (the caller leaves out pieces cut by the image's border or occluded),
/// from at least `min_views` views. None with fewer.
///
/// Why: the sphere fitted to a bulb's surface points is as large as stage 1 built the bulb, and
/// stage 1 builds a small bright object a little inflated (on the second room 0.110 m for a
/// 0.100 m bulb: ×1.20 of its light, which stage 2 fitted into a Kd 10 % too bright). A sphere's
/// silhouette is a disc of angular radius asin(r / d) from any side, which the masks measure
/// directly.
pub fn mask_radius(pieces: &[MaskPiece], c: DVec3, r: f64, min_views: usize) -> Option<f64> {
    let members: Vec<usize> = (0..pieces.len())
        .filter(|&i| ray_fit(&pieces[i], c).is_some_and(|(_, d)| d <= r))
        .collect();
    if distinct_views(pieces, &members) < min_views.max(1) {
        return None;
    }
    let mut radii: Vec<f64> = members
        .iter()
        .filter_map(|&i| ray_fit(&pieces[i], c).map(|(ri, _)| ri))
        .collect();
    radii.sort_by(f64::total_cmp);
    Some(radii[radii.len() / 2])
}

/// The angular radius (radians) of a mask piece of `area` pixels that covers `solid_angle`
/// steradians (the sum of its pixels' own): the radius of the disc of that solid angle. A
/// pixel's solid angle is cos³θ / (fx·fy) off the axis θ of a pinhole camera, so an image far
/// from the centre is larger in pixels than the same light on the axis (the second room's bulb,
/// 40° off: 1.9 times the area; counted in pixels over f², its masks made the 0.100 m bulb
/// 0.118 m). A piece of `clipped` (saturated) LDR pixels takes every pixel the light touches
/// enough to saturate, partly covered rim pixels included: a light far brighter than white
/// saturates a pixel it covers a small part of, so the piece is its disc grown by a fraction of
/// a pixel, [`CLIPPED_RIM_PX`], which is taken off. Counting only the pixels saturated in every
/// channel instead gave 0.69 times the radius on the default room's capture: JPEG's halved
/// chroma keeps a warm light's blue under saturation over much of its disc. A dataset's mask
/// marks pixel centres, as do HDR targets' pieces: the disc of the area as it is.
pub fn disc_angle(area: usize, solid_angle: f64, clipped: bool) -> f64 {
    let angle = (solid_angle / std::f64::consts::PI).sqrt();
    let r = (area as f64 / std::f64::consts::PI).sqrt();
    match clipped {
        true if r > 0.0 => angle * (r - CLIPPED_RIM_PX).max(0.5) / r,
        _ => angle,
    }
}

/// How far (pixels) a clipped piece reaches past its light's silhouette. Measured on both
/// built-in captures' found masks (the bulb's whole pieces, 11 and 13 of them, at the true
/// poses; `docs/results.md`): the median radius came out 0.104 / 0.110 m for a 0.100 m bulb with
/// nothing taken off, 0.089 / 0.096 m with half a pixel, 0.097 / 0.103 m with a quarter.
pub const CLIPPED_RIM_PX: f64 = 0.25;

/// Whether a piece is compact enough to be the image of a small light: its area at least
/// `COMPACTNESS` of the disc about its centroid through its farthest pixel (a disc gives about
/// 1, a 2:1 ellipse 0.5; the sliver of a panel seen edge-on much less).
pub fn is_compact(pixels: &[u32], width: usize) -> bool {
    const COMPACTNESS: f64 = 0.4;
    if pixels.is_empty() {
        return false;
    }
    let n = pixels.len() as f64;
    let xy = |p: u32| ((p as usize % width) as f64 + 0.5, (p as usize / width) as f64 + 0.5);
    let (sx, sy) = pixels.iter().fold((0.0, 0.0), |(sx, sy), &p| {
        let (x, y) = xy(p);
        (sx + x, sy + y)
    });
    let (cx, cy) = (sx / n, sy / n);
    // Each pixel is a unit square: its far corner, not its centre, bounds the piece.
    let far = pixels
        .iter()
        .map(|&p| {
            let (x, y) = xy(p);
            ((x - cx).abs() + 0.5).hypot((y - cy).abs() + 0.5)
        })
        .fold(0.0f64, f64::max);
    n >= COMPACTNESS * std::f64::consts::PI * far * far
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A piece seen from `origin` of a sphere (`c`, `r`), its centroid ray off by `off` (world,
    /// perpendicular), with `pixels` pixels.
    fn piece(view: usize, origin: DVec3, c: DVec3, r: f64, off: DVec3) -> MaskPiece {
        let dir = (c + off - origin).normalize();
        MaskPiece {
            view,
            origin,
            dir,
            angle: r / (c - origin).length(),
            pixels: vec![0; 12],
        }
    }

    #[test]
    fn a_sphere_seen_from_four_views_is_found_at_its_centre_and_size() {
        let (c, r) = (DVec3::new(-1.8, 1.8, -1.5), 0.1);
        let origins = [
            DVec3::new(0.5, 1.5, 1.0),
            DVec3::new(1.2, 1.4, -0.5),
            DVec3::new(-0.3, 1.6, 1.5),
            DVec3::new(0.8, 1.2, 0.2),
        ];
        // Centroids off by up to a third of a radius, as partly found masks give.
        let offs = [
            DVec3::new(0.03, 0.0, 0.0),
            DVec3::new(0.0, -0.02, 0.0),
            DVec3::new(0.0, 0.0, 0.03),
            DVec3::ZERO,
        ];
        let mut pieces: Vec<MaskPiece> = (0..4).map(|v| piece(v, origins[v], c, r, offs[v])).collect();
        // A piece elsewhere (the panel's reflection in one view) joins nothing.
        pieces.push(piece(1, origins[1], DVec3::new(1.0, 0.0, 1.0), 0.2, DVec3::ZERO));
        let found = triangulate(&pieces, 2, &mut |_| true);
        assert_eq!(found.len(), 1, "{found:?}");
        assert!((found[0].centre - c).length() < 0.03, "{:?}", found[0].centre);
        assert!((found[0].radius - r).abs() < 0.01, "{}", found[0].radius);
        let mut members = found[0].pieces.clone();
        members.sort_unstable();
        assert_eq!(members, vec![0, 1, 2, 3]);
    }

    /// The masks size a sphere whose surface fit came out 10 % large: the median of the pieces
    /// that pass through it (one partly occluded, smaller), pieces elsewhere left out; too few
    /// views give nothing.
    #[test]
    fn the_masks_give_a_fitted_bulb_its_radius() {
        let (c, r) = (DVec3::new(2.0, 1.8, -1.4), 0.1);
        let origins = [
            DVec3::new(0.5, 1.5, 1.0),
            DVec3::new(-1.2, 1.4, -0.5),
            DVec3::new(-0.3, 1.6, 1.5),
            DVec3::new(0.8, 1.2, 0.2),
            DVec3::new(0.0, 1.0, -2.0),
        ];
        let mut pieces: Vec<MaskPiece> = (0..5)
            .map(|v| piece(v, origins[v], c, r, DVec3::new(0.0, 0.01 * v as f64, 0.0)))
            .collect();
        pieces[2].angle *= 0.6;
        pieces.push(piece(1, origins[1], DVec3::new(1.0, 0.0, 1.0), 0.3, DVec3::ZERO));
        let found = mask_radius(&pieces, c + DVec3::new(0.01, 0.0, 0.0), 1.1 * r, 3).unwrap();
        assert!((found - r).abs() < 0.003, "{found}");
        assert!(mask_radius(&pieces[..2], c, 1.1 * r, 3).is_none());
    }

    #[test]
    fn one_view_or_a_rejected_proposal_gives_no_light() {
        let (c, r) = (DVec3::new(0.0, 2.0, 0.0), 0.1);
        let o = [DVec3::new(2.0, 1.5, 0.0), DVec3::new(2.2, 1.5, 0.3)];
        // Two pieces of one view: no baseline.
        let same_view = vec![piece(0, o[0], c, r, DVec3::ZERO), piece(0, o[0], c, r, DVec3::ZERO)];
        assert!(triangulate(&same_view, 2, &mut |_| true).is_empty());
        // Two views, but the caller's test says no: nothing, and the test was asked once.
        let two = vec![piece(0, o[0], c, r, DVec3::ZERO), piece(1, o[1], c, r, DVec3::ZERO)];
        let mut asked = 0;
        assert!(triangulate(&two, 2, &mut |_| {
            asked += 1;
            false
        })
        .is_empty());
        assert_eq!(asked, 1);
        // Two views, and three required.
        assert!(triangulate(&two, 3, &mut |_| true).is_empty());
        assert_eq!(triangulate(&two, 2, &mut |_| true).len(), 1);
    }

    #[test]
    fn rays_that_diverge_or_are_parallel_propose_nothing() {
        let a = MaskPiece {
            view: 0,
            origin: DVec3::ZERO,
            dir: DVec3::X,
            angle: 0.01,
            pixels: vec![0],
        };
        let parallel = MaskPiece {
            view: 1,
            origin: DVec3::Y,
            ..a.clone()
        };
        assert!(nearest_point(&a, &parallel).is_none());
        // Crossing behind the first camera.
        let behind = MaskPiece {
            view: 1,
            origin: DVec3::new(-1.0, 1.0, 0.0),
            dir: DVec3::new(0.0, -1.0, 0.0),
            angle: 0.01,
            pixels: vec![0],
        };
        assert!(nearest_point(&a, &behind).is_none());
        let crossing = MaskPiece {
            origin: DVec3::new(2.0, 1.0, 0.0),
            ..behind
        };
        let (p, gap) = nearest_point(&a, &crossing).unwrap();
        assert!((p - DVec3::new(2.0, 0.0, 0.0)).length() < 1e-12 && gap < 1e-12);
    }

    #[test]
    fn discs_are_compact_and_slivers_are_not() {
        let w = 64;
        let disc: Vec<u32> = (0..w * w)
            .filter(|&p| {
                let (x, y) = ((p % w) as f64 - 20.0, (p / w) as f64 - 20.0);
                x * x + y * y <= 25.0
            })
            .map(|p| p as u32)
            .collect();
        assert!(is_compact(&disc, w));
        let sliver: Vec<u32> = (10..40).map(|x| (20 * w + x) as u32).collect();
        assert!(!is_compact(&sliver, w));
        assert!(is_compact(&[5], w));
        assert!(!is_compact(&[], w));
        // 12 px of 1e-4 sr each (f = 100 px on the axis): a disc of radius √(12/π) px;
        // clipped, the rim less; never under half a pixel.
        let r = (12.0 / std::f64::consts::PI).sqrt();
        assert!((disc_angle(12, 12e-4, false) - r / 100.0).abs() < 1e-15);
        assert!((disc_angle(12, 12e-4, true) - (r - CLIPPED_RIM_PX) / 100.0).abs() < 1e-15);
        assert!((disc_angle(1, 1e-4, true) - 0.5 / 100.0).abs() < 1e-15);
        // Off the axis a pixel subtends less: the same area at a quarter of the solid angle is
        // half the angle.
        assert!((disc_angle(12, 3e-4, false) - 0.5 * r / 100.0).abs() < 1e-15);
    }
}
