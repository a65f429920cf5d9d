//! Colour helpers. RGB values are linear and stored in `glam::Vec3` (x = r, y = g, z = b).

use glam::Vec3;

/// Luminance with the supplementary's weights, `lum(C) = 0.213 r + 0.715 g + 0.072 b`
/// (supp. "BRDF Model"); it mixes the diffuse and specular lobes and sets F90.
#[inline]
pub fn luminance(c: Vec3) -> f32 {
    0.213 * c.x + 0.715 * c.y + 0.072 * c.z
}

/// Largest channel, used for Russian roulette survival probabilities.
#[inline]
pub fn max_channel(c: Vec3) -> f32 {
    c.x.max(c.y).max(c.z)
}

/// True when every channel is finite.
#[inline]
pub fn is_finite_rgb(c: Vec3) -> bool {
    c.x.is_finite() && c.y.is_finite() && c.z.is_finite()
}
