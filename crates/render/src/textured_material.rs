//! A material whose diffuse albedo is textured on some surfaces: the base material's BRDF with Kd
//! replaced by a [`KdTexture`] where a surface has one. Composition, not a table: the base can be
//! any [`Material`] (the editor overrides regions of neural materials the same way).

use crate::brdf::GgxBrdf;
use crate::material::{KdTexture, Material, SurfacePoint};

pub struct TexturedMaterial<M: Material> {
    pub base: M,
    /// Per surface label; `None` keeps the base's Kd.
    pub textures: Vec<Option<Box<dyn KdTexture>>>,
}

impl<M: Material> Material for TexturedMaterial<M> {
    fn eval_batch(&self, points: &[SurfacePoint], out: &mut [GgxBrdf]) {
        self.base.eval_batch(points, out);
        for (p, o) in points.iter().zip(out) {
            if let Some(Some(tex)) = self.textures.get(p.surface as usize) {
                o.kd = tex.kd_at(o.kd, p.position);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::constant_material::ConstantMaterial;
    use glam::Vec3;

    /// Kd halved where x < 0.
    struct HalfLeft;
    impl KdTexture for HalfLeft {
        fn kd_at(&self, kd: Vec3, p: Vec3) -> Vec3 {
            if p.x < 0.0 {
                0.5 * kd
            } else {
                kd
            }
        }
    }

    #[test]
    fn textures_replace_kd_only_where_given() {
        let a = GgxBrdf::new(Vec3::splat(0.8), Vec3::splat(0.04), 0.4);
        let m = TexturedMaterial {
            base: ConstantMaterial::new(vec![a, a]),
            textures: vec![Some(Box::new(HalfLeft)), None],
        };
        let p = |surface, x| SurfacePoint {
            position: Vec3::new(x, 0.0, 0.0),
            normal: Vec3::Y,
            surface,
            prim: 0,
        };
        let mut out = [a; 4];
        m.eval_batch(&[p(0, -1.0), p(0, 1.0), p(1, -1.0), p(1, 1.0)], &mut out);
        assert_eq!(out[0].kd, Vec3::splat(0.4));
        assert_eq!((out[0].ks, out[0].rho), (a.ks, a.rho));
        assert_eq!([out[1], out[2], out[3]], [a, a, a]);
    }
}
