//! Normalising weights given by their logarithms without overflow (log-sum-exp).

/// Log-weights more than this below the largest get weight zero in [`normalize_log_weights`]:
/// e⁻⁵⁰ ≈ 1.9·10⁻²², so even a million such weights change the total by less than the
/// round-off of its largest term, and their exponentials need not be computed (most of a wide
/// grid under a concentrated density).
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
    // (f64::max returns the other argument when one is NaN.)
    let max = log_w.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    normalize_log_weights_from_max(log_w, max, out)
}

/// [`normalize_log_weights`] for a caller that has the largest log-weight `max` at hand: it
/// must be the largest of the non-NaN entries of `log_w` (another value gives wrong weights).
///
/// # Panics
/// If `out` is shorter than `log_w`.
pub fn normalize_log_weights_from_max(log_w: &[f64], max: f64, out: &mut [f64]) -> Option<f64> {
    if !max.is_finite() {
        return None;
    }
    let mut total = 0.0;
    for (w, &l) in out.iter_mut().zip(log_w) {
        // (A NaN fails the comparison.)
        *w = if l - max >= NEGLIGIBLE_LOG_WEIGHT { (l - max).exp() } else { 0.0 };
        total += *w;
    }
    for w in out[..log_w.len()].iter_mut() {
        *w /= total;
    }
    Some(max + total.ln())
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
