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
    Capacity(String),
    /// Occurs when a render or experiment fails after its input was accepted
    /// (a node failed, a budget could not be met at run time).
    #[error("{0}")]
    Render(String),
    /// Occurs when an output file cannot be written; nothing partial is left.
    #[error("{}: cannot write: {message}", path.display())]
    Write { path: PathBuf, message: String },
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
