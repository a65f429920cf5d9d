//! Materials constant per surface label: one [`GgxBrdf`] per shape (a synthetic room's table).

use crate::brdf::GgxBrdf;
use crate::material::{Material, SurfacePoint};

#[derive(Clone, Debug)]
pub struct ConstantMaterial {
    pub per_surface: Vec<GgxBrdf>,
}

impl ConstantMaterial {
    pub fn new(per_surface: Vec<GgxBrdf>) -> Self {
        ConstantMaterial { per_surface }
    }
}

impl Material for ConstantMaterial {
    fn eval_batch(&self, points: &[SurfacePoint], out: &mut [GgxBrdf]) {
        assert_eq!(points.len(), out.len());
        for (p, o) in points.iter().zip(out) {
            *o = self.per_surface[p.surface as usize];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn looks_up_the_surface_label() {
        let a = GgxBrdf::new(Vec3::splat(0.2), Vec3::ZERO, 0.7);
        let b = GgxBrdf::new(Vec3::splat(0.9), Vec3::splat(0.1), 0.3);
        let m = ConstantMaterial::new(vec![a, b]);
        let p = |surface| SurfacePoint {
            position: Vec3::ZERO,
            normal: Vec3::Y,
            surface,
            prim: 0,
        };
        let mut out = [a; 3];
        m.eval_batch(&[p(1), p(0), p(1)], &mut out);
        assert_eq!(out, [b, a, b]);
    }
}
