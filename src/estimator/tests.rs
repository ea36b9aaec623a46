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
