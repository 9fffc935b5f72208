//! Known answers on the unicycle: Crocoddyl's `ActionModelUnicycle`
//! problems, whose optimal costs Crocoddyl's own solver found.
//!
//! Crocoddyl's running cost is `½(w_x²‖x‖² + w_u²‖u‖²)` per knot and its
//! terminal cost `½w_x²‖x_N‖²`, goal the origin, explicit Euler with step
//! `dt`: here `Q = Q_f = w_x²/2·I`, `R = w_u²/2·I` (no ½ factors), goal 0,
//! [`Euler`]. `bench/crocoddyl_unicycle.py` checks that correspondence
//! numerically (Crocoddyl's rollout and cost against these formulas) and
//! times both solvers on these problems.
//!
//! The guess is zero controls, as there. The two solvers' stopping tests
//! differ (Crocoddyl: `Σ‖Q_u‖² < 1e-9`; here a full step gaining less than
//! 1e-9 of the cost), and this solver stops 2e-10 to 6e-10 above
//! Crocoddyl's cost, which stops within 2e-13 of the optimum.

use std::sync::atomic::AtomicBool;

use ilqr::{
    ControlEffort, Cost, DiscreteDynamics, Euler, Objective, Options, Problem, Solver,
    StateTracking, Status, TerminalTracking, Unicycle,
};
use nalgebra::{Vector2, Vector3};

type UnicycleProblem = Problem<Euler<Unicycle>, Objective<3, 2>, 3>;

/// Crocoddyl's unicycle problem with weights `(w_x, w_u)`, step `dt`,
/// horizon `n`, from `x0`.
fn crocoddyl_problem(x0: [f64; 3], w_x: f64, w_u: f64, dt: f64, n: usize) -> UnicycleProblem {
    let (q, r) = (w_x * w_x / 2.0, w_u * w_u / 2.0);
    let cost = Objective::new()
        .with_stage(StateTracking {
            goal: Vector3::zeros(),
            weights: Vector3::repeat(q),
        })
        .with_stage(ControlEffort {
            weights: Vector2::repeat(r),
        })
        .with_terminal(TerminalTracking {
            goal: Vector3::zeros(),
            weights: Vector3::repeat(q),
        });
    Problem {
        dynamics: Euler {
            model: Unicycle,
            dt,
        },
        cost,
        x0: Vector3::from(x0),
        horizon: n,
    }
}

/// Solve `problem` from zero controls with the default options, and check
/// what must hold of any converged solve: the status, that the states are
/// the rollout of the controls from `x0`, and that the cost recomputed
/// from that trajectory is the reported one. Returns the cost.
fn solve_and_check(problem: &UnicycleProblem, what: &str) -> f64 {
    let n = problem.horizon;
    let mut solver = Solver::<3, 2>::new(n);
    let summary = solver
        .solve(
            problem,
            &vec![Vector2::zeros(); n],
            &Options::default(),
            &AtomicBool::new(false),
        )
        .expect("the problem is valid");
    assert_eq!(summary.status, Status::Converged, "{what}");

    let (xs, us) = (solver.states(), solver.controls());
    assert_eq!((xs.len(), us.len()), (n + 1, n), "{what}");
    assert_eq!(xs[0], problem.x0, "{what}");
    for k in 0..n {
        let next = problem.dynamics.step(&xs[k], &us[k]);
        assert!(
            (next - xs[k + 1]).amax() <= 1e-12 * next.amax().max(1.0),
            "{what}: x_{} is not the step from x_{k} under u_{k}",
            k + 1
        );
    }
    let recomputed: f64 = (0..n)
        .map(|k| problem.cost.stage(k, &xs[k], &us[k]))
        .sum::<f64>()
        + problem.cost.terminal(&xs[n]);
    assert!(
        (recomputed - summary.cost).abs() <= 1e-12 * summary.cost.abs(),
        "{what}: reported {} but the trajectory costs {recomputed}",
        summary.cost
    );
    summary.cost
}

fn assert_matches(cost: f64, reference: f64, what: &str) {
    let rel = (cost - reference).abs() / reference.abs();
    assert!(
        rel <= 1e-6,
        "{what}: cost {cost} is {rel:e} from Crocoddyl's {reference}"
    );
}

/// Crocoddyl's defaults: `w_x = 10`, `w_u = 1`, `dt = 0.1`, from
/// `[-1, -1, 1]`, N = 100.
#[test]
fn crocoddyl_default_n100() {
    // Crocoddyl 3.x SolverDDP, bench/crocoddyl_unicycle.py (3.2.1; its
    // tight reference, th_stop 1e-20, is 250.0393199731935).
    const CROCODDYL: f64 = 250.039_319_973_200_9;
    let problem = crocoddyl_problem([-1.0, -1.0, 1.0], 10.0, 1.0, 0.1, 100);
    assert_matches(
        solve_and_check(&problem, "default, N = 100"),
        CROCODDYL,
        "default, N = 100",
    );
}

/// The same at N = 1000.
#[test]
fn crocoddyl_default_n1000() {
    // Crocoddyl 3.x SolverDDP, bench/crocoddyl_unicycle.py (3.2.1).
    const CROCODDYL: f64 = 250.157_804_932_506_05;
    let problem = crocoddyl_problem([-1.0, -1.0, 1.0], 10.0, 1.0, 0.1, 1000);
    assert_matches(
        solve_and_check(&problem, "default, N = 1000"),
        CROCODDYL,
        "default, N = 1000",
    );
}

/// Another start and weights: from `[2, −1.5, −2.5]` (heading away from
/// the goal), `w_x = 3`, `w_u = 2`, `dt = 0.1`, N = 100.
#[test]
fn crocoddyl_second_start_and_weights() {
    // Crocoddyl 3.x SolverDDP, bench/crocoddyl_unicycle.py (3.2.1).
    const CROCODDYL: f64 = 503.831_485_140_595_53;
    let problem = crocoddyl_problem([2.0, -1.5, -2.5], 3.0, 2.0, 0.1, 100);
    assert_matches(
        solve_and_check(&problem, "second, N = 100"),
        CROCODDYL,
        "second, N = 100",
    );
}

/// The goal behind: from `[0.5, 1, 0]` (the goal behind and to the
/// right), `w_x = 1`, `w_u = 0.5`, `dt = 0.05`, N = 100.
#[test]
fn crocoddyl_reverse() {
    // Crocoddyl 3.x SolverDDP, bench/crocoddyl_unicycle.py (3.2.1).
    const CROCODDYL: f64 = 24.619_626_551_187_41;
    let problem = crocoddyl_problem([0.5, 1.0, 0.0], 1.0, 0.5, 0.05, 100);
    assert_matches(
        solve_and_check(&problem, "reverse, N = 100"),
        CROCODDYL,
        "reverse, N = 100",
    );
}
