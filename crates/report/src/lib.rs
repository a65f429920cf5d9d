//! `i2sdf report`: one self-contained static HTML page about a run (the README's "Commands"):
//! the metrics against the paper's, training curves, GT | ours | error grids of a test view,
//! the emitters from above, the recovered surface, relit and edited views, timings and memory.
//! `index.html` with its images under `img/` and SVG charts beside it; relative links only, no
//! network, scripts or external styles, so it opens from disk in any browser.
//!
//! The renders reuse what `render`, `eval` and `edit` call (see [`views`]); nothing long runs
//! here (no evaluation: its figures come from `i2sdf eval`'s JSON).

pub mod charts;
pub mod html;
pub mod images;
pub mod metrics;
pub mod views;

use charts::{line_chart, top_view, Series, TopView, TrainingLog};
use html::{esc, format_sig, Assets};
use i2sdf_data::{DataError, Dataset, Split};
use i2sdf_edit::{EditSettings, RecoveredScene};
use i2sdf_eval::relight::RelitScoring;
use i2sdf_eval::RelightSettings;
use i2sdf_model::{extract_mesh, OpenedRun};
use i2sdf_render::{Geometry, MeshGeometry};
use serde_json::Value;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What the report is about: the opened run, its dataset and (optionally) its evaluation.
pub struct RunInputs<'a> {
    /// The run, opened once (its frozen scene, recovered scene and settings are the ones `eval`
    /// and `edit` use).
    pub run: &'a OpenedRun,
    pub data: &'a Path,
    pub dataset: &'a Dataset,
    /// The `eval` JSON and its file.
    pub metrics: Option<(&'a Path, &'a Value)>,
    /// The room exported by `i2sdf export` (a .glb or .gltf) and its link from the report's
    /// final folder ([`relative_to`]), shown in the surface section.
    pub scene: Option<(&'a Path, String)>,
}

/// How much rendering the report does.
#[derive(Clone, Copy, Debug)]
pub struct ReportOptions {
    /// Index of the test view shown.
    pub view: usize,
    /// Paths per pixel of the path-traced images (re-render, relit sets, the mirror edit).
    pub spp: u32,
    pub bounces: u32,
    /// Marching-cubes resolution of the surface (preview, top view, the edit renderer's mesh;
    /// the re-render casts the surface stage 2 baked).
    pub mesh_resolution: usize,
}

impl Default for ReportOptions {
    fn default() -> Self {
        ReportOptions {
            view: 0,
            spp: 32,
            bounces: EditSettings::default().bounces,
            mesh_resolution: i2sdf_edit::MESH_RESOLUTION,
        }
    }
}

/// What was written.
pub struct ReportSummary {
    pub index: PathBuf,
    pub files: usize,
    pub seconds: f64,
}

/// Writes the report into `out` (created; a previous report there is replaced). `progress` is
/// told each step as it starts.
pub fn write_report(
    input: &RunInputs,
    options: &ReportOptions,
    out: &Path,
    progress: &dyn Fn(&str),
) -> Result<ReportSummary, DataError> {
    let start = Instant::now();
    let (split, frame) = shown_frame(input.dataset, options.view)?;
    let mut page = Page {
        body: String::new(),
        assets: Assets::new(out)?,
        timings: Vec::new(),
        lap: Instant::now(),
        progress,
    };
    header(&mut page.body, input, &frame.name, split);
    page.body.push_str(&metrics::metrics_section(
        input.metrics,
        &input.run.dir.root,
        input.data,
    ));

    (page.progress)("training curves");
    let log = TrainingLog::read(&input.run.dir.log_path())?;
    let curves = curves_section(&mut page.assets, &log)?;
    page.body.push_str(&curves);
    page.mark("training curves");

    let mut cache = views::RenderCache::default();
    stage1_section(&mut page, input.run, frame, &mut cache)?;
    stage2_section(&mut page, input, options, frame)?;

    (page.progress)("surface (marching cubes)");
    let run = input.run;
    let recovered = match &run.fields {
        Some(_) => Some(RecoveredScene::of_run(run, input.dataset, options.mesh_resolution)?),
        None => None,
    };
    let own;
    let (mesh, geometry): (&i2sdf_data::TriangleMesh, &dyn Geometry) = match &recovered {
        Some(r) => (&r.surface.mesh, &r.surface.geometry),
        None => {
            own = stage1_surface(run, input.dataset, options.mesh_resolution)?;
            (&own.0, &own.1)
        }
    };
    page.mark("marching cubes");

    (page.progress)("emitters and mesh preview");
    let emitters = emitters_section(&mut page.assets, input, &mesh.positions)?;
    page.body.push_str(&emitters);
    surface_section(
        &mut page,
        options.mesh_resolution,
        &input.dataset.bounds,
        frame,
        mesh,
        geometry,
    )?;
    if let Some((scene, href)) = &input.scene {
        scene_link(&mut page.body, scene, href);
    }
    page.mark("emitters, mesh preview");

    relight_section(&mut page, input, options, recovered.as_ref(), frame, &mut cache)?;

    publish(page, input, start)
}

/// `path` relative to the folder `from` (both made absolute against the working directory), so
/// that a link from the report survives moving the folders together.
pub fn relative_to(path: &Path, from: &Path) -> PathBuf {
    let abs = |p: &Path| i2sdf_data::output::absolute(p);
    let (path, from) = (abs(path), abs(from));
    let common = path
        .components()
        .zip(from.components())
        .take_while(|(a, b)| a == b)
        .count();
    let mut rel = PathBuf::new();
    for _ in from.components().skip(common) {
        rel.push("..");
    }
    for c in path.components().skip(common) {
        rel.push(c);
    }
    rel
}

/// The link to the exported room, with its size and how to open it.
fn scene_link(body: &mut String, scene: &Path, href: &str) {
    let size = std::fs::metadata(scene)
        .map(|m| i2sdf_data::output::human_bytes(m.len()))
        .unwrap_or_default();
    let _ = write!(
        body,
        "<p>The room as a glTF 2.0 scene (<code>i2sdf export</code>: the surface, Kd as vertex colours, \
         GGX materials, the emitters as emissive materials, the cameras): <a href=\"{}\">{}</a> ({}). \
         Open it in Blender (File → Import → glTF 2.0) or any glTF viewer.</p>",
        html::esc(href),
        html::esc(
            &scene
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default()
        ),
        size
    );
}

/// The page being written: its HTML body and files, and the time each step took.
struct Page<'p> {
    body: String,
    assets: Assets,
    timings: Vec<(String, f64)>,
    /// When the step being timed started.
    lap: Instant,
    /// Told each step as it starts.
    progress: &'p dyn Fn(&str),
}

impl Page<'_> {
    /// Records the time since the previous mark (or the start) as step `name`'s.
    fn mark(&mut self, name: &str) {
        self.timings.push((name.to_string(), self.lap.elapsed().as_secs_f64()));
        self.lap = Instant::now();
    }
}

/// The last sections (timings and memory, the run's configuration) and the page itself, moved
/// into place.
fn publish(page: Page, input: &RunInputs, start: Instant) -> Result<ReportSummary, DataError> {
    let run = input.run;
    let total = start.elapsed().as_secs_f64();
    let mut body = page.body;
    body.push_str(&resources_section(input, &page.timings, total));
    if let Ok(cfg) = run.dir.read_config_toml() {
        let _ = write!(
            body,
            "<h2 id=\"config\">Configuration</h2><details><summary>RUN/config.toml</summary><pre>{}</pre></details>",
            esc(&cfg)
        );
    }
    let files = page.assets.files.len() + 1;
    let index = page.assets.publish(&html::page(
        &format!("i2sdf report — {}", run.dir.root.display()),
        &body,
    ))?;
    Ok(ReportSummary {
        index,
        files,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// The split and frame the report shows: view `view` of the test split, or of the train split
/// when the dataset has no test views.
fn shown_frame(dataset: &Dataset, view: usize) -> Result<(Split, &i2sdf_data::Frame), DataError> {
    let (split, frames): (Split, Vec<_>) = match dataset.count(Split::Test) {
        0 => (Split::Train, dataset.split(Split::Train).collect()),
        _ => (Split::Test, dataset.split(Split::Test).collect()),
    };
    let frame = *frames.get(view).ok_or_else(|| {
        DataError::invalid(format!(
            "--view {}: the {} split has {} views",
            view,
            split.name(),
            frames.len()
        ))
    })?;
    Ok((split, frame))
}

/// The test view's GT | ours | error grid of stage 1's volume renders.
fn stage1_section(
    page: &mut Page,
    run: &OpenedRun,
    frame: &i2sdf_data::Frame,
    cache: &mut views::RenderCache,
) -> Result<(), DataError> {
    (page.progress)("stage-1 maps of the test view");
    let _ = write!(
        page.body,
        "<h2 id=\"images\">Test view {}</h2><p>Ground truth | ours | error heat-map. Stage 1: the \
         volume renderer with the run's sampling settings.</p>",
        esc(&frame.name)
    );
    let grid = views::stage1_grid(&mut page.assets, &run.scene, &run.config.render, frame, cache)?;
    page.body.push_str(&grid);
    page.mark("stage-1 maps");
    Ok(())
}

/// The test view's material maps from one Monte Carlo re-render of stage 2's fields, or a note
/// that the run has no stage 2.
fn stage2_section(
    page: &mut Page,
    input: &RunInputs,
    options: &ReportOptions,
    frame: &i2sdf_data::Frame,
) -> Result<(), DataError> {
    let run = input.run;
    let (Some(fields), Some(frozen)) = (&run.fields, run.frozen(input.dataset)?) else {
        page.body.push_str("<h3>Stage 2: materials</h3><p class=\"muted\">No stage 2 in this run (no <code>RUN/stage2.safetensors</code>): train it with <code>i2sdf train --stage material</code>.</p>");
        return Ok(());
    };
    (page.progress)("stage-2 maps (re-render)");
    let cast = match &run.bake {
        Some(b) => format!("its rays cast in the surface stage 2 baked at {}", b.resolution),
        None => "its rays sphere traced, as stage 2 traced them".to_string(),
    };
    let _ = write!(
        page.body,
        "<h3>Stage 2: materials</h3><p>From one Monte Carlo re-render ({} paths per pixel), {cast}.</p>",
        options.spp
    );
    let grid = views::stage2_grid(
        &mut page.assets,
        &frozen,
        fields,
        frame,
        options.view as u32,
        options.spp,
    )?;
    page.body.push_str(&grid);
    page.mark("stage-2 maps");
    Ok(())
}

/// Without stage 2 (no recovered scene to take it from), the surface extracted from stage 1's
/// SDF, as one unlabelled mesh for ray casting.
fn stage1_surface(
    run: &OpenedRun,
    dataset: &Dataset,
    resolution: usize,
) -> Result<(i2sdf_data::TriangleMesh, MeshGeometry), DataError> {
    let mesh = extract_mesh(&run.scene, &dataset.bounds, resolution)?;
    let geometry = MeshGeometry::new(&mesh, vec![0; mesh.faces.len()]);
    Ok((mesh, geometry))
}

/// The recovered surface ray cast from the test camera and from a top corner, coloured by
/// normal.
fn surface_section(
    page: &mut Page,
    mesh_resolution: usize,
    bounds: &i2sdf_data::Bounds,
    frame: &i2sdf_data::Frame,
    mesh: &i2sdf_data::TriangleMesh,
    geometry: &dyn Geometry,
) -> Result<(), DataError> {
    let _ = write!(
        page.body,
        "<h2 id=\"mesh\">Recovered surface</h2><p>Marching cubes of the SDF at {} samples along the \
         bounds' longest side ({} triangles), ray cast and coloured by normal ((n + 1) / 2).</p>",
        mesh_resolution,
        mesh.faces.len()
    );
    let overview = views::overview_camera(bounds, 480, 360);
    let assets = &mut page.assets;
    let cells = [
        html::Cell::img(
            format!("test camera ({})", frame.name),
            assets.png("mesh_test", &views::normal_shaded(geometry, &frame.camera))?,
        ),
        html::Cell::img(
            "overview camera (a top corner)",
            assets.png("mesh_overview", &views::normal_shaded(geometry, &overview))?,
        ),
    ];
    page.body.push_str(&html::grid_row("mesh", &cells, ""));
    Ok(())
}

/// The relit sets and the mirror edit, path traced by the edit renderer in the recovered scene
/// (`None` without stage 2: the section says they need it).
fn relight_section(
    page: &mut Page,
    input: &RunInputs,
    options: &ReportOptions,
    recovered: Option<&RecoveredScene>,
    frame: &i2sdf_data::Frame,
    cache: &mut views::RenderCache,
) -> Result<(), DataError> {
    let (run, dataset) = (input.run, input.dataset);
    page.body.push_str("<h2 id=\"relight\">Relighting and editing</h2>");
    if let Some(note) = no_emitters_note(run.fields.as_ref().map(|f| f.emitters.len())) {
        page.body.push_str(&note);
    }
    let Some(r) = recovered else {
        page.body
            .push_str("<p class=\"muted\">Relighting and editing need stage 2.</p>");
        return Ok(());
    };
    let settings = EditSettings {
        spp: options.spp,
        bounces: options.bounces,
        ..Default::default()
    };
    let ctx = views::EditContext {
        scoring: RelitScoring {
            recovered: r,
            volume: Some(&run.config.render),
            settings: &settings,
            frames_per_set: Some(1),
        },
        unedited: r.edited(&Default::default(), &Default::default()),
    };
    let _ = write!(
        page.body,
        "<p>Path traced by the edit renderer ({} paths per pixel, {} bounces) in the \
         recovered scene; differential: stage 1's radiance field + the path-traced change \
         (Debevec 1998). Captions: PSNR against the ground truth.</p>",
        options.spp, options.bounces
    );
    let ours = RelightSettings {
        spp: options.spp,
        bounces: options.bounces,
        seed: settings.seed,
        mesh_resolution: options.mesh_resolution,
        denoised: settings.denoise.is_some(),
    };
    if let Some(note) = input.metrics.and_then(|(_, m)| settings_note(m, &ours)) {
        page.body.push_str(&note);
    }
    if dataset.relight.is_empty() {
        page.body
            .push_str("<p class=\"muted\">The dataset has no relit sets.</p>");
    } else if run.fields.as_ref().is_some_and(|f| f.emitters.is_empty()) {
        // As eval: without emitters every relit image would be black (see the note above).
        page.body
            .push_str("<p class=\"muted\">The relit sets are not rendered: no emitters.</p>");
    } else {
        (page.progress)("relit sets");
        let grid = views::relight_grid(&mut page.assets, &ctx, cache, dataset)?;
        page.body.push_str(&grid);
        page.mark("relit sets");
    }
    (page.progress)("mirror edit");
    let grid = views::mirror_grid(&mut page.assets, &ctx, cache, &dataset.bounds, frame)?;
    page.body.push_str(&grid);
    page.mark("mirror edit");
    Ok(())
}

fn header(body: &mut String, input: &RunInputs, view: &str, split: Split) {
    let stage = |s: Option<&i2sdf_model::StageProgress>| match s {
        Some(p) if p.iterations > 0 => format!(
            "{} iterations{}, {} s",
            p.iterations,
            if p.done { "" } else { " (not finished)" },
            format_sig(p.seconds)
        ),
        _ => "not trained".into(),
    };
    let _ = write!(
        body,
        "<h1>i2sdf report</h1><table><tr><th>run</th><td><code>{}</code></td></tr>\
         <tr><th>dataset</th><td><code>{}</code> ({} train, {} test views, {}×{})</td></tr>\
         <tr><th>stage 1</th><td>{}</td></tr><tr><th>stage 2</th><td>{}</td></tr>\
         <tr><th>view shown</th><td>{} ({} split)</td></tr></table>\
         <p><a href=\"#metrics\">metrics</a> · <a href=\"#curves\">training curves</a> · \
         <a href=\"#images\">images</a> · <a href=\"#emitters\">emitters</a> · \
         <a href=\"#mesh\">surface</a> · <a href=\"#relight\">relighting and editing</a> · \
         <a href=\"#resources\">timings and memory</a></p>",
        esc(&input.run.dir.root.display().to_string()),
        esc(&input.data.display().to_string()),
        input.dataset.count(Split::Train),
        input.dataset.count(Split::Test),
        input.dataset.frames.first().map_or(0, |f| f.camera.width),
        input.dataset.frames.first().map_or(0, |f| f.camera.height),
        stage(Some(&input.run.info.stage1)),
        stage(input.run.info.stage2.as_ref()),
        esc(view),
        split.name()
    );
}

/// Stage 1's loss terms (log scale), PSNR and β; stage 2's losses and emissions.
fn curves_section(assets: &mut Assets, log: &TrainingLog) -> Result<String, DataError> {
    let mut s = String::from("<h2 id=\"curves\">Training curves</h2>");
    if log.unreadable > 0 {
        let _ = write!(
            s,
            "<p class=\"muted\">{} unreadable line(s) of RUN/log.jsonl skipped.</p>",
            log.unreadable
        );
    }
    let charts: [(&str, &str, &str, &[&str], bool); 6] = [
        (
            "stage1",
            "stage 1 losses",
            "value (each term as logged)",
            &[
                "loss", "rgb", "depth", "normal", "eikonal", "emitter", "bubble", "smooth",
            ],
            true,
        ),
        ("stage1", "stage 1 training PSNR", "dB", &["psnr"], false),
        ("stage1", "stage 1 β (VolSDF density)", "β", &["beta"], true),
        (
            "stage1",
            "stage 1 time per iteration",
            "ms",
            &["ms_sampling", "ms_forward", "ms_losses", "ms_backward", "ms_adam"],
            false,
        ),
        (
            "stage2",
            "stage 2 losses",
            "value",
            &["loss", "render", "emitter", "smooth", "energy"],
            true,
        ),
        ("stage2", "", "", &[], true),
    ];
    let mut any = false;
    s.push_str("<div class=\"charts\">");
    for (n, (stage, title, unit, keys, log_y)) in charts.iter().enumerate() {
        let Some(st) = log.stages.get(*stage) else { continue };
        let svg = if keys.is_empty() {
            // Stage 2's emissions, one curve per emitter (luminance of L[k]).
            let series: Vec<Series> = st
                .emission
                .iter()
                .enumerate()
                .map(|(k, p)| Series {
                    name: format!("emitter {k}"),
                    points: p,
                })
                .collect();
            line_chart("stage 2 emissions L[k] (luminance)", "image units", &series, false)?
        } else {
            let series: Vec<Series> = keys
                .iter()
                .filter_map(|k| {
                    st.series.get(*k).map(|p| Series {
                        name: k.to_string(),
                        points: p,
                    })
                })
                .collect();
            line_chart(title, unit, &series, *log_y)?
        };
        if let Some(svg) = svg {
            let src = assets.text(&format!("chart_{n}.svg"), &svg)?;
            let _ = write!(s, "<img src=\"{}\" alt=\"{}\">", esc(&src), esc(title));
            any = true;
        }
    }
    s.push_str("</div>");
    for stage in ["stage1", "stage2"] {
        if !log.stages.contains_key(stage) {
            let _ = write!(s, "<p class=\"muted\">No {stage} lines in RUN/log.jsonl.</p>");
        }
    }
    if !any {
        s.push_str("<p class=\"muted\">Nothing to plot.</p>");
    }
    Ok(s)
}

/// The emitters on a top view and in a table.
fn emitters_section(assets: &mut Assets, input: &RunInputs, vertices: &[[f32; 3]]) -> Result<String, DataError> {
    let mut s = String::from("<h2 id=\"emitters\">Emitters</h2>");
    let table = input.run.fields.as_ref().map(|f| &f.emitters);
    let recovered: Vec<([f64; 3], String)> = table
        .map(|t| {
            t.emitters
                .iter()
                .enumerate()
                .map(|(k, e)| (e.centre, format!("#{k}")))
                .collect()
        })
        .unwrap_or_default();
    let gt: Vec<([f64; 3], [f64; 3], String)> = input
        .dataset
        .emitters
        .iter()
        .map(|e| (e.bounds_min, e.bounds_max, e.name.clone()))
        .collect();
    let svg = top_view(&TopView {
        vertices,
        recovered: &recovered,
        gt_boxes: &gt,
    })?;
    let src = assets.text("emitters_top.svg", &svg)?;
    let _ = write!(
        s,
        "<p>Looking down onto the x–z plane: the recovered surface's vertices (grey), {} recovered \
         emitter centre(s) (RUN/emitters.json, blue), {} ground-truth emitter box(es) (red).</p>\
         <img class=\"wide\" src=\"{}\" alt=\"emitters, top view\">",
        recovered.len(),
        if gt.is_empty() {
            "no".to_string()
        } else {
            gt.len().to_string()
        },
        esc(&src)
    );
    match table {
        Some(t) if !t.is_empty() => {
            s.push_str("<table><tr><th>#</th><th>centre (world)</th><th>extent</th><th>points</th><th>emission L[k] (RGB, image units)</th></tr>");
            for (k, e) in t.emitters.iter().enumerate() {
                let v = |a: [f64; 3]| a.map(format_sig).join(", ");
                let l = t.emission(k);
                let _ = write!(
                    s,
                    "<tr><td>{k}</td><td>{}</td><td>{}</td><td class=\"num\">{}</td><td>{}</td></tr>",
                    v(e.centre),
                    v(e.extent),
                    e.points,
                    v([l.x as f64, l.y as f64, l.z as f64])
                );
            }
            s.push_str("</table>");
        }
        Some(_) => s.push_str("<p class=\"muted\">Stage 2 found no emitters.</p>"),
        None => s.push_str("<p class=\"muted\">No stage 2: emitters are clustered there.</p>"),
    }
    Ok(s)
}

/// A note when `metrics` (eval's) scored the relit sets with other settings than `ours`: the
/// captions then differ from eval's figures by the Monte Carlo noise (and the surface) of
/// each. With the same settings they are eval's own figures.
fn settings_note(metrics: &Value, ours: &RelightSettings) -> Option<String> {
    let theirs: RelightSettings = serde_json::from_value(metrics.get("relight")?.get("settings")?.clone()).ok()?;
    let denoised = |s: &RelightSettings| if s.denoised { ", denoised" } else { "" };
    (theirs != *ours).then(|| {
        format!(
            "<p class=\"muted\">Eval scored the relit sets at {} paths per pixel, {} bounces, seed {}, \
             surface at {}³{}; this report renders at {}, {}, {}, {}³{}, so its captions differ from \
             the metrics' per-frame figures by the noise of each.</p>",
            theirs.spp,
            theirs.bounces,
            theirs.seed,
            theirs.mesh_resolution,
            denoised(&theirs),
            ours.spp,
            ours.bounces,
            ours.seed,
            ours.mesh_resolution,
            denoised(ours),
        )
    })
}

/// The warning at the top of the relighting section when stage 2 found no emitters
/// (`stage2_emitters`: the run's emitter count, `None` without stage 2): every path-traced panel
/// below is then black and every differential one the radiance field's image unchanged, which
/// reads as a broken renderer unless the page says why.
fn no_emitters_note(stage2_emitters: Option<usize>) -> Option<String> {
    (stage2_emitters == Some(0)).then(|| {
        "<div class=\"warn\"><b>Stage 2 found no emitters,</b> so the relit and edited views below \
         show nothing about relighting. No training pixel's emitter probability (F_e) was above \
         <code>stage2.emitter_threshold</code> (or the dataset has no emitter masks), so there was \
         nothing to cluster into emitters. The edit renderer lights the scene with the recovered \
         emitters alone: the path-traced images are black, and the differential composites are \
         stage 1's radiance field unchanged (the path-traced change is zero). The re-render above \
         has only the radiance field's indirect light. Train stage 1 longer (the emitter field \
         needs a converged surface) or lower <code>stage2.emitter_threshold</code>.</div>"
            .to_string()
    })
}

fn resources_section(input: &RunInputs, timings: &[(String, f64)], total: f64) -> String {
    let mut s = String::from("<h2 id=\"resources\">Timings and memory</h2><table><tr><th>what</th><th>value</th></tr>");
    let mut row = |k: &str, v: String| {
        let _ = write!(s, "<tr><td>{}</td><td class=\"num\">{}</td></tr>", esc(k), esc(&v));
    };
    row(
        "training, stage 1 (run.json)",
        format!("{} s", format_sig(input.run.info.stage1.seconds)),
    );
    if let Some(p) = &input.run.info.stage2 {
        row("training, stage 2 (run.json)", format!("{} s", format_sig(p.seconds)));
    }
    if let Some((_, m)) = input.metrics {
        for (k, v) in metrics::metrics_resources(m) {
            row(&format!("eval JSON: {k}"), format_sig(v));
        }
    }
    for (k, v) in timings {
        row(&format!("report: {k}"), format!("{} s", format_sig(*v)));
    }
    row("report: total", format!("{} s", format_sig(total)));
    if let Some(b) = i2sdf_model::memory::peak_rss() {
        row(
            "report: peak resident memory (VmHWM)",
            format!("{} MiB", format_sig(b as f64 / (1u64 << 20) as f64)),
        );
    }
    s.push_str("</table>");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_relight_section_says_why_it_is_black_without_emitters() {
        let note = no_emitters_note(Some(0)).expect("a note for stage 2 without emitters");
        assert!(note.contains("class=\"warn\"") && note.contains("black"), "{note}");
        assert!(no_emitters_note(Some(2)).is_none());
        assert!(
            no_emitters_note(None).is_none(),
            "no stage 2: the section says so already"
        );
    }

    #[test]
    fn the_scene_link_is_relative_to_the_report_folder() {
        let rel = |a: &str, b: &str| relative_to(Path::new(a), Path::new(b)).to_string_lossy().into_owned();
        assert_eq!(rel("/x/demo/room.glb", "/x/demo/report"), "../room.glb");
        assert_eq!(rel("/x/demo/report/room.glb", "/x/demo/report"), "room.glb");
        assert_eq!(rel("/y/room.glb", "/x/demo/report"), "../../../y/room.glb");
        let mut body = String::new();
        scene_link(&mut body, Path::new("/nonexistent/room.glb"), "../room.glb");
        assert!(
            body.contains("href=\"../room.glb\"") && body.contains(">room.glb</a>"),
            "{body}"
        );
    }
}
