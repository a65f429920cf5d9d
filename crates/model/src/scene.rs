//! The neural scene of stage 1: F_d, F_c, F_e and β, in the normalized frame (unit sphere).

use crate::config::{Backbone, ModelConfig};
use i2sdf_data::{DataError, Normalization};
use i2sdf_nn::params::{load_modules, ModuleSlot};
use i2sdf_nn::{
    save_safetensors, FrequencyEncoding, HashGrid, HashGridGrad, Mlp, ParamError, Parameters, SdfEncoding, SdfGrad,
    SdfNetwork, SphericalHarmonics,
};
use std::collections::HashMap;
use std::path::Path;

/// The learnable β of the VolSDF density (paper eq:density), kept as β = β_min + exp(raw): positive
/// whatever the optimizer does, and learned in log space so that a short CPU schedule can move it
/// over orders of magnitude (0.1 → 0.001) at a constant relative rate.
#[derive(Clone, Debug, PartialEq)]
pub struct Beta {
    pub raw: [f32; 1],
    pub min: f32,
}

impl Beta {
    pub fn new(init: f32, min: f32) -> Self {
        Beta {
            raw: [(init - min).ln()],
            min,
        }
    }
    pub fn value(&self) -> f32 {
        self.min + self.raw[0].exp()
    }
    /// dβ/d raw.
    pub fn dvalue(&self) -> f32 {
        self.raw[0].exp()
    }
}

impl Parameters for Beta {
    fn visit(&self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &[f32])) {
        f(format!("{prefix}.beta_raw"), vec![1], &self.raw);
    }
    fn visit_mut(&mut self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &mut [f32])) {
        f(format!("{prefix}.beta_raw"), vec![1], &mut self.raw);
    }
}

/// The view-direction encoding of F_c: spherical harmonics (hash-grid backbone) or the paper's
/// positional encoding with 4 bands.
#[derive(Clone, Debug)]
pub enum DirectionEncoding {
    Sh(SphericalHarmonics),
    Frequency(FrequencyEncoding),
}

impl DirectionEncoding {
    pub fn output_dim(&self) -> usize {
        match self {
            DirectionEncoding::Sh(s) => s.output_dim(),
            DirectionEncoding::Frequency(f) => f.output_dim(),
        }
    }
    pub fn encode(&self, dirs: &[f32], out: &mut [f32]) {
        match self {
            DirectionEncoding::Sh(s) => s.encode(dirs, out),
            DirectionEncoding::Frequency(f) => f.encode(dirs, out, None),
        }
    }
}

/// Which learning rate of the training configuration an optimizer group takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LrClass {
    /// The hash grid's table.
    Grid,
    /// The small MLPs.
    Mlp,
    /// log β of the density.
    Beta,
}

/// How the optimizer updates a group: dense, or (hash tables) only the rows the batch touched.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Update {
    Dense,
    /// Lazy rows of this many parameters ([`i2sdf_nn::Adam::update_sparse`]).
    SparseRows(usize),
}

/// One parameter group of a scene: what the optimizer, the checkpoint and the gradients know
/// about it.
#[derive(Clone, Debug, PartialEq)]
pub struct GroupSpec {
    /// Optimizer group name (Adam state tensors `adam.{name}.m` / `.v`).
    pub name: String,
    /// Prefix of the group's tensors in a checkpoint.
    pub prefix: String,
    pub lr: LrClass,
    pub update: Update,
    /// A checkpoint must hold it (the stage-1 fields); optional groups (stage-2 modules) that a
    /// checkpoint lacks keep their fresh initialisation.
    pub required: bool,
}

/// A flat parameter buffer with named tensors: what a scene group holds.
pub trait ParamBlock: Parameters {
    fn values(&self) -> &[f32];
    fn values_mut(&mut self) -> &mut [f32];
}

impl ParamBlock for Mlp {
    fn values(&self) -> &[f32] {
        &self.params
    }
    fn values_mut(&mut self) -> &mut [f32] {
        &mut self.params
    }
}

impl ParamBlock for HashGrid {
    fn values(&self) -> &[f32] {
        &self.params
    }
    fn values_mut(&mut self) -> &mut [f32] {
        &mut self.params
    }
}

impl ParamBlock for Beta {
    fn values(&self) -> &[f32] {
        &self.raw
    }
    fn values_mut(&mut self) -> &mut [f32] {
        &mut self.raw
    }
}

/// A module added to the scene beyond the stage-1 fields (stage 2's material fields and emission
/// table): it says how it is optimized and checkpointed, and the scene does the rest (save, load,
/// gradients, optimizer groups). Its gradient is a dense buffer in [`SceneGrads::extra`].
pub trait SceneModule: ParamBlock + std::fmt::Debug + Send + Sync {
    fn spec(&self) -> GroupSpec;
    fn clone_box(&self) -> Box<dyn SceneModule>;
}

impl Clone for Box<dyn SceneModule> {
    fn clone(&self) -> Self {
        self.clone_box()
    }
}

/// A group's gradient buffer.
pub enum GradMut<'a> {
    Dense(&'a mut [f32]),
    /// A hash table's gradient with its touched-rows bitmap.
    Sparse(&'a mut HashGridGrad),
}

/// A group with its parameters and (for the optimizer) its gradient.
pub struct GroupMut<'a> {
    pub spec: GroupSpec,
    pub module: &'a mut dyn ParamBlock,
    pub grad: Option<GradMut<'a>>,
}

/// Gradients of the parameters of a [`NeuralScene`], one buffer per group of
/// [`NeuralScene::groups`] (the renderer's backward writes the stage-1 ones by field).
pub struct SceneGrads {
    pub sdf: SdfGrad,
    pub radiance: Vec<f32>,
    pub emitter: Vec<f32>,
    /// dL/d raw β (chained through β = β_min + exp(raw) by the renderer).
    pub beta: [f32; 1],
    /// One dense buffer per [`NeuralScene::extra`] module, in order.
    pub extra: Vec<Vec<f32>>,
}

impl SceneGrads {
    pub fn new(scene: &NeuralScene) -> Self {
        SceneGrads {
            sdf: SdfGrad::new(&scene.sdf),
            radiance: vec![0.0; scene.radiance.params.len()],
            emitter: vec![0.0; scene.emitter.params.len()],
            beta: [0.0],
            extra: scene.extra.iter().map(|m| vec![0.0; m.values().len()]).collect(),
        }
    }
}

#[derive(Clone, Debug)]
pub struct NeuralScene {
    pub config: ModelConfig,
    pub normalization: Normalization,
    pub sdf: SdfNetwork,
    pub radiance: Mlp,
    pub emitter: Mlp,
    pub direction: DirectionEncoding,
    pub beta: Beta,
    /// Modules beyond stage 1 (see [`SceneModule`]).
    pub extra: Vec<Box<dyn SceneModule>>,
}

fn spec(name: &str, prefix: &str, lr: LrClass, update: Update) -> GroupSpec {
    GroupSpec {
        name: name.into(),
        prefix: prefix.into(),
        lr,
        update,
        required: true,
    }
}

impl NeuralScene {
    pub fn new(config: &ModelConfig, normalization: Normalization, seed: u64) -> Self {
        let direction = match config.backbone {
            Backbone::HashGrid => DirectionEncoding::Sh(SphericalHarmonics::new(config.sh_degree)),
            Backbone::Mlp => DirectionEncoding::Frequency(FrequencyEncoding::new(3, 4)),
        };
        NeuralScene {
            config: config.clone(),
            normalization,
            sdf: SdfNetwork::new(config.sdf_network(), seed),
            radiance: Mlp::new(config.radiance_mlp(), seed.wrapping_add(1)),
            emitter: Mlp::new(config.emitter_mlp(), seed.wrapping_add(2)),
            direction,
            beta: Beta::new(config.beta_init, config.beta_min),
            extra: Vec::new(),
        }
    }

    pub fn feature_dim(&self) -> usize {
        self.sdf.feature_dim()
    }

    /// Operand precision of the stage-1 networks' products (SDF, radiance, emitter): stage 1 sets
    /// it from `train.matmul_precision`; a scene as built or loaded runs f32.
    pub fn set_matmul_precision(&mut self, p: i2sdf_nn::linalg::MatmulPrecision) {
        self.sdf.mlp.precision = p;
        self.radiance.precision = p;
        self.emitter.precision = p;
    }

    /// Assembles F_c's input rows [z, enc(v), ∇d] for `n` points (`dirs`: unit view directions
    /// from the camera, `[n×3]`; `gradients`: ∇d, `[n×3]`, the raw SDF gradient as VolSDF feeds it).
    pub fn radiance_input(&self, features: &[f32], dirs: &[f32], gradients: &[f32], out: &mut Vec<f32>) {
        let mut enc = Vec::new();
        self.radiance_input_into(features, dirs, gradients, &mut enc, out);
    }

    /// [`NeuralScene::radiance_input`] with the direction encoding's buffer supplied (no
    /// allocation once both buffers have grown).
    pub fn radiance_input_into(
        &self,
        features: &[f32],
        dirs: &[f32],
        gradients: &[f32],
        enc: &mut Vec<f32>,
        out: &mut Vec<f32>,
    ) {
        let f = self.feature_dim();
        let e = self.direction.output_dim();
        let n = dirs.len() / 3;
        let w = f + e + 3;
        out.clear();
        out.resize(n * w, 0.0);
        enc.clear();
        enc.resize(n * e, 0.0);
        self.direction.encode(dirs, enc);
        for i in 0..n {
            let row = &mut out[i * w..(i + 1) * w];
            row[..f].copy_from_slice(&features[i * f..(i + 1) * f]);
            row[f..f + e].copy_from_slice(&enc[i * e..(i + 1) * e]);
            row[f + e..].copy_from_slice(&gradients[i * 3..i * 3 + 3]);
        }
    }

    /// Every parameter group with its tensors: the one list that save, load, `is_finite`, the
    /// gradients and the optimizer follow ([`NeuralScene::groups`] is its mutable twin, in the
    /// same order).
    pub fn modules(&self) -> Vec<(GroupSpec, &dyn ParamBlock)> {
        let mut v: Vec<(GroupSpec, &dyn ParamBlock)> = Vec::new();
        if let SdfEncoding::HashGrid(g) = &self.sdf.encoding {
            let rows = Update::SparseRows(g.config.features_per_level);
            v.push((spec("hash_grid", "sdf.hash_grid", LrClass::Grid, rows), g));
        }
        v.push((spec("sdf_mlp", "sdf.mlp", LrClass::Mlp, Update::Dense), &self.sdf.mlp));
        v.push((
            spec("radiance", "radiance", LrClass::Mlp, Update::Dense),
            &self.radiance,
        ));
        v.push((spec("emitter", "emitter", LrClass::Mlp, Update::Dense), &self.emitter));
        v.push((spec("beta", "density", LrClass::Beta, Update::Dense), &self.beta));
        for m in &self.extra {
            v.push((m.spec(), m.as_ref() as &dyn ParamBlock));
        }
        v
    }

    /// The groups, mutably, with their gradient buffers when `grads` is given (the optimizer) or
    /// without (loading): the mutable twin of [`NeuralScene::modules`], in the same order and
    /// with the same specs (taken from it).
    pub fn groups<'a>(&'a mut self, grads: Option<&'a mut SceneGrads>) -> Vec<GroupMut<'a>> {
        let specs: Vec<GroupSpec> = self.modules().into_iter().map(|(s, _)| s).collect();
        let mut specs = specs.into_iter();
        let mut v = Vec::new();
        let mut push = |module: &'a mut dyn ParamBlock, grad: Option<GradMut<'a>>| {
            let spec = specs.next().expect("modules() and groups() list the same groups");
            if let Some(g) = &grad {
                let len = match g {
                    GradMut::Dense(g) => g.len(),
                    GradMut::Sparse(g) => g.values.len(),
                };
                assert_eq!(
                    module.values().len(),
                    len,
                    "gradient of group {} has the wrong size",
                    spec.name
                );
            }
            v.push(GroupMut { spec, module, grad });
        };
        let NeuralScene {
            sdf,
            radiance,
            emitter,
            beta,
            extra,
            ..
        } = self;
        // Split the gradients into per-group buffers (all None when not asked for).
        let (mut g_hash, mut g_mlp, mut g_rad, mut g_emi, mut g_beta, mut g_extra) =
            (None, None, None, None, None, Vec::new());
        if let Some(SceneGrads {
            sdf: gs,
            radiance: gr,
            emitter: ge,
            beta: gb,
            extra: gx,
        }) = grads
        {
            g_hash = gs.hash_grid.as_mut().map(GradMut::Sparse);
            g_mlp = Some(GradMut::Dense(&mut gs.mlp[..]));
            g_rad = Some(GradMut::Dense(&mut gr[..]));
            g_emi = Some(GradMut::Dense(&mut ge[..]));
            g_beta = Some(GradMut::Dense(&mut gb[..]));
            assert_eq!(gx.len(), extra.len(), "SceneGrads of another scene");
            g_extra = gx.iter_mut().map(|g| Some(GradMut::Dense(&mut g[..]))).collect();
        }
        if let SdfEncoding::HashGrid(g) = &mut sdf.encoding {
            push(g, g_hash);
        }
        push(&mut sdf.mlp, g_mlp);
        push(radiance, g_rad);
        push(emitter, g_emi);
        push(beta, g_beta);
        g_extra.resize_with(extra.len(), || None);
        for (m, g) in extra.iter_mut().zip(g_extra) {
            push(m.as_mut(), g);
        }
        v
    }

    /// Writes the fields' parameters (and the config and normalization as metadata) to a
    /// safetensors file, atomically. `extra` adds metadata entries.
    pub fn save(&self, path: &Path, extra: &[(&str, String)]) -> Result<(), DataError> {
        self.save_with(path, extra, &[])
    }

    /// [`NeuralScene::save`] with more tensors in the same file (optimizer state).
    pub fn save_with(
        &self,
        path: &Path,
        extra: &[(&str, String)],
        extra_modules: &[(&str, &dyn Parameters)],
    ) -> Result<(), DataError> {
        let mut meta = HashMap::new();
        meta.insert(
            "model_config".to_string(),
            serde_json::to_string(&self.config).expect("config serializes"),
        );
        meta.insert(
            "normalization".to_string(),
            serde_json::to_string(&self.normalization).expect("serializes"),
        );
        for (k, v) in extra {
            meta.insert(k.to_string(), v.clone());
        }
        let groups = self.modules();
        let views: Vec<AsParams> = groups.iter().map(|(_, m)| AsParams(*m)).collect();
        let mut modules: Vec<(&str, &dyn Parameters)> = groups
            .iter()
            .zip(&views)
            .map(|((s, _), v)| (s.prefix.as_str(), v as &dyn Parameters))
            .collect();
        modules.extend_from_slice(extra_modules);
        i2sdf_data::imageio::write_atomic(path, |tmp| {
            save_safetensors(tmp, &modules, Some(meta)).map_err(|e| e.to_string())
        })
    }

    /// Reads a scene written by [`NeuralScene::save`]; returns it with the file's metadata.
    pub fn load(path: &Path) -> Result<(NeuralScene, HashMap<String, String>), DataError> {
        let (mut scene, meta) = Self::load_config(path)?;
        scene.load_params(path, &mut [])?;
        Ok((scene, meta))
    }

    /// A fresh scene with the configuration and normalization stored in a checkpoint, and the
    /// checkpoint's metadata (parameters not loaded yet: see [`NeuralScene::load_params`]).
    pub fn load_config(path: &Path) -> Result<(NeuralScene, HashMap<String, String>), DataError> {
        let bytes = std::fs::read(path).map_err(|e| DataError::file(path, format!("cannot read: {e}")))?;
        let (header, tensor_bytes) = safetensors_header(&bytes).map_err(|m| DataError::file(path, m))?;
        let config: ModelConfig = header
            .get("model_config")
            .ok_or_else(|| DataError::field(path, "model_config", "missing from the metadata"))
            .and_then(|s| serde_json::from_str(s).map_err(|e| DataError::field(path, "model_config", e.to_string())))?;
        // The configuration sizes the fields allocated below: out-of-range values would panic in
        // the engine, and a table larger than the file's tensors cannot be this file's.
        config
            .validate()
            .map_err(|m| DataError::field(path, "model_config", m))?;
        if config.backbone == Backbone::HashGrid {
            let grid = (
                config.hash_levels,
                config.hash_features,
                config.hash_log2_table,
                config.hash_base_resolution,
                config.hash_finest_resolution,
            );
            check_table_fits(path, "model_config", tensor_bytes, grid)?;
        }
        let normalization: Normalization = header
            .get("normalization")
            .ok_or_else(|| DataError::field(path, "normalization", "missing from the metadata"))
            .and_then(|s| {
                serde_json::from_str(s).map_err(|e| DataError::field(path, "normalization", e.to_string()))
            })?;
        if !(normalization.scale.is_finite() && normalization.scale > 0.0)
            || normalization.center.iter().any(|c| !c.is_finite())
        {
            return Err(DataError::field(
                path,
                "normalization",
                format!(
                    "scale {} and center {:?} must be finite, the scale positive",
                    normalization.scale, normalization.center
                ),
            ));
        }
        Ok((NeuralScene::new(&config, normalization, 0), header))
    }

    /// Loads the groups' parameters from a checkpoint written with this scene's configuration,
    /// and `extra` slots (optimizer state) from the same file. Required groups must be there;
    /// optional groups (modules a later stage added) that the file lacks keep their
    /// initialisation; a tensor of the wrong shape or type, or one that no group claims, is an
    /// error naming it — except the optimizer state (tensors under [`OPTIMIZER_PREFIX`]), which
    /// only the slots in `extra` claim (a resumed trainer) and an inference load skips. Returns,
    /// per group of [`NeuralScene::modules`], whether it was loaded.
    pub fn load_params(&mut self, path: &Path, extra: &mut [ModuleSlot]) -> Result<Vec<bool>, DataError> {
        let groups = self.groups(None);
        let (specs, mut views): (Vec<GroupSpec>, Vec<AsParamsMut>) =
            groups.into_iter().map(|g| (g.spec, AsParamsMut(g.module))).unzip();
        let mut slots: Vec<ModuleSlot> = specs
            .iter()
            .zip(views.iter_mut())
            .map(|(s, v)| ModuleSlot {
                prefix: s.prefix.as_str(),
                module: v,
                required: s.required,
            })
            .collect();
        let n = slots.len();
        for e in extra.iter_mut() {
            slots.push(ModuleSlot {
                prefix: e.prefix,
                module: &mut *e.module,
                required: e.required,
            });
        }
        let (_, loaded) = load_modules(path, &mut slots, Some(OPTIMIZER_PREFIX)).map_err(|e| param_error(path, e))?;
        Ok(loaded[..n].to_vec())
    }

    /// Are all parameters finite? (Checked before a checkpoint is written.)
    pub fn is_finite(&self) -> bool {
        self.modules()
            .iter()
            .all(|(_, m)| m.values().iter().all(|x| x.is_finite()))
    }
}

/// Prefix of the optimizer-state tensors in a checkpoint (`adam.{group}.m` / `.v`).
pub const OPTIMIZER_PREFIX: &str = "adam.";

/// A parameter-file error as the house's error: unreadable files are the file's fault, a
/// tensor at fault is named as the field.
pub fn param_error(path: &Path, e: ParamError) -> DataError {
    match e.tensor() {
        Some(t) => {
            let t = t.to_string();
            let msg = e.to_string();
            let prefix = format!("{}: ", path.display());
            DataError::field(path, t, msg.strip_prefix(&prefix).unwrap_or(&msg).to_string())
        }
        None => DataError::file(path, e.to_string()),
    }
}

/// `&dyn ParamBlock` seen as `&dyn Parameters` (without trait upcasting, for the declared MSRV).
struct AsParams<'a>(&'a dyn ParamBlock);
struct AsParamsMut<'a>(&'a mut dyn ParamBlock);

impl Parameters for AsParams<'_> {
    fn visit(&self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &[f32])) {
        self.0.visit(prefix, f)
    }
    fn visit_mut(&mut self, _: &str, _: &mut dyn FnMut(String, Vec<usize>, &mut [f32])) {
        unreachable!("read-only view")
    }
}

impl Parameters for AsParamsMut<'_> {
    fn visit(&self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &[f32])) {
        self.0.visit(prefix, f)
    }
    fn visit_mut(&mut self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &mut [f32])) {
        self.0.visit_mut(prefix, f)
    }
}

/// The metadata of a safetensors file without loading its tensors.
/// The metadata of a checkpoint file (without reading its tensors into modules).
pub fn checkpoint_metadata(path: &Path) -> Result<HashMap<String, String>, DataError> {
    checkpoint_header(path).map(|(meta, _)| meta)
}

/// The metadata of a checkpoint file and the number of bytes its tensors hold.
pub fn checkpoint_header(path: &Path) -> Result<(HashMap<String, String>, u64), DataError> {
    let bytes = std::fs::read(path).map_err(|e| DataError::file(path, format!("cannot read: {e}")))?;
    safetensors_header(&bytes).map_err(|m| DataError::file(path, m))
}

fn safetensors_header(bytes: &[u8]) -> Result<(HashMap<String, String>, u64), String> {
    let (n, meta) =
        safetensors::SafeTensors::read_metadata(bytes).map_err(|e| format!("not a safetensors file: {e}"))?;
    // 8 bytes of header length, the JSON header, then the tensors' data.
    let tensor_bytes = (bytes.len() as u64).saturating_sub(8 + n as u64);
    Ok((meta.metadata().clone().unwrap_or_default(), tensor_bytes))
}

/// Refuses a checkpoint whose configuration describes a hash grid (`levels`, `features`,
/// `log2_table`, `base`, `finest` resolution) larger than the tensors the file holds, before the
/// grid is allocated: a few bytes of metadata must not make a loader allocate gigabytes. The
/// bound is a lower one on the engine's table (each level holds min((res + 1)³, 2^log2)
/// entries, its resolution at least `base`, the finest at least `finest` − 1), so it never
/// refuses a checkpoint that holds its grid.
pub fn check_table_fits(
    path: &Path,
    field: &str,
    tensor_bytes: u64,
    (levels, features, log2_table, base, finest): (usize, usize, u32, u32, u32),
) -> Result<(), DataError> {
    let table = 1u64.checked_shl(log2_table).unwrap_or(u64::MAX);
    let level = |res: u64| res.saturating_add(1).saturating_pow(3).min(table);
    let last = if levels > 1 { finest.max(1) - 1 } else { base };
    let entries = level(last as u64).saturating_add((levels.max(1) as u64 - 1).saturating_mul(level(base as u64)));
    let needed = entries.saturating_mul(features as u64).saturating_mul(4);
    if needed > tensor_bytes {
        return Err(DataError::field(
            path,
            field,
            format!(
                "describes a hash grid of at least {needed} bytes, but the file's tensors hold {tensor_bytes}: \
                 the metadata does not belong to these tensors"
            ),
        ));
    }
    Ok(())
}

/// The small scene the model's unit tests share: a 4-level hash grid, inverted sphere of radius
/// 0.7, identity normalization.
#[cfg(test)]
pub(crate) fn tiny_test_scene() -> NeuralScene {
    let c = ModelConfig {
        hash_levels: 4,
        hash_log2_table: 12,
        hash_finest_resolution: 64,
        init_radius: 0.7,
        ..Default::default()
    };
    NeuralScene::new(
        &c,
        Normalization {
            center: [0.0; 3],
            scale: 1.0,
        },
        1,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::SceneQuery;

    fn unit() -> Normalization {
        Normalization {
            center: [0.0; 3],
            scale: 1.0,
        }
    }

    fn small() -> ModelConfig {
        ModelConfig {
            hash_levels: 4,
            hash_log2_table: 12,
            hash_finest_resolution: 64,
            init_radius: 0.8,
            ..Default::default()
        }
    }

    #[test]
    fn starts_as_an_inverted_sphere() {
        let scene = NeuralScene::new(
            &small(),
            Normalization {
                center: [0.0; 3],
                scale: 1.0,
            },
            3,
        );
        let mut q = SceneQuery::new(&scene);
        let pts = [0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0, -0.9, 0.0, 0.0, 0.0, 1.3];
        let mut d = [0.0; 4];
        q.sdf(&pts, &mut d);
        // ≈ r − ‖x‖ (a small softplus MLP only approximates the cone at the centre): free space
        // inside, decreasing outwards, negative outside the sphere.
        assert!(d[0] > 0.5 && d[0] > d[1] && d[1] > d[2] && d[3] < 0.0, "{d:?}");
        assert!((d[1] - 0.3).abs() < 0.1, "{d:?}");
    }

    #[test]
    fn save_load_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let mut scene = NeuralScene::new(
            &small(),
            Normalization {
                center: [1.0, 2.0, 3.0],
                scale: 4.0,
            },
            5,
        );
        scene.beta.raw[0] = -3.14;
        scene.radiance.params[7] = 0.5;
        let p = dir.path().join("fields.safetensors");
        scene.save(&p, &[("iteration", "12".into())]).unwrap();
        let (back, meta) = NeuralScene::load(&p).unwrap();
        assert_eq!(meta["iteration"], "12");
        assert_eq!(back.config, scene.config);
        assert_eq!(back.normalization, scene.normalization);
        assert_eq!(back.beta, scene.beta);
        assert_eq!(back.radiance.params, scene.radiance.params);
        assert_eq!(back.sdf.mlp.params, scene.sdf.mlp.params);
        std::fs::write(&p, b"junk").unwrap();
        assert!(NeuralScene::load(&p)
            .unwrap_err()
            .to_string()
            .contains("fields.safetensors"));
    }

    /// A stage-2-like module: a dense table (think the emission table L[k]).
    #[derive(Clone, Debug)]
    struct Table {
        values: Vec<f32>,
        rows: usize,
    }

    impl Parameters for Table {
        fn visit(&self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &[f32])) {
            f(format!("{prefix}.values"), vec![self.rows, 3], &self.values);
        }
        fn visit_mut(&mut self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &mut [f32])) {
            f(format!("{prefix}.values"), vec![self.rows, 3], &mut self.values);
        }
    }

    impl ParamBlock for Table {
        fn values(&self) -> &[f32] {
            &self.values
        }
        fn values_mut(&mut self) -> &mut [f32] {
            &mut self.values
        }
    }

    impl SceneModule for Table {
        fn spec(&self) -> GroupSpec {
            GroupSpec {
                name: "emission".into(),
                prefix: "emission".into(),
                lr: LrClass::Mlp,
                update: Update::Dense,
                required: false,
            }
        }
        fn clone_box(&self) -> Box<dyn SceneModule> {
            Box::new(self.clone())
        }
    }

    fn table(rows: usize, v: f32) -> Box<dyn SceneModule> {
        Box::new(Table {
            values: vec![v; rows * 3],
            rows,
        })
    }

    /// Groups, gradients and modules list the same groups in the same order, and an extra module
    /// joins all of them.
    #[test]
    fn one_enumeration_of_groups() {
        let mut scene = NeuralScene::new(&small(), unit(), 1);
        scene.extra.push(table(4, 1.0));
        let names: Vec<String> = scene.modules().iter().map(|(s, _)| s.name.clone()).collect();
        assert_eq!(
            names,
            ["hash_grid", "sdf_mlp", "radiance", "emitter", "beta", "emission"]
        );
        let lens: Vec<usize> = scene.modules().iter().map(|(_, m)| m.values().len()).collect();
        let mut grads = SceneGrads::new(&scene);
        assert_eq!(grads.extra.len(), 1);
        let groups = scene.groups(Some(&mut grads));
        let got: Vec<(String, usize)> = groups
            .iter()
            .map(|g| (g.spec.name.clone(), g.module.values().len()))
            .collect();
        let want: Vec<(String, usize)> = names.into_iter().zip(lens).collect();
        assert_eq!(got, want);
        assert!(groups.iter().all(|g| g.grad.is_some()));
        assert!(matches!(groups[0].grad, Some(GradMut::Sparse(_))));
        scene.extra[0].values_mut()[2] = f32::NAN;
        assert!(!scene.is_finite());
    }

    /// A stage-1 checkpoint loads into a scene with a stage-2 module (which keeps its fresh
    /// values); the scene with it saves and loads back; a scene without the module refuses its
    /// tensors, and a tensor of the wrong shape is an error naming it.
    #[test]
    fn stage1_checkpoint_loads_into_a_scene_with_more_modules() {
        let dir = tempfile::tempdir().unwrap();
        let p1 = dir.path().join("stage1.safetensors");
        let mut s1 = NeuralScene::new(&small(), unit(), 5);
        s1.radiance.params[3] = 0.25;
        s1.save(&p1, &[]).unwrap();
        let (mut s2, _) = NeuralScene::load_config(&p1).unwrap();
        s2.extra.push(table(4, 0.5));
        let loaded = s2.load_params(&p1, &mut []).unwrap();
        assert_eq!(loaded, [true, true, true, true, true, false]);
        assert_eq!(s2.radiance.params, s1.radiance.params);
        assert_eq!(s2.extra[0].values(), &[0.5; 12]);
        // With the module trained, it round-trips.
        s2.extra[0].values_mut()[7] = 2.0;
        let p2 = dir.path().join("stage2.safetensors");
        s2.save(&p2, &[]).unwrap();
        let (mut s3, _) = NeuralScene::load_config(&p2).unwrap();
        s3.extra.push(table(4, 0.0));
        assert!(s3.load_params(&p2, &mut []).unwrap().iter().all(|&l| l));
        assert_eq!(s3.extra[0].values()[7], 2.0);
        // Optimizer state in the file is skipped by an inference load.
        let state = vec![0.5f32; 12];
        struct State<'a>(&'a [f32]);
        impl Parameters for State<'_> {
            fn visit(&self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &[f32])) {
                f(format!("{prefix}.m"), vec![self.0.len()], self.0);
            }
            fn visit_mut(&mut self, _: &str, _: &mut dyn FnMut(String, Vec<usize>, &mut [f32])) {
                unreachable!()
            }
        }
        let p3 = dir.path().join("with_state.safetensors");
        s1.save_with(&p3, &[], &[("adam.radiance", &State(&state))]).unwrap();
        assert_eq!(NeuralScene::load(&p3).unwrap().0.radiance.params, s1.radiance.params);
        // A stage-1 scene does not silently drop the stage-2 tensors.
        let e = NeuralScene::load(&p2).unwrap_err();
        assert!(e.to_string().contains("emission.values") && e.is_bad_input(), "{e}");
        // Another table size: the tensor is named with both shapes.
        let (mut s4, _) = NeuralScene::load_config(&p2).unwrap();
        s4.extra.push(table(5, 0.0));
        let e = s4.load_params(&p2, &mut []).unwrap_err().to_string();
        assert!(
            e.contains("emission.values") && e.contains("[4, 3]") && e.contains("[5, 3]"),
            "{e}"
        );
    }
}
