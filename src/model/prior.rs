//! Priors on the initial states x0, z0 and the parameters θ.
//!
//! A [`Prior`] is a one-dimensional density ([`PriorDensity`]: flat, Gaussian, gamma,
//! log-normal), optionally truncated to an interval [lower, upper]. Joint priors are products of
//! these, as in `000_74b95e149527c64e.txt (4.7)`: Gaussian priors on states and drift
//! parameters, a gamma prior on the measurement scale σ_y.
//!
//! The CLI syntax (parsed by [`Prior::parse`], printed by `Display`):
//!
//! ```text
//! flat                    improper constant density
//! normal:MEAN,SD          N(MEAN, SD²)            (also `gaussian:MEAN,SD`)
//! gamma:SHAPE,SCALE       Γ(SHAPE, SCALE), density ∝ x^(SHAPE−1) e^(−x/SCALE)
//! lognormal:MU,SIGMA      ln X ~ N(MU, SIGMA²)
//! ...;lower=L,upper=U     optional truncation to [L, U] (either bound may be left out)
//! ```
//!
//! e.g. `normal:0,0.4`, `gamma:1.1,10`, `flat;lower=0`, `normal:1,2;lower=0,upper=5`.

use std::fmt;

use rand::{Rng, RngExt};
use rand_distr::Distribution;
use statrs::distribution::ContinuousCDF;

use super::observation::format_number as num;
use super::special::{ln_gamma, log_diff_ndtr};
use super::Scalar;
use crate::{Error, Result};

/// ln √(2π).
const LN_SQRT_2PI: f64 = 0.918_938_533_204_672_8;

/// Maximum number of draws of rejection sampling from a truncated prior.
const MAX_REJECTIONS: usize = 100_000;

/// The untruncated density of a [`Prior`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PriorDensity {
    /// The improper constant density (log-density 0).
    Flat,
    /// N(mean, sd²): ln p = −ln(sd √(2π)) − (x − mean)²/(2 sd²).
    Gaussian {
        /// Mean.
        mean: f64,
        /// Standard deviation, > 0.
        sd: f64,
    },
    /// Gamma with shape r and scale s on (0, ∞), `000_74b95e149527c64e.txt (4.5), (4.7)`:
    /// ln p = (r − 1) ln x − x/s − ln Γ(r) − r ln s.
    Gamma {
        /// Shape r > 0.
        shape: f64,
        /// Scale s > 0 (the mean is r s).
        scale: f64,
    },
    /// Log-normal on (0, ∞): ln X ~ N(mu, sigma²),
    /// ln p = −ln x − ln(sigma √(2π)) − (ln x − mu)²/(2 sigma²).
    LogNormal {
        /// Mean of ln X.
        mu: f64,
        /// Standard deviation of ln X, > 0.
        sigma: f64,
    },
}

/// A one-dimensional prior: a [`PriorDensity`] truncated to [`lower`, `upper`] (±∞ by
/// default, i.e. not truncated).
///
/// [`Prior::log_density`] is normalised over the truncated support for the proper densities
/// and is 0 (unnormalised) inside the bounds for [`PriorDensity::Flat`]. Check the
/// hyperparameters with [`Prior::validate`] ([`Prior::parse`] does).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prior {
    /// The untruncated density.
    pub density: PriorDensity,
    /// Lower bound (−∞ for none); the support is [lower, upper].
    pub lower: f64,
    /// Upper bound (+∞ for none).
    pub upper: f64,
}

impl Default for Prior {
    /// The flat, unbounded prior.
    fn default() -> Self {
        Prior::flat()
    }
}

impl Prior {
    fn unbounded(density: PriorDensity) -> Prior {
        Prior { density, lower: f64::NEG_INFINITY, upper: f64::INFINITY }
    }

    /// The improper flat prior on the real line.
    pub fn flat() -> Prior {
        Prior::unbounded(PriorDensity::Flat)
    }

    /// The Gaussian prior N(mean, sd²).
    pub fn gaussian(mean: f64, sd: f64) -> Prior {
        Prior::unbounded(PriorDensity::Gaussian { mean, sd })
    }

    /// The gamma prior with shape r and scale s, density ∝ x^{r−1} e^{−x/s}
    /// (`000_74b95e149527c64e.txt (4.5), (4.7)`).
    pub fn gamma(shape: f64, scale: f64) -> Prior {
        Prior::unbounded(PriorDensity::Gamma { shape, scale })
    }

    /// The log-normal prior: ln X ~ N(mu, sigma²).
    pub fn log_normal(mu: f64, sigma: f64) -> Prior {
        Prior::unbounded(PriorDensity::LogNormal { mu, sigma })
    }

    /// The same density truncated to [lower, upper] (use ±∞ for a one-sided bound).
    pub fn with_bounds(self, lower: f64, upper: f64) -> Prior {
        Prior { lower, upper, ..self }
    }

    /// Whether the prior is a probability distribution (every density but a flat one with an
    /// infinite bound).
    pub fn is_proper(&self) -> bool {
        !matches!(self.density, PriorDensity::Flat) || (self.lower.is_finite() && self.upper.is_finite())
    }

    /// ln of the probability that the untruncated density gives to [lower, upper]
    /// (0 without bounds, and for the flat density).
    pub fn log_mass_in_bounds(&self) -> f64 {
        let (l, u) = (self.lower, self.upper);
        if l == f64::NEG_INFINITY && u == f64::INFINITY {
            return 0.0;
        }
        match self.density {
            PriorDensity::Flat => 0.0,
            PriorDensity::Gaussian { mean, sd } => log_diff_ndtr((l - mean) / sd, (u - mean) / sd),
            PriorDensity::LogNormal { mu, sigma } => {
                let z = |b: f64| if b <= 0.0 { f64::NEG_INFINITY } else { (b.ln() - mu) / sigma };
                log_diff_ndtr(z(l), z(u))
            }
            PriorDensity::Gamma { shape, scale } => gamma_log_mass(shape, scale, l, u),
        }
    }

    /// The log prior density at x, generic over the scalar for automatic differentiation:
    /// the [`PriorDensity`]'s formula minus [`Prior::log_mass_in_bounds`], −∞ outside
    /// [lower, upper] or outside the density's support (x ≤ 0 for gamma and log-normal), 0
    /// inside the bounds for the flat density. NaN when x is NaN or the hyperparameters are
    /// invalid (see [`Prior::validate`]).
    pub fn log_density<D: Scalar>(&self, x: D) -> D {
        let xr = x.re();
        if xr.is_nan() {
            return D::from(f64::NAN);
        }
        if xr < self.lower || xr > self.upper {
            return D::from(f64::NEG_INFINITY);
        }
        let unnormalised = match self.density {
            PriorDensity::Flat => return D::from(0.0),
            PriorDensity::Gaussian { mean, sd } => {
                let z = (x - mean) / sd;
                -z * z * 0.5 - (sd.ln() + LN_SQRT_2PI)
            }
            PriorDensity::Gamma { shape, scale } => {
                if xr <= 0.0 {
                    return D::from(f64::NEG_INFINITY);
                }
                x.ln() * (shape - 1.0) - x / scale - (ln_gamma(shape) + shape * scale.ln())
            }
            PriorDensity::LogNormal { mu, sigma } => {
                if xr <= 0.0 {
                    return D::from(f64::NEG_INFINITY);
                }
                let lx = x.ln();
                let z = (lx - mu) / sigma;
                -lx - z * z * 0.5 - (sigma.ln() + LN_SQRT_2PI)
            }
        };
        unnormalised - self.log_mass_in_bounds()
    }

    /// Draws from the (truncated) prior: the flat prior uniformly on finite bounds; the others
    /// by their samplers, truncated by rejection.
    ///
    /// Errors: [`Error::InvalidOption`] (name `prior`) for an improper prior (flat with an
    /// infinite bound), invalid hyperparameters, or when 100 000 draws all fall outside the
    /// bounds.
    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> Result<f64> {
        self.validate()?;
        let (l, u) = (self.lower, self.upper);
        let draw = |rng: &mut R| -> f64 {
            match self.density {
                PriorDensity::Flat => l + (u - l) * rng.random::<f64>(),
                PriorDensity::Gaussian { mean, sd } => {
                    let z: f64 = rand_distr::StandardNormal.sample(rng);
                    mean + sd * z
                }
                PriorDensity::Gamma { shape, scale } => match rand_distr::Gamma::new(shape, scale) {
                    Ok(g) => g.sample(rng),
                    Err(_) => f64::NAN,
                },
                PriorDensity::LogNormal { mu, sigma } => {
                    let z: f64 = rand_distr::StandardNormal.sample(rng);
                    (mu + sigma * z).exp()
                }
            }
        };
        if matches!(self.density, PriorDensity::Flat) {
            if !self.is_proper() {
                return Err(Error::InvalidOption {
                    name: "prior".into(),
                    reason: format!("cannot sample the improper prior `{self}`; give it finite bounds"),
                });
            }
            return Ok(draw(rng).clamp(l, u));
        }
        for _ in 0..MAX_REJECTIONS {
            let v = draw(rng);
            if v >= l && v <= u {
                return Ok(v);
            }
        }
        Err(Error::InvalidOption {
            name: "prior".into(),
            reason: format!(
                "rejection sampling from `{self}` failed {MAX_REJECTIONS} times: the bounds hold probability {:e}",
                self.log_mass_in_bounds().exp()
            ),
        })
    }

    /// The mean of the (truncated) prior: the midpoint of finite bounds for the flat prior
    /// (`None` if a bound is infinite); for the proper densities the closed forms of the
    /// truncated laws, with Z = the mass in the bounds:
    /// Gaussian μ + sd (φ(α) − φ(β))/Z; gamma r s [P(r+1, u/s) − P(r+1, l/s)]/[P(r, u/s) −
    /// P(r, l/s)] (P the regularised incomplete gamma function); log-normal
    /// e^{μ+σ²/2} [Φ(β − σ) − Φ(α − σ)]/Z, with α, β the standardised bounds.
    /// `None` when the hyperparameters are invalid or the result is not finite.
    pub fn mean(&self) -> Option<f64> {
        self.validate().ok()?;
        let (l, u) = (self.lower, self.upper);
        let bounded = l > f64::NEG_INFINITY || u < f64::INFINITY;
        let m = match self.density {
            PriorDensity::Flat => 0.5 * (l + u),
            PriorDensity::Gaussian { mean, sd } if bounded => {
                let (a, b) = ((l - mean) / sd, (u - mean) / sd);
                let log_z = log_diff_ndtr(a, b);
                let ln_phi = |t: f64| -0.5 * t * t - LN_SQRT_2PI;
                mean + sd * ((ln_phi(a) - log_z).exp() - (ln_phi(b) - log_z).exp())
            }
            PriorDensity::Gaussian { mean, .. } => mean,
            PriorDensity::Gamma { shape, scale } if bounded => {
                shape
                    * scale
                    * (gamma_log_mass(shape + 1.0, scale, l, u) - gamma_log_mass(shape, scale, l, u)).exp()
            }
            PriorDensity::Gamma { shape, scale } => shape * scale,
            PriorDensity::LogNormal { mu, sigma } => {
                let z = |b: f64| if b <= 0.0 { f64::NEG_INFINITY } else { (b.ln() - mu) / sigma };
                let (a, b) = (z(l), z(u));
                (mu + 0.5 * sigma * sigma + log_diff_ndtr(a - sigma, b - sigma) - log_diff_ndtr(a, b)).exp()
            }
        };
        m.is_finite().then_some(m)
    }

    /// Checks the hyperparameters (finite location, positive finite scales and shapes), the
    /// bounds (not NaN, lower < upper) and that the bounds hold positive probability.
    /// Errors: [`Error::InvalidOption`] naming the field (`prior.sd`, `prior.bounds`, …).
    pub fn validate(&self) -> Result<()> {
        let bad =
            |field: &str, reason: String| Error::InvalidOption { name: format!("prior.{field}"), reason };
        let positive = |field: &str, v: f64| {
            if v > 0.0 && v.is_finite() {
                Ok(())
            } else {
                Err(bad(field, format!("must be positive and finite, got {v}")))
            }
        };
        let finite = |field: &str, v: f64| {
            if v.is_finite() {
                Ok(())
            } else {
                Err(bad(field, format!("must be finite, got {v}")))
            }
        };
        match self.density {
            PriorDensity::Flat => {}
            PriorDensity::Gaussian { mean, sd } => {
                finite("mean", mean)?;
                positive("sd", sd)?;
            }
            PriorDensity::Gamma { shape, scale } => {
                positive("shape", shape)?;
                positive("scale", scale)?;
            }
            PriorDensity::LogNormal { mu, sigma } => {
                finite("mu", mu)?;
                positive("sigma", sigma)?;
            }
        }
        if self.lower.is_nan() || self.upper.is_nan() || self.lower >= self.upper {
            return Err(bad("bounds", format!("need lower < upper, got [{}, {}]", self.lower, self.upper)));
        }
        let log_mass = self.log_mass_in_bounds();
        if log_mass == f64::NEG_INFINITY || log_mass.is_nan() {
            return Err(bad(
                "bounds",
                format!("[{}, {}] holds no probability of `{self}`", self.lower, self.upper),
            ));
        }
        Ok(())
    }

    /// Parses the CLI syntax of the module documentation: `flat`, `normal:MEAN,SD` (or
    /// `gaussian:`), `gamma:SHAPE,SCALE`, `lognormal:MU,SIGMA`, each optionally followed by
    /// `;lower=L,upper=U` (either key may be left out; `inf` and `-inf` are accepted), and
    /// validates the result.
    ///
    /// Errors: [`Error::UnknownName`] (kind `prior`) for an unknown family;
    /// [`Error::InvalidOption`] (name `prior`) for a wrong number of values, an unparsable
    /// number, an unknown or repeated bound key; those of [`Prior::validate`].
    pub fn parse(spec: &str) -> Result<Prior> {
        let invalid = |reason: String| Error::InvalidOption { name: "prior".into(), reason };
        let (main, bounds) = match spec.split_once(';') {
            Some((m, b)) => (m.trim(), Some(b.trim())),
            None => (spec.trim(), None),
        };
        let (family, args) = match main.split_once(':') {
            Some((f, a)) => (f.trim(), Some(a.trim())),
            None => (main, None),
        };
        let number = |s: &str| -> Result<f64> {
            s.trim()
                .parse::<f64>()
                .map_err(|_| invalid(format!("cannot parse `{}` as a number in `{spec}`", s.trim())))
        };
        let values: Vec<f64> = match args {
            Some(a) => a.split(',').map(number).collect::<Result<_>>()?,
            None => Vec::new(),
        };
        let (expected, usage) = match family {
            "flat" => (0, "flat"),
            "normal" | "gaussian" => (2, "normal:MEAN,SD"),
            "gamma" => (2, "gamma:SHAPE,SCALE"),
            "lognormal" => (2, "lognormal:MU,SIGMA"),
            _ => {
                return Err(Error::UnknownName {
                    kind: "prior".into(),
                    name: family.to_string(),
                    known: ["flat", "normal", "gamma", "lognormal"].iter().map(|s| s.to_string()).collect(),
                })
            }
        };
        if values.len() != expected {
            return Err(invalid(format!(
                "`{spec}`: expected `{usage}` ({expected} values), got {} values",
                values.len()
            )));
        }
        let mut prior = match family {
            "flat" => Prior::flat(),
            "normal" | "gaussian" => Prior::gaussian(values[0], values[1]),
            "gamma" => Prior::gamma(values[0], values[1]),
            _ => Prior::log_normal(values[0], values[1]),
        };
        if let Some(b) = bounds {
            let (mut lower, mut upper) = (None, None);
            for item in b.split(',') {
                let (k, v) = item.split_once('=').ok_or_else(|| {
                    invalid(format!("expected `lower=L` or `upper=U` after `;` in `{spec}`"))
                })?;
                let slot = match k.trim() {
                    "lower" => &mut lower,
                    "upper" => &mut upper,
                    other => {
                        return Err(invalid(format!(
                            "unknown bound `{other}` in `{spec}` (accepted: lower, upper)"
                        )))
                    }
                };
                if slot.replace(number(v)?).is_some() {
                    return Err(invalid(format!("bound `{}` given twice in `{spec}`", k.trim())));
                }
            }
            prior = prior.with_bounds(lower.unwrap_or(f64::NEG_INFINITY), upper.unwrap_or(f64::INFINITY));
        }
        prior.validate()?;
        Ok(prior)
    }
}

/// ln P(l < X < u) for X ~ Γ(shape, scale), through statrs' regularised incomplete gamma
/// function (the upper tail through the survival function, to keep relative accuracy).
fn gamma_log_mass(shape: f64, scale: f64, l: f64, u: f64) -> f64 {
    let Ok(g) = statrs::distribution::Gamma::new(shape, 1.0 / scale) else { return f64::NAN };
    let l = l.max(0.0);
    if u <= l {
        return f64::NEG_INFINITY;
    }
    let lower_cdf = g.cdf(l);
    let mass = if lower_cdf > 0.5 { g.sf(l) - g.sf(u) } else { g.cdf(u) - lower_cdf };
    mass.ln()
}

impl fmt::Display for Prior {
    /// The CLI syntax of [`Prior::parse`], with `;lower=..,upper=..` for finite bounds.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.density {
            PriorDensity::Flat => write!(f, "flat")?,
            PriorDensity::Gaussian { mean, sd } => write!(f, "normal:{},{}", num(mean), num(sd))?,
            PriorDensity::Gamma { shape, scale } => write!(f, "gamma:{},{}", num(shape), num(scale))?,
            PriorDensity::LogNormal { mu, sigma } => write!(f, "lognormal:{},{}", num(mu), num(sigma))?,
        }
        let mut bounds = Vec::new();
        if self.lower > f64::NEG_INFINITY {
            bounds.push(format!("lower={}", num(self.lower)));
        }
        if self.upper < f64::INFINITY {
            bounds.push(format!("upper={}", num(self.upper)));
        }
        if !bounds.is_empty() {
            write!(f, ";{}", bounds.join(","))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use num_dual::{Dual64, HyperDual64};
    use proptest::prelude::*;
    use rand::rngs::StdRng;
    use rand::SeedableRng;
    use statrs::distribution::{Continuous, Gamma, LogNormal, Normal};

    /// Five-point central difference (truncation O(h⁴)).
    fn five_point(f: impl Fn(f64) -> f64, x: f64, h: f64) -> f64 {
        (f(x - 2.0 * h) - 8.0 * f(x - h) + 8.0 * f(x + h) - f(x + 2.0 * h)) / (12.0 * h)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]

        /// Untruncated log-densities agree with statrs' `ln_pdf` to 1e-12 relative.
        #[test]
        fn log_densities_match_statrs(
            loc in -5.0..5.0_f64, scale in 0.05..5.0_f64, shape in 0.2..20.0_f64, u in 0.01..0.99_f64,
        ) {
            let normal = Normal::new(loc, scale).unwrap();
            let x = loc + scale * (4.0 * u - 2.0);
            let (ours, reference) = (Prior::gaussian(loc, scale).log_density(x), normal.ln_pdf(x));
            prop_assert!((ours - reference).abs() <= 1e-12 * reference.abs().max(1.0), "normal {} vs {}", ours, reference);

            let gamma = Gamma::new(shape, 1.0 / scale).unwrap();
            let x = shape * scale * 4.0 * u;
            let (ours, reference) = (Prior::gamma(shape, scale).log_density(x), gamma.ln_pdf(x));
            prop_assert!((ours - reference).abs() <= 1e-12 * reference.abs().max(1.0), "gamma {} vs {}", ours, reference);

            let ln = LogNormal::new(loc, scale).unwrap();
            let x = (loc + scale * (4.0 * u - 2.0)).exp();
            let (ours, reference) = (Prior::log_normal(loc, scale).log_density(x), ln.ln_pdf(x));
            prop_assert!((ours - reference).abs() <= 1e-12 * reference.abs().max(1.0), "lognormal {} vs {}", ours, reference);
        }

        /// d/dx and d²/dx² of ln p (Dual64, HyperDual64) agree with five-point differences,
        /// relative 1e-6, truncated or not.
        #[test]
        fn derivatives_match_finite_differences(
            loc in -3.0..3.0_f64, scale in 0.1..3.0_f64, shape in 0.5..10.0_f64, u in 0.05..0.95_f64,
        ) {
            let priors = [
                (Prior::gaussian(loc, scale), loc + scale * (4.0 * u - 2.0)),
                (Prior::gaussian(loc, scale).with_bounds(loc - 3.0 * scale, f64::INFINITY), loc + scale * (4.0 * u - 2.0)),
                (Prior::gamma(shape, scale), shape * scale * 3.0 * u),
                (Prior::log_normal(loc, scale), (loc + scale * (4.0 * u - 2.0)).exp()),
            ];
            for (p, x) in priors {
                let h = 1e-4 * x.abs().min(scale);
                let d1 = p.log_density(Dual64::new(x, 1.0)).eps;
                let fd = five_point(|v| p.log_density(v), x, h);
                let tol = 1e-6 * fd.abs() + 1e-13 * p.log_density(x).abs().max(1.0) / h;
                prop_assert!((d1 - fd).abs() <= tol, "{} at {}: {} vs {}", p, x, d1, fd);
                let d2 = p.log_density(HyperDual64::new(x, 1.0, 1.0, 0.0)).eps1eps2;
                let fd2 = five_point(|v| p.log_density(Dual64::new(v, 1.0)).eps, x, h);
                let tol = 1e-6 * fd2.abs() + 1e-13 * d1.abs().max(1.0) / h;
                prop_assert!((d2 - fd2).abs() <= tol, "{} second derivative at {}: {} vs {}", p, x, d2, fd2);
            }
        }
    }

    #[test]
    fn gamma_prior_has_the_form_of_eq_4_7() {
        // 000 (4.7): ln p = (r − 1) ln σ − σ/s + const, so d/dσ ln p = (r − 1)/σ − 1/s.
        let (r, s) = (1.1, 10.0);
        let p = Prior::gamma(r, s);
        for x in [0.01, 0.1, 1.0, 30.0] {
            let d = p.log_density(Dual64::new(x, 1.0)).eps;
            assert_relative_eq!(d, (r - 1.0) / x - 1.0 / s, epsilon = 0.0, max_relative = 1e-14);
        }
        // Support: x ≤ 0 is impossible.
        assert_eq!(p.log_density(0.0), f64::NEG_INFINITY);
        assert_eq!(p.log_density(-1.0), f64::NEG_INFINITY);
        assert_eq!(Prior::log_normal(0.0, 1.0).log_density(0.0), f64::NEG_INFINITY);
    }

    /// ∫ p over the truncated support by composite Simpson's rule (n = 20 000 panels; error
    /// ~ (b − a)⁵ max|p⁗|/(180 n⁴) < 1e-12 for these smooth densities).
    fn integral(p: &Prior, a: f64, b: f64) -> f64 {
        let n = 20_000;
        let h = (b - a) / n as f64;
        let f = |x: f64| p.log_density(x).exp();
        let mut s = f(a) + f(b);
        for i in 1..n {
            s += f(a + i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
        }
        s * h / 3.0
    }

    #[test]
    fn truncated_densities_are_normalised() {
        let cases = [
            (Prior::gaussian(0.5, 1.2).with_bounds(-1.0, 2.0), -1.0, 2.0),
            (Prior::gaussian(0.0, 1.0).with_bounds(3.0, 6.0), 3.0, 6.0),
            (Prior::gamma(2.5, 0.7).with_bounds(0.5, 3.0), 0.5, 3.0),
            (Prior::gamma(30.0, 0.1).with_bounds(4.0, 6.0), 4.0, 6.0),
            (Prior::log_normal(0.2, 0.5).with_bounds(0.3, 5.0), 0.3, 5.0),
        ];
        for (p, a, b) in cases {
            p.validate().unwrap();
            assert_relative_eq!(integral(&p, a, b), 1.0, epsilon = 0.0, max_relative = 1e-10);
            assert_eq!(p.log_density(a - 1e-9), f64::NEG_INFINITY);
            assert_eq!(p.log_density(b + 1e-9), f64::NEG_INFINITY);
        }
        // Flat: 0 inside the bounds, −∞ outside; unbounded proper densities need no constant.
        let positive = Prior::flat().with_bounds(0.0, f64::INFINITY);
        assert_eq!(positive.log_density(3.0), 0.0);
        assert_eq!(positive.log_density(-3.0), f64::NEG_INFINITY);
        assert_eq!(Prior::gaussian(1.0, 2.0).log_mass_in_bounds(), 0.0);
        assert!(Prior::flat().log_density(f64::NAN).is_nan());
    }

    #[test]
    fn means_match_closed_forms() {
        let sqrt_2_over_pi = (2.0 / std::f64::consts::PI).sqrt();
        let cases = [
            (Prior::gaussian(1.0, 2.0), 1.0),
            // Half-normal: E = sd √(2/π).
            (Prior::gaussian(0.0, 2.0).with_bounds(0.0, f64::INFINITY), 2.0 * sqrt_2_over_pi),
            // Symmetric truncation keeps the mean.
            (Prior::gaussian(1.0, 2.0).with_bounds(-1.0, 3.0), 1.0),
            (Prior::gamma(1.1, 10.0), 11.0),
            // Exponential (r = 1) truncated to [a, ∞): memoryless, E = a + s.
            (Prior::gamma(1.0, 2.0).with_bounds(3.0, f64::INFINITY), 5.0),
            (Prior::log_normal(0.3, 0.5), (0.3_f64 + 0.125).exp()),
            // Log-normal truncated at its median from below: e^{μ+σ²/2} Φ(σ)/½ (closed form;
            // Φ(0.5) = 0.69146246127401310 from mpmath: m.ncdf(0.5)).
            (
                Prior::log_normal(0.0, 0.5).with_bounds(1.0, f64::INFINITY),
                0.125_f64.exp() * 2.0 * 0.691_462_461_274_013_1,
            ),
            (Prior::flat().with_bounds(-1.0, 5.0), 2.0),
        ];
        for (p, m) in cases {
            assert_relative_eq!(p.mean().unwrap(), m, epsilon = 1e-15, max_relative = 1e-13);
        }
        assert_eq!(Prior::flat().mean(), None);
        assert_eq!(Prior::flat().with_bounds(0.0, f64::INFINITY).mean(), None);
        assert_eq!(Prior::gaussian(0.0, -1.0).mean(), None);
    }

    /// Monte Carlo: sample means within 4 standard errors of [`Prior::mean`] (n = 20 000, the
    /// standard error from the sample variance), samples inside the bounds.
    #[test]
    fn samples_have_the_right_mean_and_respect_bounds() {
        let mut rng = StdRng::seed_from_u64(4_242);
        let priors = [
            Prior::gaussian(1.0, 2.0),
            Prior::gaussian(0.0, 1.0).with_bounds(0.5, 1.5),
            Prior::gamma(1.1, 10.0),
            Prior::gamma(4.0, 0.05).with_bounds(0.1, 0.3),
            Prior::log_normal(0.0, 0.5).with_bounds(1.0, f64::INFINITY),
            Prior::flat().with_bounds(-2.0, 4.0),
        ];
        let n = 20_000;
        for p in priors {
            let s: Vec<f64> = (0..n).map(|_| p.sample(&mut rng).unwrap()).collect();
            assert!(s.iter().all(|&v| v >= p.lower && v <= p.upper), "{p}");
            let mean = s.iter().sum::<f64>() / n as f64;
            let var = s.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
            let expected = p.mean().unwrap();
            assert!((mean - expected).abs() < 4.0 * (var / n as f64).sqrt(), "{p}: {mean} vs {expected}");
        }
        // Improper and hopeless priors are errors, not panics or endless loops.
        assert!(matches!(Prior::flat().sample(&mut rng), Err(Error::InvalidOption { .. })));
        assert!(matches!(
            Prior::flat().with_bounds(0.0, f64::INFINITY).sample(&mut rng),
            Err(Error::InvalidOption { .. })
        ));
        let far = Prior::gaussian(0.0, 1.0).with_bounds(9.0, 10.0);
        assert!(matches!(far.sample(&mut rng), Err(Error::InvalidOption { .. })));
    }

    #[test]
    fn validate_rejects_bad_hyperparameters_and_bounds() {
        let name = |p: Prior| match p.validate() {
            Err(Error::InvalidOption { name, .. }) => name,
            other => panic!("{p:?}: expected InvalidOption, got {other:?}"),
        };
        assert_eq!(name(Prior::gaussian(0.0, 0.0)), "prior.sd");
        assert_eq!(name(Prior::gaussian(f64::NAN, 1.0)), "prior.mean");
        assert_eq!(name(Prior::gamma(-1.0, 1.0)), "prior.shape");
        assert_eq!(name(Prior::gamma(1.0, f64::INFINITY)), "prior.scale");
        assert_eq!(name(Prior::log_normal(0.0, -0.1)), "prior.sigma");
        assert_eq!(name(Prior::flat().with_bounds(1.0, 1.0)), "prior.bounds");
        assert_eq!(name(Prior::flat().with_bounds(f64::NAN, 1.0)), "prior.bounds");
        assert_eq!(name(Prior::gamma(2.0, 1.0).with_bounds(-5.0, 0.0)), "prior.bounds");
        // 60 sd out the bounds still hold positive (tiny) probability: valid.
        assert!(Prior::gaussian(0.0, 1.0).with_bounds(60.0, 61.0).validate().is_ok());
        assert!(Prior::flat().validate().is_ok());
        assert!(Prior::flat().with_bounds(0.0, f64::INFINITY).validate().is_ok());
    }

    #[test]
    fn parse_and_display_round_trip() {
        let cases = [
            ("flat", Prior::flat()),
            ("normal:0,0.4", Prior::gaussian(0.0, 0.4)),
            ("gamma:1.1,10", Prior::gamma(1.1, 10.0)),
            ("lognormal:0,1", Prior::log_normal(0.0, 1.0)),
            ("flat;lower=0", Prior::flat().with_bounds(0.0, f64::INFINITY)),
            ("normal:1,2;lower=0,upper=5", Prior::gaussian(1.0, 2.0).with_bounds(0.0, 5.0)),
            ("gamma:4,0.0125;upper=0.2", Prior::gamma(4.0, 0.0125).with_bounds(f64::NEG_INFINITY, 0.2)),
        ];
        for (spec, expected) in cases {
            let p = Prior::parse(spec).unwrap();
            assert_eq!(p, expected, "{spec}");
            assert_eq!(p.to_string(), spec);
        }
        // Alternative spellings.
        assert_eq!(Prior::parse(" gaussian : 0 , 0.4 ").unwrap(), Prior::gaussian(0.0, 0.4));
        assert_eq!(
            Prior::parse("normal:0,1; upper=inf, lower=-1").unwrap(),
            Prior::gaussian(0.0, 1.0).with_bounds(-1.0, f64::INFINITY)
        );
        let p = Prior::gaussian(0.1 + 0.2, 1.0 / 3.0).with_bounds(-0.7, 1e300);
        assert_eq!(Prior::parse(&p.to_string()).unwrap(), p);
    }

    #[test]
    fn parse_errors() {
        assert!(
            matches!(Prior::parse("cauchy:0,1"), Err(Error::UnknownName { kind, .. }) if kind == "prior")
        );
        let reason = |spec: &str| match Prior::parse(spec) {
            Err(Error::InvalidOption { reason, .. }) => reason,
            other => panic!("{spec}: expected InvalidOption, got {other:?}"),
        };
        assert!(reason("normal:0").contains("2 values"));
        assert!(reason("flat:1").contains("0 values"));
        assert!(reason("normal:0,x").contains("cannot parse `x`"));
        assert!(reason("normal:0,1;left=0").contains("unknown bound"));
        assert!(reason("normal:0,1;lower=0,lower=1").contains("twice"));
        assert!(reason("normal:0,1;lower").contains("lower=L"));
        assert!(reason("normal:0,-1").contains("positive"));
        assert!(reason("normal:0,1;lower=2,upper=1").contains("lower < upper"));
    }
}
