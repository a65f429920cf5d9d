//! What an exported scene holds, in glTF's axes and units, before it is written: one vertex
//! array (position, normal, a linear colour or a texture coordinate), faces grouped by material,
//! the materials and their textures, the lights, the cameras. Filled from a trained run by [`crate::build`], written by [`crate::gltf_write`].

use crate::bake::MaterialTextures;
use crate::material_map::GltfPbr;

/// One material of the scene.
#[derive(Clone, Debug, PartialEq)]
pub enum MaterialDesc {
    /// A recovered GGX material: the vertex colours are its base colour (Kd), `pbr.base_color`
    /// the factor they are multiplied by (white).
    Ggx { name: String, pbr: GltfPbr },
    /// The recovered GGX material baked into the scene's [`MaterialTextures`] (read through
    /// TEXCOORD_0).
    TexturedGgx { name: String },
    /// Emitter k: black, emitting L\[k\] (linear, the input images' units).
    Emitter { name: String, emission: [f32; 3] },
    /// A stage-1 run's surface: unlit (`KHR_materials_unlit`), its vertex colours the radiance
    /// field's linear radiance.
    Radiance { name: String },
}

impl MaterialDesc {
    pub fn name(&self) -> &str {
        match self {
            MaterialDesc::Ggx { name, .. }
            | MaterialDesc::TexturedGgx { name }
            | MaterialDesc::Emitter { name, .. }
            | MaterialDesc::Radiance { name } => name,
        }
    }
}

/// Faces of one material (indices into the vertex arrays).
#[derive(Clone, Debug, PartialEq)]
pub struct PrimitiveDesc {
    pub faces: Vec<[u32; 3]>,
    pub material: usize,
}

/// A pinhole camera node (glTF cameras look down −Z with +Y up).
#[derive(Clone, Debug, PartialEq)]
pub struct CameraDesc {
    pub name: String,
    /// Vertical field of view (radians).
    pub yfov: f32,
    /// Width / height.
    pub aspect_ratio: f32,
    pub znear: f32,
    /// The node's local-to-world transform, column-major, glTF axes.
    pub matrix: [f32; 16],
}

/// A punctual light (`KHR_lights_punctual`): a point light, or a spot light shining along
/// `direction` with a cone of `cone` radians (half-angle).
#[derive(Clone, Debug, PartialEq)]
pub struct LightDesc {
    pub name: String,
    pub position: [f32; 3],
    /// Unit vector, glTF axes; `None`: a point light.
    pub direction: Option<[f32; 3]>,
    pub cone: f32,
    /// Linear colour in [0, 1] (the largest channel 1).
    pub color: [f32; 3],
    /// Candela: 683 × the emitter's radiant intensity in the input images' units × world units²
    /// (`material_scene::LUMENS_PER_WATT`).
    pub intensity: f32,
}

#[derive(Clone, Debug, Default, PartialEq)]
pub struct SceneModel {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    /// Linear RGB per vertex (COLOR_0), or empty.
    pub colors: Vec<[f32; 3]>,
    /// Texture coordinates per vertex (TEXCOORD_0, glTF's: v down the image), or empty.
    pub uvs: Vec<[f32; 2]>,
    /// The textures of [`MaterialDesc::TexturedGgx`].
    pub textures: Option<MaterialTextures>,
    pub lights: Vec<LightDesc>,
    pub primitives: Vec<PrimitiveDesc>,
    pub materials: Vec<MaterialDesc>,
    pub cameras: Vec<CameraDesc>,
    /// Provenance written as the root's `extras` (the run, units, the up axis, how materials
    /// were mapped).
    pub extras: serde_json::Value,
}

impl SceneModel {
    pub fn faces(&self) -> usize {
        self.primitives.iter().map(|p| p.faces.len()).sum()
    }

    /// The axis-aligned bounds of the vertices (glTF axes).
    pub fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in &self.positions {
            for i in 0..3 {
                lo[i] = lo[i].min(p[i]);
                hi[i] = hi[i].max(p[i]);
            }
        }
        (lo, hi)
    }
}
