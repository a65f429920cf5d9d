//! `i2sdf export` end to end on tiny runs of the fixture: the files read back through the `gltf`
//! crate (counts, bounds, materials in range, cameras), the axis conversion, a stage-1 run, and
//! bad input refused before any work.

mod common;

use common::*;
use std::path::Path;

fn export(run: &Path, out: &Path, extra: &[&str]) -> Outcome {
    let mut args = vec!["export", "--run", s(run), "--out", s(out), "--resolution", "48"];
    args.extend_from_slice(extra);
    i2sdf(&args)
}

struct Read {
    doc: gltf::Document,
    positions: Vec<[f32; 3]>,
    faces: usize,
}

fn read(path: &Path) -> Read {
    let (doc, buffers, _) = gltf::import(path).expect("a valid glTF");
    let mut positions = None;
    let mut faces = 0;
    for mesh in doc.meshes() {
        for prim in mesh.primitives() {
            let r = prim.reader(|b| Some(&buffers[b.index()]));
            positions.get_or_insert_with(|| r.read_positions().unwrap().collect::<Vec<_>>());
            let colours: Vec<[f32; 3]> = r.read_colors(0).unwrap().into_rgb_f32().collect();
            assert!(colours.iter().flatten().all(|c| c.is_finite() && *c >= 0.0));
            faces += r.read_indices().unwrap().into_u32().count() / 3;
        }
    }
    Read {
        doc,
        positions: positions.expect("a mesh"),
        faces,
    }
}

#[test]
fn a_stage2_run_exports_a_scene_that_reads_back() {
    let t = trained_stages();
    let dir = tempfile::tempdir().unwrap();
    let dataset = i2sdf_data::load(&t.data).unwrap();
    let glb = dir.path().join("room.glb");
    let o = export(&t.stage2, &glb, &["--up", "+y"]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    let r = read(&glb);
    assert!(r.faces > 100, "{} faces", r.faces);
    // +y up: glTF's axes are the world's, and the surface lies within the scene bounds padded
    // as marching cubes pads them
    let b = &dataset.bounds;
    let margin =
        (i2sdf_model::marching_cubes::PAD_FRACTION + 1e-3) * (0..3).map(|i| b.max[i] - b.min[i]).fold(0.0f64, f64::max);
    for p in &r.positions {
        for i in 0..3 {
            assert!(
                p[i] as f64 >= b.min[i] - margin && p[i] as f64 <= b.max[i] + margin,
                "{p:?} outside {b:?}"
            );
        }
    }
    // every frame's camera, named by split and frame
    assert_eq!(r.doc.cameras().count(), dataset.frames.len());
    let f = &dataset.frames[0];
    let node = r
        .doc
        .nodes()
        .find(|n| n.name() == Some(&format!("{}_{}", f.split.name(), f.name)))
        .expect("the first frame's camera node");
    let m = node.transform().matrix();
    let centre = f.camera.center();
    for i in 0..3 {
        assert!(
            (m[3][i] as f64 - centre[i]).abs() < 1e-4,
            "camera centre {:?} vs {centre:?}",
            m[3]
        );
    }
    // materials in range; the emitters' emission is L[k]
    let table = i2sdf_model::EmitterTable::read_json(&t.stage2.join("emitters.json")).unwrap();
    let mut emissive = Vec::new();
    for m in r.doc.materials() {
        let pbr = m.pbr_metallic_roughness();
        assert!((0.0..=1.0).contains(&pbr.roughness_factor()));
        assert_eq!(pbr.metallic_factor(), 0.0);
        if let Some(strength) = m.emissive_strength() {
            emissive.push(m.emissive_factor().map(|c| c * strength));
        } else {
            let spec = m.specular().expect("KHR_materials_specular");
            assert!((0.0..=1.0).contains(&spec.specular_factor()));
            assert!(spec.specular_color_factor().iter().all(|c| c.is_finite() && *c >= 0.0));
        }
    }
    let with_faces = emissive.len();
    assert!(with_faces <= table.len());
    for l in &emissive {
        let found = (0..table.len()).any(|k| {
            let e = table.emission(k).to_array();
            (0..3).all(|i| (l[i] - e[i]).abs() <= 1e-4 * e[i].max(1.0))
        });
        assert!(found, "emission {l:?} is no L[k]");
    }
    // the same scene as .gltf (buffer embedded): one file, the same faces
    let gltf = dir.path().join("room.gltf");
    let o = export(&t.stage2, &gltf, &["--up", "+y"]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    assert_eq!(read(&gltf).faces, r.faces);
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        2,
        "wrote only the two files"
    );
}

#[test]
fn the_up_axis_turns_the_room_into_gltf_axes() {
    let t = trained_stages();
    let dir = tempfile::tempdir().unwrap();
    let (y, z) = (dir.path().join("y.glb"), dir.path().join("z.glb"));
    for (out, up) in [(&y, "+y"), (&z, "+z")] {
        let o = export(&t.stage1, out, &["--up", up]);
        assert_eq!(o.code, 0, "{}", o.stderr);
    }
    let (y, z) = (read(&y), read(&z));
    assert_eq!(y.positions.len(), z.positions.len());
    // world (x, y, z) with +z up is glTF (x, z, −y)
    for (a, b) in y.positions.iter().zip(&z.positions) {
        let want = [a[0], a[2], -a[1]];
        for i in 0..3 {
            assert!((b[i] - want[i]).abs() < 1e-5, "{b:?} vs {want:?}");
        }
    }
}

#[test]
fn a_stage1_run_exports_its_radiance_unlit_and_says_so() {
    let t = trained_stages();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("geometry.glb");
    let o = export(&t.stage1, &out, &[]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    assert!(o.stderr.contains("has no stage 2"), "{}", o.stderr);
    let r = read(&out);
    let materials: Vec<_> = r.doc.materials().collect();
    assert_eq!(materials.len(), 1);
    assert!(materials[0].unlit());
}

#[test]
fn bad_export_arguments_are_refused_before_any_work() {
    let t = trained_stages();
    let dir = tempfile::tempdir().unwrap();
    // an --out that cannot be created fails (exit 1, as every command's) before the surface is
    // extracted
    let unwritable = unwritable(dir.path(), "room.glb");
    let o = export(&t.stage2, &unwritable, &[]);
    assert!(!o.stderr.contains("extracting"), "{}", o.stderr);
    expect(o, 1, &["--out", "not_a_directory"]);
    expect(
        export(&t.stage2, &dir.path().join("room.obj"), &[]),
        2,
        &["--out", ".glb"],
    );
    expect(
        export(&t.stage2, &dir.path().join("a.glb"), &["--up", "sideways"]),
        2,
        &["--up sideways"],
    );
    expect(
        export(&t.stage2, &dir.path().join("a.glb"), &["--materials", "0"]),
        2,
        &["--materials 0"],
    );
    expect(
        export(&t.stage2, &dir.path().join("a.glb"), &["--max-faces", "3"]),
        2,
        &["--max-faces 3"],
    );
    expect(
        export(&dir.path().join("no_run"), &dir.path().join("a.glb"), &[]),
        2,
        &["no_run"],
    );
    // a user's file is not replaced without --force
    let mine = dir.path().join("mine.glb");
    std::fs::write(&mine, b"mine").unwrap();
    expect(export(&t.stage2, &mine, &[]), 2, &["--force"]);
    assert_eq!(std::fs::read(&mine).unwrap(), b"mine");
    // nothing but the blocker and the user's file
    let mut left: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    assert_eq!(left, vec!["mine.glb", "not_a_directory"]);
}
