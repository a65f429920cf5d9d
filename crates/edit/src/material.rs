//! The edited scene's materials: the recovered material (the neural fields, or any [`Material`])
//! at the base surface with the spec's region overrides applied in order, and each inserted
//! object's own constant GGX material. One batched query of the base for all its points of a
//! bounce, as the integrator asks.

use glam::Vec3;
use i2sdf_render::{GgxBrdf, Material, SurfacePoint};

/// Where an override applies (world position → inside).
pub type RegionTest = Box<dyn Fn(Vec3) -> bool + Send + Sync>;
/// Kd of a projected texture at a world position (linear RGB).
pub type KdLookup = Box<dyn Fn(Vec3) -> Vec3 + Send + Sync>;

/// One `kind = "material"` op, resolved: inside `region`, each given parameter replaces the
/// recovered one (`None` keeps it); a texture, where given, sets Kd.
pub struct MaterialEdit {
    pub region: RegionTest,
    pub kd: Option<Vec3>,
    pub ks: Option<Vec3>,
    pub roughness: Option<f32>,
    pub texture: Option<KdLookup>,
}

impl MaterialEdit {
    fn apply(&self, p: Vec3, brdf: &mut GgxBrdf) {
        if !(self.region)(p) {
            return;
        }
        if let Some(kd) = self.kd {
            brdf.kd = kd;
        }
        if let Some(t) = &self.texture {
            brdf.kd = t(p);
        }
        if let Some(ks) = self.ks {
            brdf.ks = ks;
        }
        if let Some(r) = self.roughness {
            brdf.rho = r;
        }
    }
}

pub struct EditedMaterial<'a> {
    pub base: &'a dyn Material,
    /// Labels from here on are inserted objects (label − first_insert_label indexes `inserts`).
    pub first_insert_label: u32,
    /// Applied in spec order at base surfaces, so a later op wins where regions overlap.
    pub edits: &'a [MaterialEdit],
    pub inserts: &'a [GgxBrdf],
}

impl Material for EditedMaterial<'_> {
    fn eval_batch(&self, points: &[SurfacePoint], out: &mut [GgxBrdf]) {
        assert_eq!(points.len(), out.len());
        let base: Vec<usize> = (0..points.len())
            .filter(|&i| points[i].surface < self.first_insert_label)
            .collect();
        if !base.is_empty() {
            let pts: Vec<SurfacePoint> = base.iter().map(|&i| points[i]).collect();
            let mut brdfs = vec![GgxBrdf::new(Vec3::ZERO, Vec3::ZERO, 1.0); pts.len()];
            self.base.eval_batch(&pts, &mut brdfs);
            for ((&i, p), mut b) in base.iter().zip(&pts).zip(brdfs) {
                for e in self.edits {
                    e.apply(p.position, &mut b);
                }
                out[i] = b;
            }
        }
        for (p, o) in points.iter().zip(out.iter_mut()) {
            if p.surface >= self.first_insert_label {
                *o = self.inserts[(p.surface - self.first_insert_label) as usize];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use i2sdf_render::ConstantMaterial;

    #[test]
    fn overrides_apply_in_order_inside_their_regions_and_inserts_keep_theirs() {
        let recovered = GgxBrdf::new(Vec3::splat(0.5), Vec3::splat(0.04), 0.6);
        let base = ConstantMaterial::new(vec![recovered; 3]);
        let edits = [
            MaterialEdit {
                region: Box::new(|p: Vec3| p.x > 0.0),
                kd: Some(Vec3::ZERO),
                ks: Some(Vec3::ONE),
                roughness: Some(0.02),
                texture: None,
            },
            MaterialEdit {
                region: Box::new(|p: Vec3| p.y > 0.0),
                kd: None,
                ks: None,
                roughness: Some(0.3),
                texture: Some(Box::new(|p: Vec3| Vec3::splat(p.z))),
            },
        ];
        let glass = GgxBrdf::new(Vec3::splat(0.1), Vec3::splat(0.9), 0.1);
        let m = EditedMaterial {
            base: &base,
            first_insert_label: 3,
            edits: &edits,
            inserts: &[glass],
        };
        let p = |x: f32, y: f32, z: f32, surface| SurfacePoint {
            position: Vec3::new(x, y, z),
            normal: Vec3::Y,
            surface,
            prim: 0,
        };
        let pts = [
            p(-1.0, -1.0, 0.0, 0),
            p(1.0, -1.0, 0.0, 0),
            p(1.0, 1.0, 0.25, 0),
            p(-1.0, 1.0, 0.75, 2),
            p(1.0, 1.0, 0.0, 3),
        ];
        let mut out = [recovered; 5];
        m.eval_batch(&pts, &mut out);
        assert_eq!(out[0], recovered);
        assert_eq!(out[1], GgxBrdf::new(Vec3::ZERO, Vec3::ONE, 0.02));
        assert_eq!(out[2], GgxBrdf::new(Vec3::splat(0.25), Vec3::ONE, 0.3));
        assert_eq!(out[3], GgxBrdf::new(Vec3::splat(0.75), Vec3::splat(0.04), 0.3));
        assert_eq!(out[4], glass);
    }
}
