//! Shared checks for the fuzz targets.
use std::time::{Duration, Instant};

use ilqr_service::solve::{SolveResult, SolveStatus};

/// Every number in a result must be finite (serde_json writes NaN/inf as
/// `null`, which the OpenAPI schema's `number` does not allow).
pub fn check_finite(r: &SolveResult, what: &str) {
    let bad = |name: &str, x: f64| {
        if !x.is_finite() {
            panic!(
                "{what}: non-finite {name} = {x} (status {:?}, iterations {})",
                r.status, r.iterations
            );
        }
    };
    bad("cost", r.cost);
    bad("initial_cost", r.initial_cost);
    bad("goal_distance", r.goal_distance);
    for (j, c) in r.closest_approach.iter().enumerate() {
        bad(&format!("closest_approach[{j}]"), *c);
    }
    for (k, x) in r.states.iter().enumerate() {
        for (i, v) in x.iter().enumerate() {
            bad(&format!("states[{k}][{i}]"), *v);
        }
    }
    for (k, u) in r.controls.iter().enumerate() {
        for (i, v) in u.iter().enumerate() {
            bad(&format!("controls[{k}][{i}]"), *v);
        }
    }
    if let Some(g) = &r.gains {
        bad("gains.regularization", g.regularization);
        for (k, m) in g.feedback.iter().enumerate() {
            for (i, row) in m.iter().enumerate() {
                for (j, v) in row.iter().enumerate() {
                    bad(&format!("gains.feedback[{k}][{i}][{j}]"), *v);
                }
            }
        }
        for (k, d) in g.feedforward.iter().enumerate() {
            for (i, v) in d.iter().enumerate() {
                bad(&format!("gains.feedforward[{k}][{i}]"), *v);
            }
        }
    }
    if let Some(t) = &r.trace {
        for (k, row) in t.iter().enumerate() {
            bad(&format!("trace[{k}].cost"), row.cost);
            bad(
                &format!("trace[{k}].expected_reduction"),
                row.expected_reduction,
            );
            bad(
                &format!("trace[{k}].actual_reduction"),
                row.actual_reduction,
            );
            bad(&format!("trace[{k}].step_size"), row.step_size);
            bad(&format!("trace[{k}].regularization"), row.regularization);
            bad(
                &format!("trace[{k}].feedforward_norm"),
                row.feedforward_norm,
            );
            bad(&format!("trace[{k}].elapsed_ms"), row.elapsed_ms);
        }
    }
    bad("solve_time_ms", r.solve_time_ms);
    // Documented: cost never above the initial cost.
    if r.cost > r.initial_cost {
        panic!(
            "{what}: cost {} above initial cost {}",
            r.cost, r.initial_cost
        );
    }
}

/// The result serialises, the JSON reads back, and it holds no `null`.
pub fn check_json(r: &SolveResult, what: &str) {
    let json = r
        .to_json()
        .unwrap_or_else(|e| panic!("{what}: to_json failed: {e}"));
    let v: serde_json::Value = serde_json::from_slice(&json)
        .unwrap_or_else(|e| panic!("{what}: result JSON does not parse: {e}"));
    if contains_null(&v) {
        panic!("{what}: result JSON contains null");
    }
}

fn contains_null(v: &serde_json::Value) -> bool {
    match v {
        serde_json::Value::Null => true,
        serde_json::Value::Array(a) => a.iter().any(contains_null),
        serde_json::Value::Object(o) => o.values().any(contains_null),
        _ => false,
    }
}

/// A solve with budget `limit` must end within it plus this much slack
/// (the initial rollout always completes: ~11 ms at N = 10000 with 100
/// obstacles; the machine is shared, so be generous).
pub const SLACK: Duration = Duration::from_millis(500);

pub fn check_time(started: Instant, limit: Duration, r: &SolveResult, what: &str) {
    let took = started.elapsed();
    if took > limit + SLACK {
        panic!(
            "{what}: solve took {took:?} against a budget of {limit:?} (status {:?}, iterations {}, solve_time_ms {})",
            r.status, r.iterations, r.solve_time_ms
        );
    }
    if r.status == SolveStatus::TimeLimit && r.solve_time_ms > (limit + SLACK).as_secs_f64() * 1e3 {
        panic!(
            "{what}: time_limit status but solve_time_ms {}",
            r.solve_time_ms
        );
    }
}
