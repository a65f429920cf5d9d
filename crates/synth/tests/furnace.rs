//! White-furnace test of the synthetic scenes through the shared integrator (`i2sdf_render`): a closed box whose walls all emit the same radiance Le
//! (and reflect nothing), holding objects of albedo 1 (Lambertian). Every path ends on a wall with
//! throughput exactly 1, so every pixel's radiance is Le; NEE, MIS weights, light pdfs and Russian
//! roulette must all be right for the estimate to agree.

use glam::Vec3;
use i2sdf_render::render_view;
use i2sdf_synth::camera::looking;
use i2sdf_synth::scene::{CameraRig, Geometry, MaterialDesc, RoomBounds, SceneDesc, ShapeDesc};
use i2sdf_synth::RenderScene;

fn furnace_scene(le: [f32; 3], kd: [f32; 3]) -> SceneDesc {
    let (lo, hi) = (Vec3::new(-2.0, 0.0, -2.0), Vec3::new(2.0, 3.0, 2.0));
    let (w, h, d) = (4.0, 3.0, 4.0);
    let wall = |name: &str, origin: Vec3, u: [f32; 3], v: [f32; 3]| ShapeDesc {
        name: name.into(),
        object: None,
        tags: Vec::new(),
        geometry: Geometry::Quad {
            origin: origin.into(),
            u,
            v,
        },
        material: MaterialDesc {
            kd: [0.0; 3],
            ks: [0.0; 3],
            roughness: 1.0,
            texture: None,
        },
        emission: Some(le),
    };
    let white = MaterialDesc {
        kd,
        ks: [0.0; 3],
        roughness: 1.0,
        texture: None,
    };
    let mut shapes = vec![
        wall("floor", lo, [0.0, 0.0, d], [w, 0.0, 0.0]),
        wall("ceiling", Vec3::new(lo.x, hi.y, lo.z), [w, 0.0, 0.0], [0.0, 0.0, d]),
        wall("back", lo, [w, 0.0, 0.0], [0.0, h, 0.0]),
        wall("front", Vec3::new(lo.x, 0.0, hi.z), [0.0, h, 0.0], [w, 0.0, 0.0]),
        wall("left", lo, [0.0, h, 0.0], [0.0, 0.0, d]),
        wall("right", Vec3::new(hi.x, 0.0, lo.z), [0.0, 0.0, d], [0.0, h, 0.0]),
    ];
    // Concave arrangement (a box under a sphere next to a cylinder) so that paths bounce between
    // objects several times.
    shapes.push(ShapeDesc {
        name: "box".into(),
        object: None,
        tags: Vec::new(),
        geometry: Geometry::Box {
            min: [-0.8, 0.0, -1.2],
            max: [0.4, 0.9, -0.3],
            yaw_deg: 20.0,
        },
        material: white.clone(),
        emission: None,
    });
    shapes.push(ShapeDesc {
        name: "sphere".into(),
        object: None,
        tags: Vec::new(),
        geometry: Geometry::Sphere {
            center: [-0.2, 1.3, -0.8],
            radius: 0.4,
            subdivisions: 3,
        },
        material: white.clone(),
        emission: None,
    });
    shapes.push(ShapeDesc {
        name: "cylinder".into(),
        object: None,
        tags: Vec::new(),
        geometry: Geometry::Cylinder {
            a: [0.7, 0.0, -0.9],
            b: [0.7, 1.6, -0.9],
            radius: 0.25,
            segments: 24,
        },
        material: white,
        emission: None,
    });
    SceneDesc {
        name: "furnace".into(),
        room: RoomBounds {
            min: lo.into(),
            max: hi.into(),
        },
        camera: CameraRig {
            fov_x_deg: 60.0,
            eye_height: [1.0, 1.5],
            pitch_deg: [-10.0, 0.0],
        },
        shapes,
    }
}

fn mean_and_max_dev(le: [f32; 3], kd: [f32; 3], spp: u32) -> (Vec3, f32) {
    let desc = furnace_scene(le, kd);
    desc.validate(std::path::Path::new("furnace")).unwrap();
    let scene = RenderScene::new(desc);
    let cam = looking(Vec3::new(0.0, 1.2, 1.5), 0.0, -0.2, 24, 18, 60.0);
    let r = render_view(&scene.scene(), &cam, &scene.view_settings(spp, 5, 0, 64), &|| {});
    let ones = vec![Vec3::ONE; r.emitters];
    let hdr = r.hdr(&ones);
    let mean = hdr.iter().copied().sum::<Vec3>() / hdr.len() as f32;
    let max_dev = hdr
        .iter()
        .map(|p| ((*p - Vec3::from(le)) / Vec3::from(le)).abs().max_element())
        .fold(0.0f32, f32::max);
    // Sanity: the objects fill a good part of the view, so the test exercises reflection.
    let on_objects = r.emitter_mask.iter().filter(|m| !**m).count();
    assert!(on_objects > hdr.len() / 5, "only {on_objects} pixels see an object");
    (mean, max_dev)
}

#[test]
fn white_furnace_radiance_equals_emission() {
    let le = [1.0, 0.5, 2.0];
    let (mean, max_dev) = mean_and_max_dev(le, [1.0; 3], 64);
    let rel = ((mean - Vec3::from(le)) / Vec3::from(le)).abs().max_element();
    assert!(rel < 0.01, "mean radiance {mean} vs emission {le:?}");
    // Per pixel the estimate is an average of 64 paths; a bias anywhere would show as a shift.
    assert!(max_dev < 0.25, "a pixel deviates by {max_dev}");
}

#[test]
fn furnace_with_grey_objects_is_darker() {
    // The same test must detect energy loss: albedo 0.5 objects give less than Le on their pixels
    // (walls stay at Le), so the image mean drops clearly below Le.
    let le = [1.0, 1.0, 1.0];
    let (mean, _) = mean_and_max_dev(le, [0.5; 3], 16);
    assert!(mean.x < 0.9, "mean {mean}");
}
