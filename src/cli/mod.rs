//! The subcommands of the `onsager` binary. Output goes to stdout here, never in the library.

pub mod compare;
pub mod estimate;
pub mod experiment;
pub mod progress;
pub mod simulate;

use std::path::{Path, PathBuf};

use clap::Args;

use onsager::data::continuous::ContinuousRecord;
use onsager::data::{Dataset, StatePath};
use onsager::estimator::{Estimator, IterationLimits};
use onsager::model::library::{self, Preset};
use onsager::model::observation::Noise;
use onsager::model::prior::Prior;
use onsager::model::{Observation, Sde};
use onsager::{Error, Result};

/// `--max-iterations` and `--tolerance` of `estimate` and `compare`.
#[derive(Args, Debug, Clone, Default)]
pub struct LimitArgs {
    /// Iteration limit of an iterating estimator (at least 1): the interior-point solver of jme,
    /// mee, ksp-closure and double-exp-closure, the dual's Newton steps of gaussian-closure,
    /// exp-closure and mean-optimal, BFGS of pem. The others do not iterate and ignore it (with
    /// a note). Reaching it is the status `max-iterations` (exit code 2).
    #[arg(long, value_name = "N", value_parser = parse_max_iterations)]
    pub max_iterations: Option<usize>,
    /// Convergence tolerance of an iterating estimator (positive), in its own measure: the
    /// interior-point solver's scaled optimality error (jme, mee, ksp-closure,
    /// double-exp-closure; default 1e-8, 1e-9 for the closures), the dual's optimality residual
    /// (gaussian-closure, exp-closure, mean-optimal; default 1e-9), pem's relative gradient
    /// (default 1e-8).
    #[arg(long, value_name = "TOL", value_parser = parse_tolerance, allow_negative_numbers = true)]
    pub tolerance: Option<f64>,
}

impl LimitArgs {
    /// The limits of the flags.
    pub fn limits(&self) -> IterationLimits {
        IterationLimits { max_iterations: self.max_iterations, tolerance: self.tolerance }
    }

    /// The note for `estimator` when the flags are set and it does not iterate.
    pub fn ignored_note(&self, estimator: &Estimator) -> Option<String> {
        (!self.limits().is_empty() && !estimator.method().iterates()).then(|| {
            format!(
                "`{}` does not iterate: --max-iterations and --tolerance do not apply to it",
                estimator.name()
            )
        })
    }
}

/// Parses `--max-iterations`: a whole number of at least 1.
fn parse_max_iterations(s: &str) -> std::result::Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(0) => Err("must be at least 1".into()),
        Ok(n) => Ok(n),
        Err(_) => Err(format!("expected a whole number of at least 1, got `{s}`")),
    }
}

/// Parses `--tolerance`: a positive finite number.
fn parse_tolerance(s: &str) -> std::result::Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("expected a positive finite number, got `{s}`")),
    }
}

/// The model flags every subcommand takes (DESIGN.md, "Data formats").
#[derive(Args, Debug, Clone)]
pub struct ModelArgs {
    /// Built-in model name (see `onsager models`).
    #[arg(long, default_value = "double-well")]
    pub model: String,
    /// A model file (TOML; see docs/models.md, "Models in a file") instead of a built-in
    /// model.
    #[arg(long, value_name = "PATH", conflicts_with = "model")]
    pub model_file: Option<PathBuf>,
    /// Parameter value `NAME=VALUE`; repeatable.
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// Measurement model, e.g. `gaussian:sigma=0.1`, `gaussian:sigma=sigma_y` (a parameter),
    /// `student-t:nu=4,scale=0.5`, `mixture:p=0.25,sigma=0.5,sigma_outlier=3`,
    /// `quantized:sigma=sigma_y,bit=0.05`, `laplace:scale=0.2` (default: the model's).
    #[arg(long)]
    pub likelihood: Option<String>,
    /// Prior of the initial state (noisy then clean states): `flat`,
    /// `gaussian:mean=M1;M2,sd=S1;S2`, or per state `NAME=SPEC` with SPEC as in
    /// `normal:0,0.4`, `gamma:1.1,10`, `lognormal:0,1`, `flat`; repeatable
    /// (default: the model's).
    #[arg(long = "x0-prior", value_name = "SPEC")]
    pub x0_prior: Vec<String>,
}

fn parse_assignment(s: &str, flag: &str) -> Result<(String, String)> {
    match s.split_once('=') {
        Some((k, v)) if !k.trim().is_empty() => Ok((k.trim().to_string(), v.trim().to_string())),
        _ => {
            Err(Error::InvalidOption { name: flag.into(), reason: format!("expected NAME=VALUE, got `{s}`") })
        }
    }
}

fn parse_number(v: &str, flag: &str, what: &str) -> Result<f64> {
    let x: f64 = v.trim().parse().map_err(|_| Error::InvalidOption {
        name: flag.into(),
        reason: format!("cannot parse `{v}` as a number for {what}"),
    })?;
    if !x.is_finite() {
        return Err(Error::InvalidOption { name: flag.into(), reason: format!("{what} must be finite") });
    }
    Ok(x)
}

/// An error of a prior's text or values as an error of `--x0-prior` (the prior's own field,
/// e.g. `prior.sd`, in the reason).
fn x0_flag(e: Error) -> Error {
    match e {
        Error::InvalidOption { name, reason } => {
            let field = name.strip_prefix("prior.").unwrap_or(&name);
            Error::InvalidOption { name: "--x0-prior".into(), reason: format!("{field} {reason}") }
        }
        other => other,
    }
}

/// Parses one `--x0-prior` flag into (state index, prior) pairs for `names` (noisy then clean).
fn parse_initial_prior(spec: &str, names: &[String]) -> Result<Vec<(usize, Prior)>> {
    let flag = "--x0-prior";
    let head = spec.split(':').next().unwrap_or("");
    if head.contains('=') {
        // Per state: NAME=SPEC.
        let (k, v) = parse_assignment(spec, flag)?;
        let i = names.iter().position(|n| *n == k).ok_or_else(|| Error::UnknownName {
            kind: "state".into(),
            name: k.clone(),
            known: names.to_vec(),
        })?;
        return Ok(vec![(i, Prior::parse(&v).and_then(|p| p.validate().map(|()| p)).map_err(x0_flag)?)]);
    }
    if spec.trim() == "flat" {
        return Ok((0..names.len()).map(|i| (i, Prior::flat())).collect());
    }
    // gaussian:mean=M1;M2,sd=S1;S2
    let rest = spec.strip_prefix("gaussian:").or_else(|| spec.strip_prefix("normal:")).ok_or_else(|| {
        Error::InvalidOption {
            name: flag.into(),
            reason: format!("`{spec}`: expected `flat`, `gaussian:mean=M1;M2,sd=S1;S2` or `STATE=SPEC`"),
        }
    })?;
    let (mut mean, mut sd) = (None, None);
    for part in rest.split(',') {
        let (k, v) = parse_assignment(part, flag)?;
        let values = v.split(';').map(|x| parse_number(x, flag, &k)).collect::<Result<Vec<f64>>>()?;
        if values.len() != names.len() {
            return Err(Error::InvalidOption {
                name: flag.into(),
                reason: format!(
                    "`{k}` has {} values for the {} states {}",
                    values.len(),
                    names.len(),
                    names.join(", ")
                ),
            });
        }
        match k.as_str() {
            "mean" => mean = Some(values),
            "sd" => sd = Some(values),
            _ => {
                return Err(Error::UnknownName {
                    kind: "x0-prior key".into(),
                    name: k,
                    known: vec!["mean".into(), "sd".into()],
                })
            }
        }
    }
    let (Some(mean), Some(sd)) = (mean, sd) else {
        return Err(Error::InvalidOption {
            name: flag.into(),
            reason: "both `mean` and `sd` are required".into(),
        });
    };
    let priors = mean.iter().zip(&sd).map(|(&m, &s)| Prior::gaussian(m, s)).collect::<Vec<_>>();
    for p in &priors {
        p.validate().map_err(x0_flag)?;
    }
    Ok(priors.into_iter().enumerate().collect())
}

impl ModelArgs {
    /// The model's preset (built-in, or read from `--model-file`) with the flags applied.
    pub fn preset(&self) -> Result<Preset> {
        let mut p = match &self.model_file {
            Some(path) => Preset::from_path(path)?,
            None => library::preset(&self.model)?,
        };
        let defaults = p.clone();
        let mut set = Vec::new();
        for s in &self.params {
            let (k, v) = parse_assignment(s, "--param")?;
            let value = parse_number(&v, "--param", &format!("parameter `{k}`"))?;
            p.set_param(&k, value)?;
            set.push((k, value));
        }
        if let Err(e) = p.model.diffusion_matrix(&p.theta) {
            return Err(blame_param(&p, &defaults, &set, e));
        }
        if let Some(spec) = &self.likelihood {
            p.observation.noise = Noise::parse(spec, &p.model.param_names())?;
        }
        let names = p.model.state_names();
        let n_noisy = p.model.dims().noisy;
        for spec in &self.x0_prior {
            for (i, prior) in parse_initial_prior(spec, &names)? {
                if i < n_noisy {
                    p.x0_prior[i] = prior;
                } else {
                    p.z0_prior[i - n_noisy] = prior;
                }
            }
        }
        p.validate()?;
        Ok(p)
    }
}

/// `e` with the library's option names replaced by the flags that set them (`table`: library
/// name, flag), so that messages name what the user types.
pub fn as_flags(e: Error, table: &[(&str, &str)]) -> Error {
    match e {
        Error::InvalidOption { name, reason } => {
            let name = table.iter().find(|(n, _)| *n == name).map_or(name, |(_, flag)| (*flag).to_string());
            Error::InvalidOption { name, reason }
        }
        other => other,
    }
}

/// After a diffusion G(θ) that the `--param` values break: the parameter to blame (the first
/// whose model default gives a valid G again), with what it must be.
fn blame_param(p: &Preset, defaults: &Preset, set: &[(String, f64)], e: Error) -> Error {
    if !matches!(e, Error::SingularDiffusion { .. }) {
        return e;
    }
    for (name, value) in set {
        let Ok(i) = p.param_index(name) else { continue };
        let mut theta = p.theta.clone();
        theta[i] = defaults.theta[i];
        if p.model.diffusion_matrix(&theta).is_ok() {
            return Error::InvalidOption {
                name: "--param".into(),
                reason: format!(
                    "`{name}={value}` makes the diffusion G(θ) non-finite or singular ({e}); `{name}` \
                     is a noise intensity here and must keep G defined, e.g. positive (default {})",
                    defaults.theta[i]
                ),
            };
        }
    }
    e
}

/// Reads `--data` for the outputs of `preset`. A continuous-time record (first line
/// `# continuous: R=…`, [`ContinuousRecord`]) is read as its cell averages, and the preset's
/// likelihood becomes the record's, Gaussian with variance R/Δ (a note says so);
/// `likelihood_flag` says whether `--likelihood` was given, which contradicts a record. Errors:
/// those of the readers; `--likelihood` with a record; a file without a single measured value
/// (every output missing on every line).
pub fn read_data(file: &Path, preset: &mut Preset, likelihood_flag: bool) -> Result<Dataset> {
    let outputs = preset.observation.output_names();
    let data = if ContinuousRecord::is_record_file(file)? {
        let record = ContinuousRecord::read_csv_for(file, &outputs)?;
        if likelihood_flag {
            return Err(Error::InvalidOption {
                name: "--likelihood".into(),
                reason: format!(
                    "{} is a continuous record, whose likelihood is set by its intensity: Gaussian with \
                     variance R/Δ = {}; drop --likelihood",
                    file.display(),
                    record.variance()
                ),
            });
        }
        preset.observation.noise = record.noise();
        outln!(
            "note: {} is a continuous record (R = {}, cells of {}): {} cell averages, each a measurement \
             with variance R/Δ = {}",
            file.display(),
            record.intensity,
            record.cell(),
            record.data.len(),
            record.variance()
        );
        record.data
    } else {
        Dataset::read_csv_for(file, &outputs)?
    };
    if data.values.iter().flatten().all(|v| v.is_nan()) {
        return Err(Error::InvalidOption {
            name: "--data".into(),
            reason: format!(
                "{} has no measured value: every output is missing (empty or NaN) on all its {} lines",
                file.display(),
                data.len()
            ),
        });
    }
    Ok(data)
}

/// A warning on stderr when the truth of `--truth` does not cover the data's time span (the
/// distances to it are then measured on the overlap only).
pub fn warn_if_truth_short(truth: &StatePath, file: &Path, data: &Dataset) {
    let (Some(&t0), Some(&t1), Some(&d0), Some(&d1)) =
        (truth.times.first(), truth.times.last(), data.times.first(), data.times.last())
    else {
        return;
    };
    let slack = 1e-9 * (d1 - d0).abs().max(1.0);
    if t0 > d0 + slack || t1 < d1 - slack {
        eprintln!(
            "warning: --truth {} covers t in [{t0}, {t1}] but the data span [{d0}, {d1}]; the \
             distances to the truth are measured where it is defined",
            file.display()
        );
    }
}

/// Creates the parent folder of an output file.
pub fn create_parent(file: &Path) -> Result<()> {
    if let Some(dir) = file.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|source| Error::Io { path: dir.to_path_buf(), source })?;
    }
    Ok(())
}

/// Flags of `onsager models`.
#[derive(Args, Debug, Clone)]
pub struct ModelsArgs {
    /// Check a model file and print what it declares, instead of listing the built-in models.
    #[arg(long, value_name = "PATH")]
    pub check: Option<PathBuf>,
}

/// `onsager models`: the built-in models, or the model a file declares (`--check`).
pub fn models(args: &ModelsArgs) -> Result<()> {
    match &args.check {
        Some(path) => {
            let p = Preset::from_path(path)?;
            outln!("{}: a valid model file", path.display());
            print_preset(&p);
            if let library::Model::Expression(m) = &p.model {
                print_expressions(m);
            }
        }
        None => {
            for name in library::NAMES {
                print_preset(&library::preset(name)?);
                outln!();
            }
        }
    }
    Ok(())
}

/// What an expression model derives from its expressions.
fn print_expressions(m: &onsager::model::expression::ExpressionModel) {
    let degree = m.drift_polynomial_degree().map_or("not a polynomial in the state".to_string(), |d| {
        format!("polynomial of degree {d} in the state")
    });
    let time = if m.drift_is_autonomous() { "does not read t" } else { "reads t" };
    outln!("  drift: {degree}, {time}");
    let g_only: Vec<String> = m
        .param_names()
        .into_iter()
        .enumerate()
        .filter(|(i, _)| !m.drift_uses_param(*i))
        .map(|(_, n)| n)
        .collect();
    if !g_only.is_empty() {
        outln!("  parameters not in the drift: {}", g_only.join(", "));
    }
    let [f, h, g, div, d] = m.tape_lengths();
    outln!("  compiled operations: drift {f}, clean drift {h}, G {g}, divergence {div}, derivatives {d}");
}

/// One model's declaration.
fn print_preset(p: &Preset) {
    {
        let m = &p.model;
        outln!("{} — {}", p.name, p.description);
        outln!("  source:  {}", p.source);
        outln!("  noisy states: {}", m.noisy_names().join(", "));
        let clean = m.clean_names();
        if !clean.is_empty() {
            outln!("  clean states: {}", clean.join(", "));
        }
        let params: Vec<String> =
            m.param_names().iter().zip(&p.theta).map(|(n, v)| format!("{n}={v}")).collect();
        outln!("  parameters:   {}", params.join(", "));
        let priors: Vec<String> = p
            .theta_prior
            .iter()
            .zip(m.param_names())
            .filter(|(pr, _)| pr.is_proper())
            .map(|(pr, n)| format!("{n}={pr}"))
            .collect();
        if !priors.is_empty() {
            outln!("  parameter priors: {}", priors.join(", "));
        }
        let names = m.state_names();
        let priors: Vec<String> =
            p.x0_prior.iter().chain(&p.z0_prior).zip(&names).map(|(pr, n)| format!("{n}={pr}")).collect();
        outln!("  initial-state prior: {}", priors.join(", "));
        outln!(
            "  outputs: {} ~ {}",
            p.observation.names.join(", "),
            p.observation.noise.describe(&m.param_names())
        );
        outln!(
            "  simulation: t_end={} dt={} first_sample={} sample_every={}",
            p.t_end,
            p.dt,
            p.first_sample,
            p.sample_every
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names() -> Vec<String> {
        vec!["x".into(), "z".into()]
    }

    #[test]
    fn initial_prior_syntaxes() {
        let v = parse_initial_prior("gaussian:mean=0;1,sd=0.4;0.5", &names()).unwrap();
        assert_eq!(v, vec![(0, Prior::gaussian(0.0, 0.4)), (1, Prior::gaussian(1.0, 0.5))]);
        let v = parse_initial_prior("z=normal:2,3", &names()).unwrap();
        assert_eq!(v, vec![(1, Prior::gaussian(2.0, 3.0))]);
        assert_eq!(parse_initial_prior("flat", &names()).unwrap().len(), 2);
        assert!(parse_initial_prior("gaussian:mean=0,sd=1", &names()).is_err());
        assert!(parse_initial_prior("gaussian:mean=0;0,sd=1;-1", &names()).is_err());
        assert!(parse_initial_prior("w=normal:0,1", &names()).is_err());
        assert!(parse_initial_prior("cauchy", &names()).is_err());
    }
}
