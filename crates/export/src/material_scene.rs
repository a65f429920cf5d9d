//! The exported scene of a trained run, in world axes: the simplified surface and, for stage 2,
//! its materials — baked into textures over a UV atlas ([`crate::atlas`], [`crate::bake`]) or
//! as vertex colours with the faces' (Ks, ρ) grouped into K GGX materials — the emitters as
//! emissive primitives and, when asked, as punctual lights; for stage 1, the radiance field's
//! colour, unlit. What either material encoding loses is measured here against the fields.

use crate::atlas;
use crate::bake::{rasterize, MaterialTextures};
use crate::cluster;
use crate::material_map::{emissive, GltfPbr};
use crate::scene_model::{LightDesc, MaterialDesc, PrimitiveDesc, SceneModel};
use crate::ExportOptions;
use glam::Vec3;
use i2sdf_data::DataError;
use i2sdf_edit::{RecoveredScene, RecoveredSurface};
use i2sdf_model::{FrozenScene, NeuralMaterial};
use i2sdf_render::simplify;
use i2sdf_render::{GgxBrdf, Material, SurfacePoint};
use rand::{Rng, SeedableRng};

/// Texels between charts and of dilation around each (2 each side keeps bilinear filtering and
/// the first mip levels inside a chart's own colours).
pub const TEXTURE_PADDING: u32 = 2;
/// A spot light's outer cone: a hemisphere, the largest the specification allows (π/2 itself
/// rounds above π/2 in f32, which validators reject).
const HEMISPHERE_CONE: f32 = 1.570_796_2;
/// Surface points the material loss is measured at.
const LOSS_SAMPLES: usize = 100_000;

/// What the exported materials lose against the material fields, at random points of the
/// exported surface (area-weighted), read as a glTF viewer reads them: vertex colours
/// interpolated across a face, or the 8-bit textures filtered bilinearly.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct MaterialLoss {
    /// `vertex colours` or `textures`.
    pub encoding: &'static str,
    /// PSNR (dB) of the exported Kd against the field's (both clamped to [0, 1]).
    pub kd_psnr: f64,
    /// RMS difference of Ks (per channel) and of ρ.
    pub ks_rms: f64,
    pub rho_rms: f64,
}

/// The atlas the textures were baked over.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct TextureSummary {
    pub width: u32,
    pub height: u32,
    pub charts: usize,
    pub texels_per_unit: f32,
    /// Fraction of the page the charts cover.
    pub utilization: f32,
}

/// The surface's faces grouped (ordinary surface, then each emitter), simplified to the budget,
/// and the vertices they keep (world units) with the SDF's normals there (smoothed where the
/// run's shading normals are, [`FrozenScene::smoothed_normals`]).
fn simplified(
    frozen: &FrozenScene,
    surface: &RecoveredSurface,
    opts: &ExportOptions,
) -> (Vec<Vec3>, Vec<Vec3>, Vec<Vec<[u32; 3]>>) {
    let mesh = &surface.mesh;
    let mut in_emitter = vec![false; mesh.faces.len()];
    for f in surface.emitter_faces.iter().flatten() {
        in_emitter[*f as usize] = true;
    }
    let mut groups = vec![mesh
        .faces
        .iter()
        .zip(&in_emitter)
        .filter(|(_, &e)| !e)
        .map(|(f, _)| *f)
        .collect::<Vec<_>>()];
    groups.extend(
        surface
            .emitter_faces
            .iter()
            .map(|fs| fs.iter().map(|&f| mesh.faces[f as usize]).collect()),
    );
    let groups = simplify::simplify_groups(&mesh.positions, &groups, opts.max_faces, opts.max_error);
    let (kept, groups) = simplify::compact(mesh.positions.len(), &groups);
    let vertices: Vec<Vec3> = kept.iter().map(|&v| Vec3::from(mesh.positions[v as usize])).collect();
    // Smoothed as the run's shading normals are (stage 2 fitted the materials with them).
    let normals = frozen.shading_normals(&vertices);
    (vertices, normals, groups)
}

fn triangle_area(p: &[Vec3], f: [u32; 3]) -> f32 {
    let [a, b, c] = f.map(|i| p[i as usize]);
    0.5 * (b - a).cross(c - a).length()
}

/// The point of face `f` at barycentrics `b`, and its interpolated unit normal.
fn at_bary(vertices: &[Vec3], normals: &[Vec3], f: [u32; 3], b: [f32; 3]) -> (Vec3, Vec3) {
    let mut p = Vec3::ZERO;
    let mut n = Vec3::ZERO;
    for k in 0..3 {
        p += b[k] * vertices[f[k] as usize];
        n += b[k] * normals[f[k] as usize];
    }
    (p, n.normalize_or_zero())
}

/// The material fields at `points`.
fn field_at(nm: &NeuralMaterial, points: &[Vec3], normals: &[Vec3]) -> Vec<GgxBrdf> {
    let sp: Vec<SurfacePoint> = points
        .iter()
        .zip(normals)
        .map(|(&position, &normal)| SurfacePoint {
            position,
            normal,
            surface: 0,
            prim: 0,
        })
        .collect();
    let mut out = vec![GgxBrdf::new(Vec3::ZERO, Vec3::ZERO, 1.0); sp.len()];
    nm.eval_batch(&sp, &mut out);
    out
}

/// [`MaterialLoss`] of `exported(face, barycentrics)` against the fields, at [`LOSS_SAMPLES`]
/// area-weighted random points of `faces` (a fixed seed: the same surface gives the same points).
fn material_loss(
    encoding: &'static str,
    nm: &NeuralMaterial,
    vertices: &[Vec3],
    normals: &[Vec3],
    faces: &[[u32; 3]],
    exported: impl Fn(usize, [f32; 3]) -> GgxBrdf,
) -> MaterialLoss {
    let mut cdf = Vec::with_capacity(faces.len());
    let mut total = 0.0f64;
    for f in faces {
        total += triangle_area(vertices, *f) as f64;
        cdf.push(total);
    }
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(0x1e2d);
    let mut picks = Vec::with_capacity(LOSS_SAMPLES);
    if total > 0.0 {
        for _ in 0..LOSS_SAMPLES {
            let x = rng.gen::<f64>() * total;
            let fi = cdf.partition_point(|&c| c < x).min(faces.len() - 1);
            let (r1, r2) = (rng.gen::<f32>().sqrt(), rng.gen::<f32>());
            picks.push((fi, [1.0 - r1, r1 * (1.0 - r2), r1 * r2]));
        }
    }
    let (points, pnormals): (Vec<Vec3>, Vec<Vec3>) = picks
        .iter()
        .map(|&(fi, b)| at_bary(vertices, normals, faces[fi], b))
        .unzip();
    let field = field_at(nm, &points, &pnormals);
    let (mut kd_se, mut ks_se, mut rho_se) = (0.0f64, 0.0f64, 0.0f64);
    for (&(fi, b), want) in picks.iter().zip(&field) {
        let got = exported(fi, b);
        let c01 = |v: Vec3| v.clamp(Vec3::ZERO, Vec3::ONE);
        kd_se += (c01(got.kd) - c01(want.kd)).length_squared() as f64 / 3.0;
        ks_se += (c01(got.ks) - c01(want.ks)).length_squared() as f64 / 3.0;
        rho_se += ((got.rho - want.rho.clamp(0.0, 1.0)) as f64).powi(2);
    }
    let n = picks.len().max(1) as f64;
    MaterialLoss {
        encoding,
        kd_psnr: -10.0 * (kd_se / n).max(1e-12).log10(),
        ks_rms: (ks_se / n).sqrt(),
        rho_rms: (rho_se / n).sqrt(),
    }
}

/// Lumens per watt of glTF lights: `KHR_lights_punctual` gives intensity in candela, while
/// emissive strength is taken as radiance as it is (Blender's importer and exporter both convert
/// lights at 683 lm/W and leave emission alone). A light of the emitter's radiant intensity I (the
/// input images' units × world units²) is written as 683·I candela, so that it lights the room as
/// its emissive surface does.
pub const LUMENS_PER_WATT: f32 = 683.0;

/// One punctual light per emitter primitive, for viewers that light only by lights: a spot
/// light along the faces' mean normal for a flat emitter (|mean normal| ≥ 0.9), a point light
/// at its centroid otherwise. A one-sided Lambertian emitter of radiance L and area A sends
/// out Φ = π·L·A; a point light sending out the same has I = Φ/(4π) = L·A/4; a glTF spot (inner
/// cone 0, outer π/2, the specification's cos² fall-off) has I = 3Φ/(2π) = 3·L·A/2. Both are
/// written in candela ([`LUMENS_PER_WATT`]).
fn emitter_lights(vertices: &[Vec3], normals: &[Vec3], emitters: &[(Vec<[u32; 3]>, Vec3)]) -> Vec<LightDesc> {
    let mut lights = Vec::new();
    for (k, (faces, l)) in emitters.iter().enumerate() {
        let (mut area, mut centroid, mut normal) = (0.0f32, Vec3::ZERO, Vec3::ZERO);
        for f in faces {
            let a = triangle_area(vertices, *f);
            area += a;
            centroid += a * f.iter().map(|&v| vertices[v as usize]).sum::<Vec3>() / 3.0;
            normal += a * f.iter().map(|&v| normals[v as usize]).sum::<Vec3>() / 3.0;
        }
        if area <= 0.0 {
            continue;
        }
        centroid /= area;
        let mean_normal = normal / area;
        let (colour, strength) = emissive(l.to_array());
        let flat = mean_normal.length() >= 0.9;
        lights.push(LightDesc {
            name: format!("emitter_{k}_light"),
            position: centroid.to_array(),
            direction: flat.then(|| mean_normal.normalize().to_array()),
            cone: if flat { HEMISPHERE_CONE } else { 0.0 },
            color: colour,
            intensity: LUMENS_PER_WATT * strength * area * if flat { 1.5 } else { 0.25 },
        });
    }
    lights
}

/// Stage 2's scene (module docs), with what its materials lose and its atlas.
pub fn material_scene(
    rec: &RecoveredScene,
    opts: &ExportOptions,
) -> Result<(SceneModel, MaterialLoss, Option<TextureSummary>), DataError> {
    let (vertices, normals, groups) = simplified(&rec.frozen, &rec.surface, opts);
    let nm = NeuralMaterial::new(rec.material, &rec.frozen);
    let emitters: Vec<(Vec<[u32; 3]>, Vec3)> = groups[1..]
        .iter()
        .enumerate()
        .map(|(k, faces)| (faces.clone(), rec.frozen.emitters.emission(k)))
        .collect();
    let lights = if opts.lights {
        emitter_lights(&vertices, &normals, &emitters)
    } else {
        Vec::new()
    };
    let mut materials = Vec::new();
    let mut primitives = Vec::new();
    let (model_vertices, model_normals, colors, uvs, textures, loss, summary, emitter_faces);
    if opts.texture_size > 0 {
        let surface_faces = groups[0].len();
        let all: Vec<[u32; 3]> = groups.concat();
        let ignore: Vec<bool> = (0..all.len()).map(|i| i >= surface_faces).collect();
        let positions: Vec<[f32; 3]> = vertices.iter().map(|v| v.to_array()).collect();
        let uv_atlas = atlas::unwrap(&positions, &all, &ignore, opts.texture_size, TEXTURE_PADDING)?;
        let v: Vec<Vec3> = uv_atlas.xref.iter().map(|&x| vertices[x as usize]).collect();
        let n: Vec<Vec3> = uv_atlas.xref.iter().map(|&x| normals[x as usize]).collect();
        let samples = rasterize(&uv_atlas, &ignore);
        let (points, pnormals): (Vec<Vec3>, Vec<Vec3>) = samples
            .face
            .iter()
            .zip(&samples.bary)
            .map(|(&f, &b)| at_bary(&v, &n, uv_atlas.faces[f as usize], b))
            .unzip();
        let baked = MaterialTextures::bake(&samples, &field_at(&nm, &points, &pnormals), TEXTURE_PADDING as usize);
        let faces = &uv_atlas.faces[..surface_faces];
        loss = material_loss("textures", &nm, &v, &n, faces, |fi, b| {
            let f = faces[fi];
            let mut uv = [0.0f32; 2];
            for k in 0..3 {
                uv[0] += b[k] * uv_atlas.uv[f[k] as usize][0];
                uv[1] += b[k] * uv_atlas.uv[f[k] as usize][1];
            }
            baked.lookup(uv)
        });
        summary = Some(TextureSummary {
            width: uv_atlas.width,
            height: uv_atlas.height,
            charts: uv_atlas.charts,
            texels_per_unit: uv_atlas.texels_per_unit,
            utilization: uv_atlas.utilization,
        });
        materials.push(MaterialDesc::TexturedGgx { name: "ggx".into() });
        primitives.push(PrimitiveDesc {
            faces: faces.to_vec(),
            material: 0,
        });
        let mut start = surface_faces;
        emitter_faces = groups[1..]
            .iter()
            .map(|g| {
                let fs = uv_atlas.faces[start..start + g.len()].to_vec();
                start += g.len();
                fs
            })
            .collect::<Vec<_>>();
        (model_vertices, model_normals) = (v, n);
        colors = Vec::new();
        uvs = uv_atlas.uv;
        textures = Some(baked);
    } else {
        let brdf = field_at(&nm, &vertices, &normals);
        let vertex_kd: Vec<Vec3> = brdf.iter().map(|b| b.kd.clamp(Vec3::ZERO, Vec3::ONE)).collect();
        // ordinary faces: (Ks, ρ) per face, clustered
        let surface_faces = &groups[0];
        let areas: Vec<f32> = surface_faces.iter().map(|&f| triangle_area(&vertices, f)).collect();
        let features: Vec<f32> = surface_faces
            .iter()
            .flat_map(|f| {
                let mut ks = Vec3::ZERO;
                let mut rho = 0.0;
                for &v in f {
                    ks += brdf[v as usize].ks / 3.0;
                    rho += brdf[v as usize].rho / 3.0;
                }
                [ks.x, ks.y, ks.z, rho]
            })
            .collect();
        let (labels, centres) = cluster::kmeans(&features, 4, &areas, opts.materials);
        loss = material_loss("vertex colours", &nm, &vertices, &normals, surface_faces, |fi, b| {
            let f = surface_faces[fi];
            let kd = (0..3).map(|k| b[k] * vertex_kd[f[k] as usize]).sum::<Vec3>();
            let c = &centres[labels[fi] as usize];
            GgxBrdf::new(kd, Vec3::new(c[0], c[1], c[2]), c[3])
        });
        for (k, c) in centres.iter().enumerate() {
            materials.push(MaterialDesc::Ggx {
                name: format!("ggx_{k}"),
                // the base colour factor is white: COLOR_0 carries Kd
                pbr: GltfPbr::from_ggx(&GgxBrdf::new(Vec3::ONE, Vec3::new(c[0], c[1], c[2]), c[3])),
            });
            primitives.push(PrimitiveDesc {
                faces: Vec::new(),
                material: k,
            });
        }
        for (f, &l) in surface_faces.iter().zip(&labels) {
            primitives[l as usize].faces.push(*f);
        }
        emitter_faces = groups[1..].to_vec();
        colors = vertex_kd.iter().map(|c| c.to_array()).collect();
        (model_vertices, model_normals) = (vertices, normals);
        uvs = Vec::new();
        textures = None;
        summary = None;
    }
    for (k, faces) in emitter_faces.into_iter().enumerate() {
        materials.push(MaterialDesc::Emitter {
            name: format!("emitter_{k}"),
            emission: emitters[k].1.to_array(),
        });
        primitives.push(PrimitiveDesc {
            faces,
            material: materials.len() - 1,
        });
    }
    Ok((
        SceneModel {
            positions: model_vertices.iter().map(|v| v.to_array()).collect(),
            normals: model_normals.iter().map(|v| v.to_array()).collect(),
            colors,
            uvs,
            textures,
            lights,
            primitives,
            materials,
            cameras: Vec::new(),
            extras: serde_json::Value::Null,
        },
        loss,
        summary,
    ))
}

/// A stage-1 run's scene: the radiance field's linear colour seen head-on (view direction −n) at
/// each vertex, one unlit material.
pub fn radiance_scene(frozen: &FrozenScene, surface: &RecoveredSurface, opts: &ExportOptions) -> SceneModel {
    let (vertices, normals, groups) = simplified(frozen, surface, opts);
    let dirs: Vec<Vec3> = normals.iter().map(|n| -*n).collect();
    let mut rgb = vec![Vec3::ZERO; vertices.len()];
    frozen.surface_radiance(&vertices, &dirs, &mut rgb);
    SceneModel {
        positions: vertices.iter().map(|v| v.to_array()).collect(),
        normals: normals.iter().map(|v| v.to_array()).collect(),
        colors: rgb.iter().map(|c| c.max(Vec3::ZERO).to_array()).collect(),
        primitives: vec![PrimitiveDesc {
            faces: groups.into_iter().flatten().collect(),
            material: 0,
        }],
        materials: vec![MaterialDesc::Radiance {
            name: "radiance".into(),
        }],
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lights_carry_the_emitters_flux() {
        // a 1 × 1 ceiling panel facing down (two faces), and a small closed box (a bulb)
        let mut v = vec![
            Vec3::new(0.0, 2.0, 0.0),
            Vec3::new(1.0, 2.0, 0.0),
            Vec3::new(1.0, 2.0, 1.0),
            Vec3::new(0.0, 2.0, 1.0),
        ];
        let mut n = vec![Vec3::NEG_Y; 4];
        let panel = vec![[0, 1, 2], [0, 2, 3]];
        // the bulb: an octahedron of radius 0.1 around (3, 1, 3), normals outwards
        let c = Vec3::new(3.0, 1.0, 3.0);
        for d in [Vec3::X, Vec3::NEG_X, Vec3::Y, Vec3::NEG_Y, Vec3::Z, Vec3::NEG_Z] {
            v.push(c + 0.1 * d);
            n.push(d);
        }
        let o = |i: u32| i + 4;
        let bulb: Vec<[u32; 3]> = [
            [0, 2, 4],
            [2, 1, 4],
            [1, 3, 4],
            [3, 0, 4],
            [2, 0, 5],
            [1, 2, 5],
            [3, 1, 5],
            [0, 3, 5],
        ]
        .iter()
        .map(|f| [o(f[0]), o(f[1]), o(f[2])])
        .collect();
        let bulb_area: f32 = bulb.iter().map(|f| triangle_area(&v, *f)).sum();
        let lights = emitter_lights(&v, &n, &[(panel, Vec3::new(4.0, 2.0, 1.0)), (bulb, Vec3::splat(10.0))]);
        assert_eq!(lights.len(), 2);
        let spot = &lights[0];
        assert_eq!(spot.direction, Some([0.0, -1.0, 0.0]));
        assert_eq!(spot.position, [0.5, 2.0, 0.5]);
        assert_eq!(spot.color, [1.0, 0.5, 0.25]);
        // flux of the spot (cos² over the hemisphere: 2π/3·I) = π·L·A
        let flux = 2.0 * std::f32::consts::PI / 3.0 * spot.intensity / LUMENS_PER_WATT;
        assert!((flux - std::f32::consts::PI * 4.0 * 1.0).abs() < 1e-4, "{flux}");
        let point = &lights[1];
        assert_eq!(point.direction, None);
        assert!((Vec3::from(point.position) - c).length() < 1e-6);
        let flux = 4.0 * std::f32::consts::PI * point.intensity / LUMENS_PER_WATT;
        assert!((flux - std::f32::consts::PI * 10.0 * bulb_area).abs() < 1e-4, "{flux}");
    }
}
