//! Solver benchmarks (divan).
//!
//! ```text
//! cargo bench -p ilqr --bench solver            # everything
//! cargo bench -p ilqr --bench solver -- seed    # only the seed solves
//! ```
//!
//! * `seed_solve::reused_solver`: the seed problem of the paper (N = 100,
//!   dt = 0.05, hover start) solved to convergence by one `Solver` kept
//!   across iterations, so its workspace is warm and nothing is allocated.
//! * `seed_solve::new_solver`: the same, constructing a fresh `Solver` every
//!   time (what the service does per request).
//! * `long_horizon::n1000`: the same scenario with N = 1000 at dt = 0.005
//!   (same 5 s horizon, ten times the knots).
//! * `backward::riccati_step_one_knot`: one knot of the backward pass on
//!   realistic inputs (the seed problem linearised at hover at `x0`, the
//!   value function of the terminal cost there), compiled for the
//!   quadrotor's stated `Sparsity` as the solver is;
//!   `riccati_step_one_knot_zeros_tested` the same for a model that states
//!   none (every entry of `A` and `B` tested for zero at run time).
//! * `backward::full_pass_n100`: the first backward pass of the seed solve,
//!   100 `riccati_step`s along the hover rollout, through the public API.
//!
//! * `constrained::dubins_three_obstacles`: ALTRO's three-obstacle Dubins
//!   car (unicycle, RK4, N = 100, three hard circles, speed and turn-rate
//!   bounds, the goal as an equality) solved from controls of 0.01 by the
//!   augmented Lagrangian with box-DDP, one `Solver` reused.
//!
//! `AllocProfiler` is the global allocator, so each row also reports the
//! allocations made per iteration.

use std::sync::atomic::AtomicBool;

use divan::{AllocProfiler, Bencher, black_box};
use ilqr::{
    Cost, DiscreteDynamics, Euler, Options, Quadrotor2D, Solver, Sparsity, StageExpansion,
    TerminalExpansion, Value, riccati_step,
};
use nalgebra::{SMatrix, SVector};

#[path = "../tests/common/mod.rs"]
mod common;

use common::{dubins, hover, seed_problem};

#[global_allocator]
static ALLOC: AllocProfiler = AllocProfiler::system();

fn main() {
    divan::main();
}

mod constrained {
    use super::*;

    #[divan::bench]
    fn dubins_three_obstacles(bencher: Bencher) {
        let (problem, constraints) = dubins();
        let u = vec![SVector::<f64, 2>::repeat(0.01); 100];
        let options = Options::default();
        let cancel = AtomicBool::new(false);
        let mut solver = Solver::<3, 2>::new(100);
        bencher.bench_local(|| {
            solver
                .solve_constrained(
                    black_box(&problem),
                    &constraints,
                    &u,
                    &options,
                    &cancel,
                    &mut |_| {},
                )
                .unwrap()
        });
    }
}

mod seed_solve {
    use super::*;

    /// One `Solver` reused across iterations: the warm-workspace cost of a
    /// seed solve (no allocation at all).
    #[divan::bench]
    fn reused_solver(bencher: Bencher) {
        let problem = seed_problem(100, 0.05);
        let u = hover(100);
        let options = Options::default();
        let cancel = AtomicBool::new(false);
        let mut solver = Solver::<6, 2>::new(100);
        bencher.bench_local(|| {
            solver
                .solve(black_box(&problem), black_box(&u), &options, &cancel)
                .expect("the seed problem is valid")
                .cost
        });
    }

    /// A new `Solver` per solve, as the service does per request.
    #[divan::bench]
    fn new_solver(bencher: Bencher) {
        let problem = seed_problem(100, 0.05);
        let u = hover(100);
        let options = Options::default();
        let cancel = AtomicBool::new(false);
        bencher.bench_local(|| {
            let mut solver = Solver::<6, 2>::new(black_box(100));
            solver
                .solve(black_box(&problem), black_box(&u), &options, &cancel)
                .expect("the seed problem is valid")
                .cost
        });
    }
}

mod long_horizon {
    use super::*;

    /// N = 1000 at dt = 0.005 (same 5 s horizon), reused solver.
    #[divan::bench(sample_count = 20)]
    fn n1000(bencher: Bencher) {
        let problem = seed_problem(1000, 0.005);
        let u = hover(1000);
        let options = Options::default();
        let cancel = AtomicBool::new(false);
        let mut solver = Solver::<6, 2>::new(1000);
        bencher.bench_local(|| {
            solver
                .solve(black_box(&problem), black_box(&u), &options, &cancel)
                .expect("the N = 1000 problem is valid")
                .cost
        });
    }
}

#[allow(non_snake_case)]
mod backward {
    use super::*;

    type Knot = (SMatrix<f64, 6, 6>, SMatrix<f64, 6, 2>, StageExpansion<6, 2>);

    /// The seed model's pattern, as the solver passes it.
    const SPARSITY: Option<&Sparsity<6, 2>> =
        <Euler<Quadrotor2D> as DiscreteDynamics<6, 2>>::SPARSITY.as_ref();

    /// `(A_k, B_k, l_k)` along the rollout of hover thrust from `x0`, and the
    /// terminal value function at its end: the inputs of the first backward
    /// pass of the seed solve.
    fn hover_rollout(n: usize) -> (Vec<Knot>, Value<6>) {
        let problem = seed_problem(n, 0.05);
        let us = hover(n);
        let mut x = problem.x0;
        let mut knots = Vec::with_capacity(n);
        for (k, u) in us.iter().enumerate() {
            let (A, B) = problem.dynamics.linearize(&x, u);
            let mut l = StageExpansion::zeros();
            problem.cost.stage_expand(k, &x, u, &mut l);
            knots.push((A, B, l));
            x = problem.dynamics.step(&x, u);
        }
        let mut t = TerminalExpansion::zeros();
        problem.cost.terminal_expand(&x, &mut t);
        (
            knots,
            Value {
                V_x: t.l_x,
                V_xx: t.l_xx,
            },
        )
    }

    /// One knot: the seed problem linearised at hover at `x0`, with the value
    /// function of the terminal cost at `x0`, μ = 0.
    #[divan::bench]
    fn riccati_step_one_knot(bencher: Bencher) {
        one_knot::<true>(bencher);
    }

    /// The same knot for a model that states no pattern.
    #[divan::bench]
    fn riccati_step_one_knot_zeros_tested(bencher: Bencher) {
        one_knot::<false>(bencher);
    }

    /// With the pattern when `STATED`. Named in the call itself, so that it
    /// is a constant there, as in the solver: held in a variable the closure
    /// captures, it would be read at run time (as many instructions per
    /// knot as without a pattern, `valgrind --tool=callgrind`).
    fn one_knot<const STATED: bool>(bencher: Bencher) {
        let problem = seed_problem(100, 0.05);
        let x = problem.x0;
        let u = hover(1)[0];
        let (A, B) = problem.dynamics.linearize(&x, &u);
        let mut l = StageExpansion::zeros();
        problem.cost.stage_expand(0, &x, &u, &mut l);
        let mut t = TerminalExpansion::zeros();
        problem.cost.terminal_expand(&x, &mut t);
        let value = Value {
            V_x: t.l_x,
            V_xx: t.l_xx,
        };
        assert!(riccati_step(&A, &B, &l, &value, 0.0, SPARSITY).is_some());
        bencher.bench_local(|| {
            let (A, B, l, value, mu) = (
                black_box(&A),
                black_box(&B),
                black_box(&l),
                black_box(&value),
                black_box(0.0),
            );
            if STATED {
                riccati_step(A, B, l, value, mu, SPARSITY)
            } else {
                riccati_step(A, B, l, value, mu, None)
            }
        });
    }

    /// A whole backward pass over N = 100 knots (the first one of the seed
    /// solve, along the hover rollout), via `riccati_step` in a loop.
    #[divan::bench]
    fn full_pass_n100(bencher: Bencher) {
        let (knots, terminal) = hover_rollout(100);
        let mut K = vec![SMatrix::<f64, 2, 6>::zeros(); 100];
        let mut d = vec![SVector::<f64, 2>::zeros(); 100];
        bencher.bench_local(|| {
            let mut value = *black_box(&terminal);
            let (mut dv1, mut dv2) = (0.0, 0.0);
            for (k, (A, B, l)) in black_box(&knots).iter().enumerate().rev() {
                let step = riccati_step(A, B, l, &value, black_box(0.0), SPARSITY)
                    .expect("Q_uu is positive definite along the hover rollout");
                K[k] = step.K;
                d[k] = step.d;
                dv1 += step.dv1;
                dv2 += step.dv2;
                value = step.value;
            }
            black_box((&K, &d));
            (dv1, dv2, value)
        });
    }
}
