//! The image products of a trained run, in one place for `render`, `eval`, `report` and `edit`:
//! volume rendering whole views of a [`NeuralScene`] (colour as the radiance field predicts it,
//! the dataset's LDR encoding; z-depth in world units; world-space normals; the emitter
//! probability), and the images of stage 2's Monte Carlo re-render (`rerender_view`): its HDR
//! image and the dataset's tone mapping of it, the material maps, the emission map. `render`
//! writes the [`MapImage`]s of [`stage1_maps`] and [`stage2_maps`]. (The Monte Carlo renderer of
//! stage 2 and the editor lives in `i2sdf_render`.)

use crate::emitters::EmitterTable;
use crate::intrinsic::{rerender_view, FrozenScene};
use crate::intrinsic_io::IntrinsicFields;
use crate::renderer::{self, RenderSettings, RenderWorkspace};
use crate::scene::NeuralScene;
use glam::{DVec3, Vec3};
use i2sdf_data::{imageio, Camera, ImageF32, Radiometry};
use i2sdf_render::ViewRender;

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

/// The re-render's HDR image (all emitters at their L\[k\], plus F_c's slot), linear image units,
/// 3 channels.
pub fn rerender_hdr(v: &ViewRender) -> ImageF32 {
    let gains = vec![Vec3::ONE; v.emitters];
    rgb_map(v.width, v.height, &v.hdr(&gains))
}

/// The re-render tone-mapped with the dataset's transfer ([`Radiometry::encode_image`]):
/// comparable with its LDR images (what `eval` scores and `report` shows).
pub fn rerender_ldr(v: &ViewRender, radiometry: &Radiometry) -> ImageF32 {
    radiometry.encode_image(&rerender_hdr(v))
}

/// Per-pixel RGB values (Kd, Ks, radiance) as a 3-channel image.
pub fn rgb_map(width: usize, height: usize, values: &[Vec3]) -> ImageF32 {
    ImageF32::from_data(width, height, 3, values.iter().flat_map(|c| c.to_array()).collect())
}

/// L\[k\] where the pixel-centre ray sees an emitter (the re-render's emitter mask), else 0: k is
/// `table.index` of the seen point (backprojected from the z-depth), else the nearest centre.
pub fn emission_map(v: &ViewRender, camera: &Camera, table: &EmitterTable, margin: f64) -> ImageF32 {
    let mut out = ImageF32::new(v.width, v.height, 3);
    if table.is_empty() {
        return out;
    }
    for y in 0..v.height {
        for x in 0..v.width {
            let i = y * v.width + x;
            if !v.emitter_mask[i] || !v.depth[i].is_finite() {
                continue;
            }
            let p = camera.backproject(x, y, v.depth[i] as f64);
            let k = table.index(p, margin).unwrap_or_else(|| nearest_centre(table, p));
            out.data[i * 3..i * 3 + 3].copy_from_slice(&table.emission(k).to_array());
        }
    }
    out
}

fn nearest_centre(table: &EmitterTable, p: DVec3) -> usize {
    (0..table.len())
        .min_by(|&a, &b| {
            let d = |k: usize| DVec3::from_array(table.emitters[k].centre).distance_squared(p);
            d(a).total_cmp(&d(b))
        })
        .expect("a non-empty table")
}

/// The maps of stage 1 (the volume renderer), as `render --what` names them.
pub const STAGE1_MAPS: [&str; 4] = ["rgb", "depth", "normal", "emitter"];
/// The maps of stage 2 (one Monte Carlo re-render per view).
pub const STAGE2_MAPS: [&str; 5] = ["albedo", "specular", "roughness", "emission", "rerender"];

/// One map of one view: the PNG (display values) and, for a quantity, its EXR.
pub struct MapImage {
    /// Its name in [`STAGE1_MAPS`] or [`STAGE2_MAPS`] (the folder `render` writes it to).
    pub map: &'static str,
    pub png: ImageF32,
    pub exr: Option<ImageF32>,
}

/// Stage 1's maps of `camera` among `what`: `rgb` (LDR as the dataset stores it), `depth`
/// (z-depth, world units; PNG near = bright), `normal` (world-space; PNG (n + 1)/2), `emitter`
/// (probability).
pub fn stage1_maps(scene: &NeuralScene, settings: &RenderSettings, camera: &Camera, what: &[&str]) -> Vec<MapImage> {
    stage1_maps_of(&render_volume_view(scene, settings, camera), what)
}

/// [`stage1_maps`] of a view already rendered (`eval` writes the views it scored).
pub fn stage1_maps_of(v: &RenderedView, what: &[&str]) -> Vec<MapImage> {
    let mut normal = v.normal.clone();
    normal.data.iter_mut().for_each(|x| *x = 0.5 * (*x + 1.0));
    let maps = [
        ("rgb", v.rgb.clone(), None),
        ("depth", depth_preview(&v.depth), Some(v.depth.clone())),
        ("normal", normal, Some(v.normal.clone())),
        ("emitter", v.emitter.clone(), None),
    ];
    wanted(maps, what)
}

/// Stage 2's maps of `camera` among `what`, from one re-render of `frozen` (`spp` paths per
/// pixel, sampler view index `view`; `on_row` after each row): `albedo`, `specular` (Kd, Ks:
/// linear EXR, sRGB PNG), `roughness` (ρ as is), `emission` ([`emission_map`]) and `rerender`
/// ([`rerender_hdr`]), the last two with PNGs in the dataset's tone mapping.
pub fn stage2_maps(
    frozen: &FrozenScene,
    fields: &IntrinsicFields,
    camera: &Camera,
    (spp, view): (u32, u32),
    what: &[&str],
    on_row: &(dyn Fn() + Sync),
) -> Vec<MapImage> {
    let v = rerender_view(frozen, &fields.material, camera, spp, 0, view, on_row);
    stage2_maps_of(&v, frozen, fields, camera, what)
}

/// [`stage2_maps`] of a re-render already made (`v`, of `camera`): `eval` writes the re-renders
/// it scored.
pub fn stage2_maps_of(
    v: &ViewRender,
    frozen: &FrozenScene,
    fields: &IntrinsicFields,
    camera: &Camera,
    what: &[&str],
) -> Vec<MapImage> {
    let rm = &fields.radiometry;
    let kd = rgb_map(v.width, v.height, &v.kd);
    let ks = rgb_map(v.width, v.height, &v.ks);
    let rough = ImageF32::from_data(v.width, v.height, 1, v.roughness.clone());
    let emission = emission_map(v, camera, &fields.emitters, frozen.index_margin);
    let hdr = rerender_hdr(v);
    let maps = [
        ("albedo", imageio::tone_map_srgb(&kd, 1.0), Some(kd)),
        ("specular", imageio::tone_map_srgb(&ks, 1.0), Some(ks)),
        ("roughness", rough.clone(), Some(rough)),
        ("emission", rm.encode_image(&emission), Some(emission)),
        ("rerender", rm.encode_image(&hdr), Some(hdr)),
    ];
    wanted(maps, what)
}

/// Writes a view's maps as `render` lays them out: `DIR/MAP/NAME.png`, and `DIR/MAP/NAME.exr`
/// where the map has one (each map's folder created).
pub fn write_maps(dir: &std::path::Path, name: &str, maps: &[MapImage]) -> Result<(), i2sdf_data::DataError> {
    for m in maps {
        let file = |ext: &str| dir.join(m.map).join(format!("{name}.{ext}"));
        if let Some(exr) = &m.exr {
            imageio::write_exr(&file("exr"), exr)?;
        }
        imageio::write_png(&file("png"), &m.png)?;
    }
    Ok(())
}

fn wanted<const N: usize>(maps: [(&'static str, ImageF32, Option<ImageF32>); N], what: &[&str]) -> Vec<MapImage> {
    maps.into_iter()
        .filter(|(m, _, _)| what.contains(m))
        .map(|(map, png, exr)| MapImage { map, png, exr })
        .collect()
}

/// Depth scaled to [0, 1] by the view's own 99th percentile, near = bright.
pub fn depth_preview(depth: &ImageF32) -> ImageF32 {
    let mut sorted: Vec<f32> = depth.data.iter().copied().filter(|d| d.is_finite()).collect();
    sorted.sort_by(f32::total_cmp);
    let far = sorted.get(sorted.len() * 99 / 100).copied().unwrap_or(1.0).max(1e-6);
    let mut out = depth.clone();
    out.data.iter_mut().for_each(|d| *d = 1.0 - (*d / far).clamp(0.0, 1.0));
    out
}
