//! Exit codes by class (the README's "Commands"), per command: bad input — a dataset, a run
//! directory, a config key, a `--set` value or an argument that is wrong — exits 2 with the key or
//! file named; a write that fails exits 1 and leaves nothing half-written; nothing panics (a panic
//! exits 101, which every assertion here would report).

mod common;
use common::*;
use i2sdf_data::fixture::{self, FixtureOptions};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// A fixture dataset and a finished tiny run on it, shared by the tests.
fn trained() -> &'static (tempfile::TempDir, PathBuf, PathBuf) {
    static RUN: OnceLock<(tempfile::TempDir, PathBuf, PathBuf)> = OnceLock::new();
    RUN.get_or_init(tiny_stage1)
}

#[test]
fn train_bad_input_exits_2_naming_the_key_or_file() {
    let (_, data, _) = trained();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let train = |extra: &[&str]| {
        let mut args = vec!["train", "--quiet", "--data", s(data), "--out", s(&out)];
        args.extend_from_slice(extra);
        i2sdf(&args)
    };
    for (set, key) in [
        ("model.hash_features=3", "model.hash_features"),
        ("model.hash_levels=0", "model.hash_levels"),
        ("model.sdf_hidden=0", "model.sdf_hidden"),
        ("sampling.epsilon=0", "sampling.epsilon"),
        ("loss.rgb=nan", "loss.rgb"),
        ("train.iteratons=5", "iteratons"),
        ("train.rays=many", "train.rays=many"),
    ] {
        expect(train(&["--set", set]), 2, &[key]);
    }
    let config = dir.path().join("bad.toml");
    std::fs::write(&config, "[train]\nrays = -3\n").unwrap();
    expect(train(&["--config", s(&config)]), 2, &["bad.toml", "rays"]);
    expect(
        i2sdf(&["train", "--data", s(&dir.path().join("nowhere")), "--out", s(&out)]),
        2,
        &["nowhere"],
    );
    // Resuming a run that does not exist, and starting over a run that does.
    expect(train(&["--resume"]), 2, &["run"]);
    let (_, _, run) = trained();
    expect(
        i2sdf(&["train", "--quiet", "--data", s(data), "--out", s(run)]),
        2,
        &["already holds a run"],
    );
    // Nothing was created for the refused runs.
    assert!(!out.exists(), "a refused run left {}", out.display());
}

/// Stage 2 needs a finished stage-1 run; bad stage-2 keys name themselves; a tiny stage 2 on a
/// copy of the tiny run works end to end and refuses to start over without --resume.
#[test]
fn train_material_stage() {
    let (_, data, run) = trained();
    let dir = tempfile::tempdir().unwrap();
    let material = |out: &Path, extra: &[&str]| train_material(data, out, extra);
    let nowhere = dir.path().join("nowhere");
    expect(material(&nowhere, &[]), 2, &["nowhere", "stage-1 run"]);
    assert!(!nowhere.exists());
    let copy = dir.path().join("copy");
    copy_stage1(run, &copy);
    expect(material(&copy, &["--set", "stage2.pixels=0"]), 2, &["stage2.pixels"]);
    expect(
        material(&copy, &["--set", "stage2.refresh_pixels=5"]),
        2,
        &["stage2.refresh_pixels", "stage2.irradiance_radius"],
    );
    let tiny = TINY_STAGE2;
    let o = material(&copy, &tiny);
    assert_eq!(o.code, 0, "{}", o.stderr);
    assert!(copy.join("stage2.safetensors").is_file() && copy.join("emitters.json").is_file());
    let emitters: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(copy.join("emitters.json")).unwrap()).unwrap();
    assert!(emitters["emitters"].is_array());
    expect(material(&copy, &tiny), 2, &["stage2.safetensors", "--resume"]);
    let o = material(&copy, &[&["--resume"][..], &tiny[..]].concat());
    assert_eq!(o.code, 0, "{}", o.stderr);
}

#[test]
fn mesh_bad_input_exits_2() {
    let (_, _, run) = trained();
    let dir = tempfile::tempdir().unwrap();
    let ply = dir.path().join("m.ply");
    expect(
        i2sdf(&["mesh", "--run", s(&dir.path().join("norun")), "--out", s(&ply)]),
        2,
        &["run.json"],
    );
    expect(
        i2sdf(&["mesh", "--run", s(run), "--out", s(&ply), "--resolution", "1"]),
        2,
        &["resolution"],
    );
    // A corrupt checkpoint is named.
    let broken = dir.path().join("broken");
    std::fs::create_dir_all(&broken).unwrap();
    std::fs::copy(run.join("run.json"), broken.join("run.json")).unwrap();
    std::fs::copy(run.join("config.toml"), broken.join("config.toml")).unwrap();
    std::fs::write(broken.join("checkpoint.safetensors"), b"not a checkpoint").unwrap();
    expect(
        i2sdf(&["mesh", "--run", s(&broken), "--out", s(&ply)]),
        2,
        &["checkpoint.safetensors"],
    );
    assert!(!ply.exists());
}

#[test]
fn render_bad_input_exits_2() {
    let (_, _, run) = trained();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("renders");
    expect(
        i2sdf(&["render", "--run", s(run), "--out", s(&out), "--split", "validation"]),
        2,
        &["--split", "validation"],
    );
    expect(
        i2sdf(&["render", "--run", s(run), "--out", s(&out), "--what", "rgb,sparkle"]),
        2,
        &["--what", "sparkle"],
    );
    expect(
        i2sdf(&[
            "render",
            "--run",
            s(run),
            "--out",
            s(&out),
            "--data",
            s(&dir.path().join("gone")),
        ]),
        2,
        &["gone"],
    );
    expect(
        i2sdf(&["render", "--run", s(&dir.path().join("norun")), "--out", s(&out)]),
        2,
        &["run.json"],
    );
    assert!(!out.exists(), "a refused render created {}", out.display());
}

#[test]
fn render_stage2_maps_of_a_stage1_run_exit_2() {
    let (_, _, run) = trained();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("renders");
    for what in ["albedo", "rgb,rerender", "emission"] {
        expect(
            i2sdf(&["render", "--run", s(run), "--out", s(&out), "--what", what]),
            2,
            &["stage2.safetensors", "no stage 2"],
        );
    }
    expect(
        i2sdf(&["render", "--run", s(run), "--out", s(&out), "--what", "albedo,glitter"]),
        2,
        &["--what", "glitter"],
    );
    expect(
        i2sdf(&[
            "render",
            "--run",
            s(run),
            "--out",
            s(&out),
            "--what",
            "rgb",
            "--spp",
            "0",
        ]),
        2,
        &["--spp"],
    );
    assert!(!out.exists(), "a refused render created {}", out.display());
}

#[test]
fn eval_bad_input_exits_2() {
    let (_, data, run) = trained();
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("m.json");
    expect(
        i2sdf(&[
            "eval",
            "--run",
            s(run),
            "--data",
            s(&dir.path().join("gone")),
            "--out",
            s(&json),
        ]),
        2,
        &["gone"],
    );
    expect(
        i2sdf(&[
            "eval",
            "--run",
            s(&dir.path().join("norun")),
            "--data",
            s(data),
            "--out",
            s(&json),
        ]),
        2,
        &["run.json"],
    );
    expect(
        i2sdf(&eval_args(run, data, &json, &["--threshold=-1"])),
        2,
        &["threshold"],
    );
    // Refused before any view is rendered.
    let t = std::time::Instant::now();
    expect(
        i2sdf(&eval_args(run, data, &json, &["--mesh-resolution", "100000"])),
        2,
        &["marching cubes at resolution 100000", "lower the resolution"],
    );
    assert!(t.elapsed().as_secs() < 30, "refused late: {:?}", t.elapsed());
    // LPIPS weights that are missing or not weights: refused before any view is rendered.
    let t = std::time::Instant::now();
    let gone = dir.path().join("gone.safetensors");
    expect(
        i2sdf(&eval_args(run, data, &json, &["--lpips-weights", s(&gone)])),
        2,
        &["gone.safetensors", "LPIPS weights"],
    );
    let text = dir.path().join("text.safetensors");
    std::fs::write(&text, "not tensors").unwrap();
    expect(
        i2sdf(&eval_args(run, data, &json, &["--lpips-weights", s(&text)])),
        2,
        &["text.safetensors", "not a safetensors file"],
    );
    assert!(t.elapsed().as_secs() < 30, "refused late: {:?}", t.elapsed());
    assert!(!json.exists());
}

/// `eval --lpips-weights` with weights of the right shapes: the fixture's 24×18 views are smaller
/// than AlexNet takes, so `novel_view.lpips` is null and the note says so; without the flag the
/// note says the weights are missing.
#[test]
fn eval_notes_why_lpips_is_null() {
    let (_, data, run) = trained();
    let dir = tempfile::tempdir().unwrap();
    let weights = dir.path().join("lpips.safetensors");
    let specs = i2sdf_eval::lpips::ALEXNET;
    i2sdf_eval::LpipsWeights {
        conv_weights: specs
            .iter()
            .map(|l| vec![0.01; l.out_channels * l.in_channels * l.kernel * l.kernel])
            .collect(),
        conv_biases: specs.iter().map(|l| vec![0.0; l.out_channels]).collect(),
        heads: specs.iter().map(|l| vec![0.1; l.out_channels]).collect(),
    }
    .write(&weights)
    .unwrap();
    for (extra, words) in [
        (vec!["--lpips-weights", s(&weights)], ["24×18", "31×31"]),
        (vec![], ["--lpips-weights", "scripts/lpips_weights.py"]),
    ] {
        let json = dir.path().join("m.json");
        let mut args = vec!["--mesh-resolution", "16", "--force"];
        args.extend(extra);
        let o = i2sdf(&eval_args(run, data, &json, &args));
        assert_eq!(o.code, 0, "{}", o.stderr);
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        assert!(
            v["novel_view"]["lpips"].is_null() && v["novel_view"]["psnr"].is_number(),
            "{v}"
        );
        let notes = v["notes"].to_string();
        for w in words {
            assert!(
                notes.contains("novel_view.lpips is null") && notes.contains(w),
                "{notes}"
            );
        }
    }
}

#[test]
fn failed_writes_exit_1_and_leave_nothing_half_written() {
    let (_, data, run) = trained();
    let dir = tempfile::tempdir().unwrap();
    let ply = unwritable(dir.path(), "m.ply");
    expect(
        i2sdf(&["mesh", "--run", s(run), "--out", s(&ply), "--resolution", "32"]),
        1,
        &["not_a_directory"],
    );
    let renders = unwritable(dir.path(), "renders");
    expect(
        i2sdf(&["render", "--run", s(run), "--out", s(&renders), "--what", "rgb"]),
        1,
        &["not_a_directory"],
    );
    let json = unwritable(dir.path(), "m.json");
    expect(
        i2sdf(&eval_args(run, data, &json, &["--mesh-resolution", "32"])),
        1,
        &["not_a_directory"],
    );
    let out = unwritable(dir.path(), "run");
    let mut args = vec!["train", "--quiet", "--data", s(data), "--out", s(&out)];
    args.extend_from_slice(&TINY);
    expect(i2sdf(&args), 1, &["not_a_directory"]);
    let scene = unwritable(dir.path(), "scene");
    expect(
        i2sdf(&[
            "synth",
            "--out",
            s(&scene),
            "--width",
            "16",
            "--height",
            "12",
            "--views",
            "2",
            "--spp",
            "1",
        ]),
        1,
        &["not_a_directory"],
    );
    // Only the blocking file is there: no temporaries or partial outputs beside it.
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left, ["not_a_directory"], "{left:?}");
}

/// A copy of the tiny run with a tiny stage 2, for the commands that need one. The fixture's
/// views see no emitter, so at the default threshold stage 2 finds none and every relight would
/// be refused; [`tiny_stage2_any_emitters`] makes emitters of the untrained emitter field's
/// marks instead.
fn trained_stage2() -> &'static (tempfile::TempDir, PathBuf) {
    static RUN: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    RUN.get_or_init(|| {
        let (_, data, run) = trained();
        let dir = tempfile::tempdir().unwrap();
        let copy = dir.path().join("run2");
        copy_stage1(run, &copy);
        let o = train_material(data, &copy, &tiny_stage2_any_emitters());
        assert_eq!(o.code, 0, "{}", o.stderr);
        (dir, copy)
    })
}

/// `i2sdf edit`: every bad input exits 2 naming the op, key, file or argument and writes
/// nothing; a spec with every op kind renders PNG + EXR + the spec's copy; a failed write exits 1.
#[test]
fn edit_bad_input_exits_2_and_good_specs_render() {
    let (_, stage1) = (trained(), &trained().2);
    let (_, run) = trained_stage2();
    let dir = tempfile::tempdir().unwrap();
    let spec = |name: &str, text: &str| {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        p
    };
    let out = dir.path().join("out");
    let edit = |run: &Path, spec: &Path, extra: &[&str]| {
        let mut args = vec![
            "edit",
            "--run",
            s(run),
            "--spec",
            s(spec),
            "--out",
            s(&out),
            "--spp",
            "2",
            "--bounces",
            "2",
            "--mesh-resolution",
            "32",
        ];
        args.extend_from_slice(extra);
        i2sdf(&args)
    };
    let empty = spec("empty.toml", "");
    let cases: Vec<(PathBuf, Vec<&str>, Vec<&str>)> = vec![
        (spec("kind.toml", "[[op]]\nkind = \"paint\"\n"), vec![], vec!["kind.toml", "op[0].kind", "paint"]),
        (
            spec("key.toml", "[[op]]\nkind = \"relight\"\nat = [0, 0, 0]\nscale = 1\nshine = 2\n"),
            vec![],
            vec!["op[0].shine"],
        ),
        (
            spec("box.toml", "[[op]]\nkind = \"material\"\nbox = { lo = [1, 0, 0], hi = [0, 1, 1] }\npreset = \"mirror\"\n"),
            vec![],
            vec!["op[0].box.lo"],
        ),
        (
            spec(
                "tex.toml",
                "[[op]]\nkind = \"material\"\nsphere = { centre = [0, 0, 0], radius = 1 }\ntexture = { image = \"missing.png\", origin = [0, 0, 0], u = [1, 0, 0], v = [0, 1, 0] }\n",
            ),
            vec![],
            vec!["op[0].texture.image", "missing.png"],
        ),
        (
            spec("mesh.toml", "[[op]]\nkind = \"insert\"\nmesh = { path = \"broken.ply\" }\n"),
            vec![],
            vec!["op[0].mesh.path"],
        ),
        (
            spec("nan.toml", "[[op]]\nkind = \"relight\"\nat = [nan, 0, 0]\nscale = 1\n"),
            vec![],
            vec!["op[0].at"],
        ),
        (empty.clone(), vec!["--view", "99"], vec!["--view 99"]),
        (empty.clone(), vec!["--width", "20"], vec!["--width and --height"]),
        (empty.clone(), vec!["--split", "validation"], vec!["--split validation"]),
        (empty.clone(), vec!["--composite", "product"], vec!["--composite", "product"]),
        (dir.path().join("absent.toml"), vec![], vec!["absent.toml"]),
    ];
    std::fs::write(dir.path().join("broken.ply"), b"ply\nformat nonsense\n").unwrap();
    for (spec, extra, needles) in &cases {
        expect(edit(run, spec, extra), 2, needles);
        assert!(!out.exists(), "{} wrote {}", spec.display(), out.display());
    }
    for (flag, value) in [("--spp", "0"), ("--bounces", "0"), ("--mesh-resolution", "3")] {
        let o = i2sdf(&[
            "edit",
            "--run",
            s(run),
            "--spec",
            s(&empty),
            "--out",
            s(&out),
            flag,
            value,
        ]);
        expect(o, 2, &[&format!("{flag} {value}")]);
    }
    expect(edit(stage1, &empty, &[]), 2, &["stage2.safetensors", "no stage 2"]);
    assert!(!out.exists());
    // Every op kind at once: a relight, a mirror region, an emitting inserted sphere, a box.
    let full = spec(
        "full.toml",
        "[[op]]\nkind = \"relight\"\nat = [0, 0, 0]\nscale = 2\ncolor = [1, 0.8, 0.6]\n\
         [[op]]\nkind = \"material\"\nbelow = { point = [0, 0, 0], normal = [0, 1, 0] }\npreset = \"mirror\"\n\
         [[op]]\nkind = \"insert\"\nsphere = { centre = [0, 0.5, 0], radius = 0.1 }\npreset = \"matte\"\nemission = [5, 5, 5]\n\
         [[op]]\nkind = \"insert\"\nbox = { lo = [-0.2, 0, -0.2], hi = [0.2, 0.1, 0.2] }\nkd = [0.2, 0.5, 0.2]\n",
    );
    let o = edit(run, &full, &["--view", "0", "--width", "12", "--height", "10"]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    let names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names.len(), 3, "{names:?}");
    assert!(names.iter().any(|n| n.ends_with(".png")) && names.iter().any(|n| n.ends_with(".exr")));
    assert_eq!(
        std::fs::read(out.join("edit.toml")).unwrap(),
        std::fs::read(&full).unwrap()
    );
    let png = i2sdf_data::imageio::read_image(&out.join(names.iter().find(|n| n.ends_with(".png")).unwrap())).unwrap();
    assert_eq!((png.width, png.height), (12, 10));
    // The same edit by differential rendering and by its ratio form (two path-traced passes
    // and the radiance field).
    for composite in ["differential", "ratio"] {
        std::fs::remove_dir_all(&out).unwrap();
        let o = edit(
            run,
            &full,
            &[
                "--view",
                "0",
                "--width",
                "12",
                "--height",
                "10",
                "--composite",
                composite,
            ],
        );
        assert_eq!(o.code, 0, "{composite}: {}", o.stderr);
        assert_eq!(std::fs::read_dir(&out).unwrap().count(), 3);
    }
    // A failed write exits 1.
    let blocked = unwritable(dir.path(), "out");
    let o = i2sdf(&[
        "edit",
        "--run",
        s(run),
        "--spec",
        s(&empty),
        "--out",
        s(&blocked),
        "--spp",
        "1",
        "--bounces",
        "1",
        "--mesh-resolution",
        "32",
        "--view",
        "0",
    ]);
    expect(o, 1, &["not_a_directory"]);
}

/// `i2sdf eval` on a dataset with relit sets (here the fixture's test views declared relit, with a
/// relight-only spec and one that also edits a material: the truth is not theirs, the pipeline
/// is what is tested) fills `relight`, path traced and by differential rendering, per set.
#[test]
fn eval_scores_the_relit_sets() {
    let (_, run) = trained_stage2();
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    fixture::write_native(&data, &FixtureOptions::default());
    let json_path = data.join("transforms.json");
    let mut top: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json_path).unwrap()).unwrap();
    let tests: Vec<serde_json::Value> = top["frames"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| f["split"] == "test")
        .map(|f| {
            let mut f = f.clone();
            f.as_object_mut().unwrap().remove("split");
            f
        })
        .collect();
    assert!(!tests.is_empty());
    std::fs::write(
        data.join("brighter.toml"),
        "[[op]]\nkind = \"relight\"\nat = [0, 0, 0]\nscale = 2\n",
    )
    .unwrap();
    std::fs::write(
        data.join("mirror.toml"),
        "[[op]]\nkind = \"relight\"\nat = [0, 0, 0]\nscale = 0.5\n\
         [[op]]\nkind = \"material\"\nbelow = { point = [0, 0, 0], normal = [0, 1, 0] }\npreset = \"mirror\"\n",
    )
    .unwrap();
    top["relight"] = serde_json::json!([
        {"spec": "brighter.toml", "frames": tests},
        {"spec": "mirror.toml", "frames": tests},
    ]);
    std::fs::write(&json_path, serde_json::to_string(&top).unwrap()).unwrap();
    let out = dir.path().join("m.json");
    let renders = dir.path().join("renders");
    let o = i2sdf(&[
        "eval",
        "--run",
        s(run),
        "--data",
        s(&data),
        "--out",
        s(&out),
        "--spp",
        "2",
        "--bounces",
        "2",
        "--mesh-resolution",
        "32",
        "--renders",
        s(&renders),
    ]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    // The views eval wrote as it scored them are what `render` writes of the same views.
    let rendered = dir.path().join("rendered");
    let all = "rgb,depth,normal,emitter,albedo,specular,roughness,emission,rerender";
    let o = i2sdf(&[
        "render",
        "--run",
        s(run),
        "--data",
        s(&data),
        "--out",
        s(&rendered),
        "--what",
        all,
        "--spp",
        "2",
    ]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    let mut compared = 0;
    for map in all.split(',') {
        for entry in std::fs::read_dir(rendered.join(map)).unwrap() {
            let path = entry.unwrap().path();
            let theirs = renders.join(map).join(path.file_name().unwrap());
            // EXRs by their values: the encoder's bytes are not the same from run to run.
            let same = match path.extension().and_then(|e| e.to_str()) {
                Some("exr") => {
                    let read = |p: &std::path::Path| i2sdf_data::imageio::read_float_map(p).unwrap();
                    read(&path) == read(&theirs)
                }
                _ => std::fs::read(&path).unwrap() == std::fs::read(&theirs).unwrap(),
            };
            assert!(same, "{}", theirs.display());
            compared += 1;
        }
    }
    assert_eq!(compared, tests.len() * 16, "9 PNGs and 7 EXRs per view");
    let m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let r = &m["relight"];
    for key in [
        "psnr",
        "ssim",
        "psnr_differential",
        "ssim_differential",
        "psnr_ratio",
        "ssim_ratio",
    ] {
        assert!(r[key].is_number(), "relight.{key}: {r}");
    }
    for set in ["brighter", "mirror"] {
        let v = &r["sets"][set];
        assert!(
            v["psnr"].is_number() && v["psnr_differential"].is_number() && v["psnr_ratio"].is_number(),
            "{set}: {v}"
        );
        assert_eq!(v["frames"], tests.len());
    }
    // Doing nothing is scored for the relight-only set, and the unedited render on the tests.
    assert!(r["sets"]["brighter"]["psnr_unedited"].is_number());
    assert!(r["sets"]["mirror"]["psnr_unedited"].is_null());
    assert_eq!(r["unedited"]["frames"], tests.len());
    assert_eq!(r["settings"]["denoised"], false);
    // Denoised: every set scored again, other figures, and the settings say so.
    let denoised = dir.path().join("denoised.json");
    let mut args = vec!["eval", "--run", s(run), "--data", s(&data), "--out", s(&denoised)];
    args.extend_from_slice(&["--spp", "2", "--bounces", "2", "--mesh-resolution", "32", "--denoise"]);
    let o = i2sdf(&args);
    assert_eq!(o.code, 0, "{}", o.stderr);
    let d: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&denoised).unwrap()).unwrap();
    assert_eq!(d["relight"]["settings"]["denoised"], true);
    for set in ["brighter", "mirror"] {
        let (raw, den) = (&r["sets"][set]["psnr"], &d["relight"]["sets"][set]["psnr"]);
        assert!(den.is_number() && den != raw, "{set}: {raw} → {den}");
    }
}

/// `render --path` and `edit --path`: the path's frames, the looping GIF, and bad path
/// arguments exit 2 naming the flag.
#[test]
fn camera_paths_render_frames_and_an_animation() {
    let (_, _, run) = trained();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("orbit");
    let render = |extra: &[&str]| {
        let mut a = vec!["render", "--run", s(run), "--out", s(&out), "--what", "rgb"];
        a.extend_from_slice(extra);
        i2sdf(&a)
    };
    for (extra, needle) in [
        (&["--path", "spiral"][..], "--path"),
        (&["--path", "orbit", "--frames", "0"], "--frames 0"),
        (&["--path", "interpolate", "--keyframes", "0,99"], "--keyframes"),
        (&["--path", "interpolate", "--keyframes", "0"], "at least two cameras"),
        (&["--path", "orbit", "--fps", "0"], "--fps 0"),
    ] {
        expect(render(extra), 2, &[needle]);
        assert!(!out.exists());
    }
    let o = render(&["--path", "orbit", "--frames", "3"]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    for i in 0..3 {
        assert!(out.join(format!("rgb/frame_{i:04}.png")).is_file());
    }
    let gif = std::fs::read(out.join("rgb.gif")).unwrap();
    assert!(gif.starts_with(b"GIF89a"));
    // The same folder again: refused without --force, replaced with it.
    expect(render(&["--path", "orbit", "--frames", "3"]), 2, &["--force"]);
    let o = render(&[
        "--path",
        "interpolate",
        "--keyframes",
        "0,1",
        "--frames",
        "2",
        "--force",
    ]);
    assert_eq!(o.code, 0, "{}", o.stderr);

    let (_, run2) = trained_stage2();
    let spec = dir.path().join("empty.toml");
    std::fs::write(&spec, "").unwrap();
    let edited = dir.path().join("edited");
    let o = i2sdf(&[
        "edit",
        "--run",
        s(run2),
        "--spec",
        s(&spec),
        "--out",
        s(&edited),
        "--spp",
        "1",
        "--bounces",
        "1",
        "--mesh-resolution",
        "32",
        "--width",
        "8",
        "--height",
        "6",
        "--path",
        "orbit",
        "--frames",
        "2",
    ]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    assert!(edited.join("frame_0001.png").is_file() && edited.join("frame_0001.exr").is_file());
    assert!(std::fs::read(edited.join("edit.gif")).unwrap().starts_with(b"GIF89a"));
}

/// A scene in the paper's release format with every optional file (a GT point cloud as
/// `mesh.ply`, material masks, GT materials, HDR, the val views' annotations), trained through
/// stage 2 with the tiny settings, is evaluated with every depth, normal, material and mesh figure
/// filled — the val views scored on their own depth, normals and materials. A triangle `mesh.ply`
/// (where the official code's `--score` looks) is scored as well, and without one the mesh
/// figures are null.
#[test]
fn a_paper_format_scene_is_evaluated_with_every_figure_filled() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("paper");
    let extra = fixture::PaperOptions {
        val_maps: true,
        material_masks: true,
        materials: true,
        hdr_exposure: Some(1.5),
        point_cloud: true,
        ..Default::default()
    };
    fixture::write_paper_with(&data, &FixtureOptions::default(), &extra);
    let run = dir.path().join("run");
    let mut args = vec!["train", "--quiet", "--data", s(&data), "--out", s(&run)];
    args.extend_from_slice(&TINY);
    expect(i2sdf(&args), 0, &[]);
    expect(train_material(&data, &run, &TINY_STAGE2), 0, &[]);
    let metrics = |name: &str| {
        let out = dir.path().join(name);
        let o = i2sdf(&eval_args(
            &run,
            &data,
            &out,
            &["--mesh-resolution", "32", "--spp", "2"],
        ));
        assert_eq!(o.code, 0, "{}", o.stderr);
        serde_json::from_str::<serde_json::Value>(&std::fs::read_to_string(out).unwrap()).unwrap()
    };
    let m = metrics("cloud.json");
    let filled = |group: &str, keys: &[&str]| {
        for k in keys {
            let v = k.split('.').fold(&m[group], |v, k| &v[k]);
            assert!(v.as_f64().is_some(), "{group}.{k} is {v} in {}", m[group]);
        }
    };
    filled("geometry", &["depth_l1", "normal_angular_l1"]);
    filled(
        "geometry",
        &[
            "mesh.accuracy",
            "mesh.completeness",
            "mesh.precision",
            "mesh.recall",
            "mesh.fscore",
        ],
    );
    filled("material", &["albedo_psnr", "albedo_psnr_scaled", "roughness_l1"]);
    filled("rerender", &["psnr", "ssim"]);
    filled("novel_view", &["psnr", "ssim"]);
    // The re-render scored denoised: a figure, and not the raw one.
    let denoised = dir.path().join("denoised.json");
    let o = i2sdf(&eval_args(
        &run,
        &data,
        &denoised,
        &["--mesh-resolution", "32", "--spp", "2", "--denoise"],
    ));
    assert_eq!(o.code, 0, "{}", o.stderr);
    let d: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(denoised).unwrap()).unwrap();
    let psnr = d["rerender"]["psnr"].as_f64().expect("a denoised re-render PSNR");
    assert_ne!(Some(psnr), m["rerender"]["psnr"].as_f64());
    // And the metrics say which they are.
    assert_eq!(
        (&d["rerender"]["denoised"], &m["rerender"]["denoised"]),
        (&true.into(), &false.into())
    );
    // A triangle mesh in world units is scored too: the run's own, put into the dataset by hand
    // (no command writes into a dataset).
    let ply = dir.path().join("gt.ply");
    let o = i2sdf(&["mesh", "--run", s(&run), "--out", s(&ply), "--resolution", "32"]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    std::fs::copy(&ply, data.join("mesh.ply")).unwrap();
    let m = metrics("scored.json");
    assert!(
        m["geometry"]["mesh"]["fscore"].as_f64().is_some_and(|f| f > 0.5),
        "{}",
        m["geometry"]
    );
    std::fs::remove_file(data.join("mesh.ply")).unwrap();
    assert!(metrics("none.json")["geometry"]["mesh"]["fscore"].is_null());
}

/// A declared exposure that the images contradict: `check` warns naming the key, stage 2
/// refuses (exit 2, the run untouched) unless `--trust-exposure` is given.
#[test]
fn a_contradicted_exposure_is_refused_unless_trusted() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("room");
    let o = i2sdf(&[
        "synth",
        "--out",
        s(&data),
        "--width",
        "24",
        "--height",
        "18",
        "--views",
        "6",
        "--spp",
        "2",
    ]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    let json = data.join("transforms.json");
    let mut t: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let truth = t["ldr"]["exposure"].as_f64().unwrap();
    t["ldr"]["exposure"] = serde_json::json!(truth * 3.0);
    std::fs::write(&json, serde_json::to_string(&t).unwrap()).unwrap();
    let o = i2sdf(&["check", "--data", s(&data)]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    assert!(
        o.stderr.contains("ldr.exposure") && o.stderr.contains("check the key"),
        "{}",
        o.stderr
    );
    let run = dir.path().join("run");
    let mut args = vec!["train", "--quiet", "--data", s(&data), "--out", s(&run)];
    args.extend_from_slice(&TINY);
    expect(i2sdf(&args), 0, &[]);
    let before = tree(&run);
    let o = train_material(&data, &run, &TINY_STAGE2);
    expect(o, 2, &["ldr.exposure", "measure", "--trust-exposure"]);
    assert!(
        tree_diff(&before, &tree(&run)).is_empty(),
        "a refused stage 2 changed the run"
    );
    let o = train_material(&data, &run, &[&TINY_STAGE2[..], &["--trust-exposure"]].concat());
    assert_eq!(o.code, 0, "{}", o.stderr);
}
