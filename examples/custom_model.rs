//! Writing your own model: a damped pendulum driven by noise, with a noisy angular velocity
//! and a clean (noise-free) angle, implementing `onsager::model::Sde`.
//!
//! Run with `cargo run --release --example custom_model`.

use onsager::model::library::preset;
use onsager::model::{Dims, Scalar, Sde};

/// A damped pendulum in the model class dX = f dt + G dW, dZ = h dt:
///
/// dω = (−(g/l) sin φ − c ω) dt + σ dW,   dφ = ω dt,
///
/// with noisy state x = (ω), clean state z = (φ) and parameters θ = (g_over_l, c, sigma).
struct Pendulum;

impl Sde for Pendulum {
    fn dims(&self) -> Dims {
        Dims { noisy: 1, clean: 1, params: 3 }
    }

    fn noisy_names(&self) -> Vec<String> {
        vec!["omega".into()]
    }

    fn clean_names(&self) -> Vec<String> {
        vec!["phi".into()]
    }

    fn param_names(&self) -> Vec<String> {
        vec!["g_over_l".into(), "c".into(), "sigma".into()]
    }

    // Written once, generic over the scalar D: f64 or a dual number.
    fn drift<D: Scalar>(&self, _t: D, x: &[D], z: &[D], theta: &[D], out: &mut [D]) {
        let (omega, phi) = (x[0], z[0]);
        let (g_over_l, c) = (theta[0], theta[1]);
        out[0] = -g_over_l * phi.sin() - c * omega;
    }

    fn clean_drift<D: Scalar>(&self, _t: D, x: &[D], _z: &[D], _theta: &[D], out: &mut [D]) {
        out[0] = x[0];
    }

    // G(θ), noisy × noisy, column-major.
    fn diffusion<D: Scalar>(&self, theta: &[D], out: &mut [D]) {
        out[0] = theta[2];
    }
}

fn main() -> onsager::Result<()> {
    let model = Pendulum;
    let theta = [9.81, 0.5, 0.2];
    let (t, x, z) = (0.0, [0.3], [1.0]);

    // G must be square and invertible at θ.
    let g = model.diffusion_matrix(&theta)?;
    println!("G = {}", g[(0, 0)]);

    // f and its derivatives by automatic differentiation (1 × 1 matrices here).
    let f = model.drift_jacobians(t, &x, &z, &theta);
    println!("f = {:.6}", f.value[0]);
    println!("df/domega = {:.6} (closed form -c = {})", f.dx[(0, 0)], -theta[1]);
    println!("df/dphi = {:.6} (closed form -g/l cos phi = {:.6})", f.dz[(0, 0)], -theta[0] * z[0].cos());
    println!("df/dtheta = {:.6?}", f.dtheta.iter().collect::<Vec<_>>());
    let h = model.clean_drift_jacobians(t, &x, &z, &theta);
    println!("h = {}, dh/domega = {}", h.value[0], h.dx[(0, 0)]);

    // The Onsager–Machlup correction div_x f (here -c), with its gradient in (x, z, θ).
    let div = model.divergence_derivatives(t, &x, &z, &theta);
    println!("div f = {} (closed form -c = {})", div.value, -theta[1]);
    println!("grad div f = {:?}", div.gradient);

    // The noise energy ½|G⁻¹(ẋ − f)|² of a local velocity ẋ, with derivatives in (ẋ, x, z, θ).
    let xdot = [f.value[0] + 0.1];
    if let Some(e) = model.noise_energy_derivatives(t, &xdot, &x, &z, &theta) {
        println!(
            "noise energy = {:.6} (closed form ½(0.1/sigma)² = {:.6})",
            e.value,
            0.5 * (0.1 / theta[2]).powi(2)
        );
        println!("gradient = {:.6?}", e.gradient);
    }

    // Built-in models come from the registry, with their defaults and sources.
    let duffing = preset("duffing")?;
    println!("{}: {} [{}]", duffing.name, duffing.description, duffing.source);
    println!("parameters {:?} = {:?}", duffing.param_names(), duffing.theta);
    Ok(())
}
