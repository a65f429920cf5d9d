//! Stage 2's targets: the training views in linear radiance in the units of the input images
//! (docs/results.md, "Stage 2: emitters and materials"), with which channels are saturated, the emitter masks
//! in force ([`TrainingMaps`]: the dataset's, or found from the images), the dataset's material
//! masks and its normals.

use crate::maps::TrainingMaps;
use i2sdf_data::{Dataset, Radiometry, Split};

/// LDR values at or above this are saturated (8-bit 255 with some slack for 16-bit PNGs).
pub const SATURATED: f32 = 254.5 / 255.0;

/// One training view as stage 2 fits it: linear targets, which channels are saturated, and
/// (where the dataset has them) the emitter mask.
#[derive(Clone, Debug)]
pub struct TargetView {
    pub camera: i2sdf_data::Camera,
    /// Linear RGB per pixel, row-major.
    pub rgb: Vec<[f32; 3]>,
    /// Per pixel, bit c set when channel c only bounds the prediction from below.
    pub saturated: Vec<u8>,
    /// The emitter mask in force (`maps.emitter_masks`), if any.
    pub emitter_mask: Option<Vec<bool>>,
    /// The dataset's material mask, if any: false where the material is not one GGX can fit, so
    /// the surface pixel is not fitted (`Frame::material_mask`).
    pub material_mask: Option<Vec<bool>>,
    /// The dataset's world-space normal per pixel, where it has normal maps (zero: none).
    pub normal: Option<Vec<[f32; 3]>>,
}

/// The dataset's radiometry as stage 2 uses it: its transfer, and the declared exposure, else the
/// one its LDR and HDR images measure (`i2sdf_data::exposure`), else none.
pub fn radiometry(dataset: &Dataset) -> Radiometry {
    Radiometry {
        exposure: i2sdf_data::exposure::exposure_in_use(dataset),
        ..dataset.radiometry
    }
}

/// The training views' targets (see the module comment for the radiometry), with the emitter
/// masks of `maps`.
pub fn target_views(dataset: &Dataset, use_hdr: bool, maps: &TrainingMaps) -> Vec<TargetView> {
    let rm = radiometry(dataset);
    dataset
        .frames
        .iter()
        .enumerate()
        .filter(|(_, f)| f.split == Split::Train)
        .map(|(index, f)| {
            let n = f.pixel_count();
            let (mut rgb, mut saturated) = (Vec::with_capacity(n), Vec::with_capacity(n));
            match (&f.hdr, use_hdr) {
                (Some(hdr), true) => {
                    let scale = rm.exposure.unwrap_or(1.0) as f32;
                    for p in hdr.data.chunks_exact(3) {
                        rgb.push([p[0] * scale, p[1] * scale, p[2] * scale]);
                        saturated.push(0);
                    }
                }
                _ => {
                    for p in f.rgb.data.chunks_exact(3) {
                        rgb.push([rm.linearize(p[0]), rm.linearize(p[1]), rm.linearize(p[2])]);
                        saturated.push((0..3).fold(0u8, |m, c| m | (((p[c] >= SATURATED) as u8) << c)));
                    }
                }
            }
            TargetView {
                camera: f.camera.clone(),
                rgb,
                saturated,
                emitter_mask: maps
                    .emitter_mask(index, f)
                    .map(|m| m.data.iter().map(|&v| v > 0.5).collect()),
                material_mask: f
                    .material_mask
                    .as_ref()
                    .map(|m| m.data.iter().map(|&v| v > 0.5).collect()),
                normal: f
                    .normal
                    .as_ref()
                    .map(|m| m.data.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()),
            }
        })
        .collect()
}
