//! The edited scene as the shared path tracer sees it: base geometry ∪ inserts
//! ([`UnionGeometry`]), base material with overrides ∪ insert materials ([`EditedMaterial`]), and
//! one light set — the base's emitters (for the frozen SDF: one cone light per emitter cluster
//! with L\[k\]), then every emitting insert (a [`SphereLight`] for spheres, an [`AreaLight`] for
//! boxes and meshes). Relighting is per emitter: the integrator keeps each emitter's share of a
//! pixel apart ([`i2sdf_render::ViewRender::hdr`]), so the relit image is Σ_k g_k ⊙ L_k with the
//! gains of the spec's `relight` ops, exact and from one render.

use crate::geometry::UnionGeometry;
use crate::material::{EditedMaterial, MaterialEdit};
use glam::Vec3;
use i2sdf_data::{Camera, TriangleMesh};
use i2sdf_render::{
    render_view, AreaLight, Geometry, GgxBrdf, Integrator, Light, LightSet, Material, MeshGeometry, PathStart,
    RadianceField, Scene, SphereLight, ViewRender, ViewSettings,
};

/// An inserted object, in world units.
pub struct InsertedObject {
    pub mesh: TriangleMesh,
    pub brdf: GgxBrdf,
    /// Radiance it emits (linear image units), making it a light.
    pub emission: Option<Vec3>,
    /// Centre and radius when the object is a (tessellated) sphere: sampled by solid angle.
    pub sphere: Option<(Vec3, f32)>,
}

/// The base scene's side of the light set: its emitters, which of its surface labels emit which
/// emitter, and each emitter's bounding box (world units: what a `relight` op's `at` selects by).
pub struct BaseLights {
    pub lights: Vec<Box<dyn Light>>,
    /// `emitter_of_label[l]`: the emitter of base label `l`; its length is the number of base
    /// labels (inserts are labelled after them).
    pub emitter_of_label: Vec<Option<u32>>,
    pub boxes: Vec<(Vec3, Vec3)>,
}

pub struct EditedScene {
    first_insert_label: u32,
    inserts: Option<MeshGeometry>,
    insert_brdfs: Vec<GgxBrdf>,
    edits: Vec<MaterialEdit>,
    lights: LightSet,
    boxes: Vec<(Vec3, Vec3)>,
    base_emitters: usize,
}

impl EditedScene {
    pub fn new(base: BaseLights, inserts: Vec<InsertedObject>, edits: Vec<MaterialEdit>) -> Self {
        assert_eq!(base.lights.len(), base.boxes.len(), "one box per base emitter");
        let first_insert_label = base.emitter_of_label.len() as u32;
        let base_emitters = base.lights.len();
        let (mut lights, mut labels, mut boxes) = (base.lights, base.emitter_of_label, base.boxes);
        let mut meshes = Vec::new();
        let mut face_labels = Vec::new();
        let mut insert_brdfs = Vec::new();
        for (j, o) in inserts.into_iter().enumerate() {
            let label = first_insert_label + j as u32;
            face_labels.extend(std::iter::repeat_n(label, o.mesh.faces.len()));
            insert_brdfs.push(o.brdf);
            match o.emission {
                Some(le) => {
                    let faces: Vec<u32> = (0..o.mesh.faces.len() as u32).collect();
                    let light: Box<dyn Light> = match o.sphere {
                        Some((c, _)) => Box::new(SphereLight::new(&o.mesh, &faces, c, le)),
                        None => Box::new(AreaLight::new(&o.mesh, &faces, le)),
                    };
                    labels.push(Some(lights.len() as u32));
                    lights.push(light);
                    boxes.push(mesh_box(&o.mesh));
                }
                None => labels.push(None),
            }
            meshes.push(o.mesh);
        }
        let inserts = (!meshes.is_empty()).then(|| MeshGeometry::new(&TriangleMesh::concat(&meshes), face_labels));
        EditedScene {
            first_insert_label,
            inserts,
            insert_brdfs,
            edits,
            lights: LightSet::new(lights, labels),
            boxes,
            base_emitters,
        }
    }

    /// Every emitter's bounding box (base emitters first, then emitting inserts), in light order.
    pub fn light_boxes(&self) -> &[(Vec3, Vec3)] {
        &self.boxes
    }

    pub fn lights(&self) -> usize {
        self.lights.len()
    }

    pub fn base_emitters(&self) -> usize {
        self.base_emitters
    }

    /// The integrator's scene of this edit over a base, handed to `f`.
    fn with_scene<R>(
        &self,
        base_geometry: &dyn Geometry,
        base_material: &dyn Material,
        radiance_field: Option<&dyn RadianceField>,
        f: impl FnOnce(&Scene) -> R,
    ) -> R {
        let geometry = UnionGeometry {
            base: base_geometry,
            inserts: self.inserts.as_ref(),
        };
        let material = EditedMaterial {
            base: base_material,
            first_insert_label: self.first_insert_label,
            edits: &self.edits,
            inserts: &self.insert_brdfs,
        };
        f(&Scene {
            geometry: &geometry,
            material: &material,
            lights: &self.lights,
            radiance_field,
        })
    }

    /// Traces arbitrary paths through the edited scene (no radiance field), adding light k's
    /// share of path i to `radiance[i · lights() + k]`: the integrator's own interface, for
    /// rays that no camera makes (the mirror check's reflected rays).
    pub fn trace(
        &self,
        base_geometry: &dyn Geometry,
        base_material: &dyn Material,
        integrator: &Integrator,
        paths: &mut [PathStart],
        radiance: &mut [Vec3],
    ) {
        self.with_scene(base_geometry, base_material, None, |scene| {
            integrator.trace(scene, paths, radiance)
        })
    }

    /// Renders one view of the edited scene through the shared integrator (`settings` says spp,
    /// seed and bounces). A radiance field, where given, answers for paths that reach an
    /// ordinary surface after `max_depth` scattering events (its part has the last slot).
    pub fn render(
        &self,
        base_geometry: &dyn Geometry,
        base_material: &dyn Material,
        radiance_field: Option<&dyn RadianceField>,
        camera: &Camera,
        settings: &ViewSettings,
        on_row: &(dyn Fn() + Sync),
    ) -> ViewRender {
        self.with_scene(base_geometry, base_material, radiance_field, |scene| {
            render_view(scene, camera, settings, on_row)
        })
    }
}

/// The axis-aligned box of a mesh's vertices.
pub fn mesh_box(mesh: &TriangleMesh) -> (Vec3, Vec3) {
    mesh.positions
        .iter()
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(Vec3::from(*p)), hi.max(Vec3::from(*p)))
        })
}
