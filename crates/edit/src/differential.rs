//! Differential rendering (Debevec 1998, "Rendering synthetic objects into real scenes", the
//! standard way to edit a captured scene): the edited image is the captured appearance plus what
//! the edit changes according to the model,
//!
//!   I_edit = I_captured + (PT_edited − PT_unedited),
//!
//! where I_captured is stage 1's radiance field seen from the camera (the scene as photographed,
//! ~30 dB on the test views, against ~26 dB for the path tracer over the recovered materials) and
//! both path-traced renders share their samples (same seed and view: the per-pixel samplers are
//! keyed on them), so the parts of the noise the edit does not touch cancel. Where the model is
//! exact this is the path-traced edit itself; where it is not, only the *change* carries the
//! model's material error. It is the image-level form of the "radiance-field shortcut": the
//! frozen radiance field stands for the light transport the edit leaves unchanged.
//!
//! The captured term cannot stand where it is wrong for the edited scene, so those pixels take
//! the path-traced edit (Debevec's "object pixels"):
//! - the pixel-centre ray sees something else (an inserted object, an edited material: its depth,
//!   Kd, Ks, roughness or emitter label differs between the two renders);
//! - the radiance field is saturated there (F_c is trained on clipped LDR images and cannot say
//!   how bright an emitter is).
//!
//! A relit set (gains only) needs one render: its edited and unedited images are the same paths
//! with different per-emitter gains ([`ViewRender::hdr`]). Negative results (a light turned off
//! where the model over-estimated its share) are clamped to zero.
//!
//! The ratio form ([`Composite::Ratio`]) takes, where the edit takes light away, the "ratio
//! image" of relighting instead of the difference,
//!
//!   I_edit = I_captured · PT_edited / PT_unedited   (per channel, where PT_edited < PT_unedited),
//!
//! and the difference where the edit adds light (the two agree where nothing changes). Why: the
//! capture's light is taken away in proportion to the model's shares, so what the capture says of
//! the material stays (a diffuse pixel is Kd ⊙ irradiance, and Kd is where stage 2 is weakest),
//! where the difference subtracts the model's light, with its material's error and its paths'
//! noise, from the captured one. When the room is left to its small light, the difference takes
//! the large light's whole noisy share from a bright capture to leave a dim image; the ratio of
//! two renders of the same paths leaves the dim image with their common noise divided out. Where
//! light is added the ratio would scale the capture's own error by the gain, and the difference
//! adds only the model's light: measured on the default room, the ratio everywhere lost 0.4 dB
//! on its brightened set and gained 1.1 dB on its dimmed ones. Where the model's light is weak
//! the ratio is undefined (a shadow it never saw lit): it fades into the difference below
//! [`RATIO_FLOOR`] of the image's mean model light.

use glam::Vec3;
use i2sdf_data::{ImageF32, Radiometry};
use i2sdf_render::{luminance, ViewRender};

/// How `i2sdf edit` and the relight evaluation form the edited image.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Composite {
    /// The path tracer's render of the edited scene, as it is.
    #[default]
    PathTraced,
    /// The radiance field's view + (edited − unedited) path-traced: see the module docs.
    Differential,
    /// The radiance field's view × (edited / unedited) path-traced where the edit dims, as
    /// `Differential` where it brightens: see the module docs.
    Ratio,
}

impl Composite {
    /// `"path-traced"` or `"differential"`.
    pub fn from_name(name: &str) -> Result<Self, String> {
        match name {
            "path-traced" => Ok(Composite::PathTraced),
            "differential" => Ok(Composite::Differential),
            "ratio" => Ok(Composite::Ratio),
            other => Err(format!(
                "{other:?}: must be \"path-traced\", \"differential\" or \"ratio\""
            )),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Composite::PathTraced => "path-traced",
            Composite::Differential => "differential",
            Composite::Ratio => "ratio",
        }
    }

    /// Whether the image is formed over the radiance field's view (and, for an edit that does
    /// more than relight, over the unedited scene's render of the same paths).
    pub fn over_capture(self) -> bool {
        self != Composite::PathTraced
    }
}

/// Below this fraction of the image's mean model light (luminance of the unedited render), the
/// ratio composite fades into the difference: the weight of the ratio is u² / (u² + floor²), a
/// half at the floor and 0.9975 at the mean.
pub const RATIO_FLOOR: f32 = 0.05;

/// A display value of F_c at or above this is clipped: the radiance field does not know the
/// radiance there.
const SATURATED: f32 = 0.99;

/// Whether the pixel-centre ray of `a` and `b` sees the same surface with the same material.
fn same_surface(a: &ViewRender, b: &ViewRender, i: usize) -> bool {
    let (da, db) = (a.depth[i], b.depth[i]);
    let depth_same =
        (da.is_finite() == db.is_finite()) && (!da.is_finite() || (da - db).abs() <= 1e-4 * da.abs().max(1.0));
    depth_same
        && a.emitter_mask[i] == b.emitter_mask[i]
        && a.kd[i].abs_diff_eq(b.kd[i], 1e-5)
        && a.ks[i].abs_diff_eq(b.ks[i], 1e-5)
        && (a.roughness[i] - b.roughness[i]).abs() <= 1e-5
}

/// The image `kind` forms, in linear HDR (image units): `captured` is the radiance field's view
/// (display values, 3 channels), `edited` the edited scene's render with `gains`, `unedited` the
/// unedited scene's render of the same camera, seed and view (all ones gains; for a relight only,
/// `edited` itself).
///
/// - [`Composite::PathTraced`]: the edited render with its gains.
/// - [`Composite::Differential`]: c + e − u per pixel.
/// - [`Composite::Ratio`]: per channel where the edit dims (e < u), c · e / u where the model's
///   light u is well above [`RATIO_FLOOR`] and the difference where it is not, blended by
///   u² / (u² + floor²) between; where the edit brightens, the difference.
pub fn composite_hdr(
    kind: Composite,
    captured: &ImageF32,
    edited: &ViewRender,
    gains: &[Vec3],
    unedited: &ViewRender,
    radiometry: &Radiometry,
) -> Vec<Vec3> {
    let e = edited.hdr(gains);
    if kind == Composite::PathTraced {
        return e;
    }
    let u = unedited.hdr(&vec![Vec3::ONE; unedited.emitters]);
    let images = (&e[..], &u[..]);
    if kind == Composite::Differential {
        return over_capture(captured, edited, unedited, images, radiometry, |c, e, u| c + e - u);
    }
    let mean = u.iter().map(|c| luminance(*c)).sum::<f32>() / u.len().max(1) as f32;
    let floor = Vec3::splat((RATIO_FLOOR * mean).max(f32::MIN_POSITIVE));
    over_capture(captured, edited, unedited, images, radiometry, |c, e, u| {
        let u = u.max(Vec3::ZERO);
        let w = u * u / (u * u + floor * floor);
        let ratio = w * (c * e / u.max(floor)) + (Vec3::ONE - w) * (c + e - u);
        Vec3::select(e.cmplt(u), ratio, c + e - u)
    })
}

/// Per pixel, `combine(captured, edited, unedited)` (linear, clamped at zero) of the captured
/// image and the two renders' images `(e, u)`, or the edited render where the captured image
/// cannot stand (see the module docs).
fn over_capture(
    captured: &ImageF32,
    edited: &ViewRender,
    unedited: &ViewRender,
    (e, u): (&[Vec3], &[Vec3]),
    radiometry: &Radiometry,
    combine: impl Fn(Vec3, Vec3, Vec3) -> Vec3,
) -> Vec<Vec3> {
    assert_eq!(
        (captured.width, captured.height, captured.channels),
        (edited.width, edited.height, 3)
    );
    assert_eq!((unedited.width, unedited.height), (edited.width, edited.height));
    e.iter()
        .zip(u)
        .enumerate()
        .map(|(i, (&e, &u))| {
            let c = &captured.data[3 * i..3 * i + 3];
            if c.iter().any(|&x| x >= SATURATED) || !same_surface(edited, unedited, i) {
                return e;
            }
            let c = Vec3::new(
                radiometry.linearize(c[0]),
                radiometry.linearize(c[1]),
                radiometry.linearize(c[2]),
            );
            combine(c, e, u).max(Vec3::ZERO)
        })
        .collect()
}

/// Linear HDR → the dataset's LDR tone mapping, both as images.
pub fn hdr_ldr_images(hdr: &[Vec3], width: usize, height: usize, radiometry: &Radiometry) -> (ImageF32, ImageF32) {
    let hdr = ImageF32::from_data(width, height, 3, hdr.iter().flat_map(|c| c.to_array()).collect());
    let ldr = radiometry.encode_image(&hdr);
    (hdr, ldr)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2×1 render of one emitter (plus nothing else) with given radiance and maps.
    fn view(radiance: [f32; 2], kd: [f32; 2]) -> ViewRender {
        ViewRender {
            width: 2,
            height: 1,
            emitters: 1,
            radiance: radiance.iter().map(|&r| Vec3::splat(r)).collect(),
            variance: vec![0.0; 2],
            depth: vec![1.0, 2.0],
            normal: vec![Vec3::Z; 2],
            emitter_mask: vec![false; 2],
            kd: kd.iter().map(|&k| Vec3::splat(k)).collect(),
            ks: vec![Vec3::ZERO; 2],
            roughness: vec![1.0; 2],
        }
    }

    fn linear() -> Radiometry {
        Radiometry::from_name("linear", None).unwrap()
    }

    /// [`composite_hdr`] with linear radiometry.
    fn composite(kind: Composite, c: &ImageF32, e: &ViewRender, gains: &[Vec3], u: &ViewRender) -> Vec<Vec3> {
        composite_hdr(kind, c, e, gains, u, &linear())
    }

    #[test]
    fn a_relight_adds_the_change_to_the_captured_image() {
        // The model under-estimates the light (0.2 where the capture says 0.4): doubling the
        // light adds the model's share once more, the captured 0.4 is kept.
        let v = view([0.2, 0.1], [0.5, 0.5]);
        let captured = ImageF32::from_data(2, 1, 3, vec![0.4; 6]);
        let out = composite(Composite::Differential, &captured, &v, &[Vec3::splat(2.0)], &v);
        assert!((out[0] - Vec3::splat(0.6)).abs().max_element() < 1e-6, "{:?}", out[0]);
        assert!((out[1] - Vec3::splat(0.5)).abs().max_element() < 1e-6);
        // Turning it off where the model over-estimates clamps at zero, not below.
        let out = composite(
            Composite::Differential,
            &captured,
            &view([0.6, 0.1], [0.5, 0.5]),
            &[Vec3::ZERO],
            &view([0.6, 0.1], [0.5, 0.5]),
        );
        assert_eq!(out[0], Vec3::ZERO);
        assert!((out[1] - Vec3::splat(0.3)).abs().max_element() < 1e-6);
    }

    #[test]
    fn edited_surfaces_and_saturated_pixels_take_the_path_traced_edit() {
        let unedited = view([0.2, 0.2], [0.5, 0.5]);
        // Pixel 1's material was edited: it takes the edited render's 0.9.
        let edited = view([0.3, 0.9], [0.5, 0.1]);
        let mut captured = ImageF32::from_data(2, 1, 3, vec![0.4; 6]);
        let out = composite(Composite::Differential, &captured, &edited, &[Vec3::ONE], &unedited);
        assert!((out[0] - Vec3::splat(0.5)).abs().max_element() < 1e-6);
        assert_eq!(out[1], Vec3::splat(0.9));
        // A clipped capture says nothing about the radiance: the path tracer's stands.
        captured.data[0] = 1.0;
        let out = composite(Composite::Differential, &captured, &edited, &[Vec3::ONE], &unedited);
        assert_eq!(out[0], Vec3::splat(0.3));
    }

    #[test]
    fn dimming_keeps_what_the_capture_says_of_the_material() {
        // The capture is twice the model (its Kd is twice stage 2's): a quarter of the light
        // leaves a quarter of the captured 0.4, where the difference subtracts the model's
        // 0.15 only.
        let v = view([0.2, 0.2], [0.5, 0.5]);
        let captured = ImageF32::from_data(2, 1, 3, vec![0.4; 6]);
        let out = composite(Composite::Ratio, &captured, &v, &[Vec3::splat(0.25)], &v);
        let w = 1.0 / (1.0 + RATIO_FLOOR * RATIO_FLOOR);
        let expect = w * 0.1 + (1.0 - w) * 0.25;
        assert!(
            (out[0] - Vec3::splat(expect)).abs().max_element() < 1e-6,
            "{:?}",
            out[0]
        );
        assert!(out[0].x < 0.101, "nearly the ratio: {:?}", out[0]);
        let d = composite(Composite::Differential, &captured, &v, &[Vec3::splat(0.25)], &v);
        assert!((d[0] - Vec3::splat(0.25)).abs().max_element() < 1e-6);
    }

    #[test]
    fn brightening_adds_the_models_light() {
        // Per channel: red tripled takes the difference, blue halved the ratio.
        let v = view([0.2, 0.2], [0.5, 0.5]);
        let captured = ImageF32::from_data(2, 1, 3, vec![0.4; 6]);
        let gains = [Vec3::new(3.0, 1.0, 0.5)];
        let out = composite(Composite::Ratio, &captured, &v, &gains, &v);
        let d = composite(Composite::Differential, &captured, &v, &gains, &v);
        assert_eq!(out[0].x, d[0].x);
        assert!(
            (out[0].y - 0.4).abs() < 1e-6,
            "nothing changes: the capture, {:?}",
            out[0]
        );
        assert!((out[0].z - 0.2).abs() < 1e-3, "{:?}", out[0]);
    }

    #[test]
    fn a_ratio_fades_into_the_difference_where_the_model_has_no_light() {
        // Pixel 1: the model's light is 1e-5 of pixel 0's (a shadow it never saw lit).
        let v = view([1.0, 1e-5], [0.5, 0.5]);
        let captured = ImageF32::from_data(2, 1, 3, vec![0.4; 6]);
        let out = composite(Composite::Ratio, &captured, &v, &[Vec3::splat(0.5)], &v);
        let d = composite(Composite::Differential, &captured, &v, &[Vec3::splat(0.5)], &v);
        assert!(
            (out[1] - d[1]).abs().max_element() < 1e-5,
            "{:?} against {:?}",
            out[1],
            d[1]
        );
        assert!((out[0] - Vec3::splat(0.2)).abs().max_element() < 1e-3, "{:?}", out[0]);
    }

    #[test]
    fn a_common_dimming_scales_the_capture_whatever_the_renders_noise() {
        // Two emitters, each pixel's paths noisy in their own way: both halved give half the
        // capture through the ratio (up to the floor's blend), not the capture less the noise.
        let mut v = view([0.0, 0.0], [0.5, 0.5]);
        v.emitters = 2;
        v.radiance = vec![Vec3::splat(0.3), Vec3::splat(0.05), Vec3::splat(0.1), Vec3::splat(0.6)];
        let captured = ImageF32::from_data(2, 1, 3, vec![0.4; 6]);
        let out = composite(Composite::Ratio, &captured, &v, &[Vec3::splat(0.5); 2], &v);
        for p in out {
            assert!((p - Vec3::splat(0.2)).abs().max_element() < 1e-3, "{p:?}");
        }
    }

    #[test]
    fn names_round_trip() {
        for c in [Composite::PathTraced, Composite::Differential, Composite::Ratio] {
            assert_eq!(Composite::from_name(c.name()), Ok(c));
        }
        assert!(Composite::from_name("product").is_err());
    }
}
