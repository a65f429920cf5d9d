//! Shared physics of i2sdf: the GGX (Unreal) BRDF of the supplementary ("BRDF Model") with its
//! importance sampling and exact pdf, small Monte Carlo sampling utilities and colour helpers.
//! Used by the synthetic ground-truth path tracer (`i2sdf-synth`), by stage 2's differentiable
//! Monte Carlo shading and by the edit renderer, so all three shade with one model.

pub mod brdf;
pub mod color;
pub mod sampling;
pub mod volume;

pub use brdf::{BrdfLobe, BrdfSample, GgxBrdf};
pub use color::luminance;
