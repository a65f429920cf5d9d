//! Object identity in the ground truth: every face of `mesh.ply` carries the `object_id` of the
//! object its shape belongs to, transforms.json's `objects` names and tags exactly those ids, the
//! presets tag their thin and suspended parts by what their geometry is, and scene TOMLs written
//! before objects existed still load.

mod common;

use i2sdf_synth::scene::{tags, Geometry, SceneObject};
use i2sdf_synth::{RoomPreset, SceneDesc, SceneMesh};
use std::collections::BTreeSet;
use std::path::Path;

#[test]
fn every_face_of_the_written_mesh_names_a_listed_object() {
    let tmp = tempfile::tempdir().unwrap();
    let written = common::render_tiny(tmp.path(), RoomPreset::Livingroom, 2, 2);
    let (_, faces, ids) = common::read_ply_with_objects(&tmp.path().join("mesh.ply"));
    let ids = ids.expect("mesh.ply declares a per-face object_id");
    assert_eq!(ids.len(), faces.len());

    // The ids are exactly the scene's objects, face by face.
    let desc = RoomPreset::Livingroom.build(2);
    let (objects, object_of_shape) = desc.objects();
    let mesh = SceneMesh::from_scene(&desc);
    assert_eq!(mesh.mesh.faces.len(), faces.len());
    for (f, &shape) in mesh.shape_of.iter().enumerate() {
        assert_eq!(ids[f], object_of_shape[shape as usize], "face {f}");
    }

    // transforms.json lists each id once, with the scene's names and tags, and every listed
    // object owns faces.
    let listed = written.json["objects"].as_array().expect("an objects list");
    assert_eq!(listed.len(), objects.len());
    for (entry, object) in listed.iter().zip(&objects) {
        let tags: Vec<String> = serde_json::from_value(entry["tags"].clone()).unwrap();
        assert_eq!(entry["id"].as_i64(), Some(object.id as i64));
        assert_eq!(entry["name"].as_str(), Some(object.name.as_str()));
        assert_eq!(tags, object.tags);
    }
    let in_mesh: BTreeSet<i32> = ids.iter().copied().collect();
    let in_json: BTreeSet<i32> = objects.iter().map(|o| o.id).collect();
    assert_eq!(in_mesh, in_json);

    // The project's loader reads the same list.
    let ds = i2sdf_data::load(tmp.path()).unwrap();
    assert_eq!(ds.objects.len(), objects.len());
    for (info, object) in ds.objects.iter().zip(&objects) {
        assert_eq!(
            (info.id, &info.name, &info.tags),
            (object.id, &object.name, &object.tags)
        );
    }
}

/// The two largest extents of a shape's cross-section are under `limit` (a rod, not a slab).
fn rod_like(g: &Geometry, limit: f32) -> bool {
    match g {
        Geometry::Cylinder { radius, .. } => 2.0 * radius < limit,
        Geometry::Box { min, max, .. } => {
            let mut e: Vec<f32> = (0..3).map(|a| max[a] - min[a]).collect();
            e.sort_by(f32::total_cmp);
            e[1] < limit
        }
        Geometry::Sphere { radius, .. } => 2.0 * radius < limit,
        Geometry::Quad { .. } => false,
    }
}

#[test]
fn presets_tag_thin_and_suspended_objects_by_their_geometry() {
    for preset in RoomPreset::ALL {
        for seed in 0..8 {
            let desc = preset.build(seed);
            let (objects, object_of_shape) = desc.objects();
            let what = format!("{} seed {seed}", preset.name());
            let has = |o: &SceneObject, tag: &str| o.tags.iter().any(|t| t == tag);
            assert!(objects.iter().any(|o| has(o, tags::THIN)), "{what}: no thin object");
            assert!(
                objects.iter().any(|o| has(o, tags::SUSPENDED)),
                "{what}: no suspended object"
            );
            assert!(objects.iter().any(|o| has(o, tags::SMALL)), "{what}: no small object");
            assert_eq!(objects.iter().filter(|o| has(o, tags::ROOM)).count(), 6, "{what}");
            assert!(objects.iter().all(|o| !o.tags.is_empty()), "{what}: an untagged object");
            for (shape, &id) in desc.shapes.iter().zip(&object_of_shape) {
                let object = &objects[id as usize];
                // Thin objects are made of rods only, and every rod belongs to a thin object, or
                // is a small object (a 3.5 cm die is under the limit in every direction). The
                // wardrobe handle (4 × 3 cm, relief on the wardrobe's face) is the boundary case,
                // just outside the limit.
                let rod = rod_like(&shape.geometry, 0.038);
                let small = has(object, tags::SMALL);
                assert_eq!(
                    has(object, tags::THIN),
                    rod && !small,
                    "{what}: {} in {}",
                    shape.name,
                    object.name
                );
                if small {
                    // Under 5 cm in every direction, and not a thin or suspended object.
                    let mut m = SceneMesh::default();
                    m.add_geometry(&shape.geometry, 0);
                    let (lo, hi) = m.shape_bounds(0);
                    assert!(
                        (hi - lo).max_element() < 0.05,
                        "{what}: {} is {:?}",
                        shape.name,
                        hi - lo
                    );
                    assert!(
                        !has(object, tags::THIN) && !has(object, tags::SUSPENDED),
                        "{what}: {}",
                        shape.name
                    );
                }
                assert_eq!(
                    has(object, tags::EMITTER),
                    shape.emission.is_some(),
                    "{what}: {}",
                    shape.name
                );
                if has(object, tags::SUSPENDED) {
                    // Hanging well above the floor and the furniture.
                    let mesh = {
                        let mut m = SceneMesh::default();
                        m.add_geometry(&shape.geometry, 0);
                        m
                    };
                    let (lo, _) = mesh.shape_bounds(0);
                    assert!(lo.y > 1.5, "{what}: {} reaches down to {}", shape.name, lo.y);
                }
            }
        }
    }
}

#[test]
fn scene_toml_without_objects_loads_with_one_object_per_shape() {
    let desc = RoomPreset::Bedroom.build(5);
    // The same scene as a TOML written before shapes had `object` and `tags`.
    let mut value: toml::Value = toml::from_str(&desc.to_toml_string()).unwrap();
    for shape in value["shape"].as_array_mut().unwrap() {
        let table = shape.as_table_mut().unwrap();
        table.remove("object");
        table.remove("tags");
    }
    let old = toml::to_string(&value).unwrap();
    assert!(!old.contains("tags") && !old.contains("object"), "{old}");
    let back = SceneDesc::from_toml_str(&old, Path::new("old.toml")).unwrap();
    let (objects, object_of_shape) = back.objects();
    assert_eq!(objects.len(), back.shapes.len());
    for (i, (shape, object)) in back.shapes.iter().zip(&objects).enumerate() {
        assert_eq!((object_of_shape[i], &object.name), (i as i32, &shape.name));
        let expected: Vec<String> = shape.emission.iter().map(|_| tags::EMITTER.to_string()).collect();
        assert_eq!(object.tags, expected);
    }
    // Geometry and materials are untouched: the old file renders the same room.
    for (a, b) in back.shapes.iter().zip(&desc.shapes) {
        assert_eq!(
            (&a.geometry, &a.material, a.emission),
            (&b.geometry, &b.material, b.emission)
        );
    }

    let mut bad = desc.clone();
    bad.shapes[2].tags = vec![String::new()];
    let err = SceneDesc::from_toml_str(&bad.to_toml_string(), Path::new("room.toml")).unwrap_err();
    assert!(err.to_string().contains("tags"), "{err}");
}
