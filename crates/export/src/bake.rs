//! Baking the material fields into textures over a [`UvAtlas`]: every texel whose centre lies in
//! a charted face gets the surface point there (barycentric position and normal), the fields are
//! evaluated at those points, the result is written into glTF's textures, and each chart is grown
//! by a few texels (dilation) so that filtering and mipmaps at its border read its own colours,
//! not the empty page's.
//!
//! The textures, in glTF's channels ([`crate::material_map`] for the mapping):
//! - `baseColorTexture`: Kd, sRGB-encoded RGB;
//! - one RGBA texture, linear, serving as `metallicRoughnessTexture` (G = ρ, B = metallic = 0,
//!   R = 1: no occlusion) and as `KHR_materials_specular`'s `specularTexture` (A = F90);
//! - `specularColorTexture`: `specularColor / S`, sRGB-encoded RGB, with `specularColorFactor`
//!   = S, the largest specularColor channel on the surface (specularColor = Ks / (0.04·F90)
//!   exceeds 1 wherever lum(Ks) > 0.04).

use crate::atlas::UvAtlas;
use crate::material_map::{GltfPbr, GLTF_DIELECTRIC_F0};
use glam::Vec3;
use i2sdf_data::imageio::{linear_to_srgb, srgb_to_linear};
use i2sdf_render::GgxBrdf;

/// The texels of an atlas page that lie in charted faces, and where each is on the surface.
#[derive(Clone, Debug, PartialEq)]
pub struct TexelSamples {
    pub width: usize,
    pub height: usize,
    /// Per sample: its texel (row-major).
    pub texel: Vec<u32>,
    /// Per sample: its face and barycentric coordinates there.
    pub face: Vec<u32>,
    pub bary: Vec<[f32; 3]>,
}

/// The texel centres inside each face not flagged in `ignore` (the first face claims a texel on
/// a shared edge).
pub fn rasterize(atlas: &UvAtlas, ignore: &[bool]) -> TexelSamples {
    let (w, h) = (atlas.width as usize, atlas.height as usize);
    let mut claimed = vec![false; w * h];
    let mut out = TexelSamples {
        width: w,
        height: h,
        texel: Vec::new(),
        face: Vec::new(),
        bary: Vec::new(),
    };
    for (fi, f) in atlas.faces.iter().enumerate() {
        if ignore[fi] {
            continue;
        }
        let q = f.map(|v| {
            let [u, t] = atlas.uv[v as usize];
            [u * w as f32, t * h as f32]
        });
        let area = (q[1][0] - q[0][0]) * (q[2][1] - q[0][1]) - (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]);
        if area.abs() < 1e-12 {
            continue;
        }
        let x0 = q.iter().map(|p| p[0]).fold(f32::INFINITY, f32::min).floor().max(0.0) as usize;
        let x1 = (q.iter().map(|p| p[0]).fold(f32::NEG_INFINITY, f32::max).ceil() as usize).min(w);
        let y0 = q.iter().map(|p| p[1]).fold(f32::INFINITY, f32::min).floor().max(0.0) as usize;
        let y1 = (q.iter().map(|p| p[1]).fold(f32::NEG_INFINITY, f32::max).ceil() as usize).min(h);
        // edge functions, normalized so that the three sum to 1 (barycentrics)
        let edge = |a: [f32; 2], b: [f32; 2], c: [f32; 2]| {
            ((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])) / area
        };
        let tol = -1e-5;
        for y in y0..y1 {
            for x in x0..x1 {
                let c = [x as f32 + 0.5, y as f32 + 0.5];
                let b0 = edge(q[1], q[2], c);
                let b1 = edge(q[2], q[0], c);
                let b2 = 1.0 - b0 - b1;
                if b0 < tol || b1 < tol || b2 < tol || claimed[y * w + x] {
                    continue;
                }
                claimed[y * w + x] = true;
                out.texel.push((y * w + x) as u32);
                out.face.push(fi as u32);
                out.bary.push([b0.max(0.0), b1.max(0.0), b2.max(0.0)]);
            }
        }
    }
    out
}

/// Grows the covered texels of `img` (`channels` per texel) by `rings` texels: each uncovered
/// texel with covered neighbours (8-connected) takes their mean.
pub fn dilate(img: &mut [f32], channels: usize, covered: &mut [bool], width: usize, height: usize, rings: usize) {
    for _ in 0..rings {
        let mut grown = Vec::new();
        for y in 0..height {
            for x in 0..width {
                if covered[y * width + x] {
                    continue;
                }
                let mut sum = [0.0f32; 4];
                let mut n = 0;
                for dy in -1i32..=1 {
                    for dx in -1i32..=1 {
                        let (xx, yy) = (x as i32 + dx, y as i32 + dy);
                        if xx < 0 || yy < 0 || xx >= width as i32 || yy >= height as i32 {
                            continue;
                        }
                        let j = yy as usize * width + xx as usize;
                        if covered[j] {
                            for c in 0..channels {
                                sum[c] += img[j * channels + c];
                            }
                            n += 1;
                        }
                    }
                }
                if n > 0 {
                    grown.push((y * width + x, sum.map(|s| s / n as f32)));
                }
            }
        }
        if grown.is_empty() {
            break;
        }
        for (i, v) in grown {
            img[i * channels..(i + 1) * channels].copy_from_slice(&v[..channels]);
            covered[i] = true;
        }
    }
}

/// An 8-bit texture as a viewer samples it.
#[derive(Clone, Debug, PartialEq)]
pub struct Texture8 {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: Vec<u8>,
    /// Whether RGB is sRGB-encoded (alpha is always linear).
    pub srgb: bool,
}

impl Texture8 {
    fn from_f32(img: &[f32], width: usize, height: usize, channels: usize, srgb: bool) -> Texture8 {
        let data = img
            .iter()
            .enumerate()
            .map(|(i, &v)| {
                let v = if srgb && i % channels < 3 {
                    linear_to_srgb(v.clamp(0.0, 1.0))
                } else {
                    v
                };
                (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
            })
            .collect();
        Texture8 {
            width,
            height,
            channels,
            data,
            srgb,
        }
    }

    /// The texel's linear values.
    fn texel(&self, x: usize, y: usize) -> [f32; 4] {
        let mut out = [0.0; 4];
        let i = (y * self.width + x) * self.channels;
        for c in 0..self.channels {
            let v = self.data[i + c] as f32 / 255.0;
            out[c] = if self.srgb && c < 3 { srgb_to_linear(v) } else { v };
        }
        out
    }

    /// Bilinear lookup at glTF texture coordinates (clamped to the edge), texels decoded to
    /// linear before filtering (as GPUs do for sRGB formats).
    pub fn sample(&self, uv: [f32; 2]) -> [f32; 4] {
        let fx = (uv[0] * self.width as f32 - 0.5).clamp(0.0, (self.width - 1) as f32);
        let fy = (uv[1] * self.height as f32 - 0.5).clamp(0.0, (self.height - 1) as f32);
        let (x0, y0) = (fx.floor() as usize, fy.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
        let [a, b, c, d] = [
            self.texel(x0, y0),
            self.texel(x1, y0),
            self.texel(x0, y1),
            self.texel(x1, y1),
        ];
        let mut out = [0.0; 4];
        for k in 0..4 {
            out[k] = (a[k] * (1.0 - tx) + b[k] * tx) * (1.0 - ty) + (c[k] * (1.0 - tx) + d[k] * tx) * ty;
        }
        out
    }

    /// PNG bytes.
    pub fn png(&self) -> Vec<u8> {
        use image::ImageEncoder;
        let mut out = Vec::new();
        let colour = if self.channels == 4 {
            image::ExtendedColorType::Rgba8
        } else {
            image::ExtendedColorType::Rgb8
        };
        image::codecs::png::PngEncoder::new(&mut out)
            .write_image(&self.data, self.width as u32, self.height as u32, colour)
            .expect("an in-memory PNG encodes");
        out
    }
}

/// The material textures of a surface (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialTextures {
    pub base_color: Texture8,
    /// R = 1, G = ρ, B = 0 (metallic), A = F90.
    pub roughness_specular: Texture8,
    pub specular_color: Texture8,
    /// `specularColorFactor` (the same in the three channels).
    pub specular_color_scale: f32,
}

impl MaterialTextures {
    /// `brdf[i]` is the material at `samples`' i-th texel; `rings` texels of dilation.
    pub fn bake(samples: &TexelSamples, brdf: &[GgxBrdf], rings: usize) -> MaterialTextures {
        let (w, h) = (samples.width, samples.height);
        let pbr: Vec<GltfPbr> = brdf.iter().map(GltfPbr::from_ggx).collect();
        let scale = pbr.iter().flat_map(|p| p.specular_color).fold(1.0f32, f32::max);
        let mut kd = vec![0.0f32; w * h * 3];
        let mut rs = vec![0.0f32; w * h * 4];
        let mut sc = vec![0.0f32; w * h * 3];
        let mut covered = vec![false; w * h];
        for (&t, p) in samples.texel.iter().zip(&pbr) {
            let t = t as usize;
            kd[t * 3..t * 3 + 3].copy_from_slice(&p.base_color);
            rs[t * 4..t * 4 + 4].copy_from_slice(&[1.0, p.roughness, p.metallic, p.specular]);
            for c in 0..3 {
                sc[t * 3 + c] = p.specular_color[c] / scale;
            }
            covered[t] = true;
        }
        let grow = |img: &mut Vec<f32>, ch: usize| {
            let mut cov = covered.clone();
            dilate(img, ch, &mut cov, w, h, rings);
        };
        grow(&mut kd, 3);
        grow(&mut rs, 4);
        grow(&mut sc, 3);
        // the empty page: no occlusion, rough, no specular
        for (i, &c) in covered.iter().enumerate() {
            if !c && rs[i * 4] == 0.0 {
                rs[i * 4] = 1.0;
                rs[i * 4 + 1] = 1.0;
            }
        }
        MaterialTextures {
            base_color: Texture8::from_f32(&kd, w, h, 3, true),
            roughness_specular: Texture8::from_f32(&rs, w, h, 4, false),
            specular_color: Texture8::from_f32(&sc, w, h, 3, true),
            specular_color_scale: scale,
        }
    }

    /// The GGX material a glTF viewer reads at `uv`: Kd, F0 (= Ks) and ρ.
    pub fn lookup(&self, uv: [f32; 2]) -> GgxBrdf {
        let kd = self.base_color.sample(uv);
        let rs = self.roughness_specular.sample(uv);
        let sc = self.specular_color.sample(uv);
        let f90 = rs[3];
        let ks =
            Vec3::new(sc[0], sc[1], sc[2]).map(|c| (GLTF_DIELECTRIC_F0 * self.specular_color_scale * c).min(1.0) * f90);
        GgxBrdf::new(Vec3::new(kd[0], kd[1], kd[2]), ks, rs[1])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two triangles covering the whole unit square of uv.
    fn square_atlas(n: u32) -> UvAtlas {
        UvAtlas {
            width: n,
            height: n,
            xref: vec![0, 1, 2, 3],
            uv: vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
            faces: vec![[0, 1, 2], [0, 2, 3]],
            texels_per_unit: n as f32,
            charts: 1,
            utilization: 1.0,
        }
    }

    #[test]
    fn every_texel_of_a_covered_page_is_claimed_once_with_its_barycentrics() {
        let a = square_atlas(16);
        let s = rasterize(&a, &[false, false]);
        assert_eq!(s.texel.len(), 256);
        let mut seen = vec![false; 256];
        for i in 0..s.texel.len() {
            assert!(!seen[s.texel[i] as usize]);
            seen[s.texel[i] as usize] = true;
            // the barycentric point is the texel centre
            let f = a.faces[s.face[i] as usize];
            let b = s.bary[i];
            let (mut u, mut v) = (0.0, 0.0);
            for k in 0..3 {
                u += b[k] * a.uv[f[k] as usize][0];
                v += b[k] * a.uv[f[k] as usize][1];
            }
            let t = s.texel[i] as usize;
            assert!((u * 16.0 - ((t % 16) as f32 + 0.5)).abs() < 1e-4);
            assert!((v * 16.0 - ((t / 16) as f32 + 0.5)).abs() < 1e-4);
        }
        // an ignored face leaves its half empty
        assert!(rasterize(&a, &[true, false]).texel.len() < 256 - 100);
    }

    #[test]
    fn dilation_grows_a_chart_by_its_rings_only() {
        let (w, h) = (9, 9);
        let mut img = vec![0.0f32; w * h];
        let mut cov = vec![false; w * h];
        img[4 * w + 4] = 0.75;
        cov[4 * w + 4] = true;
        dilate(&mut img, 1, &mut cov, w, h, 2);
        for y in 0..h {
            for x in 0..w {
                let inside = (x as i32 - 4).abs() <= 2 && (y as i32 - 4).abs() <= 2;
                assert_eq!(cov[y * w + x], inside);
                assert_eq!(img[y * w + x], if inside { 0.75 } else { 0.0 });
            }
        }
    }

    #[test]
    fn a_baked_material_reads_back_within_8_bit_precision() {
        let a = square_atlas(8);
        let s = rasterize(&a, &[false, false]);
        // Kd a ramp along u, glossy Ks above the 0.04 knee and a dim one below, ρ a ramp along v
        let brdf: Vec<GgxBrdf> = s
            .texel
            .iter()
            .map(|&t| {
                let (x, y) = ((t % 8) as f32 / 7.0, (t / 8) as f32 / 7.0);
                let ks = if x < 0.5 {
                    Vec3::new(0.08, 0.06, 0.05)
                } else {
                    Vec3::splat(0.01)
                };
                GgxBrdf::new(Vec3::new(x, 0.5, 1.0 - x), ks, 0.1 + 0.8 * y)
            })
            .collect();
        let tex = MaterialTextures::bake(&s, &brdf, 2);
        assert!((tex.specular_color_scale - 0.08 / 0.04).abs() < 1e-6);
        for (i, &t) in s.texel.iter().enumerate() {
            let uv = [((t % 8) as f32 + 0.5) / 8.0, ((t / 8) as f32 + 0.5) / 8.0];
            let got = tex.lookup(uv);
            let want = brdf[i];
            assert!(
                (got.kd - want.kd).abs().max_element() < 0.01,
                "{:?} vs {:?}",
                got.kd,
                want.kd
            );
            assert!(
                (got.ks - want.ks).abs().max_element() < 0.002,
                "{:?} vs {:?}",
                got.ks,
                want.ks
            );
            assert!((got.rho - want.rho).abs() < 0.004);
        }
        // the PNGs decode to the same bytes
        for t in [&tex.base_color, &tex.roughness_specular, &tex.specular_color] {
            let img = image::load_from_memory(&t.png()).unwrap();
            let bytes = if t.channels == 4 {
                img.to_rgba8().into_raw()
            } else {
                img.to_rgb8().into_raw()
            };
            assert_eq!(bytes, t.data);
        }
    }
}
