//! Editing and relighting the intrinsic scene (paper Sec. "Scene Editing"; docs/EDITING.md): the spec's operations applied to what stage 2 recovered — relight gains on
//! the emitters, material overrides in regions of the SDF's surface, inserted objects (which may
//! emit) — and the result rendered by the shared path tracer of `i2sdf_render` (NEE over every
//! emitter with MIS, GGX sampling, several bounces, Russian roulette).

pub mod geometry;
pub mod material;
pub mod scene;

pub use geometry::UnionGeometry;
pub use material::{brdf_of, values_of, EditedMaterial, MaterialEdit};
pub use scene::{mesh_box, BaseLights, EditedScene, InsertedObject};
pub mod recovered;
pub use recovered::{edit_images, recovered_lights, EditSettings, RecoveredScene, RecoveredSurface, MESH_RESOLUTION};
pub mod apply;
pub use apply::{edited_scene, light_gains};
pub mod differential;
pub use differential::{composite_hdr, hdr_ldr_images, Composite};
pub mod renderer;
/// The renders' denoiser, for the edit and eval settings that take one.
pub use i2sdf_render::Denoiser;
pub use renderer::EditRenderer;
