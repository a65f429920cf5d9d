//! Checkpoints whose metadata would have made a loader panic or allocate what the header claims
//! (the `checkpoint` fuzz target's class of input, docs/ARCHITECTURE.md, "Fuzzing"): each is refused with an
//! error naming the file and the metadata field, before a field is allocated.

use i2sdf_data::{Normalization, Radiometry};
use i2sdf_model::intrinsic_io::IntrinsicFields;
use i2sdf_model::material_field::{MaterialBackbone, MaterialConfig, MaterialField};
use i2sdf_model::{Emitter, EmitterTable, ModelConfig, NeuralScene};
use std::path::Path;

fn tiny_model() -> ModelConfig {
    ModelConfig {
        hash_levels: 2,
        hash_features: 1,
        hash_log2_table: 8,
        hash_base_resolution: 2,
        hash_finest_resolution: 4,
        sdf_hidden: 4,
        sdf_layers: 1,
        feature_dim: 3,
        color_hidden: 4,
        color_layers: 1,
        emitter_hidden: 4,
        emitter_layers: 1,
        sh_degree: 1,
        ..Default::default()
    }
}

const NORM: Normalization = Normalization {
    center: [0.0; 3],
    scale: 1.0,
};

/// A valid tiny checkpoint with `meta` entries written over the saved ones.
fn stage1(path: &Path, meta: &[(&str, String)]) {
    NeuralScene::new(&tiny_model(), NORM, 1).save(path, meta).unwrap();
}

fn refused<T>(result: Result<T, i2sdf_data::DataError>, field: &str, expected: &str) {
    let Err(e) = result else { panic!("accepted") };
    let msg = e.to_string();
    assert!(e.is_bad_input(), "{msg}");
    assert!(
        msg.contains("c.safetensors") && msg.contains(field) && msg.contains(expected),
        "{msg}"
    );
}

#[test]
fn stage1_metadata_that_would_panic_or_allocate_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("c.safetensors");
    stage1(&p, &[]);
    assert!(NeuralScene::load(&p).is_ok());
    let config = |f: &dyn Fn(&mut ModelConfig)| {
        let mut c = tiny_model();
        f(&mut c);
        serde_json::to_string(&c).unwrap()
    };
    // A 1 GiB table (within the engine's range) that a 3 KB file cannot hold.
    let huge = config(&|c| {
        c.hash_levels = 16;
        c.hash_log2_table = 24;
        c.hash_base_resolution = 256;
        c.hash_finest_resolution = 4096;
    });
    stage1(&p, &[("model_config", huge)]);
    refused(NeuralScene::load(&p), "model_config", "hash grid of at least");
    // Out of the engine's range: these asserted (or shifted past 64 bits) in the engine.
    for bad in [
        config(&|c| c.hash_levels = 0),
        config(&|c| c.hash_log2_table = 70),
        config(&|c| c.sdf_layers = 0),
        config(&|c| c.sh_degree = 9),
    ] {
        stage1(&p, &[("model_config", bad)]);
        refused(NeuralScene::load(&p), "model_config", "model.");
    }
    for norm in [r#"{"center":[0,0,0],"scale":0}"#, r#"{"center":[0,0,0],"scale":-2}"#] {
        stage1(&p, &[("normalization", norm.to_string())]);
        refused(NeuralScene::load(&p), "normalization", "positive");
    }
}

#[test]
fn stage2_metadata_describing_a_grid_the_file_lacks_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("c.safetensors");
    let material = MaterialConfig {
        backbone: MaterialBackbone::HashGrid,
        hash_levels: 1,
        hash_log2_table: 8,
        hash_base_resolution: 2,
        hash_finest_resolution: 2,
        hidden_dim: 8,
        hidden_layers: 1,
        ..Default::default()
    };
    let emitter = Emitter {
        centre: [0.0; 3],
        extent: [0.1; 3],
        radius: 0.1,
        points: 1,
        sphere: None,
        bounds: None,
        panel: None,
    };
    let fields = IntrinsicFields {
        material: MaterialField::new(&material, 3, 0),
        emitters: EmitterTable::new(vec![emitter], &[[1.0; 3]]),
        radiometry: Radiometry::from_name("srgb", None).unwrap(),
    };
    fields.save(&p, &[], &[]).unwrap();
    assert!(IntrinsicFields::load(&p, 3, &mut []).is_ok());
    // 32 levels of 2^24 entries: a 4 GiB table, within material.*'s ranges.
    let huge = MaterialConfig {
        hash_levels: 32,
        hash_log2_table: 24,
        hash_base_resolution: 512,
        hash_finest_resolution: 1 << 16,
        ..material
    };
    fields
        .save(&p, &[("material_config", serde_json::to_string(&huge).unwrap())], &[])
        .unwrap();
    refused(
        IntrinsicFields::load(&p, 3, &mut []),
        "material_config",
        "hash grid of at least",
    );
}
