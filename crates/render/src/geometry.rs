//! The geometry interface of the Monte Carlo integrator: batched closest-hit and occlusion
//! queries. The integrator never sees triangles: a triangle-mesh BVH ([`crate::MeshGeometry`]), an
//! SDF sphere tracer (stage 2 traces its secondary rays in the frozen SDF, paper eq:render and
//! eq:radiance) or a union of both (edited scenes: the SDF surface ∪ inserted meshes) answer the same two calls.
//! Queries come in batches (a tile of paths at one bounce), so an implementation can vectorise
//! them: an SDF tracer evaluates its network on all rays of the batch at once.

use glam::Vec3;

/// A ray segment: the points `origin + t · dir` with `t_min < t < t_max`; `dir` is unit length
/// (hit distances are distances).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: Vec3,
    pub dir: Vec3,
    pub t_min: f32,
    pub t_max: f32,
}

impl Ray {
    pub fn new(origin: Vec3, dir: Vec3, t_min: f32, t_max: f32) -> Self {
        Ray {
            origin,
            dir,
            t_min,
            t_max,
        }
    }

    #[inline]
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + t * self.dir
    }
}

/// The closest surface point along a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) ray direction.
    pub t: f32,
    /// Unit geometric normal, oriented outward (a mesh's winding, an SDF's gradient) and *not*
    /// flipped towards the ray: one-sided emitters need to know which side was hit.
    pub normal: Vec3,
    /// The geometry's label of the surface: the shape of a synthetic room, the emitter cluster of
    /// an SDF hit. Materials and the light set key on it (see [`crate::LightSet`]).
    pub surface: u32,
    /// Primitive within the surface (triangle index), for implementations that need it.
    pub prim: u32,
}

/// Batched ray queries. `hits[i]` / `occluded[i]` answer `rays[i]`; slices have equal length.
pub trait Geometry: Sync {
    /// Closest hit within each ray's (t_min, t_max), `None` where the ray escapes.
    fn intersect(&self, rays: &[Ray], hits: &mut [Option<Hit>]);
    /// Whether anything lies within each ray's (t_min, t_max) (shadow rays; any hit will do).
    fn occluded(&self, rays: &[Ray], occluded: &mut [bool]);
}

/// One ray through a batched [`Geometry`] (set-up code, tests; the integrator batches).
pub fn intersect_one(geometry: &dyn Geometry, ray: Ray) -> Option<Hit> {
    let mut hit = [None];
    geometry.intersect(&[ray], &mut hit);
    hit[0]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The plane y = 0 facing +y, as the smallest possible implementation.
    struct Floor;
    impl Geometry for Floor {
        fn intersect(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
            for (r, h) in rays.iter().zip(hits) {
                let t = -r.origin.y / r.dir.y;
                *h = (t > r.t_min && t < r.t_max).then_some(Hit {
                    t,
                    normal: Vec3::Y,
                    surface: 0,
                    prim: 0,
                });
            }
        }
        fn occluded(&self, rays: &[Ray], occluded: &mut [bool]) {
            let mut hits = vec![None; rays.len()];
            self.intersect(rays, &mut hits);
            for (o, h) in occluded.iter_mut().zip(hits) {
                *o = h.is_some();
            }
        }
    }

    #[test]
    fn intersect_one_respects_the_segment() {
        let down = Ray::new(Vec3::new(0.0, 2.0, 0.0), -Vec3::Y, 0.0, f32::INFINITY);
        let h = intersect_one(&Floor, down).unwrap();
        assert_eq!((h.t, down.at(h.t)), (2.0, Vec3::ZERO));
        assert!(intersect_one(&Floor, Ray { t_max: 1.5, ..down }).is_none());
        assert!(intersect_one(&Floor, Ray { dir: Vec3::Y, ..down }).is_none());
    }
}
