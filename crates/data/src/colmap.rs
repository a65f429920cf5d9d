//! The COLMAP format (docs/DATASETS.md, format 3): a sparse model as COLMAP writes
//! it and the images it was made from.
//!
//! ```text
//! sparse/0/cameras.bin images.bin points3D.bin   (or .txt; or directly in sparse/)
//! images/<NAME>          the images, by the names the model gives them
//! depth/<STEM>.png|.exr|.npy   optional z-depth per image: 16-bit PNG in millimetres, EXR/.npy in metres
//! masks/<STEM>.png       optional emitter masks
//! train.txt, test.txt    optional split lists (image names, one a line)
//! ```
//!
//! COLMAP's conventions are the house's: the pose is world-to-camera (a unit quaternion and a
//! translation) in OpenCV axes, and pixel centres sit at +0.5 — no shift is applied. The camera
//! models SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV and OPENCV_FISHEYE map onto
//! [`Lens`]; others are refused. An image at another size than its camera but with its aspect ratio
//! (a downscaled copy) gets the camera scaled to it.
//!
//! A model's scale is arbitrary. Where depth maps exist it is tied to theirs: every observation of
//! a 3D point in a view with depth gives the ratio of the depth map at the point's projection to
//! the point's z-depth in the model, and the median ratio scales the poses and points
//! ([`ScaleFix`], printed by `check`). Without depth the model's units stay, and the scene's extent
//! comes from its 3D points ([`crate::dataset::BoundsSource::SfmPoints`]).
//!
//! Splits: `train.txt` / `test.txt` next to `sparse/` list image names (blank lines and `#`
//! comments ignored); with only one of them, the images it does not list form the other split.
//! Without either, every 8th image in name order (0, 8, 16, …) is a test view.

mod model;

pub use model::{
    parse_cameras_bin, parse_cameras_txt, parse_images_bin, parse_images_txt, parse_points_bin, parse_points_txt,
    read_model, ColmapCamera, ColmapImage, ColmapModel, ColmapPoint, NO_POINT3D,
};

use crate::camera::{validate_rigid, Camera, Lens};
use crate::dataset::{self, Dataset, Format, Frame, Split};
use crate::error::{DataError, Result};
use crate::imageio;
use crate::radiometry::Radiometry;
use crate::sensor_depth::DepthDropped;
use glam::{DMat3, DMat4, DVec3};
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

/// Depth PNGs hold millimetres.
const PNG_DEPTH_SCALE: f64 = 1e-3;

/// How the model's scale was tied to the depth maps: world (depth) units per model unit.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ScaleFix {
    /// The median of depth / model z-depth over all observations that land on a depth pixel.
    pub ratio: f64,
    /// The median relative deviation of those ratios from it (0.01 = 1 %).
    pub spread: f64,
    /// Observations the ratio rests on.
    pub samples: usize,
    /// Views that contributed at least one.
    pub views: usize,
}

impl ScaleFix {
    /// Depth and model disagreeing by more than this (the ratios' spread) is said.
    pub const SPREAD_WARNING: f64 = 0.05;

    /// What to say when the ratios scatter: the depth maps and the model do not describe the same
    /// geometry well (noisy depth, a poor reconstruction, or depth in other units per view).
    pub fn warning(&self) -> Option<String> {
        (self.spread > Self::SPREAD_WARNING).then(|| {
            format!(
                "the depth maps and the COLMAP model disagree: their depth/SfM ratios spread by {:.1} % around the \
                 scale {:.4} (over {} observations); check the depth's units and the reconstruction",
                100.0 * self.spread,
                self.ratio,
                self.samples
            )
        })
    }
}

/// The folder holding the model: `sparse/0` if it has one, else `sparse`.
pub fn model_dir(root: &Path) -> Result<PathBuf> {
    let sparse = root.join("sparse");
    let has_model = |d: &Path| ["bin", "txt"].iter().any(|e| d.join(format!("cameras.{e}")).is_file());
    [sparse.join("0"), sparse.clone()]
        .into_iter()
        .find(|d| has_model(d))
        .ok_or_else(|| {
            DataError::file(
                &sparse,
                "no COLMAP model: neither sparse/0/ nor sparse/ holds cameras.bin or cameras.txt",
            )
        })
}

/// The camera-to-world pose of COLMAP's world-to-camera quaternion (w, x, y, z) and translation.
/// The quaternion is normalized (as COLMAP does on reading); a zero or non-finite one is refused.
pub fn pose_c2w(qvec: [f64; 4], tvec: [f64; 3]) -> std::result::Result<DMat4, String> {
    let norm = qvec.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !(norm.is_finite() && norm > 1e-9) {
        return Err(format!(
            "quaternion [{}, {}, {}, {}] has norm {norm}: not a rotation",
            qvec[0], qvec[1], qvec[2], qvec[3]
        ));
    }
    let [w, x, y, z] = qvec.map(|v| v / norm);
    // Rows of the world-to-camera rotation (COLMAP's qvec2rotmat).
    let r_w2c_rows = [
        DVec3::new(
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ),
        DVec3::new(
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ),
        DVec3::new(
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ),
    ];
    // Camera-to-world rotation = transpose: its columns are those rows.
    let r_c2w = DMat3::from_cols(r_w2c_rows[0], r_w2c_rows[1], r_w2c_rows[2]);
    let center = -(r_c2w * DVec3::from(tvec));
    Ok(crate::camera::rigid(r_c2w, center))
}

/// Intrinsics (fx, fy, cx, cy) and lens of a camera, from COLMAP's parameter order per model.
pub fn intrinsics(cam: &ColmapCamera) -> std::result::Result<(f64, f64, f64, f64, Lens), String> {
    let p = &cam.params;
    let expected = model::parameter_count(cam.model);
    if expected != Some(p.len()) {
        return Err(format!("camera model {} with {} parameters", cam.model, p.len()));
    }
    let (fx, fy, cx, cy, coeffs): (f64, f64, f64, f64, &[(&str, f64)]) = match cam.model {
        "SIMPLE_PINHOLE" => (p[0], p[0], p[1], p[2], &[]),
        "PINHOLE" => (p[0], p[1], p[2], p[3], &[]),
        "SIMPLE_RADIAL" => (p[0], p[0], p[1], p[2], &[("k1", p[3])]),
        "RADIAL" => (p[0], p[0], p[1], p[2], &[("k1", p[3]), ("k2", p[4])]),
        "OPENCV" => (
            p[0],
            p[1],
            p[2],
            p[3],
            &[("k1", p[4]), ("k2", p[5]), ("p1", p[6]), ("p2", p[7])],
        ),
        "OPENCV_FISHEYE" => (
            p[0],
            p[1],
            p[2],
            p[3],
            &[("k1", p[4]), ("k2", p[5]), ("k3", p[6]), ("k4", p[7])],
        ),
        other => return Err(format!("camera model {other} is not supported")),
    };
    let lens =
        Lens::from_model(cam.model, |k| coeffs.iter().find(|(n, _)| *n == k).map(|(_, v)| *v)).map_err(|(_, m)| m)?;
    Ok((fx, fy, cx, cy, lens))
}

/// The model's camera for one image (model units), checked.
fn camera_of(model: &ColmapModel, image: &ColmapImage, cameras_file: &Path, images_file: &Path) -> Result<Camera> {
    let image_field = format!("image {} ({})", image.id, image.name);
    let cam = model.cameras.get(&image.camera_id).ok_or_else(|| {
        DataError::field(
            images_file,
            &image_field,
            format!(
                "camera id {} is not in {}",
                image.camera_id,
                cameras_file.file_name().unwrap_or_default().to_string_lossy()
            ),
        )
    })?;
    let camera_field = format!("camera {}", cam.id);
    let (fx, fy, cx, cy, lens) = intrinsics(cam).map_err(|m| DataError::field(cameras_file, &camera_field, m))?;
    let c2w = pose_c2w(image.qvec, image.tvec).map_err(|m| DataError::field(images_file, &image_field, m))?;
    let camera = Camera {
        width: cam.width,
        height: cam.height,
        fx,
        fy,
        cx,
        cy,
        c2w,
        lens,
    };
    camera
        .validate_intrinsics()
        .map_err(|(_, m)| DataError::field(cameras_file, &camera_field, m))?;
    validate_rigid(&camera.c2w).map_err(|m| DataError::field(images_file, &image_field, m))?;
    Ok(camera)
}

/// The file of the model next to `dir` that was read for `stem` (for naming it in errors).
fn model_file(dir: &Path, stem: &str) -> PathBuf {
    let bin = dir.join(format!("{stem}.bin"));
    if bin.is_file() {
        bin
    } else {
        dir.join(format!("{stem}.txt"))
    }
}

/// `base` + `.ext` for the first extension that exists; two that exist are ambiguous.
fn find_with_extension(base: &Path, exts: &[&str]) -> Result<Option<PathBuf>> {
    let found: Vec<PathBuf> = exts
        .iter()
        .map(|e| {
            let mut s = base.as_os_str().to_os_string();
            s.push(format!(".{e}"));
            PathBuf::from(s)
        })
        .filter(|p| p.is_file())
        .collect();
    match found.len() {
        0 => Ok(None),
        1 => Ok(found.into_iter().next()),
        _ => Err(DataError::file(
            &found[0],
            format!("ambiguous: {} is there too", found[1].display()),
        )),
    }
}

/// The size of an image file, from its header where the format allows.
fn image_size(path: &Path) -> Result<(usize, usize)> {
    if !path.is_file() {
        return Err(DataError::file(
            path,
            "file not found (the COLMAP model names this image)",
        ));
    }
    if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr")) {
        let img = imageio::read_image(path)?;
        return Ok((img.width, img.height));
    }
    let (w, h) = image::ImageReader::open(path)
        .and_then(|r| r.with_guessed_format())
        .map_err(|e| DataError::file(path, format!("cannot read: {e}")))?
        .into_dimensions()
        .map_err(|e| DataError::file(path, format!("cannot decode image: {e}")))?;
    Ok((w as usize, h as usize))
}

/// The camera for an image file of size (w, h): the model's, or scaled to a downscaled copy with
/// the same aspect ratio (within 1 %).
fn fit_camera(camera: Camera, image_path: &Path, (w, h): (usize, usize), camera_id: i32) -> Result<Camera> {
    if (w, h) == (camera.width, camera.height) {
        return Ok(camera);
    }
    let aspect = |w: usize, h: usize| w as f64 / h as f64;
    if (aspect(w, h) / aspect(camera.width, camera.height) - 1.0).abs() > 0.01 {
        return Err(DataError::file(
            image_path,
            format!(
                "size {w}×{h} does not match camera {camera_id}'s {}×{} (nor its aspect ratio)",
                camera.width, camera.height
            ),
        ));
    }
    Ok(camera.resized(w, h))
}

/// One name list (`train.txt` / `test.txt`): (line number, name) pairs, or None if absent.
fn read_list(path: &Path) -> Result<Option<Vec<(usize, String)>>> {
    if !path.exists() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(path).map_err(|e| DataError::file(path, format!("cannot read: {e}")))?;
    Ok(Some(
        text.lines()
            .enumerate()
            .map(|(i, l)| (i + 1, l.trim()))
            .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
            .map(|(i, l)| {
                let l = l.trim_start_matches("./");
                (i, l.strip_prefix("images/").unwrap_or(l).to_string())
            })
            .collect(),
    ))
}

/// The split of each image (by name, in name order).
fn splits(root: &Path, names: &[&str]) -> Result<Vec<Split>> {
    let train_path = root.join("train.txt");
    let test_path = root.join("test.txt");
    let train = read_list(&train_path)?;
    let test = read_list(&test_path)?;
    if train.is_none() && test.is_none() {
        return Ok((0..names.len())
            .map(|i| if i % 8 == 0 { Split::Test } else { Split::Train })
            .collect());
    }
    let known: HashMap<&str, usize> = names.iter().enumerate().map(|(i, n)| (*n, i)).collect();
    let mut listed: Vec<Option<Split>> = vec![None; names.len()];
    for (list, path, split) in [(&train, &train_path, Split::Train), (&test, &test_path, Split::Test)] {
        for (line, name) in list.iter().flatten() {
            let field = format!("line {line}");
            let &i = known.get(name.as_str()).ok_or_else(|| {
                DataError::field(path, &field, format!("'{name}' is not an image of the COLMAP model"))
            })?;
            if listed[i].is_some_and(|s| s != split) {
                return Err(DataError::field(
                    path,
                    &field,
                    format!("'{name}' is in both train.txt and test.txt"),
                ));
            }
            listed[i] = Some(split);
        }
    }
    let rest = match (&train, &test) {
        (Some(_), None) => Some(Split::Test),
        (None, Some(_)) => Some(Split::Train),
        _ => None,
    };
    listed
        .iter()
        .zip(names)
        .map(|(s, name)| {
            s.or(rest).ok_or_else(|| {
                DataError::file(
                    &train_path,
                    format!("image '{name}' is in neither train.txt nor test.txt"),
                )
            })
        })
        .collect()
}

/// The ratio of depth to model z-depth over every observation of a 3D point in a view with depth.
/// `images[k]` is the model image of `frames[k]`; cameras are still in model units.
pub fn fix_scale(frames: &[Frame], images: &[&ColmapImage], points: &BTreeMap<u64, ColmapPoint>) -> Option<ScaleFix> {
    let mut ratios = Vec::new();
    let mut views = 0;
    for (frame, image) in frames.iter().zip(images) {
        let Some(depth) = &frame.depth else { continue };
        let before = ratios.len();
        for &(_, pid) in &image.points2d {
            let Some(point) = u64::try_from(pid).ok().and_then(|id| points.get(&id)) else {
                continue;
            };
            let Some((u, v, z)) = frame.camera.project(point.xyz) else {
                continue;
            };
            if !(u >= 0.0 && v >= 0.0 && u < depth.width as f64 && v < depth.height as f64) {
                continue;
            }
            let d = depth.pixel(u as usize, v as usize)[0] as f64;
            if d > 0.0 && d.is_finite() {
                ratios.push(d / z);
            }
        }
        views += (ratios.len() > before) as usize;
    }
    if ratios.is_empty() {
        return None;
    }
    let (ratio, spread) = crate::exposure::median_and_spread(&mut ratios);
    Some(ScaleFix {
        ratio,
        spread,
        samples: ratios.len(),
        views,
    })
}

/// The model's files, for naming them in errors.
struct ModelFiles {
    cameras: PathBuf,
    images: PathBuf,
    points: PathBuf,
}

/// Every observation of every image must name a point of points3D (or none).
fn check_observations(model: &ColmapModel, files: &ModelFiles) -> Result<()> {
    for image in model.images.values() {
        for (k, &(_, pid)) in image.points2d.iter().enumerate() {
            let known = pid == NO_POINT3D || u64::try_from(pid).is_ok_and(|id| model.points.contains_key(&id));
            if !known {
                return Err(DataError::field(
                    &files.images,
                    format!("image {} ({})", image.id, image.name),
                    format!(
                        "observation {k} refers to 3D point {pid}, which {} does not have",
                        files.points.file_name().unwrap_or_default().to_string_lossy()
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// The model's images in name order (the order of the frames and of the every-8th split); two
/// images of one name are refused.
fn images_by_name<'a>(model: &'a ColmapModel, images_file: &Path) -> Result<Vec<&'a ColmapImage>> {
    let mut images: Vec<&ColmapImage> = model.images.values().collect();
    images.sort_by(|a, b| a.name.cmp(&b.name));
    if let Some(w) = images.windows(2).find(|w| w[0].name == w[1].name) {
        return Err(DataError::field(
            images_file,
            format!("image {}", w[1].id),
            format!("name '{}' is also image {}'s", w[1].name, w[0].id),
        ));
    }
    Ok(images)
}

/// Where a frame's files are: `images/`, `depth/` and `masks/` under the dataset's root.
struct FrameDirs {
    images: PathBuf,
    depth: PathBuf,
    masks: PathBuf,
}

/// One model image as a frame: the image (with the camera fitted to its size), its depth map and
/// emitter mask where there are; also what became of its depth samples. The camera is still in
/// model units.
fn load_frame(image: &ColmapImage, camera: &Camera, split: Split, dirs: &FrameDirs) -> Result<(Frame, DepthDropped)> {
    let image_path = dirs.images.join(&image.name);
    let camera = fit_camera(camera.clone(), &image_path, image_size(&image_path)?, image.camera_id)?;
    let rgb = dataset::load_rgb(&image_path, &camera)?;
    let stem = Path::new(&image.name).with_extension("");
    let depth = find_with_extension(&dirs.depth.join(&stem), &["png", "exr", "npy"])?
        .map(|p| {
            let is_png = p.extension().is_some_and(|e| e == "png");
            crate::sensor_depth::load_depth(&p, &camera, if is_png { PNG_DEPTH_SCALE } else { 1.0 }, None)
        })
        .transpose()?;
    let (depth, dropped) = match depth {
        Some((d, dropped, _)) => (Some(d), dropped),
        None => (None, Default::default()),
    };
    let emitter_mask = find_with_extension(&dirs.masks.join(&stem), &["png"])?
        .map(|p| dataset::load_mask(&p, &camera))
        .transpose()?;
    let frame = Frame {
        // Images in subfolders (one per camera of a rig) keep the folder in their name.
        name: stem.to_string_lossy().replace(['/', '\\'], "_"),
        split,
        camera,
        image_path,
        rgb,
        hdr: None,
        depth,
        depth_low: None,
        normal: None,
        emitter_mask,
        material_mask: None,
        albedo: None,
        specular: None,
        roughness: None,
    };
    Ok((frame, dropped))
}

/// Ties the model's arbitrary scale to the depth maps' where any frame has one: the camera centres
/// are scaled by [`fix_scale`]'s ratio. Depth maps on which no 3D point of the model is observed
/// are refused: the scale would be a guess.
fn scale_to_depth(
    frames: &mut [Frame],
    images: &[&ColmapImage],
    model: &ColmapModel,
    depth_dir: &Path,
    points_file: &Path,
) -> Result<Option<ScaleFix>> {
    if !frames.iter().any(|f| f.depth.is_some()) {
        return Ok(None);
    }
    let fix = fix_scale(frames, images, &model.points).ok_or_else(|| {
        DataError::file(
            depth_dir,
            format!(
                "no 3D point of the COLMAP model ({}) is observed where a depth map has depth: the model's \
                 scale cannot be tied to the depth's",
                points_file.display()
            ),
        )
    })?;
    for f in frames.iter_mut() {
        let c = f.camera.center() * fix.ratio;
        f.camera.c2w.w_axis = c.extend(1.0);
    }
    Ok(Some(fix))
}

pub fn load(root: &Path) -> Result<Dataset> {
    let dir = model_dir(root)?;
    let model = read_model(&dir)?;
    let files = ModelFiles {
        cameras: model_file(&dir, "cameras"),
        images: model_file(&dir, "images"),
        points: model_file(&dir, "points3D"),
    };
    if model.images.is_empty() {
        return Err(DataError::file(&files.images, "the model has no registered image"));
    }
    check_observations(&model, &files)?;
    let images = images_by_name(&model, &files.images)?;
    let names: Vec<&str> = images.iter().map(|i| i.name.as_str()).collect();
    let splits = splits(root, &names)?;
    let dirs = FrameDirs {
        images: root.join("images"),
        depth: root.join("depth"),
        masks: root.join("masks"),
    };
    if !dirs.images.is_dir() {
        return Err(DataError::file(
            &dirs.images,
            "directory not found (the images of the COLMAP model)",
        ));
    }
    let cameras: Vec<Camera> = images
        .iter()
        .map(|im| camera_of(&model, im, &files.cameras, &files.images))
        .collect::<Result<_>>()?;
    let entries: Vec<(usize, Split)> = splits.into_iter().enumerate().collect();
    let loaded = crate::native::par_load(&entries, |_, &(k, split)| {
        load_frame(images[k], &cameras[k], split, &dirs)
    })?;
    let mut depth_dropped = DepthDropped::default();
    let mut frames: Vec<Frame> = loaded
        .into_iter()
        .map(|(f, d)| {
            depth_dropped.add(&d);
            f
        })
        .collect();
    dataset::check_splits(root, &frames)?;

    let colmap_scale = scale_to_depth(&mut frames, &images, &model, &dirs.depth, &files.points)?;
    let scale = colmap_scale.map_or(1.0, |s| s.ratio);
    let points: Vec<DVec3> = model.points.values().map(|p| p.xyz * scale).collect();
    let (bounds, bounds_source, normalization) = dataset::measure_bounds_with_points(&frames, &points);
    crate::sensor_depth::apply_validity_window(&mut frames, &normalization, &mut depth_dropped);
    Ok(Dataset {
        root: root.to_path_buf(),
        format: Format::Colmap,
        frames,
        // The format declares no radiometry: sRGB images, no exposure.
        radiometry: Radiometry::default(),
        // Structure from motion's poses carry its residual error: stage 1 corrects them.
        poses_exact: false,
        depth_exact: false,
        emitters: Vec::new(),
        mesh_path: None,
        relight: Vec::new(),
        objects: Vec::new(),
        bounds,
        bounds_source,
        normalization,
        colmap_scale,
        depth_dropped,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pose_is_world_to_camera() {
        // A camera at (1, 2, 3) looking along world +x: COLMAP stores R (world → camera) and
        // t = −R·c.
        let c2w = crate::camera::look_at(DVec3::new(1.0, 2.0, 3.0), DVec3::new(5.0, 2.0, 3.0), DVec3::Z);
        let r_w2c = DMat3::from_mat4(c2w).transpose();
        let q = glam::DQuat::from_mat3(&r_w2c);
        let t = -(r_w2c * DVec3::new(1.0, 2.0, 3.0));
        let got = pose_c2w([q.w, q.x, q.y, q.z], t.to_array()).unwrap();
        assert!(got.abs_diff_eq(c2w, 1e-12), "{got} vs {c2w}");
        // Scaled quaternions are normalized; a zero one is refused.
        let got2 = pose_c2w([2.0 * q.w, 2.0 * q.x, 2.0 * q.y, 2.0 * q.z], t.to_array()).unwrap();
        assert!(got2.abs_diff_eq(c2w, 1e-12));
        assert!(pose_c2w([0.0; 4], [0.0; 3]).unwrap_err().contains("norm 0"));
    }

    #[test]
    fn split_lists_assign_names_and_refuse_strangers() {
        let dir = tempfile::tempdir().unwrap();
        let names = ["a.png", "b.png", "c.png"];
        let s = splits(dir.path(), &names).unwrap();
        assert_eq!(s, vec![Split::Test, Split::Train, Split::Train]);
        std::fs::write(dir.path().join("test.txt"), "# held out\nimages/b.png\n\n").unwrap();
        let s = splits(dir.path(), &names).unwrap();
        assert_eq!(s, vec![Split::Train, Split::Test, Split::Train]);
        std::fs::write(dir.path().join("train.txt"), "a.png\n").unwrap();
        let e = splits(dir.path(), &names).unwrap_err();
        assert!(e.to_string().contains("'c.png' is in neither"), "{e}");
        std::fs::write(dir.path().join("train.txt"), "a.png\nc.png\nd.png\n").unwrap();
        let e = splits(dir.path(), &names).unwrap_err();
        assert!(e.to_string().contains("train.txt: line 3"), "{e}");
    }
}
