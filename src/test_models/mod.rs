//! Shared test fixtures: the models and data sets the tests, examples and benchmarks use, so that
//! each is written once, with its equations and its known answers beside it (diffsol's
//! `ode_solver::test_models` is the model).
//!
//! Models (each a unit struct implementing [`Sde`](crate::model::Sde) with the required methods
//! only, so every derivative of it comes by automatic differentiation); where a test needs a
//! built-in model of [`model::library`](crate::model::library) it uses that one:
//!
//! | fixture | equations | known answers |
//! |---|---|---|
//! | [`LinearOscillator`] | dV = (−kV − cQ + u) dt + σ dW, dQ = V dt | exact Kalman/RTS (linear, with a clean state) |
//! | [`UnscaledDoubleWell`] | dX = (X − X³) dt + σ dW | strong orders 1 (Euler–Maruyama) and 1.5 (Itô–Taylor) |
//! | [`UnforcedDuffing`] | dV = (−Q³ + Q − 0.2V) dt + σ dW, dQ = V dt | Itô–Taylor strong order 2 (drift linear in V) |
//! | [`CubicDampedDuffing`] | dV = (−Q³ + Q − 0.2V − V³) dt + σ dW, dQ = V dt | strong orders 1 and 1.5, with a clean state |
//! | [`TwoNoisyOneClean`] | two noisy states, a clean one, t-dependent, full G | one Itô–Taylor step = its formula from Jacobians |
//! | [`DampedRotation`] | dX = AX dt + 0.5 dW, A = [[−1, 0.5], [−0.5, −1]] | Gaussian smoothing laws; stationary Σ = 0.125 I |
//! | [`RotationWithPosition`] | [`DampedRotation`] and dZ = X₁ dt (three states, one clean) | exact Kalman/RTS |
//! | [`RotationWithLag`] | [`DampedRotation`] and dX₃ = (X₁ − X₃) dt + 0.5 dW₃ (three noisy states) | exact Kalman/RTS |
//!
//! Data sets (each owning what an [`EstimationProblem`](crate::estimate::EstimationProblem)
//! borrows, with a `problem()` method):
//!
//! | fixture | what | reference |
//! |---|---|---|
//! | [`OscillatorRecord`] | [`LinearOscillator`] on [0, 4], q measured every 0.2, one datum missing | exact Kalman/RTS |
//! | [`RotationRecord`] | [`RotationWithPosition`] on [0, 4], x₂ and z measured every 0.25, one datum missing | [`RotationRecord::rts`] |
//! | [`LagRecord`] | [`RotationWithLag`] on [0, 0.5 n], x₁ and x₃ measured every 0.5 | [`LagRecord::rts`] |
//! | [`OuRecord`] | [`Ou`](crate::model::library::Ou) (θ = 1, σ = 0.5) on [0, 5], y ~ N(x, 0.2²) every 0.5 | [`OuRecord::rts`] |
//! | [`DoubleWellRecord`] | [`DoubleWell`](crate::model::library::DoubleWell) (D = 0.5), y ~ N(x, 0.2²) at given times | the exact grid estimators |
//! | [`PresetRecord`] | any preset simulated and measured with its own settings | per model |
//! | [`van_der_pol_student_t`] | the Van der Pol problem of `001_8aefdf0570c96f51.txt` Sec. 9 | convergence of the MAP paths |
//! | [`cosine_data`] | y(t) = a cos(1.3 t) + b, deterministic | identities that hold for any data |
//!
//! Model files ([`MODEL_FILES`]): the files of `examples/models/`, one twin per built-in model
//! (the same model, priors, measurements and defaults, so the same numbers), the pendulum of
//! `docs/models.md` and the three-state double well of `docs/closures.md`, each with the name
//! it declares.
//!
//! Every simulated record draws all its random numbers from one seeded `StdRng`, so its numbers
//! are fixed for a given version of `rand`.

mod models;
mod records;

/// The model files of `examples/models/` as (declared name, text): a twin of every built-in model
/// (same name, model and defaults as [`preset`](crate::model::library::preset) of that name), in
/// the order of [`NAMES`](crate::model::library::NAMES), then `pendulum` and `double-well-3d`
/// (no built-in twin).
pub const MODEL_FILES: &[(&str, &str)] = &[
    ("ou", include_str!("../../examples/models/ou.toml")),
    ("tanh", include_str!("../../examples/models/tanh.toml")),
    ("van-der-pol", include_str!("../../examples/models/van-der-pol.toml")),
    ("duffing", include_str!("../../examples/models/duffing.toml")),
    ("holmes-rand", include_str!("../../examples/models/holmes-rand.toml")),
    ("double-well", include_str!("../../examples/models/double-well.toml")),
    ("double-well-2d", include_str!("../../examples/models/double-well-2d.toml")),
    ("lorenz63", include_str!("../../examples/models/lorenz63.toml")),
    ("lorenz96", include_str!("../../examples/models/lorenz96.toml")),
    ("pendulum", include_str!("../../examples/models/pendulum.toml")),
    ("double-well-3d", include_str!("../../examples/models/double-well-3d.toml")),
];

/// The preset of the model file called `name` in [`MODEL_FILES`]. Errors:
/// [`Error::UnknownName`](crate::Error::UnknownName) for another name, and those of
/// [`Preset::from_toml_str`](crate::model::library::Preset::from_toml_str).
pub fn model_file(name: &str) -> crate::Result<crate::model::library::Preset> {
    let (_, text) =
        MODEL_FILES.iter().find(|(n, _)| *n == name).ok_or_else(|| crate::Error::UnknownName {
            kind: "model file".into(),
            name: name.into(),
            known: MODEL_FILES.iter().map(|(n, _)| n.to_string()).collect(),
        })?;
    crate::model::library::Preset::from_toml_str(text, &format!("examples/models/{name}.toml"))
}

pub use models::{
    CubicDampedDuffing, DampedRotation, LinearOscillator, RotationWithLag, RotationWithPosition,
    TwoNoisyOneClean, UnforcedDuffing, UnscaledDoubleWell,
};
pub use records::{
    cosine_data, gaussian_measurement, van_der_pol_student_t, DoubleWellRecord, LagRecord, OscillatorRecord,
    OuRecord, PresetRecord, RotationRecord, Start,
};
