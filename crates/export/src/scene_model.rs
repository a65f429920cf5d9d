//! What an exported scene holds, in glTF's axes and units, before it is written: one vertex
//! array (position, normal, a linear colour), faces grouped by material, the materials, the
//! cameras. Filled from a trained run by [`crate::build`], written by [`crate::gltf_write`].

use crate::material_map::GltfPbr;

/// One material of the scene.
#[derive(Clone, Debug, PartialEq)]
pub enum MaterialDesc {
    /// A recovered GGX material: the vertex colours are its base colour (Kd), `pbr.base_color`
    /// the factor they are multiplied by (white).
    Ggx { name: String, pbr: GltfPbr },
    /// Emitter k: black, emitting L\[k\] (linear, the input images' units).
    Emitter { name: String, emission: [f32; 3] },
    /// A stage-1 run's surface: unlit (`KHR_materials_unlit`), its vertex colours the radiance
    /// field's linear radiance.
    Radiance { name: String },
}

impl MaterialDesc {
    pub fn name(&self) -> &str {
        match self {
            MaterialDesc::Ggx { name, .. } | MaterialDesc::Emitter { name, .. } | MaterialDesc::Radiance { name } => {
                name
            }
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

#[derive(Clone, Debug, Default, PartialEq)]
pub struct SceneModel {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    /// Linear RGB per vertex (COLOR_0).
    pub colors: Vec<[f32; 3]>,
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
