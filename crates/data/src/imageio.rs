//! Reading and writing the images and float maps of the house: PNG (8/16 bit), OpenEXR and NumPy
//! `.npy`. Every reader validates (size, channel count, finiteness where asked) and names the file
//! in its error; every writer is atomic (write a temporary file beside the target, then rename), so a
//! killed job never leaves half a file behind.

use crate::error::{DataError, Result};
use std::path::{Path, PathBuf};

/// A float image, row-major with interleaved channels: `data[(y * width + x) * channels + c]`.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageF32 {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

impl ImageF32 {
    pub fn new(width: usize, height: usize, channels: usize) -> Self {
        ImageF32 {
            width,
            height,
            channels,
            data: vec![0.0; width * height * channels],
        }
    }

    pub fn from_data(width: usize, height: usize, channels: usize, data: Vec<f32>) -> Self {
        assert_eq!(data.len(), width * height * channels, "ImageF32 data size");
        ImageF32 {
            width,
            height,
            channels,
            data,
        }
    }

    #[inline]
    pub fn pixel(&self, x: usize, y: usize) -> &[f32] {
        let i = (y * self.width + x) * self.channels;
        &self.data[i..i + self.channels]
    }

    #[inline]
    pub fn pixel_mut(&mut self, x: usize, y: usize) -> &mut [f32] {
        let i = (y * self.width + x) * self.channels;
        &mut self.data[i..i + self.channels]
    }

    /// One channel as its own image (channel `c` of every pixel).
    pub fn channel(&self, c: usize) -> ImageF32 {
        let data = self.data.iter().skip(c).step_by(self.channels).copied().collect();
        ImageF32::from_data(self.width, self.height, 1, data)
    }

    /// Position of the first non-finite value, as (x, y, channel).
    pub fn first_non_finite(&self) -> Option<(usize, usize, usize)> {
        self.data.iter().position(|v| !v.is_finite()).map(|i| {
            let c = i % self.channels;
            let p = i / self.channels;
            (p % self.width, p / self.width, c)
        })
    }
}

/// The sRGB electro-optical transfer: encoded \[0,1\] value → linear.
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// The sRGB opto-electronic transfer: linear → encoded \[0,1\] value.
pub fn linear_to_srgb(v: f32) -> f32 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.0031308 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// The one tone map of linear images for display: each value × `exposure`, clamped to [0, 1],
/// sRGB-encoded ([`linear_to_srgb`]). The synthetic datasets' LDR images (their exposure),
/// stage 2's re-renders and edits in an sRGB dataset's encoding, and the linear albedo maps shown
/// as PNGs (exposure 1) all go through it.
pub fn tone_map_srgb(linear: &ImageF32, exposure: f32) -> ImageF32 {
    let mut out = linear.clone();
    out.data.iter_mut().for_each(|x| *x = linear_to_srgb(*x * exposure));
    out
}

fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

fn ensure_exists(path: &Path) -> Result<()> {
    if !path.is_file() {
        return Err(DataError::file(path, "file not found"));
    }
    Ok(())
}

/// The largest image the readers accept, in pixels (8192 × 8192, far above any indoor dataset):
/// a header is checked against it before anything is decoded, so a corrupt or hostile file that
/// claims 10⁹ × 10⁹ pixels is refused instead of allocating.
pub const MAX_PIXELS: u64 = 1 << 26;

/// The most values (pixels × channels) one float map may hold: 1 GiB of f32.
pub const MAX_SAMPLES: u64 = 1 << 28;

fn read_all(path: &Path) -> Result<Vec<u8>> {
    ensure_exists(path)?;
    std::fs::read(path).map_err(|e| DataError::file(path, format!("cannot read: {e}")))
}

/// Reads a colour or grey image: PNG (8 or 16 bit), JPEG, TIFF, BMP or WebP (scaled to \[0,1\],
/// values as stored, no transfer function applied), or EXR (linear floats). Grey images give 1
/// channel, grey+alpha 2, RGB 3, RGBA 4.
pub fn read_image(path: &Path) -> Result<ImageF32> {
    ensure_exists(path)?;
    image_format(path)?;
    read_image_bytes(path, &read_all(path)?)
}

/// [`read_image`] of a file's bytes already in memory; `path` picks the format by its extension
/// and names the file in errors.
pub fn read_image_bytes(path: &Path, bytes: &[u8]) -> Result<ImageF32> {
    match image_format(path)? {
        "exr" => read_exr(path, bytes),
        _ => read_raster(path, bytes),
    }
}

/// Extensions of the images [`read_image`] decodes (EXR aside), lower case: what a folder of
/// frames may hold.
pub const RASTER_EXTENSIONS: [&str; 7] = ["png", "jpg", "jpeg", "tif", "tiff", "bmp", "webp"];

fn image_format(path: &Path) -> Result<&'static str> {
    match extension(path).as_str() {
        // Decoded by the `image` crate, which finds the format from the bytes.
        e if RASTER_EXTENSIONS.contains(&e) => Ok("raster"),
        "exr" => Ok("exr"),
        other => Err(DataError::file(
            path,
            format!("unsupported image format '.{other}' (expected .png, .jpg, .tif, .bmp, .webp or .exr)"),
        )),
    }
}

fn float_map_format(path: &Path) -> Result<&'static str> {
    match extension(path).as_str() {
        "npy" => Ok("npy"),
        "exr" => Ok("exr"),
        "png" => Ok("png"),
        other => Err(DataError::file(
            path,
            format!("unsupported float map format '.{other}' (expected .exr, .npy or .png)"),
        )),
    }
}

/// Reads a float map (depth, normals, material maps): EXR or `.npy` (float32/float64, H×W or
/// H×W×C), or a PNG read as \[0,1\] values.
pub fn read_float_map(path: &Path) -> Result<ImageF32> {
    ensure_exists(path)?;
    float_map_format(path)?;
    read_float_map_bytes(path, &read_all(path)?)
}

/// [`read_float_map`] of a file's bytes already in memory (`path` picks the format and names
/// the file in errors).
pub fn read_float_map_bytes(path: &Path, bytes: &[u8]) -> Result<ImageF32> {
    match float_map_format(path)? {
        "npy" => read_npy(path, bytes),
        "exr" => read_exr(path, bytes),
        _ => read_raster(path, bytes),
    }
}

/// Refuses an image size beyond [`MAX_PIXELS`] (or an empty one) before it is allocated.
fn check_dimensions(path: &Path, width: u64, height: u64, channels: u64) -> Result<()> {
    let pixels = width.checked_mul(height);
    if width == 0 || height == 0 {
        return Err(DataError::file(path, format!("image size {width}×{height} is empty")));
    }
    match pixels {
        Some(p) if p <= MAX_PIXELS && p.saturating_mul(channels) <= MAX_SAMPLES => Ok(()),
        _ => Err(DataError::file(
            path,
            format!(
                "image size {width}×{height}×{channels} is larger than this reader accepts \
                 ({MAX_PIXELS} pixels, {MAX_SAMPLES} values): a corrupt header?"
            ),
        )),
    }
}

/// Decodes a raster image (PNG, JPEG, TIFF, BMP, WebP) held in memory, with the header's size
/// checked before the pixels are.
fn decode_raster(path: &Path, bytes: &[u8]) -> Result<image::DynamicImage> {
    let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| DataError::file(path, format!("cannot read: {e}")))?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(1 << 16);
    limits.max_image_height = Some(1 << 16);
    reader.limits(limits.clone());
    let (w, h) = reader
        .into_dimensions()
        .map_err(|e| DataError::file(path, format!("cannot decode image: {e}")))?;
    check_dimensions(path, w as u64, h as u64, 4)?;
    let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| DataError::file(path, format!("cannot read: {e}")))?;
    reader.limits(limits);
    reader
        .decode()
        .map_err(|e| DataError::file(path, format!("cannot decode image: {e}")))
}

fn read_raster(path: &Path, bytes: &[u8]) -> Result<ImageF32> {
    let img = decode_raster(path, bytes)?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    let channels = img.color().channel_count() as usize;
    let data: Vec<f32> = match channels {
        1 => img.to_luma32f().into_raw(),
        2 => img.to_luma_alpha32f().into_raw(),
        3 => img.to_rgb32f().into_raw(),
        _ => img.to_rgba32f().into_raw(),
    };
    let channels = channels.min(4);
    Ok(ImageF32::from_data(w, h, channels, data))
}

/// Reads a 16-bit (or 8-bit) grey PNG as raw integer values (depth PNGs scaled by
/// `depth_unit_scale_factor`, confidence maps).
pub fn read_png_raw_gray(path: &Path) -> Result<ImageF32> {
    read_png_raw_gray_bytes(path, &read_all(path)?)
}

/// [`read_png_raw_gray`] of a file's bytes already in memory.
pub fn read_png_raw_gray_bytes(path: &Path, bytes: &[u8]) -> Result<ImageF32> {
    let img = decode_raster(path, bytes)?;
    if img.color().channel_count() != 1 {
        return Err(DataError::file(
            path,
            format!(
                "a depth PNG must have one channel, found {}",
                img.color().channel_count()
            ),
        ));
    }
    let (w, h) = (img.width() as usize, img.height() as usize);
    // The stored integers, whatever the bit depth: `to_luma16` would rescale 8-bit values by 257.
    let data = match img {
        image::DynamicImage::ImageLuma8(b) => b.into_raw().into_iter().map(f32::from).collect(),
        other => other.to_luma16().into_raw().into_iter().map(f32::from).collect(),
    };
    Ok(ImageF32::from_data(w, h, 1, data))
}

/// Channel order used when reading EXRs: colour first, then the usual single-channel names.
const EXR_ORDER: [&str; 8] = ["R", "G", "B", "A", "X", "Y", "Z", "D"];

/// The most channels an EXR layer may have (ours have at most 4; AOV files a few dozen).
const MAX_EXR_CHANNELS: usize = 64;

fn read_exr(path: &Path, bytes: &[u8]) -> Result<ImageF32> {
    use exr::prelude::*;
    let bad = |e: exr::error::Error| DataError::file(path, format!("cannot read EXR: {e}"));
    // The headers first: every layer's size is checked before the reader allocates its pixels.
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), false).map_err(bad)?;
    for header in &meta.headers {
        let size = header.layer_size;
        let channels = header.channels.list.len();
        if channels > MAX_EXR_CHANNELS {
            return Err(DataError::file(
                path,
                format!("EXR layer has {channels} channels (at most {MAX_EXR_CHANNELS} are read)"),
            ));
        }
        check_dimensions(path, size.width() as u64, size.height() as u64, channels.max(1) as u64)?;
    }
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .map_err(bad)?;
    let layer = &image.layer_data;
    let (w, h) = (layer.size.width(), layer.size.height());
    check_dimensions(path, w as u64, h as u64, layer.channel_data.list.len().max(1) as u64)?;
    // exr sorts channels alphabetically; reorder so RGB(A) / XYZ come out in their natural order.
    let mut chans: Vec<(String, Vec<f32>)> = layer
        .channel_data
        .list
        .iter()
        .map(|c| (c.name.to_string(), c.sample_data.values_as_f32().collect()))
        .collect();
    let rank = |name: &str| {
        let last = name.rsplit('.').next().unwrap_or(name).to_ascii_uppercase();
        EXR_ORDER.iter().position(|n| *n == last).unwrap_or(EXR_ORDER.len())
    };
    chans.sort_by_key(|(n, _)| rank(n));
    if chans.is_empty() {
        return Err(DataError::file(path, "EXR has no channels"));
    }
    let c = chans.len();
    let mut data = vec![0.0f32; w * h * c];
    for (ci, (_, values)) in chans.iter().enumerate() {
        if values.len() != w * h {
            return Err(DataError::file(path, "EXR channel size does not match the image size"));
        }
        for (p, v) in values.iter().enumerate() {
            data[p * c + ci] = *v;
        }
    }
    Ok(ImageF32::from_data(w, h, c, data))
}

fn read_npy(path: &Path, bytes: &[u8]) -> Result<ImageF32> {
    npy_to_image(path, npy_file(path, bytes)?)
}

const MAX_NPY_HEADER_NESTING: usize = 8;

/// Opens a `.npy` array held in memory. The header's length field is checked against the bytes
/// first: npyz allocates whatever length the field claims (up to 4 GiB in a version-2/3 file)
/// before reading the header.
pub fn npy_file<'a>(path: &Path, bytes: &'a [u8]) -> Result<npyz::NpyFile<&'a [u8]>> {
    let bad = |msg: String| DataError::file(path, format!("not a valid .npy file: {msg}"));
    if bytes.len() >= 10 && bytes.starts_with(b"\x93NUMPY") {
        let (start, len) = match bytes[6] {
            1 => (10, u16::from_le_bytes([bytes[8], bytes[9]]) as usize),
            _ if bytes.len() >= 12 => (
                12,
                u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            ),
            _ => return Err(bad("truncated header".into())),
        };
        if start + len > bytes.len() {
            return Err(bad(format!(
                "the header claims {len} bytes, the file has {} after it",
                bytes.len() - start
            )));
        }
        // npyz's header grammar backtracks exponentially in the nesting depth (the fuzzer found
        // 41 nested braces taking minutes). A header is a flat dict with a shape tuple (a
        // structured dtype, refused anyway, nests a few levels more).
        let mut depth = 0usize;
        for &b in &bytes[start..start + len] {
            match b {
                b'{' | b'[' | b'(' => depth += 1,
                b'}' | b']' | b')' => depth = depth.saturating_sub(1),
                _ => {}
            }
            if depth > MAX_NPY_HEADER_NESTING {
                return Err(bad(format!(
                    "the header nests brackets more than {MAX_NPY_HEADER_NESTING} deep"
                )));
            }
        }
    }
    npyz::NpyFile::new(bytes).map_err(|e| bad(e.to_string()))
}

/// Reads one `.npy` array held in memory as an image (see [`npy_to_image`]).
pub fn read_npy_bytes(path: &Path, bytes: &[u8]) -> Result<ImageF32> {
    read_npy(path, bytes)
}

/// Converts one `.npy` array (from a file or an npz member) of shape H×W or H×W×C to an image.
pub fn npy_to_image<R: std::io::Read>(path: &Path, npy: npyz::NpyFile<R>) -> Result<ImageF32> {
    let shape: Vec<usize> = npy.shape().iter().map(|&s| s as usize).collect();
    let (h, w, c) = match shape.as_slice() {
        [h, w] => (*h, *w, 1),
        [h, w, c] if *c >= 1 && *c <= 4 => (*h, *w, *c),
        [h, w, 1, c] => (*h, *w, *c),
        _ => {
            return Err(DataError::file(
                path,
                format!("expected an H×W or H×W×C array (C ≤ 4), found shape {shape:?}"),
            ))
        }
    };
    check_dimensions(path, w as u64, h as u64, c as u64)?;
    if npy.order() == npyz::Order::Fortran {
        return Err(DataError::file(
            path,
            "Fortran-ordered arrays are not supported (save with np.ascontiguousarray)",
        ));
    }
    let data = read_npy_values(path, npy)?;
    Ok(ImageF32::from_data(w, h, c, data))
}

/// All values of a numeric `.npy` array as f32 (float32, float64 and integer arrays accepted).
pub fn read_npy_values<R: std::io::Read>(path: &Path, npy: npyz::NpyFile<R>) -> Result<Vec<f32>> {
    let type_str = npy_type(path, &npy)?;
    check_npy_len(path, &npy)?;
    if type_str == "f4" {
        // The common case, without a round trip through f64.
        return npy
            .into_vec::<f32>()
            .map_err(|e| DataError::file(path, format!("cannot read array data: {e}")));
    }
    Ok(read_npy_f64(path, npy)?.into_iter().map(|v| v as f32).collect())
}

/// Refuses an array whose shape claims more than [`MAX_SAMPLES`] values (or whose element count
/// overflows) before its data is read.
fn check_npy_len<R: std::io::Read>(path: &Path, npy: &npyz::NpyFile<R>) -> Result<()> {
    let len = npy.shape().iter().try_fold(1u64, |n, &s| n.checked_mul(s));
    match len {
        Some(n) if n <= MAX_SAMPLES => Ok(()),
        _ => Err(DataError::file(
            path,
            format!(
                "array shape {:?} holds more than {MAX_SAMPLES} values: a corrupt header?",
                npy.shape()
            ),
        )),
    }
}

fn npy_type<R: std::io::Read>(path: &Path, npy: &npyz::NpyFile<R>) -> Result<String> {
    match npy.dtype() {
        npyz::DType::Plain(ts) => Ok(ts.to_string().trim_start_matches(['<', '>', '|', '=']).to_string()),
        other => Err(DataError::file(path, format!("unsupported array dtype {other:?}"))),
    }
}

/// All values of a numeric `.npy` array as f64, without losing the precision of float64 data
/// (camera matrices).
pub fn read_npy_f64<R: std::io::Read>(path: &Path, npy: npyz::NpyFile<R>) -> Result<Vec<f64>> {
    let type_str = npy_type(path, &npy)?;
    check_npy_len(path, &npy)?;
    let err = |e: std::io::Error| DataError::file(path, format!("cannot read array data: {e}"));
    Ok(match type_str.as_str() {
        "f8" => npy.into_vec::<f64>().map_err(err)?,
        "f4" => npy.into_vec::<f32>().map_err(err)?.into_iter().map(f64::from).collect(),
        "i4" => npy.into_vec::<i32>().map_err(err)?.into_iter().map(f64::from).collect(),
        "i8" => npy
            .into_vec::<i64>()
            .map_err(err)?
            .into_iter()
            .map(|v| v as f64)
            .collect(),
        "u1" => npy.into_vec::<u8>().map_err(err)?.into_iter().map(f64::from).collect(),
        "u2" => npy.into_vec::<u16>().map_err(err)?.into_iter().map(f64::from).collect(),
        "b1" => npy
            .into_vec::<bool>()
            .map_err(err)?
            .into_iter()
            .map(|v| v as u8 as f64)
            .collect(),
        "f2" => {
            return Err(DataError::file(
                path,
                "float16 arrays are not supported; save as float32",
            ))
        }
        _ => return Err(DataError::file(path, format!("unsupported array dtype '{type_str}'"))),
    })
}

/// Writes to a temporary file beside `path` and renames it into place, so readers never see a
/// partial file. Creates the parent directory.
pub fn write_atomic(path: &Path, write: impl FnOnce(&Path) -> std::result::Result<(), String>) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| DataError::io(dir, format!("cannot create directory: {e}")))?;
    }
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("out");
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("tmp");
    // The temporary keeps the extension: some encoders pick the format from it.
    let tmp: PathBuf = path.with_file_name(format!(".{name}.{}.partial.{ext}", std::process::id()));
    if let Err(msg) = write(&tmp) {
        let _ = std::fs::remove_file(&tmp);
        return Err(DataError::io(path, format!("cannot write: {msg}")));
    }
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        DataError::io(path, format!("cannot move into place: {e}"))
    })
}

/// Writes bytes atomically (JSON, TOML, PLY headers…).
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic(path, |tmp| std::fs::write(tmp, bytes).map_err(|e| e.to_string()))
}

fn png_color(channels: usize, sixteen: bool) -> image::ExtendedColorType {
    use image::ExtendedColorType as C;
    match (channels, sixteen) {
        (1, false) => C::L8,
        (2, false) => C::La8,
        (3, false) => C::Rgb8,
        (4, false) => C::Rgba8,
        (1, true) => C::L16,
        (2, true) => C::La16,
        (3, true) => C::Rgb16,
        _ => C::Rgba16,
    }
}

fn check_png_channels(path: &Path, img: &ImageF32) -> Result<()> {
    if !(1..=4).contains(&img.channels) {
        return Err(DataError::file(
            path,
            format!("cannot write {} channels as PNG", img.channels),
        ));
    }
    Ok(())
}

/// The image's values clamped to [0,1] and rounded to 8 bits.
fn to_8bit(img: &ImageF32) -> Vec<u8> {
    img.data
        .iter()
        .map(|v| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8)
        .collect()
}

/// Writes an 8-bit PNG; values are clamped to \[0,1\] and written as given (apply
/// [`linear_to_srgb`] first for display-referred images).
pub fn write_png(path: &Path, img: &ImageF32) -> Result<()> {
    check_png_channels(path, img)?;
    let bytes = to_8bit(img);
    write_atomic(path, |tmp| {
        image::save_buffer_with_format(
            tmp,
            &bytes,
            img.width as u32,
            img.height as u32,
            png_color(img.channels, false),
            image::ImageFormat::Png,
        )
        .map_err(|e| e.to_string())
    })
}

/// Writes an 8-bit JPEG (1 or 3 channels) at `quality` (1–100, the image crate's encoder);
/// values are clamped and quantized as [`write_png`] does.
pub fn write_jpeg(path: &Path, img: &ImageF32, quality: u8) -> Result<()> {
    if !matches!(img.channels, 1 | 3) {
        return Err(DataError::file(
            path,
            format!("cannot write {} channels as JPEG", img.channels),
        ));
    }
    let bytes = to_8bit(img);
    write_atomic(path, |tmp| {
        let file = std::fs::File::create(tmp).map_err(|e| e.to_string())?;
        let mut out = std::io::BufWriter::new(file);
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, quality.clamp(1, 100))
            .encode(
                &bytes,
                img.width as u32,
                img.height as u32,
                png_color(img.channels, false),
            )
            .map_err(|e| e.to_string())?;
        std::io::Write::flush(&mut out).map_err(|e| e.to_string())
    })
}

/// Writes a 16-bit PNG of values in \[0,1\] (clamped).
pub fn write_png16(path: &Path, img: &ImageF32) -> Result<()> {
    let raw: Vec<u16> = img
        .data
        .iter()
        .map(|v| (v.clamp(0.0, 1.0) * 65535.0 + 0.5) as u16)
        .collect();
    write_png16_raw(path, img.width, img.height, img.channels, &raw)
}

/// Writes a 16-bit PNG of raw integer values (e.g. depth in millimetres).
pub fn write_png16_raw(path: &Path, width: usize, height: usize, channels: usize, raw: &[u16]) -> Result<()> {
    if !(1..=4).contains(&channels) || raw.len() != width * height * channels {
        return Err(DataError::file(path, "bad 16-bit PNG buffer"));
    }
    // `image` takes 16-bit samples as native-endian bytes and handles PNG's big-endian itself.
    let bytes: Vec<u8> = raw.iter().flat_map(|v| v.to_ne_bytes()).collect();
    write_atomic(path, |tmp| {
        image::save_buffer_with_format(
            tmp,
            &bytes,
            width as u32,
            height as u32,
            png_color(channels, true),
            image::ImageFormat::Png,
        )
        .map_err(|e| e.to_string())
    })
}

/// Writes a float EXR (f32, lossless): 1 channel → "Y", 3 → "R","G","B", 4 → RGBA, 2 → "Y","A".
pub fn write_exr(path: &Path, img: &ImageF32) -> Result<()> {
    use exr::prelude::*;
    let names: &[&str] = match img.channels {
        1 => &["Y"],
        2 => &["Y", "A"],
        3 => &["R", "G", "B"],
        4 => &["R", "G", "B", "A"],
        n => return Err(DataError::file(path, format!("cannot write {n} channels as EXR"))),
    };
    let list: SmallVec<[AnyChannel<FlatSamples>; 4]> = names
        .iter()
        .enumerate()
        .map(|(c, name)| {
            let values: Vec<f32> = img.data.iter().skip(c).step_by(img.channels).copied().collect();
            AnyChannel::new(*name, FlatSamples::F32(values))
        })
        .collect();
    let layer = Layer::new(
        (img.width, img.height),
        LayerAttributes::named("main"),
        Encoding::FAST_LOSSLESS,
        AnyChannels::sort(list),
    );
    let image = Image::from_layer(layer);
    write_atomic(path, |tmp| image.write().to_file(tmp).map_err(|e| e.to_string()))
}

/// Writes a float32 `.npy` array of shape H×W (1 channel) or H×W×C.
pub fn write_npy(path: &Path, img: &ImageF32) -> Result<()> {
    use npyz::WriterBuilder;
    let shape: Vec<u64> = if img.channels == 1 {
        vec![img.height as u64, img.width as u64]
    } else {
        vec![img.height as u64, img.width as u64, img.channels as u64]
    };
    write_atomic(path, |tmp| {
        let file = std::fs::File::create(tmp).map_err(|e| e.to_string())?;
        let mut writer = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&shape)
            .writer(std::io::BufWriter::new(file))
            .begin_nd()
            .map_err(|e| e.to_string())?;
        writer.extend(img.data.iter().copied()).map_err(|e| e.to_string())?;
        writer.finish().map_err(|e| e.to_string())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: usize, h: usize, c: usize) -> ImageF32 {
        let data = (0..w * h * c).map(|i| (i as f32 * 0.37).sin() * 0.5 + 0.5).collect();
        ImageF32::from_data(w, h, c, data)
    }

    #[test]
    fn exr_round_trip_keeps_channel_order() {
        let dir = tempfile::tempdir().unwrap();
        for c in [1, 3, 4] {
            let img = ramp(7, 5, c);
            let p = dir.path().join(format!("a{c}.exr"));
            write_exr(&p, &img).unwrap();
            assert_eq!(read_image(&p).unwrap(), img);
        }
    }

    #[test]
    fn npy_round_trip_and_f64() {
        let dir = tempfile::tempdir().unwrap();
        for c in [1, 3] {
            let img = ramp(6, 4, c);
            let p = dir.path().join(format!("a{c}.npy"));
            write_npy(&p, &img).unwrap();
            assert_eq!(read_float_map(&p).unwrap(), img);
        }
        // float64 arrays, as numpy writes by default
        use npyz::WriterBuilder;
        let p = dir.path().join("f64.npy");
        let mut out = Vec::new();
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&[2, 3])
            .writer(&mut out)
            .begin_nd()
            .unwrap();
        w.extend([1.0f64, 2.0, 3.0, 4.0, 5.0, 6.5]).unwrap();
        w.finish().unwrap();
        std::fs::write(&p, out).unwrap();
        let m = read_float_map(&p).unwrap();
        assert_eq!((m.width, m.height, m.channels), (3, 2, 1));
        assert_eq!(m.data[5], 6.5);
    }

    #[test]
    fn jpeg_writes_decode_near_the_original() {
        let dir = tempfile::tempdir().unwrap();
        // A smooth image (JPEG's blocks are lossy on the ramp's per-pixel oscillation).
        let data = (0..32 * 24 * 3)
            .map(|i| ((i / 3) % 32) as f32 / 40.0 + (i % 3) as f32 * 0.1)
            .collect();
        let img = ImageF32::from_data(32, 24, 3, data);
        let p = dir.path().join("a.jpg");
        write_jpeg(&p, &img, 95).unwrap();
        let back = read_image(&p).unwrap();
        assert_eq!((back.width, back.height, back.channels), (32, 24, 3));
        let mean = back.data.iter().zip(&img.data).map(|(a, b)| (a - b).abs()).sum::<f32>() / img.data.len() as f32;
        assert!(mean < 0.01, "mean error {mean}");
        let e = write_jpeg(&dir.path().join("b.jpg"), &ramp(4, 4, 2), 90).unwrap_err();
        assert!(e.to_string().contains("b.jpg"), "{e}");
    }

    #[test]
    fn png_8_and_16_bit_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let img = ramp(9, 3, 3);
        let p8 = dir.path().join("a.png");
        write_png(&p8, &img).unwrap();
        let back = read_image(&p8).unwrap();
        assert!(back
            .data
            .iter()
            .zip(&img.data)
            .all(|(a, b)| (a - b).abs() <= 0.5 / 255.0 + 1e-6));
        let p16 = dir.path().join("b.png");
        write_png16(&p16, &img).unwrap();
        let back = read_image(&p16).unwrap();
        assert!(back
            .data
            .iter()
            .zip(&img.data)
            .all(|(a, b)| (a - b).abs() <= 0.5 / 65535.0 + 1e-6));
        let raw: Vec<u16> = (0..12).map(|i| i * 1000).collect();
        let pr = dir.path().join("d.png");
        write_png16_raw(&pr, 4, 3, 1, &raw).unwrap();
        let back = read_png_raw_gray(&pr).unwrap();
        assert_eq!(back.data[11], 11000.0);
    }

    #[test]
    fn missing_and_bad_files_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("nope.exr");
        let e = read_image(&p).unwrap_err().to_string();
        assert!(e.contains("nope.exr") && e.contains("not found"), "{e}");
        let bad = dir.path().join("bad.png");
        std::fs::write(&bad, b"not a png").unwrap();
        let e = read_image(&bad).unwrap_err().to_string();
        assert!(e.contains("bad.png"), "{e}");
        let bad = dir.path().join("bad.npy");
        std::fs::write(&bad, b"\x93NUMPY garbage").unwrap();
        assert!(read_float_map(&bad).unwrap_err().to_string().contains("bad.npy"));
    }

    #[test]
    fn srgb_transfer_inverts() {
        for i in 0..=100 {
            let v = i as f32 / 100.0;
            assert!((srgb_to_linear(linear_to_srgb(v)) - v).abs() < 1e-5);
        }
    }

    #[test]
    fn atomic_write_leaves_no_partial_file_on_failure() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.bin");
        assert!(write_atomic(&p, |_| Err("boom".into())).is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}

#[cfg(test)]
mod raster_tests {
    use super::*;

    /// A smooth colour image, as 8-bit RGB.
    fn smooth(w: u32, h: u32) -> image::RgbImage {
        image::RgbImage::from_fn(w, h, |x, y| {
            image::Rgb([
                (x * 255 / w) as u8,
                (y * 255 / h) as u8,
                ((x + y) * 127 / (w + h)) as u8,
            ])
        })
    }

    /// JPEG (as phones and nerfstudio's processed captures write it) decodes to the image within
    /// its compression error; BMP and TIFF decode exactly; the format comes from the bytes.
    #[test]
    fn jpeg_tiff_and_bmp_decode() {
        let dir = tempfile::tempdir().unwrap();
        let src = smooth(64, 48);
        let exact: Vec<f32> = src.as_raw().iter().map(|&v| v as f32 / 255.0).collect();
        let jpg = dir.path().join("frame.jpg");
        let mut bytes = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, 90)
            .encode_image(&src)
            .unwrap();
        std::fs::write(&jpg, &bytes).unwrap();
        let img = read_image(&jpg).unwrap();
        assert_eq!((img.width, img.height, img.channels), (64, 48, 3));
        let mae = img.data.iter().zip(&exact).map(|(a, b)| (a - b).abs()).sum::<f32>() / exact.len() as f32;
        assert!(mae < 0.01, "JPEG q90 mean error {mae}");
        for ext in ["bmp", "tif"] {
            let p = dir.path().join(format!("frame.{ext}"));
            src.save(&p).unwrap();
            let img = read_image(&p).unwrap();
            assert_eq!(img.data, exact, "{ext}");
        }
        // A JPEG named .JPEG (any case) is read too; a truncated one names the file.
        let upper = dir.path().join("frame2.JPEG");
        std::fs::write(&upper, &bytes).unwrap();
        assert!(read_image(&upper).is_ok());
        let cut = dir.path().join("cut.jpg");
        std::fs::write(&cut, &bytes[..bytes.len() / 3]).unwrap();
        let e = read_image(&cut).unwrap_err().to_string();
        assert!(e.contains("cut.jpg"), "{e}");
        let odd = dir.path().join("x.gifx");
        std::fs::write(&odd, &bytes).unwrap();
        let e = read_image(&odd).unwrap_err().to_string();
        assert!(e.contains(".jpg") && e.contains(".exr"), "{e}");
    }
}
