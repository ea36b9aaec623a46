//! The Monte Carlo runner: replicates in parallel, one `results.csv` row per (scenario,
//! replicate, estimator) appended as soon as the estimator finishes, resumable.

use std::collections::HashSet;
use std::fs::OpenOptions;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use rand::rngs::StdRng;
use rand::SeedableRng;
use rayon::prelude::*;

use super::report::{self, Results};
use super::shard::{self, Shard};
use super::spec::{Experiment, ExperimentSpec, Metric, MetricsAt, Scenario, ScenarioEstimator};
use crate::data::{Dataset, StatePath};
use crate::estimate::{EstimationProblem, PathEstimate, RowStatus};
use crate::estimator::Method;
use crate::figures::EstimatorLooks;
use crate::metrics;
use crate::simulate::{sample_measurements_at, sample_record, simulate, SimulateOptions};
use crate::{Error, Result};

/// The first columns of `results.csv`, before the metrics and the parameter estimates.
pub const KEY_COLUMNS: [&str; 7] =
    ["scenario", "replicate", "estimator", "method", "status", "iterations", "solve_seconds"];

/// How to run an experiment.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct RunOptions {
    /// Output folder (`results.csv`, `summary.json`, `plots/`).
    pub out: PathBuf,
    /// Worker threads (0: one per core). Results do not depend on it.
    pub jobs: usize,
    /// Keep the rows of an earlier run in `out` and run only the missing ones.
    pub resume: bool,
    /// Run the spec's quick version (its `[quick]` overrides).
    pub quick: bool,
    /// Replicates per scenario (default: the spec's).
    pub replicates: Option<usize>,
    /// Seed (default: the spec's).
    pub seed: Option<u64>,
    /// Stop after writing this many rows (an interrupted run, for tests); no summary then.
    pub max_rows: Option<usize>,
    /// Write the plots (default true).
    pub plots: bool,
    /// Run only this shard's replicates, into `out/shards/I-of-N` (see [`super::shard`]); no
    /// summary then (the merge writes it). Default: none, the whole experiment.
    pub shard: Option<Shard>,
    /// A flag another thread sets to stop the run early (e.g. on Ctrl-C in a caller): rows
    /// still being computed are not written, the run returns with `complete` false and no
    /// summary, and `resume` continues it. Default: none.
    pub cancel: Option<Cancel>,
}

/// A shared stop flag for [`RunOptions::cancel`]; clones share the flag.
#[derive(Debug, Clone, Default)]
pub struct Cancel(std::sync::Arc<AtomicBool>);

impl Cancel {
    /// A flag that is not set.
    pub fn new() -> Cancel {
        Cancel::default()
    }

    /// Sets the flag: the runs holding it stop.
    pub fn cancel(&self) {
        self.0.store(true, Ordering::SeqCst);
    }

    /// Whether the flag is set.
    pub fn is_cancelled(&self) -> bool {
        self.0.load(Ordering::SeqCst)
    }
}

impl PartialEq for Cancel {
    /// Two flags are equal when they are the same flag.
    fn eq(&self, other: &Cancel) -> bool {
        std::sync::Arc::ptr_eq(&self.0, &other.0)
    }
}

impl RunOptions {
    /// Options writing to `out`, every other option at its default (all cores, no resume,
    /// full version, the spec's replicates and seed, plots on).
    pub fn new(out: impl Into<PathBuf>) -> RunOptions {
        RunOptions {
            out: out.into(),
            jobs: 0,
            resume: false,
            quick: false,
            replicates: None,
            seed: None,
            max_rows: None,
            plots: true,
            shard: None,
            cancel: None,
        }
    }
}

/// The default output folder of an experiment: `out/experiments/NAME`, and its `quick`
/// subfolder for the quick version (`onsager experiment run` and the Python package).
pub fn default_out(name: &str, quick: bool) -> PathBuf {
    let dir = PathBuf::from("out/experiments").join(name);
    if quick {
        dir.join("quick")
    } else {
        dir
    }
}

/// One row of `results.csv`.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// Scenario name.
    pub scenario: String,
    /// Replicate index (from 0).
    pub replicate: usize,
    /// Estimator label.
    pub estimator: String,
    /// The estimator's method.
    pub method: Method,
    /// The estimate's status, or `error` when the method returned an error.
    pub status: RowStatus,
    /// Iterations of the method.
    pub iterations: usize,
    /// Solve time in seconds.
    pub solve_seconds: f64,
    /// One value per metric column (NaN where it could not be computed).
    pub metrics: Vec<f64>,
    /// One value per parameter column (None where the estimator does not estimate it).
    pub theta: Vec<Option<f64>>,
    /// The error message (status `error`) or the reason a metric is missing; empty otherwise.
    pub message: String,
}

/// What the runner reports after each row.
#[derive(Debug, Clone)]
pub struct Progress {
    /// Rows done (written now or found by `--resume`).
    pub done: usize,
    /// Rows of the whole experiment.
    pub total: usize,
    /// Rows found in an earlier run.
    pub resumed: usize,
    /// Seconds since the start of this run.
    pub elapsed: f64,
    /// The row just written.
    pub row: Row,
}

/// The outcome of [`run`].
#[derive(Debug, Clone)]
pub struct RunReport {
    /// Rows written by this run.
    pub written: usize,
    /// Rows kept from an earlier run.
    pub resumed: usize,
    /// Rows of the whole experiment.
    pub total: usize,
    /// Whether every row is present (of the shard, for a shard; false when stopped by
    /// `max_rows`).
    pub complete: bool,
    /// `results.csv` (`out/shards/I-of-N/results.csv` for a shard).
    pub results: PathBuf,
    /// `summary.json` (written when complete, unless the run is a shard).
    pub summary: Option<PathBuf>,
    /// The plots written (stems; each has `.svg` and `.png`).
    pub plots: Vec<PathBuf>,
}

/// The columns of `results.csv` for these scenarios: the key columns, one per metric, one per
/// estimated parameter (`theta_NAME`), and `message`.
pub fn columns(scenarios: &[Scenario]) -> (Vec<String>, Vec<String>) {
    let mut metric_cols: Vec<String> = Vec::new();
    let mut theta_cols: Vec<String> = Vec::new();
    for s in scenarios {
        for m in &s.metrics {
            if !metric_cols.contains(&m.column()) {
                metric_cols.push(m.column());
            }
        }
        for e in &s.estimators {
            let names = e.preset.param_names();
            for &i in &e.estimate {
                if !theta_cols.contains(&names[i]) {
                    theta_cols.push(names[i].clone());
                }
            }
        }
    }
    (metric_cols, theta_cols)
}

fn header(metric_cols: &[String], theta_cols: &[String]) -> Vec<String> {
    let mut h: Vec<String> = KEY_COLUMNS.iter().map(|s| s.to_string()).collect();
    h.extend(metric_cols.iter().cloned());
    h.extend(theta_cols.iter().map(|n| format!("theta_{n}")));
    h.push("message".into());
    h
}

/// One CSV line (with its newline), quoted where needed.
pub(crate) fn csv_line(fields: &[String]) -> String {
    let mut w = csv::WriterBuilder::new().terminator(csv::Terminator::Any(b'\n')).from_writer(Vec::new());
    w.write_record(fields).expect("writing to memory");
    String::from_utf8(w.into_inner().expect("writing to memory")).expect("UTF-8 fields")
}

/// A number as written in `results.csv`: the shortest round-trip decimal, `NaN` for NaN.
fn number(v: f64) -> String {
    if v.is_nan() {
        "NaN".into()
    } else {
        format!("{v}")
    }
}

impl Row {
    /// The fields of its `results.csv` line.
    pub(crate) fn fields(&self) -> Vec<String> {
        let mut f = vec![
            self.scenario.clone(),
            self.replicate.to_string(),
            self.estimator.clone(),
            self.method.name().to_string(),
            self.status.name().to_string(),
            self.iterations.to_string(),
            format!("{:.6}", self.solve_seconds),
        ];
        f.extend(self.metrics.iter().map(|&v| number(v)));
        f.extend(self.theta.iter().map(|v| v.map(number).unwrap_or_default()));
        f.push(self.message.replace(['\n', '\r'], " "));
        f
    }
}

/// SplitMix64's finaliser (Steele, Lea & Flood 2014): a bijective mix of 64 bits.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// FNV-1a hash of a string (stable across platforms and Rust versions).
fn fnv(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01B3))
}

/// The seed of one replicate: a function of (seed, scenario name, replicate) only, so the
/// results do not depend on the number of threads or on the order of the work.
pub fn replicate_seed(seed: u64, scenario: &str, replicate: usize) -> u64 {
    mix(mix(seed ^ mix(fnv(scenario))) ^ replicate as u64)
}

/// The truth and the data of one replicate.
pub fn simulate_replicate(scenario: &Scenario, seed: u64) -> Result<(StatePath, Dataset)> {
    let p = &scenario.truth;
    let mut rng = StdRng::seed_from_u64(seed);
    let n_noisy = p.dims().noisy;
    let s0 = scenario.initial.iter().map(|pr| pr.sample(&mut rng)).collect::<Result<Vec<f64>>>()?;
    let options = SimulateOptions::new(0.0, p.t_end, p.dt).with_scheme(scenario.scheme);
    let truth = simulate(&p.model, &p.theta, &s0[..n_noisy], &s0[n_noisy..], &options, &mut rng)?;
    let data = match scenario.continuous {
        Some(r) => sample_record(&p.observation, &truth, n_noisy, p.sample_every, r, &mut rng)?.data,
        None => sample_measurements_at(&p.observation, &p.theta, &truth, n_noisy, &scenario.times, &mut rng)?,
    };
    Ok((truth, data))
}

/// The metrics of `estimate` against the truth and the other estimates of the replicate
/// (`refs`: label → estimate), in the order of `metric_cols`, by [`metrics::measure`]; NaN (with
/// a message) where a metric cannot be computed.
pub(super) fn metric_values(
    scenario: &Scenario,
    metric_cols: &[String],
    estimate: &StatePath,
    truth: &StatePath,
    refs: &[(String, PathEstimate)],
    message: &mut Vec<String>,
) -> Vec<f64> {
    let others: Vec<(&str, &StatePath)> = refs.iter().map(|(l, e)| (l.as_str(), &e.path)).collect();
    let mut values = vec![f64::NAN; metric_cols.len()];
    if estimate.times.is_empty() {
        message.push("no metrics: the estimator returned no path".into());
        return values;
    }
    for m in &scenario.metrics {
        let col = metric_cols.iter().position(|c| *c == m.column()).expect("every metric has a column");
        match metrics::measure(m, estimate, Some(truth), &others) {
            Ok(v) => values[col] = v,
            Err(e) => message.push(format!("{}: {e}", m.column())),
        }
    }
    values
}

/// Rows already in `results.csv`, the file truncated after its last complete line.
fn read_done(path: &Path, header: &[String]) -> Result<Vec<Row>> {
    let io = |source| Error::Io { path: path.to_path_buf(), source };
    let text = std::fs::read_to_string(path).map_err(io)?;
    let complete = match text.rfind('\n') {
        Some(i) => i + 1,
        None => 0,
    };
    if complete < text.len() {
        // A truncated last line (the run was killed while writing it): drop it.
        let f = OpenOptions::new().write(true).open(path).map_err(io)?;
        f.set_len(complete as u64).map_err(io)?;
    }
    let text = &text[..complete];
    if text.is_empty() {
        return Ok(Vec::new());
    }
    let rows = report::parse_results(text, path)?;
    if rows.header != header {
        return Err(Error::InvalidOption {
            name: "--resume".into(),
            reason: format!(
                "{} has the columns `{}`, this experiment writes `{}`; use another output folder",
                path.display(),
                rows.header.join(","),
                header.join(",")
            ),
        });
    }
    Ok(rows.rows)
}

/// The output folder of a run: `results.csv` opened for appending (with its header), the rows
/// of an earlier run when resuming, and the key of `run.json`.
struct Output {
    results: PathBuf,
    file: std::fs::File,
    done: Vec<Row>,
}

fn io_error(path: &Path) -> impl Fn(std::io::Error) -> Error + '_ {
    move |source| Error::Io { path: path.to_path_buf(), source }
}

/// Opens the output folder: locks `results.csv` (so that a second run of the same folder or
/// shard fails instead of writing its rows twice), checks a resumed run's key, reads its rows,
/// writes `run.json` and the header of a new `results.csv`.
fn open_output(out: &Path, header: &[String], key: &str, resume: bool) -> Result<Output> {
    std::fs::create_dir_all(out).map_err(io_error(out))?;
    let results = out.join("results.csv");
    let run_json = out.join("run.json");
    let existed = results.exists();
    if existed && !resume {
        return Err(Error::InvalidOption {
            name: "--out".into(),
            reason: format!(
                "{} exists; pass --resume to continue it, or choose another folder",
                results.display()
            ),
        });
    }
    let mut file = OpenOptions::new().create(true).append(true).open(&results).map_err(io_error(&results))?;
    // Advisory and best effort: a file system without locks runs unguarded.
    if let Err(std::fs::TryLockError::WouldBlock) = file.try_lock() {
        return Err(Error::InvalidOption {
            name: "--out".into(),
            reason: format!(
                "{} is being written by another run of the same folder (or shard); wait for it to end",
                results.display()
            ),
        });
    }
    let done = if existed {
        let recorded = std::fs::read_to_string(&run_json).unwrap_or_default();
        if recorded.trim() != key {
            return Err(Error::InvalidOption {
                name: "--resume".into(),
                reason: format!(
                    "{} was written by another spec, seed or --quick setting; use another output folder",
                    out.display()
                ),
            });
        }
        read_done(&results, header)?
    } else {
        Vec::new()
    };
    std::fs::write(&run_json, format!("{key}\n")).map_err(io_error(&run_json))?;
    if done.is_empty() && file.metadata().map(|m| m.len()).unwrap_or(0) == 0 {
        file.write_all(csv_line(header).as_bytes()).map_err(io_error(&results))?;
        file.flush().map_err(io_error(&results))?;
    }
    Ok(Output { results, file, done })
}

/// The (scenario, replicate, estimator) of the rows an earlier run left (found by `--resume`).
struct Done(HashSet<(String, usize, String)>);

impl Done {
    fn new(rows: &[Row]) -> Done {
        Done(rows.iter().map(|r| (r.scenario.clone(), r.replicate, r.estimator.clone())).collect())
    }

    fn contains(&self, scenario: &str, replicate: usize, label: &str) -> bool {
        self.0.contains(&(scenario.to_string(), replicate, label.to_string()))
    }
}

/// What every worker of a run shares.
struct Shared<'a> {
    scenarios: &'a [Scenario],
    seed: u64,
    metric_cols: &'a [String],
    theta_cols: &'a [String],
    done: &'a Done,
    options: &'a RunOptions,
    results: &'a Path,
    writer: Mutex<std::fs::File>,
    written: AtomicUsize,
    stop: AtomicBool,
    plots: Mutex<Vec<PathBuf>>,
    looks: EstimatorLooks,
    start: Instant,
    total: usize,
    resumed: usize,
}

/// An estimator's outcome on a replicate: its estimate, or the error's message.
type Outcome = std::result::Result<PathEstimate, String>;

impl Shared<'_> {
    fn is_done(&self, scenario: &str, replicate: usize, label: &str) -> bool {
        self.done.contains(scenario, replicate, label)
    }

    /// Runs estimator `e` on the replicate's data with its seed (a function of the replicate's
    /// seed and the label).
    fn estimate(&self, e: &ScenarioEstimator, data: &Dataset, unit_seed: u64) -> Outcome {
        let problem = EstimationProblem {
            seed: mix(unit_seed ^ mix(fnv(&e.label))),
            ..e.preset.problem(data, &e.estimate)
        };
        e.estimator.run(&problem).map(|run| run.estimate).map_err(|err| err.to_string())
    }

    /// The row of estimator `e` on replicate `r` of `scenario`.
    fn row(
        &self,
        scenario: &Scenario,
        r: usize,
        e: &ScenarioEstimator,
        outcome: Outcome,
        truth: &StatePath,
        refs: &[(String, PathEstimate)],
    ) -> Row {
        let mut row = Row {
            scenario: scenario.name.clone(),
            replicate: r,
            estimator: e.label.clone(),
            method: e.estimator.method(),
            status: RowStatus::Error,
            iterations: 0,
            solve_seconds: 0.0,
            metrics: vec![f64::NAN; self.metric_cols.len()],
            theta: vec![None; self.theta_cols.len()],
            message: String::new(),
        };
        match outcome {
            Ok(est) => {
                let mut messages = Vec::new();
                row.status = RowStatus::Finished(est.status);
                row.iterations = est.iterations;
                row.solve_seconds = est.solve_seconds;
                row.metrics =
                    metric_values(scenario, self.metric_cols, &est.path, truth, refs, &mut messages);
                let names = e.preset.param_names();
                for &k in &e.estimate {
                    let c =
                        self.theta_cols.iter().position(|n| *n == names[k]).expect("a column per parameter");
                    row.theta[c] = Some(est.theta[k]);
                }
                if !est.status.is_success() {
                    let reasons = est.details.failure_reasons().into_iter().map(|(_, why)| why.to_string());
                    messages.splice(0..0, reasons);
                }
                row.message = messages.join("; ");
            }
            Err(message) => row.message = message,
        }
        row
    }

    /// Whether the run stops: `max_rows` reached or [`RunOptions::cancel`] set.
    fn stopped(&self) -> bool {
        self.stop.load(Ordering::SeqCst) || self.options.cancel.as_ref().is_some_and(Cancel::is_cancelled)
    }

    /// Appends `row` to `results.csv` (flushed) and reports progress; `false` once `max_rows`
    /// rows are written (the run then stops).
    fn write(&self, row: Row, progress: &(dyn Fn(&Progress) + Sync)) -> Result<bool> {
        // A worker that panicked while holding the file propagates its panic through the pool;
        // the file itself is append-only, so its guard is still usable.
        let mut f = self.writer.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if self.stopped() {
            return Ok(false);
        }
        if let Some(max) = self.options.max_rows {
            if self.written.load(Ordering::SeqCst) >= max {
                self.stop.store(true, Ordering::SeqCst);
                return Ok(false);
            }
        }
        f.write_all(csv_line(&row.fields()).as_bytes()).map_err(io_error(self.results))?;
        f.flush().map_err(io_error(self.results))?;
        let n = self.written.fetch_add(1, Ordering::SeqCst) + 1;
        progress(&Progress {
            done: self.resumed + n,
            total: self.total,
            resumed: self.resumed,
            elapsed: self.start.elapsed().as_secs_f64(),
            row,
        });
        Ok(true)
    }

    /// One replicate of one scenario: simulate, run the missing estimators (the references of
    /// `rmse-to` first: their rows wait until all references are known, so that they too get
    /// their distances to each other; then the others, each row written as soon as its
    /// estimator finishes), and the path plot of replicate 0.
    fn unit(&self, si: usize, r: usize, progress: &(dyn Fn(&Progress) + Sync)) -> Result<()> {
        if self.stopped() {
            return Ok(());
        }
        let scenario = &self.scenarios[si];
        let unit_seed = replicate_seed(self.seed, &scenario.name, r);
        let (truth, data) = simulate_replicate(scenario, unit_seed)?;
        let at_measurements = match scenario.spec.metrics_at {
            MetricsAt::Truth => None,
            MetricsAt::Measurements => Some(truth.at_times(&data.times)),
        };
        let judged = at_measurements.as_ref().unwrap_or(&truth);
        let refs: Vec<&str> = scenario
            .metrics
            .iter()
            .filter_map(|m| if let Metric::RmseTo(l) = m { Some(l.as_str()) } else { None })
            .collect();
        let mut order: Vec<usize> = (0..scenario.estimators.len()).collect();
        order.sort_by_key(|&i| !refs.contains(&scenario.estimators[i].label.as_str()));
        let n_refs = order.iter().filter(|&&i| refs.contains(&scenario.estimators[i].label.as_str())).count();
        let mut estimates: Vec<(String, PathEstimate)> = Vec::new();
        let mut errors: Vec<(String, String)> = Vec::new();
        let mut pending: Vec<(usize, Outcome)> = Vec::new();
        for (position, &i) in order.iter().enumerate() {
            let e = &scenario.estimators[i];
            let is_ref = position < n_refs;
            if !is_ref && self.is_done(&scenario.name, r, &e.label) {
                continue;
            }
            if self.stopped() {
                return Ok(());
            }
            let outcome = self.estimate(e, &data, unit_seed);
            match &outcome {
                Ok(est) => estimates.push((e.label.clone(), est.clone())),
                Err(why) => errors.push((e.label.clone(), why.clone())),
            }
            pending.push((i, outcome));
            if is_ref && position + 1 < n_refs {
                continue;
            }
            for (i, outcome) in pending.drain(..) {
                let e = &scenario.estimators[i];
                if self.is_done(&scenario.name, r, &e.label) {
                    continue;
                }
                let row = self.row(scenario, r, e, outcome, judged, &estimates);
                if !self.write(row, progress)? {
                    return Ok(());
                }
            }
        }
        if r == 0 && self.options.plots {
            let stem =
                self.options.out.join("plots").join(format!("paths_{}", report::file_name(&scenario.name)));
            let paths =
                report::ReplicatePaths { truth: &truth, data: &data, estimates: &estimates, errors: &errors };
            report::path_figure(scenario, r, paths, &self.looks).write(&stem)?;
            self.plots.lock().unwrap_or_else(std::sync::PoisonError::into_inner).push(stem);
        }
        Ok(())
    }
}

/// Writes `summary.json` of `table` in `out` and, with `plots`, the summary plots in
/// `out/plots`; returns the summary's path and the plots' stems.
pub(crate) fn finish(
    out: &Path,
    spec: &ExperimentSpec,
    scenarios: &[Scenario],
    table: &Results,
    quick: bool,
    plots: bool,
) -> Result<(PathBuf, Vec<PathBuf>)> {
    let path = out.join("summary.json");
    let json = report::summary(spec, scenarios, table, quick);
    let pretty = serde_json::to_string_pretty(&json).expect("a JSON value serialises");
    std::fs::write(&path, pretty + "\n").map_err(io_error(&path))?;
    let stems = if plots { report::summary_plots(scenarios, table, &out.join("plots"))? } else { Vec::new() };
    Ok((path, stems))
}

/// The (scenario, replicate) units of the run (those of `shard` only, when given) with at
/// least one row not in `done`; the rows of the run and how many of them are in `done`.
fn units(
    scenarios: &[Scenario],
    replicates: usize,
    shard: Option<Shard>,
    done: &Done,
) -> (Vec<(usize, usize)>, usize, usize) {
    let (mut units, mut total, mut resumed) = (Vec::new(), 0, 0);
    let is_done = |s: &str, r: usize, e: &str| done.contains(s, r, e);
    for (si, s) in scenarios.iter().enumerate() {
        for r in 0..replicates {
            if shard.is_some_and(|sh| !sh.owns(si, r, scenarios.len())) {
                continue;
            }
            let missing = s.estimators.iter().filter(|e| !is_done(&s.name, r, &e.label)).count();
            total += s.estimators.len();
            resumed += s.estimators.len() - missing;
            if missing > 0 {
                units.push((si, r));
            }
        }
    }
    (units, total, resumed)
}

/// Runs the experiment `spec` with `options`: every (scenario, replicate, estimator) row is
/// appended to `out/results.csv` when its estimator finishes (flushed), `progress` is called
/// after each row, and at the end `summary.json` and the plots are written.
///
/// A method's error is a row with status `error` and the message; a non-converged estimate is
/// a row with its status. With `resume`, the rows of an earlier run of the same spec and seed
/// in `out` are kept (a truncated last line is dropped) and only the missing rows are computed.
///
/// With [`RunOptions::shard`], only the shard's (scenario, replicate) units run, into
/// `out/shards/I-of-N/` ([`super::shard`]: the assignment, the files); their rows are those
/// an unsharded run writes for them, and [`super::shard::merge`] writes the summary.
///
/// Errors: an invalid spec (naming the key), an existing `results.csv` without `resume`, a
/// resumed folder of another spec, a folder another run is writing, I/O, a simulation error.
pub fn run(
    experiment: &Experiment,
    options: &RunOptions,
    progress: &(dyn Fn(&Progress) + Sync),
) -> Result<RunReport> {
    let mut experiment = experiment.clone();
    if let Some(r) = options.replicates {
        experiment = experiment.with_replicates(r);
    }
    if let Some(s) = options.seed {
        experiment = experiment.with_seed(s);
    }
    let scenarios = experiment.scenarios(options.quick)?;
    let spec = scenarios[0].spec.clone();
    let replicates = spec.replicates;
    let (metric_cols, theta_cols) = columns(&scenarios);
    let header = header(&metric_cols, &theta_cols);
    let folder = options.shard.map_or_else(|| options.out.clone(), |s| s.folder(&options.out));
    let Output { results, file, done } =
        open_output(&folder, &header, &experiment.resume_key(options.quick), options.resume)?;
    if let Some(s) = options.shard {
        shard::write_record(&folder, s, replicates)?;
    }
    let done = Done::new(&done);
    let (units, total, resumed) = units(&scenarios, replicates, options.shard, &done);
    let shared = Shared {
        scenarios: &scenarios,
        seed: spec.seed,
        metric_cols: &metric_cols,
        theta_cols: &theta_cols,
        done: &done,
        options,
        results: &results,
        writer: Mutex::new(file),
        written: AtomicUsize::new(0),
        stop: AtomicBool::new(false),
        plots: Mutex::new(Vec::new()),
        looks: report::looks(&scenarios),
        start: Instant::now(),
        total,
        resumed,
    };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(options.jobs).build().map_err(|e| {
        Error::InvalidOption {
            name: "--jobs".into(),
            reason: format!("cannot start the worker threads: {e}"),
        }
    })?;
    pool.install(|| units.par_iter().try_for_each(|&(si, r)| shared.unit(si, r, progress)))?;
    let written = shared.written.into_inner();
    let mut plots = shared.plots.into_inner().unwrap_or_else(std::sync::PoisonError::into_inner);
    let complete = resumed + written == total;
    let mut summary = None;
    if complete && options.shard.is_none() {
        let text = std::fs::read_to_string(&results).map_err(io_error(&results))?;
        let mut table = report::parse_results(&text, &results)?;
        // A resumed run may ask for fewer replicates than were computed: summarise its own.
        table.rows.retain(|r| r.replicate < replicates && scenarios.iter().any(|s| s.name == r.scenario));
        let (path, stems) = finish(&options.out, &spec, &scenarios, &table, options.quick, options.plots)?;
        summary = Some(path);
        plots.extend(stems);
    }
    plots.sort();
    Ok(RunReport { written, resumed, total, complete, results, summary, plots })
}
