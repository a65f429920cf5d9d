//! Timing and PSNR of the unedited path-traced render of one test view of a stage-2 run:
//! `edit_probe RUN DATA VIEW SPP BOUNCES`.

use glam::Vec3;
use i2sdf_edit::{render_recovered, EditSettings, EditedScene, RecoveredSurface};
use i2sdf_model::{intrinsic_io, FrozenScene, RunDir};
use std::time::Instant;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let run = RunDir::new(std::path::Path::new(&a[1]));
    let ds = i2sdf_data::load(std::path::Path::new(&a[2])).unwrap();
    let view: usize = a[3].parse().unwrap();
    let spp: u32 = a[4].parse().unwrap();
    let bounces: u32 = a[5].parse().unwrap();
    let (scene, fields) = intrinsic_io::load_run(&run).unwrap();
    let fields = fields.unwrap();
    let mut frozen = FrozenScene::new(&scene, &fields.emitters, fields.radiometry);
    let t = Instant::now();
    let res: usize = std::env::var("RES").map(|r| r.parse().unwrap()).unwrap_or(256);
    let surface = RecoveredSurface::extract(&frozen, &ds.bounds, res).unwrap();
    eprintln!(
        "surface {:.1}s: {} triangles, emitter faces {:?}",
        t.elapsed().as_secs_f64(),
        surface.mesh.faces.len(),
        surface.emitter_faces.iter().map(|f| f.len()).collect::<Vec<_>>()
    );
    let edited = EditedScene::new(surface.lights(&fields.emitters), Vec::new(), Vec::new());
    let frames: Vec<_> = ds.split(i2sdf_data::Split::Test).collect();
    let f = frames[view];
    let settings = EditSettings { spp, bounces, seed: 0 };
    let t = Instant::now();
    let v = render_recovered(
        &edited,
        &surface,
        &frozen,
        &fields.material,
        &f.camera,
        &settings,
        view as u32,
        &|| {},
    );
    let secs = t.elapsed().as_secs_f64();
    let v = if std::env::var("RERENDER").is_ok() {
        frozen.bake(&ds.bounds, 256).unwrap();
        i2sdf_model::rerender_view(&frozen, &fields.material, &f.camera, spp, 0, view as u32, &|| {})
    } else {
        v
    };
    let img = v.hdr(&vec![Vec3::ONE; v.emitters]);
    let rm = fields.radiometry;
    let gt = &f.rgb;
    let mut se = 0.0f64;
    for (i, c) in img.iter().enumerate() {
        for ch in 0..3 {
            let p = rm.encode(c[ch]) as f64;
            let g = gt.data[i * gt.channels + ch] as f64;
            se += (p - g) * (p - g);
        }
    }
    let mse = se / (img.len() * 3) as f64;
    let lin_gt: f64 = gt.data.iter().map(|&g| rm.linearize(g) as f64).sum::<f64>() / gt.data.len() as f64;
    let lin_p: f64 = img.iter().map(|c| (c.x + c.y + c.z) as f64 / 3.0).sum::<f64>() / img.len() as f64;
    let m3 = |x: &[Vec3]| x.iter().copied().sum::<Vec3>() / x.len() as f32;
    println!(
        "pixel maps: kd {} ks {} rho {}",
        m3(&v.kd),
        m3(&v.ks),
        v.roughness.iter().sum::<f32>() / v.roughness.len() as f32
    );
    println!("mean linear: render {lin_p:.4} gt {lin_gt:.4}");
    for (k, e) in (0..v.emitters).map(|k| {
        (k, {
            let mut g = vec![Vec3::ZERO; v.emitters];
            g[k] = Vec3::ONE;
            v.hdr(&g)
        })
    }) {
        println!(
            "slot {k}: mean {:.4}",
            e.iter().map(|c| (c.x + c.y + c.z) as f64 / 3.0).sum::<f64>() / e.len() as f64
        );
    }
    let enc = i2sdf_data::ImageF32::from_data(
        v.width,
        v.height,
        3,
        img.iter()
            .flat_map(|c| [rm.encode(c.x), rm.encode(c.y), rm.encode(c.z)])
            .collect(),
    );
    i2sdf_data::imageio::write_png(std::path::Path::new("/tmp/edit_probe.png"), &enc).unwrap();
    println!(
        "view {view} spp {spp} bounces {bounces}: {secs:.1}s psnr {:.2}",
        -10.0 * mse.log10()
    );
}
