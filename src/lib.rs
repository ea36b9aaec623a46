//! # onsager
//!
//! State-path and parameter estimation for nonlinear stochastic differential equations
//! observed at discrete times, comparing two theories of "the best path" on equal terms.
//!
//! ## The estimation problem
//!
//! The state has noisy components X and clean components Z
//! (`000_74b95e149527c64e.txt (2.4)`):
//!
//! $$ dX_t = f(t, X_t, Z_t, \theta)\,dt + G(\theta)\,dW_t, \qquad dZ_t = h(t, X_t, Z_t, \theta)\,dt, $$
//!
//! with priors on $X_0$, $Z_0$ and $\theta$, measured at times $t_k$ through a likelihood
//! $\psi(y_k \mid X_{t_k}, Z_{t_k}, \theta)$. The library estimates the path $t \mapsto (X_t, Z_t)$
//! and $\theta$ from $y_0, \dots, y_N$:
//!
//! - **path-space MAP** (Dutra): the maximiser of the Onsager–Machlup posterior
//!   $\ln\pi(x_0, z_0, \theta) + \sum_k \ln\psi(y_k \mid \cdot) - \int \big(\tfrac12 |G^{-1}(\dot x - f)|^2 +
//!   \tfrac12 \operatorname{div}_x f\big) \, dt$ (`000_74b95e149527c64e.txt (2.49)`), and the
//!   minimum-energy path without the divergence term (`(2.60)`);
//! - **effective action** (Eyink): the mean-optimal estimator and its Rayleigh–Ritz closures
//!   (`003_d2fc48a470e528fc.txt`).
//!
//! ## Where things are
//!
//! - [`model`]: the [`model::Sde`] trait (models written once, generic over the scalar, with
//!   every derivative by automatic differentiation), measurement models
//!   ([`model::Observation`], [`model::observation::Noise`]), priors ([`model::prior`]), special
//!   functions usable with dual numbers ([`model::special`]) and the built-in models
//!   ([`model::library`]).
//! - [`simulate`]: Euler–Maruyama and the strong order 1.5 Itô–Taylor scheme, measurement
//!   sampling.
//! - [`data`]: measurement datasets and state paths with CSV I/O and precise errors.
//! - [`estimate`]: what every estimator takes ([`estimate::EstimationProblem`]) and returns
//!   ([`estimate::PathEstimate`]), so that methods compare on equal terms.
//! - [`path`]: the path-space MAP estimators (Onsager–Machlup and minimum-energy paths by Euler,
//!   trapezoidal and Hermite–Simpson transcriptions, joint with parameters), solved by [`nlp`],
//!   a sparse primal–dual interior-point solver; [`spline`] gives their initial guesses.
//! - [`action`]: Eyink's effective action on a grid — the exact KSP smoother, the mean-optimal
//!   estimator through its concave dual, and the ensemble dispersion; [`closures`] holds the
//!   trial densities of the Rayleigh–Ritz closures.
//! - [`kalman`] and [`particle`]: the baselines (EKF/EKS, UKF/UKS, the prediction error method,
//!   the ensemble Kalman smoother, a bootstrap particle filter with a backward-simulation
//!   smoother), and the exact
//!   Kalman/RTS reference for linear models ([`kalman::linear`]).
//!
//! - [`estimator`]: every estimator as a value — a [`estimator::Method`] with its typed options,
//!   the [`estimator::Estimator`] — built the same way by the CLI, `compare`, the experiment
//!   specs and the JSON form; [`estimator::Estimator::run`] is the one way in.
//!
//! - [`compare`]: several estimators on the same data, measured against each other and the truth.
//! - [`plot`]: SVG/PNG line plots with bands, box plots and panel grids (no system fonts);
//!   [`figures`]: the figures of estimates built on it, with one look per estimator.
//! - [`metrics`]: distances between paths (ISE, RMSE, same-well fraction) for comparisons.
//! - [`test_models`]: the shared test fixtures (models with known answers, seeded data sets) of
//!   the tests, examples and benchmarks.
//!
//! Misuse is an [`Error`]; numerical outcomes are statuses in reports. Randomness is always
//! injected (`&mut impl Rng`). Library code never prints.
// No function over 150 lines (the threshold is in clippy.toml); CI's clippy denies the warning.
#![warn(clippy::too_many_lines)]

pub mod action;
pub mod compare;
pub mod data;
pub mod error;
pub mod estimate;
pub mod estimator;
pub mod experiment;
pub mod figures;
pub mod kalman;
pub mod metrics;
pub mod model;
pub mod nlp;
pub mod particle;
pub mod path;
pub mod plot;
pub mod simulate;
pub mod spline;
pub mod status;
pub mod test_models;

pub use error::{Error, Result};
pub use estimator::{Estimator, Method};
/// The trial-density families of the Rayleigh–Ritz closures (the `onsager-closures` crate).
pub use onsager_closures as closures;
pub use status::Status;
