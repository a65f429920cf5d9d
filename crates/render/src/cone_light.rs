//! An emitter known only by a bounding sphere: stage 2's clusters of emitter points on the
//! neural SDF (paper Sec. 4.2), whose surface is the SDF itself and has no tessellation to sample.
//! Like [`crate::SphereLight`] it is sampled by solid angle, uniformly in the cone that the sphere
//! subtends (pbrt-v3 §14.2.2), and the ray then finds the emitting surface: the integrator maps
//! the first hit to this light through the surface label of [`crate::LightSet`]. The cone pdf is
//! constant, so it also serves as the emitter lobe of stage 2's direction mixture
//! ([`crate::proposal`]), through the free functions [`cone_sample`] and [`cone_density`].

use crate::geometry::Hit;
use crate::light::{cone_one_minus_cos, Light, LightSample, Visibility};
use crate::sampling::Frame;
use glam::Vec3;
use std::f32::consts::TAU;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ConeLight {
    pub centre: Vec3,
    /// Radius of a sphere that contains every emitting point (the cone must cover them all).
    pub radius: f32,
    /// Radiance leaving the front of the emitter.
    pub emission: Vec3,
}

/// A direction uniform in the cone that the sphere (`centre`, `radius`) subtends from `x`, with
/// its solid-angle density 1/(2π(1 − cos θ_max)); `None` when `x` is inside the sphere.
#[inline]
pub fn cone_sample(x: Vec3, centre: Vec3, radius: f32, u1: f32, u2: f32) -> Option<(Vec3, f32)> {
    let omc = cone_one_minus_cos(x, centre, radius)?;
    // Uniform in 1 − cos θ ∈ [0, omc] and in φ, computed from 1 − cos θ so that distant, small
    // cones keep their precision (as SphereLight).
    let axis = (centre - x).normalize();
    let one_minus_cos = u1 * omc;
    let cos_t = 1.0 - one_minus_cos;
    let sin_t = (one_minus_cos * (2.0 - one_minus_cos)).max(0.0).sqrt();
    let phi = TAU * u2;
    let wi = Frame::from_normal(axis).to_world(Vec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t));
    Some((wi, 1.0 / (TAU * omc)))
}

/// The density of [`cone_sample`] at the unit direction `wi`: 1/(2π(1 − cos θ_max)) inside the
/// cone, 0 outside it and when `x` is inside the sphere.
#[inline]
pub fn cone_density(x: Vec3, centre: Vec3, radius: f32, wi: Vec3) -> f32 {
    let Some(omc) = cone_one_minus_cos(x, centre, radius) else {
        return 0.0;
    };
    let axis = (centre - x).normalize();
    // 1 − cos θ = |wi − axis|²/2 for unit vectors: no cancellation for narrow cones. The slack
    // keeps the sampler's own edge directions inside: their rounding through the frame (~1e-7
    // per component) moves |wi − axis|² by ~3.4e-7 sin θ_max ≈ 5e-7 sqrt(omc). It is kept that
    // small because it inflates ∫ pdf dω beyond 1 by its relative size.
    let one_minus_cos = 0.5 * (wi - axis).length_squared();
    if one_minus_cos <= omc * (1.0 + 1e-6) + 1e-6 * omc.sqrt() {
        1.0 / (TAU * omc)
    } else {
        0.0
    }
}

impl ConeLight {
    pub fn new(centre: Vec3, radius: f32, emission: Vec3) -> Self {
        ConeLight {
            centre,
            radius,
            emission,
        }
    }

    /// The solid-angle density with which [`Light::sample`] from `x` draws `wi` (no hit needed).
    #[inline]
    pub fn cone_pdf(&self, x: Vec3, wi: Vec3) -> f32 {
        cone_density(x, self.centre, self.radius, wi)
    }
}

impl Light for ConeLight {
    fn sample(&self, x: Vec3, u: [f32; 3]) -> Option<LightSample> {
        let (wi, pdf) = cone_sample(x, self.centre, self.radius, u[1], u[2])?;
        Some(LightSample {
            wi,
            pdf,
            radiance: self.emission,
            // Every emitting point lies within the sphere, so the first hit is nearer than this.
            visibility: Visibility::FirstHit((self.centre - x).length() + self.radius),
        })
    }

    fn pdf(&self, x: Vec3, wi: Vec3, _hit: &Hit) -> f32 {
        self.cone_pdf(x, wi)
    }

    fn emitted(&self, hit: &Hit, wi: Vec3) -> Vec3 {
        if hit.normal.dot(wi) < 0.0 {
            self.emission
        } else {
            Vec3::ZERO
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::area_light::test_support::check_density;
    use crate::chi2::chi2_pvalue;
    use crate::mesh_geometry::MeshGeometry;
    use crate::sampling::uniform_sphere;
    use i2sdf_data::TriangleMesh;
    use rand::{Rng, SeedableRng};

    fn bulb(center: Vec3, radius: f32) -> TriangleMesh {
        let mut m = TriangleMesh::unit_icosphere(3);
        m.positions
            .iter_mut()
            .for_each(|p| *p = (center + radius * Vec3::from(*p)).to_array());
        m
    }

    #[test]
    fn pdf_is_the_density_of_sample() {
        // An emitter surface inside the bounding sphere (a tessellated bulb); near and far.
        let c = Vec3::new(0.0, 0.6, 0.0);
        let mesh = bulb(c, 0.3);
        let faces: Vec<u32> = (0..mesh.faces.len() as u32).collect();
        let geo = MeshGeometry::new(&mesh, vec![0; faces.len()]);
        let light = ConeLight::new(c, 0.3 * (1.0 + 1e-4), Vec3::new(1.0, 0.9, 0.8));
        check_density(&light, &geo, Vec3::new(0.4, 0.0, 0.3), Vec3::Y);
        check_density(
            &light,
            &geo,
            Vec3::new(3.0, 0.2, -2.0),
            Vec3::new(-1.0, 0.2, 0.5).normalize(),
        );
    }

    #[test]
    fn samples_lie_in_the_cone_and_follow_the_pdf() {
        let light = ConeLight::new(Vec3::new(0.3, 1.0, -0.2), 0.4, Vec3::ONE);
        for (k, x) in [Vec3::ZERO, Vec3::new(5.0, -3.0, 2.0)].into_iter().enumerate() {
            let axis = (light.centre - x).normalize();
            let dist = (light.centre - x).length();
            let cos_max = (1.0 - (light.radius / dist).powi(2)).sqrt();
            let mut rng = rand_pcg::Pcg32::seed_from_u64(4 + k as u64);
            for _ in 0..10_000 {
                let s = light.sample(x, [rng.gen(), rng.gen(), rng.gen()]).unwrap();
                assert!((s.wi.length() - 1.0).abs() < 1e-5);
                assert!(s.wi.dot(axis) >= cos_max - 1e-5, "outside the cone");
                assert_eq!(light.cone_pdf(x, s.wi), s.pdf);
                assert_eq!(s.radiance, light.emission);
                assert!(matches!(s.visibility, Visibility::FirstHit(t) if (t - dist - light.radius).abs() < 1e-5));
            }
            // χ² of the samples against cone_pdf, binned in (cos θ, φ) about the axis over the
            // cone and a margin outside it.
            let cos_min = 1.0 - 1.2 * (1.0 - cos_max as f64);
            let p = chi2_pvalue(
                axis,
                cos_min,
                |w| light.cone_pdf(x, w) as f64,
                |u| light.sample(x, u).map(|s| s.wi),
                200_000,
                9 + k as u64,
            );
            eprintln!("cone from {x}: χ² p-value {p:.3}");
            assert!(p > 1e-3, "χ² p-value {p:.2e}");
        }
    }

    #[test]
    fn cone_pdf_integrates_to_one() {
        let light = ConeLight::new(Vec3::new(0.3, 1.0, -0.2), 0.4, Vec3::ONE);
        let mut rng = rand_pcg::Pcg32::seed_from_u64(2);
        for x in [Vec3::ZERO, Vec3::new(2.0, -1.0, 1.0)] {
            // Stratified uniform directions over the sphere.
            let m = 700;
            let mut acc = 0.0f64;
            for i in 0..m {
                for j in 0..m {
                    let u1 = (i as f32 + rng.gen::<f32>()) / m as f32;
                    let u2 = (j as f32 + rng.gen::<f32>()) / m as f32;
                    acc += light.cone_pdf(x, uniform_sphere(u1, u2)) as f64;
                }
            }
            let total = acc * 4.0 * std::f64::consts::PI / (m * m) as f64;
            assert!((total - 1.0).abs() < 5e-3, "∫ pdf dω = {total}");
        }
    }

    #[test]
    fn inside_the_sphere_and_one_sided_emission() {
        let light = ConeLight::new(Vec3::ZERO, 1.0, Vec3::new(2.0, 1.0, 0.5));
        let x = Vec3::new(0.2, 0.1, 0.0);
        assert!(light.sample(x, [0.5; 3]).is_none());
        assert_eq!(light.cone_pdf(x, Vec3::X), 0.0);
        let hit = Hit {
            t: 1.0,
            normal: -Vec3::Y,
            surface: 0,
            prim: 0,
        };
        assert_eq!(light.pdf(x, Vec3::Y, &hit), 0.0);
        assert_eq!(light.emitted(&hit, Vec3::Y), light.emission);
        assert_eq!(light.emitted(&hit, -Vec3::Y), Vec3::ZERO);
        // Outside, directions away from the sphere have no density.
        let far = Vec3::new(0.0, -3.0, 0.0);
        assert!(light.cone_pdf(far, Vec3::Y) > 0.0);
        assert_eq!(light.cone_pdf(far, -Vec3::Y), 0.0);
    }
}
