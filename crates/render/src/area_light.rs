//! An emitter made of triangles with uniform radiance, sampled uniformly by area (quads, boxes,
//! cylinders of a synthetic room; also the fallback of [`crate::SphereLight`] for points inside).

use crate::geometry::Hit;
use crate::light::{Light, LightSample, Visibility};
use crate::sampling::uniform_triangle;
use glam::Vec3;
use i2sdf_data::TriangleMesh;

#[derive(Clone, Debug)]
pub struct AreaLight {
    /// Vertices of each emitting triangle.
    tris: Vec<[Vec3; 3]>,
    /// Outward unit normal of each.
    normals: Vec<Vec3>,
    /// Running sum of the triangles' areas.
    cdf: Vec<f32>,
    area: f32,
    pub emission: Vec3,
}

impl AreaLight {
    /// The triangles `faces` of `mesh`, emitting `emission` along their outward (winding) normal.
    pub fn new(mesh: &TriangleMesh, faces: &[u32], emission: Vec3) -> Self {
        assert!(!faces.is_empty(), "an area light needs triangles");
        let (mut tris, mut normals, mut cdf, mut area) = (Vec::new(), Vec::new(), Vec::new(), 0.0f32);
        for &f in faces {
            let p = [0, 1, 2].map(|k| mesh.vertex(f as usize, k));
            let c = (p[1] - p[0]).cross(p[2] - p[0]);
            area += 0.5 * c.length();
            tris.push(p);
            normals.push(c.normalize_or_zero());
            cdf.push(area);
        }
        AreaLight {
            tris,
            normals,
            cdf,
            area,
            emission,
        }
    }

    pub fn area(&self) -> f32 {
        self.area
    }

    /// Every vertex (for bounding spheres).
    pub fn vertices(&self) -> impl Iterator<Item = Vec3> + '_ {
        self.tris.iter().flatten().copied()
    }
}

impl Light for AreaLight {
    fn sample(&self, x: Vec3, u: [f32; 3]) -> Option<LightSample> {
        let i = self
            .cdf
            .partition_point(|&c| c <= u[0] * self.area)
            .min(self.tris.len() - 1);
        let [p0, p1, p2] = self.tris[i];
        let (b1, b2) = uniform_triangle(u[1], u[2]);
        let y = p0 * (1.0 - b1 - b2) + p1 * b1 + p2 * b2;
        let to = y - x;
        let dist = to.length();
        let wi = to / dist;
        let cos_y = -self.normals[i].dot(wi);
        if !(cos_y > 0.0) {
            return None;
        }
        Some(LightSample {
            wi,
            // Area density 1/A converted to solid angle at x.
            pdf: dist * dist / (self.area * cos_y),
            radiance: self.emission,
            visibility: Visibility::Segment(dist),
        })
    }

    fn pdf(&self, _x: Vec3, wi: Vec3, hit: &Hit) -> f32 {
        let cos_light = -hit.normal.dot(wi);
        if cos_light <= 0.0 {
            return 0.0;
        }
        hit.t * hit.t / (self.area * cos_light)
    }

    fn emitted(&self, hit: &Hit, wi: Vec3) -> Vec3 {
        if -hit.normal.dot(wi) > 0.0 {
            self.emission
        } else {
            Vec3::ZERO
        }
    }
}

/// Checks shared by the light tests: `pdf` agrees with the density `sample` reports, and that
/// density is right, i.e. E[g(wi)/pdf] over light samples equals ∫ g dω over the directions that
/// see the emitter's front, estimated independently with uniform directions.
#[cfg(test)]
pub(crate) mod test_support {
    use super::*;
    use crate::geometry::{intersect_one, Geometry, Ray};
    use crate::sampling::uniform_sphere;
    use rand::{Rng, SeedableRng};

    pub fn check_density(light: &dyn Light, geometry: &dyn Geometry, x: Vec3, n: Vec3) {
        let mut rng = rand_pcg::Pcg32::seed_from_u64(17);
        // g: a cosine lobe around n (clamped), so the check weighs directions unevenly.
        let g = |w: Vec3| n.dot(w).max(0.0) + 0.1;
        let front =
            |w: Vec3| intersect_one(geometry, Ray::new(x, w, 0.0, f32::INFINITY)).filter(|h| h.normal.dot(w) < 0.0);
        let samples = 200_000;
        let (mut by_light, mut checked) = (0.0f64, 0);
        for _ in 0..samples {
            let Some(ls) = light.sample(x, [rng.gen(), rng.gen(), rng.gen()]) else {
                continue;
            };
            assert!((ls.wi.length() - 1.0).abs() < 1e-4);
            let Some(hit) = front(ls.wi) else {
                continue;
            };
            // A sampled point hidden behind another part of the emitter is not what x sees.
            if let Visibility::Segment(d) = ls.visibility {
                if (hit.t - d).abs() > 1e-3 * d {
                    continue;
                }
            }
            let pdf = light.pdf(x, ls.wi, &hit);
            assert!((pdf / ls.pdf - 1.0).abs() < 2e-3, "pdf {pdf} vs sample's {}", ls.pdf);
            assert_eq!(light.emitted(&hit, ls.wi), ls.radiance);
            checked += 1;
            by_light += (g(ls.wi) / ls.pdf) as f64;
        }
        assert!(checked > samples / 2, "only {checked} samples reached the emitter");
        by_light /= samples as f64;
        let mut by_sphere = 0.0f64;
        let uniform = 2_000_000;
        for _ in 0..uniform {
            let w = uniform_sphere(rng.gen(), rng.gen());
            if front(w).is_some() {
                by_sphere += g(w) as f64 * 4.0 * std::f64::consts::PI;
            }
        }
        by_sphere /= uniform as f64;
        assert!(
            (by_light / by_sphere - 1.0).abs() < 0.02,
            "∫g dω: {by_light} by light sampling, {by_sphere} by uniform directions"
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh_geometry::MeshGeometry;

    /// A 1×0.5 quad facing down at height 1, and a smaller tilted one beside it.
    fn panels() -> TriangleMesh {
        // The quad's winding faces it down (towards the shading points below).
        TriangleMesh {
            positions: vec![
                [-0.5, 1.0, -0.25],
                [0.5, 1.0, -0.25],
                [0.5, 1.0, 0.25],
                [-0.5, 1.0, 0.25],
                [0.8, 0.6, 0.0],
                [1.0, 0.9, 0.0],
                [1.0, 0.9, 0.3],
            ],
            faces: vec![[0, 1, 2], [0, 2, 3], [4, 5, 6]],
            face_object_ids: None,
        }
    }

    #[test]
    fn pdf_is_the_density_of_sample() {
        let mesh = panels();
        let light = AreaLight::new(&mesh, &[0, 1, 2], Vec3::new(2.0, 1.0, 0.5));
        // The quad (0.5) and the triangle ½|(0.2, 0.3, 0) × (0.2, 0.3, 0.3)| = ½ √0.0117.
        assert!((light.area() - (0.5 + 0.5 * 0.0117f32.sqrt())).abs() < 1e-5);
        let geo = MeshGeometry::new(&mesh, vec![0; 3]);
        test_support::check_density(&light, &geo, Vec3::new(0.2, 0.0, 0.1), Vec3::Y);
        test_support::check_density(
            &light,
            &geo,
            Vec3::new(-0.6, 0.3, 0.4),
            Vec3::new(1.0, 1.0, 0.0).normalize(),
        );
    }

    #[test]
    fn emits_from_the_front_only() {
        let mesh = panels();
        let light = AreaLight::new(&mesh, &[0, 1], Vec3::ONE);
        let below = light.sample(Vec3::ZERO, [0.3, 0.5, 0.5]).unwrap();
        assert!(below.wi.y > 0.0 && matches!(below.visibility, Visibility::Segment(d) if d > 0.9));
        assert!(light.sample(Vec3::new(0.0, 2.0, 0.0), [0.3, 0.5, 0.5]).is_none());
        let hit = Hit {
            t: 1.0,
            normal: -Vec3::Y,
            surface: 0,
            prim: 0,
        };
        assert_eq!(light.emitted(&hit, Vec3::Y), Vec3::ONE);
        assert_eq!(light.emitted(&hit, -Vec3::Y), Vec3::ZERO);
        assert_eq!(light.pdf(Vec3::ZERO, -Vec3::Y, &hit), 0.0);
    }
}
