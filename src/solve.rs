//! From a validated [`ProblemSpec`] to a [`SolveResult`]: builds the core
//! problem (model, integrator, cost terms), runs the solver and turns its
//! output into the wire format. Shared by the CLI and the service.
//!
//! Each thread keeps the solver workspace of its last solve for the next one
//! (up to horizon 1000, about 1.5 MB), so a service worker allocates only
//! the answer's own vectors per request.

use std::cell::Cell;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use ilqr::{
    ControlEffort, Cost, DiscreteDynamics, Euler, ExpObstacle, Objective, Options, Problem,
    Quadrotor2D, SolveError, Solver, StateTracking, TerminalTracking,
};
use nalgebra::{SVector, Vector2};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use crate::problem::{FieldError, Integrator, Method, ModelKind, ProblemSpec};
use crate::schema;

/// How a solve ended. Every status is a successful answer carrying the best
/// trajectory found.
///
/// * `converged`: the model about the result predicts that a full step
///   would gain less than `solver.tolerance` × |cost| (and the last full
///   step gained less too, or no regularisation was needed), or the cost
///   reached 0, its lower bound, up to round-off;
/// * `max_iterations`: `solver.max_iterations` ran out first;
/// * `time_limit`: the time budget (`solver.time_limit_ms`, counted from
///   admission) ran out first;
/// * `cancelled`: the client left, or the service was shutting down;
/// * `no_progress`: no step could reduce the cost at any regularisation,
///   with the exact Hessian nor (with obstacles, or with `ddp`) the convex
///   model tried after it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum SolveStatus {
    /// The model about the result (the cost's exact Hessian) predicts that
    /// a full step would gain less than `solver.tolerance` relative to the
    /// cost, after a full step gained less than that too or with no
    /// regularisation needed; or the cost is 0, its lower bound (a global
    /// optimum: every weight is zero, say), up to round-off (within 4.9e-32,
    /// machine epsilon squared, of the initial cost).
    Converged,
    /// `solver.max_iterations` ran out first.
    MaxIterations,
    /// The time budget ran out first.
    TimeLimit,
    /// The solve was cancelled (client gone, or service shutting down).
    Cancelled,
    /// Regularisation passed its maximum: no step could reduce the cost,
    /// with the exact Hessian nor (with obstacles, or with `ddp`) with the convex model
    /// tried after it; or the exact Hessian could not move from a point
    /// where the convex model stopped (see `convex_model_at_end`).
    NoProgress,
}

impl SolveStatus {
    /// The wire name, e.g. `max_iterations`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Converged => "converged",
            Self::MaxIterations => "max_iterations",
            Self::TimeLimit => "time_limit",
            Self::Cancelled => "cancelled",
            Self::NoProgress => "no_progress",
        }
    }
}

impl From<ilqr::Status> for SolveStatus {
    fn from(s: ilqr::Status) -> Self {
        match s {
            ilqr::Status::Converged => Self::Converged,
            ilqr::Status::MaxIterations => Self::MaxIterations,
            ilqr::Status::TimeLimit => Self::TimeLimit,
            ilqr::Status::Cancelled => Self::Cancelled,
            ilqr::Status::NoProgress => Self::NoProgress,
        }
    }
}

/// The solution of a problem.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct SolveResult {
    /// How the solve ended.
    pub status: SolveStatus,
    /// Final cost J: eqs. 13–15 of the paper summed over the horizon, with
    /// no ½ factors. A weighted sum of squared errors in m², rad², (m/s)²,
    /// (rad/s)² and N², plus the obstacle terms, so it has no single unit:
    /// compare costs of one problem, not across weights.
    pub cost: f64,
    /// Cost of the initial guess (the initial controls rolled out), same
    /// terms as `cost`.
    pub initial_cost: f64,
    /// Iterations performed.
    pub iterations: usize,
    /// Distance (m) of the final position from the goal position.
    pub goal_distance: f64,
    /// For each obstacle, the smallest distance (m) from its centre to the
    /// path: the straight segments between consecutive states' positions
    /// (the path the model flies under explicit Euler), not only the states
    /// themselves. The cost penalises the obstacle at the states only, so at
    /// a coarse `dt` this can be much smaller than the distance at any state.
    pub closest_approach: Vec<f64>,
    /// The optimised states.
    #[schema(schema_with = schema::states)]
    pub states: Vec<[f64; 6]>,
    /// The optimised controls.
    #[schema(schema_with = schema::controls)]
    pub controls: Vec<[f64; 2]>,
    /// The time-varying feedback policy. Absent when `output.gains` is
    /// false, and when no backward pass completed, so that there is no
    /// policy to give: a solve that ended (`time_limit` or `cancelled`, 0
    /// iterations) before its first backward pass completed, or one whose
    /// first pass failed at every regularisation, with the exact and (with
    /// obstacles) the convex model (`no_progress`, 0 iterations; only where
    /// the derivatives overflow, at extreme parameters).
    // Left out when None, never `null`: the schema must not offer null.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    #[schema(nullable = false)]
    pub gains: Option<Gains>,
    /// One row per iteration; absent when `output.trace` is false.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    #[schema(nullable = false)]
    pub trace: Option<Vec<TraceEntry>>,
    /// Absent when the solve used the cost's exact Hessian throughout (the
    /// seed and nearly every problem). Otherwise the number of iterations
    /// completed when it fell back to a convex model of the cost: the
    /// exact Hessian gave no progress at any μ up to 1e20 (`Q_uu + μI`
    /// indefinite, or no step the line search accepts: obstacles' negative
    /// curvature piled up over a long horizon, a flight of 200 s or more,
    /// or steps of seconds), and the solve went on with the obstacles'
    /// curvature across their radial direction dropped. Where the convex
    /// model converges, the solve goes back to the exact Hessian to check
    /// that point (the convex model's larger curvature can under-predict
    /// what a step gains): see `convex_model_at_end`.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    #[schema(nullable = false, minimum = 0)]
    pub convexified_after_iteration: Option<usize>,
    /// Present with `convexified_after_iteration`. True: the gains come from
    /// the convex model (the solve stopped on it, or the exact Hessian could
    /// complete no backward pass about its minimum); never with `converged`,
    /// which the exact Hessian confirms. False: the exact Hessian took over
    /// again and gave the gains.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    #[schema(nullable = false)]
    pub convex_model_at_end: Option<bool>,
    /// Time spent solving, in ms.
    pub solve_time_ms: f64,
    /// Time spent waiting for a worker, in ms (0 outside the service).
    pub queue_time_ms: f64,
}

/// Feedback and feedforward gains along the trajectory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct Gains {
    /// `K_k`, see the schema description.
    #[schema(schema_with = schema::feedback)]
    pub feedback: Vec<[[f64; 6]; 2]>,
    /// `d_k`, see the schema description.
    #[schema(schema_with = schema::feedforward)]
    pub feedforward: Vec<[f64; 2]>,
    /// The regularisation μ of the backward pass that produced these gains
    /// (`Q_uu + μI` in place of `Q_uu`, in the cost's units per N²). 0: the
    /// undamped Riccati gains; larger values give smaller, more cautious `K`
    /// and `d`. A solve that converges usually ends at 0; one stopped by a
    /// cap, a budget or near an obstacle's steep centre may not. A solve
    /// that ends `no_progress` or `max_iterations` after failed line
    /// searches returns the least damped gains about its result (0 where
    /// the model allows it). Gains at a large μ (above about 1e6, where the
    /// solver had to overpower negative curvature) are not a stabilising
    /// policy: check them in simulation before flying them.
    #[schema(minimum = 0.0)]
    pub regularization: f64,
    /// False: the gains were computed about the returned `states` and
    /// `controls`. True when the solve stopped (`time_limit` or
    /// `cancelled`; `no_progress` only where the derivatives overflow) after
    /// an accepted step but before the backward pass about the new iterate
    /// completed (while linearising about it, during the pass, or while
    /// raising the regularisation): the gains are then
    /// the previous iterate's, one accepted step away: a fallback. At the
    /// last knot `K` was 0–12% off with one to six obstacles and 2–60% off
    /// with 100 (the cases measured), and `feedforward` 7.8% to over
    /// 1000% off. Common when a tight `time_limit_ms` stops a long horizon; never
    /// at N below 128 unless the regularisation was being raised.
    pub about_previous_iterate: bool,
}

/// One iteration of the solver.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct TraceEntry {
    /// 1-based iteration number.
    #[schema(minimum = 1)]
    pub iteration: usize,
    /// Cost after the iteration (unchanged when no step was accepted).
    pub cost: f64,
    /// Reduction the quadratic model predicted for the step taken, or for
    /// the last step size tried when none was accepted.
    pub expected_reduction: f64,
    /// Reduction achieved (0 when no step was accepted).
    pub actual_reduction: f64,
    /// Line-search step size α accepted, 0 when none was.
    pub step_size: f64,
    /// Levenberg–Marquardt regularisation μ of the backward pass
    /// (`Q_uu + μI`): 0, or at least 1e-6.
    #[schema(minimum = 0.0)]
    pub regularization: f64,
    /// Mean over steps of `max_i |d_i| / (|u_i| + 1)`.
    pub feedforward_norm: f64,
    /// True when the iteration's backward pass used the convex model of
    /// the cost (obstacles' curvature across their radial direction
    /// dropped) instead of its exact Hessian: in the iterations after
    /// `convexified_after_iteration` (the first is iteration
    /// `convexified_after_iteration + 1`), until the exact Hessian takes
    /// over again to check the convex model's minimum; true again if it
    /// falls back a second time. False on nearly every solve.
    pub convex_model: bool,
    /// Time since the solve started, ms.
    pub elapsed_ms: f64,
}

/// A problem that passed validation but cannot be solved as posed.
#[derive(Debug, Clone, PartialEq)]
pub struct Unsolvable(pub FieldError);

/// Solve a problem that [`ProblemSpec::validate`] accepted, within the
/// wall-clock budget `time_limit` (the caller decides it: the CLI uses
/// `solver.time_limit_ms`, the service also counts the time spent queued).
/// `cancel` is polled with the budget, every iteration and every 128 knots
/// of a pass.
pub fn solve(
    spec: &ProblemSpec,
    time_limit: Option<Duration>,
    cancel: &AtomicBool,
) -> Result<SolveResult, Unsolvable> {
    let (problem, u_init) = build(spec);
    let options = Options {
        max_iterations: spec.solver.max_iterations,
        tolerance: spec.solver.tolerance,
        time_limit,
        // Every term is non-negative (validation keeps weights ≥ 0), so a
        // cost of 0 is a global optimum.
        cost_lower_bound: Some(0.0),
        second_order: spec.solver.method == Method::Ddp,
        ..Options::default()
    };

    let cacheable = spec.horizon <= CACHED_HORIZON;
    let mut solver = cacheable
        .then(|| CACHED_SOLVER.take())
        .flatten()
        .unwrap_or_else(|| Solver::<6, 2>::new(spec.horizon));
    let result = solve_on(&mut solver, spec, &problem, &u_init, &options, cancel);
    if cacheable {
        CACHED_SOLVER.set(Some(solver));
    }
    result
}

/// The problem `spec` describes, in the solver's types, and its
/// initial controls (hover thrust unless given).
fn build(
    spec: &ProblemSpec,
) -> (
    Problem<Euler<Quadrotor2D>, Objective<6, 2>, 6>,
    Vec<Vector2<f64>>,
) {
    let ModelKind::Quadrotor2d = spec.model.kind;
    let Integrator::Euler = spec.integrator;
    let model = Quadrotor2D {
        mass: spec.model.mass,
        inertia: spec.model.inertia,
        arm_length: spec.model.arm_length,
        gravity: spec.model.gravity,
    };
    let goal = SVector::from(spec.goal_state);
    let mut cost = Objective::new()
        .with_stage(StateTracking {
            goal,
            weights: SVector::from(spec.weights.state),
        })
        .with_stage(ControlEffort {
            weights: Vector2::from(spec.weights.control),
        })
        .with_terminal(TerminalTracking {
            goal,
            weights: SVector::from(spec.weights.terminal),
        });
    for o in &spec.obstacles {
        cost = cost.with_stage(ExpObstacle {
            center: Vector2::from(o.center),
            weight: o.weight,
            position: (0, 1),
        });
    }
    let problem = Problem {
        dynamics: Euler { model, dt: spec.dt },
        cost,
        x0: SVector::from(spec.initial_state),
        horizon: spec.horizon,
    };
    let u_init: Vec<Vector2<f64>> = match &spec.initial_controls {
        Some(us) => us.iter().map(|u| Vector2::from(*u)).collect(),
        None => vec![Vector2::repeat(model.hover_thrust()); spec.horizon],
    };
    (problem, u_init)
}

/// The solver's gains in the wire's layout (`feedback` row-major: row i is
/// rotor i's gains over the six states), with what the summary says of
/// them.
fn wire_gains(solver: &Solver<6, 2>, summary: &ilqr::Summary) -> Gains {
    Gains {
        feedback: solver
            .feedback()
            .iter()
            .map(|k| [k.row(0).transpose().into(), k.row(1).transpose().into()])
            .collect(),
        feedforward: solver.feedforward().iter().map(|d| (*d).into()).collect(),
        regularization: summary.gains_regularization,
        about_previous_iterate: summary.gains_about_previous_iterate,
    }
}

/// Run `solver` on the built problem and convert what it found.
fn solve_on<D: DiscreteDynamics<6, 2>, C: Cost<6, 2>>(
    solver: &mut Solver<6, 2>,
    spec: &ProblemSpec,
    problem: &Problem<D, C, 6>,
    u_init: &[Vector2<f64>],
    options: &Options,
    cancel: &AtomicBool,
) -> Result<SolveResult, Unsolvable> {
    let summary = solver
        .solve(problem, u_init, options, cancel)
        .map_err(|e| Unsolvable(field_error(e, spec)))?;

    let states: Vec<[f64; 6]> = solver.states().iter().map(|x| (*x).into()).collect();
    let position = |x: &[f64; 6], c: [f64; 2]| (x[0] - c[0]).hypot(x[1] - c[1]);
    let last = states.last().copied().unwrap_or(spec.initial_state);
    let goal_distance = position(&last, [spec.goal_state[0], spec.goal_state[1]]);
    let closest_approach = spec
        .obstacles
        .iter()
        .map(|o| closest_approach(&states, o.center))
        .collect();
    // Zero gains from a solve whose first backward pass never completed
    // would read as a valid (open-loop) policy; leave them out instead.
    let gains = (spec.output.gains && summary.has_gains).then(|| wire_gains(solver, &summary));
    let trace = spec.output.trace.then(|| {
        solver
            .trace()
            .iter()
            .map(|r| TraceEntry {
                iteration: r.iteration,
                cost: r.cost,
                expected_reduction: r.expected_reduction,
                actual_reduction: r.actual_reduction,
                step_size: r.step_size,
                regularization: r.regularization,
                feedforward_norm: r.feedforward_norm,
                convex_model: r.convex_model,
                elapsed_ms: millis(r.elapsed),
            })
            .collect()
    });
    Ok(SolveResult {
        status: summary.status.into(),
        cost: summary.cost,
        initial_cost: summary.initial_cost,
        iterations: summary.iterations,
        goal_distance,
        closest_approach,
        states,
        controls: solver.controls().iter().map(|u| (*u).into()).collect(),
        gains,
        trace,
        convexified_after_iteration: summary.convexified_after,
        convex_model_at_end: summary.convexified_after.map(|_| summary.gains_convex),
        solve_time_ms: millis(summary.solve_time),
        queue_time_ms: 0.0,
    })
}

/// A duration in milliseconds, as the nearest double to its whole
/// nanoseconds / 10⁶, so that JSON writes `43.6889`, not the
/// `43.688900000000004` of `as_secs_f64() * 1e3` (two roundings).
pub fn millis(d: Duration) -> f64 {
    // Exact below 2⁵³ ns (104 days), and one correctly rounded division.
    d.as_nanos() as f64 / 1e6
}

/// Longest horizon whose solver workspace a thread keeps for its next solve
/// (about 1.5 kB per step: at most ~1.5 MB per thread). Longer problems
/// allocate their own; next to their solve time that costs nothing.
const CACHED_HORIZON: usize = 1000;

thread_local! {
    /// The solver this thread used last, kept for its next solve. A fresh
    /// workspace for the seed problem is ~146 kB allocated and zeroed per
    /// solve, and glibc returns such blocks to the kernel when they are
    /// freed, so every solve also paid page faults and TLB shootdowns. The
    /// solver resizes its buffers to each problem's horizon (keeping their
    /// capacity), and a panicking solve simply drops it.
    static CACHED_SOLVER: Cell<Option<Solver<6, 2>>> = const { Cell::new(None) };
}

impl SolveResult {
    /// The result as compact JSON, in a buffer sized for it up front (a
    /// seed result is 16–50 kB; growing a small buffer by doubling copies
    /// it several times).
    pub fn to_json(&self) -> serde_json::Result<Vec<u8>> {
        // ~20 bytes per number on the wire; 24 leaves room without waste.
        let numbers = self.states.len() * 6
            + self.controls.len() * 2
            + self.gains.as_ref().map_or(0, |g| g.feedback.len() * 14)
            + self.trace.as_ref().map_or(0, |t| t.len() * 8)
            + self.closest_approach.len();
        let mut buf = Vec::with_capacity(24 * numbers + 512);
        serde_json::to_writer(&mut buf, self)?;
        Ok(buf)
    }
}

/// The smallest distance (m) from `center` to the path through the
/// states' positions, taken as straight segments between knots. Under
/// explicit Euler that is the path itself (the position moves with the
/// constant velocity `v_k` during step k); the knots alone can miss a close
/// pass: at `dt = 1` the seed's path passes 0.2 m from the centre between
/// two knots that are both 3.4 m away. The cost, like the paper's, sees
/// only the knots.
fn closest_approach(states: &[[f64; 6]], center: [f64; 2]) -> f64 {
    // Squared distances pick the nearest point, and `hypot` (about 20 ns,
    // five times the rest of a segment's work) runs once, on it: at
    // N = 10000 with 100 obstacles the million calls took about 13 ms per
    // answer. Squares overflow past 1.3e154 m; if every point is that far,
    // the slow loop below measures them. (They underflow below 1.5e-154 m,
    // where the first such point is taken as the nearest: an error far
    // below any distance that matters.)
    let mut best = f64::INFINITY;
    let mut nearest = None;
    for_each_nearest_point(states, center, |a, b| {
        let d2 = a * a + b * b;
        if d2 < best {
            best = d2;
            nearest = Some((a, b));
        }
    });
    if let Some((a, b)) = nearest {
        return a.hypot(b);
    }
    let mut best = f64::INFINITY;
    for_each_nearest_point(states, center, |a, b| best = best.min(a.hypot(b)));
    best
}

/// Calls `f` with the offset from `center` of the first state's position,
/// then of each segment's point nearest `center`.
fn for_each_nearest_point(states: &[[f64; 6]], center: [f64; 2], mut f: impl FnMut(f64, f64)) {
    let at = |x: &[f64; 6]| (x[0] - center[0], x[1] - center[1]);
    if let Some(x) = states.first() {
        let (a, b) = at(x);
        f(a, b);
    }
    for pair in states.windows(2) {
        // Relative to the centre: p0 and the segment d = p1 − p0.
        let (x0, y0) = at(&pair[0]);
        let (x1, y1) = at(&pair[1]);
        let (dx, dy) = (x1 - x0, y1 - y0);
        let len2 = dx * dx + dy * dy;
        // The segment's point nearest the centre, t in [0, 1]. A segment of
        // zero (or non-finite) length counts by its end point; its start
        // was counted as the previous segment's end (or as the first state).
        let t = if len2 > 0.0 && len2.is_finite() {
            (-(x0 * dx + y0 * dy) / len2).clamp(0.0, 1.0)
        } else {
            1.0
        };
        f(x0 + t * dx, y0 + t * dy);
    }
}

fn field_error(e: SolveError, spec: &ProblemSpec) -> FieldError {
    let pointer = match e {
        SolveError::EmptyHorizon => "/horizon",
        SolveError::ControlsLength { .. } => "/initial_controls",
        SolveError::InitialRolloutNotFinite { .. } if spec.initial_controls.is_some() => {
            "/initial_controls"
        }
        SolveError::InitialRolloutNotFinite { .. } => "",
    };
    FieldError {
        pointer: pointer.to_owned(),
        detail: e.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whole nanoseconds print as at most six decimals of a millisecond,
    /// never with the tail of a second rounding.
    #[test]
    fn millis_prints_what_was_measured() {
        for (nanos, json) in [
            (43_688_900, "43.6889"),
            (33_626, "0.033626"),
            (1, "1e-6"),
            (0, "0.0"),
            (86_400_000_000_000, "86400000.0"),
        ] {
            let ms = serde_json::to_string(&millis(Duration::from_nanos(nanos))).unwrap();
            assert_eq!(ms, json);
        }
        // The old expression, for contrast: the test's first case is one
        // it got wrong.
        assert_ne!(
            (Duration::from_nanos(43_688_900).as_secs_f64() * 1e3).to_string(),
            "43.6889"
        );
    }

    /// The wire gains carry the summary's word on them (a gain about the
    /// previous iterate cannot be produced on demand through a solve: it
    /// needs a budget to run out at one exact point) and the solver's
    /// `K` in row-major order.
    #[test]
    fn wire_gains_pass_on_what_the_summary_says_and_k_row_major() {
        // The seed problem, as a request of `{}` builds it.
        let (problem, u_init) = build(&ProblemSpec::default());
        let mut solver = Solver::<6, 2>::new(problem.horizon);
        let mut summary = solver
            .solve(
                &problem,
                &u_init,
                &Options::default(),
                &AtomicBool::new(false),
            )
            .unwrap();
        for flag in [false, true] {
            summary.gains_about_previous_iterate = flag;
            summary.gains_regularization = 0.25;
            let gains = wire_gains(&solver, &summary);
            assert_eq!(gains.about_previous_iterate, flag);
            assert_eq!(gains.regularization, 0.25);
            for (k, (wire, core)) in gains.feedback.iter().zip(solver.feedback()).enumerate() {
                for (i, j) in (0..2).flat_map(|i| (0..6).map(move |j| (i, j))) {
                    assert_eq!(wire[i][j], core[(i, j)], "K_{k}[{i}][{j}]");
                }
            }
        }
        // The rotors' rows differ (they turn the body opposite ways), so a
        // swap of the rows would be seen.
        assert!(
            solver
                .feedback()
                .iter()
                .any(|k| (k[(0, 2)] - k[(1, 2)]).abs() > 1e-3)
        );
    }

    /// Squares overflow past 1.3e154 m: where every point is that far, the
    /// distances are still measured (with `hypot`), and a finite point
    /// beats any overflowing one.
    #[test]
    fn closest_approach_survives_overflowing_squares() {
        let at = |x: f64, y: f64| [x, y, 0.0, 0.0, 0.0, 0.0];
        let far = [at(1e200, 0.0), at(1e200, 3e200)];
        assert_eq!(super::closest_approach(&far, [0.0, 0.0]), 1e200);
        let mixed = [at(3.0, 4.0), at(3.0, 4.0), at(1e200, 1e200)];
        assert_eq!(super::closest_approach(&mixed, [0.0, 0.0]), 5.0);
        // The nearest point of a segment, not only its ends.
        let line = [at(-1.0, 2.0), at(1.0, 2.0)];
        assert_eq!(super::closest_approach(&line, [0.0, 0.0]), 2.0);
        assert_eq!(super::closest_approach(&[], [0.0, 0.0]), f64::INFINITY);
    }
}
