//! COLMAP's sparse model files, binary and text, as COLMAP writes them (`Reconstruction::Write…`
//! in COLMAP's `reconstruction_io`; the layouts below were checked against its
//! `scripts/python/read_write_model.py` and against files written by pycolmap 4):
//!
//! ```text
//! cameras.bin   u64 count; per camera: i32 id, i32 model_id, u64 width, u64 height, f64 params[n(model)]
//! images.bin    u64 count; per image: i32 id, f64 qw qx qy qz, f64 tx ty tz, i32 camera_id,
//!               NUL-terminated name, u64 n_points2D, n × (f64 x, f64 y, i64 point3D_id (−1: none))
//! points3D.bin  u64 count; per point: u64 id, f64 x y z, u8 r g b, f64 error, u64 track_length,
//!               track_length × (i32 image_id, i32 point2D_idx)
//! ```
//!
//! All little-endian. The text files hold the same fields, one record per line after `#` comments
//! (`CAMERA_ID MODEL WIDTH HEIGHT PARAMS…`, `POINT3D_ID X Y Z R G B ERROR (IMAGE_ID POINT2D_IDX)…`),
//! except `images.txt`, which has two lines per image: `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID
//! NAME` and then its observations `(X Y POINT3D_ID)…` (a line that may be empty).
//!
//! Every count is checked against the bytes left before anything is allocated, and every error
//! names the file and the record.

use crate::error::{DataError, Result};
use glam::{DVec2, DVec3};
use std::collections::BTreeMap;
use std::path::Path;

/// COLMAP's camera models by id: name and parameter count. Only the first six are read (the ones
/// [`crate::Lens`] models); the others are named in the error that refuses them.
const CAMERA_MODELS: [(&str, usize); 18] = [
    ("SIMPLE_PINHOLE", 3),
    ("PINHOLE", 4),
    ("SIMPLE_RADIAL", 4),
    ("RADIAL", 5),
    ("OPENCV", 8),
    ("OPENCV_FISHEYE", 8),
    ("FULL_OPENCV", 12),
    ("FOV", 5),
    ("SIMPLE_RADIAL_FISHEYE", 4),
    ("RADIAL_FISHEYE", 5),
    ("THIN_PRISM_FISHEYE", 12),
    ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
    ("SIMPLE_DIVISION", 4),
    ("DIVISION", 5),
    ("SIMPLE_FISHEYE", 3),
    ("FISHEYE", 4),
    ("EUCM", 6),
    ("EQUIRECTANGULAR", 2),
];

/// How many of [`CAMERA_MODELS`] are supported (ids 0–5).
const SUPPORTED_MODELS: usize = 6;

/// The point3D id of an observation without a 3D point.
pub const NO_POINT3D: i64 = -1;

/// One camera of the model: its COLMAP model name, image size and parameters in COLMAP's order.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    pub id: i32,
    pub model: &'static str,
    pub width: usize,
    pub height: usize,
    pub params: Vec<f64>,
}

/// One registered image: its world-to-camera pose (unit quaternion w x y z and translation, OpenCV
/// axes), camera, name (relative to `images/`) and 2D observations.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    pub id: i32,
    pub qvec: [f64; 4],
    pub tvec: [f64; 3],
    pub camera_id: i32,
    pub name: String,
    /// (pixel position, point3D id or [`NO_POINT3D`]).
    pub points2d: Vec<(DVec2, i64)>,
}

/// One 3D point with its track ((image id, point2D index) pairs).
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapPoint {
    pub xyz: DVec3,
    pub rgb: [u8; 3],
    pub error: f64,
    pub track: Vec<(i32, i32)>,
}

/// A sparse model: cameras and images by id, points by id.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ColmapModel {
    pub cameras: BTreeMap<i32, ColmapCamera>,
    pub images: BTreeMap<i32, ColmapImage>,
    pub points: BTreeMap<u64, ColmapPoint>,
}

/// Reads the model in `dir`: each of `cameras`, `images`, `points3D` from its `.bin` if there is
/// one, else its `.txt`.
pub fn read_model(dir: &Path) -> Result<ColmapModel> {
    let pick = |stem: &str| -> Result<(std::path::PathBuf, bool)> {
        let bin = dir.join(format!("{stem}.bin"));
        let txt = dir.join(format!("{stem}.txt"));
        if bin.is_file() {
            Ok((bin, true))
        } else if txt.is_file() {
            Ok((txt, false))
        } else {
            Err(DataError::file(
                &bin,
                format!("file not found (nor {stem}.txt): a COLMAP model needs cameras, images and points3D"),
            ))
        }
    };
    let read = |path: &Path| std::fs::read(path).map_err(|e| DataError::file(path, format!("cannot read: {e}")));
    let (path, bin) = pick("cameras")?;
    let bytes = read(&path)?;
    let cameras = if bin {
        parse_cameras_bin(&path, &bytes)?
    } else {
        parse_cameras_txt(&path, text(&path, &bytes)?)?
    };
    let (path, bin) = pick("images")?;
    let bytes = read(&path)?;
    let images = if bin {
        parse_images_bin(&path, &bytes)?
    } else {
        parse_images_txt(&path, text(&path, &bytes)?)?
    };
    let (path, bin) = pick("points3D")?;
    let bytes = read(&path)?;
    let points = if bin {
        parse_points_bin(&path, &bytes)?
    } else {
        parse_points_txt(&path, text(&path, &bytes)?)?
    };
    Ok(ColmapModel {
        cameras,
        images,
        points,
    })
}

fn text<'a>(path: &Path, bytes: &'a [u8]) -> Result<&'a str> {
    std::str::from_utf8(bytes).map_err(|e| DataError::file(path, format!("not UTF-8 text: {e}")))
}

/// The camera of a model id and its parameters, checked; `field` names the record in errors.
fn camera(
    path: &Path,
    field: &str,
    id: i32,
    model_id: i64,
    width: u64,
    height: u64,
    params: Vec<f64>,
) -> Result<ColmapCamera> {
    let err = |msg: String| DataError::field(path, field, msg);
    let (model, n) = supported_model(model_id).map_err(err)?;
    if params.len() != n {
        return Err(err(format!("{model} has {n} parameters, found {}", params.len())));
    }
    if let Some(v) = params.iter().find(|v| !v.is_finite()) {
        return Err(err(format!("parameter {v} is not finite")));
    }
    let pixels = width.checked_mul(height);
    if width == 0 || height == 0 || pixels.is_none_or(|p| p > crate::imageio::MAX_PIXELS) {
        return Err(err(format!("image size {width}×{height} is empty or too large")));
    }
    Ok(ColmapCamera {
        id,
        model,
        width: width as usize,
        height: height as usize,
        params,
    })
}

fn supported_model(model_id: i64) -> std::result::Result<(&'static str, usize), String> {
    match usize::try_from(model_id)
        .ok()
        .and_then(|i| CAMERA_MODELS.get(i).map(|m| (i, *m)))
    {
        Some((i, m)) if i < SUPPORTED_MODELS => Ok(m),
        Some((_, (name, _))) => Err(format!(
            "camera model id {model_id} ({name}) is not supported (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, \
             OPENCV, OPENCV_FISHEYE: undistort the images with COLMAP's image_undistorter first)"
        )),
        None => Err(format!("unknown camera model id {model_id}")),
    }
}

/// The number of parameters of a supported camera model (by COLMAP's name).
pub fn parameter_count(model: &str) -> Option<usize> {
    CAMERA_MODELS[..SUPPORTED_MODELS]
        .iter()
        .find(|(n, _)| *n == model)
        .map(|(_, n)| *n)
}

fn model_id_of_name(name: &str) -> Option<i64> {
    CAMERA_MODELS.iter().position(|(n, _)| *n == name).map(|i| i as i64)
}

fn insert_unique<K: Ord + std::fmt::Display, V>(
    map: &mut BTreeMap<K, V>,
    path: &Path,
    field: &str,
    id: K,
    v: V,
) -> Result<()> {
    if map.contains_key(&id) {
        return Err(DataError::field(path, field, format!("id {id} appears twice")));
    }
    map.insert(id, v);
    Ok(())
}

fn check_pose(path: &Path, field: &str, q: [f64; 4], t: [f64; 3]) -> Result<()> {
    if !q.iter().chain(&t).all(|v| v.is_finite()) {
        return Err(DataError::field(path, field, "pose has non-finite entries"));
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Binary.

/// A little-endian reader over a file's bytes; running out names the file, the offset and what
/// was being read.
struct Reader<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn new(path: &'a Path, bytes: &'a [u8]) -> Self {
        Reader { path, bytes, pos: 0 }
    }

    fn take<const N: usize>(&mut self, what: &str) -> Result<[u8; N]> {
        let end = self.pos.checked_add(N).filter(|e| *e <= self.bytes.len());
        let Some(end) = end else {
            return Err(DataError::file(
                self.path,
                format!(
                    "truncated: {what} needs {N} bytes at offset {}, the file has {}",
                    self.pos,
                    self.bytes.len()
                ),
            ));
        };
        let out = self.bytes[self.pos..end].try_into().expect("N bytes");
        self.pos = end;
        Ok(out)
    }
    fn u8(&mut self, what: &str) -> Result<u8> {
        Ok(self.take::<1>(what)?[0])
    }
    fn i32(&mut self, what: &str) -> Result<i32> {
        Ok(i32::from_le_bytes(self.take(what)?))
    }
    fn u64(&mut self, what: &str) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take(what)?))
    }
    fn i64(&mut self, what: &str) -> Result<i64> {
        Ok(i64::from_le_bytes(self.take(what)?))
    }
    fn f64(&mut self, what: &str) -> Result<f64> {
        Ok(f64::from_le_bytes(self.take(what)?))
    }

    /// A count of records of at least `record_bytes` each: one the rest of the file cannot hold is
    /// refused before anything is allocated for it.
    fn count(&mut self, what: &str, record_bytes: usize) -> Result<usize> {
        let n = self.u64(&format!("the number of {what}"))?;
        let left = (self.bytes.len() - self.pos) as u64;
        if n > left / record_bytes as u64 {
            return Err(DataError::file(
                self.path,
                format!(
                    "truncated: {n} {what} need at least {} bytes from offset {}, the file has {left} left",
                    n.saturating_mul(record_bytes as u64),
                    self.pos
                ),
            ));
        }
        Ok(n as usize)
    }

    fn name(&mut self, what: &str) -> Result<String> {
        let rest = &self.bytes[self.pos..];
        let Some(len) = rest.iter().position(|b| *b == 0) else {
            return Err(DataError::file(
                self.path,
                format!("truncated: {what} has no terminating NUL byte"),
            ));
        };
        let name = std::str::from_utf8(&rest[..len])
            .map_err(|_| DataError::file(self.path, format!("{what} is not UTF-8")))?
            .to_string();
        self.pos += len + 1;
        Ok(name)
    }

    fn finish(&self) -> Result<()> {
        if self.pos != self.bytes.len() {
            return Err(DataError::file(
                self.path,
                format!(
                    "{} bytes left over after the last record (offset {}): not a COLMAP model file",
                    self.bytes.len() - self.pos,
                    self.pos
                ),
            ));
        }
        Ok(())
    }
}

pub fn parse_cameras_bin(path: &Path, bytes: &[u8]) -> Result<BTreeMap<i32, ColmapCamera>> {
    let mut r = Reader::new(path, bytes);
    let n = r.count("cameras", 24)?;
    let mut cameras = BTreeMap::new();
    for k in 0..n {
        let what = format!("camera {k}");
        let id = r.i32(&what)?;
        let model_id = r.i32(&what)?;
        let width = r.u64(&what)?;
        let height = r.u64(&what)?;
        let field = format!("camera {id}");
        // The parameter count depends on the model: an unknown one cannot be skipped.
        let (_, n_params) = supported_model(model_id as i64).map_err(|m| DataError::field(path, &field, m))?;
        let params = (0..n_params).map(|_| r.f64(&what)).collect::<Result<Vec<_>>>()?;
        let cam = camera(path, &field, id, model_id as i64, width, height, params)?;
        insert_unique(&mut cameras, path, &field, id, cam)?;
    }
    r.finish()?;
    Ok(cameras)
}

pub fn parse_images_bin(path: &Path, bytes: &[u8]) -> Result<BTreeMap<i32, ColmapImage>> {
    let mut r = Reader::new(path, bytes);
    // id, 7 doubles, camera id, an empty name's NUL, the observation count.
    let n = r.count("images", 4 + 56 + 4 + 1 + 8)?;
    let mut images = BTreeMap::new();
    for k in 0..n {
        let what = format!("image {k}");
        let id = r.i32(&what)?;
        let mut qvec = [0.0; 4];
        for q in &mut qvec {
            *q = r.f64(&what)?;
        }
        let mut tvec = [0.0; 3];
        for t in &mut tvec {
            *t = r.f64(&what)?;
        }
        let camera_id = r.i32(&what)?;
        let name = r.name(&format!("image {id}'s name"))?;
        let field = format!("image {id} ({name})");
        check_pose(path, &field, qvec, tvec)?;
        let n_points = r.count(&format!("observations of image {id}"), 24)?;
        let mut points2d = Vec::with_capacity(n_points);
        for _ in 0..n_points {
            let x = r.f64(&what)?;
            let y = r.f64(&what)?;
            let pid = r.i64(&what)?;
            points2d.push((DVec2::new(x, y), pid));
        }
        let image = ColmapImage {
            id,
            qvec,
            tvec,
            camera_id,
            name,
            points2d,
        };
        insert_unique(&mut images, path, &field, id, image)?;
    }
    r.finish()?;
    Ok(images)
}

pub fn parse_points_bin(path: &Path, bytes: &[u8]) -> Result<BTreeMap<u64, ColmapPoint>> {
    let mut r = Reader::new(path, bytes);
    let n = r.count("points", 8 + 24 + 3 + 8 + 8)?;
    let mut points = BTreeMap::new();
    for k in 0..n {
        let what = format!("point {k}");
        let id = r.u64(&what)?;
        let xyz = DVec3::new(r.f64(&what)?, r.f64(&what)?, r.f64(&what)?);
        let rgb = [r.u8(&what)?, r.u8(&what)?, r.u8(&what)?];
        let error = r.f64(&what)?;
        let track_len = r.count(&format!("track elements of point {id}"), 8)?;
        let mut track = Vec::with_capacity(track_len);
        for _ in 0..track_len {
            track.push((r.i32(&what)?, r.i32(&what)?));
        }
        let field = format!("point {id}");
        if !xyz.is_finite() {
            return Err(DataError::field(path, &field, "position is not finite"));
        }
        insert_unique(&mut points, path, &field, id, ColmapPoint { xyz, rgb, error, track })?;
    }
    r.finish()?;
    Ok(points)
}

// ---------------------------------------------------------------------------------------------
// Text.

/// The data lines of a text file: (1-based line number, line), comments and blank lines left out.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

/// The first `n` whitespace-separated fields of a line (fewer if it has fewer) and the rest of
/// it, trimmed.
fn split_fields(line: &str, n: usize) -> (Vec<&str>, &str) {
    let mut fields = Vec::with_capacity(n);
    let mut rest = line.trim();
    while fields.len() < n && !rest.is_empty() {
        let end = rest.find(char::is_whitespace).unwrap_or(rest.len());
        fields.push(&rest[..end]);
        rest = rest[end..].trim_start();
    }
    (fields, rest.trim_end())
}

/// Parses one whitespace-separated token, naming the line and column in errors.
fn token<T: std::str::FromStr>(path: &Path, line: usize, what: &str, tok: Option<&str>) -> Result<T> {
    let field = format!("line {line}");
    let tok = tok.ok_or_else(|| DataError::field(path, &field, format!("{what} is missing")))?;
    tok.parse()
        .map_err(|_| DataError::field(path, &field, format!("{what} '{tok}' is not a valid number")))
}

pub fn parse_cameras_txt(path: &Path, text: &str) -> Result<BTreeMap<i32, ColmapCamera>> {
    let mut cameras = BTreeMap::new();
    for (line, l) in data_lines(text) {
        let mut it = l.split_whitespace();
        let id: i32 = token(path, line, "CAMERA_ID", it.next())?;
        let model = it.next().unwrap_or("");
        let model_id = model_id_of_name(model)
            .ok_or_else(|| DataError::field(path, format!("line {line}"), format!("unknown camera model '{model}'")))?;
        let width: u64 = token(path, line, "WIDTH", it.next())?;
        let height: u64 = token(path, line, "HEIGHT", it.next())?;
        let params = it
            .map(|t| token::<f64>(path, line, "a parameter", Some(t)))
            .collect::<Result<Vec<_>>>()?;
        let field = format!("line {line} (camera {id})");
        let cam = camera(path, &field, id, model_id, width, height, params)?;
        insert_unique(&mut cameras, path, &field, id, cam)?;
    }
    Ok(cameras)
}

pub fn parse_images_txt(path: &Path, text: &str) -> Result<BTreeMap<i32, ColmapImage>> {
    let mut images = BTreeMap::new();
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim()));
    while let Some((line, l)) = lines.next() {
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let (head, rest) = split_fields(l, 9);
        let mut it = head.into_iter();
        let id: i32 = token(path, line, "IMAGE_ID", it.next())?;
        let mut q = [0.0; 4];
        for (v, what) in q.iter_mut().zip(["QW", "QX", "QY", "QZ"]) {
            *v = token(path, line, what, it.next())?;
        }
        let mut t = [0.0; 3];
        for (v, what) in t.iter_mut().zip(["TX", "TY", "TZ"]) {
            *v = token(path, line, what, it.next())?;
        }
        let camera_id: i32 = token(path, line, "CAMERA_ID", it.next())?;
        // The name is the rest of the line (it may hold spaces).
        let name = rest.to_string();
        let field = format!("line {line} (image {id})");
        if name.is_empty() {
            return Err(DataError::field(path, &field, "NAME is missing"));
        }
        check_pose(path, &field, q, t)?;
        // The observations are the very next line, which may be empty (an image without any).
        let mut points2d = Vec::new();
        if let Some((pline, p)) = lines.next() {
            let toks: Vec<&str> = p.split_whitespace().collect();
            if toks.len() % 3 != 0 {
                return Err(DataError::field(
                    path,
                    format!("line {pline}"),
                    format!(
                        "image {id}'s observations are not (X Y POINT3D_ID) triples ({} values)",
                        toks.len()
                    ),
                ));
            }
            for c in toks.chunks(3) {
                let x: f64 = token(path, pline, "X", Some(c[0]))?;
                let y: f64 = token(path, pline, "Y", Some(c[1]))?;
                let pid: i64 = token(path, pline, "POINT3D_ID", Some(c[2]))?;
                points2d.push((DVec2::new(x, y), pid));
            }
        }
        let image = ColmapImage {
            id,
            qvec: q,
            tvec: t,
            camera_id,
            name,
            points2d,
        };
        insert_unique(&mut images, path, &field, id, image)?;
    }
    Ok(images)
}

pub fn parse_points_txt(path: &Path, text: &str) -> Result<BTreeMap<u64, ColmapPoint>> {
    let mut points = BTreeMap::new();
    for (line, l) in data_lines(text) {
        let mut it = l.split_whitespace();
        let id: u64 = token(path, line, "POINT3D_ID", it.next())?;
        let mut xyz = DVec3::ZERO;
        for a in 0..3 {
            xyz[a] = token(path, line, ["X", "Y", "Z"][a], it.next())?;
        }
        let mut rgb = [0u8; 3];
        for (c, what) in rgb.iter_mut().zip(["R", "G", "B"]) {
            *c = token(path, line, what, it.next())?;
        }
        let error: f64 = token(path, line, "ERROR", it.next())?;
        let rest: Vec<&str> = it.collect();
        let field = format!("line {line} (point {id})");
        if rest.len() % 2 != 0 {
            return Err(DataError::field(
                path,
                &field,
                "the track is not (IMAGE_ID POINT2D_IDX) pairs",
            ));
        }
        let track = rest
            .chunks(2)
            .map(|c| {
                Ok((
                    token(path, line, "IMAGE_ID", Some(c[0]))?,
                    token(path, line, "POINT2D_IDX", Some(c[1]))?,
                ))
            })
            .collect::<Result<Vec<_>>>()?;
        if !xyz.is_finite() {
            return Err(DataError::field(path, &field, "position is not finite"));
        }
        insert_unique(&mut points, path, &field, id, ColmapPoint { xyz, rgb, error, track })?;
    }
    Ok(points)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cameras_bin(model_id: i32, params: &[f64]) -> Vec<u8> {
        let mut b = 1u64.to_le_bytes().to_vec();
        b.extend(7i32.to_le_bytes());
        b.extend(model_id.to_le_bytes());
        b.extend(8u64.to_le_bytes());
        b.extend(6u64.to_le_bytes());
        params.iter().for_each(|p| b.extend(p.to_le_bytes()));
        b
    }

    #[test]
    fn a_binary_camera_reads_and_an_unknown_model_is_named() {
        let p = Path::new("m/cameras.bin");
        let cams = parse_cameras_bin(p, &cameras_bin(1, &[10.0, 11.0, 4.0, 3.0])).unwrap();
        assert_eq!(cams[&7].model, "PINHOLE");
        assert_eq!(cams[&7].params, vec![10.0, 11.0, 4.0, 3.0]);
        let e = parse_cameras_bin(p, &cameras_bin(6, &[0.0; 12])).unwrap_err();
        assert!(e.to_string().contains("model id 6 (FULL_OPENCV)"), "{e}");
        assert!(e.to_string().contains("cameras.bin"), "{e}");
        let e = parse_cameras_bin(p, &cameras_bin(99, &[])).unwrap_err();
        assert!(e.to_string().contains("unknown camera model id 99"), "{e}");
    }

    #[test]
    fn a_huge_count_is_refused_before_allocating() {
        let p = Path::new("m/points3D.bin");
        let mut b = u64::MAX.to_le_bytes().to_vec();
        b.extend([0u8; 64]);
        let e = parse_points_bin(p, &b).unwrap_err();
        assert!(e.to_string().contains("truncated"), "{e}");
        // A track length past the file's end too.
        let mut b = 1u64.to_le_bytes().to_vec();
        b.extend(5u64.to_le_bytes());
        b.extend([0u8; 24 + 3 + 8]);
        b.extend((1u64 << 60).to_le_bytes());
        let e = parse_points_bin(p, &b).unwrap_err();
        assert!(e.to_string().contains("track elements of point 5"), "{e}");
    }

    #[test]
    fn text_images_take_empty_observation_lines_and_names_with_spaces() {
        let p = Path::new("m/images.txt");
        let text = "# header\n1 1 0 0 0 0 0 0 2 a b.png\n\n2 1 0 0 0 1 2 3 2 c.png\n1.5 2.5 -1 3 4 7\n";
        let images = parse_images_txt(p, text).unwrap();
        assert_eq!(images[&1].name, "a b.png");
        assert!(images[&1].points2d.is_empty());
        assert_eq!(
            images[&2].points2d,
            vec![(DVec2::new(1.5, 2.5), -1), (DVec2::new(3.0, 4.0), 7)]
        );
        let e = parse_images_txt(p, "1 1 0 0 0 0 0 0 2 a.png\n1 2\n").unwrap_err();
        assert!(e.to_string().contains("line 2"), "{e}");
        let e = parse_images_txt(p, "1 1 0 x 0 0 0 0 2 a.png\n\n").unwrap_err();
        assert!(e.to_string().contains("QY 'x'"), "{e}");
    }
}
