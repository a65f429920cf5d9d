//! The maps training uses, per training view, and what stands in for each the dataset lacks (docs/DATASETS.md,
//! "Missing maps"):
//! - emitter masks (`maps.emitter_masks`): the dataset's, else found from the images
//!   ([`i2sdf_data::emitter_detect`]); they supervise stage 1's F_e and make stage 2's emitters;
//! - normal maps (`maps.normals`): the dataset's, else derived from depth
//!   ([`i2sdf_data::depth_normals`]; measured as good as the true normals on a synthetic room,
//!   where no normal loss lost 0.08 F-score) or none; they supervise stage 1's normal loss;
//! - depth: without it stage 1 has no depth loss and no error-guided sampling, and takes its
//!   smoothness and bubble points from the rendered surface (`crate::stage1`); depth the dataset
//!   does not declare exact is a sensor's, whose far samples weigh less
//!   (`maps.depth_noise_distance`);
//! - HDR: stage 2 fits the LDR images instead (`crate::stage2::targets`);
//! - material masks (the paper's release marks non-GGX areas): without them stage 2 fits every
//!   surface pixel.
//!
//! Masks found from the images are written into the run (`RUN/emitter_masks/NAME.png`, for the
//! user to look at) and read back by every later session of it (a resume, stage 2), so the whole
//! run trains with the same masks.

use crate::config::{EmitterMasks, Normals, TrainConfig};
use i2sdf_data::emitter_detect::{detect_emitters, EmitterDetection};
use i2sdf_data::{DataError, Dataset, Frame, ImageF32, Split};
use i2sdf_model::RunDir;
use std::borrow::Cow;
use std::fmt;
use std::path::{Path, PathBuf};

/// Where a run's found masks are when they were read back from or written to it.
#[derive(Clone, Debug, PartialEq)]
pub enum MasksInRun {
    Written(PathBuf),
    Read(PathBuf),
}

/// The maps in force for training a dataset with a configuration.
#[derive(Clone, Debug)]
pub struct TrainingMaps {
    emitter_policy: EmitterMasks,
    normal_policy: Normals,
    /// Per dataset frame: the emitter mask found from the images, where it stands in for the
    /// dataset's (training views only).
    found: Vec<Option<ImageF32>>,
    /// What the detection found, when it ran in this session.
    pub detection: Option<EmitterDetection>,
    pub masks_in_run: Option<MasksInRun>,
    /// Use stage 2's HDR targets (`stage2.use_hdr`), for the description.
    use_hdr: bool,
    /// Stage 2 smooths the SDF's shading normals where a view has no normal map
    /// (`stage2.normal_smoothing_radius` > 0), for the description.
    smooths_normals: bool,
    /// The depth sensor's noise model in force (metres; 0: every depth sample weighs alike).
    pub depth_noise_distance: f32,
    /// When stage 1 sweeps the images for the depth a sensor lost (`maps.photo_depth`, a fraction
    /// of its iterations; 0: never, as for exact depth).
    pub photo_depth: f32,
}

/// One map as `check` and `train` say it: how many training views have it in the dataset and
/// what training does with it (or instead of it).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct MapLine {
    /// `depth`, `normals`, `emitter masks`, `hdr`.
    pub map: &'static str,
    /// Training views whose dataset frame has the map, of `views`.
    pub present: usize,
    pub views: usize,
    /// What training does, in a few words.
    pub then: String,
}

impl fmt::Display for MapLine {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.present {
            0 => write!(f, "{}: absent → {}", self.map, self.then),
            n => write!(f, "{}: {n}/{} views → {}", self.map, self.views, self.then),
        }
    }
}

/// The training views of `dataset` with their frame index.
fn train_frames(dataset: &Dataset) -> Vec<(usize, &Frame)> {
    dataset
        .frames
        .iter()
        .enumerate()
        .filter(|(_, f)| f.split == Split::Train)
        .collect()
}

/// Refuses a `dataset` policy whose map some training view lacks, naming the key.
fn require(dataset: &Dataset, key: &str, what: &str, has: impl Fn(&Frame) -> bool) -> Result<(), DataError> {
    let frames = train_frames(dataset);
    let lacking: Vec<&str> = frames
        .iter()
        .filter(|(_, f)| !has(f))
        .map(|(_, f)| f.name.as_str())
        .collect();
    match lacking.first() {
        None => Ok(()),
        Some(first) => Err(DataError::invalid(format!(
            "{key} = \"dataset\": {} of the {} training views have no {what} (the first: {first}); \"auto\" uses what the dataset has and fills in the rest, \"off\" trains without",
            lacking.len(),
            frames.len()
        ))),
    }
}

/// The file name of training view `frame`'s found mask in `RUN/emitter_masks/`: its name, or
/// with its index in front where two training views share a name.
fn mask_file_name(dataset: &Dataset, index: usize) -> String {
    let name = &dataset.frames[index].name;
    let shared = train_frames(dataset).iter().filter(|(_, f)| &f.name == name).count() > 1;
    let safe: String = name
        .chars()
        .map(|c| {
            if c.is_alphanumeric() || "-_.".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect();
    if shared {
        format!("{index:05}_{safe}.png")
    } else {
        format!("{safe}.png")
    }
}

impl TrainingMaps {
    /// The maps `config` asks of `dataset`: refuses a `dataset` policy the dataset cannot meet
    /// (bad input naming the key), runs the emitter detection where masks are to be found.
    pub fn prepare(dataset: &Dataset, config: &TrainConfig) -> Result<TrainingMaps, DataError> {
        let mut maps = TrainingMaps::unfound(dataset, config)?;
        let needs = maps.needs_found(dataset);
        if !needs.is_empty() {
            // Every training view is a witness for the others, whichever need masks.
            let frames = train_frames(dataset);
            let refs: Vec<&Frame> = frames.iter().map(|(_, f)| *f).collect();
            let mut detection = detect_emitters(&refs);
            for ((index, _), mask) in frames.iter().zip(std::mem::take(&mut detection.masks)) {
                if needs.contains(index) {
                    maps.found[*index] = Some(mask);
                }
            }
            maps.detection = Some(detection);
        }
        Ok(maps)
    }

    /// The policies checked, no mask found yet.
    fn unfound(dataset: &Dataset, config: &TrainConfig) -> Result<TrainingMaps, DataError> {
        let m = &config.maps;
        if m.emitter_masks == EmitterMasks::Dataset {
            require(dataset, "maps.emitter_masks", "emitter mask", |f| {
                f.emitter_mask.is_some()
            })?;
        }
        match m.normals {
            Normals::Dataset => require(dataset, "maps.normals", "normal map", |f| f.normal.is_some())?,
            Normals::Depth if !train_frames(dataset).iter().any(|(_, f)| f.depth.is_some()) => {
                return Err(DataError::invalid(
                    "maps.normals = \"depth\": the dataset has no depth maps to derive normals from",
                ))
            }
            _ => {}
        }
        Ok(TrainingMaps {
            emitter_policy: m.emitter_masks,
            normal_policy: m.normals,
            found: vec![None; dataset.frames.len()],
            detection: None,
            masks_in_run: None,
            use_hdr: config.stage2.use_hdr,
            smooths_normals: config.stage2.normal_smoothing_radius > 0.0,
            // Exact depth has no noise to model.
            depth_noise_distance: if dataset.depth_exact {
                0.0
            } else {
                m.depth_noise_distance
            },
            photo_depth: if dataset.depth_exact { 0.0 } else { m.photo_depth },
        })
    }

    /// The training views (frame indices) whose emitter mask is to be found from the images.
    fn needs_found(&self, dataset: &Dataset) -> Vec<usize> {
        train_frames(dataset)
            .into_iter()
            .filter(|(_, f)| match self.emitter_policy {
                EmitterMasks::Images => true,
                EmitterMasks::Auto => f.emitter_mask.is_none(),
                EmitterMasks::Dataset | EmitterMasks::Off => false,
            })
            .map(|(i, _)| i)
            .collect()
    }

    /// The maps of a run's session: masks found by an earlier session are read back from
    /// `RUN/emitter_masks/` (all of them, or the folder is not the run's: refused as bad input);
    /// a first session finds them and writes them there.
    pub fn for_run(run: &RunDir, dataset: &Dataset, config: &TrainConfig) -> Result<TrainingMaps, DataError> {
        let dir = run.emitter_masks_dir();
        let mut maps = TrainingMaps::unfound(dataset, config)?;
        let needs = maps.needs_found(dataset);
        if needs.is_empty() {
            return Ok(maps);
        }
        if dir.is_dir() {
            for &i in &needs {
                let path = dir.join(mask_file_name(dataset, i));
                if !path.is_file() {
                    return Err(DataError::file(
                        &path,
                        "missing: the run's emitter masks are incomplete (remove the folder to find them again)",
                    ));
                }
                maps.found[i] = Some(i2sdf_data::dataset::load_mask(&path, &dataset.frames[i].camera)?);
            }
            maps.masks_in_run = Some(MasksInRun::Read(dir));
            return Ok(maps);
        }
        let mut maps = TrainingMaps::prepare(dataset, config)?;
        maps.write_masks(&dir, dataset)?;
        maps.masks_in_run = Some(MasksInRun::Written(dir));
        Ok(maps)
    }

    /// Writes the found masks into `dir`, which is created; each file atomically, the folder
    /// itself last (built aside and renamed), so a killed session leaves none or all of them (and
    /// the folder it was building aside, removed here by the next).
    fn write_masks(&self, dir: &Path, dataset: &Dataset) -> Result<(), DataError> {
        let name = dir.file_name().and_then(|n| n.to_str()).unwrap_or("emitter_masks");
        if let Some(parent) = dir.parent() {
            for stale in i2sdf_data::output::entries(parent) {
                if stale.starts_with(&format!("{name}.")) && stale.ends_with(".partial") {
                    let p = parent.join(&stale);
                    std::fs::remove_dir_all(&p).map_err(|e| DataError::io(&p, format!("cannot clear: {e}")))?;
                }
            }
        }
        let aside = dir.with_extension(format!("{}.partial", std::process::id()));
        std::fs::create_dir_all(&aside).map_err(|e| DataError::io(&aside, format!("cannot create: {e}")))?;
        for (i, mask) in self.found.iter().enumerate() {
            if let Some(mask) = mask {
                i2sdf_data::imageio::write_png(&aside.join(mask_file_name(dataset, i)), mask)?;
            }
        }
        std::fs::rename(&aside, dir).map_err(|e| DataError::io(dir, format!("cannot move into place: {e}")))
    }

    /// The emitter mask training uses for dataset frame `index` (`frame`), if any.
    pub fn emitter_mask<'a>(&'a self, index: usize, frame: &'a Frame) -> Option<&'a ImageF32> {
        match self.emitter_policy {
            EmitterMasks::Off => None,
            EmitterMasks::Dataset => frame.emitter_mask.as_ref(),
            EmitterMasks::Images => self.found[index].as_ref(),
            EmitterMasks::Auto => frame.emitter_mask.as_ref().or(self.found[index].as_ref()),
        }
    }

    /// The normal map stage 1's normal loss uses for `frame`, if any: the dataset's, or derived
    /// from its depth (computed here: a few milliseconds a view, not kept).
    pub fn normal<'a>(&self, frame: &'a Frame) -> Option<Cow<'a, ImageF32>> {
        let derived = || {
            frame
                .depth
                .as_ref()
                .map(|d| Cow::Owned(i2sdf_data::depth_normals::normals_from_depth(d, &frame.camera)))
        };
        match self.normal_policy {
            Normals::Off => None,
            Normals::Dataset => frame.normal.as_ref().map(Cow::Borrowed),
            Normals::Auto => frame.normal.as_ref().map(Cow::Borrowed).or_else(derived),
            Normals::Depth => derived(),
        }
    }

    /// One line per map: what the dataset has and what training does (`check` and `train` print
    /// them).
    pub fn describe(&self, dataset: &Dataset) -> Vec<MapLine> {
        let frames = train_frames(dataset);
        let views = frames.len();
        let count = |has: &dyn Fn(&Frame) -> bool| frames.iter().filter(|(_, f)| has(f)).count();
        let line = |map, present, then: String| MapLine {
            map,
            present,
            views,
            then,
        };
        let depth = count(&|f| f.depth.is_some());
        let normals = count(&|f| f.normal.is_some());
        let masks = count(&|f| f.emitter_mask.is_some());
        let hdr = count(&|f| f.hdr.is_some());
        let mut out = Vec::new();
        out.push(line(
            "depth",
            depth,
            match depth {
                0 => {
                    "no depth loss; smoothness and bubble points on the rendered surface (where each ray's termination density peaks)"
                        .into()
                }
                n => {
                    let uses = if n == views {
                        "depth loss, bubble points, smoothness"
                    } else {
                        "depth loss, bubble points and smoothness where given"
                    };
                    let noise = match (dataset.depth_exact, self.depth_noise_distance) {
                        (true, _) => "; declared exact (depth_exact): every sample weighs alike".to_string(),
                        (false, d) if d > 0.0 => format!(
                            "; a sensor's: far samples weigh less, its noise doubled at {d} m \
                             (maps.depth_noise_distance)"
                        ),
                        (false, _) => "; a sensor's, every sample weighed alike (maps.depth_noise_distance = 0)".into(),
                    };
                    let photo = if self.photo_depth > 0.0 {
                        format!(
                            "; where it lost a thin foreground, depth from the images at {:.0} % of stage 1 \
                             (maps.photo_depth)",
                            100.0 * self.photo_depth
                        )
                    } else {
                        String::new()
                    };
                    format!("{uses}{noise}{photo}")
                }
            },
        ));
        out.push(line(
            "normals",
            normals,
            match (self.normal_policy, normals) {
                (Normals::Off, _) => "no normal loss (maps.normals = \"off\")".into(),
                (Normals::Depth, _) => {
                    format!("derived from depth ({depth} views) for the normal loss (maps.normals = \"depth\")")
                }
                (_, n) if n == views => "normal loss".into(),
                (Normals::Auto, n) => {
                    let derived = count(&|f| f.normal.is_none() && f.depth.is_some());
                    match (n, derived) {
                        (0, 0) => "no normal loss (no depth to derive them from)".into(),
                        (0, d) => format!("derived from depth ({d} views) for the normal loss"),
                        (_, 0) => "normal loss where given".into(),
                        (_, d) => format!("normal loss; derived from depth for {d} views without"),
                    }
                }
                _ => "normal loss where given".into(),
            } + if normals < views && self.smooths_normals {
                "; stage 2 and the renderers shade with the SDF's normals, smoothed (stage2.normal_smoothing_radius)"
            } else {
                ""
            },
        ));
        let found: usize = self.found.iter().flatten().count();
        let found_px: usize = self
            .found
            .iter()
            .flatten()
            .map(|m| m.data.iter().filter(|v| **v > 0.5).count())
            .sum();
        let with_emitters = self
            .found
            .iter()
            .flatten()
            .filter(|m| m.data.iter().any(|v| *v > 0.5))
            .count();
        let mut emitters = match (self.emitter_policy, found) {
            (EmitterMasks::Off, _) => {
                "no emitter loss, no emitters in stage 2 (maps.emitter_masks = \"off\")".to_string()
            }
            (_, 0) => "emitter loss, stage 2's emitters".to_string(),
            (policy, _) => {
                let how = match &self.detection {
                    Some(d) => {
                        let test = match d.hdr_threshold {
                            Some(t) => format!("HDR luminance > {t:.3}"),
                            None => "saturated LDR".into(),
                        };
                        let views = if d.multi_view {
                            format!(", {} dropped as dark from other views", d.dropped_inconsistent)
                        } else {
                            "; no depth: no cross-view check".into()
                        };
                        let holes = if d.holes_filled > 0 {
                            format!(", {} px of enclosed speckle filled", d.holes_filled)
                        } else {
                            String::new()
                        };
                        format!(
                            " ({test}; {} pieces kept, {} dropped as small{views}{holes})",
                            d.kept, d.dropped_small
                        )
                    }
                    None => String::new(),
                };
                let which = if policy == EmitterMasks::Images {
                    " (maps.emitter_masks = \"images\")"
                } else {
                    ""
                };
                format!("found from the images{which}: {found_px} px in {with_emitters} of {found} views{how}")
            }
        };
        match &self.masks_in_run {
            Some(MasksInRun::Written(d)) => emitters += &format!("; written to {}/", d.display()),
            Some(MasksInRun::Read(d)) => emitters += &format!("; read back from {}/", d.display()),
            None => {}
        }
        out.push(line("emitter masks", masks, emitters));
        // Only datasets that have material masks (the paper's release) get the line: nothing
        // stands in for a missing one.
        let material_masks = count(&|f| f.material_mask.is_some());
        if material_masks > 0 {
            out.push(line(
                "material masks",
                material_masks,
                "stage 2 does not fit the pixels they mark non-GGX (0)".into(),
            ));
        }
        out.push(line(
            "hdr",
            hdr,
            match (hdr, self.use_hdr) {
                (0, _) => "stage 2 fits the LDR images (saturated channels as lower bounds; a light seen only clipped gets its L from the light it throws on the room, stage2.emission_from_shading)".into(),
                (_, false) => "unused: stage 2 fits the LDR images (stage2.use_hdr = false)".into(),
                (n, true) if n == views => "stage 2 fits the HDR images".into(),
                _ => "stage 2 fits the HDR images where given, else the LDR ones".into(),
            },
        ));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use i2sdf_data::fixture::{self, FixtureOptions};

    fn dataset() -> (tempfile::TempDir, Dataset) {
        let dir = tempfile::tempdir().unwrap();
        fixture::write_native(dir.path(), &FixtureOptions::default());
        let ds = i2sdf_data::load(dir.path()).unwrap();
        (dir, ds)
    }

    fn config(sets: &[&str]) -> TrainConfig {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        TrainConfig::load(None, &sets).unwrap()
    }

    /// A bad value names its key; a `dataset` policy the dataset cannot meet names its key too.
    #[test]
    fn policies_are_validated_naming_their_key() {
        for (set, key) in [
            ("maps.emitter_masks=lamps", "maps.emitter_masks"),
            ("maps.normals=sdf", "maps.normals"),
            ("maps.emitter_masks=1", "maps.emitter_masks"),
        ] {
            let e = TrainConfig::load(None, &[set.to_string()]).unwrap_err();
            assert!(e.is_bad_input() && e.to_string().contains(key), "{set}: {e}");
        }
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.toml");
        std::fs::write(&p, "[maps]\nnormals = \"guess\"\n").unwrap();
        let e = TrainConfig::load(Some(&p), &[]).unwrap_err().to_string();
        assert!(e.contains("maps.normals (line 2)"), "{e}");

        let (_d, mut ds) = dataset();
        for f in &mut ds.frames {
            f.emitter_mask = None;
            f.normal = None;
        }
        for (set, key) in [
            ("maps.emitter_masks=dataset", "maps.emitter_masks"),
            ("maps.normals=dataset", "maps.normals"),
        ] {
            let e = TrainingMaps::prepare(&ds, &config(&[set])).unwrap_err();
            assert!(e.is_bad_input() && e.to_string().contains(key), "{set}: {e}");
        }
        for f in &mut ds.frames {
            f.depth = None;
        }
        let e = TrainingMaps::prepare(&ds, &config(&["maps.normals=depth"])).unwrap_err();
        assert!(
            e.to_string().contains("maps.normals") && e.to_string().contains("no depth"),
            "{e}"
        );
    }

    /// Depth not declared exact is a sensor's: its noise model and the sweep for depth from the
    /// images are in force as configured (by default the first off, the second on).
    #[test]
    fn sensor_depth_gets_the_noise_model_and_says_so() {
        let (_d, mut ds) = dataset();
        ds.depth_exact = false;
        let maps = TrainingMaps::prepare(&ds, &config(&[])).unwrap();
        assert_eq!(maps.depth_noise_distance, 0.0);
        let line = maps.describe(&ds)[0].to_string();
        assert!(line.contains("every sample weighed alike"), "{line}");
        assert!(
            line.ends_with("depth from the images at 75 % of stage 1 (maps.photo_depth)"),
            "{line}"
        );
        let maps = TrainingMaps::prepare(&ds, &config(&["maps.depth_noise_distance=2", "maps.photo_depth=0"])).unwrap();
        assert_eq!(maps.depth_noise_distance, 2.0);
        let line = maps.describe(&ds)[0].to_string();
        assert!(
            line.ends_with("a sensor's: far samples weigh less, its noise doubled at 2 m (maps.depth_noise_distance)"),
            "{line}"
        );
        let e = TrainConfig::load(None, &["maps.depth_noise_distance=-1".to_string()]).unwrap_err();
        assert!(
            e.is_bad_input() && e.to_string().contains("maps.depth_noise_distance"),
            "{e}"
        );
    }

    /// What stands in for each missing map, per policy, and the lines that say it.
    #[test]
    fn each_policy_gives_its_maps_and_says_so() {
        let (_d, full) = dataset();
        let maps = TrainingMaps::prepare(&full, &config(&[])).unwrap();
        assert!(maps.detection.is_none());
        let (k, f) = train_frames(&full)[0];
        assert_eq!(maps.emitter_mask(k, f), f.emitter_mask.as_ref());
        assert!(matches!(maps.normal(f), Some(Cow::Borrowed(_))));
        let lines: Vec<String> = maps.describe(&full).iter().map(|l| l.to_string()).collect();
        assert_eq!(
            lines[0],
            "depth: 4/4 views → depth loss, bubble points, smoothness; declared exact (depth_exact): every sample weighs alike"
        );
        assert_eq!(maps.depth_noise_distance, 0.0);
        assert_eq!(lines[1], "normals: 4/4 views → normal loss");
        assert_eq!(lines[2], "emitter masks: 4/4 views → emitter loss, stage 2's emitters");
        assert!(
            lines[3].starts_with("hdr: absent → stage 2 fits the LDR images"),
            "{}",
            lines[3]
        );

        let mut bare = full.clone();
        for f in &mut bare.frames {
            f.emitter_mask = None;
            f.normal = None;
        }
        let maps = TrainingMaps::prepare(&bare, &config(&[])).unwrap();
        let (k, f) = train_frames(&bare)[0];
        // The fixture's ceiling patch is not bright: found, and empty.
        let found = maps.emitter_mask(k, f).expect("a found mask");
        assert!(found.data.iter().all(|v| *v == 0.0) && maps.detection.is_some());
        assert!(matches!(maps.normal(f), Some(Cow::Owned(_))));
        let lines: Vec<String> = maps.describe(&bare).iter().map(|l| l.to_string()).collect();
        assert_eq!(
            lines[1],
            "normals: absent → derived from depth (4 views) for the normal loss; stage 2 and the \
             renderers shade with the SDF's normals, smoothed (stage2.normal_smoothing_radius)"
        );
        let unsmoothed = TrainingMaps::prepare(&bare, &config(&["stage2.normal_smoothing_radius=0"])).unwrap();
        assert_eq!(
            unsmoothed.describe(&bare)[1].to_string(),
            "normals: absent → derived from depth (4 views) for the normal loss"
        );
        assert!(
            lines[2].starts_with("emitter masks: absent → found from the images: 0 px in 0 of 4 views"),
            "{}",
            lines[2]
        );

        let off = TrainingMaps::prepare(&bare, &config(&["maps.normals=off"])).unwrap();
        assert!(off.normal(&full.frames[k]).is_none());
        let maps = TrainingMaps::prepare(&bare, &config(&["maps.normals=depth", "maps.emitter_masks=off"])).unwrap();
        let n = maps.normal(f).expect("derived normals");
        // The fixture is a box room: every derived normal is an axis, as the dataset's were.
        let given = full.frames[k].normal.as_ref().unwrap();
        let agree = (0..f.pixel_count())
            .filter(|&p| (0..3).map(|c| n.data[p * 3 + c] * given.data[p * 3 + c]).sum::<f32>() > 0.999)
            .count();
        assert!(agree as f64 > 0.8 * f.pixel_count() as f64, "{agree}");
        assert!(maps.emitter_mask(k, f).is_none());
        let lines: Vec<String> = maps.describe(&bare).iter().map(|l| l.to_string()).collect();
        assert!(lines[1].contains("derived from depth (4 views)"), "{}", lines[1]);
        assert!(lines[2].contains("no emitter loss"), "{}", lines[2]);
    }

    /// A run's found masks are written once and read back (the same), and an incomplete folder
    /// is refused naming the missing file.
    #[test]
    fn found_masks_are_written_into_the_run_and_read_back() {
        let (_d, mut ds) = dataset();
        for f in &mut ds.frames {
            f.emitter_mask = None;
        }
        // A bright square in every training view's image, found (without depth: no view can
        // refute another's).
        for f in ds.frames.iter_mut() {
            f.depth = None;
            for j in 2..6 {
                for i in 3..7 {
                    f.rgb.pixel_mut(i, j).copy_from_slice(&[1.0; 3]);
                }
            }
        }
        let run_dir = tempfile::tempdir().unwrap();
        let run = RunDir::new(run_dir.path());
        // What a session killed while writing them left aside.
        let stale = run_dir.path().join("emitter_masks.1.partial");
        std::fs::create_dir(&stale).unwrap();
        std::fs::write(stale.join("0000.png"), b"torn").unwrap();
        let c = config(&["maps.emitter_masks=images"]);
        let first = TrainingMaps::for_run(&run, &ds, &c).unwrap();
        assert!(matches!(first.masks_in_run, Some(MasksInRun::Written(_))) && !stale.exists());
        let again = TrainingMaps::for_run(&run, &ds, &c).unwrap();
        assert!(matches!(again.masks_in_run, Some(MasksInRun::Read(_))) && again.detection.is_none());
        for (k, f) in train_frames(&ds) {
            let (a, b) = (first.emitter_mask(k, f).unwrap(), again.emitter_mask(k, f).unwrap());
            assert_eq!(a, b);
            assert_eq!(a.data.iter().filter(|v| **v > 0.5).count(), 16);
        }
        let names = i2sdf_data::output::entries(&run.emitter_masks_dir());
        assert_eq!(names.len(), 4, "{names:?}");
        let gone = run.emitter_masks_dir().join(&names[0]);
        std::fs::remove_file(&gone).unwrap();
        let e = TrainingMaps::for_run(&run, &ds, &c).unwrap_err();
        assert!(e.is_bad_input() && e.to_string().contains(&names[0]), "{e}");
    }
}
