//! The three steps of stage 1 (paper Sec. 5 "Training of geometry and radiance fields", supp.
//! "Implementation Details"): warm-up (no bubble), bubble (bubble loss and adaptive sampling on,
//! eikonal and smoothness off), smooth (bubble off, eikonal and smoothness on). Step lengths scale
//! with the total iteration count (paper: 50k / 100k / 50k of 200k).

use crate::auto::Auto;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    WarmUp,
    Bubble,
    Smooth,
}

/// Loss weights (supp. "Implementation Details"): λ_geo = 1, λ_emi = 0.5, λ2 (depth) = 0.1,
/// λ3 (normal) = 0.05; λ1 (eikonal), λ4 (smooth), λ5 (bubble) depend on the phase.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LossWeights {
    pub rgb: f32,
    pub eikonal: f32,
    pub depth: f32,
    pub normal: f32,
    pub smooth: f32,
    pub bubble: f32,
    pub emitter: f32,
    /// Beyond the paper: the hinge max(0, d) on points just behind each bubble point along its
    /// ray (`losses::inside`), on whenever the bubble loss is; 0 turns it off (the paper).
    pub inside: f32,
}

impl Default for LossWeights {
    fn default() -> Self {
        LossWeights {
            rgb: 1.0,
            eikonal: 0.1,
            depth: 0.1,
            normal: 0.05,
            smooth: 0.01,
            bubble: 0.5,
            emitter: 0.5,
            inside: 0.5,
        }
    }
}

/// The paper's λ1 in the bubble step (as a fraction of warm-up's): the eikonal term off.
pub const PAPER_BUBBLE_EIKONAL: f64 = 0.0;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Schedule {
    /// Fraction of the iterations spent in warm-up (paper: 50k of 200k).
    pub warmup_fraction: f64,
    /// Fraction spent in the bubble step (paper: 100k of 200k); the rest is the smooth step.
    pub bubble_fraction: f64,
    /// Turn the bubble step off entirely (ablation): the bubble step then trains like warm-up.
    pub bubble: bool,
    /// λ5 in the smooth step, as a fraction of the bubble step's (beyond the paper, which turns
    /// bubbles off there: 0; the default 1 keeps it). The bubble points are still drawn from the error-guided PDF maps,
    /// which by then hold only the pixels whose depth error stays above P_min — the thin and
    /// suspended objects that the smooth step's eikonal and smoothness terms would otherwise
    /// erase — so the bubbles stay on only where the error persists.
    pub smooth_bubble: f64,
    /// λ1 in the bubble step, as a fraction of warm-up's (the paper turns the eikonal term off
    /// there: 0). Without it nothing holds the SDF to a distance for most of stage 1, and
    /// eq:bubble on a sensor's noisy points can flatten it over the noise's band. `"auto"`: 1
    /// where the depth is a sensor's, else 0 (`TrainConfig::resolve`).
    pub bubble_eikonal: Auto<f64>,
}

impl Default for Schedule {
    fn default() -> Self {
        Schedule {
            // Issue 26: the room closes as soon as the bubble step starts, and the thin objects it
            // recovers are partly lost in a smooth step, so the bubble step starts at 15 % and
            // runs to the end (the paper's 25 / 50 / 25 %: configs/paper.toml).
            warmup_fraction: 0.15,
            bubble_fraction: 0.85,
            bubble: true,
            // Measured on the default room (issue 12): the thin objects survive the smooth step.
            smooth_bubble: 1.0,
            bubble_eikonal: Auto::AUTO,
        }
    }
}

impl Schedule {
    pub fn validate(&self) -> Result<(), String> {
        let ok = |f: f64| (0.0..=1.0).contains(&f);
        if let Some(e) = self.bubble_eikonal.value().filter(|e| !ok(*e)) {
            return Err(format!("bubble_eikonal ({e}) must be in [0, 1] or \"auto\""));
        }
        if !ok(self.smooth_bubble) {
            return Err(format!("smooth_bubble ({}) must be in [0, 1]", self.smooth_bubble));
        }
        if !ok(self.warmup_fraction) || !ok(self.bubble_fraction) || self.warmup_fraction + self.bubble_fraction > 1.0 {
            return Err(format!(
                "warmup_fraction ({}) and bubble_fraction ({}) must be in [0, 1] and sum to at most 1",
                self.warmup_fraction, self.bubble_fraction
            ));
        }
        Ok(())
    }

    /// First iteration of the bubble and of the smooth step.
    pub fn boundaries(&self, total: u64) -> (u64, u64) {
        let b = (self.warmup_fraction * total as f64).round() as u64;
        let s = ((self.warmup_fraction + self.bubble_fraction) * total as f64).round() as u64;
        (b, s.max(b))
    }

    pub fn phase(&self, iteration: u64, total: u64) -> Phase {
        let (b, s) = self.boundaries(total);
        if iteration < b {
            Phase::WarmUp
        } else if iteration < s {
            Phase::Bubble
        } else {
            Phase::Smooth
        }
    }

    /// The weights in force in a phase (supp.: warm-up λ1 = 0.1, λ4 = λ5 = 0; bubble λ1 = λ4 = 0,
    /// or `bubble_eikonal` × λ1, λ5 = 0.5; smooth λ1 = 0.1, λ4 = 0.01, λ5 = 0, or `smooth_bubble`
    /// × λ5).
    pub fn weights(&self, phase: Phase, base: &LossWeights) -> LossWeights {
        let mut w = base.clone();
        match phase {
            Phase::WarmUp => {
                w.smooth = 0.0;
                w.bubble = 0.0;
            }
            Phase::Bubble if self.bubble => {
                // Unresolved (never a run's: `TrainConfig::resolve`): the paper's.
                w.eikonal = base.eikonal * self.bubble_eikonal.or(PAPER_BUBBLE_EIKONAL) as f32;
                w.smooth = 0.0;
            }
            Phase::Bubble => {
                // Ablation without bubbles: the middle step is more warm-up.
                w.smooth = 0.0;
                w.bubble = 0.0;
            }
            Phase::Smooth if self.bubble => w.bubble = base.bubble * self.smooth_bubble as f32,
            Phase::Smooth => w.bubble = 0.0,
        }
        if w.bubble == 0.0 {
            w.inside = 0.0;
        }
        w
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_step_lengths_and_weights() {
        // configs/paper.toml's schedule
        let s = Schedule {
            warmup_fraction: 0.25,
            bubble_fraction: 0.5,
            smooth_bubble: 0.0,
            ..Default::default()
        };
        assert_eq!(s.boundaries(200_000), (50_000, 150_000));
        assert_eq!(s.phase(49_999, 200_000), Phase::WarmUp);
        assert_eq!(s.phase(50_000, 200_000), Phase::Bubble);
        assert_eq!(s.phase(150_000, 200_000), Phase::Smooth);
        let base = LossWeights::default();
        let w = s.weights(Phase::WarmUp, &base);
        assert_eq!((w.eikonal, w.smooth, w.bubble), (0.1, 0.0, 0.0));
        let w = s.weights(Phase::Bubble, &base);
        assert_eq!((w.eikonal, w.smooth, w.bubble), (0.0, 0.0, 0.5));
        let w = s.weights(Phase::Smooth, &base);
        assert_eq!((w.eikonal, w.smooth, w.bubble), (0.1, 0.01, 0.0));
        assert_eq!((w.depth, w.normal, w.emitter, w.rgb), (0.1, 0.05, 0.5, 1.0));
    }

    #[test]
    fn the_default_bubble_step_runs_to_the_end() {
        let s = Schedule::default();
        assert_eq!(s.boundaries(2500), (375, 2500));
        assert_eq!(s.phase(374, 2500), Phase::WarmUp);
        assert_eq!(s.phase(2499, 2500), Phase::Bubble);
    }

    #[test]
    fn the_bubble_step_can_keep_part_of_the_eikonal_term() {
        let s = Schedule {
            bubble_eikonal: 0.25.into(),
            ..Default::default()
        };
        let w = s.weights(Phase::Bubble, &LossWeights::default());
        assert!((w.eikonal - 0.025).abs() < 1e-7);
        assert_eq!((w.smooth, w.bubble), (0.0, 0.5));
        assert!(Schedule {
            bubble_eikonal: 1.5.into(),
            ..Default::default()
        }
        .validate()
        .is_err());
    }

    #[test]
    fn bubbles_can_persist_into_the_smooth_step() {
        let s = Schedule {
            smooth_bubble: 0.2,
            ..Default::default()
        };
        let w = s.weights(Phase::Smooth, &LossWeights::default());
        assert_eq!((w.eikonal, w.smooth), (0.1, 0.01));
        assert!((w.bubble - 0.1).abs() < 1e-7);
        assert!(Schedule {
            smooth_bubble: 1.5,
            ..Default::default()
        }
        .validate()
        .is_err());
    }

    #[test]
    fn ablation_without_bubbles_never_applies_them() {
        let s = Schedule {
            bubble: false,
            smooth_bubble: 0.5,
            ..Default::default()
        };
        for it in (0..1000).step_by(50) {
            assert_eq!(s.weights(s.phase(it, 1000), &LossWeights::default()).bubble, 0.0);
        }
        assert!(Schedule {
            warmup_fraction: 0.8,
            bubble_fraction: 0.5,
            bubble: true,
            smooth_bubble: 0.0,
            bubble_eikonal: Auto::AUTO,
        }
        .validate()
        .is_err());
    }
}
