//! Writing one rendered view in the native format (the README's "Dataset formats"): LDR PNG (sRGB of
//! clamp(exposure · HDR, 0, 1)), HDR RGB EXR, z-depth EXR (channel Y, metres), world-space normal
//! EXR, emitter mask PNG (255 = emitter), and the GT material maps Kd, Ks (RGB EXR) and roughness
//! ρ (EXR, channel Y).

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
    ImageF32::from_data(
        w,
        h,
        3,
        hdr.iter()
            .flat_map(|p| p.to_array())
            .map(|v| imageio::linear_to_srgb((v * exposure).clamp(0.0, 1.0)))
            .collect(),
    )
}

/// Paths of one frame's files, relative to the scene directory.
#[derive(Clone, Debug)]
pub struct FramePaths {
    pub image: String,
    pub hdr: String,
    pub depth: String,
    pub depth_gt: Option<String>,
    pub normal: String,
    pub mask: String,
    pub kd: String,
    pub ks: String,
    pub roughness: String,
}

impl FramePaths {
    pub fn new(stem: &str, keep_clean_depth: bool) -> Self {
        FramePaths {
            image: format!("images/{stem}.png"),
            hdr: format!("hdr/{stem}.exr"),
            depth: format!("depth/{stem}.exr"),
            depth_gt: keep_clean_depth.then(|| format!("depth_gt/{stem}.exr")),
            normal: format!("normal/{stem}.exr"),
            mask: format!("mask/{stem}.png"),
            kd: format!("material/{stem}_kd.exr"),
            ks: format!("material/{stem}_ks.exr"),
            roughness: format!("material/{stem}_roughness.exr"),
        }
    }
}

/// Writes every file of one view. `depth` is what the dataset calls depth (noisy when a noise
/// model is on); the clean z-depth goes to `depth_gt` when the paths ask for it.
pub fn write_view(
    root: &Path,
    paths: &FramePaths,
    view: &ViewRender,
    hdr: &[Vec3],
    depth: &[f32],
    exposure: f32,
) -> Result<(), DataError> {
    let (w, h) = (view.width, view.height);
    imageio::write_png(&root.join(&paths.image), &ldr_image(w, h, hdr, exposure))?;
    imageio::write_exr(&root.join(&paths.hdr), &rgb_image(w, h, hdr))?;
    imageio::write_exr(&root.join(&paths.depth), &gray_image(w, h, depth))?;
    if let Some(p) = &paths.depth_gt {
        imageio::write_exr(&root.join(p), &gray_image(w, h, &view.depth))?;
    }
    imageio::write_exr(&root.join(&paths.normal), &rgb_image(w, h, &view.normal))?;
    let mask: Vec<f32> = view.emitter_mask.iter().map(|&m| if m { 1.0 } else { 0.0 }).collect();
    imageio::write_png(&root.join(&paths.mask), &gray_image(w, h, &mask))?;
    imageio::write_exr(&root.join(&paths.kd), &rgb_image(w, h, &view.kd))?;
    imageio::write_exr(&root.join(&paths.ks), &rgb_image(w, h, &view.ks))?;
    imageio::write_exr(&root.join(&paths.roughness), &gray_image(w, h, &view.roughness))?;
    Ok(())
}
