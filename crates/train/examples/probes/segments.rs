//! `stage2_ablation`'s probes of a per-material specular: the floor's pixels pooled under a
//! shared (Ks, ρ) (`SEGMENT_FIT=1`), and each material segment taking the variant whose fit
//! explains its training pixels best (`SEGMENT_SELECT=1`).

use glam::Vec3;
use i2sdf_data::Split;
use i2sdf_eval::image_metrics::psnr_from_mse;
use i2sdf_model::material_field::{brdf_of_channels, MATERIAL_CHANNELS};
use i2sdf_render::GgxBrdf;
use i2sdf_train::stage2::lobe_choice::{feature, kmeans, nearest, FEATURES};
use i2sdf_train::stage2::{CachedPixel, PixelKind, Stage2};

/// The cached training pixels on the default room's floor sheen (GT Ks 0.03–0.05, ρ 0.45–0.55,
/// unsaturated): each with its cache index and its true material.
pub fn sheen_pixels<'a>(stage: &'a Stage2, train: &[&i2sdf_data::Frame]) -> Vec<(&'a CachedPixel, usize, GgxBrdf)> {
    let mut out = Vec::new();
    for px in &stage.pixels {
        let PixelKind::Surface { index } = px.kind else {
            continue;
        };
        let fr = train[px.view as usize];
        let (Some(kd), Some(ks), Some(r)) = (&fr.albedo, &fr.specular, &fr.roughness) else {
            continue;
        };
        let p = px.pixel as usize;
        if (0.03..0.05).contains(&ks.data[p * 3]) && (0.45..0.55).contains(&r.data[p]) && px.saturated == 0 {
            let gt = GgxBrdf::new(
                Vec3::from_slice(&kd.data[p * 3..p * 3 + 3]),
                Vec3::from_slice(&ks.data[p * 3..p * 3 + 3]),
                r.data[p],
            );
            out.push((px, index as usize, gt));
        }
    }
    out
}

/// The fitted materials' L1 (mean over RGB) on every cached surface pixel, in cache order, and
/// each pixel's segmentation feature ([`feature`]): what stage 2's lobe choice scores.
pub fn training_l1(stage: &Stage2) -> (Vec<f32>, Vec<[f32; FEATURES]>) {
    let (l1, m) = stage.surface_scores();
    let features = stage.surface_features(&m);
    (l1, features)
}

/// Choosing the specular per material segment: each segment takes one variant's fit by the mean
/// L1 of each fit on its cached training pixels, and its test pixels take that fit's materials.
/// The first variant is the defaults; the others are meant as lobes forced narrow to wide, the
/// last the widest (see the rules in the body). Segmentations: the TRUE material classes (Ks
/// luminance to 0.01, ρ to 0.05: an oracle, the upper bound) and k-means of the first fit's
/// [`feature`]s for each k of `SEGMENTS` (default "16 32 64 128") and each shuffle seed of
/// `SEGMENT_SEED` (default "0"), what a method can do. Prints the composite's Kd PSNR and
/// roughness L1 on the test pixels for each rule and margin, and each segment's L1s (k-means
/// ones with `SEGMENT_VERBOSE`).
pub fn segment_select(
    stage: &Stage2,
    gt_data: &i2sdf_data::Dataset,
    kept: &[(Vec<f32>, Vec<f32>, Vec<[f32; FEATURES]>)],
    test_gt: &[(Vec3, Vec3, f32)],
    test_normal: &[Vec3],
    test_world: &[Vec3],
) {
    let class = |ks: f32, r: f32| ((ks * 100.0).round() as i32, (r * 20.0).round() as i32);
    let train: Vec<_> = gt_data.split(Split::Train).collect();
    let oracle_train: Vec<(i32, i32)> = stage
        .pixels
        .iter()
        .filter(|p| matches!(p.kind, PixelKind::Surface { .. }))
        .map(|px| {
            let fr = train[px.view as usize];
            match (&fr.specular, &fr.roughness) {
                (Some(ks), Some(r)) => {
                    let p = px.pixel as usize;
                    class(
                        (ks.data[p * 3] + ks.data[p * 3 + 1] + ks.data[p * 3 + 2]) / 3.0,
                        r.data[p],
                    )
                }
                _ => (-1, -1),
            }
        })
        .collect();
    let oracle_test: Vec<(i32, i32)> = test_gt
        .iter()
        .map(|(_, ks, r)| class(ks.element_sum() / 3.0, *r))
        .collect();
    let mut segmentations = vec![(
        "oracle classes (Ks x100, rho x20)".to_string(),
        oracle_train.clone(),
        oracle_test,
    )];
    let ks = std::env::var("SEGMENTS").unwrap_or_else(|_| "16 32 64 128".into());
    let seeds: Vec<u64> = std::env::var("SEGMENT_SEED")
        .unwrap_or_else(|_| "0".into())
        .split_whitespace()
        .filter_map(|v| v.parse().ok())
        .collect();
    let ks: Vec<usize> = ks.split_whitespace().filter_map(|v| v.parse().ok()).collect();
    for (&seed, &k) in seeds.iter().flat_map(|s| ks.iter().map(move |k| (s, k))) {
        let centres = kmeans(&kept[0].2, k, seed);
        let train: Vec<(i32, i32)> = kept[0].2.iter().map(|f| (nearest(&centres, f) as i32, 0)).collect();
        let test: Vec<(i32, i32)> = (0..test_gt.len())
            .map(|j| {
                let kd = &kept[0].1[j * MATERIAL_CHANNELS..j * MATERIAL_CHANNELS + 3];
                (
                    nearest(&centres, &feature(kd, test_normal[j], stage.normalized(test_world[j]))) as i32,
                    0,
                )
            })
            .collect();
        segmentations.push((
            format!("k-means ({k}, shuffle seed {seed}) of the fitted Kd, normal and position"),
            train,
            test,
        ));
    }
    let verbose = std::env::var("SEGMENT_VERBOSE").is_ok();
    for (name, seg_train, seg_test) in segmentations {
        // Per segment: the L1 sum of each variant, the pixel count, the true Ks and ρ sums.
        let mut sums: std::collections::BTreeMap<(i32, i32), (Vec<f64>, usize, f64, f64)> = Default::default();
        for (j, key) in seg_train.iter().enumerate() {
            let e = sums.entry(*key).or_insert_with(|| (vec![0.0; kept.len()], 0, 0.0, 0.0));
            for (v, (l1, ..)) in kept.iter().enumerate() {
                e.0[v] += l1[j] as f64;
            }
            e.1 += 1;
            e.2 += oracle_train[j].0 as f64 / 100.0;
            e.3 += oracle_train[j].1 as f64 / 20.0;
        }
        // Rule "best": a variant other than the first (the defaults) must beat it by `margin` of
        // its L1. Rule "narrow": the best of the others (forced lobes, the last the widest) must
        // beat the widest lobe by `margin` (the data ask for a narrower lobe) and be within
        // `margin` of the defaults.
        let choose = |e: &Vec<f64>, margin: f64, narrow: bool| {
            if !narrow {
                let best = (0..e.len()).min_by(|&a, &b| e[a].total_cmp(&e[b])).unwrap_or(0);
                return if e[best] < e[0] * (1.0 - margin) { best } else { 0 };
            }
            let last = e.len() - 1;
            let best = (1..e.len()).min_by(|&a, &b| e[a].total_cmp(&e[b])).unwrap_or(0);
            if best < last && e[best] < e[last] * (1.0 - margin) && e[best] < e[0] * (1.0 + margin) {
                best
            } else {
                0
            }
        };
        println!("segment selection by {name}: mean training L1 per variant (the segment's mean true Ks, rho):");
        for (key, e) in sums.iter().filter(|_| verbose || name.starts_with("oracle")) {
            let n = e.1 as f64;
            let l: Vec<String> = e.0.iter().map(|x| format!("{:.5}", x / n)).collect();
            println!(
                "  {key:?}: {} px (Ks {:.3}, rho {:.2}), L1 {} -> variant {}",
                e.1,
                e.2 / n,
                e.3 / n,
                l.join(" "),
                choose(&e.0, 0.0, false)
            );
        }
        for (narrow, margin) in [false, true]
            .into_iter()
            .flat_map(|n| [0.0, 0.005, 0.01, 0.02].map(|m| (n, m)))
        {
            let choice: std::collections::BTreeMap<(i32, i32), usize> =
                sums.iter().map(|(k, e)| (*k, choose(&e.0, margin, narrow))).collect();
            // The sheen's (true Ks 0.04, ρ 0.5: the floor) training pixels by the chosen variant.
            let mut sheen = vec![0usize; kept.len()];
            for (j, key) in seg_train.iter().enumerate() {
                if oracle_train[j] == (4, 10) {
                    sheen[choice[key]] += 1;
                }
            }
            let (mut se, mut rl1, mut ch) = (0.0f64, 0.0f64, vec![0usize; kept.len()]);
            for (j, (kd, _, r)) in test_gt.iter().enumerate() {
                let v = *choice.get(&seg_test[j]).unwrap_or(&0);
                ch[v] += 1;
                let o = &kept[v].1[j * MATERIAL_CHANNELS..(j + 1) * MATERIAL_CHANNELS];
                se += (0..3).map(|c| ((o[c] - kd[c]) as f64).powi(2)).sum::<f64>();
                rl1 += (o[6] - r).abs() as f64;
            }
            let n = test_gt.len().max(1) as f64;
            println!(
                "  {} margin {:.1} %: composite on the test pixels Kd PSNR {:.2}, rough L1 {:.3}; test pixels per variant {ch:?}, the sheen's training pixels {sheen:?}",
                if narrow { "narrow" } else { "best" },
                margin * 100.0,
                psnr_from_mse(se / (3.0 * n)),
                rl1 / n,
            );
        }
    }
}

/// The floor's cached pixels (GT Ks 0.03–0.05, ρ 0.45–0.55, unsaturated), shaded with the fitted
/// Kd times a scale c and a shared specular (Ks grey, ρ) from a grid: the L1 over all of them
/// with one c (least L1 over a grid of c), and with one c per 2 cm cell (as `SHEEN=1`: a Kd free
/// to absorb each cell's mean sheen). If the truth (0.04, 0.5) wins clearly once the floor is
/// pooled, a per-segment specular fit could find it; if not, the data do not decide it.
pub fn segment_fit(stage: &Stage2, gt_data: &i2sdf_data::Dataset) -> Result<(), Box<dyn std::error::Error>> {
    let train: Vec<_> = gt_data.split(Split::Train).collect();
    let emission = stage.emissions();
    let floor = sheen_pixels(stage, &train);
    let world: Vec<Vec3> = floor.iter().map(|(px, ..)| px.point.position).collect();
    let m = stage.materials_at(&world);
    let ks_grid = [0.0f32, 0.01, 0.02, 0.04, 0.06];
    let rho_grid = [0.3f32, 0.45, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0];
    // Per pixel: fitted Kd ⊙ diffuse sums, target, specular of each hypothesis, its cell.
    let rows: Vec<(Vec3, Vec3, Vec<Vec3>, [i32; 3], Vec3)> = floor
        .iter()
        .enumerate()
        .map(|(j, (px, i, _))| {
            let o = &m[j * MATERIAL_CHANNELS..(j + 1) * MATERIAL_CHANNELS];
            let nv = px.point.normal.dot(px.point.view);
            let kd = Vec3::from_slice(&o[..3]);
            let d = stage.cache.shade(*i, &GgxBrdf::new(kd, Vec3::ZERO, 1.0), nv, &emission);
            let spec = ks_grid
                .iter()
                .flat_map(|&k| rho_grid.iter().map(move |&r| (k, r)))
                .map(|(k, r)| {
                    stage
                        .cache
                        .shade(*i, &GgxBrdf::new(Vec3::ZERO, Vec3::splat(k), r), nv, &emission)
                })
                .collect();
            let own = stage.cache.shade(*i, &brdf_of_channels(o), nv, &emission);
            let cell = (px.point.position / 0.02).floor().as_ivec3().to_array();
            (d, px.target, spec, cell, own)
        })
        .collect();
    let mut cells: std::collections::HashMap<[i32; 3], Vec<usize>> = Default::default();
    for (j, r) in rows.iter().enumerate() {
        cells.entry(r.3).or_default().push(j);
    }
    let n = (rows.len() * 3).max(1) as f64;
    let best_c = |set: &[usize], h: usize| -> f64 {
        (0..=400)
            .map(|j| 0.6 + j as f32 * 0.002)
            .map(|c| {
                set.iter()
                    .map(|&j| (rows[j].0 * c + rows[j].2[h] - rows[j].1).abs().element_sum() as f64)
                    .sum::<f64>()
            })
            .fold(f64::INFINITY, f64::min)
    };
    let all: Vec<usize> = (0..rows.len()).collect();
    let own: f64 = rows.iter().map(|r| (r.4 - r.1).abs().element_sum() as f64).sum();
    // The true materials on the same pixels: is the fit's optimum the truth's?
    let truth: f64 = floor
        .iter()
        .zip(&rows)
        .map(|((px, i, gt), r)| {
            let nv = px.point.normal.dot(px.point.view);
            (stage.cache.shade(*i, gt, nv, &emission) - r.1).abs().element_sum() as f64
        })
        .sum();
    println!(
        "    segment fit: {} floor px in {} cells; L1 of the fit's own materials {:.5}, of the true ones {:.5}",
        rows.len(),
        cells.len(),
        own / n,
        truth / n
    );
    println!("    Ks by rho: L1 with one c | one c per cell");
    for (a, k) in ks_grid.iter().enumerate() {
        let line: Vec<String> = rho_grid
            .iter()
            .enumerate()
            .map(|(b, r)| {
                let h = a * rho_grid.len() + b;
                let per_cell: f64 = cells.values().map(|set| best_c(set, h)).sum();
                format!("{r}: {:.5} | {:.5}", best_c(&all, h) / n, per_cell / n)
            })
            .collect();
        println!("    Ks {k}: {}", line.join(", "));
    }
    Ok(())
}
