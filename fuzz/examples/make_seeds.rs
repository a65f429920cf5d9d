//! Writes the seed corpora, `corpus/<target>/seed_*`, from the project's own writers (the
//! fixtures, `write_ply`, the checkpoint savers), so every seed is a valid file the fuzzer
//! mutates from. Small on purpose (a 4×3 dataset, a scene of a few thousand parameters).
//! Run from `fuzz/`: `cargo run --release --example make_seeds`.

use i2sdf_data::fixture::{self, DepthFormat, FixtureOptions};
use i2sdf_data::{imageio, ply, ImageF32, Normalization, Radiometry, TriangleMesh};
use i2sdf_model::intrinsic_io::IntrinsicFields;
use i2sdf_model::material_field::{MaterialBackbone, MaterialConfig, MaterialField};
use i2sdf_model::{Emitter, EmitterTable, ModelConfig, NeuralScene, RunInfo, StageProgress};
use std::path::Path;

fn put(target: &str, name: &str, bytes: &[u8]) {
    let dir = Path::new("corpus").join(target);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join(format!("seed_{name}")), bytes).unwrap();
}

fn copy(target: &str, name: &str, file: &Path) {
    put(target, name, &std::fs::read(file).unwrap());
}

fn main() {
    let tmp = tempfile::tempdir().unwrap();
    let opts = FixtureOptions {
        width: 4,
        height: 3,
        train_views: 2,
        test_views: 1,
        depth: DepthFormat::Exr,
        anchor: None,
    };
    let native = tmp.path().join("native");
    fixture::write_native(&native, &opts);
    copy("transforms_json", "fixture.json", &native.join("transforms.json"));
    // The optional keys the fixture leaves out, so the fuzzer starts inside their parsers.
    let mut v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(native.join("transforms.json")).unwrap()).unwrap();
    let frames = v["frames"].as_array_mut().unwrap();
    for f in frames.iter_mut() {
        f.as_object_mut().unwrap().remove("split");
    }
    v["train_filenames"] = serde_json::json!(["images/frame_000.png", "images/frame_001.png"]);
    v["test_filenames"] = serde_json::json!(["images/frame_002.png"]);
    v["ldr"] = serde_json::json!({"transfer": "linear", "exposure": 0.5});
    v["objects"] = serde_json::json!([{"id": 1, "name": "wall", "tags": ["room"]}]);
    v["emitters"] =
        serde_json::json!([{"name": "bulb", "emission": [1, 2, 3], "bounds_min": [0, 0, 0], "bounds_max": [1, 1, 1]}]);
    put("transforms_json", "optional_keys.json", v.to_string().as_bytes());

    let paper = tmp.path().join("paper");
    fixture::write_paper(&paper, &opts);
    copy("paper_npz", "fixture.npz", &paper.join("cameras_normalize.npz"));

    // COLMAP: the selector byte, then the file (the model pycolmap wrote for the data tests).
    let colmap = Path::new("../crates/data/tests/fixtures/colmap");
    for (k, file) in ["cameras.bin", "images.bin", "points3D.bin", "cameras.txt", "images.txt", "points3D.txt"]
        .iter()
        .enumerate()
    {
        let dir = if k < 3 { colmap.join("bin/sparse/0") } else { colmap.join("txt/sparse") };
        let mut bytes = vec![k as u8];
        bytes.extend(std::fs::read(dir.join(file)).unwrap());
        put("colmap_model", file, &bytes);
    }

    let img3 = ImageF32::from_data(4, 3, 3, (0..36).map(|i| i as f32 / 36.0).collect());
    let img1 = ImageF32::from_data(4, 3, 1, (0..12).map(|i| i as f32 / 12.0).collect());
    let p = tmp.path().join("m.npy");
    imageio::write_npy(&p, &img3).unwrap();
    copy("npy", "hw3_f4.npy", &p);
    imageio::write_npy(&p, &img1).unwrap();
    copy("npy", "hw_f4.npy", &p);
    {
        use npyz::WriterBuilder;
        let mut out = Vec::new();
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&[4, 4])
            .writer(&mut out)
            .begin_nd()
            .unwrap();
        w.extend((0..16).map(|i| i as f64)).unwrap();
        w.finish().unwrap();
        put("npy", "mat_f8.npy", &out);
    }

    let p = tmp.path().join("m.exr");
    imageio::write_exr(&p, &img3).unwrap();
    copy("exr", "rgb.exr", &p);
    imageio::write_exr(&p, &img1).unwrap();
    copy("exr", "y.exr", &p);

    let p = tmp.path().join("m.png");
    imageio::write_png(&p, &img3).unwrap();
    copy("png", "rgb8.png", &p);
    imageio::write_png16_raw(&p, 4, 3, 1, &(0..12).map(|i| i * 1000).collect::<Vec<u16>>()).unwrap();
    copy("png", "gray16.png", &p);

    let p = tmp.path().join("m.ply");
    let mut mesh = TriangleMesh::axis_box([0.0; 3], [1.0, 2.0, 3.0]);
    mesh.face_object_ids = Some((0..12).collect());
    ply::write_ply(&p, &mesh).unwrap();
    copy("ply", "box_ids.ply", &p);
    put(
        "ply",
        "ascii_quad.ply",
        b"ply\nformat ascii 1.0\ncomment c\nelement vertex 4\nproperty double x\nproperty float nx\n\
          property double y\nproperty double z\nelement face 1\nproperty list uchar uint vertex_index\n\
          property ushort object_id\nelement edge 1\nproperty int a\nproperty int b\nend_header\n\
          0 9 0 0\n1 9 0 0\n1 9 1 0\n0 9 1 0\n4 0 1 2 3 7\n0 1\n",
    );

    let config = i2sdf_train::config::TrainConfig::load(None, &[]).unwrap();
    put("train_config", "default.toml", config.to_toml().as_bytes());
    put(
        "train_config",
        "sets.toml",
        b"[model]\nhash_levels = 8\n\0train.rays=256\nmodel.backbone=mlp\nstage2.iterations=10\n",
    );

    put(
        "edit_spec",
        "relight.toml",
        b"[[op]]\nkind = \"relight\"\nat = [1, 2, 3]\nscale = 0.5\ncolor = [1.0, 0.8, 0.6]\n",
    );
    put(
        "edit_spec",
        "all_kinds.toml",
        br#"[[op]]
kind = "material"
box = { lo = [0, 0, 0], hi = [1, 0, 1] }
preset = "mirror"

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
mesh = { path = "tri.ply", scale = 0.5, rotation = [0, 90, 0], translation = [1, 0, 0] }
kd = [0.1, 0.1, 0.1]
"#,
    );

    // A scene small enough to be a seed (the checkpoint target loads stage 2 with FEATURE_DIM 3).
    let model = ModelConfig {
        hash_levels: 2,
        hash_features: 1,
        hash_log2_table: 8,
        hash_base_resolution: 2,
        hash_finest_resolution: 4,
        sdf_hidden: 4,
        sdf_layers: 1,
        feature_dim: 3,
        color_hidden: 4,
        color_layers: 1,
        emitter_hidden: 4,
        emitter_layers: 1,
        sh_degree: 1,
        ..Default::default()
    };
    let norm = Normalization {
        center: [0.1, 0.2, 0.3],
        scale: 2.0,
    };
    let p = tmp.path().join("c.safetensors");
    NeuralScene::new(&model, norm, 1).save(&p, &[]).unwrap();
    copy("checkpoint", "stage1.safetensors", &p);
    let material = MaterialConfig {
        backbone: MaterialBackbone::HashGrid,
        hash_levels: 1,
        hash_log2_table: 8,
        hash_base_resolution: 2,
        hash_finest_resolution: 2,
        hidden_dim: 8,
        hidden_layers: 1,
        ..Default::default()
    };
    let emitter = Emitter {
        centre: [0.0, 1.0, 2.0],
        extent: [0.1, 0.1, 0.1],
        radius: 0.1,
        points: 5,
    };
    let fields = IntrinsicFields {
        material: MaterialField::new(&material, 3, 0),
        emitters: EmitterTable::new(vec![emitter], &[[1.0, 2.0, 3.0]]),
        radiometry: Radiometry::from_name("srgb", Some(0.5)).unwrap(),
    };
    fields.save(&p, &[], &[]).unwrap();
    copy("checkpoint", "stage2.safetensors", &p);

    let info = RunInfo {
        data: "scene".into(),
        normalization: Some(norm),
        bounds: Some(i2sdf_data::Bounds {
            min: [-1.0; 3],
            max: [1.0; 3],
        }),
        stage1: StageProgress {
            iterations: 100,
            done: true,
            seconds: 1.5,
        },
        stage2: Some(StageProgress::default()),
    };
    put(
        "run_info",
        "full.json",
        serde_json::to_string_pretty(&info).unwrap().as_bytes(),
    );
    put("run_info", "empty.json", b"{\"data\": \"scene\"}");
    println!("seeds written under corpus/");
}
