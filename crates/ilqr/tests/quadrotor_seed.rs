//! Known answers and invariants on the seed scenario of the paper.

mod common;

use std::sync::atomic::AtomicBool;

use common::{OBSTACLE, SEED_OPTIMUM, goal, hover, seed_problem};
use ilqr::{Cost, DiscreteDynamics, Options, Solver, Status};
use nalgebra::{SVector, Vector2};

fn solve_seed() -> (Solver<6, 2>, ilqr::Summary) {
    let problem = seed_problem(100, 0.05);
    let mut solver = Solver::new(100);
    let summary = solver
        .solve(
            &problem,
            &hover(100),
            &Options::default(),
            &AtomicBool::new(false),
        )
        .expect("seed problem is valid");
    (solver, summary)
}

#[test]
fn seed_reaches_the_reference_optimum() {
    let (solver, s) = solve_seed();
    eprintln!("{s:?}");
    for r in solver.trace() {
        eprintln!("{r:?}");
    }
    assert_eq!(s.status, Status::Converged);
    let rel = (s.cost - SEED_OPTIMUM).abs() / SEED_OPTIMUM;
    assert!(rel < 1e-4, "cost {} is {rel:e} from {SEED_OPTIMUM}", s.cost);
}
