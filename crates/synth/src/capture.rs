//! What a phone capture of a synthetic room looks like (issue 24, item 7): the same room, cameras
//! and test views as the exact dataset of the same seed, with each of a phone's degradations
//! selectable alone and all of them together (`--capture`):
//! - frames as JPEG at a quality (phone: 90);
//! - a lens: the images are rendered through it (the cameras' rays undistort), and transforms.json
//!   declares it (`camera_model` and its coefficients; see [`PHONE_OPENCV`], [`PHONE_FISHEYE`]);
//! - sensor depth on a coarse grid (the image size / N per axis; phone: 4): the true z-depth at
//!   the grid's pixel centres (traced at those rays, not averaged from a fine map), with the
//!   paper's noise model, as a 16-bit PNG in millimetres;
//! - a confidence map per depth sample (ARKit's 0 low / 1 medium / 2 high; [`confidence_of`]),
//!   whose low samples carry large errors (flying pixels at depth edges, 10 % errors elsewhere);
//! - no normal maps, no emitter masks, no HDR frames and no declared exposure;
//! - training poses perturbed by a fixed rotation and translation (the true ones in
//!   `poses_true.json`); test poses stay exact.

use crate::noise::{standard_normal, DepthNoise};
use crate::tracer::RenderScene;
use glam::{DMat3, DVec3, Vec3};
use i2sdf_data::{Camera, DataError, Lens};
use i2sdf_render::{Geometry, Hit, Ray};
use rand::Rng;
use rayon::prelude::*;
use serde_json::json;

/// A phone's main camera before the ISP's correction, in OpenCV's Brown–Conrady model: mild
/// barrel distortion (about −6 % at the corners of the rooms' 75° images) and a slight decentring.
pub const PHONE_OPENCV: Lens = Lens::BrownConrady {
    k1: -0.08,
    k2: 0.02,
    k3: 0.0,
    p1: 0.0005,
    p2: -0.0003,
};

/// A phone's ultra-wide camera in OpenCV's fisheye (Kannala–Brandt) model: the equidistant
/// projection with a mild correction, monotonic far beyond the rooms' field of view.
pub const PHONE_FISHEYE: Lens = Lens::Fisheye {
    k1: 0.05,
    k2: -0.02,
    k3: 0.004,
    k4: 0.0,
};

/// A rigid perturbation of fixed size: a translation of `cm` centimetres in a uniformly random
/// direction and a rotation of `deg` degrees about a uniformly random axis through the camera
/// centre (both magnitudes exact, so that a test can check them).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseNoise {
    pub cm: f64,
    pub deg: f64,
}

impl PoseNoise {
    /// `CM,DEG`, e.g. `1,0.5`.
    pub fn parse(s: &str) -> Result<PoseNoise, DataError> {
        let bad = || DataError::invalid(format!("--pose-noise: '{s}' is not CM,DEG (e.g. 1,0.5)"));
        let (cm, deg) = s.split_once(',').ok_or_else(bad)?;
        let (cm, deg): (f64, f64) = (
            cm.trim().parse().map_err(|_| bad())?,
            deg.trim().parse().map_err(|_| bad())?,
        );
        if !(0.0..=100.0).contains(&cm) || !(0.0..=45.0).contains(&deg) {
            return Err(DataError::invalid(format!(
                "--pose-noise {s}: the translation must be in 0..=100 cm and the rotation in 0..=45°"
            )));
        }
        Ok(PoseNoise { cm, deg })
    }

    pub fn is_zero(&self) -> bool {
        self.cm == 0.0 && self.deg == 0.0
    }

    /// `cam` moved by this perturbation (the rooms are in metres). The rotation turns the camera
    /// about its own centre (a world-frame axis).
    pub fn perturb(&self, cam: &Camera, rng: &mut impl Rng) -> Camera {
        let axis = random_unit(rng);
        let dir = random_unit(rng);
        let rot = DMat3::from_axis_angle(axis, self.deg.to_radians());
        let r = rot * cam.rotation();
        let c = cam.center() + dir * (self.cm / 100.0);
        Camera {
            c2w: i2sdf_data::camera::rigid(r, c),
            ..cam.clone()
        }
    }
}

/// A uniformly random unit vector (normalized Gaussian).
fn random_unit(rng: &mut impl Rng) -> DVec3 {
    loop {
        let v = DVec3::new(
            standard_normal(rng) as f64,
            standard_normal(rng) as f64,
            standard_normal(rng) as f64,
        );
        if v.length_squared() > 1e-12 {
            return v.normalize();
        }
    }
}

/// Which degradations of a phone capture a dataset gets. The default is the exact room.
#[derive(Clone, Debug, PartialEq)]
pub struct CaptureOptions {
    /// Frames as JPEG at this quality (1–100) instead of PNG.
    pub jpeg_quality: Option<u8>,
    /// The lens every view (train and test) is rendered through.
    pub lens: Lens,
    /// Depth as a 16-bit PNG (millimetres) at the image size divided by this per axis, instead
    /// of the full-resolution float EXR.
    pub depth_grid: Option<usize>,
    /// A confidence map per depth map, and large errors on its low samples.
    pub confidence: bool,
    pub normals: bool,
    pub masks: bool,
    /// HDR frames and the declared LDR exposure (a phone gives neither).
    pub hdr: bool,
    /// Perturbation of the training poses written to transforms.json.
    pub pose_noise: Option<PoseNoise>,
}

impl Default for CaptureOptions {
    fn default() -> Self {
        CaptureOptions {
            jpeg_quality: None,
            lens: Lens::Pinhole,
            depth_grid: None,
            confidence: false,
            normals: true,
            masks: true,
            hdr: true,
            pose_noise: None,
        }
    }
}

/// The phone defaults of `--capture` (the depth noise's is [`PHONE_DEPTH_NOISE`]).
pub const PHONE_JPEG_QUALITY: u8 = 90;
/// ARKit's 256×192 depth for 1920×1440 frames is 7.5× coarser; 4 keeps a few samples per object
/// at the rooms' small image sizes (the default 160×120 → 40×30).
pub const PHONE_DEPTH_GRID: usize = 4;
pub const PHONE_DEPTH_NOISE: DepthNoise = DepthNoise::Sigma;
/// About a pixel at the default image size (fx ≈ 104 px: 0.5° ≈ 0.9 px; 1 cm at 2 m ≈ 0.5 px),
/// a visual-inertial tracker's drift over a short room scan.
pub const PHONE_POSE_NOISE: PoseNoise = PoseNoise { cm: 1.0, deg: 0.5 };

impl CaptureOptions {
    /// Every degradation at the phone defaults.
    pub fn phone() -> Self {
        CaptureOptions {
            jpeg_quality: Some(PHONE_JPEG_QUALITY),
            lens: PHONE_OPENCV,
            depth_grid: Some(PHONE_DEPTH_GRID),
            confidence: true,
            normals: false,
            masks: false,
            hdr: false,
            pose_noise: Some(PHONE_POSE_NOISE),
        }
    }

    /// Whether nothing is degraded (a zero pose noise perturbs nothing).
    pub fn is_exact(&self) -> bool {
        CaptureOptions {
            pose_noise: self.pose_perturbation(),
            ..self.clone()
        } == CaptureOptions::default()
    }

    /// The perturbation of the training poses, if any is non-zero.
    pub fn pose_perturbation(&self) -> Option<PoseNoise> {
        self.pose_noise.filter(|p| !p.is_zero())
    }

    /// The depth map's size for images of `width`×`height`: the image size divided by the grid,
    /// rounded (full size without a grid).
    pub fn depth_size(&self, width: usize, height: usize) -> (usize, usize) {
        match self.depth_grid {
            None => (width, height),
            Some(n) => (
                ((width as f64 / n as f64).round() as usize).max(1),
                ((height as f64 / n as f64).round() as usize).max(1),
            ),
        }
    }

    /// Checks the options against the image size: the JPEG quality within 1–100, the depth grid's
    /// aspect ratio within 1 % of the image's (the dataset contract), the lens invertible.
    pub fn validate(&self, width: usize, height: usize) -> Result<(), DataError> {
        if let Some(q) = self.jpeg_quality {
            if !(1..=100).contains(&q) {
                return Err(DataError::invalid(format!("--jpeg-quality {q}: must be in 1..=100")));
            }
        }
        if let Some(n) = self.depth_grid {
            if n == 0 || n > width.min(height) {
                return Err(DataError::invalid(format!(
                    "--depth-grid {n}: must be in 1..={} (the image is {width}×{height})",
                    width.min(height)
                )));
            }
            let (w, h) = self.depth_size(width, height);
            let aspect = (w as f64 / h as f64) / (width as f64 / height as f64);
            if (aspect - 1.0).abs() > 0.01 {
                return Err(DataError::invalid(format!(
                    "--depth-grid {n}: a {w}×{h} depth map does not keep the {width}×{height} image's aspect \
                     ratio within 1 %; choose a grid that divides both sides"
                )));
            }
        }
        Ok(())
    }

    /// The options as transforms.json's `generator.capture` records them.
    pub fn to_json(&self, depth_noise: DepthNoise) -> serde_json::Value {
        json!({
            "jpeg_quality": self.jpeg_quality,
            "lens": self.lens.model_name(),
            "depth_grid": self.depth_grid,
            "depth_noise": depth_noise.name(),
            "confidence": self.confidence,
            "normals": self.normals,
            "masks": self.masks,
            "hdr": self.hdr,
            "pose_noise": self.pose_perturbation().map(|p| json!({
                "cm": p.cm, "deg": p.deg,
                "kind": "fixed magnitudes: translation in a uniformly random direction, rotation about a uniformly random axis through the camera centre",
            })),
            "scored_against": "the exact room: i2sdf synth with the same preset or scene, seed, size and views and none of the capture options",
        })
    }
}

/// The lens of `--lens`: `opencv`, `fisheye` or `none`.
pub fn lens_preset(name: &str) -> Result<Lens, DataError> {
    match name {
        "opencv" => Ok(PHONE_OPENCV),
        "fisheye" => Ok(PHONE_FISHEYE),
        "none" => Ok(Lens::Pinhole),
        _ => Err(DataError::invalid(format!(
            "--lens: '{name}' is not opencv, fisheye or none"
        ))),
    }
}

/// ARKit-like confidence of a depth sample (0 low, 1 medium, 2 high) from its true z-depth `z`
/// (metres), the cosine `cos` between its ray and the surface normal, and `edge`, how far its
/// footprint is from one plane ([`edge_measure`]: 0 on a plane however slanted, the relative
/// depth step where the footprint straddles a depth edge):
/// - low: a depth edge (edge > 5 %), a grazing surface (over 80° from the ray) or beyond 5 m;
/// - medium: a smaller step or crease (edge > 1 %), over 70° from the ray, or beyond 3.5 m;
/// - high otherwise.
pub fn confidence_of(z: f32, cos: f32, edge: f32) -> u8 {
    if edge > EDGE_LOW || cos < 0.1736 || z > 5.0 {
        0
    } else if edge > 0.01 || cos < 0.342 || z > 3.5 {
        1
    } else {
        2
    }
}

/// Non-planarity of a sample's footprint: its centre's z-depth `z` against the two diagonals of
/// its cell's corners (`corners` in the order top-left, top-right, bottom-left, bottom-right).
/// Inverse depth is affine in the image over a plane (pinhole; nearly so through a mild lens), so
/// the centre's inverse depth is the mean of each diagonal's; the measure is the larger relative
/// departure, 0 on any plane, large where the footprint straddles a depth edge.
pub fn edge_measure(z: f32, corners: [f32; 4]) -> f32 {
    let diagonal = |a: f32, b: f32| (z * 0.5 * (1.0 / a + 1.0 / b) - 1.0).abs();
    diagonal(corners[0], corners[3]).max(diagonal(corners[1], corners[2]))
}

/// Above this edge measure a low-confidence sample lies on a depth edge (a flying pixel).
const EDGE_LOW: f32 = 0.05;
/// Relative error (standard deviation) of a low-confidence sample off edges.
const LOW_CONFIDENCE_ERROR: f32 = 0.1;

/// The sensor depth of one view: z-depth at the pixel centres of `cam`'s image resized to
/// `width`×`height` (metres, 0 where nothing was measured), and its confidence.
pub struct SensorDepth {
    pub width: usize,
    pub height: usize,
    pub depth: Vec<f32>,
    pub confidence: Option<Vec<u8>>,
}

/// What one traced sensor ray saw: its z-depth and |cos| between the ray and the surface.
fn trace(scene: &RenderScene, origin: Vec3, dirs: &[Vec3], forward: Vec3) -> Vec<Option<(f32, f32)>> {
    let rays: Vec<Ray> = dirs.iter().map(|d| Ray::new(origin, *d, 0.0, f32::INFINITY)).collect();
    let mut hits: Vec<Option<Hit>> = vec![None; rays.len()];
    scene.geometry.intersect(&rays, &mut hits);
    hits.iter()
        .zip(&rays)
        .map(|(h, r)| h.map(|h| (h.t * r.dir.dot(forward), h.normal.dot(r.dir).abs())))
        .collect()
}

/// Traces the sensor's rays of `cam` (its lens included) on a `width`×`height` grid mapped onto
/// the image: the true z-depth at each sample's centre, then the paper's `noise`, then, with
/// `confidence`, the confidence map and its low samples' errors, drawn from `rng` in pixel order.
pub fn sensor_depth(
    scene: &RenderScene,
    cam: &Camera,
    (width, height): (usize, usize),
    noise: DepthNoise,
    confidence: bool,
    rng: &mut impl Rng,
) -> SensorDepth {
    let gen = cam.resized(width, height).ray_generator();
    let forward = gen.forward();
    // Centres (w×h), then with confidence the cell corners ((w+1)×(h+1)).
    let centres: Vec<Option<(f32, f32)>> = (0..height)
        .into_par_iter()
        .flat_map_iter(|y| {
            let dirs: Vec<Vec3> = (0..width).map(|x| gen.dir(x as f32 + 0.5, y as f32 + 0.5)).collect();
            trace(scene, gen.origin, &dirs, forward)
        })
        .collect();
    let mut depth: Vec<f32> = centres.iter().map(|c| c.map_or(0.0, |c| c.0)).collect();
    noise.apply(&mut depth, rng);
    if !confidence {
        return SensorDepth {
            width,
            height,
            depth,
            confidence: None,
        };
    }
    let corners: Vec<Option<(f32, f32)>> = (0..=height)
        .into_par_iter()
        .flat_map_iter(|y| {
            let dirs: Vec<Vec3> = (0..=width).map(|x| gen.dir(x as f32, y as f32)).collect();
            trace(scene, gen.origin, &dirs, forward)
        })
        .collect();
    let mut conf = vec![0u8; width * height];
    for y in 0..height {
        for x in 0..width {
            let i = y * width + x;
            let Some((z, cos)) = centres[i] else {
                depth[i] = 0.0;
                continue;
            };
            let corner_z = [(x, y), (x + 1, y), (x, y + 1), (x + 1, y + 1)]
                .map(|(cx, cy)| corners[cy * (width + 1) + cx].map_or(f32::INFINITY, |c| c.0));
            let (lo, hi) = corner_z.iter().fold((z, z), |(lo, hi), &c| (lo.min(c), hi.max(c)));
            let edge = edge_measure(z, corner_z);
            conf[i] = confidence_of(z, cos, edge);
            if conf[i] == 0 {
                depth[i] = if edge > EDGE_LOW && hi.is_finite() {
                    // A flying pixel: somewhere between the surfaces the sample straddles.
                    rng.gen_range(lo..=hi)
                } else {
                    (z * (1.0 + LOW_CONFIDENCE_ERROR * standard_normal(rng))).max(0.0)
                };
            }
        }
    }
    SensorDepth {
        width,
        height,
        depth,
        confidence: Some(conf),
    }
}

/// Depth in metres → the 16-bit PNG's millimetres (0 = no depth; beyond 65.535 m saturates).
pub fn depth_to_mm(depth: &[f32]) -> Vec<u16> {
    depth
        .iter()
        .map(|&z| {
            if z.is_finite() && z > 0.0 {
                (z * 1000.0).round().clamp(0.0, 65535.0) as u16
            } else {
                0
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn pose_noise_moves_and_turns_by_exactly_the_requested_amount() {
        let cam = crate::camera::looking(Vec3::new(0.3, 1.4, -0.2), 0.7, -0.1, 64, 48, 75.0);
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        let noise = PoseNoise { cm: 2.0, deg: 1.5 };
        for _ in 0..20 {
            let p = noise.perturb(&cam, &mut rng);
            assert!(((p.center() - cam.center()).length() - 0.02).abs() < 1e-9);
            let rel = p.rotation() * cam.rotation().transpose();
            let angle = ((rel.x_axis.x + rel.y_axis.y + rel.z_axis.z - 1.0) / 2.0)
                .clamp(-1.0, 1.0)
                .acos();
            // acos near 1 magnifies the f32 pose's rounding (~1e-7) to ~1e-4°.
            assert!((angle.to_degrees() - 1.5).abs() < 1e-3, "{}", angle.to_degrees());
            i2sdf_data::camera::validate_rigid(&p.c2w).unwrap();
        }
    }

    #[test]
    fn pose_noise_parses_cm_and_degrees() {
        assert_eq!(PoseNoise::parse("1,0.5").unwrap(), PoseNoise { cm: 1.0, deg: 0.5 });
        for bad in ["1", "a,b", "-1,0", "1,90", ""] {
            let e = PoseNoise::parse(bad).unwrap_err().to_string();
            assert!(e.contains("--pose-noise"), "{e}");
        }
    }

    #[test]
    fn confidence_follows_edges_angles_and_distance() {
        assert_eq!(confidence_of(2.0, 0.9, 0.0), 2);
        assert_eq!(confidence_of(2.0, 0.9, 0.03), 1);
        assert_eq!(confidence_of(2.0, 0.9, 0.3), 0);
        assert_eq!(confidence_of(2.0, 0.3, 0.0), 1);
        assert_eq!(confidence_of(2.0, 0.1, 0.0), 0);
        assert_eq!(confidence_of(4.0, 0.9, 0.0), 1);
        assert_eq!(confidence_of(6.0, 0.9, 0.0), 0);
    }

    #[test]
    fn the_edge_measure_ignores_slanted_planes_and_sees_steps() {
        // A plane: inverse depth affine over the cell (here 1/z = 0.5 + 0.1 x + 0.05 y).
        let inv = |x: f32, y: f32| 1.0 / (0.5 + 0.1 * x + 0.05 * y);
        let corners = [inv(-1.0, -1.0), inv(1.0, -1.0), inv(-1.0, 1.0), inv(1.0, 1.0)];
        assert!(edge_measure(inv(0.0, 0.0), corners) < 1e-6);
        // A step from 2 m to 3 m through the cell.
        assert!(edge_measure(2.0, [2.0, 2.0, 3.0, 3.0]) > 0.15);
    }

    #[test]
    fn the_depth_grid_must_keep_the_aspect_ratio() {
        let grid = |n| CaptureOptions {
            depth_grid: Some(n),
            ..Default::default()
        };
        assert!(grid(4).validate(160, 120).is_ok());
        assert_eq!(grid(4).depth_size(160, 120), (40, 30));
        let e = grid(4).validate(40, 30).unwrap_err().to_string();
        assert!(e.contains("--depth-grid 4"), "{e}");
        assert!(grid(0).validate(40, 30).is_err());
        let q = CaptureOptions {
            jpeg_quality: Some(0),
            ..Default::default()
        };
        assert!(q.validate(40, 30).unwrap_err().to_string().contains("--jpeg-quality"));
    }

    #[test]
    fn the_phone_lenses_are_invertible_over_the_rooms_images() {
        for lens in [PHONE_OPENCV, PHONE_FISHEYE] {
            let mut cam = crate::camera::looking(Vec3::ZERO, 0.0, 0.0, 160, 120, 75.0);
            cam.lens = lens;
            cam.validate_intrinsics().unwrap();
        }
        assert!(CaptureOptions::default().is_exact());
        assert!(!CaptureOptions::phone().is_exact());
    }

    #[test]
    fn depth_in_millimetres_rounds_and_marks_missing_as_zero() {
        assert_eq!(
            depth_to_mm(&[1.2344, 0.0, -1.0, f32::NAN, 70.0]),
            vec![1234, 0, 0, 0, 65535]
        );
    }
}
