//! [`Geometry`] of a triangle mesh: the [`Bvh`] plus, per triangle, its outward unit normal and
//! the surface label that materials and lights key on (a synthetic room's shape index).

use crate::bvh::{prefetch, Bvh, BvhHit};
use crate::geometry::{Geometry, Hit, Ray};
use glam::Vec3;
use i2sdf_data::TriangleMesh;

pub struct MeshGeometry {
    bvh: Bvh,
    /// What a hit on each triangle reads, one cache line per triangle.
    shading: Vec<TriShading>,
    /// Whether hits carry the blend of `TriShading::vertex` (else the facet's normal).
    smooth: bool,
}

/// A triangle's unit geometric normal (its winding: outward), its surface label, and its
/// vertices' shading normals when the mesh samples a smooth surface. Why together: a hit read
/// the facet normal, the label, the triangle's vertex indices and then the three vertex
/// normals from four arrays, each a cache miss on a large mesh (7 % of the relit sets' path
/// tracing in `eval`); here it is one line, prefetched ahead ([`MeshGeometry::intersect`]).
#[derive(Clone, Copy)]
#[repr(C, align(64))]
struct TriShading {
    facet: Vec3,
    surface: u32,
    vertex: [Vec3; 3],
}

/// Hits whose shading is prefetched ahead of the one read.
const SHADING_AHEAD: usize = 8;

impl MeshGeometry {
    /// `surface_of[t]`: the label of triangle `t` (one per face).
    pub fn new(mesh: &TriangleMesh, surface_of: Vec<u32>) -> Self {
        assert_eq!(surface_of.len(), mesh.faces.len(), "one surface label per triangle");
        let shading = (0..mesh.faces.len())
            .map(|t| {
                let facet = (mesh.vertex(t, 1) - mesh.vertex(t, 0))
                    .cross(mesh.vertex(t, 2) - mesh.vertex(t, 0))
                    .normalize_or_zero();
                TriShading {
                    facet,
                    surface: surface_of[t],
                    vertex: [facet; 3],
                }
            })
            .collect();
        MeshGeometry {
            bvh: Bvh::build(mesh),
            shading,
            smooth: false,
        }
    }

    /// As [`MeshGeometry::new`], with shading normals interpolated from `vertex_normals` (one
    /// unit outward normal per vertex). A blend that comes out zero or facing against the
    /// facet falls back to the facet's normal.
    pub fn with_vertex_normals(mesh: &TriangleMesh, surface_of: Vec<u32>, vertex_normals: Vec<Vec3>) -> Self {
        assert_eq!(vertex_normals.len(), mesh.positions.len(), "one normal per vertex");
        let mut g = MeshGeometry::new(mesh, surface_of);
        for (s, f) in g.shading.iter_mut().zip(&mesh.faces) {
            s.vertex = f.map(|i| vertex_normals[i as usize]);
        }
        g.smooth = true;
        g
    }

    pub fn bvh(&self) -> &Bvh {
        &self.bvh
    }

    /// Outward unit normal of triangle `t`.
    pub fn normal(&self, t: u32) -> Vec3 {
        self.shading[t as usize].facet
    }

    /// The hit of a ray on the BVH's triangle, with its shading normal.
    fn hit_of(&self, h: BvhHit) -> Hit {
        let s = &self.shading[h.triangle as usize];
        let normal = if self.smooth {
            let [a, b, c] = s.vertex;
            let n = (a * (1.0 - h.u - h.v) + b * h.u + c * h.v).normalize_or_zero();
            if n.dot(s.facet) > 0.0 {
                n
            } else {
                s.facet
            }
        } else {
            s.facet
        };
        Hit {
            t: h.t,
            normal,
            surface: s.surface,
            prim: h.triangle,
        }
    }
}

impl Geometry for MeshGeometry {
    fn intersect(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        assert_eq!(rays.len(), hits.len());
        let ray = |i: usize| {
            let r = &rays[i];
            Some((r.origin, r.dir, r.t_min, r.t_max))
        };
        hits.fill(None);
        if !self.bvh.interleaves() {
            // A mesh that fits the caches: its shading lines are there too.
            self.bvh
                .intersect_each(rays.len(), ray, |i, h| hits[i] = Some(self.hit_of(h)));
            return;
        }
        // The BVH's hits first, then their shading, each line asked for a few hits ahead.
        let mut found = Vec::with_capacity(rays.len());
        self.bvh.intersect_each(rays.len(), ray, |i, h| found.push((i, h)));
        for (k, &(i, h)) in found.iter().enumerate() {
            if let Some(&(_, ahead)) = found.get(k + SHADING_AHEAD) {
                prefetch(self.shading.as_ptr().wrapping_add(ahead.triangle as usize));
            }
            hits[i] = Some(self.hit_of(h));
        }
    }

    fn occluded(&self, rays: &[Ray], occluded: &mut [bool]) {
        assert_eq!(rays.len(), occluded.len());
        occluded.fill(false);
        let ray = |i: usize| {
            let r = &rays[i];
            Some((r.origin, r.dir, r.t_min, r.t_max))
        };
        self.bvh.occluded_each(rays.len(), ray, |i| occluded[i] = true);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::tests::random_ray;
    use crate::geometry::intersect_one;
    use rand::{Rng, SeedableRng};

    /// A batch answers exactly what the same rays answer one at a time (labels and normals
    /// included), for closest hits and shadow queries with finite segments.
    #[test]
    fn batched_queries_agree_with_one_ray_at_a_time() {
        let mut rng = rand_pcg::Pcg32::seed_from_u64(1);
        let mut parts = Vec::new();
        let mut labels = Vec::new();
        for s in 0..30u32 {
            let c = Vec3::new(
                rng.gen_range(-2.0..2.0),
                rng.gen_range(-2.0..2.0),
                rng.gen_range(-2.0..2.0),
            );
            let mut m = TriangleMesh::unit_icosphere(2);
            m.positions
                .iter_mut()
                .for_each(|p| *p = (c + 0.4 * Vec3::from(*p)).to_array());
            labels.extend(std::iter::repeat_n(s, m.faces.len()));
            parts.push(m);
        }
        let mesh = TriangleMesh::concat(&parts);
        let geo = MeshGeometry::new(&mesh, labels.clone());
        let rays: Vec<Ray> = (0..3000)
            .map(|_| {
                let (o, d) = random_ray(&mut rng, 3.0);
                Ray::new(o, d, rng.gen_range(0.0..0.1), rng.gen_range(0.5..8.0))
            })
            .collect();
        let mut hits = vec![None; rays.len()];
        let mut occ = vec![false; rays.len()];
        geo.intersect(&rays, &mut hits);
        geo.occluded(&rays, &mut occ);
        let mut n_hit = 0;
        for (i, r) in rays.iter().enumerate() {
            let one = intersect_one(&geo, *r);
            assert_eq!(hits[i], one, "ray {i}");
            let mut o = [false];
            geo.occluded(std::slice::from_ref(r), &mut o);
            assert_eq!(occ[i], o[0]);
            assert_eq!(occ[i], one.is_some(), "occlusion and closest hit disagree for ray {i}");
            if let Some(h) = one {
                n_hit += 1;
                assert_eq!(h.surface, labels[h.prim as usize]);
                assert!((h.normal.length() - 1.0).abs() < 1e-5);
                assert!(h.t > r.t_min && h.t < r.t_max);
            }
        }
        assert!(
            n_hit > 300 && n_hit < 2700,
            "{n_hit} hits: the test needs both outcomes"
        );
    }

    /// With the sphere's own normals at the vertices, hits carry the blend: far nearer the true
    /// normal than the facets are.
    #[test]
    fn vertex_normals_are_interpolated() {
        let mesh = TriangleMesh::unit_icosphere(2);
        let vn: Vec<Vec3> = mesh.positions.iter().map(|p| Vec3::from(*p).normalize()).collect();
        let flat = MeshGeometry::new(&mesh, vec![0; mesh.faces.len()]);
        let smooth = MeshGeometry::with_vertex_normals(&mesh, vec![0; mesh.faces.len()], vn);
        let mut rng = rand_pcg::Pcg32::seed_from_u64(3);
        let (mut err_flat, mut err_smooth) = (0.0f32, 0.0f32);
        for _ in 0..200 {
            let o = Vec3::new(rng.gen_range(-3.0..3.0), rng.gen_range(-3.0..3.0), 4.0);
            let r = Ray::new(o, (-o).normalize(), 0.0, f32::INFINITY);
            let (a, b) = (intersect_one(&flat, r).unwrap(), intersect_one(&smooth, r).unwrap());
            assert_eq!((a.t, a.prim), (b.t, b.prim));
            let truth = r.at(a.t).normalize();
            err_flat = err_flat.max(a.normal.angle_between(truth));
            err_smooth = err_smooth.max(b.normal.angle_between(truth));
        }
        assert!(err_smooth < 0.3 * err_flat, "smooth {err_smooth} vs flat {err_flat}");
    }
}
