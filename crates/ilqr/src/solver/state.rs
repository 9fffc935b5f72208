//! [`LoopState`]: what the iteration carries from one pass to the next, and
//! its transitions: μ's schedule, a pass completed, a step accepted or
//! rejected, a change of the cost's model. Each moves several fields at
//! once and is written once, here; the loop sets single flags itself.

use super::{Options, Status, Summary};
use crate::cost::Cost;

/// Which expansion of the cost the passes use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Model {
    /// The exact Hessian, from the start.
    Exact,
    /// The convex expansion ([`Cost::stage_expand_convex`]), after the exact
    /// one made no progress at any μ up to `mu_max`.
    Convex,
    /// The exact Hessian again, checking a minimum the convex expansion
    /// found.
    Checking,
}

impl Model {
    /// Whether the backward pass keeps the dynamics' curvature: with
    /// [`Options::second_order`], except under the convex model, which keeps
    /// only the curvature that cannot be negative.
    pub(super) fn second_order(self, options: &Options) -> bool {
        options.second_order && self != Model::Convex
    }
}

/// Which gains the workspace's `K` and `d` hold.
#[derive(Debug, Clone, Copy)]
pub(super) struct Gains {
    /// A backward pass has completed in this solve; before that `K` and `d`
    /// are zero.
    pub(super) exist: bool,
    /// They are about the nominal trajectory: no step has been accepted
    /// since the pass that made them.
    pub(super) current: bool,
    /// The μ of that pass.
    pub(super) mu: f64,
    /// That pass used the convex expansion.
    pub(super) convex: bool,
}

/// The state of the iteration between passes: the nominal trajectory's
/// cost (the trajectory itself is in the [`Solver`](super::Solver)'s
/// workspace), the regularisation and the cost's model in use, what the
/// passes have found out about the current iterate, and which gains the
/// workspace holds.
///
/// Plain data on the stack, so a solve that runs the loop several times
/// (an outer loop around it) allocates nothing for it.
#[derive(Debug, Clone)]
pub(super) struct LoopState {
    /// Regularisation μ: the backward pass factorises `Q_uu + μI`.
    pub(super) mu: f64,
    /// The factor Δ of Tassa's schedule for μ.
    delta: f64,
    /// The expansion of the cost in use.
    pub(super) model: Model,
    /// Iterations completed: forward passes attempted.
    pub(super) iterations: usize,
    /// Cost of the nominal trajectory.
    pub(super) cost: f64,
    /// Cost of the initial rollout.
    pub(super) initial_cost: f64,
    /// Whether the derivatives along the nominal trajectory must be
    /// computed again: a step was accepted, or the model changed. After a
    /// rejected step the same ones are reused with a larger μ.
    pub(super) stale: bool,
    /// The last accepted step was a full one (α = 1) at μ ≤
    /// `mu_converged_max` and gained less than `tolerance·|J|`: convergence,
    /// if the model about the new iterate agrees.
    pub(super) small_full_step: bool,
    /// A step was accepted since the model last changed. The convex
    /// expansion cannot tell a minimum from a maximum or a saddle (the
    /// curvature that would is what it drops): where it finds nothing to
    /// do at once, the exact model had found no descent either (an
    /// obstacle's centre held by the guess), and calling that point
    /// converged would be false.
    pub(super) moved: bool,
    /// The convex model's step was tried where it predicted nothing worth
    /// taking (see the termination check, step 3); at most
    /// once per model.
    pub(super) convex_step_tried: bool,
    /// A pass at μ = 0 failed at the current iterate (`Q_uu` not positive
    /// definite there, or its step rejected): the derivatives are the same
    /// until a step is accepted, so it would fail again.
    pub(super) probe_failed: bool,
    /// The μ of the first backward pass that completed at the current
    /// iterate and model, or 0 once a pass at μ = 0 has: the least
    /// regularised gains about it, since μ only grows between accepted
    /// steps.
    pub(super) least_mu: Option<f64>,
    /// The μ that this iteration's pass at μ = 0 replaced, if it ran:
    /// restored, then raised, if its step is rejected.
    pub(super) probe_replaced: Option<f64>,
    /// Which gains the workspace holds.
    pub(super) gains: Gains,
    /// Iterations completed when the convex model was first switched to.
    pub(super) convexified_after: Option<usize>,
    /// The convergence tolerance in force: [`Options::tolerance`], or a
    /// constrained solve's looser one for its intermediate inner solves.
    pub(super) tolerance: f64,
    /// The cost's lower bound in force ([`Options::cost_lower_bound`];
    /// none for an augmented Lagrangian's inner solves).
    pub(super) cost_lower_bound: Option<f64>,
    /// The iteration count at which the loop stops `MaxIterations`:
    /// [`Options::max_iterations`], or sooner for an inner solve of an
    /// augmented Lagrangian.
    pub(super) max_iterations: usize,
}

impl LoopState {
    /// The state before the first iteration, at the initial rollout's
    /// `cost`.
    pub(super) fn new(options: &Options, cost: f64) -> Self {
        Self {
            mu: options.mu_init,
            delta: 1.0,
            model: Model::Exact,
            iterations: 0,
            cost,
            initial_cost: cost,
            stale: true,
            small_full_step: false,
            moved: false,
            convex_step_tried: false,
            probe_failed: false,
            least_mu: None,
            probe_replaced: None,
            gains: Gains {
                exist: false,
                current: false,
                mu: 0.0,
                convex: false,
            },
            convexified_after: None,
            tolerance: options.tolerance,
            cost_lower_bound: options.cost_lower_bound,
            max_iterations: options.max_iterations,
        }
    }

    /// The derivatives along the nominal trajectory are up to date: what
    /// was known of the passes at the previous iterate (or model) no
    /// longer applies.
    pub(super) fn linearized(&mut self) {
        self.stale = false;
        self.least_mu = None;
        self.probe_failed = false;
    }

    /// A backward pass at μ completed: its gains are in the workspace.
    pub(super) fn pass_completed(&mut self) {
        self.gains = Gains {
            exist: true,
            current: true,
            mu: self.mu,
            convex: self.model == Model::Convex,
        };
        self.least_mu.get_or_insert(self.mu);
    }

    /// The pass at μ = 0 completed in place of the pass at μ: its gains
    /// are in the workspace, and its step is the one to try.
    pub(super) fn probe_completed(&mut self) {
        self.probe_replaced = Some(self.mu);
        self.mu = 0.0;
        self.gains.mu = 0.0;
        self.gains.convex = self.model == Model::Convex;
        self.least_mu = Some(0.0);
    }

    /// The line search accepted step size `alpha`, which took the cost to
    /// `cost`, `actual` less: the new trajectory is the nominal one, and μ
    /// comes down.
    pub(super) fn accept_step(&mut self, options: &Options, alpha: f64, cost: f64, actual: f64) {
        // Under a huge μ every step is tiny wherever the iterate is, so its
        // small gain proves nothing (`mu_converged_max`); there the next
        // iteration's model test decides.
        self.small_full_step = alpha == 1.0
            && self.mu <= options.mu_converged_max
            && actual <= self.tolerance * self.cost.abs();
        self.cost = cost;
        self.moved = true;
        self.stale = true;
        // The gains describe the previous iterate until the next backward
        // pass completes.
        self.gains.current = false;
        self.decrease_mu(options);
    }

    /// The line search found no step size that gains enough: the iterate
    /// stays, and μ goes up.
    pub(super) fn reject_step(&mut self, options: &Options) {
        // The model about the last step's iterate predicted more than it
        // found: its small gain no longer counts, or the rising μ would
        // shrink the model's prediction until it agreed.
        self.small_full_step = false;
        // Any rejected step at μ = 0 (an ordinary pass there too) tells the
        // pass at μ = 0 not to run again at this iterate. A failed step of
        // that pass is no reason to restart the schedule from μ_min: the
        // damped model it replaced still stands, so μ goes on up from where
        // it was. Restarting would repeat the negligible prediction, the
        // pass at μ = 0 and its failed step, and μ would never rise (mass
        // 1e6 from zero thrust: 250 iterations without an accepted step, μ
        // alternating 0 and 1e-6).
        self.probe_failed |= self.mu == 0.0;
        if let Some(before) = self.probe_replaced {
            self.mu = before;
        }
        self.increase_mu(options);
    }

    /// Whether the model in use can do no more here: μ has passed `mu_max`,
    /// or the convex model's trial step (taken where it predicted nothing)
    /// was rejected, where raising μ would only shrink the same step.
    pub(super) fn exhausted(&self, options: &Options) -> bool {
        (self.convex_step_tried && !self.moved) || self.mu > options.mu_max
    }

    /// The model in use is [`exhausted`](Self::exhausted). `Ok` switches to
    /// the convex expansion ([`Options::convex_fallback`]), recording the
    /// first switch in `convexified_after`, and restarts the
    /// regularisation:
    ///
    /// * from the exact model;
    /// * from the exact model checking a convex minimum, after it moved (it
    ///   found the minimum false and then got stuck in turn).
    ///
    /// `Err(NoProgress)` ends the solve otherwise:
    ///
    /// * the check could not move from the convex minimum at any μ. That is
    ///   no confirmation: `Q_uu` indefinite up to μ = 1e20 at a point of
    ///   zero gradient is a saddle's signature, and IPOPT lowers such a
    ///   point 16× (1 mg quadrotor, 10 s steps). Nor is a model step that
    ///   no line search accepts;
    /// * the convex expansion is stuck too, the fallback is off, or the
    ///   cost has nothing to convexify (and the solve is not DDP, whose
    ///   convex model drops the dynamics' curvature too).
    pub(super) fn switch_model<const NX: usize, const NU: usize>(
        &mut self,
        cost: &impl Cost<NX, NU>,
        options: &Options,
    ) -> Result<(), Status> {
        // A cost with nothing to convexify would only repeat what just
        // failed (and report a fallback that changed nothing), except under
        // DDP: the convex model also drops the dynamics' curvature, which
        // can make V_xx indefinite where no μ on Q_uu helps (without this,
        // DDP would end `NoProgress` at iteration 0 on 59 of 200 random
        // obstacle-free problems where iLQR makes progress).
        if self.model == Model::Convex
            || (self.model == Model::Checking && !self.moved)
            || !options.convex_fallback
            || !(cost.has_convex_approximation() || options.second_order)
        {
            return Err(Status::NoProgress);
        }
        self.model = Model::Convex;
        self.convexified_after.get_or_insert(self.iterations);
        self.restart(options);
        Ok(())
    }

    /// The convex model found a minimum after moving: the exact Hessian
    /// checks it, since the convex model's larger curvature under-predicts
    /// what a step gains.
    pub(super) fn check_convex_minimum(&mut self, options: &Options) {
        self.model = Model::Checking;
        self.restart(options);
    }

    /// A new model starts from the current iterate: derivatives to compute,
    /// μ from `mu_init`, and nothing carried over of what the last model
    /// showed. In particular a convergence its last step claimed does not
    /// count: the next model must find it for itself.
    fn restart(&mut self, options: &Options) {
        (self.mu, self.delta) = (options.mu_init, 1.0);
        self.stale = true;
        self.small_full_step = false;
        self.moved = false;
        self.convex_step_tried = false;
    }

    /// Tassa's schedule: grow the multiplier Δ, then μ ← max(μ_min, μ·Δ).
    pub(super) fn increase_mu(&mut self, o: &Options) {
        self.delta = (self.delta * o.mu_factor).max(o.mu_factor);
        self.mu = (self.mu * self.delta).max(o.mu_min);
    }

    /// Tassa's schedule: shrink Δ, then μ ← μ·Δ, snapping to 0 below μ_min.
    fn decrease_mu(&mut self, o: &Options) {
        self.delta = (self.delta / o.mu_factor).min(1.0 / o.mu_factor);
        let next = self.mu * self.delta;
        self.mu = if next > o.mu_min { next } else { 0.0 };
    }

    /// What the solve reports, ended with `status` after `solve_time`.
    pub(super) fn summary(&self, status: Status, solve_time: std::time::Duration) -> Summary {
        Summary {
            status,
            cost: self.cost,
            initial_cost: self.initial_cost,
            iterations: self.iterations,
            solve_time,
            has_gains: self.gains.exist,
            gains_about_previous_iterate: self.gains.exist && !self.gains.current,
            gains_regularization: self.gains.mu,
            convexified_after: self.convexified_after,
            gains_convex: self.gains.convex,
            constraint_violation: 0.0,
            outer_iterations: 0,
        }
    }
}
