//! `i2sdf synth`: renders a scene description into a dataset directory in the native format
//! (transforms.json + images + ground truth), with held-out test views and their relit ground
//! truth. The GT mesh carries a per-face `object_id`; transforms.json's `objects` names and tags
//! each id.

use crate::camera::place_camera;
use crate::capture::{self, CaptureOptions, SensorDepth};
use crate::edit::{self, EditOp, EditSpec};
use crate::noise::DepthNoise;
use crate::output::{self, FramePaths};
use crate::scene::{SceneDesc, SceneObject};
use crate::tracer::{Estimator, RenderScene, ViewRender};
use glam::Vec3;
use i2sdf_data::{Camera, DataError};
use i2sdf_render::color::luminance;
use i2sdf_render::render_view;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use rayon::prelude::*;
use serde_json::json;
use std::path::Path;

/// Everything that shapes a rendered dataset besides the scene.
#[derive(Clone, Debug)]
pub struct SynthOptions {
    pub width: usize,
    pub height: usize,
    /// Total number of views; one in six (at least one) is held out for testing.
    pub views: usize,
    pub spp: u32,
    pub seed: u64,
    pub max_depth: u32,
    pub depth_noise: DepthNoise,
    /// Free-form provenance written into transforms.json (e.g. the preset name).
    pub preset: Option<String>,
    /// The path tracer's estimator: [`Estimator::DATASET`] (path-space regularization, recorded
    /// in transforms.json's `generator`) unless `--unbiased` asks for [`Estimator::UNBIASED`].
    /// Every view and every relit view is rendered with it.
    pub estimator: Estimator,
    /// A phone capture's degradations (`crate::capture`); the default is the exact room.
    pub capture: CaptureOptions,
}

impl Default for SynthOptions {
    fn default() -> Self {
        SynthOptions {
            width: 160,
            height: 120,
            views: 48,
            // With every emitter sampled per vertex a path costs ~1.75× what it did with one
            // light sample (default room: ≈ 440 s CPU, under 4 min on two free cores); 96 spp
            // would leave view 1 at 35.5 dB PSNR against 4× spp, 128 gives 37 dB.
            spp: 128,
            seed: 0,
            max_depth: 64,
            depth_noise: DepthNoise::None,
            preset: None,
            estimator: Estimator::DATASET,
            capture: CaptureOptions::default(),
        }
    }
}

/// Most views of a dataset (the paper's rooms have ~200; a dataset of 10⁴ views at the smallest
/// size already takes hours to render here).
pub const MAX_VIEWS: usize = 10_000;
/// Most paths per pixel and scattering events per path.
pub const MAX_SPP: u32 = 1 << 16;
pub const MAX_DEPTH: u32 = 1024;

impl SynthOptions {
    /// Bytes the dataset will take on disk, roughly: per pixel of each view the LDR PNG, the HDR
    /// image, depth, normals, the three material maps and the mask (EXRs uncompressed at worst),
    /// and the relit test views; for the free-space check before rendering.
    pub fn estimated_bytes(&self) -> u64 {
        let pixels = (self.width * self.height * self.views) as u64;
        pixels * 64 + (16 << 20)
    }

    pub fn test_views(&self) -> usize {
        ((self.views as f32 / 6.0).round() as usize).clamp(1, self.views.saturating_sub(1).max(1))
    }

    pub fn validate(&self) -> Result<(), DataError> {
        if self.width < 8 || self.height < 8 || self.width > 8192 || self.height > 8192 {
            return Err(DataError::invalid(format!(
                "image size {}×{} must be within 8..=8192",
                self.width, self.height
            )));
        }
        if !(2..=MAX_VIEWS).contains(&self.views) {
            return Err(DataError::invalid(format!(
                "--views {}: must be in 2..={MAX_VIEWS} (train and test views)",
                self.views
            )));
        }
        if !(1..=MAX_SPP).contains(&self.spp) {
            return Err(DataError::invalid(format!(
                "--spp {}: must be in 1..={MAX_SPP}",
                self.spp
            )));
        }
        // Depth 0 traces no path at all: every image would be black.
        if !(1..=MAX_DEPTH).contains(&self.max_depth) {
            return Err(DataError::invalid(format!(
                "--max-depth {}: must be in 1..={MAX_DEPTH} (scattering events per path)",
                self.max_depth
            )));
        }
        self.capture.validate(self.width, self.height)
    }
}

/// One camera of the dataset.
#[derive(Clone, Debug)]
pub struct ViewSpec {
    pub camera: Camera,
    pub test: bool,
    pub stem: String,
}

/// Train cameras spread their yaw around the full circle (inside-out capture); test cameras are
/// placed independently with yaws halfway between, so they are novel views of the same room.
pub fn plan_views(scene: &RenderScene, opts: &SynthOptions) -> Result<Vec<ViewSpec>, DataError> {
    let n_test = opts.test_views();
    let n_train = opts.views - n_test;
    let mut rng = Pcg64::seed_from_u64(opts.seed.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ 0xCA3E_7A5);
    let mut views = Vec::with_capacity(opts.views);
    let offset = rng.gen_range(0.0..std::f32::consts::TAU);
    for i in 0..n_train {
        let yaw = offset + std::f32::consts::TAU * i as f32 / n_train as f32;
        views.push(ViewSpec {
            camera: place_camera(scene, &mut rng, yaw, opts.width, opts.height)?,
            test: false,
            stem: format!("{i:04}"),
        });
    }
    for j in 0..n_test {
        let yaw = offset + std::f32::consts::TAU * (j as f32 + 0.5) / n_test as f32;
        let stem = format!("{:04}", n_train + j);
        views.push(ViewSpec {
            camera: place_camera(scene, &mut rng, yaw, opts.width, opts.height)?,
            test: true,
            stem,
        });
    }
    Ok(views)
}

/// Exposure that maps the log-average luminance of the non-emitter pixels of the training views
/// to 0.18 (Reinhard's key value): emitters then saturate in the LDR images, as in photographs.
pub fn auto_exposure(renders: &[(&ViewSpec, &ViewRender)]) -> f32 {
    let (mut sum, mut n) = (0.0f64, 0usize);
    for (spec, r) in renders {
        if spec.test {
            continue;
        }
        let ones = vec![Vec3::ONE; r.emitters];
        for (l, &m) in r.hdr(&ones).iter().zip(&r.emitter_mask) {
            if !m {
                sum += (1e-4 + luminance(*l) as f64).ln();
                n += 1;
            }
        }
    }
    if n == 0 {
        return 1.0;
    }
    (0.18 / (sum / n as f64).exp()) as f32
}

/// The relit test conditions:
/// - `brighter_warmer`: the first emitter 2× brighter and warmer;
/// - `light_off`: the last one off (`light_dim`, halved, when the scene has a single emitter,
///   which would otherwise go black);
/// - with two emitters or more, `small_light_alone`: the most powerful emitter off and the least
///   powerful 3× brighter, so that the room is lit by its small light — what stage 2 recovered of
///   a small emitter (its extent, its emission, the light it throws) then decides the image;
/// - and `small_light_cool`: the least powerful emitter 2× brighter and cool blue, the others
///   as they are (its colour and its place must be right for the change to come out right).
///
/// Power is the emitter's luminance × area.
pub fn default_relight_specs(scene: &RenderScene) -> Vec<(String, EditSpec)> {
    let centre = |k: usize| {
        let (lo, hi) = scene.emitters[k].bounds;
        (0.5 * (lo + hi)).to_array()
    };
    let first = EditSpec {
        ops: vec![EditOp::relight(centre(0), 2.0, [1.0, 0.8, 0.6])],
    };
    let last = scene.emitters.len() - 1;
    let (name, scale) = if last > 0 {
        ("light_off", 0.0)
    } else {
        ("light_dim", 0.5)
    };
    let second = EditSpec {
        ops: vec![EditOp::relight(centre(last), scale, [1.0; 3])],
    };
    let mut specs = vec![("brighter_warmer".to_string(), first), (name.to_string(), second)];
    if last > 0 {
        let power: Vec<f64> = scene.emitters.iter().map(|e| emitter_power(scene, e)).collect();
        let by_power = |a: &usize, b: &usize| power[*a].total_cmp(&power[*b]);
        let largest = (0..power.len()).max_by(by_power).expect("emitters");
        let smallest = (0..power.len()).min_by(by_power).expect("emitters");
        specs.push((
            "small_light_alone".to_string(),
            EditSpec {
                ops: vec![
                    EditOp::relight(centre(largest), 0.0, [1.0; 3]),
                    EditOp::relight(centre(smallest), 3.0, [1.0; 3]),
                ],
            },
        ));
        specs.push((
            "small_light_cool".to_string(),
            EditSpec {
                ops: vec![EditOp::relight(centre(smallest), 2.0, [0.5, 0.7, 1.0])],
            },
        ));
    }
    specs
}

/// An emitter's luminance × the area of its shape's triangles.
fn emitter_power(scene: &RenderScene, e: &crate::tracer::Emitter) -> f64 {
    let area: f64 = (0..scene.mesh.mesh.num_faces())
        .filter(|&f| scene.mesh.shape_of[f] == e.shape)
        .map(|f| scene.mesh.mesh.face_area(f))
        .sum();
    luminance(e.emission) as f64 * area
}

/// What a finished dataset looks like, for the caller's summary.
#[derive(Clone, Debug)]
pub struct SynthSummary {
    pub train_views: usize,
    pub test_views: usize,
    pub triangles: usize,
    pub emitters: usize,
    pub exposure: f32,
    pub render_seconds: f64,
}

/// Renders `desc` with `opts` into `out` (created if needed). `on_row` is called once per
/// rendered image row (views × height in all), from worker threads.
pub fn generate(
    desc: SceneDesc,
    opts: &SynthOptions,
    out: &Path,
    on_row: &(dyn Fn() + Sync),
) -> Result<SynthSummary, DataError> {
    opts.validate()?;
    desc.validate(Path::new("scene"))?;
    std::fs::create_dir_all(out).map_err(|e| DataError::io(out, format!("cannot create: {e}")))?;
    let mut scene = RenderScene::new(desc);
    scene.estimator = opts.estimator;
    let views = views_through_lens(&scene, opts)?;
    let start = std::time::Instant::now();
    let renders = render_views(&scene, &views, opts, on_row);
    let render_seconds = start.elapsed().as_secs_f64();
    check_closed(&views, &renders)?;
    let pairs: Vec<(&ViewSpec, &ViewRender)> = views.iter().zip(&renders).collect();
    let exposure = auto_exposure(&pairs);
    let noisy = opts.depth_noise != DepthNoise::None;
    let frame_paths: Vec<FramePaths> = views
        .iter()
        .map(|v| FramePaths::new(&v.stem, noisy, &opts.capture))
        .collect();
    write_views(&scene, opts, out, &pairs, &frame_paths, exposure)?;
    let relight_json = write_relit_test_views(&scene, out, &pairs, exposure)?;

    let (objects, object_of_shape) = scene.desc.objects();
    scene.mesh.write_ply(&out.join("mesh.ply"), &object_of_shape)?;
    i2sdf_data::imageio::write_bytes_atomic(&out.join("scene.toml"), scene.desc.to_toml_string().as_bytes())?;
    let written = written_poses(opts, out, &views, &frame_paths)?;
    let transforms = transforms_json(
        &scene,
        opts,
        &views,
        &written,
        &frame_paths,
        exposure,
        relight_json,
        &objects,
    );
    i2sdf_data::imageio::write_bytes_atomic(
        &out.join("transforms.json"),
        serde_json::to_string_pretty(&transforms).expect("JSON").as_bytes(),
    )?;
    let n_test = views.iter().filter(|v| v.test).count();
    Ok(SynthSummary {
        train_views: views.len() - n_test,
        test_views: n_test,
        triangles: scene.mesh.mesh.faces.len(),
        emitters: scene.emitters.len(),
        exposure,
        render_seconds,
    })
}

/// The planned views, each camera given the capture's lens. The whole capture is taken through
/// the lens; the cameras are placed as in the exact room, so one seed gives the same room, poses
/// and test views whatever the capture options.
fn views_through_lens(scene: &RenderScene, opts: &SynthOptions) -> Result<Vec<ViewSpec>, DataError> {
    let mut views = plan_views(scene, opts)?;
    for v in &mut views {
        v.camera.lens = opts.capture.lens;
        v.camera
            .validate_intrinsics()
            .map_err(|(_, m)| DataError::invalid(format!("--lens {}: {m}", opts.capture.lens.model_name())))?;
    }
    Ok(views)
}

/// Renders every view, one after the other, each with its own seed.
fn render_views(
    scene: &RenderScene,
    views: &[ViewSpec],
    opts: &SynthOptions,
    on_row: &(dyn Fn() + Sync),
) -> Vec<ViewRender> {
    views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let settings = scene.view_settings(opts.spp, opts.seed, i as u32, opts.max_depth);
            render_view(&scene.scene(), &v.camera, &settings, on_row)
        })
        .collect()
}

/// Refuses renders with a pixel that sees no surface: the room is not closed.
fn check_closed(views: &[ViewSpec], renders: &[ViewRender]) -> Result<(), DataError> {
    for (v, r) in views.iter().zip(renders) {
        if let Some(i) = r.depth.iter().position(|d| !d.is_finite()) {
            return Err(DataError::invalid(format!(
                "view {}: pixel {i} sees no surface: the room is not closed",
                v.stem
            )));
        }
    }
    Ok(())
}

/// Writes every view's frame and ground truth, views in parallel. The depth is the capture's
/// sensor depth where it has its own grid or a confidence map, else the rendered depth with the
/// depth noise; each view draws its noise from its own RNG stream.
fn write_views(
    scene: &RenderScene,
    opts: &SynthOptions,
    out: &Path,
    pairs: &[(&ViewSpec, &ViewRender)],
    frame_paths: &[FramePaths],
    exposure: f32,
) -> Result<(), DataError> {
    let ones = vec![Vec3::ONE; scene.emitters.len()];
    let cap = &opts.capture;
    pairs
        .par_iter()
        .zip(frame_paths)
        .enumerate()
        .try_for_each(|(i, ((v, r), paths))| {
            let mut rng = Pcg64::seed_from_u64(opts.seed ^ (0xD3_9751 + i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
            let depth = if cap.depth_grid.is_some() || cap.confidence {
                let size = cap.depth_size(r.width, r.height);
                capture::sensor_depth(scene, &v.camera, size, opts.depth_noise, cap.confidence, &mut rng)
            } else {
                let mut depth = r.depth.clone();
                opts.depth_noise.apply(&mut depth, &mut rng);
                SensorDepth {
                    width: r.width,
                    height: r.height,
                    depth,
                    confidence: None,
                }
            };
            output::write_view(out, paths, r, &r.hdr(&ones), &depth, exposure, cap.jpeg_quality)
        })
}

/// Relit ground truth of the test views (exact by linearity in the emitters; see
/// `i2sdf_render::integrator`): per default relight spec, the spec and each test view's PNG and
/// EXR. Returns their entries of transforms.json.
fn write_relit_test_views(
    scene: &RenderScene,
    out: &Path,
    pairs: &[(&ViewSpec, &ViewRender)],
    exposure: f32,
) -> Result<Vec<serde_json::Value>, DataError> {
    let mut relight_json = Vec::new();
    for (name, spec) in default_relight_specs(scene) {
        let spec_rel = format!("relight/{name}.toml");
        i2sdf_data::imageio::write_bytes_atomic(&out.join(&spec_rel), spec.to_toml_string().as_bytes())?;
        let gains = edit::emitter_gains(&spec, &scene.emitters);
        let mut frames = Vec::new();
        for (v, r) in pairs.iter().filter(|(v, _)| v.test) {
            let hdr = r.hdr(&gains);
            let (png, exr) = (
                format!("relight/{name}/{}.png", v.stem),
                format!("relight/{name}/{}.exr", v.stem),
            );
            i2sdf_data::imageio::write_png(&out.join(&png), &output::ldr_image(r.width, r.height, &hdr, exposure))?;
            i2sdf_data::imageio::write_exr(&out.join(&exr), &output::rgb_image(r.width, r.height, &hdr))?;
            frames.push(json!({"file_path": png, "hdr_file_path": exr, "transform_matrix": matrix_json(&v.camera)}));
        }
        relight_json.push(json!({"spec": spec_rel, "frames": frames}));
    }
    Ok(relight_json)
}

/// The training poses as written: perturbed when the options say so (the images were rendered at
/// the true ones, which then go to poses_true.json); the test poses stay exact.
fn written_poses(
    opts: &SynthOptions,
    out: &Path,
    views: &[ViewSpec],
    frame_paths: &[FramePaths],
) -> Result<Vec<Camera>, DataError> {
    let Some(noise) = opts.capture.pose_perturbation() else {
        return Ok(views.iter().map(|v| v.camera.clone()).collect());
    };
    let mut rng = Pcg64::seed_from_u64(opts.seed ^ 0x9053_E5A1_7ED0_0001);
    let written = views
        .iter()
        .map(|v| {
            if v.test {
                v.camera.clone()
            } else {
                noise.perturb(&v.camera, &mut rng)
            }
        })
        .collect();
    let truth: serde_json::Map<String, serde_json::Value> = views
        .iter()
        .zip(frame_paths)
        .map(|(v, p)| (p.image.clone(), matrix_json(&v.camera)))
        .collect();
    let poses_true = json!({
        "note": "the true camera-to-world matrices (OpenGL axes, as transforms.json) of every frame, keyed by file_path; transforms.json's training poses are these perturbed",
        "transform_matrix": truth,
    });
    i2sdf_data::imageio::write_bytes_atomic(
        &out.join(POSES_TRUE_FILE),
        serde_json::to_string_pretty(&poses_true).expect("JSON").as_bytes(),
    )?;
    Ok(written)
}

/// The renderer's estimator as transforms.json records it: whether the images are unbiased, and
/// the regularization that makes them biased otherwise.
fn estimator_json(e: &Estimator) -> serde_json::Value {
    json!({
        "unbiased": e.regularize_roughness.is_none(),
        "light_sampling": "every emitter per vertex; spheres by solid angle, others by area; MIS (power heuristic)",
        "regularization": e.regularize_roughness.map(|rho| json!({
            "method": "path-space regularization (Kaplanyan & Dachsbacher 2013)",
            "min_roughness_after_diffuse": rho,
        })),
    })
}

fn matrix_json(cam: &Camera) -> serde_json::Value {
    // OpenGL convention, row-major rows, as nerfstudio writes them; in f32, the precision the
    // poses are made in (`camera::looking`), so the numbers are exactly those placed.
    let m = cam.opengl_c2w();
    json!((0..4)
        .map(|r| (0..4).map(|c| m.col(c)[r] as f32).collect::<Vec<f32>>())
        .collect::<Vec<_>>())
}

/// The side file of a dataset with perturbed training poses: every frame's true pose.
pub const POSES_TRUE_FILE: &str = "poses_true.json";

#[allow(clippy::too_many_arguments)]
fn transforms_json(
    scene: &RenderScene,
    opts: &SynthOptions,
    views: &[ViewSpec],
    written: &[Camera],
    paths: &[FramePaths],
    exposure: f32,
    relight: Vec<serde_json::Value>,
    objects: &[SceneObject],
) -> serde_json::Value {
    let cam = &views[0].camera;
    let cap = &opts.capture;
    let frames: Vec<_> = views
        .iter()
        .zip(written)
        .zip(paths)
        .map(|((v, pose), p)| {
            let mut f = serde_json::Map::new();
            let mut put = |k: &str, v: Option<&String>| {
                if let Some(v) = v {
                    f.insert(k.to_string(), json!(v));
                }
            };
            put("file_path", Some(&p.image));
            put("hdr_file_path", p.hdr.as_ref());
            put("depth_file_path", Some(&p.depth));
            put("normal_file_path", p.normal.as_ref());
            put("emitter_mask_path", p.mask.as_ref());
            put("albedo_file_path", Some(&p.kd));
            put("specular_file_path", Some(&p.ks));
            put("roughness_file_path", Some(&p.roughness));
            f.insert("split".into(), json!(if v.test { "test" } else { "train" }));
            f.insert("transform_matrix".into(), matrix_json(pose));
            if let Some(gt) = &p.depth_gt {
                f.insert("depth_gt_file_path".into(), json!(gt));
            }
            if let Some(c) = &p.confidence {
                f.insert("confidence_file_path".into(), json!(c));
            }
            serde_json::Value::Object(f)
        })
        .collect();
    let (mu, sigma) = match opts.depth_noise {
        DepthNoise::None => ("0", "0"),
        DepthNoise::Sigma => ("0.0001125 z^2 + 0.0048875", "0.002925 z^2 + 0.003325"),
        DepthNoise::ThreeSigma => ("0.0001125 z^2 + 0.0048875", "3 (0.002925 z^2 + 0.003325)"),
    };
    let mut depth = json!({"kind": "z-depth along the optical axis", "unit": "metre",
                           "noise": opts.depth_noise.name(), "noise_mu": mu, "noise_sigma": sigma});
    if cap.depth_grid.is_some() || cap.confidence {
        let (w, h) = cap.depth_size(cam.width, cam.height);
        depth["grid"] = json!([w, h]);
        depth["sampling"] =
            json!("the true z-depth at the depth map's pixel centres mapped onto the image (traced through the lens), then the noise");
    }
    if cap.depth_grid.is_some() {
        depth["encoding"] = json!("16-bit PNG, millimetres (x depth_unit_scale_factor = metres), 0 = no depth");
    }
    if cap.confidence {
        depth["confidence"] = json!({
            "values": "0 low, 1 medium, 2 high (ARKit's)",
            "edge": "the sample's footprint against a plane: max over its cell's two corner diagonals of |z_centre * mean(1/z_corner) - 1| (0 on any plane)",
            "low": "edge over 5 %, over 80 deg from the surface normal, or beyond 5 m; its depth is corrupted: on an edge a flying pixel uniform between the footprint's nearest and farthest z, else a 10 % relative Gaussian error",
            "medium": "edge over 1 %, over 70 deg from the normal, or beyond 3.5 m",
        });
    }
    let mut ldr = json!({"transfer": "srgb"});
    if cap.hdr {
        ldr["exposure"] = json!(exposure);
        ldr["encoding"] = json!("png = srgb(clamp(exposure * hdr, 0, 1)), 8 bit; hdr = linear radiance");
    }
    let mut generator = json!({"name": "i2sdf synth", "preset": opts.preset, "seed": opts.seed, "spp": opts.spp,
                               "max_depth": opts.max_depth, "units": "metre", "up": "+y",
                               "estimator": estimator_json(&opts.estimator)});
    if !cap.is_exact() {
        generator["capture"] = cap.to_json(opts.depth_noise);
    }
    let mut top = json!({
        "fl_x": cam.fx as f32, "fl_y": cam.fy as f32, "cx": cam.cx as f32, "cy": cam.cy as f32, "w": cam.width, "h": cam.height,
        "ldr": ldr,
        "depth": depth,
        "poses_exact": cap.pose_perturbation().is_none(),
        "depth_exact": opts.depth_noise == DepthNoise::None,
        "mesh_path": "mesh.ply",
        "scene_path": "scene.toml",
        "generator": generator,
        "emitters": scene.emitters.iter().map(|e| json!({
            "name": e.name, "emission": e.emission.to_array(),
            "bounds_min": e.bounds.0.to_array(), "bounds_max": e.bounds.1.to_array()})).collect::<Vec<_>>(),
        "objects": objects.iter().map(|o| json!({"id": o.id, "name": o.name, "tags": o.tags})).collect::<Vec<_>>(),
        "frames": frames,
        "relight": relight,
    });
    if !cam.lens.is_pinhole() {
        top["camera_model"] = json!(cam.lens.model_name());
        for (k, v) in cam.lens.params() {
            top[k] = json!(v);
        }
    }
    if cap.depth_grid.is_some() {
        top["depth_unit_scale_factor"] = json!(0.001);
    }
    if cap.pose_perturbation().is_some() {
        top["poses_true_path"] = json!(POSES_TRUE_FILE);
    }
    top
}
