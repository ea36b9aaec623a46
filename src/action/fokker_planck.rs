//! The Fokker–Planck operator on a grid and its exact discrete adjoint.
//!
//! The forward Kolmogorov (Fokker–Planck) equation `003_d2fc48a470e528fc.txt (0.4), (I.16)`,
//!
//! $$ \partial_t \mathcal P = -\nabla\cdot(f\mathcal P) + \nabla\cdot(D\nabla\mathcal P), \qquad D = \tfrac12 GG^\top, $$
//!
//! is discretised in conservative flux form on the cell masses m_i with the Chang–Cooper
//! (Scharfetter–Gummel) flux across the face between cells i and i+1 of an axis with width h,
//!
//! $$ J_{i+1/2} = \frac{D}{h^2}\bigl[B(-w)\,m_i - B(w)\,m_{i+1}\bigr], \qquad w = \frac{f_{i+1/2}\,h}{D}, \qquad B(w) = \frac{w}{e^w - 1}, $$
//!
//! (upwind fluxes where D = 0, i.e. along clean states), zero flux through the boundary. Both
//! coefficients are non-negative, so the generator L has non-negative off-diagonals and zero
//! column sums; the flux is second order in h for smooth densities.
//!
//! A time step is of second order: per axis the two-stage (TR-BDF2) rational function
//! S_a(τ) = (a M_a⁻¹ − (a − 1)) M_a⁻¹, M_a = I − g τ L_a, g = 1 − 1/√2, a = 1 + √2, so that
//! S_a = I + τL + τ²L²/2 + O(τ³), with |S_a| → 0 for stiff modes (L-stable). In two and three
//! dimensions the axes are Strang-split, S = S₀(Δt/2) S₁(Δt) S₀(Δt/2) and
//! S = S₀(Δt/2) S₁(Δt/2) S₂(Δt) S₁(Δt/2) S₀(Δt/2) (Strang, SIAM J. Numer. Anal. 5 (1968)
//! 506–517: a symmetric product of second-order factors is of second order). Because
//! 1ᵀM_a = 1ᵀ, every step keeps the total mass exactly. The damped step ([`StepKind::Damped`],
//! used after a jump) is eight implicit Euler steps (I − Δt/8 L_a)⁻¹ per axis: every M_a is a column-diagonally-dominant
//! M-matrix, so it keeps positivity, and it removes the stiff modes a jump excites, which the
//! two-stage step would map to small negative multiples (R(z) = (1 + (√2 − 1)z)/(1 − gz)² is
//! negative for z < −(1 + √2), down to −0.21). The backward Kolmogorov step
//! `003 (I.17)` is the exact transpose (the sub-steps in reverse order, M_a⁻ᵀ for M_a⁻¹), so
//! ⟨a, m⟩ is conserved by the discrete scheme to rounding.
//!
//! The first-order alternative [`TimeScheme::ImplicitEuler`] makes every step one implicit Euler
//! step (I − Δt L_a)⁻¹ per axis (Lie splitting in two and three dimensions, m⁺ = M₁⁻¹ M₀⁻¹ m in
//! two), the damped step with a single sub-step: positive at every step size, first order in Δt.

use serde::{Deserialize, Serialize};

use crate::model::Sde;
use crate::{Error, Result};

use super::grid::{Grid, MAX_AXES};

/// B(w) = w/(eʷ − 1), the Bernoulli function of the Chang–Cooper flux, stable for all w.
fn bernoulli(w: f64) -> f64 {
    if w.abs() < 1e-6 {
        1.0 - 0.5 * w + w * w / 12.0
    } else {
        w / w.exp_m1()
    }
}

/// How the cells of one axis are laid out: `len` cells per line, `lines` lines; cell p of a line
/// is `stride` cells after cell p − 1 (the product of the lower axes' cell counts). The lines
/// come in blocks of `stride` neighbouring lines ([`Axis::line_start`]): in one block their cells
/// p lie side by side, so a strided axis is solved on all lines of a block in lockstep.
#[derive(Debug, Clone, Copy)]
struct Axis {
    len: usize,
    stride: usize,
    lines: usize,
}

impl Axis {
    fn of(grid: &Grid, a: usize) -> Axis {
        let c = grid.cells();
        Axis { len: c[a], stride: c[..a].iter().product(), lines: grid.len() / c[a] }
    }

    /// The first cell of line q: line q mod stride of block ⌊q / stride⌋ (blocks of
    /// stride · len cells).
    fn line_start(&self, q: usize) -> usize {
        q % self.stride + (q / self.stride) * self.stride * self.len
    }

    /// The blocks of lines, as ranges of cells (one line per block on a contiguous axis).
    fn blocks(&self) -> impl Iterator<Item = std::ops::Range<usize>> {
        let size = self.stride * self.len;
        (0..self.lines / self.stride).map(move |b| b * size..(b + 1) * size)
    }
}

/// The LU factors of one axis's tridiagonal matrices M = I − Δt L (all lines), indexed by cell:
/// unit lower factor `l`, inverse diagonal of U `uinv`, super-diagonal `c`.
#[derive(Debug, Clone)]
struct AxisFactor {
    l: Vec<f64>,
    uinv: Vec<f64>,
    c: Vec<f64>,
}

/// The factors of one time step (one per axis): of the two-stage step and of the damped step.
#[derive(Debug, Clone)]
struct StepFactors {
    dt: f64,
    axes: Vec<AxisFactor>,
    damped: Vec<AxisFactor>,
}

/// The discrete Fokker–Planck operator of an [`Sde`] at fixed θ on a [`Grid`].
///
/// For an autonomous drift (checked at construction) the factorisation of each distinct step
/// size is computed once by [`FokkerPlanck::prepare`]; otherwise every step assembles and factors
/// its matrices at the step's end time.
pub struct FokkerPlanck<'a, S: Sde + ?Sized> {
    sde: &'a S,
    theta: Vec<f64>,
    grid: Grid,
    diff: Vec<f64>,
    axes: Vec<Axis>,
    autonomous: bool,
    cache: Vec<StepFactors>,
    scheme: TimeScheme,
    /// Tridiagonal solves so far (one per vector and axis sub-step, all lines of the axis).
    solves: std::cell::Cell<usize>,
    /// Work vector of the two-stage step (M⁻¹x), kept between steps.
    scratch: std::cell::Cell<Vec<f64>>,
}

impl<S: Sde + ?Sized> std::fmt::Debug for FokkerPlanck<'_, S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FokkerPlanck")
            .field("grid", &self.grid)
            .field("diffusion", &self.diff)
            .field("autonomous", &self.autonomous)
            .finish()
    }
}

/// Checks that the grid methods can take `sde` on `grid`: at most [`MAX_AXES`] noisy states, and one
/// grid axis per state (noisy then clean). Errors: [`Error::InvalidOption`].
pub fn check_model_fits_grid<S: Sde + ?Sized>(sde: &S, grid: &Grid) -> Result<()> {
    let d = sde.dims();
    if d.noisy > MAX_AXES {
        return Err(Error::InvalidOption {
            name: "model".into(),
            reason: format!(
                "the grid methods handle models with 1 to {MAX_AXES} noisy states; this model has {}",
                d.noisy
            ),
        });
    }
    if d.states() != grid.dim() {
        return Err(Error::InvalidOption {
            name: "grid".into(),
            reason: format!(
                "the grid has {} axes but the model has {} states (noisy then clean: {})",
                grid.dim(),
                d.states(),
                sde.state_names().join(", ")
            ),
        });
    }
    Ok(())
}

impl<'a, S: Sde + ?Sized> FokkerPlanck<'a, S> {
    /// The operator of `sde` at `theta` on `grid`, whose axes are the states [x; z].
    /// `probe_times` are times at which the drift is compared to decide whether it is autonomous.
    ///
    /// Errors: [`Error::InvalidOption`] when the model has more than [`MAX_AXES`] noisy states, when the
    /// grid's axes are not the model's states, or when D = ½GGᵀ is not diagonal in two or three
    /// dimensions (the split scheme needs it); [`Error::SingularDiffusion`] for a bad G(θ).
    pub fn try_new(sde: &'a S, theta: &[f64], grid: &Grid, probe_times: &[f64]) -> Result<Self> {
        check_model_fits_grid(sde, grid)?;
        let d = sde.dims();
        let g = sde.diffusion_matrix(theta)?;
        let dd = &g * g.transpose() * 0.5;
        let mut diff = vec![0.0; grid.dim()];
        for i in 0..d.noisy {
            diff[i] = dd[(i, i)];
            for j in 0..d.noisy {
                if i != j && dd[(i, j)].abs() > 1e-14 * (dd[(i, i)] + dd[(j, j)]) {
                    return Err(Error::InvalidOption {
                        name: "model".into(),
                        reason: "the split grid scheme needs a diagonal diffusion matrix ½GGᵀ".into(),
                    });
                }
            }
        }
        let axes = (0..grid.dim()).map(|a| Axis::of(grid, a)).collect();
        let mut fp = FokkerPlanck {
            sde,
            theta: theta.to_vec(),
            grid: grid.clone(),
            diff,
            axes,
            autonomous: true,
            cache: Vec::new(),
            scheme: TimeScheme::default(),
            solves: std::cell::Cell::new(0),
            scratch: std::cell::Cell::new(Vec::new()),
        };
        if let Some(&t0) = probe_times.first() {
            let first = fp.face_drifts(t0);
            fp.autonomous = probe_times[1..].iter().all(|&t| fp.face_drifts(t) == first);
        }
        for v in fp.face_drifts(probe_times.first().copied().unwrap_or(0.0)) {
            if v.iter().any(|f| !f.is_finite()) {
                return Err(Error::NonFinite { what: "drift at a face of the grid".into() });
            }
        }
        Ok(fp)
    }

    /// The operator with time scheme `scheme` (default [`TimeScheme::TrBdf2`]); set it before
    /// [`FokkerPlanck::prepare`].
    pub fn with_scheme(mut self, scheme: TimeScheme) -> Self {
        self.scheme = scheme;
        self.cache.clear();
        self
    }

    /// The time scheme.
    pub fn scheme(&self) -> TimeScheme {
        self.scheme
    }

    /// The number of tridiagonal solves of the steps taken so far: one per vector and axis
    /// sub-step (each solves every line of the axis), a machine-independent measure of the work.
    pub fn solves(&self) -> usize {
        self.solves.get()
    }

    /// The implicit Euler sub-steps of a damped step: [`DAMPING_STEPS`] for TR-BDF2, one (the
    /// whole step) for implicit Euler.
    fn euler_substeps(&self) -> usize {
        match self.scheme {
            TimeScheme::TrBdf2 => DAMPING_STEPS,
            TimeScheme::ImplicitEuler => 1,
        }
    }

    /// The kind of step the scheme takes when `kind` is asked for: implicit Euler steps are all
    /// damped steps of one sub-step.
    fn effective(&self, kind: StepKind) -> StepKind {
        match self.scheme {
            TimeScheme::TrBdf2 => kind,
            TimeScheme::ImplicitEuler => StepKind::Damped,
        }
    }

    /// Whether the drift was found autonomous (the factorisations are then reused).
    pub fn is_autonomous(&self) -> bool {
        self.autonomous
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The diffusion coefficient D_aa of each axis (0 along clean states).
    pub fn diffusion(&self) -> &[f64] {
        &self.diff
    }

    /// Factors the step matrices for each of the step sizes `dts` (autonomous drift only; a
    /// no-op otherwise).
    pub fn prepare(&mut self, dts: &[f64]) {
        if !self.autonomous {
            return;
        }
        for &dt in dts {
            if self.cached(dt).is_none() {
                let f = self.factor(0.0, dt, None);
                self.cache.push(f);
            }
        }
    }

    /// The number of step sizes whose factors are kept ([`FokkerPlanck::prepare`]).
    pub fn factored_step_sizes(&self) -> usize {
        self.cache.len()
    }

    fn cached(&self, dt: f64) -> Option<&StepFactors> {
        self.cache.iter().find(|f| f.dt == dt)
    }

    /// Drift of each axis at the faces between consecutive cells (index of the left cell; the
    /// last cell of a line has no face and gets 0).
    fn face_drifts(&self, t: f64) -> Vec<Vec<f64>> {
        let d = self.sde.dims();
        let n = self.grid.len();
        let mut s = vec![0.0; self.grid.dim()];
        let mut f = vec![0.0; d.noisy];
        let mut h = vec![0.0; d.clean];
        (0..self.grid.dim())
            .map(|a| {
                let ax = self.axes[a];
                let mut out = vec![0.0; n];
                for q in 0..ax.lines {
                    for p in 0..ax.len - 1 {
                        let idx = ax.line_start(q) + p * ax.stride;
                        self.grid.coords(idx, &mut s);
                        s[a] += 0.5 * self.grid.widths()[a];
                        let (x, z) = s.split_at(d.noisy);
                        out[idx] = if a < d.noisy {
                            self.sde.drift(t, x, z, &self.theta, &mut f);
                            f[a]
                        } else {
                            self.sde.clean_drift(t, x, z, &self.theta, &mut h);
                            h[a - d.noisy]
                        };
                    }
                }
                out
            })
            .collect()
    }

    /// The Chang–Cooper rates of each axis at time t: `(a, b)` per face (left cell index), the
    /// flux being J = a m_left − b m_right.
    fn rates(&self, t: f64) -> Vec<(Vec<f64>, Vec<f64>)> {
        let drifts = self.face_drifts(t);
        drifts
            .into_iter()
            .enumerate()
            .map(|(axis, fd)| {
                let h = self.grid.widths()[axis];
                let dcoef = self.diff[axis];
                let (mut ra, mut rb) = (vec![0.0; fd.len()], vec![0.0; fd.len()]);
                for (i, &f) in fd.iter().enumerate() {
                    if dcoef > 0.0 {
                        let w = f * h / dcoef;
                        let k = dcoef / (h * h);
                        ra[i] = k * bernoulli(-w);
                        rb[i] = k * bernoulli(w);
                    } else {
                        ra[i] = f.max(0.0) / h;
                        rb[i] = (-f).max(0.0) / h;
                    }
                }
                (ra, rb)
            })
            .collect()
    }

    /// The generator L applied to `m` at time t (used by tests and diagnostics): dm/dt = L m.
    pub fn apply_generator(&self, t: f64, m: &[f64]) -> Vec<f64> {
        let rates = self.rates(t);
        let mut out = vec![0.0; m.len()];
        for (axis, (ra, rb)) in rates.iter().enumerate() {
            let ax = self.axes[axis];
            for q in 0..ax.lines {
                for p in 0..ax.len - 1 {
                    let i = ax.line_start(q) + p * ax.stride;
                    let j = i + ax.stride;
                    let flux = ra[i] * m[i] - rb[i] * m[j];
                    out[i] -= flux;
                    out[j] += flux;
                }
            }
        }
        out
    }

    /// The factors of one step of size `dt` with the rates at time `t`: per axis, the LU factors
    /// of I − g τ_a L_a with τ_a the axis's sub-step ([`FokkerPlanck::substep`]), and of the
    /// damping sub-step I − (dt/n) L_a (n = [`FokkerPlanck::euler_substeps`]); only those of
    /// `only` if given (implicit Euler: only the damping factors, n = 1).
    fn factor(&self, t: f64, dt: f64, only: Option<StepKind>) -> StepFactors {
        let rates = self.rates(t);
        let dim = rates.len();
        let only = if self.scheme == TimeScheme::ImplicitEuler { Some(StepKind::Damped) } else { only };
        let smooth = only != Some(StepKind::Damped);
        let damped = only != Some(StepKind::Smooth);
        let axes = (0..dim)
            .filter(|_| smooth)
            .map(|a| self.axis_factor(a, &rates[a], STAGE * self.substep(a, dt)))
            .collect();
        let damped = (0..dim)
            .filter(|_| damped)
            .map(|a| self.axis_factor(a, &rates[a], dt / self.euler_substeps() as f64))
            .collect();
        StepFactors { dt, axes, damped }
    }

    /// The LU factors of I − k L_a on every line of axis `axis` (rates `(ra, rb)` per face).
    fn axis_factor(&self, axis: usize, (ra, rb): &(Vec<f64>, Vec<f64>), k: f64) -> AxisFactor {
        let ax = self.axes[axis];
        let n = self.grid.len();
        let (mut l, mut uinv, mut c) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        for q in 0..ax.lines {
            let mut u_prev = 0.0;
            let mut sup_prev = 0.0;
            for p in 0..ax.len {
                let i = ax.line_start(q) + p * ax.stride;
                let last = p + 1 == ax.len;
                let (a_in, b_in) = if p > 0 { (ra[i - ax.stride], rb[i - ax.stride]) } else { (0.0, 0.0) };
                let (a_out, b_out) = if last { (0.0, 0.0) } else { (ra[i], rb[i]) };
                let sub = -k * a_in;
                let diag = 1.0 + k * (b_in + a_out);
                let sup = -k * b_out;
                let u = if p == 0 {
                    diag
                } else {
                    let li = sub / u_prev;
                    l[i] = li;
                    diag - li * sup_prev
                };
                uinv[i] = 1.0 / u;
                c[i] = sup;
                u_prev = u;
                sup_prev = sup;
            }
        }
        AxisFactor { l, uinv, c }
    }

    /// The sub-step of axis `axis` within a step `dt`: dt for the last axis, dt/2 for the others
    /// (the Strang sequence 0, 1, 0 in two dimensions, 0, 1, 2, 1, 0 in three, each of the outer
    /// axes twice over dt/2).
    fn substep(&self, axis: usize, dt: f64) -> f64 {
        if axis + 1 < self.grid.dim() {
            0.5 * dt
        } else {
            dt
        }
    }

    /// Runs `f` with the factors of a step of size `dt` ending at `t_new`: the cached ones for
    /// an autonomous drift, otherwise freshly factored (only those of `kind`) with the rates at
    /// the step's midpoint (TR-BDF2) or end (implicit Euler).
    fn with_factors<R>(&self, t_new: f64, dt: f64, kind: StepKind, f: impl FnOnce(&StepFactors) -> R) -> R {
        if self.autonomous {
            if let Some(fac) = self.cached(dt) {
                return f(fac);
            }
        }
        let t = match self.scheme {
            TimeScheme::TrBdf2 => t_new - 0.5 * dt,
            TimeScheme::ImplicitEuler => t_new,
        };
        let fac = self.factor(t, dt, Some(kind));
        f(&fac)
    }

    /// Applies the step (or, with `adjoint`, its transpose) to `x`, where `solve(axis factor,
    /// axis, x)` applies M⁻¹ (or M⁻ᵀ) in place and returns the number of vectors it solved, and
    /// `combine(x, x0)` sets x ← a x − (a − 1) x0. The two-stage sub-steps keep M⁻¹x in a
    /// buffer reused from step to step.
    fn apply(
        &self,
        (t_new, dt): (f64, f64),
        kind: StepKind,
        adjoint: bool,
        x: &mut [f64],
        mut solve: impl FnMut(&AxisFactor, Axis, &mut [f64]) -> usize,
        combine: impl Fn(&mut [f64], &[f64]),
    ) {
        let kind = self.effective(kind);
        let mut solve = |f: &AxisFactor, ax: Axis, x: &mut [f64]| {
            let n = solve(f, ax, x);
            self.solves.set(self.solves.get() + n);
        };
        let dim = self.axes.len();
        // The axis of sub-step k of the forward sequence; the adjoint runs it backwards.
        let axis = |k: usize, len: usize| {
            let k = if adjoint { len - 1 - k } else { k };
            k % dim
        };
        self.with_factors(t_new, dt, kind, |fac| match kind {
            StepKind::Damped => {
                let len = self.euler_substeps() * dim;
                for k in 0..len {
                    let a = axis(k, len);
                    solve(&fac.damped[a], self.axes[a], x);
                }
            }
            StepKind::Smooth => {
                // Strang sequence 0, 1, 0 in two dimensions, 0, 1, 2, 1, 0 in three (a palindrome:
                // the same for the adjoint).
                let seq = (0..dim).chain((0..dim - 1).rev());
                let mut x0 = self.scratch.take();
                x0.resize(x.len(), 0.0);
                for a in seq {
                    let af = &fac.axes[a];
                    solve(af, self.axes[a], x);
                    x0.copy_from_slice(x);
                    solve(af, self.axes[a], x);
                    combine(x, &x0);
                }
                self.scratch.set(x0);
            }
        });
    }

    /// One forward (Fokker–Planck) step of size `dt` ending at `t_new`: m ← S m with
    /// S = S₀(dt/2) S₁(dt) S₀(dt/2) in two dimensions (likewise in three), S_a(τ) = R(τ L_a) (see
    /// the module doc); a [`StepKind::Damped`] step is eight implicit Euler sub-steps of dt/8
    /// instead.
    pub fn step(&self, t_new: f64, dt: f64, kind: StepKind, m: &mut [f64]) {
        self.apply(
            (t_new, dt),
            kind,
            false,
            m,
            |f, ax, x| {
                solve(ax, f, x);
                1
            },
            |x, x0| combine(x, x0, 1, 1),
        );
    }

    /// One backward (Kolmogorov) step, the exact transpose of [`FokkerPlanck::step`]:
    /// a ← Sᵀ a (the sub-steps in reverse order, each transposed).
    pub fn step_adjoint(&self, t_new: f64, dt: f64, kind: StepKind, a: &mut [f64]) {
        self.apply(
            (t_new, dt),
            kind,
            true,
            a,
            |f, ax, x| {
                solve_transposed(ax, f, x);
                1
            },
            |x, x0| combine(x, x0, 1, 1),
        );
    }

    /// [`FokkerPlanck::step`] applied to the first `active` of `nv` vectors stored interleaved
    /// (`x[cell · nv + v]`), in lockstep (the tangent sweeps).
    pub fn step_batch(&self, t_new: f64, dt: f64, kind: StepKind, x: &mut [f64], nv: usize, active: usize) {
        self.apply(
            (t_new, dt),
            kind,
            false,
            x,
            |f, ax, x| {
                solve_batch(ax, f, x, nv, active);
                active
            },
            |x, x0| combine(x, x0, nv, active),
        );
    }

    /// [`FokkerPlanck::step_adjoint`] applied to the first `active` of `nv` interleaved vectors.
    pub fn step_adjoint_batch(
        &self,
        t_new: f64,
        dt: f64,
        kind: StepKind,
        x: &mut [f64],
        nv: usize,
        active: usize,
    ) {
        self.apply(
            (t_new, dt),
            kind,
            true,
            x,
            |f, ax, x| {
                solve_transposed_batch(ax, f, x, nv, active);
                active
            },
            |x, x0| combine(x, x0, nv, active),
        );
    }
}

/// The number of implicit Euler sub-steps of a damped step.
const DAMPING_STEPS: usize = 8;

/// The time scheme of the exact grid estimators (option `scheme`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum TimeScheme {
    /// Second order: the two-stage TR-BDF2 step per axis (Strang splitting in two and three
    /// dimensions), eight implicit Euler sub-steps after t0 and after every measurement (see the
    /// module doc).
    #[default]
    TrBdf2,
    /// First order: one implicit Euler step per axis (Lie splitting in two and three dimensions);
    /// positive at every step size, one tridiagonal solve per axis and step.
    ImplicitEuler,
}

/// Which step a sweep asks for (the scheme decides what it is, [`TimeScheme`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StepKind {
    /// The scheme's regular step: the two-stage step of TR-BDF2, one implicit Euler step.
    Smooth,
    /// Eight implicit Euler sub-steps of dt/8 (positive, first order): the first step after a
    /// jump, which damps the stiff modes a jump excites. With [`TimeScheme::ImplicitEuler`]
    /// every step is one implicit Euler step of dt.
    Damped,
}

/// The implicit coefficient g = 1 − 1/√2 of the two-stage step R(z) = (a/(1 − gz) − (a − 1))/(1 − gz).
const STAGE: f64 = 1.0 - std::f64::consts::FRAC_1_SQRT_2;

/// The weight a = 1 + √2 of the two-stage step (a = 1/g − 1).
const OUTER: f64 = 1.0 + std::f64::consts::SQRT_2;

/// x ← a x − (a − 1) x0 on the first `active` of every `nv` interleaved entries.
fn combine(x: &mut [f64], x0: &[f64], nv: usize, active: usize) {
    if nv == 1 {
        x.iter_mut().zip(x0).for_each(|(v, v0)| *v = OUTER * *v - (OUTER - 1.0) * v0);
        return;
    }
    for (c, c0) in x.chunks_exact_mut(nv).zip(x0.chunks_exact(nv)) {
        for (v, v0) in c[..active].iter_mut().zip(&c0[..active]) {
            *v = OUTER * *v - (OUTER - 1.0) * v0;
        }
    }
}

/// Visits the cells of an axis at positions `ps` (in that order) on every line: one line at a
/// time for contiguous lines, for strided ones the lines of a block in lockstep (contiguous
/// memory).
fn for_cells(ax: Axis, ps: impl Iterator<Item = usize> + Clone, mut f: impl FnMut(usize)) {
    if ax.stride == 1 {
        for q in 0..ax.lines {
            for p in ps.clone() {
                f(q * ax.len + p);
            }
        }
    } else {
        for block in ax.blocks() {
            for p in ps.clone() {
                let first = block.start + p * ax.stride;
                (first..first + ax.stride).for_each(&mut f);
            }
        }
    }
}

/// [`solve`] for `active` of `nv` interleaved vectors.
fn solve_batch(ax: Axis, f: &AxisFactor, x: &mut [f64], nv: usize, active: usize) {
    let (s, len) = (ax.stride, ax.len);
    for_cells(ax, 1..len, |i| {
        let li = f.l[i];
        let (prev, cur) = x.split_at_mut(i * nv);
        let prev = &prev[(i - s) * nv..(i - s) * nv + active];
        for (c, pr) in cur[..active].iter_mut().zip(prev) {
            *c -= li * pr;
        }
    });
    for_cells(ax, len - 1..len, |i| {
        let u = f.uinv[i];
        x[i * nv..i * nv + active].iter_mut().for_each(|v| *v *= u);
    });
    for_cells(ax, (0..len - 1).rev(), |i| {
        let (ci, ui) = (f.c[i], f.uinv[i]);
        let (cur, next) = x.split_at_mut((i + s) * nv);
        let cur = &mut cur[i * nv..i * nv + active];
        for (c, nx) in cur.iter_mut().zip(&next[..active]) {
            *c = (*c - ci * nx) * ui;
        }
    });
}

/// [`solve_transposed`] for `active` of `nv` interleaved vectors.
fn solve_transposed_batch(ax: Axis, f: &AxisFactor, x: &mut [f64], nv: usize, active: usize) {
    let (s, len) = (ax.stride, ax.len);
    for_cells(ax, 0..1, |i| {
        let u = f.uinv[i];
        x[i * nv..i * nv + active].iter_mut().for_each(|v| *v *= u);
    });
    for_cells(ax, 1..len, |i| {
        let (ci, ui) = (f.c[i - s], f.uinv[i]);
        let (prev, cur) = x.split_at_mut(i * nv);
        let prev = &prev[(i - s) * nv..(i - s) * nv + active];
        for (c, pr) in cur[..active].iter_mut().zip(prev) {
            *c = (*c - ci * pr) * ui;
        }
    });
    for_cells(ax, (0..len - 1).rev(), |i| {
        let li = f.l[i + s];
        let (cur, next) = x.split_at_mut((i + s) * nv);
        let cur = &mut cur[i * nv..i * nv + active];
        for (c, nx) in cur.iter_mut().zip(&next[..active]) {
            *c -= li * nx;
        }
    });
}

/// Solves M x = r in place for every line of an axis (Thomas algorithm on stored LU factors).
fn solve(ax: Axis, f: &AxisFactor, x: &mut [f64]) {
    let len = ax.len;
    for r in ax.blocks() {
        let (x, l, uinv, c) = (&mut x[r.clone()], &f.l[r.clone()], &f.uinv[r.clone()], &f.c[r]);
        if ax.stride == 1 {
            for i in 1..len {
                x[i] -= l[i] * x[i - 1];
            }
            x[len - 1] *= uinv[len - 1];
            for i in (0..len - 1).rev() {
                x[i] = (x[i] - c[i] * x[i + 1]) * uinv[i];
            }
        } else {
            solve_lockstep(ax.stride, len, x, (l, uinv, c));
        }
    }
}

/// [`solve`] on one block of `s` strided lines of `len` cells, in lockstep (the inner loop
/// contiguous); x and the factors (l, uinv, c) are the block's.
fn solve_lockstep(s: usize, len: usize, x: &mut [f64], (l, uinv, c): (&[f64], &[f64], &[f64])) {
    for p in 1..len {
        let (prev, cur) = x[(p - 1) * s..].split_at_mut(s);
        let l = &l[p * s..(p + 1) * s];
        for q in 0..s {
            cur[q] -= l[q] * prev[q];
        }
    }
    let last = (len - 1) * s;
    for q in 0..s {
        x[last + q] *= uinv[last + q];
    }
    for p in (0..len - 1).rev() {
        let (cur, next) = x[p * s..].split_at_mut(s);
        let (c, uinv) = (&c[p * s..(p + 1) * s], &uinv[p * s..(p + 1) * s]);
        for q in 0..s {
            cur[q] = (cur[q] - c[q] * next[q]) * uinv[q];
        }
    }
}

/// Solves Mᵀ x = r in place (Mᵀ = Uᵀ Lᵀ) for every line of an axis.
fn solve_transposed(ax: Axis, f: &AxisFactor, x: &mut [f64]) {
    let len = ax.len;
    for r in ax.blocks() {
        let (x, l, uinv, c) = (&mut x[r.clone()], &f.l[r.clone()], &f.uinv[r.clone()], &f.c[r]);
        if ax.stride == 1 {
            x[0] *= uinv[0];
            for i in 1..len {
                x[i] = (x[i] - c[i - 1] * x[i - 1]) * uinv[i];
            }
            for i in (0..len - 1).rev() {
                x[i] -= l[i + 1] * x[i + 1];
            }
        } else {
            solve_transposed_lockstep(ax.stride, len, x, (l, uinv, c));
        }
    }
}

/// [`solve_transposed`] on one block of `s` strided lines, in lockstep.
fn solve_transposed_lockstep(s: usize, len: usize, x: &mut [f64], (l, uinv, c): (&[f64], &[f64], &[f64])) {
    x[..s].iter_mut().zip(&uinv[..s]).for_each(|(v, u)| *v *= u);
    for p in 1..len {
        let (prev, cur) = x[(p - 1) * s..].split_at_mut(s);
        let (c, uinv) = (&c[(p - 1) * s..p * s], &uinv[p * s..(p + 1) * s]);
        for q in 0..s {
            cur[q] = (cur[q] - c[q] * prev[q]) * uinv[q];
        }
    }
    for p in (0..len - 1).rev() {
        let (cur, next) = x[p * s..].split_at_mut(s);
        let l = &l[(p + 1) * s..(p + 2) * s];
        for q in 0..s {
            cur[q] -= l[q] * next[q];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::action::grid::GridSpec;
    use crate::model::library::{DoubleWell, Duffing, Lorenz63, Lorenz96, Ou, VanDerPol};
    use crate::model::{Dims, Scalar};
    use approx::assert_relative_eq;
    use onsager_closures::dot;

    #[test]
    fn bernoulli_matches_closed_form() {
        // B(w) − B(−w) = −w for every w (the identity that makes constant density flux f ρ).
        for w in [-800.0, -30.0, -1.0, -1e-7, 0.0, 1e-7, 0.5, 30.0, 800.0] {
            assert_relative_eq!(bernoulli(w) - bernoulli(-w), -w, epsilon = 1e-12, max_relative = 1e-12);
        }
        assert_relative_eq!(bernoulli(1.0), 1.0 / (std::f64::consts::E - 1.0), max_relative = 1e-15);
    }

    #[test]
    fn steps_conserve_mass_positivity_and_pairing() {
        // 1-D double well, 2-D Van der Pol, the (non-autonomous, partly clean) Duffing and 3-D
        // Lorenz-63:
        // 1ᵀ m and ⟨a, m⟩ are invariants of the discrete scheme (exact adjoint).
        let dw = Grid::try_new(GridSpec::new_1d(-2.5, 2.5, 37)).unwrap();
        let vdp = Grid::try_new(GridSpec::new_2d([-3.0, -4.0], [3.0, 4.0], [13, 11])).unwrap();
        let duf = Grid::try_new(GridSpec::new_2d([-2.0, -2.0], [2.0, 2.0], [9, 12])).unwrap();
        fn check<S: Sde>(sde: &S, theta: &[f64], grid: &Grid, autonomous: bool) {
            let mut fp = FokkerPlanck::try_new(sde, theta, grid, &[0.0, 0.7, 3.1]).unwrap();
            assert_eq!(fp.is_autonomous(), autonomous);
            fp.prepare(&[0.05]);
            let n = grid.len();
            let mut m: Vec<f64> = (0..n).map(|i| 1.0 + ((i * 7) % 5) as f64).collect();
            let total: f64 = m.iter().sum();
            m.iter_mut().for_each(|v| *v /= total);
            let a0: Vec<f64> = (0..n).map(|i| ((i * 3) % 4) as f64 - 1.0).collect();
            let mut ms = vec![m.clone()];
            // Rough initial data: the first step damped, as after a jump.
            let kind = |k: usize| if k == 1 { StepKind::Damped } else { StepKind::Smooth };
            for k in 1..=20 {
                fp.step(0.05 * k as f64, 0.05, kind(k), &mut m);
                // The damped step is positive; the second-order one only approximately on such
                // rough data (no second-order linear scheme is positive for every step size).
                let negative: f64 = m.iter().map(|&v| (-v).max(0.0)).sum();
                assert!(if k == 1 { negative == 0.0 } else { negative < 1e-2 }, "step {k}: {negative}");
                assert_relative_eq!(m.iter().sum::<f64>(), 1.0, epsilon = 1e-13);
                ms.push(m.clone());
            }
            let mut a = a0.clone();
            let pair_end = dot(&a, &ms[20]);
            for k in (0..20).rev() {
                fp.step_adjoint(0.05 * (k + 1) as f64, 0.05, kind(k + 1), &mut a);
                assert_relative_eq!(dot(&a, &ms[k]), pair_end, epsilon = 1e-13);
            }
            // Generator columns sum to zero.
            let lm = fp.apply_generator(0.3, &ms[3]);
            assert!(lm.iter().sum::<f64>().abs() < 1e-12);
        }
        check(&DoubleWell, &[0.5], &dw, true);
        check(&Ou, &[1.0, 0.5], &dw, true);
        check(&VanDerPol, &[2.0, 0.3], &vdp, true);
        check(&Duffing, &Duffing::NOMINAL, &duf, false);
        check(&Lorenz63, &Lorenz63::NOMINAL, &lorenz_grid(), true);
    }

    /// A 3-D grid for Lorenz-63 with unequal axes (7, 6, 5 cells).
    fn lorenz_grid() -> Grid {
        Grid::try_new(GridSpec::parse("lo=-20;-25;0,hi=20;25;50,cells=7;6;5").unwrap()).unwrap()
    }

    #[test]
    fn implicit_euler_steps_are_positive_and_damped_substeps() {
        // Identity: with TimeScheme::ImplicitEuler eight steps of dt/8 are the TR-BDF2 damped step
        // of dt (Lie splitting in 2-D); every step keeps positivity, mass and the pairing; the
        // solve counts are one per axis (implicit Euler), two per axis sub-step (two-stage step,
        // Strang: three sub-steps in 2-D, five in 3-D) and eight per axis (damped step).
        let dw = Grid::try_new(GridSpec::new_1d(-2.5, 2.5, 37)).unwrap();
        let vdp = Grid::try_new(GridSpec::new_2d([-3.0, -4.0], [3.0, 4.0], [13, 11])).unwrap();
        fn check<S: Sde>(sde: &S, theta: &[f64], grid: &Grid) {
            let dim = grid.dim();
            let mut ie = FokkerPlanck::try_new(sde, theta, grid, &[0.0, 0.7]).unwrap();
            ie = ie.with_scheme(TimeScheme::ImplicitEuler);
            ie.prepare(&[0.01]);
            let mut tr = FokkerPlanck::try_new(sde, theta, grid, &[0.0, 0.7]).unwrap();
            tr.prepare(&[0.08]);
            let n = grid.len();
            let mut m: Vec<f64> = (0..n).map(|i| 1.0 + ((i * 7) % 5) as f64).collect();
            let total: f64 = m.iter().sum();
            m.iter_mut().for_each(|v| *v /= total);
            let mut m_tr = m.clone();
            tr.step(0.08, 0.08, StepKind::Damped, &mut m_tr);
            assert_eq!(tr.solves(), 8 * dim);
            tr.step(0.16, 0.08, StepKind::Smooth, &mut m_tr.clone());
            assert_eq!(tr.solves(), 8 * dim + 2 * (2 * dim - 1));
            let mut ms = vec![m.clone()];
            for k in 1..=8 {
                ie.step(0.01 * k as f64, 0.01, StepKind::Smooth, &mut m);
                assert!(m.iter().all(|&v| v > 0.0), "step {k}");
                assert_relative_eq!(m.iter().sum::<f64>(), 1.0, epsilon = 1e-13);
                ms.push(m.clone());
            }
            assert_eq!(ie.solves(), 8 * dim);
            for (x, y) in m.iter().zip(&m_tr) {
                assert_relative_eq!(x, y, epsilon = 1e-15, max_relative = 1e-12);
            }
            let mut a: Vec<f64> = (0..n).map(|i| ((i * 3) % 4) as f64 - 1.0).collect();
            let pair_end = dot(&a, &ms[8]);
            for k in (0..8).rev() {
                ie.step_adjoint(0.01 * (k + 1) as f64, 0.01, StepKind::Smooth, &mut a);
                assert_relative_eq!(dot(&a, &ms[k]), pair_end, epsilon = 1e-13);
            }
        }
        check(&DoubleWell, &[0.5], &dw);
        check(&VanDerPol, &[2.0, 0.3], &vdp);
        check(&Lorenz63, &Lorenz63::NOMINAL, &lorenz_grid());
    }

    #[test]
    fn a_3d_step_is_the_dense_strang_product_of_its_axes() {
        // Independent reference: the generator of each axis assembled as a dense matrix from the
        // cells' multi-indices and the drift at each face (Chang–Cooper rates, module doc), then
        // the step as dense algebra: S₀(h/2) S₁(h/2) S₂(h) S₁(h/2) S₀(h/2) with
        // S_a(τ) = (a M⁻¹ − (a − 1)) M⁻¹, M = I − gτL_a, and the damped step as eight rounds of
        // (I − h/8 L_a)⁻¹ over the axes; the adjoint steps as the transposes. Lorenz-63's rates
        // differ from line to line, so a solve that read another line's factors would show.
        let grid = lorenz_grid();
        let theta = Lorenz63::NOMINAL;
        let (n, h, dt) = (grid.len(), grid.widths().to_vec(), 0.01);
        let mut fp = FokkerPlanck::try_new(&Lorenz63, &theta, &grid, &[0.0]).unwrap();
        fp.prepare(&[dt]);
        let g = Lorenz63.diffusion_matrix(&theta).unwrap();
        let generators: Vec<nalgebra::DMatrix<f64>> = (0..3)
            .map(|a| {
                let d = 0.5 * (g[(a, a)] * g[(a, a)]);
                let stride: usize = grid.cells()[..a].iter().product();
                let mut l = nalgebra::DMatrix::zeros(n, n);
                let (mut s, mut f) = ([0.0; 3], [0.0; 3]);
                for c in (0..n).filter(|&c| grid.index_on(a, c) + 1 < grid.cells()[a]) {
                    grid.coords(c, &mut s);
                    s[a] += 0.5 * h[a];
                    Lorenz63.drift(0.0, &s, &[], &theta, &mut f);
                    let w = f[a] * h[a] / d;
                    let (ra, rb) = (d / (h[a] * h[a]) * bernoulli(-w), d / (h[a] * h[a]) * bernoulli(w));
                    let j = c + stride;
                    l[(c, c)] -= ra;
                    l[(j, c)] += ra;
                    l[(c, j)] += rb;
                    l[(j, j)] -= rb;
                }
                l
            })
            .collect();
        let eye = nalgebra::DMatrix::<f64>::identity(n, n);
        let inverse = |m: nalgebra::DMatrix<f64>| m.try_inverse().unwrap();
        let two_stage = |a: usize, tau: f64| {
            let minv = inverse(&eye - &generators[a] * (STAGE * tau));
            (&minv * OUTER - &eye * (OUTER - 1.0)) * &minv
        };
        let mut smooth = eye.clone();
        for (a, tau) in [(0, 0.5 * dt), (1, 0.5 * dt), (2, dt), (1, 0.5 * dt), (0, 0.5 * dt)] {
            smooth = two_stage(a, tau) * smooth;
        }
        let mut damped = eye.clone();
        for a in (0..8).flat_map(|_| 0..3) {
            damped = inverse(&eye - &generators[a] * (dt / 8.0)) * damped;
        }
        let m0 = nalgebra::DVector::from_fn(n, |i, _| 1.0 + ((i * 7) % 5) as f64);
        for (kind, dense) in [(StepKind::Smooth, smooth), (StepKind::Damped, damped)] {
            let (mut m, mut a) = (m0.as_slice().to_vec(), m0.as_slice().to_vec());
            fp.step(dt, dt, kind, &mut m);
            fp.step_adjoint(dt, dt, kind, &mut a);
            let (want_m, want_a) = (&dense * &m0, dense.transpose() * &m0);
            for (x, y) in m.iter().zip(want_m.iter()).chain(a.iter().zip(want_a.iter())) {
                assert_relative_eq!(*x, *y, epsilon = 1e-11, max_relative = 1e-9);
            }
        }
    }

    /// Independent double wells, one per state: state k is well w = `self.0[k]`, with
    /// dX = (X − X³ + 0.3 w) dt + (0.6 + 0.2 w) dW (a drift and diffusion separate per axis).
    struct Wells(&'static [usize]);

    const WELLS: [usize; 3] = [0, 1, 2];

    impl Sde for Wells {
        fn dims(&self) -> Dims {
            Dims { noisy: self.0.len(), clean: 0, params: 0 }
        }

        fn noisy_names(&self) -> Vec<String> {
            self.0.iter().map(|w| format!("x{w}")).collect()
        }

        fn param_names(&self) -> Vec<String> {
            Vec::new()
        }

        fn drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _theta: &[D], out: &mut [D]) {
            for (k, &w) in self.0.iter().enumerate() {
                out[k] = x[k] - x[k] * x[k] * x[k] + D::from(0.3 * w as f64);
            }
        }

        fn diffusion<D: Scalar>(&self, _theta: &[D], out: &mut [D]) {
            let n = self.0.len();
            for (i, o) in out.iter_mut().enumerate() {
                *o = if i % (n + 1) == 0 { D::from(0.6 + 0.2 * self.0[i / n] as f64) } else { D::from(0.0) };
            }
        }
    }

    #[test]
    fn a_separable_3d_step_is_the_product_of_its_axes_steps() {
        // Identity: with a drift and diffusion separate per axis the axes' operators commute, so
        // a 3-D step of a product density is the product of 1-D steps, Strang
        // S₀(h/2) S₁(h/2) S₂(h) S₁(h/2) S₀(h/2) giving S₀(h/2)² ⊗ S₁(h/2)² ⊗ S₂(h), and the
        // damped step each axis's eight implicit Euler sub-steps; likewise the adjoint steps.
        // Unequal axes (5, 6, 7 cells) check the strides and blocks of the 3-D layout.
        let (lo, hi, cells) = ([-2.0, -1.5, -2.5], [2.0, 2.5, 1.5], [5usize, 6, 7]);
        let spec = GridSpec { lo: lo.to_vec(), hi: hi.to_vec(), cells: cells.to_vec() };
        let grid = Grid::try_new(spec).unwrap();
        let dt = 0.1;
        let mut fp = FokkerPlanck::try_new(&Wells(&WELLS), &[], &grid, &[0.0]).unwrap();
        fp.prepare(&[dt]);
        let factors: Vec<Vec<f64>> =
            (0..3).map(|a| (0..cells[a]).map(|i| 1.0 + ((i * (a + 2)) % 5) as f64).collect()).collect();
        let product = |f: &[Vec<f64>]| -> Vec<f64> {
            (0..grid.len()).map(|c| (0..3).map(|a| f[a][grid.index_on(a, c)]).product()).collect()
        };
        for kind in [StepKind::Smooth, StepKind::Damped] {
            for adjoint in [false, true] {
                let axes: Vec<Vec<f64>> = (0..3)
                    .map(|a| {
                        let line = Grid::try_new(GridSpec::new_1d(lo[a], hi[a], cells[a])).unwrap();
                        let well = Wells(&WELLS[a..=a]);
                        let mut fp1 = FokkerPlanck::try_new(&well, &[], &line, &[0.0]).unwrap();
                        fp1.prepare(&[0.5 * dt, dt]);
                        let halves = a < 2 && kind == StepKind::Smooth;
                        let steps: &[f64] = if halves { &[0.5 * dt, 0.5 * dt] } else { &[dt] };
                        let mut m = factors[a].clone();
                        for &h in steps {
                            if adjoint {
                                fp1.step_adjoint(h, h, kind, &mut m);
                            } else {
                                fp1.step(h, h, kind, &mut m);
                            }
                        }
                        m
                    })
                    .collect();
                let mut m = product(&factors);
                if adjoint {
                    fp.step_adjoint(dt, dt, kind, &mut m);
                } else {
                    fp.step(dt, dt, kind, &mut m);
                }
                for (x, y) in m.iter().zip(product(&axes)) {
                    assert_relative_eq!(*x, y, epsilon = 1e-13, max_relative = 1e-12);
                }
            }
        }
    }

    #[test]
    fn batched_steps_equal_single_steps() {
        // The lockstep (interleaved) solves used by the tangent sweeps give the same result as
        // one vector at a time, in 1-D and along every axis of a 2-D and a 3-D grid (identity,
        // rounding only).
        for grid in [
            Grid::try_new(GridSpec::new_1d(-2.0, 2.0, 17)).unwrap(),
            Grid::try_new(GridSpec::new_2d([-3.0, -4.0], [3.0, 4.0], [7, 9])).unwrap(),
            lorenz_grid(),
        ] {
            let theta: &[f64] = [&[0.5][..], &[2.0, 0.4], &Lorenz63::NOMINAL][grid.dim() - 1];
            let run = |batch: bool| -> Vec<f64> {
                let (nv, active) = (4, 3);
                let n = grid.len();
                let mut x: Vec<f64> = (0..n * nv).map(|i| ((i * 13) % 7) as f64 * 0.1).collect();
                if grid.dim() == 1 {
                    let mut fp = FokkerPlanck::try_new(&DoubleWell, theta, &grid, &[0.0]).unwrap();
                    fp.prepare(&[0.1]);
                    step_all(&fp, &mut x, nv, active, batch);
                } else if grid.dim() == 3 {
                    let mut fp = FokkerPlanck::try_new(&Lorenz63, theta, &grid, &[0.0]).unwrap();
                    fp.prepare(&[0.1]);
                    step_all(&fp, &mut x, nv, active, batch);
                } else {
                    let mut fp = FokkerPlanck::try_new(&VanDerPol, theta, &grid, &[0.0]).unwrap();
                    fp.prepare(&[0.1]);
                    step_all(&fp, &mut x, nv, active, batch);
                }
                x
            };
            let (a, b) = (run(true), run(false));
            for (x, y) in a.iter().zip(&b) {
                assert_relative_eq!(x, y, epsilon = 1e-14, max_relative = 1e-13);
            }
        }
    }

    fn step_all<S: Sde>(fp: &FokkerPlanck<'_, S>, x: &mut [f64], nv: usize, active: usize, batch: bool) {
        let n = x.len() / nv;
        if batch {
            for kind in [StepKind::Damped, StepKind::Smooth] {
                fp.step_batch(0.1, 0.1, kind, x, nv, active);
                fp.step_adjoint_batch(0.1, 0.1, kind, x, nv, active);
            }
        } else {
            for v in 0..active {
                let mut col: Vec<f64> = (0..n).map(|i| x[i * nv + v]).collect();
                for kind in [StepKind::Damped, StepKind::Smooth] {
                    fp.step(0.1, 0.1, kind, &mut col);
                    fp.step_adjoint(0.1, 0.1, kind, &mut col);
                }
                (0..n).for_each(|i| x[i * nv + v] = col[i]);
            }
        }
    }

    #[test]
    fn stationary_density_of_gradient_flow() {
        // For f = −V′ the Chang–Cooper scheme has the exact discrete equilibrium m_i ∝ e^{−V(x_i)/D}
        // when the face drift is the difference quotient of V; with f at the face it is second-order
        // accurate: compare the double-well stationary mean of x² after a long run.
        let grid = Grid::try_new(GridSpec::new_1d(-2.5, 2.5, 400)).unwrap();
        let mut fp = FokkerPlanck::try_new(&DoubleWell, &[0.5], &grid, &[0.0]).unwrap();
        fp.prepare(&[0.5]);
        let n = grid.len();
        let mut m = vec![1.0 / n as f64; n];
        for k in 0..400 {
            fp.step(0.5 * k as f64, 0.5, StepKind::Smooth, &mut m);
        }
        // Reference: ∫x² e^{−(x⁴−2x²)/D} / ∫ e^{−(x⁴−2x²)/D} by a fine midpoint rule.
        let (mut num, mut den) = (0.0, 0.0);
        for i in 0..200_000 {
            let x = -2.5 + (i as f64 + 0.5) * 5.0 / 200_000.0;
            let w = (-(x.powi(4) - 2.0 * x * x) / 0.5).exp();
            num += x * x * w;
            den += w;
        }
        let x2: f64 = grid.centers(0).iter().zip(&m).map(|(x, p)| x * x * p).sum();
        assert_relative_eq!(x2, num / den, max_relative = 1e-3);
    }

    #[test]
    fn rejects_more_than_three_noisy_states() {
        let grid = Grid::try_new(GridSpec::new_1d(-1.0, 1.0, 5)).unwrap();
        let err =
            FokkerPlanck::try_new(&Lorenz96::new(4).unwrap(), &Lorenz96::NOMINAL, &grid, &[0.0]).unwrap_err();
        assert!(err.to_string().contains("1 to 3 noisy states"), "{err}");
    }
}
