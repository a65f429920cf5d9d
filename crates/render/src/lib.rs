//! Shared physics of i2sdf: the GGX (Unreal) BRDF of the supplementary ("BRDF Model") with its
//! importance sampling and exact pdf, sampling utilities, colour helpers, and
//! the one Monte Carlo integrator of the house with its interfaces: geometry (batched ray
//! queries; a triangle BVH here, the SDF tracer of stage 2 elsewhere), materials (batched BRDF
//! parameters; constant and textured here, neural fields elsewhere) and lights (area and
//! spherical emitters here, stage 2's emitter clusters elsewhere). The synthetic ground-truth
//! renderer (`i2sdf-synth`), stage 2's Monte Carlo shading and the edit renderer all shade with
//! one model through one estimator.
//!
//! Interfaces: [`geometry`], [`material`], [`light`], [`integrator`]; one implementation per file
//! beside them; [`render_view()`] renders a camera view through the integrator.

pub mod area_light;
pub mod brdf;
pub mod bvh;
#[cfg(any(test, feature = "test-support"))]
pub mod chi2;
pub mod color;
pub mod cone_light;
pub mod constant_material;
pub mod denoise;
pub mod geometry;
pub mod integrator;
pub mod light;
pub mod material;
pub mod mesh_geometry;
pub mod proposal;
pub mod render_view;
pub mod sampling;
pub mod simplify;
pub mod sphere_light;
pub mod textured_material;

pub use area_light::AreaLight;
pub use brdf::{BrdfLobe, BrdfSample, GgxBrdf, GgxGrad};
pub use bvh::Bvh;
pub use color::luminance;
pub use cone_light::ConeLight;
pub use constant_material::ConstantMaterial;
pub use denoise::Denoiser;
pub use geometry::{Geometry, Hit, Ray};
pub use integrator::{Estimator, Integrator, PathStart, RadianceField, Scene};
pub use light::{Light, LightSample, LightSet, Visibility};
pub use material::{KdTexture, Material, SurfacePoint};
pub use mesh_geometry::MeshGeometry;
pub use proposal::{DirectionMixture, Lobe};
pub use render_view::{render_view, ViewRender, ViewSettings};
pub use sphere_light::SphereLight;
pub use textured_material::TexturedMaterial;
