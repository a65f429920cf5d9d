//! Shared helpers of the synth integration tests: a tiny rendered dataset and readers for what
//! it wrote (cameras from transforms.json, depth EXRs, the binary PLY with its object ids).

#![allow(dead_code)]

use glam::{DMat3, DVec3, Mat4, Vec3};
use i2sdf_synth::{generate, RoomPreset, SynthOptions};
use std::path::{Path, PathBuf};

pub struct WrittenView {
    pub c2w: Mat4,
    pub depth: Vec<f32>,
    pub split: String,
}

pub struct Written {
    pub dir: PathBuf,
    pub width: usize,
    pub height: usize,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub views: Vec<WrittenView>,
    pub json: serde_json::Value,
}

pub fn render_tiny(dir: &Path, preset: RoomPreset, seed: u64, views: usize) -> Written {
    let opts = SynthOptions {
        width: 64,
        height: 48,
        views,
        spp: 2,
        seed,
        max_depth: 4,
        preset: Some(preset.name().into()),
        ..Default::default()
    };
    generate(preset.build(seed), &opts, dir, &|| {}).expect("tiny dataset renders");
    read_written(dir)
}

pub fn read_written(dir: &Path) -> Written {
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("transforms.json")).unwrap()).unwrap();
    let num = |k: &str| json[k].as_f64().unwrap();
    let (width, height) = (num("w") as usize, num("h") as usize);
    let views = json["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            let rows: Vec<Vec<f32>> = serde_json::from_value(f["transform_matrix"].clone()).unwrap();
            let c2w = Mat4::from_cols_array_2d(&[
                [rows[0][0], rows[1][0], rows[2][0], rows[3][0]],
                [rows[0][1], rows[1][1], rows[2][1], rows[3][1]],
                [rows[0][2], rows[1][2], rows[2][2], rows[3][2]],
                [rows[0][3], rows[1][3], rows[2][3], rows[3][3]],
            ]);
            let img = i2sdf_data::imageio::read_float_map(&dir.join(f["depth_file_path"].as_str().unwrap())).unwrap();
            assert_eq!((img.width, img.height, img.channels), (width, height, 1));
            WrittenView {
                c2w,
                depth: img.data,
                split: f["split"].as_str().unwrap().to_string(),
            }
        })
        .collect();
    Written {
        dir: dir.to_path_buf(),
        width,
        height,
        fx: num("fl_x"),
        fy: num("fl_y"),
        cx: num("cx"),
        cy: num("cy"),
        views,
        json,
    }
}

impl Written {
    /// World point of pixel (x, y) from the written z-depth, in f64: OpenGL camera axes, pixel
    /// centres at +0.5.
    pub fn back_project(&self, v: &WrittenView, x: usize, y: usize) -> DVec3 {
        let z = v.depth[y * self.width + x] as f64;
        let cam = DVec3::new(
            (x as f64 + 0.5 - self.cx) / self.fx * z,
            -(y as f64 + 0.5 - self.cy) / self.fy * z,
            -z,
        );
        let m = v.c2w.as_dmat4();
        m.transform_point3(cam)
    }

    /// Continuous pixel coordinates and z-depth of a world point in view `v`.
    pub fn project(&self, v: &WrittenView, p: DVec3) -> (f64, f64, f64) {
        let m = v.c2w.as_dmat4();
        let r = DMat3::from_mat4(m);
        let c = r.transpose() * (p - m.w_axis.truncate());
        let z = -c.z;
        (c.x / z * self.fx + self.cx, -c.y / z * self.fy + self.cy, z)
    }
}

/// Reads the written mesh through the project's one PLY reader (`i2sdf_data::ply`).
pub fn read_ply(path: &Path) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let (verts, faces, _) = read_ply_with_objects(path);
    (verts, faces)
}

/// [`read_ply`] with the per-face `object_id`, checking that the file is the binary
/// little-endian layout the dataset format promises (float vertices, `uchar int` index lists,
/// `int object_id`).
pub fn read_ply_with_objects(path: &Path) -> (Vec<Vec3>, Vec<[u32; 3]>, Option<Vec<i32>>) {
    let bytes = std::fs::read(path).unwrap();
    let end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    assert!(header.contains("format binary_little_endian 1.0"), "{header}");
    assert!(
        header.contains("property float x\nproperty float y\nproperty float z\n"),
        "{header}"
    );
    let mesh = i2sdf_data::ply::read_ply(path).unwrap();
    if mesh.face_object_ids.is_some() {
        assert!(
            header.contains("property list uchar int vertex_indices\nproperty int object_id\n"),
            "{header}"
        );
    }
    let verts = mesh.positions.iter().map(|p| Vec3::from(*p)).collect();
    (verts, mesh.faces, mesh.face_object_ids)
}

/// Distance from `p` to triangle (a, b, c) (Ericson, Real-Time Collision Detection 5.1.5), f64.
pub fn point_triangle_distance(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return (p - a).length();
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return (p - b).length();
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (p - (a + v * ab)).length();
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return (p - c).length();
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (p - (a + w * ac)).length();
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (p - (b + w * (c - b))).length();
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    (p - (a + ab * v + ac * w)).length()
}
