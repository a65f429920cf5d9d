//! Editing and relighting the intrinsic scene (paper Sec. "Scene Editing"; DESIGN.md "Editing
//! and relighting"): the spec's operations applied to what stage 2 recovered — relight gains on
//! the emitters, material overrides in regions of the SDF's surface, inserted objects (which may
//! emit) — and the result rendered by the shared path tracer of `i2sdf_render` (NEE over every
//! emitter with MIS, GGX sampling, several bounces, Russian roulette).

pub mod geometry;
pub mod material;
pub mod scene;

pub use geometry::UnionGeometry;
pub use material::{EditedMaterial, KdLookup, MaterialEdit, RegionTest};
pub use scene::{mesh_box, BaseLights, EditedScene, InsertedObject};
pub mod recovered;
pub use recovered::{recovered_lights, render_recovered, EditSettings, RecoveredSurface};
