//! The page and its files: HTML escaping, the inline style sheet, image grids, and the staging
//! directory the whole report is written into before it is moved into place (a failure leaves
//! the previous report, or nothing, never half a page).

use crate::images::turbo_css_gradient;
use i2sdf_data::{imageio, DataError, ImageF32};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Escapes text for HTML content and attribute values.
pub fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// The report's files, written under a staging directory and published together.
pub struct Assets {
    /// The final directory.
    pub out: PathBuf,
    /// Where files go until [`Assets::publish`].
    pub stage: PathBuf,
    /// Relative paths written so far.
    pub files: Vec<String>,
}

impl Assets {
    /// Creates `out` and a fresh staging directory `out/.partial` inside it (same file system:
    /// the final moves are renames).
    pub fn new(out: &Path) -> Result<Self, DataError> {
        std::fs::create_dir_all(out).map_err(|e| DataError::io(out, format!("cannot create directory: {e}")))?;
        let stage = out.join(".partial");
        if stage.exists() {
            std::fs::remove_dir_all(&stage).map_err(|e| DataError::io(&stage, format!("cannot clear: {e}")))?;
        }
        std::fs::create_dir_all(stage.join("img"))
            .map_err(|e| DataError::io(&stage, format!("cannot create directory: {e}")))?;
        Ok(Assets {
            out: out.to_path_buf(),
            stage,
            files: Vec::new(),
        })
    }

    /// Writes `img/NAME.png`; returns its relative path.
    pub fn png(&mut self, name: &str, img: &ImageF32) -> Result<String, DataError> {
        let rel = format!("img/{name}.png");
        imageio::write_png(&self.stage.join(&rel), img)?;
        self.files.push(rel.clone());
        Ok(rel)
    }

    /// Writes a text file (an SVG chart) at the report's top level; returns its relative path.
    pub fn text(&mut self, name: &str, text: &str) -> Result<String, DataError> {
        let path = self.stage.join(name);
        std::fs::write(&path, text).map_err(|e| DataError::io(&path, format!("cannot write: {e}")))?;
        self.files.push(name.to_string());
        Ok(name.to_string())
    }

    /// Writes `index.html` and moves everything into `out`: the images and charts first, the
    /// page last, so a page in `out` always finds its files. A previous report's `img/` is
    /// replaced whole.
    pub fn publish(self, html: &str) -> Result<PathBuf, DataError> {
        let page = self.stage.join("index.html");
        std::fs::write(&page, html).map_err(|e| DataError::io(&page, format!("cannot write: {e}")))?;
        let mv = |from: PathBuf, to: PathBuf| -> Result<(), DataError> {
            if to.is_dir() {
                std::fs::remove_dir_all(&to).map_err(|e| DataError::io(&to, format!("cannot replace: {e}")))?;
            }
            std::fs::rename(&from, &to).map_err(|e| DataError::io(&to, format!("cannot move into place: {e}")))
        };
        mv(self.stage.join("img"), self.out.join("img"))?;
        for f in self.files.iter().filter(|f| !f.starts_with("img/")) {
            mv(self.stage.join(f), self.out.join(f))?;
        }
        mv(page, self.out.join("index.html"))?;
        let _ = std::fs::remove_dir_all(&self.stage);
        Ok(self.out.join("index.html"))
    }
}

impl Drop for Assets {
    /// A report that failed half-way leaves no staging directory behind.
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.stage);
    }
}

/// One cell of an image grid: a caption and an image (None: a placeholder saying why not).
pub struct Cell {
    pub caption: String,
    pub src: Result<String, String>,
}

impl Cell {
    pub fn img(caption: impl Into<String>, src: String) -> Self {
        Cell {
            caption: caption.into(),
            src: Ok(src),
        }
    }
    pub fn missing(caption: impl Into<String>, why: impl Into<String>) -> Self {
        Cell {
            caption: caption.into(),
            src: Err(why.into()),
        }
    }
}

/// A labelled row of cells, with a note under it (the error map's range).
pub fn grid_row(label: &str, cells: &[Cell], note: &str) -> String {
    let mut s = String::new();
    let _ = write!(s, "<div class=\"row\"><div class=\"label\">{}</div>", esc(label));
    for c in cells {
        s.push_str("<figure>");
        match &c.src {
            Ok(src) => {
                let _ = write!(s, "<img src=\"{}\" alt=\"{}\">", esc(src), esc(&c.caption));
            }
            Err(why) => {
                let _ = write!(s, "<div class=\"none\">{}</div>", esc(why));
            }
        }
        let _ = write!(s, "<figcaption>{}</figcaption></figure>", esc(&c.caption));
    }
    s.push_str("</div>");
    if !note.is_empty() {
        let _ = write!(s, "<p class=\"note\">{note}</p>");
    }
    s
}

/// The colour bar of the heat-maps with its range: `0 – max unit`.
pub fn colour_bar(max: f32, unit: &str) -> String {
    format!(
        "<span class=\"bar\"></span> turbo, 0 – {} {}",
        esc(&format_sig(max as f64)),
        esc(unit)
    )
}

/// A number with about four significant digits, without exponents for ordinary magnitudes.
pub fn format_sig(x: f64) -> String {
    if !x.is_finite() {
        return "—".to_string();
    }
    let a = x.abs();
    if a == 0.0 {
        "0".to_string()
    } else if x.fract() == 0.0 && a < 1e6 {
        // Counts (emitters, frames) read as integers.
        format!("{}", x as i64)
    } else if !(1e-3..1e5).contains(&a) {
        format!("{x:.3e}")
    } else if a >= 100.0 {
        format!("{x:.1}")
    } else if a >= 10.0 {
        format!("{x:.2}")
    } else if a >= 1.0 {
        format!("{x:.3}")
    } else {
        format!("{x:.4}")
    }
}

/// The whole page around its sections' HTML.
pub fn page(title: &str, body: &str) -> String {
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n\
         <title>{}</title>\n<style>\n{}</style>\n</head>\n<body>\n{}\n</body>\n</html>\n",
        esc(title),
        STYLE.replace("TURBO", &turbo_css_gradient()),
        body
    )
}

/// The page's only style sheet (no external CSS, fonts or scripts: the report opens from disk).
const STYLE: &str = "body { font-family: system-ui, -apple-system, 'Segoe UI', sans-serif; margin: 0 auto; \
max-width: 1200px; padding: 0 20px 40px; color: #222; background: #fafafa; }
h1 { font-size: 1.6em; margin: 0.6em 0 0.2em; }
h2 { font-size: 1.25em; border-bottom: 2px solid #ddd; padding-bottom: 4px; margin-top: 1.6em; }
h3 { font-size: 1.05em; margin: 1em 0 0.3em; }
table { border-collapse: collapse; margin: 8px 0; font-size: 0.92em; }
th, td { border: 1px solid #ccc; padding: 3px 8px; text-align: left; }
th { background: #eee; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
.row { display: flex; flex-wrap: wrap; align-items: flex-start; gap: 8px; margin: 6px 0 0; }
.row .label { width: 110px; font-weight: 600; padding-top: 4px; }
figure { margin: 0; }
figure img { width: 320px; image-rendering: pixelated; border: 1px solid #bbb; display: block; background: #000; }
figcaption { font-size: 0.82em; color: #555; max-width: 320px; }
.none { width: 320px; height: 120px; border: 1px dashed #bbb; color: #888; display: flex; \
align-items: center; justify-content: center; font-size: 0.9em; text-align: center; }
.note { margin: 2px 0 10px 118px; font-size: 0.85em; color: #444; }
.bar { display: inline-block; width: 120px; height: 10px; vertical-align: middle; background: TURBO; \
border: 1px solid #999; }
.charts img { width: 560px; max-width: 100%; border: 1px solid #ddd; background: #fff; margin: 4px; }
.charts { display: flex; flex-wrap: wrap; }
img.wide { max-width: 100%; border: 1px solid #ddd; background: #fff; }
.muted { color: #777; }
.warn { background: #fff4d6; border: 1px solid #e0b84c; border-left: 5px solid #d99a00; padding: 6px 10px; \
margin: 8px 0; }
.warn ul { margin: 4px 0; padding-left: 20px; }
pre { background: #f0f0f0; padding: 8px; overflow-x: auto; font-size: 0.85em; }
";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_markup() {
        assert_eq!(esc("<a href=\"x\">&'"), "&lt;a href=&quot;x&quot;&gt;&amp;&#39;");
    }

    #[test]
    fn numbers_read_well() {
        assert_eq!(format_sig(30.3155), "30.32");
        assert_eq!(format_sig(0.011059), "0.0111");
        assert_eq!(format_sig(1384.5), "1384.5");
        assert_eq!(format_sig(1e-6), "1.000e-6");
        assert_eq!(format_sig(2.0), "2");
    }

    #[test]
    fn publish_moves_the_report_into_place_and_a_failure_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("r");
        let mut a = Assets::new(&out).unwrap();
        let src = a.png("x", &ImageF32::new(2, 2, 3)).unwrap();
        a.text("c.svg", "<svg/>").unwrap();
        a.publish(&format!("<img src=\"{src}\">")).unwrap();
        assert!(out.join("img/x.png").is_file() && out.join("c.svg").is_file());
        assert!(out.join("index.html").is_file() && !out.join(".partial").exists());
        let failed = Assets::new(&dir.path().join("q")).unwrap();
        drop(failed);
        assert!(!dir.path().join("q/.partial").exists());
    }
}
