//! What the targets share: small datasets on disk (written once per process) whose images the
//! fuzzed camera files point at, so a mutated `transforms.json` or `cameras_normalize.npz` is
//! read all the way through the loader, not refused for a missing image.
#![allow(dead_code)]

use i2sdf_data::fixture::{self, DepthFormat, FixtureOptions};
use std::path::Path;
use std::sync::OnceLock;

/// Tiny on purpose: the loader's image reads are in every execution.
pub fn options() -> FixtureOptions {
    FixtureOptions {
        width: 4,
        height: 3,
        train_views: 2,
        test_views: 1,
        depth: DepthFormat::Exr,
        anchor: None,
    }
}

fn dir(cell: &'static OnceLock<tempfile::TempDir>, write: fn(&Path)) -> &'static Path {
    cell.get_or_init(|| {
        let d = tempfile::tempdir().expect("temporary directory");
        write(d.path());
        d
    })
    .path()
}

/// A native dataset (its `transforms.json` is ignored: the target passes its own text).
pub fn native_dir() -> &'static Path {
    static D: OnceLock<tempfile::TempDir> = OnceLock::new();
    dir(&D, |p| {
        fixture::write_native(p, &options());
    })
}

/// A paper-format dataset (its `cameras_normalize.npz` is ignored: the target passes bytes).
pub fn paper_dir() -> &'static Path {
    static D: OnceLock<tempfile::TempDir> = OnceLock::new();
    dir(&D, |p| {
        fixture::write_paper(p, &options());
    })
}

/// An empty scratch folder for targets whose loader only takes a path.
pub fn scratch_dir() -> &'static Path {
    static D: OnceLock<tempfile::TempDir> = OnceLock::new();
    dir(&D, |_| {})
}

/// A folder with the files edit specs name in the seeds: `tex.png` and `tri.ply`.
pub fn edit_dir() -> &'static Path {
    static D: OnceLock<tempfile::TempDir> = OnceLock::new();
    dir(&D, |p| {
        let img = i2sdf_data::ImageF32::from_data(2, 2, 3, vec![0.5; 12]);
        i2sdf_data::imageio::write_png(&p.join("tex.png"), &img).expect("texture");
        let mesh = i2sdf_data::TriangleMesh::axis_box([0.0; 3], [1.0; 3]);
        i2sdf_data::ply::write_ply(p.join("tri.ply"), &mesh).expect("mesh");
    })
}
