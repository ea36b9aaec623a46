//! The node sums of a polynomial exponential closure on a tensor grid, by raw moments
//! ([`TensorPlan`]): the fast path of [`super::ExponentialDrift`] on a fixed box and on the frame
//! x = m + Lξ of nodes that follow the density (whose grid is a tensor grid in ξ).
//!
//! With M the monomials x^α of total degree 1 to d and constant diffusion D, every node sum
//! of W, ∂W/∂λ and ∇²(κᵀW) (`003_d2fc48a470e528fc.txt (II.3)`, `(II.43)`) is a linear
//! combination of the moments Σπ_k ξ_k^α and the drift-weighted moments Σπ_k f_i(x_k) ξ_k^α of
//! a centred and scaled coordinate ξ = (x − c)/s. On a tensor grid each of those tables is one
//! contraction per axis, the last first: in 2-D two small matrix products
//! (Σ_p ξ_p^α Σ_q π_pq ξ_q^β), so one evaluation costs a few times K·(4d + 1) multiply-adds for
//! K nodes instead of K·R² for the R moments (2-D and 3-D).
//!
//! The sums are formed in the basis Ξ = (ξ^β) of the same exponents, M(x) = AΞ(ξ) + b with A
//! lower triangular (binomial expansion of (c + sξ)^α), and carried back exactly:
//! C = AC̃Aᵀ, V = AṼ, W = A⁻ᵀW̃, ∂W/∂λ = A⁻ᵀ(∂W̃/∂λ̃)Aᵀ, ∇²(κᵀW) = A∇²(κ̃ᵀW̃)Aᵀ with
//! λ̃ = Aᵀλ and κ̃ = A⁻¹κ. Centring at the density's mean and scaling by its standard deviation
//! keeps the raw moments of degree up to 4d near 1 where the density lives.

use super::exponential::{covariance_failure, SpdFactor};
use super::Unrealizable;
use nalgebra::{DMatrixView, DMatrixViewMut};
use onsager_closures::{dot, Exponential, TrialFamily};

/// The dimensions a [`TensorPlan`] handles.
const DIMENSIONS: std::ops::RangeInclusive<usize> = 2..=3;

/// A tensor grid in two or three dimensions (the last axis runs fastest: in 2-D node k is
/// (axes₀[k / K₁], axes₁[k mod K₁])) carrying the complete polynomial family of degree d, its
/// exponents sorted by total degree.
#[derive(Debug, Clone)]
pub(super) struct TensorPlan {
    axes: Vec<Vec<f64>>,
    degree: usize,
    exponents: Vec<Vec<usize>>,
    /// Per axis, the powers x^0, …, x^d of its points, power-major (row j holds x^j).
    powers: Vec<Vec<f64>>,
    /// For nodes x = m + Lξ that follow the density, the frame: the axes are those of ξ.
    frame: Option<Affine>,
}

/// The frame x = m + Lξ (L lower triangular, row-major) of a [`TensorPlan`] on the axes of ξ,
/// with the expansion of the family's monomials in those of ξ: M(x) = BΞ(ξ) + M(m), B lower
/// triangular for exponents sorted by degree, then lexicographically descending (x_i holds
/// ξ_1, …, ξ_i only, so a power ξ^β of x^α of the same degree moves exponent to earlier axes:
/// β is lexicographically no smaller than α, and comes no later; in 2-D, ξ₁^p ξ₂^q of x₁^a x₂^b
/// has p ≥ a).
#[derive(Debug, Clone)]
struct Affine {
    mean: Vec<f64>,
    chol: Vec<f64>,
    /// L⁻¹ (row-major, lower triangular).
    inverse: Vec<f64>,
    /// B (row-major R × R).
    b: Vec<f64>,
    /// M(m).
    at_mean: Vec<f64>,
}

/// What an evaluation returns besides W: nothing, ∂W/∂λ, or ∂W/∂λ and ∇²(κᵀW).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub(super) enum Order {
    W,
    Jacobian,
    Hessian,
}

/// The buffers of one evaluation on a [`TensorPlan`], reused.
#[derive(Debug, Default)]
pub(super) struct TensorWork {
    centre: Vec<f64>,
    scale: Vec<f64>,
    powers: Vec<Vec<f64>>,
    rows: Vec<f64>,
    /// The moment table (block 0) and the n drift-weighted tables (blocks 1..=n), each (b)ⁿ.
    sums: Vec<f64>,
    mu: Vec<f64>,
    at: Vec<usize>,
    generator: Vec<Vec<Term>>,
    c: SpdFactor,
    cov: Vec<f64>,
    v: Vec<f64>,
    w: Vec<f64>,
    jac: Vec<f64>,
    dense: Vec<f64>,
    a: Vec<f64>,
    scratch: [Vec<f64>; 2],
    /// L⁻¹(π f) in a frame.
    frame_drift: Vec<f64>,
}

/// The node values an evaluation on a [`TensorPlan`] sums: the node probabilities `p`, the
/// drift-weighted probabilities `pf` (π_k f_i(x_k), state-major, 0 where π_k = 0), the diffusion
/// (row-major n × n) and κ of ∇²(κᵀW) (empty unless [`Order::Hessian`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct NodeValues<'a> {
    pub(super) p: &'a [f64],
    pub(super) pf: &'a [f64],
    pub(super) diffusion: &'a [f64],
    pub(super) kappa: &'a [f64],
}

/// One term c·(table entry at `at` + shift) of an expectation E[q ξ^γ].
#[derive(Debug, Clone, Copy)]
struct Term {
    at: usize,
    coef: f64,
}

impl TensorPlan {
    /// The plan of `family`, if its nodes are a tensor grid in two or three dimensions and its
    /// moments are all monomials of total degree 1 to d, sorted by degree. (In one dimension the
    /// node sums cost R²K with K ≈ 100 nodes, no more than the tables would.)
    pub(super) fn of(family: &Exponential) -> Option<TensorPlan> {
        if !DIMENSIONS.contains(&family.dim()) {
            return None;
        }
        let axes = tensor_axes(family.grid().points(), family.dim())?;
        if axes.iter().map(Vec::len).product::<usize>() != family.grid().len() {
            return None;
        }
        Self::on_axes(family.exponents()?, axes)
    }

    /// The plan of the polynomial family of `exponents` on nodes x = m + Lξ that follow the
    /// density, ξ on the tensor grid of `axis` in each dimension
    /// ([`onsager_closures::frame_grid`]: `mean` = m, `chol` = L row-major lower triangular),
    /// if they are all the exponents of total degree 1 to d in two or three states, sorted by
    /// degree and lexicographically descending within a degree (B is then lower triangular;
    /// checked).
    pub(super) fn in_frame(
        exponents: &[Vec<u32>],
        axis: &[f64],
        mean: &[f64],
        chol: &[f64],
    ) -> Option<TensorPlan> {
        let n = mean.len();
        if chol.len() != n * n {
            return None;
        }
        let mut plan = Self::on_axes(exponents, vec![axis.to_vec(); n])?;
        let (b, at_mean) = monomial_map(&plan.exponents, mean, chol);
        let r = plan.exponents.len();
        if (0..r).any(|a| (a + 1..r).any(|col| b[a * r + col] != 0.0)) {
            return None;
        }
        let mut inverse = vec![0.0; n * n];
        for j in 0..n {
            let mut col: Vec<f64> = (0..n).map(|i| if i == j { 1.0 } else { 0.0 }).collect();
            solve_lower(chol, n, &mut col);
            (0..n).for_each(|i| inverse[i * n + j] = col[i]);
        }
        plan.frame = Some(Affine { mean: mean.to_vec(), chol: chol.to_vec(), inverse, b, at_mean });
        Some(plan)
    }

    fn on_axes(exponents: &[Vec<u32>], axes: Vec<Vec<f64>>) -> Option<TensorPlan> {
        let n = axes.len();
        if !DIMENSIONS.contains(&n) || axes.iter().any(Vec::is_empty) {
            return None;
        }
        let exponents: Vec<Vec<usize>> =
            exponents.iter().map(|e| e.iter().map(|&x| x as usize).collect()).collect();
        let degree = exponents.iter().map(|e| e.iter().sum::<usize>()).max()?;
        let complete = monomial_count(n, degree);
        let sorted = exponents.windows(2).all(|w| w[0].iter().sum::<usize>() <= w[1].iter().sum::<usize>());
        let mut distinct = exponents.clone();
        distinct.sort();
        distinct.dedup();
        if exponents.len() != complete
            || distinct.len() != complete
            || !sorted
            || exponents.iter().any(|e| e.len() != n)
        {
            return None;
        }
        let powers = axes
            .iter()
            .map(|axis| (0..=degree).flat_map(|j| axis.iter().map(move |x| x.powi(j as i32))).collect())
            .collect();
        Some(TensorPlan { axes, degree, exponents, powers, frame: None })
    }

    /// λᵀM(x_k) at every node into `s` (resized to K), by the axis tables: with X_i the powers
    /// x^0, …, x^d of axis i's points and Λ the (d + 1)ⁿ tensor of λ by exponent (Λ_0 = 0; in
    /// a frame, Λ of Bᵀλ on the axes of ξ and Λ_0 = λᵀM(m)), Λ contracted with X₀, then X₁, …:
    /// in 2-D s = X₀ΛX₁ᵀ, d + 1 multiply-adds per node instead of R. The exponents of the
    /// family's density (`003_d2fc48a470e528fc.txt (II.36)`) without its base log-weights;
    /// `row` is scratch (the partly contracted tensors).
    pub(super) fn polynomial_into(&self, lambda: &[f64], row: &mut Vec<f64>, s: &mut Vec<f64>) {
        let d1 = self.degree + 1;
        let n = self.n();
        let mut by_exponent = vec![0.0; d1.pow(n as u32)];
        // In a frame, λᵀM(x) = (Bᵀλ)ᵀΞ(ξ) + λᵀM(m).
        let (lambda, constant) = match &self.frame {
            Some(f) => {
                let r = self.exponents.len();
                debug_assert_eq!(lambda.len(), r, "λ has one entry per moment");
                let bt: Vec<f64> =
                    (0..r).map(|col| (col..r).map(|a| f.b[a * r + col] * lambda[a]).sum()).collect();
                (std::borrow::Cow::Owned(bt), lambda.iter().zip(&f.at_mean).map(|(l, m)| l * m).sum())
            }
            None => (std::borrow::Cow::Borrowed(lambda), 0.0),
        };
        for (e, &l) in self.exponents.iter().zip(lambda.iter()) {
            by_exponent[table_index(e, d1)] = l;
        }
        by_exponent[0] = constant;
        s.clear();
        s.resize(self.len(), 0.0);
        // The tensors left after axes 0, 0 and 1, …: (d + 1)ⁿ⁻¹ + … + (d + 1) entries.
        row.clear();
        row.resize((1..n).map(|i| d1.pow((n - i) as u32)).sum(), 0.0);
        self.contract_polynomial(0, &by_exponent, row, s);
    }

    /// Adds Σ_γ coef_γ Π_{i ≥ axis} x_i^γ_i into `out`, the nodes of the axes from `axis` on
    /// (last fastest), for `coef` the (d + 1)^(n − axis) tensor of the exponents of those axes;
    /// `levels` holds the tensors of the later axes.
    fn contract_polynomial(&self, axis: usize, coef: &[f64], levels: &mut [f64], out: &mut [f64]) {
        let d1 = self.degree + 1;
        let (powers, len) = (&self.powers[axis], self.axes[axis].len());
        if axis + 1 == self.n() {
            for (j, &c) in coef.iter().enumerate() {
                for (v, &x) in out.iter_mut().zip(&powers[j * len..(j + 1) * len]) {
                    *v += c * x;
                }
            }
            return;
        }
        let rest = coef.len() / d1;
        let (next, deeper) = levels.split_at_mut(rest);
        for (k, chunk) in out.chunks_exact_mut(out.len() / len).enumerate() {
            // Λ's leading index contracted with the powers of this axis's point k.
            for (col, v) in next.iter_mut().enumerate() {
                *v = (0..d1).map(|a| powers[a * len + k] * coef[a * rest + col]).sum::<f64>();
            }
            let next: &[f64] = next;
            self.contract_polynomial(axis + 1, next, deeper, chunk);
        }
    }

    /// The mean and covariance (row-major) of the state under the node probabilities `p`: those
    /// of the axes' coordinates (the means by the axes' marginals, the covariance centred, by
    /// rows along the last axis: about 4 multiply-adds per node), and in a frame x = m + Lξ,
    /// m + Lμ_ξ and LΣ_ξLᵀ.
    pub(super) fn state_moments(&self, p: &[f64]) -> (Vec<f64>, Vec<f64>) {
        debug_assert_eq!(p.len(), self.len(), "one probability per node");
        let n = self.n();
        let mut marginal = Vec::new();
        let mu: Vec<f64> = (0..n)
            .map(|i| {
                self.marginal(p, i, &mut marginal);
                dot(&self.axes[i], &marginal)
            })
            .collect();
        let centred: Vec<Vec<f64>> =
            self.axes.iter().zip(&mu).map(|(axis, m)| axis.iter().map(|x| x - m).collect()).collect();
        // By rows along the last axis: per row, Σπ, Σπd and Σπd² of the last coordinate.
        let mut cov = vec![0.0; n * n];
        let (last, inner) = (&centred[n - 1], self.axes[n - 1].len());
        let mut index = vec![0; n - 1];
        let mut d = vec![0.0; n - 1];
        for row in p.chunks_exact(inner) {
            let (mut s0, mut s1, mut s2) = (0.0, 0.0, 0.0);
            for (&pk, &y) in row.iter().zip(last) {
                let py = pk * y;
                s0 += pk;
                s1 += py;
                s2 += py * y;
            }
            (0..n - 1).for_each(|i| d[i] = centred[i][index[i]]);
            for i in 0..n - 1 {
                (0..=i).for_each(|j| cov[i * n + j] += s0 * d[i] * d[j]);
                cov[(n - 1) * n + i] += d[i] * s1;
            }
            cov[n * n - 1] += s2;
            next_index(&mut index, &self.axes[..n - 1]);
        }
        mirror_lower(&mut cov, n);
        let Some(f) = &self.frame else { return (mu, cov) };
        // L lower triangular: (LΣLᵀ)_ij = Σ_{k ≤ i, l ≤ j} L_ik Σ_kl L_jl.
        let l = &f.chol;
        let mean = (0..n).map(|i| f.mean[i] + (0..=i).map(|j| l[i * n + j] * mu[j]).sum::<f64>()).collect();
        let entry = |i: usize, j: usize| -> f64 {
            (0..=i).map(|k| l[i * n + k] * (0..=j).map(|m| cov[k * n + m] * l[j * n + m]).sum::<f64>()).sum()
        };
        let mut out = vec![0.0; n * n];
        (0..n).for_each(|i| (0..=i).for_each(|j| out[i * n + j] = entry(i, j)));
        mirror_lower(&mut out, n);
        (mean, out)
    }

    /// The marginal of `p` on axis `i`'s points into `out`: K additions.
    fn marginal(&self, p: &[f64], i: usize, out: &mut Vec<f64>) {
        let len = self.axes[i].len();
        let stride: usize = self.axes[i + 1..].iter().map(Vec::len).product();
        out.clear();
        out.resize(len, 0.0);
        if stride == 1 {
            for row in p.chunks_exact(len) {
                out.iter_mut().zip(row).for_each(|(m, &pk)| *m += pk);
            }
            return;
        }
        for block in p.chunks_exact(len * stride) {
            for (m, run) in out.iter_mut().zip(block.chunks_exact(stride)) {
                *m += run.iter().sum::<f64>();
            }
        }
    }

    /// The family's moment count R.
    pub(super) fn n_moments(&self) -> usize {
        self.exponents.len()
    }

    fn n(&self) -> usize {
        self.axes.len()
    }

    /// The nodes' count K.
    pub(super) fn len(&self) -> usize {
        self.axes.iter().map(Vec::len).product()
    }

    /// W into `w`, and for [`Order::Jacobian`] ∂W/∂λ into `jac`, for [`Order::Hessian`] also
    /// ∇²(κᵀW) into `hess`, from the node `values`.
    ///
    /// In a frame x = m + Lξ the sums run in ξ, whose drift is L⁻¹f and diffusion L⁻¹DL⁻ᵀ, for
    /// the family of the monomials of ξ at λ̃ = Bᵀλ (the same density), and are carried back:
    /// W = B⁻ᵀW̃, ∂W/∂λ = B⁻ᵀ(∂W̃/∂λ̃)Bᵀ, ∇²(κᵀW) = B∇²(κ̃ᵀW̃)Bᵀ with κ̃ = B⁻¹κ.
    pub(super) fn evaluate(
        &self,
        order: Order,
        values: NodeValues,
        work: &mut TensorWork,
        out: (&mut [f64], &mut [f64], &mut [f64]),
    ) -> Result<(), Unrealizable> {
        let Some(frame) = &self.frame else {
            return self.evaluate_on_axes(order, values, work, out);
        };
        let NodeValues { p, pf, diffusion, kappa } = values;
        let (n, r, nodes) = (self.n(), self.exponents.len(), p.len());
        let inv = &frame.inverse;
        // L⁻¹(π f), state-major, and L⁻¹DL⁻ᵀ.
        let mut pf_xi = std::mem::take(&mut work.frame_drift);
        pf_xi.clear();
        pf_xi.resize(n * nodes, 0.0);
        for i in 0..n {
            for j in 0..=i {
                let c = inv[i * n + j];
                let (dst, src) = (i * nodes..(i + 1) * nodes, j * nodes..(j + 1) * nodes);
                pf_xi[dst].iter_mut().zip(&pf[src]).for_each(|(v, &u)| *v += c * u);
            }
        }
        let d_xi: Vec<f64> = (0..n * n)
            .map(|ij| {
                let (i, j) = (ij / n, ij % n);
                (0..n)
                    .map(|k| {
                        inv[i * n + k] * (0..n).map(|l| diffusion[k * n + l] * inv[j * n + l]).sum::<f64>()
                    })
                    .sum()
            })
            .collect();
        let mut kappa_xi = kappa.to_vec();
        if !kappa_xi.is_empty() {
            solve_lower(&frame.b, r, &mut kappa_xi);
        }
        let in_xi = NodeValues { p, pf: &pf_xi, diffusion: &d_xi, kappa: &kappa_xi };
        let result = self.evaluate_on_axes(order, in_xi, work, (&mut *out.0, &mut *out.1, &mut *out.2));
        work.frame_drift = pf_xi;
        result?;
        let (w, jac, hess) = out;
        let b = &frame.b;
        solve_upper_transposed(b, r, w);
        if order >= Order::Jacobian {
            // B⁻ᵀ J̃ Bᵀ: J̃Bᵀ, then B⁻ᵀ on its columns.
            let jb: Vec<f64> = (0..r * r)
                .map(|ij| {
                    let (i, j) = (ij / r, ij % r);
                    (0..=j).map(|k| jac[i * r + k] * b[j * r + k]).sum()
                })
                .collect();
            jac[..r * r].copy_from_slice(&jb);
            solve_upper_transposed(b, r, &mut jac[..r * r]);
        }
        if order == Order::Hessian {
            let h = hess[..r * r].to_vec();
            lower_congruence(b, r, |k, j| h[k * r + j], hess);
        }
        Ok(())
    }

    fn evaluate_on_axes(
        &self,
        order: Order,
        values: NodeValues,
        work: &mut TensorWork,
        out: (&mut [f64], &mut [f64], &mut [f64]),
    ) -> Result<(), Unrealizable> {
        let NodeValues { p, pf, diffusion, kappa } = values;
        let (w, jac, hess) = out;
        let r = self.exponents.len();
        let level = match order {
            Order::W => 2,
            Order::Jacobian => 3,
            Order::Hessian => 4,
        };
        let b = level * self.degree + 1;
        self.centre_and_scale(p, work);
        self.tables(p, b, Some((pf, (level - 1) * self.degree)), work);
        self.basis(b, diffusion, work);
        let TensorWork { sums, mu, at, c, cov, v, w: wt, generator, .. } = &mut *work;
        cov.clear();
        cov.extend((0..r * r).map(|aj| sums[at[aj / r] + at[aj % r]] - mu[aj / r] * mu[aj % r]));
        v.clear();
        v.extend(generator.iter().map(|g| expect(sums, g, 0)));
        if !v.iter().all(|x| x.is_finite()) {
            return Err(Unrealizable("the drift is not finite on the family's grid".into()));
        }
        c.factor(cov, r).map_err(|e| covariance_failure(e, p, r))?;
        wt.clear();
        wt.extend_from_slice(v);
        c.solve(wt);
        self.transform(work);
        let a = &work.a;
        w.copy_from_slice(&work.w);
        solve_upper_transposed(a, r, w);
        if order == Order::W {
            return Ok(());
        }
        self.jacobian(work);
        // ∂W/∂λ = A⁻ᵀ J̃ Aᵀ.
        let (jt, a) = (&work.jac, &work.a);
        for i in 0..r {
            for j in 0..r {
                jac[i * r + j] = (0..=j).map(|k| jt[i * r + k] * a[j * r + k]).sum();
            }
        }
        solve_upper_transposed(a, r, &mut jac[..r * r]);
        if order == Order::Hessian {
            self.hessian(kappa, work, hess);
        }
        Ok(())
    }

    /// The mean μ and covariance C (row-major R × R) of M under the node probabilities `p`
    /// (`003_d2fc48a470e528fc.txt (II.37)–(II.38)`) by the raw-moment table to degree 2d per
    /// axis: μ̃ and C̃ in the basis ξ^β, then μ = Aμ̃ + c^α and C = AC̃Aᵀ; about K·(2d + 1)
    /// multiply-adds instead of the node sums' K·R²/2.
    /// In a frame, μ = Bμ̃ + M(m) and C = BC̃Bᵀ from those of the monomials of ξ.
    pub(super) fn cumulants(&self, p: &[f64], work: &mut TensorWork) -> (Vec<f64>, Vec<f64>) {
        let (mean, cov) = self.cumulants_on_axes(p, work);
        let Some(frame) = &self.frame else { return (mean, cov) };
        let r = mean.len();
        let b = &frame.b;
        let mean =
            (0..r).map(|a| frame.at_mean[a] + (0..=a).map(|k| b[a * r + k] * mean[k]).sum::<f64>()).collect();
        let mut out = vec![0.0; r * r];
        lower_congruence(b, r, |k, j| cov[k * r + j], &mut out);
        mirror_lower(&mut out, r);
        (mean, out)
    }

    fn cumulants_on_axes(&self, p: &[f64], work: &mut TensorWork) -> (Vec<f64>, Vec<f64>) {
        let r = self.exponents.len();
        let b = 2 * self.degree + 1;
        self.centre_and_scale(p, work);
        self.tables(p, b, None, work);
        self.transform(work);
        let (centre, sums, a) = (&work.centre, &work.sums, &work.a);
        let at: Vec<usize> = self.exponents.iter().map(|e| table_index(e, b)).collect();
        let mu_t: Vec<f64> = at.iter().map(|&k| sums[k]).collect();
        let mean = (0..r)
            .map(|row| {
                let c_alpha: f64 =
                    self.exponents[row].iter().zip(centre).map(|(&e, c)| c.powi(e as i32)).product();
                c_alpha + (0..=row).map(|col| a[row * r + col] * mu_t[col]).sum::<f64>()
            })
            .collect();
        let mut cov = vec![0.0; r * r];
        lower_congruence(a, r, |k, j| sums[at[k] + at[j]] - mu_t[k] * mu_t[j], &mut cov);
        mirror_lower(&mut cov, r);
        (mean, cov)
    }

    /// The centre c (the density's mean) and scale s (its standard deviation, per axis), from
    /// the marginals of `p`.
    fn centre_and_scale(&self, p: &[f64], work: &mut TensorWork) {
        let TensorWork { centre, scale, scratch: [marginal, _], .. } = work;
        centre.clear();
        scale.clear();
        for (i, axis) in self.axes.iter().enumerate() {
            self.marginal(p, i, marginal);
            let m: f64 = axis.iter().zip(&*marginal).map(|(x, q)| q * x).sum();
            let var: f64 = axis.iter().zip(&*marginal).map(|(x, q)| q * (x - m).powi(2)).sum();
            let s = var.sqrt();
            centre.push(m);
            scale.push(if s.is_finite() && s > 0.0 { s } else { 1.0 });
        }
    }

    /// The table Σπ_k ξ_k^α (exponents < `b` per axis) and, with `drift` = (π_k f_i(x_k)
    /// state-major, bf), the tables Σπ_k f_i(x_k) ξ_k^α (exponents < bf), each laid out with
    /// stride `b`, into `work.sums`. Each table contracts the nodes' axes one at a time, the last
    /// first: one matrix product per axis (in 3-D, per point of the outer axes for the middle one).
    fn tables(&self, p: &[f64], b: usize, drift: Option<(&[f64], usize)>, work: &mut TensorWork) {
        debug_assert_eq!(p.len(), self.len(), "one probability per node");
        let n = self.n();
        let size = b.pow(n as u32);
        let nodes = self.len();
        let TensorWork { centre, scale, powers, rows, sums, scratch: [_, contracted], .. } = work;
        powers.resize_with(n, Vec::new);
        for (i, axis) in self.axes.iter().enumerate() {
            let table = &mut powers[i];
            table.clear();
            for &x in axis {
                let xi = (x - centre[i]) / scale[i];
                let mut v = 1.0;
                for _ in 0..b {
                    table.push(v);
                    v *= xi;
                }
            }
        }
        let blocks = 1 + drift.map_or(0, |_| n);
        sums.clear();
        sums.resize(blocks * size, 0.0);
        for block in 0..blocks {
            let (weights, count) = match drift {
                Some((pf, bf)) if block > 0 => (&pf[(block - 1) * nodes..block * nodes], bf),
                _ => (p, b),
            };
            self.contract_nodes(weights, count, b, powers, [rows, &mut *contracted]);
            // `rows` holds the table with stride `count` per axis: spread to stride `b`.
            let out = &mut sums[block * size..(block + 1) * size];
            for (k, &v) in rows.iter().enumerate() {
                let (mut at, mut rest, mut scale_b) = (0, k, 1);
                for _ in 0..n {
                    at += (rest % count) * scale_b;
                    rest /= count;
                    scale_b *= b;
                }
                out[at] = v;
            }
        }
    }

    /// Σ_k w_k Π_i ξ_{k,i}^γ_i for γ_i < `count` into `buffers[0]` (row-major, stride `count`),
    /// from the node weights `weights` and the axes' `powers` (stride `b`): the last axis by one
    /// product (K_last × count per row of the outer axes), then each axis before it.
    fn contract_nodes(
        &self,
        weights: &[f64],
        count: usize,
        b: usize,
        powers: &[Vec<f64>],
        buffers: [&mut Vec<f64>; 2],
    ) {
        let n = self.n();
        let [current, next] = buffers;
        // The last axis: current[q][γ] = Σ_k w_qk ξ_k^γ over the rows q of the outer axes, as
        // column-major views (a row-major matrix is its transpose).
        let inner = self.axes[n - 1].len();
        let outer = weights.len() / inner;
        current.clear();
        current.resize(outer * count, 0.0);
        let powers_inner = DMatrixView::from_slice_with_strides(&powers[n - 1], count, inner, 1, b);
        let w = DMatrixView::from_slice(weights, inner, outer);
        DMatrixViewMut::from_slice(current, count, outer).gemm(1.0, &powers_inner, &w, 0.0);
        // Axis i, with the axes after it done: for each row q of the axes before it,
        // next[q][γ_i][s] = Σ_k ξ_k^γ_i current[q][k][s], s the done axes' exponents.
        let mut done = count;
        for i in (0..n - 1).rev() {
            let len = self.axes[i].len();
            let prefixes = current.len() / (len * done);
            next.clear();
            next.resize(prefixes * count * done, 0.0);
            let powers_i = DMatrixView::from_slice_with_strides(&powers[i], len, count, b, 1);
            for (src, dst) in current.chunks_exact(len * done).zip(next.chunks_exact_mut(count * done)) {
                let src = DMatrixView::from_slice(src, done, len);
                DMatrixViewMut::from_slice(dst, done, count).gemm(1.0, &src, &powers_i, 0.0);
            }
            // The contents, so that `buffers[0]` ends holding the table.
            std::mem::swap(current, next);
            done *= count;
        }
    }

    /// The index of each basis exponent in a table of stride `b`, the means μ̃, and the
    /// generator L ξ^β = Σ_i f_i ∂_i ξ^β + D : ∇∇ξ^β of each as terms of the tables.
    fn basis(&self, b: usize, diffusion: &[f64], work: &mut TensorWork) {
        let n = self.n();
        let size = b.pow(n as u32);
        let index = |e: &[usize]| table_index(e, b);
        let TensorWork { scale, sums, mu, at, generator, .. } = work;
        at.clear();
        at.extend(self.exponents.iter().map(|e| index(e)));
        mu.clear();
        mu.extend(at.iter().map(|&k| sums[k]));
        generator.resize_with(self.exponents.len(), Vec::new);
        for (g, e) in generator.iter_mut().zip(&self.exponents) {
            g.clear();
            let mut lower = e.clone();
            for i in 0..n {
                if e[i] == 0 {
                    continue;
                }
                lower[i] -= 1;
                g.push(Term { at: (i + 1) * size + index(&lower), coef: e[i] as f64 / scale[i] });
                for j in 0..n {
                    let dij = diffusion[i * n + j];
                    if dij == 0.0 || lower[j] == 0 {
                        continue;
                    }
                    let factor = (e[i] * lower[j]) as f64 / (scale[i] * scale[j]);
                    lower[j] -= 1;
                    g.push(Term { at: index(&lower), coef: dij * factor });
                    lower[j] += 1;
                }
                lower[i] += 1;
            }
        }
    }

    /// A (row a: the coefficients of x^α_a in the basis ξ^β, without the constant), row-major.
    fn transform(&self, work: &mut TensorWork) {
        let r = self.exponents.len();
        let (c, s) = (&work.centre, &work.scale);
        work.a.clear();
        work.a.resize(r * r, 0.0);
        for (row, alpha) in self.exponents.iter().enumerate() {
            for (col, beta) in self.exponents.iter().enumerate().take(row + 1) {
                if beta.iter().zip(alpha).all(|(b, a)| b <= a) {
                    work.a[row * r + col] = alpha
                        .iter()
                        .zip(beta)
                        .enumerate()
                        .map(|(i, (&a, &b))| binomial(a, b) * c[i].powi((a - b) as i32) * s[i].powi(b as i32))
                        .product();
                }
            }
        }
    }

    /// J̃ = C̃⁻¹(⟨g̃ d̃ᵀ⟩ − ⟨(W̃·d̃) d̃d̃ᵀ⟩) into `work.jac` (`(II.43)` in the basis ξ).
    fn jacobian(&self, work: &mut TensorWork) {
        let r = self.exponents.len();
        let mut third = std::mem::take(&mut work.scratch[1]);
        let w_poly = linear_poly(&work.w, &work.at, &work.mu);
        expect_dd(&work.sums, &w_poly, &work.at, &work.mu, &mut third);
        let TensorWork { sums, mu, at, generator, v, c, jac, .. } = &mut *work;
        jac.clear();
        jac.resize(r * r, 0.0);
        for a in 0..r {
            for j in 0..r {
                jac[a * r + j] = expect(sums, &generator[a], at[j]) - v[a] * mu[j] - third[a * r + j];
            }
        }
        c.solve_rows(jac, r);
        work.scratch[1] = third;
    }

    /// ∇²(κᵀW) into `hess`: ∇²(κ̃ᵀW̃) by the formula of `ExponentialDrift::w_second` in the
    /// basis ξ, then A(·)Aᵀ.
    fn hessian(&self, kappa: &[f64], work: &mut TensorWork, hess: &mut [f64]) {
        let r = self.exponents.len();
        let mut kt = kappa.to_vec();
        solve_lower(&work.a, r, &mut kt);
        let mut u = kt.clone();
        work.c.solve(&mut u);
        // ψ = uᵀg̃ − (uᵀd̃)(W̃ᵀd̃) as terms; T's weight uᵀd̃.
        let ud = linear_poly(&u, &work.at, &work.mu);
        let wd = linear_poly(&work.w, &work.at, &work.mu);
        let mut psi: Vec<Term> = Vec::new();
        for (&ua, g) in u.iter().zip(&work.generator) {
            psi.extend(g.iter().map(|t| Term { at: t.at, coef: ua * t.coef }));
        }
        let dense = &mut work.dense;
        dense.clear();
        dense.resize(work.sums.len(), 0.0);
        for x in &ud {
            for y in &wd {
                dense[x.at + y.at] -= x.coef * y.coef;
            }
        }
        for t in &psi {
            dense[t.at] += t.coef;
        }
        let psi: Vec<Term> = dense
            .iter()
            .enumerate()
            .filter(|(_, &c)| c != 0.0)
            .map(|(at, &coef)| Term { at, coef })
            .collect();
        let mut h = vec![0.0; r * r];
        let mut t = vec![0.0; r * r];
        expect_dd(&work.sums, &psi, &work.at, &work.mu, &mut h);
        expect_dd(&work.sums, &ud, &work.at, &work.mu, &mut t);
        let jt = &work.jac;
        let tj: Vec<f64> =
            (0..r * r).map(|aj| (0..r).map(|b| t[(aj / r) * r + b] * jt[b * r + aj % r]).sum()).collect();
        for a in 0..r {
            for j in 0..r {
                h[a * r + j] += -tj[a * r + j] - tj[j * r + a] + kt[a] * work.v[j] + work.v[a] * kt[j];
            }
        }
        lower_congruence(&work.a, r, |k, j| h[k * r + j], hess);
    }
}

/// The expansion of the monomials x^α of `exponents` (sorted by degree, then lexicographically
/// descending) at x = m + Lξ in the monomials ξ^β of the same exponents:
/// (B row-major R × R, lower triangular, and the constants M(m)). With x_i = m_i + Σ_j L_ij ξ_j
/// as polynomials in ξ (coefficients by exponent, stride d + 1 per axis), each x^α is a product
/// of them.
fn monomial_map(exponents: &[Vec<usize>], mean: &[f64], chol: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let n = mean.len();
    let degree = exponents.iter().map(|e| e.iter().sum::<usize>()).max().unwrap_or(0);
    let stride = degree + 1;
    let size = stride.pow(n as u32);
    let unit = |i: usize| -> Vec<usize> { (0..n).map(|j| usize::from(i == j)).collect() };
    let index = |e: &[usize]| table_index(e, stride);
    // x_i as a polynomial in ξ.
    let linear: Vec<Vec<f64>> = (0..n)
        .map(|i| {
            let mut q = vec![0.0; size];
            q[0] = mean[i];
            for j in 0..=i {
                q[index(&unit(j))] += chol[i * n + j];
            }
            q
        })
        .collect();
    // The exponent of each table position, for products.
    let exponent_at = |mut k: usize| -> Vec<usize> {
        let mut e = vec![0; n];
        for i in (0..n).rev() {
            e[i] = k % stride;
            k /= stride;
        }
        e
    };
    let times = |q: &[f64], x: &[f64]| -> Vec<f64> {
        let mut out = vec![0.0; size];
        for (k, &qk) in q.iter().enumerate().filter(|(_, &v)| v != 0.0) {
            let ek = exponent_at(k);
            for (l, &xl) in x.iter().enumerate().filter(|(_, &v)| v != 0.0) {
                let sum: Vec<usize> = ek.iter().zip(exponent_at(l)).map(|(a, b)| a + b).collect();
                if sum.iter().sum::<usize>() <= degree {
                    out[index(&sum)] += qk * xl;
                }
            }
        }
        out
    };
    let r = exponents.len();
    let (mut b, mut constants) = (vec![0.0; r * r], vec![0.0; r]);
    for (row, alpha) in exponents.iter().enumerate() {
        let mut q = vec![0.0; size];
        q[0] = 1.0;
        for (i, &a) in alpha.iter().enumerate() {
            for _ in 0..a {
                q = times(&q, &linear[i]);
            }
        }
        constants[row] = q[0];
        for (col, beta) in exponents.iter().enumerate() {
            b[row * r + col] = q[index(beta)];
        }
    }
    (b, constants)
}

/// The position of the exponent `e` in a table of stride `b` per axis.
fn table_index(e: &[usize], b: usize) -> usize {
    e.iter().fold(0, |acc, &x| acc * b + x)
}

/// A X Aᵀ (row-major r × r) into `out`, for A lower triangular (row-major) and X by its entries
/// `x(k, j)`: first A X, then (A X) Aᵀ, each sum over the triangle of A.
fn lower_congruence(a: &[f64], r: usize, x: impl Fn(usize, usize) -> f64, out: &mut [f64]) {
    let ax: Vec<f64> =
        (0..r * r).map(|ij| (0..=ij / r).map(|k| a[(ij / r) * r + k] * x(k, ij % r)).sum()).collect();
    for i in 0..r {
        for j in 0..r {
            out[i * r + j] = (0..=j).map(|k| ax[i * r + k] * a[j * r + k]).sum();
        }
    }
}

/// The axes of a tensor grid of `points` (row-major, `n` per node) whose last axis runs
/// fastest, if it is one.
fn tensor_axes(points: &[f64], n: usize) -> Option<Vec<Vec<f64>>> {
    let nodes = points.len() / n;
    let at = |k: usize, i: usize| points[k * n + i];
    // Axis i runs over nodes 0, s, 2s, … (s the product of the later axes' lengths) while the
    // coordinates before it stay those of node 0.
    let mut axes = vec![Vec::new(); n];
    let mut stride = 1;
    for i in (0..n).rev() {
        let same_prefix = |k: usize| (0..i).all(|c| at(k, c) == at(0, c));
        axes[i] = (0..)
            .map(|j| j * stride)
            .take_while(|&k| k < nodes && same_prefix(k))
            .map(|k| at(k, i))
            .collect();
        stride *= axes[i].len();
    }
    if nodes == 0 || stride != nodes {
        return None;
    }
    let mut index = vec![0; n];
    for x in points.chunks_exact(n) {
        if (0..n).any(|i| x[i] != axes[i][index[i]]) {
            return None;
        }
        next_index(&mut index, &axes);
    }
    Some(axes)
}

/// The number of monomials of total degree 1 to `degree` in `n` variables: C(d + n, n) − 1.
pub(super) fn monomial_count(n: usize, degree: usize) -> usize {
    (1..=n).fold(1, |c, i| c * (degree + i) / i) - 1
}

/// The index on `axes` of the node after that of `index` in a tensor grid (the last axis
/// fastest; after the last node, the first).
fn next_index(index: &mut [usize], axes: &[Vec<f64>]) {
    for i in (0..index.len()).rev() {
        index[i] += 1;
        if index[i] < axes[i].len() {
            return;
        }
        index[i] = 0;
    }
}

/// The lower triangle of the row-major r × r matrix `m` mirrored into its upper triangle.
pub(super) fn mirror_lower(m: &mut [f64], r: usize) {
    for i in 0..r {
        for j in 0..i {
            m[j * r + i] = m[i * r + j];
        }
    }
}

/// E[q ξ^γ] for the terms `q` and the table index `shift` of γ.
fn expect(sums: &[f64], q: &[Term], shift: usize) -> f64 {
    q.iter().map(|t| t.coef * sums[t.at + shift]).sum()
}

/// E[q d̃_a d̃_j] for all a, j (symmetric, row-major) into `out`, d̃ = ξ^β − μ̃.
fn expect_dd(sums: &[f64], q: &[Term], at: &[usize], mu: &[f64], out: &mut Vec<f64>) {
    let r = at.len();
    out.clear();
    out.resize(r * r, 0.0);
    let e0 = expect(sums, q, 0);
    let e1: Vec<f64> = at.iter().map(|&k| expect(sums, q, k)).collect();
    for a in 0..r {
        for j in a..r {
            let v = expect(sums, q, at[a] + at[j]) - mu[j] * e1[a] - mu[a] * e1[j] + mu[a] * mu[j] * e0;
            out[a * r + j] = v;
            out[j * r + a] = v;
        }
    }
}

/// The terms of vᵀd̃ = Σ_a v_a(ξ^β_a − μ̃_a).
fn linear_poly(v: &[f64], at: &[usize], mu: &[f64]) -> Vec<Term> {
    let mut terms: Vec<Term> = v.iter().zip(at).map(|(&coef, &at)| Term { at, coef }).collect();
    terms.push(Term { at: 0, coef: -v.iter().zip(mu).map(|(a, b)| a * b).sum::<f64>() });
    terms
}

fn binomial(n: usize, k: usize) -> f64 {
    (0..k).fold(1.0, |acc, i| acc * (n - i) as f64 / (i + 1) as f64)
}

/// x = L⁻¹x for L lower triangular (row-major r × r).
pub(super) fn solve_lower(l: &[f64], r: usize, x: &mut [f64]) {
    for i in 0..r {
        let s: f64 = (0..i).map(|k| l[i * r + k] * x[k]).sum();
        x[i] = (x[i] - s) / l[i * r + i];
    }
}

/// X = L⁻ᵀX for L lower triangular (row-major r × r) and X row-major r × m, m = `x.len()` / r
/// (every column at once; a vector for m = 1).
fn solve_upper_transposed(l: &[f64], r: usize, x: &mut [f64]) {
    debug_assert_eq!(x.len() % r, 0, "x has whole rows");
    let m = x.len() / r;
    for i in (0..r).rev() {
        let (head, tail) = x.split_at_mut((i + 1) * m);
        let row = &mut head[i * m..];
        for k in i + 1..r {
            let c = l[k * r + i];
            row.iter_mut().zip(&tail[(k - i - 1) * m..(k - i) * m]).for_each(|(v, &u)| *v -= c * u);
        }
        let inv = l[i * r + i].recip();
        row.iter_mut().for_each(|v| *v *= inv);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// B Ξ(ξ) + M(m) = M(m + Lξ) for every monomial of the quartic and sextic families in two
    /// states, at points ξ spread over a box (an identity of polynomials; to round-off), and B is
    /// lower triangular.
    #[test]
    fn the_monomial_map_expands_the_monomials_at_m_plus_l_xi() {
        let (mean, chol) = ([0.7, -1.3], [0.9, 0.0, -0.4, 0.6]);
        for degree in [4u32, 6] {
            let exponents: Vec<Vec<usize>> = onsager_closures::Polynomial::try_new(2, degree)
                .unwrap()
                .exponents()
                .iter()
                .map(|e| e.iter().map(|&x| x as usize).collect())
                .collect();
            let (b, at_mean) = monomial_map(&exponents, &mean, &chol);
            let r = exponents.len();
            let power =
                |x: &[f64], e: &[usize]| x.iter().zip(e).map(|(v, &p)| v.powi(p as i32)).product::<f64>();
            for a in 0..r {
                assert!((a + 1..r).all(|col| b[a * r + col] == 0.0), "row {a} of B is lower triangular");
            }
            for k in 0..25 {
                let xi = [-2.0 + 0.17 * k as f64, 1.5 - 0.13 * k as f64];
                let x = [mean[0] + chol[0] * xi[0], mean[1] + chol[2] * xi[0] + chol[3] * xi[1]];
                for (a, alpha) in exponents.iter().enumerate() {
                    let expanded = at_mean[a]
                        + (0..=a).map(|col| b[a * r + col] * power(&xi, &exponents[col])).sum::<f64>();
                    let exact = power(&x, alpha);
                    assert!(
                        (expanded - exact).abs() <= 1e-12 * (1.0 + exact.abs()),
                        "x^{alpha:?} at ξ = {xi:?}: {expanded} vs {exact}"
                    );
                }
            }
        }
    }
}
