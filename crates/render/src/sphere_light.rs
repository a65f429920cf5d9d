//! A spherical emitter (a tessellated bulb), sampled by solid angle: directions uniform in the
//! cone that its circumscribed sphere subtends (pbrt's `Sphere::Sample(ref, u)`), the ray then
//! finding the point on the tessellation. Uniform area sampling wastes the half of the samples
//! that land on the far side and weighs the rest by cos/d², which close to a small bright bulb
//! was the largest source of variance of the livingroom (≈45 % of it in direct light alone); the
//! cone pdf is constant over the bulb. Points inside the sphere fall back to area sampling.

use crate::area_light::AreaLight;
use crate::cone_light::cone_sample;
use crate::geometry::Hit;
use crate::light::{cone_one_minus_cos, Light, LightSample, Visibility};
use glam::Vec3;
use i2sdf_data::TriangleMesh;

#[derive(Clone, Debug)]
pub struct SphereLight {
    pub center: Vec3,
    /// Radius of the circumscribed sphere (the cone must contain every emitting point).
    pub radius: f32,
    area: AreaLight,
}

impl SphereLight {
    /// The tessellated sphere `faces` of `mesh` around `center`.
    pub fn new(mesh: &TriangleMesh, faces: &[u32], center: Vec3, emission: Vec3) -> Self {
        let area = AreaLight::new(mesh, faces, emission);
        // The tessellation's vertices lie on the nominal sphere up to rounding; pad a little.
        let radius = area.vertices().map(|v| (v - center).length()).fold(0.0f32, f32::max) * (1.0 + 1e-4);
        SphereLight { center, radius, area }
    }

    fn cone(&self, x: Vec3) -> Option<f32> {
        cone_one_minus_cos(x, self.center, self.radius)
    }
}

impl Light for SphereLight {
    fn sample(&self, x: Vec3, u: [f32; 3]) -> Option<LightSample> {
        // Uniform in the cone around x → centre (pbrt-v3 §14.2.2), as the cone light samples.
        let Some((wi, pdf)) = cone_sample(x, self.center, self.radius, u[1], u[2]) else {
            return self.area.sample(x, u);
        };
        Some(LightSample {
            wi,
            pdf,
            radiance: self.area.emission,
            // The chord through the tessellation starts within the circumscribed sphere.
            visibility: Visibility::FirstHit((self.center - x).length() + self.radius),
        })
    }

    fn pdf(&self, x: Vec3, wi: Vec3, hit: &Hit) -> f32 {
        if -hit.normal.dot(wi) <= 0.0 {
            return 0.0;
        }
        match self.cone(x) {
            Some(omc) => 1.0 / (std::f32::consts::TAU * omc),
            None => self.area.pdf(x, wi, hit),
        }
    }

    fn emitted(&self, hit: &Hit, wi: Vec3) -> Vec3 {
        self.area.emitted(hit, wi)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::area_light::test_support::check_density;
    use crate::mesh_geometry::MeshGeometry;

    fn bulb(center: Vec3, radius: f32) -> TriangleMesh {
        let mut m = TriangleMesh::unit_icosphere(3);
        m.positions
            .iter_mut()
            .for_each(|p| *p = (center + radius * Vec3::from(*p)).to_array());
        m
    }

    #[test]
    fn pdf_is_the_density_of_sample() {
        let c = Vec3::new(0.0, 0.6, 0.0);
        let mesh = bulb(c, 0.3);
        let faces: Vec<u32> = (0..mesh.faces.len() as u32).collect();
        let light = SphereLight::new(&mesh, &faces, c, Vec3::new(1.0, 0.9, 0.8));
        assert!((light.radius / 0.3 - 1.0).abs() < 2e-4);
        let geo = MeshGeometry::new(&mesh, vec![0; faces.len()]);
        // Near (a wide cone) and far (a narrow one), the receiver tilted.
        check_density(&light, &geo, Vec3::new(0.4, 0.0, 0.3), Vec3::Y);
        check_density(
            &light,
            &geo,
            Vec3::new(3.0, 0.2, -2.0),
            Vec3::new(-1.0, 0.2, 0.5).normalize(),
        );
    }

    #[test]
    fn cone_samples_cover_the_bulb() {
        let c = Vec3::new(0.0, 0.6, 0.0);
        let mesh = bulb(c, 0.3);
        let faces: Vec<u32> = (0..mesh.faces.len() as u32).collect();
        let light = SphereLight::new(&mesh, &faces, c, Vec3::ONE);
        let x = Vec3::ZERO;
        // Cone edge: sin θ_max = r/d.
        let edge = light.sample(x, [0.0, 1.0, 0.0]).unwrap();
        let sin = edge.wi.cross((c - x).normalize()).length();
        assert!((sin - light.radius / 0.6).abs() < 1e-4, "{sin}");
        assert!(matches!(edge.visibility, Visibility::FirstHit(d) if (d - 0.9).abs() < 1e-3));
    }
}
