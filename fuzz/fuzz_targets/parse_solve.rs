//! Target 1: request bytes -> parse -> validate -> solve (small budget) ->
//! result JSON; every rejection rendered as the problem document the
//! service would send.
#![no_main]

use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use ilqr_service::problem::{ParseError, parse};
use ilqr_service::server::ApiError;
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

/// Budget per solve.
const BUDGET_MS: u64 = 30;

fn render(e: ApiError) {
    let status = e.status().as_u16();
    assert!(matches!(status, 400 | 413 | 415 | 422), "status {status}");
    let p = e.problem();
    let body = serde_json::to_vec(&p).expect("problem document serialises");
    assert!(!body.is_empty());
    if status == 422 {
        assert!(!p.errors.is_empty(), "422 without errors: {}", p.detail);
    }
}

fuzz_target!(|data: &[u8]| {
    // As the server with no flags.
    let limits = common::service_limits();
    let spec = match parse(data) {
        Ok(spec) => spec,
        Err(ParseError::Syntax(msg)) => return render(ApiError::MalformedJson(msg)),
        Err(ParseError::Shape(shapes)) => {
            return render(ApiError::Validation(shapes.with_range_errors(&limits)));
        }
    };
    if let Err(invalid) = spec.validate(&limits) {
        return render(ApiError::Validation(invalid));
    }
    // Override the budget so each exec is fast (the server would use the
    // request's, or its default of 10 s).
    let budget = Duration::from_millis(
        spec.solver
            .time_limit_ms
            .unwrap_or(BUDGET_MS)
            .min(BUDGET_MS),
    );
    let started = Instant::now();
    let cancel = AtomicBool::new(false);
    match ilqr_service::solve::solve(&spec, Some(budget), &cancel) {
        Ok(r) => {
            common::check_time(started, budget, &r, "parse_solve");
            common::check_result(&r, "parse_solve");
        }
        // A validated problem the solver refuses: the service answers 422
        // with this pointer; docs/api.md: "The ranges guarantee that no
        // valid problem overflows", so this should not happen.
        Err(u) => panic!("validated problem unsolvable: {:?}", u.0),
    }
});
