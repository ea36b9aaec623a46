//! Quadrature rules: Gauss–Hermite, Gauss–Legendre (single and composite), tensor products, and
//! the spherical–radial cubature rules of degree 3 and 5 for the standard normal.
//!
//! Gauss rules are computed here, not tabulated: the nodes are the eigenvalues of the Jacobi
//! matrix of the three-term recurrence (Golub–Welsch), polished by Newton's method on the
//! orthonormal recurrence, and the weights are the Christoffel numbers
//! $w_i = 1 / \sum_{k<n} q_k(x_i)^2$ (for a probability weight function), which are accurate to
//! relative precision even where they are tiny. An $n$-point Gauss rule integrates polynomials up
//! to degree $2n-1$ exactly.

use crate::error::{check_finite, check_len, Error};

/// Largest number of Gauss–Hermite nodes: beyond it the orthonormal polynomials overflow at the
/// outermost nodes.
pub const MAX_GAUSS_HERMITE: usize = 200;
/// Largest number of nodes of a single Gauss–Legendre rule (use composite rules for more).
pub const MAX_GAUSS_LEGENDRE: usize = 256;

/// A quadrature rule in `dim` dimensions: points $x_k$ and weights $w_k$ with
/// $\int f d\nu \approx \sum_k w_k f(x_k)$ for the rule's measure $\nu$.
///
/// Points are stored row-major: point $k$ is `points()[k * dim..(k + 1) * dim]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Rule {
    dim: usize,
    points: Vec<f64>,
    weights: Vec<f64>,
}

impl Rule {
    /// A rule from its points (row-major, `weights.len() * dim` entries) and weights.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] if `dim == 0`, [`Error::DimensionMismatch`] if the lengths
    /// disagree, [`Error::NonFinite`] for non-finite points or weights.
    pub fn try_new(dim: usize, points: Vec<f64>, weights: Vec<f64>) -> Result<Self, Error> {
        if dim == 0 {
            return Err(Error::InvalidOption {
                name: "dim",
                reason: "a rule needs at least one dimension".into(),
            });
        }
        check_len("points", &points, weights.len() * dim)?;
        check_finite("points", &points)?;
        check_finite("weights", &weights)?;
        Ok(Self { dim, points, weights })
    }

    /// Dimension of the points.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.weights.len()
    }

    /// Whether the rule has no points.
    pub fn is_empty(&self) -> bool {
        self.weights.is_empty()
    }

    /// All points, row-major (`len() * dim()` entries).
    pub fn points(&self) -> &[f64] {
        &self.points
    }

    /// All weights.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// Point `k`, or `None` if `k >= len()`.
    pub fn point(&self, k: usize) -> Option<&[f64]> {
        self.points.get(k * self.dim..(k + 1) * self.dim)
    }

    /// Iterator over `(point, weight)` pairs.
    pub fn iter(&self) -> impl Iterator<Item = (&[f64], f64)> + '_ {
        self.points.chunks_exact(self.dim).zip(self.weights.iter().copied())
    }

    /// $\sum_k w_k f(x_k)$.
    pub fn integrate(&self, mut f: impl FnMut(&[f64]) -> f64) -> f64 {
        self.iter().map(|(x, w)| w * f(x)).sum()
    }

    /// The one-dimensional rule mapped affinely from $[-1, 1]$ to $[a, b]$: points
    /// $\tfrac{a+b}{2} + \tfrac{b-a}{2}x_k$, weights scaled by $\tfrac{b-a}{2}$.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] if the rule is not one-dimensional or the interval is empty or
    /// not finite.
    pub fn mapped_to_interval(&self, lower: f64, upper: f64) -> Result<Self, Error> {
        check_interval(lower, upper)?;
        if self.dim != 1 {
            return Err(Error::InvalidOption {
                name: "dim",
                reason: "only one-dimensional rules can be mapped to an interval".into(),
            });
        }
        let c = 0.5 * (lower + upper);
        let h = 0.5 * (upper - lower);
        Ok(Self {
            dim: 1,
            points: self.points.iter().map(|x| c + h * x).collect(),
            weights: self.weights.iter().map(|w| h * w).collect(),
        })
    }
}

fn check_interval(lower: f64, upper: f64) -> Result<(), Error> {
    if lower.is_finite() && upper.is_finite() && lower < upper {
        Ok(())
    } else {
        Err(Error::InvalidOption {
            name: "interval",
            reason: format!("need finite lower < upper, got [{lower}, {upper}]"),
        })
    }
}

/// Gauss rule of `n` nodes for a symmetric probability measure with orthonormal recurrence
/// $\beta_{k+1} q_{k+1}(x) = x q_k(x) - \beta_k q_{k-1}(x)$, $q_0 = 1$ (Golub–Welsch plus Newton
/// polishing). `beta[k-1]` $=\beta_k$ for $k = 1..n-1$. Weights sum to one.
fn symmetric_gauss(n: usize, beta: &[f64]) -> Vec<(f64, f64)> {
    debug_assert_eq!(beta.len() + 1, n);
    // Golub–Welsch: eigenvalues of the symmetric tridiagonal Jacobi matrix.
    let jacobi = nalgebra::DMatrix::<f64>::from_fn(n, n, |i, j| {
        if i + 1 == j {
            beta[i]
        } else if j + 1 == i {
            beta[j]
        } else {
            0.0
        }
    });
    let mut x: Vec<f64> = jacobi.symmetric_eigenvalues().iter().copied().collect();
    x.sort_by(f64::total_cmp);
    // Evaluates (q_n-proportional) p(x) = x q_{n-1} - β_{n-1} q_{n-2}, its derivative, and
    // Σ_{k<n} q_k².
    let eval = |t: f64| -> (f64, f64, f64) {
        let (mut q_prev, mut q) = (0.0, 1.0);
        let (mut d_prev, mut d) = (0.0, 0.0);
        let mut sum_sq = 1.0;
        for k in 0..n {
            // p_{k+1} = t q_k - β_k q_{k-1}; normalised by β_{k+1} except at the last step.
            let b_k = if k == 0 { 0.0 } else { beta[k - 1] };
            let p = t * q - b_k * q_prev;
            let dp = q + t * d - b_k * d_prev;
            if k + 1 == n {
                return (p, dp, sum_sq);
            }
            let b_next = beta[k];
            q_prev = q;
            d_prev = d;
            q = p / b_next;
            d = dp / b_next;
            sum_sq += q * q;
        }
        unreachable!("the loop returns at k = n - 1")
    };
    for xi in x.iter_mut() {
        for _ in 0..4 {
            let (p, dp, _) = eval(*xi);
            if dp == 0.0 {
                break;
            }
            let step = p / dp;
            *xi -= step;
            if step.abs() <= 1e-16 * xi.abs().max(1.0) {
                break;
            }
        }
    }
    // Exact symmetry of the nodes about zero.
    for i in 0..n / 2 {
        let s = 0.5 * (x[n - 1 - i] - x[i]);
        x[i] = -s;
        x[n - 1 - i] = s;
    }
    if n % 2 == 1 {
        x[n / 2] = 0.0;
    }
    x.into_iter().map(|t| (t, 1.0 / eval(t).2)).collect()
}

/// Gauss–Hermite rule of `n` points for the **standard normal** measure (probabilists' Hermite
/// polynomials): $\int f(x) \frac{e^{-x^2/2}}{\sqrt{2\pi}}dx \approx \sum_k w_k f(x_k)$, exact
/// for polynomials of degree $\le 2n-1$; the weights sum to one.
///
/// Recurrence $He_{k+1} = x He_k - k He_{k-1}$, i.e. $\beta_k = \sqrt k$.
///
/// # Errors
/// [`Error::InvalidOption`] unless $1 \le n \le$ [`MAX_GAUSS_HERMITE`].
pub fn gauss_hermite(n: usize) -> Result<Rule, Error> {
    if n == 0 || n > MAX_GAUSS_HERMITE {
        return Err(Error::InvalidOption {
            name: "n",
            reason: format!("Gauss–Hermite needs 1 <= n <= {MAX_GAUSS_HERMITE}, got {n}"),
        });
    }
    let beta: Vec<f64> = (1..n).map(|k| (k as f64).sqrt()).collect();
    let (points, weights) = symmetric_gauss(n, &beta).into_iter().unzip();
    Rule::try_new(1, points, weights)
}

/// Gauss–Legendre rule of `n` points on $[-1, 1]$ with Lebesgue measure:
/// $\int_{-1}^{1} f(x) dx \approx \sum_k w_k f(x_k)$, exact for polynomials of degree
/// $\le 2n-1$; the weights sum to two.
///
/// Recurrence $(k+1)P_{k+1} = (2k+1)xP_k - kP_{k-1}$, i.e. $\beta_k = k/\sqrt{4k^2-1}$.
///
/// # Errors
/// [`Error::InvalidOption`] unless $1 \le n \le$ [`MAX_GAUSS_LEGENDRE`].
pub fn gauss_legendre(n: usize) -> Result<Rule, Error> {
    if n == 0 || n > MAX_GAUSS_LEGENDRE {
        return Err(Error::InvalidOption {
            name: "n",
            reason: format!("Gauss–Legendre needs 1 <= n <= {MAX_GAUSS_LEGENDRE}, got {n}"),
        });
    }
    let beta: Vec<f64> = (1..n)
        .map(|k| {
            let k = k as f64;
            k / (4.0 * k * k - 1.0).sqrt()
        })
        .collect();
    let (points, weights): (Vec<f64>, Vec<f64>) = symmetric_gauss(n, &beta).into_iter().unzip();
    Rule::try_new(1, points, weights.into_iter().map(|w| 2.0 * w).collect())
}

/// Composite Gauss–Legendre rule on $[a, b]$: `panels` equal panels with `points_per_panel`
/// Gauss–Legendre points each.
///
/// For $f \in C^{2q}$ with $q$ points per panel of width $h = (b-a)/P$ the error is at most
/// $\frac{(b-a) h^{2q}(q!)^4}{(2q+1)[(2q)!]^3}\max|f^{(2q)}|$ (the Gauss–Legendre remainder summed
/// over panels); for $q = 8$ and $h$ no larger than the length scale of $f$ this is below
/// $10^{-12}$ relative.
///
/// # Errors
/// [`Error::InvalidOption`] for an empty or infinite interval, zero panels, or an invalid
/// `points_per_panel` (see [`gauss_legendre`]).
pub fn composite_gauss_legendre(
    lower: f64,
    upper: f64,
    panels: usize,
    points_per_panel: usize,
) -> Result<Rule, Error> {
    check_interval(lower, upper)?;
    if panels == 0 {
        return Err(Error::InvalidOption { name: "panels", reason: "need at least one panel".into() });
    }
    let base = gauss_legendre(points_per_panel)?;
    let h = (upper - lower) / panels as f64;
    let mut points = Vec::with_capacity(panels * points_per_panel);
    let mut weights = Vec::with_capacity(panels * points_per_panel);
    for p in 0..panels {
        let a = lower + h * p as f64;
        let b = if p + 1 == panels { upper } else { a + h };
        let r = base.mapped_to_interval(a, b)?;
        points.extend_from_slice(r.points());
        weights.extend_from_slice(r.weights());
    }
    Rule::try_new(1, points, weights)
}

/// Tensor product of rules: points are concatenations $(x^{(1)}_{k_1}, \dots, x^{(m)}_{k_m})$ and
/// weights products $w^{(1)}_{k_1}\cdots w^{(m)}_{k_m}$; the last factor varies fastest. The
/// product of rules exact to degree $d_i$ in each factor integrates every monomial
/// $\prod_i x_i^{a_i}$ with $a_i \le d_i$ exactly.
///
/// # Errors
/// [`Error::InvalidOption`] if `factors` is empty.
pub fn tensor_product(factors: &[Rule]) -> Result<Rule, Error> {
    let Some(first) = factors.first() else {
        return Err(Error::InvalidOption {
            name: "factors",
            reason: "a tensor product needs at least one factor".into(),
        });
    };
    let mut out = first.clone();
    for f in &factors[1..] {
        let dim = out.dim + f.dim;
        let mut points = Vec::with_capacity(out.len() * f.len() * dim);
        let mut weights = Vec::with_capacity(out.len() * f.len());
        for (x, w) in out.iter() {
            for (y, v) in f.iter() {
                points.extend_from_slice(x);
                points.extend_from_slice(y);
                weights.push(w * v);
            }
        }
        out = Rule::try_new(dim, points, weights)?;
    }
    Ok(out)
}

/// Tensor-product Gauss–Hermite rule for the standard normal $N(0, I_{dim})$ with `n` points per
/// dimension ($n^{dim}$ points, exact for $\prod_i x_i^{a_i}$ with every $a_i \le 2n-1$).
///
/// # Errors
/// As [`gauss_hermite`]; [`Error::InvalidOption`] if `dim == 0` or $n^{dim}$ exceeds $10^7$.
pub fn gauss_hermite_tensor(dim: usize, n: usize) -> Result<Rule, Error> {
    if dim == 0 {
        return Err(Error::InvalidOption { name: "dim", reason: "need dim >= 1".into() });
    }
    let total = (n as f64).powi(dim as i32);
    if total > 1e7 {
        return Err(Error::InvalidOption {
            name: "n",
            reason: format!("{n}^{dim} points is too many for a tensor rule"),
        });
    }
    let r = gauss_hermite(n)?;
    tensor_product(&vec![r; dim])
}

/// Third-degree spherical–radial cubature for $N(0, I_n)$ (the cubature Kalman filter rule):
/// $2n$ points $\pm\sqrt n e_i$ with weights $1/(2n)$; exact for all polynomials of total
/// degree $\le 3$.
///
/// # Errors
/// [`Error::InvalidOption`] if `dim == 0`.
pub fn cubature3(dim: usize) -> Result<Rule, Error> {
    if dim == 0 {
        return Err(Error::InvalidOption { name: "dim", reason: "need dim >= 1".into() });
    }
    let r = (dim as f64).sqrt();
    let mut points = Vec::with_capacity(2 * dim * dim);
    for i in 0..dim {
        for s in [1.0, -1.0] {
            let mut p = vec![0.0; dim];
            p[i] = s * r;
            points.extend(p);
        }
    }
    Rule::try_new(dim, points, vec![1.0 / (2 * dim) as f64; 2 * dim])
}

/// Fifth-degree cubature for $N(0, I_n)$ (Stroud's rule, as used by the fifth-degree cubature
/// Kalman filter), $2n^2+1$ points:
/// the origin with weight $\frac{2}{n+2}$; $\pm\sqrt{n+2} e_i$ with weight
/// $\frac{4-n}{2(n+2)^2}$; $\pm\sqrt{(n+2)/2} (e_i \pm e_j)$, $i<j$, with weight
/// $\frac{1}{(n+2)^2}$. Exact for all polynomials of total degree $\le 5$. The axis weights are
/// negative for $n > 4$.
///
/// # Errors
/// [`Error::InvalidOption`] if `dim == 0`.
pub fn cubature5(dim: usize) -> Result<Rule, Error> {
    if dim == 0 {
        return Err(Error::InvalidOption { name: "dim", reason: "need dim >= 1".into() });
    }
    let n = dim as f64;
    let mut points = vec![0.0; dim];
    let mut weights = vec![2.0 / (n + 2.0)];
    let r_axis = (n + 2.0).sqrt();
    let w_axis = (4.0 - n) / (2.0 * (n + 2.0) * (n + 2.0));
    for i in 0..dim {
        for s in [1.0, -1.0] {
            let mut p = vec![0.0; dim];
            p[i] = s * r_axis;
            points.extend(p);
            weights.push(w_axis);
        }
    }
    let r_pair = ((n + 2.0) / 2.0).sqrt();
    let w_pair = 1.0 / ((n + 2.0) * (n + 2.0));
    for i in 0..dim {
        for j in (i + 1)..dim {
            for si in [1.0, -1.0] {
                for sj in [1.0, -1.0] {
                    let mut p = vec![0.0; dim];
                    p[i] = si * r_pair;
                    p[j] = sj * r_pair;
                    points.extend(p);
                    weights.push(w_pair);
                }
            }
        }
    }
    Rule::try_new(dim, points, weights)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// E[x^k] under N(0, 1): (k-1)!! for even k, 0 for odd k (closed form).
    fn normal_moment(k: u32) -> f64 {
        if k % 2 == 1 {
            0.0
        } else {
            (1..k).step_by(2).map(|j| j as f64).product()
        }
    }

    #[test]
    fn gauss_hermite_exactness_degree_is_2n_minus_1() {
        for n in 1..=20usize {
            let r = gauss_hermite(n).unwrap();
            for k in 0..=(2 * n - 1) as u32 {
                let q = r.integrate(|x| x[0].powi(k as i32));
                let exact = normal_moment(k);
                // Round-off scale of the sum: Σ w |x|^k (odd moments cancel to this level).
                let scale = r.integrate(|x| x[0].abs().powi(k as i32));
                assert_relative_eq!(q, exact, epsilon = 1e-14 * scale, max_relative = 1e-12);
            }
            // Degree 2n is not integrated exactly: the error is E[He_n²]·(leading coeff) = n!.
            let k = 2 * n as i32;
            let q = r.integrate(|x| x[0].powi(k));
            let err = normal_moment(2 * n as u32) - q;
            let n_fact: f64 = (1..=n).map(|j| j as f64).product();
            assert_relative_eq!(err, n_fact, max_relative = 1e-9);
        }
    }

    #[test]
    fn gauss_hermite_large_n_weights_are_positive_and_sum_to_one() {
        let r = gauss_hermite(MAX_GAUSS_HERMITE).unwrap();
        assert!(r.weights().iter().all(|&w| w > 0.0));
        // Identity: Σ w = E[1] = 1.
        assert_relative_eq!(r.weights().iter().sum::<f64>(), 1.0, epsilon = 1e-13);
        // E[x²] = 1 and E[x⁴] = 3 (closed forms).
        assert_relative_eq!(r.integrate(|x| x[0] * x[0]), 1.0, max_relative = 1e-12);
        assert_relative_eq!(r.integrate(|x| x[0].powi(4)), 3.0, max_relative = 1e-12);
    }

    #[test]
    fn gauss_legendre_exactness_degree_is_2n_minus_1() {
        for n in [1usize, 2, 3, 5, 8, 16, 40, MAX_GAUSS_LEGENDRE] {
            let r = gauss_legendre(n).unwrap();
            let max_k = (2 * n - 1).min(60);
            for k in 0..=max_k as i32 {
                let q = r.integrate(|x| x[0].powi(k));
                // ∫_{-1}^{1} x^k dx = 2/(k+1) for even k, 0 for odd k (closed form).
                let exact = if k % 2 == 0 { 2.0 / (k + 1) as f64 } else { 0.0 };
                assert_relative_eq!(q, exact, epsilon = 1e-14, max_relative = 1e-13);
            }
            if n <= 8 {
                // Degree 2n is not exact: the Gauss remainder for x^{2n} is ∫ π_n² with π_n the
                // monic Legendre polynomial, = 2^{2n+1} (n!)^4 / ((2n+1) ((2n)!)^2).
                let k = 2 * n as i32;
                let q = r.integrate(|x| x[0].powi(k));
                let fact = |m: usize| (1..=m).map(|j| j as f64).product::<f64>();
                let remainder = 2f64.powi(k + 1) * fact(n).powi(4) / ((k + 1) as f64 * fact(2 * n).powi(2));
                assert_relative_eq!(2.0 / (k + 1) as f64 - q, remainder, max_relative = 1e-6);
            }
        }
    }

    #[test]
    fn composite_legendre_integrates_a_gaussian() {
        // ∫_{-12}^{12} exp(-x²/2) dx = √(2π) up to a tail of 2·φ(12)/12 < 1e-32 (closed form).
        let r = composite_gauss_legendre(-12.0, 12.0, 24, 8).unwrap();
        let q = r.integrate(|x| (-0.5 * x[0] * x[0]).exp());
        assert_relative_eq!(q, (2.0 * std::f64::consts::PI).sqrt(), max_relative = 1e-13);
    }

    #[test]
    fn tensor_product_exactness() {
        let r = tensor_product(&[gauss_legendre(3).unwrap(), gauss_legendre(4).unwrap()]).unwrap();
        assert_eq!((r.dim(), r.len()), (2, 12));
        for a in 0..=5 {
            for b in 0..=7 {
                let q = r.integrate(|x| x[0].powi(a) * x[1].powi(b));
                // ∫∫ x^a y^b over [-1,1]² factorises (closed form).
                let f = |k: i32| if k % 2 == 0 { 2.0 / (k + 1) as f64 } else { 0.0 };
                assert_relative_eq!(q, f(a) * f(b), epsilon = 1e-14, max_relative = 1e-13);
            }
        }
    }

    /// All exponent vectors of length `dim` with total degree ≤ `deg`.
    fn multi_indices(dim: usize, deg: u32) -> Vec<Vec<u32>> {
        if dim == 0 {
            return vec![vec![]];
        }
        let mut out = Vec::new();
        for a in 0..=deg {
            for mut rest in multi_indices(dim - 1, deg - a) {
                rest.insert(0, a);
                out.push(rest);
            }
        }
        out
    }

    fn check_normal_degree(r: &Rule, deg: u32) {
        for idx in multi_indices(r.dim(), deg) {
            let q = r.integrate(|x| x.iter().zip(&idx).map(|(v, &a)| v.powi(a as i32)).product());
            // Isserlis: E[Π x_i^{a_i}] = Π E[x^{a_i}] for independent N(0,1) coordinates.
            let exact: f64 = idx.iter().map(|&a| normal_moment(a)).product();
            assert_relative_eq!(q, exact, epsilon = 1e-12, max_relative = 1e-12);
        }
    }

    #[test]
    fn cubature_rules_exactness_degree() {
        for dim in [1usize, 2, 3, 6] {
            check_normal_degree(&cubature3(dim).unwrap(), 3);
            check_normal_degree(&cubature5(dim).unwrap(), 5);
            assert_eq!(cubature5(dim).unwrap().len(), 2 * dim * dim + 1);
        }
        // Degree 4 is beyond cubature3 (E[x⁴] = 3 but the rule gives n for dim n = 2).
        let q = cubature3(2).unwrap().integrate(|x| x[0].powi(4));
        assert_relative_eq!(q, 2.0, max_relative = 1e-14);
        // cubature5 in 1-D is the 3-point Gauss–Hermite rule (identity).
        let (c, g) = (cubature5(1).unwrap(), gauss_hermite(3).unwrap());
        let mut pts: Vec<(f64, f64)> = c.iter().map(|(x, w)| (x[0], w)).collect();
        pts.sort_by(|a, b| a.0.total_cmp(&b.0));
        for ((x, w), (y, v)) in pts.iter().zip(g.iter()) {
            assert_relative_eq!(*x, y[0], epsilon = 1e-14);
            assert_relative_eq!(*w, v, epsilon = 1e-14);
        }
    }

    #[test]
    fn tensor_gauss_hermite_exactness() {
        check_normal_degree(&gauss_hermite_tensor(3, 3).unwrap(), 5);
    }

    #[test]
    fn invalid_rules_are_errors() {
        assert!(gauss_hermite(0).is_err());
        assert!(gauss_hermite(MAX_GAUSS_HERMITE + 1).is_err());
        assert!(gauss_legendre(0).is_err());
        assert!(composite_gauss_legendre(1.0, 1.0, 3, 4).is_err());
        assert!(composite_gauss_legendre(0.0, f64::INFINITY, 3, 4).is_err());
        assert!(composite_gauss_legendre(0.0, 1.0, 0, 4).is_err());
        assert!(tensor_product(&[]).is_err());
        assert!(cubature3(0).is_err());
        assert!(gauss_hermite_tensor(8, 20).is_err());
        assert!(Rule::try_new(2, vec![0.0; 3], vec![1.0; 2]).is_err());
        assert!(Rule::try_new(1, vec![f64::NAN], vec![1.0]).is_err());
    }
}
