//! Synthetic indoor scenes with full ground truth (issue 3): procedural rooms described in TOML,
//! tessellated into one triangle mesh (which is also the ground-truth PLY), rendered by an
//! unbiased CPU path tracer (next-event estimation + MIS, Russian roulette, the supplementary's
//! GGX BRDF from `i2sdf-render`), and written in the native dataset format of DESIGN.md with
//! depth, normals, emitter masks, material maps, the mesh and relit test views.

pub mod bvh;
pub mod camera;
pub mod dataset;
pub mod edit;
pub mod mesh;
pub mod noise;
pub mod output;
pub mod presets;
pub mod scene;
pub mod tracer;

pub use camera::Camera;
pub use dataset::{generate, SynthOptions, SynthSummary};
pub use edit::{EditOp, EditSpec};
pub use mesh::TriangleMesh;
pub use noise::DepthNoise;
pub use presets::RoomPreset;
pub use scene::SceneDesc;
pub use tracer::RenderScene;
