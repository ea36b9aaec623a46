//! The scalar area-rule closure (`003_d2fc48a470e528fc.txt (II.17)–(II.35)`): one state, one
//! moment variable μ(t) = ⟨M⟩ with M = x, one scalar measured variable Z.
//!
//! # Family
//!
//! The trial densities are the exponential tilts of a reference,
//! P(x; μ) ∝ exp(θ(μ) x) p_*(x) (`(II.36)` with R = 1), with p_* the model's stationary density
//! p_*(x) ∝ exp(∫ f(x, t₀) dx / D) of a one-state model with constant diffusion D = ½g² (every
//! one-state drift is a gradient), on the nodes of a fixed box of Gauss–Legendre panels (the
//! [`Exponential`] family of the exponential closure, with the reference as its log-density).
//! The moment equation (II.18) between measurements is μ̇ = V(μ) = ⟨f⟩_μ (the Rayleigh–Ritz drift
//! (II.3) with M = x), integrated in the natural parameter, θ̇ = V/C (`(II.46)`, the
//! [`ExponentialDrift`] with the single moment x); ζ(μ) = ⟨Z⟩_μ and C^Z(μ) = Cov_μ(Z, M)
//! (`(II.5)–(II.6)`).
//!
//! # Jumps
//!
//! - General Z ([`JumpRule::Area`]): the first area rule (II.19) as the ODE dμ/dλ = C^Z(μ)
//!   (`(II.27)`, in θ: dθ/dλ = C^Z/C) from λ = 0 to λ_k, and the second area rule (II.23) as
//!   d(ΔF)/dλ = ζ(μ(λ)) (`(II.29)`), by classical Runge–Kutta with `jump_steps` steps;
//!   F_Z = Σ_k (ΔF)_k (`(II.22)`).
//! - Z = M ([`JumpRule::Explicit`]): λ(μ) is the natural parameter θ and F(λ) the log-partition
//!   function log N(θ) (`(II.31)–(II.33)`: F′ = μ, F″ = C), so the jumps are the differences
//!   θ⁺ = θ⁻ + λ_k (`(II.34)`) and (ΔF)_k = log N(θ⁺) − log N(θ⁻) (`(II.35)`).
//!
//! # Adjoint
//!
//! The adjoint α(t) = ∂(Σ_{t_j > t} ΔF_j)/∂μ(t) obeys α̇ = −(∂V/∂μ) α between measurements
//! (`(II.16)` with k = 0, h = 0) and the backward jump (II.21) at t_k; z_k = ζ_k⁺ + C_k^{Z+}α_k⁺
//! = ∂F_Z/∂λ_k. The scalar linear adjoint ODE is solved by its integrating factor: the forward
//! sweep integrates the variational equation δθ̇ = (∂W/∂θ) δθ with the same Runge–Kutta stages,
//! so ∂μ(t_k)/∂μ(τ) = C(t_k) ∂θ(t_k)/∂θ(τ) / C(τ) and α(τ) = α_k⁻ ∂μ(t_k)/∂μ(τ). The history of
//! the state is x̂ = μ + Cα (`(II.4)` with Z = x); the variance column under the tilted measure
//! is the closure density's C(μ(τ)) (exact for the linear-Gaussian case). ∇²F and the cross-covariances ∂x̂(τ)/∂λ_m of the dispersion are central
//! differences of the sweeps, which are smooth in λ (fixed steps).
//!
//! Between measurements the steps are fixed (at most `max_step`, output times on step
//! boundaries), so F is a smooth function of λ and the finite differences are accurate to
//! round-off.

use serde::{Deserialize, Serialize};
use std::time::Instant;

use nalgebra::DMatrix;
use onsager_closures::{Exponential, Polynomial, Reference};

use super::drift::{gaussian_prior, ClosureDrift, ExponentialDrift};
use super::{check_box_covers_data, default_domain, invalid, output_times, ClosureOptions, FailureAt};
use crate::action::continuation::BranchRule;
use crate::action::dual::{
    ActionValue, DualData, DualOptions, EffectiveAction, History, SweepFailure, Swept, Work,
};
use crate::action::exact::gaussian_dual_data;
use crate::action::mean_optimal::{self, DualStart, Plan};
use crate::estimate::{EstimationProblem, Method, MethodRun, PathEstimate};
use crate::estimator::EstimatorOptions;
use crate::model::observation::StateMeasurement;
use crate::model::Sde;
use crate::Result;

/// How the jumps at the measurement times are computed (option `jumps`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum JumpRule {
    /// Z = M: the differences of the explicit λ(μ) and F(λ) (`003_d2fc48a470e528fc.txt
    /// (II.34)–(II.35)`).
    #[default]
    Explicit,
    /// The area rules (II.19), (II.23) integrated as ODEs in λ (`(II.27)`, `(II.29)`); needed
    /// when Z ≠ M, the same answer (to the Runge–Kutta error in λ) when Z = M.
    Area,
}

/// Options of the scalar area-rule closure (`area-closure`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
#[non_exhaustive]
pub struct AreaClosure {
    /// Support [a, b] of the family (its quadrature box); `None`: the range of the data and of
    /// the initial prior (mean ± 5 sd), widened by half its width plus 1 on each side. It must
    /// cover every datum ([`Error::InvalidOption`](crate::Error) otherwise): the family is
    /// truncated to it.
    pub domain: Option<(f64, f64)>,
    /// Gauss–Legendre panels (8 points each) on the box. Default 12.
    pub panels: usize,
    /// The largest Runge–Kutta step between measurements. Default 0.01.
    pub max_step: f64,
    /// How the jumps are computed: `explicit` (Z = M, the default) or `area`.
    pub jumps: JumpRule,
    /// Runge–Kutta steps in λ of one jump with `jumps = "area"`. Default 32.
    pub jump_steps: usize,
    /// Step of the output grid. Default: the mean measurement spacing / 10.
    pub output_step: Option<f64>,
    /// Further output times (finite, ≥ t0).
    pub extra_times: Vec<f64>,
    /// Whether to compute the ensemble dispersion (sd columns, `(I.85)–(I.90)`); otherwise the
    /// tilted variance of the closure. Default true.
    pub dispersion: bool,
    /// Which stationary point of the dual is the estimate (as for the other closures): `filter`
    /// (the default; here Newton's method from λ = ½R⁻¹(r − z(0)), retried from λ = 0) or
    /// `continuation`.
    pub branch: BranchRule,
    /// Options of the dual maximisation.
    pub dual: DualOptions,
}

impl Default for AreaClosure {
    fn default() -> Self {
        AreaClosure {
            domain: None,
            panels: 12,
            max_step: 0.01,
            jumps: JumpRule::Explicit,
            jump_steps: 32,
            output_step: None,
            extra_times: Vec::new(),
            dispersion: true,
            branch: BranchRule::default(),
            dual: DualOptions::default(),
        }
    }
}

impl AreaClosure {
    /// Sets the jump rule.
    pub fn with_jumps(mut self, jumps: JumpRule) -> Self {
        self.jumps = jumps;
        self
    }

    /// Sets the output step.
    pub fn with_output_step(mut self, step: f64) -> Self {
        self.output_step = Some(step);
        self
    }

    /// Sets the largest Runge–Kutta step.
    pub fn with_max_step(mut self, step: f64) -> Self {
        self.max_step = step;
        self
    }

    /// Sets the support of the family.
    pub fn with_domain(mut self, lower: f64, upper: f64) -> Self {
        self.domain = Some((lower, upper));
        self
    }

    /// Sets the rule that picks the dual's stationary point.
    pub fn with_branch(mut self, branch: BranchRule) -> Self {
        self.branch = branch;
        self
    }

    /// Sets the dual options.
    pub fn with_dual(mut self, dual: DualOptions) -> Self {
        self.dual = dual;
        self
    }

    /// The output times' part of the options, as the other closures take them.
    fn closure_options(&self) -> ClosureOptions {
        ClosureOptions {
            output_step: self.output_step,
            extra_times: self.extra_times.clone(),
            ..Default::default()
        }
    }
}

impl EstimatorOptions for AreaClosure {
    fn validate(&self) -> Result<()> {
        if self.panels == 0 {
            return Err(invalid("panels", "must be at least 1, got 0"));
        }
        if !(self.max_step.is_finite() && self.max_step > 0.0) {
            return Err(invalid("max_step", format!("must be positive and finite, got {}", self.max_step)));
        }
        if self.jump_steps == 0 {
            return Err(invalid("jump_steps", "must be at least 1, got 0"));
        }
        if let Some((a, b)) = self.domain {
            if !(a.is_finite() && b.is_finite() && a < b) {
                return Err(invalid("domain", format!("need finite a < b, got [{a}, {b}]")));
            }
        }
        crate::error::check_positive("output_step", self.output_step)?;
        if let Some(&t) = self.extra_times.iter().find(|&&t| !t.is_finite()) {
            return Err(invalid("extra_times", format!("must be finite, got {t}")));
        }
        self.dual.validate().map_err(|e| e.within("dual"))
    }

    fn run<S: Sde + ?Sized>(
        &self,
        _: Method,
        problem: &EstimationProblem<'_, S, StateMeasurement>,
    ) -> Result<MethodRun> {
        area_estimate(problem, self).map(MethodRun::from)
    }
}

/// The cumulants of the family at θ that the area rules need.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AreaMoments {
    /// The natural parameter θ.
    pub theta: f64,
    /// F(θ) = log N(θ), the log-partition function (`(II.32)` up to a constant).
    pub log_partition: f64,
    /// μ = ⟨M⟩ = ⟨x⟩.
    pub mu: f64,
    /// C = Var(M) (`(II.33)`).
    pub c: f64,
    /// ζ = ⟨Z⟩ (`(II.5)`).
    pub zeta: f64,
    /// C^Z = Cov(Z, M) (`(II.6)`).
    pub cz: f64,
}

/// The scalar family P(x; μ) ∝ exp(θx) p_*(x) with its measured function Z and the closure
/// drift: everything one sweep of the area rules needs.
pub struct ScalarArea<'a, S: Sde + ?Sized> {
    drift: ExponentialDrift<'a, S>,
    family: Exponential,
    nodes: Vec<f64>,
    z_nodes: Vec<f64>,
    jumps: JumpRule,
    jump_steps: usize,
    domain: (f64, f64),
}

impl<S: Sde + ?Sized> std::fmt::Debug for ScalarArea<'_, S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ScalarArea").field("nodes", &self.nodes.len()).field("jumps", &self.jumps).finish()
    }
}

/// Gauss–Legendre points per panel.
const POINTS_PER_PANEL: usize = 8;

/// log p_*(x_j) = ∫_{x_0}^{x_j} f(s, t₀) ds / D at the (sorted) nodes, by 8-point Gauss–Legendre
/// between neighbouring nodes: the stationary density of a one-state model with constant D.
fn stationary_log_density<S: Sde + ?Sized>(
    sde: &S,
    theta: &[f64],
    t0: f64,
    nodes: &[f64],
    d: f64,
) -> Result<Vec<f64>> {
    let rule = onsager_closures::quadrature::gauss_legendre(POINTS_PER_PANEL)
        .map_err(|e| invalid("panels", e.to_string()))?;
    let f = |x: f64| {
        let mut out = [0.0];
        sde.drift(t0, &[x], &[], theta, &mut out);
        out[0]
    };
    let mut out = Vec::with_capacity(nodes.len());
    let mut acc = 0.0;
    for (j, &x) in nodes.iter().enumerate() {
        if j > 0 {
            let a = nodes[j - 1];
            let half = 0.5 * (x - a);
            acc += rule.iter().map(|(p, w)| w * f(a + half * (p[0] + 1.0))).sum::<f64>() * half / d;
        }
        if !acc.is_finite() {
            return Err(invalid(
                "domain",
                format!("the stationary density is not finite at x = {x}; give a narrower `domain`"),
            ));
        }
        out.push(acc);
    }
    Ok(out)
}

impl<'a, S: Sde + ?Sized> ScalarArea<'a, S> {
    /// The family on `panels` × 8 Gauss–Legendre nodes of `domain` with the stationary reference
    /// of the one-state model `sde` at θ (drift at `t0`), and the measured function `z`.
    ///
    /// Errors: a model with more than one state or a clean state, a non-constant or singular
    /// diffusion, an invalid domain.
    pub fn try_new(
        sde: &'a S,
        theta: &[f64],
        t0: f64,
        domain: (f64, f64),
        panels: usize,
        z: impl Fn(f64) -> f64,
    ) -> Result<Self> {
        let dims = sde.dims();
        if dims.states() != 1 || dims.noisy != 1 {
            return Err(invalid(
                "method",
                format!("the area-rule closure takes one noisy state, the model has {}", dims.states()),
            ));
        }
        let g = sde.diffusion_matrix(theta)?;
        let d = 0.5 * g[(0, 0)] * g[(0, 0)];
        if !(d.is_finite() && d > 0.0) {
            return Err(invalid(
                "method",
                format!("the area-rule closure needs a positive diffusion, got D = {d}"),
            ));
        }
        let grid = onsager_closures::panel_grid(&[domain], panels, POINTS_PER_PANEL)
            .map_err(|e| invalid("domain", e.to_string()))?;
        let nodes: Vec<f64> = grid.points().to_vec();
        let log_p = stationary_log_density(sde, theta, t0, &nodes, d)?;
        let table: std::sync::Arc<Vec<(f64, f64)>> =
            std::sync::Arc::new(nodes.iter().copied().zip(log_p).collect());
        let lookup = move |x: &[f64]| {
            let i = table.partition_point(|&(p, _)| p < x[0]);
            table.get(i).filter(|(p, _)| *p == x[0]).map_or(f64::NEG_INFINITY, |&(_, v)| v)
        };
        let moments = Polynomial::try_new(1, 1).map_err(|e| invalid("method", e.to_string()))?;
        let family =
            Exponential::from_moments(grid, Reference::LogDensity(std::sync::Arc::new(lookup)), moments)
                .map_err(|e| invalid("domain", e.to_string()))?;
        let nodes: Vec<f64> = family.grid().points().to_vec();
        let z_nodes: Vec<f64> = nodes.iter().map(|&x| z(x)).collect();
        if let Some(x) = nodes.iter().zip(&z_nodes).find(|(_, z)| !z.is_finite()).map(|(x, _)| x) {
            return Err(invalid("measured function", format!("Z is not finite at x = {x}")));
        }
        let drift = ExponentialDrift::try_new(sde, theta, family.clone())?;
        Ok(ScalarArea { drift, family, nodes, z_nodes, jumps: JumpRule::Explicit, jump_steps: 32, domain })
    }

    /// The support [a, b] of the family (its box).
    pub fn domain(&self) -> (f64, f64) {
        self.domain
    }

    /// Sets the jump rule and the Runge–Kutta steps of an area-rule jump.
    pub fn with_jumps(mut self, jumps: JumpRule, steps: usize) -> Self {
        self.jumps = jumps;
        self.jump_steps = steps.max(1);
        self
    }

    /// The cumulants at θ. Errors: θ where the family has no normalizable density.
    pub fn moments(&self, theta: f64) -> Swept<AreaMoments> {
        self.moments_or_why(theta).map_err(|_| SweepFailure::Unrealizable)
    }

    /// [`ScalarArea::moments`], with why not in words.
    fn moments_or_why(&self, theta: f64) -> std::result::Result<AreaMoments, String> {
        let (p, log_partition) = self
            .family
            .node_probabilities(&[theta])
            .map_err(|e| format!("θ = {theta:.6e} gives no density on the nodes ({e})"))?;
        let (mut mu, mut zeta) = (0.0, 0.0);
        for ((&pi, &x), &z) in p.iter().zip(&self.nodes).zip(&self.z_nodes) {
            mu += pi * x;
            zeta += pi * z;
        }
        let (mut c, mut cz) = (0.0, 0.0);
        for ((&pi, &x), &z) in p.iter().zip(&self.nodes).zip(&self.z_nodes) {
            let d = x - mu;
            c += pi * d * d;
            cz += pi * (z - zeta) * d;
        }
        let out = AreaMoments { theta, log_partition, mu, c, zeta, cz };
        let finite = [log_partition, mu, c, zeta, cz].iter().all(|v| v.is_finite());
        if finite && c > 0.0 && cz != 0.0 {
            Ok(out)
        } else {
            Err(format!(
                "the cumulants at θ = {theta:.6e} are not a density's: variance C = {c:.3e}, \
                 C^Z = {cz:.3e}, F = {log_partition:.3e} (need C > 0, C^Z ≠ 0, all finite)"
            ))
        }
    }

    /// The natural parameter with mean μ (the Legendre inverse, `(II.31)` up to its origin).
    pub fn theta_of_mean(&self, mu: f64) -> Swept<f64> {
        let mut theta = 0.0;
        for _ in 0..200 {
            let m = self.moments(theta)?;
            let step = ((mu - m.mu) / m.c).clamp(-50.0, 50.0);
            theta += step;
            if step.abs() <= 1e-14 * (1.0 + theta.abs()) {
                return Ok(theta);
            }
        }
        let m = self.moments(theta)?;
        if (m.mu - mu).abs() <= 1e-12 * (1.0 + mu.abs()) {
            Ok(theta)
        } else {
            Err(SweepFailure::Unrealizable)
        }
    }

    /// The jump at a measurement with multiplier λ_k from θ⁻: (θ⁺, (ΔF)_k) by the rule set with
    /// [`ScalarArea::with_jumps`]: `(II.34)–(II.35)` or the area rules `(II.19)`, `(II.23)`.
    pub fn jump(&self, theta_minus: f64, lambda: f64) -> Swept<(f64, f64)> {
        self.jump_or_why(theta_minus, lambda).map_err(|_| SweepFailure::Unrealizable)
    }

    /// [`ScalarArea::jump`], with why not in words.
    fn jump_or_why(&self, theta_minus: f64, lambda: f64) -> std::result::Result<(f64, f64), String> {
        match self.jumps {
            JumpRule::Explicit => {
                let before = self.moments_or_why(theta_minus)?;
                let after = self.moments_or_why(theta_minus + lambda)?;
                Ok((after.theta, after.log_partition - before.log_partition))
            }
            JumpRule::Area => self.area_jump(theta_minus, lambda),
        }
    }

    /// The area rules as ODEs in λ: dθ/dλ = C^Z/C (`(II.27)` in θ), d(ΔF)/dλ = ζ (`(II.29)`),
    /// classical Runge–Kutta with `jump_steps` steps from λ = 0 to λ_k.
    fn area_jump(&self, theta_minus: f64, lambda: f64) -> std::result::Result<(f64, f64), String> {
        if lambda == 0.0 {
            return Ok((theta_minus, 0.0));
        }
        let rhs = |th: f64| -> std::result::Result<(f64, f64), String> {
            let m = self.moments_or_why(th)?;
            Ok((m.cz / m.c, m.zeta))
        };
        let h = lambda / self.jump_steps as f64;
        let (mut th, mut df) = (theta_minus, 0.0);
        for _ in 0..self.jump_steps {
            let k1 = rhs(th)?;
            let k2 = rhs(th + 0.5 * h * k1.0)?;
            let k3 = rhs(th + 0.5 * h * k2.0)?;
            let k4 = rhs(th + h * k3.0)?;
            th += h / 6.0 * (k1.0 + 2.0 * k2.0 + 2.0 * k3.0 + k4.0);
            df += h / 6.0 * (k1.1 + 2.0 * k2.1 + 2.0 * k3.1 + k4.1);
        }
        if th.is_finite() && df.is_finite() {
            Ok((th, df))
        } else {
            Err(format!("the area rule's integration in λ is not finite (θ = {th:.3e}, ΔF = {df:.3e})"))
        }
    }

    /// One classical Runge–Kutta step of θ̇ = W(θ) (`(II.46)`) with its variational equation
    /// δ̇ = W′(θ)δ from δ = 1: (θ(t + h), ∂θ(t + h)/∂θ(t)).
    fn flow_step(&self, t: f64, theta: f64, h: f64) -> std::result::Result<(f64, f64), String> {
        let f = |t: f64, th: f64| -> std::result::Result<(f64, f64), String> {
            let (mut w, mut j) = ([0.0], [0.0]);
            self.drift
                .w_jacobian(t, &[th], &mut w, &mut j)
                .map_err(|e| format!("at θ = {th:.6e}: {}", e.0))?;
            Ok((w[0], j[0]))
        };
        let (w1, j1) = f(t, theta)?;
        let d1 = j1;
        let (w2, j2) = f(t + 0.5 * h, theta + 0.5 * h * w1)?;
        let d2 = j2 * (1.0 + 0.5 * h * d1);
        let (w3, j3) = f(t + 0.5 * h, theta + 0.5 * h * w2)?;
        let d3 = j3 * (1.0 + 0.5 * h * d2);
        let (w4, j4) = f(t + h, theta + h * w3)?;
        let d4 = j4 * (1.0 + h * d3);
        let th = theta + h / 6.0 * (w1 + 2.0 * w2 + 2.0 * w3 + w4);
        let dd = 1.0 + h / 6.0 * (d1 + 2.0 * d2 + 2.0 * d3 + d4);
        if th.is_finite() && dd.is_finite() && dd > 0.0 {
            Ok((th, dd))
        } else {
            Err(format!(
                "a Runge–Kutta step of {h:.3e} from θ = {theta:.6e} gives θ = {th:.3e} with sensitivity \
                 {dd:.3e} (need both finite, the sensitivity positive)"
            ))
        }
    }
}

/// An event of the sweeps: a time where the state is recorded (an output), a jump happens (a
/// measurement), or both.
#[derive(Debug, Clone, PartialEq)]
struct Event {
    time: f64,
    output: Option<usize>,
    measurement: Option<usize>,
    /// Runge–Kutta steps from the previous event.
    steps: usize,
}

/// The forward sweep's record.
#[derive(Debug, Clone)]
struct Forward {
    f: f64,
    /// Per measurement: the cumulants before and after the jump and ∂θ(t_k−)/∂θ(t_{k−1}+).
    minus: Vec<AreaMoments>,
    plus: Vec<AreaMoments>,
    /// Per output: θ (before a jump at the same time), the cumulants, ∂θ(τ)/∂θ(last jump+), and
    /// the index of the next measurement (n after the last).
    out_moments: Vec<AreaMoments>,
    out_factor: Vec<f64>,
    out_next: Vec<usize>,
    segment_factor: Vec<f64>,
}

/// The area-rule closure as an [`EffectiveAction`]: F_Z(λ) = Σ(ΔF)_k and z_k = ∂F_Z/∂λ_k by the
/// adjoint (see the [module documentation](self)).
#[derive(Debug)]
pub struct AreaAction<'a, S: Sde + ?Sized> {
    family: ScalarArea<'a, S>,
    t0: f64,
    theta0: f64,
    times: Vec<f64>,
    output_times: Vec<f64>,
    events: Vec<Event>,
    sweeps: usize,
    steps: usize,
    /// Where and why the last sweep that failed failed.
    last_failure: Option<String>,
}

impl<'a, S: Sde + ?Sized> AreaAction<'a, S> {
    /// The action of `family` from θ(t₀) = `theta0` with measurements at `times` (increasing,
    /// ≥ t0) and the history at `outputs` (≥ t0), with Runge–Kutta steps of at most `max_step`.
    ///
    /// Errors: unsorted times, times before t0, a non-positive step.
    pub fn try_new(
        family: ScalarArea<'a, S>,
        t0: f64,
        theta0: f64,
        times: &[f64],
        outputs: &[f64],
        max_step: f64,
    ) -> Result<Self> {
        if times.is_empty()
            || times.windows(2).any(|w| w[0].partial_cmp(&w[1]) != Some(std::cmp::Ordering::Less))
            || times[0] < t0
        {
            return Err(invalid("data", "the measurement times must increase and not be before t0"));
        }
        if !(max_step > 0.0 && max_step.is_finite()) {
            return Err(invalid("max_step", format!("must be positive, got {max_step}")));
        }
        let mut outs: Vec<f64> = outputs.to_vec();
        outs.extend_from_slice(times);
        outs.sort_by(f64::total_cmp);
        outs.dedup_by(|a, b| (*a - *b).abs() <= 1e-12 * (1.0 + b.abs()));
        if outs[0] < t0 {
            return Err(invalid("output times", format!("must not be before t0 = {t0}")));
        }
        let mut events: Vec<Event> = Vec::new();
        let (mut i, mut k) = (0, 0);
        let mut last = t0;
        while i < outs.len() || k < times.len() {
            let (t, output, measurement) = match (outs.get(i), times.get(k)) {
                (Some(&o), Some(&m)) if (o - m).abs() <= 1e-12 * (1.0 + m.abs()) => (m, Some(i), Some(k)),
                (Some(&o), Some(&m)) if o < m => (o, Some(i), None),
                (Some(&o), None) => (o, Some(i), None),
                (_, Some(&m)) => (m, None, Some(k)),
                (None, None) => unreachable!("loop condition"),
            };
            i += usize::from(output.is_some());
            k += usize::from(measurement.is_some());
            let steps = ((t - last) / max_step).ceil().max(if t > last { 1.0 } else { 0.0 }) as usize;
            events.push(Event { time: t, output, measurement, steps });
            last = t;
        }
        Ok(AreaAction {
            family,
            t0,
            theta0,
            times: times.to_vec(),
            output_times: outs,
            events,
            sweeps: 0,
            steps: 0,
            last_failure: None,
        })
    }

    /// The family of the action.
    pub fn family(&self) -> &ScalarArea<'a, S> {
        &self.family
    }

    /// θ(t₀).
    pub fn theta0(&self) -> f64 {
        self.theta0
    }

    fn forward(&mut self, lambda: &[f64]) -> Swept<Forward> {
        self.sweeps += 1;
        let mut steps = 0;
        let swept = self.sweep(lambda, &mut steps);
        self.steps += steps;
        self.failed(swept)
    }

    /// A sweep's value, or its failure kept as [`EffectiveAction::last_failure`].
    fn failed<T>(&mut self, swept: std::result::Result<T, FailureAt>) -> Swept<T> {
        swept.map_err(|FailureAt { why, .. }| {
            self.last_failure = Some(why);
            SweepFailure::Unrealizable
        })
    }

    /// The forward sweep at λ, counting its Runge–Kutta steps into `steps`.
    fn sweep(&self, lambda: &[f64], steps: &mut usize) -> std::result::Result<Forward, FailureAt> {
        let n = self.times.len();
        let m_out = self.output_times.len();
        let mut fw = Forward {
            f: 0.0,
            minus: Vec::with_capacity(n),
            plus: Vec::with_capacity(n),
            out_moments: Vec::with_capacity(m_out),
            out_factor: Vec::with_capacity(m_out),
            out_next: Vec::with_capacity(m_out),
            segment_factor: Vec::with_capacity(n),
        };
        let family = &self.family;
        let (mut t, mut theta, mut factor) = (self.t0, self.theta0, 1.0);
        for e in &self.events {
            let h = if e.steps > 0 { (e.time - t) / e.steps as f64 } else { 0.0 };
            for s in 0..e.steps {
                let ts = t + s as f64 * h;
                let (th, d) = family.flow_step(ts, theta, h).map_err(|why| FailureAt::at(ts, why))?;
                theta = th;
                factor *= d;
                *steps += 1;
            }
            t = e.time;
            let moments = |theta| family.moments_or_why(theta).map_err(|why| FailureAt::at(t, why));
            if e.output.is_some() {
                fw.out_moments.push(moments(theta)?);
                fw.out_factor.push(factor);
                fw.out_next.push(e.measurement.unwrap_or(fw.minus.len()));
            }
            if let Some(k) = e.measurement {
                let before = moments(theta)?;
                let (th, df) = family.jump_or_why(theta, lambda[k]).map_err(|why| {
                    FailureAt::at(t, format!("the jump of measurement {k} (λ_k = {:.6e}): {why}", lambda[k]))
                })?;
                let after = moments(th)?;
                fw.f += df;
                fw.minus.push(before);
                fw.plus.push(after);
                fw.segment_factor.push(factor);
                theta = th;
                factor = 1.0;
            }
        }
        if fw.f.is_finite() {
            Ok(fw)
        } else {
            Err(FailureAt::at(t, "the log-partition increments are not finite"))
        }
    }

    /// The backward sweep: α_k⁺ and α_k⁻ at every measurement by (II.21) and the adjoint flow.
    fn backward(fw: &Forward) -> (Vec<f64>, Vec<f64>) {
        let n = fw.minus.len();
        let (mut a_plus, mut a_minus) = (vec![0.0; n], vec![0.0; n]);
        let mut next = 0.0;
        for k in (0..n).rev() {
            let (mi, pl) = (&fw.minus[k], &fw.plus[k]);
            a_plus[k] = next;
            // (II.21): α_k⁻ = ((ζ⁺ − ζ⁻) + C^{Z+}α⁺)/C^{Z−}.
            a_minus[k] = ((pl.zeta - mi.zeta) + pl.cz * a_plus[k]) / mi.cz;
            // Across the interval before t_k: α(t_{k−1}+) = α_k⁻ ∂μ(t_k−)/∂μ(t_{k−1}+).
            next = if k > 0 { a_minus[k] * mi.c * fw.segment_factor[k] / fw.plus[k - 1].c } else { 0.0 };
        }
        (a_plus, a_minus)
    }

    fn value_and_gradient(&mut self, lambda: &[f64]) -> Swept<(f64, Vec<f64>, Forward, Vec<f64>)> {
        let fw = self.forward(lambda)?;
        let (a_plus, a_minus) = Self::backward(&fw);
        let z: Vec<f64> = fw.plus.iter().zip(&a_plus).map(|(p, a)| p.zeta + p.cz * a).collect();
        if let Some(k) = z.iter().position(|v| !v.is_finite()) {
            let why = FailureAt::at(self.times[k], "the adjoint's history at the measurement is not finite");
            return self.failed(Err(why));
        }
        Ok((fw.f, z, fw, a_minus))
    }

    /// The estimate x̂(τ) = μ + Cα at the output times (`(II.4)` with Z = x).
    fn history_of(fw: &Forward, a_minus: &[f64]) -> Vec<f64> {
        let n = fw.minus.len();
        let mut mean = Vec::with_capacity(fw.out_moments.len());
        for ((m, &factor), &k) in fw.out_moments.iter().zip(&fw.out_factor).zip(&fw.out_next) {
            let alpha =
                if k < n { a_minus[k] * fw.minus[k].c * (fw.segment_factor[k] / factor) / m.c } else { 0.0 };
            mean.push(m.mu + m.c * alpha);
        }
        mean
    }

    fn check(&self, lambda: &[f64]) -> Result<()> {
        crate::model::check_len("multipliers", self.times.len(), lambda.len())
    }

    /// The history means at λ (for finite differences).
    fn means(&mut self, lambda: &[f64]) -> Swept<(Vec<f64>, Vec<f64>)> {
        let (_, z, fw, a_minus) = self.value_and_gradient(lambda)?;
        Ok((Self::history_of(&fw, &a_minus), z))
    }
}

impl<S: Sde + ?Sized> EffectiveAction for AreaAction<'_, S> {
    fn measurement_times(&self) -> &[f64] {
        &self.times
    }

    fn output_dim(&self) -> usize {
        1
    }

    fn evaluate(&mut self, lambda: &[f64]) -> Result<ActionValue> {
        self.check(lambda)?;
        Ok(match self.value_and_gradient(lambda) {
            Ok((value, z, _, _)) => ActionValue { value, z },
            Err(_) => ActionValue { value: f64::NAN, z: vec![f64::NAN; lambda.len()] },
        })
    }

    fn history(&mut self, lambda: &[f64], cross: bool) -> Result<Swept<History>> {
        if cross {
            return Ok(self.history_and_hessian(lambda)?.map(|(h, _)| h));
        }
        self.check(lambda)?;
        let (_, _, fw, a_minus) = match self.value_and_gradient(lambda) {
            Ok(v) => v,
            Err(e) => return Ok(Err(e)),
        };
        let mean = Self::history_of(&fw, &a_minus);
        let variance = fw.out_moments.iter().map(|m| vec![m.c]).collect();
        let mean = mean.into_iter().map(|m| vec![m]).collect();
        Ok(Ok(History { times: self.output_times.clone(), mean, variance, cross: None }))
    }

    /// ∇²F and Cov(x(τ), Z_m) = ∂x̂(τ)/∂λ_m by central differences of the sweeps (steps
    /// 10⁻⁵(1 + |λ_m|)).
    fn history_and_hessian(&mut self, lambda: &[f64]) -> Result<Swept<(History, DMatrix<f64>)>> {
        let mut history = match self.history(lambda, false)? {
            Ok(h) => h,
            Err(e) => return Ok(Err(e)),
        };
        let (n, m_out) = (lambda.len(), self.output_times.len());
        let mut hess = DMatrix::zeros(n, n);
        let mut cross = vec![DMatrix::zeros(1, n); m_out];
        let mut l = lambda.to_vec();
        for j in 0..n {
            let step = 1e-5 * (1.0 + lambda[j].abs());
            l[j] = lambda[j] + step;
            let plus = self.means(&l);
            l[j] = lambda[j] - step;
            let minus = self.means(&l);
            l[j] = lambda[j];
            let ((xp, zp), (xm, zm)) = match (plus, minus) {
                (Ok(p), Ok(m)) => (p, m),
                (Err(e), _) | (_, Err(e)) => return Ok(Err(e)),
            };
            for i in 0..n {
                hess[(i, j)] = (zp[i] - zm[i]) / (2.0 * step);
            }
            for (e, c) in cross.iter_mut().enumerate() {
                c[(0, j)] = (xp[e] - xm[e]) / (2.0 * step);
            }
        }
        history.cross = Some(cross);
        Ok(Ok((history, (&hess + hess.transpose()) * 0.5)))
    }

    fn work(&self) -> Option<Work> {
        // Fixed steps: none is rejected.
        Some(Work { sweeps: self.sweeps, steps: self.steps, rejected: 0 })
    }

    fn last_failure(&self) -> Option<&str> {
        self.last_failure.as_deref()
    }
}

/// The area-rule closure's [`AreaAction`] for a problem with Z = x (the measured state), as
/// [`area_estimate`] builds it. θ(t₀) matches the mean of the Gaussian x0 prior (the family's
/// variance at that mean is the reference's, not the prior's).
///
/// Errors: more than one state, more than one measured output, a non-Gaussian prior or
/// likelihood, parameters to estimate, invalid options.
pub fn area_action<'a, S: Sde + ?Sized>(
    problem: &EstimationProblem<'a, S, StateMeasurement>,
    options: &AreaClosure,
) -> Result<AreaAction<'a, S>> {
    problem.validate()?;
    options.validate()?;
    problem.observation.validate(problem.sde.dims(), problem.theta)?;
    if !problem.estimate.is_empty() {
        return Err(invalid("estimate", "the closures do not estimate parameters; θ is taken as given"));
    }
    let dims = problem.sde.dims();
    if dims.states() != 1 || dims.noisy != 1 {
        return Err(invalid(
            "method",
            format!("the area-rule closure takes one noisy state, the model has {} states", dims.states()),
        ));
    }
    if problem.observation.states.len() != 1 {
        return Err(invalid(
            "method",
            format!(
                "the area-rule closure takes one scalar measured output, the model has {}",
                problem.observation.states.len()
            ),
        ));
    }
    let (m0, v0) = gaussian_prior(&problem.x0_prior[0], &problem.sde.state_names()[0])?;
    let values: Vec<f64> = problem.data.values.iter().map(|row| row[0]).collect();
    let domain = options.domain.unwrap_or_else(|| default_domain(&values, m0, v0));
    check_box_covers_data(problem, &[domain])?;
    let family = ScalarArea::try_new(problem.sde, problem.theta, problem.t0, domain, options.panels, |x| x)?
        .with_jumps(options.jumps, options.jump_steps);
    let theta0 = family.theta_of_mean(m0).map_err(|_| {
        invalid("x0 prior", format!("its mean {m0} is not a mean of the family on the domain {domain:?}"))
    })?;
    let outs = output_times(problem.t0, &problem.data.times, &options.closure_options())?;
    AreaAction::try_new(family, problem.t0, theta0, &problem.data.times, &outs, options.max_step)
}

/// The mean-optimal estimate of the area-rule closure as a [`PathEstimate`]
/// (method `area-closure`): the dual (`003_d2fc48a470e528fc.txt (I.60)`) of F_Z of the area
/// rules maximised by [`mean_optimal::solve_on_branch`] (or from ½R⁻¹(r − z(0)) with
/// `branch = "filter"`), the history x̂(t) and the ensemble dispersion (`(I.85)–(I.90)`).
///
/// Errors: as [`area_action`]; non-convergence and sweeps that leave the family are the status.
pub fn area_estimate<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    options: &AreaClosure,
) -> Result<PathEstimate> {
    let start = Instant::now();
    let mut action = area_action(problem, options)?;
    let data = gaussian_dual_data(problem)?;
    let plan = Plan {
        dual: options.dual.clone(),
        stages: None,
        retry_from_zero: true,
        dispersion: options.dispersion,
    };
    let sol = match options.branch {
        BranchRule::Continuation => mean_optimal::solve_on_branch(&mut action, &data, &plan)?,
        BranchRule::Filter => {
            let begin = prior_start(&mut action, &data)?;
            mean_optimal::solve(&mut action, &data, begin, &plan)?
        }
    };
    let mut details = sol.details(Some(describe(options)), action.work(), &plan);
    details.domain = Some(vec![action.family().domain()]);
    Ok(super::dual_path_estimate(problem, Method::AreaClosure, sol, details, start))
}

fn describe(options: &AreaClosure) -> String {
    let jumps = match options.jumps {
        JumpRule::Explicit => "explicit",
        JumpRule::Area => "area",
    };
    format!("Area {{ M = Z = x, reference: stationary, jumps: {jumps} }}")
}

/// λ_k = ½R⁻¹(r_k − z_k(0)) from the prior prediction (λ = 0 where it has no value).
fn prior_start<S: Sde + ?Sized>(
    action: &mut AreaAction<'_, S>,
    data: &DualData,
) -> Result<(Vec<f64>, DualStart)> {
    let zero = vec![0.0; data.r.len()];
    let prior = action.evaluate(&zero)?;
    if !prior.z.iter().all(|v| v.is_finite()) {
        return Ok((zero, DualStart::Zero));
    }
    let half = (0..zero.len())
        .map(|m| if data.r[m].is_nan() { 0.0 } else { 0.5 * (data.r[m] - prior.z[m]) / data.variance[m] })
        .collect();
    Ok((half, DualStart::Prior))
}
