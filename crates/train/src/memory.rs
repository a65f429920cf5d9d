//! What training will hold in memory, estimated before it starts (`i2sdf check` prints it and
//! warns when it exceeds the machine's memory). Each stage's estimate is a sum of named items
//! computed from the dataset's shape and the configuration, following what the trainers
//! allocate:
//! - both stages hold the whole dataset (every map of every frame, f32);
//! - stage 1 ([`crate::stage1`]): per training pixel its ray, colour, depth, normal and emitter
//!   mask ([`crate::stage1::rays::TrainImage`], 48 bytes) and the PDF maps (value, validity, ~6 bytes);
//!   the fields' parameters four times (values, gradients, Adam's two moments); per point of a
//!   batch (ray samples + eikonal + bubble + smoothness points) the SDF's saved activations
//!   (encoding, its Jacobian and the double-backward buffers) and per ray sample F_c's and F_e's;
//! - stage 2 ([`crate::stage2`]): the frozen stage-1 fields; the material field's parameters four
//!   times; per cached pixel its cast (ray, hit) and [`crate::stage2::CachedPixel`]; the
//!   incident-radiance cache (`cache_pixels × cache_samples` samples of 32 bytes, or with
//!   `specular_bake` each pixel's specular sums at the bake's roughness levels) with the rays and
//!   hits of one traced block; the pooled diffuse sums; the baked surface (marching-cubes
//!   mesh and its BVH); the batch's material activations.
//!
//! Checked against the peak RSS of 50-iteration runs on the default room (`/usr/bin/time -v`):
//! stage 1 estimated 0.89 GB, measured 0.92 GB (0.41 GB with `adaptive.enabled = false`: the
//! PDF-map pass is the peak); stage 2 estimated 0.79 GB, measured 0.78 GB. A constant for the
//! process itself (code, thread stacks, allocator slack) is part of each stage.

use crate::config::TrainConfig;
use i2sdf_model::marching_cubes::MESH_VERTICES_PER_FACE_CELL;
use i2sdf_model::material_field::MaterialBackbone;
pub use i2sdf_model::memory::{gib, MachineMemory};
use i2sdf_nn::sdf::SdfEncodingConfig;
use serde::Serialize;

/// Bytes of the process before any data: code, rayon's thread stacks, allocator slack (the
/// measured RSS of `i2sdf check` on the default room, 93 MB, less its 75 MB dataset).
const PROCESS_BYTES: f64 = 20e6;

/// The shape of a dataset as the estimate needs it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct DatasetShape {
    /// Bytes of every map of every frame (relit sets included), as loaded.
    pub bytes: f64,
    /// Pixels of the training views.
    pub train_pixels: usize,
    pub train_views: usize,
    /// Side lengths of the scene's bounds (any unit: only their ratios matter).
    pub extent: [f64; 3],
    /// Bytes of the training views' low-confidence footprints, which stage 1 keeps a copy of for
    /// the photometric depth.
    pub train_low_bytes: f64,
}

impl DatasetShape {
    pub fn of(dataset: &i2sdf_data::Dataset) -> DatasetShape {
        let low_bytes = |f: &i2sdf_data::Frame| f.depth_low.as_ref().map_or(0.0, |m| m.data.len() as f64 * 4.0);
        let frame_bytes = |f: &i2sdf_data::Frame| {
            f.maps()
                .into_iter()
                .flatten()
                .map(|m| m.data.len() as f64 * 4.0)
                .sum::<f64>()
                + low_bytes(f)
        };
        let relit = dataset.relight.iter().flat_map(|s| s.frames.iter());
        let train: Vec<_> = dataset.split(i2sdf_data::Split::Train).collect();
        DatasetShape {
            bytes: dataset.frames.iter().chain(relit).map(frame_bytes).sum(),
            train_pixels: train.iter().map(|f| f.pixel_count()).sum(),
            train_views: train.len(),
            extent: std::array::from_fn(|k| dataset.bounds.max[k] - dataset.bounds.min[k]),
            train_low_bytes: train.iter().map(|f| low_bytes(f)).sum(),
        }
    }
}

/// One stage's estimate: named items in bytes and their sum.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct StageMemory {
    pub items: Vec<(String, f64)>,
    pub total: f64,
}

impl StageMemory {
    fn add(&mut self, what: &str, bytes: f64) {
        self.items.push((what.to_string(), bytes));
        self.total += bytes;
    }

    /// `total GiB (item GiB, …)` with the items over 1 % of the total.
    pub fn describe(&self) -> String {
        let parts: Vec<String> = self
            .items
            .iter()
            .filter(|(_, b)| *b > 0.01 * self.total)
            .map(|(w, b)| format!("{w} {:.2}", b / GIB))
            .collect();
        format!("{} ({} GiB)", gib(self.total), parts.join(", "))
    }
}

const GIB: f64 = (1u64 << 30) as f64;

#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct TrainingMemory {
    pub stage1: StageMemory,
    pub stage2: StageMemory,
}

impl TrainingMemory {
    /// The larger stage: what the machine must hold.
    pub fn peak(&self) -> f64 {
        self.stage1.total.max(self.stage2.total)
    }

    /// Why training `stages` ("stage 1", "stage 2" or both) would not fit in `available` bytes,
    /// or `None` when it fits: the estimate, its largest items with the keys that size them, and
    /// the keys `config` sets away from the defaults (the likely culprits). `check` warns with
    /// it; `train` refuses with it unless forced.
    pub fn over(&self, config: &TrainConfig, stage1: bool, stage2: bool, available: u64) -> Option<String> {
        let stages: Vec<(&str, &StageMemory)> = [("stage 1", &self.stage1, stage1), ("stage 2", &self.stage2, stage2)]
            .into_iter()
            .filter(|(_, m, on)| *on && m.total > available as f64)
            .map(|(name, m, _)| (name, m))
            .collect();
        let (name, worst) = *stages.iter().max_by(|a, b| a.1.total.total_cmp(&b.1.total))?;
        let mut items: Vec<&(String, f64)> = worst.items.iter().collect();
        items.sort_by(|a, b| b.1.total_cmp(&a.1));
        let largest: Vec<String> = items
            .iter()
            .take(2)
            .map(|(w, b)| match item_keys(w) {
                Some(keys) => format!("{w} {} ({keys})", gib(*b)),
                None => format!("{w} {}", gib(*b)),
            })
            .collect();
        let changed = crate::resume::config_changes(&TrainConfig::default(), config, true);
        let changed = if changed.is_empty() {
            String::new()
        } else {
            format!("; set away from the defaults: {}", changed.join(", "))
        };
        Some(format!(
            "{name} needs about {} of memory, more than the {} available: largest {}{changed}",
            gib(worst.total),
            gib(available as f64),
            largest.join(", ")
        ))
    }
}

/// The configuration keys that size an estimate's item.
fn item_keys(item: &str) -> Option<&'static str> {
    Some(match item {
        "batch activations" => "train.rays × sampling.samples, train.eikonal_points, train.bubble_points",
        "PDF-map pass" => "sampling.samples, adaptive.enabled",
        "fields + Adam" | "frozen stage-1 fields" => "model.hash_levels, model.hash_log2_table",
        "material field + Adam" => "material.hash_levels, material.hash_log2_table",
        "cached pixels" | "pooled irradiance" => "stage2.cache_pixels",
        "specular bake" | "incident-radiance cache" | "tracing block" => "stage2.cache_pixels × stage2.cache_samples",
        "baked surface" => "stage2.bake_resolution",
        "batch" => "stage2.pixels × stage2.samples, material.hidden_dim × material.hidden_layers",
        "dataset" | "training rays" | "targets" => "the dataset's views and resolution",
        _ => return None,
    })
}

/// Entries of a multiresolution hash grid (as `i2sdf_nn::HashGrid::new` lays it out: a level is
/// dense while its (N_l + 1)³ vertices fit the table, each level padded to 64 entries).
pub fn hash_grid_entries(levels: usize, log2_table: u32, base: u32, finest: u32) -> f64 {
    let table = 2f64.powi(log2_table as i32);
    let growth = if levels > 1 {
        ((finest as f64).ln() - (base as f64).ln()) / (levels - 1) as f64
    } else {
        0.0
    };
    (0..levels)
        .map(|l| {
            let res = (base as f64 * (growth * l as f64).exp() + 1e-6).floor();
            let size = (res + 1.0).powi(3).min(table);
            (size / 64.0).ceil() * 64.0
        })
        .sum()
}

/// Cells on the faces of a marching-cubes grid with `resolution` samples along the longest side
/// of a box of `extent` (a cube when the extent is unknown or degenerate).
fn face_cells(extent: [f64; 3], resolution: usize) -> f64 {
    let longest = extent.iter().cloned().fold(0.0, f64::max);
    let r = resolution as f64;
    let n = if longest.is_finite() && longest > 0.0 {
        extent.map(|e| (r * e / longest).max(2.0))
    } else {
        [r; 3]
    };
    2.0 * (n[0] * n[1] + n[1] * n[2] + n[0] * n[2])
}

/// Weights of an MLP `inputs → hidden × layers → outputs` (with biases).
fn mlp_params(inputs: usize, hidden: usize, layers: usize, outputs: usize) -> f64 {
    let (i, h, o) = (inputs as f64, hidden as f64, outputs as f64);
    (i + 1.0) * h + (layers.saturating_sub(1) as f64) * (h + 1.0) * h + (h + 1.0) * o
}

/// Stage 1's and stage 2's estimates for `config` on a dataset of `shape`.
pub fn estimate(shape: &DatasetShape, config: &TrainConfig) -> TrainingMemory {
    TrainingMemory {
        stage1: stage1(shape, config),
        stage2: stage2(shape, config),
    }
}

/// The stage-1 networks as the model builds them (the MLP backbone fixes its own widths: the
/// `model.sdf_hidden`-style keys are the hash grid's).
struct Stage1Shapes {
    /// Parameters of every field (tables and MLPs).
    params: f64,
    /// Width of the SDF's input encoding.
    enc: usize,
    /// Floats per hidden layer × layers, of F_d, F_c and F_e.
    sdf_units: usize,
    color_units: usize,
    emitter_units: usize,
    /// Inputs of F_c and of F_e.
    radiance_in: usize,
    emitter_in: usize,
}

fn stage1_shapes(config: &TrainConfig) -> Stage1Shapes {
    let m = &config.model;
    let sdf = m.sdf_network();
    let (grid, enc) = match &sdf.encoding {
        SdfEncodingConfig::HashGrid(g) => (
            hash_grid_entries(g.levels, g.log2_table_size, g.base_resolution, g.finest_resolution)
                * g.features_per_level as f64,
            g.levels * g.features_per_level,
        ),
        // Positional encoding: xyz and a sine and cosine per axis and band; no table.
        SdfEncodingConfig::Frequency { frequencies } => (0.0, 3 + 6 * frequencies),
    };
    let (color, emitter) = (m.radiance_mlp(), m.emitter_mlp());
    let mlps = mlp_params(3 + enc, sdf.hidden_dim, sdf.hidden_layers, 1 + sdf.feature_dim)
        + mlp_params(color.input_dim, color.hidden_dim, color.hidden_layers, color.output_dim)
        + mlp_params(
            emitter.input_dim,
            emitter.hidden_dim,
            emitter.hidden_layers,
            emitter.output_dim,
        );
    Stage1Shapes {
        params: grid + mlps,
        enc,
        sdf_units: sdf.hidden_dim * sdf.hidden_layers,
        color_units: color.hidden_dim * color.hidden_layers,
        emitter_units: emitter.hidden_dim * emitter.hidden_layers,
        radiance_in: color.input_dim,
        emitter_in: emitter.input_dim,
    }
}

fn stage1(shape: &DatasetShape, config: &TrainConfig) -> StageMemory {
    let mut s = StageMemory::default();
    let t = &config.train;
    s.add("process", PROCESS_BYTES);
    s.add("dataset", shape.bytes);
    s.add("training rays", shape.train_pixels as f64 * (48.0 + 6.0));
    if shape.train_low_bytes > 0.0 {
        s.add("low-confidence footprints", shape.train_low_bytes);
    }
    let f = stage1_shapes(config);
    let enc = f.enc;
    s.add("fields + Adam", f.params * 4.0 * 4.0);
    // Points of one step: the ray samples, the eikonal and bubble points, the smoothness pairs
    // (two points per depth pixel of the batch, at most one per ray).
    let samples = (t.rays * config.sampling.samples) as f64;
    let points = samples + (t.eikonal_points + t.bubble_points) as f64 + 2.0 * t.rays as f64;
    // SdfWorkspace per point: x, the encoding, its xyz Jacobian, the double-backward buffers
    // (3 + 8 × encoding floats) and forward + backward activations with their xyz derivatives.
    let sdf_point = 3.0 + 6.0 * enc as f64 + 4.0 * f.sdf_units as f64;
    // Per ray sample: F_c's and F_e's inputs, activations and their gradients; σ, weights, dirs.
    let radiance_in = f.radiance_in as f64;
    let per_sample = 2.0 * (radiance_in + 2.0 * f.color_units as f64)
        + 2.0 * (f.emitter_in as f64 + 2.0 * f.emitter_units as f64)
        + 16.0;
    // The coarse pass and the error-bounded upsampling keep every candidate t and its SDF.
    let sampler = (t.rays * (config.sampling.coarse + config.sampling.samples) * 4) as f64;
    s.add(
        "batch activations",
        4.0 * (points * sdf_point + samples * per_sample + sampler),
    );
    if config.adaptive.enabled {
        // The PDF maps' initial depth errors are rendered in chunks (4096 rays at the defaults)
        // with a workspace of their own (forward only, with the SDF's Jacobian), beside the
        // training one: on the default room this is the peak (measured 0.52 GB of 0.92).
        let chunk = crate::stage1::pdf_init_chunk_rays(config);
        let rays = chunk.min(shape.train_pixels / shape.train_views.max(1)).max(1);
        let forward = 3.0
            + 6.0 * enc as f64
            + 2.0 * f.sdf_units as f64
            + radiance_in
            + 2.0 * f.color_units as f64
            + f.emitter_in as f64
            + 2.0 * f.emitter_units as f64
            + 16.0;
        s.add("PDF-map pass", 4.0 * (rays * config.sampling.samples) as f64 * forward);
    }
    s
}

fn stage2(shape: &DatasetShape, config: &TrainConfig) -> StageMemory {
    let mut s = StageMemory::default();
    let (c2, mat) = (&config.stage2, &config.material);
    s.add("process", PROCESS_BYTES);
    s.add("dataset", shape.bytes);
    // The target views: colour, saturation and emitter flags, the dataset's normals.
    s.add("targets", shape.train_pixels as f64 * (12.0 + 2.0 + 12.0));
    let stage1_params = stage1_shapes(config).params;
    s.add("frozen stage-1 fields", stage1_params * 4.0);
    let (grid, enc) = match mat.backbone {
        MaterialBackbone::HashGrid => (
            hash_grid_entries(
                mat.hash_levels,
                mat.hash_log2_table,
                mat.hash_base_resolution,
                mat.hash_finest_resolution,
            ) * 2.0,
            mat.hash_levels * 2,
        ),
        MaterialBackbone::FeatureMlp => (0.0, config.model.feature_size()),
    };
    let material = grid + mlp_params(3 + enc, mat.hidden_dim, mat.hidden_layers, 7);
    s.add("material field + Adam", material * 4.0 * 4.0);
    let pixels = if c2.cache_pixels == 0 {
        shape.train_pixels
    } else {
        c2.cache_pixels.min(shape.train_pixels)
    } as f64;
    // The first cast (pixel order 8, ray 32, hit 36 bytes) and the cached pixels (72 bytes).
    s.add("cached pixels", pixels * (8.0 + 32.0 + 36.0 + 72.0));
    let m = c2.cache_samples as f64;
    if c2.specular_bake {
        // Each pixel's specular sums at the bake's levels (emitters as for the pooled sums).
        let per = crate::stage2::surface_cache::SpecularBake::bytes_per_pixel(c2.max_emitters.min(8)) as f64;
        s.add("specular bake", pixels * per);
    } else {
        s.add("incident-radiance cache", pixels * m * 32.0);
    }
    // One traced block of 8192 pixels: its rays, hits and samples.
    s.add("tracing block", 8192.0 * m * (32.0 + 36.0 + 32.0));
    if c2.irradiance_radius > 0.0 {
        // Two sets of sums (own and pooled: radiance + one float per emitter) and the grid.
        let per = 12.0 + 24.0 + 4.0 * c2.max_emitters.min(8) as f64;
        s.add("pooled irradiance", pixels * (2.0 * per + 16.0));
    }
    if c2.bake_resolution > 0 {
        // The baked mesh over a box about the scene's: its vertices (position, normal, label)
        // and ~2 triangles each in the mesh and in the BVH (node, reference, triangle copy).
        let vertices = MESH_VERTICES_PER_FACE_CELL * face_cells(shape.extent, c2.bake_resolution);
        s.add("baked surface", vertices * (28.0 + 2.0 * (12.0 + 32.0 + 4.0 + 36.0)));
    }
    // One step's batch: the material field's activations and the samples' BRDF terms.
    let per_pixel = 4.0 * (enc as f64 * 4.0 + 4.0 * (mat.hidden_dim * mat.hidden_layers) as f64)
        + if c2.specular_bake { 0.0 } else { m * 48.0 };
    let mut batch = c2.pixels as f64 * per_pixel;
    if c2.estimator == crate::config::Stage2Estimator::Live {
        batch += c2.pixels as f64 * c2.samples as f64 * (32.0 + 36.0 + 32.0);
    }
    s.add("batch", batch);
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn room() -> DatasetShape {
        // The default synthetic room: 48 views of 160×120, 40 for training, every map.
        DatasetShape {
            bytes: 48.0 * 19200.0 * 4.0 * 18.0,
            train_pixels: 40 * 19200,
            train_views: 40,
            extent: [5.0, 3.7, 2.0],
            train_low_bytes: 0.0,
        }
    }

    #[test]
    fn grid_entries_follow_the_hash_grid_layout() {
        // One level of 16³ cells: 17³ = 4913 vertices, dense, padded to 4928.
        assert_eq!(hash_grid_entries(1, 17, 16, 16), 4928.0);
        // A level past the table is the table.
        assert_eq!(hash_grid_entries(1, 12, 64, 64), 4096.0);
        let grid = i2sdf_nn::HashGrid::new(
            i2sdf_nn::hashgrid::HashGridConfig {
                levels: 6,
                features_per_level: 2,
                log2_table_size: 12,
                base_resolution: 4,
                finest_resolution: 64,
                bound: 1.0,
            },
            0,
        );
        assert_eq!(hash_grid_entries(6, 12, 4, 64) * 2.0, grid.params.len() as f64);
    }

    #[test]
    fn estimates_grow_with_what_they_hold() {
        let c = TrainConfig::default();
        let base = estimate(&room(), &c);
        // The default room measured 0.92 GB (stage 1) and 0.77 GB (stage 2) peak RSS.
        for (stage, measured) in [(&base.stage1, 0.92e9), (&base.stage2, 0.77e9)] {
            assert!(
                stage.total > 0.6 * measured && stage.total < 1.6 * measured,
                "{}",
                stage.describe()
            );
        }
        let mut big = c.clone();
        big.model.hash_log2_table = 24;
        big.model.hash_levels = 32;
        let e = estimate(&room(), &big);
        // Up to 32 levels × 2^24 entries × 2 features × 16 bytes (the coarse levels are dense
        // and smaller): 8.5 GB.
        assert!(e.stage1.total > 8e9, "{}", e.stage1.describe());
        // Kept samples grow with their count; the baked default holds a fixed size per pixel.
        let mut cache = c.clone();
        cache.stage2.specular_bake = false;
        cache.stage2.cache_samples = 256;
        assert!(estimate(&room(), &cache).stage2.total > base.stage2.total + 0.7e9);
        assert!(base.peak() >= base.stage1.total && base.peak() >= base.stage2.total);
        assert!(base.stage1.describe().contains("dataset"));
    }
}
