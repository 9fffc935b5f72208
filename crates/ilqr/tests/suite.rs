//! The solver's tests, one module (one file) per problem family, built as
//! one test binary: every test binary is compiled and linked on its own,
//! and as six binaries these files took 119 s of compiling and linking
//! where as one they take 49 s (`cargo test --release --timings`,
//! 2026-12-01). `cargo test --release -p ilqr --test suite riccati::` runs
//! one family.
//!
//! `allocation.rs` stays a binary of its own: it installs a counting
//! global allocator, which would count the other families' allocations.

mod common;
mod derivatives;
mod integrators;
mod interruption;
mod linear_quadratic;
mod optimality;
mod quadrotor_seed;
mod riccati;
mod unicycle;
mod warm_start;
