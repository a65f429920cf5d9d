//! `i2sdf export`: the recovered room as a glTF 2.0 scene that Blender, three.js or a game engine
//! opens — the surface (marching cubes of the frozen SDF, simplified to a face budget), the
//! material fields' Kd as vertex colours with Ks and ρ grouped into a few GGX materials
//! ([`material_map`] says exactly how they map onto glTF's metallic-roughness model and
//! `KHR_materials_specular`), each recovered emitter as an emissive material with L\[k\] in the
//! input images' linear units (`KHR_materials_emissive_strength`), and the dataset's cameras. A
//! stage-1 run exports its surface with the radiance field's colour, unlit.
//!
//! Data flows: trained run → [`build`] (a [`SceneModel`] in glTF's axes) → [`gltf_write`].

pub mod axes;
pub mod cluster;
pub mod gltf_write;
pub mod material_map;
pub mod scene_model;
pub mod simplify;

pub use axes::UpAxis;
pub use gltf_write::Container;
pub use scene_model::{CameraDesc, MaterialDesc, PrimitiveDesc, SceneModel};

use glam::{DMat4, Vec3};
use i2sdf_data::{DataError, Dataset};
use i2sdf_edit::{RecoveredScene, RecoveredSurface};
use i2sdf_model::{EmitterTable, FrozenScene, NeuralMaterial, OpenedRun};
use i2sdf_render::{GgxBrdf, Material, SurfacePoint};
use material_map::GltfPbr;

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
}

impl Default for ExportOptions {
    fn default() -> Self {
        ExportOptions {
            resolution: 256,
            max_faces: 200_000,
            max_error: 0.005,
            materials: 8,
            up: None,
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
        Ok(())
    }
}

/// What vertex colours and K materials lose against the material fields, area-weighted over the
/// exported faces.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct VertexColourLoss {
    /// PSNR (dB) of the faces' Kd as exported (the mean of their vertices' colours) against the
    /// field's Kd at the faces' centroids.
    pub kd_psnr: f64,
    /// RMS difference of each face's Ks (rgb) from its material's.
    pub ks_rms: f64,
    /// RMS difference of each face's ρ from its material's.
    pub rho_rms: f64,
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
    pub loss: Option<VertexColourLoss>,
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
    let (mut model, faces_extracted, emitters, loss) = match run.fields.as_ref() {
        Some(_) => {
            let rec = RecoveredScene::of_run(run, dataset, opts.resolution)?;
            let faces = rec.surface.mesh.faces.len();
            let (model, loss) = material_scene(&rec, opts)?;
            (model, faces, rec.frozen.emitters.len(), Some(loss))
        }
        None => {
            let frozen = FrozenScene::new(&run.scene, &empty, dataset.radiometry);
            let surface = RecoveredSurface::extract(&frozen, &dataset.bounds, opts.resolution, None)?;
            let faces = surface.mesh.faces.len();
            (radiance_scene(&frozen, &surface, opts), faces, 0, None)
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
        "materials": "COLOR_0 = Kd (linear); metallic 0; roughness = ρ (α = ρ²); KHR_materials_specular: specularFactor = min(lum(Ks)/0.04, 1), specularColorFactor = Ks / (0.04 · specularFactor), so F0 = Ks",
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
        loss,
        notes,
    };
    Ok((model, summary))
}

/// The surface's faces grouped (ordinary surface, then each emitter), simplified to the budget,
/// and the vertices they keep (world units) with the SDF's normals there.
fn simplified(
    frozen: &FrozenScene,
    surface: &RecoveredSurface,
    opts: &ExportOptions,
) -> (Vec<Vec3>, Vec<Vec3>, Vec<Vec<[u32; 3]>>) {
    let mesh = &surface.mesh;
    let mut in_emitter = vec![false; mesh.faces.len()];
    for f in surface.emitter_faces.iter().flatten() {
        in_emitter[*f as usize] = true;
    }
    let mut groups = vec![mesh
        .faces
        .iter()
        .zip(&in_emitter)
        .filter(|(_, &e)| !e)
        .map(|(f, _)| *f)
        .collect::<Vec<_>>()];
    groups.extend(
        surface
            .emitter_faces
            .iter()
            .map(|fs| fs.iter().map(|&f| mesh.faces[f as usize]).collect()),
    );
    let groups = simplify::simplify_groups(&mesh.positions, &groups, opts.max_faces, opts.max_error);
    let (kept, groups) = simplify::compact(mesh.positions.len(), &groups);
    let vertices: Vec<Vec3> = kept.iter().map(|&v| Vec3::from(mesh.positions[v as usize])).collect();
    let normals = frozen
        .sdf_gradient(&vertices)
        .into_iter()
        .map(|(_, g)| g.normalize_or_zero())
        .collect();
    (vertices, normals, groups)
}

fn triangle_area(p: &[Vec3], f: [u32; 3]) -> f32 {
    let [a, b, c] = f.map(|i| p[i as usize]);
    0.5 * (b - a).cross(c - a).length()
}

/// Stage 2's scene: Kd per vertex, the faces' (Ks, ρ) in K materials, one emissive primitive per
/// emitter.
fn material_scene(rec: &RecoveredScene, opts: &ExportOptions) -> Result<(SceneModel, VertexColourLoss), DataError> {
    let (vertices, normals, groups) = simplified(&rec.frozen, &rec.surface, opts);
    let nm = NeuralMaterial::new(rec.material, &rec.frozen);
    let eval = |points: &[Vec3], normals: &[Vec3]| -> Vec<GgxBrdf> {
        let sp: Vec<SurfacePoint> = points
            .iter()
            .zip(normals)
            .map(|(&position, &normal)| SurfacePoint {
                position,
                normal,
                surface: 0,
                prim: 0,
            })
            .collect();
        let mut out = vec![GgxBrdf::new(Vec3::ZERO, Vec3::ZERO, 1.0); sp.len()];
        nm.eval_batch(&sp, &mut out);
        out
    };
    let brdf = eval(&vertices, &normals);
    let colors: Vec<[f32; 3]> = brdf
        .iter()
        .map(|b| b.kd.clamp(Vec3::ZERO, Vec3::ONE).to_array())
        .collect();

    // ordinary faces: (Ks, ρ) per face, clustered
    let surface_faces = &groups[0];
    let areas: Vec<f32> = surface_faces.iter().map(|&f| triangle_area(&vertices, f)).collect();
    let features: Vec<f32> = surface_faces
        .iter()
        .flat_map(|f| {
            let mut ks = Vec3::ZERO;
            let mut rho = 0.0;
            for &v in f {
                ks += brdf[v as usize].ks / 3.0;
                rho += brdf[v as usize].rho / 3.0;
            }
            [ks.x, ks.y, ks.z, rho]
        })
        .collect();
    let (labels, centres) = cluster::kmeans(&features, 4, &areas, opts.materials);

    // what the vertex colours and the K materials lose, at the faces' centroids
    let centroids: Vec<Vec3> = surface_faces
        .iter()
        .map(|f| f.iter().map(|&v| vertices[v as usize]).sum::<Vec3>() / 3.0)
        .collect();
    let face_normals: Vec<Vec3> = surface_faces
        .iter()
        .map(|f| f.iter().map(|&v| normals[v as usize]).sum::<Vec3>().normalize_or_zero())
        .collect();
    let at_centroid = eval(&centroids, &face_normals);
    let (mut kd_se, mut ks_se, mut rho_se, mut wsum) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for (i, f) in surface_faces.iter().enumerate() {
        let w = areas[i] as f64;
        let kd_vertex = f.iter().map(|&v| Vec3::from(colors[v as usize])).sum::<Vec3>() / 3.0;
        let kd_field = at_centroid[i].kd.clamp(Vec3::ZERO, Vec3::ONE);
        kd_se += w * (kd_vertex - kd_field).length_squared() as f64 / 3.0;
        let c = &centres[labels[i] as usize];
        let row = &features[i * 4..i * 4 + 4];
        ks_se += w * (0..3).map(|j| ((row[j] - c[j]) as f64).powi(2)).sum::<f64>() / 3.0;
        rho_se += w * ((row[3] - c[3]) as f64).powi(2);
        wsum += w;
    }
    let wsum = wsum.max(f64::MIN_POSITIVE);
    let loss = VertexColourLoss {
        kd_psnr: -10.0 * (kd_se / wsum).max(1e-12).log10(),
        ks_rms: (ks_se / wsum).sqrt(),
        rho_rms: (rho_se / wsum).sqrt(),
    };

    let mut materials: Vec<MaterialDesc> = centres
        .iter()
        .enumerate()
        .map(|(k, c)| MaterialDesc::Ggx {
            name: format!("ggx_{k}"),
            // the base colour factor is white: COLOR_0 carries Kd
            pbr: GltfPbr::from_ggx(&GgxBrdf::new(Vec3::ONE, Vec3::new(c[0], c[1], c[2]), c[3])),
        })
        .collect();
    let mut primitives: Vec<PrimitiveDesc> = (0..centres.len())
        .map(|k| PrimitiveDesc {
            faces: Vec::new(),
            material: k,
        })
        .collect();
    for (f, &l) in surface_faces.iter().zip(&labels) {
        primitives[l as usize].faces.push(*f);
    }
    for (k, faces) in groups[1..].iter().enumerate() {
        let l = rec.frozen.emitters.emission(k);
        materials.push(MaterialDesc::Emitter {
            name: format!("emitter_{k}"),
            emission: l.to_array(),
        });
        primitives.push(PrimitiveDesc {
            faces: faces.clone(),
            material: materials.len() - 1,
        });
    }
    Ok((
        SceneModel {
            positions: vertices.iter().map(|v| v.to_array()).collect(),
            normals: normals.iter().map(|v| v.to_array()).collect(),
            colors,
            primitives,
            materials,
            cameras: Vec::new(),
            extras: serde_json::Value::Null,
        },
        loss,
    ))
}

/// A stage-1 run's scene: the radiance field's linear colour seen head-on (view direction −n) at
/// each vertex, one unlit material.
fn radiance_scene(frozen: &FrozenScene, surface: &RecoveredSurface, opts: &ExportOptions) -> SceneModel {
    let (vertices, normals, groups) = simplified(frozen, surface, opts);
    let dirs: Vec<Vec3> = normals.iter().map(|n| -*n).collect();
    let mut rgb = vec![Vec3::ZERO; vertices.len()];
    frozen.surface_radiance(&vertices, &dirs, &mut rgb);
    SceneModel {
        positions: vertices.iter().map(|v| v.to_array()).collect(),
        normals: normals.iter().map(|v| v.to_array()).collect(),
        colors: rgb.iter().map(|c| c.max(Vec3::ZERO).to_array()).collect(),
        primitives: vec![PrimitiveDesc {
            faces: groups.into_iter().flatten().collect(),
            material: 0,
        }],
        materials: vec![MaterialDesc::Radiance {
            name: "radiance".into(),
        }],
        cameras: Vec::new(),
        extras: serde_json::Value::Null,
    }
}

/// Writes `model` to `path` (`.glb` or `.gltf`) atomically; returns the file's size.
pub fn write(path: &std::path::Path, model: &SceneModel) -> Result<u64, DataError> {
    let container = Container::of_path(path)
        .ok_or_else(|| DataError::invalid(format!("--out {}: must end in .glb or .gltf", path.display())))?;
    let bytes = gltf_write::encode(model, container);
    i2sdf_data::imageio::write_bytes_atomic(path, &bytes)?;
    Ok(bytes.len() as u64)
}
