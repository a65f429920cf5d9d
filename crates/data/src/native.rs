//! The native format (docs/DATASETS.md, format 1): a nerfstudio-style `transforms.json`.
//!
//! Cameras: `fl_x fl_y cx cy w h` at the top level or per frame (per-frame values win),
//! `camera_model` (PINHOLE by default; SIMPLE_PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV,
//! OPENCV_FISHEYE) with its coefficients `k1 k2 k3 k4 p1 p2` (see `lens`), `transform_matrix` = camera-to-world in the
//! OpenGL convention, principal point in the pixel-centre-at-+0.5 convention (nerfstudio's).
//! Per frame: `file_path` (LDR PNG or EXR), optional `hdr_file_path`, `depth_file_path` (z-depth in
//! world units: EXR or `.npy` float32, or 16-bit PNG times `depth_unit_scale_factor`, default
//! 0.001; at the image's resolution or another one of the same aspect, mapped onto the image's
//! pixels), `confidence_file_path` (per depth sample 0/1/2, at the depth map's resolution; samples
//! below the top-level `depth_confidence_min`, default 1, are dropped; see `sensor_depth`),
//! `normal_file_path` (world-space unit normals), `emitter_mask_path`, `split`, and the GT
//! material maps `albedo_file_path`, `specular_file_path`, `roughness_file_path`. Splits come from
//! `split`, else from nerfstudio's top-level `train_filenames` / `test_filenames`; a dataset with
//! neither holds out every 8th frame (0, 8, 16, …) for testing. Top level, optional: `mesh_path`,
//! `relight: [{spec, frames}]`, `ldr: {transfer: "srgb"|"linear"}`, `objects: [{id, name, tags}]`
//! (the GT mesh's per-face `object_id`s, named and tagged), `poses_exact` (true: the poses are
//! exact and training does not correct them; default false), `depth_exact` (true: the depth maps are
//! exact, as rendered ones are, and training does not model a sensor's noise; default false).
//! Unknown keys are ignored.

use crate::camera::{validate_rigid, Camera, Lens};
use crate::dataset::{self, Dataset, Format, Frame, GtEmitter, ObjectInfo, RelightSet, Split};
use crate::error::{DataError, Result};
use crate::radiometry::{Radiometry, Transfer};
use crate::sensor_depth::{self, Confidence, DepthDropped};
use glam::DMat4;
use rayon::prelude::*;
use serde_json::{Map, Value};
use std::collections::HashSet;
use std::path::{Path, PathBuf};

/// Where a frame entry sits in the JSON, for error messages: `frames[3]` or `relight[0].frames[1]`.
struct Ctx<'a> {
    json: &'a Path,
    entry: String,
}

impl Ctx<'_> {
    fn err(&self, field: &str, msg: impl Into<String>) -> DataError {
        DataError::field(self.json, format!("{}.{field}", self.entry), msg)
    }
}

fn get_f64(obj: &Map<String, Value>, top: &Map<String, Value>, key: &str, ctx: &Ctx) -> Result<f64> {
    let v = obj.get(key).or_else(|| top.get(key));
    match v {
        Some(v) => v
            .as_f64()
            .filter(|x| x.is_finite())
            .ok_or_else(|| ctx.err(key, format!("expected a finite number, found {v}"))),
        None => Err(ctx.err(key, "missing (needed at the top level or in the frame)")),
    }
}

fn parse_matrix(v: Option<&Value>, ctx: &Ctx) -> Result<DMat4> {
    let rows = v
        .and_then(Value::as_array)
        .ok_or_else(|| ctx.err("transform_matrix", "missing or not a 4×4 array"))?;
    if rows.len() != 4 && rows.len() != 3 {
        return Err(ctx.err("transform_matrix", format!("expected 4 rows, found {}", rows.len())));
    }
    let mut m = [[0.0f64; 4]; 4];
    m[3] = [0.0, 0.0, 0.0, 1.0];
    for (i, row) in rows.iter().enumerate() {
        let row = row
            .as_array()
            .filter(|r| r.len() == 4)
            .ok_or_else(|| ctx.err("transform_matrix", format!("row {i} is not 4 numbers")))?;
        for (j, x) in row.iter().enumerate() {
            m[i][j] = x
                .as_f64()
                .ok_or_else(|| ctx.err("transform_matrix", format!("entry [{i}][{j}] is not a number")))?;
        }
    }
    // JSON is row-major; glam is column-major.
    Ok(DMat4::from_cols_array_2d(&m).transpose())
}

fn camera_of(obj: &Map<String, Value>, top: &Map<String, Value>, ctx: &Ctx) -> Result<Camera> {
    let model = match obj.get("camera_model").or_else(|| top.get("camera_model")) {
        None | Some(Value::Null) => "PINHOLE",
        Some(Value::String(m)) => m.as_str(),
        Some(v) => return Err(ctx.err("camera_model", format!("expected a model name, found {v}"))),
    };
    for k in ["k1", "k2", "k3", "k4", "p1", "p2"] {
        if let Some(v) = obj.get(k).or_else(|| top.get(k)) {
            if !v.is_null() && v.as_f64().is_none() {
                return Err(ctx.err(k, format!("expected a number, found {v}")));
            }
        }
    }
    let lens = Lens::from_model(model, |k| obj.get(k).or_else(|| top.get(k)).and_then(Value::as_f64))
        .map_err(|(key, m)| ctx.err(key, m))?;
    let w = get_f64(obj, top, "w", ctx)?;
    let h = get_f64(obj, top, "h", ctx)?;
    if w < 1.0 || h < 1.0 || w.fract() != 0.0 || h.fract() != 0.0 {
        return Err(ctx.err("w", format!("image size {w}×{h} is not a positive integer size")));
    }
    let fx = get_f64(obj, top, "fl_x", ctx)?;
    let fy = match get_f64(obj, top, "fl_y", ctx) {
        Ok(v) => v,
        Err(_) if !obj.contains_key("fl_y") && !top.contains_key("fl_y") => fx,
        Err(e) => return Err(e),
    };
    let cx = get_f64(obj, top, "cx", ctx).unwrap_or(w / 2.0);
    let cy = get_f64(obj, top, "cy", ctx).unwrap_or(h / 2.0);
    let c2w = parse_matrix(obj.get("transform_matrix"), ctx)?;
    let cam = Camera {
        lens,
        ..Camera::from_opengl_c2w(w as usize, h as usize, fx, fy, cx, cy, c2w)
    };
    cam.validate_intrinsics().map_err(|(name, m)| {
        let key = match name {
            "fx" => "fl_x",
            "fy" => "fl_y",
            "width" => "w",
            "distortion" => "camera_model",
            other => other,
        };
        ctx.err(key, m)
    })?;
    validate_rigid(&cam.c2w).map_err(|m| ctx.err("transform_matrix", m))?;
    Ok(cam)
}

fn opt_path(obj: &Map<String, Value>, key: &str, root: &Path, ctx: &Ctx) -> Result<Option<PathBuf>> {
    match obj.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::String(s)) => Ok(Some(root.join(s))),
        Some(v) => Err(ctx.err(key, format!("expected a path string, found {v}"))),
    }
}

/// How the dataset's depth files are read: the top-level `depth_unit_scale_factor` and
/// `depth_confidence_min`.
#[derive(Clone, Copy)]
struct DepthUnits {
    png_scale: f64,
    confidence_min: u8,
}

impl DepthUnits {
    fn of(json_path: &Path, top: &Map<String, Value>) -> Result<DepthUnits> {
        let png_scale = match top.get("depth_unit_scale_factor") {
            None => 1e-3,
            Some(v) => v
                .as_f64()
                .filter(|s| s.is_finite() && *s > 0.0)
                .ok_or_else(|| DataError::field(json_path, "depth_unit_scale_factor", "not a positive number"))?,
        };
        let confidence_min = match top.get("depth_confidence_min") {
            None | Some(Value::Null) => 1,
            Some(v) => v.as_u64().filter(|c| *c <= 2).map(|c| c as u8).ok_or_else(|| {
                DataError::field(
                    json_path,
                    "depth_confidence_min",
                    format!("expected an integer 0, 1 or 2 (ARKit's low, medium, high), found {v}"),
                )
            })?,
        };
        Ok(DepthUnits {
            png_scale,
            confidence_min,
        })
    }
}

/// Reads one frame entry: camera, image and every annotation it names; also what became of its
/// depth samples.
fn load_frame(
    root: &Path,
    obj: &Map<String, Value>,
    top: &Map<String, Value>,
    ctx: &Ctx,
    split: Split,
    units: DepthUnits,
) -> Result<(Frame, DepthDropped)> {
    let camera = camera_of(obj, top, ctx)?;
    let image_path = opt_path(obj, "file_path", root, ctx)?.ok_or_else(|| ctx.err("file_path", "missing"))?;
    let rgb = dataset::load_rgb(&image_path, &camera)?;
    let path = |k: &str| opt_path(obj, k, root, ctx);
    let hdr = path("hdr_file_path")?
        .map(|p| dataset::load_rgb(&p, &camera))
        .transpose()?;
    let confidence_path = path("confidence_file_path")?;
    let (depth, depth_dropped, depth_low) = match path("depth_file_path")? {
        Some(p) => {
            let confidence = confidence_path.as_deref().map(|path| Confidence {
                path,
                min: units.confidence_min,
            });
            let (depth, dropped, low) = sensor_depth::load_depth(&p, &camera, units.png_scale, confidence)?;
            (Some(depth), dropped, low)
        }
        None if confidence_path.is_some() => {
            return Err(ctx.err("confidence_file_path", "given without a depth_file_path"))
        }
        None => (None, DepthDropped::default(), None),
    };
    let normal = path("normal_file_path")?
        .map(|p| dataset::load_normal(&p, &camera, None))
        .transpose()?;
    let emitter_mask = path("emitter_mask_path")?
        .map(|p| dataset::load_mask(&p, &camera))
        .transpose()?;
    let albedo = path("albedo_file_path")?
        .map(|p| dataset::load_float(&p, &camera, 3, "an albedo map"))
        .transpose()?;
    let specular = path("specular_file_path")?
        .map(|p| dataset::load_float(&p, &camera, 3, "a specular map"))
        .transpose()?;
    let roughness = path("roughness_file_path")?
        .map(|p| dataset::load_float(&p, &camera, 1, "a roughness map"))
        .transpose()?;
    let name = image_path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let frame = Frame {
        name,
        split,
        camera,
        image_path,
        rgb,
        hdr,
        depth,
        depth_low,
        normal,
        emitter_mask,
        material_mask: None,
        albedo,
        specular,
        roughness,
    };
    Ok((frame, depth_dropped))
}

fn normalize_name(s: &str) -> String {
    s.trim_start_matches("./").to_string()
}

fn filename_set(top: &Map<String, Value>, key: &str, json: &Path) -> Result<Option<HashSet<String>>> {
    match top.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::Array(a)) => a
            .iter()
            .enumerate()
            .map(|(i, v)| {
                v.as_str()
                    .map(normalize_name)
                    .ok_or_else(|| DataError::field(json, format!("{key}[{i}]"), "not a string"))
            })
            .collect::<Result<HashSet<_>>>()
            .map(Some),
        Some(v) => Err(DataError::field(
            json,
            key,
            format!("expected a list of file names, found {v}"),
        )),
    }
}

/// Runs `f` over items in parallel and returns the results in order, or the first error in order
/// (so the message a user sees does not depend on thread timing).
pub(crate) fn par_load<T: Sync, R: Send>(items: &[T], f: impl Fn(usize, &T) -> Result<R> + Sync) -> Result<Vec<R>> {
    let results: Vec<Result<R>> = items.par_iter().enumerate().map(|(i, t)| f(i, t)).collect();
    results.into_iter().collect()
}

pub fn load(root: &Path) -> Result<Dataset> {
    let json_path = root.join("transforms.json");
    let text =
        std::fs::read_to_string(&json_path).map_err(|e| DataError::file(&json_path, format!("cannot read: {e}")))?;
    load_from_str(root, &text)
}

/// [`load`] with the text of `root/transforms.json` already in memory (the files it names are
/// read from `root`).
pub fn load_from_str(root: &Path, text: &str) -> Result<Dataset> {
    let json_path = root.join("transforms.json");
    let value: Value =
        serde_json::from_str(text).map_err(|e| DataError::file(&json_path, format!("invalid JSON: {e}")))?;
    let top = value
        .as_object()
        .ok_or_else(|| DataError::file(&json_path, "the top level is not a JSON object"))?;
    let frames_json = top
        .get("frames")
        .and_then(Value::as_array)
        .ok_or_else(|| DataError::field(&json_path, "frames", "missing or not a list"))?;
    if frames_json.is_empty() {
        return Err(DataError::field(&json_path, "frames", "the list is empty"));
    }
    let units = DepthUnits::of(&json_path, top)?;
    let entries = resolve_splits(&json_path, top, frames_json)?;
    let mut depth_dropped = DepthDropped::default();
    let mut frames = Vec::with_capacity(entries.len());
    for (frame, dropped) in par_load(&entries, |i, (obj, split)| {
        let ctx = Ctx {
            json: &json_path,
            entry: format!("frames[{i}]"),
        };
        load_frame(root, obj, top, &ctx, *split, units)
    })? {
        depth_dropped.add(&dropped);
        frames.push(frame);
    }
    dataset::check_splits(&json_path, &frames)?;

    let mesh_path = parse_mesh_path(root, &json_path, top)?;
    let mut relight = load_relight(root, &json_path, top, units, &mut depth_dropped)?;
    let objects = parse_objects(&json_path, top)?;
    let radiometry = parse_ldr(&json_path, top)?;
    let poses_exact = parse_declaration(&json_path, top, "poses_exact")?;
    let depth_exact = parse_declaration(&json_path, top, "depth_exact")?;
    let emitters = parse_emitters(&json_path, top)?;
    let (bounds, bounds_source, normalization) = dataset::measure_bounds(&frames);
    let relight_frames = relight.iter_mut().flat_map(|r| r.frames.iter_mut());
    sensor_depth::apply_validity_window(
        frames.iter_mut().chain(relight_frames),
        &normalization,
        &mut depth_dropped,
    );
    Ok(Dataset {
        root: root.to_path_buf(),
        format: Format::Native,
        frames,
        radiometry,
        poses_exact,
        depth_exact,
        emitters,
        mesh_path,
        relight,
        objects,
        bounds,
        bounds_source,
        normalization,
        depth_dropped,
        colmap_scale: None,
    })
}

/// Each frame entry with its split, resolved before anything is loaded so that a split error costs
/// no I/O.
fn resolve_splits<'a>(
    json_path: &Path,
    top: &Map<String, Value>,
    frames_json: &'a [Value],
) -> Result<Vec<(&'a Map<String, Value>, Split)>> {
    let names = SplitLists {
        train: filename_set(top, "train_filenames", json_path)?,
        test: filename_set(top, "test_filenames", json_path)?,
        any_split_key: frames_json.iter().any(|f| f.get("split").is_some()),
    };
    let mut entries = Vec::with_capacity(frames_json.len());
    for (i, fj) in frames_json.iter().enumerate() {
        let ctx = Ctx {
            json: json_path,
            entry: format!("frames[{i}]"),
        };
        let obj = fj.as_object().ok_or_else(|| ctx.err("", "not a JSON object"))?;
        entries.push((obj, names.split_of(i, obj, &ctx)?));
    }
    Ok(entries)
}

/// What decides the frames' splits: nerfstudio's top-level `train_filenames` / `test_filenames`
/// and whether any frame has its own `split`.
struct SplitLists {
    train: Option<HashSet<String>>,
    test: Option<HashSet<String>>,
    any_split_key: bool,
}

impl SplitLists {
    /// The split of frame entry `i`: its own `split`, else the lists', else every 8th frame is a
    /// test view (a dataset where some frames have a `split` must give it for all).
    fn split_of(&self, i: usize, obj: &Map<String, Value>, ctx: &Ctx) -> Result<Split> {
        let file = obj
            .get("file_path")
            .and_then(Value::as_str)
            .map(normalize_name)
            .ok_or_else(|| ctx.err("file_path", "missing or not a string"))?;
        Ok(if let Some(s) = obj.get("split") {
            s.as_str()
                .and_then(Split::parse)
                .ok_or_else(|| ctx.err("split", format!("expected \"train\" or \"test\", found {s}")))?
        } else if self.train.is_some() || self.test.is_some() {
            let in_train = self.train.as_ref().is_some_and(|s| s.contains(&file));
            let in_test = self.test.as_ref().is_some_and(|s| s.contains(&file));
            match (in_train, in_test) {
                (true, false) => Split::Train,
                (false, true) => Split::Test,
                (true, true) => {
                    return Err(ctx.err(
                        "file_path",
                        format!("'{file}' is in both train_filenames and test_filenames"),
                    ))
                }
                (false, false) => {
                    return Err(ctx.err(
                        "file_path",
                        format!("'{file}' is in neither train_filenames nor test_filenames"),
                    ))
                }
            }
        } else if self.any_split_key {
            return Err(ctx.err("split", "missing while other frames have one"));
        } else if i % 8 == 0 {
            Split::Test
        } else {
            Split::Train
        })
    }
}

/// The optional top-level `mesh_path` (the ground-truth mesh), which must exist when given.
fn parse_mesh_path(root: &Path, json_path: &Path, top: &Map<String, Value>) -> Result<Option<PathBuf>> {
    match top.get("mesh_path") {
        None | Some(Value::Null) => Ok(None),
        Some(Value::String(s)) => {
            let p = root.join(s);
            if !p.is_file() {
                return Err(DataError::field(
                    json_path,
                    "mesh_path",
                    format!("{} not found", p.display()),
                ));
            }
            Ok(Some(p))
        }
        Some(v) => Err(DataError::field(json_path, "mesh_path", format!("not a path: {v}"))),
    }
}

/// The top-level `ldr: {transfer, exposure}`: how the LDR images encode radiance (`transfer`,
/// "srgb" by default, or "linear") and the optional positive exposure relating them to the HDR
/// images. Parsed here so that a bad value is refused at load, naming its key.
pub(crate) fn parse_ldr(json_path: &Path, top: &Map<String, Value>) -> Result<Radiometry> {
    let ldr = match top.get("ldr") {
        None | Some(Value::Null) => return Ok(Radiometry::default()),
        Some(Value::Object(ldr)) => ldr,
        Some(v) => {
            return Err(DataError::field(
                json_path,
                "ldr",
                format!("expected an object {{\"transfer\": …, \"exposure\": …}}, found {v}"),
            ))
        }
    };
    let transfer = match ldr.get("transfer") {
        None | Some(Value::Null) => Transfer::Srgb,
        Some(Value::String(s)) => Transfer::from_name(s).ok_or_else(|| {
            DataError::field(
                json_path,
                "ldr.transfer",
                format!("'{s}' is not \"srgb\" or \"linear\""),
            )
        })?,
        Some(v) => {
            return Err(DataError::field(
                json_path,
                "ldr.transfer",
                format!("expected \"srgb\" or \"linear\", found {v}"),
            ))
        }
    };
    let exposure = match ldr.get("exposure") {
        None | Some(Value::Null) => None,
        Some(v) => match v.as_f64() {
            Some(e) if e.is_finite() && e > 0.0 => Some(e),
            _ => {
                return Err(DataError::field(
                    json_path,
                    "ldr.exposure",
                    format!("expected a positive finite number, found {v}"),
                ))
            }
        },
    };
    Ok(Radiometry { transfer, exposure })
}

/// An optional top-level declaration that some input is exact, `poses_exact` or `depth_exact`
/// (default false: training treats it as measured, correcting the poses or modelling the depth
/// sensor's noise).
fn parse_declaration(json_path: &Path, top: &Map<String, Value>, key: &str) -> Result<bool> {
    match top.get(key) {
        None | Some(Value::Null) => Ok(false),
        Some(Value::Bool(b)) => Ok(*b),
        Some(v) => Err(DataError::field(
            json_path,
            key,
            format!("expected true or false, found {v}"),
        )),
    }
}

fn load_relight(
    root: &Path,
    json_path: &Path,
    top: &Map<String, Value>,
    units: DepthUnits,
    depth_dropped: &mut DepthDropped,
) -> Result<Vec<RelightSet>> {
    let Some(list) = top.get("relight") else {
        return Ok(Vec::new());
    };
    let list = list
        .as_array()
        .ok_or_else(|| DataError::field(json_path, "relight", "not a list"))?;
    let mut sets = Vec::new();
    for (k, entry) in list.iter().enumerate() {
        let ctx = Ctx {
            json: json_path,
            entry: format!("relight[{k}]"),
        };
        let obj = entry.as_object().ok_or_else(|| ctx.err("", "not a JSON object"))?;
        let spec = opt_path(obj, "spec", root, &ctx)?.ok_or_else(|| ctx.err("spec", "missing"))?;
        if !spec.is_file() {
            return Err(ctx.err("spec", format!("{} not found", spec.display())));
        }
        let frames_json = obj
            .get("frames")
            .and_then(Value::as_array)
            .ok_or_else(|| ctx.err("frames", "missing or not a list"))?;
        let objs: Vec<&Map<String, Value>> = frames_json
            .iter()
            .enumerate()
            .map(|(i, f)| {
                f.as_object()
                    .ok_or_else(|| ctx.err(&format!("frames[{i}]"), "not a JSON object"))
            })
            .collect::<Result<_>>()?;
        let loaded = par_load(&objs, |i, obj| {
            let ctx = Ctx {
                json: json_path,
                entry: format!("relight[{k}].frames[{i}]"),
            };
            load_frame(root, obj, top, &ctx, Split::Test, units)
        })?;
        let mut frames = Vec::with_capacity(loaded.len());
        for (frame, dropped) in loaded {
            depth_dropped.add(&dropped);
            frames.push(frame);
        }
        sets.push(RelightSet { spec, frames });
    }
    Ok(sets)
}

/// The top-level `emitters` list (`[{name, emission, bounds_min, bounds_max}]`), as `i2sdf synth`
/// writes it; absent means none.
fn parse_emitters(json_path: &Path, top: &Map<String, Value>) -> Result<Vec<GtEmitter>> {
    let list = match top.get("emitters") {
        None | Some(Value::Null) => return Ok(Vec::new()),
        Some(Value::Array(a)) => a,
        Some(v) => return Err(DataError::field(json_path, "emitters", format!("not a list: {v}"))),
    };
    list.iter()
        .enumerate()
        .map(|(i, entry)| {
            let key = |field: &str| format!("emitters[{i}].{field}");
            let vec3 = |field: &str| -> Result<[f64; 3]> {
                let v = entry
                    .get(field)
                    .ok_or_else(|| DataError::field(json_path, key(field), "missing"))?;
                let a = v.as_array().filter(|a| a.len() == 3);
                let vals: Option<Vec<f64>> = a.map(|a| a.iter().map(Value::as_f64).collect()).flatten();
                match vals {
                    Some(x) if x.iter().all(|c| c.is_finite()) => Ok([x[0], x[1], x[2]]),
                    _ => Err(DataError::field(
                        json_path,
                        key(field),
                        format!("expected three finite numbers, found {v}"),
                    )),
                }
            };
            let name = match entry.get("name") {
                Some(Value::String(s)) => s.clone(),
                None | Some(Value::Null) => format!("emitter {i}"),
                Some(v) => {
                    return Err(DataError::field(
                        json_path,
                        key("name"),
                        format!("expected a string, found {v}"),
                    ))
                }
            };
            Ok(GtEmitter {
                name,
                emission: vec3("emission")?,
                bounds_min: vec3("bounds_min")?,
                bounds_max: vec3("bounds_max")?,
            })
        })
        .collect()
}

/// The optional top-level `objects: [{"id": 7, "name": "lamp_pole", "tags": ["thin"]}, …]`; ids
/// are distinct integers, `tags` may be left out.
fn parse_objects(json_path: &Path, top: &Map<String, Value>) -> Result<Vec<ObjectInfo>> {
    let list = match top.get("objects") {
        None | Some(Value::Null) => return Ok(Vec::new()),
        Some(Value::Array(a)) => a,
        Some(v) => return Err(DataError::field(json_path, "objects", format!("not a list: {v}"))),
    };
    let mut seen = HashSet::new();
    let mut objects = Vec::with_capacity(list.len());
    for (i, entry) in list.iter().enumerate() {
        let err = |field: &str, msg: String| DataError::field(json_path, format!("objects[{i}].{field}"), msg);
        let obj = entry
            .as_object()
            .ok_or_else(|| DataError::field(json_path, format!("objects[{i}]"), "not a JSON object"))?;
        let id = match obj.get("id") {
            Some(v) => v
                .as_i64()
                .and_then(|x| i32::try_from(x).ok())
                .ok_or_else(|| err("id", format!("expected a 32-bit integer, found {v}")))?,
            None => return Err(err("id", "missing".into())),
        };
        if !seen.insert(id) {
            return Err(err("id", format!("{id} is listed twice")));
        }
        let name = match obj.get("name") {
            Some(Value::String(s)) => s.clone(),
            Some(v) => return Err(err("name", format!("expected a string, found {v}"))),
            None => return Err(err("name", "missing".into())),
        };
        let tags = match obj.get("tags") {
            None | Some(Value::Null) => Vec::new(),
            Some(Value::Array(a)) => a
                .iter()
                .enumerate()
                .map(|(k, t)| {
                    t.as_str()
                        .map(str::to_string)
                        .ok_or_else(|| err(&format!("tags[{k}]"), format!("expected a string, found {t}")))
                })
                .collect::<Result<_>>()?,
            Some(v) => return Err(err("tags", format!("expected a list of strings, found {v}"))),
        };
        objects.push(ObjectInfo { id, name, tags });
    }
    Ok(objects)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn parse(v: Value) -> Result<Vec<ObjectInfo>> {
        parse_objects(Path::new("scene/transforms.json"), v.as_object().unwrap())
    }

    #[test]
    fn exactness_declarations_default_to_measured_and_bad_values_name_their_key() {
        let path = Path::new("scene/transforms.json");
        for key in ["poses_exact", "depth_exact"] {
            let read = |v: Value| parse_declaration(path, v.as_object().unwrap(), key);
            assert!(!read(json!({})).unwrap());
            assert!(read(json!({key: true})).unwrap());
            let e = read(json!({key: "yes"})).unwrap_err();
            assert!(e.is_bad_input() && e.to_string().contains(key), "{e}");
        }
    }

    #[test]
    fn emitters_are_read_and_bad_entries_name_their_key() {
        let path = Path::new("scene/transforms.json");
        let top = json!({"emitters": [
            {"name": "bulb", "emission": [1.0, 2.0, 3.0], "bounds_min": [0, 0, 0], "bounds_max": [1, 1, 1]},
        ]});
        let got = parse_emitters(path, top.as_object().unwrap()).unwrap();
        assert_eq!(got.len(), 1);
        assert_eq!((got[0].name.as_str(), got[0].emission), ("bulb", [1.0, 2.0, 3.0]));
        let none = json!({});
        assert!(parse_emitters(path, none.as_object().unwrap()).unwrap().is_empty());
        let bad = json!({"emitters": [{"emission": [1.0, 2.0], "bounds_min": [0, 0, 0], "bounds_max": [1, 1, 1]}]});
        let e = parse_emitters(path, bad.as_object().unwrap()).unwrap_err();
        assert!(
            e.is_bad_input() && e.to_string().contains("emitters[0].emission"),
            "{e}"
        );
    }

    #[test]
    fn objects_are_read_and_default_to_none() {
        assert_eq!(parse(json!({"frames": []})).unwrap(), Vec::new());
        let objects = parse(json!({"objects": [
            {"id": 0, "name": "floor", "tags": ["room"]},
            {"id": 9, "name": "chandelier", "tags": ["suspended", "thin"], "extra": 1},
            {"id": -1, "name": "unlabelled"},
        ]}))
        .unwrap();
        assert_eq!(
            objects,
            vec![
                ObjectInfo {
                    id: 0,
                    name: "floor".into(),
                    tags: vec!["room".into()]
                },
                ObjectInfo {
                    id: 9,
                    name: "chandelier".into(),
                    tags: vec!["suspended".into(), "thin".into()]
                },
                ObjectInfo {
                    id: -1,
                    name: "unlabelled".into(),
                    tags: Vec::new()
                },
            ]
        );
    }

    #[test]
    fn malformed_objects_name_the_entry_and_field() {
        let cases = [
            (json!({"objects": {"id": 0}}), "objects"),
            (json!({"objects": [3]}), "objects[0]"),
            (json!({"objects": [{"name": "a"}]}), "objects[0].id"),
            (json!({"objects": [{"id": 1.5, "name": "a"}]}), "objects[0].id"),
            (
                json!({"objects": [{"id": 4294967296i64, "name": "a"}]}),
                "objects[0].id",
            ),
            (
                json!({"objects": [{"id": 1, "name": "a"}, {"id": 1, "name": "b"}]}),
                "objects[1].id",
            ),
            (json!({"objects": [{"id": 1}]}), "objects[0].name"),
            (
                json!({"objects": [{"id": 1, "name": "a", "tags": "thin"}]}),
                "objects[0].tags",
            ),
            (
                json!({"objects": [{"id": 1, "name": "a", "tags": ["thin", 2]}]}),
                "objects[0].tags[1]",
            ),
        ];
        for (value, expected) in cases {
            match parse(value.clone()).unwrap_err() {
                DataError::Field { path, field, .. } => {
                    assert_eq!(field, expected, "{value}");
                    assert_eq!(path, Path::new("scene/transforms.json"));
                }
                e => panic!("{value}: {e}"),
            }
        }
    }
}
