//! i2sdf fields (docs/ARCHITECTURE.md, "Rooms and data flow"): the SDF field F_d (distance + geometry feature z), the
//! radiance field F_c (z, view direction, normal → LDR colour), the emitter field F_e (z →
//! probability) and the VolSDF density's β, held together with the normalization as a
//! [`NeuralScene`]; saved and loaded as safetensors with the configuration in the metadata; the
//! run directory and a trained run opened for inference ([`OpenedRun`]) with its image products
//! ([`images`]); the volume renderer ([`renderer`]) with VolSDF's density, compositing and
//! error-bounded sampler beside it ([`volume`]); inference queries ([`SceneQuery`]), the ray
//! caster of the trained SDF ([`raycast`]), marching cubes ([`marching_cubes()`]) and the mesh of
//! the SDF's zero level set ([`sdf_mesh`]).

pub mod baked_surface;
pub mod config;
pub mod emitter_panel;
pub mod emitters;
pub mod images;
pub mod intrinsic;
pub mod intrinsic_io;
pub mod marching_cubes;
pub mod material_field;
pub mod mc_band;
pub mod mc_tables;
pub mod memory;
pub mod observed;
pub mod occupancy;
pub mod opened_run;
pub mod poses;
pub mod query;
pub mod raycast;
pub mod renderer;
pub mod run_dir;
pub mod scene;
pub mod sdf_mesh;
pub mod shading_normals;
pub mod volume;

pub use config::{Backbone, ModelConfig};
pub use emitters::{Emitter, EmitterTable};
pub use intrinsic::{emitter_cone_lights, emitter_lights, rerender_view, FrozenScene, LabelledHit, NeuralMaterial};
pub use marching_cubes::{marching_cubes, McGrid, McOptions};
pub use material_field::{
    MaterialBackbone, MaterialConfig, MaterialField, MaterialGrad, MaterialWorkspace, MATERIAL_CHANNELS,
};
pub use opened_run::{BakeRecord, InferenceConfig, OpenedRun};
pub use query::SceneQuery;
pub use run_dir::{RunDir, RunInfo, StageProgress};
pub use scene::{Beta, GroupSpec, LrClass, NeuralScene, ParamBlock, SceneGrads, SceneModule, Update};
pub use sdf_mesh::{extract_mesh, voxel_size, TRACED_SIMPLIFY_VOXELS};
