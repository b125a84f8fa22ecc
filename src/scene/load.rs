//! Loading scene files: syntax by extension, parsing into the `model`,
//! validation, and compilation into a `Scene`. Owns every load-time rule of
//! `SCENE_FORMAT.md` and the wording of scene errors: a syntax error names
//! the file, line and column (`Error::Syntax`); a meaningless value names the
//! file and the value's path in the scene, e.g.
//! `objects[2].Difference.children[5].Sphere.radius` (`Error::Invalid`).
//!
//! **Deep trees.** Scenes may be 10,000 levels deep (a left-deep chain of
//! differences). Parsing, validating, compiling and dropping the model all
//! recurse per level, so the whole load runs on a thread of its own with a
//! `LOAD_STACK_BYTES` stack; nesting deeper than that stack holds (about
//! 20,000 levels in JSON, 48,000 in RON) is refused as a syntax error.
//!
//! Rules, each a load error unless said otherwise (messages are one line):
//! - every number finite (no NaN, no infinity);
//! - camera: `eye != look_at`, `up` non-zero and not parallel to the view
//!   direction, `fov_y` in (0, 180), size per `check_resolution`;
//! - colours (background, ambient, lights, materials) not negative;
//!   material coefficients and `shininess` not negative, `ior > 0`;
//!   material `base` names an existing material, without cycles;
//! - `max_depth <= MAX_DEPTH_LIMIT` (64);
//! - sphere and cylinder radius > 0; cone radii >= 0, not both 0;
//!   cylinder/cone `base != top`; box `min <= max` on every axis (`min == max`
//!   on an axis is a zero-thickness sheet: accepted with a warning, since it
//!   bounds no volume and renders as nothing, `ROBUSTNESS.md` case 13);
//!   triangles of non-zero area; polygons of at least 3 vertices accepted by
//!   `Polygon::from_vertices`; transform scales without a zero component,
//!   and composed transforms invertible and finite;
//! - operators have at least one child; every `material` is a known name;
//! - surfaces (triangles, polygons, uncapped cylinders and cones) nowhere
//!   below an `Intersection` or a `Difference`.

use std::collections::{HashMap, HashSet};
use std::fmt::Write as _;
use std::path::Path;

use super::model::{self, Node, SceneFile, Vector};
use super::{Camera, Light, MAX_DEPTH_LIMIT, Material, MaterialId, Scene};
use crate::csg::{CsgTree, NodeId, Op, Polygon, PrimId, Primitive, Shape};
use crate::error::{fmt_num, fmt_sig};
use crate::geom::{Affine, Vec3, frobenius_norm};
use crate::{Error, Result};

/// The syntaxes a scene file may be written in, chosen by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SceneSyntax {
    Ron,
    Json,
    Nff,
}

impl SceneSyntax {
    /// The syntax of `path` by its extension (`.ron`, `.json`, `.nff`, in
    /// any case); anything else is a usage error (exit status 2).
    pub fn from_path(path: &Path) -> Result<SceneSyntax> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("ron") => Ok(SceneSyntax::Ron),
            Some("json") => Ok(SceneSyntax::Json),
            Some("nff") => Ok(SceneSyntax::Nff),
            _ => Err(Error::Usage(format!(
                "{}: unknown scene file type: the name must end in .ron, .json or .nff",
                path.display()
            ))),
        }
    }
}

/// The largest magnitude a coordinate may have: camera and light positions
/// and every primitive's bounds in the world. Squares and higher powers of
/// coordinates appear in the intersection arithmetic; a sphere of radius
/// 1e77 around the camera rendered differently with the cells and with
/// Roth (the square of its radius times another is past f64's 1.8e308),
/// one of 1e75 the same. This limit leaves a factor of 1e25 below that,
/// and is far beyond any scene's needs (a ground box reaching 1e50 away is
/// an infinite plane in every picture).
pub const MAX_COORDINATE: f64 = 1e50;

/// The largest colour component (of materials, lights, the background and
/// the ambient light) and material coefficient (`ambient`, `diffuse`,
/// `specular`, `reflect`, `transmit`) a scene may give. Products of a few
/// of them and a ray's weight must stay finite: a material colour of 1e50
/// made a shadow ray's weight, kept in f32, infinite. (Weights that grow
/// bounce after bounce, under a `reflect` above 1, are held at f32's
/// largest: `trace::to_weight`.)
pub const MAX_INTENSITY: f64 = 1e30;

/// The largest image side `check_resolution` accepts.
pub const MAX_SIDE: u32 = 65536;
/// The largest pixel count `check_resolution` accepts (2^28, e.g. 16384²).
pub const MAX_PIXELS: u64 = 1 << 28;
/// The deepest bracket nesting a JSON scene may have: a tree level costs
/// up to 3 brackets (`{"Difference": {"children": [`), so JSON trees of
/// about 20,000 levels load. Checked before parsing, since serde_json's own
/// guard (128) is off.
pub const MAX_NESTING: usize = 60_000;
/// RON's own recursion guard, counted in nested values: a tree level costs
/// 3 (`Transform`) to 5 (`Difference`), so RON trees of about 48,000 levels
/// load (80,000 of transforms).
const RON_RECURSION_LIMIT: usize = 4 * MAX_NESTING;
/// Stack of the loading thread. Measured in debug builds, deserializing a
/// `Difference` chain costs about 12 KiB per level and overflowed 1 GiB
/// only beyond 60,000 levels; both limits above stay below that, and so does
/// the validation walk. Only the pages touched are ever committed.
pub const LOAD_STACK_BYTES: usize = 1 << 30;

/// Reads, parses, validates and compiles the scene at `path`. Warnings (see
/// `load_scene_with_warnings`) are dropped.
pub fn load_scene(path: &Path) -> Result<Scene> {
    load_scene_with_warnings(path).map(|(scene, _)| scene)
}

/// Reads, parses, validates and compiles the scene at `path`, with the
/// warnings about things accepted but probably unintended (a zero-thickness
/// box, an empty scene), each one line of the form `file: path: message`.
pub fn load_scene_with_warnings(path: &Path) -> Result<(Scene, Vec<String>)> {
    let syntax = SceneSyntax::from_path(path)?;
    let text = read_text(path)?;
    parse_scene_str_with_warnings(&text, syntax, path)
}

/// Reads and validates the scene at `path` and returns its model (NFF
/// imported), for converters: the same checks and messages as
/// `load_scene`, the model instead of the compiled scene.
pub fn load_model(path: &Path) -> Result<SceneFile> {
    let syntax = SceneSyntax::from_path(path)?;
    let text = read_text(path)?;
    on_load_stack(|| {
        let model = match syntax {
            SceneSyntax::Ron | SceneSyntax::Json => {
                let model = deserialize(&text, syntax, path)?;
                compile(&model, path)?;
                model
            }
            SceneSyntax::Nff => {
                let nff = super::nff::parse_nff(&text, path)?;
                compile(&nff.model, path).map_err(|e| nff.locate(e))?;
                nff.model
            }
        };
        // Returned to the caller's thread, as from `parse_model_str`:
        // dropping a model thousands of levels deep needs a large stack.
        Ok(model)
    })?
}

/// A scene file's text: UTF-8, without a byte-order mark. Only a regular
/// file of at most `input::MAX_INPUT_BYTES` is read (`crate::input`).
fn read_text(path: &Path) -> Result<String> {
    let bytes = crate::input::read(path)?;
    let text = match String::from_utf8(bytes) {
        Ok(t) => t,
        Err(e) => {
            let good = &e.as_bytes()[..e.utf8_error().valid_up_to()];
            // `good` is valid UTF-8 by construction.
            let (line, column) = line_col_at_end(std::str::from_utf8(good).unwrap_or(""));
            return Err(Error::Syntax {
                file: path.to_path_buf(),
                line,
                column,
                message: "the file is not valid UTF-8 text".into(),
            });
        }
    };
    // A byte-order mark is no part of the text (and editors do not count
    // it in columns).
    Ok(match text.strip_prefix('\u{feff}') {
        Some(rest) => rest.to_string(),
        None => text,
    })
}

/// Parses, validates and compiles scene text; `file` is used in messages.
pub fn parse_scene_str(text: &str, syntax: SceneSyntax, file: &Path) -> Result<Scene> {
    parse_scene_str_with_warnings(text, syntax, file).map(|(scene, _)| scene)
}

/// `parse_scene_str` with the warnings of `load_scene_with_warnings`.
pub fn parse_scene_str_with_warnings(
    text: &str,
    syntax: SceneSyntax,
    file: &Path,
) -> Result<(Scene, Vec<String>)> {
    on_load_stack(|| match syntax {
        SceneSyntax::Ron | SceneSyntax::Json => {
            // The model is dropped on this thread too: dropping recurses.
            let model = deserialize(text, syntax, file)?;
            compile(&model, file)
        }
        SceneSyntax::Nff => {
            let nff = super::nff::parse_nff(text, file)?;
            compile(&nff.model, file).map_err(|e| nff.locate(e))
        }
    })?
}

/// Parses RON or JSON text into the model without validating it (NFF text
/// is imported with `nff::parse_nff`). For converters and tests. The model
/// is returned to the caller's thread: dropping a model thousands of levels
/// deep needs a large stack there (see `model`).
pub fn parse_model_str(text: &str, syntax: SceneSyntax, file: &Path) -> Result<SceneFile> {
    on_load_stack(|| deserialize(text, syntax, file))?
}

/// Validates and compiles a model (built by a generator, say); `file` is
/// used in messages.
pub fn compile_model(model: &SceneFile, file: &Path) -> Result<(Scene, Vec<String>)> {
    on_load_stack(|| compile(model, file))?
}

/// Writes a model as RON (pretty, with bare optional values as `load`
/// reads them), JSON (pretty) or NFF (`nff::write_nff`, which refuses what
/// NFF cannot say), as `write_scene` does, naming the scene `<scene>` in
/// errors.
pub fn scene_to_string(model: &SceneFile, syntax: SceneSyntax) -> Result<String> {
    write_scene(model, syntax, Path::new("<scene>"))
}

/// Writes a model as RON, JSON or NFF text; errors name `source`. Both
/// pretty forms indent the first `PRETTY_DEPTH` levels of nesting and
/// write what lies deeper compactly. A tree deeper than JSON scenes load
/// (`MAX_NESTING`) is refused as JSON, so that no file is written that
/// cannot be read back.
pub fn write_scene(model: &SceneFile, syntax: SceneSyntax, source: &Path) -> Result<String> {
    let cannot = |syntax: &str, e: &dyn std::fmt::Display| {
        Error::Render(format!("cannot write the scene as {syntax}: {e}"))
    };
    match syntax {
        SceneSyntax::Ron => on_load_stack(|| {
            let pretty = ron::ser::PrettyConfig::default().depth_limit(PRETTY_DEPTH);
            ron_options()
                .to_string_pretty(model, pretty)
                .map_err(|e| cannot("RON", &e))
        })?,
        SceneSyntax::Json => on_load_stack(|| {
            let mut text = Vec::new();
            let mut ser = serde_json::Serializer::with_formatter(&mut text, DepthCapped::default());
            serde::Serialize::serialize(model, &mut ser).map_err(|e| cannot("JSON", &e))?;
            // serde_json writes valid UTF-8 only.
            let text = String::from_utf8(text).map_err(|e| cannot("JSON", &e))?;
            // The loader's own check, so that what it refuses is never
            // written.
            if json_too_deep(&text).is_some() {
                return Err(Error::invalid(
                    source,
                    "objects",
                    format!(
                        "JSON cannot hold this tree: it nests more than the {MAX_NESTING} \
                         brackets JSON scenes load (about {} tree levels); write .ron, which \
                         loads about {} levels",
                        MAX_NESTING / 3,
                        RON_RECURSION_LIMIT / 5
                    ),
                ));
            }
            Ok(text)
        })?,
        SceneSyntax::Nff => super::nff::write_nff(model, source),
    }
}

/// Levels of nesting that written scenes indent (`scene_to_string`);
/// deeper values follow compactly. Indenting every level made a tree
/// 40,000 levels deep, which loads, a file of billions of spaces (the
/// indentation grows with the depth on each of a number of lines that
/// grows with it too), and the conversion ran out of memory.
pub const PRETTY_DEPTH: usize = 48;

/// serde_json's pretty layout for the first `PRETTY_DEPTH` levels of
/// nesting, its compact one below them (`scene_to_string`).
#[derive(Default)]
struct DepthCapped {
    pretty: serde_json::ser::PrettyFormatter<'static>,
    /// Arrays and objects open.
    depth: usize,
}

/// `$self.$name(w, ..)` of the pretty formatter where the innermost open
/// container is laid out pretty, else of the compact one: the one choice
/// every method of `DepthCapped` makes.
macro_rules! by_depth {
    ($self:ident, $name:ident($($arg:ident),*)) => {
        if $self.depth <= PRETTY_DEPTH {
            $self.pretty.$name($($arg),*)
        } else {
            serde_json::ser::CompactFormatter.$name($($arg),*)
        }
    };
}

/// Each call goes to the formatter of the container it belongs to
/// (`by_depth!`); a container's opening and closing calls are taken at
/// the same depth, so both go to the same one.
impl serde_json::ser::Formatter for DepthCapped {
    fn begin_array<W: ?Sized + std::io::Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        self.depth += 1;
        by_depth!(self, begin_array(w))
    }

    fn end_array<W: ?Sized + std::io::Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        let written = by_depth!(self, end_array(w));
        self.depth -= 1;
        written
    }

    fn begin_array_value<W: ?Sized + std::io::Write>(
        &mut self,
        w: &mut W,
        first: bool,
    ) -> std::io::Result<()> {
        by_depth!(self, begin_array_value(w, first))
    }

    fn end_array_value<W: ?Sized + std::io::Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        by_depth!(self, end_array_value(w))
    }

    fn begin_object<W: ?Sized + std::io::Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        self.depth += 1;
        by_depth!(self, begin_object(w))
    }

    fn end_object<W: ?Sized + std::io::Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        let written = by_depth!(self, end_object(w));
        self.depth -= 1;
        written
    }

    fn begin_object_key<W: ?Sized + std::io::Write>(
        &mut self,
        w: &mut W,
        first: bool,
    ) -> std::io::Result<()> {
        by_depth!(self, begin_object_key(w, first))
    }

    fn begin_object_value<W: ?Sized + std::io::Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        by_depth!(self, begin_object_value(w))
    }

    fn end_object_value<W: ?Sized + std::io::Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        by_depth!(self, end_object_value(w))
    }
}

/// Checks an image size: at least 1x1, at most `MAX_SIDE` per side and
/// `MAX_PIXELS` in total (4096x4096 passes, 10^6 x 10^6 does not). The
/// message is one line, without the place (the caller knows it).
pub fn check_resolution(width: u32, height: u32) -> std::result::Result<(), String> {
    if width == 0 || height == 0 {
        return Err(format!(
            "image size {width}x{height} is empty: width and height must be at least 1"
        ));
    }
    if width > MAX_SIDE || height > MAX_SIDE {
        return Err(format!(
            "image size {width}x{height} is too large: at most {MAX_SIDE} pixels per side"
        ));
    }
    if u64::from(width) * u64::from(height) > MAX_PIXELS {
        return Err(format!(
            "image size {width}x{height} is too large: at most {MAX_PIXELS} pixels (2^28) in total"
        ));
    }
    Ok(())
}

/// Runs `f` on a thread with a `LOAD_STACK_BYTES` stack and waits for it.
/// A panic in `f` is a bug of ours, not bad input: it is passed on as is.
pub(crate) fn on_load_stack<T: Send>(f: impl FnOnce() -> T + Send) -> Result<T> {
    std::thread::scope(|s| {
        let handle = std::thread::Builder::new()
            .name("scene-load".into())
            .stack_size(LOAD_STACK_BYTES)
            .spawn_scoped(s, f)
            .map_err(|e| Error::Render(format!("cannot start the scene loading thread: {e}")))?;
        match handle.join() {
            Ok(v) => Ok(v),
            Err(panic) => std::panic::resume_unwind(panic),
        }
    })
}

// ---------------------------------------------------------------------------
// Syntax: RON and JSON into the model.

/// RON as scene files use it: optional values written bare
/// (`implicit_some`), and a recursion guard raised for deep trees.
fn ron_options() -> ron::Options {
    ron::Options::default()
        .with_default_extension(ron::extensions::Extensions::IMPLICIT_SOME)
        .with_recursion_limit(RON_RECURSION_LIMIT)
}

/// `file`'s syntax error at 1-based `line` and `column`, on one line.
fn syntax_error(file: &Path, line: usize, column: usize, message: String) -> Error {
    Error::Syntax {
        file: file.to_path_buf(),
        line: line.max(1),
        column: column.max(1),
        message: one_line(&message),
    }
}

/// A RON error in `text` as our messages say it, at the first character
/// of what it is about (scene and topology files).
pub(crate) fn ron_syntax_error(text: &str, file: &Path, e: &ron::error::SpannedError) -> Error {
    let ron::error::Position { line, col } = e.span.start;
    let (line, col) = skip_blanks(text, line, col);
    syntax_error(file, line, col, ron_message(&e.code))
}

/// A JSON error as our messages say it (scene and topology files).
pub(crate) fn json_syntax_error(file: &Path, e: &serde_json::Error) -> Error {
    syntax_error(file, e.line(), e.column(), json_message(e))
}

/// RON or JSON text into the model.
fn deserialize(text: &str, syntax: SceneSyntax, file: &Path) -> Result<SceneFile> {
    let syntax_error =
        |line: usize, column: usize, message: String| syntax_error(file, line, column, message);
    match syntax {
        SceneSyntax::Ron => ron_options()
            .from_str::<SceneFile>(text)
            .map_err(|e| ron_syntax_error(text, file, &e)),
        SceneSyntax::Json => {
            // serde_json's own guard (128 levels) is off, so bound the
            // nesting here before serde_json recurses into it.
            if let Some((line, column)) = json_too_deep(text) {
                return Err(syntax_error(line, column, too_deep_message(syntax)));
            }
            let mut de = serde_json::Deserializer::from_str(text);
            de.disable_recursion_limit();
            let model = <SceneFile as serde::Deserialize>::deserialize(&mut de)
                .and_then(|m| de.end().map(|()| m));
            model.map_err(|e| json_syntax_error(file, &e))
        }
        SceneSyntax::Nff => Ok(super::nff::parse_nff(text, file)?.model),
    }
}

fn too_deep_message(syntax: SceneSyntax) -> String {
    match syntax {
        SceneSyntax::Json => format!(
            "the scene is nested too deeply: JSON scenes may nest {MAX_NESTING} brackets (about {} tree levels)",
            MAX_NESTING / 3
        ),
        _ => format!(
            "the scene is nested too deeply: RON scenes may nest {RON_RECURSION_LIMIT} values (about {} tree levels)",
            RON_RECURSION_LIMIT / 5
        ),
    }
}

/// The position of the first bracket that opens level `MAX_NESTING + 1` in
/// JSON text, if any. Lexes strings exactly as JSON does, so brackets inside
/// strings are not counted and none can be hidden from the count.
fn json_too_deep(text: &str) -> Option<(usize, usize)> {
    let (mut depth, mut in_string, mut escaped) = (0usize, false, false);
    let (mut line, mut col) = (1usize, 0usize);
    for c in text.chars() {
        if c == '\n' {
            line += 1;
            col = 0;
        } else {
            col += 1;
        }
        if in_string {
            match c {
                _ if escaped => escaped = false,
                '\\' => escaped = true,
                '"' => in_string = false,
                _ => {}
            }
            continue;
        }
        match c {
            '"' => in_string = true,
            '[' | '{' => {
                depth += 1;
                if depth > MAX_NESTING {
                    return Some((line, col));
                }
            }
            ']' | '}' => depth = depth.saturating_sub(1),
            _ => {}
        }
    }
    None
}

/// The one-line message for a RON error, worded like serde's JSON errors
/// and naming our types as the file does (`SceneFile` is "the top level").
fn ron_message(code: &ron::Error) -> String {
    use ron::Error as E;
    let within = |outer: &Option<String>| match outer.as_deref() {
        None => String::new(),
        Some("SceneFile") => " at the top level".into(),
        Some("Camera") => " in the camera".into(),
        Some("Light") => " in a light".into(),
        Some("Material") => " in a material".into(),
        Some("TopologyFile") => " in the topology".into(),
        Some(o) => format!(" in {o}"),
    };
    match code {
        E::NoSuchStructField {
            expected,
            found,
            outer,
        } => {
            format!(
                "unknown field `{found}`{}, expected {}",
                within(outer),
                one_of(expected)
            )
        }
        E::NoSuchEnumVariant {
            expected,
            found,
            outer,
        } if outer.as_deref() == Some("Node") || outer.is_none() => {
            format!("unknown node type `{found}`, expected {}", one_of(expected))
        }
        E::MissingStructField { field, outer } => {
            format!("missing field `{field}`{}", within(outer))
        }
        E::DuplicateStructField { field, outer } => {
            format!("duplicate field `{field}`{}", within(outer))
        }
        E::InvalidValueForType { expected, found } => format!("expected {expected}, found {found}"),
        E::ExpectedDifferentLength { expected, found } => {
            format!("expected {expected}, found {found} element(s)")
        }
        E::ExpectedFloat => "expected a number".into(),
        E::ExpectedInteger => "expected an integer".into(),
        E::IntegerOutOfBounds => {
            "integer out of range for this field (negative, or too large)".into()
        }
        E::ExpectedStructLike => "expected `(` (a struct, or a vector written `(x, y, z)`)".into(),
        E::ExceededRecursionLimit => too_deep_message(SceneSyntax::Ron),
        other => lower_first(&other.to_string()),
    }
}

fn one_of(names: &[&str]) -> String {
    match names {
        [] => "nothing here".into(),
        [one] => format!("`{one}`"),
        _ => {
            let list: Vec<String> = names.iter().map(|n| format!("`{n}`")).collect();
            format!("one of {}", list.join(", "))
        }
    }
}

/// serde_json's message without its trailing " at line L column C" (the
/// position goes into `Error::Syntax`'s fields).
fn json_message(e: &serde_json::Error) -> String {
    let full = e.to_string();
    let suffix = format!(" at line {} column {}", e.line(), e.column());
    let msg = full.strip_suffix(&suffix).unwrap_or(&full);
    // Our only enum is `Node`: say what an unknown variant is.
    match msg.strip_prefix("unknown variant") {
        Some(rest) => format!("unknown node type{rest}"),
        None => msg.to_string(),
    }
}

fn lower_first(s: &str) -> String {
    let mut c = s.chars();
    match c.next() {
        Some(f) => f.to_lowercase().chain(c).collect(),
        None => String::new(),
    }
}

/// `s` with line breaks (and other control characters) as spaces, so that
/// every message prints as one line.
fn one_line(s: &str) -> String {
    s.trim()
        .chars()
        .map(|c| if c.is_control() { ' ' } else { c })
        .collect()
}

/// The position of the first non-blank character at or after the 1-based
/// (`line`, `column`) of `text`, or the position itself when only blanks
/// follow. RON's spans start where the parser stood, often on the blank
/// before the offending value.
fn skip_blanks(text: &str, line: usize, column: usize) -> (usize, usize) {
    let mut rest = text.split('\n').enumerate().skip(line.saturating_sub(1));
    let mut skip = column.saturating_sub(1);
    for (i, l) in rest.by_ref() {
        for (j, c) in l.chars().enumerate().skip(skip) {
            if !c.is_whitespace() {
                return (i + 1, j + 1);
            }
        }
        skip = 0;
    }
    (line, column)
}

/// 1-based line and column just after `text`.
fn line_col_at_end(text: &str) -> (usize, usize) {
    let line = 1 + text.matches('\n').count();
    let column = 1 + text.rsplit('\n').next().map_or(0, |l| l.chars().count());
    (line, column)
}

// ---------------------------------------------------------------------------
// Paths: built only when a message needs one.

/// One step from a node to a child in the scene tree.
#[derive(Clone, Copy)]
enum Step {
    /// `objects[i]`.
    Object(usize),
    /// `.<Op>.children[i]`.
    Child(&'static str, usize),
    /// `.Transform.child`.
    TransformChild,
}

/// A node's place in the tree, as a chain up to `objects[i]`, held on the
/// stack of the recursive walk. Materialized into a string only for a
/// message: storing every node's full path would cost quadratic memory in
/// a 10,000-level chain.
struct Place<'a> {
    step: Step,
    parent: Option<&'a Place<'a>>,
}

impl Place<'_> {
    /// E.g. `objects[2].Difference.children[5]`.
    fn path(&self) -> String {
        let mut steps = Vec::new();
        let mut p = Some(self);
        while let Some(place) = p {
            steps.push(place.step);
            p = place.parent;
        }
        let mut s = String::new();
        for step in steps.iter().rev() {
            // Writing to a String cannot fail.
            let _ = match step {
                Step::Object(i) => write!(s, "objects[{i}]"),
                Step::Child(op, i) => write!(s, ".{op}.children[{i}]"),
                Step::TransformChild => write!(s, ".Transform.child"),
            };
        }
        s
    }

    /// E.g. `objects[2].Difference.children[5].Sphere.radius`.
    fn field(&self, kind: &str, field: &str) -> String {
        format!("{}.{kind}.{field}", self.path())
    }
}

// ---------------------------------------------------------------------------
// Validation and compilation.

/// What a node inherits from its ancestors.
#[derive(Clone, Copy)]
struct Inherited<'a> {
    material: MaterialId,
    /// Object-to-world map of the node (composed `Transform`s above it).
    to_world: &'a Affine,
    /// The innermost `Transform` above, linked to those above it.
    transforms: Option<&'a TransformLink<'a>>,
    /// The nearest `Intersection` or `Difference` above, if any: surfaces
    /// are forbidden below it.
    solid_only: Option<(&'a Place<'a>, &'static str)>,
}

/// One `Transform` on the way down from the top.
struct TransformLink<'a> {
    /// The transform's own map.
    own: Affine,
    /// The map of everything down to and including it.
    to_world: Affine,
    parent: Option<&'a TransformLink<'a>>,
}

/// How many transforms above a primitive `place` looks through.
const BAKE_LOOKUP: usize = 64;

/// Places a primitive under the transforms above it, folding the innermost
/// ones into its parameters first, as far as that is exact for the shape
/// (`csg::shape::bake_exactly`), and keeping the rest as its transform.
///
/// Composing first and baking the composition is not the same: a box
/// carved by a scaled unit box, the two under one rotation (case 10
/// turned), had the rotation composed with the scale, so neither could be
/// baked and each met rays in its own object space, mapped by differently
/// rounded matrices; the shared faces speckled. Baking the scale first
/// leaves both under the very same rotation, so they meet the same mapped
/// ray and their faces agree bit for bit. Only the `BAKE_LOOKUP` innermost
/// transforms are looked through, so deep chains of transforms over many
/// primitives stay linear.
fn place_primitive(shape: Shape, up: &Inherited<'_>, material: MaterialId) -> Primitive {
    let mut link = up.transforms;
    let mut inner = Affine::IDENTITY;
    // The shape baked under `inner`, kept rather than baked again.
    let mut baked = None;
    for _ in 0..BAKE_LOOKUP {
        let Some(l) = link else { break };
        let candidate = l.own.then_inner(&inner);
        let Some(b) = crate::csg::shape::bake_exactly(shape.clone(), &candidate) else {
            break;
        };
        (inner, baked) = (candidate, Some(b));
        link = l.parent;
    }
    let outer = link.map_or(Affine::IDENTITY, |l| l.to_world);
    // Under identity transforms the shape stays exactly as written.
    let shape = match baked {
        Some(b) if !inner.is_identity() => b,
        _ => shape,
    };
    Primitive::new(shape, &outer, material)
}

struct Compiler<'m> {
    file: &'m Path,
    material_ids: HashMap<&'m str, MaterialId>,
    material_names: Vec<String>,
    primitives: Vec<Primitive>,
    tree: CsgTree,
    warnings: Vec<String>,
}

/// Validates and compiles on the calling thread (which must have a large
/// stack for deep trees: see `on_load_stack`).
pub(crate) fn compile(model: &SceneFile, file: &Path) -> Result<(Scene, Vec<String>)> {
    let invalid = |path: String, message: String| Error::invalid(file, path, message);

    let camera = compile_camera(&model.camera).map_err(|(p, m)| invalid(p, m))?;
    check_colour(model.background, "background", || "background".into())
        .map_err(|(p, m)| invalid(p, m))?;
    check_colour(model.ambient, "ambient", || "ambient".into()).map_err(|(p, m)| invalid(p, m))?;
    let mut lights = Vec::with_capacity(model.lights.len());
    for (i, l) in model.lights.iter().enumerate() {
        check_position(l.position, "position", || format!("lights[{i}].position"))
            .map_err(|(p, m)| invalid(p, m))?;
        check_colour(l.color, "color", || format!("lights[{i}].color"))
            .map_err(|(p, m)| invalid(p, m))?;
        lights.push(Light {
            position: Vec3::from_array(l.position),
            color: Vec3::from_array(l.color),
        });
    }
    if model.max_depth > MAX_DEPTH_LIMIT {
        return Err(invalid(
            "max_depth".into(),
            format!(
                "max_depth must be at most {MAX_DEPTH_LIMIT}, got {}",
                model.max_depth
            ),
        ));
    }
    let (materials, material_names) = compile_materials(model).map_err(|(p, m)| invalid(p, m))?;

    let mut c = Compiler {
        file,
        // Ids follow `compile_materials`' order: 0 the default, then by name.
        material_ids: model
            .materials
            .keys()
            .enumerate()
            .map(|(i, name)| (name.as_str(), MaterialId(i as u32 + 1)))
            .collect(),
        material_names,
        primitives: Vec::new(),
        tree: CsgTree::new(),
        warnings: Vec::new(),
    };
    if model.objects.is_empty() {
        c.warnings.push(format!(
            "{}: objects: the scene has no objects: the image is all background",
            file.display()
        ));
    }
    let top = Inherited {
        material: MaterialId::DEFAULT,
        to_world: &Affine::IDENTITY,
        transforms: None,
        solid_only: None,
    };
    let mut roots = Vec::with_capacity(model.objects.len());
    for (i, node) in model.objects.iter().enumerate() {
        let place = Place {
            step: Step::Object(i),
            parent: None,
        };
        roots.push(c.node(node, &place, top)?);
    }
    // The objects list is an implicit union, always an explicit root node.
    let root = c.tree.op(Op::Union, roots);
    c.tree.finish(root, &c.primitives);
    let scene = Scene {
        camera,
        background: Vec3::from_array(model.background),
        ambient: Vec3::from_array(model.ambient),
        lights,
        materials,
        material_names: c.material_names,
        primitives: c.primitives,
        tree: c.tree,
        max_depth: model.max_depth,
    };
    Ok((scene, c.warnings))
}

/// A validation failure before it gets its file: (path, message).
type Found = (String, String);

fn compile_camera(cam: &model::Camera) -> std::result::Result<Camera, Found> {
    check_position(cam.eye, "eye", || "camera.eye".into())?;
    check_position(cam.look_at, "look_at", || "camera.look_at".into())?;
    check_finite(cam.up, "up", || "camera.up".into())?;
    check_finite_scalar(cam.fov_y, "fov_y", || "camera.fov_y".into())?;
    if !(cam.fov_y > 0.0 && cam.fov_y < 180.0) {
        return Err((
            "camera.fov_y".into(),
            format!("fov_y must be in (0, 180) degrees, got {}", cam.fov_y),
        ));
    }
    check_resolution(cam.width, cam.height).map_err(|m| ("camera".to_string(), m))?;
    let (eye, look_at, up) = (
        Vec3::from_array(cam.eye),
        Vec3::from_array(cam.look_at),
        Vec3::from_array(cam.up),
    );
    if eye == look_at {
        return Err((
            "camera.look_at".into(),
            format!(
                "look_at must differ from eye, both are {}",
                fmt_vec(cam.eye)
            ),
        ));
    }
    if up == Vec3::ZERO {
        return Err(("camera.up".into(), "up must not be zero".into()));
    }
    if parallel(up, look_at - eye) {
        return Err((
            "camera.up".into(),
            format!(
                "up {} is parallel to the view direction from eye to look_at {}",
                fmt_vec(cam.up),
                fmt_v3(look_at - eye)
            ),
        ));
    }
    Ok(Camera {
        eye,
        look_at,
        up,
        fov_y: cam.fov_y,
        width: cam.width,
        height: cam.height,
    })
}

/// Materials: index 0 the default, then the named ones sorted by name.
fn compile_materials(
    model: &SceneFile,
) -> std::result::Result<(Vec<Material>, Vec<String>), Found> {
    let at = |name: &str, field: &str| format!("materials[{name:?}].{field}");
    for (name, m) in &model.materials {
        if name == DEFAULT_MATERIAL_NAME {
            return Err((
                format!("materials[{name:?}]"),
                format!("the name {DEFAULT_MATERIAL_NAME:?} is reserved for the default material"),
            ));
        }
        if let Some(c) = m.color {
            check_colour(c, "color", || at(name, "color"))?;
        }
        // Each with its largest value: the coefficients scale light, so
        // `MAX_INTENSITY`; `shininess` is an exponent of a cosine at most
        // 1, whose power stays at most 1 whatever it is.
        for (field, value, max) in [
            ("ambient", m.ambient, MAX_INTENSITY),
            ("diffuse", m.diffuse, MAX_INTENSITY),
            ("specular", m.specular, MAX_INTENSITY),
            ("shininess", m.shininess, f64::INFINITY),
            ("reflect", m.reflect, MAX_INTENSITY),
            ("transmit", m.transmit, MAX_INTENSITY),
        ] {
            if let Some(v) = value {
                check_finite_scalar(v, field, || at(name, field))?;
                if v < 0.0 {
                    return Err((at(name, field), format!("{field} must be >= 0, got {v}")));
                }
                if v > max {
                    return Err((at(name, field), format!("{field} is {v:e}, above {max:e}")));
                }
            }
        }
        if let Some(ior) = m.ior {
            check_finite_scalar(ior, "ior", || at(name, "ior"))?;
            if ior <= 0.0 {
                return Err((at(name, "ior"), format!("ior must be > 0, got {ior}")));
            }
        }
    }

    // Inheritance: resolve each chain once, base-most first, memoized so a
    // long chain costs linear time.
    let mut resolved: HashMap<&str, Material> = HashMap::new();
    for start in model.materials.keys() {
        let mut chain: Vec<&str> = Vec::new();
        let mut on_chain: HashSet<&str> = HashSet::new();
        let mut cur: &str = start;
        let mut inherited = loop {
            if let Some(done) = resolved.get(cur) {
                break done.clone();
            }
            if !on_chain.insert(cur) {
                let from = chain.iter().position(|n| *n == cur).unwrap_or(0);
                let cycle: Vec<String> = chain[from..]
                    .iter()
                    .chain([&cur])
                    .map(|n| format!("{n:?}"))
                    .collect();
                return Err((
                    at(cur, "base"),
                    format!("material inheritance cycle: {}", cycle.join(" -> ")),
                ));
            }
            chain.push(cur);
            match model.materials.get(cur).and_then(|m| m.base.as_deref()) {
                None => break Material::default(),
                Some(base) => match model.materials.get_key_value(base) {
                    Some((key, _)) => cur = key.as_str(),
                    None => {
                        return Err((
                            at(cur, "base"),
                            format!("unknown base material {base:?}{}", known_names(model)),
                        ));
                    }
                },
            }
        };
        for name in chain.iter().rev() {
            if let Some(m) = model.materials.get(*name) {
                inherited = apply_material(m, inherited);
            }
            resolved.insert(name, inherited.clone());
        }
    }

    let mut materials = vec![Material::default()];
    let mut names = vec![DEFAULT_MATERIAL_NAME.to_string()];
    for name in model.materials.keys() {
        materials.push(resolved.remove(name.as_str()).unwrap_or_default());
        names.push(name.clone());
    }
    Ok((materials, names))
}

/// The name of `Scene::materials[0]`.
pub const DEFAULT_MATERIAL_NAME: &str = "<default>";

/// `m`'s own fields over `base`'s.
fn apply_material(m: &model::Material, base: Material) -> Material {
    Material {
        color: m.color.map_or(base.color, Vec3::from_array),
        ambient: m.ambient.unwrap_or(base.ambient),
        diffuse: m.diffuse.unwrap_or(base.diffuse),
        specular: m.specular.unwrap_or(base.specular),
        shininess: m.shininess.unwrap_or(base.shininess),
        reflect: m.reflect.unwrap_or(base.reflect),
        transmit: m.transmit.unwrap_or(base.transmit),
        ior: m.ior.unwrap_or(base.ior),
    }
}

fn known_names(model: &SceneFile) -> String {
    let names: Vec<&String> = model.materials.keys().collect();
    known_list(&names)
}

/// " (known: "a", "b")" for a message, at most ten names.
fn known_list<S: AsRef<str>>(names: &[S]) -> String {
    if names.is_empty() {
        return " (the scene defines no materials)".into();
    }
    let shown: Vec<String> = names
        .iter()
        .take(10)
        .map(|n| format!("{:?}", n.as_ref()))
        .collect();
    let more = if names.len() > 10 { ", …" } else { "" };
    format!(" (known: {}{more})", shown.join(", "))
}

impl<'m> Compiler<'m> {
    fn invalid(&self, path: String, message: String) -> Error {
        Error::invalid(self.file, path, message)
    }

    /// Validates `node` and adds it (and its subtree) to the tree.
    fn node(&mut self, node: &'m Node, place: &Place<'_>, up: Inherited<'_>) -> Result<NodeId> {
        let kind = node.kind();
        let material = match node.material() {
            None => up.material,
            Some(name) => match self.material_ids.get(name) {
                Some(id) => *id,
                None => {
                    return Err(self.invalid(
                        place.field(kind, "material"),
                        format!(
                            "unknown material {name:?}{}",
                            known_list(&self.material_names[1..])
                        ),
                    ));
                }
            },
        };
        if node.is_surface()
            && let Some((op_place, op)) = up.solid_only
        {
            return Err(self.invalid(
                place.path(),
                format!(
                    "{kind} is a surface (it bounds no volume) and cannot be inside the {op} at {}: \
                     surfaces may appear only under Union and Assembly",
                    op_place.path()
                ),
            ));
        }
        let finite = |v: Vector, field: &str| check_finite(v, field, || place.field(kind, field));
        let finite1 =
            |v: f64, field: &str| check_finite_scalar(v, field, || place.field(kind, field));
        let shape = match node {
            Node::Sphere { center, radius, .. } => {
                finite(*center, "center")
                    .and_then(|()| finite1(*radius, "radius"))
                    .map_err(|f| self.found(f))?;
                if *radius <= 0.0 {
                    return Err(self.invalid(
                        place.field(kind, "radius"),
                        format!("radius must be > 0, got {radius}"),
                    ));
                }
                Shape::Sphere {
                    center: Vec3::from_array(*center),
                    radius: *radius,
                }
            }
            Node::Box { min, max, .. } => {
                finite(*min, "min")
                    .and_then(|()| finite(*max, "max"))
                    .map_err(|f| self.found(f))?;
                for (axis, name) in ["x", "y", "z"].iter().enumerate() {
                    if min[axis] > max[axis] {
                        return Err(self.invalid(
                            place.path(),
                            format!(
                                "Box min.{name} = {} is above max.{name} = {}: min must not exceed max on any axis",
                                min[axis], max[axis]
                            ),
                        ));
                    }
                }
                let flat: Vec<&str> = ["x", "y", "z"]
                    .iter()
                    .enumerate()
                    .filter(|(axis, _)| min[*axis] == max[*axis])
                    .map(|(_, n)| *n)
                    .collect();
                if !flat.is_empty() {
                    self.warnings.push(format!(
                        "{}: {}: Box has zero thickness along {} (min == max): it bounds no volume and will not be seen",
                        self.file.display(),
                        place.path(),
                        flat.join(", ")
                    ));
                }
                Shape::Box {
                    min: Vec3::from_array(*min),
                    max: Vec3::from_array(*max),
                }
            }
            Node::Cylinder {
                base,
                top,
                radius,
                capped,
                ..
            } => {
                finite(*base, "base")
                    .and_then(|()| finite(*top, "top"))
                    .and_then(|()| finite1(*radius, "radius"))
                    .map_err(|f| self.found(f))?;
                if *radius <= 0.0 {
                    return Err(self.invalid(
                        place.field(kind, "radius"),
                        format!("radius must be > 0, got {radius}"),
                    ));
                }
                if base == top {
                    return Err(self.invalid(
                        place.path(),
                        format!(
                            "Cylinder base and top are the same point {}",
                            fmt_vec(*base)
                        ),
                    ));
                }
                Shape::Cylinder {
                    base: Vec3::from_array(*base),
                    top: Vec3::from_array(*top),
                    radius: *radius,
                    capped: *capped,
                }
            }
            Node::Cone {
                base,
                base_radius,
                top,
                top_radius,
                capped,
                ..
            } => {
                finite(*base, "base")
                    .and_then(|()| finite(*top, "top"))
                    .and_then(|()| finite1(*base_radius, "base_radius"))
                    .and_then(|()| finite1(*top_radius, "top_radius"))
                    .map_err(|f| self.found(f))?;
                for (field, r) in [("base_radius", base_radius), ("top_radius", top_radius)] {
                    if *r < 0.0 {
                        return Err(self.invalid(
                            place.field(kind, field),
                            format!("{field} must be >= 0, got {r}"),
                        ));
                    }
                }
                if *base_radius == 0.0 && *top_radius == 0.0 {
                    return Err(self.invalid(
                        place.path(),
                        "Cone base_radius and top_radius are both 0".into(),
                    ));
                }
                if base == top {
                    return Err(self.invalid(
                        place.path(),
                        format!("Cone base and top are the same point {}", fmt_vec(*base)),
                    ));
                }
                Shape::Cone {
                    base: Vec3::from_array(*base),
                    base_radius: *base_radius,
                    top: Vec3::from_array(*top),
                    top_radius: *top_radius,
                    capped: *capped,
                }
            }
            Node::Triangle { a, b, c, .. } => {
                finite(*a, "a")
                    .and_then(|()| finite(*b, "b"))
                    .and_then(|()| finite(*c, "c"))
                    .map_err(|f| self.found(f))?;
                let (a, b, c) = (
                    Vec3::from_array(*a),
                    Vec3::from_array(*b),
                    Vec3::from_array(*c),
                );
                if parallel(b - a, c - a) {
                    return Err(self.invalid(
                        place.path(),
                        "Triangle has zero area: its corners coincide or lie on one line".into(),
                    ));
                }
                Shape::Triangle { a, b, c }
            }
            Node::Polygon { vertices, .. } => {
                for (i, v) in vertices.iter().enumerate() {
                    check_finite(*v, &format!("vertices[{i}]"), || {
                        format!("{}[{i}]", place.field(kind, "vertices"))
                    })
                    .map_err(|f| self.found(f))?;
                }
                if vertices.len() < 3 {
                    return Err(self.invalid(
                        place.field(kind, "vertices"),
                        format!(
                            "a Polygon needs at least 3 vertices, got {}",
                            vertices.len()
                        ),
                    ));
                }
                let vs = vertices.iter().map(|v| Vec3::from_array(*v)).collect();
                match Polygon::from_vertices(vs) {
                    Ok(p) => Shape::Polygon(p),
                    Err(why) => {
                        return Err(
                            self.invalid(place.path(), format!("bad Polygon: {}", one_line(&why)))
                        );
                    }
                }
            }
            Node::Union { children, .. }
            | Node::Intersection { children, .. }
            | Node::Difference { children, .. }
            | Node::Assembly { children, .. } => {
                let (op, solid_only) = match node {
                    Node::Union { .. } => (Op::Union, up.solid_only),
                    Node::Assembly { .. } => (Op::Assembly, up.solid_only),
                    Node::Intersection { .. } => (Op::Intersection, Some((place, kind))),
                    _ => (Op::Difference, Some((place, kind))),
                };
                if children.is_empty() {
                    return Err(self.invalid(
                        place.field(kind, "children"),
                        format!("{kind} has no children"),
                    ));
                }
                let below = Inherited {
                    material,
                    to_world: up.to_world,
                    transforms: up.transforms,
                    solid_only,
                };
                let mut ids = Vec::with_capacity(children.len());
                for (i, child) in children.iter().enumerate() {
                    let child_place = Place {
                        step: Step::Child(kind, i),
                        parent: Some(place),
                    };
                    ids.push(self.node(child, &child_place, below)?);
                }
                return Ok(self.tree.op(op, ids));
            }
            Node::Transform {
                translate,
                rotate,
                scale,
                child,
                ..
            } => {
                finite(*translate, "translate")
                    .and_then(|()| finite(*rotate, "rotate"))
                    .and_then(|()| finite(*scale, "scale"))
                    .map_err(|f| self.found(f))?;
                if scale.contains(&0.0) {
                    return Err(self.invalid(
                        place.field(kind, "scale"),
                        format!("scale must have no zero component, got {}", fmt_vec(*scale)),
                    ));
                }
                let own = Affine::from_srt(
                    Vec3::from_array(*scale),
                    Vec3::from_array(*rotate),
                    Vec3::from_array(*translate),
                );
                let to_world = up.to_world.then_inner(&own);
                if !(to_world.linear.is_finite()
                    && to_world.inv_linear.is_finite()
                    && to_world.translation.is_finite()
                    && to_world.linear.determinant() != 0.0)
                {
                    return Err(self.invalid(
                        place.path(),
                        "the transforms down to here compose to a map that is not finite or not invertible \
                         (scales or translations multiply beyond floating point)"
                            .into(),
                    ));
                }
                let child_place = Place {
                    step: Step::TransformChild,
                    parent: Some(place),
                };
                let link = TransformLink {
                    own,
                    to_world,
                    parent: up.transforms,
                };
                let below = Inherited {
                    material,
                    to_world: &link.to_world,
                    transforms: Some(&link),
                    solid_only: up.solid_only,
                };
                return self.node(child, &child_place, below);
            }
        };
        let prim = place_primitive(shape, &up, material);
        // Bounds are finite, or `Aabb::EMPTY` for a primitive that holds
        // nothing; anything else means the numbers overflowed on the way.
        let b = prim.bounds;
        let finite = b.min.is_finite() && b.max.is_finite();
        if b.min.is_nan() || b.max.is_nan() || !(finite || b.is_empty()) {
            return Err(self.invalid(
                place.path(),
                format!("{kind} placed in the world has bounds that are not finite (coordinates too large)"),
            ));
        }
        if !b.is_empty() {
            let reach = b.min.abs().max(b.max.abs()).max_element();
            if reach > MAX_COORDINATE {
                return Err(self.invalid(
                    place.path(),
                    format!(
                        "{kind} placed in the world reaches {reach:e}, beyond ±{MAX_COORDINATE:e}: \
                         coordinates this large overflow the intersection arithmetic"
                    ),
                ));
            }
            if let Some((radius, size)) = curved_size(&prim)
                && size > 0.0
                && size < reach * MIN_CURVED_SIZE
            {
                let world = if prim.transform.is_some() {
                    format!(" ({} or more in the world)", fmt_sig(size))
                } else {
                    String::new()
                };
                return Err(self.invalid(
                    place.path(),
                    format!(
                        "{kind} has a radius of {radius}{world} where its coordinates reach \
                         {}: its surface is lost in their rounding (the radius must be at \
                         least 2^-48 = {MIN_CURVED_SIZE:.1e} of them)",
                        fmt_sig(reach)
                    ),
                ));
            }
        }
        let id = PrimId(self.primitives.len() as u32);
        self.primitives.push(prim);
        Ok(self.tree.leaf(id))
    }

    fn found(&self, (path, message): Found) -> Error {
        self.invalid(path, message)
    }
}

// The checks below take the path as a closure: building a path costs the
// node's depth, so it is built only for a message (else a 10,000-level chain
// would take quadratic time).

/// `v` finite; `field` names it in the message.
fn check_finite(
    v: Vector,
    field: &str,
    path: impl FnOnce() -> String,
) -> std::result::Result<(), Found> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err((
            path(),
            format!("{field} must be finite, got {}", fmt_vec(v)),
        ))
    }
}

/// The least radius of a sphere, cylinder or cone, against the largest
/// coordinate it reaches: their intersections are computed from points at
/// that magnitude (a centre, an end of the axis), which rounding places
/// only to some 2^-53 of it, so that below 2^-48 the surface would be off
/// by more than a thirtieth of the radius. Found by the scene mutants: a
/// rod of radius 0.2 reaching 1e30 had its surface placed to some 1e14,
/// the rays spawned on it started 1e16 away, and the cells and Roth
/// disagreed on what those met (`docs/robustness.md`). Boxes, triangles
/// and polygons have flat faces, placed to rounding of their own
/// coordinates, and are not limited (a ground reaching 1e50 renders).
pub const MIN_CURVED_SIZE: f64 = 1.0 / (1u64 << 48) as f64;

/// The radius of a curved primitive (the larger of a cone's two) and, under
/// a transform, a lower bound of its world radius (scaled by the map's
/// least stretch, at least 1 / ‖inverse‖, bounded by the Frobenius norm);
/// None for flat ones.
fn curved_size(prim: &Primitive) -> Option<(f64, f64)> {
    let radius = match prim.shape {
        Shape::Sphere { radius, .. } => radius,
        Shape::Cylinder { radius, .. } => radius,
        Shape::Cone {
            base_radius,
            top_radius,
            ..
        } => base_radius.max(top_radius),
        _ => return None,
    };
    let stretch = match &prim.transform {
        Some(t) => 1.0 / frobenius_norm(&t.inv_linear),
        None => 1.0,
    };
    Some((radius, radius * stretch))
}

/// A position: finite and within `MAX_COORDINATE` of the origin.
fn check_position(
    v: Vector,
    field: &str,
    path: impl FnOnce() -> String,
) -> std::result::Result<(), Found> {
    // (NaN is not within the bound either: it gets `check_finite`'s word.)
    if v.iter().all(|x| x.abs() <= MAX_COORDINATE) {
        return Ok(());
    }
    let path = path();
    check_finite(v, field, || path.clone())?;
    let worst = v
        .iter()
        .copied()
        .fold(0.0f64, |a, x| if x.abs() > a.abs() { x } else { a });
    Err((
        path,
        format!(
            "{field} has a coordinate of {worst:e}, beyond ±{MAX_COORDINATE:e}: coordinates \
             this large overflow the intersection arithmetic"
        ),
    ))
}

fn check_finite_scalar(
    x: f64,
    field: &str,
    path: impl FnOnce() -> String,
) -> std::result::Result<(), Found> {
    if x.is_finite() {
        Ok(())
    } else {
        Err((path(), format!("{field} must be finite, got {x}")))
    }
}

/// A colour: finite, no negative component.
fn check_colour(
    c: Vector,
    field: &str,
    path: impl FnOnce() -> String,
) -> std::result::Result<(), Found> {
    if !c.iter().all(|x| x.is_finite()) {
        return Err((
            path(),
            format!("{field} must be finite, got {}", fmt_vec(c)),
        ));
    }
    if c.iter().any(|x| *x < 0.0) {
        return Err((
            path(),
            format!(
                "{field} must have no negative component, got {}",
                fmt_vec(c)
            ),
        ));
    }
    if let Some(x) = c.iter().find(|x| **x > MAX_INTENSITY) {
        return Err((
            path(),
            format!("{field} has a component of {x:e}, above {MAX_INTENSITY:e}"),
        ));
    }
    Ok(())
}

/// True when `a` and `b` are parallel or either is zero, to a relative
/// tolerance of a few ulps of the angle between them. Both are scaled to
/// unit max-norm first so that no product overflows or underflows.
fn parallel(a: Vec3, b: Vec3) -> bool {
    let (ma, mb) = (a.abs().max_element(), b.abs().max_element());
    if ma == 0.0 || mb == 0.0 {
        return true;
    }
    let (a, b) = (a / ma, b / mb);
    a.cross(b).length() <= 8.0 * f64::EPSILON * a.length() * b.length()
}

fn fmt_vec(v: Vector) -> String {
    format!("({}, {}, {})", fmt_num(v[0]), fmt_num(v[1]), fmt_num(v[2]))
}

fn fmt_v3(v: Vec3) -> String {
    fmt_vec(v.to_array())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::csg::CsgNode;
    use std::path::PathBuf;

    const CAMERA: &str =
        "camera: (eye: (0, -6, 2), look_at: (0, 0, 0.8), fov_y: 40, width: 64, height: 48)";

    fn data(path: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data")
            .join(path)
    }

    fn ron(objects: &str) -> String {
        format!("({CAMERA}, objects: [{objects}])")
    }

    fn load_ron(text: &str) -> Result<(Scene, Vec<String>)> {
        parse_scene_str_with_warnings(text, SceneSyntax::Ron, Path::new("test.ron"))
    }

    /// `text` must fail with an `Error::Invalid` whose one-line message
    /// contains `expected`.
    #[track_caller]
    fn check_invalid(text: &str, expected: &str) {
        match load_ron(text) {
            Err(e @ Error::Invalid { .. }) => {
                let msg = e.to_string();
                assert!(
                    msg.contains(expected),
                    "{msg:?} should contain {expected:?}"
                );
                assert!(!msg.contains('\n'), "{msg:?} is not one line");
            }
            Err(e) => panic!("expected Error::Invalid containing {expected:?}, got {e:?}"),
            Ok(_) => panic!("expected Error::Invalid containing {expected:?}, got a scene"),
        }
    }

    /// Numbers in messages keep to the shorter of their plain and
    /// exponent forms: an eye 1e-300 off the vertical through `look_at`
    /// was named with three hundred digits.
    #[test]
    fn messages_write_tiny_and_huge_numbers_short() {
        let text = "(camera: (eye: (1e-300, 0, 5), look_at: (0, 0, 0), fov_y: 40, width: 8, height: 6), objects: [])";
        check_invalid(
            text,
            "up (0, 0, 1) is parallel to the view direction from eye to look_at (-1e-300, 0, -5)",
        );
        assert_eq!(fmt_vec([0.25, 1e20, -3.0]), "(0.25, 1e20, -3)");
        assert_eq!(fmt_vec([1e6, 1e12, -2.5e-7]), "(1000000, 1e12, -2.5e-7)");
        assert_eq!(fmt_num(1234567.5), "1234567.5");
    }

    #[track_caller]
    fn load_ok(text: &str) -> Scene {
        match load_ron(text) {
            Ok((scene, _)) => scene,
            Err(e) => panic!("{e}"),
        }
    }

    /// Every file of `tests/data/bad` is listed in `EXPECTED.tsv` with a
    /// substring of its error. The kind follows the name: `syntax_*` files
    /// give `Error::Syntax`, `usage_*` files `Error::Usage`, the others
    /// `Error::Invalid`.
    #[test]
    fn every_bad_file_fails_with_one_line_naming_the_place() {
        let dir = data("bad");
        let table = std::fs::read_to_string(dir.join("EXPECTED.tsv")).expect("EXPECTED.tsv");
        let mut listed = HashSet::new();
        for line in table.lines().filter(|l| !l.trim().is_empty()) {
            let (name, expected) = line.split_once('\t').expect("name<TAB>substring");
            listed.insert(name.to_string());
            let err = match load_scene_with_warnings(&dir.join(name)) {
                Ok(_) => panic!("{name}: loaded, but should fail with {expected:?}"),
                Err(e) => e,
            };
            let kind_ok = match &err {
                Error::Syntax { line, column, .. } => {
                    name.starts_with("syntax_") && *line >= 1 && *column >= 1
                }
                Error::Usage(_) => name.starts_with("usage_"),
                Error::Invalid { .. } => {
                    !name.starts_with("syntax_") && !name.starts_with("usage_")
                }
                _ => false,
            };
            assert!(kind_ok, "{name}: wrong kind of error: {err:?}");
            assert_eq!(err.exit_code(), 2, "{name}");
            let msg = err.to_string();
            assert!(!msg.contains('\n'), "{name}: not one line: {msg:?}");
            assert!(
                msg.contains(expected),
                "{name}: {msg:?} should contain {expected:?}"
            );
            assert!(msg.contains(name), "{name}: {msg:?} should name the file");
        }
        for entry in std::fs::read_dir(&dir).expect("tests/data/bad") {
            let name = entry
                .expect("entry")
                .file_name()
                .to_string_lossy()
                .into_owned();
            assert!(
                name == "EXPECTED.tsv" || listed.contains(&name),
                "{name} is not in EXPECTED.tsv"
            );
        }
        assert!(listed.len() >= 20);
    }

    #[test]
    fn every_good_file_loads() {
        for entry in std::fs::read_dir(data("good")).expect("tests/data/good") {
            let path = entry.expect("entry").path();
            if let Err(e) = load_scene(&path) {
                panic!("{e}");
            }
        }
    }

    #[test]
    fn ron_and_json_of_the_same_scene_compile_to_equal_scenes() {
        let a = load_scene(&data("good/example.ron")).expect("example.ron");
        let b = load_scene(&data("good/example.json")).expect("example.json");
        // `Scene` has no `PartialEq` (the tree carries derived data); its
        // Debug form shows every field, floats exactly.
        assert_eq!(format!("{a:?}"), format!("{b:?}"));
        let ma = parse_model_str(
            &std::fs::read_to_string(data("good/example.ron")).expect("read"),
            SceneSyntax::Ron,
            Path::new("example.ron"),
        )
        .expect("ron model");
        let mb = parse_model_str(
            &std::fs::read_to_string(data("good/example.json")).expect("read"),
            SceneSyntax::Json,
            Path::new("example.json"),
        )
        .expect("json model");
        assert_eq!(ma, mb);
    }

    #[test]
    fn the_example_compiles_as_scene_format_describes() {
        let s = load_scene(&data("good/example.ron")).expect("example.ron");
        assert_eq!(s.material_names, ["<default>", "red", "steel"]);
        assert_eq!(s.materials[2].specular, 0.6);
        assert_eq!(s.materials[2].ambient, 0.1);
        // Sphere and cylinder inherit the Difference's steel; the inner box
        // is red; the floor has the default.
        let mats: Vec<u32> = s.primitives.iter().map(|p| p.material.0).collect();
        assert_eq!(mats, [2, 1, 2, 0]);
        // Root: an explicit Union over the two objects.
        let root = s.tree.root.expect("root");
        assert!(matches!(
            s.tree.nodes[root.index()],
            CsgNode::Op { op: Op::Union, .. }
        ));
        assert_eq!(s.tree.children_of(root).len(), 2);
        let diff = s.tree.children_of(root)[0];
        assert!(matches!(
            s.tree.nodes[diff.index()],
            CsgNode::Op {
                op: Op::Difference,
                ..
            }
        ));
        assert_eq!(s.tree.children_of(diff).len(), 3);
        assert_eq!(s.background, Vec3::new(0.05, 0.05, 0.1));
    }

    #[test]
    fn integers_are_accepted_as_floats_in_both_syntaxes() {
        let r = load_ok(&ron("Sphere(center: (0, 0, 1), radius: 2)"));
        let j = parse_scene_str(
            r#"{"camera": {"eye": [0, -6, 2], "look_at": [0, 0, 0.8], "fov_y": 40, "width": 64, "height": 48},
                "objects": [{"Sphere": {"center": [0, 0, 1], "radius": 2}}]}"#,
            SceneSyntax::Json,
            Path::new("t.json"),
        )
        .expect("json");
        assert_eq!(format!("{r:?}"), format!("{j:?}"));
        assert_eq!(r.camera.fov_y, 40.0);
        assert!(matches!(r.primitives[0].shape, Shape::Sphere { radius, .. } if radius == 2.0));
    }

    #[test]
    fn defaults_follow_scene_format() {
        let s = load_ok(&ron(
            "Cylinder(base: (0, 0, 0), top: (0, 0, 1), radius: 1), \
             Cone(base: (0, 0, 0), base_radius: 1, top: (0, 0, 1), top_radius: 0), \
             Transform(child: Sphere(center: (1, 2, 3), radius: 1))",
        ));
        assert_eq!(s.background, Vec3::ZERO);
        assert_eq!(s.ambient, Vec3::ONE);
        assert!(s.lights.is_empty());
        assert_eq!(s.max_depth, 5);
        assert_eq!(s.camera.up, Vec3::Z);
        assert_eq!(s.materials, [Material::default()]);
        assert_eq!(s.material_names, [DEFAULT_MATERIAL_NAME]);
        assert!(
            s.primitives[0].is_solid() && s.primitives[1].is_solid(),
            "capped by default"
        );
        // The default transform is the identity: the sphere stays put.
        assert_eq!(s.primitives[2].bounds.min, Vec3::new(0.0, 1.0, 2.0));
        let m = parse_model_str(
            &format!(
                "({CAMERA}, lights: [(position: (1, 2, 3))], materials: {{\"m\": ()}}, objects: [])"
            ),
            SceneSyntax::Ron,
            Path::new("t.ron"),
        )
        .expect("model");
        assert_eq!(m.lights[0].color, [1.0; 3]);
        let s = compile_model(&m, Path::new("t.ron")).expect("compile").0;
        assert_eq!(s.materials[1], Material::default());
        assert_eq!(
            Material::default(),
            Material {
                color: Vec3::ONE,
                ambient: 0.1,
                diffuse: 0.7,
                specular: 0.0,
                shininess: 20.0,
                reflect: 0.0,
                transmit: 0.0,
                ior: 1.0
            }
        );
    }

    #[test]
    fn materials_are_numbered_by_name_after_the_default() {
        let s = load_ok(&format!(
            "({CAMERA}, materials: {{\"zinc\": (diffuse: 0.2), \"alu\": (diffuse: 0.3)}}, \
             objects: [Sphere(center: (0, 0, 0), radius: 1, material: \"zinc\")])"
        ));
        assert_eq!(s.material_names, ["<default>", "alu", "zinc"]);
        assert_eq!(s.primitives[0].material, MaterialId(2));
        assert_eq!(s.material(MaterialId(2)).diffuse, 0.2);
    }

    #[test]
    fn nodes_inherit_the_nearest_ancestors_material() {
        let s = load_ok(&format!(
            "({CAMERA}, materials: {{\"a\": (), \"b\": ()}}, objects: [
                Union(material: \"a\", children: [
                    Sphere(center: (0, 0, 0), radius: 1),
                    Transform(material: \"b\", translate: (1, 0, 0), child:
                        Assembly(children: [Sphere(center: (0, 0, 0), radius: 1)])),
                    Box(min: (0, 0, 0), max: (1, 1, 1), material: \"b\"),
                ]),
                Sphere(center: (0, 0, 0), radius: 1),
            ])"
        ));
        let mats: Vec<u32> = s.primitives.iter().map(|p| p.material.0).collect();
        assert_eq!(mats, [1, 2, 2, 0]);
    }

    #[test]
    fn material_base_fills_unset_fields_along_a_chain() {
        let s = load_ok(&format!(
            "({CAMERA}, materials: {{
                \"a\": (color: (0.5, 0.5, 0.5), specular: 0.4, shininess: 50),
                \"b\": (base: \"a\", reflect: 0.3, shininess: 10),
                \"c\": (base: \"b\", ior: 1.3),
            }}, objects: [])"
        ));
        let c = s.material(MaterialId(3));
        assert_eq!(c.color, Vec3::splat(0.5));
        assert_eq!(
            (c.specular, c.shininess, c.reflect, c.ior),
            (0.4, 10.0, 0.3, 1.3)
        );
        assert_eq!(c.diffuse, 0.7, "unset everywhere: the default");
        check_invalid(
            &format!("({CAMERA}, materials: {{\"a\": (base: \"a\")}}, objects: [])"),
            "materials[\"a\"].base: material inheritance cycle: \"a\" -> \"a\"",
        );
        check_invalid(
            &format!("({CAMERA}, materials: {{\"<default>\": ()}}, objects: [])"),
            "reserved",
        );
    }

    #[test]
    fn paths_name_the_node_and_field() {
        check_invalid(
            &ron("Sphere(center: (0, 0, 0), radius: 1), \
                  Difference(children: [Sphere(center: (0, 0, 0), radius: 1), \
                  Transform(child: Union(children: [Box(min: (0, 0, 0), max: (1, 1, 1)), \
                  Sphere(center: (0, 0, 0), radius: 0)]))])"),
            "test.ron: objects[1].Difference.children[1].Transform.child.Union.children[1].Sphere.radius: \
             radius must be > 0, got 0",
        );
        check_invalid(
            &ron(
                "Intersection(children: [Sphere(center: (0, 0, 0), radius: 1), \
                  Assembly(children: [Triangle(a: (0, 0, 0), b: (1, 0, 0), c: (0, 1, 0))])])",
            ),
            "objects[0].Intersection.children[1].Assembly.children[0]: Triangle is a surface (it bounds no volume) \
             and cannot be inside the Intersection at objects[0]",
        );
        check_invalid(
            &ron("Cone(base: (0, 0, 0), base_radius: -1, top: (0, 0, 1), top_radius: 0)"),
            "objects[0].Cone.base_radius: base_radius must be >= 0, got -1",
        );
        check_invalid(
            &ron("Polygon(vertices: [(0, 0, 0), (1, 0, 0)])"),
            "objects[0].Polygon.vertices: a Polygon needs at least 3 vertices, got 2",
        );
        check_invalid(
            &ron("Polygon(vertices: [(0, 0, 0), (1, 0, 0), (0, NaN, 0)])"),
            "objects[0].Polygon.vertices[2]: vertices[2] must be finite, got (0, NaN, 0)",
        );
        check_invalid(
            &ron("Transform(scale: (1e-60, 1e-60, 1e-60), child: \
                  Transform(scale: (1e-60, 1e-60, 1e-60), child: Sphere(center: (0, 0, 0), radius: 1)))"),
            "objects[0].Transform.child: the transforms down to here compose to a map that is not finite",
        );
        check_invalid(
            &format!("({CAMERA}, lights: [(position: (0, NaN, 0))], objects: [])"),
            "lights[0].position: position must be finite, got (0, NaN, 0)",
        );
        check_invalid(
            &format!("({CAMERA}, background: (0, -1, 0), objects: [])"),
            "background: background must have no negative component",
        );
        check_invalid(
            &format!("({CAMERA}, materials: {{\"m\": (specular: -0.5)}}, objects: [])"),
            "materials[\"m\"].specular: specular must be >= 0, got -0.5",
        );
        check_invalid(
            &format!("({CAMERA}, materials: {{\"m\": (shininess: -1)}}, objects: [])"),
            "materials[\"m\"].shininess: shininess must be >= 0, got -1",
        );
        check_invalid(
            "(camera: (eye: (0, 0, 0), look_at: (1, 0, 0), up: (0, 0, 0), fov_y: 40, width: 4, height: 4), objects: [])",
            "camera.up: up must not be zero",
        );
        check_invalid(
            &ron("Cylinder(base: (0, 0, 0), top: (0, 0, 1), radius: inf)"),
            "objects[0].Cylinder.radius: radius must be finite, got inf",
        );
    }

    #[test]
    fn surfaces_are_allowed_under_union_and_assembly_only() {
        let s = load_ok(&ron("Union(children: [Assembly(children: [ \
            Triangle(a: (0, 0, 0), b: (1, 0, 0), c: (0, 1, 0)), \
            Cone(base: (0, 0, 0), base_radius: 1, top: (0, 0, 1), top_radius: 0.5, capped: false)])]), \
            Polygon(vertices: [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)])"));
        assert_eq!(s.primitives.len(), 3);
        // A capped cylinder is a solid: fine under a difference.
        load_ok(&ron(
            "Difference(children: [Sphere(center: (0, 0, 0), radius: 1), \
            Cylinder(base: (0, 0, -2), top: (0, 0, 2), radius: 0.5)])",
        ));
        check_invalid(
            &ron(
                "Difference(children: [Union(children: [Sphere(center: (0, 0, 0), radius: 1), \
                  Cone(base: (0, 0, 0), base_radius: 1, top: (0, 0, 1), top_radius: 0, capped: false)])])",
            ),
            "objects[0].Difference.children[0].Union.children[1]: Cone is a surface",
        );
    }

    #[test]
    fn a_zero_thickness_box_loads_with_a_warning() {
        let (s, warnings) =
            load_scene_with_warnings(&data("good/zero_thickness_box.ron")).expect("loads");
        assert_eq!(s.primitives.len(), 2);
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(
            warnings[0]
                .contains("objects[0].Difference.children[1]: Box has zero thickness along x")
        );
        assert!(!warnings[0].contains('\n'));
        // Inverted is still an error.
        check_invalid(
            &ron("Box(min: (0, 0, 1), max: (1, 1, 0))"),
            "objects[0]: Box min.z = 1 is above max.z = 0",
        );
    }

    #[test]
    fn an_empty_scene_loads_with_a_warning() {
        let (s, warnings) = load_ron(&ron("")).expect("loads");
        assert!(s.primitives.is_empty());
        let root = s.tree.root.expect("root");
        assert!(s.tree.children_of(root).is_empty());
        assert!(warnings[0].contains("no objects"), "{warnings:?}");
    }

    #[test]
    fn resolution_bounds() {
        assert!(check_resolution(4096, 4096).is_ok());
        assert!(check_resolution(1, 1).is_ok());
        assert!(check_resolution(65536, 4096).is_ok());
        assert!(check_resolution(16384, 16384).is_ok());
        assert!(check_resolution(1_000_000, 1_000_000).is_err());
        assert!(check_resolution(65537, 1).is_err());
        assert!(check_resolution(65536, 65536).is_err());
        assert!(check_resolution(0, 10).is_err());
        assert!(check_resolution(10, 0).is_err());
    }

    #[test]
    fn syntax_is_chosen_by_extension() {
        assert_eq!(
            SceneSyntax::from_path(Path::new("a/b.RON")).ok(),
            Some(SceneSyntax::Ron)
        );
        assert_eq!(
            SceneSyntax::from_path(Path::new("b.json")).ok(),
            Some(SceneSyntax::Json)
        );
        assert_eq!(
            SceneSyntax::from_path(Path::new("b.nff")).ok(),
            Some(SceneSyntax::Nff)
        );
        assert!(matches!(
            SceneSyntax::from_path(Path::new("b.yaml")),
            Err(Error::Usage(_))
        ));
        assert!(matches!(
            SceneSyntax::from_path(Path::new("scene")),
            Err(Error::Usage(_))
        ));
        let missing = load_scene(Path::new("/nonexistent/scene.ron"));
        assert!(matches!(missing, Err(Error::Read { .. })));
    }

    #[test]
    fn syntax_errors_give_line_and_column() {
        let text = format!(
            "(\n  {CAMERA},\n  objects: [\n    Sphere(center: (0, 0, 1), radius: 1, colour: 2),\n  ],\n)"
        );
        match load_ron(&text) {
            Err(Error::Syntax {
                line,
                column,
                message,
                ..
            }) => {
                assert_eq!((line, column), (4, 42));
                assert!(
                    message
                        .starts_with("unknown field `colour` in Sphere, expected one of `center`"),
                    "{message}"
                );
            }
            other => panic!("{other:?}"),
        }
        let json = "{\n\"camera\": {\"eye\": [0, -6, 2], \"look_at\": [0, 0, 0.8], \"fov_y\": 40, \"width\": 64, \"height\": 48}\n}";
        match parse_scene_str(json, SceneSyntax::Json, Path::new("t.json")) {
            Err(e @ Error::Syntax { line: 3, .. }) => {
                assert_eq!(e.to_string(), "t.json:3:1: missing field `objects`");
            }
            other => panic!("{other:?}"),
        }
        for text in ["", "   "] {
            assert!(matches!(
                parse_scene_str(text, SceneSyntax::Json, Path::new("t.json")),
                Err(Error::Syntax {
                    line: 1,
                    column: 1..,
                    ..
                })
            ));
            assert!(matches!(load_ron(text), Err(Error::Syntax { line: 1, .. })));
        }
    }

    #[test]
    fn models_round_trip_through_ron_and_json() {
        let text = std::fs::read_to_string(data("good/features.ron")).expect("read");
        let model =
            parse_model_str(&text, SceneSyntax::Ron, Path::new("features.ron")).expect("model");
        for syntax in [SceneSyntax::Ron, SceneSyntax::Json] {
            let written = scene_to_string(&model, syntax).expect("write");
            let again = parse_model_str(&written, syntax, Path::new("again")).expect("reread");
            assert_eq!(model, again, "{syntax:?}:\n{written}");
        }
        // Optional material fields are written bare, as people write them.
        let written = scene_to_string(&model, SceneSyntax::Ron).expect("write");
        assert!(written.contains("base: \"metal\""), "{written}");
        assert!(!written.contains("Some("), "{written}");
    }

    /// A left-deep chain of `depth` differences, as RON and as JSON.
    fn deep_chain(depth: usize) -> (String, String) {
        let mut r = format!("({CAMERA}, objects: [");
        let mut j = String::from(
            r#"{"camera": {"eye": [0, -6, 2], "look_at": [0, 0, 0.8], "fov_y": 40, "width": 64, "height": 48}, "objects": ["#,
        );
        for _ in 0..depth {
            r.push_str("Difference(children: [");
            j.push_str(r#"{"Difference": {"children": ["#);
        }
        r.push_str("Sphere(center: (0, 0, 0), radius: 2)");
        j.push_str(r#"{"Sphere": {"center": [0, 0, 0], "radius": 2}}"#);
        for _ in 0..depth {
            r.push_str(", Sphere(center: (1, 0, 0), radius: 0.5)])");
            j.push_str(r#", {"Sphere": {"center": [1, 0, 0], "radius": 0.5}}]}}"#);
        }
        r.push_str("])");
        j.push_str("]}");
        (r, j)
    }

    #[test]
    fn inner_transforms_are_baked_before_outer_ones() {
        // A scaled unit box under a rotation: the scale is folded into the
        // box, the rotation kept, so it shares its object space with any
        // other primitive under that rotation (`ROBUSTNESS.md` case 10).
        let s = load_ok(&ron(
            "Transform(rotate: (30, 40, 50), child: Union(children: [
               Box(min: (-1, -1, -1), max: (1, 1, 1)),
               Transform(scale: (1, 2, 2), translate: (0, -1, -1),
                 child: Box(min: (0, 0, 0), max: (1, 1, 1)))]))",
        ));
        let rotation = Affine::from_srt(Vec3::ONE, Vec3::new(30.0, 40.0, 50.0), Vec3::ZERO);
        let b = &s.primitives[1];
        assert_eq!(
            b.shape,
            Shape::Box {
                min: Vec3::new(0.0, -1.0, -1.0),
                max: Vec3::ONE
            }
        );
        assert_eq!(b.transform, Some(Box::new(rotation)));
        assert_eq!(s.primitives[0].transform, Some(Box::new(rotation)));
        // Everything bakes when everything can: translations over a box.
        let s = load_ok(&ron(
            "Transform(translate: (1, 0, 0), child: Transform(scale: (2, 2, 2), \
             child: Box(min: (0, 0, 0), max: (1, 1, 1))))",
        ));
        assert_eq!(s.primitives[0].transform, None);
        assert_eq!(s.primitives[0].bounds.max, Vec3::new(3.0, 2.0, 2.0));
    }

    #[test]
    fn a_ten_thousand_level_chain_loads() {
        let depth = 10_000;
        let (r, j) = deep_chain(depth);
        for (text, syntax) in [(r, SceneSyntax::Ron), (j, SceneSyntax::Json)] {
            let s = parse_scene_str(&text, syntax, Path::new("deep")).expect("deep chain loads");
            assert_eq!(s.primitives.len(), depth + 1);
            // Leaves, differences and the root union.
            assert_eq!(s.tree.nodes.len(), 2 * depth + 2);
        }
        // And as a chain of transforms, each a tiny translation.
        let mut t = format!("({CAMERA}, objects: [");
        t.push_str(&"Transform(translate: (0.001, 0, 0), child: ".repeat(depth));
        t.push_str("Sphere(center: (0, 0, 0), radius: 1)");
        t.push_str(&")".repeat(depth));
        t.push_str("])");
        let s = load_ok(&t);
        assert!((s.primitives[0].bounds.min.x - 9.0).abs() < 1e-6);
    }

    #[test]
    fn nesting_beyond_the_limit_is_a_syntax_error() {
        let json = format!(
            "{}{}",
            "[".repeat(MAX_NESTING + 1),
            "]".repeat(MAX_NESTING + 1)
        );
        match parse_scene_str(&json, SceneSyntax::Json, Path::new("t.json")) {
            Err(Error::Syntax {
                message, column, ..
            }) => {
                assert!(message.contains("nested too deeply"), "{message}");
                assert_eq!(column, MAX_NESTING + 1);
            }
            other => panic!("{other:?}"),
        }
        // Brackets inside strings do not count.
        assert_eq!(
            json_too_deep(&format!("[\"{}\"]", "[".repeat(MAX_NESTING + 5))),
            None
        );
        let ron_text = format!(
            "({CAMERA}, objects: [{}])",
            "Union(children: [".repeat(RON_RECURSION_LIMIT / 2)
        );
        match load_ron(&ron_text) {
            Err(Error::Syntax { message, .. }) => {
                assert!(message.contains("nested too deeply"), "{message}")
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn nff_imports_view_lights_materials_and_objects() {
        let s = load_scene(&data("good/spd_like.nff")).expect("nff");
        // angle 45 between the centres of the outer rows of 60.
        let expected = 2.0
            * ((22.5f64).to_radians().tan() * 60.0 / 59.0)
                .atan()
                .to_degrees();
        assert!((s.camera.fov_y - expected).abs() < 1e-12);
        assert_eq!((s.camera.width, s.camera.height), (80, 60));
        assert_eq!(s.background, Vec3::new(0.1, 0.1, 0.3));
        // Two lights: the colourless one gets sqrt(2)/4.
        assert!((s.lights[0].color.x - 2f64.sqrt() / 4.0).abs() < 1e-15);
        assert_eq!(s.lights[1].color, Vec3::new(1.0, 0.9, 0.8));
        assert_eq!(s.material_names, ["<default>", "f@12", "f@14"]);
        let glass = s.material(MaterialId(2));
        assert_eq!(
            (glass.specular, glass.reflect, glass.transmit, glass.ior),
            (0.5, 0.5, 0.9, 1.5)
        );
        let kinds: Vec<&str> = s
            .primitives
            .iter()
            .map(|p| match p.shape {
                Shape::Sphere { .. } => "s",
                Shape::Cone { capped: false, .. } => "cone",
                Shape::Cylinder { capped: false, .. } => "cyl",
                Shape::Polygon(_) => "p",
                Shape::Triangle { .. } => "t",
                _ => "?",
            })
            .collect();
        assert_eq!(kinds, ["s", "cone", "cyl", "p", "t"]);
        let mats: Vec<u32> = s.primitives.iter().map(|p| p.material.0).collect();
        assert_eq!(mats, [1, 2, 2, 2, 2]);
    }

    #[test]
    fn nff_errors_give_their_line() {
        let file = Path::new("t.nff");
        let view = "v\nfrom 0 -6 2\nat 0 0 0\nup 0 0 1\nangle 40\nresolution 8 8\n";
        let cases = [
            (format!("{view}l 1 2\n"), "t.nff:7:1: `l` takes 3 numbers"),
            (
                format!("{view}f 1 1 1 0.5\n"),
                "t.nff:7:1: `f` takes 8 numbers, got 4",
            ),
            (
                format!("{view}s 0 0 0 1 9\n"),
                "t.nff:7:11: `s` takes 4 numbers, unexpected `9`",
            ),
            (
                format!("{view}s 0 0 nan 1\n"),
                "t.nff:7:7: expected a finite number, got `nan`",
            ),
            (
                format!("{view}p 2\n0 0 0\n1 0 0\n"),
                "t.nff:7:1: `p` takes one whole number",
            ),
            (
                format!("{view}pp 3\n0 0 0\n1 0 0\n0 1 0\n"),
                "t.nff:8:1: expected a vertex and its normal",
            ),
            (
                format!("{view}c\n0 0 0 1\n"),
                "the file ends where the apex of `c`",
            ),
            ("s 0 0 0 1\n".to_string(), "t.nff:1:1: no view entity `v`"),
            (
                "v\nfrom 0 0 0\nat 1 0 0\nup 0 0 1\n".to_string(),
                "t.nff:1:1: the view entity `v` has no `angle` line",
            ),
            (
                format!("{view}{view}"),
                "t.nff:7:1: a second view entity `v` (the first is on line 1)",
            ),
            (
                "v\nfrom 0 0 0\nat 1 0 0\nup 0 0 1\nangle 180\n".to_string(),
                "t.nff:5:7: `angle` must be in (0, 180)",
            ),
            (
                format!("{view}  # fine\ntorus 1\n"),
                "t.nff:8:1: unknown NFF entity `torus`",
            ),
            (
                format!("{view}p 3\n0 0 0\n1 1 1\n2 2 2\n"),
                "objects[0] (line 7): Triangle has zero area",
            ),
            (
                format!("{view}l 1 1 1 -1 0 0\n"),
                "lights[0].color (line 7)",
            ),
            (
                "v\nfrom 0 0 0\nat 0 0 0\nup 0 0 1\nangle 40\n".to_string(),
                "camera.look_at (line 1)",
            ),
        ];
        for (text, expected) in cases {
            match parse_scene_str(&text, SceneSyntax::Nff, file) {
                Err(e) => {
                    let msg = e.to_string();
                    assert!(
                        msg.contains(expected),
                        "{msg:?} should contain {expected:?}"
                    );
                    assert!(!msg.contains('\n'));
                }
                Ok(_) => panic!("{text:?} should fail with {expected:?}"),
            }
        }
    }
}
