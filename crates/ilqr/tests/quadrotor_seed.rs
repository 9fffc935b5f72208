//! Known answers and invariants on the seed scenario of the paper
//! (x0 = [5,0,0,0,0,0], goal = [4,9,0,0,0,0], one obstacle at (4.5, 4.5),
//! dt = 0.05, N = 100, hover initial controls).

use crate::common;

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use common::{OBSTACLE, SEED_OPTIMUM, Seed, goal, hover, seed_problem};
use ilqr::{Cost, DiscreteDynamics, Options, Solver, Status, Summary};
use nalgebra::{SVector, Vector2};

/// Solve `problem` from hover with `options`.
fn solve_problem(problem: &Seed, options: &Options) -> (Solver<6, 2>, Summary) {
    solve_from(problem, &hover(problem.horizon), options)
}

/// Solve `problem` from the initial controls `us` with `options`.
fn solve_from(problem: &Seed, us: &[Vector2<f64>], options: &Options) -> (Solver<6, 2>, Summary) {
    let mut solver = Solver::new(problem.horizon);
    let summary = solver
        .solve(problem, us, options, &AtomicBool::new(false))
        .expect("the problem is valid");
    (solver, summary)
}

fn solve_with(options: &Options) -> (Solver<6, 2>, Summary) {
    solve_problem(&seed_problem(100, 0.05), options)
}

fn solve_seed() -> (Solver<6, 2>, Summary) {
    solve_with(&Options::default())
}

/// The seed's quadratic terms about `goal`, with diagonal weights `q`
/// (state), `r` (control) and `qf` (terminal), and no obstacle.
fn tracking(goal: SVector<f64, 6>, q: f64, r: f64, qf: f64) -> ilqr::Objective<6, 2> {
    ilqr::Objective::new()
        .with_stage(ilqr::StateTracking {
            goal,
            weights: SVector::repeat(q),
        })
        .with_stage(ilqr::ControlEffort {
            weights: Vector2::repeat(r),
        })
        .with_terminal(ilqr::TerminalTracking {
            goal,
            weights: SVector::repeat(qf),
        })
}

#[test]
fn seed_converges_to_the_reference_optimum() {
    let (solver, s) = solve_seed();
    assert_eq!(s.status, Status::Converged);
    assert_eq!(s.convexified_after, None, "the exact Hessian throughout");
    assert!(solver.trace().iter().all(|r| !r.convex_model));
    let rel = (s.cost - SEED_OPTIMUM).abs() / SEED_OPTIMUM;
    assert!(rel < 1e-4, "cost {} is {rel:e} from {SEED_OPTIMUM}", s.cost);
    assert!(s.initial_cost > 1e6, "hover start is far from optimal");
}

#[test]
fn seed_reaches_the_goal_and_clears_the_obstacle() {
    let (solver, _) = solve_seed();
    let last = solver.states()[100];
    let miss = (last.fixed_rows::<2>(0) - goal().fixed_rows::<2>(0)).norm();
    assert!(miss < 0.002, "final position is {miss} m from the goal");
    let closest = solver
        .states()
        .iter()
        .map(|x| (Vector2::new(x[0], x[1]) - Vector2::from(OBSTACLE)).norm())
        .fold(f64::INFINITY, f64::min);
    assert!(
        (closest - 2.98).abs() < 0.01,
        "closest approach {closest} m, reference about 2.98"
    );
}

#[test]
fn trace_cost_never_rises_and_has_one_row_per_iteration() {
    let (solver, s) = solve_seed();
    let trace = solver.trace();
    assert_eq!(trace.len(), s.iterations);
    let mut prev = s.initial_cost;
    for (i, row) in trace.iter().enumerate() {
        assert_eq!(row.iteration, i + 1);
        assert!(
            row.cost <= prev,
            "iteration {} raised the cost",
            row.iteration
        );
        assert!((prev - row.cost - row.actual_reduction).abs() <= 1e-9 * prev);
        if row.step_size > 0.0 {
            assert!(row.expected_reduction > 0.0);
        }
        prev = row.cost;
    }
    assert_eq!(prev, s.cost);
    assert!(trace.windows(2).all(|w| w[0].elapsed <= w[1].elapsed));
}

#[test]
fn returned_states_are_the_dynamics_applied_to_the_returned_controls() {
    let problem = seed_problem(100, 0.05);
    let (solver, s) = solve_seed();
    let (xs, us) = (solver.states(), solver.controls());
    assert_eq!((xs.len(), us.len()), (101, 100));
    assert_eq!(xs[0], problem.x0);
    let mut cost = 0.0;
    for k in 0..100 {
        assert_eq!(xs[k + 1], problem.dynamics.step(&xs[k], &us[k]), "knot {k}");
        cost += problem.cost.stage(k, &xs[k], &us[k]);
    }
    cost += problem.cost.terminal(&xs[100]);
    assert!((cost - s.cost).abs() <= 1e-9 * cost);
}

/// The gains are a policy: from a perturbed start, following
/// `u = ū + K(x − x̄)` lands nearer the goal than replaying `ū`.
#[test]
fn feedback_gains_correct_a_perturbed_start() {
    let problem = seed_problem(100, 0.05);
    let (solver, _) = solve_seed();
    let (xs, us, ks) = (solver.states(), solver.controls(), solver.feedback());
    for perturbation in [
        [0.3, -0.2, 0.0, 0.0, 0.0, 0.0],
        [-0.2, 0.1, 0.05, 0.1, 0.0, 0.0],
        [0.0, 0.0, 0.0, -0.3, 0.3, 0.1],
    ] {
        let x0 = problem.x0 + SVector::from(perturbation);
        let (mut open, mut closed) = (x0, x0);
        for k in 0..100 {
            open = problem.dynamics.step(&open, &us[k]);
            let u = us[k] + ks[k] * (closed - xs[k]);
            closed = problem.dynamics.step(&closed, &u);
        }
        let miss = |x: SVector<f64, 6>| (x - goal()).norm();
        assert!(
            miss(closed) < 0.5 * miss(open),
            "{perturbation:?}: closed loop misses by {}, open loop by {}",
            miss(closed),
            miss(open)
        );
    }
}

/// How far the closed loop `u = ū + K(x − x̄)` and the open loop `ū` end
/// from the goal, started 0.3 m east and 0.2 m south of `x0`.
fn closed_and_open_miss(problem: &Seed, solver: &Solver<6, 2>) -> (f64, f64) {
    let (xs, us, ks) = (solver.states(), solver.controls(), solver.feedback());
    let x0 = problem.x0 + SVector::from([0.3, -0.2, 0.0, 0.0, 0.0, 0.0]);
    let (mut open, mut closed) = (x0, x0);
    for k in 0..problem.horizon {
        open = problem.dynamics.step(&open, &us[k]);
        closed = problem
            .dynamics
            .step(&closed, &(us[k] + ks[k] * (closed - xs[k])));
    }
    ((closed - goal()).norm(), (open - goal()).norm())
}

/// A solve that ends on failed line searches returns its iterate's least
/// regularised gains, not the last pass's. With a zero tolerance the seed
/// reaches its optimum, every line search then fails on round-off, and μ
/// climbs past its maximum (twice: with the exact Hessian, then after the
/// convex fallback), so the last pass runs at μ ≈ 4e18, where `K` is 6e-11 at
/// most and its "closed loop" misses the goal from a perturbed start by the
/// same 1.4 m as the open loop. The gains returned are the exact Hessian's at
/// μ = 0.
#[test]
fn a_solve_ended_by_failed_line_searches_returns_useful_gains() {
    let problem = seed_problem(100, 0.05);
    let options = Options {
        tolerance: 0.0,
        ..Options::default()
    };
    let (solver, s) = solve_problem(&problem, &options);
    assert_eq!(s.status, Status::NoProgress, "{s:?}");
    assert!((s.cost - SEED_OPTIMUM).abs() < 1e-3, "{s:?}");
    assert!(s.has_gains && !s.gains_about_previous_iterate, "{s:?}");
    assert!(s.gains_regularization <= options.mu_init, "{s:?}");
    // The convex fallback, tried at the end, moved nothing: the gains are
    // the exact Hessian's, about the optimum it reached.
    assert!(s.convexified_after.is_some() && !s.gains_convex, "{s:?}");
    let (closed, open) = closed_and_open_miss(&problem, &solver);
    assert!(
        closed < 0.1 * open,
        "closed loop misses by {closed}, open loop by {open}"
    );
}

/// The convex fallback is skipped where the cost has nothing to convexify
/// (no obstacle): it would rerun what just failed and report a fallback
/// that changed nothing.
#[test]
fn a_cost_without_obstacles_does_not_fall_back() {
    let mut problem = seed_problem(100, 0.05);
    problem.cost = tracking(goal(), 1.0, 0.1, 50000.0);
    let options = Options {
        tolerance: 0.0,
        ..Options::default()
    };
    let (solver, s) = solve_problem(&problem, &options);
    assert_eq!(s.status, Status::NoProgress, "{s:?}");
    assert_eq!(s.convexified_after, None, "{s:?}");
    let (closed, open) = closed_and_open_miss(&problem, &solver);
    assert!(closed < 0.1 * open, "closed {closed}, open {open}");
}

#[test]
fn max_iterations_stops_early_with_a_consistent_trajectory() {
    let (solver, s) = solve_with(&Options {
        max_iterations: 3,
        ..Options::default()
    });
    assert_eq!(s.status, Status::MaxIterations);
    assert_eq!(s.iterations, 3);
    assert!(s.cost < s.initial_cost && s.cost > SEED_OPTIMUM);
    assert_eq!(solver.states().len(), 101);
}

#[test]
fn zero_iterations_returns_the_initial_guess() {
    let (solver, s) = solve_with(&Options {
        max_iterations: 0,
        ..Options::default()
    });
    assert_eq!(s.status, Status::MaxIterations);
    assert_eq!((s.iterations, s.cost), (0, s.initial_cost));
    assert!(solver.controls().iter().all(|u| *u == hover(1)[0]));
}

#[test]
fn a_time_budget_ends_a_long_solve_with_the_best_trajectory_so_far() {
    let problem = seed_problem(5000, 0.001);
    let mut solver = Solver::new(5000);
    let options = Options {
        max_iterations: 10_000,
        tolerance: 0.0,
        time_limit: Some(Duration::from_millis(30)),
        ..Options::default()
    };
    let s = solver
        .solve(&problem, &hover(5000), &options, &AtomicBool::new(false))
        .unwrap();
    assert_eq!(s.status, Status::TimeLimit);
    assert!(
        s.solve_time < Duration::from_millis(500),
        "{:?}",
        s.solve_time
    );
    assert!(s.cost <= s.initial_cost);
}

#[test]
fn a_set_cancellation_flag_stops_the_solve() {
    let problem = seed_problem(100, 0.05);
    let mut solver = Solver::new(100);
    let cancel = AtomicBool::new(true);
    let s = solver
        .solve(&problem, &hover(100), &Options::default(), &cancel)
        .unwrap();
    assert_eq!(s.status, Status::Cancelled);
    assert_eq!(s.iterations, 0);

    // Set from another thread while the solve runs.
    let problem = seed_problem(5000, 0.001);
    let mut solver = Solver::new(5000);
    let cancel = AtomicBool::new(false);
    let options = Options {
        max_iterations: 10_000,
        tolerance: 0.0,
        ..Options::default()
    };
    std::thread::scope(|scope| {
        scope.spawn(|| {
            std::thread::sleep(Duration::from_millis(30));
            cancel.store(true, Ordering::Relaxed);
        });
        let s = solver
            .solve(&problem, &hover(5000), &options, &cancel)
            .unwrap();
        assert_eq!(s.status, Status::Cancelled);
    });
}

#[test]
fn input_the_solver_cannot_use_is_an_error_not_a_panic() {
    let problem = seed_problem(100, 0.05);
    let mut solver = Solver::new(100);
    let never = AtomicBool::new(false);
    let o = Options::default();
    assert_eq!(
        solver.solve(&problem, &hover(99), &o, &never).unwrap_err(),
        ilqr::SolveError::ControlsLength {
            expected: 100,
            got: 99
        }
    );
    let empty = seed_problem(0, 0.05);
    assert_eq!(
        solver.solve(&empty, &[], &o, &never).unwrap_err(),
        ilqr::SolveError::EmptyHorizon
    );
    let huge = vec![Vector2::new(1e300, -1e300); 100];
    assert!(matches!(
        solver.solve(&problem, &huge, &o, &never).unwrap_err(),
        ilqr::SolveError::InitialRolloutNotFinite { .. }
    ));
    // A NaN state is caught even where the cost does not read it (control
    // effort only, so the cost stays finite).
    let mut blind = seed_problem(100, 0.05);
    blind.x0[0] = f64::NAN;
    blind.cost = ilqr::Objective::new().with_stage(ilqr::ControlEffort {
        weights: Vector2::repeat(0.1),
    });
    assert_eq!(
        solver.solve(&blind, &hover(100), &o, &never).unwrap_err(),
        ilqr::SolveError::InitialRolloutNotFinite { knot: 0 }
    );
}

/// `max_iterations` of any size is safe: the trace reserves at most 10000
/// rows up front, not that many (a capacity-overflow panic at `usize::MAX`,
/// an abort on allocation at 2^40). The seed still converges in its 16
/// iterations.
#[test]
fn an_unbounded_iteration_cap_is_safe() {
    for cap in [usize::MAX, 1 << 40] {
        let (solver, s) = solve_with(&Options {
            max_iterations: cap,
            time_limit: Some(Duration::from_secs(10)),
            ..Options::default()
        });
        assert_eq!((s.status, s.iterations), (Status::Converged, 16), "{s:?}");
        assert_eq!(solver.trace().len(), 16);
    }
}

/// At an obstacle centre the cost is a cone tip: zero gradient, unbounded
/// negative curvature. Nothing may turn NaN there, and the solver must
/// escape: for offsets below 1 mm the curvature accumulated through `V_xx`
/// needs μ ≈ 1.7e11, above iLQG.m's `mu_max` of 1e10.
#[test]
fn starts_on_and_near_the_obstacle_centre_stay_finite_and_escape() {
    for offset in [0.0, 1e-4, 0.05, 0.5] {
        let mut problem = seed_problem(100, 0.05);
        problem.x0 = SVector::from([4.5 + offset, 4.5, 0.0, 0.0, 0.0, 0.0]);
        let (solver, s) = solve_problem(&problem, &Options::default());
        assert!(s.cost.is_finite(), "offset {offset}: {s:?}");
        assert!(
            solver
                .states()
                .iter()
                .all(|x| x.iter().all(|v| v.is_finite()))
        );
        assert!(
            solver
                .feedback()
                .iter()
                .all(|k| k.iter().all(|v| v.is_finite()))
        );
        assert_eq!(s.status, Status::Converged, "offset {offset}: {s:?}");
        assert!(s.cost < 0.01 * s.initial_cost, "offset {offset}: {s:?}");
    }
}

/// Long horizons pile up the obstacle's negative curvature (it grows with
/// the cube of the horizon through `V_xx`): the seed at `N = 1000` (same
/// `dt`, so a 50 s flight) needs μ far above 1e10 on its first iterations.
#[test]
fn the_seed_over_a_long_horizon_converges() {
    let (solver, s) = solve_problem(&seed_problem(1000, 0.05), &Options::default());
    assert_eq!(s.status, Status::Converged, "{s:?}");
    assert!(s.cost < 15_000.0, "{s:?}");
    let end = solver.states()[1000];
    assert!((end - goal()).norm() < 0.01, "ends at {end:?}");
}

/// A flight of 400 s (N = 8000 at dt = 0.05) from a guess a hair above
/// hover (4.9051 N per rotor, hover is 4.905): the obstacle's negative
/// curvature piles up over the horizon until no μ up to `mu_max` makes
/// `Q_uu` positive definite: the exact Hessian alone ends `NoProgress` at
/// iteration 0 with the guess. The convex fallback drops that curvature
/// and goes on from the same iterate.
#[test]
fn a_very_long_flight_falls_back_to_the_convex_expansion() {
    let n = 8000;
    let problem = seed_problem(n, 0.05);
    let guess = vec![Vector2::new(4.9051, 4.9051); n];
    let exact_only = Options {
        convex_fallback: false,
        ..Options::default()
    };
    let (_, stuck) = solve_from(&problem, &guess, &exact_only);
    assert_eq!(
        (stuck.status, stuck.iterations, stuck.convexified_after),
        (Status::NoProgress, 0, None),
        "{stuck:?}"
    );
    let (solver, s) = solve_from(&problem, &guess, &Options::default());
    assert_eq!(s.status, Status::Converged, "{s:?}");
    assert_eq!(s.convexified_after, Some(0), "{s:?}");
    assert!(s.cost < 0.05 * s.initial_cost, "{s:?}");
    assert!(s.has_gains && !s.gains_about_previous_iterate, "{s:?}");
    let end = solver.states()[n];
    assert!((end - goal()).norm() < 0.01, "ends at {end:?}");
    // Every accepted step lowered the cost, after the switch as before.
    let costs: Vec<f64> = solver.trace().iter().map(|r| r.cost).collect();
    assert!(costs.windows(2).all(|w| w[1] <= w[0]), "{costs:?}");
}

/// The seed at `dt = 10` with a 1e12 obstacle: the exact Hessian fails at
/// once, and the convex model's minimum is not the cost's (its larger
/// curvature under-predicts what a step gains): at tolerance 1e-9 it lies
/// 1.9e-6 above IPOPT's 21611203310.7. The exact Hessian, back to check that
/// point, goes on to within 1e-8 of it, and the result says the exact model
/// gave the gains. The trace says which model each iteration used: the convex
/// one from the first, then the exact one to the end.
#[test]
fn the_exact_hessian_checks_the_convex_models_minimum() {
    let mut problem = seed_problem(100, 10.0);
    problem.cost = tracking(goal(), 1.0, 0.1, 50000.0).with_stage(ilqr::ExpObstacle {
        center: Vector2::from(OBSTACLE),
        weight: 1e12,
        position: (0, 1),
    });
    let (solver, s) = solve_problem(&problem, &Options::default());
    assert_eq!(s.status, Status::Converged, "{s:?}");
    assert_eq!(
        (s.convexified_after, s.gains_convex),
        (Some(0), false),
        "{s:?}"
    );
    let convex: Vec<bool> = solver.trace().iter().map(|r| r.convex_model).collect();
    let switch = convex.iter().position(|&c| !c).unwrap_or(convex.len());
    assert!(
        switch > 0 && switch < convex.len() && !convex[switch..].contains(&true),
        "convex model in rows {convex:?}"
    );
    let ipopt = 21611203310.7;
    assert!((s.cost - ipopt) / ipopt < 1e-8, "{s:?}");
}

/// Where the exact Hessian cannot complete a pass about the convex model's
/// minimum at any μ, that point is not called converged: `Q_uu` indefinite up
/// to μ = 1e20 where the gradient vanishes is a saddle's signature. A 1 mg,
/// 1 mg·m² quadrotor flying steps of 10 s: the convex model stops after 3
/// iterations at 27303.55, which IPOPT lowers to 1736.92 from that very
/// point. The solve ends `NoProgress`, with the convex model's gains, and
/// says so.
#[test]
fn a_convex_minimum_the_exact_hessian_cannot_check_is_not_converged() {
    let mut problem = seed_problem(300, 10.0);
    problem.dynamics.model.mass = 1e-6;
    problem.dynamics.model.inertia = 1e-6;
    let hover = vec![Vector2::repeat(problem.dynamics.model.hover_thrust()); 300];
    let (_, s) = solve_from(&problem, &hover, &Options::default());
    assert_eq!(s.status, Status::NoProgress, "{s:?}");
    assert_eq!(
        (s.convexified_after, s.gains_convex),
        (Some(0), true),
        "{s:?}"
    );
    assert!(s.has_gains && !s.gains_about_previous_iterate, "{s:?}");
}

/// A convergence claimed by the exact model's last step is not carried
/// over the fallback. With `mu_max = 10` and a loose tolerance, the seed's
/// first step counts as converged, then the exact pass about the new
/// iterate fails at every μ up to 10: the convex model finds that iterate
/// stationary at once, which it cannot tell from a maximum, so the solve
/// ends `NoProgress` there, as it does without the fallback.
#[test]
fn a_convergence_claimed_before_the_fallback_is_not_carried_over() {
    let problem = seed_problem(100, 0.05);
    let loose = |convex_fallback| Options {
        mu_max: 10.0,
        tolerance: 0.99,
        convex_fallback,
        ..Options::default()
    };
    let (_, exact) = solve_problem(&problem, &loose(false));
    assert_eq!(
        (exact.status, exact.iterations),
        (Status::NoProgress, 1),
        "{exact:?}"
    );
    let (_, s) = solve_problem(&problem, &loose(true));
    assert_eq!(s.convexified_after, Some(1), "{s:?}");
    assert_ne!(s.status, Status::Converged, "{s:?}");
    assert!(s.cost <= exact.cost, "{s:?} against {exact:?}");
}

/// The budget is checked between the backward passes that raise μ, too: at
/// `N = 2000` the first pass needs μ far above 1, and raising it takes a
/// dozen passes (12 ms at `N = 10000`, more than a tight budget). With no
/// budget at all the solve stops after the first failed pass, and since no
/// pass completed the gains are zero, not the half-written gains of the
/// failed pass.
#[test]
fn the_budget_is_checked_while_mu_is_raised_and_failed_passes_leave_no_gains() {
    let n = 2000;
    let problem = seed_problem(n, 0.05);
    let mut solver = Solver::new(n);
    // Without a budget the first pass indeed fails at μ = 1.
    let first = Options {
        max_iterations: 0,
        ..Options::default()
    };
    let s = solver
        .solve(&problem, &hover(n), &first, &AtomicBool::new(false))
        .unwrap();
    assert!(s.has_gains);
    assert!(
        solver
            .feedback()
            .iter()
            .any(|k| k.iter().any(|v| *v != 0.0))
    );

    let options = Options {
        time_limit: Some(Duration::ZERO),
        ..Options::default()
    };
    let s = solver
        .solve(&problem, &hover(n), &options, &AtomicBool::new(false))
        .unwrap();
    assert_eq!((s.status, s.iterations), (Status::TimeLimit, 0), "{s:?}");
    assert!(!s.has_gains);
    assert!(
        solver
            .feedback()
            .iter()
            .all(|k| k.iter().all(|v| *v == 0.0))
    );
    assert!(solver.feedforward().iter().all(|d| *d == Vector2::zeros()));
    assert_eq!(s.cost, s.initial_cost);
}

/// A problem whose cost is identically zero (every weight 0): no step gains
/// anything, so the gradient test never fires and the solve ends
/// `NoProgress`; with the lower bound 0 that every sum of non-negative terms
/// has, the trajectory is known to be a global optimum and the solve
/// converges at once. A cost above the bound changes nothing.
#[test]
fn a_cost_at_its_lower_bound_is_converged() {
    let mut problem = seed_problem(100, 0.05);
    problem.cost = tracking(goal(), 0.0, 0.0, 0.0);
    let (_, s) = solve_problem(&problem, &Options::default());
    assert_eq!(s.status, Status::NoProgress, "{s:?}");

    let bounded = Options {
        cost_lower_bound: Some(0.0),
        ..Options::default()
    };
    let (solver, s) = solve_problem(&problem, &bounded);
    assert_eq!(
        (s.status, s.iterations, s.cost),
        (Status::Converged, 0, 0.0)
    );
    assert!(solver.controls().iter().all(|u| *u == hover(1)[0]));

    // A zero optimum reached up to round-off counts too. With only the
    // terminal weights the cost comes to rest at 7.8e-34 (the states 1e-17
    // from the goal), where the relative test would need a gain round-off
    // never gives: without the bound the solve ends `NoProgress` at
    // μ = 2e18.
    problem.cost = tracking(goal(), 0.0, 0.0, 1.0);
    let (solver, s) = solve_problem(&problem, &bounded);
    assert_eq!(s.status, Status::Converged, "{s:?}");
    assert!(s.iterations < 30, "{s:?}");
    assert!((solver.states()[100] - goal()).norm() < 1e-12, "{s:?}");
    let (_, unbounded) = solve_problem(&problem, &Options::default());
    assert_eq!(unbounded.status, Status::NoProgress, "{unbounded:?}");

    // The floor scales with the initial cost, so a wild guess must not
    // lift it to the optimum's level: from 1e7 N per rotor (initial cost
    // 3.6e21) a floor of ε rather than ε² would call 7.3e5 converged, with
    // the optimum near 5.4e3.
    let seed = seed_problem(100, 0.05);
    let (_, wild) = solve_from(&seed, &[Vector2::repeat(1e7); 100], &bounded);
    assert!(wild.initial_cost > 1e21, "{wild:?}");
    assert_eq!(wild.status, Status::Converged, "{wild:?}");
    assert!(wild.cost < 6000.0, "{wild:?}");

    // The seed is unaffected: same answer, same iterations.
    let (_, free) = solve_seed();
    let (_, with_bound) = solve_with(&bounded);
    assert_eq!(
        (free.status, free.iterations, free.cost),
        (with_bound.status, with_bound.iterations, with_bound.cost)
    );
}

/// The seed without its obstacle at `dt = 10`: a full step reaches the goal
/// to 1e-10 in two iterations, and what a next step could gain is below
/// round-off. Tiny accepted partial steps leave μ above `mu_min`, where the
/// model test alone is not trusted: without the pass at μ = 0 that confirms
/// the optimum, every later line search would fail on round-off until μ
/// passed `mu_max`, and the solve would end `NoProgress` at this same
/// optimum.
#[test]
fn an_optimum_reached_to_round_off_is_converged_not_no_progress() {
    let mut problem = seed_problem(100, 10.0);
    problem.cost = tracking(goal(), 1.0, 0.1, 50000.0);
    let (solver, s) = solve_problem(&problem, &Options::default());
    assert_eq!(s.status, Status::Converged, "{s:?}");
    assert!(s.iterations <= 5, "{s:?}");
    let end = solver.states()[100];
    assert!((end - goal()).norm() < 1e-6, "ends at {end:?}");
    // The gains describe the returned trajectory: they come from a complete
    // pass, not zero.
    assert!(
        solver
            .feedback()
            .iter()
            .all(|k| k.iter().all(|v| v.is_finite()))
    );
    assert!(solver.feedback().iter().any(|k| k.norm() > 0.0));
    // Built at μ = 0, the pass that confirmed the optimum, and said so.
    assert_eq!(s.gains_regularization, 0.0, "{s:?}");
}

/// The same check must not call a maximum converged: start and goal on the
/// obstacle's centre, no gravity and zero thrust hold the quadrotor on the
/// cone tip, where the gradient is zero and a heavily regularised step
/// predicts no gain. `Q_uu` is indefinite there without μ, so the pass at
/// μ = 0 fails and the solve still ends `NoProgress` with the initial
/// guess (cost q·N = 1e5), not `Converged`. The convex fallback, tried
/// when μ passes its maximum, finds no step either: its model drops the
/// curvature that makes the tip a maximum, and a point where it sees
/// nothing to do at once is not called converged.
#[test]
fn a_trajectory_held_on_an_obstacle_centre_is_not_called_converged() {
    let centre = SVector::from([OBSTACLE[0], OBSTACLE[1], 0.0, 0.0, 0.0, 0.0]);
    let mut problem = seed_problem(100, 0.05);
    problem.dynamics.model.gravity = 0.0;
    problem.x0 = centre;
    problem.cost = tracking(centre, 1.0, 0.1, 50000.0).with_stage(ilqr::ExpObstacle {
        center: Vector2::from(OBSTACLE),
        weight: 1000.0,
        position: (0, 1),
    });
    let (_, s) = solve_from(&problem, &[Vector2::zeros(); 100], &Options::default());
    assert_eq!(s.status, Status::NoProgress, "{s:?}");
    assert_eq!(s.cost, 1e5, "{s:?}");
    assert!(s.convexified_after.is_some(), "{s:?}");
    // The convex model's one trial step (it predicts nothing) costs one
    // iteration, not a climb of μ to its maximum (14 more).
    assert_eq!(s.iterations, s.convexified_after.unwrap() + 1, "{s:?}");
}

/// A start on the centre of steep obstacles, with gravity and a goal away
/// from them, is no such maximum: any step off the tip gains about q per
/// metre. There the exact Hessian finds no μ that works, and the convex
/// model, which sees the tip's gradient as 0, predicts only what the tracking
/// terms gain (1e6 here, below 1e-9 of the cost of 1.1e15). That prediction
/// alone would end the solve `NoProgress` at iteration 0, at the initial
/// guess; the convex model's step is tried first, and gains almost all of the
/// cost.
#[test]
fn a_start_on_the_centre_of_steep_obstacles_leaves_it() {
    let centre = SVector::from([OBSTACLE[0], OBSTACLE[1], 0.0, 0.0, 0.0, 0.0]);
    let mut problem = seed_problem(100, 0.05);
    problem.x0 = centre;
    let mut cost = tracking(goal(), 1.0, 0.1, 50000.0);
    for _ in 0..11 {
        cost = cost.with_stage(ilqr::ExpObstacle {
            center: Vector2::from(OBSTACLE),
            weight: 1e12,
            position: (0, 1),
        });
    }
    problem.cost = cost;
    let (solver, s) = solve_problem(&problem, &Options::default());
    assert!(s.iterations > 0, "{s:?}");
    assert!(s.convexified_after.is_some(), "{s:?}");
    // The first stage's cost (11e12 at the centre) cannot be avoided; the
    // other 100 stages leave the centre.
    assert!(s.cost < 0.05 * s.initial_cost, "{s:?}");
    assert_eq!(s.status, Status::Converged, "{s:?}");
    assert!((solver.states()[100] - centre).norm() > 1.0);
}

/// A start 0.1 mm from the centre of a steep obstacle (q = 1e6): `Q_uu` is so
/// indefinite that the first pass raises μ to about 1e16, where a full step
/// moves the thrusts by 1e-13 and gains almost nothing. Counted as
/// convergence, that gain would end the solve `Converged` after one
/// iteration, the cost unchanged and the quadrotor 9 m from the goal. Such a
/// step is no evidence of a minimum (`mu_converged_max`); the solve goes on
/// and reaches the goal.
#[test]
fn a_step_damped_by_a_huge_mu_is_not_called_converged() {
    let mut problem = seed_problem(100, 0.05);
    problem.cost = tracking(goal(), 1.0, 0.1, 50000.0).with_stage(ilqr::ExpObstacle {
        center: Vector2::new(5.0, 1e-4),
        weight: 1e6,
        position: (0, 1),
    });
    let (solver, s) = solve_problem(&problem, &Options::default());
    assert_eq!(s.status, Status::Converged, "{s:?}");
    assert!(s.cost < 0.05 * s.initial_cost, "{s:?}");
    let end = solver.states()[100];
    assert!((end - goal()).norm() < 0.01, "ends at {end:?}");
    // No accepted step under μ > mu_converged_max ended the solve.
    let last = solver.trace().last().expect("a trace row");
    assert!(
        last.regularization <= Options::default().mu_converged_max,
        "{last:?}"
    );
}

/// Convergence is tested before the iteration cap: a solve that converges in
/// exactly `max_iterations` iterations is `Converged`, and so is an optimal
/// warm start given `max_iterations = 0`: `MaxIterations` would tell an MPC
/// caller with a tight cap that the solve ran out when it had not.
#[test]
fn a_solve_that_converges_at_the_iteration_cap_is_converged() {
    let (free_solver, free) = solve_seed();
    assert_eq!(free.status, Status::Converged);
    let capped = |max_iterations| {
        solve_with(&Options {
            max_iterations,
            ..Options::default()
        })
        .1
    };
    let exact = capped(free.iterations);
    assert_eq!(
        (exact.status, exact.iterations, exact.cost),
        (Status::Converged, free.iterations, free.cost)
    );
    assert_eq!(capped(free.iterations - 1).status, Status::MaxIterations);

    let (_, s) = solve_from(
        &seed_problem(100, 0.05),
        free_solver.controls(),
        &Options {
            max_iterations: 0,
            ..Options::default()
        },
    );
    assert_eq!(
        (s.status, s.iterations, s.cost),
        (Status::Converged, 0, free.cost)
    );
}

/// The textbook gains `−(Q_uu + μI)⁻¹(Q_ux, Q_u)` at the last knot about
/// the solver's returned trajectory, where `V' = l_f` exactly.
#[allow(non_snake_case)]
fn last_knot_gains(
    problem: &Seed,
    solver: &Solver<6, 2>,
    mu: f64,
) -> (nalgebra::SMatrix<f64, 2, 6>, Vector2<f64>) {
    let n = problem.horizon;
    let (x, u) = (solver.states()[n - 1], solver.controls()[n - 1]);
    let (A, B) = problem.dynamics.linearize(&x, &u);
    let mut l = ilqr::StageExpansion::zeros();
    problem.cost.stage_expand(n - 1, &x, &u, &mut l);
    let mut f = ilqr::TerminalExpansion::zeros();
    problem.cost.terminal_expand(&solver.states()[n], &mut f);
    let Q_u = l.l_u + B.transpose() * f.l_x;
    let Q_uu = l.l_uu + B.transpose() * f.l_xx * B;
    let Q_ux = l.l_ux + B.transpose() * f.l_xx * A;
    let inv = (Q_uu + nalgebra::Matrix2::identity() * mu)
        .try_inverse()
        .expect("Q_uu is positive definite at the last knot");
    (-inv * Q_ux, -inv * Q_u)
}

/// `Summary::gains_regularization` is the μ the returned gains were built
/// with: at the last knot, where `V' = l_f` exactly, `K` and `d` equal the
/// textbook `−(Q_uu + μI)⁻¹(Q_ux, Q_u)` about the returned trajectory with
/// that μ and with no other. The seed ends at μ = 0; three obstacles end at
/// μ > 0 (the case that needs the field), where μ = 0 would be ~1% off.
#[test]
#[allow(non_snake_case)]
fn the_reported_gains_regularization_is_the_one_the_gains_were_built_with() {
    let mut three = seed_problem(100, 0.05);
    for center in [[3.0, 6.5], [6.0, 6.0]] {
        three.cost = three.cost.with_stage(ilqr::ExpObstacle {
            center: Vector2::from(center),
            weight: 1000.0,
            position: (0, 1),
        });
    }
    let options = Options {
        max_iterations: 300,
        tolerance: 1e-9,
        ..Options::default()
    };
    for (name, problem, damped) in [
        ("seed", seed_problem(100, 0.05), false),
        ("three obstacles", three, true),
    ] {
        let (solver, s) = solve_problem(&problem, &options);
        assert!(
            s.has_gains && !s.gains_about_previous_iterate,
            "{name}: {s:?}"
        );
        assert_eq!(s.gains_regularization > 0.0, damped, "{name}: {s:?}");

        let n = problem.horizon;
        let gains = |mu: f64| last_knot_gains(&problem, &solver, mu);
        let (K, d) = gains(s.gains_regularization);
        let (K_got, d_got) = (solver.feedback()[n - 1], solver.feedforward()[n - 1]);
        let err = (K_got - K).amax() / K.amax();
        assert!(
            err < 1e-9,
            "{name}: K off by {err:e} at μ = {}",
            s.gains_regularization
        );
        assert!(
            (d_got - d).amax() <= 1e-9 * d.amax().max(1e-6),
            "{name}: d {d_got} vs {d}"
        );
        if damped {
            let (K0, _) = gains(0.0);
            let off = (K_got - K0).amax() / K0.amax();
            assert!(off > 1e-4, "{name}: μ = 0 would match too ({off:e})");
        }
    }
}

/// Gains about the iterate before the returned one are flagged. With
/// `mu_max = 10` (and no convex fallback) the seed takes one step, then the
/// backward pass about the new iterate fails at every μ up to 10:
/// `NoProgress` after 1 iteration.
/// The workspace still holds the first iterate's gains, which differ from
/// the new iterate's own (checked at the last knot), so
/// `gains_about_previous_iterate` must say so. Other exits at the same
/// point (a time limit or cancellation while μ is raised) take the same
/// path.
#[test]
#[allow(non_snake_case)]
fn gains_about_the_previous_iterate_are_flagged() {
    let problem = seed_problem(100, 0.05);
    let options = Options {
        mu_max: 10.0,
        convex_fallback: false,
        ..Options::default()
    };
    let (solver, s) = solve_problem(&problem, &options);
    assert_eq!((s.status, s.iterations), (Status::NoProgress, 1), "{s:?}");
    assert!(s.cost < s.initial_cost, "the step was accepted: {s:?}");
    assert!(s.has_gains && s.gains_about_previous_iterate, "{s:?}");

    // What the stale gains would have claimed, against the truth.
    let (K, d) = last_knot_gains(&problem, &solver, s.gains_regularization);
    let n = problem.horizon;
    let k_off = (solver.feedback()[n - 1] - K).amax() / K.amax();
    let d_off = (solver.feedforward()[n - 1] - d).amax() / d.amax();
    println!("stale gains at the last knot: K off by {k_off:.3}, d off by {d_off:.3}");
    assert!(
        k_off > 0.01 && d_off > 0.1,
        "the stale gains are not off ({k_off:e}, {d_off:e}): is the test still testing?"
    );

    // One iteration with a cap instead ends at the same trajectory with
    // its own backward pass done: gains reported.
    let capped = Options {
        max_iterations: 1,
        ..Options::default()
    };
    let (capped_solver, c) = solve_problem(&problem, &capped);
    assert_eq!(capped_solver.controls(), solver.controls());
    assert!(c.has_gains && !c.gains_about_previous_iterate, "{c:?}");
}

/// The expected reduction is the model's for the step size taken,
/// `α·ΔV₁ + α²·ΔV₂`, and the trace records that α: on a nearly linear
/// problem (hover, a goal 5 cm up) with only α = 0.5 on offer and no
/// regularisation, every step is recorded at 0.5 and the actual reduction
/// matches the expected one to a few percent (with `α·ΔV₂` it is 1.5 times
/// off).
#[test]
fn the_expected_reduction_is_the_models_at_the_step_taken() {
    let mut problem = seed_problem(50, 0.05);
    let start = problem.x0;
    let mut goal = start;
    goal[1] += 0.05;
    problem.cost = tracking(goal, 1.0, 0.1, 100.0);
    let options = Options {
        step_sizes: vec![0.5],
        mu_init: 0.0,
        max_iterations: 5,
        ..Options::default()
    };
    let (solver, s) = solve_problem(&problem, &options);
    let taken: Vec<_> = solver
        .trace()
        .iter()
        .filter(|r| r.step_size > 0.0)
        .collect();
    assert!(taken.len() >= 3, "{s:?}: {:?}", solver.trace());
    for row in taken {
        assert_eq!(row.step_size, 0.5, "{row:?}");
        let ratio = row.actual_reduction / row.expected_reduction;
        assert!((ratio - 1.0).abs() < 0.05, "ratio {ratio}: {row:?}");
    }
}

/// The trace's `feedforward_norm` is the documented mean over knots of
/// `max_i |d_i| / (|ū_i| + 1)`: iteration 1's row, from the first pass
/// about the hover guess, matches it recomputed from that pass's `d`
/// (which a solve with `max_iterations: 0` returns). Both start at μ = 0,
/// since a solve stopped by the cap returns its least regularised gains.
#[test]
fn the_feedforward_norm_is_the_documented_mean() {
    let problem = seed_problem(100, 0.05);
    let undamped = Options {
        mu_init: 0.0,
        ..Options::default()
    };
    let (first_pass, s) = solve_problem(
        &problem,
        &Options {
            max_iterations: 0,
            ..undamped.clone()
        },
    );
    assert_eq!(s.gains_regularization, 0.0, "{s:?}");
    let guess = hover(problem.horizon);
    let mean = first_pass
        .feedforward()
        .iter()
        .zip(&guess)
        .map(|(d, u)| {
            (0..2)
                .map(|i| d[i].abs() / (u[i].abs() + 1.0))
                .fold(0.0, f64::max)
        })
        .sum::<f64>()
        / problem.horizon as f64;
    let (solver, _) = solve_problem(&problem, &undamped);
    let row = solver.trace()[0];
    assert_eq!(row.regularization, 0.0);
    assert!(mean > 0.0);
    assert!(
        (row.feedforward_norm - mean).abs() <= 1e-12 * mean,
        "trace says {}, recomputed {mean}",
        row.feedforward_norm
    );
}

/// `x ← x + u`, except that a thrust above 5 breaks the model (NaN): the
/// line search must reject such steps even where the cost would not see
/// the NaN (the terminal cost below ignores the state).
struct BreaksAboveFive;

impl DiscreteDynamics<1, 1> for BreaksAboveFive {
    fn step(&self, x: &SVector<f64, 1>, u: &SVector<f64, 1>) -> SVector<f64, 1> {
        if u[0] > 5.0 {
            SVector::from([f64::NAN])
        } else {
            x + u
        }
    }
    fn linearize(
        &self,
        _x: &SVector<f64, 1>,
        _u: &SVector<f64, 1>,
    ) -> (nalgebra::SMatrix<f64, 1, 1>, nalgebra::SMatrix<f64, 1, 1>) {
        (nalgebra::SMatrix::identity(), nalgebra::SMatrix::identity())
    }
}

/// `(u − 10)²` at every stage, nothing at the end.
struct WantsTen;

impl Cost<1, 1> for WantsTen {
    fn stage(&self, _k: usize, _x: &SVector<f64, 1>, u: &SVector<f64, 1>) -> f64 {
        (u[0] - 10.0).powi(2)
    }
    fn stage_expand(
        &self,
        _k: usize,
        _x: &SVector<f64, 1>,
        u: &SVector<f64, 1>,
        e: &mut ilqr::StageExpansion<1, 1>,
    ) {
        e.l_u[0] += 2.0 * (u[0] - 10.0);
        e.l_uu[(0, 0)] += 2.0;
    }
    fn terminal(&self, _x: &SVector<f64, 1>) -> f64 {
        0.0
    }
    fn terminal_expand(&self, _x: &SVector<f64, 1>, _e: &mut ilqr::TerminalExpansion<1>) {}
}

/// A step whose rollout leaves the model's domain is rejected even when
/// the cost stays finite: every returned state is finite, and the thrust
/// stops at the edge of the domain instead of crossing it.
#[test]
fn a_rollout_with_a_non_finite_state_is_rejected_even_at_finite_cost() {
    let problem = ilqr::Problem {
        dynamics: BreaksAboveFive,
        cost: WantsTen,
        x0: SVector::from([0.0]),
        horizon: 1,
    };
    let mut solver = Solver::<1, 1>::new(1);
    let s = solver
        .solve(
            &problem,
            &[SVector::from([0.0])],
            &Options::default(),
            &AtomicBool::new(false),
        )
        .expect("valid problem");
    assert!(
        solver.states().iter().all(|x| x[0].is_finite()),
        "{s:?}: {:?}",
        solver.states()
    );
    let u = solver.controls()[0][0];
    assert!(u > 2.0 && u <= 5.0, "{s:?}: u = {u}");
}

/// The pass at μ = 0 (taken when the damped model predicts a negligible gain)
/// may propose a step the line search rejects. Then μ must go on up from
/// where it was, not restart from μ_min. Restarting, this problem (mass 1e6,
/// g = 1e4, from zero thrust) would alternate μ between 0 and 1e-6 on every
/// rejected step, accept nothing after iteration 89, and report that the
/// exact Hessian failed "up to μ = 1e20" when it had tried 1e4.
#[test]
fn a_failed_step_at_mu_zero_does_not_reset_the_regularisation() {
    let mut problem = seed_problem(100, 0.05);
    problem.dynamics.model.mass = 1e6;
    problem.dynamics.model.gravity = 1e4;
    let options = Options {
        max_iterations: 300,
        ..Options::default()
    };
    let (solver, s) = solve_from(&problem, &[Vector2::zeros(); 100], &options);
    let trace = solver.trace();
    // Between two accepted steps, the damped passes' μ only rises (a row at
    // μ = 0 is the undamped pass, tried at most once per iterate).
    let mut last_damped = None;
    let mut undamped_at_this_iterate = 0;
    for row in trace {
        if row.regularization == 0.0 {
            undamped_at_this_iterate += 1;
            assert!(
                undamped_at_this_iterate <= 1 || row.step_size > 0.0,
                "iteration {}: the failed pass at μ = 0 was repeated",
                row.iteration
            );
        } else if let Some(previous) = last_damped {
            assert!(
                row.regularization > previous,
                "iteration {}: μ fell from {previous} to {} with no step accepted",
                row.iteration,
                row.regularization
            );
        }
        if row.step_size > 0.0 {
            (last_damped, undamped_at_this_iterate) = (None, 0);
        } else if row.regularization > 0.0 {
            last_damped = Some(row.regularization);
        }
    }
    // And the solve keeps moving to the end instead of stalling.
    let late = trace
        .iter()
        .filter(|r| r.iteration > 200 && r.step_size > 0.0);
    assert!(late.count() > 10, "{s:?}");
}

/// The seed with a control weight R = 90·I: a problem whose optimum has
/// large costates, which iLQR's model (the paper's, without the dynamics'
/// second derivatives) misses.
fn heavy_control_seed() -> Seed {
    let mut problem = seed_problem(100, 0.05);
    problem.cost = tracking(goal(), 1.0, 90.0, 50000.0).with_stage(ilqr::ExpObstacle {
        center: Vector2::from(OBSTACLE),
        weight: 1000.0,
        position: (0, 1),
    });
    problem
}

/// Where iLQR converges linearly, in hundreds of half steps each gaining a
/// two-hundredth of its prediction, DDP's model (`second_order`) is right
/// and converges in a few full steps to the same optimum.
#[test]
fn second_order_converges_in_a_few_steps_where_ilqr_crawls() {
    let problem = heavy_control_seed();
    let (_, ilqr) = solve_problem(&problem, &Options::default());
    let ddp_options = Options {
        second_order: true,
        ..Options::default()
    };
    let (_, ddp) = solve_problem(&problem, &ddp_options);
    assert_eq!(ilqr.status, Status::Converged);
    assert_eq!(ddp.status, Status::Converged);
    assert!(ilqr.iterations > 200, "iLQR took {}", ilqr.iterations);
    assert!(ddp.iterations <= 15, "DDP took {}", ddp.iterations);
    assert!(
        (ddp.cost - ilqr.cost).abs() <= 1e-8 * ilqr.cost,
        "{} vs {}",
        ddp.cost,
        ilqr.cost
    );
}

/// On the seed itself DDP reaches another local optimum, 1.8% below iLQR's
/// 5520.212: IPOPT (`bench/casadi_ipopt.py`) started from DDP's controls
/// stays at 5418.303870. It is a stationary point of iLQR's model too:
/// started there, iLQR has nothing to do.
#[test]
fn second_order_finds_the_seeds_lower_local_optimum() {
    const LOWER_OPTIMUM: f64 = 5418.303870;
    let problem = seed_problem(100, 0.05);
    let options = Options {
        second_order: true,
        ..Options::default()
    };
    let (solver, ddp) = solve_problem(&problem, &options);
    assert_eq!(ddp.status, Status::Converged);
    assert!(
        (ddp.cost - LOWER_OPTIMUM).abs() <= 1e-6 * LOWER_OPTIMUM,
        "{}",
        ddp.cost
    );
    assert!(ddp.cost < SEED_OPTIMUM * 0.99);
    let (_, again) = solve_from(&problem, solver.controls(), &Options::default());
    assert_eq!(again.status, Status::Converged);
    assert!(again.iterations <= 1, "{}", again.iterations);
    assert!((again.cost - ddp.cost).abs() <= 1e-9 * ddp.cost);
}

/// DDP's model of a step is second-order exact where iLQR's is not: near
/// the R = 90·I optimum (iLQR's 40th iterate), a DDP step gains what its
/// model predicts, while iLQR's gains a small fraction of its prediction
/// (the crawl): DDP's step gains 1.0001 of its prediction, iLQR's 0.0036.
/// Without DDP's `l_ux` term the ratio is 0.9968; without `l_xx` the full
/// step is not even accepted.
#[test]
fn ddp_predicts_its_step_where_ilqr_does_not() {
    let problem = heavy_control_seed();
    let forty = Options {
        max_iterations: 40,
        ..Options::default()
    };
    let (near, _) = solve_problem(&problem, &forty);
    let one_step = |second_order| {
        let options = Options {
            max_iterations: 1,
            second_order,
            ..Options::default()
        };
        let (solver, _) = solve_from(&problem, near.controls(), &options);
        let row = solver.trace()[0];
        (row.actual_reduction / row.expected_reduction, row.step_size)
    };
    let (ddp, ddp_step) = one_step(true);
    let (ilqr, _) = one_step(false);
    assert_eq!(ddp_step, 1.0);
    assert!(
        (ddp - 1.0).abs() < 1e-3,
        "DDP gained {ddp} of its prediction"
    );
    assert!(ilqr < 0.1, "iLQR gained {ilqr} of its prediction");
}

/// The seed's dynamics without their stated sparsity pattern: the backward
/// pass then finds the zeros of `A` and `B` at run time.
struct Unstated(ilqr::Euler<ilqr::Quadrotor2D>);

impl DiscreteDynamics<6, 2> for Unstated {
    fn step(&self, x: &SVector<f64, 6>, u: &Vector2<f64>) -> SVector<f64, 6> {
        self.0.step(x, u)
    }
    fn linearize(
        &self,
        x: &SVector<f64, 6>,
        u: &Vector2<f64>,
    ) -> (nalgebra::SMatrix<f64, 6, 6>, nalgebra::SMatrix<f64, 6, 2>) {
        self.0.linearize(x, u)
    }
    fn curvature(
        &self,
        x: &SVector<f64, 6>,
        u: &Vector2<f64>,
        lambda: &SVector<f64, 6>,
    ) -> Option<ilqr::Curvature<6, 2>> {
        self.0.curvature(x, u, lambda)
    }
}

/// The stated pattern only saves work: the seed solves to the same
/// numbers with it and without it, as iLQR and as DDP (equal under `==`,
/// which does not tell a zero's sign). The pattern skips some of the zeros
/// the run-time test finds; the others are entries inside the pattern that
/// are zero at the point (at θ = 0, `∂ẍ/∂u` and `∂ÿ/∂θ`), and the products
/// with them add nothing to finite sums.
#[test]
fn the_stated_sparsity_changes_no_number() {
    for second_order in [false, true] {
        let options = Options {
            second_order,
            ..Options::default()
        };
        assert!(<ilqr::Euler<ilqr::Quadrotor2D> as DiscreteDynamics<6, 2>>::SPARSITY.is_some());
        let (stated, s) = solve_with(&options);
        let seed = seed_problem(100, 0.05);
        let problem = ilqr::Problem {
            dynamics: Unstated(seed.dynamics),
            cost: seed.cost,
            x0: seed.x0,
            horizon: seed.horizon,
        };
        let mut unstated = Solver::<6, 2>::new(100);
        let u = unstated
            .solve(&problem, &hover(100), &options, &AtomicBool::new(false))
            .expect("the problem is valid");
        assert_eq!(
            (s.status, s.iterations, s.cost),
            (u.status, u.iterations, u.cost)
        );
        assert_eq!(stated.states(), unstated.states());
        assert_eq!(stated.controls(), unstated.controls());
        assert_eq!(stated.feedback(), unstated.feedback());
        assert_eq!(stated.feedforward(), unstated.feedforward());
        let model = |t: &[ilqr::TraceRow]| {
            t.iter()
                .map(|r| (r.cost, r.expected_reduction, r.step_size, r.regularization))
                .collect::<Vec<_>>()
        };
        assert_eq!(model(stated.trace()), model(unstated.trace()));
    }
}
