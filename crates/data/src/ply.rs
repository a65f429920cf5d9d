//! PLY meshes: read ASCII and binary (little- and big-endian) files, write binary little-endian.
//! Vertices are `x y z` of any numeric type; faces are a list property named `vertex_indices` or
//! `vertex_index` (polygons are fan-triangulated) with an optional per-face `object_id`. Other
//! elements and properties are skipped. Every error names the file. The one PLY reader and writer
//! of the house: the synthetic generator's ground-truth `mesh.ply` (per-face `object_id`), `i2sdf
//! mesh`'s output and the meshes of the evaluation all go through it. A file without faces reads
//! as a mesh without faces: a point cloud, which [`read_ground_truth`] accepts as geometry GT.

use crate::mesh::TriangleMesh;
use crate::DataError;
use std::path::Path;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Encoding {
    Ascii,
    BinaryLittleEndian,
    BinaryBigEndian,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
}

#[derive(Clone, Debug)]
struct Property {
    name: String,
    /// `Some(count type)` for a list property.
    list_count: Option<Scalar>,
    value: Scalar,
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

/// Reads values one at a time from the body, in the file's encoding.
struct BodyReader<'a> {
    encoding: Encoding,
    bytes: &'a [u8],
    pos: usize,
    path: &'a Path,
}

impl BodyReader<'_> {
    fn truncated(&self) -> DataError {
        DataError::file(
            self.path,
            "PLY body is truncated (fewer values than the header declares)",
        )
    }

    fn next_token(&mut self) -> Result<&str, DataError> {
        let b = self.bytes;
        while self.pos < b.len() && b[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        let start = self.pos;
        while self.pos < b.len() && !b[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        if start == self.pos {
            return Err(self.truncated());
        }
        std::str::from_utf8(&b[start..self.pos]).map_err(|_| DataError::file(self.path, "PLY ASCII body is not text"))
    }

    fn read(&mut self, scalar: Scalar) -> Result<f64, DataError> {
        if self.encoding == Encoding::Ascii {
            let path = self.path;
            let token = self.next_token()?;
            return token
                .parse::<f64>()
                .map_err(|_| DataError::file(path, format!("PLY ASCII body: '{token}' is not a number")));
        }
        let n = scalar.size();
        if self.pos + n > self.bytes.len() {
            return Err(self.truncated());
        }
        let mut raw = [0u8; 8];
        raw[..n].copy_from_slice(&self.bytes[self.pos..self.pos + n]);
        if self.encoding == Encoding::BinaryBigEndian {
            raw[..n].reverse();
        }
        self.pos += n;
        Ok(match scalar {
            Scalar::I8 => raw[0] as i8 as f64,
            Scalar::U8 => raw[0] as f64,
            Scalar::I16 => i16::from_le_bytes([raw[0], raw[1]]) as f64,
            Scalar::U16 => u16::from_le_bytes([raw[0], raw[1]]) as f64,
            Scalar::I32 => i32::from_le_bytes([raw[0], raw[1], raw[2], raw[3]]) as f64,
            Scalar::U32 => u32::from_le_bytes([raw[0], raw[1], raw[2], raw[3]]) as f64,
            Scalar::F32 => f32::from_le_bytes([raw[0], raw[1], raw[2], raw[3]]) as f64,
            Scalar::F64 => f64::from_le_bytes(raw),
        })
    }
}

fn parse_header(path: &Path, bytes: &[u8]) -> Result<(Encoding, Vec<Element>, usize), DataError> {
    let bad = |msg: String| DataError::file(path, format!("PLY header: {msg}"));
    let mut pos = 0;
    let mut lines = Vec::new();
    loop {
        let Some(len) = bytes[pos..].iter().position(|&b| b == b'\n') else {
            return Err(bad("no 'end_header' line".into()));
        };
        let line = std::str::from_utf8(&bytes[pos..pos + len])
            .map_err(|_| bad("not text".into()))?
            .trim_end_matches('\r')
            .trim()
            .to_string();
        pos += len + 1;
        let done = line == "end_header";
        lines.push(line);
        if done {
            break;
        }
    }
    if lines.first().map(String::as_str) != Some("ply") {
        return Err(DataError::file(path, "not a PLY file (no 'ply' magic line)"));
    }
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    for line in &lines[1..lines.len() - 1] {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", fmt, _version] => {
                encoding = Some(match *fmt {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::BinaryLittleEndian,
                    "binary_big_endian" => Encoding::BinaryBigEndian,
                    other => return Err(bad(format!("unknown format '{other}'"))),
                })
            }
            ["element", name, count] => elements.push(Element {
                name: name.to_string(),
                count: count
                    .parse()
                    .map_err(|_| bad(format!("element '{name}' has a bad count '{count}'")))?,
                properties: Vec::new(),
            }),
            ["property", "list", count_type, value_type, name] => {
                let element = elements
                    .last_mut()
                    .ok_or_else(|| bad(format!("property '{name}' before any element")))?;
                let parse = |t: &str| Scalar::parse(t).ok_or_else(|| bad(format!("unknown type '{t}'")));
                element.properties.push(Property {
                    name: name.to_string(),
                    list_count: Some(parse(count_type)?),
                    value: parse(value_type)?,
                });
            }
            ["property", value_type, name] => {
                let element = elements
                    .last_mut()
                    .ok_or_else(|| bad(format!("property '{name}' before any element")))?;
                element.properties.push(Property {
                    name: name.to_string(),
                    list_count: None,
                    value: Scalar::parse(value_type).ok_or_else(|| bad(format!("unknown type '{value_type}'")))?,
                });
            }
            _ => return Err(bad(format!("cannot parse line '{line}'"))),
        }
    }
    let encoding = encoding.ok_or_else(|| bad("no 'format' line".into()))?;
    Ok((encoding, elements, pos))
}

/// Reads a triangle mesh (see the module doc for what is understood).
pub fn read_ply(path: impl AsRef<Path>) -> Result<TriangleMesh, DataError> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| DataError::file(path, format!("cannot read: {e}")))?;
    parse_ply(path, &bytes)
}

/// Reads a dataset's geometry ground truth: a triangle mesh, or a point cloud (a PLY with vertices
/// and no faces, as the paper's authors promise for their release), which the mesh metrics use as
/// its points. A PLY with neither faces nor vertices is refused: nothing could be scored against
/// it, and every figure would come out null without a word.
pub fn read_ground_truth(path: impl AsRef<Path>) -> Result<TriangleMesh, DataError> {
    let path = path.as_ref();
    let mesh = read_ply(path)?;
    if mesh.num_faces() == 0 && mesh.num_vertices() == 0 {
        return Err(DataError::field(
            path,
            "vertex",
            "no vertices: a ground-truth point cloud needs points (and a mesh, faces)",
        ));
    }
    Ok(mesh)
}

/// [`read_ply`] of a file's bytes already in memory (`path` names the file in errors).
pub fn parse_ply(path: &Path, bytes: &[u8]) -> Result<TriangleMesh, DataError> {
    let (encoding, elements, body_start) = parse_header(path, bytes)?;
    check_body_can_hold(path, encoding, &elements, bytes.len() - body_start)?;
    let mut body = BodyReader {
        encoding,
        bytes: &bytes[body_start..],
        pos: 0,
        path,
    };
    let mut mesh = TriangleMesh::default();
    let mut object_ids = Vec::new();
    let mut saw_vertex = false;
    let mut has_object_id = false;
    for element in &elements {
        match element.name.as_str() {
            "vertex" => {
                saw_vertex = true;
                read_vertices(&mut body, element, &mut mesh)?;
            }
            "face" => has_object_id = read_faces(&mut body, element, &mut mesh, &mut object_ids)?,
            // An element without properties holds no data: a huge count of it would only spin.
            _ if element.properties.is_empty() => {}
            _ => skip_element(&mut body, element)?,
        }
    }
    if !saw_vertex {
        return Err(DataError::file(path, "PLY has no 'vertex' element"));
    }
    let n = mesh.positions.len() as u32;
    if let Some(f) = mesh.faces.iter().position(|f| f.iter().any(|&v| v >= n)) {
        return Err(DataError::field(
            path,
            "face",
            format!("triangle {f} indexes past the {n} vertices: {:?}", mesh.faces[f]),
        ));
    }
    if has_object_id {
        mesh.face_object_ids = Some(object_ids);
    }
    Ok(mesh)
}

/// Every value takes at least one byte of the body (a digit and a separator in ASCII), so an
/// element count the body cannot hold is refused here, before anything is reserved or looped
/// over: a header that claims 10¹² vertices costs nothing.
fn check_body_can_hold(
    path: &Path,
    encoding: Encoding,
    elements: &[Element],
    body_len: usize,
) -> Result<(), DataError> {
    let body_len = body_len as u128;
    let mut needed = 0u128;
    for element in elements {
        let min_bytes: u128 = element
            .properties
            .iter()
            .map(|p| match (encoding, p.list_count) {
                (Encoding::Ascii, _) => 2,
                (_, Some(count)) => count.size() as u128,
                (_, None) => p.value.size() as u128,
            })
            .sum();
        needed += element.count as u128 * min_bytes;
    }
    // The last ASCII value may end the file without a separator.
    if needed > body_len + 1 {
        return Err(DataError::file(
            path,
            format!(
                "PLY body is truncated: the header declares at least {needed} bytes of values, the body has {body_len}"
            ),
        ));
    }
    Ok(())
}

/// Reads and drops the values of one property of the current element (all of a list's).
fn skip_property(body: &mut BodyReader, prop: &Property) -> Result<(), DataError> {
    if let Some(count_type) = prop.list_count {
        let n = body.read(count_type)? as usize;
        for _ in 0..n {
            body.read(prop.value)?;
        }
    } else {
        body.read(prop.value)?;
    }
    Ok(())
}

/// Reads past an element the mesh does not use.
fn skip_element(body: &mut BodyReader, element: &Element) -> Result<(), DataError> {
    for _ in 0..element.count {
        for prop in &element.properties {
            skip_property(body, prop)?;
        }
    }
    Ok(())
}

/// Appends the `vertex` element's positions (`x y z`; other properties are skipped) to the mesh.
fn read_vertices(body: &mut BodyReader, element: &Element, mesh: &mut TriangleMesh) -> Result<(), DataError> {
    let path = body.path;
    let coord = ["x", "y", "z"].map(|axis| element.properties.iter().position(|p| p.name == axis));
    for (axis, c) in ["x", "y", "z"].iter().zip(coord) {
        match c {
            None => return Err(DataError::field(path, format!("vertex.{axis}"), "missing")),
            Some(i) if element.properties[i].list_count.is_some() => {
                return Err(DataError::field(path, format!("vertex.{axis}"), "is a list"))
            }
            Some(_) => {}
        }
    }
    let coord = coord.map(Option::unwrap);
    mesh.positions.reserve(element.count);
    for v in 0..element.count {
        let mut p = [0.0f32; 3];
        for (i, prop) in element.properties.iter().enumerate() {
            if prop.list_count.is_some() {
                skip_property(body, prop)?;
                continue;
            }
            let value = body.read(prop.value)?;
            if let Some(axis) = coord.iter().position(|&c| c == i) {
                p[axis] = value as f32;
            }
        }
        if p.iter().any(|x| !x.is_finite()) {
            return Err(DataError::field(
                path,
                "vertex",
                format!("vertex {v} is not finite: {p:?}"),
            ));
        }
        mesh.positions.push(p);
    }
    Ok(())
}

/// Appends the `face` element's polygons, fan-triangulated, to the mesh, and each triangle's
/// `object_id` to `object_ids` when the element has that property. Returns whether it has.
fn read_faces(
    body: &mut BodyReader,
    element: &Element,
    mesh: &mut TriangleMesh,
    object_ids: &mut Vec<i32>,
) -> Result<bool, DataError> {
    let path = body.path;
    let indices = element
        .properties
        .iter()
        .position(|p| p.name == "vertex_indices" || p.name == "vertex_index")
        .ok_or_else(|| DataError::field(path, "face", "no 'vertex_indices' or 'vertex_index' list property"))?;
    if element.properties[indices].list_count.is_none() {
        return Err(DataError::field(path, "face.vertex_indices", "is not a list"));
    }
    let object_id = element.properties.iter().position(|p| p.name == "object_id");
    let mut polygon = Vec::new();
    for f in 0..element.count {
        let mut id = 0i32;
        let mut triangles = 0;
        for (i, prop) in element.properties.iter().enumerate() {
            let Some(count_type) = prop.list_count else {
                let value = body.read(prop.value)?;
                if Some(i) == object_id {
                    id = value as i32;
                }
                continue;
            };
            let n = body.read(count_type)? as usize;
            polygon.clear();
            for _ in 0..n {
                polygon.push(body.read(prop.value)?);
            }
            if i != indices {
                continue;
            }
            if n < 3 {
                return Err(DataError::field(path, "face", format!("face {f} has {n} vertices")));
            }
            if polygon
                .iter()
                .any(|&x| x < 0.0 || x.fract() != 0.0 || x >= u32::MAX as f64)
            {
                return Err(DataError::field(path, "face", format!("face {f} has a bad index")));
            }
            // Polygons are fan-triangulated.
            for k in 1..n - 1 {
                mesh.faces
                    .push([polygon[0], polygon[k], polygon[k + 1]].map(|x| x as u32));
            }
            triangles = n - 2;
        }
        if object_id.is_some() {
            object_ids.extend(std::iter::repeat_n(id, triangles));
        }
    }
    Ok(object_id.is_some())
}

/// Writes a binary little-endian PLY: float `x y z` vertices, faces as `uchar` count + `int`
/// indices (`vertex_indices`), and an `int object_id` per face when the mesh has them.
pub fn write_ply(path: impl AsRef<Path>, mesh: &TriangleMesh) -> Result<(), DataError> {
    write_ply_with_comment(path, mesh, "written by i2sdf")
}

/// [`write_ply`] with the header's `comment` line saying what the mesh is (units, up axis). The
/// file is written atomically (a temporary file renamed into place), so a reader never sees half a
/// mesh.
pub fn write_ply_with_comment(path: impl AsRef<Path>, mesh: &TriangleMesh, comment: &str) -> Result<(), DataError> {
    let path = path.as_ref();
    if let Some(ids) = &mesh.face_object_ids {
        if ids.len() != mesh.faces.len() {
            return Err(DataError::invalid(format!(
                "writing {}: {} object ids for {} faces",
                path.display(),
                ids.len(),
                mesh.faces.len()
            )));
        }
    }
    if comment.contains('\n') {
        return Err(DataError::invalid(format!(
            "writing {}: a PLY comment must be one line",
            path.display()
        )));
    }
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\nelement face {}\n\
         property list uchar int vertex_indices\n",
        mesh.positions.len(),
        mesh.faces.len()
    );
    if mesh.face_object_ids.is_some() {
        header.push_str("property int object_id\n");
    }
    header.push_str("end_header\n");
    let mut buf = Vec::with_capacity(header.len() + mesh.positions.len() * 12 + mesh.faces.len() * 17);
    buf.extend_from_slice(header.as_bytes());
    for p in &mesh.positions {
        for x in p {
            buf.extend_from_slice(&x.to_le_bytes());
        }
    }
    for (f, face) in mesh.faces.iter().enumerate() {
        buf.push(3u8);
        for &v in face {
            buf.extend_from_slice(&(v as i32).to_le_bytes());
        }
        if let Some(ids) = &mesh.face_object_ids {
            buf.extend_from_slice(&ids[f].to_le_bytes());
        }
    }
    crate::imageio::write_bytes_atomic(path, &buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn box_mesh(min: [f32; 3], max: [f32; 3]) -> TriangleMesh {
        TriangleMesh::axis_box(min, max)
    }

    #[test]
    fn binary_round_trip_with_object_ids() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("box.ply");
        let mut mesh = box_mesh([0.0, -1.0, 2.5], [1.0, 0.5, 3.0]);
        mesh.face_object_ids = Some((0..12).map(|f| f / 4 - 1).collect());
        write_ply(&path, &mesh).unwrap();
        assert_eq!(read_ply(&path).unwrap(), mesh);
        mesh.face_object_ids = None;
        write_ply(&path, &mesh).unwrap();
        assert_eq!(read_ply(&path).unwrap(), mesh);
    }

    #[test]
    fn ascii_with_quads_extra_properties_and_vertex_index() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("quad.ply");
        let text = "ply\r\nformat ascii 1.0\r\ncomment hello\r\nelement vertex 4\r\n\
            property double x\r\nproperty float nx\r\nproperty double y\r\nproperty double z\r\n\
            property uchar red\r\nelement face 1\r\nproperty list uchar uint vertex_index\r\n\
            property ushort object_id\r\nelement edge 1\r\nproperty int vertex1\r\n\
            property int vertex2\r\nend_header\r\n\
            0 9 0 0 255\r\n1 9 0 0 255\r\n1 9 1 0 255\r\n0 9 1 0 255\r\n4 0 1 2 3 7\r\n0 1\r\n";
        std::fs::write(&path, text).unwrap();
        let mesh = read_ply(&path).unwrap();
        assert_eq!(mesh.positions[2], [1.0, 1.0, 0.0]);
        assert_eq!(mesh.faces, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(mesh.face_object_ids, Some(vec![7, 7]));
    }

    /// A vertices-only PLY (a point cloud, ASCII as scanners write them) is geometry GT; one with
    /// no vertices is refused naming the file and element.
    #[test]
    fn ground_truth_point_clouds() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("points.ply");
        let cloud = |n: usize| {
            let mut text = format!(
                "ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\n\
                 property float z\nproperty uchar red\nend_header\n"
            );
            (0..n).for_each(|k| text.push_str(&format!("{k} 0.5 -1 200\n")));
            text
        };
        std::fs::write(&path, cloud(3)).unwrap();
        let gt = read_ground_truth(&path).unwrap();
        assert_eq!((gt.num_vertices(), gt.num_faces()), (3, 0));
        assert_eq!(gt.positions[2], [2.0, 0.5, -1.0]);
        // A binary cloud as write_ply writes a mesh without faces reads back the same.
        write_ply(&path, &gt).unwrap();
        assert_eq!(read_ground_truth(&path).unwrap(), gt);
        std::fs::write(&path, cloud(0)).unwrap();
        let e = read_ground_truth(&path).unwrap_err().to_string();
        assert!(
            e.contains("points.ply") && e.contains("vertex") && e.contains("no vertices"),
            "{e}"
        );
        // A mesh is still read as a mesh.
        write_ply(&path, &box_mesh([0.0; 3], [1.0; 3])).unwrap();
        assert_eq!(read_ground_truth(&path).unwrap().num_faces(), 12);
    }

    #[test]
    fn big_endian_binary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("be.ply");
        let mut bytes = b"ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty float x\n\
            property float y\nproperty float z\nelement face 1\n\
            property list uchar int vertex_indices\nend_header\n"
            .to_vec();
        for v in [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0]] {
            v.iter().for_each(|x| bytes.extend_from_slice(&x.to_be_bytes()));
        }
        bytes.push(3);
        [0i32, 1, 2]
            .iter()
            .for_each(|x| bytes.extend_from_slice(&x.to_be_bytes()));
        std::fs::write(&path, bytes).unwrap();
        let mesh = read_ply(&path).unwrap();
        assert_eq!(mesh.positions[2], [0.0, 2.0, 0.0]);
        assert_eq!(mesh.faces, vec![[0, 1, 2]]);
        assert!((mesh.surface_area() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn errors_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let cases: [(&str, &[u8], &str); 5] = [
            ("notply.ply", b"hello\nend_header\n", "not a PLY"),
            ("short.ply", b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n", "truncated"),
            ("index.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0 1 0 0 0 1 0\n3 0 1 5\n", "indexes past"),
            ("nan.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\nnan 0 0\n", "not finite"),
            ("noz.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 0\n", "vertex.z"),
        ];
        for (name, bytes, expected) in cases {
            let path = dir.path().join(name);
            std::fs::write(&path, bytes).unwrap();
            let msg = read_ply(&path).unwrap_err().to_string();
            assert!(msg.contains(name) && msg.contains(expected), "{msg}");
        }
        let missing = read_ply(dir.path().join("missing.ply")).unwrap_err().to_string();
        assert!(missing.contains("missing.ply"), "{missing}");
    }
}
