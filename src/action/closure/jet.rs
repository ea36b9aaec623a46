//! Truncated Taylor expansions in two variables, for the one-state Gaussian closure drift.
//!
//! The one-state Gaussian closure ([`super::GaussianDrift`], R = 2 natural parameters) evaluates
//! W(λ) at every Runge–Kutta stage of its forward sweeps with its Jacobian and the Hessians of
//! both components (second-order jets, kept for the Hessian's adjoint sweep:
//! [`super::ClosureDrift::keeps_hessians`]); the first-order jets serve `w_jacobian` called
//! alone. `num-dual`'s fixed-size vector duals carry their
//! derivative parts as optional vectors and matrices, which their arithmetic tests and builds on
//! every operation; a [`Jet`] carries the value, the two first and the three distinct second
//! partial derivatives as plain numbers, so the same formulas ([`OneStateScalar`]) run as a few
//! dozen multiply-adds per operation. The rules are those of any second-order forward mode:
//! (uv)″ = u″v + 2u′v′ + uv″ and φ(u)″ = φ′(u)u″ + φ″(u)u′u′ for the unary φ ∈ {1/u, √u}.
//! The first-order jet (`Jet<false>`) skips the second-order parts at compile time.

use std::ops::{Add, Mul, Neg, Sub};

use crate::model::Scalar;

/// The operations the one-state Gaussian closure drift is written with: the arithmetic of
/// numbers, the reciprocal and the square root. Implemented for every [`Scalar`] (numbers and
/// `num-dual`'s dual numbers) and for [`Jet`].
pub(crate) trait OneStateScalar:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Neg<Output = Self>
    + Add<f64, Output = Self>
    + Sub<f64, Output = Self>
    + Mul<f64, Output = Self>
{
    /// The value (the real part).
    fn value(&self) -> f64;
    /// 1/x.
    fn reciprocal(&self) -> Self;
    /// √x.
    fn square_root(&self) -> Self;

    /// A function φ of (m, s) given by its value and partial derivatives at the values (m₀, s₀)
    /// of `m` and `s`, c = (φ, ∂_mφ, ∂_sφ, ∂²_mφ, ∂_m∂_sφ, ∂²_sφ), composed with the scalars m and
    /// s to second order: φ + φ_m δm + φ_s δs + ½φ_mm δm² + φ_ms δm δs + ½φ_ss δs² with
    /// δm = m − m₀, δs = s − s₀ (exact for every scalar of derivative order ≤ 2; δm and δs have
    /// value 0).
    fn lift(c: &[f64; 6], m: Self, s: Self) -> Self {
        let (dm, ds) = (m - m.value(), s - s.value());
        let (dmm, dms, dss) = (dm * dm * 0.5, dm * ds, ds * ds * 0.5);
        dm * c[1] + ds * c[2] + dmm * c[3] + dms * c[4] + dss * c[5] + c[0]
    }
}

impl<D: Scalar> OneStateScalar for D {
    fn value(&self) -> f64 {
        self.re()
    }
    fn reciprocal(&self) -> Self {
        self.recip()
    }
    fn square_root(&self) -> Self {
        self.sqrt()
    }
}

/// A function of two variables (u₀, u₁) to second order at a point: its value `v`, gradient
/// `g` and Hessian `h` = (∂²/∂u₀², ∂²/∂u₀∂u₁, ∂²/∂u₁²). With `SECOND = false` only the value
/// and the gradient are propagated (`h` stays zero).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Jet<const SECOND: bool> {
    /// The value.
    pub v: f64,
    /// ∂/∂u₀, ∂/∂u₁.
    pub g: [f64; 2],
    /// ∂²/∂u₀², ∂²/∂u₀∂u₁, ∂²/∂u₁².
    pub h: [f64; 3],
}

/// The index pairs (i, j) of the entries of [`Jet::h`].
const PAIRS: [(usize, usize); 3] = [(0, 0), (0, 1), (1, 1)];

impl<const SECOND: bool> Jet<SECOND> {
    /// The independent variable u_i at `value`.
    pub fn variable(value: f64, i: usize) -> Self {
        let mut g = [0.0; 2];
        g[i] = 1.0;
        Jet { v: value, g, h: [0.0; 3] }
    }

    /// φ(u) from φ(v), φ′(v), φ″(v) (the chain rule to second order).
    #[inline(always)]
    fn chain(self, f: f64, f1: f64, f2: f64) -> Self {
        let mut h = [0.0; 3];
        if SECOND {
            for (hk, (&uh, (i, j))) in h.iter_mut().zip(self.h.iter().zip(PAIRS)) {
                *hk = f1 * uh + f2 * self.g[i] * self.g[j];
            }
        }
        Jet { v: f, g: [f1 * self.g[0], f1 * self.g[1]], h }
    }
}

impl<const SECOND: bool> Add for Jet<SECOND> {
    type Output = Self;
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        Jet {
            v: self.v + o.v,
            g: [self.g[0] + o.g[0], self.g[1] + o.g[1]],
            h: if SECOND { std::array::from_fn(|k| self.h[k] + o.h[k]) } else { [0.0; 3] },
        }
    }
}

impl<const SECOND: bool> Sub for Jet<SECOND> {
    type Output = Self;
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        self + (-o)
    }
}

impl<const SECOND: bool> Neg for Jet<SECOND> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        self * -1.0
    }
}

impl<const SECOND: bool> Mul for Jet<SECOND> {
    type Output = Self;
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        let mut h = [0.0; 3];
        if SECOND {
            for (k, (i, j)) in PAIRS.into_iter().enumerate() {
                h[k] = self.v * o.h[k] + self.h[k] * o.v + self.g[i] * o.g[j] + self.g[j] * o.g[i];
            }
        }
        Jet { v: self.v * o.v, g: [self.v * o.g[0] + self.g[0] * o.v, self.v * o.g[1] + self.g[1] * o.v], h }
    }
}

impl<const SECOND: bool> Add<f64> for Jet<SECOND> {
    type Output = Self;
    #[inline(always)]
    fn add(self, c: f64) -> Self {
        Jet { v: self.v + c, ..self }
    }
}

impl<const SECOND: bool> Sub<f64> for Jet<SECOND> {
    type Output = Self;
    #[inline(always)]
    fn sub(self, c: f64) -> Self {
        Jet { v: self.v - c, ..self }
    }
}

impl<const SECOND: bool> Mul<f64> for Jet<SECOND> {
    type Output = Self;
    #[inline(always)]
    fn mul(self, c: f64) -> Self {
        Jet {
            v: self.v * c,
            g: [self.g[0] * c, self.g[1] * c],
            h: if SECOND { [self.h[0] * c, self.h[1] * c, self.h[2] * c] } else { [0.0; 3] },
        }
    }
}

impl<const SECOND: bool> OneStateScalar for Jet<SECOND> {
    fn value(&self) -> f64 {
        self.v
    }
    #[inline(always)]
    fn reciprocal(&self) -> Self {
        let r = 1.0 / self.v;
        self.chain(r, -r * r, 2.0 * r * r * r)
    }
    #[inline(always)]
    fn square_root(&self) -> Self {
        let s = self.v.sqrt();
        self.chain(s, 0.5 / s, -0.25 / (s * self.v))
    }

    /// [`OneStateScalar::lift`] by the chain rule written out for two inner jets (the products of
    /// the zero-valued δm, δs keep only their gradients' products):
    /// ∂_i = φ_m m_i + φ_s s_i and
    /// ∂_ij = φ_m m_ij + φ_s s_ij + φ_mm m_i m_j + φ_ms (m_i s_j + m_j s_i) + φ_ss s_i s_j.
    /// A non-finite derivative in `c` makes the value NaN, as in the generic form (where it
    /// multiplies a δ of value 0), so that the caller's finiteness test sees it.
    #[inline(always)]
    fn lift(c: &[f64; 6], m: Self, s: Self) -> Self {
        let mut h = [0.0; 3];
        if SECOND {
            for (k, (i, j)) in PAIRS.into_iter().enumerate() {
                h[k] = c[1] * m.h[k]
                    + c[2] * s.h[k]
                    + c[3] * m.g[i] * m.g[j]
                    + c[4] * (m.g[i] * s.g[j] + m.g[j] * s.g[i])
                    + c[5] * s.g[i] * s.g[j];
            }
        }
        // c·0 is 0 for a finite c and NaN otherwise.
        let v = c[0] + c[1..].iter().map(|x| x * 0.0).sum::<f64>();
        Jet { v, g: [c[1] * m.g[0] + c[2] * s.g[0], c[1] * m.g[1] + c[2] * s.g[1]], h }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use num_dual::Dual2SVec64;

    /// An expression with every operation and the lift, in a jet (whose lift is its own chain
    /// rule) and in `num-dual`'s second-order vector duals (an independent implementation of the
    /// same derivatives, with the lift's generic Taylor form): equal to round-off; the
    /// first-order jet has the same value and gradient and a zero Hessian.
    #[test]
    fn jets_agree_with_second_order_dual_numbers() {
        fn expr<T: OneStateScalar>(u: T, w: T) -> T {
            let p = -(w * 2.0);
            let v = p.reciprocal();
            let m = v * u;
            let s = v.square_root();
            let c = [0.3, -1.2, 0.8, 2.5, -0.7, 1.9];
            (m - 0.3) * s * (m + 1.5) + p * m - s * 0.7 + T::lift(&c, m, s) * s
        }
        for (a, b) in [(0.4, -1.5), (-25.0, -12.5), (3.0, -0.01)] {
            let (j2, j1) = (
                expr(Jet::<true>::variable(a, 0), Jet::<true>::variable(b, 1)),
                expr(Jet::<false>::variable(a, 0), Jet::<false>::variable(b, 1)),
            );
            let d = |i: usize, x: f64| Dual2SVec64::<2>::from_re(x).derivative(i);
            let r = expr(d(0, a), d(1, b));
            let (g, h) = (r.v1.0.unwrap(), r.v2.0.unwrap());
            let tol = |x: f64, y: f64| assert_relative_eq!(x, y, epsilon = 1e-12, max_relative = 1e-12);
            tol(j2.v, r.re);
            for i in 0..2 {
                tol(j2.g[i], g[i]);
                tol(j1.g[i], g[i]);
            }
            for (k, (i, j)) in PAIRS.into_iter().enumerate() {
                tol(j2.h[k], h[(i, j)]);
            }
            assert_eq!((j1.v, j1.h), (j2.v, [0.0; 3]));
        }
    }
}
