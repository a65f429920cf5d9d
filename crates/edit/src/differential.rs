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

use glam::Vec3;
use i2sdf_data::{ImageF32, Radiometry};
use i2sdf_render::ViewRender;

/// How `i2sdf edit` and the relight evaluation form the edited image.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Composite {
    /// The path tracer's render of the edited scene, as it is.
    #[default]
    PathTraced,
    /// The radiance field's view + (edited − unedited) path-traced: see the module docs.
    Differential,
}

impl Composite {
    /// `"path-traced"` or `"differential"`.
    pub fn from_name(name: &str) -> Result<Self, String> {
        match name {
            "path-traced" => Ok(Composite::PathTraced),
            "differential" => Ok(Composite::Differential),
            other => Err(format!("{other:?}: must be \"path-traced\" or \"differential\"")),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Composite::PathTraced => "path-traced",
            Composite::Differential => "differential",
        }
    }
}

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

/// The differential image in linear HDR (image units): `captured` is the radiance field's view
/// (display values, 3 channels), `edited` the edited scene's render with `gains`, `unedited` the
/// unedited scene's render of the same camera, seed and view (all ones gains). For a relight
/// only, `unedited` is `edited` itself.
pub fn differential_hdr(
    captured: &ImageF32,
    edited: &ViewRender,
    gains: &[Vec3],
    unedited: &ViewRender,
    radiometry: &Radiometry,
) -> Vec<Vec3> {
    assert_eq!(
        (captured.width, captured.height, captured.channels),
        (edited.width, edited.height, 3)
    );
    assert_eq!((unedited.width, unedited.height), (edited.width, edited.height));
    let e = edited.hdr(gains);
    let u = unedited.hdr(&vec![Vec3::ONE; unedited.emitters]);
    e.iter()
        .zip(&u)
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
            (c + e - u).max(Vec3::ZERO)
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

    #[test]
    fn a_relight_adds_the_change_to_the_captured_image() {
        // The model under-estimates the light (0.2 where the capture says 0.4): doubling the
        // light adds the model's share once more, the captured 0.4 is kept.
        let v = view([0.2, 0.1], [0.5, 0.5]);
        let captured = ImageF32::from_data(2, 1, 3, vec![0.4; 6]);
        let out = differential_hdr(&captured, &v, &[Vec3::splat(2.0)], &v, &linear());
        assert!((out[0] - Vec3::splat(0.6)).abs().max_element() < 1e-6, "{:?}", out[0]);
        assert!((out[1] - Vec3::splat(0.5)).abs().max_element() < 1e-6);
        // Turning it off where the model over-estimates clamps at zero, not below.
        let out = differential_hdr(
            &captured,
            &view([0.6, 0.1], [0.5, 0.5]),
            &[Vec3::ZERO],
            &view([0.6, 0.1], [0.5, 0.5]),
            &linear(),
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
        let out = differential_hdr(&captured, &edited, &[Vec3::ONE], &unedited, &linear());
        assert!((out[0] - Vec3::splat(0.5)).abs().max_element() < 1e-6);
        assert_eq!(out[1], Vec3::splat(0.9));
        // A clipped capture says nothing about the radiance: the path tracer's stands.
        captured.data[0] = 1.0;
        let out = differential_hdr(&captured, &edited, &[Vec3::ONE], &unedited, &linear());
        assert_eq!(out[0], Vec3::splat(0.3));
    }

    #[test]
    fn names_round_trip() {
        for c in [Composite::PathTraced, Composite::Differential] {
            assert_eq!(Composite::from_name(c.name()), Ok(c));
        }
        assert!(Composite::from_name("ratio").is_err());
    }
}
