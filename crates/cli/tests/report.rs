//! `i2sdf report`: on a tiny fixture run (stage 1 only, then with a tiny stage 2) the page is
//! valid HTML (html5ever, through `scraper`, reports no parse error), every file it references
//! exists inside the report, and it links nothing outside (no network); bad input exits 2
//! naming the file, an unwritable output exits 1, and neither leaves a report behind.

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The fixture dataset, a tiny stage-1 run, and a copy of it with a tiny stage 2.
fn runs() -> &'static (tempfile::TempDir, PathBuf, PathBuf, PathBuf) {
    static RUNS: OnceLock<(tempfile::TempDir, PathBuf, PathBuf, PathBuf)> = OnceLock::new();
    RUNS.get_or_init(|| {
        let (dir, data, run) = tiny_stage1();
        let run2 = dir.path().join("run2");
        tiny_stage2(&data, &run, &run2);
        (dir, data, run, run2)
    })
}

/// `i2sdf report` with the fast settings and `extra` arguments.
fn report(run: &Path, out: &Path, extra: &[&str]) -> Outcome {
    let mut args = vec![
        "report",
        "--run",
        s(run),
        "--out",
        s(out),
        "--spp",
        "2",
        "--bounces",
        "2",
        "--mesh-resolution",
        "32",
    ];
    args.extend_from_slice(extra);
    i2sdf(&args)
}

/// Parses `DIR/index.html`: no parse errors, every `src`/`href` a relative path to a file inside
/// DIR (or a `#fragment` of the page); returns the page's text and how many files it references.
fn check_page(dir: &Path) -> (String, usize) {
    let text = std::fs::read_to_string(dir.join("index.html")).unwrap();
    let doc = scraper::Html::parse_document(&text);
    assert!(doc.errors.is_empty(), "HTML parse errors: {:?}", doc.errors);
    let sel = scraper::Selector::parse("[src], [href]").unwrap();
    let mut files = 0;
    for el in doc.select(&sel) {
        for attr in ["src", "href"] {
            let Some(link) = el.value().attr(attr) else { continue };
            if link.starts_with('#') {
                let id = &link[1..];
                let by_id = scraper::Selector::parse(&format!("[id=\"{id}\"]")).unwrap();
                assert!(doc.select(&by_id).next().is_some(), "no element with id {id}");
                continue;
            }
            assert!(
                !link.contains(':') && !link.starts_with('/') && !link.contains(".."),
                "not a relative link inside the report: {link}"
            );
            assert!(dir.join(link).is_file(), "{attr}={link} does not exist");
            files += 1;
        }
    }
    assert!(!dir.join(".partial").exists(), "the staging directory was left behind");
    (text, files)
}

#[test]
fn stage1_and_stage2_reports_are_valid_and_complete() {
    let (_, data, run, run2) = runs();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r1");
    let o = report(run, &out, &["--data", s(data)]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    let (text, files) = check_page(&out);
    assert!(files >= 10, "only {files} files referenced");
    assert!(
        text.contains("Not evaluated") && text.contains("No stage 2"),
        "stage-1 page"
    );
    for name in [
        "rgb_gt",
        "rgb_ours",
        "rgb_err",
        "depth_err",
        "normal_err",
        "emitter_err",
        "mesh_overview",
    ] {
        assert!(out.join(format!("img/{name}.png")).is_file(), "{name}");
    }
    assert!(text.contains("chart_0.svg") && out.join("emitters_top.svg").is_file());

    // With stage 2 and a metrics file (the dataset defaults to the run's).
    let metrics = dir.path().join("m.json");
    std::fs::write(
        &metrics,
        r#"{"novel_view": {"psnr": 21.5, "ssim": 0.5, "lpips": null}, "geometry": {"mesh": {"fscore": 0.4}}}"#,
    )
    .unwrap();
    let out2 = dir.path().join("r2");
    let o = report(run2, &out2, &["--metrics", s(&metrics)]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    let (text, _) = check_page(&out2);
    assert!(
        text.contains("21.50") && text.contains("28.42"),
        "metrics beside the paper's"
    );
    for name in [
        "albedo_ours",
        "roughness_ours",
        "rerender_ours",
        "mirror_traced",
        "mirror_diff",
    ] {
        assert!(out2.join(format!("img/{name}.png")).is_file(), "{name}");
    }
    // A second report into the same directory: refused, then with --force it replaces the first.
    expect(report(run, &out2, &["--data", s(data)]), 2, &["--force"]);
    let o = report(run, &out2, &["--data", s(data), "--force"]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    check_page(&out2);
    assert!(
        !out2.join("img/albedo_ours.png").exists(),
        "stale images of the previous report"
    );
}

#[test]
fn bad_input_exits_2_and_failed_writes_exit_1() {
    let (_, data, run, _) = runs();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    expect(report(&dir.path().join("nowhere"), &out, &[]), 2, &["run.json"]);
    let bad = dir.path().join("bad_metrics.json");
    std::fs::write(&bad, "{ \"novel_view\": ").unwrap();
    expect(report(run, &out, &["--metrics", s(&bad)]), 2, &["bad_metrics.json"]);
    std::fs::write(&bad, "[1, 2, 3]").unwrap();
    expect(report(run, &out, &["--metrics", s(&bad)]), 2, &["bad_metrics.json"]);
    expect(
        report(run, &out, &["--metrics", s(&dir.path().join("absent.json"))]),
        2,
        &["absent.json"],
    );
    expect(
        report(run, &out, &["--data", s(&dir.path().join("no_data"))]),
        2,
        &["no_data"],
    );
    expect(
        report(run, &out, &["--data", s(data), "--view", "99"]),
        2,
        &["--view 99"],
    );
    let spp0 = ["report", "--run", s(run), "--out", s(&out), "--spp", "0"];
    expect(i2sdf(&spp0), 2, &["--spp 0"]);
    assert!(!out.exists(), "a refused report wrote {}", out.display());
    // The output's parent is a regular file: nothing can be created there.
    let blocker = dir.path().join("not_a_directory");
    std::fs::write(&blocker, b"x").unwrap();
    expect(
        report(run, &blocker.join("r"), &["--data", s(data)]),
        1,
        &["not_a_directory"],
    );
}

/// Eval and the report of one run agree on the relit sets: the report renders the first frame of
/// each set through eval's own relight scoring, so at eval's settings its captions are the
/// figures eval's metrics give that frame (`relight.sets.NAME.per_frame`); at other settings the
/// report says that its renders differ.
#[test]
fn relit_captions_are_evals_per_frame_figures() {
    let (_, _, stage1, _) = runs();
    let dir = tempfile::tempdir().unwrap();
    // The fixture again, with a relit set: the test frames under a spec that doubles the light
    // nearest the origin (the images are not relit: only the agreement is tested).
    let data = dir.path().join("data");
    i2sdf_data::fixture::write_native(&data, &i2sdf_data::fixture::FixtureOptions::default());
    let json_path = data.join("transforms.json");
    let mut json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json_path).unwrap()).unwrap();
    let tests: Vec<serde_json::Value> = json["frames"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| f["split"] == "test")
        .cloned()
        .collect();
    assert!(!tests.is_empty());
    json["relight"] = serde_json::json!([{"spec": "relight/brighter.toml", "frames": tests}]);
    std::fs::write(&json_path, serde_json::to_string_pretty(&json).unwrap()).unwrap();
    std::fs::create_dir_all(data.join("relight")).unwrap();
    std::fs::write(
        data.join("relight/brighter.toml"),
        "[[op]]\nkind = \"relight\"\nat = [0, 0, 0]\nscale = 2\n",
    )
    .unwrap();
    // Stage 2 with emitters to relight.
    let run = dir.path().join("run");
    copy_stage1(stage1, &run);
    let o = train_material(&data, &run, &tiny_stage2_any_emitters());
    assert_eq!(o.code, 0, "{}", o.stderr);

    let metrics = dir.path().join("metrics.json");
    let fast = ["--spp", "2", "--bounces", "2", "--mesh-resolution", "32"];
    let o = i2sdf(&eval_args(&run, &data, &metrics, &fast));
    assert_eq!(o.code, 0, "{}", o.stderr);
    let m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&metrics).unwrap()).unwrap();
    let frame = &m["relight"]["sets"]["brighter"]["per_frame"][0];
    let (traced, diff, ratio) = (
        frame["psnr"].as_f64().unwrap(),
        frame["psnr_differential"].as_f64().unwrap(),
        frame["psnr_ratio"].as_f64().unwrap(),
    );

    let caption = |text: &str, what: &str| -> String {
        let at = text
            .find(&format!("{what}, "))
            .unwrap_or_else(|| panic!("no '{what}' caption"));
        let rest = &text[at + what.len() + 2..];
        rest[..rest.find(" dB").unwrap()].to_string()
    };
    let out = dir.path().join("r");
    let o = report(&run, &out, &["--data", s(&data), "--metrics", s(&metrics)]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    let (text, _) = check_page(&out);
    for (what, figure) in [("path traced", traced), ("differential", diff), ("ratio", ratio)] {
        let shown = caption(&text, what);
        assert_eq!(
            shown,
            i2sdf_report::html::format_sig(figure),
            "{what}: the report shows {shown} dB, eval {figure} dB"
        );
    }
    assert!(
        !text.contains("Eval scored the relit sets at"),
        "same settings, no note"
    );
    // At other settings the report says so.
    let out = dir.path().join("r3");
    let o = i2sdf(&[
        "report",
        "--run",
        s(&run),
        "--out",
        s(&out),
        "--data",
        s(&data),
        "--metrics",
        s(&metrics),
        "--spp",
        "3",
        "--bounces",
        "2",
        "--mesh-resolution",
        "32",
    ]);
    assert_eq!(o.code, 0, "{}", o.stderr);
    let (text, _) = check_page(&out);
    assert!(text.contains("Eval scored the relit sets at 2 paths per pixel"));
}
