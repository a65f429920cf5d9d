//! A [`SceneModel`] as glTF 2.0: the document built with `gltf-json`'s structures, one binary
//! buffer (positions, normals, colours or texture coordinates, each primitive's indices, the
//! textures' PNGs), written as `.glb` (the binary container: a JSON chunk and a BIN chunk) or as
//! `.gltf` (JSON, the buffer embedded as a base64 data URI, so the scene stays one file).

use crate::scene_model::{LightDesc, MaterialDesc, SceneModel};
use base64::Engine;
use gltf_json as json;
use json::validation::{Checked::Valid, USize64};
use json::Index;
use std::path::Path;

/// Which container a path asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Container {
    Glb,
    Gltf,
}

impl Container {
    /// From the file name's extension (`.glb` or `.gltf`, case-insensitive).
    pub fn of_path(path: &Path) -> Option<Container> {
        match path.extension()?.to_str()?.to_ascii_lowercase().as_str() {
            "glb" => Some(Container::Glb),
            "gltf" => Some(Container::Gltf),
            _ => None,
        }
    }
}

fn align4(buf: &mut Vec<u8>, pad: u8) {
    while buf.len() % 4 != 0 {
        buf.push(pad);
    }
}

/// Appends `bytes` to the buffer as a new view (4-byte aligned) and returns its index.
fn push_view(
    root: &mut json::Root,
    bin: &mut Vec<u8>,
    bytes: &[u8],
    target: Option<json::buffer::Target>,
) -> Index<json::buffer::View> {
    align4(bin, 0);
    let offset = bin.len();
    bin.extend_from_slice(bytes);
    root.push(json::buffer::View {
        buffer: Index::new(0),
        byte_length: USize64::from(bytes.len()),
        byte_offset: Some(USize64::from(offset)),
        byte_stride: None,
        name: None,
        target: target.map(Valid),
        extensions: None,
        extras: Default::default(),
    })
}

fn accessor(
    view: Index<json::buffer::View>,
    count: usize,
    component: json::accessor::ComponentType,
    type_: json::accessor::Type,
    min_max: Option<([f32; 3], [f32; 3])>,
) -> json::Accessor {
    json::Accessor {
        buffer_view: Some(view),
        byte_offset: Some(USize64(0)),
        count: USize64::from(count),
        component_type: Valid(json::accessor::GenericComponentType(component)),
        extensions: None,
        extras: Default::default(),
        type_: Valid(type_),
        min: min_max.map(|(lo, _)| serde_json::json!(lo)),
        max: min_max.map(|(_, hi)| serde_json::json!(hi)),
        name: None,
        normalized: false,
        sparse: None,
    }
}

fn vec3_bytes(v: &[[f32; 3]]) -> Vec<u8> {
    v.iter().flatten().flat_map(|x| x.to_le_bytes()).collect()
}

/// The textures of a textured material, as glTF texture indices.
struct TextureIndices {
    base_color: Index<json::Texture>,
    roughness_specular: Index<json::Texture>,
    specular_color: Index<json::Texture>,
    specular_color_scale: f32,
}

fn info(index: Index<json::Texture>) -> json::texture::Info {
    json::texture::Info {
        index,
        tex_coord: 0,
        extensions: None,
        extras: Default::default(),
    }
}

fn material(desc: &MaterialDesc, textures: Option<&TextureIndices>) -> json::Material {
    use json::extensions::material as ext;
    use json::material::{EmissiveFactor, PbrBaseColorFactor, PbrMetallicRoughness, StrengthFactor};
    let mut m = json::Material {
        name: Some(desc.name().to_string()),
        // both sides: marching cubes orients the surface outwards from the solid, and a room is
        // seen from inside
        double_sided: true,
        ..Default::default()
    };
    let mut extensions = ext::Material::default();
    match desc {
        MaterialDesc::Ggx { pbr, .. } => {
            m.pbr_metallic_roughness = PbrMetallicRoughness {
                base_color_factor: PbrBaseColorFactor([pbr.base_color[0], pbr.base_color[1], pbr.base_color[2], 1.0]),
                metallic_factor: StrengthFactor(pbr.metallic),
                roughness_factor: StrengthFactor(pbr.roughness),
                ..Default::default()
            };
            extensions.specular = Some(ext::Specular {
                specular_factor: ext::SpecularFactor(pbr.specular),
                specular_color_factor: ext::SpecularColorFactor(pbr.specular_color),
                ..Default::default()
            });
        }
        MaterialDesc::TexturedGgx { .. } => {
            let t = textures.expect("a textured material comes with its textures");
            m.pbr_metallic_roughness = PbrMetallicRoughness {
                base_color_texture: Some(info(t.base_color)),
                metallic_roughness_texture: Some(info(t.roughness_specular)),
                ..Default::default()
            };
            extensions.specular = Some(ext::Specular {
                specular_factor: ext::SpecularFactor(1.0),
                specular_texture: Some(info(t.roughness_specular)),
                specular_color_factor: ext::SpecularColorFactor([t.specular_color_scale; 3]),
                specular_color_texture: Some(info(t.specular_color)),
                ..Default::default()
            });
        }
        MaterialDesc::Emitter { emission, .. } => {
            let (colour, strength) = crate::material_map::emissive(*emission);
            m.pbr_metallic_roughness = PbrMetallicRoughness {
                base_color_factor: PbrBaseColorFactor([0.0, 0.0, 0.0, 1.0]),
                metallic_factor: StrengthFactor(0.0),
                roughness_factor: StrengthFactor(1.0),
                ..Default::default()
            };
            m.emissive_factor = EmissiveFactor(colour);
            extensions.emissive_strength = Some(ext::EmissiveStrength {
                emissive_strength: ext::EmissiveStrengthFactor(strength),
            });
        }
        MaterialDesc::Radiance { .. } => {
            m.pbr_metallic_roughness = PbrMetallicRoughness {
                metallic_factor: StrengthFactor(0.0),
                roughness_factor: StrengthFactor(1.0),
                ..Default::default()
            };
            extensions.unlit = Some(ext::Unlit {});
        }
    }
    m.extensions = Some(extensions);
    m
}

fn light(l: &LightDesc) -> json::extensions::scene::khr_lights_punctual::Light {
    use json::extensions::scene::khr_lights_punctual as punctual;
    punctual::Light {
        color: l.color,
        extensions: None,
        extras: Default::default(),
        intensity: l.intensity,
        name: Some(l.name.clone()),
        range: None,
        spot: l.direction.map(|_| punctual::Spot {
            inner_cone_angle: 0.0,
            outer_cone_angle: l.cone,
        }),
        type_: Valid(if l.direction.is_some() {
            punctual::Type::Spot
        } else {
            punctual::Type::Point
        }),
    }
}

/// The node rotation (x, y, z, w) that turns glTF's spot direction (−Z) onto `dir`.
pub fn spot_rotation(dir: [f32; 3]) -> [f32; 4] {
    glam::Quat::from_rotation_arc(glam::Vec3::NEG_Z, glam::Vec3::from(dir).normalize()).to_array()
}

/// The glTF document of `model` and its binary buffer (the buffer's `uri` unset: the GLB
/// container's BIN chunk).
pub fn document(model: &SceneModel) -> (json::Root, Vec<u8>) {
    use json::accessor::{ComponentType, Type};
    use json::buffer::Target;
    let mut root = json::Root {
        asset: json::Asset {
            generator: Some(format!("i2sdf export {}", env!("CARGO_PKG_VERSION"))),
            ..Default::default()
        },
        ..Default::default()
    };
    let mut bin = Vec::new();
    let n = model.positions.len();
    let bounds = model.bounds();
    let pos_view = push_view(
        &mut root,
        &mut bin,
        &vec3_bytes(&model.positions),
        Some(Target::ArrayBuffer),
    );
    let pos = root.push(accessor(pos_view, n, ComponentType::F32, Type::Vec3, Some(bounds)));
    let nrm_view = push_view(
        &mut root,
        &mut bin,
        &vec3_bytes(&model.normals),
        Some(Target::ArrayBuffer),
    );
    let nrm = root.push(accessor(nrm_view, n, ComponentType::F32, Type::Vec3, None));
    let col = (!model.colors.is_empty()).then(|| {
        let view = push_view(
            &mut root,
            &mut bin,
            &vec3_bytes(&model.colors),
            Some(Target::ArrayBuffer),
        );
        root.push(accessor(view, n, ComponentType::F32, Type::Vec3, None))
    });
    let uv = (!model.uvs.is_empty()).then(|| {
        let bytes: Vec<u8> = model.uvs.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        let view = push_view(&mut root, &mut bin, &bytes, Some(Target::ArrayBuffer));
        root.push(accessor(view, n, ComponentType::F32, Type::Vec2, None))
    });
    let textures = model.textures.as_ref().map(|t| {
        use json::texture::{MagFilter, MinFilter, WrappingMode};
        let sampler = root.push(json::texture::Sampler {
            mag_filter: Some(Valid(MagFilter::Linear)),
            min_filter: Some(Valid(MinFilter::LinearMipmapLinear)),
            name: None,
            // charts end at their dilated borders; nothing wraps around the page
            wrap_s: Valid(WrappingMode::ClampToEdge),
            wrap_t: Valid(WrappingMode::ClampToEdge),
            extensions: None,
            extras: Default::default(),
        });
        let mut texture = |name: &str, png: Vec<u8>| {
            let view = push_view(&mut root, &mut bin, &png, None);
            let image = root.push(json::Image {
                buffer_view: Some(view),
                mime_type: Some(json::image::MimeType("image/png".into())),
                name: Some(name.into()),
                uri: None,
                extensions: None,
                extras: Default::default(),
            });
            root.push(json::Texture {
                name: Some(name.into()),
                sampler: Some(sampler),
                source: image,
                extensions: None,
                extras: Default::default(),
            })
        };
        TextureIndices {
            base_color: texture("base_color_kd", t.base_color.png()),
            roughness_specular: texture("roughness_g_specular_a", t.roughness_specular.png()),
            specular_color: texture("specular_color", t.specular_color.png()),
            specular_color_scale: t.specular_color_scale,
        }
    });

    let materials: Vec<Index<json::Material>> = model
        .materials
        .iter()
        .map(|m| root.push(material(m, textures.as_ref())))
        .collect();
    let mut used = std::collections::BTreeSet::new();
    for m in &model.materials {
        used.insert(match m {
            MaterialDesc::Ggx { .. } | MaterialDesc::TexturedGgx { .. } => "KHR_materials_specular",
            MaterialDesc::Emitter { .. } => "KHR_materials_emissive_strength",
            MaterialDesc::Radiance { .. } => "KHR_materials_unlit",
        });
    }
    let mut primitives = Vec::new();
    for p in model.primitives.iter().filter(|p| !p.faces.is_empty()) {
        let idx: Vec<u8> = p.faces.iter().flatten().flat_map(|i| i.to_le_bytes()).collect();
        let view = push_view(&mut root, &mut bin, &idx, Some(Target::ElementArrayBuffer));
        let indices = root.push(accessor(
            view,
            p.faces.len() * 3,
            ComponentType::U32,
            Type::Scalar,
            None,
        ));
        let mut attributes = std::collections::BTreeMap::new();
        attributes.insert(Valid(json::mesh::Semantic::Positions), pos);
        attributes.insert(Valid(json::mesh::Semantic::Normals), nrm);
        if let Some(col) = col {
            attributes.insert(Valid(json::mesh::Semantic::Colors(0)), col);
        }
        if let (Some(uv), MaterialDesc::TexturedGgx { .. }) = (uv, &model.materials[p.material]) {
            attributes.insert(Valid(json::mesh::Semantic::TexCoords(0)), uv);
        }
        primitives.push(json::mesh::Primitive {
            attributes,
            extensions: None,
            extras: Default::default(),
            indices: Some(indices),
            material: Some(materials[p.material]),
            mode: Valid(json::mesh::Mode::Triangles),
            targets: None,
        });
    }
    let mut nodes = Vec::new();
    if !primitives.is_empty() {
        let mesh = root.push(json::Mesh {
            extensions: None,
            extras: Default::default(),
            name: Some("room".into()),
            primitives,
            weights: None,
        });
        nodes.push(root.push(json::Node {
            mesh: Some(mesh),
            name: Some("room".into()),
            ..Default::default()
        }));
    }
    for c in &model.cameras {
        let camera = root.push(json::Camera {
            name: Some(c.name.clone()),
            orthographic: None,
            perspective: Some(json::camera::Perspective {
                aspect_ratio: Some(c.aspect_ratio),
                yfov: c.yfov,
                zfar: None,
                znear: c.znear,
                extensions: None,
                extras: Default::default(),
            }),
            type_: Valid(json::camera::Type::Perspective),
            extensions: None,
            extras: Default::default(),
        });
        nodes.push(root.push(json::Node {
            camera: Some(camera),
            name: Some(c.name.clone()),
            matrix: Some(c.matrix),
            ..Default::default()
        }));
    }
    if !model.lights.is_empty() {
        use json::extensions::scene::khr_lights_punctual as punctual;
        let mut lights = Vec::new();
        for (i, l) in model.lights.iter().enumerate() {
            lights.push(light(l));
            nodes.push(root.push(json::Node {
                name: Some(l.name.clone()),
                translation: Some(l.position),
                rotation: l.direction.map(|d| json::scene::UnitQuaternion(spot_rotation(d))),
                extensions: Some(json::extensions::scene::Node {
                    khr_lights_punctual: Some(punctual::KhrLightsPunctual {
                        light: Index::new(i as u32),
                    }),
                    ..Default::default()
                }),
                ..Default::default()
            }));
        }
        root.extensions = Some(json::extensions::root::Root {
            khr_lights_punctual: Some(json::extensions::root::KhrLightsPunctual { lights }),
            ..Default::default()
        });
        used.insert("KHR_lights_punctual");
    }
    let scene = root.push(json::Scene {
        extensions: None,
        extras: Default::default(),
        name: Some("i2sdf".into()),
        nodes,
    });
    root.scene = Some(scene);
    root.extensions_used = used.into_iter().map(String::from).collect();
    if !model.extras.is_null() {
        root.extras = serde_json::value::to_raw_value(&model.extras).ok();
    }
    align4(&mut bin, 0);
    root.push(json::Buffer {
        byte_length: USize64::from(bin.len()),
        name: None,
        uri: None,
        extensions: None,
        extras: Default::default(),
    });
    (root, bin)
}

/// The file's bytes in `container`.
pub fn encode(model: &SceneModel, container: Container) -> Vec<u8> {
    let (mut root, bin) = document(model);
    match container {
        Container::Glb => {
            let mut text = root.to_vec().expect("a glTF document serializes");
            align4(&mut text, b' ');
            let total = 12 + 8 + text.len() + 8 + bin.len();
            let mut out = Vec::with_capacity(total);
            out.extend_from_slice(b"glTF");
            out.extend_from_slice(&2u32.to_le_bytes());
            out.extend_from_slice(&(total as u32).to_le_bytes());
            out.extend_from_slice(&(text.len() as u32).to_le_bytes());
            out.extend_from_slice(b"JSON");
            out.extend_from_slice(&text);
            out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
            out.extend_from_slice(b"BIN\0");
            out.extend_from_slice(&bin);
            out
        }
        Container::Gltf => {
            root.buffers[0].uri = Some(format!(
                "data:application/octet-stream;base64,{}",
                base64::engine::general_purpose::STANDARD.encode(&bin)
            ));
            root.to_vec_pretty().expect("a glTF document serializes")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material_map::GltfPbr;
    use crate::scene_model::{CameraDesc, PrimitiveDesc};
    use i2sdf_render::GgxBrdf;

    fn tetra() -> SceneModel {
        SceneModel {
            positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            normals: vec![[0.0, 1.0, 0.0]; 4],
            colors: vec![[0.5, 0.25, 0.125]; 4],
            primitives: vec![
                PrimitiveDesc {
                    faces: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2]],
                    material: 0,
                },
                PrimitiveDesc {
                    faces: vec![[1, 2, 3]],
                    material: 1,
                },
            ],
            materials: vec![
                MaterialDesc::Ggx {
                    name: "ggx_0".into(),
                    pbr: GltfPbr {
                        base_color: [1.0; 3],
                        metallic: 0.0,
                        roughness: 0.3,
                        specular: 1.0,
                        specular_color: [2.0, 2.0, 2.0],
                    },
                },
                MaterialDesc::Emitter {
                    name: "emitter_0".into(),
                    emission: [8.0, 4.0, 2.0],
                },
            ],
            cameras: vec![CameraDesc {
                name: "test_000".into(),
                yfov: 1.0,
                aspect_ratio: 4.0 / 3.0,
                znear: 0.01,
                matrix: glam::Mat4::from_translation(glam::Vec3::new(0.0, 1.0, 3.0)).to_cols_array(),
            }],
            extras: serde_json::json!({"units": "metre"}),
            uvs: Vec::new(),
            textures: None,
            lights: vec![
                LightDesc {
                    name: "light_0".into(),
                    position: [0.5, 2.0, 0.5],
                    direction: Some([0.0, -1.0, 0.0]),
                    cone: std::f32::consts::FRAC_PI_2,
                    color: [1.0, 0.5, 0.25],
                    intensity: 12.0,
                },
                LightDesc {
                    name: "light_1".into(),
                    position: [0.1, 0.2, 0.3],
                    direction: None,
                    cone: 0.0,
                    color: [1.0; 3],
                    intensity: 3.0,
                },
            ],
        }
    }

    #[test]
    fn both_containers_read_back_through_the_gltf_crate() {
        let model = tetra();
        for container in [Container::Glb, Container::Gltf] {
            let bytes = encode(&model, container);
            if container == Container::Glb {
                assert_eq!(&bytes[..4], b"glTF");
                assert_eq!(
                    u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize,
                    bytes.len()
                );
            }
            let (doc, buffers, _) = gltf::import_slice(&bytes).expect("a valid glTF");
            let mesh = doc.meshes().next().unwrap();
            let mut faces = 0;
            for prim in mesh.primitives() {
                let r = prim.reader(|b| Some(&buffers[b.index()]));
                let pos: Vec<[f32; 3]> = r.read_positions().unwrap().collect();
                assert_eq!(pos, model.positions);
                let col: Vec<[f32; 3]> = r.read_colors(0).unwrap().into_rgb_f32().collect();
                assert_eq!(col, model.colors);
                faces += r.read_indices().unwrap().into_u32().count() / 3;
                let b = prim.bounding_box();
                assert_eq!((b.min, b.max), ([0.0; 3], [1.0; 3]));
            }
            assert_eq!(faces, 4);
            let mats: Vec<_> = doc.materials().collect();
            assert_eq!(mats[0].pbr_metallic_roughness().roughness_factor(), 0.3);
            let spec = mats[0].specular().expect("KHR_materials_specular");
            assert_eq!((spec.specular_factor(), spec.specular_color_factor()), (1.0, [2.0; 3]));
            assert_eq!(mats[1].emissive_factor(), [1.0, 0.5, 0.25]);
            assert_eq!(mats[1].emissive_strength(), Some(8.0));
            let cam = doc.cameras().next().unwrap();
            assert_eq!(cam.name(), Some("test_000"));
            assert!(doc.extensions_used().any(|e| e == "KHR_materials_emissive_strength"));
            // the lights: a spot turned to shine down, a point light
            let lights: Vec<_> = doc.nodes().filter_map(|n| n.light().map(|l| (n, l))).collect();
            assert_eq!(lights.len(), 2);
            let (node, spot) = &lights[0];
            assert_eq!((spot.intensity(), spot.color()), (12.0, [1.0, 0.5, 0.25]));
            let gltf::khr_lights_punctual::Kind::Spot { outer_cone_angle, .. } = spot.kind() else {
                panic!("a spot light")
            };
            assert_eq!(outer_cone_angle, std::f32::consts::FRAC_PI_2);
            let (t, r, _) = node.transform().decomposed();
            assert_eq!(t, [0.5, 2.0, 0.5]);
            let down = glam::Quat::from_array(r) * glam::Vec3::NEG_Z;
            assert!((down - glam::Vec3::NEG_Y).length() < 1e-6, "{down}");
            assert!(matches!(lights[1].1.kind(), gltf::khr_lights_punctual::Kind::Point));
        }
    }

    #[test]
    fn a_textured_material_reads_back_with_its_textures() {
        use crate::atlas::UvAtlas;
        use crate::bake::{rasterize, MaterialTextures};
        let mut model = tetra();
        model.colors.clear();
        model.uvs = vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
        let atlas = UvAtlas {
            width: 8,
            height: 8,
            xref: vec![0, 1, 2, 3],
            uv: model.uvs.clone(),
            faces: vec![[0, 1, 2], [0, 2, 3]],
            texels_per_unit: 8.0,
            charts: 1,
            utilization: 1.0,
        };
        let samples = rasterize(&atlas, &[false, false]);
        let brdf =
            vec![GgxBrdf::new(glam::Vec3::new(0.5, 0.25, 0.125), glam::Vec3::splat(0.1), 0.4); samples.texel.len()];
        model.textures = Some(MaterialTextures::bake(&samples, &brdf, 2));
        model.materials[0] = MaterialDesc::TexturedGgx { name: "ggx".into() };
        for container in [Container::Glb, Container::Gltf] {
            let (doc, buffers, images) = gltf::import_slice(&encode(&model, container)).expect("a valid glTF");
            assert_eq!(images.len(), 3);
            let m = doc.materials().next().unwrap();
            let pbr = m.pbr_metallic_roughness();
            let base = pbr.base_color_texture().expect("a base colour texture");
            let img = &images[base.texture().source().index()];
            assert_eq!((img.width, img.height), (8, 8));
            // Kd 0.5 in sRGB
            let want = (i2sdf_data::imageio::linear_to_srgb(0.5) * 255.0 + 0.5) as u8;
            assert_eq!(img.pixels[0], want);
            let mr = pbr.metallic_roughness_texture().expect("a roughness texture");
            let spec = m.specular().expect("KHR_materials_specular");
            assert_eq!(spec.specular_texture().unwrap().texture().index(), mr.texture().index());
            assert_eq!(spec.specular_color_factor(), [2.5; 3]);
            assert!(spec.specular_color_texture().is_some());
            let prim = doc.meshes().next().unwrap().primitives().next().unwrap();
            let r = prim.reader(|b| Some(&buffers[b.index()]));
            let uv: Vec<[f32; 2]> = r.read_tex_coords(0).unwrap().into_f32().collect();
            assert_eq!(uv, model.uvs);
            assert!(r.read_colors(0).is_none());
        }
    }
}
