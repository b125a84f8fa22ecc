//! Scene and topology files cut, garbled and shuffled, as a fuzzer of their
//! text would make them: every one loads with a one-line error that names
//! the file, or loads and renders (the cells as Roth, the machine as one
//! node), and none panics. The number mutants (`robustness`) change values
//! in files that stay well formed; these break the form itself.

use std::path::{Path, PathBuf};

use hypercast::machine::topology::parse_topology;
use hypercast::machine::{MachineOptions, Topology};
use hypercast::scene::{SceneSyntax, parse_scene_str};

use crate::cells::{assert_renders_equal, hunt_size, seeds};
use crate::csg_props::Rng;
use crate::util;

/// Bytes a garbling edit writes: the punctuation of RON, JSON and NFF, the
/// pieces of numbers, and letters that start keywords and units.
const GARBLE: &[u8] = b"()[]{},:;\"'#-+.0123456789eE \n\tabcfilnoprstvxyzBSTUMKi";

/// One random edit of `text`, described for a failure message. Edits keep
/// the text UTF-8 (the loaders take `&str`; reading a file that is not is
/// refused before them, `tests/data/bad/syntax_not_utf8.ron`): they work on
/// char boundaries.
fn garble(text: &str, rng: &mut Rng) -> (String, String) {
    if text.lines().next().is_none() {
        return (text.to_string(), "nothing left to garble".into());
    }
    let bounds: Vec<usize> = text
        .char_indices()
        .map(|(i, _)| i)
        .chain([text.len()])
        .collect();
    let at = |rng: &mut Rng| bounds[rng.below(bounds.len())];
    // A range of up to `max` chars from a random boundary.
    let span = |rng: &mut Rng, max: usize| {
        let i = rng.below(bounds.len());
        let j = (i + 1 + rng.below(max)).min(bounds.len() - 1);
        (bounds[i], bounds[j])
    };
    let mut out = text.to_string();
    let what = match rng.below(7) {
        0 => {
            let (a, b) = span(rng, 24);
            out.replace_range(a..b, "");
            format!("deleted {:?}", &text[a..b])
        }
        1 => {
            let (a, b) = span(rng, 60);
            let to = at(rng);
            out.insert_str(to, &text[a..b]);
            format!("copied {:?} to byte {to}", &text[a..b])
        }
        2 => {
            let (a, b) = span(rng, 1);
            let c = GARBLE[rng.below(GARBLE.len())] as char;
            out.replace_range(a..b, &c.to_string());
            format!("replaced {:?} at byte {a} by {c:?}", &text[a..b])
        }
        3 => {
            let a = at(rng);
            out.truncate(a);
            format!("cut at byte {a}")
        }
        4 => {
            let mut lines: Vec<&str> = text.lines().collect();
            let (i, j) = (rng.below(lines.len()), rng.below(lines.len()));
            lines.swap(i, j);
            out = lines.join("\n");
            format!("swapped lines {} and {}", i + 1, j + 1)
        }
        5 => {
            let mut lines: Vec<&str> = text.lines().collect();
            let i = rng.below(lines.len());
            let line = lines.remove(i);
            out = lines.join("\n");
            format!("deleted line {}: {line:?}", i + 1)
        }
        _ => {
            let mut lines: Vec<&str> = text.lines().collect();
            let (i, j) = (rng.below(lines.len()), rng.below(lines.len() + 1));
            lines.insert(j, lines[i]);
            out = lines.join("\n");
            format!("line {} copied before line {}", i + 1, j + 1)
        }
    };
    (out, what)
}

/// `text` with one to `max_edits` random edits, and what they were, for a
/// failure message.
fn garbled(
    seed: u64,
    text: &str,
    path: &Path,
    max_edits: usize,
    rng: &mut Rng,
) -> (String, String) {
    let mut garbled = text.to_string();
    let mut what = Vec::new();
    for _ in 0..1 + rng.below(max_edits) {
        let (g, w) = garble(&garbled, rng);
        garbled = g;
        what.push(w);
    }
    let what = format!("seed {seed}: {} with {}", path.display(), what.join("; "));
    (garbled, what)
}

/// What `load` makes of the garbled `text`: a value, or None after an error
/// that names the file on one line, as the CLI prints it; never a panic.
fn loaded<T>(
    what: &str,
    text: &str,
    file: &Path,
    load: impl FnOnce(&str) -> hypercast::error::Result<T>,
) -> Option<T> {
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| load(text)));
    match result {
        Err(_) => panic!("{what}: the loader panicked; the text:\n{text}"),
        Ok(Err(e)) => {
            let message = e.to_string();
            let name = file.file_name().unwrap().to_string_lossy();
            assert!(
                message.contains(name.as_ref()) && !message.trim_end().contains('\n'),
                "{what}: the error does not name {name} on one line:\n{message}"
            );
            None
        }
        Ok(Ok(value)) => Some(value),
    }
}

/// A scene file's path, syntax and text.
type SceneText = (PathBuf, SceneSyntax, String);

/// Every text the tests garble: the bundled scenes small enough to render
/// at once (the level-2 sphereflake for NFF), the example files of every
/// syntax, and the topologies.
fn sources() -> (Vec<SceneText>, Vec<(PathBuf, String)>) {
    let mut scenes = Vec::new();
    for dir in ["scenes", "scenes/small", "tests/data/good"] {
        for e in std::fs::read_dir(util::repo(dir)).unwrap().flatten() {
            let path = e.path();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            if name.starts_with("sphereflake") && name != "sphereflake2.nff" {
                continue;
            }
            let Ok(syntax) = SceneSyntax::from_path(&path) else {
                continue;
            };
            let text = std::fs::read_to_string(&path).unwrap();
            scenes.push((path, syntax, text));
        }
    }
    let topologies = std::fs::read_dir(util::repo("topology"))
        .unwrap()
        .flatten()
        .map(|e| {
            let path = e.path();
            let text = std::fs::read_to_string(&path).unwrap();
            (path, text)
        })
        .collect();
    (scenes, topologies)
}

/// The seed's random generator, apart from the number mutants' seeds.
fn rng_for(seed: u64) -> Rng {
    Rng((0x6A12_BB1E_D7E5_7000 ^ seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)) | 1)
}

/// 600 garbled scenes, a seed each, one to three edits: a one-line error
/// naming the file, or the cells render the scene as Roth does (12x9, the
/// mutants' size), and nothing panics. Hunts: `HYPERCAST_SEEDS=a..b`,
/// `HYPERCAST_SIZE=WxH`.
#[test]
fn garbled_scene_files_load_with_a_located_error_or_render_as_roth_does() {
    let (scenes, _) = sources();
    assert!(scenes.len() >= 12, "{} scenes", scenes.len());
    let syntaxes = [SceneSyntax::Ron, SceneSyntax::Json, SceneSyntax::Nff];
    for s in syntaxes {
        assert!(scenes.iter().any(|(_, x, _)| *x == s), "no {s:?} scene");
    }
    let (w, h) = hunt_size().unwrap_or((12, 9));
    let tries = seeds(0..600);
    let count = tries.clone().count();
    let (mut rendered, mut refused) = (0, 0);
    for seed in tries {
        let mut rng = rng_for(seed);
        let (path, syntax, text) = &scenes[rng.below(scenes.len())];
        let (garbled, what) = garbled(seed, text, path, 3, &mut rng);
        let Some(scene) = loaded(&what, &garbled, path, |t| parse_scene_str(t, *syntax, path))
        else {
            refused += 1;
            continue;
        };
        rendered += 1;
        if std::panic::catch_unwind(|| assert_renders_equal(&scene, w, h)).is_err() {
            panic!("{what}: the accelerators differ (above); the text:\n{garbled}");
        }
    }
    // Both outcomes occur, or the garbling tests nothing.
    assert!(
        count < 600 || rendered >= 30 && refused >= 300,
        "{rendered} rendered, {refused} refused"
    );
}

/// 300 garbled topologies: a one-line error naming the file, or the machine
/// renders a small scene on the topology (at most 8 nodes, so that the test
/// stays short; the memory the file gives, unless too small for the
/// scene, which must then be refused before rendering) with the single
/// node's picture, and nothing panics.
#[test]
fn garbled_topology_files_load_with_a_located_error_or_render_the_single_node_image() {
    let (_, topologies) = sources();
    assert!(topologies.len() >= 3);
    let scene =
        util::scene(&std::fs::read_to_string(util::repo("scenes/small/shadow.ron")).unwrap());
    let opts = MachineOptions::new(8, 6, 1);
    let one = Topology::ipsc_d5()
        .with_overrides(Some(0), Some(64 << 20))
        .unwrap();
    let (single, _, _) = hypercast::machine::render(&scene, &one, &opts, &|_| {}).unwrap();
    let tries = seeds(0..300);
    let count = tries.clone().count();
    let (mut rendered, mut refused) = (0, 0);
    for seed in tries {
        let mut rng = rng_for(seed ^ 0x7070);
        let (path, text) = &topologies[rng.below(topologies.len())];
        let (garbled, what) = garbled(seed, text, path, 2, &mut rng);
        let Some(topo) = loaded(&what, &garbled, path, |t| parse_topology(t, path)) else {
            refused += 1;
            continue;
        };
        rendered += 1;
        let d = topo.dimension.min(3);
        let topo = topo
            .with_overrides(Some(d), None)
            .unwrap_or_else(|e| panic!("{what}: d = {d} refused: {e}"));
        let run =
            std::panic::catch_unwind(|| hypercast::machine::render(&scene, &topo, &opts, &|_| {}));
        match run {
            Err(_) => panic!("{what}: the machine panicked; the text:\n{garbled}"),
            Ok(Err(e)) => {
                // Only a share too large for the file's memory may stop it.
                let m = e.to_string();
                assert!(m.contains("budget"), "{what}: {m}");
            }
            Ok(Ok((film, _, _))) => {
                assert_eq!(film.sums(), single.sums(), "{what}: d = {d} differs")
            }
        }
    }
    assert!(
        count < 300 || rendered >= 20 && refused >= 100,
        "{rendered} rendered, {refused} refused"
    );
}
