//! The scene description: shapes (box, sphere, cylinder, quad) with GGX materials, optional
//! procedural Kd textures and emission, the room bounds and the camera rig. It round-trips through
//! TOML (`scene.toml` in every generated dataset), so a room can be edited by hand and re-rendered.

use glam::Vec3;
use i2sdf_data::{validate, DataError};
use serde::{Deserialize, Serialize};
use std::fmt::Display;
use std::path::Path;

/// A whole synthetic scene, in metres, y up.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneDesc {
    pub name: String,
    pub room: RoomBounds,
    pub camera: CameraRig,
    #[serde(rename = "shape")]
    pub shapes: Vec<ShapeDesc>,
}

/// The inside of the room (cameras are placed in it, inset from the walls).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RoomBounds {
    pub min: [f32; 3],
    pub max: [f32; 3],
}

/// How cameras are placed: horizontal field of view and the eye-height range.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraRig {
    pub fov_x_deg: f32,
    pub eye_height: [f32; 2],
    /// Pitch range in degrees (negative looks down).
    #[serde(default = "default_pitch")]
    pub pitch_deg: [f32; 2],
}

fn default_pitch() -> [f32; 2] {
    [-25.0, 5.0]
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShapeDesc {
    pub name: String,
    /// The object this shape is part of: shapes naming the same object form one object of the
    /// ground truth (one `object_id` in `mesh.ply`, one entry of `objects` in transforms.json), so
    /// that four table legs can be scored together. Defaults to the shape's own name.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub object: Option<String>,
    /// Tags of that object (see [`tags`]); an object's tags are the union over its shapes.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tags: Vec<String>,
    #[serde(flatten)]
    pub geometry: Geometry,
    pub material: MaterialDesc,
    /// Emitted radiance (linear RGB, W·sr⁻¹·m⁻² up to a global scale), one-sided along the
    /// outward normal. A shape with emission is one emitter; emitters reflect nothing.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub emission: Option<[f32; 3]>,
}

/// Geometry of a shape; everything is tessellated into triangles before rendering, and the
/// triangles are exactly what the ground-truth mesh holds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Geometry {
    /// Axis-aligned box rotated by `yaw_deg` about the vertical axis through its centre.
    Box {
        min: [f32; 3],
        max: [f32; 3],
        #[serde(default)]
        yaw_deg: f32,
    },
    /// Icosphere with `subdivisions` loop subdivisions of the icosahedron (20·4ⁿ faces).
    Sphere {
        center: [f32; 3],
        radius: f32,
        #[serde(default = "default_subdivisions")]
        subdivisions: u32,
    },
    /// Closed cylinder from `a` to `b` (cap centres) with `segments` sides.
    Cylinder {
        a: [f32; 3],
        b: [f32; 3],
        radius: f32,
        #[serde(default = "default_segments")]
        segments: u32,
    },
    /// One-sided parallelogram `origin + s·u + t·v`, s,t ∈ \[0,1\]; it faces along u × v.
    Quad { origin: [f32; 3], u: [f32; 3], v: [f32; 3] },
}

impl Geometry {
    /// Signed distance from `p` to the shape's surface (world units) for the solids (boxes,
    /// spheres, cylinders, as their exact shapes, not their tessellations); `None` for a quad,
    /// which bounds no inside. What the probes use to tell which pixels see a thin shape.
    pub fn distance(&self, p: glam::Vec3) -> Option<f32> {
        match self {
            Geometry::Box { min, max, yaw_deg } => {
                let (lo, hi) = (glam::Vec3::from(*min), glam::Vec3::from(*max));
                let c = 0.5 * (lo + hi);
                // Into the box's frame: the inverse of its yaw about the vertical through its centre.
                let q = glam::Quat::from_rotation_y(-yaw_deg.to_radians()) * (p - c);
                let d = q.abs() - 0.5 * (hi - lo);
                Some(d.max(glam::Vec3::ZERO).length() + d.max_element().min(0.0))
            }
            Geometry::Cylinder { a, b, radius, .. } => {
                let (a, b) = (glam::Vec3::from(*a), glam::Vec3::from(*b));
                let ab = b - a;
                let s = ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
                Some((p - (a + s * ab)).length() - radius)
            }
            Geometry::Sphere { center, radius, .. } => Some((p - glam::Vec3::from(*center)).length() - radius),
            Geometry::Quad { .. } => None,
        }
    }
}

/// The object tags the generator writes. Evaluation groups objects by them: `thin` and
/// `suspended` objects are what the paper's bubble loss exists to recover.
pub mod tags {
    /// Floor, ceiling and walls.
    pub const ROOM: &str = "room";
    pub const FURNITURE: &str = "furniture";
    /// Rod-like parts, under ~4 cm across in both directions of their cross-section (a lamp pole,
    /// table legs, chandelier rods). Slabs thin in one direction only (table tops, shelf boards, a
    /// rug) are not thin: a flat plate is as easy to see from depth as a wall.
    pub const THIN: &str = "thin";
    /// Hanging in the air, attached only to the ceiling (the chandelier).
    pub const SUSPENDED: &str = "suspended";
    /// Under 5 cm in every direction, resting on furniture (a ball on a table, a die): a few
    /// depth samples at most, and in contact with a larger surface that the SDF can smooth over.
    pub const SMALL: &str = "small";
    /// Implied by a shape's `emission`; never needs writing.
    pub const EMITTER: &str = "emitter";
}

/// One object of the scene as the ground truth names it: `id` is the mesh's per-face
/// `object_id`.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneObject {
    pub id: i32,
    pub name: String,
    pub tags: Vec<String>,
}

fn default_subdivisions() -> u32 {
    2
}
fn default_segments() -> u32 {
    16
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MaterialDesc {
    pub kd: [f32; 3],
    #[serde(default)]
    pub ks: [f32; 3],
    #[serde(default = "default_roughness")]
    pub roughness: f32,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texture: Option<TextureDesc>,
}

fn default_roughness() -> f32 {
    0.5
}

/// A solid (3D) procedural texture on Kd: world-space checker cells or stripes of size `scale`
/// alternating between `kd` and `kd2`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "pattern", rename_all = "lowercase")]
pub enum TextureDesc {
    Checker {
        kd2: [f32; 3],
        scale: f32,
    },
    /// Stripes across world axis `axis` (0 = x, 1 = y, 2 = z).
    Stripe {
        kd2: [f32; 3],
        scale: f32,
        axis: usize,
    },
}

impl TextureDesc {
    /// Kd at world point `p`, given the base `kd`. Cells are offset by half a cell so that
    /// surfaces lying on multiples of `scale` (the floor at y = 0) sit mid-cell, not on a border.
    pub fn kd_at(&self, kd: Vec3, p: Vec3) -> Vec3 {
        let (alt, odd) = match self {
            TextureDesc::Checker { kd2, scale } => {
                let c = (p / *scale + Vec3::splat(0.5)).floor();
                (Vec3::from(*kd2), (c.x + c.y + c.z).rem_euclid(2.0) >= 1.0)
            }
            TextureDesc::Stripe { kd2, scale, axis } => {
                let c = (p[*axis] / *scale + 0.5).floor();
                (Vec3::from(*kd2), c.rem_euclid(2.0) >= 1.0)
            }
        };
        if odd {
            alt
        } else {
            kd
        }
    }
}

/// The integrator's materials apply scene textures through this.
impl i2sdf_render::KdTexture for TextureDesc {
    fn kd_at(&self, base_kd: Vec3, p: Vec3) -> Vec3 {
        TextureDesc::kd_at(self, base_kd, p)
    }
}

fn finite3(a: &[f32; 3]) -> bool {
    a.iter().all(|x| x.is_finite())
}

impl SceneDesc {
    pub fn from_toml_str(text: &str, path: &Path) -> Result<Self, DataError> {
        let scene: SceneDesc =
            toml::from_str(text).map_err(|e| DataError::file(path, format!("bad scene TOML: {e}")))?;
        scene.validate(path)?;
        Ok(scene)
    }

    pub fn read(path: &Path) -> Result<Self, DataError> {
        let text = std::fs::read_to_string(path).map_err(|e| DataError::file(path, e.to_string()))?;
        Self::from_toml_str(&text, path)
    }

    pub fn to_toml_string(&self) -> String {
        toml::to_string_pretty(self).expect("scene descriptions always serialize")
    }

    /// The scene's objects, numbered 0, 1, … in order of first appearance, and the object id of
    /// every shape. Tags are merged over an object's shapes in order of first appearance, with
    /// `emitter` added where a shape emits.
    pub fn objects(&self) -> (Vec<SceneObject>, Vec<i32>) {
        let mut objects: Vec<SceneObject> = Vec::new();
        let mut index = std::collections::HashMap::new();
        let mut object_of_shape = Vec::with_capacity(self.shapes.len());
        for s in &self.shapes {
            let name = s.object.as_deref().unwrap_or(&s.name);
            let id = *index.entry(name.to_string()).or_insert_with(|| {
                objects.push(SceneObject {
                    id: objects.len() as i32,
                    name: name.to_string(),
                    tags: Vec::new(),
                });
                objects.len() as i32 - 1
            });
            let tags = &mut objects[id as usize].tags;
            let implied = s.emission.is_some().then_some(tags::EMITTER);
            for t in s.tags.iter().map(String::as_str).chain(implied) {
                if !tags.iter().any(|x| x == t) {
                    tags.push(t.to_string());
                }
            }
            object_of_shape.push(id);
        }
        (objects, object_of_shape)
    }

    /// The solid shapes (those with a [`Geometry::distance`]) of the objects carrying any of
    /// `tags`, grouped by object name in order of first appearance: what the probes score the
    /// thin, suspended and small objects by.
    pub fn solid_shapes_tagged(&self, tags: &[&str]) -> Vec<(String, Vec<usize>)> {
        let (objects, object_of) = self.objects();
        let mut groups: Vec<(String, Vec<usize>)> = Vec::new();
        for (s, shape) in self.shapes.iter().enumerate() {
            let o = &objects[object_of[s] as usize];
            if o.tags.iter().any(|t| tags.contains(&t.as_str())) && shape.geometry.distance(Vec3::ZERO).is_some() {
                match groups.iter_mut().find(|g| g.0 == o.name) {
                    Some(g) => g.1.push(s),
                    None => groups.push((o.name.clone(), vec![s])),
                }
            }
        }
        groups
    }

    /// Checks every value a renderer relies on; errors name the shape and field.
    pub fn validate(&self, path: &Path) -> Result<(), DataError> {
        let (lo, hi) = (Vec3::from(self.room.min), Vec3::from(self.room.max));
        if !finite3(&self.room.min) || !finite3(&self.room.max) || !(hi - lo).cmpgt(Vec3::splat(0.5)).all() {
            return Err(DataError::field(
                path,
                "room",
                "min/max must be finite with max − min > 0.5 m on every axis",
            ));
        }
        let c = &self.camera;
        if !(c.fov_x_deg > 1.0 && c.fov_x_deg < 170.0) {
            return Err(DataError::field(path, "camera.fov_x_deg", "must be in (1, 170)"));
        }
        if !(c.eye_height[0] <= c.eye_height[1]) || c.eye_height[0] <= lo.y || c.eye_height[1] >= hi.y {
            return Err(DataError::field(
                path,
                "camera.eye_height",
                "must be an increasing range inside the room",
            ));
        }
        if !(c.pitch_deg[0] <= c.pitch_deg[1]) || c.pitch_deg[0] < -89.0 || c.pitch_deg[1] > 89.0 {
            return Err(DataError::field(
                path,
                "camera.pitch_deg",
                "must be an increasing range within ±89°",
            ));
        }
        if self.shapes.is_empty() {
            return Err(DataError::field(path, "shape", "a scene needs shapes"));
        }
        let mut emitters = 0;
        for (i, s) in self.shapes.iter().enumerate() {
            let field = |f: &str| format!("shape[{i}] ({}).{f}", s.name);
            let bad = |f: &str, msg: &str| Err(DataError::field(path, field(f), msg));
            // A rule of the house's value checks, at `f`, with the value found.
            let rule = |f: &str, rule: Result<(), String>, found: &dyn Display| {
                rule.map_err(|m| DataError::field(path, field(f), format!("{m}, found {found}")))
            };
            let v3 = |v: &[f32; 3]| format!("[{}, {}, {}]", v[0], v[1], v[2]);
            let positive = |f: &str, x: f32| rule(f, validate::positive_up_to(x as f64, f64::INFINITY), &x);
            if s.object.as_ref().is_some_and(|o| o.trim().is_empty()) {
                return bad("object", "must not be empty (leave it out to use the shape's name)");
            }
            if s.tags.iter().any(|t| t.trim().is_empty()) {
                return bad("tags", "tags must not be empty strings");
            }
            match &s.geometry {
                Geometry::Box { min, max, yaw_deg } => {
                    if !finite3(min)
                        || !finite3(max)
                        || !yaw_deg.is_finite()
                        || !(Vec3::from(*max) - Vec3::from(*min)).cmpgt(Vec3::ZERO).all()
                    {
                        return bad("min/max", "need finite min < max on every axis");
                    }
                }
                Geometry::Sphere {
                    center,
                    radius,
                    subdivisions,
                } => {
                    rule("center", validate::each_finite(center), &v3(center))?;
                    positive("radius", *radius)?;
                    rule("subdivisions", validate::int_in(*subdivisions, 0, 5), subdivisions)?;
                }
                Geometry::Cylinder { a, b, radius, segments } => {
                    rule("a", validate::each_finite(a), &v3(a))?;
                    rule("b", validate::each_finite(b), &v3(b))?;
                    if (Vec3::from(*a) - Vec3::from(*b)).length() <= 0.0 {
                        return bad("a/b", "the ends must be distinct");
                    }
                    positive("radius", *radius)?;
                    rule("segments", validate::int_in(*segments, 3, 256), segments)?;
                }
                Geometry::Quad { origin, u, v } => {
                    if !finite3(origin) || Vec3::from(*u).cross(Vec3::from(*v)).length() <= 0.0 {
                        return bad("u/v", "need non-parallel edges");
                    }
                }
            }
            let m = &s.material;
            rule("material.kd", validate::each_in(&m.kd, 0.0, 1.0), &v3(&m.kd))?;
            rule("material.ks", validate::each_in(&m.ks, 0.0, 1.0), &v3(&m.ks))?;
            let roughness = validate::positive_up_to(m.roughness as f64, 1.0);
            rule("material.roughness", roughness, &m.roughness)?;
            match &m.texture {
                Some(TextureDesc::Checker { kd2, scale }) | Some(TextureDesc::Stripe { kd2, scale, .. }) => {
                    rule("material.texture.kd2", validate::each_in(kd2, 0.0, 1.0), &v3(kd2))?;
                    positive("material.texture.scale", *scale)?;
                }
                None => {}
            }
            if let Some(TextureDesc::Stripe { axis, .. }) = &m.texture {
                rule("material.texture.axis", validate::int_in(*axis, 0, 2), axis)?;
            }
            if let Some(e) = &s.emission {
                rule("emission", validate::each_non_negative(e), &v3(e))?;
                if e.iter().all(|x| *x == 0.0) {
                    return bad("emission", "must not be all zero");
                }
                emitters += 1;
            }
        }
        if emitters == 0 {
            return Err(DataError::field(path, "shape", "a scene needs at least one emitter"));
        }
        if emitters > crate::tracer::MAX_EMITTERS {
            return Err(DataError::field(
                path,
                "shape",
                format!("at most {} emitters", crate::tracer::MAX_EMITTERS),
            ));
        }
        Ok(())
    }
}
