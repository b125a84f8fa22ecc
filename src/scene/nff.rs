//! Import of Eric Haines' Neutral File Format (NFF, the format of the
//! Standard Procedural Databases) into the scene `model`. Owns NFF syntax
//! and the mapping of its entities onto `SCENE_FORMAT.md`; validation is
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

use std::path::Path;

use super::model::{Camera, Light, Material, Node, SceneFile, Vector};
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
                    materials.insert(
                        name.clone(),
                        Material {
                            color: Some([r, g, b]),
                            ambient: Some(0.1),
                            diffuse: Some(kd),
                            specular: Some(ks),
                            shininess: Some(shine),
                            reflect: Some(ks),
                            transmit: Some(t),
                            ior: Some(if t == 0.0 && ior <= 0.0 { 1.0 } else { ior }),
                            base: None,
                        },
                    );
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
        let n = lights.len().max(1) as f64;
        let grey = n.sqrt() / (2.0 * n);
        let light_lines = lights.iter().map(|l| l.line).collect();
        let lights = lights
            .into_iter()
            .map(|l| Light {
                position: l.position,
                color: l.color.unwrap_or([grey; 3]),
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
        // NFF's angle spans the centres of the outer rows; `fov_y` their edges.
        let fov_y = if height > 1 {
            let h = f64::from(height);
            2.0 * ((angle.to_radians() / 2.0).tan() * h / (h - 1.0))
                .atan()
                .to_degrees()
        } else {
            angle
        };
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
