//! Iterative LQR (iLQR) trajectory optimisation on fixed-size nalgebra matrices.
//!
//! The crate is the pure, synchronous solver behind `ilqr-service`: no async
//! runtime, no web types, no serialisation. Everything on the hot path is a
//! const-generic `SMatrix`/`SVector`, and a [`Solver`] owns every buffer it
//! needs, so the iteration loop never touches the heap.
//!
//! # Layout
//!
//! * [`dynamics`]: the [`ContinuousDynamics`] and [`DiscreteDynamics`] traits
//!   and the integrators that turn one into the other, explicit [`Euler`]
//!   (eq. 9 of the seed paper) and [`Rk4`]; optionally the dynamics' second derivatives
//!   ([`Curvature`]) for DDP and the Jacobians' pattern of zeros
//!   ([`Sparsity`]), which the backward pass is compiled for.
//! * [`model`]: the [`Model`] trait, what a model says about itself (state
//!   and control names and units, parameters and their ranges, where its
//!   position is) so that a service can offer it without knowing it.
//! * [`quadrotor`]: the planar quadrotor of eqs. 4–6 with analytic Jacobians
//!   (eq. 11) and curvature.
//! * [`unicycle`]: the unicycle (kinematic car), `[x, y, θ]` driven by speed
//!   and turn rate.
//! * [`cost`]: the [`Cost`] trait the solver minimises, its quadratic model
//!   ([`StageExpansion`], [`TerminalExpansion`]) and the terms of eqs. 13–15
//!   ([`StateTracking`], [`ControlEffort`], [`ExpObstacle`], [`TerminalTracking`]),
//!   summed by [`Objective`].
//! * [`constraint`]: hard constraints ([`Constraint`]: [`StateBounds`],
//!   [`GoalTolerance`], [`Clearance`] from a [`Region`]) and
//!   [`ControlBounds`], which [`Solver::solve_constrained`] meets with an
//!   augmented-Lagrangian outer loop around iLQR and a box-constrained
//!   backward pass;
//! * [`search`]: where a search over the ways around obstacles starts
//!   ([`search::detours`]: a via-point on each side of each obstacle in the
//!   way, for a guiding solve with a [`ViaPath`] term).
//! * [`solver`]: the iLQR driver loop (backward pass eqs. 31–48, forward pass
//!   and line search eqs. 49–51) with Levenberg–Marquardt regularisation and,
//!   where no regularisation helps, a fall back to the cost's convex
//!   expansion ([`Cost::stage_expand_convex`]); its [`Options`], the
//!   [`Status`] that says how a solve ended and the per-iteration
//!   [`TraceRow`]. With [`Options::second_order`] the backward pass keeps
//!   the dynamics' curvature (DDP) instead of dropping it (iLQR).
//! * [`boxqp`]: a box-constrained QP, `min ½ uᵀH u + gᵀu` over
//!   `lower ≤ u ≤ upper`, by projected Newton ([`solve_box_qp`]), with the
//!   free set's factor for the clamped feedback gains
//!   ([`BoxQpSolution::feedback_gain`]): the per-knot subproblem of a
//!   control-limited (box-DDP) backward pass.
//! * `kernels` (private): the column-major small-matrix kernels the Riccati
//!   step ([`riccati_step`]) is written in.
//!
//! The algorithm in [`solver`] knows nothing about quadrotors: it sees a
//! [`DiscreteDynamics`] and a [`Cost`]. New models, integrators and cost terms
//! are new trait implementations.
//!
//! # Example
//!
//! ```
//! use ilqr::{Euler, Objective, Options, Problem, Quadrotor2D, Solver, Status};
//! use ilqr::{ControlEffort, StateTracking, TerminalTracking};
//! use nalgebra::{SVector, Vector2};
//! use std::sync::atomic::AtomicBool;
//!
//! let model = Quadrotor2D { mass: 1.0, inertia: 1.0, arm_length: 1.0, gravity: 9.81 };
//! let goal = SVector::<f64, 6>::from([0.0, 1.0, 0.0, 0.0, 0.0, 0.0]);
//! let cost = Objective::new()
//!     .with_stage(StateTracking { goal, weights: SVector::repeat(1.0) })
//!     .with_stage(ControlEffort { weights: Vector2::repeat(0.1) })
//!     .with_terminal(TerminalTracking { goal, weights: SVector::repeat(1e4) });
//! let problem = Problem { dynamics: Euler { model, dt: 0.05 }, cost, x0: SVector::zeros(), horizon: 40 };
//! let hover = vec![Vector2::repeat(9.81 / 2.0); 40];
//!
//! let mut solver = Solver::new(40);
//! let summary = solver.solve(&problem, &hover, &Options::default(), &AtomicBool::new(false)).unwrap();
//! assert_eq!(summary.status, Status::Converged);
//! assert!((solver.states()[40][1] - 1.0).abs() < 0.05);
//! ```
#![warn(missing_docs)]

pub mod boxqp;
pub mod constraint;
pub mod cost;
pub mod dynamics;
mod kernels;
pub mod model;
pub mod quadrotor;
pub mod search;
pub mod solver;
pub mod unicycle;

pub use boxqp::{BoxQpError, BoxQpOptions, BoxQpSolution, BoxQpStatus, solve_box_qp};
pub use constraint::{
    Clearance, Constraint, Constraints, ControlBounds, Distance, GoalTolerance, Knot, Rectangle,
    Region, Shape, StateBounds,
};
pub use cost::{
    ControlEffort, Cost, ExpObstacle, Objective, ShapeObstacle, StageCost, StageExpansion,
    StateTracking, TerminalCost, TerminalExpansion, TerminalTracking, ViaPath,
};
pub use dynamics::{ContinuousDynamics, Curvature, DiscreteDynamics, Euler, Rk4, Sparsity};
pub use model::{Model, Parameter, Quantity};
pub use quadrotor::Quadrotor2D;
pub use solver::{
    Options, Problem, RiccatiStep, SolveError, Solver, Status, Summary, TraceRow, Value,
    riccati_step,
};
pub use unicycle::Unicycle;
