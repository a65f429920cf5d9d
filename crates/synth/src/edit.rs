//! Edit specs (TOML, world coordinates) as far as synthetic relighting needs them: `relight`
//! operations that scale and tint the emitter nearest to a point. The edit crate reads the same
//! files and extends them with material and insertion operations.
//!
//! ```toml
//! [[op]]
//! kind = "relight"
//! at = [x, y, z]            # selects the emitter nearest to this world point
//! scale = 2.0               # 0 turns it off
//! color = [1.0, 0.8, 0.6]   # per-channel multiplier, default [1, 1, 1]
//! ```

use crate::tracer::Emitter;
use glam::Vec3;
use i2sdf_data::DataError;
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EditSpec {
    #[serde(rename = "op", default)]
    pub ops: Vec<EditOp>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum EditOp {
    Relight {
        at: [f32; 3],
        scale: f32,
        #[serde(default = "ones")]
        color: [f32; 3],
    },
}

fn ones() -> [f32; 3] {
    [1.0; 3]
}

/// Distance from `p` to an axis-aligned box (0 inside).
fn box_distance(p: Vec3, lo: Vec3, hi: Vec3) -> f32 {
    (lo - p).max(p - hi).max(Vec3::ZERO).length()
}

/// The emitter nearest to `at`: smallest distance to its bounding box, ties (e.g. `at` inside
/// several boxes) broken by the distance to the box centre.
pub fn nearest_emitter(emitters: &[Emitter], at: Vec3) -> Option<usize> {
    let key = |e: &Emitter| {
        (
            box_distance(at, e.bounds.0, e.bounds.1),
            (0.5 * (e.bounds.0 + e.bounds.1) - at).length(),
        )
    };
    (0..emitters.len()).min_by(|&a, &b| key(&emitters[a]).partial_cmp(&key(&emitters[b])).unwrap())
}

impl EditSpec {
    pub fn read(path: &Path) -> Result<Self, DataError> {
        let text = std::fs::read_to_string(path).map_err(|e| DataError::file(path, e.to_string()))?;
        let spec: EditSpec = toml::from_str(&text).map_err(|e| DataError::file(path, format!("bad edit spec: {e}")))?;
        for (i, op) in spec.ops.iter().enumerate() {
            let EditOp::Relight { at, scale, color } = op;
            if !at.iter().chain(color.iter()).all(|x| x.is_finite())
                || !(*scale >= 0.0 && scale.is_finite())
                || color.iter().any(|c| *c < 0.0)
            {
                return Err(DataError::field(
                    path,
                    format!("op[{i}]"),
                    "relight needs finite `at`, scale ≥ 0 and colour ≥ 0",
                ));
            }
        }
        Ok(spec)
    }

    pub fn to_toml_string(&self) -> String {
        toml::to_string_pretty(self).expect("edit specs always serialize")
    }

    /// Per-emitter RGB gains after applying every relight op in order.
    pub fn emitter_gains(&self, emitters: &[Emitter]) -> Vec<Vec3> {
        let mut gains = vec![Vec3::ONE; emitters.len()];
        for op in &self.ops {
            let EditOp::Relight { at, scale, color } = op;
            if let Some(k) = nearest_emitter(emitters, Vec3::from(*at)) {
                gains[k] *= *scale * Vec3::from(*color);
            }
        }
        gains
    }
}
