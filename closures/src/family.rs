//! The [`TrialFamily`] trait and the Legendre machinery shared by every family.

use crate::error::{check_finite, check_len, Error};
use crate::quadrature::Rule;
use crate::scalar::{cholesky, cholesky_solve};

/// The log-partition function and the first two cumulants of $M$ at one $\lambda$.
#[derive(Debug, Clone, PartialEq)]
pub struct Cumulants {
    /// $F(\lambda) = \log\mathcal N(\lambda)$, `003_d2fc48a470e528fc.txt (II.38)`.
    pub log_partition: f64,
    /// $\mu = \nabla F(\lambda) = \langle M\rangle_\lambda$ (length $R$).
    pub mean: Vec<f64>,
    /// $C = \nabla^2 F(\lambda) = \partial\mu/\partial\lambda$, the covariance of $M$ (row-major
    /// $R\times R$).
    pub covariance: Vec<f64>,
}

/// Options of the damped Newton solver for the Legendre inverse $\lambda(\mu)$
/// (`003_d2fc48a470e528fc.txt (II.39)`).
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct LegendreOptions {
    /// Iteration limit. Default `100`.
    pub max_iterations: usize,
    /// Convergence when the Newton step satisfies
    /// $\Vert \delta\Vert_\infty \le$ `step_tolerance` $\cdot\max(1, \Vert \lambda\Vert_\infty)$,
    /// or when the Newton decrement $g^\top C^{-1}g$ ($g = \mu - \nabla F$) falls to the
    /// round-off level of $\mu^\top\lambda - F$. Default `1e-13`.
    pub step_tolerance: f64,
    /// Steps are capped to $\Vert \lambda\Vert_\infty \le$ `lambda_bound`, and the moments are declared
    /// unrealizable once an accepted iterate reaches half of it: the dual objective
    /// $\mu^\top\lambda - F(\lambda)$ is then (numerically) unbounded along the Newton path.
    /// Default `1e8`.
    pub lambda_bound: f64,
    /// Starting point; `None` starts from $\lambda = 0$ (the reference density). Default `None`.
    pub initial: Option<Vec<f64>>,
}

impl Default for LegendreOptions {
    fn default() -> Self {
        Self { max_iterations: 100, step_tolerance: 1e-13, lambda_bound: 1e8, initial: None }
    }
}

impl LegendreOptions {
    /// Sets [`LegendreOptions::initial`].
    pub fn with_initial(mut self, lambda0: Vec<f64>) -> Self {
        self.initial = Some(lambda0);
        self
    }

    /// Sets [`LegendreOptions::max_iterations`].
    pub fn with_max_iterations(mut self, n: usize) -> Self {
        self.max_iterations = n;
        self
    }

    /// Sets [`LegendreOptions::step_tolerance`].
    pub fn with_step_tolerance(mut self, tol: f64) -> Self {
        self.step_tolerance = tol;
        self
    }

    /// Sets [`LegendreOptions::lambda_bound`].
    pub fn with_lambda_bound(mut self, bound: f64) -> Self {
        self.lambda_bound = bound;
        self
    }

    /// Checks the options once.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] for a zero iteration limit or a non-positive tolerance or bound.
    pub fn validate(&self) -> Result<(), Error> {
        if self.max_iterations == 0 {
            return Err(Error::InvalidOption { name: "max_iterations", reason: "must be at least 1".into() });
        }
        if !(self.step_tolerance > 0.0 && self.step_tolerance.is_finite()) {
            return Err(Error::InvalidOption {
                name: "step_tolerance",
                reason: format!("must be positive and finite, got {}", self.step_tolerance),
            });
        }
        if self.lambda_bound.is_nan() || self.lambda_bound <= 0.0 {
            return Err(Error::InvalidOption {
                name: "lambda_bound",
                reason: format!("must be positive, got {}", self.lambda_bound),
            });
        }
        Ok(())
    }
}

/// The Legendre inverse $\lambda(\mu)$ and how it was found.
#[derive(Debug, Clone, PartialEq)]
pub struct LegendreSolution {
    /// The multipliers $\lambda$ with $\nabla F(\lambda) = \mu$.
    pub lambda: Vec<f64>,
    /// Newton iterations used (0 for closed forms).
    pub iterations: usize,
    /// Final residual $\Vert \mu - \nabla F(\lambda)\Vert_\infty$.
    pub residual: f64,
    /// The relative entropy $H(\mu) = \mu^\top\lambda - F(\lambda)$,
    /// `003_d2fc48a470e528fc.txt (II.39)`.
    pub relative_entropy: f64,
}

/// A family of trial densities
/// $p(x;\lambda) = e^{\lambda^\top M(x)} p_{\ast}(x)/\mathcal N(\lambda)$
/// (`003_d2fc48a470e528fc.txt (II.36)`–(II.37)) with its cumulant algebra.
///
/// Vectors indexed by moments have length $R$ = [`n_moments`](TrialFamily::n_moments); points
/// $x$ have length [`dim`](TrialFamily::dim); matrices are row-major.
///
/// The trait is object safe, so closures can hold a `Box<dyn TrialFamily>`.
pub trait TrialFamily {
    /// Dimension of the state $x$.
    fn dim(&self) -> usize;

    /// Number $R$ of moment functions $M = (M_1, \dots, M_R)$.
    fn n_moments(&self) -> usize;

    /// Evaluates the moment functions $M(x)$ into `out` (length $R$).
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`] for wrong lengths.
    fn moment_functions(&self, x: &[f64], out: &mut [f64]) -> Result<(), Error>;

    /// Derivatives of the moment functions at $x$: the Jacobian
    /// $J_{ai} = \partial M_a/\partial x_i$ into `jacobian` ($R\times dim$, row-major) and the
    /// Hessians $\partial^2M_a/\partial x_i\partial x_j$ into `hessians` (index
    /// $(a dim + i) dim + j$). A closure needs them for the generator average
    /// $\langle f\cdot\nabla M_a + D:\nabla\nabla M_a\rangle_\lambda$.
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`]; [`Error::Unsupported`] if the family has no derivatives.
    fn moment_derivatives(&self, x: &[f64], jacobian: &mut [f64], hessians: &mut [f64]) -> Result<(), Error>;

    /// The log-partition function $F(\lambda) = \log\int e^{\lambda^\top M(x)}p_{\ast}(x) dx$,
    /// `003_d2fc48a470e528fc.txt (II.38)`.
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`], [`Error::NonFinite`], or [`Error::NotNormalizable`] if the
    /// integral diverges.
    fn log_partition(&self, lambda: &[f64]) -> Result<f64, Error>;

    /// $F$, $\mu = \nabla F$ and $C = \nabla^2 F$ at $\lambda$ in one pass
    /// (`003_d2fc48a470e528fc.txt (II.38)` and the relations after (II.39)).
    ///
    /// # Errors
    /// As [`log_partition`](TrialFamily::log_partition).
    fn cumulants(&self, lambda: &[f64]) -> Result<Cumulants, Error>;

    /// The third cumulant $C_{abc} = \partial C_{ab}/\partial\lambda_c$ of $M$
    /// (`003_d2fc48a470e528fc.txt (II.42)`–(II.43)), stored with index $(a R + b) R + c$.
    ///
    /// # Errors
    /// As [`log_partition`](TrialFamily::log_partition).
    fn third_cumulant(&self, lambda: &[f64]) -> Result<Vec<f64>, Error>;

    /// Points and probability weights of a quadrature rule for $p(\cdot;\lambda)$:
    /// $\langle g\rangle_\lambda \approx \sum_k w_k g(x_k)$ with $\sum_k w_k = 1$ (the
    /// fifth-degree cubature of [`Gaussian`](crate::Gaussian) has some negative weights for
    /// $n > 4$). A caller evaluates its own functions (e.g. a drift) at these points.
    ///
    /// # Errors
    /// As [`log_partition`](TrialFamily::log_partition).
    fn quadrature(&self, lambda: &[f64]) -> Result<Rule, Error>;

    /// Checks necessary conditions for $\mu$ to be the mean of $M$ under some member of the
    /// family, without solving for $\lambda$. The default checks length and finiteness only.
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`], [`Error::NonFinite`] or [`Error::Unrealizable`].
    fn check_realizable(&self, mu: &[f64]) -> Result<(), Error> {
        check_len("mu", mu, self.n_moments())?;
        check_finite("mu", mu)
    }

    /// The Legendre inverse $\lambda(\mu)$: the maximiser of $\mu^\top\lambda - F(\lambda)$
    /// (`003_d2fc48a470e528fc.txt (II.39)`, $\lambda = \partial H/\partial\mu$). The default runs
    /// [`legendre_newton`] after [`check_realizable`](TrialFamily::check_realizable).
    ///
    /// # Errors
    /// [`Error::Unrealizable`] if $\mu$ is not in the interior of the family's moment space,
    /// [`Error::NoConvergence`] at the iteration limit, plus input errors.
    fn legendre(&self, mu: &[f64], options: &LegendreOptions) -> Result<LegendreSolution, Error> {
        self.check_realizable(mu)?;
        legendre_newton(self, mu, options)
    }

    /// The relative entropy $H(\mu) = \max_\lambda\lbrace \mu^\top\lambda - F(\lambda)\rbrace$ of
    /// $p(\cdot;\lambda(\mu))$ with respect to the reference $p_{\ast}$,
    /// `003_d2fc48a470e528fc.txt (II.39)`.
    ///
    /// # Errors
    /// As [`legendre`](TrialFamily::legendre) with default options.
    fn relative_entropy(&self, mu: &[f64]) -> Result<f64, Error> {
        Ok(self.legendre(mu, &LegendreOptions::default())?.relative_entropy)
    }

    /// The mean $\mu = \nabla F(\lambda)$ of $M$ (see [`cumulants`](TrialFamily::cumulants)).
    ///
    /// # Errors
    /// As [`cumulants`](TrialFamily::cumulants).
    fn mean(&self, lambda: &[f64]) -> Result<Vec<f64>, Error> {
        Ok(self.cumulants(lambda)?.mean)
    }

    /// The covariance $C = \nabla^2 F(\lambda)$ of $M$ (see
    /// [`cumulants`](TrialFamily::cumulants)).
    ///
    /// # Errors
    /// As [`cumulants`](TrialFamily::cumulants).
    fn covariance(&self, lambda: &[f64]) -> Result<Vec<f64>, Error> {
        Ok(self.cumulants(lambda)?.covariance)
    }

    /// Expectations $\langle g\rangle_\lambda$ of a caller-supplied vector function
    /// $g:\mathbb R^{dim}\to\mathbb R^{n_{out}}$ through
    /// [`quadrature`](TrialFamily::quadrature). `g(x, out)` writes $g(x)$ into `out`.
    ///
    /// # Errors
    /// As [`quadrature`](TrialFamily::quadrature); [`Error::NonFinite`] if $g$ returns a
    /// non-finite value at a node.
    fn expectation(
        &self,
        lambda: &[f64],
        n_out: usize,
        g: &mut dyn FnMut(&[f64], &mut [f64]),
    ) -> Result<Vec<f64>, Error> {
        let rule = self.quadrature(lambda)?;
        let mut acc = vec![0.0; n_out];
        let mut buf = vec![0.0; n_out];
        for (x, w) in rule.iter() {
            buf.iter_mut().for_each(|v| *v = 0.0);
            g(x, &mut buf);
            for (a, b) in acc.iter_mut().zip(&buf) {
                *a += w * b;
            }
        }
        check_finite("expectation", &acc)?;
        Ok(acc)
    }
}

/// Largest entry in absolute value.
pub(crate) fn max_abs(x: &[f64]) -> f64 {
    x.iter().fold(0.0, |m, v| m.max(v.abs()))
}

/// Damped Newton method for the Legendre inverse $\lambda(\mu)$ of
/// `003_d2fc48a470e528fc.txt (II.39)`: maximises the concave dual
/// $\Phi(\lambda) = \mu^\top\lambda - F(\lambda)$, whose gradient is $\mu - \nabla F$ and Hessian
/// $-C$ (II.38 and the relations after II.39). Steps $\delta = C^{-1}(\mu - \nabla F)$ are damped
/// by Armijo backtracking on $\Phi$; a singular $C$ is regularised Levenberg-style.
///
/// Realizability: $\Phi$ is bounded above iff $\mu$ is in the closure of the moment space, and
/// has a maximiser iff $\mu$ is in its interior. Steps are capped to
/// $\Vert \lambda\Vert_\infty \le$ [`LegendreOptions::lambda_bound`] $=: B$, and an accepted iterate
/// with $\Vert \lambda\Vert_\infty \ge B/2$ signals [`Error::Unrealizable`].
///
/// # Errors
/// [`Error::Unrealizable`], [`Error::NoConvergence`] (residual $\Vert \mu-\nabla F\Vert_\infty$),
/// [`Error::InvalidOption`], and input errors.
pub fn legendre_newton<F: TrialFamily + ?Sized>(
    family: &F,
    mu: &[f64],
    options: &LegendreOptions,
) -> Result<LegendreSolution, Error> {
    options.validate()?;
    let r = family.n_moments();
    check_len("mu", mu, r)?;
    check_finite("mu", mu)?;
    let mut lambda = match &options.initial {
        Some(l0) => {
            check_len("initial", l0, r)?;
            check_finite("initial", l0)?;
            if max_abs(l0) >= 0.5 * options.lambda_bound {
                return Err(Error::InvalidOption {
                    name: "initial",
                    reason: "the initial multipliers exceed half of lambda_bound".into(),
                });
            }
            l0.clone()
        }
        None => vec![0.0; r],
    };
    let dual = |c: &Cumulants, l: &[f64]| -> f64 {
        mu.iter().zip(l).map(|(m, l)| m * l).sum::<f64>() - c.log_partition
    };
    let unrealizable = |l: &[f64]| Error::Unrealizable {
        reason: format!(
            "the Legendre multipliers diverge (|lambda|_inf = {:e}): mu is not in the interior \
             of the moment space",
            max_abs(l)
        ),
    };
    let mut cum = family.cumulants(&lambda)?;
    let mut phi = dual(&cum, &lambda);
    for iteration in 1..=options.max_iterations {
        let g: Vec<f64> = mu.iter().zip(&cum.mean).map(|(m, e)| m - e).collect();
        let delta = newton_step(&cum.covariance, &g, r).ok_or_else(|| unrealizable(&lambda))?;
        let decrement: f64 = g.iter().zip(&delta).map(|(a, b)| a * b).sum();
        let full_step_small = max_abs(&delta) <= options.step_tolerance * max_abs(&lambda).max(1.0);
        // Armijo backtracking on Φ (concave): accept Φ(λ+tδ) ≥ Φ(λ) + 1e-4 t gᵀδ − ε, where ε
        // is the round-off level of Φ so that steps at the round-off floor are not rejected.
        let scale: f64 = mu.iter().zip(&lambda).map(|(m, l)| (m * l).abs()).sum();
        let noise = 8.0 * f64::EPSILON * (scale + cum.log_partition.abs() + 1.0);
        // The Newton decrement gᵀC⁻¹g ≈ 2(max Φ − Φ(λ)): below the round-off level of Φ no
        // further progress is possible (the usual stopping rule for Newton's method).
        if full_step_small || decrement <= 2.0 * noise {
            // Converged in Φ. Polish with full Newton steps while they reduce the gradient,
            // which is accurate far below Φ's round-off (quadratic convergence: few steps).
            let (mut lambda, mut cum, mut g, mut delta) = (lambda, cum, g, delta);
            for _ in 0..5 {
                let trial: Vec<f64> = lambda.iter().zip(&delta).map(|(l, d)| l + d).collect();
                let Ok(c) = family.cumulants(&trial) else { break };
                let g_trial: Vec<f64> = mu.iter().zip(&c.mean).map(|(m, e)| m - e).collect();
                if max_abs(&g_trial) >= max_abs(&g) || max_abs(&trial) >= 0.5 * options.lambda_bound {
                    break;
                }
                let Some(d) = newton_step(&c.covariance, &g_trial, r) else { break };
                (lambda, cum, g, delta) = (trial, c, g_trial, d);
            }
            return Ok(solution(mu, lambda, cum, iteration));
        }
        // Cap the step so that the trial stays within the bound (|λ_a + t δ_a| ≤ bound).
        let mut t: f64 = 1.0;
        for (l, d) in lambda.iter().zip(&delta) {
            if (l + d).abs() > options.lambda_bound {
                t = t.min((options.lambda_bound - l * d.signum()) / d.abs());
            }
        }
        let mut accepted = None;
        for _ in 0..60 {
            let trial: Vec<f64> = lambda.iter().zip(&delta).map(|(l, d)| l + t * d).collect();
            if let Ok(c) = family.cumulants(&trial) {
                let p = dual(&c, &trial);
                if p.is_finite() && p >= phi + 1e-4 * t * decrement - noise {
                    accepted = Some((trial, c, p));
                    break;
                }
            }
            t *= 0.5;
        }
        match accepted {
            Some((trial, c, p)) => {
                lambda = trial;
                cum = c;
                phi = p;
                if max_abs(&lambda) >= 0.5 * options.lambda_bound {
                    return Err(unrealizable(&lambda));
                }
            }
            None => {
                return Err(Error::NoConvergence { iterations: iteration, residual: max_abs(&g) });
            }
        }
    }
    let resid = max_abs(&mu.iter().zip(&cum.mean).map(|(m, e)| m - e).collect::<Vec<_>>());
    Err(Error::NoConvergence { iterations: options.max_iterations, residual: resid })
}

fn solution(mu: &[f64], lambda: Vec<f64>, cum: Cumulants, iterations: usize) -> LegendreSolution {
    let residual = max_abs(&mu.iter().zip(&cum.mean).map(|(m, e)| m - e).collect::<Vec<_>>());
    let relative_entropy = mu.iter().zip(&lambda).map(|(m, l)| m * l).sum::<f64>() - cum.log_partition;
    LegendreSolution { lambda, iterations, residual, relative_entropy }
}

/// Solves $C\delta = g$ by Cholesky, with Jacobi scaling and Levenberg regularisation if $C$ is
/// numerically singular. `None` if $C$ has no positive scale at all (a point mass).
fn newton_step(c: &[f64], g: &[f64], r: usize) -> Option<Vec<f64>> {
    // Jacobi scaling s_a = 1/√C_aa makes the step invariant to the scale of each M_a.
    let s: Vec<f64> = (0..r)
        .map(|a| {
            let d = c[a * r + a];
            if d > 0.0 && d.is_finite() {
                Some(1.0 / d.sqrt())
            } else {
                None
            }
        })
        .collect::<Option<Vec<f64>>>()?;
    let mut scaled: Vec<f64> = (0..r * r).map(|k| c[k] * s[k / r] * s[k % r]).collect();
    let gs: Vec<f64> = g.iter().zip(&s).map(|(g, s)| g * s).collect();
    let mut tau = 0.0;
    for _ in 0..12 {
        if let Ok(l) = cholesky(&scaled, r) {
            let y = cholesky_solve(&l, &gs).ok()?;
            let d: Vec<f64> = y.iter().zip(&s).map(|(y, s)| y * s).collect();
            if d.iter().all(|v| v.is_finite()) {
                return Some(d);
            }
        }
        let new_tau = if tau == 0.0 { 1e-12 } else { tau * 100.0 };
        for a in 0..r {
            scaled[a * r + a] += new_tau - tau;
        }
        tau = new_tau;
    }
    None
}
