//! Procedural rooms. A preset names a kind of room; a seed picks its size, colours and the
//! positions of its furniture. Every room is closed (floor, four walls, ceiling), has a ceiling
//! light panel and a floor lamp with a thin pole (~1–2 px at 160×120) and a bare bulb, a
//! chandelier-like cluster of small spheres suspended from the ceiling, furniture of very different
//! sizes (thin table legs included), diffuse and glossy materials and checker/stripe textures.
//! Every shape belongs to a named, tagged object (see [`crate::scene::tags`]), so that evaluation
//! can score the thin and suspended objects on their own.

use crate::scene::tags::{FURNITURE, ROOM, SMALL, SUSPENDED, THIN};
use crate::scene::{CameraRig, Geometry, MaterialDesc, RoomBounds, SceneDesc, ShapeDesc, TextureDesc};
use glam::{Quat, Vec3};
use i2sdf_data::DataError;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RoomPreset {
    Bedroom,
    Livingroom,
}

impl RoomPreset {
    pub const ALL: [RoomPreset; 2] = [RoomPreset::Bedroom, RoomPreset::Livingroom];

    pub fn name(self) -> &'static str {
        match self {
            RoomPreset::Bedroom => "bedroom",
            RoomPreset::Livingroom => "livingroom",
        }
    }

    pub fn parse(name: &str) -> Result<Self, DataError> {
        Self::ALL.into_iter().find(|p| p.name() == name).ok_or_else(|| {
            DataError::invalid(format!(
                "unknown preset `{name}` (expected one of: bedroom, livingroom)"
            ))
        })
    }

    pub fn build(self, seed: u64) -> SceneDesc {
        let mut b = RoomBuilder::new(self.name(), seed);
        match self {
            RoomPreset::Bedroom => b.bedroom(),
            RoomPreset::Livingroom => b.livingroom(),
        }
        b.finish()
    }
}

fn mat(kd: [f32; 3], ks: f32, roughness: f32) -> MaterialDesc {
    MaterialDesc {
        kd,
        ks: [ks; 3],
        roughness,
        texture: None,
    }
}

/// An object's frame: local +z faces into the room, local x runs along its wall.
#[derive(Clone, Copy)]
struct Placement {
    origin: Vec3,
    yaw: f32,
}

impl Placement {
    fn to_world(&self, local: Vec3) -> Vec3 {
        self.origin + Quat::from_rotation_y(self.yaw) * local
    }
}

struct RoomBuilder {
    name: String,
    rng: Pcg64,
    lo: Vec3,
    hi: Vec3,
    shapes: Vec<ShapeDesc>,
    /// Occupied floor rectangles (xz min, xz max) for non-overlapping placement.
    footprints: Vec<([f32; 2], [f32; 2])>,
    /// Centre (x, z) and half size of the ceiling light panel, which the chandelier keeps clear of.
    panel: ([f32; 2], [f32; 2]),
    /// The object (name, tags) the shapes added next belong to; see [`RoomBuilder::object`].
    object: (String, Vec<String>),
}

impl RoomBuilder {
    fn new(name: &str, seed: u64) -> Self {
        let mut rng = Pcg64::seed_from_u64(seed ^ 0x5EED_0F_A_B00C);
        let (w, d, h) = (
            rng.gen_range(4.6..5.6f32),
            rng.gen_range(3.8..4.6f32),
            rng.gen_range(2.6..2.9f32),
        );
        let (lo, hi) = (Vec3::new(-w / 2.0, 0.0, -d / 2.0), Vec3::new(w / 2.0, h, d / 2.0));
        let mut b = RoomBuilder {
            name: name.to_string(),
            rng,
            lo,
            hi,
            shapes: Vec::new(),
            footprints: Vec::new(),
            panel: ([0.0; 2], [0.0; 2]),
            object: (String::new(), Vec::new()),
        };
        b.shell();
        b
    }

    /// Starts an object: every shape added until the next call belongs to it.
    fn object(&mut self, name: &str, tags: &[&str]) {
        self.object = (name.to_string(), tags.iter().map(|t| t.to_string()).collect());
    }

    /// The current object, as a shape records it: left out where the shape is the whole object
    /// and carries its name, so that scene.toml stays terse.
    fn object_of(&self, shape: &str) -> (Option<String>, Vec<String>) {
        let (name, tags) = &self.object;
        assert!(!name.is_empty(), "shape {shape} added outside an object");
        ((name != shape).then(|| name.clone()), tags.clone())
    }

    fn add(&mut self, name: &str, geometry: Geometry, material: MaterialDesc) {
        let (object, tags) = self.object_of(name);
        self.shapes.push(ShapeDesc {
            name: name.to_string(),
            object,
            tags,
            geometry,
            material,
            emission: None,
        });
    }

    fn add_emitter(&mut self, name: &str, geometry: Geometry, emission: [f32; 3]) {
        let black = mat([0.0; 3], 0.0, 1.0);
        let (object, tags) = self.object_of(name);
        self.shapes.push(ShapeDesc {
            name: name.to_string(),
            object,
            tags,
            geometry,
            material: black,
            emission: Some(emission),
        });
    }

    fn pastel(&mut self) -> [f32; 3] {
        let base = self.rng.gen_range(0.55..0.8f32);
        [
            base + self.rng.gen_range(-0.1..0.1),
            base + self.rng.gen_range(-0.1..0.1),
            base + self.rng.gen_range(-0.1..0.1),
        ]
    }

    fn saturated(&mut self) -> [f32; 3] {
        let hues = [
            [0.6, 0.15, 0.1],
            [0.15, 0.35, 0.6],
            [0.2, 0.5, 0.25],
            [0.65, 0.5, 0.12],
            [0.45, 0.2, 0.5],
        ];
        let c = hues[self.rng.gen_range(0..hues.len())];
        let s = self.rng.gen_range(0.8..1.1f32);
        [c[0] * s, c[1] * s, c[2] * s]
    }

    /// Floor, ceiling and four walls as one-sided quads facing into the room, plus the ceiling
    /// light panel (an emitting quad 5 mm under the ceiling).
    fn shell(&mut self) {
        let (lo, hi) = (self.lo, self.hi);
        let (w, h, d) = (hi.x - lo.x, hi.y - lo.y, hi.z - lo.z);
        let wood_a = [
            self.rng.gen_range(0.4..0.55),
            self.rng.gen_range(0.25..0.35),
            self.rng.gen_range(0.12..0.2),
        ];
        let wood_b = [wood_a[0] * 0.7, wood_a[1] * 0.7, wood_a[2] * 0.7];
        let floor_texture = if self.rng.gen_bool(0.5) {
            TextureDesc::Checker {
                kd2: wood_b,
                scale: 0.4,
            }
        } else {
            TextureDesc::Stripe {
                kd2: wood_b,
                scale: 0.18,
                axis: 0,
            }
        };
        let floor = MaterialDesc {
            kd: wood_a,
            ks: [0.04; 3],
            roughness: 0.5,
            texture: Some(floor_texture),
        };
        self.object("floor", &[ROOM]);
        self.add(
            "floor",
            Geometry::Quad {
                origin: lo.into(),
                u: [0.0, 0.0, d],
                v: [w, 0.0, 0.0],
            },
            floor,
        );
        self.object("ceiling", &[ROOM]);
        self.add(
            "ceiling",
            Geometry::Quad {
                origin: [lo.x, hi.y, lo.z],
                u: [w, 0.0, 0.0],
                v: [0.0, 0.0, d],
            },
            mat([0.85; 3], 0.0, 1.0),
        );
        let wall = self.pastel();
        let accent = self.pastel();
        let paper = MaterialDesc {
            kd: accent,
            ks: [0.0; 3],
            roughness: 0.8,
            texture: Some(TextureDesc::Stripe {
                kd2: [accent[0] * 0.75, accent[1] * 0.8, accent[2] * 0.85],
                scale: 0.12,
                axis: 0,
            }),
        };
        self.object("wall_back", &[ROOM]);
        self.add(
            "wall_back",
            Geometry::Quad {
                origin: lo.into(),
                u: [w, 0.0, 0.0],
                v: [0.0, h, 0.0],
            },
            paper,
        );
        self.object("wall_front", &[ROOM]);
        self.add(
            "wall_front",
            Geometry::Quad {
                origin: [lo.x, 0.0, hi.z],
                u: [0.0, h, 0.0],
                v: [w, 0.0, 0.0],
            },
            mat(wall, 0.0, 0.9),
        );
        self.object("wall_left", &[ROOM]);
        self.add(
            "wall_left",
            Geometry::Quad {
                origin: lo.into(),
                u: [0.0, h, 0.0],
                v: [0.0, 0.0, d],
            },
            mat(wall, 0.0, 0.9),
        );
        self.object("wall_right", &[ROOM]);
        self.add(
            "wall_right",
            Geometry::Quad {
                origin: [hi.x, 0.0, lo.z],
                u: [0.0, 0.0, d],
                v: [0.0, h, 0.0],
            },
            mat(wall, 0.0, 0.9),
        );
        let (pw, pd) = (self.rng.gen_range(1.2..1.6f32), self.rng.gen_range(0.7..0.9f32));
        // The panel sits in one half of the room (along x), the chandelier in the other.
        let side = if self.rng.gen_bool(0.5) { 1.0f32 } else { -1.0 };
        let (px, pz) = (side * self.rng.gen_range(0.5..0.8f32), self.rng.gen_range(-0.3..0.3f32));
        self.panel = ([px, pz], [pw / 2.0, pd / 2.0]);
        let y = hi.y - 0.005;
        let e = self.rng.gen_range(4.0..5.0f32);
        self.object("ceiling_light", &[]);
        self.add_emitter(
            "ceiling_light",
            Geometry::Quad {
                origin: [px - pw / 2.0, y, pz - pd / 2.0],
                u: [pw, 0.0, 0.0],
                v: [0.0, 0.0, pd],
            },
            [e, e * 0.97, e * 0.92],
        );
    }

    /// Finds a spot against a random wall for a footprint `width` (along the wall) × `depth`,
    /// keeping `gap` to the wall and 0.1 m to other furniture.
    fn against_wall(&mut self, width: f32, depth: f32, gap: f32) -> Option<Placement> {
        for _ in 0..200 {
            let wall = self.rng.gen_range(0..4);
            let (yaw, along_len) = match wall {
                0 => (0.0f32, self.hi.x - self.lo.x),
                1 => (std::f32::consts::PI, self.hi.x - self.lo.x),
                2 => (std::f32::consts::FRAC_PI_2, self.hi.z - self.lo.z),
                _ => (-std::f32::consts::FRAC_PI_2, self.hi.z - self.lo.z),
            };
            let slack = along_len / 2.0 - width / 2.0 - 0.15;
            if slack <= 0.0 {
                continue;
            }
            let s = self.rng.gen_range(-slack..slack);
            let off = gap + depth / 2.0;
            let origin = match wall {
                0 => Vec3::new(s, 0.0, self.lo.z + off),
                1 => Vec3::new(s, 0.0, self.hi.z - off),
                2 => Vec3::new(self.lo.x + off, 0.0, s),
                _ => Vec3::new(self.hi.x - off, 0.0, s),
            };
            let p = Placement { origin, yaw };
            if self.claim(p, width, depth) {
                return Some(p);
            }
        }
        None
    }

    /// Reserves the footprint of a `width` × `depth` object at `p` if it overlaps nothing.
    fn claim(&mut self, p: Placement, width: f32, depth: f32) -> bool {
        let a = p.to_world(Vec3::new(-width / 2.0, 0.0, -depth / 2.0));
        let b = p.to_world(Vec3::new(width / 2.0, 0.0, depth / 2.0));
        let (lo, hi) = (
            [a.x.min(b.x) - 0.1, a.z.min(b.z) - 0.1],
            [a.x.max(b.x) + 0.1, a.z.max(b.z) + 0.1],
        );
        if self
            .footprints
            .iter()
            .any(|(l, h)| lo[0] < h[0] && hi[0] > l[0] && lo[1] < h[1] && hi[1] > l[1])
        {
            return false;
        }
        self.footprints.push((lo, hi));
        true
    }

    /// A box given in the object's local frame (local min/max), rotated with the object.
    fn local_box(&mut self, p: Placement, name: &str, lmin: [f32; 3], lmax: [f32; 3], m: MaterialDesc) {
        let (lmin, lmax) = (Vec3::from(lmin), Vec3::from(lmax));
        let c = p.to_world(0.5 * (lmin + lmax));
        let half = 0.5 * (lmax - lmin);
        self.add(
            name,
            Geometry::Box {
                min: (c - half).into(),
                max: (c + half).into(),
                yaw_deg: p.yaw.to_degrees(),
            },
            m,
        );
    }

    fn local_cylinder(
        &mut self,
        p: Placement,
        name: &str,
        a: [f32; 3],
        b: [f32; 3],
        radius: f32,
        segments: u32,
        m: MaterialDesc,
    ) {
        let (a, b) = (p.to_world(a.into()), p.to_world(b.into()));
        self.add(
            name,
            Geometry::Cylinder {
                a: a.into(),
                b: b.into(),
                radius,
                segments,
            },
            m,
        );
    }

    /// Floor lamp in a free corner: base disc, a pole of radius 13–16 mm (1–2 px at 160×120 from
    /// a few metres) and a bare spherical bulb emitter.
    fn floor_lamp(&mut self, name: &str) {
        // Far enough from the walls that the bulb does not make a small, very bright hot spot
        // on them (indirect light from such a spot is the noisiest part of the image).
        let inset = 0.6;
        let corners = [
            (self.lo.x + inset, self.lo.z + inset),
            (self.hi.x - inset, self.lo.z + inset),
            (self.lo.x + inset, self.hi.z - inset),
            (self.hi.x - inset, self.hi.z - inset),
        ];
        let start = self.rng.gen_range(0..4);
        let mut spot = None;
        for k in 0..4 {
            let (x, z) = corners[(start + k) % 4];
            let p = Placement {
                origin: Vec3::new(x, 0.0, z),
                yaw: 0.0,
            };
            if self.claim(p, 0.4, 0.4) {
                spot = Some(p);
                break;
            }
        }
        let Some(p) = spot else { return };
        let metal = mat([0.15, 0.15, 0.16], 0.6, 0.3);
        let height = self.rng.gen_range(1.4..1.7f32);
        let radius = self.rng.gen_range(0.013..0.016f32);
        self.object(&format!("{name}_base"), &[FURNITURE]);
        self.local_cylinder(
            p,
            &format!("{name}_base"),
            [0.0, 0.0, 0.0],
            [0.0, 0.03, 0.0],
            0.16,
            32,
            metal.clone(),
        );
        self.object(&format!("{name}_pole"), &[THIN]);
        self.local_cylinder(
            p,
            &format!("{name}_pole"),
            [0.0, 0.03, 0.0],
            [0.0, height, 0.0],
            radius,
            12,
            metal,
        );
        // The bulb floats 4 cm above the pole's top. Any surface touching an emitter has an
        // irradiance singularity (1/d² next to the contact) that light sampling reaches with
        // unbounded variance: a pole into or under the bulb filled every image with fireflies.
        let e = self.rng.gen_range(12.0..16.0f32);
        self.object(&format!("{name}_bulb"), &[]);
        let c = p.to_world(Vec3::new(0.0, height + 0.04 + 0.1, 0.0));
        self.add_emitter(
            &format!("{name}_bulb"),
            Geometry::Sphere {
                center: c.into(),
                radius: 0.1,
                subdivisions: 2,
            },
            [e, e * 0.8, e * 0.55],
        );
    }

    /// A chandelier-like suspended cluster: a rod from the ceiling, a hub, and a ring of small
    /// glossy spheres on thin arms at alternating heights.
    fn chandelier(&mut self) {
        // Hang it well clear of the light panel: a rod through an emitter would put surfaces
        // millimetres from it, whose 1/d² irradiance only fireflies can sample.
        let ([px, pz], [hx, _]) = self.panel;
        let cx = px - px.signum() * (hx + self.rng.gen_range(0.7..0.9f32));
        let c = Vec3::new(cx, 0.0, pz + self.rng.gen_range(-0.3..0.3));
        let hub_y = self.hi.y - self.rng.gen_range(0.55..0.75f32);
        let brass = MaterialDesc {
            kd: [0.45, 0.35, 0.15],
            ks: [0.55, 0.45, 0.25],
            roughness: 0.3,
            texture: None,
        };
        let glass = MaterialDesc {
            kd: [0.8, 0.8, 0.75],
            ks: [0.2; 3],
            roughness: 0.35,
            texture: None,
        };
        // Two objects: the rod and arms (1–2 cm across: thin) and the hub with its globes (8–12 cm),
        // so that the thin-object score is not carried by the globes.
        self.object("chandelier_rods", &[THIN, SUSPENDED]);
        self.add(
            "chandelier_rod",
            Geometry::Cylinder {
                a: [c.x, hub_y, c.z],
                b: [c.x, self.hi.y, c.z],
                radius: 0.01,
                segments: 8,
            },
            brass.clone(),
        );
        self.object("chandelier_globes", &[SUSPENDED]);
        self.add(
            "chandelier_hub",
            Geometry::Sphere {
                center: [c.x, hub_y, c.z],
                radius: 0.06,
                subdivisions: 2,
            },
            brass.clone(),
        );
        let n = self.rng.gen_range(5..8);
        let ring = self.rng.gen_range(0.28..0.36f32);
        let phase = self.rng.gen_range(0.0..1.0f32);
        for i in 0..n {
            let phi = std::f32::consts::TAU * (i as f32 + phase) / n as f32;
            let dy = if i % 2 == 0 { -0.12 } else { -0.04 };
            let ball = Vec3::new(c.x + ring * phi.cos(), hub_y + dy, c.z + ring * phi.sin());
            let r = if i % 2 == 0 { 0.05 } else { 0.04 };
            self.object("chandelier_rods", &[THIN, SUSPENDED]);
            self.add(
                &format!("chandelier_arm_{i}"),
                Geometry::Cylinder {
                    a: [c.x, hub_y, c.z],
                    b: ball.into(),
                    radius: 0.006,
                    segments: 6,
                },
                brass.clone(),
            );
            self.object("chandelier_globes", &[SUSPENDED]);
            self.add(
                &format!("chandelier_ball_{i}"),
                Geometry::Sphere {
                    center: ball.into(),
                    radius: r,
                    subdivisions: 2,
                },
                glass.clone(),
            );
        }
    }

    fn bedroom(&mut self) {
        self.floor_lamp("floor_lamp");
        self.chandelier();
        let frame_color = self.saturated();
        let sheet = self.pastel();
        // Bed: frame, mattress, pillow, headboard (against a wall, headboard at the wall).
        let (bw, bl) = (self.rng.gen_range(1.4..1.8f32), 2.05f32);
        if let Some(p) = self.against_wall(bw + 1.1, bl, 0.0) {
            self.object("bed", &[FURNITURE]);
            self.local_box(
                p,
                "bed_frame",
                [-bw / 2.0, 0.0, -bl / 2.0],
                [bw / 2.0, 0.3, bl / 2.0],
                mat(frame_color, 0.04, 0.5),
            );
            self.local_box(
                p,
                "bed_mattress",
                [-bw / 2.0 + 0.03, 0.3, -bl / 2.0 + 0.06],
                [bw / 2.0 - 0.03, 0.52, bl / 2.0 - 0.03],
                mat(sheet, 0.0, 0.9),
            );
            self.local_box(
                p,
                "bed_pillow",
                [-bw / 2.0 + 0.15, 0.52, -bl / 2.0 + 0.1],
                [bw / 2.0 - 0.15, 0.64, -bl / 2.0 + 0.5],
                mat([0.9, 0.9, 0.88], 0.0, 0.9),
            );
            self.local_box(
                p,
                "bed_headboard",
                [-bw / 2.0, 0.0, -bl / 2.0],
                [bw / 2.0, 1.05, -bl / 2.0 + 0.06],
                mat(frame_color, 0.04, 0.5),
            );
            // Nightstands beside the bed, each with a small glossy sphere ornament on one.
            for (i, side) in [-1.0f32, 1.0].into_iter().enumerate() {
                let x = side * (bw / 2.0 + 0.3);
                self.object(&format!("nightstand_{i}"), &[FURNITURE]);
                self.local_box(
                    p,
                    &format!("nightstand_{i}"),
                    [x - 0.22, 0.0, -bl / 2.0],
                    [x + 0.22, 0.5, -bl / 2.0 + 0.42],
                    mat([0.5, 0.36, 0.22], 0.1, 0.3),
                );
            }
            let x = -(bw / 2.0 + 0.3);
            let c = p.to_world(Vec3::new(x, 0.62, -bl / 2.0 + 0.21));
            self.object("ornament_sphere", &[FURNITURE]);
            self.add(
                "ornament_sphere",
                Geometry::Sphere {
                    center: c.into(),
                    radius: 0.12,
                    subdivisions: 3,
                },
                mat([0.05, 0.05, 0.3], 0.5, 0.3),
            );
        }
        // Wardrobe: tall glossy painted box.
        let ww = self.rng.gen_range(0.9..1.3f32);
        if let Some(p) = self.against_wall(ww, 0.58, 0.0) {
            let paint = self.pastel();
            // The handle (3 cm deep) is relief on the wardrobe's face, not a free-standing thin
            // structure: it stays part of the wardrobe.
            self.object("wardrobe", &[FURNITURE]);
            self.local_box(
                p,
                "wardrobe",
                [-ww / 2.0, 0.0, -0.29],
                [ww / 2.0, 2.0, 0.29],
                mat(paint, 0.12, 0.25),
            );
            self.local_box(
                p,
                "wardrobe_handle",
                [-0.02, 1.0, 0.29],
                [0.02, 1.25, 0.32],
                mat([0.8, 0.7, 0.4], 0.6, 0.35),
            );
        }
        self.desk_with_legs("desk");
    }

    /// The living room: the floor lamp and the chandelier, then a sofa, a TV stand and a
    /// bookshelf against the walls, a coffee-table group in the middle and a side table.
    fn livingroom(&mut self) {
        self.floor_lamp("floor_lamp");
        self.chandelier();
        self.sofa();
        self.tv_stand();
        self.bookshelf();
        self.coffee_table_group();
        self.desk_with_legs("side_table");
    }

    /// A sofa against a wall, in a saturated fabric: seat, back, two armrests.
    fn sofa(&mut self) {
        let fabric = self.saturated();
        let sw = self.rng.gen_range(1.8..2.3f32);
        if let Some(p) = self.against_wall(sw, 0.9, 0.05) {
            self.object("sofa", &[FURNITURE]);
            self.local_box(
                p,
                "sofa_seat",
                [-sw / 2.0, 0.0, -0.45],
                [sw / 2.0, 0.42, 0.45],
                mat(fabric, 0.0, 0.9),
            );
            self.local_box(
                p,
                "sofa_back",
                [-sw / 2.0, 0.42, -0.45],
                [sw / 2.0, 0.85, -0.25],
                mat(fabric, 0.0, 0.9),
            );
            for (i, side) in [-1.0f32, 1.0].into_iter().enumerate() {
                let x = side * (sw / 2.0 - 0.1);
                self.local_box(
                    p,
                    &format!("sofa_arm_{i}"),
                    [x - 0.1, 0.42, -0.25],
                    [x + 0.1, 0.62, 0.45],
                    mat(fabric, 0.0, 0.9),
                );
            }
        }
    }

    /// A TV stand against a wall with a glossy black screen.
    fn tv_stand(&mut self) {
        let tw = self.rng.gen_range(1.2..1.6f32);
        if let Some(p) = self.against_wall(tw, 0.45, 0.0) {
            self.object("tv_stand", &[FURNITURE]);
            self.local_box(
                p,
                "tv_stand",
                [-tw / 2.0, 0.0, -0.22],
                [tw / 2.0, 0.45, 0.22],
                mat([0.3, 0.22, 0.15], 0.08, 0.35),
            );
            self.object("tv_screen", &[FURNITURE]);
            self.local_box(
                p,
                "tv_screen",
                [-0.55, 0.5, -0.08],
                [0.55, 1.15, -0.03],
                mat([0.02; 3], 0.5, 0.3),
            );
        }
    }

    /// A bookshelf against a wall: a frame of boards with coloured "books" (boxes) on its
    /// shelves.
    fn bookshelf(&mut self) {
        let shelf_w = self.rng.gen_range(0.8..1.1f32);
        if let Some(p) = self.against_wall(shelf_w, 0.35, 0.0) {
            let wood = mat([0.55, 0.4, 0.25], 0.04, 0.5);
            self.object("bookshelf", &[FURNITURE]);
            self.local_box(
                p,
                "shelf_side_l",
                [-shelf_w / 2.0, 0.0, -0.175],
                [-shelf_w / 2.0 + 0.03, 1.8, 0.175],
                wood.clone(),
            );
            self.local_box(
                p,
                "shelf_side_r",
                [shelf_w / 2.0 - 0.03, 0.0, -0.175],
                [shelf_w / 2.0, 1.8, 0.175],
                wood.clone(),
            );
            self.local_box(
                p,
                "shelf_back",
                [-shelf_w / 2.0, 0.0, -0.175],
                [shelf_w / 2.0, 1.8, -0.155],
                wood.clone(),
            );
            for k in 0..5 {
                let y = k as f32 * 0.43;
                self.object("bookshelf", &[FURNITURE]);
                self.local_box(
                    p,
                    &format!("shelf_board_{k}"),
                    [-shelf_w / 2.0 + 0.03, y, -0.155],
                    [shelf_w / 2.0 - 0.03, y + 0.03, 0.175],
                    wood.clone(),
                );
                if k < 4 {
                    self.shelf_books(p, shelf_w, k, y);
                }
            }
        }
    }

    /// A row of books of random widths, heights and colours on board `k` (at height `y`) of the
    /// bookshelf at `p`, until the shelf is full.
    fn shelf_books(&mut self, p: Placement, shelf_w: f32, k: usize, y: f32) {
        let mut x = -shelf_w / 2.0 + 0.05;
        let mut j = 0;
        while x < shelf_w / 2.0 - 0.15 {
            let bw = self.rng.gen_range(0.03..0.07f32);
            let bh = self.rng.gen_range(0.2..0.36f32);
            let c = self.saturated();
            self.object("books", &[FURNITURE]);
            self.local_box(
                p,
                &format!("book_{k}_{j}"),
                [x, y + 0.03, -0.14],
                [x + bw, y + 0.03 + bh, 0.12],
                mat(c, 0.02, 0.6),
            );
            x += bw + self.rng.gen_range(0.0..0.02);
            j += 1;
        }
    }

    /// A coffee table, free-standing and slightly turned: a glass-like glossy top on four thin
    /// legs, a glossy sphere and a 4 cm ball on it, and a striped rug under it.
    fn coffee_table_group(&mut self) {
        let yaw = self.rng.gen_range(-0.3..0.3f32);
        let origin = Vec3::new(self.rng.gen_range(-0.4..0.4), 0.0, self.rng.gen_range(-0.3..0.3));
        let p = Placement { origin, yaw };
        if self.claim(p, 1.2, 0.7) {
            let rug = self.saturated();
            let rug_mat = MaterialDesc {
                kd: rug,
                ks: [0.0; 3],
                roughness: 1.0,
                texture: Some(TextureDesc::Stripe {
                    kd2: [0.85, 0.82, 0.75],
                    scale: 0.15,
                    axis: 2,
                }),
            };
            self.object("rug", &[FURNITURE]);
            self.local_box(p, "rug", [-1.0, 0.0, -0.7], [1.0, 0.01, 0.7], rug_mat);
            self.object("coffee_table", &[FURNITURE]);
            self.local_box(
                p,
                "coffee_table_top",
                [-0.55, 0.42, -0.32],
                [0.55, 0.45, 0.32],
                mat([0.1, 0.1, 0.1], 0.35, 0.3),
            );
            for (i, (sx, sz)) in [(-1.0f32, -1.0f32), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
                .into_iter()
                .enumerate()
            {
                self.object("coffee_table_legs", &[THIN]);
                self.local_cylinder(
                    p,
                    &format!("coffee_table_leg_{i}"),
                    [sx * 0.5, 0.01, sz * 0.27],
                    [sx * 0.5, 0.42, sz * 0.27],
                    0.018,
                    10,
                    mat([0.7, 0.7, 0.7], 0.5, 0.25),
                );
            }
            let c = p.to_world(Vec3::new(0.2, 0.45 + 0.1, 0.0));
            self.object("glossy_ball", &[FURNITURE]);
            self.add(
                "glossy_ball",
                Geometry::Sphere {
                    center: c.into(),
                    radius: 0.1,
                    subdivisions: 3,
                },
                mat([0.6, 0.08, 0.05], 0.4, 0.3),
            );
            // Placed and coloured without the generator's random numbers, so that adding it left
            // every other object of the rooms where it was.
            let c = p.to_world(Vec3::new(-0.3, 0.45 + 0.02, 0.12));
            self.object("coffee_table_ball", &[SMALL]);
            self.add(
                "coffee_table_ball",
                Geometry::Sphere {
                    center: c.into(),
                    radius: 0.02,
                    subdivisions: 3,
                },
                mat([0.85, 0.62, 0.12], 0.04, 0.5),
            );
        }
    }

    /// A small table against a wall on four thin legs, with a cylinder vase and a 3.5 cm die on
    /// it.
    fn desk_with_legs(&mut self, name: &str) {
        let (w, d) = (self.rng.gen_range(0.9..1.2f32), 0.55f32);
        if let Some(p) = self.against_wall(w, d, 0.02) {
            let top = mat([0.6, 0.45, 0.3], 0.08, 0.3);
            self.object(name, &[FURNITURE]);
            self.local_box(
                p,
                &format!("{name}_top"),
                [-w / 2.0, 0.72, -d / 2.0],
                [w / 2.0, 0.75, d / 2.0],
                top,
            );
            for (i, (sx, sz)) in [(-1.0f32, -1.0f32), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
                .into_iter()
                .enumerate()
            {
                let (x, z) = (sx * (w / 2.0 - 0.04), sz * (d / 2.0 - 0.04));
                self.object(&format!("{name}_legs"), &[THIN]);
                self.local_cylinder(
                    p,
                    &format!("{name}_leg_{i}"),
                    [x, 0.0, z],
                    [x, 0.72, z],
                    0.017,
                    10,
                    mat([0.2, 0.2, 0.2], 0.3, 0.4),
                );
            }
            let c = self.saturated();
            self.object(&format!("{name}_vase"), &[FURNITURE]);
            self.local_cylinder(
                p,
                &format!("{name}_vase"),
                [0.2, 0.75, 0.0],
                [0.2, 1.0, 0.0],
                0.06,
                24,
                mat(c, 0.3, 0.3),
            );
            // Without random numbers, as the coffee table's ball.
            self.object(&format!("{name}_die"), &[SMALL]);
            self.local_box(
                p,
                &format!("{name}_die"),
                [-0.2, 0.75, -0.0175],
                [-0.165, 0.785, 0.0175],
                mat([0.12, 0.25, 0.7], 0.04, 0.5),
            );
        }
    }

    fn finish(self) -> SceneDesc {
        SceneDesc {
            name: self.name,
            room: RoomBounds {
                min: self.lo.into(),
                max: self.hi.into(),
            },
            camera: CameraRig {
                fov_x_deg: 75.0,
                eye_height: [1.1, 1.6],
                pitch_deg: [-20.0, 10.0],
            },
            shapes: self.shapes,
        }
    }
}
