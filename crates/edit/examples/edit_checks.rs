//! The edit renderer's measurements on a stage-2 run (issue 10's "must show"):
//! `edit_checks RUN DATA [SPP]` on test view 0 with 8 bounces:
//! - a mirror on part of the back wall against the same scene seen along the mirrored camera
//!   rays (PSNR inside the region), and a matte edit of the same region against the same;
//! - a sphere inserted on the floor: the darkening of the floor pixels in its shadow, and its
//!   appearance in the mirror;
//! - the time of a 160×120 view at 64 spp with 3 bounces.

use glam::{DVec3, Vec3};
use i2sdf_data::edit_spec::EditSpec;
use i2sdf_data::Split;
use i2sdf_edit::{edit_images, light_gains, EditSettings, RecoveredScene};
use i2sdf_eval::ImageRef;
use i2sdf_model::{intrinsic_io, RunDir};
use i2sdf_render::PathStart;
use rand::{Rng, SeedableRng};
use std::path::Path;
use std::time::Instant;

/// The back wall (z = −2.13 in the default room) between the lamp and the TV.
const MIRROR: &str =
    "[[op]]\nkind = \"material\"\nbox = { lo = [-2.35, 0.5, -2.3], hi = [-0.75, 2.3, -2.05] }\npreset = \"mirror\"\n";
const MATTE: &str =
    "[[op]]\nkind = \"material\"\nbox = { lo = [-2.35, 0.5, -2.3], hi = [-0.75, 2.3, -2.05] }\npreset = \"matte\"\n";
const SPHERE: &str =
    "[[op]]\nkind = \"insert\"\nsphere = { centre = [-1.1, 0.3, -1.4], radius = 0.3 }\npreset = \"glossy\"\n";

fn spec(text: &str) -> EditSpec {
    EditSpec::from_toml_str(text, Path::new("check.toml")).unwrap()
}

/// PSNR over all the values of `a` and `b` (eval's, on them as one row of one channel).
fn psnr(a: &[f32], b: &[f32]) -> f64 {
    fn row(v: &[f32]) -> ImageRef<'_> {
        ImageRef::new(v, v.len(), 1, 1).unwrap()
    }
    i2sdf_eval::psnr(row(a), row(b), None).unwrap().unwrap_or(f64::NAN)
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let run = RunDir::new(Path::new(&a[1]));
    let ds = i2sdf_data::load(Path::new(&a[2])).unwrap();
    let spp: u32 = a.get(3).map_or(64, |s| s.parse().unwrap());
    let (scene, fields) = intrinsic_io::load_run(&run).unwrap();
    let fields = fields.unwrap();
    let t = Instant::now();
    let train: Vec<_> = ds.split(Split::Train).map(|f| f.camera.clone()).collect();
    let rec = RecoveredScene::new(&scene, &fields, 0.5, &ds.bounds, 256, Some(&train)).unwrap();
    println!("surface: {:.1} s", t.elapsed().as_secs_f64());
    let frames: Vec<_> = ds.split(Split::Test).collect();
    let cam = &frames[0].camera;
    let settings = EditSettings {
        spp,
        bounces: 8,
        seed: 0,
        denoise: None,
    };
    let assets = Default::default();
    let render = |text: &str| {
        let sp = spec(text);
        let ed = rec.edited(&sp, &assets);
        let t = Instant::now();
        let v = rec.render(&ed, cam, &settings, 0, &|| {});
        let secs = t.elapsed().as_secs_f64();
        let (hdr, ldr) = edit_images(&v, &light_gains(&sp, &ed), &rec.radiometry);
        (v, hdr, ldr, secs)
    };
    let (plain, _, plain_ldr, secs) = render("");
    println!(
        "unedited: {secs:.1} s, PSNR vs test image {:.2} dB",
        psnr(&plain_ldr.data, &frames[0].rgb.data)
    );
    i2sdf_data::imageio::write_png(Path::new("/tmp/check_plain.png"), &plain_ldr).unwrap();

    // 1. Mirror against the mirrored camera rays.
    let (mv, _, mirror_ldr, _) = render(MIRROR);
    i2sdf_data::imageio::write_png(Path::new("/tmp/check_mirror.png"), &mirror_ldr).unwrap();
    let sp = spec(MIRROR);
    let region = match &sp.ops[0] {
        i2sdf_data::EditOp::Material(m) => m.region,
        _ => unreachable!(),
    };
    let (w, h) = (cam.width, cam.height);
    let mut inside = Vec::new();
    for j in 0..h {
        for i in 0..w {
            let d = mv.depth[j * w + i];
            if d.is_finite() {
                let p = cam.backproject(i, j, d as f64).as_vec3();
                if region.contains(p) {
                    inside.push((j * w + i, p, mv.normal[j * w + i]));
                }
            }
        }
    }
    let ed = rec.edited(&sp, &assets);
    let gen = cam.ray_generator();
    let mut rng = rand_pcg::Pcg32::seed_from_u64(9);
    let mut paths = Vec::new();
    // Each path through a random point of its pixel, as the camera's own paths: the camera ray
    // meets the wall's plane at the pixel-centre hit (p, n), and leaves it mirrored.
    let o = cam.center().as_vec3();
    for &(px, p, n) in &inside {
        let (i, j) = ((px % w) as f32, (px / w) as f32);
        let n = if n.dot(gen.dir(i + 0.5, j + 0.5)) > 0.0 { -n } else { n };
        for _ in 0..spp {
            let d = gen.dir(i + rng.gen::<f32>(), j + rng.gen::<f32>());
            let t = (p - o).dot(n) / d.dot(n);
            let r = d - 2.0 * d.dot(n) * n;
            paths.push(PathStart {
                origin: o + t * d + n * 2e-3,
                dir: r,
                strata: std::array::from_fn(|_| std::array::from_fn(|_| rng.gen())),
                rng: rand_pcg::Pcg32::new(rng.gen(), rng.gen()),
            });
        }
    }
    let nl = ed.lights();
    let mut paths2: Vec<PathStart> = paths
        .iter()
        .map(|p| PathStart {
            strata: std::array::from_fn(|_| std::array::from_fn(|_| rng.gen())),
            rng: rand_pcg::Pcg32::new(rng.gen(), rng.gen()),
            ..p.clone()
        })
        .collect();
    let mut rad = vec![Vec3::ZERO; paths.len() * nl];
    rec.trace(&ed, &settings, &mut paths, &mut rad);
    let mut rad2 = vec![Vec3::ZERO; paths2.len() * nl];
    rec.trace(&ed, &settings, &mut paths2, &mut rad2);
    let mut reflected2 = Vec::new();
    let (mut reflected, mut in_mirror, mut in_plain, mut in_matte) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (_, _, matte_ldr, _) = render(MATTE);
    for (q, &(px, _, _)) in inside.iter().enumerate() {
        let sum: Vec3 = (0..spp as usize * nl)
            .map(|s| rad[q * spp as usize * nl + s])
            .sum::<Vec3>()
            / spp as f32;
        reflected.extend(sum.to_array().map(|x| rec.radiometry.encode(x)));
        let sum2: Vec3 = (0..spp as usize * nl)
            .map(|s| rad2[q * spp as usize * nl + s])
            .sum::<Vec3>()
            / spp as f32;
        reflected2.extend(sum2.to_array().map(|x| rec.radiometry.encode(x)));
        for c in 0..3 {
            in_mirror.push(mirror_ldr.data[px * 3 + c]);
            in_plain.push(plain_ldr.data[px * 3 + c]);
            in_matte.push(matte_ldr.data[px * 3 + c]);
        }
    }
    println!(
        "mirror region: {} pixels; mirrored rays vs mirrored rays of another seed {:.2} dB (the noise floor); mirror vs mirrored rays {:.2} dB; matte vs mirrored rays {:.2} dB; unedited vs mirrored rays {:.2} dB",
        inside.len(),
        psnr(&reflected2, &reflected),
        psnr(&in_mirror, &reflected),
        psnr(&in_matte, &reflected),
        psnr(&in_plain, &reflected)
    );
    i2sdf_data::imageio::write_png(Path::new("/tmp/check_matte.png"), &matte_ldr).unwrap();
    let mut shown = mirror_ldr.clone();
    for (q, &(px, _, _)) in inside.iter().enumerate() {
        shown.data[px * 3..px * 3 + 3].copy_from_slice(&reflected[q * 3..q * 3 + 3]);
    }
    i2sdf_data::imageio::write_png(Path::new("/tmp/check_reflected.png"), &shown).unwrap();

    // 2. A sphere on the floor: its shadow, and its reflection.
    let (sv, _, sphere_ldr, _) = render(SPHERE);
    i2sdf_data::imageio::write_png(Path::new("/tmp/check_sphere.png"), &sphere_ldr).unwrap();
    let lum = |img: &[f32], px: usize| 0.2126 * img[px * 3] + 0.7152 * img[px * 3 + 1] + 0.0722 * img[px * 3 + 2];
    let (mut floor, mut darker, mut ratio_sum, mut shadowed_ratio) = (0, 0, 0.0f64, 0.0f64);
    let c = DVec3::new(-1.1, 0.3, -1.4);
    for j in 0..h {
        for i in 0..w {
            let px = j * w + i;
            let (ds_, dp) = (sv.depth[px], plain.depth[px]);
            if !(ds_.is_finite() && (ds_ - dp).abs() < 1e-3) {
                continue; // the sphere itself covers this pixel
            }
            let p = cam.backproject(i, j, dp as f64);
            if p.y > 0.03 || (p - DVec3::new(c.x, 0.0, c.z)).length() > 0.8 {
                continue; // floor within 0.8 m of the sphere's contact point only
            }
            floor += 1;
            let r = (lum(&sphere_ldr.data, px) / lum(&plain_ldr.data, px).max(1e-4)) as f64;
            ratio_sum += r;
            if r < 0.8 {
                darker += 1;
                shadowed_ratio += r;
            }
        }
    }
    println!(
        "sphere shadow: {floor} floor pixels within 0.8 m; {darker} darker by > 20 % (mean ratio there {:.3}); mean ratio over all {:.3}",
        shadowed_ratio / darker.max(1) as f64,
        ratio_sum / floor.max(1) as f64
    );
    let (_, _, both_ldr, _) = render(&format!("{MIRROR}{SPHERE}"));
    i2sdf_data::imageio::write_png(Path::new("/tmp/check_mirror_sphere.png"), &both_ldr).unwrap();
    let changed = inside
        .iter()
        .filter(|&&(px, _, _)| (lum(&both_ldr.data, px) - lum(&mirror_ldr.data, px)).abs() > 0.1)
        .count();
    let analytic = inside
        .iter()
        .filter(|&&(px, p, n)| {
            let d = gen.dir((px % w) as f32 + 0.5, (px / w) as f32 + 0.5);
            let n = if n.dot(d) > 0.0 { -n } else { n };
            let r = (d - 2.0 * d.dot(n) * n).as_dvec3();
            let oc = p.as_dvec3() - c;
            let b = oc.dot(r);
            b < 0.0 && b * b - (oc.length_squared() - 0.09) > 0.0
        })
        .count();
    println!("sphere in the mirror: {changed} mirror pixels change by > 0.1 in luminance; {analytic} mirror pixels' reflected ray meets the sphere");

    // 3. The time target: 64 spp, 3 bounces.
    let quick = EditSettings {
        spp: 64,
        bounces: 3,
        seed: 1,
        denoise: None,
    };
    let ed = rec.edited(&EditSpec::default(), &assets);
    let t = Instant::now();
    let _ = rec.render(&ed, cam, &quick, 0, &|| {});
    println!(
        "{}×{} at 64 spp, 3 bounces: {:.1} s",
        cam.width,
        cam.height,
        t.elapsed().as_secs_f64()
    );
}
