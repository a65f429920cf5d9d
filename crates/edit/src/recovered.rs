//! What stage 2 recovered, as the edit renderer's base: the frozen SDF's surface as a labelled
//! triangle mesh ([`RecoveredSurface`]), the material fields for materials, and each stage-2
//! emitter as an area light over its own triangles with L\[k\].
//!
//! Why a mesh and not stage 2's baked cast (BVH hit refined onto the SDF by a Newton step): a
//! path tracer samples points *on* its emitters and tests the segment to them; on a refined
//! surface those points lie a fraction of a voxel off the surface the shadow ray meets, and the
//! test fails at random. On the mesh, sampled points and hits are the same surface, the labels
//! are per triangle (no F_e query per hit), the normals are the SDF's gradient at the vertices
//! (smoothed where the run's are) interpolated, and a ray costs a BVH traversal alone.

use crate::apply::edited_scene;
use crate::differential::hdr_ldr_images;
use crate::scene::{BaseLights, EditedScene};
use glam::{DVec3, Vec3};
use i2sdf_data::edit_spec::EditSpec;
use i2sdf_data::{Bounds, Camera, DataError, Dataset, EditAssets, ImageF32, Radiometry, TriangleMesh};
use i2sdf_model::emitters::on_recovered_bulb;
use i2sdf_model::images::render_volume_view;
use i2sdf_model::intrinsic_io::IntrinsicFields;
use i2sdf_model::observed::ObservedViews;
use i2sdf_model::renderer::RenderSettings;
use i2sdf_model::{
    emitter_cone_lights, extract_mesh, EmitterTable, FrozenScene, MaterialField, NeuralMaterial, NeuralScene, OpenedRun,
};
use i2sdf_render::{
    AreaLight, Denoiser, Estimator, Integrator, Light, MeshGeometry, PathStart, SphereLight, ViewRender, ViewSettings,
};

/// The frozen SDF's zero level set as the edit renderer's base geometry: the marching-cubes mesh
/// (world units) with, per triangle, label 0 (ordinary) or k + 1 (emitter k: F_e > threshold at
/// its centroid and `index` k there, as [`FrozenScene::cast`] labels hits) and the SDF's gradient
/// at the vertices as shading normals (averaged as the run's are, [`FrozenScene::smoothed_normals`]).
pub struct RecoveredSurface {
    pub geometry: MeshGeometry,
    pub mesh: TriangleMesh,
    /// The triangles of each emitter.
    pub emitter_faces: Vec<Vec<u32>>,
}

/// The recovered surface's marching-cubes resolution (samples along the bounds' longest side)
/// unless asked otherwise: `edit`'s, and that of the relit sets `eval` scores and `report` shows.
pub const MESH_RESOLUTION: usize = 256;

impl RecoveredSurface {
    /// Extracts the surface at `resolution` samples along the bounds' longest side (padded as
    /// stage 2's bake, [`i2sdf_model::sdf_mesh::PAD_FRACTION`]: walls on the bounds stay
    /// closed).
    ///
    /// With `cameras` (the training views), triangles inside an emitter's sphere that none of
    /// them sees are that emitter whatever F_e says, as stage 2 labels its hits
    /// (`stage2.label_unobserved`, [`i2sdf_model::observed`]).
    ///
    /// The labelled mesh is then simplified, each label apart, by at most
    /// [`i2sdf_model::TRACED_SIMPLIFY_VOXELS`] of a voxel: the paths are traced in fewer, larger
    /// triangles (the default room's relit sets in `eval`: 55 s → 40.5 s; the figures are at the
    /// constant).
    pub fn extract(
        frozen: &FrozenScene,
        bounds: &Bounds,
        resolution: usize,
        cameras: Option<&[Camera]>,
    ) -> Result<Self, DataError> {
        let mesh = extract_mesh(frozen.scene, bounds, resolution)?;
        if mesh.faces.is_empty() {
            return Err(DataError::failed(
                "the recovered SDF has no surface inside the scene bounds",
            ));
        }
        let observed = cameras
            .filter(|_| !frozen.emitters.is_empty())
            .map(|c| ObservedViews::new(&MeshGeometry::new(&mesh, vec![0; mesh.faces.len()]), c));
        let vertices: Vec<Vec3> = mesh.positions.iter().map(|p| Vec3::from(*p)).collect();
        // Smoothed as the run's shading normals are (stage 2 fitted the materials with them).
        let normals = frozen.shading_normals(&vertices);
        let centroids: Vec<Vec3> = mesh
            .faces
            .iter()
            .map(|f| f.iter().map(|&i| vertices[i as usize]).sum::<Vec3>() / 3.0)
            .collect();
        let mut labels = vec![0u32; mesh.faces.len()];
        let mut emitter_faces = vec![Vec::new(); frozen.emitters.len()];
        if !frozen.emitters.is_empty() {
            let near: Vec<(usize, usize)> = (0..centroids.len())
                .filter_map(|t| Some((t, frozen.emitters.index(centroids[t].as_dvec3(), frozen.index_margin)?)))
                .collect();
            let points: Vec<Vec3> = near.iter().map(|&(t, _)| centroids[t]).collect();
            let mut prob = vec![0.0; points.len()];
            frozen.emitter_prob(&points, &mut prob);
            for (&(t, k), p) in near.iter().zip(prob) {
                if frozen.emits(k, p, centroids[t], observed.as_ref()) {
                    labels[t] = k as u32 + 1;
                }
            }
        }
        let voxel = i2sdf_model::voxel_size(frozen.scene, bounds, resolution)?;
        let (mesh, labels, kept) =
            i2sdf_render::simplify::simplify_labelled(&mesh, &labels, i2sdf_model::TRACED_SIMPLIFY_VOXELS * voxel);
        let normals: Vec<Vec3> = kept.iter().map(|&v| normals[v as usize]).collect();
        let (mesh, labels, normals) = fitted_bulbs(mesh, labels, normals, frozen.emitters);
        let (mesh, labels, normals) = fitted_panels(mesh, labels, normals, frozen.emitters);
        for (t, &l) in labels.iter().enumerate() {
            if l > 0 {
                emitter_faces[l as usize - 1].push(t as u32);
            }
        }
        Ok(RecoveredSurface {
            geometry: MeshGeometry::with_vertex_normals(&mesh, labels, normals),
            mesh,
            emitter_faces,
        })
    }

    /// The recovered emitters: label 0 ordinary surface, k + 1 emitter k; emitter k its
    /// triangles emitting L\[k\] ([`emitter_light`]; a cone light about its cluster where it has
    /// none), its box its cluster's (centre ± extent / 2).
    pub fn lights(&self, table: &EmitterTable) -> BaseLights {
        let mut base = recovered_lights(table);
        for (k, faces) in self.emitter_faces.iter().enumerate() {
            if !faces.is_empty() {
                base.lights[k] = emitter_light(&self.mesh, faces, table.emission(k));
            }
        }
        base
    }
}

/// Each emitter with a fitted sphere (stage 2's `fit_sphere`: a bulb seen from one side) becomes
/// that sphere, emitting L\[k\] all round as [`FrozenScene::cast`] sees it: the surface within
/// [`i2sdf_model::emitters::BULB_CLEARANCE`] radii of its centre that faces away from the centre
/// (the recovered bulb, seen side and unseen side; a wall or ceiling near it faces the light and
/// stays) is replaced by an icosphere of the fitted radius labelled as the emitter.
fn fitted_bulbs(
    mesh: TriangleMesh,
    labels: Vec<u32>,
    normals: Vec<Vec3>,
    table: &EmitterTable,
) -> (TriangleMesh, Vec<u32>, Vec<Vec3>) {
    let spheres = table.bulbs();
    let unit = TriangleMesh::unit_icosphere(3);
    let stand_ins = spheres
        .iter()
        .map(|&(k, centre, r)| StandIn {
            emitter: k,
            vertices: (unit.positions.iter())
                .map(|p| {
                    let n = Vec3::from(*p).normalize();
                    (centre + r * n, n)
                })
                .collect(),
            faces: unit.faces.clone(),
        })
        .collect();
    let cleared = |p: [Vec3; 3]| {
        let (centroid, n) = ((p[0] + p[1] + p[2]) / 3.0, (p[1] - p[0]).cross(p[2] - p[0]));
        spheres.iter().any(|&(_, c, r)| on_recovered_bulb(c, r, centroid, n))
    };
    swap_emitter_faces(mesh, labels, normals, &cleared, stand_ins)
}

/// Each flat emitter's rectangle ([`i2sdf_model::emitter_panel`]) replaces the recovered panel
/// as [`FrozenScene::cast`] sees it: the triangles in its slab over the rectangle go, two
/// triangles facing the room, labelled as the emitter, come in.
fn fitted_panels(
    mesh: TriangleMesh,
    labels: Vec<u32>,
    normals: Vec<Vec3>,
    table: &EmitterTable,
) -> (TriangleMesh, Vec<u32>, Vec<Vec3>) {
    let panels = table.panels();
    let stand_ins = panels
        .iter()
        .map(|&(k, p)| StandIn {
            emitter: k,
            vertices: p.corners().iter().map(|&c| (c, p.normal())).collect(),
            faces: vec![[0, 1, 2], [0, 2, 3]],
        })
        .collect();
    let cleared = |p: [Vec3; 3]| panels.iter().any(|(_, q)| q.holds((p[0] + p[1] + p[2]) / 3.0));
    swap_emitter_faces(mesh, labels, normals, &cleared, stand_ins)
}

/// An emitter's exact shape for the recovered one: its vertices (position, normal) and faces on
/// them, labelled as emitter `emitter`.
struct StandIn {
    emitter: usize,
    vertices: Vec<(Vec3, Vec3)>,
    faces: Vec<[u32; 3]>,
}

/// The labelled mesh without the faces `cleared` picks (by their corners), with `stand_ins`
/// added; vertex normals follow the vertices.
fn swap_emitter_faces(
    mesh: TriangleMesh,
    labels: Vec<u32>,
    mut normals: Vec<Vec3>,
    cleared: &dyn Fn([Vec3; 3]) -> bool,
    stand_ins: Vec<StandIn>,
) -> (TriangleMesh, Vec<u32>, Vec<Vec3>) {
    if stand_ins.is_empty() {
        return (mesh, labels, normals);
    }
    let TriangleMesh {
        mut positions, faces, ..
    } = mesh;
    let (mut kept_faces, mut kept_labels) = (Vec::with_capacity(faces.len()), Vec::with_capacity(faces.len()));
    for (f, &l) in faces.iter().zip(&labels) {
        if !cleared(f.map(|i| Vec3::from(positions[i as usize]))) {
            kept_faces.push(*f);
            kept_labels.push(l);
        }
    }
    for s in stand_ins {
        let base = positions.len() as u32;
        for (p, n) in s.vertices {
            positions.push(p.to_array());
            normals.push(n);
        }
        kept_faces.extend(s.faces.iter().map(|f| f.map(|i| i + base)));
        kept_labels.extend(std::iter::repeat(s.emitter as u32 + 1).take(s.faces.len()));
    }
    let mesh = TriangleMesh {
        positions,
        faces: kept_faces,
        face_object_ids: None,
    };
    (mesh, kept_labels, normals)
}

/// An emitter whose triangles' area-weighted normals sum to at most this fraction of its area
/// faces every way: a closed surface, such as a bulb (a flat panel sums to 1, a sphere to 0).
pub const CLOSED_EMITTER_NET_NORMAL: f32 = 0.5;
/// A closed emitter whose area is at least this fraction of its bounding sphere's (a sphere
/// 1, a cube 0.64, a 1 m tube of 2 cm radius 0.04) is sampled by that sphere's solid angle.
pub const COMPACT_EMITTER_FILL: f32 = 0.25;

/// The light of one emitter's triangles `faces` of `mesh`, emitting `emission` from their front:
/// a [`SphereLight`] about their bounding sphere when they are closed and compact (a bulb: by
/// area, half the samples land on its far side and the rest are weighed by cos/d²; by the
/// sphere's solid angle, every sample sees the near side with one density), else an
/// [`AreaLight`] (a panel, whose triangles all face one way).
pub fn emitter_light(mesh: &TriangleMesh, faces: &[u32], emission: Vec3) -> Box<dyn Light> {
    let (mut net, mut area) = (Vec3::ZERO, 0.0f32);
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for &f in faces {
        let p = [0, 1, 2].map(|k| mesh.vertex(f as usize, k));
        let c = (p[1] - p[0]).cross(p[2] - p[0]);
        net += 0.5 * c;
        area += 0.5 * c.length();
        for v in p {
            (lo, hi) = (lo.min(v), hi.max(v));
        }
    }
    let centre = 0.5 * (lo + hi);
    let radius = faces
        .iter()
        .flat_map(|&f| [0, 1, 2].map(|k| mesh.vertex(f as usize, k)))
        .map(|v| (v - centre).length())
        .fold(0.0f32, f32::max);
    let closed = net.length() <= CLOSED_EMITTER_NET_NORMAL * area;
    let compact = area >= COMPACT_EMITTER_FILL * 4.0 * std::f32::consts::PI * radius * radius;
    if closed && compact && radius > 0.0 {
        Box::new(SphereLight::new(mesh, faces, centre, emission))
    } else {
        Box::new(AreaLight::new(mesh, faces, emission))
    }
}

/// How an edited view is rendered.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EditSettings {
    /// Paths per pixel.
    pub spp: u32,
    /// Most scattering events per path (Russian roulette from the third).
    pub bounces: u32,
    pub seed: u64,
    /// Denoise each render (every emitter's slot apart, so relighting stays exact):
    /// [`i2sdf_render::denoise`].
    pub denoise: Option<Denoiser>,
}

impl Default for EditSettings {
    fn default() -> Self {
        EditSettings {
            spp: 64,
            bounces: 8,
            seed: 0,
            denoise: None,
        }
    }
}

impl EditSettings {
    /// The integrator's settings for view `view`: the dataset's estimator (`i2sdf synth`'s
    /// path-space regularization after a diffuse bounce: the edits' mirrors and the camera's own
    /// glossy reflections stay sharp; the bulb's caustics through glossy surfaces lose their
    /// fireflies, as in the images the relit ground truth was rendered with).
    pub fn view_settings(&self, view: u32) -> ViewSettings {
        ViewSettings {
            spp: self.spp,
            seed: self.seed,
            view,
            integrator: Integrator {
                estimator: Estimator::DATASET,
                max_depth: self.bounces,
            },
        }
    }
}

/// The recovered emitters as cone lights (without a surface to sample): label 0 ordinary surface, k + 1 emitter k (the
/// frozen scene's labels), each emitter's box its cluster's (centre ± extent / 2).
pub fn recovered_lights(table: &EmitterTable) -> BaseLights {
    let mut emitter_of_label = vec![None];
    emitter_of_label.extend((0..table.len() as u32).map(Some));
    let boxes = table
        .emitters
        .iter()
        .map(|e| {
            let (c, h) = (DVec3::from_array(e.centre), 0.5 * DVec3::from_array(e.extent));
            ((c - h).as_vec3(), (c + h).as_vec3())
        })
        .collect();
    BaseLights {
        lights: emitter_cone_lights(table),
        emitter_of_label,
        boxes,
    }
}

/// A run's recovered scene, ready to render edits of: its frozen stage-1 fields with the
/// emitter table, the surface mesh, and the material fields.
pub struct RecoveredScene<'a> {
    pub frozen: FrozenScene<'a>,
    pub surface: RecoveredSurface,
    pub material: &'a MaterialField,
    pub radiometry: Radiometry,
}

impl<'a> RecoveredScene<'a> {
    /// `emitter_threshold`: the F_e threshold stage 2 labelled its emitters with; the surface is
    /// extracted over `bounds` (world units) at `resolution` samples along the longest side;
    /// `cameras`: the training views, where stage 2 labelled unobserved emitter surface
    /// (`stage2.label_unobserved`).
    pub fn new(
        scene: &'a NeuralScene,
        fields: &'a IntrinsicFields,
        emitter_threshold: f32,
        bounds: &Bounds,
        resolution: usize,
        cameras: Option<&[Camera]>,
    ) -> Result<Self, DataError> {
        let mut frozen = FrozenScene::new(scene, &fields.emitters, fields.radiometry);
        frozen.emitter_threshold = emitter_threshold;
        let surface = RecoveredSurface::extract(&frozen, bounds, resolution, cameras)?;
        Ok(RecoveredScene {
            frozen,
            surface,
            material: &fields.material,
            radiometry: fields.radiometry,
        })
    }

    /// The recovered scene of a trained run's stage 2 (refused without one), with its emitter
    /// threshold and, where it labelled by them, the training views of `dataset`; the surface
    /// over the dataset's bounds at `resolution`.
    pub fn of_run(run: &'a OpenedRun, dataset: &Dataset, resolution: usize) -> Result<Self, DataError> {
        let observers = run.observers(dataset);
        Self::new(
            &run.scene,
            run.stage2()?,
            run.config.emitter_threshold,
            &dataset.bounds,
            resolution,
            observers.as_deref(),
        )
    }

    /// The edited scene of `spec` over this one.
    pub fn edited(&self, spec: &EditSpec, assets: &EditAssets) -> EditedScene {
        edited_scene(spec, assets, self.surface.lights(self.frozen.emitters))
    }

    /// Renders view `view` of `edited`: full path tracing (no radiance-field shortcut), every
    /// emitter's share in its own slot. The camera is world-space.
    pub fn render(
        &self,
        edited: &EditedScene,
        camera: &Camera,
        settings: &EditSettings,
        view: u32,
        on_row: &(dyn Fn() + Sync),
    ) -> ViewRender {
        let nm = NeuralMaterial::new(self.material, &self.frozen);
        let mut render = edited.render(
            &self.surface.geometry,
            &nm,
            None,
            camera,
            &settings.view_settings(view),
            on_row,
        );
        if let Some(denoiser) = &settings.denoise {
            denoiser.apply(&mut render);
        }
        render
    }
}

impl RecoveredScene<'_> {
    /// Stage 1's radiance field seen from `camera` (display values, as the dataset's images): the
    /// captured image of [`crate::differential`].
    pub fn captured(&self, camera: &Camera, settings: &RenderSettings) -> ImageF32 {
        render_volume_view(self.frozen.scene, settings, camera).rgb
    }

    /// Traces `paths` through `edited` ([`EditedScene::trace`]) with the integrator of
    /// `settings`.
    pub fn trace(&self, edited: &EditedScene, settings: &EditSettings, paths: &mut [PathStart], radiance: &mut [Vec3]) {
        let nm = NeuralMaterial::new(self.material, &self.frozen);
        let integrator = settings.view_settings(0).integrator;
        edited.trace(&self.surface.geometry, &nm, &integrator, paths, radiance);
    }
}

/// A render's image with per-light gains: linear HDR (image units) and, tone-mapped as the
/// dataset's images, LDR.
pub fn edit_images(v: &ViewRender, gains: &[Vec3], radiometry: &Radiometry) -> (ImageF32, ImageF32) {
    hdr_ldr_images(&v.hdr(gains), v.width, v.height, radiometry)
}

#[cfg(test)]
mod tests {
    use super::*;
    use i2sdf_render::Visibility;

    /// A panel: the recovered surface in its slab over the rectangle goes (a bulge 3 cm below
    /// it, labelled or not), the ceiling beside it and a lamp 10 cm below stay, and the
    /// rectangle comes in as two triangles labelled as the emitter, facing the room.
    #[test]
    fn a_panel_replaces_the_recovered_one() {
        let tri = |m: &mut TriangleMesh, a: [f32; 3], b: [f32; 3], c: [f32; 3]| {
            let base = m.positions.len() as u32;
            m.positions.extend([a, b, c]);
            m.faces.push([base, base + 1, base + 2]);
        };
        let mut mesh = TriangleMesh {
            positions: Vec::new(),
            faces: Vec::new(),
            face_object_ids: None,
        };
        tri(&mut mesh, [0.2, 2.57, 0.2], [0.4, 2.57, 0.2], [0.3, 2.57, 0.4]); // the bulge
        tri(&mut mesh, [0.3, 2.58, 0.3], [0.5, 2.58, 0.3], [0.4, 2.58, 0.5]); // labelled
        tri(&mut mesh, [1.2, 2.6, 0.2], [1.4, 2.6, 0.2], [1.3, 2.6, 0.4]); // the ceiling beside
        tri(&mut mesh, [0.5, 2.5, 0.2], [0.6, 2.5, 0.2], [0.55, 2.5, 0.4]); // a lamp below
        let labels = vec![0, 1, 0, 0];
        let normals = vec![-Vec3::Y; mesh.positions.len()];
        let bounds = [[0.0, 2.58, 0.0], [1.0, 2.62, 0.8]];
        let panel = i2sdf_model::emitter_panel::Panel::of_box(bounds, [0.5, 1.3, 0.4], 0.02);
        let table = EmitterTable::new(
            vec![i2sdf_model::emitters::Emitter {
                centre: [0.5, 2.6, 0.4],
                extent: [1.0, 0.04, 0.8],
                radius: 0.65,
                points: 10,
                sphere: None,
                bounds: Some(bounds),
                panel,
            }],
            &[[5.0; 3]],
        );
        let (out, labels, normals) = fitted_panels(mesh, labels, normals, &table);
        assert_eq!(
            labels,
            [0, 0, 1, 1],
            "the ceiling and the lamp stayed, the rectangle came"
        );
        assert_eq!(normals.len(), out.positions.len());
        for f in &out.faces[2..] {
            let p = f.map(|i| Vec3::from(out.positions[i as usize]));
            assert!((p[1] - p[0]).cross(p[2] - p[0]).y < 0.0, "faces the room below");
            assert!(p.iter().all(|q| (q.y - 2.6).abs() < 1e-6));
        }
    }

    /// A bulb with a fitted sphere: the recovered bulb (a coarse ball about the centre, larger
    /// than the sphere, partly labelled) goes, a wall within the clearance that faces the bulb
    /// stays, and the sphere comes in whole with the emitter's label and radial normals.
    #[test]
    fn a_fitted_bulb_replaces_the_recovered_one() {
        let c = Vec3::new(0.5, 1.8, -0.4);
        let r = 0.1;
        let mut mesh = TriangleMesh::unit_icosphere(1);
        for p in &mut mesh.positions {
            *p = (c + 0.13 * Vec3::from(*p)).to_array();
        }
        let blob = mesh.faces.len();
        // A wall 0.15 from the centre, facing it (normal −x).
        let base = mesh.positions.len() as u32;
        for (y, z) in [(-0.2, -0.2), (0.2, -0.2), (0.2, 0.2), (-0.2, 0.2)] {
            mesh.positions.push((c + Vec3::new(0.15, y, z)).to_array());
        }
        mesh.faces.push([base, base + 2, base + 1]);
        mesh.faces.push([base, base + 3, base + 2]);
        for f in &mesh.faces[blob..] {
            let p = f.map(|i| Vec3::from(mesh.positions[i as usize]));
            assert!((p[1] - p[0]).cross(p[2] - p[0]).x < 0.0, "the wall faces the bulb");
        }
        let labels: Vec<u32> = (0..mesh.faces.len())
            .map(|t| if t < blob && t % 2 == 0 { 1 } else { 0 })
            .collect();
        let normals = vec![Vec3::Y; mesh.positions.len()];
        let table = EmitterTable::new(
            vec![i2sdf_model::emitters::Emitter {
                centre: c.as_dvec3().to_array(),
                extent: [0.2; 3],
                radius: 0.15,
                points: 10,
                sphere: Some([c.x as f64, c.y as f64, c.z as f64, r as f64]),
                bounds: None,
                panel: None,
            }],
            &[[5.0; 3]],
        );
        let (out, labels, normals) = fitted_bulbs(mesh, labels, normals, &table);
        let sphere = TriangleMesh::unit_icosphere(3).faces.len();
        assert_eq!(out.faces.len(), 2 + sphere, "the ball went, the wall stayed");
        assert_eq!(&labels[..2], &[0, 0]);
        assert!(labels[2..].iter().all(|&l| l == 1));
        assert_eq!(normals.len(), out.positions.len());
        for f in &out.faces[2..] {
            for &i in f {
                let p = Vec3::from(out.positions[i as usize]);
                assert!(((p - c).length() - r).abs() < 1e-5);
                assert!((normals[i as usize] - (p - c) / r).length() < 1e-4);
            }
        }
    }

    /// Whether the light's samples (from either side, the first that carries light) are
    /// directions whose first hit decides, rather than points on the emitter.
    fn samples_by_direction(light: &dyn Light) -> bool {
        let s = [3.0f32, -3.0]
            .into_iter()
            .flat_map(|x| (0..16).map(move |i| (x, i as f32 / 16.0)))
            .find_map(|(x, u)| light.sample(Vec3::new(x, 0.5, 0.2), [u, 0.6, 0.2]))
            .unwrap();
        matches!(s.visibility, Visibility::FirstHit(_))
    }

    /// A bulb (a closed, compact mesh) is sampled by its sphere's solid angle; a panel, half a
    /// bulb and a long thin tube by area.
    #[test]
    fn bulbs_are_sampled_by_solid_angle_and_the_rest_by_area() {
        let mut bulb = TriangleMesh::unit_icosphere(2);
        bulb.positions
            .iter_mut()
            .for_each(|p| *p = (0.1 * Vec3::from(*p)).to_array());
        let all: Vec<u32> = (0..bulb.faces.len() as u32).collect();
        assert!(samples_by_direction(emitter_light(&bulb, &all, Vec3::ONE).as_ref()));
        let upper: Vec<u32> = all
            .iter()
            .copied()
            .filter(|&f| (0..3).all(|k| bulb.vertex(f as usize, k).x >= -1e-6))
            .collect();
        assert!(!samples_by_direction(emitter_light(&bulb, &upper, Vec3::ONE).as_ref()));
        let mut panel = TriangleMesh::default();
        panel.positions = vec![[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]];
        panel.faces = vec![[0, 1, 2], [0, 2, 3]];
        assert!(!samples_by_direction(
            emitter_light(&panel, &[0, 1], Vec3::ONE).as_ref()
        ));
        let mut tube = TriangleMesh::unit_icosphere(2);
        tube.positions
            .iter_mut()
            .for_each(|p| *p = [0.02 * p[0], 0.5 * p[1], 0.02 * p[2]]);
        assert!(!samples_by_direction(emitter_light(&tube, &all, Vec3::ONE).as_ref()));
    }
}
