//! How close stage 1's corrected training poses are to the poses of the dataset evaluated on.
//! With `eval --data` a dataset whose poses are exact (a synth room without `--pose-noise`),
//! these are the pose errors before and after the correction.

use i2sdf_data::{Dataset, Split};
use i2sdf_model::poses::{pose_difference, PoseCorrections};
use serde::{Deserialize, Serialize};

/// Errors of one set of poses against the evaluated dataset's.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseErrors {
    pub rotation_deg_median: f64,
    pub rotation_deg_max: f64,
    /// Camera centre distances, in world units.
    pub translation_median: f64,
    pub translation_max: f64,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseMetrics {
    /// Corrected training views found in the evaluated dataset (by frame name).
    pub views: usize,
    /// The poses the run was given, and the ones stage 1 corrected them to.
    pub given: PoseErrors,
    pub corrected: PoseErrors,
}

/// The pose errors of a run's corrected views against `dataset`'s training frames of the same
/// names; None when no view matches.
pub fn pose_metrics(corrections: &PoseCorrections, dataset: &Dataset) -> Option<PoseMetrics> {
    let mut given = Vec::new();
    let mut corrected = Vec::new();
    for v in &corrections.views {
        let Some(f) = dataset.split(Split::Train).find(|f| f.name == v.name) else {
            continue;
        };
        // Opened as the run's own dataset, the training frames hold the corrected poses
        // (`PoseCorrections::apply` sets them from `v.c2w()`, bit for bit): the reference is
        // then the dataset's own, given pose.
        let reference = if f.camera.c2w == v.c2w() {
            v.given_c2w()
        } else {
            f.camera.c2w
        };
        given.push(pose_difference(reference, v.given_c2w()));
        corrected.push(pose_difference(reference, v.c2w()));
    }
    (!given.is_empty()).then(|| PoseMetrics {
        views: given.len(),
        given: errors(&given),
        corrected: errors(&corrected),
    })
}

fn errors(d: &[(f64, f64)]) -> PoseErrors {
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        }
    };
    let rot: Vec<f64> = d.iter().map(|x| x.0).collect();
    let tr: Vec<f64> = d.iter().map(|x| x.1).collect();
    PoseErrors {
        rotation_deg_max: rot.iter().copied().fold(0.0, f64::max),
        translation_max: tr.iter().copied().fold(0.0, f64::max),
        rotation_deg_median: median(rot),
        translation_median: median(tr),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use i2sdf_model::poses::CorrectedView;

    #[test]
    fn errors_are_measured_against_the_evaluated_poses() {
        let dir = tempfile::tempdir().unwrap();
        i2sdf_data::fixture::write_native(dir.path(), &i2sdf_data::fixture::FixtureOptions::default());
        let ds = i2sdf_data::load(dir.path()).unwrap();
        let views: Vec<CorrectedView> = ds
            .frames
            .iter()
            .enumerate()
            .filter(|(_, f)| f.split == Split::Train)
            .map(|(k, f)| {
                let truth = f.camera.c2w;
                let mut given = truth;
                given.w_axis.x += 0.02;
                let mut corrected = truth;
                corrected.w_axis.x += 0.005;
                CorrectedView::new(&f.name, k, given, corrected)
            })
            .collect();
        let n = views.len();
        let m = pose_metrics(&PoseCorrections { views }, &ds).unwrap();
        assert_eq!(m.views, n);
        assert!((m.given.translation_median - 0.02).abs() < 1e-12);
        assert!((m.corrected.translation_max - 0.005).abs() < 1e-12);
        assert!(m.given.rotation_deg_max < 1e-6);
    }

    #[test]
    fn the_runs_own_dataset_is_scored_against_its_given_poses() {
        let dir = tempfile::tempdir().unwrap();
        i2sdf_data::fixture::write_native(dir.path(), &i2sdf_data::fixture::FixtureOptions::default());
        let mut ds = i2sdf_data::load(dir.path()).unwrap();
        let (k, f) = ds
            .frames
            .iter()
            .enumerate()
            .find(|(_, f)| f.split == Split::Train)
            .unwrap();
        let mut corrected = f.camera.c2w;
        corrected.w_axis.y += 0.01;
        let c = PoseCorrections {
            views: vec![CorrectedView::new(&f.name, k, f.camera.c2w, corrected)],
        };
        c.apply(&mut ds, std::path::Path::new("poses.json")).unwrap();
        let m = pose_metrics(&c, &ds).unwrap();
        assert!(m.given.translation_max < 1e-12);
        assert!((m.corrected.translation_max - 0.01).abs() < 1e-9);
    }
}
