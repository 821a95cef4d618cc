//! Errors of a solve: bad input, or a method the operator cannot support.

/// Why a solve could not start.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SolveError {
    #[error("{what} has length {len} but the operator has {expected} unknowns")]
    WrongLength {
        what: &'static str,
        len: usize,
        expected: usize,
    },
    #[error("{what} has a non-finite value ({value}) at index {index}")]
    NonFinite {
        what: &'static str,
        index: usize,
        value: f64,
    },
    #[error("method {method} needs {needs}, which this operator does not provide; choose another method")]
    Unsupported { method: String, needs: &'static str },
    #[error("invalid solve options: {0}")]
    InvalidOptions(String),
    #[error("the operator's {what} is invalid: {reason}")]
    InvalidOperatorData { what: &'static str, reason: String },
}
