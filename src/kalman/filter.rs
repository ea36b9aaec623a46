//! The continuous-discrete Gaussian filter and its Rauch–Tung–Striebel smoother, shared by the
//! extended and the unscented methods (they differ only in how the moment equations are
//! approximated, [`Rule`]).
//!
//! The filter is generic over the scalar so that the prediction-error log-likelihood can be
//! differentiated with respect to θ by forward-mode automatic differentiation ([`super::pem`]).

use std::sync::Arc;

use nalgebra::DMatrix;
use num_dual::Dual;
use onsager_closures::quadrature::Rule as QuadratureRule;

use super::dense::{cholesky, matmul, symmetrize_in_place, transpose};
use super::{Gaussian, UnscentedParams};
use crate::data::Dataset;
use crate::estimate::EstimationProblem;
use crate::model::observation::StateMeasurement;
use crate::model::prior::{Prior, PriorDensity};
use crate::model::{Param, Scalar, Sde};
use crate::{Error, Result};

/// ln(2π).
const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// The most halvings of one integration step ([`MomentDynamics::refined_step`]): steps down to
/// 1/1024 of the grid's.
const MAX_HALVINGS: u32 = 10;

/// How the mean and covariance ODEs are approximated.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Rule {
    /// Linearisation about the mean (extended Kalman filter).
    Extended,
    /// Sigma points of N(m, P) (unscented / cubature Kalman filter).
    Unscented(UnscentedParams),
    /// A quadrature rule (ξₖ, wₖ) for the standard normal N(0, I), mapped to N(m, P) by
    /// Xₖ = m + L ξₖ (P = L Lᵀ): Gauss–Hermite tensor rules or spherical–radial cubature
    /// ([`onsager_closures::GaussianRule`]), the expectations of the Gaussian KSP closure.
    Quadrature(Arc<QuadratureRule>),
}

/// A time of the filter: the initial time or a measurement time, with the number of
/// integration steps from the previous node.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Node {
    pub t: f64,
    /// Row of the dataset measured at this time.
    pub row: Option<usize>,
    /// Integration steps from the previous node (0 for the first).
    pub steps: usize,
}

/// What the filter needs that does not depend on θ (except through `sigma`).
#[derive(Debug, Clone)]
pub(crate) struct Setup {
    pub noisy: usize,
    pub states: usize,
    pub nodes: Vec<Node>,
    /// Measured state indices (into s = [x; z]), one per output.
    pub measured: Vec<usize>,
    /// The measurement standard deviation.
    pub sigma: Param,
    pub m0: Vec<f64>,
    /// Initial covariance, column-major.
    pub p0: Vec<f64>,
}

/// Mean and variance of a one-dimensional initial-state prior: exact for an unbounded
/// Gaussian prior; any other prior is rejected (a Kalman filter needs a Gaussian initial law).
fn prior_moments(prior: &Prior, name: &str) -> Result<(f64, f64)> {
    match prior.density {
        PriorDensity::Gaussian { mean, sd } if prior.lower == f64::NEG_INFINITY && prior.upper == f64::INFINITY => {
            Ok((mean, sd * sd))
        }
        _ => Err(Error::InvalidOption {
            name: "x0-prior".into(),
            reason: format!(
                "the Kalman methods need an unbounded Gaussian prior for the initial state `{name}`, got `{prior}`"
            ),
        }),
    }
}

/// The measurement standard deviation σ of `observation`, checked against the model `sde` and
/// θ = `theta`: the Kalman-type methods assume Gaussian measurement errors y = s[i] + N(0, σ²).
///
/// Errors: those of [`StateMeasurement::validate`]; [`Error::InvalidOption`] (name
/// `likelihood`, naming `method`) for any other measurement-error law.
pub(crate) fn gaussian_sigma<S: Sde + ?Sized>(
    sde: &S,
    observation: &StateMeasurement,
    theta: &[f64],
    method: &str,
) -> Result<Param> {
    observation.validate(sde.dims(), theta)?;
    observation.noise.gaussian_sigma(
        &sde.param_names(),
        &format!("`{method}`"),
        "use `gaussian:sigma=...` or a method that takes any likelihood (particle, the MAP path, KSP)",
    )
}

impl Setup {
    /// Checks the pieces of `problem` that the filter uses (its model, measurement model,
    /// initial-state priors and data) with θ = `theta` and builds the node list. `t0` is the time
    /// of the initial-state prior (≤ the first measurement time), `dt` the largest integration
    /// step, `method` the name in error messages.
    pub fn new<S: Sde + ?Sized>(
        problem: &EstimationProblem<'_, S, StateMeasurement>,
        theta: &[f64],
        t0: f64,
        dt: f64,
        method: &str,
    ) -> Result<Setup> {
        let EstimationProblem { sde, observation, x0_prior, z0_prior, data, .. } = *problem;
        let d = sde.dims();
        let sigma = gaussian_sigma(sde, observation, theta, method)?;
        sde.diffusion_matrix(theta)?;
        let names = sde.state_names();
        let mut m0 = Vec::with_capacity(d.states());
        let mut p0 = vec![0.0; d.states() * d.states()];
        for (i, prior) in x0_prior.iter().chain(z0_prior).enumerate() {
            let (mean, var) = prior_moments(prior, &names[i])?;
            m0.push(mean);
            p0[i + i * d.states()] = var;
        }
        if !(t0.is_finite()) {
            return Err(Error::InvalidOption {
                name: "t0".into(),
                reason: format!("must be finite, got {t0}"),
            });
        }
        if !(dt.is_finite() && dt > 0.0) {
            return Err(Error::InvalidOption {
                name: "dt".into(),
                reason: format!("must be positive and finite, got {dt}"),
            });
        }
        let nodes = build_nodes(&data.times, t0, dt)?;
        // The smoothers keep the moments and Φ of every integration step (each a few small
        // vectors and matrices on the heap): bound that memory.
        let total: usize = nodes.iter().map(|node| node.steps).sum();
        let n = d.states() as f64;
        let bytes = (total + nodes.len()) as f64 * (16.0 * (3.0 * n * n + 2.0 * n) + 800.0);
        let size = format!(
            "{total} integration steps of {dt:e} (set by --dt; default a tenth of the median measurement \
             interval, at most 0.01) × {n} states"
        );
        problem.max_memory.check(&format!("`{method}`"), size, bytes)?;
        Ok(Setup {
            noisy: d.noisy,
            states: d.states(),
            nodes,
            measured: observation.states.clone(),
            sigma,
            m0,
            p0,
        })
    }
}

/// Nodes at `t0` and at every measurement time, with ⌈Δt / dt⌉ equal steps between
/// consecutive nodes. Errors when `t0` is after the first measurement or the times are not
/// strictly increasing.
pub(crate) fn build_nodes(times: &[f64], t0: f64, dt: f64) -> Result<Vec<Node>> {
    if times.is_empty() {
        return Err(Error::InvalidOption { name: "data".into(), reason: "has no measurements".into() });
    }
    if t0 > times[0] {
        return Err(Error::InvalidOption {
            name: "t0".into(),
            reason: format!("the initial time {t0} is after the first measurement time {}", times[0]),
        });
    }
    let mut nodes = Vec::with_capacity(times.len() + 1);
    let mut last = t0;
    if t0 < times[0] {
        nodes.push(Node { t: t0, row: None, steps: 0 });
    }
    for (k, &t) in times.iter().enumerate() {
        if !t.is_finite() || (k > 0 && t <= times[k - 1]) {
            return Err(Error::InvalidOption {
                name: "data".into(),
                reason: format!(
                    "measurement times must be finite and strictly increasing (row {k}, t = {t})"
                ),
            });
        }
        let steps =
            if nodes.is_empty() { 0 } else { ((t - last) / dt * (1.0 - 1e-12)).ceil().max(1.0) as usize };
        nodes.push(Node { t, row: Some(k), steps });
        last = t;
    }
    let total: usize = nodes.iter().map(|n| n.steps).sum();
    if total > crate::simulate::MAX_STEPS {
        return Err(Error::InvalidOption {
            name: "dt".into(),
            reason: format!(
                "{total} integration steps (step {dt:e}) exceed the limit of {}; use a larger --dt",
                crate::simulate::MAX_STEPS
            ),
        });
    }
    Ok(nodes)
}

/// The moments stored on the grid for the smoother (all `f64`).
#[derive(Debug, Clone, Default)]
pub(crate) struct Store {
    pub times: Vec<f64>,
    /// Whether a measurement was assimilated at the grid point.
    pub measured: Vec<bool>,
    /// Predicted moments (before the update; the prior at the first point).
    pub predicted: Vec<Gaussian>,
    /// Filtered moments (after the update, if any).
    pub filtered: Vec<Gaussian>,
    /// Φ_j: the transition matrix of the (statistically) linearised dynamics over step j → j+1.
    pub phi: Vec<DMatrix<f64>>,
}

fn to_gaussian<D: Scalar>(m: &[D], p: &[D], n: usize) -> Gaussian {
    Gaussian {
        mean: m.iter().map(|v| v.re()).collect(),
        cov: DMatrix::from_iterator(n, n, p.iter().map(|v| v.re())),
    }
}

/// (ṁ, Ṗ, F): the moment rates and, when asked, the effective Jacobian.
type Rates<D> = (Vec<D>, Vec<D>, Option<Vec<D>>);

/// The moment ODEs of one filter run: the model, how the moment equations are approximated,
/// θ and the diffusion Q = B Bᵀ of the full state (column-major), all fixed along the run.
struct MomentDynamics<'a, S: Sde + ?Sized, D> {
    sde: &'a S,
    rule: &'a Rule,
    theta: &'a [D],
    q: &'a [D],
}

impl<S: Sde + ?Sized, D: Scalar> MomentDynamics<'_, S, D> {
    /// Time derivatives of the moments at (t, m, P): ṁ, Ṗ and, when asked, the effective
    /// Jacobian F of Φ̇ = F Φ.
    ///
    /// - Extended (Jazwinski 1970, Sec. 9.3; Särkkä & Solin 2019, (10.80)): ṁ = a(t, m),
    ///   Ṗ = F P + P Fᵀ + B Bᵀ with F = ∂a/∂s(t, m) (by a [`Dual`] pass per state).
    /// - Unscented (Särkkä 2007, (18)–(19); the continuous-time limit of the sigma-point
    ///   prediction of Arasaratnam, Haykin & Hurd 2010): ṁ = Σ_i Wᵢ a(t, Xᵢ),
    ///   M = Σ_i Wᵢ (Xᵢ − m)(a(t, Xᵢ) − ṁ)ᵀ, Ṗ = M + Mᵀ + B Bᵀ, with the sigma points
    ///   Xᵢ = m ± √(n + λ) Lₑᵢ of P = L Lᵀ; the statistical linearisation F = Mᵀ P⁻¹ gives the
    ///   cross-covariance of the state at two times used by the smoother (Särkkä 2008).
    fn rates(&self, t: D, m: &[D], p: &[D], want_f: bool) -> Option<Rates<D>> {
        let MomentDynamics { sde, rule, theta, q } = *self;
        let n = m.len();
        let zero = D::from(0.0);
        match rule {
            Rule::Extended => {
                let mut a = vec![zero; n];
                sde.state_drift(t, m, theta, &mut a);
                // F = ∂a/∂s, column j from one Dual<D> pass seeded along s_j.
                let mut f = vec![zero; n * n];
                let lift = |v: &[D]| v.iter().map(|&u| Dual::from_re(u)).collect::<Vec<Dual<D>>>();
                let (mut md, td) = (lift(m), lift(theta));
                let mut out = vec![Dual::from_re(zero); n];
                for j in 0..n {
                    md[j].eps = D::from(1.0);
                    sde.state_drift(Dual::from_re(t), &md, &td, &mut out);
                    md[j].eps = zero;
                    for i in 0..n {
                        f[i + j * n] = out[i].eps;
                    }
                }
                let fp = matmul(&f, p, n, n, n);
                let mut pdot = vec![zero; n * n];
                for j in 0..n {
                    for i in 0..n {
                        pdot[i + j * n] = fp[i + j * n] + fp[j + i * n] + q[i + j * n];
                    }
                }
                Some((a, pdot, want_f.then_some(f)))
            }
            &Rule::Unscented(u) => {
                let l = cholesky(p, n)?;
                let (wm0, wi, scale) = u.weights(n);
                let mut mdot = vec![zero; n];
                let mut a0 = vec![zero; n];
                sde.state_drift(t, m, theta, &mut a0);
                for i in 0..n {
                    mdot[i] = a0[i] * wm0;
                }
                // Sigma points m ± scale L e_j. Because the deviations come in ± pairs,
                // Σ Wᵢ (Xᵢ − m) = 0 and M = Σ Wᵢ (Xᵢ − m)(aᵢ − ṁ)ᵀ = Σ Wᵢ (Xᵢ − m) aᵢᵀ (the centre
                // point has Xᵢ − m = 0), accumulated in the same pass as ṁ.
                let mut mm = vec![zero; n * n];
                let mut x = vec![zero; n];
                let mut a = vec![zero; n];
                for j in 0..n {
                    for sign in [1.0, -1.0] {
                        let k = scale * sign;
                        for i in 0..n {
                            x[i] = m[i] + l.entry(i, j) * k;
                        }
                        sde.state_drift(t, &x, theta, &mut a);
                        for c in 0..n {
                            mdot[c] += a[c] * wi;
                            let ac = a[c] * (wi * k);
                            // (Xᵢ − m)_r = L_rj k; L is lower triangular, rows r ≥ j.
                            for r in j..n {
                                mm[r + c * n] += l.entry(r, j) * ac;
                            }
                        }
                    }
                }
                Some(statistical_rates(mdot, &mm, &l, q, want_f))
            }
            Rule::Quadrature(rule) => {
                let l = cholesky(p, n)?;
                let mut mdot = vec![zero; n];
                // M = Σₖ wₖ (Xₖ − m)(aₖ − ṁ)ᵀ = Σₖ wₖ (Xₖ − m) aₖᵀ − (Σₖ wₖ (Xₖ − m)) ṁᵀ, one pass.
                let mut mm = vec![zero; n * n];
                let mut mean_dev = vec![zero; n];
                let mut dev = vec![zero; n];
                let mut x = vec![zero; n];
                let mut a = vec![zero; n];
                for (xi, w) in rule.iter() {
                    for r in 0..n {
                        dev[r] = (0..=r).map(|j| l.entry(r, j) * xi[j]).sum();
                        x[r] = m[r] + dev[r];
                        mean_dev[r] += dev[r] * w;
                    }
                    sde.state_drift(t, &x, theta, &mut a);
                    for c in 0..n {
                        mdot[c] += a[c] * w;
                        let ac = a[c] * w;
                        for r in 0..n {
                            mm[r + c * n] += dev[r] * ac;
                        }
                    }
                }
                for c in 0..n {
                    for r in 0..n {
                        mm[r + c * n] -= mean_dev[r] * mdot[c];
                    }
                }
                Some(statistical_rates(mdot, &mm, &l, q, want_f))
            }
        }
    }

    /// A step of size h by [`Self::rk4_step`], split in two halves (recursively, at most
    /// [`MAX_HALVINGS`] times) when it fails or leaves a covariance that is not positive
    /// definite: a fixed step that is stable on most of a record can be unstable where an update
    /// has moved the moments into a stiff region of the drift (the Van der Pol oscillator after
    /// an outlier, say). Φ of the step is the product of the halves' (Φ₂ Φ₁). At the deepest
    /// level the plain step is taken, so the refinement never fails where the fixed step does not.
    fn refined_step(
        &self,
        t: f64,
        h: f64,
        m: &mut [D],
        p: &mut [D],
        phi: Option<&mut Vec<D>>,
        depth: u32,
    ) -> Option<()> {
        let n = m.len();
        if depth == MAX_HALVINGS {
            return self.rk4_step(t, h, m, p, phi);
        }
        let (m0, p0) = (m.to_vec(), p.to_vec());
        let mut phi_step: Option<Vec<D>> = phi.as_ref().map(|_| Vec::new());
        if self.rk4_step(t, h, m, p, phi_step.as_mut()).is_some() && cholesky(p, n).is_some() {
            if let (Some(phi), Some(step)) = (phi, phi_step) {
                *phi = step;
            }
            return Some(());
        }
        m.copy_from_slice(&m0);
        p.copy_from_slice(&p0);
        let (mut first, mut second): (Option<Vec<D>>, Option<Vec<D>>) =
            (phi.as_ref().map(|_| Vec::new()), phi.as_ref().map(|_| Vec::new()));
        self.refined_step(t, 0.5 * h, m, p, first.as_mut(), depth + 1)?;
        self.refined_step(t + 0.5 * h, 0.5 * h, m, p, second.as_mut(), depth + 1)?;
        if let (Some(phi), Some(first), Some(second)) = (phi, first, second) {
            *phi = matmul(&second, &first, n, n, n);
        }
        Some(())
    }

    /// One classical Runge–Kutta step of size h for (m, P) and, when `phi` is given, Φ̇ = F Φ.
    fn rk4_step(&self, t: f64, h: f64, m: &mut [D], p: &mut [D], phi: Option<&mut Vec<D>>) -> Option<()> {
        let n = m.len();
        let nn = n * n;
        let want_f = phi.is_some();
        let mut phi_cur: Vec<D> = if want_f {
            let mut e = vec![D::from(0.0); nn];
            for i in 0..n {
                e[i + i * n] = D::from(1.0);
            }
            e
        } else {
            Vec::new()
        };
        let (m0, p0, phi0) = (m.to_vec(), p.to_vec(), phi_cur.clone());
        let mut acc_m = vec![D::from(0.0); n];
        let mut acc_p = vec![D::from(0.0); nn];
        let mut acc_phi = vec![D::from(0.0); phi0.len()];
        let (mut ms, mut ps) = (m0.clone(), p0.clone());
        for (stage, (c, w)) in [(0.0, 1.0), (0.5, 2.0), (0.5, 2.0), (1.0, 1.0)].into_iter().enumerate() {
            let ts = D::from(t + c * h);
            let (dm, dp, f) = self.rates(ts, &ms, &ps, want_f)?;
            let dphi = f.map(|f| matmul(&f, &phi_cur, n, n, n));
            for i in 0..n {
                acc_m[i] += dm[i] * w;
            }
            for i in 0..nn {
                acc_p[i] += dp[i] * w;
            }
            if let Some(dphi) = &dphi {
                for i in 0..nn {
                    acc_phi[i] += dphi[i] * w;
                }
            }
            if stage < 3 {
                let next_c = if stage == 2 { 1.0 } else { 0.5 };
                for i in 0..n {
                    ms[i] = m0[i] + dm[i] * (next_c * h);
                }
                for i in 0..nn {
                    ps[i] = p0[i] + dp[i] * (next_c * h);
                }
                symmetrize_in_place(&mut ps, n);
                if let Some(dphi) = &dphi {
                    for i in 0..nn {
                        phi_cur[i] = phi0[i] + dphi[i] * (next_c * h);
                    }
                }
            }
        }
        for i in 0..n {
            m[i] = m0[i] + acc_m[i] * (h / 6.0);
        }
        for i in 0..nn {
            p[i] = p0[i] + acc_p[i] * (h / 6.0);
        }
        symmetrize_in_place(p, n);
        if let Some(phi) = phi {
            *phi = (0..nn).map(|i| phi0[i] + acc_phi[i] * (h / 6.0)).collect();
        }
        if m.iter().chain(p.iter()).any(|v| !v.re().is_finite()) {
            return None;
        }
        Some(())
    }
}

/// The moment rates of a statistical (sigma-point or quadrature) rule from ṁ and
/// M = E[(S − m)(a(t, S) − ṁ)ᵀ]: Ṗ = M + Mᵀ + B Bᵀ and, when asked, the statistical
/// linearisation F = Mᵀ P⁻¹ (P = L Lᵀ) of the smoother's cross-covariance (Särkkä 2008).
fn statistical_rates<D: Scalar>(
    mdot: Vec<D>,
    mm: &[D],
    l: &super::dense::CholeskyFactor<D>,
    q: &[D],
    want_f: bool,
) -> Rates<D> {
    let n = mdot.len();
    let mut pdot = vec![D::from(0.0); n * n];
    for j in 0..n {
        for i in 0..n {
            pdot[i + j * n] = mm[i + j * n] + mm[j + i * n] + q[i + j * n];
        }
    }
    let f = want_f.then(|| {
        // F = Mᵀ P⁻¹ = (P⁻¹ M)ᵀ.
        let mut pm = mm.to_vec();
        l.solve_in_place(&mut pm);
        transpose(&pm, n, n)
    });
    (mdot, pdot, f)
}

/// The Kalman measurement update with the selection y = s[measured] + N(0, σ² I), skipping
/// missing (NaN) components; returns the log-likelihood of the innovation,
/// ln N(ν; 0, S) with S = H P Hᵀ + σ² I (the prediction-error decomposition, Kristensen et al.
/// 2004, (8)–(9)). `None` when S is not positive definite.
fn update<D: Scalar>(m: &mut [D], p: &mut [D], measured: &[usize], y: &[f64], sigma: D) -> Option<D> {
    let n = m.len();
    let idx: Vec<(usize, f64)> =
        measured.iter().zip(y).filter(|(_, yv)| !yv.is_nan()).map(|(&i, &yv)| (i, yv)).collect();
    let k = idx.len();
    if k == 0 {
        return Some(D::from(0.0));
    }
    let var = sigma * sigma;
    let mut s = vec![D::from(0.0); k * k];
    for (c, &(jc, _)) in idx.iter().enumerate() {
        for (r, &(jr, _)) in idx.iter().enumerate() {
            s[r + c * k] = p[jr + jc * n];
        }
        s[c + c * k] += var;
    }
    let l = cholesky(&s, k)?;
    let nu: Vec<D> = idx.iter().map(|&(j, yv)| D::from(yv) - m[j]).collect();
    let mut snu = nu.clone();
    l.solve_in_place(&mut snu);
    // P Hᵀ (n × k) and S⁻¹ H P (k × n).
    let mut pht = vec![D::from(0.0); n * k];
    for (c, &(jc, _)) in idx.iter().enumerate() {
        for r in 0..n {
            pht[r + c * n] = p[r + jc * n];
        }
    }
    let mut sinv_hp = transpose(&pht, n, k);
    l.solve_in_place(&mut sinv_hp);
    for i in 0..n {
        for c in 0..k {
            m[i] += pht[i + c * n] * snu[c];
        }
    }
    let correction = matmul(&pht, &sinv_hp, n, k, n);
    for i in 0..n * n {
        p[i] -= correction[i];
    }
    symmetrize_in_place(p, n);
    let quad: D = nu.iter().zip(&snu).map(|(&a, &b)| a * b).sum();
    Some(-(quad + l.log_det() + LN_2PI * k as f64) * 0.5)
}

/// Runs the filter at θ and returns the prediction-error log-likelihood Σ_k ln N(ν_k; 0, S_k),
/// or `Err(t)` with the time of a numerical failure (a covariance that stopped being positive
/// definite or a non-finite moment). When `store` is given, the moments and the transition
/// matrices are recorded on the grid for the smoother.
pub(crate) fn run<S: Sde + ?Sized, D: Scalar>(
    sde: &S,
    setup: &Setup,
    data: &Dataset,
    rule: &Rule,
    theta: &[D],
    mut store: Option<&mut Store>,
) -> std::result::Result<D, f64> {
    let n = setup.states;
    let noisy = setup.noisy;
    // Q = B Bᵀ with B = (G; 0).
    let mut g = vec![D::from(0.0); noisy * noisy];
    sde.diffusion(theta, &mut g);
    let mut q = vec![D::from(0.0); n * n];
    for j in 0..noisy {
        for i in 0..noisy {
            q[i + j * n] = (0..noisy).map(|k| g[i + k * noisy] * g[j + k * noisy]).sum();
        }
    }
    let dynamics = MomentDynamics { sde, rule, theta, q: &q };
    let sigma = setup.sigma.value(theta).ok_or(setup.nodes[0].t)?;
    let mut m: Vec<D> = setup.m0.iter().map(|&v| D::from(v)).collect();
    let mut p: Vec<D> = setup.p0.iter().map(|&v| D::from(v)).collect();
    let mut loglik = D::from(0.0);
    let mut t_prev = setup.nodes[0].t;
    let mut phi: Vec<D> = Vec::new();
    for node in &setup.nodes {
        let h = if node.steps > 0 { (node.t - t_prev) / node.steps as f64 } else { 0.0 };
        for s in 0..node.steps {
            let t = t_prev + s as f64 * h;
            let phi_arg = store.is_some().then_some(&mut phi);
            dynamics.refined_step(t, h, &mut m, &mut p, phi_arg, 0).ok_or(t)?;
            if let Some(st) = store.as_deref_mut() {
                st.phi.push(DMatrix::from_iterator(n, n, phi.iter().map(|v| v.re())));
                if s + 1 < node.steps {
                    let t_next = t_prev + (s + 1) as f64 * h;
                    let gm = to_gaussian(&m, &p, n);
                    st.times.push(t_next);
                    st.measured.push(false);
                    st.predicted.push(gm.clone());
                    st.filtered.push(gm);
                }
            }
        }
        let predicted = store.is_some().then(|| to_gaussian(&m, &p, n));
        let mut was_measured = false;
        if let Some(row) = node.row {
            let y = &data.values[row];
            was_measured = y.iter().any(|v| !v.is_nan());
            loglik += update(&mut m, &mut p, &setup.measured, y, sigma).ok_or(node.t)?;
            if m.iter().chain(p.iter()).any(|v| !v.re().is_finite()) {
                return Err(node.t);
            }
        }
        if let Some(st) = store.as_deref_mut() {
            st.times.push(node.t);
            st.measured.push(was_measured);
            st.predicted.push(predicted.expect("stored"));
            st.filtered.push(to_gaussian(&m, &p, n));
        }
        t_prev = node.t;
    }
    if !loglik.re().is_finite() {
        return Err(t_prev);
    }
    Ok(loglik)
}

/// The Rauch–Tung–Striebel backward pass over the grid: with the filtered (m_j, P_j), the
/// predicted (m⁻_{j+1}, P⁻_{j+1}) and the transition Φ_j of step j → j+1, the cross-covariance
/// Cov(s_j, s_{j+1}) ≈ P_j Φ_jᵀ gives the gain G_j = P_j Φ_jᵀ (P⁻_{j+1})⁻¹ and
///
/// m^s_j = m_j + G_j (m^s_{j+1} − m⁻_{j+1}),  P^s_j = P_j + G_j (P^s_{j+1} − P⁻_{j+1}) G_jᵀ
///
/// (Rauch, Tung & Striebel 1965; Särkkä 2008, (9) for the unscented cross-covariance;
/// exact for a linear SDE whose moment ODEs are integrated exactly). `Err(t)` when a predicted
/// covariance is singular.
pub(crate) fn smooth(store: &Store) -> std::result::Result<Vec<Gaussian>, f64> {
    let len = store.filtered.len();
    let mut out = store.filtered.clone();
    for j in (0..len.saturating_sub(1)).rev() {
        let f = &store.filtered[j];
        let pred = &store.predicted[j + 1];
        let cross = &f.cov * store.phi[j].transpose(); // Cov(s_j, s_{j+1})
        let chol = pred.cov.clone().cholesky().ok_or(store.times[j + 1])?;
        let gain = chol.solve(&cross.transpose()).transpose();
        let next = &out[j + 1];
        let dm = nalgebra::DVector::from_iterator(
            f.mean.len(),
            next.mean.iter().zip(&pred.mean).map(|(a, b)| a - b),
        );
        let mean: Vec<f64> =
            (nalgebra::DVector::from_column_slice(&f.mean) + &gain * dm).iter().copied().collect();
        let mut cov = &f.cov + &gain * (&next.cov - &pred.cov) * gain.transpose();
        cov = (&cov + cov.transpose()) * 0.5;
        if mean.iter().chain(cov.iter()).any(|v| !v.is_finite()) {
            return Err(store.times[j]);
        }
        out[j] = Gaussian { mean, cov };
    }
    Ok(out)
}
