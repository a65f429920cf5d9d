//! The `eval` command's JSON (the README's "Commands"): every figure that cannot be computed
//! is `null`, never absent. Extra keys beyond the contract: `geometry.mesh.per_object_recall`
//! (with the dataset's object names and tags), `geometry.thin_objects`, `material.pixels` and
//! `material.albedo_scale`, `emitters.emission` and `emitters.matches`, `relight.unedited`,
//! `relight.psnr_differential`/`ssim_differential`, `relight.psnr_ratio`/`ssim_ratio` and the per-set
//! `*_unedited`, `*_differential`, `*_ratio`,
//! and the top-level `notes`: sentences saying why figures are missing or not meaningful (always
//! present, `[]` when there is nothing to say), e.g. [`zero_emitter_note`] when stage 2 found no
//! emitters, [`no_lpips_note`] when no LPIPS weights were given.

use crate::mesh_metrics::{GroupRecall, MeshMetrics};
use i2sdf_data::dataset::ObjectInfo;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    pub novel_view: NovelViewMetrics,
    /// The same figures on the training views (`eval --split train|both`; null otherwise): the
    /// paper's bracketed figures (Table 1), how closely the field fits what it was trained on.
    #[serde(default)]
    pub train_view: Option<ViewSplitMetrics>,
    pub geometry: GeometryMetrics,
    pub rerender: RerenderMetrics,
    pub material: MaterialMetrics,
    pub emitters: EmitterMetrics,
    pub relight: RelightMetrics,
    pub time_s: StageTimes,
    /// Stage 1's pose correction against the evaluated dataset's training poses (null: the run
    /// corrected no poses, or the dataset has none of its training views).
    #[serde(default)]
    pub poses: Option<crate::poses::PoseMetrics>,
    /// Why figures are null or not meaningful, in plain words, for whoever reads the JSON (and
    /// the HTML report, which shows them). Absent in older reports: read as none.
    #[serde(default)]
    pub notes: Vec<String>,
}

/// What a run whose stage 2 found no emitters means for its figures. Stage 2 makes emitters of
/// the surface points of the training pixels whose emitter probability F_e is above
/// `stage2.emitter_threshold`; with none (F_e not trained enough, or a dataset without emitter
/// masks) it finds no emitters, and everything downstream is lit by nothing but the radiance field.
pub fn zero_emitter_note() -> String {
    "stage 2 found no emitters: no training pixel's emitter probability (F_e) was above \
     stage2.emitter_threshold (or the dataset has no emitter masks), or every connected piece of \
     the marked points failed stage 2's tests (stage2.emitter_min_views, \
     stage2.emitter_mask_agreement), so there was no light. The re-render therefore has only the radiance field's indirect light (no light \
     from any emitter), and every relit image would be black when path traced and unchanged \
     when composited differentially: the relight figures are null, not meaningful. Train stage 1 \
     longer (the emitter field needs a converged surface) or lower stage2.emitter_threshold."
        .to_string()
}

/// Why `novel_view.lpips` is null: LPIPS needs network weights that i2sdf does not ship.
pub fn no_lpips_note() -> String {
    "novel_view.lpips is null: LPIPS needs the lpips package's AlexNet weights, which i2sdf does \
     not ship; give them with --lpips-weights FILE.safetensors (scripts/lpips_weights.py writes \
     the file where torchvision's pretrained weights can be downloaded)."
        .to_string()
}

/// Why `novel_view.lpips` is null although weights were given: a test view of `width × height`
/// is smaller than AlexNet's layers take.
pub fn lpips_too_small_note(width: usize, height: usize) -> String {
    format!(
        "novel_view.lpips is null: a test view is {width}×{height} pixels, and LPIPS's AlexNet needs \
         at least {side}×{side}.",
        side = crate::lpips::MIN_SIDE
    )
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct NovelViewMetrics {
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    pub lpips: Option<f64>,
}

/// One split's image metrics, with its depth and normal errors and its number of views.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ViewSplitMetrics {
    #[serde(flatten)]
    pub images: NovelViewMetrics,
    pub depth_l1: Option<f64>,
    pub normal_angular_l1: Option<f64>,
    pub views: usize,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GeometryMetrics {
    pub depth_l1: Option<f64>,
    pub normal_angular_l1: Option<f64>,
    pub mesh: MeshReport,
    /// Recall of the GT objects tagged `thin` or `suspended`, `null` when the dataset has none.
    pub thin_objects: Option<ObjectGroupReport>,
    /// Recall of the GT objects tagged `small` (under 5 cm, on furniture), `null` when the
    /// dataset has none.
    pub small_objects: Option<ObjectGroupReport>,
}

/// How much of a group of objects the extracted mesh recovers: the fraction of their visible GT
/// surface points within 2 cm and 5 cm (0.02 and 0.05 scene units) of it. The groups: the thin
/// and suspended objects (lamp poles, table legs, chandeliers: what the paper's bubble loss
/// exists to recover) and the small ones (a ball on a table, a die).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ObjectGroupReport {
    pub recall_2cm: Option<f64>,
    pub recall_5cm: Option<f64>,
    /// Visible GT points on those objects.
    pub points: usize,
    /// Names of the objects covered.
    pub objects: Vec<String>,
}

impl ObjectGroupReport {
    /// From the recall of the group of thin objects at thresholds (0.02, 0.05).
    pub fn new(group: &GroupRecall, objects: Vec<String>) -> Self {
        let at = |t: f64| {
            group
                .thresholds
                .iter()
                .position(|&x| x == t)
                .and_then(|i| group.recall[i])
        };
        ObjectGroupReport {
            recall_2cm: at(0.02),
            recall_5cm: at(0.05),
            points: group.points,
            objects,
        }
    }
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MeshReport {
    pub accuracy: Option<f64>,
    pub completeness: Option<f64>,
    pub precision: Option<f64>,
    pub recall: Option<f64>,
    pub fscore: Option<f64>,
    pub threshold: Option<f64>,
    /// The sampled points that survived culling: predicted and GT.
    pub pred_points: Option<usize>,
    pub gt_points: Option<usize>,
    /// How the points were culled to what the training views see, in words (`eval` before
    /// 2026-12-07 also counted GT surfaces hidden less than the threshold behind a seen one).
    pub culling: Option<String>,
    /// Recall per ground-truth object, `null` when the GT mesh has no object ids.
    pub per_object_recall: Option<Vec<ObjectRecallReport>>,
}

/// One GT object's recall at the main threshold, with its name and tags where the dataset lists
/// the object.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObjectRecallReport {
    pub object_id: i32,
    pub name: Option<String>,
    pub tags: Vec<String>,
    pub recall: Option<f64>,
    /// Within 2 cm and 5 cm (scene units 0.02, 0.05), whatever the main threshold.
    pub recall_2cm: Option<f64>,
    pub recall_5cm: Option<f64>,
    pub points: usize,
}

impl MeshReport {
    /// Joins names and tags from the dataset's object list onto the per-object recall.
    pub fn join_objects(&mut self, objects: &[ObjectInfo]) {
        for r in self.per_object_recall.iter_mut().flatten() {
            if let Some(o) = objects.iter().find(|o| o.id == r.object_id) {
                r.name = Some(o.name.clone());
                r.tags = o.tags.clone();
            }
        }
    }
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
            pred_points: Some(m.pred_points),
            gt_points: Some(m.gt_points),
            culling: Some(m.culling.clone()),
            per_object_recall: (!m.per_object_recall.is_empty()).then(|| {
                m.per_object_recall
                    .iter()
                    .map(|r| ObjectRecallReport {
                        object_id: r.object_id,
                        name: None,
                        tags: Vec::new(),
                        recall: r.recall,
                        recall_2cm: r.recall_thin[0],
                        recall_5cm: r.recall_thin[1],
                        points: r.points,
                    })
                    .collect()
            }),
        }
    }
}

/// Stage 2's re-render of the test views (eq:render by the Monte Carlo integrator), tone-mapped
/// with the dataset's own transfer, against the test LDR images: means over views.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RerenderMetrics {
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    /// The re-render was denoised before it was scored (`eval --denoise`).
    #[serde(default)]
    pub denoised: bool,
}

/// Stage 2's material maps (from the pixel-centre rays of the test views) against the GT maps,
/// over the pixels with GT that are not emitters and that the re-render hit, all test views
/// pooled.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MaterialMetrics {
    /// PSNR (peak 1) of Kd against the GT albedo (both linear).
    pub albedo_psnr: Option<f64>,
    /// The same after the per-channel least-squares scale `albedo_scale` (the albedo–lighting
    /// scale ambiguity removed).
    pub albedo_psnr_scaled: Option<f64>,
    /// Mean |ρ − ρ_gt|.
    pub roughness_l1: Option<f64>,
    /// s_c = Σ pred·gt / Σ pred², per channel, over all test views together.
    pub albedo_scale: Option<[f64; 3]>,
    /// Pixels compared (albedo).
    pub pixels: Option<usize>,
    /// Kd's PSNR over the compared pixels whose surface at least
    /// [`crate::intrinsic::SEEN_BY`] training views see (the test view's GT depth point
    /// projected into each, agreeing with its GT depth within 2 %): what stage 2 could learn, not
    /// the guess it extrapolates onto surfaces the training views miss. `null` without exact
    /// depth for every view (`depth_exact`).
    #[serde(default)]
    pub albedo_psnr_seen: Option<f64>,
    /// The share of the compared pixels counted in `albedo_psnr_seen`.
    #[serde(default)]
    pub seen_fraction: Option<f64>,
    /// Mean |ρ − ρ_gt| over the compared pixels whose GT Ks luminance is at least
    /// [`crate::intrinsic::LOBE_KS`]: where ρ changes what a camera sees. Elsewhere (Ks = 0) ρ
    /// changes no pixel, and `roughness_l1` there measures only the fit's prior. `null` without
    /// GT Ks maps or where no pixel has a lobe.
    #[serde(default)]
    pub roughness_l1_lobe: Option<f64>,
    /// The share of the roughness pixels counted in `roughness_l1_lobe`.
    #[serde(default)]
    pub lobe_fraction: Option<f64>,
}

/// The emitters stage 2 found (world units) and, where the dataset lists its GT emitters, how
/// they match.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EmitterMetrics {
    pub count: Option<usize>,
    /// Cluster centres, world units.
    pub centres: Option<Vec<[f64; 3]>>,
    /// L\[k\], RGB, linear image units (exposure × physical radiance).
    pub emission: Option<Vec<[f64; 3]>>,
    /// One per GT emitter; `null` when the dataset lists none.
    pub matches: Option<Vec<EmitterMatch>>,
}

/// A GT emitter and the predicted emitter nearest to it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EmitterMatch {
    pub name: String,
    /// Index of the nearest predicted emitter (by the distance of its centre to the GT box, ties
    /// by the distance to the box's centre); `null` when none was predicted.
    pub predicted: Option<usize>,
    /// Distance (world units) from that emitter's centre to the GT box, 0 inside.
    pub distance: Option<f64>,
    /// L\[k\] / (GT emission × exposure), per channel (exposure 1 when the dataset states none).
    pub emission_ratio: Option<[f64; 3]>,
    /// Σ_c L\[k\]_c / Σ_c (GT emission × exposure)_c.
    pub emission_ratio_mean: Option<f64>,
}

/// The dataset's relit sets rendered with their specs (`i2sdf edit`'s path tracer) against their
/// ground truth: over all their frames, and per set (named by its spec's file stem).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RelightMetrics {
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    pub sets: Option<std::collections::BTreeMap<String, RelightSetMetrics>>,
    /// The unedited path-traced render against the test images of the same cameras (the
    /// renderer's own floor, before any edit).
    pub unedited: Option<ImagePair>,
    /// The same sets by differential rendering (`i2sdf edit --composite differential`: stage 1's
    /// radiance field + the path-traced change), over all their frames.
    pub psnr_differential: Option<f64>,
    pub ssim_differential: Option<f64>,
    /// The same sets by the ratio composite (`i2sdf edit --composite ratio`: stage 1's radiance
    /// field × the path-traced edited / unedited), over all their frames.
    pub psnr_ratio: Option<f64>,
    pub ssim_ratio: Option<f64>,
    /// How the sets were rendered (None when nothing was): a report rendering with the same
    /// settings shows the same images and figures.
    #[serde(default)]
    pub settings: Option<RelightSettings>,
}

/// The path tracer's settings of a relight evaluation, and the marching-cubes resolution of the
/// recovered surface it traces.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RelightSettings {
    pub spp: u32,
    pub bounces: u32,
    pub seed: u64,
    pub mesh_resolution: usize,
    /// The renders were denoised before they were scored (`eval --denoise`).
    #[serde(default)]
    pub denoised: bool,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RelightSetMetrics {
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    /// The unedited render against this set's relit ground truth: what doing nothing scores.
    pub psnr_unedited: Option<f64>,
    pub ssim_unedited: Option<f64>,
    /// By differential rendering (see [`RelightMetrics::psnr_differential`]).
    pub psnr_differential: Option<f64>,
    pub ssim_differential: Option<f64>,
    /// By the ratio composite (see [`RelightMetrics::psnr_ratio`]).
    pub psnr_ratio: Option<f64>,
    pub ssim_ratio: Option<f64>,
    pub frames: usize,
    /// Each scored frame's figures, in the set's order.
    #[serde(default)]
    pub per_frame: Vec<RelightFrameMetrics>,
}

/// One relit frame's figures: path traced, by differential rendering and by the ratio composite.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RelightFrameMetrics {
    pub name: String,
    pub psnr: Option<f64>,
    pub psnr_differential: Option<f64>,
    pub psnr_ratio: Option<f64>,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ImagePair {
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    pub frames: usize,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StageTimes {
    pub stage1: Option<f64>,
    pub stage2: Option<f64>,
}

impl EvalReport {
    /// Records that stage 2 found no emitters (`fields.emitters` is empty, `emitters.count` is 0):
    /// adds [`zero_emitter_note`] once, and nulls the relight figures, which would only score
    /// black or unchanged images ([`crate::relight::relight_metrics`] already returns them null
    /// then; the frame counts of the sets stay).
    pub fn note_no_emitters(&mut self) {
        let note = zero_emitter_note();
        if !self.notes.contains(&note) {
            self.notes.push(note);
        }
        let sets = self.relight.sets.take().map(|sets| {
            sets.into_iter()
                .map(|(name, set)| {
                    let frames = set.frames;
                    (
                        name,
                        RelightSetMetrics {
                            frames,
                            ..Default::default()
                        },
                    )
                })
                .collect()
        });
        self.relight = RelightMetrics {
            sets,
            ..Default::default()
        };
    }

    /// Pretty JSON. Non-finite figures (a PSNR of identical images is +inf) are written as `null`
    /// by serde_json, as JSON has no infinity.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("the report is plain data")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh_metrics::ObjectRecall;
    use serde_json::Value;

    const CONTRACT: [(&str, &[&str]); 7] = [
        ("novel_view", &["psnr", "ssim", "lpips"]),
        ("geometry", &["depth_l1", "normal_angular_l1", "mesh"]),
        ("rerender", &["psnr", "ssim"]),
        ("material", &["albedo_psnr", "albedo_psnr_scaled", "roughness_l1"]),
        ("emitters", &["count", "centres"]),
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
        assert_eq!(v["notes"], serde_json::json!([]), "notes are always present");
        assert!(v["geometry"]["thin_objects"].is_null());
        assert!(v["geometry"].as_object().unwrap().contains_key("thin_objects"));
        for key in ["emission", "matches"] {
            assert!(v["emitters"].as_object().unwrap().contains_key(key), "emitters.{key}");
            assert!(v["emitters"][key].is_null());
        }
    }

    #[test]
    fn stage2_sections_serialize() {
        let mut report = EvalReport::default();
        report.rerender.psnr = Some(21.5);
        report.material.albedo_psnr_scaled = Some(18.0);
        report.emitters = EmitterMetrics {
            count: Some(1),
            centres: Some(vec![[1.0, 2.0, 3.0]]),
            emission: Some(vec![[4.0, 5.0, 6.0]]),
            matches: Some(vec![EmitterMatch {
                name: "lamp".into(),
                predicted: Some(0),
                distance: Some(0.0),
                emission_ratio: Some([1.0, 1.0, 1.0]),
                emission_ratio_mean: Some(1.0),
            }]),
        };
        let json = report.to_json();
        let v: Value = serde_json::from_str(&json).unwrap();
        assert_eq!(v["rerender"]["psnr"], 21.5);
        assert!(v["rerender"]["ssim"].is_null());
        assert_eq!(v["emitters"]["centres"][0][2], 3.0);
        assert_eq!(v["emitters"]["matches"][0]["name"], "lamp");
        let back: EvalReport = serde_json::from_str(&json).unwrap();
        assert_eq!(back, report);
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
            culling: "none".into(),
            per_object_recall: vec![
                ObjectRecall {
                    object_id: 3,
                    recall: Some(0.5),
                    recall_thin: [Some(0.25), Some(0.5)],
                    points: 4,
                },
                ObjectRecall {
                    object_id: 5,
                    recall: None,
                    recall_thin: [None, None],
                    points: 0,
                },
            ],
            group_recall: Vec::new(),
        });
        report.geometry.mesh.join_objects(&[ObjectInfo {
            id: 3,
            name: "lamp_pole".into(),
            tags: vec!["thin".into()],
        }]);
        let thin = GroupRecall {
            name: "thin".into(),
            points: 4,
            thresholds: vec![0.02, 0.05],
            recall: vec![Some(0.25), Some(0.5)],
        };
        report.geometry.thin_objects = Some(ObjectGroupReport::new(&thin, vec!["lamp_pole".into()]));
        let json = report.to_json();
        let v: Value = serde_json::from_str(&json).unwrap();
        assert!(v["novel_view"]["psnr"].is_null(), "infinity is written as null");
        assert_eq!(v["geometry"]["mesh"]["threshold"], 0.05);
        let objects = &v["geometry"]["mesh"]["per_object_recall"];
        assert_eq!(objects[0]["object_id"], 3);
        assert_eq!(
            (&objects[0]["name"], &objects[0]["tags"][0]),
            (&"lamp_pole".into(), &"thin".into())
        );
        assert!(objects[1]["name"].is_null() && objects[1]["recall"].is_null());
        let thin = &v["geometry"]["thin_objects"];
        assert_eq!(
            (&thin["recall_2cm"], &thin["recall_5cm"], &thin["points"]),
            (&0.25.into(), &0.5.into(), &4.into())
        );
        let back: EvalReport = serde_json::from_str(&json).unwrap();
        assert_eq!(back.geometry, report.geometry);
        assert_eq!(back.novel_view.psnr, None);
    }

    #[test]
    fn no_emitters_leave_a_note_and_null_relight_figures() {
        let mut report = EvalReport::default();
        report.emitters.count = Some(0);
        report.relight.psnr = Some(3.5);
        report.relight.sets = Some(
            [(
                "lamp_dim".to_string(),
                RelightSetMetrics {
                    psnr: Some(3.5),
                    frames: 4,
                    ..Default::default()
                },
            )]
            .into(),
        );
        report.note_no_emitters();
        report.note_no_emitters();
        assert_eq!(report.notes, [zero_emitter_note()], "noted once");
        assert!(report.relight.psnr.is_none());
        let set = &report.relight.sets.as_ref().unwrap()["lamp_dim"];
        assert_eq!((set.psnr, set.frames), (None, 4));
        let json = report.to_json();
        let v: Value = serde_json::from_str(&json).unwrap();
        let note = v["notes"][0].as_str().unwrap();
        assert!(
            note.contains("no emitters") && note.contains("relight figures are null"),
            "{note}"
        );
        let back: EvalReport = serde_json::from_str(&json).unwrap();
        assert_eq!(back, report);
        // A report written before `notes` existed reads as having none.
        let mut old: serde_json::Map<String, Value> = serde_json::from_str(&json).unwrap();
        old.remove("notes");
        let back: EvalReport = serde_json::from_value(Value::Object(old)).unwrap();
        assert!(back.notes.is_empty());
    }
}
