//! `Model` (a [`Preset`]: built-in or from a TOML model file) and `Simulation`.

use std::collections::BTreeMap;

use numpy::{PyArray1, PyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rand::rngs::StdRng;
use rand::SeedableRng;

use onsager::model::library::{self, Preset};
use onsager::model::observation::Noise;
use onsager::model::{Observation, Sde};
use onsager::simulate::Scheme;

use crate::{guarded, interruptible, matrix, value_error, vector};

/// A model: its SDE, parameter values, priors, measurement model and simulation defaults.
#[pyclass(module = "onsager._onsager", frozen)]
#[derive(Clone)]
pub struct Model {
    pub(crate) preset: Preset,
    /// The parameters whose values the user set (kept as the initial guess of jme and mee, as
    /// `onsager estimate --param` does).
    pub(crate) set: Vec<String>,
}

impl Model {
    /// A copy with the parameters of `params` set.
    fn with(&self, params: Option<&Bound<'_, PyDict>>) -> PyResult<Model> {
        let mut m = self.clone();
        if let Some(params) = params {
            for (k, v) in params.iter() {
                let name: String = k.extract()?;
                let value: f64 = v.extract().map_err(|_| {
                    pyo3::exceptions::PyValueError::new_err(format!(
                        "parameter `{name}`: expected a number, got {}",
                        v.repr().map_or_else(|_| "?".into(), |r| r.to_string())
                    ))
                })?;
                m.preset.set_param(&name, value).map_err(value_error)?;
                if !m.set.contains(&name) {
                    m.set.push(name);
                }
            }
        }
        m.preset.validate().map_err(value_error)?;
        Ok(m)
    }
}

#[pymethods]
impl Model {
    /// A built-in model by name (see `onsager.builtin_models()`), with parameters set by
    /// keyword, e.g. `Model.builtin("double-well", D=0.5)`.
    #[staticmethod]
    #[pyo3(signature = (name, **params))]
    fn builtin(name: &str, params: Option<&Bound<'_, PyDict>>) -> PyResult<Model> {
        guarded(|| {
            let preset = library::preset(name).map_err(value_error)?;
            Model { preset, set: Vec::new() }.with(params)
        })
    }

    /// The model a TOML model file declares (docs/models.md, "Models in a file").
    #[staticmethod]
    fn from_file(path: std::path::PathBuf) -> PyResult<Model> {
        guarded(|| {
            let preset = Preset::from_path(&path).map_err(value_error)?;
            Ok(Model { preset, set: Vec::new() })
        })
    }

    /// The model a TOML text declares; `name` stands for the file in error messages.
    #[staticmethod]
    #[pyo3(signature = (text, name = "<string>"))]
    fn from_str(text: &str, name: &str) -> PyResult<Model> {
        guarded(|| {
            let preset = Preset::from_toml_str(text, name).map_err(value_error)?;
            Ok(Model { preset, set: Vec::new() })
        })
    }

    /// A copy with parameters set by keyword.
    #[pyo3(signature = (**params))]
    fn with_params(&self, params: Option<&Bound<'_, PyDict>>) -> PyResult<Model> {
        guarded(|| self.with(params))
    }

    /// A copy with another measurement model, e.g. `"gaussian:sigma=0.1"` or
    /// `"student-t:nu=4,scale=0.5"` (the `--likelihood` syntax).
    fn with_likelihood(&self, spec: &str) -> PyResult<Model> {
        guarded(|| {
            let mut m = self.clone();
            m.preset.observation.noise = Noise::parse(spec, &m.preset.param_names()).map_err(value_error)?;
            m.preset.validate().map_err(value_error)?;
            Ok(m)
        })
    }

    /// The model's name.
    #[getter]
    fn name(&self) -> String {
        self.preset.name.clone()
    }

    /// One-line description.
    #[getter]
    fn description(&self) -> String {
        self.preset.description.clone()
    }

    /// State names: noisy states, then clean states.
    #[getter]
    fn states(&self) -> Vec<String> {
        self.preset.model.state_names()
    }

    /// Parameter values by name.
    #[getter]
    fn params(&self) -> BTreeMap<String, f64> {
        self.preset.param_names().into_iter().zip(self.preset.theta.iter().copied()).collect()
    }

    /// Names of the parameters the model's source estimates by default.
    #[getter]
    fn estimated_by_default(&self) -> Vec<String> {
        self.preset
            .param_names()
            .into_iter()
            .zip(&self.preset.estimate)
            .filter(|(_, &e)| e)
            .map(|(n, _)| n)
            .collect()
    }

    /// Names of the measured outputs (the columns of `y`).
    #[getter]
    fn outputs(&self) -> Vec<String> {
        self.preset.observation.output_names()
    }

    /// The measurement model, as text.
    #[getter]
    fn likelihood(&self) -> String {
        self.preset.observation.noise.describe(&self.preset.param_names())
    }

    /// Simulation defaults: `t_end`, `dt`, `first_sample`, `sample_every`.
    #[getter]
    fn simulation(&self) -> BTreeMap<&'static str, f64> {
        let p = &self.preset;
        BTreeMap::from([
            ("t_end", p.t_end),
            ("dt", p.dt),
            ("first_sample", p.first_sample),
            ("sample_every", p.sample_every),
        ])
    }

    /// Simulates the model as `onsager simulate` does (same seed, same numbers).
    #[pyo3(signature = (t_end = None, dt = None, sample_every = None, seed = 1, likelihood = None, scheme = "ito-taylor-1.5"))]
    #[allow(clippy::too_many_arguments)]
    fn simulate(
        &self,
        py: Python<'_>,
        t_end: Option<f64>,
        dt: Option<f64>,
        sample_every: Option<f64>,
        seed: u64,
        likelihood: Option<&str>,
        scheme: &str,
    ) -> PyResult<Simulation> {
        let mut p = match likelihood {
            Some(spec) => self.with_likelihood(spec)?.preset,
            None => self.preset.clone(),
        };
        p.t_end = t_end.unwrap_or(p.t_end);
        p.dt = dt.unwrap_or(p.dt);
        p.sample_every = sample_every.unwrap_or(p.sample_every);
        let scheme: Scheme = scheme.parse().map_err(value_error)?;
        let (path, data) =
            interruptible(py, move || p.simulate(scheme, &mut StdRng::seed_from_u64(seed)), || {})?
                .map_err(value_error)?;
        Ok(Simulation {
            t: vector(py, &data.times).unbind(),
            y: matrix(py, &data.values, data.names.len()).unbind(),
            truth_t: vector(py, &path.times).unbind(),
            truth_x: matrix(py, &path.values, path.names.len()).unbind(),
            outputs: data.names,
            states: path.names,
        })
    }

    fn __repr__(&self) -> String {
        let params: Vec<String> = self.params().iter().map(|(k, v)| format!("{k}={v}")).collect();
        format!("Model({:?}; states {}; {})", self.preset.name, self.states().join(", "), params.join(", "))
    }
}

/// A simulated record: measurements `t`, `y` and the true path `truth_t`, `truth_x`.
#[pyclass(module = "onsager._onsager", frozen, get_all)]
pub struct Simulation {
    /// Measurement times, shape (n,).
    t: Py<PyArray1<f64>>,
    /// Measurements, shape (n, outputs); NaN for a missing value.
    y: Py<PyArray2<f64>>,
    /// Times of the true path, shape (m,).
    truth_t: Py<PyArray1<f64>>,
    /// The true path, shape (m, states).
    truth_x: Py<PyArray2<f64>>,
    /// Output names (columns of `y`).
    outputs: Vec<String>,
    /// State names (columns of `truth_x`).
    states: Vec<String>,
}

#[pymethods]
impl Simulation {
    fn __repr__(&self, py: Python<'_>) -> String {
        format!(
            "Simulation({} measurements of {}; true path of {} at {} times)",
            self.t.bind(py).len().unwrap_or(0),
            self.outputs.join(", "),
            self.states.join(", "),
            self.truth_t.bind(py).len().unwrap_or(0)
        )
    }
}

/// The names of the built-in models.
#[pyfunction]
pub fn builtin_models() -> Vec<&'static str> {
    library::NAMES.to_vec()
}
