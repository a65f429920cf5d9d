//! `i2sdf export`: the recovered room as a glTF 2.0 scene that Blender, three.js or a game engine
//! opens — the surface (marching cubes of the frozen SDF, simplified to a face budget), the
//! material fields baked into textures over a UV atlas (or, with `texture_size` 0, Kd as vertex
//! colours with Ks and ρ grouped into a few GGX materials; [`material_map`] says exactly how they
//! map onto glTF's metallic-roughness model and `KHR_materials_specular`), each recovered emitter
//! as an emissive material with L\[k\] in the input images' linear units
//! (`KHR_materials_emissive_strength`) and optionally as a punctual light, and the dataset's
//! cameras. A stage-1 run exports its surface with the radiance field's colour, unlit.
//!
//! Data flows: trained run → [`build`] ([`material_scene`], then glTF's axes: a [`SceneModel`])
//! → [`gltf_write`].

pub mod atlas;
pub mod axes;
pub mod bake;
pub mod cluster;
pub mod gltf_write;
pub mod material_map;
pub mod material_scene;
pub mod scene_model;

pub use axes::UpAxis;
pub use gltf_write::Container;
pub use material_scene::{MaterialLoss, TextureSummary};
pub use scene_model::{CameraDesc, LightDesc, MaterialDesc, PrimitiveDesc, SceneModel};

use glam::{DMat4, Vec3};
use i2sdf_data::{DataError, Dataset};
use i2sdf_edit::{RecoveredScene, RecoveredSurface};
use i2sdf_model::{EmitterTable, FrozenScene, OpenedRun};

/// What to export and how finely.
#[derive(Clone, Debug, PartialEq)]
pub struct ExportOptions {
    /// Marching-cubes samples along the scene bounds' longest side.
    pub resolution: usize,
    /// Face budget of the simplified surface.
    pub max_faces: usize,
    /// Largest distance (world units) the simplification may move the surface.
    pub max_error: f32,
    /// Most GGX materials the faces' (Ks, ρ) are grouped into.
    pub materials: usize,
    /// The world axis that becomes glTF's +Y (`None`: read off the cameras).
    pub up: Option<UpAxis>,
    /// Width of the texture atlas the material fields are baked into; 0: vertex colours and K
    /// materials instead.
    pub texture_size: u32,
    /// Each emitter also as a punctual light (`KHR_lights_punctual`).
    pub lights: bool,
}

impl Default for ExportOptions {
    fn default() -> Self {
        ExportOptions {
            resolution: 256,
            max_faces: 200_000,
            max_error: 0.005,
            materials: 8,
            up: None,
            texture_size: 2048,
            lights: false,
        }
    }
}

impl ExportOptions {
    /// Every value in range, named by its flag.
    pub fn check(&self) -> Result<(), DataError> {
        let bad =
            |flag: &str, v: String, range: &str| Err(DataError::invalid(format!("{flag} {v}: must be in {range}")));
        if !(16..=2048).contains(&self.resolution) {
            return bad("--resolution", self.resolution.to_string(), "[16, 2048]");
        }
        if !(12..=50_000_000).contains(&self.max_faces) {
            return bad("--max-faces", self.max_faces.to_string(), "[12, 50000000]");
        }
        if !(self.max_error.is_finite() && self.max_error >= 0.0 && self.max_error <= 1.0) {
            return bad("--max-error", self.max_error.to_string(), "[0, 1] (world units)");
        }
        if !(1..=64).contains(&self.materials) {
            return bad("--materials", self.materials.to_string(), "[1, 64]");
        }
        if self.texture_size != 0 && !(64..=8192).contains(&self.texture_size) {
            return bad(
                "--texture-size",
                self.texture_size.to_string(),
                "0 (vertex colours) or [64, 8192]",
            );
        }
        Ok(())
    }
}

/// What [`build`] made, for the command's summary.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ExportSummary {
    /// `material` (stage 2's materials and emitters) or `geometry` (a stage-1 run: radiance as
    /// vertex colour).
    pub stage: &'static str,
    pub up: &'static str,
    /// The angle between the chosen up axis and the cameras' mean up (degrees), where it was
    /// read off them.
    pub up_from_cameras_deg: Option<f64>,
    pub faces_extracted: usize,
    pub faces: usize,
    pub vertices: usize,
    pub materials: usize,
    pub emitters: usize,
    pub cameras: usize,
    pub lights: usize,
    /// The atlas, where the materials were baked into textures.
    pub textures: Option<TextureSummary>,
    pub loss: Option<MaterialLoss>,
    pub notes: Vec<String>,
}

/// The exported scene of `run` (its stage 2 where it has one) over `dataset`'s bounds and cameras.
pub fn build(
    run: &OpenedRun,
    dataset: &Dataset,
    opts: &ExportOptions,
) -> Result<(SceneModel, ExportSummary), DataError> {
    opts.check()?;
    let cameras: Vec<_> = dataset.frames.iter().collect();
    let (up, up_angle) = match opts.up {
        Some(u) => (u, None),
        None => {
            let cams: Vec<_> = cameras.iter().map(|f| f.camera.clone()).collect();
            let (u, a) = UpAxis::from_cameras(&cams)?;
            (u, Some(a))
        }
    };
    let mut notes = Vec::new();
    let empty = EmitterTable::new(Vec::new(), &[]);
    let (mut model, faces_extracted, emitters, loss, textures) = match run.fields.as_ref() {
        Some(_) => {
            let rec = RecoveredScene::of_run(run, dataset, opts.resolution)?;
            let faces = rec.surface.mesh.faces.len();
            let (model, loss, textures) = material_scene::material_scene(&rec, opts)?;
            (model, faces, rec.frozen.emitters.len(), Some(loss), textures)
        }
        None => {
            if opts.lights {
                notes.push("a stage-1 run has no emitters: no lights exported".into());
            }
            let frozen = FrozenScene::new(&run.scene, &empty, dataset.radiometry);
            let surface = RecoveredSurface::extract(&frozen, &dataset.bounds, opts.resolution, None)?;
            let faces = surface.mesh.faces.len();
            (
                material_scene::radiance_scene(&frozen, &surface, opts),
                faces,
                0,
                None,
                None,
            )
        }
    };
    // world → glTF axes
    let r = up.to_gltf();
    let rf = r.as_mat3();
    for p in &mut model.positions {
        *p = (rf * Vec3::from(*p)).to_array();
    }
    for n in &mut model.normals {
        *n = (rf * Vec3::from(*n)).to_array();
    }
    for l in &mut model.lights {
        l.position = (rf * Vec3::from(l.position)).to_array();
        l.direction = l.direction.map(|d| (rf * Vec3::from(d)).to_array());
    }
    let r4 = DMat4::from_mat3(r);
    let mut distorted = 0;
    let mut off_centre = 0;
    for f in &cameras {
        let c = &f.camera;
        if !c.lens.is_pinhole() {
            distorted += 1;
        }
        if (c.cx - c.width as f64 / 2.0).abs() > 0.5
            || (c.cy - c.height as f64 / 2.0).abs() > 0.5
            || (c.fx - c.fy).abs() > 1e-3 * c.fy
        {
            off_centre += 1;
        }
        model.cameras.push(CameraDesc {
            name: format!("{}_{}", f.split.name(), f.name),
            yfov: (2.0 * (c.height as f64 / (2.0 * c.fy)).atan()) as f32,
            aspect_ratio: (c.width as f64 / c.height as f64) as f32,
            znear: 0.01,
            matrix: (r4 * c.opengl_c2w()).as_mat4().to_cols_array(),
        });
    }
    if distorted > 0 {
        notes.push(format!(
            "{distorted} camera(s) have lens distortion, which glTF cameras cannot carry: they are written as pinholes"
        ));
    }
    if off_centre > 0 {
        notes.push(format!(
            "{off_centre} camera(s) have an off-centre principal point or fx ≠ fy, which glTF cameras cannot carry (written centred, from fy)"
        ));
    }
    model.extras = serde_json::json!({
        "generator": "i2sdf export",
        "run": run.dir.root.display().to_string(),
        "units": "the dataset's world units",
        "up_axis": up.name(),
        "emission": "emissiveFactor × KHR_materials_emissive_strength = L[k], linear, in the input images' units (as RUN/emitters.json's emission)",
        "materials": if textures.is_some() {
            "baseColorTexture = Kd (sRGB); metallicRoughnessTexture G = ρ (α = ρ²), B = metallic 0; KHR_materials_specular: specularTexture A = F90 = min(lum(Ks)/0.04, 1), specularColorTexture × specularColorFactor = Ks / (0.04 · F90), so F0 = Ks"
        } else {
            "COLOR_0 = Kd (linear); metallic 0; roughness = ρ (α = ρ²); KHR_materials_specular: specularFactor = min(lum(Ks)/0.04, 1), specularColorFactor = Ks / (0.04 · specularFactor), so F0 = Ks"
        },
        "lights": "KHR_lights_punctual (when exported), one per emitter with the emitter's flux π·L·A: a spot (outer cone π/2) of I = 3·L·A/2 along a flat emitter's normal, else a point light of I = L·A/4; written as 683·I candela (683 lm/W: Blender's convention, which takes emissive strength as radiance), for viewers that light by lights only (a path tracer lights by the emissive surfaces; a light inside a closed emitter is shadowed by it)",
    });
    let summary = ExportSummary {
        stage: if run.fields.is_some() { "material" } else { "geometry" },
        up: up.name(),
        up_from_cameras_deg: up_angle,
        faces_extracted,
        faces: model.faces(),
        vertices: model.positions.len(),
        materials: model.materials.len(),
        emitters,
        cameras: model.cameras.len(),
        lights: model.lights.len(),
        textures,
        loss,
        notes,
    };
    Ok((model, summary))
}

/// Writes `model` to `path` (`.glb` or `.gltf`) atomically; returns the file's size.
pub fn write(path: &std::path::Path, model: &SceneModel) -> Result<u64, DataError> {
    let container = Container::of_path(path)
        .ok_or_else(|| DataError::invalid(format!("--out {}: must end in .glb or .gltf", path.display())))?;
    let bytes = gltf_write::encode(model, container);
    i2sdf_data::imageio::write_bytes_atomic(path, &bytes)?;
    Ok(bytes.len() as u64)
}
