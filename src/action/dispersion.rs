//! The ensemble dispersion of the mean-optimal estimate, written once for every
//! [`EffectiveAction`].
//!
//! Two independent routes (`003_d2fc48a470e528fc.txt` Sec. I.6):
//!
//! - **Hessian** (`(I.85)–(I.90)`): the Hessian of H_* = H_Z + ½Σ(r − z)ᵀR⁻¹(r − z) at the
//!   optimum is (∇²F)⁻¹ + R⁻¹ (Legendre duality, `(I.57)`), so the multi-time covariance is
//!   C_* = ((∇²F)⁻¹ + R⁻¹)⁻¹ = H − H_{·a}(R_a + H_aa)⁻¹H_{a·} with H = ∇²F and a the present
//!   data (a missing datum has R⁻¹ = 0, the remark after `(I.87)`). [`dispersion_from_hessian`]
//!   returns its diagonal blocks; [`posterior_variance`] applies the same formula to any state at
//!   any output time τ by treating it as an unmeasured "measurement" (R⁻¹ = 0), which needs the
//!   tilted-measure covariances Cov(x_i(τ), Z_m) of [`History::cross`].
//! - **Lagrange multiplier** (`(I.99)–(I.106)`): the constrained minimisation of H̃ with the
//!   multiplier λ̃ at t_k has the optimality condition λ_k = R_k⁻¹(r_k − z_k) + λ̃ (`(I.101)`),
//!   i.e. the dual problem with r_k shifted by R_k λ̃ (or, for a missing datum, λ_k fixed at λ̃);
//!   then C_*(t_k) = ∂z_k/∂λ̃ (`(I.104)`), taken by the central difference `(I.106)` with
//!   λ̃ = ±δ e_β (`(I.105)`). [`dispersion_by_multipliers`] re-solves the dual from λ* for each ±δ.

use nalgebra::DMatrix;

use crate::{Error, Result};

use super::dual::{maximize_dual, DualData, DualOptions, DualSolution, EffectiveAction, History};

/// (R_a + H_aa)⁻¹ for the present data `a`, by Cholesky; `None` when R_a + H_aa is not
/// positive definite.
fn inner_inverse(hessian: &DMatrix<f64>, data: &DualData, active: &[usize]) -> Option<DMatrix<f64>> {
    let na = active.len();
    let k = DMatrix::from_fn(na, na, |i, j| {
        hessian[(active[i], active[j])] + if i == j { data.variance[active[i]] } else { 0.0 }
    });
    Some(k.cholesky()?.inverse())
}

/// The dispersion C_*(t_k) (s × s) at every measurement time from ∇²F:
/// the diagonal blocks of ((∇²F)⁻¹ + R⁻¹)⁻¹ (`003_d2fc48a470e528fc.txt (I.85)–(I.90)`);
/// `None` when ∇²F + R is not positive definite on the present data (the dispersion is then
/// undefined). Errors: a Hessian of the wrong size.
pub fn dispersion_from_hessian(hessian: &DMatrix<f64>, data: &DualData) -> Result<Option<Vec<DMatrix<f64>>>> {
    let m = data.r.len();
    crate::model::check_len("hessian", m, hessian.nrows())?;
    let s = data.output_dim;
    let active = data.active();
    let Some(inv) = inner_inverse(hessian, data, &active) else { return Ok(None) };
    let ha = DMatrix::from_fn(m, active.len(), |i, j| hessian[(i, active[j])]);
    let c = hessian - &ha * inv * ha.transpose();
    Ok(Some((0..m / s).map(|k| c.view((k * s, k * s), (s, s)).into_owned()).collect()))
}

/// The posterior variance of every state at every time of `history`:
/// Var(x_i(τ)) − c_aᵀ(R_a + H_aa)⁻¹c_a with c = Cov(x_i(τ), Z_·) under the tilted measure and
/// H = ∇²F (the Hessian formula of `003_d2fc48a470e528fc.txt (I.85)–(I.90)` with x_i(τ) as an
/// unmeasured variable); `None` when ∇²F + R is not positive definite on the present data.
/// Errors when the history carries no cross-covariances.
pub fn posterior_variance(
    history: &History,
    hessian: &DMatrix<f64>,
    data: &DualData,
) -> Result<Option<Vec<Vec<f64>>>> {
    let cross = history.cross.as_ref().ok_or_else(|| Error::InvalidOption {
        name: "history".into(),
        reason: "the dispersion between measurement times needs the cross-covariances Cov(x(t), Z_k)".into(),
    })?;
    let active = data.active();
    let Some(inv) = inner_inverse(hessian, data, &active) else { return Ok(None) };
    Ok(Some(
        history
            .variance
            .iter()
            .zip(cross)
            .map(|(var, c)| {
                (0..var.len())
                    .map(|i| {
                        let ca = nalgebra::DVector::from_fn(active.len(), |j, _| c[(i, active[j])]);
                        var[i] - ca.dot(&(&inv * &ca))
                    })
                    .collect()
            })
            .collect(),
    ))
}

/// The dispersion C_*(t_k) at every measurement time by the Lagrange-multiplier finite
/// difference (`003_d2fc48a470e528fc.txt (I.99)–(I.106)`): for each k and component β the dual
/// is re-solved from λ* with λ̃ = ±δ e_β and C_αβ = (z_kα(+δ) − z_kα(−δ))/(2δ). `delta` is in
/// units of 1/Z; `None` takes δ = 10⁻³/√R_kβ (10⁻³ for a missing datum). Independent of ∇²F.
/// `None` when a re-solve does not converge.
///
/// Errors: misuse as [`maximize_dual`].
pub fn dispersion_by_multipliers<A: EffectiveAction + ?Sized>(
    action: &mut A,
    data: &DualData,
    solution: &DualSolution,
    options: &DualOptions,
    delta: Option<f64>,
) -> Result<Option<Vec<DMatrix<f64>>>> {
    let s = data.output_dim;
    let n = data.r.len() / s;
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        let mut c = DMatrix::zeros(s, s);
        for beta in 0..s {
            let m = k * s + beta;
            let present = !data.r[m].is_nan();
            let d = delta.unwrap_or(if present { 1e-3 / data.variance[m].sqrt() } else { 1e-3 });
            let mut zs = Vec::with_capacity(2);
            for sign in [1.0, -1.0] {
                let mut shifted = data.clone();
                let mut start = solution.lambda.clone();
                if present {
                    // λ_k = R⁻¹(r_k − z_k) + λ̃ ⇔ the datum r_k + R_k λ̃ (I.101).
                    shifted.r[m] += sign * d * data.variance[m];
                } else {
                    start[m] = sign * d;
                }
                let sol = maximize_dual(action, &shifted, options, Some(&start))?;
                if !sol.status.is_success() {
                    return Ok(None);
                }
                zs.push(sol.z);
            }
            for alpha in 0..s {
                c[(alpha, beta)] = (zs[0][k * s + alpha] - zs[1][k * s + alpha]) / (2.0 * d);
            }
        }
        out.push(c);
    }
    Ok(Some(out))
}
