//! The light interface of the Monte Carlo integrator: each emitter samples a direction towards
//! itself from a shading point (next-event estimation), gives the solid-angle density of any
//! direction that reaches it (for multiple importance sampling of BRDF samples), and its emitted
//! radiance. Emitters are one-sided and reflect nothing; paths end on them.
//!
//! The [`LightSet`] maps a hit to its emitter through the geometry's surface label, so that any
//! geometry can carry emitters: a room's emitting shapes, or stage 2's clusters of emitter
//! surface points (paper Sec. 4.2: the SDF tracer labels a hit with its cluster).

use crate::geometry::Hit;
use glam::Vec3;

/// How a light sample's emitter must be reached for its light to count.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Visibility {
    /// A point on the emitter was sampled at this distance: the open segment must be free.
    Segment(f32),
    /// A direction was sampled (towards a sphere, say): the first surface along it, within this
    /// distance, must be the front of this emitter.
    FirstHit(f32),
}

/// A next-event estimation sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightSample {
    /// Unit direction from the shading point towards the emitter.
    pub wi: Vec3,
    /// Solid-angle density of `wi` at the shading point.
    pub pdf: f32,
    /// Radiance the emitter sends back along −wi (if visible).
    pub radiance: Vec3,
    pub visibility: Visibility,
}

pub trait Light: Send + Sync {
    /// A direction towards the emitter from `x` with three uniforms; `None` when the sample can
    /// carry no light (the back of a one-sided emitter).
    fn sample(&self, x: Vec3, u: [f32; 3]) -> Option<LightSample>;
    /// The solid-angle density with which [`Light::sample`] from `x` produces `wi`, given that the
    /// ray (x, wi) first hits this emitter at `hit` (`hit.t` = distance from `x`).
    fn pdf(&self, x: Vec3, wi: Vec3, hit: &Hit) -> f32;
    /// Radiance leaving `hit` along −wi, for a ray travelling along `wi` (zero from behind).
    fn emitted(&self, hit: &Hit, wi: Vec3) -> Vec3;
}

/// The scene's emitters, indexed 0..len (the index is what per-emitter radiance is kept by).
pub struct LightSet {
    lights: Vec<Box<dyn Light>>,
    /// Emitter of each surface label (labels past the end emit nothing).
    emitter_of_surface: Vec<Option<u32>>,
}

impl LightSet {
    pub fn new(lights: Vec<Box<dyn Light>>, emitter_of_surface: Vec<Option<u32>>) -> Self {
        assert!(
            emitter_of_surface
                .iter()
                .flatten()
                .all(|&k| (k as usize) < lights.len()),
            "a surface names an emitter that does not exist"
        );
        LightSet {
            lights,
            emitter_of_surface,
        }
    }

    pub fn len(&self) -> usize {
        self.lights.len()
    }

    pub fn is_empty(&self) -> bool {
        self.lights.is_empty()
    }

    pub fn get(&self, k: usize) -> &dyn Light {
        self.lights[k].as_ref()
    }

    /// The emitter a hit lies on, if any.
    #[inline]
    pub fn emitter_of(&self, hit: &Hit) -> Option<usize> {
        self.emitter_of_surface
            .get(hit.surface as usize)
            .copied()
            .flatten()
            .map(|k| k as usize)
    }
}

/// 1 − cos θ_max of the cone that the sphere (`center`, `radius`) subtends from `x`, or `None`
/// when `x` is inside it. Written as sin²/(1 + cos) to stay accurate for small cones.
pub fn cone_one_minus_cos(x: Vec3, center: Vec3, radius: f32) -> Option<f32> {
    let d2 = (center - x).length_squared();
    let r2 = radius * radius;
    if d2 <= r2 * (1.0 + 1e-4) {
        return None;
    }
    let sin2 = r2 / d2;
    Some(sin2 / (1.0 + (1.0 - sin2).sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn surfaces_map_to_their_emitters() {
        struct Dark;
        impl Light for Dark {
            fn sample(&self, _: Vec3, _: [f32; 3]) -> Option<LightSample> {
                None
            }
            fn pdf(&self, _: Vec3, _: Vec3, _: &Hit) -> f32 {
                0.0
            }
            fn emitted(&self, _: &Hit, _: Vec3) -> Vec3 {
                Vec3::ZERO
            }
        }
        let set = LightSet::new(vec![Box::new(Dark), Box::new(Dark)], vec![None, Some(1), Some(0)]);
        let hit = |surface| Hit {
            t: 1.0,
            normal: Vec3::Y,
            surface,
            prim: 0,
        };
        let got: Vec<_> = (0..4).map(|s| set.emitter_of(&hit(s))).collect();
        assert_eq!(got, [None, Some(1), Some(0), None]);
    }

    #[test]
    fn cone_of_a_sphere() {
        // Seen from distance 2, a unit sphere subtends θ_max = 30°.
        let omc = cone_one_minus_cos(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, 1.0).unwrap();
        assert!((omc - (1.0 - 30f32.to_radians().cos())).abs() < 1e-6);
        assert!(cone_one_minus_cos(Vec3::new(0.0, 0.0, 0.5), Vec3::ZERO, 1.0).is_none());
    }
}
