//! From the dataset's world axes to glTF's: glTF is right-handed with +Y up (and cameras looking
//! down −Z, as the OpenGL camera convention). The built-in rooms are +Y up already; a COLMAP or
//! ARKit capture may have any axis up, so the up axis is declared (`--up`) or taken from the
//! cameras: a capture is held upright, so the mean of the cameras' up vectors (−y of their OpenCV
//! axes) is near the world's up (nerfstudio's "up" orientation does the same).

use glam::{DMat3, DVec3};
use i2sdf_data::{Camera, DataError};

/// A signed world axis, the one that becomes glTF's +Y.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UpAxis {
    PosX,
    NegX,
    PosY,
    NegY,
    PosZ,
    NegZ,
}

impl UpAxis {
    pub const ALL: [UpAxis; 6] = [
        UpAxis::PosX,
        UpAxis::NegX,
        UpAxis::PosY,
        UpAxis::NegY,
        UpAxis::PosZ,
        UpAxis::NegZ,
    ];

    pub fn name(self) -> &'static str {
        match self {
            UpAxis::PosX => "+x",
            UpAxis::NegX => "-x",
            UpAxis::PosY => "+y",
            UpAxis::NegY => "-y",
            UpAxis::PosZ => "+z",
            UpAxis::NegZ => "-z",
        }
    }

    /// `+x`, `-y`, `z` (= `+z`), … (case-insensitive).
    pub fn parse(s: &str) -> Option<UpAxis> {
        let t = s.trim().to_ascii_lowercase();
        let t = t.strip_prefix('+').unwrap_or(&t);
        UpAxis::ALL.into_iter().find(|a| a.name().trim_start_matches('+') == t)
    }

    pub fn vector(self) -> DVec3 {
        match self {
            UpAxis::PosX => DVec3::X,
            UpAxis::NegX => -DVec3::X,
            UpAxis::PosY => DVec3::Y,
            UpAxis::NegY => -DVec3::Y,
            UpAxis::PosZ => DVec3::Z,
            UpAxis::NegZ => -DVec3::Z,
        }
    }

    /// The axis nearest the cameras' mean up vector, with the angle between them (degrees), or
    /// an error when the cameras do not agree on an up (their mean is shorter than half a unit:
    /// a capture taken in every orientation).
    pub fn from_cameras(cameras: &[Camera]) -> Result<(UpAxis, f64), DataError> {
        let sum: DVec3 = cameras.iter().map(|c| -c.rotation().y_axis).sum();
        let n = cameras.len().max(1) as f64;
        let mean = sum / n;
        if mean.length() < 0.5 {
            return Err(DataError::invalid(format!(
                "--up auto: the {} cameras' up vectors do not agree (their mean has length {:.2}); give the world's up axis with --up",
                cameras.len(),
                mean.length()
            )));
        }
        let m = mean.normalize();
        let best = UpAxis::ALL
            .into_iter()
            .max_by(|a, b| a.vector().dot(m).total_cmp(&b.vector().dot(m)))
            .expect("six axes");
        Ok((best, best.vector().dot(m).clamp(-1.0, 1.0).acos().to_degrees()))
    }

    /// The rotation that takes world coordinates to glTF's (this axis onto +Y). A proper rotation
    /// (determinant +1): handedness is kept, so faces keep their winding.
    pub fn to_gltf(self) -> DMat3 {
        // Rows: the world vectors that become glTF's x, y, z.
        let (x, y) = match self {
            UpAxis::PosY => (DVec3::X, DVec3::Y),
            UpAxis::NegY => (DVec3::X, -DVec3::Y),
            UpAxis::PosZ => (DVec3::X, DVec3::Z),
            UpAxis::NegZ => (DVec3::X, -DVec3::Z),
            UpAxis::PosX => (DVec3::Y, DVec3::X),
            UpAxis::NegX => (DVec3::Y, -DVec3::X),
        };
        DMat3::from_cols(x, y, x.cross(y)).transpose()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DMat4;

    #[test]
    fn each_up_axis_becomes_plus_y_by_a_proper_rotation() {
        for a in UpAxis::ALL {
            let r = a.to_gltf();
            assert!((r * a.vector() - DVec3::Y).length() < 1e-12, "{}", a.name());
            assert!((r.determinant() - 1.0).abs() < 1e-12, "{}", a.name());
            assert!((r * r.transpose() - DMat3::IDENTITY).abs_diff_eq(DMat3::ZERO, 1e-12));
        }
        // z-up: the usual (x, y, z) → (x, z, −y)
        let r = UpAxis::PosZ.to_gltf();
        assert!((r * DVec3::new(1.0, 2.0, 3.0) - DVec3::new(1.0, 3.0, -2.0)).length() < 1e-12);
        assert_eq!(UpAxis::PosY.to_gltf(), DMat3::IDENTITY);
    }

    #[test]
    fn parses_signed_axes() {
        assert_eq!(UpAxis::parse("+Z"), Some(UpAxis::PosZ));
        assert_eq!(UpAxis::parse("z"), Some(UpAxis::PosZ));
        assert_eq!(UpAxis::parse("-y"), Some(UpAxis::NegY));
        assert_eq!(UpAxis::parse("up"), None);
    }

    fn upright_camera(up: DVec3, forward: DVec3) -> Camera {
        // OpenCV axes: x right, y down, z forward
        let z = forward.normalize();
        let y = -up;
        let x = y.cross(z);
        Camera {
            width: 4,
            height: 3,
            fx: 2.0,
            fy: 2.0,
            cx: 2.0,
            cy: 1.5,
            c2w: DMat4::from_cols(x.extend(0.0), y.extend(0.0), z.extend(0.0), DVec3::ZERO.extend(1.0)),
            lens: Default::default(),
        }
    }

    #[test]
    fn the_up_axis_is_read_off_upright_cameras() {
        let cams: Vec<Camera> = [DVec3::X, DVec3::Y, -DVec3::X, DVec3::new(0.3, 0.6, 0.2)]
            .iter()
            .map(|&f| {
                let f = DVec3::new(f.x, f.y, 0.1);
                upright_camera(DVec3::Z, f - DVec3::Z * f.z)
            })
            .collect();
        let (axis, angle) = UpAxis::from_cameras(&cams).unwrap();
        assert_eq!(axis, UpAxis::PosZ);
        assert!(angle < 1e-6);
        // cameras rolled every way have no up
        let rolled: Vec<Camera> = [DVec3::Z, -DVec3::Z, DVec3::Y, -DVec3::Y]
            .iter()
            .map(|&u| upright_camera(u, DVec3::X))
            .collect();
        let e = UpAxis::from_cameras(&rolled).unwrap_err().to_string();
        assert!(e.contains("--up"), "{e}");
    }
}
