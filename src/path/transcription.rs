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
use crate::model::{DriftDerivatives, Observation, Scalar, Sde};
use crate::nlp::NlpProblem;

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
    /// Where the global indices of the local variables, in local order, are in
    /// [`PathNlp`]'s `var_index` (one array for all blocks, not one allocation per block).
    vars: std::ops::Range<usize>,
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
    /// The blocks' variables ([`Block::vars`]).
    var_index: Vec<u32>,
    n_cons: usize,
    blocks: Vec<Block>,
    n_jac: usize,
    n_hess: usize,
    /// G(θ), column-major, for Hermite–Simpson (where no estimated θ enters it).
    g_fixed: Vec<f64>,
    /// Positions in `problem.estimate` of the estimated θ that may enter the dynamics
    /// ([`Sde::drift_uses_param`]): the θ part of a Lobatto point's local vector.
    point_theta: Vec<usize>,
    /// Number of entries of the lower triangle of (θ_d, θ_d): the block of the Hermite–Simpson
    /// Hessian that sums the points' (θ_d, θ_d) parts, first in its pattern (0 for the other
    /// transcriptions, whose blocks are dense).
    hs_theta_tri: usize,
    /// For each Lobatto point i of a Hermite–Simpson piece, the position in the piece's local
    /// vector of each entry of the point's (s_i, θ_d).
    point_index: [Vec<usize>; 3],
    /// For each input of w = (x, z, θ) of [`Sde::drift_derivatives`], its position in a
    /// point's (s_i, θ_d), or [`DriftDerivatives::DROPPED`].
    point_cols: Vec<usize>,
    /// The constant part of a Hermite–Simpson piece's constraint Jacobian
    /// ([`hs_jacobian_constant`]; empty for the other transcriptions).
    hs_jac_constant: Vec<f64>,
    /// Hermite–Simpson per-point derivatives, computed by `gradient` and reused by
    /// `jacobian_values` and `hessian_values` at the same variable vector.
    cache: PointCache,
    initial: Vec<f64>,
    /// The finite bounds, (variable, lower, upper): those of the initial-state priors and of
    /// the estimated parameters; every other variable is free.
    bounds: Vec<(usize, f64, f64)>,
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
        let node = |k: usize| k * ns..(k + 1) * ns;
        let theta_vars = theta0..n_vars;
        // the blocks' variables, each block's a range of `var_index` (`u32`: `build_nlp` rejects
        // grids with 2³² unknowns or more)
        let per_interval = if hs { 3 * ns + 2 * nx + ne } else { 2 * ns + ne };
        let n_blocks_vars = n * per_interval + (grid.measurement_nodes.len() + 1) * (ns + ne);
        let mut var_index: Vec<u32> = Vec::with_capacity(n_blocks_vars);
        let mut push_vars = |parts: &[std::ops::Range<usize>]| {
            let start = var_index.len();
            for part in parts {
                var_index.extend(part.clone().map(|v| v as u32));
            }
            start..var_index.len()
        };

        let mut blocks = Vec::with_capacity(n + grid.measurement_nodes.len() + 1);
        let mut row = 0;
        let rows_per_interval = if hs { 2 * ns } else { d.clean };
        for k in 0..n {
            let vars = if hs {
                push_vars(&[
                    node(k),
                    mid0 + k * ns..mid0 + (k + 1) * ns,
                    node(k + 1),
                    noise0 + k * 2 * nx..noise0 + (k + 1) * 2 * nx,
                    theta_vars.clone(),
                ])
            } else {
                push_vars(&[node(k), node(k + 1), theta_vars.clone()])
            };
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
            let vars = push_vars(&[node(nd), theta_vars.clone()]);
            blocks.push(Block {
                kind: BlockKind::Measurement { row: r, node: nd },
                vars,
                row0: row,
                rows: 0,
                jac0: 0,
                hess0: 0,
            });
        }
        let vars = push_vars(&[node(0), theta_vars.clone()]);
        blocks.push(Block { kind: BlockKind::Prior, vars, row0: row, rows: 0, jac0: 0, hess0: 0 });
        // Hermite–Simpson pieces: the Hessian is block-diagonal over the three Lobatto points'
        // (s_i, θ_d) plus the noise diagonal (see `hs_hessian_into`), θ_d the estimated θ that
        // enter the dynamics, whose (θ_d, θ_d) parts of all points are summed into one block
        // ahead of the others; other blocks are dense
        let point_theta: Vec<usize> =
            (0..ne).filter(|&j| problem.sde.drift_uses_param(problem.estimate[j])).collect();
        let npt = ns + point_theta.len();
        let theta_tri = if hs { point_theta.len() * (point_theta.len() + 1) / 2 } else { 0 };
        let (mut jac, mut hess) = (0, theta_tri);
        // piece-local vector: s0, sm, s1, (a, b), estimated θ
        let nv_piece = 3 * ns + 2 * nx + ne;
        let point_index = [0, ns, 2 * ns].map(|off| {
            let mut idx: Vec<usize> = (off..off + ns).collect();
            idx.extend(point_theta.iter().map(|&j| nv_piece - ne + j));
            idx
        });
        let mut point_cols: Vec<usize> = (0..ns).collect();
        point_cols.extend((0..d.params).map(|i| {
            let pos = point_theta.iter().position(|&j| problem.estimate[j] == i);
            pos.map_or(DriftDerivatives::DROPPED, |j| ns + j)
        }));
        for b in &mut blocks {
            b.jac0 = jac;
            b.hess0 = hess;
            let nv = b.vars.len();
            jac += b.rows * nv;
            hess += match (hs, b.kind) {
                (true, BlockKind::Interval(_)) => 3 * (npt * (npt + 1) / 2 - theta_tri) + 2 * nx,
                _ => nv * (nv + 1) / 2,
            };
        }
        let mut g_fixed = vec![0.0; nx * nx];
        let mut hs_jac_constant = Vec::new();
        if hs {
            // G does not depend on an estimated θ for Hermite–Simpson (checked by the caller)
            problem.sde.diffusion(problem.theta, &mut g_fixed);
            hs_jac_constant = hs_jacobian_constant(ns, nx, nv_piece, grid.step, &g_fixed);
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
        let mut bounds = Vec::new();
        for (i, p) in problem.x0_prior.iter().chain(problem.z0_prior).enumerate() {
            bounds.push((i, p.lower, p.upper));
            initial[i] = initial[i].clamp(p.lower, p.upper);
        }
        for (j, &i) in problem.estimate.iter().enumerate() {
            bounds.push((theta0 + j, problem.theta_prior[i].lower, problem.theta_prior[i].upper));
        }
        bounds.retain(|&(_, l, u)| l.is_finite() || u.is_finite());
        PathNlp {
            problem,
            merit,
            transcription,
            grid,
            n_vars,
            n_cons: row,
            blocks,
            var_index,
            n_jac: jac,
            n_hess: hess,
            g_fixed,
            point_theta,
            hs_theta_tri: theta_tri,
            point_index,
            point_cols,
            hs_jac_constant,
            cache: PointCache::default(),
            initial,
            bounds,
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
        let nx = d.noisy;
        let off = self.hs_offsets().1 + k * 2 * nx;
        w[off..off + nx].copy_from_slice(a);
        w[off + nx..off + 2 * nx].copy_from_slice(b);
    }

    /// The parts of the log-merit at `w` (see [`MeritParts`]).
    pub fn merit_parts(&self, w: &[f64]) -> MeritParts<f64> {
        let mut parts = MeritParts::zero();
        if self.transcription == Transcription::HermiteSimpson {
            self.hs_merit_parts(w, &mut parts);
        }
        for b in &self.blocks {
            if self.hs_piece(b).is_some() {
                continue;
            }
            parts += with_buffer(b.vars.len(), |local| {
                self.locals_into(b, w, local);
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
        ad::with_zeros(self.problem.theta.len(), |buf| {
            for (b, &v) in buf.iter_mut().zip(self.problem.theta.iter()) {
                *b = D::from(v);
            }
            for (j, &i) in self.problem.estimate.iter().enumerate() {
                buf[i] = est[j];
            }
            f(buf)
        })
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
                    // evaluated for all pieces at once by `hs_merit_parts`
                    Transcription::HermiteSimpson => {}
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
            // evaluated for all pieces at once by `hs_constraints`
            Transcription::HermiteSimpson => {}
        }
    }

    /// The Hermite–Simpson parts of the log-merit, added to `parts` piece by piece: the energy
    /// −h(½|a|² + |b|²/24) (Simpson's rule integrates ½|w|² of the linear-in-time noise
    /// w(σ) = a + (σ − ½) b of a piece exactly) and, for Onsager–Machlup, −½∫div_x f dt by
    /// Simpson's rule (000 (2.49)), div_x f at each node evaluated once (the end point of piece
    /// k is the start point of piece k + 1).
    fn hs_merit_parts(&self, w: &[f64], parts: &mut MeritParts<f64>) {
        let p = self.problem;
        let d = p.sde.dims();
        let (ns, nx, n) = (d.states(), d.noisy, self.grid.intervals);
        let h = self.grid.step;
        let (mid0, noise0) = self.hs_offsets();
        let om = self.merit == Merit::OnsagerMachlup;
        self.with_theta(&w[self.n_vars - p.estimate.len()..], |theta| {
            let div =
                |t: f64, s: &[f64]| if om { p.sde.divergence(t, &s[..nx], &s[nx..], theta) } else { 0.0 };
            let mut div0 = div(self.grid.time(0), &w[..ns]);
            for k in 0..n {
                let (t0, t1) = (self.grid.time(k), self.grid.time(k + 1));
                let off = noise0 + k * 2 * nx;
                let (a, bb) = (&w[off..off + nx], &w[off + nx..off + 2 * nx]);
                let sa: f64 = a.iter().map(|&v| v * v).sum();
                let sb: f64 = bb.iter().map(|&v| v * v).sum();
                let mut piece = MeritParts::zero();
                piece.energy = -(sa * 0.5 + sb / 24.0) * h;
                if om {
                    let divm = div(0.5 * (t0 + t1), &w[mid0 + k * ns..mid0 + (k + 1) * ns]);
                    let div1 = div(t1, &w[(k + 1) * ns..(k + 2) * ns]);
                    piece.divergence = -(div0 + divm * 4.0 + div1) * (h / 12.0);
                    div0 = div1;
                }
                *parts += piece;
            }
        })
    }

    /// The Hermite–Simpson defects of every piece into `c` (piece k's 2ns rows from 2ns·k):
    /// with the rates ṡ = [f + G w; h] at the three Lobatto points, w = a + (σ − ½) b, Simpson's
    /// quadrature s1 − s0 − (h/6)(ṡ0 + 4ṡm + ṡ1) and the Hermite midpoint
    /// sm − ½(s0 + s1) − (h/8)(ṡ0 − ṡ1) (000 Ch. 4). The drifts at each node are evaluated once
    /// (the end point of piece k is the start point of piece k + 1).
    fn hs_constraints(&self, w: &[f64], c: &mut [f64]) {
        let p = self.problem;
        let d = p.sde.dims();
        let (ns, nx, n) = (d.states(), d.noisy, self.grid.intervals);
        let h = self.grid.step;
        let (mid0, noise0) = self.hs_offsets();
        // G does not depend on an estimated θ for Hermite–Simpson (checked by the caller)
        let g = &self.g_fixed;
        let [(_, _, sg0), (_, _, sgm), (_, _, sg1)] = HS_WEIGHTS;
        self.with_theta(&w[self.n_vars - p.estimate.len()..], |theta| {
            let drift = |t: f64, s: &[f64], v: &mut [f64]| {
                p.sde.drift(t, &s[..nx], &s[nx..], theta, &mut v[..nx]);
                p.sde.clean_drift(t, &s[..nx], &s[nx..], theta, &mut v[nx..]);
            };
            with_buffer(3 * ns, |r| {
                let (r0, rest) = r.split_at_mut(ns);
                let (rm, r1) = rest.split_at_mut(ns);
                drift(self.grid.time(0), &w[..ns], r0);
                for (k, out) in c.chunks_exact_mut(2 * ns).enumerate().take(n) {
                    let (t0, t1) = (self.grid.time(k), self.grid.time(k + 1));
                    let (s0, s1) = (&w[k * ns..(k + 1) * ns], &w[(k + 1) * ns..(k + 2) * ns]);
                    let sm = &w[mid0 + k * ns..mid0 + (k + 1) * ns];
                    let off = noise0 + k * 2 * nx;
                    let (a, bb) = (&w[off..off + nx], &w[off + nx..off + 2 * nx]);
                    drift(0.5 * (t0 + t1), sm, rm);
                    drift(t1, s1, r1);
                    for i in 0..ns {
                        let (mut v0, mut vm, mut v1) = (r0[i], rm[i], r1[i]);
                        if i < nx {
                            for j in 0..nx {
                                let gv = g[i + j * nx];
                                v0 += (a[j] + bb[j] * sg0) * gv;
                                vm += (a[j] + bb[j] * sgm) * gv;
                                v1 += (a[j] + bb[j] * sg1) * gv;
                            }
                        }
                        out[i] = s1[i] - s0[i] - (v0 + vm * 4.0 + v1) * (h / 6.0);
                        out[ns + i] = sm[i] - (s0[i] + s1[i]) * 0.5 - (v0 - v1) * (h / 8.0);
                    }
                    r0.copy_from_slice(r1);
                }
            })
        })
    }

    /// The first variables of the Hermite–Simpson midpoint states and noise coefficients: the
    /// N + 1 node states come first, then the N midpoints, then (a_k, b_k) piece by piece.
    fn hs_offsets(&self) -> (usize, usize) {
        let (ns, n) = (self.problem.sde.dims().states(), self.grid.intervals);
        ((n + 1) * ns, (2 * n + 1) * ns)
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
    /// β = (1, 0, −1) of the defects in [`Self::hs_constraints`].
    fn hs_points(&self, k: usize) -> [(f64, usize, f64, f64, f64); 3] {
        let ns = self.problem.sde.dims().states();
        let (t0, t1) = (self.grid.time(k), self.grid.time(k + 1));
        // (t, offset, α, β, σ − ½)
        let [(a0, b0, s0), (am, bm, sm), (a1, b1, s1)] = HS_WEIGHTS;
        [(t0, 0, a0, b0, s0), (0.5 * (t0 + t1), ns, am, bm, sm), (t1, 2 * ns, a1, b1, s1)]
    }

    /// The point-local vector (s_i, θ_d) of Lobatto point `off` of a piece's local vector,
    /// written into `out` (length ns + `point_theta.len()`; θ_d: the estimated θ that enter
    /// the dynamics).
    fn hs_point_local(&self, local: &[f64], off: usize, out: &mut [f64]) {
        let ns = self.problem.sde.dims().states();
        let th = &local[local.len() - self.problem.estimate.len()..];
        self.hs_point_vector(&local[off..off + ns], th, out);
    }

    /// The point vector (s, θ_d) of the state `s` and the estimated θ `theta_e`, written into
    /// `out` (length ns + `point_theta.len()`).
    fn hs_point_vector(&self, s: &[f64], theta_e: &[f64], out: &mut [f64]) {
        let ns = s.len();
        out[..ns].copy_from_slice(s);
        for (o, &j) in out[ns..].iter_mut().zip(&self.point_theta) {
            *o = theta_e[j];
        }
    }

    /// Number of inputs of a Lobatto point's functions, (s_i, θ_d).
    fn hs_point_dim(&self) -> usize {
        self.problem.sde.dims().states() + self.point_theta.len()
    }

    /// Number of outputs of a Lobatto point's [`PointFn`] in the cache: the rate [f; h] and,
    /// for Onsager–Machlup, div_x f.
    fn hs_point_outputs(&self) -> usize {
        self.problem.sde.dims().states() + usize::from(self.merit == Merit::OnsagerMachlup)
    }

    /// A Lobatto point's function at time `t` for a piece's local vector.
    fn point_fn<'b>(&'b self, t: f64, local: &'b [f64]) -> PointFn<'b, 'a, S, O> {
        let ne = self.problem.estimate.len();
        PointFn {
            nlp: self,
            t,
            theta_e: &local[local.len() - ne..],
            with_div: false,
            div_weight: 0.0,
            mu: None,
        }
    }

    /// The [`PointCache`] entry of Lobatto point i of piece k: the nodes come first (the end
    /// point of piece k is the start point of piece k + 1, so the two share one entry), then
    /// the midpoints.
    fn hs_entry(&self, k: usize, i: usize) -> usize {
        match i {
            0 => k,
            1 => self.grid.intervals + 1 + k,
            _ => k + 1,
        }
    }

    /// Fills `cache` (see [`PointCache`]) with the derivatives of the Lobatto points' outputs
    /// at the variable vector `w`: each grid node and each midpoint once
    /// ([`Self::hs_point_derivatives`]). The Hessians of the outputs that no point has shown
    /// second derivatives for are left out; when a point shows one (at the first call, or for
    /// a model whose second derivatives depend on the point), its output is added and the
    /// points are differentiated again.
    fn hs_points_into(&self, w: &[f64], cache: &mut PointCache) {
        let ns = self.problem.sde.dims().states();
        let n = self.grid.intervals;
        let (npt, nout) = (self.hs_point_dim(), self.hs_point_outputs());
        let theta_e = &w[self.n_vars - self.problem.estimate.len()..];
        if cache.slots.len() != nout {
            // up to 64 outputs are tracked; more are all stored
            cache.stored = if nout > 64 { (0..nout).collect() } else { Vec::new() };
            cache.slots = (0..nout).map(|o| if nout > 64 { o } else { DriftDerivatives::DROPPED }).collect();
        }
        let mut ph = vec![0.0; nout * npt * npt];
        loop {
            cache.len = nout * npt + cache.stored.len() * npt * (npt + 1) / 2;
            let stored: u64 = cache.stored.iter().filter(|&&o| o < 64).fold(0, |m, &o| m | 1 << o);
            let PointCache { data, slots, len, .. } = cache;
            data.resize((2 * n + 1) * *len, 0.0);
            let missing = self.with_theta(theta_e, |theta| {
                with_buffer(npt, |pl| {
                    for (q, entry) in data.chunks_exact_mut(*len).enumerate() {
                        // node q, or the midpoint of piece q − N − 1 (states after the nodes' in w)
                        let t = if q <= n {
                            self.grid.time(q)
                        } else {
                            0.5 * (self.grid.time(q - n - 1) + self.grid.time(q - n))
                        };
                        let (jr, packed) = entry.split_at_mut(nout * npt);
                        let s = &w[q * ns..(q + 1) * ns];
                        let point = LobattoPoint { t, s, theta_e, theta };
                        let seconds = self.hs_point_derivatives(point, slots, pl, jr, packed, &mut ph);
                        if seconds & !stored != 0 {
                            return seconds & !stored;
                        }
                    }
                    0
                })
            });
            if missing == 0 {
                return;
            }
            cache.stored.extend((0..nout).filter(|&o| missing >> o & 1 == 1));
            cache.stored.sort_unstable();
            for (j, &o) in cache.stored.iter().enumerate() {
                cache.slots[o] = j;
            }
        }
    }

    /// Adds the gradient of −merit of a Hermite–Simpson piece to `grad` (global): the energy
    /// h(½|a|² + |b|²/24) and, for Onsager–Machlup, (h/12) Σ α_i div_x f(t_i, s_i), whose
    /// gradients at the three points are read from `cache` (filled by
    /// [`Self::hs_points_into`] at `w`).
    fn hs_gradient_into(&self, k: usize, b: &Block, w: &[f64], grad: &mut [f64], cache: &PointCache) {
        let d = self.problem.sde.dims();
        let (ns, nx) = (d.states(), d.noisy);
        let h = self.grid.step;
        let vars = self.vars(b);
        for &v in &vars[3 * ns..3 * ns + nx] {
            let v = v as usize;
            grad[v] += h * w[v];
        }
        for &v in &vars[3 * ns + nx..3 * ns + 2 * nx] {
            let v = v as usize;
            grad[v] += h * w[v] / 12.0;
        }
        if self.merit != Merit::OnsagerMachlup {
            return;
        }
        let nout = self.hs_point_outputs();
        for (i, (_, _, alpha, _, _)) in self.hs_points(k).into_iter().enumerate() {
            let e = self.hs_entry(k, i) * cache.len;
            let wgt = alpha * h / 12.0;
            for (&li, &g) in self.point_index[i].iter().zip(cache.data[e + ns..].iter().step_by(nout)) {
                grad[vars[li] as usize] += wgt * g;
            }
        }
    }

    /// The first and second derivatives of the outputs of a Lobatto `point` at time `t` with
    /// states `s` (the rate [f; h] and, for Onsager–Machlup, div_x f) in the point's
    /// (s, θ_d), `theta_e` the estimated θ and `theta` the full θ: the Jacobian into `jr`
    /// (outputs × npt, column-major), the packed lower triangles of the Hessians of the outputs o with
    /// `slots[o]` ≠ [`DriftDerivatives::DROPPED`] into `packed` (at `slots[o]`). From the
    /// model's closed form ([`Sde::drift_derivatives`]) when it has one, else one
    /// [`ad::hessians_into`] pass (`pl`, `ph`: scratch of npt and outputs · npt² entries).
    /// Returns the outputs (bit o) with second derivatives: those the closed form wrote, or
    /// all of them.
    fn hs_point_derivatives(
        &self,
        point: LobattoPoint<'_>,
        slots: &[usize],
        pl: &mut [f64],
        jr: &mut [f64],
        packed: &mut [f64],
        ph: &mut [f64],
    ) -> u64 {
        let LobattoPoint { t, s, theta_e, theta } = point;
        let p = self.problem;
        let nx = p.sde.dims().noisy;
        let (npt, nout) = (self.hs_point_dim(), self.hs_point_outputs());
        jr.fill(0.0);
        packed.fill(0.0);
        let mut out =
            DriftDerivatives::new(&self.point_cols, npt, nout, jr, packed).with_hessian_slots(slots);
        if p.sde.drift_derivatives(t, &s[..nx], &s[nx..], theta, &mut out) {
            return out.second_outputs();
        }
        let om = self.merit == Merit::OnsagerMachlup;
        let f = PointFn { nlp: self, t, theta_e, with_div: om, div_weight: 0.0, mu: None };
        self.hs_point_vector(s, theta_e, pl);
        with_buffer(nout, |value| ad::hessians_into(&f, pl, value, jr, ph));
        let tri = npt * (npt + 1) / 2;
        for (&j, ho) in slots.iter().zip(ph.chunks_exact(npt * npt)) {
            if j != DriftDerivatives::DROPPED {
                pack_lower(ho, npt, &mut packed[j * tri..(j + 1) * tri]);
            }
        }
        if nout >= 64 {
            u64::MAX
        } else {
            (1 << nout) - 1
        }
    }

    /// Writes the constraint Jacobian of a Hermite–Simpson piece (rows × nv, row-major) into
    /// `jac`: its constant part ([`hs_jacobian_constant`]) plus the rate Jacobians at its three
    /// points (see [`Self::hs_constraints`] for the defects), read from `cached` (the
    /// [`PointCache`] when it holds the current point; `local`, the piece's local vector, is
    /// then not read) or differentiated.
    fn hs_jacobian_into(&self, k: usize, local: &[f64], jac: &mut [f64], cached: Option<&PointCache>) {
        let ns = self.problem.sde.dims().states();
        let (npt, nout) = (self.hs_point_dim(), self.hs_point_outputs());
        jac.copy_from_slice(&self.hs_jac_constant);
        if let Some(c) = cached {
            for i in 0..3 {
                let e = self.hs_entry(k, i) * c.len;
                self.hs_add_rate_jacobian(i, &c.data[e..e + nout * npt], nout, jac);
            }
            return;
        }
        with_buffer(npt, |pl| {
            with_buffer(ns, |value| {
                with_buffer(ns * npt, |jr| {
                    for (i, (t, off, ..)) in self.hs_points(k).into_iter().enumerate() {
                        self.hs_point_local(local, off, pl);
                        ad::jacobian_into(&self.point_fn(t, local), pl, value, jr);
                        self.hs_add_rate_jacobian(i, jr, ns, jac);
                    }
                })
            })
        });
    }

    /// Adds the part of Lobatto point i of a piece to the piece's constraint Jacobian `jac`
    /// (row-major): −(h/6) α_i and −(h/8) β_i times the rate Jacobian `jr` (its columns
    /// `stride` apart, the rate in the first ns entries of each).
    fn hs_add_rate_jacobian(&self, i: usize, jr: &[f64], stride: usize, jac: &mut [f64]) {
        let ns = self.problem.sde.dims().states();
        let nv = jac.len() / (2 * ns);
        let (alpha, beta, _) = HS_WEIGHTS[i];
        let h = self.grid.step;
        let (w1, w2) = (-alpha * h / 6.0, -beta * h / 8.0);
        for (&c, jc) in self.point_index[i].iter().zip(jr.chunks_exact(stride)) {
            for (r, &v) in jc[..ns].iter().enumerate() {
                jac[r * nv + c] += w1 * v;
                jac[(ns + r) * nv + c] += w2 * v;
            }
        }
    }

    /// The Hessian pattern of a Hermite–Simpson piece, in the order of
    /// [`Self::hs_hessian_into`]: the lower triangle of each point's (s_i, θ_d) block without
    /// its (θ_d, θ_d) part (summed over all points into the block ahead of the pieces, see
    /// `hessian_structure`), then the noise diagonal. Each point's (θ_d, θ_d) part would
    /// otherwise be a KKT entry of its own, summed into the same few slots as every other
    /// point's: on Duffing with 36,000 pieces and θ = (a, b, d, σ_y) 648,000 of its 1.7 million
    /// Hessian entries.
    fn hs_hessian_structure(&self, b: &Block, out: &mut Vec<(u32, u32)>) {
        let d = self.problem.sde.dims();
        let (ns, nx) = (d.states(), d.noisy);
        // packed column by column (`packed_index`): the states' columns, then those of θ_d,
        // which hold only (θ_d, θ_d) entries
        let vars = self.vars(b);
        for idx in &self.point_index {
            for (c, &lc) in idx[..ns].iter().enumerate() {
                let vc = vars[lc];
                for &lr in &idx[c..] {
                    out.push(lower_pair(vars[lr], vc));
                }
            }
        }
        for &v in &vars[3 * ns..3 * ns + 2 * nx] {
            out.push((v, v));
        }
    }

    /// Writes the Hessian of σ_f(−merit) + λᵀc of a Hermite–Simpson piece into `values` (the
    /// block's slots, see [`Self::hs_hessian_structure`]) and adds its (θ_d, θ_d) parts to
    /// `theta` (the summed block, packed like a point's sub-triangle): at each Lobatto point the
    /// Hessian in (s_i, θ_d) of σ_f (h/12) α_i div_x f + μ_iᵀ [f; h], μ_i = −(h/6) α_i λ₁ −
    /// (h/8) β_i λ₂, then the energy's constant diagonal on (a, b). The noise term
    /// G(a + (σ − ½)b) is linear (G does not depend on an estimated θ for Hermite–Simpson).
    /// With `cached` (the data of [`PointCache`] at the current point) the point Hessians are
    /// combinations of the stored output Hessians (and `local`, the piece's local vector, is
    /// not read); otherwise one second-order pass of the combination per point. σ_f and λ (the
    /// piece's multipliers) are `weights`.
    fn hs_hessian_into(
        &self,
        k: usize,
        local: &[f64],
        weights: LagrangianWeights<'_>,
        values: &mut [f64],
        theta: &mut [f64],
        cached: Option<&PointCache>,
    ) {
        let LagrangianWeights { obj_factor, lambda } = weights;
        let d = self.problem.sde.dims();
        let ns = d.states();
        let npt = self.hs_point_dim();
        let tri = npt * (npt + 1) / 2;
        let nout = self.hs_point_outputs();
        // the point's packed triangle: the states' columns (kept), then the (θ_d, θ_d) part
        let kept = tri - self.hs_theta_tri;
        let (points, noise) = values.split_at_mut(3 * kept);
        with_buffer(ns, |mu| {
            for (i, out) in points.chunks_exact_mut(kept).enumerate() {
                let div_weight = self.hs_point_weights(i, obj_factor, lambda, mu);
                let weight = |o: usize| if o < ns { mu[o] } else { div_weight };
                if let Some(c) = cached {
                    let e = self.hs_entry(k, i) * c.len;
                    let hs = &c.data[e + nout * npt..e + c.len];
                    out.fill(0.0);
                    for (&o, hr) in c.stored.iter().zip(hs.chunks_exact(tri)) {
                        let wgt = weight(o);
                        for (v, &x) in out.iter_mut().zip(hr) {
                            *v += wgt * x;
                        }
                    }
                    if kept < tri {
                        add_theta_part(theta, &c.stored, hs, tri, kept, weight);
                    }
                    continue;
                }
                let (t, off, ..) = self.hs_points(k)[i];
                let f = PointFn { div_weight, mu: Some(mu), ..self.point_fn(t, local) };
                with_buffer(npt, |pl| {
                    with_buffer(npt, |pg| {
                        with_buffer(npt * npt, |ph| {
                            with_buffer(tri - kept, |tt| {
                                self.hs_point_local(local, off, pl);
                                ad::hessian_into(&f, pl, pg, ph);
                                pack_lower_split(ph, npt, out, tt);
                                for (a, &v) in theta.iter_mut().zip(tt.iter()) {
                                    *a += v;
                                }
                            })
                        })
                    })
                });
            }
        });
        let (h, nx) = (self.grid.step, d.noisy);
        noise[..nx].fill(obj_factor * h);
        noise[nx..2 * nx].fill(obj_factor * h / 12.0);
    }

    /// The weights of Lobatto point i of a piece in the Hessian of the Lagrangian: μ_i =
    /// −(h/6) α_i λ₁ − (h/8) β_i λ₂ of the rate [f; h] (into `mu`), and, returned, σ_f (h/12) α_i of
    /// div_x f for Onsager–Machlup (0 for the energy merit).
    fn hs_point_weights(&self, i: usize, obj_factor: f64, lambda: &[f64], mu: &mut [f64]) -> f64 {
        let (alpha, beta, _) = HS_WEIGHTS[i];
        let h = self.grid.step;
        let ns = mu.len();
        for (r, m) in mu.iter_mut().enumerate() {
            *m = -alpha * h / 6.0 * lambda[r] - beta * h / 8.0 * lambda[ns + r];
        }
        if self.merit == Merit::OnsagerMachlup {
            obj_factor * alpha * h / 12.0
        } else {
            0.0
        }
    }

    /// The global indices of block `b`'s local variables, in local order.
    fn vars(&self, b: &Block) -> &[u32] {
        &self.var_index[b.vars.clone()]
    }

    /// Copies the local vector of block `b` from `w` into `out` (length `b.vars.len()`).
    fn locals_into(&self, b: &Block, w: &[f64], out: &mut [f64]) {
        for (o, &v) in out.iter_mut().zip(self.vars(b)) {
            *o = w[v as usize];
        }
    }
}

/// Adds a Lobatto point's (θ_d, θ_d) part to the summed block `theta`: entry q is
/// Σ_o weight(o) · (Hessian of stored output o)_{kept + q}, the tail after `kept` of the packed
/// triangles (`tri` entries each) in `hs`, summed before it is added, as a separate entry of the
/// KKT pattern would have been.
#[inline(never)]
fn add_theta_part(
    theta: &mut [f64],
    stored: &[usize],
    hs: &[f64],
    tri: usize,
    kept: usize,
    weight: impl Fn(usize) -> f64,
) {
    with_buffer(theta.len(), |part| {
        for (&o, hr) in stored.iter().zip(hs.chunks_exact(tri)) {
            let wgt = weight(o);
            for (v, &x) in part.iter_mut().zip(&hr[kept..]) {
                *v += wgt * x;
            }
        }
        for (a, &v) in theta.iter_mut().zip(part.iter()) {
            *a += v;
        }
    })
}

/// The weights (α, β, σ − ½) of the three Lobatto points of a Hermite–Simpson piece: Simpson's
/// α = (1, 4, 1), the Hermite midpoint's β = (1, 0, −1) (000 Ch. 4) and the noise coefficient
/// of b in w = a + (σ − ½) b.
const HS_WEIGHTS: [(f64, f64, f64); 3] = [(1.0, 1.0, -0.5), (4.0, 0.0, 0.0), (1.0, -1.0, 0.5)];

/// The part of a Hermite–Simpson piece's constraint Jacobian (2ns rows × nv, row-major, nv the
/// length of the piece's local vector (s0, sm, s1, a, b, θ)) that does not depend on the point:
/// the derivatives of s1 − s0 and sm − ½(s0 + s1) and, through the noise term
/// G(a + (σ_i − ½) b) of the rate at the Lobatto points (weights −(h/6)(1, 4, 1) and
/// −(h/8)(1, 0, −1), see `PathNlp::hs_constraints`), ∂/∂a = G and ∂/∂b = (σ_i − ½) G on
/// the noisy rows.
fn hs_jacobian_constant(ns: usize, nx: usize, nv: usize, h: f64, g: &[f64]) -> Vec<f64> {
    let mut jac = vec![0.0; 2 * ns * nv];
    for i in 0..ns {
        jac[i * nv + i] -= 1.0; // c1 = s1 − s0 − …
        jac[i * nv + 2 * ns + i] += 1.0;
        jac[(ns + i) * nv + ns + i] += 1.0; // c2 = sm − ½(s0 + s1) − …
        jac[(ns + i) * nv + i] -= 0.5;
        jac[(ns + i) * nv + 2 * ns + i] -= 0.5;
    }
    for (alpha, beta, sigma) in HS_WEIGHTS {
        let (w1, w2) = (-alpha * h / 6.0, -beta * h / 8.0);
        for r in 0..nx {
            for j in 0..nx {
                let gv = g[r + j * nx];
                jac[r * nv + 3 * ns + j] += w1 * gv;
                jac[(ns + r) * nv + 3 * ns + j] += w2 * gv;
                jac[r * nv + 3 * ns + nx + j] += w1 * sigma * gv;
                jac[(ns + r) * nv + 3 * ns + nx + j] += w2 * sigma * gv;
            }
        }
    }
    jac
}

/// The Hessian pattern entry of variables a and b: (row, column) in the lower triangle, as
/// `u32` (`super::build_nlp` checks that the variables fit).
fn lower_pair(a: u32, b: u32) -> (u32, u32) {
    (a.max(b), a.min(b))
}

/// Length of the stack buffers of [`with_buffer`].
const BUFFER_LEN: usize = 64;

/// The lower triangle of the column-major n × n matrix `h`, column by column
/// ([`crate::model::packed_index`]), into the first n(n + 1)/2 entries of `out`: the packed
/// order of the Hessian blocks.
fn pack_lower(h: &[f64], n: usize, out: &mut [f64]) {
    pack_lower_split(h, n, out, &mut []);
}

/// [`pack_lower`] into two slices: the first `head.len()` entries into `head`, the others
/// into `tail`.
fn pack_lower_split(h: &[f64], n: usize, head: &mut [f64], tail: &mut [f64]) {
    let packed = (0..n).flat_map(|c| (c..n).map(move |r| h[r + c * n]));
    for (o, v) in head.iter_mut().chain(tail.iter_mut()).zip(packed) {
        *o = v;
    }
}

/// Calls `f` with a zeroed buffer of length `len`, on the stack when `len ≤ 64` (of 8 or 64
/// entries: only those are zeroed).
fn with_buffer<R>(len: usize, f: impl FnOnce(&mut [f64]) -> R) -> R {
    if len <= 8 {
        f(&mut [0.0; 8][..len])
    } else if len <= BUFFER_LEN {
        f(&mut [0.0; BUFFER_LEN][..len])
    } else {
        f(&mut vec![0.0; len])
    }
}

/// The per-point derivatives of the Hermite–Simpson pieces at one variable vector `w`: for
/// each Lobatto point, once per grid node (shared by the two pieces that meet there) and once
/// per midpoint, at `e · len` (entry e = [`PathNlp::hs_entry`]), the Jacobian of the outputs
/// [f; h] and, for Onsager–Machlup, div_x f in (s_i, θ_d) (outputs × npt, column-major), then
/// the packed lower triangles (column by column, [`crate::model::packed_index`]) of the
/// Hessians of the `stored` outputs: the others
/// (h = x and div_x f = −d for Duffing) are linear at every point seen so far.
/// Filled by `gradient`, which the solver calls first at each new iterate; `jacobian_values`
/// and `hessian_values` at the same `w` read it instead of differentiating again.
#[derive(Debug, Default)]
struct PointCache {
    /// The variable vector the cache holds (empty: none).
    w: Vec<f64>,
    data: Vec<f64>,
    /// Length of one point's entry.
    len: usize,
    /// The outputs whose Hessians are stored, ascending.
    stored: Vec<usize>,
    /// For each output, the position of its Hessian in an entry (after the Jacobian), or
    /// [`DriftDerivatives::DROPPED`].
    slots: Vec<usize>,
}

impl PointCache {
    /// The stored derivatives when they are those at `w`.
    fn at(&self, w: &[f64]) -> Option<&PointCache> {
        let same = self.w.len() == w.len() && self.w.iter().zip(w).all(|(a, b)| a.to_bits() == b.to_bits());
        (!self.w.is_empty() && same).then_some(self)
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

/// A Lobatto point of a Hermite–Simpson piece where [`PathNlp::hs_point_derivatives`]
/// differentiates the outputs: its time `t`, its states `s` (noisy then clean), the estimated
/// θ components `theta_e` and the full θ `theta` built from them.
#[derive(Debug, Clone, Copy)]
struct LobattoPoint<'p> {
    t: f64,
    s: &'p [f64],
    theta_e: &'p [f64],
    theta: &'p [f64],
}

/// The weights of the Hessian of the Lagrangian σ_f · (−merit) + λᵀc of one piece: the
/// objective factor σ_f and the piece's constraint multipliers λ.
#[derive(Debug, Clone, Copy)]
struct LagrangianWeights<'l> {
    obj_factor: f64,
    lambda: &'l [f64],
}

/// A function of one Lobatto point's (s_i, θ_d) (θ_d: the estimated θ that enter the
/// dynamics; the other estimated components are taken from `theta_e`): as a [`ScalarFn`],
/// `div_weight · div_x f + μᵀ [f; h]` (μ = 0 when `None`); as a [`VectorFn`], the rate
/// `[f; h]`, followed by div_x f when `with_div`.
struct PointFn<'b, 'a, S: Sde + ?Sized, O: Observation + ?Sized> {
    nlp: &'b PathNlp<'a, S, O>,
    t: f64,
    theta_e: &'b [f64],
    with_div: bool,
    div_weight: f64,
    mu: Option<&'b [f64]>,
}

impl<S: Sde + ?Sized, O: Observation + ?Sized> PointFn<'_, '_, S, O> {
    /// Writes the rate [f; h] at the point into `rate` (unless it is empty) and returns
    /// div_x f when `div` (else 0), building θ once.
    fn eval_into<D: Scalar>(&self, w: &[D], rate: &mut [D], div: bool) -> D {
        let p = self.nlp.problem;
        let d = p.sde.dims();
        let (ns, nx, nt) = (d.states(), d.noisy, p.theta.len());
        let (x, z) = w[..ns].split_at(nx);
        let t = D::from(self.t);
        let fill = |theta: &mut [D]| {
            for (b, &v) in theta.iter_mut().zip(p.theta) {
                *b = D::from(v);
            }
            for (&i, &v) in p.estimate.iter().zip(self.theta_e) {
                theta[i] = D::from(v);
            }
            for (&j, &v) in self.nlp.point_theta.iter().zip(&w[ns..]) {
                theta[p.estimate[j]] = v;
            }
        };
        let run = |theta: &[D], rate: &mut [D]| {
            if !rate.is_empty() {
                p.sde.drift(t, x, z, theta, &mut rate[..nx]);
                p.sde.clean_drift(t, x, z, theta, &mut rate[nx..]);
            }
            if div {
                p.sde.divergence(t, x, z, theta)
            } else {
                D::from(0.0)
            }
        };
        ad::with_zeros(nt, |theta| {
            fill(theta);
            run(theta, rate)
        })
    }
}

impl<S: Sde + ?Sized, O: Observation + ?Sized> ScalarFn for PointFn<'_, '_, S, O> {
    fn dim_in(&self) -> usize {
        self.nlp.hs_point_dim()
    }
    fn eval<D: Scalar>(&self, w: &[D]) -> D {
        let ns = self.nlp.problem.sde.dims().states();
        let div = self.div_weight != 0.0;
        match self.mu {
            Some(mu) => ad::with_zeros(ns, |r| {
                let mut v = self.eval_into(w, r, div) * self.div_weight;
                for (ri, &m) in r.iter().zip(mu) {
                    v += *ri * m;
                }
                v
            }),
            None => self.eval_into(w, &mut [], div) * self.div_weight,
        }
    }
}

impl<S: Sde + ?Sized, O: Observation + ?Sized> VectorFn for PointFn<'_, '_, S, O> {
    fn dim_in(&self) -> usize {
        self.nlp.hs_point_dim()
    }
    fn dim_out(&self) -> usize {
        self.nlp.problem.sde.dims().states() + usize::from(self.with_div)
    }
    fn eval<D: Scalar>(&self, w: &[D], out: &mut [D]) {
        let ns = self.nlp.problem.sde.dims().states();
        let (rate, rest) = out.split_at_mut(ns);
        let v = self.eval_into(w, rate, self.with_div);
        if self.with_div {
            rest[0] = v;
        }
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
        lower.fill(f64::NEG_INFINITY);
        upper.fill(f64::INFINITY);
        for &(i, l, u) in &self.bounds {
            lower[i] = l;
            upper[i] = u;
        }
    }

    fn initial_point(&self, w: &mut [f64]) {
        w.copy_from_slice(&self.initial);
    }

    fn objective(&mut self, w: &[f64]) -> f64 {
        -self.merit_parts(w).total()
    }

    fn gradient(&mut self, w: &[f64], grad: &mut [f64]) {
        grad.fill(0.0);
        let mut cache = std::mem::take(&mut self.cache);
        cache.w.clear();
        if self.transcription == Transcription::HermiteSimpson {
            self.hs_points_into(w, &mut cache);
        }
        for b in &self.blocks {
            if let Some(k) = self.hs_piece(b) {
                self.hs_gradient_into(k, b, w, grad, &cache);
                continue;
            }
            with_buffer(b.vars.len(), |local| {
                self.locals_into(b, w, local);
                with_buffer(local.len(), |g| {
                    ad::gradient_into(&ObjFn { nlp: self, block: b }, local, g);
                    for (&v, gi) in self.vars(b).iter().zip(g) {
                        grad[v as usize] += *gi;
                    }
                })
            });
        }
        if self.transcription == Transcription::HermiteSimpson {
            cache.w.extend_from_slice(w);
        }
        self.cache = cache;
    }

    fn constraints(&mut self, w: &[f64], c: &mut [f64]) {
        if self.transcription == Transcription::HermiteSimpson {
            // only the pieces have constraints
            self.hs_constraints(w, c);
            return;
        }
        for b in self.blocks.iter().filter(|b| b.rows > 0) {
            with_buffer(b.vars.len(), |local| {
                self.locals_into(b, w, local);
                self.block_constraints(b, local, &mut c[b.row0..b.row0 + b.rows]);
            });
        }
    }

    fn jacobian_structure(&self) -> Vec<(u32, u32)> {
        let mut s = Vec::with_capacity(self.n_jac);
        for b in &self.blocks {
            for r in 0..b.rows {
                for &v in self.vars(b) {
                    s.push(((b.row0 + r) as u32, v));
                }
            }
        }
        s
    }

    fn jacobian_values(&mut self, w: &[f64], values: &mut [f64]) {
        let cached = self.cache.at(w);
        for b in self.blocks.iter().filter(|b| b.rows > 0) {
            let nv = b.vars.len();
            let out = &mut values[b.jac0..b.jac0 + b.rows * nv];
            if let (Some(k), Some(_)) = (self.hs_piece(b), cached) {
                self.hs_jacobian_into(k, &[], out, cached);
                continue;
            }
            with_buffer(nv, |local| {
                self.locals_into(b, w, local);
                match self.hs_piece(b) {
                    Some(k) => self.hs_jacobian_into(k, local, out, cached),
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

    /// The KKT rows in time order, which keeps the KKT matrix a narrow band, the estimated θ
    /// last (a border). Euler and trapezoidal: the nodes, each with its components in reverse
    /// order, and each interval's clean-state defects right after its end node (the order the
    /// band solver's reverse Cuthill–McKee search finds on these patterns, without the search).
    ///
    /// Hermite–Simpson, piece k: its noise coefficients (a_k, b_k); the defects of the states
    /// the noise drives (rows of G with a nonzero entry), Simpson's then Hermite's; for k = 0
    /// the first node; the midpoint; the other defects; the end node. A state whose
    /// Lagrangian has no curvature (a velocity entering the drifts linearly, as in Van der Pol
    /// and Duffing) is then eliminated after a defect that holds it with a nonzero
    /// coefficient (Hermite's has 1 on the midpoint, Simpson's h/6 on the nodes), and each of
    /// those defects after the noise coefficients (curvature from the energy) that enter it,
    /// so no pivot of the unpivoted LDLᵀ is structurally zero. The node-first order with the
    /// defects after their last variable, which reverse Cuthill–McKee finds, has at least two
    /// zero pivots per piece on these models, regularised at the cost of a refinement step in
    /// every solve, and a wider envelope (test
    /// `kkt_order_avoids_zero_pivots_and_narrows_the_band`). Putting the undriven states'
    /// defects (Duffing's clean position) before the midpoint too would leave their two
    /// defects coupled to the earlier variables almost only through one node value, a nearly
    /// singular pair.
    fn kkt_order(&self) -> Option<Vec<usize>> {
        let d = self.problem.sde.dims();
        let (ns, nx) = (d.states(), d.noisy);
        let n = self.grid.intervals;
        let theta0 = self.n_vars - self.problem.estimate.len();
        let nv = self.n_vars;
        let mut order = Vec::with_capacity(nv + self.n_cons);
        let node = |k: usize| k * ns..(k + 1) * ns;
        if self.transcription == Transcription::HermiteSimpson {
            let (mid0, noise0) = self.hs_offsets();
            // the defect rows i (Simpson) and ns + i (Hermite) of the states the noise drives
            let driven: Vec<bool> =
                (0..ns).map(|i| i < nx && (0..nx).any(|j| self.g_fixed[i + j * nx] != 0.0)).collect();
            let driven = &driven;
            let rows = |k: usize, want: bool| {
                (0..2 * ns).filter(move |&r| driven[r % ns] == want).map(move |r| nv + 2 * ns * k + r)
            };
            for k in 0..n {
                order.extend(noise0 + 2 * nx * k..noise0 + 2 * nx * (k + 1));
                order.extend(rows(k, true));
                if k == 0 {
                    order.extend(node(0));
                }
                order.extend(mid0 + ns * k..mid0 + ns * (k + 1));
                order.extend(rows(k, false));
                order.extend(node(k + 1));
            }
        } else {
            let rows = d.clean;
            order.extend(node(0).rev());
            for k in 0..n {
                order.extend(node(k + 1).rev());
                order.extend(nv + rows * k..nv + rows * (k + 1));
            }
        }
        order.extend(theta0..nv);
        debug_assert_eq!(order.len(), nv + self.n_cons);
        Some(order)
    }

    fn hessian_structure(&self) -> Vec<(u32, u32)> {
        let mut s = Vec::with_capacity(self.n_hess);
        // Hermite–Simpson: the (θ_d, θ_d) block summed over all Lobatto points first, so that
        // the KKT slots receive the same sums in the same order as from one entry per point
        if self.hs_theta_tri > 0 {
            let theta0 = self.n_vars - self.problem.estimate.len();
            let v = |j: usize| (theta0 + self.point_theta[j]) as u32;
            let nt = self.point_theta.len();
            for c in 0..nt {
                for r in c..nt {
                    s.push(lower_pair(v(r), v(c)));
                }
            }
        }
        for b in &self.blocks {
            if self.hs_piece(b).is_some() {
                self.hs_hessian_structure(b, &mut s);
                continue;
            }
            // packed column by column, as `pack_lower` writes the values
            let vars = self.vars(b);
            for (j, &vj) in vars.iter().enumerate() {
                for &vi in &vars[j..] {
                    s.push(lower_pair(vi, vj));
                }
            }
        }
        s
    }

    fn hessian_values(&mut self, w: &[f64], obj_factor: f64, lambda: &[f64], values: &mut [f64]) {
        let cached = self.cache.at(w);
        let t0 = self.hs_theta_tri;
        let (theta, values) = values.split_at_mut(t0);
        theta.fill(0.0);
        for (bi, b) in self.blocks.iter().enumerate() {
            let lam = &lambda[b.row0..b.row0 + b.rows];
            let weights = LagrangianWeights { obj_factor, lambda: lam };
            let end = self.blocks.get(bi + 1).map_or(values.len() + t0, |n| n.hess0);
            let out = &mut values[b.hess0 - t0..end - t0];
            if let (Some(k), Some(_)) = (self.hs_piece(b), cached) {
                // the cached path does not read the local vector
                self.hs_hessian_into(k, &[], weights, out, theta, cached);
                continue;
            }
            with_buffer(b.vars.len(), |local| {
                self.locals_into(b, w, local);
                match self.hs_piece(b) {
                    Some(k) => self.hs_hessian_into(k, local, weights, out, theta, cached),
                    None => {
                        let nv = b.vars.len();
                        let f = LagFn { nlp: self, block: b, obj_factor, lambda: lam };
                        with_buffer(nv, |g| {
                            with_buffer(nv * nv, |h| {
                                ad::hessian_into(&f, local, g, h);
                                pack_lower(h, nv, out);
                            })
                        })
                    }
                }
            });
        }
    }
}
