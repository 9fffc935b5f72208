//! The solver's tests, one module (one file) per problem family, built as
//! one test binary: every test binary is compiled and linked on its own,
//! and as one binary these files take well under half the time to compile
//! and link that they would as six (49 s against 119 s on 2 cores, by
//! `cargo test --release --timings`). `cargo test --release -p ilqr --test
//! suite riccati::` runs one family.
//!
//! `allocation.rs` stays a binary of its own: it installs a counting
//! global allocator, which would count the other families' allocations.

mod boxqp;
mod common;
mod constraints;
mod derivatives;
mod integrators;
mod interruption;
mod linear_quadratic;
mod optimality;
mod quadrotor_seed;
mod riccati;
mod unicycle;
mod warm_start;
