//! Tests of the built-in scenes: names, errors and which objects move.

use super::*;

#[test]
fn unknown_scene_names_itself_and_the_valid_ones() {
    let e = builtin("sponza", Variant::Dynamic).unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("\"sponza\""), "{msg}");
    for n in SCENE_NAMES {
        assert!(msg.contains(n), "{msg}");
    }
    assert!(Variant::parse("moving").is_err());
    assert_eq!(Variant::parse("static").unwrap(), Variant::Static);
}

#[test]
fn every_builtin_scene_builds_with_moving_objects_only_when_dynamic() {
    for name in SCENE_NAMES {
        let d = builtin(name, Variant::Dynamic).unwrap();
        let s = builtin(name, Variant::Static).unwrap();
        assert!((0..d.objects.len()).any(|i| d.moves(i)), "{name}");
        assert!((0..s.objects.len()).all(|i| !s.moves(i)), "{name}");
        // An object moves exactly when its world transform changes with time (children of
        // moving parents included); in the static variant none changes.
        let times = [0.37, 1.3, 2.9];
        let (d0, s0) = (d.transforms(0.0), s.transforms(0.0));
        for i in 0..d.objects.len() {
            let changes = times.iter().any(|&t| d.transforms(t)[i] != d0[i]);
            assert_eq!(d.moves(i), changes, "{name} object {i}");
            assert!(
                times.iter().all(|&t| s.transforms(t)[i] == s0[i]),
                "{name} {i}"
            );
        }
    }
}
