//! The Monte Carlo runner: replicates in parallel, one `results.csv` row per (scenario,
//! replicate, estimator) appended as soon as the estimator finishes, resumable.

use std::fs::OpenOptions;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use rand::rngs::StdRng;
use rand::SeedableRng;
use rayon::prelude::*;

use super::report;
use super::spec::{Experiment, Metric, Scenario};
use crate::data::{Dataset, StatePath};
use crate::estimate::PathEstimate;
use crate::methods;
use crate::metrics;
use crate::simulate::{sample_measurements_at, simulate, SimulateOptions};
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
        }
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
    /// Method name.
    pub method: String,
    /// The estimate's status, or `error` when the method returned an error.
    pub status: String,
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
    /// Whether every row is present (false when stopped by `max_rows`).
    pub complete: bool,
    /// `results.csv`.
    pub results: PathBuf,
    /// `summary.json` (written when complete).
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
fn csv_line(fields: &[String]) -> String {
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
    fn fields(&self) -> Vec<String> {
        let mut f = vec![
            self.scenario.clone(),
            self.replicate.to_string(),
            self.estimator.clone(),
            self.method.clone(),
            self.status.clone(),
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
    let data = sample_measurements_at(&p.observation, &p.theta, &truth, n_noisy, &scenario.times, &mut rng)?;
    Ok((truth, data))
}

/// The metrics of `estimate` against the truth and the other estimates of the replicate
/// (`refs`: label → estimate), in the order of `metric_cols`; NaN (with a message) where a
/// metric cannot be computed.
fn metric_values(
    scenario: &Scenario,
    metric_cols: &[String],
    estimate: &StatePath,
    truth: &StatePath,
    refs: &[(String, PathEstimate)],
    message: &mut Vec<String>,
) -> Vec<f64> {
    let mut values = vec![f64::NAN; metric_cols.len()];
    for m in &scenario.metrics {
        let value = match m {
            Metric::Ise => metrics::ise(estimate, truth, None),
            // Over the estimate's times: the truth is interpolated there.
            Metric::Rmse => metrics::rmse(truth, estimate, None),
            Metric::RmseTo(label) => match refs.iter().find(|(l, _)| l == label) {
                Some((_, r)) => metrics::rmse(&r.path, estimate, None),
                None => Err(Error::InvalidOption {
                    name: m.column(),
                    reason: format!("the estimate of `{label}` is not available"),
                }),
            },
            Metric::WellSide(state) => {
                let state = state.clone().unwrap_or_else(|| truth.names[0].clone());
                metrics::same_side_fraction(estimate, truth, &state, 0.0)
            }
        };
        let col = metric_cols.iter().position(|c| *c == m.column()).expect("every metric has a column");
        match value {
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

/// Runs the experiment `spec` with `options`: every (scenario, replicate, estimator) row is
/// appended to `out/results.csv` when its estimator finishes (flushed), `progress` is called
/// after each row, and at the end `summary.json` and the plots are written.
///
/// A method's error is a row with status `error` and the message; a non-converged estimate is
/// a row with its status. With `resume`, the rows of an earlier run of the same spec and seed
/// in `out` are kept (a truncated last line is dropped) and only the missing rows are computed.
///
/// Errors: an invalid spec (naming the key), an existing `results.csv` without `resume`, a
/// resumed folder of another spec, I/O, a simulation error.
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
    let seed = spec.seed;
    let (metric_cols, theta_cols) = columns(&scenarios);
    let header = header(&metric_cols, &theta_cols);
    let out = &options.out;
    std::fs::create_dir_all(out).map_err(|source| Error::Io { path: out.clone(), source })?;
    let results = out.join("results.csv");
    let run_json = out.join("run.json");
    let print = experiment.resume_key(options.quick);
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| Error::Io { path: path.clone(), source }
    };
    let done_rows = if results.exists() {
        if !options.resume {
            return Err(Error::InvalidOption {
                name: "--out".into(),
                reason: format!(
                    "{} exists; pass --resume to continue it, or choose another folder",
                    results.display()
                ),
            });
        }
        let recorded = std::fs::read_to_string(&run_json).unwrap_or_default();
        if recorded.trim() != print {
            return Err(Error::InvalidOption {
                name: "--resume".into(),
                reason: format!(
                    "{} was written by another spec, seed or --quick setting; use another output folder",
                    out.display()
                ),
            });
        }
        read_done(&results, &header)?
    } else {
        Vec::new()
    };
    std::fs::write(&run_json, format!("{print}\n")).map_err(io(&run_json))?;
    let mut file = OpenOptions::new().create(true).append(true).open(&results).map_err(io(&results))?;
    if done_rows.is_empty() && file.metadata().map(|m| m.len()).unwrap_or(0) == 0 {
        file.write_all(csv_line(&header).as_bytes()).map_err(io(&results))?;
        file.flush().map_err(io(&results))?;
    }
    let is_done = |s: &str, r: usize, e: &str| {
        done_rows.iter().any(|row| row.scenario == s && row.replicate == r && row.estimator == e)
    };
    // The work: (scenario, replicate) units with at least one missing row.
    let mut units = Vec::new();
    let mut total = 0;
    let mut resumed = 0;
    for (si, s) in scenarios.iter().enumerate() {
        for r in 0..replicates {
            let missing = s.estimators.iter().filter(|e| !is_done(&s.name, r, &e.label)).count();
            total += s.estimators.len();
            resumed += s.estimators.len() - missing;
            if missing > 0 {
                units.push((si, r));
            }
        }
    }
    let start = Instant::now();
    let writer = Mutex::new(file);
    let written = AtomicUsize::new(0);
    let stop = AtomicBool::new(false);
    let plots_written = Mutex::new(Vec::new());
    let work = |&(si, r): &(usize, usize)| -> Result<()> {
        if stop.load(Ordering::SeqCst) {
            return Ok(());
        }
        let scenario = &scenarios[si];
        let unit_seed = replicate_seed(seed, &scenario.name, r);
        let (truth, data) = simulate_replicate(scenario, unit_seed)?;
        // References of `rmse-to` first, then the estimators in order.
        let refs: Vec<&str> = scenario
            .metrics
            .iter()
            .filter_map(|m| if let Metric::RmseTo(l) = m { Some(l.as_str()) } else { None })
            .collect();
        let mut order: Vec<usize> = (0..scenario.estimators.len()).collect();
        order.sort_by_key(|&i| !refs.contains(&scenario.estimators[i].label.as_str()));
        // Phase 1 runs the references (whose rows wait until all references are known, so that
        // they too get their distances to each other); phase 2 the others, each row written as
        // soon as its estimator finishes.
        let mut estimates: Vec<(String, PathEstimate)> = Vec::new();
        let mut pending: Vec<(usize, std::result::Result<PathEstimate, String>)> = Vec::new();
        let n_refs = order.iter().filter(|&&i| refs.contains(&scenario.estimators[i].label.as_str())).count();
        for (position, &i) in order.iter().enumerate() {
            let e = &scenario.estimators[i];
            let is_ref = position < n_refs;
            if !is_ref && is_done(&scenario.name, r, &e.label) {
                continue;
            }
            if stop.load(Ordering::SeqCst) {
                return Ok(());
            }
            let mut method_options = e.options.clone();
            method_options.seed = mix(unit_seed ^ mix(e.options.seed ^ fnv(&e.label)));
            let problem = e.preset.problem(&data, &e.estimate);
            let outcome = methods::run(e.method, &problem, &method_options)
                .map(|run| run.estimate)
                .map_err(|err| err.to_string());
            if let Ok(est) = &outcome {
                estimates.push((e.label.clone(), est.clone()));
            }
            pending.push((i, outcome));
            if is_ref && position + 1 < n_refs {
                continue;
            }
            for (i, outcome) in pending.drain(..) {
                let e = &scenario.estimators[i];
                if is_done(&scenario.name, r, &e.label) {
                    continue;
                }
                let names = e.preset.param_names();
                let mut row = Row {
                    scenario: scenario.name.clone(),
                    replicate: r,
                    estimator: e.label.clone(),
                    method: e.method.name().to_string(),
                    status: "error".into(),
                    iterations: 0,
                    solve_seconds: 0.0,
                    metrics: vec![f64::NAN; metric_cols.len()],
                    theta: vec![None; theta_cols.len()],
                    message: String::new(),
                };
                match outcome {
                    Ok(est) => {
                        let mut messages = Vec::new();
                        row.status = est.status.name().to_string();
                        row.iterations = est.iterations;
                        row.solve_seconds = est.solve_seconds;
                        row.metrics = metric_values(
                            scenario,
                            &metric_cols,
                            &est.path,
                            &truth,
                            &estimates,
                            &mut messages,
                        );
                        for &k in &e.estimate {
                            let c = theta_cols
                                .iter()
                                .position(|n| *n == names[k])
                                .expect("a column per parameter");
                            row.theta[c] = Some(est.theta[k]);
                        }
                        row.message = messages.join("; ");
                    }
                    Err(message) => row.message = message,
                }
                let mut f = writer.lock().map_err(|_| Error::InvalidOption {
                    name: "results".into(),
                    reason: "a worker panicked while writing".into(),
                })?;
                if let Some(max) = options.max_rows {
                    if written.load(Ordering::SeqCst) >= max {
                        stop.store(true, Ordering::SeqCst);
                        return Ok(());
                    }
                }
                f.write_all(csv_line(&row.fields()).as_bytes()).map_err(io(&results))?;
                f.flush().map_err(io(&results))?;
                let n = written.fetch_add(1, Ordering::SeqCst) + 1;
                progress(&Progress {
                    done: resumed + n,
                    total,
                    resumed,
                    elapsed: start.elapsed().as_secs_f64(),
                    row,
                });
            }
        }
        if r == 0 && options.plots {
            let stem = out.join("plots").join(format!("paths_{}", report::file_name(&scenario.name)));
            report::path_plot(scenario, &truth, &data, &estimates, &stem)?;
            plots_written.lock().map(|mut v| v.push(stem)).ok();
        }
        Ok(())
    };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(options.jobs).build().map_err(|e| {
        Error::InvalidOption {
            name: "--jobs".into(),
            reason: format!("cannot start the worker threads: {e}"),
        }
    })?;
    pool.install(|| units.par_iter().try_for_each(work))?;
    let written = written.into_inner();
    let mut plots = plots_written.into_inner().unwrap_or_default();
    let complete = resumed + written == total;
    let mut summary = None;
    if complete {
        let text = std::fs::read_to_string(&results).map_err(io(&results))?;
        let mut table = report::parse_results(&text, &results)?;
        // A resumed run may ask for fewer replicates than were computed: summarise its own.
        table.rows.retain(|r| r.replicate < replicates && scenarios.iter().any(|s| s.name == r.scenario));
        let path = out.join("summary.json");
        let json = report::summary(&spec, &scenarios, &table, options.quick);
        let pretty = serde_json::to_string_pretty(&json).expect("a JSON value serialises");
        std::fs::write(&path, pretty + "\n").map_err(io(&path))?;
        summary = Some(path);
        if options.plots {
            plots.extend(report::summary_plots(&scenarios, &table, &out.join("plots"))?);
        }
    }
    plots.sort();
    Ok(RunReport { written, resumed, total, complete, results, summary, plots })
}
