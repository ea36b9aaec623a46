//! The forward–backward sweeps of an exponential-family closure with jump conditions, as an
//! [`EffectiveAction`].
//!
//! Forward (`003_d2fc48a470e528fc.txt (II.46), (II.49)`): λ̇ = W(λ, t) from λ(t_0) = λ_0, and
//! at each measurement time λ(t_k+) = λ(t_k−) + E λ_k, where E places the multiplier of the
//! measured state x_i on the family's linear moment x_i. F(λ_1, …, λ_n) = Σ_k ΔF_k with
//! ΔF_k = F(λ(t_k+)) − F(λ(t_k−)) (`(II.51)`).
//!
//! Backward (`(II.47), (II.50)`): γ̇ + (∂W/∂λ)ᵀγ = 0 between measurements, γ(t_f) = 0,
//! γ(t_k−) = γ(t_k+) + (μ_k+ − μ_k−). The history is m(t) = μ(λ(t)) + γ(t) (`(II.48)`),
//! continuous across the jumps (`(II.44)`), and ∂F/∂λ_k = Eᵀ(μ_k+ + γ_k+) = Eᵀm(t_k)
//! (`(A.30)`).
//!
//! The ODE is integrated by the Dormand–Prince 5(4) pair with error control (Hairer, Nørsett,
//! Wanner, *Solving ODEs I*, 2nd ed., Sec. II.5, Table 5.2); the backward sweep is the exact
//! discrete adjoint of the accepted Runge–Kutta steps (the stages are stored), so the gradient
//! is that of the computed F to round-off and the continuous (II.47) to the ODE tolerance.
//! A step whose stage leaves the family's moment space (W not defined) is rejected and
//! retried smaller; a sweep that cannot proceed returns a non-finite F, which the dual solver
//! treats by backtracking (never a NaN path in a result).

use nalgebra::DMatrix;

use crate::action::dual::{ActionValue, EffectiveAction, History};
use crate::{Error, Result};

use super::drift::ClosureDrift;

const C: [f64; 7] = [0.0, 0.2, 0.3, 0.8, 8.0 / 9.0, 1.0, 1.0];
const A: [[f64; 6]; 7] = [
    [0.0; 6],
    [0.2, 0.0, 0.0, 0.0, 0.0, 0.0],
    [3.0 / 40.0, 9.0 / 40.0, 0.0, 0.0, 0.0, 0.0],
    [44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0, 0.0, 0.0, 0.0],
    [19372.0 / 6561.0, -25360.0 / 2187.0, 64448.0 / 6561.0, -212.0 / 729.0, 0.0, 0.0],
    [9017.0 / 3168.0, -355.0 / 33.0, 46732.0 / 5247.0, 49.0 / 176.0, -5103.0 / 18656.0, 0.0],
    [35.0 / 384.0, 0.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0],
];
/// Fifth-order weights (= the last row of A; the seventh stage only serves the error estimate).
const B: [f64; 6] = [35.0 / 384.0, 0.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0];
/// B − B̂ (fifth minus fourth order), seven stages.
const E: [f64; 7] =
    [71.0 / 57600.0, 0.0, -71.0 / 16695.0, 71.0 / 1920.0, -17253.0 / 339200.0, 22.0 / 525.0, -1.0 / 40.0];

/// One accepted Runge–Kutta step: start time, size and the six stage arguments.
#[derive(Debug, Clone)]
struct Step {
    t: f64,
    h: f64,
    stages: Vec<f64>,
}

/// A stored forward sweep.
#[derive(Debug, Clone)]
struct Forward {
    /// Steps of each interval between consecutive events.
    steps: Vec<Vec<Step>>,
    /// λ at every event before the jump (= after it at other events).
    lambda_minus: Vec<Vec<f64>>,
    /// μ(t_k−) and μ(t_k+), per measurement.
    mu_minus: Vec<Vec<f64>>,
    mu_plus: Vec<Vec<f64>>,
    /// μ (after the jump) and C at every event.
    mu: Vec<Vec<f64>>,
    cov: Vec<Vec<f64>>,
    /// F = Σ ΔF_k.
    f: f64,
}

/// The step sizes of a sweep, to replay it exactly (finite differences of a fixed
/// discretisation).
type Plan = Vec<Vec<f64>>;

/// The stage Jacobians ∂W/∂λ of every accepted step (6 R × R blocks), per interval, with the
/// step sizes: what the adjoint needs of a stored sweep.
type Jacobians = Vec<Vec<(f64, Vec<f64>)>>;

/// m(t) at every event and its derivatives ∂m/∂λ_j (`[j][event][moment]`).
type Tangents = Vec<Vec<Vec<f64>>>;

/// A reference sweep whose part before an event is reused (the multiplier perturbed there does
/// not change it, by causality): the forward sweep and its stage Jacobians.
struct Prefix<'r> {
    fw: &'r Forward,
    jac: &'r Jacobians,
    event: usize,
}

/// The closure effective action of one problem: the drift, the initial natural parameters, the
/// event times (t_0, output times, measurement times) and the measured moments.
pub struct ClosureAction<D: ClosureDrift> {
    drift: D,
    lambda0: Vec<f64>,
    /// Measurement times.
    meas_times: Vec<f64>,
    /// Event times of [`EffectiveAction::evaluate`]: t_0 and the measurement times.
    fit_events: Events,
    /// Event times of [`EffectiveAction::history`]: t_0, output and measurement times.
    out_events: Events,
    /// Moment index of each measured component (the matrix E).
    measured: Vec<usize>,
    rtol: f64,
    atol: f64,
    cache: Option<(Vec<f64>, Forward, Vec<Vec<f64>>)>,
    sweeps: usize,
    steps: usize,
}

impl<D: ClosureDrift> std::fmt::Debug for ClosureAction<D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClosureAction").field("measurements", &self.meas_times.len()).finish()
    }
}

#[derive(Debug, Clone)]
struct Events {
    times: Vec<f64>,
    meas: Vec<Option<usize>>,
}

impl Events {
    fn new(t0: f64, meas_times: &[f64], extra: &[f64]) -> Events {
        let m = crate::data::EventTimes::merge(meas_times, &[&[t0], extra].concat());
        Events { times: m.times, meas: m.measurement }
    }
}

/// How the forward sweep failed (a numerical outcome).
#[derive(Debug, Clone)]
struct SweepFailure;

impl<D: ClosureDrift> ClosureAction<D> {
    /// The action of `drift` from λ(t_0) = `lambda0`, measurements at `meas_times` of the
    /// moments `measured` (one index into M per measured component), history reported at
    /// `output_times` as well. `rtol`, `atol`: the Runge–Kutta tolerances.
    ///
    /// Errors ([`Error::InvalidOption`]): lengths, non-finite λ_0, a measurement before t_0,
    /// non-positive tolerances.
    #[allow(clippy::too_many_arguments)]
    pub fn try_new(
        drift: D,
        t0: f64,
        lambda0: Vec<f64>,
        meas_times: &[f64],
        measured: Vec<usize>,
        output_times: &[f64],
        rtol: f64,
        atol: f64,
    ) -> Result<Self> {
        let r = drift.n_params();
        crate::model::check_len("initial natural parameters", r, lambda0.len())?;
        if lambda0.iter().any(|v| !v.is_finite()) {
            return Err(Error::NonFinite { what: "initial natural parameters".into() });
        }
        if let Some(&a) = measured.iter().find(|&&a| a >= r) {
            return Err(Error::InvalidOption {
                name: "measured".into(),
                reason: format!("moment index {a} out of range ({r} moments)"),
            });
        }
        if meas_times.is_empty() || meas_times.iter().any(|&t| !(t >= t0 && t.is_finite())) {
            return Err(Error::InvalidOption {
                name: "t0".into(),
                reason: format!("the measurement times must be finite and not before t0 = {t0}"),
            });
        }
        for (name, v) in [("rtol", rtol), ("atol", atol)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::InvalidOption {
                    name: name.into(),
                    reason: format!("must be positive and finite, got {v}"),
                });
            }
        }
        let outs: Vec<f64> = output_times.iter().copied().filter(|&t| t >= t0).collect();
        Ok(ClosureAction {
            fit_events: Events::new(t0, meas_times, &[]),
            out_events: Events::new(t0, meas_times, &outs),
            drift,
            lambda0,
            meas_times: meas_times.to_vec(),
            measured,
            rtol,
            atol,
            cache: None,
            sweeps: 0,
            steps: 0,
        })
    }

    /// The drift.
    pub fn drift(&self) -> &D {
        &self.drift
    }

    /// Forward sweeps run so far.
    pub fn sweeps(&self) -> usize {
        self.sweeps
    }

    /// Runge–Kutta steps taken by all sweeps so far.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// The output (event) times of [`EffectiveAction::history`].
    pub fn output_times(&self) -> &[f64] {
        &self.out_events.times
    }

    fn check(&self, lambda: &[f64]) -> Result<()> {
        crate::model::check_len("multipliers", self.meas_times.len() * self.measured.len(), lambda.len())?;
        if lambda.iter().any(|v| !v.is_finite()) {
            return Err(Error::NonFinite { what: "multipliers".into() });
        }
        Ok(())
    }

    /// One Dormand–Prince step from (t, y) of size h: the new state, the error norm and the
    /// stage arguments; `None` when a stage is not realizable.
    fn rk_step(&self, t: f64, y: &[f64], h: f64) -> Option<(Vec<f64>, f64, Vec<f64>)> {
        let r = y.len();
        let mut k = vec![0.0; 7 * r];
        let mut stages = vec![0.0; 6 * r];
        let mut arg = vec![0.0; r];
        for i in 0..7 {
            for a in 0..r {
                arg[a] = y[a] + h * (0..i).map(|j| A[i][j] * k[j * r + a]).sum::<f64>();
            }
            if i < 6 {
                stages[i * r..(i + 1) * r].copy_from_slice(&arg);
            }
            let (ki, _) = k.split_at_mut((i + 1) * r);
            self.drift.w(t + C[i] * h, &arg, &mut ki[i * r..]).ok()?;
        }
        // The seventh stage argument is the fifth-order solution (FSAL).
        let y_new = arg;
        let mut err = 0.0;
        for a in 0..r {
            let e = h * (0..7).map(|i| E[i] * k[i * r + a]).sum::<f64>();
            let sc = self.atol + self.rtol * y[a].abs().max(y_new[a].abs());
            err += (e / sc) * (e / sc);
        }
        let err = (err / r as f64).sqrt();
        if !err.is_finite() || y_new.iter().any(|v| !v.is_finite()) {
            return None;
        }
        Some((y_new, err, stages))
    }

    /// Integrates from `t` to `t_end` (adaptive, or replaying `plan`), pushing the steps.
    fn integrate(
        &self,
        t: f64,
        t_end: f64,
        y: &mut Vec<f64>,
        h_guess: &mut f64,
        plan: Option<&[f64]>,
        steps: &mut Vec<Step>,
    ) -> std::result::Result<(), SweepFailure> {
        if let Some(plan) = plan {
            let mut tc = t;
            for &h in plan {
                let (y_new, _, stages) = self.rk_step(tc, y, h).ok_or(SweepFailure)?;
                steps.push(Step { t: tc, h, stages });
                *y = y_new;
                tc += h;
            }
            return Ok(());
        }
        let span = t_end - t;
        if span <= 0.0 {
            return Ok(());
        }
        let mut tc = t;
        let mut h = h_guess.min(span);
        let mut rejections = 0usize;
        while tc < t_end {
            let last = tc + h >= t_end - 1e-12 * span.max(1.0);
            let hh = if last { t_end - tc } else { h };
            match self.rk_step(tc, y, hh) {
                Some((y_new, err, stages)) if err <= 1.0 => {
                    steps.push(Step { t: tc, h: hh, stages });
                    *y = y_new;
                    tc = if last { t_end } else { tc + hh };
                    let fac = if err == 0.0 { 5.0 } else { (0.9 * err.powf(-0.2)).clamp(0.2, 5.0) };
                    h = hh * fac;
                    *h_guess = h;
                }
                Some((_, err, _)) => {
                    h = hh * (0.9 * err.powf(-0.2)).clamp(0.1, 0.9);
                    rejections += 1;
                }
                None => {
                    h = hh * 0.25;
                    rejections += 1;
                }
            }
            if h < 1e-13 * span.max(1.0) || rejections > 10_000 || steps.len() > 2_000_000 {
                return Err(SweepFailure);
            }
        }
        Ok(())
    }

    fn forward(
        &self,
        events: &Events,
        lambda: &[f64],
        plan: Option<&Plan>,
        prefix: Option<&Prefix<'_>>,
    ) -> std::result::Result<Forward, SweepFailure> {
        let s = self.measured.len();
        let ne = events.times.len();
        let span = events.times[ne - 1] - events.times[0];
        let mut h = if span > 0.0 { 1e-3 * span } else { 1.0 };
        let mut out = Forward {
            steps: Vec::with_capacity(ne.saturating_sub(1)),
            lambda_minus: Vec::with_capacity(ne),
            mu_minus: Vec::new(),
            mu_plus: Vec::new(),
            mu: Vec::with_capacity(ne),
            cov: Vec::with_capacity(ne),
            f: 0.0,
        };
        let (e0, mut y) = match prefix {
            Some(p) => {
                let e0 = p.event;
                let nm = events.meas[..e0].iter().flatten().count();
                out.steps.extend((0..e0).map(|_| Vec::new()));
                out.lambda_minus.extend_from_slice(&p.fw.lambda_minus[..e0]);
                out.mu.extend_from_slice(&p.fw.mu[..e0]);
                out.cov.extend_from_slice(&p.fw.cov[..e0]);
                out.mu_minus.extend_from_slice(&p.fw.mu_minus[..nm]);
                out.mu_plus.extend_from_slice(&p.fw.mu_plus[..nm]);
                out.f = f64::NAN;
                (e0, p.fw.lambda_minus[e0].clone())
            }
            None => (0, self.lambda0.clone()),
        };
        for e in e0..ne {
            if e > e0 {
                let mut steps = Vec::new();
                let p = plan.map(|p| p[e - 1].as_slice());
                self.integrate(events.times[e - 1], events.times[e], &mut y, &mut h, p, &mut steps)?;
                out.steps.push(steps);
            }
            out.lambda_minus.push(y.clone());
            let mut m = self.drift.moments(&y).map_err(|_| SweepFailure)?;
            if let Some(k) = events.meas[e] {
                let before = m;
                for (b, &a) in self.measured.iter().enumerate() {
                    y[a] += lambda[k * s + b];
                }
                m = self.drift.moments(&y).map_err(|_| SweepFailure)?;
                out.f += m.log_partition - before.log_partition;
                out.mu_minus.push(before.mean);
                out.mu_plus.push(m.mean.clone());
            }
            out.mu.push(m.mean);
            out.cov.push(m.covariance);
        }
        if prefix.is_none() && !out.f.is_finite() {
            return Err(SweepFailure);
        }
        Ok(out)
    }

    /// The discrete adjoint: γ at every event (after the jump at measurement events, i.e.
    /// γ(t_k+)), and the stage Jacobians of the steps it computed them for. With a prefix, the
    /// intervals before its event use the reference's Jacobians.
    fn backward(
        &self,
        events: &Events,
        fw: &Forward,
        prefix: Option<&Prefix<'_>>,
    ) -> std::result::Result<(Vec<Vec<f64>>, Jacobians), SweepFailure> {
        let r = self.drift.n_params();
        let ne = events.times.len();
        let mut gamma = vec![0.0; r];
        let mut out = vec![Vec::new(); ne];
        let mut w = vec![0.0; r];
        let mut jacs: Jacobians = vec![Vec::new(); ne.saturating_sub(1)];
        let mut kbar = vec![0.0; 6 * r];
        let mut ybar = vec![0.0; r];
        for e in (0..ne).rev() {
            out[e] = gamma.clone();
            if let Some(k) = events.meas[e] {
                for ((g, p), m) in gamma.iter_mut().zip(&fw.mu_plus[k]).zip(&fw.mu_minus[k]) {
                    *g += p - m;
                }
            }
            if e == 0 {
                break;
            }
            let reuse = prefix.filter(|p| e <= p.event);
            let n_steps = match reuse {
                Some(p) => p.jac[e - 1].len(),
                None => fw.steps[e - 1].len(),
            };
            for js in (0..n_steps).rev() {
                let (h, jac) = match reuse {
                    Some(p) => (p.jac[e - 1][js].0, p.jac[e - 1][js].1.clone()),
                    None => {
                        let step = &fw.steps[e - 1][js];
                        let mut jac = vec![0.0; 6 * r * r];
                        for i in 0..6 {
                            self.drift
                                .w_jacobian(
                                    step.t + C[i] * step.h,
                                    &step.stages[i * r..(i + 1) * r],
                                    &mut w,
                                    &mut jac[i * r * r..(i + 1) * r * r],
                                )
                                .map_err(|_| SweepFailure)?;
                        }
                        (step.h, jac)
                    }
                };
                for i in 0..6 {
                    for a in 0..r {
                        kbar[i * r + a] = h * B[i] * gamma[a];
                    }
                }
                for i in (0..6).rev() {
                    let ji = &jac[i * r * r..(i + 1) * r * r];
                    // Ȳ_i = J_iᵀ k̄_i.
                    for (b, yb) in ybar.iter_mut().enumerate() {
                        *yb = (0..r).map(|a| ji[a * r + b] * kbar[i * r + a]).sum();
                    }
                    for a in 0..r {
                        gamma[a] += ybar[a];
                    }
                    for j in 0..i {
                        let c = h * A[i][j];
                        if c != 0.0 {
                            for a in 0..r {
                                kbar[j * r + a] += c * ybar[a];
                            }
                        }
                    }
                }
                if reuse.is_none() {
                    jacs[e - 1].push((h, jac));
                }
            }
            if reuse.is_none() {
                jacs[e - 1].reverse();
            }
        }
        if out.iter().flatten().any(|v| !v.is_finite()) {
            return Err(SweepFailure);
        }
        Ok((out, jacs))
    }

    fn plan_of(fw: &Forward) -> Plan {
        fw.steps.iter().map(|s| s.iter().map(|st| st.h).collect()).collect()
    }

    fn z_of(&self, events: &Events, fw: &Forward, gamma: &[Vec<f64>]) -> Vec<f64> {
        let mut z = Vec::with_capacity(self.meas_times.len() * self.measured.len());
        for (e, m) in events.meas.iter().enumerate() {
            if m.is_some() {
                for &a in &self.measured {
                    z.push(fw.mu[e][a] + gamma[e][a]);
                }
            }
        }
        z
    }

    /// F and z at λ on `events`, optionally replaying `plan` and reusing a prefix.
    fn value(
        &mut self,
        events: &Events,
        lambda: &[f64],
        plan: Option<&Plan>,
        prefix: Option<&Prefix<'_>>,
    ) -> std::result::Result<(Forward, Vec<Vec<f64>>, Jacobians), SweepFailure> {
        self.sweeps += 1;
        let fw = self.forward(events, lambda, plan, prefix)?;
        self.steps += fw.steps.iter().map(Vec::len).sum::<usize>();
        let (g, jac) = self.backward(events, &fw, prefix)?;
        Ok((fw, g, jac))
    }

    /// m(t) = μ + γ of all moments at every event.
    fn moments_at_events(fw: &Forward, gamma: &[Vec<f64>]) -> Vec<Vec<f64>> {
        fw.mu.iter().zip(gamma).map(|(mu, ga)| mu.iter().zip(ga).map(|(a, b)| a + b).collect()).collect()
    }

    /// ∂m(t)/∂λ_j at every event for every multiplier j by one-sided differences of the
    /// sweep with the reference's steps replayed and its part before t_j reused (causality):
    /// `out[j][event][moment]`.
    fn tangents(
        &mut self,
        events: &Events,
        lambda: &[f64],
    ) -> std::result::Result<(Vec<Vec<f64>>, Tangents), SweepFailure> {
        let (fw, g, jac) = self.value(events, lambda, None, None)?;
        let plan = Self::plan_of(&fw);
        let base = Self::moments_at_events(&fw, &g);
        let s = self.measured.len();
        let event_of: Vec<usize> = events.meas.iter().enumerate().filter_map(|(e, m)| m.map(|_| e)).collect();
        let mut out = Vec::with_capacity(lambda.len());
        let mut l = lambda.to_vec();
        for j in 0..lambda.len() {
            let step = 1e-6 * (1.0 + lambda[j].abs());
            l[j] = lambda[j] + step;
            let prefix = Prefix { fw: &fw, jac: &jac, event: event_of[j / s] };
            let (fp, gp, _) = self.value(events, &l, Some(&plan), Some(&prefix))?;
            l[j] = lambda[j];
            let mp = Self::moments_at_events(&fp, &gp);
            out.push(
                mp.iter()
                    .zip(&base)
                    .map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y) / step).collect())
                    .collect(),
            );
        }
        Ok((base, out))
    }

    /// The history m(t) = μ(λ(t)) + γ(t) of all moments at the output times, with μ(t)
    /// separately (`003_d2fc48a470e528fc.txt (II.48)`): (times, m, μ). Errors when the sweep
    /// fails at λ.
    #[allow(clippy::type_complexity)]
    pub fn moment_paths(&mut self, lambda: &[f64]) -> Result<(Vec<f64>, Vec<Vec<f64>>, Vec<Vec<f64>>)> {
        self.check(lambda)?;
        let events = self.out_events.clone();
        let (fw, g, _) = self.value(&events, lambda, None, None).map_err(|_| self.failed())?;
        Ok((events.times, Self::moments_at_events(&fw, &g), fw.mu))
    }

    fn failed(&self) -> Error {
        Error::InvalidOption {
            name: "closure".into(),
            reason: "the closure sweep left the family's moment space (unrealizable moments)".into(),
        }
    }
}

impl<D: ClosureDrift> EffectiveAction for ClosureAction<D> {
    fn measurement_times(&self) -> &[f64] {
        &self.meas_times
    }

    fn output_dim(&self) -> usize {
        self.measured.len()
    }

    /// F(λ) = Σ ΔF_k (`(II.51)`) and z_k = Eᵀ(μ_k+ + γ_k+) (`(A.30)`); a sweep that leaves the
    /// moment space gives F = NaN.
    fn evaluate(&mut self, lambda: &[f64]) -> Result<ActionValue> {
        self.check(lambda)?;
        if let Some((l, fw, g)) = &self.cache {
            if l.as_slice() == lambda {
                return Ok(ActionValue { value: fw.f, z: self.z_of(&self.fit_events, fw, g) });
            }
        }
        let events = self.fit_events.clone();
        match self.value(&events, lambda, None, None) {
            Ok((fw, g, _)) => {
                let z = self.z_of(&events, &fw, &g);
                let value = fw.f;
                self.cache = Some((lambda.to_vec(), fw, g));
                Ok(ActionValue { value, z })
            }
            Err(SweepFailure) => Ok(ActionValue { value: f64::NAN, z: vec![f64::NAN; lambda.len()] }),
        }
    }

    /// ∇²F = ∂z/∂λ by one-sided differences (step 10⁻⁶(1 + |λ_j|)) of the adjoint gradient with
    /// the steps of the sweep at λ replayed (a fixed discretisation, so the differences are
    /// accurate to ~10⁻⁶ relative) and, by causality, the sweep before t_j reused; symmetrised.
    fn hessian(&mut self, lambda: &[f64]) -> Result<DMatrix<f64>> {
        self.check(lambda)?;
        let events = self.fit_events.clone();
        let (_, tangents) = self.tangents(&events, lambda).map_err(|_| self.failed())?;
        let m = lambda.len();
        let event_of: Vec<usize> =
            events.meas.iter().enumerate().filter_map(|(e, mm)| mm.map(|_| e)).collect();
        let s = self.measured.len();
        let h = DMatrix::from_fn(m, m, |i, j| tangents[j][event_of[i / s]][self.measured[i % s]]);
        Ok((&h + h.transpose()) * 0.5)
    }

    /// m(t) of every state at the output times (`(II.48)`); the variance is m_{x²} − m_x² when
    /// the family has the square moments; `cross` (Cov(x_i(τ), Z_j) = ∂m_{x_i}(τ)/∂λ_j) by
    /// the differences of [`EffectiveAction::hessian`].
    fn history(&mut self, lambda: &[f64], cross: bool) -> Result<History> {
        self.check(lambda)?;
        let n = self.drift.state_dim();
        let events = self.out_events.clone();
        let lin: Vec<usize> = (0..n)
            .map(|i| {
                self.drift.linear_index(i).ok_or_else(|| Error::InvalidOption {
                    name: "closure".into(),
                    reason: format!("the family has no linear moment of state {i}"),
                })
            })
            .collect::<Result<_>>()?;
        let (m, cr) = if cross {
            let (m, t) = self.tangents(&events, lambda).map_err(|_| self.failed())?;
            let nm = lambda.len();
            let cr =
                (0..m.len()).map(|e| DMatrix::from_fn(n, nm, |i, j| t[j][e][lin[i]])).collect::<Vec<_>>();
            (m, Some(cr))
        } else {
            let (fw, g, _) = self.value(&events, lambda, None, None).map_err(|_| self.failed())?;
            (Self::moments_at_events(&fw, &g), None)
        };
        let sq: Vec<Option<usize>> = (0..n).map(|i| self.drift.square_index(i)).collect();
        let mean: Vec<Vec<f64>> = m.iter().map(|mt| lin.iter().map(|&a| mt[a]).collect()).collect();
        let variance = m
            .iter()
            .map(|mt| {
                (0..n)
                    .map(|i| sq[i].map_or(f64::NAN, |q| (mt[q] - mt[lin[i]] * mt[lin[i]]).max(0.0)))
                    .collect()
            })
            .collect();
        Ok(History { times: events.times, mean, variance, cross: cr })
    }
}
