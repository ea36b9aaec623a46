//! Special functions usable with dual numbers.
//!
//! Every function here is generic over [`Scalar`], so that likelihoods written with them are
//! differentiated by the same forward-mode passes as the models. Functions that are not built
//! from the arithmetic of `num-dual` ([`erf`], [`erfc`], [`log_ndtr`]) compute their value and
//! their first three derivatives in `f64` with a dedicated algorithm and lift them to the dual
//! number by the truncated Taylor expansion
//!
//! $$ f(x) = f(x_0) + f'(x_0)\,h + \tfrac12 f''(x_0)\,h^2 + \tfrac16 f'''(x_0)\,h^3,
//!    \qquad x_0 = \operatorname{re}(x),\; h = x - x_0, $$
//!
//! which is exact for every dual number whose derivative parts vanish beyond third order
//! (`Dual`, `HyperDual`, `Dual2`, `Dual3`, `HyperHyperDual` and nestings such as
//! `Dual<Dual<f64>>`, `Dual<HyperDual<f64>>`), because h is nilpotent: h⁴ = 0. Fourth and
//! higher derivatives are not propagated.
//!
//! - [`erf`], [`erfc`]: the FreeBSD/fdlibm algorithm `s_erf.c` (rational approximations on
//!   four intervals, error below one ulp), ported below with its copyright notice.
//! - [`log_ndtr`]: ln Φ(x), accurate far into the lower tail through the scaled complementary
//!   error function erfcx(t) = e^{t²} erfc(t) and, beyond t = 28, its asymptotic series
//!   (Abramowitz & Stegun 7.1.23).
//! - [`log_diff_ndtr`]: ln(Φ(b) − Φ(a)), the log-probability of an interval, used by the
//!   quantized likelihood of `000_74b95e149527c64e.txt` Sec. 4.1.3.
//! - [`ln_gamma`]: ln Γ(x) by recurrence and Stirling's series, in dual arithmetic.

use super::Scalar;

/// ln √(2π).
const LN_SQRT_2PI: f64 = 0.918_938_533_204_672_8;
/// 2/√π.
const TWO_OVER_SQRT_PI: f64 = std::f64::consts::FRAC_2_SQRT_PI;
/// √(2/π).
const SQRT_2_OVER_PI: f64 = 0.797_884_560_802_865_4;
/// √π.
const SQRT_PI: f64 = 1.772_453_850_905_516;

/// Lifts a function value and its first three derivatives at x₀ = re(x) to the dual number x by
/// the truncated Taylor series (module documentation). A non-finite x₀ gets the value only.
pub fn lift_taylor<D: Scalar>(x: D, value: f64, d1: f64, d2: f64, d3: f64) -> D {
    let x0 = x.re();
    if !x0.is_finite() {
        return D::from(value);
    }
    let h = x - D::from(x0);
    // Horner form of v + d1 h + d2/2 h² + d3/6 h³; the products of zero parts are exact.
    D::from(value) + h * (h * (h * (d3 / 6.0) + d2 * 0.5) + d1)
}

// ---------------------------------------------------------------------------------------------
// erf / erfc in f64: port of FreeBSD /usr/src/lib/msun/src/s_erf.c (via musl and the `libm`
// crate). The original notice:
//
// ====================================================
// Copyright (C) 1993 by Sun Microsystems, Inc. All rights reserved.
//
// Developed at SunPro, a Sun Microsystems, Inc. business.
// Permission to use, copy, modify, and distribute this
// software is freely granted, provided that this notice
// is preserved.
// ====================================================
//
// Method (from s_erf.c): |x| < 0.84375: erf = x + x R(x²); 0.84375 ≤ |x| < 1.25: erf = c + P1(s)/Q1(s),
// s = |x| − 1; 1.25 ≤ |x| < 1/0.35: erfc = exp(−x² − 0.5625 + R1/S1)/x; 1/0.35 ≤ |x| < 28:
// erfc = exp(−x² − 0.5625 + R2/S2)/x, R/S rational in 1/x² (errors ≤ 2^−57.9 … 2^−62.6).
// The coefficients below are s_erf.c's, written as their shortest round-trip decimals (the same
// f64 bit patterns as the 21-digit literals of the original).
// ---------------------------------------------------------------------------------------------

const ERX: f64 = 0.8450629115104675;
const EFX8: f64 = 1.0270333367641007;
const PP0: f64 = 0.12837916709551256;
const PP1: f64 = -0.3250421072470015;
const PP2: f64 = -0.02848174957559851;
const PP3: f64 = -0.005770270296489442;
const PP4: f64 = -2.3763016656650163e-05;
const QQ1: f64 = 0.39791722395915535;
const QQ2: f64 = 0.0650222499887673;
const QQ3: f64 = 0.005081306281875766;
const QQ4: f64 = 0.00013249473800432164;
const QQ5: f64 = -3.960228278775368e-06;
const PA0: f64 = -0.0023621185607526594;
const PA1: f64 = 0.41485611868374833;
const PA2: f64 = -0.3722078760357013;
const PA3: f64 = 0.31834661990116175;
const PA4: f64 = -0.11089469428239668;
const PA5: f64 = 0.035478304325618236;
const PA6: f64 = -0.002166375594868791;
const QA1: f64 = 0.10642088040084423;
const QA2: f64 = 0.540397917702171;
const QA3: f64 = 0.07182865441419627;
const QA4: f64 = 0.12617121980876164;
const QA5: f64 = 0.01363708391202905;
const QA6: f64 = 0.011984499846799107;
const RA0: f64 = -0.009864944034847148;
const RA1: f64 = -0.6938585727071818;
const RA2: f64 = -10.558626225323291;
const RA3: f64 = -62.375332450326006;
const RA4: f64 = -162.39666946257347;
const RA5: f64 = -184.60509290671104;
const RA6: f64 = -81.2874355063066;
const RA7: f64 = -9.814329344169145;
const SA1: f64 = 19.651271667439257;
const SA2: f64 = 137.65775414351904;
const SA3: f64 = 434.56587747522923;
const SA4: f64 = 645.3872717332679;
const SA5: f64 = 429.00814002756783;
const SA6: f64 = 108.63500554177944;
const SA7: f64 = 6.570249770319282;
const SA8: f64 = -0.0604244152148581;
const RB0: f64 = -0.0098649429247001;
const RB1: f64 = -0.799283237680523;
const RB2: f64 = -17.757954917754752;
const RB3: f64 = -160.63638485582192;
const RB4: f64 = -637.5664433683896;
const RB5: f64 = -1025.0951316110772;
const RB6: f64 = -483.5191916086514;
const SB1: f64 = 30.33806074348246;
const SB2: f64 = 325.7925129965739;
const SB3: f64 = 1536.729586084437;
const SB4: f64 = 3199.8582195085955;
const SB5: f64 = 2553.0504064331644;
const SB6: f64 = 474.52854120695537;
const SB7: f64 = -22.44095244658582;

/// R(x²) of s_erf.c on |x| < 0.84375: erf(x) = x + x R.
fn erf_small_ratio(x: f64) -> f64 {
    let z = x * x;
    let r = PP0 + z * (PP1 + z * (PP2 + z * (PP3 + z * PP4)));
    let s = 1.0 + z * (QQ1 + z * (QQ2 + z * (QQ3 + z * (QQ4 + z * QQ5))));
    r / s
}

/// erfc(a) for 0.84375 ≤ a < 1.25 (s_erf.c `erfc1`).
fn erfc_near_one(a: f64) -> f64 {
    let s = a - 1.0;
    let p = PA0 + s * (PA1 + s * (PA2 + s * (PA3 + s * (PA4 + s * (PA5 + s * PA6)))));
    let q = 1.0 + s * (QA1 + s * (QA2 + s * (QA3 + s * (QA4 + s * (QA5 + s * QA6)))));
    1.0 - ERX - p / q
}

/// −0.5625 + R/S of s_erf.c for 1.25 ≤ a < 28, so that erfc(a) = exp(−a² + g)/a, i.e.
/// ln erfcx(a) = g − ln a.
fn erfc_log_correction(a: f64) -> f64 {
    let s = 1.0 / (a * a);
    let (r, q) = if a < 1.0 / 0.35 {
        (
            RA0 + s * (RA1 + s * (RA2 + s * (RA3 + s * (RA4 + s * (RA5 + s * (RA6 + s * RA7)))))),
            1.0 + s * (SA1 + s * (SA2 + s * (SA3 + s * (SA4 + s * (SA5 + s * (SA6 + s * (SA7 + s * SA8))))))),
        )
    } else {
        (
            RB0 + s * (RB1 + s * (RB2 + s * (RB3 + s * (RB4 + s * (RB5 + s * RB6))))),
            1.0 + s * (SB1 + s * (SB2 + s * (SB3 + s * (SB4 + s * (SB5 + s * (SB6 + s * SB7)))))),
        )
    };
    -0.5625 + r / q
}

/// erfc(a) for 1.25 ≤ a < 28 with the splitting of s_erf.c (Note 1): −a² = −z² + (z − a)(z + a)
/// with z = a rounded to 32 significant bits, so that exp(−a²) keeps full relative accuracy.
fn erfc_mid(a: f64) -> f64 {
    let z = f64::from_bits(a.to_bits() & 0xffff_ffff_0000_0000);
    (-z * z - 0.5625).exp() * ((z - a) * (z + a) + erfc_log_correction(a) + 0.5625).exp() / a
}

/// erf(x) in f64 (s_erf.c).
fn erf_f64(x: f64) -> f64 {
    if x.is_nan() {
        return x;
    }
    let a = x.abs();
    if a < 0.84375 {
        if a < 3.725_290_298_461_914e-9 {
            // |x| < 2^-28
            return 0.125 * (8.0 * x + EFX8 * x);
        }
        return x + x * erf_small_ratio(x);
    }
    let y = if a < 1.25 {
        1.0 - erfc_near_one(a)
    } else if a < 6.0 {
        1.0 - erfc_mid(a)
    } else {
        1.0
    };
    y.copysign(x)
}

/// erfc(x) in f64 (s_erf.c).
fn erfc_f64(x: f64) -> f64 {
    if x.is_nan() {
        return x;
    }
    let a = x.abs();
    if a < 0.84375 {
        let y = erf_small_ratio(x);
        if x < 0.25 {
            return 1.0 - (x + x * y);
        }
        return 0.5 - (x - 0.5 + x * y);
    }
    let c = if a < 1.25 {
        erfc_near_one(a)
    } else if a < 28.0 {
        erfc_mid(a)
    } else {
        0.0
    };
    if x < 0.0 {
        2.0 - c
    } else if a < 28.0 {
        c
    } else {
        // Beyond 28, erfc(x) < 1e-342 underflows.
        0.0
    }
}

/// ln erfcx(a) = ln(e^{a²} erfc(a)) for a ≥ 1.25: s_erf.c's rational form below 28, the
/// asymptotic series (Abramowitz & Stegun 7.1.23) beyond, where
/// erfcx(a) = 1/(a√π) · S(a), S = Σ_{n≥0} (−1)^n (2n−1)!!/(2a²)^n.
fn ln_erfcx_large(a: f64) -> f64 {
    if a < 28.0 {
        erfc_log_correction(a) - a.ln()
    } else {
        -(a * SQRT_PI).ln() + erfcx_series_minus_one(a).ln_1p()
    }
}

/// S(a) − 1 of the asymptotic series of erfcx (see [`ln_erfcx_large`]), summed without the
/// leading one, for a ≥ 28 (terms below 1e-19 after ten).
fn erfcx_series_minus_one(a: f64) -> f64 {
    let u = 1.0 / (2.0 * a * a);
    let mut term = 1.0;
    let mut sum = 0.0;
    for n in 1..=12 {
        term *= -((2 * n - 1) as f64) * u;
        sum += term;
    }
    sum
}

/// The error function, $\operatorname{erf}(x) = \frac{2}{\sqrt\pi}\int_0^x e^{-t^2}\,dt$, with
/// derivatives up to third order ($\operatorname{erf}' = \frac{2}{\sqrt\pi}e^{-x^2}$,
/// erf'' = −2x erf', erf''' = (4x² − 2) erf'). Value by the fdlibm algorithm (below one ulp).
pub fn erf<D: Scalar>(x: D) -> D {
    let x0 = x.re();
    let [d1, d2, d3] = erf_derivatives(x0);
    lift_taylor(x, erf_f64(x0), d1, d2, d3)
}

/// erf', erf'', erf''' at x (zero where e^{−x²} underflows, so no ∞ · 0 appears).
fn erf_derivatives(x: f64) -> [f64; 3] {
    let d1 = TWO_OVER_SQRT_PI * (-x * x).exp();
    if d1 == 0.0 {
        return [0.0; 3];
    }
    [d1, -2.0 * x * d1, (4.0 * x * x - 2.0) * d1]
}

/// The complementary error function, erfc(x) = 1 − erf(x), computed without cancellation for
/// large x (relative accuracy near one ulp until it underflows at x ≈ 26.5), with derivatives
/// up to third order (the negatives of those of [`erf`]).
pub fn erfc<D: Scalar>(x: D) -> D {
    let x0 = x.re();
    let [d1, d2, d3] = erf_derivatives(x0);
    lift_taylor(x, erfc_f64(x0), -d1, -d2, -d3)
}

/// ln Φ(x), its first three derivatives, in f64.
///
/// With r = φ/Φ: (ln Φ)' = r, (ln Φ)'' = −r (x + r), (ln Φ)''' = −(ln Φ)'' (x + r) − r (1 + (ln Φ)'').
fn log_ndtr_parts(x: f64) -> [f64; 4] {
    if x.is_nan() {
        return [f64::NAN; 4];
    }
    if x == f64::NEG_INFINITY {
        return [f64::NEG_INFINITY, f64::INFINITY, -1.0, 0.0];
    }
    if x > 40.0 {
        // Φ(x) = 1 − Q(x) with Q(x) < 1e-349: ln Φ and its derivatives vanish in f64.
        return [0.0; 4];
    }
    let t = -x * std::f64::consts::FRAC_1_SQRT_2;
    let (value, r, x_plus_r) = if t >= 1.25 {
        // Lower tail: Φ(x) = ½ e^{−x²/2} erfcx(t), r = √(2/π)/erfcx(t).
        let ln_erfcx = ln_erfcx_large(t);
        let value = -0.5 * x * x + ln_erfcx - std::f64::consts::LN_2;
        let (r, x_plus_r) = if t < 28.0 {
            let r = SQRT_2_OVER_PI * (-ln_erfcx).exp();
            (r, x + r)
        } else {
            // With erfcx(t) = S/(t√π) (S the asymptotic series): r = √2 t/S and
            // x + r = √2 t (1 − S)/S, both without cancellation.
            let sm1 = erfcx_series_minus_one(t);
            let r = std::f64::consts::SQRT_2 * t / (1.0 + sm1);
            (r, -r * sm1)
        };
        (value, r, x_plus_r)
    } else if x <= 0.0 {
        let phi_cdf = 0.5 * erfc_f64(t);
        let pdf = (-0.5 * x * x - LN_SQRT_2PI).exp();
        let r = pdf / phi_cdf;
        (phi_cdf.ln(), r, x + r)
    } else {
        // Upper half: ln Φ(x) = ln(1 − Q(x)), Q(x) = ½ erfc(x/√2).
        let q = 0.5 * erfc_f64(-t);
        let pdf = (-0.5 * x * x - LN_SQRT_2PI).exp();
        let r = pdf / (1.0 - q);
        ((-q).ln_1p(), r, x + r)
    };
    let d2 = -r * x_plus_r;
    let d3 = -d2 * x_plus_r - r * (1.0 + d2);
    [value, r, d2, d3]
}

/// The log of the standard normal distribution function,
/// $\ln\Phi(x) = \ln \tfrac12 \operatorname{erfc}(-x/\sqrt2)$, accurate to a few ulp on the
/// whole real line: for x < −1.25√2 through ln Φ(x) = −x²/2 + ln(½ erfcx(−x/√2)), so it is
/// finite and accurate far into the lower tail (e.g. ln Φ(−40) ≈ −804.61), with derivatives up
/// to third order ((ln Φ)' = φ/Φ).
pub fn log_ndtr<D: Scalar>(x: D) -> D {
    let [v, d1, d2, d3] = log_ndtr_parts(x.re());
    lift_taylor(x, v, d1, d2, d3)
}

/// The standard normal distribution function Φ(x) = ½ erfc(−x/√2), with derivatives.
pub fn ndtr<D: Scalar>(x: D) -> D {
    erfc(-x * std::f64::consts::FRAC_1_SQRT_2) * 0.5
}

/// ln(1 − e^u) for u ≤ 0, by Mächler's rule (ln(−expm1 u) near zero, ln1p(−e^u) below −ln 2).
pub fn log1mexp<D: Scalar>(u: D) -> D {
    if u.re() > -std::f64::consts::LN_2 {
        (-u.exp_m1()).ln()
    } else {
        (-u.exp()).ln_1p()
    }
}

/// The log-probability of an interval under the standard normal law,
/// $\ln(\Phi(b) - \Phi(a))$ for a < b, finite and accurate with a and b deep in either tail:
///
/// - a ≥ 0: by symmetry, ln(Φ(−a) − Φ(−b));
/// - b ≤ 0: ln Φ(b) + ln(1 − exp(ln Φ(a) − ln Φ(b))) with [`log1mexp`];
/// - a < 0 < b: ln(1 − Φ(a) − Φ(−b)) by `ln_1p` when the two tails hold less than half the
///   mass, else ln(½(erf(b/√2) + erf(−a/√2))), both without cancellation.
///
/// Returns −∞ when a ≥ b (an empty interval) and NaN when a or b is NaN. When b − a is tiny
/// compared with the distance to the mode, the relative accuracy of the result degrades like
/// ε |x²/2| / |(b − a) x| (cancellation in ln Φ(a) − ln Φ(b)); at 40σ with b − a = 0.5 it is
/// still ~1e-13.
///
/// Used for the quantized measurement likelihood of `000_74b95e149527c64e.txt` Sec. 4.1.3.
pub fn log_diff_ndtr<D: Scalar>(a: D, b: D) -> D {
    let (ar, br) = (a.re(), b.re());
    if ar.is_nan() || br.is_nan() {
        return D::from(f64::NAN);
    }
    if ar >= br {
        return D::from(f64::NEG_INFINITY);
    }
    if ar >= 0.0 {
        return log_diff_ndtr_negative(-b, -a);
    }
    if br <= 0.0 {
        return log_diff_ndtr_negative(a, b);
    }
    let s2 = std::f64::consts::FRAC_1_SQRT_2;
    let tails = (erfc(-a * s2) + erfc(b * s2)) * 0.5; // Φ(a) + Φ(−b)
    if tails.re() < 0.5 {
        (-tails).ln_1p()
    } else {
        ((erf(b * s2) + erf(-a * s2)) * 0.5).ln()
    }
}

/// ln(Φ(b) − Φ(a)) for a < b ≤ 0.
fn log_diff_ndtr_negative<D: Scalar>(a: D, b: D) -> D {
    let lb = log_ndtr(b);
    if a.re() == f64::NEG_INFINITY {
        return lb;
    }
    lb + log1mexp(log_ndtr(a) - lb)
}

/// Coefficients B₂ₖ/(2k(2k − 1)) of Stirling's series for ln Γ, k = 1..8.
const STIRLING: [f64; 8] = [
    1.0 / 12.0,
    -1.0 / 360.0,
    1.0 / 1260.0,
    -1.0 / 1680.0,
    1.0 / 1188.0,
    -691.0 / 360_360.0,
    1.0 / 156.0,
    -3617.0 / 122_400.0,
];

/// ln Γ(x) for x > 0, in dual arithmetic (so its derivatives, the polygamma functions, come by
/// automatic differentiation): the recurrence ln Γ(x) = ln Γ(x + n) − ln(x(x+1)⋯(x+n−1)) up to
/// x + n ≥ 15, then Stirling's series with eight terms (Abramowitz & Stegun 6.1.40), whose
/// truncation error is below 1e-19 there. Absolute error ~1e-15 near the zeros x = 1, 2,
/// relative error ~1e-15 elsewhere. Returns NaN for x ≤ 0 or NaN and +∞ for x = +∞.
pub fn ln_gamma<D: Scalar>(x: D) -> D {
    let x0 = x.re();
    if x0.is_nan() || x0 <= 0.0 {
        return D::from(f64::NAN);
    }
    if x0 == f64::INFINITY {
        return D::from(f64::INFINITY);
    }
    let mut y = x;
    let mut prod = D::from(1.0);
    let mut shifted = false;
    while y.re() < 15.0 {
        prod *= y;
        y += 1.0;
        shifted = true;
    }
    let inv = y.recip();
    let inv2 = inv * inv;
    let mut series = D::from(STIRLING[7]);
    for &c in STIRLING[..7].iter().rev() {
        series = series * inv2 + c;
    }
    let stirling = (y - 0.5) * y.ln() - y + LN_SQRT_2PI + series * inv;
    if shifted {
        stirling - prod.ln()
    } else {
        stirling
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use num_dual::{Dual64, HyperDual64};
    use proptest::prelude::*;
    use statrs::distribution::{ContinuousCDF, Normal};

    fn dual(x: f64) -> Dual64 {
        Dual64::new(x, 1.0)
    }

    fn hyper(x: f64) -> HyperDual64 {
        HyperDual64::new(x, 1.0, 1.0, 0.0)
    }

    // Reference values: mpmath 1.3 at 80 digits, printed to 17 significant digits (written
    // here as the shortest literal of the same f64), each x taken as the f64 the literal
    // denotes. Regenerate with this Python script:
    //
    //   import mpmath as m; m.mp.dps = 80
    //   X = m.mpf(float(x))
    //   erf: m.erf(X), m.erfc(X)
    //   ln Φ: m.log(m.ncdf(X)) if X <= 0 else m.log1p(-m.ncdf(-X))
    //   ln(Φ(b) − Φ(a)): m.log(m.ncdf(B) - m.ncdf(A)) if A < 0 else m.log(m.ncdf(-A) - m.ncdf(-B))
    //   printed with m.nstr(value, 17).
    const ERF_TABLE: [(f64, f64, f64); 26] = [
        (-5.5, -0.9999999999999927, 1.9999999999999927),
        (-3.1, -0.9999883513426328, 1.9999883513426329),
        (-2.857142857142857, -0.9999466876886117, 1.9999466876886116),
        (-2.0, -0.9953222650189527, 1.9953222650189526),
        (-1.25, -0.9229001282564583, 1.9229001282564582),
        (-1.0, -0.8427007929497149, 1.842700792949715),
        (-0.84375, -0.7672256612323416, 1.7672256612323416),
        (-0.5, -0.5204998778130465, 1.5204998778130465),
        (-0.1, -0.1124629160182849, 1.1124629160182848),
        (-1e-10, -1.1283791670955126e-10, 1.000000000112838),
        (1e-10, 1.1283791670955126e-10, 0.999999999887162),
        (0.1, 0.1124629160182849, 0.887537083981715),
        (0.25, 0.27632639016823696, 0.7236736098317631),
        (0.503, 0.5231322670885573, 0.47686773291144274),
        (0.84375, 0.7672256612323416, 0.23277433876765838),
        (1.0, 0.8427007929497149, 0.15729920705028513),
        (1.25, 0.9229001282564583, 0.07709987174354177),
        (1.7, 0.9837904585907745, 0.01620954140922544),
        (2.857142857142857, 0.9999466876886117, 5.3312311388322795e-05),
        (3.3, 0.9999969422902035, 3.0577097964381654e-06),
        (4.5, 0.9999999998033839, 1.9661604415428876e-10),
        (5.9, 0.9999999999999999, 7.190409783550478e-17),
        (8.0, 1.0, 1.1224297172982926e-29),
        (12.0, 1.0, 1.3562611692059042e-64),
        (20.0, 1.0, 5.395865611607901e-176),
        (26.0, 1.0, 5.663192408856143e-296),
    ];
    const LOG_NDTR_TABLE: [(f64, f64); 19] = [
        (-10000000000.0, -5e+19),
        (-10000.0, -50000010.12927891),
        (-200.0, -20006.21728089819),
        (-40.0, -804.6084420137538),
        (-37.5, -707.6689893175072),
        (-30.0, -454.3212439563432),
        (-24.2, -296.9269914714921),
        (-10.0, -53.23128515051247),
        (-5.0, -15.064998393988725),
        (-2.0, -3.783184333682032),
        (-1.7677669529663687, -3.2558008424820706),
        (-1.0, -1.8410216450092636),
        (-0.3, -0.9621028181688507),
        (0.0, -std::f64::consts::LN_2),
        (0.3, -0.4814101615884812),
        (1.0, -0.17275377902344988),
        (3.0, -0.0013508099647481938),
        (8.0, -6.220960574271786e-16),
        (20.0, -2.7536241186062337e-89),
    ];
    const LOG_DIFF_NDTR_TABLE: [(f64, f64, f64); 12] = [
        (-1.0, 2.0, -0.2001662943244626),
        (-0.1, 0.1, -2.5300420015472387),
        (0.3, 1.7, -1.0861212819703627),
        (-3.0, -2.0, -3.8443534263342056),
        (1.0, 8.0, -1.8410216450092673),
        (-9.0, 9.0, -2.257176811907681e-19),
        (-40.25, -39.75, -794.6334302644475),
        (39.75, 40.25, -794.6334302644475),
        (-1e-06, 1e-06, -14.041301910609167),
        (-30.000001, -30.0, -464.73446409010364),
        (5.0, 5.5, -15.133540811271288),
        (-0.5, 30.0, -0.3689464152886564),
    ];

    #[test]
    fn erf_erfc_match_reference_values() {
        let mut max_rel: f64 = 0.0;
        for &(x, e, c) in &ERF_TABLE {
            // Two ulp: fdlibm's bound (< 1 ulp) plus the rounding of the reference.
            assert_relative_eq!(erf(x), e, epsilon = 1e-300, max_relative = 4.5e-16);
            assert_relative_eq!(erfc(x), c, epsilon = 1e-300, max_relative = 4.5e-16);
            max_rel = max_rel.max(((erf(x) - e) / e).abs()).max(((erfc(x) - c) / c).abs());
        }
        assert!(max_rel < 4.5e-16, "max relative error {max_rel:e}");
        // Identities: odd symmetry and erf + erfc = 1 on a dense grid, and a sanity check
        // against statrs (whose erf is only accurate to ~1e-10 relative, e.g. at x = 0.503).
        for i in -600..=600 {
            let x = i as f64 * 0.01 + 0.003;
            assert_eq!(erf(-x), -erf(x));
            assert_relative_eq!(erf(x) + erfc(x), 1.0, epsilon = 0.0, max_relative = 3e-16);
            assert_relative_eq!(erf(x), statrs::function::erf::erf(x), epsilon = 0.0, max_relative = 1e-9);
            assert_relative_eq!(erfc(x), statrs::function::erf::erfc(x), epsilon = 0.0, max_relative = 1e-9);
        }
        // Limits.
        assert_eq!(erf(0.0_f64), 0.0);
        assert_eq!(erfc(0.0_f64), 1.0);
        assert_eq!(erf(f64::INFINITY), 1.0);
        assert_eq!(erfc(f64::NEG_INFINITY), 2.0);
        assert_eq!(erfc(40.0_f64), 0.0);
        assert!(erf(f64::NAN).is_nan());
    }

    #[test]
    fn erf_derivatives_match_closed_form() {
        // d/dx erf = 2/√π e^{−x²}, d²/dx² = −2x · that (closed forms).
        for x in [-3.0_f64, -0.5, 0.0, 0.7, 1.1, 2.0, 4.0] {
            let g = TWO_OVER_SQRT_PI * (-x * x).exp();
            let h = erf(hyper(x));
            assert_relative_eq!(h.eps1, g, epsilon = 0.0, max_relative = 1e-15);
            assert_relative_eq!(h.eps1eps2, -2.0 * x * g, epsilon = 1e-300, max_relative = 1e-15);
            assert_relative_eq!(erfc(dual(x)).eps, -g, epsilon = 0.0, max_relative = 1e-15);
        }
        // Third derivative through Dual3: (4x² − 2) · 2/√π e^{−x²}.
        let x = 0.9;
        let d3 = erf(num_dual::Dual3_64::new(x, 1.0, 0.0, 0.0));
        assert_relative_eq!(
            d3.v3,
            (4.0 * x * x - 2.0) * TWO_OVER_SQRT_PI * (-x * x).exp(),
            epsilon = 0.0,
            max_relative = 1e-14
        );
    }

    /// ln Φ(x) for x ≪ 0 by the asymptotic series (A&S 26.2.12):
    /// Φ(x) = φ(x)/|x| · (1 − 1/x² + 3/x⁴ − 15/x⁶ + 105/x⁸ − 945/x¹⁰ + …).
    fn log_ndtr_asymptotic(x: f64) -> f64 {
        let u = 1.0 / (x * x);
        let mut term = 1.0;
        let mut s = 0.0;
        for n in 1..=15 {
            term *= -((2 * n - 1) as f64) * u;
            s += term;
        }
        -0.5 * x * x - LN_SQRT_2PI - (-x).ln() + s.ln_1p()
    }

    #[test]
    fn log_ndtr_matches_reference_values_and_tail_asymptotics() {
        let mut max_rel: f64 = 0.0;
        // Tolerance 2e-15 times the condition number of ln Φ, which amplifies the rounding of
        // t = −x/√2: |x φ(x)/(Φ(x) ln Φ(x))| is ≤ 2 for x ≤ 0 and ≈ x² in the upper tail.
        for &(x, reference) in &LOG_NDTR_TABLE {
            let cond = if x > 0.0 { x * x } else { 1.0 };
            let rel = ((log_ndtr(x) - reference) / reference).abs();
            assert!(rel <= 2e-15 * cond, "ln Φ({x}): {} vs {reference}, relative {rel:e}", log_ndtr(x));
            max_rel = max_rel.max(rel / cond);
        }
        assert!(max_rel < 2e-15, "max relative error / condition {max_rel:e}");
        // Far tail: the asymptotic series (15 terms; truncation < 1e-20 for x ≤ −30).
        for x in [-30.0, -40.0, -100.0, -1e3, -1e6, -1e10] {
            assert_relative_eq!(log_ndtr(x), log_ndtr_asymptotic(x), epsilon = 0.0, max_relative = 2e-16);
        }
        // Sanity check against statrs where its cdf is far from underflow (statrs ~1e-10).
        let n = Normal::standard();
        for i in -2000..=600 {
            let x = i as f64 * 0.01 + 0.0007;
            assert_relative_eq!(log_ndtr(x), n.cdf(x).ln(), epsilon = 1e-15, max_relative = 1e-9);
        }
        // Continuity across the branch points x = −1.25√2 (lower-tail formula) and t = 28.
        for b in [-1.25 * std::f64::consts::SQRT_2, -28.0 * std::f64::consts::SQRT_2] {
            let (lo, hi) = (log_ndtr(b * (1.0 + 1e-15)), log_ndtr(b * (1.0 - 1e-15)));
            assert_relative_eq!(lo, hi, epsilon = 0.0, max_relative = 1e-14);
        }
        assert_eq!(log_ndtr(f64::INFINITY), 0.0);
        assert_eq!(log_ndtr(f64::NEG_INFINITY), f64::NEG_INFINITY);
        assert!(log_ndtr(f64::NAN).is_nan());
    }

    /// Closed-form derivatives of ln Φ: r = φ/Φ (φ/Φ by mpmath at 40 digits:
    /// `m.npdf(X)/m.ncdf(X)`), and r' = −r(x + r).
    #[test]
    fn log_ndtr_derivatives_match_closed_forms() {
        let table = [
            (-35.0, 35.028_524_970_596_688),
            (-13.051_690_089_010_876, 13.127_434_276_554_54),
            (-5.0, 5.186_503_967_125_842),
            (-1.0, 1.525_135_276_160_981),
        ];
        for (x, r) in table {
            let h = log_ndtr(hyper(x));
            assert_relative_eq!(h.eps1, r, epsilon = 0.0, max_relative = 1e-15);
            // x + r loses log10(r/(x + r)) digits to cancellation (3.4 at x = −35).
            assert_relative_eq!(h.eps1eps2, -r * (x + r), epsilon = 0.0, max_relative = 1e-12);
        }
        // Deep tail, where the asymptotic branch computes x + r without cancellation
        // (mpmath at 60 digits: r = m.npdf(X)/m.ncdf(X), −r (X + r) at X = −1e4).
        let h = log_ndtr(hyper(-1e4));
        assert_relative_eq!(h.eps1, 10_000.000_099_999_998, epsilon = 0.0, max_relative = 2.5e-16);
        assert_relative_eq!(h.eps1eps2, -0.999_999_990_000_000_6, epsilon = 0.0, max_relative = 2.5e-16);
        // Third derivative (Dual3) vs central difference of the HyperDual second derivative.
        for x in [-50.0, -6.0, -0.7, 1.5] {
            let d3 = log_ndtr(num_dual::Dual3_64::new(x, 1.0, 0.0, 0.0)).v3;
            let fd = five_point(|y| log_ndtr(hyper(y)).eps1eps2, x, 1e-3);
            assert_relative_eq!(d3, fd, epsilon = 1e-9, max_relative = 1e-6);
        }
    }

    #[test]
    fn log_diff_ndtr_matches_reference_values() {
        // Tolerance 2e-15 times the condition number (|a ∂_a f| + |b ∂_b f|)/|f| of
        // f = ln(Φ(b) − Φ(a)), which amplifies the rounding of the arguments (≈ 80 at
        // (−9, 9), ≈ 3e6 at (−30.000001, −30)).
        for &(a, b, reference) in &LOG_DIFF_NDTR_TABLE {
            let da = log_diff_ndtr(dual(a), Dual64::from(b)).eps;
            let db = log_diff_ndtr(Dual64::from(a), dual(b)).eps;
            let cond = (a * da).abs().max((b * db).abs()) * 2.0 / reference.abs();
            let v = log_diff_ndtr(a, b);
            let rel = ((v - reference) / reference).abs();
            assert!(rel <= 2e-15 * cond.max(1.0), "({a}, {b}): {v} vs {reference}, relative {rel:e}");
        }
        // Whole line, half lines and empty intervals.
        assert_eq!(log_diff_ndtr(f64::NEG_INFINITY, f64::INFINITY), 0.0);
        assert_eq!(log_diff_ndtr(1.0, 1.0), f64::NEG_INFINITY);
        assert_eq!(log_diff_ndtr(2.0, 1.0), f64::NEG_INFINITY);
        assert_eq!(log_diff_ndtr(f64::NEG_INFINITY, -40.0), log_ndtr(-40.0));
        assert_eq!(log_diff_ndtr(40.0, f64::INFINITY), log_ndtr(-40.0));
        // Huge arguments: no ∞ · 0 in the derivative terms.
        assert_relative_eq!(log_diff_ndtr(-3.0, 3e300), log_ndtr(3.0), epsilon = 0.0, max_relative = 1e-15);
        let d = log_diff_ndtr(Dual64::new(-1.0, 1.0), Dual64::new(1e300, 1.0));
        assert!(d.re.is_finite() && d.eps.is_finite());
        for x in [1e300, -1e300, 50.0, f64::INFINITY] {
            let h = erf(hyper(x));
            assert!(h.eps1 == 0.0 && h.eps1eps2 == 0.0, "erf at {x}: {h:?}");
            let h = log_ndtr(hyper(x));
            assert!(h.re.is_finite() || x < 0.0, "ln Φ at {x}: {h:?}");
            assert!(!h.eps1eps2.is_nan(), "ln Φ at {x}: {h:?}");
        }
        assert!(log_diff_ndtr(f64::NAN, 1.0).is_nan());
    }

    #[test]
    fn ndtr_and_log1mexp_identities() {
        // Φ(x) = exp(ln Φ(x)) and Φ(x) + Φ(−x) = 1 (identities), Φ(0) = ½. Both sides of the
        // first carry the rounding of x/√2 amplified by the condition number ≈ x² of Φ.
        assert_eq!(ndtr(0.0_f64), 0.5);
        for x in [-30.0_f64, -5.0, -1.3, -0.2, 0.4, 2.0, 7.0] {
            let tol = 4e-16 * (1.0 + x * x);
            assert_relative_eq!(ndtr(x), log_ndtr(x).exp(), epsilon = 0.0, max_relative = tol);
            assert_relative_eq!(ndtr(x) + ndtr(-x), 1.0, epsilon = 0.0, max_relative = 2e-16);
        }
        // ln(1 − e^u) on both sides of −ln 2: mpmath at 50 digits, `m.log(1 - m.exp(u))`.
        let table = [
            (-1e-9, -20.723265837446412),
            (-0.1, -2.3521684610440907),
            (-0.5, -0.9327521295671886),
            (-0.7, -0.6863410028083852),
            (-1.0, -0.4586751453870819),
            (-5.0, -0.006760749449488557),
            (-40.0, -4.248354255291589e-18),
        ];
        for (u, reference) in table {
            assert_relative_eq!(log1mexp(u), reference, epsilon = 0.0, max_relative = 4e-16);
        }
        assert_eq!(log1mexp(f64::NEG_INFINITY), 0.0);
    }

    /// Third derivatives through the Taylor lift: Dual3 (one variable) and the nesting
    /// Dual<HyperDual> (mixed) agree with differences of the HyperDual second derivative.
    #[test]
    fn third_derivatives_of_log_diff_ndtr() {
        use num_dual::{Dual, Dual3_64};
        for (a, b) in [(-41.0, -39.0), (-1.0, 0.5), (0.2, 0.3), (3.0, 9.0)] {
            let d3 = log_diff_ndtr(Dual3_64::new(a, 1.0, 0.0, 0.0), Dual3_64::from(b)).v3;
            let fd = five_point(|u| log_diff_ndtr(hyper(u), HyperDual64::from(b)).eps1eps2, a, 1e-4);
            assert_relative_eq!(d3, fd, epsilon = 1e-7, max_relative = 1e-6);
            // ∂³/∂a²∂b: outer Dual on b, HyperDual on a.
            let ad: Dual<HyperDual64> = Dual::new(HyperDual64::new(a, 1.0, 1.0, 0.0), HyperDual64::from(0.0));
            let bd: Dual<HyperDual64> = Dual::new(HyperDual64::from(b), HyperDual64::from(1.0));
            let mixed = log_diff_ndtr(ad, bd).eps.eps1eps2;
            let fd = five_point(|v| log_diff_ndtr(hyper(a), HyperDual64::from(v)).eps1eps2, b, 1e-4);
            assert_relative_eq!(mixed, fd, epsilon = 1e-7, max_relative = 1e-6);
        }
    }

    #[test]
    fn ln_gamma_matches_statrs() {
        // statrs::function::gamma::ln_gamma (Lanczos, ~1e-15).
        for x in [1e-8, 0.1, 0.5, 1.0, 1.5, 2.0, 2.5, 4.0, 7.3, 14.9, 15.0, 30.0, 171.5, 1e5] {
            let reference = statrs::function::gamma::ln_gamma(x);
            assert_relative_eq!(ln_gamma(x), reference, epsilon = 4e-15, max_relative = 1e-13);
        }
        // Derivative: digamma (statrs).
        for x in [0.3, 2.0, 4.5, 20.0] {
            let d = ln_gamma(dual(x)).eps;
            assert_relative_eq!(
                d,
                statrs::function::gamma::digamma(x),
                epsilon = 1e-14,
                max_relative = 1e-12
            );
        }
        assert!(ln_gamma(-1.0_f64).is_nan());
    }

    /// Five-point central difference (truncation O(h⁴)).
    fn five_point(f: impl Fn(f64) -> f64, x: f64, h: f64) -> f64 {
        (f(x - 2.0 * h) - 8.0 * f(x - h) + 8.0 * f(x + h) - f(x + 2.0 * h)) / (12.0 * h)
    }

    /// |ad − fd| ≤ 1e-6 |fd| plus the round-off of the five-point rule, ≈ 1.5 ε |f| / h, with
    /// a safety factor of ~300 (`f_scale` = |f| near x).
    fn close(ad: f64, fd: f64, f_scale: f64, h: f64) -> bool {
        (ad - fd).abs() <= 1e-6 * fd.abs() + 1e-13 * f_scale.max(1.0) / h
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]

        /// First derivatives by AD agree with five-point differences (relative 1e-6), and the
        /// HyperDual second derivative with differences of the AD first derivative.
        #[test]
        fn derivatives_match_finite_differences(x in -45.0..8.0_f64, w in 0.05..3.0_f64) {
            let h = 1e-3 * w.min(1.0);
            let ad = log_ndtr(dual(x)).eps;
            let fd = five_point(log_ndtr::<f64>, x, h);
            prop_assert!(close(ad, fd, log_ndtr(x).abs(), h), "log_ndtr' at {}: {} vs {}", x, ad, fd);
            let h2 = log_ndtr(hyper(x)).eps1eps2;
            let f2 = five_point(|y| log_ndtr(dual(y)).eps, x, h);
            prop_assert!(close(h2, f2, ad.abs(), h), "log_ndtr'' at {}: {} vs {}", x, h2, f2);
            // ∂/∂a and ∂/∂b of ln(Φ(b) − Φ(a)), on intervals in every position.
            for a in [x, -x - w, -0.5 * w] {
                let b = a + w;
                let da = log_diff_ndtr(dual(a), Dual64::from(b)).eps;
                let db = log_diff_ndtr(Dual64::from(a), dual(b)).eps;
                let fa = five_point(|u| log_diff_ndtr(u, b), a, h);
                let fb = five_point(|u| log_diff_ndtr(a, u), b, h);
                let f = log_diff_ndtr(a, b).abs();
                prop_assert!(close(da, fa, f, h), "d/da at ({}, {}): {} vs {}", a, b, da, fa);
                prop_assert!(close(db, fb, f, h), "d/db at ({}, {}): {} vs {}", a, b, db, fb);
                let hab = log_diff_ndtr(hyper(a), HyperDual64::new(b, 0.0, 0.0, 0.0)).eps1eps2;
                let fab = five_point(|u| log_diff_ndtr(dual(u), Dual64::from(b)).eps, a, h);
                prop_assert!(close(hab, fab, da.abs(), h), "d²/da² at ({}, {}): {} vs {}", a, b, hab, fab);
            }
        }
    }
}
