//! Volume rendering whole views of a [`NeuralScene`] (for `render`, `eval` and training previews):
//! colour as the radiance field predicts it (the dataset's LDR encoding), z-depth in world units,
//! world-space normals and the emitter probability. (The Monte Carlo renderer of stage 2 and the
//! editor lives in `i2sdf_render`.)

use crate::renderer::{self, RenderSettings, RenderWorkspace};
use crate::scene::NeuralScene;
use i2sdf_data::{Camera, ImageF32};

/// The maps of one rendered view.
pub struct RenderedView {
    /// 3 channels, LDR as the training images store it.
    pub rgb: ImageF32,
    /// 1 channel, z-depth in world units.
    pub depth: ImageF32,
    /// 3 channels, unit world-space normals (rendered Σ w n̂, renormalized).
    pub normal: ImageF32,
    /// 1 channel, emitter probability.
    pub emitter: ImageF32,
    /// 1 channel, accumulated opacity.
    pub opacity: ImageF32,
}

/// Volume-renders every pixel of `camera` (pixel centres), deterministically, in chunks of rays.
pub fn render_volume_view(scene: &NeuralScene, settings: &RenderSettings, camera: &Camera) -> RenderedView {
    let (w, h) = (camera.width, camera.height);
    let norm = &scene.normalization;
    let o = norm.to_normalized(camera.center());
    let origin = [o.x as f32, o.y as f32, o.z as f32];
    let mut view = RenderedView {
        rgb: ImageF32::new(w, h, 3),
        depth: ImageF32::new(w, h, 1),
        normal: ImageF32::new(w, h, 3),
        emitter: ImageF32::new(w, h, 1),
        opacity: ImageF32::new(w, h, 1),
    };
    let mut ws = RenderWorkspace::default();
    let pixels: Vec<usize> = (0..w * h).collect();
    for chunk in pixels.chunks(4096) {
        let mut dirs = Vec::with_capacity(chunk.len());
        let mut cos = Vec::with_capacity(chunk.len());
        for &p in chunk {
            let (_, d, c) = camera.ray((p % w) as f64 + 0.5, (p / w) as f64 + 0.5);
            dirs.push([d.x as f32, d.y as f32, d.z as f32]);
            cos.push(c);
        }
        let origins = vec![origin; chunk.len()];
        renderer::forward::<rand_pcg::Pcg64>(scene, settings, &origins, &dirs, &[], &mut ws, None);
        let out = &ws.out;
        for (q, &p) in chunk.iter().enumerate() {
            view.rgb.data[p * 3..p * 3 + 3].copy_from_slice(&out.rgb[q * 3..q * 3 + 3]);
            // Expected ray distance, normalized by the opacity so a partly transparent ray does not
            // pull the depth towards the camera, then to z-depth in world units.
            let t = out.depth[q] / out.opacity[q].max(1e-6);
            view.depth.data[p] = (t as f64 * cos[q] * norm.scale) as f32;
            let n = &out.normal[q * 3..q * 3 + 3];
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt().max(1e-8);
            for c in 0..3 {
                view.normal.data[p * 3 + c] = n[c] / len;
            }
            view.emitter.data[p] = out.emitter[q];
            view.opacity.data[p] = out.opacity[q];
        }
    }
    view
}
