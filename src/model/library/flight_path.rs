//! Flight-path reconstruction, `000_74b95e149527c64e.txt` Sec. 4.2: the rigid-body kinematics
//! of an aircraft driven by Ornstein–Uhlenbeck "jerks", measured by biased, noisy air-data,
//! attitude, rate and acceleration sensors.
//!
//! [`FlightPath`] is the SDE (6 noisy states, 16 clean states, 8 parameters),
//! [`FlightPathObservation`] the thesis's measurement likelihood (13 outputs, with `atan2` and
//! `√(u² + v² + w²)`), [`rigid_body_kinematics`] the clean drift on its own (for methods that
//! integrate the kinematics with measured inputs), and [`FlightPathSetup`] bundles them with
//! the nominal θ, the priors, the simulation settings and the start of the MAP estimators.
//!
//! The model is not in the preset registry ([`super::NAMES`]): a [`super::Preset`] carries a
//! [`StateMeasurement`](crate::model::observation::StateMeasurement), and these outputs are
//! nonlinear functions of the states. It is estimated through [`crate::path::estimate_path`],
//! which takes any [`Observation`].

use rand::Rng;

mod attas;
mod tuning;
pub use attas::{read_flight_record, read_flight_record_from, FlightColumns, Unit};
pub use tuning::{integrated_noise_intensity, noise_sd, RecordLevels, ROUGHNESS_LAG};

use super::names;
use crate::data::{Dataset, StatePath};
use crate::estimate::EstimationProblem;
use crate::model::observation::{Noise, Observation, Param};
use crate::model::prior::Prior;
use crate::model::{Dims, DriftDerivatives, Scalar, Sde};
use crate::path::{estimate_path, Laplace, Merit, PathOptions, PathSolution, Transcription};
use crate::Result;

/// Moments of inertia of a rigid aircraft, kg·m², body axes, symmetric about the x–z plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Inertia {
    /// I_x.
    pub ix: f64,
    /// I_y.
    pub iy: f64,
    /// I_z.
    pub iz: f64,
    /// I_xz.
    pub ixz: f64,
}

impl Inertia {
    /// DLR's ATTAS (VFW-Fokker 614) as in the data pre-processing of Jategaonkar, *Flight
    /// Vehicle System Identification* (the data README): I_x = 1.33367·10⁵,
    /// I_y = 2.52687·10⁵, I_z = 3.59593·10⁵, I_xz = 1.14420·10⁴ kg·m².
    pub const ATTAS: Inertia = Inertia { ix: 1.33367e5, iy: 2.52687e5, iz: 3.59593e5, ixz: 1.14420e4 };

    /// The constants C_ij of the rate equations of `000_74b95e149527c64e.txt` Sec. 4.2 (the
    /// 4th–6th rows of h). With Γ = I_x I_z − I_xz² and the normalised moments
    /// ℓ = (I_z/Γ) L, m = M/I_y, n = (I_x/Γ) N (the thesis's normalisation), Euler's equations
    /// for a body symmetric about x–z give
    ///
    /// ṗ = [I_xz(I_x − I_y + I_z)/Γ] pq + [(I_y − I_z)I_z − I_xz²]/Γ · qr + ℓ + (I_xz/I_x) n,
    /// q̇ = [(I_z − I_x)/I_y] pr + (I_xz/I_y)(r² − p²) + m,
    /// ṙ = [(I_x − I_y)I_x + I_xz²]/Γ · pq − [I_xz(I_x − I_y + I_z)/Γ] qr + (I_xz/I_z) ℓ + n.
    ///
    /// The thesis's C_13, C_23, C_33 (angular momentum of the engines) are zero here: the
    /// engines' rotor inertia is not known.
    pub fn coefficients(&self) -> MomentCoefficients {
        let Inertia { ix, iy, iz, ixz } = *self;
        let gamma = ix * iz - ixz * ixz;
        let c2 = ixz * (ix - iy + iz) / gamma;
        MomentCoefficients {
            c11: c2,
            c12: ((iy - iz) * iz - ixz * ixz) / gamma,
            c14: ixz / ix,
            c21: (iz - ix) / iy,
            c22: ixz / iy,
            c31: ((ix - iy) * ix + ixz * ixz) / gamma,
            c32: -c2,
            c34: ixz / iz,
        }
    }
}

/// The constants C_ij of the rate equations (`000_74b95e149527c64e.txt` Sec. 4.2, rows 4–6 of
/// h); see [`Inertia::coefficients`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[allow(missing_docs)]
pub struct MomentCoefficients {
    pub c11: f64,
    pub c12: f64,
    pub c14: f64,
    pub c21: f64,
    pub c22: f64,
    pub c31: f64,
    pub c32: f64,
    pub c34: f64,
}

/// Indices of the clean states z of [`FlightPath`], in the thesis's order.
pub mod state {
    /// Roll angle φ (rad).
    pub const PHI: usize = 0;
    /// Pitch angle θ (rad).
    pub const THETA: usize = 1;
    /// Yaw angle ψ (rad).
    pub const PSI: usize = 2;
    /// Roll rate p (rad/s).
    pub const P: usize = 3;
    /// Pitch rate q (rad/s).
    pub const Q: usize = 4;
    /// Yaw rate r (rad/s).
    pub const R: usize = 5;
    /// Normalised rolling moment ℓ (rad/s²).
    pub const L: usize = 6;
    /// Normalised pitching moment m (rad/s²).
    pub const M: usize = 7;
    /// Normalised yawing moment n (rad/s²).
    pub const N: usize = 8;
    /// Altitude h (m).
    pub const H: usize = 9;
    /// Body-axis velocity u (m/s).
    pub const U: usize = 10;
    /// Body-axis velocity v (m/s).
    pub const V: usize = 11;
    /// Body-axis velocity w (m/s).
    pub const W: usize = 12;
    /// Specific force a_x (m/s²), what an accelerometer at the centre of gravity reads.
    pub const AX: usize = 13;
    /// Specific force a_y (m/s²).
    pub const AY: usize = 14;
    /// Specific force a_z (m/s²).
    pub const AZ: usize = 15;
}

/// The rigid-body kinematics, the clean drift h of `000_74b95e149527c64e.txt` Sec. 4.2
/// (after Jategaonkar 2006, Eq. 10.26): `out = ż` for the clean state `z` (order of
/// [`state`]) and the jerks `jerk` = (d_x, d_y, d_z, d_ℓ, d_m, d_n):
///
/// - Euler angles: φ̇ = p + (q sin φ + r cos φ) tan θ, θ̇ = q cos φ − r sin φ,
///   ψ̇ = (q sin φ + r cos φ) sec θ;
/// - rates: Euler's equations with the constants `c` ([`Inertia::coefficients`]);
/// - moments: ℓ̇ = d_ℓ, ṁ = d_m, ṅ = d_n;
/// - altitude: ḣ = u sin θ − v cos θ sin φ − w cos θ cos φ;
/// - velocities: u̇ = −qw + rv − g sin θ + a_x, v̇ = −ru + pw + g cos θ sin φ + a_y,
///   ẇ = qu − pv + g cos θ cos φ + a_z;
/// - specific forces: ȧ_x = d_x, ȧ_y = d_y, ȧ_z = d_z.
///
/// Generic over the scalar, so that its derivatives come by automatic differentiation.
pub fn rigid_body_kinematics<D: Scalar>(c: &MomentCoefficients, g: f64, z: &[D], jerk: &[D], out: &mut [D]) {
    use state::*;
    let (phi, theta) = (z[PHI], z[THETA]);
    let (p, q, r) = (z[P], z[Q], z[R]);
    let (u, v, w) = (z[U], z[V], z[W]);
    let (sp, cp) = (phi.sin(), phi.cos());
    let (st, ct) = (theta.sin(), theta.cos());
    let qr_turn = q * sp + r * cp;
    out[PHI] = p + qr_turn * st / ct;
    out[THETA] = q * cp - r * sp;
    out[PSI] = qr_turn / ct;
    out[P] = p * q * c.c11 + q * r * c.c12 + z[L] + z[N] * c.c14;
    out[Q] = p * r * c.c21 + (r * r - p * p) * c.c22 + z[M];
    out[R] = p * q * c.c31 + q * r * c.c32 + z[L] * c.c34 + z[N];
    out[L] = jerk[3];
    out[M] = jerk[4];
    out[N] = jerk[5];
    out[H] = u * st - v * ct * sp - w * ct * cp;
    out[U] = -q * w + r * v - st * g + z[AX];
    out[V] = -r * u + p * w + ct * sp * g + z[AY];
    out[W] = q * u - p * v + ct * cp * g + z[AZ];
    out[AX] = jerk[0];
    out[AY] = jerk[1];
    out[AZ] = jerk[2];
}

/// The first and second derivatives of [`rigid_body_kinematics`] (output j of h is output 6 + j
/// of `out`; inputs w = (x, z, θ): jerk i is input i, clean state j is input 6 + j), by hand.
fn rigid_body_kinematics_derivatives(c: &MomentCoefficients, g: f64, z: &[f64], out: &mut DriftDerivatives) {
    use state::*;
    let o = |j: usize| 6 + j;
    let w = |j: usize| 6 + j;
    let (phi, th) = (z[PHI], z[THETA]);
    let (p, q, r) = (z[P], z[Q], z[R]);
    let (u, v, wv) = (z[U], z[V], z[W]);
    let (sp, cp, st, ct) = (phi.sin(), phi.cos(), th.sin(), th.cos());
    let (tt, sec) = (st / ct, 1.0 / ct);
    let a = q * sp + r * cp;
    let b = q * cp - r * sp;
    // φ̇ = p + a tan θ
    let e = o(PHI);
    out.first(e, w(P), 1.0);
    out.first(e, w(PHI), b * tt);
    out.first(e, w(THETA), a * sec * sec);
    out.first(e, w(Q), sp * tt);
    out.first(e, w(R), cp * tt);
    out.second(e, w(PHI), w(PHI), -a * tt);
    out.second(e, w(PHI), w(THETA), b * sec * sec);
    out.second(e, w(PHI), w(Q), cp * tt);
    out.second(e, w(PHI), w(R), -sp * tt);
    out.second(e, w(THETA), w(THETA), 2.0 * a * sec * sec * tt);
    out.second(e, w(THETA), w(Q), sp * sec * sec);
    out.second(e, w(THETA), w(R), cp * sec * sec);
    // θ̇ = b
    let e = o(THETA);
    out.first(e, w(PHI), -a);
    out.first(e, w(Q), cp);
    out.first(e, w(R), -sp);
    out.second(e, w(PHI), w(PHI), -b);
    out.second(e, w(PHI), w(Q), -sp);
    out.second(e, w(PHI), w(R), -cp);
    // ψ̇ = a sec θ
    let e = o(PSI);
    out.first(e, w(PHI), b * sec);
    out.first(e, w(THETA), a * sec * tt);
    out.first(e, w(Q), sp * sec);
    out.first(e, w(R), cp * sec);
    out.second(e, w(PHI), w(PHI), -a * sec);
    out.second(e, w(PHI), w(THETA), b * sec * tt);
    out.second(e, w(PHI), w(Q), cp * sec);
    out.second(e, w(PHI), w(R), -sp * sec);
    out.second(e, w(THETA), w(THETA), a * (sec * tt * tt + sec * sec * sec));
    out.second(e, w(THETA), w(Q), sp * sec * tt);
    out.second(e, w(THETA), w(R), cp * sec * tt);
    // rates
    let e = o(P);
    out.first(e, w(P), c.c11 * q);
    out.first(e, w(Q), c.c11 * p + c.c12 * r);
    out.first(e, w(R), c.c12 * q);
    out.first(e, w(L), 1.0);
    out.first(e, w(N), c.c14);
    out.second(e, w(P), w(Q), c.c11);
    out.second(e, w(Q), w(R), c.c12);
    let e = o(Q);
    out.first(e, w(P), c.c21 * r - 2.0 * c.c22 * p);
    out.first(e, w(R), c.c21 * p + 2.0 * c.c22 * r);
    out.first(e, w(M), 1.0);
    out.second(e, w(P), w(P), -2.0 * c.c22);
    out.second(e, w(P), w(R), c.c21);
    out.second(e, w(R), w(R), 2.0 * c.c22);
    let e = o(R);
    out.first(e, w(P), c.c31 * q);
    out.first(e, w(Q), c.c31 * p + c.c32 * r);
    out.first(e, w(R), c.c32 * q);
    out.first(e, w(L), c.c34);
    out.first(e, w(N), 1.0);
    out.second(e, w(P), w(Q), c.c31);
    out.second(e, w(Q), w(R), c.c32);
    // moments and specific forces: the jerks
    for (j, i) in [(L, 3), (M, 4), (N, 5), (AX, 0), (AY, 1), (AZ, 2)] {
        out.first(o(j), i, 1.0);
    }
    // ḣ = u sin θ − v cos θ sin φ − w cos θ cos φ
    let e = o(H);
    out.first(e, w(U), st);
    out.first(e, w(V), -ct * sp);
    out.first(e, w(W), -ct * cp);
    out.first(e, w(THETA), u * ct + v * st * sp + wv * st * cp);
    out.first(e, w(PHI), -v * ct * cp + wv * ct * sp);
    out.second(e, w(U), w(THETA), ct);
    out.second(e, w(V), w(THETA), st * sp);
    out.second(e, w(V), w(PHI), -ct * cp);
    out.second(e, w(W), w(THETA), st * cp);
    out.second(e, w(W), w(PHI), ct * sp);
    out.second(e, w(THETA), w(THETA), -u * st + v * ct * sp + wv * ct * cp);
    out.second(e, w(THETA), w(PHI), v * st * cp - wv * st * sp);
    out.second(e, w(PHI), w(PHI), v * ct * sp + wv * ct * cp);
    // u̇ = −qw + rv − g sin θ + a_x
    let e = o(U);
    out.first(e, w(Q), -wv);
    out.first(e, w(W), -q);
    out.first(e, w(R), v);
    out.first(e, w(V), r);
    out.first(e, w(THETA), -g * ct);
    out.first(e, w(AX), 1.0);
    out.second(e, w(Q), w(W), -1.0);
    out.second(e, w(R), w(V), 1.0);
    out.second(e, w(THETA), w(THETA), g * st);
    // v̇ = −ru + pw + g cos θ sin φ + a_y
    let e = o(V);
    out.first(e, w(R), -u);
    out.first(e, w(U), -r);
    out.first(e, w(P), wv);
    out.first(e, w(W), p);
    out.first(e, w(THETA), -g * st * sp);
    out.first(e, w(PHI), g * ct * cp);
    out.first(e, w(AY), 1.0);
    out.second(e, w(R), w(U), -1.0);
    out.second(e, w(P), w(W), 1.0);
    out.second(e, w(THETA), w(THETA), -g * ct * sp);
    out.second(e, w(THETA), w(PHI), -g * st * cp);
    out.second(e, w(PHI), w(PHI), -g * ct * sp);
    // ẇ = qu − pv + g cos θ cos φ + a_z
    let e = o(W);
    out.first(e, w(Q), u);
    out.first(e, w(U), q);
    out.first(e, w(P), -v);
    out.first(e, w(V), -p);
    out.first(e, w(THETA), -g * st * cp);
    out.first(e, w(PHI), -g * ct * sp);
    out.first(e, w(AZ), 1.0);
    out.second(e, w(Q), w(U), 1.0);
    out.second(e, w(P), w(V), -1.0);
    out.second(e, w(THETA), w(THETA), -g * ct * cp);
    out.second(e, w(THETA), w(PHI), g * st * sp);
    out.second(e, w(PHI), w(PHI), -g * ct * cp);
}

/// The flight-path model of `000_74b95e149527c64e.txt` Sec. 4.2.
///
/// Noisy states x = (d_x, d_y, d_z, d_ℓ, d_m, d_n), Ornstein–Uhlenbeck:
/// dd_i = −k_a d_i dt + σ_a dW_i (translational, i = x, y, z) and
/// dd_i = −k_m d_i dt + σ_m dW_i (rotational, i = ℓ, m, n).
/// Clean states z (16, order of [`state`]) with ż = [`rigid_body_kinematics`], the inertia
/// constants C_ij from `inertia` ([`Inertia::coefficients`]: the thesis's form with its
/// normalised moments as states, since the ATTAS inertia is known).
/// Parameters θ = (b_p, b_q, b_r, b_ax, b_ay, b_az, k_a, k_m) ([`FlightPath::PARAMS`]); the
/// biases enter the measurements only. σ_a and σ_m are known (fields), as in the thesis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlightPath {
    /// The aircraft's inertia.
    pub inertia: Inertia,
    /// σ_a, diffusion of the translational jerks (m/s³ per √s).
    pub sigma_a: f64,
    /// σ_m, diffusion of the rotational jerks (rad/s³ per √s).
    pub sigma_m: f64,
    /// Gravity g (m/s²).
    pub gravity: f64,
}

impl Default for FlightPath {
    /// ATTAS inertia, g = 9.80 m/s² (the book's value for this aircraft), σ_a = 0.1,
    /// σ_m = 10⁻³ (our choice: over 30 s they give excursions of about 0.5 m/s² in the
    /// specific forces, 0.1 rad/s in the rates and 1 rad in the attitude, while the jerks
    /// stay above the accelerometers' and gyros' noise, so that k_a and k_m are identified).
    fn default() -> Self {
        FlightPath { inertia: Inertia::ATTAS, sigma_a: 0.1, sigma_m: 1e-3, gravity: 9.80 }
    }
}

impl FlightPath {
    /// The specific forces (a_x, a_y, a_z) that make u̇ = v̇ = ẇ = 0 in
    /// [`rigid_body_kinematics`] at clean state `z` (16 values; steady flight: the forces
    /// balance gravity and the rotation of the body axes): a_x = qw − rv + g sin θ,
    /// a_y = ru − pw − g cos θ sin φ, a_z = pv − qu − g cos θ cos φ, computed as minus the
    /// kinematics' u̇, v̇, ẇ without forces, so that the sum is exactly zero.
    pub fn trim_forces(&self, z: &[f64]) -> [f64; 3] {
        use state::*;
        let mut free = z[..16].to_vec();
        free[AX..=AZ].fill(0.0);
        let mut out = [0.0; 16];
        rigid_body_kinematics(&self.inertia.coefficients(), self.gravity, &free, &[0.0; 6], &mut out);
        [-out[U], -out[V], -out[W]]
    }

    /// Parameter names, in the order of θ.
    pub const PARAMS: [&'static str; 8] = ["b_p", "b_q", "b_r", "b_ax", "b_ay", "b_az", "k_a", "k_m"];
    /// Index of the first bias (b_p) in θ; the six biases are θ[0..6].
    pub const BIASES: usize = 0;
    /// Index of k_a in θ.
    pub const K_A: usize = 6;
    /// Index of k_m in θ.
    pub const K_M: usize = 7;
    /// Noisy state names.
    pub const NOISY: [&'static str; 6] = ["d_x", "d_y", "d_z", "d_l", "d_m", "d_n"];
    /// Clean state names, in the order of [`state`].
    pub const CLEAN: [&'static str; 16] =
        ["phi", "theta", "psi", "p", "q", "r", "l", "m", "n", "h", "u", "v", "w", "a_x", "a_y", "a_z"];
}

impl Sde for FlightPath {
    fn dims(&self) -> Dims {
        Dims { noisy: 6, clean: 16, params: 8 }
    }

    fn noisy_names(&self) -> Vec<String> {
        names(&Self::NOISY)
    }

    fn clean_names(&self) -> Vec<String> {
        names(&Self::CLEAN)
    }

    fn param_names(&self) -> Vec<String> {
        names(&Self::PARAMS)
    }

    /// f = (−k_a d_x, −k_a d_y, −k_a d_z, −k_m d_ℓ, −k_m d_m, −k_m d_n), `000` Sec. 4.2.
    fn drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], theta: &[D], out: &mut [D]) {
        for i in 0..6 {
            let k = if i < 3 { theta[Self::K_A] } else { theta[Self::K_M] };
            out[i] = -k * x[i];
        }
    }

    /// h = [`rigid_body_kinematics`].
    fn clean_drift<D: Scalar>(&self, _t: D, x: &[D], z: &[D], _theta: &[D], out: &mut [D]) {
        rigid_body_kinematics(&self.inertia.coefficients(), self.gravity, z, x, out);
    }

    /// div_x f = −3 k_a − 3 k_m.
    fn divergence<D: Scalar>(&self, _t: D, _x: &[D], _z: &[D], theta: &[D]) -> D {
        -(theta[Self::K_A] + theta[Self::K_M]) * 3.0
    }

    /// f, h, div_x f and their first and second derivatives in w = (x, z, θ) in closed form
    /// (`rigid_body_kinematics_derivatives` for h), tested against automatic differentiation.
    fn drift_derivatives(
        &self,
        _t: f64,
        x: &[f64],
        z: &[f64],
        theta: &[f64],
        out: &mut DriftDerivatives,
    ) -> bool {
        for (i, &xi) in x.iter().enumerate().take(6) {
            let ik = 22 + if i < 3 { Self::K_A } else { Self::K_M };
            out.first(i, i, -theta[ik - 22]);
            out.first(i, ik, -xi);
            out.second(i, i, ik, -1.0);
        }
        rigid_body_kinematics_derivatives(&self.inertia.coefficients(), self.gravity, z, out);
        out.first(22, 22 + Self::K_A, -3.0);
        out.first(22, 22 + Self::K_M, -3.0);
        true
    }

    /// The biases enter the measurements only.
    fn drift_uses_param(&self, i: usize) -> bool {
        i == Self::K_A || i == Self::K_M
    }

    /// G = diag(σ_a, σ_a, σ_a, σ_m, σ_m, σ_m) (column-major).
    fn diffusion<D: Scalar>(&self, _theta: &[D], out: &mut [D]) {
        for (k, g) in out.iter_mut().enumerate() {
            let (row, col) = (k % 6, k / 6);
            *g = D::from(match (row == col, row < 3) {
                (false, _) => 0.0,
                (true, true) => self.sigma_a,
                (true, false) => self.sigma_m,
            });
        }
    }
}

/// A point relative to the centre of gravity, body axes (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Position {
    /// x (forward).
    pub x: f64,
    /// y (right).
    pub y: f64,
    /// z (down).
    pub z: f64,
}

/// Standard deviations of the 13 sensors' noise, in SI units (rad, rad/s, m, m/s, m/s²), in
/// the order of [`FlightPathObservation::OUTPUTS`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorSd(pub [f64; 13]);

impl Default for SensorSd {
    /// Airspeed 0.2 m/s, α and β 0.003 rad (0.17°), attitude 0.002 rad (0.11°), altitude
    /// 0.5 m, rates 0.002 rad/s (0.11°/s), accelerations 0.05 m/s²: our choice for synthetic
    /// records. A flight record's own levels: [`FlightPathSetup::for_record`].
    fn default() -> Self {
        SensorSd::grouped(0.2, 0.003, 0.002, 0.5, 0.002, 0.05)
    }
}

impl SensorSd {
    /// One sd per group of sensors: airspeed (m/s), flow angles α and β (rad), attitude
    /// φ, θ, ψ (rad), altitude (m), rates p, q, r (rad/s), accelerations (m/s²).
    pub const fn grouped(
        airspeed: f64,
        flow_angles: f64,
        attitude: f64,
        altitude: f64,
        rates: f64,
        accelerations: f64,
    ) -> SensorSd {
        let (f, a, r, c) = (flow_angles, attitude, rates, accelerations);
        SensorSd([airspeed, f, f, a, a, a, altitude, r, r, r, c, c, c])
    }

    /// The sd of each output of [`FlightPathObservation`], in the order of
    /// [`FlightPathObservation::OUTPUTS`].
    pub fn per_output(&self) -> [f64; 13] {
        self.0
    }
}

/// The measurement likelihood of `000_74b95e149527c64e.txt` Sec. 4.2: 13 independent Gaussian
/// outputs (the thesis's ln ψ_k) with means
///
/// - airspeed √(u² + v² + w²);
/// - α = atan2(w − q x_nb + p y_nb, u − r y_nb + q z_nb) and
///   β = atan2(v − p z_nb + r x_nb, u − r y_nb + q z_nb) at the nose-boom tip (x_nb, y_nb, z_nb);
/// - φ, θ, ψ, h;
/// - p + b_p, q + b_q, r + b_r;
/// - a_x + q z_as − r y_as + b_ax, a_y + r x_as − p z_as + b_ay, a_z + p y_as − q x_as + b_az at
///   the accelerometer (x_as, y_as, z_as), the thesis's lever-arm terms as printed.
///
/// The standard deviations are known ([`SensorSd`]), as in the thesis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlightPathObservation {
    /// Nose-boom tip (air-data probe).
    pub nose_boom: Position,
    /// Accelerometer.
    pub accelerometer: Position,
    /// Noise standard deviations.
    pub sd: SensorSd,
}

impl Default for FlightPathObservation {
    /// The ATTAS geometry of Jategaonkar's flight-path-reconstruction test case (data README):
    /// nose boom (13.080, −0.010, −0.027) m, accelerometer (−1.010, 0.886, 0.103) m; the
    /// default [`SensorSd`].
    fn default() -> Self {
        FlightPathObservation {
            nose_boom: Position { x: 13.080, y: -0.010, z: -0.027 },
            accelerometer: Position { x: -1.010, y: 0.886, z: 0.103 },
            sd: SensorSd::default(),
        }
    }
}

impl FlightPathObservation {
    /// Output names (the data CSV's columns), in the thesis's order.
    pub const OUTPUTS: [&'static str; 13] = [
        "v_m", "alpha_m", "beta_m", "phi_m", "theta_m", "psi_m", "h_m", "p_m", "q_m", "r_m", "ax_m", "ay_m",
        "az_m",
    ];

    /// The noise-free outputs at clean state `z` and θ, in the order of
    /// [`FlightPathObservation::OUTPUTS`].
    pub fn outputs<D: Scalar>(&self, z: &[D], theta: &[D]) -> [D; 13] {
        use state::*;
        let (nb, acc) = (self.nose_boom, self.accelerometer);
        let (p, q, r) = (z[P], z[Q], z[R]);
        let (u, v, w) = (z[U], z[V], z[W]);
        let b = &theta[FlightPath::BIASES..FlightPath::BIASES + 6];
        let u_nb = u - r * nb.y + q * nb.z;
        [
            (u * u + v * v + w * w).sqrt(),
            (w - q * nb.x + p * nb.y).atan2(u_nb),
            (v - p * nb.z + r * nb.x).atan2(u_nb),
            z[PHI],
            z[THETA],
            z[PSI],
            z[H],
            p + b[0],
            q + b[1],
            r + b[2],
            z[AX] + q * acc.z - r * acc.y + b[3],
            z[AY] + r * acc.x - p * acc.z + b[4],
            z[AZ] + p * acc.y - q * acc.x + b[5],
        ]
    }

    fn noise(sd: f64) -> Noise {
        Noise::Gaussian { sigma: Param::Fixed(sd) }
    }
}

impl Observation for FlightPathObservation {
    fn output_names(&self) -> Vec<String> {
        names(&Self::OUTPUTS)
    }

    fn output_dim(&self) -> usize {
        13
    }

    /// Σ_k ln N(y_k; mean_k, sd_k²) over the non-NaN outputs (the thesis's ln ψ_k with its
    /// constants); NaN for a `y` of the wrong length.
    fn log_likelihood<D: Scalar>(&self, _t: f64, y: &[f64], _x: &[D], z: &[D], theta: &[D]) -> D {
        if y.len() != 13 {
            return D::from(f64::NAN);
        }
        let means = self.outputs(z, theta);
        let mut total = D::from(0.0);
        for ((&yk, mean), sd) in y.iter().zip(means).zip(self.sd.per_output()) {
            if !yk.is_nan() {
                total += Self::noise(sd).log_density(yk, mean, theta);
            }
        }
        total
    }

    fn sample<R: Rng + ?Sized>(
        &self,
        _t: f64,
        _x: &[f64],
        z: &[f64],
        theta: &[f64],
        rng: &mut R,
        y: &mut [f64],
    ) {
        let means = self.outputs(z, theta);
        for ((yk, mean), sd) in y.iter_mut().zip(means).zip(self.sd.per_output()) {
            *yk = Self::noise(sd).sample(mean, theta, rng);
        }
    }
}

/// The flight-path model with everything needed to simulate and estimate it: the synthetic
/// truth, the thesis's priors, the simulation settings and the start of the estimators.
#[derive(Debug, Clone)]
pub struct FlightPathSetup {
    /// The dynamics.
    pub model: FlightPath,
    /// The measurements.
    pub observation: FlightPathObservation,
    /// θ of simulations ([`FlightPathSetup::TRUTH`] by default).
    pub theta: Vec<f64>,
    /// Priors of θ: biases N(0, σ₀²) with σ₀ = 10, k_a and k_m Gamma(shape 10, scale 1/9)
    /// (the thesis's 9 ln(k_a k_m) − 9(k_a + k_m)).
    pub theta_prior: Vec<Prior>,
    /// Priors of the initial states for estimation: N(0, σ₀²) with σ₀ = 10³ (non-informative,
    /// as the thesis's).
    pub x0_prior: Vec<Prior>,
    /// Priors of the clean initial states for estimation (as `x0_prior`).
    pub z0_prior: Vec<Prior>,
    /// Distribution of the noisy initial state in simulations.
    pub x0_sim: Vec<Prior>,
    /// Distribution of the clean initial state in simulations; for the specific forces
    /// a_x, a_y, a_z, of their offsets from [`FlightPath::trim_forces`] at the drawn state
    /// (N(0, σ²) means steady flight up to σ).
    pub z0_sim: Vec<Prior>,
    /// Final time of simulations (s); the path starts at t = 0.
    pub t_end: f64,
    /// Simulation step (s).
    pub dt: f64,
    /// Sampling interval (s), also the estimators' grid step.
    pub sample_every: f64,
}

impl Default for FlightPathSetup {
    fn default() -> Self {
        FlightPathSetup::new()
    }
}

impl FlightPathSetup {
    /// The biases of the synthetic truth: b_p = 0.002, b_q = −0.001, b_r = 0.0015 rad/s,
    /// b_ax = 0.05, b_ay = −0.03, b_az = 0.08 m/s² (our choice, a few sensor sds), and
    /// k_a = k_m = 1 (the mode of their priors).
    pub const TRUTH: [f64; 8] = [0.002, -0.001, 0.0015, 0.05, -0.03, 0.08, 1.0, 1.0];

    /// The default setup: [`FlightPath::default`], [`FlightPathObservation::default`],
    /// θ = [`FlightPathSetup::TRUTH`], 30 s at 25 Hz (the ATTAS record's length and rate),
    /// simulation step 0.004 s. Simulated initial states: jerks from their stationary laws
    /// N(0, σ²/(2k)); φ ~ N(0, 0.05²),
    /// θ ~ N(0.05, 0.02²), ψ ~ N(0, 0.1²) rad; rates N(0, 0.001²) rad/s and moments
    /// N(0, 0.001²) rad/s²; h ~ N(5000, 10²) m; u ~ N(100, 2²), v ~ N(0, 1), w ~ N(5, 1) m/s;
    /// specific forces N(0, 0.05²) m/s² about the trim values of that state
    /// ([`FlightPath::trim_forces`]): near steady flight of a transport aircraft.
    pub fn new() -> FlightPathSetup {
        let wide = |n: usize| vec![Prior::gaussian(0.0, 1e3); n];
        let n = Prior::gaussian;
        let mut theta_prior = vec![Prior::gaussian(0.0, 10.0); 6];
        theta_prior.extend([Prior::gamma(10.0, 1.0 / 9.0), Prior::gamma(10.0, 1.0 / 9.0)]);
        let (a, r) = (n(0.0, 1e-3), n(0.0, 1e-3));
        let model = FlightPath::default();
        FlightPathSetup {
            model,
            observation: FlightPathObservation::default(),
            theta: Self::TRUTH.to_vec(),
            theta_prior,
            x0_prior: wide(6),
            z0_prior: wide(16),
            x0_sim: [(model.sigma_a, FlightPath::K_A); 3]
                .into_iter()
                .chain([(model.sigma_m, FlightPath::K_M); 3])
                .map(|(sigma, k)| n(0.0, sigma / (2.0 * Self::TRUTH[k]).sqrt()))
                .collect(),
            z0_sim: vec![
                n(0.0, 0.05),
                n(0.05, 0.02),
                n(0.0, 0.1),
                r,
                r,
                r,
                a,
                a,
                a,
                n(5000.0, 10.0),
                n(100.0, 2.0),
                n(0.0, 1.0),
                n(5.0, 1.0),
                n(0.0, 0.05),
                n(0.0, 0.05),
                n(0.0, 0.05),
            ],
            t_end: 30.0,
            dt: 0.004,
            sample_every: 0.04,
        }
    }

    /// The measurement times 0, `sample_every`, … up to `t_end`.
    pub fn measurement_times(&self) -> Vec<f64> {
        let n = (self.t_end / self.sample_every + 1e-9).floor() as usize;
        (0..=n).map(|k| k as f64 * self.sample_every).collect()
    }

    /// Simulates a record: initial states from `x0_sim`, `z0_sim` (the specific forces of
    /// `z0_sim` added to [`FlightPath::trim_forces`] of the drawn state), the path by Euler–Maruyama
    /// with step `dt`, measurements at [`FlightPathSetup::measurement_times`], all from `rng`
    /// in this order. Errors: as [`crate::simulate::simulate`].
    pub fn simulate<R: Rng + ?Sized>(&self, rng: &mut R) -> Result<(StatePath, Dataset)> {
        use crate::simulate::{sample_measurements_at, simulate, SimulateOptions};
        let x0 = self.x0_sim.iter().map(|p| p.sample(rng)).collect::<Result<Vec<f64>>>()?;
        let mut z0 = self.z0_sim.iter().map(|p| p.sample(rng)).collect::<Result<Vec<f64>>>()?;
        let trim = self.model.trim_forces(&z0);
        for (k, f) in trim.into_iter().enumerate() {
            z0[state::AX + k] += f;
        }
        let options = SimulateOptions::new(0.0, self.t_end, self.dt);
        let path = simulate(&self.model, &self.theta, &x0, &z0, &options, rng)?;
        let data =
            sample_measurements_at(&self.observation, &self.theta, &path, 6, &self.measurement_times(), rng)?;
        Ok((path, data))
    }

    /// A record whose path stays in the flight envelope ([`FlightPathSetup::in_envelope`]):
    /// [`FlightPathSetup::simulate`] repeated with `rng` until its path does, at most `tries`
    /// times (at least once). The kinematics have no aerodynamic restoring forces, so an unconditioned draw
    /// can stall or fly backwards within 30 s (u through 0 makes α jump by π); the records of
    /// this method are draws of the model conditioned on the envelope.
    ///
    /// # Errors
    /// As [`FlightPathSetup::simulate`]; [`crate::Error::InvalidOption`] when no draw of
    /// `tries` stays in the envelope.
    pub fn simulate_in_envelope<R: Rng + ?Sized>(
        &self,
        rng: &mut R,
        tries: usize,
    ) -> Result<(StatePath, Dataset)> {
        for _ in 0..tries.max(1) {
            let (path, data) = self.simulate(rng)?;
            if path.values.iter().all(|row| Self::in_envelope(&row[6..])) {
                return Ok((path, data));
            }
        }
        Err(crate::Error::InvalidOption {
            name: "flight envelope".into(),
            reason: format!(
                "none of {tries} simulated records stays in the envelope; lower sigma_a or sigma_m"
            ),
        })
    }

    /// Whether clean state `z` (16 values) is away from the model's singularities: u ≥ 30 m/s and
    /// |v|, |w| ≤ u (α and β by `atan2` continuous and below 45°), |θ| ≤ 0.8 rad (tan θ and
    /// sec θ of the kinematics bounded). This is the estimators' envelope, wider than an
    /// aircraft's: it admits large sideslip, which the kinematics produce where the specific
    /// forces do not follow a turn.
    pub fn in_envelope(z: &[f64]) -> bool {
        use state::*;
        let u = z[U];
        u >= 30.0 && z[V].abs() <= u && z[W].abs() <= u && z[THETA].abs() <= 0.8
    }

    /// The estimation problem on `data` with θ starting at `theta`, estimating the θ
    /// components `estimate`, from the time of the first measurement (a flight record starts
    /// at its recorded time, not at 0; 0 without data).
    pub fn problem<'a>(
        &'a self,
        data: &'a Dataset,
        theta: &'a [f64],
        estimate: &'a [usize],
    ) -> EstimationProblem<'a, FlightPath, FlightPathObservation> {
        EstimationProblem {
            sde: &self.model,
            observation: &self.observation,
            theta,
            theta_prior: &self.theta_prior,
            estimate,
            x0_prior: &self.x0_prior,
            z0_prior: &self.z0_prior,
            data,
            t0: data.times.first().copied().unwrap_or(0.0),
            seed: 0,
            max_memory: Default::default(),
        }
    }

    /// The start of the estimators (000 Sec. 4.2: from the measurements): at each measurement
    /// time, the attitude, altitude and accelerations as measured, the rates as measured, the
    /// velocities from airspeed, α and β (u = V/√(1 + tan²α + tan²β), w = u tan α,
    /// v = u tan β), the normalised moments from the rate equations with ṗ, q̇, ṙ by central
    /// differences of the measured rates over ±2 samples, the jerks 0. Missing values are
    /// taken from the previous row (0 in the first).
    pub fn initial_path(&self, data: &Dataset) -> StatePath {
        use state::*;
        let c = self.model.inertia.coefficients();
        let n = data.times.len();
        let mut rows: Vec<Vec<f64>> = Vec::with_capacity(n);
        let mut last = [0.0; 13];
        let y: Vec<[f64; 13]> = data
            .values
            .iter()
            .map(|row| {
                for (k, v) in row.iter().enumerate().take(13) {
                    if v.is_finite() {
                        last[k] = *v;
                    }
                }
                last
            })
            .collect();
        for k in 0..n {
            let yk = &y[k];
            let mut s = vec![0.0; 22];
            let z = &mut s[6..];
            let (ta, tb) = (yk[1].tan(), yk[2].tan());
            z[U] = yk[0] / (1.0 + ta * ta + tb * tb).sqrt();
            z[W] = z[U] * ta;
            z[V] = z[U] * tb;
            z[PHI] = yk[3];
            z[THETA] = yk[4];
            z[PSI] = yk[5];
            z[H] = yk[6];
            let (p, q, r) = (yk[7], yk[8], yk[9]);
            z[P] = p;
            z[Q] = q;
            z[R] = r;
            z[AX] = yk[10];
            z[AY] = yk[11];
            z[AZ] = yk[12];
            let (lo, hi) = (k.saturating_sub(2), (k + 2).min(n - 1));
            if hi > lo {
                let dt = data.times[hi] - data.times[lo];
                let rate = |i: usize| (y[hi][i] - y[lo][i]) / dt;
                let (pd, qd, rd) = (rate(7), rate(8), rate(9));
                // ṗ − c11 pq − c12 qr = ℓ + c14 n, ṙ − c31 pq − c32 qr = c34 ℓ + n
                let e1 = pd - c.c11 * p * q - c.c12 * q * r;
                let e2 = rd - c.c31 * p * q - c.c32 * q * r;
                let det = 1.0 - c.c14 * c.c34;
                z[L] = (e1 - c.c14 * e2) / det;
                z[N] = (e2 - c.c34 * e1) / det;
                z[M] = qd - c.c21 * p * r - c.c22 * (r * r - p * p);
            }
            rows.push(s);
        }
        StatePath { names: self.model.state_names(), times: data.times.clone(), values: rows, sd: None }
    }

    /// The path-space MAP estimate of `merit` (JME: Onsager–Machlup; MEE: energy) on `data`,
    /// joint with all eight parameters, by Hermite–Simpson with step `sample_every`, started
    /// from [`FlightPathSetup::initial_path`] and θ = (0, …, 0, 1, 1) (biases zero, k at the
    /// mode of its prior), with the Laplace standard deviations of θ ([`Laplace::Parameters`]:
    /// those of the path would cost one KKT solve per node and state).
    pub fn estimate(&self, data: &Dataset, merit: Merit) -> Result<PathSolution> {
        let theta = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0];
        let estimate: Vec<usize> = (0..8).collect();
        let problem = self.problem(data, &theta, &estimate);
        let options = PathOptions::new(merit, Transcription::HermiteSimpson)
            .with_step(self.sample_every)
            .with_initial_path(self.initial_path(data))
            .with_laplace(Laplace::Parameters);
        estimate_path(&problem, options)
    }
}

/// Residuals of a reconstruction: per output of [`FlightPathObservation`], the root mean square
/// of measured minus reconstructed output and the measured range (max − min), over the
/// measurements present.
#[derive(Debug, Clone, PartialEq)]
pub struct OutputResiduals {
    /// RMS of y − ŷ per output (SI units).
    pub rms: [f64; 13],
    /// max y − min y per output (SI units).
    pub range: [f64; 13],
}

impl FlightPathSetup {
    /// The noise-free outputs ([`FlightPathObservation::outputs`]) along `path` (rows: the 6
    /// noisy then the 16 clean states) with parameters `theta`, one row per path time.
    pub fn outputs_along(&self, path: &StatePath, theta: &[f64]) -> Vec<[f64; 13]> {
        path.values.iter().map(|row| self.observation.outputs(&row[6..22], theta)).collect()
    }

    /// [`OutputResiduals`] of the reconstruction `path` with `theta` against `data`, each
    /// measurement compared with the path row at its time.
    ///
    /// # Errors
    /// [`crate::Error::InvalidOption`] if a measurement time is not a time of `path` (within
    /// 10⁻⁶ of the path's smallest spacing).
    pub fn residuals(&self, data: &Dataset, path: &StatePath, theta: &[f64]) -> Result<OutputResiduals> {
        let outputs = self.outputs_along(path, theta);
        let spacing = path.times.windows(2).map(|w| w[1] - w[0]).fold(f64::INFINITY, f64::min);
        let tol = if spacing.is_finite() { 1e-6 * spacing } else { 1e-9 };
        let (mut sum, mut count) = ([0.0; 13], [0usize; 13]);
        let (mut lo, mut hi) = ([f64::INFINITY; 13], [f64::NEG_INFINITY; 13]);
        for (t, y) in data.times.iter().zip(&data.values) {
            let k = path.times.partition_point(|&s| s < t - tol);
            if k >= path.times.len() || (path.times[k] - t).abs() > tol {
                return Err(crate::Error::InvalidOption {
                    name: "path".into(),
                    reason: format!("measurement time {t} is not a time of the reconstructed path"),
                });
            }
            for (j, &yj) in y.iter().enumerate().take(13) {
                if yj.is_finite() {
                    sum[j] += (yj - outputs[k][j]).powi(2);
                    count[j] += 1;
                    lo[j] = lo[j].min(yj);
                    hi[j] = hi[j].max(yj);
                }
            }
        }
        let rms =
            std::array::from_fn(|j| if count[j] > 0 { (sum[j] / count[j] as f64).sqrt() } else { f64::NAN });
        let range = std::array::from_fn(|j| if count[j] > 0 { hi[j] - lo[j] } else { f64::NAN });
        Ok(OutputResiduals { rms, range })
    }
}
