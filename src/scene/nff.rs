//! Eric Haines' Neutral File Format (NFF, the format of the Standard
//! Procedural Databases): import into the scene `model` (`parse_nff`), and
//! export of the models NFF can express (`write_nff`). Owns NFF syntax and
//! the mapping of its entities onto `SCENE_FORMAT.md`; validation is
//! `load`'s, with errors pointed back at NFF lines by `NffScene::locate`.
//!
//! Entities, one per line (`#` starts a comment anywhere), numbers
//! separated by white space; an entity's data may continue on the lines the
//! format says:
//!
//! - `v`, then lines `from x y z`, `at x y z`, `up x y z`, `angle a`,
//!   `hither h` (optional), `resolution w h` (optional, default 512 512).
//!   Required, once. NFF's `angle` is measured "from the centre of the top
//!   pixel row to the bottom pixel row" (and left to right column: pixels
//!   are square), while `fov_y` spans the image's edges, so
//!   `tan(fov_y/2) = tan(angle/2)·h/(h−1)` with `h` the vertical resolution.
//!   `hither` is the near plane of hidden-surface renderers; a ray tracer's
//!   eye rays start at the eye, so it is checked and ignored.
//! - `b r g b`: the background colour.
//! - `l x y z [r g b]`: a point light. Without a colour, a light gets the
//!   SPD's suggested relative intensity `sqrt(n)/(2n)` (grey) for `n` lights
//!   in the file, so that many lights do not wash the image out.
//! - `f r g b Kd Ks Shine T ior`: the material of the objects that follow
//!   (named `f@LINE`). `Ks` is both the Phong coefficient and the reflection
//!   coefficient; ambient is 0.1, as in the SPD's own NFF reader. An `ior` of
//!   0 or less on an opaque material (`T == 0`) is meaningless and read as 1.
//!   Objects before any `f` take the default material.
//! - `s x y z r`: a sphere. A negative radius ("only the inside is visible")
//!   is taken by its magnitude: spheres here are solids, seen from both sides.
//! - `c`, then `x y z r` (base) and `x y z r` (apex), each on its own line
//!   (or all eight numbers on the `c` line): an open cylinder (equal radii) or
//!   cone. Negative radii are taken by magnitude, as above.
//! - `p n`, then `n` lines `x y z`: a polygon (a triangle when `n` is 3).
//! - `pp n`, then `n` lines `x y z nx ny nz`: the same; normals are ignored.
//!
//! Unknown entities and malformed lines are `Error::Syntax` with the line.
//!
//! **Export** writes exactly what the importer reads back as the same scene
//! (numbers in their shortest exact decimal form, so a written file renders
//! like its model up to the `angle` ↔ `fov_y` conversion's last bit), and
//! refuses, naming the node or field, what NFF cannot say: CSG operators
//! other than unions and assemblies (which are flattened: NFF's object list
//! is itself a union), boxes and capped cylinders and cones (NFF's only
//! solid is the sphere; decomposing a box into six polygons would turn a
//! solid into surfaces, which changes refraction and CSG meaning, so we do
//! not pretend), transforms other than similarities of spheres, cylinders
//! and cones (a scaled sphere is no NFF sphere; polygons take any affine
//! map), materials whose `ambient` is not 0.1 or whose `reflect` differs
//! from `specular` (NFF's `Ks` is both), a global `ambient` other than
//! white and a `max_depth` other than 5 (what the importer sets).

use std::path::Path;

use std::fmt::Write as _;

use super::model::{Camera, Light, Material, Node, SceneFile, Vector};
use crate::geom::{Affine, Vec3};
use crate::{Error, Result};

/// An imported NFF file: the model, and where its parts came from.
#[derive(Clone, Debug)]
pub struct NffScene {
    pub model: SceneFile,
    /// The line of each `model.objects[i]`.
    pub object_lines: Vec<usize>,
    /// The line of each `model.lights[i]`.
    pub light_lines: Vec<usize>,
    /// The line of the `v` entity.
    pub view_line: usize,
}

impl NffScene {
    /// Points a validation error at the NFF line its path came from
    /// (`objects[3].Sphere.radius` → `objects[3].Sphere.radius (line 17)`);
    /// material names already carry their `f` line.
    pub fn locate(&self, e: Error) -> Error {
        let Error::Invalid {
            file,
            path,
            message,
        } = e
        else {
            return e;
        };
        let indexed = |prefix: &str, lines: &[usize]| {
            let rest = path.strip_prefix(prefix)?;
            let i: usize = rest[..rest.find(']')?].parse().ok()?;
            lines.get(i).copied()
        };
        let line = indexed("objects[", &self.object_lines)
            .or_else(|| indexed("lights[", &self.light_lines))
            .or_else(|| path.starts_with("camera").then_some(self.view_line));
        let path = match line {
            Some(n) => format!("{path} (line {n})"),
            None => path,
        };
        Error::Invalid {
            file,
            path,
            message,
        }
    }
}

/// The material of an NFF `f` entity (`f r g b Kd Ks Shine T ior`): `Ks`
/// is both the Phong and the reflection coefficient, ambient is 0.1.
/// Generators of SPD scenes use it too, so their models are NFF's.
pub fn material(color: Vector, kd: f64, ks: f64, shine: f64, t: f64, ior: f64) -> Material {
    Material {
        color: Some(color),
        ambient: Some(0.1),
        diffuse: Some(kd),
        specular: Some(ks),
        shininess: Some(shine),
        reflect: Some(ks),
        transmit: Some(t),
        ior: Some(ior),
        base: None,
    }
}

/// The colour NFF gives each of `n` lights written without one: the SPD's
/// suggested relative intensity `sqrt(n)/(2n)`, grey.
pub fn light_grey(n: usize) -> Vector {
    let n = n.max(1) as f64;
    [n.sqrt() / (2.0 * n); 3]
}

/// One word of a line, with its 1-based column.
#[derive(Clone, Copy)]
struct Word<'a> {
    text: &'a str,
    column: usize,
}

/// A non-blank line without its comment.
struct Line<'a> {
    number: usize,
    words: Vec<Word<'a>>,
}

struct Parser<'a> {
    file: &'a Path,
    lines: Vec<Line<'a>>,
    next: usize,
    /// Line number just past the end, for "ended early" errors.
    end_line: usize,
}

const ENTITIES: &str = "`v`, `b`, `l`, `f`, `c`, `s`, `p` or `pp`";
const VIEW_WORDS: [&str; 6] = ["from", "at", "up", "angle", "hither", "resolution"];

/// Imports NFF text; `file` is used in messages.
pub fn parse_nff(text: &str, file: &Path) -> Result<NffScene> {
    let mut lines = Vec::new();
    let mut end_line = 1;
    for (i, raw) in text.lines().enumerate() {
        end_line = i + 2;
        let code = raw.split('#').next().unwrap_or("");
        let mut words = Vec::new();
        let mut start = None;
        for (col, (byte, ch)) in code.char_indices().enumerate() {
            match (ch.is_whitespace(), start) {
                (false, None) => start = Some((byte, col + 1)),
                (true, Some((s, column))) => {
                    words.push(Word {
                        text: &code[s..byte],
                        column,
                    });
                    start = None;
                }
                _ => {}
            }
        }
        if let Some((s, column)) = start {
            words.push(Word {
                text: &code[s..],
                column,
            });
        }
        if !words.is_empty() {
            lines.push(Line {
                number: i + 1,
                words,
            });
        }
    }
    Parser {
        file,
        lines,
        next: 0,
        end_line,
    }
    .scene()
}

/// A light as read, its colour decided once the number of lights is known.
struct PendingLight {
    position: Vector,
    color: Option<Vector>,
    line: usize,
}

impl<'a> Parser<'a> {
    fn error(&self, line: usize, column: usize, message: String) -> Error {
        Error::Syntax {
            file: self.file.to_path_buf(),
            line,
            column,
            message,
        }
    }

    fn scene(mut self) -> Result<NffScene> {
        let mut camera: Option<(Camera, usize)> = None;
        let mut background = [0.0; 3];
        let mut lights: Vec<PendingLight> = Vec::new();
        let mut materials = std::collections::BTreeMap::new();
        let mut current: Option<String> = None;
        let mut objects = Vec::new();
        let mut object_lines = Vec::new();

        while self.next < self.lines.len() {
            let at = self.next;
            self.next += 1;
            let number = self.lines[at].number;
            let words = self.lines[at].words.clone();
            let (head, args) = (words[0], &words[1..]);
            match head.text {
                "v" => {
                    if let Some((_, first)) = &camera {
                        return Err(self.error(
                            number,
                            head.column,
                            format!("a second view entity `v` (the first is on line {first})"),
                        ));
                    }
                    self.no_args(number, args)?;
                    camera = Some((self.view(number)?, number));
                }
                "b" => background = self.numbers::<3>(number, head, args)?,
                "l" => {
                    let (position, color) = match args.len() {
                        3 => (self.numbers::<3>(number, head, args)?, None),
                        6 => {
                            let v = self.numbers::<6>(number, head, args)?;
                            ([v[0], v[1], v[2]], Some([v[3], v[4], v[5]]))
                        }
                        n => {
                            return Err(self.error(
                                number,
                                head.column,
                                format!("`l` takes 3 numbers (x y z) or 6 (x y z r g b), got {n}"),
                            ));
                        }
                    };
                    lights.push(PendingLight {
                        position,
                        color,
                        line: number,
                    });
                }
                "f" => {
                    let [r, g, b, kd, ks, shine, t, ior] = self.numbers::<8>(number, head, args)?;
                    let name = format!("f@{number}");
                    let ior = if t == 0.0 && ior <= 0.0 { 1.0 } else { ior };
                    materials.insert(name.clone(), material([r, g, b], kd, ks, shine, t, ior));
                    current = Some(name);
                }
                "s" => {
                    let [x, y, z, r] = self.numbers::<4>(number, head, args)?;
                    objects.push(Node::Sphere {
                        center: [x, y, z],
                        radius: r.abs(),
                        material: current.clone(),
                    });
                    object_lines.push(number);
                }
                "c" => {
                    let v: [f64; 8] = if args.is_empty() {
                        let a = self.data_line::<4>("the base of `c` (x y z radius)")?;
                        let b = self.data_line::<4>("the apex of `c` (x y z radius)")?;
                        [a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3]]
                    } else {
                        self.numbers::<8>(number, head, args)?
                    };
                    let (base, top) = ([v[0], v[1], v[2]], [v[4], v[5], v[6]]);
                    let (r0, r1) = (v[3].abs(), v[7].abs());
                    objects.push(if r0 == r1 {
                        Node::Cylinder {
                            base,
                            top,
                            radius: r0,
                            capped: false,
                            material: current.clone(),
                        }
                    } else {
                        Node::Cone {
                            base,
                            base_radius: r0,
                            top,
                            top_radius: r1,
                            capped: false,
                            material: current.clone(),
                        }
                    });
                    object_lines.push(number);
                }
                "p" | "pp" => {
                    let patch = head.text == "pp";
                    let count = match args {
                        [n] => n.text.parse::<usize>().ok().filter(|n| *n >= 3),
                        _ => None,
                    };
                    let Some(count) = count else {
                        return Err(self.error(
                            number,
                            head.column,
                            format!(
                                "`{}` takes one whole number, the vertex count (at least 3)",
                                head.text
                            ),
                        ));
                    };
                    let mut vertices = Vec::new();
                    for _ in 0..count {
                        let v = if patch {
                            let v =
                                self.data_line::<6>("a vertex and its normal (x y z nx ny nz)")?;
                            [v[0], v[1], v[2]]
                        } else {
                            self.data_line::<3>("a vertex (x y z)")?
                        };
                        vertices.push(v);
                    }
                    let material = current.clone();
                    objects.push(match vertices[..] {
                        [a, b, c] => Node::Triangle { a, b, c, material },
                        _ => Node::Polygon { vertices, material },
                    });
                    object_lines.push(number);
                }
                other => {
                    return Err(self.error(
                        number,
                        head.column,
                        format!("unknown NFF entity `{other}`, expected {ENTITIES}"),
                    ));
                }
            }
        }

        let Some((camera, view_line)) = camera else {
            return Err(self.error(1, 1, "no view entity `v`: an NFF scene needs one".into()));
        };
        let grey = light_grey(lights.len());
        let light_lines = lights.iter().map(|l| l.line).collect();
        let lights = lights
            .into_iter()
            .map(|l| Light {
                position: l.position,
                color: l.color.unwrap_or(grey),
            })
            .collect();
        Ok(NffScene {
            model: SceneFile {
                camera,
                background,
                ambient: [1.0; 3],
                lights,
                materials,
                objects,
                max_depth: 5,
            },
            object_lines,
            light_lines,
            view_line,
        })
    }

    fn no_args(&self, line: usize, args: &[Word]) -> Result<()> {
        match args.first() {
            None => Ok(()),
            Some(w) => Err(self.error(line, w.column, format!("unexpected `{}`", w.text))),
        }
    }

    /// The lines of a `v` entity, up to the first line that is not one.
    fn view(&mut self, v_line: usize) -> Result<Camera> {
        let (mut from, mut at, mut up) = (None, None, None);
        // With its line and column, to point at it if it is out of range.
        let mut angle: Option<(f64, usize, usize)> = None;
        let mut hither = None;
        let mut resolution = None;
        while let Some(line) = self.lines.get(self.next) {
            let (number, head) = (line.number, line.words[0]);
            if !VIEW_WORDS.contains(&head.text) {
                break;
            }
            let words = line.words.clone();
            self.next += 1;
            let args = &words[1..];
            let already = match head.text {
                "from" => from
                    .replace(self.numbers::<3>(number, head, args)?)
                    .is_some(),
                "at" => at.replace(self.numbers::<3>(number, head, args)?).is_some(),
                "up" => up.replace(self.numbers::<3>(number, head, args)?).is_some(),
                "angle" => {
                    let [a] = self.numbers::<1>(number, head, args)?;
                    angle.replace((a, number, args[0].column)).is_some()
                }
                // Checked (a finite number) and ignored: see the module docs.
                "hither" => hither
                    .replace(self.numbers::<1>(number, head, args)?)
                    .is_some(),
                _ => {
                    let r = match args {
                        [w, h] => w.text.parse::<u32>().ok().zip(h.text.parse::<u32>().ok()),
                        _ => None,
                    };
                    let Some(r) = r else {
                        return Err(self.error(
                            number,
                            head.column,
                            "`resolution` takes two whole numbers".into(),
                        ));
                    };
                    resolution.replace(r).is_some()
                }
            };
            if already {
                return Err(self.error(
                    number,
                    head.column,
                    format!("a second `{}` in the view", head.text),
                ));
            }
        }
        let missing = |what: &str| {
            self.error(
                v_line,
                1,
                format!("the view entity `v` has no `{what}` line"),
            )
        };
        let from = from.ok_or_else(|| missing("from"))?;
        let at = at.ok_or_else(|| missing("at"))?;
        let up = up.ok_or_else(|| missing("up"))?;
        let (angle, angle_line, angle_column) = angle.ok_or_else(|| missing("angle"))?;
        // Outside (0, 180) the conversion below folds over: refuse here,
        // where the number the user wrote can be quoted.
        if !(angle > 0.0 && angle < 180.0) {
            return Err(self.error(
                angle_line,
                angle_column,
                format!("`angle` must be in (0, 180) degrees, got {angle}"),
            ));
        }
        let (width, height) = resolution.unwrap_or((512, 512));
        let fov_y = fov_y_of_angle(angle, height);
        Ok(Camera {
            eye: from,
            look_at: at,
            up,
            fov_y,
            width,
            height,
        })
    }

    /// Exactly `N` finite numbers in `args`.
    fn numbers<const N: usize>(&self, line: usize, head: Word, args: &[Word]) -> Result<[f64; N]> {
        if args.len() != N {
            let (column, got) = match args.get(N) {
                Some(w) => (w.column, format!("unexpected `{}`", w.text)),
                None => (head.column, format!("got {}", args.len())),
            };
            return Err(self.error(
                line,
                column,
                format!(
                    "`{}` takes {N} number{}, {got}",
                    head.text,
                    if N == 1 { "" } else { "s" }
                ),
            ));
        }
        let mut out = [0.0; N];
        for (o, w) in out.iter_mut().zip(args) {
            *o = self.number(line, *w)?;
        }
        Ok(out)
    }

    fn number(&self, line: usize, w: Word) -> Result<f64> {
        match w.text.parse::<f64>() {
            Ok(x) if x.is_finite() => Ok(x),
            _ => Err(self.error(
                line,
                w.column,
                format!("expected a finite number, got `{}`", w.text),
            )),
        }
    }

    /// The next line, which must hold exactly `N` numbers (`what`).
    fn data_line<const N: usize>(&mut self, what: &str) -> Result<[f64; N]> {
        let Some(line) = self.lines.get(self.next) else {
            return Err(self.error(
                self.end_line,
                1,
                format!("the file ends where {what} was expected"),
            ));
        };
        let (number, words) = (line.number, line.words.clone());
        self.next += 1;
        if words.len() != N {
            return Err(self.error(
                number,
                words[0].column,
                format!("expected {what}: {N} numbers, got {} word(s)", words.len()),
            ));
        }
        let mut out = [0.0; N];
        for (o, w) in out.iter_mut().zip(&words) {
            *o = self.number(number, *w)?;
        }
        Ok(out)
    }
}

// ---------------------------------------------------------------------------
// Export.

/// The shortest decimal text that parses back to exactly `x` (Rust's `{:?}`
/// for non-integers, which uses an exponent only for very large or small
/// magnitudes), with integers written without a fraction. Both NFF readers
/// (`strtod`) and POV-Ray read every form it produces.
pub(crate) fn number(x: f64) -> String {
    if x == 0.0 {
        // Also turns -0 into 0: no reader needs the sign of zero.
        "0".into()
    } else if x.fract() == 0.0 && x.abs() < 1e15 {
        format!("{}", x as i64)
    } else {
        format!("{x:?}")
    }
}

/// `x y z` for NFF.
fn triple(v: Vector) -> String {
    format!("{} {} {}", number(v[0]), number(v[1]), number(v[2]))
}

/// The vertical field of view (degrees, between the image's edges) of NFF's
/// view `angle` over `height` pixel rows (between the centres of the outer
/// rows): `tan(fov_y/2) = tan(angle/2)·h/(h−1)`.
pub fn fov_y_of_angle(angle: f64, height: u32) -> f64 {
    if height > 1 {
        let h = f64::from(height);
        2.0 * ((angle.to_radians() / 2.0).tan() * h / (h - 1.0))
            .atan()
            .to_degrees()
    } else {
        angle
    }
}

/// NFF's view angle for a vertical field of view of `fov_y` degrees over
/// `height` pixel rows: the inverse of `fov_y_of_angle`.
fn nff_angle(fov_y: f64, height: u32) -> f64 {
    if height > 1 {
        let h = f64::from(height);
        2.0 * ((fov_y.to_radians() / 2.0).tan() * (h - 1.0) / h)
            .atan()
            .to_degrees()
    } else {
        fov_y
    }
}

/// Writes `model` as NFF, or refuses with an `Error::Invalid` naming the
/// node or field NFF cannot express (see the module docs); `source` names
/// the scene in messages. The model is validated first, so a written file
/// always loads.
pub fn write_nff(model: &SceneFile, source: &Path) -> Result<String> {
    // Flattening walks the tree once per level: on the loading thread's
    // large stack, like every other walk of a model.
    super::load::on_load_stack(|| {
        let (scene, _) = super::load::compile(model, source)?;
        let mut w = NffWriter {
            source,
            scene: &scene,
            out: String::new(),
            current: None,
        };
        w.scene(model)?;
        Ok(w.out)
    })?
}

struct NffWriter<'a> {
    source: &'a Path,
    /// The compiled model, for its resolved materials (`base` chains).
    scene: &'a super::Scene,
    out: String,
    /// The index (in `scene.materials`) of the last `f` written.
    current: Option<usize>,
}

impl NffWriter<'_> {
    fn refuse(&self, path: String, message: String) -> Error {
        Error::invalid(self.source, path, message)
    }

    fn scene(&mut self, model: &SceneFile) -> Result<()> {
        let c = &model.camera;
        let distance = (Vec3::from_array(c.look_at) - Vec3::from_array(c.eye)).length();
        // Writing to a String cannot fail (here and below).
        let _ = writeln!(
            self.out,
            "# Written by hypercast from {}\nv\nfrom {}\nat {}\nup {}\nangle {}\n\
             hither {}\nresolution {} {}",
            self.source.display(),
            triple(c.eye),
            triple(c.look_at),
            triple(c.up),
            number(nff_angle(c.fov_y, c.height)),
            // Ignored by ray tracers (and by our importer); hidden-surface
            // renderers want a near plane in front of everything.
            number(distance * 1e-3),
            c.width,
            c.height
        );
        let _ = writeln!(self.out, "b {}", triple(model.background));
        for l in &model.lights {
            let _ = writeln!(self.out, "l {} {}", triple(l.position), triple(l.color));
        }
        for (i, node) in model.objects.iter().enumerate() {
            self.node(node, format!("objects[{i}]"), None, &Affine::IDENTITY)?;
        }
        // After the objects, whose refusals name a node: more telling.
        if model.ambient != [1.0; 3] {
            return Err(self.refuse(
                "ambient".into(),
                format!(
                    "NFF has no global ambient light (its scenes have white), this scene has {}",
                    triple(model.ambient)
                ),
            ));
        }
        if model.max_depth != 5 {
            return Err(self.refuse(
                "max_depth".into(),
                format!(
                    "NFF has no recursion limit (its scenes get 5), this scene has {}",
                    model.max_depth
                ),
            ));
        }
        Ok(())
    }

    /// Writes `node` (at `path`) with the material it inherits and the
    /// composed transforms above it.
    fn node(
        &mut self,
        node: &Node,
        path: String,
        inherited: Option<&str>,
        to_world: &Affine,
    ) -> Result<()> {
        let material = node.material().or(inherited);
        let kind = node.kind();
        let similarity = || {
            to_world.similarity_scale().ok_or_else(|| {
                self.refuse(
                    path.clone(),
                    format!(
                        "a {kind} under a non-uniform scale is no NFF {kind} (NFF has no \
                         transforms; only rotations, translations and uniform scales can be \
                         applied to it)"
                    ),
                )
            })
        };
        match node {
            Node::Union { children, .. } | Node::Assembly { children, .. } => {
                for (i, child) in children.iter().enumerate() {
                    let p = format!("{path}.{kind}.children[{i}]");
                    self.node(child, p, material, to_world)?;
                }
            }
            Node::Transform {
                translate,
                rotate,
                scale,
                child,
                ..
            } => {
                let m = Affine::from_srt(
                    Vec3::from_array(*scale),
                    Vec3::from_array(*rotate),
                    Vec3::from_array(*translate),
                );
                let p = format!("{path}.Transform.child");
                self.node(child, p, material, &to_world.then_inner(&m))?;
            }
            Node::Intersection { .. } | Node::Difference { .. } => {
                return Err(self.refuse(
                    path,
                    format!(
                        "NFF has no CSG: {} cannot be written (NFF's object list is a \
                         union; write .ron, .json or .pov instead)",
                        with_article(kind)
                    ),
                ));
            }
            Node::Box { .. } => {
                return Err(self.refuse(
                    path,
                    "NFF has no box (its only solid is the sphere; six polygons would be \
                     surfaces, not a solid): write .ron, .json or .pov instead"
                        .into(),
                ));
            }
            Node::Cylinder { capped: true, .. } | Node::Cone { capped: true, .. } => {
                return Err(self.refuse(
                    path,
                    format!(
                        "NFF's cylinders and cones are open: a capped {kind} cannot be written \
                         (set `capped: false`, or write .ron, .json or .pov)"
                    ),
                ));
            }
            Node::Sphere { center, radius, .. } => {
                let s = similarity()?;
                self.material(material, &path)?;
                let c = to_world.point(Vec3::from_array(*center)).to_array();
                let _ = writeln!(self.out, "s {} {}", triple(c), number(radius * s));
            }
            Node::Cylinder {
                base, top, radius, ..
            } => {
                let s = similarity()?;
                self.material(material, &path)?;
                self.cone(to_world, *base, radius * s, *top, radius * s);
            }
            Node::Cone {
                base,
                base_radius,
                top,
                top_radius,
                ..
            } => {
                let s = similarity()?;
                self.material(material, &path)?;
                self.cone(to_world, *base, base_radius * s, *top, top_radius * s);
            }
            Node::Triangle { a, b, c, .. } => {
                self.material(material, &path)?;
                self.polygon(to_world, &[*a, *b, *c]);
            }
            Node::Polygon { vertices, .. } => {
                self.material(material, &path)?;
                self.polygon(to_world, vertices);
            }
        }
        Ok(())
    }

    fn cone(&mut self, to_world: &Affine, base: Vector, r0: f64, top: Vector, r1: f64) {
        let b = to_world.point(Vec3::from_array(base)).to_array();
        let t = to_world.point(Vec3::from_array(top)).to_array();
        let _ = writeln!(
            self.out,
            "c\n{} {}\n{} {}",
            triple(b),
            number(r0),
            triple(t),
            number(r1)
        );
    }

    fn polygon(&mut self, to_world: &Affine, vertices: &[Vector]) {
        let _ = writeln!(self.out, "p {}", vertices.len());
        for v in vertices {
            let w = to_world.point(Vec3::from_array(*v)).to_array();
            let _ = writeln!(self.out, "{}", triple(w));
        }
    }

    /// Writes an `f` line when the material (`name`, None for the default)
    /// differs from the last one written, or refuses one NFF cannot hold.
    fn material(&mut self, name: Option<&str>, path: &str) -> Result<()> {
        let names = &self.scene.material_names;
        // The model was compiled, so every name is known; the default is 0.
        let id = name
            .and_then(|n| names.iter().position(|m| m == n))
            .unwrap_or(0);
        if self.current == Some(id) {
            return Ok(());
        }
        let m = &self.scene.materials[id];
        let at = match name {
            Some(n) => format!("materials[{n:?}]"),
            None => format!("{path} (the default material)"),
        };
        if m.ambient != 0.1 {
            return Err(self.refuse(
                at,
                format!(
                    "NFF materials have ambient 0.1, this one has {}",
                    number(m.ambient)
                ),
            ));
        }
        if m.reflect != m.specular {
            return Err(self.refuse(
                at,
                format!(
                    "NFF's Ks is both the Phong and the reflection coefficient, this material \
                     has specular {} and reflect {}",
                    number(m.specular),
                    number(m.reflect)
                ),
            ));
        }
        let _ = writeln!(
            self.out,
            "f {} {} {} {} {} {}",
            triple(m.color.to_array()),
            number(m.diffuse),
            number(m.specular),
            number(m.shininess),
            number(m.transmit),
            number(m.ior)
        );
        self.current = Some(id);
        Ok(())
    }
}

/// `word` with its indefinite article, as a message names a node's kind
/// ("an Intersection", "a Difference").
fn with_article(word: &str) -> String {
    let vowel = word.starts_with(|c: char| "AEIOUaeiou".contains(c));
    format!("{} {word}", if vowel { "an" } else { "a" })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::SceneSyntax;
    use crate::scene::load::{compile_model, parse_model_str};

    const CAMERA: &str =
        "camera: (eye: (0, -10, 2), look_at: (0, 0, 0), fov_y: 40, width: 64, height: 48)";

    fn model(objects: &str) -> SceneFile {
        let text = format!(
            "({CAMERA}, materials: {{\"m\": (specular: 0.3, reflect: 0.3)}}, objects: [{objects}])"
        );
        parse_model_str(&text, SceneSyntax::Ron, Path::new("t.ron")).unwrap()
    }

    /// The refusal's `path: message`.
    fn refusal(objects: &str) -> String {
        match write_nff(&model(objects), Path::new("t.ron")) {
            Err(Error::Invalid { path, message, .. }) => format!("{path}: {message}"),
            other => panic!("expected a refusal, got {other:?}"),
        }
    }

    #[test]
    fn written_nff_reads_back_as_the_same_scene() {
        let m = crate::r#gen::sphereflake::sphereflake(1);
        let text = write_nff(&m, Path::new("flake")).unwrap();
        let back = parse_nff(&text, Path::new("flake.nff")).unwrap().model;
        let (a, _) = compile_model(&m, Path::new("a")).unwrap();
        let (b, _) = compile_model(&back, Path::new("b")).unwrap();
        // Material numbers follow names, which NFF does not keep: compare
        // shapes and the materials themselves.
        assert_eq!(a.primitives.len(), b.primitives.len());
        for (p, q) in a.primitives.iter().zip(&b.primitives) {
            assert_eq!(p.shape, q.shape);
            assert_eq!(a.material(p.material), b.material(q.material));
        }
        assert_eq!(a.lights, b.lights);
        assert_eq!(a.background, b.background);
        assert!((a.camera.fov_y - b.camera.fov_y).abs() < 1e-12);
        assert_eq!(
            (a.camera.eye, a.camera.width, a.camera.height),
            (b.camera.eye, b.camera.width, b.camera.height)
        );
    }

    #[test]
    fn unions_flatten_and_similarities_are_baked() {
        let text = write_nff(
            &model(
                "Union(material: \"m\", children: [Transform(translate: (1, 0, 0), scale: (2, 2, 2),
                    rotate: (0, 0, 90), child: Assembly(children: [Sphere(center: (1, 0, 0), radius: 0.5),
                    Cylinder(base: (0, 0, 0), top: (0, 0, 1), radius: 0.25, capped: false)]))])",
            ),
            Path::new("t.ron"),
        )
        .unwrap();
        let body: Vec<&str> = text.lines().skip_while(|l| !l.starts_with("f ")).collect();
        // Rotating (1, 0, 0) by 90° about z gives (0, 1, 0), to within a
        // last bit of cos 90°.
        assert_eq!(body[0], "f 1 1 1 0.7 0.3 20 0 1");
        let s: Vec<f64> = body[1][2..]
            .split(' ')
            .map(|w| w.parse().unwrap())
            .collect();
        assert!((s[0] - 1.0).abs() < 1e-12 && (s[1] - 2.0).abs() < 1e-12 && s[2] == 0.0);
        assert_eq!(s[3], 1.0);
        assert_eq!(&body[2..], ["c", "1 0 0 0.5", "1 0 2 0.5"]);
    }

    #[test]
    fn what_nff_cannot_say_is_refused_by_name() {
        let e = refusal(
            "Union(children: [Difference(children: [Sphere(center: (0, 0, 0), radius: 1),
                Sphere(center: (1, 0, 0), radius: 1)])])",
        );
        assert!(
            e.starts_with("objects[0].Union.children[0]: NFF has no CSG: a Difference"),
            "{e}"
        );
        let e = refusal(
            "Intersection(children: [Sphere(center: (0, 0, 0), radius: 1),
                Sphere(center: (1, 0, 0), radius: 1)])",
        );
        assert!(
            e.starts_with("objects[0]: NFF has no CSG: an Intersection"),
            "{e}"
        );
        assert!(
            refusal("Box(min: (0, 0, 0), max: (1, 1, 1))")
                .starts_with("objects[0]: NFF has no box")
        );
        assert!(
            refusal("Cylinder(base: (0, 0, 0), top: (0, 0, 1), radius: 1)")
                .contains("capped Cylinder")
        );
        assert!(
            refusal("Transform(scale: (1, 2, 1), child: Sphere(center: (0, 0, 0), radius: 1))")
                .starts_with("objects[0].Transform.child: a Sphere under a non-uniform scale")
        );
        let text = format!(
            "({CAMERA}, materials: {{\"gold\": (specular: 0.6, reflect: 0.1)}},
              objects: [Sphere(center: (0, 0, 0), radius: 1, material: \"gold\")])"
        );
        let m = parse_model_str(&text, SceneSyntax::Ron, Path::new("t.ron")).unwrap();
        let e = write_nff(&m, Path::new("t.ron")).unwrap_err().to_string();
        assert!(e.contains("materials[\"gold\"]: NFF's Ks is both"), "{e}");
        let mut m = model("Sphere(center: (0, 0, 0), radius: 1)");
        m.ambient = [0.5; 3];
        let e = write_nff(&m, Path::new("t.ron")).unwrap_err().to_string();
        assert!(
            e.contains("t.ron: ambient: NFF has no global ambient"),
            "{e}"
        );
    }

    #[test]
    fn numbers_are_short_and_exact() {
        for x in [0.1, 1.0 / 3.0, -2.5, 1e-7, 123456.0, 1e300, -0.0] {
            let s = number(x);
            assert_eq!(s.parse::<f64>().unwrap(), x, "{s}");
        }
        assert_eq!(number(3.0), "3");
        assert_eq!(number(-0.0), "0");
    }
}
