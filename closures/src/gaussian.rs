//! The Gaussian family in any dimension.

use crate::error::{check_finite, check_len, Error};
use crate::family::{max_abs, Cumulants, LegendreOptions, LegendreSolution, TrialFamily};
use crate::quadrature::{cubature3, cubature5, gauss_hermite_tensor, Rule};
use crate::scalar::{
    cholesky, cholesky_into, cholesky_inverse, cholesky_inverse_into, cholesky_log_det, dot, Scalar,
};

/// Quadrature used by [`Gaussian`] for expectations: a rule for $N(0, I_n)$ mapped to
/// $N(m, \Sigma)$ by $x = m + L\xi$, $\Sigma = LL^\top$ (Cholesky).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum GaussianRule {
    /// Tensor Gauss–Hermite with 16, 8, 5 points per dimension for $n = 1, 2, 3$ and
    /// [`GaussianRule::Cubature5`] for $n \ge 4$.
    Auto,
    /// Tensor Gauss–Hermite with this many points per dimension ($k^n$ nodes, exact for
    /// $\prod_i x_i^{a_i}$ with every $a_i \le 2k-1$).
    GaussHermite {
        /// Points per dimension $k \ge 1$.
        points_per_dim: usize,
    },
    /// Third-degree spherical–radial cubature, $2n$ nodes (see [`cubature3`]).
    Cubature3,
    /// Fifth-degree cubature, $2n^2+1$ nodes (see [`cubature5`]).
    Cubature5,
}

/// The Gaussian family $p(x;\lambda) \propto \exp(\lambda^\top M(x))$ on $\mathbb R^n$ with
/// Lebesgue reference $p_{\ast} = 1$ (`003_d2fc48a470e528fc.txt (II.36)`) and the non-redundant
/// moment functions
/// $$M(x) = (x_1, \dots, x_n,\  x_i x_j\ (i \le j)),\qquad R = n + \tfrac{n(n+1)}{2}.$$
///
/// Ordering: the $n$ linear moments first, then the pairs $(i, j)$, $i \le j$, row by row:
/// $(0,0), (0,1), \dots, (0,n-1), (1,1), \dots$ (see [`Gaussian::quadratic_index`]).
///
/// Natural parameters: writing $\lambda = (a, b)$,
/// $\lambda^\top M(x) = a^\top x - \tfrac12 x^\top P x$ with the precision
/// $P_{ii} = -2b_{ii}$, $P_{ij} = P_{ji} = -b_{ij}$ ($i<j$), so $\Sigma = P^{-1}$, $m = \Sigma a$
/// and $\lambda$ is normalizable iff $P \succ 0$.
#[derive(Debug, Clone, PartialEq)]
pub struct Gaussian {
    dim: usize,
    rule_kind: GaussianRule,
    standard: Rule,
}

impl Gaussian {
    /// The Gaussian family on $\mathbb R^{dim}$ with [`GaussianRule::Auto`].
    ///
    /// # Errors
    /// [`Error::InvalidOption`] if `dim == 0`.
    pub fn try_new(dim: usize) -> Result<Self, Error> {
        if dim == 0 {
            return Err(Error::InvalidOption {
                name: "dim",
                reason: "the Gaussian family needs dim >= 1".into(),
            });
        }
        Self::build(dim, GaussianRule::Auto)
    }

    /// The same family with another quadrature rule.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] for an invalid Gauss–Hermite size (see [`gauss_hermite_tensor`]).
    pub fn with_rule(self, rule: GaussianRule) -> Result<Self, Error> {
        Self::build(self.dim, rule)
    }

    fn build(dim: usize, rule_kind: GaussianRule) -> Result<Self, Error> {
        let standard = match rule_kind {
            GaussianRule::Auto => match dim {
                1 => gauss_hermite_tensor(1, 16)?,
                2 => gauss_hermite_tensor(2, 8)?,
                3 => gauss_hermite_tensor(3, 5)?,
                _ => cubature5(dim)?,
            },
            GaussianRule::GaussHermite { points_per_dim } => gauss_hermite_tensor(dim, points_per_dim)?,
            GaussianRule::Cubature3 => cubature3(dim)?,
            GaussianRule::Cubature5 => cubature5(dim)?,
        };
        Ok(Self { dim, rule_kind, standard })
    }

    /// The quadrature rule in use.
    pub fn rule_kind(&self) -> GaussianRule {
        self.rule_kind
    }

    /// The rule for the standard normal $N(0, I_n)$ that [`Gaussian::nodes`] maps.
    pub fn standard_rule(&self) -> &Rule {
        &self.standard
    }

    /// Number of moments $R = n + n(n+1)/2$.
    pub fn moment_count(&self) -> usize {
        self.dim + self.dim * (self.dim + 1) / 2
    }

    /// Index in $M$ (and $\lambda$, $\mu$) of the quadratic moment $x_i x_j$, symmetric in
    /// $(i, j)$; `None` if $i$ or $j \ge n$.
    pub fn quadratic_index(&self, i: usize, j: usize) -> Option<usize> {
        (i < self.dim && j < self.dim).then(|| self.qidx(i, j))
    }

    /// [`Gaussian::quadratic_index`] for indices known to be in range.
    fn qidx(&self, i: usize, j: usize) -> usize {
        let n = self.dim;
        let (i, j) = if i <= j { (i, j) } else { (j, i) };
        // Rows k < i hold n - k pairs each: Σ_{k<i} (n - k) = i n - i(i-1)/2.
        n + i * n - i * i.saturating_sub(1) / 2 + (j - i)
    }

    fn check_mean_cov<D: Scalar>(&self, mean: &[D], cov: &[D]) -> Result<(), Error> {
        check_len("mean", mean, self.dim)?;
        check_len("cov", cov, self.dim * self.dim)?;
        if mean.iter().chain(cov).any(|v| !v.re().is_finite()) {
            return Err(Error::NonFinite { what: "mean/cov" });
        }
        Ok(())
    }

    /// Quadrature nodes and weights for $N(m, \Sigma)$: $x_k = m + L\xi_k$ with
    /// $\Sigma = LL^\top$ and $(\xi_k, w_k)$ the [standard rule](Gaussian::standard_rule), so
    /// $\mathbb E[g(x)] \approx \sum_k w_k g(x_k)$.
    ///
    /// Generic over the scalar: with dual numbers in `mean` and `cov` (row-major $n\times n$,
    /// symmetric; the lower triangle is read) the nodes carry derivatives, so a caller can
    /// differentiate expectations of its own functions with respect to $m$ and $\Sigma$.
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`], [`Error::NonFinite`], [`Error::NotPositiveDefinite`].
    pub fn nodes<D: Scalar>(&self, mean: &[D], cov: &[D]) -> Result<Vec<(Vec<D>, f64)>, Error> {
        self.check_mean_cov(mean, cov)?;
        let n = self.dim;
        let l = cholesky(cov, n).map_err(|e| match e {
            Error::NotPositiveDefinite { .. } => Error::NotPositiveDefinite { what: "cov" },
            other => other,
        })?;
        Ok(self
            .standard
            .iter()
            .map(|(xi, w)| {
                let x = (0..n)
                    .map(|i| {
                        let mut v = mean[i];
                        for (k, xik) in xi.iter().enumerate().take(i + 1) {
                            v += l[i * n + k] * *xik;
                        }
                        v
                    })
                    .collect();
                (x, w)
            })
            .collect())
    }

    /// The moments $\mu = \langle M\rangle = (m_i,\ \Sigma_{ij} + m_i m_j)$ of $N(m, \Sigma)$.
    ///
    /// # Errors
    /// [`Error::DimensionMismatch`], [`Error::NonFinite`].
    pub fn moments_from_mean_cov<D: Scalar>(&self, mean: &[D], cov: &[D]) -> Result<Vec<D>, Error> {
        self.check_mean_cov(mean, cov)?;
        let n = self.dim;
        let mut mu = mean.to_vec();
        for i in 0..n {
            for j in i..n {
                mu.push(cov[i * n + j] + mean[i] * mean[j]);
            }
        }
        Ok(mu)
    }

    /// Mean $m$ and covariance $\Sigma$ (row-major) from the moments: $m_i = \mu_i$,
    /// $\Sigma_{ij} = \mu_{(ij)} - m_i m_j$.
    ///
    /// # Errors
    /// [`Error::Unrealizable`] if $\Sigma$ is not positive definite (e.g. a variance
    /// $\le 0$), plus input errors.
    pub fn mean_cov_from_moments<D: Scalar>(&self, mu: &[D]) -> Result<(Vec<D>, Vec<D>), Error> {
        check_len("mu", mu, self.moment_count())?;
        if mu.iter().any(|v| !v.re().is_finite()) {
            return Err(Error::NonFinite { what: "mu" });
        }
        let n = self.dim;
        let mean = mu[..n].to_vec();
        let mut cov = vec![D::zero(); n * n];
        for i in 0..n {
            for j in i..n {
                let c = mu[self.qidx(i, j)] - mean[i] * mean[j];
                cov[i * n + j] = c;
                cov[j * n + i] = c;
            }
        }
        if cholesky(&cov, n).is_err() {
            return Err(Error::Unrealizable {
                reason: "the covariance mu_(ij) - mu_i mu_j is not positive definite".into(),
            });
        }
        Ok((mean, cov))
    }

    /// Natural parameters $\lambda = (a, b)$ of $N(m, \Sigma)$: $P = \Sigma^{-1}$, $a = Pm$,
    /// $b_{ii} = -P_{ii}/2$, $b_{ij} = -P_{ij}$ ($i<j$).
    ///
    /// # Errors
    /// [`Error::NotPositiveDefinite`] if $\Sigma$ is not positive definite, plus input errors.
    pub fn natural_from_mean_cov<D: Scalar>(&self, mean: &[D], cov: &[D]) -> Result<Vec<D>, Error> {
        self.check_mean_cov(mean, cov)?;
        let n = self.dim;
        let l = cholesky(cov, n).map_err(|_| Error::NotPositiveDefinite { what: "cov" })?;
        let p = cholesky_inverse(&l, n)?;
        let mut lambda: Vec<D> = (0..n).map(|i| (0..n).map(|j| p[i * n + j] * mean[j]).sum()).collect();
        for i in 0..n {
            for j in i..n {
                lambda.push(if i == j { -p[i * n + i] * 0.5 } else { -p[i * n + j] });
            }
        }
        Ok(lambda)
    }

    /// Precision matrix $P$ (row-major) from $\lambda$ into `p`: $P_{ii} = -2b_{ii}$,
    /// $P_{ij} = -b_{ij}$.
    fn precision_into<D: Scalar>(&self, lambda: &[D], p: &mut [D]) {
        let n = self.dim;
        p.iter_mut().for_each(|v| *v = D::zero());
        for i in 0..n {
            for j in i..n {
                let b = lambda[self.qidx(i, j)];
                if i == j {
                    p[i * n + i] = -b * 2.0;
                } else {
                    p[i * n + j] = -b;
                    p[j * n + i] = -b;
                }
            }
        }
    }

    fn check_lambda<D: Scalar>(&self, lambda: &[D]) -> Result<(), Error> {
        check_len("lambda", lambda, self.moment_count())?;
        if lambda.iter().any(|v| !v.re().is_finite()) {
            return Err(Error::NonFinite { what: "lambda" });
        }
        Ok(())
    }

    /// Mean $m = P^{-1}a$ and covariance $\Sigma = P^{-1}$ (row-major) from $\lambda$.
    ///
    /// # Errors
    /// [`Error::NotNormalizable`] if $P$ is not positive definite, plus input errors.
    pub fn mean_cov_from_natural<D: Scalar>(&self, lambda: &[D]) -> Result<(Vec<D>, Vec<D>), Error> {
        let (mean, cov, _) = self.mean_cov_precision_from_natural(lambda)?;
        Ok((mean, cov))
    }

    /// Mean $m = P^{-1}a$, covariance $\Sigma = P^{-1}$ and precision $P$ (row-major) from
    /// $\lambda$: [`Gaussian::mean_cov_from_natural`] for callers that need $P$ as well.
    ///
    /// # Errors
    /// As [`Gaussian::mean_cov_from_natural`].
    #[allow(clippy::type_complexity)]
    pub fn mean_cov_precision_from_natural<D: Scalar>(
        &self,
        lambda: &[D],
    ) -> Result<(Vec<D>, Vec<D>, Vec<D>), Error> {
        self.check_lambda(lambda)?;
        let (mean, cov, p, _) = self.mean_cov_factor(lambda)?;
        Ok((mean, cov, p))
    }

    /// $(m, \Sigma, \log\det\Sigma)$ from $\lambda$.
    #[allow(clippy::type_complexity)]
    fn mean_cov_logdet<D: Scalar>(&self, lambda: &[D]) -> Result<(Vec<D>, Vec<D>, D), Error> {
        let (mean, cov, _, l) = self.mean_cov_factor(lambda)?;
        let log_det_cov = -cholesky_log_det(&l, self.dim)?;
        if !log_det_cov.re().is_finite() {
            return Err(Error::NotNormalizable { reason: "the mean or covariance overflows".into() });
        }
        Ok((mean, cov, log_det_cov))
    }

    /// $(m, \Sigma, P, L)$ from $\lambda$ with $P = LL^\top$.
    #[allow(clippy::type_complexity)]
    fn mean_cov_factor<D: Scalar>(&self, lambda: &[D]) -> Result<(Vec<D>, Vec<D>, Vec<D>, Vec<D>), Error> {
        let n = self.dim;
        let (mut mean, mut cov, mut p, mut l) =
            (vec![D::zero(); n], vec![D::zero(); n * n], vec![D::zero(); n * n], vec![D::zero(); n * n]);
        self.factor_into(lambda, &mut mean, &mut cov, &mut p, &mut l)?;
        Ok((mean, cov, p, l))
    }

    /// [`Gaussian::mean_cov_precision_from_natural`] into caller buffers, without allocating
    /// (the form of a closure drift's hot loop): $m$ into `mean` (length $n$), $\Sigma$, $P$ and
    /// the Cholesky factor $L$ of $P = LL^\top$ into `cov`, `p`, `l` ($n\times n$ each).
    ///
    /// # Errors
    /// As [`Gaussian::mean_cov_from_natural`]; [`Error::DimensionMismatch`] for buffers of the
    /// wrong length.
    pub fn mean_cov_precision_into<D: Scalar>(
        &self,
        lambda: &[D],
        mean: &mut [D],
        cov: &mut [D],
        p: &mut [D],
        l: &mut [D],
    ) -> Result<(), Error> {
        self.check_lambda(lambda)?;
        self.factor_into(lambda, mean, cov, p, l)
    }

    /// $(m, \Sigma, P, L)$ into buffers (see [`Gaussian::mean_cov_precision_into`]).
    fn factor_into<D: Scalar>(
        &self,
        lambda: &[D],
        mean: &mut [D],
        cov: &mut [D],
        p: &mut [D],
        l: &mut [D],
    ) -> Result<(), Error> {
        let n = self.dim;
        check_len("mean", mean, n)?;
        check_len("cov", cov, n * n)?;
        check_len("precision", p, n * n)?;
        check_len("cholesky factor", l, n * n)?;
        self.precision_into(lambda, p);
        cholesky_into(p, n, l).map_err(|_| Error::NotNormalizable {
            reason: "the precision matrix P (P_ii = -2 b_ii, P_ij = -b_ij) is not positive \
                     definite"
                .into(),
        })?;
        cholesky_inverse_into(l, n, cov)?;
        for (i, mi) in mean.iter_mut().enumerate() {
            *mi = (0..n).map(|j| cov[i * n + j] * lambda[j]).sum();
        }
        if mean.iter().chain(cov.iter()).any(|v| !v.re().is_finite()) {
            return Err(Error::NotNormalizable { reason: "the mean or covariance overflows".into() });
        }
        Ok(())
    }

    /// The log-partition function, generic over the scalar:
    /// $$F(\lambda) = \tfrac12 a^\top P^{-1} a + \tfrac12\log\det(2\pi P^{-1})$$
    /// (`003_d2fc48a470e528fc.txt (II.38)` for the Gaussian integral).
    ///
    /// # Errors
    /// [`Error::NotNormalizable`] if $P$ is not positive definite, plus input errors.
    pub fn log_partition_generic<D: Scalar>(&self, lambda: &[D]) -> Result<D, Error> {
        self.check_lambda(lambda)?;
        let n = self.dim;
        let (mean, _, log_det_cov) = self.mean_cov_logdet(lambda)?;
        let quad: D = (0..n).map(|i| lambda[i] * mean[i]).sum();
        let f = quad * 0.5 + log_det_cov * 0.5 + (n as f64) * 0.5 * (2.0 * std::f64::consts::PI).ln();
        if !f.re().is_finite() {
            return Err(Error::NotNormalizable { reason: "F(lambda) overflows".into() });
        }
        Ok(f)
    }

    /// Relative entropy of $N(m, \Sigma)$ with respect to Lebesgue measure,
    /// $H = \int p\log p = -\tfrac12\log\det(2\pi e\Sigma)$ (`003_d2fc48a470e528fc.txt (II.39)`).
    fn entropy_from_logdet(&self, log_det_cov: f64) -> f64 {
        let n = self.dim as f64;
        -0.5 * (n * (2.0 * std::f64::consts::PI).ln() + n + log_det_cov)
    }

    /// Linear part $l_a$ (in $y = x - m$) of each moment: $M_a = c_a + l_a^\top y + y^\top Q_a y$.
    fn linear_parts(&self, mean: &[f64]) -> Vec<Vec<f64>> {
        let n = self.dim;
        let mut out = Vec::with_capacity(self.moment_count());
        for i in 0..n {
            let mut l = vec![0.0; n];
            l[i] = 1.0;
            out.push(l);
        }
        for i in 0..n {
            for j in i..n {
                let mut l = vec![0.0; n];
                l[j] += mean[i];
                l[i] += mean[j];
                out.push(l);
            }
        }
        out
    }

    /// The pair $(i, j)$ of quadratic moment $a$ (or `None` for a linear moment).
    fn pairs(&self) -> Vec<Option<(usize, usize)>> {
        let n = self.dim;
        let mut out = vec![None; n];
        for i in 0..n {
            for j in i..n {
                out.push(Some((i, j)));
            }
        }
        out
    }

    /// $A_a = Q_a\Sigma$ for each moment ($Q_a = (e_ie_j^\top + e_je_i^\top)/2$ or 0).
    fn q_sigma(&self, cov: &[f64]) -> Vec<Vec<f64>> {
        let n = self.dim;
        self.pairs()
            .iter()
            .map(|p| {
                let mut a = vec![0.0; n * n];
                if let Some((i, j)) = *p {
                    for c in 0..n {
                        a[i * n + c] += 0.5 * cov[j * n + c];
                        a[j * n + c] += 0.5 * cov[i * n + c];
                    }
                }
                a
            })
            .collect()
    }

    /// [`TrialFamily::cumulants`] in any dimension (λ checked by the caller).
    fn general_cumulants(&self, lambda: &[f64]) -> Result<Cumulants, Error> {
        let n = self.dim;
        let (mean, cov, log_det_cov) = self.mean_cov_logdet(lambda)?;
        let quad: f64 = (0..n).map(|i| lambda[i] * mean[i]).sum();
        let log_partition =
            0.5 * quad + 0.5 * log_det_cov + 0.5 * n as f64 * (2.0 * std::f64::consts::PI).ln();
        let mu = self.moments_from_mean_cov(&mean, &cov)?;
        let covariance = self.covariance_from_mean_cov(&mean, &cov);
        let out = Cumulants { log_partition, mean: mu, covariance };
        if !out.log_partition.is_finite() || out.mean.iter().chain(&out.covariance).any(|v| !v.is_finite()) {
            return Err(Error::NotNormalizable { reason: "the cumulants overflow".into() });
        }
        Ok(out)
    }

    /// Covariance of $M$ under $N(m, \Sigma)$: with $M_a = c_a + l_a^\top y + y^\top Q_a y$,
    /// $y \sim N(0,\Sigma)$, $C_{ab} = l_a^\top\Sigma l_b + 2 \mathrm{tr}(Q_a\Sigma Q_b\Sigma)$
    /// (Isserlis).
    fn covariance_from_mean_cov(&self, mean: &[f64], cov: &[f64]) -> Vec<f64> {
        let n = self.dim;
        let r = self.moment_count();
        let l = self.linear_parts(mean);
        let a = self.q_sigma(cov);
        let u: Vec<Vec<f64>> = l.iter().map(|la| mat_vec(cov, la, n)).collect();
        let mut c = vec![0.0; r * r];
        for p in 0..r {
            for q in p..r {
                let v = dot(&l[p], &u[q]) + 2.0 * trace_product(&a[p], &a[q], n);
                c[p * r + q] = v;
                c[q * r + p] = v;
            }
        }
        c
    }
}

/// The cumulants of one state in closed form: with λ = (a, b), P = −2b, v = 1/P and m = av,
/// F = ½am + ½ln(2πv), μ = (m, v + m²) and, by Isserlis' theorem, C = [[v, 2mv], [2mv,
/// 2v² + 4m²v]] (`003_d2fc48a470e528fc.txt (II.38)`): [`Gaussian::general_cumulants`] without
/// its buffers (this runs at every event of a closure's sweep). `None` where P ≤ 0 or a value is
/// not finite, for the general form to report.
fn one_state_cumulants(lambda: &[f64]) -> Option<Cumulants> {
    let p = -2.0 * lambda[1];
    if !(p > 0.0 && p.is_finite()) {
        return None;
    }
    let v = 1.0 / p;
    let m = lambda[0] * v;
    let log_partition = 0.5 * lambda[0] * m + 0.5 * (2.0 * std::f64::consts::PI * v).ln();
    let c = 2.0 * m * v;
    let out = Cumulants {
        log_partition,
        mean: vec![m, v + m * m],
        covariance: vec![v, c, c, 2.0 * v * v + 2.0 * m * c],
    };
    (out.log_partition.is_finite() && out.mean.iter().chain(&out.covariance).all(|x| x.is_finite()))
        .then_some(out)
}

fn mat_vec(m: &[f64], v: &[f64], n: usize) -> Vec<f64> {
    (0..n).map(|i| dot(&m[i * n..(i + 1) * n], v)).collect()
}

fn mat_mul(a: &[f64], b: &[f64], n: usize) -> Vec<f64> {
    let mut c = vec![0.0; n * n];
    for i in 0..n {
        for k in 0..n {
            let aik = a[i * n + k];
            if aik != 0.0 {
                for j in 0..n {
                    c[i * n + j] += aik * b[k * n + j];
                }
            }
        }
    }
    c
}

/// $\mathrm{tr}(AB)$ for row-major $n\times n$ matrices.
fn trace_product(a: &[f64], b: &[f64], n: usize) -> f64 {
    let mut s = 0.0;
    for i in 0..n {
        for k in 0..n {
            s += a[i * n + k] * b[k * n + i];
        }
    }
    s
}

impl TrialFamily for Gaussian {
    fn dim(&self) -> usize {
        self.dim
    }

    fn n_moments(&self) -> usize {
        self.moment_count()
    }

    /// $M(x) = (x_i,\ x_i x_j\ (i\le j))$.
    fn moment_functions(&self, x: &[f64], out: &mut [f64]) -> Result<(), Error> {
        check_len("x", x, self.dim)?;
        check_len("out", out, self.moment_count())?;
        let n = self.dim;
        out[..n].copy_from_slice(x);
        let mut k = n;
        for i in 0..n {
            for j in i..n {
                out[k] = x[i] * x[j];
                k += 1;
            }
        }
        Ok(())
    }

    /// $\partial x_i/\partial x_k = \delta_{ik}$, $\partial(x_ix_j)/\partial x_k =
    /// \delta_{ik}x_j + \delta_{jk}x_i$, $\partial^2(x_ix_j)/\partial x_k\partial x_l =
    /// \delta_{ik}\delta_{jl} + \delta_{il}\delta_{jk}$.
    fn moment_derivatives(&self, x: &[f64], jacobian: &mut [f64], hessians: &mut [f64]) -> Result<(), Error> {
        let n = self.dim;
        let r = self.moment_count();
        check_len("x", x, n)?;
        check_len("jacobian", jacobian, r * n)?;
        check_len("hessians", hessians, r * n * n)?;
        check_finite("x", x)?;
        jacobian.iter_mut().for_each(|v| *v = 0.0);
        hessians.iter_mut().for_each(|v| *v = 0.0);
        for i in 0..n {
            jacobian[i * n + i] = 1.0;
        }
        for (a, p) in self.pairs().into_iter().enumerate() {
            if let Some((i, j)) = p {
                jacobian[a * n + i] += x[j];
                jacobian[a * n + j] += x[i];
                hessians[(a * n + i) * n + j] += 1.0;
                hessians[(a * n + j) * n + i] += 1.0;
            }
        }
        Ok(())
    }

    /// $F(\lambda) = \tfrac12 a^\top P^{-1}a + \tfrac12\log\det(2\pi P^{-1})$,
    /// `003_d2fc48a470e528fc.txt (II.38)`.
    fn log_partition(&self, lambda: &[f64]) -> Result<f64, Error> {
        if self.dim == 1 && lambda.len() == 2 {
            // The same closed form as `cumulants`, so that F agrees between the two to the bit.
            if let Some(c) = one_state_cumulants(lambda) {
                return Ok(c.log_partition);
            }
        }
        self.log_partition_generic(lambda)
    }

    /// Closed forms: $\mu = (m_i, \Sigma_{ij}+m_im_j)$ and $C_{ab}$ by Isserlis' theorem
    /// (`003_d2fc48a470e528fc.txt (II.38)`–(II.39)); for one state written out without buffers
    /// (`one_state_cumulants`).
    fn cumulants(&self, lambda: &[f64]) -> Result<Cumulants, Error> {
        self.check_lambda(lambda)?;
        if self.dim == 1 {
            if let Some(c) = one_state_cumulants(lambda) {
                return Ok(c);
            }
        }
        self.general_cumulants(lambda)
    }

    /// Closed form (`003_d2fc48a470e528fc.txt (II.43)`): with
    /// $M_a = c_a + l_a^\top y + y^\top Q_a y$, $y\sim N(0,\Sigma)$,
    /// $$C_{abc} = 8 \mathrm{tr}(Q_a\Sigma Q_b\Sigma Q_c\Sigma) +
    ///   2 (l_a^\top\Sigma Q_b\Sigma l_c + l_a^\top\Sigma Q_c\Sigma l_b +
    ///   l_b^\top\Sigma Q_a\Sigma l_c).$$
    ///
    /// The block of the linear moments, the third cumulant of $x$, is zero.
    fn third_cumulant(&self, lambda: &[f64]) -> Result<Vec<f64>, Error> {
        self.check_lambda(lambda)?;
        let n = self.dim;
        let r = self.moment_count();
        let (mean, cov, _) = self.mean_cov_logdet(lambda)?;
        let l = self.linear_parts(&mean);
        let a = self.q_sigma(&cov);
        let pairs = self.pairs();
        let u: Vec<Vec<f64>> = l.iter().map(|la| mat_vec(&cov, la, n)).collect();
        // u_pᵀ Q_q u_s with Q_q = (e_i e_jᵀ + e_j e_iᵀ)/2.
        let uqu = |p: usize, q: usize, s: usize| -> f64 {
            match pairs[q] {
                None => 0.0,
                Some((i, j)) => 0.5 * (u[p][i] * u[s][j] + u[p][j] * u[s][i]),
            }
        };
        let mut out = vec![0.0; r * r * r];
        for p in 0..r {
            for q in p..r {
                let apq = mat_mul(&a[p], &a[q], n);
                for s in q..r {
                    let mut v = 2.0 * (uqu(p, q, s) + uqu(p, s, q) + uqu(q, p, s));
                    if pairs[p].is_some() && pairs[q].is_some() && pairs[s].is_some() {
                        v += 8.0 * trace_product(&apq, &a[s], n);
                    }
                    for (x, y, z) in [(p, q, s), (p, s, q), (q, p, s), (q, s, p), (s, p, q), (s, q, p)] {
                        out[(x * r + y) * r + z] = v;
                    }
                }
            }
        }
        check_finite("third cumulant", &out)
            .map_err(|_| Error::NotNormalizable { reason: "the third cumulant overflows".into() })?;
        Ok(out)
    }

    /// The [standard rule](Gaussian::standard_rule) mapped to $N(m,\Sigma)$ of $\lambda$.
    fn quadrature(&self, lambda: &[f64]) -> Result<Rule, Error> {
        let (mean, cov) = self.mean_cov_from_natural(lambda)?;
        let nodes = self.nodes(&mean, &cov)?;
        let weights = nodes.iter().map(|(_, w)| *w).collect();
        let points = nodes.into_iter().flat_map(|(x, _)| x).collect();
        Rule::try_new(self.dim, points, weights)
    }

    /// $\mu$ is realizable iff $\Sigma_{ij} = \mu_{(ij)} - \mu_i\mu_j$ is positive definite.
    fn check_realizable(&self, mu: &[f64]) -> Result<(), Error> {
        self.mean_cov_from_moments(mu).map(|_| ())
    }

    /// Closed form: $\lambda(\mu)$ through $(m, \Sigma)$, no iterations
    /// (`003_d2fc48a470e528fc.txt (II.39)`); `options` are validated but otherwise unused.
    fn legendre(&self, mu: &[f64], options: &LegendreOptions) -> Result<LegendreSolution, Error> {
        options.validate()?;
        let (mean, cov) = self.mean_cov_from_moments(mu)?;
        let lambda = self
            .natural_from_mean_cov(&mean, &cov)
            .map_err(|_| Error::Unrealizable { reason: "the covariance is numerically singular".into() })?;
        let cum = self.cumulants(&lambda)?;
        let residual = max_abs(&mu.iter().zip(&cum.mean).map(|(a, b)| a - b).collect::<Vec<_>>());
        let l = cholesky(&cov, self.dim)?;
        let relative_entropy = self.entropy_from_logdet(cholesky_log_det(&l, self.dim)?);
        Ok(LegendreSolution { lambda, iterations: 0, residual, relative_entropy })
    }

    /// Closed form $H(\mu) = -\tfrac12\log\det(2\pi e\Sigma)$,
    /// `003_d2fc48a470e528fc.txt (II.39)` with Lebesgue reference.
    fn relative_entropy(&self, mu: &[f64]) -> Result<f64, Error> {
        let (_, cov) = self.mean_cov_from_moments(mu)?;
        let l = cholesky(&cov, self.dim)?;
        Ok(self.entropy_from_logdet(cholesky_log_det(&l, self.dim)?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// The one-state closed form equals the general form (Cholesky factors, Isserlis' products
    /// over the moment pairs) to round-off, also at entries of magnitude 10³, and `log_partition`
    /// equals `cumulants`' F; where P ≤ 0 or the covariance overflows, the general form reports
    /// the error.
    #[test]
    fn one_state_cumulants_equal_the_general_form() {
        let g = Gaussian::try_new(1).unwrap();
        for lambda in [[0.4 / 0.3, -0.5 / 0.3], [-25.0, -12.5], [1e3, -1e3], [0.0, -0.01]] {
            let (one, general) =
                (one_state_cumulants(&lambda).unwrap(), g.general_cumulants(&lambda).unwrap());
            assert_relative_eq!(
                one.log_partition,
                general.log_partition,
                epsilon = 1e-12,
                max_relative = 1e-12
            );
            for (a, b) in
                one.mean.iter().chain(&one.covariance).zip(general.mean.iter().chain(&general.covariance))
            {
                assert_relative_eq!(*a, *b, epsilon = 1e-12, max_relative = 1e-12);
            }
        }
        for lambda in [[0.4 / 0.3, -0.5 / 0.3], [1e3, -1e3]] {
            assert_eq!(g.log_partition(&lambda).unwrap(), g.cumulants(&lambda).unwrap().log_partition);
        }
        assert!(one_state_cumulants(&[1.0, 0.0]).is_none());
        assert!(g.cumulants(&[1.0, 0.5]).is_err());
        // v = 5·10¹⁹⁹: v² overflows, the closed form declines and the general form reports it.
        assert!(one_state_cumulants(&[0.0, -1e-200]).is_none());
        assert!(g.cumulants(&[0.0, -1e-200]).is_err());
    }
}
