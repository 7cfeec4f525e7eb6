//! The one error type of the core. The Python binding maps each variant to one of lightemma's
//! exception classes (`lightemma.errors`, all `ValueError` subclasses) in a single place
//! (`python/errors.rs`); Rust callers match on it.

use std::fmt;

/// Why a kernel refused its input. Messages name the offending shape, index or value.
#[derive(Debug, Clone, PartialEq)]
pub enum CoreError {
    /// An array has the wrong number of dimensions or the wrong extent.
    Shape(String),
    /// A NaN or infinity where only finite numbers are allowed.
    NonFinite {
        what: &'static str,
        frame: usize,
        step: usize,
    },
    /// A name (method, convention, mode) that is not one of the allowed ones.
    UnknownName {
        kind: &'static str,
        name: String,
        allowed: &'static [&'static str],
    },
    /// A scalar argument out of its range.
    Argument(String),
}

impl fmt::Display for CoreError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CoreError::Shape(msg) => write!(f, "{msg}"),
            CoreError::NonFinite { what, frame, step } => write!(
                f,
                "{what} has a non-finite value (NaN or inf) at frame {frame}, step {step}"
            ),
            CoreError::UnknownName {
                kind,
                name,
                allowed,
            } => write!(
                f,
                "unknown {kind} {name:?}; expected one of: {}",
                allowed.join(", ")
            ),
            CoreError::Argument(msg) => write!(f, "{msg}"),
        }
    }
}

impl std::error::Error for CoreError {}

pub type CoreResult<T> = Result<T, CoreError>;
