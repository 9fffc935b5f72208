//! The `serve` command refuses settings it cannot honour before it binds,
//! with exit status 2 and a message naming the setting.

use std::process::Command;

/// Run `ilqr-service serve` on a free port with `args`; it must exit at
/// once (a valid configuration would serve forever).
fn serve_with(args: &[&str]) -> (Option<i32>, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_ilqr-service"))
        .args(["serve", "--bind", "127.0.0.1:0"])
        .args(args)
        .env_remove("ILQR_WORKERS")
        .env_remove("ILQR_MAX_HORIZON")
        .env_remove("ILQR_DEFAULT_TIME_LIMIT_MS")
        .env_remove("ILQR_MAX_TIME_LIMIT_MS")
        .output()
        .unwrap();
    (out.status.code(), String::from_utf8(out.stderr).unwrap())
}

#[test]
fn settings_out_of_range_are_rejected_before_serving() {
    for (args, says) in [
        (&["--workers", "0"][..], "--workers"),
        (
            &["--max-horizon", "0"],
            "expected an integer from 1 to 10000",
        ),
        (
            &["--max-horizon", "10001"],
            "expected an integer from 1 to 10000",
        ),
        (&["--default-time-limit-ms", "0"], "--default-time-limit-ms"),
        (&["--max-time-limit-ms", "0"], "--max-time-limit-ms"),
        (
            &["--default-time-limit-ms", "70000"],
            "--default-time-limit-ms (70000) must not exceed --max-time-limit-ms (60000)",
        ),
        (
            &["--max-time-limit-ms", "5000"],
            "--default-time-limit-ms (10000) must not exceed --max-time-limit-ms (5000)",
        ),
    ] {
        let (code, stderr) = serve_with(args);
        assert_eq!(code, Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(says), "{args:?}: {stderr}");
    }
}
