use glam::Vec3;
use i2sdf_model::{intrinsic_io, FrozenScene, RunDir};
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let run = RunDir::new(std::path::Path::new(&a[1]));
    let (scene, fields) = intrinsic_io::load_run(&run).unwrap();
    let fields = fields.unwrap();
    let frozen = FrozenScene::new(&scene, &fields.emitters, fields.radiometry);
    let c = Vec3::new(-1.8025757, 1.808512, -1.5301551);
    let s = scene.normalization.scale as f32;
    for dir in [
        Vec3::X,
        -Vec3::X,
        Vec3::Y,
        -Vec3::Y,
        Vec3::Z,
        -Vec3::Z,
        Vec3::new(1.0, 1.0, 1.0).normalize(),
        Vec3::new(-1.0, 1.0, -1.0).normalize(),
    ] {
        let pts: Vec<Vec3> = (0..60).map(|i| c + dir * (i as f32 * 0.005)).collect();
        let dg = frozen.sdf_gradient(&pts);
        let mut prob = vec![0.0; pts.len()];
        frozen.emitter_prob(&pts, &mut prob);
        let r0 = (1..pts.len())
            .find(|&i| dg[i - 1].0 < 0.0 && dg[i].0 >= 0.0)
            .map(|i| i as f32 * 0.005);
        let d_at_centre = dg[0].0 * s;
        let fe = r0.map(|r| prob[(r / 0.005) as usize]);
        println!("dir {dir:?}: sdf(centre) {d_at_centre:.3} m, surface at r = {r0:?} m, F_e there {fe:?}");
    }
}
