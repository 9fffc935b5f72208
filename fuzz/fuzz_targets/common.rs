//! Shared checks for the fuzz targets.
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use ilqr_service::problem::Limits;
use ilqr_service::solve::{SolveResult, SolveStatus};

/// The service's limits with no flags (max horizon 10000, max time limit
/// 60000 ms), read once.
pub fn service_limits() -> Limits {
    static LIMITS: OnceLock<Limits> = OnceLock::new();
    *LIMITS.get_or_init(|| ilqr_service::server::Config::default().limits())
}

/// The result as the service would send it: it serialises, reads back,
/// holds only finite numbers (serde_json writes NaN and ±inf as `null`,
/// which the OpenAPI schema's `number` does not allow; the panic names the
/// first one's JSON pointer), and costs no more than the initial guess
/// (documented).
pub fn check_result(r: &SolveResult, what: &str) {
    let json = r
        .to_json()
        .unwrap_or_else(|e| panic!("{what}: to_json failed: {e}"));
    let v: serde_json::Value = serde_json::from_slice(&json)
        .unwrap_or_else(|e| panic!("{what}: result JSON does not parse: {e}"));
    if let Some(pointer) = first_null(&v, String::new()) {
        panic!(
            "{what}: non-finite number at {pointer} (status {:?}, iterations {})",
            r.status, r.iterations
        );
    }
    if r.cost > r.initial_cost {
        panic!(
            "{what}: cost {} above initial cost {}",
            r.cost, r.initial_cost
        );
    }
}

/// The JSON pointer of the first `null` in `v`, if any.
fn first_null(v: &serde_json::Value, at: String) -> Option<String> {
    match v {
        serde_json::Value::Null => Some(at),
        serde_json::Value::Array(a) => a
            .iter()
            .enumerate()
            .find_map(|(i, x)| first_null(x, format!("{at}/{i}"))),
        serde_json::Value::Object(o) => o
            .iter()
            .find_map(|(k, x)| first_null(x, format!("{at}/{k}"))),
        _ => None,
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
