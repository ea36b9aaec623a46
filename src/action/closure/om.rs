//! The double-exponential and KSP closures as moment-path problems (`003_d2fc48a470e528fc.txt`
//! (II.54)–(II.65)).
//!
//! With the double-exponential Ansatz (II.54)–(II.55) the effective action reduces to the
//! Onsager–Machlup-form action over moment paths m(t) (II.56), with Q(m) of (II.57):
//!
//! Γ[m] = K(m(t_0)) + ¼ ∫ (ṁ − V(m, t))ᵀ Q(m, t)⁻¹ (ṁ − V(m, t)) dt,
//! V = ⟨L*M⟩_{λ(m)} (II.3), Q_ij = ⟨(∇M_i)ᵀ D ∇M_j⟩ (II.57), D = ½GGᵀ.
//!
//! Family: the Gaussian family of a one-state model, M = (x, x²), parametrised by y = (μ, v)
//! (mean, variance; v > 0 is a bound of the NLP, which keeps every iterate realizable). In
//! these coordinates (ṁ − V) = J(ẏ − V_y) with J = ∂m/∂y, and Q_y = J⁻¹QJ⁻ᵀ
//! = diag(D, 4Dv) (from Q = D[[1, 2μ], [2μ, 4⟨x²⟩]]), so
//! ¼(ṁ − V)ᵀQ⁻¹(ṁ − V) = ¼[(μ̇ − ⟨f⟩)²/D + (v̇ − 2⟨f(x − μ)⟩ − 2D)²/(4Dv)],
//! the averages taken with the family's Gauss–Hermite nodes ([`Gaussian::nodes`]; for a drift
//! declared polynomial of degree d, ⌊(d + 1)/2⌋ + 1 nodes, which take them exactly, see
//! [`super::drift::gaussian_closure_rule`]).
//!
//! Initial term: K(m) = KL(N(μ, v) ‖ prior), the boundary term α(t_0)ᵀm(t_0) − F(λ(t_0)) + F(β_0)
//! of (II.59) integrated by parts, so that the smoothed initial state can move (with K the
//! constraint m(t_0) = m_0 written after (II.63) the smoothed initial law would be the prior;
//! the Ornstein–Uhlenbeck test against the RTS smoother confirms the KL term).
//!
//! Measurement terms:
//! - double-exponential closure (II.61): ½(μ(t_k) − r_k)²/R;
//! - KSP closure (II.64)–(II.65): c_k(m) = ½⟨(x − r_k)²⟩_m/R = ½[v + (μ − r_k)²]/R, the expected
//!   negative log-likelihood, linear in (⟨x⟩, ⟨x²⟩): ∂c_k/∂⟨x⟩ = −r_k/R, ∂c_k/∂⟨x²⟩ = ½R⁻¹,
//!   i.e. the adjoint jumps α_k− = α_k+ + R⁻¹r_k, A_k− = A_k+ − ½R⁻¹ of (II.63)–(II.65) with
//!   α = −∂Γ/∂m (the signs agree with the paper's jumps).
//!
//! Transcription: a grid containing t_0 and every measurement time, steps dividing each
//! spacing; the action by the midpoint rule on each piece (converges to (II.56) with O(h²)
//! error; no divergence term, this is a Rayleigh–Ritz action, not a path-integral measure);
//! variables y at the nodes; exact gradient and Hessian by dual numbers, per piece (4 × 4
//! dense blocks) and per node; solved by [`crate::nlp`].

use std::time::Instant;

use onsager_closures::Gaussian;
use serde::{Deserialize, Serialize};

use crate::data::StatePath;
use crate::error::check_positive;
use crate::estimate::{Details, EstimationProblem, Method, MethodRun, PathEstimate};
use crate::estimator::EstimatorOptions;
use crate::model::ad::{hessian_into, ScalarFn};
use crate::model::observation::StateMeasurement;
use crate::model::{Scalar, Sde};
use crate::nlp::{self, NlpOptions, NlpProblem};
use crate::{Error, Result};

use super::super::exact::gaussian_dual_data;
use super::drift::gaussian_closure_rule;
use super::drift::gaussian_prior;
use super::invalid;

/// The moment-path closures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MomentPathKind {
    /// The closure of the KSP smoother (`ksp-closure`, `(II.64)–(II.65)`).
    Ksp,
    /// The double-exponential closure (`double-exp-closure`, `(II.54)–(II.63)`).
    DoubleExponential,
}

impl MomentPathKind {
    /// The kind of a moment-path method (`ksp-closure`, `double-exp-closure`).
    pub fn of(method: Method) -> Option<MomentPathKind> {
        match method {
            Method::KspClosure => Some(MomentPathKind::Ksp),
            Method::DoubleExpClosure => Some(MomentPathKind::DoubleExponential),
            _ => None,
        }
    }

    /// The estimator's method.
    pub fn method(self) -> Method {
        match self {
            MomentPathKind::Ksp => Method::KspClosure,
            MomentPathKind::DoubleExponential => Method::DoubleExpClosure,
        }
    }

    /// The method's command-line name.
    pub fn method_name(self) -> &'static str {
        self.method().name()
    }
}

/// Options of [`moment_path_estimate`] (the options of `ksp-closure` and `double-exp-closure`).
#[non_exhaustive]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MomentPathOptions {
    /// Largest step of the transcription grid (each spacing between t0 and the measurement
    /// times is divided into ⌈spacing/step⌉ equal pieces). Default: the mean measurement
    /// spacing / 10.
    pub step: Option<f64>,
    /// Tolerance of the interior-point solver. Default 1e-9.
    pub tolerance: f64,
    /// Iteration limit of the interior-point solver. Default 500.
    pub max_iterations: usize,
    /// Gauss–Hermite points of the averages ⟨f⟩, ⟨f(x − μ)⟩ (at least 1). Default `None`:
    /// automatic, as [`super::GaussianFamily::gaussian_points`] (3 for a cubic drift, exact;
    /// 16 for a drift not declared polynomial).
    pub gaussian_points: Option<usize>,
}

impl Default for MomentPathOptions {
    fn default() -> Self {
        MomentPathOptions { step: None, tolerance: 1e-9, max_iterations: 500, gaussian_points: None }
    }
}

impl MomentPathOptions {
    /// The defaults.
    pub fn new() -> Self {
        Self::default()
    }

    /// Sets the grid step.
    pub fn with_step(mut self, step: f64) -> Self {
        self.step = Some(step);
        self
    }

    /// Sets the NLP tolerance.
    pub fn with_tolerance(mut self, tolerance: f64) -> Self {
        self.tolerance = tolerance;
        self
    }
}

impl EstimatorOptions for MomentPathOptions {
    /// `ksp-closure` or `double-exp-closure`: [`moment_path_estimate`].
    fn run<S: Sde + ?Sized>(
        &self,
        method: Method,
        problem: &EstimationProblem<'_, S, StateMeasurement>,
    ) -> Result<MethodRun> {
        let kind = MomentPathKind::of(method)
            .ok_or_else(|| invalid("method", format!("`{method}` is not a moment-path closure")))?;
        moment_path_estimate(problem, kind, self).map(MethodRun::from)
    }

    /// Checks a positive finite `step` and `tolerance`, at least one iteration and at least one
    /// Gauss–Hermite point.
    fn validate(&self) -> Result<()> {
        check_positive("step", self.step)?;
        check_positive("tolerance", self.tolerance)?;
        if self.max_iterations == 0 {
            return Err(invalid("max_iterations", "must be at least 1"));
        }
        if self.gaussian_points == Some(0) {
            return Err(invalid("gaussian_points", "must be at least 1"));
        }
        Ok(())
    }
}

/// The moment-path problem on its grid (one-state model, y = (μ, v) per node).
struct MomentPath<'a, S: Sde + ?Sized> {
    sde: &'a S,
    theta: Vec<f64>,
    /// D = ½G².
    d: f64,
    family: Gaussian,
    times: Vec<f64>,
    /// (node, r_k) of every finite measurement.
    measurements: Vec<(usize, f64)>,
    /// Measurement variance R.
    r_var: f64,
    /// Prior (mean, variance).
    prior: (f64, f64),
    ksp: bool,
    start: Vec<f64>,
}

/// The midpoint action of one piece [t_j, t_{j+1}] as a function of (μ_j, v_j, μ_{j+1}, v_{j+1}).
struct Piece<'b, 'a, S: Sde + ?Sized> {
    p: &'b MomentPath<'a, S>,
    j: usize,
}

impl<S: Sde + ?Sized> ScalarFn for Piece<'_, '_, S> {
    fn dim_in(&self) -> usize {
        4
    }
    fn eval<D: Scalar>(&self, w: &[D]) -> D {
        let p = self.p;
        let (ta, tb) = (p.times[self.j], p.times[self.j + 1]);
        let h = tb - ta;
        let mu = (w[0] + w[2]) * 0.5;
        let v = (w[1] + w[3]) * 0.5;
        let (mu_dot, v_dot) = ((w[2] - w[0]) / h, (w[3] - w[1]) / h);
        let nan = D::from(f64::NAN);
        let Ok(nodes) = p.family.nodes(&[mu], &[v]) else { return nan };
        let theta: Vec<D> = p.theta.iter().map(|&t| D::from(t)).collect();
        let t = D::from(0.5 * (ta + tb));
        let (mut f1, mut f2) = (D::from(0.0), D::from(0.0));
        let mut out = [D::from(0.0)];
        for (x, wk) in &nodes {
            p.sde.state_drift(t, x, &theta, &mut out);
            f1 += out[0] * *wk;
            f2 += out[0] * (x[0] - mu) * *wk;
        }
        let f2 = f2 * 2.0 + p.d * 2.0;
        let (e1, e2) = (mu_dot - f1, v_dot - f2);
        (e1 * e1 / p.d + e2 * e2 / (v * (4.0 * p.d))) * (0.25 * h)
    }
}

/// The node terms (initial KL term and measurement costs) of node i as a function of (μ, v).
struct NodeCost<'b, 'a, S: Sde + ?Sized> {
    p: &'b MomentPath<'a, S>,
    i: usize,
}

impl<S: Sde + ?Sized> ScalarFn for NodeCost<'_, '_, S> {
    fn dim_in(&self) -> usize {
        2
    }
    fn eval<D: Scalar>(&self, w: &[D]) -> D {
        let p = self.p;
        let (mu, v) = (w[0], w[1]);
        let mut c = D::from(0.0);
        if self.i == 0 {
            // KL(N(μ, v) ‖ N(m0, v0)) = ½[v/v0 + (μ − m0)²/v0 − 1 − ln(v/v0)].
            let (m0, v0) = p.prior;
            let dm = mu - m0;
            c += (v / v0 + dm * dm / v0 - 1.0 - (v / v0).ln()) * 0.5;
        }
        for &(_, r) in p.measurements.iter().filter(|(n, _)| *n == self.i) {
            let e = mu - r;
            c += e * e * (0.5 / p.r_var);
            if p.ksp {
                c += v * (0.5 / p.r_var);
            }
        }
        c
    }
}

impl<S: Sde + ?Sized> MomentPath<'_, S> {
    fn nodes_with_cost(&self) -> Vec<usize> {
        let mut v: Vec<usize> = std::iter::once(0).chain(self.measurements.iter().map(|m| m.0)).collect();
        v.dedup();
        v
    }
}

impl<S: Sde + ?Sized> NlpProblem for MomentPath<'_, S> {
    fn num_variables(&self) -> usize {
        2 * self.times.len()
    }
    fn num_constraints(&self) -> usize {
        0
    }
    fn bounds(&self, lower: &mut [f64], upper: &mut [f64]) {
        upper.fill(f64::INFINITY);
        for (i, l) in lower.iter_mut().enumerate() {
            *l = if i % 2 == 1 { 0.0 } else { f64::NEG_INFINITY };
        }
    }
    fn initial_point(&self, w: &mut [f64]) {
        w.copy_from_slice(&self.start);
    }
    fn objective(&mut self, w: &[f64]) -> f64 {
        let mut g = vec![0.0; w.len()];
        self.value_grad(w, &mut g)
    }
    fn gradient(&mut self, w: &[f64], grad: &mut [f64]) {
        self.value_grad(w, grad);
    }
    fn constraints(&mut self, _w: &[f64], _c: &mut [f64]) {}
    fn jacobian_structure(&self) -> Vec<(u32, u32)> {
        Vec::new()
    }
    fn jacobian_values(&mut self, _w: &[f64], _values: &mut [f64]) {}
    fn hessian_structure(&self) -> Vec<(u32, u32)> {
        let mut s: Vec<(u32, u32)> = Vec::new();
        let v = |i: usize| i as u32; // a moment path has far fewer than 2³² variables
        for j in 0..self.times.len() - 1 {
            for a in 0..4 {
                for b in 0..=a {
                    s.push((v(2 * j + a), v(2 * j + b)));
                }
            }
        }
        for i in self.nodes_with_cost() {
            s.extend([(v(2 * i), v(2 * i)), (v(2 * i + 1), v(2 * i)), (v(2 * i + 1), v(2 * i + 1))]);
        }
        s
    }
    fn hessian_values(&mut self, w: &[f64], obj_factor: f64, _lambda: &[f64], values: &mut [f64]) {
        let mut k = 0;
        let (mut g4, mut h4) = ([0.0; 4], [0.0; 16]);
        for j in 0..self.times.len() - 1 {
            hessian_into(&Piece { p: self, j }, &w[2 * j..2 * j + 4], &mut g4, &mut h4);
            for a in 0..4 {
                for b in 0..=a {
                    values[k] = obj_factor * h4[a + 4 * b];
                    k += 1;
                }
            }
        }
        let (mut g2, mut h2) = ([0.0; 2], [0.0; 4]);
        for i in self.nodes_with_cost() {
            hessian_into(&NodeCost { p: self, i }, &w[2 * i..2 * i + 2], &mut g2, &mut h2);
            values[k] = obj_factor * h2[0];
            values[k + 1] = obj_factor * h2[1];
            values[k + 2] = obj_factor * h2[3];
            k += 3;
        }
    }
}

impl<S: Sde + ?Sized> MomentPath<'_, S> {
    /// Objective value, gradient into `grad`.
    fn value_grad(&self, w: &[f64], grad: &mut [f64]) -> f64 {
        grad.fill(0.0);
        let mut f = 0.0;
        let (mut g4, mut h4) = ([0.0; 4], [0.0; 16]);
        for j in 0..self.times.len() - 1 {
            f += hessian_into(&Piece { p: self, j }, &w[2 * j..2 * j + 4], &mut g4, &mut h4);
            for a in 0..4 {
                grad[2 * j + a] += g4[a];
            }
        }
        let (mut g2, mut h2) = ([0.0; 2], [0.0; 4]);
        for i in self.nodes_with_cost() {
            f += hessian_into(&NodeCost { p: self, i }, &w[2 * i..2 * i + 2], &mut g2, &mut h2);
            grad[2 * i] += g2[0];
            grad[2 * i + 1] += g2[1];
        }
        f
    }
}

fn build<'a, S: Sde + ?Sized>(
    problem: &EstimationProblem<'a, S, StateMeasurement>,
    kind: MomentPathKind,
    options: &MomentPathOptions,
) -> Result<MomentPath<'a, S>> {
    options.validate()?;
    problem.validate()?;
    problem.observation.validate(problem.sde.dims(), problem.theta)?;
    let ksp = kind == MomentPathKind::Ksp;
    let dims = problem.sde.dims();
    if dims.states() != 1 || dims.noisy != 1 {
        return Err(invalid(
            "model",
            format!(
                "{} handles one-state noisy models only (this model has {} states)",
                kind.method_name(),
                dims.states()
            ),
        ));
    }
    if !problem.estimate.is_empty() {
        return Err(invalid("estimate", "the closures do not estimate parameters; θ is taken as given"));
    }
    let data = gaussian_dual_data(problem)?;
    let names = problem.sde.state_names();
    let prior = gaussian_prior(&problem.x0_prior[0], &names[0])?;
    let g = problem.sde.diffusion_matrix(problem.theta)?;
    let d = 0.5 * g[(0, 0)] * g[(0, 0)];
    let times = &problem.data.times;
    let t0 = problem.t0;
    let n = times.len();
    let t_last = times[n - 1];
    let step = match options.step {
        Some(s) => s,
        None if n > 1 => (t_last - times[0]) / (n - 1) as f64 / 10.0,
        None if t_last > t0 => (t_last - t0) / 10.0,
        None => 1.0,
    };
    if (t_last - t0) / step > 1e7 {
        return Err(invalid("step", format!("{step} gives too many grid nodes")));
    }
    let mut grid = vec![t0];
    let mut measurements = Vec::new();
    for (k, &tk) in times.iter().enumerate() {
        let ta = *grid.last().expect("non-empty");
        let gap = tk - ta;
        if gap > 1e-12 * (1.0 + tk.abs()) {
            let pieces = (gap / step - 1e-9).ceil().max(1.0) as usize;
            grid.extend(
                (1..=pieces).map(|i| if i == pieces { tk } else { ta + gap * i as f64 / pieces as f64 }),
            );
        }
        let r = data.r[k];
        if r.is_finite() {
            measurements.push((grid.len() - 1, r));
        }
    }
    // Only ⟨f⟩ and ⟨f(x − μ)⟩ go through the nodes: exact with ⌊(d + 1)/2⌋ + 1 points for a drift of
    // degree d (see `gaussian_closure_rule`).
    let rule = gaussian_closure_rule(problem.sde, 1, options.gaussian_points);
    let family = Gaussian::try_new(1)
        .and_then(|g| g.with_rule(rule))
        .map_err(|e| invalid("gaussian_points", e.to_string()))?;
    let r_var = data.variance[0];
    // Start: the data linearly interpolated (constant outside), variance R.
    let pts: Vec<(f64, f64)> = measurements.iter().map(|&(i, r)| (grid[i], r)).collect();
    let mut start = Vec::with_capacity(2 * grid.len());
    for &t in &grid {
        let mu = match pts.iter().position(|&(tp, _)| tp >= t) {
            None if pts.is_empty() => prior.0,
            None => pts[pts.len() - 1].1,
            Some(0) => pts[0].1,
            Some(i) => {
                let ((ta, ra), (tb, rb)) = (pts[i - 1], pts[i]);
                ra + (rb - ra) * (t - ta) / (tb - ta)
            }
        };
        start.extend([mu, r_var.min(prior.1)]);
    }
    Ok(MomentPath {
        sde: problem.sde,
        theta: problem.theta.to_vec(),
        d,
        family,
        times: grid,
        measurements,
        r_var,
        prior,
        ksp,
        start,
    })
}

/// The double-exponential (`double-exp-closure`, (II.61)) or KSP (`ksp-closure`,
/// (II.64)–(II.65)) closure estimate of a one-state model with Gaussian state measurements and a
/// Gaussian x0 prior, as a [`PathEstimate`] at the transcription grid's nodes: the mean μ(t)
/// and, as sd, √v(t), the closure's conditional variance (for the KSP closure the smoother's
/// variance; for the double-exponential closure the variance path that minimises the action
/// with no measurement term on it). Status and iterations are the interior-point solver's.
/// See the module documentation.
///
/// Errors ([`Error::InvalidOption`] unless noted): a non-Gaussian likelihood or prior, a model
/// with more than one state, parameters to estimate, data before `t0`, another closure kind,
/// invalid options; a singular diffusion ([`Error::SingularDiffusion`]).
pub fn moment_path_estimate<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    kind: MomentPathKind,
    options: &MomentPathOptions,
) -> Result<PathEstimate> {
    let start = Instant::now();
    let mut mp = build(problem, kind, options)?;
    let nlp_options = NlpOptions {
        tolerance: options.tolerance,
        // The acceptable level is never stricter than the requested one.
        acceptable_tolerance: NlpOptions::default().acceptable_tolerance.max(options.tolerance),
        max_iterations: options.max_iterations,
        ..NlpOptions::default()
    };
    let sol = nlp::solve(&mut mp, nlp_options).map_err(|e| Error::InvalidOption {
        name: "nlp".into(),
        reason: format!("{} failed: {e}", kind.method_name()),
    })?;
    let w = &sol.w;
    let path = StatePath {
        names: problem.sde.state_names(),
        times: mp.times.clone(),
        values: w.chunks(2).map(|c| vec![c[0]]).collect(),
        sd: Some(w.chunks(2).map(|c| vec![c[1].max(0.0).sqrt()]).collect()),
    };
    let mut g = vec![0.0; w.len()];
    let f = mp.value_grad(w, &mut g);
    let details = MomentPathDetails {
        closure: format!("{kind:?}"),
        action: f,
        grid_nodes: mp.times.len(),
        sd: "closure variance",
    };
    Ok(PathEstimate {
        method: kind.method(),
        path,
        theta_names: problem.sde.param_names(),
        theta: problem.theta.to_vec(),
        estimated: Vec::new(),
        theta_sd: None,
        status: sol.report.status,
        iterations: sol.report.iterations,
        solve_seconds: start.elapsed().as_secs_f64(),
        details: Details::new(details),
    })
}

/// The details of a moment-path closure's report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MomentPathDetails {
    /// `Ksp` or `DoubleExponential`.
    pub closure: String,
    /// The minimised action at the solution.
    pub action: f64,
    /// Nodes of the transcription grid.
    pub grid_nodes: usize,
    /// What the sd columns are: the closure's variance.
    pub sd: &'static str,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::Dataset;
    use crate::kalman::linear::{kalman_rts, LinearGaussianModel};
    use crate::model::library::{DoubleWell, Ou};
    use crate::model::observation::Noise;
    use crate::model::prior::Prior;
    use crate::model::Param;
    use crate::test_models::{cosine_data, gaussian_measurement};
    use nalgebra::{DMatrix, DVector};

    const OU_THETA: [f64; 2] = [1.0, 0.5];

    /// Deterministic OU data 0.6 cos(1.3 t) + 0.1 every 0.5 on [0.5, 5].
    fn ou_dataset() -> Dataset {
        let times: Vec<f64> = (1..=10).map(|k| 0.5 * k as f64).collect();
        cosine_data("y", &times, 0.6, 0.1).unwrap()
    }

    fn rts_distance(kind: MomentPathKind, step: f64) -> (f64, f64) {
        let ob = gaussian_measurement(0, 0.2);
        let data = ou_dataset();
        let priors = [Prior::flat(), Prior::flat()];
        let x0 = [Prior::gaussian(0.0, 0.5)];
        let problem = EstimationProblem {
            sde: &Ou,
            observation: &ob,
            theta: &OU_THETA,
            theta_prior: &priors,
            estimate: &[],
            x0_prior: &x0,
            z0_prior: &[],
            data: &data,
            t0: 0.0,
            seed: 0,
            max_memory: Default::default(),
        };
        let est = moment_path_estimate(&problem, kind, &MomentPathOptions::new().with_step(step)).unwrap();
        assert!(est.status.is_success(), "{:?}", est.status);
        let model = LinearGaussianModel::from_sde(
            &Ou,
            &OU_THETA,
            &ob,
            0.0,
            DVector::from_element(1, 0.0),
            DMatrix::from_element(1, 1, 0.25),
        )
        .unwrap();
        let kf = kalman_rts(&model, &data, &est.path.times).unwrap();
        let sd = est.path.sd.as_ref().unwrap();
        let (mut em, mut es): (f64, f64) = (0.0, 0.0);
        for (i, &t) in est.path.times.iter().enumerate() {
            let j = kf.index_of(t).unwrap();
            em = em.max((est.path.values[i][0] - kf.smoothed_mean[j][0]).abs());
            es = es.max((sd[i][0] - kf.smoothed_cov[j][(0, 0)].sqrt()).abs());
        }
        (em, es)
    }

    #[test]
    fn ou_closures_converge_to_the_rts_smoother() {
        for kind in [MomentPathKind::DoubleExponential, MomentPathKind::Ksp] {
            let (m1, s1) = rts_distance(kind, 0.05);
            let (m2, s2) = rts_distance(kind, 0.025);
            println!("{kind:?}: step 0.05: |Δmean| {m1:.3e} |Δsd| {s1:.3e}; step 0.025: {m2:.3e} {s2:.3e}");
            assert!(m1 < 1e-2 && m2 < m1 / 3.0, "mean: {m1} {m2}");
            if kind == MomentPathKind::Ksp {
                assert!(s1 < 1e-2 && s2 < s1 / 3.0, "sd: {s1} {s2}");
            }
        }
    }

    fn well_data() -> Dataset {
        let times: Vec<f64> = (1..=10).map(|k| k as f64).collect();
        let y = [-1.0, -0.9, -1.1, -0.2, 0.9, 1.0, 1.05, 0.95, 1.0, 1.1];
        Dataset::try_new(vec!["y".into()], times, y.iter().map(|&v| vec![v]).collect()).unwrap()
    }

    fn well_problem<'a>(
        ob: &'a StateMeasurement,
        data: &'a Dataset,
        priors: &'a [Prior],
        x0: &'a [Prior],
    ) -> EstimationProblem<'a, DoubleWell, StateMeasurement> {
        EstimationProblem {
            sde: &DoubleWell,
            observation: ob,
            theta: &[0.5],
            theta_prior: priors,
            estimate: &[],
            x0_prior: x0,
            z0_prior: &[],
            data,
            t0: 0.0,
            seed: 0,
            max_memory: Default::default(),
        }
    }

    #[test]
    fn gradient_and_hessian_match_finite_differences() {
        // Central differences of the objective (gradient) and of the gradient (Hessian), on the
        // double well (cubic drift) at a perturbed start point.
        let (ob, data) = (gaussian_measurement(0, 0.2), well_data());
        let (priors, x0) = ([Prior::flat()], [Prior::gaussian(-1.0, 0.3)]);
        let problem = well_problem(&ob, &data, &priors, &x0);
        for kind in [MomentPathKind::DoubleExponential, MomentPathKind::Ksp] {
            let mut mp = build(&problem, kind, &MomentPathOptions::new().with_step(0.5)).unwrap();
            let n = mp.num_variables();
            let mut w = vec![0.0; n];
            mp.initial_point(&mut w);
            for (i, wi) in w.iter_mut().enumerate() {
                *wi += 0.1 * ((i as f64) * 1.7).sin().abs() + if i % 2 == 1 { 0.05 } else { 0.0 };
            }
            let mut g = vec![0.0; n];
            mp.gradient(&w, &mut g);
            let structure = mp.hessian_structure();
            let mut vals = vec![0.0; structure.len()];
            mp.hessian_values(&w, 1.0, &[], &mut vals);
            let mut hess = DMatrix::<f64>::zeros(n, n);
            for (&(r, c), v) in structure.iter().zip(&vals) {
                hess[(r as usize, c as usize)] += v;
                if r != c {
                    hess[(c as usize, r as usize)] += v;
                }
            }
            let eps = 1e-6;
            for i in 0..n {
                let (mut wp, mut wm) = (w.clone(), w.clone());
                wp[i] += eps;
                wm[i] -= eps;
                let fd = (mp.objective(&wp) - mp.objective(&wm)) / (2.0 * eps);
                assert!((fd - g[i]).abs() < 1e-5 * (1.0 + g[i].abs()), "grad {i}: {fd} vs {}", g[i]);
                let (mut gp, mut gm) = (vec![0.0; n], vec![0.0; n]);
                mp.gradient(&wp, &mut gp);
                mp.gradient(&wm, &mut gm);
                for j in 0..n {
                    let fd = (gp[j] - gm[j]) / (2.0 * eps);
                    assert!(
                        (fd - hess[(j, i)]).abs() < 1e-4 * (1.0 + fd.abs()),
                        "hess ({j}, {i}): {fd} vs {}",
                        hess[(j, i)]
                    );
                }
            }
        }
    }

    #[test]
    fn double_well_runs_and_is_compared_with_the_exact_estimates() {
        use crate::action::{ksp_smoother, mean_optimal, ExactOptions, GridSpec};
        // R = 0.04, measurements every 1.0 crossing the wells; references: the exact
        // mean-optimal estimate (dual of the exact grid) and the exact KSP smoother.
        let (ob, data) = (gaussian_measurement(0, 0.2), well_data());
        let (priors, x0) = ([Prior::flat()], [Prior::gaussian(-1.0, 0.3)]);
        let problem = well_problem(&ob, &data, &priors, &x0);
        let exact_opts =
            ExactOptions::new(GridSpec::new_1d(-3.0, 3.0, 600)).with_dt(0.005).with_output_step(0.1);
        let exact = mean_optimal(&problem, &exact_opts).unwrap();
        let ksp = ksp_smoother(&problem, &exact_opts).unwrap();
        let rmse = |est: &PathEstimate, times: &[f64], reference: &[Vec<f64>]| {
            let mut s = 0.0;
            let mut n = 0;
            for (i, &t) in est.path.times.iter().enumerate() {
                if let Some(j) = times.iter().position(|&u| (u - t).abs() < 1e-9) {
                    s += (est.path.values[i][0] - reference[j][0]).powi(2);
                    n += 1;
                }
            }
            assert!(n > 50, "common times {n}");
            (s / n as f64).sqrt()
        };
        for kind in [MomentPathKind::DoubleExponential, MomentPathKind::Ksp] {
            let est = moment_path_estimate(&problem, kind, &MomentPathOptions::new()).unwrap();
            assert!(est.status.is_success(), "{kind:?}: {:?}", est.status);
            let (e_mo, e_ksp) = (
                rmse(&est, &exact.history.times, &exact.history.mean),
                rmse(&est, &ksp.times, &ksp.smoothed_mean),
            );
            println!(
                "{}: {} iterations, RMSE vs exact mean-optimal {e_mo:.4}, vs exact KSP {e_ksp:.4}",
                est.method, est.iterations
            );
            assert!(e_mo < 0.5 && e_ksp < 0.5);
        }
    }

    #[test]
    fn bad_input_is_a_clear_error() {
        let (ob, data) = (gaussian_measurement(0, 0.2), well_data());
        let priors = [Prior::flat()];
        let x0 = [Prior::gaussian(-1.0, 0.3)];
        let flat = [Prior::flat()];
        let problem = well_problem(&ob, &data, &priors, &x0);
        let o = MomentPathOptions::new();
        let is_invalid = |r: Result<PathEstimate>, what: &str| match r {
            Err(Error::InvalidOption { name, .. }) => assert_eq!(name, what),
            other => panic!("expected InvalidOption({what}), got {other:?}"),
        };
        is_invalid(moment_path_estimate(&problem, MomentPathKind::Ksp, &o.clone().with_step(-1.0)), "step");
        is_invalid(
            moment_path_estimate(&problem, MomentPathKind::Ksp, &o.clone().with_tolerance(0.0)),
            "tolerance",
        );
        let late = EstimationProblem { t0: 2.0, ..problem };
        is_invalid(moment_path_estimate(&late, MomentPathKind::Ksp, &o), "t0");
        let p2 = well_problem(&ob, &data, &priors, &flat);
        is_invalid(moment_path_estimate(&p2, MomentPathKind::Ksp, &o), "x0 prior");
        let student = StateMeasurement::new(
            vec![0],
            vec!["y".into()],
            Noise::StudentT { nu: Param::Fixed(4.0), scale: Param::Fixed(0.2) },
        );
        let p3 = well_problem(&student, &data, &priors, &x0);
        is_invalid(moment_path_estimate(&p3, MomentPathKind::DoubleExponential, &o), "likelihood");
    }
}
