//! Inputs the fuzz targets (`fuzz/`, docs/ARCHITECTURE.md, "Fuzzing") found or that stand for a class of
//! hostile files, kept so the normal test suite guards them: each must be refused with an error
//! that names the file — no panic, no abort, and no allocation sized by a header's claim (a
//! header claiming 10⁹ × 10⁹ pixels or 10¹² vertices is refused before anything is reserved, so
//! these tests also run in milliseconds and a few MB).

use i2sdf_data::fixture::{self, DepthFormat, FixtureOptions};
use i2sdf_data::{imageio, paper, ply, DataError};
use std::path::Path;

macro_rules! case {
    ($name:literal) => {
        ($name, &include_bytes!(concat!("fuzz_cases/", $name))[..])
    };
}

fn refused(name: &str, result: Result<impl std::fmt::Debug, DataError>, expected: &str) {
    match result {
        Ok(v) => panic!("{name}: accepted: {v:?}"),
        Err(e) => {
            let msg = e.to_string();
            assert!(e.is_bad_input(), "{name}: not a bad-input error: {msg}");
            assert!(msg.contains(name), "{name}: the message does not name the file: {msg}");
            assert!(msg.contains(expected), "{name}: expected {expected:?} in: {msg}");
        }
    }
}

#[test]
fn image_headers_claiming_huge_sizes_are_refused() {
    for (name, bytes, expected) in [
        // Wider than the 65536 pixels the PNG decoder is allowed: its own limit answers.
        (case!("png_1e9_by_1e9.png"), "exceeds limit"),
        (case!("png_60000_gray16.png"), "larger than"),
        (case!("exr_1e9_by_1e9.exr"), "larger than"),
    ]
    .map(|((n, b), e)| (n, b, e))
    {
        refused(name, imageio::read_image_bytes(Path::new(name), bytes), expected);
        refused(name, imageio::read_float_map_bytes(Path::new(name), bytes), expected);
        if name.ends_with(".png") {
            refused(name, imageio::read_png_raw_gray_bytes(Path::new(name), bytes), expected);
        }
    }
}

#[test]
fn npy_headers_claiming_huge_shapes_are_refused() {
    for (name, bytes) in [
        case!("npy_huge_shape.npy"),
        case!("npy_overflowing_shape.npy"),
        case!("npy_huge_f8.npy"),
    ] {
        let path = Path::new(name);
        refused(name, imageio::read_float_map_bytes(path, bytes), "");
        let npy = npyz::NpyFile::new(bytes).expect("a well-formed header");
        refused(name, imageio::read_npy_f64(path, npy), "holds more than");
    }
}

#[test]
fn ply_counts_the_body_cannot_hold_are_refused() {
    for (name, bytes) in [case!("ply_1e12_vertices.ply"), case!("ply_1e12_faces_ascii.ply")] {
        refused(name, ply::parse_ply(Path::new(name), bytes), "truncated");
    }
}

/// An element with no properties holds no data, whatever its count: skipped at once (it used
/// to loop 10¹⁸ times).
#[test]
fn ply_elements_without_properties_cost_nothing() {
    let (name, bytes) = case!("ply_empty_element_1e18.ply");
    let mesh = ply::parse_ply(Path::new(name), bytes).expect("a valid mesh");
    assert_eq!(mesh.positions, vec![[0.0; 3]]);
}

/// Camera archives whose matrices claim a huge shape, or hold fewer values than their shape,
/// are refused by the paper loader (over a real dataset, so only the archive is at fault).
#[test]
fn paper_camera_archives_with_bad_matrices_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let opts = FixtureOptions {
        width: 4,
        height: 3,
        train_views: 1,
        test_views: 1,
        depth: DepthFormat::Exr,
        anchor: None,
    };
    fixture::write_paper(dir.path(), &opts);
    for (name, bytes, expected) in [
        (case!("npz_huge_matrix.npz"), "world_mat_0"),
        (case!("npz_short_matrix.npz"), "world_mat_0"),
        (case!("npz_oom_header_length.npz"), "the header claims"),
    ]
    .map(|((n, b), e)| (n, b, e))
    {
        let npz = dir.path().join(name);
        refused(name, paper::load_with_npz_bytes(dir.path(), &npz, bytes), expected);
    }
}

/// Found by the `npy` target (out-of-memory): a version-3 header whose length field claims
/// 2.4 GB, which npyz allocated before reading. Now checked against the file's bytes, in a
/// `.npy` file and in an npz member alike.
#[test]
fn npy_header_length_past_the_end_is_refused() {
    let (name, bytes) = case!("npy_oom_header_length.npy");
    let path = Path::new(name);
    refused(name, imageio::read_float_map_bytes(path, bytes), "the header claims");
    refused(name, imageio::npy_file(path, bytes).map(|_| ()), "the header claims");
}

/// Found by the `npy` target (timeout): 41 nested braces in the header text, on which npyz's
/// header grammar backtracks for minutes. Refused by depth before it is parsed.
#[test]
fn npy_header_nesting_too_deep_is_refused() {
    let (name, bytes) = case!("npy_timeout_nested_header.npy");
    refused(
        name,
        imageio::read_float_map_bytes(Path::new(name), bytes),
        "nests brackets",
    );
}
