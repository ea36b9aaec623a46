//! Measurement models: the likelihood ψ(y | x, z, θ) of one measurement vector.
//!
//! A measurement at time t has density (or mass) ψ(y | x(t), z(t), θ) with respect to a measure
//! ν (`000_74b95e149527c64e.txt`, Assumption 2.21). Missing components of y (NaN) are skipped.
//!
//! [`Noise`] holds the scalar measurement-error laws of the papers (Gaussian, Student-t,
//! Gaussian mixture, quantized Gaussian, Laplace); [`StateMeasurement`] measures a selection of
//! the states through one of them. A general output function y = c(x, z, θ) + noise is an
//! [`Observation`] written by the user, who calls [`Noise::log_density`] per component:
//!
//! ```
//! use onsager::model::observation::{Noise, Observation, Param};
//! use onsager::model::Scalar;
//! use rand::Rng;
//!
//! /// y = x₀² + z₀ + ε, ε ~ N(0, θ[1]²).
//! struct Energy {
//!     noise: Noise,
//! }
//!
//! impl Observation for Energy {
//!     fn output_names(&self) -> Vec<String> {
//!         vec!["energy".into()]
//!     }
//!     fn log_likelihood<D: Scalar>(&self, _t: f64, y: &[f64], x: &[D], z: &[D], theta: &[D]) -> D {
//!         let mean = x[0] * x[0] + z[0];
//!         if y[0].is_nan() { D::from(0.0) } else { self.noise.log_density(y[0], mean, theta) }
//!     }
//!     fn sample<R: Rng + ?Sized>(&self, _t: f64, x: &[f64], z: &[f64], theta: &[f64], rng: &mut R, y: &mut [f64]) {
//!         y[0] = self.noise.sample(x[0] * x[0] + z[0], theta, rng);
//!     }
//! }
//!
//! let obs = Energy { noise: Noise::Gaussian { sigma: Param::Theta(1) } };
//! let theta = [0.3, 0.5];
//! obs.noise.validate(theta.len(), &theta)?;
//! let ll: f64 = obs.log_likelihood(0.0, &[1.2], &[1.0], &[0.1], &theta);
//! // ln N(1.2; 1.1, 0.5²) = −ln(0.5 √(2π)) − ½ (0.1/0.5)²
//! assert!((ll - (-(0.5 * (2.0 * std::f64::consts::PI).sqrt()).ln() - 0.02)).abs() < 1e-14);
//! # Ok::<(), onsager::Error>(())
//! ```

use std::fmt;

use rand::{Rng, RngExt};
use rand_distr::{Distribution, Exp1, StandardNormal};

use super::special::{ln_gamma, log_diff_ndtr};
use super::Scalar;
use crate::{Error, Result};

/// A measurement model: log ψ(y | x, z, θ), generic over the scalar so that its derivatives
/// with respect to the states and θ come by automatic differentiation, and sampling of y.
pub trait Observation {
    /// Names of the measured outputs (the data CSV's columns after `t`).
    fn output_names(&self) -> Vec<String>;

    /// Number of measured outputs.
    fn output_dim(&self) -> usize {
        self.output_names().len()
    }

    /// log ψ(y | x, z, θ) at time t; components of `y` that are NaN (missing) are skipped.
    fn log_likelihood<D: Scalar>(&self, t: f64, y: &[f64], x: &[D], z: &[D], theta: &[D]) -> D;

    /// Draws y ~ ψ(· | x, z, θ) at time t into `y`.
    fn sample<R: Rng + ?Sized>(
        &self,
        t: f64,
        x: &[f64],
        z: &[f64],
        theta: &[f64],
        rng: &mut R,
        y: &mut [f64],
    );

    /// The state (index into s = [x; z]) that output `output` measures directly, if it does.
    /// Default: none.
    fn measured_state(&self, _output: usize) -> Option<usize> {
        None
    }

    /// The standard deviation of the measurement errors at θ when they are Gaussian with one
    /// sd for every output. Default: none.
    fn gaussian_error_sd(&self, _theta: &[f64]) -> Option<f64> {
        None
    }
}

/// A scalar quantity of a likelihood or prior: a fixed number or a component of θ.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Param {
    /// A fixed value.
    Fixed(f64),
    /// The component `θ[i]`.
    Theta(usize),
}

impl Param {
    /// The value for the parameter vector `theta`: `v` for `Fixed(v)` (as a constant of the
    /// scalar type), `theta[i]` for `Theta(i)`; `None` when `i` is out of range.
    pub fn value<D: Scalar>(&self, theta: &[D]) -> Option<D> {
        match *self {
            Param::Fixed(v) => Some(D::from(v)),
            Param::Theta(i) => theta.get(i).copied(),
        }
    }

    /// The CLI spelling: the number, θ's name when `param_names` has it, else `theta[i]`.
    fn spell(&self, param_names: &[String]) -> String {
        match *self {
            Param::Fixed(v) => format_number(v),
            Param::Theta(i) => match param_names.get(i) {
                Some(name) => name.clone(),
                None => format!("theta[{i}]"),
            },
        }
    }
}

/// ln √(2π).
const LN_SQRT_2PI: f64 = 0.918_938_533_204_672_8;
/// ln π.
const LN_PI: f64 = 1.144_729_885_849_400_2;

/// A scalar measurement-error law, applied to each output component y_i around its mean m_i.
///
/// Each parameter is a [`Param`]: fixed, or a component of θ (then estimable, and
/// differentiated like the states). [`Noise::validate`] checks indices and domains; the CLI
/// spelling is parsed by [`Noise::parse`] and printed by `Display` / [`Noise::describe`].
#[derive(Debug, Clone, PartialEq)]
pub enum Noise {
    /// y ~ N(m, σ²): ln ψ = −ln(σ√(2π)) − (y − m)²/(2σ²) (`000_74b95e149527c64e.txt`
    /// Sec. 4.1.1). CLI: `gaussian:sigma=S`.
    Gaussian {
        /// Standard deviation σ > 0.
        sigma: Param,
    },
    /// Student's t with ν degrees of freedom and scale s:
    /// ln ψ = ln Γ((ν+1)/2) − ln Γ(ν/2) − ½ ln(νπ) − ln s − (ν+1)/2 · ln(1 + z²/ν), z = (y − m)/s
    /// (`001_8aefdf0570c96f51.txt` Sec. 9, `000_74b95e149527c64e.txt` Sec. 4.1.2 with ν = 4).
    /// CLI: `student-t:nu=N,scale=S`.
    StudentT {
        /// Degrees of freedom ν > 0.
        nu: Param,
        /// Scale s > 0.
        scale: Param,
    },
    /// Outlier mixture (1 − p) N(m, σ²) + p N(m, σ_o²) (`001_8aefdf0570c96f51.txt` Sec. 9,
    /// `000_74b95e149527c64e.txt` Sec. 4.1.2). CLI: `mixture:p=P,sigma=S,sigma_outlier=SO`.
    Mixture {
        /// Outlier probability, 0 ≤ p < 1.
        p_outlier: Param,
        /// Standard deviation of regular measurements σ > 0.
        sigma: Param,
        /// Standard deviation of outliers σ_o > 0.
        sigma_outlier: Param,
    },
    /// A Gaussian measurement quantized to the lattice l_b ℤ (`000_74b95e149527c64e.txt`
    /// Sec. 4.1.3): the probability mass (counting measure)
    /// ψ = Φ((m − y + l_b/2)/σ) − Φ((m − y − l_b/2)/σ), sampled as y = l_b · round((m + σε)/l_b).
    /// CLI: `quantized:sigma=S,bit=L`.
    Quantized {
        /// Standard deviation σ > 0 of the noise before quantization.
        sigma: Param,
        /// Bit length l_b > 0 (fixed).
        bit: f64,
    },
    /// Laplace (ℓ₁) errors: ln ψ = −ln(2b) − |y − m|/b, the ℓ₁-Laplace law of robust smoothing
    /// (`000_74b95e149527c64e.txt` Sec. 1.1.2, after Aravkin et al. 2011). CLI:
    /// `laplace:scale=B`.
    Laplace {
        /// Scale b > 0.
        scale: Param,
    },
}

/// The families [`Noise::parse`] accepts, in order.
pub const NOISE_FAMILIES: [&str; 5] = ["gaussian", "student-t", "mixture", "quantized", "laplace"];

impl Noise {
    /// The family name used by [`Noise::parse`] (one of [`NOISE_FAMILIES`]).
    pub fn family(&self) -> &'static str {
        match self {
            Noise::Gaussian { .. } => "gaussian",
            Noise::StudentT { .. } => "student-t",
            Noise::Mixture { .. } => "mixture",
            Noise::Quantized { .. } => "quantized",
            Noise::Laplace { .. } => "laplace",
        }
    }

    /// The law's [`Param`]s with their CLI keys, in the order of the CLI syntax
    /// (the fixed `bit` of [`Noise::Quantized`] is not a `Param` and is not listed).
    pub fn params(&self) -> Vec<(&'static str, Param)> {
        match *self {
            Noise::Gaussian { sigma } => vec![("sigma", sigma)],
            Noise::StudentT { nu, scale } => vec![("nu", nu), ("scale", scale)],
            Noise::Mixture { p_outlier, sigma, sigma_outlier } => {
                vec![("p", p_outlier), ("sigma", sigma), ("sigma_outlier", sigma_outlier)]
            }
            Noise::Quantized { sigma, .. } => vec![("sigma", sigma)],
            Noise::Laplace { scale } => vec![("scale", scale)],
        }
    }

    /// The full, normalised log-density (log-mass for [`Noise::Quantized`]) of one measurement
    /// component `y` given its mean `mean` and the parameters θ, generic over the scalar so
    /// that derivatives with respect to the mean and θ come by automatic differentiation.
    ///
    /// Returns −∞ when a parameter's value is outside its domain (σ ≤ 0, ν ≤ 0, p ∉ [0, 1),
    /// l_b ≤ 0, or NaN) and NaN when a `Param::Theta` index is out of range for `theta` or `y`
    /// is NaN; [`Noise::validate`] rules out both for a given θ. The quantized log-mass is
    /// finite and accurate even 40σ into the tail ([`log_diff_ndtr`]).
    pub fn log_density<D: Scalar>(&self, y: f64, mean: D, theta: &[D]) -> D {
        let nan = D::from(f64::NAN);
        let neg_inf = D::from(f64::NEG_INFINITY);
        let positive = |p: Param| -> Option<Option<D>> {
            let v = p.value(theta)?;
            Some(if v.re() > 0.0 && v.re().is_finite() { Some(v) } else { None })
        };
        macro_rules! get {
            ($p:expr) => {
                match positive($p) {
                    None => return nan,
                    Some(None) => return neg_inf,
                    Some(Some(v)) => v,
                }
            };
        }
        if y.is_nan() {
            return nan;
        }
        let r = D::from(y) - mean;
        match *self {
            Noise::Gaussian { sigma } => {
                let s = get!(sigma);
                gaussian_log_density(r, s)
            }
            Noise::StudentT { nu, scale } => {
                let (nu, s) = (get!(nu), get!(scale));
                let z = r / s;
                let half_nu1 = (nu + 1.0) * 0.5;
                ln_gamma(half_nu1)
                    - ln_gamma(nu * 0.5)
                    - (nu.ln() + LN_PI) * 0.5
                    - s.ln()
                    - half_nu1 * (z * z / nu).ln_1p()
            }
            Noise::Mixture { p_outlier, sigma, sigma_outlier } => {
                let Some(p) = p_outlier.value(theta) else { return nan };
                if !(p.re() >= 0.0 && p.re() < 1.0) {
                    return neg_inf;
                }
                let (s, so) = (get!(sigma), get!(sigma_outlier));
                let (l1, l2) = (gaussian_log_density(r, s), gaussian_log_density(r, so));
                // ln((1 − p) e^{l1} + p e^{l2}) without overflow, and differentiable at p = 0.
                let d = l2 - l1;
                if d.re() <= 0.0 {
                    l1 + (p * d.exp_m1()).ln_1p()
                } else {
                    l2 + (p + (-p + 1.0) * (-d).exp()).ln()
                }
            }
            Noise::Quantized { sigma, bit } => {
                if !(bit > 0.0 && bit.is_finite()) {
                    return neg_inf;
                }
                let s = get!(sigma);
                // Φ((y − m + l/2)/σ) − Φ((y − m − l/2)/σ), the mirror image of 000 Sec. 4.1.3's
                // Φ((m − y + l/2)/σ) − Φ((m − y − l/2)/σ) (same value, Φ(−u) = 1 − Φ(u)).
                let half = bit * 0.5;
                log_diff_ndtr((r - half) / s, (r + half) / s)
            }
            Noise::Laplace { scale } => {
                let b = get!(scale);
                -(b * 2.0).ln() - r.abs() / b
            }
        }
    }

    /// Draws one measurement component with mean `mean`. Returns NaN when the parameters are
    /// invalid for `theta` (check with [`Noise::validate`] first).
    pub fn sample<R: Rng + ?Sized>(&self, mean: f64, theta: &[f64], rng: &mut R) -> f64 {
        let val = |p: Param| p.value(theta).unwrap_or(f64::NAN);
        let normal = |rng: &mut R| -> f64 { StandardNormal.sample(rng) };
        match *self {
            Noise::Gaussian { sigma } => mean + val(sigma) * normal(rng),
            Noise::StudentT { nu, scale } => {
                let nu = val(nu);
                match rand_distr::StudentT::new(nu) {
                    Ok(t) => mean + val(scale) * t.sample(rng),
                    Err(_) => f64::NAN,
                }
            }
            Noise::Mixture { p_outlier, sigma, sigma_outlier } => {
                let p = val(p_outlier);
                if !(0.0..1.0).contains(&p) {
                    return f64::NAN;
                }
                let s = if rng.random::<f64>() < p { val(sigma_outlier) } else { val(sigma) };
                mean + s * normal(rng)
            }
            Noise::Quantized { sigma, bit } => bit * ((mean + val(sigma) * normal(rng)) / bit).round(),
            Noise::Laplace { scale } => {
                let e: f64 = Exp1.sample(rng);
                let sign = if rng.random::<bool>() { 1.0 } else { -1.0 };
                mean + sign * val(scale) * e
            }
        }
    }

    /// Checks the law against a parameter vector: `theta.len() == n_params`
    /// ([`Error::DimensionMismatch`]), every `Param::Theta` index in range, and the domains
    /// σ, s, σ_o, b > 0, ν > 0, 0 ≤ p < 1, l_b > 0, all finite ([`Error::InvalidOption`] naming
    /// the field, e.g. `mixture.sigma_outlier`).
    pub fn validate(&self, n_params: usize, theta: &[f64]) -> Result<()> {
        super::check_len("theta", n_params, theta.len())?;
        let family = self.family();
        for (key, p) in self.params() {
            let name = format!("{family}.{key}");
            let v = match p {
                Param::Fixed(v) => v,
                Param::Theta(i) if i < n_params => theta[i],
                Param::Theta(i) => {
                    return Err(Error::InvalidOption {
                        name,
                        reason: format!("theta[{i}] is out of range: there are {n_params} parameters"),
                    })
                }
            };
            let ok = match key {
                "p" => (0.0..1.0).contains(&v),
                _ => v > 0.0 && v.is_finite(),
            };
            if !ok {
                let domain = if key == "p" { "in [0, 1)" } else { "positive and finite" };
                let source = match p {
                    Param::Theta(i) => format!(" (theta[{i}])"),
                    Param::Fixed(_) => String::new(),
                };
                return Err(Error::InvalidOption {
                    name,
                    reason: format!("must be {domain}, got {v}{source}"),
                });
            }
        }
        if let Noise::Quantized { bit, .. } = *self {
            if !(bit > 0.0 && bit.is_finite()) {
                return Err(Error::InvalidOption {
                    name: "quantized.bit".into(),
                    reason: format!("must be positive and finite, got {bit}"),
                });
            }
        }
        Ok(())
    }

    /// σ for a [`Noise::Gaussian`] law (for Kalman-type methods, which need Gaussian
    /// measurement errors), `None` for the other laws or an out-of-range θ index.
    ///
    /// The σ of a Gaussian law for a method that needs one is [`Noise::gaussian_sigma`].
    pub fn gaussian_sd(&self, theta: &[f64]) -> Option<f64> {
        match *self {
            Noise::Gaussian { sigma } => sigma.value(theta),
            _ => None,
        }
    }

    /// σ of a [`Noise::Gaussian`] law (a number or a component of θ), for `user`, a method
    /// whose model needs Gaussian measurement errors. Errors: [`Error::InvalidOption`] (name
    /// `likelihood`) for another law, naming `user`, the law (with the names of θ in
    /// `param_names`) and `instead`, what to use for other laws.
    pub fn gaussian_sigma(&self, param_names: &[String], user: &str, instead: &str) -> Result<Param> {
        match *self {
            Noise::Gaussian { sigma } => Ok(sigma),
            ref other => Err(Error::InvalidOption {
                name: "likelihood".into(),
                reason: format!(
                    "{user} needs Gaussian measurement errors, not `{}`; {instead}",
                    other.describe(param_names)
                ),
            }),
        }
    }

    /// Parses the CLI syntax of `--likelihood`: `FAMILY:KEY=VALUE,...` with
    ///
    /// | family | keys |
    /// |---|---|
    /// | `gaussian` | `sigma` |
    /// | `student-t` | `nu`, `scale` |
    /// | `mixture` | `p`, `sigma`, `sigma_outlier` |
    /// | `quantized` | `sigma`, `bit` (a number) |
    /// | `laplace` | `scale` |
    ///
    /// A value is a number (`Param::Fixed`), the name of a parameter in `param_names` or
    /// `theta[i]` with i < `param_names.len()` (`Param::Theta`). Examples: `gaussian:sigma=0.1`,
    /// `student-t:nu=4,scale=sigma_y`, `mixture:p=0.25,sigma=0.5,sigma_outlier=3`,
    /// `quantized:sigma=sigma_y,bit=0.05`, `laplace:scale=0.2`. Spaces around tokens are
    /// ignored. Fixed values are checked against their domains. `sd` is accepted for `sigma` and
    /// `outlier-sd` for `sigma_outlier` (e.g. `mixture:p=0.25,sd=0.5,outlier-sd=3`).
    ///
    /// Errors: [`Error::UnknownName`] for an unknown family (kind `"likelihood"`) or parameter
    /// name (kind `"parameter"`), with the accepted names; [`Error::InvalidOption`] (name
    /// `--likelihood`) for an unknown, repeated or missing key or a malformed value.
    pub fn parse(spec: &str, param_names: &[String]) -> Result<Noise> {
        let invalid = |reason: String| Error::InvalidOption { name: "--likelihood".into(), reason };
        let (family, rest) = match spec.split_once(':') {
            Some((f, r)) => (f.trim(), r.trim()),
            None => (spec.trim(), ""),
        };
        let keys: &[&str] = match family {
            "gaussian" => &["sigma"],
            "student-t" => &["nu", "scale"],
            "mixture" => &["p", "sigma", "sigma_outlier"],
            "quantized" => &["sigma", "bit"],
            "laplace" => &["scale"],
            _ => {
                return Err(Error::UnknownName {
                    kind: "likelihood".into(),
                    name: family.to_string(),
                    known: NOISE_FAMILIES.iter().map(|s| s.to_string()).collect(),
                })
            }
        };
        let mut values: Vec<Option<&str>> = vec![None; keys.len()];
        if !rest.is_empty() {
            for item in rest.split(',') {
                let (k, v) = item.split_once('=').map(|(k, v)| (k.trim(), v.trim())).ok_or_else(|| {
                    invalid(format!("expected KEY=VALUE in `{spec}`, got `{}`", item.trim()))
                })?;
                // Aliases of the issue-4 CLI syntax (`sd`, `outlier-sd`).
                let k = match k {
                    "sd" => "sigma",
                    "outlier-sd" => "sigma_outlier",
                    other => other,
                };
                let j = keys.iter().position(|&key| key == k).ok_or_else(|| {
                    invalid(format!("unknown key `{k}` for {family} (accepted: {})", keys.join(", ")))
                })?;
                if values[j].replace(v).is_some() {
                    return Err(invalid(format!("key `{k}` given twice in `{spec}`")));
                }
            }
        }
        let mut missing = keys.iter().zip(&values).filter(|(_, v)| v.is_none()).map(|(k, _)| *k);
        if let Some(k) = missing.next() {
            return Err(invalid(format!(
                "missing key `{k}` for {family} (required: {}; e.g. `{}`)",
                keys.join(", "),
                example(family)
            )));
        }
        let vals: Vec<&str> = values.into_iter().flatten().collect();
        let param = |i: usize| parse_param(vals[i], param_names);
        let noise = match family {
            "gaussian" => Noise::Gaussian { sigma: param(0)? },
            "student-t" => Noise::StudentT { nu: param(0)?, scale: param(1)? },
            "mixture" => Noise::Mixture { p_outlier: param(0)?, sigma: param(1)?, sigma_outlier: param(2)? },
            "quantized" => {
                let bit = vals[1].parse::<f64>().map_err(|_| {
                    invalid(format!("`bit` must be a number (the fixed bit length), got `{}`", vals[1]))
                })?;
                Noise::Quantized { sigma: param(0)?, bit }
            }
            _ => Noise::Laplace { scale: param(0)? },
        };
        // Check the fixed values: validate with a θ of harmless values at the Theta indices.
        let theta: Vec<f64> = vec![0.5; param_names.len()];
        noise.validate(param_names.len(), &theta).map_err(|e| match e {
            Error::InvalidOption { name, reason } => invalid(format!("{name} {reason}")),
            other => other,
        })?;
        Ok(noise)
    }

    /// The CLI syntax with θ components printed by name (`theta[i]` for indices beyond
    /// `param_names`); [`Noise::parse`] with the same names reads it back.
    pub fn describe(&self, param_names: &[String]) -> String {
        let mut parts: Vec<String> =
            self.params().into_iter().map(|(k, p)| format!("{k}={}", p.spell(param_names))).collect();
        if let Noise::Quantized { bit, .. } = *self {
            parts.push(format!("bit={}", format_number(bit)));
        }
        format!("{}:{}", self.family(), parts.join(","))
    }
}

/// Formats a number for the CLI syntax so that it parses back to the same `f64`: the shortest
/// round-trip decimal (`0.1`, `3`), in exponent form (`1e-7`, `2.5e300`) below 1e-4 or from
/// 1e15 on in magnitude.
pub(crate) fn format_number(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && a.is_finite() && !(1e-4..1e15).contains(&a) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// An example spelling of each family, for error messages.
fn example(family: &str) -> &'static str {
    match family {
        "gaussian" => "gaussian:sigma=0.1",
        "student-t" => "student-t:nu=4,scale=0.1",
        "mixture" => "mixture:p=0.25,sigma=0.5,sigma_outlier=3",
        "quantized" => "quantized:sigma=0.1,bit=0.05",
        _ => "laplace:scale=0.2",
    }
}

/// A value of the CLI syntax: a number, a parameter name, or `theta[i]`.
fn parse_param(value: &str, param_names: &[String]) -> Result<Param> {
    if let Ok(v) = value.parse::<f64>() {
        return Ok(Param::Fixed(v));
    }
    if let Some(i) = param_names.iter().position(|n| n == value) {
        return Ok(Param::Theta(i));
    }
    if let Some(i) =
        value.strip_prefix("theta[").and_then(|s| s.strip_suffix(']')).and_then(|s| s.parse::<usize>().ok())
    {
        if i < param_names.len() {
            return Ok(Param::Theta(i));
        }
    }
    Err(Error::UnknownName { kind: "parameter".into(), name: value.to_string(), known: param_names.to_vec() })
}

impl fmt::Display for Noise {
    /// The CLI syntax of [`Noise::parse`], θ components printed as `theta[i]`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.describe(&[]))
    }
}

/// ln N(r; 0, s²) = −ln(s√(2π)) − r²/(2s²).
fn gaussian_log_density<D: Scalar>(r: D, s: D) -> D {
    let z = r / s;
    -s.ln() - LN_SQRT_2PI - z * z * 0.5
}

/// Measurements of a selection of the states through one scalar noise law:
/// `y_k = s[states[k]] + ε_k`, ε_k independent with law `noise`, where `s = [x; z]` is the
/// concatenated state vector (an index below the number of noisy states n means `x[i]`, else
/// `z[i − n]`).
///
/// `ln ψ(y | x, z, θ) = Σ_k ln ψ_noise(y_k | s[states[k]], θ)`, NaN components skipped.
#[derive(Debug, Clone, PartialEq)]
pub struct StateMeasurement {
    /// Indices into s = [x; z] of the measured states, one per output.
    pub states: Vec<usize>,
    /// Output names (the data CSV's columns), one per output.
    pub names: Vec<String>,
    /// The measurement-error law of every component.
    pub noise: Noise,
}

impl StateMeasurement {
    /// Measures `states` (indices into s = [x; z]) as outputs named `names` through `noise`.
    /// Check the lengths and indices against a model with [`StateMeasurement::validate`].
    pub fn new(states: Vec<usize>, names: Vec<String>, noise: Noise) -> StateMeasurement {
        StateMeasurement { states, names, noise }
    }

    /// Checks the measurement against a model's dimensions and a parameter vector: as many
    /// names as states ([`Error::DimensionMismatch`]), no repeated name, state indices below
    /// `dims.states()` ([`Error::InvalidOption`]) and [`Noise::validate`].
    pub fn validate(&self, dims: super::Dims, theta: &[f64]) -> Result<()> {
        super::check_len("measurement output names", self.states.len(), self.names.len())?;
        for (k, &i) in self.states.iter().enumerate() {
            if i >= dims.states() {
                return Err(Error::InvalidOption {
                    name: "measured states".into(),
                    reason: format!(
                        "output `{}` measures state index {i}, but the model has {} states",
                        self.names[k],
                        dims.states()
                    ),
                });
            }
        }
        for (k, n) in self.names.iter().enumerate() {
            if self.names[..k].contains(n) {
                return Err(Error::InvalidOption {
                    name: "measurement output names".into(),
                    reason: format!("output name `{n}` is repeated"),
                });
            }
        }
        self.noise.validate(dims.params, theta)
    }

    /// The first datum (in time, then output order) of a measured state that `inside(state, y)`
    /// rejects: its state and the datum as "name = y at t = …"; `None` if there is none.
    /// Missing values (NaN) are skipped. For the checks that a grid or a box covers the data.
    pub fn first_datum_outside(
        &self,
        data: &crate::data::Dataset,
        inside: impl Fn(usize, f64) -> bool,
    ) -> Option<(usize, String)> {
        for (k, row) in data.values.iter().enumerate() {
            for (c, &state) in self.states.iter().enumerate() {
                let y = row[c];
                if !y.is_nan() && !inside(state, y) {
                    return Some((state, format!("{} = {y} at t = {}", data.names[c], data.times[k])));
                }
            }
        }
        None
    }

    /// s[i] for s = [x; z], `None` when out of range.
    fn state<D: Copy>(i: usize, x: &[D], z: &[D]) -> Option<D> {
        if i < x.len() {
            Some(x[i])
        } else {
            z.get(i - x.len()).copied()
        }
    }
}

impl Observation for StateMeasurement {
    fn output_names(&self) -> Vec<String> {
        self.names.clone()
    }

    fn measured_state(&self, output: usize) -> Option<usize> {
        self.states.get(output).copied()
    }

    fn gaussian_error_sd(&self, theta: &[f64]) -> Option<f64> {
        self.noise.gaussian_sd(theta)
    }

    fn output_dim(&self) -> usize {
        self.states.len()
    }

    /// `Σ_k ln ψ_noise(y_k | s[states[k]], θ)` over the non-NaN components. NaN when `y` has
    /// the wrong length or a state index is out of range (ruled out by
    /// [`StateMeasurement::validate`]).
    fn log_likelihood<D: Scalar>(&self, _t: f64, y: &[f64], x: &[D], z: &[D], theta: &[D]) -> D {
        if y.len() != self.states.len() {
            return D::from(f64::NAN);
        }
        let mut total = D::from(0.0);
        for (&yk, &i) in y.iter().zip(&self.states) {
            if yk.is_nan() {
                continue;
            }
            match Self::state(i, x, z) {
                Some(m) => total += self.noise.log_density(yk, m, theta),
                None => return D::from(f64::NAN),
            }
        }
        total
    }

    /// `y_k` = a draw of the noise law around `s[states[k]]`; NaN for an out-of-range state index
    /// (ruled out by [`StateMeasurement::validate`]). Fills `min(y.len(), outputs)` entries.
    fn sample<R: Rng + ?Sized>(
        &self,
        _t: f64,
        x: &[f64],
        z: &[f64],
        theta: &[f64],
        rng: &mut R,
        y: &mut [f64],
    ) {
        for (yk, &i) in y.iter_mut().zip(&self.states) {
            *yk = match Self::state(i, x, z) {
                Some(m) => self.noise.sample(m, theta, rng),
                None => f64::NAN,
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Dims;
    use approx::assert_relative_eq;
    use num_dual::{Dual64, HyperDual64};
    use proptest::prelude::*;
    use rand::rngs::StdRng;
    use rand::SeedableRng;
    use statrs::distribution::{Continuous, Laplace, Normal, StudentsT};

    fn names(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    /// θ = (σ, ν, s, p, σ_o, b) and each family with all its parameters taken from θ.
    const SIGMA: usize = 0;
    const NU: usize = 1;
    const SCALE: usize = 2;
    const P: usize = 3;
    const SIGMA_O: usize = 4;
    const B: usize = 5;

    fn families(bit: f64) -> Vec<Noise> {
        use Param::Theta;
        vec![
            Noise::Gaussian { sigma: Theta(SIGMA) },
            Noise::StudentT { nu: Theta(NU), scale: Theta(SCALE) },
            Noise::Mixture { p_outlier: Theta(P), sigma: Theta(SIGMA), sigma_outlier: Theta(SIGMA_O) },
            Noise::Quantized { sigma: Theta(SIGMA), bit },
            Noise::Laplace { scale: Theta(B) },
        ]
    }

    /// The reference log-density from statrs (`ln_pdf`), or the log of the statrs mixture.
    fn statrs_log_density(noise: &Noise, y: f64, m: f64, th: &[f64]) -> f64 {
        match noise {
            Noise::Gaussian { .. } => Normal::new(m, th[SIGMA]).unwrap().ln_pdf(y),
            Noise::StudentT { .. } => StudentsT::new(m, th[SCALE], th[NU]).unwrap().ln_pdf(y),
            Noise::Mixture { .. } => {
                let p = th[P];
                ((1.0 - p) * Normal::new(m, th[SIGMA]).unwrap().pdf(y)
                    + p * Normal::new(m, th[SIGMA_O]).unwrap().pdf(y))
                .ln()
            }
            Noise::Laplace { .. } => Laplace::new(m, th[B]).unwrap().ln_pdf(y),
            Noise::Quantized { .. } => unreachable!("no statrs counterpart"),
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]

        /// Continuous laws agree with statrs to 1e-12 relative (statrs evaluates the same
        /// closed forms with its own ln Γ; the mixture is the log of statrs' pdfs, kept within
        /// 8σ_o so that the pdfs do not underflow).
        #[test]
        fn log_densities_match_statrs(
            m in -3.0..3.0_f64, z in -8.0..8.0_f64, sigma in 0.05..3.0_f64, nu in 0.5..30.0_f64,
            scale in 0.05..3.0_f64, p in 0.0..0.99_f64, sigma_o in 0.05..5.0_f64, b in 0.05..3.0_f64,
        ) {
            let th = [sigma, nu, scale, p, sigma_o, b];
            let y = m + z * sigma;
            for noise in families(0.1).iter().filter(|n| !matches!(n, Noise::Quantized { .. })) {
                let ours: f64 = noise.log_density(y, m, &th);
                let reference = statrs_log_density(noise, y, m, &th);
                prop_assert!((ours - reference).abs() <= 1e-12 * reference.abs().max(1.0),
                    "{}: {} vs statrs {}", noise, ours, reference);
            }
        }

        /// ∂/∂m and ∂/∂θ_j of ln ψ (Dual64) agree with five-point differences, relative 1e-6,
        /// for every family (mixture both with p = 0 and p > 0).
        #[test]
        fn gradients_match_finite_differences(
            m in -3.0..3.0_f64, z in -6.0..6.0_f64, sigma in 0.05..3.0_f64, nu in 0.5..30.0_f64,
            scale in 0.05..3.0_f64, p in 0.0..0.99_f64, sigma_o in 0.05..5.0_f64, b in 0.05..3.0_f64,
            bit in 0.01..2.0_f64, p_zero in proptest::bool::ANY,
        ) {
            let th = [sigma, nu, scale, if p_zero { 0.0 } else { p }, sigma_o, b];
            let y = m + z * sigma;
            for noise in families(bit) {
                // w = (m, θ); the step keeps θ inside its domain.
                let w: Vec<f64> = std::iter::once(m).chain(th.iter().copied()).collect();
                let f = |w: &[f64]| noise.log_density(y, w[0], &w[1..]);
                for j in 0..w.len() {
                    if j == 1 + P && th[P] < 1e-3 {
                        continue; // the stencil would leave [0, 1); p = 0 is checked below
                    }
                    let h = 1e-4 * w[j].abs().max(0.05);
                    if j == 0 && matches!(noise, Noise::Laplace { .. }) && (y - m).abs() < 3.0 * h {
                        continue; // the stencil would straddle the kink of |y − m|
                    }
                    let mut wd: Vec<Dual64> = w.iter().map(|&v| Dual64::from(v)).collect();
                    wd[j].eps = 1.0;
                    let ad = noise.log_density(y, wd[0], &wd[1..]).eps;
                    let fd = five_point(&f, &w, j, h);
                    let tol = 1e-6 * fd.abs() + 1e-13 * f(&w).abs().max(1.0) / h;
                    prop_assert!((ad - fd).abs() <= tol, "{} d/dw[{}]: {} vs {}", noise, j, ad, fd);
                }
            }
            // Mixture at p = 0: ∂/∂p ln ψ = N(y; m, σ_o²)/N(y; m, σ²) − 1 (closed form).
            let mix = &families(bit)[2];
            let mut thd: Vec<Dual64> = th.iter().map(|&v| Dual64::from(v)).collect();
            thd[P] = Dual64::new(0.0, 1.0);
            let ad = mix.log_density(y, Dual64::from(m), &thd).eps;
            let n = |s: f64| Normal::new(m, s).unwrap().pdf(y);
            let exact = n(sigma_o) / n(sigma) - 1.0;
            prop_assert!((ad - exact).abs() <= 1e-9 * exact.abs().max(1.0), "mixture d/dp at 0: {} vs {}", ad, exact);
        }

        /// HyperDual second derivatives of the quantized log-mass with respect to (m, σ) agree
        /// with five-point differences of its Dual64 first derivatives, including 40σ out.
        #[test]
        fn quantized_second_derivatives_match_finite_differences(
            m in -2.0..2.0_f64, z in -42.0..42.0_f64, sigma in 0.05..2.0_f64, bit in 0.01..2.0_f64,
        ) {
            let noise = Noise::Quantized { sigma: Param::Theta(0), bit };
            let y = bit * ((m + z * sigma) / bit).round();
            let w = [m, sigma];
            let first = |w: &[f64], i: usize| {
                let mut d = [Dual64::from(w[0]), Dual64::from(w[1])];
                d[i].eps = 1.0;
                noise.log_density(y, d[0], &d[1..]).eps
            };
            for i in 0..2 {
                for j in 0..2 {
                    let mut d = [HyperDual64::from(w[0]), HyperDual64::from(w[1])];
                    d[i].eps1 = 1.0;
                    d[j].eps2 = 1.0;
                    let ad = noise.log_density(y, d[0], &d[1..]).eps1eps2;
                    let h = 1e-4 * sigma.min(bit);
                    let fd = five_point(&|w: &[f64]| first(w, i), &w, j, h);
                    let tol = 1e-6 * fd.abs() + 1e-13 * first(&w, i).abs().max(1.0) / h;
                    prop_assert!((ad - fd).abs() <= tol, "d²/dw{}dw{} at y={}, m={}, σ={}, l={}: {} vs {}",
                        i, j, y, m, sigma, bit, ad, fd);
                }
            }
        }
    }

    /// Five-point central difference in component j (truncation O(h⁴)).
    fn five_point(f: &dyn Fn(&[f64]) -> f64, w: &[f64], j: usize, h: f64) -> f64 {
        let at = |d: f64| {
            let mut v = w.to_vec();
            v[j] += d;
            f(&v)
        };
        (at(-2.0 * h) - 8.0 * at(-h) + 8.0 * at(h) - at(2.0 * h)) / (12.0 * h)
    }

    #[test]
    fn quantized_mass_sums_to_one_over_the_lattice() {
        // Σ_k [Φ((l k − m + l/2)/σ) − Φ((l k − m − l/2)/σ)] telescopes to 1 (identity).
        for (m, sigma, bit) in
            [(0.0, 0.1, 0.05), (0.37, 0.1, 1.0), (-1.234, 2.0, 0.3), (5.0, 0.01, 0.5), (0.1, 1.0, 1e-3)]
        {
            let noise = Noise::Quantized { sigma: Param::Fixed(sigma), bit };
            let lo = ((m - 45.0 * sigma) / bit).floor() as i64 - 1;
            let hi = ((m + 45.0 * sigma) / bit).ceil() as i64 + 1;
            let total: f64 = (lo..=hi).map(|k| noise.log_density::<f64>(bit * k as f64, m, &[]).exp()).sum();
            let n = (hi - lo + 1) as f64;
            assert_relative_eq!(total, 1.0, epsilon = 0.0, max_relative = 1e-15 * n.max(10.0));
        }
    }

    #[test]
    fn quantized_far_tail_is_finite_and_accurate() {
        // y − m = ±40σ with σ = 1/8, l_b = 1/4 (exact binary fractions), so the interval is
        // [39, 41] standard deviations: ln ψ = ln(Φ(−39) − Φ(−41)) = −765.08315656437754
        // (mpmath 1.3, 80 digits: m.log(m.ncdf(-39) - m.ncdf(-41))).
        let noise = Noise::Quantized { sigma: Param::Fixed(0.125), bit: 0.25 };
        for y in [5.0, -5.0] {
            let v: f64 = noise.log_density(y, 0.0, &[]);
            assert_relative_eq!(v, -765.083_156_564_377_5, epsilon = 0.0, max_relative = 1e-15);
        }
        // 40σ with l_b = σ/2: ln(Φ(−39.75) − Φ(−40.25)) = −794.6334302644475 (mpmath, as above).
        let noise = Noise::Quantized { sigma: Param::Fixed(1.0), bit: 0.5 };
        let v: f64 = noise.log_density(40.0, 0.0, &[]);
        assert_relative_eq!(v, -794.633_430_264_447_5, epsilon = 0.0, max_relative = 1e-14);
        // 1000σ out: ψ = Φ(−u) − Φ(−u − 1/2), u = 999.75, where Φ(−u − ½)/Φ(−u) ≈ e^{−500} is
        // negligible and ln Φ(−u) = −u²/2 − ln(u√(2π)) + ln(1 − 1/u² + 3/u⁴ − …) (A&S 26.2.12,
        // truncation 15/u⁶ ≈ 1.5e-17).
        let v: f64 = noise.log_density(1000.0, 0.0, &[]);
        let u: f64 = 999.75;
        let asymptotic = -0.5 * u * u - u.ln() - LN_SQRT_2PI + (-1.0 / (u * u) + 3.0 / u.powi(4)).ln_1p();
        assert_relative_eq!(v, asymptotic, epsilon = 0.0, max_relative = 1e-15);
    }

    #[test]
    fn invalid_parameters_give_minus_infinity_and_bad_indices_nan() {
        let th = [-1.0, 2.0];
        let g = Noise::Gaussian { sigma: Param::Theta(0) };
        assert_eq!(g.log_density::<f64>(0.0, 0.0, &th), f64::NEG_INFINITY);
        let g = Noise::Gaussian { sigma: Param::Theta(7) };
        assert!(g.log_density::<f64>(0.0, 0.0, &th).is_nan());
        let m = Noise::Mixture {
            p_outlier: Param::Fixed(1.0),
            sigma: Param::Fixed(1.0),
            sigma_outlier: Param::Fixed(2.0),
        };
        assert_eq!(m.log_density::<f64>(0.0, 0.0, &th), f64::NEG_INFINITY);
        let q = Noise::Quantized { sigma: Param::Theta(1), bit: 0.0 };
        assert_eq!(q.log_density::<f64>(0.0, 0.0, &th), f64::NEG_INFINITY);
    }

    #[test]
    fn validate_names_the_field() {
        let n = Noise::Mixture {
            p_outlier: Param::Theta(0),
            sigma: Param::Fixed(0.5),
            sigma_outlier: Param::Theta(1),
        };
        assert!(n.validate(2, &[0.25, 3.0]).is_ok());
        let err = |r: Result<()>| match r {
            Err(Error::InvalidOption { name, .. }) => name,
            other => panic!("expected InvalidOption, got {other:?}"),
        };
        assert_eq!(err(n.validate(2, &[1.0, 3.0])), "mixture.p");
        assert_eq!(err(n.validate(2, &[0.2, -3.0])), "mixture.sigma_outlier");
        assert_eq!(err(n.validate(2, &[0.2, f64::NAN])), "mixture.sigma_outlier");
        assert!(matches!(n.validate(3, &[0.2, 3.0]), Err(Error::DimensionMismatch { .. })));
        assert_eq!(
            err(Noise::Gaussian { sigma: Param::Theta(2) }.validate(2, &[1.0, 1.0])),
            "gaussian.sigma"
        );
        assert_eq!(
            err(Noise::StudentT { nu: Param::Fixed(0.0), scale: Param::Fixed(1.0) }.validate(0, &[])),
            "student-t.nu"
        );
        assert_eq!(
            err(Noise::Quantized { sigma: Param::Fixed(1.0), bit: -0.1 }.validate(0, &[])),
            "quantized.bit"
        );
        assert_eq!(
            err(Noise::Laplace { scale: Param::Fixed(f64::INFINITY) }.validate(0, &[])),
            "laplace.scale"
        );
        assert_eq!(Noise::Gaussian { sigma: Param::Theta(1) }.gaussian_sd(&[0.0, 0.3]), Some(0.3));
        assert_eq!(Noise::Laplace { scale: Param::Fixed(1.0) }.gaussian_sd(&[]), None);
    }

    #[test]
    fn parse_and_display_round_trip() {
        let pn = names(&["a", "sigma_y", "nu"]);
        let cases = [
            ("gaussian:sigma=0.1", Noise::Gaussian { sigma: Param::Fixed(0.1) }),
            ("gaussian:sigma=sigma_y", Noise::Gaussian { sigma: Param::Theta(1) }),
            (
                "student-t:nu=4,scale=sigma_y",
                Noise::StudentT { nu: Param::Fixed(4.0), scale: Param::Theta(1) },
            ),
            ("student-t:nu=nu,scale=0.3", Noise::StudentT { nu: Param::Theta(2), scale: Param::Fixed(0.3) }),
            (
                "mixture:p=0.25,sigma=0.5,sigma_outlier=3",
                Noise::Mixture {
                    p_outlier: Param::Fixed(0.25),
                    sigma: Param::Fixed(0.5),
                    sigma_outlier: Param::Fixed(3.0),
                },
            ),
            ("quantized:sigma=sigma_y,bit=0.05", Noise::Quantized { sigma: Param::Theta(1), bit: 0.05 }),
            ("laplace:scale=0.2", Noise::Laplace { scale: Param::Fixed(0.2) }),
        ];
        for (spec, expected) in cases {
            let parsed = Noise::parse(spec, &pn).unwrap();
            assert_eq!(parsed, expected, "{spec}");
            assert_eq!(parsed.describe(&pn), spec);
            // Display uses theta[i], which parse reads back with the same names.
            let shown = parsed.to_string();
            assert_eq!(Noise::parse(&shown, &pn).unwrap(), expected, "{shown}");
        }
        assert_eq!(Noise::Gaussian { sigma: Param::Theta(1) }.to_string(), "gaussian:sigma=theta[1]");
        let tiny = Noise::Quantized { sigma: Param::Fixed(1.5e-7), bit: 1e20 };
        assert_eq!(tiny.to_string(), "quantized:sigma=1.5e-7,bit=1e20");
        assert_eq!(Noise::parse(&tiny.to_string(), &pn).unwrap(), tiny);
        // Spaces, key order and full-precision numbers.
        let n =
            Noise::parse(" mixture : sigma_outlier = 3 , p=0.1, sigma=0.30000000000000004 ", &pn).unwrap();
        assert_eq!(
            n,
            Noise::Mixture {
                p_outlier: Param::Fixed(0.1),
                sigma: Param::Fixed(0.30000000000000004),
                sigma_outlier: Param::Fixed(3.0)
            }
        );
        assert_eq!(Noise::parse(&n.to_string(), &pn).unwrap(), n);
        // The aliases of the issue-4 syntax.
        assert_eq!(
            Noise::parse("mixture:p=0.25,sd=0.5,outlier-sd=3", &pn).unwrap(),
            Noise::parse("mixture:p=0.25,sigma=0.5,sigma_outlier=3", &pn).unwrap()
        );
        assert_eq!(
            Noise::parse("quantized:bit=0.05,sd=sigma_y", &pn).unwrap(),
            Noise::Quantized { sigma: Param::Theta(1), bit: 0.05 }
        );
    }

    #[test]
    fn parse_errors() {
        let pn = names(&["a", "sigma_y"]);
        let unknown = |spec: &str| match Noise::parse(spec, &pn) {
            Err(Error::UnknownName { kind, name, known }) => (kind, name, known),
            other => panic!("{spec}: expected UnknownName, got {other:?}"),
        };
        let (kind, name, known) = unknown("cauchy:scale=1");
        assert_eq!((kind.as_str(), name.as_str()), ("likelihood", "cauchy"));
        assert_eq!(known, NOISE_FAMILIES.to_vec());
        let (kind, name, known) = unknown("gaussian:sigma=sigma_z");
        assert_eq!((kind.as_str(), name.as_str(), known), ("parameter", "sigma_z", pn.clone()));
        assert_eq!(unknown("gaussian:sigma=theta[2]").1, "theta[2]");
        let invalid = |spec: &str| match Noise::parse(spec, &pn) {
            Err(Error::InvalidOption { name, reason }) => {
                assert_eq!(name, "--likelihood");
                reason
            }
            other => panic!("{spec}: expected InvalidOption, got {other:?}"),
        };
        assert!(invalid("gaussian:scale=0.1").contains("accepted: sigma"));
        assert!(invalid("student-t:nu=4").contains("missing key `scale`"));
        assert!(invalid("gaussian").contains("missing key `sigma`"));
        assert!(invalid("gaussian:sigma=0.1,sigma=0.2").contains("twice"));
        assert!(invalid("gaussian:sigma").contains("KEY=VALUE"));
        assert!(invalid("quantized:sigma=0.1,bit=sigma_y").contains("must be a number"));
        assert!(invalid("gaussian:sigma=-1").contains("positive"));
        assert!(invalid("mixture:p=1.5,sigma=1,sigma_outlier=2").contains("[0, 1)"));
    }

    #[test]
    fn state_measurement_sums_components_and_skips_missing() {
        // s = [x0, x1; z0]; outputs z0 and x1, Gaussian σ = θ[0].
        let obs = StateMeasurement::new(
            vec![2, 1],
            names(&["pos", "vel"]),
            Noise::Gaussian { sigma: Param::Theta(0) },
        );
        let dims = Dims { noisy: 2, clean: 1, params: 1 };
        let th = [0.5];
        obs.validate(dims, &th).unwrap();
        assert_eq!(obs.output_names(), names(&["pos", "vel"]));
        assert_eq!(obs.output_dim(), 2);
        let (x, z) = ([1.0, 2.0], [3.0]);
        let ln = |y: f64, m: f64| Normal::new(m, 0.5).unwrap().ln_pdf(y);
        let both: f64 = obs.log_likelihood(0.0, &[3.2, 1.9], &x, &z, &th);
        assert_relative_eq!(both, ln(3.2, 3.0) + ln(1.9, 2.0), epsilon = 0.0, max_relative = 1e-14);
        let one: f64 = obs.log_likelihood(0.0, &[f64::NAN, 1.9], &x, &z, &th);
        assert_relative_eq!(one, ln(1.9, 2.0), epsilon = 0.0, max_relative = 1e-14);
        let none: f64 = obs.log_likelihood(0.0, &[f64::NAN, f64::NAN], &x, &z, &th);
        assert_eq!(none, 0.0);
        // Derivative with respect to z0: (y − z0)/σ² = 0.2/0.25 (closed form).
        let zd = [Dual64::new(3.0, 1.0)];
        let xd = [Dual64::from(1.0), Dual64::from(2.0)];
        let thd = [Dual64::from(0.5)];
        assert_relative_eq!(
            obs.log_likelihood(0.0, &[3.2, 1.9], &xd, &zd, &thd).eps,
            0.8,
            epsilon = 0.0,
            max_relative = 1e-14
        );
        // Contract violations.
        assert!(obs.log_likelihood::<f64>(0.0, &[1.0], &x, &z, &th).is_nan());
        let bad = StateMeasurement::new(vec![3], names(&["y"]), Noise::Gaussian { sigma: Param::Fixed(1.0) });
        assert!(matches!(bad.validate(dims, &th), Err(Error::InvalidOption { .. })));
        let bad =
            StateMeasurement::new(vec![0, 1], names(&["y"]), Noise::Gaussian { sigma: Param::Fixed(1.0) });
        assert!(matches!(bad.validate(dims, &th), Err(Error::DimensionMismatch { .. })));
        let bad = StateMeasurement::new(
            vec![0, 1],
            names(&["y", "y"]),
            Noise::Gaussian { sigma: Param::Fixed(1.0) },
        );
        assert!(matches!(bad.validate(dims, &th), Err(Error::InvalidOption { .. })));
        // Sampling: the quantized law lands on the lattice.
        let q = StateMeasurement::new(
            vec![0, 2],
            names(&["a", "b"]),
            Noise::Quantized { sigma: Param::Fixed(0.3), bit: 0.25 },
        );
        let mut rng = StdRng::seed_from_u64(7);
        let mut y = [0.0; 2];
        for _ in 0..100 {
            q.sample(0.0, &x, &z, &[], &mut rng, &mut y);
            for v in y {
                assert_eq!((v / 0.25).round() * 0.25, v);
            }
        }
    }

    /// Monte Carlo check of every sampler: mean and variance within 4 standard errors
    /// (n = 40 000, seeded). Variances: σ² (Gaussian), s² ν/(ν − 2) (Student-t, ν = 6),
    /// (1 − p)σ² + pσ_o² (mixture), σ² + l_b²/12 (quantized, Sheppard's correction, exact up to
    /// ~e^{−2π²σ²/l_b²} ≈ 1e-34 here), 2b² (Laplace). The variance's standard error uses the fourth
    /// central moment estimated from the sample.
    #[test]
    fn samplers_have_the_right_mean_and_variance() {
        let th = [0.4, 6.0, 0.3, 0.2, 2.0, 0.7];
        let m = 1.5;
        let laws = families(0.2);
        let variances = [0.16, 0.09 * 6.0 / 4.0, 0.8 * 0.16 + 0.2 * 4.0, 0.16 + 0.04 / 12.0, 2.0 * 0.49];
        let mut rng = StdRng::seed_from_u64(20_261_121);
        let n = 40_000;
        for (law, var) in laws.iter().zip(variances) {
            let s: Vec<f64> = (0..n).map(|_| law.sample(m, &th, &mut rng)).collect();
            let mean = s.iter().sum::<f64>() / n as f64;
            let v = s.iter().map(|y| (y - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
            let m4 = s.iter().map(|y| (y - mean).powi(4)).sum::<f64>() / n as f64;
            let se_mean = (var / n as f64).sqrt();
            let se_var = ((m4 - v * v) / n as f64).sqrt();
            assert!((mean - m).abs() < 4.0 * se_mean, "{law}: mean {mean}");
            assert!((v - var).abs() < 4.0 * se_var, "{law}: variance {v} vs {var} (se {se_var})");
        }
        // Invalid parameters give NaN, which simulate reports as an error.
        assert!(Noise::Gaussian { sigma: Param::Theta(9) }.sample(0.0, &th, &mut rng).is_nan());
    }
}
