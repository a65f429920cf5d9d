//! The edit renderer over an analytic SDF: a white furnace, relighting's linearity, an inserted
//! emitter's light and an inserted object's shadow.

use glam::{DVec3, Vec3};
use i2sdf_data::camera::look_at;
use i2sdf_data::edit_spec::{MaterialOverride, PartialMaterial, Region};
use i2sdf_data::{Camera, TriangleMesh};
use i2sdf_edit::{BaseLights, EditedScene, InsertedObject, MaterialEdit};
use i2sdf_render::{
    ConstantMaterial, Estimator, Geometry, GgxBrdf, Hit, Integrator, Light, LightSample, Ray, ViewRender, ViewSettings,
    Visibility,
};

/// Sphere tracing of an analytic SDF (positive in free space) whose parts carry labels.
struct AnalyticSdf {
    parts: Vec<(Box<dyn Fn(Vec3) -> f32 + Sync>, u32)>,
}

impl AnalyticSdf {
    fn eval(&self, p: Vec3) -> (f32, u32) {
        self.parts
            .iter()
            .map(|(f, l)| (f(p), *l))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .unwrap()
    }

    fn normal(&self, p: Vec3) -> Vec3 {
        let e = 1e-4;
        let d = |q: Vec3| self.eval(q).0;
        Vec3::new(
            d(p + Vec3::X * e) - d(p - Vec3::X * e),
            d(p + Vec3::Y * e) - d(p - Vec3::Y * e),
            d(p + Vec3::Z * e) - d(p - Vec3::Z * e),
        )
        .normalize()
    }

    fn trace(&self, r: &Ray) -> Option<Hit> {
        // Start a little off the surface the ray leaves (offset rays start within RAY_EPS).
        let mut t = r.t_min.max(2e-3);
        for _ in 0..512 {
            if t > r.t_max {
                return None;
            }
            let p = r.at(t);
            let (d, label) = self.eval(p);
            if d < 1e-5 {
                return Some(Hit {
                    t,
                    normal: self.normal(p),
                    surface: label,
                    prim: 0,
                });
            }
            t += d;
        }
        None
    }
}

impl Geometry for AnalyticSdf {
    fn intersect(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        for (r, h) in rays.iter().zip(hits) {
            *h = self.trace(r);
        }
    }
    fn occluded(&self, rays: &[Ray], occluded: &mut [bool]) {
        for (r, o) in rays.iter().zip(occluded) {
            *o = self.trace(r).is_some();
        }
    }
}

/// The furnace's enclosure as a light: radiance `le` towards the inside, sampled uniformly over
/// the sphere of directions.
struct Enclosure {
    le: Vec3,
}

impl Light for Enclosure {
    fn sample(&self, _: Vec3, u: [f32; 3]) -> Option<LightSample> {
        let z = 1.0 - 2.0 * u[1];
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = std::f32::consts::TAU * u[2];
        Some(LightSample {
            wi: Vec3::new(r * phi.cos(), r * phi.sin(), z),
            pdf: 1.0 / (4.0 * std::f32::consts::PI),
            radiance: self.le,
            visibility: Visibility::FirstHit(100.0),
        })
    }
    fn pdf(&self, _: Vec3, _: Vec3, _: &Hit) -> f32 {
        1.0 / (4.0 * std::f32::consts::PI)
    }
    fn emitted(&self, _: &Hit, _: Vec3) -> Vec3 {
        self.le
    }
}

fn torus(p: Vec3) -> f32 {
    let q = glam::Vec2::new(glam::Vec2::new(p.x, p.z).length() - 0.8, p.y);
    q.length() - 0.3
}

fn camera(eye: DVec3, target: DVec3, size: usize) -> Camera {
    Camera {
        lens: Default::default(),
        width: size,
        height: size,
        fx: size as f64,
        fy: size as f64,
        cx: size as f64 / 2.0,
        cy: size as f64 / 2.0,
        c2w: look_at(eye, target, DVec3::Y),
    }
}

fn settings(spp: u32, seed: u64, max_depth: u32) -> ViewSettings {
    ViewSettings {
        spp,
        seed,
        view: 0,
        integrator: Integrator {
            estimator: Estimator::UNBIASED,
            max_depth,
        },
    }
}

fn sphere_mesh(c: Vec3, r: f32) -> TriangleMesh {
    let mut m = TriangleMesh::unit_icosphere(4);
    m.positions
        .iter_mut()
        .for_each(|p| *p = (c + r * Vec3::from(*p)).to_array());
    m
}

fn white() -> GgxBrdf {
    GgxBrdf::new(Vec3::ONE, Vec3::ZERO, 1.0)
}

fn mean(v: &ViewRender, gains: &[Vec3]) -> Vec3 {
    let img = v.hdr(gains);
    img.iter().copied().sum::<Vec3>() / img.len() as f32
}

/// White furnace: a white (Kd = 1) non-convex SDF object, an inserted white sphere and a region
/// override (white too) inside an enclosure of uniform radiance 1 — every pixel must come out 1.
#[test]
fn white_furnace_over_an_analytic_sdf() {
    let sdf = AnalyticSdf {
        parts: vec![(Box::new(|p: Vec3| 3.0 - p.length()), 1), (Box::new(torus), 0)],
    };
    let base_material = ConstantMaterial::new(vec![white(), white()]);
    let base = BaseLights {
        lights: vec![Box::new(Enclosure { le: Vec3::ONE })],
        emitter_of_label: vec![None, Some(0)],
        boxes: vec![(Vec3::splat(-3.0), Vec3::splat(3.0))],
    };
    let inserts = vec![InsertedObject {
        mesh: sphere_mesh(Vec3::new(0.0, 0.0, 0.0), 0.35),
        brdf: white(),
        emission: None,
        sphere: Some((Vec3::ZERO, 0.35)),
    }];
    let edits = vec![MaterialEdit {
        region: Region::Above {
            point: [0.0; 3],
            normal: [1.0, 0.0, 0.0],
        },
        material: MaterialOverride::Values(PartialMaterial {
            kd: Some([1.0; 3]),
            ks: Some([0.0; 3]),
            roughness: None,
        }),
        texture: None,
    }];
    let scene = EditedScene::new(base, inserts, edits);
    let cam = camera(DVec3::new(0.3, 1.6, 2.2), DVec3::ZERO, 24);
    let v = scene.render(&sdf, &base_material, None, &cam, &settings(64, 3, 64), &|| {});
    // The pixels that see the object or the insert (the enclosure's own are 1 trivially).
    let img = v.hdr(&[Vec3::ONE]);
    let objects: Vec<Vec3> = (0..img.len()).filter(|&i| !v.emitter_mask[i]).map(|i| img[i]).collect();
    assert!(
        objects.len() > img.len() / 4,
        "the objects fill {} pixels",
        objects.len()
    );
    let m = objects.iter().copied().sum::<Vec3>() / objects.len() as f32;
    assert!((m - Vec3::ONE).abs().max_element() < 0.01, "mean {m}");
    let worst = objects
        .iter()
        .map(|c| (*c - Vec3::ONE).abs().max_element())
        .fold(0.0f32, f32::max);
    assert!(worst < 0.35, "worst pixel off by {worst}");
    // Every pixel sees something: the object, the insert or the enclosure.
    assert!(v.depth.iter().all(|d| d.is_finite()));
}

/// A floor (SDF plane) lit by two inserted spherical lamps, as the relight tests' scene.
fn lamp_scene(le0: Vec3, extra: Option<Vec3>) -> (AnalyticSdf, ConstantMaterial, EditedScene) {
    let sdf = AnalyticSdf {
        parts: vec![(Box::new(|p: Vec3| p.y), 0)],
    };
    let base_material = ConstantMaterial::new(vec![GgxBrdf::new(Vec3::splat(0.6), Vec3::splat(0.04), 0.5)]);
    let base = BaseLights {
        lights: Vec::new(),
        emitter_of_label: vec![None],
        boxes: Vec::new(),
    };
    let mut inserts = vec![
        InsertedObject {
            mesh: sphere_mesh(Vec3::new(-1.0, 1.0, 0.0), 0.2),
            brdf: white(),
            emission: Some(le0),
            sphere: Some((Vec3::new(-1.0, 1.0, 0.0), 0.2)),
        },
        InsertedObject {
            mesh: sphere_mesh(Vec3::new(1.0, 1.5, 0.5), 0.3),
            brdf: white(),
            emission: Some(Vec3::new(1.0, 2.0, 3.0)),
            sphere: Some((Vec3::new(1.0, 1.5, 0.5), 0.3)),
        },
    ];
    if let Some(le) = extra {
        inserts.push(InsertedObject {
            mesh: sphere_mesh(Vec3::new(0.0, 0.6, -0.5), 0.1),
            brdf: white(),
            emission: Some(le),
            sphere: Some((Vec3::new(0.0, 0.6, -0.5), 0.1)),
        });
    }
    (sdf, base_material, EditedScene::new(base, inserts, Vec::new()))
}

fn floor_camera() -> Camera {
    camera(DVec3::new(0.0, 2.5, 3.0), DVec3::new(0.0, 0.0, 0.0), 20)
}

/// Scaling one emitter by 2 through its radiance slot (what a relight op does) equals rendering
/// a scene whose emitter really emits twice as much, within noise.
#[test]
fn relighting_is_linear_in_each_emitter() {
    let le = Vec3::new(4.0, 3.0, 2.0);
    let (sdf, mat, scene) = lamp_scene(le, None);
    let v = scene.render(&sdf, &mat, None, &floor_camera(), &settings(64, 1, 4), &|| {});
    let relit = mean(&v, &[Vec3::splat(2.0), Vec3::ONE]);
    let plus = mean(&v, &[Vec3::ONE, Vec3::ONE]) + mean(&v, &[Vec3::ONE, Vec3::ZERO]);
    assert!((relit - plus).abs().max_element() < 1e-4 * relit.max_element());
    let (sdf2, mat2, scene2) = lamp_scene(2.0 * le, None);
    let v2 = scene2.render(&sdf2, &mat2, None, &floor_camera(), &settings(64, 2, 4), &|| {});
    let doubled = mean(&v2, &[Vec3::ONE, Vec3::ONE]);
    let rel = ((relit - doubled) / doubled).abs().max_element();
    assert!(rel < 0.03, "relit {relit} vs doubled {doubled}");
    // And the first emitter's share does matter (the test is not vacuous).
    let alone = mean(&v, &[Vec3::ONE, Vec3::ZERO]);
    assert!(alone.max_element() > 0.2 * relit.max_element());
}

/// An inserted emitter adds light to the floor, exactly its own slot's worth; a plain inserted
/// object above the floor casts a shadow.
#[test]
fn an_inserted_emitter_adds_light_and_an_inserted_object_casts_a_shadow() {
    let (sdf, mat, plain) = lamp_scene(Vec3::splat(4.0), None);
    let (_, _, lit) = lamp_scene(Vec3::splat(4.0), Some(Vec3::splat(20.0)));
    let cam = floor_camera();
    let a = plain.render(&sdf, &mat, None, &cam, &settings(32, 5, 3), &|| {});
    let b = lit.render(&sdf, &mat, None, &cam, &settings(32, 5, 3), &|| {});
    assert_eq!(lit.lights(), 3);
    let before = mean(&a, &[Vec3::ONE; 2]);
    let after = mean(&b, &[Vec3::ONE; 3]);
    let own = mean(&b, &[Vec3::ZERO, Vec3::ZERO, Vec3::ONE]);
    assert!((after / before).min_element() > 1.1, "{before} → {after}");
    assert!(((after - before - own) / after).abs().max_element() < 0.05);
    // A grey ball hanging just above the floor under the first lamp darkens the floor below it.
    let (sdf, mat, _) = lamp_scene(Vec3::splat(4.0), None);
    let ball = InsertedObject {
        mesh: sphere_mesh(Vec3::new(-1.0, 0.35, 0.0), 0.25),
        brdf: GgxBrdf::new(Vec3::splat(0.5), Vec3::ZERO, 1.0),
        emission: None,
        sphere: None,
    };
    let lamps = |inserts: &mut Vec<InsertedObject>| {
        inserts.insert(
            0,
            InsertedObject {
                mesh: sphere_mesh(Vec3::new(-1.0, 1.0, 0.0), 0.2),
                brdf: white(),
                emission: Some(Vec3::splat(4.0)),
                sphere: Some((Vec3::new(-1.0, 1.0, 0.0), 0.2)),
            },
        )
    };
    let base = || BaseLights {
        lights: Vec::new(),
        emitter_of_label: vec![None],
        boxes: Vec::new(),
    };
    let mut with = vec![ball];
    lamps(&mut with);
    let mut without = Vec::new();
    lamps(&mut without);
    let shadowed = EditedScene::new(base(), with, Vec::new());
    let open = EditedScene::new(base(), without, Vec::new());
    // Look straight down at the floor point below the lamp, past the ball's side.
    let cam = camera(DVec3::new(-0.4, 2.0, 0.8), DVec3::new(-1.0, 0.0, 0.0), 16);
    let s = shadowed.render(&sdf, &mat, None, &cam, &settings(32, 7, 3), &|| {});
    let o = open.render(&sdf, &mat, None, &cam, &settings(32, 7, 3), &|| {});
    // Floor pixels of both renders (the ball's own pixels excluded by their depth).
    let floor: Vec<usize> = (0..s.depth.len())
        .filter(|&i| (s.depth[i] - o.depth[i]).abs() < 1e-3 && s.depth[i].is_finite())
        .collect();
    let (hs, ho) = (s.hdr(&[Vec3::ONE]), o.hdr(&[Vec3::ONE]));
    let darker = floor.iter().filter(|&&i| hs[i].x < 0.7 * ho[i].x).count();
    assert!(darker >= 5, "only {darker} floor pixels in shadow");
}
