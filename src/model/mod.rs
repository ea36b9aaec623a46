//! SDE models, measurement models and priors.
//!
//! A model is written once, generic over the scalar [`Scalar`] (an `f64` or a dual number of
//! `num-dual`), with the parameter vector θ passed as an argument. Everything a solver needs in
//! `f64` — Jacobians, the divergence div_x f, parameter derivatives, second derivatives of the
//! divergence and of the noise energy — comes from the same code by automatic
//! differentiation (see [`ad`]).
//!
//! The model class is that of `000_74b95e149527c64e.txt (2.4)`:
//!
//! $$ dX_t = f(t, X_t, Z_t, \theta)\,dt + G(\theta)\,dW_t, \qquad dZ_t = h(t, X_t, Z_t, \theta)\,dt, $$
//!
//! with *noisy* states X (G square and invertible) and *clean* states Z (no noise). Eyink's
//! diffusion matrix is D = ½ G Gᵀ (`003_d2fc48a470e528fc.txt`).

pub mod ad;
pub mod expression;
pub mod library;
pub mod observation;
pub mod prior;
pub mod special;

pub use observation::{Noise, Observation, Param, StateMeasurement};
pub use prior::{Prior, PriorDensity};

use nalgebra::DMatrix;
use num_dual::Dual;

use crate::{Error, Result};
use ad::{ScalarFn, VectorFn};

/// The scalar every model method is generic over: `f64` or a (nested) dual number of
/// `num-dual` whose primitive is `f64`.
pub trait Scalar: num_dual::DualNum<Primitive = f64> + Copy {}
impl<T: num_dual::DualNum<Primitive = f64> + Copy> Scalar for T {}

/// The dimensions of a model: noisy states, clean states, parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dims {
    /// Number of noisy states x (the size of G).
    pub noisy: usize,
    /// Number of clean states z.
    pub clean: usize,
    /// Number of parameters θ (dynamics and measurement parameters share one vector).
    pub params: usize,
}

impl Dims {
    /// Number of states, noisy and clean.
    pub fn states(&self) -> usize {
        self.noisy + self.clean
    }
}

/// A stochastic differential equation with noisy and clean states,
/// `000_74b95e149527c64e.txt (2.4)`:
///
/// $$ dX = f(t, X, Z, \theta)\,dt + G(\theta)\,dW, \qquad dZ = h(t, X, Z, \theta)\,dt. $$
///
/// Implement [`Sde::dims`], the names, [`Sde::drift`], [`Sde::diffusion`] and, when the model
/// has clean states, [`Sde::clean_drift`]; every derivative is provided.
pub trait Sde {
    /// Numbers of noisy states, clean states and parameters.
    fn dims(&self) -> Dims;

    /// Names of the noisy states x.
    fn noisy_names(&self) -> Vec<String>;

    /// Names of the clean states z (none by default).
    fn clean_names(&self) -> Vec<String> {
        Vec::new()
    }

    /// Names of the parameters θ, in order.
    fn param_names(&self) -> Vec<String>;

    /// The noisy drift, `out = f(t, x, z, θ)` (length `dims().noisy`).
    fn drift<D: Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D], out: &mut [D]);

    /// The clean drift, `out = h(t, x, z, θ)` (length `dims().clean`). The default is for
    /// models without clean states.
    fn clean_drift<D: Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D], out: &mut [D]) {
        let _ = (t, x, z, theta);
        debug_assert!(out.is_empty(), "a model with clean states must implement clean_drift");
    }

    /// The noise matrix G(θ), `noisy × noisy`, column-major.
    fn diffusion<D: Scalar>(&self, theta: &[D], out: &mut [D]);

    /// Whether θ_i may enter the drifts f and h (and so div_x f). The default, `true` for
    /// every parameter, is always correct; a model returns `false` for a parameter used only by
    /// G or by the measurements, so that a transcription leaves the (zero) derivatives of the
    /// dynamics with respect to it out of its automatic differentiation. The built-in models'
    /// answers are tested against the derivatives of the drifts.
    fn drift_uses_param(&self, i: usize) -> bool {
        let _ = i;
        true
    }

    /// The first and second derivatives of f, h and div_x f at (t, x, z, θ) in closed form,
    /// written into `out` (see [`DriftDerivatives`]; outputs numbered f, then h, then div_x f,
    /// inputs w = (x, z, θ)). Returns `false`, writing nothing, when the model has no closed
    /// form (the default): a caller then differentiates [`Sde::drift`], [`Sde::clean_drift`]
    /// and [`Sde::divergence`] automatically. The built-in models override it (the
    /// transcriptions' per-point derivatives, `000_74b95e149527c64e.txt (2.49)`), tested against
    /// that automatic differentiation.
    fn drift_derivatives(
        &self,
        t: f64,
        x: &[f64],
        z: &[f64],
        theta: &[f64],
        out: &mut DriftDerivatives,
    ) -> bool {
        let _ = (t, x, z, theta, out);
        false
    }

    /// The total degree d of the state drift [f; h](t, x, z, θ) as a polynomial in the state
    /// s = (x, z), the same d for every t and θ (a bound: a term of degree d may vanish for
    /// some θ), or `None` when the drift is not a polynomial in the state (the default).
    ///
    /// Used by the Gaussian closures to choose their quadrature: their averages ⟨f⟩ and
    /// ⟨f (s − m)ᵀ⟩ over N(m, Σ) (`003_d2fc48a470e528fc.txt (II.3)`) are then averages of
    /// polynomials of degree ≤ d + 1, which a Gauss–Hermite rule of ⌊(d + 1)/2⌋ + 1 points per
    /// dimension integrates exactly, instead of the 16 / 8 / 5 points of the general rule
    /// (see `docs/closures.md`). **A wrong declaration gives wrong closure averages** with no
    /// error (a degree below the true one drops the higher moments of the drift); `None`, the
    /// default, is always correct. The built-in models' declarations are tested against their
    /// drifts.
    fn drift_polynomial_degree(&self) -> Option<usize> {
        None
    }

    /// Whether the state drift [f; h](t, x, z, θ) does not depend on t (an autonomous model),
    /// for every x, z and θ.
    ///
    /// Used by the two-state exponential closure on its fixed box: the drift at the box's nodes
    /// is then evaluated once per estimate instead of at every Runge–Kutta stage (see
    /// `docs/closures.md`). **A wrong `true` gives wrong closure drifts** with no error (the
    /// values at the first evaluation's t serve for every t); `false`, the default, is always
    /// correct. The built-in models' declarations are tested against their drifts.
    fn drift_is_autonomous(&self) -> bool {
        false
    }

    // ----- provided methods -------------------------------------------------------------

    /// Names of all states: noisy then clean.
    fn state_names(&self) -> Vec<String> {
        let mut names = self.noisy_names();
        names.extend(self.clean_names());
        names
    }

    /// The drift of the full state s = [x; z]: `out = [f(t, x, z, θ); h(t, x, z, θ)]`
    /// (length `dims().states()`).
    fn state_drift<D: Scalar>(&self, t: D, s: &[D], theta: &[D], out: &mut [D]) {
        let noisy = self.dims().noisy;
        let (x, z) = s.split_at(noisy);
        let (f, h) = out.split_at_mut(noisy);
        self.drift(t, x, z, theta, f);
        self.clean_drift(t, x, z, theta, h);
    }

    /// The divergence of the noisy drift with respect to the noisy states,
    /// $\operatorname{div}_x f = \sum_i \partial f_i / \partial x_i$
    /// (the Onsager–Machlup correction, `000_74b95e149527c64e.txt (2.49)`), generic so that
    /// its own derivatives are available. The default is [`ad_divergence`] (one nested dual
    /// pass of the drift per noisy state); a model with a closed form may override it (the
    /// built-in models do, tested against [`ad_divergence`]).
    fn divergence<D: Scalar>(&self, t: D, x: &[D], z: &[D], theta: &[D]) -> D {
        ad_divergence(self, t, x, z, theta)
    }

    /// The noise energy of a local velocity `xdot` of the noisy states,
    /// $\tfrac12 \lvert G(\theta)^{-1}(\dot x - f(t, x, z, \theta))\rvert^2$, the integrand of the
    /// energy functional (`000_74b95e149527c64e.txt (2.49)`, `(2.60)`). Returns `None` when
    /// G(θ) is singular.
    fn noise_energy<D: Scalar>(&self, t: D, xdot: &[D], x: &[D], z: &[D], theta: &[D]) -> Option<D> {
        let n = x.len();
        let mut g = vec![D::from(0.0); n * n];
        self.diffusion(theta, &mut g);
        let mut r = vec![D::from(0.0); n];
        self.drift(t, x, z, theta, &mut r);
        for (ri, &vi) in r.iter_mut().zip(xdot) {
            *ri = vi - *ri;
        }
        ad::lu_solve_in_place(&mut g, &mut r)?;
        Some(r.iter().map(|&u| u * u).sum::<D>() * 0.5)
    }

    /// ln |det G(θ)|; `None` when G(θ) is singular or not finite.
    fn log_abs_det_diffusion<D: Scalar>(&self, theta: &[D]) -> Option<D> {
        let n = self.dims().noisy;
        let mut g = vec![D::from(0.0); n * n];
        self.diffusion(theta, &mut g);
        let mut b = vec![D::from(0.0); n];
        ad::lu_solve_in_place(&mut g, &mut b)
    }

    /// G(θ) in `f64`, checked to be finite and invertible.
    fn diffusion_matrix(&self, theta: &[f64]) -> Result<DMatrix<f64>> {
        check_len("theta", self.dims().params, theta.len())?;
        let n = self.dims().noisy;
        let mut g = vec![0.0; n * n];
        self.diffusion(theta, &mut g);
        if g.iter().any(|v| !v.is_finite()) {
            return Err(Error::SingularDiffusion { reason: "G(theta) has non-finite entries".into() });
        }
        let m = DMatrix::from_column_slice(n, n, &g);
        let mut lu = g.clone();
        let mut b = vec![0.0; n];
        match ad::lu_solve_in_place(&mut lu, &mut b) {
            Some(_) => Ok(m),
            None => Err(Error::SingularDiffusion { reason: "G(theta) is singular".into() }),
        }
    }

    /// Value and derivatives of the noisy drift f at (t, x, z, θ), in `f64`.
    fn drift_jacobians(&self, t: f64, x: &[f64], z: &[f64], theta: &[f64]) -> Jacobians {
        let n = self.dims().noisy;
        jacobians(&FieldFn { sde: self, which: Field::Noisy, n_out: n, dims: self.dims() }, t, x, z, theta)
    }

    /// Value and derivatives of the clean drift h at (t, x, z, θ), in `f64`.
    fn clean_drift_jacobians(&self, t: f64, x: &[f64], z: &[f64], theta: &[f64]) -> Jacobians {
        let n = self.dims().clean;
        jacobians(&FieldFn { sde: self, which: Field::Clean, n_out: n, dims: self.dims() }, t, x, z, theta)
    }

    /// div_x f with its gradient and Hessian with respect to w = (x, z, θ), in `f64`.
    fn divergence_derivatives(&self, t: f64, x: &[f64], z: &[f64], theta: &[f64]) -> SecondOrder {
        let d = self.dims();
        let w = concat(&[x, z, theta]);
        let (value, gradient, hessian) = ad::hessian(&DivergenceFn { sde: self, t, dims: d }, &w);
        SecondOrder { value, gradient, hessian }
    }

    /// The noise energy ½|G⁻¹(ẋ − f)|² with its gradient and Hessian with respect to
    /// w = (ẋ, x, z, θ), in `f64`. `None` when G(θ) is singular.
    fn noise_energy_derivatives(
        &self,
        t: f64,
        xdot: &[f64],
        x: &[f64],
        z: &[f64],
        theta: &[f64],
    ) -> Option<SecondOrder> {
        let d = self.dims();
        let w = concat(&[xdot, x, z, theta]);
        self.noise_energy(t, xdot, x, z, theta)?;
        let (value, gradient, hessian) = ad::hessian(&EnergyFn { sde: self, t, dims: d }, &w);
        Some(SecondOrder { value, gradient, hessian })
    }
}

/// The derivatives written by [`Sde::drift_derivatives`]: for the outputs o = 0..ns of the
/// state drift [f; h] and o = ns of div_x f, the first derivatives ∂o/∂w_i and the second
/// derivatives ∂²o/∂w_i∂w_j with respect to the inputs w = (x, z, θ) (θ in full). The caller
/// keeps a subset of the inputs (the others are dropped on writing), of the outputs (the first
/// `outputs`) and of their Hessians ([`Self::with_hessian_slots`]), and zeroes the buffers
/// before the call, so that a model adds only its nonzero derivatives; the outputs whose
/// second derivatives a model writes are recorded ([`Self::second_outputs`]), so that a
/// caller can leave out the Hessians of outputs that are linear.
#[derive(Debug)]
pub struct DriftDerivatives<'a> {
    /// For each input of w, its column among the kept inputs, or [`DriftDerivatives::DROPPED`].
    cols: &'a [usize],
    /// Number of kept inputs n.
    n: usize,
    /// Length n(n + 1)/2 of a packed Hessian.
    tri: usize,
    /// Number of kept outputs.
    outputs: usize,
    /// For each kept output, the position of its Hessian in `hess` or
    /// [`DriftDerivatives::DROPPED`]; `None`: output o at position o.
    slots: Option<&'a [usize]>,
    /// First derivatives, outputs × n, column-major.
    jac: &'a mut [f64],
    /// Second derivatives: per stored output, the packed lower triangle ([`packed_index`]) of
    /// its n × n Hessian.
    hess: &'a mut [f64],
    /// Bit o set: a second derivative of output o (o < 64) in the kept inputs was written.
    seconds: u64,
}

impl<'a> DriftDerivatives<'a> {
    /// The column of an input (or the position of a Hessian) that is not kept.
    pub const DROPPED: usize = usize::MAX;

    /// Derivatives into `jac` (`outputs × n`, column-major) and `hess` (`outputs` packed lower
    /// triangles of n(n + 1)/2 entries, column by column: [`packed_index`]), both zeroed by the
    /// caller; `cols` maps each input of w = (x, z, θ) to its column 0..n or to
    /// [`Self::DROPPED`].
    pub fn new(cols: &'a [usize], n: usize, outputs: usize, jac: &'a mut [f64], hess: &'a mut [f64]) -> Self {
        debug_assert!(jac.len() >= outputs * n);
        DriftDerivatives { cols, n, tri: n * (n + 1) / 2, outputs, slots: None, jac, hess, seconds: 0 }
    }

    /// Stores the Hessian of output o at position `slots[o]` of `hess` (its packed triangle at
    /// `slots[o] · n(n + 1)/2`), or nowhere when `slots[o]` is [`Self::DROPPED`].
    pub fn with_hessian_slots(mut self, slots: &'a [usize]) -> Self {
        self.slots = Some(slots);
        self
    }

    /// Adds `v` to ∂(output o)/∂w_i.
    #[inline(always)]
    pub fn first(&mut self, o: usize, i: usize, v: f64) {
        let c = self.cols[i];
        if o < self.outputs && c != Self::DROPPED {
            self.jac[o + c * self.outputs] += v;
        }
    }

    /// Adds `v` to ∂²(output o)/∂w_i∂w_j (i and j in either order; the entry is stored once).
    #[inline(always)]
    pub fn second(&mut self, o: usize, i: usize, j: usize, v: f64) {
        let (a, b) = (self.cols[i], self.cols[j]);
        if o >= self.outputs || a == Self::DROPPED || b == Self::DROPPED {
            return;
        }
        if o < 64 {
            self.seconds |= 1 << o;
        }
        let slot = self.slots.map_or(o, |s| s[o]);
        if slot != Self::DROPPED {
            let (r, c) = (a.max(b), a.min(b));
            self.hess[slot * self.tri + packed_index(self.n, r, c)] += v;
        }
    }

    /// The kept outputs (bit o for output o < 64) of which a second derivative in the kept
    /// inputs was written, whether or not its Hessian is stored.
    pub fn second_outputs(&self) -> u64 {
        self.seconds
    }
}

/// The position of entry (r, c), r ≥ c, of a symmetric n × n matrix in its packed lower
/// triangle, column by column: column c holds rows c..n, after the n + (n − 1) + … + (n − c + 1)
/// entries of the columns before it. The layout of [`DriftDerivatives`] and of the Lobatto-point
/// Hessians of the path transcription, where it puts the (θ, θ) part of a point's (s, θ) block,
/// the columns after the states', last and in one piece.
#[inline(always)]
pub fn packed_index(n: usize, r: usize, c: usize) -> usize {
    debug_assert!(c <= r && r < n);
    c * n - c * (c + 1) / 2 + r
}

/// div_x f of `sde` by automatic differentiation: one nested dual pass of [`Sde::drift`] per
/// noisy state, summing ∂f_i/∂x_i (`000_74b95e149527c64e.txt (2.49)`). The default of
/// [`Sde::divergence`] and the reference for closed-form overrides.
pub fn ad_divergence<S: Sde + ?Sized, D: Scalar>(sde: &S, t: D, x: &[D], z: &[D], theta: &[D]) -> D {
    let n = x.len();
    let lift = |v: &[D]| v.iter().map(|&a| Dual::from_re(a)).collect::<Vec<Dual<D>>>();
    let mut xd = lift(x);
    let (zd, td) = (lift(z), lift(theta));
    let mut out = vec![Dual::from_re(D::from(0.0)); n];
    let mut div = D::from(0.0);
    for i in 0..n {
        xd[i].eps = D::from(1.0);
        sde.drift(Dual::from_re(t), &xd, &zd, &td, &mut out);
        xd[i].eps = D::from(0.0);
        div += out[i].eps;
    }
    div
}

/// Value and first derivatives of a drift (f or h) at one point.
#[derive(Debug, Clone, PartialEq)]
pub struct Jacobians {
    /// The drift's value.
    pub value: Vec<f64>,
    /// ∂/∂x (`n_out × noisy`).
    pub dx: DMatrix<f64>,
    /// ∂/∂z (`n_out × clean`).
    pub dz: DMatrix<f64>,
    /// ∂/∂θ (`n_out × params`).
    pub dtheta: DMatrix<f64>,
    /// ∂/∂t.
    pub dt: Vec<f64>,
}

/// A scalar with its gradient and Hessian with respect to a stated vector of variables.
#[derive(Debug, Clone, PartialEq)]
pub struct SecondOrder {
    /// The value.
    pub value: f64,
    /// The gradient.
    pub gradient: Vec<f64>,
    /// The (symmetric) Hessian.
    pub hessian: DMatrix<f64>,
}

/// Returns `Error::DimensionMismatch` unless `got == expected`.
pub(crate) fn check_len(what: &str, expected: usize, got: usize) -> Result<()> {
    if expected == got {
        Ok(())
    } else {
        Err(Error::DimensionMismatch { what: what.to_string(), expected, got })
    }
}

fn concat(parts: &[&[f64]]) -> Vec<f64> {
    parts.iter().flat_map(|p| p.iter().copied()).collect()
}

#[derive(Clone, Copy)]
enum Field {
    Noisy,
    Clean,
}

/// (t, x, z, θ) ↦ f or h, as a [`VectorFn`] of w = (t, x, z, θ).
struct FieldFn<'a, S: ?Sized> {
    sde: &'a S,
    which: Field,
    n_out: usize,
    dims: Dims,
}

impl<S: Sde + ?Sized> VectorFn for FieldFn<'_, S> {
    fn dim_in(&self) -> usize {
        1 + self.dims.states() + self.dims.params
    }
    fn dim_out(&self) -> usize {
        self.n_out
    }
    fn eval<D: Scalar>(&self, w: &[D], out: &mut [D]) {
        let (n, c) = (self.dims.noisy, self.dims.clean);
        let (t, x, z, th) = (w[0], &w[1..1 + n], &w[1 + n..1 + n + c], &w[1 + n + c..]);
        match self.which {
            Field::Noisy => self.sde.drift(t, x, z, th, out),
            Field::Clean => self.sde.clean_drift(t, x, z, th, out),
        }
    }
}

fn jacobians<S: Sde + ?Sized>(f: &FieldFn<'_, S>, t: f64, x: &[f64], z: &[f64], theta: &[f64]) -> Jacobians {
    let d = f.dims;
    let w = concat(&[&[t], x, z, theta]);
    let (value, j) = ad::jacobian(f, &w);
    let m = f.n_out;
    Jacobians {
        value,
        dt: j.column(0).iter().copied().collect(),
        dx: j.view((0, 1), (m, d.noisy)).into_owned(),
        dz: j.view((0, 1 + d.noisy), (m, d.clean)).into_owned(),
        dtheta: j.view((0, 1 + d.states()), (m, d.params)).into_owned(),
    }
}

struct DivergenceFn<'a, S: ?Sized> {
    sde: &'a S,
    t: f64,
    dims: Dims,
}

impl<S: Sde + ?Sized> ScalarFn for DivergenceFn<'_, S> {
    fn dim_in(&self) -> usize {
        self.dims.states() + self.dims.params
    }
    fn eval<D: Scalar>(&self, w: &[D]) -> D {
        let (n, c) = (self.dims.noisy, self.dims.clean);
        self.sde.divergence(D::from(self.t), &w[..n], &w[n..n + c], &w[n + c..])
    }
}

struct EnergyFn<'a, S: ?Sized> {
    sde: &'a S,
    t: f64,
    dims: Dims,
}

impl<S: Sde + ?Sized> ScalarFn for EnergyFn<'_, S> {
    fn dim_in(&self) -> usize {
        2 * self.dims.noisy + self.dims.clean + self.dims.params
    }
    fn eval<D: Scalar>(&self, w: &[D]) -> D {
        let (n, c) = (self.dims.noisy, self.dims.clean);
        let (v, x, z, th) = (&w[..n], &w[n..2 * n], &w[2 * n..2 * n + c], &w[2 * n + c..]);
        self.sde.noise_energy(D::from(self.t), v, x, z, th).unwrap_or(D::from(f64::NAN))
    }
}
