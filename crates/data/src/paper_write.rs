//! Writing a loaded [`Dataset`] in the paper's release format: the inverse of [`crate::paper`]'s
//! reader, convention for convention (see its module comment for the layout).
//!
//! - Training views go to `image/NNNN.png` with `world_mat_i`, test views to `val/NNNN.png` with
//!   `val_mat_i`, each split in the dataset's order. A dataset without test views is refused: the
//!   reader would then hold out every 8th training view, and the written split would not be the
//!   dataset's.
//! - `world_mat_i = K·W2C` in world units, with the principal point shifted by −½ (the reader adds
//!   it back: the release's rays go through K⁻¹·[u, v, 1] with integer u, v). `scale_mat_i` is the
//!   dataset's normalization as VolSDF spells it (normalized → world: scale, then the centre).
//! - Depth is z-depth in world units (0 where the frame has none), in a 3-channel EXR as the
//!   release ships it (the reader takes the first channel); normals go to OpenCV camera space
//!   (n_cam = Rᵀ·n_world; (0, 0, 0) stays "no normal").
//! - `mask/` is always written: a frame's own material mask, or all ones where it has none (the
//!   reader's "every pixel is used" and an all-ones mask mean the same; the release always has
//!   masks).
//! - `mesh.ply`: the GT mesh as it is, or a vertices-only point cloud sampled on its surface
//!   ([`WriteOptions::point_cloud_density`]), the form the paper's authors promised.
//! - `radiometry.json` declares the dataset's transfer and exposure (the release declares none,
//!   and the reader's default, sRGB without exposure, may not be the dataset's).
//!
//! What the format cannot hold is not written and is listed in [`Written::left_out`]: relit test
//! sets, GT emitters, named objects, a pose-noise declaration. Lens distortion cannot be left out
//! without changing the images' geometry, so it is refused.

use crate::camera::Camera;
use crate::dataset::{Dataset, Frame, Split};
use crate::error::{DataError, Result};
use crate::imageio::{self, ImageF32};
use crate::mesh::TriangleMesh;
use crate::paper::RADIOMETRY_FILE;
use glam::{DMat3, DVec3};
use rayon::prelude::*;
use std::path::Path;

/// How [`write()`] writes what the release format leaves open.
#[derive(Clone, Debug, Default)]
pub struct WriteOptions {
    /// `Some(d)`: `mesh.ply` is a point cloud of about `d` points per square world unit of the GT
    /// mesh's surface (at most [`MAX_CLOUD_POINTS`]); `None`: the GT mesh as it is.
    pub point_cloud_density: Option<f64>,
}

/// The most points [`write()`] samples for a point cloud (48 MB of PLY at most).
pub const MAX_CLOUD_POINTS: usize = 4_000_000;

/// The entries [`write()`] may create in its folder (the release's layout); it refuses a folder that
/// already holds one.
pub const RELEASE_ENTRIES: [&str; 11] = [
    "cameras_normalize.npz",
    "image",
    "val",
    "depth",
    "normal",
    "light_mask",
    "mask",
    "hdr",
    "material",
    "mesh.ply",
    RADIOMETRY_FILE,
];

/// What [`write()`] wrote, for the caller's summary.
#[derive(Clone, Debug, Default)]
pub struct Written {
    pub train_views: usize,
    pub test_views: usize,
    /// Points of the `mesh.ply` point cloud (`None`: no cloud; see `mesh_faces`).
    pub cloud_points: Option<usize>,
    /// Triangles of the `mesh.ply` mesh (`None`: no mesh written, or a cloud).
    pub mesh_faces: Option<usize>,
    /// What the dataset has that the format cannot hold, one line each.
    pub left_out: Vec<String>,
}

/// Writes `dataset` into `dir` (created if needed; holding none of [`RELEASE_ENTRIES`]) in the
/// paper's release format. Everything the format would get wrong is refused before anything is written.
pub fn write(dataset: &Dataset, dir: &Path, options: &WriteOptions) -> Result<Written> {
    let (train, test) = check_writable(dataset, dir)?;
    std::fs::create_dir_all(dir).map_err(|e| DataError::io(dir, format!("cannot create: {e}")))?;
    write_cameras(&dir.join("cameras_normalize.npz"), dataset, &train, &test)?;
    let jobs: Vec<(&Frame, std::path::PathBuf, String)> = train
        .iter()
        .enumerate()
        .map(|(i, f)| (*f, dir.to_path_buf(), format!("{i:04}")))
        .chain(
            test.iter()
                .enumerate()
                .map(|(i, f)| (*f, dir.join("val"), format!("{i:04}"))),
        )
        .collect();
    // Views in parallel; the first error in view order is reported (not the first to happen).
    let results: Vec<Result<()>> = jobs
        .par_iter()
        .map(|(frame, base, name)| write_frame(frame, base, name, frame.split == Split::Train))
        .collect();
    results.into_iter().collect::<Result<()>>()?;
    let mut written = Written {
        train_views: train.len(),
        test_views: test.len(),
        left_out: left_out(dataset),
        ..Default::default()
    };
    if let Some(mesh_path) = &dataset.mesh_path {
        let mesh = crate::ply::read_ply(mesh_path)?;
        let out = match options.point_cloud_density {
            Some(density) => {
                let cloud = sample_surface(&mesh, density);
                written.cloud_points = Some(cloud.positions.len());
                cloud
            }
            None => {
                written.mesh_faces = Some(mesh.faces.len());
                mesh
            }
        };
        crate::ply::write_ply(dir.join("mesh.ply"), &out)?;
    }
    let mut ldr = serde_json::json!({"transfer": dataset.radiometry.transfer.name()});
    if let Some(e) = dataset.radiometry.exposure {
        ldr["exposure"] = serde_json::json!(e);
    }
    let json = serde_json::to_string_pretty(&serde_json::json!({ "ldr": ldr })).expect("JSON");
    imageio::write_bytes_atomic(&dir.join(RADIOMETRY_FILE), json.as_bytes())?;
    Ok(written)
}

/// The training and test frames, in the dataset's order, once everything the format would get
/// wrong is ruled out: no test views, views of different sizes (the reader gives every camera the
/// first image's size), lens distortion (the projection matrices are pinhole), a non-empty `dir`.
fn check_writable<'a>(dataset: &'a Dataset, dir: &Path) -> Result<(Vec<&'a Frame>, Vec<&'a Frame>)> {
    let train: Vec<&Frame> = dataset.split(Split::Train).collect();
    let test: Vec<&Frame> = dataset.split(Split::Test).collect();
    if train.is_empty() || test.is_empty() {
        return Err(DataError::invalid(format!(
            "{}: the paper's format needs training and test views (found {} and {}): without val/ its \
             reader holds out views of its own",
            dataset.root.display(),
            train.len(),
            test.len()
        )));
    }
    let first = &train[0].camera;
    for f in train.iter().chain(&test) {
        if (f.camera.width, f.camera.height) != (first.width, first.height) {
            return Err(DataError::file(
                &f.image_path,
                format!(
                    "is {}×{} but the first training view is {}×{}: the paper's format has one image size",
                    f.camera.width, f.camera.height, first.width, first.height
                ),
            ));
        }
        if !f.camera.lens.is_pinhole() {
            return Err(DataError::file(
                &f.image_path,
                format!(
                    "is taken through a {} lens: the paper's format has pinhole cameras only",
                    f.camera.lens.model_name()
                ),
            ));
        }
    }
    if dir.is_file() {
        return Err(DataError::file(dir, "is a file, not a folder"));
    }
    // Another dataset's files would be mixed with (or read as) the written ones; anything else in
    // the folder (a caller's scratch space, provenance) is left alone.
    if let Some(name) = RELEASE_ENTRIES.iter().find(|n| dir.join(n).exists()) {
        return Err(DataError::file(
            dir.join(name),
            "exists: the paper's format would be written over it",
        ));
    }
    Ok((train, test))
}

/// The dataset's contents the format has no place for.
fn left_out(dataset: &Dataset) -> Vec<String> {
    let mut notes = Vec::new();
    if !dataset.relight.is_empty() {
        notes.push(format!(
            "{} relit test set(s) (relight/): the paper's format has no relit views",
            dataset.relight.len()
        ));
    }
    if !dataset.emitters.is_empty() {
        notes.push(format!(
            "{} GT emitter(s): the format has emitter masks only",
            dataset.emitters.len()
        ));
    }
    if !dataset.objects.is_empty() {
        notes.push(format!("{} named object(s)", dataset.objects.len()));
    }
    if !dataset.poses_exact {
        notes.push("the poses are approximate, but the format's reader takes them as exact".to_string());
    }
    if !dataset.depth_exact && dataset.frames.iter().any(|f| f.depth.is_some()) {
        notes.push("the depth is a sensor's, but the format's reader takes it as exact".to_string());
    }
    notes
}

/// P = K·W2C with the release's integer-pixel principal point (ours − ½), rows of a 4×4 matrix.
/// The rotation is orthonormalized first: a pose read from f32 text is a rotation only to ~1e-7,
/// and the reader's RQ decomposition would fold that error into the intrinsics (fx off by ~1e-6
/// at 15 px); orthonormal, K comes back as written and the pose within ~1e-7.
fn projection(cam: &Camera) -> [[f64; 4]; 4] {
    let k = DMat3::from_cols(
        DVec3::new(cam.fx, 0.0, 0.0),
        DVec3::new(0.0, cam.fy, 0.0),
        DVec3::new(cam.cx - 0.5, cam.cy - 0.5, 1.0),
    );
    let w2c = crate::camera::rigid(orthonormal(cam.rotation()), cam.center()).inverse();
    let mut p = [[0.0; 4]; 4];
    for (i, row) in p.iter_mut().enumerate().take(3) {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|l| k.col(l)[i] * w2c.col(j)[l]).sum();
        }
    }
    p[3] = [0.0, 0.0, 0.0, 1.0];
    p
}

/// The rotation nearest `c2w_rotation` by Gram–Schmidt on the rows of its inverse (W2C), in the
/// order the reader's RQ decomposition takes them (last row first), so that the decomposition of
/// K·R gives back K exactly.
fn orthonormal(c2w_rotation: DMat3) -> DMat3 {
    let w2c = c2w_rotation.transpose();
    let rows = [w2c.row(0), w2c.row(1), w2c.row(2)];
    let r3 = rows[2].normalize();
    let r2 = (rows[1] - rows[1].dot(r3) * r3).normalize();
    let r1 = (rows[0] - rows[0].dot(r3) * r3 - rows[0].dot(r2) * r2).normalize();
    // Rows of W2C are the columns of C2W.
    DMat3::from_cols(r1, r2, r3)
}

/// `cameras_normalize.npz`: `world_mat_i` and `scale_mat_i` per training view, `val_mat_i` per
/// test view. Written aside and renamed, so a failed write leaves no partial archive.
fn write_cameras(path: &Path, dataset: &Dataset, train: &[&Frame], test: &[&Frame]) -> Result<()> {
    let n = &dataset.normalization;
    let s = n.scale;
    // VolSDF's scale_mat maps normalized → world coordinates: x_w = s·x_n + centre.
    let scale_mat = [
        [s, 0.0, 0.0, n.center[0]],
        [0.0, s, 0.0, n.center[1]],
        [0.0, 0.0, s, n.center[2]],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let mut matrices: Vec<(String, [[f64; 4]; 4])> = Vec::new();
    for (i, f) in train.iter().enumerate() {
        matrices.push((format!("world_mat_{i}"), projection(&f.camera)));
        matrices.push((format!("scale_mat_{i}"), scale_mat));
    }
    for (i, f) in test.iter().enumerate() {
        matrices.push((format!("val_mat_{i}"), projection(&f.camera)));
    }
    imageio::write_atomic(path, |tmp| {
        use npyz::WriterBuilder;
        let err = |e: std::io::Error| e.to_string();
        let mut npz = npyz::npz::NpzWriter::create(tmp).map_err(err)?;
        for (name, m) in &matrices {
            let mut w = npz
                .array::<f64>(name, Default::default())
                .map_err(err)?
                .default_dtype()
                .shape(&[4, 4])
                .begin_nd()
                .map_err(err)?;
            w.extend(m.iter().flatten().copied()).map_err(err)?;
            w.finish().map_err(err)?;
        }
        drop(npz); // finishes the zip archive
        Ok(())
    })
}

/// One view's image and annotations under `base` (the dataset's root, or `val/`), as `name`.
fn write_frame(frame: &Frame, base: &Path, name: &str, train: bool) -> Result<()> {
    let image_dir = if train { base.join("image") } else { base.to_path_buf() };
    // PNG: lossless for the 8-bit values every reader gives (a JPEG's decoded pixels included).
    imageio::write_png(&image_dir.join(format!("{name}.png")), &frame.rgb)?;
    let exr = |sub: &str, file: String, img: &ImageF32| imageio::write_exr(&base.join(sub).join(file), img);
    if let Some(depth) = &frame.depth {
        let rgb = depth.data.iter().flat_map(|d| [*d; 3]).collect();
        exr(
            "depth",
            format!("{name}.exr"),
            &ImageF32::from_data(depth.width, depth.height, 3, rgb),
        )?;
    }
    if let Some(normal) = &frame.normal {
        let rt = frame.camera.rotation().transpose();
        let mut cam_space = normal.clone();
        for px in cam_space.data.chunks_mut(3) {
            let n = rt * DVec3::new(px[0] as f64, px[1] as f64, px[2] as f64);
            px.copy_from_slice(&[n.x as f32, n.y as f32, n.z as f32]);
        }
        exr("normal", format!("{name}.exr"), &cam_space)?;
    }
    if let Some(m) = &frame.emitter_mask {
        imageio::write_png(&base.join("light_mask").join(format!("{name}.png")), m)?;
    }
    let ones;
    let material_mask = match &frame.material_mask {
        Some(m) => m,
        None => {
            ones = ImageF32::from_data(
                frame.camera.width,
                frame.camera.height,
                1,
                vec![1.0; frame.pixel_count()],
            );
            &ones
        }
    };
    imageio::write_png(&base.join("mask").join(format!("{name}.png")), material_mask)?;
    if let Some(hdr) = &frame.hdr {
        exr("hdr", format!("{name}.exr"), hdr)?;
    }
    for (map, suffix) in [
        (&frame.albedo, "kd"),
        (&frame.specular, "ks"),
        (&frame.roughness, "rough"),
    ] {
        if let Some(m) = map {
            exr("material", format!("{name}_{suffix}.exr"), m)?;
        }
    }
    Ok(())
}

/// About `density` points per square unit of `mesh`'s surface (at least one, at most
/// [`MAX_CLOUD_POINTS`]), as a vertices-only mesh. Deterministic: stratified over the cumulative
/// area (so every face gets its share, up to one point), barycentric coordinates from the R2
/// low-discrepancy sequence.
pub fn sample_surface(mesh: &TriangleMesh, density: f64) -> TriangleMesh {
    let mut cumulative = Vec::with_capacity(mesh.faces.len());
    let mut total = 0.0;
    for f in 0..mesh.faces.len() {
        total += mesh.face_area(f);
        cumulative.push(total);
    }
    if total <= 0.0 || !total.is_finite() {
        return TriangleMesh::default();
    }
    let count = ((total * density).round().max(1.0) as usize).min(MAX_CLOUD_POINTS);
    // R2 sequence (Roberts 2018): the plastic number's powers give well-spread 2D samples.
    let (a1, a2) = (0.754_877_666_246_692_8_f64, 0.569_840_290_998_053_3_f64);
    let positions = (0..count)
        .map(|k| {
            let target = (k as f64 + 0.5) / count as f64 * total;
            let face = cumulative.partition_point(|c| *c < target).min(mesh.faces.len() - 1);
            let (mut u, mut v) = ((0.5 + a1 * k as f64).fract(), (0.5 + a2 * k as f64).fract());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            let [p0, p1, p2] = mesh.triangle(face);
            let w = 1.0 - u - v;
            std::array::from_fn(|c| (w * p0[c] as f64 + u * p1[c] as f64 + v * p2[c] as f64) as f32)
        })
        .collect();
    TriangleMesh {
        positions,
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixture::{self, FixtureOptions, PaperOptions};

    fn max_diff(a: Option<&ImageF32>, b: Option<&ImageF32>) -> f32 {
        match (a, b) {
            (Some(a), Some(b)) => {
                assert_eq!((a.width, a.height, a.channels), (b.width, b.height, b.channels));
                a.data
                    .iter()
                    .zip(&b.data)
                    .map(|(x, y)| (x - y).abs())
                    .fold(0.0, f32::max)
            }
            (None, None) => 0.0,
            _ => panic!("a map present in one dataset only"),
        }
    }

    /// The fixture's release (material masks with zeros, GT materials, HDR, validation maps, a
    /// point cloud, a declared radiometry), loaded, written and loaded again, is the same dataset.
    #[test]
    fn a_paper_dataset_written_back_loads_the_same() {
        let dir = tempfile::tempdir().unwrap();
        let (src, dst) = (dir.path().join("src"), dir.path().join("dst"));
        let extra = PaperOptions {
            val_maps: true,
            material_masks: true,
            materials: true,
            hdr_exposure: Some(0.7),
            point_cloud: true,
            radiometry_json: Some(r#"{"ldr": {"transfer": "srgb", "exposure": 0.7}}"#.into()),
            ..Default::default()
        };
        fixture::write_paper_with(&src, &FixtureOptions::default(), &extra);
        let a = crate::load(&src).unwrap();
        let written = write(&a, &dst, &WriteOptions::default()).unwrap();
        assert_eq!(written.mesh_faces, Some(0));
        let b = crate::load(&dst).unwrap();
        assert_eq!(a.frames.len(), b.frames.len());
        assert_eq!(a.radiometry, b.radiometry);
        assert!(a.normalization.same_as(&b.normalization));
        for (fa, fb) in a.frames.iter().zip(&b.frames) {
            assert_eq!(fa.split, fb.split);
            let (ca, cb) = (&fa.camera, &fb.camera);
            let k = [ca.fx - cb.fx, ca.fy - cb.fy, ca.cx - cb.cx, ca.cy - cb.cy];
            assert!(k.iter().all(|d| d.abs() < 1e-9), "{k:?}");
            assert!(ca.c2w.abs_diff_eq(cb.c2w, 1e-9));
            let maps = fa.maps().into_iter().zip(fb.maps());
            for ((ma, mb), name) in maps.zip(Frame::MAP_NAMES) {
                let tol = if name == "normal" { 1e-6 } else { 0.0 };
                assert!(max_diff(ma, mb) <= tol, "{}: {name}", fa.name);
            }
        }
        let zeros = b.frames.iter().flat_map(|f| &f.material_mask.as_ref().unwrap().data);
        assert!(zeros.filter(|v| **v == 0.0).count() > 0, "the non-GGX wall is kept");
        // The written folder refuses a second write over it, before writing anything.
        let err = write(&a, &dst, &WriteOptions::default()).unwrap_err().to_string();
        assert!(err.contains("cameras_normalize.npz"), "{err}");
    }

    #[test]
    fn a_point_cloud_lies_on_the_surface_with_the_asked_density() {
        let mesh = TriangleMesh::axis_box([0.0; 3], [1.0, 2.0, 3.0]);
        let cloud = sample_surface(&mesh, 100.0);
        assert!(cloud.faces.is_empty());
        assert_eq!(cloud.positions.len(), 2200); // area 2·(2 + 3 + 6) = 22
        for p in &cloud.positions {
            let on_face = (0..3).any(|a| p[a].abs() < 1e-5 || (p[a] - [1.0, 2.0, 3.0][a]).abs() < 1e-5);
            let inside = (0..3).all(|a| p[a] >= -1e-5 && p[a] <= [1.0, 2.0, 3.0][a] + 1e-5);
            assert!(on_face && inside, "{p:?}");
        }
        // Each of the largest faces (x·y = 1·2 ... the 2×3 pair) gets its share of the points.
        let on_x0 = cloud.positions.iter().filter(|p| p[0].abs() < 1e-5).count();
        assert!((on_x0 as f64 - 600.0).abs() <= 2.0, "{on_x0}");
    }
}
