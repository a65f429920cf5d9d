//! The K emitters of stage 2 (paper Sec. "Emitter Semantic Field"): the emitter field F_e marks
//! surface points as emitting; the train crate clusters those points into K emitters;
//! each has a learnable HDR RGB emission L\[k\]. This module stores the clusters and L\[·\], answers
//! index(x) of eq:radiance, and reads and writes `RUN/emitters.json`.
//!
//! L\[k\] is kept as its logarithm: L = exp(raw) stays positive whatever the optimizer does, and a
//! log-space step moves a dim lamp and the sun-lit window (orders of magnitude apart in HDR) at
//! the same relative rate — the LDR radiance field under-estimates emitters by a factor that is
//! unknown per emitter, which is exactly what L\[k\] has to learn.

use crate::emitter_panel::Panel;
use crate::scene::{GroupSpec, LrClass, ParamBlock, SceneModule, Update};
use glam::{DVec3, Vec3};
use i2sdf_data::DataError;
use i2sdf_nn::Parameters;
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};
use std::path::Path;

/// Emissions below this are stored as it (log of zero is not a parameter).
pub const MIN_EMISSION: f32 = 1e-8;

/// One emitter cluster, in world units.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Emitter {
    /// Centre of the cluster (the centroid of its points).
    pub centre: [f64; 3],
    /// Edge lengths of the axis-aligned box of the cluster's points.
    pub extent: [f64; 3],
    /// Radius of the sphere about `centre` that holds all the cluster's points (the cone that the
    /// integrator's light samples aim into must contain every emitting point).
    pub radius: f64,
    /// Emitter points that formed the cluster.
    pub points: usize,
    /// The sphere fitted to the cluster's points, `[x, y, z, r]`, where they lie on one (a bulb
    /// seen from one side; stage 2's `fit_sphere`), reported in `emitters.json`. None for flat or
    /// irregular emitters (a panel). On the built-in rooms' bulbs it is within 0.3 cm and 2 % of
    /// the true sphere, where the cluster's centroid and bounding radius are 6–7 cm and 40–90 %
    /// off (the cluster is the seen side only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sphere: Option<[f64; 4]>,
    /// The axis-aligned box of the cluster's points, `[min, max]` (world units). None in files
    /// written before it was kept.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bounds: Option<[[f64; 3]; 2]>,
    /// The rectangle a flat emitter is (stage 2's `fit_panels`, [`crate::emitter_panel`]): what
    /// every cast meets instead of the recovered surface there. None for bulbs, irregular
    /// emitters and files written before it was kept.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub panel: Option<Panel>,
}

/// How far outside the box of an emitter's points, as a fraction of the index margin, surface no
/// training camera sees still counts as the emitter (`stage2.label_unobserved`): about 2 cm on
/// the built-in rooms, the spacing of the cached points that bound the box.
pub const UNSEEN_BOX_MARGIN: f64 = 0.25;

/// Largest fitted radius of a bulb, as a multiple of its cluster's bounding radius: the seen
/// side of a bulb spans its sphere (the built-in rooms' bulbs: 0.5–0.8); a slightly curved
/// panel fits a sphere far larger than itself (1.8 on seed 7's ceiling panel).
pub const BULB_MAX_RADIUS: f64 = 1.25;

/// How far about a bulb's fitted sphere, in radii, the recovered surface facing away from its
/// centre is the bulb's own: stage 1 leaves the unseen side where its bubble points put it (on
/// the default room up to 1.6 radii out, towards the corner walls).
pub const BULB_CLEARANCE: f32 = 1.7;

impl Emitter {
    /// Whether surface that no training camera sees at `x` may be this emitter's
    /// (`stage2.label_unobserved`): inside the box of its points, enlarged by
    /// [`UNSEEN_BOX_MARGIN`] × `index_margin`. Its bounding sphere (the index) holds a panel's
    /// neighbourhood too: on seed 1's room 0.26 m² of unseen ceiling beside a 1.3 m² panel. A
    /// file without the box: anywhere the index holds.
    pub fn may_hold_unseen(&self, x: DVec3, index_margin: f64) -> bool {
        self.bounds.is_none_or(|[lo, hi]| {
            let m = UNSEEN_BOX_MARGIN * index_margin;
            (0..3).all(|a| x[a] >= lo[a] - m && x[a] <= hi[a] + m)
        })
    }

    /// The emitter as a bulb: its fitted sphere (centre, radius; world units) where it has one
    /// no larger than [`BULB_MAX_RADIUS`] times the cluster's bounding radius.
    pub fn bulb(&self) -> Option<(glam::Vec3, f32)> {
        let [x, y, z, r] = self.sphere?;
        (r <= BULB_MAX_RADIUS * self.radius).then(|| (glam::DVec3::new(x, y, z).as_vec3(), r as f32))
    }
}

/// Whether a surface point (with its outward normal, any length) is part of the recovered bulb
/// about the sphere (`centre`, `r`): within [`BULB_CLEARANCE`] radii of the centre and facing
/// away from it. A wall or ceiling next to the bulb faces the light and is not.
pub fn on_recovered_bulb(centre: glam::Vec3, r: f32, point: glam::Vec3, outward: glam::Vec3) -> bool {
    (point - centre).length() < BULB_CLEARANCE * r && outward.dot(point - centre) > 0.0
}

/// The K emitters and their learnable emissions L\[k\].
#[derive(Clone, Debug, PartialEq)]
pub struct EmitterTable {
    pub emitters: Vec<Emitter>,
    /// ln of each HDR RGB emission L\[k\] (K×3, row-major), learnable: L = exp(raw) keeps it
    /// positive.
    pub log_emission: Vec<f32>,
}

impl EmitterTable {
    /// The panels ([`Emitter::panel`]) with their emitter's index.
    pub fn panels(&self) -> Vec<(usize, Panel)> {
        (self.emitters.iter().enumerate())
            .filter_map(|(k, e)| e.panel.map(|p| (k, p)))
            .collect()
    }

    /// The emitters that are bulbs ([`Emitter::bulb`]): index, centre and radius.
    pub fn bulbs(&self) -> Vec<(usize, glam::Vec3, f32)> {
        (self.emitters.iter().enumerate())
            .filter_map(|(k, e)| e.bulb().map(|(c, r)| (k, c, r)))
            .collect()
    }

    /// `emission[k]` is L\[k\] (linear HDR, image units); values below [`MIN_EMISSION`] are raised
    /// to it.
    pub fn new(emitters: Vec<Emitter>, emission: &[[f32; 3]]) -> Self {
        assert_eq!(emitters.len(), emission.len(), "one emission per emitter");
        let log_emission = emission
            .iter()
            .flat_map(|e| e.map(|v| v.max(MIN_EMISSION).ln()))
            .collect();
        EmitterTable { emitters, log_emission }
    }

    pub fn len(&self) -> usize {
        self.emitters.len()
    }

    pub fn is_empty(&self) -> bool {
        self.emitters.is_empty()
    }

    /// L\[k\] = exp(raw\[k\]).
    pub fn emission(&self, k: usize) -> Vec3 {
        let r = &self.log_emission[k * 3..k * 3 + 3];
        Vec3::new(r[0].exp(), r[1].exp(), r[2].exp())
    }

    /// index(x) of eq:radiance: the emitter that a world point which F_e marks as emitting
    /// belongs to — the nearest centre among the emitters whose bounding sphere, enlarged by
    /// `margin` (world units), contains `x`; `None` when none does. Stray emitter-field positives
    /// far from every cluster are not lights (a bright white wall that F_e half-believes would
    /// otherwise borrow the nearest lamp's HDR emission). Restricting to containing spheres, not
    /// just the nearest centre, keeps a point at the edge of a large window with its window when
    /// a small lamp's centre happens to be closer.
    pub fn index(&self, x: DVec3, margin: f64) -> Option<usize> {
        let mut best: Option<(usize, f64)> = None;
        for (k, e) in self.emitters.iter().enumerate() {
            let d = (x - DVec3::from_array(e.centre)).length();
            if d <= e.radius + margin && best.is_none_or(|(_, bd)| d < bd) {
                best = Some((k, d));
            }
        }
        best.map(|(k, _)| k)
    }

    /// Writes `RUN/emitters.json`, atomically:
    /// `{"emitters": [{"centre": [x,y,z], "extent": [dx,dy,dz], "radius": r, "points": n, "sphere":
    /// [x,y,z,r] or null, "bounds": [[x,y,z], [x,y,z]] (the box of the points) or null,
    /// "panel": {"axis", "offset", "lo", "hi", "facing", "depth"} (a flat emitter's rectangle,
    /// [`Panel`]) or null, "emission": [r,g,b], "radiance": [r,g,b] or null}]}` — world units;
    /// `emission` is L\[k\] in image units, `radiance` = emission / exposure (the physical
    /// radiance) when the dataset states its exposure, else null.
    pub fn write_json(&self, path: &Path, exposure: Option<f64>) -> Result<(), DataError> {
        let entries: Vec<Value> = self
            .emitters
            .iter()
            .enumerate()
            .map(|(k, e)| {
                let l = self.emission(k).as_dvec3().to_array();
                let radiance = exposure.map(|x| l.map(|v| v / x));
                json!({
                    "centre": e.centre,
                    "extent": e.extent,
                    "radius": e.radius,
                    "points": e.points,
                    "sphere": e.sphere,
                    "bounds": e.bounds,
                    "panel": e.panel,
                    "emission": l,
                    "radiance": radiance,
                })
            })
            .collect();
        let text = serde_json::to_string_pretty(&json!({ "emitters": entries })).expect("JSON serializes");
        i2sdf_data::imageio::write_bytes_atomic(path, format!("{text}\n").as_bytes())
    }

    /// Reads a file written by [`EmitterTable::write_json`]. A file that is not JSON is the
    /// file's fault; a missing or malformed key is named (`emitters[2].emission`). `radius` may
    /// be absent (a hand-written file): then it is the half diagonal of the extent.
    pub fn read_json(path: &Path) -> Result<Self, DataError> {
        let text = std::fs::read_to_string(path).map_err(|e| DataError::file(path, format!("cannot read: {e}")))?;
        let root: Value =
            serde_json::from_str(&text).map_err(|e| DataError::file(path, format!("not valid JSON: {e}")))?;
        let list = root
            .get("emitters")
            .and_then(Value::as_array)
            .ok_or_else(|| DataError::field(path, "emitters", "missing or not a list"))?;
        let (mut emitters, mut emission) = (Vec::new(), Vec::new());
        for (i, entry) in list.iter().enumerate() {
            let key = |k: &str| format!("emitters[{i}].{k}");
            let vec3 = |k: &str, nonneg: bool| -> Result<[f64; 3], DataError> {
                let v = entry
                    .get(k)
                    .and_then(Value::as_array)
                    .filter(|a| a.len() == 3)
                    .ok_or_else(|| DataError::field(path, key(k), "missing or not a list of 3 numbers"))?;
                let mut out = [0.0; 3];
                for (o, x) in out.iter_mut().zip(v) {
                    *o = x
                        .as_f64()
                        .filter(|x| x.is_finite() && (!nonneg || *x >= 0.0))
                        .ok_or_else(|| {
                            let what = if nonneg { "non-negative " } else { "" };
                            DataError::field(path, key(k), format!("must be 3 finite {what}numbers"))
                        })?;
                }
                Ok(out)
            };
            let centre = vec3("centre", false)?;
            let extent = vec3("extent", true)?;
            let l = vec3("emission", true)?;
            let points = entry
                .get("points")
                .and_then(Value::as_u64)
                .ok_or_else(|| DataError::field(path, key("points"), "missing or not a non-negative integer"))?
                as usize;
            let radius = match entry.get("radius") {
                None | Some(Value::Null) => 0.5 * DVec3::from_array(extent).length(),
                Some(r) => r
                    .as_f64()
                    .filter(|r| r.is_finite() && *r >= 0.0)
                    .ok_or_else(|| DataError::field(path, key("radius"), "must be a finite non-negative number"))?,
            };
            // An optional key: absent or null is None; else `parse` of its list, or the error.
            let optional = |k: &str, what: &str, parse: &dyn Fn(&[Value]) -> Option<Vec<f64>>| match entry.get(k) {
                None | Some(Value::Null) => Ok(None),
                Some(v) => v
                    .as_array()
                    .and_then(|a| parse(a))
                    .map(Some)
                    .ok_or_else(|| DataError::field(path, key(k), what)),
            };
            let numbers =
                |a: &[Value]| -> Option<Vec<f64>> { a.iter().map(|x| x.as_f64().filter(|x| x.is_finite())).collect() };
            let sphere = optional("sphere", "must be 4 finite numbers [x, y, z, r], r ≥ 0", &|a| {
                numbers(a).filter(|s| s.len() == 4 && s[3] >= 0.0)
            })?
            .map(|s| [s[0], s[1], s[2], s[3]]);
            let bounds = optional("bounds", "must be [[x, y, z], [x, y, z]], min ≤ max per axis", &|a| {
                let corners: Vec<Vec<f64>> = a.iter().map(|c| numbers(c.as_array()?)).collect::<Option<_>>()?;
                let ok = corners.len() == 2 && corners.iter().all(|c| c.len() == 3);
                ok.then(|| corners.concat())
                    .filter(|c| (0..3).all(|i| c[i] <= c[i + 3]))
            })?
            .map(|c| [[c[0], c[1], c[2]], [c[3], c[4], c[5]]]);
            let panel = match entry.get("panel") {
                None | Some(Value::Null) => None,
                Some(v) => Some(
                    serde_json::from_value::<Panel>(v.clone())
                        .ok()
                        .filter(Panel::is_valid)
                        .ok_or_else(|| {
                            DataError::field(
                                path,
                                key("panel"),
                                "must be {\"axis\": 0-2, \"offset\", \"lo\": [u, v], \"hi\": [u, v] (lo ≤ hi), \"facing\": 1 or -1, \"depth\" ≥ 0}, finite",
                            )
                        })?,
                ),
            };
            emitters.push(Emitter {
                centre,
                extent,
                radius,
                points,
                sphere,
                bounds,
                panel,
            });
            emission.push(l.map(|v| v as f32));
        }
        Ok(EmitterTable::new(emitters, &emission))
    }
}

/// One tensor, `{prefix}.log_emission`, shape `[K, 3]`.
impl Parameters for EmitterTable {
    fn visit(&self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &[f32])) {
        f(
            format!("{prefix}.log_emission"),
            vec![self.len(), 3],
            &self.log_emission,
        );
    }
    fn visit_mut(&mut self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &mut [f32])) {
        let shape = vec![self.len(), 3];
        f(format!("{prefix}.log_emission"), shape, &mut self.log_emission);
    }
}

impl ParamBlock for EmitterTable {
    fn values(&self) -> &[f32] {
        &self.log_emission
    }
    fn values_mut(&mut self) -> &mut [f32] {
        &mut self.log_emission
    }
}

/// L[·] as a scene module (group `emission`, tensors under `emission.`): optional, so a stage-1
/// checkpoint loads into a stage-2 scene.
impl SceneModule for EmitterTable {
    fn spec(&self) -> GroupSpec {
        GroupSpec {
            name: "emission".into(),
            prefix: "emission".into(),
            lr: LrClass::Mlp,
            update: Update::Dense,
            required: false,
        }
    }
    fn clone_box(&self) -> Box<dyn SceneModule> {
        Box::new(self.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table() -> EmitterTable {
        EmitterTable::new(
            vec![
                Emitter {
                    centre: [0.0, 2.0, 0.0],
                    extent: [0.4, 0.1, 0.4],
                    radius: 0.3,
                    points: 120,
                    sphere: Some([0.0, 2.05, 0.0, 0.1]),
                    bounds: None,
                    panel: None,
                },
                Emitter {
                    centre: [3.0, 1.0, 0.0],
                    extent: [0.1, 1.5, 1.5],
                    radius: 2.5,
                    points: 800,
                    sphere: None,
                    bounds: Some([[2.95, 0.25, -0.75], [3.05, 1.75, 0.75]]),
                    panel: Panel::of_box([[2.95, 0.25, -0.75], [3.05, 1.75, 0.75]], [0.0, 1.0, 0.0], 0.02),
                },
            ],
            &[[5.0, 4.0, 3.0], [0.5, 0.5, 0.6]],
        )
    }

    #[test]
    fn index_picks_the_nearest_containing_emitter() {
        let t = table();
        assert_eq!(t.index(DVec3::new(0.1, 2.0, 0.0), 0.0), Some(0));
        assert_eq!(t.index(DVec3::new(3.0, 1.5, 0.5), 0.0), Some(1));
        // Between both, nearer the lamp's centre but outside its sphere: the window's.
        assert_eq!(t.index(DVec3::new(1.0, 1.8, 0.0), 0.1), Some(1));
        // Inside both spheres (enlarged): the nearer centre.
        assert_eq!(t.index(DVec3::new(1.2, 1.6, 0.0), 2.0), Some(0));
        // Far from every cluster: not a light, unless the margin reaches it.
        assert_eq!(t.index(DVec3::new(-0.5, -3.0, 0.0), 0.1), None);
        assert_eq!(t.index(DVec3::new(-0.5, -3.0, 0.0), 5.0), Some(0));
        assert!((t.emission(0) - Vec3::new(5.0, 4.0, 3.0)).length() < 1e-5);
        assert!(EmitterTable::new(vec![], &[]).index(DVec3::ZERO, 10.0).is_none());
    }

    #[test]
    fn json_round_trip_with_exactly_the_documented_keys() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("emitters.json");
        let t = table();
        t.write_json(&p, Some(2.0)).unwrap();
        let v: Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
        let top: Vec<&String> = v.as_object().unwrap().keys().collect();
        assert_eq!(top, ["emitters"]);
        let mut keys: Vec<&String> = v["emitters"][0].as_object().unwrap().keys().collect();
        keys.sort();
        assert_eq!(
            keys,
            ["bounds", "centre", "emission", "extent", "panel", "points", "radiance", "radius", "sphere"]
        );
        assert!(v["emitters"][1]["sphere"].is_null() && v["emitters"][0]["bounds"].is_null());
        assert!(v["emitters"][0]["panel"].is_null() && v["emitters"][1]["panel"]["axis"] == 0);
        let r = v["emitters"][0]["radiance"].as_array().unwrap();
        assert!((r[0].as_f64().unwrap() - 2.5).abs() < 1e-5);
        let back = EmitterTable::read_json(&p).unwrap();
        assert_eq!(back.emitters, t.emitters);
        for (a, b) in back.log_emission.iter().zip(&t.log_emission) {
            assert!((a - b).abs() < 1e-6);
        }
        // Without an exposure: radiance is null.
        t.write_json(&p, None).unwrap();
        let v: Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
        assert!(v["emitters"][1]["radiance"].is_null());
        // Bad files: named.
        std::fs::write(&p, "{\"emitters\": [{\"centre\": [0, 0], \"extent\": [1,1,1]}]}").unwrap();
        let e = EmitterTable::read_json(&p).unwrap_err();
        assert!(e.is_bad_input() && e.to_string().contains("emitters[0].centre"), "{e}");
        std::fs::write(&p, "not json").unwrap();
        let e = EmitterTable::read_json(&p).unwrap_err();
        assert!(e.is_bad_input() && e.to_string().contains("emitters.json"), "{e}");
        let s = r#"{"emitters": [{"centre": [0,0,0], "extent": [1,1,1], "points": 3, "emission": [1,-1,1]}]}"#;
        std::fs::write(&p, s).unwrap();
        let e = EmitterTable::read_json(&p).unwrap_err();
        assert!(e.to_string().contains("emitters[0].emission"), "{e}");
        let s = r#"{"emitters": [{"centre": [0,0,0], "extent": [1,1,1], "points": 3, "emission": [1,1,1], "sphere": [0,0,0]}]}"#;
        std::fs::write(&p, s).unwrap();
        let e = EmitterTable::read_json(&p).unwrap_err();
        assert!(e.is_bad_input() && e.to_string().contains("emitters[0].sphere"), "{e}");
        let s = r#"{"emitters": [{"centre": [0,0,0], "extent": [1,1,1], "points": 3, "emission": [1,1,1], "panel": {"axis": 3, "offset": 0, "lo": [0,0], "hi": [1,1], "facing": 1, "depth": 0}}]}"#;
        std::fs::write(&p, s).unwrap();
        let e = EmitterTable::read_json(&p).unwrap_err();
        assert!(e.is_bad_input() && e.to_string().contains("emitters[0].panel"), "{e}");
        let s = r#"{"emitters": [{"centre": [0,0,0], "extent": [1,1,1], "points": 3, "emission": [1,1,1], "bounds": [[0,0,0], [1,-1,1]]}]}"#;
        std::fs::write(&p, s).unwrap();
        let e = EmitterTable::read_json(&p).unwrap_err();
        assert!(e.is_bad_input() && e.to_string().contains("emitters[0].bounds"), "{e}");
    }

    #[test]
    fn unseen_surface_emits_within_the_box_of_the_points() {
        let t = table();
        let margin = 0.08; // the box takes a quarter of it: 2 cm
        let (lamp, window) = (&t.emitters[0], &t.emitters[1]);
        // No box (an older file): anywhere.
        assert!(lamp.may_hold_unseen(DVec3::new(9.0, 9.0, 9.0), margin));
        assert!(window.may_hold_unseen(DVec3::new(3.0, 1.0, 0.0), margin));
        assert!(window.may_hold_unseen(DVec3::new(3.065, 1.76, -0.765), margin));
        // Beside the window in its own plane, inside its bounding sphere (radius 2.5): not it.
        assert!(t.index(DVec3::new(3.0, 1.0, 1.0), 0.0) == Some(1));
        assert!(!window.may_hold_unseen(DVec3::new(3.0, 1.0, 1.0), margin));
        assert!(!window.may_hold_unseen(DVec3::new(3.1, 1.0, 0.0), margin));
    }

    #[test]
    fn one_log_emission_tensor() {
        let mut names = Vec::new();
        table().visit("emission", &mut |n, s, v| names.push((n, s, v.len())));
        assert_eq!(names, [("emission.log_emission".to_string(), vec![2, 3], 6)]);
    }
}
