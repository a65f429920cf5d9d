//! i2sdf datasets: the native nerfstudio-style format, the paper's release format and COLMAP sparse
//! models, read into one internal scene (OpenCV cameras, world-space normals, z-depth, a
//! normalization into the unit sphere), with every file validated on load. Also the image/array I/O every other crate uses, and the one
//! point-neighbour structure ([`KdTree`]: nearest distances for `eval`, radius queries for stage 2).

pub mod animation;
pub mod camera;
pub mod camera_path;
pub mod colmap;
pub mod dataset;
pub mod depth_normals;
pub mod edit_assets;
pub mod edit_spec;
pub mod emitter_detect;
pub mod error;
pub mod exposure;
pub mod fingerprint;
#[cfg(any(test, feature = "test-support"))]
pub mod fixture;
pub mod imageio;
pub mod kdtree;
pub mod lens;
pub mod mesh;
pub mod native;
pub mod output;
pub mod paper;
pub mod paper_write;
pub mod photo_depth;
pub mod ply;
pub mod radiometry;
pub mod sensor_depth;
pub mod summary;
pub mod validate;

pub use camera::Camera;
pub use camera_path::{camera_path, PathKind};
pub use dataset::{load, Bounds, Dataset, Format, Frame, GtEmitter, Normalization, RelightSet, Split};
pub use edit_assets::EditAssets;
pub use edit_spec::{EditOp, EditSpec};
pub use error::DataError;
pub use imageio::ImageF32;
pub use kdtree::KdTree;
pub use lens::Lens;
pub use mesh::TriangleMesh;
pub use radiometry::{Radiometry, Transfer};
pub use sensor_depth::DepthDropped;
pub use summary::Summary;
