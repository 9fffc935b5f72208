//! `ilqr-service`: trajectory optimisation with iLQR, as a CLI and a
//! service over HTTP and gRPC.
//!
//! # Layout
//!
//! * [`models`]: the models offered (the planar quadrotor, the unicycle),
//!   each with its default problem; adding one is one entry there.
//! * [`problem`]: the problem document (JSON request), its per-model
//!   defaults and its validation with JSON pointers.
//! * [`solve`]: builds the core problem from a document, runs the solver from
//!   the `ilqr` crate and produces the [`solve::SolveResult`] document.
//! * [`schema`]: OpenAPI schemas utoipa cannot derive (vectors whose length
//!   is the model's, nested objects that also take null).
//! * [`service`]: the solve service every transport calls: validation,
//!   admission against the expected wait, time budgets, the worker pool,
//!   cancellation, draining and the solve metrics.
//! * [`server`]: the HTTP service (axum) over it, its errors and metrics,
//!   and the process that serves both transports.
//! * [`grpc`]: the gRPC service (tonic) over the same solve service:
//!   `proto/ilqr/v1/ilqr.proto`, with health and reflection.
//! * [`cli`]: the `ilqr-service` command line (`serve`, `solve`, `openapi`,
//!   `healthcheck`).
//!
//! The solver itself lives in the `ilqr` crate (`crates/ilqr`), which knows
//! nothing about JSON or HTTP.

pub mod cli;
pub mod grpc;
pub mod models;
pub mod problem;
pub mod schema;
pub mod server;
pub mod service;
pub mod solve;
