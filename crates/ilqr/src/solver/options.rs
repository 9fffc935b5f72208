//! [`Options`]: the solver's settings and their defaults.

use std::time::Duration;

#[cfg(doc)]
use super::{Status, Summary};
#[cfg(doc)]
use crate::cost::Cost;
#[cfg(doc)]
use crate::dynamics::DiscreteDynamics;

/// Solver settings. The defaults follow Tassa's iLQG reference code except
/// where noted.
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// Upper bound on iterations (one backward and one forward pass each).
    /// Any value is safe, `usize::MAX` included (to leave the stop to
    /// `time_limit`): the trace reserves at most 10000 rows up front.
    pub max_iterations: usize,
    /// Convergence threshold, relative to the current cost: the solve has
    /// converged when a full step (α = 1) at μ ≤ `mu_converged_max` reduced
    /// the cost by less than `tolerance·|J|` and the model about the new
    /// iterate predicts that a full step would too, or when that model
    /// predicts it and `Q_uu` is positive definite without regularisation
    /// (μ ≤ `mu_min`, or a pass at μ = 0 succeeds). With 0 the solve runs
    /// until no step helps, the cap or the budget, unless the model
    /// predicts exactly no gain or the cost reaches
    /// [`Options::cost_lower_bound`].
    pub tolerance: f64,
    /// Wall-clock budget; `None` for no limit. Checked every iteration and
    /// every 128 knots inside each pass, so a solve overruns it by at most
    /// about 256 knots of work (the tail of one pass after its last poll and
    /// the head of the next before its first), except that the initial
    /// rollout always completes (without it there is no trajectory to
    /// return). A constrained solve keeps back the time of its own wrap-up
    /// after the loop (a rollout and a pass over the constraints), and
    /// every solve keeps back [`Options::reserve_rollouts`] more.
    pub time_limit: Option<Duration>,
    /// Time kept back at the end of `time_limit` for the caller's work
    /// with the answer (reports, encoding), in units of one rollout of
    /// this problem as measured during the solve (its slowest, the
    /// constraints' values included): the solve stops that much earlier.
    /// The unit scales with the horizon, the obstacles and the machine's
    /// speed at the time, which a fixed duration would not. Default 0.
    pub reserve_rollouts: f64,
    /// Time kept back at the end of `time_limit` per iteration done: the
    /// caller's work per trace row (encoding it). Default 0.
    pub reserve_per_iteration: Duration,
    /// Initial regularisation μ (iLQG.m starts at 1: the first steps from a
    /// poor initial guess are damped, which here saves iterations).
    pub mu_init: f64,
    /// Smallest non-zero μ; below it μ snaps to 0.
    pub mu_min: f64,
    /// Largest μ; needing more switches the exact Hessian to the cost's
    /// convex expansion ([`Options::convex_fallback`]), or, where that is
    /// off, has nothing to drop or is stuck too, ends the solve with
    /// [`Status::NoProgress`].
    ///
    /// The default, 1e20, is far above iLQG.m's 1e10 because `Q_uu` here is
    /// not normalised: the obstacle term's negative curvature (up to `q/ρ`
    /// per knot) accumulates through `V_xx` over the horizon, so `Q_uu` can be
    /// of order −1e11 or lower: a start within 1 mm of an obstacle centre,
    /// the seed at `N = 1000` or `2000`, or `dt = 1` need μ above 1e10 on
    /// their first iterations, and with 1e20 the exact Hessian converges
    /// there. The price is that a solve that cannot progress gives up
    /// later: from μ = 1, the schedule passes 1e10 after 10 consecutive
    /// increases and 1e20 after 14.
    pub mu_max: f64,
    /// Largest μ at which a full step's small gain counts as convergence
    /// (the first test under `tolerance`). Above it μ has been raised to
    /// force `Q_uu` positive definite against strong negative curvature,
    /// every step is tiny wherever the iterate is, and its small gain is no
    /// evidence of a minimum: 0.1 mm from the centre of a q = 1e6 obstacle
    /// the first pass needs μ ≈ 8e15, where a full step gains almost
    /// nothing 9 m from the goal. The model test, with its pass at μ = 0,
    /// still applies there.
    ///
    /// The default, 1e6, is far from both sides: on the random problems of
    /// `bench/robustness.py` solves converge at μ ≤ 17, and steps that only
    /// look converged come at μ ≥ 8e15. Requiring μ ≤ `mu_min` instead
    /// would deny genuine optima their `Converged`: they would end
    /// `NoProgress` or `MaxIterations` at costs at most 6e-8 lower.
    pub mu_converged_max: f64,
    /// Base factor of the μ schedule (Tassa's Δ₀).
    pub mu_factor: f64,
    /// Step sizes tried by the line search, in order.
    pub step_sizes: Vec<f64>,
    /// Accept a step when actual/expected reduction exceeds this.
    pub acceptance: f64,
    /// A known lower bound on the cost, if any: 0 when every term is
    /// non-negative. A trajectory that attains it is a global optimum, so
    /// the solve has converged there, even where the gradient test cannot
    /// say so (a problem whose cost is identically zero: every step gains
    /// nothing, and without the bound the solve ends `NoProgress`).
    ///
    /// "Attains" is up to round-off: within ε² (4.9e-32) of the initial
    /// cost's distance from the bound (`ROUND_OFF_FLOOR`). A zero optimum
    /// is rarely reached exactly: a terminal-only cost (initial 82) comes
    /// to rest at 7.8e-34, the states 1e-17 from the goal, where the
    /// relative test would need a gain of 1e-43 that round-off never gives;
    /// without the bound that solve raises μ to 2e18 and ends `NoProgress`.
    /// Only a solve whose optimum lies within that floor of the bound can
    /// stop on it (or one whose guess is about 1e16 times as costly as its
    /// optimum).
    pub cost_lower_bound: Option<f64>,
    /// When μ passes `mu_max`, go on with the cost's convex expansion
    /// ([`Cost::stage_expand_convex`]: the obstacle terms' negative
    /// curvature dropped) instead of ending [`Status::NoProgress`]; μ starts
    /// again from `mu_init`. Where the convex expansion converges, the exact
    /// Hessian takes over again to check that point: its larger curvature
    /// can under-predict what a step gains (the seed at `dt = 10` with a
    /// 1e12 obstacle: the convex minimum is 1.9e-6 above IPOPT's optimum,
    /// which the exact Hessian reaches from there). If the exact
    /// Hessian cannot move from there at any μ, the solve ends `NoProgress`
    /// (with the convex expansion's gains where no exact pass completed:
    /// [`Summary::gains_convex`]); if it moves and then gets stuck in turn,
    /// the convex expansion takes over again. The fallback starts only
    /// where the solve would otherwise end `NoProgress`, so every solve
    /// that ends another way without it is unchanged by it.
    /// Skipped for a cost without a convex approximation
    /// ([`Cost::has_convex_approximation`]: no obstacle), where it would
    /// repeat what just failed.
    ///
    /// (With [`Options::second_order`], the convex expansion also leaves
    /// out the dynamics' curvature, which can be indefinite too.)
    ///
    /// Over long horizons the exact Hessian's negative curvature
    /// accumulates through `V_xx` until no μ up to 1e20 makes `Q_uu`
    /// positive definite: from a near-hover guess (4.9051 N per rotor),
    /// N·dt = 200 s and 400 s end `NoProgress` at iteration 0–2 without the
    /// fallback; with it they converge or end at the iteration cap far
    /// below their initial cost (tests in
    /// `crates/ilqr/tests/quadrotor_seed.rs`).
    pub convex_fallback: bool,
    /// Keep the dynamics' second derivatives in the backward pass (DDP)
    /// instead of dropping them (iLQR, the paper's eqs. 33–35): each knot's
    /// `Q_xx`, `Q_ux` and `Q_uu` gain `Σ_i V_x'[i]·∇²F_i`
    /// ([`DiscreteDynamics::curvature`]; a model that gives none leaves the
    /// solve first-order). Off by default, so that the solver is the
    /// paper's.
    ///
    /// Where the optimum has large costates, iLQR's model misses those
    /// terms and converges linearly, in hundreds of damped steps; DDP's
    /// converges in a few: the seed with `R = 90·I` takes 483 iterations,
    /// with DDP 7 (the same optimum to 2.5e-10); with `inertia` 1e-4 iLQR
    /// stops at the 500-iteration cap at 2.6× the optimum, and DDP
    /// converges to it (IPOPT's 5230.6) in 58. On the seed DDP takes 32
    /// iterations to a different local optimum, 5418.30 against 5520.21
    /// (IPOPT started there stays there). Each backward pass costs a
    /// little more (one curvature per knot).
    pub second_order: bool,
    /// A constrained solve converges only with every constraint met to
    /// this, in the constraint's own units (m, rad, …). Default 1e-6.
    pub constraint_tolerance: f64,
    /// The augmented Lagrangian's first penalty ρ. Default 1 (ALTRO's).
    pub penalty_initial: f64,
    /// The first penalty of a constraint component that the initial guess
    /// meets at every knot (a route that already clears an obstacle), if
    /// larger than `penalty_initial`.
    pub penalty_feasible: f64,
    /// The factor ρ grows by after each outer iteration that ends above
    /// the tolerance. Default 10 (ALTRO's).
    pub penalty_scaling: f64,
    /// The largest ρ. Default 1e8 (ALTRO's): where the violation no longer
    /// falls at this penalty, the solve ends [`Status::Infeasible`].
    pub penalty_max: f64,
    /// The most outer iterations. Default 30 (ALTRO's).
    pub max_outer_iterations: usize,
    /// The relative tolerance of the inner solves until the violation is
    /// first under [`Options::constraint_tolerance`]: outer iterations
    /// whose multipliers will change anyway are not solved tightly (ALTRO's
    /// intermediate tolerance). The rest use [`Options::tolerance`].
    /// Default 1e-4.
    pub intermediate_tolerance: f64,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            max_iterations: 500,
            tolerance: 1e-9,
            time_limit: None,
            reserve_rollouts: 0.0,
            reserve_per_iteration: Duration::ZERO,
            mu_init: 1.0,
            mu_min: 1e-6,
            mu_max: 1e20,
            mu_converged_max: 1e6,
            mu_factor: 1.6,
            // 10^linspace(0, −3, 11), as in iLQG.m.
            step_sizes: (0..11).map(|i| 10f64.powf(-0.3 * f64::from(i))).collect(),
            acceptance: 1e-4,
            cost_lower_bound: None,
            convex_fallback: true,
            second_order: false,
            constraint_tolerance: 1e-6,
            penalty_initial: 1.0,
            penalty_feasible: 1.0,
            penalty_scaling: 10.0,
            penalty_max: 1e8,
            max_outer_iterations: 30,
            intermediate_tolerance: 1e-4,
        }
    }
}
