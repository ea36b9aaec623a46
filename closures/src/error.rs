//! The crate's error type.

/// Everything that can go wrong in `onsager-closures`.
///
/// Misuse (wrong lengths, non-finite input, bad options) and mathematically impossible requests
/// (unrealizable moments, multipliers outside the natural parameter space) are errors; no routine
/// of this crate panics on bad input or returns NaN silently.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The moment vector $\mu$ is not the mean of $M$ under any density of the family: e.g. a
    /// negative variance, or a point outside the convex hull of $M$ over the quadrature grid.
    #[error("moments are not realizable: {reason}")]
    Unrealizable {
        /// Why the moments were rejected.
        reason: String,
    },
    /// The multipliers $\lambda$ lie outside the natural parameter space: the integral
    /// $\mathcal N(\lambda)$ of `003_d2fc48a470e528fc.txt (II.37)` diverges (e.g. a Gaussian
    /// precision matrix that is not positive definite).
    #[error("multipliers are not normalizable: {reason}")]
    NotNormalizable {
        /// Why the multipliers were rejected.
        reason: String,
    },
    /// A slice had the wrong length.
    #[error("dimension mismatch in `{what}`: expected {expected}, got {got}")]
    DimensionMismatch {
        /// The argument or quantity whose length was wrong.
        what: &'static str,
        /// The expected length.
        expected: usize,
        /// The length received.
        got: usize,
    },
    /// An input contained NaN or an infinity.
    #[error("non-finite value in `{what}`")]
    NonFinite {
        /// The argument holding the non-finite value.
        what: &'static str,
    },
    /// A matrix that must be symmetric positive definite is not.
    #[error("matrix `{what}` is not symmetric positive definite")]
    NotPositiveDefinite {
        /// The matrix concerned.
        what: &'static str,
    },
    /// An option or constructor argument is out of its valid range.
    #[error("invalid option `{name}`: {reason}")]
    InvalidOption {
        /// Name of the option.
        name: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// The family cannot provide this quantity (e.g. moment derivatives of an [`Exponential`]
    /// built from a plain `f64` closure).
    ///
    /// [`Exponential`]: crate::Exponential
    #[error("unsupported: {what}")]
    Unsupported {
        /// What was asked for, and how to get it.
        what: &'static str,
    },
    /// An iterative method stopped at its iteration limit without meeting its tolerance.
    #[error("no convergence after {iterations} iterations (residual {residual:e})")]
    NoConvergence {
        /// Iterations performed.
        iterations: usize,
        /// Final residual (method specific; documented where the error is returned).
        residual: f64,
    },
}

/// Checks that `x` has length `expected`.
pub(crate) fn check_len<T>(what: &'static str, x: &[T], expected: usize) -> Result<(), Error> {
    if x.len() == expected {
        Ok(())
    } else {
        Err(Error::DimensionMismatch { what, expected, got: x.len() })
    }
}

/// Checks that every entry of `x` is finite.
pub(crate) fn check_finite(what: &'static str, x: &[f64]) -> Result<(), Error> {
    if x.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(Error::NonFinite { what })
    }
}
