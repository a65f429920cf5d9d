//! Named parameter tensors and their safetensors files.
//!
//! Every module lists its tensors with a name and shape through [`Parameters`]; a checkpoint is the
//! union of several modules under prefixes (`"sdf"`, `"radiance"`, …), stored as f32 safetensors.
//! Loading checks that every expected tensor is present with the expected shape.

use crate::hashgrid::HashGrid;
use crate::mlp::Mlp;
use crate::sdf::{SdfEncoding, SdfNetwork};
use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use std::collections::HashMap;
use std::path::Path;

/// Errors of parameter files.
#[derive(Debug, thiserror::Error)]
pub enum ParamError {
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{path}: not a safetensors file: {message}")]
    Format { path: String, message: String },
    #[error("{path}: tensor {name} is missing")]
    Missing { path: String, name: String },
    #[error("{path}: tensor {name} is not part of this model (a checkpoint of another configuration or stage?)")]
    Unknown { path: String, name: String },
    #[error("{path}: tensor {name} has shape {found:?} ({dtype}), expected {expected:?} (F32)")]
    Shape {
        path: String,
        name: String,
        found: Vec<usize>,
        expected: Vec<usize>,
        dtype: String,
    },
}

/// A module with named f32 parameter tensors (flat slices with a logical shape).
/// The visitor receives `(name, shape, values)` of each tensor.
#[allow(clippy::type_complexity)]
pub trait Parameters {
    fn visit(&self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &[f32]));
    fn visit_mut(&mut self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &mut [f32]));
}

impl Parameters for Mlp {
    fn visit(&self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &[f32])) {
        for (l, layer) in self.layers.iter().enumerate() {
            let (w, b) = (layer.weight_offset, layer.bias_offset);
            f(
                format!("{prefix}.layers.{l}.weight"),
                vec![layer.out_dim, layer.in_dim],
                &self.params[w..b],
            );
            f(
                format!("{prefix}.layers.{l}.bias"),
                vec![layer.out_dim],
                &self.params[b..b + layer.out_dim],
            );
        }
    }
    fn visit_mut(&mut self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &mut [f32])) {
        for (l, layer) in self.layers.iter().enumerate() {
            let (w, b) = (layer.weight_offset, layer.bias_offset);
            let (wp, bp) = self.params[w..b + layer.out_dim].split_at_mut(b - w);
            f(
                format!("{prefix}.layers.{l}.weight"),
                vec![layer.out_dim, layer.in_dim],
                wp,
            );
            f(format!("{prefix}.layers.{l}.bias"), vec![layer.out_dim], bp);
        }
    }
}

impl Parameters for HashGrid {
    fn visit(&self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &[f32])) {
        f(
            format!("{prefix}.table"),
            vec![self.entries(), self.config.features_per_level],
            &self.params,
        );
    }
    fn visit_mut(&mut self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &mut [f32])) {
        let shape = vec![self.entries(), self.config.features_per_level];
        f(format!("{prefix}.table"), shape, &mut self.params);
    }
}

impl Parameters for SdfNetwork {
    fn visit(&self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &[f32])) {
        if let SdfEncoding::HashGrid(g) = &self.encoding {
            g.visit(&format!("{prefix}.hash_grid"), f);
        }
        self.mlp.visit(&format!("{prefix}.mlp"), f);
    }
    fn visit_mut(&mut self, prefix: &str, f: &mut dyn FnMut(String, Vec<usize>, &mut [f32])) {
        if let SdfEncoding::HashGrid(g) = &mut self.encoding {
            g.visit_mut(&format!("{prefix}.hash_grid"), f);
        }
        self.mlp.visit_mut(&format!("{prefix}.mlp"), f);
    }
}

/// Write the tensors of `modules` (each under its prefix) to a safetensors file, with `metadata`
/// (e.g. the configuration as JSON) in its header.
pub fn save_safetensors(
    path: &Path,
    modules: &[(&str, &dyn Parameters)],
    metadata: Option<HashMap<String, String>>,
) -> Result<(), ParamError> {
    let mut tensors: Vec<(String, Vec<usize>, Vec<u8>)> = Vec::new();
    for (prefix, module) in modules {
        module.visit(prefix, &mut |name, shape, data| {
            let bytes = data.iter().flat_map(|v| v.to_le_bytes()).collect();
            tensors.push((name, shape, bytes));
        });
    }
    let p = path.display().to_string();
    let views: Vec<(String, TensorView)> = tensors
        .iter()
        .map(|(n, s, b)| {
            let view = TensorView::new(Dtype::F32, s.clone(), b).map_err(|e| ParamError::Format {
                path: p.clone(),
                message: e.to_string(),
            })?;
            Ok((n.clone(), view))
        })
        .collect::<Result<_, ParamError>>()?;
    // The header's metadata in the HashMap's (random) order as safetensors writes it, to find it.
    let written = metadata
        .as_ref()
        .map(|m| serde_json::to_string(m).expect("strings serialize"));
    let sorted = metadata.as_ref().map(|m| {
        serde_json::to_string(&m.iter().collect::<std::collections::BTreeMap<_, _>>()).expect("strings serialize")
    });
    let mut bytes = safetensors::serialize(views, metadata).map_err(|e| ParamError::Format {
        path: p.clone(),
        message: e.to_string(),
    })?;
    if let (Some(written), Some(sorted)) = (written, sorted) {
        sort_header_metadata(&mut bytes, &written, &sorted);
    }
    std::fs::write(path, &bytes).map_err(|source| ParamError::Io { path: p, source })
}

/// Rewrites the header's `__metadata__` object `written` as `sorted` (the same entries by key,
/// so the same length): safetensors serializes a HashMap, whose order changes from run to run,
/// and a fixed seed must give a byte-identical checkpoint. Leaves the bytes alone if the header
/// does not start as expected.
fn sort_header_metadata(bytes: &mut [u8], written: &str, sorted: &str) {
    let prefix = format!("{{\"__metadata__\":{written}");
    let start = 8;
    if written.len() == sorted.len() && bytes.get(start..start + prefix.len()) == Some(prefix.as_bytes()) {
        let at = start + prefix.len() - written.len();
        bytes[at..at + sorted.len()].copy_from_slice(sorted.as_bytes());
    }
}

/// Read a safetensors file into `modules` (each under its prefix); every tensor they expect must be
/// present, f32, with their shape, and every tensor of the file must belong to one of them.
/// Returns the header metadata. (The all-required case of [`load_modules`].)
pub fn load_safetensors(
    path: &Path,
    modules: &mut [(&str, &mut dyn Parameters)],
) -> Result<HashMap<String, String>, ParamError> {
    let mut slots: Vec<ModuleSlot> = modules
        .iter_mut()
        .map(|(prefix, module)| ModuleSlot {
            prefix,
            module: &mut **module,
            required: true,
        })
        .collect();
    load_modules(path, &mut slots, None).map(|(meta, _)| meta)
}

/// Copies the tensors of `module` (under `prefix`) out of `file`: each must be there, f32, with the
/// module's shape. The first offending tensor is named.
fn read_module(file: &SafeTensors, p: &str, prefix: &str, module: &mut dyn Parameters) -> Result<(), ParamError> {
    let mut first_error = None;
    module.visit_mut(prefix, &mut |name, shape, dst| {
        if first_error.is_some() {
            return;
        }
        match file.tensor(&name) {
            Err(_) => {
                first_error = Some(ParamError::Missing {
                    path: p.to_string(),
                    name,
                })
            }
            Ok(t) if t.dtype() != Dtype::F32 || t.shape() != shape.as_slice() => {
                first_error = Some(ParamError::Shape {
                    path: p.to_string(),
                    name,
                    found: t.shape().to_vec(),
                    expected: shape,
                    dtype: format!("{:?}", t.dtype()),
                })
            }
            Ok(t) => {
                for (d, c) in dst.iter_mut().zip(t.data().chunks_exact(4)) {
                    *d = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
                }
            }
        }
    });
    first_error.map_or(Ok(()), Err)
}

impl ParamError {
    /// The tensor at fault, if the error is about one.
    pub fn tensor(&self) -> Option<&str> {
        match self {
            ParamError::Missing { name, .. } | ParamError::Unknown { name, .. } | ParamError::Shape { name, .. } => {
                Some(name)
            }
            _ => None,
        }
    }
}

/// One module of [`load_modules`]: its tensors under `prefix`; an optional module whose tensors
/// are all absent from the file keeps its current (freshly initialised) values.
pub struct ModuleSlot<'a> {
    pub prefix: &'a str,
    pub module: &'a mut dyn Parameters,
    pub required: bool,
}

/// Read a safetensors file into `modules`. A module is either wholly in the file (every tensor
/// present, f32, with its shape) or, if optional, wholly absent (left as it is: a checkpoint of an
/// earlier stage loads into a scene with more modules); every tensor of the file must belong to
/// some module, except those under `unclaimed_prefix` (e.g. optimizer state that an inference
/// load does not want). Returns the header metadata and, per module, whether it was loaded.
pub fn load_modules(
    path: &Path,
    modules: &mut [ModuleSlot],
    unclaimed_prefix: Option<&str>,
) -> Result<(HashMap<String, String>, Vec<bool>), ParamError> {
    let p = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| ParamError::Io {
        path: p.clone(),
        source,
    })?;
    let format = |e: safetensors::SafeTensorError| ParamError::Format {
        path: p.clone(),
        message: e.to_string(),
    };
    let (_, header) = SafeTensors::read_metadata(&bytes).map_err(format)?;
    let file = SafeTensors::deserialize(&bytes).map_err(format)?;
    let mut claimed = std::collections::HashSet::new();
    let mut loaded = Vec::with_capacity(modules.len());
    for slot in modules.iter_mut() {
        // Which of the module's tensors does the file hold?
        let (mut names, mut present) = (Vec::new(), 0usize);
        slot.module.visit(slot.prefix, &mut |name, _, _| {
            present += usize::from(file.tensor(&name).is_ok());
            names.push(name);
        });
        claimed.extend(names.iter().cloned());
        if present == 0 && !slot.required {
            loaded.push(false);
            continue;
        }
        read_module(&file, &p, slot.prefix, slot.module)?;
        loaded.push(true);
    }
    let mut unknown: Vec<String> = file
        .names()
        .into_iter()
        .filter(|n| !claimed.contains(*n) && !unclaimed_prefix.is_some_and(|p| n.starts_with(p)))
        .map(|n| n.to_string())
        .collect();
    unknown.sort_unstable();
    if let Some(name) = unknown.first() {
        return Err(ParamError::Unknown {
            path: p.clone(),
            name: name.to_string(),
        });
    }
    Ok((header.metadata().clone().unwrap_or_default(), loaded))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{HashGridConfig, SdfEncodingConfig, SdfNetworkConfig};

    fn net(seed: u64, features: usize) -> SdfNetwork {
        let mut c = SdfNetworkConfig::hash_grid(0.8);
        c.encoding = SdfEncodingConfig::HashGrid(HashGridConfig {
            levels: 4,
            log2_table_size: 10,
            finest_resolution: 64,
            ..Default::default()
        });
        c.feature_dim = features;
        SdfNetwork::new(c, seed)
    }

    /// Each HashMap hashes with its own random keys, so its order differs between instances: the
    /// files must not.
    #[test]
    fn the_same_tensors_and_metadata_give_the_same_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let a = net(1, 7);
        let files: Vec<Vec<u8>> = (0..6)
            .map(|i| {
                let meta: HashMap<String, String> =
                    (0..12).map(|k| (format!("key{k}"), format!("value \"{k}\""))).collect();
                let path = dir.path().join(format!("{i}.safetensors"));
                save_safetensors(&path, &[("sdf", &a)], Some(meta)).unwrap();
                std::fs::read(&path).unwrap()
            })
            .collect();
        assert!(files.iter().all(|f| f == &files[0]));
        let mut b = net(2, 7);
        let got = load_safetensors(&dir.path().join("3.safetensors"), &mut [("sdf", &mut b)]).unwrap();
        assert_eq!(got.len(), 12);
        assert_eq!(got["key7"], "value \"7\"");
    }

    #[test]
    fn round_trip_and_shape_errors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.safetensors");
        let a = net(1, 7);
        let meta = HashMap::from([("config".to_string(), "{}".to_string())]);
        save_safetensors(&path, &[("sdf", &a)], Some(meta)).unwrap();
        let mut b = net(2, 7);
        assert_ne!(a.mlp.params, b.mlp.params);
        let got = load_safetensors(&path, &mut [("sdf", &mut b)]).unwrap();
        assert_eq!(got["config"], "{}");
        assert_eq!(a.mlp.params, b.mlp.params);
        let (SdfEncoding::HashGrid(ga), SdfEncoding::HashGrid(gb)) = (&a.encoding, &b.encoding) else {
            unreachable!()
        };
        assert_eq!(ga.params, gb.params);
        let mut c = net(3, 5);
        let err = load_safetensors(&path, &mut [("sdf", &mut c)]).unwrap_err();
        assert!(matches!(err, ParamError::Shape { .. }), "{err}");
        let err = load_safetensors(&path, &mut [("radiance", &mut c)]).unwrap_err();
        assert!(matches!(err, ParamError::Missing { .. }), "{err}");
    }

    /// Optional modules absent from the file keep their values; required ones, partial modules,
    /// wrong shapes and tensors no module claims are errors naming the tensor.
    #[test]
    fn load_modules_with_optional_and_unknown_tensors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.safetensors");
        let a = net(1, 7);
        save_safetensors(&path, &[("sdf", &a)], None).unwrap();
        let (mut b, mut extra) = (net(2, 7), net(3, 4));
        let fresh = extra.mlp.params.clone();
        let (_, loaded) = load_modules(
            &path,
            &mut [
                ModuleSlot {
                    prefix: "sdf",
                    module: &mut b,
                    required: true,
                },
                ModuleSlot {
                    prefix: "material",
                    module: &mut extra,
                    required: false,
                },
            ],
            None,
        )
        .unwrap();
        assert_eq!(loaded, vec![true, false]);
        assert_eq!(b.mlp.params, a.mlp.params);
        assert_eq!(extra.mlp.params, fresh);
        let err = load_modules(
            &path,
            &mut [ModuleSlot {
                prefix: "material",
                module: &mut extra,
                required: true,
            }],
            None,
        )
        .unwrap_err();
        assert_eq!(err.tensor(), Some("material.hash_grid.table"), "{err}");
        // A file with a tensor nobody claims.
        save_safetensors(&path, &[("sdf", &a), ("material", &extra)], None).unwrap();
        let err = load_modules(
            &path,
            &mut [ModuleSlot {
                prefix: "sdf",
                module: &mut b,
                required: true,
            }],
            None,
        )
        .unwrap_err();
        assert!(
            matches!(err, ParamError::Unknown { .. }) && err.tensor().unwrap().starts_with("material."),
            "{err}"
        );
        // … unless it is under the prefix the caller leaves unclaimed (optimizer state).
        let slot = ModuleSlot {
            prefix: "sdf",
            module: &mut b,
            required: true,
        };
        assert!(load_modules(&path, &mut [slot], Some("material.")).is_ok());
        // Wrong shape: a module of another size under the same prefix.
        let mut c = net(4, 5);
        let err = load_modules(
            &path,
            &mut [
                ModuleSlot {
                    prefix: "sdf",
                    module: &mut b,
                    required: true,
                },
                ModuleSlot {
                    prefix: "material",
                    module: &mut c,
                    required: false,
                },
            ],
            None,
        )
        .unwrap_err();
        assert!(
            matches!(err, ParamError::Shape { .. }) && err.to_string().contains("material.mlp"),
            "{err}"
        );
    }
}
