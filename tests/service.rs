//! The service's tests, one module (one file) per area, built as one test
//! binary: every test binary is linked on its own against the whole
//! server (tokio, hyper, axum, reqwest, with thin LTO), so as one binary
//! these files take about a third of the time to compile and link that
//! they would as four (92 s against 255 s on 2 cores, by `cargo test
//! --release --timings`). `cargo test --release --test service http::`
//! runs one area.
//!
//! `openapi.rs` stays a binary of its own, so that the command that
//! regenerates the spec (`UPDATE_OPENAPI=1 cargo test --release --test
//! openapi`) runs that and nothing else.

mod cli;
mod common;
mod constraints;
mod deadlines;
mod grpc;
mod http;
mod models;
mod search;
mod solve;
mod stream;
mod validation;
