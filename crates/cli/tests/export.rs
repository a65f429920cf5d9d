//! `i2sdf export` end to end on tiny runs of the fixture: the files read back through the `gltf`
//! crate (counts, bounds, materials and textures in range, lights, cameras), the axis
//! conversion, a stage-1 run, and bad input refused before any work.

mod common;

use common::*;
use std::path::Path;

fn export(run: &Path, out: &Path, extra: &[&str]) -> Outcome {
    let mut args = vec!["export", "--run", s(run), "--out", s(out), "--resolution", "48"];
    if !extra.contains(&"--texture-size") {
        // a small atlas: the fixture's surface is coarse
        args.extend_from_slice(&["--texture-size", "256"]);
    }
    args.extend_from_slice(extra);
    i2sdf(&args)
}

struct Read {
    doc: gltf::Document,
    images: Vec<gltf::image::Data>,
    positions: Vec<[f32; 3]>,
    faces: usize,
}

/// The file through the `gltf` crate; every vertex colour finite and ≥ 0, every texture
/// coordinate in [0, 1].
fn read(path: &Path) -> Read {
    let (doc, buffers, images) = gltf::import(path).expect("a valid glTF");
    let mut positions = None;
    let mut faces = 0;
    for mesh in doc.meshes() {
        for prim in mesh.primitives() {
            let r = prim.reader(|b| Some(&buffers[b.index()]));
            positions.get_or_insert_with(|| r.read_positions().unwrap().collect::<Vec<_>>());
            if let Some(c) = r.read_colors(0) {
                let colours: Vec<[f32; 3]> = c.into_rgb_f32().collect();
                assert!(colours.iter().flatten().all(|c| c.is_finite() && *c >= 0.0));
            }
            if let Some(t) = r.read_tex_coords(0) {
                assert!(t.into_f32().flatten().all(|c| (0.0..=1.0).contains(&c)));
            }
            faces += r.read_indices().unwrap().into_u32().count() / 3;
        }
    }
    Read {
        doc,
        images,
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
    let o = export(&t.stage2, &glb, &["--up", "+y", "--lights"]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    assert!(
        o.stdout.contains("textures against the material fields"),
        "{}",
        o.stdout
    );
    let r = read(&glb);
    assert!(r.faces > 100, "{} faces", r.faces);
    // +y up: glTF's axes are the world's, and the surface lies within the scene bounds padded
    // as marching cubes pads them
    let b = &dataset.bounds;
    let margin =
        (i2sdf_model::sdf_mesh::PAD_FRACTION + 1e-3) * (0..3).map(|i| b.max[i] - b.min[i]).fold(0.0f64, f64::max);
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
        if let Some(strength) = m.emissive_strength() {
            assert_eq!(pbr.metallic_factor(), 0.0);
            emissive.push(m.emissive_factor().map(|c| c * strength));
        } else {
            // the baked material: Kd, roughness (G), metallic (B = 0) and F90 (A) in textures
            let base = pbr.base_color_texture().expect("a base colour texture");
            let img = &r.images[base.texture().source().index()];
            assert_eq!((img.width, img.height), (256, 256));
            let mr = &r.images[pbr.metallic_roughness_texture().unwrap().texture().source().index()];
            assert_eq!(mr.format, gltf::image::Format::R8G8B8A8);
            assert!(mr.pixels.chunks(4).all(|p| p[2] == 0), "metallic 0 everywhere");
            let spec = m.specular().expect("KHR_materials_specular");
            assert!((0.0..=1.0).contains(&spec.specular_factor()));
            assert!(spec.specular_color_factor().iter().all(|c| c.is_finite() && *c >= 1.0));
            assert!(spec.specular_color_texture().is_some() && spec.specular_texture().is_some());
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
    // one light per emitter with faces
    assert_eq!(r.doc.lights().map_or(0, |l| l.count()), with_faces);
    // the same scene as .gltf (buffer embedded): one file, the same faces; and with vertex
    // colours instead of textures
    let gltf = dir.path().join("room.gltf");
    let o = export(&t.stage2, &gltf, &["--up", "+y", "--texture-size", "0"]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    assert!(
        o.stdout.contains("vertex colours against the material fields"),
        "{}",
        o.stdout
    );
    let v = read(&gltf);
    assert_eq!(v.faces, r.faces);
    assert!(v.images.is_empty());
    let prim = v.doc.meshes().next().unwrap().primitives().next().unwrap();
    assert!(prim.get(&gltf::Semantic::Colors(0)).is_some());
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
        export(&t.stage2, &dir.path().join("a.glb"), &["--texture-size", "32"]),
        2,
        &["--texture-size 32"],
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
