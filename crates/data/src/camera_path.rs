//! Camera paths for videos (`i2sdf render --path`, `i2sdf edit --path`): an orbit inside the room
//! and an interpolation through given cameras (the paper's view-interpolation videos). Every
//! camera keeps the intrinsics of the first camera it is made from.
//!
//! "Up" is not a convention of the datasets (the paper's scenes and ours differ), so it is
//! measured: the mean of the cameras' own up axes (−y in OpenCV axes). Indoor captures are taken
//! upright, so this is the room's vertical up to a few degrees.

use crate::{Bounds, Camera, DataError};
use glam::{DMat3, DMat4, DQuat, DVec3};

/// Which path.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PathKind {
    /// A full turn on a circle around the room's vertical axis at the cameras' mean height,
    /// looking across the room through its axis.
    Orbit,
    /// Through the given cameras in order: positions along straight segments, orientations by
    /// spherical interpolation, frames spread evenly by distance (and angle, for cameras that
    /// turn in place).
    Interpolate,
}

impl PathKind {
    /// `"orbit"` or `"interpolate"`.
    pub fn from_name(name: &str) -> Result<Self, String> {
        match name {
            "orbit" => Ok(PathKind::Orbit),
            "interpolate" => Ok(PathKind::Interpolate),
            other => Err(format!("{other:?}: must be \"orbit\" or \"interpolate\"")),
        }
    }
}

/// The path of `frames` cameras of `kind` from `cameras` (the split's views, or the keyframes
/// of an interpolation) in a scene of `bounds`.
pub fn camera_path(
    kind: PathKind,
    cameras: &[Camera],
    bounds: &Bounds,
    frames: usize,
) -> Result<Vec<Camera>, DataError> {
    if cameras.is_empty() {
        return Err(DataError::invalid("a camera path needs at least one camera"));
    }
    if frames == 0 {
        return Err(DataError::invalid("--frames 0: a path has at least one frame"));
    }
    match kind {
        PathKind::Orbit => Ok(orbit(cameras, bounds, frames)),
        PathKind::Interpolate if cameras.len() < 2 => Err(DataError::invalid(
            "--path interpolate needs at least two cameras to interpolate between",
        )),
        PathKind::Interpolate => Ok(interpolate(cameras, frames)),
    }
}

/// The cameras' mean up axis (unit): −y of each OpenCV camera.
pub fn mean_up(cameras: &[Camera]) -> DVec3 {
    let up: DVec3 = cameras.iter().map(|c| -(c.rotation() * DVec3::Y)).sum();
    up.try_normalize().unwrap_or(DVec3::Y)
}

/// The camera at `eye` looking at `target` with `up` (OpenCV axes), `like`'s intrinsics.
pub fn look_at(like: &Camera, eye: DVec3, target: DVec3, up: DVec3) -> Camera {
    let z = (target - eye).try_normalize().unwrap_or(DVec3::Z);
    // Any axis not parallel to z stands in for a degenerate up.
    let x = z
        .cross(up)
        .try_normalize()
        .unwrap_or_else(|| z.any_orthonormal_vector());
    let y = z.cross(x);
    Camera {
        c2w: DMat4::from_cols(x.extend(0.0), y.extend(0.0), z.extend(0.0), eye.extend(1.0)),
        ..like.clone()
    }
}

fn orbit(cameras: &[Camera], bounds: &Bounds, frames: usize) -> Vec<Camera> {
    let up = mean_up(cameras);
    let (lo, hi) = (DVec3::from_array(bounds.min), DVec3::from_array(bounds.max));
    let centre = 0.5 * (lo + hi);
    // Horizontal axes of the room: any unit vector orthogonal to up and its cross product.
    let a = up.any_orthonormal_vector();
    let b = up.cross(a);
    let half = 0.5 * (hi - lo);
    // The room's horizontal half-extent along the circle's axes (bounds are axis-aligned in the
    // world, the circle may not be): the smaller one, so the circle stays inside the room.
    let reach = |d: DVec3| (half * d.abs()).element_sum();
    let radius = 0.4 * reach(a).min(reach(b));
    let mean_eye: DVec3 = cameras.iter().map(|c| c.center()).sum::<DVec3>() / cameras.len() as f64;
    // The eye height (along up) of the cameras, the room's centre otherwise.
    let axis = centre + up * (mean_eye - centre).dot(up);
    (0..frames)
        .map(|i| {
            let t = std::f64::consts::TAU * i as f64 / frames as f64;
            let offset = radius * (a * t.cos() + b * t.sin());
            // Looking through the axis to the far side, slightly down: the floor and the far
            // wall both in view.
            let target = axis - 2.0 * offset - 0.15 * radius * up;
            look_at(&cameras[0], axis + offset, target, up)
        })
        .collect()
}

fn interpolate(cameras: &[Camera], frames: usize) -> Vec<Camera> {
    // Segment lengths: distance plus the turn in radians × a metre-ish scale, so that a camera
    // turning in place still gets frames.
    let scale = {
        let c: Vec<DVec3> = cameras.iter().map(Camera::center).collect();
        let mean = c.iter().sum::<DVec3>() / c.len() as f64;
        (c.iter().map(|p| (*p - mean).length()).sum::<f64>() / c.len() as f64).max(1e-3)
    };
    let rot = |c: &Camera| DQuat::from_mat3(&c.rotation());
    let lengths: Vec<f64> = cameras
        .windows(2)
        .map(|w| (w[1].center() - w[0].center()).length() + scale * rot(&w[0]).angle_between(rot(&w[1])) + 1e-9)
        .collect();
    let total: f64 = lengths.iter().sum();
    (0..frames)
        .map(|i| {
            let mut s = if frames == 1 {
                0.0
            } else {
                total * i as f64 / (frames - 1) as f64
            };
            let mut k = 0;
            while k + 1 < lengths.len() && s > lengths[k] {
                s -= lengths[k];
                k += 1;
            }
            let t = (s / lengths[k]).clamp(0.0, 1.0);
            let (c0, c1) = (&cameras[k], &cameras[k + 1]);
            let q = rot(c0).slerp(rot(c1), t);
            let eye = c0.center().lerp(c1.center(), t);
            let r = DMat3::from_quat(q);
            Camera {
                c2w: crate::camera::rigid(r, eye),
                ..cameras[0].clone()
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam(eye: DVec3, target: DVec3) -> Camera {
        let like = Camera {
            lens: Default::default(),
            width: 8,
            height: 6,
            fx: 8.0,
            fy: 8.0,
            cx: 4.0,
            cy: 3.0,
            c2w: DMat4::IDENTITY,
        };
        look_at(&like, eye, target, DVec3::Y)
    }

    fn room() -> Bounds {
        Bounds {
            min: [-2.0, 0.0, -3.0],
            max: [2.0, 2.5, 3.0],
        }
    }

    #[test]
    fn look_at_is_a_rigid_upright_camera_facing_the_target() {
        let c = cam(DVec3::new(1.0, 1.5, 1.0), DVec3::new(-1.0, 1.0, -2.0));
        let r = c.rotation();
        assert!((r * r.transpose()).abs_diff_eq(DMat3::IDENTITY, 1e-12));
        assert!((r.determinant() - 1.0).abs() < 1e-12);
        // The target projects to the principal point; the camera's x axis is horizontal.
        let (u, v, _) = c.project(DVec3::new(-1.0, 1.0, -2.0)).unwrap();
        assert!((u - 4.0).abs() < 1e-9 && (v - 3.0).abs() < 1e-9);
        assert!((r * DVec3::X).y.abs() < 1e-12);
        assert!((mean_up(&[c]) - DVec3::Y).length() < 0.3, "tilted down, still upright");
    }

    #[test]
    fn an_orbit_stays_inside_the_room_at_the_cameras_height_and_closes() {
        // Level cameras facing opposite ways (real captures pitch a little both ways).
        let views = [
            cam(DVec3::new(0.5, 1.6, 0.0), DVec3::new(-1.0, 1.6, -2.0)),
            cam(DVec3::new(-0.5, 1.4, 1.0), DVec3::new(0.5, 1.4, 3.0)),
        ];
        let path = camera_path(PathKind::Orbit, &views, &room(), 24).unwrap();
        assert_eq!(path.len(), 24);
        for c in &path {
            let e = c.center();
            assert!(e.x.abs() < 2.0 && e.z.abs() < 3.0, "{e}");
            assert!((e.y - 1.5).abs() < 0.15, "eye height {}", e.y);
            assert_eq!((c.width, c.fx), (8, 8.0));
            // Each looks through the vertical axis.
            let (u, _, _) = c.project(DVec3::new(0.0, e.y, 0.0)).unwrap();
            assert!((u - 4.0).abs() < 1e-6);
        }
        // Evenly spaced on a circle: the step between frames is constant, the loop closes.
        let step = |a: &Camera, b: &Camera| (a.center() - b.center()).length();
        let d0 = step(&path[0], &path[1]);
        assert!((step(&path[23], &path[0]) - d0).abs() < 1e-9);
    }

    #[test]
    fn interpolation_passes_through_its_keyframes() {
        let keys = [
            cam(DVec3::new(0.0, 1.5, 0.0), DVec3::new(0.0, 1.5, -1.0)),
            cam(DVec3::new(1.0, 1.5, 0.0), DVec3::new(1.0, 1.5, -1.0)),
            cam(DVec3::new(1.0, 1.5, 0.0), DVec3::new(2.0, 1.5, 0.0)),
        ];
        let path = camera_path(PathKind::Interpolate, &keys, &room(), 31).unwrap();
        assert!(path[0].c2w.abs_diff_eq(keys[0].c2w, 1e-9));
        assert!(path[30].c2w.abs_diff_eq(keys[2].c2w, 1e-9));
        for c in &path {
            let r = c.rotation();
            assert!((r * r.transpose()).abs_diff_eq(DMat3::IDENTITY, 1e-9));
        }
        // The second segment turns in place (90° at a spread of ~0.47): it gets frames too.
        let turning = path.iter().filter(|c| (c.center().x - 1.0).abs() < 1e-9).count();
        assert!(turning > 5, "{turning}");
    }

    #[test]
    fn bad_paths_are_refused() {
        let one = [cam(DVec3::ONE, DVec3::ZERO)];
        assert!(camera_path(PathKind::Interpolate, &one, &room(), 10).is_err());
        assert!(camera_path(PathKind::Orbit, &one, &room(), 0).is_err());
        assert!(camera_path(PathKind::Orbit, &[], &room(), 4).is_err());
        assert!(PathKind::from_name("spiral").is_err());
    }
}
