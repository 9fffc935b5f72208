//! Warm starts from a reference optimum: the seed problem (dt 0.05,
//! N 100) discretised with RK4 and, as a control, with Euler, solved by
//! IPOPT on a direct transcription of the same step
//! (`bench/casadi_ipopt.py`), its optimal controls (in `fixtures/`) given
//! to this solver as the initial guess.
//! A solver that agrees with IPOPT's optimum stays at its cost and
//! converges in a few iterations; one whose model of the dynamics differs
//! from the transcription's (an RK4 step that is not the same RK4 step)
//! would move away.
//!
//! The fixtures were written by
//!
//! ```text
//! .venv-bench/bin/python bench/casadi_ipopt.py --integrator rk4 \
//!     --controls-out crates/ilqr/tests/fixtures/seed_rk4_ipopt_controls.json
//! .venv-bench/bin/python bench/casadi_ipopt.py \
//!     --controls-out crates/ilqr/tests/fixtures/seed_euler_ipopt_controls.json
//! ```
//!
//! (CasADi 3.8.2, IPOPT tol 1e-10, from hover), each IPOPT's controls
//! with the cost of their exact rollout.

use crate::common;

use std::sync::atomic::AtomicBool;

use common::{MODEL, hover, seed_problem};
use ilqr::{Objective, Options, Problem, Rk4, Solver, Status, Summary};
use nalgebra::Vector2;

/// IPOPT's optimum of the seed under RK4 (dt 0.05, N 100) from hover,
/// the cost of the RK4 rollout of its controls: Solve_Succeeded in 20
/// iterations (CasADi 3.8.2, `bench/casadi_ipopt.py --integrator rk4`).
const IPOPT_RK4: f64 = 5_794.729_720_760_789;

/// The same under Euler, 13 iterations (`bench/casadi_ipopt.py`): the
/// seed's reference 5520.212 (`common::SEED_OPTIMUM`).
const IPOPT_EULER: f64 = 5_520.212_264_238_658_5;

/// The seed with the RK4 step in place of Euler.
fn seed_rk4() -> Problem<Rk4<ilqr::Quadrotor2D>, Objective<6, 2>, 6> {
    let seed = seed_problem(100, 0.05);
    Problem {
        dynamics: Rk4 {
            model: MODEL,
            dt: seed.dynamics.dt,
        },
        cost: seed.cost,
        x0: seed.x0,
        horizon: seed.horizon,
    }
}

/// The seed's options in the service: every term is non-negative.
fn options() -> Options {
    Options {
        cost_lower_bound: Some(0.0),
        ..Options::default()
    }
}

/// The `"initial_controls"` rows of a fixture written by
/// `casadi_ipopt.py --controls-out` (a JSON array of `[u1, u2]` pairs; the
/// rest of the object is not read).
fn fixture_controls(json: &str) -> Vec<Vector2<f64>> {
    let start = json
        .find("\"initial_controls\"")
        .expect("the fixture has initial_controls");
    let body = &json[start..];
    let open = body.find("[[").expect("an array of pairs");
    let close = body.find("]]").expect("an array of pairs");
    body[open + 2..close]
        .split("], [")
        .map(|pair| {
            let u: Vec<f64> = pair
                .split(',')
                .map(|v| v.trim().parse().expect("a number"))
                .collect();
            assert_eq!(u.len(), 2, "a pair: {pair}");
            Vector2::new(u[0], u[1])
        })
        .collect()
}

fn solve<D: ilqr::DiscreteDynamics<6, 2>>(
    problem: &Problem<D, Objective<6, 2>, 6>,
    us: &[Vector2<f64>],
) -> (Solver<6, 2>, Summary) {
    let mut solver = Solver::new(problem.horizon);
    let summary = solver
        .solve(problem, us, &options(), &AtomicBool::new(false))
        .expect("the problem is valid");
    (solver, summary)
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs()
}

#[test]
fn the_fixtures_parse_to_a_hundred_pairs() {
    for json in [
        include_str!("fixtures/seed_rk4_ipopt_controls.json"),
        include_str!("fixtures/seed_euler_ipopt_controls.json"),
    ] {
        let us = fixture_controls(json);
        assert_eq!(us.len(), 100);
        assert!(us.iter().all(|u| u.iter().all(|v| v.is_finite())));
    }
}

/// An RK4 solve warm-started with IPOPT's RK4 optimum stays at its cost to
/// 1e-7 and converges in a few iterations. It takes none: the first
/// backward pass about IPOPT's trajectory already predicts no gain worth a
/// step.
#[test]
fn rk4_from_ipopts_rk4_optimum_stays_there() {
    let problem = seed_rk4();
    let us = fixture_controls(include_str!("fixtures/seed_rk4_ipopt_controls.json"));
    let (_, s) = solve(&problem, &us);
    // The rollout of IPOPT's controls costs here what it costs in NumPy:
    // the two RK4 steps are the same step.
    assert!(
        rel(s.initial_cost, IPOPT_RK4) <= 1e-12,
        "the rollout costs {} here, {IPOPT_RK4} in NumPy",
        s.initial_cost
    );
    assert_eq!(s.status, Status::Converged);
    assert!(s.iterations <= 5, "{} iterations", s.iterations);
    assert!(
        rel(s.cost, IPOPT_RK4) <= 1e-7,
        "cost {} is {:e} from IPOPT's {IPOPT_RK4}",
        s.cost,
        rel(s.cost, IPOPT_RK4)
    );
}

/// From the same start, hover, the two solvers reach different local
/// optima of the RK4 problem: IPOPT 5794.73 (2.69 m from the obstacle at
/// its closest), iLQR 6.9% lower, passing at 2.98 m. iLQR's is a local
/// optimum of IPOPT's NLP too: IPOPT started from iLQR's controls stays
/// there (2 iterations, to the cost below).
#[test]
fn rk4_from_hover_reaches_a_lower_optimum_than_ipopt_from_hover() {
    // bench/casadi_ipopt.py --integrator rk4 with "initial_controls" the
    // controls of this solve.
    const IPOPT_FROM_ILQR: f64 = 5_394.028_735_563_595;
    let (_, s) = solve(&seed_rk4(), &hover(100));
    assert_eq!(s.status, Status::Converged);
    assert!(
        rel(s.cost, IPOPT_FROM_ILQR) <= 1e-7,
        "cost {} is {:e} from {IPOPT_FROM_ILQR}",
        s.cost,
        rel(s.cost, IPOPT_FROM_ILQR)
    );
    assert!(s.cost < 0.95 * IPOPT_RK4, "{}", s.cost);
}

/// The control: the same under Euler. Warm-started with IPOPT's Euler
/// optimum, iLQR stays there (no iteration either); from hover both
/// solvers reach that optimum.
#[test]
fn euler_from_ipopts_euler_optimum_stays_there_and_hover_reaches_it() {
    let problem = seed_problem(100, 0.05);
    let us = fixture_controls(include_str!("fixtures/seed_euler_ipopt_controls.json"));
    let (_, s) = solve(&problem, &us);
    assert!(
        rel(s.initial_cost, IPOPT_EULER) <= 1e-12,
        "the rollout costs {} here, {IPOPT_EULER} in NumPy",
        s.initial_cost
    );
    assert_eq!(s.status, Status::Converged);
    assert!(s.iterations <= 5, "{} iterations", s.iterations);
    assert!(
        rel(s.cost, IPOPT_EULER) <= 1e-7,
        "cost {} is {:e} from IPOPT's {IPOPT_EULER}",
        s.cost,
        rel(s.cost, IPOPT_EULER)
    );

    let (_, h) = solve(&problem, &hover(100));
    assert_eq!(h.status, Status::Converged);
    assert!(
        rel(h.cost, IPOPT_EULER) <= 1e-7,
        "from hover: cost {} is {:e} from IPOPT's {IPOPT_EULER}",
        h.cost,
        rel(h.cost, IPOPT_EULER)
    );
}
