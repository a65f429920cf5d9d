//! The COLMAP format, tested on models written by COLMAP's own code (pycolmap:
//! `tests/fixtures/colmap/make_fixtures.py`, binary in `bin/sparse/0/`, text in `txt/sparse/`)
//! and on the analytic room of `fixture` exported as a COLMAP model at another scale.

use glam::DVec3;
use i2sdf_data::colmap;
use i2sdf_data::dataset::BoundsSource;
use i2sdf_data::fixture::{self, DepthFormat, FixtureOptions};
use i2sdf_data::imageio::{self, ImageF32};
use i2sdf_data::{load, DataError, Dataset, Format, Lens, Split};
use std::path::{Path, PathBuf};

fn fixture_root(kind: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/colmap")
        .join(kind)
}

/// The model folder inside a fixture dataset.
fn model_dir(root: &Path) -> PathBuf {
    colmap::model_dir(root).unwrap()
}

fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dest = to.join(e.file_name());
        if e.path().is_dir() {
            copy_tree(&e.path(), &dest);
        } else {
            std::fs::copy(e.path(), dest).unwrap();
        }
    }
}

/// A dataset folder of the `bin` or `txt` fixture with its images (32×24, a gradient).
fn dataset(kind: &str) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    copy_tree(&fixture_root(kind), dir.path());
    let img = ImageF32::from_data(32, 24, 3, (0..32 * 24 * 3).map(|i| (i % 97) as f32 / 97.0).collect());
    for i in 0..9 {
        imageio::write_png(&dir.path().join(format!("images/view_{i:02}.png")), &img).unwrap();
    }
    dir
}

/// pycolmap 4.2.1's projections (Image.project_point, equal to Camera.img_from_cam of the point in
/// camera space), printed by make_fixtures.py: (image, point, pixel).
#[rustfmt::skip]
const PYCOLMAP_PROJECTIONS: [(&str, [f64; 3], [f64; 2]); 18] = [
    ("view_00.png", [0.1501145599256004, 0.47665656116349064, 0.33082282829423215], [22.16981421202042, 9.685049306183242]),
    ("view_00.png", [-0.32975137201128973, -0.23980045810652945, 0.44826413447551416], [15.02232478086489, 7.892981508919426]),
    ("view_01.png", [0.1501145599256004, 0.47665656116349064, 0.33082282829423215], [18.82342211495752, 11.312794666749497]),
    ("view_01.png", [-0.32975137201128973, -0.23980045810652945, 0.44826413447551416], [15.967310616463982, 8.40499004942828]),
    ("view_02.png", [0.1501145599256004, 0.47665656116349064, 0.33082282829423215], [15.217071900696576, 9.406904229343422]),
    ("view_02.png", [-0.32975137201128973, -0.23980045810652945, 0.44826413447551416], [18.594047130164743, 7.725900937426545]),
    ("view_03.png", [0.1501145599256004, 0.47665656116349064, 0.33082282829423215], [11.952615954229593, 9.594282509211785]),
    ("view_03.png", [-0.32975137201128973, -0.23980045810652945, 0.44826413447551416], [19.775727315364925, 7.85877093195111]),
    ("view_04.png", [0.1501145599256004, 0.47665656116349064, 0.33082282829423215], [12.029630284023646, 8.384831560655314]),
    ("view_04.png", [-0.32975137201128973, -0.23980045810652945, 0.44826413447551416], [20.67369892956137, 7.7420658046482895]),
    ("view_05.png", [0.1501145599256004, 0.47665656116349064, 0.33082282829423215], [11.80983667523461, 8.555517622192554]),
    ("view_05.png", [-0.32975137201128973, -0.23980045810652945, 0.44826413447551416], [16.370237786921916, 7.728953612880571]),
    ("view_06.png", [0.1501145599256004, 0.47665656116349064, 0.33082282829423215], [15.226242592951802, 8.48678022657234]),
    ("view_06.png", [-0.32975137201128973, -0.23980045810652945, 0.44826413447551416], [14.268334681326898, 8.467629607679296]),
    ("view_07.png", [0.1501145599256004, 0.47665656116349064, 0.33082282829423215], [17.915201819492303, 8.871624188295357]),
    ("view_07.png", [-0.32975137201128973, -0.23980045810652945, 0.44826413447551416], [11.912144575344806, 9.01359935073319]),
    ("view_08.png", [0.1501145599256004, 0.47665656116349064, 0.33082282829423215], [20.08948501102601, 9.059480762311207]),
    ("view_08.png", [-0.32975137201128973, -0.23980045810652945, 0.44826413447551416], [11.892128291540368, 7.9790088480104435]),
];

fn frame<'a>(ds: &'a Dataset, image: &str) -> &'a i2sdf_data::Frame {
    ds.frames
        .iter()
        .find(|f| f.image_path.file_name().unwrap() == image)
        .unwrap_or_else(|| panic!("no frame {image}"))
}

#[test]
fn binary_and_text_models_read_the_same() {
    let bin = colmap::read_model(&fixture_root("bin").join("sparse/0")).unwrap();
    let txt = colmap::read_model(&fixture_root("txt").join("sparse")).unwrap();
    assert_eq!(bin.cameras.len(), 6);
    assert_eq!(bin.images.len(), 9);
    assert_eq!(bin.points.len(), 12);
    let models: Vec<&str> = bin.cameras.values().map(|c| c.model).collect();
    assert_eq!(
        models,
        [
            "SIMPLE_PINHOLE",
            "PINHOLE",
            "SIMPLE_RADIAL",
            "RADIAL",
            "OPENCV",
            "OPENCV_FISHEYE"
        ]
    );
    let close = |a: &[f64], b: &[f64]| a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-12);
    for (id, c) in &bin.cameras {
        let t = &txt.cameras[id];
        assert_eq!((c.model, c.width, c.height), (t.model, t.width, t.height));
        assert!(
            close(&c.params, &t.params),
            "camera {id}: {:?} vs {:?}",
            c.params,
            t.params
        );
    }
    for (id, i) in &bin.images {
        let t = &txt.images[id];
        assert_eq!((&i.name, i.camera_id), (&t.name, t.camera_id));
        assert!(close(&i.qvec, &t.qvec) && close(&i.tvec, &t.tvec), "image {id}");
        assert_eq!(i.points2d.len(), t.points2d.len());
        for (a, b) in i.points2d.iter().zip(&t.points2d) {
            assert!((a.0 - b.0).length() <= 1e-12 && a.1 == b.1);
        }
    }
    for (id, p) in &bin.points {
        let t = &txt.points[id];
        assert!((p.xyz - t.xyz).length() <= 1e-12);
        assert_eq!((p.rgb, &p.track), (t.rgb, &t.track));
    }
}

#[test]
fn every_camera_model_loads_from_bin_and_txt_alike() {
    let (bin_dir, txt_dir) = (dataset("bin"), dataset("txt"));
    let bin = load(bin_dir.path()).unwrap();
    let txt = load(txt_dir.path()).unwrap();
    assert_eq!(bin.format, Format::Colmap);
    // No depth: COLMAP's units, the extent from the SfM points.
    assert_eq!(bin.colmap_scale, None);
    assert_eq!(bin.bounds_source, BoundsSource::SfmPoints);
    // Every 8th image in name order is a test view.
    assert_eq!((bin.count(Split::Train), bin.count(Split::Test)), (7, 2));
    assert_eq!(bin.frames[0].split, Split::Test);
    assert_eq!(bin.frames[8].split, Split::Test);
    for (a, b) in bin.frames.iter().zip(&txt.frames) {
        assert_eq!(a.name, b.name);
        assert!(a.camera.c2w.abs_diff_eq(b.camera.c2w, 1e-12), "{}", a.name);
        let (ca, cb) = (&a.camera, &b.camera);
        for (x, y) in [(ca.fx, cb.fx), (ca.fy, cb.fy), (ca.cx, cb.cx), (ca.cy, cb.cy)] {
            assert!((x - y).abs() <= 1e-12);
        }
        assert_eq!(ca.lens, cb.lens);
    }
    // The parameters land where each model puts them (view k uses camera k % 6 + 1).
    let cam = |k: usize| &bin.frames[k].camera;
    assert_eq!((cam(0).fx, cam(0).fy, cam(0).cx, cam(0).cy), (30.0, 30.0, 16.2, 11.9));
    assert_eq!(cam(0).lens, Lens::Pinhole);
    assert_eq!((cam(1).fx, cam(1).fy, cam(1).cx, cam(1).cy), (31.0, 29.5, 15.8, 12.3));
    let bc = |k1, k2, p1, p2| Lens::BrownConrady {
        k1,
        k2,
        k3: 0.0,
        p1,
        p2,
    };
    assert_eq!(cam(2).lens, bc(-0.08, 0.0, 0.0, 0.0));
    assert_eq!(cam(3).lens, bc(-0.06, 0.02, 0.0, 0.0));
    assert_eq!(cam(4).lens, bc(-0.05, 0.01, 0.002, -0.001));
    assert_eq!((cam(4).fx, cam(4).fy), (30.5, 29.8));
    assert_eq!(
        cam(5).lens,
        Lens::Fisheye {
            k1: 0.03,
            k2: -0.01,
            k3: 0.002,
            k4: -0.0005
        }
    );
    // The points' extent, not the cameras' circle of radius 3, sets the normalization.
    let summary = i2sdf_data::Summary::of(&bin).to_string();
    assert!(summary.contains("COLMAP's own units"), "{summary}");
    assert!(summary.contains("SfM points"), "{summary}");
}

#[test]
fn projections_match_pycolmaps() {
    let dir = dataset("bin");
    let ds = load(dir.path()).unwrap();
    for (image, xyz, uv) in PYCOLMAP_PROJECTIONS {
        let (u, v, _) = frame(&ds, image).camera.project(DVec3::from(xyz)).unwrap();
        let err = ((u - uv[0]).powi(2) + (v - uv[1]).powi(2)).sqrt();
        assert!(err < 1e-9, "{image}: ({u}, {v}) vs pycolmap's {uv:?}");
    }
    // And every observation the model records is where our camera projects its point.
    let model = colmap::read_model(&model_dir(dir.path())).unwrap();
    let mut checked = 0;
    for image in model.images.values() {
        let camera = &frame(&ds, &image.name).camera;
        for (xy, pid) in &image.points2d {
            let p = model.points[&(*pid as u64)].xyz;
            let (u, v, _) = camera.project(p).unwrap();
            assert!((u - xy.x).abs() < 1e-9 && (v - xy.y).abs() < 1e-9, "{}", image.name);
            checked += 1;
        }
    }
    assert_eq!(checked, 9 * 12);
}

/// Loads `dir` expecting bad input whose message names `file` and says `what`.
fn assert_refused(dir: &Path, file: &str, what: &str) {
    let e: DataError = load(dir).unwrap_err();
    let msg = e.to_string();
    assert!(e.is_bad_input(), "{msg}");
    assert!(
        msg.contains(file) && msg.contains(what),
        "expected '{file}' and '{what}' in: {msg}"
    );
}

/// Replaces field `index` of the first data line of a text model file.
fn edit_first_record(path: &Path, index: usize, value: &str) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut done = false;
    let lines: Vec<String> = text
        .lines()
        .map(|l| {
            if done || l.starts_with('#') || l.trim().is_empty() {
                return l.to_string();
            }
            done = true;
            let mut f: Vec<&str> = l.split_whitespace().collect();
            f[index] = value;
            f.join(" ")
        })
        .collect();
    std::fs::write(path, lines.join("\n") + "\n").unwrap();
}

#[test]
fn truncated_binary_files_are_refused_naming_them() {
    for file in ["cameras.bin", "images.bin", "points3D.bin"] {
        for keep in [0usize, 5, 60, 407] {
            let dir = dataset("bin");
            let path = model_dir(dir.path()).join(file);
            let bytes = std::fs::read(&path).unwrap();
            std::fs::write(&path, &bytes[..keep.min(bytes.len() - 1)]).unwrap();
            assert_refused(dir.path(), file, "truncated");
        }
    }
}

#[test]
fn unknown_camera_models_are_refused_naming_file_and_id() {
    // cameras.bin: u64 count, then the first camera's i32 id and i32 model id.
    let dir = dataset("bin");
    let path = model_dir(dir.path()).join("cameras.bin");
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[12..16].copy_from_slice(&6i32.to_le_bytes());
    std::fs::write(&path, &bytes).unwrap();
    assert_refused(
        dir.path(),
        "cameras.bin",
        "camera model id 6 (FULL_OPENCV) is not supported",
    );
    let dir = dataset("txt");
    edit_first_record(&model_dir(dir.path()).join("cameras.txt"), 1, "FOV");
    assert_refused(dir.path(), "cameras.txt", "FOV");
}

#[test]
fn bad_images_are_refused_naming_the_file() {
    // An image whose camera is not in cameras.txt.
    let dir = dataset("txt");
    edit_first_record(&model_dir(dir.path()).join("images.txt"), 8, "42");
    assert_refused(dir.path(), "images.txt", "camera id 42 is not in cameras.txt");
    // A zero quaternion.
    let dir = dataset("txt");
    let images = model_dir(dir.path()).join("images.txt");
    for k in 1..5 {
        edit_first_record(&images, k, "0");
    }
    assert_refused(dir.path(), "images.txt", "has norm 0");
    // A non-finite translation.
    let dir = dataset("txt");
    edit_first_record(&model_dir(dir.path()).join("images.txt"), 6, "nan");
    assert_refused(dir.path(), "images.txt", "non-finite");
    // An image the model names that images/ does not have.
    let dir = dataset("bin");
    std::fs::remove_file(dir.path().join("images/view_03.png")).unwrap();
    assert_refused(dir.path(), "view_03.png", "file not found");
    // An image of another aspect ratio than its camera.
    let dir = dataset("bin");
    imageio::write_png(&dir.path().join("images/view_04.png"), &ImageF32::new(32, 32, 3)).unwrap();
    assert_refused(dir.path(), "view_04.png", "does not match camera 5's 32×24");
    // An observation of a 3D point points3D does not have.
    let dir = dataset("txt");
    std::fs::write(
        model_dir(dir.path()).join("points3D.txt"),
        std::fs::read_to_string(model_dir(dir.path()).join("points3D.txt"))
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with("3 "))
            .collect::<Vec<_>>()
            .join("\n"),
    )
    .unwrap();
    assert_refused(dir.path(), "images.txt", "refers to 3D point 3");
}

#[test]
fn a_downscaled_image_gets_its_camera_scaled() {
    let dir = dataset("bin");
    imageio::write_png(&dir.path().join("images/view_01.png"), &ImageF32::new(16, 12, 3)).unwrap();
    let ds = load(dir.path()).unwrap();
    let c = &frame(&ds, "view_01.png").camera;
    assert_eq!(
        (c.width, c.height, c.fx, c.fy, c.cx, c.cy),
        (16, 12, 15.5, 14.75, 7.9, 6.15)
    );
}

/// The model written at 1/s of the world's scale comes back at the world's, from the depth maps.
#[test]
fn the_scale_is_recovered_from_depth() {
    for (depth, model_scale) in [(DepthFormat::Png16, 0.37), (DepthFormat::Exr, 2.9)] {
        let dir = tempfile::tempdir().unwrap();
        let opts = FixtureOptions {
            width: 40,
            height: 30,
            depth,
            ..Default::default()
        };
        let truth = fixture::write_colmap(dir.path(), &opts, model_scale);
        let ds = load(dir.path()).unwrap();
        let fix = ds.colmap_scale.expect("depth maps: the scale is fixed");
        let err = (fix.ratio * model_scale - 1.0).abs();
        println!(
            "{depth:?}, model at ×{model_scale}: ratio {:.6} (true {:.6}), error {:.3e}, spread {:.3e}, {} samples in {} views",
            fix.ratio,
            1.0 / model_scale,
            err,
            fix.spread,
            fix.samples,
            fix.views
        );
        assert!(err < 0.01, "ratio {} vs {}", fix.ratio, 1.0 / model_scale);
        assert_eq!(fix.views, 6);
        assert_eq!(ds.bounds_source, BoundsSource::Depth);
        // test.txt holds the last two views out.
        assert_eq!((ds.count(Split::Train), ds.count(Split::Test)), (4, 2));
        for (f, c) in ds.frames.iter().zip(&truth) {
            let d = (f.camera.center() - c.center()).length();
            assert!(d < 0.01 * c.center().length().max(1.0), "{}: off by {d}", f.name);
            assert!(f.camera.rotation().abs_diff_eq(c.rotation(), 1e-9));
            assert!(f.emitter_mask.is_some() && f.depth.is_some());
        }
        let summary = i2sdf_data::Summary::of(&ds).to_string();
        assert!(summary.contains("scale        COLMAP model ×"), "{summary}");
    }
}

#[test]
fn depth_without_any_observed_point_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    fixture::write_colmap(dir.path(), &FixtureOptions::default(), 1.0);
    let sparse = dir.path().join("sparse/0");
    std::fs::write(sparse.join("points3D.txt"), "# none\n").unwrap();
    let images = std::fs::read_to_string(sparse.join("images.txt")).unwrap();
    // Keep the pose lines, empty the observation lines.
    let lines: Vec<&str> = images.lines().collect();
    let mut out = vec![lines[0]];
    for pair in lines[1..].chunks(2) {
        out.push(pair[0]);
        out.push("");
    }
    std::fs::write(sparse.join("images.txt"), out.join("\n")).unwrap();
    assert_refused(dir.path(), "depth", "scale cannot be tied");
}

/// Every prefix of each binary file is refused (naming it), and no single corrupted byte makes
/// the parser panic or allocate what the file cannot hold.
#[test]
fn truncations_and_corrupted_bytes_are_errors_not_panics() {
    type Parse = fn(&Path, &[u8]) -> bool;
    let parsers: [(&str, Parse); 3] = [
        ("cameras.bin", |p, b| colmap::parse_cameras_bin(p, b).is_ok()),
        ("images.bin", |p, b| colmap::parse_images_bin(p, b).is_ok()),
        ("points3D.bin", |p, b| colmap::parse_points_bin(p, b).is_ok()),
    ];
    for (file, parse) in parsers {
        let path = fixture_root("bin").join("sparse/0").join(file);
        let bytes = std::fs::read(&path).unwrap();
        assert!(parse(&path, &bytes), "{file}");
        for keep in 0..bytes.len() {
            assert!(!parse(&path, &bytes[..keep]), "{file} cut to {keep} bytes was accepted");
        }
        for pos in 0..bytes.len() {
            for value in [0x00, 0x7f, 0xff] {
                let mut b = bytes.clone();
                b[pos] = value;
                let _ = parse(&path, &b);
            }
        }
    }
}
