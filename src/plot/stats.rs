//! Order statistics for box plots and experiment summaries: type-7 quantiles and Tukey boxes.

use crate::{Error, Result};

/// The `p`-quantile of an ascending sample by linear interpolation between order statistics
/// (Hyndman & Fan 1996, definition 7; the default of numpy's `quantile` and R's `quantile`):
///
/// $$ h = (n-1)p, \qquad Q(p) = x_{(\lfloor h \rfloor)} + (h - \lfloor h \rfloor)\,
///    \big(x_{(\lfloor h \rfloor + 1)} - x_{(\lfloor h \rfloor)}\big) $$
///
/// with 0-based order statistics $x_{(0)} \le \dots \le x_{(n-1)}$.
///
/// # Errors
/// [`Error::InvalidOption`] when `sorted` is empty or not ascending, or `p` is not in [0, 1];
/// [`Error::NonFinite`] when a value is NaN or infinite.
pub fn quantile(sorted: &[f64], p: f64) -> Result<f64> {
    if !(0.0..=1.0).contains(&p) {
        return Err(Error::InvalidOption {
            name: "p".into(),
            reason: format!("quantile level {p} is not in [0, 1]"),
        });
    }
    if sorted.is_empty() {
        return Err(Error::InvalidOption { name: "sorted".into(), reason: "empty sample".into() });
    }
    if sorted.iter().any(|v| !v.is_finite()) {
        return Err(Error::NonFinite { what: "quantile sample".into() });
    }
    if sorted.windows(2).any(|w| w[1] < w[0]) {
        return Err(Error::InvalidOption {
            name: "sorted".into(),
            reason: "sample is not in ascending order".into(),
        });
    }
    let h = (sorted.len() - 1) as f64 * p;
    let lo = h.floor() as usize;
    let frac = h - lo as f64;
    if lo + 1 >= sorted.len() {
        return Ok(sorted[sorted.len() - 1]);
    }
    Ok(sorted[lo] + frac * (sorted[lo + 1] - sorted[lo]))
}

/// The five numbers and outliers of a Tukey box: quartiles by [`quantile`] (type 7), whiskers at
/// the most extreme observations within 1.5 IQR of the box (the matplotlib and R `boxplot`
/// convention), every observation beyond them an outlier.
#[derive(Debug, Clone, PartialEq)]
pub struct BoxStats {
    /// Number of finite observations used.
    pub n: usize,
    /// Number of values left out (NaN, infinite, or non-positive on a logarithmic axis).
    pub skipped: usize,
    /// First quartile.
    pub q1: f64,
    /// Median.
    pub median: f64,
    /// Third quartile.
    pub q3: f64,
    /// Lower whisker: the smallest observation ≥ q1 − 1.5 IQR.
    pub whisker_low: f64,
    /// Upper whisker: the largest observation ≤ q3 + 1.5 IQR.
    pub whisker_high: f64,
    /// Observations outside the whiskers, ascending.
    pub outliers: Vec<f64>,
}

impl BoxStats {
    /// Box statistics of the finite values of `values` (the others are counted in `skipped`).
    /// `None` when no value is finite.
    pub fn from_values(values: &[f64]) -> Option<BoxStats> {
        Self::from_values_where(values, |_| true)
    }

    /// As [`BoxStats::from_values`], also skipping finite values for which `keep` is false
    /// (e.g. non-positive values on a logarithmic axis).
    pub fn from_values_where(values: &[f64], keep: impl Fn(f64) -> bool) -> Option<BoxStats> {
        let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite() && keep(*x)).collect();
        let skipped = values.len() - v.len();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        // The sample is finite, sorted and non-empty, and the levels are in [0, 1]: these cannot fail.
        let q = |p: f64| quantile(&v, p).unwrap_or(f64::NAN);
        let (q1, median, q3) = (q(0.25), q(0.5), q(0.75));
        let iqr = q3 - q1;
        let (lo_fence, hi_fence) = (q1 - 1.5 * iqr, q3 + 1.5 * iqr);
        let whisker_low = v.iter().copied().find(|x| *x >= lo_fence).unwrap_or(q1);
        let whisker_high = v.iter().rev().copied().find(|x| *x <= hi_fence).unwrap_or(q3);
        let outliers = v.iter().copied().filter(|x| *x < whisker_low || *x > whisker_high).collect();
        Some(BoxStats { n: v.len(), skipped, q1, median, q3, whisker_low, whisker_high, outliers })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// Expected values by hand from the type-7 definition, h = (n − 1)p; they agree with
    /// `numpy.quantile(x, p)` (default method "linear").
    #[test]
    fn type7_quantiles_by_hand() {
        let x = [1.0, 2.0, 3.0, 4.0];
        // h = 3 * 0.25 = 0.75 -> 1 + 0.75 * (2 - 1)
        assert_relative_eq!(quantile(&x, 0.25).unwrap(), 1.75, epsilon = 1e-15);
        assert_relative_eq!(quantile(&x, 0.5).unwrap(), 2.5, epsilon = 1e-15);
        // h = 2.25 -> 3 + 0.25
        assert_relative_eq!(quantile(&x, 0.75).unwrap(), 3.25, epsilon = 1e-15);
        assert_eq!(quantile(&x, 0.0).unwrap(), 1.0);
        assert_eq!(quantile(&x, 1.0).unwrap(), 4.0);
        let y = [-3.0, 0.5, 2.0, 7.0, 10.0];
        // h = 4 * 0.1 = 0.4 -> -3 + 0.4 * 3.5 = -1.6
        assert_relative_eq!(quantile(&y, 0.1).unwrap(), -1.6, epsilon = 1e-14);
        // h = 4 * 0.9 = 3.6 -> 7 + 0.6 * 3 = 8.8
        assert_relative_eq!(quantile(&y, 0.9).unwrap(), 8.8, epsilon = 1e-14);
        assert_eq!(quantile(&[42.0], 0.3).unwrap(), 42.0);
    }

    #[test]
    fn quantile_rejects_bad_input() {
        assert!(quantile(&[], 0.5).is_err());
        assert!(quantile(&[1.0, 2.0], 1.5).is_err());
        assert!(quantile(&[1.0, 2.0], f64::NAN).is_err());
        assert!(quantile(&[2.0, 1.0], 0.5).is_err());
        assert!(matches!(quantile(&[1.0, f64::NAN], 0.5), Err(Error::NonFinite { .. })));
    }

    #[test]
    fn box_stats_with_outlier_and_skipped_values() {
        // 1..=9 and 30: q1 = x(2.25) = 3.25, median = 5.5, q3 = x(6.75) = 7.75, IQR = 4.5,
        // fences -3.5 and 14.5: whiskers 1 and 9, outlier 30.
        let mut v: Vec<f64> = (1..=9).map(f64::from).collect();
        v.push(30.0);
        v.push(f64::NAN);
        v.push(f64::NEG_INFINITY);
        let b = BoxStats::from_values(&v).unwrap();
        assert_eq!((b.n, b.skipped), (10, 2));
        assert_relative_eq!(b.q1, 3.25, epsilon = 1e-14);
        assert_relative_eq!(b.median, 5.5, epsilon = 1e-14);
        assert_relative_eq!(b.q3, 7.75, epsilon = 1e-14);
        assert_eq!((b.whisker_low, b.whisker_high), (1.0, 9.0));
        assert_eq!(b.outliers, vec![30.0]);
    }

    #[test]
    fn box_stats_degenerate() {
        assert!(BoxStats::from_values(&[]).is_none());
        assert!(BoxStats::from_values(&[f64::NAN, f64::INFINITY]).is_none());
        let b = BoxStats::from_values(&[2.0, 2.0, 2.0]).unwrap();
        assert_eq!((b.q1, b.median, b.q3, b.whisker_low, b.whisker_high), (2.0, 2.0, 2.0, 2.0, 2.0));
        assert!(b.outliers.is_empty());
        let pos = BoxStats::from_values_where(&[-1.0, 0.0, 1.0, 10.0], |x| x > 0.0).unwrap();
        assert_eq!((pos.n, pos.skipped), (2, 2));
    }
}
