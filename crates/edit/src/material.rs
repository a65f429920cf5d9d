//! The edited scene's materials: the recovered material (the neural fields, or any [`Material`])
//! at the base surface with the spec's region overrides applied in order, and each inserted
//! object's own constant GGX material. One batched query of the base for all its points of a
//! bounce, as the integrator asks.

use glam::Vec3;
use i2sdf_data::edit_spec::{MaterialOverride, MaterialValues, Region};
use i2sdf_data::ImageF32;
use i2sdf_render::{GgxBrdf, Material, SurfacePoint};

/// One `kind = "material"` op with its decoded texture (where it projects one).
pub struct MaterialEdit {
    pub region: Region,
    pub material: MaterialOverride,
    pub texture: Option<ImageF32>,
}

/// A [`GgxBrdf`] as the spec's material values, and back.
pub fn values_of(b: &GgxBrdf) -> MaterialValues {
    MaterialValues {
        kd: b.kd.to_array(),
        ks: b.ks.to_array(),
        roughness: b.rho,
    }
}

pub fn brdf_of(v: &MaterialValues) -> GgxBrdf {
    GgxBrdf::new(Vec3::from(v.kd), Vec3::from(v.ks), v.roughness)
}

impl MaterialEdit {
    fn apply(&self, p: Vec3, brdf: &mut GgxBrdf) {
        if self.region.contains(p) {
            *brdf = brdf_of(&self.material.apply(values_of(brdf), p, self.texture.as_ref()));
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
    use i2sdf_data::edit_spec::{PartialMaterial, Preset, Texture};
    use i2sdf_render::ConstantMaterial;

    #[test]
    fn overrides_apply_in_order_inside_their_regions_and_inserts_keep_theirs() {
        let recovered = GgxBrdf::new(Vec3::splat(0.5), Vec3::splat(0.04), 0.6);
        let base = ConstantMaterial::new(vec![recovered; 3]);
        // A 2×1 texture, left texel black, right texel white, projected along x over [0, 2].
        let image = ImageF32::from_data(2, 1, 3, vec![0.0, 0.0, 0.0, 1.0, 1.0, 1.0]);
        let edits = [
            MaterialEdit {
                region: Region::Above {
                    point: [0.0; 3],
                    normal: [1.0, 0.0, 0.0],
                },
                material: MaterialOverride::Preset(Preset::Mirror),
                texture: None,
            },
            MaterialEdit {
                region: Region::Above {
                    point: [0.0; 3],
                    normal: [0.0, 1.0, 0.0],
                },
                material: MaterialOverride::Texture {
                    texture: Texture {
                        image: "unused.png".into(),
                        origin: [-1.0, 0.0, 0.0],
                        u: [2.0, 0.0, 0.0],
                        v: [0.0, 0.0, 1.0],
                    },
                    ks: None,
                    roughness: Some(0.3),
                },
                texture: Some(image),
            },
            MaterialEdit {
                region: Region::Sphere {
                    centre: [5.0, 5.0, 5.0],
                    radius: 0.5,
                },
                material: MaterialOverride::Values(PartialMaterial {
                    kd: Some([0.1, 0.2, 0.3]),
                    ..Default::default()
                }),
                texture: None,
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
            p(-0.5, 1.0, 0.25, 0),
            p(0.5, 1.0, 0.75, 2),
            p(1.0, 1.0, 0.0, 3),
            p(5.0, 5.2, 5.0, 1),
        ];
        let mut out = [recovered; 6];
        m.eval_batch(&pts, &mut out);
        let mirror = brdf_of(&Preset::Mirror.values());
        assert_eq!(out[0], recovered);
        assert_eq!(out[1], mirror);
        // Texel centres: s = 0.25 is the black texel's, s = 0.75 the white one's.
        assert_eq!(out[2], GgxBrdf::new(Vec3::ZERO, recovered.ks, 0.3));
        assert_eq!(out[3], GgxBrdf::new(Vec3::ONE, mirror.ks, 0.3));
        assert_eq!(out[4], glass);
        assert_eq!(out[5], GgxBrdf::new(Vec3::new(0.1, 0.2, 0.3), mirror.ks, 0.3));
    }
}
