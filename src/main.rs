//! The `ilqr-service` binary: a thin shell over [`ilqr_service::cli`].

fn main() -> std::process::ExitCode {
    ilqr_service::cli::main()
}
