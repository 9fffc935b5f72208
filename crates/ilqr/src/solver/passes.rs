//! The three passes over the trajectory that one iteration makes: the
//! linearisation (step 1), the backward pass (step 2) and the rollouts of
//! the line search (step 4), each polling for an interruption every 128
//! knots; and the initial rollout.

use nalgebra::{SMatrix, SVector};

use super::riccati::{Boxed, riccati_step_into};
use super::state::Model;
use super::{Solver, Status, Value};
use crate::cost::{Cost, StageExpansion, TerminalExpansion};
use crate::dynamics::{DiscreteDynamics, Sparsity};

/// Knots between two polls of the cancellation flag and the time budget
/// inside a linearisation, backward pass or rollout. Each of those passes
/// costs N × (1 + obstacles) work, 20 ms at N = 10000 with 100 obstacles,
/// which is how late a solve that polled only between passes would
/// answer. 128 knots are at most about 0.3 ms of work (2 µs a knot with
/// 100 obstacles) and one poll (~25 ns) per 128 knots is lost in the
/// noise; passes over fewer knots (the seed's N = 100) are not polled
/// inside at all.
pub(super) const POLL_EVERY: usize = 128;

/// Whether a pass polls before its next knot, `done` knots into the pass
/// (the linearisation and rollouts count from k = 0, the backward pass from
/// k = N − 1): before every 128th knot.
#[inline(always)]
fn poll_due(done: usize) -> bool {
    (done + 1).is_multiple_of(POLL_EVERY)
}

/// Outcome of one backward pass.
pub(super) struct Backward {
    /// `Σ dᵀQ_u` and `Σ ½ dᵀQ_uu d`: ΔV(α) = −(α·dv1 + α²·dv2).
    pub(super) dv1: f64,
    pub(super) dv2: f64,
}

impl Backward {
    /// Whether the model predicts that a full step (α = 1) gains at most
    /// `tolerance·|cost|`.
    pub(super) fn negligible(&self, tolerance: f64, cost: f64) -> bool {
        -(self.dv1 + self.dv2) <= tolerance * cost.abs()
    }
}

/// Why a backward pass did not complete.
pub(super) enum Unfinished {
    /// `Q_uu + μI` is not positive definite at some knot: raise μ.
    NotPositiveDefinite,
    /// The solve was cancelled or ran out of time during the pass.
    Interrupted(Status),
}

impl<const NX: usize, const NU: usize> Solver<NX, NU> {
    /// Step 1: fill `A`, `B` and the cost expansions along `(xs, us)`, with
    /// the expansion `model` names. Returns how the solve must end if
    /// `interrupted` says so on one of its polls; the derivatives are then
    /// half updated.
    pub(super) fn linearize<D, C>(
        &mut self,
        dynamics: &D,
        cost: &C,
        model: Model,
        interrupted: &impl Fn() -> Option<Status>,
    ) -> Option<Status>
    where
        D: DiscreteDynamics<NX, NU>,
        C: Cost<NX, NU>,
    {
        // One copy of the loop per expansion, each without a branch per knot.
        if model == Model::Convex {
            self.expand::<true, _, _>(dynamics, cost, interrupted)
        } else {
            self.expand::<false, _, _>(dynamics, cost, interrupted)
        }
    }

    fn expand<const CONVEX: bool, D, C>(
        &mut self,
        dynamics: &D,
        cost: &C,
        interrupted: &impl Fn() -> Option<Status>,
    ) -> Option<Status>
    where
        D: DiscreteDynamics<NX, NU>,
        C: Cost<NX, NU>,
    {
        let n = self.us.len();
        for k in 0..n {
            if poll_due(k)
                && let Some(status) = interrupted()
            {
                return Some(status);
            }
            let (x, u) = (&self.xs[k], &self.us[k]);
            (self.A[k], self.B[k]) = dynamics.linearize(x, u);
            let e = &mut self.stage[k];
            *e = StageExpansion::zeros();
            if CONVEX {
                cost.stage_expand_convex(k, x, u, e);
            } else {
                cost.stage_expand(k, x, u, e);
            }
        }
        self.terminal = TerminalExpansion::zeros();
        cost.terminal_expand(&self.xs[n], &mut self.terminal);
        None
    }

    /// Step 2 at one μ: eqs. 31–48 with `Q_uu + μI`, knot by knot from
    /// `N − 1` down to 0. Fails when `Q_uu + μI` is not positive definite
    /// at some knot, or when `interrupted` says so on one of its polls.
    /// Either way `K` and `d` keep the gains of the last completed pass:
    /// this one writes `K_next` and `d_next` and swaps them in only at the
    /// end.
    ///
    /// With `second` (DDP, [`Options::second_order`]), each knot's stage
    /// expansion gains the step's curvature weighted by the next knot's
    /// value gradient, `Σ_i V_x'[i]·∇²F_i`: the terms iLQR drops.
    ///
    /// [`Options::second_order`]: super::Options::second_order
    #[allow(non_snake_case)]
    pub(super) fn backward<D: DiscreteDynamics<NX, NU>>(
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
            // Control bounds: the step is bounded so that ū + d stays in
            // them, starting from the last pass's step.
            let boxed = self.bounds.map(|b| Boxed {
                lower: b.lower - self.us[k],
                upper: b.upper - self.us[k],
                start: self.d[k],
            });
            let (a, b) = riccati_step_into(
                &self.A[k],
                &self.B[k],
                stage,
                &next,
                mu,
                sparsity.as_ref(),
                boxed.as_ref(),
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

    /// Step 4 at one step size: roll out `u = ū + α d + K (x − x̄)` from
    /// `x̄_0` into `xs_new`/`us_new`; returns the cost, or +∞ as soon as a
    /// state or the cost stops being finite, or how the solve must end if
    /// `interrupted` says so on one of its polls.
    pub(super) fn forward<D, C>(
        &mut self,
        dynamics: &D,
        cost: &C,
        alpha: f64,
        interrupted: &impl Fn() -> Option<Status>,
    ) -> Result<f64, Status>
    where
        D: DiscreteDynamics<NX, NU>,
        C: Cost<NX, NU>,
    {
        let n = self.us.len();
        self.xs_new[0] = self.xs[0];
        let mut total = 0.0;
        for k in 0..n {
            if poll_due(k)
                && let Some(status) = interrupted()
            {
                return Err(status);
            }
            let x = self.xs_new[k];
            let mut u = self.us[k] + self.d[k] * alpha + self.K[k] * (x - self.xs[k]);
            if let Some(b) = &self.bounds {
                u = b.clamp(&u);
            }
            self.us_new[k] = u;
            total += cost.stage(k, &x, &u);
            let next = dynamics.step(&x, &u);
            if !all_finite(&next) || !total.is_finite() {
                return Ok(f64::INFINITY);
            }
            self.xs_new[k + 1] = next;
        }
        Ok(total + cost.terminal(&self.xs_new[n]))
    }

    /// The trace's [`TraceRow::feedforward_norm`]: the mean over knots of
    /// `max_i |d_i| / (|ū_i| + 1)`.
    ///
    /// [`TraceRow::feedforward_norm`]: super::TraceRow::feedforward_norm
    pub(super) fn feedforward_norm(&self) -> f64 {
        let n = self.us.len();
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
pub(super) fn rollout<D, C, const NX: usize, const NU: usize>(
    dynamics: &D,
    cost: &C,
    xs: &mut [SVector<f64, NX>],
    us: &[SVector<f64, NU>],
) -> f64
where
    D: DiscreteDynamics<NX, NU>,
    C: Cost<NX, NU>,
{
    // Never interrupted.
    polled_rollout(dynamics, cost, xs, us, &|| None).unwrap_or(f64::NAN)
}

/// [`rollout`], polling `interrupted` every 128 knots: on a stop, how the
/// solve must end, with `xs` rolled out only part of the way (the states
/// of the same controls from the same start: unchanged where they were
/// already their rollout).
pub(super) fn polled_rollout<D, C, const NX: usize, const NU: usize>(
    dynamics: &D,
    cost: &C,
    xs: &mut [SVector<f64, NX>],
    us: &[SVector<f64, NU>],
    interrupted: &impl Fn() -> Option<Status>,
) -> Result<f64, Status>
where
    D: DiscreteDynamics<NX, NU>,
    C: Cost<NX, NU>,
{
    let mut total = 0.0;
    for (k, u) in us.iter().enumerate() {
        if poll_due(k)
            && let Some(status) = interrupted()
        {
            return Err(status);
        }
        total += cost.stage(k, &xs[k], u);
        xs[k + 1] = dynamics.step(&xs[k], u);
    }
    Ok(total + cost.terminal(&xs[us.len()]))
}

pub(super) fn all_finite<const R: usize, const C: usize>(m: &SMatrix<f64, R, C>) -> bool {
    m.iter().all(|v| v.is_finite())
}

#[cfg(test)]
mod tests {
    //! The poll interval of each pass, which the integration tests (that
    //! only see the cost's calls) cannot count for the backward pass.
    use std::cell::Cell;

    use super::*;
    use crate::{Euler, Objective, Problem, Quadrotor2D, StateTracking, TerminalTracking};

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
        rollout(&problem.dynamics, &problem.cost, &mut solver.xs, &solver.us);
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
            solver.linearize(
                &problem.dynamics,
                &problem.cost,
                Model::Exact,
                &poll(&calls, usize::MAX)
            ),
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
                .forward(
                    &problem.dynamics,
                    &problem.cost,
                    1.0,
                    &poll(&calls, usize::MAX)
                )
                .is_ok()
        );
        assert!(calls.get() >= at_least, "rollout: {} polls", calls.get());
    }

    #[test]
    fn an_interrupted_backward_pass_leaves_the_gains_it_had() {
        let (mut solver, problem) = loaded();
        let never = Cell::new(0);
        assert_eq!(
            solver.linearize(
                &problem.dynamics,
                &problem.cost,
                Model::Exact,
                &poll(&never, usize::MAX)
            ),
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
