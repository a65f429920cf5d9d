//! The proposals stage 2 samples incident directions from: the cache's fixed mixture and the
//! live estimator's mixture of the current material, each with cones towards the emitters.

use glam::DVec3;
use i2sdf_model::emitters::EmitterTable;
use i2sdf_render::{DirectionMixture, GgxBrdf, Lobe};

/// The fixed proposal of the cache: cosine, five GGX lobes about the frozen normal (ρ ≈ 0.14,
/// 0.24, 0.35, 0.5, 0.71) and a cone towards each emitter. Defensive: every direction of the
/// upper hemisphere has density ≥ 0.25·cos/π, so no material's f_r·cos is left without samples.
/// The cosine share is small because the diffuse part is pooled over neighbours
/// (`stage2.irradiance_radius`) while the specular part rests on the pixel's own samples: with
/// 0.45 in specular lobes (was 0.3 in three) the GT materials' L1 on the cached glossy pixels
/// fell from 0.0236 to 0.0217 (0.0166 with 1024 samples of their own lobe).
pub fn cache_mixture(emitters: &EmitterTable, emitter_sampling: bool) -> DirectionMixture {
    let mut m = DirectionMixture::new();
    m.push(0.25, Lobe::Cosine);
    for alpha in [0.02, 0.06, 0.12, 0.25, 0.5] {
        m.push(0.09, Lobe::Specular { alpha });
    }
    add_cones(&mut m, emitters, emitter_sampling, 0.3);
    m
}

/// Cones towards the emitters sharing `weight` (as many as the mixture holds).
fn add_cones(m: &mut DirectionMixture, emitters: &EmitterTable, emitter_sampling: bool, weight: f32) {
    if !emitter_sampling || emitters.is_empty() {
        return;
    }
    let room = i2sdf_render::proposal::MAX_LOBES - m.len();
    let k = emitters.len().min(room);
    for e in emitters.emitters.iter().take(k) {
        m.push(
            weight / k as f32,
            Lobe::Cone {
                centre: DVec3::from_array(e.centre).as_vec3(),
                radius: e.radius as f32,
            },
        );
    }
}

/// The live estimator's proposal (the paper's GGX mixture of the current material, with the
/// emitter cones of one-sample MIS when enabled).
pub fn live_mixture(brdf: &GgxBrdf, emitters: &EmitterTable, emitter_sampling: bool) -> DirectionMixture {
    let mut m = DirectionMixture::new();
    m.push(
        if emitter_sampling && !emitters.is_empty() {
            0.7
        } else {
            1.0
        },
        Lobe::Brdf(*brdf),
    );
    add_cones(&mut m, emitters, emitter_sampling, 0.3);
    m
}
