use super::*;

#[test]
fn names_round_trip_and_unknown_names_are_errors() {
    for &m in Method::ALL {
        assert_eq!(m.name().parse::<Method>().unwrap(), m);
        assert_eq!(serde_json::to_string(&m).unwrap(), format!("\"{}\"", m.name()));
        assert_eq!(Estimator::new(m).method(), m);
    }
    let e = "kalman".parse::<Method>().unwrap_err().to_string();
    assert!(e.contains("kalman") && e.contains("mean-optimal"), "{e}");
}

#[test]
fn every_default_estimator_validates_and_round_trips_through_json() {
    for &m in Method::ALL {
        let e = Estimator::new(m);
        e.validate().unwrap_or_else(|err| panic!("{m}: {err}"));
        let json = serde_json::to_value(&e).unwrap();
        assert_eq!(json["method"], m.name());
        let back: Estimator = serde_json::from_value(json).unwrap();
        assert_eq!(back, e, "{m}");
        // The option names are those of the serialised defaults, which the parser accepts.
        assert_eq!(Estimator::from_options(m, &e.options_json()).unwrap(), e, "{m}");
        assert_eq!(Estimator::option_names(m), e.options_json().keys().cloned().collect::<Vec<_>>());
    }
}

#[test]
fn text_options_are_typed_and_nested() {
    let e =
        Estimator::parse("mean-optimal:grid=\"lo=-3,hi=3,cells=50\",dual.max_iterations=7,dt=0.01").unwrap();
    match e {
        Estimator::MeanOptimal(o) => {
            assert_eq!(o.exact.grid, Some(crate::action::GridSpec::new_1d(-3.0, 3.0, 50)));
            assert_eq!(o.exact.dt, Some(0.01));
            assert_eq!(o.dual.max_iterations, 7);
        }
        other => panic!("{other:?}"),
    }
    // The exact estimators' time scheme.
    match Estimator::parse("ksp:scheme=implicit-euler").unwrap() {
        Estimator::Ksp(o) => assert_eq!(o.scheme, crate::action::TimeScheme::ImplicitEuler),
        other => panic!("{other:?}"),
    }
    match Estimator::parse("mean-optimal:scheme=tr-bdf2").unwrap() {
        Estimator::MeanOptimal(o) => assert_eq!(o.exact.scheme, crate::action::TimeScheme::TrBdf2),
        other => panic!("{other:?}"),
    }
    // A domain as a JSON array on the command line: one interval for one state, or a list.
    for (text, domain) in [
        ("exp-closure:domain=\"[-3.5,3.5]\"", vec![(-3.5, 3.5)]),
        ("exp-closure:domain=-3.5;3.5", vec![(-3.5, 3.5)]),
        ("exp-closure:domain=\"[[-3,3],[-4.5,4.5]]\"", vec![(-3.0, 3.0), (-4.5, 4.5)]),
    ] {
        match Estimator::parse(text).unwrap() {
            Estimator::ExpClosure(o) => assert_eq!(o.family.domain, domain, "{text}"),
            other => panic!("{other:?}"),
        }
    }
    match Estimator::parse("area-closure:domain=\"[-2,2]\"").unwrap() {
        Estimator::AreaClosure(o) => assert_eq!(o.domain, Some((-2.0, 2.0))),
        other => panic!("{other:?}"),
    }
    // A grid as a table, as in TOML files.
    let table = serde_json::json!({"grid": {"lo": -2.0, "hi": 2.0, "cells": 40}});
    let e = Estimator::from_options(Method::Ksp, table.as_object().unwrap()).unwrap();
    assert!(matches!(e, Estimator::Ksp(o) if o.grid == Some(crate::action::GridSpec::new_1d(-2.0, 2.0, 40))));
    // Errors name the method, the option and what is allowed.
    let cases = [
        ("uks:moments=6", "moments", "alpha, dt, kappa"),
        ("jme:transcription=simpson", "transcription", "hermite-simpson"),
        ("particle:particles=1", "particles", "at least 2"),
        ("ksp:grid=\"lo=1,hi=0,cells=10\"", "grid", "lo < hi"),
        ("exp-closure:dual.tolerance=-1", "dual.tolerance", "positive"),
        ("mean-optimal:dual.nope=1", "dual", "nope"),
        ("ksp:scheme=euler", "scheme", "implicit-euler"),
        ("exp-closure:domain=\"[[1,2,3]]\"", "domain", "list of intervals"),
    ];
    for (text, option, allowed) in cases {
        match Estimator::parse(text) {
            Err(Error::EstimatorOption { method, option: o, reason }) => {
                assert_eq!(method, text.split(':').next().unwrap(), "{text}");
                assert!(o.starts_with(option), "{text}: option `{o}`");
                assert!(reason.contains(allowed), "{text}: {reason}");
            }
            other => panic!("{text}: {other:?}"),
        }
    }
    assert!(matches!(Estimator::parse("jme,uks"), Err(Error::InvalidOption { .. })));
    assert!(matches!(parse_list("dt=1,uks"), Err(Error::InvalidOption { .. })));
}

#[test]
fn applies_to_follows_the_model_the_likelihood_and_the_estimate() {
    use crate::model::library::preset;
    use crate::model::observation::Noise;
    use crate::model::observation::Param;
    let mut p = preset("duffing").unwrap();
    (p.t_end, p.dt, p.sample_every) = (2.0, 0.01, 0.5);
    let rec = crate::test_models::PresetRecord::simulate_from(p, 2, &[0.5], &[0.0]).unwrap();
    let problem = rec.preset.problem(&rec.data, &[]);
    let applies = |m: Method, pr: &EstimationProblem<'_, _, _>| Estimator::new(m).applies_to(pr);
    // Two states, x not measured: no default grid; the one-state closures do not apply.
    assert!(applies(Method::Ksp, &problem).unwrap_err().reason.contains("lo=L1;L2"));
    assert!(applies(Method::KspClosure, &problem).is_err());
    for m in [Method::GaussianClosure, Method::ExpClosure, Method::Jme, Method::Uks, Method::Particle] {
        assert!(applies(m, &problem).is_ok(), "{m}");
    }
    // pem needs parameters to estimate; with them, only jme, mee and pem apply.
    assert!(applies(Method::Pem, &problem).is_err());
    let estimating = rec.preset.problem(&rec.data, &[0]);
    for &m in Method::ALL {
        assert_eq!(applies(m, &estimating).is_ok(), m.estimates_parameters(), "{m}");
    }
    // A Student-t likelihood: ksp, jme, mee and particle only.
    let mut obs = rec.preset.observation.clone();
    obs.noise = Noise::StudentT { nu: Param::Fixed(4.0), scale: Param::Fixed(0.2) };
    let t = EstimationProblem { observation: &obs, ..problem };
    for &m in Method::ALL {
        let ok = matches!(m, Method::Jme | Method::Mee | Method::Particle);
        assert_eq!(applies(m, &t).is_ok(), ok, "{m}");
    }
}
