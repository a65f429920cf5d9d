//! A recovered emitter's direct light against the true one's, on a synthetic room: the light
//! sampling and first-hit test of the integrator, in the recovered surface the relit sets are
//! traced in (`RecoveredScene` at 256), against the dataset's true mesh and emitter.
//!
//! `cargo run --release -p i2sdf-edit --example bulb_power -- RUN ROOM [K]`: K is the recovered
//! emitter (default 1, the built-in rooms' bulb); its true emitter is the dataset's emitter whose
//! box is nearest, a sphere (centre and radius from its box) when it is one. Prints
//! - for a spherical true emitter, in nine directions from its centre: the direct irradiance at
//!   0.4 m, facing it, over that of the unoccluded true sphere, and where the recovered SDF's
//!   surface lies along the direction with F_e there;
//! - over the test views' pixels, the direct light at the first hit, recovered over true (each
//!   scene's own geometry and emitter, the recovered emission rescaled to the true one, so that
//!   only geometry and labels differ).
//! Used for "The bulb's light, traced" in docs/results.md.
use glam::Vec3;
use i2sdf_data::Split;
use i2sdf_edit::RecoveredScene;
use i2sdf_render::geometry::intersect_one;
use i2sdf_render::{AreaLight, Geometry, Light, MeshGeometry, Ray, SphereLight, Visibility};

/// Direct irradiance at `x` (normal `n`) from `light` in `geometry`, where a first hit counts as
/// the light's when `is_light(hit)`.
fn irradiance(
    light: &dyn Light,
    geometry: &dyn Geometry,
    is_light: &dyn Fn(&i2sdf_render::Hit) -> bool,
    x: Vec3,
    n: Vec3,
    m: usize,
) -> f32 {
    let mut e = 0.0f32;
    for s in 0..m {
        let u = [0.5, (s as f32 + 0.5) / m as f32, ((s * 7919) % m) as f32 / m as f32];
        let Some(ls) = light.sample(x, u) else { continue };
        let cos = ls.wi.dot(n).max(0.0);
        if cos <= 0.0 || ls.pdf <= 0.0 {
            continue;
        }
        let arrives = match ls.visibility {
            Visibility::FirstHit(t_max) => intersect_one(geometry, Ray::new(x, ls.wi, 1e-4, t_max))
                .filter(|h| is_light(h))
                .map_or(Vec3::ZERO, |h| light.emitted(&h, ls.wi)),
            Visibility::Segment(d) => match intersect_one(geometry, Ray::new(x, ls.wi, 1e-4, d * (1.0 - 1e-3))) {
                None => ls.radiance,
                Some(_) => Vec3::ZERO,
            },
        };
        e += arrives.element_sum() / 3.0 * cos / ls.pdf;
    }
    e / m as f32
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().collect();
    let (run_dir, room) = (std::path::Path::new(&a[1]), std::path::Path::new(&a[2]));
    let k: usize = a.get(3).map_or(Ok(1), |v| v.parse())?;
    let run = i2sdf_model::OpenedRun::open(
        run_dir,
        i2sdf_model::InferenceConfig {
            render: Default::default(),
            emitter_threshold: 0.5,
            label_unobserved: false,
            bake_resolution: 0,
        },
    )?;
    let ds = i2sdf_data::load(room)?;
    let recovered = RecoveredScene::of_run(&run, &ds, 256)?;
    let base = recovered.surface.lights(recovered.frozen.emitters);
    let light = base.lights[k].as_ref();
    let geometry = &recovered.surface.geometry;
    let is_recovered = |h: &i2sdf_render::Hit| h.surface == k as u32 + 1;
    let exposure = ds.radiometry.exposure.unwrap_or(1.0) as f32;
    let recovered_l = recovered.frozen.emitters.emission(k).element_sum() / 3.0 / exposure;
    let e = &recovered.frozen.emitters.emitters[k];
    let at = Vec3::new(e.centre[0] as f32, e.centre[1] as f32, e.centre[2] as f32);
    let gt_emitter = ds
        .emitters
        .iter()
        .min_by(|p, q| {
            let d = |g: &i2sdf_data::dataset::GtEmitter| {
                let c = (Vec3::from_array(g.bounds_min.map(|v| v as f32))
                    + Vec3::from_array(g.bounds_max.map(|v| v as f32)))
                    / 2.0;
                (c - at).length()
            };
            d(p).total_cmp(&d(q))
        })
        .ok_or("the dataset has no emitters")?;
    let (lo, hi) = (
        Vec3::from_array(gt_emitter.bounds_min.map(|v| v as f32)),
        Vec3::from_array(gt_emitter.bounds_max.map(|v| v as f32)),
    );
    let (centre, half) = ((lo + hi) / 2.0, (hi - lo) / 2.0);
    let true_l = gt_emitter.emission.iter().sum::<f64>() as f32 / 3.0;
    let gt = i2sdf_data::ply::read_ply(ds.mesh_path.as_ref().ok_or("the dataset has no mesh")?)?;
    let ids = gt.face_object_ids.clone().ok_or("the true mesh has no object ids")?;
    let object = ds
        .objects
        .iter()
        .find(|o| o.name == gt_emitter.name)
        .ok_or("no object of the true emitter")?
        .id;
    let faces: Vec<u32> = (0..gt.faces.len() as u32)
        .filter(|&f| ids[f as usize] == object)
        .collect();
    let sphere = half.min_element() > 0.8 * half.max_element();
    let true_light: Box<dyn Light> = match sphere {
        true => Box::new(SphereLight::new(&gt, &faces, centre, Vec3::splat(true_l))),
        false => Box::new(AreaLight::new(&gt, &faces, Vec3::splat(true_l))),
    };
    let true_geometry = MeshGeometry::new(&gt, ids.iter().map(|&i| i as u32).collect());
    let is_true = |h: &i2sdf_render::Hit| ids[h.prim as usize] == object;
    println!(
        "recovered emitter {k} against the true {}: L {:.3} against {:.3}",
        gt_emitter.name, recovered_l, true_l
    );
    if sphere {
        let r = half.max_element();
        for d in [
            Vec3::X,
            -Vec3::X,
            Vec3::Y,
            -Vec3::Y,
            Vec3::Z,
            -Vec3::Z,
            Vec3::new(-1.0, 0.0, -1.0),
            Vec3::new(-1.0, 1.0, -1.0),
            Vec3::new(1.0, 0.0, 1.0),
        ] {
            let d = d.normalize();
            let x = centre + 0.4 * d;
            let got = irradiance(light, geometry, &is_recovered, x, -d, 2048) / exposure * true_l / recovered_l;
            let want = std::f32::consts::PI * true_l * (r / 0.4).powi(2);
            // Where the recovered SDF crosses zero along d from the true centre, and F_e there.
            let pts: Vec<Vec3> = (0..60).map(|i| centre + d * (i as f32 * 0.005)).collect();
            let sdf = recovered.frozen.sdf_gradient(&pts);
            let mut fe = vec![0.0; pts.len()];
            recovered.frozen.emitter_prob(&pts, &mut fe);
            let crossing = (1..pts.len()).find(|&i| sdf[i - 1].0 < 0.0 && sdf[i].0 >= 0.0);
            let surface = crossing.map_or("no surface within 0.3 m".to_string(), |i| {
                format!("recovered surface at {:.3} m, F_e {:.2}", i as f32 * 0.005, fe[i])
            });
            println!(
                "  towards {:+.2?}: direct light at 0.4 m, recovered / true sphere {:.2}; {surface}",
                d.to_array(),
                got / want
            );
        }
    }
    let (mut got, mut want) = (0.0f64, 0.0f64);
    for f in ds.split(Split::Test) {
        let g = f.camera.ray_generator();
        for y in (0..f.camera.height).step_by(3) {
            for x in (0..f.camera.width).step_by(3) {
                let ray = Ray::new(g.origin, g.dir(x as f32 + 0.5, y as f32 + 0.5), 0.0, f32::INFINITY);
                let (Some(ht), Some(hr)) = (intersect_one(&true_geometry, ray), intersect_one(geometry, ray)) else {
                    continue;
                };
                if ds.emitters.iter().any(|e| {
                    ds.objects
                        .iter()
                        .any(|o| o.name == e.name && o.id == ids[ht.prim as usize])
                }) {
                    continue;
                }
                let facing = |n: Vec3| if n.dot(ray.dir) > 0.0 { -n } else { n };
                let (nt, nr) = (facing(ht.normal), facing(hr.normal));
                want += irradiance(
                    true_light.as_ref(),
                    &true_geometry,
                    &is_true,
                    ray.at(ht.t) + 1e-3 * nt,
                    nt,
                    256,
                ) as f64;
                got += (irradiance(light, geometry, &is_recovered, ray.at(hr.t) + 1e-3 * nr, nr, 256) / exposure
                    * true_l
                    / recovered_l) as f64;
            }
        }
    }
    println!(
        "  test views' first hits: direct light recovered / true {:.3}",
        got / want
    );
    Ok(())
}
