//! The edited scene's geometry: the recovered surface (the frozen SDF, or any [`Geometry`]) ∪ the
//! inserted objects (one triangle BVH). Both answer every batch; a ray takes the nearer hit.
//! Labels below `first_insert_label` are the base's own (0 ordinary, k + 1 emitter k for the
//! frozen SDF); insert `j`'s triangles carry label `first_insert_label + j`.

use i2sdf_render::{Geometry, Hit, MeshGeometry, Ray};

pub struct UnionGeometry<'a> {
    pub base: &'a dyn Geometry,
    /// The inserted objects, when there are any.
    pub inserts: Option<&'a MeshGeometry>,
}

impl Geometry for UnionGeometry<'_> {
    fn intersect(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        self.base.intersect(rays, hits);
        let Some(inserts) = self.inserts else {
            return;
        };
        // The inserts only need to beat the base's hit: shorten each ray to it.
        let clipped: Vec<Ray> = rays
            .iter()
            .zip(hits.iter())
            .map(|(r, h)| Ray {
                t_max: h.map_or(r.t_max, |h| h.t),
                ..*r
            })
            .collect();
        let mut near = vec![None; rays.len()];
        inserts.intersect(&clipped, &mut near);
        for (h, n) in hits.iter_mut().zip(near) {
            if let Some(n) = n {
                if h.is_none_or(|h| n.t < h.t) {
                    *h = Some(n);
                }
            }
        }
    }

    fn occluded(&self, rays: &[Ray], occluded: &mut [bool]) {
        match self.inserts {
            None => self.base.occluded(rays, occluded),
            Some(inserts) => {
                // The cheap triangle test first; the base only for the rays it leaves open.
                inserts.occluded(rays, occluded);
                let open: Vec<usize> = (0..rays.len()).filter(|&i| !occluded[i]).collect();
                let open_rays: Vec<Ray> = open.iter().map(|&i| rays[i]).collect();
                let mut base = vec![false; open.len()];
                self.base.occluded(&open_rays, &mut base);
                for (&i, b) in open.iter().zip(base) {
                    occluded[i] = b;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use i2sdf_data::TriangleMesh;

    fn sphere(c: Vec3, r: f32) -> TriangleMesh {
        let mut m = TriangleMesh::unit_icosphere(3);
        m.positions
            .iter_mut()
            .for_each(|p| *p = (c + r * Vec3::from(*p)).to_array());
        m
    }

    /// The nearer of the two answers wins, with its own label; shadow rays see both.
    #[test]
    fn the_nearer_surface_answers() {
        let far = MeshGeometry::new(&sphere(Vec3::new(0.0, 0.0, 5.0), 1.0), vec![1; 1280]);
        let near = MeshGeometry::new(&sphere(Vec3::new(0.0, 0.0, 2.0), 0.5), vec![7; 1280]);
        let side = MeshGeometry::new(&sphere(Vec3::new(3.0, 0.0, 5.0), 0.5), vec![7; 1280]);
        let rays = [
            Ray::new(Vec3::ZERO, Vec3::Z, 0.0, f32::INFINITY),
            Ray::new(Vec3::new(0.0, 0.0, 10.0), -Vec3::Z, 0.0, f32::INFINITY),
            Ray::new(Vec3::new(3.0, 0.0, 0.0), Vec3::Z, 0.0, f32::INFINITY),
            Ray::new(Vec3::new(9.0, 0.0, 0.0), Vec3::Z, 0.0, f32::INFINITY),
        ];
        let union = UnionGeometry {
            base: &far,
            inserts: Some(&near),
        };
        let mut hits = [None; 4];
        union.intersect(&rays, &mut hits);
        assert_eq!(hits[0].unwrap().surface, 7);
        assert!((hits[0].unwrap().t - 1.5).abs() < 0.02);
        assert_eq!(hits[1].unwrap().surface, 1);
        assert!((hits[1].unwrap().t - 4.0).abs() < 0.02);
        assert!(hits[2].is_none() && hits[3].is_none());
        let union = UnionGeometry {
            base: &far,
            inserts: Some(&side),
        };
        let mut occ = [false; 4];
        union.occluded(&rays, &mut occ);
        assert_eq!(occ, [true, true, true, false]);
    }
}
