//! Exponential families with user moment functions on a fixed tensor grid (1-D and 2-D).

use std::fmt;
use std::sync::Arc;

use crate::error::{check_finite, check_len, Error};
use crate::family::{Cumulants, TrialFamily};
use crate::quadrature::{composite_gauss_legendre, tensor_product, Rule};
use crate::scalar::{cholesky, Scalar};
use crate::weights::normalize_log_weights_from_max;
use num_dual::HyperDual64;

/// A shared moment-function closure: `m(x, out)` writes $M(x)$ into `out`.
pub type MomentFn = Arc<dyn Fn(&[f64], &mut [f64]) + Send + Sync>;

/// A shared derivative closure: `d(x, jacobian, hessians)` writes $\partial M_a/\partial x_i$
/// ($R\times dim$) and $\partial^2 M_a/\partial x_i\partial x_j$ ($R\times dim\times dim$).
pub type MomentDerivativeFn = Arc<dyn Fn(&[f64], &mut [f64], &mut [f64]) + Send + Sync>;

/// Moment functions $M:\mathbb R^{dim}\to\mathbb R^R$ written once, generic over the
/// [`Scalar`], so that [`Exponential::from_moments`] gets their derivatives by automatic
/// differentiation.
pub trait MomentFunctions: Send + Sync {
    /// Dimension of $x$.
    fn dim(&self) -> usize;
    /// Number $R$ of moments.
    fn n_moments(&self) -> usize;
    /// Writes $M(x)$ into `out` (length $R$; `x` has length [`dim`](MomentFunctions::dim)).
    fn eval<D: Scalar>(&self, x: &[D], out: &mut [D]);
}

/// Monomial moments $x^\alpha = \prod_i x_i^{\alpha_i}$, $1 \le |\alpha| \le d$, ordered by
/// degree and then lexicographically with the first coordinate's exponent descending (in 1-D:
/// $(x, x^2, \dots, x^d)$; in 2-D with $d = 2$: $(x, y, x^2, xy, y^2)$).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Polynomial {
    dim: usize,
    exponents: Vec<Vec<u32>>,
}

impl Polynomial {
    /// All monomials in `dim` variables of total degree 1 to `degree`.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] for `dim == 0` or `degree == 0`.
    pub fn try_new(dim: usize, degree: u32) -> Result<Self, Error> {
        if dim == 0 || degree == 0 {
            return Err(Error::InvalidOption {
                name: "degree",
                reason: format!("need dim >= 1 and degree >= 1, got dim {dim}, degree {degree}"),
            });
        }
        Ok(Self { dim, exponents: monomials(dim, degree) })
    }

    /// The exponent vectors $\alpha$, one per moment.
    pub fn exponents(&self) -> &[Vec<u32>] {
        &self.exponents
    }
}

impl MomentFunctions for Polynomial {
    fn dim(&self) -> usize {
        self.dim
    }

    fn n_moments(&self) -> usize {
        self.exponents.len()
    }

    fn eval<D: Scalar>(&self, x: &[D], out: &mut [D]) {
        for (o, e) in out.iter_mut().zip(&self.exponents) {
            *o = x.iter().zip(e).fold(D::one(), |acc, (v, &k)| acc * v.powi(k as i32));
        }
    }
}

/// A shared log-density closure $x \mapsto \log p_{\ast}(x)$ (may return $-\infty$ where $p_{\ast} = 0$).
pub type LogDensityFn = Arc<dyn Fn(&[f64]) -> f64 + Send + Sync>;

/// The reference density $p_{\ast}$ of `003_d2fc48a470e528fc.txt (II.36)`.
#[derive(Clone)]
#[non_exhaustive]
pub enum Reference {
    /// $p_{\ast} = 1$ (Lebesgue measure on the grid's box; not normalised).
    Lebesgue,
    /// $p_{\ast} = 1/\mathrm{vol}$, uniform on the grid's box, so that $F(0) = 0$.
    Uniform,
    /// A user log-density $\log p_{\ast}(x)$; nodes where it is $-\infty$ are dropped.
    LogDensity(LogDensityFn),
}

impl fmt::Debug for Reference {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Lebesgue => write!(f, "Lebesgue"),
            Self::Uniform => write!(f, "Uniform"),
            Self::LogDensity(_) => write!(f, "LogDensity(..)"),
        }
    }
}

/// A tensor grid of composite Gauss–Legendre panels on a box in 1-D, 2-D or 3-D: each axis
/// $[a_i, b_i]$ gets `panels` panels of `points_per_panel` Gauss–Legendre points.
///
/// Accuracy: see [`composite_gauss_legendre`]; with 8 points per panel and a panel width no
/// larger than the length scale of $e^{\lambda^\top M}p_{\ast}$ the relative error of every
/// integral is below $10^{-12}$. The family defined on the grid is itself an exact exponential
/// family (of discrete measures), so its $F$, $\mu$, $C$ and $\lambda(\mu)$ are mutually
/// consistent to round-off whatever the grid.
///
/// # Errors
/// [`Error::InvalidOption`] for a dimension other than 1, 2 or 3, or invalid panels.
pub fn panel_grid(bounds: &[(f64, f64)], panels: usize, points_per_panel: usize) -> Result<Rule, Error> {
    if !(1..=3).contains(&bounds.len()) {
        return Err(Error::InvalidOption {
            name: "bounds",
            reason: format!("exponential families live on 1-D, 2-D or 3-D grids, got {} axes", bounds.len()),
        });
    }
    let axes = bounds
        .iter()
        .map(|&(a, b)| composite_gauss_legendre(a, b, panels, points_per_panel))
        .collect::<Result<Vec<_>, _>>()?;
    tensor_product(&axes)
}

/// A tensor grid of composite Gauss–Legendre panels on the box $\xi \in [-c, c]^n$ of a frame
/// $x = m + L\xi$ ($L$ lower triangular, row-major $n\times n$, positive diagonal), in any
/// dimension: each axis of $\xi$ gets `panels` panels of `points_per_panel` points, the nodes
/// are $m + L\xi_k$ and the weights $w_k\det L$. With $(m, LL^\top)$ the mean and covariance of
/// a density and $c$ a few standard deviations, the nodes follow the density wherever it moves;
/// the rule integrates over the parallelepiped $m + L[-c, c]^n$ (what lies outside is cut).
///
/// # Errors
/// [`Error::DimensionMismatch`] for `chol` not $n\times n$; [`Error::InvalidOption`] for a
/// non-positive or non-finite diagonal of $L$ or width $c$, or invalid panels.
pub fn frame_grid(
    mean: &[f64],
    chol: &[f64],
    width: f64,
    panels: usize,
    points_per_panel: usize,
) -> Result<Rule, Error> {
    let n = mean.len();
    if chol.len() != n * n {
        return Err(Error::DimensionMismatch { what: "chol", expected: n * n, got: chol.len() });
    }
    check_finite("mean", mean)?;
    check_finite("chol", chol)?;
    if n == 0 || !(width.is_finite() && width > 0.0) || (0..n).any(|i| chol[i * n + i] <= 0.0) {
        return Err(Error::InvalidOption {
            name: "frame",
            reason: format!(
                "need n >= 1, a width > 0 and a positive diagonal of L, got n {n}, width {width}"
            ),
        });
    }
    let axis = composite_gauss_legendre(-width, width, panels, points_per_panel)?;
    let box_rule = tensor_product(&vec![axis; n])?;
    let det: f64 = (0..n).map(|i| chol[i * n + i]).product();
    let mut points = Vec::with_capacity(box_rule.len() * n);
    let mut weights = Vec::with_capacity(box_rule.len());
    for (xi, w) in box_rule.iter() {
        for i in 0..n {
            points.push(mean[i] + (0..=i).map(|j| chol[i * n + j] * xi[j]).sum::<f64>());
        }
        weights.push(w * det);
    }
    Rule::try_new(n, points, weights)
}

/// An exponential family $p(x;\lambda) = e^{\lambda^\top M(x)}p_{\ast}(x)/\mathcal N(\lambda)$
/// (`003_d2fc48a470e528fc.txt (II.36)`–(II.37)) with user moment functions, integrated on a fixed
/// quadrature grid $\lbrace (x_k, w_k)\rbrace$:
/// $$F(\lambda) = \log\sum_k w_k p_{\ast}(x_k) e^{\lambda^\top M(x_k)},$$
/// evaluated with the log-sum-exp shift $s_k = \log(w_kp_{\ast}(x_k)) + \lambda^\top M(x_k)$,
/// $F = \max_k s_k + \log\sum_k e^{s_k - \max s}$, so large $|\lambda|$ never overflows. The
/// node probabilities $\pi_k = e^{s_k - F}$ give every cumulant.
#[derive(Clone)]
pub struct Exponential {
    grid: Rule,
    n_moments: usize,
    log_base: Vec<f64>,
    table: Vec<f64>,
    /// `table` moment-major (row a: M_a at every node), for the exponents λᵀM(x_k).
    table_by_moment: Vec<f64>,
    moments: MomentFn,
    derivatives: Option<MomentDerivativeFn>,
    lower: Vec<f64>,
    upper: Vec<f64>,
    exponents: Option<Vec<Vec<u32>>>,
}

impl fmt::Debug for Exponential {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Exponential")
            .field("dim", &self.grid.dim())
            .field("n_moments", &self.n_moments)
            .field("nodes", &self.grid.len())
            .field("exponents", &self.exponents)
            .finish()
    }
}

impl Exponential {
    /// The family with moment functions `moments` ($R$ = `n_moments` outputs) on `grid`
    /// (e.g. from [`panel_grid`]; weights must be positive) with reference `reference`.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] for `n_moments == 0`, a non-positive grid weight, or a reference
    /// that vanishes on the whole grid; [`Error::NonFinite`] if $M$ or $\log p_{\ast}$ is not finite
    /// (or $+\infty$) at a node.
    pub fn try_new(
        grid: Rule,
        reference: Reference,
        n_moments: usize,
        moments: impl Fn(&[f64], &mut [f64]) + Send + Sync + 'static,
    ) -> Result<Self, Error> {
        Self::build(grid, reference, n_moments, Arc::new(moments), None, None)
    }

    /// The family with moment functions `m` written generically over the scalar; their
    /// derivatives ([`TrialFamily::moment_derivatives`]) come from hyper-dual numbers.
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`] if `m.dim()` differs from the grid's dimension, plus those of
    /// [`Exponential::try_new`].
    pub fn from_moments<M: MomentFunctions + 'static>(
        grid: Rule,
        reference: Reference,
        m: M,
    ) -> Result<Self, Error> {
        Self::from_moments_with(grid, reference, m, None)
    }

    fn from_moments_with<M: MomentFunctions + 'static>(
        grid: Rule,
        reference: Reference,
        m: M,
        exponents: Option<Vec<Vec<u32>>>,
    ) -> Result<Self, Error> {
        if m.dim() != grid.dim() {
            return Err(Error::DimensionMismatch {
                what: "moment functions' dim",
                expected: grid.dim(),
                got: m.dim(),
            });
        }
        let r = m.n_moments();
        let d = m.dim();
        let m = Arc::new(m);
        let m1 = Arc::clone(&m);
        let moments: MomentFn = Arc::new(move |x: &[f64], out: &mut [f64]| m1.eval(x, out));
        let derivatives: MomentDerivativeFn =
            Arc::new(move |x: &[f64], jac: &mut [f64], hess: &mut [f64]| {
                // One hyper-dual evaluation per pair i ≤ j: eps1 along e_i, eps2 along e_j.
                let mut out = vec![HyperDual64::from(0.0); r];
                for i in 0..d {
                    for j in i..d {
                        let xs: Vec<HyperDual64> = x
                            .iter()
                            .enumerate()
                            .map(|(k, &v)| {
                                HyperDual64::new(
                                    v,
                                    if k == i { 1.0 } else { 0.0 },
                                    if k == j { 1.0 } else { 0.0 },
                                    0.0,
                                )
                            })
                            .collect();
                        m.eval(&xs, &mut out);
                        for (a, o) in out.iter().enumerate() {
                            if i == j {
                                jac[a * d + i] = o.eps1;
                            }
                            hess[(a * d + i) * d + j] = o.eps1eps2;
                            hess[(a * d + j) * d + i] = o.eps1eps2;
                        }
                    }
                }
            });
        Self::build(grid, reference, r, moments, Some(derivatives), exponents)
    }

    fn build(
        grid: Rule,
        reference: Reference,
        n_moments: usize,
        moments: MomentFn,
        derivatives: Option<MomentDerivativeFn>,
        exponents: Option<Vec<Vec<u32>>>,
    ) -> Result<Self, Error> {
        if n_moments == 0 {
            return Err(Error::InvalidOption {
                name: "n_moments",
                reason: "need at least one moment function".into(),
            });
        }
        if grid.is_empty() || grid.weights().iter().any(|&w| w <= 0.0) {
            return Err(Error::InvalidOption {
                name: "grid",
                reason: "the grid must be non-empty with positive weights".into(),
            });
        }
        let dim = grid.dim();
        let volume: f64 = grid.weights().iter().sum();
        let mut points = Vec::new();
        let mut weights = Vec::new();
        let mut log_base = Vec::new();
        let mut table = Vec::new();
        let mut buf = vec![0.0; n_moments];
        for (x, w) in grid.iter() {
            let log_ref = match &reference {
                Reference::Lebesgue => 0.0,
                Reference::Uniform => -volume.ln(),
                Reference::LogDensity(f) => f(x),
            };
            if log_ref == f64::NEG_INFINITY {
                continue;
            }
            if !log_ref.is_finite() {
                return Err(Error::NonFinite { what: "reference log-density" });
            }
            buf.iter_mut().for_each(|v| *v = 0.0);
            moments(x, &mut buf);
            check_finite("moment functions", &buf)?;
            points.extend_from_slice(x);
            weights.push(w);
            log_base.push(w.ln() + log_ref);
            table.extend_from_slice(&buf);
        }
        if weights.is_empty() {
            return Err(Error::InvalidOption {
                name: "reference",
                reason: "the reference density vanishes on every grid node".into(),
            });
        }
        let mut lower = vec![f64::INFINITY; n_moments];
        let mut upper = vec![f64::NEG_INFINITY; n_moments];
        for row in table.chunks_exact(n_moments) {
            for (a, &v) in row.iter().enumerate() {
                lower[a] = lower[a].min(v);
                upper[a] = upper[a].max(v);
            }
        }
        let nodes = log_base.len();
        let mut table_by_moment = vec![0.0; table.len()];
        for (k, row) in table.chunks_exact(n_moments).enumerate() {
            for (a, &v) in row.iter().enumerate() {
                table_by_moment[a * nodes + k] = v;
            }
        }
        Ok(Self {
            grid: Rule::try_new(dim, points, weights)?,
            n_moments,
            log_base,
            table,
            table_by_moment,
            moments,
            derivatives,
            lower,
            upper,
            exponents,
        })
    }

    /// The polynomial family of total degree `degree`: $M$ = the monomials of [`Polynomial`]
    /// (in 1-D: $M = (x, x^2, \dots, x^d)$; in 2-D with $d=2$: $(x, y, x^2, xy, y^2)$). See
    /// [`Exponential::exponents`]; the moment realizability check uses the moment matrix.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] for `degree == 0`, plus those of [`Exponential::try_new`].
    pub fn polynomial(grid: Rule, reference: Reference, degree: u32) -> Result<Self, Error> {
        let p = Polynomial::try_new(grid.dim(), degree)?;
        let exps = p.exponents().to_vec();
        Self::from_moments_with(grid, reference, p, Some(exps))
    }

    /// The quartic family on $[a, b]$ for double-well problems: $M = (x, x^2, x^3, x^4)$,
    /// Lebesgue reference, a [`panel_grid`] of 64 panels × 8 Gauss–Legendre points. The
    /// density is normalizable on the grid for every $\lambda$; on $\mathbb R$ it needs
    /// $\lambda_4 < 0$.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] for an empty or infinite interval.
    pub fn quartic(lower: f64, upper: f64) -> Result<Self, Error> {
        Self::polynomial(panel_grid(&[(lower, upper)], 64, 8)?, Reference::Lebesgue, 4)
    }

    /// The exponents $\alpha$ of the moments if the family is [polynomial](Self::polynomial).
    pub fn exponents(&self) -> Option<&[Vec<u32>]> {
        self.exponents.as_deref()
    }

    /// The grid nodes (those where $p_{\ast} > 0$) and their quadrature weights $w_k$ (for the
    /// reference measure, not yet multiplied by $p_{\ast}$).
    pub fn grid(&self) -> &Rule {
        &self.grid
    }

    /// The moment functions at every [grid](Self::grid) node, row-major (node $k$, moment
    /// $a$) at index $kR + a$: callers that integrate their own functions against
    /// $p(\cdot;\lambda)$ on the fixed nodes (a closure's generator average) reuse them.
    pub fn moment_table(&self) -> &[f64] {
        &self.table
    }

    /// The same table moment-major: $M_a(x_k)$ at index $aK + k$ ($K$ nodes), one contiguous
    /// row per moment, for loops over the nodes of one moment at a time.
    pub fn moment_table_by_moment(&self) -> &[f64] {
        &self.table_by_moment
    }

    /// Node probabilities $\pi_k = e^{s_k - F}$ (summing to 1) and $F(\lambda)$ by
    /// log-sum-exp (`003_d2fc48a470e528fc.txt (II.36)`–(II.38)); the nodes are those of
    /// [`Exponential::grid`] and do not move with $\lambda$, so
    /// $\partial\pi_k/\partial\lambda = \pi_k(M(x_k) - \mu)$.
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`], [`Error::NonFinite`], [`Error::NotNormalizable`].
    pub fn node_probabilities(&self, lambda: &[f64]) -> Result<(Vec<f64>, f64), Error> {
        self.probabilities(lambda)
    }

    /// [`Exponential::node_probabilities`] into reused buffers: $\pi_k$ into `p` and the
    /// exponents $s_k$ into `s` (both resized to the number of nodes); returns $F$. The form of
    /// the hot loops of a closure drift, evaluated at every Runge–Kutta stage.
    ///
    /// # Errors
    /// As [`Exponential::node_probabilities`].
    pub fn node_probabilities_into(
        &self,
        lambda: &[f64],
        s: &mut Vec<f64>,
        p: &mut Vec<f64>,
    ) -> Result<f64, Error> {
        check_len("lambda", lambda, self.n_moments)?;
        check_finite("lambda", lambda)?;
        // s_k = log(w_k p_*(x_k)) + Σ_a λ_a M_a(x_k), the sum in moment order, one moment row at
        // a time (contiguous, so the loops vectorise).
        let nodes = self.log_base.len();
        s.clear();
        s.resize(nodes, 0.0);
        for (a, (row, &l)) in self.table_by_moment.chunks_exact(nodes).zip(lambda).enumerate() {
            if a == 0 {
                for (v, &m) in s.iter_mut().zip(row) {
                    *v = m * l;
                }
            } else {
                for (v, &m) in s.iter_mut().zip(row) {
                    *v += m * l;
                }
            }
        }
        self.node_probabilities_from_exponents(s, p)
    }

    /// [`Exponential::node_probabilities_into`] from the exponents' polynomial part: `s` holds
    /// $\sum_a \lambda_a M_a(x_k)$ at every node on entry, formed by the caller in an order of
    /// its own (e.g. by products of axis tables on a tensor grid); the base log-weights
    /// $\log(w_k p_*(x_k))$ are added, then $\pi_k$ goes into `p` (resized) and $F$ is
    /// returned.
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`] for an `s` of another length than the nodes;
    /// [`Error::NotNormalizable`].
    pub fn node_probabilities_from_exponents(&self, s: &mut [f64], p: &mut Vec<f64>) -> Result<f64, Error> {
        check_len("exponents", s, self.log_base.len())?;
        // One pass adds the base and finds the largest exponent (and any NaN); on success every
        // entry of `p` is then written, so it is resized, not cleared (on an error it is
        // unspecified).
        let (mut max, mut nan) = (f64::NEG_INFINITY, false);
        for (v, &b) in s.iter_mut().zip(&self.log_base) {
            *v += b;
            nan |= v.is_nan();
            max = max.max(*v);
        }
        p.resize(s.len(), 0.0);
        match normalize_log_weights_from_max(s, max, p) {
            Some(f) if !nan => Ok(f),
            _ => Err(Error::NotNormalizable {
                reason: format!("lambda^T M overflows on the grid (max exponent {max})"),
            }),
        }
    }

    /// Node probabilities $\pi_k = e^{s_k - F}$ and $F$ (log-sum-exp), the core of every other
    /// routine (`003_d2fc48a470e528fc.txt (II.36)`–(II.38)).
    fn probabilities(&self, lambda: &[f64]) -> Result<(Vec<f64>, f64), Error> {
        let (mut s, mut p) = (Vec::new(), Vec::new());
        let f = self.node_probabilities_into(lambda, &mut s, &mut p)?;
        Ok((p, f))
    }

    fn moments_under(&self, p: &[f64]) -> Vec<f64> {
        let r = self.n_moments;
        let mut mu = vec![0.0; r];
        for (row, &pk) in self.table.chunks_exact(r).zip(p) {
            for (m, v) in mu.iter_mut().zip(row) {
                *m += pk * v;
            }
        }
        mu
    }
}

/// All exponent vectors in `dim` variables with $1 \le |\alpha| \le$ `degree`, by degree.
fn monomials(dim: usize, degree: u32) -> Vec<Vec<u32>> {
    let mut out = Vec::new();
    for d in 1..=degree {
        out.extend(exact_degree(dim, d));
    }
    out
}

/// Exponent vectors of total degree exactly `d`, first exponent descending.
fn exact_degree(dim: usize, d: u32) -> Vec<Vec<u32>> {
    if dim == 1 {
        return vec![vec![d]];
    }
    let mut out = Vec::new();
    for a in (0..=d).rev() {
        for mut rest in exact_degree(dim - 1, d - a) {
            rest.insert(0, a);
            out.push(rest);
        }
    }
    out
}

impl TrialFamily for Exponential {
    fn dim(&self) -> usize {
        self.grid.dim()
    }

    fn n_moments(&self) -> usize {
        self.n_moments
    }

    fn moment_functions(&self, x: &[f64], out: &mut [f64]) -> Result<(), Error> {
        check_len("x", x, self.grid.dim())?;
        check_len("out", out, self.n_moments)?;
        out.iter_mut().for_each(|v| *v = 0.0);
        (self.moments)(x, out);
        check_finite("moment functions", out)
    }

    /// By hyper-dual numbers for families built with [`Exponential::from_moments`] or
    /// [`Exponential::polynomial`].
    fn moment_derivatives(&self, x: &[f64], jacobian: &mut [f64], hessians: &mut [f64]) -> Result<(), Error> {
        let d = self.grid.dim();
        let r = self.n_moments;
        check_len("x", x, d)?;
        check_len("jacobian", jacobian, r * d)?;
        check_len("hessians", hessians, r * d * d)?;
        check_finite("x", x)?;
        let f = self.derivatives.as_ref().ok_or(Error::Unsupported {
            what: "moment derivatives need moment functions generic over the scalar \
                   (Exponential::from_moments)",
        })?;
        f(x, jacobian, hessians);
        check_finite("moment derivatives", jacobian)?;
        check_finite("moment derivatives", hessians)
    }

    /// $F(\lambda) = \log\sum_k w_kp_{\ast}(x_k)e^{\lambda^\top M(x_k)}$ by log-sum-exp,
    /// `003_d2fc48a470e528fc.txt (II.38)`.
    fn log_partition(&self, lambda: &[f64]) -> Result<f64, Error> {
        Ok(self.probabilities(lambda)?.1)
    }

    /// $\mu = \sum_k\pi_kM(x_k)$, $C = \sum_k\pi_k(M(x_k)-\mu)(M(x_k)-\mu)^\top$ (two-pass,
    /// centred), `003_d2fc48a470e528fc.txt (II.38)`–(II.39).
    fn cumulants(&self, lambda: &[f64]) -> Result<Cumulants, Error> {
        let (p, f) = self.probabilities(lambda)?;
        let r = self.n_moments;
        let mu = self.moments_under(&p);
        let mut c = vec![0.0; r * r];
        let mut d = vec![0.0; r];
        for (row, &pk) in self.table.chunks_exact(r).zip(&p) {
            for a in 0..r {
                d[a] = row[a] - mu[a];
            }
            for a in 0..r {
                let pa = pk * d[a];
                for b in a..r {
                    c[a * r + b] += pa * d[b];
                }
            }
        }
        for a in 0..r {
            for b in 0..a {
                c[a * r + b] = c[b * r + a];
            }
        }
        Ok(Cumulants { log_partition: f, mean: mu, covariance: c })
    }

    /// $C_{abc} = \sum_k\pi_k d_ad_bd_c$ with $d = M(x_k) - \mu$,
    /// `003_d2fc48a470e528fc.txt (II.43)`.
    fn third_cumulant(&self, lambda: &[f64]) -> Result<Vec<f64>, Error> {
        let (p, _) = self.probabilities(lambda)?;
        let r = self.n_moments;
        let mu = self.moments_under(&p);
        let mut out = vec![0.0; r * r * r];
        let mut d = vec![0.0; r];
        for (row, &pk) in self.table.chunks_exact(r).zip(&p) {
            for a in 0..r {
                d[a] = row[a] - mu[a];
            }
            for a in 0..r {
                for b in a..r {
                    let pab = pk * d[a] * d[b];
                    for c in b..r {
                        out[(a * r + b) * r + c] += pab * d[c];
                    }
                }
            }
        }
        for a in 0..r {
            for b in a..r {
                for c in b..r {
                    let v = out[(a * r + b) * r + c];
                    for (x, y, z) in [(a, c, b), (b, a, c), (b, c, a), (c, a, b), (c, b, a)] {
                        out[(x * r + y) * r + z] = v;
                    }
                }
            }
        }
        Ok(out)
    }

    /// The fixed grid nodes with probabilities $\pi_k$.
    fn quadrature(&self, lambda: &[f64]) -> Result<Rule, Error> {
        let (p, _) = self.probabilities(lambda)?;
        Rule::try_new(self.grid.dim(), self.grid.points().to_vec(), p)
    }

    /// Necessary conditions: each $\mu_a$ strictly inside $[\min_k M_a(x_k), \max_k M_a(x_k)]$;
    /// for polynomial families also a positive definite moment matrix
    /// $G_{\alpha\beta} = \mu_{\alpha+\beta}$, $|\alpha|,|\beta| \le \lfloor d/2\rfloor$
    /// ($\mu_0 = 1$; in 1-D with $d\ge2$ this contains the variance condition
    /// $\mu_2 - \mu_1^2 > 0$). Points outside the convex hull that pass these checks are caught
    /// by the divergence test of [`legendre_newton`](crate::legendre_newton).
    fn check_realizable(&self, mu: &[f64]) -> Result<(), Error> {
        check_len("mu", mu, self.n_moments)?;
        check_finite("mu", mu)?;
        for (a, ((&m, &lo), &hi)) in mu.iter().zip(&self.lower).zip(&self.upper).enumerate() {
            if m <= lo || m >= hi {
                return Err(Error::Unrealizable {
                    reason: format!(
                        "mu[{a}] = {m} is not strictly inside the range [{lo}, {hi}] of M_{a} on the grid"
                    ),
                });
            }
        }
        if let Some(exps) = &self.exponents {
            let degree = exps.iter().map(|e| e.iter().sum::<u32>()).max().unwrap_or(0);
            let half = degree / 2;
            if half >= 1 {
                let dim = self.grid.dim();
                let mut basis = vec![vec![0u32; dim]];
                basis.extend(exps.iter().filter(|e| e.iter().sum::<u32>() <= half).cloned());
                let value = |e: &[u32]| -> f64 {
                    if e.iter().all(|&k| k == 0) {
                        1.0
                    } else {
                        exps.iter().position(|x| x.as_slice() == e).map_or(f64::NAN, |i| mu[i])
                    }
                };
                let n = basis.len();
                let mut g = vec![0.0; n * n];
                for i in 0..n {
                    for j in 0..n {
                        let e: Vec<u32> = basis[i].iter().zip(&basis[j]).map(|(a, b)| a + b).collect();
                        g[i * n + j] = value(&e);
                    }
                }
                if cholesky(&g, n).is_err() {
                    return Err(Error::Unrealizable {
                        reason: "the moment matrix mu_(alpha+beta) is not positive definite \
                                 (e.g. a variance <= 0)"
                            .into(),
                    });
                }
            }
        }
        Ok(())
    }
}
