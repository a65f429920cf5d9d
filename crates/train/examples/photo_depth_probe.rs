//! The photometric depth of `i2sdf_data::photo_depth` against a capture's truth. Per thin,
//! suspended or small object of the scene (its `scene.toml`): the training pixels that see it
//! (true depth within 1 cm of its surface), how many of them got a depth from the images, and how
//! many of those depths lie within 2 cm of its surface. Over all pixels given a depth: how close
//! it is to the true depth. Made for `docs/results.md`:
//! `cargo run --release -p i2sdf-train --example photo_depth_probe -- CAP [true | run=RUN] [key=value …]` on a room
//! written by `i2sdf synth --capture` (its `depth_gt/` maps and `poses_true.json`; `true`: sweep
//! with the true poses instead of the perturbed ones, to see what the pose noise costs; `per_shape`:
//! each shape on its own line, a table's legs apart; `key=value`: a `PhotoDepthParams` field, the
//! edge support's included; `VIS=DIR` in the environment writes each view with its depths found
//! coloured by their distance to the true surface; `field=RUN`: render each depth found with that
//! run's stage-1 field — a checkpoint taken just before its own sweep, `train.checkpoint_every` —
//! and print how the render tells halos from the depths that are right, with `explained=TAU` and
//! `explained_ratio=R` to drop the ones `maps.photo_depth_explained` would).
use glam::DMat4;
use i2sdf_data::{imageio, photo_depth, Camera, Split};
use i2sdf_synth::scene::SceneDesc;
use std::path::Path;

fn mat(v: &serde_json::Value) -> DMat4 {
    let r: Vec<Vec<f64>> = serde_json::from_value(v.clone()).unwrap();
    DMat4::from_cols_array_2d(&[
        [r[0][0], r[1][0], r[2][0], r[3][0]],
        [r[0][1], r[1][1], r[2][1], r[3][1]],
        [r[0][2], r[1][2], r[2][2], r[3][2]],
        [r[0][3], r[1][3], r[2][3], r[3][3]],
    ])
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().collect();
    let dir = Path::new(a.get(1).ok_or("usage: photo_depth_probe CAP [true]")?);
    let use_true = a.iter().any(|s| s == "true");
    // `per_shape`: each shape of an object on its own line (a table's four legs apart).
    let per_shape = a.iter().any(|s| s == "per_shape");
    let run = a.iter().find_map(|s| s.strip_prefix("run="));
    let mut params = photo_depth::PhotoDepthParams::default();
    for kv in a.iter().skip(2).filter_map(|s| s.split_once('=')) {
        match kv.0 {
            "neighbours" => params.neighbours = kv.1.parse()?,
            "steps" => params.steps = kv.1.parse()?,
            "near_fraction" => params.near_fraction = kv.1.parse()?,
            "min_gap" => params.min_gap = kv.1.parse()?,
            "background_radius_cells" => params.background_radius_cells = kv.1.parse()?,
            "background_explains" => params.background_explains = kv.1.parse()?,
            "max_cost" => params.max_cost = kv.1.parse()?,
            "min_ratio" => params.min_ratio = kv.1.parse()?,
            "uniqueness" => params.uniqueness = kv.1.parse()?,
            "min_views" => params.min_views = kv.1.parse()?,
            "see_through_radius" => params.see_through_radius = kv.1.parse()?,
            "consistency" => params.consistency = kv.1.parse()?,
            "min_agreeing" => params.min_agreeing = kv.1.parse()?,
            "min_baseline" => params.min_baseline = kv.1.parse()?,
            "full_baseline" => params.full_baseline = kv.1.parse()?,
            "slack" => params.slack = kv.1.parse()?,
            "in_front" => params.in_front = kv.1.parse()?,
            "edge_min_support" => params.edge_min_support = kv.1.parse()?,
            "edge_steps" => params.edge_steps = kv.1.parse()?,
            "edge_window" => params.edge_window = kv.1.parse()?,
            "edge_seen_through" => params.edge_seen_through = kv.1.parse()?,
            "edge_contrast" => params.edge_contrast = kv.1.parse()?,
            "edge_min_ratio" => params.edge_min_ratio = kv.1.parse()?,
            "edge_through_weight" => params.edge_through_weight = kv.1.parse()?,
            "edge_clear_radius" => params.edge_clear_radius = kv.1.parse()?,
            "edge_clear_depth" => params.edge_clear_depth = kv.1.parse()?,
            "edge_clear_count" => params.edge_clear_count = kv.1.parse()?,
            "run" | "field" | "explained" | "explained_ratio" => {}
            k => return Err(format!("unknown parameter {k}").into()),
        }
    }
    let desc = SceneDesc::read(&dir.join("scene.toml"))?;
    let mut ds = i2sdf_data::load(dir)?;
    let tf: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("transforms.json"))?)?;
    let truth: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("poses_true.json"))?)?;
    let (mut gt, mut true_cams) = (Vec::new(), Vec::new());
    for f in ds.frames.iter_mut() {
        let entry = tf["frames"]
            .as_array()
            .ok_or("frames")?
            .iter()
            .find(|e| dir.join(e["file_path"].as_str().unwrap_or("")) == f.image_path)
            .ok_or("frame not in transforms.json")?;
        gt.push(imageio::read_float_map(
            &dir.join(entry["depth_gt_file_path"].as_str().ok_or("depth_gt")?),
        )?);
        let c = &f.camera;
        let m = mat(&truth["transform_matrix"][entry["file_path"].as_str().unwrap_or("")]);
        let true_cam = Camera {
            lens: c.lens.clone(),
            ..Camera::from_opengl_c2w(c.width, c.height, c.fx, c.fy, c.cx, c.cy, m)
        };
        if use_true {
            f.camera = true_cam.clone();
        }
        true_cams.push(true_cam);
    }
    if let Some(run) = run {
        // The poses a stage-1 run corrected, as stage 2 and render use them.
        i2sdf_model::poses::with_corrected_poses(&i2sdf_model::RunDir::new(Path::new(run)), &mut ds)?;
    }
    // The thin, suspended and small shapes, grouped by object.
    let mut groups = desc.solid_shapes_tagged(&["thin", "suspended", "small"]);
    if per_shape {
        groups = groups
            .into_iter()
            .flat_map(|(_, shapes)| shapes.into_iter().map(|s| (desc.shapes[s].name.clone(), vec![s])))
            .collect();
    }
    // Every object with a solid shape, for where the depths found off any true surface come from.
    let furniture = desc.solid_shapes_tagged(&["furniture", "room", "thin", "suspended", "small"]);
    let mut on_furniture = vec![(0usize, 0usize); furniture.len()];
    let dist = |g: &[usize], p: glam::DVec3| {
        g.iter()
            .filter_map(|&s| desc.shapes[s].geometry.distance(p.as_vec3()))
            .map(f32::abs)
            .fold(f32::INFINITY, f32::min)
    };
    let train: Vec<usize> = (0..ds.frames.len())
        .filter(|&i| ds.frames[i].split == Split::Train)
        .collect();
    let refs: Vec<_> = train.iter().map(|&i| &ds.frames[i]).collect();
    let photo_views: Vec<_> = refs
        .iter()
        .map(|f| photo_depth::PhotoView::of(f).ok_or("a view without depth"))
        .collect::<Result<_, _>>()?;
    let views: Vec<usize> = (0..refs.len()).collect();
    // The true surface, densely sampled (a point every ~3 mm), for the distance of each depth found.
    let gt_mesh = i2sdf_data::ply::read_ground_truth(dir.join("mesh.ply"))?;
    let cloud = i2sdf_data::paper_write::sample_surface(&gt_mesh, 1e5);
    let tree = i2sdf_data::KdTree::new(&cloud.positions);
    let t0 = std::time::Instant::now();
    let mut found = photo_depth::photo_depth(&photo_views, &views, &params);
    let sweep_s = t0.elapsed().as_secs_f64();
    // `field=RUN`: render each depth found with that run's field (a stage-1 checkpoint taken just
    // before its own sweep) and show how its render separates halos from thin objects; with
    // `explained=TAU` (and `explained_ratio=R`, default stage 1's `EXPLAINED_RATIO`) drop the
    // depths whose render lies over R times as far and matches the pixel's colour within TAU.
    if let Some(fr) = a.iter().find_map(|s| s.strip_prefix("field=")) {
        let arg = |k: &str| a.iter().find_map(|s| s.strip_prefix(k)).map(|v| v.parse::<f32>());
        let tau = arg("explained=").transpose()?;
        let ratio_min = arg("explained_ratio=")
            .transpose()?
            .unwrap_or(i2sdf_train::stage1::photo_depth::EXPLAINED_RATIO);
        let (scene, _) = i2sdf_model::NeuralScene::load(&Path::new(fr).join("checkpoint.safetensors"))?;
        let cfg = i2sdf_train::config::TrainConfig::load(Some(&Path::new(fr).join("config.toml")), &[])?;
        let settings = i2sdf_train::stage1::render_settings(&cfg);
        let scale = scene.normalization.scale;
        // Per class (halo: the pixel's truth over 5 cm behind; good: within 2 cm; other): (ratio, err).
        let mut classes: [Vec<(f32, f32)>; 3] = Default::default();
        let mut dropped = [0usize; 3];
        for (k, pd) in found.iter_mut().enumerate() {
            let Some(pd) = pd else { continue };
            let f = refs[k];
            let im = i2sdf_train::stage1::rays::TrainImage::new(train[k], f, &scene.normalization, None, None);
            let px: Vec<usize> = (0..f.pixel_count()).filter(|&p| pd.depth.data[p] > 0.0).collect();
            let t: Vec<f32> = px
                .iter()
                .map(|&p| (pd.depth.data[p] as f64 / im.cos[p] as f64 / scale) as f32)
                .collect();
            let r = i2sdf_train::stage1::photo_depth::field_render_at(&scene, &settings, &im, &px, &t);
            for (&p, &(ratio, err)) in px.iter().zip(&r) {
                let (z, zf) = (gt[train[k]].data[p], pd.depth.data[p]);
                let c = if z > zf + 0.05 {
                    0
                } else if (z - zf).abs() < 0.02 {
                    1
                } else {
                    2
                };
                classes[c].push((ratio, err));
                if tau.is_some_and(|tau| i2sdf_train::stage1::photo_depth::is_explained(ratio, err, ratio_min, tau)) {
                    pd.depth.data[p] = 0.0;
                    dropped[c] += 1;
                }
            }
        }
        for (name, v) in ["halo (truth > 5 cm behind)", "good (within 2 cm)", "other"]
            .iter()
            .zip(&classes)
        {
            let q = |f: fn(&(f32, f32)) -> f32, x: f64| {
                let mut s: Vec<f32> = v.iter().map(f).collect();
                s.sort_by(f32::total_cmp);
                s.get(((s.len().max(1) - 1) as f64 * x) as usize)
                    .copied()
                    .unwrap_or(f32::NAN)
            };
            println!(
                "{name:28} {:5}: render/found depth 10/50/90 % {:.2} {:.2} {:.2}; colour error {:.3} {:.3} {:.3}",
                v.len(),
                q(|x| x.0, 0.1),
                q(|x| x.0, 0.5),
                q(|x| x.0, 0.9),
                q(|x| x.1, 0.1),
                q(|x| x.1, 0.5),
                q(|x| x.1, 0.9)
            );
        }
        println!("explained and dropped (halo, good, other): {dropped:?}");
    }
    println!(
        "poses: {}; sweep {:.1} s",
        if use_true {
            "true"
        } else if run.is_some() {
            "the run's"
        } else {
            "as given"
        },
        sweep_s
    );
    // Per group: pixels seeing it, given a depth, within 2 cm of it.
    let mut per_group = vec![(0usize, 0usize, 0usize); groups.len()];
    let mut outcomes = vec![[0usize; 12]; groups.len()];
    // Per group, depths found at an edge more than 2 cm behind / in front of the pixel's truth.
    let mut sign = vec![(0usize, 0usize); groups.len()];
    // Per group, halo depths (by colour, at an edge): pixels whose ray passes the object by (its
    // true depth over 5 cm behind) but whose depth found lies within 2 cm of the object's surface:
    // the object inflated by them.
    let mut halo = vec![(0usize, 0usize); groups.len()];
    let (mut swept, mut errs, mut surf) = (0, Vec::new(), Vec::new());
    for (k, pd) in found.iter().enumerate() {
        let Some(pd) = pd else { continue };
        swept += pd.swept;
        let (f, g_depth, tcam) = (refs[k], &gt[train[k]], &true_cams[train[k]]);
        let w = f.camera.width;
        // `VIS=DIR`: each view's image in grey, a depth found within 2 cm of a true surface in
        // green, within 5 cm in yellow, farther in red; by colour dim, at an edge bright.
        let mut vis = std::env::var("VIS").ok().map(|_| {
            let mut im = f.rgb.clone();
            for px in im.data.chunks_mut(3) {
                let g = (px[0] + px[1] + px[2]) / 3.0 * 0.6;
                px.copy_from_slice(&[g, g, g]);
            }
            im
        });
        for p in 0..f.pixel_count() {
            let (x, y) = (p % w, p / w);
            let z = g_depth.data[p];
            let zf = pd.depth.data[p];
            if zf > 0.0 && z > 0.0 {
                errs.push((zf - z).abs());
                // Off any true surface, with the pose the sweep used (as stage 1 would place it).
                let at = f.camera.backproject(x, y, zf as f64).as_vec3();
                let off = tree.nearest_distance(at.to_array());
                surf.push(off);
                if let Some(im) = vis.as_mut() {
                    let b = if pd.outcome[p] == 10 { 1.0 } else { 0.5 };
                    let c = if z > zf + 0.05 {
                        // The pixel's ray passes the point by: a halo.
                        [b, 0.0, b]
                    } else if off < 0.02 {
                        [0.0, b, 0.0]
                    } else if off < 0.05 {
                        [b, b, 0.0]
                    } else {
                        [b, 0.0, 0.0]
                    };
                    im.pixel_mut(x, y).copy_from_slice(&c);
                }
                let seen = tcam.backproject(x, y, z as f64);
                if let Some(fi) = furniture.iter().position(|(_, shapes)| dist(shapes, seen) < 0.01) {
                    on_furniture[fi].0 += 1;
                    on_furniture[fi].1 += (off > 0.05) as usize;
                }
            }
            if z <= 0.0 {
                continue;
            }
            let seen = tcam.backproject(x, y, z as f64);
            for (gi, (_, shapes)) in groups.iter().enumerate() {
                if zf > 0.0 && z > zf + 0.05 && dist(shapes, seen) >= 0.01 {
                    let at = f.camera.backproject(x, y, zf as f64);
                    if dist(shapes, at) < 0.02 {
                        if pd.outcome[p] == 10 {
                            halo[gi].1 += 1;
                        } else {
                            halo[gi].0 += 1;
                        }
                    }
                }
                if dist(shapes, seen) < 0.01 {
                    per_group[gi].0 += 1;
                    outcomes[gi][pd.outcome[p] as usize] += 1;
                    if zf > 0.0 {
                        per_group[gi].1 += 1;
                        let at = f.camera.backproject(x, y, zf as f64);
                        per_group[gi].2 += (dist(shapes, at) < 0.02) as usize;
                        if pd.outcome[p] == 10 {
                            sign[gi].0 += (zf > z + 0.02) as usize;
                            sign[gi].1 += (zf < z - 0.02) as usize;
                        }
                    }
                }
            }
        }
        if let (Some(im), Ok(d)) = (vis.as_ref(), std::env::var("VIS")) {
            imageio::write_png(&Path::new(&d).join(format!("{k:04}.png")), im)?;
        }
    }
    errs.sort_by(f32::total_cmp);
    if let Ok(d) = std::env::var("VIS") {
        println!("(images written to {d})");
    }
    let q = |x: f64| {
        errs.get(((errs.len().max(1) - 1) as f64 * x) as usize)
            .copied()
            .unwrap_or(f32::NAN)
    };
    let n = errs.len();
    let within = |t: f32| errs.iter().filter(|e| **e < t).count();
    println!(
        "swept {swept}, given a depth {n}: within 2 cm {}, 5 cm {}, 10 cm {}; |error| median {:.3} m, 75th {:.3}, 90th {:.3}",
        within(0.02),
        within(0.05),
        within(0.1),
        q(0.5),
        q(0.75),
        q(0.9)
    );
    let mut worst: Vec<(usize, usize, &str)> = furniture
        .iter()
        .zip(&on_furniture)
        .filter(|(_, c)| c.0 > 0)
        .map(|((name, _), c)| (c.1, c.0, name.as_str()))
        .collect();
    worst.sort_by(|a, b| b.cmp(a));
    for (off, n, name) in worst {
        println!("{name:24} depths found on its pixels {n:5}, over 5 cm off any true surface {off:5}");
    }
    println!("outcomes: sensed, no background, too few views, background explains, cost too high, ratio too low, not unique, seen through, unconfirmed, found, found at an edge, cleared");
    surf.sort_by(f32::total_cmp);
    let near = |t: f32| surf.iter().filter(|e| **e < t).count();
    println!(
        "off the true surface: within 1 cm {}, 2 cm {}, 5 cm {}; median {:.3} m, 90th {:.3}",
        near(0.01),
        near(0.02),
        near(0.05),
        surf[surf.len() / 2],
        surf[surf.len() * 9 / 10]
    );
    for (gi, (((name, _), (seen, given, near)), o)) in groups.iter().zip(&per_group).zip(&outcomes).enumerate() {
        println!("{name:24} pixels {seen:6}  given a depth {given:5}  within 2 cm of it {near:5}  {o:?}  at edges behind / in front {:?}  halo (colour, edge) {:?}", sign[gi], halo[gi]);
    }
    Ok(())
}
