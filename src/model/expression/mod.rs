//! Models written as expressions, read at run time (`Preset::from_path`, `--model-file`).
//!
//! An [`ExpressionModel`] is an [`Sde`] whose drift f, clean drift h and noise matrix G are
//! infix expressions in t, the states and the parameters (see `docs/models.md`, "Models in a
//! file", for the syntax and the file format). The expressions are parsed once into a
//! hash-consed graph (equal subexpressions shared, constants folded), differentiated
//! symbolically there, and compiled into tapes evaluated for `f64` and for every dual number
//! alike. So every estimator works on them unchanged, and the path transcriptions get closed
//! forms as the built-in models give them:
//!
//! - [`Sde::divergence`] is the compiled sum of ∂f_i/∂x_i
//!   (`000_74b95e149527c64e.txt (2.49)`);
//! - [`Sde::drift_derivatives`] evaluates one tape holding every structurally nonzero first and
//!   second derivative of f, h and div_x f in (x, z, θ);
//! - [`Sde::drift_uses_param`], [`Sde::drift_polynomial_degree`] and
//!   [`Sde::drift_is_autonomous`] are read off the expressions (the degree is a bound: a
//!   cancelling term is still counted).
//!
//! ```
//! use onsager::model::expression::{ExpressionModel, Diffusion};
//! use onsager::model::Sde;
//!
//! // dx = (θ₀ x − x³) dt + θ₁ dW
//! let m = ExpressionModel::new(&["x"], &[], &["a", "s"], &["a*x - x^3"], &[], Diffusion::Scalar("s"))?;
//! let mut f = [0.0];
//! m.drift(0.0, &[2.0], &[], &[1.0, 0.5], &mut f);
//! assert_eq!(f[0], 2.0 - 8.0);
//! assert_eq!(m.divergence(0.0, &[2.0], &[], &[1.0, 0.5]), 1.0 - 12.0);
//! assert_eq!(m.drift_polynomial_degree(), Some(3));
//! assert!(!m.drift_uses_param(1));
//! # Ok::<(), onsager::Error>(())
//! ```

pub mod file;
mod graph;
mod parse;
mod tape;

#[cfg(test)]
mod tests;

use std::collections::HashMap;

use graph::{Graph, Id};
use parse::{ParseError, Symbol, Symbols};
use tape::Tape;

use super::{Dims, DriftDerivatives, Scalar, Sde};
use crate::{Error, Result};

/// The shape of a noise matrix G(θ) given as expressions.
#[derive(Debug, Clone, PartialEq)]
pub enum Diffusion<S> {
    /// G = g I (one expression).
    Scalar(S),
    /// G = diag(g₁, …, g_n) (one expression per noisy state).
    Diagonal(Vec<S>),
    /// G by rows (n rows of n expressions).
    Full(Vec<Vec<S>>),
}

/// Which expression of a model a problem is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Part {
    /// Component i of the drift f.
    Drift(usize),
    /// Component i of the clean drift h.
    CleanDrift(usize),
    /// Entry (row, column) of G (both 0 for a scalar, (i, i) for a diagonal).
    Diffusion(usize, usize),
}

impl std::fmt::Display for Part {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            Part::Drift(i) => write!(f, "drift component {}", i + 1),
            Part::CleanDrift(i) => write!(f, "clean drift component {}", i + 1),
            Part::Diffusion(r, c) => write!(f, "diffusion entry ({}, {})", r + 1, c + 1),
        }
    }
}

/// A structurally nonzero derivative of output `o` (f, then h, then div_x f) in w_i (and w_j
/// for a second derivative, `j == NONE` for a first one), w = (x, z, θ).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Entry {
    o: u32,
    i: u32,
    j: u32,
}

const NONE: u32 = u32::MAX;

/// An SDE model given by expressions (module documentation).
#[derive(Debug, Clone, PartialEq)]
pub struct ExpressionModel {
    noisy: Vec<String>,
    clean: Vec<String>,
    params: Vec<String>,
    f: Tape,
    h: Tape,
    g: Tape,
    div: Tape,
    /// Every entry of `entries`, in order.
    derivatives: Tape,
    entries: Vec<Entry>,
    uses_param: Vec<bool>,
    degree: Option<usize>,
    autonomous: bool,
}

/// The symbols of a model's expressions: t, the states, the parameters, named constants and
/// `pi`. In G, only parameters and constants.
pub(crate) struct Names {
    map: HashMap<String, Symbol>,
    /// Inputs allowed (the diffusion reads θ only): inputs below `first_allowed` are refused.
    first_allowed: u32,
    /// What each input is called, for messages.
    kinds: Vec<(String, &'static str)>,
}

impl Names {
    /// The names of a model; `constants` are folded into the expressions.
    pub(crate) fn new(
        noisy: &[String],
        clean: &[String],
        params: &[String],
        constants: &[(String, f64)],
    ) -> Names {
        let mut map = HashMap::new();
        let mut kinds = vec![("t".to_string(), "time")];
        map.insert("t".to_string(), Symbol::Input(0));
        map.insert("pi".to_string(), Symbol::Value(std::f64::consts::PI));
        for (group, kind) in [(noisy, "noisy state"), (clean, "clean state"), (params, "parameter")] {
            for n in group {
                map.insert(n.clone(), Symbol::Input(kinds.len() as u32));
                kinds.push((n.clone(), kind));
            }
        }
        for (n, v) in constants {
            map.insert(n.clone(), Symbol::Value(*v));
        }
        Names { map, first_allowed: 0, kinds }
    }

    fn for_diffusion(&self, n_states: usize) -> Names {
        Names { map: self.map.clone(), first_allowed: 1 + n_states as u32, kinds: self.kinds.clone() }
    }
}

impl Symbols for Names {
    fn resolve(&self, name: &str) -> std::result::Result<Symbol, String> {
        match self.map.get(name) {
            Some(&Symbol::Input(i)) if i < self.first_allowed => {
                let (n, kind) = &self.kinds[i as usize];
                Err(format!("G(theta) may depend on the parameters only, not on the {kind} `{n}`"))
            }
            Some(&s) => Ok(s),
            None => {
                let mut known: Vec<&str> =
                    self.kinds[self.first_allowed as usize..].iter().map(|(n, _)| n.as_str()).collect();
                let mut constants: Vec<&str> = self
                    .map
                    .iter()
                    .filter(|(_, s)| matches!(s, Symbol::Value(_)))
                    .map(|(n, _)| n.as_str())
                    .collect();
                constants.sort();
                known.extend(constants);
                Err(format!("unknown symbol `{name}` (known: {})", known.join(", ")))
            }
        }
    }
}

/// Parses the expressions of a model into one graph, reporting the part and offset of a problem.
pub(crate) struct Builder {
    graph: Graph,
    names: Names,
    dims: Dims,
}

impl Builder {
    pub(crate) fn new(names: Names, dims: Dims) -> Builder {
        Builder { graph: Graph::default(), names, dims }
    }

    /// Parses one expression of `part`.
    pub(crate) fn parse(&mut self, part: Part, text: &str) -> std::result::Result<Id, ParseError> {
        match part {
            Part::Diffusion(..) => {
                let names = self.names.for_diffusion(self.dims.states());
                parse::parse(text, &mut self.graph, &names)
            }
            _ => parse::parse(text, &mut self.graph, &self.names),
        }
    }

    /// The model of the parsed roots: f (noisy), h (clean) and G (column-major).
    pub(crate) fn finish(mut self, f: &[Id], h: &[Id], g: &[Id]) -> ExpressionModel {
        let d = self.dims;
        let (nx, nz, ns) = (d.noisy, d.clean, d.states());
        let graph = &mut self.graph;
        let mut div = graph.num(0.0);
        for (i, &fi) in f.iter().enumerate() {
            let di = graph.derivative(fi, 1 + i as u32);
            div = graph.add(div, di);
        }
        let outputs: Vec<Id> = f.iter().chain(h).copied().chain([div]).collect();
        let n_w = (ns + d.params) as u32;
        // first derivatives of every output in every w_i it depends on
        let mut firsts: Vec<(u32, u32, Id)> = Vec::new();
        for w in 0..n_w {
            let dep = graph.depends_on(1 + w);
            for (o, &r) in outputs.iter().enumerate() {
                if dep[r as usize] {
                    let d1 = graph.derivative(r, 1 + w);
                    if graph.constant(d1) != Some(0.0) {
                        firsts.push((o as u32, w, d1));
                    }
                }
            }
        }
        let deps: Vec<Vec<bool>> = (0..n_w).map(|w| graph.depends_on(1 + w)).collect();
        let mut entries = Vec::new();
        let mut roots = Vec::new();
        for &(o, i, d1) in &firsts {
            entries.push(Entry { o, i, j: NONE });
            roots.push(d1);
        }
        for &(o, i, d1) in &firsts {
            for j in i..n_w {
                if deps[j as usize].get(d1 as usize).copied().unwrap_or(false) {
                    let d2 = graph.derivative(d1, 1 + j);
                    if graph.constant(d2) != Some(0.0) {
                        entries.push(Entry { o, i, j });
                        roots.push(d2);
                    }
                }
            }
        }
        let state_drift: Vec<Id> = f.iter().chain(h).copied().collect();
        let uses_param = (0..d.params)
            .map(|k| {
                let dep = graph.depends_on((1 + ns + k) as u32);
                state_drift.iter().any(|&r| dep[r as usize])
            })
            .collect();
        let reads_t = graph.depends_on(0);
        let autonomous = !state_drift.iter().any(|&r| reads_t[r as usize]);
        let is_state = |j: u32| j >= 1 && (j as usize) <= ns;
        let degree = state_drift
            .iter()
            .map(|&r| graph.polynomial_degree(r, &is_state))
            .try_fold(0u32, |acc, d| d.map(|d| acc.max(d)))
            .map(|d| d as usize);
        let graph = &self.graph;
        ExpressionModel {
            noisy: self.names.kinds[1..1 + nx].iter().map(|(n, _)| n.clone()).collect(),
            clean: self.names.kinds[1 + nx..1 + ns].iter().map(|(n, _)| n.clone()).collect(),
            params: self.names.kinds[1 + ns..].iter().map(|(n, _)| n.clone()).collect(),
            f: Tape::compile(graph, f, nx, nz),
            h: Tape::compile(graph, h, nx, nz),
            g: Tape::compile(graph, g, nx, nz),
            div: Tape::compile(graph, &[div], nx, nz),
            derivatives: Tape::compile(graph, &roots, nx, nz),
            entries,
            uses_param,
            degree,
            autonomous,
        }
    }

    /// The node of the constant 0 (the entries of G not given).
    pub(crate) fn zero(&mut self) -> Id {
        self.graph.num(0.0)
    }
}

impl ExpressionModel {
    /// A model from expressions: the names of the noisy states, clean states and parameters,
    /// one drift expression per noisy state, one clean-drift expression per clean state, and G.
    ///
    /// Errors: [`Error::InvalidOption`] naming the expression (`drift[2]`, `diffusion[1,1]`),
    /// the character position and what was expected, for a syntax error, an unknown symbol or
    /// function, a wrong number of arguments, a name used twice or reserved (`t`, `pi`, the
    /// functions), a diffusion that depends on t or the states; [`Error::DimensionMismatch`]
    /// for a wrong number of expressions. That G(θ) is invertible is checked at a given θ by
    /// [`Sde::diffusion_matrix`].
    pub fn new(
        noisy: &[&str],
        clean: &[&str],
        params: &[&str],
        drift: &[&str],
        clean_drift: &[&str],
        diffusion: Diffusion<&str>,
    ) -> Result<ExpressionModel> {
        let owned = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<String>>();
        let (noisy, clean, params) = (owned(noisy), owned(clean), owned(params));
        check_names(noisy.iter().chain(&clean).chain(&params).map(String::as_str))?;
        let dims = Dims { noisy: noisy.len(), clean: clean.len(), params: params.len() };
        super::check_len("drift expressions", dims.noisy, drift.len())?;
        super::check_len("clean drift expressions", dims.clean, clean_drift.len())?;
        let mut b = Builder::new(Names::new(&noisy, &clean, &params, &[]), dims);
        let parse = |b: &mut Builder, part: Part, text: &str| {
            b.parse(part, text).map_err(|e| {
                Error::invalid(
                    part.to_string(),
                    format!(
                        "at character {} of `{text}`: {}",
                        text[..e.offset].chars().count() + 1,
                        e.message
                    ),
                )
            })
        };
        let f =
            (0..dims.noisy).map(|i| parse(&mut b, Part::Drift(i), drift[i])).collect::<Result<Vec<_>>>()?;
        let h = (0..dims.clean)
            .map(|i| parse(&mut b, Part::CleanDrift(i), clean_drift[i]))
            .collect::<Result<Vec<_>>>()?;
        let n = dims.noisy;
        let mut g = vec![None; n * n];
        match diffusion {
            Diffusion::Scalar(s) => {
                let id = parse(&mut b, Part::Diffusion(0, 0), s)?;
                (0..n).for_each(|i| g[i + i * n] = Some(id));
            }
            Diffusion::Diagonal(d) => {
                super::check_len("diagonal of G", n, d.len())?;
                for (i, s) in d.iter().enumerate() {
                    g[i + i * n] = Some(parse(&mut b, Part::Diffusion(i, i), s)?);
                }
            }
            Diffusion::Full(rows) => {
                super::check_len("rows of G", n, rows.len())?;
                for (r, row) in rows.iter().enumerate() {
                    super::check_len("columns of G", n, row.len())?;
                    for (c, s) in row.iter().enumerate() {
                        g[r + c * n] = Some(parse(&mut b, Part::Diffusion(r, c), s)?);
                    }
                }
            }
        }
        let zero = b.graph.num(0.0);
        let g: Vec<Id> = g.into_iter().map(|e| e.unwrap_or(zero)).collect();
        Ok(b.finish(&f, &h, &g))
    }

    /// The number of operations of the compiled drift, clean drift, noise matrix, divergence and
    /// derivative tapes (a measure of the cost of one evaluation).
    pub fn tape_lengths(&self) -> [usize; 5] {
        [self.f.len(), self.h.len(), self.g.len(), self.div.len(), self.derivatives.len()]
    }
}

/// Checks that state, parameter and constant names are identifiers, not reserved, and distinct.
fn check_names<'a>(names: impl Iterator<Item = &'a str>) -> Result<()> {
    let mut seen: Vec<&str> = Vec::new();
    for n in names {
        name_problem(n, &seen).map_or(Ok(()), |reason| Err(Error::invalid("names", reason)))?;
        seen.push(n);
    }
    Ok(())
}

/// What is wrong with the name `n` given the names declared before it, if anything.
pub(crate) fn name_problem(n: &str, seen: &[&str]) -> Option<String> {
    if !parse::is_identifier(n) {
        Some(format!("`{n}` is not a valid name (letters, digits and `_`, not starting with a digit)"))
    } else if parse::is_reserved(n) {
        Some(format!(
            "`{n}` is reserved (t, pi and the function names cannot name a state, parameter or constant)"
        ))
    } else if seen.contains(&n) {
        Some(format!("`{n}` is declared twice"))
    } else {
        None
    }
}

impl Sde for ExpressionModel {
    fn dims(&self) -> Dims {
        Dims { noisy: self.noisy.len(), clean: self.clean.len(), params: self.params.len() }
    }

    fn noisy_names(&self) -> Vec<String> {
        self.noisy.clone()
    }

    fn clean_names(&self) -> Vec<String> {
        self.clean.clone()
    }

    fn param_names(&self) -> Vec<String> {
        self.params.clone()
    }

    /// The compiled drift expressions.
    fn drift<D: Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D], out: &mut [D]) {
        self.f.eval(t, x, z, theta, out);
    }

    /// The compiled clean-drift expressions.
    fn clean_drift<D: Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D], out: &mut [D]) {
        self.h.eval(t, x, z, theta, out);
    }

    /// The compiled entries of G(θ), column-major.
    fn diffusion<D: Scalar>(&self, theta: &[D], out: &mut [D]) {
        self.g.eval(D::from(0.0), &[], &[], theta, out);
    }

    /// Whether θ_i appears in f or h.
    fn drift_uses_param(&self, i: usize) -> bool {
        self.uses_param.get(i).copied().unwrap_or(true)
    }

    /// The compiled symbolic divergence Σ ∂f_i/∂x_i.
    fn divergence<D: Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D]) -> D {
        let mut out = [D::from(0.0)];
        self.div.eval(t, x, z, theta, &mut out);
        out[0]
    }

    /// Every structurally nonzero first and second derivative of f, h and div_x f, from one
    /// compiled tape of symbolic derivatives.
    fn drift_derivatives(
        &self,
        t: f64,
        x: &[f64],
        z: &[f64],
        theta: &[f64],
        out: &mut DriftDerivatives,
    ) -> bool {
        let n = self.entries.len();
        let mut write = |values: &mut [f64]| {
            self.derivatives.eval(t, x, z, theta, values);
            for (e, &v) in self.entries.iter().zip(values.iter()) {
                if e.j == NONE {
                    out.first(e.o as usize, e.i as usize, v);
                } else {
                    out.second(e.o as usize, e.i as usize, e.j as usize, v);
                }
            }
        };
        if n <= 64 {
            write(&mut [0.0; 64][..n]);
        } else {
            write(&mut vec![0.0; n]);
        }
        true
    }

    /// The degree read off the expressions (module documentation).
    fn drift_polynomial_degree(&self) -> Option<usize> {
        self.degree
    }

    /// Whether f and h read t, off the expressions.
    fn drift_is_autonomous(&self) -> bool {
        self.autonomous
    }
}
