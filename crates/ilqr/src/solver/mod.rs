//! The iLQR driver loop.
//!
//! One iteration follows steps 1–7 of the seed paper, in the five steps of
//! [`Solver::solve`]'s loop:
//!
//! 1. linearise the dynamics (`A_k`, `B_k`, eq. 11) and expand the cost
//!    (eqs. 18–23) along the nominal trajectory `(x̄, ū)`;
//! 2. backward pass (eqs. 31–48): from `V_x = ∂l_f/∂x`, `V_xx = ∂²l_f/∂x²` at
//!    `x_N`, form `Q_x, Q_u, Q_xx, Q_uu, Q_ux` at each knot and the gains
//!    `d_k = −Q_uu⁻¹ Q_u`, `K_k = −Q_uu⁻¹ Q_ux`;
//! 3. termination check: whether the solve ends here, and with which
//!    [`Status`];
//! 4. forward pass (eqs. 49–51): roll out `u_k = ū_k + α d_k + K_k (x_k − x̄_k)`
//!    through the nonlinear dynamics for a decreasing sequence of step sizes α;
//! 5. update: take the accepted step or keep the iterate, and adjust μ.
//!
//! Robustness beyond the paper, as mature solvers do it (Tassa et al. 2012):
//!
//! * **Levenberg–Marquardt regularisation**: `Q_uu + μI` is factorised instead
//!   of `Q_uu`. μ is raised when that is not positive definite or when the
//!   line search fails, and lowered after a success, on Tassa's quadratic
//!   schedule. The value-function update uses the consistent ("improved")
//!   formulas of eqs. 46–48, so regularisation changes the step, not the model.
//! * **Acceptance by expected reduction**: a step is taken when the actual
//!   reduction is at least `acceptance` times the reduction the quadratic model
//!   predicts, `ΔV(α) = −(α Σ dᵀQ_u + ½ α² Σ dᵀQ_uu d)`.
//! * **Non-finite rollouts are rejected** as if their cost were +∞.
//! * **A convex fallback** where no μ helps: the obstacles' negative
//!   curvature is dropped from the cost's expansion until that model
//!   converges, and the exact Hessian then checks its minimum
//!   ([`Options::convex_fallback`]).
//!
//! The driver owns termination: it checks cancellation and the time budget
//! every iteration and every 128 knots inside the linearisation, backward
//! pass and rollouts, and records one [`TraceRow`] per iteration. How the
//! solve ended is a [`Status`]; only malformed input is a [`SolveError`],
//! and which status it is gets decided in three places. A poll (inside a
//! pass, between rollouts, or once per iteration) ends the solve at once,
//! `Cancelled` or `TimeLimit`; the termination check (step 3) decides
//! `Converged` and `MaxIterations`; and where the model of the cost in use
//! can do no more at any μ, `LoopState::switch_model` hands over to the
//! next model or ends the solve `NoProgress`.
//!
//! Every buffer lives in [`Solver`] and is sized before the loop starts, so
//! the loop itself does not allocate (checked by `tests/allocation.rs`);
//! the one exception is a trace longer than its 10000 reserved rows.
//!
//! # Layout
//!
//! * this file: [`Problem`], [`Solver`] and its workspace, and the loop:
//!   [`Solver::solve`] sets up, `Solver::iterate` runs steps 1–5 until a
//!   stop, `check_termination` is step 3, and the solve's least
//!   regularised gains are found after the loop;
//! * `state`: `LoopState`, what the loop carries between passes (μ, the
//!   cost's model, what is known about the iterate, the gains'
//!   provenance), with one method per transition;
//! * `passes`: the linearisation, the backward pass and the rollouts;
//! * `riccati`: one knot of the backward pass ([`riccati_step`]);
//! * `options`, `report`: [`Options`]; [`Status`], [`Summary`],
//!   [`TraceRow`] and [`SolveError`].
//!
//! `Solver::iterate` works on whatever trajectory, gains and `LoopState`
//! it is given and allocates nothing, with the cost as a parameter of its
//! own: a loop around it (an augmented Lagrangian's, updating multipliers
//! in the cost between calls) can call it again, warm.

mod augmented;
mod constrained;
mod options;
mod passes;
mod report;
mod riccati;
mod state;

use std::cell::Cell;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use nalgebra::{SMatrix, SVector};

pub use options::Options;
pub use report::{SolveError, Status, Summary, TraceRow};
pub use riccati::{RiccatiStep, Value, riccati_step};

use crate::constraint::ControlBounds;
use crate::cost::{Cost, StageExpansion, TerminalExpansion};
use crate::dynamics::DiscreteDynamics;
use augmented::Augmented;
use passes::{Backward, Unfinished, all_finite, rollout};
use state::{LoopState, Model};

/// How close to [`Options::cost_lower_bound`], relative to the initial
/// cost's distance from it, counts as attaining it: machine epsilon
/// squared (4.9e-32). The cost is quadratic in the errors, so errors at
/// round-off relative to the start give a cost at about ε² relative to the
/// initial cost. Plain ε would scale with the guess: from 1e7 N per rotor
/// (initial cost 3.6e21) it counts 7.3e5 as converged, against an optimum
/// of 5.4e3.
const ROUND_OFF_FLOOR: f64 = f64::EPSILON * f64::EPSILON;

/// Trace rows reserved before the loop: 10000 rows of 104 B, 1 MB. The
/// loop allocates only if a solve runs more iterations than that.
const TRACE_RESERVE: usize = 10_000;
// The size above, kept true: a field added to `TraceRow` fails here first.
#[cfg(target_pointer_width = "64")]
const _: () = assert!(std::mem::size_of::<TraceRow>() == 104);

/// A trajectory-optimisation problem: minimise `cost` over `horizon` steps of
/// `dynamics`, starting from `x0`.
pub struct Problem<D, C, const NX: usize> {
    /// The discrete dynamics (model + integrator).
    pub dynamics: D,
    /// The cost to minimise.
    pub cost: C,
    /// The initial state.
    pub x0: SVector<f64, NX>,
    /// The number of control steps `N`; the trajectory has `N + 1` states.
    pub horizon: usize,
}

/// An iLQR solver with its workspace. Reusing one across solves of the same
/// horizon allocates nothing at all.
#[allow(non_snake_case)]
pub struct Solver<const NX: usize, const NU: usize> {
    /// Nominal states `x̄_0..x̄_N`.
    xs: Vec<SVector<f64, NX>>,
    /// Nominal controls `ū_0..ū_{N−1}`.
    us: Vec<SVector<f64, NU>>,
    /// Candidate trajectory of the line search.
    xs_new: Vec<SVector<f64, NX>>,
    us_new: Vec<SVector<f64, NU>>,
    A: Vec<SMatrix<f64, NX, NX>>,
    B: Vec<SMatrix<f64, NX, NU>>,
    stage: Vec<StageExpansion<NX, NU>>,
    terminal: TerminalExpansion<NX>,
    /// Feedback gains `K_k` of the last complete backward pass.
    K: Vec<SMatrix<f64, NU, NX>>,
    /// Feedforward terms `d_k` of the last complete backward pass.
    d: Vec<SVector<f64, NU>>,
    /// A backward pass writes here and is swapped into `K`, `d` only when it
    /// completes, so a pass that fails on an indefinite `Q_uu` (or a solve
    /// stopped while μ is being raised) never leaves a mix of two passes.
    K_next: Vec<SMatrix<f64, NU, NX>>,
    d_next: Vec<SVector<f64, NU>>,
    trace: Vec<TraceRow>,
    /// The control bounds of a constrained solve: the backward pass bounds
    /// its steps by them and the rollouts clamp to them.
    bounds: Option<ControlBounds<NU>>,
    /// The augmented Lagrangian's multipliers, `m` per knot for `N + 1`
    /// knots, and the next outer iteration's.
    lambda: Vec<f64>,
    lambda_next: Vec<f64>,
    /// Its penalties, one per component (the same at every knot), and
    /// each component's largest violation at the last outer iteration's
    /// end.
    rho: Vec<f64>,
    violations: Vec<f64>,
    /// The least violating iterate of a constrained solve, with its gains.
    best_xs: Vec<SVector<f64, NX>>,
    best_us: Vec<SVector<f64, NU>>,
    best_K: Vec<SMatrix<f64, NU, NX>>,
    best_d: Vec<SVector<f64, NU>>,
}

/// How step 2, the backward pass with μ raised until it completes, ended.
enum Pass {
    /// It completed at the loop's μ.
    Done(Backward),
    /// `Q_uu + μI` was not positive definite at some knot for any μ up to
    /// `mu_max`.
    Exhausted,
    /// A poll said stop.
    Interrupted(Status),
}

/// What the termination check lets the loop do next.
enum Verdict {
    /// End the solve.
    Stop(Status),
    /// Start again from step 1: the cost's model changed.
    Relinearize,
    /// Go on to the line search with this pass's model.
    Step(Backward),
}

/// How a line search ended.
enum Step {
    /// A step size was accepted: the new trajectory is the nominal one.
    Accepted {
        /// The step size α.
        alpha: f64,
        /// The new trajectory's cost.
        cost: f64,
        /// The reduction it made.
        actual: f64,
    },
    /// No step size gained enough: the nominal trajectory is unchanged.
    Rejected,
    /// A poll said stop; the nominal trajectory is unchanged.
    Interrupted(Status),
}

/// A line search's outcome and the reduction the model predicted for the
/// last step size tried (0 when none was).
struct LineSearch {
    step: Step,
    expected_reduction: f64,
}

/// How the solve must end now, if it must: `Cancelled` when `cancel` is
/// set, else `TimeLimit` when the budget counted from `start`, less what
/// `clock` keeps back, is spent. Polled once per iteration, between the
/// rollouts of a line search and inside every pass.
fn interruption<'a>(
    cancel: &'a AtomicBool,
    options: &'a Options,
    clock: &'a Clock,
) -> impl Fn() -> Option<Status> + 'a {
    move || {
        if cancel.load(Ordering::Relaxed) {
            Some(Status::Cancelled)
        } else if options
            .time_limit
            .is_some_and(|t| clock.start.elapsed() + clock.reserve() >= t)
        {
            Some(Status::TimeLimit)
        } else {
            None
        }
    }
}

/// A solve's start, and what it keeps back from the budget: rollouts
/// ([`Options::reserve_rollouts`], and a constrained solve's own wrap-up)
/// at the time its slowest one took, and a share per trace row
/// ([`Options::reserve_per_iteration`]).
struct Clock {
    start: Instant,
    rollout: Cell<Duration>,
    /// Rollouts kept back.
    rollouts: f64,
    per_row: Duration,
    rows: Cell<u32>,
}

impl Clock {
    fn new(start: Instant, rollouts: f64, options: &Options) -> Self {
        Self {
            start,
            rollout: Cell::new(Duration::ZERO),
            rollouts: options.reserve_rollouts.max(0.0) + rollouts,
            per_row: options.reserve_per_iteration,
            rows: Cell::new(0),
        }
    }

    /// Count a trace row.
    fn row(&self) {
        self.rows.set(self.rows.get().saturating_add(1));
    }

    /// Record a rollout that began at `began` and has just ended.
    fn rolled_out(&self, began: Instant) {
        self.rollout.set(self.rollout.get().max(began.elapsed()));
    }

    fn reserve(&self) -> Duration {
        self.rollout.get().mul_f64(self.rollouts) + self.per_row * self.rows.get()
    }
}

impl<const NX: usize, const NU: usize> Solver<NX, NU> {
    /// A solver with buffers for `horizon` steps. Solving a longer horizon
    /// later grows them (once, before the loop).
    pub fn new(horizon: usize) -> Self {
        let mut s = Self {
            xs: Vec::new(),
            us: Vec::new(),
            xs_new: Vec::new(),
            us_new: Vec::new(),
            A: Vec::new(),
            B: Vec::new(),
            stage: Vec::new(),
            terminal: TerminalExpansion::zeros(),
            K: Vec::new(),
            d: Vec::new(),
            K_next: Vec::new(),
            d_next: Vec::new(),
            trace: Vec::new(),
            bounds: None,
            lambda: Vec::new(),
            lambda_next: Vec::new(),
            rho: Vec::new(),
            violations: Vec::new(),
            best_xs: Vec::new(),
            best_us: Vec::new(),
            best_K: Vec::new(),
            best_d: Vec::new(),
        };
        s.resize(horizon);
        s
    }

    /// Buffers of exactly `n` steps. Growing reserves exactly what is needed
    /// (`Vec::resize` alone may double the capacity), so a solver kept for
    /// reuse holds no more than its longest horizon.
    fn resize(&mut self, n: usize) {
        fn exact<T: Clone>(v: &mut Vec<T>, len: usize, fill: T) {
            v.reserve_exact(len.saturating_sub(v.len()));
            v.resize(len, fill);
        }
        exact(&mut self.xs, n + 1, SVector::zeros());
        exact(&mut self.xs_new, n + 1, SVector::zeros());
        exact(&mut self.us, n, SVector::zeros());
        exact(&mut self.us_new, n, SVector::zeros());
        exact(&mut self.A, n, SMatrix::zeros());
        exact(&mut self.B, n, SMatrix::zeros());
        exact(&mut self.stage, n, StageExpansion::zeros());
        exact(&mut self.K, n, SMatrix::zeros());
        exact(&mut self.d, n, SVector::zeros());
        exact(&mut self.K_next, n, SMatrix::zeros());
        exact(&mut self.d_next, n, SVector::zeros());
    }

    /// States `x_0..x_N` of the last solve.
    pub fn states(&self) -> &[SVector<f64, NX>] {
        &self.xs
    }

    /// Controls `u_0..u_{N−1}` of the last solve.
    pub fn controls(&self) -> &[SVector<f64, NU>] {
        &self.us
    }

    /// Feedback gains `K_k` of the last solve: the closed-loop policy is
    /// `u_k = ū_k + K_k (x_k − x̄_k)`. They come from the last complete
    /// backward pass, which was about the returned trajectory itself unless
    /// the solve stopped between an accepted step and the completion of the
    /// backward pass about it (a time limit or cancellation while raising μ
    /// or during the linearisation, or [`Status::NoProgress`] while raising
    /// μ without [`Options::convex_fallback`]): then
    /// they are about the iterate before the last accepted step, or zero if
    /// no backward pass had completed yet ([`Summary::has_gains`] false;
    /// [`Summary::gains_about_previous_iterate`] tells the two apart).
    pub fn feedback(&self) -> &[SMatrix<f64, NU, NX>] {
        &self.K
    }

    /// Feedforward terms `d_k` of the last backward pass: the step the solver
    /// would take next (near zero at convergence).
    pub fn feedforward(&self) -> &[SVector<f64, NU>] {
        &self.d
    }

    /// One row per iteration of the last solve.
    pub fn trace(&self) -> &[TraceRow] {
        &self.trace
    }

    /// Solve `problem` from the initial control sequence `u_init`
    /// (`problem.horizon` entries). `cancel` is polled with the time budget
    /// (every iteration and every 128 knots of a pass); setting it ends the
    /// solve with [`Status::Cancelled`].
    pub fn solve<D, C>(
        &mut self,
        problem: &Problem<D, C, NX>,
        u_init: &[SVector<f64, NU>],
        options: &Options,
        cancel: &AtomicBool,
    ) -> Result<Summary, SolveError>
    where
        D: DiscreteDynamics<NX, NU>,
        C: Cost<NX, NU>,
    {
        self.solve_observed(problem, u_init, options, cancel, &mut |_| {})
    }

    /// [`Solver::solve`], calling `observe` with each iteration's
    /// [`TraceRow`] as soon as the iteration ends (the rows [`Solver::trace`]
    /// holds afterwards, in order): a caller can report progress while the
    /// solve runs. `observe` runs on the solver's thread, inside the loop,
    /// so it should be quick; it cannot stop the solve (`cancel` does).
    pub fn solve_observed<D, C>(
        &mut self,
        problem: &Problem<D, C, NX>,
        u_init: &[SVector<f64, NU>],
        options: &Options,
        cancel: &AtomicBool,
        observe: &mut impl FnMut(&TraceRow),
    ) -> Result<Summary, SolveError>
    where
        D: DiscreteDynamics<NX, NU>,
        C: Cost<NX, NU>,
    {
        let start = Instant::now();
        self.bounds = None;
        let clock = Clock::new(start, 0.0, options);
        let cost = self.prepare(problem, &problem.cost, u_init, options, &clock)?;

        let interrupted = interruption(cancel, options, &clock);
        let mut state = LoopState::new(options, cost);
        let (dynamics, cost) = (&problem.dynamics, &problem.cost);
        let status = self.iterate(
            dynamics,
            cost,
            options,
            &mut state,
            (&clock, &interrupted),
            (observe, &|_, _| {}),
        );
        self.least_regularized_gains(dynamics, cost, options, status, &mut state, &interrupted);
        Ok(state.summary(status, start.elapsed()))
    }

    /// Everything before the loop, where all allocation happens: checks
    /// the input, sizes the buffers for `problem.horizon`, loads `u_init`
    /// (clamped into the control bounds, if any) and rolls it out under
    /// `cost`, timing the rollout on `clock`; returns the initial cost.
    fn prepare<D, C, C2>(
        &mut self,
        problem: &Problem<D, C, NX>,
        cost: &C2,
        u_init: &[SVector<f64, NU>],
        options: &Options,
        clock: &Clock,
    ) -> Result<f64, SolveError>
    where
        D: DiscreteDynamics<NX, NU>,
        C2: Cost<NX, NU>,
    {
        let n = problem.horizon;
        if n == 0 {
            return Err(SolveError::EmptyHorizon);
        }
        if u_init.len() != n {
            return Err(SolveError::ControlsLength {
                expected: n,
                got: u_init.len(),
            });
        }

        // Everything that may allocate happens here, before the loop.
        self.resize(n);
        self.trace.clear();
        // Up to TRACE_RESERVE rows up front (104 B each): reserving
        // `max_iterations` itself would let a large cap, meant to leave the
        // stop to a time limit, abort the process on allocation. A solve that
        // runs past the reserve grows the trace in the loop, by doubling.
        self.trace
            .reserve(options.max_iterations.min(TRACE_RESERVE));
        self.us[..n].copy_from_slice(u_init);
        self.K[..n].fill(SMatrix::zeros());
        self.d[..n].fill(SVector::zeros());

        self.xs[0] = problem.x0;
        if let Some(b) = &self.bounds {
            for u in &mut self.us[..n] {
                *u = b.clamp(u);
            }
        }
        let began = Instant::now();
        let cost = rollout(&problem.dynamics, cost, &mut self.xs, &self.us);
        clock.rolled_out(began);
        // States too, not only the cost: a cost that does not read every
        // state component (control effort only, say) stays finite over a
        // NaN state.
        let bad_state = self.xs[..=n].iter().position(|x| !all_finite(x));
        if !cost.is_finite() || bad_state.is_some() {
            let knot = bad_state.unwrap_or(n);
            return Err(SolveError::InitialRolloutNotFinite { knot });
        }

        Ok(cost)
    }

    /// Steps 1–5 from the nominal trajectory in the workspace until a stop;
    /// returns how the solve ended. Each accepted step replaces the nominal
    /// trajectory, and each iteration adds one row to the trace, its time
    /// counted from `start`, filled in further by `annotate` (an outer
    /// loop's iteration, violation and penalty) and then passed to
    /// `observe`.
    fn iterate<D, C>(
        &mut self,
        dynamics: &D,
        cost: &C,
        options: &Options,
        state: &mut LoopState,
        (clock, interrupted): (&Clock, &impl Fn() -> Option<Status>),
        (observe, annotate): (&mut impl FnMut(&TraceRow), &impl Fn(&Self, &mut TraceRow)),
    ) -> Status
    where
        D: DiscreteDynamics<NX, NU>,
        C: Cost<NX, NU>,
    {
        loop {
            // 1. Derivatives along the nominal trajectory, when it moved or
            //    the model changed. A linearisation cut short leaves them half
            //    updated; the solve ends there, and the gains, from the pass
            //    before the accepted step, are flagged as such.
            if state.stale {
                if let Some(status) = self.linearize(dynamics, cost, state.model, interrupted) {
                    return status;
                }
                state.linearized();
            }

            // 2. Backward pass, raising μ until Q_uu + μI is positive definite.
            let pass = self.regularized_backward(dynamics, options, state, interrupted);

            // 3. Termination check.
            let bw = match self.check_termination(dynamics, cost, options, state, pass, interrupted)
            {
                Verdict::Stop(status) => return status,
                Verdict::Relinearize => continue,
                Verdict::Step(bw) => bw,
            };

            // 4. Forward pass with a line search on α.
            state.iterations += 1;
            let mut row = TraceRow {
                iteration: state.iterations,
                cost: state.cost,
                expected_reduction: 0.0,
                actual_reduction: 0.0,
                step_size: 0.0,
                regularization: state.mu,
                feedforward_norm: self.feedforward_norm(),
                convex_model: state.model == Model::Convex,
                elapsed: Duration::ZERO,
                outer_iteration: 0,
                constraint_violation: 0.0,
                penalty: 0.0,
            };
            let search = self.line_search(dynamics, cost, options, state.cost, &bw, interrupted);

            // 5. Update the iterate and μ.
            row.expected_reduction = search.expected_reduction;
            match search.step {
                Step::Accepted {
                    alpha,
                    cost: new_cost,
                    actual,
                } => {
                    (row.step_size, row.actual_reduction, row.cost) = (alpha, actual, new_cost);
                    state.accept_step(options, alpha, new_cost, actual);
                }
                Step::Rejected => state.reject_step(options),
                Step::Interrupted(status) => {
                    // The nominal trajectory is unchanged, so the gains of
                    // this iteration's backward pass still describe it.
                    row.elapsed = clock.start.elapsed();
                    annotate(self, &mut row);
                    self.trace.push(row);
                    clock.row();
                    observe(&row);
                    return status;
                }
            }
            row.elapsed = clock.start.elapsed();
            annotate(self, &mut row);
            self.trace.push(row);
            clock.row();
            observe(&row);
            // Where the model in use can do no more, the next one takes
            // over from step 1, or the solve ends `NoProgress`.
            if state.exhausted(options)
                && let Err(status) = state.switch_model(cost, options)
            {
                return status;
            }
        }
    }

    /// Step 2: the backward pass at the loop's μ, raising μ while `Q_uu +
    /// μI` is not positive definite, until it completes or μ passes
    /// `mu_max`.
    fn regularized_backward<D: DiscreteDynamics<NX, NU>>(
        &mut self,
        dynamics: &D,
        options: &Options,
        state: &mut LoopState,
        interrupted: &impl Fn() -> Option<Status>,
    ) -> Pass {
        loop {
            match self.backward(
                dynamics,
                state.mu,
                state.model.second_order(options),
                interrupted,
            ) {
                Ok(bw) => {
                    state.pass_completed();
                    return Pass::Done(bw);
                }
                // The pass writes into spare buffers, so an interrupted one
                // leaves the previous gains as they were.
                Err(Unfinished::Interrupted(status)) => return Pass::Interrupted(status),
                Err(Unfinished::NotPositiveDefinite) => {
                    state.increase_mu(options);
                    if state.mu > options.mu_max {
                        return Pass::Exhausted;
                    }
                    // Raising μ can take a dozen passes (μ from 1 past
                    // 1e11), 12 ms at N = 10000: the budget is checked
                    // between them too.
                    if let Some(status) = interrupted() {
                        return Pass::Interrupted(status);
                    }
                }
            }
        }
    }

    /// Step 3: whether the solve ends here and with which [`Status`], or
    /// what it does next. After a complete backward pass about the current
    /// iterate, in this order:
    ///
    /// 1. the cost attains [`Options::cost_lower_bound`] (up to
    ///    round-off): `Converged`;
    /// 2. the test for a minimum: the model predicts that a full step would
    ///    gain less than `tolerance·|J|`, and the last full step gained
    ///    less than that too, or `Q_uu` is positive definite without
    ///    regularisation (see [`Options::tolerance`]). Where the first two
    ///    facts do not settle it, the solve polls (`Cancelled`,
    ///    `TimeLimit`) and, where the damped model predicts almost nothing,
    ///    a pass at μ = 0 decides;
    /// 3. a minimum of the exact Hessian is `Converged`; the convex model's
    ///    is tried with one step where that model has not moved yet, and
    ///    is otherwise checked by the exact Hessian, from step 1;
    /// 4. `max_iterations` spent: `MaxIterations`.
    ///
    /// The tests come before the iteration cap and the budget: a solve that
    /// converges in exactly `max_iterations` iterations, or whose warm
    /// start is already optimal (`max_iterations = 0`), is `Converged`, not
    /// `MaxIterations`. The gains describe the current trajectory here, so
    /// every stop from here on returns a consistent policy.
    ///
    /// An interrupted pass ends the solve with the poll's status; where no
    /// μ up to `mu_max` completed the pass, the next model takes over or
    /// the solve ends `NoProgress` ([`LoopState::switch_model`]).
    fn check_termination<D, C>(
        &mut self,
        dynamics: &D,
        cost: &C,
        options: &Options,
        state: &mut LoopState,
        pass: Pass,
        interrupted: &impl Fn() -> Option<Status>,
    ) -> Verdict
    where
        D: DiscreteDynamics<NX, NU>,
        C: Cost<NX, NU>,
    {
        state.probe_replaced = None;
        let mut bw = match pass {
            Pass::Done(bw) => bw,
            Pass::Interrupted(status) => return Verdict::Stop(status),
            Pass::Exhausted => {
                return match state.switch_model(cost, options) {
                    Ok(()) => Verdict::Relinearize,
                    Err(status) => Verdict::Stop(status),
                };
            }
        };
        if state
            .cost_lower_bound
            .is_some_and(|lb| state.cost - lb <= ROUND_OFF_FLOOR * (state.initial_cost - lb))
        {
            return Verdict::Stop(Status::Converged);
        }
        let (tolerance, j) = (state.tolerance, state.cost);
        // The last full step gained less than the tolerance, and the model at
        // the new iterate agrees that a full step would gain no more. The
        // step alone is not enough: in a slow descent one full step can gain
        // a thousandth of its prediction where the next model still predicts
        // 1300 times the tolerance (the optimum then lies 4e-6 lower, at
        // tolerance 1e-9).
        let mut minimum = (state.small_full_step
            && state.mu <= options.mu_converged_max
            && bw.negligible(tolerance, j))
            || (bw.negligible(tolerance, j) && state.mu <= options.mu_min);
        if !minimum {
            // Once per iteration, and before the pass at μ = 0 below,
            // which costs a backward pass.
            if let Some(status) = interrupted() {
                return Verdict::Stop(status);
            }
            // The model says even a full step would gain almost nothing.
            // That is only evidence of a minimum without regularisation: a
            // large μ shrinks the step, and its predicted gain, wherever the
            // iterate is. So with μ above μ_min, one more pass at μ = 0
            // decides. If Q_uu is positive definite at every knot there, the
            // model is convex and that pass's prediction is trusted
            // (converged, or a plain Newton step to take); if not (a maximum
            // or saddle, such as an obstacle's centre), the gains of the pass
            // at μ are untouched and the solve goes on as before. Without
            // it, a solve whose last accepted steps are tiny partial ones
            // keeps μ above μ_min, its line searches fail on round-off, and
            // it ends `NoProgress` at a solution converged to 1e-16
            // (`dt = 10`, no obstacles).
            if bw.negligible(tolerance, j) && state.mu > options.mu_min && !state.probe_failed {
                match self.backward(
                    dynamics,
                    0.0,
                    state.model.second_order(options),
                    interrupted,
                ) {
                    Ok(unregularized) => {
                        bw = unregularized;
                        state.probe_completed();
                        minimum = bw.negligible(tolerance, j);
                    }
                    // The gains of the pass at μ stay, about this iterate.
                    Err(Unfinished::Interrupted(status)) => return Verdict::Stop(status),
                    Err(Unfinished::NotPositiveDefinite) => state.probe_failed = true,
                }
            }
        }
        if minimum {
            match (state.model, state.moved) {
                (Model::Exact | Model::Checking, _) => return Verdict::Stop(Status::Converged),
                // The convex model's first step is tried before its
                // prediction is trusted: at an obstacle's centre the
                // gradient is taken as 0 (the cone's tip has none), so the
                // model predicts only what the other terms gain, while any
                // step off the tip gains about q per metre (from the centre
                // of eleven 1e12 obstacles, the prediction alone would end
                // the solve `NoProgress` at iteration 0, at 1.1e15). Where
                // the step gains nothing either (a solve stuck at its
                // optimum on round-off, a guess held on a tip), the model is
                // exhausted and the solve ends `NoProgress` after that one
                // iteration.
                (Model::Convex, false) => state.convex_step_tried = true,
                (Model::Convex, true) => {
                    state.check_convex_minimum(options);
                    return Verdict::Relinearize;
                }
            }
        }
        if state.iterations >= state.max_iterations {
            return Verdict::Stop(Status::MaxIterations);
        }
        Verdict::Step(bw)
    }

    /// Step 4: roll out `u = ū + α d + K (x − x̄)` for each step size in
    /// turn and accept the first whose actual reduction of `cost` is at
    /// least `acceptance` times the model's, `ΔV(α) = −(α·dv1 + α²·dv2)`
    /// (or positive, where the model predicts none). An accepted rollout
    /// becomes the nominal trajectory.
    fn line_search<D, C>(
        &mut self,
        dynamics: &D,
        cost: &C,
        options: &Options,
        current: f64,
        bw: &Backward,
        interrupted: &impl Fn() -> Option<Status>,
    ) -> LineSearch
    where
        D: DiscreteDynamics<NX, NU>,
        C: Cost<NX, NU>,
    {
        let mut expected_reduction = 0.0;
        for (i, &alpha) in options.step_sizes.iter().enumerate() {
            // Between rollouts too (each also polls inside), so that no
            // rollout starts after the budget ran out.
            if i > 0
                && let Some(status) = interrupted()
            {
                return LineSearch {
                    step: Step::Interrupted(status),
                    expected_reduction,
                };
            }
            // `0.0 -`, not unary minus: a zero model reduction is +0,
            // which JSON writes as 0 rather than -0.
            let expected = 0.0 - (alpha * bw.dv1 + alpha * alpha * bw.dv2);
            expected_reduction = expected;
            let new_cost = match self.forward(dynamics, cost, alpha, interrupted) {
                Ok(new_cost) => new_cost,
                // A trial cut short is discarded like a failed one.
                Err(status) => {
                    return LineSearch {
                        step: Step::Interrupted(status),
                        expected_reduction,
                    };
                }
            };
            if !new_cost.is_finite() {
                continue;
            }
            let actual = current - new_cost;
            let ok = if expected > 0.0 {
                actual / expected > options.acceptance
            } else {
                actual > 0.0
            };
            if ok {
                std::mem::swap(&mut self.xs, &mut self.xs_new);
                std::mem::swap(&mut self.us, &mut self.us_new);
                return LineSearch {
                    step: Step::Accepted {
                        alpha,
                        cost: new_cost,
                        actual,
                    },
                    expected_reduction,
                };
            }
        }
        LineSearch {
            step: Step::Rejected,
            expected_reduction,
        }
    }

    /// After the loop: the least regularised gains about the final iterate,
    /// for a solve that ended `NoProgress` or `MaxIterations`.
    ///
    /// Failed line searches raise μ without moving the iterate, so a solve
    /// that ends on them would return gains damped to nothing: at the
    /// seed's optimum with a zero tolerance μ reaches 4e18 and max |K|
    /// 6e-11, and from a perturbed start such a closed loop misses the goal
    /// by as much as the open loop. The least regularised gains about the
    /// iterate are returned instead: the undamped Riccati gains where `Q_uu`
    /// is positive definite without μ, else those of the iterate's first
    /// pass (the same derivatives and μ, so it succeeds again unless the
    /// budget runs out; a failed pass leaves the gains as they were).
    ///
    /// A convex fallback that never moved left the trajectory where the
    /// exact Hessian got stuck, so the exact model's gains are the ones to
    /// give (the seed with a zero tolerance, stuck at its optimum on
    /// round-off, ends on the convex model). A linearisation the budget cuts
    /// short leaves the derivatives half updated: no pass may run on them
    /// then.
    fn least_regularized_gains<D, C>(
        &mut self,
        dynamics: &D,
        cost: &C,
        options: &Options,
        status: Status,
        state: &mut LoopState,
        interrupted: &impl Fn() -> Option<Status>,
    ) where
        D: DiscreteDynamics<NX, NU>,
        C: Cost<NX, NU>,
    {
        let mut relinearized = false;
        if status == Status::NoProgress
            && state.model == Model::Convex
            && !state.moved
            && state.gains.current
        {
            if self
                .linearize(dynamics, cost, Model::Exact, interrupted)
                .is_some()
            {
                return;
            }
            (state.model, state.least_mu, relinearized) = (Model::Exact, None, true);
        }
        if !matches!(status, Status::NoProgress | Status::MaxIterations) || !state.gains.current {
            return;
        }
        let first = state.least_mu.filter(|&first| first > 0.0);
        for mu in std::iter::once(0.0).chain(first) {
            if mu >= state.gains.mu && !relinearized {
                break;
            }
            let second = state.model.second_order(options);
            if self.backward(dynamics, mu, second, interrupted).is_ok() {
                state.gains.mu = mu;
                state.gains.convex = state.model == Model::Convex;
                break;
            }
        }
    }
}
