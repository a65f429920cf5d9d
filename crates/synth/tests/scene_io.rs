//! Scene descriptions: presets are deterministic per seed, carry the required features, and
//! round-trip through TOML; bad input is a `DataError` naming the field.

use i2sdf_synth::scene::Geometry;
use i2sdf_synth::{EditSpec, RoomPreset, SceneDesc};
use std::path::Path;

#[test]
fn presets_round_trip_through_toml_and_depend_on_the_seed() {
    for preset in RoomPreset::ALL {
        let a = preset.build(3);
        assert_eq!(a, preset.build(3), "same seed, same room");
        assert_ne!(a, preset.build(4), "another seed, another room");
        let text = a.to_toml_string();
        let back = SceneDesc::from_toml_str(&text, Path::new("scene.toml")).unwrap();
        assert_eq!(a, back);
    }
}

#[test]
fn presets_have_thin_structures_a_suspended_cluster_and_several_emitters() {
    for preset in RoomPreset::ALL {
        for seed in 0..8 {
            let s = preset.build(seed);
            let emitters = s.shapes.iter().filter(|x| x.emission.is_some()).count();
            assert!(emitters >= 2, "{} seed {seed}: {emitters} emitters", preset.name());
            let thin = s.shapes.iter().any(|x| {
                matches!(x.geometry, Geometry::Cylinder { radius, .. } if radius < 0.02) && x.name.contains("pole")
            });
            assert!(thin, "{} seed {seed}: no thin lamp pole", preset.name());
            let balls = s
                .shapes
                .iter()
                .filter(|x| x.name.starts_with("chandelier_ball"))
                .count();
            assert!(
                balls >= 5,
                "{} seed {seed}: chandelier has {balls} balls",
                preset.name()
            );
            let legs = s.shapes.iter().filter(|x| x.name.contains("_leg_")).count();
            assert!(legs >= 4, "{} seed {seed}: {legs} table legs", preset.name());
            assert!(s.shapes.iter().any(|x| x.material.texture.is_some()));
            assert!(
                s.shapes.iter().any(|x| x.material.ks.iter().any(|k| *k >= 0.3)),
                "a glossy material"
            );
            s.validate(Path::new("x")).unwrap();
        }
    }
}

#[test]
fn bad_scene_input_is_a_data_error_naming_the_field() {
    let mut s = RoomPreset::Bedroom.build(0);
    s.shapes[3].material.roughness = 0.0;
    let err = SceneDesc::from_toml_str(&s.to_toml_string(), Path::new("room.toml")).unwrap_err();
    assert!(
        err.to_string().contains("roughness") && err.to_string().contains("room.toml"),
        "{err}"
    );
    let err = SceneDesc::from_toml_str("name = 3", Path::new("room.toml")).unwrap_err();
    assert!(matches!(err, i2sdf_data::DataError::File { .. }), "{err}");
    assert!(RoomPreset::parse("kitchen").is_err());
}

#[test]
fn edit_spec_parses_and_defaults_colour() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("e.toml");
    std::fs::write(&p, "[[op]]\nkind = \"relight\"\nat = [0.0, 2.5, 0.0]\nscale = 0.0\n").unwrap();
    let spec = EditSpec::read(&p).unwrap();
    let i2sdf_synth::EditOp::Relight(r) = &spec.ops[0] else {
        panic!("{spec:?}")
    };
    assert_eq!((r.color, r.scale), ([1.0; 3], 0.0));
    std::fs::write(&p, "[[op]]\nkind = \"relight\"\nat = [0.0, 2.5, 0.0]\nscale = -1.0\n").unwrap();
    assert!(EditSpec::read(&p).is_err());
}
