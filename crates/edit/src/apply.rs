//! An edit spec applied to a base scene: its `material` ops become region overrides, its
//! `insert` ops objects of their own (tessellated spheres, boxes, meshes placed in world units;
//! lights where they emit), its `relight` ops per-emitter gains.

use crate::material::{brdf_of, MaterialEdit};
use crate::scene::{BaseLights, EditedScene, InsertedObject};
use glam::Vec3;
use i2sdf_data::edit_spec::{EditOp, EditSpec, Shape};
use i2sdf_data::{EditAssets, TriangleMesh};

/// Subdivisions of the icosphere an inserted sphere is tessellated into (20 480 triangles: the
/// facets are under 1 % of the radius off the sphere).
pub const SPHERE_SUBDIVISIONS: u32 = 5;

/// The edited scene of `spec` over `base` (`assets`: the spec's decoded files,
/// [`EditSpec::load_assets`]).
pub fn edited_scene(spec: &EditSpec, assets: &EditAssets, base: BaseLights) -> EditedScene {
    let mut edits = Vec::new();
    let mut inserts = Vec::new();
    for (i, op) in spec.ops.iter().enumerate() {
        match op {
            EditOp::Relight(_) => {}
            EditOp::Material(m) => edits.push(MaterialEdit {
                region: m.region,
                material: m.material.clone(),
                texture: assets.texture(i).cloned(),
            }),
            EditOp::Insert(ins) => {
                let (mesh, sphere) = match &ins.shape {
                    Shape::Sphere { centre, radius } => {
                        let c = Vec3::from(*centre);
                        let mut m = TriangleMesh::unit_icosphere(SPHERE_SUBDIVISIONS);
                        m.positions
                            .iter_mut()
                            .for_each(|p| *p = (c + *radius * Vec3::from(*p)).to_array());
                        (m, Some((c, *radius)))
                    }
                    Shape::Box { lo, hi } => (TriangleMesh::axis_box(*lo, *hi), None),
                    Shape::Mesh(_) => (
                        assets
                            .mesh(i)
                            .cloned()
                            .expect("load_assets decodes every inserted mesh"),
                        None,
                    ),
                };
                inserts.push(InsertedObject {
                    mesh,
                    brdf: brdf_of(&ins.material_values()),
                    emission: ins.is_emitter().then(|| Vec3::from(ins.emission.unwrap_or_default())),
                    sphere,
                });
            }
        }
    }
    EditedScene::new(base, inserts, edits)
}

/// Per-light gains of the spec's `relight` ops (every light of `scene`, inserted ones included,
/// can be selected by its box).
pub fn light_gains(spec: &EditSpec, scene: &EditedScene) -> Vec<Vec3> {
    spec.emitter_gains(scene.light_boxes())
}
