//! The table of bad inputs of the stage-2 commands (issue 11, "Reliability"): every error path of
//! the edit spec (ops, keys, regions, numbers, textures, meshes), of the stage-2 configuration
//! (`stage2.*` and `material.*`, by `--set` and by file) and of marching cubes at a resolution
//! that does not fit in memory. Each row runs the real binary and must exit with its code, name
//! what is at fault in stderr, and leave the output untouched: `edit --out DIR` is not created, a
//! refused stage 2 writes nothing into the run, a refused mesh writes no file. The test prints the
//! table (case → exit code → first line of the message); with `BAD_INPUT_TABLE=FILE` it also
//! appends it there as markdown. `nothing_a_user_has_is_overwritten` holds issue 23's rows: a
//! command aimed at a dataset, a run or a user's files, false successes and messages that showed
//! internals, each checked to leave every file byte-identical.

mod common;
use common::*;
use std::path::Path;

/// One row of the table, as run.
struct Row {
    case: String,
    code: i32,
    first_line: String,
    problems: Vec<String>,
}

#[derive(Default)]
struct Table {
    rows: Vec<Row>,
}

impl Table {
    /// Records `o` for `case`: its exit code must be `code`, its stderr must contain every
    /// needle, and `untouched` (checked after the run) must hold.
    fn record(&mut self, case: &str, o: Outcome, code: i32, needles: &[&str], untouched: Result<(), String>) {
        let mut problems = Vec::new();
        if o.code != code {
            problems.push(format!("exit {} (expected {code})", o.code));
        }
        for n in needles {
            if !o.stderr.contains(n) {
                problems.push(format!("stderr lacks '{n}'"));
            }
        }
        if let Err(e) = untouched {
            problems.push(e);
        }
        if !problems.is_empty() {
            problems.push(format!("stderr: {}", o.stderr.trim()));
        }
        let first_line = o
            .stderr
            .lines()
            .find(|l| l.starts_with("error:"))
            .or_else(|| o.stderr.lines().next())
            .unwrap_or("")
            .to_string();
        self.rows.push(Row {
            case: case.to_string(),
            code: o.code,
            first_line,
            problems,
        });
    }

    fn markdown(&self, strip: &[&Path]) -> String {
        let mut md = String::from("| case | exit | message (first line) |\n|---|---|---|\n");
        for r in &self.rows {
            // Temporary paths make the table unreadable and differ per run.
            let mut line = r.first_line.clone();
            for dir in strip {
                line = line.replace(&format!("{}/", dir.display()), "");
            }
            line = line.replace('|', "\\|");
            md.push_str(&format!(
                "| {} | {} | `{}` |\n",
                r.case.replace('|', "\\|"),
                r.code,
                line
            ));
        }
        md
    }

    fn finish(self, strip: &[&Path]) {
        let md = self.markdown(strip);
        println!("{md}");
        if let Ok(path) = std::env::var("BAD_INPUT_TABLE") {
            // Each test of the file adds its table.
            use std::io::Write;
            let mut f = std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(path)
                .unwrap();
            writeln!(f, "{md}").unwrap();
        }
        let failed: Vec<String> = self
            .rows
            .iter()
            .filter(|r| !r.problems.is_empty())
            .map(|r| format!("{}: {}", r.case, r.problems.join("; ")))
            .collect();
        assert!(
            failed.is_empty(),
            "{} row(s) failed:\n{}",
            failed.len(),
            failed.join("\n")
        );
    }
}

const SPHERE: &str = "sphere = { centre = [0, 0, 0], radius = 0.5 }";
const TEX_PLANE: &str = "origin = [0, 0, 0], u = [1, 0, 0], v = [0, 1, 0]";

/// The edit spec rows: (case, spec text, needles). Files named by the specs live beside them.
#[rustfmt::skip]
fn edit_rows() -> Vec<(&'static str, String, Vec<&'static str>)> {
    let relight = "[[op]]\nkind = \"relight\"\nat = [0, 0, 0]\nscale = 1\n";
    let material = |body: &str| format!("[[op]]\nkind = \"material\"\n{SPHERE}\n{body}\n");
    let insert = |body: &str| format!("[[op]]\nkind = \"insert\"\n{body}\n");
    let texture = |image: &str, plane: &str| material(&format!("texture = {{ image = \"{image}\", {plane} }}"));
    let mesh = |path: &str, extra: &str| insert(&format!("mesh = {{ path = \"{path}\"{extra} }}"));
    vec![
        ("not TOML at all", "this is { not toml".into(), vec!["spec.toml", "bad edit spec"]),
        ("binary garbage", "\u{1}\u{2}\u{fffd}[[[".into(), vec!["spec.toml", "bad edit spec"]),
        ("unknown top-level key", "[lights]\nbulb = 2\n".into(), vec!["lights", "unknown key"]),
        ("op is not a list of tables", "op = 3\n".into(), vec!["op", "[[op]]"]),
        ("op without kind", "[[op]]\nat = [0, 0, 0]\n".into(), vec!["op[0].kind", "missing"]),
        ("kind not a string", "[[op]]\nkind = 3\n".into(), vec!["op[0].kind", "string"]),
        ("unknown op kind", "[[op]]\nkind = \"paint\"\n".into(), vec!["op[0].kind", "paint"]),
        ("relight: unknown key", format!("{relight}shine = 2\n"), vec!["op[0].shine", "relight"]),
        ("material: unknown key", material("preset = \"matte\"\ncolour = 1"), vec!["op[0].colour", "material"]),
        ("insert: unknown key", insert(&format!("{SPHERE}\nglow = 1")), vec!["op[0].glow", "an \"insert\" op"]),
        ("insert: texture", insert(&format!("{SPHERE}\ntexture = {{ image = \"tex.png\", {TEX_PLANE} }}")), vec!["op[0].texture", "not a texture"]),
        ("box: unknown key", "[[op]]\nkind = \"material\"\nbox = { lo = [0, 0, 0], hi = [1, 1, 1], mid = 2 }\npreset = \"matte\"\n".into(), vec!["op[0].box", "mid"]),
        ("relight: missing at", "[[op]]\nkind = \"relight\"\nscale = 1\n".into(), vec!["op[0].at", "missing"]),
        ("relight: missing scale", "[[op]]\nkind = \"relight\"\nat = [0, 0, 0]\n".into(), vec!["op[0].scale", "missing"]),
        ("material: no region", "[[op]]\nkind = \"material\"\npreset = \"matte\"\n".into(), vec!["op[0]", "region", "none"]),
        ("material: two regions", material("below = { point = [0, 0, 0], normal = [0, 1, 0] }\npreset = \"matte\""), vec!["op[0]", "sphere and below"]),
        ("insert: no shape", insert("preset = \"matte\""), vec!["op[0]", "shape", "none"]),
        ("box: missing hi", "[[op]]\nkind = \"material\"\nbox = { lo = [0, 0, 0] }\npreset = \"matte\"\n".into(), vec!["op[0].box", "hi"]),
        ("mesh: missing path", insert("mesh = { scale = 2 }"), vec!["op[0].mesh", "path"]),
        ("relight: at wrong type", "[[op]]\nkind = \"relight\"\nat = \"ceiling\"\nscale = 1\n".into(), vec!["op[0].at"]),
        ("relight: at with 2 components", "[[op]]\nkind = \"relight\"\nat = [0, 0]\nscale = 1\n".into(), vec!["op[0].at"]),
        ("relight: scale wrong type", "[[op]]\nkind = \"relight\"\nat = [0, 0, 0]\nscale = \"x2\"\n".into(), vec!["op[0].scale"]),
        ("preset wrong type", material("preset = 1"), vec!["op[0].preset"]),
        ("kd wrong type", material("kd = 0.5"), vec!["op[0].kd"]),
        ("region box lo > hi", "[[op]]\nkind = \"material\"\nbox = { lo = [1, 0, 0], hi = [0, 1, 1] }\npreset = \"mirror\"\n".into(), vec!["op[0].box.lo", "≤ hi"]),
        ("insert box lo = hi", insert("box = { lo = [0, 0, 0], hi = [0, 1, 1] }"), vec!["op[0].box.lo", "< hi"]),
        ("region sphere radius 0", "[[op]]\nkind = \"material\"\nsphere = { centre = [0, 0, 0], radius = 0 }\npreset = \"matte\"\n".into(), vec!["op[0].sphere.radius", "> 0"]),
        ("insert sphere radius < 0", insert("sphere = { centre = [0, 0, 0], radius = -1 }"), vec!["op[0].sphere.radius", "> 0"]),
        ("plane normal zero", "[[op]]\nkind = \"material\"\nabove = { point = [0, 0, 0], normal = [0, 0, 0] }\npreset = \"matte\"\n".into(), vec!["op[0].above.normal", "non-zero"]),
        ("at = nan", "[[op]]\nkind = \"relight\"\nat = [nan, 0, 0]\nscale = 1\n".into(), vec!["op[0].at", "finite"]),
        ("scale = inf", "[[op]]\nkind = \"relight\"\nat = [0, 0, 0]\nscale = inf\n".into(), vec!["op[0].scale", "finite"]),
        ("scale = nan", "[[op]]\nkind = \"relight\"\nat = [0, 0, 0]\nscale = nan\n".into(), vec!["op[0].scale", "finite"]),
        ("box hi = inf", "[[op]]\nkind = \"material\"\nbox = { lo = [0, 0, 0], hi = [inf, 1, 1] }\npreset = \"matte\"\n".into(), vec!["op[0].box.hi", "finite"]),
        ("sphere radius = nan", insert("sphere = { centre = [0, 0, 0], radius = nan }"), vec!["op[0].sphere.radius"]),
        ("sphere centre = -inf", insert("sphere = { centre = [0, -inf, 0], radius = 1 }"), vec!["op[0].sphere.centre", "finite"]),
        ("plane point = nan", "[[op]]\nkind = \"material\"\nbelow = { point = [0, nan, 0], normal = [0, 1, 0] }\npreset = \"matte\"\n".into(), vec!["op[0].below.point", "finite"]),
        ("roughness = nan", material("roughness = nan"), vec!["op[0].roughness"]),
        ("kd = inf", material("kd = [inf, 0, 0]"), vec!["op[0].kd"]),
        ("emission = nan", insert(&format!("{SPHERE}\nemission = [nan, 1, 1]")), vec!["op[0].emission"]),
        ("texture origin = inf", texture("tex.png", "origin = [inf, 0, 0], u = [1, 0, 0], v = [0, 1, 0]"), vec!["op[0].texture.origin", "finite"]),
        ("mesh rotation = nan", mesh("good.ply", ", rotation = [nan, 0, 0]"), vec!["op[0].mesh.rotation", "finite"]),
        ("mesh translation = inf", mesh("good.ply", ", translation = [0, 0, inf]"), vec!["op[0].mesh.translation", "finite"]),
        ("huge value overflowing f32", "[[op]]\nkind = \"relight\"\nat = [1e300, 0, 0]\nscale = 1\n".into(), vec!["op[0].at"]),
        ("relight scale < 0", "[[op]]\nkind = \"relight\"\nat = [0, 0, 0]\nscale = -1\n".into(), vec!["op[0].scale", "≥ 0"]),
        ("relight color negative", format!("{relight}color = [1, -0.5, 1]\n"), vec!["op[0].color", "≥ 0"]),
        ("emission negative", insert(&format!("{SPHERE}\nemission = [1, 1, -1]")), vec!["op[0].emission", "≥ 0"]),
        ("kd > 1", material("kd = [1.5, 0, 0]"), vec!["op[0].kd", "[0, 1]"]),
        ("ks < 0", material("ks = [0, -0.1, 0]"), vec!["op[0].ks", "[0, 1]"]),
        ("roughness 0", material("roughness = 0"), vec!["op[0].roughness", "[0.01, 1]"]),
        ("unknown preset", material("preset = \"gold\""), vec!["op[0].preset", "gold"]),
        ("preset with values", material("preset = \"matte\"\nkd = [0.5, 0.5, 0.5]"), vec!["op[0].preset", "kd"]),
        ("material: neither preset nor values", material(""), vec!["op[0]", "needs a material"]),
        ("texture with kd", material(&format!("kd = [0.5, 0.5, 0.5]\ntexture = {{ image = \"tex.png\", {TEX_PLANE} }}")), vec!["op[0].texture", "kd"]),
        ("texture file missing", texture("missing.png", TEX_PLANE), vec!["op[0].texture.image", "missing.png", "not found"]),
        ("texture not an image type", texture("notes.txt", TEX_PLANE), vec!["op[0].texture.image", "notes.txt", ".png or .exr"]),
        ("texture garbage bytes", texture("garbage.png", TEX_PLANE), vec!["op[0].texture.image", "garbage.png"]),
        ("texture truncated PNG", texture("truncated.png", TEX_PLANE), vec!["op[0].texture.image", "truncated.png"]),
        ("texture garbage EXR", texture("garbage.exr", TEX_PLANE), vec!["op[0].texture.image", "garbage.exr"]),
        ("texture is a folder", texture("folder.png", TEX_PLANE), vec!["op[0].texture.image", "folder.png", "not a file"]),
        ("texture u ∥ v", texture("tex.png", "origin = [0, 0, 0], u = [1, 0, 0], v = [2, 0, 0]"), vec!["op[0].texture.v", "parallel"]),
        ("texture u zero", texture("tex.png", "origin = [0, 0, 0], u = [0, 0, 0], v = [0, 1, 0]"), vec!["op[0].texture.u", "non-zero"]),
        ("texture missing v", texture("tex.png", "origin = [0, 0, 0], u = [1, 0, 0]"), vec!["op[0].texture", "v"]),
        ("PLY mesh missing", mesh("absent.ply", ""), vec!["op[0].mesh.path", "absent.ply", "not found"]),
        ("PLY garbage", mesh("garbage.ply", ""), vec!["op[0].mesh.path", "garbage.ply"]),
        ("PLY bad header", mesh("header.ply", ""), vec!["op[0].mesh.path", "header.ply"]),
        ("PLY truncated", mesh("truncated.ply", ""), vec!["op[0].mesh.path", "truncated.ply"]),
        ("PLY faces out of range", mesh("faces.ply", ""), vec!["op[0].mesh.path", "faces.ply", "past"]),
        ("PLY non-finite vertex", mesh("nan.ply", ""), vec!["op[0].mesh.path", "nan.ply"]),
        ("PLY without faces", mesh("nofaces.ply", ""), vec!["op[0].mesh.path", "nofaces.ply", "empty"]),
        ("insert mesh scale 0", mesh("good.ply", ", scale = 0"), vec!["op[0].mesh.scale", "> 0"]),
        ("insert mesh scale < 0", mesh("good.ply", ", scale = -2"), vec!["op[0].mesh.scale", "> 0"]),
        ("mesh scale overflows to inf", mesh("good.ply", ", scale = 1e38, translation = [3e38, 0, 0]"), vec!["op[0].mesh.path", "not finite"]),
        ("error in the 2nd op", format!("{relight}[[op]]\nkind = \"insert\"\nsphere = {{ centre = [0, 0, 0], radius = 0 }}\n"), vec!["op[1].sphere.radius"]),
    ]
}

/// The files the edit rows refer to.
fn write_assets(dir: &Path) {
    let tex = i2sdf_data::imageio::ImageF32::from_data(2, 2, 3, vec![0.5; 12]);
    i2sdf_data::imageio::write_png(&dir.join("tex.png"), &tex).unwrap();
    let png = std::fs::read(dir.join("tex.png")).unwrap();
    std::fs::write(dir.join("truncated.png"), &png[..png.len() / 2]).unwrap();
    std::fs::write(dir.join("garbage.png"), b"\x00\x01 definitely not a PNG \xff\xfe").unwrap();
    std::fs::write(dir.join("garbage.exr"), b"v/1\x01 not an EXR either").unwrap();
    std::fs::write(dir.join("notes.txt"), b"wood").unwrap();
    std::fs::create_dir(dir.join("folder.png")).unwrap();
    let header = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n";
    let faces = "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
    let plys: [(&str, String); 7] = [
        ("good.ply", format!("{header}{faces}0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")),
        ("garbage.ply", "\u{7}\u{0}binary noise".into()),
        ("header.ply", "ply\nformat nonsense\n".into()),
        ("truncated.ply", format!("{header}{faces}0 0 0\n1 0")),
        ("faces.ply", format!("{header}{faces}0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")),
        ("nan.ply", format!("{header}{faces}0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n")),
        ("nofaces.ply", format!("{header}end_header\n0 0 0\n1 0 0\n0 1 0\n")),
    ];
    for (name, text) in plys {
        std::fs::write(dir.join(name), text).unwrap();
    }
}

/// The stage-2 configuration rows: (case, --set value, needles).
#[rustfmt::skip]
const STAGE2_SETS: &[(&str, &str, &[&str])] = &[
    ("iterations 0", "stage2.iterations=0", &["stage2.iterations", "1..="]),
    ("iterations negative", "stage2.iterations=-5", &["stage2.iterations"]),
    ("iterations fractional", "stage2.iterations=1.5", &["stage2.iterations"]),
    ("iterations = inf", "stage2.iterations=inf", &["stage2.iterations"]),
    ("pixels 0", "stage2.pixels=0", &["stage2.pixels", "1..="]),
    ("pixels too many", "stage2.pixels=2000000", &["stage2.pixels"]),
    ("estimator unknown", "stage2.estimator=fast", &["stage2.estimator", "fast"]),
    ("estimator wrong type", "stage2.estimator=3", &["stage2.estimator"]),
    ("cache_pixels negative", "stage2.cache_pixels=-1", &["stage2.cache_pixels"]),
    ("cache_pixels too many", "stage2.cache_pixels=100000000", &["stage2.cache_pixels"]),
    ("cache_samples 0", "stage2.cache_samples=0", &["stage2.cache_samples"]),
    ("cache_samples too many", "stage2.cache_samples=5000", &["stage2.cache_samples"]),
    ("refresh_pixels with pooled irradiance", "stage2.refresh_pixels=5", &["stage2.refresh_pixels", "stage2.irradiance_radius"]),
    ("refresh_pixels wrong type", "stage2.refresh_pixels=[1]", &["stage2.refresh_pixels"]),
    ("input_normals wrong type", "stage2.input_normals=yes", &["stage2.input_normals"]),
    ("label_unobserved wrong type", "stage2.label_unobserved=1", &["stage2.label_unobserved"]),
    ("irradiance_radius negative", "stage2.irradiance_radius=-0.1", &["stage2.irradiance_radius"]),
    ("irradiance_radius = nan", "stage2.irradiance_radius=nan", &["stage2.irradiance_radius", "finite"]),
    ("irradiance_radius too large", "stage2.irradiance_radius=0.6", &["stage2.irradiance_radius"]),
    ("bake_resolution too small", "stage2.bake_resolution=8", &["stage2.bake_resolution"]),
    ("bake_resolution too large", "stage2.bake_resolution=5000", &["stage2.bake_resolution"]),
    ("samples 0", "stage2.samples=0", &["stage2.samples"]),
    ("emitter_sampling wrong type", "stage2.emitter_sampling=maybe", &["stage2.emitter_sampling"]),
    ("lr_grid 0", "stage2.lr_grid=0", &["stage2.lr_grid"]),
    ("lr_grid = nan", "stage2.lr_grid=nan", &["stage2.lr_grid", "finite"]),
    ("lr_mlp negative", "stage2.lr_mlp=-1", &["stage2.lr_mlp"]),
    ("lr_emission = inf", "stage2.lr_emission=inf", &["stage2.lr_emission", "finite"]),
    ("lr_final_fraction > 1", "stage2.lr_final_fraction=2", &["stage2.lr_final_fraction"]),
    ("smooth negative", "stage2.smooth=-1", &["stage2.smooth"]),
    ("smooth = inf", "stage2.smooth=inf", &["stage2.smooth", "finite"]),
    ("energy = nan", "stage2.energy=nan", &["stage2.energy", "finite"]),
    ("smooth_epsilon 0", "stage2.smooth_epsilon=0", &["stage2.smooth_epsilon"]),
    ("rho_prior negative", "stage2.rho_prior=-1", &["stage2.rho_prior"]),
    ("rho_prior_target above 1", "stage2.rho_prior_target=1.2", &["stage2.rho_prior_target"]),
    ("rho_prior_from nan", "stage2.rho_prior_from=nan", &["stage2.rho_prior_from", "finite"]),
    ("emitters too many", "stage2.emitters=65", &["stage2.emitters"]),
    ("emitters wrong type", "stage2.emitters=two", &["stage2.emitters"]),
    ("max_emitters 0", "stage2.max_emitters=0", &["stage2.max_emitters"]),
    ("emitter_link 0", "stage2.emitter_link=0", &["stage2.emitter_link"]),
    ("emitter_min_fraction > 0.5", "stage2.emitter_min_fraction=0.6", &["stage2.emitter_min_fraction"]),
    ("emitter_threshold > 1", "stage2.emitter_threshold=2", &["stage2.emitter_threshold"]),
    ("emitter_threshold = -inf", "stage2.emitter_threshold=-inf", &["stage2.emitter_threshold", "finite"]),
    ("use_hdr wrong type", "stage2.use_hdr=sometimes", &["stage2.use_hdr"]),
    ("stage2.loss unknown", "stage2.loss=l3", &["stage2.loss", "l3"]),
    ("cache over 2^27 samples", "stage2.cache_pixels=67108864", &["stage2.cache_pixels", "stage2.cache_samples"]),
    ("unknown stage2 key", "stage2.iteratons=5", &["iteratons"]),
    ("lobes.rhos one lobe", "lobes.rhos=[0.5]", &["lobes.rhos", "2 to 16"]),
    ("lobes.rhos descending", "lobes.rhos=[0.7, 0.5]", &["lobes.rhos", "ascending"]),
    ("lobes.rhos nan", "lobes.rhos=[0.5, nan]", &["lobes.rhos[1]", "finite"]),
    ("lobes.rhos not a list", "lobes.rhos=0.5", &["lobes.rhos"]),
    ("lobes.segments 0", "lobes.segments=0", &["lobes.segments"]),
    ("lobes.margin negative", "lobes.margin=-0.1", &["lobes.margin"]),
    ("lobes.ks_min 0", "lobes.ks_min=0", &["lobes.ks_min"]),
    ("lobes.weight = inf", "lobes.weight=inf", &["lobes.weight", "finite"]),
    ("lobes.last_lr 0", "lobes.last_lr=0", &["lobes.last_lr"]),
    ("stage2 not a section", "stage2=3", &["stage2"]),
    ("material.hash_levels 0", "material.hash_levels=0", &["material.hash_levels"]),
    ("material.hash_log2_table 30", "material.hash_log2_table=30", &["material.hash_log2_table"]),
    ("material.hidden_dim 4", "material.hidden_dim=4", &["material.hidden_dim"]),
    ("material.rho_min = nan", "material.rho_min=nan", &["material.rho_min", "finite"]),
    ("material.rho_init 1", "material.rho_init=1", &["material.rho_init"]),
    ("material.ks_init 1.5", "material.ks_init=1.5", &["material.ks_init"]),
    ("material.backbone unknown", "material.backbone=cnn", &["material.backbone", "cnn"]),
    ("unknown material key", "material.colour=1", &["colour"]),
];

/// The configuration-file rows: (case, file text, needles).
#[rustfmt::skip]
const STAGE2_FILES: &[(&str, &str, &[&str])] = &[
    ("file: stage2 value = nan", "[stage2]\nlr_grid = nan\n", &["bad.toml", "stage2.lr_grid"]),
    ("file: stage2 wrong type", "[stage2]\npixels = \"many\"\n", &["bad.toml", "stage2.pixels (line 2)"]),
    ("file: unknown stage2 key", "[stage2]\nbounces = 3\n", &["bad.toml", "stage2.bounces (line 2)"]),
];

#[test]
fn bad_input_table() {
    let t = trained_stages();
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    write_assets(root);
    let mut table = Table::default();

    // `i2sdf edit`: the spec, its textures and meshes are checked before anything is written.
    for (i, (case, text, needles)) in edit_rows().into_iter().enumerate() {
        let spec = root.join("spec.toml");
        std::fs::write(&spec, &text).unwrap();
        let out = root.join(format!("out{i}"));
        let o = i2sdf(&[
            "edit",
            "--run",
            s(&t.stage2),
            "--spec",
            s(&spec),
            "--out",
            s(&out),
            "--spp",
            "1",
            "--bounces",
            "1",
            "--mesh-resolution",
            "32",
        ]);
        let untouched = if out.exists() {
            Err(format!("{} was created", out.display()))
        } else {
            Ok(())
        };
        table.record(&format!("edit: {case}"), o, 2, &needles, untouched);
    }
    let absent = root.join("absent.toml");
    let out = root.join("out_absent");
    let o = i2sdf(&["edit", "--run", s(&t.stage2), "--spec", s(&absent), "--out", s(&out)]);
    let untouched = if out.exists() {
        Err("out created".into())
    } else {
        Ok(())
    };
    table.record("edit: spec file missing", o, 2, &["absent.toml"], untouched);
    // An empty spec is valid (it renders the unedited scene).
    let empty = root.join("empty.toml");
    std::fs::write(&empty, "# nothing to change\n").unwrap();
    let out = root.join("out_empty");
    let o = i2sdf(&[
        "edit",
        "--run",
        s(&t.stage2),
        "--spec",
        s(&empty),
        "--out",
        s(&out),
        "--spp",
        "1",
        "--bounces",
        "1",
        "--mesh-resolution",
        "32",
        "--view",
        "0",
        "--width",
        "8",
        "--height",
        "6",
    ]);
    let written = (out.join("edit.toml").is_file())
        .then_some(())
        .ok_or("no edit.toml".into());
    table.record("edit: empty file (valid: the unedited scene)", o, 0, &[], written);

    // `i2sdf train --stage material`: a bad stage-2 value writes nothing into the run.
    let run = root.join("stage1");
    copy_stage1(&t.stage1, &run);
    let before = tree(&run);
    let unchanged = |run: &Path| {
        if tree(run) == before {
            Ok(())
        } else {
            Err(format!("{} changed", run.display()))
        }
    };
    for (case, set, needles) in STAGE2_SETS {
        let o = train_material(&t.data, &run, &["--set", set]);
        table.record(&format!("train: --set {set} ({case})"), o, 2, needles, unchanged(&run));
    }
    for (case, text, needles) in STAGE2_FILES {
        let config = root.join("bad.toml");
        std::fs::write(&config, text).unwrap();
        let o = train_material(&t.data, &run, &["--config", s(&config)]);
        table.record(&format!("train: {case}"), o, 2, needles, unchanged(&run));
    }

    // Marching cubes at a resolution that cannot fit is refused before anything is allocated.
    let ply = root.join("m.ply");
    let start = std::time::Instant::now();
    let o = i2sdf(&[
        "mesh",
        "--run",
        s(&t.stage1),
        "--out",
        s(&ply),
        "--resolution",
        "100000",
    ]);
    let quick = if start.elapsed().as_secs_f64() > 20.0 {
        Err(format!("took {:.1} s", start.elapsed().as_secs_f64()))
    } else if ply.exists() {
        Err("wrote the mesh".into())
    } else {
        Ok(())
    };
    table.record(
        "mesh: --resolution 100000",
        o,
        2,
        &["100000", "memory", "available"],
        quick,
    );
    table.finish(&[root, t._dir.path()]);
}

/// Issue 23's rows: commands aimed at a user's data, false successes, and messages that showed
/// internals. Each row runs the real binary and must exit with its code and name what is at
/// fault; after every row the dataset folder, both runs and the working folder are byte-identical
/// to before (every file hashed by its bytes), except for what a row is meant to write.
#[test]
fn nothing_a_user_has_is_overwritten() {
    let t = trained_stages();
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    // A dataset of the user's own, a stage-1 run and a stage-2 run, each a copy (so the shared
    // fixtures stay clean whatever happens here).
    let data = root.join("scene");
    i2sdf_data::fixture::write_native(&data, &i2sdf_data::fixture::FixtureOptions::default());
    let run1 = root.join("run1");
    copy_stage1(&t.stage1, &run1);
    let run2 = root.join("run2");
    copy_stage1(&t.stage2, &run2);
    for f in ["stage2.safetensors", "emitters.json"] {
        std::fs::copy(t.stage2.join(f), run2.join(f)).unwrap();
    }
    // Both runs point at this dataset (run.json records an absolute path).
    for run in [&run1, &run2] {
        let text = std::fs::read_to_string(run.join("run.json")).unwrap();
        let mut info: serde_json::Value = serde_json::from_str(&text).unwrap();
        info["data"] = serde_json::Value::String(data.display().to_string());
        std::fs::write(run.join("run.json"), serde_json::to_string_pretty(&info).unwrap()).unwrap();
    }
    let existing = root.join("metrics.json");
    std::fs::write(&existing, b"{\"mine\": true}").unwrap();
    let existing_ply = root.join("mine.ply");
    std::fs::write(&existing_ply, b"ply\n").unwrap();
    let a_file = root.join("notes.txt");
    std::fs::write(&a_file, b"a user's file").unwrap();
    let user_dir = root.join("photos");
    std::fs::create_dir(&user_dir).unwrap();
    std::fs::write(user_dir.join("a.jpg"), b"jpeg").unwrap();
    let spec = root.join("relight.toml");
    std::fs::write(&spec, "[[op]]\nkind = \"relight\"\nat = [0, 0, 0]\nscale = 2\n").unwrap();
    let fixture_pose = root.join("pose");
    let fixture_flx = root.join("flx");
    for (d, edit) in [(&fixture_pose, "pose" as &str), (&fixture_flx, "flx")] {
        i2sdf_data::fixture::write_native(d, &i2sdf_data::fixture::FixtureOptions::default());
        let p = d.join("transforms.json");
        let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
        match edit {
            "pose" => v["frames"][0]["transform_matrix"][3] = serde_json::json!([0.0, 0.0, 0.0, 0.0]),
            _ => {
                v["fl_x"] = serde_json::json!(0.0);
                if let Some(frames) = v["frames"].as_array_mut() {
                    for f in frames {
                        if let Some(o) = f.as_object_mut() {
                            o.remove("fl_x");
                        }
                    }
                }
            }
        }
        std::fs::write(&p, serde_json::to_string(&v).unwrap()).unwrap();
    }
    // A run whose run.json names a dataset that is no longer there.
    let moved = root.join("moved_run");
    copy_stage1(&run1, &moved);
    let text = std::fs::read_to_string(moved.join("run.json")).unwrap();
    let mut info: serde_json::Value = serde_json::from_str(&text).unwrap();
    info["data"] = serde_json::Value::String(root.join("gone").display().to_string());
    std::fs::write(moved.join("run.json"), serde_json::to_string_pretty(&info).unwrap()).unwrap();
    let moved_run = moved.display().to_string();
    let before = tree(root);
    let (d, r1, r2) = (s(&data), s(&run1), s(&run2));
    // Paths as the rows' arguments (a test's strings may live to its end).
    let leak = |p: &Path| -> &'static str { Box::leak(p.display().to_string().into_boxed_str()) };
    let p = |name: &str| leak(&root.join(name));
    let file_in_data = data.join("mesh.json").display().to_string();
    let below_file = a_file.join("m.json").display().to_string();
    let run_json = run1.join("run.json").display().to_string();
    let in_data = data.join("run").display().to_string();
    let e = s(&existing);
    let u = s(&user_dir);
    let nf = s(&a_file);
    let sp = s(&spec);
    #[rustfmt::skip]
    let rows: Vec<(&str, Vec<&str>, i32, Vec<&str>)> = vec![
        ("eval --out into the dataset", vec!["eval", "--run", r1, "--data", d, "--out", &file_in_data], 2, vec!["never writes into a dataset"]),
        ("eval --out a .ply", vec!["eval", "--run", r1, "--out", p("m.ply")], 2, vec!["--out", "must end in .json"]),
        ("eval --out an existing folder", vec!["eval", "--run", r1, "--out", u], 2, vec!["--out", "is a folder"]),
        ("eval --out below a file (before the work)", vec!["eval", "--run", r1, "--out", &below_file], 1, vec!["--out", "is a file"]),
        ("eval --out an existing file", vec!["eval", "--run", r1, "--out", e], 2, vec!["--out", "exists", "--force"]),
        ("eval --mesh-out into the dataset", vec!["eval", "--run", r1, "--out", p("new.json"), "--mesh-out", leak(&data.join("mesh.ply")), "--force"], 2, vec!["--mesh-out", "never writes into a dataset"]),
        ("eval --out the run's own file", vec!["eval", "--run", r1, "--out", &run_json, "--force"], 2, vec!["run's own file"]),
        ("eval --mesh a missing file", vec!["eval", "--run", r1, "--out", p("gm.json"), "--mesh", p("missing.ply")], 2, vec!["missing.ply", "cannot read"]),
        ("eval --mesh not a PLY", vec!["eval", "--run", r1, "--out", p("gm.json"), "--mesh", nf], 2, vec![nf]),
        ("eval --renders into the dataset", vec!["eval", "--run", r1, "--out", p("rd.json"), "--renders", leak(&data.join("renders"))], 2, vec!["--renders", "never writes into a dataset"]),
        ("eval --renders over a user's folder", vec!["eval", "--run", r1, "--out", p("rd.json"), "--renders", u], 2, vec!["--renders"]),
        ("eval --mesh with --mesh-out", vec!["eval", "--run", r1, "--out", p("gm.json"), "--mesh", leak(&existing_ply), "--mesh-out", p("gm.ply")], 2, vec!["--mesh-out with --mesh"]),
        ("render --out the dataset", vec!["render", "--run", r1, "--out", d], 2, vec!["--out", "is a dataset"]),
        ("render --out the dataset --force", vec!["render", "--run", r1, "--out", d, "--force"], 2, vec!["--out", "is a dataset"]),
        ("render --out a folder inside the dataset", vec!["render", "--run", r1, "--out", leak(&data.join("depth")), "--force"], 2, vec!["never writes into a dataset"]),
        ("render --out the run", vec!["render", "--run", r1, "--out", r1, "--force"], 2, vec!["is a training run"]),
        ("render --out a user's folder", vec!["render", "--run", r1, "--out", u], 2, vec!["not empty", "--force"]),
        ("render --out a user's folder --force", vec!["render", "--run", r1, "--out", u, "--force"], 2, vec!["not a render"]),
        ("render --what ''", vec!["render", "--run", r1, "--out", p("r"), "--what", ""], 2, vec!["--what", "names no map"]),
        ("render --out a file", vec!["render", "--run", r1, "--out", nf], 2, vec!["is a file"]),
        ("edit --out a file", vec!["edit", "--run", r2, "--spec", sp, "--out", nf], 2, vec!["--out", "is a file"]),
        ("edit --view -1", vec!["edit", "--run", r2, "--spec", sp, "--out", p("e"), "--view", "-1"], 2, vec!["--view", "0 or more"]),
        ("report --view -1", vec!["report", "--run", r2, "--out", p("rep"), "--view", "-1"], 2, vec!["--view", "0 or more"]),
        ("report --out the dataset", vec!["report", "--run", r2, "--out", d, "--force"], 2, vec!["is a dataset"]),
        ("synth --out a user's folder", vec!["synth", "--out", u], 2, vec!["--out", "not empty", "--force"]),
        ("synth --out a user's folder --force", vec!["synth", "--out", u, "--force"], 2, vec!["not a dataset made by synth"]),
        ("synth --out the dataset (not synth's)", vec!["synth", "--out", d, "--force"], 2, vec!["is a dataset"]),
        ("synth --out a file", vec!["synth", "--out", nf], 2, vec!["is a file"]),
        ("synth --max-depth 0", vec!["synth", "--out", p("s"), "--max-depth", "0"], 2, vec!["--max-depth 0", "1..="]),
        ("synth --views 100000000", vec!["synth", "--out", p("s"), "--views", "100000000"], 2, vec!["--views 100000000", "2..="]),
        ("mesh --out m.obj", vec!["mesh", "--run", r1, "--out", p("m.obj")], 2, vec!["--out", "must end in .ply"]),
        ("mesh --out an existing file", vec!["mesh", "--run", r1, "--out", leak(&existing_ply)], 2, vec!["--out", "exists", "--force"]),
        ("train --out inside the dataset", vec!["train", "--data", d, "--out", &in_data], 2, vec!["never writes into a dataset"]),
        ("train --out a user's folder", vec!["train", "--data", d, "--out", u], 2, vec!["not a run"]),
        ("train over the machine's memory", vec!["train", "--data", d, "--out", p("big"), "--set", "train.rays=1048576"], 2, vec!["train.rays", "1048576", "GiB", "--ignore-memory"]),
        ("train --stage material over the memory", vec!["train", "--stage", "material", "--out", r1, "--set", "stage2.pixels=1048576", "--set", "stage2.samples=256", "--set", "material.hidden_dim=256", "--set", "material.hidden_layers=8"], 2, vec!["stage 2 needs", "stage2.pixels × stage2.samples", "--ignore-memory"]),
        ("demo --out a user's folder", vec!["demo", "--out", u, "--quick"], 2, vec!["not a demo's"]),
        ("demo --lpips-weights not safetensors", vec!["demo", "--out", p("demo"), "--quick", "--lpips-weights", e], 2, vec![e]),
        ("bench --rays 0", vec!["bench", "--rays", "0"], 2, vec!["--rays 0"]),
        ("bench --iterations 0", vec!["bench", "--iterations", "0"], 2, vec!["--iterations 0"]),
        ("check --data a file", vec!["check", "--data", leak(&data.join("transforms.json"))], 2, vec!["is a file, not a dataset folder"]),
        ("check: a pose's last row", vec!["check", "--data", s(&fixture_pose)], 2, vec!["transform_matrix", "[0, 0, 0, 0]"]),
        ("check: fl_x = 0", vec!["check", "--data", s(&fixture_flx)], 2, vec!["fl_x", "must be positive"]),
        ("--set log_every=0", vec!["check", "--data", d, "--set", "train.log_every=0"], 2, vec!["train.log_every", "1..=100000000"]),
        ("--set a number too large", vec!["check", "--data", d, "--set", "train.iterations=99999999999999999999999"], 2, vec!["train.iterations", "not a number this key can hold"]),
        // The fixture's views see no emitter: its stage 2 found none.
        ("edit: relight on a run without emitters", vec!["edit", "--run", r2, "--spec", sp, "--out", p("e")], 2, vec!["op[0]", "no emitters"]),
        ("render: the run's dataset is gone", vec!["render", "--run", &moved_run, "--out", p("rm")], 2, vec!["run.json", "data", "--data"]),
    ];
    let mut table = Table::default();
    for (case, args, code, needles) in rows {
        let o = i2sdf(&args);
        let diff = tree_diff(&before, &tree(root));
        let untouched = if diff.is_empty() {
            Ok(())
        } else {
            Err(format!("changed: {}", diff.join(", ")))
        };
        // Never a message that shows internals.
        let internals = ["DVec4", "18446744073709551615", "invalid type: string", "os error 17"];
        let mut needles = needles;
        let shown: Vec<&&str> = internals.iter().filter(|n| o.stderr.contains(**n)).collect();
        if !shown.is_empty() {
            needles.push("<no internals in the message>");
        }
        table.record(case, o, code, &needles, untouched);
    }
    table.finish(&[root]);
}

/// The other side of the rows above: what the commands do write. `synth --force` replaces its
/// own earlier dataset whole (no file of a larger one left behind); `eval` writes its JSON and,
/// only when asked, the mesh; a run trained with a relative `--data` opens from another folder
/// (run.json holds the absolute path), and one whose dataset moved opens with `--data`; stage 2
/// without emitters says so.
#[test]
fn outputs_go_only_where_asked_and_runs_travel() {
    let t = trained_stages();
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    let synth = |views: &str, force: bool| {
        let out = root.join("room");
        let mut args = vec![
            "synth",
            "--out",
            s(&out),
            "--width",
            "16",
            "--height",
            "12",
            "--views",
            views,
            "--spp",
            "1",
        ];
        if force {
            args.push("--force");
        }
        i2sdf(&args)
    };
    expect(synth("6", false), 0, &[]);
    let six = tree(&root.join("room"));
    expect(synth("2", false), 2, &["--force"]);
    assert!(
        tree_diff(&six, &tree(&root.join("room"))).is_empty(),
        "a refused synth changed the room"
    );
    expect(synth("2", true), 0, &[]);
    let two = tree(&root.join("room"));
    assert!(
        two.len() < six.len(),
        "the larger dataset's files are gone: {} vs {}",
        two.len(),
        six.len()
    );
    assert!(
        !two.keys().any(|k| k.contains("0005")),
        "{:?}",
        two.keys().collect::<Vec<_>>()
    );
    assert_eq!(
        i2sdf_data::output::entries(root),
        vec!["room".to_string()],
        "no staging left"
    );

    // eval: the JSON only, the mesh with --mesh-out, an existing JSON replaced with --force.
    let out = root.join("m.json");
    let o = i2sdf(&eval_args(&t.stage1, &t.data, &out, &["--mesh-resolution", "32"]));
    assert_eq!(o.code, 0, "{}", o.stderr);
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert!(v["notes"].is_array(), "{v}");
    let mut names = i2sdf_data::output::entries(root);
    names.sort();
    assert_eq!(names, ["m.json", "room"], "eval wrote only its JSON");
    let mesh = root.join("scored.ply");
    let o = i2sdf(&eval_args(
        &t.stage1,
        &t.data,
        &out,
        &["--mesh-resolution", "32", "--mesh-out", s(&mesh), "--force"],
    ));
    assert_eq!(o.code, 0, "{}", o.stderr);
    assert!(i2sdf_data::ply::read_ply(&mesh).is_ok_and(|m| m.num_faces() > 0));

    // A run trained with a relative --data, used from another folder, then its dataset moved.
    let work = root.join("work");
    std::fs::create_dir(&work).unwrap();
    i2sdf_data::fixture::write_native(&work.join("data"), &i2sdf_data::fixture::FixtureOptions::default());
    let mut args = vec!["train", "--quiet", "--data", "data", "--out", "run"];
    args.extend_from_slice(&TINY);
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_i2sdf"))
        .args(&args)
        .current_dir(&work)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let info: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(work.join("run/run.json")).unwrap()).unwrap();
    assert!(Path::new(info["data"].as_str().unwrap()).is_absolute(), "{info}");
    assert!(info["data_fingerprint"]["cameras"].is_string(), "{info}");
    let render = |run: &Path, out: &Path, extra: &[&str]| {
        let mut args = vec!["render", "--run", s(run), "--out", s(out), "--what", "rgb"];
        args.extend_from_slice(extra);
        i2sdf(&args)
    };
    expect(render(&work.join("run"), &root.join("r1"), &[]), 0, &[]);
    std::fs::rename(work.join("data"), root.join("data_moved")).unwrap();
    expect(
        render(&work.join("run"), &root.join("r2"), &[]),
        2,
        &["run.json", "--data"],
    );
    assert!(!root.join("r2").exists());
    let moved = root.join("data_moved");
    expect(
        render(&work.join("run"), &root.join("r2"), &["--data", s(&moved)]),
        0,
        &[],
    );
    // Another dataset under --data is said (a warning), not refused.
    let o = render(&work.join("run"), &root.join("r3"), &["--data", s(&root.join("room"))]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    assert!(
        o.stderr.contains("not the dataset the run was trained on"),
        "{}",
        o.stderr
    );

    // Stage 2 that finds no emitters says so (the fixture's views see none).
    let run2 = root.join("run_s2");
    copy_stage1(&t.stage1, &run2);
    let o = train_material(&t.data, &run2, &TINY_STAGE2);
    assert_eq!(o.code, 0, "{}", o.stderr);
    assert!(o.stderr.contains("stage 2 found no emitters"), "{}", o.stderr);
}

/// A declared exposure that the dataset's own LDR and HDR images contradict is refused by stage 2
/// (exit 2, naming `ldr.exposure` and both values, the run unchanged) unless trusted; `check`
/// prints the measured exposure and the same disagreement as a warning.
/// The paper release's files beyond the cameras and images (issue 27): material masks, the val
/// views' annotations, `radiometry.json`, a GT point cloud, a scene without `val/`. Each wrong one
/// exits 2 naming the file (and field), and nothing is written into the dataset or beside it.
#[test]
fn paper_release_bad_input_table() {
    use i2sdf_data::fixture::{FixtureOptions, PaperOptions};
    use i2sdf_data::imageio::{self, ImageF32};
    let t = trained_stages();
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    let full = PaperOptions {
        val_maps: true,
        material_masks: true,
        materials: true,
        point_cloud: true,
        ..Default::default()
    };
    let small = |channels| ImageF32::new(10, 7, channels);
    type Break = Box<dyn Fn(&Path)>;
    #[rustfmt::skip]
    let rows: Vec<(&str, Break, Vec<&str>)> = vec![
        ("material mask of the wrong size",
         Box::new(move |d| imageio::write_png(&d.join("mask/0001.png"), &small(1)).unwrap()),
         vec!["mask/0001.png", "10×7", "24×18"]),
        ("material masks not one per image",
         Box::new(|d| std::fs::remove_file(d.join("mask/0003.png")).unwrap()),
         vec!["mask", "3 files but image/ has 4"]),
        ("val depth of the wrong size",
         Box::new(move |d| imageio::write_exr(&d.join("val/depth/0001.exr"), &small(3)).unwrap()),
         vec!["val/depth/0001.exr", "10×7"]),
        ("val Kd map of the wrong size",
         Box::new(move |d| imageio::write_exr(&d.join("val/material/0000_kd.exr"), &small(3)).unwrap()),
         vec!["val/material/0000_kd.exr", "10×7"]),
        ("val normals not one per val image",
         Box::new(|d| std::fs::remove_file(d.join("val/normal/0001.exr")).unwrap()),
         vec!["val/normal", "1 files but val/ has 2"]),
        ("radiometry.json not JSON",
         Box::new(|d| std::fs::write(d.join("radiometry.json"), "ldr: srgb").unwrap()),
         vec!["radiometry.json", "invalid JSON"]),
        ("radiometry.json without ldr",
         Box::new(|d| std::fs::write(d.join("radiometry.json"), r#"{"exposure": 2}"#).unwrap()),
         vec!["radiometry.json", "ldr", "missing"]),
        ("radiometry.json with a bad transfer",
         Box::new(|d| std::fs::write(d.join("radiometry.json"), r#"{"ldr": {"transfer": "log"}}"#).unwrap()),
         vec!["radiometry.json", "ldr.transfer", "log"]),
        ("no val/ and one image",
         Box::new(|d| {
             std::fs::remove_dir_all(d.join("val")).unwrap();
             for k in 1..4 {
                 for (sub, ext) in [("image", "png"), ("depth", "exr"), ("normal", "exr"), ("light_mask", "png"),
                                    ("mask", "png")] {
                     std::fs::remove_file(d.join(format!("{sub}/{k:04}.{ext}"))).unwrap();
                 }
             }
         }),
         vec!["image", "nothing to train on"]),
    ];
    let mut table = Table::default();
    let mut row = |case: &str, args: &[&str], needles: &[&str]| {
        let before = tree(root);
        let o = i2sdf(args);
        let diff = tree_diff(&before, &tree(root));
        let untouched = if diff.is_empty() { Ok(()) } else { Err(diff.join(", ")) };
        table.record(case, o, 2, needles, untouched);
    };
    for (k, (case, break_it, needles)) in rows.iter().enumerate() {
        let data = root.join(format!("paper{k}"));
        i2sdf_data::fixture::write_paper_with(&data, &FixtureOptions::default(), &full);
        break_it(&data);
        let (case, args) = (format!("check (paper): {case}"), ["check", "--data", s(&data)]);
        row(&case, &args, needles);
    }
    // A GT point cloud without points: refused before any view is rendered, no metrics written.
    let data = root.join("paper_cloud");
    i2sdf_data::fixture::write_paper_with(&data, &FixtureOptions::default(), &full);
    i2sdf_data::ply::write_ply(data.join("mesh.ply"), &Default::default()).unwrap();
    let out = root.join("metrics.json");
    let eval = eval_args(&t.stage1, &data, &out, &["--mesh-resolution", "16"]);
    let needles = ["mesh.ply", "vertex", "no vertices"];
    row("eval (paper): GT point cloud with no vertices", &eval, &needles);
    table.finish(&[root]);
}
