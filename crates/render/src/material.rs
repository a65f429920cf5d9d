//! The material interface of the Monte Carlo integrator: the supplementary's GGX parameters
//! (Kd, Ks, ρ; `crate::brdf`) at a batch of surface points. Batched because stage 2's materials
//! are neural fields (F_a for Kd/Ks, F_ρ for roughness) whose evaluation pays off only over a
//! tile of points; a table lookup ([`crate::ConstantMaterial`]) answers the same call.

use crate::brdf::GgxBrdf;
use glam::Vec3;

/// Where a material is evaluated: a ray's hit, as the geometry labelled it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfacePoint {
    pub position: Vec3,
    /// Unit shading normal, facing the incoming ray.
    pub normal: Vec3,
    /// The geometry's surface label ([`crate::Hit::surface`]).
    pub surface: u32,
    /// The primitive within the surface ([`crate::Hit::prim`]).
    pub prim: u32,
}

pub trait Material: Sync {
    /// `out[i]` = the BRDF at `points[i]`; slices have equal length.
    fn eval_batch(&self, points: &[SurfacePoint], out: &mut [GgxBrdf]);
}

/// A spatially varying diffuse albedo: Kd at a world point given the surface's base Kd.
pub trait KdTexture: Send + Sync {
    fn kd_at(&self, base_kd: Vec3, p: Vec3) -> Vec3;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The contract in its smallest form: albedo from the height (what a field would compute).
    struct ByHeight;
    impl Material for ByHeight {
        fn eval_batch(&self, points: &[SurfacePoint], out: &mut [GgxBrdf]) {
            for (p, o) in points.iter().zip(out) {
                *o = GgxBrdf::new(Vec3::splat(p.position.y.clamp(0.0, 1.0)), Vec3::ZERO, 1.0);
            }
        }
    }

    #[test]
    fn batches_answer_point_by_point() {
        let pts: Vec<SurfacePoint> = (0..5)
            .map(|i| SurfacePoint {
                position: Vec3::new(0.0, i as f32 * 0.25, 0.0),
                normal: Vec3::Y,
                surface: 0,
                prim: 0,
            })
            .collect();
        let mut out = vec![GgxBrdf::new(Vec3::ZERO, Vec3::ZERO, 1.0); 5];
        ByHeight.eval_batch(&pts, &mut out);
        for (i, b) in out.iter().enumerate() {
            let mut one = [*b];
            ByHeight.eval_batch(&pts[i..i + 1], &mut one);
            assert_eq!(one[0], *b);
        }
        assert_eq!(out[4].kd, Vec3::ONE);
    }
}
