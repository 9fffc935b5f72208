//! Generates the gRPC server and client code of `proto/ilqr/v1/ilqr.proto`
//! at build time, with protox (a protobuf compiler in Rust, so no `protoc`
//! needs to be installed), and writes the compiled descriptors for server
//! reflection.

use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!("cargo:rerun-if-changed=proto");
    let mut compiler = protox::Compiler::new(["proto"])?;
    compiler
        // Comments too, so that reflection clients (grpcurl describe,
        // grpcui) show the contract's documentation.
        .include_source_info(true)
        .include_imports(true)
        .open_files(["ilqr/v1/ilqr.proto"])?;
    let out = PathBuf::from(std::env::var_os("OUT_DIR").ok_or("OUT_DIR is not set")?);
    std::fs::write(
        out.join("ilqr_v1_descriptor.bin"),
        compiler.encode_file_descriptor_set(),
    )?;
    tonic_prost_build::configure()
        .build_server(true)
        // The client (without `connect`, which needs tonic's transport):
        // for tests and Rust callers that bring their own channel.
        .build_client(true)
        .build_transport(false)
        // Model parameters in name order, so that their errors come in the
        // same order on every call.
        .btree_map(".")
        .compile_fds(compiler.file_descriptor_set())?;
    Ok(())
}
