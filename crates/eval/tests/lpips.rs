//! LPIPS against the `lpips` package (v0.1.4, AlexNet, v0.1 heads): `scripts/lpips_reference.py`
//! runs the package's own model in float64 with the linear heads it ships (the fixture
//! `fixtures/lpips_alex_v0.1_heads.safetensors`, 1152 values, BSD-2-Clause like the package) and a
//! backbone set from a deterministic formula, which this test rebuilds bit for bit, on image pairs
//! also made by formula (see the script's docstring for both). The expected values are its output.

use i2sdf_eval::image_metrics::ImageRef;
use i2sdf_eval::lpips::{head_name, Lpips, LpipsWeights, ALEXNET};
use std::path::{Path, PathBuf};

fn hash32(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846ca68b);
    x ^= x >> 16;
    x
}

/// In [−1, 1), exact in f32.
fn unit(stream: u32, i: u32) -> f64 {
    let h = hash32(i.wrapping_add(0x9E3779B9u32.wrapping_mul(stream)));
    (h >> 8) as f64 / (1u32 << 24) as f64 * 2.0 - 1.0
}

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/lpips_alex_v0.1_heads.safetensors")
}

/// The package's heads from the fixture and the formula's backbone.
fn weights() -> LpipsWeights {
    let bytes = std::fs::read(fixture()).unwrap();
    let file = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let mut w = LpipsWeights {
        conv_weights: Vec::new(),
        conv_biases: Vec::new(),
        heads: Vec::new(),
    };
    for (l, s) in ALEXNET.iter().enumerate() {
        let fan_in = s.in_channels * s.kernel * s.kernel;
        let scale = (6.0 / fan_in as f64).sqrt();
        let n = s.out_channels * fan_in;
        let l = l as u32;
        w.conv_weights
            .push((0..n as u32).map(|i| (unit(2 * l + 1, i) * scale) as f32).collect());
        w.conv_biases.push(
            (0..s.out_channels as u32)
                .map(|o| (0.1 * unit(2 * l + 2, o)) as f32)
                .collect(),
        );
        let t = file.tensor(&head_name(l as usize)).unwrap();
        assert_eq!(t.shape(), [1, s.out_channels, 1, 1]);
        w.heads.push(
            t.data()
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
        );
    }
    w
}

/// `(phase, freq, seed, noise)` of a test image.
type Pattern = (f64, f64, u32, f64);

fn image(w: usize, h: usize, (phase, freq, seed, noise): Pattern) -> Vec<f32> {
    let mut img = Vec::with_capacity(w * h * 3);
    for y in 0..h {
        for x in 0..w {
            for c in 0..3 {
                let mut v = 0.5
                    + 0.35
                        * (freq * (1.0 + 0.3 * c as f64) * x as f64 + 0.17 * y as f64 + phase + 0.5 * c as f64).sin();
                v += noise * unit(100 + seed, ((y * w + x) * 3 + c) as u32);
                img.push(v.clamp(0.0, 1.0) as f32);
            }
        }
    }
    img
}

/// The script's pairs, and the package's LPIPS of each (float64) with its 5 layer terms: the
/// output of `python3 scripts/lpips_reference.py` (lpips 0.1.4, torch 2.0.1).
const PAIRS: [(usize, usize, Pattern, Pattern, f64, [f64; 5]); 4] = [
    (
        64,
        48,
        (0.0, 0.21, 1, 0.10),
        (0.6, 0.21, 2, 0.10),
        0.0324233247,
        [0.0160912887, 0.0080311171, 0.0031092372, 0.0030676739, 0.0021240079],
    ),
    (
        64,
        48,
        (1.0, 0.13, 3, 0.05),
        (1.0, 0.13, 4, 0.05),
        0.0038096965,
        [0.0009395553, 0.0011136426, 0.0006912634, 0.0005442645, 0.0005209706],
    ),
    (
        70,
        50,
        (0.3, 0.31, 5, 0.10),
        (0.3, 0.11, 6, 0.10),
        0.1570896706,
        [0.0623042696, 0.0461998782, 0.0195703845, 0.0173153287, 0.0116998096],
    ),
    (
        131,
        97,
        (2.0, 0.07, 7, 0.02),
        (2.2, 0.08, 8, 0.20),
        0.0787935895,
        [0.0298518094, 0.0323118736, 0.0059891218, 0.0057212522, 0.0049195325],
    ),
];

fn model() -> (tempfile::TempDir, PathBuf, Lpips) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lpips.safetensors");
    weights().write(&path).unwrap();
    let lpips = Lpips::load(&path).unwrap();
    (dir, path, lpips)
}

#[test]
fn lpips_matches_the_lpips_package() {
    let (_dir, _, lpips) = model();
    let (mut worst, mut worst_rel) = (0.0f64, 0.0f64);
    for (w, h, pa, pb, want, want_layers) in PAIRS {
        let (a, b) = (image(w, h, pa), image(w, h, pb));
        let (ra, rb) = (ImageRef::new(&a, w, h, 3).unwrap(), ImageRef::new(&b, w, h, 3).unwrap());
        let got = lpips.distance(ra, rb).unwrap();
        let layers = lpips.layer_distances(ra, rb).unwrap();
        let err = (got - want).abs();
        println!("{w}x{h}: {got:.10} (package {want:.10}, |Δ| {err:.2e}) layers {layers:.10?}");
        // The brief's bound, and a relative one: the figures agree to the printed digits.
        assert!(err < 1e-4, "{w}x{h}: {got} vs the package's {want}");
        assert!(err < 1e-5 * want, "{w}x{h}: {got} vs the package's {want}");
        for (l, (g, e)) in layers.iter().zip(want_layers).enumerate() {
            assert!((g - e).abs() < 1e-5 * e + 1e-9, "{w}x{h} layer {l}: {g} vs {e}");
        }
        worst = worst.max(err);
        worst_rel = worst_rel.max(err / want);
        assert!((lpips.distance(rb, ra).unwrap() - got).abs() < 1e-9, "symmetric");
        assert_eq!(lpips.distance(ra, ra).unwrap(), 0.0, "identical images");
    }
    println!("largest difference {worst:.2e} (relative {worst_rel:.2e})");
}

/// Writes `w` less the tensor `drop` (if any) to `dir/name`.
fn write_without(dir: &Path, name: &str, w: &LpipsWeights, drop: &str) -> PathBuf {
    let tensors = w.tensors();
    let bytes: Vec<(String, Vec<usize>, Vec<u8>)> = tensors
        .iter()
        .filter(|(n, _, _)| n != drop)
        .map(|(n, s, v)| (n.clone(), s.clone(), v.iter().flat_map(|x| x.to_le_bytes()).collect()))
        .collect();
    let views: Vec<(String, safetensors::tensor::TensorView)> = bytes
        .iter()
        .map(|(n, s, b)| {
            let view = safetensors::tensor::TensorView::new(safetensors::Dtype::F32, s.clone(), b).unwrap();
            (n.clone(), view)
        })
        .collect();
    let path = dir.join(name);
    std::fs::write(&path, safetensors::serialize(views, None).unwrap()).unwrap();
    path
}

fn load_error(path: &Path) -> i2sdf_data::DataError {
    match Lpips::load(path) {
        Ok(_) => panic!("{} loaded", path.display()),
        Err(e) => e,
    }
}

#[test]
fn bad_weight_files_name_the_file_and_the_tensor() {
    let dir = tempfile::tempdir().unwrap();
    let w = weights();
    let expect = |e: i2sdf_data::DataError, words: &[&str]| {
        let msg = e.to_string();
        assert!(e.is_bad_input(), "{msg}");
        for word in words {
            assert!(msg.contains(word), "{msg} lacks {word}");
        }
    };
    let gone = dir.path().join("gone.safetensors");
    expect(
        load_error(&gone),
        &["gone.safetensors", "cannot read the LPIPS weights"],
    );
    let text = dir.path().join("text.safetensors");
    std::fs::write(&text, "not tensors").unwrap();
    expect(load_error(&text), &["text.safetensors", "not a safetensors file"]);
    // The fixture holds only the heads.
    expect(
        load_error(&fixture()),
        &["net.slice1.0.weight", "missing", "lpips_weights.py"],
    );
    let no_head = write_without(dir.path(), "no_head.safetensors", &w, "lin3.model.1.weight");
    expect(
        load_error(&no_head),
        &["no_head.safetensors", "lin3.model.1.weight", "missing"],
    );
    // A first layer stored [in][out][k][k]: the shape is named with the expected one.
    let full = dir.path().join("full.safetensors");
    w.write(&full).unwrap();
    let bytes = std::fs::read(&full).unwrap();
    let file = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let mut views: Vec<(String, safetensors::tensor::TensorView)> = file
        .tensors()
        .into_iter()
        .filter(|(n, _)| n != "net.slice1.0.weight")
        .collect();
    let zeros = vec![0u8; 3 * 64 * 11 * 11 * 4];
    let wrong = safetensors::tensor::TensorView::new(safetensors::Dtype::F32, vec![3, 64, 11, 11], &zeros).unwrap();
    views.push(("net.slice1.0.weight".into(), wrong));
    let shape = dir.path().join("shape.safetensors");
    std::fs::write(&shape, safetensors::serialize(views, None).unwrap()).unwrap();
    expect(
        load_error(&shape),
        &[
            "shape.safetensors",
            "net.slice1.0.weight",
            "[3, 64, 11, 11]",
            "[64, 3, 11, 11]",
        ],
    );
    let mut negative = w.clone();
    negative.heads[2][5] = -0.5;
    let path = dir.path().join("negative.safetensors");
    negative.write(&path).unwrap();
    expect(load_error(&path), &["lin2.model.1.weight", "non-negative"]);
    let mut nan = w;
    nan.conv_biases[4][0] = f32::NAN;
    nan.write(&path).unwrap();
    expect(load_error(&path), &["net.slice5.10.bias", "NaN"]);
}

#[test]
fn images_too_small_or_of_different_sizes_are_refused() {
    let (_dir, _, lpips) = model();
    let small = image(30, 40, (0.0, 0.1, 1, 0.0));
    let r = ImageRef::new(&small, 30, 40, 3).unwrap();
    let e = lpips.distance(r, r).unwrap_err();
    assert!(e.is_bad_input() && e.to_string().contains("at least 31×31"), "{e}");
    let (a, b) = (image(32, 32, (0.0, 0.1, 1, 0.0)), image(33, 32, (0.0, 0.1, 1, 0.0)));
    let e = lpips
        .distance(
            ImageRef::new(&a, 32, 32, 3).unwrap(),
            ImageRef::new(&b, 33, 32, 3).unwrap(),
        )
        .unwrap_err();
    assert!(e.to_string().contains("32×32×3, ground truth 33×32×3"), "{e}");
    // The smallest image accepted.
    let c = image(31, 31, (0.0, 0.1, 1, 0.0));
    let d = image(31, 31, (1.0, 0.1, 2, 0.1));
    let r = |v| ImageRef::new(v, 31, 31, 3).unwrap();
    assert!(lpips.distance(r(&c), r(&d)).unwrap() > 0.0);
}

/// Timing (not a check): `cargo test -p i2sdf-eval --release --test lpips -- --ignored --nocapture`.
#[test]
#[ignore]
fn lpips_timing() {
    let (_dir, _, lpips) = model();
    for (w, h) in [(160, 120), (640, 480)] {
        let (a, b) = (image(w, h, (0.0, 0.05, 1, 0.05)), image(w, h, (0.5, 0.05, 2, 0.05)));
        let (ra, rb) = (ImageRef::new(&a, w, h, 3).unwrap(), ImageRef::new(&b, w, h, 3).unwrap());
        lpips.distance(ra, rb).unwrap();
        // The fastest of a few runs: the least disturbed by other work on the cores.
        let per = (0..5)
            .map(|_| {
                let t = std::time::Instant::now();
                std::hint::black_box(lpips.distance(ra, rb).unwrap());
                t.elapsed().as_secs_f64()
            })
            .fold(f64::INFINITY, f64::min);
        println!(
            "LPIPS {w}x{h} pair: {:.1} ms ({} threads)",
            per * 1e3,
            rayon::current_num_threads()
        );
    }
}
