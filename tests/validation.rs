//! Every kind of bad input gets an error naming the field (a JSON pointer)
//! and what was expected, and nothing panics.

use ilqr_service::problem::{Limits, ParseError, ProblemSpec, parse};
use ilqr_service::solve::solve;
use proptest::prelude::*;
use serde_json::{Value, json};

/// Parse and validate; the pointers of every error.
fn errors(doc: &Value) -> Vec<String> {
    match parse(doc.to_string().as_bytes()) {
        Err(ParseError::Shape(f)) => vec![f.pointer],
        Err(ParseError::Syntax(msg)) => panic!("{doc} is JSON, got syntax error {msg}"),
        Ok(spec) => match spec.validate(&Limits::default()) {
            Ok(()) => vec![],
            Err(errs) => errs.into_iter().map(|e| e.pointer).collect(),
        },
    }
}

fn rejects(doc: Value, pointer: &str) {
    let errs = errors(&doc);
    assert!(
        errs.iter().any(|p| p == pointer),
        "{doc}: expected an error at {pointer}, got {errs:?}"
    );
}

#[test]
fn the_empty_document_is_the_seed_problem() {
    assert_eq!(parse(b"{}").unwrap(), ProblemSpec::default());
    assert!(errors(&json!({})).is_empty());
    let expanded = serde_json::to_value(ProblemSpec::default()).unwrap();
    assert_eq!(
        parse(expanded.to_string().as_bytes()).unwrap(),
        ProblemSpec::default()
    );
}

#[test]
fn non_positive_physical_parameters_are_rejected() {
    for field in ["mass", "inertia", "arm_length"] {
        for bad in [json!(0.0), json!(-1.0)] {
            rejects(json!({"model": {field: bad}}), &format!("/model/{field}"));
        }
    }
    rejects(json!({"model": {"gravity": -9.81}}), "/model/gravity");
    rejects(json!({"dt": 0}), "/dt");
    rejects(json!({"dt": -0.05}), "/dt");
}

#[test]
fn out_of_range_numbers_are_rejected() {
    // JSON has no NaN or Infinity; 1e999 is the nearest a client can send.
    rejects(json!({"dt": "NaN"}), "/dt");
    // It does not fit an f64, so the document is not one we can read.
    let overflow = br#"{"goal_state": [1e999, 0, 0, 0, 0, 0]}"#;
    match parse(overflow) {
        Err(ParseError::Syntax(msg)) => assert!(msg.contains("out of range"), "{msg}"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn negative_weights_are_rejected() {
    rejects(
        json!({"weights": {"state": [1, 1, -1, 1, 1, 1]}}),
        "/weights/state/2",
    );
    rejects(
        json!({"weights": {"control": [0.1, -0.1]}}),
        "/weights/control/1",
    );
    rejects(
        json!({"weights": {"terminal": [-5, 1, 1, 1, 1, 1]}}),
        "/weights/terminal/0",
    );
    rejects(
        json!({"obstacles": [{"center": [1, 1], "weight": -1}]}),
        "/obstacles/0/weight",
    );
}

#[test]
fn horizon_bounds_are_enforced() {
    rejects(json!({"horizon": 0}), "/horizon");
    rejects(json!({"horizon": 10001}), "/horizon");
    rejects(json!({"horizon": -3}), "/horizon");
    rejects(json!({"horizon": 2.5}), "/horizon");
    assert!(errors(&json!({"horizon": 10000})).is_empty());
    // An integral float is an integer in JSON Schema.
    assert!(errors(&json!({"horizon": 50.0})).is_empty());
    let tight = Limits {
        max_horizon: 200,
        max_time_limit_ms: Some(1000),
    };
    let spec = parse(br#"{"horizon": 201, "solver": {"time_limit_ms": 1001}}"#).unwrap();
    let errs: Vec<_> = spec
        .validate(&tight)
        .unwrap_err()
        .into_iter()
        .map(|e| e.pointer)
        .collect();
    assert_eq!(errs, ["/horizon", "/solver/time_limit_ms"]);
}

#[test]
fn wrong_vector_lengths_name_the_vector() {
    rejects(json!({"initial_state": [1, 2, 3]}), "/initial_state");
    rejects(json!({"goal_state": [1, 2, 3, 4, 5, 6, 7]}), "/goal_state");
    rejects(json!({"weights": {"control": [1]}}), "/weights/control");
    rejects(
        json!({"obstacles": [{"center": [1], "weight": 1}]}),
        "/obstacles/0/center",
    );
}

#[test]
fn initial_controls_must_match_the_horizon() {
    rejects(
        json!({"horizon": 3, "initial_controls": [[1, 1], [1, 1]]}),
        "/initial_controls",
    );
    rejects(
        json!({"horizon": 2, "initial_controls": [[1, 1], [1, 1, 1]]}),
        "/initial_controls/1",
    );
    assert!(errors(&json!({"horizon": 2, "initial_controls": [[1, 1], [2, 2]]})).is_empty());
}

#[test]
fn wrong_types_and_unknown_fields_are_rejected() {
    rejects(json!({"horizn": 100}), "/horizn");
    rejects(json!({"model": {"mas": 1}}), "/model/mas");
    rejects(json!({"model": {"type": "quadrotor_3d"}}), "/model/type");
    rejects(json!({"integrator": "rk4"}), "/integrator");
    rejects(json!({"obstacles": [{"center": [1, 1]}]}), "/obstacles/0");
    rejects(
        json!({"solver": {"tolerance": "small"}}),
        "/solver/tolerance",
    );
    rejects(json!({"solver": {"tolerance": 1.5}}), "/solver/tolerance");
    rejects(
        json!({"solver": {"max_iterations": 1_000_000}}),
        "/solver/max_iterations",
    );
    rejects(
        json!({"solver": {"time_limit_ms": 0}}),
        "/solver/time_limit_ms",
    );
    rejects(json!({"output": {"gains": "yes"}}), "/output/gains");
    rejects(json!([]), "");
}

#[test]
fn several_errors_are_reported_together() {
    let errs = errors(&json!({"dt": -1, "horizon": 0, "weights": {"state": [-1, 1, 1, 1, 1, 1]}}));
    assert_eq!(errs, ["/dt", "/horizon", "/weights/state/0"]);
}

#[test]
fn malformed_json_is_a_syntax_error() {
    for bad in [&b"{"[..], b"{\"dt\": }", b"", b"{} {}", b"nul"] {
        assert!(
            matches!(parse(bad), Err(ParseError::Syntax(_))),
            "{:?}",
            String::from_utf8_lossy(bad)
        );
    }
}

#[test]
fn controls_that_blow_up_are_reported_at_initial_controls() {
    let spec =
        parse(br#"{"horizon": 3, "initial_controls": [[1e300, -1e300], [0, 0], [0, 0]]}"#).unwrap();
    spec.validate(&Limits::default()).unwrap();
    let err = solve(&spec, None, &Default::default()).unwrap_err();
    assert_eq!(err.0.pointer, "/initial_controls");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Any JSON object of plausible keys and arbitrary values: parsing and
    /// validation return, and whatever validates also solves without panic.
    #[test]
    fn no_document_makes_it_panic(
        dt in prop_oneof![Just(json!(0.05)), any::<f64>().prop_map(|v| json!(v)), Just(json!(null))],
        horizon in prop_oneof![Just(json!(20)), (0i64..40).prop_map(|v| json!(v)), Just(json!(-1))],
        mass in prop_oneof![Just(json!(1.0)), (-1e3..1e3f64).prop_map(|v| json!(v))],
        x0 in prop::collection::vec(-1e6..1e6f64, 0..8),
        weight in -1e6..1e6f64,
    ) {
        let doc = json!({"dt": dt, "horizon": horizon, "model": {"mass": mass},
                         "initial_state": x0, "obstacles": [{"center": [0, 0], "weight": weight}],
                         "solver": {"max_iterations": 5}});
        if let Ok(spec) = parse(doc.to_string().as_bytes())
            && spec.validate(&Limits::default()).is_ok()
            && let Ok(r) = solve(&spec, None, &Default::default())
        {
            prop_assert!(r.cost.is_finite());
        }
    }
}
