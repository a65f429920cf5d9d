//! The recovered GGX material (Kd, Ks, ρ of the supplementary's BRDF, `i2sdf_render::GgxBrdf`)
//! in glTF's metallic-roughness model with `KHR_materials_specular`, and an emitter's L\[k\] as an
//! emissive material with `KHR_materials_emissive_strength`.
//!
//! Ours: `f = Kd/π + D·V·F`, `F = Ks + (F90 − Ks)(1 − v·h)⁵`, `F90 = min(lum(Ks)/0.04, 1)`,
//! `α = ρ²`. glTF's dielectric (metallic 0) with the specular extension:
//! `f0 = min(0.04·specularColor, 1)·specular`, `f90 = specular`, the same D and height-correlated
//! V with `α = roughness²`. So, exactly for the specular lobe:
//! - `roughness = ρ` (glTF's roughness is perceptual, α = roughness², as ours);
//! - `specular = F90 = min(lum(Ks)/0.04, 1)` and `specularColor = Ks / (0.04·specular)`: then
//!   `f0 = Ks` and `f90 = F90`. Where lum(Ks) ≥ 0.04, specularColor = Ks/0.04 (glTF lets it exceed
//!   1); below, it is Ks's chromaticity at luminance 1;
//! - `metallic = 0`, `baseColor = Kd`.
//!
//! What does not map: glTF weights the diffuse lobe by `1 − F` (energy kept between the
//! layers), ours adds the two lobes. At Ks = 0.04 the diffuse is 4 % darker in glTF at normal
//! incidence, more at grazing angles; Kd is not compensated (a per-angle factor has no place in
//! the material).

use i2sdf_render::GgxBrdf;

/// glTF's dielectric F0 at the default IOR 1.5 ((1.5 − 1)/(1.5 + 1))², the scale of
/// `specularColorFactor`.
pub const GLTF_DIELECTRIC_F0: f32 = 0.04;

/// A GGX material in glTF's terms.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GltfPbr {
    /// Linear RGB in [0, 1].
    pub base_color: [f32; 3],
    pub metallic: f32,
    /// Perceptual roughness in [0, 1] (α = roughness²).
    pub roughness: f32,
    /// `KHR_materials_specular`'s specularFactor in [0, 1] (= F90).
    pub specular: f32,
    /// `KHR_materials_specular`'s specularColorFactor (linear, ≥ 0, may exceed 1).
    pub specular_color: [f32; 3],
}

impl GltfPbr {
    /// The mapping of the module docs; inputs are clamped to their ranges (Kd, Ks in [0, 1],
    /// ρ in [0, 1]).
    pub fn from_ggx(brdf: &GgxBrdf) -> GltfPbr {
        let c01 = |v: f32| if v.is_finite() { v.clamp(0.0, 1.0) } else { 0.0 };
        let kd = brdf.kd.to_array().map(c01);
        let ks = brdf.ks.to_array().map(c01);
        let f90 = i2sdf_render::brdf::fresnel_f90(glam::Vec3::from(ks));
        let specular_color = if f90 > 0.0 {
            ks.map(|k| k / (GLTF_DIELECTRIC_F0 * f90))
        } else {
            [0.0; 3]
        };
        GltfPbr {
            base_color: kd,
            metallic: 0.0,
            roughness: c01(brdf.rho),
            specular: f90,
            specular_color,
        }
    }

    /// glTF's F0 and F90 of this material (the extension's formulas), for the tests and for
    /// checking a file read back.
    pub fn fresnel_f0_f90(&self) -> ([f32; 3], f32) {
        (
            self.specular_color
                .map(|c| (GLTF_DIELECTRIC_F0 * c).min(1.0) * self.specular),
            self.specular,
        )
    }
}

/// An emitter's HDR emission L\[k\] (linear, the input images' units) as glTF's emissiveFactor
/// (in [0, 1], the colour) and `KHR_materials_emissive_strength` (its largest channel): their
/// product is L.
pub fn emissive(l: [f32; 3]) -> ([f32; 3], f32) {
    let l = l.map(|v| if v.is_finite() { v.max(0.0) } else { 0.0 });
    let m = l[0].max(l[1]).max(l[2]);
    if m <= 0.0 {
        ([0.0; 3], 1.0)
    } else {
        (l.map(|v| v / m), m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use i2sdf_render::brdf::{fresnel_f90, schlick_fresnel};

    fn check_fresnel(kd: Vec3, ks: Vec3, rho: f32) {
        let b = GgxBrdf::new(kd, ks, rho);
        let g = GltfPbr::from_ggx(&b);
        let (f0, f90) = g.fresnel_f0_f90();
        for i in 0..3 {
            assert!((f0[i] - ks[i]).abs() < 1e-6, "F0 {f0:?} vs Ks {ks:?}");
        }
        assert!((f90 - fresnel_f90(ks)).abs() < 1e-6, "F90 {f90} vs {}", fresnel_f90(ks));
        // the whole Schlick curve agrees with ours
        for &c in &[1.0f32, 0.7, 0.3, 0.0] {
            let m = (1.0 - c).powi(5);
            let ours = schlick_fresnel(ks, c);
            for i in 0..3 {
                let theirs = f0[i] + (f90 - f0[i]) * m;
                assert!((ours[i] - theirs).abs() < 1e-5, "cos {c}: {ours:?} vs {theirs}");
            }
        }
        assert_eq!(g.base_color, kd.to_array());
        assert_eq!(g.roughness, rho);
        assert_eq!(g.metallic, 0.0);
        assert!((0.0..=1.0).contains(&g.specular));
        assert!(g.specular_color.iter().all(|&c| c >= 0.0 && c.is_finite()));
    }

    #[test]
    fn the_specular_lobe_maps_exactly_at_the_extremes() {
        // glossy dielectric above the 0.04 knee, a dim Ks below it (F90 < 1), no specular at all,
        // a white mirror-like Ks, coloured Ks
        check_fresnel(Vec3::new(0.5, 0.4, 0.3), Vec3::splat(0.08), 0.2);
        check_fresnel(Vec3::new(0.8, 0.8, 0.8), Vec3::splat(0.01), 0.9);
        check_fresnel(Vec3::ZERO, Vec3::ZERO, 1.0);
        check_fresnel(Vec3::ONE, Vec3::ONE, 0.0);
        check_fresnel(Vec3::new(0.1, 0.2, 0.3), Vec3::new(0.02, 0.0, 0.005), 0.5);
        let g = GltfPbr::from_ggx(&GgxBrdf::new(Vec3::ZERO, Vec3::ZERO, 0.5));
        assert_eq!((g.specular, g.specular_color), (0.0, [0.0; 3]));
        let g = GltfPbr::from_ggx(&GgxBrdf::new(Vec3::ZERO, Vec3::ONE, 0.5));
        assert_eq!((g.specular, g.specular_color), (1.0, [25.0; 3]));
    }

    #[test]
    fn out_of_range_inputs_are_clamped() {
        let g = GltfPbr::from_ggx(&GgxBrdf::new(Vec3::new(1.5, -0.1, f32::NAN), Vec3::splat(2.0), 1.3));
        assert_eq!(g.base_color, [1.0, 0.0, 0.0]);
        assert_eq!(g.roughness, 1.0);
        assert_eq!(g.fresnel_f0_f90(), ([1.0; 3], 1.0));
    }

    #[test]
    fn emission_splits_into_colour_and_strength() {
        let (c, s) = emissive([12.0, 6.0, 3.0]);
        assert_eq!((c, s), ([1.0, 0.5, 0.25], 12.0));
        assert_eq!(emissive([0.0; 3]), ([0.0; 3], 1.0));
        assert_eq!(emissive([f32::INFINITY, -1.0, 2.0]).0, [0.0, 0.0, 1.0]);
    }
}
