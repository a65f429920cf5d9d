//! Writing one rendered view in the native format (docs/DATASETS.md): LDR PNG (sRGB of
//! clamp(exposure · HDR, 0, 1)), HDR RGB EXR, z-depth EXR (channel Y, metres), world-space normal
//! EXR, emitter mask PNG (255 = emitter), and the GT material maps Kd, Ks (RGB EXR) and roughness
//! ρ (EXR, channel Y); a capture's variants of them (`crate::capture`): JPEG frames, a 16-bit PNG
//! depth in millimetres on a coarser grid, a confidence PNG, and no HDR, normals or masks.

use crate::capture::{depth_to_mm, CaptureOptions, SensorDepth};
use glam::Vec3;
use i2sdf_data::imageio::{self, ImageF32};
use i2sdf_data::DataError;
use i2sdf_render::ViewRender;
use std::path::Path;

pub fn rgb_image(w: usize, h: usize, px: &[Vec3]) -> ImageF32 {
    ImageF32::from_data(w, h, 3, px.iter().flat_map(|p| p.to_array()).collect())
}

pub fn gray_image(w: usize, h: usize, px: &[f32]) -> ImageF32 {
    ImageF32::from_data(w, h, 1, px.to_vec())
}

/// The LDR encoding of an HDR image: sRGB transfer of clamp(exposure · L, 0, 1).
pub fn ldr_image(w: usize, h: usize, hdr: &[Vec3], exposure: f32) -> ImageF32 {
    imageio::tone_map_srgb(&rgb_image(w, h, hdr), exposure)
}

/// Paths of one frame's files, relative to the scene directory (`None`: not written).
#[derive(Clone, Debug)]
pub struct FramePaths {
    pub image: String,
    pub hdr: Option<String>,
    pub depth: String,
    pub depth_gt: Option<String>,
    pub confidence: Option<String>,
    pub normal: Option<String>,
    pub mask: Option<String>,
    pub kd: String,
    pub ks: String,
    pub roughness: String,
}

impl FramePaths {
    /// The exact room's files (a noisy depth keeps the clean one as `depth_gt`), less what the
    /// capture options leave out or change: JPEG frames, a 16-bit PNG depth in millimetres on a
    /// depth grid (the clean full-resolution depth then kept too), the confidence map.
    pub fn new(stem: &str, noisy_depth: bool, capture: &CaptureOptions) -> Self {
        let sensor = capture.depth_grid.is_some() || capture.confidence;
        FramePaths {
            image: match capture.jpeg_quality {
                Some(_) => format!("images/{stem}.jpg"),
                None => format!("images/{stem}.png"),
            },
            hdr: capture.hdr.then(|| format!("hdr/{stem}.exr")),
            depth: match capture.depth_grid {
                Some(_) => format!("depth/{stem}.png"),
                None => format!("depth/{stem}.exr"),
            },
            depth_gt: (noisy_depth || sensor).then(|| format!("depth_gt/{stem}.exr")),
            confidence: capture.confidence.then(|| format!("confidence/{stem}.png")),
            normal: capture.normals.then(|| format!("normal/{stem}.exr")),
            mask: capture.masks.then(|| format!("mask/{stem}.png")),
            kd: format!("material/{stem}_kd.exr"),
            ks: format!("material/{stem}_ks.exr"),
            roughness: format!("material/{stem}_roughness.exr"),
        }
    }
}

/// Writes every file of one view: the frame (PNG, or JPEG at `jpeg_quality`), the maps its paths
/// name, and `depth`, what the dataset calls depth (noisy when a noise model is on; a 16-bit PNG
/// in millimetres when its path is a PNG), with its confidence. The clean full-resolution z-depth
/// goes to `depth_gt` when the paths ask for it.
pub fn write_view(
    root: &Path,
    paths: &FramePaths,
    view: &ViewRender,
    hdr: &[Vec3],
    depth: &SensorDepth,
    exposure: f32,
    jpeg_quality: Option<u8>,
) -> Result<(), DataError> {
    let (w, h) = (view.width, view.height);
    let ldr = ldr_image(w, h, hdr, exposure);
    match jpeg_quality {
        Some(q) => imageio::write_jpeg(&root.join(&paths.image), &ldr, q)?,
        None => imageio::write_png(&root.join(&paths.image), &ldr)?,
    }
    if let Some(p) = &paths.hdr {
        imageio::write_exr(&root.join(p), &rgb_image(w, h, hdr))?;
    }
    let (dw, dh) = (depth.width, depth.height);
    if paths.depth.ends_with(".png") {
        imageio::write_png16_raw(&root.join(&paths.depth), dw, dh, 1, &depth_to_mm(&depth.depth))?;
    } else {
        imageio::write_exr(&root.join(&paths.depth), &gray_image(dw, dh, &depth.depth))?;
    }
    if let (Some(p), Some(conf)) = (&paths.confidence, &depth.confidence) {
        // ARKit's raw values 0/1/2 in an 8-bit PNG (k/255 quantizes back to k exactly).
        let levels: Vec<f32> = conf.iter().map(|&c| c as f32 / 255.0).collect();
        imageio::write_png(&root.join(p), &gray_image(dw, dh, &levels))?;
    }
    if let Some(p) = &paths.depth_gt {
        imageio::write_exr(&root.join(p), &gray_image(w, h, &view.depth))?;
    }
    if let Some(p) = &paths.normal {
        imageio::write_exr(&root.join(p), &rgb_image(w, h, &view.normal))?;
    }
    if let Some(p) = &paths.mask {
        let mask: Vec<f32> = view.emitter_mask.iter().map(|&m| if m { 1.0 } else { 0.0 }).collect();
        imageio::write_png(&root.join(p), &gray_image(w, h, &mask))?;
    }
    imageio::write_exr(&root.join(&paths.kd), &rgb_image(w, h, &view.kd))?;
    imageio::write_exr(&root.join(&paths.ks), &rgb_image(w, h, &view.ks))?;
    imageio::write_exr(&root.join(&paths.roughness), &gray_image(w, h, &view.roughness))?;
    Ok(())
}
