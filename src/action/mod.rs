//! The effective action of Eyink (`003_d2fc48a470e528fc.txt`): exact estimators on a grid and
//! the dual machinery shared with the Rayleigh–Ritz closures.
//!
//! - [`grid`] and [`fokker_planck`]: the forward (Fokker–Planck) and backward (Kolmogorov)
//!   equations on a 1-D, 2-D or 3-D grid, conservative and positivity preserving, the backward step
//!   being the exact transpose of the forward step (`(0.4)`, `(I.16)–(I.17)`).
//! - [`exact`]: the sweeps with jump conditions; the KSP smoother ([`exact::ksp_smoother`],
//!   `(0.3)–(0.7)`, `(I.80)–(I.84)`, Appendix 1) with any likelihood, and the exact effective
//!   action ([`exact::ExactAction`], `(I.61)–(I.76)`) with the mean-optimal estimator
//!   ([`exact::mean_optimal`]).
//! - [`dual`]: the [`dual::EffectiveAction`] trait (F, ∇F by the adjoint sweep, the history
//!   z(t)) and the dual maximisation [`dual::maximize_dual`] (`(I.57)–(I.60)`), written once
//!   for the exact grid and every closure.
//! - [`dispersion`]: the ensemble dispersion from ((∇²F)⁻¹ + R⁻¹)⁻¹ (`(I.85)–(I.90)`) and by the
//!   Lagrange-multiplier finite difference (`(I.99)–(I.106)`).
//!
//! - [`mean_optimal`](mod@mean_optimal): the mean-optimal estimator of any [`dual::EffectiveAction`] — start,
//!   dual (in two stages for adaptive sweeps), history and dispersion — written once for the
//!   exact grid and every closure.
//! - [`continuation`]: which stationary point of a non-concave dual is the estimate — the
//!   branch from the prior, followed in the measurement precision.
//! - [`closure`]: the Rayleigh–Ritz closures (Gaussian, exponential family) with their jump
//!   conditions (`(II.36)–(II.53)`, `(A.30)`) on the same [`dual::EffectiveAction`] interface,
//!   and [`closure::closure_estimate`].
//!
//! See `docs/effective-action.md` and `docs/closures.md` for the theory.

pub mod closure;
pub mod continuation;
pub mod dispersion;
pub mod dual;
pub mod exact;
pub mod fokker_planck;
pub mod grid;
pub mod mean_optimal;

pub use closure::{
    closure_estimate, Closure, ClosureAction, ClosureFamily, ClosureOptions, ExponentialFamily,
    GaussianFamily, NodeRule,
};
pub use continuation::{Branch, BranchEnd, BranchRule};
pub use dual::{
    maximize_dual, maximize_dual_chord, DualData, DualOptions, DualSolution, DualStop, EffectiveAction,
    History, SweepFailure, Swept, Work,
};
pub use exact::{
    default_grid, ksp_estimate, ksp_path_estimate, ksp_smoother, mean_optimal, mean_optimal_estimate,
    mean_optimal_path_estimate, ExactAction, ExactGrid, ExactOptions, KspSmoothing, MeanOptimal,
    MeanOptimalOptions,
};
pub use fokker_planck::TimeScheme;
pub use grid::{Grid, GridSpec};
pub use mean_optimal::{DualDetails, DualStart, SdKind};
