//! `onsager estimate`: every method takes the same model flags and writes the same path CSV
//! and JSON report (DESIGN.md, "Data formats").

use std::path::PathBuf;

use clap::Args;

use onsager::action::mean_optimal::DualDetails;
use onsager::action::GridSpec;
use onsager::data::Dataset;
use onsager::estimate::{EstimationProblem, PathEstimate};
use onsager::estimator::{keep_set_parameters, options_from_pairs, Estimator, Method};
use onsager::model::library::{Model, Preset};
use onsager::model::observation::StateMeasurement;
use onsager::model::Sde;
use onsager::path::Transcription;
use onsager::{Result, Status};

use super::{create_parent, LimitArgs, ModelArgs};

/// Parses `--method` (the names of [`Method`]).
pub fn parse_method(s: &str) -> std::result::Result<Method, String> {
    s.parse::<Method>().map_err(|e| e.to_string())
}

/// Parses `--grid` (of `estimate` and `compare`).
pub(super) fn parse_grid(s: &str) -> std::result::Result<GridSpec, String> {
    GridSpec::parse(s).map_err(|e| e.to_string())
}

/// Parses `--transcription`.
fn parse_transcription(s: &str) -> std::result::Result<Transcription, String> {
    Transcription::parse(s).map_err(|e| e.to_string())
}

/// Parses `--option NAME=VALUE`.
fn parse_pair(s: &str) -> std::result::Result<(String, String), String> {
    match s.split_once('=') {
        Some((k, v)) if !k.trim().is_empty() => Ok((k.trim().to_string(), v.trim().to_string())),
        _ => Err(format!("expected NAME=VALUE, got `{s}`")),
    }
}

/// The `--method` help: every method with its description and its options.
pub fn methods_help() -> String {
    let mut h = String::from("The estimator (its options in brackets, set with --option NAME=VALUE):");
    for &m in Method::ALL {
        h.push_str(&format!(
            "\n  {:<19} {}\n  {:<19} [{}]",
            m.name(),
            m.description(),
            "",
            Estimator::option_names(m).join(", ")
        ));
    }
    h
}

/// Flags of `onsager estimate`.
#[derive(Args, Debug, Clone)]
pub struct EstimateArgs {
    #[command(flatten)]
    pub model: ModelArgs,
    /// Measurements CSV (`t,<outputs>`).
    #[arg(long)]
    pub data: PathBuf,
    /// The estimator (see `--help` for the list).
    #[arg(long, value_parser = parse_method, long_help = methods_help())]
    pub method: Method,
    /// An option of the estimator, `NAME=VALUE` (repeatable; nested options with a dotted name,
    /// `dual.max_iterations=100`; the names are listed under `--method` in `--help` and in
    /// docs/). The flags below are shorthands for the common ones.
    #[arg(long = "option", value_name = "NAME=VALUE", value_parser = parse_pair)]
    pub options: Vec<(String, String)>,
    /// Parameters to estimate, comma-separated names (methods that estimate parameters).
    #[arg(long, value_delimiter = ',')]
    pub estimate: Vec<String>,
    /// Grid of the exact methods: `lo=L,hi=H,cells=N` (two states: `lo=L1;L2,hi=H1;H2,cells=N1;N2`; three likewise).
    #[arg(long, value_parser = parse_grid)]
    pub grid: Option<GridSpec>,
    /// Time step of the method's time integration (grid, Kalman and particle methods).
    #[arg(long, allow_negative_numbers = true)]
    pub dt: Option<f64>,
    /// Number of particles of the particle smoother.
    #[arg(long)]
    pub particles: Option<usize>,
    /// Transcription of the path-space MAP methods: `hermite-simpson` (default),
    /// `trapezoidal` or `euler`.
    #[arg(long, value_parser = parse_transcription)]
    pub transcription: Option<Transcription>,
    /// Step of the path-space MAP transcription (default: measurement spacing / 20).
    #[arg(long, allow_negative_numbers = true)]
    pub step: Option<f64>,
    /// Degree of the exponential closure's moments, M = (x, …, x^D) (default 4).
    #[arg(long)]
    pub moments: Option<usize>,
    /// Gauss–Hermite points per dimension of the Gaussian closures (`gaussian-closure`,
    /// `ksp-closure`, `double-exp-closure`; at least 1). Default: automatic — for a drift the
    /// model declares polynomial of degree d, ⌊(d + 1)/2⌋ + 1 (exact; 3 for a cubic), otherwise
    /// 16 / 8 / 5 per dimension for 1 / 2 / 3 states.
    #[arg(long)]
    pub gaussian_points: Option<usize>,
    #[command(flatten)]
    pub limits: LimitArgs,
    /// Seed of the methods that draw random numbers.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Memory limit of the estimator's structures (`4GiB`, `512MB`, `unlimited`): the estimator
    /// estimates its memory from the problem's size and refuses above it.
    #[arg(long, default_value = "4GiB", value_name = "SIZE")]
    pub max_memory: onsager::estimate::MemoryLimit,
    /// Where to write the estimated path (`t,<states>,sd_<states>`).
    #[arg(long, default_value = "out/estimate.csv")]
    pub out: PathBuf,
    /// Where to write the JSON report.
    #[arg(long)]
    pub report: Option<PathBuf>,
}

impl EstimateArgs {
    /// The estimator of the flags: `--method` with the options of `--option` and of the
    /// shorthand flags; for `jme` and `mee`, the parameters set by `--param` are kept as the
    /// initial guess (`keep_initial`). Errors: an option the method does not have, a bad value,
    /// an option given twice.
    pub fn estimator(&self) -> Result<Estimator> {
        let mut pairs = self.options.clone();
        let mut flag = |name: &str, value: Option<String>| {
            if let Some(v) = value {
                pairs.push((name.to_string(), v));
            }
        };
        flag("grid", self.grid.as_ref().map(|g| g.to_string()));
        flag("dt", self.dt.map(|v| v.to_string()));
        flag("particles", self.particles.map(|v| v.to_string()));
        flag("transcription", self.transcription.map(|t| t.name().to_string()));
        flag("step", self.step.map(|v| v.to_string()));
        flag("moments", self.moments.map(|v| v.to_string()));
        flag("gaussian_points", self.gaussian_points.map(|v| v.to_string()));
        let mut options = options_from_pairs(pairs)?;
        let kept: Vec<String> = self
            .model
            .params
            .iter()
            .filter_map(|s| s.split_once('='))
            .map(|(k, _)| k.trim().to_string())
            .collect();
        keep_set_parameters(self.method, &mut options, &kept);
        Estimator::from_options(self.method, &options)?.with_limits(self.limits.limits())
    }
}

impl EstimateArgs {
    /// The shorthand flags given, as (the option they set, the flag).
    fn shorthands(&self) -> Vec<(&'static str, &'static str)> {
        [
            (self.grid.is_some(), "grid", "--grid"),
            (self.dt.is_some(), "dt", "--dt"),
            (self.particles.is_some(), "particles", "--particles"),
            (self.transcription.is_some(), "transcription", "--transcription"),
            (self.step.is_some(), "step", "--step"),
            (self.moments.is_some(), "moments", "--moments"),
            (self.gaussian_points.is_some(), "gaussian_points", "--gaussian-points"),
        ]
        .into_iter()
        .filter(|(given, _, _)| *given)
        .map(|(_, option, flag)| (option, flag))
        .collect()
    }

    /// `e` naming the flag the user typed where it is about an option a shorthand flag set.
    fn as_typed(&self, e: onsager::Error) -> onsager::Error {
        let table = self.shorthands();
        match e {
            onsager::Error::EstimatorOption { method, option, reason } => {
                let option =
                    table.iter().find(|(o, _)| *o == option).map_or(option, |(_, f)| (*f).to_string());
                onsager::Error::EstimatorOption { method, option, reason }
            }
            other => super::as_flags(other, &table),
        }
    }
}

/// The indices of the parameters named by `--estimate`.
pub fn parameter_indices(preset: &Preset, names: &[String]) -> Result<Vec<usize>> {
    names.iter().filter(|s| !s.trim().is_empty()).map(|name| preset.param_index(name.trim())).collect()
}

/// The estimation problem of the command line: a built-in model with the flags applied.
pub type CliProblem<'a> = EstimationProblem<'a, Model, StateMeasurement>;

/// Builds the problem pieces that the [`EstimationProblem`] borrows.
pub struct Setup {
    /// The configured preset.
    pub preset: Preset,
    /// The data, columns in the model's output order.
    pub data: Dataset,
    /// Indices of the parameters to estimate.
    pub estimate: Vec<usize>,
}

impl Setup {
    /// Reads the data and resolves the flags.
    pub fn new(args: &EstimateArgs) -> Result<Setup> {
        let mut preset = args.model.preset()?;
        let data = super::read_data(&args.data, &mut preset, args.model.likelihood.is_some())?;
        let estimate = parameter_indices(&preset, &args.estimate)?;
        Ok(Setup { preset, data, estimate })
    }

    /// The problem, borrowing from `self`.
    pub fn problem(&self) -> CliProblem<'_> {
        self.preset.problem(&self.data, &self.estimate)
    }
}

/// Runs `onsager estimate`; `Ok(false)` when the estimator did not succeed (the CLI then exits
/// non-zero after writing what it has).
pub fn run(args: &EstimateArgs) -> Result<bool> {
    let estimator = args.estimator().map_err(|e| args.as_typed(e))?;
    let setup = Setup::new(args)?;
    let problem = EstimationProblem { seed: args.seed, max_memory: args.max_memory, ..setup.problem() };
    problem.validate()?;
    if let Some(note) = args.limits.ignored_note(&estimator) {
        outln!("note: {note}");
    }
    let run = super::progress::run_with_progress(&estimator, &problem).map_err(|e| args.as_typed(e))?;
    for note in &run.notes {
        outln!("note: {note}");
    }
    let est = run.estimate;
    print_summary(&est, &problem);
    let partial = est.partial();
    let out = match &partial {
        // A partial path is not written where a complete one is expected.
        Some(why) => {
            outln!("partial: {why}");
            args.out.with_extension("partial.csv")
        }
        None => args.out.clone(),
    };
    create_parent(&out)?;
    est.path.write_csv(&out)?;
    match partial {
        Some(_) => outln!("wrote the partial path to {} (not to {})", out.display(), args.out.display()),
        None => outln!("wrote the estimated path to {}", out.display()),
    }
    if let Some(report) = &args.report {
        create_parent(report)?;
        est.write_report(report)?;
        outln!("wrote the report to {}", report.display());
    }
    Ok(est.status.is_success())
}

/// A closure on a fixed box: the box per state, where its density reaches the box's edge and
/// what a wider box showed, how many times it was widened, and the quadrature check's verdict.
fn print_closure_box(est: &PathEstimate, states: &[String]) {
    let Some(details) = est.details.get::<DualDetails>() else { return };
    if let Some(domain) = &details.domain {
        let boxes: Vec<String> =
            states.iter().zip(domain).map(|(name, (a, b))| format!("{name} [{a:.4}, {b:.4}]")).collect();
        outln!("  box (domain): {}", boxes.join(", "));
    }
    if let Some(e) = &details.edge {
        let moved = |s: f64| format!("on a wider box the means move by {s:.2e}");
        let verdict = match (est.status, details.edge_shift) {
            (Status::GridEdge, Some(s)) => format!("{}; widen `domain` or raise `widen`", moved(s)),
            (Status::GridEdge, None) => "widen `domain` or raise `widen`".to_string(),
            (status, Some(s)) if status.is_success() => format!("{}, within the tolerance: kept", moved(s)),
            (_, Some(s)) => moved(s),
            (_, None) => "the wider box's sweep failed".to_string(),
        };
        outln!(
            "  box edge: {:.1e} of the density's mass near the edge of `{}` at t = {}; {verdict}",
            e.mass,
            states[e.axis],
            e.time
        );
    }
    if details.widenings > 0 {
        outln!("  box widened {} time(s): the density reached its edge", details.widenings);
    }
    let Some(q) = &details.quadrature else { return };
    if q.accepted {
        let shift = q.shift.map_or(String::new(), |s| format!(": shift {s:.2e}"));
        outln!("  quadrature: {} (checked on {}{shift}, tolerance {})", q.nodes, q.checked_on, q.tolerance);
    } else if !matches!(est.status, Status::Unresolved | Status::GridEdge) {
        outln!("  quadrature: {} after {} refinement(s)", q.nodes, q.refinements);
    } else {
        let why = match q.shift {
            Some(s) => format!("the last moved the means by {s:.2e}, tolerance {}", q.tolerance),
            None => "a sweep failed on the coarser nodes or in the check".to_string(),
        };
        outln!(
            "  quadrature: {}, not checked: the refinements ran out ({}; {why}); raise `refine` or `panels`",
            q.nodes,
            q.refinements
        );
    }
}

fn print_summary(est: &PathEstimate, problem: &CliProblem<'_>) {
    outln!(
        "method {}: status {}, {} iterations, solve {:.3} s",
        est.method,
        est.status,
        est.iterations,
        est.solve_seconds
    );
    if !est.status.is_success() {
        for (key, why) in est.details.failure_reasons() {
            outln!("  {}: {why}", key.replace('_', " "));
        }
    }
    print_closure_box(est, &problem.sde.state_names());
    let names = problem.sde.param_names();
    for (k, &i) in est.estimated.iter().enumerate() {
        let sd = est.theta_sd.as_ref().map_or(String::new(), |sd| format!(" ± {:.4}", sd[k]));
        outln!("  {} = {:.6}{sd}", names[i], est.theta[i]);
    }
}
