//! The command line around the server: `serve` refuses settings it cannot
//! honour before it binds (exit status 2, the setting named), and
//! `healthcheck` answers for the service it is pointed at.

use std::process::Command;

/// Run `ilqr-service serve` on a free port with `args`; it must exit at
/// once. A configuration it wrongly accepts would serve forever, so after
/// 10 s the child is killed and the test fails rather than hangs.
fn serve_with(args: &[&str]) -> (Option<i32>, String) {
    use std::io::Read;
    let mut child = Command::new(env!("CARGO_BIN_EXE_ilqr-service"))
        .args(["serve", "--bind", "127.0.0.1:0"])
        .args(args)
        .env_remove("ILQR_WORKERS")
        .env_remove("ILQR_MAX_HORIZON")
        .env_remove("ILQR_DEFAULT_TIME_LIMIT_MS")
        .env_remove("ILQR_MAX_TIME_LIMIT_MS")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let started = std::time::Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if started.elapsed() > std::time::Duration::from_secs(10) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("serve {args:?} was accepted: still serving after 10 s");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    let mut stderr = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    (status.code(), stderr)
}

/// A port that is taken is an error that names the port and how to pick
/// another (the default 8080 is often taken on a developer's machine),
/// with exit status 1, at once.
#[test]
fn a_taken_port_names_the_flag_that_moves_the_service() {
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let bind = taken.local_addr().unwrap().to_string();
    let out = Command::new(env!("CARGO_BIN_EXE_ilqr-service"))
        .args(["serve", "--bind", &bind, "--workers", "1"])
        .stdout(std::process::Stdio::null())
        .output()
        .unwrap();
    let stderr = String::from_utf8(out.stderr).unwrap();
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.starts_with(&format!("error: cannot listen on {bind}: address in use (")),
        "{stderr}"
    );
    assert!(
        stderr.ends_with("; pick another with --bind HOST:PORT (or ILQR_BIND)\n"),
        "{stderr}"
    );
    drop(taken);
}

/// A `--grpc-bind` port that is taken is an error as `--bind`'s is, naming
/// its own flag, with exit status 1, at once.
#[test]
fn a_taken_grpc_port_names_its_flag() {
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let grpc = taken.local_addr().unwrap().to_string();
    let out = Command::new(env!("CARGO_BIN_EXE_ilqr-service"))
        .args(["serve", "--bind", "127.0.0.1:0", "--grpc-bind", &grpc])
        .args(["--workers", "1"])
        .stdout(std::process::Stdio::null())
        .output()
        .unwrap();
    let stderr = String::from_utf8(out.stderr).unwrap();
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.starts_with(&format!("error: cannot listen on {grpc}: address in use (")),
        "{stderr}"
    );
    assert!(
        stderr.ends_with("; pick another with --grpc-bind HOST:PORT (or ILQR_GRPC_BIND)\n"),
        "{stderr}"
    );
    drop(taken);
}

/// The binary serves gRPC at `--grpc-bind` beside HTTP: health says
/// SERVING, a solve and the model list answer; SIGTERM then ends it at
/// once (nothing in flight) with status 0.
#[test]
fn the_binary_serves_grpc_beside_http() {
    use ilqr_service::grpc::proto;
    use ilqr_service::grpc::proto::trajectory_optimizer_client::TrajectoryOptimizerClient;
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::{HealthCheckRequest, health_client::HealthClient};
    let grpc = format!("127.0.0.1:{}", free_port());
    let (mut server, _) = serve_on_free_port(|cmd, bind| {
        cmd.args([
            "serve",
            "--bind",
            bind,
            "--grpc-bind",
            &grpc,
            "--workers",
            "1",
        ])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null());
    });
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    runtime.block_on(async {
        let channel = tonic::transport::Endpoint::from_shared(format!("http://{grpc}"))
            .unwrap()
            .connect()
            .await
            .unwrap();
        let health = HealthClient::new(channel.clone())
            .check(HealthCheckRequest {
                service: "ilqr.v1.TrajectoryOptimizer".into(),
            })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(health.status(), ServingStatus::Serving);
        let mut client = TrajectoryOptimizerClient::new(channel);
        let solved = client
            .solve(proto::SolveRequest { problem: None })
            .await
            .unwrap()
            .into_inner()
            .result
            .unwrap();
        assert_eq!(solved.status(), proto::SolveStatus::Converged);
        let models = client
            .list_models(proto::ListModelsRequest {})
            .await
            .unwrap()
            .into_inner()
            .models;
        assert_eq!(models.len(), 2);
    });
    // The client's connection closes with its runtime: an open one would
    // get the drain's GOAWAY and up to 5 s to close.
    drop(runtime);
    let started = std::time::Instant::now();
    let ok = Command::new("kill")
        .args(["-TERM", &server.0.id().to_string()])
        .status()
        .unwrap();
    assert!(ok.success());
    let status = server.0.wait().unwrap();
    assert_eq!(status.code(), Some(0));
    assert!(
        started.elapsed() < std::time::Duration::from_secs(3),
        "{:?}",
        started.elapsed()
    );
}

#[test]
fn settings_out_of_range_are_rejected_before_serving() {
    for (args, says) in [
        // Each range in words, with the value given, not clap's "number
        // would be zero for non-zero type" or "0 is not in
        // 1..18446744073709551615".
        (
            &["--workers", "0"][..],
            "invalid value '0' for '--workers <WORKERS>': expected 1 to 1024 threads, got 0",
        ),
        (
            &["--runtime-threads", "0"],
            "invalid value '0' for '--runtime-threads <RUNTIME_THREADS>': \
             expected 1 to 1024 threads, got 0",
        ),
        (
            &["--retry-after-secs", "0"],
            "invalid value '0' for '--retry-after-secs <RETRY_AFTER_SECS>': \
             expected at least 1 second, got 0",
        ),
        (
            &["--gzip-level", "10"],
            "invalid value '10' for '--gzip-level <GZIP_LEVEL>': \
             expected 0 (no compression) to 9, got 10",
        ),
        (
            &["--max-horizon", "99"],
            "expected an integer from 100 (the default problem's horizon) to 10000, got 99",
        ),
        (
            &["--max-horizon", "10001"],
            "expected an integer from 100 (the default problem's horizon) to 10000",
        ),
        (
            &["--max-body-bytes", "0"],
            "invalid value '0' for '--max-body-bytes <MAX_BODY_BYTES>': expected at least 4096",
        ),
        (
            &["--default-time-limit-ms", "0"],
            "invalid value '0' for '--default-time-limit-ms <DEFAULT_TIME_LIMIT_MS>': \
             expected at least 1 ms, got 0",
        ),
        (&["--max-time-limit-ms", "0"], "--max-time-limit-ms"),
        (
            &["--grpc-bind", "localhost:50051"],
            "--grpc-bind / ILQR_GRPC_BIND takes IP:PORT, e.g. 0.0.0.0:50051, 127.0.0.1:50051 \
             or [::]:50051 (host names are not resolved), got \"localhost:50051\"",
        ),
        // Not numbers, or negative: not "invalid digit found in string" or
        // "unexpected argument '-1' found".
        (
            &["--queue-capacity", "lots"],
            "invalid value 'lots' for '--queue-capacity <QUEUE_CAPACITY>': \
             expected 0 to 65536 waiting solves, got \"lots\"",
        ),
        (
            &["--max-body-bytes", "4MB"],
            "expected at least 4096 (the default problem takes 0.5 KB), got \"4MB\"",
        ),
        (
            &["--shutdown-grace-secs", "-1"],
            "invalid value '-1' for '--shutdown-grace-secs <SHUTDOWN_GRACE_SECS>': \
             expected a whole number of seconds, got \"-1\"",
        ),
        (
            &["--workers", "-2"],
            "invalid value '-2' for '--workers <WORKERS>': expected 1 to 1024 threads, got \"-2\"",
        ),
        // Accepted, these would log "listening" and then fail: every
        // connection would panic in hyper's timer, or the pool would reserve
        // the whole queue.
        (
            &["--read-timeout-secs", "10000000000000000000"],
            "invalid value '10000000000000000000' for '--read-timeout-secs <READ_TIMEOUT_SECS>': \
             expected 1 to 3600 seconds, got 10000000000000000000",
        ),
        (
            &["--queue-capacity", "18446744073709551615"],
            "invalid value '18446744073709551615' for '--queue-capacity <QUEUE_CAPACITY>': \
             expected 0 to 65536 waiting solves, got 18446744073709551615",
        ),
        // Past u64: the range alone would read as satisfied.
        (
            &["--default-time-limit-ms", "99999999999999999999"],
            "invalid value '99999999999999999999' for '--default-time-limit-ms \
             <DEFAULT_TIME_LIMIT_MS>': expected at least 1 ms, got 99999999999999999999: \
             more than 18446744073709551615",
        ),
        (
            &["--queue-capacity", "99999999999999999999"],
            "expected 0 to 65536 waiting solves, got 99999999999999999999: more than 65536",
        ),
        (
            &["--workers", "5000"],
            "invalid value '5000' for '--workers <WORKERS>': expected 1 to 1024 threads, got 5000",
        ),
        (
            &["--runtime-threads", "1025"],
            "invalid value '1025' for '--runtime-threads <RUNTIME_THREADS>': \
             expected 1 to 1024 threads, got 1025",
        ),
        (
            &["--default-time-limit-ms", "70000"],
            "--default-time-limit-ms / ILQR_DEFAULT_TIME_LIMIT_MS (70000) must not exceed \
             --max-time-limit-ms / ILQR_MAX_TIME_LIMIT_MS (60000)",
        ),
        (
            &["--max-time-limit-ms", "5000"],
            "(10000) must not exceed --max-time-limit-ms / ILQR_MAX_TIME_LIMIT_MS (5000)",
        ),
        (
            &["--max-inflight-body-bytes", "1000000"],
            "--max-inflight-body-bytes / ILQR_MAX_INFLIGHT_BODY_BYTES (1000000) must be at \
             least --max-body-bytes / ILQR_MAX_BODY_BYTES (4194304)",
        ),
        (
            &["--max-inflight-body-bytes", "100"],
            "expected at least 4096 (the default problem takes 0.5 KB), got 100",
        ),
    ] {
        let (code, stderr) = serve_with(args);
        assert_eq!(code, Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(says), "{args:?}: {stderr}");
    }
}

/// A bind address that is not IP:PORT is refused with a message naming
/// both the flag and the variable (the value may come from either).
#[test]
fn a_bind_address_must_be_ip_and_port() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_ilqr-service"))
        .arg("serve")
        .env("ILQR_BIND", "localhost:0")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Accepted by mistake, it would serve forever: kill it after 10 s.
    let started = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if started.elapsed() > std::time::Duration::from_secs(10) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("ILQR_BIND=localhost:0 was accepted");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains(
            "--bind / ILQR_BIND takes IP:PORT, e.g. 0.0.0.0:8080, 127.0.0.1:8080 or [::]:8080 \
             (host names are not resolved), got \"localhost:0\""
        ),
        "{stderr}"
    );
}

/// The binary without the `ILQR_*` variables this process inherited, so
/// that a case sets only its own (an inherited bad one would answer first).
fn without_ilqr_env() -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_ilqr-service"));
    for (name, _) in std::env::vars_os() {
        if name.to_string_lossy().starts_with("ILQR_") {
            cmd.env_remove(name);
        }
    }
    cmd
}

/// A bad value from an environment variable is reported under the
/// variable's name (clap names the flag, which the command line may not
/// have); one from the flag keeps the flag's name. Both exit 2 at once.
#[test]
fn a_bad_value_names_where_it_came_from() {
    type Case<'a> = (&'a [&'a str], &'a [(&'a str, &'a str)], &'a str);
    let cases: [Case; 8] = [
        (
            &[],
            &[("ILQR_RUNTIME_THREADS", "0")],
            "invalid value '0' for 'ILQR_RUNTIME_THREADS': expected 1 to 1024 threads, got 0",
        ),
        (
            &["serve"],
            &[("ILQR_WORKERS", "abc")],
            "invalid value 'abc' for 'ILQR_WORKERS': expected 1 to 1024 threads, got \"abc\"",
        ),
        (
            &[],
            &[("ILQR_RETRY_AFTER_SECS", "0")],
            "invalid value '0' for 'ILQR_RETRY_AFTER_SECS': expected at least 1 second, got 0",
        ),
        // Serve flags at the top level, without `serve`: the flag given is
        // named as such, and a variable beside it as a variable.
        (
            &["--workers", "0"],
            &[("ILQR_WORKERS", "2")],
            "invalid value '0' for '--workers <WORKERS>'",
        ),
        (
            &["--workers", "2"],
            &[("ILQR_GZIP_LEVEL", "12")],
            "invalid value '12' for 'ILQR_GZIP_LEVEL': expected 0 (no compression) to 9, got 12",
        ),
        (
            &["serve"],
            &[("ILQR_LOG_FORMAT", "xml")],
            "invalid value 'xml' for 'ILQR_LOG_FORMAT'",
        ),
        (
            &["serve", "--workers", "0"],
            &[("ILQR_WORKERS", "2")],
            "invalid value '0' for '--workers <WORKERS>'",
        ),
        (
            &["serve", "--gzip-level=12"],
            &[],
            "invalid value '12' for '--gzip-level <GZIP_LEVEL>'",
        ),
    ];
    for (args, env, expected) in cases {
        let mut cmd = without_ilqr_env();
        let out = cmd
            .args(args)
            .envs(env.iter().copied())
            // Accepted by mistake, the value would still not start a
            // server: this limit, valid alone, fails the config check
            // against the default maximum (exit 2, another message).
            .env("ILQR_DEFAULT_TIME_LIMIT_MS", "70000")
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?} {env:?}: {stderr}");
        assert!(stderr.contains(expected), "{args:?} {env:?}: {stderr}");
    }
}

/// A variable that is not UTF-8 is named too (clap says only "invalid
/// UTF-8 was detected in one or more arguments"); a non-UTF-8 command-line
/// argument keeps clap's message, the caller's own line being the place to
/// look.
#[test]
fn a_variable_that_is_not_utf8_is_named() {
    use std::os::unix::ffi::OsStrExt;
    let bad = std::ffi::OsStr::from_bytes(b"\xff");
    type Case<'a> = (&'a [&'a str], &'a [&'a str], &'a str);
    let cases: [Case; 5] = [
        (
            &[],
            &["ILQR_WORKERS"],
            "error: the value of ILQR_WORKERS is not valid UTF-8",
        ),
        (
            &["serve"],
            &["ILQR_WORKERS"],
            "error: the value of ILQR_WORKERS is not valid UTF-8",
        ),
        // Not a variable whose flag is given (clap does not read it) ...
        (
            &["serve", "--workers", "2"],
            &["ILQR_WORKERS", "ILQR_GZIP_LEVEL"],
            "error: the value of ILQR_GZIP_LEVEL is not valid UTF-8",
        ),
        // ... nor one of another subcommand.
        (
            &["healthcheck"],
            &["ILQR_BIND", "ILQR_HEALTHCHECK_ADDR"],
            "error: the value of ILQR_HEALTHCHECK_ADDR is not valid UTF-8",
        ),
        (
            &[],
            &["ILQR_WORKERS", "ILQR_GZIP_LEVEL"],
            "error: the values of ILQR_WORKERS, ILQR_GZIP_LEVEL are not valid UTF-8",
        ),
    ];
    for (args, bad_vars, expected) in cases {
        let mut cmd = without_ilqr_env();
        for name in bad_vars {
            cmd.env(name, bad);
        }
        let out = cmd
            .args(args)
            .env("ILQR_DEFAULT_TIME_LIMIT_MS", "70000")
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert_eq!(stderr.trim_end(), expected, "{args:?}");
    }
    let out = Command::new(env!("CARGO_BIN_EXE_ilqr-service"))
        .arg("serve")
        .arg("--workers")
        .arg(bad)
        .env("ILQR_WORKERS", bad)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("invalid UTF-8 was detected"), "{stderr}");
}

/// The serve flags work without `serve` (docs/cli.md's
/// `ilqr-service --bind 127.0.0.1:9000`), but not before another subcommand;
/// and the serve settings' variables are read only by serving, so a bad one
/// does not stop `solve`, `openapi` or `healthcheck`.
#[test]
fn serve_flags_work_at_the_top_level() {
    let (_server, bind) = serve_on_free_port(|cmd, bind| {
        cmd.args(["--bind", bind, "--workers", "1"])
            .env_remove("ILQR_BIND")
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null());
    });
    let out = without_ilqr_env()
        .args(["healthcheck", "--addr", &bind])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0), "{out:?}");

    let out = without_ilqr_env()
        .args(["--workers", "1", "openapi"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("the subcommand 'openapi' cannot be used with '--workers <WORKERS>'"),
        "{stderr}"
    );

    for args in [
        &["openapi"][..],
        &["solve", "examples/seed.json"],
        &["help"],
    ] {
        let out = without_ilqr_env()
            .args(args)
            .env("ILQR_WORKERS", "0")
            .env("ILQR_BIND", "nowhere")
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(0), "{args:?}: {stderr}");
    }
}

/// A variable set but empty (`ILQR_WORKERS=`, as compose files and
/// manifests write "unset") is read as unset: the server starts with the
/// defaults instead of failing with "cannot parse integer from empty
/// string", with and without `serve`.
#[test]
fn an_empty_variable_counts_as_unset() {
    const EMPTY: [&str; 12] = [
        "ILQR_WORKERS",
        "ILQR_RUNTIME_THREADS",
        "ILQR_QUEUE_CAPACITY",
        "ILQR_DEFAULT_TIME_LIMIT_MS",
        "ILQR_MAX_TIME_LIMIT_MS",
        "ILQR_MAX_HORIZON",
        "ILQR_MAX_BODY_BYTES",
        "ILQR_SHUTDOWN_GRACE_SECS",
        "ILQR_RETRY_AFTER_SECS",
        "ILQR_READ_TIMEOUT_SECS",
        "ILQR_GZIP_LEVEL",
        "ILQR_LOG_FORMAT",
    ];
    for serve in [&[][..], &["serve"]] {
        let (_server, _) = serve_on_free_port(|cmd, bind| {
            cmd.args(serve)
                .args(["--bind", bind])
                .stdout(std::process::Stdio::null())
                .stderr(std::process::Stdio::null());
            for name in EMPTY {
                cmd.env(name, "");
            }
        });
    }
    // `healthcheck` with an empty `ILQR_HEALTHCHECK_ADDR` follows
    // ILQR_BIND, as with none.
    let (_server, bind) = serve_on_free_port(|cmd, bind| {
        cmd.args(["--bind", bind])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null());
    });
    let out = without_ilqr_env()
        .arg("healthcheck")
        .env("ILQR_HEALTHCHECK_ADDR", "")
        .env("ILQR_BIND", &bind)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0), "{out:?}");
}

/// The health check's 2 s cover connect, write and every read together: a
/// peer that trickles its answer a byte every 300 ms cannot stretch it (with
/// 2 s for each read, it would take 4 s and more), and the addresses after
/// it fail at once.
#[test]
fn the_healthcheck_deadline_covers_a_trickling_answer() {
    use std::io::Write;
    use std::time::{Duration, Instant};
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    std::thread::spawn(move || {
        let (mut peer, _) = listener.accept().unwrap();
        for b in b"HTTP/1.1 200 OK\r\n" {
            std::thread::sleep(Duration::from_millis(300));
            if peer.write_all(&[*b]).is_err() {
                return;
            }
        }
    });
    let started = Instant::now();
    let err = ilqr_service::server::healthcheck_any(&[addr, addr]).unwrap_err();
    let took = started.elapsed();
    assert!(took < Duration::from_secs(3), "{took:?}: {err}");
    assert!(took >= Duration::from_millis(1900), "{took:?}: {err}");
    assert_eq!(err, format!("{addr}: timed out; {addr}: timed out"));
}

/// Kills the server child when the test ends, whether it passes or not.
struct Child(std::process::Child);

impl Drop for Child {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// Start `ilqr-service` on a loopback port that was free a moment ago and
/// wait until `/healthz` answers. `configure` gives the command its bind
/// address (flag or environment) and the rest of its setup. Another process
/// can take the port between the check and the bind; the server then exits,
/// and the next try picks another port.
fn serve_on_free_port(configure: impl Fn(&mut Command, &str)) -> (Child, String) {
    serve_on_free_port_of("127.0.0.1", configure)
}

/// [`serve_on_free_port`] on another loopback address (`127.0.0.2`).
fn serve_on_free_port_of(host: &str, configure: impl Fn(&mut Command, &str)) -> (Child, String) {
    for _ in 0..3 {
        let bind = format!("{host}:{}", free_port());
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_ilqr-service"));
        // gRPC on a port of its own (a case may set another): the default,
        // 0.0.0.0:50051, is one port for every server these tests run at
        // once.
        cmd.env("ILQR_GRPC_BIND", format!("{host}:0"));
        configure(&mut cmd, &bind);
        let mut server = Child(cmd.spawn().unwrap());
        let started = std::time::Instant::now();
        loop {
            if ilqr_service::server::healthcheck(&bind).is_ok() {
                return (server, bind);
            }
            if server.0.try_wait().unwrap().is_some() {
                break; // it could not bind: try another port
            }
            assert!(
                started.elapsed() < std::time::Duration::from_secs(10),
                "the service on {bind} never became healthy"
            );
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
    }
    panic!("the service exited at start three times (ports taken?)");
}

/// `healthcheck` (the container's HEALTHCHECK, which has no curl) follows
/// the port of `ILQR_BIND`, so moving the service moves the check; it fails
/// with exit status 1 and a reason when nothing answers.
#[test]
fn healthcheck_follows_ilqr_bind_and_fails_when_nothing_answers() {
    let (_server, bind) = serve_on_free_port(|cmd, bind| {
        cmd.arg("serve")
            .env("ILQR_BIND", bind)
            .env("ILQR_WORKERS", "1")
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null());
    });
    let check = |env: &[(&str, &str)]| {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_ilqr-service"));
        cmd.arg("healthcheck")
            .env_remove("ILQR_BIND")
            .env_remove("ILQR_HEALTHCHECK_ADDR");
        for (k, v) in env {
            cmd.env(k, v);
        }
        let out = cmd.output().unwrap();
        (out.status.code(), String::from_utf8(out.stderr).unwrap())
    };
    assert_eq!(check(&[("ILQR_BIND", &bind)]).0, Some(0));
    // The bind address is 0.0.0.0-style in a container; only its port counts.
    let port = bind.rsplit(':').next().unwrap();
    let any = format!("0.0.0.0:{port}");
    assert_eq!(check(&[("ILQR_BIND", &any)]).0, Some(0));
    // `[::]` takes IPv4 too: checked on [::1], then on 127.0.0.1, where
    // this (IPv4) service answers.
    let any6 = format!("[::]:{port}");
    assert_eq!(check(&[("ILQR_BIND", &any6)]).0, Some(0));
    // Every address a name resolves to is tried, in order: one that
    // refuses first (as `::1` does for `localhost` on many machines) does
    // not fail the check.
    let v4: std::net::SocketAddr = bind.parse().unwrap();
    let refusing: std::net::SocketAddr = format!("127.0.0.1:{}", free_port()).parse().unwrap();
    ilqr_service::server::healthcheck_any(&[refusing, v4]).unwrap();
    let err = ilqr_service::server::healthcheck_any(&[refusing]).unwrap_err();
    assert!(err.starts_with(&format!("{refusing}: ")), "{err}");
    assert_eq!(check(&[("ILQR_HEALTHCHECK_ADDR", &bind)]).0, Some(0));
    let named = format!("localhost:{port}");
    assert_eq!(check(&[("ILQR_HEALTHCHECK_ADDR", &named)]).0, Some(0));

    let nobody = format!("127.0.0.1:{}", free_port());
    let (code, stderr) = check(&[("ILQR_HEALTHCHECK_ADDR", &nobody)]);
    assert_eq!(code, Some(1));
    assert!(stderr.starts_with("unhealthy: "), "{stderr}");

    // A service bound to one specific address is checked there, not on
    // 127.0.0.1.
    let (_other, other) = serve_on_free_port_of("127.0.0.2", |cmd, bind| {
        cmd.arg("serve")
            .env("ILQR_BIND", bind)
            .env("ILQR_WORKERS", "1")
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null());
    });
    assert_eq!(check(&[("ILQR_BIND", &other)]), (Some(0), String::new()));

    // An ILQR_BIND that is not IP:PORT is an error naming it and the way
    // around it, not a silent check of 127.0.0.1:8080; with an address
    // given, it is not read.
    let (code, stderr) = check(&[("ILQR_BIND", "garbage")]);
    assert_eq!(code, Some(1), "{stderr}");
    assert_eq!(
        stderr,
        "error: ILQR_BIND is \"garbage\", which is not IP:PORT (e.g. 0.0.0.0:8080), so the \
         address to check is unknown; fix it, or give the address with --addr or \
         ILQR_HEALTHCHECK_ADDR\n"
    );
    assert_eq!(
        check(&[("ILQR_BIND", "garbage"), ("ILQR_HEALTHCHECK_ADDR", &bind)]),
        (Some(0), String::new())
    );
    let out = Command::new(env!("CARGO_BIN_EXE_ilqr-service"))
        .args(["healthcheck", "--addr", &bind])
        .env("ILQR_BIND", "garbage")
        .env_remove("ILQR_HEALTHCHECK_ADDR")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0), "{out:?}");
}

/// A `Config` built in code gets the same checks, in the flags' words:
/// the service refuses to start rather than accept horizons its state
/// bounds were not made for.
#[test]
fn a_config_built_in_code_is_checked_too() {
    use ilqr_service::server::{AppState, Config};
    let base = Config::default;
    for (bad, says) in [
        (
            Config {
                max_horizon: 20_000,
                ..base()
            },
            "--max-horizon / ILQR_MAX_HORIZON: expected an integer from 100 \
             (the default problem's horizon) to 10000, got 20000",
        ),
        (
            Config {
                max_horizon: 99,
                ..base()
            },
            "to 10000, got 99",
        ),
        (
            Config {
                max_body_bytes: 4095,
                ..base()
            },
            "--max-body-bytes / ILQR_MAX_BODY_BYTES: expected at least 4096 \
             (the default problem takes 0.5 KB), got 4095",
        ),
        (
            Config {
                default_time_limit_ms: 0,
                ..base()
            },
            "--default-time-limit-ms / ILQR_DEFAULT_TIME_LIMIT_MS: expected at least 1 ms, got 0",
        ),
        (
            Config {
                default_time_limit_ms: 70_000,
                ..base()
            },
            "(70000) must not exceed --max-time-limit-ms / ILQR_MAX_TIME_LIMIT_MS (60000)",
        ),
        (
            Config {
                read_timeout_secs: 0,
                ..base()
            },
            "--read-timeout-secs / ILQR_READ_TIMEOUT_SECS: expected 1 to 3600 seconds, got 0",
        ),
        (
            Config {
                read_timeout_secs: 3601,
                ..base()
            },
            "expected 1 to 3600 seconds, got 3601",
        ),
        (
            Config {
                queue_capacity: 65_537,
                ..base()
            },
            "--queue-capacity / ILQR_QUEUE_CAPACITY: expected 0 to 65536 waiting solves, got 65537",
        ),
        (
            Config {
                workers: std::num::NonZeroUsize::new(1025),
                ..base()
            },
            "--workers / ILQR_WORKERS: expected 1 to 1024 threads, got 1025",
        ),
        (
            Config {
                retry_after_secs: 0,
                ..base()
            },
            "--retry-after-secs / ILQR_RETRY_AFTER_SECS: expected at least 1 second, got 0",
        ),
        (
            Config {
                gzip_level: 10,
                ..base()
            },
            "--gzip-level / ILQR_GZIP_LEVEL: expected 0 (no compression) to 9, got 10",
        ),
    ] {
        let err = AppState::new(bad.clone()).err().expect("accepted");
        assert_eq!(err.kind(), std::io::ErrorKind::InvalidInput, "{bad:?}");
        assert!(err.to_string().contains(says), "{bad:?}: {err}");
    }
    assert!(AppState::new(Config::default()).is_ok());
}

/// `text` logs carry no colour escapes when stdout is not a terminal (a
/// file, a pipe, `docker logs`), where they would be noise on every line.
#[test]
fn text_logs_to_a_pipe_have_no_colour_escapes() {
    let (mut server, _) = serve_on_free_port(|cmd, bind| {
        cmd.args(["serve", "--bind", bind, "--workers", "1"])
            .env_remove("ILQR_LOG_FORMAT")
            .env("RUST_LOG", "info")
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::null());
    });
    let logs = stop_and_read_stdout(&mut server);
    assert!(logs.contains("INFO"), "no log lines: {logs:?}");
    assert!(!logs.contains('\u{1b}'), "escape codes in {logs:?}");
}

/// `serve` with one worker and its output discarded, on a free port.
fn serve_quietly() -> (Child, String) {
    serve_on_free_port(|cmd, bind| {
        cmd.args(["serve", "--bind", bind, "--workers", "1"])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null());
    })
}

/// The running service folds histogram samples into buckets on a thread of
/// its own: without it they would be kept until `/metrics` is scraped, and
/// an unscraped service would grow by 2.9 MB per 10 s at saturation.
#[cfg(target_os = "linux")]
#[test]
fn metrics_upkeep_runs_without_a_scrape() {
    let (server, _) = serve_quietly();
    let tasks = format!("/proc/{}/task", server.0.id());
    let names: Vec<String> = std::fs::read_dir(&tasks)
        .unwrap()
        .filter_map(|t| std::fs::read_to_string(t.ok()?.path().join("comm")).ok())
        .map(|n| n.trim().to_owned())
        .collect();
    assert!(
        names.iter().any(|n| n == "metrics-upkeep"),
        "threads: {names:?}"
    );
}

/// A client that closes its connection mid-body is counted as 499 (it left),
/// not as a 400 `unreadable_body` answer that nobody received. The server's
/// own process, so its metrics count this test's requests only.
#[test]
fn a_client_that_leaves_mid_body_is_counted_as_499() {
    use std::io::Write;
    let (_server, bind) = serve_quietly();
    let mut conn = std::net::TcpStream::connect(&bind).unwrap();
    conn.write_all(
        b"POST /solve HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n\
          Content-Length: 5000\r\n\r\n{\"horizon\": 100",
    )
    .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(200));
    drop(conn);
    let started = std::time::Instant::now();
    let metrics = loop {
        let text = exchange(
            &bind,
            "GET /metrics HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n",
        );
        if text.contains("status=\"499\"") || started.elapsed().as_secs() > 5 {
            break text;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    };
    assert!(
        metrics.contains("http_requests_total{route=\"/solve\",status=\"499\"} 1"),
        "{metrics}"
    );
    assert!(!metrics.contains("unreadable_body"), "{metrics}");
    assert!(!metrics.contains("status=\"400\""), "{metrics}");
}

/// Stop a server started with piped stdout; what it wrote there.
fn stop_and_read_stdout(server: &mut Child) -> String {
    use std::io::Read;
    let _ = server.0.kill();
    let _ = server.0.wait();
    let mut out = String::new();
    server
        .0
        .stdout
        .take()
        .expect("stdout was piped")
        .read_to_string(&mut out)
        .expect("stdout is UTF-8");
    out
}

/// One request over a fresh connection, read to its end.
fn exchange(addr: &str, request: &str) -> String {
    use std::io::{Read, Write};
    let mut conn = std::net::TcpStream::connect(addr).unwrap();
    conn.write_all(request.as_bytes()).unwrap();
    let mut answer = String::new();
    conn.read_to_string(&mut answer).unwrap();
    answer
}

/// The log line of a 4xx says why, with the problem's type, title and
/// detail (not only `status=422 latency_ms=...`), under the request's
/// id, in both formats; the detail is cut to 300 characters, and the body
/// is not logged.
#[test]
fn a_client_error_is_logged_with_its_reason() {
    for format in ["text", "json"] {
        let (mut server, bind) = serve_on_free_port(|cmd, bind| {
            cmd.args(["--bind", bind, "--workers", "1", "--log-format", format])
                .env("RUST_LOG", "info")
                .stdout(std::process::Stdio::piped())
                .stderr(std::process::Stdio::null());
        });
        let body = r#"{"dt": -1, "note": "secret-body-text"}"#;
        let answer = exchange(
            &bind,
            &format!(
                "POST /solve HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n\
                 x-request-id: req-422\r\nConnection: close\r\nContent-Length: {}\r\n\r\n{body}",
                body.len()
            ),
        );
        assert!(answer.starts_with("HTTP/1.1 422"), "{answer}");
        let answer = exchange(
            &bind,
            "GET /solve/ HTTP/1.1\r\nHost: x\r\nx-request-id: req-404\r\n\
             Connection: close\r\n\r\n",
        );
        assert!(answer.starts_with("HTTP/1.1 404"), "{answer}");
        // A detail that quotes 1000 characters (elided to about 400).
        let body = format!(r#"{{"dt": "{}"}}"#, "y".repeat(1000));
        let answer = exchange(
            &bind,
            &format!(
                "POST /solve HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n\
                 x-request-id: req-long\r\nConnection: close\r\nContent-Length: {}\r\n\r\n{body}",
                body.len()
            ),
        );
        assert!(answer.starts_with("HTTP/1.1 422"), "{answer}");
        // A path of thousands of characters: every line of the request's
        // span repeats the URI, cut to 200.
        let path = "p".repeat(5000);
        let answer = exchange(
            &bind,
            &format!("GET /{path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"),
        );
        assert!(answer.starts_with("HTTP/1.1 404"), "{answer}");
        let logs = stop_and_read_stdout(&mut server);
        let line = |id: &str| {
            logs.lines()
                .find(|l| l.contains(id) && l.contains("response"))
                .unwrap_or_else(|| panic!("{format}: no response line for {id} in {logs}"))
                .to_owned()
        };
        let invalid = line("req-422");
        assert!(!invalid.contains("secret-body-text"), "{invalid}");
        let huge = line(&"p".repeat(199));
        assert!(!huge.contains(&"p".repeat(200)), "{format}: {huge}");
        assert!(huge.len() < 2000, "{format}: {} bytes", huge.len());
        let not_found = line("req-404");
        let long = line("req-long");
        if format == "json" {
            let invalid: serde_json::Value = serde_json::from_str(&invalid).unwrap();
            assert_eq!(invalid["level"], "INFO");
            assert_eq!(invalid["status"], 422);
            assert_eq!(invalid["problem_type"], "urn:ilqr-service:validation");
            assert_eq!(invalid["title"], "Invalid problem");
            assert_eq!(invalid["detail"], "2 invalid fields; see `errors`");
            let not_found: serde_json::Value = serde_json::from_str(&not_found).unwrap();
            assert_eq!(not_found["problem_type"], "urn:ilqr-service:not-found");
            assert_eq!(not_found["title"], "Not found");
            let detail = not_found["detail"].as_str().unwrap();
            assert!(
                detail.starts_with("no route for GET `/solve/`. Did you mean /solve?"),
                "{detail}"
            );
            let long: serde_json::Value = serde_json::from_str(&long).unwrap();
            let detail = long["detail"].as_str().unwrap();
            assert_eq!(detail.chars().count(), 303, "{detail}");
            assert!(detail.starts_with("/dt: invalid type: string"), "{detail}");
            assert!(detail.ends_with("..."), "{detail}");
        } else {
            for says in [
                " INFO ",
                "status=422",
                "problem_type=\"urn:ilqr-service:validation\"",
                "title=\"Invalid problem\"",
                "detail=\"2 invalid fields; see `errors`\"",
            ] {
                assert!(invalid.contains(says), "{says}: {invalid}");
            }
            assert!(
                not_found.contains(
                    "problem_type=\"urn:ilqr-service:not-found\" title=\"Not found\" \
                     detail=\"no route for GET `/solve/`. Did you mean /solve?"
                ),
                "{not_found}"
            );
            // Quoted, with the quotes around the string it quotes escaped.
            let detail = &long[long.find("detail=").unwrap() + "detail=".len()..];
            assert!(
                detail.starts_with(r#""/dt: invalid type: string \"yyy"#),
                "{detail}"
            );
            assert!(detail.ends_with(r#"yyy...""#), "{detail}");
            assert!(detail.len() < 320, "{detail}");
        }
    }
}

/// The JSON log's schema, as a typed log store needs it: the solve's
/// outcome is `solve_status` (a string; `status` is the HTTP status, a
/// number), the request's span appears once (`span`, no `spans` copy); a
/// 503 for a full queue leaves no line above `debug` (a warning each would
/// be 12 MB/s of log at saturation; `solve_rejections_total` counts them);
/// a `RUST_LOG` that cannot be read is said, not silently replaced;
/// the "listening" line gives the effective settings.
#[test]
fn json_logs_keep_one_type_per_field_and_overload_does_not_flood_them() {
    let (mut server, bind) = serve_on_free_port(|cmd, bind| {
        cmd.args(["--bind", bind, "--workers", "1", "--queue-capacity", "0"])
            .args(["--log-format", "json"])
            .env("RUST_LOG", "info,not[a filter")
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::null());
    });
    let post = |id: &str, body: &str| {
        format!(
            "POST /solve HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n\
             x-request-id: {id}\r\nConnection: close\r\nContent-Length: {}\r\n\r\n{body}",
            body.len()
        )
    };
    // Runs to its 1.5 s budget (as tests/http.rs's `slow`): 10000 steps,
    // 100 far obstacles, no tolerance.
    let obstacles = vec![r#"{"center": [1000, 1000], "weight": 1}"#; 100].join(",");
    let slow = post(
        "req-slow",
        &format!(
            r#"{{"horizon": 10000, "dt": 0.0005, "obstacles": [{obstacles}],
                "solver": {{"tolerance": 0, "max_iterations": 10000, "time_limit_ms": 1500}},
                "output": {{"gains": false, "trace": false}}}}"#
        ),
    );
    let addr = bind.clone();
    let running = std::thread::spawn(move || exchange(&addr, &slow));
    // Time for the slow solve to take the only worker (its answer, below,
    // says whether it did); then, the queue of 0 full, a solve is a 503.
    // Few attempts: stdout is read only at the end, and a full pipe would
    // block the logging threads.
    std::thread::sleep(std::time::Duration::from_millis(300));
    let rejected = (0..3)
        .filter(|_| exchange(&bind, &post("req-503", "{}")).starts_with("HTTP/1.1 503"))
        .count();
    let slow = running.join().unwrap();
    assert!(slow.starts_with("HTTP/1.1 200"), "{slow}");
    assert_eq!(
        rejected, 3,
        "a solve was admitted while the only worker was busy"
    );
    let logs = stop_and_read_stdout(&mut server);
    let lines: Vec<serde_json::Value> = logs
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    assert!(
        !logs.contains("req-503"),
        "a 503 overloaded was logged at info or above: {logs}"
    );
    assert!(lines.iter().all(|l| l.get("spans").is_none()), "{logs}");
    let finished = lines
        .iter()
        .find(|l| l["message"] == "solve finished")
        .unwrap_or_else(|| panic!("no solve line: {logs}"));
    assert!(finished["solve_status"].is_string(), "{finished}");
    assert!(finished.get("status").is_none(), "{finished}");
    assert_eq!(finished["span"]["request_id"], "req-slow");
    // Its own target, so that RUST_LOG can drop it alone.
    assert_eq!(finished["target"], "ilqr_service::solves", "{finished}");
    let warned = lines
        .iter()
        .find(|l| l["level"] == "WARN")
        .unwrap_or_else(|| panic!("no warning for RUST_LOG: {logs}"));
    let message = warned["message"].as_str().unwrap();
    assert!(message.starts_with("RUST_LOG ignored"), "{message}");
    assert!(message.contains("not[a filter"), "{message}");
    let listening = lines.iter().find(|l| l["message"] == "listening").unwrap();
    for setting in [
        "version",
        "grpc_addr",
        "queue_capacity",
        "max_time_limit_ms",
        "shutdown_grace_secs",
    ] {
        assert!(listening.get(setting).is_some(), "{setting}: {listening}");
    }
}

/// SIGTERM starts a drain that waits for the solves in flight; a second
/// SIGTERM during it ends the process at once with exit status 143 (the
/// way out of a long drain at a terminal).
#[test]
fn a_second_signal_ends_the_drain_at_once() {
    use std::io::Write;
    use std::time::{Duration, Instant};
    let (mut server, bind) = serve_on_free_port(|cmd, bind| {
        cmd.arg("serve")
            .env("ILQR_BIND", bind)
            .env("ILQR_WORKERS", "1")
            .env("ILQR_SHUTDOWN_GRACE_SECS", "60")
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null());
    });
    // Three solves of about 3 s each (N = 10000, 100 obstacles; longer on
    // a slower machine), one running and two queued: a drain of 9 s or so.
    let obstacles: Vec<String> = (0..100)
        .map(|i| format!(r#"{{"center":[{},{}],"weight":1}}"#, i % 10, i / 10))
        .collect();
    let body = format!(
        r#"{{"horizon":10000,"dt":0.0005,"obstacles":[{}],"solver":{{"max_iterations":10000,"tolerance":0,"time_limit_ms":60000}}}}"#,
        obstacles.join(",")
    );
    let clients: Vec<std::net::TcpStream> = (0..3)
        .map(|_| {
            let mut c = std::net::TcpStream::connect(&bind).unwrap();
            write!(
                c,
                "POST /solve HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n\
                 Content-Length: {}\r\n\r\n{body}",
                body.len()
            )
            .unwrap();
            c
        })
        .collect();
    std::thread::sleep(Duration::from_millis(300));
    let pid = server.0.id().to_string();
    let term = || {
        let ok = Command::new("kill")
            .args(["-TERM", &pid])
            .status()
            .unwrap()
            .success();
        assert!(ok);
    };
    term();
    std::thread::sleep(Duration::from_millis(500));
    assert!(
        server.0.try_wait().unwrap().is_none(),
        "the first SIGTERM did not wait for the solves in flight"
    );
    let second = Instant::now();
    term();
    let status = loop {
        if let Some(status) = server.0.try_wait().unwrap() {
            break status;
        }
        assert!(
            second.elapsed() < Duration::from_secs(2),
            "still draining 2 s after the second SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(status.code(), Some(143));
    drop(clients);
}

/// With nothing in flight, SIGTERM ends the process at once with status 0,
/// an idle keep-alive connection open or not: there is nothing to drain.
#[test]
fn an_idle_server_exits_on_sigterm_at_once() {
    use std::io::{Read, Write};
    use std::time::{Duration, Instant};
    let (mut server, bind) = serve_on_free_port(|cmd, bind| {
        cmd.args(["serve", "--bind", bind, "--workers", "1"])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null());
    });
    // A solve answered on a connection that stays open, idle.
    let mut idle = std::net::TcpStream::connect(&bind).unwrap();
    write!(
        idle,
        "POST /solve HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n\
         Content-Length: 2\r\n\r\n{{}}"
    )
    .unwrap();
    let mut head = [0u8; 12];
    idle.read_exact(&mut head).unwrap();
    assert_eq!(&head, b"HTTP/1.1 200");
    std::thread::sleep(Duration::from_millis(200));
    let pid = server.0.id().to_string();
    let sent = Instant::now();
    assert!(
        Command::new("kill")
            .args(["-TERM", &pid])
            .status()
            .unwrap()
            .success()
    );
    let status = loop {
        if let Some(status) = server.0.try_wait().unwrap() {
            break status;
        }
        assert!(
            sent.elapsed() < Duration::from_millis(500),
            "an idle server still running 0.5 s after SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(5));
    };
    assert_eq!(status.code(), Some(0));
}

/// The image's version label is an `ARG` default in the Dockerfile (the
/// build has no other way to know it); it must say what Cargo.toml says.
#[test]
fn the_dockerfile_labels_the_crate_version() {
    let dockerfile = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/Dockerfile"))
        .expect("Dockerfile");
    let version = dockerfile
        .lines()
        .find_map(|l| l.trim().strip_prefix("ARG VERSION="))
        .expect("an `ARG VERSION=` line");
    assert_eq!(version, env!("CARGO_PKG_VERSION"));
}

/// `GET path` over a fresh connection to the real binary, the body as text.
fn get_text(bind: &str, path: &str) -> String {
    use std::io::{Read, Write};
    let mut conn = std::net::TcpStream::connect(bind).unwrap();
    write!(
        conn,
        "GET {path} HTTP/1.1\r\nHost: {bind}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut text = String::new();
    conn.read_to_string(&mut text).unwrap();
    text
}

/// The value of one unlabelled Prometheus sample in `text`.
fn sample(text: &str, name: &str) -> Option<f64> {
    text.lines()
        .find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.trim().parse().ok())
}

/// The pool's gauges say how full it is, from the binary's own flags: an
/// operator's dashboard needs no copy of `--workers` or `--queue-capacity`.
/// Run against the real binary (one server per process), since the
/// in-process servers of tests/http.rs share one recorder.
#[test]
fn the_pool_gauges_say_how_full_the_pool_is() {
    use std::io::Write;
    use std::time::{Duration, Instant};
    let (_server, bind) = serve_on_free_port(|cmd, bind| {
        cmd.args([
            "serve",
            "--bind",
            bind,
            "--workers",
            "1",
            "--queue-capacity",
            "3",
        ])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null());
    });
    let idle = get_text(&bind, "/metrics");
    assert_eq!(sample(&idle, "solve_workers"), Some(1.0), "{idle}");
    assert_eq!(sample(&idle, "solve_queue_capacity"), Some(3.0), "{idle}");
    assert_eq!(sample(&idle, "solves_running"), Some(0.0), "{idle}");

    // A solve that runs for seconds (as tests/http.rs's `slow`); leaving
    // its connection open keeps it running.
    let obstacles: Vec<String> = (0..100)
        .map(|j| format!(r#"{{"center":[{},1000],"weight":1}}"#, 1000 + j))
        .collect();
    let body = format!(
        r#"{{"horizon":10000,"dt":0.0005,"obstacles":[{}],"solver":{{"tolerance":0,"max_iterations":10000,"time_limit_ms":20000}},"output":{{"gains":false,"trace":false}}}}"#,
        obstacles.join(",")
    );
    let mut solving = std::net::TcpStream::connect(&bind).unwrap();
    write!(
        solving,
        "POST /solve HTTP/1.1\r\nHost: {bind}\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    )
    .unwrap();
    let until = |want: f64| {
        let started = Instant::now();
        loop {
            let text = get_text(&bind, "/metrics");
            if sample(&text, "solves_running") == Some(want) {
                return text;
            }
            assert!(
                started.elapsed() < Duration::from_secs(10),
                "solves_running never {want}:\n{text}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    };
    let busy = until(1.0);
    assert_eq!(sample(&busy, "solve_queue_depth"), Some(0.0), "{busy}");
    // The client leaves: its solve is cancelled and the worker is free.
    drop(solving);
    until(0.0);
}
