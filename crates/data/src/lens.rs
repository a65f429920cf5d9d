//! Lens models: how a camera-space direction lands on the image plane, in normalized coordinates
//! (x/z, y/z before the intrinsics K are applied). Every ray of the house goes through
//! [`Lens::undistort`] (training, render, eval, edit) and every projection through
//! [`Lens::distort`], so a distorted capture is used as it is: no image is resampled.
//!
//! The models and their parameter names are OpenCV's, which COLMAP and nerfstudio share:
//! - `Pinhole`: no distortion (COLMAP's PINHOLE and SIMPLE_PINHOLE).
//! - `BrownConrady`: radial k1 k2 k3 and tangential p1 p2 (OpenCV's default model; COLMAP's OPENCV,
//!   and its RADIAL / SIMPLE_RADIAL, which are the same with fewer non-zero terms):
//!   x_d = x·(1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²),
//!   y_d = y·(1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y²) + 2 p2 x y.
//! - `Fisheye`: the equidistant Kannala–Brandt model of OpenCV's fisheye module (COLMAP's
//!   OPENCV_FISHEYE): θ = atan(r), θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸), x_d = (θ_d / r) x.

use glam::DVec2;

/// A lens distortion model (see the module documentation for the formulas).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "model", rename_all = "snake_case")]
pub enum Lens {
    #[default]
    Pinhole,
    BrownConrady {
        k1: f64,
        k2: f64,
        k3: f64,
        p1: f64,
        p2: f64,
    },
    Fisheye {
        k1: f64,
        k2: f64,
        k3: f64,
        k4: f64,
    },
}

/// The largest incidence angle a fisheye ray is given (just under 90°): the house's rays are
/// directions with z = 1, which cannot express a ray at or beyond 90° off the axis.
const MAX_FISHEYE_THETA: f64 = 89.5 * std::f64::consts::PI / 180.0;

impl Lens {
    pub fn is_pinhole(&self) -> bool {
        match *self {
            Lens::Pinhole => true,
            Lens::BrownConrady { k1, k2, k3, p1, p2 } => [k1, k2, k3, p1, p2].iter().all(|v| *v == 0.0),
            Lens::Fisheye { .. } => false,
        }
    }

    /// The lens of a named camera model (COLMAP's and nerfstudio's names) from its coefficients,
    /// looked up by key (`k1` … `k4`, `p1`, `p2`; absent ones are 0). A coefficient the model
    /// does not have must be absent or 0. Errors name the key.
    pub fn from_model(model: &str, get: impl Fn(&str) -> Option<f64>) -> Result<Lens, (&'static str, String)> {
        let allowed: &[&'static str] = match model {
            "PINHOLE" | "SIMPLE_PINHOLE" => &[],
            "SIMPLE_RADIAL" => &["k1"],
            "RADIAL" => &["k1", "k2"],
            "OPENCV" => &["k1", "k2", "k3", "p1", "p2"],
            "OPENCV_FISHEYE" => &["k1", "k2", "k3", "k4"],
            _ => {
                return Err((
                    "camera_model",
                    format!(
                        "'{model}' is not a supported camera model (PINHOLE, SIMPLE_PINHOLE, SIMPLE_RADIAL, RADIAL, \
                         OPENCV, OPENCV_FISHEYE)"
                    ),
                ))
            }
        };
        for key in ["k1", "k2", "k3", "k4", "p1", "p2"] {
            let v = get(key).unwrap_or(0.0);
            if !v.is_finite() {
                return Err((key, format!("{key} = {v} is not finite")));
            }
            if v != 0.0 && !allowed.contains(&key) {
                return Err((key, format!("{key} = {v}, but the {model} camera model has no {key}")));
            }
        }
        let k = |key: &str| get(key).unwrap_or(0.0);
        Ok(match model {
            "PINHOLE" | "SIMPLE_PINHOLE" => Lens::Pinhole,
            "OPENCV_FISHEYE" => Lens::Fisheye {
                k1: k("k1"),
                k2: k("k2"),
                k3: k("k3"),
                k4: k("k4"),
            },
            _ => Lens::BrownConrady {
                k1: k("k1"),
                k2: k("k2"),
                k3: k("k3"),
                p1: k("p1"),
                p2: k("p2"),
            },
        })
    }

    /// The name a user would give it (COLMAP's model names).
    pub fn model_name(&self) -> &'static str {
        match self {
            Lens::Pinhole => "PINHOLE",
            Lens::BrownConrady { .. } => "OPENCV",
            Lens::Fisheye { .. } => "OPENCV_FISHEYE",
        }
    }

    /// The parameters as `(key, value)` pairs, in the keys of `transforms.json`.
    pub fn params(&self) -> Vec<(&'static str, f64)> {
        match *self {
            Lens::Pinhole => Vec::new(),
            Lens::BrownConrady { k1, k2, k3, p1, p2 } => {
                vec![("k1", k1), ("k2", k2), ("k3", k3), ("p1", p1), ("p2", p2)]
            }
            Lens::Fisheye { k1, k2, k3, k4 } => vec![("k1", k1), ("k2", k2), ("k3", k3), ("k4", k4)],
        }
    }

    /// Undistorted normalized coordinates → distorted normalized coordinates (where the lens puts
    /// the direction (x, y, 1)).
    #[inline]
    pub fn distort(&self, p: DVec2) -> DVec2 {
        match *self {
            Lens::Pinhole => p,
            Lens::BrownConrady { k1, k2, k3, p1, p2 } => {
                let (x, y) = (p.x, p.y);
                let r2 = x * x + y * y;
                let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
                DVec2::new(
                    x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                    y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
                )
            }
            Lens::Fisheye { k1, k2, k3, k4 } => {
                let r = p.length();
                if r < 1e-12 {
                    return p;
                }
                let theta = r.atan();
                p * (fisheye_theta_d(theta, k1, k2, k3, k4) / r)
            }
        }
    }

    /// Distorted normalized coordinates → undistorted ones: the inverse of [`Lens::distort`] by
    /// Newton's method (closed form for the pinhole). Returns the best iterate; use
    /// [`Lens::check_invertible`] once per camera to know it converges over the image.
    #[inline]
    pub fn undistort(&self, pd: DVec2) -> DVec2 {
        match *self {
            Lens::Pinhole => pd,
            Lens::BrownConrady { k1, k2, k3, p1, p2 } => {
                // Newton on f(p) = distort(p) − pd with the analytic Jacobian, from p = pd.
                let mut p = pd;
                for _ in 0..20 {
                    let (x, y) = (p.x, p.y);
                    let r2 = x * x + y * y;
                    let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
                    // d(radial)/d(r²)
                    let dr = k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3);
                    let fx = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - pd.x;
                    let fy = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - pd.y;
                    let j00 = radial + 2.0 * x * x * dr + 2.0 * p1 * y + 6.0 * p2 * x;
                    let j01 = 2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y;
                    let j10 = 2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y;
                    let j11 = radial + 2.0 * y * y * dr + 6.0 * p1 * y + 2.0 * p2 * x;
                    let det = j00 * j11 - j01 * j10;
                    if det.abs() < 1e-15 {
                        break;
                    }
                    let step = DVec2::new((j11 * fx - j01 * fy) / det, (j00 * fy - j10 * fx) / det);
                    p -= step;
                    if step.length_squared() < 1e-26 {
                        break;
                    }
                }
                p
            }
            Lens::Fisheye { k1, k2, k3, k4 } => {
                let rd = pd.length();
                if rd < 1e-12 {
                    return pd;
                }
                // Solve θ_d(θ) = rd for θ by Newton from θ = rd.
                let mut theta = rd.min(MAX_FISHEYE_THETA);
                for _ in 0..20 {
                    let f = fisheye_theta_d(theta, k1, k2, k3, k4) - rd;
                    let t2 = theta * theta;
                    let df = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)));
                    if df.abs() < 1e-15 {
                        break;
                    }
                    let step = f / df;
                    theta = (theta - step).clamp(0.0, MAX_FISHEYE_THETA);
                    if step.abs() < 1e-13 {
                        break;
                    }
                }
                pd * (theta.tan() / rd)
            }
        }
    }

    /// Checks that the model is invertible over the image: undistorting and distorting again
    /// every point of a grid over the image (and its border) must come back within 1e-3 pixels,
    /// and the model must be monotonic along the rays through the centre. `to_normalized` maps a
    /// pixel position to distorted normalized coordinates. The error says where it fails.
    pub fn check_invertible(
        &self,
        width: usize,
        height: usize,
        focal: f64,
        to_normalized: impl Fn(f64, f64) -> DVec2,
    ) -> Result<(), String> {
        if self.is_pinhole() {
            return Ok(());
        }
        for v in self.params().iter().map(|(_, v)| v) {
            if !v.is_finite() {
                return Err(format!("distortion coefficient {v} is not finite"));
            }
        }
        let n = 24;
        for a in 0..=n {
            for b in 0..=n {
                let u = width as f64 * a as f64 / n as f64;
                let v = height as f64 * b as f64 / n as f64;
                let pd = to_normalized(u, v);
                let p = self.undistort(pd);
                let back = self.distort(p);
                let err_px = (back - pd).length() * focal;
                if !(err_px < 1e-3) {
                    return Err(format!(
                        "the {} lens model cannot be inverted at pixel ({u:.0}, {v:.0}) (off by {err_px:.2e} px): \
                         its coefficients fold the image over itself there",
                        self.model_name()
                    ));
                }
            }
        }
        Ok(())
    }
}

#[inline]
fn fisheye_theta_d(theta: f64, k1: f64, k2: f64, k3: f64, k4: f64) -> f64 {
    let t2 = theta * theta;
    theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lenses() -> Vec<Lens> {
        vec![
            Lens::Pinhole,
            Lens::BrownConrady {
                k1: -0.28,
                k2: 0.07,
                k3: 0.0,
                p1: 0.001,
                p2: -0.0005,
            },
            Lens::BrownConrady {
                k1: 0.12,
                k2: -0.03,
                k3: 0.01,
                p1: -0.002,
                p2: 0.003,
            },
            Lens::Fisheye {
                k1: 0.05,
                k2: -0.01,
                k3: 0.002,
                k4: -0.0003,
            },
        ]
    }

    #[test]
    fn undistort_inverts_distort_over_a_wide_field() {
        for lens in lenses() {
            for i in -10..=10 {
                for j in -8..=8 {
                    let p = DVec2::new(i as f64 * 0.07, j as f64 * 0.07);
                    let back = lens.undistort(lens.distort(p));
                    assert!((back - p).length() < 1e-10, "{lens:?} at {p}: {back}");
                }
            }
        }
    }

    #[test]
    fn brown_conrady_matches_the_formula_and_fisheye_the_angle() {
        let lens = Lens::BrownConrady {
            k1: 0.1,
            k2: 0.01,
            k3: 0.001,
            p1: 0.002,
            p2: 0.003,
        };
        let d = lens.distort(DVec2::new(0.3, -0.2));
        let (x, y, r2) = (0.3f64, -0.2f64, 0.13f64);
        let radial = 1.0 + 0.1 * r2 + 0.01 * r2 * r2 + 0.001 * r2 * r2 * r2;
        let ex = x * radial + 2.0 * 0.002 * x * y + 0.003 * (r2 + 2.0 * x * x);
        let ey = y * radial + 0.002 * (r2 + 2.0 * y * y) + 2.0 * 0.003 * x * y;
        assert!((d.x - ex).abs() < 1e-15 && (d.y - ey).abs() < 1e-15);
        // An undistorted fisheye with k = 0 is the equidistant projection: r_d = θ.
        let f = Lens::Fisheye {
            k1: 0.0,
            k2: 0.0,
            k3: 0.0,
            k4: 0.0,
        };
        let p = DVec2::new(1.0, 0.0); // 45°
        assert!((f.distort(p).x - std::f64::consts::FRAC_PI_4).abs() < 1e-15);
    }

    #[test]
    fn named_models_take_their_own_coefficients_only() {
        let get = |pairs: &'static [(&'static str, f64)]| move |k: &str| pairs.iter().find(|p| p.0 == k).map(|p| p.1);
        assert_eq!(Lens::from_model("PINHOLE", get(&[])).unwrap(), Lens::Pinhole);
        assert_eq!(
            Lens::from_model("SIMPLE_RADIAL", get(&[("k1", 0.1)])).unwrap(),
            Lens::BrownConrady {
                k1: 0.1,
                k2: 0.0,
                k3: 0.0,
                p1: 0.0,
                p2: 0.0
            }
        );
        assert!(matches!(
            Lens::from_model("OPENCV_FISHEYE", get(&[("k4", 0.01)])).unwrap(),
            Lens::Fisheye { k4, .. } if k4 == 0.01
        ));
        assert_eq!(Lens::from_model("RADIAL", get(&[("p1", 0.1)])).unwrap_err().0, "p1");
        assert_eq!(Lens::from_model("OPENCV", get(&[("k4", 0.1)])).unwrap_err().0, "k4");
        assert_eq!(Lens::from_model("PINHOLE", get(&[("k1", 0.1)])).unwrap_err().0, "k1");
        assert_eq!(Lens::from_model("FOV", get(&[])).unwrap_err().0, "camera_model");
    }

    #[test]
    fn folding_coefficients_are_refused() {
        // k1 = −0.6 folds r_d(r) = r(1 − 0.6 r²) back beyond r = 0.75: the corners of a wide image
        // cannot be inverted.
        let lens = Lens::BrownConrady {
            k1: -0.6,
            k2: 0.0,
            k3: 0.0,
            p1: 0.0,
            p2: 0.0,
        };
        let err = lens
            .check_invertible(640, 480, 300.0, |u, v| {
                DVec2::new((u - 320.0) / 300.0, (v - 240.0) / 300.0)
            })
            .unwrap_err();
        assert!(err.contains("cannot be inverted"), "{err}");
        for lens in lenses() {
            lens.check_invertible(640, 480, 500.0, |u, v| {
                DVec2::new((u - 320.0) / 500.0, (v - 240.0) / 500.0)
            })
            .unwrap();
        }
    }
}
