//! The bootstrap particle filter and the forward-filtering backward-simulation (FFBSi)
//! smoother, for any measurement likelihood.
//!
//! # Filter
//!
//! N particles start from the initial-state priors at the initial time t₀ and are propagated
//! between consecutive times (t₀ and the measurement times) by Euler–Maruyama substeps
//! (`000_74b95e149527c64e.txt (3.1)`) of equal size h ≤ [`ParticleOptions::dt`],
//! s ← s + a(t, s) h + B ΔW with ΔW ~ N(0, h I) and B = (G; 0). At a measurement time each
//! weight is multiplied by the likelihood ψ(y_k | s, θ) of the [`Observation`] (any law;
//! missing components are skipped by the observation). Before each propagation the particles
//! are resampled by systematic resampling (Kitagawa 1996) when the effective sample size
//! 1/Σ wᵢ² falls below [`ParticleOptions::ess_threshold`] · N (Gordon, Salmond & Smith 1993;
//! Doucet & Johansen 2011, Sec. 4). The log of the product of the weight normalisers estimates
//! ln p(y_0, …, y_N | θ).
//!
//! # Smoother
//!
//! FFBSi (Godsill, Doucet & West 2004) for the model *as discretised by the filter*: the state
//! of the Markov chain at time t_k is the particle's segment of Euler–Maruyama points on
//! (t_{k−1}, t_k]. Given the next segment, whose first point u was drawn from the Euler step
//! N(s_k + a(t_k, s_k) h, G Gᵀ h) out of the particle s_k at t_k, the backward kernel is
//! proportional to w_k^i · N(u; s_k^i + a(t_k, s_k^i) h, G Gᵀ h): only the first substep of
//! each interval enters, so the smoother is exact for the Euler-discretised SDE at the cost
//! O(N M) per measurement for M backward paths. The smoothed path is reported at t₀ and the
//! measurement times, as the mean and standard deviation of the M backward paths.
//!
//! With clean states the Euler step is degenerate (a Dirac in z), the backward kernel is not
//! defined, and the smoother falls back to the ancestral paths of the filter (Kitagawa 1996):
//! M final particles drawn by weight and traced back through their resampling ancestors —
//! consistent, but degenerate for long records. The report's details name the smoother used.
//!
//! References: N. J. Gordon, D. J. Salmond, A. F. M. Smith, IEE Proc. F 140(2), 1993;
//! G. Kitagawa, J. Comput. Graph. Stat. 5(1), 1996; S. J. Godsill, A. Doucet, M. West,
//! "Monte Carlo smoothing for nonlinear time series", JASA 99, 2004; A. Doucet, A. M. Johansen,
//! "A tutorial on particle filtering and smoothing: fifteen years later", 2011.

#[cfg(test)]
mod tests;

use std::time::Instant;

use rand::{Rng, RngExt};
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::data::StatePath;
use crate::estimate::{Details, EstimationProblem, Method, MethodRun, PathEstimate, Status};
use crate::estimator::EstimatorOptions;
use crate::kalman::{build_nodes, Node};
use crate::model::observation::StateMeasurement;
use crate::model::{Observation, Sde};
use crate::{Error, Result};

/// Options of the particle smoother (`particle`). Its random numbers come from the problem's
/// seed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[non_exhaustive]
pub struct ParticleOptions {
    /// Number of particles N ≥ 2. Default 1000.
    pub particles: usize,
    /// Number of backward paths M ≥ 1. Default (`None`): min(N, 500).
    pub backward_paths: Option<usize>,
    /// Resample when the effective sample size is below this fraction of N, in [0, 1].
    /// Default 0.5.
    pub ess_threshold: f64,
    /// Largest Euler–Maruyama substep. Default (`None`): a tenth of the median interval
    /// between the initial time and the measurement times, at most 0.01 (as the Kalman
    /// methods, [`crate::kalman::KalmanOptions::dt`]).
    pub dt: Option<f64>,
}

impl Default for ParticleOptions {
    fn default() -> Self {
        ParticleOptions { particles: 1000, backward_paths: None, ess_threshold: 0.5, dt: None }
    }
}

impl ParticleOptions {
    /// Sets the number of particles.
    pub fn with_particles(mut self, particles: usize) -> Self {
        self.particles = particles;
        self
    }

    /// Sets the number of backward paths.
    pub fn with_backward_paths(mut self, paths: usize) -> Self {
        self.backward_paths = Some(paths);
        self
    }

    /// Sets the largest substep.
    pub fn with_dt(mut self, dt: f64) -> Self {
        self.dt = Some(dt);
        self
    }
}

impl EstimatorOptions for ParticleOptions {
    /// `particle`: [`estimate`] with its random numbers seeded by the problem's seed.
    fn run<S: Sde + ?Sized>(
        &self,
        _: Method,
        problem: &EstimationProblem<'_, S, StateMeasurement>,
    ) -> Result<MethodRun> {
        let mut rng = <rand::rngs::StdRng as rand::SeedableRng>::seed_from_u64(problem.seed);
        estimate(problem, self, &mut rng).map(MethodRun::from)
    }

    /// Checks N ≥ 2, M ≥ 1, the ESS threshold in [0, 1] and a positive finite `dt`.
    fn validate(&self) -> Result<()> {
        let bad = |name: &str, reason: String| Err(Error::InvalidOption { name: name.into(), reason });
        if self.particles < 2 {
            return bad("particles", format!("must be at least 2, got {}", self.particles));
        }
        if self.backward_paths == Some(0) {
            return bad("backward_paths", "must be at least 1".into());
        }
        if !(0.0..=1.0).contains(&self.ess_threshold) {
            return bad("ess_threshold", format!("must lie in [0, 1], got {}", self.ess_threshold));
        }
        crate::error::check_positive("dt", self.dt)
    }
}

/// Which smoother produced the backward paths.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Smoother {
    /// Forward-filtering backward-simulation (models without clean states).
    #[serde(rename = "ffbsi")]
    Ffbsi,
    /// Ancestral paths of the filter (models with clean states).
    #[serde(rename = "ancestral-paths")]
    Ancestral,
}

/// The details of a particle estimate's report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ParticleDetails {
    /// The filter's estimate of ln p(y | θ).
    pub log_likelihood: f64,
    /// N.
    pub particles: usize,
    /// M, the backward paths.
    pub backward_paths: usize,
    /// Resampling steps.
    pub resamplings: usize,
    /// The smallest effective sample size.
    pub min_ess: f64,
    /// The smoother.
    pub smoother: Smoother,
    /// The substep.
    pub dt: f64,
    /// The time at which every particle's weight vanished, if it happened.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub failed_at: Option<f64>,
}

impl Smoother {
    /// The name written in reports.
    pub fn name(self) -> &'static str {
        match self {
            Smoother::Ffbsi => "ffbsi",
            Smoother::Ancestral => "ancestral-paths",
        }
    }
}

/// The output of [`smooth`]: M backward paths at t₀ and the measurement times.
#[derive(Debug, Clone)]
pub struct ParticleSmoothing {
    /// t₀ (when before the first measurement) and the measurement times.
    pub times: Vec<f64>,
    /// The backward paths: `paths[p][k]` is the state (noisy then clean) of path p at
    /// `times[k]`.
    pub paths: Vec<Vec<Vec<f64>>>,
    /// The filter's estimate of ln p(y_0, …, y_N | θ).
    pub log_likelihood: f64,
    /// The effective sample size after each measurement update.
    pub ess: Vec<f64>,
    /// Number of resampling steps.
    pub resamplings: usize,
    /// The smoother used.
    pub smoother: Smoother,
    /// [`Status::Converged`], or [`Status::NumericalFailure`] when every particle had zero
    /// likelihood (the paths then end at `failed_at`).
    pub status: Status,
    /// Time at which all weights vanished, if that happened.
    pub failed_at: Option<f64>,
    /// The substep used (the largest; each interval has equal substeps).
    pub dt: f64,
}

impl ParticleSmoothing {
    /// The mean and standard deviation of the backward paths at each time.
    pub fn mean_and_sd(&self) -> (Vec<Vec<f64>>, Vec<Vec<f64>>) {
        let m = self.paths.len() as f64;
        let nt = self.paths.first().map_or(0, |p| p.len());
        let dim = self.paths.first().and_then(|p| p.first()).map_or(0, |s| s.len());
        let mut mean = vec![vec![0.0; dim]; nt];
        let mut sd = vec![vec![0.0; dim]; nt];
        for k in 0..nt {
            for i in 0..dim {
                let mu = self.paths.iter().map(|p| p[k][i]).sum::<f64>() / m;
                let var = self.paths.iter().map(|p| (p[k][i] - mu).powi(2)).sum::<f64>() / (m - 1.0).max(1.0);
                mean[k][i] = mu;
                sd[k][i] = var.sqrt();
            }
        }
        (mean, sd)
    }
}

/// Systematic resampling (Kitagawa 1996): N indices from normalised weights with one uniform.
fn systematic<R: Rng + ?Sized>(w: &[f64], rng: &mut R, out: &mut [usize]) {
    let n = out.len();
    let u0: f64 = rng.random::<f64>() / n as f64;
    let mut cum = w[0];
    let mut i = 0;
    for (k, o) in out.iter_mut().enumerate() {
        let u = u0 + k as f64 / n as f64;
        while u > cum && i + 1 < w.len() {
            i += 1;
            cum += w[i];
        }
        *o = i;
    }
}

/// One index drawn from unnormalised log-weights.
fn draw_log<R: Rng + ?Sized>(lw: &[f64], scratch: &mut Vec<f64>, rng: &mut R) -> Option<usize> {
    scratch.resize(lw.len(), 0.0);
    onsager_closures::normalize_log_weights(lw, scratch)?;
    let u: f64 = rng.random::<f64>();
    let mut cum = 0.0;
    for (i, &w) in scratch.iter().enumerate() {
        cum += w;
        if u < cum {
            return Some(i);
        }
    }
    scratch.iter().rposition(|&w| w > 0.0)
}

/// What is stored per node for the backward pass.
struct NodeStore {
    /// Particles (N × states, row-major).
    states: Vec<f64>,
    /// Logarithms of the normalised filter weights after the update.
    log_weights: Vec<f64>,
    /// Index at the previous node of each particle's parent.
    parent: Vec<usize>,
    /// G⁻¹ times the noisy part of the first Euler point of each particle's segment
    /// (N × noisy), the point after the node before.
    first: Vec<f64>,
    /// G⁻¹ times the mean of the first Euler step out of each particle at this node
    /// (N × noisy), so that the Euler log-density is −½ |first − next_mean|² / h.
    next_mean: Vec<f64>,
    /// The substep of the interval after this node.
    h_next: f64,
}

/// The model of a particle run: the SDE at θ with G and G⁻¹, and the sizes.
struct Model<'a, S: Sde + ?Sized> {
    sde: &'a S,
    theta: &'a [f64],
    g: nalgebra::DMatrix<f64>,
    g_inv: nalgebra::DMatrix<f64>,
    n_noisy: usize,
    dim: usize,
}

/// The filter's particles and weights between nodes.
struct Swarm {
    /// States (N × dim).
    states: Vec<f64>,
    /// Log-weights (unnormalised).
    lw: Vec<f64>,
    /// Normalised weights.
    w: Vec<f64>,
    /// Resampling indices (scratch).
    idx: Vec<usize>,
    /// Resampling steps so far.
    resamplings: usize,
}

impl<S: Sde + ?Sized> Model<'_, S> {
    /// From the node at `prev_t` (stored in `prev`) to `node`: systematic resampling when the
    /// ESS is below `ess_threshold` · N, the mean of the first Euler step out of each particle
    /// at the previous node (into `prev`), then Euler–Maruyama substeps. Returns the parents and
    /// G⁻¹ times the first Euler point of each particle, or `None` when a particle is no longer
    /// finite (the model returned NaN or infinity: the smoother then stops with a failed status).
    fn advance<R: Rng + ?Sized>(
        &self,
        swarm: &mut Swarm,
        (prev, prev_t): (&mut NodeStore, f64),
        node: &Node,
        ess_threshold: f64,
        rng: &mut R,
    ) -> Option<(Vec<usize>, Vec<f64>)> {
        let (n, dim, n_noisy) = (swarm.w.len(), self.dim, self.n_noisy);
        let mut parent: Vec<usize> = (0..n).collect();
        let mut first = vec![0.0; n * n_noisy];
        let mut drift = vec![0.0; dim];
        let mut dw = vec![0.0; n_noisy];
        let h = (node.t - prev_t) / node.steps as f64;
        let ess = 1.0 / swarm.w.iter().map(|v| v * v).sum::<f64>();
        let mut new_states = vec![0.0; n * dim];
        if ess < ess_threshold * n as f64 {
            systematic(&swarm.w, rng, &mut swarm.idx);
            swarm.resamplings += 1;
            for (j, &i) in swarm.idx.iter().enumerate() {
                parent[j] = i;
                new_states[j * dim..(j + 1) * dim].copy_from_slice(&swarm.states[i * dim..(i + 1) * dim]);
            }
            swarm.lw.iter_mut().for_each(|v| *v = 0.0);
        } else {
            new_states.copy_from_slice(&swarm.states);
            for (l, &wi) in swarm.lw.iter_mut().zip(&swarm.w) {
                *l = wi.ln();
            }
        }
        prev.h_next = h;
        let mut next_mean = vec![0.0; n * n_noisy];
        for i in 0..n {
            let s = &prev.states[i * dim..(i + 1) * dim];
            self.sde.state_drift(prev_t, s, self.theta, &mut drift);
            for r in 0..n_noisy {
                dw[r] = s[r] + drift[r] * h;
            }
            whiten(&self.g_inv, &dw, &mut next_mean[i * n_noisy..(i + 1) * n_noisy]);
        }
        prev.next_mean = next_mean;
        for j in 0..n {
            let s = &mut new_states[j * dim..(j + 1) * dim];
            for step in 0..node.steps {
                let t = prev_t + step as f64 * h;
                self.sde.state_drift(t, s, self.theta, &mut drift);
                for v in dw.iter_mut() {
                    let e: f64 = StandardNormal.sample(rng);
                    *v = e * h.sqrt();
                }
                for r in 0..dim {
                    let noise =
                        if r < n_noisy { (0..n_noisy).map(|c| self.g[(r, c)] * dw[c]).sum() } else { 0.0 };
                    s[r] += drift[r] * h + noise;
                }
                if step == 0 {
                    whiten(&self.g_inv, &s[..n_noisy], &mut first[j * n_noisy..(j + 1) * n_noisy]);
                }
            }
        }
        swarm.states = new_states;
        if swarm.states.iter().any(|v| !v.is_finite()) {
            return None;
        }
        Some((parent, first))
    }
}

/// `m_paths` backward paths through the stored nodes: ancestral (following the parents) or
/// FFBSi (reweighting by the Euler transition density of each particle's first step).
fn backward_paths<R: Rng + ?Sized>(
    store: &[NodeStore],
    smoother: Smoother,
    (m_paths, dim, n_noisy): (usize, usize, usize),
    rng: &mut R,
) -> Vec<Vec<Vec<f64>>> {
    let nt = store.len();
    let mut paths = vec![vec![vec![0.0; dim]; nt]; m_paths];
    let Some(last) = store.last() else { return paths };
    let mut scratch = Vec::new();
    let mut lwb = vec![0.0; last.log_weights.len()];
    for path in paths.iter_mut() {
        let mut j = draw_log(&last.log_weights, &mut scratch, rng).unwrap_or(0);
        path[nt - 1].copy_from_slice(&last.states[j * dim..(j + 1) * dim]);
        for k in (0..nt - 1).rev() {
            let node = &store[k];
            j = match smoother {
                Smoother::Ancestral => store[k + 1].parent[j],
                Smoother::Ffbsi => {
                    let u = &store[k + 1].first[j * n_noisy..(j + 1) * n_noisy];
                    let h = node.h_next;
                    let half_inv_h = 0.5 / h;
                    for ((l, &lwi), mu) in
                        lwb.iter_mut().zip(&node.log_weights).zip(node.next_mean.chunks_exact(n_noisy))
                    {
                        // ln wᵢ − ½ |G⁻¹(u − μᵢ)|² / h
                        let q: f64 = u.iter().zip(mu).map(|(a, b)| (a - b) * (a - b)).sum();
                        *l = lwi - q * half_inv_h;
                    }
                    draw_log(&lwb, &mut scratch, rng).unwrap_or(store[k + 1].parent[j])
                }
            };
            path[k].copy_from_slice(&node.states[j * dim..(j + 1) * dim]);
        }
    }
    paths
}

/// Runs the bootstrap particle filter and the backward smoother at `problem.theta`
/// (see the module documentation).
///
/// Errors: those of [`EstimationProblem::validate`]; [`Error::InvalidOption`] for bad options
/// or an initial time after the first measurement, or (from [`crate::model::prior::Prior::sample`])
/// an improper initial-state prior; [`Error::SingularDiffusion`].
pub fn smooth<S, O, R>(
    problem: &EstimationProblem<'_, S, O>,
    options: &ParticleOptions,
    rng: &mut R,
) -> Result<ParticleSmoothing>
where
    S: Sde + ?Sized,
    O: Observation + ?Sized,
    R: Rng + ?Sized,
{
    problem.validate()?;
    options.validate()?;
    let sde = problem.sde;
    let d = sde.dims();
    let (n_noisy, dim) = (d.noisy, d.states());
    let theta = problem.theta;
    let g = sde.diffusion_matrix(theta)?;
    let g_inv = g
        .clone()
        .try_inverse()
        .ok_or_else(|| Error::SingularDiffusion { reason: "G(theta) is singular".into() })?;
    let model = Model { sde, theta, g, g_inv, n_noisy, dim };
    let data = problem.data;
    let t0 = problem.t0;
    let dt = options.dt.unwrap_or_else(|| crate::kalman::default_step(t0, &data.times));
    let nodes = build_nodes(&data.times, t0, dt)?;
    let n = options.particles;
    let m_paths = options.backward_paths.unwrap_or(n.min(500));
    // Stored per node: the particles, weights, parents and Euler points (`NodeStore`), and the
    // backward paths.
    let per_particle = 8.0 * dim as f64 + 16.0 + 16.0 * n_noisy as f64;
    let bytes = nodes.len() as f64 * (n as f64 * per_particle + m_paths as f64 * 8.0 * dim as f64);
    let size = format!("{n} particles (`particles`) × {} times × {dim} states", nodes.len());
    problem.max_memory.check("`particle`", size, bytes)?;
    let smoother = if d.clean == 0 { Smoother::Ffbsi } else { Smoother::Ancestral };

    // Initial particles from the priors.
    let mut states = vec![0.0; n * dim];
    for i in 0..n {
        for (j, prior) in problem.x0_prior.iter().chain(problem.z0_prior).enumerate() {
            states[i * dim + j] = prior.sample(rng)?;
        }
    }
    let mut swarm =
        Swarm { states, lw: vec![0.0; n], w: vec![1.0 / n as f64; n], idx: vec![0usize; n], resamplings: 0 };
    let mut log_likelihood = 0.0;
    let mut ess_list = Vec::new();
    let mut store: Vec<NodeStore> = Vec::with_capacity(nodes.len());
    let mut failed_at = None;
    for (k, node) in nodes.iter().enumerate() {
        let (parent, first) = if k > 0 {
            let prev = store.last_mut().expect("a previous node");
            match model.advance(&mut swarm, (prev, nodes[k - 1].t), node, options.ess_threshold, rng) {
                Some(advanced) => advanced,
                None => {
                    failed_at = Some(node.t);
                    break;
                }
            }
        } else {
            ((0..n).collect(), vec![0.0; n * n_noisy])
        };
        // Measurement update.
        let Swarm { states, lw, w, .. } = &mut swarm;
        if let Some(row) = node.row {
            let y = &data.values[row];
            let before = onsager_closures::normalize_log_weights(lw, w).unwrap_or(f64::NAN);
            for i in 0..n {
                let s = &states[i * dim..(i + 1) * dim];
                let ll = problem.observation.log_likelihood(node.t, y, &s[..n_noisy], &s[n_noisy..], theta);
                lw[i] += if ll.is_nan() { f64::NEG_INFINITY } else { ll };
            }
            match onsager_closures::normalize_log_weights(lw, w) {
                Some(after) => log_likelihood += after - before,
                None => {
                    failed_at = Some(node.t);
                    break;
                }
            }
            ess_list.push(1.0 / w.iter().map(|v| v * v).sum::<f64>());
        } else {
            onsager_closures::normalize_log_weights(lw, w);
        }
        store.push(NodeStore {
            states: states.clone(),
            log_weights: w.iter().map(|v| v.ln()).collect(),
            parent,
            first,
            next_mean: Vec::new(),
            h_next: 0.0,
        });
    }
    let times: Vec<f64> = nodes[..store.len()].iter().map(|nd| nd.t).collect();
    let paths = backward_paths(&store, smoother, (m_paths, dim, n_noisy), rng);
    Ok(ParticleSmoothing {
        times,
        paths,
        log_likelihood: if failed_at.is_some() { f64::NAN } else { log_likelihood },
        ess: ess_list,
        resamplings: swarm.resamplings,
        smoother,
        status: if failed_at.is_some() { Status::NumericalFailure } else { Status::Converged },
        failed_at,
        dt,
    })
}

/// out = G⁻¹ v.
fn whiten(g_inv: &nalgebra::DMatrix<f64>, v: &[f64], out: &mut [f64]) {
    for (a, o) in out.iter_mut().enumerate() {
        *o = v.iter().enumerate().map(|(c, &vc)| g_inv[(a, c)] * vc).sum();
    }
}

/// The particle smoother as an estimator: the mean and standard deviation of the backward
/// paths at t₀ and the measurement times, at `problem.theta`. The details hold the
/// log-likelihood estimate, N, M, the number of resamplings, the smallest ESS, the smoother
/// used and the substep.
///
/// Errors: those of [`smooth`]; [`Error::InvalidOption`] (name `estimate`) when
/// `problem.estimate` is not empty.
pub fn estimate<S, O, R>(
    problem: &EstimationProblem<'_, S, O>,
    options: &ParticleOptions,
    rng: &mut R,
) -> Result<PathEstimate>
where
    S: Sde + ?Sized,
    O: Observation + ?Sized,
    R: Rng + ?Sized,
{
    if !problem.estimate.is_empty() {
        return Err(Error::InvalidOption {
            name: "estimate".into(),
            reason: "`particle` does not estimate parameters (use `pem` or a MAP method)".into(),
        });
    }
    let start = Instant::now();
    let out = smooth(problem, options, rng)?;
    let (mean, sd) = out.mean_and_sd();
    let details = ParticleDetails {
        log_likelihood: out.log_likelihood,
        particles: options.particles,
        backward_paths: out.paths.len(),
        resamplings: out.resamplings,
        min_ess: out.ess.iter().copied().fold(f64::INFINITY, f64::min),
        smoother: out.smoother,
        dt: out.dt,
        failed_at: out.failed_at,
    };
    Ok(PathEstimate {
        method: Method::Particle,
        path: StatePath {
            names: problem.sde.state_names(),
            times: out.times.clone(),
            values: mean,
            sd: Some(sd),
        },
        theta_names: problem.sde.param_names(),
        theta: problem.theta.to_vec(),
        estimated: Vec::new(),
        theta_sd: None,
        status: out.status,
        iterations: 0,
        solve_seconds: start.elapsed().as_secs_f64(),
        details: Details::new(details),
    })
}
