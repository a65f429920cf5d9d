//! `i2sdf demo [--out DIR] [--quick]`: the whole pipeline on the built-in synthetic room —
//! synthesize it, validate it, train stage 1 and stage 2, extract the mesh, render the test views
//! (with the material maps and the Monte Carlo re-render) and evaluate.
//! Each step reuses the subcommand of the same name; finished steps are skipped on a re-run.

use super::{check, eval, mesh, render, synth, train};
use clap::Args as ClapArgs;
use std::path::PathBuf;

#[derive(ClapArgs)]
pub struct Args {
    /// Output directory: scene/, run/, mesh.ply, render/, metrics.json.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// A small room (80×60, 24 views) and a short training: about a minute and a half.
    #[arg(long)]
    pub quick: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let scene = args.out.join("scene");
    let run_dir = args.out.join("run");
    if !scene.join("transforms.json").is_file() {
        eprintln!("== 1/6 synthesize the room into {}", scene.display());
        let (width, height, views, spp) = if args.quick {
            (80, 60, 24, 32)
        } else {
            (160, 120, 48, 128)
        };
        synth::run(synth::Args {
            out: scene.clone(),
            preset: "livingroom".into(),
            scene: None,
            seed: 0,
            width,
            height,
            views,
            spp,
            depth_noise: "none".into(),
            max_depth: 64,
            unbiased: false,
        })?;
    } else {
        eprintln!("== 1/6 reuse the room in {}", scene.display());
    }
    check::run(check::Args {
        data: scene.clone(),
        json: false,
    })?;

    let info = i2sdf_model::RunDir::new(&run_dir);
    let done = info.read_info().map(|i| i.stage1.done).unwrap_or(false);
    if !done {
        eprintln!("== 2/6 train stage 1 into {}", run_dir.display());
        let set = if args.quick {
            vec![
                "train.iterations=1500".to_string(),
                "train.rays=512".into(),
                "model.hash_log2_table=16".into(),
            ]
        } else {
            Vec::new()
        };
        train::run(train::Args {
            data: scene.clone(),
            out: run_dir.clone(),
            config: None,
            set,
            stage: train::Stage::Geometry,
            resume: info.checkpoint_path().is_file(),
            quiet: false,
        })?;
    }
    let stage2_done = info
        .read_info()
        .ok()
        .and_then(|i| i.stage2.map(|s| s.done))
        .unwrap_or(false);
    if !stage2_done {
        eprintln!("== 3/6 train stage 2 (emitters, materials) into {}", run_dir.display());
        let set = if args.quick {
            vec![
                "stage2.iterations=400".to_string(),
                "stage2.cache_pixels=32768".into(),
                "stage2.bake_resolution=128".into(),
            ]
        } else {
            Vec::new()
        };
        train::run(train::Args {
            data: scene.clone(),
            out: run_dir.clone(),
            config: None,
            set,
            stage: train::Stage::Material,
            resume: info.stage2_checkpoint_path().is_file(),
            quiet: false,
        })?;
    }
    eprintln!("== 4/6 extract the mesh");
    let resolution = if args.quick { 128 } else { 256 };
    mesh::run(mesh::Args {
        run: run_dir.clone(),
        out: args.out.join("mesh.ply"),
        resolution,
    })?;
    eprintln!("== 5/6 render the test views");
    render::run(render::Args {
        run: run_dir.clone(),
        out: args.out.join("render"),
        split: "test".into(),
        what: "rgb,depth,normal,emitter,albedo,specular,roughness,emission,rerender".into(),
        data: Some(scene.clone()),
        spp: if args.quick { 16 } else { 64 },
        path: Default::default(),
    })?;
    eprintln!("== 6/6 evaluate");
    eval::run(eval::Args {
        run: run_dir,
        data: scene,
        out: args.out.join("metrics.json"),
        mesh_resolution: resolution,
        threshold: 0.05,
        spp: if args.quick { 16 } else { 64 },
        bounces: if args.quick { 4 } else { 8 },
    })?;
    Ok(())
}
