//! The triangle mesh the evaluation exchanges is the data layer's ([`i2sdf_data::mesh`]); this
//! module re-exports it so that `i2sdf_eval::mesh::TriangleMesh` keeps naming the one type.

pub use i2sdf_data::mesh::*;

#[cfg(test)]
pub(crate) mod test_shapes {
    use super::TriangleMesh;

    pub fn box_mesh(min: [f32; 3], max: [f32; 3]) -> TriangleMesh {
        TriangleMesh::axis_box(min, max)
    }

    pub fn concat(meshes: &[TriangleMesh]) -> TriangleMesh {
        TriangleMesh::concat(meshes)
    }
}
