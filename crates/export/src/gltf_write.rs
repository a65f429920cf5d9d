//! A [`SceneModel`] as glTF 2.0: the document built with `gltf-json`'s structures, one binary
//! buffer (positions, normals, colours, then each primitive's indices), written as `.glb` (the
//! binary container: a JSON chunk and a BIN chunk) or as `.gltf` (JSON, the buffer embedded as a
//! base64 data URI, so the scene stays one file).

use crate::scene_model::{MaterialDesc, SceneModel};
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
    target: json::buffer::Target,
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
        target: Some(Valid(target)),
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

fn material(desc: &MaterialDesc) -> json::Material {
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
    let pos_view = push_view(&mut root, &mut bin, &vec3_bytes(&model.positions), Target::ArrayBuffer);
    let pos = root.push(accessor(pos_view, n, ComponentType::F32, Type::Vec3, Some(bounds)));
    let nrm_view = push_view(&mut root, &mut bin, &vec3_bytes(&model.normals), Target::ArrayBuffer);
    let nrm = root.push(accessor(nrm_view, n, ComponentType::F32, Type::Vec3, None));
    let col_view = push_view(&mut root, &mut bin, &vec3_bytes(&model.colors), Target::ArrayBuffer);
    let col = root.push(accessor(col_view, n, ComponentType::F32, Type::Vec3, None));

    let materials: Vec<Index<json::Material>> = model.materials.iter().map(|m| root.push(material(m))).collect();
    let mut used = std::collections::BTreeSet::new();
    for m in &model.materials {
        used.insert(match m {
            MaterialDesc::Ggx { .. } => "KHR_materials_specular",
            MaterialDesc::Emitter { .. } => "KHR_materials_emissive_strength",
            MaterialDesc::Radiance { .. } => "KHR_materials_unlit",
        });
    }
    let mut primitives = Vec::new();
    for p in model.primitives.iter().filter(|p| !p.faces.is_empty()) {
        let idx: Vec<u8> = p.faces.iter().flatten().flat_map(|i| i.to_le_bytes()).collect();
        let view = push_view(&mut root, &mut bin, &idx, Target::ElementArrayBuffer);
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
        attributes.insert(Valid(json::mesh::Semantic::Colors(0)), col);
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
        }
    }
}
