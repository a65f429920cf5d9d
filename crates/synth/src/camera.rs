//! Pinhole cameras placed inside the room looking around (inside-out capture).

use crate::tracer::RenderScene;
use glam::{Mat3, Mat4, Vec3};
use i2sdf_data::DataError;
use rand::Rng;

/// A pinhole camera: pixel (x, y) with centre at (x + 0.5, y + 0.5) looks along
/// `rotation · ((x + 0.5 − cx)/fx, −(y + 0.5 − cy)/fy, −1)` (OpenGL camera axes: x right, y up,
/// looking down −z), matching `transforms.json`'s camera-to-world matrices.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub position: Vec3,
    /// Camera-to-world rotation, columns = camera x (right), y (up), z (backwards).
    pub rotation: Mat3,
    pub width: usize,
    pub height: usize,
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
}

impl Camera {
    /// A camera at `position` with yaw (about +y, 0 looks down −z) and pitch, in radians.
    pub fn looking(position: Vec3, yaw: f32, pitch: f32, width: usize, height: usize, fov_x_deg: f32) -> Self {
        let forward = Vec3::new(-yaw.sin() * pitch.cos(), pitch.sin(), -yaw.cos() * pitch.cos());
        let right = forward.cross(Vec3::Y).normalize();
        let up = right.cross(forward);
        let fx = 0.5 * width as f32 / (0.5 * fov_x_deg.to_radians()).tan();
        Camera {
            position,
            rotation: Mat3::from_cols(right, up, -forward),
            width,
            height,
            fx,
            fy: fx,
            cx: 0.5 * width as f32,
            cy: 0.5 * height as f32,
        }
    }

    pub fn forward(&self) -> Vec3 {
        -self.rotation.z_axis
    }

    /// Unit world direction through image point (px, py) in pixel units (pixel centres at +0.5).
    #[inline]
    pub fn ray_dir(&self, px: f32, py: f32) -> Vec3 {
        let c = Vec3::new((px - self.cx) / self.fx, -(py - self.cy) / self.fy, -1.0);
        (self.rotation * c).normalize()
    }

    /// 4×4 camera-to-world, OpenGL/nerfstudio convention.
    pub fn c2w(&self) -> Mat4 {
        Mat4::from_cols(
            self.rotation.x_axis.extend(0.0),
            self.rotation.y_axis.extend(0.0),
            self.rotation.z_axis.extend(0.0),
            self.position.extend(1.0),
        )
    }
}

/// Picks a camera inside the room: eye height and pitch from the scene's rig, outside every
/// closed shape's bounds (with a margin), and with nothing closer than `min_clearance` in a grid
/// of probe rays, so views look across the room rather than into a wall.
pub fn place_camera(
    scene: &RenderScene,
    rng: &mut impl Rng,
    yaw: f32,
    width: usize,
    height: usize,
) -> Result<Camera, DataError> {
    let desc = &scene.desc;
    let (lo, hi) = (Vec3::from(desc.room.min), Vec3::from(desc.room.max));
    let inset = 0.35;
    let mut min_clearance = 0.6f32;
    let mut yaw = yaw;
    for attempt in 0..10_000 {
        if attempt > 0 && attempt % 200 == 0 {
            // A crowded room: relax the clearance and the requested direction.
            min_clearance *= 0.8;
            yaw = rng.gen_range(0.0..std::f32::consts::TAU);
        }
        // Stand on the far side of the room from where the camera looks, so that views look
        // across the room at the furniture along the opposite walls.
        let dir = Vec3::new(-yaw.sin(), 0.0, -yaw.cos());
        let centre = 0.5 * (lo + hi);
        let back = rng.gen_range(0.3..0.85) * (0.5 * (hi - lo) - Vec3::splat(inset)).max(Vec3::ZERO);
        let side = Vec3::new(dir.z, 0.0, -dir.x) * rng.gen_range(-0.5..0.5) * (hi.x - lo.x).min(hi.z - lo.z) * 0.5;
        let mut p = centre - dir * back + side;
        p.x = p.x.clamp(lo.x + inset, hi.x - inset);
        p.z = p.z.clamp(lo.z + inset, hi.z - inset);
        p.y = rng.gen_range(desc.camera.eye_height[0]..=desc.camera.eye_height[1]);
        if scene
            .obstacle_bounds
            .iter()
            .any(|(a, b)| p.cmpgt(*a - Vec3::splat(0.25)).all() && p.cmplt(*b + Vec3::splat(0.25)).all())
        {
            continue;
        }
        let jitter = rng.gen_range(-0.35..0.35);
        let pitch = rng
            .gen_range(desc.camera.pitch_deg[0]..=desc.camera.pitch_deg[1])
            .to_radians();
        let cam = Camera::looking(p, yaw + jitter, pitch, width, height, desc.camera.fov_x_deg);
        let clear = (0..5).all(|i| {
            (0..4).all(|j| {
                let px = (i as f32 + 0.5) / 5.0 * width as f32;
                let py = (j as f32 + 0.5) / 4.0 * height as f32;
                let d = cam.ray_dir(px, py);
                scene
                    .bvh
                    .intersect(p, d, 0.0, f32::INFINITY)
                    .is_some_and(|h| h.t * d.dot(cam.forward()) > min_clearance)
            })
        });
        if clear {
            return Ok(cam);
        }
    }
    Err(DataError::invalid(format!(
        "scene {}: no free camera position found in the room",
        desc.name
    )))
}
