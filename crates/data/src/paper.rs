//! The paper's dataset release format (docs/DATASETS.md, format 2; VolSDF/IDR style):
//!
//! ```text
//! cameras_normalize.npz   world_mat_i = K·W2C (world units), scale_mat_i, val_mat_i
//! image/NNNN.png          LDR training images (sorted by name; index i ↔ world_mat_i)
//! depth/NNNN.exr          z-depth in the original world units (0, non-finite or outside the
//!                         validity window = no depth; see `sensor_depth`)
//! normal/NNNN.exr         unit normals in OpenCV camera space (0 = invalid)
//! light_mask/NNNN.png     emitter masks (optional)
//! mask/NNNN.png           material masks (optional): 1 where the material is GGX, 0 where it is
//!                         not (stage 2 does not fit those pixels, the material metrics skip them)
//! hdr/NNNN.exr            HDR images (optional)
//! material/NNNN_kd.exr, NNNN_ks.exr, NNNN_rough.exr   GT materials (optional)
//! val/NNNN.png            held-out test images (↔ val_mat_i; optional, see below)
//! val/depth/, val/normal/, val/light_mask/, val/mask/, val/hdr/, val/material/
//!                         the same annotations of the test images (each optional; read as the
//!                         training views' are, so `eval` scores depth, normals and materials on
//!                         them)
//! mesh.ply                the geometry GT in world units (optional; where the official code's
//!                         `--score` looks for it): a triangle mesh, or a point cloud (vertices
//!                         only), against which `eval` scores the mesh
//! radiometry.json         {"ldr": {"transfer": "srgb"|"linear", "exposure": x}} (optional; the
//!                         native format's `ldr` key): the release declares neither, so sRGB and
//!                         no exposure without it
//! ```
//!
//! Each annotation directory matches its images one to one in name order; the GT materials are
//! found by the image's stem. Without validation images (no `val/`, or none in it), every
//! [`HOLDOUT_EVERY`]th training view (0, 8, 16, … in name order) is a test view instead, with its
//! annotations, and is not trained on — the native and COLMAP formats' rule.
//!
//! Two conventions of the release's own loader are kept to read its data right: pixel (u, v)'s ray
//! goes through K⁻¹·[u, v, 1] with integer u, v (no half-pixel offset) — so the principal point is
//! shifted by +0.5 into our pixel-centre convention — and depths are z-depths in world units (the
//! release's loader divides them by `scale_mat`'s scale because it works in normalized units; we
//! keep cameras in world units, so they are used as they are).

use crate::camera::{decompose_projection, Camera};
use crate::dataset::{self, Dataset, Format, Frame, Split};
use crate::error::{DataError, Result};
use crate::imageio;
use crate::radiometry::Radiometry;
use crate::sensor_depth::{self, DepthDropped};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Sorted image-like files of a subdirectory (None if it does not exist).
fn list_dir(dir: &Path, exts: &[&str]) -> Result<Option<Vec<PathBuf>>> {
    if !dir.is_dir() {
        return Ok(None);
    }
    let rd = std::fs::read_dir(dir).map_err(|e| DataError::file(dir, format!("cannot list: {e}")))?;
    let mut files: Vec<PathBuf> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.is_file()
                && p.extension()
                    .and_then(|e| e.to_str())
                    .is_some_and(|e| exts.iter().any(|x| e.eq_ignore_ascii_case(x)))
        })
        .collect();
    files.sort();
    Ok(Some(files))
}

/// A 4×4 float64 matrix is 128 bytes of data after a header of at most a few hundred: anything
/// much longer is not a camera matrix (and is not read further).
const MAX_MATRIX_BYTES: u64 = 1 << 16;

fn read_matrix<R: std::io::Read + std::io::Seek>(
    npz: &mut npyz::npz::NpzArchive<R>,
    path: &Path,
    name: &str,
) -> Result<[[f64; 4]; 4]> {
    // The member's bytes, at most what a matrix can need, are read first and parsed in memory:
    // npyz would trust the lengths in the member's header (see `imageio::npy_file`).
    let file_name = npyz::npz::file_name_from_array_name(name);
    let zip = npz.zip_archive();
    if !zip.file_names().any(|n| n == file_name) {
        return Err(DataError::field(path, name, "missing"));
    }
    let mut bytes = Vec::new();
    {
        use std::io::Read;
        let member = zip
            .by_name(&file_name)
            .map_err(|e| DataError::field(path, name, format!("cannot read: {e}")))?;
        member
            .take(MAX_MATRIX_BYTES)
            .read_to_end(&mut bytes)
            .map_err(|e| DataError::field(path, name, format!("cannot read: {e}")))?;
    }
    let npy = imageio::npy_file(path, &bytes).map_err(|e| DataError::field(path, name, e.to_string()))?;
    let shape: Vec<u64> = npy.shape().to_vec();
    // The shape first: a matrix is 16 values, whatever size the header claims.
    let rows = match shape.as_slice() {
        [4, 4] => 4,
        [3, 4] => 3,
        _ => {
            return Err(DataError::field(
                path,
                name,
                format!("expected a 4×4 or 3×4 matrix, found shape {shape:?}"),
            ))
        }
    };
    let values = imageio::read_npy_f64(path, npy).map_err(|e| DataError::field(path, name, e.to_string()))?;
    if values.len() != rows * 4 {
        return Err(DataError::field(
            path,
            name,
            format!("holds {} values, its shape {shape:?} says {}", values.len(), rows * 4),
        ));
    }
    let mut m = [[0.0; 4]; 4];
    m[3] = [0.0, 0.0, 0.0, 1.0];
    for i in 0..rows {
        for j in 0..4 {
            let v = values[i * 4 + j];
            if !v.is_finite() {
                return Err(DataError::field(path, name, format!("entry [{i}][{j}] is not finite")));
            }
            m[i][j] = v;
        }
    }
    Ok(m)
}

/// Camera from a VolSDF/IDR projection matrix P = K·W2C, with the release's integer-pixel ray
/// convention converted to ours.
fn camera_from_projection(p4: [[f64; 4]; 4], width: usize, height: usize) -> std::result::Result<Camera, String> {
    let p = [p4[0], p4[1], p4[2]];
    let (k, c2w) = decompose_projection(p)?;
    if k.y_axis.x.abs() > 1e-6 * k.x_axis.x.abs() {
        return Err(format!("skewed intrinsics (skew {}) are not supported", k.y_axis.x));
    }
    let cam = Camera {
        lens: Default::default(),
        width,
        height,
        fx: k.x_axis.x,
        fy: k.y_axis.y,
        // K⁻¹[u, v, 1] with integer u, v  ==  our K'⁻¹[u + ½, v + ½, 1] with c' = c + ½.
        cx: k.z_axis.x + 0.5,
        cy: k.z_axis.y + 0.5,
        c2w,
    };
    cam.validate()?;
    Ok(cam)
}

fn image_size(path: &Path) -> Result<(usize, usize)> {
    let img = imageio::read_image(path)?;
    Ok((img.width, img.height))
}

pub fn load(root: &Path) -> Result<Dataset> {
    let npz_path = [root.join("cameras_normalize.npz"), root.join("cameras.npz")]
        .into_iter()
        .find(|p| p.is_file())
        .ok_or_else(|| DataError::file(root.join("cameras_normalize.npz"), "file not found"))?;
    let npz = npyz::npz::NpzArchive::open(&npz_path)
        .map_err(|e| DataError::file(&npz_path, format!("not a valid .npz archive: {e}")))?;
    load_with_npz(root, &npz_path, npz)
}

/// Without validation images, training view i (in name order) is a test view when i is a multiple
/// of this: 0, 8, 16, … — the rule of the native and COLMAP formats, so a scene gets the same split
/// whichever format it is read from.
pub const HOLDOUT_EVERY: usize = 8;

/// The training images (`image/`, sorted by name, not empty) and the validation images (`val/`,
/// sorted by name; empty when there is no `val/` or it holds no image, and then there must be
/// training images to hold out: at least two).
fn list_views(root: &Path, frame_exts: &[&str]) -> Result<(Vec<PathBuf>, Vec<PathBuf>)> {
    let image_dir = root.join("image");
    let images = list_dir(&image_dir, frame_exts)?.ok_or_else(|| DataError::file(&image_dir, "directory not found"))?;
    if images.is_empty() {
        return Err(DataError::file(&image_dir, "no images: the 'train' split is empty"));
    }
    let vals = list_dir(&root.join("val"), frame_exts)?.unwrap_or_default();
    if vals.is_empty() && images.len() < 2 {
        return Err(DataError::file(
            &image_dir,
            format!(
                "holds 1 image and val/ none: holding out every {HOLDOUT_EVERY}th view for testing leaves \
                 nothing to train on"
            ),
        ));
    }
    Ok((images, vals))
}

/// The optional per-view annotation files of a set of views (`None` where the release has no such
/// directory): in `image/`'s siblings for the training views, in `val/`'s subdirectories for the
/// validation views.
struct Annotations {
    /// The directory the annotation directories are in (the dataset's root, or `val/`).
    base: PathBuf,
    depths: Option<Vec<PathBuf>>,
    normals: Option<Vec<PathBuf>>,
    light_masks: Option<Vec<PathBuf>>,
    material_masks: Option<Vec<PathBuf>>,
    hdrs: Option<Vec<PathBuf>>,
}

impl Annotations {
    /// Lists the annotation directories under `base`; each must match the `image_count` images of
    /// `images` (a directory's name, for messages) one to one.
    fn list(base: &Path, images: &str, image_count: usize) -> Result<Annotations> {
        let matched = |sub: &str, exts: &[&str]| -> Result<Option<Vec<PathBuf>>> {
            let dir = base.join(sub);
            match list_dir(&dir, exts)? {
                None => Ok(None),
                Some(files) if files.len() == image_count => Ok(Some(files)),
                Some(files) => Err(DataError::file(
                    &dir,
                    format!("has {} files but {images} has {} images", files.len(), image_count),
                )),
            }
        };
        Ok(Annotations {
            base: base.to_path_buf(),
            depths: matched("depth", &["exr", "npy"])?,
            normals: matched("normal", &["exr", "npy"])?,
            light_masks: matched("light_mask", &["png", "exr"])?,
            material_masks: matched("mask", &["png", "exr"])?,
            hdrs: matched("hdr", &["exr"])?,
        })
    }
}

/// The cameras of `count` views from the archive's `{prefix}_0`, `{prefix}_1`, … projection
/// matrices, for images of size `width`×`height`.
fn read_cameras<R: std::io::Read + std::io::Seek>(
    npz: &mut npyz::npz::NpzArchive<R>,
    npz_path: &Path,
    prefix: &str,
    count: usize,
    (width, height): (usize, usize),
) -> Result<Vec<Camera>> {
    let mut cameras = Vec::with_capacity(count);
    for i in 0..count {
        let name = format!("{prefix}_{i}");
        let m = read_matrix(npz, npz_path, &name)?;
        cameras.push(camera_from_projection(m, width, height).map_err(|e| DataError::field(npz_path, &name, e))?);
    }
    Ok(cameras)
}

/// `scale_mat_0` must be a similarity (VolSDF normalization). Our cameras stay in world units, so it
/// is only read to validate the file.
fn check_scale_mat<R: std::io::Read + std::io::Seek>(
    npz: &mut npyz::npz::NpzArchive<R>,
    npz_path: &Path,
) -> Result<()> {
    let scale = read_matrix(npz, npz_path, "scale_mat_0")?;
    if scale[0][0] <= 0.0
        || (scale[0][0] - scale[1][1]).abs() > 1e-6 * scale[0][0]
        || (scale[0][0] - scale[2][2]).abs() > 1e-6 * scale[0][0]
    {
        return Err(DataError::field(
            npz_path,
            "scale_mat_0",
            "not a uniform scale + translation",
        ));
    }
    Ok(())
}

/// One view: its image and every annotation `annotations` has for it (the GT materials are found
/// by the image's stem in the `material/` directory beside the annotations), as a frame of
/// `split` named `name`; also what became of its depth samples.
fn load_frame(
    i: usize,
    camera: Camera,
    image_path: PathBuf,
    (name, split): (String, Split),
    annotations: &Annotations,
) -> Result<(Frame, DepthDropped)> {
    let material_dir = annotations.base.join("material");
    let stem = image_path
        .file_stem()
        .unwrap_or_default()
        .to_string_lossy()
        .into_owned();
    let material = |suffix: &str| -> Option<PathBuf> {
        let p = material_dir.join(format!("{stem}_{suffix}.exr"));
        p.is_file().then_some(p)
    };
    let rgb = dataset::load_rgb(&image_path, &camera)?;
    let rot = camera.rotation();
    let (depth, depth_dropped) = match &annotations.depths {
        Some(d) => {
            let (depth, dropped, _) = sensor_depth::load_depth(&d[i], &camera, 1.0, None)?;
            (Some(depth), dropped)
        }
        None => (None, DepthDropped::default()),
    };
    let normal = annotations
        .normals
        .as_ref()
        .map(|n| dataset::load_normal(&n[i], &camera, Some(rot)))
        .transpose()?;
    let mask = |masks: &Option<Vec<PathBuf>>| masks.as_ref().map(|m| dataset::load_mask(&m[i], &camera)).transpose();
    let emitter_mask = mask(&annotations.light_masks)?;
    let material_mask = mask(&annotations.material_masks)?;
    let hdr = annotations
        .hdrs
        .as_ref()
        .map(|m| dataset::load_rgb(&m[i], &camera))
        .transpose()?;
    let albedo = material("kd")
        .map(|p| dataset::load_float(&p, &camera, 3, "a Kd map"))
        .transpose()?;
    let specular = material("ks")
        .map(|p| dataset::load_float(&p, &camera, 3, "a Ks map"))
        .transpose()?;
    let roughness = material("rough")
        .map(|p| dataset::load_float(&p, &camera, 1, "a roughness map"))
        .transpose()?;
    let frame = Frame {
        name,
        split,
        camera,
        image_path,
        rgb,
        hdr,
        depth,
        depth_low: None,
        normal,
        emitter_mask,
        material_mask,
        albedo,
        specular,
        roughness,
    };
    Ok((frame, depth_dropped))
}

/// The radiometry the dataset declares in the optional `radiometry.json` beside its cameras —
/// `{"ldr": {"transfer": "srgb" | "linear", "exposure": x}}`, the native format's `ldr` key, read
/// by the same parser — as the release itself declares none. Without the file: sRGB images, no
/// exposure (stage 2 then uses the one the LDR/HDR pairs measure, `exposure`).
fn read_radiometry(root: &Path) -> Result<Radiometry> {
    let path = root.join(RADIOMETRY_FILE);
    if !path.exists() {
        return Ok(Radiometry::default());
    }
    let text = std::fs::read_to_string(&path).map_err(|e| DataError::file(&path, format!("cannot read: {e}")))?;
    let value: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| DataError::file(&path, format!("invalid JSON: {e}")))?;
    let top = value
        .as_object()
        .ok_or_else(|| DataError::file(&path, "the top level is not a JSON object"))?;
    // The file exists only to declare `ldr`: without it, whatever was meant is not read.
    if !top.contains_key("ldr") {
        return Err(DataError::field(
            &path,
            "ldr",
            "missing: the file declares {\"ldr\": {\"transfer\": …, \"exposure\": …}}",
        ));
    }
    crate::native::parse_ldr(&path, top)
}

/// The name of the optional radiometry declaration of a paper-format dataset (read by `read_radiometry`).
pub const RADIOMETRY_FILE: &str = "radiometry.json";

/// [`load`] with the camera archive already open (from a file or from bytes in memory: see
/// [`load_with_npz_bytes`]); `npz_path` names it in errors. The images are read from `root`.
pub fn load_with_npz<R: std::io::Read + std::io::Seek>(
    root: &Path,
    npz_path: &Path,
    mut npz: npyz::npz::NpzArchive<R>,
) -> Result<Dataset> {
    let frame_exts: Vec<&str> = imageio::RASTER_EXTENSIONS.iter().copied().chain(["exr"]).collect();
    let (images, vals) = list_views(root, &frame_exts)?;
    let annotations = Annotations::list(root, "image/", images.len())?;
    let val_annotations = Annotations::list(&root.join("val"), "val/", vals.len())?;
    let radiometry = read_radiometry(root)?;

    let size = image_size(&images[0])?;
    let cameras = read_cameras(&mut npz, npz_path, "world_mat", images.len(), size)?;
    let val_cameras = read_cameras(&mut npz, npz_path, "val_mat", vals.len(), size)?;
    check_scale_mat(&mut npz, npz_path)?;

    let stem = |p: &Path| p.file_stem().unwrap_or_default().to_string_lossy().into_owned();
    let held_out = |i: usize| vals.is_empty() && i % HOLDOUT_EVERY == 0;
    // Every view is loaded before any error is reported, then the first error in view order wins
    // (so the message does not depend on thread timing).
    let train: Vec<Result<(Frame, DepthDropped)>> = (0..images.len())
        .into_par_iter()
        .map(|i| {
            let split = if held_out(i) { Split::Test } else { Split::Train };
            let name = (stem(&images[i]), split);
            load_frame(i, cameras[i].clone(), images[i].clone(), name, &annotations)
        })
        .collect();
    let test: Vec<Result<(Frame, DepthDropped)>> = (0..vals.len())
        .into_par_iter()
        .map(|i| {
            let name = (format!("val_{}", stem(&vals[i])), Split::Test);
            load_frame(i, val_cameras[i].clone(), vals[i].clone(), name, &val_annotations)
        })
        .collect();
    let mut depth_dropped = DepthDropped::default();
    let mut frames = Vec::with_capacity(train.len() + test.len());
    for loaded in train.into_iter().chain(test) {
        let (frame, dropped) = loaded?;
        depth_dropped.add(&dropped);
        frames.push(frame);
    }
    let (bounds, bounds_source, normalization) = dataset::measure_bounds(&frames);
    sensor_depth::apply_validity_window(&mut frames, &normalization, &mut depth_dropped);
    Ok(Dataset {
        root: root.to_path_buf(),
        format: Format::Paper,
        frames,
        radiometry,
        // The release's poses are the renderer's own (synthetic) or calibrated (real rooms).
        poses_exact: true,
        depth_exact: true,
        emitters: Vec::new(),
        mesh_path: Some(root.join("mesh.ply")).filter(|p| p.is_file()),
        relight: Vec::new(),
        objects: Vec::new(),
        bounds,
        bounds_source,
        normalization,
        depth_dropped,
        colmap_scale: None,
    })
}

/// [`load`] with the bytes of `cameras_normalize.npz` already in memory.
pub fn load_with_npz_bytes(root: &Path, npz_path: &Path, bytes: &[u8]) -> Result<Dataset> {
    let npz = npyz::npz::NpzArchive::new(std::io::Cursor::new(bytes))
        .map_err(|e| DataError::file(npz_path, format!("not a valid .npz archive: {e}")))?;
    load_with_npz(root, npz_path, npz)
}
