//! The report's renders, all through the crates that `render`, `eval` and `edit` use: the
//! radiance field's view of the test camera (`render_volume_view`), stage 2's Monte Carlo
//! re-render with its material maps (`rerender_view`), the recovered surface shaded by normal,
//! and the relit sets and a mirror edit path traced by the edit renderer (`RecoveredScene`), with
//! the differential and ratio composites beside them.

use crate::html::{colour_bar, esc, format_sig, grid_row, Assets, Cell};
use crate::images::{abs_error, depth_display, depth_error, depth_far, normal_display, normal_error, ErrorMap};
use glam::{DVec3, Vec3};
use i2sdf_data::imageio::tone_map_srgb;
use i2sdf_data::{Bounds, Camera, DataError, Dataset, EditSpec, Frame, ImageF32};
use i2sdf_edit::{edit_images, light_gains, EditedScene};
use i2sdf_eval::relight::{edited_view, read_specs, score_relit_sets, set_name, RelitFrame, RelitScoring};
use i2sdf_eval::{psnr, ImageRef};
use i2sdf_model::images::{render_volume_view, rerender_ldr, rgb_map};
use i2sdf_model::intrinsic_io::IntrinsicFields;
use i2sdf_model::renderer::RenderSettings;
use i2sdf_model::{rerender_view, FrozenScene, NeuralScene};
use i2sdf_render::{Geometry, Ray};
use rayon::prelude::*;
use std::fmt::Write as _;

/// Renders shared between the sections: the radiance field's view of a camera (stage 1's map,
/// the differential's captured image) and the unedited scene's path-traced render, kept by eval's
/// relight scoring so that the relit sets and the mirror edit render each camera once.
pub use i2sdf_eval::relight::SharedRenders as RenderCache;

/// PSNR of two same-sized 3-channel images (None when it cannot be computed).
fn psnr_of(a: &ImageF32, b: &ImageF32) -> Option<f64> {
    if (a.width, a.height, a.channels) != (b.width, b.height, b.channels) {
        return None;
    }
    let p = ImageRef::new(&a.data, a.width, a.height, a.channels).ok()?;
    let g = ImageRef::new(&b.data, b.width, b.height, b.channels).ok()?;
    psnr(p, g, None).ok().flatten().map(|x| x.min(100.0))
}

fn gray3(img: &ImageF32) -> ImageF32 {
    if img.channels == 3 {
        return img.clone();
    }
    let data = img.data.iter().flat_map(|&v| [v; 3]).collect();
    ImageF32::from_data(img.width, img.height, 3, data)
}

/// One GT | ours | error row. `gt`, `ours` are display images; `err` the error map with its
/// range (fixed where the quantity has a natural one, else its 99th percentile) and unit.
struct Triple<'a> {
    key: &'a str,
    label: &'a str,
    gt: Option<ImageF32>,
    ours: ImageF32,
    err: Option<ErrorMap>,
    range: Option<f32>,
    unit: &'a str,
}

fn triple_row(assets: &mut Assets, t: Triple) -> Result<String, DataError> {
    let gt_cell = match &t.gt {
        Some(g) => Cell::img("ground truth", assets.png(&format!("{}_gt", t.key), g)?),
        None => Cell::missing("ground truth", "no ground truth in the dataset"),
    };
    let ours = Cell::img("ours", assets.png(&format!("{}_ours", t.key), &t.ours)?);
    let (err_cell, note) = match &t.err {
        Some(e) => {
            let max = t.range.unwrap_or_else(|| e.p99()).max(1e-6);
            let src = assets.png(&format!("{}_err", t.key), &e.heat(max))?;
            let mean = e.mean().map_or("—".into(), format_sig);
            (
                Cell::img("error", src),
                format!(
                    "error: {}; mean {} {}",
                    colour_bar(max, t.unit),
                    esc(&mean),
                    esc(t.unit)
                ),
            )
        }
        None => (Cell::missing("error", "no ground truth to compare with"), String::new()),
    };
    Ok(grid_row(t.label, &[gt_cell, ours, err_cell], &note))
}

/// Stage 1's maps of `frame`: RGB, depth, normals, emitter probability, each beside its ground
/// truth with the error.
pub fn stage1_grid(
    assets: &mut Assets,
    scene: &NeuralScene,
    settings: &RenderSettings,
    frame: &Frame,
    cache: &mut RenderCache,
) -> Result<String, DataError> {
    let v = render_volume_view(scene, settings, &frame.camera);
    cache.insert_captured(&frame.camera, v.rgb.clone());
    let mut s = String::new();
    s.push_str(&triple_row(
        assets,
        Triple {
            key: "rgb",
            label: "RGB",
            gt: Some(frame.rgb.clone()),
            ours: v.rgb.clone(),
            err: abs_error(&v.rgb, &frame.rgb, None),
            range: None,
            unit: "(|Δ| of LDR values, mean of RGB)",
        },
    )?);
    let far = frame.depth.as_ref().map_or_else(|| depth_far(&v.depth), depth_far);
    s.push_str(&triple_row(
        assets,
        Triple {
            key: "depth",
            label: "depth",
            gt: frame.depth.as_ref().map(|d| depth_display(d, far)),
            ours: depth_display(&v.depth, far),
            err: frame.depth.as_ref().and_then(|d| depth_error(&v.depth, d)),
            range: None,
            unit: "world units (|Δz|)",
        },
    )?);
    s.push_str(&format!(
        "<p class=\"note\">depth shown near = bright over 0 – {} world units</p>",
        format_sig(far as f64)
    ));
    s.push_str(&triple_row(
        assets,
        Triple {
            key: "normal",
            label: "normals",
            gt: frame.normal.as_ref().map(normal_display),
            ours: normal_display(&v.normal),
            err: frame.normal.as_ref().and_then(|n| normal_error(&v.normal, n)),
            range: Some(45.0),
            unit: "degrees",
        },
    )?);
    s.push_str(&triple_row(
        assets,
        Triple {
            key: "emitter",
            label: "emitter mask",
            gt: frame.emitter_mask.as_ref().map(gray3),
            ours: gray3(&v.emitter),
            err: frame.emitter_mask.as_ref().and_then(|m| abs_error(&v.emitter, m, None)),
            range: Some(1.0),
            unit: "(|F_e − mask|)",
        },
    )?);
    Ok(s)
}

/// Stage 2's maps of `frame` from one re-render: Kd, ρ and the re-render itself, each beside its
/// ground truth. Albedo errors are in linear Kd on the pixels that see no GT emitter (as eval's
/// `albedo_psnr`).
pub fn stage2_grid(
    assets: &mut Assets,
    frozen: &FrozenScene,
    fields: &IntrinsicFields,
    frame: &Frame,
    view: u32,
    spp: u32,
) -> Result<String, DataError> {
    let v = rerender_view(frozen, &fields.material, &frame.camera, spp, 0, view, &|| {});
    let kd = rgb_map(v.width, v.height, &v.kd);
    let rough = ImageF32::from_data(v.width, v.height, 1, v.roughness.clone());
    let not_emitter: Option<Vec<bool>> = frame
        .emitter_mask
        .as_ref()
        .map(|m| m.data.iter().map(|&x| x < 0.5).collect());
    let mut s = String::new();
    s.push_str(&triple_row(
        assets,
        Triple {
            key: "albedo",
            label: "albedo Kd",
            gt: frame.albedo.as_ref().map(|a| tone_map_srgb(a, 1.0)),
            ours: tone_map_srgb(&kd, 1.0),
            err: frame
                .albedo
                .as_ref()
                .and_then(|a| abs_error(&kd, a, not_emitter.as_deref())),
            range: None,
            unit: "(|Δ| linear Kd, mean of RGB; emitters excluded)",
        },
    )?);
    s.push_str(&triple_row(
        assets,
        Triple {
            key: "roughness",
            label: "roughness ρ",
            gt: frame.roughness.as_ref().map(gray3),
            ours: gray3(&rough),
            err: frame
                .roughness
                .as_ref()
                .and_then(|r| abs_error(&rough, r, not_emitter.as_deref())),
            range: Some(1.0),
            unit: "(|Δρ|; emitters excluded)",
        },
    )?);
    let rerender = rerender_ldr(&v, &fields.radiometry);
    let p = psnr_of(&rerender, &frame.rgb).map_or("—".into(), format_sig);
    s.push_str(&triple_row(
        assets,
        Triple {
            key: "rerender",
            label: &format!("re-render ({spp} spp, {p} dB)"),
            gt: Some(frame.rgb.clone()),
            err: abs_error(&rerender, &frame.rgb, None),
            ours: rerender,
            range: None,
            unit: "(|Δ| of LDR values, mean of RGB)",
        },
    )?);
    Ok(s)
}

/// A camera inside the room near a top corner, looking across at the opposite lower side: an
/// overview of the whole surface (the scene's up is +y, as the datasets' are).
pub fn overview_camera(bounds: &Bounds, width: usize, height: usize) -> Camera {
    let (lo, hi) = (DVec3::from(bounds.min), DVec3::from(bounds.max));
    let c = 0.5 * (lo + hi);
    let h = 0.5 * (hi - lo);
    let eye = c + DVec3::new(0.8 * h.x, 0.7 * h.y, 0.8 * h.z);
    let target = c + DVec3::new(-0.3 * h.x, -0.6 * h.y, -0.3 * h.z);
    // 75° horizontal field of view.
    let f = 0.5 * width as f64 / (37.5f64.to_radians()).tan();
    Camera {
        lens: Default::default(),
        width,
        height,
        fx: f,
        fy: f,
        cx: 0.5 * width as f64,
        cy: 0.5 * height as f64,
        c2w: i2sdf_data::camera::look_at(eye, target, DVec3::Y),
    }
}

/// The surface seen from `camera`, coloured by its normal ((n + 1) / 2, dimmed by the angle to
/// the view so the shape reads); background black.
pub fn normal_shaded(geometry: &dyn Geometry, camera: &Camera) -> ImageF32 {
    let (w, h) = (camera.width, camera.height);
    let mut out = ImageF32::new(w, h, 3);
    let o = camera.center().as_vec3();
    out.data.par_chunks_mut(3 * w).enumerate().for_each(|(j, row)| {
        let rays: Vec<Ray> = (0..w)
            .map(|i| {
                let (_, d, _) = camera.ray(i as f64 + 0.5, j as f64 + 0.5);
                Ray::new(o, d.as_vec3(), 0.0, f32::INFINITY)
            })
            .collect();
        let mut hits = vec![None; w];
        geometry.intersect(&rays, &mut hits);
        for (i, hit) in hits.iter().enumerate() {
            if let Some(hit) = hit {
                let mut n = hit.normal;
                if n.dot(rays[i].dir) > 0.0 {
                    n = -n;
                }
                let shade = 0.45 + 0.55 * n.dot(-rays[i].dir).max(0.0);
                let c = (n + Vec3::ONE) * 0.5 * shade;
                row[i * 3..i * 3 + 3].copy_from_slice(&c.to_array());
            }
        }
    });
    out
}

/// Where a relit or edited view is rendered, and how: eval's relight scoring (the recovered
/// scene, the radiance field's settings for the differential, the path tracer's settings) and
/// the unedited scene.
pub struct EditContext<'r, 'a> {
    pub scoring: RelitScoring<'r, 'a>,
    pub unedited: EditedScene,
}

fn psnr_caption(what: &str, img: &ImageF32, gt: &ImageF32) -> String {
    psnr_of(img, gt).map_or_else(|| what.to_string(), |p| format!("{what}, {} dB", format_sig(p)))
}

/// The dataset's relit sets, the first frame of each: GT | path traced | differential | ratio. The
/// frames are rendered and scored by eval's relight scoring itself (`ctx.scoring` selects the
/// first frame of each set), so with eval's settings the captions are the figures `eval` gives
/// these frames (`relight.sets.NAME.per_frame` in its metrics).
pub fn relight_grid(
    assets: &mut Assets,
    ctx: &EditContext,
    cache: &mut RenderCache,
    dataset: &Dataset,
) -> Result<String, DataError> {
    let specs = read_specs(dataset)?;
    let mut rows = String::new();
    let mut saved: Result<(), DataError> = Ok(());
    let mut on_frame = |f: RelitFrame| {
        if saved.is_err() {
            return;
        }
        let set = &dataset.relight[f.set];
        let name = set_name(set, f.set);
        let safe: String = name
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
            .collect();
        let caption = |what: &str, p: Option<f64>| {
            p.map_or_else(|| what.to_string(), |p| format!("{what}, {} dB", format_sig(p)))
        };
        let stem = format!("relight_{}_{safe}", f.set);
        let cells = (|| -> Result<_, DataError> {
            let gt = Cell::img("ground truth (relit)", assets.png(&format!("{stem}_gt"), &f.frame.rgb)?);
            let traced = Cell::img(
                caption("path traced", f.figures.psnr),
                assets.png(&format!("{stem}_traced"), f.traced)?,
            );
            let diff = match f.differential {
                Some(d) => Cell::img(
                    caption("differential", f.figures.psnr_differential),
                    assets.png(&format!("{stem}_diff"), d)?,
                ),
                None => Cell::missing("differential", "no radiance field settings"),
            };
            let ratio = match f.ratio {
                Some(r) => Cell::img(
                    caption("ratio", f.figures.psnr_ratio),
                    assets.png(&format!("{stem}_ratio"), r)?,
                ),
                None => Cell::missing("ratio", "no radiance field settings"),
            };
            Ok([gt, traced, diff, ratio])
        })();
        match cells {
            Ok(cells) => {
                let note = format!("frame {} of {}", esc(&f.frame.name), set.frames.len());
                rows.push_str(&grid_row(&name.replace('_', " "), &cells, &note));
            }
            Err(e) => saved = Err(e),
        }
    };
    score_relit_sets(&ctx.scoring, dataset, &specs, cache, &|| {}, &mut on_frame)?;
    saved?;
    Ok(rows)
}

/// The wall the camera faces (the bounds' side along its dominant horizontal viewing axis) made
/// a mirror: a thin box around that side of the bounds.
pub fn mirror_spec(bounds: &Bounds, camera: &Camera) -> (EditSpec, String, String) {
    let fwd = camera.rotation() * DVec3::Z;
    let axis = if fwd.x.abs() >= fwd.z.abs() { 0 } else { 2 };
    let positive = fwd[axis] > 0.0;
    let (mut lo, mut hi) = (DVec3::from(bounds.min), DVec3::from(bounds.max));
    let ext = hi - lo;
    let pad = 0.1 * ext.max_element();
    let depth = 0.04 * ext[axis];
    let wall = if positive { hi[axis] } else { lo[axis] };
    // The other axes: the whole wall, floor to ceiling, but not the floor and ceiling themselves.
    lo -= DVec3::splat(pad);
    hi += DVec3::splat(pad);
    lo.y = bounds.min[1] + 0.03 * ext.y;
    hi.y = bounds.max[1] - 0.03 * ext.y;
    if positive {
        lo[axis] = wall - depth;
        hi[axis] = wall + pad;
    } else {
        lo[axis] = wall - pad;
        hi[axis] = wall + depth;
    }
    let name = format!("the {}{} wall", if positive { "+" } else { "−" }, ["x", "y", "z"][axis]);
    let text = format!(
        "[[op]]\nkind = \"material\"\nbox = {{ lo = [{}, {}, {}], hi = [{}, {}, {}] }}\npreset = \"mirror\"\n",
        lo.x, lo.y, lo.z, hi.x, hi.y, hi.z
    );
    let spec = EditSpec::from_toml_str(&text, std::path::Path::new("mirror.toml")).expect("a valid generated spec");
    (spec, name, text)
}

/// The view index of the mirror edit's camera when no relit set renders it.
const MIRROR_VIEW: u32 = 2000;

/// A mirror edit of the wall the test camera faces: unedited | path traced | differential (no
/// ground truth exists for this edit).
pub fn mirror_grid(
    assets: &mut Assets,
    ctx: &EditContext,
    cache: &mut RenderCache,
    bounds: &Bounds,
    frame: &Frame,
) -> Result<String, DataError> {
    let (spec, wall, text) = mirror_spec(bounds, &frame.camera);
    let r = ctx.scoring.recovered;
    let mirror = r.edited(&spec, &Default::default());
    let gains = light_gains(&spec, &mirror);
    // A view index of its own when the test camera is not one of the relit sets' (whose
    // indices count from 0).
    let view = edited_view(
        &ctx.scoring,
        &ctx.unedited,
        Some(&mirror),
        &gains,
        cache,
        &frame.camera,
        MIRROR_VIEW,
        &|| {},
    );
    let (traced, diff) = (view.traced, view.differential);
    let (base, _) = cache.unedited(
        r,
        &ctx.unedited,
        &frame.camera,
        ctx.scoring.settings,
        MIRROR_VIEW,
        &|| {},
    );
    let (_, plain) = edit_images(base, &vec![Vec3::ONE; base.emitters], &r.radiometry);
    let diff_cell = match &diff {
        Some(d) => Cell::img("mirror, differential", assets.png("mirror_diff", d)?),
        None => Cell::missing("mirror, differential", "no radiance field settings"),
    };
    let cells = [
        Cell::img(
            psnr_caption("unedited, path traced (vs test image)", &plain, &frame.rgb),
            assets.png("mirror_unedited", &plain)?,
        ),
        Cell::img("mirror, path traced", assets.png("mirror_traced", &traced)?),
        diff_cell,
    ];
    let mut s = grid_row(
        "mirror edit",
        &cells,
        &format!("{} set to the mirror preset; no ground truth", esc(&wall)),
    );
    let _ = write!(
        s,
        "<details><summary>edit spec</summary><pre>{}</pre></details>",
        esc(&text)
    );
    Ok(s)
}
