//! Pinhole cameras in the one internal convention of the house (docs/DATASETS.md):
//! OpenCV axes (x right, y down, z forward), camera-to-world pose in world units, and continuous
//! pixel coordinates whose pixel centres sit at +0.5 (pixel (i, j) covers [i, i+1) × [j, j+1)).
//! Every loader converts into this; nothing downstream knows about OpenGL poses or integer-pixel
//! rays. A camera may carry a lens model ([`Lens`]): its rays and projections go through it, so
//! everything that uses these methods sees the distorted capture as it was taken.

pub use crate::lens::Lens;
use glam::{DMat3, DMat4, DVec2, DVec3, DVec4, Mat3, Vec3};

/// A camera: intrinsics in pixels, a lens model and a rigid camera-to-world transform (OpenCV
/// axes).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Camera {
    pub width: usize,
    pub height: usize,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// Camera-to-world, OpenCV axes: columns 0..3 are the camera's x (right), y (down), z (forward)
    /// axes in world coordinates, column 3 the camera centre.
    pub c2w: DMat4,
    /// The lens distortion (pinhole unless the dataset declares a model).
    #[serde(default, skip_serializing_if = "Lens::is_pinhole")]
    pub lens: Lens,
}

/// Flips the y and z axes: OpenGL/nerfstudio camera axes (x right, y up, looking down −z) ↔ OpenCV.
pub const GL_TO_CV: DMat4 = DMat4::from_cols(
    DVec4::new(1.0, 0.0, 0.0, 0.0),
    DVec4::new(0.0, -1.0, 0.0, 0.0),
    DVec4::new(0.0, 0.0, -1.0, 0.0),
    DVec4::new(0.0, 0.0, 0.0, 1.0),
);

impl Camera {
    /// From an OpenGL/nerfstudio camera-to-world matrix (camera looks down −z, y up).
    pub fn from_opengl_c2w(width: usize, height: usize, fx: f64, fy: f64, cx: f64, cy: f64, c2w_gl: DMat4) -> Self {
        Camera {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            c2w: c2w_gl * GL_TO_CV,
            lens: Lens::Pinhole,
        }
    }

    /// The camera-to-world matrix in the OpenGL/nerfstudio convention (for writers).
    pub fn opengl_c2w(&self) -> DMat4 {
        self.c2w * GL_TO_CV
    }

    pub fn center(&self) -> DVec3 {
        self.c2w.w_axis.truncate()
    }

    pub fn rotation(&self) -> DMat3 {
        DMat3::from_mat4(self.c2w)
    }

    pub fn w2c(&self) -> DMat4 {
        // Rigid inverse: [Rᵀ | −Rᵀ c]; exact and cheaper than a general inverse.
        let r_t = self.rotation().transpose();
        let t = -(r_t * self.center());
        rigid(r_t, t)
    }

    /// The intrinsic matrix K (pixel-centre-at-+0.5 convention).
    pub fn k(&self) -> DMat3 {
        DMat3::from_cols(
            DVec3::new(self.fx, 0.0, 0.0),
            DVec3::new(0.0, self.fy, 0.0),
            DVec3::new(self.cx, self.cy, 1.0),
        )
    }

    /// Direction in camera coordinates through continuous pixel position (u, v), scaled so that
    /// z = 1: a point at z-depth `d` along it is `d * dir`. Goes through the lens model.
    #[inline]
    pub fn pixel_dir_cam(&self, u: f64, v: f64) -> DVec3 {
        let p = self
            .lens
            .undistort(DVec2::new((u - self.cx) / self.fx, (v - self.cy) / self.fy));
        p.extend(1.0)
    }

    /// Direction in camera coordinates through the centre of pixel (i, j).
    #[inline]
    pub fn pixel_center_dir_cam(&self, i: usize, j: usize) -> DVec3 {
        self.pixel_dir_cam(i as f64 + 0.5, j as f64 + 0.5)
    }

    /// World-space ray through continuous pixel position (u, v): origin, unit direction, and the
    /// cosine between the ray and the optical axis (z-depth = t · cos).
    pub fn ray(&self, u: f64, v: f64) -> (DVec3, DVec3, f64) {
        let d_cam = self.pixel_dir_cam(u, v);
        let len = d_cam.length();
        let d_world = self.rotation() * (d_cam / len);
        (self.center(), d_world, 1.0 / len)
    }

    /// The world point seen at pixel (i, j)'s centre with z-depth `depth` (paper eq:unproj:
    /// x = t + D · R K⁻¹ [u, v, 1]ᵀ).
    pub fn backproject(&self, i: usize, j: usize, depth: f64) -> DVec3 {
        self.backproject_at(i as f64 + 0.5, j as f64 + 0.5, depth)
    }

    /// The world point seen at continuous pixel position (u, v) with z-depth `depth`.
    pub fn backproject_at(&self, u: f64, v: f64, depth: f64) -> DVec3 {
        self.center() + self.rotation() * (self.pixel_dir_cam(u, v) * depth)
    }

    /// Projects a world point: continuous pixel position (u, v) and z-depth. `None` behind the
    /// camera.
    pub fn project(&self, p: DVec3) -> Option<(f64, f64, f64)> {
        let pc = self.w2c().transform_point3(p);
        if pc.z <= 1e-12 {
            return None;
        }
        let (u, v) = self.project_camera_space(pc);
        Some((u, v, pc.z))
    }

    /// The pixel position of a camera-space point in front of the camera (z > 0), through the
    /// lens model.
    #[inline]
    pub fn project_camera_space(&self, pc: DVec3) -> (f64, f64) {
        let p = self.lens.distort(DVec2::new(pc.x / pc.z, pc.y / pc.z));
        (self.fx * p.x + self.cx, self.fy * p.y + self.cy)
    }

    /// The same camera at another image size (intrinsics scaled with it, the lens unchanged: its
    /// coefficients act on normalized coordinates).
    pub fn resized(&self, width: usize, height: usize) -> Camera {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Camera {
            width,
            height,
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            c2w: self.c2w,
            lens: self.lens,
        }
    }

    /// The camera's identity as bits (size, intrinsics, lens, pose): equal keys mean the same
    /// rays, so renders of one camera can be shared.
    pub fn key(&self) -> Vec<u64> {
        let mut k = vec![self.width as u64, self.height as u64];
        k.extend([self.fx, self.fy, self.cx, self.cy].map(f64::to_bits));
        k.extend(self.lens.params().iter().map(|(_, v)| v.to_bits()));
        k.push(self.lens.model_name().len() as u64);
        k.extend(self.c2w.to_cols_array().map(f64::to_bits));
        k
    }

    /// The same pose and intrinsics without the lens distortion (what `render --pinhole` draws).
    pub fn pinhole(&self) -> Camera {
        Camera {
            lens: Lens::Pinhole,
            ..self.clone()
        }
    }

    /// The camera in f32 for the Monte Carlo renderer's inner loop (one direction per path).
    pub fn ray_generator(&self) -> RayGenerator {
        RayGenerator {
            origin: self.center().as_vec3(),
            rotation: self.rotation().as_mat3(),
            fx: self.fx as f32,
            fy: self.fy as f32,
            cx: self.cx as f32,
            cy: self.cy as f32,
            lens: self.lens,
        }
    }

    /// Checks intrinsics and pose; the message says what is wrong (the caller names the file).
    pub fn validate(&self) -> Result<(), String> {
        self.validate_intrinsics().map_err(|(_, msg)| msg)?;
        validate_rigid(&self.c2w)
    }

    /// The image size, intrinsics and lens alone, with the name of the faulty one (`width`, `fx`,
    /// `fy`, `cx`, `cy`, `distortion`), so that a dataset reader can name its own key for it
    /// (`fl_x` …) rather than the pose's.
    pub fn validate_intrinsics(&self) -> Result<(), (&'static str, String)> {
        if self.width == 0 || self.height == 0 {
            return Err(("width", format!("image size {}×{} is empty", self.width, self.height)));
        }
        for (name, v) in [("fx", self.fx), ("fy", self.fy), ("cx", self.cx), ("cy", self.cy)] {
            if !v.is_finite() {
                return Err((name, format!("intrinsic {name} = {v} is not finite")));
            }
        }
        for (name, v) in [("fx", self.fx), ("fy", self.fy)] {
            if v <= 0.0 {
                return Err((name, format!("focal length {name} = {v}: must be positive")));
            }
        }
        let (fx, fy, cx, cy) = (self.fx, self.fy, self.cx, self.cy);
        self.lens
            .check_invertible(self.width, self.height, fx.max(fy), |u, v| {
                DVec2::new((u - cx) / fx, (v - cy) / fy)
            })
            .map_err(|m| ("distortion", m))?;
        Ok(())
    }
}

/// A [`Camera`] in f32, for generating many rays: the path tracer traces a few hundred per pixel
/// and needs neither the f64 precision of the pose nor a matrix conversion per ray. Same
/// conventions (OpenCV axes, pixel centres at +0.5) and lens model (inverted in f64: a few Newton
/// steps per ray cost nothing beside tracing it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayGenerator {
    pub origin: Vec3,
    /// Camera-to-world rotation, columns = camera x (right), y (down), z (forward).
    pub rotation: Mat3,
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    pub lens: Lens,
}

impl RayGenerator {
    /// Unit world direction through continuous pixel position (u, v).
    #[inline]
    pub fn dir(&self, u: f32, v: f32) -> Vec3 {
        let (x, y) = ((u - self.cx) / self.fx, (v - self.cy) / self.fy);
        let (x, y) = match self.lens {
            Lens::Pinhole => (x, y),
            lens => {
                let p = lens.undistort(DVec2::new(x as f64, y as f64));
                (p.x as f32, p.y as f32)
            }
        };
        (self.rotation * Vec3::new(x, y, 1.0)).normalize()
    }

    /// The optical axis (z-depth of a point p is (p − origin) · forward).
    #[inline]
    pub fn forward(&self) -> Vec3 {
        self.rotation.z_axis
    }
}

/// Checks that a 4×4 pose is a finite rigid transform: orthonormal rotation with det +1 and a
/// bottom row [0 0 0 1].
pub fn validate_rigid(m: &DMat4) -> Result<(), String> {
    if !m.is_finite() {
        return Err("pose has non-finite entries".into());
    }
    let row3 = m.row(3);
    if (row3 - DVec4::new(0.0, 0.0, 0.0, 1.0)).abs().max_element() > 1e-6 {
        return Err(format!(
            "pose's last row is [{}, {}, {}, {}], expected [0, 0, 0, 1]",
            row3.x, row3.y, row3.z, row3.w
        ));
    }
    let r = DMat3::from_mat4(*m);
    let det = r.determinant();
    if det.abs() < 1e-9 {
        return Err("pose is not invertible (rotation determinant is 0)".into());
    }
    let rtr = r.transpose() * r;
    let err = (rtr - DMat3::IDENTITY)
        .to_cols_array()
        .iter()
        .fold(0.0f64, |a, v| a.max(v.abs()));
    if err > 1e-3 {
        return Err(format!(
            "pose is not rigid: its rotation part is not orthonormal (|RᵀR − I| = {err:.2e}; scaled or sheared poses are not supported)"
        ));
    }
    if det < 0.0 {
        return Err("pose is a reflection (rotation determinant is −1)".into());
    }
    Ok(())
}

/// Decomposes a 3×4 projection matrix P = λ·K·[R | t] (world → pixels) into K (with K₃₃ = 1) and a
/// camera-to-world pose, as OpenCV's `decomposeProjectionMatrix` does for IDR/VolSDF data. `p` is
/// row-major. Errors if P is degenerate.
pub fn decompose_projection(p: [[f64; 4]; 3]) -> Result<(DMat3, DMat4), String> {
    let row = |i: usize| DVec3::new(p[i][0], p[i][1], p[i][2]);
    let col3 = DVec3::new(p[0][3], p[1][3], p[2][3]);
    if !(row(0).is_finite() && row(1).is_finite() && row(2).is_finite() && col3.is_finite()) {
        return Err("projection matrix has non-finite entries".into());
    }
    let mut m = [row(0), row(1), row(2)];
    let mut col3 = col3;
    // RQ decomposition by Gram–Schmidt from the last row up: M = K R, K upper triangular.
    let rq = |m: &[DVec3; 3]| -> Option<(DMat3, [DVec3; 3])> {
        let k33 = m[2].length();
        if k33 < 1e-12 {
            return None;
        }
        let r3 = m[2] / k33;
        let k23 = m[1].dot(r3);
        let r2p = m[1] - k23 * r3;
        let k22 = r2p.length();
        if k22 < 1e-12 {
            return None;
        }
        let r2 = r2p / k22;
        let k13 = m[0].dot(r3);
        let k12 = m[0].dot(r2);
        let r1p = m[0] - k13 * r3 - k12 * r2;
        let k11 = r1p.length();
        if k11 < 1e-12 {
            return None;
        }
        let r1 = r1p / k11;
        // Column-major K.
        let k = DMat3::from_cols(
            DVec3::new(k11, 0.0, 0.0),
            DVec3::new(k12, k22, 0.0),
            DVec3::new(k13, k23, k33),
        );
        Some((k, [r1, r2, r3]))
    };
    let (mut k, mut r_rows) = rq(&m).ok_or("projection matrix is degenerate (rank < 3)")?;
    let det = r_rows[0].dot(r_rows[1].cross(r_rows[2]));
    if det < 0.0 {
        // P is only defined up to scale; a negative scale flips R's handedness. Use −P.
        m = [-m[0], -m[1], -m[2]];
        col3 = -col3;
        (k, r_rows) = rq(&m).ok_or("projection matrix is degenerate (rank < 3)")?;
    }
    // P[:,3] = K t  →  t = K⁻¹ P[:,3]; camera centre c = −Rᵀ t.
    let t = k.inverse() * col3;
    let r_w2c = DMat3::from_cols(r_rows[0], r_rows[1], r_rows[2]).transpose();
    let r_c2w = r_w2c.transpose();
    let c = -(r_c2w * t);
    let k = k * (1.0 / k.z_axis.z);
    let c2w = rigid(r_c2w, c);
    Ok((k, c2w))
}

/// A camera looking from `eye` towards `target`, OpenCV axes, `up` the world's up direction.
/// The rigid transform [R | t] (a camera-to-world pose from its rotation and centre).
pub fn rigid(r: DMat3, t: DVec3) -> DMat4 {
    DMat4::from_cols(
        r.x_axis.extend(0.0),
        r.y_axis.extend(0.0),
        r.z_axis.extend(0.0),
        t.extend(1.0),
    )
}

pub fn look_at(eye: DVec3, target: DVec3, up: DVec3) -> DMat4 {
    let z = (target - eye).normalize();
    let x = z.cross(up).normalize();
    let y = z.cross(x);
    DMat4::from_cols(x.extend(0.0), y.extend(0.0), z.extend(0.0), eye.extend(1.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera {
            lens: Default::default(),
            width: 64,
            height: 48,
            fx: 50.0,
            fy: 52.0,
            cx: 32.0,
            cy: 24.0,
            c2w: look_at(DVec3::new(0.3, -0.2, 1.0), DVec3::new(1.0, 2.0, 0.5), DVec3::Z),
        }
    }

    #[test]
    fn backproject_then_project_is_identity() {
        let c = cam();
        assert!(c.validate().is_ok());
        let p = c.backproject(10, 7, 2.5);
        let (u, v, z) = c.project(p).unwrap();
        assert!((u - 10.5).abs() < 1e-9 && (v - 7.5).abs() < 1e-9 && (z - 2.5).abs() < 1e-9);
    }

    #[test]
    fn ray_cosine_converts_ray_length_to_z_depth() {
        let c = cam();
        let (o, d, cos) = c.ray(3.5, 40.5);
        let t = 4.0;
        let (_, _, z) = c.project(o + d * t).unwrap();
        assert!((z - t * cos).abs() < 1e-9);
    }

    #[test]
    fn ray_generator_agrees_with_the_f64_ray() {
        let c = cam();
        let g = c.ray_generator();
        for (u, v) in [(0.0, 0.0), (3.25, 40.5), (63.9, 47.9), (32.0, 24.0)] {
            let (o, d, cos) = c.ray(u, v);
            let df = g.dir(u as f32, v as f32);
            assert!((df.as_dvec3() - d).length() < 1e-6, "{df} vs {d}");
            assert!((g.origin.as_dvec3() - o).length() < 1e-6);
            assert!((df.dot(g.forward()) as f64 - cos).abs() < 1e-6);
        }
    }

    #[test]
    fn opengl_round_trip() {
        let c = cam();
        let gl = c.opengl_c2w();
        // OpenGL camera looks down its −z axis: the same world direction as OpenCV's +z.
        assert!((gl.z_axis.truncate() + c.c2w.z_axis.truncate()).length() < 1e-12);
        let back = Camera::from_opengl_c2w(c.width, c.height, c.fx, c.fy, c.cx, c.cy, gl);
        assert!((back.c2w - c.c2w).abs_diff_eq(DMat4::ZERO, 1e-12));
    }

    #[test]
    fn projection_decomposition_recovers_k_and_pose_even_with_negative_scale() {
        let c = cam();
        let k = c.k();
        let w2c = c.w2c();
        for scale in [1.0, -3.7] {
            let mut p = [[0.0; 4]; 3];
            for i in 0..3 {
                for j in 0..4 {
                    let mut s = 0.0;
                    for l in 0..3 {
                        s += k.col(l)[i] * w2c.col(j)[l];
                    }
                    p[i][j] = s * scale;
                }
            }
            let (k2, c2w) = decompose_projection(p).unwrap();
            assert!(k2.abs_diff_eq(k, 1e-9), "{k2:?}");
            assert!(c2w.abs_diff_eq(c.c2w, 1e-9), "{c2w:?}");
        }
    }

    #[test]
    fn validation_catches_bad_poses() {
        let mut c = cam();
        c.c2w.x_axis *= 2.0;
        assert!(c.validate().unwrap_err().contains("not rigid"));
        let mut c = cam();
        c.c2w.x_axis = DVec4::ZERO;
        assert!(c.validate().unwrap_err().contains("not invertible"));
        let mut c = cam();
        c.c2w.x_axis = -c.c2w.x_axis;
        assert!(c.validate().unwrap_err().contains("reflection"));
        let mut c = cam();
        c.fx = -1.0;
        assert!(c.validate().is_err());
        let mut c = cam();
        c.c2w.w_axis.x = f64::NAN;
        assert!(c.validate().unwrap_err().contains("non-finite"));
    }
}
