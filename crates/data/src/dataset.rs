//! The internal scene every format is read into: frames with OpenCV cameras in world units, images
//! and the optional per-pixel annotations (z-depth in world units, world-space unit normals,
//! emitter masks, HDR and GT material maps), plus the normalization into the unit sphere that the
//! neural fields work in. Also the map loaders shared by the format readers, which validate size
//! and finiteness and name the file in every error (depth maps: `sensor_depth`).

use crate::camera::Camera;
use crate::error::{DataError, Result};
use crate::imageio::{self, ImageF32};
use crate::radiometry::Radiometry;
use crate::sensor_depth::DepthDropped;
use glam::{DMat4, DVec3};
use std::path::{Path, PathBuf};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Split {
    Train,
    Test,
}

impl Split {
    pub fn parse(s: &str) -> Option<Split> {
        match s {
            "train" => Some(Split::Train),
            "test" | "val" => Some(Split::Test),
            _ => None,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Test => "test",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Format {
    /// nerfstudio-style `transforms.json`.
    Native,
    /// The paper's VolSDF/IDR-style release (`cameras_normalize.npz`).
    Paper,
    /// A COLMAP sparse model (`sparse/0/{cameras,images,points3D}.{bin,txt}`) with `images/`.
    Colmap,
}

/// One view with its annotations. Maps are `None` when the dataset does not provide them.
#[derive(Clone, Debug)]
pub struct Frame {
    /// A short name for messages and outputs (the image's file stem).
    pub name: String,
    pub split: Split,
    pub camera: Camera,
    /// The image file (for messages).
    pub image_path: PathBuf,
    /// LDR colour in \[0,1\], 3 channels, as stored (display-referred; see `Dataset::radiometry`).
    pub rgb: ImageF32,
    /// Linear HDR radiance, 3 channels.
    pub hdr: Option<ImageF32>,
    /// z-depth (along the optical axis) in world units, 1 channel; 0 marks a pixel without depth.
    pub depth: Option<ImageF32>,
    /// 1 over the footprints of the depth samples the sensor's confidence map marked below the
    /// dataset's minimum (dropped from `depth`), 0 elsewhere; `None` without a confidence map.
    pub depth_low: Option<ImageF32>,
    /// World-space unit normals, 3 channels; (0,0,0) marks a pixel without a normal.
    pub normal: Option<ImageF32>,
    /// 1 where the pixel sees an emitter, else 0.
    pub emitter_mask: Option<ImageF32>,
    /// 1 where the surface's material is one the GGX model can fit, 0 where it is not (the
    /// paper's release marks such areas — glass, mirrors, … — to be skipped): stage 2 does not fit
    /// the pixels marked 0 and the material metrics do not score them. `None`: every pixel is used.
    pub material_mask: Option<ImageF32>,
    /// Ground-truth diffuse albedo Kd, specular albedo Ks (3 channels) and roughness (1 channel),
    /// for evaluation only.
    pub albedo: Option<ImageF32>,
    pub specular: Option<ImageF32>,
    pub roughness: Option<ImageF32>,
}

impl Frame {
    pub fn pixel_count(&self) -> usize {
        self.camera.width * self.camera.height
    }

    /// Every map of the frame, in the order of [`Frame::MAP_NAMES`]: the LDR colour, then the
    /// optional maps (`None` where the frame has none).
    pub fn maps(&self) -> [Option<&ImageF32>; 9] {
        [
            Some(&self.rgb),
            self.hdr.as_ref(),
            self.depth.as_ref(),
            self.normal.as_ref(),
            self.emitter_mask.as_ref(),
            self.material_mask.as_ref(),
            self.albedo.as_ref(),
            self.specular.as_ref(),
            self.roughness.as_ref(),
        ]
    }

    /// The names of [`Frame::maps`]. The first [`Frame::TRAINING_MAPS`] are the ones training
    /// reads; the rest are ground truth for evaluation.
    pub const MAP_NAMES: [&'static str; 9] = [
        "rgb",
        "hdr",
        "depth",
        "normal",
        "emitter_mask",
        "material_mask",
        "albedo",
        "specular",
        "roughness",
    ];

    /// How many of [`Frame::maps`] (the first ones) training reads.
    pub const TRAINING_MAPS: usize = 6;
}

/// A set of relit ground-truth views: the edit spec that produced them and the images.
#[derive(Clone, Debug)]
pub struct RelightSet {
    pub spec: PathBuf,
    pub frames: Vec<Frame>,
}

/// One named object of the ground truth (native format, top-level `objects`): `id` is the
/// per-face `object_id` of the GT mesh; `tags` say what kind of object it is (the synthetic
/// generator writes `room`, `furniture`, `thin`, `suspended`, `emitter`).
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ObjectInfo {
    pub id: i32,
    pub name: String,
    pub tags: Vec<String>,
}

/// One ground-truth emitter: its name, HDR emission (linear, the HDR images' units) and
/// axis-aligned box in world units.
#[derive(Clone, Debug, PartialEq)]
pub struct GtEmitter {
    pub name: String,
    pub emission: [f64; 3],
    pub bounds_min: [f64; 3],
    pub bounds_max: [f64; 3],
}

/// Similarity transform from world units into the normalized frame of the neural fields:
/// `x_n = (x_w − center) / scale`. The whole scene lies in the unit sphere of the normalized frame.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Normalization {
    pub center: [f64; 3],
    pub scale: f64,
}

impl Normalization {
    /// The same transform up to JSON round-off (serde_json's float parsing may move the last
    /// bit): what a run directory's stored normalization is checked against.
    pub fn same_as(&self, other: &Normalization) -> bool {
        let tol = 1e-9 * self.scale.abs().max(other.scale.abs()).max(1e-300);
        (self.scale - other.scale).abs() <= tol
            && self.center.iter().zip(&other.center).all(|(a, b)| (a - b).abs() <= tol)
    }

    pub fn to_normalized(&self, p: DVec3) -> DVec3 {
        (p - DVec3::from(self.center)) / self.scale
    }
    pub fn to_world(&self, p: DVec3) -> DVec3 {
        p * self.scale + DVec3::from(self.center)
    }
    /// The 4×4 matrix mapping world → normalized coordinates.
    pub fn world_to_normalized(&self) -> DMat4 {
        DMat4::from_scale(DVec3::splat(1.0 / self.scale)) * DMat4::from_translation(-DVec3::from(self.center))
    }
}

/// Axis-aligned bounds in world units.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Bounds {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

/// What the scene's extent was measured from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BoundsSource {
    /// Back-projected depth maps and camera centres.
    Depth,
    /// Camera centres only (no depth), enlarged: a guess.
    Cameras,
    /// A structure-from-motion point cloud (COLMAP's points3D) and the camera centres (no depth).
    SfmPoints,
}

#[derive(Clone, Debug)]
pub struct Dataset {
    pub root: PathBuf,
    pub format: Format,
    pub frames: Vec<Frame>,
    /// The radiometry the dataset declares (native `ldr`, paper `radiometry.json`): how the LDR
    /// images encode light (`transfer`: sRGB by default, or linear), and the exposure they were
    /// made with (`ldr.exposure`: LDR = transfer(exposure · HDR)) when the dataset states it. Stage 2 scales
    /// HDR images by the exposure into the LDR images' linear units, and reports each emitter's
    /// radiance as emission / exposure; with none declared it uses the one the images measure
    /// (`exposure::exposure_in_use`).
    pub radiometry: Radiometry,
    /// The dataset declares its poses exact (native `poses_exact: true`, as the synthetic rooms
    /// write; the paper's release, calibrated): training then does not correct them.
    pub poses_exact: bool,
    /// The dataset declares its depth maps exact (native `depth_exact: true`, as the synthetic
    /// rooms without sensor noise write; the paper's release, rendered): training then weighs
    /// every depth sample alike instead of modelling a sensor's noise
    /// (`maps.depth_noise_distance`).
    pub depth_exact: bool,
    /// The ground-truth emitters (native format, top-level `emitters`), for evaluation only.
    pub emitters: Vec<GtEmitter>,
    /// Ground-truth mesh (PLY) in world units, if the dataset has one.
    pub mesh_path: Option<PathBuf>,
    pub relight: Vec<RelightSet>,
    /// The GT mesh's objects, when the dataset names them; empty otherwise (always for the paper's
    /// format).
    pub objects: Vec<ObjectInfo>,
    pub bounds: Bounds,
    pub bounds_source: BoundsSource,
    pub normalization: Normalization,
    /// The depth samples read and why those without depth were dropped (`sensor_depth`).
    pub depth_dropped: DepthDropped,
    /// How a COLMAP model's arbitrary scale was tied to its depth maps' units (None: not a COLMAP
    /// dataset, or one without depth, which stays in COLMAP's units).
    pub colmap_scale: Option<crate::colmap::ScaleFix>,
}

impl Dataset {
    pub fn split(&self, split: Split) -> impl Iterator<Item = &Frame> {
        self.frames.iter().filter(move |f| f.split == split)
    }
    pub fn count(&self, split: Split) -> usize {
        self.split(split).count()
    }
}

/// Reads the dataset in `dir`, detecting its format: `transforms.json` (native),
/// `cameras_normalize.npz` / `cameras.npz` (paper release) or a `sparse/` folder (COLMAP), in that
/// order (a folder converted to `transforms.json` from its COLMAP model is read as converted).
pub fn load(dir: &Path) -> Result<Dataset> {
    if dir.is_file() {
        let hint = match dir.file_name().and_then(|n| n.to_str()) {
            Some("transforms.json" | "cameras_normalize.npz" | "cameras.npz") => " (give the folder that holds it)",
            _ => "",
        };
        return Err(DataError::file(dir, format!("is a file, not a dataset folder{hint}")));
    }
    if !dir.exists() {
        return Err(DataError::file(dir, "dataset folder not found"));
    }
    if !dir.is_dir() {
        return Err(DataError::file(dir, "not a dataset folder"));
    }
    if dir.join("transforms.json").is_file() {
        crate::native::load(dir)
    } else if dir.join("cameras_normalize.npz").is_file() || dir.join("cameras.npz").is_file() {
        crate::paper::load(dir)
    } else if dir.join("sparse").is_dir() {
        crate::colmap::load(dir)
    } else {
        Err(DataError::file(
            dir,
            "not a dataset: neither transforms.json (native format), cameras_normalize.npz (paper format) nor \
             sparse/ (a COLMAP model) found",
        ))
    }
}

// ---------------------------------------------------------------------------------------------
// Map loading shared by the format readers.

fn check_size(path: &Path, img: &ImageF32, cam: &Camera) -> Result<()> {
    if img.width != cam.width || img.height != cam.height {
        return Err(DataError::file(
            path,
            format!(
                "size {}×{} does not match the camera's {}×{}",
                img.width, img.height, cam.width, cam.height
            ),
        ));
    }
    Ok(())
}

fn check_finite(path: &Path, img: &ImageF32) -> Result<()> {
    if let Some((x, y, c)) = img.first_non_finite() {
        return Err(DataError::file(
            path,
            format!(
                "non-finite value {} at pixel ({x}, {y}), channel {c}",
                img.pixel(x, y)[c]
            ),
        ));
    }
    Ok(())
}

/// Keeps the first `n` channels, or replicates a single channel to `n`.
fn to_channels(path: &Path, img: ImageF32, n: usize, what: &str) -> Result<ImageF32> {
    if img.channels == n {
        return Ok(img);
    }
    if img.channels > n {
        let mut out = ImageF32::new(img.width, img.height, n);
        for p in 0..img.width * img.height {
            out.data[p * n..(p + 1) * n].copy_from_slice(&img.data[p * img.channels..p * img.channels + n]);
        }
        return Ok(out);
    }
    if img.channels == 1 {
        let data = img.data.iter().flat_map(|v| std::iter::repeat_n(*v, n)).collect();
        return Ok(ImageF32::from_data(img.width, img.height, n, data));
    }
    Err(DataError::file(
        path,
        format!("{what} needs {n} channels, found {}", img.channels),
    ))
}

/// An LDR or HDR colour image, 3 channels, checked for size and finiteness.
pub fn load_rgb(path: &Path, cam: &Camera) -> Result<ImageF32> {
    let img = imageio::read_image(path)?;
    check_size(path, &img, cam)?;
    check_finite(path, &img)?;
    to_channels(path, img, 3, "a colour image")
}

/// A normal map, 3 channels. `rotation` maps the file's frame to world (identity for world-space
/// normals, the camera rotation for camera-space ones). Zero vectors mean "no normal"; others must
/// be roughly unit length and are renormalized.
pub fn load_normal(path: &Path, cam: &Camera, rotation: Option<glam::DMat3>) -> Result<ImageF32> {
    let img = imageio::read_float_map(path)?;
    check_size(path, &img, cam)?;
    check_finite(path, &img)?;
    if img.channels < 3 {
        return Err(DataError::file(
            path,
            format!("a normal map needs 3 channels, found {}", img.channels),
        ));
    }
    let mut img = to_channels(path, img, 3, "a normal map")?;
    for p in 0..img.width * img.height {
        let n = &mut img.data[p * 3..p * 3 + 3];
        let v = DVec3::new(n[0] as f64, n[1] as f64, n[2] as f64);
        let len = v.length();
        if len < 1e-3 {
            n.copy_from_slice(&[0.0; 3]);
            continue;
        }
        if !(0.9..=1.1).contains(&len) {
            return Err(DataError::file(
                path,
                format!(
                    "normal at pixel ({}, {}) has length {len:.3}; expected unit normals (not [0,1]-encoded colours)",
                    p % img.width,
                    p / img.width
                ),
            ));
        }
        let v = rotation.map_or(v, |r| r * v) / len;
        n.copy_from_slice(&[v.x as f32, v.y as f32, v.z as f32]);
    }
    Ok(img)
}

/// A mask (PNG or float map), 1 channel, binarized at 0.5.
pub fn load_mask(path: &Path, cam: &Camera) -> Result<ImageF32> {
    let img = imageio::read_float_map(path)?;
    check_size(path, &img, cam)?;
    check_finite(path, &img)?;
    let mut m = img.channel(0);
    m.data.iter_mut().for_each(|v| *v = if *v > 0.5 { 1.0 } else { 0.0 });
    Ok(m)
}

/// A float map with `channels` channels (material maps), checked for size and finiteness.
pub fn load_float(path: &Path, cam: &Camera, channels: usize, what: &str) -> Result<ImageF32> {
    let img = imageio::read_float_map(path)?;
    check_size(path, &img, cam)?;
    check_finite(path, &img)?;
    to_channels(path, img, channels, what)
}

// ---------------------------------------------------------------------------------------------
// Bounds and normalization.

/// Measures the scene's extent from depth (robustly: 0.1–99.9 % per axis, so a few outlier depth
/// pixels cannot blow the normalization up) and the camera centres, and derives the
/// normalization: centre of the box, scale so the box's circumscribed sphere, enlarged by 5 %,
/// becomes the unit sphere.
pub fn measure_bounds(frames: &[Frame]) -> (Bounds, BoundsSource, Normalization) {
    measure_bounds_with_points(frames, &[])
}

/// [`measure_bounds`] for a dataset that also has a structure-from-motion point cloud (world
/// units): without depth, the points and camera centres give the extent (robustly: 1–99 % per
/// axis, as SfM clouds carry stray points) instead of a guess from the cameras alone.
pub fn measure_bounds_with_points(frames: &[Frame], sfm_points: &[DVec3]) -> (Bounds, BoundsSource, Normalization) {
    let mut pts: Vec<DVec3> = frames.iter().map(|f| f.camera.center()).collect();
    let mut depth_pts = 0usize;
    for f in frames {
        let Some(depth) = &f.depth else { continue };
        // Subsample so a 200-view 640×480 scene stays cheap: about 4k points per view.
        let step = ((f.pixel_count() / 4096).max(1) as f64).sqrt().ceil() as usize;
        for j in (0..f.camera.height).step_by(step) {
            for i in (0..f.camera.width).step_by(step) {
                let d = depth.pixel(i, j)[0] as f64;
                if d > 0.0 {
                    pts.push(f.camera.backproject(i, j, d));
                    depth_pts += 1;
                }
            }
        }
    }
    let source = if depth_pts > 0 {
        BoundsSource::Depth
    } else if !sfm_points.is_empty() {
        pts.extend_from_slice(sfm_points);
        BoundsSource::SfmPoints
    } else {
        BoundsSource::Cameras
    };
    let mut min = [0.0; 3];
    let mut max = [0.0; 3];
    for a in 0..3 {
        let mut v: Vec<f64> = pts.iter().map(|p| p[a]).collect();
        v.sort_by(|x, y| x.total_cmp(y));
        let lo = match source {
            BoundsSource::Depth if depth_pts > 1000 => v.len() / 1000,
            BoundsSource::SfmPoints if sfm_points.len() > 100 => v.len() / 100,
            _ => 0,
        };
        let hi = v.len() - 1 - lo;
        min[a] = v[lo];
        max[a] = v[hi];
    }
    let bounds = Bounds { min, max };
    let (lo, hi) = (DVec3::from(min), DVec3::from(max));
    let center = (lo + hi) * 0.5;
    let mut radius = (hi - lo).length() * 0.5 * 1.05;
    if source == BoundsSource::Cameras {
        // Cameras inside a room do not span it: guess the room is 3× the spread of the cameras.
        radius = (radius * 3.0).max(1.0);
    }
    let radius = radius.max(1e-6);
    (
        bounds,
        source,
        Normalization {
            center: center.to_array(),
            scale: radius,
        },
    )
}

/// Checks that both splits are non-empty.
pub fn check_splits(root: &Path, frames: &[Frame]) -> Result<()> {
    for split in [Split::Train, Split::Test] {
        if !frames.iter().any(|f| f.split == split) {
            return Err(DataError::field(
                root,
                "split",
                format!("the '{}' split is empty: no frame belongs to it", split.name()),
            ));
        }
    }
    Ok(())
}
