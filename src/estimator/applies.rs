//! Which estimators apply to a problem: the one rule that `onsager compare` uses to choose its
//! default estimators and to refuse explicit ones, available to every front door.

use std::fmt;

use super::{Estimator, Method};
use crate::action::closure::ExponentialFamily;
use crate::action::exact::{default_grid, MeanOptimalOptions};
use crate::action::grid::MAX_AXES;
use crate::estimate::EstimationProblem;
use crate::model::observation::{Noise, StateMeasurement};
use crate::model::Sde;

/// Why an estimator does not apply to a problem ([`Estimator::applies_to`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NotApplicable {
    /// The estimator's method.
    pub method: Method,
    /// The reason, for a user: what the method needs and what the problem has.
    pub reason: String,
}

impl fmt::Display for NotApplicable {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "`{}` does not apply: {}", self.method, self.reason)
    }
}

impl std::error::Error for NotApplicable {}

/// The methods that need Gaussian measurement errors: the dual of the mean-optimal estimator and
/// its closures (`003_d2fc48a470e528fc.txt (I.52)`), and the Kalman and ensemble methods.
fn needs_gaussian_likelihood(method: Method) -> bool {
    !matches!(method, Method::Ksp | Method::Jme | Method::Mee | Method::Particle)
}

impl Estimator {
    /// Whether the estimator applies to `problem`, judged before it runs from the model's
    /// dimensions, the likelihood, the parameters to estimate and the estimator's options:
    ///
    /// - parameters to estimate: only `jme`, `mee` and `pem` estimate them;
    /// - `ksp`, `mean-optimal`: one to [`MAX_AXES`] (three) states, and a grid (the default grid needs every
    ///   state measured directly);
    /// - `exp-closure`: one to three states (moments up to degree 6 in two, 4 in three);
    ///   `ksp-closure`, `double-exp-closure`: one noisy state;
    ///   `gaussian-closure`, `gaussian-ksp-closure`: any number of states, clean states too;
    ///   `area-closure`: one noisy state and one scalar measured output;
    /// - `pem`: parameters to estimate;
    /// - Gaussian measurement errors for every method except `ksp`, `jme`, `mee` and `particle`.
    ///
    /// An estimator that applies may still refuse a bad option when it runs (an error) or fail
    /// numerically (a status). Errors: the [`NotApplicable`] reason.
    pub fn applies_to<S: Sde + ?Sized>(
        &self,
        problem: &EstimationProblem<'_, S, StateMeasurement>,
    ) -> std::result::Result<(), NotApplicable> {
        let method = self.method();
        let no = |reason: String| Err(NotApplicable { method, reason });
        let dims = problem.sde.dims();
        let n = dims.states();
        if !problem.estimate.is_empty() && !method.estimates_parameters() {
            return no("it takes the parameters as given (jme, mee and pem estimate them)".into());
        }
        if method == Method::Pem && problem.estimate.is_empty() {
            return no("it estimates parameters and none are given to estimate (`--estimate NAME,…`)".into());
        }
        if needs_gaussian_likelihood(method) {
            if let ref other @ (Noise::StudentT { .. }
            | Noise::Mixture { .. }
            | Noise::Quantized { .. }
            | Noise::Laplace { .. }) = problem.observation.noise
            {
                return no(format!(
                    "it needs Gaussian measurement errors, the likelihood is `{}`",
                    other.describe(&problem.sde.param_names())
                ));
            }
        }
        match self {
            Estimator::Ksp(o) | Estimator::MeanOptimal(MeanOptimalOptions { exact: o, .. }) => {
                if !(1..=MAX_AXES).contains(&n) {
                    return no(format!("the grid methods take 1 to {MAX_AXES} states, the model has {n}"));
                }
                if let Some(g) = &o.grid {
                    if g.cells.len() != n {
                        return no(format!("the grid {g} has {} axes, the model {n} states", g.cells.len()));
                    }
                } else {
                    if let Err(e) = default_grid(problem) {
                        let why = match &e {
                            crate::Error::InvalidOption { reason, .. } => {
                                reason.split("; give one").next().unwrap_or(reason).to_string()
                            }
                            other => other.to_string(),
                        };
                        const EXAMPLE: [&str; MAX_AXES] = [
                            "lo=L,hi=H,cells=N",
                            "lo=L1;L2,hi=H1;H2,cells=N1;N2",
                            "lo=L1;L2;L3,hi=H1;H2;H3,cells=N1;N2;N3",
                        ];
                        let example = EXAMPLE[n - 1];
                        return no(format!("{why}; give a grid, `--grid {example}`"));
                    }
                }
            }
            Estimator::ExpClosure(c) => match ExponentialFamily::max_degree(n) {
                None => return no(format!("the exponential closure takes one to three states, the model has {n}")),
                Some(most) if n > 1 && c.family.moments > most => {
                    return no(format!(
                        "in {n} states the exponential closure takes moments up to degree {most}, not {}",
                        c.family.moments
                    ))
                }
                Some(_) => {}
            },
            Estimator::AreaClosure(_) if n != 1 || dims.noisy != 1 => {
                return no(format!("it takes one-state noisy models (one moment variable), the model has {n} states"))
            }
            Estimator::AreaClosure(_) if problem.observation.states.len() != 1 => {
                return no(format!(
                    "it takes one scalar measured output (the area rules, 003 II.19-II.23), the measurement has {}",
                    problem.observation.states.len()
                ))
            }
            Estimator::KspClosure(_) | Estimator::DoubleExpClosure(_) if n != 1 || dims.noisy != 1 => {
                return no(format!("it takes one-state noisy models, the model has {n} states"))
            }
            _ => {}
        }
        Ok(())
    }
}
