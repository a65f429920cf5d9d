//! The files an edit spec refers to, decoded before anything is rendered or written: projected
//! textures (to linear RGB in [0, 1], refused over [`MAX_TEXTURE_SIDE`] from the header, before
//! decoding) and meshes to insert (transformed into world units). Errors name the op, key and file.

use crate::edit_spec::{
    fmt3, EditOp, EditSpec, InsertOp, MaterialOp, MaterialOverride, MeshShape, Shape, MAX_TEXTURE_SIDE,
};
use crate::error::{DataError, Result};
use crate::imageio::{self, ImageF32};
use crate::mesh::TriangleMesh;
use crate::ply;
use glam::Vec3;
use std::path::Path;

/// The decoded files of a spec, by op index.
#[derive(Clone, Debug, Default)]
pub struct EditAssets {
    /// Linear RGB (3 channels), values clamped to [0, 1], for each textured material op.
    pub textures: Vec<Option<ImageF32>>,
    /// In world units (transform applied), for each mesh insert.
    pub meshes: Vec<Option<TriangleMesh>>,
}

impl EditAssets {
    pub fn texture(&self, op: usize) -> Option<&ImageF32> {
        self.textures.get(op).and_then(Option::as_ref)
    }
    pub fn mesh(&self, op: usize) -> Option<&TriangleMesh> {
        self.meshes.get(op).and_then(Option::as_ref)
    }
}

impl EditSpec {
    /// Decodes every texture (to linear RGB in [0, 1]) and every mesh (to world units).
    pub fn load_assets(&self) -> Result<EditAssets> {
        let mut assets = EditAssets {
            textures: vec![None; self.ops.len()],
            meshes: vec![None; self.ops.len()],
        };
        for (i, op) in self.ops.iter().enumerate() {
            match op {
                EditOp::Material(MaterialOp {
                    material: MaterialOverride::Texture { texture, .. },
                    ..
                }) => assets.textures[i] = Some(load_texture(i, &texture.image)?),
                EditOp::Insert(InsertOp {
                    shape: Shape::Mesh(m), ..
                }) => assets.meshes[i] = Some(load_mesh(i, m)?),
                _ => {}
            }
        }
        Ok(assets)
    }
}

/// The message of a loader's error, without the path it already names.
fn inner_message(e: DataError) -> String {
    match e {
        DataError::File { msg, .. } => msg,
        DataError::Field { field, msg, .. } => format!("{field}: {msg}"),
        other => other.to_string(),
    }
}

fn image_dimensions(path: &Path, exr: bool) -> std::result::Result<(usize, usize), String> {
    if exr {
        let meta = exr::meta::MetaData::read_from_file(path, false).map_err(|e| format!("cannot read EXR: {e}"))?;
        let h = meta.headers.first().ok_or("EXR has no layers")?;
        Ok((h.layer_size.width(), h.layer_size.height()))
    } else {
        let (w, h) = image::ImageReader::open(path)
            .map_err(|e| format!("cannot open: {e}"))?
            .with_guessed_format()
            .map_err(|e| format!("cannot read: {e}"))?
            .into_dimensions()
            .map_err(|e| format!("cannot decode image: {e}"))?;
        Ok((w as usize, h as usize))
    }
}

fn load_texture(op: usize, path: &Path) -> Result<ImageF32> {
    let key = format!("op[{op}].texture.image");
    let err = |msg: String| DataError::field(path, key.as_str(), msg);
    let exr = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("exr"));
    let (w, h) = image_dimensions(path, exr).map_err(err)?;
    if w == 0 || h == 0 || w > MAX_TEXTURE_SIDE || h > MAX_TEXTURE_SIDE {
        return Err(err(format!(
            "image is {w}×{h}; textures must be 1 to {MAX_TEXTURE_SIDE} pixels on each side"
        )));
    }
    let img = imageio::read_image(path).map_err(|e| err(inner_message(e)))?;
    if let Some((x, y, c)) = img.first_non_finite() {
        return Err(err(format!("non-finite value at pixel ({x}, {y}), channel {c}")));
    }
    // PNGs come back as stored (sRGB-encoded); EXRs are linear.
    let decode = |v: f32| {
        let v = if exr { v } else { imageio::srgb_to_linear(v) };
        v.clamp(0.0, 1.0)
    };
    let mut data = Vec::with_capacity(img.width * img.height * 3);
    for y in 0..img.height {
        for x in 0..img.width {
            let p = img.pixel(x, y);
            let rgb = if p.len() >= 3 { [p[0], p[1], p[2]] } else { [p[0]; 3] };
            data.extend(rgb.map(decode));
        }
    }
    Ok(ImageF32::from_data(img.width, img.height, 3, data))
}

fn load_mesh(op: usize, shape: &MeshShape) -> Result<TriangleMesh> {
    let path = shape.path.as_path();
    let key = format!("op[{op}].mesh.path");
    let err = |msg: String| DataError::field(path, key.as_str(), msg);
    let mut mesh = ply::read_ply(path).map_err(|e| err(inner_message(e)))?;
    if mesh.positions.is_empty() || mesh.faces.is_empty() {
        return Err(err(format!(
            "mesh is empty ({} vertices, {} faces)",
            mesh.positions.len(),
            mesh.faces.len()
        )));
    }
    for (i, p) in mesh.positions.iter_mut().enumerate() {
        let q = shape.transform_point(Vec3::from(*p));
        if !q.is_finite() {
            return Err(err(format!(
                "vertex {i} is not finite after scale / rotation / translation: {}",
                fmt3(q.to_array())
            )));
        }
        *p = q.to_array();
    }
    Ok(mesh)
}
