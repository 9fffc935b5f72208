//! The seed scenario of the paper, built directly on the core crate, shared
//! by the integration tests and benchmarks.
#![allow(dead_code)]

use ilqr::{
    ControlEffort, Euler, ExpObstacle, Objective, Problem, Quadrotor2D, StateTracking,
    TerminalTracking,
};
use nalgebra::{SVector, Vector2};

pub type Seed = Problem<Euler<Quadrotor2D>, Objective<6, 2>, 6>;

/// Cost that two independent solvers (IPOPT on a direct transcription and a
/// plain reference iLQR) reach on the seed problem.
pub const SEED_OPTIMUM: f64 = 5520.212;

pub const MODEL: Quadrotor2D = Quadrotor2D {
    mass: 1.0,
    inertia: 1.0,
    arm_length: 1.0,
    gravity: 9.81,
};

pub fn goal() -> SVector<f64, 6> {
    SVector::from([4.0, 9.0, 0.0, 0.0, 0.0, 0.0])
}

pub const OBSTACLE: [f64; 2] = [4.5, 4.5];

/// The seed problem with horizon `n` and step `dt`.
pub fn seed_problem(n: usize, dt: f64) -> Seed {
    let cost = Objective::new()
        .with_stage(StateTracking {
            goal: goal(),
            weights: SVector::repeat(1.0),
        })
        .with_stage(ControlEffort {
            weights: Vector2::repeat(0.1),
        })
        .with_stage(ExpObstacle {
            center: Vector2::from(OBSTACLE),
            weight: 1000.0,
            position: (0, 1),
        })
        .with_terminal(TerminalTracking {
            goal: goal(),
            weights: SVector::repeat(50000.0),
        });
    Problem {
        dynamics: Euler { model: MODEL, dt },
        cost,
        x0: SVector::from([5.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
        horizon: n,
    }
}

/// Hover thrust on both rotors for `n` steps.
pub fn hover(n: usize) -> Vec<Vector2<f64>> {
    vec![Vector2::repeat(MODEL.hover_thrust()); n]
}
