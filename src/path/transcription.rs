//! The transcribed nonlinear program of a path-space MAP problem: variables, per-block merit
//! terms and constraints, and their exact derivatives by automatic differentiation, scattered
//! into fixed sparsity patterns.
//!
//! The program is a sum of small *blocks*, each depending on a few variables (its local
//! vector): one block per interval (piece) of the grid carrying the dynamics' merit terms and
//! the clean-state (and, for Hermite–Simpson, the noisy-state) defect constraints, one block
//! per measurement node carrying ln ψ, and one block carrying the log-priors of x0, z0 and the
//! estimated θ. Each block's value, gradient, Hessian and constraint Jacobian are computed on
//! its dense local vector by [`ad`] and scattered into the global patterns through index lists
//! computed once, before the first iteration.

use std::ops::AddAssign;

use num_dual::Dual;

use super::{Grid, Merit, Transcription};
use crate::estimate::EstimationProblem;
use crate::model::ad::{self, ScalarFn, VectorFn};
use crate::model::{Observation, Scalar, Sde};
use crate::nlp::NlpProblem;

/// Length of the stack buffers of the per-point AD evaluations (θ, the rate); longer vectors
/// fall back to the heap.
const STACK_LEN: usize = 8;

/// The four parts of the log-merit of a path (all are log-densities, to be maximised).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MeritParts<D = f64> {
    /// Σ ln ψ(y_k | x(t_k), z(t_k), θ) over the measurements.
    pub log_likelihood: D,
    /// ln of the priors of x0, z0 and the estimated θ.
    pub log_prior: D,
    /// −½∫|w|² dt (Hermite–Simpson), or its discrete analogue
    /// −½Σ δ‖Δx/δ − f‖²_Q − N ln|det G| (Euler, trapezoidal, `001_8aefdf0570c96f51.txt (16)`,
    /// `(21)`).
    pub energy: D,
    /// −½∫div_x f dt for the Onsager–Machlup merit (Simpson's rule), or the trapezoidal
    /// scheme's Σ ln det(I − ½δ∇_x f(t_{k+1}, x_{k+1})) (`001_8aefdf0570c96f51.txt (21)`);
    /// zero for the energy merit and the Euler scheme.
    pub divergence: D,
}

impl<D: Scalar> MeritParts<D> {
    fn zero() -> Self {
        let z = D::from(0.0);
        MeritParts { log_likelihood: z, log_prior: z, energy: z, divergence: z }
    }

    /// The total log-merit.
    pub fn total(&self) -> D {
        self.log_likelihood + self.log_prior + self.energy + self.divergence
    }
}

impl<D: Scalar> AddAssign for MeritParts<D> {
    fn add_assign(&mut self, o: Self) {
        self.log_likelihood += o.log_likelihood;
        self.log_prior += o.log_prior;
        self.energy += o.energy;
        self.divergence += o.divergence;
    }
}

#[derive(Debug, Clone, Copy)]
enum BlockKind {
    /// Interval / piece k of the grid.
    Interval(usize),
    /// The measurement in data row `row`, at grid node `node`.
    Measurement { row: usize, node: usize },
    /// The priors of x0, z0 and θ.
    Prior,
}

#[derive(Debug, Clone)]
struct Block {
    kind: BlockKind,
    /// Global indices of the local variables, in local order.
    vars: Vec<usize>,
    /// First constraint row and number of rows.
    row0: usize,
    rows: usize,
    /// First slot of this block in the Jacobian and Hessian value arrays.
    jac0: usize,
    hess0: usize,
}

/// The nonlinear program of a transcribed path-space MAP problem (minimise the negative
/// log-merit subject to the defect constraints), implementing [`NlpProblem`].
///
/// Variables, in order: the states s_k = [x_k; z_k] at the grid nodes k = 0..N; for
/// Hermite–Simpson, the states at the piece midpoints and the noise coefficients (a_k, b_k)
/// of each piece; the estimated components of θ.
pub struct PathNlp<'a, S: Sde + ?Sized, O: Observation + ?Sized> {
    problem: &'a EstimationProblem<'a, S, O>,
    merit: Merit,
    transcription: Transcription,
    grid: Grid,
    n_vars: usize,
    n_cons: usize,
    blocks: Vec<Block>,
    n_jac: usize,
    n_hess: usize,
    /// G(θ), column-major, for Hermite–Simpson (where no estimated θ enters it).
    g_fixed: Vec<f64>,
    initial: Vec<f64>,
    lower: Vec<f64>,
    upper: Vec<f64>,
}

impl<'a, S: Sde + ?Sized, O: Observation + ?Sized> PathNlp<'a, S, O> {
    /// Builds the program on `grid` with the initial state path `guess` (one row of states per
    /// grid node; midpoints are interpolated linearly and the noise coefficients start at 0).
    /// Callers go through [`super::estimate_path`], which checks the inputs.
    pub(super) fn new(
        problem: &'a EstimationProblem<'a, S, O>,
        merit: Merit,
        transcription: Transcription,
        grid: Grid,
        guess: &[Vec<f64>],
    ) -> Self {
        let d = problem.sde.dims();
        let (ns, nx) = (d.states(), d.noisy);
        let n = grid.intervals;
        let ne = problem.estimate.len();
        let hs = transcription == Transcription::HermiteSimpson;
        let mid0 = (n + 1) * ns;
        let noise0 = mid0 + if hs { n * ns } else { 0 };
        let theta0 = noise0 + if hs { n * 2 * nx } else { 0 };
        let n_vars = theta0 + ne;
        let theta_vars: Vec<usize> = (theta0..n_vars).collect();
        let node = |k: usize| (k * ns..(k + 1) * ns).collect::<Vec<usize>>();

        let mut blocks = Vec::new();
        let mut row = 0;
        let rows_per_interval = if hs { 2 * ns } else { d.clean };
        for k in 0..n {
            let mut vars = node(k);
            if hs {
                vars.extend(mid0 + k * ns..mid0 + (k + 1) * ns);
            }
            vars.extend(node(k + 1));
            if hs {
                vars.extend(noise0 + k * 2 * nx..noise0 + (k + 1) * 2 * nx);
            }
            vars.extend(&theta_vars);
            blocks.push(Block {
                kind: BlockKind::Interval(k),
                vars,
                row0: row,
                rows: rows_per_interval,
                jac0: 0,
                hess0: 0,
            });
            row += rows_per_interval;
        }
        for (r, &nd) in grid.measurement_nodes.iter().enumerate() {
            let mut vars = node(nd);
            vars.extend(&theta_vars);
            blocks.push(Block {
                kind: BlockKind::Measurement { row: r, node: nd },
                vars,
                row0: row,
                rows: 0,
                jac0: 0,
                hess0: 0,
            });
        }
        let mut vars = node(0);
        vars.extend(&theta_vars);
        blocks.push(Block { kind: BlockKind::Prior, vars, row0: row, rows: 0, jac0: 0, hess0: 0 });
        let (mut jac, mut hess) = (0, 0);
        // Hermite–Simpson pieces: the Hessian is block-diagonal over the three Lobatto points'
        // (s_i, θ_e) plus the noise diagonal (see `hs_hessian_into`); other blocks are dense
        let npt = ns + ne;
        for b in &mut blocks {
            b.jac0 = jac;
            b.hess0 = hess;
            let nv = b.vars.len();
            jac += b.rows * nv;
            hess += match (hs, b.kind) {
                (true, BlockKind::Interval(_)) => 3 * npt * (npt + 1) / 2 + 2 * nx,
                _ => nv * (nv + 1) / 2,
            };
        }
        let mut g_fixed = vec![0.0; nx * nx];
        if hs {
            // G does not depend on an estimated θ for Hermite–Simpson (checked by the caller)
            problem.sde.diffusion(problem.theta, &mut g_fixed);
        }

        let mut initial = vec![0.0; n_vars];
        for (k, s) in guess.iter().enumerate().take(n + 1) {
            initial[k * ns..(k + 1) * ns].copy_from_slice(s);
        }
        if hs {
            for k in 0..n {
                for i in 0..ns {
                    initial[mid0 + k * ns + i] = 0.5 * (guess[k][i] + guess[k + 1][i]);
                }
            }
        }
        for (j, &i) in problem.estimate.iter().enumerate() {
            initial[theta0 + j] = problem.theta[i];
        }
        let mut lower = vec![f64::NEG_INFINITY; n_vars];
        let mut upper = vec![f64::INFINITY; n_vars];
        for (i, p) in problem.x0_prior.iter().chain(problem.z0_prior).enumerate() {
            lower[i] = p.lower;
            upper[i] = p.upper;
            initial[i] = initial[i].clamp(p.lower, p.upper);
        }
        for (j, &i) in problem.estimate.iter().enumerate() {
            lower[theta0 + j] = problem.theta_prior[i].lower;
            upper[theta0 + j] = problem.theta_prior[i].upper;
        }
        PathNlp {
            problem,
            merit,
            transcription,
            grid,
            n_vars,
            n_cons: row,
            blocks,
            n_jac: jac,
            n_hess: hess,
            g_fixed,
            initial,
            lower,
            upper,
        }
    }

    /// The grid of the transcription.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The states at the grid nodes of a variable vector `w`, one row per node.
    pub fn node_states(&self, w: &[f64]) -> Vec<Vec<f64>> {
        let ns = self.problem.sde.dims().states();
        (0..=self.grid.intervals).map(|k| w[k * ns..(k + 1) * ns].to_vec()).collect()
    }

    /// The full θ of a variable vector `w` (fixed components from the problem).
    pub fn theta(&self, w: &[f64]) -> Vec<f64> {
        let ne = self.problem.estimate.len();
        self.theta_full(&w[self.n_vars - ne..])
    }

    /// Writes the noise coefficients of a Hermite–Simpson piece into `w`: the noise on piece k
    /// is w(t_k + σh) = a_k + (σ − ½) b_k, σ ∈ [0, 1] (no effect for the other transcriptions).
    pub fn set_piece_noise(&self, w: &mut [f64], k: usize, a: &[f64], b: &[f64]) {
        if self.transcription != Transcription::HermiteSimpson {
            return;
        }
        let d = self.problem.sde.dims();
        let (ns, nx, n) = (d.states(), d.noisy, self.grid.intervals);
        let off = (n + 1) * ns + n * ns + k * 2 * nx;
        w[off..off + nx].copy_from_slice(a);
        w[off + nx..off + 2 * nx].copy_from_slice(b);
    }

    /// The parts of the log-merit at `w` (see [`MeritParts`]).
    pub fn merit_parts(&self, w: &[f64]) -> MeritParts<f64> {
        let mut parts = MeritParts::zero();
        for b in &self.blocks {
            parts += with_buffer(b.vars.len(), |local| {
                Self::locals_into(b, w, local);
                self.block_merit(b, local)
            });
        }
        parts
    }

    fn theta_full<D: Scalar>(&self, est: &[D]) -> Vec<D> {
        let mut theta: Vec<D> = self.problem.theta.iter().map(|&v| D::from(v)).collect();
        for (j, &i) in self.problem.estimate.iter().enumerate() {
            theta[i] = est[j];
        }
        theta
    }

    /// Calls `f` with the full θ (fixed values with the estimated ones `est` put in), held on
    /// the stack when θ is short, so the per-point AD evaluations do not allocate.
    fn with_theta<D: Scalar, R>(&self, est: &[D], f: impl FnOnce(&[D]) -> R) -> R {
        let nt = self.problem.theta.len();
        if nt > STACK_LEN {
            return f(&self.theta_full(est));
        }
        let mut buf = [D::from(0.0); STACK_LEN];
        for (b, &v) in buf.iter_mut().zip(self.problem.theta.iter()) {
            *b = D::from(v);
        }
        for (j, &i) in self.problem.estimate.iter().enumerate() {
            buf[i] = est[j];
        }
        f(&buf[..nt])
    }

    /// The log-merit contribution of a block at its local vector.
    fn block_merit<D: Scalar>(&self, b: &Block, w: &[D]) -> MeritParts<D> {
        let ne = self.problem.estimate.len();
        self.with_theta(&w[w.len() - ne..], |theta| self.block_merit_theta(b, w, theta))
    }

    /// [`Self::block_merit`] given the full θ.
    fn block_merit_theta<D: Scalar>(&self, b: &Block, w: &[D], theta: &[D]) -> MeritParts<D> {
        let p = self.problem;
        let d = p.sde.dims();
        let (ns, nx) = (d.states(), d.noisy);
        let mut out = MeritParts::zero();
        match b.kind {
            BlockKind::Measurement { row, node } => {
                let s = &w[..ns];
                let t = self.grid.time(node);
                out.log_likelihood =
                    p.observation.log_likelihood(t, &p.data.values[row], &s[..nx], &s[nx..], theta);
            }
            BlockKind::Prior => {
                let mut lp = D::from(0.0);
                for (i, pr) in p.x0_prior.iter().chain(p.z0_prior).enumerate() {
                    lp += pr.log_density(w[i]);
                }
                for &i in p.estimate {
                    lp += p.theta_prior[i].log_density(theta[i]);
                }
                out.log_prior = lp;
            }
            BlockKind::Interval(k) => {
                let h = self.grid.step;
                let (t0, t1) = (self.grid.time(k), self.grid.time(k + 1));
                match self.transcription {
                    Transcription::Euler | Transcription::Trapezoidal => {
                        let (s0, s1) = (&w[..ns], &w[ns..2 * ns]);
                        let mut r = vec![D::from(0.0); nx];
                        p.sde.drift(D::from(t0), &s0[..nx], &s0[nx..], theta, &mut r);
                        if self.transcription == Transcription::Trapezoidal {
                            // 001 (21): the mean of the drifts at both ends.
                            let mut f1 = vec![D::from(0.0); nx];
                            p.sde.drift(D::from(t1), &s1[..nx], &s1[nx..], theta, &mut f1);
                            for (a, b) in r.iter_mut().zip(&f1) {
                                *a = (*a + *b) * 0.5;
                            }
                            out.divergence = log_det_implicit(p.sde, t1, h, s1, nx, theta);
                        }
                        // residual Δx/δ − f̄
                        for i in 0..nx {
                            r[i] = (s1[i] - s0[i]) / h - r[i];
                        }
                        // −½ δ ‖G⁻¹ r‖² − ln|det G|, 001 (16), (21).
                        out.energy = match half_sq_ginv(p.sde, theta, &mut r) {
                            Some((e, logdet)) => -(e * h) - logdet,
                            None => D::from(f64::NAN),
                        };
                    }
                    Transcription::HermiteSimpson => {
                        // Linear-in-time noise per piece: w(σ) = a + (σ − ½) b. Simpson's rule
                        // integrates ½|w|² exactly: h (½|a|² + |b|²/24).
                        let off = 3 * ns;
                        let (a, bb) = (&w[off..off + nx], &w[off + nx..off + 2 * nx]);
                        let sa: D = a.iter().map(|&v| v * v).sum();
                        let sb: D = bb.iter().map(|&v| v * v).sum();
                        out.energy = -(sa * 0.5 + sb / 24.0) * h;
                        if self.merit == Merit::OnsagerMachlup {
                            let tm = 0.5 * (t0 + t1);
                            let (s0, sm, s1) = (&w[..ns], &w[ns..2 * ns], &w[2 * ns..3 * ns]);
                            let div =
                                |t: f64, s: &[D]| p.sde.divergence(D::from(t), &s[..nx], &s[nx..], theta);
                            // −½ ∫ div_x f dt by Simpson's rule, 000 (2.49).
                            out.divergence = -(div(t0, s0) + div(tm, sm) * 4.0 + div(t1, s1)) * (h / 12.0);
                        }
                    }
                }
            }
        }
        out
    }

    /// The defect constraints of a block at its local vector (`out.len() == b.rows`).
    fn block_constraints<D: Scalar>(&self, b: &Block, w: &[D], out: &mut [D]) {
        let ne = self.problem.estimate.len();
        self.with_theta(&w[w.len() - ne..], |theta| self.block_constraints_theta(b, w, theta, out))
    }

    /// [`Self::block_constraints`] given the full θ.
    fn block_constraints_theta<D: Scalar>(&self, b: &Block, w: &[D], theta: &[D], out: &mut [D]) {
        let BlockKind::Interval(k) = b.kind else { return };
        let p = self.problem;
        let d = p.sde.dims();
        let (ns, nx, nz) = (d.states(), d.noisy, d.clean);
        let h = self.grid.step;
        let (t0, t1) = (self.grid.time(k), self.grid.time(k + 1));
        match self.transcription {
            Transcription::Euler | Transcription::Trapezoidal => {
                let (s0, s1) = (&w[..ns], &w[ns..2 * ns]);
                let mut h0 = vec![D::from(0.0); nz];
                p.sde.clean_drift(D::from(t0), &s0[..nx], &s0[nx..], theta, &mut h0);
                if self.transcription == Transcription::Trapezoidal {
                    let mut h1 = vec![D::from(0.0); nz];
                    p.sde.clean_drift(D::from(t1), &s1[..nx], &s1[nx..], theta, &mut h1);
                    for (a, b) in h0.iter_mut().zip(&h1) {
                        *a = (*a + *b) * 0.5;
                    }
                }
                for i in 0..nz {
                    out[i] = s1[nx + i] - s0[nx + i] - h0[i] * h;
                }
            }
            Transcription::HermiteSimpson => {
                let tm = 0.5 * (t0 + t1);
                let (s0, sm, s1) = (&w[..ns], &w[ns..2 * ns], &w[2 * ns..3 * ns]);
                let off = 3 * ns;
                let (a, bb) = (&w[off..off + nx], &w[off + nx..off + 2 * nx]);
                // G does not depend on an estimated θ for Hermite–Simpson (checked by the caller)
                let g = &self.g_fixed;
                // ṡ = [f + G w; h] at the three Lobatto points, w = a + (σ − ½) b.
                let rate = |t: f64, s: &[D], sigma: f64, v: &mut [D]| {
                    p.sde.drift(D::from(t), &s[..nx], &s[nx..], theta, &mut v[..nx]);
                    p.sde.clean_drift(D::from(t), &s[..nx], &s[nx..], theta, &mut v[nx..]);
                    for i in 0..nx {
                        for j in 0..nx {
                            v[i] += (a[j] + bb[j] * (sigma - 0.5)) * g[i + j * nx];
                        }
                    }
                };
                let mut heap = Vec::new();
                let mut stack = [D::from(0.0); 3 * STACK_LEN];
                let r = if ns <= STACK_LEN {
                    &mut stack[..3 * ns]
                } else {
                    heap.resize(3 * ns, D::from(0.0));
                    &mut heap[..]
                };
                let (r0, rest) = r.split_at_mut(ns);
                let (rm, r1) = rest.split_at_mut(ns);
                rate(t0, s0, 0.0, r0);
                rate(tm, sm, 0.5, rm);
                rate(t1, s1, 1.0, r1);
                // Hermite–Simpson defects (000 Ch. 4): Simpson quadrature and Hermite midpoint.
                for i in 0..ns {
                    out[i] = s1[i] - s0[i] - (r0[i] + rm[i] * 4.0 + r1[i]) * (h / 6.0);
                    out[ns + i] = sm[i] - (s0[i] + s1[i]) * 0.5 - (r0[i] - r1[i]) * (h / 8.0);
                }
            }
        }
    }

    /// The piece index of a Hermite–Simpson interval block (`None` for every other block).
    fn hs_piece(&self, b: &Block) -> Option<usize> {
        match (self.transcription, b.kind) {
            (Transcription::HermiteSimpson, BlockKind::Interval(k)) => Some(k),
            _ => None,
        }
    }

    /// Time, local offset of the states and (α, β) weights of the three Lobatto points of
    /// piece k: the Simpson weights α = (1, 4, 1) and the Hermite midpoint weights
    /// β = (1, 0, −1) of the defects in [`Self::block_constraints`].
    fn hs_points(&self, k: usize) -> [(f64, usize, f64, f64, f64); 3] {
        let ns = self.problem.sde.dims().states();
        let (t0, t1) = (self.grid.time(k), self.grid.time(k + 1));
        // (t, offset, α, β, σ − ½)
        [(t0, 0, 1.0, 1.0, -0.5), (0.5 * (t0 + t1), ns, 4.0, 0.0, 0.0), (t1, 2 * ns, 1.0, -1.0, 0.5)]
    }

    /// The point-local vector (s_i, θ_e) of Lobatto point `off` of a piece's local vector,
    /// written into `out` (length ns + ne).
    fn hs_point_local(&self, local: &[f64], off: usize, out: &mut [f64]) {
        let ns = self.problem.sde.dims().states();
        let ne = self.problem.estimate.len();
        out[..ns].copy_from_slice(&local[off..off + ns]);
        out[ns..ns + ne].copy_from_slice(&local[local.len() - ne..]);
    }

    /// Scatters a point-local (s_i, θ_e) index into the piece-local vector.
    fn hs_point_index(&self, nv: usize, off: usize, j: usize) -> usize {
        let ns = self.problem.sde.dims().states();
        let ne = self.problem.estimate.len();
        if j < ns {
            off + j
        } else {
            nv - ne + (j - ns)
        }
    }

    /// Adds the gradient of −merit of a Hermite–Simpson piece to `grad` (global), point by
    /// point: the energy h(½|a|² + |b|²/24) and, for Onsager–Machlup,
    /// (h/12) Σ α_i div_x f(t_i, s_i).
    fn hs_gradient_into(&self, k: usize, b: &Block, local: &[f64], grad: &mut [f64]) {
        let d = self.problem.sde.dims();
        let (ns, nx) = (d.states(), d.noisy);
        let h = self.grid.step;
        let nv = local.len();
        for i in 0..nx {
            grad[b.vars[3 * ns + i]] += h * local[3 * ns + i];
            grad[b.vars[3 * ns + nx + i]] += h * local[3 * ns + nx + i] / 12.0;
        }
        if self.merit == Merit::OnsagerMachlup {
            let npt = ns + self.problem.estimate.len();
            with_buffer(npt, |pl| {
                with_buffer(npt, |pg| {
                    for (t, off, alpha, _, _) in self.hs_points(k) {
                        let f = PointFn { nlp: self, t, div_weight: alpha * h / 12.0, mu: None };
                        self.hs_point_local(local, off, pl);
                        ad::gradient_into(&f, pl, pg);
                        for (j, &v) in pg.iter().enumerate() {
                            grad[b.vars[self.hs_point_index(nv, off, j)]] += v;
                        }
                    }
                })
            });
        }
    }

    /// Writes the constraint Jacobian of a Hermite–Simpson piece (rows × nv, row-major) into
    /// `jac`, from the rate Jacobians at its three points (see [`Self::block_constraints`] for
    /// the defects).
    fn hs_jacobian_into(&self, k: usize, local: &[f64], jac: &mut [f64]) {
        let p = self.problem;
        let d = p.sde.dims();
        let (ns, nx) = (d.states(), d.noisy);
        let h = self.grid.step;
        let nv = local.len();
        let npt = ns + p.estimate.len();
        let gm = &self.g_fixed;
        jac.fill(0.0);
        for i in 0..ns {
            jac[i * nv + i] -= 1.0; // c1 = s1 − s0 − …
            jac[i * nv + 2 * ns + i] += 1.0;
            jac[(ns + i) * nv + ns + i] += 1.0; // c2 = sm − ½(s0 + s1) − …
            jac[(ns + i) * nv + i] -= 0.5;
            jac[(ns + i) * nv + 2 * ns + i] -= 0.5;
        }
        with_buffer(npt, |pl| {
            with_buffer(ns, |value| {
                with_buffer(ns * npt, |jr| {
                    for (t, off, alpha, beta, sigma) in self.hs_points(k) {
                        let (w1, w2) = (-alpha * h / 6.0, -beta * h / 8.0);
                        let f = PointFn { nlp: self, t, div_weight: 0.0, mu: None };
                        self.hs_point_local(local, off, pl);
                        ad::jacobian_into(&f, pl, value, jr);
                        for j in 0..npt {
                            let c = self.hs_point_index(nv, off, j);
                            for r in 0..ns {
                                let v = jr[r + j * ns];
                                jac[r * nv + c] += w1 * v;
                                jac[(ns + r) * nv + c] += w2 * v;
                            }
                        }
                        // ∂r_i/∂a = G, ∂r_i/∂b = (σ_i − ½) G on the noisy rows.
                        for r in 0..nx {
                            for j in 0..nx {
                                let gv = gm[r + j * nx];
                                jac[r * nv + 3 * ns + j] += w1 * gv;
                                jac[(ns + r) * nv + 3 * ns + j] += w2 * gv;
                                jac[r * nv + 3 * ns + nx + j] += w1 * sigma * gv;
                                jac[(ns + r) * nv + 3 * ns + nx + j] += w2 * sigma * gv;
                            }
                        }
                    }
                })
            })
        });
    }

    /// The Hessian pattern of a Hermite–Simpson piece, in the order of
    /// [`Self::hs_hessian_into`]: the lower triangle of each point's (s_i, θ_e) block, then the
    /// noise diagonal.
    fn hs_hessian_structure(&self, b: &Block, out: &mut Vec<(usize, usize)>) {
        let d = self.problem.sde.dims();
        let (ns, nx) = (d.states(), d.noisy);
        let nv = b.vars.len();
        let npt = ns + self.problem.estimate.len();
        for off in [0, ns, 2 * ns] {
            for r in 0..npt {
                let vr = b.vars[self.hs_point_index(nv, off, r)];
                for c in 0..=r {
                    let vc = b.vars[self.hs_point_index(nv, off, c)];
                    out.push((vr.max(vc), vr.min(vc)));
                }
            }
        }
        for i in 0..2 * nx {
            let v = b.vars[3 * ns + i];
            out.push((v, v));
        }
    }

    /// Writes the Hessian of σ_f(−merit) + λᵀc of a Hermite–Simpson piece into `values` (the
    /// block's slots, see [`Self::hs_hessian_structure`]): at each Lobatto point the Hessian in
    /// (s_i, θ_e) of σ_f (h/12) α_i div_x f + μ_iᵀ [f; h], μ_i = −(h/6) α_i λ₁ − (h/8) β_i λ₂,
    /// then the energy's constant diagonal on (a, b). The noise term G(a + (σ − ½)b) is linear
    /// (G does not depend on an estimated θ for Hermite–Simpson).
    fn hs_hessian_into(&self, k: usize, local: &[f64], obj_factor: f64, lambda: &[f64], values: &mut [f64]) {
        let d = self.problem.sde.dims();
        let (ns, nx) = (d.states(), d.noisy);
        let h = self.grid.step;
        let npt = ns + self.problem.estimate.len();
        let om = self.merit == Merit::OnsagerMachlup;
        let mut slot = 0;
        with_buffer(ns, |mu| {
            with_buffer(npt, |pl| {
                with_buffer(npt, |pg| {
                    with_buffer(npt * npt, |ph| {
                        for (t, off, alpha, beta, _) in self.hs_points(k) {
                            for r in 0..ns {
                                mu[r] = -alpha * h / 6.0 * lambda[r] - beta * h / 8.0 * lambda[ns + r];
                            }
                            let div_weight = if om { obj_factor * alpha * h / 12.0 } else { 0.0 };
                            let f = PointFn { nlp: self, t, div_weight, mu: Some(mu) };
                            self.hs_point_local(local, off, pl);
                            ad::hessian_into(&f, pl, pg, ph);
                            for r in 0..npt {
                                for c in 0..=r {
                                    values[slot] = ph[r + c * npt];
                                    slot += 1;
                                }
                            }
                        }
                    })
                })
            })
        });
        for i in 0..nx {
            values[slot + i] = obj_factor * h;
            values[slot + nx + i] = obj_factor * h / 12.0;
        }
    }

    /// Copies the local vector of block `b` from `w` into `out` (length `b.vars.len()`).
    fn locals_into(b: &Block, w: &[f64], out: &mut [f64]) {
        for (o, &v) in out.iter_mut().zip(&b.vars) {
            *o = w[v];
        }
    }
}

/// Length of the stack buffers of [`with_buffer`].
const BUFFER_LEN: usize = 64;

/// Calls `f` with a zeroed buffer of length `len`, on the stack when `len ≤ 64`.
fn with_buffer<R>(len: usize, f: impl FnOnce(&mut [f64]) -> R) -> R {
    if len <= BUFFER_LEN {
        f(&mut [0.0; BUFFER_LEN][..len])
    } else {
        f(&mut vec![0.0; len])
    }
}

/// ½‖G⁻¹r‖² and ln|det G| (r is overwritten); `None` when G is singular.
fn half_sq_ginv<S: Sde + ?Sized, D: Scalar>(sde: &S, theta: &[D], r: &mut [D]) -> Option<(D, D)> {
    let n = r.len();
    let mut g = vec![D::from(0.0); n * n];
    sde.diffusion(theta, &mut g);
    let logdet = ad::lu_solve_in_place(&mut g, r)?;
    Some((r.iter().map(|&u| u * u).sum::<D>() * 0.5, logdet))
}

/// ln |det(I − ½ δ ∇_x f(t, x, z, θ))|, the trapezoidal scheme's volume term
/// (`001_8aefdf0570c96f51.txt (21)`), generic for its own derivatives (one nested dual pass
/// per noisy state for the Jacobian). NaN when the matrix is singular.
fn log_det_implicit<S: Sde + ?Sized, D: Scalar>(
    sde: &S,
    t: f64,
    delta: f64,
    s: &[D],
    nx: usize,
    theta: &[D],
) -> D {
    let lift = |v: &[D]| v.iter().map(|&a| Dual::from_re(a)).collect::<Vec<Dual<D>>>();
    let mut xd = lift(&s[..nx]);
    let (zd, td) = (lift(&s[nx..]), lift(theta));
    let mut out = vec![Dual::from_re(D::from(0.0)); nx];
    let mut m = vec![D::from(0.0); nx * nx];
    for j in 0..nx {
        xd[j].eps = D::from(1.0);
        sde.drift(Dual::from_re(D::from(t)), &xd, &zd, &td, &mut out);
        xd[j].eps = D::from(0.0);
        for i in 0..nx {
            let id = if i == j { 1.0 } else { 0.0 };
            m[i + j * nx] = D::from(id) - out[i].eps * (0.5 * delta);
        }
    }
    let mut b = vec![D::from(0.0); nx];
    ad::lu_solve_in_place(&mut m, &mut b).unwrap_or(D::from(f64::NAN))
}

/// A function of one Lobatto point's (s_i, θ_e): as a [`ScalarFn`],
/// `div_weight · div_x f + μᵀ [f; h]` (μ = 0 when `None`); as a [`VectorFn`], the rate
/// `[f; h]` itself.
struct PointFn<'b, 'a, S: Sde + ?Sized, O: Observation + ?Sized> {
    nlp: &'b PathNlp<'a, S, O>,
    t: f64,
    div_weight: f64,
    mu: Option<&'b [f64]>,
}

impl<S: Sde + ?Sized, O: Observation + ?Sized> PointFn<'_, '_, S, O> {
    fn rate<D: Scalar>(&self, w: &[D], out: &mut [D]) {
        let d = self.nlp.problem.sde.dims();
        let (ns, nx) = (d.states(), d.noisy);
        let (x, z) = w[..ns].split_at(nx);
        let sde = self.nlp.problem.sde;
        self.nlp.with_theta(&w[ns..], |theta| {
            sde.drift(D::from(self.t), x, z, theta, &mut out[..nx]);
            sde.clean_drift(D::from(self.t), x, z, theta, &mut out[nx..]);
        });
    }
}

impl<S: Sde + ?Sized, O: Observation + ?Sized> ScalarFn for PointFn<'_, '_, S, O> {
    fn dim_in(&self) -> usize {
        self.nlp.problem.sde.dims().states() + self.nlp.problem.estimate.len()
    }
    fn eval<D: Scalar>(&self, w: &[D]) -> D {
        let d = self.nlp.problem.sde.dims();
        let (ns, nx) = (d.states(), d.noisy);
        let mut v = D::from(0.0);
        if self.div_weight != 0.0 {
            let sde = self.nlp.problem.sde;
            v += self
                .nlp
                .with_theta(&w[ns..], |theta| sde.divergence(D::from(self.t), &w[..nx], &w[nx..ns], theta))
                * self.div_weight;
        }
        if let Some(mu) = self.mu {
            let mut dot = |r: &mut [D]| {
                self.rate(w, r);
                for (ri, &m) in r.iter().zip(mu) {
                    v += *ri * m;
                }
            };
            if ns <= STACK_LEN {
                dot(&mut [D::from(0.0); STACK_LEN][..ns]);
            } else {
                dot(&mut vec![D::from(0.0); ns]);
            }
        }
        v
    }
}

impl<S: Sde + ?Sized, O: Observation + ?Sized> VectorFn for PointFn<'_, '_, S, O> {
    fn dim_in(&self) -> usize {
        self.nlp.problem.sde.dims().states() + self.nlp.problem.estimate.len()
    }
    fn dim_out(&self) -> usize {
        self.nlp.problem.sde.dims().states()
    }
    fn eval<D: Scalar>(&self, w: &[D], out: &mut [D]) {
        self.rate(w, out);
    }
}

struct ObjFn<'b, 'a, S: Sde + ?Sized, O: Observation + ?Sized> {
    nlp: &'b PathNlp<'a, S, O>,
    block: &'b Block,
}

impl<S: Sde + ?Sized, O: Observation + ?Sized> ScalarFn for ObjFn<'_, '_, S, O> {
    fn dim_in(&self) -> usize {
        self.block.vars.len()
    }
    fn eval<D: Scalar>(&self, w: &[D]) -> D {
        -self.nlp.block_merit(self.block, w).total()
    }
}

struct ConFn<'b, 'a, S: Sde + ?Sized, O: Observation + ?Sized> {
    nlp: &'b PathNlp<'a, S, O>,
    block: &'b Block,
}

impl<S: Sde + ?Sized, O: Observation + ?Sized> VectorFn for ConFn<'_, '_, S, O> {
    fn dim_in(&self) -> usize {
        self.block.vars.len()
    }
    fn dim_out(&self) -> usize {
        self.block.rows
    }
    fn eval<D: Scalar>(&self, w: &[D], out: &mut [D]) {
        self.nlp.block_constraints(self.block, w, out);
    }
}

/// σ_f · (−merit) + Σ λ_r c_r of one block.
struct LagFn<'b, 'a, S: Sde + ?Sized, O: Observation + ?Sized> {
    nlp: &'b PathNlp<'a, S, O>,
    block: &'b Block,
    obj_factor: f64,
    lambda: &'b [f64],
}

impl<S: Sde + ?Sized, O: Observation + ?Sized> ScalarFn for LagFn<'_, '_, S, O> {
    fn dim_in(&self) -> usize {
        self.block.vars.len()
    }
    fn eval<D: Scalar>(&self, w: &[D]) -> D {
        let mut v = D::from(0.0);
        if self.obj_factor != 0.0 {
            v = -self.nlp.block_merit(self.block, w).total() * self.obj_factor;
        }
        if self.block.rows > 0 {
            let mut c = vec![D::from(0.0); self.block.rows];
            self.nlp.block_constraints(self.block, w, &mut c);
            for (ci, &l) in c.iter().zip(self.lambda) {
                v += *ci * l;
            }
        }
        v
    }
}

impl<S: Sde + ?Sized, O: Observation + ?Sized> NlpProblem for PathNlp<'_, S, O> {
    fn num_variables(&self) -> usize {
        self.n_vars
    }

    fn num_constraints(&self) -> usize {
        self.n_cons
    }

    fn bounds(&self, lower: &mut [f64], upper: &mut [f64]) {
        lower.copy_from_slice(&self.lower);
        upper.copy_from_slice(&self.upper);
    }

    fn initial_point(&self, w: &mut [f64]) {
        w.copy_from_slice(&self.initial);
    }

    fn objective(&mut self, w: &[f64]) -> f64 {
        -self.merit_parts(w).total()
    }

    fn gradient(&mut self, w: &[f64], grad: &mut [f64]) {
        grad.fill(0.0);
        for b in &self.blocks {
            with_buffer(b.vars.len(), |local| {
                Self::locals_into(b, w, local);
                match self.hs_piece(b) {
                    Some(k) => self.hs_gradient_into(k, b, local, grad),
                    None => with_buffer(local.len(), |g| {
                        ad::gradient_into(&ObjFn { nlp: self, block: b }, local, g);
                        for (&v, gi) in b.vars.iter().zip(g) {
                            grad[v] += *gi;
                        }
                    }),
                }
            });
        }
    }

    fn constraints(&mut self, w: &[f64], c: &mut [f64]) {
        for b in self.blocks.iter().filter(|b| b.rows > 0) {
            with_buffer(b.vars.len(), |local| {
                Self::locals_into(b, w, local);
                self.block_constraints(b, local, &mut c[b.row0..b.row0 + b.rows]);
            });
        }
    }

    fn jacobian_structure(&self) -> Vec<(usize, usize)> {
        let mut s = Vec::with_capacity(self.n_jac);
        for b in &self.blocks {
            for r in 0..b.rows {
                for &v in &b.vars {
                    s.push((b.row0 + r, v));
                }
            }
        }
        s
    }

    fn jacobian_values(&mut self, w: &[f64], values: &mut [f64]) {
        for b in self.blocks.iter().filter(|b| b.rows > 0) {
            let nv = b.vars.len();
            let out = &mut values[b.jac0..b.jac0 + b.rows * nv];
            with_buffer(nv, |local| {
                Self::locals_into(b, w, local);
                match self.hs_piece(b) {
                    Some(k) => self.hs_jacobian_into(k, local, out),
                    None => with_buffer(b.rows, |value| {
                        with_buffer(b.rows * nv, |j| {
                            ad::jacobian_into(&ConFn { nlp: self, block: b }, local, value, j);
                            for r in 0..b.rows {
                                for c in 0..nv {
                                    out[r * nv + c] = j[r + c * b.rows];
                                }
                            }
                        })
                    }),
                }
            });
        }
    }

    fn hessian_structure(&self) -> Vec<(usize, usize)> {
        let mut s = Vec::with_capacity(self.n_hess);
        for b in &self.blocks {
            if self.hs_piece(b).is_some() {
                self.hs_hessian_structure(b, &mut s);
                continue;
            }
            for (i, &vi) in b.vars.iter().enumerate() {
                for &vj in &b.vars[..=i] {
                    s.push((vi.max(vj), vi.min(vj)));
                }
            }
        }
        s
    }

    fn hessian_values(&mut self, w: &[f64], obj_factor: f64, lambda: &[f64], values: &mut [f64]) {
        for (bi, b) in self.blocks.iter().enumerate() {
            let lam = &lambda[b.row0..b.row0 + b.rows];
            let end = self.blocks.get(bi + 1).map_or(values.len(), |n| n.hess0);
            let out = &mut values[b.hess0..end];
            with_buffer(b.vars.len(), |local| {
                Self::locals_into(b, w, local);
                match self.hs_piece(b) {
                    Some(k) => self.hs_hessian_into(k, local, obj_factor, lam, out),
                    None => {
                        let nv = b.vars.len();
                        let f = LagFn { nlp: self, block: b, obj_factor, lambda: lam };
                        with_buffer(nv, |g| {
                            with_buffer(nv * nv, |h| {
                                ad::hessian_into(&f, local, g, h);
                                let mut slot = 0;
                                for i in 0..nv {
                                    for j in 0..=i {
                                        out[slot] = h[i + j * nv];
                                        slot += 1;
                                    }
                                }
                            })
                        })
                    }
                }
            });
        }
    }
}
