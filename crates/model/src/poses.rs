//! `RUN/poses.json`: the training views' poses as stage 1 corrected them (world units, in
//! `transforms.json`'s convention: row-major camera-to-world, OpenGL axes), with how far each
//! moved. Stage 2, `render` and `edit` of training views use them; test views keep the
//! dataset's poses (they are scored at their given poses).

use crate::run_dir::RunDir;
use i2sdf_data::camera::GL_TO_CV;
use i2sdf_data::{imageio, DataError, Dataset, Split};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseCorrections {
    pub views: Vec<CorrectedView>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CorrectedView {
    /// The frame's name (its image's file stem) and its index among the dataset's frames.
    pub name: String,
    pub frame: usize,
    /// The corrected camera-to-world matrix (row-major, OpenGL axes, world units).
    pub transform_matrix: [[f64; 4]; 4],
    /// The pose the dataset gave (same convention), so that the correction can be scored
    /// against true poses (`eval --data` a dataset with exact ones).
    pub given_transform_matrix: [[f64; 4]; 4],
    /// How far the correction turned the view (degrees) and moved its centre (world units).
    pub rotation_deg: f64,
    pub translation: f64,
}

impl CorrectedView {
    /// The corrected pose in the house's convention (OpenCV axes).
    pub fn c2w(&self) -> glam::DMat4 {
        glam::DMat4::from_cols_array_2d(&self.transform_matrix).transpose() * GL_TO_CV
    }

    /// The given pose (OpenCV axes).
    pub fn given_c2w(&self) -> glam::DMat4 {
        glam::DMat4::from_cols_array_2d(&self.given_transform_matrix).transpose() * GL_TO_CV
    }

    /// A view from the given and the corrected camera-to-world poses (OpenCV axes).
    pub fn new(name: &str, frame: usize, given: glam::DMat4, corrected: glam::DMat4) -> Self {
        let (rotation_deg, translation) = pose_difference(given, corrected);
        CorrectedView {
            name: name.to_string(),
            frame,
            transform_matrix: (corrected * GL_TO_CV).transpose().to_cols_array_2d(),
            given_transform_matrix: (given * GL_TO_CV).transpose().to_cols_array_2d(),
            rotation_deg,
            translation,
        }
    }
}

/// How far apart two camera-to-world poses are: the angle of the relative rotation (degrees)
/// and the distance between the camera centres (world units).
pub fn pose_difference(a: glam::DMat4, b: glam::DMat4) -> (f64, f64) {
    let r = glam::DMat3::from_mat4(b) * glam::DMat3::from_mat4(a).transpose();
    // atan2 of the axis-angle's sine and cosine: acos of the trace alone loses half the digits
    // of a small angle, and the corrections are tenths of a degree.
    let cos = (r.x_axis.x + r.y_axis.y + r.z_axis.z - 1.0) / 2.0;
    let sin = 0.5
        * glam::DVec3::new(
            r.y_axis.z - r.z_axis.y,
            r.z_axis.x - r.x_axis.z,
            r.x_axis.y - r.y_axis.x,
        )
        .length();
    (sin.atan2(cos).to_degrees(), (b.w_axis - a.w_axis).truncate().length())
}

impl PoseCorrections {
    pub fn write(&self, path: &std::path::Path) -> Result<(), DataError> {
        let text = serde_json::to_string_pretty(self).expect("serializes");
        imageio::write_bytes_atomic(path, text.as_bytes())
    }

    /// The run's corrections, if stage 1 made any.
    pub fn read(run: &RunDir) -> Result<Option<PoseCorrections>, DataError> {
        let path = run.poses_path();
        if !path.is_file() {
            return Ok(None);
        }
        let text = std::fs::read_to_string(&path).map_err(|e| DataError::file(&path, format!("cannot read: {e}")))?;
        serde_json::from_str(&text)
            .map(Some)
            .map_err(|e| DataError::file(&path, format!("invalid JSON: {e}")))
    }

    /// Gives the dataset's training views their corrected poses. Every entry must name a training
    /// frame of this dataset (the run's data is checked before this is called).
    pub fn apply(&self, dataset: &mut Dataset, path: &std::path::Path) -> Result<(), DataError> {
        for (k, v) in self.views.iter().enumerate() {
            let f = dataset
                .frames
                .get_mut(v.frame)
                .filter(|f| f.split == Split::Train && f.name == v.name)
                .ok_or_else(|| {
                    DataError::field(
                        path,
                        format!("views[{k}]"),
                        format!("frame {} '{}' is not a training view of this dataset", v.frame, v.name),
                    )
                })?;
            let c2w = v.c2w();
            i2sdf_data::camera::validate_rigid(&c2w)
                .map_err(|m| DataError::field(path, format!("views[{k}].transform_matrix"), m))?;
            f.camera.c2w = c2w;
        }
        Ok(())
    }

    /// The largest rotation (degrees) and translation (world units) of the corrections.
    pub fn largest(&self) -> (f64, f64) {
        self.views
            .iter()
            .fold((0.0, 0.0), |(r, t), v| (r.max(v.rotation_deg), t.max(v.translation)))
    }
}

/// Opens a run's dataset as training saw it: the training views take stage 1's corrected poses
/// when the run has them. Returns whether it did.
pub fn with_corrected_poses(run: &RunDir, dataset: &mut Dataset) -> Result<bool, DataError> {
    match PoseCorrections::read(run)? {
        Some(p) => {
            p.apply(dataset, &run.poses_path())?;
            Ok(true)
        }
        None => Ok(false),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DMat4, DQuat, DVec3};

    #[test]
    fn a_view_round_trips_and_says_how_far_it_moved() {
        let given = i2sdf_data::camera::look_at(DVec3::new(1.0, 2.0, 0.5), DVec3::ZERO, DVec3::Z);
        let turn = DMat4::from_quat(DQuat::from_axis_angle(DVec3::new(0.0, 0.6, 0.8), 0.5f64.to_radians()));
        let mut corrected = given;
        let r = glam::DMat3::from_mat4(turn) * glam::DMat3::from_mat4(given);
        corrected.x_axis = r.x_axis.extend(0.0);
        corrected.y_axis = r.y_axis.extend(0.0);
        corrected.z_axis = r.z_axis.extend(0.0);
        corrected.w_axis += DVec3::new(0.01, 0.0, -0.02).extend(0.0);
        let v = CorrectedView::new("frame_001", 1, given, corrected);
        assert!((v.rotation_deg - 0.5).abs() < 1e-9, "{}", v.rotation_deg);
        assert!((v.translation - 0.0005f64.sqrt()).abs() < 1e-12);
        assert!(v.c2w().abs_diff_eq(corrected, 1e-12));
        assert!(v.given_c2w().abs_diff_eq(given, 1e-12));
        let text = serde_json::to_string(&PoseCorrections { views: vec![v.clone()] }).unwrap();
        let back: PoseCorrections = serde_json::from_str(&text).unwrap();
        // serde_json's default float parser may round the last bit (no `float_roundtrip`).
        let b = &back.views[0];
        assert_eq!((b.name.as_str(), b.frame), (v.name.as_str(), v.frame));
        assert!(b.c2w().abs_diff_eq(v.c2w(), 1e-14));
        assert!((b.rotation_deg - v.rotation_deg).abs() < 1e-12);
        assert!((b.translation - v.translation).abs() < 1e-15);
    }
}
