//! The real binary (`CLI.md`): exit codes, one-line errors without panics,
//! nothing written on failure, images and statistics on success.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use crate::util;

const BIN: &str = env!("CARGO_BIN_EXE_hypercast");

/// Runs `hypercast` in `dir` (a fresh temporary folder, so "no file left"
/// is checkable), with the environment that would make a panic talk.
pub(crate) fn run(dir: &Path, args: &[&str]) -> Output {
    Command::new(BIN)
        .args(args)
        .current_dir(dir)
        .env("RUST_BACKTRACE", "1")
        .output()
        .expect("the binary runs")
}

pub(crate) fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

pub(crate) fn files_in(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    v.sort();
    v
}

pub(crate) fn path_str(p: &Path) -> &str {
    p.to_str().expect("UTF-8 path")
}

/// What every refusal must look like: exit 2, one line on stderr naming
/// the problem, no panic, nothing written. Returns the problems found.
pub(crate) fn check_refusal(dir: &Path, args: &[&str], expected: &str) -> Vec<String> {
    check_failure(dir, args, &run(dir, args), 2, expected)
}

/// `check_refusal` of a run already made, with exit status `code`.
fn check_failure(dir: &Path, args: &[&str], o: &Output, code: i32, expected: &str) -> Vec<String> {
    let err = stderr(o);
    let mut problems = Vec::new();
    if o.status.code() != Some(code) {
        problems.push(format!("exit status {:?}, want {code}", o.status.code()));
    }
    if err.trim_end_matches('\n').contains('\n') || err.is_empty() {
        problems.push("stderr is not exactly one line".into());
    }
    if !err.contains(expected) {
        problems.push(format!("stderr lacks {expected:?}"));
    }
    if err.contains("panicked") || err.contains("RUST_BACKTRACE") {
        problems.push("a panic".into());
    }
    let left = files_in(dir);
    if !left.is_empty() {
        problems.push(format!("files left behind: {left:?}"));
    }
    if problems.is_empty() {
        return problems;
    }
    vec![format!(
        "hypercast {}: {}\n  stderr: {err}",
        args.join(" "),
        problems.join("; ")
    )]
}

/// Every file of `tests/data/bad/` is refused as `EXPECTED.tsv` says, and
/// the table and the folder list the same files.
#[test]
fn bad_scenes_are_refused_with_one_line_and_no_output() {
    let bad = util::repo("tests/data/bad");
    let table = std::fs::read_to_string(bad.join("EXPECTED.tsv")).expect("EXPECTED.tsv");
    let expected: Vec<(&str, &str)> = table
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .map(|l| {
            l.split_once('\t')
                .unwrap_or_else(|| panic!("EXPECTED.tsv line without a tab: {l:?}"))
        })
        .collect();
    let mut problems = Vec::new();
    let mut files = 0;
    for path in files_in(&bad) {
        let name = path.file_name().unwrap().to_str().unwrap();
        if name == "EXPECTED.tsv" {
            continue;
        }
        files += 1;
        let Some((_, want)) = expected.iter().find(|(f, _)| *f == name) else {
            problems.push(format!("{name}: not in EXPECTED.tsv"));
            continue;
        };
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("out.png");
        problems.extend(check_refusal(
            tmp.path(),
            &["render", path_str(&path), "-o", path_str(&out)],
            want,
        ));
    }
    for (f, _) in &expected {
        if !bad.join(f).exists() {
            problems.push(format!("EXPECTED.tsv names {f}, which does not exist"));
        }
    }
    assert!(files >= 20, "only {files} bad scenes");
    assert!(
        problems.is_empty(),
        "{} problems:\n{}",
        problems.len(),
        problems.join("\n")
    );
}

#[test]
fn bad_options_are_refused_before_rendering() {
    let sphere = util::repo("scenes/small/sphere.ron");
    let sphere = path_str(&sphere);
    let mut problems = Vec::new();
    // A link capacity near 2^64 panicked in crossbeam ("bounded channel
    // capacity is too large"); 10^9 aborted allocating its slots.
    let huge = u64::MAX.to_string();
    let cases: [(&[&str], &str); 8] = [
        (&["-o", "x.jpg"], "x.jpg"),
        (&["-o", "out.png", "--width", "0"], "0x48"),
        (&["-o", "out.png", "--height", "0"], "64x0"),
        (&["-o", "out.png", "--spp", "0"], "--spp"),
        (&["-o", "no/such/folder/out.png"], "no/such/folder"),
        (
            &["-o", "out.png", "--link-capacity", "0"],
            "--link-capacity",
        ),
        (
            &["-o", "out.png", "--link-capacity", &huge],
            "--link-capacity",
        ),
        (
            &["-o", "out.png", "--link-capacity", "1000000000"],
            "--link-capacity must be in 1..=1024, got 1000000000",
        ),
    ];
    for (extra, want) in cases {
        let tmp = tempfile::tempdir().unwrap();
        let mut args = vec!["render", sphere];
        args.extend_from_slice(extra);
        problems.extend(check_refusal(tmp.path(), &args, want));
    }
    // The output is checked before the scene is even read: a bad scene with
    // a bad output name reports the output.
    let tmp = tempfile::tempdir().unwrap();
    let bad = util::repo("tests/data/bad/negative_radius.ron");
    problems.extend(check_refusal(
        tmp.path(),
        &["render", path_str(&bad), "-o", "x.jpg"],
        "x.jpg",
    ));
    // A scene that does not exist is named.
    let tmp = tempfile::tempdir().unwrap();
    problems.extend(check_refusal(
        tmp.path(),
        &["render", "missing.ron", "-o", "out.png"],
        "missing.ron",
    ));
    assert!(
        problems.is_empty(),
        "{} problems:\n{}",
        problems.len(),
        problems.join("\n")
    );
}

/// How long `run_bounded` waits: the refusals it runs take milliseconds.
const BOUND_SECONDS: u64 = 30;

/// Runs `hypercast` as `run` does, within 2 GiB of address space (the
/// scene loader reserves a 1 GiB stack) and `BOUND_SECONDS`, so that an
/// input read without bound fails the test and spares the host:
/// `/dev/zero` read whole filled memory, and a named pipe waited for a
/// writer for ever.
fn run_bounded(dir: &Path, args: &[&str]) -> Result<Output, String> {
    let mut child = Command::new("sh")
        .arg("-c")
        .arg("ulimit -v 2097152 && exec \"$0\" \"$@\"")
        .arg(BIN)
        .args(args)
        .current_dir(dir)
        .env("RUST_BACKTRACE", "1")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("sh runs the binary");
    let deadline = Instant::now() + Duration::from_secs(BOUND_SECONDS);
    while child
        .try_wait()
        .expect("the binary is waited for")
        .is_none()
    {
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            return Err(format!(
                "hypercast {}: still running after {BOUND_SECONDS} s",
                args.join(" ")
            ));
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    Ok(child.wait_with_output().expect("the binary's output"))
}

/// Audit: a scene, topology or reference image that is not a regular file
/// was read without a bound: `/dev/zero` (here through a link with the
/// scene's extension) until memory ran out, a named pipe not at all, as
/// the run waited for a writer. Each is refused at once, naming the path
/// and what it is; so is a file above the 1 GiB limit (sparse: nothing is
/// written).
#[test]
fn inputs_that_are_not_regular_files_or_too_large_are_refused_at_once() {
    let inputs = tempfile::tempdir().unwrap();
    let at = |name: &str| path_str(&inputs.path().join(name)).to_owned();
    for ext in ["ron", "png"] {
        std::fs::create_dir(at(&format!("folder.{ext}"))).unwrap();
        std::os::unix::fs::symlink("/dev/zero", at(&format!("zero.{ext}"))).unwrap();
        let made = Command::new("mkfifo")
            .arg(at(&format!("pipe.{ext}")))
            .status()
            .expect("mkfifo runs");
        assert!(made.success(), "mkfifo");
    }
    let limit = hypercast::input::MAX_INPUT_BYTES;
    std::fs::File::create(at("big.ron"))
        .unwrap()
        .set_len(limit + 1)
        .unwrap();
    let sphere = util::repo("scenes/small/sphere.ron");
    let sphere = path_str(&sphere);
    let what = [
        ("folder", "is a folder, not a regular file"),
        ("zero", "is a character device, not a regular file"),
        ("pipe", "is a named pipe, not a regular file"),
    ];
    let mut cases: Vec<(Vec<String>, String)> = Vec::new();
    let args = |a: &[&str]| a.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    for (name, why) in what {
        let (ron, png) = (at(&format!("{name}.ron")), at(&format!("{name}.png")));
        let want = |p: &str| format!("{p}: cannot read: {why}");
        cases.push((args(&["render", &ron, "-o", "out.png"]), want(&ron)));
        cases.push((args(&["convert", &ron, "-o", "out.json"]), want(&ron)));
        cases.push((
            args(&["render", sphere, "-o", "out.png", "--topology", &ron]),
            want(&ron),
        ));
        cases.push((
            args(&["render", sphere, "-o", "out.png", "--reference", &png]),
            want(&png),
        ));
    }
    let big = at("big.ron");
    cases.push((
        args(&["render", &big, "-o", "out.png"]),
        format!(
            "{big}: cannot read: is {} bytes, more than the 1 GiB an input file may be",
            limit + 1
        ),
    ));
    let mut problems = Vec::new();
    for (args, want) in &cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let tmp = tempfile::tempdir().unwrap();
        match run_bounded(tmp.path(), &args) {
            Ok(o) => problems.extend(check_failure(tmp.path(), &args, &o, 2, want)),
            Err(e) => problems.push(e),
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// Audit: a thread the OS refused to start was a panic
/// (`std::thread::Scope::spawn`): the render threads of `--accel roth`,
/// then the mapping's pre-pass, which the default render (cells on the
/// modelled machine), `inspect` and `scale` all run, and the build's
/// depth cuts on a large scene (`cells::PARALLEL_CUT_PRIMS`; on a host
/// of two cores or more, else the pre-pass is refused). It is a failed
/// run now: exit 1, one line naming the thread, no image, statistics or
/// folder, nothing on stdout. The OS refuses for real here: every thread
/// started without a stack size of its own (the scene loader and the
/// machine's nodes set theirs) asks for a stack larger than any address
/// space (`RUST_MIN_STACK`, 2^62 bytes).
#[test]
fn a_thread_the_os_refuses_is_a_failed_run_not_a_panic() {
    let sphere = util::repo("scenes/small/sphere.ron");
    let sphere = path_str(&sphere);
    let flake = util::repo("scenes/sphereflake4.nff");
    let flake = path_str(&flake);
    let cut = match std::thread::available_parallelism().map_or(1, |n| n.get()) {
        1 => "hypercast: error: cannot start pre-pass thread 1 of 1: ",
        _ => "hypercast: error: cannot start cell build thread 1 of ",
    };
    let size = ["--width", "40", "--height", "30"];
    let cases: [(&[&str], &str); 5] = [
        (
            &[
                "render",
                sphere,
                "-o",
                "out.png",
                "--accel",
                "roth",
                "--threads",
                "2",
            ],
            "hypercast: error: cannot start render thread 1 of 2: ",
        ),
        (
            &["render", sphere, "-o", "out.png"],
            "hypercast: error: cannot start pre-pass thread 1 of ",
        ),
        (
            &["inspect", sphere, "--stats", "stats.json"],
            "hypercast: error: cannot start pre-pass thread 1 of ",
        ),
        (
            &["scale", sphere, "--dims", "0..1", "--out", "out"],
            "hypercast: error: at d = 0: cannot start pre-pass thread 1 of ",
        ),
        (&["render", flake, "-o", "out.png"], cut),
    ];
    let mut problems = Vec::new();
    for (args, want) in cases {
        let tmp = tempfile::tempdir().unwrap();
        let args = [args, &size[..]].concat();
        let o = Command::new(BIN)
            .args(&args)
            .current_dir(tmp.path())
            .env("RUST_BACKTRACE", "1")
            .env("RUST_MIN_STACK", (1u64 << 62).to_string())
            .output()
            .expect("the binary runs");
        problems.extend(check_failure(tmp.path(), &args, &o, 1, want));
        // Nor half a report: `inspect` and `scale` print theirs only
        // once the plan is made.
        if !o.stdout.is_empty() {
            problems.push(format!("hypercast {}: printed on stdout", args.join(" ")));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// An output that would replace an input, or another output, is refused
/// before anything is read or written: `convert` onto its own scene would
/// rewrite it without its comments, `--stats` onto the scene would replace
/// it, the image onto its reference would lose it. So is an output that
/// names a folder (it failed only after the render). Every file is left as
/// it was, and no other appears.
#[test]
fn outputs_that_would_replace_an_input_or_each_other_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    std::fs::copy(util::repo("scenes/small/sphere.ron"), dir.join("s.ron")).unwrap();
    std::fs::create_dir(dir.join("folder.png")).unwrap();
    assert!(
        render_ok(dir, "ref.png", &[]).status.success(),
        "the reference renders"
    );
    #[cfg(unix)]
    std::os::unix::fs::symlink("s.ron", dir.join("link.ron")).unwrap();
    let before: Vec<(PathBuf, Vec<u8>)> = files_in(dir)
        .into_iter()
        .filter(|p| p.is_file())
        .map(|p| {
            let bytes = std::fs::read(&p).unwrap();
            (p, bytes)
        })
        .collect();
    let cases: [(&[&str], &str); 9] = [
        (
            &["convert", "s.ron", "-o", "s.ron"],
            "would replace the scene",
        ),
        (
            &["convert", "s.ron", "-o", "./s.ron"],
            "would replace the scene",
        ),
        (
            &["convert", "s.ron", "-o", "link.ron"],
            "would replace the scene",
        ),
        (
            &["convert", "link.ron", "-o", "s.ron"],
            "would replace the scene",
        ),
        (
            &["render", "s.ron", "-o", "x.png", "--stats", "s.ron"],
            "statistics would replace the scene",
        ),
        (
            &["render", "s.ron", "-o", "x.png", "--stats", "x.png"],
            "would replace the image",
        ),
        (
            &["render", "s.ron", "-o", "ref.png", "--reference", "ref.png"],
            "would replace the reference",
        ),
        (
            &["inspect", "s.ron", "--overlay", "x.png", "--stats", "x.png"],
            "would replace the overlay",
        ),
        (&["render", "s.ron", "-o", "folder.png"], "is a folder"),
    ];
    let mut problems = Vec::new();
    for (args, want) in cases {
        let o = run(dir, args);
        let err = stderr(&o);
        let mut wrong = Vec::new();
        if o.status.code() != Some(2) {
            wrong.push(format!("exit status {:?}, want 2", o.status.code()));
        }
        if err.trim_end_matches('\n').contains('\n') || !err.contains(want) {
            wrong.push(format!("stderr is not one line with {want:?}"));
        }
        let now: Vec<PathBuf> = files_in(dir).into_iter().filter(|p| p.is_file()).collect();
        if now.len() != before.len() {
            wrong.push(format!("files now: {now:?}"));
        }
        for (p, bytes) in &before {
            if std::fs::read(p).ok().as_ref() != Some(bytes) {
                wrong.push(format!("{} changed", p.display()));
            }
        }
        if !wrong.is_empty() {
            problems.push(format!(
                "hypercast {}: {}\n  stderr: {err}",
                args.join(" "),
                wrong.join("; ")
            ));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// Renders `scenes/small/sphere.ron` at 40x30 into `dir/name`.
pub fn render_ok(dir: &Path, name: &str, extra: &[&str]) -> Output {
    let sphere = util::repo("scenes/small/sphere.ron");
    let mut args = vec![
        "render",
        path_str(&sphere),
        "-o",
        name,
        "--width",
        "40",
        "--height",
        "30",
        "--threads",
        "2",
    ];
    args.extend_from_slice(extra);
    let o = run(dir, &args);
    assert_eq!(
        o.status.code(),
        Some(0),
        "hypercast {}: {}",
        args.join(" "),
        stderr(&o)
    );
    o
}

/// Good renders, both accelerators and all three formats: exit 0, a
/// decodable image of the asked size, the same pixels as the library's
/// render (PNG: the 8-bit sRGB encoding; EXR: linear, exact).
#[test]
fn good_renders_write_decodable_images_of_the_right_size() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = hypercast::scene::load_scene(&util::repo("scenes/small/sphere.ron")).unwrap();
    let (film, _) = util::roth(&scene, 40, 30);
    let linear = film.to_linear();
    let srgb8 = hypercast::report::image_io::to_srgb8(&linear);
    for accel in ["roth", "cells"] {
        for ext in ["png", "ppm", "exr"] {
            let name = format!("{accel}.{ext}");
            render_ok(tmp.path(), &name, &["--accel", accel, "--quiet"]);
            let img = image::open(tmp.path().join(&name)).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!((img.width(), img.height()), (40, 30), "{name}");
            if ext == "exr" {
                let px: Vec<f32> = img.to_rgb32f().into_raw();
                let want: Vec<f32> = linear.iter().flatten().copied().collect();
                assert!(
                    px == want,
                    "{name}: linear pixels differ from the library's render"
                );
            } else {
                assert!(
                    img.to_rgb8().into_raw() == srgb8,
                    "{name}: pixels differ from the library's render"
                );
            }
        }
    }
    // Written atomically: no temporary file remains.
    let left: Vec<PathBuf> = files_in(tmp.path());
    assert_eq!(left.len(), 6, "{left:?}");
}

#[test]
fn stats_json_has_the_keys_of_cli_md() {
    let tmp = tempfile::tempdir().unwrap();
    for accel in ["roth", "cells"] {
        let json = format!("{accel}.json");
        render_ok(
            tmp.path(),
            "out.png",
            &["--accel", accel, "--stats", &json, "--quiet"],
        );
        let text = std::fs::read_to_string(tmp.path().join(&json)).unwrap();
        let v: serde_json::Value =
            serde_json::from_str(&text).unwrap_or_else(|e| panic!("{json}: {e}\n{text}"));
        let scene = v["scene"]
            .as_str()
            .unwrap_or_else(|| panic!("scene: {text}"));
        assert!(scene.ends_with("sphere.ron"), "{scene}");
        assert_eq!(v["width"], 40);
        assert_eq!(v["height"], 30);
        assert_eq!(v["accel"], accel);
        for kind in ["primary", "shadow", "reflected", "refracted"] {
            assert!(v["rays"][kind].is_u64(), "rays.{kind} in {text}");
        }
        for key in ["intersection_tests", "pixels_traced", "pixels_background"] {
            assert!(v[key].is_u64(), "{key} in {text}");
        }
        let wall = v["wall_seconds"]
            .as_f64()
            .unwrap_or_else(|| panic!("wall_seconds in {text}"));
        assert!(wall >= 0.0);
        let (traced, bg) = (
            v["pixels_traced"].as_u64().unwrap(),
            v["pixels_background"].as_u64().unwrap(),
        );
        assert_eq!(traced + bg, 40 * 30, "every pixel is traced or background");
        assert!(v["rays"]["primary"].as_u64().unwrap() >= traced);
        assert!(
            v["rays"]["shadow"].as_u64().unwrap() > 0,
            "the sphere is lit"
        );
        assert_eq!(v["rays"]["reflected"], 0, "nothing reflects in sphere.ron");
        assert!(v["intersection_tests"].as_u64().unwrap() > 0);
    }
}

/// Parses `rmse X  psnr Y dB ...` from stdout.
pub fn metrics(o: &Output) -> (f64, String) {
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    let words: Vec<&str> = out.split_whitespace().collect();
    let after = |k: &str| {
        let i = words
            .iter()
            .position(|w| *w == k)
            .unwrap_or_else(|| panic!("no {k} in {out:?}"));
        words[i + 1].to_string()
    };
    (after("rmse").parse().unwrap(), after("psnr"))
}

/// `--reference` against a linear EXR of the same render: no error at all.
#[test]
fn reference_exr_of_the_same_render_has_zero_error() {
    let tmp = tempfile::tempdir().unwrap();
    render_ok(tmp.path(), "ref.exr", &["--accel", "roth", "--quiet"]);
    for accel in ["roth", "cells"] {
        let o = render_ok(
            tmp.path(),
            "again.png",
            &["--accel", accel, "--reference", "ref.exr", "--quiet"],
        );
        let (rmse, psnr) = metrics(&o);
        assert_eq!(rmse, 0.0, "{accel}");
        assert_eq!(psnr, "inf", "{accel}");
    }
    // And it can tell a different picture: the same scene at other max_depth
    // is identical (no mirrors), so use another scene of the same size.
    let shadow = util::repo("scenes/small/shadow.ron");
    let args = [
        "render",
        path_str(&shadow),
        "-o",
        "s.png",
        "--width",
        "40",
        "--height",
        "30",
        "--reference",
        "ref.exr",
        "-q",
    ];
    let o = run(tmp.path(), &args);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(metrics(&o).0 > 0.01);
    // A reference of another size is bad input.
    let tmp2 = tempfile::tempdir().unwrap();
    let r = tmp.path().join("ref.exr");
    let sphere = util::repo("scenes/small/sphere.ron");
    let args = [
        "render",
        path_str(&sphere),
        "-o",
        "o.png",
        "--reference",
        path_str(&r),
    ];
    let problems = check_refusal(tmp2.path(), &args, "ref.exr");
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// `--reference` against the PNG the same command just wrote must report
/// no error: the written image is what the reference is compared with.
#[test]
fn reference_png_of_the_same_render_has_zero_error() {
    let tmp = tempfile::tempdir().unwrap();
    render_ok(tmp.path(), "ref.png", &["--accel", "roth", "--quiet"]);
    let o = render_ok(
        tmp.path(),
        "again.png",
        &["--accel", "roth", "--reference", "ref.png", "--quiet"],
    );
    let (rmse, psnr) = metrics(&o);
    assert!(rmse == 0.0 && psnr == "inf", "rmse {rmse}, psnr {psnr}");
}

#[test]
fn quiet_success_prints_nothing_on_stderr() {
    let tmp = tempfile::tempdir().unwrap();
    for accel in ["roth", "cells"] {
        let o = render_ok(tmp.path(), "q.png", &["--accel", accel, "--quiet"]);
        assert!(o.stderr.is_empty(), "{accel}: {}", stderr(&o));
        assert!(
            o.stdout.is_empty(),
            "{accel}: {}",
            String::from_utf8_lossy(&o.stdout)
        );
    }
    // Without --quiet a summary is printed (so the check above can fail).
    let o = render_ok(tmp.path(), "loud.png", &["--accel", "roth"]);
    assert!(!o.stderr.is_empty());
}

/// A default render that sent paths between nodes although every node
/// could hold the whole scene says how to render it without them; a
/// render whose placement the user chose does not.
#[test]
fn a_scene_that_fits_every_node_gets_the_whole_scene_hint() {
    let tmp = tempfile::tempdir().unwrap();
    let hint = "--replicas whole renders it with no paths between nodes";
    let house = util::repo("scenes/house.ron");
    let render = |extra: &[&str]| {
        // (At 64x48 on 32 nodes the distributed plan leaves most nodes
        // idle, and the default takes the whole scene itself.)
        let mut args = vec!["render", path_str(&house), "-o", "h.png", "--width", "96"];
        args.extend_from_slice(&["--height", "72"]);
        args.extend_from_slice(extra);
        let o = run(tmp.path(), &args);
        assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
        stderr(&o)
    };
    let default = render(&[]);
    assert!(default.contains(hint), "{default}");
    for chosen in ["none", "whole"] {
        let err = render(&["--replicas", chosen]);
        assert!(!err.contains(hint), "--replicas {chosen}: {err}");
    }
    // Nodes with less than twice the scene's 0.3 MiB get no hint.
    let err = render(&["--node-memory", "512KiB"]);
    assert!(!err.contains(hint), "512 KiB nodes: {err}");
}

/// Where the paper's distributed plan would leave most nodes idle (a room
/// of mirrors on 4 nodes, all its work on one), the default puts the whole
/// scene on every node and says so, in the render's note, its statistics
/// and `inspect`; `--replicas none` keeps the paper's plan, and the image
/// is the same.
#[test]
fn the_default_placement_names_a_whole_scene_it_chose() {
    let tmp = tempfile::tempdir().unwrap();
    let hall = tmp.path().join("hall.ron");
    std::fs::write(
        &hall,
        hypercast::r#gen::stress::mirror_hall(16, true, 64, 48),
    )
    .unwrap();
    let machine = ["--dim", "2"];
    let render = |out: &str, extra: &[&str]| -> (String, serde_json::Value) {
        let stats = format!("{out}.json");
        let mut args = vec!["render", path_str(&hall), "-o", out, "--stats", &stats];
        args.extend_from_slice(&machine);
        args.extend_from_slice(extra);
        let o = run(tmp.path(), &args);
        assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
        let text = std::fs::read_to_string(tmp.path().join(&stats)).unwrap();
        (stderr(&o), serde_json::from_str(&text).unwrap())
    };
    let note = "every node held the whole scene";
    let (err, stats) = render("auto.png", &[]);
    assert!(
        err.contains(note) && err.contains("--replicas none"),
        "{err}"
    );
    assert_eq!(stats["placement"], "whole", "{stats}");
    let uneven = stats["distributed_predicted_imbalance"].as_f64().unwrap();
    assert!(uneven >= 4.0, "{stats}");
    assert_eq!(stats["hops"], 0);
    let (err, stats) = render("paper.png", &["--replicas", "none"]);
    assert!(!err.contains(note), "{err}");
    assert_eq!(stats["placement"], "distributed", "{stats}");
    assert!(
        stats["distributed_predicted_imbalance"].is_null(),
        "{stats}"
    );
    let image = |f: &str| std::fs::read(tmp.path().join(f)).unwrap();
    assert_eq!(image("auto.png"), image("paper.png"));
    let inspect = |extra: &[&str]| {
        let mut args = vec!["inspect", path_str(&hall)];
        args.extend_from_slice(&machine);
        args.extend_from_slice(extra);
        let o = run(tmp.path(), &args);
        assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    let out = inspect(&[]);
    assert!(
        out.contains("placement           the whole scene on every node: distributed"),
        "{out}"
    );
    let out = inspect(&["--replicas", "whole"]);
    assert!(
        out.contains("placement           the whole scene on every node (--replicas whole)"),
        "{out}"
    );
    assert!(!inspect(&["--replicas", "none"]).contains("placement"));
}

/// `--stats` says what a scene does not need, in numbers (issue 5): no
/// shadow rays without lights, no reflected rays without `reflect`, no
/// refracted rays without `transmit`, only the pixels that see something
/// traced (cells), and per-cell subtrees smaller than the whole tree.
#[test]
fn stats_count_none_of_what_a_scene_cannot_use() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = |lights: &str, material: &str| {
        format!(
            "(camera: (eye: (0, -8, 2), look_at: (0, 0, 0), fov_y: 30, width: 48, height: 36),
              lights: [{lights}], materials: {{ \"m\": ({material}) }},
              objects: [
                Difference(material: \"m\", children: [
                  Sphere(center: (-1, 0, 0), radius: 0.8), Box(min: (-1, -1, 0.3), max: (0, 0, 1))]),
                Union(material: \"m\", children: [
                  Sphere(center: (1, 0, 0), radius: 0.5), Cylinder(base: (1, 0, -1), top: (1, 0, 1), radius: 0.2)]),
              ])"
        )
    };
    let stats = |name: &str, text: &str, accel: &str| -> serde_json::Value {
        let file = tmp.path().join(format!("{name}.ron"));
        std::fs::write(&file, text).unwrap();
        let json = format!("{name}-{accel}.json");
        let mut args = vec![
            "render",
            path_str(&file),
            "-o",
            "out.png",
            "--accel",
            accel,
            "--stats",
            &json,
            "--quiet",
            "--threads",
            "2",
        ];
        if accel == "cells" {
            // The paper's rule cuts the screen along every box edge, so the
            // background around four primitives is its own cells (the
            // default cost model may judge the cut not worth it).
            args.extend(["--bsp", "fewest-splits"]);
        }
        let o = run(tmp.path(), &args);
        assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
        serde_json::from_str(&std::fs::read_to_string(tmp.path().join(&json)).unwrap()).unwrap()
    };
    let lit = "(position: (3, -5, 5))";
    let cases: [(&str, &str, &str, &[&str]); 4] = [
        (
            "dark",
            "",
            "reflect: 0.5, transmit: 0.5, ior: 1.5",
            &["shadow"],
        ),
        ("matte", lit, "specular: 0.3", &["reflected", "refracted"]),
        ("mirror", lit, "reflect: 0.6", &["refracted"]),
        // Clear glass of ior 1 never reflects totally, so nothing reflects.
        ("glass", lit, "transmit: 0.9, ior: 1", &["reflected"]),
    ];
    for (name, lights, material, zeros) in cases {
        for accel in ["roth", "cells"] {
            let v = stats(name, &scene(lights, material), accel);
            let rays = &v["rays"];
            for kind in ["primary", "shadow", "reflected", "refracted"] {
                let n = rays[kind]
                    .as_u64()
                    .unwrap_or_else(|| panic!("rays.{kind}: {v}"));
                let zero = zeros.contains(&kind);
                assert_eq!(n == 0, zero, "{name} ({accel}): rays.{kind} = {n}");
            }
            let (traced, bg) = (
                v["pixels_traced"].as_u64().unwrap(),
                v["pixels_background"].as_u64().unwrap(),
            );
            assert_eq!(traced + bg, 48 * 36);
            if accel == "cells" {
                assert!(
                    bg > 0 && traced > 0,
                    "{name}: {traced} traced, {bg} background"
                );
                let sub = &v["subtree_nodes_per_cell"];
                let whole = sub["whole_tree"].as_u64().unwrap();
                assert!(sub["max"].as_u64().unwrap() < whole, "{name}: {sub}");
            } else {
                assert_eq!(bg, 0, "Roth traces every pixel");
            }
        }
    }
}

/// `inspect`'s per-node rows (node, super cells, cells, primitives,
/// memory, structure, work), split into words.
/// The number in `text` after the first `marker`, up to `end`.
fn number_after<T: std::str::FromStr>(text: &str, marker: &str, end: char) -> Option<T> {
    text.split(marker).nth(1)?.split(end).next()?.parse().ok()
}

fn node_rows(out: &str) -> Vec<Vec<&str>> {
    out.lines()
        .map(|l| l.split_whitespace().collect::<Vec<_>>())
        .filter(|w| w.len() == 8 && w[0].parse::<u32>().is_ok())
        .collect()
}

/// A node that owns nothing prints no work, not "-0" (an empty float sum
/// is -0.0): at 8x8 pixels csg_basics has too few super cells with work
/// for 32 nodes (heavy ones are split to no less than 16 pixels).
#[test]
fn inspect_prints_nodes_that_own_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = util::repo("scenes/csg_basics.ron");
    let o = run(
        tmp.path(),
        &[
            "inspect",
            path_str(&scene),
            "--dim",
            "5",
            "--width",
            "8",
            "--height",
            "8",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    let rows = node_rows(&out);
    assert_eq!(rows.len(), 32, "{out}");
    let idle: Vec<_> = rows.iter().filter(|w| w[1] == "0").collect();
    assert!(!idle.is_empty(), "{out}");
    assert!(idle.iter().all(|w| w[7] == "0"), "{out}");
    assert!(rows.iter().all(|w| !w.contains(&"-0")), "{out}");
}

/// `inspect` says how far the walk's rounding grows every box, and hints
/// where that blurs the subdivision: a ball on a ground reaching 1e20 is
/// one front super cell (`docs/robustness.md`); the jagged ball is not
/// hinted at.
#[test]
fn inspect_and_render_hint_where_the_walks_margin_blurs_the_subdivision() {
    let tmp = tempfile::tempdir().unwrap();
    let far = tmp.path().join("far_ground.ron");
    std::fs::write(
        &far,
        "(camera: (eye: (1.6, -2.5, 1.3), look_at: (-2, 0.4, 0.8), fov_y: 50, width: 64, height: 48),
          lights: [(position: (0, -3, 4))],
          objects: [
            Sphere(center: (0, 0.5, 0.6), radius: 0.6),
            Box(min: (-1e20, -1e20, -1), max: (1e20, 1e20, 0)),
          ])",
    )
    .unwrap();
    let jagged = util::repo("scenes/jagged_ball.ron");
    for (scene, hinted) in [(far.as_path(), true), (jagged.as_path(), false)] {
        let o = run(tmp.path(), &["inspect", path_str(scene), "--dim", "1"]);
        assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
        let out = String::from_utf8_lossy(&o.stdout).into_owned();
        assert!(out.contains("walk margin"), "{out}");
        let err = stderr(&o);
        assert_eq!(
            err.contains("grown by"),
            hinted,
            "{}: hint {hinted} expected\n{err}",
            scene.display()
        );
        // `render` says so too, on two nodes and on the default 32.
        for args in [&["--dim", "1"][..], &[][..]] {
            let mut argv = vec![
                "render",
                path_str(scene),
                "-o",
                "out.png",
                "--width",
                "32",
                "--height",
                "24",
            ];
            argv.extend_from_slice(args);
            let o = run(tmp.path(), &argv);
            assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
            let err = stderr(&o);
            assert_eq!(
                err.contains("grown by"),
                hinted,
                "{argv:?}: hint {hinted} expected\n{err}"
            );
        }
    }
}

/// `inspect` (issue 3): the subdivision's counts, the share of every node
/// against the replicated scene, the overlay at the image's size, and the
/// same numbers in `--stats`; each node's share and work sum to the whole.
#[test]
fn inspect_prints_the_subdivision_and_every_nodes_share() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = util::repo("scenes/jagged_ball.ron");
    let o = run(
        tmp.path(),
        &[
            "inspect",
            path_str(&scene),
            "--overlay",
            "overlay.png",
            "--width",
            "160",
            "--height",
            "120",
            "--dim",
            "5",
            "--stats",
            "inspect.json",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    for key in [
        "primitives          203",
        "super cells",
        "subtree nodes/cell",
        "structure bytes",
        "replicated scene",
        "with 32 nodes",
        "structure held",
    ] {
        assert!(out.contains(key), "no {key:?} in\n{out}");
    }
    // One row per node, and no negative zero for a node that owns nothing.
    let rows = node_rows(&out);
    assert_eq!(rows.len(), 32, "{out}");
    // The machine asks the build for 8 front super cells per node (the
    // cost model alone stops at 36 on the jagged ball): each of the 32
    // nodes owns some.
    assert!(rows.iter().all(|w| w[1] != "0"), "{out}");
    assert!(rows.iter().all(|w| !w.contains(&"-0")), "{out}");
    let img = image::open(tmp.path().join("overlay.png")).expect("the overlay");
    assert_eq!((img.width(), img.height()), (160, 120));
    // The overlay's key: the outlines' scale ends at the most primitives
    // of a super cell, which is the most of any cell in it at least.
    let err = stderr(&o);
    let most: u64 = number_after(&err, "blue 1 to red ", ',')
        .unwrap_or_else(|| panic!("no key for the overlay in {err}"));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tmp.path().join("inspect.json")).unwrap())
            .unwrap();
    assert_eq!(v["primitives"], 203);
    assert_eq!(v["nodes"], 32);
    // The predicted imbalance is the node rows' most work against their
    // mean, in the text and the JSON.
    let work: Vec<f64> = rows.iter().map(|w| w[7].parse().unwrap()).collect();
    let expect = work.iter().cloned().fold(0.0, f64::max) / (work.iter().sum::<f64>() / 32.0);
    let said: f64 = number_after(&out, "predicted imbalance ", ' ')
        .unwrap_or_else(|| panic!("no predicted imbalance in\n{out}"));
    let json = v["predicted_imbalance"]
        .as_f64()
        .expect("predicted_imbalance");
    assert!(
        (said - expect).abs() < 0.01 * expect && (json - said).abs() < 0.001,
        "{said} and {json} against {expect}"
    );
    let per_cell = v["primitives_per_cell"]["max"]
        .as_u64()
        .expect("max per cell");
    assert!(most >= per_cell && most <= 203, "{most} against {per_cell}");
    let nodes = v["per_node"].as_array().expect("per_node");
    assert_eq!(nodes.len(), 32);
    let supers: u64 = nodes
        .iter()
        .map(|n| n["super_cells"].as_u64().unwrap())
        .sum();
    assert_eq!(supers, v["super_cells"].as_u64().unwrap(), "{v}");
    let cells: u64 = nodes.iter().map(|n| n["cells"].as_u64().unwrap()).sum();
    assert_eq!(cells, v["cells"].as_u64().unwrap(), "{v}");
    // A share is less than the whole scene, and no node over budget.
    let replicated = v["replicated_scene_bytes"].as_u64().unwrap();
    let budget = v["memory_budget_bytes"].as_u64().unwrap();
    for n in nodes {
        let m = n["memory_bytes"].as_u64().unwrap();
        assert!(m < replicated && m <= budget, "{n}");
        // The structure is part of the share.
        let st = n["structure_bytes"].as_u64().unwrap();
        assert!(st > 0 && st < m, "{n}");
    }
}

/// A dimension whose shares do not fit the nodes stops `scale` before it
/// writes anything, with exit 2 and one line naming the dimension, the
/// node and the memory that would do; the folder `--out` names is not
/// made.
#[test]
fn scale_refuses_a_dimension_that_does_not_fit_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = util::repo("scenes/sphereflake3.nff");
    let mut args = vec![
        "scale",
        path_str(&scene),
        "--dims",
        "0..1",
        "--node-memory",
        "200KiB",
        "--width",
        "40",
        "--height",
        "30",
    ];
    let o = run(tmp.path(), &args);
    // Its hint speaks of --dims, which scale takes, not --dim.
    let err = stderr(&o);
    assert!(
        err.contains("start --dims at 4 (the fewest nodes that fit) or use --node-memory")
            && !err.contains("--dim "),
        "{err}"
    );
    args.extend(["--out", "out"]);
    let problems = check_refusal(tmp.path(), &args, "at d = 0: node 0 needs");
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// Audit: `scale --dims 2,2` ran dimension 2 twice (two rows of one
/// dimension), and `--dims 1,0` took speedups against two nodes. A
/// dimension given twice is a usage error naming it, before the scene is
/// read; a list in any order runs smallest first, the baseline of the
/// speedups.
#[test]
fn scale_refuses_a_repeated_dimension_and_runs_the_smallest_first() {
    let scene = util::repo("scenes/small/mirror.ron");
    let scene = path_str(&scene);
    let mut problems = Vec::new();
    for (dims, d) in [("2,2", 2), ("1,0,1", 1)] {
        let tmp = tempfile::tempdir().unwrap();
        problems.extend(check_refusal(
            tmp.path(),
            &["scale", scene, "--dims", dims, "--out", "out"],
            &format!("--dims: {d} is given more than once"),
        ));
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    let tmp = tempfile::tempdir().unwrap();
    let args = [
        "scale", scene, "--dims", "1,0", "--width", "40", "--height", "30", "--out", "out", "-q",
    ];
    let o = run(tmp.path(), &args);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let csv = std::fs::read_to_string(tmp.path().join("out/scaling.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    let dims: Vec<&str> = rows.iter().map(|r| r[col("dimension")]).collect();
    assert_eq!(dims, ["0", "1"], "{csv}");
    for k in ["speedup_wall", "speedup_virtual", "work_ratio"] {
        assert_eq!(rows[0][col(k)].parse::<f64>(), Ok(1.0), "{k}: {csv}");
    }
}

/// The README's examples of an error (a `$ hypercast ...` line followed by
/// `hypercast: error: ...`) are what the binary prints today, word for
/// word: the README is where a new user first meets them.
#[test]
fn the_readmes_example_errors_are_what_the_binary_prints() {
    let readme = std::fs::read_to_string(util::repo("README.md")).unwrap();
    let lines: Vec<&str> = readme.lines().collect();
    let mut checked = 0;
    for pair in lines.windows(2) {
        let (Some(command), Some(_)) = (
            pair[0].strip_prefix("$ hypercast "),
            pair[1].strip_prefix("hypercast: error: "),
        ) else {
            continue;
        };
        // Inputs from the project's folder; the run in an empty one, so
        // that a render that failed to refuse leaves its file there.
        let repo = util::repo("");
        let args: Vec<String> = command
            .split_whitespace()
            .map(|a| {
                let path = repo.join(a);
                if path.exists() && !a.starts_with('-') {
                    path_str(&path).to_owned()
                } else {
                    a.to_owned()
                }
            })
            .collect();
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let tmp = tempfile::tempdir().unwrap();
        let problems = check_refusal(tmp.path(), &args, pair[1]);
        assert!(
            problems.is_empty(),
            "$ hypercast {command}\n{}",
            problems.join("\n")
        );
        checked += 1;
    }
    assert!(checked >= 1, "no example error found in README.md");
}

/// `hypercast scale` (issue 4): one render per dimension, a printed
/// table, `scaling.csv` with a row per dimension whose counts hang
/// together, and `scaling.png`.
#[test]
fn scale_writes_the_table_csv_and_plot() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = util::repo("scenes/small/mirror.ron");
    let o = run(
        tmp.path(),
        &[
            "scale",
            path_str(&scene),
            "--dims",
            "0..2",
            "--repeat",
            "2",
            "--width",
            "40",
            "--height",
            "30",
            "--out",
            "out",
            "-q",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let table = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        table.contains("speedup_virtual") && table.contains("bytes_per_ray"),
        "{table}"
    );
    let csv = std::fs::read_to_string(tmp.path().join("out/scaling.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 3, "{csv}");
    let col = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .unwrap_or_else(|| panic!("no {name}"))
    };
    let num = |r: &[&str], name: &str| r[col(name)].parse::<f64>().unwrap();
    for (d, r) in rows.iter().enumerate() {
        assert_eq!(r.len(), header.len(), "{csv}");
        assert_eq!(num(r, "dimension"), d as f64);
        assert_eq!(num(r, "nodes"), (1 << d) as f64);
        assert!(num(r, "virtual_seconds") > 0.0 && num(r, "wall_seconds") > 0.0);
        for k in [
            "imbalance_balanced",
            "imbalance_equal_area",
            "imbalance_tests",
            "imbalance_work",
        ] {
            assert!(num(r, k) >= 1.0, "{k} {csv}");
        }
        // Every ray is counted, the same on every dimension.
        assert_eq!(r[col("rays")], rows[0][col("rays")], "{csv}");
        assert!(num(r, "peak_over_budget") <= 1.0);
        let per_ray = num(r, "message_bytes") / num(r, "rays");
        assert!((per_ray - num(r, "bytes_per_ray")).abs() < 0.06, "{csv}");
        // Speedups are against the first dimension's runs, efficiency is
        // speedup per node.
        for (speedup, efficiency) in [
            ("speedup_wall", "efficiency_wall"),
            ("speedup_virtual", "efficiency_virtual"),
        ] {
            // (Both printed to 3 decimals.)
            let (s, e, n) = (num(r, speedup), num(r, efficiency), (1 << d) as f64);
            assert!(s > 0.0 && (e * n - s).abs() <= 0.001 * n, "{csv}");
            if d == 0 {
                assert_eq!(s, 1.0, "{csv}");
            }
        }
    }
    // The efficiency's factors are against the first dimension's runs; a
    // share of the node time is computing, another waiting, and together
    // they are at most all of it.
    assert_eq!(num(&rows[0], "work_ratio"), 1.0, "{csv}");
    assert_eq!(num(&rows[0], "cost_ratio"), 1.0, "{csv}");
    for r in &rows {
        let (u, w) = (num(r, "utilisation"), num(r, "waiting"));
        assert!(u > 0.0 && u <= 1.001, "{csv}");
        assert!(w >= 0.0 && u + w <= 1.002, "{csv}");
        assert!(num(r, "work_ratio") > 0.0 && num(r, "cost_ratio") > 0.0);
    }
    assert!(
        table.contains("utilisation") && table.contains("waiting"),
        "{table}"
    );
    // The share of the host the nodes had: a positive number, or empty
    // where the runs were too short to tell.
    for r in &rows {
        let share = r[col("host_share")];
        assert!(
            share.is_empty() || share.parse::<f64>().is_ok_and(|s| s > 0.0),
            "{csv}"
        );
    }
    // One node holds the whole structure; more nodes hold more of it
    // together (every one the skeleton), and send rays to each other.
    assert_eq!(num(&rows[0], "structure_ratio"), 1.0);
    assert_eq!(num(&rows[0], "hops"), 0.0);
    for r in &rows[1..] {
        assert!(num(r, "structure_ratio") > 1.0, "{csv}");
        assert!(num(r, "hops") > 0.0, "{csv}");
    }
    let img = image::open(tmp.path().join("out/scaling.png")).expect("the plot");
    assert!(img.width() > 100 && img.height() > 100);
}

/// A reader that stops early (`hypercast inspect scene.ron | head`) is no
/// failure: `inspect` printed its report with `println!`, which panicked
/// on the closed pipe. Now it exits 0 and still writes its overlay. The
/// pipe's reading end is closed before the run starts, so every write to
/// standard output meets it closed.
#[test]
fn a_closed_standard_output_ends_no_report_early() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = util::repo("scenes/small/sphere.ron");
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let o = Command::new(BIN)
        .args(["inspect", path_str(&scene), "--overlay", "o.png"])
        .current_dir(tmp.path())
        .env("RUST_BACKTRACE", "1")
        .stdout(writer)
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    assert!(o.status.success(), "{:?}: {}", o.status, stderr(&o));
    assert!(!stderr(&o).contains("panicked"), "{}", stderr(&o));
    assert!(tmp.path().join("o.png").is_file(), "the overlay is written");
}

/// An interrupt while an image is being written (`CLI.md`: no half-written
/// output file) removes the temporary file too, which the signal's default
/// action would have left beside the output. The write is held at a known
/// point (a test-only environment variable) and interrupted there, with
/// SIGINT as Ctrl-C sends it and with SIGTERM.
#[cfg(unix)]
#[test]
fn an_interrupted_write_leaves_no_file_behind() {
    use std::io::{BufRead, BufReader};
    let scene = util::repo("scenes/small/sphere.ron");
    for signal in ["INT", "TERM"] {
        let tmp = tempfile::tempdir().unwrap();
        let mut child = Command::new(BIN)
            .args([
                "render",
                path_str(&scene),
                "--width",
                "16",
                "--height",
                "12",
            ])
            .args(["--dim", "0", "-o", "out.png"])
            .current_dir(tmp.path())
            .env("HYPERCAST_TEST_HOLD_COMMIT", "20")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut err = BufReader::new(child.stderr.take().unwrap());
        let mut line = String::new();
        while !line.starts_with("hypercast: holding") {
            line.clear();
            assert_ne!(err.read_line(&mut line).unwrap(), 0, "no hold announced");
        }
        assert_eq!(files_in(tmp.path()).len(), 1, "the temporary file exists");
        let killed = Command::new("kill")
            .args([&format!("-{signal}"), &child.id().to_string()])
            .status()
            .unwrap();
        assert!(killed.success());
        let start = Instant::now();
        let status = child.wait().unwrap();
        let mut rest = String::new();
        std::io::Read::read_to_string(&mut err, &mut rest).unwrap();
        assert_eq!(status.code(), Some(130), "SIG{signal}: {status:?} {rest}");
        assert!(rest.contains("interrupted"), "{rest}");
        assert!(start.elapsed() < Duration::from_secs(10));
        assert_eq!(files_in(tmp.path()), Vec::<PathBuf>::new(), "SIG{signal}");
    }
}

/// An output that is a symbolic link is written where the link points,
/// the link kept: the atomic rename would otherwise have replaced the link
/// with a plain file and left its target as it was. A link to one of the
/// run's inputs is refused like the input itself.
#[cfg(unix)]
#[test]
fn an_output_through_a_symbolic_link_writes_its_target() {
    use std::os::unix::fs::symlink;
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let scene = util::repo("scenes/small/sphere.ron");
    std::fs::create_dir(dir.join("renders")).unwrap();
    symlink("renders/old.png", dir.join("latest.png")).unwrap();
    std::fs::write(dir.join("renders/old.png"), b"an older image").unwrap();
    symlink("renders/new.png", dir.join("dangling.png")).unwrap();
    let args =
        |out: &'static str| [vec!["render", path_str(&scene), "-q", "-o"], vec![out]].concat();
    for out in ["latest.png", "dangling.png"] {
        let o = run(dir, &args(out));
        assert_eq!(o.status.code(), Some(0), "{out}: {}", stderr(&o));
        assert!(
            dir.join(out)
                .symlink_metadata()
                .unwrap()
                .file_type()
                .is_symlink()
        );
    }
    for target in ["renders/old.png", "renders/new.png"] {
        let png = std::fs::read(dir.join(target)).unwrap();
        assert!(png.starts_with(b"\x89PNG"), "{target} is the render");
    }
    // Refused before anything is written, with exit 2 and why.
    let refused = |out: &'static str, why: &str| {
        let o = run(dir, &args(out));
        assert_eq!(o.status.code(), Some(2), "{out}: {}", stderr(&o));
        assert!(stderr(&o).contains(why), "{out}: {}", stderr(&o));
    };
    symlink(&scene, dir.join("scene.png")).unwrap();
    refused("scene.png", "would replace the scene");
    symlink("loop2.png", dir.join("loop1.png")).unwrap();
    symlink("loop1.png", dir.join("loop2.png")).unwrap();
    refused("loop1.png", "too many levels");
    assert!(
        dir.join("loop1.png").is_symlink(),
        "the loop is left as it was"
    );
    symlink("nowhere/x.png", dir.join("lost.png")).unwrap();
    refused("lost.png", "nowhere does not exist");
}
