//! The exponential-family closure drift on the fixed nodes of an [`Exponential`] family
//! ([`ExponentialDrift`]).

use onsager_closures::{
    cholesky_into, cholesky_solve_rows_in_place, dot, frame_grid, Exponential, TrialFamily,
};

use super::{diffusion_matrix, unrealizable, ClosureDrift, FamilyMoments, Unrealizable, EDGE_BAND};
use onsager_closures::LegendreOptions;
use serde::{Deserialize, Serialize};

use super::gaussian_prior;
use super::tensor::{mirror_lower, monomial_count, solve_lower, NodeValues, Order, TensorPlan, TensorWork};
use crate::action::closure::{
    check_box_covers_data, default_domain, ClosureFamily, FamilySetup, Refinement, Widening,
};
use crate::action::exact::GridEdge;
use crate::estimate::{EstimationProblem, Method};
use crate::model::observation::StateMeasurement;
use crate::model::prior::Prior;
use crate::model::Sde;
use crate::{Error, Result};

/// An exponential-family closure on the fixed nodes of an [`Exponential`] family (1-D to 3-D,
/// the family's state = the model's full state). The generator averages
/// g_k = f(x_k)·∇M(x_k) + D:∇∇M(x_k) (`003_d2fc48a470e528fc.txt (II.3)`) are formed at the
/// nodes, with ∇M and ∇∇M computed once per node set; then V = Σπ_k g_k, W = C⁻¹V and
///
/// $$ \partial W/\partial\lambda = C^{-1}\sum_k \pi_k\,(g_k - (d_k\cdot W)\,d_k)\,d_k^\top,
///    \qquad d_k = M(x_k) - \mu , $$
///
/// from ∂V/∂λ = Σπ_k g_k d_kᵀ and ∂C_ab/∂λ_j = Σπ_k d_a d_b d_j (`(II.43)`).
///
/// The drift keeps the work buffers of one evaluation in a `RefCell`, so it is not `Sync`:
/// threads that evaluate closures in parallel (Monte Carlo replicates) each build their own.
pub struct ExponentialDrift<'a, S: Sde + ?Sized> {
    sde: &'a S,
    theta: Vec<f64>,
    diffusion: Vec<f64>,
    /// The nodes, the family on them and the node tables; replaced when nodes that follow the
    /// density move.
    nodes: std::cell::RefCell<Nodes>,
    /// How the nodes follow the density, if they do.
    follow: Option<DensityNodes>,
    /// Nodes that follow the density: those of the initial density, where every sweep starts.
    initial: Option<Nodes>,
    n_moments: usize,
    linear: Vec<Option<usize>>,
    square: Vec<Option<usize>>,
    /// The buffers of one evaluation, reused (the drift is evaluated at every Runge–Kutta stage).
    work: std::cell::RefCell<ExpWork>,
    /// The box the family is truncated to, per state, when it is known ([`ClosureDrift::support`]).
    support: Option<Vec<(f64, f64)>>,
}

/// ∂M_a/∂x_i at row a·n + i and D : ∇∇M_a at row a, one row of node values each.
type DerivativeTables = (Vec<f64>, Vec<f64>);

/// The mean and covariance (row-major) of the moments.
type MeanAndCovariance = (Vec<f64>, Vec<f64>);

/// The nodes of an [`ExponentialDrift`]: the family on them and its node tables. The hot loops
/// run over the nodes with one contiguous row per moment ("moment-major"): M_a(x_k) at row a is
/// the family's [`Exponential::moment_table_by_moment`], ∂M_a/∂x_i(x_k) at row a·dim + i of
/// the first of `tables`, and D : ∇∇M_a(x_k) at row a of the second.
#[derive(Clone)]
struct Nodes {
    family: Exponential,
    /// ∂M_a/∂x_i and D : ∇∇M_a at the nodes ([`derivative_tables`]): for the node sums.
    tables: std::cell::OnceCell<std::result::Result<DerivativeTables, Unrealizable>>,
    /// The frame x = m + Lξ of nodes that follow the density; `None` for a fixed box.
    frame: Option<Frame>,
    /// The raw-moment sums of a tensor grid ([`TensorPlan`]: a fixed box, or a frame of nodes
    /// that follow the density), where they apply.
    tensor: Option<TensorPlan>,
    /// The model's drift at every node, state-major, for a model whose drift does not read t
    /// ([`Sde::drift_is_autonomous`]): evaluated at the first evaluation of the raw moment sums
    /// on these nodes, then reused.
    drift: std::cell::OnceCell<Vec<f64>>,
}

/// A frame of nodes that follow the density: centre m, lower-triangular L (row-major), the
/// half-width c of the box in ξ and, per node, whether it lies on the box's boundary (its
/// outermost points on some axis).
#[derive(Debug, Clone)]
struct Frame {
    mean: Vec<f64>,
    chol: Vec<f64>,
    width: f64,
    panels: usize,
    edge: Vec<bool>,
    /// log w_k of the nodes (filled by [`Nodes::try_new`]).
    log_weights: Vec<f64>,
}

/// Nodes that follow the density (`nodes = density`): a tensor grid of `panels` × 8
/// Gauss–Legendre points per axis on ±`width` standard deviations of a frame m + Lξ
/// ([`onsager_closures::frame_grid`]), refined to `tolerance`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct DensityNodes {
    pub(crate) degree: u32,
    pub(crate) panels: usize,
    pub(crate) width: f64,
    pub(crate) tolerance: f64,
}

/// Gauss–Legendre points per panel of the node grids.
const POINTS_PER_PANEL: usize = 8;
/// The most panels per axis the refinement of nodes that follow the density may reach.
const MAX_DENSITY_PANELS: usize = 32;
/// The most nodes the refinement of nodes that follow the density may reach: in 3-D, 12 panels
/// per axis (96³ = 884,736 nodes, about 0.5 GB of tables for the quartic family).
const MAX_DENSITY_NODES: usize = 1 << 20;

/// The most panels per axis of nodes that follow the density in `n` dimensions: within
/// [`MAX_DENSITY_PANELS`] and [`MAX_DENSITY_NODES`].
fn max_density_panels(n: usize) -> usize {
    let per_axis = (MAX_DENSITY_NODES as f64).powf(1.0 / n as f64).floor() as usize;
    MAX_DENSITY_PANELS.min(per_axis / POINTS_PER_PANEL)
}
/// The widest box, in standard deviations of the frame, the nodes may widen to.
const MAX_DENSITY_WIDTH: f64 = 24.0;
/// The frame is moved when the density's mean has moved this many frame standard deviations,
/// or its covariance in frame coordinates differs from I by this much in some entry.
const FRAME_DRIFT: f64 = 0.5;

impl<S: Sde + ?Sized> std::fmt::Debug for ExponentialDrift<'_, S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ExponentialDrift")
            .field("family", &self.nodes.borrow().family)
            .field("follow", &self.follow)
            .finish()
    }
}

impl<'a, S: Sde + ?Sized> ExponentialDrift<'a, S> {
    /// The closure of `sde` at θ with `family` (whose dimension must be the model's number of
    /// states and whose moment functions must have derivatives). Errors:
    /// [`Error::InvalidOption`] for a dimension mismatch or missing derivatives; a singular G.
    pub fn try_new(sde: &'a S, theta: &[f64], family: Exponential) -> Result<Self> {
        Self::with_nodes(sde, theta, family, None, None)
    }

    /// The closure of `sde` at θ with nodes that follow the density: `family` must be on the
    /// [`frame_grid`] of `frame` = (m, L) with `follow`'s width and panels (as built by
    /// [`density_family`]). Errors: those of [`ExponentialDrift::try_new`].
    pub(crate) fn following(
        sde: &'a S,
        theta: &[f64],
        family: Exponential,
        frame: (Vec<f64>, Vec<f64>),
        follow: DensityNodes,
    ) -> Result<Self> {
        Self::with_nodes(sde, theta, family, Some(frame), Some(follow))
    }

    fn with_nodes(
        sde: &'a S,
        theta: &[f64],
        family: Exponential,
        frame: Option<(Vec<f64>, Vec<f64>)>,
        follow: Option<DensityNodes>,
    ) -> Result<Self> {
        let n = sde.dims().states();
        if family.dim() != n {
            return Err(Error::InvalidOption {
                name: "method".into(),
                reason: format!(
                    "the exponential family has dimension {} but the model has {n} states",
                    family.dim()
                ),
            });
        }
        let diffusion = diffusion_matrix(sde, theta)?;
        let r = family.n_moments();
        // Find x_i and x_i² among the moments numerically on the nodes.
        let grid = family.grid();
        let table = family.moment_table();
        let find = |g: &dyn Fn(&[f64]) -> f64| -> Option<usize> {
            (0..r).find(|&a| {
                grid.iter().enumerate().all(|(k, (x, _))| {
                    let v = g(x);
                    (table[k * r + a] - v).abs() <= 1e-12 * (1.0 + v.abs())
                })
            })
        };
        let linear = (0..n).map(|i| find(&|x: &[f64]| x[i])).collect();
        let square = (0..n).map(|i| find(&|x: &[f64]| x[i] * x[i])).collect();
        let frame = match (frame, follow) {
            (Some((mean, chol)), Some(f)) => Some(Frame::new(mean, chol, f.width, f.panels, n)),
            _ => None,
        };
        let nodes = Nodes::try_new(family, &diffusion, frame).map_err(|e| Error::InvalidOption {
            name: "method".into(),
            reason: format!("exponential closure: {}", e.0),
        })?;
        Ok(ExponentialDrift {
            sde,
            theta: theta.to_vec(),
            diffusion,
            initial: follow.map(|_| nodes.clone()),
            nodes: std::cell::RefCell::new(nodes),
            follow,
            n_moments: r,
            linear,
            square,
            work: Default::default(),
            support: None,
        })
    }

    /// The same closure, recording that its family is truncated to the box `domain` (one
    /// interval per state), for [`ClosureDrift::support`].
    pub fn on_box(mut self, domain: Vec<(f64, f64)>) -> Self {
        self.support = Some(domain);
        self
    }

    /// The family on the current nodes (for nodes that follow the density, those of the last
    /// evaluation).
    pub fn family(&self) -> Exponential {
        self.nodes.borrow().family.clone()
    }

    /// The diffusion D = ½GGᵀ of the full state (row-major).
    pub fn diffusion(&self) -> &[f64] {
        &self.diffusion
    }
}

impl Frame {
    /// The frame (m, L) with box half-width `width` and `panels` per axis in `n` dimensions;
    /// the node order is that of [`frame_grid`] (the last axis fastest).
    fn new(mean: Vec<f64>, chol: Vec<f64>, width: f64, panels: usize, n: usize) -> Frame {
        let per_axis = panels * POINTS_PER_PANEL;
        let total = per_axis.pow(n as u32);
        let edge = (0..total)
            .map(|mut k| {
                (0..n).any(|_| {
                    let i = k % per_axis;
                    k /= per_axis;
                    i == 0 || i + 1 == per_axis
                })
            })
            .collect();
        Frame { mean, chol, width, panels, edge, log_weights: Vec::new() }
    }

    /// Whether a density of mean `mean` and covariance `cov` has left the frame: its mean
    /// more than [`FRAME_DRIFT`] frame standard deviations from the centre, or its covariance
    /// in frame coordinates, L⁻¹ cov L⁻ᵀ, more than that from I in some entry.
    fn moved(&self, mean: &[f64], cov: &[f64]) -> bool {
        let n = mean.len();
        let mut z: Vec<f64> = mean.iter().zip(&self.mean).map(|(a, b)| a - b).collect();
        solve_lower(&self.chol, n, &mut z);
        if z.iter().any(|v| v.abs() > FRAME_DRIFT) {
            return true;
        }
        // B = L⁻¹ cov (column by column, row-major), then column j of S = L⁻¹ cov L⁻ᵀ is
        // L⁻¹ times row j of B.
        let mut b = vec![0.0; n * n];
        let mut col = vec![0.0; n];
        for j in 0..n {
            (0..n).for_each(|i| col[i] = cov[i * n + j]);
            solve_lower(&self.chol, n, &mut col);
            (0..n).for_each(|i| b[i * n + j] = col[i]);
        }
        for j in 0..n {
            col.copy_from_slice(&b[j * n..(j + 1) * n]);
            solve_lower(&self.chol, n, &mut col);
            for (i, &v) in col.iter().enumerate() {
                let identity = if i == j { 1.0 } else { 0.0 };
                if (v - identity).abs() > FRAME_DRIFT || !v.is_finite() {
                    return true;
                }
            }
        }
        false
    }
}

/// The mean and covariance (row-major) of the state under node probabilities `p` at `points`.
fn state_moments(points: &[f64], p: &[f64], n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut mean = vec![0.0; n];
    for (x, &pk) in points.chunks_exact(n).zip(p) {
        mean.iter_mut().zip(x).for_each(|(m, &v)| *m += pk * v);
    }
    let mut cov = vec![0.0; n * n];
    for (x, &pk) in points.chunks_exact(n).zip(p) {
        for i in 0..n {
            for j in 0..=i {
                cov[i * n + j] += pk * (x[i] - mean[i]) * (x[j] - mean[j]);
            }
        }
    }
    mirror_lower(&mut cov, n);
    (mean, cov)
}

/// The polynomial family of total degree `degree` on the [`frame_grid`] of (m, L) with
/// `panels` × 8 Gauss–Legendre points per axis on ±`width`.
pub(crate) fn density_family(
    mean: &[f64],
    chol: &[f64],
    width: f64,
    panels: usize,
    degree: u32,
) -> std::result::Result<Exponential, onsager_closures::Error> {
    let grid = frame_grid(mean, chol, width, panels, POINTS_PER_PANEL)?;
    Exponential::polynomial(grid, onsager_closures::Reference::Lebesgue, degree)
}

impl Nodes {
    /// The nodes of `family` for the diffusion D (row-major n × n): their tensor plan where
    /// there is one, else their derivative tables ([`derivative_tables`], needed only by the
    /// node sums).
    fn try_new(
        family: Exponential,
        diffusion: &[f64],
        frame: Option<Frame>,
    ) -> std::result::Result<Nodes, Unrealizable> {
        let nodes = family.grid().len();
        if frame.as_ref().is_some_and(|f| f.edge.len() != nodes) {
            return Err(Unrealizable("the frame and the family have different nodes".into()));
        }
        let tensor = match &frame {
            None => TensorPlan::of(&family),
            Some(f) => {
                let axis = onsager_closures::quadrature::composite_gauss_legendre(
                    -f.width,
                    f.width,
                    f.panels,
                    POINTS_PER_PANEL,
                )
                .map_err(unrealizable)?;
                family
                    .exponents()
                    .and_then(|e| TensorPlan::in_frame(e, axis.points(), &f.mean, &f.chol))
                    .filter(|plan| plan.len() == nodes)
            }
        };
        let tables = std::cell::OnceCell::new();
        if tensor.is_none() {
            tables.get_or_init(|| derivative_tables(&family, diffusion)).as_ref().map_err(Clone::clone)?;
        }
        let frame = frame
            .map(|f| Frame { log_weights: family.grid().weights().iter().map(|w| w.ln()).collect(), ..f });
        Ok(Nodes { family, tables, frame, tensor, drift: Default::default() })
    }

    /// The derivative tables of [`derivative_tables`], computed at the first call.
    fn tables(&self, diffusion: &[f64]) -> std::result::Result<&DerivativeTables, Unrealizable> {
        self.tables.get_or_init(|| derivative_tables(&self.family, diffusion)).as_ref().map_err(Clone::clone)
    }
}

/// ∂M_a/∂x_i at row a·n + i and D : ∇∇M_a at row a of the nodes of `family` (moment-major, one
/// row of node values each), for the diffusion D (row-major n × n).
fn derivative_tables(
    family: &Exponential,
    diffusion: &[f64],
) -> std::result::Result<DerivativeTables, Unrealizable> {
    let n = family.dim();
    let r = family.n_moments();
    let nodes = family.grid().len();
    let mut jac = vec![0.0; nodes * r * n];
    let mut second = vec![0.0; nodes * r];
    let mut h = vec![0.0; r * n * n];
    for (k, (x, _)) in family.grid().iter().enumerate() {
        family.moment_derivatives(x, &mut jac[k * r * n..(k + 1) * r * n], &mut h).map_err(unrealizable)?;
        for a in 0..r {
            second[k * r + a] = (0..n * n).map(|ij| diffusion[ij] * h[a * n * n + ij]).sum::<f64>();
        }
    }
    // Node-major → moment-major.
    let transpose = |m: &[f64], rows: usize| -> Vec<f64> {
        let mut out = vec![0.0; m.len()];
        for k in 0..nodes {
            for a in 0..rows {
                out[a * nodes + k] = m[k * rows + a];
            }
        }
        out
    };
    Ok((transpose(&jac, r * n), transpose(&second, r)))
}

impl<S: Sde + ?Sized> ExponentialDrift<'_, S> {
    /// Moves nodes that follow the density to the density at λ, if it has left their frame
    /// ([`Frame::moved`]: the new box has the `width` of the options) or reaches the box's
    /// boundary (its density there above `tolerance` times its peak: the box widens by half).
    /// The new frame is centred at the density's mean m with L the Cholesky factor of its
    /// covariance, both from the old nodes,
    /// and its panels are refined ([`ExponentialDrift::refined`]); then the test repeats on the
    /// new nodes, at most 8 times. Within a frame W, ∂W/∂λ and ∇²(κᵀW) are exact derivatives
    /// of one another; across a move they agree to the node rule's tolerance. Returns whether
    /// `work.s` and `work.p_all` now hold the exponents and the probabilities at λ on the nodes
    /// it leaves (true for nodes that follow the density; a fixed box computes nothing).
    fn follow_density(&self, lambda: &[f64], work: &mut ExpWork) -> std::result::Result<bool, Unrealizable> {
        let Some(opts) = self.follow else { return Ok(false) };
        let mut nodes = self.nodes.borrow_mut();
        let n = nodes.family.dim();
        for _ in 0..8 {
            let frame = nodes.frame.as_ref().ok_or_else(|| Unrealizable("no frame for the nodes".into()))?;
            let ExpWork { s, p_all, col, .. } = work;
            probabilities(&nodes, lambda, (col, s, p_all))?;
            let (mean, cov) = match &nodes.tensor {
                Some(plan) => plan.state_moments(p_all),
                None => state_moments(nodes.family.grid().points(), p_all, n),
            };
            // log p at the nodes = s_k − log w_k (Lebesgue reference).
            let (mut peak, mut edge) = (f64::NEG_INFINITY, f64::NEG_INFINITY);
            for ((&sk, &log_w), &e) in s.iter().zip(&frame.log_weights).zip(&frame.edge) {
                let v = sk - log_w;
                peak = peak.max(v);
                if e {
                    edge = edge.max(v);
                }
            }
            let cut = edge - peak > opts.tolerance.ln();
            let moved = frame.moved(&mean, &cov);
            if !cut && !moved {
                return Ok(true);
            }
            let width = if moved { opts.width } else { frame.width * 1.5 };
            if width > MAX_DENSITY_WIDTH {
                return Err(unbounded(
                    &nodes.family,
                    lambda,
                    format!("the density reaches the boundary of its nodes at ±{MAX_DENSITY_WIDTH} standard deviations"),
                ));
            }
            let chol = onsager_closures::cholesky(&cov, n)
                .map_err(|_| Unrealizable("the density's covariance is not positive definite".into()))?;
            let (family, panels) = self
                .refined(lambda, &mean, &chol, width, opts)
                .map_err(|Unrealizable(why)| unbounded(&nodes.family, lambda, why))?;
            *nodes = Nodes::try_new(family, &self.diffusion, Some(Frame::new(mean, chol, width, panels, n)))?;
        }
        Err(Unrealizable("the nodes that follow the density did not settle in 8 moves".into()))
    }

    /// The family on the frame (m, L, width) with the fewest panels P (from `opts.panels`,
    /// scaled with the width, doubling up to [`max_density_panels`]) whose moments agree with
    /// those on 2P panels (or the most allowed, if fewer) to
    /// `opts.tolerance` times their standard deviations: max_a |μ_a(P) − μ_a(2P)|/√C_aa. The
    /// moments on each candidate come from its tensor plan ([`frame_cumulants`]) where there is
    /// one, and only the family of the P chosen is built.
    fn refined(
        &self,
        lambda: &[f64],
        mean: &[f64],
        chol: &[f64],
        width: f64,
        opts: DensityNodes,
    ) -> std::result::Result<(Exponential, usize), Unrealizable> {
        let degree = opts.degree;
        let most = max_density_panels(mean.len());
        let mut panels = (((opts.panels as f64) * width / opts.width).ceil() as usize).min(most);
        let family = |p: usize| density_family(mean, chol, width, p, degree).map_err(unrealizable);
        let cumulants = |p: usize| match frame_cumulants(lambda, mean, chol, width, p, degree) {
            Some(done) => done,
            None => family(p)?.cumulants(lambda).map(|c| (c.mean, c.covariance)).map_err(unrealizable),
        };
        let (mut mu, mut cov) = cumulants(panels)?;
        while panels < most {
            let finer = (2 * panels).min(most);
            let (mu_fine, cov_fine) = cumulants(finer)?;
            let r = mu.len();
            let err = (0..r)
                .map(|a| (mu[a] - mu_fine[a]).abs() / cov[a * r + a].max(f64::MIN_POSITIVE).sqrt())
                .fold(0.0, f64::max);
            if err <= opts.tolerance {
                return Ok((family(panels)?, panels));
            }
            panels = finer;
            (mu, cov) = (mu_fine, cov_fine);
        }
        Err(Unrealizable(format!(
            "the nodes that follow the density do not reach the tolerance {} with {panels} panels per axis \
             ({} nodes, the most allowed; a larger `density_tolerance`, or `nodes = box`)",
            opts.tolerance,
            (panels * POINTS_PER_PANEL).pow(mean.len() as u32)
        )))
    }
}

/// The mean and covariance of M at λ for the polynomial family of total degree `degree` on the
/// [`frame_grid`] of (m, L) with `panels` × 8 points per axis on ±`width`, by its tensor plan
/// ([`TensorPlan::in_frame`]) without building the family; `None` where there is no plan.
fn frame_cumulants(
    lambda: &[f64],
    mean: &[f64],
    chol: &[f64],
    width: f64,
    panels: usize,
    degree: u32,
) -> Option<std::result::Result<MeanAndCovariance, Unrealizable>> {
    let exponents = onsager_closures::Polynomial::try_new(mean.len(), degree).ok()?;
    let axis =
        onsager_closures::quadrature::composite_gauss_legendre(-width, width, panels, POINTS_PER_PANEL)
            .ok()?;
    let plan = TensorPlan::in_frame(exponents.exponents(), axis.points(), mean, chol)?;
    if lambda.len() != plan.n_moments() || !lambda.iter().all(|v| v.is_finite()) {
        return None;
    }
    let (mut row, mut s) = (Vec::new(), Vec::new());
    plan.polynomial_into(lambda, &mut row, &mut s);
    if s.iter().any(|v| v.is_nan()) {
        return Some(Err(Unrealizable("the density's exponent is not a number on the frame's nodes".into())));
    }
    // log w_k = Σ_i log w_{k_i}, k_i the digits of k in base P (the factor det L is common to
    // all nodes).
    let log_w: Vec<f64> = axis.weights().iter().map(|w| w.ln()).collect();
    let per_axis = log_w.len();
    let n = mean.len();
    for (k, sk) in s.iter_mut().enumerate() {
        // The outer axis first.
        *sk += (0..n).rev().map(|i| log_w[k / per_axis.pow(i as u32) % per_axis]).sum::<f64>();
    }
    let mut p = vec![0.0; s.len()];
    if onsager_closures::normalize_log_weights(&s, &mut p).is_none() {
        return Some(Err(Unrealizable("the density has no mass on the frame's nodes".into())));
    }
    Some(Ok(plan.cumulants(&p, &mut TensorWork::default())))
}

/// `why` the nodes cannot hold the density at λ, with the reason no nodes can when its density
/// is not normalizable ([`top_form_max`] ≥ 0).
fn unbounded(family: &Exponential, lambda: &[f64], why: String) -> Unrealizable {
    match family.exponents().map(|e| top_form_max(e, lambda)) {
        Some(top) if top >= 0.0 => Unrealizable(format!(
            "{why}: the density is not normalizable (the highest-degree terms of λ·M reach {top:.3e} \
             ≥ 0 on the unit circle or sphere, so it grows without bound there); nodes that follow the density \
             need a normalizable one, the fixed box (`nodes = box`) truncates it to its domain"
        )),
        _ => Unrealizable(why),
    }
}

/// The largest value on the unit sphere of the highest-degree terms of λ·M, for the polynomial
/// family with `exponents` in one to three states (the terms of the highest degree with a
/// non-zero coefficient; 720 directions in 2-D, a Fibonacci lattice of 2000 in 3-D; NaN in
/// more states). exp(λ·M) is normalizable on Rⁿ when this is negative (an even degree with a
/// negative definite form).
fn top_form_max(exponents: &[Vec<u32>], lambda: &[f64]) -> f64 {
    let degree = |e: &Vec<u32>| e.iter().sum::<u32>();
    let Some(top) = exponents.iter().zip(lambda).filter(|(_, &l)| l != 0.0).map(|(e, _)| degree(e)).max()
    else {
        return 0.0;
    };
    let form = |x: &[f64]| -> f64 {
        exponents
            .iter()
            .zip(lambda)
            .filter(|(e, _)| degree(e) == top)
            .map(|(e, &l)| l * e.iter().zip(x).map(|(&p, &xi)| xi.powi(p as i32)).product::<f64>())
            .sum()
    };
    let directions: Vec<Vec<f64>> = match exponents.first().map_or(0, Vec::len) {
        1 => vec![vec![1.0], vec![-1.0]],
        2 => (0..720)
            .map(|k| {
                let a = std::f64::consts::PI * k as f64 / 360.0;
                vec![a.cos(), a.sin()]
            })
            .collect(),
        3 => (0..2000)
            .map(|k| {
                // Points at equal areas: heights evenly spaced, longitudes by the golden angle.
                let z = 1.0 - (2 * k + 1) as f64 / 2000.0;
                let rho = (1.0 - z * z).sqrt();
                let a = k as f64 * std::f64::consts::PI * (3.0 - 5f64.sqrt());
                vec![rho * a.cos(), rho * a.sin(), z]
            })
            .collect(),
        _ => return f64::NAN,
    };
    directions.iter().map(|x| form(x)).fold(f64::NEG_INFINITY, f64::max)
}

/// The failure `e` of the factor of C (of `moments` moments), with how many of the nodes (node
/// probabilities `p`) carry the density.
pub(super) fn covariance_failure(Unrealizable(why): Unrealizable, p: &[f64], moments: usize) -> Unrealizable {
    let top = p.iter().copied().fold(0.0, f64::max);
    let held = p.iter().filter(|&&pk| pk > 1e-9 * top).count();
    Unrealizable(format!(
        "{why}: the density has {held} of the {} nodes above 1e-9 of its peak, for {} moments \
         (nodes that do not resolve the density: more `panels` or a `domain` closer to it)",
        p.len(),
        moments
    ))
}

/// The Jacobi-scaled Cholesky factor of a moment covariance C (entries of very different
/// sizes): C = S⁻¹LLᵀS⁻¹ with S = diag(1/√C_aa).
#[derive(Debug, Default)]
pub(super) struct SpdFactor {
    scale: Vec<f64>,
    scaled: Vec<f64>,
    l: Vec<f64>,
}

impl SpdFactor {
    /// Factors C (row-major R × R) in place of the previous factor.
    pub(super) fn factor(&mut self, c: &[f64], r: usize) -> std::result::Result<(), Unrealizable> {
        self.scale.clear();
        self.scale.extend((0..r).map(|a| 1.0 / c[a * r + a].max(f64::MIN_POSITIVE).sqrt()));
        self.scaled.clear();
        let scale = &self.scale;
        self.scaled.extend((0..r * r).map(|ab| c[ab] * scale[ab / r] * scale[ab % r]));
        self.l.resize(r * r, 0.0);
        cholesky_into(&self.scaled, r, &mut self.l)
            .map_err(|_| Unrealizable("the moment covariance C is not positive definite".into()))
    }

    /// x = C⁻¹b in place.
    pub(super) fn solve(&self, x: &mut [f64]) {
        self.solve_rows(x, 1);
    }

    /// X = C⁻¹B in place for B row-major R × m (`m` right-hand sides, every column at once).
    pub(super) fn solve_rows(&self, x: &mut [f64], m: usize) {
        let scale_rows = |x: &mut [f64]| {
            for (row, s) in x.chunks_exact_mut(m).zip(&self.scale) {
                row.iter_mut().for_each(|v| *v *= s);
            }
        };
        scale_rows(x);
        cholesky_solve_rows_in_place(&self.l, x, m).expect("the factor and x have matching sizes");
        scale_rows(x);
    }
}

/// What W and ∂W/∂λ of an exponential closure are made of (see [`ExponentialDrift`]), flat:
/// node probabilities π, centred moments d = M(x_k) − μ, πd, generator values g_k (each
/// moment-major: one row of node values per moment; g is 0 where π is), V, the factor of C, W.
#[derive(Debug, Default)]
struct FirstOrder {
    p: Vec<f64>,
    d: Vec<f64>,
    pd: Vec<f64>,
    g: Vec<f64>,
    v: Vec<f64>,
    c: SpdFactor,
    w: Vec<f64>,
}

/// The buffers of one evaluation of an [`ExponentialDrift`]: [`FirstOrder`] and the scratch of
/// the log-weights, the drift at the nodes, C, and the node and moment vectors of ∂W/∂λ and
/// ∇²(κᵀW).
#[derive(Debug, Default)]
struct ExpWork {
    z: FirstOrder,
    s: Vec<f64>,
    fs: Vec<f64>,
    f: Vec<f64>,
    cov: Vec<f64>,
    /// π on all nodes, before the restriction to the nodes with mass.
    p_all: Vec<f64>,
    nodes: [Vec<f64>; 5],
    col: Vec<f64>,
    u: Vec<f64>,
    tm: Vec<f64>,
    tj: Vec<f64>,
    tensor: TensorWork,
}

/// The node probabilities π of the family of `nodes` at λ into `p` and F = log Σ exp(…), with
/// λᵀM by their tensor plan where there is one ([`tensor_probabilities`]); `row` and `s` are
/// scratch.
fn probabilities(
    nodes: &Nodes,
    lambda: &[f64],
    scratch: (&mut Vec<f64>, &mut Vec<f64>, &mut Vec<f64>),
) -> std::result::Result<f64, Unrealizable> {
    match &nodes.tensor {
        Some(plan) => tensor_probabilities(&nodes.family, plan, lambda, scratch),
        None => {
            let (_, s, p) = scratch;
            nodes.family.node_probabilities_into(lambda, s, p).map_err(unrealizable)
        }
    }
}

/// The node probabilities π of `family` at λ into `p` and F = log Σ exp(…), on the tensor grid
/// of `plan` (λᵀM by [`TensorPlan::polynomial_into`]); λ of the wrong length or not finite goes
/// to [`Exponential::node_probabilities_into`] for its error. `row` and `s` are scratch.
fn tensor_probabilities(
    family: &Exponential,
    plan: &TensorPlan,
    lambda: &[f64],
    (row, s, p): (&mut Vec<f64>, &mut Vec<f64>, &mut Vec<f64>),
) -> std::result::Result<f64, Unrealizable> {
    if lambda.len() == plan.n_moments() && lambda.iter().all(|v| v.is_finite()) {
        plan.polynomial_into(lambda, row, s);
        family.node_probabilities_from_exponents(s, p)
    } else {
        family.node_probabilities_into(lambda, s, p)
    }
    .map_err(unrealizable)
}

impl<S: Sde + ?Sized> ExponentialDrift<'_, S> {
    /// W and, by `order`, ∂W/∂λ and ∇²(κᵀW) into `out` by the raw-moment sums of a tensor grid
    /// ([`TensorPlan`]: a fixed box, or the frame of nodes that follow the density, moved first
    /// by [`ExponentialDrift::follow_density`]); `None` where they do not apply (a family other
    /// than all monomials up to a degree), and the node sums of [`ExponentialDrift::zeroth`]
    /// serve.
    fn tensor_sums(
        &self,
        t: f64,
        lambda: &[f64],
        order: Order,
        kappa: &[f64],
        out: (&mut [f64], &mut [f64], &mut [f64]),
    ) -> Option<std::result::Result<(), Unrealizable>> {
        self.nodes.borrow().tensor.as_ref()?;
        let work = &mut *self.work.borrow_mut();
        let computed = match self.follow_density(lambda, work) {
            Ok(computed) => computed,
            Err(e) => return Some(Err(e)),
        };
        let held = self.nodes.borrow();
        let plan = held.tensor.as_ref()?;
        let ExpWork { s, p_all, fs, f, col, tensor, .. } = work;
        let run = || {
            if !computed {
                tensor_probabilities(&held.family, plan, lambda, (col, s, p_all))?;
            }
            let points = held.family.grid().points();
            // π_k f_i(x_k), state-major (0 where π_k = 0).
            if self.sde.drift_is_autonomous() {
                let all = held.drift.get_or_init(|| {
                    let (mut all, mut scratch) = (Vec::new(), Vec::new());
                    self.drift_at_nodes(t, points, &vec![1.0; p_all.len()], &mut all, &mut scratch);
                    all
                });
                fs.clear();
                for row in all.chunks_exact(p_all.len()) {
                    fs.extend(
                        row.iter().zip(p_all.iter()).map(|(&v, &pk)| if pk != 0.0 { v * pk } else { 0.0 }),
                    );
                }
            } else {
                self.drift_at_nodes(t, points, p_all, fs, f);
                for row in fs.chunks_exact_mut(p_all.len()) {
                    for (v, &pk) in row.iter_mut().zip(p_all.iter()) {
                        *v *= pk;
                    }
                }
            }
            let values = NodeValues { p: p_all, pf: fs, diffusion: &self.diffusion, kappa };
            plan.evaluate(order, values, tensor, out)
        };
        Some(run())
    }

    /// The moments of [`ClosureDrift::moments`] by the raw-moment table of a tensor grid;
    /// `None` where it does not apply (as [`ExponentialDrift::tensor_sums`]).
    fn tensor_moments(&self, lambda: &[f64]) -> Option<std::result::Result<FamilyMoments, Unrealizable>> {
        let held = self.nodes.borrow();
        let plan = held.tensor.as_ref()?;
        let ExpWork { s, p_all, col, tensor, .. } = &mut *self.work.borrow_mut();
        Some(tensor_probabilities(&held.family, plan, lambda, (col, s, p_all)).map(|log_partition| {
            let (mean, covariance) = plan.cumulants(p_all, tensor);
            FamilyMoments { log_partition, mean, covariance }
        }))
    }

    /// The drift at the nodes `points` (row-major) that carry mass (`p_k` ≠ 0), state-major into
    /// `fs` (one row of node values per state, 0 where p_k = 0); `f` is scratch.
    fn drift_at_nodes(&self, t: f64, points: &[f64], p: &[f64], fs: &mut Vec<f64>, f: &mut Vec<f64>) {
        let (n, nodes) = (self.linear.len(), p.len());
        fs.clear();
        fs.resize(n * nodes, 0.0);
        f.clear();
        f.resize(n, 0.0);
        for (k, &pk) in p.iter().enumerate() {
            if pk != 0.0 {
                self.sde.state_drift(t, &points[k * n..(k + 1) * n], &self.theta, f);
                for i in 0..n {
                    fs[i * nodes + k] = f[i];
                }
            }
        }
    }
}

impl<S: Sde + ?Sized> ExponentialDrift<'_, S> {
    /// π, d, g, V, C and W = C⁻¹V at (t, λ) into `z`, with the scratch of `work`, on the nodes
    /// `lo..hi` from the first to the last of non-zero probability: the node vectors of `z` are
    /// that range, compact. A concentrated density has no mass that counts on most of a wide
    /// grid, and the family gives probability 0 to nodes below e⁻⁵⁰ of the largest
    /// ([`onsager_closures::NEGLIGIBLE_LOG_WEIGHT`]), so W, ∂W/∂λ and ∇²(κᵀW) remain the
    /// exact derivatives of one another.
    fn zeroth(&self, t: f64, lambda: &[f64], work: &mut ExpWork) -> std::result::Result<(), Unrealizable> {
        let computed = self.follow_density(lambda, work)?;
        let held = self.nodes.borrow();
        let (jac, second) = held.tables(&self.diffusion)?;
        let family = &held.family;
        let n = family.dim();
        let r = family.n_moments();
        let ExpWork { z, s, fs, f, cov, p_all, .. } = work;
        if !computed {
            family.node_probabilities_into(lambda, s, p_all).map_err(unrealizable)?;
        }
        let all = p_all.len();
        let lo = p_all.iter().position(|&pk| pk > 0.0).unwrap_or(0);
        let hi = p_all.iter().rposition(|&pk| pk > 0.0).map_or(all, |k| k + 1);
        z.p.clear();
        z.p.extend_from_slice(&p_all[lo..hi]);
        let p = &z.p;
        let nodes = p.len();
        // Row `row` of a table of rows of `all` node values, restricted to lo..hi.
        let active = |row: usize| row * all + lo..row * all + hi;
        self.drift_at_nodes(t, &family.grid().points()[lo * n..hi * n], p, fs, f);
        let table = family.moment_table_by_moment();
        let massless = p.contains(&0.0);
        let (d, pd, g, v) = (&mut z.d, &mut z.pd, &mut z.g, &mut z.v);
        d.clear();
        pd.clear();
        g.clear();
        v.clear();
        v.resize(r, 0.0);
        for (a, va) in v.iter_mut().enumerate() {
            let row = a * nodes..(a + 1) * nodes;
            let ma = &table[active(a)];
            let mu = dot(p, ma);
            d.extend(ma.iter().map(|&mk| mk - mu));
            pd.extend(p.iter().zip(&d[row.clone()]).map(|(&pk, &dk)| pk * dk));
            g.extend_from_slice(&second[active(a)]);
            let ga = &mut g[row];
            for i in 0..n {
                let ji = &jac[active(a * n + i)];
                let fi = &fs[i * nodes..(i + 1) * nodes];
                for ((gk, &jk), &fk) in ga.iter_mut().zip(ji).zip(fi) {
                    *gk += jk * fk;
                }
            }
            if massless {
                for (gk, &pk) in ga.iter_mut().zip(p) {
                    if pk == 0.0 {
                        *gk = 0.0;
                    }
                }
            }
            *va = dot(p, ga);
        }
        if !v.iter().all(|x| x.is_finite()) {
            return Err(Unrealizable("the drift is not finite on the family's grid".into()));
        }
        cov.clear();
        cov.resize(r * r, 0.0);
        for a in 0..r {
            for b in a..r {
                let cab = dot(&pd[a * nodes..(a + 1) * nodes], &d[b * nodes..(b + 1) * nodes]);
                cov[a * r + b] = cab;
                cov[b * r + a] = cab;
            }
        }
        z.c.factor(cov, r).map_err(|e| covariance_failure(e, p_all, r))?;
        z.w.clear();
        z.w.extend_from_slice(v);
        z.c.solve(&mut z.w);
        Ok(())
    }

    /// Σ_k s_k d_a(x_k) d_b(x_k) for all a, b (symmetric, row-major r × r) of a node weight s;
    /// `sd` is scratch.
    fn weighted_second_moments(z: &FirstOrder, s: &[f64], out: &mut [f64], sd: &mut Vec<f64>) {
        let r = z.w.len();
        let nodes = z.p.len();
        sd.clear();
        sd.resize(nodes, 0.0);
        for a in 0..r {
            let da = &z.d[a * nodes..(a + 1) * nodes];
            for ((x, &sk), &dk) in sd.iter_mut().zip(s).zip(da) {
                *x = sk * dk;
            }
            for b in a..r {
                let v = dot(sd, &z.d[b * nodes..(b + 1) * nodes]);
                out[a * r + b] = v;
                out[b * r + a] = v;
            }
        }
    }

    /// Σ_a c_a m_a(x_k) at every node of moment-major rows m, into `out`.
    fn project(rows: &[f64], c: &[f64], out: &mut Vec<f64>) {
        let nodes = rows.len() / c.len().max(1);
        out.clear();
        out.resize(nodes, 0.0);
        for (row, &ca) in rows.chunks_exact(nodes).zip(c) {
            for (o, &mk) in out.iter_mut().zip(row) {
                *o += ca * mk;
            }
        }
    }

    /// ∂W/∂λ = C⁻¹Σπ_k(g_k − (d_k·W)d_k)d_kᵀ into `jac` (row-major), of `work.z`.
    fn jacobian_of(work: &mut ExpWork, jac: &mut [f64]) {
        let ExpWork { z, nodes: [wd, e, ..], .. } = work;
        let r = z.w.len();
        let nodes = z.p.len();
        Self::project(&z.d, &z.w, wd);
        e.clear();
        e.resize(nodes, 0.0);
        for a in 0..r {
            let row = a * nodes..(a + 1) * nodes;
            for (((ek, &pk), &gk), (&pdk, &u)) in
                e.iter_mut().zip(&z.p).zip(&z.g[row.clone()]).zip(z.pd[row].iter().zip(wd.iter()))
            {
                *ek = pk * gk - u * pdk;
            }
            for j in 0..r {
                jac[a * r + j] = dot(e, &z.d[j * nodes..(j + 1) * nodes]);
            }
        }
        z.c.solve_rows(&mut jac[..r * r], r);
    }

    /// ∇²(κᵀW) of [`ClosureDrift::w_second`] into `hess`, from the node values of `work.z` and
    /// J = ∂W/∂λ.
    fn hessian_of(&self, work: &mut ExpWork, kappa: &[f64], jac: &[f64], hess: &mut [f64]) {
        let r = self.n_moments;
        let ExpWork { z, nodes: [ud, wd, ug, psi, tu], u, tm, tj, f: sd, .. } = work;
        u.clear();
        u.extend_from_slice(kappa);
        z.c.solve(u);
        // hess = ⟨ψ d dᵀ⟩, tm = T, with ψ_k = π_k(uᵀg_k − (uᵀd_k)(Wᵀd_k)) and π_k uᵀd_k.
        Self::project(&z.d, u, ud);
        Self::project(&z.d, &z.w, wd);
        Self::project(&z.g, u, ug);
        psi.clear();
        psi.extend((0..z.p.len()).map(|k| z.p[k] * (ug[k] - ud[k] * wd[k])));
        tu.clear();
        tu.extend(z.p.iter().zip(ud.iter()).map(|(p, u)| p * u));
        tm.clear();
        tm.resize(r * r, 0.0);
        Self::weighted_second_moments(z, psi, hess, sd);
        Self::weighted_second_moments(z, tu, tm, sd);
        tj.clear();
        tj.resize(r * r, 0.0);
        for a in 0..r {
            for j in 0..r {
                tj[a * r + j] = (0..r).map(|b| tm[a * r + b] * jac[b * r + j]).sum();
            }
        }
        for a in 0..r {
            for j in 0..r {
                hess[a * r + j] += -tj[a * r + j] - tj[j * r + a] + kappa[a] * z.v[j] + z.v[a] * kappa[j];
            }
        }
    }
}

impl<S: Sde + ?Sized> ClosureDrift for ExponentialDrift<'_, S> {
    fn support(&self) -> Option<Vec<(f64, f64)>> {
        self.support.clone()
    }

    fn start_sweep(&self) {
        if let Some(initial) = &self.initial {
            *self.nodes.borrow_mut() = initial.clone();
        }
    }

    /// The node probabilities at λ summed over the nodes within [`EDGE_BAND`] of the box's
    /// width from either end of each axis; `None` for nodes that follow the density, or where
    /// the density is not normalizable at λ.
    fn edge_mass(&self, lambda: &[f64]) -> Option<(usize, f64)> {
        let support = self.support.as_ref()?;
        let held = self.nodes.borrow();
        if held.frame.is_some() {
            return None;
        }
        let ExpWork { s, p_all, .. } = &mut *self.work.borrow_mut();
        held.family.node_probabilities_into(lambda, s, p_all).ok()?;
        let (n, points) = (support.len(), held.family.grid().points());
        let mut worst: Option<(usize, f64)> = None;
        for (axis, &(a, b)) in support.iter().enumerate() {
            let band = EDGE_BAND * (b - a);
            let mass: f64 = (p_all.iter().enumerate())
                .filter(|&(k, _)| !(a + band..=b - band).contains(&points[k * n + axis]))
                .map(|(_, &pk)| pk)
                .sum();
            if worst.is_none_or(|(_, m)| mass > m) {
                worst = Some((axis, mass));
            }
        }
        worst
    }

    fn n_params(&self) -> usize {
        self.n_moments
    }

    fn state_dim(&self) -> usize {
        self.linear.len()
    }

    fn w(&self, t: f64, lambda: &[f64], out: &mut [f64]) -> std::result::Result<(), Unrealizable> {
        if let Some(done) = self.tensor_sums(t, lambda, Order::W, &[], (out, &mut [], &mut [])) {
            return done;
        }
        let work = &mut *self.work.borrow_mut();
        self.zeroth(t, lambda, work)?;
        out.copy_from_slice(&work.z.w);
        Ok(())
    }

    fn w_jacobian(
        &self,
        t: f64,
        lambda: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
    ) -> std::result::Result<(), Unrealizable> {
        if let Some(done) = self.tensor_sums(t, lambda, Order::Jacobian, &[], (w, jac, &mut [])) {
            return done;
        }
        let work = &mut *self.work.borrow_mut();
        self.zeroth(t, lambda, work)?;
        Self::jacobian_of(work, jac);
        w.copy_from_slice(&work.z.w);
        Ok(())
    }

    /// In closed form on the fixed nodes: with u = C⁻¹κ, d_k = M(x_k) − μ and
    /// ψ_k = uᵀg_k − (uᵀd_k)(Wᵀd_k) (so that ∂(κᵀW)/∂λ_j = ⟨ψ d_j⟩ and ⟨ψ⟩ = 0),
    ///
    /// $$ \nabla^2(\kappa^\top W) = \langle \psi\, d d^\top\rangle - TJ - (TJ)^\top
    ///    + \kappa V^\top + V \kappa^\top, \qquad T = \langle (u^\top d)\, d d^\top\rangle, $$
    ///
    /// J = ∂W/∂λ, from ∂⟨h⟩/∂λ_j = ⟨∂_j h⟩ + ⟨h d_j⟩ and ∂d/∂λ_j = −C_{·j}.
    fn w_second(
        &self,
        t: f64,
        lambda: &[f64],
        kappa: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
        hess: &mut [f64],
    ) -> std::result::Result<(), Unrealizable> {
        if let Some(done) = self.tensor_sums(t, lambda, Order::Hessian, kappa, (w, jac, hess)) {
            return done;
        }
        let work = &mut *self.work.borrow_mut();
        self.zeroth(t, lambda, work)?;
        Self::jacobian_of(work, jac);
        self.hessian_of(work, kappa, jac, hess);
        w.copy_from_slice(&work.z.w);
        Ok(())
    }

    /// The Jacobian of [`ClosureDrift::w_jacobian`] is the same computation
    /// (`jacobian_of` of the same node values): `jac` is used as given.
    fn w_second_with_jacobian(
        &self,
        t: f64,
        lambda: &[f64],
        kappa: &[f64],
        w: &mut [f64],
        jac: &mut [f64],
        hess: &mut [f64],
    ) -> std::result::Result<(), Unrealizable> {
        if let Some(done) = self.tensor_sums(t, lambda, Order::Hessian, kappa, (w, jac, hess)) {
            return done;
        }
        let work = &mut *self.work.borrow_mut();
        self.zeroth(t, lambda, work)?;
        self.hessian_of(work, kappa, jac, hess);
        w.copy_from_slice(&work.z.w);
        Ok(())
    }

    /// On a tensor grid (a fixed box, or the frame of nodes that follow the density) by the
    /// raw-moment table ([`TensorPlan::cumulants`]), else by node sums.
    fn moments(&self, lambda: &[f64]) -> std::result::Result<FamilyMoments, Unrealizable> {
        self.follow_density(lambda, &mut self.work.borrow_mut())?;
        if let Some(moments) = self.tensor_moments(lambda) {
            return moments;
        }
        let c = self.nodes.borrow().family.cumulants(lambda).map_err(unrealizable)?;
        Ok(FamilyMoments { log_partition: c.log_partition, mean: c.mean, covariance: c.covariance })
    }

    fn linear_index(&self, state: usize) -> Option<usize> {
        self.linear.get(state).copied().flatten()
    }

    fn square_index(&self, state: usize) -> Option<usize> {
        self.square.get(state).copied().flatten()
    }
}

/// The polynomial exponential family M = the monomials of total degree ≤ `moments` (1-D:
/// x, …, x^moments; 2-D: x^i y^j, i + j ≤ moments) on a fixed quadrature grid (`exp-closure`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
#[non_exhaustive]
pub struct ExponentialFamily {
    /// The highest total degree: 2 to 12 in 1-D, 2 to 6 in 2-D, 2 to 4 in 3-D (34 moments).
    /// Default 4 (the quartic family).
    pub moments: usize,
    /// Support of the family (its quadrature grid): one interval [a, b] per state, or empty for
    /// the default: per state, the range of its data and of its initial prior (mean ± 5 sd),
    /// widened by half its width plus 1 on each side. Set it for a state that is not measured
    /// and whose range the prior does not cover. On a box (`nodes = box`) it must cover every
    /// datum of a measured state ([`Error::InvalidOption`] otherwise): the box truncates the
    /// density to it. On the command line, `domain=[a,b]` (one state) or `domain=[[a,b],[c,d]]`.
    #[serde(deserialize_with = "intervals")]
    pub domain: Vec<(f64, f64)>,
    /// Panels × 8 Gauss–Legendre points per dimension of the fixed box (`nodes = box`). Default
    /// 12 (96 nodes in 1-D; the double-well estimates of `benches/closure.rs` agree with 24
    /// panels to 1e-5); in 2-D and 3-D half as many per dimension (6 × 8 = 48: 2304 nodes in
    /// 2-D, 110,592 in 3-D). The nodes are checked against the problem's memory limit.
    pub panels: usize,
    /// Where the nodes are: on a fixed box (`box`, the default, with `domain` and `panels`), or
    /// on a grid that follows the density (`density`, with `density_panels`, `density_width`
    /// and `density_tolerance`).
    pub nodes: NodeRule,
    /// On the box: how many times its panels may grow by half (⌈1.5 P⌉) when the quadrature
    /// check fails. After the dual converges on P panels, the history at its multipliers is
    /// computed again on ⌈1.5 P⌉; if a state's mean moves by more than `refine_tolerance` of its
    /// typical standard deviation on the path, the estimate is solved again on the finer box
    /// (from the coarser solution), and checked again while refinements remain. An estimate that fails
    /// (`numerical-failure`) on the first box is solved afresh once on the next. Default 2; 0
    /// turns the check off.
    pub refine: usize,
    /// On the box: how many times the box may be widened (one axis each time) when the density
    /// reaches its edge (more than 10⁻³ of its mass within 2 % of an axis's width from an end,
    /// at an output or a measurement time, on the history's sweep). The history at the
    /// estimate's multipliers is computed again on the box with that axis grown by half its
    /// width (a quarter at each end); if a state's mean moves there by more than
    /// `refine_tolerance`, the estimate is solved again on the wider box from its solution
    /// (with the quadrature check and the refinements of `refine`), and so on. Default 2; an
    /// estimate whose box cuts the density off and whose means move on the wider box, with no
    /// widening left (or 0), ends `grid-edge`.
    pub widen: usize,
    /// The quadrature check's tolerance: the largest shift of a state's mean from P to ⌈1.5 P⌉
    /// panels, in units of the state's typical standard deviation on the path (the root mean
    /// square over the output times of the closure's history). Default 0.01.
    pub refine_tolerance: f64,
    /// Nodes that follow the density: the panels × 8 Gauss–Legendre points per axis the
    /// refinement starts from. Default 3 (24 per axis, 576 nodes in 2-D, 13,824 in 3-D). The
    /// refinement stops at 32 panels per axis and about 10⁶ nodes (12 panels in 3-D).
    pub density_panels: usize,
    /// Nodes that follow the density: the half-width of their box in standard deviations of the
    /// density. Default 6; the box widens by half wherever the density at its boundary is above
    /// `density_tolerance` times its peak.
    pub density_width: f64,
    /// Nodes that follow the density: the panels double until the moments on P and 2P panels
    /// agree to this many of their standard deviations. Default 1e-4.
    pub density_tolerance: f64,
}

/// Where the nodes of the exponential closure are (option `nodes`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum NodeRule {
    /// A fixed box of Gauss–Legendre panels (`domain`, `panels`).
    #[default]
    Box,
    /// A grid centred and scaled by the density's mean and covariance, moved with it and
    /// refined to `density_tolerance` (`density_panels`, `density_width`).
    Density,
}

/// A `domain`: one interval [a, b] (a one-state family) or a list of them, one per state.
fn intervals<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Vec<(f64, f64)>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged, expecting = "an interval [a, b] or a list of intervals [[a, b], [c, d]]")]
    enum Domain {
        One((f64, f64)),
        Many(Vec<(f64, f64)>),
    }
    Ok(match Domain::deserialize(d)? {
        Domain::One(interval) => vec![interval],
        Domain::Many(list) => list,
    })
}

impl Default for ExponentialFamily {
    fn default() -> Self {
        ExponentialFamily {
            moments: 4,
            domain: Vec::new(),
            panels: 12,
            nodes: NodeRule::Box,
            refine: 2,
            widen: 2,
            refine_tolerance: 0.01,
            density_panels: 3,
            density_width: 6.0,
            density_tolerance: 1e-4,
        }
    }
}

impl ExponentialFamily {
    /// The highest total degree of the family in `states` dimensions: 12, 6 and 4 (the quartic
    /// family's 34 moments) in 1-D to 3-D; `None` beyond three states.
    pub fn max_degree(states: usize) -> Option<usize> {
        [12, 6, 4].get(states.checked_sub(1)?).copied()
    }

    /// The family of the monomials up to `degree`, on the default support.
    pub fn of_degree(degree: usize) -> Self {
        ExponentialFamily { moments: degree, ..Default::default() }
    }

    /// Sets the support, one interval per state.
    pub fn with_domain(mut self, domain: &[(f64, f64)]) -> Self {
        self.domain = domain.to_vec();
        self
    }

    /// Sets the number of Gauss–Legendre panels per dimension.
    pub fn with_panels(mut self, panels: usize) -> Self {
        self.panels = panels;
        self
    }

    /// Sets where the nodes are.
    pub fn with_nodes(mut self, nodes: NodeRule) -> Self {
        self.nodes = nodes;
        self
    }

    /// Sets the tolerance of the nodes that follow the density.
    pub fn with_density_tolerance(mut self, tolerance: f64) -> Self {
        self.density_tolerance = tolerance;
        self
    }

    /// Sets how many times the box may be refined by the quadrature check (0: no check).
    pub fn with_refine(mut self, refine: usize) -> Self {
        self.refine = refine;
        self
    }

    /// The same family with `widen` widenings of the box allowed ([`ExponentialFamily::widen`]).
    pub fn with_widen(mut self, widen: usize) -> Self {
        self.widen = widen;
        self
    }

    /// Whether the nodes follow the density.
    fn follows_density(&self) -> bool {
        self.nodes == NodeRule::Density
    }
}

impl ClosureFamily for ExponentialFamily {
    type Drift<'a, S: Sde + ?Sized + 'a> = ExponentialDrift<'a, S>;
    const METHOD: Method = Method::ExpClosure;

    fn describe(&self) -> String {
        format!("Exponential {{ degree: {} }}", self.moments)
    }

    fn validate(&self) -> Result<()> {
        if !(2..=12).contains(&self.moments) {
            return Err(Error::invalid(
                "moments",
                format!("must be 2 to 12 (2 to 6 in 2-D, 2 to 4 in 3-D), got {}", self.moments),
            ));
        }
        if self.panels == 0 {
            return Err(Error::invalid("panels", "must be at least 1, got 0"));
        }
        if !(self.refine_tolerance > 0.0 && self.refine_tolerance.is_finite()) {
            return Err(Error::invalid(
                "refine_tolerance",
                format!("must be positive and finite, got {}", self.refine_tolerance),
            ));
        }
        if self.density_panels == 0 || self.density_panels > MAX_DENSITY_PANELS / 2 {
            return Err(Error::invalid(
                "density_panels",
                format!("must be 1 to {}, got {}", MAX_DENSITY_PANELS / 2, self.density_panels),
            ));
        }
        if !(self.density_width.is_finite() && (2.0..=MAX_DENSITY_WIDTH).contains(&self.density_width)) {
            return Err(Error::invalid(
                "density_width",
                format!("must be 2 to {MAX_DENSITY_WIDTH} standard deviations, got {}", self.density_width),
            ));
        }
        if !(self.density_tolerance > 0.0 && self.density_tolerance < 1.0) {
            return Err(Error::invalid(
                "density_tolerance",
                format!("must be in (0, 1), got {}", self.density_tolerance),
            ));
        }
        match self.domain.iter().find(|(a, b)| !(a.is_finite() && b.is_finite() && a < b)) {
            Some((a, b)) => Err(Error::invalid("domain", format!("need finite a < b, got [{a}, {b}]"))),
            None => Ok(()),
        }
    }

    /// The box with the axis of `edge` widened by half, a quarter at each end: checked on these
    /// panels to `refine_tolerance`, solved on the panels and refinements of `start` with one
    /// widening fewer.
    fn widened(&self, start: &Self, support: &[(f64, f64)], edge: &GridEdge) -> Option<Widening<Self>> {
        if self.follows_density() {
            return None;
        }
        let mut domain = support.to_vec();
        let (a, b) = *domain.get(edge.axis)?;
        domain[edge.axis] = (a - 0.25 * (b - a), b + 0.25 * (b - a));
        let check = ExponentialFamily { domain: domain.clone(), ..self.clone() };
        let wider = ExponentialFamily { domain, widen: start.widen.saturating_sub(1), ..start.clone() };
        Some(Widening { check, wider, tolerance: self.refine_tolerance, may_solve: start.widen > 0 })
    }

    /// Nodes that follow the density: `density_tolerance` (the accuracy, in standard deviations,
    /// to which the nodes are refined; their frame moves with λ); a fixed box: 0.
    fn quadrature_noise(&self) -> f64 {
        if self.follows_density() {
            self.density_tolerance
        } else {
            0.0
        }
    }

    /// The box with ⌈1.5 P⌉ panels and one refinement fewer, while any remain.
    fn refined(&self) -> Option<Refinement<Self>> {
        if self.follows_density() || self.refine == 0 {
            return None;
        }
        let panels = (3 * self.panels).div_ceil(2);
        let finer = ExponentialFamily { panels, refine: self.refine - 1, ..self.clone() };
        let nodes = (format!("{} panels", self.panels), format!("{panels} panels"));
        Some(Refinement { finer, tolerance: self.refine_tolerance, nodes })
    }

    fn setup<'a, S: Sde + ?Sized>(
        &self,
        problem: &EstimationProblem<'a, S, StateMeasurement>,
    ) -> Result<FamilySetup<ExponentialDrift<'a, S>>> {
        let (drift, lambda0) = exponential_setup(problem, self)?;
        let measured = problem
            .observation
            .states
            .iter()
            .map(|&s| {
                drift
                    .linear_index(s)
                    .ok_or_else(|| Error::invalid("moments", "the family has no linear moment"))
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(FamilySetup { drift, lambda0, measured })
    }
}

/// Bytes per node and moment of a family: its moment table, twice (by node and by moment).
const BYTES_PER_NODE_MOMENT: f64 = 16.0;
/// Bytes per node besides the moment tables: the points, weights, exponents, probabilities and
/// the drift at the nodes, and their scratch.
const BYTES_PER_NODE: f64 = 120.0;

/// Checks the family's nodes, `panels` × 8 points per axis, against the problem's memory limit
/// (the nodes that follow the density may refine up to [`MAX_DENSITY_NODES`]).
fn check_node_memory<S: Sde + ?Sized>(
    problem: &EstimationProblem<'_, S, StateMeasurement>,
    panels: usize,
    degree: usize,
) -> Result<()> {
    let n = problem.sde.dims().states();
    let nodes = ((panels * POINTS_PER_PANEL) as f64).powi(n as i32);
    let moments = monomial_count(n, degree);
    let bytes = nodes * (moments as f64 * BYTES_PER_NODE_MOMENT + BYTES_PER_NODE);
    let size = format!("{nodes:.0} nodes ({} per axis) × {moments} moments", panels * POINTS_PER_PANEL);
    problem.max_memory.check("the exponential closure's nodes", size, bytes)
}

fn exponential_setup<'a, S: Sde + ?Sized>(
    problem: &EstimationProblem<'a, S, StateMeasurement>,
    options: &ExponentialFamily,
) -> Result<(ExponentialDrift<'a, S>, Vec<f64>)> {
    let degree = options.moments;
    let n = problem.sde.dims().states();
    let Some(max_degree) = ExponentialFamily::max_degree(n) else {
        return Err(Error::invalid(
            "method",
            format!(
                "the exponential closure handles models with one to three states (this model has {n}); use gaussian-closure"
            ),
        ));
    };
    if !(2..=max_degree).contains(&degree) {
        return Err(Error::invalid(
            "moments",
            format!("the exponential closure in {n}-D needs degree 2 to {max_degree}, got {degree}"),
        ));
    }
    if !options.domain.is_empty() && options.domain.len() != n {
        return Err(Error::invalid(
            "domain",
            format!("one interval per state: the model has {n}, got {}", options.domain.len()),
        ));
    }
    let names = problem.sde.state_names();
    let priors: Vec<&Prior> = problem.x0_prior.iter().chain(problem.z0_prior).collect();
    let mut moments = Vec::with_capacity(n);
    let mut domain = Vec::with_capacity(n);
    for i in 0..n {
        let (m0, v0) = gaussian_prior(priors[i], &names[i])?;
        moments.push((m0, v0));
        let values: Vec<f64> = problem
            .observation
            .states
            .iter()
            .enumerate()
            .filter(|&(_, &s)| s == i)
            .flat_map(|(b, _)| problem.data.values.iter().map(move |row| row[b]))
            .collect();
        domain.push(options.domain.get(i).copied().unwrap_or_else(|| default_domain(&values, m0, v0)));
    }
    if !options.follows_density() {
        check_box_covers_data(problem, &domain)?;
    }
    let panels = if options.follows_density() {
        options.density_panels
    } else if n == 1 {
        options.panels
    } else {
        options.panels.div_ceil(2)
    };
    if options.follows_density() && panels > max_density_panels(n) {
        return Err(Error::invalid(
            "density_panels",
            format!("in {n}-D must be 1 to {}, got {panels}", max_density_panels(n)),
        ));
    }
    check_node_memory(problem, panels, degree)?;
    let follow = options.follows_density().then_some(DensityNodes {
        degree: degree as u32,
        panels: options.density_panels,
        width: options.density_width,
        tolerance: options.density_tolerance,
    });
    // Nodes that follow the density start on the frame of the prior: its means and sds.
    let frame_mean: Vec<f64> = moments.iter().map(|m| m.0).collect();
    let mut frame_chol = vec![0.0; n * n];
    (0..n).for_each(|i| frame_chol[i * n + i] = moments[i].1.sqrt());
    let family = match follow {
        Some(f) => density_family(&frame_mean, &frame_chol, f.width, f.panels, f.degree)
            .map_err(|e| Error::invalid("density_width", e.to_string()))?,
        None => {
            let grid = onsager_closures::panel_grid(&domain, panels, POINTS_PER_PANEL)
                .map_err(|e| Error::invalid("domain", e.to_string()))?;
            Exponential::polynomial(grid, onsager_closures::Reference::Lebesgue, degree as u32).map_err(|e| {
                let whence =
                    if options.domain.is_empty() { " (the default, from the data's range)" } else { "" };
                Error::invalid(
                    "domain",
                    format!(
                        "{domain:?}{whence} is too wide for moments of degree {degree} ({e}); give a narrower \
                         `domain` or rescale the data"
                    ),
                )
            })?
        }
    };
    // λ_0: the (independent) Gaussian prior is the member with m_i/v_i on x_i, −1/(2v_i) on
    // x_i² and 0 elsewhere; polished by the Legendre inverse of its moments on the grid (moment
    // matching, (II.39)).
    let exponents = family.exponents().ok_or_else(|| Error::invalid("moments", "no polynomial exponents"))?;
    let guess: Vec<f64> = exponents
        .iter()
        .map(|e| {
            let total: u32 = e.iter().sum();
            match e.iter().position(|&p| p > 0) {
                Some(i) if total == e[i] && e[i] == 1 => moments[i].0 / moments[i].1,
                Some(i) if total == e[i] && e[i] == 2 => -0.5 / moments[i].1,
                _ => 0.0,
            }
        })
        .collect();
    let mu0 = family.mean(&guess).map_err(|e| Error::invalid("x0 prior", e.to_string()))?;
    let lambda0 = family
        .legendre(&mu0, &LegendreOptions::default().with_initial(guess.clone()))
        .map(|s| s.lambda)
        .unwrap_or(guess);
    let drift = match follow {
        Some(f) => {
            ExponentialDrift::following(problem.sde, problem.theta, family, (frame_mean, frame_chol), f)?
        }
        None => ExponentialDrift::try_new(problem.sde, problem.theta, family)?.on_box(domain),
    };
    Ok((drift, lambda0))
}

#[cfg(test)]
mod tests {
    use super::super::tests::fd_jacobian;
    use super::*;
    use crate::model::library::DoubleWell;
    use approx::assert_relative_eq;

    /// CW = V for the double well (D = 0.5) and the quartic family, with V by the family's own
    /// quadrature on all its nodes: V = ⟨f M' + D M''⟩ with f = 4x − 4x³, M = x^a, i.e.
    /// V_a = ⟨a x^{a−1} f + a(a−1)/2 x^{a−2}⟩.
    fn assert_w_is_c_inverse_v(family: &Exponential, lambda: &[f64], w: &[f64]) {
        let rule = family.quadrature(lambda).unwrap();
        let c = family.covariance(lambda).unwrap();
        for a in 1..=4i32 {
            let v = rule.integrate(|x| {
                let x = x[0];
                let f = 4.0 * x - 4.0 * x.powi(3);
                a as f64 * x.powi(a - 1) * f + 0.5 * (a * (a - 1)) as f64 * x.powi((a - 2).max(0))
            });
            let cw: f64 = (0..4).map(|b| c[(a as usize - 1) * 4 + b] * w[b]).sum();
            assert_relative_eq!(cw, v, epsilon = 1e-9, max_relative = 1e-9);
        }
    }

    #[test]
    fn the_edge_mass_of_a_uniform_density_is_the_weight_of_the_outer_nodes() {
        // λ = 0 on [−2, 2] (Lebesgue reference): the uniform density. Its mass within 2 % of the
        // width of each end lies on the three outermost of the eight Gauss–Legendre points of the
        // end panels (at 0.0199, 0.1017 and 0.2372 of a panel, 12 panels): the weights
        // 0.1012285363, 0.2223810345, 0.3137066459 of the rule on [−1, 1] (Abramowitz & Stegun,
        // Table 25.4), half of each per unit panel, 1/12 of the mass per panel, at both ends.
        let grid = onsager_closures::panel_grid(&[(-2.0, 2.0)], 12, 8).unwrap();
        let family = Exponential::polynomial(grid, onsager_closures::Reference::Lebesgue, 4).unwrap();
        let drift = ExponentialDrift::try_new(&DoubleWell, &[0.5], family).unwrap().on_box(vec![(-2.0, 2.0)]);
        let outer = (0.1012285363 + 0.2223810345 + 0.3137066459) / 2.0;
        let (axis, mass) = drift.edge_mass(&[0.0; 4]).unwrap();
        assert_eq!(axis, 0);
        assert_relative_eq!(mass, 2.0 * outer / 12.0, max_relative = 1e-9);
        // A density of sd 0.2 at 0 has next to none there (e^{−46} of its peak at the outermost
        // nodes); without a box there is no edge.
        let narrow = [0.0, -0.5 / 0.04, 0.0, 0.0];
        assert!(drift.edge_mass(&narrow).unwrap().1 < 1e-15);
        let grid = onsager_closures::panel_grid(&[(-2.0, 2.0)], 12, 8).unwrap();
        let family = Exponential::polynomial(grid, onsager_closures::Reference::Lebesgue, 4).unwrap();
        assert_eq!(
            ExponentialDrift::try_new(&DoubleWell, &[0.5], family).unwrap().edge_mass(&[0.0; 4]),
            None
        );
    }

    #[test]
    fn exponential_drift_jacobian_matches_finite_differences_and_w_is_c_inverse_v() {
        let family = Exponential::quartic(-3.0, 3.0).unwrap();
        let dr = ExponentialDrift::try_new(&DoubleWell, &[0.5], family.clone()).unwrap();
        let lambda = [0.3, 1.0, -0.2, -0.8];
        let (mut w, mut jac) = ([0.0; 4], [0.0; 16]);
        dr.w_jacobian(0.0, &lambda, &mut w, &mut jac).unwrap();
        let fd = fd_jacobian(&dr, 0.0, &lambda);
        for k in 0..16 {
            assert_relative_eq!(jac[k], fd[k], epsilon = 1e-5, max_relative = 1e-5);
        }
        assert_w_is_c_inverse_v(&family, &lambda, &w);
        assert_eq!(dr.linear_index(0), Some(0));
        assert_eq!(dr.square_index(0), Some(1));
    }

    /// W, ∂W/∂λ, ∇²(κᵀW), the moments and W alone of `fast` equal those of `nodes` at λ, each
    /// to `tol` times its largest entry.
    fn assert_same_sums<S: Sde + ?Sized>(
        fast: &ExponentialDrift<S>,
        nodes: &ExponentialDrift<S>,
        lambda: &[f64],
        kappa: &[f64],
        tol: f64,
    ) {
        let r = lambda.len();
        let z = || (vec![0.0; r], vec![0.0; r * r], vec![0.0; r * r]);
        let ((mut w1, mut j1, mut h1), (mut w2, mut j2, mut h2)) = (z(), z());
        fast.w_second(0.2, lambda, kappa, &mut w1, &mut j1, &mut h1).unwrap();
        nodes.w_second(0.2, lambda, kappa, &mut w2, &mut j2, &mut h2).unwrap();
        for (what, fast, nodes) in [("W", &w1, &w2), ("J", &j1, &j2), ("H", &h1, &h2)] {
            let scale = nodes.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for (a, b) in fast.iter().zip(nodes) {
                assert!(
                    (a - b).abs() <= tol * scale,
                    "{what}: {a} vs {b} (largest entry {scale}) at {lambda:?}"
                );
            }
        }
        let (m1, m2) = (fast.moments(lambda).unwrap(), nodes.moments(lambda).unwrap());
        assert!((m1.log_partition - m2.log_partition).abs() <= tol * m2.log_partition.abs().max(1.0));
        for (what, fast, nodes) in [("mean", &m1.mean, &m2.mean), ("C", &m1.covariance, &m2.covariance)] {
            let scale = nodes.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for (a, b) in fast.iter().zip(nodes) {
                assert!((a - b).abs() <= tol * scale, "{what}: {a} vs {b} (largest entry {scale})");
            }
        }
        let mut w3 = vec![0.0; r];
        fast.w(0.2, lambda, &mut w3).unwrap();
        // The same sums with tables of another size: equal to round-off.
        let scale = w1.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (a, b) in w1.iter().zip(&w3) {
            assert!((a - b).abs() <= tol * scale, "W alone {b} is W of the Hessian's evaluation {a}");
        }
    }

    /// On nodes that follow the density, the raw-moment sums in the frame x = m + Lξ (L not
    /// diagonal: [`TensorPlan::in_frame`]) equal the node sums of [`ExponentialDrift::zeroth`]
    /// on the same nodes: W, ∂W/∂λ, ∇²(κᵀW) and the moments, on a bimodal density with its
    /// wells along the diagonal and on a narrow correlated Gaussian, each in the frame of its own
    /// mean and covariance, to round-off times the condition of C (measured: within 1e-11 of
    /// the largest entry on the bimodal density; on the narrow one, whose monomials are nearly
    /// dependent near (1, 0.8), 2e-11 on W).
    #[test]
    fn raw_moment_sums_in_a_frame_equal_the_node_sums() {
        use crate::model::library::DoubleWell2d;
        let follow = DensityNodes { degree: 4, panels: 4, width: 6.0, tolerance: 1e-4 };
        let kappa: Vec<f64> = (0..14).map(|a| ((a * 7 % 5) as f64 - 2.0) * 0.3).collect();
        let check = |lambda: &[f64], tol: f64| {
            let grid = onsager_closures::panel_grid(&[(-6.0, 6.0), (-6.0, 6.0)], 48, 8).unwrap();
            let wide = Exponential::polynomial(grid, onsager_closures::Reference::Lebesgue, 4).unwrap();
            let (mut s, mut p) = (Vec::new(), Vec::new());
            wide.node_probabilities_into(lambda, &mut s, &mut p).unwrap();
            let (mean, cov) = state_moments(wide.grid().points(), &p, 2);
            let chol = onsager_closures::cholesky(&cov, 2).unwrap();
            assert!(chol[2].abs() > 0.1 * chol[3], "the frame is not diagonal: {chol:?}");
            let drift = || {
                let family = density_family(&mean, &chol, follow.width, follow.panels, 4).unwrap();
                ExponentialDrift::following(
                    &DoubleWell2d,
                    &[0.5],
                    family,
                    (mean.clone(), chol.clone()),
                    follow,
                )
                .unwrap()
            };
            let (fast, nodes) = (drift(), drift());
            assert!(fast.nodes.borrow().tensor.is_some(), "a frame of monomials is a tensor plan");
            nodes.nodes.borrow_mut().tensor = None;
            assert_same_sums(&fast, &nodes, lambda, &kappa, tol);
            assert!(nodes.nodes.borrow().tensor.is_none(), "the nodes stayed on their frame");
        };
        let bimodal =
            [0.5, 0.0, 4.0 - 1.0 / 0.6, 2.0 / 0.6, -1.0 / 0.6, 0.0, 0.0, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0, 0.0];
        check(&bimodal, 1e-10);
        // Mean (1, 0.8), covariance 0.04·[[1, 0.6], [0.6, 1]]: precision P = 25/0.64·[[1, −0.6], [−0.6, 1]].
        let (m, q) = ([1.0, 0.8], 25.0 / 0.64);
        let (p11, p12) = (q, -0.6 * q);
        let narrow = [
            p11 * m[0] + p12 * m[1],
            p12 * m[0] + p11 * m[1],
            -0.5 * p11,
            -p12,
            -0.5 * p11,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
        ];
        check(&narrow, 1e-9);
    }

    /// In a frame, the moments that decide where the nodes move and how fine they are, from the
    /// tensor plan, equal those of the node sums on the same nodes: the state's mean and
    /// covariance ([`TensorPlan::state_moments`] against [`state_moments`]) and the moments of M
    /// on a frame of P panels ([`frame_cumulants`] against the family's cumulants), on a bimodal
    /// density in a correlated frame.
    #[test]
    fn the_frame_moments_by_the_plan_equal_the_node_sums() {
        // On the frame (m, L) of half-width `width` with `panels` panels, at the λ that
        // `lambda` gives for the family's exponents.
        fn check(
            mean: &[f64],
            chol: &[f64],
            width: f64,
            panels: usize,
            lambda: impl Fn(&[Vec<u32>]) -> Vec<f64>,
        ) {
            let family = density_family(mean, chol, width, panels, 4).unwrap();
            let lambda = lambda(family.exponents().unwrap());
            let axis = onsager_closures::quadrature::composite_gauss_legendre(
                -width,
                width,
                panels,
                POINTS_PER_PANEL,
            )
            .unwrap();
            let plan = TensorPlan::in_frame(family.exponents().unwrap(), axis.points(), mean, chol).unwrap();
            let (mut s, mut p) = (Vec::new(), Vec::new());
            family.node_probabilities_into(&lambda, &mut s, &mut p).unwrap();
            let (m1, c1) = plan.state_moments(&p);
            let (m2, c2) = state_moments(family.grid().points(), &p, mean.len());
            let (mu, cov) = frame_cumulants(&lambda, mean, chol, width, panels, 4).unwrap().unwrap();
            let c = family.cumulants(&lambda).unwrap();
            let n = mean.len();
            for (what, a, b, tol) in [
                ("state mean", &m1, &m2, 1e-13),
                ("state covariance", &c1, &c2, 1e-13),
                ("mean of M", &mu, &c.mean, 1e-10),
                ("covariance of M", &cov, &c.covariance, 1e-10),
            ] {
                let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                for (x, y) in a.iter().zip(b) {
                    assert!((x - y).abs() <= tol * scale, "{n}-D {what} on {panels} panels: {x} vs {y}");
                }
            }
        }
        let bimodal =
            [0.5, 0.0, 4.0 - 1.0 / 0.6, 2.0 / 0.6, -1.0 / 0.6, 0.0, 0.0, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0, 0.0];
        for panels in [3, 6] {
            check(&[0.1, 0.05], &[0.8, 0.0, 0.6, 0.4], 6.0, panels, |_| bimodal.to_vec());
        }
        // Three states: a bimodal correlated density in a correlated frame.
        let chol3 = [0.9, 0.0, 0.0, 0.4, 0.6, 0.0, 0.2, 0.5, 0.7];
        for panels in [2, 3] {
            check(&[0.1, 0.05, 0.0], &chol3, 5.0, panels, three_state_bimodal);
        }
    }

    /// The raw-moment sums of a fixed tensor box ([`TensorPlan`]) equal the node sums of
    /// [`ExponentialDrift::zeroth`] (the same quadrature, summed another way): W, ∂W/∂λ and
    /// ∇²(κᵀW), on a bimodal, a concentrated and a spread density (quartic) and with the
    /// sextic family, to a small multiple of round-off times the condition of C relative to each
    /// output's largest entry (measured: 1e-9 on the concentrated density, whose degree-4
    /// moments are nearly dependent on the box's nodes, ≤ 1e-11 on the others).
    #[test]
    fn raw_moment_sums_on_a_tensor_box_equal_the_node_sums() {
        use crate::model::library::DoubleWell2d;
        fn compare<S: Sde>(sde: &S, family: Exponential, lambda: &[f64], kappa: &[f64], tol: f64) {
            let fast = ExponentialDrift::try_new(sde, &[0.5], family.clone()).unwrap();
            let nodes = ExponentialDrift::try_new(sde, &[0.5], family).unwrap();
            assert!(fast.nodes.borrow().tensor.is_some(), "a box of monomials is a tensor plan");
            nodes.nodes.borrow_mut().tensor = None;
            assert_same_sums(&fast, &nodes, lambda, kappa, tol);
        }
        let box2 = |degree| {
            Exponential::polynomial(
                onsager_closures::panel_grid(&[(-3.0, 3.0), (-3.0, 3.0)], 6, 8).unwrap(),
                onsager_closures::Reference::Lebesgue,
                degree,
            )
            .unwrap()
        };
        let kappa: Vec<f64> = (0..14).map(|a| ((a * 7 % 5) as f64 - 2.0) * 0.3).collect();
        // exp(0.5x − 2(x² − 1)² − (v − x)²/0.6): two wells in x, v following x; then one narrow
        // well at (1, 0.8).
        let bimodal =
            [0.5, 0.0, 4.0 - 1.0 / 0.6, 2.0 / 0.6, -1.0 / 0.6, 0.0, 0.0, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0, 0.0];
        compare(&DoubleWell2d, box2(4), &bimodal, &kappa, 1e-10);
        let (m, v) = ([1.0, 0.8], 0.01);
        let narrow =
            [m[0] / v, m[1] / v, -0.5 / v, 0.0, -0.5 / v, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        compare(&DoubleWell2d, box2(4), &narrow, &kappa, 1e-8);
        // A spread density and the sextic family (27 moments, tables to degree 24 per axis).
        let spread: Vec<f64> = (0..14)
            .map(|a| {
                if a == 2 || a == 4 {
                    -0.3
                } else if a >= 9 {
                    -0.02
                } else {
                    0.05
                }
            })
            .collect();
        compare(&DoubleWell2d, box2(4), &spread, &kappa, 1e-11);
        let mut sextic = spread.clone();
        sextic.extend((14..27).map(|a| if a == 21 || a == 27 - 1 || a == 14 { -0.004 } else { 0.0 }));
        let kappa6: Vec<f64> = (0..27).map(|a| ((a * 7 % 5) as f64 - 2.0) * 0.3).collect();
        compare(&DoubleWell2d, box2(6), &sextic, &kappa6, 1e-11);
    }

    /// λ of the quartic family in three states (its exponents `exponents`) for the density
    /// exp(0.3x + 2x² − x⁴ − (y − 0.5x)²/0.5 − (z − y)²/0.8 − 0.1y⁴ − 0.1z⁴ + 0.05xyz): two
    /// wells in x, y and z following it, correlated.
    fn three_state_bimodal(exponents: &[Vec<u32>]) -> Vec<f64> {
        exponents
            .iter()
            .map(|e| match (e[0], e[1], e[2]) {
                (1, 0, 0) => 0.3,
                (2, 0, 0) => 2.0 - 0.25 / 0.5,
                (1, 1, 0) => 1.0 / 0.5,
                (0, 2, 0) => -1.0 / 0.5 - 1.0 / 0.8,
                (0, 1, 1) => 2.0 / 0.8,
                (0, 0, 2) => -1.0 / 0.8,
                (4, 0, 0) => -1.0,
                (0, 4, 0) | (0, 0, 4) => -0.1,
                (1, 1, 1) => 0.05,
                _ => 0.0,
            })
            .collect()
    }

    /// In three states (the quartic family, 34 moments, on Lorenz-63's drift), the raw-moment
    /// sums of a fixed tensor box and of a frame x = m + Lξ with L not diagonal equal the node
    /// sums on the same nodes: W, ∂W/∂λ, ∇²(κᵀW) and the moments, on a bimodal correlated
    /// density (measured: within 1e-11 of each output's largest entry, ∇²(κᵀW) the farthest).
    #[test]
    fn raw_moment_sums_in_three_states_equal_the_node_sums() {
        use crate::model::library::Lorenz63;
        let theta = [10.0, 28.0, 8.0 / 3.0, 1.0];
        let grid = onsager_closures::panel_grid(&[(-2.5, 2.5), (-2.5, 2.5), (-2.5, 2.5)], 2, 8).unwrap();
        let family = Exponential::polynomial(grid, onsager_closures::Reference::Lebesgue, 4).unwrap();
        let lambda = three_state_bimodal(family.exponents().unwrap());
        assert_eq!(lambda.len(), 34);
        let kappa: Vec<f64> = (0..34).map(|a| ((a * 7 % 5) as f64 - 2.0) * 0.3).collect();
        let fast = ExponentialDrift::try_new(&Lorenz63, &theta, family.clone()).unwrap();
        let nodes = ExponentialDrift::try_new(&Lorenz63, &theta, family).unwrap();
        assert!(fast.nodes.borrow().tensor.is_some(), "a 3-D box of monomials is a tensor plan");
        nodes.nodes.borrow_mut().tensor = None;
        assert_same_sums(&fast, &nodes, &lambda, &kappa, 1e-10);
        // The frame of the density's own mean and covariance (on a wider box), L not diagonal.
        let wide = onsager_closures::panel_grid(&[(-4.0, 4.0), (-4.0, 4.0), (-4.0, 4.0)], 4, 8).unwrap();
        let wide = Exponential::polynomial(wide, onsager_closures::Reference::Lebesgue, 4).unwrap();
        let (mut s, mut p) = (Vec::new(), Vec::new());
        wide.node_probabilities_into(&lambda, &mut s, &mut p).unwrap();
        let (mean, cov) = state_moments(wide.grid().points(), &p, 3);
        let chol = onsager_closures::cholesky(&cov, 3).unwrap();
        assert!(
            chol[3].abs() > 0.1 * chol[4] && chol[7].abs() > 0.1 * chol[8],
            "L is not diagonal: {chol:?}"
        );
        let follow = DensityNodes { degree: 4, panels: 2, width: 5.0, tolerance: 1e-4 };
        let drift = || {
            let family = density_family(&mean, &chol, follow.width, follow.panels, 4).unwrap();
            ExponentialDrift::following(&Lorenz63, &theta, family, (mean.clone(), chol.clone()), follow)
                .unwrap()
        };
        let (fast, nodes) = (drift(), drift());
        assert!(fast.nodes.borrow().tensor.is_some(), "a 3-D frame of monomials is a tensor plan");
        nodes.nodes.borrow_mut().tensor = None;
        assert_same_sums(&fast, &nodes, &lambda, &kappa, 1e-10);
        assert!(nodes.nodes.borrow().tensor.is_none(), "the nodes stayed on their frame");
        // Their refinement stops at about 10⁶ nodes: 96³ in 3-D.
        assert_eq!([1, 2, 3].map(max_density_panels), [32, 32, 12]);
        assert_eq!(
            [0, 1, 2, 3, 4].map(ExponentialFamily::max_degree),
            [None, Some(12), Some(6), Some(4), None]
        );
    }

    /// Nodes that follow the density: after an evaluation at a density far from the prior's
    /// frame (a bimodal quartic density of the two-state double well), the frame has moved to
    /// it, and W agrees with W on a fine fixed box to the node tolerance; at that λ (the frame
    /// settled), ∂W/∂λ by the closed form equals central differences of W.
    #[test]
    fn exponential_drift_on_nodes_that_follow_the_density() {
        use crate::model::library::DoubleWell2d;
        let lambda = [
            -1.43, -1.72, 2.92, 0.82, -1.15, 0.31, 0.18, 0.04, 0.0035, -1.67, -0.038, 0.0027, 0.0014,
            0.000_12,
        ];
        let follow = DensityNodes { degree: 4, panels: 3, width: 6.0, tolerance: 1e-4 };
        let chol = [0.2, 0.0, 0.0, 0.2];
        let family = density_family(&[-1.0, -1.0], &chol, 6.0, 3, 4).unwrap();
        let dr = ExponentialDrift::following(
            &DoubleWell2d,
            &[0.5],
            family,
            (vec![-1.0, -1.0], chol.to_vec()),
            follow,
        )
        .unwrap();
        let (mut w, mut jac) = ([0.0; 14], [0.0; 196]);
        dr.w_jacobian(0.0, &lambda, &mut w, &mut jac).unwrap();
        let moved = dr.nodes.borrow().frame.clone().unwrap();
        // Within the frame drift (half a standard deviation, sd_x ≈ 0.49) of the density's mean.
        assert!((moved.mean[0] + 0.788).abs() < 0.25, "frame centre {:?}", moved.mean);
        let fixed = Exponential::polynomial(
            onsager_closures::panel_grid(&[(-8.0, 8.0), (-8.0, 8.0)], 40, 8).unwrap(),
            onsager_closures::Reference::Lebesgue,
            4,
        )
        .unwrap();
        let reference = ExponentialDrift::try_new(&DoubleWell2d, &[0.5], fixed).unwrap();
        let mut w_ref = [0.0; 14];
        reference.w(0.0, &lambda, &mut w_ref).unwrap();
        let scale = w_ref.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        // The node tolerance 1e-4 bounds the moments' errors; W = C⁻¹V amplifies them to about
        // 1e-3 of W's largest entry.
        for (a, b) in w.iter().zip(&w_ref) {
            assert!((a - b).abs() <= 5e-3 * scale, "{a} vs {b} (largest entry {scale})");
        }
        let fd = fd_jacobian(&dr, 0.0, &lambda);
        assert_eq!(dr.nodes.borrow().frame.as_ref().unwrap().mean, moved.mean, "the frame stays");
        let scale = jac.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (a, b) in jac.iter().zip(&fd) {
            assert!((a - b).abs() <= 1e-6 * scale, "{a} vs {b} (largest entry {scale})");
        }
    }

    /// A sweep starts on the initial density's frame, wherever the last sweep left the nodes:
    /// from a frame that followed the density to (2, 2), the prior N((−1, −1), 0.2²I) piles up
    /// on the frame's corner and the moves from there do not reach it; after
    /// [`ClosureDrift::start_sweep`] W at the prior is that of a fresh drift.
    #[test]
    fn a_sweep_starts_on_the_initial_frame() {
        use crate::model::library::DoubleWell2d;
        // A Gaussian of mean (m, m) and sd 0.2 per state, in the family's order x, y, x², xy, y², ….
        let gaussian = |m: f64| {
            let mut l = [0.0; 14];
            (l[0], l[1], l[2], l[4]) = (m / 0.04, m / 0.04, -0.5 / 0.04, -0.5 / 0.04);
            l
        };
        let follow = DensityNodes { degree: 4, panels: 3, width: 6.0, tolerance: 1e-4 };
        let chol = [0.2, 0.0, 0.0, 0.2];
        let drift = || {
            let family = density_family(&[-1.0, -1.0], &chol, 6.0, 3, 4).unwrap();
            ExponentialDrift::following(
                &DoubleWell2d,
                &[0.5],
                family,
                (vec![-1.0, -1.0], chol.to_vec()),
                follow,
            )
            .unwrap()
        };
        let (dr, fresh) = (drift(), drift());
        let mut w = [0.0; 14];
        for step in 0..=30 {
            dr.w(0.0, &gaussian(-1.0 + 0.1 * f64::from(step)), &mut w).unwrap();
        }
        let centre = dr.nodes.borrow().frame.as_ref().unwrap().mean.clone();
        assert!(centre.iter().all(|c| (c - 2.0).abs() < 0.1), "the frame followed to {centre:?}");
        assert!(dr.w(0.0, &gaussian(-1.0), &mut w).is_err(), "the far frame does not find the prior");
        dr.start_sweep();
        let mut w_fresh = [0.0; 14];
        dr.w(0.0, &gaussian(-1.0), &mut w).unwrap();
        fresh.w(0.0, &gaussian(-1.0), &mut w_fresh).unwrap();
        assert_eq!(w, w_fresh);
    }

    /// A density concentrated on a small part of a wide grid (N(1, 0.2²) on [−6, 6], 512 nodes):
    /// the drift works on the nodes of non-zero probability only (most of the grid has
    /// probability 0 under the e⁻⁵⁰ cut), and W = C⁻¹V still holds against the family's
    /// own all-node quadrature, with ∂W/∂λ and ∇²(κᵀW) against finite differences.
    #[test]
    fn the_top_form_decides_normalizability() {
        // The quartic monomials of two states, in the family's order: x, y, x², xy, y², x³, …, y⁴.
        let exps = onsager_closures::Polynomial::try_new(2, 4).unwrap().exponents().to_vec();
        let at = |terms: &[((u32, u32), f64)]| -> Vec<f64> {
            exps.iter()
                .map(|e| terms.iter().find(|((i, j), _)| e[..] == [*i, *j]).map_or(0.0, |t| t.1))
                .collect()
        };
        // −(x² + y²)² is −1 on the unit circle; with a positive quadratic part it still decides.
        let ring = at(&[((4, 0), -1.0), ((2, 2), -2.0), ((0, 4), -1.0), ((2, 0), 5.0)]);
        assert!((top_form_max(&exps, &ring) + 1.0).abs() < 1e-12);
        // x⁴ − 2y⁴ reaches 1 at (1, 0): not normalizable.
        assert!((top_form_max(&exps, &at(&[((4, 0), 1.0), ((0, 4), -2.0)])) - 1.0).abs() < 1e-12);
        // An odd top degree (x³, the quartic terms zero) is never normalizable.
        assert!(top_form_max(&exps, &at(&[((3, 0), -0.5), ((0, 2), -1.0)])) > 0.0);
        // A Gaussian: the quadratic terms decide.
        assert!(top_form_max(&exps, &at(&[((2, 0), -0.5), ((1, 1), 0.3), ((0, 2), -0.5)])) < 0.0);
        // One state: the sign of the top coefficient, and the parity of its degree.
        let one = onsager_closures::Polynomial::try_new(1, 4).unwrap().exponents().to_vec();
        assert_eq!(top_form_max(&one, &[0.0, 1.0, 0.0, -2.0]), -2.0);
        assert_eq!(top_form_max(&one, &[0.0, -1.0, 0.5, 0.0]), 0.5);
    }

    #[test]
    fn exponential_drift_on_the_nodes_with_mass_of_a_concentrated_density() {
        let family = Exponential::quartic(-6.0, 6.0).unwrap();
        let (m, v) = (1.0, 0.04);
        let lambda = [m / v, -0.5 / v, 0.0, 0.0];
        let p = family.node_probabilities(&lambda).unwrap().0;
        let zero = p.iter().filter(|&&pk| pk == 0.0).count();
        assert!(zero > p.len() / 2, "{zero} of {} nodes have probability 0", p.len());
        let dr = ExponentialDrift::try_new(&DoubleWell, &[0.5], family.clone()).unwrap();
        let (mut w, mut jac) = ([0.0; 4], [0.0; 16]);
        dr.w_jacobian(0.0, &lambda, &mut w, &mut jac).unwrap();
        assert_w_is_c_inverse_v(&family, &lambda, &w);
        // ∂W/∂λ and ∇²(κᵀW) against fourth-order central differences, relative to their
        // largest entries (the small entries are below the differences' round-off at these λ).
        let kappa = [0.5, -0.25, 0.1, 0.8];
        let (mut w2, mut j2, mut hess) = ([0.0; 4], [0.0; 16], [0.0; 16]);
        dr.w_second(0.0, &lambda, &kappa, &mut w2, &mut j2, &mut hess).unwrap();
        let at = |j: usize, dl: f64| {
            let (mut l, mut w, mut jac) = (lambda, [0.0; 4], [0.0; 16]);
            l[j] += dl;
            dr.w_jacobian(0.0, &l, &mut w, &mut jac).unwrap();
            (w, jac)
        };
        let (mut fd_j, mut fd_h) = ([0.0; 16], [0.0; 16]);
        for j in 0..4 {
            let h = 1e-4 * (1.0 + lambda[j].abs());
            let pts = [(2.0, -1.0), (1.0, 8.0), (-1.0, -8.0), (-2.0, 1.0)].map(|(s, c)| (at(j, s * h), c));
            for i in 0..4 {
                fd_j[i * 4 + j] = pts.iter().map(|((w, _), c)| c * w[i]).sum::<f64>() / (12.0 * h);
                fd_h[i * 4 + j] = pts
                    .iter()
                    .map(|((_, jac), c)| c * (0..4).map(|a| kappa[a] * jac[a * 4 + i]).sum::<f64>())
                    .sum::<f64>()
                    / (12.0 * h);
            }
        }
        for (exact, fd) in [(&jac, &fd_j), (&hess, &fd_h)] {
            let scale = exact.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for (a, b) in exact.iter().zip(fd) {
                assert!((a - b).abs() <= 1e-6 * scale, "{a} vs {b} (largest entry {scale})");
            }
        }
        assert_eq!(j2, jac);
    }
}
