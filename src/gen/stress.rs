//! Scenes that stress size and depth (issue 5, `docs/robustness.md`): many
//! primitives, CSG chains thousands of levels deep, and halls of mirrors.
//! Deterministic; sized by their arguments, so tests run them small and
//! `examples/stress.rs` full size.
//!
//! They are RON text rather than models: a model thousands of levels deep
//! recurses when it is dropped, and only the loader's own thread has the
//! stack for that (`scene::load`).

use std::fmt::Write as _;

/// A camera, lights, two materials and `objects`, as a scene file.
fn scene(camera: &str, max_depth: u32, lights: &str, materials: &str, objects: &str) -> String {
    format!(
        "(camera: {camera}, background: (0.2, 0.25, 0.35), max_depth: {max_depth},
          lights: [{lights}], materials: {{ {materials} }}, objects: [{objects}])"
    )
}

/// `n` spheres on a cubic lattice of side `⌈∛n⌉` (spacing 1, radius 0.35,
/// each nudged by a hash of its index so that no two rows align), seen from
/// outside by a camera that frames the whole block: a flat union of `n`
/// primitives, most of them visible.
pub fn sphere_lattice(n: usize, width: u32, height: u32) -> String {
    let side = (n as f64).cbrt().ceil().max(1.0) as usize;
    let mut objects = String::with_capacity(n * 64);
    for i in 0..n {
        let (x, y, z) = (i % side, i / side % side, i / (side * side));
        let h = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 40;
        let jitter = |k: u32| ((h >> (8 * k)) & 0xff) as f64 / 255.0 * 0.2 - 0.1;
        let _ = write!(
            objects,
            "Sphere(center: ({:.3}, {:.3}, {:.3}), radius: 0.35, material: \"{}\"),",
            x as f64 + jitter(0),
            y as f64 + jitter(1),
            z as f64 + jitter(2),
            if i % 7 == 0 { "mirror" } else { "matte" }
        );
    }
    let s = side as f64;
    let c = (s - 1.0) / 2.0;
    scene(
        &format!(
            "(eye: ({:.3}, {:.3}, {:.3}), look_at: ({c:.3}, {c:.3}, {c:.3}), fov_y: 40, width: {width}, height: {height})",
            c + 1.2 * s,
            c - 1.6 * s,
            c + 1.0 * s
        ),
        3,
        &format!(
            "(position: ({:.3}, {:.3}, {:.3}))",
            c - s,
            c - 2.0 * s,
            c + 3.0 * s
        ),
        "\"matte\": (color: (0.8, 0.5, 0.3)), \"mirror\": (color: (0.9, 0.9, 0.9), reflect: 0.5)",
        &objects,
    )
}

/// The shapes of a deep chain.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Chain {
    /// `((box − s₁) − s₂) − …`: a block drilled by `depth` small spheres
    /// along its front edge, each level one difference, the first operand
    /// the deep one.
    LeftDifference,
    /// `s₀ ∪ (s₁ ∪ (s₂ ∪ …))`: a rod of overlapping spheres, the last
    /// operand the deep one.
    RightUnion,
}

/// A CSG chain `depth` operators deep (see `Chain`), seen from the front.
pub fn deep_chain(depth: usize, chain: Chain, width: u32, height: u32) -> String {
    // Sphere k sits at x = k·step along a block of length `len`.
    let len = 20.0;
    let step = len / depth.max(1) as f64;
    // Drill holes just wider than the step; the union's spheres overlap
    // into a visible rod.
    let radius = match chain {
        Chain::LeftDifference => 0.6 * step,
        Chain::RightUnion => 0.25,
    };
    let sphere = |k: usize| {
        format!(
            "Sphere(center: ({:?}, -0.5, 0.5), radius: {radius:?})",
            k as f64 * step
        )
    };
    let mut s = String::with_capacity(depth * 96);
    match chain {
        Chain::LeftDifference => {
            s.push_str(&"Difference(children: [".repeat(depth));
            let _ = write!(s, "Box(min: (0, -0.5, -0.5), max: ({len:?}, 0.5, 0.5))");
            for k in 0..depth {
                let _ = write!(s, ", {}])", sphere(k));
            }
        }
        Chain::RightUnion => {
            for k in 0..depth {
                let _ = write!(s, "Union(children: [{}, ", sphere(k));
            }
            s.push_str(&sphere(depth));
            s.push_str(&"])".repeat(depth));
        }
    }
    let c = len / 2.0;
    scene(
        &format!(
            "(eye: ({c:?}, -{:?}, 6), look_at: ({c:?}, 0, 0), fov_y: 70, width: {width}, height: {height})",
            len * 0.8
        ),
        2,
        &format!("(position: ({c:?}, -10, 10))"),
        "\"red\": (color: (0.9, 0.2, 0.1))",
        &format!("Union(material: \"red\", children: [{s}])"),
    )
}

/// A closed room of mirrors (reflect 0.9) with a light inside, and the
/// camera: every ray bounces until `max_depth` stops it. With `glass`, a
/// diffuse ball and a glass ball (reflect 0.1, transmit 0.85) stand in the
/// room, and each ray that meets the glass splits in two.
pub fn mirror_hall(max_depth: u32, glass: bool, width: u32, height: u32) -> String {
    let balls = if glass {
        "Sphere(center: (-0.6, 0.5, 0.7), radius: 0.7, material: \"ball\"),
         Sphere(center: (0.9, 1.2, 0.9), radius: 0.6, material: \"glass\"),"
    } else {
        ""
    };
    scene(
        &format!(
            "(eye: (-1.5, -2.2, 1.4), look_at: (0.5, 1, 0.8), fov_y: 60, width: {width}, height: {height})"
        ),
        max_depth,
        "(position: (0, 0, 2.5))",
        "\"mirror\": (color: (0.9, 0.9, 0.9), ambient: 0.02, diffuse: 0.05, reflect: 0.9),
         \"glass\": (color: (1, 1, 1), ambient: 0, diffuse: 0.05, reflect: 0.1, transmit: 0.85, ior: 1.5),
         \"ball\": (color: (0.85, 0.2, 0.1), specular: 0.4)",
        &format!(
            "Difference(material: \"mirror\", children: [
               Box(min: (-3.1, -3.1, -0.1), max: (3.1, 3.1, 3.1)),
               Box(min: (-3, -3, 0), max: (3, 3, 3))]),
             {balls}"
        ),
    )
}
