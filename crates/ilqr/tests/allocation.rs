//! The iteration loop does not allocate: a [`Solver`] reused for the same
//! horizon makes no heap allocation at all during `solve`, whatever the
//! number of iterations. A counting global allocator checks it.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::AtomicBool;

use ilqr::{Options, Solver, Status};

struct Counting;

thread_local! {
    /// Count only this thread's allocations: the test harness allocates on
    /// its own threads while a test runs.
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    /// And count them per thread: with one global count, the tests running
    /// at once on other threads would add their own counted allocations
    /// (the first test's deliberate Vec) to this one's window.
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

fn note() {
    if COUNTING.with(Cell::get) {
        ALLOCATIONS.with(|n| n.set(n.get() + 1));
    }
}

fn allocations() -> usize {
    ALLOCATIONS.with(Cell::get)
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note();
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations made by a second solve of `problem` on a warm solver.
fn allocations_of_a_warm_solve(
    problem: &common::Seed,
    options: &Options,
) -> (usize, ilqr::Summary) {
    let n = problem.horizon;
    let hover = common::hover(n);
    let never = AtomicBool::new(false);
    let mut solver = Solver::new(n);
    // The first solve may size the trace buffer.
    solver.solve(problem, &hover, options, &never).unwrap();

    let before = allocations();
    COUNTING.with(|c| c.set(true));
    let s = solver.solve(problem, &hover, options, &never).unwrap();
    COUNTING.with(|c| c.set(false));
    (allocations() - before, s)
}

#[test]
fn a_warm_solver_solves_without_allocating() {
    let (during, s) =
        allocations_of_a_warm_solve(&common::seed_problem(100, 0.05), &Options::default());
    assert_eq!(s.status, Status::Converged);
    assert!(s.iterations > 5);
    // The counter works: the same thread counted while building a Vec.
    COUNTING.with(|c| c.set(true));
    let v = std::hint::black_box(vec![1u8; 64]);
    COUNTING.with(|c| c.set(false));
    drop(v);
    assert_eq!(allocations(), during + 1);
    assert_eq!(
        during, 0,
        "{during} allocations in a {}-iteration solve",
        s.iterations
    );
}

/// Nor with the dynamics' curvature in the backward pass (DDP).
#[test]
fn a_second_order_solve_does_not_allocate() {
    let options = Options {
        second_order: true,
        ..Options::default()
    };
    let (during, s) = allocations_of_a_warm_solve(&common::seed_problem(100, 0.05), &options);
    assert_eq!(s.status, Status::Converged);
    assert!(s.iterations > 5);
    assert_eq!(during, 0, "{during} allocations");
}

/// The other paths of the loop do not allocate either: the convex
/// fallback and the exact Hessian's check of the convex minimum (the seed
/// at dt = 10 with a 1e12 obstacle added on its own), and the
/// least-regularised gains recomputed at the end (the seed with a zero
/// tolerance, which also falls back, and ends on failed line searches).
#[test]
fn the_fallback_and_the_final_gains_do_not_allocate() {
    let mut steep = common::seed_problem(100, 10.0);
    steep.cost = steep.cost.with_stage(ilqr::ExpObstacle {
        center: nalgebra::Vector2::from(common::OBSTACLE),
        weight: 1e12,
        position: (0, 1),
    });
    let (during, s) = allocations_of_a_warm_solve(&steep, &Options::default());
    assert_eq!(
        (s.status, s.convexified_after, s.gains_convex),
        (Status::Converged, Some(0), false),
        "{s:?}"
    );
    assert_eq!(during, 0, "{during} allocations: {s:?}");

    let exhaustive = Options {
        tolerance: 0.0,
        ..Options::default()
    };
    let (during, s) = allocations_of_a_warm_solve(&common::seed_problem(100, 0.05), &exhaustive);
    assert_eq!(s.status, Status::NoProgress, "{s:?}");
    assert!(
        s.convexified_after.is_some() && s.gains_regularization == 0.0,
        "{s:?}"
    );
    assert_eq!(during, 0, "{during} allocations: {s:?}");
}

/// A constrained solve's loops allocate nothing either: a warm solve of
/// the seed with thrust bounds (box-DDP, no outer loop) allocates nothing
/// at all, and the Dubins car's augmented Lagrangian (a dozen outer iterations)
/// nothing between its first iteration and its last, multiplier updates
/// included. Its final projection, after the loop, does allocate.
#[test]
fn a_constrained_solve_does_not_allocate_in_its_loops() {
    use ilqr::{Constraints, ControlBounds};
    use nalgebra::SVector;
    let never = AtomicBool::new(false);
    let options = Options::default();

    let seed = common::seed_problem(100, 0.05);
    let bounds = Constraints {
        control: Some(ControlBounds {
            lower: SVector::from([0.0, 0.0]),
            upper: SVector::from([20.0, 20.0]),
        }),
        other: Vec::new(),
    };
    let hover = common::hover(100);
    let mut solver = Solver::new(100);
    let warm = |solver: &mut Solver<6, 2>| {
        solver
            .solve_constrained(&seed, &bounds, &hover, &options, &never, &mut |_| {})
            .unwrap()
    };
    warm(&mut solver);
    let before = allocations();
    COUNTING.with(|c| c.set(true));
    let s = warm(&mut solver);
    COUNTING.with(|c| c.set(false));
    assert_eq!(s.status, Status::Converged, "{s:?}");
    assert_eq!(allocations() - before, 0, "{s:?}");

    let (dubins, constraints) = common::dubins();
    let start = vec![SVector::<f64, 2>::repeat(0.01); 100];
    let mut solver = Solver::new(100);
    let run = |solver: &mut Solver<3, 2>, seen: &mut Vec<usize>| {
        solver
            .solve_constrained(&dubins, &constraints, &start, &options, &never, &mut |_| {
                seen.push(allocations())
            })
            .unwrap()
    };
    // Room for every row, so that recording one allocates nothing.
    let mut seen = Vec::with_capacity(10_000);
    run(&mut solver, &mut seen);
    seen.clear();
    COUNTING.with(|c| c.set(true));
    let s = run(&mut solver, &mut seen);
    COUNTING.with(|c| c.set(false));
    assert_eq!(s.status, Status::Converged, "{s:?}");
    assert!(s.outer_iterations > 3 && seen.len() > 20, "{s:?}");
    let (first, last) = (seen[0], seen[seen.len() - 1]);
    assert_eq!(last - first, 0, "{s:?}");
}

/// The box-constrained QP and its feedback gain allocate nothing, on a
/// problem with a control clamped at each bound and one free.
#[test]
fn a_box_qp_solve_does_not_allocate() {
    use ilqr::{BoxQpOptions, BoxQpStatus, solve_box_qp};
    use nalgebra::{SMatrix, SVector};

    let h = SMatrix::<f64, 3, 3>::new(4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0);
    let g = SVector::<f64, 3>::new(10.0, -10.0, 0.1);
    let lower = SVector::<f64, 3>::new(-1.0, -1.0, f64::NEG_INFINITY);
    let upper = SVector::<f64, 3>::new(1.0, 1.0, f64::INFINITY);
    let q_ux = SMatrix::<f64, 3, 6>::repeat(1.0);
    let options = BoxQpOptions::default();

    let before = allocations();
    COUNTING.with(|c| c.set(true));
    let s = solve_box_qp(&h, &g, &lower, &upper, &SVector::zeros(), &options);
    let k = s.as_ref().ok().and_then(|s| s.feedback_gain(&q_ux));
    COUNTING.with(|c| c.set(false));
    let during = allocations() - before;

    let s = s.unwrap();
    assert_eq!(s.status, BoxQpStatus::Converged);
    assert_eq!(s.free, [false, false, true]);
    assert!(s.iterations >= 1);
    assert!(k.is_some());
    assert_eq!(during, 0, "{during} allocations");
}
