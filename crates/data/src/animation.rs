//! Animated outputs of camera paths (`render --path`, `edit --path`): an animated GIF of the
//! frames, written atomically, and an MP4 through `ffmpeg` when it is on the PATH (a video
//! encoder is not ours to write, and no pure-Rust H.264 encoder is well kept).

use crate::imageio::{write_bytes_atomic, ImageF32};
use crate::DataError;
use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame, Rgba, RgbaImage};
use std::path::Path;
use std::process::{Command, Stdio};

/// An image of 1 (grey) or 3 (RGB) channels in [0, 1] as 8-bit RGBA.
fn rgba(img: &ImageF32) -> Result<RgbaImage, DataError> {
    if img.channels != 1 && img.channels != 3 {
        return Err(DataError::invalid(format!(
            "an animation frame has {} channels: 1 or 3 expected",
            img.channels
        )));
    }
    let q = |x: f32| (x.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
    let c = img.channels;
    Ok(RgbaImage::from_fn(img.width as u32, img.height as u32, |x, y| {
        let i = (y as usize * img.width + x as usize) * c;
        let p = &img.data[i..i + c];
        let (r, g, b) = if c == 1 { (p[0], p[0], p[0]) } else { (p[0], p[1], p[2]) };
        Rgba([q(r), q(g), q(b), 255])
    }))
}

/// Writes `frames` (same size, display values in [0, 1]) as a looping animated GIF at `fps`.
pub fn write_gif(path: &Path, frames: &[ImageF32], fps: u32) -> Result<(), DataError> {
    let Some(first) = frames.first() else {
        return Err(DataError::invalid(format!(
            "{}: an animation needs at least one frame",
            path.display()
        )));
    };
    if frames
        .iter()
        .any(|f| (f.width, f.height) != (first.width, first.height))
    {
        return Err(DataError::invalid(format!(
            "{}: the frames differ in size",
            path.display()
        )));
    }
    let mut bytes = Vec::new();
    {
        // Speed 10 of 1–30: a palette per frame good enough for previews, ~10× faster than 1.
        let mut enc = GifEncoder::new_with_speed(&mut bytes, 10);
        let fail = |e: image::ImageError| DataError::io(path, e.to_string());
        enc.set_repeat(Repeat::Infinite).map_err(fail)?;
        let delay = Delay::from_numer_denom_ms(1000, fps.max(1));
        for f in frames {
            enc.encode_frame(Frame::from_parts(rgba(f)?, 0, 0, delay))
                .map_err(fail)?;
        }
    }
    write_bytes_atomic(path, &bytes)
}

/// Whether `ffmpeg` runs here.
pub fn ffmpeg_available() -> bool {
    Command::new("ffmpeg")
        .arg("-version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// Encodes the PNG frames `pattern` (an ffmpeg pattern such as `DIR/frame_%04d.png`) into the
/// H.264 MP4 `out` at `fps`, through a temporary file renamed into place. Ok(false) when ffmpeg is
/// not on the PATH.
pub fn write_mp4(pattern: &Path, out: &Path, fps: u32) -> Result<bool, DataError> {
    if !ffmpeg_available() {
        return Ok(false);
    }
    let partial = out.with_extension("partial.mp4");
    let result = Command::new("ffmpeg")
        .args(["-y", "-loglevel", "error", "-framerate", &fps.max(1).to_string(), "-i"])
        .arg(pattern)
        // yuv420p for players that cannot do 4:4:4; even sides, which yuv420p needs.
        .args([
            "-pix_fmt",
            "yuv420p",
            "-vf",
            "scale=trunc(iw/2)*2:trunc(ih/2)*2",
            "-c:v",
            "libx264",
        ])
        .arg(&partial)
        .output()
        .map_err(|e| DataError::io(out, format!("ffmpeg: {e}")))?;
    if !result.status.success() {
        let _ = std::fs::remove_file(&partial);
        return Err(DataError::io(
            out,
            format!("ffmpeg failed: {}", String::from_utf8_lossy(&result.stderr).trim()),
        ));
    }
    std::fs::rename(&partial, out).map_err(|e| DataError::io(out, e.to_string()))?;
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_gif_holds_every_frame_and_loops() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.gif");
        let frames: Vec<ImageF32> = (0..5)
            .map(|i| ImageF32::from_data(4, 3, 3, vec![i as f32 / 4.0; 36]))
            .collect();
        write_gif(&path, &frames, 12).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert!(bytes.starts_with(b"GIF89a"));
        // The NETSCAPE2.0 application extension is what makes it loop.
        assert!(bytes.windows(11).any(|w| w == b"NETSCAPE2.0"));
        use image::AnimationDecoder;
        let dec = image::codecs::gif::GifDecoder::new(std::io::Cursor::new(bytes)).unwrap();
        let decoded = dec.into_frames().collect_frames().unwrap();
        assert_eq!(decoded.len(), 5);
        let last = decoded[4].buffer().get_pixel(1, 1).0;
        assert!(last[0] >= 250, "{last:?}");
    }

    #[test]
    fn bad_frames_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("b.gif");
        assert!(write_gif(&path, &[], 10).is_err());
        let a = ImageF32::from_data(2, 2, 3, vec![0.0; 12]);
        let b = ImageF32::from_data(3, 2, 3, vec![0.0; 18]);
        assert!(write_gif(&path, &[a, b], 10).is_err());
        assert!(!path.exists());
    }
}
