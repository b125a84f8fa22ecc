//! Random CSG scenes for property tests (cells against Roth, `ROBUSTNESS.md`)
//! and for `gen random-csg`: every primitive and operator, random transforms,
//! mirrors and glass, and cameras outside the scene, inside it, or with most
//! of it behind the eye. Deterministic: a seed and options give the same
//! model (own SplitMix64, no `rand`; across platforms, up to last-bit
//! differences of `sin` and `cos` that the rounding below nearly always hides).
//!
//! Every scene is valid by construction (`scene::load`'s rules). Each node
//! is generated inside a ball that holds its geometry; children's balls lie
//! inside their parent's, so the whole scene lies in a ball of radius
//! `SCENE_RADIUS` about the origin, intersections and differences overlap
//! their operands, and assembly children really do not overlap.
//!
//! Numbers are rounded to 3 decimals (angles to 0.1°) so that RON and JSON
//! files are readable and read back bit for bit; rounding also puts many
//! faces on shared planes, which is what cell boundaries must survive.

use std::collections::BTreeMap;
use std::f64::consts::TAU;

use crate::geom::Vec3;
use crate::scene::model::{Camera, Light, Material, Node, SceneFile, Vector};

/// The deepest operator nesting `random_csg` makes.
pub const MAX_TREE_DEPTH: u32 = 6;

/// Radius of the ball about the origin that holds every scene's geometry
/// (not the mirror of `CameraPlacement::BehindEye`, which lies outside it).
pub const SCENE_RADIUS: f64 = 10.0;

/// Where the camera goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraPlacement {
    /// Outside the scene's ball, looking at it.
    Outside,
    /// Inside the scene's ball (maybe inside a solid), looking anywhere.
    Inside,
    /// In the scene, looking out of it at a large mirror sphere (counted as
    /// one of the primitives): most geometry is behind the eye and is seen
    /// only by reflection, which exercises the cells' back region.
    BehindEye,
    /// One of the three above, chosen by the seed.
    Mixed,
}

/// What `random_csg` may generate.
#[derive(Clone, Debug)]
pub struct RandomCsgOptions {
    /// Operator levels, counting the top-level objects list (an implicit
    /// union) as one: 1 makes a flat list of primitives. Transforms are not
    /// counted. Clamped to `1..=MAX_TREE_DEPTH`.
    pub max_tree_depth: u32,
    /// Triangles, polygons and open cylinders and cones, only where no
    /// intersection or difference is above them.
    pub surfaces: bool,
    /// Mirror (`reflect`) and glass (`transmit`, `ior` 1.5) materials
    /// among the random ones.
    pub mirrors_and_glass: bool,
    pub camera: CameraPlacement,
    /// Number of point lights, at most 3; None: 0 to 3 by the seed.
    pub lights: Option<u32>,
    /// The scene's `max_depth` (reflection and refraction generations).
    pub trace_depth: u32,
    /// The camera's image size.
    pub width: u32,
    pub height: u32,
}

impl Default for RandomCsgOptions {
    fn default() -> Self {
        RandomCsgOptions {
            max_tree_depth: 4,
            surfaces: true,
            mirrors_and_glass: true,
            camera: CameraPlacement::Mixed,
            lights: None,
            trace_depth: 3,
            width: 64,
            height: 48,
        }
    }
}

/// A random scene of exactly `primitives` primitives (0 gives an empty
/// scene), the same for the same seed and options.
pub fn random_csg(seed: u64, primitives: usize, opts: &RandomCsgOptions) -> SceneFile {
    let mut g = Gen {
        rng: SplitMix64(seed),
        max_level: opts.max_tree_depth.clamp(1, MAX_TREE_DEPTH),
        palette: if opts.mirrors_and_glass {
            PALETTE.len()
        } else {
            MATTE
        },
        used_mirror: false,
    };
    let placement = match opts.camera {
        CameraPlacement::Mixed => [
            CameraPlacement::Outside,
            CameraPlacement::Inside,
            CameraPlacement::BehindEye,
        ][g.rng.below(3)],
        p => p,
    };
    let r = SCENE_RADIUS;
    let (camera, mut objects) = match placement {
        CameraPlacement::BehindEye if primitives > 0 => {
            let f = g.rng.unit();
            let eye = q3(f * r * g.rng.range(0.0, 0.5) + g.rng.in_ball() * 0.1 * r);
            let look_at = q3(Vec3::from_array(eye) + (f + g.rng.in_ball() * 0.2) * r);
            let camera = Gen::camera(eye, look_at, g.rng.range(40.0, 90.0), opts);
            // Its nearest point is 1.2 R from the origin: outside the scene.
            g.used_mirror = true;
            let mirror = Node::Sphere {
                center: q3(f * 3.2 * r),
                radius: 2.0 * r,
                material: Some(MIRROR.into()),
            };
            let mut objects = g.group(primitives - 1, Vec3::ZERO, r, 1, opts.surfaces);
            objects.push(mirror);
            (camera, objects)
        }
        CameraPlacement::Inside | CameraPlacement::BehindEye => {
            // Looking at a point of the scene, or anywhere.
            let eye = g.rng.in_ball() * 0.8 * r;
            let target = g.rng.in_ball() * 0.5 * r;
            let dir = if (target - eye).length() > 0.1 * r && g.rng.chance(0.8) {
                (target - eye).normalize()
            } else {
                g.rng.unit()
            };
            let eye = q3(eye);
            let look_at = q3(Vec3::from_array(eye) + dir * r * 0.5);
            let camera = Gen::camera(eye, look_at, g.rng.range(40.0, 110.0), opts);
            (camera, g.group(primitives, Vec3::ZERO, r, 1, opts.surfaces))
        }
        _ => {
            let eye = q3(g.rng.unit() * r * g.rng.range(1.15, 2.2));
            let look_at = q3(g.rng.in_ball() * 0.3 * r);
            let camera = Gen::camera(eye, look_at, g.rng.range(25.0, 70.0), opts);
            (camera, g.group(primitives, Vec3::ZERO, r, 1, opts.surfaces))
        }
    };
    if primitives == 0 {
        objects.clear();
    }
    let n_lights = opts.lights.unwrap_or_else(|| g.rng.below(4) as u32).min(3);
    let lights = (0..n_lights)
        .map(|_| Light {
            position: q3(g.rng.unit() * r * g.rng.range(1.1, 2.5)),
            color: [
                q(g.rng.range(0.3, 1.0)),
                q(g.rng.range(0.3, 1.0)),
                q(g.rng.range(0.3, 1.0)),
            ],
        })
        .collect();
    let materials = PALETTE[..g.palette]
        .iter()
        .chain(g.used_mirror.then_some(&PALETTE[MATTE]))
        .map(|(name, m)| (name.to_string(), m()))
        .collect::<BTreeMap<_, _>>();
    SceneFile {
        camera,
        background: [
            q(g.rng.range(0.0, 0.3)),
            q(g.rng.range(0.0, 0.3)),
            q(g.rng.range(0.1, 0.4)),
        ],
        ambient: [1.0; 3],
        lights,
        materials,
        objects,
        max_depth: opts.trace_depth,
    }
}

/// Named materials: the matte ones first, then the mirror and the glass.
type MaterialFn = fn() -> Material;
const MIRROR: &str = "mirror";
const MATTE: usize = 4;
const PALETTE: [(&str, MaterialFn); 6] = [
    ("red", || matte([0.8, 0.15, 0.1])),
    ("green", || matte([0.2, 0.7, 0.25])),
    ("blue", || matte([0.15, 0.3, 0.8])),
    ("white", || Material {
        specular: Some(0.5),
        shininess: Some(40.0),
        ..matte([0.9, 0.9, 0.9])
    }),
    (MIRROR, || Material {
        color: Some([0.9, 0.9, 0.95]),
        diffuse: Some(0.1),
        specular: Some(0.6),
        shininess: Some(80.0),
        reflect: Some(0.8),
        ..Material::default()
    }),
    ("glass", || Material {
        color: Some([1.0, 1.0, 1.0]),
        ambient: Some(0.0),
        diffuse: Some(0.05),
        specular: Some(0.5),
        shininess: Some(100.0),
        reflect: Some(0.1),
        transmit: Some(0.85),
        ior: Some(1.5),
        ..Material::default()
    }),
];

fn matte(color: Vector) -> Material {
    Material {
        color: Some(color),
        ..Material::default()
    }
}

/// Operators a node may be.
#[derive(Clone, Copy, PartialEq)]
enum OpKind {
    Union,
    Intersection,
    Difference,
    Assembly,
}

struct Gen {
    rng: SplitMix64,
    max_level: u32,
    /// How many of `PALETTE` random nodes may use.
    palette: usize,
    used_mirror: bool,
}

impl Gen {
    fn camera(eye: Vector, look_at: Vector, fov_y: f64, opts: &RandomCsgOptions) -> Camera {
        let f = (Vec3::from_array(look_at) - Vec3::from_array(eye)).normalize();
        // Far from parallel to the view, whatever the rounding did.
        let up = if f.z.abs() < 0.9 {
            [0.0, 0.0, 1.0]
        } else {
            [0.0, 1.0, 0.0]
        };
        Camera {
            eye,
            look_at,
            up,
            fov_y: (fov_y * 10.0).round() / 10.0,
            width: opts.width.max(1),
            height: opts.height.max(1),
        }
    }

    fn material(&mut self) -> Option<String> {
        self.rng
            .chance(0.3)
            .then(|| PALETTE[self.rng.below(self.palette)].0.to_string())
    }

    /// The children of an operator at operator level `level` with `n`
    /// primitives below it, inside the ball (c, r). Level 1 is the objects
    /// list, which is a union.
    fn group(&mut self, n: usize, c: Vec3, r: f64, level: u32, surfaces: bool) -> Vec<Node> {
        self.children(OpKind::Union, n, c, r, level, surfaces)
    }

    fn children(
        &mut self,
        op: OpKind,
        n: usize,
        c: Vec3,
        r: f64,
        level: u32,
        surfaces: bool,
    ) -> Vec<Node> {
        if n == 0 {
            return Vec::new();
        }
        let k = if level >= self.max_level {
            n
        } else {
            2 + self.rng.below(n.min(5) - 1)
        }
        .min(n);
        let counts = self.split(n, k);
        let surfaces = surfaces && matches!(op, OpKind::Union | OpKind::Assembly);
        // Assembly children get disjoint balls: slots of a g×g×g grid in the
        // cube inscribed in the parent's ball.
        let g = (1..).find(|g| g * g * g >= k).unwrap_or(1);
        let mut slots: Vec<usize> = (0..g * g * g).collect();
        self.rng.shuffle(&mut slots);
        let half = r / 3f64.sqrt();
        let cell = 2.0 * half / g as f64;
        let mut out = Vec::with_capacity(k);
        for (i, &m) in counts.iter().enumerate() {
            // A child ball (cc, rr) with |cc − c| + rr ≤ r. Operands of
            // intersections nearly share their centre, so they overlap;
            // subtrahends sit near the first operand's surface, taking bites.
            let (cc, rr) = match op {
                OpKind::Union => {
                    let rr = r * self.rng.range(0.4, 0.7);
                    (c + self.rng.in_ball() * (r - rr), rr)
                }
                OpKind::Intersection => {
                    let rr = r * self.rng.range(0.75, 0.95);
                    (c + self.rng.in_ball() * (r - rr) * 0.5, rr)
                }
                OpKind::Difference if i == 0 => (c + self.rng.in_ball() * 0.05 * r, 0.95 * r),
                OpKind::Difference => {
                    let rr = r * self.rng.range(0.25, 0.5);
                    (
                        c + self.rng.unit() * (r - rr) * self.rng.range(0.5, 1.0),
                        rr,
                    )
                }
                OpKind::Assembly => {
                    let s = slots[i];
                    let ijk = Vec3::new((s % g) as f64, (s / g % g) as f64, (s / (g * g)) as f64);
                    (c - Vec3::splat(half) + (ijk + 0.5) * cell, 0.45 * cell)
                }
            };
            out.push(self.subtree(m, cc, rr, level + 1, surfaces, true));
        }
        out
    }

    /// `n` as a sum of `k` positive parts, in random proportions.
    fn split(&mut self, n: usize, k: usize) -> Vec<usize> {
        let mut counts = vec![1; k];
        let weights: Vec<f64> = (0..k).map(|_| self.rng.range(0.1, 1.0)).collect();
        let total: f64 = weights.iter().sum();
        for _ in k..n {
            let mut x = self.rng.range(0.0, total);
            let mut i = 0;
            while i + 1 < k && x >= weights[i] {
                x -= weights[i];
                i += 1;
            }
            counts[i] += 1;
        }
        counts
    }

    /// A node with `n` primitives inside the ball (c, r), an operator at
    /// `level` if it needs one.
    fn subtree(
        &mut self,
        n: usize,
        c: Vec3,
        r: f64,
        level: u32,
        surfaces: bool,
        wrap: bool,
    ) -> Node {
        if wrap && self.rng.chance(0.25) {
            return self.transformed(n, c, r, level, surfaces);
        }
        if n == 1 {
            return self.leaf(c, r, surfaces);
        }
        let op = [
            OpKind::Union,
            OpKind::Intersection,
            OpKind::Difference,
            OpKind::Assembly,
        ][self.rng.below(4)];
        let material = self.material();
        let children = self.children(op, n, c, r, level, surfaces);
        match op {
            OpKind::Union => Node::Union { children, material },
            OpKind::Intersection => Node::Intersection { children, material },
            OpKind::Difference => Node::Difference { children, material },
            OpKind::Assembly => Node::Assembly { children, material },
        }
    }

    /// A random transform of a subtree built about the origin. Its scale
    /// stretches by at most `m`, so the child is built in a ball of radius
    /// r/m and ends up in (c, r).
    fn transformed(&mut self, n: usize, c: Vec3, r: f64, level: u32, surfaces: bool) -> Node {
        let mut scale = [0.0; 3];
        for s in &mut scale {
            *s = (self.rng.range(0.5, 2.0) * 100.0).round() / 100.0;
        }
        if self.rng.chance(0.1) {
            scale[self.rng.below(3)] *= -1.0;
        }
        let m = scale.iter().fold(0.0f64, |m, s| m.max(s.abs()));
        let rotate = self.rotation();
        let material = self.material();
        let child = self.subtree(n, Vec3::ZERO, r / m, level, surfaces, false);
        Node::Transform {
            translate: q3(c),
            rotate,
            scale,
            child: Box::new(child),
            material,
        }
    }

    fn rotation(&mut self) -> Vector {
        let mut a = [0.0; 3];
        for x in &mut a {
            *x = (self.rng.range(-180.0, 180.0) * 10.0).round() / 10.0;
        }
        a
    }

    /// A random axis: along a coordinate axis one time in three (faces on
    /// shared planes), else any direction.
    fn axis(&mut self) -> Vec3 {
        if self.rng.chance(1.0 / 3.0) {
            let mut v = Vec3::ZERO;
            v[self.rng.below(3)] = if self.rng.chance(0.5) { 1.0 } else { -1.0 };
            v
        } else {
            self.rng.unit()
        }
    }

    /// A primitive inside the ball (c, r). Sizes have floors so that
    /// rounding never makes them degenerate.
    fn leaf(&mut self, c: Vec3, r: f64, surfaces: bool) -> Node {
        let material = self.material();
        let kinds = if surfaces { 6 } else { 4 };
        let center = q3(c);
        match self.rng.below(kinds) {
            0 => Node::Sphere {
                center,
                radius: q(r * self.rng.range(0.4, 1.0)).max(0.002),
                material,
            },
            1 => {
                let mut min = [0.0; 3];
                let mut max = [0.0; 3];
                for a in 0..3 {
                    let h = (r * self.rng.range(0.2, 0.577)).max(0.002);
                    min[a] = q(c[a] - h);
                    max[a] = q(c[a] + h);
                }
                Node::Box { min, max, material }
            }
            k @ (2 | 3) => {
                // Half length and radius with hl² + ρ² ≤ r².
                let axis = self.axis();
                let hl = (r * self.rng.range(0.2, 0.8)).max(0.002);
                let room = (r * r - hl * hl).max(0.0).sqrt();
                let base = q3(c - axis * hl);
                let top = q3(c + axis * hl);
                let capped = !(surfaces && self.rng.chance(0.3));
                let radius = |g: &mut Gen| q(room * g.rng.range(0.3, 1.0)).max(0.002);
                if k == 2 {
                    Node::Cylinder {
                        base,
                        top,
                        radius: radius(self),
                        capped,
                        material,
                    }
                } else {
                    // A point at the top, at the base, or none.
                    let (mut br, mut tr) = (radius(self), radius(self));
                    match self.rng.below(10) {
                        0..=2 => tr = 0.0,
                        3 => br = 0.0,
                        _ => {}
                    }
                    Node::Cone {
                        base,
                        base_radius: br,
                        top,
                        top_radius: tr,
                        capped,
                        material,
                    }
                }
            }
            4 => {
                // Corners about a third of a turn apart: never collinear.
                let (u, v) = self.plane();
                let a0 = self.rng.range(0.0, TAU);
                let mut p = [[0.0; 3]; 3];
                for (i, p) in p.iter_mut().enumerate() {
                    let a = a0 + i as f64 * TAU / 3.0 + self.rng.range(-0.4, 0.4);
                    let rho = r * self.rng.range(0.5, 1.0);
                    *p = q3(c + (u * a.cos() + v * a.sin()) * rho);
                }
                Node::Triangle {
                    a: p[0],
                    b: p[1],
                    c: p[2],
                    material,
                }
            }
            _ => {
                // Star-shaped about its centre (so simple), in the plane
                // z = 0 so that rounding keeps it planar; a transform turns it,
                // one time in three about z alone, so that it stays in a
                // coordinate plane (met as a box's face, `shape::on_plane`).
                let level = self.rng.chance(1.0 / 3.0);
                let n = 3 + self.rng.below(6);
                let gap = TAU / n as f64;
                let a0 = self.rng.range(0.0, TAU);
                let vertices = (0..n)
                    .map(|i| {
                        let a = a0 + (i as f64 + self.rng.range(-0.3, 0.3)) * gap;
                        let rho = r * self.rng.range(0.4, 1.0);
                        [q(rho * a.cos()), q(rho * a.sin()), 0.0]
                    })
                    .collect();
                let mut rotate = self.rotation();
                if level {
                    rotate[0] = 0.0;
                    rotate[1] = 0.0;
                }
                Node::Transform {
                    translate: center,
                    rotate,
                    scale: [1.0; 3],
                    child: Box::new(Node::Polygon { vertices, material }),
                    material: None,
                }
            }
        }
    }

    /// Two orthonormal vectors of a random plane.
    fn plane(&mut self) -> (Vec3, Vec3) {
        let n = self.rng.unit();
        let u = n.any_orthonormal_vector();
        (u, n.cross(u))
    }
}

/// Rounded to 3 decimals; exact through RON and JSON text.
fn q(x: f64) -> f64 {
    (x * 1000.0).round() / 1000.0
}

fn q3(v: Vec3) -> Vector {
    [q(v.x), q(v.y), q(v.z)]
}

/// SplitMix64 (Steele, Lea and Flood 2014): tiny, fast, and good enough for
/// test scenes; its output depends on nothing but the seed.
pub(crate) struct SplitMix64(pub(crate) u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub(crate) fn unit_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    pub(crate) fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit_f64()
    }

    /// Uniform in `0..n` (n > 0).
    pub(crate) fn below(&mut self, n: usize) -> usize {
        ((self.next_u64() as u128 * n as u128) >> 64) as usize
    }

    pub(crate) fn chance(&mut self, p: f64) -> bool {
        self.unit_f64() < p
    }

    /// Uniform in the unit ball.
    fn in_ball(&mut self) -> Vec3 {
        loop {
            let v = Vec3::new(
                self.range(-1.0, 1.0),
                self.range(-1.0, 1.0),
                self.range(-1.0, 1.0),
            );
            if v.length_squared() <= 1.0 {
                return v;
            }
        }
    }

    /// Uniform on the unit sphere.
    fn unit(&mut self) -> Vec3 {
        loop {
            let v = self.in_ball();
            let l = v.length();
            if l > 0.1 {
                return v / l;
            }
        }
    }

    fn shuffle<T>(&mut self, v: &mut [T]) {
        for i in (1..v.len()).rev() {
            v.swap(i, self.below(i + 1));
        }
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;
    use crate::scene::SceneSyntax;
    use crate::scene::load::{parse_model_str, parse_scene_str, scene_to_string};

    /// Operator levels of a node, transforms not counted.
    fn levels(n: &Node) -> u32 {
        match n {
            Node::Union { children, .. }
            | Node::Intersection { children, .. }
            | Node::Difference { children, .. }
            | Node::Assembly { children, .. } => 1 + children.iter().map(levels).max().unwrap_or(0),
            Node::Transform { child, .. } => levels(child),
            _ => 0,
        }
    }

    fn options(seed: u64) -> RandomCsgOptions {
        RandomCsgOptions {
            max_tree_depth: 1 + (seed % MAX_TREE_DEPTH as u64) as u32,
            surfaces: !seed.is_multiple_of(3),
            mirrors_and_glass: !seed.is_multiple_of(4),
            camera: [
                CameraPlacement::Outside,
                CameraPlacement::Inside,
                CameraPlacement::BehindEye,
                CameraPlacement::Mixed,
            ][(seed % 4) as usize],
            ..RandomCsgOptions::default()
        }
    }

    #[test]
    fn generated_scenes_load_from_ron_and_json_and_read_back_exactly() {
        for seed in 0..50 {
            let opts = options(seed);
            let n = (seed as usize * 7) % 61;
            let model = random_csg(seed, n, &opts);
            for syntax in [SceneSyntax::Ron, SceneSyntax::Json] {
                let text = scene_to_string(&model, syntax).unwrap();
                let scene = parse_scene_str(&text, syntax, Path::new("gen"))
                    .unwrap_or_else(|e| panic!("seed {seed}: {e}\n{text}"));
                assert_eq!(scene.primitives.len(), n, "seed {seed}");
                assert_eq!(
                    parse_model_str(&text, syntax, Path::new("gen")).unwrap(),
                    model,
                    "seed {seed}"
                );
            }
            let depth = 1 + model.objects.iter().map(levels).max().unwrap_or(0);
            assert!(depth <= opts.max_tree_depth, "seed {seed}: depth {depth}");
        }
    }

    #[test]
    fn same_seed_same_scene() {
        let opts = RandomCsgOptions::default();
        assert_eq!(random_csg(7, 30, &opts), random_csg(7, 30, &opts));
        assert_ne!(random_csg(7, 30, &opts), random_csg(8, 30, &opts));
    }

    #[test]
    fn deepest_trees_use_every_operator_and_primitive() {
        let mut kinds = std::collections::BTreeSet::new();
        fn walk(n: &Node, kinds: &mut std::collections::BTreeSet<&'static str>) {
            kinds.insert(n.kind());
            match n {
                Node::Union { children, .. }
                | Node::Intersection { children, .. }
                | Node::Difference { children, .. }
                | Node::Assembly { children, .. } => children.iter().for_each(|c| walk(c, kinds)),
                Node::Transform { child, .. } => walk(child, kinds),
                _ => {}
            }
        }
        let opts = RandomCsgOptions {
            max_tree_depth: MAX_TREE_DEPTH,
            ..RandomCsgOptions::default()
        };
        for seed in 0..20 {
            let m = random_csg(seed, 60, &opts);
            m.objects.iter().for_each(|n| walk(n, &mut kinds));
        }
        assert_eq!(kinds.len(), 11, "{kinds:?}");
    }
}
