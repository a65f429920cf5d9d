//! Pinhole cameras placed inside the room looking around (inside-out capture), as the data
//! layer's [`Camera`].

use crate::tracer::RenderScene;
use glam::{Mat4, Vec3};
use i2sdf_data::{Camera, DataError};
use i2sdf_render::Ray;
use rand::Rng;

/// A camera (the data layer's: OpenCV axes, pixel centres at +0.5) at `position` with yaw (about
/// +y, 0 looks down −z) and pitch, in radians, and a horizontal field of view. The pose is
/// computed in f32 as the generator always has, so transforms.json's OpenGL matrices (written
/// back in f32) are unchanged.
pub fn looking(position: Vec3, yaw: f32, pitch: f32, width: usize, height: usize, fov_x_deg: f32) -> Camera {
    let forward = Vec3::new(-yaw.sin() * pitch.cos(), pitch.sin(), -yaw.cos() * pitch.cos());
    let right = forward.cross(Vec3::Y).normalize();
    let up = right.cross(forward);
    let fx = 0.5 * width as f32 / (0.5 * fov_x_deg.to_radians()).tan();
    // OpenGL camera-to-world (x right, y up, z backwards), converted exactly (sign flips) to
    // OpenCV by the data layer.
    let c2w_gl = Mat4::from_cols(
        right.extend(0.0),
        up.extend(0.0),
        (-forward).extend(0.0),
        position.extend(1.0),
    );
    Camera::from_opengl_c2w(
        width,
        height,
        fx as f64,
        fx as f64,
        (0.5 * width as f32) as f64,
        (0.5 * height as f32) as f64,
        c2w_gl.as_dmat4(),
    )
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
        let cam = looking(p, yaw + jitter, pitch, width, height, desc.camera.fov_x_deg);
        let gen = cam.ray_generator();
        let probes: Vec<Ray> = (0..5)
            .flat_map(|i| (0..4).map(move |j| (i, j)))
            .map(|(i, j)| {
                let px = (i as f32 + 0.5) / 5.0 * width as f32;
                let py = (j as f32 + 0.5) / 4.0 * height as f32;
                Ray::new(gen.origin, gen.dir(px, py), 0.0, f32::INFINITY)
            })
            .collect();
        let mut hits = vec![None; probes.len()];
        i2sdf_render::Geometry::intersect(&scene.geometry, &probes, &mut hits);
        let clear = probes
            .iter()
            .zip(&hits)
            .all(|(r, h)| h.is_some_and(|h| h.t * r.dir.dot(gen.forward()) > min_clearance));
        if clear {
            return Ok(cam);
        }
    }
    Err(DataError::invalid(format!(
        "scene {}: no free camera position found in the room",
        desc.name
    )))
}
