//! Forward-mode automatic differentiation helpers over the crate's generic scalar.
//!
//! Models and likelihoods are written once, generic over [`Scalar`]; the functions here
//! evaluate them with [`Dual64`] (first derivatives, one pass per input) and
//! [`HyperDual64`] (second derivatives, one pass per pair of inputs) and return plain `f64`
//! values and `nalgebra` matrices. Dual numbers stop at this layer (DESIGN.md).
//!
//! Because Rust closures cannot be generic, a differentiable function is a type implementing
//! [`ScalarFn`] or [`VectorFn`].
//!
//! The `*_into` variants write into caller-provided buffers and, for at most [`MAX_FIXED`]
//! inputs, evaluate the function once with fixed-size vector dual numbers ([`DualSVec64`] for
//! first, [`Dual2SVec64`] for second derivatives, held on the stack), instead of once per
//! input or pair of inputs; they allocate nothing.

use nalgebra::DMatrix;
use num_dual::{Dual2SVec64, Dual64, DualSVec64, HyperDual64};

use super::Scalar;

/// A scalar function of a vector, generic over the scalar type.
pub trait ScalarFn {
    /// Number of inputs.
    fn dim_in(&self) -> usize;
    /// φ(w).
    fn eval<D: Scalar>(&self, w: &[D]) -> D;
}

/// A vector function of a vector, generic over the scalar type.
pub trait VectorFn {
    /// Number of inputs.
    fn dim_in(&self) -> usize;
    /// Number of outputs.
    fn dim_out(&self) -> usize;
    /// out = φ(w).
    fn eval<D: Scalar>(&self, w: &[D], out: &mut [D]);
}

fn lift<D: Scalar>(w: &[f64]) -> Vec<D> {
    w.iter().map(|&v| D::from(v)).collect()
}

/// Value and gradient of `f` at `w`, one [`Dual64`] pass per input.
pub fn gradient<F: ScalarFn + ?Sized>(f: &F, w: &[f64]) -> (f64, Vec<f64>) {
    let n = w.len();
    let mut wd: Vec<Dual64> = lift(w);
    let mut grad = vec![0.0; n];
    let mut value = if n == 0 { f.eval::<f64>(w) } else { 0.0 };
    for i in 0..n {
        wd[i].eps = 1.0;
        let r = f.eval(&wd);
        wd[i].eps = 0.0;
        value = r.re;
        grad[i] = r.eps;
    }
    (value, grad)
}

/// Value, gradient and (symmetric, dense) Hessian of `f` at `w`, one [`HyperDual64`] pass per
/// pair i ≤ j.
pub fn hessian<F: ScalarFn + ?Sized>(f: &F, w: &[f64]) -> (f64, Vec<f64>, DMatrix<f64>) {
    let n = w.len();
    let mut wd: Vec<HyperDual64> = lift(w);
    let mut grad = vec![0.0; n];
    let mut hess = DMatrix::zeros(n, n);
    let mut value = if n == 0 { f.eval::<f64>(w) } else { 0.0 };
    for i in 0..n {
        for j in i..n {
            wd[i].eps1 = 1.0;
            wd[j].eps2 = 1.0;
            let r = f.eval(&wd);
            wd[i].eps1 = 0.0;
            wd[j].eps2 = 0.0;
            value = r.re;
            if j == i {
                grad[i] = r.eps1;
            }
            hess[(i, j)] = r.eps1eps2;
            hess[(j, i)] = r.eps1eps2;
        }
    }
    (value, grad, hess)
}

/// Value and Jacobian (`dim_out × dim_in`) of `f` at `w`, one [`Dual64`] pass per input.
pub fn jacobian<F: VectorFn + ?Sized>(f: &F, w: &[f64]) -> (Vec<f64>, DMatrix<f64>) {
    let n = w.len();
    let m = f.dim_out();
    let mut wd: Vec<Dual64> = lift(w);
    let mut out = vec![Dual64::from(0.0); m];
    let mut jac = DMatrix::zeros(m, n);
    let mut value = vec![0.0; m];
    if n == 0 {
        f.eval::<f64>(w, &mut value);
    }
    for j in 0..n {
        wd[j].eps = 1.0;
        f.eval(&wd, &mut out);
        wd[j].eps = 0.0;
        for i in 0..m {
            value[i] = out[i].re;
            jac[(i, j)] = out[i].eps;
        }
    }
    (value, jac)
}

/// Largest number of inputs handled by the fixed-size vector dual numbers of the `*_into`
/// functions; above it they fall back to [`gradient`], [`hessian`] and [`jacobian`].
pub const MAX_FIXED: usize = 8;

/// Largest number of outputs of [`jacobian_into`] held on the stack.
const MAX_FIXED_OUT: usize = 16;

/// Calls `$body` with the const generic `$n` bound to `$dim` when `1 ≤ $dim ≤ MAX_FIXED`,
/// otherwise evaluates `$fallback`.
macro_rules! with_fixed_dim {
    ($dim:expr, $n:ident => $body:expr, $fallback:expr) => {
        match $dim {
            1 => {
                const $n: usize = 1;
                $body
            }
            2 => {
                const $n: usize = 2;
                $body
            }
            3 => {
                const $n: usize = 3;
                $body
            }
            4 => {
                const $n: usize = 4;
                $body
            }
            5 => {
                const $n: usize = 5;
                $body
            }
            6 => {
                const $n: usize = 6;
                $body
            }
            7 => {
                const $n: usize = 7;
                $body
            }
            8 => {
                const $n: usize = 8;
                $body
            }
            _ => $fallback,
        }
    };
}

/// Value of `f` at `w`, with its gradient written into `grad` (length `w.len()`): one pass of
/// [`DualSVec64`] for at most [`MAX_FIXED`] inputs.
pub fn gradient_into<F: ScalarFn + ?Sized>(f: &F, w: &[f64], grad: &mut [f64]) -> f64 {
    fn fixed<const N: usize, F: ScalarFn + ?Sized>(f: &F, w: &[f64], grad: &mut [f64]) -> f64 {
        let x: [DualSVec64<N>; N] = std::array::from_fn(|i| DualSVec64::<N>::from_re(w[i]).derivative(i));
        let r = f.eval(&x);
        match &r.eps.0 {
            Some(g) => grad[..N].copy_from_slice(g.as_slice()),
            None => grad[..N].fill(0.0),
        }
        r.re
    }
    with_fixed_dim!(w.len(), N => fixed::<N, F>(f, w, grad), {
        if w.is_empty() {
            return f.eval::<f64>(w);
        }
        let (v, g) = gradient(f, w);
        grad.copy_from_slice(&g);
        v
    })
}

/// Value of `f` at `w`, with its gradient written into `grad` (length n = `w.len()`) and its
/// Hessian into `hess` (n × n, column-major, symmetric): one pass of [`Dual2SVec64`] for at
/// most [`MAX_FIXED`] inputs.
pub fn hessian_into<F: ScalarFn + ?Sized>(f: &F, w: &[f64], grad: &mut [f64], hess: &mut [f64]) -> f64 {
    fn fixed<const N: usize, F: ScalarFn + ?Sized>(
        f: &F,
        w: &[f64],
        grad: &mut [f64],
        hess: &mut [f64],
    ) -> f64 {
        let x: [Dual2SVec64<N>; N] = std::array::from_fn(|i| Dual2SVec64::<N>::from_re(w[i]).derivative(i));
        let r = f.eval(&x);
        match &r.v1.0 {
            Some(g) => grad[..N].copy_from_slice(g.as_slice()),
            None => grad[..N].fill(0.0),
        }
        match &r.v2.0 {
            Some(h) => hess[..N * N].copy_from_slice(h.as_slice()),
            None => hess[..N * N].fill(0.0),
        }
        r.re
    }
    with_fixed_dim!(w.len(), N => fixed::<N, F>(f, w, grad, hess), {
        if w.is_empty() {
            return f.eval::<f64>(w);
        }
        let (v, g, h) = hessian(f, w);
        grad.copy_from_slice(&g);
        hess.copy_from_slice(h.as_slice());
        v
    })
}

/// Writes the value of `f` at `w` into `value` (length `dim_out`) and its Jacobian into `jac`
/// (`dim_out × dim_in`, column-major): one pass of [`DualSVec64`] for at most [`MAX_FIXED`]
/// inputs and 16 outputs.
pub fn jacobian_into<F: VectorFn + ?Sized>(f: &F, w: &[f64], value: &mut [f64], jac: &mut [f64]) {
    fn fixed<const N: usize, F: VectorFn + ?Sized>(f: &F, w: &[f64], value: &mut [f64], jac: &mut [f64]) {
        let m = value.len();
        let x: [DualSVec64<N>; N] = std::array::from_fn(|i| DualSVec64::<N>::from_re(w[i]).derivative(i));
        with_zeros(m, |out: &mut [DualSVec64<N>]| {
            f.eval(&x, out);
            for (i, o) in out.iter().enumerate() {
                value[i] = o.re;
                match &o.eps.0 {
                    Some(g) => {
                        for j in 0..N {
                            jac[i + j * m] = g[j];
                        }
                    }
                    None => {
                        for j in 0..N {
                            jac[i + j * m] = 0.0;
                        }
                    }
                }
            }
        })
    }
    let m = f.dim_out();
    let fallback = |value: &mut [f64], jac: &mut [f64]| {
        if w.is_empty() {
            f.eval::<f64>(w, value);
            return;
        }
        let (v, j) = jacobian(f, w);
        value.copy_from_slice(&v);
        jac.copy_from_slice(j.as_slice());
    };
    if m > MAX_FIXED_OUT {
        return fallback(value, jac);
    }
    with_fixed_dim!(w.len(), N => fixed::<N, F>(f, w, value, jac), fallback(value, jac))
}

/// Writes the value of `f` at `w` into `value` (length m = `dim_out`), its Jacobian into `jac`
/// (m × n, column-major, n = `w.len()`) and the Hessian of every output into `hess` (m
/// column-major n × n blocks, output r's at `r·n²`): one pass of [`Dual2SVec64`] for at most
/// [`MAX_FIXED`] inputs and 16 outputs, otherwise one [`hessian`] per output.
pub fn hessians_into<F: VectorFn + ?Sized>(
    f: &F,
    w: &[f64],
    value: &mut [f64],
    jac: &mut [f64],
    hess: &mut [f64],
) {
    fn fixed<const N: usize, F: VectorFn + ?Sized>(
        f: &F,
        w: &[f64],
        value: &mut [f64],
        jac: &mut [f64],
        hess: &mut [f64],
    ) {
        let m = value.len();
        let x: [Dual2SVec64<N>; N] = std::array::from_fn(|i| Dual2SVec64::<N>::from_re(w[i]).derivative(i));
        with_zeros(m, |out: &mut [Dual2SVec64<N>]| {
            f.eval(&x, out);
            for (r, o) in out.iter().enumerate() {
                value[r] = o.re;
                match &o.v1.0 {
                    Some(g) => {
                        for j in 0..N {
                            jac[r + j * m] = g[j];
                        }
                    }
                    None => {
                        for j in 0..N {
                            jac[r + j * m] = 0.0;
                        }
                    }
                }
                let hr = &mut hess[r * N * N..(r + 1) * N * N];
                match &o.v2.0 {
                    Some(h) => hr.copy_from_slice(h.as_slice()),
                    None => hr.fill(0.0),
                }
            }
        })
    }
    let (n, m) = (w.len(), f.dim_out());
    let fallback = |value: &mut [f64], jac: &mut [f64], hess: &mut [f64]| {
        if n == 0 {
            f.eval::<f64>(w, value);
            return;
        }
        for r in 0..m {
            let (v, g, h) = hessian(&Component { f, r }, w);
            value[r] = v;
            for j in 0..n {
                jac[r + j * m] = g[j];
            }
            hess[r * n * n..(r + 1) * n * n].copy_from_slice(h.as_slice());
        }
    };
    if m > MAX_FIXED_OUT {
        return fallback(value, jac, hess);
    }
    with_fixed_dim!(n, N => fixed::<N, F>(f, w, value, jac, hess), fallback(value, jac, hess))
}

/// Output `r` of a [`VectorFn`], as a [`ScalarFn`].
struct Component<'a, F: ?Sized> {
    f: &'a F,
    r: usize,
}

impl<F: VectorFn + ?Sized> ScalarFn for Component<'_, F> {
    fn dim_in(&self) -> usize {
        self.f.dim_in()
    }
    fn eval<D: Scalar>(&self, w: &[D]) -> D {
        let mut out = vec![D::from(0.0); self.f.dim_out()];
        self.f.eval(w, &mut out);
        out[self.r]
    }
}

/// Calls `f` with a buffer of `len` zeros of `D`: on the stack in an array of 2, 4, 8 or 16
/// entries (the smallest that fits, so that few are cleared: a second-order dual number of 8
/// inputs has 75 words), on the heap beyond 16.
pub fn with_zeros<D: Scalar, R>(len: usize, f: impl FnOnce(&mut [D]) -> R) -> R {
    match len {
        0..=2 => f(&mut zeros::<D, 2>()[..len]),
        3..=4 => f(&mut zeros::<D, 4>()[..len]),
        5..=8 => f(&mut zeros::<D, 8>()[..len]),
        9..=16 => f(&mut zeros::<D, 16>()[..len]),
        _ => f(&mut vec![D::from(0.0); len]),
    }
}

/// An array of zeros built element by element: for large dual numbers this writes only their
/// real parts and empty-derivative tags, where `[D::from(0.0); M]` copies every byte.
pub fn zeros<D: Scalar, const M: usize>() -> [D; M] {
    std::array::from_fn(|_| D::from(0.0))
}

/// Solves the small dense system `A u = b` in place by Gaussian elimination with partial
/// pivoting (pivots chosen on the real parts), generic over the scalar so it can be
/// differentiated. `a` is `n × n`, column-major, and is overwritten by its LU factors.
///
/// Returns ln |det A|, or `None` when a pivot is zero or not finite.
pub fn lu_solve_in_place<D: Scalar>(a: &mut [D], b: &mut [D]) -> Option<D> {
    let n = b.len();
    debug_assert_eq!(a.len(), n * n);
    let mut log_det = D::from(0.0);
    for k in 0..n {
        let (mut p, mut best) = (k, a[k + k * n].re().abs());
        for i in k + 1..n {
            let v = a[i + k * n].re().abs();
            if v > best {
                p = i;
                best = v;
            }
        }
        if best == 0.0 || !best.is_finite() {
            return None;
        }
        if p != k {
            for j in 0..n {
                a.swap(k + j * n, p + j * n);
            }
            b.swap(k, p);
        }
        let pivot = a[k + k * n];
        log_det += pivot.abs().ln();
        for i in k + 1..n {
            let l = a[i + k * n] / pivot;
            a[i + k * n] = l;
            for j in k + 1..n {
                let akj = a[k + j * n];
                a[i + j * n] -= l * akj;
            }
            let bk = b[k];
            b[i] -= l * bk;
        }
    }
    for k in (0..n).rev() {
        let mut s = b[k];
        for j in k + 1..n {
            s -= a[k + j * n] * b[j];
        }
        b[k] = s / a[k + k * n];
    }
    Some(log_det)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    struct Rosen;
    impl ScalarFn for Rosen {
        fn dim_in(&self) -> usize {
            2
        }
        fn eval<D: Scalar>(&self, w: &[D]) -> D {
            let a = D::from(1.0) - w[0];
            let b = w[1] - w[0] * w[0];
            a * a + b * b * 100.0
        }
    }

    #[test]
    fn rosenbrock_gradient_and_hessian_match_closed_form() {
        // Closed form: ∇f = (−2(1−x) − 400x(y−x²), 200(y−x²)),
        // ∇²f = [[2 − 400(y − 3x²), −400x], [−400x, 200]].
        let (x, y) = (-1.2, 1.0);
        let (v, g, h) = hessian(&Rosen, &[x, y]);
        assert_relative_eq!(v, (1.0f64 - x).powi(2) + 100.0 * (y - x * x).powi(2));
        assert_relative_eq!(g[0], -2.0 * (1.0 - x) - 400.0 * x * (y - x * x));
        assert_relative_eq!(g[1], 200.0 * (y - x * x));
        assert_relative_eq!(h[(0, 0)], 2.0 - 400.0 * (y - 3.0 * x * x));
        assert_relative_eq!(h[(0, 1)], -400.0 * x);
        assert_relative_eq!(h[(1, 1)], 200.0);
        let (v2, g2) = gradient(&Rosen, &[x, y]);
        assert_eq!(v, v2);
        assert_eq!(g, g2);
    }

    /// f(w) = (Σ i·wᵢ)² + Π exp(wᵢ/10): exercises every fixed size and the fallback.
    struct Mixed;
    impl ScalarFn for Mixed {
        fn dim_in(&self) -> usize {
            0
        }
        fn eval<D: Scalar>(&self, w: &[D]) -> D {
            let mut s = D::from(0.0);
            let mut p = D::from(1.0);
            for (i, &v) in w.iter().enumerate() {
                s += v * (i as f64 + 1.0);
                p *= (v / 10.0).exp();
            }
            s * s + p
        }
    }

    struct Map;
    impl VectorFn for Map {
        fn dim_in(&self) -> usize {
            0
        }
        fn dim_out(&self) -> usize {
            3
        }
        fn eval<D: Scalar>(&self, w: &[D], out: &mut [D]) {
            let s: D = w.iter().copied().sum();
            out[0] = s.sin();
            out[1] = w[0] * w[w.len() - 1];
            out[2] = D::from(2.0);
        }
    }

    #[test]
    fn fixed_size_derivatives_equal_the_pass_per_input_ones() {
        // the one-pass vector duals against the per-input / per-pair passes, every size
        for n in 1..=MAX_FIXED + 2 {
            let w: Vec<f64> = (0..n).map(|i| 0.3 * i as f64 - 0.7).collect();
            let (v, g, h) = hessian(&Mixed, &w);
            let (mut g2, mut h2) = (vec![0.0; n], vec![0.0; n * n]);
            let v2 = hessian_into(&Mixed, &w, &mut g2, &mut h2);
            assert_relative_eq!(v, v2, max_relative = 1e-14);
            for i in 0..n {
                assert_relative_eq!(g[i], g2[i], max_relative = 1e-14, epsilon = 1e-14);
                for j in 0..n {
                    assert_relative_eq!(h[(i, j)], h2[i + j * n], max_relative = 1e-14, epsilon = 1e-14);
                }
            }
            let mut g3 = vec![0.0; n];
            assert_relative_eq!(gradient_into(&Mixed, &w, &mut g3), v, max_relative = 1e-14);
            for i in 0..n {
                assert_relative_eq!(g[i], g3[i], max_relative = 1e-14, epsilon = 1e-14);
            }
            let (mut hv, mut hj, mut hh) = (vec![0.0; 3], vec![0.0; 3 * n], vec![0.0; 3 * n * n]);
            hessians_into(&Map, &w, &mut hv, &mut hj, &mut hh);
            for r in 0..3 {
                let (v, g, h) = hessian(&Component { f: &Map, r }, &w);
                assert_relative_eq!(hv[r], v, max_relative = 1e-14);
                for i in 0..n {
                    assert_relative_eq!(hj[r + i * 3], g[i], max_relative = 1e-14, epsilon = 1e-14);
                    for j in 0..n {
                        let hij = hh[r * n * n + i + j * n];
                        assert_relative_eq!(hij, h[(i, j)], max_relative = 1e-14, epsilon = 1e-14);
                    }
                }
            }
            let (jv, jm) = jacobian(&Map, &w);
            let (mut v4, mut j4) = (vec![0.0; 3], vec![0.0; 3 * n]);
            jacobian_into(&Map, &w, &mut v4, &mut j4);
            for i in 0..3 {
                assert_relative_eq!(jv[i], v4[i], max_relative = 1e-14);
                for j in 0..n {
                    assert_relative_eq!(jm[(i, j)], j4[i + j * 3], max_relative = 1e-14, epsilon = 1e-14);
                }
            }
        }
    }

    #[test]
    fn lu_solve_matches_known_solution_and_determinant() {
        // A = [[0, 2], [3, 1]] (column-major [0, 3, 2, 1]); det = −6; A [1, 2]ᵀ = [4, 5]ᵀ.
        let mut a = [0.0, 3.0, 2.0, 1.0];
        let mut b = [4.0, 5.0];
        let ld = lu_solve_in_place(&mut a, &mut b).unwrap();
        assert_relative_eq!(b[0], 1.0, epsilon = 1e-14);
        assert_relative_eq!(b[1], 2.0, epsilon = 1e-14);
        assert_relative_eq!(ld, 6.0f64.ln(), epsilon = 1e-14);
        let mut s = [1.0, 2.0, 2.0, 4.0];
        assert!(lu_solve_in_place(&mut s, &mut [1.0, 1.0]).is_none());
    }
}
