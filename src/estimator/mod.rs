//! Every estimator as a value: a [`Method`] (its name) with its typed options, the
//! [`Estimator`]. The command line, `onsager compare`, the experiment specs and the JSON form
//! (for other languages) all build the same value, and [`Estimator::run`] is the one way in:
//!
//! ```
//! use onsager::estimator::{Estimator, Method};
//! use onsager::model::library::preset;
//! use onsager::simulate::{sample_measurements, simulate, SimulateOptions};
//! use rand::SeedableRng;
//!
//! let p = preset("double-well")?;
//! let mut rng = rand::rngs::StdRng::seed_from_u64(1);
//! let truth = simulate(&p.model, &p.theta, &[1.0], &[], &SimulateOptions::new(0.0, 4.0, 0.01), &mut rng)?;
//! let data = sample_measurements(&p.observation, &p.theta, &truth, 1, 0.5, &mut rng)?;
//! let problem = p.problem(&data, &[]);
//! // From text, as on the command line; the same options as JSON or TOML.
//! let quartic = Estimator::parse("exp-closure:moments=4")?;
//! let same: Estimator = serde_json::from_str(r#"{"method": "exp-closure", "options": {"moments": 4}}"#).unwrap();
//! assert_eq!(quartic, same);
//! let run = Estimator::new(Method::Uks).run(&problem)?;
//! assert_eq!(run.estimate.method, Method::Uks);
//! # Ok::<(), onsager::Error>(())
//! ```
//!
//! Options are written with the names of the fields of each method's options type (see
//! [`Estimator`]); an unknown option, a value of the wrong type or outside its domain is an
//! [`Error::EstimatorOption`] naming the method, the option and what is allowed.

mod applies;
mod parse;

use std::fmt;
use std::str::FromStr;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Deserializer, Serialize};
use serde_json::{Map, Value};

use crate::action::closure::area::AreaClosure;
use crate::action::closure::om::MomentPathOptions;
use crate::action::closure::{Closure, ExponentialFamily, GaussianFamily};
use crate::action::exact::{ExactOptions, MeanOptimalOptions};
use crate::estimate::{EstimationProblem, MethodRun};
use crate::kalman::{EnksOptions, ExtendedOptions, GaussianKspOptions, KalmanOptions, PemOptions};
use crate::model::observation::StateMeasurement;
use crate::model::Sde;
use crate::particle::ParticleOptions;
use crate::path::MapOptions;
use crate::{Error, Result};

pub use applies::NotApplicable;
pub use parse::{keep_set_parameters, list_from_json, options_from_pairs, parse_list, read_list};

/// What every options type of an estimator provides: defaults, serde (the field names are the
/// option names), a check of the values that names the field and the bad value, and the run.
pub trait EstimatorOptions: Serialize + DeserializeOwned + Default + Clone + fmt::Debug + PartialEq {
    /// Checks every value against its domain. Errors: [`Error::InvalidOption`] with the
    /// option's name and the value.
    fn validate(&self) -> Result<()>;

    /// Runs the estimator `method` (one of those these are the options of) on `problem`.
    ///
    /// Errors: those of the method (bad input); a numerical failure is the estimate's status.
    fn run<S: Sde + ?Sized>(
        &self,
        method: Method,
        problem: &EstimationProblem<'_, S, StateMeasurement>,
    ) -> Result<MethodRun>;
}

/// The estimators, one line each: variant, command-line name, options type, description. This
/// table is the registration of an estimator (docs/extending.md).
macro_rules! estimators {
    ($($(#[$doc:meta])* $variant:ident, $name:literal, $options:ty, $description:literal;)*) => {
        /// The estimators of the library by name (the `method` of every front door).
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
        #[serde(rename_all = "kebab-case")]
        #[non_exhaustive]
        pub enum Method {
            $($(#[$doc])* $variant,)*
        }

        impl Method {
            /// Every method, in the order of the tables.
            pub const ALL: &'static [Method] = &[$(Method::$variant),*];

            /// The command-line name (also the `method` of reports and tables).
            pub fn name(self) -> &'static str {
                match self {
                    $(Method::$variant => $name,)*
                }
            }

            /// One line describing the method.
            pub fn description(self) -> &'static str {
                match self {
                    $(Method::$variant => $description,)*
                }
            }
        }

        /// An estimator: a method with its typed options. Serialised as
        /// `{"method": "exp-closure", "options": {"moments": 6}}` (TOML:
        /// `method = "exp-closure"` and `options = { moments = 6 }`); every option has a
        /// default, so `options` may be left out.
        #[derive(Debug, Clone, PartialEq, Serialize)]
        #[serde(tag = "method", content = "options", rename_all = "kebab-case")]
        #[non_exhaustive]
        pub enum Estimator {
            $($(#[$doc])* $variant($options),)*
        }

        impl Estimator {
            /// The estimator `method` with its default options.
            pub fn new(method: Method) -> Estimator {
                match method {
                    $(Method::$variant => Estimator::$variant(<$options>::default()),)*
                }
            }

            /// Its method.
            pub fn method(&self) -> Method {
                match self {
                    $(Estimator::$variant(_) => Method::$variant,)*
                }
            }

            /// The estimator `method` with `options` (option name → value, as in JSON). Errors:
            /// [`Error::EstimatorOption`] for an option `method` does not have (naming its
            /// options), a value of the wrong type or outside its domain.
            pub fn from_options(method: Method, options: &Map<String, Value>) -> Result<Estimator> {
                Ok(match method {
                    $(Method::$variant => Estimator::$variant(parse::typed::<$options>(method, options)?),)*
                })
            }

            /// The names of the options of `method`.
            pub fn option_names(method: Method) -> Vec<String> {
                match method {
                    $(Method::$variant => parse::option_names::<$options>(),)*
                }
            }

            /// Checks the options' values (as [`Estimator::from_options`] does).
            pub fn validate(&self) -> Result<()> {
                let method = self.method();
                match self {
                    $(Estimator::$variant(o) => o.validate().map_err(|e| parse::named(method, e)),)*
                }
            }

            /// Runs the estimator's options type on `problem` (after [`Estimator::run`]'s
            /// checks).
            fn dispatch<S: Sde + ?Sized>(&self, problem: &EstimationProblem<'_, S, StateMeasurement>) -> Result<MethodRun> {
                match self {
                    $(Estimator::$variant(o) => o.run(Method::$variant, problem),)*
                }
            }

            /// The options as a JSON object (every option, defaults included).
            pub fn options_json(&self) -> Map<String, Value> {
                let value = match self {
                    $(Estimator::$variant(o) => serde_json::to_value(o),)*
                };
                match value {
                    Ok(Value::Object(map)) => map,
                    _ => Map::new(),
                }
            }
        }
    };
}

estimators! {
    /// Exact Kushner–Stratonovich–Pardoux smoother on a grid (`003_d2fc48a470e528fc.txt (0.3)–(0.7)`).
    Ksp, "ksp", ExactOptions,
        "exact Kushner-Stratonovich-Pardoux smoother on a grid (003 eq. 0.3-0.7)";
    /// Exact mean-optimal (effective-action) estimator on a grid (`003 (I.60)–(I.76)`).
    MeanOptimal, "mean-optimal", MeanOptimalOptions,
        "exact mean-optimal (effective-action) estimator on a grid (003 I.60-I.76)";
    /// Gaussian Rayleigh–Ritz closure of the mean-optimal estimator (`003 (II.36)–(II.53)`).
    GaussianClosure, "gaussian-closure", Closure<GaussianFamily>,
        "Gaussian Rayleigh-Ritz closure of the mean-optimal estimator (003 II.36-II.53)";
    /// Exponential-family closure with the polynomial moments of total degree `moments`
    /// (`003 (II.36)–(II.53)`).
    ExpClosure, "exp-closure", Closure<ExponentialFamily>,
        "exponential-family closure, polynomial moments up to degree `moments`, 1-D to 3-D (003 II.36-II.53)";
    /// Scalar area-rule closure: one state, one moment M = x, one measured output
    /// (`003 (II.17)–(II.35)`).
    AreaClosure, "area-closure", AreaClosure,
        "scalar area-rule closure: one state, the tilt exp(theta x) of the stationary density, one measured output (003 II.17-II.35)";
    /// Closure of the KSP smoother (`003 (II.64)–(II.65)`).
    KspClosure, "ksp-closure", MomentPathOptions,
        "closure of the KSP smoother (003 II.64-II.65)";
    /// Gaussian closure of the KSP smoother in any number of states: moment equations by
    /// Gauss–Hermite or cubature rules, the Gaussian Bayes update at the measurements and the
    /// RTS backward pass (`003 (I.80)–(I.84)`, `(II.64)–(II.65)`;
    /// [`crate::kalman::gaussian_ksp()`]).
    GaussianKspClosure, "gaussian-ksp-closure", GaussianKspOptions,
        "Gaussian closure of the KSP smoother in n states: moment ODEs by Gauss-Hermite/cubature, Bayes jumps, RTS (003 I.80-I.84, II.64-II.65)";
    /// Double-exponential closure (`003 (II.54)–(II.63)`).
    DoubleExpClosure, "double-exp-closure", MomentPathOptions,
        "double-exponential closure (003 II.54-II.63)";
    /// Joint Onsager–Machlup MAP path and parameters (`000_74b95e149527c64e.txt (2.49)–(2.51)`).
    Jme, "jme", MapOptions,
        "joint Onsager-Machlup MAP path and parameters (000 eq. 2.49-2.51)";
    /// Minimum-energy path and parameters (`000 (2.58)–(2.60)`).
    Mee, "mee", MapOptions,
        "minimum-energy path and parameters (000 eq. 2.58-2.60)";
    /// Continuous-discrete extended Kalman filter.
    Ekf, "ekf", ExtendedOptions,
        "continuous-discrete extended Kalman filter";
    /// Extended Rauch–Tung–Striebel smoother.
    Eks, "eks", ExtendedOptions,
        "extended Rauch-Tung-Striebel smoother";
    /// Continuous-discrete unscented Kalman filter.
    Ukf, "ukf", KalmanOptions,
        "continuous-discrete unscented Kalman filter";
    /// Unscented Rauch–Tung–Striebel smoother.
    Uks, "uks", KalmanOptions,
        "unscented Rauch-Tung-Striebel smoother";
    /// Prediction error method (UKF likelihood) followed by the UKS at θ̂.
    Pem, "pem", PemOptions,
        "prediction error method (UKF likelihood), then the UKS at the estimate";
    /// Bootstrap particle filter with a backward-simulation smoother.
    Particle, "particle", ParticleOptions,
        "bootstrap particle filter with a backward-simulation smoother";
    /// Ensemble Kalman smoother: stochastic EnKF with perturbed observations and the smoother
    /// of Evensen & van Leeuwen (2000) ([`crate::kalman::enks()`]).
    Enks, "enks", EnksOptions,
        "ensemble Kalman smoother (stochastic EnKF with perturbed observations, Evensen & van Leeuwen 2000)";
    /// Ensemble Kalman filter: the filtered part of `enks` ([`crate::kalman::enks()`] without the
    /// smoother's updates).
    Enkf, "enkf", EnksOptions,
        "ensemble Kalman filter (stochastic, perturbed observations; Evensen 2003)";
}

impl Method {
    /// Whether the method estimates parameters (the problem's `estimate`); the others take θ
    /// as given.
    pub fn estimates_parameters(self) -> bool {
        matches!(self, Method::Jme | Method::Mee | Method::Pem)
    }

    /// Whether the method iterates to a tolerance (an NLP, a dual maximisation or BFGS), so
    /// that [`IterationLimits`] apply to it; the filters, smoothers and the exact KSP smoother
    /// run a fixed number of steps.
    pub fn iterates(self) -> bool {
        matches!(
            self,
            Method::Jme
                | Method::Mee
                | Method::Pem
                | Method::MeanOptimal
                | Method::GaussianClosure
                | Method::ExpClosure
                | Method::AreaClosure
                | Method::KspClosure
                | Method::DoubleExpClosure
        )
    }

    /// Whether the method is one of the exact grid methods (one to three states).
    pub fn uses_grid(self) -> bool {
        matches!(self, Method::Ksp | Method::MeanOptimal)
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Method {
    type Err = Error;

    fn from_str(s: &str) -> Result<Method> {
        Method::ALL.iter().copied().find(|m| m.name() == s.trim()).ok_or_else(|| Error::UnknownName {
            kind: "method".into(),
            name: s.trim().into(),
            known: Method::ALL.iter().map(|m| m.name().to_string()).collect(),
        })
    }
}

impl Estimator {
    /// The command-line name of its method.
    pub fn name(&self) -> &'static str {
        self.method().name()
    }

    /// Parses the text form `METHOD` or `METHOD:NAME=VALUE,NAME=VALUE…` (nested options with
    /// dotted names, `dual.max_iterations=100`; a value with commas in double quotes). Errors:
    /// an unknown method; [`Error::EstimatorOption`] for a bad option.
    pub fn parse(text: &str) -> Result<Estimator> {
        let mut list = parse_list(text)?;
        match (list.len(), list.pop()) {
            (1, Some(one)) => Ok(one.estimator),
            _ => Err(Error::InvalidOption {
                name: "method".into(),
                reason: format!("`{text}` is not one estimator"),
            }),
        }
    }

    /// Runs the estimator on `problem`.
    ///
    /// Errors: bad options (as [`Estimator::validate`]); parameters to estimate for a method
    /// that takes θ as given; those of the method (a grid that does not cover the data, a
    /// non-Gaussian likelihood for the mean-optimal estimator and the closures, …). A numerical
    /// failure is not an error: it is the estimate's status. An estimate whose path or θ is not
    /// finite (a model that returned NaN or ∞ on the way) never has a successful status: it is
    /// reported as [`Status::EvaluationError`](crate::status::Status::EvaluationError), with a
    /// note.
    pub fn run<S: Sde + ?Sized>(
        &self,
        problem: &EstimationProblem<'_, S, StateMeasurement>,
    ) -> Result<MethodRun> {
        self.validate()?;
        let method = self.method();
        if !problem.estimate.is_empty() && !method.estimates_parameters() {
            return Err(Error::InvalidOption {
                name: "estimate".into(),
                reason: format!("`{method}` takes the parameters as given; jme, mee and pem estimate them"),
            });
        }
        let mut run = self.dispatch(problem)?;
        let e = &mut run.estimate;
        let finite = e.path.values.iter().flatten().chain(&e.theta).all(|v| v.is_finite());
        if e.status.is_success() && !finite {
            e.status = crate::status::Status::EvaluationError;
            run.notes.push(format!(
                "`{method}` ended as converged, but its path or parameters are not finite (the model \
                 returned NaN or infinity): reported as {}",
                e.status
            ));
        }
        Ok(run)
    }
}

/// An iteration limit and a convergence tolerance for any iterating estimator (the command
/// line's `--max-iterations` and `--tolerance`), mapped by [`Estimator::with_limits`] onto the
/// method's own options: the interior-point solver's `max_iterations` and `tolerance` (`jme`,
/// `mee`, `ksp-closure`, `double-exp-closure`), the dual's `dual.max_iterations` and
/// `dual.tolerance` (`gaussian-closure`, `exp-closure`, `mean-optimal`), BFGS's
/// `max_iterations` and `gradient_tolerance` (`pem`). Each tolerance is the method's own
/// measure (docs/reports.md). Methods that do not iterate ([`Method::iterates`]) ignore them.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct IterationLimits {
    /// The iteration limit (at least 1); `None` keeps the method's.
    pub max_iterations: Option<usize>,
    /// The convergence tolerance (positive); `None` keeps the method's.
    pub tolerance: Option<f64>,
}

impl IterationLimits {
    /// Whether neither limit is set.
    pub fn is_empty(&self) -> bool {
        self.max_iterations.is_none() && self.tolerance.is_none()
    }
}

impl Estimator {
    /// The estimator with `limits` written into its options (see [`IterationLimits`]); an
    /// estimator that does not iterate is returned unchanged. Errors:
    /// [`Error::InvalidOption`] naming `max_iterations` (0) or `tolerance` (not positive and
    /// finite).
    pub fn with_limits(mut self, limits: IterationLimits) -> Result<Estimator> {
        if limits.max_iterations == Some(0) {
            return Err(Error::invalid("max_iterations", "must be at least 1, got 0"));
        }
        crate::error::check_positive("tolerance", limits.tolerance)?;
        let set = |n: &mut usize, tol: &mut f64| {
            *n = limits.max_iterations.unwrap_or(*n);
            *tol = limits.tolerance.unwrap_or(*tol);
        };
        match &mut self {
            Estimator::Jme(o) | Estimator::Mee(o) => {
                o.max_iterations = limits.max_iterations.or(o.max_iterations);
                o.tolerance = limits.tolerance.or(o.tolerance);
            }
            Estimator::Pem(o) => set(&mut o.max_iterations, &mut o.gradient_tolerance),
            Estimator::MeanOptimal(o) => set(&mut o.dual.max_iterations, &mut o.dual.tolerance),
            Estimator::GaussianClosure(o) => {
                set(&mut o.options.dual.max_iterations, &mut o.options.dual.tolerance)
            }
            Estimator::ExpClosure(o) => {
                set(&mut o.options.dual.max_iterations, &mut o.options.dual.tolerance)
            }
            Estimator::AreaClosure(o) => set(&mut o.dual.max_iterations, &mut o.dual.tolerance),
            Estimator::KspClosure(o) | Estimator::DoubleExpClosure(o) => {
                set(&mut o.max_iterations, &mut o.tolerance)
            }
            _ => {}
        }
        Ok(self)
    }

    /// The estimator with `grid` as the grid of an exact grid method ([`Method::uses_grid`]) that
    /// has none of its own; any other estimator, or one with its own grid, is returned unchanged.
    pub fn with_default_grid(mut self, grid: &crate::action::grid::GridSpec) -> Estimator {
        match &mut self {
            Estimator::Ksp(o) if o.grid.is_none() => o.grid = Some(grid.clone()),
            Estimator::MeanOptimal(o) if o.exact.grid.is_none() => o.exact.grid = Some(grid.clone()),
            _ => {}
        }
        self
    }

    /// Runs the estimator as [`Estimator::run`], with `observer` receiving its progress
    /// ([`crate::estimate::progress`]).
    pub fn run_observed<S: Sde + ?Sized>(
        &self,
        problem: &EstimationProblem<'_, S, StateMeasurement>,
        observer: crate::estimate::progress::Observer,
    ) -> Result<MethodRun> {
        crate::estimate::progress::observe(observer, || self.run(problem))
    }
}

/// The JSON form without options.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Written {
    method: Method,
    #[serde(default)]
    options: Map<String, Value>,
}

impl<'de> Deserialize<'de> for Estimator {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> std::result::Result<Self, D::Error> {
        let w = Written::deserialize(deserializer)?;
        Estimator::from_options(w.method, &w.options).map_err(serde::de::Error::custom)
    }
}

/// An estimator with the label of its results (a row of `compare`, a column of an
/// experiment): by default the method's name.
#[derive(Debug, Clone, PartialEq)]
pub struct Labelled {
    /// The label.
    pub label: String,
    /// The estimator.
    pub estimator: Estimator,
}

impl Labelled {
    /// `estimator` labelled with its method's name.
    pub fn new(estimator: Estimator) -> Labelled {
        Labelled { label: estimator.name().to_string(), estimator }
    }
}

#[cfg(test)]
mod tests;
