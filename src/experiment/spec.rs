//! The experiment specification (TOML) and its expansion into scenarios.
//!
//! A spec is parsed with serde (`deny_unknown_fields` everywhere), so an unknown key is an
//! error that names it; values are then checked against the model (parameter, state and
//! likelihood names, positive steps, …), each error naming its key (`measurements.every`,
//! `estimators.jme.estimate`, …).
//!
//! The `[grid]` table holds the scenario variables: each entry is a list of values, and the
//! scenarios are the cartesian product of the lists (in the order of the keys). An entry whose
//! key contains a dot overrides that spec key (`"simulation.t_end" = [50, 100, 200]`); a key in
//! an array of tables is addressed by the element's `label` (or `method`), e.g.
//! `"estimators.euler.options.step"`. An entry without a dot is a variable: every string of the
//! spec equal to `"{name}"` is replaced by the value (keeping its type) and every other
//! occurrence of `{name}` inside a string by the value's text, so that
//! `generate = "mixture:p={p_o},sigma=0.5,sigma_outlier={sigma_o}"` spans a grid of
//! likelihoods. A variable whose values are tables is a list of named settings: each table
//! holds a `name` (the scenario's value of the variable) and dotted-key overrides applied
//! together, e.g. `setting = [{ name = "dense", "measurements.every" = 0.2 }, { name = "sparse",
//! "measurements.every" = 0.5, "measurements.states" = ["x"] }]`. The `[quick]` table holds dotted-key overrides applied before the grid when the
//! experiment is run with `--quick` (fewer replicates, shorter horizons, a smaller grid).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::estimator::{Estimator, Method};
pub use crate::metrics::Metric;
use crate::model::library::{self, Preset, MAX_MEASUREMENT_TIMES};
use crate::model::observation::Noise;
use crate::model::prior::Prior;
use crate::model::Sde;
use crate::simulate::Scheme;
use crate::{Error, Result};

fn invalid(name: impl Into<String>, reason: impl Into<String>) -> Error {
    Error::InvalidOption { name: name.into(), reason: reason.into() }
}

fn one() -> usize {
    1
}

/// A Monte Carlo experiment: a model, how to simulate and measure it, the estimators to run on
/// each replicate, the metrics to record, and the grid of scenarios.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExperimentSpec {
    /// Name of the experiment (the default output folder is `out/experiments/NAME`).
    pub name: String,
    /// What the experiment shows.
    #[serde(default)]
    pub description: String,
    /// The paper's section and figure it reproduces.
    #[serde(default)]
    pub source: String,
    /// Replicates per scenario (≥ 1). Default 1.
    #[serde(default = "one")]
    pub replicates: usize,
    /// Seed of the whole experiment; replicate seeds derive from (seed, scenario, replicate).
    #[serde(default)]
    pub seed: u64,
    /// The model and its parameter overrides.
    pub model: ModelSpec,
    /// How the true path is simulated.
    #[serde(default)]
    pub simulation: SimulationSpec,
    /// How the measurements are generated and which likelihood the estimators use.
    #[serde(default)]
    pub measurements: MeasurementSpec,
    /// The estimators run on every replicate.
    pub estimators: Vec<EstimatorSpec>,
    /// The metrics of every row (see [`Metric::parse`]). θ̂, status, iterations and
    /// `solve_seconds` are always recorded.
    #[serde(default)]
    pub metrics: Vec<String>,
    /// Where the metrics against the truth are evaluated ([`MetricsAt`]; default `truth`, the
    /// simulation grid).
    #[serde(default, skip_serializing_if = "MetricsAt::is_default")]
    pub metrics_at: MetricsAt,
    /// Scenario variables: key → list of values (see the module documentation).
    #[serde(default)]
    pub grid: toml::Table,
    /// Dotted-key overrides of the quick version (`--quick`).
    #[serde(default)]
    pub quick: toml::Table,
}

/// The times at which the metrics against the truth (`rmse`, `ise`, `mean-sd`, `coverage`,
/// `well-side`) are evaluated; the estimate is interpolated linearly at them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MetricsAt {
    /// Every time of the simulated true path (its integration grid): the error over the whole
    /// window, including between the measurements.
    #[default]
    Truth,
    /// The measurement times only: the only times at which the particle and ensemble smoothers
    /// report their path, so on fast dynamics (Lorenz-63) it compares them with the Kalman
    /// smoothers and the closures on equal terms, without the error of interpolating between
    /// the measurements.
    Measurements,
}

impl MetricsAt {
    fn is_default(&self) -> bool {
        *self == MetricsAt::Truth
    }
}

/// The model of an experiment.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelSpec {
    /// A built-in model (see `onsager models`); give `name` or `file`.
    #[serde(default)]
    pub name: String,
    /// A model file (docs/models.md, "Models in a file") instead of a built-in model; a relative
    /// path is taken from the spec file's folder ([`Experiment::from_path`]), or from the
    /// working directory for a spec given as text ([`Experiment::from_toml`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<PathBuf>,
    /// Parameter values replacing the preset's nominal ones (name → value).
    #[serde(default)]
    pub params: BTreeMap<String, f64>,
}

/// The simulation of the true path (defaults: the model preset's).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimulationSpec {
    /// Integration scheme (default `ito-taylor-1.5`).
    pub scheme: Option<Scheme>,
    /// Integration step (default: the preset's).
    pub dt: Option<f64>,
    /// Final time; the path starts at t = 0 (default: the preset's).
    pub t_end: Option<f64>,
    /// Law of the initial state, per state name (prior syntax, e.g. `normal:0,0.1`); states not
    /// listed are drawn from the preset's initial-state prior.
    #[serde(default)]
    pub initial: BTreeMap<String, String>,
}

/// The measurements (defaults: the model preset's).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeasurementSpec {
    /// Spacing of the measurement times (default: the preset's).
    pub every: Option<f64>,
    /// First measurement time (default: the preset's).
    pub first: Option<f64>,
    /// Explicit measurement times (instead of `every` and `first`).
    pub times: Option<Vec<f64>>,
    /// Likelihood the measurements are drawn from (syntax of `--likelihood`; default: the
    /// preset's), or `continuous:R=<intensity>` for a continuous-time record of the measured
    /// states seen on cells of width `every` from t = 0 (the cell averages at the cell
    /// midpoints, [`crate::simulate::sample_record`]), whose likelihood is Gaussian with
    /// variance R/`every`.
    pub generate: Option<String>,
    /// Likelihood the estimators use (default: `generate`); an estimator may override it.
    pub estimate: Option<String>,
    /// Initial-state prior of the estimators, per state name (default: the preset's).
    #[serde(default)]
    pub x0_prior: BTreeMap<String, String>,
    /// The measured states by name (default: the preset's); an output keeps the preset's name
    /// when the preset measures that state, else it is named `y_STATE`.
    pub states: Option<Vec<String>>,
}

/// One estimator of an experiment: an [`Estimator`] as written (`method` and `options`, the
/// option names of the method's options type), with its label, the parameters it estimates and
/// its likelihood.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EstimatorSpec {
    /// The method (any [`Method`]).
    pub method: Method,
    /// Its name in the results (default: the method's name); unique within the experiment.
    pub label: Option<String>,
    /// Parameters it estimates (jme, mee, pem).
    #[serde(default)]
    pub estimate: Vec<String>,
    /// Likelihood of this estimator (default: `measurements.estimate`), e.g. a Gaussian one for
    /// the Kalman methods when the others use a Student-t likelihood.
    pub likelihood: Option<String>,
    /// The method's options (see [`Estimator`]).
    #[serde(default)]
    pub options: toml::Table,
}

impl EstimatorSpec {
    /// The label (default: the method's name).
    pub fn label(&self) -> String {
        self.label.clone().unwrap_or_else(|| self.method.name().to_string())
    }

    /// The estimator with its options. Errors: [`Error::InvalidOption`] named
    /// `estimators.LABEL.options.NAME` for an option the method does not have or a bad value.
    pub fn estimator(&self) -> Result<Estimator> {
        let options = match serde_json::to_value(&self.options) {
            Ok(serde_json::Value::Object(map)) => map,
            _ => serde_json::Map::new(),
        };
        Estimator::from_options(self.method, &options).map_err(|e| match e {
            Error::EstimatorOption { method, option, reason } => invalid(
                format!("estimators.{}.options.{option}", self.label()),
                format!("{reason} (`{method}`)"),
            ),
            other => other,
        })
    }
}

/// One estimator of a scenario, resolved against the model.
#[derive(Debug, Clone)]
pub struct ScenarioEstimator {
    /// Label in the results.
    pub label: String,
    /// The estimator with its options.
    pub estimator: Estimator,
    /// The preset the estimator sees: the scenario's model with the estimator's likelihood and
    /// the estimators' initial-state prior.
    pub preset: Preset,
    /// Indices of the estimated parameters.
    pub estimate: Vec<usize>,
}

/// One point of the grid, resolved: everything a replicate needs.
#[derive(Debug, Clone)]
pub struct Scenario {
    /// `default` without a grid, else `var=value` pairs joined by `,`.
    pub name: String,
    /// The grid values of this scenario (key, value as text).
    pub vars: Vec<(String, String)>,
    /// The spec with this scenario's overrides applied.
    pub spec: ExperimentSpec,
    /// The model preset with the parameter overrides, horizon, step and generating likelihood.
    pub truth: Preset,
    /// Law of the initial state (noisy then clean).
    pub initial: Vec<Prior>,
    /// Integration scheme.
    pub scheme: Scheme,
    /// Measurement times (of a continuous record: the cell midpoints).
    pub times: Vec<f64>,
    /// The intensity R of a continuous-time record (`measurements.generate =
    /// "continuous:R=…"`), on cells of width `truth.sample_every`; `None` for discrete
    /// measurements.
    pub continuous: Option<f64>,
    /// The estimators.
    pub estimators: Vec<ScenarioEstimator>,
    /// The metrics.
    pub metrics: Vec<Metric>,
}

/// An experiment as written: the TOML document, whose typed form ([`ExperimentSpec`]) exists
/// per scenario once the grid variables are substituted.
#[derive(Debug, Clone, PartialEq)]
pub struct Experiment {
    table: toml::Table,
    /// A seed replacing the document's (any u64; TOML integers stop at i64::MAX).
    seed: Option<u64>,
    /// A number of replicates replacing the document's and the quick version's.
    replicates: Option<usize>,
    /// The folder relative model-file paths start from (the spec file's), if any.
    base_dir: Option<PathBuf>,
    /// The spec of the first scenario of the full version (name, description, source,
    /// replicates, seed, estimators as written there).
    pub spec: ExperimentSpec,
}

impl Experiment {
    /// Parses a TOML document and checks every scenario of its full and quick versions.
    ///
    /// Errors: [`Error::InvalidOption`] naming the key at fault: the TOML parser's message
    /// (with the line) for a syntax error; `section.key` for an unknown key or an invalid value
    /// (e.g. `measurements.every`, `estimators.jme.options.step`).
    pub fn from_toml(text: &str) -> Result<Experiment> {
        Self::from_toml_in(text, None)
    }

    /// Reads a spec file: [`Experiment::from_toml`] on its text, with relative model-file paths
    /// (`[model] file`) taken from the spec file's folder. Errors: [`Error::Io`] when the file
    /// cannot be read, and those of [`Experiment::from_toml`].
    pub fn from_path(path: &Path) -> Result<Experiment> {
        let text =
            std::fs::read_to_string(path).map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
        let base = path.parent().map(Path::to_path_buf);
        Self::from_toml_in(&text, base)
    }

    fn from_toml_in(text: &str, base_dir: Option<PathBuf>) -> Result<Experiment> {
        let table: toml::Table =
            toml::from_str(text).map_err(|e| invalid("spec", e.to_string().trim_end().to_string()))?;
        let mut experiment =
            Experiment { table, seed: None, replicates: None, base_dir, spec: placeholder() };
        experiment.spec = experiment.scenarios(false)?.remove(0).spec;
        experiment.scenarios(true)?;
        Ok(experiment)
    }

    /// Replaces the number of replicates per scenario (of the full and the quick version).
    pub fn with_replicates(mut self, replicates: usize) -> Experiment {
        self.replicates = Some(replicates);
        self.spec.replicates = replicates;
        self
    }

    /// Replaces the seed.
    pub fn with_seed(mut self, seed: u64) -> Experiment {
        self.seed = Some(seed);
        self.spec.seed = seed;
        self
    }

    /// The seed: the replaced one, else the document's.
    pub fn seed(&self) -> u64 {
        self.seed.unwrap_or(self.spec.seed)
    }

    /// The document as TOML text (without the replaced seed or number of replicates).
    pub fn to_toml(&self) -> String {
        toml::to_string(&self.table).unwrap_or_default()
    }

    /// What a resumed run must share with the run it continues: the document without its
    /// number of replicates (which may grow), the seed and the version.
    pub(crate) fn resume_key(&self, quick: bool) -> String {
        let mut table = self.table.clone();
        table.remove("replicates");
        if let Some(toml::Value::Table(q)) = table.get_mut("quick") {
            q.remove("replicates");
        }
        let text = toml::to_string(&table).unwrap_or_default();
        serde_json::json!({ "spec": text, "seed": self.seed(), "quick": quick }).to_string()
    }

    /// The scenarios (after the `[quick]` overrides when `quick`), each resolved and checked.
    /// Errors name the key at fault.
    pub fn scenarios(&self, quick: bool) -> Result<Vec<Scenario>> {
        let mut raw = self.table.clone();
        let overrides = match raw.get("quick") {
            None => toml::Table::new(),
            Some(toml::Value::Table(t)) => t.clone(),
            Some(_) => return Err(invalid("quick", "must be a table of `\"dotted.key\" = value` overrides")),
        };
        if quick {
            for (key, value) in &overrides {
                if key == "quick" || key.starts_with("quick.") {
                    return Err(invalid(format!("quick.{key}"), "cannot override the quick table"));
                }
                set_path(&mut raw, key, value.clone()).map_err(|r| invalid(format!("quick.{key}"), r))?;
            }
        }
        let grid: Vec<(String, Vec<toml::Value>)> = match raw.remove("grid") {
            None => Vec::new(),
            Some(toml::Value::Table(t)) => t
                .into_iter()
                .map(|(k, v)| match v {
                    toml::Value::Array(a) if !a.is_empty() => Ok((k, a)),
                    _ => Err(invalid(format!("grid.{k}"), "must be a non-empty list of values")),
                })
                .collect::<Result<_>>()?,
            Some(_) => return Err(invalid("grid", "must be a table of `key = [values]`")),
        };
        raw.remove("quick");
        // Every variable must be used somewhere.
        let text = toml::to_string(&raw).unwrap_or_default();
        for (k, values) in &grid {
            let settings = values.iter().all(toml::Value::is_table);
            if !k.contains('.') && !settings && !text.contains(&format!("{{{k}}}")) {
                return Err(invalid(
                    format!("grid.{k}"),
                    format!("the variable `{{{k}}}` appears nowhere in the spec"),
                ));
            }
        }
        let mut scenarios = Vec::new();
        let count: usize = grid.iter().map(|(_, v)| v.len()).product();
        for index in 0..count {
            let mut rest = index;
            let mut picks = Vec::with_capacity(grid.len());
            for (k, values) in grid.iter().rev() {
                picks.push((k.clone(), values[rest % values.len()].clone()));
                rest /= values.len();
            }
            picks.reverse();
            let mut table = raw.clone();
            for (k, v) in &picks {
                if k.contains('.') {
                    set_path(&mut table, k, v.clone()).map_err(|r| invalid(format!("grid.{k}"), r))?;
                } else if let toml::Value::Table(setting) = v {
                    for (key, value) in setting.iter().filter(|(key, _)| *key != "name") {
                        set_path(&mut table, key, value.clone())
                            .map_err(|r| invalid(format!("grid.{k}.{key}"), r))?;
                    }
                } else {
                    substitute_table(&mut table, k, v);
                }
            }
            let vars: Vec<(String, String)> = picks.iter().map(|(k, v)| (k.clone(), value_text(v))).collect();
            let name = if vars.is_empty() {
                "default".to_string()
            } else {
                vars.iter().map(|(k, v)| format!("{k}={v}")).collect::<Vec<_>>().join(",")
            };
            let in_scenario = |e: Error| match e {
                Error::InvalidOption { name: key, reason } if !vars.is_empty() => {
                    invalid(key, format!("{reason} (scenario `{name}`)"))
                }
                other => other,
            };
            let mut spec = deserialize(&table).map_err(in_scenario)?;
            if let Some(seed) = self.seed {
                spec.seed = seed;
            }
            if let Some(r) = self.replicates {
                spec.replicates = r;
            }
            let base = self.base_dir.as_deref();
            scenarios.push(Scenario::resolve(name.clone(), vars.clone(), spec, base).map_err(in_scenario)?);
        }
        Ok(scenarios)
    }
}

fn placeholder() -> ExperimentSpec {
    ExperimentSpec {
        name: String::new(),
        description: String::new(),
        source: String::new(),
        replicates: 1,
        seed: 0,
        model: ModelSpec::default(),
        simulation: SimulationSpec::default(),
        measurements: MeasurementSpec::default(),
        estimators: Vec::new(),
        metrics: Vec::new(),
        metrics_at: MetricsAt::default(),
        grid: toml::Table::new(),
        quick: toml::Table::new(),
    }
}

fn de<T: serde::de::DeserializeOwned>(table: &toml::Table) -> std::result::Result<T, String> {
    T::deserialize(toml::Value::Table(table.clone())).map_err(|e| e.message().trim_end().to_string())
}

/// The first key of `table` that `T` rejects on its own (a missing field does not count), with
/// the message; `None` when each key alone is fine.
fn blame<T: serde::de::DeserializeOwned>(table: &toml::Table) -> Option<(String, String)> {
    table.iter().find_map(|(k, v)| {
        let single: toml::Table = [(k.clone(), v.clone())].into_iter().collect();
        match de::<T>(&single) {
            Err(m) if !m.starts_with("missing field") => Some((k.clone(), m)),
            _ => None,
        }
    })
}

/// The key of a section (`model`, `simulation`, `measurements`, an estimator, its `options`)
/// that its type rejects.
fn blame_section(section: &str, value: &toml::Value) -> Option<(String, String)> {
    let t = value.as_table()?;
    match section {
        "model" => blame::<ModelSpec>(t),
        "simulation" => blame::<SimulationSpec>(t),
        "measurements" => blame::<MeasurementSpec>(t),
        _ => blame::<EstimatorSpec>(t),
    }
}

/// Deserializes a scenario's table; on error, names the key at fault (`section.key`).
fn deserialize(table: &toml::Table) -> Result<ExperimentSpec> {
    let message = match de::<ExperimentSpec>(table) {
        Ok(spec) => return Ok(spec),
        Err(m) => m,
    };
    let Some((key, top)) = blame::<ExperimentSpec>(table) else { return Err(invalid("spec", message)) };
    let (name, reason) = match (key.as_str(), &table[&key]) {
        ("estimators", toml::Value::Array(items)) => items
            .iter()
            .enumerate()
            .find_map(|(i, item)| {
                let t = item.as_table()?;
                let label = ["label", "method"]
                    .iter()
                    .find_map(|k| t.get(*k).and_then(|v| v.as_str()).map(String::from))
                    .unwrap_or_else(|| i.to_string());
                if let Some((k, m)) = blame_section("estimator", item) {
                    return Some((format!("estimators.{label}.{k}"), m));
                }
                de::<EstimatorSpec>(t).err().map(|m| (format!("estimators.{label}"), m))
            })
            .unwrap_or((key.clone(), top)),
        (section @ ("model" | "simulation" | "measurements"), v) => match blame_section(section, v) {
            Some((k, m)) => (format!("{section}.{k}"), m),
            None => (key.clone(), top),
        },
        _ => (key.clone(), top),
    };
    Err(invalid(name, reason))
}

/// A value as text (strings without quotes; a setting of the grid by its `name`).
fn value_text(v: &toml::Value) -> String {
    match v {
        toml::Value::String(s) => s.clone(),
        toml::Value::Table(t) if t.contains_key("name") => value_text(&t["name"]),
        other => other.to_string(),
    }
}

fn substitute_table(table: &mut toml::Table, var: &str, value: &toml::Value) {
    for (_, v) in table.iter_mut() {
        substitute(v, var, value);
    }
}

fn substitute(v: &mut toml::Value, var: &str, value: &toml::Value) {
    let pattern = format!("{{{var}}}");
    match v {
        toml::Value::String(s) if *s == pattern => *v = value.clone(),
        toml::Value::String(s) => *s = s.replace(&pattern, &value_text(value)),
        toml::Value::Array(a) => a.iter_mut().for_each(|x| substitute(x, var, value)),
        toml::Value::Table(t) => substitute_table(t, var, value),
        _ => {}
    }
}

/// Sets `value` at the dotted `path` of `table`, creating tables on the way; an array element
/// is chosen by its index or by its `label` (else `method`).
fn set_path(table: &mut toml::Table, path: &str, value: toml::Value) -> std::result::Result<(), String> {
    let parts: Vec<&str> = path.split('.').collect();
    if parts.iter().any(|p| p.is_empty()) {
        return Err(format!("`{path}` is not a dotted key"));
    }
    let mut current = table;
    for (i, part) in parts.iter().enumerate() {
        let last = i + 1 == parts.len();
        if last {
            current.insert(part.to_string(), value);
            return Ok(());
        }
        let entry = current.entry(part.to_string()).or_insert_with(|| toml::Value::Table(toml::Table::new()));
        current = match entry {
            toml::Value::Table(t) => t,
            toml::Value::Array(items) => {
                let key = parts[i + 1];
                let pos = key.parse::<usize>().ok().filter(|&k| k < items.len()).or_else(|| {
                    items.iter().position(|item| {
                        let t = item.as_table();
                        let name = t.and_then(|t| t.get("label").or_else(|| t.get("method")));
                        name.and_then(|n| n.as_str()) == Some(key)
                    })
                });
                let Some(pos) = pos else {
                    return Err(format!("`{}` has no element `{key}`", parts[..=i].join(".")));
                };
                if i + 2 == parts.len() {
                    items[pos] = value;
                    return Ok(());
                }
                // Skip the element's key.
                let rest = parts[i + 2..].join(".");
                return match &mut items[pos] {
                    toml::Value::Table(t) => set_path(t, &rest, value),
                    _ => Err(format!("`{}` is not a table", parts[..=i + 1].join("."))),
                };
            }
            _ => return Err(format!("`{}` is not a table", parts[..=i].join("."))),
        };
    }
    Ok(())
}

fn positive(name: &str, v: f64) -> Result<f64> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(invalid(name, format!("must be positive and finite, got {v}")))
    }
}

/// The preset of `[model]`: the built-in `name`, or the model `file` (relative to `base_dir`).
fn model_preset(model: &ModelSpec, base_dir: Option<&Path>) -> Result<Preset> {
    match (&model.file, model.name.is_empty()) {
        (Some(_), false) => {
            Err(invalid("model", "give either `name` (a built-in model) or `file`, not both"))
        }
        (None, true) => Err(invalid("model", "give `name` (a built-in model) or `file` (a model file)")),
        (None, false) => library::preset(&model.name).map_err(|e| invalid("model.name", e.to_string())),
        (Some(file), true) => {
            let path = match base_dir {
                Some(dir) if file.is_relative() => dir.join(file),
                _ => file.clone(),
            };
            Preset::from_path(&path).map_err(|e| match e {
                e @ Error::ModelFile { .. } => e,
                other => invalid("model.file", other.to_string()),
            })
        }
    }
}

fn parse_noise(spec: &str, p: &Preset, key: &str) -> Result<Noise> {
    Noise::parse(spec, &p.model.param_names()).map_err(|e| match e {
        Error::InvalidOption { reason, .. } => invalid(key, reason),
        other => invalid(key, other.to_string()),
    })
}

fn parse_state_priors(map: &BTreeMap<String, String>, p: &Preset, key: &str) -> Result<Vec<Prior>> {
    let names = p.model.state_names();
    let mut priors: Vec<Prior> = p.x0_prior.iter().chain(&p.z0_prior).cloned().collect();
    for (state, text) in map {
        let i = names.iter().position(|n| n == state).ok_or_else(|| {
            invalid(format!("{key}.{state}"), format!("unknown state (known: {})", names.join(", ")))
        })?;
        priors[i] = Prior::parse(text).map_err(|e| invalid(format!("{key}.{state}"), e.to_string()))?;
    }
    Ok(priors)
}

/// The intensity R of `measurements.generate = "continuous:R=<value>"` (positive, finite); the
/// record's times are its cells', so `measurements.times` and `measurements.first` are errors.
fn parse_continuous(spec: &str, m: &MeasurementSpec) -> Result<f64> {
    let key = "measurements.generate";
    if m.times.is_some() || m.first.is_some() {
        return Err(invalid(
            key,
            "a continuous record covers [0, t_end] in cells of `measurements.every`; drop `times` and `first`",
        ));
    }
    let rest = spec.trim_start_matches("continuous:").trim();
    let value = rest
        .strip_prefix("R=")
        .ok_or_else(|| invalid(key, format!("`{spec}`: expected `continuous:R=<intensity>`")))?;
    match value.trim().parse::<f64>() {
        Ok(r) if r.is_finite() && r > 0.0 => Ok(r),
        _ => Err(invalid(key, format!("`{spec}`: the intensity R must be a positive finite number"))),
    }
}

/// The measurement times of a scenario: the cells' midpoints of a continuous record, the
/// explicit `measurements.times`, or the preset's grid (`every`, `first`).
fn scenario_times(m: &MeasurementSpec, p: &Preset, continuous: Option<f64>) -> Result<Vec<f64>> {
    match &m.times {
        _ if continuous.is_some() => {
            let times = crate::data::continuous::cell_midpoints(0.0, p.t_end, p.sample_every);
            if times.len() < 2 {
                return Err(invalid(
                    "measurements.every",
                    format!(
                        "a continuous record needs at least two cells of {} in [0, {}]",
                        p.sample_every, p.t_end
                    ),
                ));
            }
            Ok(times)
        }
        Some(t) => {
            if m.every.is_some() || m.first.is_some() {
                return Err(invalid(
                    "measurements.times",
                    "give either `times` or `every`/`first`, not both",
                ));
            }
            if t.is_empty() || t.iter().any(|&x| !(x.is_finite() && (0.0..=p.t_end).contains(&x))) {
                return Err(invalid(
                    "measurements.times",
                    format!("must be non-empty and within [0, {}]", p.t_end),
                ));
            }
            if t.windows(2).any(|w| w[1] <= w[0]) {
                return Err(invalid("measurements.times", "must be strictly increasing"));
            }
            Ok(t.clone())
        }
        None => {
            // Checked before the times are allocated: a tiny `every` would ask for more times
            // than memory holds.
            let count = (p.t_end - p.first_sample) / p.sample_every;
            if count > MAX_MEASUREMENT_TIMES as f64 {
                return Err(invalid(
                    "measurements.every",
                    format!(
                        "{} gives {count:.3e} measurement times on [{}, {}]; at most \
                         {MAX_MEASUREMENT_TIMES} are allowed",
                        p.sample_every, p.first_sample, p.t_end
                    ),
                ));
            }
            Ok(p.measurement_times())
        }
    }
}

/// Measures the `states` (by name) of the preset `p` (`measurements.states`).
fn measure_states(p: &mut Preset, states: &[String]) -> Result<()> {
    let names = p.model.state_names();
    if states.is_empty() {
        return Err(invalid("measurements.states", "must name at least one state"));
    }
    let mut indices = Vec::with_capacity(states.len());
    let mut outputs = Vec::with_capacity(states.len());
    for state in states {
        let i = names.iter().position(|n| n == state).ok_or_else(|| {
            invalid("measurements.states", format!("unknown state `{state}` (known: {})", names.join(", ")))
        })?;
        if indices.contains(&i) {
            return Err(invalid("measurements.states", format!("`{state}` is listed twice")));
        }
        let obs = &p.observation;
        let output = match obs.states.iter().position(|&j| j == i) {
            Some(k) => obs.names[k].clone(),
            None => format!("y_{state}"),
        };
        indices.push(i);
        outputs.push(output);
    }
    p.observation.states = indices;
    p.observation.names = outputs;
    Ok(())
}

impl Scenario {
    fn resolve(
        name: String,
        vars: Vec<(String, String)>,
        spec: ExperimentSpec,
        base_dir: Option<&Path>,
    ) -> Result<Scenario> {
        if spec.replicates == 0 {
            return Err(invalid("replicates", "must be at least 1"));
        }
        let mut p = model_preset(&spec.model, base_dir)?;
        for (k, &v) in &spec.model.params {
            p.set_param(k, v).map_err(|e| invalid(format!("model.params.{k}"), e.to_string()))?;
        }
        let sim = &spec.simulation;
        if let Some(dt) = sim.dt {
            p.dt = positive("simulation.dt", dt)?;
        }
        if let Some(t) = sim.t_end {
            p.t_end = positive("simulation.t_end", t)?;
        }
        let m = &spec.measurements;
        if let Some(e) = m.every {
            p.sample_every = positive("measurements.every", e)?;
        }
        if let Some(f) = m.first {
            if !(f.is_finite() && (0.0..=p.t_end).contains(&f)) {
                return Err(invalid(
                    "measurements.first",
                    format!("must lie in [0, t_end = {}], got {f}", p.t_end),
                ));
            }
            p.first_sample = f;
        }
        let continuous = match m.generate.as_deref().map(str::trim) {
            Some(g) if g.starts_with("continuous:") => Some(parse_continuous(g, m)?),
            _ => None,
        };
        let times = scenario_times(m, &p, continuous)?;
        if let Some(states) = &m.states {
            measure_states(&mut p, states)?;
        }
        let initial = parse_state_priors(&sim.initial, &p, "simulation.initial")?;
        let estimator_x0 = parse_state_priors(&m.x0_prior, &p, "measurements.x0_prior")?;
        let generate = match &m.generate {
            _ if continuous.is_some() => {
                let r = continuous.expect("checked");
                Noise::Gaussian {
                    sigma: crate::model::observation::Param::Fixed((r / p.sample_every).sqrt()),
                }
            }
            Some(s) => parse_noise(s, &p, "measurements.generate")?,
            None => p.observation.noise.clone(),
        };
        let estimate_noise = match &m.estimate {
            Some(s) => parse_noise(s, &p, "measurements.estimate")?,
            None => generate.clone(),
        };
        let mut truth = p.clone();
        truth.observation.noise = generate;
        truth.validate().map_err(|e| invalid("model", e.to_string()))?;
        if spec.estimators.is_empty() {
            return Err(invalid("estimators", "at least one estimator is required"));
        }
        let mut estimators: Vec<ScenarioEstimator> = Vec::new();
        for e in &spec.estimators {
            let label = e.label();
            let key = format!("estimators.{label}");
            if label.is_empty() || label.contains(|c: char| c == ',' || c == '"' || c.is_whitespace()) {
                return Err(invalid(
                    format!("{key}.label"),
                    "must be non-empty, without commas, quotes or spaces",
                ));
            }
            if estimators.iter().any(|o| o.label == label) {
                return Err(invalid(
                    format!("{key}.label"),
                    "is used twice; give each estimator its own label",
                ));
            }
            let mut ep = p.clone();
            ep.observation.noise = match &e.likelihood {
                Some(s) => parse_noise(s, &p, &format!("{key}.likelihood"))?,
                None => estimate_noise.clone(),
            };
            let n_noisy = ep.dims().noisy;
            ep.x0_prior = estimator_x0[..n_noisy].to_vec();
            ep.z0_prior = estimator_x0[n_noisy..].to_vec();
            ep.validate().map_err(|err| invalid(key.clone(), err.to_string()))?;
            let estimate = e
                .estimate
                .iter()
                .map(|n| ep.param_index(n).map_err(|err| invalid(format!("{key}.estimate"), err.to_string())))
                .collect::<Result<Vec<_>>>()?;
            if !estimate.is_empty() && !e.method.estimates_parameters() {
                return Err(invalid(
                    format!("{key}.estimate"),
                    format!("`{}` takes the parameters as given", e.method),
                ));
            }
            estimators.push(ScenarioEstimator { label, estimator: e.estimator()?, preset: ep, estimate });
        }
        let mut metrics = Vec::new();
        for s in &spec.metrics {
            let metric = Metric::parse(s)?;
            match &metric {
                Metric::RmseTo(label) if !estimators.iter().any(|e| &e.label == label) => {
                    return Err(invalid("metrics", format!("`{s}`: no estimator is labelled `{label}`")));
                }
                Metric::WellSide { state: Some(state), .. } if !p.model.state_names().contains(state) => {
                    return Err(invalid("metrics", format!("`{s}`: unknown state `{state}`")));
                }
                _ => {}
            }
            if metrics.contains(&metric) {
                return Err(invalid("metrics", format!("`{s}` is listed twice")));
            }
            metrics.push(metric);
        }
        let scheme = sim.scheme.unwrap_or(Scheme::ItoTaylor15);
        Ok(Scenario { name, vars, truth, initial, scheme, times, continuous, estimators, metrics, spec })
    }
}
