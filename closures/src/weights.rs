//! Normalising weights given by their logarithms without overflow (log-sum-exp).

/// Log-weights more than this below the largest get weight zero in [`normalize_log_weights`]:
/// e⁻⁵⁰ ≈ 1.9·10⁻²², so even a million such weights change the total by less than the
/// round-off of its largest term (most of a wide grid under a concentrated density), and the
/// nodes where a closure's weights are zero can be left out of its averages.
pub const NEGLIGIBLE_LOG_WEIGHT: f64 = -50.0;

/// Writes the normalised weights $w_i = e^{\ell_i - L}$ of the log-weights `log_w` into `out`
/// and returns $L = \ln \sum_i e^{\ell_i}$, computed as $m + \ln\sum_i e^{\ell_i - m}$ with
/// $m = \max_i \ell_i$ so that no exponential overflows. A NaN log-weight counts as a zero
/// weight, and so does a log-weight below $m$ + [`NEGLIGIBLE_LOG_WEIGHT`]. Returns `None` (and
/// leaves `out` unspecified) when every weight is zero or NaN, or when some log-weight is
/// $+\infty$.
///
/// # Panics
/// If `out` is shorter than `log_w`.
pub fn normalize_log_weights(log_w: &[f64], out: &mut [f64]) -> Option<f64> {
    // (A NaN fails the comparison and is passed over, as with f64::max; written as a comparison
    // so that the loop vectorises.)
    let max = log_w.iter().fold(f64::NEG_INFINITY, |m, &l| if l > m { l } else { m });
    if !max.is_finite() {
        return None;
    }
    // Branch-free, so that the loop vectorises: the exponential of every shifted log-weight
    // (clamped into exp_nonpositive's range), then zero where it is negligible or NaN.
    for (w, &l) in out.iter_mut().zip(log_w) {
        let y = l - max;
        let e = exp_nonpositive(y.max(NEGLIGIBLE_LOG_WEIGHT - 1.0));
        // (A NaN fails the comparison.)
        *w = if y >= NEGLIGIBLE_LOG_WEIGHT { e } else { 0.0 };
    }
    let total: f64 = out[..log_w.len()].iter().sum();
    for w in out[..log_w.len()].iter_mut() {
        *w /= total;
    }
    Some(max + total.ln())
}

/// e^x for −708 ≤ x ≤ 0 (the shifted log-weights), within 2 ulp of [`f64::exp`] (test
/// `exp_nonpositive_is_within_two_ulp_of_exp`, which sees at most 1), written without branches or calls so that a loop
/// over it vectorises. Cody–Waite reduction x = k ln 2 + r, |r| ≤ ½ln 2, with ln 2 split as in
/// fdlibm's `e_exp.c` (its high part has 11 trailing zero bits, so k·ln2_hi is exact), k
/// rounded by adding 1.5·2⁵² (round to nearest, k read from the low bits); e^r by its Taylor
/// polynomial of degree 13 (remainder < r¹⁴/14! < 5·10⁻¹⁸) in Horner form; 2^k by building the
/// exponent bits.
#[inline(always)]
fn exp_nonpositive(x: f64) -> f64 {
    // ln 2 = LN2_HI + LN2_LO (fdlibm's words 0x3fe62e42_fee00000 and 0x3dea39ef_35793c76).
    const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000);
    const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76);
    const SHIFT: f64 = 6_755_399_441_055_744.0;
    let t = x * std::f64::consts::LOG2_E + SHIFT;
    let kf = t - SHIFT;
    let k = (t.to_bits() as i64).wrapping_sub(SHIFT.to_bits() as i64);
    let r = (x - kf * LN2_HI) - kf * LN2_LO;
    // 1/j! for j = 13 down to 2.
    const C: [f64; 12] = [
        1.0 / 6_227_020_800.0,
        1.0 / 479_001_600.0,
        1.0 / 39_916_800.0,
        1.0 / 3_628_800.0,
        1.0 / 362_880.0,
        1.0 / 40_320.0,
        1.0 / 5_040.0,
        1.0 / 720.0,
        1.0 / 120.0,
        1.0 / 24.0,
        1.0 / 6.0,
        0.5,
    ];
    let mut p = C[0];
    for &c in &C[1..] {
        p = p * r + c;
    }
    let er = 1.0 + r * (1.0 + r * p);
    er * f64::from_bits(((k + 1023) as u64) << 52)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn matches_the_direct_formula_and_survives_huge_log_weights() {
        // Direct: weights (1, 2, 3)/6 and ln 6.
        let mut w = [0.0; 3];
        let l = normalize_log_weights(&[0.0, 2f64.ln(), 3f64.ln()], &mut w).unwrap();
        assert_relative_eq!(l, 6f64.ln(), epsilon = 1e-15);
        for (a, b) in w.iter().zip([1.0 / 6.0, 2.0 / 6.0, 3.0 / 6.0]) {
            assert_relative_eq!(*a, b, epsilon = 1e-15);
        }
        // Shifted by 1e4 (exp would overflow): same weights, L shifted by 1e4.
        let l = normalize_log_weights(&[1e4, 1e4 + 2f64.ln(), 1e4 + 3f64.ln()], &mut w).unwrap();
        assert_relative_eq!(l, 1e4 + 6f64.ln(), max_relative = 1e-15);
        assert_relative_eq!(w[2], 0.5, epsilon = 1e-12);
        // NaN is a zero weight; all −∞ or NaN is None.
        let l = normalize_log_weights(&[f64::NAN, 0.0], &mut w[..2]).unwrap();
        assert_eq!((l, w[0], w[1]), (0.0, 0.0, 1.0));
        assert!(normalize_log_weights(&[f64::NEG_INFINITY, f64::NAN], &mut w[..2]).is_none());
        assert!(normalize_log_weights(&[f64::INFINITY], &mut w[..1]).is_none());
    }

    #[test]
    fn exp_nonpositive_is_within_two_ulp_of_exp() {
        // A dense sweep of the log-weights' range (and of the whole range it is valid on),
        // including the reduction's boundaries k ln 2 ± ½ln 2 and 0.
        let mut worst: f64 = 0.0;
        let n = 2_000_000;
        for i in 0..=n {
            for x in [-51.0 * i as f64 / n as f64, -708.0 * i as f64 / n as f64] {
                let (a, b) = (exp_nonpositive(x), x.exp());
                worst = worst.max((a - b).abs() / (b * f64::EPSILON));
            }
        }
        for k in 0..75 {
            let x = -(k as f64 + 0.5) * std::f64::consts::LN_2;
            for y in [x, x.next_up(), x.next_down()] {
                let (a, b) = (exp_nonpositive(y), y.exp());
                worst = worst.max((a - b).abs() / (b * f64::EPSILON));
            }
        }
        assert_eq!(exp_nonpositive(0.0), 1.0);
        assert!(worst <= 2.0, "max error {worst} ulp");
    }

    #[test]
    fn negligible_weights_are_zero_and_the_rest_unchanged() {
        // 0, −49 and −51 below the largest: e⁻⁴⁹ is kept, e⁻⁵¹ is zero; L as if it were kept
        // (to round-off).
        let logs = [0.0, -49.0, -51.0];
        let mut w = [1.0; 3];
        let l = normalize_log_weights(&logs, &mut w).unwrap();
        let total = 1.0 + (-49f64).exp() + (-51f64).exp();
        assert_relative_eq!(l, total.ln(), epsilon = 1e-30);
        assert_relative_eq!(w[0], 1.0 / total, max_relative = 1e-15);
        assert_relative_eq!(w[1], (-49f64).exp() / total, max_relative = 1e-15);
        assert_eq!(w[2], 0.0);
    }
}
