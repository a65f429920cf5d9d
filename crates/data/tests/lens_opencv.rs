//! Lens models against OpenCV: pixel positions from `cv2.projectPoints` / `cv2.fisheye.projectPoints`
//! and normalized coordinates from `cv2.undistortPoints` / `cv2.fisheye.undistortPoints`, made by
//! `fixtures/lens/opencv_reference.py` (opencv-python-headless, used only to make these values).
//! Both dataset formats name these models as COLMAP does (SIMPLE_RADIAL, RADIAL, OPENCV,
//! OPENCV_FISHEYE); a camera's projection and unprojection must match OpenCV's.

use glam::{DMat4, DVec3};
use i2sdf_data::{Camera, Lens};

const POINTS: [[f64; 3]; 6] = [
    [0.0, 0.0, 1.0],
    [0.3, -0.2, 1.0],
    [-0.45, 0.31, 1.2],
    [0.52, 0.38, 0.9],
    [-0.61, -0.44, 1.5],
    [0.05, 0.4, 0.7],
];

// SIMPLE_RADIAL: {'k1': -0.11}
const SIMPLE_RADIAL_UV: [[f64; 2]; 6] = [
    [321.5, 243.25],
    [472.90351999999996, 143.10288],
    [133.87946666666667, 371.48993745370376],
    [600.6583007956104, 445.6565444170096],
    [119.04510715259264, 98.3578456414815],
    [356.73731778425656, 522.9462099125365],
];
const SIMPLE_RADIAL_NORMALIZED: [[f64; 2]; 6] = [
    [0.0, 0.0],
    [0.29999999999999993, -0.2],
    [-0.37499999999999994, 0.2583333333333334],
    [0.5777777777777778, 0.4222222222222223],
    [-0.4066666666666665, -0.2933333333333333],
    [0.07142857142857144, 0.5714285714285715],
];
// RADIAL: {'k1': -0.11, 'k2': 0.035}
const RADIAL_UV: [[f64; 2]; 6] = [
    [321.5, 243.25],
    [472.99437439999997, 143.0427836],
    [133.59051587037038, 371.687437329575],
    [603.3735287560094, 447.6252478630561],
    [118.58444354693165, 98.02815964911039],
    [356.8780924614744, 524.063608912953],
];
const RADIAL_NORMALIZED: [[f64; 2]; 6] = [
    [0.0, 0.0],
    [0.3, -0.19999999999999998],
    [-0.37499999999999994, 0.25833333333333336],
    [0.5777777777777777, 0.42222222222222217],
    [-0.40666666666666657, -0.2933333333333333],
    [0.07142857142857147, 0.5714285714285714],
];
// OPENCV: {'k1': -0.28, 'k2': 0.07, 'p1': 0.0012, 'p2': -0.0007}
const OPENCV_UV: [[f64; 2]; 6] = [
    [321.5, 243.25],
    [469.5058368, 145.39873519999998],
    [139.77567351851852, 367.5354494369277],
    [580.2123666148996, 431.277263594425],
    [126.9611176360855, 104.24090255155411],
    [354.8847003748438, 509.3866510620575],
];
const OPENCV_NORMALIZED: [[f64; 2]; 6] = [
    [0.0, 0.0],
    [0.3, -0.20000000000000007],
    [-0.375, 0.2583333333333333],
    [0.577777777777778, 0.4222222222222223],
    [-0.40666666666666657, -0.2933333333333333],
    [0.07142857142857142, 0.5714285714285714],
];
// OPENCV_K3: {'k1': 0.12, 'k2': -0.03, 'p1': -0.002, 'p2': 0.003, 'k3': 0.01}
const OPENCV_K3_UV: [[f64; 2]; 6] = [
    [321.5, 243.25],
    [478.020699392, 139.718079048],
    [125.90185958972734, 376.9497099204705],
    [634.8834729033053, 469.3812381947773],
    [108.01641579891933, 89.93304532858679],
    [359.8609662446284, 543.3599654851052],
];
const OPENCV_K3_NORMALIZED: [[f64; 2]; 6] = [
    [0.0, 0.0],
    [0.3, -0.2],
    [-0.375, 0.25833333333333336],
    [0.5777777777777777, 0.4222222222222222],
    [-0.4066666666666666, -0.2933333333333332],
    [0.07142857142857147, 0.5714285714285716],
];
// OPENCV_FISHEYE: {'k1': 0.05, 'k2': -0.01, 'k3': 0.002, 'k4': -0.0003}
const OPENCV_FISHEYE_UV: [[f64; 2]; 6] = [
    [321.5, 243.25],
    [469.7813866998883, 145.16804108913638],
    [139.7438232801537, 367.4816089836866],
    [582.862408522778, 432.7534530545262],
    [126.50178649589569, 103.69441379854828],
    [355.1107526839098, 510.03534942853446],
];
const OPENCV_FISHEYE_NORMALIZED: [[f64; 2]; 6] = [
    [0.0, 0.0],
    [0.3, -0.20000000000000004],
    [-0.37499999999999994, 0.2583333333333333],
    [0.5777777777777777, 0.4222222222222221],
    [-0.40666666666666673, -0.2933333333333334],
    [0.07142857142857138, 0.5714285714285715],
];

fn camera(model: &str, coefficients: &[(&str, f64)]) -> Camera {
    let lens = Lens::from_model(model, |k| coefficients.iter().find(|c| c.0 == k).map(|c| c.1)).unwrap();
    Camera {
        width: 640,
        height: 480,
        fx: 512.0,
        fy: 508.0,
        cx: 321.5,
        cy: 243.25,
        c2w: DMat4::IDENTITY,
        lens,
    }
}

fn check(cam: &Camera, uv: &[[f64; 2]; 6], normalized: &[[f64; 2]; 6]) {
    cam.validate().unwrap();
    for (i, p) in POINTS.iter().enumerate() {
        let p = DVec3::from_array(*p);
        // Projection: the world point (camera = world here) lands where OpenCV puts it.
        let (u, v, z) = cam.project(p).unwrap();
        assert!(
            (u - uv[i][0]).abs() < 1e-9 && (v - uv[i][1]).abs() < 1e-9,
            "{:?} point {i}: ({u}, {v}) vs OpenCV {:?}",
            cam.lens,
            uv[i]
        );
        assert!((z - p.z).abs() < 1e-12);
        // Unprojection: OpenCV's undistorted normalized coordinates of that pixel.
        let d = cam.pixel_dir_cam(uv[i][0], uv[i][1]);
        assert!(
            (d.x - normalized[i][0]).abs() < 1e-9 && (d.y - normalized[i][1]).abs() < 1e-9 && d.z == 1.0,
            "{:?} pixel {i}: {d} vs OpenCV {:?}",
            cam.lens,
            normalized[i]
        );
        // Round trip through the ray: the point at its z-depth along the pixel's ray.
        let back = cam.backproject_at(uv[i][0], uv[i][1], p.z);
        assert!((back - p).length() < 1e-9, "{back} vs {p}");
    }
}

#[test]
fn simple_radial_matches_opencv() {
    check(
        &camera("SIMPLE_RADIAL", &[("k1", -0.11)]),
        &SIMPLE_RADIAL_UV,
        &SIMPLE_RADIAL_NORMALIZED,
    );
}

#[test]
fn radial_matches_opencv() {
    check(
        &camera("RADIAL", &[("k1", -0.11), ("k2", 0.035)]),
        &RADIAL_UV,
        &RADIAL_NORMALIZED,
    );
}

#[test]
fn opencv_matches_opencv() {
    let c = [("k1", -0.28), ("k2", 0.07), ("p1", 0.0012), ("p2", -0.0007)];
    check(&camera("OPENCV", &c), &OPENCV_UV, &OPENCV_NORMALIZED);
    let c = [("k1", 0.12), ("k2", -0.03), ("p1", -0.002), ("p2", 0.003), ("k3", 0.01)];
    check(&camera("OPENCV", &c), &OPENCV_K3_UV, &OPENCV_K3_NORMALIZED);
}

#[test]
fn opencv_fisheye_matches_opencv() {
    let c = [("k1", 0.05), ("k2", -0.01), ("k3", 0.002), ("k4", -0.0003)];
    check(
        &camera("OPENCV_FISHEYE", &c),
        &OPENCV_FISHEYE_UV,
        &OPENCV_FISHEYE_NORMALIZED,
    );
}

#[test]
fn the_ray_generator_follows_the_lens() {
    let c = [("k1", -0.28), ("k2", 0.07), ("p1", 0.0012), ("p2", -0.0007)];
    let cam = camera("OPENCV", &c);
    let g = cam.ray_generator();
    for [u, v] in OPENCV_UV {
        let (_, d, _) = cam.ray(u, v);
        let df = g.dir(u as f32, v as f32).as_dvec3();
        assert!((df - d).length() < 1e-5, "{df} vs {d}");
    }
}

/// `transforms.json` declares the lens at the top level or per frame; unknown models, a
/// coefficient the model lacks and coefficients that fold the image are refused naming the key.
#[test]
fn transforms_json_reads_the_lens_and_names_bad_keys() {
    use i2sdf_data::fixture::{self, FixtureOptions};
    let dir = tempfile::tempdir().unwrap();
    fixture::write_native(dir.path(), &FixtureOptions::default());
    let json_path = dir.path().join("transforms.json");
    let original: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json_path).unwrap()).unwrap();
    let with = |edit: &dyn Fn(&mut serde_json::Value)| {
        let mut v = original.clone();
        edit(&mut v);
        std::fs::write(&json_path, serde_json::to_string(&v).unwrap()).unwrap();
        i2sdf_data::load(dir.path())
    };
    let ds = with(&|v| {
        v["camera_model"] = "OPENCV".into();
        v["k1"] = (-0.05).into();
        v["p2"] = 0.001.into();
        v["frames"][1]["camera_model"] = "OPENCV_FISHEYE".into();
        v["frames"][1]["k4"] = 0.002.into();
        v["frames"][1]["p2"] = 0.0.into();
    })
    .unwrap();
    assert!(matches!(ds.frames[0].camera.lens, Lens::BrownConrady { k1, p2, .. } if k1 == -0.05 && p2 == 0.001));
    assert!(matches!(ds.frames[1].camera.lens, Lens::Fisheye { k1, k4, .. } if k1 == -0.05 && k4 == 0.002));
    for (edit, key) in [
        (
            Box::new(|v: &mut serde_json::Value| v["camera_model"] = "FOV".into())
                as Box<dyn Fn(&mut serde_json::Value)>,
            "frames[0].camera_model",
        ),
        (
            Box::new(|v: &mut serde_json::Value| {
                v["camera_model"] = "RADIAL".into();
                v["frames"][2]["p1"] = 0.01.into();
            }),
            "frames[2].p1",
        ),
        (
            Box::new(|v: &mut serde_json::Value| {
                v["camera_model"] = "OPENCV".into();
                v["k1"] = (-3.0).into();
            }),
            "frames[0].camera_model",
        ),
        (
            Box::new(|v: &mut serde_json::Value| v["k2"] = "x".into()),
            "frames[0].k2",
        ),
    ] {
        let e = with(&*edit).unwrap_err();
        assert!(e.is_bad_input(), "{e}");
        match e {
            i2sdf_data::DataError::Field { field, .. } => assert_eq!(field, key),
            e => panic!("{e}"),
        }
    }
}
