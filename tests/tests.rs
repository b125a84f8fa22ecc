//! hypercast's integration tests: one crate (`STYLE.md`), one module per
//! area, in `tests/it/` so that cargo does not build each as its own crate.

#[path = "it/bundled.rs"]
mod bundled;
#[path = "it/cells.rs"]
mod cells;
#[path = "it/cli.rs"]
mod cli;
#[path = "it/convert.rs"]
mod convert;
#[path = "it/csg_props.rs"]
mod csg_props;
#[path = "it/garbled.rs"]
mod garbled;
#[path = "it/known_answer.rs"]
mod known_answer;
#[path = "it/machine.rs"]
mod machine;
#[path = "it/povray.rs"]
mod povray;
#[path = "it/quality.rs"]
mod quality;
#[path = "it/robustness.rs"]
mod robustness;
#[path = "it/shading.rs"]
mod shading;
#[path = "it/stress.rs"]
mod stress;

/// Helpers shared by the modules.
mod util {
    use std::path::{Path, PathBuf};

    use hypercast::geom::Vec3;
    use hypercast::render::{self, RenderOptions, RenderStats};
    use hypercast::scene::{Scene, SceneSyntax, parse_scene_str};
    use hypercast::trace::Film;

    /// A file of the repository (tests run with the package as cwd, but
    /// the CLI tests change directory).
    pub fn repo(rel: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
    }

    /// A scene from RON text; panics with the loader's message.
    pub fn scene(ron: &str) -> Scene {
        parse_scene_str(ron, SceneSyntax::Ron, Path::new("inline.ron"))
            .unwrap_or_else(|e| panic!("scene does not load: {e}\n{ron}"))
    }

    /// Small, two threads: CI runs the debug build on two cores.
    pub fn opts(width: u32, height: u32) -> RenderOptions {
        RenderOptions {
            width,
            height,
            spp: 1,
            threads: 2,
        }
    }

    pub fn roth(scene: &Scene, width: u32, height: u32) -> (Film, RenderStats) {
        let (film, stats) = render::render_roth(scene, &opts(width, height), &|_| {});
        assert_finite(&film);
        (film, stats)
    }

    pub fn cells(scene: &Scene, width: u32, height: u32) -> (Film, RenderStats) {
        let (film, stats, _) =
            render::render_cells(scene, &opts(width, height), Default::default(), &|_| {});
        assert_finite(&film);
        (film, stats)
    }

    /// Pixels whose fixed-point sums differ.
    pub fn differing(a: &Film, b: &Film) -> usize {
        a.sums()
            .iter()
            .zip(b.sums())
            .filter(|(x, y)| x != y)
            .count()
    }

    /// `ROBUSTNESS.md`: no pixel is NaN or infinite, ever.
    pub fn assert_finite(film: &Film) {
        for (i, p) in film.to_linear().iter().enumerate() {
            assert!(p.iter().all(|c| c.is_finite()), "pixel {i} is {p:?}");
        }
    }

    /// The direction of the primary ray through the centre of pixel (i, j),
    /// from `SCENE_FORMAT.md`'s pinhole camera, computed here rather than
    /// by the renderer's `CameraFrame` so known answers stay independent.
    #[allow(clippy::too_many_arguments)]
    pub fn pixel_dir(
        eye: Vec3,
        look_at: Vec3,
        up: Vec3,
        fov_y: f64,
        width: u32,
        height: u32,
        i: u32,
        j: u32,
    ) -> Vec3 {
        let (sx, sy) = screen(fov_y, width, height, i, j);
        let f = (look_at - eye).normalize();
        let r = f.cross(up).normalize();
        let u = r.cross(f);
        r * sx + u * sy + f
    }

    /// Screen coordinates (image plane at distance 1) of pixel (i, j)'s centre.
    pub fn screen(fov_y: f64, width: u32, height: u32, i: u32, j: u32) -> (f64, f64) {
        let half_h = (fov_y.to_radians() / 2.0).tan();
        let half_w = half_h * width as f64 / height as f64;
        let sx = (2.0 * (i as f64 + 0.5) / width as f64 - 1.0) * half_w;
        let sy = (1.0 - 2.0 * (j as f64 + 0.5) / height as f64) * half_h;
        (sx, sy)
    }
}
