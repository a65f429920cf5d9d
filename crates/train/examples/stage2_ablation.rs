//! Stage-2 ablations on one cache: builds the cache of a finished stage-1 run once, then fits
//! each variant (a list of `--set` overrides) from scratch on it and measures the materials on
//! the test views at the pixel centres (Kd PSNR raw and per-channel scaled on non-emitter pixels,
//! roughness L1, Ks L1) and the emissions against the dataset's GT emitters × exposure.
//!
//! `cargo run --release -p i2sdf-train --example stage2_ablation -- RUN DATA "k=v k=v" "k=v" ...`
//! (an empty string is the run's own configuration).

use glam::Vec3;
use i2sdf_data::Split;
use i2sdf_eval::image_metrics::psnr_from_mse;
use i2sdf_model::intrinsic::{FrozenScene, LabelledHit};
use i2sdf_model::material_field::{brdf_of_channels, MATERIAL_CHANNELS};
use i2sdf_model::{NeuralScene, RunDir};
use i2sdf_render::Ray;
use i2sdf_train::config::TrainConfig;
use i2sdf_train::driver::{TrainStage, Trainer};
use i2sdf_train::maps::TrainingMaps;
use i2sdf_train::run::read_run_config;
use i2sdf_train::stage2::{radiometry, target_views, Stage2};
use std::time::Instant;

#[path = "probes/segments.rs"]
mod segments;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 4 {
        eprintln!("usage: stage2_ablation RUN DATA \"k=v ...\" ...");
        std::process::exit(2);
    }
    let run = RunDir::new(std::path::Path::new(&args[1]));
    let mut dataset = i2sdf_data::load(std::path::Path::new(&args[2]))?;
    // Stage 2 sees the training views where stage 1 put them.
    if let Some(p) = i2sdf_model::poses::PoseCorrections::read(&run)? {
        p.apply(&mut dataset, &run.poses_path())?;
    }
    // GT_DATA=ROOM scores against another dataset of the same views (a capture's exact room).
    let gt_data = match std::env::var("GT_DATA") {
        Ok(p) => i2sdf_data::load(std::path::Path::new(&p))?,
        Err(_) => dataset.clone(),
    };
    let base = read_run_config(&run)?;
    let variants: Vec<Vec<String>> = args[3..]
        .iter()
        .map(|v| v.split_whitespace().map(str::to_string).collect())
        .collect();
    let config_of = |sets: &[String]| -> Result<TrainConfig, Box<dyn std::error::Error>> {
        let dir = tempfile_dir()?;
        let p = dir.join("base.toml");
        std::fs::write(&p, base.to_toml())?;
        Ok(TrainConfig::load(Some(&p), sets)?)
    };
    let first = config_of(&variants[0])?;
    let (scene, _) = NeuralScene::load(&run.checkpoint_path())?;
    let t0 = Instant::now();
    let maps = TrainingMaps::for_run(&run, &dataset, &first)?;
    let views = target_views(&dataset, first.stage2.use_hdr, &maps);
    let mut stage = Stage2::new(first.clone(), scene, &views, radiometry(&dataset), None, &|m| {
        eprintln!("{m}")
    })?;
    let (surface, emitter) = stage.counts();
    println!(
        "cache: {surface} surface + {emitter} emitter pixels × {} samples ({}), built in {:.1} s",
        stage.cache.per_pixel,
        if stage.cache.bake.is_some() { "baked" } else { "kept" },
        t0.elapsed().as_secs_f64()
    );
    // The floor of the fit: the cached estimator with the GROUND-TRUTH materials of the training
    // pixels against their targets (what frozen geometry, F_c and the emissions allow).
    {
        use i2sdf_train::stage2::PixelKind;
        let train: Vec<_> = gt_data.split(Split::Train).collect();
        let emission = stage.emissions();
        let (mut l1, mut l1_rel, mut n) = (0.0f64, 0.0f64, 0.0f64);
        let mut ratio = Vec::new();
        let mut glossy_ratio = Vec::new();
        let mut glossy_diffuse = Vec::new();
        let mut glossy_px = Vec::new();
        // DUMP_RATIO=DIR: the GT-material pred/target ratio of the first training views as
        // images (grey = ratio / 2: mid-grey where the fit's floor is exact).
        let dump = std::env::var("DUMP_RATIO").ok();
        let mut ratio_maps: Vec<Vec<f32>> = train.iter().take(6).map(|f| vec![0.0; f.pixel_count() * 3]).collect();
        for px in &stage.pixels {
            let PixelKind::Surface { index } = px.kind else {
                continue;
            };
            let index = index as usize;
            let fr = train[px.view as usize];
            let (Some(kd), Some(ks), Some(r)) = (&fr.albedo, &fr.specular, &fr.roughness) else {
                continue;
            };
            let p = px.pixel as usize;
            let brdf = i2sdf_render::GgxBrdf::new(
                Vec3::from_slice(&kd.data[p * 3..p * 3 + 3]),
                Vec3::from_slice(&ks.data[p * 3..p * 3 + 3]),
                r.data[p],
            );
            let nv = px.point.normal.dot(px.point.view);
            let pred = stage.cache.shade(index, &brdf, nv, &emission);
            l1 += (pred - px.target).abs().element_sum() as f64 / 3.0;
            l1_rel += ((pred - px.target).abs().element_sum() / px.target.element_sum().max(1e-3)) as f64;
            ratio.push(pred.element_sum() / px.target.element_sum().max(1e-4));
            if ks.data[p * 3] > 0.2 {
                glossy_ratio.push(pred.element_sum() / px.target.element_sum().max(1e-4));
                // The same pixel shaded as a pure diffuse surface of the Kd that fits it best.
                let d = i2sdf_render::GgxBrdf::new(Vec3::ONE, Vec3::ZERO, 1.0);
                let e = stage.cache.shade(index, &d, nv, &emission);
                glossy_diffuse.push((px.target, e, pred));
                glossy_px.push((px.point, px.target, brdf, index));
            }
            if let Some(m) = ratio_maps.get_mut(px.view as usize) {
                let r = 0.5 * pred.element_sum() / px.target.element_sum().max(1e-4);
                m[p * 3..p * 3 + 3].copy_from_slice(&[r; 3]);
            }
            n += 1.0;
        }
        if let Some(dir) = &dump {
            // Block means (4 × 4 pixels: the sampled pixels are sparse), shown 4× enlarged.
            std::fs::create_dir_all(dir)?;
            for (v, m) in ratio_maps.into_iter().enumerate() {
                let c = &train[v].camera;
                let (bw, bh) = (c.width.div_ceil(4), c.height.div_ceil(4));
                let mut sum = vec![(0.0f32, 0u32); bw * bh];
                for p in 0..c.width * c.height {
                    if m[p * 3] > 0.0 {
                        let b = (p / c.width / 4) * bw + (p % c.width) / 4;
                        sum[b].0 += m[p * 3];
                        sum[b].1 += 1;
                    }
                }
                let mut img = i2sdf_data::ImageF32::new(c.width, c.height, 3);
                for p in 0..c.width * c.height {
                    let (s, k) = sum[(p / c.width / 4) * bw + (p % c.width) / 4];
                    // Red: too dark (ratio < 1), green: too bright, black: no sample.
                    let r = if k > 0 { 2.0 * s / k as f32 } else { 1.0 };
                    let px = [
                        (1.0 - r).max(0.0) * 3.0,
                        (r - 1.0).max(0.0) * 3.0,
                        (k == 0) as u8 as f32 * 0.0,
                    ];
                    img.data[p * 3..p * 3 + 3].copy_from_slice(&px);
                }
                i2sdf_data::imageio::write_png(&std::path::Path::new(dir).join(format!("ratio_{v}.png")), &img)?;
            }
        }
        glossy_ratio.sort_by(f32::total_cmp);
        if !glossy_ratio.is_empty() {
            let q = |f: f64| glossy_ratio[((glossy_ratio.len() - 1) as f64 * f) as usize];
            // Best constant grey Kd explaining all glossy pixels as diffuse, and its L1 vs GT's.
            let (num, den) = glossy_diffuse.iter().fold((0.0f64, 0.0f64), |(a, b), (t, e, _)| {
                (a + t.dot(*e) as f64, b + e.dot(*e) as f64)
            });
            let kd = (num / den.max(1e-12)) as f32;
            let (mut l_gt, mut l_d) = (0.0f64, 0.0f64);
            for (t, e, pr) in &glossy_diffuse {
                l_gt += (*pr - *t).abs().element_sum() as f64;
                l_d += (*e * kd - *t).abs().element_sum() as f64;
            }
            println!(
                "  glossy pixels ({}): GT-material ratio p10 {:.2} p50 {:.2} p90 {:.2}; L1 GT {:.4} vs best grey diffuse Kd {:.3}: {:.4}",
                glossy_ratio.len(),
                q(0.1),
                q(0.5),
                q(0.9),
                l_gt / (3 * glossy_diffuse.len()) as f64,
                kd,
                l_d / (3 * glossy_diffuse.len()) as f64
            );
        }
        // RAD_CHECK=1: F_c's linearized radiance at each cached surface pixel's own point towards
        // its camera, against the pixel's linear target (unsaturated channels): the scale the
        // field term of every pixel's irradiance inherits.
        if std::env::var("RAD_CHECK").is_ok() {
            let frozen = stage.frozen();
            let sel: Vec<_> = stage
                .pixels
                .iter()
                .filter(|p| matches!(p.kind, PixelKind::Surface { .. }) && p.saturated == 0)
                .collect();
            let pts: Vec<Vec3> = sel.iter().map(|p| p.point.position).collect();
            let dirs: Vec<Vec3> = sel.iter().map(|p| -p.point.view).collect();
            let mut rad = vec![Vec3::ZERO; pts.len()];
            frozen.surface_radiance(&pts, &dirs, &mut rad);
            for c in 0..3 {
                let mut r: Vec<f32> = sel
                    .iter()
                    .zip(&rad)
                    .filter(|(p, _)| p.target[c] > 0.01)
                    .map(|(p, l)| l[c] / p.target[c])
                    .collect();
                r.sort_by(f32::total_cmp);
                let q = |f: f64| r[((r.len() - 1) as f64 * f) as usize];
                let (s_l, s_t) = sel.iter().zip(&rad).fold((0.0f64, 0.0f64), |a, (p, l)| {
                    (a.0 + l[c] as f64, a.1 + p.target[c] as f64)
                });
                println!(
                    "F_c / target, channel {c}: p10 {:.3} p50 {:.3} p90 {:.3}, sums {:.4}",
                    q(0.1),
                    q(0.5),
                    q(0.9),
                    s_l / s_t
                );
            }
        }
        // SHEEN=1: can the cache tell the floor's sheen (GT Ks ≈ 0.04, ρ ≈ 0.5) from a brighter
        // Kd? Floor pixels are binned into 8 cm cells; in each, Kd = c·GT Kd with the c that
        // minimizes the L1 of the cell's pixels, under the true specular and under alternatives.
        if std::env::var("SHEEN").is_ok() {
            let emission = stage.emissions();
            let hyp: [(f32, f32); 5] = [(-1.0, -1.0), (0.0, 0.9), (0.01, 0.9), (0.04, 0.9), (0.02, 0.5)];
            let mut cells: std::collections::HashMap<[i32; 3], Vec<(Vec3, Vec3, Vec3, Vec<Vec3>, u32)>> =
                std::collections::HashMap::new();
            for (px, i, gt) in segments::sheen_pixels(&stage, &train) {
                let nv = px.point.normal.dot(px.point.view);
                let (gks, gr) = (gt.ks.x, gt.rho);
                let diffuse = stage.cache.shade(
                    i,
                    &i2sdf_render::GgxBrdf::new(Vec3::ONE, Vec3::ZERO, 1.0),
                    nv,
                    &emission,
                );
                let specs: Vec<Vec3> = hyp
                    .iter()
                    .map(|&(k, r0)| {
                        let (k, r0) = if k < 0.0 { (gks, gr) } else { (k, r0) };
                        stage.cache.shade(
                            i,
                            &i2sdf_render::GgxBrdf::new(Vec3::ZERO, Vec3::splat(k), r0),
                            nv,
                            &emission,
                        )
                    })
                    .collect();
                let q = (px.point.position / 0.02).floor().as_ivec3().to_array();
                cells
                    .entry(q)
                    .or_default()
                    .push((gt.kd, diffuse, px.target, specs, px.view));
            }
            let mut tot = vec![0.0f64; hyp.len() + 1];
            const MIN_PX: usize = 4;
            let (mut ncell, mut npx) = (0usize, 0usize);
            let mut cs = vec![Vec::new(); hyp.len()];
            for v in cells.values() {
                let views: std::collections::HashSet<u32> = v.iter().map(|e| e.4).collect();
                if v.len() < MIN_PX || views.len() < 2 {
                    continue;
                }
                ncell += 1;
                npx += v.len();
                let l1 = |h: usize, c: f32| -> f64 {
                    v.iter()
                        .map(|(k, d, t, s, _)| ((*k * *d * c + s[h]) - *t).abs().element_sum() as f64)
                        .sum()
                };
                tot[hyp.len()] += l1(0, 1.0);
                for h in 0..hyp.len() {
                    let best = (0..=600)
                        .map(|j| 0.5 + j as f32 * 0.0025)
                        .map(|c| (l1(h, c), c))
                        .min_by(|a, b| a.0.total_cmp(&b.0))
                        .unwrap();
                    tot[h] += best.0;
                    cs[h].push(best.1);
                }
            }
            let n = (npx * 3) as f64;
            let all: usize = cells.values().map(|v| v.len()).sum();
            println!("  sheen: {} cells hold {all} floor px", cells.len());
            println!(
                "  sheen: {ncell} floor cells, {npx} px; L1 with GT material, c = 1: {:.5}",
                tot[hyp.len()] / n
            );
            for (h, (k, r0)) in hyp.iter().enumerate() {
                cs[h].sort_by(f32::total_cmp);
                println!(
                    "    Ks {} rho {}: best-c L1 {:.5}, median c {:.3}",
                    if *k < 0.0 { "GT".to_string() } else { format!("{k}") },
                    if *r0 < 0.0 { "GT".to_string() } else { format!("{r0}") },
                    tot[h] / n,
                    cs[h][cs[h].len() / 2]
                );
            }
        }
        // GLOSSY_LIVE=N: the GT materials of (up to 4000) glossy pixels shaded from N samples
        // of their own GGX mixture (the live proposal): is the cache's floor noise or bias?
        if let Some(nl) = std::env::var("GLOSSY_LIVE").ok().and_then(|v| v.parse::<usize>().ok()) {
            use i2sdf_train::stage2::shading::{shade, shade_pooled as pooled, trace_incident};
            use rand::SeedableRng;
            let sel: Vec<_> = glossy_px.iter().step_by((glossy_px.len() / 4000).max(1)).collect();
            let frozen = stage.frozen();
            let pts: Vec<_> = sel.iter().map(|g| g.0).collect();
            let mut rngs: Vec<rand_pcg::Pcg32> = (0..pts.len())
                .map(|i| rand_pcg::Pcg32::seed_from_u64(i as u64 + 99))
                .collect();
            let em = &stage.fields.emitters;
            let live = trace_incident(
                &frozen,
                &pts,
                nl,
                stage.scene.normalization.scale as f32,
                &|j| i2sdf_train::stage2::live_mixture(&sel[j].2, em, true),
                &mut rngs,
            );
            let (mut l_full, mut l_pool, mut l_cache) = (0.0f64, 0.0f64, 0.0f64);
            let mut r_full = Vec::new();
            for (j, g) in sel.iter().enumerate() {
                let s = &live[j * nl..(j + 1) * nl];
                let nv = g.0.normal.dot(g.0.view);
                let full = shade(&g.2, nv, s, &emission);
                l_full += (full - g.1).abs().element_sum() as f64 / 3.0;
                r_full.push(full.element_sum() / g.1.element_sum().max(1e-4));
                if let Some(d) = stage.cache.diffuse.get(g.3) {
                    l_pool += (pooled(&g.2, nv, s, &emission, d) - g.1).abs().element_sum() as f64 / 3.0;
                }
                l_cache += (stage.cache.shade(g.3, &g.2, nv, &emission) - g.1).abs().element_sum() as f64 / 3.0;
            }
            r_full.sort_by(f32::total_cmp);
            let q = |f: f64| r_full[((r_full.len() - 1) as f64 * f) as usize];
            let k = sel.len() as f64;
            println!(
                "  glossy GT materials, {} px, live N={nl}: L1 {:.4} (ratio p10 {:.2} p50 {:.2} p90 {:.2}); pooled diffuse + live specular {:.4}; cache {:.4}",
                sel.len(),
                l_full / k,
                q(0.1),
                q(0.5),
                q(0.9),
                l_pool / k,
                l_cache / k
            );
        }
        ratio.sort_by(f32::total_cmp);
        let q = |f: f64| ratio[((ratio.len() - 1) as f64 * f) as usize];
        println!(
            "GT materials on the cache: re-render L1 {:.4} (relative {:.1} %), pred/target ratio p10 {:.2} p50 {:.2} p90 {:.2}",
            l1 / n,
            100.0 * l1_rel / n,
            q(0.1),
            q(0.5),
            q(0.9)
        );
    }
    // EST=1: L[k] from the shading (`emission_from_shading`), printed against the GT; with
    // EST=hold every variant starts there (hold it with a tiny stage2.lr_emission).
    let mut estimated: Option<Vec<Vec3>> = None;
    if let Ok(mode) = std::env::var("EST") {
        use i2sdf_train::stage2::emission_from_shading::{
            estimate_emission, neighbour_pairs, ShadedPixel, ShadingEstimate,
        };
        use i2sdf_train::stage2::PixelKind;
        let t = Instant::now();
        let (mut px, mut sums) = (Vec::new(), Vec::new());
        for p in &stage.pixels {
            if let PixelKind::Surface { index } = p.kind {
                px.push(ShadedPixel::of(p));
                sums.push(stage.cache.diffuse[index as usize].clone());
            }
        }
        let widths: Vec<usize> = dataset.split(Split::Train).map(|f| f.camera.width).collect();
        // EST_DUMP=FILE: the estimator's inputs as little-endian f32 rows (position, normal,
        // target, field, emit[K], view, pixel, saturated), for the `emission_probe` example.
        if let Ok(path) = std::env::var("EST_DUMP") {
            let mut raw: Vec<f32> = vec![px.len() as f32, stage.emissions().len() as f32, widths[0] as f32];
            for e in stage.emissions() {
                raw.extend(e.to_array());
            }
            for (p, d) in px.iter().zip(&sums) {
                raw.extend(p.position.to_array());
                raw.extend(p.normal.to_array());
                raw.extend(p.target.to_array());
                raw.extend(d.field.to_array());
                raw.extend(&d.emit);
                raw.extend([p.view as f32, p.pixel as f32, p.saturated as f32]);
            }
            std::fs::write(path, raw.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>())?;
        }
        let s = ShadingEstimate::default();
        let pairs = neighbour_pairs(&px, &widths, &s);
        let bound = stage.emissions();
        let est = estimate_emission(&px, &sums, &pairs, &bound, &vec![true; bound.len()], &s);
        let exposure = gt_data.radiometry.exposure.unwrap_or(1.0) as f32;
        for (k, e) in est.iter().enumerate() {
            let c = stage.fields.emitters.emitters[k].centre;
            let gt = gt_data.emitters.iter().min_by(|a, b| {
                let d = |g: &i2sdf_data::GtEmitter| {
                    let m = (glam::DVec3::from_array(g.bounds_min) + glam::DVec3::from_array(g.bounds_max)) * 0.5;
                    (m - glam::DVec3::from_array(c)).length()
                };
                d(a).total_cmp(&d(b))
            });
            let want = gt.map(|g| glam::DVec3::from_array(g.emission).as_vec3() * exposure);
            println!(
                "estimated L{k} {:.3}/{:.3}/{:.3} (bound {:.3}/{:.3}/{:.3}), GT {:?}, ratio {:?}",
                e.x,
                e.y,
                e.z,
                bound[k].x,
                bound[k].y,
                bound[k].z,
                want,
                want.map(|w| *e / w)
            );
        }
        println!(
            "  {} pixels, {} pairs, {:.1} s",
            px.len(),
            pairs.len(),
            t.elapsed().as_secs_f64()
        );
        if mode == "hold" {
            estimated = Some(est);
        }
    }
    // Test pixels: cast once.
    let test: Vec<_> = gt_data.split(Split::Test).collect();
    let mut rays = Vec::new();
    let mut gt = Vec::new();
    for f in &test {
        let g = f.camera.ray_generator();
        let (Some(kd), Some(ks), Some(r)) = (&f.albedo, &f.specular, &f.roughness) else {
            continue;
        };
        for p in 0..f.pixel_count() {
            if f.emitter_mask.as_ref().is_some_and(|m| m.data[p] > 0.5) {
                continue;
            }
            let (x, y) = (p % f.camera.width, p / f.camera.width);
            rays.push(Ray::new(
                g.origin,
                g.dir(x as f32 + 0.5, y as f32 + 0.5),
                0.0,
                f32::INFINITY,
            ));
            gt.push((
                Vec3::from_slice(&kd.data[p * 3..p * 3 + 3]),
                Vec3::from_slice(&ks.data[p * 3..p * 3 + 3]),
                r.data[p],
            ));
        }
    }
    let mut hits: Vec<Option<LabelledHit>> = vec![None; rays.len()];
    {
        let frozen = FrozenScene::new(&stage.scene, &stage.fields.emitters, stage.fields.radiometry);
        frozen.cast(&rays, &mut hits);
    }
    let idx: Vec<usize> = (0..hits.len()).filter(|&i| hits[i].is_some()).collect();
    let world: Vec<Vec3> = idx.iter().map(|&i| hits[i].unwrap().position).collect();
    let exposure = gt_data.radiometry.exposure.unwrap_or(1.0) as f32;
    // SEGMENT_SELECT=1: each variant's training-pixel L1 and test-pixel materials, for the
    // per-material selection after the last variant.
    let select = std::env::var("SEGMENT_SELECT").is_ok();
    let mut kept: Vec<(
        Vec<f32>,
        Vec<f32>,
        Vec<[f32; i2sdf_train::stage2::lobe_choice::FEATURES]>,
    )> = Vec::new();
    for (vi, sets) in variants.iter().enumerate() {
        let config = config_of(sets)?;
        if vi > 0 {
            stage.restart(config.clone());
        }
        // SET_L="r,g,b;r,g,b": start each L[k] there (with a tiny stage2.lr_emission: held).
        if let Ok(v) = std::env::var("SET_L") {
            for (k, e) in v.split(';').enumerate() {
                for (c, x) in e.split(',').enumerate() {
                    stage.fields.emitters.log_emission[k * 3 + c] = x.parse::<f32>()?.ln();
                }
            }
        }
        if let Some(est) = &estimated {
            for (k, e) in est.iter().enumerate() {
                for c in 0..3 {
                    stage.fields.emitters.log_emission[k * 3 + c] = e[c].ln();
                }
            }
        }
        let t = Instant::now();
        let mut trainer = Trainer::new(stage);
        let trace = std::env::var("TRACE").is_ok();
        let mut it = 0;
        while !trainer.done() {
            trainer.step()?;
            it += 1;
            // TRACE=1: the emissions and the loss terms every 100 iterations.
            if trace && it % 100 == 0 {
                let l: Vec<String> = trainer
                    .stage
                    .emissions()
                    .iter()
                    .map(|e| format!("{:.3}/{:.3}/{:.3}", e.x, e.y, e.z))
                    .collect();
                println!("    it {it}: L {}", l.join(", "));
            }
        }
        stage = trainer.stage;
        let secs = t.elapsed().as_secs_f64();
        // Materials at the test pixels.
        let m = stage.materials_at(&world);
        let (mut se, mut cnt, mut rl1, mut ksl1) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        let (mut pg, mut pp) = ([0.0f64; 3], [0.0f64; 3]);
        let mut glossy = [[0.0f64; 6]; 3];
        for (j, &i) in idx.iter().enumerate() {
            let (kd, ks, r) = gt[i];
            let o = &m[j * MATERIAL_CHANNELS..(j + 1) * MATERIAL_CHANNELS];
            for c in 0..3 {
                se += ((o[c] - kd[c]) as f64).powi(2);
                pg[c] += (o[c] * kd[c]) as f64;
                pp[c] += (o[c] * o[c]) as f64;
                ksl1 += (o[3 + c] - ks[c]).abs() as f64 / 3.0;
            }
            cnt += 3.0;
            rl1 += (o[6] - r).abs() as f64;
            // Glossy (GT Ks > 0.2) against the rest: is ρ learnt where it is identifiable?
            // 2: weak dielectric sheens (GT Ks 0.015–0.1, the floors).
            let mks = ks.element_sum() / 3.0;
            let g = &mut glossy[if mks > 0.2 {
                1
            } else if (0.015..0.1).contains(&mks) {
                2
            } else {
                0
            }];
            g[0] += 1.0;
            g[1] += (0..3).map(|c| ((o[c] - kd[c]) as f64).powi(2)).sum::<f64>() / 3.0;
            g[2] += o[6] as f64;
            g[3] += r as f64;
            g[4] += (o[3] + o[4] + o[5]) as f64 / 3.0;
            g[5] += ks.element_sum() as f64 / 3.0;
        }
        let s: Vec<f64> = (0..3).map(|c| pg[c] / pp[c].max(1e-12)).collect();
        let mut se2 = 0.0;
        for (j, &i) in idx.iter().enumerate() {
            for c in 0..3 {
                se2 += (m[j * MATERIAL_CHANNELS + c] as f64 * s[c] - gt[i].0[c] as f64).powi(2);
            }
        }
        let px = idx.len() as f64;
        let em: Vec<String> = (0..stage.fields.emitters.len())
            .map(|k| {
                let l = stage.fields.emitters.emission(k);
                let c = stage.fields.emitters.emitters[k].centre;
                let gt = gt_data.emitters.iter().min_by(|a, b| {
                    let d = |e: &i2sdf_data::GtEmitter| {
                        (0..3)
                            .map(|i| ((e.bounds_min[i] + e.bounds_max[i]) / 2.0 - c[i]).powi(2))
                            .sum::<f64>()
                    };
                    d(a).total_cmp(&d(b))
                });
                match gt {
                    Some(g) => format!(
                        "L{k} {:.2}/{:.2}/{:.2} ({} ×{:.3})",
                        l.x,
                        l.y,
                        l.z,
                        g.name,
                        (l.x + l.y + l.z) / (exposure * (g.emission[0] + g.emission[1] + g.emission[2]) as f32)
                    ),
                    None => format!("L{k} {:.2}/{:.2}/{:.2}", l.x, l.y, l.z),
                }
            })
            .collect();
        println!(
            "[{}] {} its {:.1} s: Kd PSNR {:.2} (scaled {:.2}, s = {:.2}/{:.2}/{:.2}), rough L1 {:.3}, Ks L1 {:.3}; {}",
            sets.join(" "),
            stage.iteration(),
            secs,
            psnr_from_mse(se / cnt),
            psnr_from_mse(se2 / cnt),
            s[0],
            s[1],
            s[2],
            rl1 / px,
            ksl1 / px,
            em.join(", ")
        );
        // The fitted materials on the training pixels' cache: L1 against the targets, matte and
        // glossy (GT Ks > 0.2), to set beside the GT materials' L1 on the same pixels (above).
        {
            use i2sdf_train::stage2::PixelKind;
            let train: Vec<_> = gt_data.split(Split::Train).collect();
            let emission = stage.emissions();
            let surf: Vec<usize> = (0..stage.pixels.len())
                .filter(|&i| matches!(stage.pixels[i].kind, PixelKind::Surface { .. }))
                .collect();
            let w: Vec<Vec3> = surf.iter().map(|&i| stage.pixels[i].point.position).collect();
            let mo = stage.materials_at(&w);
            let mut acc = [[0.0f64; 2]; 2];
            for (j, &i) in surf.iter().enumerate() {
                let px = &stage.pixels[i];
                let PixelKind::Surface { index } = px.kind else {
                    continue;
                };
                let fr = train[px.view as usize];
                let Some(ks) = &fr.specular else { continue };
                let o = &mo[j * MATERIAL_CHANNELS..(j + 1) * MATERIAL_CHANNELS];
                let brdf = brdf_of_channels(o);
                let nv = px.point.normal.dot(px.point.view);
                let pred = stage.cache.shade(index as usize, &brdf, nv, &emission);
                let g = (ks.data[px.pixel as usize * 3] > 0.2) as usize;
                acc[g][0] += (pred - px.target).abs().element_sum() as f64 / 3.0;
                acc[g][1] += 1.0;
            }
            println!(
                "    fitted materials on the cache: L1 matte {:.4}, glossy {:.4} ({} px)",
                acc[0][0] / acc[0][1].max(1.0),
                acc[1][0] / acc[1][1].max(1.0),
                acc[1][1]
            );
        }
        if select {
            let (l1, feat) = segments::training_l1(&stage);
            kept.push((l1, m.clone(), feat));
        }
        // SEGMENT_FIT=1: after the fit, the floor's pixels pooled: does a shared (Ks, ρ) with the
        // fitted Kd decide the sheen?
        if std::env::var("SEGMENT_FIT").is_ok() {
            segments::segment_fit(&stage, &gt_data)?;
        }
        for (name, g) in ["matte", "glossy", "sheen"].iter().zip(&glossy) {
            let n = g[0].max(1.0);
            println!(
                "    {name} (GT Ks {}): {} px, Kd PSNR {:.2}, rho {:.3} (GT {:.3}), Ks {:.3} (GT {:.3})",
                match *name {
                    "glossy" => "> 0.2",
                    "sheen" => "0.015–0.1",
                    _ => "other",
                },
                g[0],
                psnr_from_mse(g[1] / n),
                g[2] / n,
                g[3] / n,
                g[4] / n,
                g[5] / n
            );
        }
    }
    if select {
        let test_gt: Vec<_> = idx.iter().map(|&i| gt[i]).collect();
        let test_normal: Vec<Vec3> = idx.iter().map(|&i| hits[i].unwrap().normal).collect();
        segments::segment_select(&stage, &gt_data, &kept, &test_gt, &test_normal, &world);
    }
    Ok(())
}

fn tempfile_dir() -> std::io::Result<std::path::PathBuf> {
    let d = std::env::temp_dir().join(format!("stage2_ablation_{}", std::process::id()));
    std::fs::create_dir_all(&d)?;
    Ok(d)
}
