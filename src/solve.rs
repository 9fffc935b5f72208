//! From a validated [`ProblemSpec`] to a [`SolveResult`]: builds the core
//! problem (model, integrator, cost terms), runs the solver and turns its
//! output into the wire format. Shared by the CLI and the service.
//!
//! With obstacles, a solve is a search over routes: the plain start and
//! the detours of [`ilqr::search`], each a solve of its own (a detour's
//! begins with a guiding solve), run on this thread and on the threads a
//! caller lends ([`Helpers`]), the best kept (`choose`). How and why:
//! docs/solver.md, "Searching over routes".
//!
//! The model is chosen at run time ([`crate::models`]), the solver is
//! compiled per model and integrator: [`solve`] hands the problem to its
//! model's entry, which calls [`solve_model`] with the model's type and
//! dimensions.
//!
//! Each thread keeps the solver workspace of its last solve of each model
//! for the next one (up to horizon 1000, about 1.5 MB for the quadrotor),
//! so a service worker allocates only the answer's own vectors per request.

use std::any::Any;
use std::cell::{Cell, RefCell};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock, mpsc};
use std::time::{Duration, Instant};

use ilqr::{
    Clearance, Constraint, Constraints, ControlBounds, ControlEffort, Cost, DiscreteDynamics,
    Euler, ExpObstacle, GoalTolerance, Model, Objective, Options, Problem, Rectangle, Region, Rk4,
    Shape, ShapeObstacle, SolveError, Solver, StateBounds, StateTracking, TerminalTracking,
    ViaPath,
    search::{self, Detour},
};
use nalgebra::{SVector, Vector2};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use crate::problem::{FieldError, Integrator, Method, Obstacle, ObstacleShape, ProblemSpec};
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
///   model tried after it; or, with hard constraints, the violation
///   stalled just above `solver.constraint_tolerance`;
/// * `infeasible`: with hard constraints, evidence that they cannot be
///   met from here: the violation stalled well above the tolerance with
///   every penalty at its largest.
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
    /// where the convex model stopped (see `convex_model_at_end`). With
    /// hard constraints also: the violation stalled for three outer
    /// iterations at the largest penalties, but within ten times
    /// `solver.constraint_tolerance`: a stuck solver, not an infeasible
    /// problem (`constraint_violation` says by how much).
    NoProgress,
    /// With hard constraints, evidence that they cannot be met from this
    /// start: the violation stalled above ten times
    /// `solver.constraint_tolerance` for three outer iterations in a row
    /// with every penalty at its largest (1e8). A goal inside a hard
    /// obstacle, say, or bounds the dynamics cannot keep. Outer iterations
    /// that run out with the violation still falling end
    /// `max_iterations` instead. The result is the least violating
    /// trajectory found; `constraint_violation` says by how much.
    Infeasible,
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
            Self::Infeasible => "infeasible",
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
            ilqr::Status::Infeasible => Self::Infeasible,
        }
    }
}

/// The solution of a problem.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct SolveResult {
    /// The model solved for (`model.type` of the problem).
    pub model: String,
    /// The integrator the dynamics were discretised with.
    pub integrator: Integrator,
    /// How the solve ended.
    pub status: SolveStatus,
    /// Final cost J: eqs. 13–15 of the paper summed over the horizon, with
    /// no ½ factors. A weighted sum of squared errors in the squares of the
    /// state's and controls' units, plus the obstacle terms, so it has no
    /// single unit: compare costs of one problem, not across weights.
    pub cost: f64,
    /// Cost of the chosen start's initial guess (its controls rolled out;
    /// for a detour, the guiding solve's), same terms as `cost`.
    pub initial_cost: f64,
    /// Iterations performed.
    pub iterations: usize,
    /// Distance (m) of the final position from the goal position.
    pub goal_distance: f64,
    /// For each obstacle, the smallest distance (m) from its centre to the
    /// path: the straight segments between consecutive states' positions
    /// (the path the quadrotor flies under explicit Euler), not only the
    /// states themselves. The cost penalises the obstacle at the states only, so at
    /// a coarse `dt` this can be much smaller than the distance at any state.
    pub closest_approach: Vec<f64>,
    /// The optimised states.
    #[schema(schema_with = schema::states)]
    pub states: Rows,
    /// The optimised controls.
    #[schema(schema_with = schema::controls)]
    pub controls: Rows,
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
    /// The largest violation of any hard constraint (bounds, goal
    /// tolerance, obstacle clearances), each in its own unit (m, rad, N,
    /// …); 0 without hard constraints. At most
    /// `solver.constraint_tolerance` when `status` is `converged`.
    #[schema(minimum = 0.0)]
    pub constraint_violation: f64,
    /// Each hard constraint's state at the result; absent without hard
    /// constraints.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    #[schema(nullable = false)]
    pub constraint_report: Option<ConstraintReport>,
    /// What a caller who reads only `status` could miss: a goal not
    /// reached, a path through a soft obstacle, a control the hardware
    /// cannot produce. Empty when there is nothing to say.
    pub warnings: Vec<Warning>,
    /// The starts solved from, in the order they were built: the plain
    /// start first, then (when `solver.multi_start` searches) the detours
    /// around the obstacles in the way. The result, its `trace` and its
    /// `gains` are those of the one marked `chosen`: the cheapest that
    /// meets the hard constraints (see docs/solver.md, "Searching over
    /// routes").
    pub starts: Vec<StartReport>,
    /// Wall-clock time spent solving, in ms: every start's, which run side
    /// by side on idle workers (the sum of the starts' `solve_time_ms` is
    /// their CPU time; a detour begun on an idle worker and then ruled out
    /// is not listed).
    pub solve_time_ms: f64,
    /// Time spent waiting for a worker, in ms (0 outside the service).
    pub queue_time_ms: f64,
}

/// The state of the hard constraints at the result. A constraint is
/// *active* at a step when it is within `solver.constraint_tolerance` of
/// its bound, or past it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct ConstraintReport {
    /// Outer iterations of the augmented Lagrangian (each a warm iLQR
    /// solve at new multipliers and penalty).
    pub outer_iterations: usize,
    /// `constraints.control`, if given.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    #[schema(nullable = false)]
    pub control: Option<ConstraintStatus>,
    /// `constraints.state`, if given.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    #[schema(nullable = false)]
    pub state: Option<ConstraintStatus>,
    /// `constraints.goal_tolerance`, if given (`active_steps` is 1 when a
    /// component is at its tolerance).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    #[schema(nullable = false)]
    pub goal: Option<ConstraintStatus>,
    /// One entry per hard obstacle (one with a `clearance`), in the
    /// problem's order.
    pub obstacles: Vec<ObstacleStatus>,
}

/// One constraint's largest violation and how often it is active.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct ConstraintStatus {
    /// The largest violation, in the constrained quantity's unit; 0 when
    /// it holds everywhere.
    #[schema(minimum = 0.0)]
    pub max_violation: f64,
    /// Steps at which it is active.
    pub active_steps: usize,
}

/// A hard obstacle at the result.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct ObstacleStatus {
    /// Its index in `obstacles`.
    pub obstacle: usize,
    /// How far inside its clearance the path goes at worst (m); 0 when
    /// the clearance holds at every state.
    #[schema(minimum = 0.0)]
    pub max_violation: f64,
    /// Steps at which the clearance is active.
    pub active_steps: usize,
    /// The smallest signed distance `d` (m) from a state after the
    /// initial one to the obstacle; at least `clearance` when the
    /// constraint holds.
    pub smallest_distance: f64,
}

/// Something the result's `status` does not say.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct Warning {
    /// What it is, for programs.
    pub code: WarningCode,
    /// What it is, for people: where, by how much, and how to turn it
    /// into a hard constraint.
    pub message: String,
}

/// The kinds of [`Warning`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum WarningCode {
    /// The final position is more than 0.1 m from the goal's (unless a
    /// goal tolerance on both position components bounds it). Hard:
    /// `constraints.goal_tolerance`.
    GoalNotReached,
    /// A state after the initial one is inside a soft obstacle (`d ≤ 0`;
    /// for a point, at its centre). Hard: give the obstacle a `clearance`.
    InsideObstacle,
    /// A control is below the model's physical minimum (the quadrotor's
    /// rotors cannot pull: thrust below 0 N) and no bound forbids it.
    /// Hard: `constraints.control.lower`.
    NegativeThrust,
}

impl WarningCode {
    /// The wire name, e.g. `goal_not_reached`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::GoalNotReached => "goal_not_reached",
            Self::InsideObstacle => "inside_obstacle",
            Self::NegativeThrust => "negative_thrust",
        }
    }
}

/// One start of a solve, and how its solve ended.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct StartReport {
    /// Which way it went: `rest controls` (the model's rest: hover for the
    /// quadrotor), `initial_controls` or `warm_start` for the plain start;
    /// for a detour, the compass side of the obstacle its via-point is on,
    /// e.g. `east of obstacle 0` (x is east, y north).
    pub label: String,
    /// A detour's obstacle (its index in `obstacles`).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    #[schema(nullable = false, minimum = 0)]
    pub obstacle: Option<usize>,
    /// A detour's side of the straight path from the initial to the goal
    /// position, facing the goal.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    #[schema(nullable = false)]
    pub side: Option<DetourSide>,
    /// How its solve ended.
    pub status: SolveStatus,
    /// For a detour: the side of the straight path on which its answer
    /// passes its obstacle. Not `side` when its solve slid back round the
    /// other way, the plain start's way as a rule: that side was then not
    /// searched by this start. Absent for the plain starts, and for an
    /// answer through the obstacle's centre.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    #[schema(nullable = false)]
    pub passes: Option<DetourSide>,
    /// Its final cost.
    pub cost: f64,
    /// Its solve's iterations.
    pub iterations: usize,
    /// A detour's guiding solve's iterations (the cost plus a via-point
    /// beside the obstacle, from the plain start; at most 6), not counted
    /// in `iterations`. Absent for the plain start, and for a detour whose
    /// guide could not run (its initial rollout not finite: the plain start
    /// then fails alike).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    #[schema(nullable = false, minimum = 0)]
    pub guide_iterations: Option<usize>,
    /// Its largest hard-constraint violation (0 without hard constraints).
    #[schema(minimum = 0.0)]
    pub constraint_violation: f64,
    /// Its time, the guiding solve included, ms.
    pub solve_time_ms: f64,
    /// Whether the result is this start's.
    pub chosen: bool,
}

/// A side of the straight path, facing from the initial position to the
/// goal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum DetourSide {
    /// Passing the obstacle with it on the right.
    Left,
    /// Passing the obstacle with it on the left.
    Right,
}

impl DetourSide {
    /// The wire name.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Left => "left",
            Self::Right => "right",
        }
    }
}

/// How far from the goal position (m) the final position may end before
/// [`WarningCode::GoalNotReached`].
pub const GOAL_WARNING_DISTANCE: f64 = 0.1;

/// Feedback and feedforward gains along the trajectory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct Gains {
    /// `K_k`, see the schema description.
    #[schema(schema_with = schema::feedback)]
    pub feedback: Vec<Rows>,
    /// `d_k`, see the schema description.
    #[schema(schema_with = schema::feedforward)]
    pub feedforward: Rows,
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
    /// raising the regularisation): the gains are then the previous
    /// iterate's, one accepted step away: a fallback, whose `feedback` is
    /// further off the more obstacles there are, and whose `feedforward`
    /// can be off by more than its own size (see docs/limits.md). Common
    /// when a tight `time_limit_ms` stops a long horizon; never at N below
    /// 128 unless the regularisation was being raised.
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
    /// With hard constraints: the outer iteration of the augmented
    /// Lagrangian this iteration belongs to (1-based).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    #[schema(nullable = false, minimum = 1)]
    pub outer_iteration: Option<usize>,
    /// With hard constraints: their largest violation after the iteration
    /// (control bounds hold throughout and are not counted).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    #[schema(nullable = false, minimum = 0.0)]
    pub constraint_violation: Option<f64>,
    /// With hard constraints: the augmented Lagrangian's penalty ρ (cost
    /// units per squared constraint unit).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    #[schema(nullable = false, minimum = 0.0)]
    pub penalty: Option<f64>,
    /// In a progress stream of a search: the start (index in the result's
    /// `starts`) the iteration belongs to. Absent in the result's `trace`,
    /// which is the chosen start's.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    #[schema(nullable = false, minimum = 0)]
    pub start: Option<usize>,
}

/// A problem that passed validation but cannot be solved as posed.
#[derive(Debug, Clone, PartialEq)]
pub struct Unsolvable(pub FieldError);

/// A job of a search that another thread may run, called with a check
/// that says whether it should give way (a request waits for its worker).
pub type Helper = Box<dyn FnOnce(&dyn Fn() -> bool) + Send + 'static>;

/// Where a search may run its starts besides the calling thread (see
/// [`solve_shared`]).
pub struct Helpers<'a> {
    /// The problem, for the other threads.
    pub spec: Arc<ProblemSpec>,
    /// The solve's cancellation flag, polled by this thread's starts and
    /// passed on to the other threads' (within about 5 ms while this
    /// thread waits for them).
    pub cancel: Arc<AtomicBool>,
    /// Runs a job on an idle thread now, or hands it back when none is
    /// idle.
    pub lend: Lend<'a>,
}

/// A solve as a model's entry runs it: the problem, its budget, its
/// cancellation flag, where each iteration's row goes, and where starts of
/// a search may run besides this thread.
pub struct Call<'a> {
    /// The validated problem.
    pub spec: &'a ProblemSpec,
    /// The budget of the whole solve, every start included.
    pub budget: Budget,
    /// Polled with the budget.
    pub cancel: &'a AtomicBool,
    /// Each iteration's trace row, as it ends.
    pub progress: &'a mut dyn FnMut(&TraceEntry),
    /// Other threads for a search's starts; `None`: all on this one.
    pub helpers: Option<Helpers<'a>>,
}

/// Solve a problem that [`ProblemSpec::validate`] accepted, within the
/// wall-clock budget `time_limit` (the caller decides it: the CLI uses
/// `solver.time_limit_ms`, the service also counts the time spent queued).
/// `cancel` is polled with the budget, every iteration and every 128 knots
/// of a pass. A search's starts run one after another on this thread.
pub fn solve(
    spec: &ProblemSpec,
    time_limit: Option<Duration>,
    cancel: &AtomicBool,
) -> Result<SolveResult, Unsolvable> {
    solve_observed(spec, time_limit, cancel, &mut |_| {})
}

/// [`solve`], calling `progress` with each iteration's trace row as soon
/// as the iteration ends, on the solving thread (a stream of progress to a
/// caller). The rows are those of the result's `trace`, whatever
/// `output.trace` says; in a search of several starts, every start's rows,
/// each with its `start`.
pub fn solve_observed(
    spec: &ProblemSpec,
    time_limit: Option<Duration>,
    cancel: &AtomicBool,
    progress: &mut dyn FnMut(&TraceEntry),
) -> Result<SolveResult, Unsolvable> {
    dispatch(Call {
        spec,
        budget: Budget {
            time_limit,
            ..Budget::default()
        },
        cancel,
        progress,
        helpers: None,
    })
}

/// [`solve_observed`], with a search's starts also run on the threads
/// `helpers.lend` finds idle. Rows of starts on other threads reach
/// `progress` on this thread, when it next reports a row of its own or
/// once its own starts are done; those of a start begun before the plain
/// start decided which are kept, only after that decision, and only if
/// it is kept. A detour's rows come when it ends, those of the try it
/// keeps (it is guided a second time if it slid back).
pub fn solve_shared(
    helpers: Helpers<'_>,
    budget: Budget,
    progress: &mut dyn FnMut(&TraceEntry),
) -> Result<SolveResult, Unsolvable> {
    let spec = Arc::clone(&helpers.spec);
    let cancel = Arc::clone(&helpers.cancel);
    dispatch(Call {
        spec: &spec,
        budget,
        cancel: &cancel,
        progress,
        helpers: Some(helpers),
    })
}

/// A solve's time budget as its caller sets it.
#[derive(Clone, Default)]
pub struct Budget {
    /// The wall-clock budget of the whole solve, every start included,
    /// from the call; `None` for none.
    pub time_limit: Option<Duration>,
    /// Time the caller needs after the solve per trace row of the answer
    /// (encoding it): the solve keeps it back from `time_limit` for every
    /// iteration it does.
    pub per_row: Duration,
    /// Whether nobody will read the answer of a cancelled solve (a client
    /// that left, not a shutdown that still answers): asked when a start
    /// ends `cancelled`, which then skips its report, closest approaches
    /// and warnings, to free its thread sooner. `None`: always read.
    pub unread_if_cancelled: Option<Unread>,
}

/// See [`Budget::unread_if_cancelled`].
pub type Unread = Arc<dyn Fn() -> bool + Send + Sync>;

/// What every start of a solve shares: its deadline, what it keeps back
/// per trace row, and whether a cancelled start's answer is read.
#[derive(Clone)]
struct Terms {
    deadline: Option<Instant>,
    per_row: Duration,
    unread: Option<Unread>,
}

impl Terms {
    fn unread(&self) -> bool {
        self.unread.as_ref().is_some_and(|unread| unread())
    }
}

fn dispatch(call: Call<'_>) -> Result<SolveResult, Unsolvable> {
    match call.spec.model.served() {
        Some(model) => model.solve(call),
        None => Err(Unsolvable(FieldError {
            pointer: "/model/type".into(),
            detail: format!("unknown model: expected one of {}", crate::models::names()),
        })),
    }
}

/// Where a start's initial guess comes from.
#[derive(Debug, Clone, Copy)]
enum Start {
    /// The plain initial guess: the given controls or the model's rest.
    Plain,
    /// The plain guess, solved keeping the clearances it already has
    /// ([`KEPT_CLEAR_PENALTY`]).
    KeptClear,
    /// The plain guess bent past an obstacle by a guiding solve.
    Detour(Detour),
}

impl Start {
    /// The augmented Lagrangian's first penalty for the constraints this
    /// start's guess already meets. The plain start explores: at ALTRO's
    /// penalty of 1 the first inner solve all but ignores the obstacles,
    /// and the route it ends on is wherever the penalties then push it
    /// out. The others are routes to keep: a stiff penalty holds the
    /// path on its side of every obstacle it clears, as an interior-point
    /// solver's barrier would.
    fn penalty_feasible(&self) -> f64 {
        match self {
            Self::Plain => 1.0,
            Self::KeptClear | Self::Detour(_) => KEPT_CLEAR_PENALTY,
        }
    }
}

/// The first penalty (cost units per squared constraint unit) of the
/// constraints a route start's guess already meets. A path 0.1 m into
/// an obstacle then costs 5 per knot; the seed's whole flight costs
/// about 5000.
const KEPT_CLEAR_PENALTY: f64 = 1e3;

/// A start's outcome.
struct Attempt {
    result: SolveResult,
    /// With a detour: the guiding solve's iterations.
    guide_iterations: Option<usize>,
}

/// The iterations a guiding solve may take: it only has to bend the guess
/// to one side; the real solve does the rest.
const GUIDE_ITERATIONS: usize = 6;
/// How much more the guide's route weighs than the problem's own pull on
/// the position.
const GUIDE_GAIN: f64 = 10.0;
/// The guiding solve's relative tolerance, loose for the same reason.
const GUIDE_TOLERANCE: f64 = 1e-3;
/// Time kept back from a solve's budget for turning the solver's answer
/// into a result (the constraint report, closest approaches, warnings,
/// the rows), in units of one rollout of the problem, which does about as
/// much work per knot and obstacle: a pass over the trajectory with every
/// obstacle in it.
const FINISH_ROLLOUTS: f64 = 2.0;
/// A start replaces an earlier one only when cheaper by more than this
/// share of the cost: two starts that reach one optimum differ by about
/// the solver's tolerance, and the earlier start (the plain one first)
/// keeps it.
pub const NEAR_TIE: f64 = 1e-6;

/// [`solve`] for the model `M`: the starts (one, or a search's several),
/// each built in the solver's types and run with the problem's
/// integrator, and the best of them.
pub(crate) fn solve_model<M, const NX: usize, const NU: usize>(
    call: Call<'_>,
) -> Result<SolveResult, Unsolvable>
where
    M: Model<NX, NU> + 'static,
{
    let Call {
        spec,
        budget,
        cancel,
        progress,
        helpers,
    } = call;
    let started = Instant::now();
    let deadline = budget.time_limit.and_then(|t| started.checked_add(t));
    let terms = Terms {
        deadline,
        per_row: budget.per_row,
        unread: budget.unread_if_cancelled,
    };
    let starts = Arc::new(starts::<M, NX, NU>(spec));
    let n = starts.len();
    let ran: Vec<(usize, Attempt)> = if n == 1 {
        vec![(
            0,
            attempt::<M, NX, NU>(spec, starts[0], &terms, cancel, progress)?,
        )]
    } else {
        let here = |i: usize, progress: &mut dyn FnMut(&TraceEntry)| {
            attempt::<M, NX, NU>(spec, starts[i], &terms, cancel, progress)
        };
        let keep = |plain: &Attempt| kept::<M, NX, NU>(spec, &starts, plain);
        let lent = helpers.map(|h| {
            let (spec, starts, terms) = (h.spec, Arc::clone(&starts), terms.clone());
            let run: Arc<StartFn> = Arc::new(move |i, stop, progress| {
                attempt::<M, NX, NU>(&spec, starts[i], &terms, stop, progress)
            });
            (h.lend, run)
        });
        // Every start builds the same problem: one that cannot be solved
        // fails them all alike, and the first says why.
        search(n, &here, &keep, lent, (cancel, deadline), progress)
            .into_iter()
            .map(|(i, outcome)| outcome.map(|a| (i, a)))
            .collect::<Result<_, _>>()?
    };
    let attempts: Vec<&Attempt> = ran.iter().map(|(_, a)| a).collect();
    let chosen = choose(&attempts, spec.solver.constraint_tolerance);
    let rows = ran
        .iter()
        .enumerate()
        .map(|(k, (i, a))| start_report(spec, (&starts[*i], M::POSITION), a, k == chosen))
        .collect();
    let mut result = ran
        .into_iter()
        .nth(chosen)
        .expect("`choose` picks one of the attempts")
        .1
        .result;
    result.starts = rows;
    result.solve_time_ms = millis(started.elapsed());
    Ok(result)
}

/// Which of `starts` a search keeps, given its plain start's outcome: the
/// plain start, then the detours in order up to `solver.max_starts` in
/// all, less those on a side of their obstacle the plain start's answer
/// already takes (when it converged: it is that side's local optimum, or
/// one near it, and a detour there would as a rule find it again).
fn kept<M: Model<NX, NU>, const NX: usize, const NU: usize>(
    spec: &ProblemSpec,
    starts: &[Start],
    plain: &Attempt,
) -> Vec<bool> {
    let r = &plain.result;
    let path = || r.states.iter().map(|x| planar(x, M::POSITION));
    let settled = r.status == SolveStatus::Converged;
    let mut room = spec.solver.max_starts.saturating_sub(1);
    starts
        .iter()
        .map(|start| match start {
            Start::Plain => true,
            Start::KeptClear => {
                let keep = room > 0;
                room -= usize::from(keep);
                keep
            }
            Start::Detour(d) => {
                let keep = room > 0 && !(settled && d.is_taken_by(path()));
                room -= usize::from(keep);
                keep
            }
        })
        .collect()
}

/// Runs start `i` on another thread, polling its own stop flag (the
/// request's cancellation reaches it through the search's owner), and
/// sending its rows to the callback.
type StartFn = dyn Fn(usize, &AtomicBool, &mut dyn FnMut(&TraceEntry)) -> Result<Attempt, Unsolvable>
    + Send
    + Sync;

/// Runs start `i` on this thread.
type HereFn<'a> = dyn Fn(usize, &mut dyn FnMut(&TraceEntry)) -> Result<Attempt, Unsolvable> + 'a;

/// Runs a job on an idle thread now, or hands it back ([`Helpers::lend`]).
pub type Lend<'a> = &'a (dyn Fn(Helper) -> Result<(), Helper> + Sync);

/// What a start run on another thread reports.
enum Message {
    Row(usize, TraceEntry),
    Done(usize, Ran),
}

/// How long the plain start runs before idle threads begin detours that
/// it may yet rule out. A shorter plain start is left to decide first: a
/// thread woken beside it (0.5–1 ms to wake on a small VM) would get
/// little done, and what it began would compete with the plain start for
/// the cores and, half the time, be dropped.
const SPECULATE_AFTER: Duration = Duration::from_millis(5);

/// Run a search over starts `0..n`. Start 0, the plain start, runs on this
/// thread first; its outcome decides (`keep`) which of the others to run.
/// Those run on this thread and, where `lent` finds idle threads, on them
/// too: every thread takes the next start not yet taken, so a helper that
/// is late finds nothing left and ends, and this thread waits only for
/// starts already running elsewhere. Under load no thread is idle and the
/// starts run one after another here.
///
/// Helpers are lent once the plain start has ended, when more than one
/// start is left, or once it has run for [`SPECULATE_AFTER`]. Those lent
/// before it ends take starts whether or not they will be kept; at the
/// decision the ones not kept are stopped and dropped, rows and all, so
/// the answer is the same however the starts were spread over threads,
/// and the waste is idle threads' time while the plain start ran.
///
/// A start begins only while there is time for it ([`Shared::take`]):
/// with at least as long left as the plain start took, or before it has
/// ended, twice what it has taken so far. Once one is dropped for time, every
/// later one is, so the starts run are the first kept ones, in order.
///
/// `cancel` (the request's) reaches the starts on other threads through
/// their stop flags, set by this thread whenever it sees `cancel`: while
/// it solves, or every [`STOP_POLL`] while it waits.
///
/// Returns the outcomes of the kept starts that ran, with their indices,
/// in order; only the plain start's error when it fails.
fn search(
    n: usize,
    here: &HereFn<'_>,
    keep: &dyn Fn(&Attempt) -> Vec<bool>,
    lent: Option<(Lend<'_>, Arc<StartFn>)>,
    (cancel, deadline): (&AtomicBool, Option<Instant>),
    progress: &mut dyn FnMut(&TraceEntry),
) -> Vec<(usize, Result<Attempt, Unsolvable>)> {
    let shared = Arc::new(Shared {
        // Start 0 is this thread's; the others are taken from 1.
        next: AtomicUsize::new(1),
        decided: OnceLock::new(),
        stop: (0..n).map(|_| AtomicBool::new(false)).collect(),
        deadline,
        began: Instant::now(),
        start_by: OnceLock::new(),
        late: AtomicBool::new(false),
    });
    // However this returns or unwinds, the helpers take no more starts and
    // stop the ones they run: a search left behind wastes nothing.
    let _abandon = Abandon(&shared);
    let follow_cancel = || {
        if cancel.load(Ordering::Relaxed) {
            shared.stop_all();
        }
    };
    let (tx, rx) = mpsc::channel::<Message>();
    let lent_yet = Cell::new(false);
    // Up to `helpers` idle threads, until some were lent.
    let lend_helpers = |helpers: usize, tx: &mpsc::Sender<Message>| {
        let Some((lend, run)) = &lent else {
            return;
        };
        if lent_yet.get() {
            return;
        }
        for _ in 0..helpers {
            let (shared, tx, run) = (Arc::clone(&shared), tx.clone(), Arc::clone(run));
            let job: Helper = Box::new(move |give_way| {
                // Between starts: a request waiting for this worker gets it,
                // and this search's owner runs the rest.
                while !give_way() {
                    let Some((i, in_time)) = shared.take() else {
                        break;
                    };
                    if shared.decided.get().is_some_and(|kept| !kept[i]) {
                        continue;
                    }
                    let ran = if in_time {
                        Ran::Finished(Box::new(run(i, &shared.stop[i], &mut |row| {
                            let _ = tx.send(Message::Row(i, row.clone()));
                        })))
                    } else {
                        Ran::Dropped
                    };
                    let _ = tx.send(Message::Done(i, ran));
                }
            });
            if lend(job).is_err() {
                break;
            }
            lent_yet.set(true);
        }
    };
    let mut inbox = Inbox::new(n);
    let began = Instant::now();
    let plain = here(0, &mut |row| {
        if !lent_yet.get() && began.elapsed() >= SPECULATE_AFTER {
            lend_helpers(n - 1, &tx);
        }
        follow_cancel();
        inbox.drain(&rx, progress);
        progress(&TraceEntry {
            start: Some(0),
            ..row.clone()
        });
    });
    let plain = match plain {
        Ok(plain) => plain,
        Err(e) => return vec![(0, Err(e))],
    };
    // A detour needs about as long as the plain start took: a short guide,
    // then a solve like it.
    let took = began.elapsed();
    let _ = shared
        .start_by
        .set(deadline.map(|d| d.checked_sub(took).unwrap_or(d)));
    let kept = shared.decided.get_or_init(|| keep(&plain)).clone();
    for (i, k) in kept.iter().enumerate() {
        if !k {
            shared.stop[i].store(true, Ordering::SeqCst);
        }
    }
    inbox.decide(&kept, progress);
    inbox.done[0] = Some(Ran::Finished(Box::new(Ok(plain))));
    // One start left is this thread's: a helper would only make it wait.
    let left = kept.iter().skip(1).filter(|&&k| k).count();
    if !shared.too_late() {
        lend_helpers(left.saturating_sub(1), &tx);
    }
    drop(tx);
    while let Some((i, in_time)) = {
        follow_cancel();
        shared.take()
    } {
        let Some(place) = inbox.place(i) else {
            continue;
        };
        if !in_time {
            inbox.done[i] = Some(Ran::Dropped);
            continue;
        }
        let outcome = here(i, &mut |row| {
            follow_cancel();
            inbox.drain(&rx, progress);
            progress(&TraceEntry {
                start: Some(place),
                ..row.clone()
            });
        });
        inbox.done[i] = Some(Ran::Finished(Box::new(outcome)));
    }
    let waiting = |inbox: &Inbox| (0..n).any(|i| kept[i] && inbox.done[i].is_none());
    while waiting(&inbox) {
        follow_cancel();
        match rx.recv_timeout(STOP_POLL) {
            Ok(m) => inbox.take(m, progress),
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            // Every helper has ended, one without reporting its start.
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        }
    }
    (0..n)
        .filter(|&i| kept[i])
        .filter_map(|i| match inbox.done[i].take() {
            Some(Ran::Finished(outcome)) => Some((i, *outcome)),
            Some(Ran::Dropped) => None,
            None => panic!("a start of the search panicked on another thread"),
        })
        .collect()
}

/// What became of a start a thread took.
enum Ran {
    // Boxed: a whole result, where `Dropped` is nothing.
    Finished(Box<Result<Attempt, Unsolvable>>),
    /// Taken when there was no time left to run it.
    Dropped,
}

/// How often a search's owner, waiting for starts on other threads, looks
/// at the request's cancellation flag.
const STOP_POLL: Duration = Duration::from_millis(5);

/// What a search's threads share.
struct Shared {
    /// The next start to take.
    next: AtomicUsize,
    /// Which starts are kept, once the plain start has ended.
    decided: OnceLock<Vec<bool>>,
    /// Each start's stop flag, polled like a cancellation flag.
    stop: Vec<AtomicBool>,
    /// The solve's deadline, and when the search began.
    deadline: Option<Instant>,
    began: Instant,
    /// Once the plain start has ended: the latest time a detour may begin.
    start_by: OnceLock<Option<Instant>>,
    /// A start was found too late to begin: so is every later one.
    late: AtomicBool,
}

impl Shared {
    fn stop_all(&self) {
        for flag in &self.stop {
            flag.store(true, Ordering::SeqCst);
        }
    }

    /// Whether it is too late to begin a start: less time is left than the
    /// plain start took, or, before it has ended, than twice what it has
    /// taken so far (a detour begun beside it needs as long at least, and
    /// the plain start is not done).
    fn too_late(&self) -> bool {
        let now = Instant::now();
        match self.start_by.get() {
            Some(by) => by.is_some_and(|by| now >= by),
            None => self
                .deadline
                .is_some_and(|end| end.saturating_duration_since(now) <= 2 * (now - self.began)),
        }
    }

    /// The next start, and whether to run it: not when it is too late, or
    /// the start is already stopped (the request was cancelled); `None`
    /// when none is left. Lateness is sticky and read after the start is
    /// taken, so a start taken after one found late is late too: the starts
    /// that run are the first ones, whichever threads took them.
    fn take(&self) -> Option<(usize, bool)> {
        if self.too_late() {
            self.late.store(true, Ordering::SeqCst);
        }
        let i = self.next.fetch_add(1, Ordering::SeqCst);
        let run =
            |i: usize| !self.late.load(Ordering::SeqCst) && !self.stop[i].load(Ordering::SeqCst);
        (i < self.stop.len()).then(|| (i, run(i)))
    }
}

/// Ends a search for its helpers when dropped.
struct Abandon<'a>(&'a Shared);

impl Drop for Abandon<'_> {
    fn drop(&mut self) {
        // Past the last start (and far from wrapping round to the first).
        self.0.next.store(self.0.stop.len(), Ordering::SeqCst);
        self.0.stop_all();
    }
}

/// What a search's owner has heard from the threads helping it.
struct Inbox {
    done: Vec<Option<Ran>>,
    /// Each start's place among the kept ones (its `start` in the rows),
    /// once the plain start has decided them.
    places: Option<Vec<Option<usize>>>,
    /// Rows that came before that decision.
    held: Vec<(usize, TraceEntry)>,
}

impl Inbox {
    fn new(n: usize) -> Self {
        Self {
            done: (0..n).map(|_| None).collect(),
            places: None,
            held: Vec::new(),
        }
    }

    fn place(&self, i: usize) -> Option<usize> {
        self.places.as_ref().and_then(|p| p[i])
    }

    /// Number the kept starts and pass on the rows held for them.
    fn decide(&mut self, kept: &[bool], progress: &mut dyn FnMut(&TraceEntry)) {
        let mut count = 0;
        self.places = Some(
            kept.iter()
                .map(|&k| {
                    count += usize::from(k);
                    k.then_some(count - 1)
                })
                .collect(),
        );
        for (i, row) in std::mem::take(&mut self.held) {
            self.forward(i, row, progress);
        }
        // A start ruled out that ended before the decision.
        for (done, &k) in self.done.iter_mut().zip(kept) {
            if !k {
                *done = None;
            }
        }
    }

    fn forward(&mut self, i: usize, row: TraceEntry, progress: &mut dyn FnMut(&TraceEntry)) {
        if self.places.is_none() {
            self.held.push((i, row));
        } else if let Some(place) = self.place(i) {
            progress(&TraceEntry {
                start: Some(place),
                ..row
            });
        }
    }

    fn take(&mut self, m: Message, progress: &mut dyn FnMut(&TraceEntry)) {
        match m {
            Message::Row(i, row) => self.forward(i, row, progress),
            Message::Done(i, outcome) => {
                if self.place(i).is_some() || self.places.is_none() {
                    self.done[i] = Some(outcome);
                }
            }
        }
    }

    fn drain(&mut self, rx: &mpsc::Receiver<Message>, progress: &mut dyn FnMut(&TraceEntry)) {
        while let Ok(m) = rx.try_recv() {
            self.take(m, progress);
        }
    }
}

/// The start to keep: the cheapest that meets the hard constraints,
/// converged or not (one stopped short of its optimum would only have got
/// cheaper: its route is the better one); failing that the least
/// violating. Ties and near-ties ([`NEAR_TIE`]) go to the earlier start,
/// so the choice is the same whatever order the starts ended in.
fn choose(attempts: &[&Attempt], constraint_tolerance: f64) -> usize {
    let meets = |r: &SolveResult| r.constraint_violation <= constraint_tolerance;
    let key = |r: &SolveResult| {
        if meets(r) {
            r.cost
        } else {
            r.constraint_violation
        }
    };
    let mut best = 0;
    for (i, a) in attempts.iter().enumerate().skip(1) {
        let (a, b) = (&a.result, &attempts[best].result);
        let better = match (meets(a), meets(b)) {
            (true, false) => true,
            (false, true) => false,
            _ => key(a) < key(b) - NEAR_TIE * key(b).abs(),
        };
        if better {
            best = i;
        }
    }
    best
}

/// The starts of `spec`: the plain one, then (when it searches) the
/// detours around the obstacles in the way, from which `kept` picks up to
/// `solver.max_starts` in all.
fn starts<M: Model<NX, NU>, const NX: usize, const NU: usize>(spec: &ProblemSpec) -> Vec<Start> {
    let mut out = vec![Start::Plain];
    // `max_iterations: 0` asks for the plain guess rolled out, no more.
    if !spec.searches() || spec.obstacles.is_empty() || spec.solver.max_iterations == 0 {
        return out;
    }
    // With hard obstacles, the plain guess is also solved keeping the
    // clearances it has.
    if spec.obstacles.iter().any(|o| o.clearance.is_some()) {
        out.push(Start::KeptClear);
    }
    let (from, to) = (
        planar(&spec.initial_state, M::POSITION),
        planar(&spec.goal_state, M::POSITION),
    );
    // Beyond what an obstacle keeps itself, 5% of the straight path: a
    // hard obstacle with no clearance still gets its via-points off its
    // boundary.
    let spare = 0.05 * (to - from).norm();
    // An obstacle with neither weight nor clearance shapes nothing: its
    // margin is NaN, so it gets no detours, and keeps its index.
    let obstacles: Vec<search::Obstacle> = spec
        .obstacles
        .iter()
        .map(|o| search::Obstacle {
            region: region(o),
            margin: if o.weight > 0.0 || o.clearance.is_some() {
                o.clearance.unwrap_or(0.0) + soft_reach(o.weight) + spare
            } else {
                f64::NAN
            },
        })
        .collect();
    let detours = search::detours(from, to, spec.horizon, &obstacles);
    out.extend(
        detours
            .into_iter()
            // The plain start keeps at most one side of each obstacle
            // out (`kept`): twice the room leaves enough.
            .take(spec.solver.max_starts.saturating_sub(1).saturating_mul(2))
            .map(Start::Detour),
    );
    out
}

/// The position `(px, py)` of the state `x`; NaN where `x` is too short
/// (a NaN position is on no side and near no obstacle).
fn planar(x: &[f64], (px, py): (usize, usize)) -> Vector2<f64> {
    let at = |i: usize| x.get(i).copied().unwrap_or(f64::NAN);
    Vector2::new(at(px), at(py))
}

/// How far from its boundary (m) a soft obstacle of weight `q` keeps an
/// optimal path, roughly: `ln(1 + q) / 2` (the seed's `q = 1000` gives
/// 3.5 m; its optimal paths pass at 2.9 and 3.0 m). Only where the detours
/// go depends on it: the real solve finds the distance itself.
fn soft_reach(q: f64) -> f64 {
    if q > 0.0 { q.ln_1p() / 2.0 } else { 0.0 }
}

/// Solve from one start: for a detour, first the guiding solve (the cost
/// plus a via-point, from the plain guess), then the problem itself from
/// the guiding solve's controls.
fn attempt<M, const NX: usize, const NU: usize>(
    spec: &ProblemSpec,
    start: Start,
    terms: &Terms,
    cancel: &AtomicBool,
    progress: &mut dyn FnMut(&TraceEntry),
) -> Result<Attempt, Unsolvable>
where
    M: Model<NX, NU> + 'static,
{
    let started = Instant::now();
    let values: Vec<f64> = M::PARAMETERS
        .iter()
        .map(|p| spec.model.get(p.name).unwrap_or(p.default))
        .collect();
    let model = M::from_parameters(&values);
    let plain = initial_controls::<M, NX, NU>(spec, &model)?;
    let options = Options {
        max_iterations: spec.solver.max_iterations,
        tolerance: spec.solver.tolerance,
        time_limit: terms
            .deadline
            .map(|d| d.saturating_duration_since(Instant::now())),
        reserve_rollouts: FINISH_ROLLOUTS,
        // Only the result's trace is encoded: rows it leaves out cost
        // nothing after the solve.
        reserve_per_iteration: if spec.output.trace {
            terms.per_row
        } else {
            Duration::ZERO
        },
        // Every term is non-negative (validation keeps weights ≥ 0), so a
        // cost of 0 is a global optimum.
        cost_lower_bound: Some(0.0),
        second_order: spec.solver.method == Method::Ddp,
        constraint_tolerance: spec.solver.constraint_tolerance,
        penalty_feasible: start.penalty_feasible(),
        ..Options::default()
    };
    let constraints = hard_constraints::<NX, NU>(spec, M::POSITION)?;
    let x0 = vector::<NX>(&spec.initial_state, "/initial_state")?;
    let (dt, horizon) = (spec.dt, spec.horizon);
    let run = |guide: Guide, progress: &mut dyn FnMut(&TraceEntry)| {
        let model = M::from_parameters(&values);
        let guide = match start {
            Start::Detour(d) => Some(
                objective::<NX, NU>(spec, M::POSITION)?.with_stage(guide.path(
                    spec,
                    &d,
                    M::POSITION,
                )),
            ),
            Start::Plain | Start::KeptClear => None,
        };
        let built = Built {
            cost: objective::<NX, NU>(spec, M::POSITION)?,
            guide,
            x0,
            plain: plain.clone(),
            terms: terms.clone(),
        };
        let run = (&options, &constraints, cancel, progress);
        with_solver(horizon, |solver| match spec.integrator {
            Integrator::Euler => {
                attempt_on::<M, _, NX, NU>(solver, spec, Euler { model, dt }, built, run)
            }
            Integrator::Rk4 => {
                attempt_on::<M, _, NX, NU>(solver, spec, Rk4 { model, dt }, built, run)
            }
        })
    };
    let Start::Detour(d) = start else {
        let mut attempt = run(Guide::Route, progress)?;
        attempt.result.solve_time_ms = millis(started.elapsed());
        return Ok(attempt);
    };
    // A detour that slid back round the other side did not search its
    // side: it is guided once more, differently, while time is left. Its
    // rows are held until it is known which try it keeps, so that a
    // stream shows that try's alone, numbered from 1, as its trace.
    let mut rows = Vec::new();
    let mut attempt = run(Guide::Route, &mut |row| rows.push(row.clone()))?;
    let passes =
        |a: &Attempt| d.is_taken_by(a.result.states.iter().map(|x| planar(x, M::POSITION)));
    let took = started.elapsed();
    let time_left = terms.deadline.is_none_or(|end| Instant::now() + took < end);
    if !passes(&attempt) && time_left && !cancel.load(Ordering::Relaxed) {
        let mut again_rows = Vec::new();
        let again = run(Guide::Point, &mut |row| again_rows.push(row.clone()))?;
        let guided = attempt.guide_iterations.unwrap_or(0) + again.guide_iterations.unwrap_or(0);
        // The better of the two answers, as among starts: the first when
        // they tie.
        if choose(&[&attempt, &again], spec.solver.constraint_tolerance) == 1 {
            (attempt, rows) = (again, again_rows);
        }
        attempt.guide_iterations = Some(guided);
    }
    for row in &rows {
        progress(row);
    }
    attempt.result.solve_time_ms = millis(started.elapsed());
    Ok(attempt)
}

/// How a guiding solve pulls the path past a detour's obstacle.
#[derive(Debug, Clone, Copy)]
enum Guide {
    /// Every knot along the route start, via-point, goal
    /// ([`guide_weight`] per knot): the path follows the route whatever
    /// the number of knots.
    Route,
    /// The via-point's knot alone, ten times the terminal position weight:
    /// the path is free elsewhere, to go round the other obstacles as the
    /// cost prefers where the route's straight legs would cross them.
    Point,
}

impl Guide {
    fn path(self, spec: &ProblemSpec, d: &Detour, position: (usize, usize)) -> ViaPath {
        let (reach, weight) = match self {
            Self::Route => (spec.horizon, guide_weight(spec, position)),
            Self::Point => {
                let w = &spec.weights.terminal;
                let at = |i: usize| w.get(i).copied().unwrap_or(0.0);
                (0, 10.0 * at(position.0).max(at(position.1)).max(1.0))
            }
        };
        ViaPath {
            from: planar(&spec.initial_state, position),
            via: d.via,
            to: planar(&spec.goal_state, position),
            knot: d.knot,
            horizon: spec.horizon,
            reach,
            weight,
            position,
        }
    }
}

/// A start's problem in the solver's types.
struct Built<const NX: usize, const NU: usize> {
    cost: Objective<NX, NU>,
    /// With a detour: the guiding solve's cost.
    guide: Option<Objective<NX, NU>>,
    x0: SVector<f64, NX>,
    /// The plain initial guess.
    plain: Vec<SVector<f64, NU>>,
    terms: Terms,
}

/// The guiding solve (for a detour), then the solve itself, on `solver`.
fn attempt_on<M, D, const NX: usize, const NU: usize>(
    solver: &mut Solver<NX, NU>,
    spec: &ProblemSpec,
    dynamics: D,
    built: Built<NX, NU>,
    (options, constraints, cancel, progress): Run<'_, '_, NX, NU>,
) -> Result<Attempt, Unsolvable>
where
    M: Model<NX, NU>,
    D: DiscreteDynamics<NX, NU> + Clone,
{
    let Built {
        cost,
        guide,
        x0,
        plain,
        terms,
    } = built;
    let horizon = spec.horizon;
    let remaining = || {
        terms
            .deadline
            .map(|d| d.saturating_duration_since(Instant::now()))
    };
    let mut guide_iterations = None;
    let mut u_init = plain;
    if let Some(guide) = guide {
        let problem = Problem {
            dynamics: dynamics.clone(),
            cost: guide,
            x0,
            horizon,
        };
        let guiding = Options {
            max_iterations: GUIDE_ITERATIONS,
            tolerance: GUIDE_TOLERANCE,
            // Half of what is left at most: the solve itself needs the rest.
            time_limit: remaining().map(|t| t / 2),
            reserve_rollouts: FINISH_ROLLOUTS,
            cost_lower_bound: Some(0.0),
            ..Options::default()
        };
        // Within the control bounds (clamping an unbounded guide's controls
        // afterwards can send the rollout anywhere), without the other
        // constraints: the guide only bends the path.
        let bounds = Constraints {
            control: constraints.control,
            other: Vec::new(),
        };
        // A guide that fails leaves the plain guess; the solve itself then
        // says what is wrong with it.
        if let Ok(summary) =
            solver.solve_constrained(&problem, &bounds, &u_init, &guiding, cancel, &mut |_| {})
        {
            guide_iterations = Some(summary.iterations);
            u_init = solver.controls().to_vec();
        }
    }
    let options = Options {
        time_limit: remaining(),
        ..options.clone()
    };
    let problem = Problem {
        dynamics,
        cost,
        x0,
        horizon,
    };
    let result = solve_on::<M, _, _, NX, NU>(
        solver,
        spec,
        (&problem, &u_init, &terms),
        (&options, constraints, cancel, progress),
    )?;
    Ok(Attempt {
        result,
        guide_iterations,
    })
}

/// The guiding solve's route weight per stage: [`GUIDE_GAIN`] times the
/// larger of the position's weight per stage and its terminal weight
/// spread over the stages (at least 1 in all). Both scale with the number
/// of stages as the rest of the cost does, so a problem resampled at a
/// finer `dt` gets the same guide.
fn guide_weight(spec: &ProblemSpec, (px, py): (usize, usize)) -> f64 {
    let w = |weights: &[f64]| {
        let at = |i: usize| weights.get(i).copied().unwrap_or(0.0);
        at(px).max(at(py))
    };
    let n = spec.horizon.max(1) as f64;
    GUIDE_GAIN
        * w(&spec.weights.state)
            .max(w(&spec.weights.terminal) / n)
            .max(1.0 / n)
}

/// A start's row in the result's `starts`.
fn start_report(
    spec: &ProblemSpec,
    (start, position): (&Start, (usize, usize)),
    attempt: &Attempt,
    chosen: bool,
) -> StartReport {
    let r = &attempt.result;
    let wire = |side: search::Side| match side {
        search::Side::Left => DetourSide::Left,
        search::Side::Right => DetourSide::Right,
    };
    let plain = if spec.initial_controls.is_some() {
        "initial_controls"
    } else if spec.warm_start.is_some() {
        "warm_start"
    } else {
        "rest controls"
    };
    let (label, obstacle, side, passes) = match start {
        Start::Plain => (plain.to_owned(), None, None, None),
        Start::KeptClear => (format!("{plain}, clearances kept"), None, None, None),
        Start::Detour(d) => {
            let v = d.direction;
            let compass = if v.x.abs() >= v.y.abs() {
                if v.x > 0.0 { "east" } else { "west" }
            } else if v.y > 0.0 {
                "north"
            } else {
                "south"
            };
            let path = r.states.iter().map(|x| planar(x, position));
            (
                format!("{compass} of obstacle {}", d.obstacle),
                Some(d.obstacle),
                Some(wire(d.side)),
                d.side_of(path).map(wire),
            )
        }
    };
    StartReport {
        label,
        obstacle,
        side,
        passes,
        status: r.status,
        cost: r.cost,
        iterations: r.iterations,
        guide_iterations: attempt.guide_iterations,
        constraint_violation: r.constraint_violation,
        solve_time_ms: r.solve_time_ms,
        chosen,
    }
}

/// The cost of eqs. 13–15: state tracking, control effort, terminal
/// tracking, then one term per obstacle at the model's `position`.
fn objective<const NX: usize, const NU: usize>(
    spec: &ProblemSpec,
    position: (usize, usize),
) -> Result<Objective<NX, NU>, Unsolvable> {
    let goal = vector::<NX>(&spec.goal_state, "/goal_state")?;
    let mut cost = Objective::new()
        .with_stage(StateTracking {
            goal,
            weights: vector::<NX>(&spec.weights.state, "/weights/state")?,
        })
        .with_stage(ControlEffort {
            weights: vector::<NU>(&spec.weights.control, "/weights/control")?,
        })
        .with_terminal(TerminalTracking {
            goal,
            weights: vector::<NX>(&spec.weights.terminal, "/weights/terminal")?,
        });
    for o in &spec.obstacles {
        cost = match o.shape {
            ObstacleShape::Point => cost.with_stage(ExpObstacle {
                center: Vector2::from(o.center),
                weight: o.weight,
                position,
            }),
            // A hard-only shape (weight 0) adds nothing to the cost.
            _ if o.weight == 0.0 => cost,
            _ => cost.with_stage(ShapeObstacle {
                region: region(o),
                weight: o.weight,
                position,
            }),
        };
    }
    Ok(cost)
}

/// What an obstacle occupies, as the core sees it.
fn region(o: &Obstacle) -> Region {
    let shape = match o.shape {
        ObstacleShape::Point => Shape::Point,
        ObstacleShape::Circle => Shape::Circle {
            radius: o.radius.unwrap_or(0.0),
        },
        ObstacleShape::Rectangle => Shape::Rectangle(Rectangle::new(
            Vector2::from(o.size.unwrap_or([0.0, 0.0])),
            o.angle.unwrap_or(0.0),
        )),
    };
    Region {
        center: Vector2::from(o.center),
        shape,
    }
}

/// Which part of the problem each of the core's constraints is, in the
/// order [`hard_constraints`] builds them.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Part {
    State,
    Goal,
    Obstacle(usize),
}

/// The parts of `spec`'s hard constraints in the order
/// [`hard_constraints`] builds them.
fn parts(spec: &ProblemSpec) -> Vec<Part> {
    let c = &spec.constraints;
    let state = c.state.iter().map(|_| Part::State);
    let goal = c.goal_tolerance.iter().map(|_| Part::Goal);
    let obstacles = spec
        .obstacles
        .iter()
        .enumerate()
        .filter(|(_, o)| o.clearance.is_some())
        .map(|(j, _)| Part::Obstacle(j));
    state.chain(goal).chain(obstacles).collect()
}

/// The hard constraints: control bounds, then (as [`parts`] lists them)
/// state bounds, the goal tolerance and each hard obstacle's clearance.
fn hard_constraints<const NX: usize, const NU: usize>(
    spec: &ProblemSpec,
    position: (usize, usize),
) -> Result<Constraints<NX, NU>, Unsolvable> {
    let c = &spec.constraints;
    // Bounds that bound nothing (`{}`, all null) are none: the solve stays
    // the unconstrained one.
    let control = c
        .control
        .as_ref()
        .map(|b| {
            let (lower, upper) = b.resolved(NU);
            ControlBounds {
                lower: SVector::from_column_slice(&lower),
                upper: SVector::from_column_slice(&upper),
            }
        })
        .filter(|b: &ControlBounds<NU>| {
            b.lower.iter().chain(b.upper.iter()).any(|x| x.is_finite())
        });
    let mut other: Vec<Box<dyn Constraint<NX, NU>>> = Vec::new();
    for part in parts(spec) {
        match part {
            Part::State => {
                let (lower, upper) = c.state.clone().unwrap_or_default().resolved(NX);
                other.push(Box::new(StateBounds::new(
                    &SVector::from_column_slice(&lower),
                    &SVector::from_column_slice(&upper),
                )));
            }
            Part::Goal => {
                let tolerance = c.goal_tolerance.as_deref().unwrap_or(&[]);
                other.push(Box::new(GoalTolerance::new(
                    vector::<NX>(&spec.goal_state, "/goal_state")?,
                    &vector::<NX>(tolerance, "/constraints/goal_tolerance")?,
                )));
            }
            Part::Obstacle(j) => {
                let o = &spec.obstacles[j];
                other.push(Box::new(Clearance {
                    region: region(o),
                    clearance: o.clearance.unwrap_or(0.0),
                    position,
                }));
            }
        }
    }
    Ok(Constraints { control, other })
}

/// The initial guess: the given rows (`initial_controls` or the warm
/// start's), or the model's rest controls at every step.
fn initial_controls<M: Model<NX, NU>, const NX: usize, const NU: usize>(
    spec: &ProblemSpec,
    model: &M,
) -> Result<Vec<SVector<f64, NU>>, Unsolvable> {
    match spec.given_controls() {
        Some(rows) => {
            let at = if spec.initial_controls.is_some() {
                "/initial_controls"
            } else {
                "/warm_start/controls"
            };
            rows.iter()
                .enumerate()
                .map(|(k, row)| vector::<NU>(row, &format!("{at}/{k}")))
                .collect()
        }
        None => Ok(vec![model.rest_controls(); spec.horizon]),
    }
}

/// `xs` as a vector of length `N`. Validation has checked the length; a
/// problem that skipped it gets an error here, not a panic.
fn vector<const N: usize>(xs: &[f64], pointer: &str) -> Result<SVector<f64, N>, Unsolvable> {
    if xs.len() == N {
        Ok(SVector::from_column_slice(xs))
    } else {
        Err(Unsolvable(FieldError {
            pointer: pointer.to_owned(),
            detail: format!("must have {N} entries, got {}", xs.len()),
        }))
    }
}

/// The solver's gains in the wire's layout (`feedback` row-major: row i is
/// control i's gains over the states), with what the summary says of them.
fn wire_gains<const NX: usize, const NU: usize>(
    solver: &Solver<NX, NU>,
    summary: &ilqr::Summary,
) -> Gains {
    Gains {
        feedback: solver
            .feedback()
            .iter()
            .map(|k| Rows::from_rows(NX, (0..NU).map(|i| k.row(i).transpose())))
            .collect(),
        feedforward: Rows::from_rows(NU, solver.feedforward().iter()),
        regularization: summary.gains_regularization,
        about_previous_iterate: summary.gains_about_previous_iterate,
    }
}

/// How to run a solve: its options, its cancellation flag, and where each
/// iteration's row goes.
type Run<'a, 'p, const NX: usize, const NU: usize> = (
    &'a Options,
    &'a Constraints<NX, NU>,
    &'a AtomicBool,
    &'a mut (dyn FnMut(&TraceEntry) + 'p),
);

/// Run `solver` on the built problem and convert what it found.
fn solve_on<M, D, C, const NX: usize, const NU: usize>(
    solver: &mut Solver<NX, NU>,
    spec: &ProblemSpec,
    (problem, u_init, terms): (&Problem<D, C, NX>, &[SVector<f64, NU>], &Terms),
    (options, constraints, cancel, progress): Run<'_, '_, NX, NU>,
) -> Result<SolveResult, Unsolvable>
where
    M: Model<NX, NU>,
    D: DiscreteDynamics<NX, NU>,
    C: Cost<NX, NU>,
{
    let summary = solver
        .solve_constrained(problem, constraints, u_init, options, cancel, &mut |row| {
            progress(&trace_entry(row));
        })
        .map_err(|e| Unsolvable(field_error(e, spec)))?;
    // Nobody reads it: the status and cost are enough to rank it, and the
    // passes over every obstacle that make the rest would only hold this
    // thread longer.
    let read = !(summary.status == ilqr::Status::Cancelled && terms.unread());

    let states = Rows::from_rows(NX, solver.states().iter());
    let (px, py) = M::POSITION;
    let goal_distance = states.last().map_or(f64::NAN, |x| {
        (x[px] - spec.goal_state[px]).hypot(x[py] - spec.goal_state[py])
    });
    let closest_approach = spec
        .obstacles
        .iter()
        .filter(|_| read)
        .map(|o| closest_approach(&states, M::POSITION, o.center))
        .collect();
    // Zero gains from a solve whose first backward pass never completed
    // would read as a valid (open-loop) policy; leave them out instead.
    let gains =
        (read && spec.output.gains && summary.has_gains).then(|| wire_gains(solver, &summary));
    let trace =
        (read && spec.output.trace).then(|| solver.trace().iter().map(trace_entry).collect());
    let report = (read && !constraints.is_empty())
        .then(|| constraint_report(spec, constraints, solver, summary.outer_iterations));
    let warnings = if read {
        warnings::<M, NX, NU>(spec, solver, goal_distance)
    } else {
        Vec::new()
    };
    Ok(SolveResult {
        model: M::NAME.to_owned(),
        integrator: spec.integrator,
        status: summary.status.into(),
        cost: summary.cost,
        initial_cost: summary.initial_cost,
        iterations: summary.iterations,
        goal_distance,
        closest_approach,
        states,
        controls: Rows::from_rows(NU, solver.controls().iter()),
        gains,
        trace,
        convexified_after_iteration: summary.convexified_after,
        convex_model_at_end: summary.convexified_after.map(|_| summary.gains_convex),
        constraint_violation: report.as_ref().map_or(0.0, |r| {
            r.control
                .iter()
                .map(|c| c.max_violation)
                .fold(summary.constraint_violation, f64::max)
        }),
        constraint_report: report,
        warnings,
        starts: Vec::new(),
        solve_time_ms: millis(summary.solve_time),
        queue_time_ms: 0.0,
    })
}

/// Each hard constraint's largest violation and active steps at the
/// solver's result.
fn constraint_report<const NX: usize, const NU: usize>(
    spec: &ProblemSpec,
    constraints: &Constraints<NX, NU>,
    solver: &Solver<NX, NU>,
    outer_iterations: usize,
) -> ConstraintReport {
    let tolerance = spec.solver.constraint_tolerance;
    let (xs, us) = (solver.states(), solver.controls());
    let control = constraints.control.map(|b| {
        let mut status = ConstraintStatus {
            max_violation: 0.0,
            active_steps: 0,
        };
        for u in us {
            let mut active = false;
            for i in 0..NU {
                let excess = (b.lower[i] - u[i]).max(u[i] - b.upper[i]);
                status.max_violation = status.max_violation.max(excess);
                active |= excess >= -tolerance;
            }
            status.active_steps += usize::from(active);
        }
        status
    });
    let parts = parts(spec);
    // Per part: the largest violation, the last step counted active, the
    // active steps, and (for an obstacle) the smallest distance.
    let mut found: Vec<(f64, Option<usize>, usize, f64)> =
        vec![(0.0, None, 0, f64::INFINITY); parts.len()];
    constraints.for_each_value(xs, us, |j, _, k, c, equality| {
        let entry = &mut found[j];
        entry.0 = entry.0.max(ilqr::constraint::violation(c, equality));
        let active = if equality { true } else { c >= -tolerance };
        if active && entry.1 != Some(k) {
            (entry.1, entry.2) = (Some(k), entry.2 + 1);
        }
        if let Part::Obstacle(o) = parts[j] {
            // c = clearance − d.
            let d = spec.obstacles[o].clearance.unwrap_or(0.0) - c;
            entry.3 = entry.3.min(d);
        }
    });
    let status =
        |(max_violation, _, active_steps, _): (f64, Option<usize>, usize, f64)| ConstraintStatus {
            max_violation,
            active_steps,
        };
    let of = |part: Part| {
        parts
            .iter()
            .position(|p| *p == part)
            .map(|j| status(found[j]))
    };
    ConstraintReport {
        outer_iterations,
        control,
        state: of(Part::State),
        goal: of(Part::Goal),
        obstacles: parts
            .iter()
            .zip(&found)
            .filter_map(|(part, f)| match part {
                Part::Obstacle(o) => Some(ObstacleStatus {
                    obstacle: *o,
                    max_violation: f.0,
                    active_steps: f.2,
                    smallest_distance: f.3,
                }),
                _ => None,
            })
            .collect(),
    }
}

/// What the result's status does not say (see [`WarningCode`]).
fn warnings<M: Model<NX, NU>, const NX: usize, const NU: usize>(
    spec: &ProblemSpec,
    solver: &Solver<NX, NU>,
    goal_distance: f64,
) -> Vec<Warning> {
    let mut out = Vec::new();
    let (px, py) = M::POSITION;
    let c = &spec.constraints;
    // A goal tolerance on the position that keeps it within the threshold
    // says so itself (in the constraint report).
    let goal_bounded = c.goal_tolerance.as_ref().is_some_and(|t| {
        let at = |i: usize| t.get(i).copied().unwrap_or(f64::INFINITY);
        at(px).hypot(at(py)) <= GOAL_WARNING_DISTANCE
    });
    if goal_distance > GOAL_WARNING_DISTANCE && !goal_bounded {
        out.push(Warning {
            code: WarningCode::GoalNotReached,
            message: format!(
                "the final position is {} m from the goal's (more than {GOAL_WARNING_DISTANCE} \
                 m): raise weights.terminal or the horizon, or make the goal hard with \
                 constraints.goal_tolerance",
                round(goal_distance)
            ),
        });
    }
    let xs = solver.states();
    for (j, o) in spec.obstacles.iter().enumerate() {
        if o.weight == 0.0 || o.clearance.is_some() {
            continue;
        }
        let r = region(o);
        let deepest = xs
            .iter()
            .enumerate()
            .skip(1)
            .map(|(k, x)| (k, r.distance(&Vector2::new(x[px], x[py])).value))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((k, d)) = deepest
            && d <= 0.0
        {
            out.push(Warning {
                code: WarningCode::InsideObstacle,
                message: format!(
                    "the path is inside soft obstacle {j} (d = {} m at step {k}): raise its \
                     weight, or make it hard with a clearance",
                    round(d)
                ),
            });
        }
    }
    if let Some(minimum) = M::CONTROL_MINIMUM {
        let bound = |i: usize| {
            c.control
                .as_ref()
                .and_then(|b| b.lower.as_ref())
                .and_then(|l| l.get(i).copied().flatten())
                .is_some_and(|lo| lo >= minimum[i])
        };
        let lowest = solver
            .controls()
            .iter()
            .enumerate()
            .flat_map(|(k, u)| (0..NU).map(move |i| (k, i, u[i])))
            .filter(|&(_, i, v)| v < minimum[i] && !bound(i))
            .min_by(|a, b| (a.2 - minimum[a.1]).total_cmp(&(b.2 - minimum[b.1])));
        if let Some((k, i, v)) = lowest {
            let q = &M::CONTROL[i];
            out.push(Warning {
                code: WarningCode::NegativeThrust,
                message: format!(
                    "{} is {} {} at step {k}, below the least the hardware produces ({} {}): \
                     bound it with constraints.control.lower",
                    q.name,
                    round(v),
                    q.unit,
                    minimum[i],
                    q.unit
                ),
            });
        }
    }
    out
}

/// `x` to 4 significant digits, for a message.
fn round(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        return x.to_string();
    }
    let digits = 3 - x.abs().log10().floor() as i32;
    let scale = 10f64.powi(digits.clamp(0, 15));
    ((x * scale).round() / scale).to_string()
}

/// A trace row in the wire's form.
fn trace_entry(r: &ilqr::TraceRow) -> TraceEntry {
    TraceEntry {
        iteration: r.iteration,
        cost: r.cost,
        expected_reduction: r.expected_reduction,
        actual_reduction: r.actual_reduction,
        step_size: r.step_size,
        regularization: r.regularization,
        feedforward_norm: r.feedforward_norm,
        convex_model: r.convex_model,
        elapsed_ms: millis(r.elapsed),
        outer_iteration: (r.outer_iteration > 0).then_some(r.outer_iteration),
        constraint_violation: (r.outer_iteration > 0).then_some(r.constraint_violation),
        penalty: (r.outer_iteration > 0).then_some(r.penalty),
        start: None,
    }
}

/// Rows of numbers of one width (states, controls, a gain matrix), stored
/// flat: a JSON array of arrays on the wire, without an allocation per row.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Rows {
    width: usize,
    len: usize,
    data: Vec<f64>,
}

impl Rows {
    /// Rows of `width` numbers from an iterator of rows (each must have
    /// `width` numbers; a longer one is cut, a shorter one padded with NaN).
    pub fn from_rows<R, T>(width: usize, rows: R) -> Self
    where
        R: IntoIterator<Item = T>,
        T: AsRef<[f64]>,
    {
        let mut out = Self {
            width,
            len: 0,
            data: Vec::new(),
        };
        for row in rows {
            let row = row.as_ref();
            out.data
                .extend((0..width).map(|i| row.get(i).copied().unwrap_or(f64::NAN)));
            out.len += 1;
        }
        out
    }

    /// The number of rows.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are no rows.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The numbers in a row.
    pub fn width(&self) -> usize {
        self.width
    }

    /// The rows, in order.
    pub fn iter(&self) -> impl ExactSizeIterator<Item = &[f64]> + '_ {
        (0..self.len).map(move |k| &self[k])
    }

    /// The last row.
    pub fn last(&self) -> Option<&[f64]> {
        self.len.checked_sub(1).map(|k| &self[k])
    }

    /// Every number, row after row.
    pub fn flat(&self) -> &[f64] {
        &self.data
    }
}

impl<'a> IntoIterator for &'a Rows {
    type Item = &'a [f64];
    type IntoIter = Box<dyn ExactSizeIterator<Item = &'a [f64]> + 'a>;

    fn into_iter(self) -> Self::IntoIter {
        Box::new(self.iter())
    }
}

impl std::ops::Index<usize> for Rows {
    type Output = [f64];

    fn index(&self, k: usize) -> &[f64] {
        &self.data[k * self.width..(k + 1) * self.width]
    }
}

impl Serialize for Rows {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(self.iter())
    }
}

/// From an array of arrays of one length.
impl<'de> Deserialize<'de> for Rows {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let rows = Vec::<Vec<f64>>::deserialize(d)?;
        let width = rows.first().map_or(0, Vec::len);
        if let Some(k) = rows.iter().position(|r| r.len() != width) {
            return Err(serde::de::Error::custom(format_args!(
                "row {k} has {} numbers, row 0 has {width}",
                rows[k].len()
            )));
        }
        Ok(Self::from_rows(width, rows))
    }
}

/// Each thread's solvers of its last solves, one per dimensions: the
/// workspace kept for the next solve. A fresh workspace for the seed
/// problem is ~146 kB allocated and zeroed per solve, and glibc returns
/// such blocks to the kernel when they are freed, so every solve would
/// also pay page faults and TLB shootdowns. The solver resizes its
/// buffers to each problem's horizon (keeping their capacity), and a
/// panicking solve simply drops it.
fn with_solver<const NX: usize, const NU: usize, T>(
    horizon: usize,
    run: impl FnOnce(&mut Solver<NX, NU>) -> T,
) -> T {
    thread_local! {
        static CACHED: RefCell<Vec<Box<dyn Any>>> = const { RefCell::new(Vec::new()) };
    }
    let cacheable = horizon <= CACHED_HORIZON;
    let cached = cacheable
        .then(|| {
            CACHED.with_borrow_mut(|cache| {
                let at = cache.iter().position(|s| s.is::<Solver<NX, NU>>())?;
                cache.swap_remove(at).downcast::<Solver<NX, NU>>().ok()
            })
        })
        .flatten();
    let mut solver = cached.unwrap_or_else(|| Box::new(Solver::<NX, NU>::new(horizon)));
    let out = run(&mut solver);
    if cacheable {
        CACHED.with_borrow_mut(|cache| cache.push(solver));
    }
    out
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

impl SolveResult {
    /// The result as compact JSON, in a buffer sized for it up front (a
    /// seed result is 16–50 kB; growing a small buffer by doubling copies
    /// it several times).
    /// The numbers the answer holds: states, controls, gains, trace rows
    /// and the per-obstacle and per-start entries (what its encoding's
    /// time grows with).
    pub fn numbers(&self) -> usize {
        let rows = |r: &Rows| r.len() * r.width;
        let gains = self.gains.as_ref().map_or(0, |g| {
            g.feedback.iter().map(rows).sum::<usize>() + rows(&g.feedforward)
        });
        let trace = self.trace.as_ref().map_or(0, |t| t.len() * 14);
        rows(&self.states)
            + rows(&self.controls)
            + gains
            + trace
            + self.closest_approach.len()
            + 10 * self.starts.len()
    }

    pub fn to_json(&self) -> serde_json::Result<Vec<u8>> {
        // ~20 bytes per number on the wire; 24 leaves room without waste.
        let numbers = self.states.flat().len()
            + self.controls.flat().len()
            + self.gains.as_ref().map_or(0, |g| {
                g.feedback.iter().map(|k| k.flat().len()).sum::<usize>()
                    + g.feedforward.flat().len()
            })
            + self.trace.as_ref().map_or(0, |t| t.len() * 8)
            + self.closest_approach.len();
        let mut buf = Vec::with_capacity(24 * numbers + 512);
        serde_json::to_writer(&mut buf, self)?;
        Ok(buf)
    }
}

/// The smallest distance (m) from `center` to the path through the
/// states' positions, taken as straight segments between knots. Under
/// explicit Euler that is the quadrotor's path itself (the position moves
/// with the constant velocity `v_k` during step k); the knots alone can
/// miss a close pass: at `dt = 1` the seed's path passes 0.2 m from the
/// centre between two knots that are both 3.4 m away. The cost, like the
/// paper's, sees only the knots. `position` says which state entries are
/// the position.
fn closest_approach(states: &Rows, position: (usize, usize), center: [f64; 2]) -> f64 {
    // Squared distances pick the nearest point, and `hypot` (about 20 ns,
    // five times the rest of a segment's work) runs once, on it: at N = 10000
    // with 100 obstacles a call per segment would add about 13 ms to an
    // answer. Squares overflow past 1.3e154 m; if every point is that far,
    // the slow loop below measures them. (They underflow below 1.5e-154 m,
    // where the first such point is taken as the nearest: an error far below
    // any distance that matters.)
    let mut best = f64::INFINITY;
    let mut nearest = None;
    for_each_nearest_point(states, position, center, |a, b| {
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
    for_each_nearest_point(states, position, center, |a, b| {
        best = best.min(a.hypot(b));
    });
    best
}

/// Calls `f` with the offset from `center` of the first state's position,
/// then of each segment's point nearest `center`.
fn for_each_nearest_point(
    states: &Rows,
    (px, py): (usize, usize),
    center: [f64; 2],
    mut f: impl FnMut(f64, f64),
) {
    let at = |x: &[f64]| (x[px] - center[0], x[py] - center[1]);
    let mut rows = states.iter();
    let Some(first) = rows.next() else {
        return;
    };
    let (a, b) = at(first);
    f(a, b);
    let mut previous = first;
    for next in rows {
        // Relative to the centre: p0 and the segment d = p1 − p0.
        let (x0, y0) = at(previous);
        let (x1, y1) = at(next);
        previous = next;
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
        SolveError::InvalidControlBounds { .. } => "/constraints/control",
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
        // `as_secs_f64() * 1e3`, for contrast: the test's first case is one
        // it gets wrong.
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
        let spec = ProblemSpec::default();
        let model = ilqr::Quadrotor2D::from_parameters(&[1.0, 1.0, 1.0, 9.81]);
        let problem = Problem {
            dynamics: Euler { model, dt: spec.dt },
            cost: objective::<6, 2>(&spec, (0, 1)).unwrap(),
            x0: vector::<6>(&spec.initial_state, "").unwrap(),
            horizon: spec.horizon,
        };
        let u_init = initial_controls::<ilqr::Quadrotor2D, 6, 2>(&spec, &model).unwrap();
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

    /// The cheapest start that meets the constraints wins, converged or
    /// not; a near-tie goes to the earlier start; without one that meets
    /// them, the least violating.
    #[test]
    fn the_chosen_start_is_the_cheapest_feasible_earliest_on_ties() {
        let base = solve(&ProblemSpec::default(), None, &AtomicBool::new(false)).unwrap();
        let at = |status: SolveStatus, cost: f64, violation: f64| Attempt {
            result: SolveResult {
                status,
                cost,
                constraint_violation: violation,
                ..base.clone()
            },
            guide_iterations: None,
        };
        use SolveStatus::{Converged, Infeasible, MaxIterations};
        let pick = |a: &[Attempt]| choose(&a.iter().collect::<Vec<_>>(), 1e-6);
        assert_eq!(
            pick(&[at(Converged, 10.0, 0.0), at(Converged, 9.0, 0.0)]),
            1
        );
        assert_eq!(
            pick(&[at(Converged, 10.0, 0.0), at(MaxIterations, 1.0, 0.0)]),
            1
        );
        assert_eq!(
            pick(&[at(MaxIterations, 1.0, 0.1), at(Converged, 10.0, 0.0)]),
            1
        );
        let tie = 10.0 * (1.0 - 0.5 * NEAR_TIE);
        assert_eq!(
            pick(&[at(Converged, 10.0, 0.0), at(Converged, tie, 0.0)]),
            0
        );
        let cheaper = 10.0 * (1.0 - 2.0 * NEAR_TIE);
        assert_eq!(
            pick(&[at(Converged, 10.0, 0.0), at(Converged, cheaper, 0.0)]),
            1
        );
        assert_eq!(
            pick(&[at(Infeasible, 1.0, 0.1), at(MaxIterations, 50.0, 0.0)]),
            1
        );
        assert_eq!(
            pick(&[at(Infeasible, 1.0, 0.1), at(Infeasible, 50.0, 0.01)]),
            1
        );
        assert_eq!(pick(&[at(Converged, 10.0, 0.0)]), 0);
    }

    /// Squares overflow past 1.3e154 m: where every point is that far, the
    /// distances are still measured (with `hypot`), and a finite point
    /// beats any overflowing one.
    #[test]
    fn closest_approach_survives_overflowing_squares() {
        let at = |x: f64, y: f64| [x, y, 0.0, 0.0, 0.0, 0.0];
        let path = |points: &[[f64; 6]]| Rows::from_rows(6, points);
        let ca = |points: &[[f64; 6]]| super::closest_approach(&path(points), (0, 1), [0.0, 0.0]);
        assert_eq!(ca(&[at(1e200, 0.0), at(1e200, 3e200)]), 1e200);
        assert_eq!(ca(&[at(3.0, 4.0), at(3.0, 4.0), at(1e200, 1e200)]), 5.0);
        // The nearest point of a segment, not only its ends.
        assert_eq!(ca(&[at(-1.0, 2.0), at(1.0, 2.0)]), 2.0);
        assert_eq!(ca(&[]), f64::INFINITY);
        // The position is where the model says, not always entries 0 and 1.
        let swapped = Rows::from_rows(3, [[7.0, 3.0, 4.0]]);
        assert_eq!(super::closest_approach(&swapped, (2, 1), [0.0, 0.0]), 5.0);
    }
}
