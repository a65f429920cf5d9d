//! `i2sdf check --data SCENE [--config FILE] [--set KEY=VALUE]...`: validate a dataset (every
//! file is read and checked), summarize it, say per map what training with that configuration
//! does with it or instead of it (`i2sdf_train::maps`: emitter masks found from the images,
//! normals derived from depth, …), and state what training will hold in memory (stage 1 and
//! stage 2, `i2sdf_train::memory`) against the machine's memory, with a warning when it does not
//! fit: better said now than by the OOM killer an hour in.

use clap::Args as ClapArgs;
use i2sdf_train::config::TrainConfig;
use i2sdf_train::maps::TrainingMaps;
use i2sdf_train::memory::{self, gib, DatasetShape, MachineMemory};
use std::path::PathBuf;

#[derive(ClapArgs)]
pub struct Args {
    /// Dataset directory: transforms.json (native format), cameras_normalize.npz (paper format) or a
    /// COLMAP model in sparse/ with images/ (COLMAP format).
    #[arg(long)]
    pub data: PathBuf,
    /// Print the summary as one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    /// The training configuration the memory estimate is for (as `train --config`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override a configuration value (as `train --set`, repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    // The configuration first: a bad key is reported before the dataset is read.
    let mut config = TrainConfig::load(args.config.as_deref(), &args.set)?;
    let dataset = i2sdf_data::load(&args.data)?;
    // What `train` would fill its "auto" settings with on this dataset.
    let filled = config.resolve(&dataset);
    let summary = i2sdf_data::Summary::of(&dataset);
    let maps = TrainingMaps::prepare(&dataset, &config)?;
    let map_lines = maps.describe(&dataset);
    let exposure = i2sdf_data::exposure::estimate_exposure(&dataset);
    let radiometry_warnings = exposure.as_ref().map(|e| e.warnings(&dataset)).unwrap_or_default();
    let estimate = memory::estimate(&DatasetShape::of(&dataset), &config);
    let machine = MachineMemory::read();
    let warning = machine.and_then(|m| {
        estimate.over(&config, true, true, m.available).map(|why| {
            format!(
                "warning: {why} (of {} total); `train` refuses this unless --ignore-memory",
                gib(m.total as f64)
            )
        })
    });
    if args.json {
        let mut v = serde_json::to_value(&summary)?;
        v["training_maps"] = serde_json::json!({
            "maps": map_lines,
            "emitter_detection": maps.detection,
            "auto": filled,
        });
        v["exposure"] = serde_json::json!({
            "declared": dataset.radiometry.exposure,
            "measured": exposure,
            "warnings": radiometry_warnings,
        });
        v["memory"] = serde_json::json!({
            "stage1_bytes": estimate.stage1.total,
            "stage2_bytes": estimate.stage2.total,
            "stage1": estimate.stage1.items,
            "stage2": estimate.stage2.items,
            "available_bytes": machine.map(|m| m.available),
            "total_bytes": machine.map(|m| m.total),
            "fits": warning.is_none(),
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!("{summary}");
        // What training with this configuration does per map, in the summary's columns.
        for (k, line) in map_lines.iter().enumerate() {
            println!("{:13}{line}", if k == 0 { "training" } else { "" });
        }
        if let Some(line) = &filled {
            println!("{:13}{line}", "");
        }
        match &exposure {
            Some(e) => println!(
                "exposure     declared {}, measured {:.4} from the LDR/HDR pairs ({} channels, spread {:.1} %)",
                dataset.radiometry.exposure.map_or("–".to_string(), |d| d.to_string()),
                e.exposure,
                e.samples,
                100.0 * e.spread
            ),
            None => println!(
                "exposure     declared {} (no LDR/HDR pairs to measure it)",
                dataset.radiometry.exposure.map_or("–".to_string(), |d| d.to_string())
            ),
        }
        println!("training memory (estimate): stage 1 {}", estimate.stage1.describe());
        println!("training memory (estimate): stage 2 {}", estimate.stage2.describe());
        match machine {
            Some(m) => println!(
                "machine memory: {} available of {}",
                gib(m.available as f64),
                gib(m.total as f64)
            ),
            None => println!("machine memory: unknown (no /proc/meminfo)"),
        }
        println!("ok");
    }
    for w in &radiometry_warnings {
        eprintln!("warning: {w}");
    }
    if let Some(w) = dataset.colmap_scale.and_then(|s| s.warning()) {
        eprintln!("warning: {w}");
    }
    if let Some(w) = warning {
        eprintln!("{w}");
    }
    Ok(())
}
