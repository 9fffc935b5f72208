//! Cancellation and the time budget are polled inside the long passes, not
//! only between them: a pass over N knots with many obstacles costs
//! milliseconds (20 ms at N = 10000 with 100 obstacles), which is how late
//! an answer would come if only the driver loop polled.
//!
//! The tests trip the cancellation flag from inside the cost at a chosen
//! call, so where the solve stops is deterministic (a clock would not be),
//! and count how much work ran after the trip. The solver polls every 128
//! knots; the bound asserted is that, so a pass that ran to its end (10000
//! knots) fails.

use crate::common;

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use common::{hover, seed_problem};
use ilqr::{Cost, Objective, Options, Problem, Solver, StageExpansion, Status, TerminalExpansion};
use nalgebra::SVector;

const N: usize = 10_000;
/// The solver's poll interval, in knots.
const POLL_EVERY: usize = 128;

/// Which call of the cost sets the cancellation flag.
#[derive(Clone, Copy)]
enum Trip {
    /// The n-th call of `stage_expand` (1-based): inside a linearisation.
    Expand(usize),
    /// The n-th call of `stage` (1-based): inside a rollout.
    Stage(usize),
}

/// The seed objective, counting its calls and setting `cancel` at `trip`.
struct Tripwire<'a> {
    inner: Objective<6, 2>,
    cancel: &'a AtomicBool,
    trip: Trip,
    expands: AtomicUsize,
    stages: AtomicUsize,
}

impl Cost<6, 2> for Tripwire<'_> {
    fn stage(&self, k: usize, x: &SVector<f64, 6>, u: &SVector<f64, 2>) -> f64 {
        let calls = self.stages.fetch_add(1, Ordering::Relaxed) + 1;
        if matches!(self.trip, Trip::Stage(n) if n == calls) {
            self.cancel.store(true, Ordering::Relaxed);
        }
        self.inner.stage(k, x, u)
    }

    fn stage_expand(
        &self,
        k: usize,
        x: &SVector<f64, 6>,
        u: &SVector<f64, 2>,
        e: &mut StageExpansion<6, 2>,
    ) {
        let calls = self.expands.fetch_add(1, Ordering::Relaxed) + 1;
        if matches!(self.trip, Trip::Expand(n) if n == calls) {
            self.cancel.store(true, Ordering::Relaxed);
        }
        self.inner.stage_expand(k, x, u, e);
    }

    fn terminal(&self, x: &SVector<f64, 6>) -> f64 {
        self.inner.terminal(x)
    }

    fn terminal_expand(&self, x: &SVector<f64, 6>, e: &mut TerminalExpansion<6>) {
        self.inner.terminal_expand(x, e);
    }
}

/// Solve the seed scenario over `N` knots (dt = 0.0005, the long-horizon
/// benchmark problem, whose first backward pass succeeds at μ = 1), with
/// the flag tripped at `trip`. Returns the solver, the summary and the
/// cost's call counts `(stage, stage_expand)`.
fn solve_tripped(trip: Trip) -> (Solver<6, 2>, ilqr::Summary, usize, usize) {
    let cancel = AtomicBool::new(false);
    let seed = seed_problem(N, 0.0005);
    let problem = Problem {
        dynamics: seed.dynamics,
        cost: Tripwire {
            inner: seed.cost,
            cancel: &cancel,
            trip,
            expands: AtomicUsize::new(0),
            stages: AtomicUsize::new(0),
        },
        x0: seed.x0,
        horizon: N,
    };
    let mut solver = Solver::new(N);
    let options = Options {
        tolerance: 0.0,
        ..Options::default()
    };
    let s = solver
        .solve(&problem, &hover(N), &options, &cancel)
        .expect("the problem is valid");
    let stages = problem.cost.stages.load(Ordering::Relaxed);
    let expands = problem.cost.expands.load(Ordering::Relaxed);
    (solver, s, stages, expands)
}

/// Where the trips fall: 100 knots into a pass. With a poll interval P the
/// pass stops after P − 1 knots, so the bounds (under 100 + 128) fail for
/// P ≥ 229; the unit tests in `solver/passes.rs` pin the interval itself.
const TRIP: usize = 100;

#[test]
fn a_linearisation_stops_within_one_poll_interval() {
    let (solver, s, _, expands) = solve_tripped(Trip::Expand(TRIP));
    assert_eq!((s.status, s.iterations), (Status::Cancelled, 0), "{s:?}");
    assert!(
        expands < TRIP + POLL_EVERY,
        "{expands} knots linearised, the trip was at {TRIP}"
    );
    // No backward pass ran, so there are no gains to return.
    assert!(!s.has_gains);
    assert!(solver.trace().is_empty());
    assert_eq!(s.cost, s.initial_cost);
}

#[test]
fn a_rollout_stops_within_one_poll_interval_and_is_discarded() {
    // The initial rollout makes N `stage` calls; trip into the first
    // line-search rollout.
    let trip = N + TRIP;
    let (solver, s, stages, _) = solve_tripped(Trip::Stage(trip));
    assert_eq!((s.status, s.iterations), (Status::Cancelled, 1), "{s:?}");
    assert!(
        stages < trip + POLL_EVERY,
        "{} knots rolled out after the trip",
        stages - trip
    );
    // The partial rollout is not the answer: the nominal trajectory stays,
    // and so the gains of the backward pass about it are current.
    assert_eq!(s.cost, s.initial_cost);
    assert!(s.has_gains && !s.gains_about_previous_iterate, "{s:?}");
    let row = &solver.trace()[0];
    assert_eq!((row.step_size, row.actual_reduction), (0.0, 0.0));
    // The row still tells what the cut-short step (α = 1) was expected to gain.
    assert!(row.expected_reduction > 0.0, "{row:?}");
    assert!(solver.controls().iter().all(|u| *u == hover(1)[0]));
}

#[test]
fn a_backward_pass_stops_within_one_poll_interval_and_keeps_no_half_gains() {
    // Tripped at the linearisation's last knot, after its last poll: the
    // linearisation completes and the backward pass is the first to poll.
    let (solver, s, _, expands) = solve_tripped(Trip::Expand(N));
    assert_eq!(expands, N);
    assert_eq!((s.status, s.iterations), (Status::Cancelled, 0), "{s:?}");
    // Had the pass run to its end, its gains would be returned.
    assert!(!s.has_gains, "{s:?}");
    assert!(
        solver
            .feedback()
            .iter()
            .all(|k| k.iter().all(|v| *v == 0.0)),
        "the interrupted pass wrote into the returned feedback gains"
    );
    assert!(
        solver
            .feedforward()
            .iter()
            .all(|d| d.iter().all(|v| *v == 0.0)),
        "the interrupted pass wrote into the returned feedforward"
    );
}

#[test]
fn a_linearisation_after_an_accepted_step_flags_the_gains_it_returns() {
    // Tripped in the second linearisation, about the iterate the first
    // iteration's accepted step produced: the gains returned are the first
    // pass's, about the initial guess, and must say so.
    let trip = N + TRIP;
    let (solver, s, _, expands) = solve_tripped(Trip::Expand(trip));
    assert_eq!((s.status, s.iterations), (Status::Cancelled, 1), "{s:?}");
    assert!(expands < trip + POLL_EVERY, "{expands}");
    assert!(
        s.cost < s.initial_cost,
        "the first step was accepted: {s:?}"
    );
    assert!(s.has_gains && s.gains_about_previous_iterate, "{s:?}");
    assert_eq!(solver.trace().len(), 1);
    assert!(solver.trace()[0].step_size > 0.0);
}
