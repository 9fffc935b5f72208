//! What a solve reports: how it ended ([`Status`]), what it found
//! ([`Summary`]), each iteration ([`TraceRow`]), and the input it cannot
//! work with ([`SolveError`]).

use std::time::Duration;

#[cfg(doc)]
use super::{Options, Solver};
#[cfg(doc)]
use crate::cost::Cost;

/// How a solve ended. None of these is an error: every status comes with the
/// best trajectory found so far.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Status {
    /// The exact Hessian's model predicts no full step would gain
    /// `tolerance·|J|`, after a full step gained less than that or without
    /// regularisation (see [`Options::tolerance`]), or the cost reached
    /// [`Options::cost_lower_bound`] (up to round-off). A minimum the convex
    /// expansion finds is checked with the exact Hessian first
    /// ([`Options::convex_fallback`]).
    Converged,
    /// `max_iterations` were spent first.
    MaxIterations,
    /// The time budget ran out first.
    TimeLimit,
    /// The cancellation flag was set.
    Cancelled,
    /// A constrained solve ([`Solver::solve_constrained`]): the
    /// augmented Lagrangian's outer loop could not bring the constraints'
    /// violation under [`Options::constraint_tolerance`] (its penalty at
    /// [`Options::penalty_max`] with the violation no longer falling, or
    /// [`Options::max_outer_iterations`] spent). The trajectory returned
    /// is the least violating one found ([`Summary::constraint_violation`]).
    Infeasible,
    /// Regularisation passed `mu_max`: neither the backward pass nor the line
    /// search could make progress, with the exact Hessian nor (where
    /// `convex_fallback` is on and the cost has obstacles) with the convex
    /// expansion after it. Also where the convex expansion found a
    /// stationary point at once, which its model cannot tell from a
    /// maximum, or one the exact Hessian could not move from (a saddle's
    /// signature, or a model step no line search accepts).
    NoProgress,
}

/// One iteration of the solve, as recorded in the trace.
///
/// `non_exhaustive`: the solver makes these and callers only read them, so
/// a field added to them breaks no caller.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct TraceRow {
    /// 1-based iteration number.
    pub iteration: usize,
    /// Cost after this iteration (unchanged when the step was rejected).
    pub cost: f64,
    /// Reduction predicted by the quadratic model for the step taken (or for
    /// the last step size tried, when none was accepted, including a
    /// rollout cut short by the budget or cancellation).
    pub expected_reduction: f64,
    /// Actual reduction (0 when no step was accepted).
    pub actual_reduction: f64,
    /// Accepted step size α, or 0 when the line search failed.
    pub step_size: f64,
    /// Regularisation μ used by this iteration's backward pass.
    pub regularization: f64,
    /// Feedforward size: mean over knots of `max_i |d_i| / (|ū_i| + 1)`.
    pub feedforward_norm: f64,
    /// Whether this iteration's backward pass used the cost's convex
    /// expansion ([`Cost::stage_expand_convex`]) instead of its exact
    /// Hessian: after a fall back ([`Options::convex_fallback`]) and until
    /// the exact Hessian takes over again to check the convex minimum.
    pub convex_model: bool,
    /// Time since the solve started.
    pub elapsed: Duration,
    /// A constrained solve's outer iteration (1-based) this iteration
    /// belongs to; 0 in a solve without constraints.
    pub outer_iteration: usize,
    /// The largest violation of the hard constraints (other than control
    /// bounds, which hold exactly) after this iteration; 0 without
    /// constraints.
    pub constraint_violation: f64,
    /// The augmented Lagrangian's penalty ρ in this iteration; 0 without
    /// constraints.
    pub penalty: f64,
}

/// What a solve reports besides the trajectory, which stays in the [`Solver`].
///
/// `non_exhaustive`, as [`TraceRow`]: constraint violations, for one, will
/// be added here.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct Summary {
    /// How the solve ended.
    pub status: Status,
    /// Final cost `J`.
    pub cost: f64,
    /// Cost of the initial rollout.
    pub initial_cost: f64,
    /// Iterations performed (forward passes attempted).
    pub iterations: usize,
    /// Wall-clock time of the whole solve.
    pub solve_time: Duration,
    /// Whether a backward pass completed, so that [`Solver::feedback`] and
    /// [`Solver::feedforward`] hold a policy. False only when the solve
    /// ended before its first backward pass completed (a time limit or
    /// cancellation during the first linearisation or pass, or, without
    /// [`Options::convex_fallback`], [`Status::NoProgress`] while raising μ
    /// for it, all at iteration 0); the gains are then zero, which is no
    /// policy at all.
    pub has_gains: bool,
    /// Whether the gains are about the iterate before the returned one: the
    /// solve stopped (a time limit, cancellation, or [`Status::NoProgress`]
    /// without [`Options::convex_fallback`]) after an accepted step, before
    /// the backward pass about the new iterate completed (during its
    /// linearisation, the pass itself, or while raising μ). `K` is then the
    /// policy of a trajectory one step away, further off the more
    /// obstacles there are, and `d` can be off the next step by more than
    /// its own size (docs/limits.md, "Gains about the previous iterate").
    /// False whenever the gains were computed about the returned
    /// trajectory, which every other exit guarantees.
    pub gains_about_previous_iterate: bool,
    /// The regularisation μ of the backward pass that produced the gains
    /// (`Q_uu + μI` in place of `Q_uu`): 0 means the undamped Riccati gains
    /// of the final model, larger values damp `K` and `d`. A solve that
    /// ends `NoProgress` or `MaxIterations` on failed line searches (which
    /// raise μ without moving the iterate) returns its iterate's least
    /// regularised gains: μ = 0 where `Q_uu` is positive definite without
    /// regularisation, else the μ of the first pass about it. Meaningless
    /// without [`Summary::has_gains`].
    pub gains_regularization: f64,
    /// The number of iterations completed when the solve fell back to the
    /// cost's convex expansion (see [`Options::convex_fallback`]), or
    /// `None` if it used the exact Hessian throughout.
    pub convexified_after: Option<usize>,
    /// Whether the gains come from the convex expansion: the solve ended on
    /// it, or went back to the exact Hessian to check its minimum and found
    /// no pass to complete there. Never with `Converged`, which the exact
    /// Hessian confirms (a cost at its lower bound aside). False when the
    /// exact Hessian gave the gains, and whenever
    /// [`Summary::convexified_after`] is `None`.
    pub gains_convex: bool,
    /// The largest violation of the constraints at the returned
    /// trajectory, in their own units; 0 without constraints. Control
    /// bounds hold exactly and are not counted.
    pub constraint_violation: f64,
    /// Outer iterations of the augmented Lagrangian; 0 without
    /// constraints.
    pub outer_iterations: usize,
}

/// Input the solver cannot work with.
#[derive(Debug, Clone, PartialEq)]
pub enum SolveError {
    /// `horizon` was 0.
    EmptyHorizon,
    /// The initial control sequence does not have `horizon` entries.
    ControlsLength {
        /// `horizon`.
        expected: usize,
        /// What was given.
        got: usize,
    },
    /// The control bounds of component `index` admit no value (`lower >
    /// upper`, a NaN, `lower = +∞` or `upper = −∞`).
    InvalidControlBounds {
        /// The control component.
        index: usize,
    },
    /// The rollout of the initial controls produced a NaN or infinite state or
    /// cost, so there is nothing to improve on.
    InitialRolloutNotFinite {
        /// The first knot at which it went wrong.
        knot: usize,
    },
}

impl std::fmt::Display for SolveError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::EmptyHorizon => write!(f, "the horizon must have at least one step"),
            Self::ControlsLength { expected, got } => {
                write!(f, "expected {expected} initial controls, got {got}")
            }
            Self::InvalidControlBounds { index } => write!(
                f,
                "the bounds of control {index} admit no value (lower above upper, or NaN)"
            ),
            Self::InitialRolloutNotFinite { knot } => write!(
                f,
                "the initial controls drive the state or cost to NaN/infinity at step {knot}"
            ),
        }
    }
}

impl std::error::Error for SolveError {}
