//! Axis ranges and "nice" tick values (steps 1, 2 or 5 × 10^k), and their labels.

/// A data range widened so that it has positive, finite length: a single value `v` becomes
/// `v ± max(|v|/10, 0.5)`; a non-finite range becomes `[0, 1]`.
pub(crate) fn widen(lo: f64, hi: f64) -> (f64, f64) {
    if !(lo.is_finite() && hi.is_finite()) || hi < lo {
        return (0.0, 1.0);
    }
    let span = hi - lo;
    if !span.is_finite() {
        // Beyond what can be drawn: keep the middle of the range (values outside are clipped).
        return (lo.max(-1e307), hi.min(1e307));
    }
    if span <= 1e-12 * lo.abs().max(hi.abs()).max(1e-300) {
        let d = (lo.abs() / 10.0).max(0.5);
        return (lo - d, hi + d);
    }
    (lo, hi)
}

/// The 1-2-5 step closest from above to `raw`: the smallest of {1, 2, 5, 10} × 10^k that is ≥ `raw`.
pub(crate) fn nice_step(raw: f64) -> f64 {
    if !(raw.is_finite() && raw > 0.0) {
        return 1.0;
    }
    let mag = 10f64.powf(raw.log10().floor());
    let f = raw / mag;
    let m = if f <= 1.0 + 1e-9 {
        1.0
    } else if f <= 2.0 + 1e-9 {
        2.0
    } else if f <= 5.0 + 1e-9 {
        5.0
    } else {
        10.0
    };
    m * mag
}

/// Tick positions inside `[lo, hi]` with a 1-2-5 step giving at most about `target` intervals
/// (at least 2 ticks for any range of positive length). Returns (ticks, step).
pub(crate) fn linear_ticks(lo: f64, hi: f64, target: usize) -> (Vec<f64>, f64) {
    let (lo, hi) = widen(lo, hi);
    let target = target.max(2) as f64;
    let mut step = nice_step((hi - lo) / target);
    loop {
        let ticks = ticks_with_step(lo, hi, step);
        if ticks.len() >= 2 || step < (hi - lo) * 1e-6 {
            return (ticks, step);
        }
        // Fewer than two multiples of the step inside the range: the next smaller 1-2-5 step.
        let mantissa = step / 10f64.powf(step.log10().floor());
        step *= if mantissa > 4.0 { 0.4 } else { 0.5 };
    }
}

fn ticks_with_step(lo: f64, hi: f64, step: f64) -> Vec<f64> {
    if !(lo.is_finite() && hi.is_finite() && step > 0.0) || (hi - lo) / step > 1e4 {
        return vec![];
    }
    let first = (lo / step - 1e-9).ceil() as i64;
    let last = (hi / step + 1e-9).floor() as i64;
    (first..=last.max(first - 1))
        .map(|k| {
            let v = k as f64 * step;
            // Snap tiny round-off (e.g. 3 * 0.1) to the decimal the label shows.
            if v.abs() < step * 1e-9 {
                0.0
            } else {
                v
            }
        })
        .collect()
}

/// Ticks for a logarithmic axis over `[lo, hi]` (both > 0), as values (not logarithms):
/// powers of ten when the range spans at least one decade (every k-th decade so that there are
/// at most about `target` ticks), otherwise the 1-2-5 ticks of the linear range.
pub(crate) fn log_ticks(lo: f64, hi: f64, target: usize) -> Vec<f64> {
    let (a, b) = (lo.log10(), hi.log10());
    if !(a.is_finite() && b.is_finite()) || b <= a {
        return vec![];
    }
    let (first, last) = ((a - 1e-9).ceil() as i64, (b + 1e-9).floor() as i64);
    if last - first >= 1 {
        let every = (((last - first) as f64 / target.max(2) as f64).ceil() as i64).max(1);
        return (first..=last).filter(|k| (k - first) % every == 0).map(|k| 10f64.powi(k as i32)).collect();
    }
    // Less than a decade: 1, 2, 5 multiples first, linear 1-2-5 ticks if those are too few.
    let mut t: Vec<f64> = (first - 1..=last)
        .flat_map(|k| [1.0, 2.0, 5.0].map(|m| m * 10f64.powi(k as i32)))
        .filter(|v| *v >= lo * (1.0 - 1e-9) && *v <= hi * (1.0 + 1e-9))
        .collect();
    if t.len() < 3 {
        t = linear_ticks(lo, hi, target).0.into_iter().filter(|v| *v > 0.0).collect();
    }
    t
}

/// Labels of linear ticks with the given step: as many decimals as the step needs, scientific
/// notation for very large or very small values, never "-0".
pub(crate) fn format_ticks(ticks: &[f64], step: f64) -> Vec<String> {
    let max_abs = ticks.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let scientific = max_abs >= 1e6 || (step < 1e-4 && max_abs < 1e-3);
    ticks
        .iter()
        .map(|&v| {
            if v == 0.0 {
                return "0".to_string();
            }
            if scientific {
                return format_sci(v);
            }
            let decimals = (-(step.log10() + 1e-9).floor()).max(0.0) as usize;
            let s = format!("{:.*}", decimals.min(12), v);
            if s.trim_start_matches('-').chars().all(|c| c == '0' || c == '.') {
                "0".to_string()
            } else {
                s
            }
        })
        .collect()
}

/// Labels of logarithmic ticks: plain decimals between 1e-4 and 1e5, otherwise `1e-6` style.
pub(crate) fn format_log_ticks(ticks: &[f64]) -> Vec<String> {
    ticks
        .iter()
        .map(|&v| {
            if (1e-4..1e5).contains(&v) {
                let decimals = (-(v.log10() + 1e-9).floor()).max(0.0) as usize;
                format!("{:.*}", decimals, v)
            } else {
                format_sci(v)
            }
        })
        .collect()
}

/// `2.5e-7`, `1e6`: the shortest mantissa with up to 3 significant digits.
fn format_sci(v: f64) -> String {
    let s = format!("{:.2e}", v);
    let (mant, exp) = s.split_once('e').unwrap_or((&s, "0"));
    let mant = mant.trim_end_matches('0').trim_end_matches('.');
    format!("{mant}e{exp}")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: &[f64], b: &[f64]) -> bool {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-12 * (1.0 + y.abs()))
    }

    #[test]
    fn nice_steps_are_1_2_5() {
        assert_eq!(nice_step(0.13), 0.2);
        assert_eq!(nice_step(1.0), 1.0);
        assert_eq!(nice_step(3.0), 5.0);
        assert_eq!(nice_step(7.0), 10.0);
        assert_eq!(nice_step(1800.0), 2000.0);
        assert!((nice_step(0.0004) - 0.0005).abs() < 1e-18);
    }

    #[test]
    fn linear_ticks_closed_cases() {
        // [0, 10] with about 5 intervals: step 2.
        let (t, s) = linear_ticks(0.0, 10.0, 5);
        assert_eq!(s, 2.0);
        assert!(close(&t, &[0.0, 2.0, 4.0, 6.0, 8.0, 10.0]));
        // [-1.3, 2.7], 8 intervals: raw 0.5 -> step 0.5, ticks -1.0 .. 2.5.
        let (t, s) = linear_ticks(-1.3, 2.7, 8);
        assert_eq!(s, 0.5);
        assert!(close(&t, &[-1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 2.0, 2.5]));
        assert_eq!(format_ticks(&t, s), ["-1.0", "-0.5", "0", "0.5", "1.0", "1.5", "2.0", "2.5"]);
        let (t, s) = linear_ticks(-1.2, 4.3, 6);
        assert_eq!(format_ticks(&t, s), ["-1", "0", "1", "2", "3", "4"]);
        let (t, s) = linear_ticks(0.0, 0.035, 4);
        assert_eq!(format_ticks(&t, s), ["0", "0.01", "0.02", "0.03"]);
        // A constant range is widened: 3 -> [2.5, 3.5].
        let (t, _) = linear_ticks(3.0, 3.0, 5);
        assert!(t.len() >= 2 && t.contains(&3.0));
        // A range between two multiples of the first step still gets two ticks.
        let (t, _) = linear_ticks(0.31, 0.39, 1);
        assert!(t.len() >= 2, "{t:?}");
        assert!(t.iter().all(|v| (0.31..=0.39).contains(v)));
        // Large values: scientific labels.
        let (t, s) = linear_ticks(0.0, 4e7, 4);
        assert_eq!(format_ticks(&t, s), ["0", "1e7", "2e7", "3e7", "4e7"]);
        // Non-finite input gives the unit range, no panic.
        let (t, _) = linear_ticks(f64::NAN, 1.0, 5);
        assert!(t.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn log_ticks_closed_cases() {
        assert!(close(&log_ticks(0.005, 200.0, 8), &[0.01, 0.1, 1.0, 10.0, 100.0]));
        assert_eq!(
            format_log_ticks(&[0.01, 0.1, 1.0, 100.0, 1e-6, 2e5]),
            ["0.01", "0.1", "1", "100", "1e-6", "2e5"]
        );
        // Less than a decade: 1-2-5 values when there are three of them, else linear ticks.
        assert!(close(&log_ticks(0.15, 2.5, 8), &[0.2, 0.5, 1.0, 2.0]));
        assert!(close(&log_ticks(1.5, 9.0, 8), &[2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]));
        // 1e-8 .. 1e8 with 4 ticks: every 4th decade.
        assert!(close(&log_ticks(1e-8, 1e8, 4), &[1e-8, 1e-4, 1.0, 1e4, 1e8]));
    }
}
