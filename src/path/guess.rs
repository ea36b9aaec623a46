//! The smoothing-spline initial path of `000_74b95e149527c64e.txt` Sec. 4.1: a measured state
//! is guessed by a smoothing spline through its measurements, a state that is the derivative of
//! a measured one by the spline's derivative, any other state by zero.

use crate::data::{Dataset, StatePath};
use crate::model::Sde;
use crate::spline::{Smoothing, SmoothingSpline};
use crate::Result;

/// For each state i, the state j with ds_i/dt = s_j exactly (the drift component of s_i is the
/// state s_j itself, independent of t, θ and the other states), checked on the Jacobians of the
/// drifts at two points. Van der Pol: u̇ = v; Duffing: ż = x.
pub fn derivative_states<S: Sde + ?Sized>(sde: &S, theta: &[f64]) -> Vec<Option<usize>> {
    let d = sde.dims();
    let (ns, nx) = (d.states(), d.noisy);
    let mut found: Vec<Option<usize>> = vec![None; ns];
    let probes: [Vec<f64>; 2] = [
        (0..ns).map(|i| 0.37 + 0.11 * i as f64).collect(),
        (0..ns).map(|i| -0.83 + 0.29 * i as f64).collect(),
    ];
    for (pi, s) in probes.iter().enumerate() {
        let t = 0.3 + 1.7 * pi as f64;
        let (x, z) = s.split_at(nx);
        let f = sde.drift_jacobians(t, x, z, theta);
        let h = sde.clean_drift_jacobians(t, x, z, theta);
        for (i, slot) in found.iter_mut().enumerate() {
            let (value, row_x, row_z, row_th, dt) = if i < nx {
                (
                    f.value[i],
                    f.dx.row(i).iter().copied().collect::<Vec<f64>>(),
                    f.dz.row(i).iter().copied().collect::<Vec<f64>>(),
                    f.dtheta.row(i).amax(),
                    f.dt[i],
                )
            } else {
                let r = i - nx;
                (
                    h.value[r],
                    h.dx.row(r).iter().copied().collect(),
                    h.dz.row(r).iter().copied().collect(),
                    h.dtheta.row(r).amax(),
                    h.dt[r],
                )
            };
            let row: Vec<f64> = row_x.into_iter().chain(row_z).collect();
            let unit =
                (0..ns).find(|&j| row[j] == 1.0 && row.iter().enumerate().all(|(k, &v)| k == j || v == 0.0));
            let ok = unit.filter(|&j| row_th == 0.0 && dt == 0.0 && value == s[j]);
            *slot = if pi == 0 { ok } else { slot.filter(|&j| ok == Some(j)) };
        }
    }
    found
}

/// The initial path at `times`: for each state measured directly (output k measures state
/// `measured[k]`, indices into s = [x; z]), the GCV smoothing spline of its measurements
/// ([`SmoothingSpline`], linear outside the measurement range); for a state that is the
/// derivative of a measured one ([`derivative_states`]), the spline's derivative; zeros
/// otherwise. Outputs with fewer than three measurements fall back to linear interpolation
/// ([`super::interpolation_guess`]).
pub fn spline_guess<S: Sde + ?Sized>(
    sde: &S,
    theta: &[f64],
    measured: &[usize],
    data: &Dataset,
    times: &[f64],
) -> Result<StatePath> {
    let ns = sde.dims().states();
    let t0 = times.first().copied().unwrap_or(0.0);
    let linear = super::interpolation_guess(sde.state_names(), ns, measured, data, t0);
    let mut values: Vec<Vec<f64>> = times.iter().map(|&t| super::guess_on_times(&linear, t)).collect();
    let derivative_of = derivative_states(sde, theta);
    for (k, &s) in measured.iter().enumerate() {
        if s >= ns {
            continue;
        }
        let column: Vec<f64> = data.values.iter().map(|row| row[k]).collect();
        if column.iter().filter(|v| v.is_finite()).count() < 3 {
            continue;
        }
        let spline = SmoothingSpline::fit(&data.times, &column, Smoothing::Gcv)?;
        let points = spline.eval_sorted(times)?;
        for (row, p) in values.iter_mut().zip(&points) {
            row[s] = p.value;
            if let Some(j) = derivative_of[s] {
                if !measured.contains(&j) {
                    row[j] = p.first;
                }
            }
        }
    }
    Ok(StatePath { names: sde.state_names(), times: times.to_vec(), values, sd: None })
}
