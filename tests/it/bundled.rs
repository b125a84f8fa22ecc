//! Every bundled scene: it loads, renders finite pixels, and the paper's
//! cells give exactly the image of Roth's brute force (issue 3's first
//! acceptance criterion; `DESIGN.md`'s first invariant).

use hypercast::scene::load_scene;

use crate::util::{cells, differing, repo, roth};

fn bundled() -> Vec<std::path::PathBuf> {
    let mut v = Vec::new();
    for dir in ["scenes", "scenes/small"] {
        for e in std::fs::read_dir(repo(dir)).expect("scenes folder") {
            let p = e.expect("dir entry").path();
            if matches!(
                p.extension().and_then(|e| e.to_str()),
                Some("ron" | "json" | "nff")
            ) {
                v.push(p);
            }
        }
    }
    v.sort();
    assert!(v.len() >= 10, "expected the bundled scenes, found {v:?}");
    v
}

#[test]
fn every_bundled_scene_renders_identically_with_cells_and_roth() {
    for path in bundled() {
        let scene = load_scene(&path).unwrap_or_else(|e| panic!("{e}"));
        // Small, with the scene's own aspect ratio, so the debug build stays quick.
        let (w, h) = (96, (96 * scene.camera.height / scene.camera.width).max(1));
        let (a, _) = roth(&scene, w, h);
        let (b, _) = cells(&scene, w, h);
        let diff = differing(&a, &b);
        assert_eq!(
            diff,
            0,
            "{}: {diff} of {} pixels differ between cells and roth",
            path.display(),
            w * h
        );
    }
}
