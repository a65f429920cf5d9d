//! Shared by the integration tests that compare the ray caster with the volume renderer.
// Each test binary includes this module and uses part of it.
#![allow(dead_code)]

use i2sdf_data::Dataset;
use i2sdf_model::raycast::{CastSettings, Hit, SdfCaster};
use i2sdf_model::renderer::{self, RenderSettings, RenderWorkspace};
use i2sdf_model::NeuralScene;
use std::time::Instant;

pub fn quantile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// The rays of every pixel of every view: normalized-frame origins and directions, and the
/// world-frame ones.
pub struct ViewRays {
    pub origins: Vec<[f32; 3]>,
    pub dirs: Vec<[f32; 3]>,
    pub world: Vec<(glam::DVec3, glam::DVec3)>,
}

pub fn view_rays(ds: &Dataset) -> ViewRays {
    let norm = ds.normalization;
    let mut r = ViewRays {
        origins: Vec::new(),
        dirs: Vec::new(),
        world: Vec::new(),
    };
    for f in &ds.frames {
        let c = &f.camera;
        for j in 0..c.height {
            for i in 0..c.width {
                let (o, d, _) = c.ray(i as f64 + 0.5, j as f64 + 0.5);
                let on = norm.to_normalized(o);
                r.origins.push([on.x as f32, on.y as f32, on.z as f32]);
                r.dirs.push([d.x as f32, d.y as f32, d.z as f32]);
                r.world.push((o, d));
            }
        }
    }
    r
}

/// Expected ray distance (normalized by the opacity) and opacity of deterministic volume
/// renders, and the rays per second.
pub fn volume_depths(scene: &NeuralScene, settings: &RenderSettings, rays: &ViewRays) -> (Vec<f32>, Vec<f32>, f64) {
    let t0 = Instant::now();
    let mut ws = RenderWorkspace::default();
    let (mut t, mut opacity) = (Vec::new(), Vec::new());
    for (o, d) in rays.origins.chunks(4096).zip(rays.dirs.chunks(4096)) {
        renderer::forward::<rand_pcg::Pcg64>(scene, settings, o, d, &[], &mut ws, None);
        for r in 0..o.len() {
            t.push(ws.out.depth[r] / ws.out.opacity[r].max(1e-6));
            opacity.push(ws.out.opacity[r]);
        }
    }
    let rate = rays.origins.len() as f64 / t0.elapsed().as_secs_f64();
    (t, opacity, rate)
}

/// The caster's hits and its rays per second (best of `reps` timed passes after a warm-up).
pub fn cast(scene: &NeuralScene, rays: &ViewRays, reps: usize) -> (Vec<Hit>, f64) {
    let n = rays.origins.len();
    let caster = SdfCaster::new(scene, CastSettings::default());
    let mut hits = vec![Hit::default(); n];
    let t_max = vec![f32::INFINITY; n];
    caster.cast(&rays.origins, &rays.dirs, &t_max, &mut hits);
    let mut best = f64::INFINITY;
    for _ in 0..reps {
        let t0 = Instant::now();
        caster.cast(&rays.origins, &rays.dirs, &t_max, &mut hits);
        best = best.min(t0.elapsed().as_secs_f64());
    }
    (hits, n as f64 / best)
}

/// Agreement of the cast hits with the volume-rendered depth over the opaque rays.
pub struct Agreement {
    pub rays: usize,
    pub counted: usize,
    pub misses: usize,
    /// |t_cast − t_volume|, normalized units.
    pub median: f64,
    pub p95: f64,
    /// Against the fixture's analytic room (world units): (median, p95) of cast and volume.
    pub cast_gt: (f64, f64),
    pub volume_gt: (f64, f64),
}

pub fn agreement(scene: &NeuralScene, rays: &ViewRays, hits: &[Hit], t_volume: &[f32], opacity: &[f32]) -> Agreement {
    let scale = scene.normalization.scale;
    let (mut diff, mut cast_gt, mut volume_gt) = (Vec::new(), Vec::new(), Vec::new());
    let mut misses = 0;
    for i in 0..hits.len() {
        if opacity[i] < 0.9 {
            continue;
        }
        if !hits[i].hit {
            misses += 1;
            continue;
        }
        diff.push((hits[i].t - t_volume[i]).abs() as f64);
        let (gt, _) = i2sdf_data::fixture::room_hit(rays.world[i].0, rays.world[i].1);
        cast_gt.push((hits[i].t as f64 * scale - gt).abs());
        volume_gt.push((t_volume[i] as f64 * scale - gt).abs());
    }
    Agreement {
        rays: hits.len(),
        counted: diff.len(),
        misses,
        median: quantile(&mut diff, 0.5),
        p95: quantile(&mut diff, 0.95),
        cast_gt: (quantile(&mut cast_gt, 0.5), quantile(&mut cast_gt, 0.95)),
        volume_gt: (quantile(&mut volume_gt, 0.5), quantile(&mut volume_gt, 0.95)),
    }
}

impl std::fmt::Display for Agreement {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(
            f,
            "{} rays, {} opaque and hit, {} opaque but missed; |t_cast − t_volume| median {:.5} p95 {:.5} \
             (normalized); against the analytic room (world units): cast median {:.4} p95 {:.4}, volume \
             median {:.4} p95 {:.4}",
            self.rays,
            self.counted,
            self.misses,
            self.median,
            self.p95,
            self.cast_gt.0,
            self.cast_gt.1,
            self.volume_gt.0,
            self.volume_gt.1
        )
    }
}

/// The tiny fixture room both tests train on (32×24, 6 training views, 1 test view).
pub fn dataset() -> (tempfile::TempDir, Dataset) {
    let dir = tempfile::tempdir().unwrap();
    let opts = i2sdf_data::fixture::FixtureOptions {
        width: 32,
        height: 24,
        train_views: 6,
        test_views: 1,
        ..Default::default()
    };
    i2sdf_data::fixture::write_native(dir.path(), &opts);
    let ds = i2sdf_data::load(dir.path()).unwrap();
    (dir, ds)
}
