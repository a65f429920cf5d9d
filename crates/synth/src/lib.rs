//! Synthetic indoor scenes with full ground truth (issue 3): procedural rooms described in TOML,
//! tessellated into one triangle mesh (which is also the ground-truth PLY), rendered by the shared
//! Monte Carlo integrator of `i2sdf-render` (next-event estimation + MIS, Russian roulette, the
//! supplementary's GGX BRDF), and written in the native dataset format (docs/DATASETS.md) with
//! depth, normals, emitter masks, material maps, the mesh and relit test views.

pub mod camera;
pub mod capture;
pub mod dataset;
pub mod edit;
pub mod mesh;
pub mod noise;
pub mod output;
pub mod presets;
pub mod scene;
pub mod tracer;

pub use camera::looking;
pub use capture::CaptureOptions;
pub use dataset::{generate, SynthOptions, SynthSummary};
pub use edit::{EditOp, EditSpec, RelightOp};
pub use i2sdf_data::Camera;
pub use mesh::SceneMesh;
pub use noise::DepthNoise;
pub use presets::RoomPreset;
pub use scene::SceneDesc;
pub use tracer::RenderScene;
