//! The frozen SDF baked once: its marching-cubes mesh in a BVH, with the smoothed shading
//! normals of its vertices where the run has them; [`crate::intrinsic::FrozenScene`] casts into it.

use crate::emitters::EmitterTable;
use crate::intrinsic::FrozenScene;
use crate::scene::NeuralScene;
use crate::sdf_mesh::{extract_mesh, voxel_size};
use crate::shading_normals::SmoothedNormals;
use glam::Vec3;
use i2sdf_data::{Bounds, DataError, Radiometry};
use i2sdf_render::Bvh;

/// The marching-cubes mesh of the frozen SDF in a BVH, world units.
pub struct BakedSurface {
    pub(crate) bvh: Bvh,
    /// The grid step (world units): the Newton step's clamp and the largest |d| at a BVH hit
    /// that is accepted as lying on the zero level set.
    pub(crate) voxel: f32,
    /// Where the run shades with smoothed normals (a dataset without normal maps,
    /// `stage2.normal_smoothing_radius`): the field and the mesh's vertex normals smoothed.
    pub(crate) shading: Option<BakedShading>,
}

/// The smoothed shading normals of a baked surface ([`SmoothedNormals`] over its vertices):
/// a BVH hit's normal is its triangle's smoothed vertex normals interpolated.
pub(crate) struct BakedShading {
    pub(crate) field: SmoothedNormals,
    pub(crate) faces: Vec<[u32; 3]>,
    pub(crate) vertex_normals: Vec<Vec3>,
}

impl BakedSurface {
    /// The marching-cubes mesh of `scene`'s SDF over `bounds` (world units, padded by
    /// [`PAD_FRACTION`](crate::sdf_mesh::PAD_FRACTION)) at `resolution` samples along the
    /// longest side, in a BVH ([`FrozenScene::bake`]).
    ///
    /// Not simplified, unlike the edit renderer's surface: simplified by a tenth of a voxel
    /// (493k faces → 76k), the default room's test-view re-render took as long (41.2 s against
    /// 40.6 s; its time is in the network queries) and lost 0.03 dB.
    ///
    /// With `normal_smoothing` > 0 (world units) the hits' shading normals are the SDF's
    /// averaged over that radius ([`SmoothedNormals`] over the mesh's vertices, their normals
    /// the SDF's gradient there).
    pub fn new(
        scene: &NeuralScene,
        bounds: &Bounds,
        resolution: usize,
        normal_smoothing: f32,
    ) -> Result<Self, DataError> {
        let mesh = extract_mesh(scene, bounds, resolution)?;
        let voxel = voxel_size(scene, bounds, resolution)?;
        let shading = (normal_smoothing > 0.0 && !mesh.faces.is_empty()).then(|| {
            let vertices: Vec<Vec3> = mesh.positions.iter().map(|p| Vec3::from(*p)).collect();
            let none = EmitterTable::new(Vec::new(), &[]);
            let normals = FrozenScene::new(scene, &none, Radiometry::default())
                .sdf_gradient(&vertices)
                .into_iter()
                .map(|(_, g)| g.normalize_or_zero())
                .collect();
            let field = SmoothedNormals::new(&vertices, normals, normal_smoothing);
            BakedShading {
                vertex_normals: field.at_samples(),
                field,
                faces: mesh.faces.clone(),
            }
        });
        Ok(BakedSurface {
            bvh: Bvh::build(&mesh),
            voxel,
            shading,
        })
    }

    /// The smoothed shading normals of this surface, where it has them.
    pub fn smoothed_normals(&self) -> Option<&SmoothedNormals> {
        self.shading.as_ref().map(|s| &s.field)
    }
}
