//! A scene changed through its public fields, or built with a camera path that cannot give a
//! pose, is refused with an error by the render functions (it panicked: an index out of range
//! for an object added without `Scene::refresh`, or for a path without keys).

use reproj_scene::{
    builtin, mono, render_client_frame, render_ground_truth, render_server, render_server_frame,
    render_shadow_fraction, Anim, Scene, SceneError, Variant,
};

/// Every render function's answer for `scene`.
fn renders(scene: &Scene) -> Vec<Result<(), SceneError>> {
    let pose = builtin("courtyard", Variant::Dynamic)
        .unwrap()
        .path
        .client_pose(0.1);
    let cam = mono(&pose, 8, 6, scene.near, scene.far);
    vec![
        render_server(scene, &cam, 0.1, 0.1, 4, 1).map(drop),
        render_ground_truth(scene, &cam, 0.1, 1).map(drop),
        render_shadow_fraction(scene, &cam, 0.1).map(drop),
        render_server_frame(scene, 1, 0.004, 10.0, 4).map(drop),
        render_client_frame(scene, 1, 0.004, 120.0, false).map(drop),
    ]
}

#[test]
fn objects_changed_without_refresh_are_refused_until_refreshed() {
    let mut scene = builtin("courtyard", Variant::Dynamic).unwrap();
    assert!(renders(&scene).iter().all(Result::is_ok));
    // An object added: the moves derived by Scene::new no longer cover it.
    scene.objects.push(scene.objects[0].clone());
    for r in renders(&scene) {
        assert!(
            matches!(r, Err(SceneError::Changed { derived, now }) if now == derived + 1),
            "{r:?}"
        );
    }
    let e = renders(&scene).remove(0).unwrap_err().to_string();
    assert!(e.contains("call Scene::refresh"), "{e}");
    scene.refresh().unwrap();
    assert!(renders(&scene).iter().all(Result::is_ok));
    // An object that stood still given a motion: as many objects, but it moves now.
    let still = (0..scene.objects.len()).find(|&i| !scene.moves(i)).unwrap();
    scene.objects[still].anims.push(Anim::Translate {
        velocity: [0.1, 0.0, 0.0],
        acceleration: [0.0; 3],
    });
    assert!(matches!(
        renders(&scene).remove(1),
        Err(SceneError::Changed { .. })
    ));
    scene.refresh().unwrap();
    assert!(scene.moves(still));
    // An object that is its own parent.
    let was = scene.objects[3].parent;
    scene.objects[3].parent = Some(3);
    for r in renders(&scene) {
        assert!(
            matches!(
                r,
                Err(SceneError::BadHierarchy {
                    index: 3,
                    parent: 3,
                    ..
                })
            ),
            "{r:?}"
        );
    }
    assert!(matches!(
        scene.refresh(),
        Err(SceneError::BadHierarchy { index: 3, .. })
    ));
    scene.objects[3].parent = was;
    scene.refresh().unwrap();
    // A parent that comes after its child.
    let last = scene.objects.len() - 1;
    scene.objects[0].parent = Some(last);
    for r in renders(&scene) {
        assert!(
            matches!(r, Err(SceneError::BadHierarchy { index: 0, .. })),
            "{r:?}"
        );
    }
}

#[test]
fn camera_paths_that_give_no_pose_are_refused() {
    let scene = builtin("lab", Variant::Static).unwrap();
    let rebuilt = |keys: Vec<(f64, [f64; 3], [f64; 3])>| {
        let mut path = scene.path.clone();
        path.keys = keys;
        Scene::new(
            "lab",
            Variant::Static,
            scene.objects.clone(),
            scene.light,
            scene.sky,
            scene.duration,
            (scene.near, scene.far),
            path,
        )
    };
    let key = scene.path.keys[0];
    let why = |r: Result<Scene, SceneError>| match r {
        Err(SceneError::BadPath { why }) => why,
        other => panic!("{other:?}"),
    };
    assert!(why(rebuilt(vec![])).starts_with("no keys"));
    let nan = (key.0, [f64::NAN, 0.0, 0.0], key.2);
    assert!(why(rebuilt(vec![key, nan])).contains("key 1 is"));
    let earlier = (key.0 - 1.0, key.1, key.2);
    assert!(why(rebuilt(vec![key, earlier])).contains("increasing order"));
    assert!(rebuilt(vec![key]).is_ok());
    // A path emptied through the public field after Scene::new: every render function says so.
    let mut emptied = scene.clone();
    emptied.path.keys.clear();
    for r in renders(&emptied) {
        assert!(matches!(r, Err(SceneError::BadPath { .. })), "{r:?}");
    }
}
