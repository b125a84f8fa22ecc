//! Issue 6's race: hypercast against POV-Ray 3.7, side by side in one run,
//! on the same scene, resolution and features (point lights with shadows,
//! Phong highlights, reflection, one ray per pixel: POV-Ray `-A`, hypercast
//! `--spp 1`) and the same number of worker threads (POV-Ray `+WT2`).
//! POV-Ray gets the scene through `hypercast convert`, with the camera's
//! size set to the render's so both see the same frame, and traces the
//! same ray tree (`max_trace_level` = our `max_depth` + 1, `adc_bailout 0`:
//! see `scene::pov`).
//!
//! Each measurement is the wall time of the whole process, reading the
//! scene to writing the PNG, for both; the two renderers alternate, three
//! times each, and the table gives medians and the ratio hypercast/POV-Ray,
//! with the RMSE between the two pictures (display values in [0, 1]) as a
//! check that both did the same work.
//!
//! `cargo bench --bench povray_race` (needs `povray` on the PATH). Set
//! `POVRAY_RACE_QUICK=1` for a quarter of the resolution, to try it out.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use hypercast::report::{compare, read_display_image};

const BIN: &str = env!("CARGO_BIN_EXE_hypercast");
const RUNS: usize = 3;

/// hypercast's configurations, each a row per scene: the render options
/// after the scene, sizes and output, and whether the targets are
/// for it. The one place to change how hypercast runs: `--dim 1` is the
/// issue's configuration (two worker threads, as POV-Ray's `+WT2`), the
/// default topology is reported beside it.
const HYPERCAST: &[(&str, &[&str], bool)] = &[
    ("--dim 1 (2 node threads)", &["--dim", "1"], true),
    ("ipsc-d5 (32 node threads)", &[], false),
];

/// POV-Ray's options beside input, output and size: no antialiasing, two
/// worker threads, no display, no pause, sRGB PNG like ours, no text.
const POVRAY: &[&str] = &["-A", "+WT2", "-D", "-P", "+FN", "File_Gamma=sRGB", "-GA"];

/// The scenes: name, file, size, and the target ratio if any.
const SCENES: &[(&str, &str, u32, u32, Option<f64>)] = &[
    (
        "sphereflake level 4",
        "scenes/sphereflake4.nff",
        1024,
        1024,
        Some(0.5),
    ),
    (
        "jagged_ball.ron",
        "scenes/jagged_ball.ron",
        1024,
        1024,
        Some(0.25),
    ),
    ("house.ron", "scenes/house.ron", 1024, 768, None),
];

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Runs a command to completion and returns its wall time; panics with its
/// output when it fails (a benchmark has nobody to report an error to).
fn timed(cmd: &mut Command) -> f64 {
    let t = Instant::now();
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("cannot run {cmd:?}: {e}"));
    let seconds = t.elapsed().as_secs_f64();
    assert!(
        out.status.success(),
        "{cmd:?} failed:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    seconds
}

fn hypercast(scene: &Path, out: &Path, w: u32, h: u32, options: &[&str]) -> Command {
    let mut c = Command::new(BIN);
    c.arg("render")
        .arg(scene)
        .arg("-o")
        .arg(out)
        .args([
            "--width",
            &w.to_string(),
            "--height",
            &h.to_string(),
            "--spp",
            "1",
        ])
        .args(options)
        .arg("--quiet");
    c
}

fn povray(dir: &Path, pov: &str, png: &str, w: u32, h: u32) -> Command {
    let mut c = Command::new("povray");
    // POV-Ray's I/O restrictions allow writing in the working folder.
    c.current_dir(dir)
        .arg(format!("+I{pov}"))
        .arg(format!("+O{png}"))
        .arg(format!("+W{w}"))
        .arg(format!("+H{h}"))
        .args(POVRAY);
    c
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let quick = std::env::var_os("POVRAY_RACE_QUICK").is_some();
    let dir = tempfile::tempdir().expect("temporary folder");
    let version = Command::new("povray").arg("--version").output();
    let Ok(version) = version else {
        eprintln!("povray is not installed (Debian package povray): no race");
        std::process::exit(1);
    };
    let version = String::from_utf8_lossy(&version.stderr);
    eprintln!(
        "{} against {}, {RUNS} runs each, medians",
        BIN,
        version
            .lines()
            .find(|l| l.contains("POV-Ray"))
            .unwrap_or("POV-Ray")
    );
    println!(
        "| scene | size | hypercast | hypercast s | POV-Ray s | hypercast/POV-Ray | target | RMSE vs POV-Ray |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for &(name, file, w, h, target) in SCENES {
        let (w, h) = if quick { (w / 4, h / 4) } else { (w, h) };
        let scene: PathBuf = root.join(file);
        let pov = format!("race_{w}x{h}.pov");
        timed(
            Command::new(BIN)
                .arg("convert")
                .arg(&scene)
                .arg("-o")
                .arg(dir.path().join(&pov))
                .args(["--width", &w.to_string(), "--height", &h.to_string(), "-q"]),
        );
        for &(config, options, targeted) in HYPERCAST {
            let ours = dir.path().join("hypercast.png");
            let (mut t_ours, mut t_pov) = (Vec::new(), Vec::new());
            for _ in 0..RUNS {
                t_ours.push(timed(&mut hypercast(&scene, &ours, w, h, options)));
                t_pov.push(timed(&mut povray(dir.path(), &pov, "povray.png", w, h)));
            }
            let a = read_display_image(&ours).expect("hypercast's image");
            let b = read_display_image(&dir.path().join("povray.png")).expect("POV-Ray's image");
            let rmse = compare(&a.pixels, &b.pixels).rmse;
            let (ours_s, pov_s) = (median(t_ours), median(t_pov));
            let ratio = ours_s / pov_s;
            let target = match target.filter(|_| targeted) {
                Some(t) if ratio <= t => format!("<= {t}: met"),
                Some(t) => format!("<= {t}: **not met**"),
                None => "-".into(),
            };
            println!(
                "| {name} | {w}x{h} | {config} | {ours_s:.2} | {pov_s:.2} | {ratio:.2}x | {target} | {rmse:.4} |"
            );
        }
    }
}
