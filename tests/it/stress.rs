//! Issue 5's stress cases, at sizes that fit CI (`examples/stress.rs` runs
//! them full size and reports time and peak memory in
//! `docs/robustness.md`): many primitives, a CSG chain 10,000 levels deep,
//! a 4096×4096 image, and `max_depth` 64 in halls of mirrors. Each must
//! finish with the right picture (cells equal to Roth) and bounded memory,
//! or be refused with a clear message.

use std::process::Command;

use hypercast::cells::SegmentChoice;
use hypercast::r#gen::stress::{Chain, deep_chain, mirror_hall, sphere_lattice};
use hypercast::reference::RothTracer;
use hypercast::trace::{CameraFrame, MIN_WEIGHT, RayJob, RayKind, Shader, Tracer};

use crate::cells::assert_renders_equal_with;
use crate::util;

const BIN: &str = env!("CARGO_BIN_EXE_hypercast");

/// 20,000 primitives (100,000 in the experiment): the subdivision stays
/// linear in the primitives (at most 16 n + 64 super cells per region,
/// bytes per primitive bounded) and renders what Roth renders.
#[test]
fn stress_many_primitives() {
    let n = 20_000;
    let scene = util::scene(&sphere_lattice(n, 48, 36));
    assert_eq!(scene.primitives.len(), n);
    let (_, structures) = assert_renders_equal_with(&scene, 48, 36, &[SegmentChoice::Sampled]);
    let s = &structures[0].stats;
    assert!(
        s.super_cells <= 2 * (16 * n + 64),
        "{} super cells",
        s.super_cells
    );
    // A few hundred bytes per primitive, not a table per pixel or per pair.
    assert!(
        s.bytes <= 2000 * n,
        "{} structure bytes for {n} primitives",
        s.bytes
    );
}

/// A chain 10,000 operators deep, left-deep (differences) and right-deep
/// (unions): loading, Algorithm 1's boxes, Algorithm 3's subtrees and the
/// evaluator all walk it without recursion, so render threads with
/// ordinary 2 MiB stacks finish, with cells equal to Roth. The real binary
/// renders it too (a stack overflow would abort it).
#[test]
fn stress_csg_chain_ten_thousand_levels_deep() {
    let depth = 10_000;
    for chain in [Chain::LeftDifference, Chain::RightUnion] {
        let text = deep_chain(depth, chain, 32, 24);
        let scene = util::scene(&text);
        assert_eq!(scene.tree.nodes.len(), 2 * depth + 3, "{chain:?}");
        let boxes = scene.tree.minimal_boxes();
        assert_eq!(boxes.len(), scene.tree.nodes.len());
        let (film, _) = assert_renders_equal_with(&scene, 32, 24, &[SegmentChoice::Sampled]);
        assert!(
            film.sums().iter().any(|p| *p != film.sums()[0]),
            "{chain:?}: nothing drawn"
        );
        let tmp = tempfile::tempdir().unwrap();
        let file = tmp.path().join("chain.ron");
        std::fs::write(&file, &text).unwrap();
        let out = Command::new(BIN)
            .args([
                "render",
                file.to_str().unwrap(),
                "-o",
                "chain.png",
                "--quiet",
            ])
            .args(["--threads", "2"])
            .current_dir(tmp.path())
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{chain:?}: {:?}\n{}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(tmp.path().join("chain.png").is_file());
    }
}

/// A 4096×4096 image is rendered and written whole; sizes beyond the
/// limits are refused before any work, with the numbers.
#[test]
fn stress_4096_by_4096_output() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = util::repo("scenes/small/sphere.ron");
    let run = |extra: &[&str]| {
        Command::new(BIN)
            .args([
                "render",
                scene.to_str().unwrap(),
                "--quiet",
                "--threads",
                "2",
            ])
            .args(extra)
            .current_dir(tmp.path())
            .output()
            .unwrap()
    };
    let out = run(&["--width", "4096", "--height", "4096", "-o", "big.ppm"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let path = tmp.path().join("big.ppm");
    // A PPM (binary pixmap), not PAM, which the image crate also reads.
    let magic = std::fs::read(&path).unwrap()[..2].to_vec();
    assert_eq!(magic, b"P6");
    let img = image::open(&path).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (4096, 4096));
    // The sphere is in the middle, the corner is background.
    assert_ne!(img.get_pixel(2048, 2048), img.get_pixel(0, 0));
    for (w, h, says) in [
        ("65537", "2", "at most 65536 pixels per side"),
        ("20000", "20000", "at most 268435456 pixels"),
    ] {
        let out = run(&["--width", w, "--height", h, "-o", "huge.png"]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{err}");
        assert!(err.contains(says), "{err}");
        assert!(!tmp.path().join("huge.png").exists());
    }
}

/// `max_depth` 64 in a closed room of mirrors: paths go 64 bounces deep
/// (0.9^64 is above `MIN_WEIGHT`) and stop there, with exact ray counts.
/// With a glass ball in the room every ray that meets it splits in two,
/// 2^64 rays per pixel were it not for `MIN_WEIGHT`: generation by
/// generation, every spawned ray carries at least `MIN_WEIGHT`, the
/// weights sum to at most 1 (reflect + transmit ≤ 1 here), so a generation
/// holds fewer than `1 / MIN_WEIGHT` rays, and none is left after 64.
#[test]
fn stress_max_depth_64_in_a_hall_of_mirrors() {
    let (w, h) = (24u32, 16u32);
    let pixels = u64::from(w * h);
    let rendered = |glass: bool| {
        let scene = util::scene(&mirror_hall(64, glass, w, h));
        let (_, stats) = util::roth(&scene, w, h);
        let (film, _) = assert_renders_equal_with(&scene, w, h, &[SegmentChoice::Sampled]);
        util::assert_finite(&film);
        (scene, stats)
    };
    // Nothing but mirrors: every hit reflects and sees the light, so the
    // counts are exact.
    let (_, hall) = rendered(false);
    assert_eq!(hall.rays.get(RayKind::Reflected), 64 * pixels);
    assert_eq!(hall.rays.get(RayKind::Shadow), 65 * pixels);
    let (scene, glass) = rendered(true);
    assert!(
        glass.rays.get(RayKind::Refracted) > pixels,
        "the glass is seen"
    );
    // Each pixel's ray tree, generation by generation.
    let shader = Shader::new(&scene);
    let cam = CameraFrame::new(&scene, w, h);
    let mut roth = RothTracer::new(&scene);
    let mut widest = 0;
    for j in 0..h {
        for i in 0..w {
            let mut generation = vec![cam.primary(i, j, 0.5, 0.5, 1.0)];
            for depth in 0..=64 {
                let total: f64 = generation.iter().map(|r| r.weight().max_element()).sum();
                assert!(
                    total <= 1.0 + 1e-6,
                    "pixel ({i}, {j}) depth {depth}: {total}"
                );
                assert!((generation.len() as f64) < 1.0 / MIN_WEIGHT);
                widest = widest.max(generation.len());
                let mut next = Vec::new();
                for job in &generation {
                    let Some(hit) = roth.nearest(&job.ray, 0.0, job.t_max) else {
                        continue;
                    };
                    shader.shade(job, &hit, &mut |spawned: RayJob| {
                        if spawned.kind != RayKind::Shadow {
                            assert!(spawned.weight().max_element() >= MIN_WEIGHT);
                            next.push(spawned);
                        }
                    });
                }
                generation = next;
            }
            assert!(
                generation.is_empty(),
                "pixel ({i}, {j}): rays beyond max_depth"
            );
        }
    }
    // Mirror paths stay single; the glass makes a generation wider.
    assert!(widest > 1, "no ray ever split");
}
