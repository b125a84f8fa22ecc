//! The crate's one error type. Every kind says when it occurs; scene and
//! topology errors carry the file and either a line and column (syntax) or
//! the node's path in the tree (meaning). Only `main.rs` prints errors and
//! turns them into exit codes.

use std::path::PathBuf;

/// Everything that can go wrong, by kind.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Occurs when an input file (scene, topology, reference image) cannot be read.
    #[error("{}: cannot read: {source}", path.display())]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    /// Occurs when an input file is not well-formed: bad syntax, an unknown
    /// field or variant, a value of the wrong type. Line and column are 1-based.
    #[error("{}:{line}:{column}: {message}", file.display())]
    Syntax {
        file: PathBuf,
        line: usize,
        column: usize,
        message: String,
    },
    /// Occurs when a well-formed input means something impossible: degenerate
    /// geometry, NaN, an unknown material, a surface under a difference.
    /// `path` names the place, e.g. `objects[2].Difference.children[5]`.
    #[error("{}: {path}: {message}", file.display())]
    Invalid {
        file: PathBuf,
        path: String,
        message: String,
    },
    /// Occurs when command-line options are inconsistent or out of range.
    #[error("{0}")]
    Usage(String),
    /// Occurs when a scene's share of the cell structure, with room for the
    /// rays in flight, does not fit a node's memory budget: refused before
    /// rendering, with the numbers and what to change.
    #[error("{0}")]
    Capacity(Refusal),
    /// Occurs when a render or experiment fails after its input was accepted
    /// (a node failed, a budget could not be met at run time).
    #[error("{0}")]
    Render(String),
    /// Occurs when an output file cannot be written; nothing partial is left.
    #[error("{}: cannot write: {message}", path.display())]
    Write { path: PathBuf, message: String },
}

/// A share that does not fit a node (`Error::Capacity`): the numbers, and
/// what would make it fit. Kept in parts, not as one line, so that an
/// experiment over several dimensions (`scale --dims`) can name the one
/// refused and ask for more nodes in its own options.
#[derive(Clone, Debug, PartialEq)]
pub struct Refusal {
    /// Which node needs how much for what, against which budget.
    pub numbers: String,
    /// The memory per node that would fit the share on the same
    /// dimension, as `--node-memory` reads it: every remedy names it.
    pub memory: String,
    /// The dimension refused, named by a run over several (`scale`): more
    /// nodes are then asked for as `--dims` takes them, not as `--dim`.
    pub among_dims: Option<u32>,
    /// What would make the share fit besides `memory`.
    pub remedy: Remedy,
}

/// What would make a refused share fit, besides more memory per node.
#[derive(Clone, Debug, PartialEq)]
pub enum Remedy {
    /// More nodes than at `dimension`, the largest known not to fit (the
    /// one refused, or the last that `machine::host::advise` planned):
    /// from `fits_at` where that is known (the least larger dimension
    /// whose plan was made and fits), else any above.
    MoreNodes {
        dimension: u32,
        fits_at: Option<u32>,
    },
    /// Nothing else; `why` says why more nodes cannot help, unless there
    /// are no more (the largest dimension).
    MoreMemory { why: Option<String> },
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(d) = self.among_dims {
            write!(f, "at d = {d}: ")?;
        }
        write!(f, "{}; ", self.numbers)?;
        let memory = &self.memory;
        match (&self.remedy, self.among_dims) {
            (
                Remedy::MoreNodes {
                    fits_at: Some(d), ..
                },
                None,
            ) => write!(
                f,
                "use --dim {d} (the fewest nodes that fit) or --node-memory {memory}"
            ),
            (
                Remedy::MoreNodes {
                    fits_at: Some(d), ..
                },
                Some(_),
            ) => write!(
                f,
                "start --dims at {d} (the fewest nodes that fit) or use --node-memory {memory}"
            ),
            (Remedy::MoreNodes { dimension, .. }, None) => write!(
                f,
                "use --dim {} or more, or --node-memory {memory}",
                dimension + 1
            ),
            (Remedy::MoreNodes { dimension, .. }, Some(_)) => {
                write!(
                    f,
                    "start --dims above {dimension}, or --node-memory {memory}"
                )
            }
            (Remedy::MoreMemory { why: Some(why) }, _) => {
                write!(f, "{why}: use --node-memory {memory}")
            }
            (Remedy::MoreMemory { why: None }, _) => write!(f, "use --node-memory {memory}"),
        }
    }
}

impl Error {
    /// `CLI.md`: 1 when a render or experiment failed, 2 for bad input.
    pub fn exit_code(&self) -> i32 {
        match self {
            Error::Render(_) | Error::Write { .. } => 1,
            Error::Read { .. }
            | Error::Syntax { .. }
            | Error::Invalid { .. }
            | Error::Usage(_)
            | Error::Capacity(_) => 2,
        }
    }

    pub fn invalid(
        file: impl Into<PathBuf>,
        path: impl Into<String>,
        message: impl Into<String>,
    ) -> Error {
        Error::Invalid {
            file: file.into(),
            path: path.into(),
            message: message.into(),
        }
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Starts worker `i` of `n` (`what`, e.g. "render thread") in `scope`,
/// named `hypercast-{tag}-{i}`. A thread the OS refuses (too many threads,
/// no memory for a stack) is `Error::Render` naming it, not the panic of
/// `Scope::spawn`: the run fails rather than go on with fewer threads
/// than asked for, as a slower run that says nothing would mislead the
/// timings the experiments take. The caller stops the workers already
/// started from taking more work; the scope joins them.
pub fn start_worker<'scope, T: Send + 'scope>(
    scope: &'scope std::thread::Scope<'scope, '_>,
    (tag, what): (&str, &str),
    (i, n): (usize, usize),
    work: impl FnOnce() -> T + Send + 'scope,
) -> Result<std::thread::ScopedJoinHandle<'scope, T>> {
    std::thread::Builder::new()
        .name(format!("hypercast-{tag}-{i}"))
        .spawn_scoped(scope, work)
        .map_err(|e| Error::Render(format!("cannot start {what} {} of {n}: {e}", i + 1)))
}

/// A number as messages write it: plain up to seven characters (`5`,
/// `0.25`, `1000000`), else the shortest of its plain and exponent forms
/// (`1e-300`, not three hundred digits; `1e12`, `1234567.5`).
pub(crate) fn fmt_num(x: f64) -> String {
    let plain = format!("{x}");
    if plain.len() <= 7 {
        return plain;
    }
    [format!("{x:?}"), format!("{x:e}")]
        .into_iter()
        .fold(plain, |a, b| if b.len() < a.len() { b } else { a })
}

/// `x` to four significant digits, written as `fmt_num` writes it
/// (`0.9254`, `7.071e-16`).
pub(crate) fn fmt_sig(x: f64) -> String {
    fmt_num(format!("{x:.3e}").parse().unwrap_or(x))
}
