//! `ilqr-service`: trajectory optimisation with iLQR for the planar
//! quadrotor, as a CLI and an HTTP service.
//!
//! # Layout
//!
//! * [`problem`]: the problem document (JSON request), its seed-scenario
//!   defaults and its validation with JSON pointers.
//! * [`solve`]: builds the core problem from a document, runs the solver from
//!   the `ilqr` crate and produces the [`solve::SolveResult`] document.
//! * [`schema`]: OpenAPI schemas utoipa cannot derive (nested fixed arrays).
//! * [`server`]: the HTTP service (axum), its worker pool, errors and metrics.
//! * [`cli`]: the `ilqr-service` command line (`serve`, `solve`, `openapi`,
//!   `healthcheck`).
//!
//! The solver itself lives in the `ilqr` crate (`crates/ilqr`), which knows
//! nothing about JSON or HTTP.

pub mod cli;
pub mod problem;
pub mod schema;
pub mod server;
pub mod solve;
