//! A dataset's summary, as `i2sdf check` prints it (and as JSON with `--json`).

use crate::colmap::ScaleFix;
use crate::dataset::{Bounds, BoundsSource, Dataset, Format, Frame, Normalization, Split};
use crate::sensor_depth::{depth_window, DepthDropped};
use std::fmt;

/// How many frames carry each optional map: name and count in the order of [`Frame::maps`]
/// (`rgb`, which every frame has, left out); serialized as a map from name to count.
#[derive(Clone, Debug)]
pub struct MapCounts(pub Vec<(&'static str, usize)>);

impl serde::Serialize for MapCounts {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_map(self.0.iter().map(|(k, c)| (k, c)))
    }
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct Summary {
    pub root: String,
    pub format: Format,
    pub train_views: usize,
    pub test_views: usize,
    /// Distinct image sizes (width, height).
    pub resolutions: Vec<(usize, usize)>,
    /// How many frames carry each map.
    pub maps: MapCounts,
    /// Range of valid z-depths in world units, and the fraction of pixels with depth.
    pub depth_range: Option<(f64, f64)>,
    pub depth_coverage: Option<f64>,
    /// The depth samples read and why some were dropped; the validity window in world units
    /// (when there is depth).
    pub depth_dropped: DepthDropped,
    pub depth_window: Option<(f64, f64)>,
    pub bounds: Bounds,
    pub bounds_source: BoundsSource,
    pub normalization: Normalization,
    /// The dataset's transfer by name (`"srgb"` or `"linear"`), as `check --json` has always
    /// written it.
    pub ldr_transfer: String,
    /// How a COLMAP model's scale was tied to its depth maps (None otherwise).
    pub colmap_scale: Option<ScaleFix>,
    pub mesh_path: Option<String>,
    pub relight_sets: Vec<(String, usize)>,
}

impl Summary {
    pub fn of(ds: &Dataset) -> Summary {
        let count = |k: usize| ds.frames.iter().filter(|f| f.maps()[k].is_some()).count();
        let maps = MapCounts(
            Frame::MAP_NAMES
                .iter()
                .enumerate()
                .skip(1)
                .map(|(k, &name)| (name, count(k)))
                .collect(),
        );
        let mut resolutions: Vec<(usize, usize)> =
            ds.frames.iter().map(|f| (f.camera.width, f.camera.height)).collect();
        resolutions.sort();
        resolutions.dedup();
        let (mut lo, mut hi, mut valid, mut total) = (f64::INFINITY, 0.0f64, 0usize, 0usize);
        for d in ds.frames.iter().filter_map(|f| f.depth.as_ref()) {
            total += d.data.len();
            for &v in &d.data {
                if v > 0.0 {
                    lo = lo.min(v as f64);
                    hi = hi.max(v as f64);
                    valid += 1;
                }
            }
        }
        Summary {
            root: ds.root.display().to_string(),
            format: ds.format,
            train_views: ds.count(Split::Train),
            test_views: ds.count(Split::Test),
            resolutions,
            maps,
            depth_range: (valid > 0).then_some((lo, hi)),
            depth_coverage: (total > 0).then(|| valid as f64 / total as f64),
            depth_dropped: ds.depth_dropped,
            depth_window: (ds.depth_dropped.samples_total > 0).then(|| depth_window(&ds.normalization)),
            bounds: ds.bounds,
            bounds_source: ds.bounds_source,
            normalization: ds.normalization,
            ldr_transfer: ds.radiometry.transfer.name().to_string(),
            colmap_scale: ds.colmap_scale,
            mesh_path: ds.mesh_path.as_ref().map(|p| p.display().to_string()),
            relight_sets: ds
                .relight
                .iter()
                .map(|r| (r.spec.display().to_string(), r.frames.len()))
                .collect(),
        }
    }
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let format = match self.format {
            Format::Native => "native (transforms.json)",
            Format::Paper => "paper release (cameras_normalize.npz)",
            Format::Colmap => "COLMAP sparse model (sparse/)",
        };
        let n = self.train_views + self.test_views;
        writeln!(f, "dataset      {}", self.root)?;
        writeln!(f, "format       {format}")?;
        writeln!(f, "views        {} train, {} test", self.train_views, self.test_views)?;
        let res: Vec<String> = self.resolutions.iter().map(|(w, h)| format!("{w}×{h}")).collect();
        writeln!(f, "resolution   {}", res.join(", "))?;
        let list: Vec<String> = self
            .maps
            .0
            .iter()
            .map(|(k, c)| {
                if *c == 0 {
                    format!("{k} –")
                } else {
                    format!("{k} {c}/{n}")
                }
            })
            .collect();
        writeln!(f, "maps         {}", list.join(", "))?;
        match (self.depth_range, self.depth_coverage) {
            (Some((lo, hi)), Some(cov)) => writeln!(
                f,
                "depth        {lo:.4} … {hi:.4} (world units, z-depth), {:.1} % of pixels valid",
                cov * 100.0
            )?,
            _ => writeln!(f, "depth        none")?,
        }
        if let Some((lo, hi)) = self.depth_window {
            let d = &self.depth_dropped;
            let reasons: Vec<String> = [
                (d.non_finite, "non-finite"),
                (d.non_positive, "≤ 0"),
                (d.low_confidence, "below depth_confidence_min"),
                (d.superseded, "superseded (depth finer than its image)"),
                (d.out_of_window, "outside the validity window"),
            ]
            .iter()
            .filter(|(n, _)| *n > 0)
            .map(|(n, why)| format!("{n} {why}"))
            .collect();
            let dropped = if reasons.is_empty() {
                "none dropped".to_string()
            } else {
                format!("dropped {}", reasons.join(", "))
            };
            writeln!(
                f,
                "depth kept   {} of {} samples, {dropped}; validity window {lo:.4} … {hi:.4} (world units)",
                d.kept, d.samples_total
            )?;
        }
        let b = &self.bounds;
        let src = match self.bounds_source {
            BoundsSource::Depth => "from depth and cameras",
            BoundsSource::Cameras => "from cameras only (no depth): a guess",
            BoundsSource::SfmPoints => "from the SfM points and cameras (no depth)",
        };
        writeln!(
            f,
            "bounds       [{:.3}, {:.3}, {:.3}] … [{:.3}, {:.3}, {:.3}] (world units, {src})",
            b.min[0], b.min[1], b.min[2], b.max[0], b.max[1], b.max[2]
        )?;
        let c = &self.normalization.center;
        writeln!(
            f,
            "normalized   x_n = (x − [{:.4}, {:.4}, {:.4}]) / {:.4}  (scene inside the unit sphere)",
            c[0], c[1], c[2], self.normalization.scale
        )?;
        match (self.format, &self.colmap_scale) {
            (_, Some(s)) => writeln!(
                f,
                "scale        COLMAP model × {:.6} into the depth's units (median of {} depth/SfM ratios in {} views, \
                 spread {:.2} %)",
                s.ratio,
                s.samples,
                s.views,
                100.0 * s.spread
            )?,
            (Format::Colmap, None) => writeln!(f, "scale        COLMAP's own units (no depth to fix them)")?,
            _ => {}
        }
        writeln!(f, "ldr          {}", self.ldr_transfer)?;
        writeln!(f, "mesh         {}", self.mesh_path.as_deref().unwrap_or("–"))?;
        if self.relight_sets.is_empty() {
            write!(f, "relight      –")?;
        } else {
            let r: Vec<String> = self
                .relight_sets
                .iter()
                .map(|(s, k)| format!("{s} ({k} views)"))
                .collect();
            write!(f, "relight      {}", r.join(", "))?;
        }
        Ok(())
    }
}
