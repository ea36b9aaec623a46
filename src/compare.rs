//! Several estimators on the same model and data, side by side: the library side of
//! `onsager compare`.
//!
//! [`compare()`] runs each labelled [`Estimator`](crate::estimator::Estimator) through
//! [`Estimator::run`](crate::estimator::Estimator::run) (so on equal terms with the CLI and the
//! experiments), keeps going when one fails (its row carries the error), and measures each
//! estimate against the truth (when known), the exact KSP smoothed mean and the exact
//! mean-optimal estimate (when they are among the estimators) by the one rule of
//! [`crate::metrics::measure`].

use serde::Serialize;

use crate::data::{Dataset, StatePath};
use crate::estimate::{EstimationProblem, PathEstimate, RowStatus};
use crate::estimator::{Estimator, Labelled, Method, NotApplicable};
use crate::figures::{EstimatorLooks, Outcome, PathFigure};
use crate::metrics::{self, Metric};
use crate::model::observation::StateMeasurement;
use crate::model::Sde;
use crate::plot::{LinePlot, Panels};
use crate::Result;

/// Options of [`compare`].
#[derive(Debug, Clone, PartialEq, Default)]
#[non_exhaustive]
pub struct CompareOptions {
    /// For bistable models: the barrier between the wells of the first state (0 for the double
    /// well); the table then reports the fraction of times on the true well's side.
    pub barrier: Option<f64>,
}

/// One estimator's line of the comparison.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CompareRow {
    /// The estimator's label.
    pub label: String,
    /// Its method.
    pub method: Method,
    /// Its estimate's status, or `error` when it could not run.
    pub status: RowStatus,
    /// The error message, when it could not run.
    pub error: Option<String>,
    /// RMSE against the truth ([`Metric::Rmse`]).
    pub rmse_truth: Option<f64>,
    /// RMSE against the exact KSP smoothed mean ([`Metric::RmseTo`] the first `ksp`).
    pub rmse_ksp: Option<f64>,
    /// RMSE against the exact mean-optimal estimate (the first `mean-optimal`).
    pub rmse_mean_optimal: Option<f64>,
    /// Fraction of the truth's times at which the first state is on the true well's side
    /// ([`Metric::WellSide`]).
    pub same_well: Option<f64>,
    /// The solve time in seconds.
    pub seconds: f64,
    /// The estimator's notes (see [`crate::estimate::MethodRun`]).
    pub notes: Vec<String>,
}

/// The result of [`compare`]: one row and (when it ran) one estimate per estimator, in order.
#[derive(Debug, Clone)]
pub struct Comparison {
    /// The rows.
    pub rows: Vec<CompareRow>,
    /// The estimates (`None` where the estimator failed to run).
    pub estimates: Vec<Option<PathEstimate>>,
    /// The estimators left out because they do not apply (filled by the caller, e.g. from
    /// [`default_estimators`]); listed under the table and in `summary.json`.
    pub skipped: Vec<NotApplicable>,
}

/// The candidates of [`default_estimators`], in the order of the table.
pub const DEFAULT_METHODS: [Method; 10] = [
    Method::Ksp,
    Method::MeanOptimal,
    Method::GaussianClosure,
    Method::ExpClosure,
    Method::DoubleExpClosure,
    Method::KspClosure,
    Method::GaussianKspClosure,
    Method::Jme,
    Method::Mee,
    Method::Uks,
];

/// The estimators compared by default, with their default options: those of
/// [`DEFAULT_METHODS`] (the exact grid methods, the five closures, JME, MEE and the UKS) that
/// apply to the problem ([`Estimator::applies_to`]), and the others with the reason they do not.
/// With a `grid`, the exact grid methods take it ([`Estimator::with_default_grid`]) before
/// their applicability is checked, so they also apply where the default grid cannot be formed
/// (a state that is not measured).
/// The exponential closure, and the exact grid methods without a `grid`, apply in three states
/// but are left out with their reason: they take a minute or more per record there
/// (docs/closures.md, "The quartic closure in three states"; docs/effective-action.md, "Three
/// states"); name them, or give a grid for the grid methods, to run them.
pub fn default_estimators<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    grid: Option<&crate::action::grid::GridSpec>,
) -> (Vec<Labelled>, Vec<NotApplicable>) {
    let (mut chosen, mut skipped) = (Vec::new(), Vec::new());
    let n = problem.sde.dims().states();
    for m in DEFAULT_METHODS {
        let e = match grid {
            Some(g) => Estimator::new(m).with_default_grid(g),
            None => Estimator::new(m),
        };
        let costly = m == Method::ExpClosure || (m.uses_grid() && grid.is_none());
        match e.applies_to(problem) {
            Ok(()) if n == 3 && costly => {
                let (what, how) = if m.uses_grid() {
                    ("the grid methods take about a minute", format!("name `{m}`, or give a grid"))
                } else {
                    ("the exponential closure takes minutes", format!("name `{m}`"))
                };
                skipped.push(NotApplicable {
                    method: m,
                    reason: format!("in 3 states {what} per record; not run by default ({how})"),
                })
            }
            Ok(()) => chosen.push(Labelled::new(e)),
            Err(why) => skipped.push(why),
        }
    }
    (chosen, skipped)
}

/// The value of `metric` where it can be computed.
fn value_of(
    metric: &Metric,
    est: &PathEstimate,
    truth: Option<&StatePath>,
    refs: &[(&str, &StatePath)],
) -> Option<f64> {
    metrics::measure(metric, &est.path, truth, refs).ok()
}

/// Runs `estimators` on `problem` and measures them with [`metrics::measure`] against the
/// truth (when given), the first successful `ksp` and `mean-optimal` estimates among them.
/// An estimator that does not apply ([`Estimator::applies_to`]) or fails is a row with status
/// `error` and its message; the comparison goes on.
///
/// Errors: none from the estimators; a `truth` whose state names differ from the model's.
pub fn compare<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    estimators: &[Labelled],
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
    let mut rows = Vec::with_capacity(estimators.len());
    let mut estimates = Vec::with_capacity(estimators.len());
    for e in estimators {
        let ran = e
            .estimator
            .applies_to(problem)
            .map_err(|why| why.to_string())
            .and_then(|()| e.estimator.run(problem).map_err(|err| err.to_string()));
        let (status, error, seconds, notes, estimate) = match ran {
            Ok(mut run) => {
                let est = run.estimate;
                if let Some(why) = est.partial() {
                    run.notes.push(format!("partial: {why}"));
                }
                (RowStatus::Finished(est.status), None, est.solve_seconds, run.notes, Some(est))
            }
            Err(err) => (RowStatus::Error, Some(err), 0.0, Vec::new(), None),
        };
        rows.push(CompareRow {
            label: e.label.clone(),
            method: e.estimator.method(),
            status,
            error,
            rmse_truth: None,
            rmse_ksp: None,
            rmse_mean_optimal: None,
            same_well: None,
            seconds,
            notes,
        });
        estimates.push(estimate);
    }
    let reference = |m: Method| -> Option<&PathEstimate> {
        estimates.iter().flatten().find(|e| e.method == m && e.status.is_success())
    };
    let refs: Vec<(&str, &StatePath)> =
        [("ksp", reference(Method::Ksp)), ("mean-optimal", reference(Method::MeanOptimal))]
            .into_iter()
            .filter_map(|(l, e)| e.map(|e| (l, &e.path)))
            .collect();
    for (row, est) in rows.iter_mut().zip(&estimates) {
        let Some(est) = est else { continue };
        row.rmse_truth = value_of(&Metric::Rmse, est, truth, &refs);
        if let Some(barrier) = options.barrier {
            row.same_well = value_of(&Metric::WellSide { state: None, barrier }, est, truth, &refs);
        }
        if row.method != Method::Ksp {
            row.rmse_ksp = value_of(&Metric::RmseTo("ksp".into()), est, truth, &refs);
        }
        if row.method != Method::MeanOptimal {
            row.rmse_mean_optimal = value_of(&Metric::RmseTo("mean-optimal".into()), est, truth, &refs);
        }
    }
    Ok(Comparison { rows, estimates, skipped: Vec::new() })
}

/// One row of `summary.json`.
#[derive(Debug, Serialize)]
struct SummaryRow<'a> {
    label: &'a str,
    method: Method,
    status: RowStatus,
    error: &'a Option<String>,
    rmse_truth: Option<f64>,
    rmse_ksp: Option<f64>,
    rmse_mean_optimal: Option<f64>,
    same_well_fraction: Option<f64>,
    solve_seconds: f64,
    iterations: Option<usize>,
    notes: &'a [String],
}

/// One estimator left out of the comparison, in `summary.json`.
#[derive(Debug, Serialize)]
struct SkippedRow {
    method: Method,
    reason: String,
}

/// `summary.json`: the rows in order, then the estimators left out with their reasons.
#[derive(Debug, Serialize)]
pub struct Summary<'a> {
    methods: Vec<SummaryRow<'a>>,
    skipped: Vec<SkippedRow>,
}

impl Comparison {
    /// The summary: one object per estimator with its label, method, status, metrics (null when
    /// not available), seconds, iterations, notes and error.
    pub fn summary(&self) -> Summary<'_> {
        let finite = |x: Option<f64>| x.filter(|v| v.is_finite());
        let methods = self
            .rows
            .iter()
            .zip(&self.estimates)
            .map(|(r, e)| SummaryRow {
                label: &r.label,
                method: r.method,
                status: r.status,
                error: &r.error,
                rmse_truth: finite(r.rmse_truth),
                rmse_ksp: finite(r.rmse_ksp),
                rmse_mean_optimal: finite(r.rmse_mean_optimal),
                same_well_fraction: finite(r.same_well),
                solve_seconds: r.seconds,
                iterations: e.as_ref().map(|e| e.iterations),
                notes: &r.notes,
            })
            .collect();
        let skipped =
            self.skipped.iter().map(|s| SkippedRow { method: s.method, reason: s.reason.clone() }).collect();
        Summary { methods, skipped }
    }

    /// The estimates with their labels.
    fn labelled(&self) -> impl Iterator<Item = (&str, &PathEstimate)> {
        self.rows.iter().zip(&self.estimates).filter_map(|(r, e)| e.as_ref().map(|e| (r.label.as_str(), e)))
    }

    /// All estimated paths in one long table: `method,t,<states>,sd_<states>` (the estimator's
    /// label in `method`; the sd cells empty where an estimate has none, or a NaN), the same
    /// columns whatever the estimators.
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
        for (label, est) in self.labelled() {
            for (i, &t) in est.path.times.iter().enumerate() {
                let mut rec = vec![label.to_string(), format!("{t}")];
                rec.extend(est.path.values[i].iter().map(|v| format!("{v}")));
                match &est.path.sd {
                    Some(sd) => {
                        rec.extend(
                            sd[i].iter().map(|v| if v.is_nan() { String::new() } else { format!("{v}") }),
                        )
                    }
                    None => rec.extend(state_names.iter().map(|_| String::new())),
                }
                w.write_record(&rec).map_err(csv_err)?;
            }
        }
        w.flush().map_err(io)
    }
}

impl Comparison {
    /// The looks of the estimators of the comparison (failed ones included), one per label.
    pub fn looks(&self) -> EstimatorLooks {
        EstimatorLooks::new(self.rows.iter().map(|r| (r.label.as_str(), r.method)))
    }

    /// The figure of the comparison ([`PathFigure`]): per state an overview of every path with
    /// the truth (when given) and the measurements of that state, then one panel per estimator
    /// with its ±2 sd band where it has an sd, or why it has none or no estimate.
    pub fn figure(
        &self,
        state_names: &[String],
        data: &Dataset,
        observation: &StateMeasurement,
        truth: Option<&StatePath>,
        title: &str,
    ) -> Panels<LinePlot> {
        let looks = self.looks();
        let estimates = self
            .rows
            .iter()
            .zip(&self.estimates)
            .map(|(r, e)| {
                let outcome = match e {
                    Some(e) => Outcome::Estimate(e),
                    None => Outcome::Missing(r.error.as_deref().unwrap_or("it did not run")),
                };
                (r.label.as_str(), outcome)
            })
            .collect();
        PathFigure {
            title: title.into(),
            states: state_names,
            truth,
            data,
            measured: &observation.states,
            estimates,
            looks: &looks,
        }
        .panels()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::library::preset;
    use crate::test_models::PresetRecord;

    #[test]
    fn compares_and_keeps_going_after_a_failure() {
        // The double-well preset from x(0) = 1 on [0, 5] (step 0.01), measured every 1.0.
        let mut p = preset("double-well").unwrap();
        (p.t_end, p.dt, p.sample_every) = (5.0, 0.01, 1.0);
        let PresetRecord { preset: p, truth, data } = PresetRecord::simulate_from(p, 2, &[1.0], &[]).unwrap();
        let problem = p.problem(&data, &[]);
        let options = CompareOptions { barrier: Some(0.0) };
        let methods: Vec<Labelled> = [Method::Ksp, Method::Uks, Method::KspClosure, Method::Eks]
            .into_iter()
            .map(|m| Labelled::new(Estimator::new(m)))
            .collect();
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
        if c.rows[2].status == RowStatus::Error {
            assert!(c.rows[2].error.as_ref().unwrap().contains("ksp-closure"));
            assert!(c.estimates[2].is_none());
        }
        assert_eq!(c.rows[3].status, RowStatus::Finished(crate::Status::Converged));
        let j = serde_json::to_value(c.summary()).unwrap();
        assert_eq!(j["methods"].as_array().unwrap().len(), 4);
        assert_eq!(j["methods"][3]["status"], "converged");
        // A truth with other states is an error.
        let fig = c.figure(&p.model.state_names(), &data, &p.observation, Some(&truth), "double well");
        // One overview and one panel per estimator.
        assert_eq!((fig.header.len(), fig.panels.len()), (1, 4));
        // The overview: the truth, every estimate and the data.
        assert_eq!(fig.header[0].series.len(), 2 + c.estimates.iter().flatten().count());
        let svg = crate::plot::render_svg(&fig.scene().unwrap());
        assert!(svg.contains("uks") && svg.contains("truth"));
        let bad = StatePath { names: vec!["q".into()], ..truth.clone() };
        assert!(compare(&problem, &methods, Some(&bad), &options).is_err());
    }

    #[test]
    fn the_default_estimators_are_those_that_apply() {
        // Lorenz-63 (three states, Gaussian errors): the grid methods and the one- and two-state
        // closures are skipped with their reason; the Gaussian closures, JME, MEE and the UKS run.
        let p = preset("lorenz63").unwrap();
        let data = crate::data::Dataset { names: vec![], times: vec![], values: vec![] };
        let (chosen, skipped) = default_estimators(&p.problem(&data, &[]), None);
        let chosen: Vec<Method> = chosen.iter().map(|l| l.estimator.method()).collect();
        assert_eq!(
            chosen,
            [Method::GaussianClosure, Method::GaussianKspClosure, Method::Jme, Method::Mee, Method::Uks]
        );
        let skipped_methods: Vec<Method> = skipped.iter().map(|s| s.method).collect();
        assert_eq!(
            skipped_methods,
            [
                Method::Ksp,
                Method::MeanOptimal,
                Method::ExpClosure,
                Method::DoubleExpClosure,
                Method::KspClosure
            ]
        );
        // Without data there is no default grid; the closures name the 3 states.
        for s in &skipped {
            let why = if s.method.uses_grid() { "no finite data" } else { "3 states" };
            assert!(s.reason.contains(why), "{s}");
        }
        // With data for a default grid the grid methods apply in three states, and are left out
        // with their cost as the reason.
        let one = crate::data::Dataset {
            names: vec!["y1".into(), "y2".into(), "y3".into()],
            times: vec![0.0],
            values: vec![vec![1.0, 2.0, 20.0]],
        };
        let problem = p.problem(&one, &[]);
        assert!(Estimator::new(Method::MeanOptimal).applies_to(&problem).is_ok());
        let (_, skipped) = default_estimators(&problem, None);
        for m in [Method::Ksp, Method::MeanOptimal] {
            let why = skipped.iter().find(|s| s.method == m).unwrap();
            assert!(
                why.reason.contains("a minute per record") && why.reason.contains(&format!("name `{m}`")),
                "{why}"
            );
        }
        // Given a grid, they run, with that grid, even without data for a default grid; the
        // exponential closure is still left out.
        let grid = crate::action::grid::GridSpec::parse("lo=-20;-25;0,hi=20;25;50,cells=8;8;8").unwrap();
        for data in [&data, &one] {
            let (chosen, skipped) = default_estimators(&p.problem(data, &[]), Some(&grid));
            let grids: Vec<_> = chosen
                .iter()
                .filter_map(|l| match &l.estimator {
                    Estimator::Ksp(o) => o.grid.clone(),
                    Estimator::MeanOptimal(o) => o.exact.grid.clone(),
                    _ => None,
                })
                .collect();
            assert_eq!(grids, [grid.clone(), grid.clone()]);
            assert!(skipped.iter().all(|s| !s.method.uses_grid()));
            assert!(skipped.iter().any(|s| s.method == Method::ExpClosure));
        }
        // A grid of two axes on three states: the grid methods are left out, with the reason.
        let flat = crate::action::grid::GridSpec::parse("lo=-20;-25,hi=20;25,cells=8;8").unwrap();
        let (chosen, skipped) = default_estimators(&problem, Some(&flat));
        assert!(chosen.iter().all(|l| !l.estimator.method().uses_grid()));
        for m in [Method::Ksp, Method::MeanOptimal] {
            let why = skipped.iter().find(|s| s.method == m).unwrap();
            assert!(why.reason.contains("has 2 axes, the model 3 states"), "{why}");
        }
        // A Student-t likelihood: the Gaussian KSP closure needs Gaussian errors.
        let mut p = preset("double-well").unwrap();
        p.observation.noise = crate::model::Noise::StudentT {
            nu: crate::model::Param::Fixed(4.0),
            scale: crate::model::Param::Fixed(0.2),
        };
        let (chosen, skipped) = default_estimators(&p.problem(&data, &[]), None);
        assert!(chosen.iter().all(|l| l.estimator.method() != Method::GaussianKspClosure));
        let why = skipped.iter().find(|s| s.method == Method::GaussianKspClosure).unwrap();
        assert!(why.reason.contains("Gaussian measurement errors"), "{why}");
    }

    #[test]
    fn paths_csv_has_the_sd_columns_whatever_the_estimators() {
        let mut p = preset("double-well").unwrap();
        (p.t_end, p.dt, p.sample_every) = (5.0, 0.01, 1.0);
        let PresetRecord { preset: p, truth, data } = PresetRecord::simulate_from(p, 2, &[1.0], &[]).unwrap();
        let problem = p.problem(&data, &[]);
        // jme without its Laplace sd, so with no sd at all.
        let methods = crate::estimator::parse_list("jme:laplace_max_states=0").unwrap();
        let c = compare(&problem, &methods, Some(&truth), &CompareOptions::default()).unwrap();
        assert!(c.estimates[0].as_ref().unwrap().path.sd.is_none());
        let file = std::env::temp_dir().join(format!("onsager-paths-{}.csv", std::process::id()));
        c.write_paths_csv(&file, &p.model.state_names()).unwrap();
        let text = std::fs::read_to_string(&file).unwrap();
        std::fs::remove_file(&file).unwrap();
        let mut lines = text.lines();
        assert_eq!(lines.next(), Some("method,t,x,sd_x"));
        assert!(lines.all(|l| l.starts_with("jme,") && l.ends_with(',') && l.split(',').count() == 4));
    }
}
