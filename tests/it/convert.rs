//! `hypercast gen` and `hypercast convert` through the real binary: the NFF
//! round trip of issue 6 (every `scenes/*.nff` renders identically to its
//! `.ron` translation), generated scenes that load with the counts their
//! descriptions promise, and refusals: exit 2, one line naming what and
//! where, nothing written.

use std::path::Path;

use hypercast::scene::load_scene;

use crate::cli::{check_refusal, files_in, path_str, run, stderr};
use crate::util::{cells, repo};

/// Runs the binary in `dir` and insists on success.
fn ok(dir: &Path, args: &[&str]) {
    let o = run(dir, args);
    assert!(
        o.status.success(),
        "hypercast {} failed: {}",
        args.join(" "),
        stderr(&o)
    );
}

#[test]
fn every_bundled_nff_renders_identically_to_its_ron_translation() {
    let tmp = tempfile::tempdir().unwrap();
    let mut seen = 0;
    for nff in files_in(&repo("scenes")) {
        if nff.extension().and_then(|e| e.to_str()) != Some("nff") {
            continue;
        }
        seen += 1;
        let ron = tmp
            .path()
            .join(nff.file_stem().unwrap())
            .with_extension("ron");
        ok(
            tmp.path(),
            &["convert", path_str(&nff), "-o", path_str(&ron), "-q"],
        );
        let a = load_scene(&nff).unwrap_or_else(|e| panic!("{e}"));
        let b = load_scene(&ron).unwrap_or_else(|e| panic!("{e}"));
        let (w, h) = (64, 64 * a.camera.height / a.camera.width);
        let (fa, _) = cells(&a, w, h);
        let (fb, _) = cells(&b, w, h);
        assert!(
            fa.sums() == fb.sums(),
            "{}: the NFF and its RON translation render differently",
            nff.display()
        );
        // The picture is not blank: the comparison means something.
        assert!(fa.sums().iter().any(|s| *s != fa.sums()[0]));
    }
    assert!(
        seen >= 3,
        "expected the bundled sphereflakes, found {seen} NFF files"
    );
}

#[test]
fn generated_scenes_load_with_their_promised_counts() {
    let tmp = tempfile::tempdir().unwrap();
    let cases: [(&[&str], &str, usize); 5] = [
        // (9^3 − 1)/8 spheres and the floor.
        (&["sphereflake", "--level", "2"], "flake.nff", 92),
        // 5 + 10 rings of 30 spheres and 30 cylinders, and the floor.
        (&["rings", "--size", "2"], "rings.json", 15 * 60 + 1),
        // 200 cuts and additions, the ball, the pedestal and the floor.
        (&["jagged-ball"], "jagged.ron", 203),
        (
            &["jagged-ball", "--points", "10", "--seed", "3"],
            "small_jagged.json",
            13,
        ),
        (
            &["random-csg", "--seed", "7", "--primitives", "25"],
            "random.ron",
            25,
        ),
    ];
    for (args, file, count) in cases {
        let out = tmp.path().join(file);
        let mut full = vec!["gen"];
        full.extend_from_slice(args);
        full.extend_from_slice(&["-o", path_str(&out), "--quiet"]);
        ok(tmp.path(), &full);
        let scene = load_scene(&out).unwrap_or_else(|e| panic!("{file}: {e}"));
        assert_eq!(scene.primitives.len(), count, "{file}");
    }
}

#[test]
fn what_cannot_be_written_is_refused_by_name_and_nothing_is_left() {
    let jagged = repo("scenes/jagged_ball.ron");
    let jagged = path_str(&jagged);
    let sphere = repo("scenes/small/sphere.ron");
    let sphere = path_str(&sphere);
    let cases: [(&[&str], &str); 6] = [
        (
            &["convert", jagged, "-o", "jagged.nff"],
            "jagged_ball.ron: objects[0].Union.children[0]: NFF has no CSG: a Difference",
        ),
        (
            &["gen", "jagged-ball", "-o", "jagged.nff"],
            "jagged ball seed 1987: objects[0].Union.children[0]: NFF has no CSG",
        ),
        (&["convert", sphere, "-o", "out.txt"], "unknown output type"),
        (
            &["convert", sphere, "-o", "no/such/folder/out.pov"],
            "no/such/folder",
        ),
        (
            &["gen", "rings", "-o", "rings.png"],
            "unknown scene file type",
        ),
        (
            &[
                "gen",
                "sphereflake",
                "--level",
                "2",
                "-o",
                "no/such/folder/f.nff",
            ],
            "no/such/folder",
        ),
    ];
    let mut problems = Vec::new();
    for (args, want) in cases {
        let tmp = tempfile::tempdir().unwrap();
        problems.extend(check_refusal(tmp.path(), args, want));
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// `convert` reads scenes exactly as `render` does: every bad scene of
/// `tests/data/bad` is refused with the message `EXPECTED.tsv` gives.
#[test]
fn bad_scenes_are_refused_by_convert_as_by_render() {
    let bad = repo("tests/data/bad");
    let table = std::fs::read_to_string(bad.join("EXPECTED.tsv")).expect("EXPECTED.tsv");
    let mut problems = Vec::new();
    for line in table
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
    {
        let (file, want) = line.split_once('\t').expect("a tab");
        let tmp = tempfile::tempdir().unwrap();
        let path = bad.join(file);
        problems.extend(check_refusal(
            tmp.path(),
            &["convert", path_str(&path), "-o", "out.pov"],
            want,
        ));
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn pov_export_of_every_bundled_scene_is_written() {
    let tmp = tempfile::tempdir().unwrap();
    for dir in ["scenes", "scenes/small"] {
        for scene in files_in(&repo(dir)) {
            if scene.is_dir() {
                continue;
            }
            let out = tmp.path().join("out.pov");
            ok(
                tmp.path(),
                &["convert", path_str(&scene), "-o", "out.pov", "-q"],
            );
            let text = std::fs::read_to_string(&out).unwrap();
            assert!(
                text.contains("#version 3.7;") && text.contains("camera {"),
                "{text}"
            );
        }
    }
}

/// Random CSG models (every primitive, operator, transform and material
/// the generator makes; cameras inside and outside) are written as RON and
/// as JSON and read back as the same model, to the last bit of every
/// number: `convert` between the two loses nothing. 300 seeds; hunts:
/// `HYPERCAST_SEEDS=a..b`.
#[test]
fn random_csg_models_round_trip_through_ron_and_json_exactly() {
    use hypercast::r#gen::random::{RandomCsgOptions, random_csg};
    use hypercast::scene::SceneSyntax;
    use hypercast::scene::load::{parse_model_str, scene_to_string};
    let opts = RandomCsgOptions::default();
    for seed in crate::cells::seeds(0..300) {
        let model = random_csg(seed, 1 + (seed % 60) as usize, &opts);
        for syntax in [SceneSyntax::Ron, SceneSyntax::Json] {
            let text = scene_to_string(&model, syntax)
                .unwrap_or_else(|e| panic!("seed {seed}: {syntax:?} refused: {e}"));
            let again = parse_model_str(&text, syntax, Path::new("again"))
                .unwrap_or_else(|e| panic!("seed {seed}: {syntax:?} not read back: {e}\n{text}"));
            assert_eq!(
                model, again,
                "seed {seed}: {syntax:?} changed the model:\n{text}"
            );
        }
    }
}

/// A tree deeper than indentation can follow: 34,000 levels load from RON
/// (`scene::load::MAX_NESTING`), and were written indented level by level.
/// The POV writer then asked `format!` for an indentation beyond its limit
/// and panicked; the RON and JSON writers ran out of memory on billions of
/// spaces. Now each indents the first levels only, RON reads back to the
/// same model, and JSON, which loads fewer levels, is refused by name.
#[test]
fn a_tree_thousands_of_levels_deep_converts_in_linear_size() {
    const LEVELS: usize = 34_000;
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("deep.ron");
    let text = format!(
        "(camera: (eye: (0, -5, 0), look_at: (0, 0, 0), fov_y: 45, width: 8, height: 6), \
         lights: [(position: (2, -2, 2), color: (1, 1, 1))], objects: [{}Sphere(center: \
         (0, 0, 0), radius: 0.5){}])",
        "Difference(children: [Sphere(center: (0, 0, 0), radius: 1), ".repeat(LEVELS),
        "])".repeat(LEVELS)
    );
    std::fs::write(&scene, text).unwrap();
    for (out, bytes_per_level) in [("deep.pov", 500), ("back.ron", 200)] {
        ok(tmp.path(), &["convert", "deep.ron", "-o", out, "-q"]);
        let written = std::fs::metadata(tmp.path().join(out)).unwrap().len();
        assert!(
            written < (bytes_per_level * LEVELS) as u64,
            "{out}: {written} bytes for {LEVELS} levels"
        );
    }
    // Compared and dropped on a stack as deep as the loader's: both recurse
    // through the tree.
    let dir = tmp.path().to_owned();
    let same = std::thread::Builder::new()
        .stack_size(hypercast::scene::load::LOAD_STACK_BYTES)
        .spawn(move || {
            let read = |p: &str| {
                let text = std::fs::read_to_string(dir.join(p)).unwrap();
                let syntax = hypercast::scene::SceneSyntax::Ron;
                hypercast::scene::load::parse_model_str(&text, syntax, p.as_ref()).unwrap()
            };
            read("deep.ron") == read("back.ron")
        })
        .unwrap()
        .join()
        .unwrap();
    assert!(same, "RON round trip");
    let empty = tempfile::tempdir().unwrap();
    let problems = check_refusal(
        empty.path(),
        &["convert", path_str(&scene), "-o", "deep.json"],
        "deep.ron: objects: JSON cannot hold this tree",
    );
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
