//! The service's tests, one module (one file) per area, built as one test
//! binary: every test binary is linked on its own against the whole
//! server (tokio, hyper, axum, reqwest, with thin LTO): as four binaries
//! these files took 255 s of compiling and linking, as one they take 92 s
//! (`cargo test --release --timings`, 2026-12-01). `cargo test --release
//! --test service http::` runs one area.
//!
//! `openapi.rs` stays a binary of its own, so that the command that
//! regenerates the spec (`UPDATE_OPENAPI=1 cargo test --release --test
//! openapi`) runs that and nothing else.

mod cli;
mod http;
mod models;
mod solve;
mod validation;
