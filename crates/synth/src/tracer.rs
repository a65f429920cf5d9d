//! The ground-truth renderer's scene: the room's triangles, materials and emitters turned into
//! the shared integrator's geometry, material and light interfaces (`i2sdf_render`), which render
//! them (`i2sdf_render::render_view`: next-event estimation on every emitter at every vertex,
//! spherical emitters sampled by solid angle and others by area, MIS, Russian roulette, the
//! supplementary's GGX BRDF). Unbiased by default; the dataset generator adds path-space
//! regularization of glossy lobes after a diffuse bounce ([`Estimator::DATASET`]).
//!
//! Radiance is kept per emitter (see `i2sdf_render::integrator`), so relit views are exact sums
//! of the per-emitter images and are rendered with the same estimator as the originals.

use crate::mesh::SceneMesh;
use crate::scene::{Geometry as ShapeGeometry, SceneDesc};
use glam::Vec3;
use i2sdf_render::{
    AreaLight, ConstantMaterial, GgxBrdf, Integrator, KdTexture, Light, LightSet, MeshGeometry, Scene, SphereLight,
    TexturedMaterial, ViewSettings,
};

pub use i2sdf_render::integrator::{BounceUniforms, STRATIFIED_BOUNCES};
pub use i2sdf_render::{Estimator, ViewRender};

/// Most emitters a scene may have (each keeps its own radiance image for relighting).
pub const MAX_EMITTERS: usize = 8;

/// One emitter: a shape with emission.
#[derive(Clone, Debug)]
pub struct Emitter {
    pub shape: u32,
    pub name: String,
    pub emission: Vec3,
    pub bounds: (Vec3, Vec3),
}

pub struct RenderScene {
    pub desc: SceneDesc,
    /// The estimator the views are rendered with (unbiased unless set).
    pub estimator: Estimator,
    pub mesh: SceneMesh,
    /// The triangles behind the integrator's geometry interface, labelled by shape index.
    pub geometry: MeshGeometry,
    /// Per shape: its GGX parameters, Kd textured in world space where the shape has a texture.
    pub material: TexturedMaterial<ConstantMaterial>,
    /// Emitter k is `emitters[k]`; quads, boxes and cylinders sampled by area, spheres by cone.
    pub lights: LightSet,
    pub emitters: Vec<Emitter>,
    /// Bounds of the closed shapes (boxes, spheres, cylinders) that cameras must stay out of.
    pub obstacle_bounds: Vec<(Vec3, Vec3)>,
}

impl RenderScene {
    pub fn new(desc: SceneDesc) -> Self {
        let mesh = SceneMesh::from_scene(&desc);
        let geometry = MeshGeometry::new(&mesh.mesh, mesh.shape_of.clone());
        let mut emitters = Vec::new();
        let mut emitter_of_shape = Vec::new();
        let mut lights: Vec<Box<dyn Light>> = Vec::new();
        let mut obstacle_bounds = Vec::new();
        for (i, s) in desc.shapes.iter().enumerate() {
            let bounds = mesh.shape_bounds(i as u32);
            if let Some(e) = s.emission {
                emitter_of_shape.push(Some(emitters.len() as u32));
                let emission = Vec3::from(e);
                let faces = mesh.shape_faces(i as u32);
                lights.push(match s.geometry {
                    ShapeGeometry::Sphere { center, .. } => {
                        Box::new(SphereLight::new(&mesh.mesh, &faces, Vec3::from(center), emission))
                    }
                    _ => Box::new(AreaLight::new(&mesh.mesh, &faces, emission)),
                });
                emitters.push(Emitter {
                    shape: i as u32,
                    name: s.name.clone(),
                    emission,
                    bounds,
                });
            } else {
                emitter_of_shape.push(None);
            }
            if !matches!(s.geometry, ShapeGeometry::Quad { .. }) {
                obstacle_bounds.push(bounds);
            }
        }
        let brdfs = desc
            .shapes
            .iter()
            .map(|s| {
                let m = &s.material;
                GgxBrdf::new(Vec3::from(m.kd), Vec3::from(m.ks), m.roughness)
            })
            .collect();
        let textures = desc
            .shapes
            .iter()
            .map(|s| s.material.texture.clone().map(|t| Box::new(t) as Box<dyn KdTexture>))
            .collect();
        RenderScene {
            desc,
            estimator: Estimator::UNBIASED,
            mesh,
            geometry,
            material: TexturedMaterial {
                base: ConstantMaterial::new(brdfs),
                textures,
            },
            lights: LightSet::new(lights, emitter_of_shape),
            emitters,
            obstacle_bounds,
        }
    }

    /// The scene as the integrator sees it.
    pub fn scene(&self) -> Scene<'_> {
        Scene {
            geometry: &self.geometry,
            material: &self.material,
            lights: &self.lights,
            radiance_field: None,
        }
    }

    /// What `i2sdf_render::render_view` needs for view `view`, with this scene's estimator.
    pub fn view_settings(&self, spp: u32, seed: u64, view: u32, max_depth: u32) -> ViewSettings {
        ViewSettings {
            spp,
            seed,
            view,
            integrator: Integrator {
                estimator: self.estimator,
                max_depth,
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{CameraRig, MaterialDesc, RoomBounds, ShapeDesc, TextureDesc};
    use i2sdf_render::{render_view, Material, SurfacePoint};

    fn shape(name: &str, geometry: ShapeGeometry, emission: Option<[f32; 3]>) -> ShapeDesc {
        ShapeDesc {
            name: name.into(),
            object: None,
            tags: Vec::new(),
            geometry,
            material: MaterialDesc {
                kd: [0.5; 3],
                ks: [0.1; 3],
                roughness: 0.4,
                texture: Some(TextureDesc::Stripe {
                    kd2: [0.1, 0.2, 0.3],
                    scale: 1.0,
                    axis: 0,
                }),
            },
            emission,
        }
    }

    /// The scene's shapes reach the integrator's interfaces: a sphere emitter is a cone-sampled
    /// light, a quad emitter an area light, surfaces are labelled by shape, and the texture is
    /// applied by the material.
    #[test]
    fn shapes_become_geometry_materials_and_lights() {
        let scene = RenderScene::new(SceneDesc {
            name: "t".into(),
            room: RoomBounds {
                min: [-5.0, 0.0, -5.0],
                max: [5.0, 3.0, 5.0],
            },
            camera: CameraRig {
                fov_x_deg: 60.0,
                eye_height: [1.0, 1.5],
                pitch_deg: [-10.0, 0.0],
            },
            shapes: vec![
                shape(
                    "floor",
                    ShapeGeometry::Quad {
                        origin: [-5.0, 0.0, -5.0],
                        u: [0.0, 0.0, 10.0],
                        v: [10.0, 0.0, 0.0],
                    },
                    None,
                ),
                shape(
                    "bulb",
                    ShapeGeometry::Sphere {
                        center: [0.0, 2.0, 0.0],
                        radius: 0.2,
                        subdivisions: 2,
                    },
                    Some([3.0; 3]),
                ),
                shape(
                    "panel",
                    ShapeGeometry::Quad {
                        origin: [2.0, 2.9, -0.5],
                        u: [1.0, 0.0, 0.0],
                        v: [0.0, 0.0, 1.0],
                    },
                    Some([1.0; 3]),
                ),
            ],
        });
        assert_eq!(scene.lights.len(), 2);
        assert_eq!(scene.emitters[1].name, "panel");
        let cone = scene.lights.get(0).sample(Vec3::ZERO, [0.5, 0.5, 0.5]).unwrap();
        assert!(matches!(cone.visibility, i2sdf_render::Visibility::FirstHit(_)));
        let area = scene.lights.get(1).sample(Vec3::ZERO, [0.5, 0.5, 0.5]).unwrap();
        assert!(matches!(area.visibility, i2sdf_render::Visibility::Segment(_)));
        let mut out = [GgxBrdf::new(Vec3::ZERO, Vec3::ZERO, 1.0); 2];
        let at = |x: f32| SurfacePoint {
            position: Vec3::new(x, 0.0, 0.0),
            normal: Vec3::Y,
            surface: 0,
            prim: 0,
        };
        scene.material.eval_batch(&[at(0.2), at(1.2)], &mut out);
        assert_eq!((out[0].kd, out[1].kd), (Vec3::splat(0.5), Vec3::new(0.1, 0.2, 0.3)));
        // A view straight through the scene renders, with per-emitter radiance.
        let cam = crate::camera::looking(Vec3::new(0.0, 1.0, 3.0), 0.0, 0.2, 8, 6, 60.0);
        let r = render_view(&scene.scene(), &cam, &scene.view_settings(4, 0, 0, 4), &|| {});
        assert_eq!(r.radiance.len(), 8 * 6 * 2);
        assert!(r.hdr(&[Vec3::ONE, Vec3::ZERO]).iter().any(|p| p.x > 0.0));
    }
}
