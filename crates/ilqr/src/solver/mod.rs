//! The iLQR driver loop.
//!
//! One iteration, following steps 1–7 of the seed paper:
//!
//! 1. linearise the dynamics (`A_k`, `B_k`, eq. 11) and expand the cost
//!    (eqs. 18–23) along the nominal trajectory `(x̄, ū)`;
//! 2. backward pass (eqs. 31–48): from `V_x = ∂l_f/∂x`, `V_xx = ∂²l_f/∂x²` at
//!    `x_N`, form `Q_x, Q_u, Q_xx, Q_uu, Q_ux` at each knot and the gains
//!    `d_k = −Q_uu⁻¹ Q_u`, `K_k = −Q_uu⁻¹ Q_ux`;
//! 3. forward pass (eqs. 49–51): roll out `u_k = ū_k + α d_k + K_k (x_k − x̄_k)`
//!    through the nonlinear dynamics for a decreasing sequence of step sizes α.
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
//! solve ended is a [`Status`]; only malformed input is a [`SolveError`].
//!
//! Every buffer lives in [`Solver`] and is sized before the loop starts, so
//! the loop itself does not allocate (checked by `tests/allocation.rs`);
//! the one exception is a trace longer than its 10000 reserved rows.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use nalgebra::{SMatrix, SVector};

mod options;
mod report;
mod riccati;

pub use options::Options;
pub use report::{SolveError, Status, Summary, TraceRow};
pub use riccati::{RiccatiStep, Value, riccati_step};

use crate::cost::{Cost, StageExpansion, TerminalExpansion};
use crate::dynamics::{DiscreteDynamics, Sparsity};
use riccati::riccati_step_into;

/// Knots between two polls of the cancellation flag and the time budget
/// inside a linearisation, backward pass or rollout. Each of those passes
/// costs N × (1 + obstacles) work, 20 ms at N = 10000 with 100 obstacles,
/// so polling only between them let a solve answer that late. 128 knots
/// are at most about 0.3 ms of work (2 µs a knot with 100 obstacles) and
/// one poll (~25 ns) per 128 knots is lost in the noise; the seed's
/// N = 100 passes are not polled inside at all.
const POLL_EVERY: usize = 128;

/// Whether a pass polls before its next knot, `done` knots into the pass
/// (the linearisation and rollouts count from k = 0, the backward pass from
/// k = N − 1): before every 128th knot.
#[inline(always)]
fn poll_due(done: usize) -> bool {
    (done + 1).is_multiple_of(POLL_EVERY)
}

/// How close to [`Options::cost_lower_bound`], relative to the initial
/// cost's distance from it, counts as attaining it: machine epsilon
/// squared (4.9e-32). The cost is quadratic in the errors, so errors at
/// round-off relative to the start give a cost at about ε² relative to the
/// initial cost. Plain ε was too coarse: it scales with the guess, and a
/// guess of 1e7 N per rotor (initial cost 3.6e21) then counted 7.3e5 as
/// converged, against an optimum of 5.4e3.
const ROUND_OFF_FLOOR: f64 = f64::EPSILON * f64::EPSILON;

/// Trace rows reserved before the loop: 10000 rows of 80 B, 800 KB. The
/// loop allocates only if a solve runs more iterations than that.
const TRACE_RESERVE: usize = 10_000;
// The size above, kept true: a field added to `TraceRow` fails here first.
#[cfg(target_pointer_width = "64")]
const _: () = assert!(std::mem::size_of::<TraceRow>() == 80);

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
}

/// Outcome of one backward pass.
struct Backward {
    /// `Σ dᵀQ_u` and `Σ ½ dᵀQ_uu d`: ΔV(α) = −(α·dv1 + α²·dv2).
    dv1: f64,
    dv2: f64,
}

/// Why a backward pass did not complete.
enum Unfinished {
    /// `Q_uu + μI` is not positive definite at some knot: raise μ.
    NotPositiveDefinite,
    /// The solve was cancelled or ran out of time during the pass.
    Interrupted(Status),
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
        let start = Instant::now();
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
        // Up to TRACE_RESERVE rows up front (80 B each): reserving
        // `max_iterations` itself would let a large cap, meant to leave the
        // stop to a time limit, abort the process on allocation. A solve that
        // runs past the reserve grows the trace in the loop, by doubling.
        self.trace
            .reserve(options.max_iterations.min(TRACE_RESERVE));
        self.us[..n].copy_from_slice(u_init);
        self.K[..n].fill(SMatrix::zeros());
        self.d[..n].fill(SVector::zeros());

        self.xs[0] = problem.x0;
        let mut cost = rollout(problem, &mut self.xs, &self.us);
        // States too, not only the cost: a cost that does not read every
        // state component (control effort only, say) stays finite over a
        // NaN state.
        let bad_state = self.xs[..=n].iter().position(|x| !all_finite(x));
        if !cost.is_finite() || bad_state.is_some() {
            let knot = bad_state.unwrap_or(n);
            return Err(SolveError::InitialRolloutNotFinite { knot });
        }
        let initial_cost = cost;

        // Cancellation and the time budget, polled once per iteration,
        // between the rollouts of a line search and inside every pass.
        let interrupted = || {
            if cancel.load(Ordering::Relaxed) {
                Some(Status::Cancelled)
            } else if options.time_limit.is_some_and(|t| start.elapsed() >= t) {
                Some(Status::TimeLimit)
            } else {
                None
            }
        };
        let mut mu = options.mu_init;
        let mut delta = 1.0;
        let mut iterations = 0;
        let mut converged = false;
        let mut stale = true;
        let mut has_gains = false;
        let mut gains_current = false;
        let mut gains_mu = 0.0;
        // Whether the gains come from the convex expansion.
        let mut gains_convex = false;
        // The μ of the first backward pass that succeeded at the current
        // iterate and expansion: the least regularised gains about it, since
        // μ only grows between accepted steps.
        let mut iterate_mu = None;
        // Whether a pass at μ = 0 failed at the current iterate (Q_uu not
        // positive definite there, or its step rejected): the derivatives
        // are the same until a step is accepted, so it would fail again.
        let mut probe_failed = false;
        let mut convexified_after = None;
        let mut model = Model::Exact;
        // The dynamics' curvature for the backward pass: with
        // `second_order`, except under the convex model, which keeps only
        // the curvature that cannot be negative.
        let second = |model: Model| options.second_order && model != Model::Convex;
        // Whether a step was accepted since the last change of `model`.
        // The convex expansion cannot tell a minimum from a maximum or a
        // saddle (the curvature that would is what it drops): where it finds
        // nothing to do at once, the exact model had found no descent either
        // (an obstacle's centre held by the guess), and calling that point
        // converged would be false.
        let mut moved = false;
        // Whether the convex model's step was tried where it predicted
        // nothing worth taking (see the end of the convergence tests); once
        // per change of `model`.
        let mut convex_step_tried = false;

        let status = 'outer: loop {
            // 1. Derivatives along the nominal trajectory. They change only
            //    when a step was accepted; after a rejected step the same
            //    ones are reused with a larger μ.
            if stale {
                // An interrupted linearisation leaves the derivatives half
                // updated; the solve ends here, and the gains, from the
                // pass before the accepted step, are flagged as such.
                // One copy of the loop per expansion, each without a branch
                // per knot.
                let interrupted_at = if model == Model::Convex {
                    self.linearize::<true, _, _>(problem, &interrupted)
                } else {
                    self.linearize::<false, _, _>(problem, &interrupted)
                };
                if let Some(status) = interrupted_at {
                    break 'outer status;
                }
                stale = false;
                iterate_mu = None;
                probe_failed = false;
            }

            // 2. Backward pass, raising μ until Q_uu + μI is positive definite.
            let mut bw = loop {
                match self.backward(&problem.dynamics, mu, second(model), &interrupted) {
                    Ok(bw) => {
                        has_gains = true;
                        gains_current = true;
                        gains_mu = mu;
                        gains_convex = model == Model::Convex;
                        iterate_mu.get_or_insert(mu);
                        break bw;
                    }
                    // The pass writes into spare buffers, so an interrupted
                    // one leaves the previous gains as they were.
                    Err(Unfinished::Interrupted(status)) => break 'outer status,
                    Err(Unfinished::NotPositiveDefinite) => {
                        increase(&mut mu, &mut delta, options);
                        if mu > options.mu_max {
                            if let Err(status) = fall_back(
                                problem,
                                options,
                                (&mut model, &mut convexified_after),
                                (moved, iterations),
                            ) {
                                break 'outer status;
                            }
                            // A convergence the last model's last step
                            // claimed is not carried over: the next model
                            // must find it for itself.
                            (mu, delta, stale, converged, moved, convex_step_tried) =
                                (options.mu_init, 1.0, true, false, false, false);
                            continue 'outer;
                        }
                        // Raising μ can take a dozen passes (μ from 1 past
                        // 1e11): unchecked, a 10 ms budget at N = 10000
                        // ended 11.7 ms late (BENCHMARKS.md). So the budget
                        // is checked between them too.
                        if let Some(status) = interrupted() {
                            break 'outer status;
                        }
                    }
                }
            };

            // The gains now describe the current trajectory, so every exit
            // from here on returns a consistent policy. The convergence tests
            // come before the iteration cap and the budget: a solve that
            // converged in exactly `max_iterations` iterations, or whose
            // warm start was already optimal (`max_iterations = 0`), is
            // `Converged`, not `MaxIterations`.
            if options
                .cost_lower_bound
                .is_some_and(|lb| cost - lb <= ROUND_OFF_FLOOR * (initial_cost - lb))
            {
                break Status::Converged;
            }
            let negligible = |bw: &Backward| -(bw.dv1 + bw.dv2) <= options.tolerance * cost.abs();
            // The last full step gained less than the tolerance, and the
            // model at the new iterate agrees that a full step would gain no
            // more. The step alone is not enough: one full step that gained a
            // thousandth of its prediction ended a slow descent whose next
            // model predicted 1300 times the tolerance (IPOPT then found the
            // cost 4e-6 lower, at tolerance 1e-9).
            let mut minimum = (converged && mu <= options.mu_converged_max && negligible(&bw))
                || (negligible(&bw) && mu <= options.mu_min);
            // The μ the pass at μ = 0 below replaced, if it ran this
            // iteration: restored, then raised, if its step is rejected.
            let mut mu_before_probe = None;
            if !minimum {
                // Once per iteration, and before the pass at μ = 0 below,
                // which costs a backward pass.
                if let Some(status) = interrupted() {
                    break status;
                }
                // The model says even a full step would gain almost nothing.
                // That is only evidence of a minimum without regularisation:
                // a large μ shrinks the step, and its predicted gain,
                // wherever the iterate is. So with μ above μ_min, one more
                // pass at μ = 0 decides. If Q_uu is positive definite at
                // every knot there, the model is convex and that pass's
                // prediction is trusted (converged, or a plain Newton step
                // to take); if not (a maximum or saddle, such as an
                // obstacle's centre), the gains of the pass at μ are
                // untouched and the solve goes on as before. Without this, a
                // solve whose last accepted steps were tiny partial ones kept
                // μ above μ_min, its line searches then failed on round-off,
                // and it ended `NoProgress` at a solution converged to 1e-16
                // (`dt = 10`, no obstacles).
                if negligible(&bw) && mu > options.mu_min && !probe_failed {
                    match self.backward(&problem.dynamics, 0.0, second(model), &interrupted) {
                        Ok(unregularised) => {
                            bw = unregularised;
                            mu_before_probe = Some(mu);
                            mu = 0.0;
                            gains_mu = 0.0;
                            gains_convex = model == Model::Convex;
                            iterate_mu = Some(0.0);
                            minimum = negligible(&bw);
                        }
                        // The gains of the pass at μ stay, about this iterate.
                        Err(Unfinished::Interrupted(status)) => break status,
                        Err(Unfinished::NotPositiveDefinite) => probe_failed = true,
                    }
                }
            }
            if minimum {
                match (model, moved) {
                    (Model::Exact | Model::Checking, _) => break Status::Converged,
                    // The convex model's first step is tried before its
                    // prediction is trusted: at an obstacle's centre the
                    // gradient is taken as 0 (the cone's tip has none), so
                    // the model predicts only what the other terms gain,
                    // while any step off the tip gains about q per metre. A
                    // start on the centre of eleven 1e12 obstacles ended
                    // `NoProgress` at iteration 0 at 1.1e15, with ten at
                    // 2e13. Where the step gains nothing either (a solve
                    // stuck at its optimum on round-off, a guess held on a
                    // tip), the solve ends `NoProgress` after that one
                    // iteration (after the line search below).
                    (Model::Convex, false) => convex_step_tried = true,
                    // The convex model's minimum may not be the cost's: its
                    // larger curvature under-predicts what a step gains. The
                    // exact Hessian checks it, from μ_init.
                    (Model::Convex, true) => {
                        model = Model::Checking;
                        (mu, delta, stale, converged, moved, convex_step_tried) =
                            (options.mu_init, 1.0, true, false, false, false);
                        continue 'outer;
                    }
                }
            }
            if iterations >= options.max_iterations {
                break Status::MaxIterations;
            }
            iterations += 1;

            // 3. Forward pass with a line search on α.
            let ff_norm = self.feedforward_norm(n);
            let mut row = TraceRow {
                iteration: iterations,
                cost,
                expected_reduction: 0.0,
                actual_reduction: 0.0,
                step_size: 0.0,
                regularization: mu,
                feedforward_norm: ff_norm,
                convex_model: model == Model::Convex,
                elapsed: Duration::ZERO,
            };
            let mut accepted = false;
            let mut stop = None;
            for (i, &alpha) in options.step_sizes.iter().enumerate() {
                // Between rollouts too (each also polls inside), so that no
                // rollout starts after the budget ran out.
                if i > 0 {
                    stop = interrupted();
                    if stop.is_some() {
                        break;
                    }
                }
                // `0.0 -`, not unary minus: a zero model reduction is +0,
                // which JSON writes as 0 rather than -0.
                let expected = 0.0 - (alpha * bw.dv1 + alpha * alpha * bw.dv2);
                row.expected_reduction = expected;
                let new_cost = match self.forward(problem, alpha, &interrupted) {
                    Ok(new_cost) => new_cost,
                    // A trial cut short is discarded like a failed one.
                    Err(status) => {
                        stop = Some(status);
                        break;
                    }
                };
                if !new_cost.is_finite() {
                    continue;
                }
                let actual = cost - new_cost;
                let ok = if expected > 0.0 {
                    actual / expected > options.acceptance
                } else {
                    actual > 0.0
                };
                if ok {
                    std::mem::swap(&mut self.xs, &mut self.xs_new);
                    std::mem::swap(&mut self.us, &mut self.us_new);
                    row.actual_reduction = actual;
                    row.step_size = alpha;
                    row.cost = new_cost;
                    // Under a huge μ every step is tiny wherever the iterate
                    // is, so its small gain proves nothing (`mu_converged_max`);
                    // there the next iteration's model test decides.
                    converged = alpha == 1.0
                        && mu <= options.mu_converged_max
                        && actual <= options.tolerance * cost.abs();
                    cost = new_cost;
                    accepted = true;
                    moved = true;
                    break;
                }
            }
            if let Some(status) = stop {
                // The nominal trajectory is unchanged, so the gains of this
                // iteration's backward pass still describe it.
                row.elapsed = start.elapsed();
                self.trace.push(row);
                break status;
            }
            if accepted {
                stale = true;
                // The gains describe the previous iterate until the next
                // backward pass completes.
                gains_current = false;
                decrease(&mut mu, &mut delta, options);
            } else {
                // The model about the last step's iterate predicted more
                // than it found: its small gain no longer counts, or the
                // rising μ would shrink the model's prediction until it
                // agreed.
                converged = false;
                // A failed step of the pass at μ = 0 is no reason to restart
                // the schedule from μ_min: the damped model it replaced
                // still stands, so μ goes on up from where it was. Without
                // this, each retry at μ_min repeated the negligible
                // prediction, the pass at μ = 0 and its failed step, and μ
                // never rose: mass 1e6 from zero thrust ran 250 iterations
                // without an accepted step, at μ alternating 0 and 1e-6.
                // Any rejected step at μ = 0 (an ordinary pass there too)
                // tells the pass at μ = 0 not to run again at this iterate.
                probe_failed |= mu == 0.0;
                if let Some(before) = mu_before_probe {
                    mu = before;
                }
                increase(&mut mu, &mut delta, options);
            }
            row.elapsed = start.elapsed();
            self.trace.push(row);
            // The convex model's trial step (below its negligible
            // prediction) found nothing either: the model stands, and
            // raising μ to its maximum would only shrink the same step (14
            // more passes, each with a full line search).
            // (The flag is only ever set under the convex model, and cleared
            // when the model changes.)
            if !accepted && convex_step_tried && !moved {
                break Status::NoProgress;
            }
            if mu > options.mu_max {
                if let Err(status) = fall_back(
                    problem,
                    options,
                    (&mut model, &mut convexified_after),
                    (moved, iterations),
                ) {
                    break status;
                }
                (mu, delta, stale, converged, moved, convex_step_tried) =
                    (options.mu_init, 1.0, true, false, false, false);
            }
        };

        // Failed line searches raise μ without moving the iterate, so a
        // solve that ends on them (`NoProgress`, or the iteration cap) would
        // return gains damped to nothing: at the seed's optimum with a zero
        // tolerance, μ reached 4e18 and max |K| 6e-11, and from a perturbed
        // start the closed loop missed the goal by as much as the open loop.
        // The least regularised gains about the iterate are returned
        // instead: the undamped Riccati gains where `Q_uu` is positive
        // definite without μ, else those of the iterate's first pass (the
        // same derivatives and μ, so it succeeds again unless the budget
        // runs out; a failed pass leaves the gains as they were).
        //
        // A convex fallback that never moved left the trajectory where the
        // exact Hessian got stuck, so the exact model's gains are the ones
        // to give: the seed with a zero tolerance, stuck at its optimum on
        // round-off, ended on the convex model's.
        // A linearisation the budget cut short leaves the derivatives half
        // updated: no pass may run on them then.
        let (mut relinearized, mut derivatives_whole) = (false, true);
        if status == Status::NoProgress && model == Model::Convex && !moved && gains_current {
            match self.linearize::<false, _, _>(problem, &interrupted) {
                None => (model, iterate_mu, relinearized) = (Model::Exact, None, true),
                Some(_) => derivatives_whole = false,
            }
        }
        if matches!(status, Status::NoProgress | Status::MaxIterations)
            && gains_current
            && derivatives_whole
        {
            let first = iterate_mu.filter(|&first| first > 0.0);
            for mu in std::iter::once(0.0).chain(first) {
                if mu >= gains_mu && !relinearized {
                    break;
                }
                if self
                    .backward(&problem.dynamics, mu, second(model), &interrupted)
                    .is_ok()
                {
                    gains_mu = mu;
                    gains_convex = model == Model::Convex;
                    break;
                }
            }
        }

        Ok(Summary {
            status,
            cost,
            initial_cost,
            iterations,
            solve_time: start.elapsed(),
            has_gains,
            gains_about_previous_iterate: has_gains && !gains_current,
            gains_regularization: gains_mu,
            convexified_after,
            gains_convex,
        })
    }

    /// Fill `A`, `B` and the cost expansions along `(xs, us)`. Returns how
    /// the solve must end if `interrupted` says so on one of its polls.
    fn linearize<const CONVEX: bool, D, C>(
        &mut self,
        problem: &Problem<D, C, NX>,
        interrupted: &impl Fn() -> Option<Status>,
    ) -> Option<Status>
    where
        D: DiscreteDynamics<NX, NU>,
        C: Cost<NX, NU>,
    {
        let n = problem.horizon;
        for k in 0..n {
            if poll_due(k)
                && let Some(status) = interrupted()
            {
                return Some(status);
            }
            let (x, u) = (&self.xs[k], &self.us[k]);
            (self.A[k], self.B[k]) = problem.dynamics.linearize(x, u);
            let e = &mut self.stage[k];
            *e = StageExpansion::zeros();
            if CONVEX {
                problem.cost.stage_expand_convex(k, x, u, e);
            } else {
                problem.cost.stage_expand(k, x, u, e);
            }
        }
        self.terminal = TerminalExpansion::zeros();
        problem
            .cost
            .terminal_expand(&self.xs[n], &mut self.terminal);
        None
    }

    /// Eqs. 31–48 with `Q_uu + μI`, knot by knot from `N − 1` down to 0.
    /// Fails when `Q_uu + μI` is not positive definite at some knot, or when
    /// `interrupted` says so on one of its polls. Either way `K` and `d` keep
    /// the gains of the last completed pass: this one writes `K_next` and
    /// `d_next` and swaps them in only at the end.
    ///
    /// With `second` (DDP, [`Options::second_order`]), each knot's stage
    /// expansion gains the step's curvature weighted by the next knot's
    /// value gradient, `Σ_i V_x'[i]·∇²F_i`: the terms iLQR drops.
    #[allow(non_snake_case)]
    fn backward<D: DiscreteDynamics<NX, NU>>(
        &mut self,
        dynamics: &D,
        mu: f64,
        second: bool,
        interrupted: &impl Fn() -> Option<Status>,
    ) -> Result<Backward, Unfinished> {
        let n = self.us.len();
        // A constant of `D`'s, so the Riccati step is compiled for it.
        let sparsity: &'static Option<Sparsity<NX, NU>> = const { &D::SPARSITY };
        let second = second.then_some(dynamics);
        // Ping-pong between two value functions: knot k reads one and
        // writes the other.
        let mut next = Value {
            V_x: self.terminal.l_x,
            V_xx: self.terminal.l_xx,
        };
        let mut here = next;
        let (mut dv1, mut dv2) = (0.0, 0.0);
        for k in (0..n).rev() {
            if poll_due(n - 1 - k)
                && let Some(status) = interrupted()
            {
                return Err(Unfinished::Interrupted(status));
            }
            let curved;
            let stage = match second.and_then(|f| f.curvature(&self.xs[k], &self.us[k], &next.V_x))
            {
                Some(c) => {
                    let mut l = self.stage[k];
                    l.l_xx += c.xx;
                    l.l_ux += c.ux;
                    l.l_uu += c.uu;
                    curved = l;
                    &curved
                }
                None => &self.stage[k],
            };
            let (a, b) = riccati_step_into(
                &self.A[k],
                &self.B[k],
                stage,
                &next,
                mu,
                sparsity.as_ref(),
                &mut self.K_next[k],
                &mut self.d_next[k],
                &mut here,
            )
            .ok_or(Unfinished::NotPositiveDefinite)?;
            dv1 += a;
            dv2 += b;
            std::mem::swap(&mut next, &mut here);
        }
        std::mem::swap(&mut self.K, &mut self.K_next);
        std::mem::swap(&mut self.d, &mut self.d_next);
        Ok(Backward { dv1, dv2 })
    }

    /// Roll out `u = ū + α d + K (x − x̄)` into `xs_new`/`us_new`; returns the
    /// cost, or +∞ as soon as a state or the cost stops being finite, or how
    /// the solve must end if `interrupted` says so on one of its polls.
    fn forward<D, C>(
        &mut self,
        problem: &Problem<D, C, NX>,
        alpha: f64,
        interrupted: &impl Fn() -> Option<Status>,
    ) -> Result<f64, Status>
    where
        D: DiscreteDynamics<NX, NU>,
        C: Cost<NX, NU>,
    {
        let n = problem.horizon;
        self.xs_new[0] = problem.x0;
        let mut cost = 0.0;
        for k in 0..n {
            if poll_due(k)
                && let Some(status) = interrupted()
            {
                return Err(status);
            }
            let x = self.xs_new[k];
            let u = self.us[k] + self.d[k] * alpha + self.K[k] * (x - self.xs[k]);
            self.us_new[k] = u;
            cost += problem.cost.stage(k, &x, &u);
            let next = problem.dynamics.step(&x, &u);
            if !all_finite(&next) || !cost.is_finite() {
                return Ok(f64::INFINITY);
            }
            self.xs_new[k + 1] = next;
        }
        Ok(cost + problem.cost.terminal(&self.xs_new[n]))
    }

    fn feedforward_norm(&self, n: usize) -> f64 {
        let total: f64 = (0..n)
            .map(|k| {
                (0..NU)
                    .map(|i| self.d[k][i].abs() / (self.us[k][i].abs() + 1.0))
                    .fold(0.0, f64::max)
            })
            .sum();
        total / n as f64
    }
}

/// Roll `us` out from `xs[0]` into `xs`; returns the total cost (NaN or ∞
/// when the rollout diverges).
fn rollout<D, C, const NX: usize, const NU: usize>(
    problem: &Problem<D, C, NX>,
    xs: &mut [SVector<f64, NX>],
    us: &[SVector<f64, NU>],
) -> f64
where
    D: DiscreteDynamics<NX, NU>,
    C: Cost<NX, NU>,
{
    let mut cost = 0.0;
    for (k, u) in us.iter().enumerate() {
        cost += problem.cost.stage(k, &xs[k], u);
        xs[k + 1] = problem.dynamics.step(&xs[k], u);
    }
    cost + problem.cost.terminal(&xs[us.len()])
}

fn all_finite<const R: usize, const C: usize>(m: &SMatrix<f64, R, C>) -> bool {
    m.iter().all(|v| v.is_finite())
}

/// Which expansion of the cost the solve is using.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Model {
    /// The exact Hessian, from the start.
    Exact,
    /// The convex expansion ([`Cost::stage_expand_convex`]), after the exact
    /// one made no progress at any μ up to `mu_max`.
    Convex,
    /// The exact Hessian again, checking a minimum the convex expansion
    /// found.
    Checking,
}

/// μ has passed μ_max under `model` after `iterations`, `moved` telling
/// whether a step was accepted since the model was chosen. `Ok` switches
/// to the convex expansion ([`Options::convex_fallback`]), recording the
/// first switch in `convexified_after`, and the caller restarts μ:
///
/// * from the exact model;
/// * from the exact model checking a convex minimum, after it moved (it
///   found the minimum false and then got stuck in turn).
///
/// `Err(NoProgress)` ends the solve otherwise:
///
/// * the check could not move from the convex minimum at any μ. That is
///   no confirmation: `Q_uu` indefinite up to μ = 1e20 at a point of zero
///   gradient is a saddle's signature, and IPOPT lowered such a point 16×
///   (1 mg quadrotor, 10 s steps). Nor is a model step that no line search
///   accepts;
/// * the convex expansion is stuck too, the fallback is off, or the cost
///   has nothing to convexify (and the solve is not DDP, whose convex model
///   drops the dynamics' curvature too).
fn fall_back<D, C: Cost<NX, NU>, const NX: usize, const NU: usize>(
    problem: &Problem<D, C, NX>,
    options: &Options,
    (model, convexified_after): (&mut Model, &mut Option<usize>),
    (moved, iterations): (bool, usize),
) -> Result<(), Status> {
    // A cost with nothing to convexify would only repeat what just failed
    // (and report a fallback that changed nothing), except under DDP: the
    // convex model also drops the dynamics' curvature, which can make V_xx
    // indefinite where no μ on Q_uu helps (a review's obstacle-free
    // problems: DDP ended `NoProgress` at iteration 0 in 59 of 200 where
    // iLQR made progress).
    if *model == Model::Convex
        || (*model == Model::Checking && !moved)
        || !options.convex_fallback
        || !(problem.cost.has_convex_approximation() || options.second_order)
    {
        return Err(Status::NoProgress);
    }
    *model = Model::Convex;
    convexified_after.get_or_insert(iterations);
    Ok(())
}

/// Tassa's schedule: grow the multiplier Δ, then μ ← max(μ_min, μ·Δ).
fn increase(mu: &mut f64, delta: &mut f64, o: &Options) {
    *delta = (*delta * o.mu_factor).max(o.mu_factor);
    *mu = (*mu * *delta).max(o.mu_min);
}

/// Tassa's schedule: shrink Δ, then μ ← μ·Δ, snapping to 0 below μ_min.
fn decrease(mu: &mut f64, delta: &mut f64, o: &Options) {
    *delta = (*delta / o.mu_factor).min(1.0 / o.mu_factor);
    let next = *mu * *delta;
    *mu = if next > o.mu_min { next } else { 0.0 };
}

#[cfg(test)]
mod tests {
    //! The poll interval of each pass, which the integration tests (that
    //! only see the cost's calls) cannot count for the backward pass.
    use std::cell::Cell;

    use super::*;
    use crate::{Euler, Objective, Quadrotor2D, StateTracking, TerminalTracking};

    const N: usize = 10_000;

    /// A solver with a hover rollout of a plain tracking problem loaded.
    fn loaded() -> (
        Solver<6, 2>,
        Problem<Euler<Quadrotor2D>, Objective<6, 2>, 6>,
    ) {
        let model = Quadrotor2D {
            mass: 1.0,
            inertia: 1.0,
            arm_length: 1.0,
            gravity: 9.81,
        };
        let goal = SVector::from([1.0, 2.0, 0.0, 0.0, 0.0, 0.0]);
        let problem = Problem {
            dynamics: Euler { model, dt: 0.001 },
            cost: Objective::new()
                .with_stage(StateTracking {
                    goal,
                    weights: SVector::repeat(1.0),
                })
                .with_terminal(TerminalTracking {
                    goal,
                    weights: SVector::repeat(100.0),
                }),
            x0: SVector::zeros(),
            horizon: N,
        };
        let mut solver = Solver::new(N);
        solver.resize(N);
        solver.us[..N].fill(SVector::repeat(model.hover_thrust()));
        solver.xs[0] = problem.x0;
        rollout(&problem, &mut solver.xs, &solver.us);
        (solver, problem)
    }

    /// The backward pass without the dynamics' curvature (iLQR).
    const FIRST_ORDER: bool = false;

    /// A poll that counts its calls and interrupts from call `stop_at` on.
    fn poll(calls: &Cell<usize>, stop_at: usize) -> impl Fn() -> Option<Status> + '_ {
        move || {
            calls.set(calls.get() + 1);
            (calls.get() >= stop_at).then_some(Status::Cancelled)
        }
    }

    #[test]
    fn every_pass_polls_at_least_n_over_128_times() {
        let (mut solver, problem) = loaded();
        // The documented interval, not POLL_EVERY: raising that must fail.
        let at_least = N / 128;
        let calls = Cell::new(0);
        assert_eq!(
            solver.linearize::<false, _, _>(&problem, &poll(&calls, usize::MAX)),
            None
        );
        assert!(
            calls.get() >= at_least,
            "linearisation: {} polls",
            calls.get()
        );
        calls.set(0);
        // A large μ, so the pass completes.
        assert!(
            solver
                .backward(
                    &problem.dynamics,
                    1e6,
                    FIRST_ORDER,
                    &poll(&calls, usize::MAX)
                )
                .is_ok()
        );
        assert!(
            calls.get() >= at_least,
            "backward pass: {} polls",
            calls.get()
        );
        calls.set(0);
        assert!(
            solver
                .forward(&problem, 1.0, &poll(&calls, usize::MAX))
                .is_ok()
        );
        assert!(calls.get() >= at_least, "rollout: {} polls", calls.get());
    }

    #[test]
    fn an_interrupted_backward_pass_leaves_the_gains_it_had() {
        let (mut solver, problem) = loaded();
        let never = Cell::new(0);
        assert_eq!(
            solver.linearize::<false, _, _>(&problem, &poll(&never, usize::MAX)),
            None
        );
        assert!(
            solver
                .backward(
                    &problem.dynamics,
                    1e6,
                    FIRST_ORDER,
                    &poll(&never, usize::MAX)
                )
                .is_ok()
        );
        let (k, d) = (solver.K.clone(), solver.d.clone());
        // At μ = 1e3 the pass would give other gains; it stops at its
        // second poll, part-way through.
        let calls = Cell::new(0);
        assert!(matches!(
            solver.backward(&problem.dynamics, 1e3, FIRST_ORDER, &poll(&calls, 2)),
            Err(Unfinished::Interrupted(Status::Cancelled))
        ));
        assert_eq!(calls.get(), 2);
        assert!(solver.K == k && solver.d == d);
    }
}
