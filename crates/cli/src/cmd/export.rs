//! `i2sdf export --run RUN --out room.glb`: the recovered room as a glTF 2.0 scene (`.glb` or
//! `.gltf`, one file): the surface simplified to a face budget, the material fields baked into
//! textures over a UV atlas (Kd, ρ, Ks through `KHR_materials_specular`; `--texture-size 0`: Kd
//! as vertex colours with Ks and ρ in a few GGX materials), the emitters as emissive materials
//! (`KHR_materials_emissive_strength`, L\[k\] in the input images' linear units) and with
//! `--lights` as punctual lights, the dataset's cameras; a stage-1 run exports its surface with
//! the radiance field's colour. Everything is checked before the surface is extracted; the file
//! is written atomically.

use clap::Args as ClapArgs;
use i2sdf_data::DataError;
use i2sdf_export::{ExportOptions, UpAxis};
use std::path::PathBuf;

#[derive(ClapArgs)]
pub struct Args {
    /// The trained run (stage 2 for materials and emitters; a stage-1 run exports its radiance).
    #[arg(long)]
    pub run: PathBuf,
    /// Output scene: .glb (binary) or .gltf (JSON with the buffer embedded).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace --out if it exists.
    #[arg(long)]
    pub force: bool,
    /// Marching-cubes samples along the scene's longest side.
    #[arg(long, default_value_t = ExportOptions::default().resolution)]
    pub resolution: usize,
    /// Face budget of the simplified surface (meshoptimizer).
    #[arg(long, default_value_t = ExportOptions::default().max_faces)]
    pub max_faces: usize,
    /// Largest distance the simplification may move the surface (world units).
    #[arg(long, default_value_t = ExportOptions::default().max_error)]
    pub max_error: f32,
    /// Most GGX materials the faces' Ks and roughness are grouped into.
    #[arg(long, default_value_t = ExportOptions::default().materials)]
    pub materials: usize,
    /// Width of the texture atlas the materials are baked into (0: Kd as vertex colours, Ks and
    /// roughness in --materials GGX materials).
    #[arg(long, default_value_t = ExportOptions::default().texture_size)]
    pub texture_size: u32,
    /// Also export each emitter as a punctual light (KHR_lights_punctual) of the same power, for
    /// viewers that light only by lights (path tracers light by the emissive surfaces).
    #[arg(long)]
    pub lights: bool,
    /// The world axis that becomes glTF's +Y: +x, -x, +y, -y, +z, -z, or auto (the cameras' mean up).
    #[arg(long, default_value = "auto")]
    pub up: String,
    /// Dataset whose cameras are exported (defaults to the one the run was trained on).
    #[arg(long)]
    pub data: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let up = match args.up.as_str() {
        "auto" => None,
        s => Some(
            UpAxis::parse(s)
                .ok_or_else(|| DataError::invalid(format!("--up {s}: expected auto, +x, -x, +y, -y, +z or -z")))?,
        ),
    };
    let opts = ExportOptions {
        resolution: args.resolution,
        max_faces: args.max_faces,
        max_error: args.max_error,
        materials: args.materials,
        up,
        texture_size: args.texture_size,
        lights: args.lights,
    };
    opts.check()?;
    let info = i2sdf_model::RunDir::new(&args.run).read_info()?;
    let trained_on = PathBuf::from(&info.data);
    let mut inputs = vec![trained_on.as_path()];
    if let Some(d) = &args.data {
        inputs.push(d.as_path());
    }
    super::output_file("--out", &args.out, &["glb", "gltf"], args.force, &inputs, None)?;
    let (_, dataset) = super::run_dataset(&args.run, args.data.as_deref())?;
    let run = super::open_run(&args.run)?;
    if run.fields.is_none() {
        crate::progress::line(&format!(
            "note: {} has no stage 2: exporting its surface with the radiance field's colour (unlit), without materials or emitters",
            args.run.display()
        ));
    }
    let start = std::time::Instant::now();
    eprintln!("extracting the surface at {}…", args.resolution);
    let (model, summary) = i2sdf_export::build(&run, &dataset, &opts)?;
    let bytes = i2sdf_export::write(&args.out, &model)?;
    for note in &summary.notes {
        crate::progress::line(&format!("note: {note}"));
    }
    println!(
        "wrote {}: {} faces (of {} extracted), {} vertices, {} material(s), {} emitter(s), {} light(s), {} camera(s), up {}{}, {} ({:.1} s)",
        args.out.display(),
        summary.faces,
        summary.faces_extracted,
        summary.vertices,
        summary.materials,
        summary.emitters,
        summary.lights,
        summary.cameras,
        summary.up,
        summary
            .up_from_cameras_deg
            .map_or(String::new(), |a| format!(" (the cameras' mean up, {a:.1}° off)")),
        i2sdf_data::output::human_bytes(bytes),
        start.elapsed().as_secs_f64()
    );
    if let Some(t) = summary.textures {
        println!(
            "textures: {}×{} texels, {} charts, {:.0} texels per unit ({:.1} mm a texel), {:.0} % of the page used",
            t.width,
            t.height,
            t.charts,
            t.texels_per_unit,
            1000.0 / t.texels_per_unit,
            100.0 * t.utilization
        );
    }
    if let Some(l) = summary.loss {
        println!(
            "{} against the material fields at 100 000 surface points: Kd {:.2} dB, Ks RMS {:.4}, roughness RMS {:.4}",
            l.encoding, l.kd_psnr, l.ks_rms, l.rho_rms
        );
    }
    Ok(())
}
