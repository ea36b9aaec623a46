//! Several estimators on the same model and data, side by side: the library side of
//! `onsager compare`.
//!
//! [`compare`] runs each method through [`crate::methods::run`] (so on equal terms with the CLI
//! and the experiments), keeps going when one fails (its row carries the error), and measures
//! each estimate against the truth (when known), the exact KSP smoothed mean and the exact
//! mean-optimal estimate (when they are among the methods), with [`crate::metrics`].

use serde_json::{json, Value};

use crate::data::{Dataset, StatePath};
use crate::estimate::{EstimationProblem, PathEstimate};
use crate::methods::{self, Method, MethodOptions};
use crate::metrics;
use crate::model::observation::StateMeasurement;
use crate::model::Sde;
use crate::plot::{LinePlot, Panels, Series};
use crate::Result;

/// Options of [`compare`].
#[derive(Debug, Clone, PartialEq, Default)]
#[non_exhaustive]
pub struct CompareOptions {
    /// Grid of the exact methods (default: [`methods::default_grid`]).
    pub grid: Option<String>,
    /// Seed of the methods that draw random numbers.
    pub seed: u64,
    /// For bistable models: the barrier between the wells of the first state (0 for the double
    /// well); the table then reports the fraction of times on the true well's side.
    pub barrier: Option<f64>,
}

/// One method's line of the comparison.
#[derive(Debug, Clone, PartialEq)]
pub struct CompareRow {
    /// The method.
    pub method: Method,
    /// The status name (`converged`, …), or `error` when the method could not run.
    pub status: String,
    /// The error message, when the method could not run.
    pub error: Option<String>,
    /// RMSE against the truth over the truth's times (all states).
    pub rmse_truth: Option<f64>,
    /// RMSE against the exact KSP smoothed mean over its output times.
    pub rmse_ksp: Option<f64>,
    /// RMSE against the exact mean-optimal estimate over its output times.
    pub rmse_mean_optimal: Option<f64>,
    /// Fraction of the truth's times at which the first state is on the true well's side.
    pub same_well: Option<f64>,
    /// The method's solve time in seconds.
    pub seconds: f64,
    /// The method's notes (see [`methods::MethodRun`]).
    pub notes: Vec<String>,
}

/// The result of [`compare`]: one row and (when it ran) one estimate per method, in order.
#[derive(Debug, Clone)]
pub struct Comparison {
    /// The rows.
    pub rows: Vec<CompareRow>,
    /// The estimates (`None` where the method failed to run).
    pub estimates: Vec<Option<PathEstimate>>,
}

/// The methods compared by default: the exact grid methods where the model has at most two
/// states, the closures where it has one (Gaussian, quartic exponential, double-exponential and
/// KSP; seconds on a 40-measurement record; in 2-D ask for them explicitly), then JME, MEE and
/// the UKS.
pub fn default_methods<S: Sde + ?Sized>(problem: &EstimationProblem<'_, S, StateMeasurement>) -> Vec<Method> {
    let mut m = Vec::new();
    let states = problem.sde.dims().states();
    if states <= 2 {
        m.extend([Method::Ksp, Method::MeanOptimal]);
    }
    if states == 1 {
        m.extend([Method::GaussianClosure, Method::ExpClosure, Method::DoubleExpClosure, Method::KspClosure]);
    }
    m.extend([Method::Jme, Method::Mee, Method::Uks]);
    m
}

/// Runs `methods` on `problem` and measures them (see the [module documentation](self)).
/// A method that fails is a row with status `error` and its message; the comparison goes on.
///
/// Errors: none from the methods; a `truth` whose state names differ from the model's.
pub fn compare<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    methods: &[Method],
    truth: Option<&StatePath>,
    options: &CompareOptions,
) -> Result<Comparison> {
    let names = problem.sde.state_names();
    if let Some(t) = truth {
        if t.names != names {
            return Err(crate::Error::InvalidOption {
                name: "truth".into(),
                reason: format!("has states {} but the model has {}", t.names.join(", "), names.join(", ")),
            });
        }
    }
    let mut rows = Vec::with_capacity(methods.len());
    let mut estimates = Vec::with_capacity(methods.len());
    for &method in methods {
        let mut o = MethodOptions::default();
        if method.uses_grid() {
            o.grid = options.grid.clone();
        }
        o.seed = options.seed;
        match methods::run(method, problem, &o) {
            Ok(run) => {
                rows.push(CompareRow {
                    method,
                    status: run.estimate.status.name().to_string(),
                    error: None,
                    rmse_truth: None,
                    rmse_ksp: None,
                    rmse_mean_optimal: None,
                    same_well: None,
                    seconds: run.estimate.solve_seconds,
                    notes: run.notes,
                });
                estimates.push(Some(run.estimate));
            }
            Err(e) => {
                rows.push(CompareRow {
                    method,
                    status: "error".into(),
                    error: Some(e.to_string()),
                    rmse_truth: None,
                    rmse_ksp: None,
                    rmse_mean_optimal: None,
                    same_well: None,
                    seconds: 0.0,
                    notes: Vec::new(),
                });
                estimates.push(None);
            }
        }
    }
    let reference = |m: Method| -> Option<&PathEstimate> {
        methods
            .iter()
            .position(|&x| x == m)
            .and_then(|i| estimates[i].as_ref())
            .filter(|e| e.status.is_success())
    };
    let ksp = reference(Method::Ksp).map(|e| e.path.clone());
    let mean_optimal = reference(Method::MeanOptimal).map(|e| e.path.clone());
    for (row, est) in rows.iter_mut().zip(&estimates) {
        let Some(est) = est else { continue };
        let path = &est.path;
        if let Some(t) = truth {
            row.rmse_truth = metrics::rmse(path, t, None).ok();
            if let Some(b) = options.barrier {
                row.same_well = metrics::same_side_fraction(path, t, &names[0], b).ok();
            }
        }
        if row.method != Method::Ksp {
            row.rmse_ksp = ksp.as_ref().and_then(|r| metrics::rmse(path, r, None).ok());
        }
        if row.method != Method::MeanOptimal {
            row.rmse_mean_optimal = mean_optimal.as_ref().and_then(|r| metrics::rmse(path, r, None).ok());
        }
    }
    Ok(Comparison { rows, estimates })
}

impl Comparison {
    /// The summary as JSON: one object per method with its status, metrics (null when not
    /// available), seconds, iterations, notes and error.
    pub fn summary_json(&self) -> Value {
        let rows: Vec<Value> = self
            .rows
            .iter()
            .zip(&self.estimates)
            .map(|(r, e)| {
                let finite = |x: Option<f64>| x.filter(|v| v.is_finite());
                json!({
                    "method": r.method.name(),
                    "status": r.status,
                    "error": r.error,
                    "rmse_truth": finite(r.rmse_truth),
                    "rmse_ksp": finite(r.rmse_ksp),
                    "rmse_mean_optimal": finite(r.rmse_mean_optimal),
                    "same_well_fraction": finite(r.same_well),
                    "solve_seconds": r.seconds,
                    "iterations": e.as_ref().map(|e| e.iterations),
                    "notes": r.notes,
                })
            })
            .collect();
        json!({ "methods": rows })
    }

    /// All estimated paths in one long table: `method,t,<states>,sd_<states>` (empty sd where
    /// a method has none).
    pub fn write_paths_csv(&self, path: &std::path::Path, state_names: &[String]) -> Result<()> {
        let io = |source| crate::Error::Io { path: path.to_path_buf(), source };
        let mut w = csv::Writer::from_path(path).map_err(|e| match e.into_kind() {
            csv::ErrorKind::Io(source) => io(source),
            other => io(std::io::Error::other(format!("{other:?}"))),
        })?;
        let mut header = vec!["method".to_string(), "t".to_string()];
        header.extend(state_names.iter().cloned());
        header.extend(state_names.iter().map(|n| format!("sd_{n}")));
        let csv_err = |e: csv::Error| io(std::io::Error::other(e.to_string()));
        w.write_record(&header).map_err(csv_err)?;
        for est in self.estimates.iter().flatten() {
            for (i, &t) in est.path.times.iter().enumerate() {
                let mut rec = vec![est.method.clone(), format!("{t}")];
                rec.extend(est.path.values[i].iter().map(|v| format!("{v}")));
                match &est.path.sd {
                    Some(sd) => rec.extend(sd[i].iter().map(|v| format!("{v}"))),
                    None => rec.extend(state_names.iter().map(|_| String::new())),
                }
                w.write_record(&rec).map_err(csv_err)?;
            }
        }
        w.flush().map_err(io)
    }
}

impl Comparison {
    /// The figure of the comparison: one panel per state with the truth (when given), every
    /// estimate with its ±2 sd band (where it has an sd), and the measurements of that state.
    pub fn figure(
        &self,
        state_names: &[String],
        data: &Dataset,
        observation: &StateMeasurement,
        truth: Option<&StatePath>,
        title: &str,
    ) -> Panels<LinePlot> {
        let panels = state_names
            .iter()
            .enumerate()
            .map(|(a, name)| {
                let mut series = Vec::new();
                if let Some(t) = truth {
                    series.push(Series::line(
                        "truth",
                        t.times.clone(),
                        t.values.iter().map(|r| r[a]).collect(),
                    ));
                }
                for est in self.estimates.iter().flatten() {
                    let p = &est.path;
                    let y: Vec<f64> = p.values.iter().map(|r| r[a]).collect();
                    let mut s = Series::line(est.method.clone(), p.times.clone(), y);
                    if let Some(sd) = &p.sd {
                        let sd: Vec<f64> = sd.iter().map(|r| r[a]).collect();
                        s = s.with_sd_band(&sd, 2.0);
                    }
                    series.push(s);
                }
                if let Some(c) = observation.states.iter().position(|&st| st == a) {
                    let y: Vec<f64> = data.values.iter().map(|r| r[c]).collect();
                    series.push(Series::points("data", data.times.clone(), y));
                }
                LinePlot {
                    title: format!("{name} (bands: ±2 sd)"),
                    x_label: "t".into(),
                    y_label: name.clone(),
                    series,
                    ..LinePlot::default()
                }
            })
            .collect();
        Panels { title: title.into(), panels, columns: 1 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::library::preset;
    use crate::simulate::{sample_measurements, simulate, SimulateOptions};
    use rand::SeedableRng;

    #[test]
    fn compares_and_keeps_going_after_a_failure() {
        let p = preset("double-well").unwrap();
        let mut rng = rand::rngs::StdRng::seed_from_u64(2);
        let truth =
            simulate(&p.model, &p.theta, &[1.0], &[], &SimulateOptions::new(0.0, 5.0, 0.01), &mut rng)
                .unwrap();
        let data = sample_measurements(&p.observation, &p.theta, &truth, 1, 1.0, &mut rng).unwrap();
        let problem = p.problem(&data, &[]);
        let options = CompareOptions { barrier: Some(0.0), ..Default::default() };
        let methods = [Method::Ksp, Method::Uks, Method::KspClosure, Method::Eks];
        let c = compare(&problem, &methods, Some(&truth), &options).unwrap();
        assert_eq!(c.rows.len(), 4);
        // The KSP row has no RMSE to itself; the UKS row has all three distances.
        assert!(c.rows[0].rmse_ksp.is_none() && c.rows[0].rmse_truth.unwrap() > 0.0);
        let uks = &c.rows[1];
        assert!(uks.rmse_ksp.unwrap() > 0.0 && uks.rmse_truth.unwrap() > 0.0);
        assert!((0.0..=1.0).contains(&uks.same_well.unwrap()));
        // Same metric as metrics::rmse directly.
        let direct = metrics::rmse(&c.estimates[1].as_ref().unwrap().path, &truth, None).unwrap();
        assert_eq!(uks.rmse_truth.unwrap(), direct);
        // A method that cannot run is a row with its error, and the comparison goes on.
        if c.rows[2].status == "error" {
            assert!(c.rows[2].error.as_ref().unwrap().contains("ksp-closure"));
            assert!(c.estimates[2].is_none());
        }
        assert_eq!(c.rows[3].status, "converged");
        let j = c.summary_json();
        assert_eq!(j["methods"].as_array().unwrap().len(), 4);
        // A truth with other states is an error.
        let fig = c.figure(&p.model.state_names(), &data, &p.observation, Some(&truth), "double well");
        assert_eq!(fig.panels.len(), 1);
        // truth, three estimates (KSP, UKS, EKS) and the data.
        assert_eq!(fig.panels[0].series.len(), 2 + c.estimates.iter().flatten().count());
        let svg = crate::plot::render_svg(&fig.scene().unwrap());
        assert!(svg.contains("uks") && svg.contains("truth"));
        let bad = StatePath { names: vec!["q".into()], ..truth.clone() };
        assert!(compare(&problem, &methods, Some(&bad), &options).is_err());
    }
}
