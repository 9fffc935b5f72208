//! The service process: configuration, state, the HTTP API (its
//! middleware and routes) and, beside it, the gRPC one ([`crate::grpc`]),
//! both over one solve service; shutdown.
//!
//! # Mechanisms
//!
//! * **Admission.** `POST /solve` reads its body within a memory budget
//!   shared by all bodies being read (`body`), parses it on the async
//!   runtime (cheap), then hands the problem to the solve service
//!   ([`crate::service`]), which validates, admits, queues, times, cancels
//!   and drains solves for every transport. An exhausted body budget, a
//!   full queue, or a queue too long for the solve's time budget answers
//!   503 with `Retry-After` at once; nothing waits for bytes or a slot.
//! * **Cancellation.** The handler owns its solve through the service's
//!   guard: hyper drops the handler when the client disconnects (or
//!   half-closes its socket: see the comment in [`run`]), which withdraws
//!   the queued solve or cancels the running one.
//! * **Shutdown.** On SIGTERM/SIGINT `/readyz` turns 503 and `/solve` answers
//!   503 (gRPC: health `NOT_SERVING`, solves `UNAVAILABLE`); in-flight
//!   solves of both transports get `shutdown_grace` to finish, then the
//!   rest are cancelled (a running one answers 200 with status `cancelled`
//!   and its best trajectory so far; one still queued, which has computed
//!   nothing, answers 503 `shutting-down`), then the server stops.
//! * **CPU work stays on the pool.** A worker serialises its result and, if
//!   the request's `Accept-Encoding` admits gzip, compresses it (the
//!   service runs the handler's encoder there); the runtime only moves
//!   bytes. So one runtime thread (the default up to 8 cores) keeps
//!   `/healthz` answering in about a millisecond behind megabyte answers,
//!   and takes few time slices from the solvers.

mod body;
mod chunks;
mod error;
mod metrics;
mod routes;
mod stall;

use std::future::Future;
use std::io::{Read, Write};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use tokio::net::TcpListener;

pub use error::{ApiError, Overload, PROBLEM_JSON, Problem};
pub(crate) use routes::drop_unusable_request_id;
pub use routes::{ApiDoc, app, openapi, openapi_json};

use crate::problem::{DEFAULT_HORIZON, DEFAULT_MAX_HORIZON, Limits};
use crate::service::{Settings, SolveService};

/// Smallest `--max-body-bytes` accepted: room for the default problem
/// with up to about 35 obstacles pretty-printed (0.87 KB with one), or
/// about 95 compact. Problems with `initial_controls` or many obstacles
/// need more (100 obstacles: 4.2 KB compact, 9.6 KB pretty-printed).
pub const MIN_BODY_BYTES: usize = 4096;

/// Largest `--queue-capacity`. Each waiting solve holds its parsed problem
/// (up to ~0.3 MB with 10000 rows of `initial_controls`), and a client that
/// leaves is withdrawn by a linear search of the queue under its lock; a
/// queue this long already waits minutes for 2 workers.
pub const MAX_QUEUE_CAPACITY: usize = 65_536;

/// Largest `--workers` and `--runtime-threads`: a typo of a few digits
/// would otherwise start that many threads before failing.
pub const MAX_THREADS: usize = 1024;

/// Largest `--read-timeout-secs`: an hour. Far larger values overflow the
/// timer's deadline arithmetic, in every connection rather than at start.
pub const MAX_READ_TIMEOUT_SECS: u64 = 3600;

/// `--bind` / `ILQR_BIND`: an IP address and port, with an error that says
/// so (and names both spellings: clap's own names only the flag, and the
/// value may have come from the environment).
fn parse_bind(value: &str) -> Result<SocketAddr, String> {
    parse_addr(value, "--bind / ILQR_BIND", 8080)
}

/// `--grpc-bind` / `ILQR_GRPC_BIND`, as [`parse_bind`].
fn parse_grpc_bind(value: &str) -> Result<SocketAddr, String> {
    parse_addr(value, "--grpc-bind / ILQR_GRPC_BIND", 50051)
}

fn parse_addr(value: &str, name: &str, port: u16) -> Result<SocketAddr, String> {
    value.parse().map_err(|_| {
        format!(
            "{name} takes IP:PORT, e.g. 0.0.0.0:{port}, 127.0.0.1:{port} or \
             [::]:{port} (host names are not resolved), got {value:?}"
        )
    })
}

/// Where the gRPC service listens when `--grpc-bind` is not given.
pub const DEFAULT_GRPC_BIND: SocketAddr =
    SocketAddr::new(std::net::IpAddr::V4(std::net::Ipv4Addr::UNSPECIFIED), 50051);

/// A whole number from `min` to `max`, or an error that says the range
/// (`expected`) and what was given: clap's own parsers say "number would
/// be zero for non-zero type", "0 is not in 1..18446744073709551615" or
/// "invalid digit found in string", in Rust's terms. Clap puts the flag or
/// (see `cli::name_env_source`) the variable in front.
fn whole_number(value: &str, min: u64, max: u64, expected: &str) -> Result<u64, String> {
    match value.parse::<u64>() {
        Ok(n) if (min..=max).contains(&n) => Ok(n),
        Ok(n) => Err(format!("expected {expected}, got {n}")),
        // Past u64, the range alone would read as satisfied ("at least 1
        // ms, got 99999999999999999999").
        Err(e) if *e.kind() == std::num::IntErrorKind::PosOverflow => {
            Err(format!("expected {expected}, got {value}: more than {max}"))
        }
        Err(_) => Err(format!("expected {expected}, got {value:?}")),
    }
}

/// `--workers`, `--runtime-threads`: 1 to [`MAX_THREADS`].
fn parse_threads(value: &str) -> Result<std::num::NonZeroUsize, String> {
    let expected = format!("1 to {MAX_THREADS} threads");
    let n = whole_usize(value, 1, MAX_THREADS, &expected)?;
    std::num::NonZeroUsize::new(n).ok_or_else(|| format!("expected {expected}, got {value:?}"))
}

/// A `usize` flag from `min` to `max`.
fn whole_usize(value: &str, min: usize, max: usize, expected: &str) -> Result<usize, String> {
    let n = whole_number(value, min as u64, max as u64, expected)?;
    usize::try_from(n).map_err(|_| format!("expected {expected}, got {value:?}"))
}

/// `--queue-capacity`: 0 to [`MAX_QUEUE_CAPACITY`].
fn parse_queue_capacity(value: &str) -> Result<usize, String> {
    whole_usize(
        value,
        0,
        MAX_QUEUE_CAPACITY,
        &format!("0 to {MAX_QUEUE_CAPACITY} waiting solves"),
    )
}

/// `--default-time-limit-ms`, `--max-time-limit-ms`: at least 1.
fn parse_time_limit(value: &str) -> Result<u64, String> {
    whole_number(value, 1, u64::MAX, "at least 1 ms")
}

/// `--max-horizon`: below the default horizon, `{}` and the document
/// served at /problems/default would be refused by the service that
/// serves it.
fn parse_max_horizon(value: &str) -> Result<usize, String> {
    whole_usize(
        value,
        DEFAULT_HORIZON,
        DEFAULT_MAX_HORIZON,
        &format!(
            "an integer from {DEFAULT_HORIZON} (the default problem's horizon) to \
             {DEFAULT_MAX_HORIZON}"
        ),
    )
}

/// `--max-body-bytes`: at least [`MIN_BODY_BYTES`].
fn parse_max_body_bytes(value: &str) -> Result<usize, String> {
    whole_usize(
        value,
        MIN_BODY_BYTES,
        usize::MAX,
        &format!("at least {MIN_BODY_BYTES} (the default problem takes 0.5 KB)"),
    )
}

/// `--shutdown-grace-secs`: any whole number of seconds (0 cancels
/// in-flight solves at once; a huge one waits for them, since tokio's
/// timer saturates instead of overflowing).
fn parse_grace(value: &str) -> Result<u64, String> {
    whole_number(value, 0, u64::MAX, "a whole number of seconds")
}

/// `--read-timeout-secs`: 1 to [`MAX_READ_TIMEOUT_SECS`].
fn parse_read_timeout(value: &str) -> Result<u64, String> {
    whole_number(
        value,
        1,
        MAX_READ_TIMEOUT_SECS,
        &format!("1 to {MAX_READ_TIMEOUT_SECS} seconds"),
    )
}

/// `--retry-after-secs`: at least 1 (`Retry-After: 0` invites an
/// immediate retry into the same full queue).
fn parse_retry_after(value: &str) -> Result<u64, String> {
    whole_number(value, 1, u64::MAX, "at least 1 second")
}

/// `--gzip-level`: 0 (off) to 9.
fn parse_gzip_level(value: &str) -> Result<u32, String> {
    whole_number(value, 0, 9, "0 (no compression) to 9").map(|n| n as u32)
}

/// `value` of a `Config` field (built in code, not parsed) run through its
/// flag's parser, so that both give the same words, prefixed with `name`.
fn recheck<T>(
    name: &str,
    value: impl std::fmt::Display,
    parse: fn(&str) -> Result<T, String>,
) -> Result<(), String> {
    parse(&value.to_string())
        .map(drop)
        .map_err(|e| format!("{name}: {e}"))
}

/// `cmd` with every argument whose environment variable is set but empty
/// read as if the variable were unset. Compose files and Kubernetes
/// manifests write `ILQR_WORKERS=` (or `value: ""`) to mean "not set",
/// while clap takes the empty string as the value and fails to parse it
/// ("cannot parse integer from empty string"), and has no setting to do
/// otherwise. Clap reads a variable when the argument is built, so taking
/// the variable off the argument (rather than out of the process's
/// environment, which needs `unsafe` in Rust 2024) is enough.
pub(crate) fn unset_empty_env(cmd: clap::Command) -> clap::Command {
    cmd.mut_args(|arg| {
        let empty = arg
            .get_env()
            .and_then(std::env::var_os)
            .is_some_and(|v| v.is_empty());
        if empty { arg.env(None) } else { arg }
    })
    .mut_subcommands(unset_empty_env)
}

/// Service configuration: flags, each also read from an environment variable.
#[derive(Debug, Clone, clap::Args)]
pub struct Config {
    /// Address to listen on: IP:PORT (`0.0.0.0:8080` for every IPv4
    /// interface, `127.0.0.1:8080` for this machine only, `[::]:8080` for
    /// IPv6). Host names are not resolved: which address `localhost` means
    /// differs between machines.
    #[arg(long, env = "ILQR_BIND", default_value = "0.0.0.0:8080", value_parser = parse_bind)]
    pub bind: SocketAddr,
    /// Address of the gRPC service (`ilqr.v1.TrajectoryOptimizer`, with the
    /// standard health and reflection services), IP:PORT as for `--bind`
    /// (default: 0.0.0.0:50051). When given, an address that cannot be
    /// bound ends the process, as for `--bind`; when the default is taken
    /// (by another instance on the same machine), a warning says so and
    /// the service runs without gRPC.
    #[arg(long, env = "ILQR_GRPC_BIND", value_parser = parse_grpc_bind)]
    pub grpc_bind: Option<SocketAddr>,
    /// Solver threads, 1 to 1024 (default: the available cores).
    #[arg(long, env = "ILQR_WORKERS", value_parser = parse_threads, allow_negative_numbers = true)]
    pub workers: Option<std::num::NonZeroUsize>,
    /// Async runtime threads, which accept connections, parse and validate
    /// requests and write answers; solves never run on them (default: cores
    /// / 8 rounded up, so 1 up to 8 cores). A request costs them tens of
    /// microseconds next to a solve's milliseconds; on 2 cores a second
    /// runtime thread doubled the context switches per request and added
    /// ~25 µs of kernel time to each (bench/server_cost.sh). At most 1024.
    #[arg(long, env = "ILQR_RUNTIME_THREADS", value_parser = parse_threads, allow_negative_numbers = true)]
    pub runtime_threads: Option<std::num::NonZeroUsize>,
    /// Solves that may wait for a worker before new ones get 503, at most
    /// 65536.
    #[arg(long, env = "ILQR_QUEUE_CAPACITY", default_value_t = 16,
          value_parser = parse_queue_capacity, allow_negative_numbers = true)]
    pub queue_capacity: usize,
    /// Time budget of a solve that sets no `solver.time_limit_ms`, in ms; at
    /// most `--max-time-limit-ms`.
    #[arg(long, env = "ILQR_DEFAULT_TIME_LIMIT_MS", default_value_t = 10_000,
          value_parser = parse_time_limit, allow_negative_numbers = true)]
    pub default_time_limit_ms: u64,
    /// Largest `solver.time_limit_ms` a request may ask for, in ms.
    #[arg(long, env = "ILQR_MAX_TIME_LIMIT_MS", default_value_t = 60_000,
          value_parser = parse_time_limit, allow_negative_numbers = true)]
    pub max_time_limit_ms: u64,
    /// Largest accepted horizon, from 100 (the default problem's, which
    /// `{}` asks for) to 10000 (the solver's own ceiling: the state bounds
    /// that keep every rollout finite assume it).
    #[arg(long, env = "ILQR_MAX_HORIZON", default_value_t = DEFAULT_MAX_HORIZON,
          value_parser = parse_max_horizon, allow_negative_numbers = true)]
    pub max_horizon: usize,
    /// Largest accepted request body, in bytes, at least 4096 (the default
    /// problem takes 0.5 KB, 0.87 KB pretty-printed; N rows of
    /// `initial_controls` add 14–66 bytes each, from short numbers in compact
    /// JSON to full precision pretty-printed).
    #[arg(long, env = "ILQR_MAX_BODY_BYTES", default_value_t = 4 * 1024 * 1024,
          value_parser = parse_max_body_bytes, allow_negative_numbers = true)]
    pub max_body_bytes: usize,
    /// Bytes that the request bodies being received may hold together, over
    /// all connections: each is held whole until it is parsed, and
    /// connections are not limited, so without it memory grows with the
    /// number of clients uploading at once. A body that would take the total past this waits for
    /// nothing: it gets 503 `overloaded` with `Retry-After`, as a full queue
    /// does. The answers being sent have a budget of this size too (an
    /// answer over it while others hold it is a 503). At least
    /// `--max-body-bytes` (default: 16 times it, 64 MiB at its default).
    #[arg(long, env = "ILQR_MAX_INFLIGHT_BODY_BYTES",
          value_parser = parse_max_body_bytes, allow_negative_numbers = true)]
    pub max_inflight_body_bytes: Option<usize>,
    /// Seconds in-flight solves get to finish on shutdown before they are
    /// cancelled.
    #[arg(long, env = "ILQR_SHUTDOWN_GRACE_SECS", default_value_t = 10,
          value_parser = parse_grace, allow_negative_numbers = true)]
    pub shutdown_grace_secs: u64,
    /// `Retry-After` sent with 503 overload answers, in seconds, at least 1.
    #[arg(long, env = "ILQR_RETRY_AFTER_SECS", default_value_t = 1,
          value_parser = parse_retry_after, allow_negative_numbers = true)]
    pub retry_after_secs: u64,
    /// Seconds a client gets to send a request's headers, and again its
    /// body. A connection that stalls longer is closed (headers) or answered
    /// 408 (body), so slow or stuck clients cannot pile up connections or
    /// hold up a shutdown. 30 s moves the largest body (4 MiB) at 1.12 Mbit/s.
    /// Also how long an answer may go without the client reading any of it;
    /// then the connection is closed and the answer freed. 1 to 3600.
    #[arg(long, env = "ILQR_READ_TIMEOUT_SECS", default_value_t = 30,
          value_parser = parse_read_timeout, allow_negative_numbers = true)]
    pub read_timeout_secs: u64,
    /// gzip level of answers to clients that accept gzip: 1 (fastest) to 9
    /// (smallest), 0 to send every answer uncompressed. The seed answer
    /// takes ~0.6 ms to compress at 3 (2.1×), more than its 0.45 ms solve:
    /// where clients sit on the same host or a fast LAN, 0 buys throughput.
    #[arg(long, env = "ILQR_GZIP_LEVEL", default_value_t = 3,
          value_parser = parse_gzip_level, allow_negative_numbers = true)]
    pub gzip_level: u32,
    /// Log format.
    #[arg(long, env = "ILQR_LOG_FORMAT", value_enum, default_value_t = LogFormat::Text)]
    pub log_format: LogFormat,
}

/// Log output format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LogFormat {
    /// Human-readable lines.
    Text,
    /// One JSON object per line.
    Json,
}

/// # Panics
///
/// If an `ILQR_*` variable holds a value its flag rejects. The binary reads
/// the environment through [`Config::from_env`] instead, and reports such a
/// value.
impl Default for Config {
    fn default() -> Self {
        Self::from_env().expect("the ILQR_* environment variables hold valid values")
    }
}

impl Config {
    /// What `serve` gets with no flags: each setting from its environment
    /// variable (an empty one counts as unset), else its default.
    ///
    /// # Errors
    ///
    /// Clap's error for a variable whose value its flag rejects.
    pub fn from_env() -> Result<Self, clap::Error> {
        let matches = unset_empty_env(<Self as clap::Args>::augment_args(
            clap::Command::new("serve").bin_name("ilqr-service serve"),
        ))
        .try_get_matches_from(["serve"])?;
        <Self as clap::FromArgMatches>::from_arg_matches(&matches)
    }

    /// Problem limits this configuration imposes.
    pub fn limits(&self) -> Limits {
        Limits {
            max_horizon: self.max_horizon,
            max_time_limit_ms: Some(self.max_time_limit_ms),
        }
    }

    /// The ranges of the limits (each through its flag's parser, so that a
    /// `Config` built in code gets the flags' words) and how they relate:
    /// the CLI runs it before binding, and [`AppState::new`] refuses a
    /// config that fails it.
    pub fn check(&self) -> Result<(), String> {
        recheck(
            "--max-horizon / ILQR_MAX_HORIZON",
            self.max_horizon,
            parse_max_horizon,
        )?;
        recheck(
            "--max-body-bytes / ILQR_MAX_BODY_BYTES",
            self.max_body_bytes,
            parse_max_body_bytes,
        )?;
        recheck(
            "--default-time-limit-ms / ILQR_DEFAULT_TIME_LIMIT_MS",
            self.default_time_limit_ms,
            parse_time_limit,
        )?;
        recheck(
            "--max-time-limit-ms / ILQR_MAX_TIME_LIMIT_MS",
            self.max_time_limit_ms,
            parse_time_limit,
        )?;
        recheck(
            "--queue-capacity / ILQR_QUEUE_CAPACITY",
            self.queue_capacity,
            parse_queue_capacity,
        )?;
        for (name, threads) in [
            ("--workers / ILQR_WORKERS", self.workers),
            (
                "--runtime-threads / ILQR_RUNTIME_THREADS",
                self.runtime_threads,
            ),
        ] {
            if let Some(n) = threads {
                recheck(name, n, parse_threads)?;
            }
        }
        recheck(
            "--retry-after-secs / ILQR_RETRY_AFTER_SECS",
            self.retry_after_secs,
            parse_retry_after,
        )?;
        recheck(
            "--gzip-level / ILQR_GZIP_LEVEL",
            self.gzip_level,
            parse_gzip_level,
        )?;
        recheck(
            "--read-timeout-secs / ILQR_READ_TIMEOUT_SECS",
            self.read_timeout_secs,
            parse_read_timeout,
        )?;
        if let Some(n) = self.max_inflight_body_bytes {
            recheck(
                "--max-inflight-body-bytes / ILQR_MAX_INFLIGHT_BODY_BYTES",
                n,
                parse_max_body_bytes,
            )?;
            if n < self.max_body_bytes {
                return Err(format!(
                    "--max-inflight-body-bytes / ILQR_MAX_INFLIGHT_BODY_BYTES ({n}) must be at \
                     least --max-body-bytes / ILQR_MAX_BODY_BYTES ({}), or no body of the \
                     largest size could ever be received",
                    self.max_body_bytes
                ));
            }
        }
        if self.default_time_limit_ms > self.max_time_limit_ms {
            return Err(format!(
                "--default-time-limit-ms / ILQR_DEFAULT_TIME_LIMIT_MS ({}) must not exceed \
                 --max-time-limit-ms / ILQR_MAX_TIME_LIMIT_MS ({})",
                self.default_time_limit_ms, self.max_time_limit_ms
            ));
        }
        Ok(())
    }

    /// `--max-inflight-body-bytes`, or its default.
    pub fn inflight_body_bytes(&self) -> usize {
        self.max_inflight_body_bytes
            .unwrap_or_else(|| self.max_body_bytes.saturating_mul(16))
    }

    fn workers(&self) -> usize {
        self.workers.map_or_else(cores, std::num::NonZeroUsize::get)
    }

    fn runtime_threads(&self) -> usize {
        self.runtime_threads
            .map_or_else(|| cores().div_ceil(8), std::num::NonZeroUsize::get)
    }
}

fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
}

/// Shared state of the HTTP service.
pub struct AppState {
    config: Config,
    /// Admission, budgets, cancellation and draining of solves (shared with
    /// any other transport).
    service: Arc<SolveService>,
    /// Bytes of the request bodies being read, against
    /// `--max-inflight-body-bytes`.
    bodies: body::BodyBudget,
    /// Bytes of the answers being sent, against the same limit as the
    /// bodies (a budget of its own: see `stall`).
    answers: Arc<stall::AnswerBudget>,
}

impl AppState {
    /// State for `config`, starting the solver pool.
    pub fn new(config: Config) -> std::io::Result<Arc<Self>> {
        config
            .check()
            .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?;
        metrics::handle(); // install the recorder before anything records
        let service = SolveService::new(Settings {
            workers: config.workers(),
            queue_capacity: config.queue_capacity,
            limits: config.limits(),
            default_time_limit: Some(Duration::from_millis(config.default_time_limit_ms)),
            retry_after_secs: config.retry_after_secs,
        })?;
        Ok(Arc::new(Self {
            bodies: body::BodyBudget::new(config.inflight_body_bytes()),
            answers: stall::AnswerBudget::new(config.inflight_body_bytes()),
            config,
            service,
        }))
    }

    /// The solve service behind `/solve`, for another transport to share.
    pub fn service(&self) -> &Arc<SolveService> {
        &self.service
    }

    /// What the gRPC front end takes from the configuration.
    pub fn grpc_settings(&self) -> crate::grpc::Settings {
        crate::grpc::Settings {
            limits: self.config.limits(),
            default_time_limit_ms: self.config.default_time_limit_ms,
            max_message_bytes: self.config.max_body_bytes,
            keepalive: Duration::from_secs(self.config.read_timeout_secs),
        }
    }

    /// Stop admitting solves, wait up to the grace period for those in
    /// flight, then cancel what is left (see [`SolveService::drain`]).
    pub async fn drain(&self) {
        let grace = Duration::from_secs(self.config.shutdown_grace_secs);
        self.service.drain(grace).await;
    }
}

/// After the drain, how long open connections get to finish writing their
/// answers before the server returns anyway (closing them).
const CLOSE_TIMEOUT: Duration = Duration::from_secs(5);

/// Serve HTTP on `listener` until `shutdown` resolves, then drain and
/// return: [`run_with_grpc`] without the gRPC service.
pub async fn run(
    listener: TcpListener,
    state: Arc<AppState>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    run_with_grpc(listener, None, state, shutdown).await
}

/// Serve HTTP on `listener`, and the gRPC service ([`crate::grpc`]) on
/// `grpc` if given, both over the state's one solve service, until
/// `shutdown` resolves; then drain and return.
///
/// The HTTP accept loop is `axum::serve`'s, plus what that lacks: a header
/// read timeout (hyper's `header_read_timeout` needs a timer, which
/// `axum::serve` does not set, so a client that never finished its headers
/// held its connection forever), the same limit on a write that makes no
/// progress ([`stall::WriteStall`]: a client that never read its answer
/// held it forever) and a bound on shutdown. HTTP/1.1 only:
/// hyper's HTTP/2 has no idle or first-request timeout, and hyper-util's
/// HTTP/1-or-2 detection none either, so a connection that sent nothing, or
/// the start of the HTTP/2 preface, stayed open forever. gRPC has its own
/// listener, with HTTP/2 keepalive pings (see [`crate::grpc`]).
///
/// Shutdown: on `shutdown`, gRPC health turns `NOT_SERVING` and
/// [`AppState::drain`] runs while connections are still accepted
/// (`/readyz` and `/solve` answer 503, gRPC solves `UNAVAILABLE`); then
/// both listeners close, every HTTP connection is told to finish its
/// current exchange and every gRPC connection its calls (GOAWAY), and
/// after [`CLOSE_TIMEOUT`] the rest are dropped. The longest shutdown is
/// thus the grace period plus 5 s, whatever the clients do.
pub async fn run_with_grpc(
    listener: TcpListener,
    grpc: Option<TcpListener>,
    state: Arc<AppState>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    use hyper::server::conn::http1::Builder;
    use hyper_util::rt::{TokioIo, TokioTimer};
    use hyper_util::service::TowerToHyperService;
    use tower::ServiceExt;

    let read_timeout = Duration::from_secs(state.config.read_timeout_secs);
    let service =
        app(Arc::clone(&state)).map_request(|req: axum::http::Request<hyper::body::Incoming>| {
            req.map(axum::body::Body::new)
        });
    let grpc = grpc.map(|listener| {
        let server = crate::grpc::Server::new(Arc::clone(&state.service), state.grpc_settings());
        let health = server.health();
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let served = async move {
            let stopped = async {
                let _ = stopped.await;
            };
            if let Err(e) = server.serve(listener, stopped).await {
                tracing::error!(error = %e, "the gRPC server stopped");
            }
        };
        (health, stop, tokio::spawn(served))
    });
    let drained = {
        let state = Arc::clone(&state);
        let health = grpc.as_ref().map(|(health, _, _)| health.clone());
        async move {
            shutdown.await;
            if let Some(health) = health {
                health.draining().await;
            }
            state.drain().await;
        }
    };
    let mut drained = std::pin::pin!(drained);
    // Flipped once, when the drain is over: connections finish and close.
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    let mut connections = tokio::task::JoinSet::new();
    loop {
        tokio::select! {
            () = &mut drained => break,
            accepted = listener.accept() => {
                let (io, _peer) = match accepted {
                    Ok(conn) => conn,
                    Err(e) => {
                        // Out of file descriptors and the like: the listener
                        // recovers once connections close. Back off briefly.
                        tracing::warn!(error = %e, "accept failed");
                        tokio::time::sleep(Duration::from_millis(100)).await;
                        continue;
                    }
                };
                let _ = io.set_nodelay(true);
                // What chunked bodies on this connection declare, for
                // `body::read_with` (see `chunks`).
                let watch = Arc::new(chunks::Watch::default());
                let io = chunks::Sniff::new(io, Arc::clone(&watch));
                let requests = chunks::Counter::default();
                let service = TowerToHyperService::new(service.clone().map_request(
                    move |mut req: axum::http::Request<hyper::body::Incoming>| {
                        req.extensions_mut().insert(chunks::Declared {
                            watch: Arc::clone(&watch),
                            request: requests.next(),
                        });
                        req
                    },
                ));
                let mut stop = stop_rx.clone();
                connections.spawn(async move {
                    // `half_close` stays off (hyper's default): the end of
                    // a client's input (TCP FIN) is read as the client
                    // leaving, which drops the handler and so withdraws or
                    // cancels its solve (nginx logs this case as 499). TCP
                    // cannot tell a half-close (`shutdown(SHUT_WR)`, `nc
                    // -N`, Go's CloseWrite) from a full close, and
                    // cancelling abandoned solves is a requirement, so a
                    // client that half-closes may get no answer, on GET
                    // routes too; HTTP clients do not half-close (README,
                    // "Connections and cancellation on disconnect").
                    let conn = Builder::new()
                        .timer(TokioTimer::new())
                        .header_read_timeout(read_timeout)
                        .serve_connection(
                            TokioIo::new(stall::WriteStall::new(io, read_timeout)),
                            service,
                        );
                    let mut conn = std::pin::pin!(conn);
                    tokio::select! {
                        _ = conn.as_mut() => return,
                        _ = stop.wait_for(|stop| *stop) => conn.as_mut().graceful_shutdown(),
                    }
                    let _ = conn.await;
                });
            }
            // Reap finished connections so the set does not grow.
            Some(_) = connections.join_next(), if !connections.is_empty() => {}
        }
    }
    drop(listener);
    let _ = stop_tx.send(true);
    let mut grpc = grpc.map(|(_, stop, task)| {
        let _ = stop.send(());
        task
    });
    let open = connections.len();
    let closed = tokio::time::timeout(CLOSE_TIMEOUT, async {
        while connections.join_next().await.is_some() {}
        if let Some(task) = &mut grpc {
            let _ = task.await;
        }
    })
    .await;
    if closed.is_err() {
        tracing::warn!(
            open = connections.len(),
            of = open,
            grpc_open = grpc.as_ref().is_some_and(|task| !task.is_finished()),
            "connections still open after the drain; closing them"
        );
        connections.shutdown().await;
        // The gRPC server's accept loop; tonic runs each connection in a
        // task of its own, which ends with the runtime.
        if let Some(task) = grpc {
            task.abort();
        }
    }
    Ok(())
}

/// Signals closer together than this are one request to stop.
const SIGNALS_APART: Duration = Duration::from_millis(10);

/// Resolves on SIGINT or SIGTERM, and from then on a second one ends the
/// process at once (`std::process::exit`, code 130 or 143), without
/// finishing the drain: the way out of a long drain at a terminal (`docker
/// run -it`, Ctrl-C twice). Meant for the binary ([`serve_forever`]); a
/// program that embeds [`run`] and must not exit passes its own future.
pub async fn shutdown_signal() {
    let mut signals = StopSignals::new();
    signals.next().await;
    let first = std::time::Instant::now();
    tracing::info!("shutdown signal received; draining (a second one exits at once)");
    tokio::spawn(async move {
        loop {
            let code = signals.next().await;
            // Signals within SIGNALS_APART of the first are one request to
            // stop, which should drain: one sent to a process group and to
            // the process itself, or a SIGINT and a SIGTERM together.
            if first.elapsed() >= SIGNALS_APART {
                tracing::warn!("second shutdown signal: exiting without finishing the drain");
                std::process::exit(i32::from(code));
            }
        }
    });
}

/// SIGINT and SIGTERM, listened for from [`StopSignals::new`] on, so that
/// none sent between two [`StopSignals::next`] calls is missed: a listener
/// made after a signal does not see it, while tokio's handler, installed
/// for good by the first listener, keeps the signal from ending the
/// process. (Two of the same kind that arrive before the runtime has taken
/// the first are one anyway: tokio coalesces them, as the kernel does
/// pending signals.) Also what `solve` on the command line stops on.
pub struct StopSignals {
    #[cfg(unix)]
    streams: Option<(tokio::signal::unix::Signal, tokio::signal::unix::Signal)>,
}

impl StopSignals {
    /// Start listening; inside a tokio runtime with I/O enabled.
    pub fn new() -> Self {
        #[cfg(unix)]
        {
            use tokio::signal::unix::{SignalKind, signal};
            let streams = match (
                signal(SignalKind::interrupt()),
                signal(SignalKind::terminate()),
            ) {
                (Ok(int), Ok(term)) => Some((int, term)),
                _ => None,
            };
            Self { streams }
        }
        #[cfg(not(unix))]
        Self {}
    }

    /// The next SIGINT or SIGTERM, as the exit code a process it ends
    /// reports (128 + its number: 130, 143).
    pub async fn next(&mut self) -> u8 {
        #[cfg(unix)]
        if let Some((int, term)) = &mut self.streams {
            return tokio::select! {
                _ = int.recv() => 130,
                _ = term.recv() => 143,
            };
        }
        // No streams (or not Unix): Ctrl-C only.
        let _ = tokio::signal::ctrl_c().await;
        130
    }
}

impl Default for StopSignals {
    fn default() -> Self {
        Self::new()
    }
}

/// The `serve` subcommand: logging, runtime, listener, signals.
pub fn serve_forever(config: Config) -> std::io::Result<()> {
    init_logging(config.log_format);
    log_panics();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(config.runtime_threads())
        .enable_all()
        .build()?;
    let served = runtime.block_on(async move {
        // The state (its checks, the worker threads) before the socket, so
        // that "listening" is logged only by a server that can serve.
        let state = AppState::new(config)?;
        let config = &state.config;
        let listener = TcpListener::bind(config.bind).await.map_err(|e| {
            std::io::Error::new(e.kind(), cannot_listen(config.bind, &e, BIND_FLAG))
        })?;
        let grpc = bind_grpc(config.grpc_bind, DEFAULT_GRPC_BIND).await?;
        let grpc_addr = match &grpc {
            Some(grpc) => grpc.local_addr()?.to_string(),
            None => "none".to_owned(),
        };
        // The effective settings, whichever of flag, variable or default
        // each came from.
        tracing::info!(
            version = env!("CARGO_PKG_VERSION"),
            addr = %listener.local_addr()?,
            grpc_addr,
            workers = config.workers(),
            runtime_threads = config.runtime_threads(),
            queue_capacity = config.queue_capacity,
            default_time_limit_ms = config.default_time_limit_ms,
            max_time_limit_ms = config.max_time_limit_ms,
            max_horizon = config.max_horizon,
            max_body_bytes = config.max_body_bytes,
            max_inflight_body_bytes = config.inflight_body_bytes(),
            shutdown_grace_secs = config.shutdown_grace_secs,
            read_timeout_secs = config.read_timeout_secs,
            gzip_level = config.gzip_level,
            "listening"
        );
        run_with_grpc(listener, grpc, state, shutdown_signal()).await
    });
    // Everything that must finish (the drain, the answers being written)
    // has when `run` returns. Dropping the runtime would also wait for its
    // blocking threads, such as a large body's parse still running for a
    // client that left (`body::read_with`), before the process could exit.
    runtime.shutdown_background();
    served
}

/// The gRPC listener: at `given` (`--grpc-bind`), or at `default`
/// ([`DEFAULT_GRPC_BIND`]) when it is not given. A given address that
/// cannot be bound is an error, as `--bind`'s is; the default address in
/// use is a warning, and no gRPC (so that a second instance on one
/// machine, started with only `--bind`, as test harnesses do, still
/// serves HTTP).
async fn bind_grpc(
    given: Option<SocketAddr>,
    default: SocketAddr,
) -> std::io::Result<Option<TcpListener>> {
    let addr = given.unwrap_or(default);
    match TcpListener::bind(addr).await {
        Ok(listener) => Ok(Some(listener)),
        Err(e) if given.is_none() && e.kind() == std::io::ErrorKind::AddrInUse => {
            tracing::warn!(
                "serving without gRPC: {}",
                cannot_listen(addr, &e, GRPC_BIND_FLAG)
            );
            Ok(None)
        }
        Err(e) => Err(std::io::Error::new(
            e.kind(),
            cannot_listen(addr, &e, GRPC_BIND_FLAG),
        )),
    }
}

/// How to move the HTTP service, for [`cannot_listen`].
const BIND_FLAG: &str = "--bind HOST:PORT (or ILQR_BIND)";

/// How to move the gRPC service, for [`cannot_listen`].
const GRPC_BIND_FLAG: &str = "--grpc-bind HOST:PORT (or ILQR_GRPC_BIND)";

/// Why the service cannot listen on `bind`, and, where another address
/// would do, how to give one (`flag`): the default port is often taken on
/// a developer's machine.
fn cannot_listen(bind: SocketAddr, e: &std::io::Error, flag: &str) -> String {
    match e.kind() {
        std::io::ErrorKind::AddrInUse => {
            format!("cannot listen on {bind}: address in use ({e}); pick another with {flag}")
        }
        std::io::ErrorKind::PermissionDenied => format!(
            "cannot listen on {bind}: permission denied ({e}; ports below 1024 need \
             privileges); pick another with {flag}"
        ),
        std::io::ErrorKind::AddrNotAvailable => format!(
            "cannot listen on {bind}: no such address on this machine ({e}); pick another \
             with {flag}"
        ),
        _ => format!("cannot listen on {bind}: {e}"),
    }
}

/// A panic's report goes through the log, in its format and in the span of
/// the request that caused it (the worker enters it), with its location;
/// the default hook wrote plain text to stderr, outside a JSON log. The
/// backtrace is included when `RUST_BACKTRACE` asks for one. Panics are
/// still caught: a 500 for the request, and the thread goes on.
fn log_panics() {
    std::panic::set_hook(Box::new(|info| {
        let payload = info.payload();
        let message = payload
            .downcast_ref::<&str>()
            .copied()
            .or_else(|| payload.downcast_ref::<String>().map(String::as_str))
            .unwrap_or("(not a string)");
        let location = info.location().map(ToString::to_string).unwrap_or_default();
        let backtrace = std::backtrace::Backtrace::capture();
        if backtrace.status() == std::backtrace::BacktraceStatus::Captured {
            tracing::error!(message, location, backtrace = %backtrace, "panic");
        } else {
            tracing::error!(message, location, "panic");
        }
    }));
}

fn init_logging(format: LogFormat) {
    use tracing_subscriber::EnvFilter;
    // Unset or empty: `info`. Set but unreadable: `info` too, and a warning
    // says so once logging works, so a typo is not taken silently.
    let (filter, rejected) = match std::env::var(EnvFilter::DEFAULT_ENV) {
        Ok(v) if !v.trim().is_empty() => match EnvFilter::try_new(&v) {
            Ok(filter) => (filter, None),
            Err(e) => (EnvFilter::new("info"), Some(format!("{v:?}: {e}"))),
        },
        _ => (EnvFilter::new("info"), None),
    };
    // Colour only on a terminal: `docker logs`, files and log collectors
    // would otherwise get raw escape sequences in every `text` line.
    use std::io::IsTerminal;
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(std::io::stdout().is_terminal());
    let _ = match format {
        LogFormat::Text => builder.try_init(),
        LogFormat::Json => builder
            .json()
            .flatten_event(true)
            .with_current_span(true)
            // The request span only, once: `spans` repeated it.
            .with_span_list(false)
            .try_init(),
    };
    if let Some(why) = rejected {
        tracing::warn!("RUST_LOG ignored, logging at info: {why}");
    }
}

/// `GET /healthz` over a plain TCP socket, for container health checks.
/// `addr` is `HOST:PORT` (`127.0.0.1:8080`, `localhost:8080`); every
/// address the host resolves to is tried in turn (`localhost` is often
/// `::1` first, where an IPv4-only service refuses).
pub fn healthcheck(addr: &str) -> Result<(), String> {
    use std::net::ToSocketAddrs;
    // The deadline starts before the name is resolved, which counts
    // against it (a resolver slower than 2 s is not cut short, though:
    // the system's lookup cannot be bounded from here).
    let deadline = std::time::Instant::now() + HEALTHCHECK_BUDGET;
    let addrs: Vec<SocketAddr> = addr
        .to_socket_addrs()
        .map_err(|e| format!("bad address {addr} (expected HOST:PORT): {e}"))?
        .collect();
    if addrs.is_empty() {
        return Err(format!("{addr} resolves to no address"));
    }
    check_until(&addrs, deadline)
}

/// All of a health check's work: a container's check is killed after its
/// own timeout, 3 s in ours.
const HEALTHCHECK_BUDGET: Duration = Duration::from_secs(2);

/// [`healthcheck`] on each of `addrs` in turn until one answers 200, all
/// within [`HEALTHCHECK_BUDGET`]. The error lists each address's failure.
pub fn healthcheck_any(addrs: &[SocketAddr]) -> Result<(), String> {
    check_until(addrs, std::time::Instant::now() + HEALTHCHECK_BUDGET)
}

fn check_until(addrs: &[SocketAddr], deadline: std::time::Instant) -> Result<(), String> {
    let mut failures = Vec::new();
    for addr in addrs {
        match healthz(addr, deadline) {
            Ok(()) => return Ok(()),
            Err(e) => failures.push(format!("{addr}: {e}")),
        }
    }
    Err(failures.join("; "))
}

/// One address, everything (connect, write, each read) within `deadline`.
fn healthz(addr: &SocketAddr, deadline: std::time::Instant) -> Result<(), String> {
    let left = || {
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        // A zero timeout is an error for connect and "none" for reads.
        if left.is_zero() {
            Err("timed out".to_owned())
        } else {
            Ok(left)
        }
    };
    let mut stream =
        std::net::TcpStream::connect_timeout(addr, left()?).map_err(|e| e.to_string())?;
    stream
        .set_write_timeout(Some(left()?))
        .map_err(|e| e.to_string())?;
    stream
        .write_all(b"GET /healthz HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n")
        .map_err(|e| e.to_string())?;
    // "HTTP/1.1 200", read in as many pieces as the peer sends, each read
    // bounded by what is left of the deadline (a trickling peer cannot
    // stretch it).
    let mut head = [0u8; 12];
    let mut got = 0;
    while got < head.len() {
        stream
            .set_read_timeout(Some(left()?))
            .map_err(|e| e.to_string())?;
        match stream.read(&mut head[got..]) {
            Ok(0) => return Err("connection closed before an answer".to_owned()),
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            // What a read timeout looks like on Unix ("Resource
            // temporarily unavailable").
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                return Err("timed out".to_owned());
            }
            Err(e) => return Err(e.to_string()),
        }
    }
    if head.starts_with(b"HTTP/1.1 200") {
        Ok(())
    } else {
        Err(format!("answer: {}", String::from_utf8_lossy(&head)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `--grpc-bind` that is taken ends the process with the flag named;
    /// the default taken leaves the service without gRPC.
    #[tokio::test]
    async fn a_taken_grpc_port_is_fatal_only_when_given() {
        let taken = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = taken.local_addr().unwrap();
        let e = bind_grpc(Some(addr), DEFAULT_GRPC_BIND).await.unwrap_err();
        assert_eq!(e.kind(), std::io::ErrorKind::AddrInUse);
        let message = e.to_string();
        assert!(
            message.starts_with(&format!("cannot listen on {addr}: address in use (")),
            "{message}"
        );
        assert!(
            message.ends_with("; pick another with --grpc-bind HOST:PORT (or ILQR_GRPC_BIND)"),
            "{message}"
        );
        assert!(bind_grpc(None, addr).await.unwrap().is_none());
        let free = bind_grpc(None, "127.0.0.1:0".parse().unwrap())
            .await
            .unwrap();
        assert!(free.is_some());
    }
}
