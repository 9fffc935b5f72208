//! [`Solver::solve_constrained`]: the augmented-Lagrangian outer loop
//! (ALTRO's) around the iLQR loop, with control bounds met by the
//! backward pass itself (box-DDP).
//!
//! Each outer iteration runs the iLQR loop, warm, on the base cost plus
//! the penalty terms of `augmented` at the current multipliers `λ` and
//! penalty ρ; then, unless the constraints hold to
//! [`Options::constraint_tolerance`] at a tight inner solve, it updates
//! `λ` and multiplies ρ by [`Options::penalty_scaling`] up to
//! [`Options::penalty_max`]. The solve ends:
//!
//! * `Converged`: an inner solve converged at [`Options::tolerance`] with
//!   the violation under the tolerance. Inner solves before the violation
//!   first gets there use the looser [`Options::intermediate_tolerance`];
//! * `Infeasible`: at the largest penalty the violation fell by less than
//!   1% over an outer iteration, or the outer iterations ran out, with the
//!   violation above the tolerance. The least violating iterate found is
//!   returned;
//! * `MaxIterations`, `TimeLimit`, `Cancelled`: as for an unconstrained
//!   solve, counted over all the inner solves together; also
//!   `MaxIterations` where the outer iterations ran out with the
//!   constraints met but the last inner solve cut short by its own cap of
//!   30 iterations;
//! * `NoProgress`: an inner solve at the tight tolerance made no progress
//!   where the violation is already under the tolerance.
//!
//! The returned cost is the base cost, without penalties.

use std::cell::Cell;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use nalgebra::SVector;

use super::augmented::Worst;
use super::passes::{polled_rollout, rollout};
use super::state::LoopState;
use super::{Augmented, Clock, Options, Problem, SolveError, Solver, Status, Summary, TraceRow};
use crate::constraint::Constraints;
use crate::cost::Cost;
use crate::dynamics::DiscreteDynamics;

/// The violation must fall by at least this fraction per outer iteration at
/// the largest penalties, or the outer iteration counts as stalled.
const STALL: f64 = 0.01;

/// Stalled outer iterations in a row that end the solve.
const STALL_ROUNDS: usize = 3;

/// A violation stalled above this many times the tolerance, with every
/// penalty at its cap, is evidence that the constraints cannot be met
/// from here (`Infeasible`); one stalled below it only shows a stuck
/// solver (`NoProgress`): a few times the tolerance, still moving, is not
/// evidence of anything.
const EVIDENCE: f64 = 10.0;

/// The largest violation the projection starts from; below it the inner
/// solves are tight.
const PROJECT_BELOW: f64 = 1e-4;

/// The most Gauss–Newton steps of the final projection.
const PROJECTION_STEPS: usize = 8;

/// The most entries of the projection's dense constraint Jacobian (rows ×
/// N·NU): 16 MB. Beyond it the solve goes without the projection.
const PROJECTION_ENTRIES: usize = 2_000_000;

/// The most multiplications of the projection's `GGᵀ` (rows² × N·NU):
/// about 0.1 s. Beyond it the solve goes without the projection.
const PROJECTION_PRODUCTS: usize = 200_000_000;

/// Rows of the projection's system between two polls of the budget.
const PROJECTION_POLL_ROWS: usize = 16;

/// How a projection ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Projection {
    /// The violation is under the tolerance.
    Feasible,
    /// It lowered the violation but not under the tolerance: the
    /// trajectory moved, and the gains are about the one before.
    Moved,
    /// Nothing changed.
    Unchanged,
}

/// Rollouts of time kept back from the budget for the solve's wrap-up
/// after its loop: the base cost's rollout and a pass over the
/// constraints.
const WRAP_UP_ROLLOUTS: f64 = 2.0;

/// The most iterations of one inner solve: one that needs more goes on
/// as the next outer iteration, at updated multipliers. An infeasible
/// problem's inner solves at large penalties otherwise crawl for a
/// hundred iterations each.
const INNER_ITERATIONS: usize = 30;

/// The least regularisation an inner solve starts from.
const MU_FLOOR: f64 = 1e-2;

/// An outer iteration whose violation is at most this fraction of the last
/// one's keeps the penalty: its multipliers are doing the work (the
/// classic rule of augmented-Lagrangian methods, Nocedal & Wright §17.4).
const SUFFICIENT: f64 = 0.25;

/// Whether every component still violated (beyond `tolerance`) has its
/// penalty at `max`.
fn at_cap(rho: &[f64], violations: &[f64], tolerance: f64, max: f64) -> bool {
    rho.iter()
        .zip(violations)
        .all(|(&rho, &v)| v <= tolerance || rho >= max)
}

impl<const NX: usize, const NU: usize> Solver<NX, NU> {
    /// Solve `problem` subject to `constraints` (see the
    /// [module documentation](self)). Control bounds hold exactly in the
    /// returned controls (the initial ones are clamped into them first),
    /// and the returned states are their rollout. Without any constraint
    /// this is [`Solver::solve_observed`].
    pub fn solve_constrained<D, C>(
        &mut self,
        problem: &Problem<D, C, NX>,
        constraints: &Constraints<NX, NU>,
        u_init: &[SVector<f64, NU>],
        options: &Options,
        cancel: &AtomicBool,
        observe: &mut impl FnMut(&TraceRow),
    ) -> Result<Summary, SolveError>
    where
        D: DiscreteDynamics<NX, NU>,
        C: Cost<NX, NU>,
    {
        if constraints.is_empty() {
            return self.solve_observed(problem, u_init, options, cancel, observe);
        }
        if let Some(b) = &constraints.control
            && let Some(index) = (0..NU).find(|&i| {
                let (lo, hi) = (b.lower[i], b.upper[i]);
                !(lo <= hi && lo < f64::INFINITY && hi > f64::NEG_INFINITY)
            })
        {
            return Err(SolveError::InvalidControlBounds { index });
        }
        let start = Instant::now();
        let n = problem.horizon;
        let m = constraints.components();
        self.bounds = constraints.control;
        let clock = Clock::new(start, WRAP_UP_ROLLOUTS, options);
        let initial_cost = self.prepare(problem, &problem.cost, u_init, options, &clock)?;
        // The rest of what the outer loop needs, before it.
        for v in [&mut self.lambda, &mut self.lambda_next] {
            v.clear();
            v.resize((n + 1) * m, 0.0);
        }
        // A component the initial guess meets everywhere starts at a
        // stiffer penalty than one it violates: see `penalty_feasible`.
        let mut offsets = Vec::with_capacity(constraints.other.len());
        let mut at = 0;
        for c in &constraints.other {
            offsets.push(at);
            at += c.dim();
        }
        self.violations.clear();
        self.violations.resize(m, 0.0);
        constraints.for_each_value(&self.xs, &self.us, |j, i, _, value, equality| {
            let v = &mut self.violations[offsets[j] + i];
            *v = v.max(crate::constraint::violation(value, equality));
        });
        self.rho.clear();
        self.rho.extend(self.violations.iter().map(|&v| {
            if v == 0.0 {
                options.penalty_feasible.max(options.penalty_initial)
            } else {
                options.penalty_initial
            }
        }));

        self.best_xs.clone_from(&self.xs);
        self.best_us.clone_from(&self.us);
        self.best_K.clone_from(&self.K);
        self.best_d.clone_from(&self.d);
        let loose = options.tolerance.max(options.intermediate_tolerance);
        let tolerance = options.constraint_tolerance;

        let interrupted = super::interruption(cancel, options, &clock);
        let dynamics = &problem.dynamics;
        // Control bounds alone need no outer loop: one tight solve.
        let mut tight = m == 0;
        let mut outer = 0;
        let mut iterations = 0;
        let mut carried_mu: Option<f64> = None;
        let mut previous = f64::INFINITY;
        let mut best = (f64::INFINITY, 0usize);
        let mut stuck = 0;
        // The gains in the workspace, carried from one inner solve to the
        // next: about the same trajectory, until a step moves it.
        let mut gains = None;
        let mut last_summary;
        let status = loop {
            outer += 1;
            let lambda = std::mem::take(&mut self.lambda);
            let rho = std::mem::take(&mut self.rho);
            let rho_max = rho.iter().copied().fold(0.0, f64::max);
            let augmented = Augmented {
                base: &problem.cost,
                constraints,
                lambda: &lambda,
                m,
                n,
                rho: &rho,
                worst: Worst::default(),
            };
            // The iterate's cost under this outer iteration's multipliers
            // (it evaluates every constraint, so it is timed for the
            // budget's reserve), and its violation.
            let began = Instant::now();
            let mut xs = std::mem::take(&mut self.xs);
            let rolled = polled_rollout(dynamics, &augmented, &mut xs, &self.us[..n], &interrupted);
            self.xs = xs;
            let mut state = LoopState::new(options, *rolled.as_ref().unwrap_or(&f64::NAN));
            state.iterations = iterations;
            if let Some(gains) = gains {
                state.gains = gains;
            }
            if let Err(status) = rolled {
                last_summary = state.summary(status, start.elapsed());
                self.lambda = lambda;
                self.rho = rho;
                break status;
            }
            clock.rolled_out(began);
            let nominal = Cell::new(augmented.worst.get());
            if let Some(mu) = carried_mu {
                state.mu = mu;
            }
            state.tolerance = if tight { options.tolerance } else { loose };
            // With the penalties added, the caller's lower bound on the
            // cost is not the inner problems': they converge by the
            // gradient test alone.
            state.cost_lower_bound = None;
            // Control bounds alone need no outer loop: no cap there.
            if m > 0 {
                state.max_iterations = options
                    .max_iterations
                    .min(iterations.saturating_add(INNER_ITERATIONS));
            }
            let annotate = |_: &Self, row: &mut TraceRow| {
                row.outer_iteration = outer;
                row.penalty = rho_max;
                // An accepted step's rollout was the line search's last.
                if row.step_size > 0.0 {
                    nominal.set(augmented.worst.get());
                }
                row.constraint_violation = nominal.get();
            };
            let inner = self.iterate(
                dynamics,
                &augmented,
                options,
                &mut state,
                (&clock, &interrupted),
                (&mut *observe, &annotate),
            );
            iterations = state.iterations;
            gains = Some(state.gains);
            carried_mu = Some(state.mu.clamp(MU_FLOOR, options.mu_init.max(MU_FLOOR)));
            // The nominal trajectory's, as its last accepted rollout found
            // it: a pass over the constraints of its own would cost as
            // much as a rollout.
            let violation = nominal.get();
            if violation < best.0 {
                best = (violation, outer);
                self.best_xs.copy_from_slice(&self.xs);
                self.best_us.copy_from_slice(&self.us);
                self.best_K.copy_from_slice(&self.K);
                self.best_d.copy_from_slice(&self.d);
            }
            let feasible = violation <= tolerance;
            let near = violation <= PROJECT_BELOW;
            // The multipliers no longer shrink the violation: what is left
            // is the inner problems' stiffness, not the multipliers' error.
            let stalled = violation > SUFFICIENT * previous;
            // Outer iterations in a row at the largest penalties without the
            // violation falling by `STALL`.
            if at_cap(&rho, &self.violations, tolerance, options.penalty_max)
                && violation > (1.0 - STALL) * previous
            {
                stuck += 1;
            } else {
                stuck = 0;
            }
            // An inner solve cut short by its own cap goes on as the next
            // outer iteration; the caller's cap ends the solve.
            let spent = iterations >= options.max_iterations;
            let stop = match inner {
                Status::TimeLimit | Status::Cancelled => Some(inner),
                Status::MaxIterations if spent => Some(inner),
                Status::Converged if feasible && tight => Some(Status::Converged),
                Status::NoProgress if feasible && tight => Some(Status::NoProgress),
                // A tight inner solve came close and the multiplier update
                // stopped helping: the multipliers are about right, and the
                // projection closes the last gap at a cost change of about
                // λ·violation, where more outer iterations would stiffen
                // the inner problems past what their line searches resolve.
                Status::Converged | Status::NoProgress if tight && near && stalled => self
                    .settle_by_projection(
                        dynamics,
                        constraints,
                        &augmented,
                        options,
                        &mut state,
                        &interrupted,
                    )
                    .then_some(Status::Converged),
                _ if outer >= options.max_outer_iterations || stuck >= STALL_ROUNDS => {
                    // The outer loop can do no more. Where it came close,
                    // the projection may finish the job: the result is
                    // `Converged` after an inner solve that settled, and
                    // feasible but unproven (`MaxIterations`) after one cut
                    // short by its cap.
                    let settled = matches!(inner, Status::Converged | Status::NoProgress);
                    if near
                        && self.settle_by_projection(
                            dynamics,
                            constraints,
                            &augmented,
                            options,
                            &mut state,
                            &interrupted,
                        )
                    {
                        Some(if settled {
                            Status::Converged
                        } else {
                            Status::MaxIterations
                        })
                    } else if constraints.violation(&self.xs, &self.us) <= tolerance {
                        Some(Status::MaxIterations)
                    } else if stuck >= STALL_ROUNDS && violation > EVIDENCE * tolerance {
                        // Evidence: the violation stalled well above the
                        // tolerance for several outer iterations with every
                        // penalty at its cap.
                        Some(Status::Infeasible)
                    } else if stuck >= STALL_ROUNDS {
                        // Stalled just above the tolerance: the solver is
                        // stuck, which is no evidence against the problem.
                        Some(Status::NoProgress)
                    } else {
                        // The outer iterations ran out, the violation still
                        // falling.
                        Some(Status::MaxIterations)
                    }
                }
                _ => None,
            };
            if let Some(status) = stop {
                self.least_regularized_gains(
                    dynamics,
                    &augmented,
                    options,
                    status,
                    &mut state,
                    &interrupted,
                );
                last_summary = state.summary(status, start.elapsed());
                self.lambda = lambda;
                self.rho = rho;
                break status;
            }
            if near || feasible {
                // Close to feasible: solve tightly from here on, so that a
                // projection starts from an accurate minimum.
                tight = true;
            }
            augmented.update(
                &self.xs,
                &self.us,
                &mut self.lambda_next,
                &mut self.violations,
            );
            self.rho = rho;
            if !feasible && stalled {
                // The multipliers alone did not shrink the violation
                // enough: the penalties grow. Growing them every outer
                // iteration instead (ALTRO's default) conditions the inner
                // problems so badly at 1e6 and beyond that their line
                // searches fail (the Dubins car stalls at 1.2e-5).
                for rho in &mut self.rho {
                    *rho = (*rho * options.penalty_scaling).min(options.penalty_max);
                }
            }
            previous = violation;
            self.lambda = lambda;
            std::mem::swap(&mut self.lambda, &mut self.lambda_next);
        };
        // (Not after a stop on the clock: a pass over the constraints costs
        // as much as a rollout, and the best so far is the latest then.)
        if !matches!(status, Status::TimeLimit | Status::Cancelled)
            && best.1 != outer
            && constraints.violation(&self.xs, &self.us) > tolerance
        {
            // An earlier outer iteration violated the constraints least.
            self.xs.copy_from_slice(&self.best_xs);
            self.us.copy_from_slice(&self.best_us);
            self.K.copy_from_slice(&self.best_K);
            self.d.copy_from_slice(&self.best_d);
        }
        let mut xs = std::mem::take(&mut self.xs);
        last_summary.cost = rollout(dynamics, &problem.cost, &mut xs, &self.us[..n]);
        self.xs = xs;
        last_summary.initial_cost = initial_cost;
        last_summary.constraint_violation = constraints.violation(&self.xs, &self.us);
        last_summary.outer_iterations = outer;
        last_summary.solve_time = start.elapsed();
        Ok(last_summary)
    }

    /// The final projection: Gauss–Newton steps that move the controls by
    /// the least amount (in the 2-norm) that zeroes the linearised
    /// near-active constraints (`c > −tolerance`, and every equality), the
    /// states following through the linearised dynamics, with the
    /// controls at a bound held there. Each step is rolled out through the
    /// nonlinear dynamics and kept where it lowers the violation (halved up
    /// to 4 times otherwise). Whether the violation ends under
    /// `tolerance`.
    ///
    /// It runs where the augmented Lagrangian has come within
    /// [`PROJECT_BELOW`] and its multiplier updates stopped shrinking the
    /// violation, or the outer loop can do no more: its inner problems are
    /// then too stiff (the penalty at 1e6 and more) for their line searches
    /// to gain the last digits. It polls `interrupted` between steps, skips
    /// a system of more than [`PROJECTION_ENTRIES`] entries, and allocates
    /// (its system's size depends on the active set); the iteration loops
    /// do not.
    #[allow(non_snake_case)]
    fn project<D: DiscreteDynamics<NX, NU>>(
        &mut self,
        dynamics: &D,
        constraints: &Constraints<NX, NU>,
        tolerance: f64,
        interrupted: &impl Fn() -> Option<Status>,
    ) -> Projection {
        use nalgebra::{DMatrix, DVector};
        let n = self.us.len();
        let mut violation = constraints.violation(&self.xs, &self.us);
        let mut moved = false;
        'steps: for _ in 0..PROJECTION_STEPS {
            if violation <= 0.1 * tolerance || interrupted().is_some() {
                break;
            }
            for k in 0..n {
                (self.A[k], self.B[k]) = dynamics.linearize(&self.xs[k], &self.us[k]);
            }
            // The rows: each near-active component's value and gradients.
            let mut rows = Vec::new();
            for c in &constraints.other {
                for k in 0..=n {
                    let (knot, u) = if k < n {
                        (crate::constraint::Knot::Stage(k), self.us[k])
                    } else {
                        (crate::constraint::Knot::Terminal, SVector::zeros())
                    };
                    if !c.applies(knot) {
                        continue;
                    }
                    for i in 0..c.dim() {
                        let (value, c_x, c_u) = c.linearize(i, &self.xs[k], &u);
                        if c.is_equality(i) || value > -tolerance {
                            rows.push((k, value, c_x, c_u));
                        }
                    }
                }
            }
            // Its system is dense: rows × N·NU entries, and rows² × N·NU
            // multiplications to form GGᵀ.
            let entries = rows.len() * n * NU;
            if rows.is_empty()
                || entries > PROJECTION_ENTRIES
                || entries.saturating_mul(rows.len()) > PROJECTION_PRODUCTS
            {
                break;
            }
            // A control at a bound stays there: its columns are zero.
            let held = |k: usize, j: usize| {
                self.bounds.is_some_and(|b| {
                    let u = self.us[k][j];
                    u <= b.lower[j] || u >= b.upper[j]
                })
            };
            let mut G = DMatrix::<f64>::zeros(rows.len(), n * NU);
            let mut c = DVector::<f64>::zeros(rows.len());
            for (r, (k, value, c_x, c_u)) in rows.iter().enumerate() {
                // Each row sweeps back over up to N knots.
                if r % PROJECTION_POLL_ROWS == 0 && interrupted().is_some() {
                    break 'steps;
                }
                c[r] = *value;
                if *k < n {
                    for j in 0..NU {
                        G[(r, k * NU + j)] = c_u[j];
                    }
                }
                // ∂c/∂u_i = c_x Φ(k, i + 1) B_i for i < k, by a sweep back.
                let mut w = *c_x;
                for i in (0..*k).rev() {
                    let g = self.B[i].transpose() * w;
                    for j in 0..NU {
                        G[(r, i * NU + j)] = g[j];
                    }
                    w = self.A[i].transpose() * w;
                }
                for i in 0..n {
                    for j in 0..NU {
                        if held(i, j) {
                            G[(r, i * NU + j)] = 0.0;
                        }
                    }
                }
            }
            // δu = −Gᵀ(GGᵀ)⁻¹c, the least-norm step, lightly regularised
            // for rows that coincide (the same bound at both ends of a
            // step).
            let mut GGt = DMatrix::<f64>::zeros(rows.len(), rows.len());
            for r0 in (0..rows.len()).step_by(PROJECTION_POLL_ROWS) {
                if interrupted().is_some() {
                    break 'steps;
                }
                let len = PROJECTION_POLL_ROWS.min(rows.len() - r0);
                GGt.rows_mut(r0, len)
                    .copy_from(&(G.rows(r0, len) * G.transpose()));
            }
            for r in 0..rows.len() {
                GGt[(r, r)] += 1e-12 * (1.0 + GGt[(r, r)]);
            }
            let Some(chol) = GGt.cholesky() else {
                break;
            };
            let step = -(G.transpose() * chol.solve(&c));
            let mut improved = false;
            let mut alpha = 1.0;
            for _ in 0..5 {
                self.xs_new[0] = self.xs[0];
                for k in 0..n {
                    let mut u = self.us[k];
                    for j in 0..NU {
                        u[j] += alpha * step[k * NU + j];
                    }
                    if let Some(b) = &self.bounds {
                        u = b.clamp(&u);
                    }
                    self.us_new[k] = u;
                    self.xs_new[k + 1] = dynamics.step(&self.xs_new[k], &u);
                }
                let v = constraints.violation(&self.xs_new, &self.us_new);
                if v < violation {
                    std::mem::swap(&mut self.xs, &mut self.xs_new);
                    std::mem::swap(&mut self.us, &mut self.us_new);
                    violation = v;
                    improved = true;
                    moved = true;
                    break;
                }
                alpha *= 0.5;
            }
            if !improved {
                break;
            }
        }
        if violation <= tolerance {
            Projection::Feasible
        } else if moved {
            Projection::Moved
        } else {
            Projection::Unchanged
        }
    }

    /// [`Solver::project`], then the gains it leaves: a backward pass about
    /// the projected trajectory where it reached the tolerance (whether
    /// it did), the gains flagged as about the previous iterate where it
    /// moved without reaching it.
    fn settle_by_projection<D, C>(
        &mut self,
        dynamics: &D,
        constraints: &Constraints<NX, NU>,
        cost: &C,
        options: &Options,
        state: &mut LoopState,
        interrupted: &impl Fn() -> Option<Status>,
    ) -> bool
    where
        D: DiscreteDynamics<NX, NU>,
        C: Cost<NX, NU>,
    {
        match self.project(
            dynamics,
            constraints,
            options.constraint_tolerance,
            interrupted,
        ) {
            Projection::Feasible => {
                self.gains_after_projection(dynamics, cost, options, state);
                true
            }
            Projection::Moved => {
                state.gains.current = false;
                false
            }
            Projection::Unchanged => false,
        }
    }

    /// The gains about the projected trajectory: a backward pass of the
    /// augmented Lagrangian's model there, at μ = 0 where `Q_uu` allows,
    /// else at the loop's μ. Where neither completes, the gains stay those
    /// of the trajectory before the projection (within the tolerance of
    /// it), and the summary says they are about the previous iterate.
    fn gains_after_projection<D, C>(
        &mut self,
        dynamics: &D,
        cost: &C,
        options: &Options,
        state: &mut LoopState,
    ) where
        D: DiscreteDynamics<NX, NU>,
        C: Cost<NX, NU>,
    {
        let never = || None;
        let model = super::state::Model::Exact;
        if self.linearize(dynamics, cost, model, &never).is_some() {
            return;
        }
        let second = model.second_order(options);
        for mu in [0.0, state.mu.max(options.mu_min)] {
            if self.backward(dynamics, mu, second, &never).is_ok() {
                state.gains.current = true;
                state.gains.mu = mu;
                return;
            }
        }
        state.gains.current = false;
    }
}
