//! Tests of the built-in models: automatic derivatives against central finite differences for
//! every model (the argmin practice, STYLE.md), closed-form divergences, and the consistency
//! of every preset.

use approx::relative_eq;
use nalgebra::{DMatrix, DVector};
use rand::rngs::StdRng;
use rand::{Rng, RngExt, SeedableRng};

use super::*;
use crate::model::Observation;

/// Random points per model for the derivative tests.
const N_POINTS: usize = 50;
/// Relative tolerance of AD against central differences (the brief's 1e-6).
const MAX_RELATIVE: f64 = 1e-6;
/// Absolute floor of the same comparison, for derivatives that are (close to) zero: with the
/// step below, central differences carry a rounding error of order 1e-16·|φ|/h ≲ 1e-8 for
/// |φ| ≲ 1e3 and a truncation error of order h²|φ'''| ≲ 1e-8, both far below this floor.
const EPSILON: f64 = 1e-6;

/// Finite-difference step for a variable of value v: 1e-6·max(1, |v|).
fn step(v: f64) -> f64 {
    1e-6 * v.abs().max(1.0)
}

/// Central-difference derivative of the vector function `f` with respect to `w[i]`.
fn central(f: &dyn Fn(&[f64]) -> Vec<f64>, w: &[f64], i: usize) -> Vec<f64> {
    let h = step(w[i]);
    let (mut wp, mut wm) = (w.to_vec(), w.to_vec());
    wp[i] += h;
    wm[i] -= h;
    // The step actually taken (w ± h rounded to f64).
    let width = wp[i] - wm[i];
    f(&wp).iter().zip(f(&wm)).map(|(a, b)| (a - b) / width).collect()
}

/// Central-difference Jacobian (`m × n`) of `f` at `w`.
fn fd_jacobian(f: &dyn Fn(&[f64]) -> Vec<f64>, m: usize, w: &[f64]) -> DMatrix<f64> {
    let mut j = DMatrix::zeros(m, w.len());
    for i in 0..w.len() {
        for (r, v) in central(f, w, i).into_iter().enumerate() {
            j[(r, i)] = v;
        }
    }
    j
}

/// Asserts AD and FD agree entrywise under the combined absolute/relative criterion.
fn assert_close(ad: &DMatrix<f64>, fd: &DMatrix<f64>, what: &str) {
    assert_eq!(ad.shape(), fd.shape(), "{what}: shapes");
    for (k, (a, f)) in ad.iter().zip(fd.iter()).enumerate() {
        assert!(
            relative_eq!(*a, *f, epsilon = EPSILON, max_relative = MAX_RELATIVE),
            "{what}: entry {k} (column-major) AD = {a}, FD = {f}\nAD = {ad}\nFD = {fd}"
        );
    }
}

/// One random evaluation point of a model.
struct Point {
    t: f64,
    x: Vec<f64>,
    z: Vec<f64>,
    theta: Vec<f64>,
    xdot: Vec<f64>,
}

fn uniform<R: Rng + ?Sized>(rng: &mut R, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.random::<f64>()
}

/// A random point: t ∈ [0, 10]; states uniform in ±2 (±15 for Lorenz-63, whose attractor is
/// that large); each θ_i within ±50 % of its nominal value (so scale parameters stay positive
/// and G invertible); ẋ = f + G u with u uniform in ±3, a plausible local velocity.
fn random_point<R: Rng + ?Sized>(p: &Preset, rng: &mut R) -> Point {
    let d = p.dims();
    let scale = match p.name.as_str() {
        "lorenz63" => 15.0,
        "lorenz96" => 8.0,
        _ => 2.0,
    };
    let t = uniform(rng, 0.0, 10.0);
    let x: Vec<f64> = (0..d.noisy).map(|_| uniform(rng, -scale, scale)).collect();
    let z: Vec<f64> = (0..d.clean).map(|_| uniform(rng, -scale, scale)).collect();
    let theta: Vec<f64> = p.theta.iter().map(|&v| v * (1.0 + uniform(rng, -0.5, 0.5))).collect();
    let mut f = vec![0.0; d.noisy];
    p.model.drift(t, &x, &z, &theta, &mut f);
    let g = p.model.diffusion_matrix(&theta).expect("G invertible near the nominal θ");
    let u = DVector::from_fn(d.noisy, |_, _| uniform(rng, -3.0, 3.0));
    let gu = g * u;
    let xdot = f.iter().zip(gu.iter()).map(|(a, b)| a + b).collect();
    Point { t, x, z, theta, xdot }
}

/// Every preset: each built-in model followed by its twin from a model file (an expression
/// model, `crate::test_models::MODEL_FILES`), then the model files without a built-in twin.
fn every_preset() -> Vec<Preset> {
    let files = crate::test_models::MODEL_FILES;
    let mut presets = Vec::new();
    for name in NAMES {
        presets.push(preset(name).unwrap());
        presets.push(crate::test_models::model_file(name).unwrap());
    }
    for (name, _) in files.iter().filter(|(n, _)| !NAMES.contains(n)) {
        presets.push(crate::test_models::model_file(name).unwrap());
    }
    presets
}

/// Runs `check` on N_POINTS random points of every preset's model (built-in and from a file),
/// with a fixed seed per model.
fn for_every_model(check: impl Fn(&Preset, &Point)) {
    for (k, p) in every_preset().iter().enumerate() {
        let mut rng = StdRng::seed_from_u64(0x5eed + k as u64);
        for _ in 0..N_POINTS {
            let pt = random_point(p, &mut rng);
            check(p, &pt);
        }
    }
}

fn row(v: &[f64]) -> DMatrix<f64> {
    DMatrix::from_row_slice(1, v.len(), v)
}

fn concat(parts: &[&[f64]]) -> Vec<f64> {
    parts.iter().flat_map(|p| p.iter().copied()).collect()
}

/// f (or h) as a function of w = (t, x, z, θ), in f64.
fn field(p: &Preset, clean: bool) -> impl Fn(&[f64]) -> Vec<f64> + '_ {
    move |w: &[f64]| {
        let d = p.dims();
        let (n, c) = (d.noisy, d.clean);
        let (t, x, z, th) = (w[0], &w[1..1 + n], &w[1 + n..1 + n + c], &w[1 + n + c..]);
        let mut out = vec![0.0; if clean { c } else { n }];
        if clean {
            p.model.clean_drift(t, x, z, th, &mut out);
        } else {
            p.model.drift(t, x, z, th, &mut out);
        }
        out
    }
}

#[test]
fn drift_jacobians_match_central_differences() {
    for_every_model(|p, pt| {
        let d = p.dims();
        for clean in [false, true] {
            let jac = if clean {
                p.model.clean_drift_jacobians(pt.t, &pt.x, &pt.z, &pt.theta)
            } else {
                p.model.drift_jacobians(pt.t, &pt.x, &pt.z, &pt.theta)
            };
            let m = if clean { d.clean } else { d.noisy };
            let f = field(p, clean);
            let w = concat(&[&[pt.t], &pt.x, &pt.z, &pt.theta]);
            // The AD value is the f64 evaluation (same arithmetic on the real parts).
            assert_close(&row(&jac.value), &row(&f(&w)), &format!("{} value (clean: {clean})", p.name));
            let fd = fd_jacobian(&f, m, &w);
            let what = |part: &str| format!("{} d{part} of {}", p.name, if clean { "h" } else { "f" });
            assert_close(
                &DMatrix::from_column_slice(m, 1, &jac.dt),
                &fd.columns(0, 1).into_owned(),
                &what("t"),
            );
            assert_close(&jac.dx, &fd.columns(1, d.noisy).into_owned(), &what("x"));
            assert_close(&jac.dz, &fd.columns(1 + d.noisy, d.clean).into_owned(), &what("z"));
            assert_close(&jac.dtheta, &fd.columns(1 + d.states(), d.params).into_owned(), &what("theta"));
        }
    });
}

#[test]
fn divergence_matches_trace_of_finite_difference_jacobian() {
    for_every_model(|p, pt| {
        let d = p.dims();
        let f = field(p, false);
        let w = concat(&[&[pt.t], &pt.x, &pt.z, &pt.theta]);
        let fd = fd_jacobian(&f, d.noisy, &w);
        let trace: f64 = (0..d.noisy).map(|i| fd[(i, 1 + i)]).sum();
        let div = p.model.divergence(pt.t, &pt.x, &pt.z, &pt.theta);
        assert_close(&row(&[div]), &row(&[trace]), &format!("{} divergence", p.name));
    });
}

#[test]
fn divergence_derivatives_match_central_differences() {
    for_every_model(|p, pt| {
        let d = p.dims();
        let (n, c) = (d.noisy, d.clean);
        let t = pt.t;
        let div = |w: &[f64]| vec![p.model.divergence(t, &w[..n], &w[n..n + c], &w[n + c..])];
        let grad = |w: &[f64]| p.model.divergence_derivatives(t, &w[..n], &w[n..n + c], &w[n + c..]).gradient;
        let w = concat(&[&pt.x, &pt.z, &pt.theta]);
        let so = p.model.divergence_derivatives(t, &pt.x, &pt.z, &pt.theta);
        assert_close(&row(&[so.value]), &row(&div(&w)), &format!("{} divergence value", p.name));
        assert_close(&row(&so.gradient), &fd_jacobian(&div, 1, &w), &format!("{} grad div", p.name));
        let fd_hess = fd_jacobian(&grad, w.len(), &w);
        assert_close(&so.hessian, &fd_hess, &format!("{} Hessian of div", p.name));
    });
}

/// A parameter that a model declares absent from its dynamics ([`Sde::drift_uses_param`]
/// false) has zero derivatives of f, h and div_x f at random points.
#[test]
fn parameters_outside_the_dynamics_have_zero_drift_derivatives() {
    for_every_model(|p, pt| {
        let d = p.dims();
        let f = p.model.drift_jacobians(pt.t, &pt.x, &pt.z, &pt.theta);
        let h = p.model.clean_drift_jacobians(pt.t, &pt.x, &pt.z, &pt.theta);
        let div = p.model.divergence_derivatives(pt.t, &pt.x, &pt.z, &pt.theta);
        for i in (0..d.params).filter(|&i| !p.model.drift_uses_param(i)) {
            let zero = f.dtheta.column(i).iter().chain(h.dtheta.column(i).iter()).all(|&v| v == 0.0);
            assert!(zero, "{}: the drifts depend on θ_{i}", p.name);
            assert_eq!(div.gradient[d.states() + i], 0.0, "{}: div_x f depends on θ_{i}", p.name);
        }
    });
    let duffing = preset("duffing").unwrap();
    let used: Vec<bool> = (0..6).map(|i| duffing.model.drift_uses_param(i)).collect();
    assert_eq!(used, [true, true, true, true, false, false]);
}

/// ½|G⁻¹(ẋ − f)|² computed independently with nalgebra's LU (the definition,
/// `000_74b95e149527c64e.txt (2.60)`).
fn energy_reference(p: &Preset, t: f64, xdot: &[f64], x: &[f64], z: &[f64], theta: &[f64]) -> f64 {
    let n = p.dims().noisy;
    let mut f = vec![0.0; n];
    p.model.drift(t, x, z, theta, &mut f);
    let r = DVector::from_fn(n, |i, _| xdot[i] - f[i]);
    let g = p.model.diffusion_matrix(theta).unwrap();
    let u = g.lu().solve(&r).unwrap();
    0.5 * u.norm_squared()
}

#[test]
fn noise_energy_derivatives_match_central_differences() {
    for_every_model(|p, pt| {
        let d = p.dims();
        let (n, c) = (d.noisy, d.clean);
        let t = pt.t;
        let split = |w: &[f64]| -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
            (w[..n].to_vec(), w[n..2 * n].to_vec(), w[2 * n..2 * n + c].to_vec(), w[2 * n + c..].to_vec())
        };
        let energy = |w: &[f64]| {
            let (v, x, z, th) = split(w);
            vec![p.model.noise_energy(t, &v, &x, &z, &th).unwrap()]
        };
        let grad = |w: &[f64]| {
            let (v, x, z, th) = split(w);
            p.model.noise_energy_derivatives(t, &v, &x, &z, &th).unwrap().gradient
        };
        let w = concat(&[&pt.xdot, &pt.x, &pt.z, &pt.theta]);
        let so = p.model.noise_energy_derivatives(t, &pt.xdot, &pt.x, &pt.z, &pt.theta).unwrap();
        let reference = energy_reference(p, t, &pt.xdot, &pt.x, &pt.z, &pt.theta);
        assert_close(&row(&[so.value]), &row(&[reference]), &format!("{} energy value", p.name));
        assert_close(&row(&so.gradient), &fd_jacobian(&energy, 1, &w), &format!("{} grad energy", p.name));
        let fd_hess = fd_jacobian(&grad, w.len(), &w);
        assert_close(&so.hessian, &fd_hess, &format!("{} Hessian of energy", p.name));
    });
}

/// The closed-form divergence div_x f of each model, from its equations.
fn divergence_closed_form(p: &Preset, x: &[f64], z: &[f64], th: &[f64]) -> f64 {
    match p.model {
        // f = −θx.
        Model::Ou(_) => -th[Ou::THETA],
        // f = tanh x: d/dx tanh x = 1 − tanh² x.
        Model::Tanh(_) => 1.0 - x[0].tanh().powi(2),
        // 001_8aefdf0570c96f51.txt Sec. 9: div f = μ(1 − u²) (= 2(1 − u²) at μ = 2).
        Model::VanDerPol(_) => th[VanDerPol::MU] * (1.0 - x[0] * x[0]),
        // 000_74b95e149527c64e.txt (4.6): ∂f/∂x = −d.
        Model::Duffing(_) => -th[Duffing::D],
        // 000_74b95e149527c64e.txt (4.8a): ∂f/∂x = −(a + γz²).
        Model::HolmesRand(_) => -(th[HolmesRand::A] + th[HolmesRand::GAMMA] * z[0] * z[0]),
        // f = 4x − 4x³: f' = 4 − 12x².
        Model::DoubleWell(_) => 4.0 - 12.0 * x[0] * x[0],
        // f = (4x − 4x³, x − v): (4 − 12x²) + (−1).
        Model::DoubleWell2d(_) => 3.0 - 12.0 * x[0] * x[0],
        // Lorenz: −s − 1 − b.
        Model::Lorenz63(_) => -(th[Lorenz63::SIGMA] + 1.0 + th[Lorenz63::BETA]),
        // Lorenz-96: ∂f_i/∂x_i = −1.
        Model::Lorenz96(m) => -(m.states() as f64),
        // A model file: the twin's closed form; the pendulum and the 3-D double well (no twin).
        Model::Expression(_) => match preset(&p.name) {
            Ok(twin) => divergence_closed_form(&twin, x, z, th),
            Err(_) if p.name == "pendulum" => -th[1],
            // f = (4x − 4x³, x − v, v − u): (4 − 12x²) − 1 − 1.
            Err(_) if p.name == "double-well-3d" => 2.0 - 12.0 * x[0] * x[0],
            Err(_) => panic!("{}: no closed-form divergence in this test", p.name),
        },
    }
}

#[test]
fn divergence_matches_closed_forms() {
    for_every_model(|p, pt| {
        let div = p.model.divergence(pt.t, &pt.x, &pt.z, &pt.theta);
        let exact = divergence_closed_form(p, &pt.x, &pt.z, &pt.theta);
        // Same arithmetic up to a few roundings: 1e-12 relative, 1e-12 absolute.
        assert!(
            relative_eq!(div, exact, epsilon = 1e-12, max_relative = 1e-12),
            "{}: {div} vs {exact}",
            p.name
        );
    });
}

/// Every built-in model's closed-form `divergence` override equals the automatic-differentiation
/// default [`crate::model::ad_divergence`], in `f64` and through first and second derivatives
/// (hyper-dual numbers), on random points.
#[test]
fn closed_form_divergence_equals_ad_default() {
    use crate::model::ad_divergence;
    use num_dual::HyperDual64;
    for_every_model(|p, pt| {
        let (div, ad) = (
            p.model.divergence(pt.t, &pt.x, &pt.z, &pt.theta),
            ad_divergence(&p.model, pt.t, &pt.x, &pt.z, &pt.theta),
        );
        assert!(relative_eq!(div, ad, epsilon = 1e-12, max_relative = 1e-12), "{}: {div} vs {ad}", p.name);
        // Second derivatives in every pair of the variables (x, z, θ).
        let w = concat(&[&pt.x, &pt.z, &pt.theta]);
        let (n, c) = (pt.x.len(), pt.z.len());
        for i in 0..w.len() {
            for j in 0..w.len() {
                let mut wd: Vec<HyperDual64> = w.iter().map(|&v| HyperDual64::from(v)).collect();
                wd[i].eps1 = 1.0;
                wd[j].eps2 = 1.0;
                let t = HyperDual64::from(pt.t);
                let (x, z, th) = (&wd[..n], &wd[n..n + c], &wd[n + c..]);
                let (a, b) = (p.model.divergence(t, x, z, th), ad_divergence(&p.model, t, x, z, th));
                for (u, v) in [(a.re, b.re), (a.eps1, b.eps1), (a.eps2, b.eps2), (a.eps1eps2, b.eps1eps2)] {
                    assert!(
                        relative_eq!(u, v, epsilon = 1e-12, max_relative = 1e-12),
                        "{} ({i}, {j}): {u} vs {v}",
                        p.name
                    );
                }
            }
        }
    });
}

#[test]
fn van_der_pol_divergence_at_the_papers_mu() {
    // 001_8aefdf0570c96f51.txt Sec. 9: div f(t, x) = 2(1 − u²) with μ = 2; at u = 0.5 it is 1.5.
    let p = preset("van-der-pol").unwrap();
    let div = p.model.divergence(0.0, &[0.5, -0.7], &[], &p.theta);
    approx::assert_relative_eq!(div, 1.5, epsilon = 1e-15, max_relative = 1e-15);
}

#[test]
fn duffing_divergence_is_minus_damping() {
    // 000_74b95e149527c64e.txt (4.6) with Table 4.1: div_x f = −d = −0.2 everywhere.
    let p = preset("duffing").unwrap();
    let div = p.model.divergence(1.3, &[0.4], &[-1.1], &p.theta);
    approx::assert_relative_eq!(div, -0.2, epsilon = 1e-15, max_relative = 1e-15);
}

#[test]
fn ou_noise_energy_closed_form() {
    // ½((ẋ + θx)/σ)² with θ = 1, σ = 0.5, x = 0.3, ẋ = 0.2: ½(0.5/0.5)² = 0.5; gradient with
    // respect to (ẋ, x, θ, σ) = (r/σ², θr/σ², x r/σ², −r²/σ³) with r = ẋ + θx = 0.5.
    let p = preset("ou").unwrap();
    let so = p.model.noise_energy_derivatives(0.0, &[0.2], &[0.3], &[], &p.theta).unwrap();
    let (r, s, th, x) = (0.5, 0.5, 1.0, 0.3);
    approx::assert_relative_eq!(so.value, 0.5, epsilon = 1e-15, max_relative = 1e-14);
    let expected = [r / (s * s), th * r / (s * s), x * r / (s * s), -r * r / (s * s * s)];
    for (g, e) in so.gradient.iter().zip(expected) {
        approx::assert_relative_eq!(*g, e, epsilon = 1e-14, max_relative = 1e-14);
    }
}

#[test]
fn duffing_nominal_matches_table_4_1() {
    // 000_74b95e149527c64e.txt Table 4.1: A = 1, B = −1, D = 0.2, Σ_y = 0.1, γ = 0.3, σ_D = 0.1.
    let p = preset("duffing").unwrap();
    for (name, v) in [("a", 1.0), ("b", -1.0), ("d", 0.2), ("gamma", 0.3), ("sigma_d", 0.1), ("sigma_y", 0.1)]
    {
        assert_eq!(p.theta[p.param_index(name).unwrap()], v, "{name}");
    }
    // Table 4.3 for Holmes–Rand.
    let p = preset("holmes-rand").unwrap();
    for (name, v) in [("a", 0.2), ("b", -1.0), ("gamma", 0.2), ("d", 1.0), ("phi", 0.4), ("sigma_d", 0.1)] {
        assert_eq!(p.theta[p.param_index(name).unwrap()], v, "{name}");
    }
}

#[test]
fn every_preset_is_consistent() {
    for name in NAMES {
        let p = preset(name).unwrap();
        let d = p.dims();
        assert_eq!(p.name, *name);
        assert_eq!(p.model.builtin_name(), Some(*name));
        assert_eq!(p.model.noisy_names().len(), d.noisy, "{name}: noisy names");
        assert_eq!(p.model.clean_names().len(), d.clean, "{name}: clean names");
        assert_eq!(p.model.state_names().len(), d.states(), "{name}: state names");
        assert_eq!(p.param_names().len(), d.params, "{name}: parameter names");
        assert_eq!(p.theta.len(), d.params, "{name}: theta");
        assert_eq!(p.theta_prior.len(), d.params, "{name}: theta priors");
        assert_eq!(p.estimate.len(), d.params, "{name}: estimate flags");
        assert_eq!(p.x0_prior.len(), d.noisy, "{name}: x0 priors");
        assert_eq!(p.z0_prior.len(), d.clean, "{name}: z0 priors");
        assert!(p.theta.iter().all(|v| v.is_finite()), "{name}: theta finite");
        // Names are unique, and state names never clash with output names (CSV columns).
        let mut all = p.model.state_names();
        all.extend(p.param_names());
        let outputs = p.observation.output_names();
        all.extend(outputs.iter().cloned());
        let mut sorted = all.clone();
        sorted.sort();
        sorted.dedup();
        assert_eq!(sorted.len(), all.len(), "{name}: duplicate names in {all:?}");
        // Observation: indices in range, one name per measured state, `y` or `y1, y2, …`.
        let obs = &p.observation;
        assert_eq!(obs.names.len(), obs.states.len(), "{name}: output names");
        assert_eq!(obs.output_dim(), obs.states.len(), "{name}: output dim");
        assert!(obs.states.iter().all(|&s| s < d.states()), "{name}: state index out of range");
        let expected: Vec<String> = if obs.states.len() == 1 {
            vec!["y".into()]
        } else {
            (1..=obs.states.len()).map(|k| format!("y{k}")).collect()
        };
        assert_eq!(obs.names, expected, "{name}: output naming");
        obs.validate(d, &p.theta).unwrap_or_else(|e| panic!("{name}: observation: {e}"));
        // G invertible at the nominal θ.
        p.model.diffusion_matrix(&p.theta).unwrap_or_else(|e| panic!("{name}: G: {e}"));
        // Time settings.
        assert!(p.dt > 0.0 && p.sample_every > 0.0 && p.t_end > 0.0, "{name}: times");
        assert!(p.dt <= p.sample_every, "{name}: dt > sample_every");
        assert!((0.0..=p.t_end).contains(&p.first_sample), "{name}: first sample");
        // Each multiple of dt lands on the measurement grid: sample_every / dt is an integer.
        let ratio = p.sample_every / p.dt;
        assert!((ratio - ratio.round()).abs() < 1e-9, "{name}: sample_every / dt = {ratio}");
        assert!(!p.description.is_empty() && !p.source.is_empty());
        p.validate().unwrap_or_else(|e| panic!("{name}: validate: {e}"));
    }
}

#[test]
fn unknown_model_and_parameter_names_are_errors() {
    match preset("duffin") {
        Err(Error::UnknownName { kind, name, known }) => {
            assert_eq!((kind.as_str(), name.as_str()), ("model", "duffin"));
            assert_eq!(known, NAMES.iter().map(|s| s.to_string()).collect::<Vec<_>>());
        }
        other => panic!("expected UnknownName, got {other:?}"),
    }
    let mut p = preset("duffing").unwrap();
    assert_eq!(p.param_index("sigma_y").unwrap(), Duffing::SIGMA_Y);
    p.set_param("a", 1.5).unwrap();
    assert_eq!(p.theta[Duffing::A], 1.5);
    match p.set_param("alpha", 1.0) {
        Err(Error::UnknownName { kind, known, .. }) => {
            assert_eq!(kind, "parameter");
            assert_eq!(known, p.param_names());
        }
        other => panic!("expected UnknownName, got {other:?}"),
    }
    assert!(matches!(p.set_param("b", f64::NAN), Err(Error::NonFinite { .. })));
    assert_eq!(p.theta[Duffing::B], -1.0, "a rejected value leaves θ unchanged");
}

#[test]
fn singular_diffusion_is_an_error_not_a_nan() {
    // D = 0 makes G = √(2D) = 0; D < 0 makes it NaN. Both are rejected.
    let m = DoubleWell;
    assert!(matches!(m.diffusion_matrix(&[0.0]), Err(Error::SingularDiffusion { .. })));
    assert!(matches!(m.diffusion_matrix(&[-1.0]), Err(Error::SingularDiffusion { .. })));
    assert!(Lorenz63.noise_energy(0.0, &[0.0; 3], &[1.0; 3], &[], &[10.0, 28.0, 2.0, 0.0]).is_none());
}

#[test]
fn models_md_shows_the_compiled_example() {
    // docs/models.md must contain examples/custom_model.rs verbatim, so the code it shows
    // compiles (STYLE.md: code in docs comes from compiled examples).
    let doc = include_str!("../../../docs/models.md");
    let example = include_str!("../../../examples/custom_model.rs");
    assert!(doc.contains(example.trim_end()), "docs/models.md is out of date with examples/custom_model.rs");
}

#[test]
fn measurement_times_follow_the_sources() {
    let count = |name: &str| preset(name).unwrap().measurement_times().len();
    // 000_74b95e149527c64e.txt Sec. 4.1.3: N + 1 = 501 measurements, t_s = 0.1, t_f = 50.
    assert_eq!(count("holmes-rand"), 501);
    // 001_8aefdf0570c96f51.txt Sec. 9: T_m = {0, 0.1, …, 16}, 161 times.
    assert_eq!(count("van-der-pol"), 161);
    // 000 Sec. 4.1.1: Y_0 … Y_N at k t_s, t_f = 100: 1001 times.
    assert_eq!(count("duffing"), 1001);
    // 001 Sec. 2: a single measurement at t = 5.
    assert_eq!(preset("tanh").unwrap().measurement_times(), vec![5.0]);
    let times = preset("van-der-pol").unwrap().measurement_times();
    approx::assert_relative_eq!(times[37], 3.7, epsilon = 1e-15, max_relative = 1e-15);
    assert_eq!(*times.last().unwrap(), 16.0);
}

#[test]
fn validate_rejects_bad_settings() {
    let mut p = preset("lorenz63").unwrap();
    p.theta.pop();
    assert!(matches!(p.validate(), Err(Error::DimensionMismatch { .. })));
    let mut p = preset("lorenz63").unwrap();
    p.set_param("sigma_w", 0.0).unwrap();
    assert!(matches!(p.validate(), Err(Error::SingularDiffusion { .. })));
    let mut p = preset("ou").unwrap();
    p.dt = -0.1;
    assert!(matches!(p.validate(), Err(Error::InvalidOption { .. })));
    let mut p = preset("ou").unwrap();
    p.sample_every = 0.015;
    let mut rng = rand::rngs::StdRng::seed_from_u64(0);
    let simulated = p.simulate(crate::simulate::Scheme::EulerMaruyama, &mut rng);
    let Err(Error::InvalidOption { name, reason }) = simulated else { panic!("simulated every 0.015") };
    assert_eq!(name, "sample_every");
    assert!(reason.contains("multiple of the simulation step dt = 0.01"), "{reason}");
    p.sample_every = 0.03;
    assert_eq!(p.simulate(crate::simulate::Scheme::EulerMaruyama, &mut rng).unwrap().1.len(), 334);
    // One measurement (at t = 0): its spacing does not matter.
    p.sample_every = 10.015;
    assert_eq!(p.simulate(crate::simulate::Scheme::EulerMaruyama, &mut rng).unwrap().1.len(), 1);
    let mut p = preset("tanh").unwrap();
    p.first_sample = 6.0;
    assert!(matches!(p.validate(), Err(Error::InvalidOption { .. })));
    assert!(p.measurement_times().is_empty());
    let mut p = preset("duffing").unwrap();
    p.observation.states = vec![2];
    assert!(matches!(p.validate(), Err(Error::InvalidOption { .. })));
}

/// [f; h; div_x f] of a model as a function of w = (x, z, θ) at a fixed t: the automatic-
/// differentiation reference of the closed-form `drift_derivatives`.
struct PointOutputs<'a> {
    p: &'a Preset,
    t: f64,
}

impl crate::model::ad::VectorFn for PointOutputs<'_> {
    fn dim_in(&self) -> usize {
        self.p.dims().states() + self.p.dims().params
    }
    fn dim_out(&self) -> usize {
        self.p.dims().states() + 1
    }
    fn eval<D: Scalar>(&self, w: &[D], out: &mut [D]) {
        let d = self.p.dims();
        let (n, c) = (d.noisy, d.clean);
        let (x, z, th) = (&w[..n], &w[n..n + c], &w[n + c..]);
        let t = D::from(self.t);
        self.p.model.drift(t, x, z, th, &mut out[..n]);
        self.p.model.clean_drift(t, x, z, th, &mut out[n..n + c]);
        out[n + c] = self.p.model.divergence(t, x, z, th);
    }
}

/// Every built-in model's closed-form `drift_derivatives` (first and second derivatives of f,
/// h and div_x f) equals the automatic derivatives of `drift`, `clean_drift` and `divergence`
/// on random points, with every input kept and with every other input dropped (the
/// transcription keeps the states and some of θ); with only the first outputs kept, the
/// others are not written.
#[test]
fn closed_form_drift_derivatives_equal_automatic_differentiation() {
    use crate::model::ad::hessians_into;
    use crate::model::{packed_index, DriftDerivatives};
    for_every_model(|p, pt| {
        let d = p.dims();
        let (ns, n) = (d.states(), d.states() + d.params);
        let m = ns + 1;
        let w = concat(&[&pt.x, &pt.z, &pt.theta]);
        let (mut value, mut jac, mut hess) = (vec![0.0; m], vec![0.0; m * n], vec![0.0; m * n * n]);
        hessians_into(&PointOutputs { p, t: pt.t }, &w, &mut value, &mut jac, &mut hess);
        let all: Vec<usize> = (0..n).collect();
        let odd: Vec<usize> =
            (0..n).map(|i| if i % 2 == 0 { i / 2 } else { DriftDerivatives::DROPPED }).collect();
        for (cols, outputs) in [(&all, m), (&odd, m), (&all, ns)] {
            let kept: Vec<usize> = (0..n).filter(|&i| cols[i] != DriftDerivatives::DROPPED).collect();
            let k = kept.len();
            let tri = k * (k + 1) / 2;
            let (mut cj, mut ch) = (vec![0.0; outputs * k], vec![0.0; m * tri]);
            let mut out = DriftDerivatives::new(cols, k, outputs, &mut cj, &mut ch);
            assert!(p.model.drift_derivatives(pt.t, &pt.x, &pt.z, &pt.theta, &mut out), "{}", p.name);
            for o in 0..outputs {
                for (a, &i) in kept.iter().enumerate() {
                    let (u, v) = (cj[o + a * outputs], jac[o + i * m]);
                    assert!(
                        relative_eq!(u, v, epsilon = 1e-12, max_relative = 1e-12),
                        "{} d{o}/d{i}: {u} vs {v}",
                        p.name
                    );
                    for (b, &j) in kept.iter().enumerate().take(a + 1) {
                        let (u, v) = (ch[o * tri + packed_index(k, a, b)], hess[o * n * n + i + j * n]);
                        assert!(
                            relative_eq!(u, v, epsilon = 1e-12, max_relative = 1e-12),
                            "{} d2{o}/d{i}d{j}: {u} vs {v}",
                            p.name
                        );
                    }
                }
            }
            assert!(
                ch[outputs * tri..].iter().all(|&v| v == 0.0),
                "{}: an output not kept was written",
                p.name
            );
        }
    });
}

/// The (d + 1)-th forward difference Δ_h^{d+1} g(0) = Σ_k (−1)^{d+1−k} C(d + 1, k) g(kh) of
/// every component of g: zero for a polynomial of degree ≤ d, d! h^d times the leading
/// coefficient for degree d + 1 (Newton's forward-difference identity).
fn forward_difference(g: &dyn Fn(f64) -> Vec<f64>, order: usize, h: f64) -> (Vec<f64>, f64) {
    let mut out = Vec::new();
    let mut scale = 0.0f64;
    let mut binom = 1.0;
    for k in 0..=order {
        let sign = if (order - k).is_multiple_of(2) { 1.0 } else { -1.0 };
        let v = g(k as f64 * h);
        out.resize(v.len(), 0.0);
        for (o, vi) in out.iter_mut().zip(&v) {
            *o += sign * binom * vi;
            scale = scale.max(binom * vi.abs());
        }
        binom = binom * (order - k) as f64 / (k + 1) as f64;
    }
    (out, scale)
}

/// Every built-in model that declares `drift_polynomial_degree() = Some(d)` has a state drift
/// [f; h] of degree exactly d along random lines s0 + τu of the state (t and θ random): the
/// (d + 1)-th finite difference vanishes to round-off at every point, the d-th does not
/// (so d is not an overstatement) on some. `tanh` is not a polynomial and declares nothing;
/// `Model` forwards the declaration.
#[test]
fn declared_drift_polynomial_degrees_are_exact() {
    let declared = std::cell::RefCell::new(Vec::new());
    let leading = std::cell::RefCell::new(Vec::new());
    for_every_model(|p, pt| {
        let Some(d) = p.model.drift_polynomial_degree() else {
            assert!(
                ["tanh", "pendulum"].contains(&p.name.as_str()),
                "{}: a polynomial model without a declared degree",
                p.name
            );
            return;
        };
        declared.borrow_mut().push(p.name.clone());
        let ns = p.dims().states();
        let s0 = concat(&[&pt.x, &pt.z]);
        // A direction from the point's velocity and state, of length ~1.
        let u: Vec<f64> = (0..ns).map(|i| ((i + 1) as f64 * 1.7 + s0[i]).sin()).collect();
        let g = |tau: f64| {
            let s: Vec<f64> = s0.iter().zip(&u).map(|(a, b)| a + tau * b).collect();
            let mut out = vec![0.0; ns];
            p.model.state_drift(pt.t, &s, &pt.theta, &mut out);
            out
        };
        let h = 0.5;
        let (high, scale) = forward_difference(&g, d + 1, h);
        for v in &high {
            assert!(v.abs() <= 1e-13 * scale, "{}: Δ^{} = {v} (scale {scale})", p.name, d + 1);
        }
        let (top, scale) = forward_difference(&g, d, h);
        if top.iter().any(|v| v.abs() > 1e-6 * scale) {
            leading.borrow_mut().push(p.name.clone());
        }
    });
    let (mut declared, mut leading) = (declared.into_inner(), leading.into_inner());
    declared.dedup();
    leading.dedup();
    assert_eq!(declared, leading, "models whose declared degree is never reached");
    // every model but tanh and the pendulum is a polynomial
    assert_eq!(declared.len(), crate::test_models::MODEL_FILES.len() - 2);
}

/// A model declares `drift_is_autonomous()` exactly when its state drift [f; h] is the same at
/// t and t + 1.37 at every random point (bit for bit): no model whose drift reads t declares it
/// (duffing, holmes-rand, the flight-path models, their twins), every model whose drift does
/// not declares it (built-in models and model files alike).
#[test]
fn declared_autonomous_drifts_do_not_read_t() {
    let reads_t = std::cell::RefCell::new(std::collections::BTreeMap::new());
    for_every_model(|p, pt| {
        let ns = p.dims().states();
        let s0 = concat(&[&pt.x, &pt.z]);
        let at = |t: f64| {
            let mut out = vec![0.0; ns];
            p.model.state_drift(t, &s0, &pt.theta, &mut out);
            out
        };
        let moved = at(pt.t) != at(pt.t + 1.37);
        *reads_t.borrow_mut().entry(p.name.clone()).or_insert(false) |= moved;
        if p.model.drift_is_autonomous() {
            assert!(!moved, "{}: declared autonomous, but its drift reads t", p.name);
        }
    });
    for (name, reads) in reads_t.into_inner() {
        let declared =
            every_preset().iter().filter(|p| p.name == name).all(|p| p.model.drift_is_autonomous());
        assert_eq!(declared, !reads, "{name}: drift_is_autonomous() = {declared}, reads t = {reads}");
    }
}

/// The flight-path model (`000_74b95e149527c64e.txt` Sec. 4.2) at a random point near level
/// flight: w = (x, z, θ).
fn flight_point<R: Rng + ?Sized>(rng: &mut R) -> Vec<f64> {
    let mut w: Vec<f64> = (0..30).map(|_| uniform(rng, -0.5, 0.5)).collect();
    w[6 + flight_state::H] = uniform(rng, 4000.0, 6000.0);
    w[6 + flight_state::U] = uniform(rng, 80.0, 120.0);
    w[6 + flight_state::AZ] = uniform(rng, -10.5, -9.0);
    w[22 + FlightPath::K_A] = uniform(rng, 0.5, 2.0);
    w[22 + FlightPath::K_M] = uniform(rng, 0.5, 2.0);
    w
}

/// [f; h; div_x f] of the flight-path model as a function of w = (x, z, θ).
struct FlightOutputs(FlightPath);

impl crate::model::ad::VectorFn for FlightOutputs {
    fn dim_in(&self) -> usize {
        30
    }
    fn dim_out(&self) -> usize {
        23
    }
    fn eval<D: Scalar>(&self, w: &[D], out: &mut [D]) {
        let (x, z, th) = (&w[..6], &w[6..22], &w[22..]);
        let t = D::from(0.0);
        self.0.drift(t, x, z, th, &mut out[..6]);
        self.0.clean_drift(t, x, z, th, &mut out[6..22]);
        out[22] = self.0.divergence(t, x, z, th);
    }
}

/// The flight-path drift's automatic Jacobian equals central differences, and its closed-form
/// first and second derivatives equal automatic differentiation.
#[test]
fn flight_path_drift_derivatives_match_differences_and_ad() {
    use crate::model::ad::{hessians_into, VectorFn};
    use crate::model::{packed_index, DriftDerivatives};
    let model = FlightPath::default();
    let outputs = FlightOutputs(model);
    let mut rng = StdRng::seed_from_u64(37);
    for _ in 0..20 {
        let w = flight_point(&mut rng);
        let f = |w: &[f64]| {
            let mut out = vec![0.0; 23];
            outputs.eval(w, &mut out);
            out
        };
        let (mut value, mut jac, mut hess) = (vec![0.0; 23], vec![0.0; 23 * 30], vec![0.0; 23 * 900]);
        hessians_into(&outputs, &w, &mut value, &mut jac, &mut hess);
        assert_close(
            &DMatrix::from_column_slice(23, 30, &jac),
            &fd_jacobian(&f, 23, &w),
            "flight-path Jacobian",
        );
        let cols: Vec<usize> = (0..30).collect();
        let tri = 30 * 31 / 2;
        let (mut cj, mut ch) = (vec![0.0; 23 * 30], vec![0.0; 23 * tri]);
        let mut out = DriftDerivatives::new(&cols, 30, 23, &mut cj, &mut ch);
        assert!(model.drift_derivatives(0.0, &w[..6], &w[6..22], &w[22..], &mut out));
        for o in 0..23 {
            for i in 0..30 {
                let (u, v) = (cj[o + i * 23], jac[o + i * 23]);
                assert!(relative_eq!(u, v, epsilon = 1e-10, max_relative = 1e-10), "d{o}/d{i}: {u} vs {v}");
                for j in 0..=i {
                    let (u, v) = (ch[o * tri + packed_index(30, i, j)], hess[o * 900 + i + j * 30]);
                    assert!(
                        relative_eq!(u, v, epsilon = 1e-10, max_relative = 1e-10),
                        "d2{o}/d{i}d{j}: {u} vs {v}"
                    );
                }
            }
        }
    }
}

/// The flight-path log-likelihood's automatic gradient equals central differences.
#[test]
fn flight_path_log_likelihood_gradient_matches_central_differences() {
    struct Ll<'a>(&'a FlightPathObservation, Vec<f64>);
    impl crate::model::ad::ScalarFn for Ll<'_> {
        fn dim_in(&self) -> usize {
            30
        }
        fn eval<D: Scalar>(&self, w: &[D]) -> D {
            self.0.log_likelihood(0.0, &self.1, &w[..6], &w[6..22], &w[22..])
        }
    }
    let obs = FlightPathObservation::default();
    let mut rng = StdRng::seed_from_u64(38);
    for _ in 0..20 {
        let w = flight_point(&mut rng);
        let mut y = vec![0.0; 13];
        obs.sample(0.0, &w[..6], &w[6..22], &w[22..], &mut rng, &mut y);
        let ll = Ll(&obs, y);
        let (_, grad) = crate::model::ad::gradient(&ll, &w);
        let f = |w: &[f64]| vec![crate::model::ad::ScalarFn::eval(&ll, w)];
        assert_close(&row(&grad), &fd_jacobian(&f, 1, &w), "flight-path log-likelihood gradient");
    }
}

/// Steady level flight (φ = θ = 0, no rotation, no moments, no jerk, a_z = −g, the rest 0) is
/// an equilibrium of the rigid-body kinematics, and the measurements are then the airspeed,
/// α = β = 0 up to the nose boom's offsets, and the biases plus −g on the z accelerometer.
#[test]
fn steady_level_flight_is_an_equilibrium() {
    let model = FlightPath::default();
    let mut z = [0.0; 16];
    z[flight_state::H] = 5000.0;
    z[flight_state::U] = 100.0;
    z[flight_state::AZ] = -model.gravity;
    let mut zdot = [1.0; 16];
    rigid_body_kinematics(&model.inertia.coefficients(), model.gravity, &z, &[0.0; 6], &mut zdot);
    assert!(zdot.iter().all(|&v| v.abs() < 1e-14), "{zdot:?}");
    let theta = FlightPathSetup::TRUTH;
    let y = FlightPathObservation::default().outputs(&z, &theta);
    assert_eq!(y[0], 100.0);
    assert_eq!((y[1], y[2]), (0.0, 0.0));
    assert_eq!(y[12], -model.gravity + theta[5]);
}

/// At the trim forces of any state the velocities are stationary: u̇ = v̇ = ẇ = 0 exactly, and
/// the forces have their closed form (a_x = qw − rv + g sin θ, a_y = ru − pw − g cos θ sin φ,
/// a_z = pv − qu − g cos θ cos φ).
#[test]
fn trim_forces_make_the_velocities_stationary() {
    use flight_state::*;
    let model = FlightPath::default();
    let mut rng = rand::rngs::StdRng::seed_from_u64(5);
    for _ in 0..20 {
        let w = flight_point(&mut rng);
        let mut z = w[6..22].to_vec();
        let trim = model.trim_forces(&z);
        z[AX..=AZ].copy_from_slice(&trim);
        let mut zdot = [1.0; 16];
        rigid_body_kinematics(&model.inertia.coefficients(), model.gravity, &z, &[0.0; 6], &mut zdot);
        assert_eq!([zdot[U], zdot[V], zdot[W]], [0.0; 3]);
        let g = model.gravity;
        let (p, q, r, u, v, wv) = (z[P], z[Q], z[R], z[U], z[V], z[W]);
        let (sp, cp, st, ct) = (z[PHI].sin(), z[PHI].cos(), z[THETA].sin(), z[THETA].cos());
        let closed = [q * wv - r * v + g * st, r * u - p * wv - g * ct * sp, p * v - q * u - g * ct * cp];
        for (a, b) in trim.iter().zip(closed) {
            assert!((a - b).abs() < 1e-12 * (1.0 + b.abs()), "{a} vs {b}");
        }
    }
}
