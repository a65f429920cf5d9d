//! The `eval` command's JSON (DESIGN.md "The command line"): every figure that cannot be computed
//! is `null`, never absent. Extra keys beyond the contract: `geometry.mesh.per_object_recall`.

use crate::mesh_metrics::{MeshMetrics, ObjectRecall};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    pub novel_view: NovelViewMetrics,
    pub geometry: GeometryMetrics,
    pub material: MaterialMetrics,
    pub relight: RelightMetrics,
    pub time_s: StageTimes,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct NovelViewMetrics {
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    pub lpips: Option<f64>,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GeometryMetrics {
    pub depth_l1: Option<f64>,
    pub normal_angular_l1: Option<f64>,
    pub mesh: MeshReport,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MeshReport {
    pub accuracy: Option<f64>,
    pub completeness: Option<f64>,
    pub precision: Option<f64>,
    pub recall: Option<f64>,
    pub fscore: Option<f64>,
    pub threshold: Option<f64>,
    /// Recall per ground-truth object, `null` when the dataset names no objects.
    pub per_object_recall: Option<Vec<ObjectRecall>>,
}

impl From<&MeshMetrics> for MeshReport {
    fn from(m: &MeshMetrics) -> Self {
        MeshReport {
            accuracy: m.accuracy,
            completeness: m.completeness,
            precision: m.precision,
            recall: m.recall,
            fscore: m.fscore,
            threshold: Some(m.threshold),
            per_object_recall: (!m.per_object_recall.is_empty()).then(|| m.per_object_recall.clone()),
        }
    }
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MaterialMetrics {
    pub albedo_psnr: Option<f64>,
    pub roughness_l1: Option<f64>,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RelightMetrics {
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StageTimes {
    pub stage1: Option<f64>,
    pub stage2: Option<f64>,
}

impl EvalReport {
    /// Pretty JSON. Non-finite figures (a PSNR of identical images is +inf) are written as `null`
    /// by serde_json, as JSON has no infinity.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("the report is plain data")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::Value;

    const CONTRACT: [(&str, &[&str]); 5] = [
        ("novel_view", &["psnr", "ssim", "lpips"]),
        ("geometry", &["depth_l1", "normal_angular_l1", "mesh"]),
        ("material", &["albedo_psnr", "roughness_l1"]),
        ("relight", &["psnr", "ssim"]),
        ("time_s", &["stage1", "stage2"]),
    ];
    const MESH_KEYS: [&str; 6] = ["accuracy", "completeness", "precision", "recall", "fscore", "threshold"];

    #[test]
    fn empty_report_has_every_key_as_null() {
        let v: Value = serde_json::from_str(&EvalReport::default().to_json()).unwrap();
        for (section, keys) in CONTRACT {
            for key in keys {
                let value = &v[section][key];
                if *key == "mesh" {
                    for mk in MESH_KEYS {
                        assert!(value.as_object().unwrap().contains_key(mk), "geometry.mesh.{mk}");
                        assert!(value[mk].is_null());
                    }
                } else {
                    assert!(v[section].as_object().unwrap().contains_key(*key), "{section}.{key}");
                    assert!(value.is_null(), "{section}.{key}");
                }
            }
        }
    }

    #[test]
    fn filled_report_round_trips() {
        let mut report = EvalReport::default();
        report.novel_view.psnr = Some(f64::INFINITY);
        report.novel_view.ssim = Some(0.9);
        report.time_s.stage1 = Some(12.5);
        report.geometry.mesh = MeshReport::from(&MeshMetrics {
            accuracy: Some(0.01),
            completeness: Some(0.02),
            precision: Some(0.9),
            recall: Some(0.8),
            fscore: Some(2.0 * 0.72 / 1.7),
            threshold: 0.05,
            pred_points: 10,
            gt_points: 10,
            per_object_recall: vec![ObjectRecall {
                object_id: 3,
                recall: Some(0.5),
                points: 4,
            }],
        });
        let json = report.to_json();
        let v: Value = serde_json::from_str(&json).unwrap();
        assert!(v["novel_view"]["psnr"].is_null(), "infinity is written as null");
        assert_eq!(v["geometry"]["mesh"]["threshold"], 0.05);
        assert_eq!(v["geometry"]["mesh"]["per_object_recall"][0]["object_id"], 3);
        let back: EvalReport = serde_json::from_str(&json).unwrap();
        assert_eq!(back.geometry, report.geometry);
        assert_eq!(back.novel_view.psnr, None);
    }
}
