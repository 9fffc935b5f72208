//! Every kind of bad input gets an error naming the field (a JSON pointer)
//! and what was expected, and nothing panics.

use ilqr_service::problem::{
    FieldError, Limits, MAX_CONTROL, MAX_OBJECTS, MAX_OBSTACLES, ParseError, ProblemSpec, parse,
};
use ilqr_service::solve::solve;
use proptest::prelude::*;
use serde_json::{Value, json};

/// Parse and validate; the pointers of every error.
fn errors(doc: &Value) -> Vec<String> {
    match parse(doc.to_string().as_bytes()) {
        Err(ParseError::Shape(s)) => s
            .with_range_errors(&Limits::default())
            .errors
            .into_iter()
            .map(|e| e.pointer)
            .collect(),
        Err(ParseError::Syntax(msg)) => panic!("{doc} is JSON, got syntax error {msg}"),
        Ok(spec) => match spec.validate(&Limits::default()) {
            Ok(()) => vec![],
            Err(invalid) => invalid.errors.into_iter().map(|e| e.pointer).collect(),
        },
    }
}

/// The first error of a document that must fail to parse with shape
/// errors (a wrong value somewhere, not a syntax error).
fn first_error(doc: &[u8]) -> FieldError {
    match parse(doc) {
        Err(ParseError::Shape(s)) => s.first().clone(),
        other => panic!("{}: {other:?}", String::from_utf8_lossy(doc)),
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
    // With a byte order mark in front, as Windows tools write it; one
    // anywhere else is not JSON.
    assert_eq!(parse(b"\xEF\xBB\xBF{}").unwrap(), ProblemSpec::default());
    assert!(matches!(
        parse(b"{}\xEF\xBB\xBF"),
        Err(ParseError::Syntax(_))
    ));
    assert!(matches!(
        parse(b"\xEF\xBB\xBF\xEF\xBB\xBF{}"),
        Err(ParseError::Syntax(_))
    ));
    // Byte offsets count it, as the body was sent.
    assert_eq!(
        parse(b"\xEF\xBB\xBF{\"dt\": \"\xFF\"}"),
        Err(ParseError::Syntax("invalid UTF-8 at byte 11".into()))
    );
    assert!(errors(&json!({})).is_empty());
    let expanded = serde_json::to_value(ProblemSpec::default()).unwrap();
    assert_eq!(
        parse(expanded.to_string().as_bytes()).unwrap(),
        ProblemSpec::default()
    );
}

#[test]
fn an_obstacle_without_a_weight_gets_the_seed_obstacles() {
    // The seed problem spelled with its obstacle's weight left out.
    assert_eq!(
        parse(br#"{"obstacles": [{"center": [4.5, 4.5]}]}"#).unwrap(),
        ProblemSpec::default()
    );
    let two =
        parse(br#"{"obstacles": [{"center": [1, 2]}, {"center": [3, 4], "weight": 5}]}"#).unwrap();
    let weights: Vec<f64> = two.obstacles.iter().map(|o| o.weight).collect();
    assert_eq!(weights, [1000.0, 5.0]);
    // A null weight is a wrong type, as a null number is everywhere else.
    rejects(
        json!({"obstacles": [{"center": [1, 2], "weight": null}]}),
        "/obstacles/0/weight",
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
    // It does not fit an f64: valid JSON, but no value we can read, so it
    // is told at its pointer like any other bad value.
    for (doc, pointer) in [
        (
            &br#"{"goal_state": [1e999, 0, 0, 0, 0, 0]}"#[..],
            "/goal_state/0",
        ),
        (br#"{"dt": -1e400}"#, "/dt"),
        (
            br#"{"obstacles": [{"center": [1, 2]}, {"center": [0, 1e999]}]}"#,
            "/obstacles/1/center/1",
        ),
    ] {
        let f = first_error(doc);
        assert_eq!(f.pointer, pointer);
        assert!(
            f.detail
                .starts_with("number out of range: JSON numbers here must fit a 64-bit float"),
            "{}",
            f.detail
        );
    }
    // In a count field the message is the field's own: an integer, and
    // which ones, not "a 64-bit float".
    for (doc, pointer, expected) in [
        (
            &br#"{"horizon": 1e999}"#[..],
            "/horizon",
            "an integer from 1 to the maximum horizon",
        ),
        (
            br#"{"solver": {"max_iterations": -1e999}}"#,
            "/solver/max_iterations",
            "an integer from 0 to 10000",
        ),
        (
            br#"{"solver": {"time_limit_ms": 1e400}}"#,
            "/solver/time_limit_ms",
            "a positive integer (ms",
        ),
    ] {
        let f = first_error(doc);
        assert_eq!(f.pointer, pointer);
        assert!(
            f.detail
                .starts_with(&format!("number out of range: expected {expected}")),
            "{}",
            f.detail
        );
    }
    // A syntax error anywhere still makes it a syntax error, with the
    // syntax error's own message (not the number's).
    match parse(br#"{"dt": 1e999, "horizon": }"#) {
        Err(ParseError::Syntax(msg)) => assert!(msg.starts_with("expected value"), "{msg}"),
        other => panic!("{other:?}"),
    }
}

/// A bare NaN or Infinity is not JSON, but Python's `json.dumps` writes it:
/// a bad value at its pointer when it is the document's only departure
/// from the grammar, a syntax error otherwise.
#[test]
fn bare_nan_and_infinity_are_bad_values_at_their_pointer() {
    for (doc, pointer, token) in [
        (&br#"{"dt": NaN}"#[..], "/dt", "got NaN,"),
        (br#"{"dt":-Infinity}"#, "/dt", "got -Infinity,"),
        (
            br#"{"weights": {"state": [1, Infinity, 1, 1, 1, 1]}}"#,
            "/weights/state/1",
            "got Infinity,",
        ),
        (
            "{\"x\": \"\u{e9}\\\" NaN [\",\n \"obstacles\": [{\"center\": [0,\n   -NaN]}]}"
                .as_bytes(),
            "/obstacles/0/center/1",
            "got -NaN,",
        ),
        // The first one read is the one told.
        (
            br#"{"dt": 0.05, "horizon": NaN, "x": NaN}"#,
            "/horizon",
            "got NaN,",
        ),
        // Where no number goes, what does.
        (br#"{"model": NaN}"#, "/model", "got NaN,"),
        (
            br#"{"output": {"gains": -Infinity}}"#,
            "/output/gains",
            "got -Infinity,",
        ),
        (br#"{"foo": NaN}"#, "/foo", "got NaN,"),
        (br#"{"obstacles": [NaN]}"#, "/obstacles/0", "got NaN,"),
        // Null is taken at both, so what a null is told says nothing of
        // what goes there: what a number is told does (an array; an
        // object), not "a finite number".
        (
            br#"{"initial_controls": NaN}"#,
            "/initial_controls",
            "got NaN,",
        ),
        (br#"{"solver": Infinity}"#, "/solver", "got Infinity,"),
    ] {
        let text = String::from_utf8_lossy(doc);
        match parse(doc) {
            Err(ParseError::Shape(s)) => {
                let f = s.first().clone();
                assert_eq!(f.pointer, pointer, "{text}");
                assert!(f.detail.starts_with(token), "{text}: {}", f.detail);
                assert!(
                    f.detail.contains("which is not JSON"),
                    "{text}: {}",
                    f.detail
                );
                let expected = match pointer {
                    "/horizon" => ": expected an integer from 1 to the maximum horizon",
                    "/model" | "/solver" => ": expected a JSON object, or null for the defaults",
                    "/obstacles/0" => ": expected a JSON object",
                    "/initial_controls" => ": expected an array",
                    "/output/gains" => ": expected a boolean",
                    "/foo" => "; and unknown field `foo`, expected one of `model`",
                    _ => ": expected a finite number",
                };
                assert!(f.detail.contains(expected), "{text}: {}", f.detail);
            }
            other => panic!("{text}: {other:?}"),
        }
    }
    // Anything else wrong with the grammar is still a syntax error, told
    // where it is (not at the NaN).
    for (doc, message) in [
        (
            &br#"{"dt": NaN, "horizon": }"#[..],
            "expected value at line 1 column 24",
        ),
        (br#"{"dt": 1NaN}"#, "expected `,` or `}` at line 1 column 9"),
        (br#"{"dt": - NaN}"#, "invalid number at line 1 column 9"),
        (
            br#"{"dt": "NaN" NaN}"#,
            "expected `,` or `}` at line 1 column 14",
        ),
        (br#"{NaN: 1}"#, "key must be a string at line 1 column 2"),
        (br#"{"dt": nan}"#, "expected ident at line 1 column 9"),
        (br#"{"dt": +Infinity}"#, "expected value at line 1 column 8"),
        (br#"NaN"#, "expected value at line 1 column 1"),
    ] {
        let text = String::from_utf8_lossy(doc);
        match parse(doc) {
            Err(ParseError::Syntax(msg)) => assert_eq!(msg, message, "{text}"),
            other => panic!("{text}: {other:?}"),
        }
    }
}

/// Where the member holding a bare NaN is wrong itself, that is what the
/// NaN is told; where the rest of the document could not be checked, the
/// NaN is told nothing of what its place takes. Neither is told "expected
/// a finite number": in the first a number would be wrong too, in the
/// second it is not known to be right.
#[test]
fn a_bare_nan_is_told_what_is_known_of_its_place() {
    let told = |doc: &[u8]| {
        let f = first_error(doc);
        (f.pointer, f.detail)
    };
    for (doc, pointer, above) in [
        (
            &br#"{"model": [NaN]}"#[..],
            "/model/0",
            "; and /model: invalid type: array, expected a JSON object, or null for the defaults",
        ),
        (
            br#"{"dt": {"a": NaN}}"#,
            "/dt/a",
            "; and /dt: invalid type: object, expected a number",
        ),
        (
            br#"{"obstacles": [{"center": [1, 1, NaN]}]}"#,
            "/obstacles/0/center/2",
            "; and /obstacles/0/center: ",
        ),
        (
            br#"{"foo": [NaN]}"#,
            "/foo/0",
            "; and /foo: unknown field `foo`",
        ),
    ] {
        let (at, detail) = told(doc);
        assert_eq!(at, pointer, "{detail}");
        assert!(detail.starts_with("got NaN, which is not JSON"), "{detail}");
        assert!(detail.contains(above), "{detail}");
        assert!(!detail.contains("finite number"), "{detail}");
    }
    // Reading the masked document stopped early: at a number it cannot
    // read, or when the re-read budget (1 MiB) ran out at `/dt` in a
    // 2 MB body.
    let rows = vec!["[1,1]"; 200_000].join(",");
    let long = format!(r#"{{"dt": "x", "initial_controls": [{rows}], "model": NaN}}"#);
    for doc in [&br#"{"model": NaN, "dt": 1e999}"#[..], long.as_bytes()] {
        let (at, detail) = told(doc);
        assert_eq!(at, "/model");
        assert_eq!(
            detail,
            "got NaN, which is not JSON (Python's json.dumps writes it for a non-finite float)"
        );
    }
    // Where the whole document was checked and a number is taken, it says so.
    assert!(
        told(br#"{"dt": NaN, "foo": 1}"#)
            .1
            .ends_with(": expected a finite number")
    );
}

#[test]
fn nesting_beyond_the_parser_limit_is_told_at_its_member() {
    let deep = |open: usize, close: usize| {
        format!(
            "{{\"dt\": 0.05, \"model\": {}{}}}",
            "[".repeat(open),
            "]".repeat(close)
        )
    };
    // The document is level 1, so 127 brackets reach level 128, the first
    // the parser refuses; 126 are read, and are a type error at the member.
    for open in [127, 200] {
        match parse(deep(open, open).as_bytes()) {
            Err(ParseError::Shape(s)) => {
                let f = s.first().clone();
                assert_eq!(f.pointer, "/model");
                assert!(
                    f.detail.starts_with("nested 128 levels deep or more"),
                    "{open}: {}",
                    f.detail
                );
            }
            other => panic!("{open}: {other:?}"),
        }
    }
    match parse(deep(126, 126).as_bytes()) {
        Err(ParseError::Shape(s)) => {
            let f = s.first().clone();
            assert_eq!(f.pointer, "/model");
            assert!(f.detail.contains("expected a JSON object"), "{}", f.detail);
        }
        other => panic!("{other:?}"),
    }
    // Unbalanced: a syntax error, however deep.
    assert!(matches!(
        parse(deep(200, 199).as_bytes()),
        Err(ParseError::Syntax(_))
    ));
    // A document that is not an object is wrong at its root, deep or not.
    let root = "[".repeat(200) + &"]".repeat(200);
    for doc in [root.as_bytes(), b"[1e999]", b"1e999", br#""\ud800""#] {
        let f = first_error(doc);
        assert_eq!(f.pointer, "");
        assert!(f.detail.ends_with("expected a JSON object"), "{}", f.detail);
    }
}

/// A document may hold at most `MAX_OBJECTS` JSON objects: past that, reading
/// stops with an error at the next one (a 4 MB body of `{"a":1}` would build
/// 363 MiB without the bound). Among obstacles it is told as too many
/// obstacles. The largest valid problem is far inside the bound, and a syntax
/// error later in the document still wins.
#[test]
fn a_document_holds_a_bounded_number_of_objects() {
    let first = |doc: &str| match parse(doc.as_bytes()) {
        Err(ParseError::Shape(s)) => s.first().clone(),
        other => panic!("{other:?}"),
    };
    let objects = |n: usize| vec!["{\"a\": 1}"; n].join(",");
    let f = first(&format!("{{\"foo\": [{}]}}", objects(2 * MAX_OBJECTS)));
    assert_eq!(f.pointer, format!("/foo/{}", MAX_OBJECTS - 1));
    assert!(
        f.detail.starts_with(&format!(
            "the document holds more than {MAX_OBJECTS} JSON objects (this is the next one)"
        )),
        "{}",
        f.detail
    );
    // Exactly at the bound (the document is one): read, and the unknown
    // member is the error.
    let f = first(&format!("{{\"foo\": [{}]}}", objects(MAX_OBJECTS - 1)));
    assert_eq!(f.pointer, "/foo");
    let obstacles =
        |n: usize| json!({"obstacles": vec![json!({"center": [1, 1], "weight": 1}); n]});
    let f = first(&obstacles(2 * MAX_OBJECTS).to_string());
    assert_eq!(f.pointer, "/obstacles");
    assert_eq!(
        f.detail,
        format!(
            "at most 100 obstacles, got more than {0} (reading stopped at obstacle {0}, \
             the document's JSON object number {1})",
            MAX_OBJECTS - 1,
            MAX_OBJECTS + 1
        )
    );
    // Below the bound, the usual error with the exact count.
    let limits = Limits::default();
    let detail = match parse(obstacles(MAX_OBJECTS - 1).to_string().as_bytes()) {
        Ok(spec) => spec.validate(&limits).unwrap_err().errors[0].detail.clone(),
        other => panic!("{other:?}"),
    };
    assert_eq!(
        detail,
        format!("at most 100 obstacles, got {}", MAX_OBJECTS - 1)
    );
    // Surplus objects elsewhere, the bound reached among the first hundred
    // obstacles: not told as too many obstacles.
    let mut doc = obstacles(50);
    doc["foo"] = json!(vec![json!({}); 1000]);
    let text = doc.to_string();
    assert!(
        text.find("\"foo\"") < text.find("\"obstacles\""),
        "{text:.40}"
    );
    let f = first(&text);
    assert_eq!(f.pointer, "/obstacles/23");
    assert!(
        f.detail.starts_with("the document holds more than"),
        "{}",
        f.detail
    );
    let mut largest = obstacles(MAX_OBSTACLES);
    largest["model"] = json!({"mass": 1});
    largest["weights"] = json!({"control": [1, 1]});
    largest["solver"] = json!({"max_iterations": 1});
    largest["output"] = json!({"trace": false});
    assert_eq!(errors(&largest), Vec::<String>::new());
    let broken = format!("{{\"foo\": [{}], \"x\": }}", objects(2 * MAX_OBJECTS));
    assert!(matches!(
        parse(broken.as_bytes()),
        Err(ParseError::Syntax(_))
    ));
}

#[test]
fn unpaired_surrogate_escapes_are_told_at_their_pointer_and_bad_utf8_is_a_syntax_error() {
    // `"\ud800"` is JSON grammar but no Unicode text: like 1e999, a value
    // the parser cannot read, at its pointer, whichever comes first.
    for (doc, pointer) in [
        (&br#"{"model": {"type": "\ud800"}}"#[..], "/model/type"),
        (br#"{"integrator": "a\udc00"}"#, "/integrator"),
        (br#"{"x": "\ud800", "dt": 1e999}"#, "/x"),
        (br#"{"dt": 1e999, "x": "\ud800"}"#, "/dt"),
        (br#"{"model": {"a\ud800": 1}}"#, "/model"),
        (br#"{"x": "\ud800\\"}"#, "/x"),
    ] {
        match parse(doc) {
            Err(ParseError::Shape(s)) => assert_eq!(s.first().pointer, pointer),
            other => panic!("{}: {other:?}", String::from_utf8_lossy(doc)),
        }
    }
    // A malformed escape after a surrogate is a grammar error, not one.
    for doc in [&br#"{"x": "\ud800\uZZZZ"}"#[..], br#"{"x": "\ud800\u12"}"#] {
        assert!(
            matches!(parse(doc), Err(ParseError::Syntax(_))),
            "{}",
            String::from_utf8_lossy(doc)
        );
    }
    // Bytes that are not UTF-8 are not JSON at all (RFC 8259), wherever
    // they are: before or after an unreadable number.
    for doc in [
        &b"{\"dt\": 1e999, \"x\": \"\xff\"}"[..],
        b"{\"x\": \"\xff\", \"dt\": 1e999}",
    ] {
        match parse(doc) {
            Err(ParseError::Syntax(m)) => assert!(m.starts_with("invalid"), "{m}"),
            other => panic!("{}: {other:?}", String::from_utf8_lossy(doc)),
        }
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
        .errors
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
    // Against a horizon out of range only the horizon is wrong: "expected 0
    // rows" or "20000 rows" would be advice that cannot make it valid.
    for horizon in [0, 20000] {
        assert_eq!(
            errors(&json!({"horizon": horizon, "initial_controls": [[1, 1]]})),
            ["/horizon"]
        );
    }
}

#[test]
fn wrong_types_and_unknown_fields_are_rejected() {
    rejects(json!({"horizn": 100}), "/horizn");
    rejects(json!({"model": {"mas": 1}}), "/model/mas");
    rejects(json!({"model": {"type": "quadrotor_3d"}}), "/model/type");
    rejects(json!({"integrator": "rk45"}), "/integrator");
    rejects(json!({"solver": {"method": "newton"}}), "/solver/method");
    rejects(json!({"solver": {"method": null}}), "/solver/method");
    assert!(errors(&json!({"solver": {"method": "ddp"}})).is_empty());
    rejects(json!({"obstacles": [{"weight": 1}]}), "/obstacles/0/center");
    rejects(
        json!({"solver": {"tolerance": "small"}}),
        "/solver/tolerance",
    );
    rejects(json!({"solver": {"tolerance": 1.5}}), "/solver/tolerance");
    // Below 1 exclusive: a relative change of 1 is every step.
    rejects(json!({"solver": {"tolerance": 1}}), "/solver/tolerance");
    assert!(errors(&json!({"solver": {"tolerance": 0.999}})).is_empty());
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

/// The first shape error of `doc`, as `(pointer, detail)`.
fn shape_error(doc: Value) -> (String, String) {
    match parse(doc.to_string().as_bytes()) {
        Err(ParseError::Shape(s)) => (s.first().pointer.clone(), s.first().detail.clone()),
        other => panic!("{doc}: expected a shape error, got {other:?}"),
    }
}

#[test]
fn shape_errors_say_what_was_expected_at_the_field_itself() {
    // Counts: an integer, not "a JSON number", and the range the field
    // takes, so `-3` is told the same range as `0` (by validation).
    const HORIZON: &str =
        "expected an integer from 1 to the maximum horizon (10000 unless configured lower)";
    for (doc, got, expected) in [
        (json!({"horizon": "x"}), "string \"x\"", HORIZON),
        (json!({"horizon": -3}), "number -3", HORIZON),
        (json!({"horizon": 2.5}), "number 2.5", HORIZON),
        (
            json!({"solver": {"max_iterations": true}}),
            "invalid type: true,",
            "expected an integer from 0 to 10000",
        ),
        (
            json!({"solver": {"max_iterations": -1}}),
            "number -1",
            "expected an integer from 0 to 10000",
        ),
        (
            json!({"solver": {"time_limit_ms": "5"}}),
            "string \"5\"",
            "expected a positive integer (ms; a service takes at most 60000 unless configured), or null",
        ),
        (
            json!({"solver": {"time_limit_ms": -5}}),
            "number -5",
            "expected a positive integer (ms; a service takes at most 60000 unless configured), or null",
        ),
    ] {
        let (_, detail) = shape_error(doc.clone());
        assert!(detail.contains(got), "{doc}: {detail}");
        assert!(detail.ends_with(expected), "{doc}: {detail}");
    }
    assert!(errors(&json!({"horizon": 3.0, "solver": {"time_limit_ms": null}})).is_empty());
    // A vector's length is its model's: validation names the model, the
    // length and the components, too long or too short, for either model.
    for (doc, pointer, detail) in [
        (
            json!({"goal_state": [1, 2, 3, 4, 5, 6, 7]}),
            "/goal_state",
            "must have 6 entries for model `quadrotor_2d`, [x, y, θ, ẋ, ẏ, θ̇] in m, m, rad, \
             m/s, m/s, rad/s: got 7",
        ),
        (
            json!({"initial_state": [1]}),
            "/initial_state",
            "must have 6 entries for model `quadrotor_2d`, [x, y, θ, ẋ, ẏ, θ̇] in m, m, rad, \
             m/s, m/s, rad/s: got 1",
        ),
        (
            json!({"model": {"type": "unicycle"}, "weights": {"terminal": [1, 1, 1, 1, 1, 1]}}),
            "/weights/terminal",
            "must have 3 entries for model `unicycle`, [x, y, θ] in m, m, rad: got 6",
        ),
        (
            json!({"weights": {"control": [1, 2, 3]}}),
            "/weights/control",
            "must have 2 entries for model `quadrotor_2d`, [u1, u2] in N, N: got 3",
        ),
        (
            json!({"model": {"type": "unicycle"}, "horizon": 2, "initial_controls": [[1, 1], [1, 1, 1]]}),
            "/initial_controls/1",
            "must have 2 entries for model `unicycle`, [v, ω] in m/s, rad/s: got 3",
        ),
    ] {
        let found = match parse(doc.to_string().as_bytes()) {
            Ok(spec) => spec.validate(&Limits::default()).unwrap_err().errors,
            other => panic!("{doc}: {other:?}"),
        };
        assert_eq!(
            found,
            [FieldError {
                pointer: pointer.into(),
                detail: detail.into()
            }],
            "{doc}"
        );
    }
    // An obstacle's centre is a point in the plane for every model: its
    // length is the document's shape.
    assert_eq!(
        shape_error(json!({"obstacles": [{"center": [1, 2, 3], "weight": 1}]})),
        (
            "/obstacles/0/center".into(),
            "invalid length 3, expected an array of length 2".into()
        )
    );
    // Names are strings only: serde alone also takes `{"euler": null}`.
    for doc in [
        json!({"integrator": {"euler": null}}),
        json!({"integrator": ["euler"]}),
        json!({"model": {"type": {"quadrotor_2d": null}}}),
        json!({"solver": {"method": {"ddp": null}}}),
        json!({"solver": {"method": {"ddp": 1}}}),
        json!({"solver": {"method": null}}),
        json!({"solver": {"method": 1}}),
    ] {
        let (pointer, detail) = shape_error(doc.clone());
        assert!(
            ["/integrator", "/model/type", "/solver/method"].contains(&pointer.as_str()),
            "{doc}: {pointer}"
        );
        assert!(detail.ends_with("expected a string"), "{doc}: {detail}");
    }
    assert!(errors(&json!({"integrator": "euler", "model": {"type": "quadrotor_2d"}})).is_empty());
    assert!(errors(&json!({"solver": {"method": "ddp"}})).is_empty());
    let (pointer, detail) = shape_error(json!({"solver": {"method": {"ddp": 1}}}));
    assert_eq!(pointer, "/solver/method");
    assert_eq!(
        errors(&json!({"solver": {"method": {"ddp": 1}}})),
        ["/solver/method"],
        "one error for one value: {detail}"
    );
    // Nested structs are objects only: serde alone fills them from arrays in
    // field order, so `{"solver": [5]}` would set max_iterations to 5. The
    // four members with defaults also take null (an obstacle has none).
    const OR_NULL: &str = "expected a JSON object, or null for the defaults";
    for (doc, pointer, expected) in [
        (json!({"model": []}), "/model", OR_NULL),
        (
            json!({"weights": [[1, 1, 1, 1, 1, 1]]}),
            "/weights",
            OR_NULL,
        ),
        (json!({"solver": [5]}), "/solver", OR_NULL),
        (json!({"solver": false}), "/solver", OR_NULL),
        (json!({"output": [false, false]}), "/output", OR_NULL),
        (
            json!({"obstacles": [{"center": [1, 1], "weight": 1}, [[1, 1], 5]]}),
            "/obstacles/1",
            "expected a JSON object",
        ),
        (
            json!({"obstacles": [null]}),
            "/obstacles/0",
            "expected a JSON object",
        ),
    ] {
        let (at, detail) = shape_error(doc.clone());
        assert_eq!(at, pointer, "{doc}");
        assert!(detail.ends_with(expected), "{doc}: {detail}");
    }
    assert_eq!(
        shape_error(json!({"obstacles": {}})).1,
        "invalid type: object, expected an array of JSON objects"
    );
    // ... and errors inside them still point into them.
    assert_eq!(
        shape_error(json!({"obstacles": [{"center": [1, 1], "weight": "a"}]})),
        (
            "/obstacles/0/weight".into(),
            "invalid type: string \"a\", expected a number".into()
        )
    );
    assert_eq!(
        shape_error(json!({"model": {"mass": null}})).0,
        "/model/mass"
    );
    // Integral but beyond 2^53, where f64 stops holding every integer.
    assert_eq!(
        shape_error(json!({"horizon": 1e20})).1,
        "1e20 is too large: expected an integer from 1 to the maximum horizon (10000 unless configured lower)"
    );
    // Numbers are written alike on both sides of the range (serde writes
    // the negative one `-1e+30`).
    assert_eq!(
        shape_error(json!({"horizon": -1e30})).1,
        "invalid value: number -1e30, expected an integer from 1 to the maximum horizon \
         (10000 unless configured lower)"
    );
    // A missing field is pointed at, not its parent object.
    assert_eq!(
        shape_error(json!({"obstacles": [{"weight": 1}, {"center": [0, 0]}]})),
        (
            "/obstacles/0/center".into(),
            "this field is required".into()
        )
    );
}

#[test]
fn several_errors_are_reported_together() {
    let errs = errors(&json!({"dt": -1, "horizon": 0, "weights": {"state": [-1, 1, 1, 1, 1, 1]}}));
    assert_eq!(errs, ["/dt", "/horizon", "/weights/state/0"]);
}

/// Messages name JSON's kinds (array, object, number, true, null), not
/// serde's data model (sequence, map, integer `5`, boolean `true`): the
/// reader sent JSON. A quoted string or key that holds such a word is
/// quoted as sent.
#[test]
fn shape_errors_name_json_kinds() {
    let first = |doc: &[u8]| match parse(doc) {
        Err(ParseError::Shape(s)) => s.first().detail.clone(),
        other => panic!(
            "{}: expected a shape error, got {other:?}",
            String::from_utf8_lossy(doc)
        ),
    };
    for (doc, detail) in [
        (&b"[]"[..], "invalid type: array, expected a JSON object"),
        // Unreadable (beyond f64) inside a root that is not an object.
        (b"[1e999]", "invalid type: array, expected a JSON object"),
        (b"5", "invalid type: number 5, expected a JSON object"),
        (b"true", "invalid type: true, expected a JSON object"),
        (
            br#"{"initial_state": {"x": 5}}"#,
            "invalid type: object, expected an array",
        ),
        (
            br#"{"initial_controls": {}}"#,
            "invalid type: object, expected an array",
        ),
        (
            br#"{"weights": []}"#,
            "invalid type: array, expected a JSON object, or null for the defaults",
        ),
        (br#"{"dt": [1]}"#, "invalid type: array, expected a number"),
        (
            br#"{"output": {"gains": 1}}"#,
            "invalid type: number 1, expected a boolean",
        ),
        (
            br#"{"horizon": 1.5}"#,
            "invalid value: number 1.5, expected an integer from 1 to the maximum horizon \
             (10000 unless configured lower)",
        ),
        (
            br#"{"dt": "sequence, map"}"#,
            r#"invalid type: string "sequence, map", expected a number"#,
        ),
    ] {
        assert_eq!(first(doc), detail, "{}", String::from_utf8_lossy(doc));
    }
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

/// A key given twice in one object is ambiguous (JSON leaves it open, and
/// serde_json's `Value` would keep the last silently): it is rejected at the
/// repeated key's pointer, at any depth, and only within one object.
#[test]
fn a_key_given_twice_in_one_object_is_rejected_at_its_pointer() {
    let repeated = |body: &str| match parse(body.as_bytes()) {
        Err(ParseError::Shape(s)) => {
            let f = s.first().clone();
            assert!(f.detail.contains("more than once"), "{body}: {}", f.detail);
            f.pointer
        }
        other => panic!("{body}: {other:?}"),
    };
    assert_eq!(repeated(r#"{"dt": 0.05, "dt": 10}"#), "/dt");
    assert_eq!(
        repeated(
            r#"{"weights": {"state": [1,1,1,1,1,1], "control": [1,1], "state": [2,2,2,2,2,2]}}"#
        ),
        "/weights/state"
    );
    assert_eq!(
        repeated(
            r#"{"obstacles": [{"center": [1,2], "weight": 1}, {"center": [1,2], "weight": 1, "weight": 2}]}"#
        ),
        "/obstacles/1/weight"
    );
    // Pointer escaping (RFC 6901), and the first repeat is the one named.
    assert_eq!(
        repeated(r#"{"a/b": 1, "a~b": 1, "a/b": 2, "dt": 1, "dt": 2}"#),
        "/a~1b"
    );
    // The same key in two different objects is no repeat.
    let ok = r#"{"obstacles": [{"center": [1,2], "weight": 1}, {"center": [3,4], "weight": 1}]}"#;
    assert!(parse(ok.as_bytes()).is_ok());
    // Broken JSON after a repeat is still a syntax error (400 over 422).
    assert!(matches!(
        parse(br#"{"dt": 1, "dt": 2, "horizon": }"#),
        Err(ParseError::Syntax(_))
    ));
}

#[test]
fn magnitudes_beyond_the_documented_ranges_are_rejected() {
    for (doc, pointer) in [
        (json!({"model": {"mass": 1e-7}}), "/model/mass"),
        (json!({"model": {"inertia": 2e6}}), "/model/inertia"),
        (
            json!({"model": {"arm_length": 1e-300}}),
            "/model/arm_length",
        ),
        (json!({"model": {"gravity": 1e5}}), "/model/gravity"),
        (json!({"dt": 11}), "/dt"),
        (
            json!({"initial_state": [2e6, 0, 0, 0, 0, 0]}),
            "/initial_state/0",
        ),
        (
            json!({"goal_state": [0, 0, 0, 0, 0, -1e300]}),
            "/goal_state/5",
        ),
        (
            json!({"weights": {"terminal": [1, 1, 1e13, 1, 1, 1]}}),
            "/weights/terminal/2",
        ),
        (
            json!({"obstacles": [{"center": [0, 1e200], "weight": 0}]}),
            "/obstacles/0/center/1",
        ),
        (
            json!({"obstacles": [{"center": [0, 0], "weight": 1e13}]}),
            "/obstacles/0/weight",
        ),
        (
            json!({"horizon": 3, "initial_controls": [[1, 1], [1e300, -1e300], [0, 0]]}),
            "/initial_controls/1/0",
        ),
    ] {
        rejects(doc, pointer);
    }
    // The bounds themselves are accepted.
    assert!(
        errors(
            &json!({"model": {"mass": 1e-6, "inertia": 1e6, "gravity": 1e4}, "dt": 10,
                       "goal_state": [1e6, -1e6, 0, 0, 0, 0]})
        )
        .is_empty()
    );
    // `null` is the same as leaving initial_controls out.
    assert_eq!(
        parse(br#"{"initial_controls": null}"#).unwrap(),
        ProblemSpec::default()
    );
}

/// `model`, `weights`, `solver` and `output` may be null, which leaves them
/// at their defaults as leaving them out does: clients generated from the
/// OpenAPI document (pydantic models from datamodel-code-generator) send
/// null for the nested objects a caller did not set.
#[test]
fn null_nested_objects_are_their_defaults() {
    let doc = br#"{"model": null, "weights": null, "solver": null, "output": null}"#;
    assert_eq!(parse(doc).unwrap(), ProblemSpec::default());
    // One at a time, beside members that are set: only the null one is
    // defaulted.
    let spec = parse(br#"{"horizon": 20, "solver": null, "model": {"mass": 2}}"#).unwrap();
    assert_eq!(spec.horizon, 20);
    assert_eq!(spec.model.get("mass"), Some(2.0));
    assert_eq!(spec.solver, ProblemSpec::default().solver);
    // Null inside them is still wrong where a value has no "none" (a mass),
    // and reported beside the other errors.
    assert_eq!(
        errors(&json!({"model": {"mass": null}, "weights": null, "dt": -1})),
        ["/model/mass", "/dt"]
    );
    // The document itself and an obstacle are not defaulted by null.
    assert_eq!(shape_error(json!(null)).0, "");
    assert_eq!(shape_error(json!({"obstacles": [null]})).0, "/obstacles/0");
}

/// The ranges exist so that no valid problem overflows: the most extreme one
/// (lightest, weakest-armed vehicle, strongest thrusts, longest steps and
/// horizon, largest weights) still has a finite initial cost and solves to a
/// finite result, with finite gains where it has any.
#[test]
fn the_most_extreme_valid_problem_stays_finite() {
    let n = 10_000;
    // The largest rotor imbalance, held: θ̇ grows every step; and the
    // largest total thrust, held: the speed does. The second's derivatives
    // overflow, so no backward pass completes there (`no_progress`, and no
    // gains, which the answer leaves out).
    for (controls, has_gains) in [
        (vec![[MAX_CONTROL, -MAX_CONTROL]; n], true),
        (vec![[MAX_CONTROL, MAX_CONTROL]; n], false),
    ] {
        let doc = json!({
            "model": {"mass": 1e-6, "inertia": 1e-6, "arm_length": 1e6, "gravity": 1e4},
            "dt": 10, "horizon": n,
            "initial_state": [1e6, -1e6, 1e6, -1e6, 1e6, -1e6],
            "goal_state": [-1e6, 1e6, -1e6, 1e6, -1e6, 1e6],
            "weights": {"state": vec![1e12; 6], "control": vec![1e12; 2], "terminal": vec![1e12; 6]},
            "obstacles": [{"center": [1e6, 1e6], "weight": 1e12}, {"center": [-1e6, -1e6], "weight": 1e12}],
            "initial_controls": controls,
            "solver": {"max_iterations": 3},
            "output": {"trace": false}
        });
        assert!(errors(&doc).is_empty());
        let spec = parse(doc.to_string().as_bytes()).unwrap();
        let r = solve(&spec, None, &Default::default()).expect("a valid problem solves");
        assert!(
            r.initial_cost.is_finite() && r.cost.is_finite(),
            "{} {}",
            r.initial_cost,
            r.cost
        );
        assert!(r.goal_distance.is_finite());
        assert!(r.closest_approach.iter().all(|d| d.is_finite()));
        assert!(r.states.iter().flatten().all(|v| v.is_finite()));
        assert_eq!(r.gains.is_some(), has_gains);
        if let Some(gains) = r.gains {
            assert!(
                gains
                    .feedback
                    .iter()
                    .flatten()
                    .flatten()
                    .all(|v| v.is_finite())
            );
        }
    }
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

#[test]
fn every_wrong_shape_is_listed_with_the_range_errors_of_the_rest() {
    // Two wrong types and a negative weight: all three in one answer.
    assert_eq!(
        errors(&json!({"dt": "x", "horizon": "y", "weights": {"state": [1, 1, -1, 1, 1, 1]}})),
        ["/dt", "/horizon", "/weights/state/2"]
    );
    // Unknown fields and a wrong type inside a nested object.
    assert_eq!(
        errors(&json!({"a": 1, "b": 2, "model": {"mass": "x", "inertia": -1}})),
        ["/a", "/b", "/model/mass", "/model/inertia"]
    );
    // A bad horizon reads as the default 100; the rows of initial_controls
    // are not then counted against it, but their values are still checked.
    assert_eq!(
        errors(&json!({"horizon": "x", "initial_controls": [[1, 1], [1e13, 1]]})),
        ["/horizon", "/initial_controls/1/0"]
    );
    // Every key given twice is listed, and the values under one are still
    // checked (the last is the one read).
    for (body, pointers) in [
        (
            r#"{"dt": 1, "dt": 2, "horizon": 1, "horizon": 2}"#,
            &["/dt", "/horizon"][..],
        ),
        (
            r#"{"weights": {}, "weights": {"state": [1, 1, -1, 1, 1, 1]}}"#,
            &["/weights", "/weights/state/2"],
        ),
        // A repeated horizon is still the horizon the rows must match.
        (
            r#"{"horizon": 3, "horizon": 2, "initial_controls": [[1, 1]]}"#,
            &["/horizon", "/initial_controls"],
        ),
    ] {
        match parse(body.as_bytes()) {
            Err(ParseError::Shape(s)) => {
                let all = s.with_range_errors(&Limits::default());
                let got: Vec<&str> = all.errors.iter().map(|e| e.pointer.as_str()).collect();
                assert_eq!(got, pointers, "{body}");
                assert!(!all.incomplete);
            }
            other => panic!("{body}: {other:?}"),
        }
    }
    // A key given twice is one error, whatever its last value is.
    for body in [r#"{"dt": "x", "dt": -3}"#, r#"{"dt": 1, "dt": -3}"#] {
        match parse(body.as_bytes()) {
            Err(ParseError::Shape(s)) => {
                let all = s.with_range_errors(&Limits::default()).errors;
                assert_eq!(all.len(), 1, "{body}: {all:?}");
                assert_eq!(all[0].pointer, "/dt");
            }
            other => panic!("{body}: {other:?}"),
        }
    }
    // A wrong shape inside an array is stood in for, so the array's other
    // elements are still read and checked: every wrong value in it is
    // listed, wrong shapes first, then the rest's ranges in schema order.
    assert_eq!(
        errors(&json!({"obstacles": [{"center": [1, "a"]}, {"weight": -1}], "dt": -1})),
        [
            "/obstacles/0/center/1",
            "/obstacles/1/center",
            "/dt",
            "/obstacles/1/weight"
        ]
    );
    for (doc, pointers) in [
        (
            json!({"obstacles": [{"center": [1, 2], "weight": -5}, {"center": "x", "weight": 1}]}),
            &["/obstacles/1/center", "/obstacles/0/weight"][..],
        ),
        (
            json!({"obstacles": ["x", {"center": [1e7, 0]}, [], {"center": [1, 2, 3]}]}),
            &[
                "/obstacles/0",
                "/obstacles/2",
                "/obstacles/3/center",
                "/obstacles/1/center/0",
            ],
        ),
        (
            json!({"weights": {"state": [1, "x", -1, 1, 1, 1], "control": [null, -1]}}),
            // Wrong shapes in key order, as everywhere.
            &[
                "/weights/control/0",
                "/weights/state/1",
                "/weights/state/2",
                "/weights/control/1",
            ],
        ),
        (
            json!({"initial_state": [1, 2, "3", 4, 5, 1e7], "goal_state": [true, 0, 0, 0, 0, 0]}),
            &["/goal_state/0", "/initial_state/2", "/initial_state/5"],
        ),
        // A row of the wrong shape keeps its place, so the rows are still
        // counted against the horizon and the others' values checked.
        (
            json!({"horizon": 3, "initial_controls": [[1, 1], [1, 2, 3], [1e13, "u"]]}),
            &[
                "/initial_controls/2/1",
                "/initial_controls/1",
                "/initial_controls/2/0",
            ],
        ),
        (
            json!({"horizon": 4, "initial_controls": [[1, 1], "x", [1e13, 0]]}),
            &[
                "/initial_controls/1",
                "/initial_controls",
                "/initial_controls/2/0",
            ],
        ),
    ] {
        assert_eq!(errors(&doc), pointers, "{doc}");
    }
}

#[test]
fn the_list_of_wrong_shapes_is_capped_and_its_rereads_bounded() {
    use ilqr_service::problem::{MAX_REPORTED_ERRORS, RETRY_BYTES};
    let all = |body: &[u8]| match parse(body) {
        Err(ParseError::Shape(s)) => s.with_range_errors(&Limits::default()),
        other => panic!("{other:?}"),
    };
    // 150 unknown fields in a small document: the first 100 are listed,
    // and the list says that checking stopped there.
    let mut doc = serde_json::Map::new();
    for i in 0..150 {
        doc.insert(format!("k{i:03}"), json!(i));
    }
    doc.insert("dt".into(), json!(-1));
    let invalid = all(Value::Object(doc).to_string().as_bytes());
    assert_eq!(invalid.errors.len(), MAX_REPORTED_ERRORS);
    assert_eq!(invalid.errors[0].pointer, "/k000");
    assert_eq!(invalid.errors[99].pointer, "/k099");
    assert!(invalid.incomplete);
    // A list that is complete says so.
    assert!(!all(br#"{"dt": "x", "horizon": 0}"#).incomplete);
    // In a large one, each extra read costs a read of the whole document,
    // so they stop at RETRY_BYTES in all.
    let rows = vec![json!([4.9, 4.9]); 12_000];
    let mut doc = serde_json::Map::new();
    doc.insert("initial_controls".into(), json!(rows));
    for i in 0..30 {
        doc.insert(format!("z{i:02}"), json!(i));
    }
    let body = Value::Object(doc).to_string();
    let reads = RETRY_BYTES / body.len();
    assert!((2..30).contains(&reads), "{} bytes", body.len());
    let invalid = all(body.as_bytes());
    assert_eq!(invalid.errors.len(), reads);
    assert_eq!(invalid.errors[0].pointer, "/z00");
    assert!(invalid.incomplete);
    // Wrong rows stand in for one per read, but the last fix takes out
    // their array, so the last read still checks the rest: 8 bad rows in
    // a document with 7 reads, and the bad dt is still listed (standing in
    // to the end would leave it unchecked). Rows 6 and 7 go unchecked with
    // the array, which the list says.
    let mut rows = vec![json!([4.905, 4.905]); 10_000];
    for row in rows.iter_mut().take(8) {
        *row = json!([null, 4.905]);
    }
    let body = json!({"dt": -1, "horizon": 10_000, "initial_controls": rows}).to_string();
    let reads = RETRY_BYTES / body.len();
    assert_eq!(reads, 7, "{} bytes", body.len());
    let invalid = all(body.as_bytes());
    let pointers: Vec<&str> = invalid.errors.iter().map(|e| e.pointer.as_str()).collect();
    let mut expected: Vec<String> = (0..6).map(|k| format!("/initial_controls/{k}/0")).collect();
    expected.push("/dt".into());
    assert_eq!(pointers, expected);
    assert!(invalid.incomplete);
    // Over RETRY_BYTES, one read: the first wrong shape only.
    let rows = vec![json!([4.9, 4.9]); 120_000];
    let mut doc = serde_json::Map::new();
    doc.insert("initial_controls".into(), json!(rows));
    doc.insert("z".into(), json!(0));
    doc.insert("zz".into(), json!(0));
    let body = Value::Object(doc).to_string();
    assert!(body.len() > RETRY_BYTES);
    let invalid = all(body.as_bytes());
    assert_eq!(invalid.errors.len(), 1);
    assert!(invalid.incomplete);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    /// Each field is left out, valid, of the wrong type or out of range:
    /// the errors name exactly the bad ones, each once.
    #[test]
    fn the_errors_name_exactly_the_bad_fields(
        kinds in prop::collection::vec(0u8..4, 7),
        unknown in any::<bool>(),
    ) {
        // (pointer, valid, wrong type, out of range; null: no such value)
        let fields: [(&str, Value, Value, Value); 7] = [
            ("/dt", json!(0.1), json!("x"), json!(-1)),
            ("/horizon", json!(20), json!([1]), json!(0)),
            ("/model/mass", json!(2), json!(true), json!(0)),
            ("/model/inertia", json!(2), json!({}), json!(1e9)),
            ("/solver/tolerance", json!(1e-6), json!("1e-6"), json!(2)),
            ("/solver/max_iterations", json!(50), json!(2.5), json!(20000)),
            ("/output/trace", json!(false), json!("no"), Value::Null),
        ];
        let mut doc = json!({});
        let mut expected = Vec::new();
        for ((pointer, valid, wrong, out), kind) in fields.iter().zip(&kinds) {
            let value = match kind {
                1 => valid,
                2 => wrong,
                3 if !out.is_null() => out,
                _ => continue,
            };
            if *kind >= 2 {
                expected.push(pointer.to_string());
            }
            let mut tokens = pointer.split('/').skip(1).peekable();
            let mut at = &mut doc;
            while let Some(t) = tokens.next() {
                if tokens.peek().is_none() {
                    at[t] = value.clone();
                } else {
                    at = at.as_object_mut().unwrap().entry(t).or_insert(json!({}));
                }
            }
        }
        if unknown {
            doc["model"]["colour"] = json!("red");
            expected.push("/model/colour".into());
        }
        let mut got = errors(&doc);
        let n = got.len();
        got.sort();
        got.dedup();
        prop_assert_eq!(got.len(), n, "a pointer listed twice for {}", doc);
        expected.sort();
        prop_assert_eq!(got, expected, "{}", doc);
    }
}

/// A huge key is in the pointer of every error under it: past the first
/// error, the list holds at most `MAX_REPORTED_BYTES` of pointers and
/// messages, and the rest are counted. Without that cap, 60 repeated keys
/// under a 100 kB key would give 6 MB of errors for a 100 kB body.
#[test]
fn errors_under_a_huge_key_are_listed_up_to_a_byte_cap() {
    use ilqr_service::problem::MAX_REPORTED_BYTES;
    let key = "k".repeat(100_000);
    let pairs: Vec<String> = (0..60).map(|i| format!(r#""a{i}":1,"a{i}":1"#)).collect();
    let body = format!(r#"{{"{key}": {{{}}}}}"#, pairs.join(","));
    let Err(ParseError::Shape(shapes)) = parse(body.as_bytes()) else {
        panic!("accepted");
    };
    let invalid = shapes.with_range_errors(&Limits::default());
    let bytes = |e: &ilqr_service::problem::FieldError| e.pointer.len() + e.detail.len();
    let listed: usize = invalid.errors[1..].iter().map(bytes).sum();
    assert!(listed <= MAX_REPORTED_BYTES, "{listed} bytes listed");
    // The first is listed whole, and the list is the first ones found: the
    // rest are counted, none dropped (60 repeats and the unknown key).
    assert_eq!(invalid.errors[0].pointer, format!("/{key}/a0"));
    assert!(invalid.errors.len() < 3, "{}", invalid.errors.len());
    assert_eq!(invalid.errors.len() + invalid.unlisted, 61);
    for (i, e) in invalid.errors.iter().enumerate() {
        assert_eq!(e.pointer, format!("/{key}/a{i}"));
    }

    // A key repeated three times is one invalid value, listed or only
    // counted: 1 + 2 under a huge key as 3 under a small one.
    for parent in ["x".to_owned(), "k".repeat(70_000)] {
        let body = format!(r#"{{"{parent}": {{"a0":1,"a0":1,"a1":1,"a1":1,"a1":1}}}}"#);
        let Err(ParseError::Shape(shapes)) = parse(body.as_bytes()) else {
            panic!("accepted");
        };
        let invalid = shapes.with_range_errors(&Limits::default());
        assert_eq!(
            invalid.errors.len() + invalid.unlisted,
            3,
            "{}",
            parent.len()
        );
    }

    // Small pointers still get the full hundred.
    let pairs: Vec<String> = (0..150).map(|i| format!(r#""a{i}":1,"a{i}":1"#)).collect();
    let body = format!(r#"{{"x": {{{}}}}}"#, pairs.join(","));
    let Err(ParseError::Shape(shapes)) = parse(body.as_bytes()) else {
        panic!("accepted");
    };
    let invalid = shapes.with_range_errors(&Limits::default());
    assert_eq!((invalid.errors.len(), invalid.unlisted), (100, 51));
}
