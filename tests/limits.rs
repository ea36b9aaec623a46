//! Iteration limits and tolerances mapped onto each method's options, and the progress observer
//! of a single estimate.

use std::sync::{Arc, Mutex};

use onsager::data::Dataset;
use onsager::estimate::progress::ProgressEvent;
use onsager::estimator::{Estimator, IterationLimits, Method};
use onsager::model::library::preset;
use onsager::simulate::{sample_measurements, simulate, SimulateOptions};
use onsager::Status;
use rand::SeedableRng;

/// Double-well measurements every 0.5 to t = 5 (11 points), seed 3.
fn double_well_data() -> Dataset {
    let p = preset("double-well").unwrap();
    let mut rng = rand::rngs::StdRng::seed_from_u64(3);
    let truth =
        simulate(&p.model, &p.theta, &[1.0], &[], &SimulateOptions::new(0.0, 5.0, 0.005), &mut rng).unwrap();
    sample_measurements(&p.observation, &p.theta, &truth, 1, 0.5, &mut rng).unwrap()
}

#[test]
fn limits_reach_each_iterating_methods_own_options() {
    let limits = IterationLimits { max_iterations: Some(7), tolerance: Some(1e-4) };
    for &m in Method::ALL {
        let e = Estimator::new(m).with_limits(limits).unwrap();
        let o = serde_json::Value::Object(e.options_json());
        let (n, tol) = match m {
            Method::Jme | Method::Mee | Method::KspClosure | Method::DoubleExpClosure => {
                (&o["max_iterations"], &o["tolerance"])
            }
            Method::Pem => (&o["max_iterations"], &o["gradient_tolerance"]),
            Method::MeanOptimal | Method::GaussianClosure | Method::ExpClosure | Method::AreaClosure => {
                (&o["dual"]["max_iterations"], &o["dual"]["tolerance"])
            }
            _ => {
                assert!(!m.iterates(), "{m}");
                assert_eq!(e, Estimator::new(m), "{m} does not iterate: unchanged");
                continue;
            }
        };
        assert!(m.iterates(), "{m}");
        assert_eq!((n.as_u64(), tol.as_f64()), (Some(7), Some(1e-4)), "{m}: {o}");
    }
    // Unset limits keep the method's own values.
    let pem = Estimator::new(Method::Pem).with_limits(IterationLimits::default()).unwrap();
    assert_eq!(pem, Estimator::new(Method::Pem));
    // Bad values name the option.
    let zero = IterationLimits { max_iterations: Some(0), tolerance: None };
    assert!(Estimator::new(Method::Jme)
        .with_limits(zero)
        .unwrap_err()
        .to_string()
        .contains("max_iterations"));
    let negative = IterationLimits { max_iterations: None, tolerance: Some(-1.0) };
    assert!(Estimator::new(Method::Jme).with_limits(negative).unwrap_err().to_string().contains("tolerance"));
}

#[test]
fn a_jme_estimate_at_its_iteration_limit_is_max_iterations() {
    let p = preset("double-well").unwrap();
    let data = double_well_data();
    let problem = p.problem(&data, &[]);
    let one = IterationLimits { max_iterations: Some(1), tolerance: None };
    let run = Estimator::new(Method::Jme).with_limits(one).unwrap().run(&problem).unwrap();
    assert_eq!(run.estimate.status, Status::MaxIterations);
    assert!(!run.estimate.status.is_success());
    // (The effect of `tolerance` on the iterations is checked through the command line, in
    // `cli::max_iterations_and_tolerance_and_no_progress_text_on_a_pipe`.)
}

#[test]
fn the_progress_observer_sees_the_iterations_of_a_jme_estimate() {
    let p = preset("double-well").unwrap();
    let data = double_well_data();
    let problem = p.problem(&data, &[]);
    let seen = Arc::new(Mutex::new(Vec::new()));
    let observer = {
        let seen = Arc::clone(&seen);
        Arc::new(move |event: ProgressEvent| {
            if let ProgressEvent::Iteration { iteration, merit } = event {
                seen.lock().unwrap().push((iteration, merit));
            }
        })
    };
    let run = Estimator::new(Method::Jme).run_observed(&problem, observer).unwrap();
    let seen = seen.lock().unwrap().clone();
    // One event per iteration and one for the starting point, numbered 0, 1, 2, …
    assert_eq!(seen.len(), run.estimate.iterations + 1, "{seen:?}");
    assert!(seen.iter().enumerate().all(|(k, &(i, m))| i == k && m.is_finite()), "{seen:?}");
    // Outside `run_observed` nothing is observed.
    let before = seen.len();
    Estimator::new(Method::Jme).run(&problem).unwrap();
    assert_eq!(before, seen.len());
}
