//! The effective action of Eyink (`003_d2fc48a470e528fc.txt`): exact estimators on a grid and
//! the dual machinery shared with the Rayleigh–Ritz closures.
//!
//! - [`grid`] and [`fokker_planck`]: the forward (Fokker–Planck) and backward (Kolmogorov)
//!   equations on a 1-D or 2-D grid, conservative and positivity preserving, the backward step
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
//! - [`closure`]: the Rayleigh–Ritz closures (Gaussian, exponential family) with their jump
//!   conditions (`(II.36)–(II.53)`, `(A.30)`) on the same [`dual::EffectiveAction`] interface,
//!   and [`closure::closure_estimate`].
//!
//! See `docs/effective-action.md` and `docs/closures.md` for the theory.

pub mod closure;
pub mod dispersion;
pub mod dual;
pub mod exact;
pub mod fokker_planck;
pub mod grid;

pub use closure::{closure_estimate, ClosureAction, ClosureKind, ClosureOptions};
pub use dual::{
    maximize_dual, maximize_dual_chord, DualData, DualOptions, DualSolution, EffectiveAction, History,
};
pub use exact::{
    ksp_smoother, mean_optimal, ExactAction, ExactGrid, ExactOptions, KspSmoothing, MeanOptimal,
};
pub use grid::{Grid, GridSpec};

use serde_json::{json, Map};

use crate::data::StatePath;
use crate::estimate::{EstimationProblem, PathEstimate, Status};
use crate::model::{Observation, Sde};

fn base_estimate<S: Sde + ?Sized, O: Observation + ?Sized>(
    method: &str,
    problem: &EstimationProblem<'_, S, O>,
    path: StatePath,
) -> PathEstimate {
    PathEstimate {
        method: method.into(),
        path,
        theta_names: problem.sde.param_names(),
        theta: problem.theta.to_vec(),
        estimated: Vec::new(),
        theta_sd: None,
        status: Status::Converged,
        iterations: 0,
        solve_seconds: 0.0,
        details: Map::new(),
    }
}

/// The KSP result as the common [`PathEstimate`] (method `ksp`): the smoothed mean and sd at
/// the output times; details: the log marginal likelihood and the number of output times.
pub fn ksp_path_estimate<S: Sde + ?Sized, O: Observation + ?Sized>(
    problem: &EstimationProblem<'_, S, O>,
    ksp: &KspSmoothing,
) -> PathEstimate {
    let path = StatePath {
        names: problem.sde.state_names(),
        times: ksp.times.clone(),
        values: ksp.smoothed_mean.clone(),
        sd: Some(ksp.smoothed_sd.clone()),
    };
    let mut est = base_estimate("ksp", problem, path);
    est.solve_seconds = ksp.solve_seconds;
    est.details.insert("log_likelihood".into(), json!(ksp.log_likelihood));
    est.details.insert("output_times".into(), json!(ksp.times.len()));
    est
}

/// The mean-optimal result as the common [`PathEstimate`] (method `mean-optimal`): the history
/// z(t) and the ensemble dispersion at the output times; details: λ*, z* at the measurement
/// times, the optimality residual, F(λ*), Φ(λ*), sweeps.
pub fn mean_optimal_path_estimate<S: Sde + ?Sized, O: Observation + ?Sized>(
    problem: &EstimationProblem<'_, S, O>,
    mo: &MeanOptimal,
) -> PathEstimate {
    let path = StatePath {
        names: problem.sde.state_names(),
        times: mo.history.times.clone(),
        values: mo.history.mean.clone(),
        sd: Some(mo.sd.clone()),
    };
    let mut est = base_estimate("mean-optimal", problem, path);
    est.status = mo.dual.status;
    est.iterations = mo.dual.iterations;
    est.solve_seconds = mo.solve_seconds;
    let finite =
        |v: &[f64]| v.iter().map(|x| if x.is_finite() { json!(x) } else { json!(null) }).collect::<Vec<_>>();
    est.details.insert("lambda".into(), json!(finite(&mo.dual.lambda)));
    est.details.insert("z_at_measurements".into(), json!(finite(&mo.dual.z)));
    est.details.insert("optimality_residual".into(), json!(finite(&[mo.dual.residual])[0]));
    est.details.insert("f_value".into(), json!(finite(&[mo.dual.f_value])[0]));
    est.details.insert("phi".into(), json!(finite(&[mo.dual.phi])[0]));
    if let Some(reason) = &mo.dual.reason {
        est.details.insert("dual_reason".into(), json!(reason));
    }
    est.details.insert("sweeps".into(), json!(mo.dual.evaluations));
    est
}
