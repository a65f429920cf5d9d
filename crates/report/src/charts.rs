//! Training curves from `RUN/log.jsonl` and the emitters' top view, drawn as SVG by `plotters`
//! (its SVG backend only: text stays SVG `<text>`, so no fonts are needed to draw).

use i2sdf_data::DataError;
use plotters::coord::Shift;
use plotters::prelude::*;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::Path;

/// One stage's logged series: key → (iteration, value), in file order.
#[derive(Default, Debug)]
pub struct StageLog {
    pub series: BTreeMap<String, Vec<(f64, f64)>>,
    /// Per-emitter emission luminance (stage 2's `emission` arrays).
    pub emission: Vec<Vec<(f64, f64)>>,
    pub lines: usize,
}

/// The run's log split by stage (`stage1`, `stage2`), and how many lines could not be read (a
/// run killed mid-write leaves a partial last line; the report shows what is there).
#[derive(Default, Debug)]
pub struct TrainingLog {
    pub stages: BTreeMap<String, StageLog>,
    pub unreadable: usize,
}

impl TrainingLog {
    /// Reads `path`; a missing log is an empty one (a run trained without logging).
    pub fn read(path: &Path) -> Result<Self, DataError> {
        let text = match std::fs::read_to_string(path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Self::default()),
            Err(e) => return Err(DataError::file(path, format!("cannot read: {e}"))),
        };
        Ok(Self::parse(&text))
    }

    pub fn parse(text: &str) -> Self {
        let mut log = TrainingLog::default();
        for line in text.lines().filter(|l| !l.trim().is_empty()) {
            let Ok(Value::Object(rec)) = serde_json::from_str::<Value>(line) else {
                log.unreadable += 1;
                continue;
            };
            let stage = rec.get("stage").and_then(Value::as_str).unwrap_or("stage1").to_string();
            let Some(it) = rec.get("iteration").and_then(Value::as_f64) else {
                log.unreadable += 1;
                continue;
            };
            let s = log.stages.entry(stage).or_default();
            s.lines += 1;
            for (k, v) in &rec {
                if let Some(x) = v.as_f64().filter(|x| x.is_finite()) {
                    if k != "iteration" {
                        s.series.entry(k.clone()).or_default().push((it, x));
                    }
                }
            }
            if let Some(Value::Array(em)) = rec.get("emission") {
                for (k, e) in em.iter().enumerate() {
                    let c: Vec<f64> = e.as_array().into_iter().flatten().filter_map(Value::as_f64).collect();
                    if c.len() == 3 {
                        if s.emission.len() <= k {
                            s.emission.resize_with(k + 1, Vec::new);
                        }
                        // Rec. 709 luminance: one curve per emitter.
                        s.emission[k].push((it, 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]));
                    }
                }
            }
        }
        log
    }
}

/// One named curve.
pub struct Series<'a> {
    pub name: String,
    pub points: &'a [(f64, f64)],
}

fn plot_err<E: std::fmt::Debug>(e: E) -> DataError {
    DataError::failed(format!("drawing a chart: {e:?}"))
}

/// Chart size in SVG pixels.
const CHART: (u32, u32) = (560, 320);

/// A line chart of `series` against iteration, the y axis logarithmic when `log_y` (non-positive
/// values are left out there). None when no series has a point to draw.
pub fn line_chart(title: &str, y_label: &str, series: &[Series], log_y: bool) -> Result<Option<String>, DataError> {
    let keep = |y: f64| y.is_finite() && (!log_y || y > 0.0);
    let pts: Vec<(f64, f64)> = series
        .iter()
        .flat_map(|s| s.points.iter().copied())
        .filter(|p| keep(p.1))
        .collect();
    if pts.is_empty() {
        return Ok(None);
    }
    let x1 = pts.iter().map(|p| p.0).fold(f64::MIN, f64::max).max(1.0);
    let x0 = pts.iter().map(|p| p.0).fold(f64::MAX, f64::min).min(x1 - 1.0);
    let (mut y0, mut y1) = pts
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
    if log_y {
        // Whole decades read best on a log axis.
        y0 = 10f64.powf(y0.log10().floor());
        y1 = 10f64.powf(y1.log10().ceil());
        if y1 <= y0 {
            y1 = y0 * 10.0;
        }
    } else {
        let pad = ((y1 - y0) * 0.05).max(1e-6 * y1.abs().max(1.0));
        y0 -= pad;
        y1 += pad;
    }
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, CHART).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        if log_y {
            let mut chart = builder(&root, title)
                .build_cartesian_2d(x0..x1, (y0..y1).log_scale())
                .map_err(plot_err)?;
            chart
                .configure_mesh()
                .x_desc("iteration")
                .y_desc(y_label)
                .y_label_formatter(&|y| format!("{y:.0e}"))
                .draw()
                .map_err(plot_err)?;
            draw_lines(&mut chart, series, &keep)?;
        } else {
            let mut chart = builder(&root, title)
                .build_cartesian_2d(x0..x1, y0..y1)
                .map_err(plot_err)?;
            chart
                .configure_mesh()
                .x_desc("iteration")
                .y_desc(y_label)
                .draw()
                .map_err(plot_err)?;
            draw_lines(&mut chart, series, &keep)?;
        }
        root.present().map_err(plot_err)?;
    }
    Ok(Some(buf))
}

fn builder<'a, 'b>(root: &'a DrawingArea<SVGBackend<'b>, Shift>, title: &str) -> ChartBuilder<'a, 'b, SVGBackend<'b>> {
    let mut b = ChartBuilder::on(root);
    b.caption(title, ("sans-serif", 17))
        .margin(10)
        .x_label_area_size(36)
        .y_label_area_size(58);
    b
}

/// Each series as a line in its palette colour, labelled, then the legend (log and linear
/// charts differ only in their coordinates).
fn draw_lines<'a, 'b: 'a, X, Y>(
    chart: &mut ChartContext<'a, SVGBackend<'b>, Cartesian2d<X, Y>>,
    series: &[Series],
    keep: &dyn Fn(f64) -> bool,
) -> Result<(), DataError>
where
    X: Ranged<ValueType = f64>,
    Y: Ranged<ValueType = f64>,
{
    for (i, s) in series.iter().enumerate() {
        let colour = Palette99::pick(i).to_rgba();
        // A gap where a value is not drawn (a loss term that is off in one step, 0 on a log
        // axis) breaks the line rather than bridging the step with a straight segment.
        let mut runs: Vec<Vec<(f64, f64)>> = vec![Vec::new()];
        for &p in s.points {
            if keep(p.1) {
                runs.last_mut().expect("never empty").push(p);
            } else if !runs.last().expect("never empty").is_empty() {
                runs.push(Vec::new());
            }
        }
        for (k, run) in runs.into_iter().filter(|r| !r.is_empty()).enumerate() {
            let drawn = chart
                .draw_series(LineSeries::new(run, colour.stroke_width(2)))
                .map_err(plot_err)?;
            if k == 0 {
                drawn
                    .label(s.name.clone())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2)));
            }
        }
    }
    legend(chart)
}

fn legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
) -> Result<(), DataError> {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.4))
        .label_font(("sans-serif", 12))
        .draw()
        .map_err(plot_err)
}

/// What the top view shows: the surface's vertices (x, z), the recovered emitters' centres and
/// the ground truth's emitter boxes (x–z extents), world units.
pub struct TopView<'a> {
    pub vertices: &'a [[f32; 3]],
    pub recovered: &'a [([f64; 3], String)],
    pub gt_boxes: &'a [([f64; 3], [f64; 3], String)],
}

/// The top view (looking down −y onto the x–z plane) as SVG, equal scales on both axes.
pub fn top_view(v: &TopView) -> Result<String, DataError> {
    let mut xs: Vec<f64> = Vec::new();
    let mut zs: Vec<f64> = Vec::new();
    // Every k-th vertex: a light scatter, a few thousand dots (the SVG stays small).
    let step = (v.vertices.len() / 6000).max(1);
    let dots: Vec<(f64, f64)> = v
        .vertices
        .iter()
        .step_by(step)
        .map(|p| (p[0] as f64, p[2] as f64))
        .collect();
    xs.extend(dots.iter().map(|d| d.0));
    zs.extend(dots.iter().map(|d| d.1));
    for (c, _) in v.recovered {
        xs.push(c[0]);
        zs.push(c[2]);
    }
    for (lo, hi, _) in v.gt_boxes {
        xs.extend([lo[0], hi[0]]);
        zs.extend([lo[2], hi[2]]);
    }
    if xs.is_empty() {
        xs.extend([-1.0, 1.0]);
        zs.extend([-1.0, 1.0]);
    }
    let (x0, x1) = (
        xs.iter().copied().fold(f64::MAX, f64::min),
        xs.iter().copied().fold(f64::MIN, f64::max),
    );
    let (z0, z1) = (
        zs.iter().copied().fold(f64::MAX, f64::min),
        zs.iter().copied().fold(f64::MIN, f64::max),
    );
    let pad = 0.05 * (x1 - x0).max(z1 - z0).max(1e-3);
    let (x0, x1, z0, z1) = (x0 - pad, x1 + pad, z0 - pad, z1 + pad);
    // Equal scales: the plot area's aspect follows the extents (label areas added around it).
    let width = 560u32;
    let plot_w = (width - 80) as f64;
    let plot_h = (plot_w * (z1 - z0) / (x1 - x0)).clamp(120.0, 900.0);
    let size = (width, plot_h as u32 + 80);
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, size).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption("emitters, top view (x–z, world units)", ("sans-serif", 17))
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(40)
            // z grows downwards on the page: seen from above with x to the right.
            .build_cartesian_2d(x0..x1, z1..z0)
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_desc("x")
            .y_desc("z")
            .disable_mesh()
            .draw()
            .map_err(plot_err)?;
        let grey = RGBColor(150, 150, 150).mix(0.35);
        chart
            .draw_series(dots.iter().map(|&p| Circle::new(p, 1, grey.filled())))
            .map_err(plot_err)?
            .label("surface (mesh vertices)")
            .legend(move |(x, y)| Circle::new((x + 8, y), 3, grey.filled()));
        let red = RGBColor(220, 40, 40);
        chart
            .draw_series(
                v.gt_boxes
                    .iter()
                    .map(|(lo, hi, _)| Rectangle::new([(lo[0], lo[2]), (hi[0], hi[2])], red.stroke_width(2))),
            )
            .map_err(plot_err)?
            .label("ground-truth emitter box")
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 16, y + 5)], red.stroke_width(2)));
        for (lo, hi, name) in v.gt_boxes {
            chart
                .draw_series(std::iter::once(Text::new(
                    name.clone(),
                    (lo[0], hi[2]),
                    ("sans-serif", 11).into_font().color(&red),
                )))
                .map_err(plot_err)?;
        }
        let blue = RGBColor(20, 80, 220);
        chart
            .draw_series(
                v.recovered
                    .iter()
                    .map(|(c, _)| Cross::new((c[0], c[2]), 7, blue.stroke_width(3))),
            )
            .map_err(plot_err)?
            .label("recovered emitter centre")
            .legend(move |(x, y)| Cross::new((x + 8, y), 5, blue.stroke_width(2)));
        for (c, name) in v.recovered {
            chart
                .draw_series(std::iter::once(Text::new(
                    name.clone(),
                    (c[0], c[2]),
                    ("sans-serif", 12).into_font().color(&blue),
                )))
                .map_err(plot_err)?;
        }
        legend(&mut chart)?;
        root.present().map_err(plot_err)?;
    }
    Ok(buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_log_is_split_by_stage_and_bad_lines_are_counted() {
        let log = TrainingLog::parse(
            "{\"stage\":\"stage1\",\"iteration\":0,\"loss\":0.5,\"psnr\":15,\"phase\":\"warm_up\"}\n\
             {\"stage\":\"stage1\",\"iteration\":10,\"loss\":0.25}\n\
             {\"stage\":\"stage2\",\"iteration\":0,\"loss\":0.1,\"emission\":[[1,1,1],[2,2,2]]}\n{\"trunc",
        );
        assert_eq!(log.unreadable, 1);
        let s1 = &log.stages["stage1"];
        assert_eq!(s1.series["loss"], [(0.0, 0.5), (10.0, 0.25)]);
        assert!(!s1.series.contains_key("phase"));
        let s2 = &log.stages["stage2"];
        assert_eq!(s2.emission.len(), 2);
        assert!((s2.emission[1][0].1 - 2.0).abs() < 1e-9);
    }

    #[test]
    fn a_term_that_is_off_for_a_while_breaks_its_line() {
        let lines = |pts: &[(f64, f64)]| {
            let svg = line_chart(
                "loss",
                "value",
                &[Series {
                    name: "eikonal".into(),
                    points: pts,
                }],
                true,
            )
            .unwrap()
            .unwrap();
            svg.matches("<polyline").count()
        };
        let whole = lines(&[(0.0, 1.0), (10.0, 0.5), (20.0, 0.3), (30.0, 0.2), (40.0, 0.1)]);
        let gapped = lines(&[(0.0, 1.0), (10.0, 0.5), (20.0, 0.0), (30.0, 0.2), (40.0, 0.1)]);
        assert_eq!(gapped, whole + 1, "one more line on the far side of the gap");
    }

    #[test]
    fn charts_are_svg_and_empty_series_draw_nothing() {
        let pts = [(0.0, 1.0), (10.0, 0.1), (20.0, 0.0)];
        let svg = line_chart(
            "loss",
            "value",
            &[Series {
                name: "loss".into(),
                points: &pts,
            }],
            true,
        )
        .unwrap()
        .unwrap();
        assert!(svg.contains("<svg") && svg.contains("loss"));
        let none = line_chart(
            "x",
            "y",
            &[Series {
                name: "z".into(),
                points: &[(0.0, 0.0)],
            }],
            true,
        )
        .unwrap();
        assert!(none.is_none());
        let top = top_view(&TopView {
            vertices: &[[0.0, 0.0, 0.0], [1.0, 2.0, 1.0]],
            recovered: &[([0.5, 1.0, 0.5], "0".into())],
            gt_boxes: &[([0.4, 0.9, 0.4], [0.6, 1.1, 0.6], "lamp".into())],
        })
        .unwrap();
        assert!(top.contains("<svg") && top.contains("lamp"));
    }
}
