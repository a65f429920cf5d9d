//! The metrics section: the `i2sdf eval` JSON read as a loose JSON value (a newer or older eval
//! may add or drop keys; a missing figure shows as "—"), beside the paper's figures where the
//! paper reports a comparable one. The paper's numbers are on its own dataset (12 artist-made
//! scenes rendered at 4096 spp), so they are a reference point, not a like-for-like comparison.

use crate::html::{esc, format_sig};
use i2sdf_data::DataError;
use serde_json::Value;
use std::fmt::Write as _;
use std::path::Path;

/// Reads the metrics JSON: bad input (exit 2, the file named) when it is not a JSON object.
pub fn read_metrics(path: &Path) -> Result<Value, DataError> {
    let text = std::fs::read_to_string(path).map_err(|e| DataError::file(path, format!("cannot read: {e}")))?;
    let v: Value = serde_json::from_str(&text).map_err(|e| DataError::file(path, format!("not valid JSON: {e}")))?;
    if !v.is_object() {
        return Err(DataError::file(
            path,
            "not an i2sdf eval report: expected a JSON object",
        ));
    }
    if !["novel_view", "geometry", "rerender", "material", "relight"]
        .iter()
        .any(|k| v.get(k).is_some())
    {
        return Err(DataError::file(
            path,
            "not an i2sdf eval report: none of novel_view, geometry, rerender, material, relight",
        ));
    }
    Ok(v)
}

/// The figure at a dotted path (`geometry.mesh.fscore`), when it is a number.
pub fn at(v: &Value, path: &str) -> Option<f64> {
    path.split('.').try_fold(v, |v, k| v.get(k))?.as_f64()
}

/// One row: label, JSON path, the paper's figure (with its source), which way is better.
struct Row {
    label: &'static str,
    path: &'static str,
    paper: Option<(f64, &'static str)>,
    better: &'static str,
}

const fn row(label: &'static str, path: &'static str, paper: Option<(f64, &'static str)>, better: &'static str) -> Row {
    Row {
        label,
        path,
        paper,
        better,
    }
}

/// The rows of the table. The paper's figures: Table "novel" (synthetic, test views; training
/// views in brackets, which `eval --split train|both` measures), Table
/// "mesh" (synthetic), the supplementary's per-scene normal / depth table (its mean). The paper
/// reports no material, re-render or relighting figures.
const ROWS: &[Row] = &[
    row(
        "novel view PSNR (dB)",
        "novel_view.psnr",
        Some((28.42, "Tab. novel, synthetic")),
        "↑",
    ),
    row(
        "novel view SSIM",
        "novel_view.ssim",
        Some((0.87, "Tab. novel, synthetic")),
        "↑",
    ),
    row(
        "novel view LPIPS",
        "novel_view.lpips",
        Some((0.15, "Tab. novel, synthetic")),
        "↓",
    ),
    row(
        "training views PSNR (dB)",
        "train_view.psnr",
        Some((29.70, "Tab. novel, synthetic, in brackets")),
        "↑",
    ),
    row(
        "training views SSIM",
        "train_view.ssim",
        Some((0.87, "Tab. novel, synthetic, in brackets")),
        "↑",
    ),
    row(
        "training views LPIPS",
        "train_view.lpips",
        Some((0.19, "Tab. novel, synthetic, in brackets")),
        "↓",
    ),
    row(
        "depth L1 (world units)",
        "geometry.depth_l1",
        Some((0.035, "supp. Tab. normal/depth, mean")),
        "↓",
    ),
    row(
        "normal angular L1 (1 − n̂·n)",
        "geometry.normal_angular_l1",
        Some((0.053, "supp. Tab. normal/depth, mean")),
        "↓",
    ),
    row(
        "mesh accuracy",
        "geometry.mesh.accuracy",
        Some((0.035, "Tab. mesh")),
        "↓",
    ),
    row("mesh completeness", "geometry.mesh.completeness", None, "↓"),
    row(
        "mesh precision",
        "geometry.mesh.precision",
        Some((0.87, "Tab. mesh")),
        "↑",
    ),
    row("mesh recall", "geometry.mesh.recall", Some((0.79, "Tab. mesh")), "↑"),
    row("mesh F-score", "geometry.mesh.fscore", Some((0.83, "Tab. mesh")), "↑"),
    row(
        "F-score threshold",
        "geometry.mesh.threshold",
        Some((0.05, "Sec. 6")),
        "",
    ),
    row(
        "thin objects recall @2 cm",
        "geometry.thin_objects.recall_2cm",
        None,
        "↑",
    ),
    row(
        "thin objects recall @5 cm",
        "geometry.thin_objects.recall_5cm",
        None,
        "↑",
    ),
    row(
        "small objects recall @2 cm",
        "geometry.small_objects.recall_2cm",
        None,
        "↑",
    ),
    row(
        "small objects recall @5 cm",
        "geometry.small_objects.recall_5cm",
        None,
        "↑",
    ),
    row("re-render PSNR (dB)", "rerender.psnr", None, "↑"),
    row("re-render SSIM", "rerender.ssim", None, "↑"),
    row("albedo PSNR (dB)", "material.albedo_psnr", None, "↑"),
    row("albedo PSNR, scaled (dB)", "material.albedo_psnr_scaled", None, "↑"),
    row(
        "albedo PSNR where ≥ 2 training views see the surface (dB)",
        "material.albedo_psnr_seen",
        None,
        "↑",
    ),
    row("roughness L1", "material.roughness_l1", None, "↓"),
    row(
        "roughness L1 where the surface has a specular lobe",
        "material.roughness_l1_lobe",
        None,
        "↓",
    ),
    row("emitters found", "emitters.count", None, ""),
    row("relight PSNR, path traced (dB)", "relight.psnr", None, "↑"),
    row("relight SSIM, path traced", "relight.ssim", None, "↑"),
    row(
        "relight PSNR, differential (dB)",
        "relight.psnr_differential",
        None,
        "↑",
    ),
    row("relight SSIM, differential", "relight.ssim_differential", None, "↑"),
    row("relight PSNR, ratio (dB)", "relight.psnr_ratio", None, "↑"),
    row("relight SSIM, ratio", "relight.ssim_ratio", None, "↑"),
    row(
        "unedited render vs test images PSNR (dB)",
        "relight.unedited.psnr",
        None,
        "↑",
    ),
];

fn cell(x: Option<f64>) -> String {
    x.map_or_else(
        || "<td class=\"num muted\">—</td>".to_string(),
        |x| format!("<td class=\"num\">{}</td>", format_sig(x)),
    )
}

/// The metrics section's HTML. `metrics`: the eval JSON and its file, or None (then the table
/// says how to make one).
pub fn metrics_section(metrics: Option<(&Path, &Value)>, run: &Path, data: &Path) -> String {
    let mut s = String::from("<h2 id=\"metrics\">Metrics</h2>");
    let Some((file, m)) = metrics else {
        let _ = write!(
            s,
            "<p><b>Not evaluated.</b> No metrics file was given. Evaluate the run (it takes minutes: \
             mesh metrics, and with stage 2 the Monte Carlo re-render and the relit sets), then pass \
             its output to the report:</p><pre>i2sdf eval --run {r} --data {d} --out {r}/metrics.json\n\
             i2sdf report --run {r} --data {d} --metrics {r}/metrics.json --out REPORT</pre>\
             <p>The paper's figures for reference (its dataset): novel-view PSNR 28.42 dB, SSIM 0.87, \
             LPIPS 0.15; mesh accuracy 0.035, precision 0.87, recall 0.79, F-score 0.83.</p>",
            r = esc(&run.display().to_string()),
            d = esc(&data.display().to_string())
        );
        return s;
    };
    let _ = write!(
        s,
        "<p>From <code>{}</code>. “paper (its dataset)”: the figure the paper reports for its own \
         synthetic scenes; the scenes differ, so it is a reference point, not a like-for-like \
         comparison. — : not computed (null) or not reported.</p>",
        esc(&file.display().to_string())
    );
    s.push_str(&notes(m));
    s.push_str(
        "<table><tr><th>metric</th><th></th><th>ours</th><th>paper (its dataset)</th><th>paper's source</th></tr>",
    );
    let train_evaluated = m.get("train_view").is_some_and(|t| !t.is_null());
    for r in ROWS {
        if r.path.starts_with("train_view.") && !train_evaluated {
            // Not asked for (`eval --split test`): no row of dashes.
            continue;
        }
        let ours = at(m, r.path);
        let _ = write!(
            s,
            "<tr><td>{}</td><td>{}</td>{}{}<td class=\"muted\">{}</td></tr>",
            esc(r.label),
            r.better,
            cell(ours),
            // As the paper prints it.
            r.paper.map_or_else(
                || "<td class=\"num muted\">—</td>".to_string(),
                |p| format!("<td class=\"num\">{}</td>", p.0)
            ),
            esc(r.paper.map_or("", |p| p.1))
        );
    }
    s.push_str("</table>");
    emitter_matches(&mut s, m);
    relight_sets(&mut s, m);
    s
}

/// The eval JSON's `notes` (why figures are null or not meaningful, e.g. stage 2 found no
/// emitters), shown above the table they explain; empty without notes.
fn notes(m: &Value) -> String {
    let notes: Vec<&str> = m
        .get("notes")
        .and_then(Value::as_array)
        .map(|a| a.iter().filter_map(Value::as_str).collect())
        .unwrap_or_default();
    if notes.is_empty() {
        return String::new();
    }
    let mut s = String::from("<div class=\"warn\"><b>Notes from <code>i2sdf eval</code>:</b><ul>");
    for n in notes {
        let _ = write!(s, "<li>{}</li>", esc(n));
    }
    s.push_str("</ul></div>");
    s
}

/// The recovered emitters matched with the ground truth's.
fn emitter_matches(s: &mut String, m: &Value) {
    let Some(matches) = m
        .pointer("/emitters/matches")
        .and_then(Value::as_array)
        .filter(|a| !a.is_empty())
    else {
        return;
    };
    s.push_str(
        "<h3>Emitters against the ground truth</h3><table><tr><th>GT emitter</th><th>recovered #</th>\
         <th>distance to its box</th><th>emission ratio (mean of RGB)</th></tr>",
    );
    for e in matches {
        let name = e.get("name").and_then(Value::as_str).unwrap_or("?");
        let k = e
            .get("predicted")
            .and_then(Value::as_u64)
            .map_or("—".into(), |k| k.to_string());
        let _ = write!(
            s,
            "<tr><td>{}</td><td class=\"num\">{}</td>{}{}</tr>",
            esc(name),
            k,
            cell(at(e, "distance")),
            cell(at(e, "emission_ratio_mean"))
        );
    }
    s.push_str("</table>");
}

/// Per relit set: path traced, differential, and doing nothing.
fn relight_sets(s: &mut String, m: &Value) {
    let Some(sets) = m
        .pointer("/relight/sets")
        .and_then(Value::as_object)
        .filter(|o| !o.is_empty())
    else {
        return;
    };
    s.push_str(
        "<h3>Relit sets (PSNR dB / SSIM)</h3><table><tr><th>set</th><th>frames</th><th>path traced</th>\
         <th>differential</th><th>ratio</th><th>unedited (doing nothing)</th></tr>",
    );
    for (name, v) in sets {
        let pair = |p: &str, q: &str| {
            format!(
                "<td class=\"num\">{} / {}</td>",
                at(v, p).map_or("—".into(), format_sig),
                at(v, q).map_or("—".into(), format_sig)
            )
        };
        let _ = write!(
            s,
            "<tr><td>{}</td><td class=\"num\">{}</td>{}{}{}{}</tr>",
            esc(name),
            at(v, "frames").map_or("—".into(), |f| format!("{f}")),
            pair("psnr", "ssim"),
            pair("psnr_differential", "ssim_differential"),
            pair("psnr_ratio", "ssim_ratio"),
            pair("psnr_unedited", "ssim_unedited")
        );
    }
    s.push_str("</table>");
}

/// Any memory or timing figures the metrics carry (`time_s`, and `memory` where a newer eval
/// writes one), as (label, value) pairs.
pub fn metrics_resources(m: &Value) -> Vec<(String, f64)> {
    let mut out = Vec::new();
    for section in ["time_s", "memory"] {
        if let Some(o) = m.get(section).and_then(Value::as_object) {
            for (k, v) in o {
                if let Some(x) = v.as_f64() {
                    out.push((format!("{section}.{k}"), x));
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_metrics_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.json");
        std::fs::write(&p, "{ not json").unwrap();
        let e = read_metrics(&p).unwrap_err();
        assert!(e.is_bad_input() && e.to_string().contains("m.json"), "{e}");
        std::fs::write(&p, "[1, 2]").unwrap();
        assert!(read_metrics(&p).unwrap_err().is_bad_input());
        std::fs::write(&p, "{\"novel_view\": {\"psnr\": 30.5}}").unwrap();
        let v = read_metrics(&p).unwrap();
        assert_eq!(at(&v, "novel_view.psnr"), Some(30.5));
        let html = metrics_section(Some((&p, &v)), Path::new("r"), Path::new("d"));
        assert!(html.contains("30.50") && html.contains(">28.42<"));
    }

    #[test]
    fn notes_show_above_the_table() {
        let v: Value =
            serde_json::from_str(r#"{"relight": {"psnr": null}, "notes": ["stage 2 found no emitters: <none>"]}"#)
                .unwrap();
        let html = metrics_section(Some((Path::new("m.json"), &v)), Path::new("r"), Path::new("d"));
        let note = html
            .find("stage 2 found no emitters: &lt;none&gt;")
            .expect("the note, escaped");
        assert!(html.contains("class=\"warn\"") && note < html.find("<table>").unwrap());
        // No notes, or an empty list: nothing extra.
        for json in [r#"{"relight": {}}"#, r#"{"relight": {}, "notes": []}"#] {
            let v: Value = serde_json::from_str(json).unwrap();
            let html = metrics_section(Some((Path::new("m.json"), &v)), Path::new("r"), Path::new("d"));
            assert!(!html.contains("warn"), "{html}");
        }
    }
}
