//! `i2sdf check --data SCENE`: validate a dataset (every file is read and checked) and summarize it.

use clap::Args as ClapArgs;
use std::path::PathBuf;

#[derive(ClapArgs)]
pub struct Args {
    /// Dataset directory: transforms.json (native format) or cameras_normalize.npz (paper format).
    #[arg(long)]
    pub data: PathBuf,
    /// Print the summary as one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let dataset = i2sdf_data::load(&args.data)?;
    let summary = i2sdf_data::Summary::of(&dataset);
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!("{summary}");
        println!("ok");
    }
    Ok(())
}
