//! The edit-spec format: round trips, synth's relight files byte for byte, every error path,
//! regions, texture lookup, mesh transforms and emitter selection.

use glam::Vec3;
use i2sdf_data::edit_assets::EditAssets;
use i2sdf_data::edit_spec::*;
use i2sdf_data::imageio::{self, ImageF32};
use i2sdf_data::{ply, TriangleMesh};
use std::path::Path;

/// What synth wrote before the format moved here (captured from the old `to_toml_string`).
const SYNTH_BRIGHTER: &str = "[[op]]\nkind = \"relight\"\nat = [\n    0.25,\n    2.5,\n    -1.0,\n]\nscale = 2.0\ncolor = [\n    1.0,\n    0.8,\n    0.6,\n]\n";
const SYNTH_TWO: &str = "[[op]]\nkind = \"relight\"\nat = [\n    0.1,\n    0.3,\n    0.0000001,\n]\nscale = 0.5\ncolor = [\n    1.0,\n    1.0,\n    1.0,\n]\n\n[[op]]\nkind = \"relight\"\nat = [\n    -3.0,\n    10000000000.0,\n    0.0,\n]\nscale = 1.5\ncolor = [\n    0.0,\n    1.0,\n    2.0,\n]\n";

fn fixture() -> (tempfile::TempDir, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    // 2×2 texture: top row red, green; bottom row blue, white (sRGB-encoded values as stored).
    let img = ImageF32::from_data(2, 2, 3, vec![1., 0., 0., 0., 1., 0., 0., 0., 1., 1., 1., 1.]);
    imageio::write_png(&dir.path().join("tex.png"), &img).unwrap();
    imageio::write_exr(&dir.path().join("tex.exr"), &img).unwrap();
    ply::write_ply(&dir.path().join("tri.ply"), &TriangleMesh::axis_box([0.0; 3], [1.0; 3])).unwrap();
    let spec = dir.path().join("spec.toml");
    (dir, spec)
}

fn read(spec: &Path, text: &str) -> Result<EditSpec, i2sdf_data::DataError> {
    std::fs::write(spec, text).unwrap();
    EditSpec::read(spec)
}

fn err(spec: &Path, text: &str) -> String {
    match read(spec, text) {
        Ok(s) => panic!("accepted {text}: {s:?}"),
        Err(e) => {
            assert!(e.is_bad_input(), "{e}");
            e.to_string()
        }
    }
}

/// Asserts the error of `body` (one op, preceded by a valid relight op so the index is 1) names
/// `op[1]` and every one of `needles`.
fn assert_err(spec: &Path, body: &str, needles: &[&str]) {
    let text = format!("[[op]]\nkind = \"relight\"\nat = [0, 0, 0]\nscale = 1\n\n[[op]]\n{body}\n");
    let e = err(spec, &text);
    assert!(e.contains("op[1]"), "{e}");
    assert!(e.contains("spec.toml"), "{e}");
    for n in needles {
        assert!(e.contains(n), "expected {n:?} in: {e}");
    }
}

#[test]
fn synth_relight_files_are_unchanged() {
    let a = EditSpec {
        ops: vec![EditOp::relight([0.25, 2.5, -1.0], 2.0, [1.0, 0.8, 0.6])],
    };
    assert_eq!(a.to_toml_string(), SYNTH_BRIGHTER);
    let c = EditSpec {
        ops: vec![
            EditOp::relight([0.1, 0.30000001, 1e-7], 0.5, [1.0; 3]),
            EditOp::relight([-3.0, 1e10, 0.0], 1.5, [0.0, 1.0, 2.0]),
        ],
    };
    assert_eq!(c.to_toml_string(), SYNTH_TWO);
    assert_eq!(EditSpec::default().to_toml_string(), "op = []\n");
    let (_d, spec) = fixture();
    assert_eq!(read(&spec, SYNTH_BRIGHTER).unwrap(), a);
    assert_eq!(read(&spec, SYNTH_TWO).unwrap(), c);
    assert_eq!(read(&spec, "op = []\n").unwrap(), EditSpec::default());
    assert_eq!(read(&spec, "").unwrap(), EditSpec::default());
    // Colour defaults to white; integers are accepted where numbers are expected.
    let s = read(&spec, "[[op]]\nkind = \"relight\"\nat = [0, 2, 0]\nscale = 0\n").unwrap();
    assert_eq!(s.ops, vec![EditOp::relight([0.0, 2.0, 0.0], 0.0, [1.0; 3])]);
}

#[test]
fn every_op_kind_round_trips() {
    let (dir, spec) = fixture();
    let text = r#"
[[op]]
kind = "relight"
at = [1, 2, 3]
scale = 0.5
color = [1.0, 0.8, 0.6]

[[op]]
kind = "material"
box = { lo = [0, 0, 0], hi = [1, 0, 1] }
preset = "mirror"

[[op]]
kind = "material"
sphere = { centre = [0, 1, 0], radius = 0.25 }
kd = [0.2, 0.3, 0.4]
roughness = 0.5

[[op]]
kind = "material"
below = { point = [0, 0.1, 0], normal = [0, 2, 0] }
ks = [0.04, 0.04, 0.04]

[[op]]
kind = "material"
above = { point = [0, 0, 0], normal = [1, 0, 0] }
texture = { image = "tex.png", origin = [0, 0, 0], u = [2, 0, 0], v = [0, 0, 2] }
roughness = 0.3

[[op]]
kind = "insert"
sphere = { centre = [0, 1, 0], radius = 0.2 }
emission = [5, 5, 4]

[[op]]
kind = "insert"
box = { lo = [0, 0, 0], hi = [0.5, 0.5, 0.5] }
preset = "glossy"

[[op]]
kind = "insert"
mesh = { path = "tri.ply", scale = 0.5, rotation = [0, 90, 0], translation = [1, 0, 0] }
kd = [0.1, 0.1, 0.1]
"#;
    let s = read(&spec, text).unwrap();
    assert_eq!(s.ops.len(), 8);
    match &s.ops[3] {
        EditOp::Material(MaterialOp {
            region: Region::Below { normal, .. },
            material:
                MaterialOverride::Values(PartialMaterial {
                    kd: None,
                    ks: Some(_),
                    roughness: None,
                }),
        }) => assert_eq!(*normal, [0.0, 1.0, 0.0]),
        other => panic!("{other:?}"),
    }
    match &s.ops[4] {
        EditOp::Material(MaterialOp {
            material:
                MaterialOverride::Texture {
                    texture,
                    ks: None,
                    roughness: Some(r),
                },
            ..
        }) => {
            assert_eq!(texture.image, dir.path().join("tex.png"));
            assert_eq!(*r, 0.3);
        }
        other => panic!("{other:?}"),
    }
    let EditOp::Insert(plain) = &s.ops[5] else { panic!() };
    assert_eq!(plain.material, MaterialOverride::Preset(Preset::Matte));
    assert!(plain.is_emitter());
    let EditOp::Insert(mesh) = &s.ops[7] else { panic!() };
    let Shape::Mesh(m) = &mesh.shape else { panic!() };
    assert_eq!(m.path, dir.path().join("tri.ply"));
    let v = mesh.material_values();
    assert_eq!((v.kd, v.ks, v.roughness), ([0.1; 3], [0.0; 3], 1.0));
    // Written and read back (from another folder: paths are stored resolved).
    let again = dir.path().join("sub");
    std::fs::create_dir(&again).unwrap();
    let written = s.to_toml_string();
    let back = read(&again.join("spec.toml"), &written).unwrap();
    assert_eq!(back, s, "{written}");
    assert_eq!(back.to_toml_string(), written);
}

#[test]
fn presets_and_overrides() {
    assert_eq!(
        Preset::Mirror.values(),
        MaterialValues {
            kd: [0.0; 3],
            ks: [1.0; 3],
            roughness: 0.02
        }
    );
    assert_eq!(
        Preset::Glossy.values(),
        MaterialValues {
            kd: [0.3; 3],
            ks: [0.6; 3],
            roughness: 0.2
        }
    );
    assert_eq!(
        Preset::Matte.values(),
        MaterialValues {
            kd: [0.7; 3],
            ks: [0.0; 3],
            roughness: 1.0
        }
    );
    for p in Preset::ALL {
        assert_eq!(Preset::parse(p.name()), Some(p));
    }
    let rec = MaterialValues {
        kd: [0.5; 3],
        ks: [0.1; 3],
        roughness: 0.7,
    };
    let partial = MaterialOverride::Values(PartialMaterial {
        kd: None,
        ks: Some([0.9; 3]),
        roughness: None,
    });
    let v = partial.apply(rec, Vec3::ZERO, None);
    assert_eq!((v.kd, v.ks, v.roughness), ([0.5; 3], [0.9; 3], 0.7));
    assert_eq!(
        MaterialOverride::Preset(Preset::Glossy).apply(rec, Vec3::ZERO, None),
        Preset::Glossy.values()
    );
}

#[test]
fn serde_deny_unknown_fields_names_the_key() {
    // The nested tables are plain serde structs with deny_unknown_fields; the top-level keys are
    // checked against each kind's list. Both name the offending key.
    let (_d, spec) = fixture();
    assert_err(
        &spec,
        "kind = \"material\"\nbox = { lo = [0,0,0], hi = [1,1,1], mid = 3 }\npreset = \"matte\"",
        &["op[1].box", "unknown field `mid`"],
    );
    assert_err(
        &spec,
        "kind = \"insert\"\nsphere = { center = [0,0,0], radius = 1 }",
        &["op[1].sphere", "`center`"],
    );
    assert_err(
        &spec,
        "kind = \"material\"\nbox = { lo = [0,0,0] }\npreset = \"matte\"",
        &["op[1].box", "missing field `hi`"],
    );
}

#[test]
fn every_error_names_the_op_and_key() {
    let (_d, spec) = fixture();
    let r = "kind = \"relight\"\nat = [0, 0, 0]\n";
    let m = "kind = \"material\"\nbox = { lo = [0,0,0], hi = [1,1,1] }\n";
    let i = "kind = \"insert\"\nsphere = { centre = [0,0,0], radius = 1 }\n";
    let cases: Vec<(String, Vec<&str>)> = vec![
        ("kind = \"paint\"".into(), vec!["op[1].kind", "paint", "relight"]),
        ("at = [0, 0, 0]".into(), vec!["op[1].kind", "missing"]),
        (format!("{r}scale = 1\nbrightness = 2"), vec!["op[1].brightness", "unknown key", "relight"]),
        (format!("{m}preset = \"matte\"\nshine = 1"), vec!["op[1].shine", "unknown key", "material"]),
        (format!("{i}glow = 1"), vec!["op[1].glow", "unknown key", "insert"]),
        (format!("{i}texture = {{ image = \"tex.png\", origin = [0,0,0], u = [1,0,0], v = [0,1,0] }}"), vec!["op[1].texture", "not a texture"]),
        (format!("{r}scale = -1"), vec!["op[1].scale", "≥ 0", "-1"]),
        (format!("{r}scale = 1\ncolor = [1, -0.5, 1]"), vec!["op[1].color", "≥ 0"]),
        (format!("{r}scale = nan"), vec!["op[1].scale", "NaN"]),
        ("kind = \"relight\"\nat = [0, inf, 0]\nscale = 1".into(), vec!["op[1].at", "finite", "inf"]),
        ("kind = \"relight\"\nat = [0, 0]\nscale = 1".into(), vec!["op[1].at", "length"]),
        ("kind = \"relight\"\nat = [0, 0, 0]\nscale = \"big\"".into(), vec!["op[1].scale", "string"]),
        ("kind = \"relight\"\nscale = 1".into(), vec!["op[1].at", "missing"]),
        ("kind = \"material\"\nbox = { lo = [0,2,0], hi = [1,1,1] }\npreset = \"matte\"".into(), vec!["op[1].box.lo", "≤ hi"]),
        ("kind = \"material\"\nbox = { lo = [0,nan,0], hi = [1,1,1] }\npreset = \"matte\"".into(), vec!["op[1].box.lo", "finite"]),
        ("kind = \"material\"\nsphere = { centre = [0,0,0], radius = 0 }\npreset = \"matte\"".into(), vec!["op[1].sphere.radius", "> 0"]),
        ("kind = \"material\"\nbelow = { point = [0,0,0], normal = [0,0,0] }\npreset = \"matte\"".into(), vec!["op[1].below.normal", "non-zero"]),
        ("kind = \"material\"\nabove = { point = [0,0,0], normal = [0,-inf,0] }\npreset = \"matte\"".into(), vec!["op[1].above.normal", "finite"]),
        (format!("{m}sphere = {{ centre = [0,0,0], radius = 1 }}\npreset = \"matte\""), vec!["op[1]", "exactly one region", "box and sphere"]),
        ("kind = \"material\"\npreset = \"matte\"".into(), vec!["op[1]", "exactly one region", "none"]),
        (m.to_string(), vec!["op[1]", "needs a material"]),
        (format!("{m}preset = \"mirror\"\nkd = [0.1, 0.1, 0.1]"), vec!["op[1].preset", "kd"]),
        (format!("{m}preset = \"chrome\""), vec!["op[1].preset", "chrome", "mirror"]),
        (format!("{m}kd = [0.5, 1.5, 0.5]"), vec!["op[1].kd", "[0, 1]", "1.5"]),
        (format!("{m}ks = [0.5, -0.1, 0.5]"), vec!["op[1].ks", "[0, 1]"]),
        (format!("{m}roughness = 0.001"), vec!["op[1].roughness", "[0.01, 1]"]),
        (format!("{m}roughness = 1.5"), vec!["op[1].roughness", "[0.01, 1]"]),
        (format!("{m}texture = {{ image = \"tex.png\", origin = [0,0,0], u = [1,0,0], v = [0,1,0] }}\nkd = [0.1,0.1,0.1]"), vec!["op[1].texture", "kd"]),
        (format!("{m}texture = {{ image = \"tex.png\", origin = [0,0,0], u = [1,0,0], v = [-2,0,0] }}"), vec!["op[1].texture.v", "parallel"]),
        (format!("{m}texture = {{ image = \"tex.png\", origin = [0,0,0], u = [0,0,0], v = [0,1,0] }}"), vec!["op[1].texture.u", "non-zero"]),
        (format!("{m}texture = {{ image = \"nope.png\", origin = [0,0,0], u = [1,0,0], v = [0,1,0] }}"), vec!["op[1].texture.image", "not found", "nope.png"]),
        (format!("{m}texture = {{ image = \"tri.ply\", origin = [0,0,0], u = [1,0,0], v = [0,1,0] }}"), vec!["op[1].texture.image", ".png or .exr"]),
        ("kind = \"insert\"\nbox = { lo = [0,0,0], hi = [1,0,1] }".into(), vec!["op[1].box.lo", "< hi"]),
        ("kind = \"insert\"\nsphere = { centre = [0,0,0], radius = -1 }".into(), vec!["op[1].sphere.radius", "> 0"]),
        (format!("{i}box = {{ lo = [0,0,0], hi = [1,1,1] }}"), vec!["op[1]", "exactly one shape", "sphere and box"]),
        ("kind = \"insert\"\nemission = [1, 1, 1]".into(), vec!["op[1]", "exactly one shape", "none"]),
        (format!("{i}emission = [1, -1, 1]"), vec!["op[1].emission", "≥ 0"]),
        (format!("{i}emission = [1, inf, 1]"), vec!["op[1].emission", "finite"]),
        (format!("{i}preset = \"matte\"\nroughness = 0.5"), vec!["op[1].preset", "roughness"]),
        ("kind = \"insert\"\nmesh = { path = \"gone.ply\" }".into(), vec!["op[1].mesh.path", "not found", "gone.ply"]),
        ("kind = \"insert\"\nmesh = { path = \"tri.ply\", scale = 0 }".into(), vec!["op[1].mesh.scale", "> 0"]),
        ("kind = \"insert\"\nmesh = { path = \"tri.ply\", scale = -2 }".into(), vec!["op[1].mesh.scale", "> 0"]),
        ("kind = \"insert\"\nmesh = { path = \"tri.ply\", rotation = [0, nan, 0] }".into(), vec!["op[1].mesh.rotation", "finite"]),
    ];
    for (body, needles) in cases {
        assert_err(&spec, &body, &needles);
    }
    // Document-level errors.
    assert!(err(&spec, "[[op]\nkind =").contains("bad edit spec"));
    assert!(err(&spec, "ops = []").contains("ops"));
    assert!(err(&spec, "op = 3").contains("op"));
    assert!(err(&spec, "op = [3]").contains("op[0]"));
    assert!(EditSpec::read(&spec.with_file_name("missing.toml"))
        .unwrap_err()
        .to_string()
        .contains("missing.toml"));
}

fn one_op(spec: &Path, body: &str) -> Result<EditAssets, String> {
    read(spec, &format!("[[op]]\n{body}\n"))
        .unwrap()
        .load_assets()
        .map_err(|e| {
            assert!(e.is_bad_input(), "{e}");
            e.to_string()
        })
}

#[test]
fn assets_decode_and_report_their_files() {
    let (dir, spec) = fixture();
    let tex = |f: &str| {
        format!("kind = \"material\"\nbox = {{ lo = [0,0,0], hi = [1,1,1] }}\ntexture = {{ image = \"{f}\", origin = [0,0,0], u = [1,0,0], v = [0,0,1] }}")
    };
    // PNG: sRGB-encoded values decode to linear; EXR is linear already.
    let a = one_op(&spec, &tex("tex.png")).unwrap();
    let img = a.texture(0).unwrap();
    assert_eq!((img.width, img.height, img.channels), (2, 2, 3));
    assert_eq!(img.pixel(1, 0), &[0.0, 1.0, 0.0]);
    let grey = ImageF32::from_data(1, 1, 1, vec![0.5]);
    imageio::write_png(&dir.path().join("grey.png"), &grey).unwrap();
    let g = one_op(&spec, &tex("grey.png")).unwrap();
    let expect = imageio::srgb_to_linear(128.0 / 255.0);
    assert!(
        g.texture(0).unwrap().data.iter().all(|v| (v - expect).abs() < 1e-6),
        "{:?}",
        g.texture(0)
    );
    assert!(one_op(&spec, &tex("tex.exr")).unwrap().texture(0).unwrap().pixel(0, 1) == [0.0, 0.0, 1.0]);
    // Undecodable files name the op, the key and the file.
    std::fs::write(dir.path().join("junk.png"), b"not a png at all").unwrap();
    let e = one_op(&spec, &tex("junk.png")).unwrap_err();
    eprintln!("{e}");
    assert!(
        e.contains("op[0].texture.image") && e.contains("junk.png") && e.contains("decode"),
        "{e}"
    );
    std::fs::write(dir.path().join("junk.exr"), b"not an exr").unwrap();
    let e = one_op(&spec, &tex("junk.exr")).unwrap_err();
    assert!(e.contains("op[0].texture.image") && e.contains("junk.exr"), "{e}");
    // Oversized images are refused from their header.
    imageio::write_png(&dir.path().join("wide.png"), &ImageF32::new(MAX_TEXTURE_SIDE + 1, 1, 1)).unwrap();
    let e = one_op(&spec, &tex("wide.png")).unwrap_err();
    assert!(e.contains("op[0].texture.image") && e.contains("16385×1"), "{e}");
    // Meshes: transformed to world units.
    let mesh =
        "kind = \"insert\"\nmesh = { path = \"tri.ply\", scale = 2, rotation = [90, 90, 0], translation = [0, 0, 10] }";
    let a = one_op(&spec, mesh).unwrap();
    let m = a.mesh(0).unwrap();
    assert_eq!(m.faces.len(), 12);
    // Vertex 2 of the unit box is (0, 1, 0): ×2 → (0, 2, 0); x 90° → (0, 0, 2); y 90° → (2, 0, 0).
    let v = Vec3::from(m.positions[2]);
    assert!((v - Vec3::new(2.0, 0.0, 10.0)).length() < 1e-5, "{v}");
    assert!(a.texture(0).is_none() && a.mesh(1).is_none());
    std::fs::write(
        dir.path().join("bad.ply"),
        b"ply\nformat ascii 1.0\nelement vertex 1\nend_header\n",
    )
    .unwrap();
    let e = one_op(&spec, "kind = \"insert\"\nmesh = { path = \"bad.ply\" }").unwrap_err();
    assert!(e.contains("op[0].mesh.path") && e.contains("bad.ply"), "{e}");
    let empty = TriangleMesh::default();
    ply::write_ply(&dir.path().join("empty.ply"), &empty).unwrap();
    let e = one_op(&spec, "kind = \"insert\"\nmesh = { path = \"empty.ply\" }").unwrap_err();
    assert!(e.contains("op[0].mesh.path") && e.contains("empty"), "{e}");
    let e = one_op(
        &spec,
        "kind = \"insert\"\nmesh = { path = \"tri.ply\", scale = 1e38, translation = [3e38, 0, 0] }",
    )
    .unwrap_err();
    assert!(e.contains("op[0].mesh.path") && e.contains("not finite"), "{e}");
}

#[test]
fn mesh_transform_order() {
    let m = MeshShape {
        path: "x.ply".into(),
        scale: 3.0,
        rotation: [0.0, 0.0, 90.0],
        translation: [1.0, 2.0, 3.0],
    };
    let p = m.transform_point(Vec3::X);
    assert!((p - Vec3::new(1.0, 5.0, 3.0)).length() < 1e-5, "{p}");
}

#[test]
fn regions_contain_their_points() {
    let b = Region::Box {
        lo: [0.0; 3],
        hi: [1.0, 0.0, 1.0],
    };
    assert!(b.contains(Vec3::new(0.5, 0.0, 1.0)));
    assert!(!b.contains(Vec3::new(0.5, 0.01, 0.5)));
    let s = Region::Sphere {
        centre: [0.0, 1.0, 0.0],
        radius: 0.5,
    };
    assert!(s.contains(Vec3::new(0.0, 1.4, 0.0)) && !s.contains(Vec3::new(0.4, 1.4, 0.0)));
    let below = Region::Below {
        point: [0.0, 1.0, 0.0],
        normal: [0.0, 1.0, 0.0],
    };
    let above = Region::Above {
        point: [0.0, 1.0, 0.0],
        normal: [0.0, 1.0, 0.0],
    };
    assert!(below.contains(Vec3::new(5.0, 0.5, -3.0)) && !below.contains(Vec3::new(0.0, 1.5, 0.0)));
    assert!(above.contains(Vec3::new(0.0, 1.5, 0.0)) && !above.contains(Vec3::new(0.0, 0.5, 0.0)));
    assert!(above.contains(Vec3::new(0.0, 1.0, 0.0)) && below.contains(Vec3::new(0.0, 1.0, 0.0)));
}

#[test]
fn texture_lookup_is_bilinear_and_wraps() {
    // 2×2: top row red, green; bottom row blue, white (linear values).
    let img = ImageF32::from_data(2, 2, 3, vec![1., 0., 0., 0., 1., 0., 0., 0., 1., 1., 1., 1.]);
    let t = Texture {
        image: "t.png".into(),
        origin: [0.0; 3],
        u: [2.0, 0.0, 0.0],
        v: [0.0, 0.0, 2.0],
    };
    let at = |s: f32, tt: f32| t.kd_at(Vec3::new(2.0 * s, 7.0, 2.0 * tt), &img);
    let close = |a: Vec3, b: Vec3| (a - b).length() < 1e-5;
    assert_eq!(t.st(Vec3::new(1.0, 0.0, 0.5)), (0.5, 0.25));
    assert!(close(at(0.25, 0.25), Vec3::X), "{}", at(0.25, 0.25));
    assert!(close(at(0.75, 0.25), Vec3::Y));
    assert!(close(at(0.25, 0.75), Vec3::Z));
    assert!(close(at(0.75, 0.75), Vec3::ONE));
    assert!(close(at(1.25, -0.25), Vec3::Z), "{}", at(1.25, -0.25)); // wraps
    assert!(close(at(0.5, 0.25), Vec3::new(0.5, 0.5, 0.0))); // halfway between red and green
    assert!(close(at(0.0, 0.25), Vec3::new(0.5, 0.5, 0.0))); // across the seam
    assert!(close(at(0.5, 0.5), Vec3::splat(0.5)));
}

#[test]
fn nearest_box_and_emitter_gains() {
    let boxes = vec![
        (Vec3::new(0.0, 2.0, 0.0), Vec3::new(1.0, 2.1, 1.0)),
        (Vec3::new(3.0, 2.0, 0.0), Vec3::new(4.0, 2.1, 1.0)),
        (Vec3::new(-1.0, -1.0, -1.0), Vec3::new(10.0, 10.0, 10.0)), // contains everything
    ];
    assert_eq!(nearest_box(&boxes[..2], Vec3::new(0.5, 0.0, 0.5)), Some(0));
    assert_eq!(nearest_box(&boxes[..2], Vec3::new(3.2, 5.0, 0.5)), Some(1));
    // Inside two boxes: the nearer centre wins.
    assert_eq!(nearest_box(&boxes, Vec3::new(0.5, 2.05, 0.5)), Some(0));
    assert_eq!(nearest_box(&[], Vec3::ZERO), None);
    // NaN never panics.
    let nan = (Vec3::splat(f32::NAN), Vec3::splat(f32::NAN));
    assert_eq!(nearest_box(&[nan, boxes[1]], Vec3::ZERO), Some(1));
    assert!(nearest_box(&boxes, Vec3::splat(f32::NAN)).is_some());
    let spec = EditSpec {
        ops: vec![
            EditOp::relight([0.5, 2.0, 0.5], 2.0, [1.0, 0.5, 0.25]),
            EditOp::relight([0.5, 2.0, 0.5], 3.0, [1.0; 3]),
            EditOp::relight([3.5, 2.0, 0.5], 0.0, [1.0; 3]),
        ],
    };
    assert_eq!(
        spec.emitter_gains(&boxes[..2]),
        vec![Vec3::new(6.0, 3.0, 1.5), Vec3::ZERO]
    );
    assert!(spec.emitter_gains(&[]).is_empty());
}
