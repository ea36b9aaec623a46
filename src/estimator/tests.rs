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
