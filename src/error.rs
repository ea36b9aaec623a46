//! The crate's error type: misuse and bad input are errors; numerical outcomes are statuses.

use std::path::PathBuf;

/// Everything that can go wrong before a computation starts, or that makes its input unusable.
///
/// Non-convergence is *not* an error: solvers and estimators report it through a `Status`
/// in their report (see DESIGN.md, "Misuse is an error, non-convergence is a status").
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// Two objects that must agree in size do not.
    #[error("dimension mismatch in {what}: expected {expected}, got {got}")]
    DimensionMismatch {
        /// What was being checked.
        what: String,
        /// The size that was expected.
        expected: usize,
        /// The size that was found.
        got: usize,
    },
    /// An option or argument has a value outside its domain.
    #[error("invalid option `{name}`: {reason}")]
    InvalidOption {
        /// The option's name.
        name: String,
        /// Why the value is rejected.
        reason: String,
    },
    /// An option of an estimator that it does not have, or a value it does not take.
    #[error("invalid option `{option}` of `{method}`: {reason}")]
    EstimatorOption {
        /// The estimator's method name (`exp-closure`, …).
        method: String,
        /// The option's name (`moments`, `dual.tolerance`, …).
        option: String,
        /// Why it is rejected, with the allowed names or values.
        reason: String,
    },
    /// A name (model, parameter, state, output, likelihood) that is not known.
    #[error("unknown {kind} `{name}`{}", if .known.is_empty() { String::new() } else { format!(" (known: {})", .known.join(", ")) })]
    UnknownName {
        /// What kind of name it is ("model", "parameter", ...).
        kind: String,
        /// The name that was given.
        name: String,
        /// The names that would have been accepted.
        known: Vec<String>,
    },
    /// A numerical input is NaN or infinite where a finite value is required.
    #[error("non-finite value in {what}")]
    NonFinite {
        /// Where the value was found.
        what: String,
    },
    /// The diffusion matrix G(θ) is singular or not finite.
    #[error("singular diffusion matrix G(theta): {reason}")]
    SingularDiffusion {
        /// Why it is rejected.
        reason: String,
    },
    /// A data file is malformed; names the file, line and (when known) column.
    #[error("{}:{line}{}: {reason}", .path.display(), match .column { Some(c) => format!(", column {c}"), None => String::new() })]
    Data {
        /// The file being read or written.
        path: PathBuf,
        /// 1-based line number (the header is line 1).
        line: usize,
        /// 1-based column number or name, when the problem is in one cell.
        column: Option<String>,
        /// What is wrong.
        reason: String,
    },
    /// The shards of a sharded experiment cannot be merged: they are not parts of one run, a
    /// row is duplicated or misplaced, or a shard is still running. Names the folder; the
    /// reason names the files.
    #[error("cannot merge the shards in {}: {reason}", .path.display())]
    Merge {
        /// The output folder being merged.
        path: PathBuf,
        /// Why, naming the shard folders or files at fault.
        reason: String,
    },
    /// A model file is malformed or declares an inconsistent model; names the file, the line
    /// and the column (1-based, in characters) of the problem, and what was expected.
    #[error("{file}:{line}:{column}: {reason}")]
    ModelFile {
        /// The file (as given), or a label for text that did not come from a file.
        file: String,
        /// 1-based line.
        line: usize,
        /// 1-based column, in characters.
        column: usize,
        /// What is wrong and what was expected.
        reason: String,
    },
    /// A computation whose structures would need more memory than the limit allows
    /// ([`MemoryLimit`](crate::estimate::MemoryLimit)); checked before anything is allocated.
    #[error(
        "{what}: {size} needs about {} of memory, above the limit of {} (raise it with \
         `--max-memory`, e.g. `--max-memory {}`, or make the problem smaller)",
        crate::estimate::format_bytes(*.estimate), crate::estimate::MemoryLimit::new(*.limit),
        crate::estimate::MemoryLimit::new(crate::estimate::MemoryLimit::suggestion(*.estimate) as u64)
    )]
    MemoryLimit {
        /// The estimator or reader that refused.
        what: String,
        /// The sizes that drive the estimate (e.g. `10⁹ grid cells × 40 output times`).
        size: String,
        /// The estimated bytes.
        estimate: f64,
        /// The limit in bytes.
        limit: u64,
    },
    /// An I/O error, with the path it concerns.
    #[error("{}: {source}", .path.display())]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
}

impl Error {
    /// [`Error::InvalidOption`] with `name` and `reason`.
    pub fn invalid(name: impl Into<String>, reason: impl Into<String>) -> Error {
        Error::InvalidOption { name: name.into(), reason: reason.into() }
    }

    /// An [`Error::InvalidOption`] of a nested option group named `prefix.name`; other errors
    /// unchanged.
    pub fn within(self, prefix: &str) -> Error {
        match self {
            Error::InvalidOption { name, reason } => {
                Error::InvalidOption { name: format!("{prefix}.{name}"), reason }
            }
            other => other,
        }
    }
}

/// Checks an option that must be positive and finite (when given). Errors:
/// [`Error::InvalidOption`] naming `name` and the value.
pub fn check_positive(name: &str, value: impl Into<Option<f64>>) -> Result<()> {
    match value.into() {
        Some(v) if !(v.is_finite() && v > 0.0) => {
            Err(Error::invalid(name, format!("must be positive and finite, got {v}")))
        }
        _ => Ok(()),
    }
}

/// Shorthand for `Result<T, onsager::Error>`.
pub type Result<T> = std::result::Result<T, Error>;
