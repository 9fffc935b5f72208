//! The iteration loop does not allocate: a [`Solver`] reused for the same
//! horizon makes no heap allocation at all during `solve`, whatever the
//! number of iterations. A counting global allocator checks it.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use ilqr::{Options, Solver, Status};

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    /// Count only this thread's allocations: the test harness allocates on
    /// its own threads while a test runs.
    static COUNTING: Cell<bool> = const { Cell::new(false) };
}

fn note() {
    if COUNTING.with(Cell::get) {
        ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
    }
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

#[test]
fn a_warm_solver_solves_without_allocating() {
    let problem = common::seed_problem(100, 0.05);
    let hover = common::hover(100);
    let options = Options::default();
    let never = AtomicBool::new(false);
    let mut solver = Solver::new(100);
    // The first solve may size the trace buffer.
    solver.solve(&problem, &hover, &options, &never).unwrap();

    COUNTING.with(|c| c.set(true));
    let s = solver.solve(&problem, &hover, &options, &never).unwrap();
    COUNTING.with(|c| c.set(false));
    let during = ALLOCATIONS.load(Ordering::SeqCst);

    assert_eq!(s.status, Status::Converged);
    assert!(s.iterations > 5);
    // The counter works: the same thread counted while building a Vec.
    COUNTING.with(|c| c.set(true));
    let v = std::hint::black_box(vec![1u8; 64]);
    COUNTING.with(|c| c.set(false));
    drop(v);
    assert_eq!(ALLOCATIONS.load(Ordering::SeqCst), during + 1);
    assert_eq!(
        during, 0,
        "{during} allocations in a {}-iteration solve",
        s.iterations
    );
}
