//! Prometheus metrics.
//!
//! One process-wide recorder from the `metrics` facade, rendered by
//! `GET /metrics`. Names:
//!
//! * `http_requests_total{route, status}`, counter, every request that
//!   reached a route, by the status of its answer: 500 for a handler that
//!   panicked, and `499` for a request whose client left before its answer
//!   (its solve counts as `cancelled` below). Not counted: what hyper
//!   rejects before any route runs (400 for broken framing, 414, 431);
//! * `grpc_requests_total{method, code}`, counter, every call of the gRPC
//!   optimizer service by method (`Solve`, `SolveStream`, …) and status
//!   code (`OK`, `INVALID_ARGUMENT`, …; `CANCELLED` for a call its caller
//!   left, or whose deadline tonic enforced, before the answer); and
//!   `grpc_request_duration_seconds{method}`, histogram, to the call's end
//!   (a stream's last message);
//! * `solves_total{status, transport}`, counter, by solve status
//!   (`converged`, …) and front end (`http`, `grpc`); a solve withdrawn
//!   from the queue because its client left counts as `cancelled`;
//! * `solve_rejections_total{reason, transport}`, counter, every `/solve`
//!   request that got an error: `malformed_json`, `unsupported_media_type`,
//!   `too_large`, `body_timeout`, `unreadable_body`, `invalid`,
//!   `queue_full`, `queue_wait` (it could not have started within its
//!   budget), `expired_in_queue` (its budget ran out while queued),
//!   `body_budget` (the bodies being read hold
//!   `--max-inflight-body-bytes`), `answer_budget` (the answers being sent
//!   hold as many bytes: refused before solving when they hold all of it,
//!   otherwise after), `shutting_down`, `internal` (a solver
//!   panic);
//! * `solve_queue_depth`, gauge: solves waiting for a worker;
//! * `solves_running`, gauge: solves on a worker (read with
//!   `solve_queue_depth`, under one lock);
//! * `solve_worker_seconds_estimate`, gauge: the measured time a solve
//!   holds a worker, from which admission estimates a new solve's wait
//!   (see [`crate::service`]); absent until a solve has ended;
//! * `solve_workers`, `solve_queue_capacity`, gauges: `--workers` and
//!   `--queue-capacity`, so that a dashboard can show how full the pool is,
//!   `(solves_running + solve_queue_depth) / (solve_workers +
//!   solve_queue_capacity)`, without knowing the flags;
//! * `request_body_bytes_held`, gauge: bytes the bodies being read hold,
//!   against `--max-inflight-body-bytes`;
//! * `answer_bytes_held`, gauge: bytes the answers being sent hold, against
//!   a budget of the same size;
//! * `solve_queue_wait_seconds{transport}`, `solve_duration_seconds{transport}`,
//!   histograms;
//! * `solve_iterations`, histogram (the chosen start's);
//! * `solve_starts`, histogram: starts per solve (1 without a search);
//! * `http_request_duration_seconds{route}`, histogram: from routing to
//!   the answer's head (the body's transfer is not in it);
//! * `build_info{version}`, gauge, always 1;
//! * `process_cpu_seconds_total`, `process_resident_memory_bytes`,
//!   `process_virtual_memory_bytes`, `process_start_time_seconds`,
//!   `process_open_fds`, `process_max_fds`: the standard process metrics,
//!   read from `/proc/self` at each scrape (Linux only).
//!
//! Each has a `# HELP` line. A labelled counter appears from its first
//! increment (`rate()` and `absent()` alerts see no series before it).
//! Histogram samples are folded into buckets every second by a thread of
//! the recorder's own, scraped or not (see [`start_upkeep`]).

use std::sync::OnceLock;

use axum::extract::{MatchedPath, Request};
use axum::middleware::Next;
use axum::response::Response;
use metrics_exporter_prometheus::{Matcher, PrometheusBuilder, PrometheusHandle};

static HANDLE: OnceLock<PrometheusHandle> = OnceLock::new();

/// The process-wide recorder, installed on first use. Several servers in one
/// process (as in tests) share it.
pub fn handle() -> &'static PrometheusHandle {
    HANDLE.get_or_init(|| {
        let seconds = [
            // 0.75 ms: the seed solve takes 0.4-0.7 ms, and a boundary there
            // tells a slowdown of the common case from a heavier problem.
            0.0001, 0.00025, 0.0005, 0.00075, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25,
            0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0,
        ];
        let iterations = [
            1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0, 10000.0,
        ];
        let builder = PrometheusBuilder::new()
            .set_buckets_for_metric(Matcher::Suffix("_seconds".into()), &seconds)
            .and_then(|b| {
                b.set_buckets_for_metric(Matcher::Full("solve_iterations".into()), &iterations)
            })
            .and_then(|b| {
                let starts = [1.0, 2.0, 3.0, 5.0, 7.0, 9.0, 13.0, 17.0, 25.0, 32.0];
                b.set_buckets_for_metric(Matcher::Full("solve_starts".into()), &starts)
            })
            .unwrap_or_else(|_| PrometheusBuilder::new());
        let recorder = builder.build_recorder();
        let handle = recorder.handle();
        // Fails only if another recorder is installed; then ours stays empty,
        // which /metrics makes visible rather than hiding.
        let _ = metrics::set_global_recorder(recorder);
        describe();
        start_upkeep(handle.clone());
        handle
    })
}

/// How often histogram samples are folded into their buckets.
const UPKEEP_EVERY: std::time::Duration = std::time::Duration::from_secs(1);

/// Fold histogram samples into their buckets every [`UPKEEP_EVERY`], on a
/// thread of its own (`metrics-upkeep`) for the life of the process.
///
/// A histogram keeps every sample it is given until the exporter's upkeep
/// folds them into buckets, and `build_recorder` (unlike the exporter's
/// `build`, which needs the runtime at construction) spawns no upkeep:
/// samples were folded only when `/metrics` was scraped. Unscraped, as
/// under plain curl or a bare container, memory grew without bound, by
/// 2.9 MB per 10 s at 5000 solves/s (a 512Mi pod in about half an hour).
fn start_upkeep(handle: PrometheusHandle) {
    let spawned = std::thread::Builder::new()
        .name("metrics-upkeep".into())
        .spawn(move || {
            loop {
                std::thread::sleep(UPKEEP_EVERY);
                handle.run_upkeep();
            }
        });
    if let Err(e) = spawned {
        tracing::warn!(
            error = %e,
            "no metrics upkeep thread: histogram samples are kept until /metrics is scraped"
        );
    }
}

/// The `# HELP` lines, with units where there are any.
fn describe() {
    use metrics::{Unit, describe_counter, describe_gauge, describe_histogram};
    describe_counter!(
        "http_requests_total",
        "Requests that reached a route, by matched route (\"unmatched\" for none) and the HTTP status of their answer (499: the client left first)"
    );
    describe_counter!(
        "grpc_requests_total",
        "Calls of the gRPC optimizer service, by method and status code (CANCELLED: the caller left, or its deadline passed, first)"
    );
    describe_histogram!(
        "grpc_request_duration_seconds",
        Unit::Seconds,
        "Time from a gRPC call's start to its end (a stream's last message), by method"
    );
    describe_counter!(
        "solves_total",
        "Solves ended, by solve status and transport; one withdrawn from the queue because its client left counts as cancelled"
    );
    describe_counter!(
        "solve_rejections_total",
        "Solve requests answered with an error, by reason and transport"
    );
    describe_gauge!("solve_queue_depth", "Solves waiting for a worker");
    describe_gauge!("solves_running", "Solves on a worker");
    describe_gauge!("solve_workers", "Solver worker threads (--workers)");
    describe_gauge!(
        "solve_worker_seconds_estimate",
        Unit::Seconds,
        "Measured time a solve holds a worker (a moving average), from which admission estimates a new solve's wait"
    );
    describe_gauge!(
        "solve_queue_capacity",
        "Solves that may wait for a worker (--queue-capacity)"
    );
    describe_gauge!(
        "answer_bytes_held",
        Unit::Bytes,
        "Bytes held by the answers being sent, against --max-inflight-body-bytes"
    );
    describe_gauge!(
        "request_body_bytes_held",
        Unit::Bytes,
        "Bytes held by the request bodies being read, against --max-inflight-body-bytes"
    );
    describe_histogram!(
        "solve_queue_wait_seconds",
        Unit::Seconds,
        "Time an admitted solve waited for a worker"
    );
    describe_histogram!(
        "solve_duration_seconds",
        Unit::Seconds,
        "Time spent solving, without the queue wait, parsing or encoding the answer"
    );
    describe_histogram!(
        "solve_iterations",
        "Iterations per solve (the chosen start's)"
    );
    describe_histogram!(
        "solve_starts",
        "Starts per solve (1 without a search over routes)"
    );

    describe_histogram!(
        "http_request_duration_seconds",
        Unit::Seconds,
        "Time from routing a request to its answer's head, by matched route (for /solve: reading the body, queueing, solving, encoding)"
    );
    describe_gauge!("build_info", "Always 1; the version is a label");
    metrics::gauge!("build_info", "version" => env!("CARGO_PKG_VERSION")).set(1.0);
}

/// Middleware counting requests by matched route and status, and timing
/// them by route: every request that reached a route, including those
/// whose handler panicked (500, answered by the panic layer outside) and
/// those whose client left first (`status="499"`, nginx's code for it; the
/// slowest requests are often these).
pub async fn track(req: Request, next: Next) -> Response {
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map_or_else(|| "unmatched".to_owned(), |p| p.as_str().to_owned());
    let mut seen = Seen {
        route,
        start: std::time::Instant::now(),
        recorded: false,
    };
    let mut answer = std::pin::pin!(next.run(req));
    let polled = std::future::poll_fn(|cx| {
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| answer.as_mut().poll(cx)))
            .map_or_else(|panic| std::task::Poll::Ready(Err(panic)), |p| p.map(Ok))
    })
    .await;
    match polled {
        Ok(res) => {
            seen.record(res.status().as_u16());
            res
        }
        Err(panic) => {
            seen.record(500);
            std::panic::resume_unwind(panic)
        }
    }
}

/// A request being tracked: recorded once, with 499 if it is dropped
/// before its answer (the client left and hyper dropped the handler).
struct Seen {
    route: String,
    start: std::time::Instant,
    recorded: bool,
}

impl Seen {
    fn record(&mut self, status: u16) {
        self.recorded = true;
        metrics::histogram!("http_request_duration_seconds", "route" => self.route.clone())
            .record(self.start.elapsed().as_secs_f64());
        metrics::counter!(
            "http_requests_total",
            "route" => self.route.clone(),
            "status" => status.to_string()
        )
        .increment(1);
    }
}

impl Drop for Seen {
    fn drop(&mut self) {
        if !self.recorded {
            self.record(499);
        }
    }
}

/// The standard `process_*` metrics of Prometheus client libraries, read
/// from `/proc/self` at each scrape (Linux; empty elsewhere). Written as
/// text rather than through the recorder, which has no floating-point
/// counter for `process_cpu_seconds_total`.
pub fn process_text() -> String {
    #[cfg(target_os = "linux")]
    {
        linux::process_text().unwrap_or_default()
    }
    #[cfg(not(target_os = "linux"))]
    {
        String::new()
    }
}

#[cfg(target_os = "linux")]
mod linux {
    use std::fmt::Write;

    /// `/proc` reports CPU times and the start time in USER_HZ ticks,
    /// which Linux fixes at 100 per second for userspace on every
    /// architecture, whatever the kernel's own tick rate.
    const TICKS_PER_SEC: f64 = 100.0;

    pub(super) fn process_text() -> Option<String> {
        let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
        // The command name, in parentheses, may hold spaces: fields are
        // counted from the last ')'; field 3 (state) is index 0.
        let fields: Vec<&str> = stat
            .get(stat.rfind(')')? + 1..)?
            .split_whitespace()
            .collect();
        let field = |n: usize| -> Option<f64> { fields.get(n - 3)?.parse().ok() };
        let cpu = (field(14)? + field(15)?) / TICKS_PER_SEC;
        let virtual_bytes = field(23)?;
        let boot = std::fs::read_to_string("/proc/stat").ok()?;
        let btime: f64 = boot
            .lines()
            .find_map(|l| l.strip_prefix("btime "))?
            .trim()
            .parse()
            .ok()?;
        let start = btime + field(22)? / TICKS_PER_SEC;
        let status = std::fs::read_to_string("/proc/self/status").ok()?;
        let rss_kb: f64 = status
            .lines()
            .find_map(|l| l.strip_prefix("VmRSS:"))?
            .trim()
            .trim_end_matches("kB")
            .trim()
            .parse()
            .ok()?;
        let open_fds = std::fs::read_dir("/proc/self/fd").ok()?.count();
        let limits = std::fs::read_to_string("/proc/self/limits").ok()?;
        let max_fds = limits
            .lines()
            .find_map(|l| l.strip_prefix("Max open files"))
            .and_then(|l| l.split_whitespace().next())
            .and_then(|soft| soft.parse::<f64>().ok());

        let mut out = String::new();
        let mut family = |name: &str, kind: &str, help: &str, value: f64| {
            let _ = write!(
                out,
                "# HELP {name} {help}\n# TYPE {name} {kind}\n{name} {value}\n\n"
            );
        };
        family(
            "process_cpu_seconds_total",
            "counter",
            "User and system CPU time spent, in seconds",
            cpu,
        );
        family(
            "process_resident_memory_bytes",
            "gauge",
            "Resident memory size, in bytes",
            rss_kb * 1024.0,
        );
        family(
            "process_virtual_memory_bytes",
            "gauge",
            "Virtual memory size, in bytes",
            virtual_bytes,
        );
        family(
            "process_start_time_seconds",
            "gauge",
            "Start time of the process since the Unix epoch, in seconds",
            start,
        );
        family(
            "process_open_fds",
            "gauge",
            "Open file descriptors (sockets included)",
            open_fds as f64,
        );
        if let Some(max) = max_fds {
            family(
                "process_max_fds",
                "gauge",
                "Soft limit on open file descriptors",
                max,
            );
        }
        Some(out)
    }
}

#[cfg(test)]
mod tests {
    use axum::Router;
    use axum::body::Body;
    use axum::routing::get;
    use tower::ServiceExt;

    async fn boom() -> &'static str {
        panic!("on purpose")
    }

    /// A handler that panics is counted (and timed) as the 500 the panic
    /// layer outside answers; the panic still reaches that layer.
    #[tokio::test]
    async fn a_panicking_handler_is_counted_as_500() {
        let handle = super::handle();
        let app = Router::new()
            .route("/tracked-panic", get(boom))
            .layer(axum::middleware::from_fn(super::track))
            .layer(tower_http::catch_panic::CatchPanicLayer::new());
        let req = axum::http::Request::get("/tracked-panic")
            .body(Body::empty())
            .unwrap();
        let res = app.oneshot(req).await.unwrap();
        assert_eq!(res.status(), 500);
        let text = handle.render();
        for needle in [
            "http_requests_total{route=\"/tracked-panic\",status=\"500\"} 1",
            "http_request_duration_seconds_count{route=\"/tracked-panic\"} 1",
        ] {
            assert!(text.contains(needle), "missing {needle} in\n{text}");
        }
    }
}
