//! The iteration loop does not allocate: a [`Solver`] reused for the same
//! horizon makes no heap allocation at all during `solve`, whatever the
//! number of iterations. A counting global allocator checks it.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use ilqr::{Options, Solver, Status};

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn a_warm_solver_solves_without_allocating() {
    let problem = common::seed_problem(100, 0.05);
    let hover = common::hover(100);
    let options = Options::default();
    let never = AtomicBool::new(false);
    let mut solver = Solver::new(100);
    // The first solve may size the trace buffer.
    solver.solve(&problem, &hover, &options, &never).unwrap();

    let before = ALLOCATIONS.load(Ordering::SeqCst);
    let s = solver.solve(&problem, &hover, &options, &never).unwrap();
    let during = ALLOCATIONS.load(Ordering::SeqCst) - before;

    assert_eq!(s.status, Status::Converged);
    assert!(s.iterations > 5);
    assert_eq!(
        during, 0,
        "{during} allocations in a {}-iteration solve",
        s.iterations
    );
}
