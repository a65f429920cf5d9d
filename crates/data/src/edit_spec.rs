//! The edit spec of the house (docs/EDITING.md): a TOML list of `[[op]]`
//! tables in the dataset's world units, read by `i2sdf edit` and written by `synth` for its relit
//! views. Each op has a `kind`:
//! - `relight`: `at`, `scale` (≥ 0), optional `color` (≥ 0, default white): the emitter whose box is
//!   nearest to `at` ([`nearest_box`]);
//! - `material`: one region (`box` lo ≤ hi, `sphere`, `below` / `above` a plane) and one source: a
//!   `preset`, any of `kd` / `ks` (in [0, 1]) / `roughness` (in [0.01, 1]), or a projected
//!   `texture = { image, origin, u, v }` (with optional ks / roughness);
//! - `insert`: one shape (`sphere`, `box` lo < hi, `mesh = { path, scale, rotation, translation }`),
//!   a preset or values (default "matte"), optional `emission` (≥ 0): an emitting insert is a light.
//!
//! Paths are relative to the spec file's folder and stored resolved. Every value is validated on
//! read; errors name the op and key, e.g.
//! `spec.toml: op[2].box.lo: must be ≤ hi on every axis, found lo [0, 1, 0], hi [1, 0, 1]`.

use crate::error::{DataError, Result};
use crate::imageio::ImageF32;
use crate::validate;
use glam::{Quat, Vec3};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Largest texture side accepted (checked from the file header before decoding).
pub const MAX_TEXTURE_SIDE: usize = 16384;

/// A parsed, validated edit spec: the ops in file order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EditSpec {
    pub ops: Vec<EditOp>,
}

#[derive(Clone, Debug, PartialEq)]
pub enum EditOp {
    Relight(RelightOp),
    Material(MaterialOp),
    Insert(InsertOp),
}

/// Scales and tints the emitter nearest to `at`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RelightOp {
    pub at: [f32; 3],
    pub scale: f32,
    pub color: [f32; 3],
}

/// Overrides the recovered material inside `region`.
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialOp {
    pub region: Region,
    pub material: MaterialOverride,
}

/// Inserts an object (a light when `emission` is non-zero).
#[derive(Clone, Debug, PartialEq)]
pub struct InsertOp {
    pub shape: Shape,
    /// A preset or values (missing values from "matte"); never `Texture` (read rejects it).
    pub material: MaterialOverride,
    pub emission: Option<[f32; 3]>,
}

/// Where a material op applies. Boundaries are inside.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Region {
    Box {
        lo: [f32; 3],
        hi: [f32; 3],
    },
    Sphere {
        centre: [f32; 3],
        radius: f32,
    },
    /// Points with (p − point)·normal ≤ 0; `normal` is unit length after read.
    Below {
        point: [f32; 3],
        normal: [f32; 3],
    },
    /// Points with (p − point)·normal ≥ 0; `normal` is unit length after read.
    Above {
        point: [f32; 3],
        normal: [f32; 3],
    },
}

/// The geometry of an inserted object, in world units.
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    Sphere { centre: [f32; 3], radius: f32 },
    Box { lo: [f32; 3], hi: [f32; 3] },
    Mesh(MeshShape),
}

/// A PLY mesh placed by `world = rotation · (scale · p) + translation`.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshShape {
    /// Resolved against the spec's folder.
    pub path: PathBuf,
    pub scale: f32,
    /// XYZ Euler angles in degrees, applied x first, then y, then z.
    pub rotation: [f32; 3],
    pub translation: [f32; 3],
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preset {
    Mirror,
    Glossy,
    Matte,
}

/// A full material: Kd and Ks (linear RGB; Ks is GGX's F0) and roughness ρ (α = ρ²).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MaterialValues {
    pub kd: [f32; 3],
    pub ks: [f32; 3],
    pub roughness: f32,
}

/// Explicit values; `None` keeps the recovered (or, for inserts, the matte) value.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PartialMaterial {
    pub kd: Option<[f32; 3]>,
    pub ks: Option<[f32; 3]>,
    pub roughness: Option<f32>,
}

#[derive(Clone, Debug, PartialEq)]
pub enum MaterialOverride {
    Preset(Preset),
    Values(PartialMaterial),
    /// Kd from a projected image; ks / roughness as in `Values`.
    Texture {
        texture: Texture,
        ks: Option<[f32; 3]>,
        roughness: Option<f32>,
    },
}

/// An image projected along a plane: (s, t) = ((p − origin)·u / |u|², (p − origin)·v / |v|²).
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    /// Resolved against the spec's folder.
    pub image: PathBuf,
    pub origin: [f32; 3],
    pub u: [f32; 3],
    pub v: [f32; 3],
}

impl EditOp {
    pub fn relight(at: [f32; 3], scale: f32, color: [f32; 3]) -> EditOp {
        EditOp::Relight(RelightOp { at, scale, color })
    }
}

impl Preset {
    pub const ALL: [Preset; 3] = [Preset::Mirror, Preset::Glossy, Preset::Matte];

    pub fn name(self) -> &'static str {
        match self {
            Preset::Mirror => "mirror",
            Preset::Glossy => "glossy",
            Preset::Matte => "matte",
        }
    }

    pub fn parse(name: &str) -> Option<Preset> {
        Preset::ALL.into_iter().find(|p| p.name() == name)
    }

    /// The one definition of the presets. Mirror's ρ = 0.02 gives α = 4e-4, below the renderer's
    /// α floor (`ALPHA_MIN` = 1e-3), i.e. the sharpest lobe it renders.
    pub fn values(self) -> MaterialValues {
        let (kd, ks, roughness) = match self {
            Preset::Mirror => (0.0, 1.0, 0.02),
            Preset::Glossy => (0.3, 0.6, 0.2),
            Preset::Matte => (0.7, 0.0, 1.0),
        };
        MaterialValues {
            kd: [kd; 3],
            ks: [ks; 3],
            roughness,
        }
    }
}

impl MaterialOverride {
    /// The material at `p` given the `recovered` one; `texture` is the decoded image of a
    /// `Texture` override (`EditAssets::texture`); without it a texture keeps the recovered Kd.
    pub fn apply(&self, recovered: MaterialValues, p: Vec3, texture: Option<&ImageF32>) -> MaterialValues {
        match self {
            MaterialOverride::Preset(preset) => preset.values(),
            MaterialOverride::Values(v) => MaterialValues {
                kd: v.kd.unwrap_or(recovered.kd),
                ks: v.ks.unwrap_or(recovered.ks),
                roughness: v.roughness.unwrap_or(recovered.roughness),
            },
            MaterialOverride::Texture {
                texture: t,
                ks,
                roughness,
            } => MaterialValues {
                kd: texture.map_or(recovered.kd, |img| t.kd_at(p, img).to_array()),
                ks: ks.unwrap_or(recovered.ks),
                roughness: roughness.unwrap_or(recovered.roughness),
            },
        }
    }
}

impl InsertOp {
    /// The inserted object's material (missing explicit values from the matte preset).
    pub fn material_values(&self) -> MaterialValues {
        self.material.apply(Preset::Matte.values(), Vec3::ZERO, None)
    }

    /// Whether the object is a light (some emission channel > 0).
    pub fn is_emitter(&self) -> bool {
        self.emission.is_some_and(|e| e.iter().any(|c| *c > 0.0))
    }
}

impl Region {
    pub fn contains(&self, p: Vec3) -> bool {
        match *self {
            Region::Box { lo, hi } => p.cmpge(Vec3::from(lo)).all() && p.cmple(Vec3::from(hi)).all(),
            Region::Sphere { centre, radius } => (p - Vec3::from(centre)).length_squared() <= radius * radius,
            Region::Below { point, normal } => (p - Vec3::from(point)).dot(Vec3::from(normal)) <= 0.0,
            Region::Above { point, normal } => (p - Vec3::from(point)).dot(Vec3::from(normal)) >= 0.0,
        }
    }
}

impl Texture {
    /// Texture coordinates (s, t) of `p`, not yet wrapped.
    pub fn st(&self, p: Vec3) -> (f32, f32) {
        let d = p - Vec3::from(self.origin);
        let (u, v) = (Vec3::from(self.u), Vec3::from(self.v));
        (d.dot(u) / u.length_squared(), d.dot(v) / v.length_squared())
    }

    /// Bilinear lookup at `p` with wrapping; texel (x, y) has its centre at
    /// ((x + ½)/W, (y + ½)/H), row 0 at the top. Grey images give grey.
    pub fn kd_at(&self, p: Vec3, image: &ImageF32) -> Vec3 {
        let (s, t) = self.st(p);
        sample_bilinear_wrap(image, s, t)
    }
}

/// Bilinear, wrapped lookup of an image at (s, t) ∈ [0, 1]² (row 0 at t = 0) as RGB.
pub fn sample_bilinear_wrap(image: &ImageF32, s: f32, t: f32) -> Vec3 {
    let (w, h) = (image.width as i64, image.height as i64);
    if w == 0 || h == 0 || !s.is_finite() || !t.is_finite() {
        return Vec3::ZERO;
    }
    let x = s.rem_euclid(1.0) * w as f32 - 0.5;
    let y = t.rem_euclid(1.0) * h as f32 - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let texel = |xi: i64, yi: i64| {
        let px = image.pixel(xi.rem_euclid(w) as usize, yi.rem_euclid(h) as usize);
        if px.len() >= 3 {
            Vec3::new(px[0], px[1], px[2])
        } else {
            Vec3::splat(px[0])
        }
    };
    let (x0, y0) = (x0 as i64, y0 as i64);
    let top = texel(x0, y0) * (1.0 - fx) + texel(x0 + 1, y0) * fx;
    let bottom = texel(x0, y0 + 1) * (1.0 - fx) + texel(x0 + 1, y0 + 1) * fx;
    top * (1.0 - fy) + bottom * fy
}

impl MeshShape {
    pub fn rotation_quat(&self) -> Quat {
        let [rx, ry, rz] = self.rotation.map(f32::to_radians);
        Quat::from_rotation_z(rz) * Quat::from_rotation_y(ry) * Quat::from_rotation_x(rx)
    }

    /// A mesh-file point in world units: scale, then rotate (x, y, z), then translate.
    pub fn transform_point(&self, p: Vec3) -> Vec3 {
        self.rotation_quat() * (p * self.scale) + Vec3::from(self.translation)
    }
}

/// Distance from `p` to an axis-aligned box (0 inside).
fn box_distance(p: Vec3, lo: Vec3, hi: Vec3) -> f32 {
    (lo - p).max(p - hi).max(Vec3::ZERO).length()
}

/// The box nearest to `at`: smallest distance to the box, ties (e.g. `at` inside several boxes)
/// broken by the distance to the box centre, then by the lower index. Boxes with non-finite
/// corners and NaN distances sort last (never a panic).
pub fn nearest_box(boxes: &[(Vec3, Vec3)], at: Vec3) -> Option<usize> {
    let finite = |d: f32| if d.is_nan() { f32::INFINITY } else { d };
    let key = |&(lo, hi): &(Vec3, Vec3)| {
        if !(lo.is_finite() && hi.is_finite()) {
            return (f32::INFINITY, f32::INFINITY);
        }
        (
            finite(box_distance(at, lo, hi)),
            finite((0.5 * (lo + hi) - at).length()),
        )
    };
    (0..boxes.len()).min_by(|&a, &b| {
        let (ka, kb) = (key(&boxes[a]), key(&boxes[b]));
        ka.0.total_cmp(&kb.0).then(ka.1.total_cmp(&kb.1))
    })
}

// ---- serialization: one flat table per op, keys in a fixed order ---------------------------

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct BoxT {
    lo: [f32; 3],
    hi: [f32; 3],
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SphereT {
    centre: [f32; 3],
    radius: f32,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PlaneT {
    point: [f32; 3],
    normal: [f32; 3],
}

fn one() -> f32 {
    1.0
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct MeshT {
    path: String,
    #[serde(default = "one")]
    scale: f32,
    #[serde(default)]
    rotation: [f32; 3],
    #[serde(default)]
    translation: [f32; 3],
}

impl From<&MeshShape> for MeshT {
    fn from(m: &MeshShape) -> MeshT {
        let path = path_string(&m.path);
        let (scale, rotation, translation) = (m.scale, m.rotation, m.translation);
        MeshT {
            path,
            scale,
            rotation,
            translation,
        }
    }
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TextureT {
    image: String,
    origin: [f32; 3],
    u: [f32; 3],
    v: [f32; 3],
}

/// What one `[[op]]` table is written as (toml skips `None` fields). The order of the relight
/// keys (kind, at, scale, color) is the one synth has always written.
#[derive(Serialize, Default)]
struct OpOut {
    kind: &'static str,
    at: Option<[f32; 3]>,
    scale: Option<f32>,
    color: Option<[f32; 3]>,
    #[serde(rename = "box")]
    box_: Option<BoxT>,
    sphere: Option<SphereT>,
    below: Option<PlaneT>,
    above: Option<PlaneT>,
    mesh: Option<MeshT>,
    preset: Option<&'static str>,
    kd: Option<[f32; 3]>,
    ks: Option<[f32; 3]>,
    roughness: Option<f32>,
    texture: Option<TextureT>,
    emission: Option<[f32; 3]>,
}

#[derive(Serialize)]
struct SpecOut {
    op: Vec<OpOut>,
}

fn path_string(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

impl OpOut {
    fn set_material(&mut self, m: &MaterialOverride) {
        match m {
            MaterialOverride::Preset(p) => self.preset = Some(p.name()),
            MaterialOverride::Values(v) => (self.kd, self.ks, self.roughness) = (v.kd, v.ks, v.roughness),
            MaterialOverride::Texture { texture, ks, roughness } => {
                self.texture = Some(TextureT {
                    image: path_string(&texture.image),
                    origin: texture.origin,
                    u: texture.u,
                    v: texture.v,
                });
                (self.ks, self.roughness) = (*ks, *roughness);
            }
        }
    }

    fn from_op(op: &EditOp) -> OpOut {
        match op {
            EditOp::Relight(r) => OpOut {
                kind: "relight",
                at: Some(r.at),
                scale: Some(r.scale),
                color: Some(r.color),
                ..Default::default()
            },
            EditOp::Material(m) => {
                let mut out = OpOut {
                    kind: "material",
                    ..Default::default()
                };
                match m.region {
                    Region::Box { lo, hi } => out.box_ = Some(BoxT { lo, hi }),
                    Region::Sphere { centre, radius } => out.sphere = Some(SphereT { centre, radius }),
                    Region::Below { point, normal } => out.below = Some(PlaneT { point, normal }),
                    Region::Above { point, normal } => out.above = Some(PlaneT { point, normal }),
                }
                out.set_material(&m.material);
                out
            }
            EditOp::Insert(ins) => {
                let mut out = OpOut {
                    kind: "insert",
                    emission: ins.emission,
                    ..Default::default()
                };
                match ins.shape {
                    Shape::Sphere { centre, radius } => out.sphere = Some(SphereT { centre, radius }),
                    Shape::Box { lo, hi } => out.box_ = Some(BoxT { lo, hi }),
                    Shape::Mesh(ref m) => out.mesh = Some(MeshT::from(m)),
                }
                out.set_material(&ins.material);
                out
            }
        }
    }
}

// ---- reading ---------------------------------------------------------------------------------

const RELIGHT_KEYS: &str = "kind at scale color";
const MATERIAL_KEYS: &str = "kind box sphere below above preset kd ks roughness texture";
const INSERT_KEYS: &str = "kind sphere box mesh preset kd ks roughness emission";

/// Reading context of one op: the spec file, its folder and the op index.
struct OpReader<'a> {
    path: &'a Path,
    base: &'a Path,
    index: usize,
    table: &'a toml::Table,
}

pub(crate) fn fmt3(v: [f32; 3]) -> String {
    format!("[{}, {}, {}]", v[0], v[1], v[2])
}

impl OpReader<'_> {
    fn err(&self, key: &str, msg: impl Into<String>) -> DataError {
        let field = if key.is_empty() {
            format!("op[{}]", self.index)
        } else {
            format!("op[{}].{key}", self.index)
        };
        DataError::field(self.path, field, msg)
    }

    fn get<T: DeserializeOwned>(&self, key: &str) -> Result<Option<T>> {
        self.table
            .get(key)
            .map(|v| {
                v.clone()
                    .try_into::<T>()
                    .map_err(|e| self.err(key, e.message().to_string()))
            })
            .transpose()
    }

    /// `Ok(())` when `ok`, else the error `msg` at `key`.
    fn ensure(&self, ok: bool, key: &str, msg: impl FnOnce() -> String) -> Result<()> {
        ok.then_some(()).ok_or_else(|| self.err(key, msg()))
    }

    fn require<T: DeserializeOwned>(&self, key: &str) -> Result<T> {
        self.get(key)?.ok_or_else(|| self.err(key, "missing"))
    }

    fn check_keys(&self, kind: &str, allowed: &str) -> Result<()> {
        let allowed: Vec<&str> = allowed.split(' ').collect();
        match self.table.keys().find(|k| !allowed.contains(&k.as_str())) {
            Some(key) if kind == "insert" && key == "texture" => Err(self.err(
                key,
                "unknown key: inserted objects take a preset or kd / ks / roughness, not a texture",
            )),
            Some(key) => Err(self.err(
                key,
                format!(
                    "unknown key for {} \"{kind}\" op (allowed: {})",
                    if kind == "insert" { "an" } else { "a" },
                    allowed.join(", ")
                ),
            )),
            None => Ok(()),
        }
    }

    /// A [`validate`] rule's failure at `key`, with the value found.
    fn rule(&self, key: &str, rule: std::result::Result<(), String>, found: impl FnOnce() -> String) -> Result<()> {
        rule.map_err(|m| self.err(key, format!("{m}, found {}", found())))
    }

    fn finite3(&self, key: &str, v: [f32; 3]) -> Result<[f32; 3]> {
        self.rule(key, validate::each_finite(&v), || fmt3(v)).map(|_| v)
    }

    fn in_range3(&self, key: &str, v: [f32; 3], lo: f32, hi: f32) -> Result<[f32; 3]> {
        self.rule(key, validate::each_in(&v, lo, hi), || fmt3(v)).map(|_| v)
    }

    fn non_negative3(&self, key: &str, v: [f32; 3]) -> Result<[f32; 3]> {
        self.rule(key, validate::each_non_negative(&v), || fmt3(v)).map(|_| v)
    }

    fn positive(&self, key: &str, x: f32) -> Result<f32> {
        self.rule(key, validate::positive_up_to(x as f64, f64::INFINITY), || x.to_string())
            .map(|_| x)
    }

    fn non_zero3(&self, key: &str, v: [f32; 3]) -> Result<Vec3> {
        let v = Vec3::from(self.finite3(key, v)?);
        let ok = v.length_squared() > 0.0 && v.length_squared().is_finite();
        self.ensure(ok, key, || {
            format!("must be a non-zero vector, found {}", fmt3(v.to_array()))
        })
        .map(|_| v)
    }

    /// The resolved path of a file the op names; it must exist.
    fn file(&self, key: &str, rel: &str) -> Result<PathBuf> {
        let resolved = self.base.join(rel);
        let ok = resolved.is_file();
        self.ensure(ok, key, || match resolved.exists() {
            true => format!("not a file: {}", resolved.display()),
            false => format!("file not found: {}", resolved.display()),
        })
        .map(|_| resolved)
    }

    /// Exactly one of `keys` present: its name.
    fn exactly_one(&self, what: &str, keys: &[&'static str]) -> Result<&'static str> {
        let present: Vec<&'static str> = keys.iter().copied().filter(|k| self.table.contains_key(*k)).collect();
        let options = keys.join(", ");
        match present.as_slice() {
            [one] => Ok(one),
            [] => Err(self.err("", format!("needs exactly one {what} ({options}), found none"))),
            several => Err(self.err(
                "",
                format!("needs exactly one {what} ({options}), found {}", several.join(" and ")),
            )),
        }
    }

    fn read_box(&self, key: &str, strict: bool) -> Result<([f32; 3], [f32; 3])> {
        let b: BoxT = self.require(key)?;
        let lo = self.finite3(&format!("{key}.lo"), b.lo)?;
        let hi = self.finite3(&format!("{key}.hi"), b.hi)?;
        let ok = (0..3).all(|a| if strict { lo[a] < hi[a] } else { lo[a] <= hi[a] });
        let rel = if strict { "<" } else { "≤" };
        let msg = || format!("must be {rel} hi on every axis, found lo {}, hi {}", fmt3(lo), fmt3(hi));
        self.ensure(ok, &format!("{key}.lo"), msg).map(|_| (lo, hi))
    }

    fn read_sphere(&self) -> Result<([f32; 3], f32)> {
        let s: SphereT = self.require("sphere")?;
        let centre = self.finite3("sphere.centre", s.centre)?;
        Ok((centre, self.positive("sphere.radius", s.radius)?))
    }

    fn read_plane(&self, key: &str) -> Result<([f32; 3], [f32; 3])> {
        let p: PlaneT = self.require(key)?;
        let point = self.finite3(&format!("{key}.point"), p.point)?;
        let normal = self.non_zero3(&format!("{key}.normal"), p.normal)?;
        Ok((point, normal.normalize().to_array()))
    }

    fn read_relight(&self) -> Result<RelightOp> {
        self.check_keys("relight", RELIGHT_KEYS)?;
        let at = self.finite3("at", self.require("at")?)?;
        let scale: f32 = self.require("scale")?;
        self.rule("scale", validate::non_negative(scale as f64), || scale.to_string())?;
        let color = self.non_negative3("color", self.get("color")?.unwrap_or([1.0; 3]))?;
        Ok(RelightOp { at, scale, color })
    }

    fn read_values(&self) -> Result<PartialMaterial> {
        let kd = self.get("kd")?.map(|v| self.in_range3("kd", v, 0.0, 1.0)).transpose()?;
        let ks = self.get("ks")?.map(|v| self.in_range3("ks", v, 0.0, 1.0)).transpose()?;
        let roughness = self.get::<f32>("roughness")?;
        if let Some(r) = roughness {
            self.rule("roughness", validate::real_in(r, 0.01, 1.0), || r.to_string())?;
        }
        Ok(PartialMaterial { kd, ks, roughness })
    }

    /// The material source of a material or insert op; `None` when none is given.
    fn read_material(&self) -> Result<Option<MaterialOverride>> {
        let has = |k: &str| self.table.contains_key(k);
        let values = ["kd", "ks", "roughness"];
        if has("preset") {
            let others: Vec<&str> = ["kd", "ks", "roughness", "texture"]
                .into_iter()
                .filter(|k| has(k))
                .collect();
            let msg = || format!("a preset cannot be combined with {}", others.join(" / "));
            self.ensure(others.is_empty(), "preset", msg)?;
            let name: String = self.require("preset")?;
            let preset = Preset::parse(&name).ok_or_else(|| {
                self.err(
                    "preset",
                    format!("unknown preset \"{name}\" (expected \"mirror\", \"glossy\" or \"matte\")"),
                )
            })?;
            return Ok(Some(MaterialOverride::Preset(preset)));
        }
        if has("texture") {
            self.ensure(!has("kd"), "texture", || {
                "a texture gives kd; it cannot be combined with kd".into()
            })?;
            let t: TextureT = self.require("texture")?;
            let image = self.file("texture.image", &t.image)?;
            let ext = image
                .extension()
                .and_then(|e| e.to_str())
                .unwrap_or("")
                .to_ascii_lowercase();
            let msg = || format!("must be a .png or .exr image, found {}", image.display());
            self.ensure(ext == "png" || ext == "exr", "texture.image", msg)?;
            let origin = self.finite3("texture.origin", t.origin)?;
            let u = self.non_zero3("texture.u", t.u)?;
            let v = self.non_zero3("texture.v", t.v)?;
            let ok = u.cross(v).length() > 1e-6 * u.length() * v.length();
            let msg = || format!("must not be parallel to u, found u {}, v {}", fmt3(t.u), fmt3(t.v));
            self.ensure(ok, "texture.v", msg)?;
            let p = self.read_values()?;
            let texture = Texture {
                image,
                origin,
                u: t.u,
                v: t.v,
            };
            return Ok(Some(MaterialOverride::Texture {
                texture,
                ks: p.ks,
                roughness: p.roughness,
            }));
        }
        if values.iter().any(|k| has(k)) {
            return Ok(Some(MaterialOverride::Values(self.read_values()?)));
        }
        Ok(None)
    }

    fn read_material_op(&self) -> Result<MaterialOp> {
        self.check_keys("material", MATERIAL_KEYS)?;
        let region = match self.exactly_one("region", &["box", "sphere", "below", "above"])? {
            "box" => self.read_box("box", false).map(|(lo, hi)| Region::Box { lo, hi })?,
            "sphere" => self
                .read_sphere()
                .map(|(centre, radius)| Region::Sphere { centre, radius })?,
            "below" => self
                .read_plane("below")
                .map(|(point, normal)| Region::Below { point, normal })?,
            _ => self
                .read_plane("above")
                .map(|(point, normal)| Region::Above { point, normal })?,
        };
        let material = self.read_material()?.ok_or_else(|| {
            self.err(
                "",
                "needs a material: preset, kd / ks / roughness values or a texture, found none",
            )
        })?;
        Ok(MaterialOp { region, material })
    }

    fn read_insert(&self) -> Result<InsertOp> {
        self.check_keys("insert", INSERT_KEYS)?;
        let shape = match self.exactly_one("shape", &["sphere", "box", "mesh"])? {
            "sphere" => self
                .read_sphere()
                .map(|(centre, radius)| Shape::Sphere { centre, radius })?,
            "box" => self.read_box("box", true).map(|(lo, hi)| Shape::Box { lo, hi })?,
            _ => {
                let m: MeshT = self.require("mesh")?;
                let path = self.file("mesh.path", &m.path)?;
                Shape::Mesh(MeshShape {
                    path,
                    scale: self.positive("mesh.scale", m.scale)?,
                    rotation: self.finite3("mesh.rotation", m.rotation)?,
                    translation: self.finite3("mesh.translation", m.translation)?,
                })
            }
        };
        let material = self.read_material()?.unwrap_or(MaterialOverride::Preset(Preset::Matte));
        let emission = self
            .get("emission")?
            .map(|e| self.non_negative3("emission", e))
            .transpose()?;
        Ok(InsertOp {
            shape,
            material,
            emission,
        })
    }

    fn read_op(&self) -> Result<EditOp> {
        let kind = match self.table.get("kind") {
            Some(toml::Value::String(s)) => s.as_str(),
            Some(_) => return Err(self.err("kind", "must be a string: \"relight\", \"material\" or \"insert\"")),
            None => return Err(self.err("kind", "missing (\"relight\", \"material\" or \"insert\")")),
        };
        match kind {
            "relight" => self.read_relight().map(EditOp::Relight),
            "material" => self.read_material_op().map(EditOp::Material),
            "insert" => self.read_insert().map(EditOp::Insert),
            other => Err(self.err(
                "kind",
                format!("unknown kind \"{other}\" (expected \"relight\", \"material\" or \"insert\")"),
            )),
        }
    }
}

impl EditSpec {
    /// Reads and validates a spec file; relative paths resolve against its folder.
    pub fn read(path: &Path) -> Result<EditSpec> {
        let text = std::fs::read_to_string(path).map_err(|e| DataError::file(path, format!("cannot read: {e}")))?;
        EditSpec::from_toml_str(&text, path)
    }

    /// Parses and validates spec text as if read from `path` (errors name it; relative paths
    /// resolve against its folder, and the files they name must exist).
    pub fn from_toml_str(text: &str, path: &Path) -> Result<EditSpec> {
        let doc: toml::Table =
            toml::from_str(text).map_err(|e| DataError::file(path, format!("bad edit spec: {e}")))?;
        if let Some(key) = doc.keys().find(|k| *k != "op") {
            return Err(DataError::field(
                path,
                key.as_str(),
                "unknown key (an edit spec is a list of [[op]] tables)",
            ));
        }
        let tables = match doc.get("op") {
            None => return Ok(EditSpec::default()),
            Some(toml::Value::Array(a)) => a,
            Some(_) => return Err(DataError::field(path, "op", "must be a list of [[op]] tables")),
        };
        let base = path.parent().unwrap_or(Path::new(""));
        let mut ops = Vec::with_capacity(tables.len());
        for (index, value) in tables.iter().enumerate() {
            let table = value
                .as_table()
                .ok_or_else(|| DataError::field(path, format!("op[{index}]"), "must be a table"))?;
            let reader = OpReader {
                path,
                base,
                index,
                table,
            };
            ops.push(reader.read_op()?);
        }
        Ok(EditSpec { ops })
    }

    /// The spec as TOML (paths as stored, i.e. resolved). Relight ops are written exactly as
    /// synth has always written them.
    pub fn to_toml_string(&self) -> String {
        let out = SpecOut {
            op: self.ops.iter().map(OpOut::from_op).collect(),
        };
        toml::to_string_pretty(&out).expect("edit specs always serialize")
    }

    /// Per-emitter RGB gains (emitters given by their bounding boxes): the product of
    /// `scale · color` of every relight op whose `at` selects the emitter (`nearest_box`).
    pub fn emitter_gains(&self, boxes: &[(Vec3, Vec3)]) -> Vec<Vec3> {
        let mut gains = vec![Vec3::ONE; boxes.len()];
        for op in &self.ops {
            if let EditOp::Relight(r) = op {
                if let Some(k) = nearest_box(boxes, Vec3::from(r.at)) {
                    gains[k] *= r.scale * Vec3::from(r.color);
                }
            }
        }
        gains
    }
}
