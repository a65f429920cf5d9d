//! Small datasets of a known geometry, written in either format, for tests (here and in other
//! crates) — no binary blobs in the repository. The scene is the inside of an axis-aligned box
//! room, rendered analytically: depth, normals, an emitter patch on the ceiling and a colour that
//! depends on the hit point. Each writer follows its format's own conventions independently of the
//! loaders (OpenGL poses and +0.5 pixel centres for the native format; K·W2C projection matrices,
//! integer-pixel rays and camera-space normals for the paper's), so a loader that gets a convention
//! wrong fails the tests.

use crate::camera::{look_at, Camera};
use crate::imageio::{self, ImageF32};
use glam::{DMat3, DVec3};
use std::path::Path;

/// The room: the inside of [ROOM_MIN, ROOM_MAX] (z up), in world units.
pub const ROOM_MIN: DVec3 = DVec3::new(-2.0, -1.5, -0.2);
pub const ROOM_MAX: DVec3 = DVec3::new(2.5, 1.8, 2.4);

/// Where a ray from inside the room leaves it: distance along the unit direction and the inward
/// wall normal there.
pub fn room_hit(o: DVec3, d: DVec3) -> (f64, DVec3) {
    let mut best = (f64::INFINITY, DVec3::ZERO);
    for a in 0..3 {
        if d[a].abs() < 1e-12 {
            continue;
        }
        let (wall, n) = if d[a] > 0.0 {
            (ROOM_MAX[a], -1.0)
        } else {
            (ROOM_MIN[a], 1.0)
        };
        let t = (wall - o[a]) / d[a];
        if t > 0.0 && t < best.0 {
            let mut nv = DVec3::ZERO;
            nv[a] = n;
            best = (t, nv);
        }
    }
    best
}

fn albedo_at(p: DVec3) -> [f32; 3] {
    [
        (0.5 + 0.4 * (3.0 * p.x).sin()) as f32,
        (0.5 + 0.4 * (2.0 * p.y + 1.0).sin()) as f32,
        (0.5 + 0.4 * (2.5 * p.z + 2.0).cos()) as f32,
    ]
}

fn is_emitter(p: DVec3, n: DVec3) -> bool {
    n.z < -0.5 && p.x.abs() < 0.6 && p.y.abs() < 0.5
}

/// The fixture's material masks call the wall at `ROOM_MAX.x` (inward normal −x) not GGX, as
/// the paper's release marks mirrors and glass.
fn is_ggx(n: DVec3) -> bool {
    n.x > -0.5
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DepthFormat {
    Exr,
    Npy,
    /// 16-bit PNG in millimetres (`depth_unit_scale_factor` = 0.001).
    Png16,
}

#[derive(Clone, Debug)]
pub struct FixtureOptions {
    pub width: usize,
    pub height: usize,
    pub train_views: usize,
    pub test_views: usize,
    pub depth: DepthFormat,
    /// If set, each camera's principal point is nudged (by less than a pixel) so that this world
    /// point projects exactly onto a pixel centre in every view: two views then see the very same
    /// point at a pixel centre, which is what the two-view depth consistency test needs.
    pub anchor: Option<DVec3>,
}

impl Default for FixtureOptions {
    fn default() -> Self {
        FixtureOptions {
            width: 24,
            height: 18,
            train_views: 4,
            test_views: 2,
            depth: DepthFormat::Exr,
            anchor: None,
        }
    }
}

/// The cameras of the fixture (OpenCV, our pixel-centre convention): inside the room, looking at
/// `anchor` (or around the room).
pub fn cameras(opts: &FixtureOptions) -> Vec<Camera> {
    let n = opts.train_views + opts.test_views;
    (0..n)
        .map(|i| {
            let a = i as f64 * 2.399; // golden angle: spread the views
            let eye = DVec3::new(0.6 * a.cos(), 0.5 * a.sin(), 1.0 + 0.2 * (i as f64).sin());
            let target = opts
                .anchor
                .unwrap_or(DVec3::new(2.0 * (a + 1.0).cos(), 1.5 * (a + 1.0).sin(), 0.8));
            let fx = 0.9 * opts.width as f64 + i as f64;
            let mut cam = Camera {
                lens: Default::default(),
                width: opts.width,
                height: opts.height,
                fx,
                fy: fx * 1.01,
                cx: opts.width as f64 / 2.0 + 0.1,
                cy: opts.height as f64 / 2.0 - 0.2,
                c2w: look_at(eye, target, DVec3::Z),
            };
            if let Some(anchor) = opts.anchor {
                let (u, v, _) = cam.project(anchor).expect("anchor in front of the camera");
                cam.cx += u.floor() + 0.5 - u;
                cam.cy += v.floor() + 0.5 - v;
            }
            cam
        })
        .collect()
}

/// Renders the analytic maps of one view. `pixel_offset` is where the format puts pixel centres
/// (0.5 for ours, 0.0 for the paper's integer-pixel rays, with `cx`, `cy` in that convention).
struct Maps {
    rgb: ImageF32,
    depth: ImageF32,
    normal_world: ImageF32,
    mask: ImageF32,
    /// 1 where the surface is GGX, 0 on the wall at `ROOM_MAX.x` (a "mirror": see [`is_ggx`]).
    ggx: ImageF32,
}

fn render(cam: &Camera, cx: f64, cy: f64, pixel_offset: f64) -> Maps {
    let (w, h) = (cam.width, cam.height);
    let mut m = Maps {
        rgb: ImageF32::new(w, h, 3),
        depth: ImageF32::new(w, h, 1),
        normal_world: ImageF32::new(w, h, 3),
        mask: ImageF32::new(w, h, 1),
        ggx: ImageF32::new(w, h, 1),
    };
    let r = DMat3::from_mat4(cam.c2w);
    for j in 0..h {
        for i in 0..w {
            let d_cam = DVec3::new(
                (i as f64 + pixel_offset - cx) / cam.fx,
                (j as f64 + pixel_offset - cy) / cam.fy,
                1.0,
            );
            let len = d_cam.length();
            let d = r * (d_cam / len);
            let (t, n) = room_hit(cam.center(), d);
            let p = cam.center() + d * t;
            m.rgb.pixel_mut(i, j).copy_from_slice(&albedo_at(p));
            m.depth.pixel_mut(i, j)[0] = (t / len) as f32; // z-depth = t · cos θ
            m.normal_world
                .pixel_mut(i, j)
                .copy_from_slice(&[n.x as f32, n.y as f32, n.z as f32]);
            m.mask.pixel_mut(i, j)[0] = is_emitter(p, n) as u8 as f32;
            m.ggx.pixel_mut(i, j)[0] = is_ggx(n) as u8 as f32;
        }
    }
    m
}

fn write_depth(path_stem: &Path, depth: &ImageF32, fmt: DepthFormat) -> String {
    match fmt {
        DepthFormat::Exr => {
            let p = path_stem.with_extension("exr");
            imageio::write_exr(&p, depth).unwrap();
            p.file_name().unwrap().to_string_lossy().into_owned()
        }
        DepthFormat::Npy => {
            let p = path_stem.with_extension("npy");
            imageio::write_npy(&p, depth).unwrap();
            p.file_name().unwrap().to_string_lossy().into_owned()
        }
        DepthFormat::Png16 => {
            let p = path_stem.with_extension("png");
            let raw: Vec<u16> = depth.data.iter().map(|d| (d * 1000.0).round() as u16).collect();
            imageio::write_png16_raw(&p, depth.width, depth.height, 1, &raw).unwrap();
            p.file_name().unwrap().to_string_lossy().into_owned()
        }
    }
}

/// Writes the native format into `dir` and returns the true cameras (train first, then test).
pub fn write_native(dir: &Path, opts: &FixtureOptions) -> Vec<Camera> {
    let cams = cameras(opts);
    let mut frames = Vec::new();
    for (k, cam) in cams.iter().enumerate() {
        let name = format!("frame_{k:03}");
        let maps = render(cam, cam.cx, cam.cy, 0.5);
        imageio::write_png(&dir.join("images").join(format!("{name}.png")), &maps.rgb).unwrap();
        let depth_name = write_depth(&dir.join("depth").join(&name), &maps.depth, opts.depth);
        imageio::write_npy(&dir.join("normals").join(format!("{name}.npy")), &maps.normal_world).unwrap();
        imageio::write_png(&dir.join("masks").join(format!("{name}.png")), &maps.mask).unwrap();
        let gl = cam.opengl_c2w();
        let rows: Vec<Vec<f64>> = (0..4).map(|r| gl.row(r).to_array().to_vec()).collect();
        frames.push(serde_json::json!({
            "file_path": format!("images/{name}.png"),
            "depth_file_path": format!("depth/{depth_name}"),
            "normal_file_path": format!("normals/{name}.npy"),
            "emitter_mask_path": format!("masks/{name}.png"),
            "split": if k < opts.train_views { "train" } else { "test" },
            "fl_x": cam.fx, "fl_y": cam.fy, "cx": cam.cx, "cy": cam.cy,
            "transform_matrix": rows,
        }));
    }
    let json = serde_json::json!({
        "w": opts.width, "h": opts.height,
        "camera_model": "OPENCV",
        "depth_unit_scale_factor": 0.001,
        "poses_exact": true,
        "depth_exact": true,
        "an_unknown_key": {"is": "ignored"},
        "frames": frames,
    });
    imageio::write_bytes_atomic(
        &dir.join("transforms.json"),
        serde_json::to_string_pretty(&json).unwrap().as_bytes(),
    )
    .unwrap();
    cams
}

/// What [`write_paper_with`] writes beyond the release's usual files (cameras, `image/`, `depth/`,
/// `normal/`, `light_mask/`, `val/`), each off by default.
#[derive(Clone, Debug, Default)]
pub struct PaperOptions {
    /// No `val/`: every view is a training image (`world_mat_i`), so the loader holds out its own.
    pub no_val: bool,
    /// The validation views' annotations under `val/` (`depth/`, `normal/`, `light_mask/`, and
    /// `mask/`, `material/`, `hdr/` where those are asked for).
    pub val_maps: bool,
    /// Material masks in `mask/` (1 = GGX, 0 on the wall at `ROOM_MAX.x`).
    pub material_masks: bool,
    /// GT materials in `material/`: Kd the image's linearized colour, Ks 0.04, roughness 0.6.
    pub materials: bool,
    /// HDR images in `hdr/` such that LDR = sRGB(exposure · HDR).
    pub hdr_exposure: Option<f64>,
    /// `mesh.ply` as a point cloud (vertices only): a grid of points on the room's walls.
    pub point_cloud: bool,
    /// `radiometry.json`, as written.
    pub radiometry_json: Option<String>,
}

/// Writes the paper's release format into `dir` and returns the true cameras (train, then val).
pub fn write_paper(dir: &Path, opts: &FixtureOptions) -> Vec<Camera> {
    write_paper_with(dir, opts, &PaperOptions::default())
}

/// [`write_paper`] with the extra files of `extra`. With `extra.no_val` all the views are training
/// images, in the order of the returned cameras.
pub fn write_paper_with(dir: &Path, opts: &FixtureOptions, extra: &PaperOptions) -> Vec<Camera> {
    let cams = cameras(opts);
    std::fs::create_dir_all(dir).unwrap();
    let train_views = if extra.no_val { cams.len() } else { opts.train_views };
    write_paper_cameras(&dir.join("cameras_normalize.npz"), &cams, train_views);
    for (k, cam) in cams.iter().enumerate() {
        let is_train = k < train_views;
        let idx = if is_train { k } else { k - train_views };
        // The release's convention: ray through K⁻¹[u, v, 1] with integer u, v.
        let maps = render(cam, cam.cx - 0.5, cam.cy - 0.5, 0.0);
        let name = format!("{idx:04}");
        let (base, images) = if is_train {
            (dir.to_path_buf(), "image")
        } else {
            (dir.join("val"), "")
        };
        imageio::write_png(&base.join(images).join(format!("{name}.png")), &maps.rgb).unwrap();
        if is_train || extra.val_maps {
            write_paper_annotations(&base, &name, cam, &maps, extra);
        }
    }
    if extra.point_cloud {
        let positions = room_points(0.05);
        crate::ply::write_ply(
            &dir.join("mesh.ply"),
            &crate::mesh::TriangleMesh {
                positions,
                ..Default::default()
            },
        )
        .unwrap();
    }
    if let Some(text) = &extra.radiometry_json {
        std::fs::write(dir.join("radiometry.json"), text).unwrap();
    }
    cams
}

/// `cameras_normalize.npz`: `world_mat_i` for the first `train_views` cameras, `val_mat_i` for the
/// rest, as K·W2C in the release's integer-pixel convention, and a VolSDF `scale_mat_i` per
/// training view.
fn write_paper_cameras(npz_path: &Path, cams: &[Camera], train_views: usize) {
    use npyz::WriterBuilder;
    let mut npz = npyz::npz::NpzWriter::create(npz_path).unwrap();
    let mut put = |name: &str, m: [[f64; 4]; 4]| {
        let mut w = npz
            .array::<f64>(name, Default::default())
            .unwrap()
            .default_dtype()
            .shape(&[4, 4])
            .begin_nd()
            .unwrap();
        w.extend(m.iter().flatten().copied()).unwrap();
        w.finish().unwrap();
    };
    // A VolSDF-style normalization: uniform scale + translation.
    let s = 2.0;
    let scale_mat = [
        [s, 0.0, 0.0, 0.2],
        [0.0, s, 0.0, 0.1],
        [0.0, 0.0, s, 1.1],
        [0.0, 0.0, 0.0, 1.0],
    ];
    put("scale_mat_0", scale_mat);
    for (k, cam) in cams.iter().enumerate() {
        // The release's convention: ray through K⁻¹[u, v, 1] with integer u, v, so its principal
        // point is ours minus ½.
        let k_mat = DMat3::from_cols(
            DVec3::new(cam.fx, 0.0, 0.0),
            DVec3::new(0.0, cam.fy, 0.0),
            DVec3::new(cam.cx - 0.5, cam.cy - 0.5, 1.0),
        );
        let w2c = cam.w2c();
        let mut p = [[0.0; 4]; 4];
        for i in 0..3 {
            for j in 0..4 {
                p[i][j] = (0..3).map(|l| k_mat.col(l)[i] * w2c.col(j)[l]).sum::<f64>() * 3.0;
            }
        }
        p[3] = [0.0, 0.0, 0.0, 1.0];
        if k < train_views {
            put(&format!("world_mat_{k}"), p);
            put(&format!("scale_mat_{k}"), scale_mat);
        } else {
            put(&format!("val_mat_{}", k - train_views), p);
        }
    }
    drop(npz); // finishes the zip archive
}

/// One view's annotations in the release's layout under `base` (the dataset, or its `val/`).
fn write_paper_annotations(base: &Path, name: &str, cam: &Camera, maps: &Maps, extra: &PaperOptions) {
    let exr = |sub: &str, file: String, img: &ImageF32| imageio::write_exr(&base.join(sub).join(file), img).unwrap();
    // Depth as a 3-channel EXR, as the release ships it (the loader reads the R channel).
    let depth3 = ImageF32::from_data(
        maps.depth.width,
        maps.depth.height,
        3,
        maps.depth.data.iter().flat_map(|d| [*d; 3]).collect(),
    );
    exr("depth", format!("{name}.exr"), &depth3);
    // Normals in OpenCV camera space: n_cam = Rᵀ n_world.
    let rt = DMat3::from_mat4(cam.c2w).transpose();
    let mut ncam = maps.normal_world.clone();
    for px in ncam.data.chunks_mut(3) {
        let n = rt * DVec3::new(px[0] as f64, px[1] as f64, px[2] as f64);
        px.copy_from_slice(&[n.x as f32, n.y as f32, n.z as f32]);
    }
    exr("normal", format!("{name}.exr"), &ncam);
    imageio::write_png(&base.join("light_mask").join(format!("{name}.png")), &maps.mask).unwrap();
    if extra.material_masks {
        imageio::write_png(&base.join("mask").join(format!("{name}.png")), &maps.ggx).unwrap();
    }
    // The linear colour of the image as written (8-bit), so that the HDR images relate to the
    // LDR ones by exactly the exposure.
    let mut linear = maps.rgb.clone();
    linear
        .data
        .iter_mut()
        .for_each(|v| *v = imageio::srgb_to_linear((v.clamp(0.0, 1.0) * 255.0 + 0.5).floor() / 255.0));
    if extra.materials {
        let (w, h) = (maps.rgb.width, maps.rgb.height);
        exr("material", format!("{name}_kd.exr"), &linear);
        exr(
            "material",
            format!("{name}_ks.exr"),
            &ImageF32::from_data(w, h, 3, vec![0.04; w * h * 3]),
        );
        exr(
            "material",
            format!("{name}_rough.exr"),
            &ImageF32::from_data(w, h, 1, vec![0.6; w * h]),
        );
    }
    if let Some(exposure) = extra.hdr_exposure {
        linear.data.iter_mut().for_each(|v| *v /= exposure as f32);
        exr("hdr", format!("{name}.exr"), &linear);
    }
}

/// Points on a grid of `spacing` over each of the room's six walls (world units).
pub fn room_points(spacing: f64) -> Vec<[f32; 3]> {
    let mut points = Vec::new();
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let steps = |a: usize| ((ROOM_MAX[a] - ROOM_MIN[a]) / spacing).round() as usize;
        for wall in [ROOM_MIN[axis], ROOM_MAX[axis]] {
            for i in 0..=steps(u) {
                for j in 0..=steps(v) {
                    let mut p = DVec3::ZERO;
                    p[axis] = wall;
                    p[u] = ROOM_MIN[u] + i as f64 * spacing;
                    p[v] = ROOM_MIN[v] + j as f64 * spacing;
                    points.push(p.min(ROOM_MAX).as_vec3().to_array());
                }
            }
        }
    }
    points
}

/// Writes a COLMAP text model into `sparse_dir`: one camera per view (PINHOLE, OPENCV or
/// OPENCV_FISHEYE by its lens), each view's world-to-camera pose and, for every point, an
/// observation in each view it projects into (at that projection). Cameras and points are taken
/// as they are (in the model's units). Written from COLMAP's documented text layout, independently
/// of the loader.
pub fn write_colmap_text(sparse_dir: &Path, views: &[(String, Camera)], points: &[DVec3]) {
    use crate::camera::Lens;
    use std::fmt::Write;
    std::fs::create_dir_all(sparse_dir).unwrap();
    let mut cameras = String::from("# Camera list with one line of data per camera:\n");
    let mut images = String::from("# Image list with two lines of data per image:\n");
    let mut tracks: Vec<Vec<(usize, usize)>> = vec![Vec::new(); points.len()];
    for (k, (name, cam)) in views.iter().enumerate() {
        let (model, extra) = match cam.lens {
            Lens::Pinhole => ("PINHOLE", vec![]),
            Lens::BrownConrady { k1, k2, k3, p1, p2 } => {
                assert_eq!(k3, 0.0, "COLMAP's OPENCV model has no k3");
                ("OPENCV", vec![k1, k2, p1, p2])
            }
            Lens::Fisheye { k1, k2, k3, k4 } => ("OPENCV_FISHEYE", vec![k1, k2, k3, k4]),
        };
        let params: Vec<String> = [cam.fx, cam.fy, cam.cx, cam.cy]
            .iter()
            .chain(&extra)
            .map(|v| format!("{v:?}"))
            .collect();
        writeln!(
            cameras,
            "{} {model} {} {} {}",
            k + 1,
            cam.width,
            cam.height,
            params.join(" ")
        )
        .unwrap();
        let r_w2c = DMat3::from_mat4(cam.c2w).transpose();
        let q = glam::DQuat::from_mat3(&r_w2c);
        let t = -(r_w2c * cam.center());
        writeln!(
            images,
            "{} {:?} {:?} {:?} {:?} {:?} {:?} {:?} {} {name}",
            k + 1,
            q.w,
            q.x,
            q.y,
            q.z,
            t.x,
            t.y,
            t.z,
            k + 1
        )
        .unwrap();
        let mut obs = Vec::new();
        for (p_idx, p) in points.iter().enumerate() {
            let Some((u, v, _)) = cam.project(*p) else { continue };
            if u >= 0.0 && v >= 0.0 && u < cam.width as f64 && v < cam.height as f64 {
                tracks[p_idx].push((k + 1, obs.len()));
                obs.push(format!("{u:?} {v:?} {}", p_idx + 1));
            }
        }
        writeln!(images, "{}", obs.join(" ")).unwrap();
    }
    let mut pts = String::from("# 3D point list with one line of data per point:\n");
    for (p_idx, p) in points.iter().enumerate() {
        let track: Vec<String> = tracks[p_idx].iter().map(|(i, o)| format!("{i} {o}")).collect();
        writeln!(
            pts,
            "{} {:?} {:?} {:?} 128 128 128 0.5 {}",
            p_idx + 1,
            p.x,
            p.y,
            p.z,
            track.join(" ")
        )
        .unwrap();
    }
    std::fs::write(sparse_dir.join("cameras.txt"), cameras).unwrap();
    std::fs::write(sparse_dir.join("images.txt"), images).unwrap();
    std::fs::write(sparse_dir.join("points3D.txt"), pts).unwrap();
}

/// Writes the fixture as a COLMAP dataset into `dir`: `images/`, `depth/` (in `opts.depth`'s
/// format, world units: PNGs in millimetres), `masks/`, a `test.txt` naming the test views, and a
/// text model in `sparse/0/` whose coordinates are the world's times `model_scale` (COLMAP's scale
/// is arbitrary: the loader must find 1 / `model_scale` from the depth). The 3D points are room
/// surface points seen through a grid of pixels of every view. Returns the true cameras (world
/// units; train first, then test).
pub fn write_colmap(dir: &Path, opts: &FixtureOptions, model_scale: f64) -> Vec<Camera> {
    let cams = cameras(opts);
    let mut views = Vec::new();
    let mut points = Vec::new();
    let mut test_list = String::new();
    for (k, cam) in cams.iter().enumerate() {
        let name = format!("frame_{k:03}");
        let maps = render(cam, cam.cx, cam.cy, 0.5);
        imageio::write_png(&dir.join("images").join(format!("{name}.png")), &maps.rgb).unwrap();
        write_depth(&dir.join("depth").join(&name), &maps.depth, opts.depth);
        imageio::write_png(&dir.join("masks").join(format!("{name}.png")), &maps.mask).unwrap();
        if k >= opts.train_views {
            test_list.push_str(&format!("{name}.png\n"));
        }
        for j in (1..cam.height).step_by(4) {
            for i in (1..cam.width).step_by(4) {
                let (o, d, _) = cam.ray(i as f64 + 0.25, j as f64 + 0.75);
                points.push((o + d * room_hit(o, d).0) * model_scale);
            }
        }
        let mut model_cam = cam.clone();
        model_cam.c2w.w_axis = (cam.center() * model_scale).extend(1.0);
        views.push((format!("{name}.png"), model_cam));
    }
    write_colmap_text(&dir.join("sparse").join("0"), &views, &points);
    std::fs::write(dir.join("test.txt"), test_list).unwrap();
    cams
}
