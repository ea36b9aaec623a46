//! Trial-density families for Rayleigh–Ritz moment closures: the Ansätze of Eyink's
//! exponential-family closures, their cumulant algebra, and the quadrature that evaluates them.
//!
//! This crate knows nothing of SDE models. It provides families of densities
//! (`003_d2fc48a470e528fc.txt (II.36)`–(II.37))
//! $$p(x;\lambda) = \frac{e^{\lambda^\top M(x)}}{\mathcal N(\lambda)} p_{\ast}(x),\qquad
//!   \mathcal N(\lambda) = \int e^{\lambda^\top M(x)}p_{\ast}(x) dx,$$
//! with moment functions $M = (M_1,\dots,M_R)$ and reference density $p_{\ast}$, and the
//! quantities a closure needs:
//!
//! - the log-partition (cumulant-generating) function $F(\lambda) = \log\mathcal N(\lambda)$
//!   (II.38), the mean $\mu = \nabla F$, the covariance $C = \nabla^2F = \partial\mu/\partial\lambda$
//!   and the third cumulant $C_{abc} = \partial C_{ab}/\partial\lambda_c$, which gives
//!   $\partial C_{aj}/\partial\mu_i = C_{ajk}\Gamma_{ki}$ with $\Gamma = C^{-1}$ (II.42)–(II.43);
//! - the Legendre transform, the relative entropy
//!   $H(\mu) = \max_\lambda\lbrace \mu^\top\lambda - F(\lambda)\rbrace$ (II.39), and its maximiser, the
//!   inverse map $\lambda(\mu) = \partial H/\partial\mu$, by a damped Newton method
//!   ([`legendre_newton`]) that reports unrealizable $\mu$ as an error;
//! - expectations $\langle g\rangle_\lambda$ of caller-supplied functions through each family's
//!   quadrature nodes and weights ([`TrialFamily::quadrature`],
//!   [`TrialFamily::expectation`]), e.g. of a drift $f$ to form the closure's generator
//!   average $\langle f\cdot\nabla M + D:\nabla\nabla M\rangle_\lambda$, with the derivatives
//!   of $M$ from [`TrialFamily::moment_derivatives`] (closed forms, or hyper-dual numbers for
//!   moment functions written once over the scalar, [`MomentFunctions`]).
//!
//! # Families
//!
//! - [`Gaussian`] on $\mathbb R^n$: $M(x) = (x_i,\ x_ix_j\ (i\le j))$, $p_{\ast} = 1$,
//!   $$F(\lambda) = \tfrac12a^\top P^{-1}a + \tfrac12\log\det(2\pi P^{-1}),\qquad
//!   H(\mu) = -\tfrac12\log\det(2\pi e\Sigma),$$
//!   where $\lambda = (a, b)$, $P_{ii} = -2b_{ii}$, $P_{ij} = -b_{ij}$, $\Sigma = P^{-1}$,
//!   $m = \Sigma a$. All conversions between $(m, \Sigma)$, $\lambda$ and $\mu$ are closed
//!   forms, and [`Gaussian::nodes`] places Gauss–Hermite or cubature nodes at $m + L\xi_k$
//!   ($\Sigma = LL^\top$), generic over the dual-number [`Scalar`] so that callers can
//!   differentiate through them.
//! - [`Exponential`] with user moment functions and reference density on a fixed 1-D or 2-D
//!   grid of Gauss–Legendre panels ([`panel_grid`]):
//!   $F(\lambda) = \log\sum_kw_kp_{\ast}(x_k)e^{\lambda^\top M(x_k)}$, evaluated by log-sum-exp so
//!   that large $|\lambda|$ never overflows. [`Exponential::polynomial`] and
//!   [`Exponential::quartic`] (the double-well family $M = (x, x^2, x^3, x^4)$) are ready made.
//!
//! Both implement [`TrialFamily`], which is object safe.
//!
//! # Quadrature
//!
//! The [`quadrature`] module computes Gauss–Hermite and Gauss–Legendre rules (Golub–Welsch with
//! Newton polishing on the three-term recurrence), composite and tensor-product rules, and the
//! degree-3 and degree-5 cubature rules for the standard normal.
//!
//! # Example
//!
//! ```
//! use onsager_closures::{Exponential, LegendreOptions, TrialFamily};
//!
//! let family = Exponential::quartic(-4.0, 4.0)?;
//! let lambda = [0.0, 2.0, 0.0, -1.0]; // a symmetric double well
//! let mu = family.mean(&lambda)?;
//! let back = family.legendre(&mu, &LegendreOptions::default())?;
//! assert!((back.lambda[1] - 2.0).abs() < 1e-9);
//! # Ok::<(), onsager_closures::Error>(())
//! ```
//!
//! # Errors
//!
//! Every fallible routine returns [`Error`]; nothing panics on bad input and no NaN is returned
//! silently.

#![warn(missing_docs)]
// No function over 150 lines (clippy.toml); CI denies the warning.
#![warn(clippy::too_many_lines)]

mod error;
mod exponential;
mod family;
mod gaussian;
pub mod quadrature;
mod scalar;
pub mod weights;

pub use error::Error;
pub use exponential::{
    frame_grid, panel_grid, Exponential, LogDensityFn, MomentDerivativeFn, MomentFn, MomentFunctions,
    Polynomial, Reference,
};
pub use family::{legendre_newton, Cumulants, LegendreOptions, LegendreSolution, TrialFamily};
pub use gaussian::{Gaussian, GaussianRule};
pub use quadrature::Rule;
pub use scalar::{
    cholesky, cholesky_into, cholesky_inverse, cholesky_inverse_into, cholesky_log_det, cholesky_solve,
    cholesky_solve_in_place, cholesky_solve_rows_in_place, dot, Scalar,
};
pub use weights::{normalize_log_weights, normalize_log_weights_from_max, NEGLIGIBLE_LOG_WEIGHT};
