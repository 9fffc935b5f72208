//! The seed scenario of the paper and ALTRO's three-obstacle Dubins car,
//! built directly on the core crate, shared by the integration tests and
//! benchmarks, and the tests' random generator.
#![allow(dead_code)]

use ilqr::{
    Clearance, Constraint, Constraints, ControlBounds, ControlEffort, Euler, ExpObstacle,
    GoalTolerance, Objective, Problem, Quadrotor2D, Region, Rk4, Shape, StateTracking,
    TerminalTracking, Unicycle,
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

/// A small deterministic generator, so that the random problems are the
/// same on every run and a failure names a seed one can rerun.
pub struct Lcg(pub u64);

impl Lcg {
    pub fn unit(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
    pub fn vector<const N: usize>(&mut self, lo: f64, hi: f64) -> SVector<f64, N> {
        SVector::from_fn(|_, _| self.range(lo, hi))
    }
}

/// ALTRO's three-obstacle Dubins car (Altro.jl `problems/dubins_car.jl`).
pub fn dubins() -> (
    Problem<Rk4<Unicycle>, Objective<3, 2>, 3>,
    Constraints<3, 2>,
) {
    let goal = SVector::from([3.0, 3.0, 0.0]);
    let cost = Objective::new()
        .with_stage(StateTracking {
            goal,
            weights: SVector::repeat(1.0),
        })
        .with_stage(ControlEffort {
            weights: Vector2::repeat(0.5),
        })
        .with_terminal(TerminalTracking {
            goal,
            weights: SVector::repeat(10.0),
        });
    let problem = Problem {
        dynamics: Rk4 {
            model: Unicycle,
            dt: 0.05,
        },
        cost,
        x0: SVector::zeros(),
        horizon: 100,
    };
    let mut other: Vec<Box<dyn Constraint<3, 2>>> = Vec::new();
    for c in [0.75, 1.5, 2.25] {
        other.push(Box::new(Clearance {
            region: Region {
                center: Vector2::new(c, c),
                shape: Shape::Circle { radius: 0.425 },
            },
            clearance: 0.0,
            position: (0, 1),
        }));
    }
    other.push(Box::new(GoalTolerance::new(goal, &SVector::zeros())));
    let constraints = Constraints {
        control: Some(ControlBounds {
            lower: SVector::from([0.0, -3.0]),
            upper: SVector::from([3.0, 3.0]),
        }),
        other,
    };
    (problem, constraints)
}
