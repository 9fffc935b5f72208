//! gRPC against HTTP on one running server, in one run: solves per second
//! and the server's CPU time per solve, with the same load generator for
//! both (tokio; reqwest for HTTP/1.1 with keep-alive, tonic for gRPC over
//! one HTTP/2 connection per client).
//!
//! ```text
//! cargo bench --bench transports -- --pid PID --http 127.0.0.1:8080 \
//!     --grpc 127.0.0.1:50051 [--clients 8] [--secs 8] [--rounds 4] [--body lean|full]
//!     [--count N] [--only http|grpc]
//! ```
//!
//! `--count N` sends N solves per round (split over the clients) instead
//! of `--secs` of them, and `--only` one transport: what
//! `bench/transports_instructions.sh` needs to count instructions.
//!
//! `bench/transports.sh` starts the release server, pins it to CPU 0 and
//! this to CPU 1, and runs this. Rounds alternate HTTP and gRPC, so the
//! host's drift falls on both. The server's CPU is its process's user +
//! system time from `/proc/PID/stat` over the round, divided by the solves
//! answered (200 / OK): the work of the transport, parsing, the solve and
//! encoding, without the load generator's. Both send the seed problem;
//! `lean` asks for no gains and no trace, `full` for both.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use ilqr_service::grpc::proto::{self, trajectory_optimizer_client::TrajectoryOptimizerClient};

struct Args {
    pid: u32,
    http: String,
    grpc: String,
    clients: usize,
    secs: u64,
    rounds: usize,
    full: bool,
    /// Solves per round in all, split over the clients; 0: `secs` of them.
    count: u64,
    only: Option<String>,
}

fn args() -> Result<Args, String> {
    let mut a = Args {
        pid: 0,
        http: "127.0.0.1:8080".into(),
        grpc: "127.0.0.1:50051".into(),
        clients: 8,
        secs: 8,
        rounds: 4,
        full: false,
        count: 0,
        only: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        // `cargo bench` passes `--bench`; nothing else of its own.
        if flag == "--bench" {
            continue;
        }
        let value = it.next().ok_or(format!("{flag} needs a value"))?;
        let number = |v: &str| v.parse::<u64>().map_err(|e| format!("{flag}: {e}"));
        match flag.as_str() {
            "--pid" => a.pid = number(&value)? as u32,
            "--http" => a.http = value,
            "--grpc" => a.grpc = value,
            "--clients" => a.clients = number(&value)? as usize,
            "--secs" => a.secs = number(&value)?,
            "--rounds" => a.rounds = number(&value)? as usize,
            "--body" => a.full = value == "full",
            "--count" => a.count = number(&value)?,
            "--only" if value == "http" || value == "grpc" => a.only = Some(value),
            other => return Err(format!("unknown flag {other}")),
        }
    }
    if a.clients == 0 {
        return Err("--clients must be at least 1".into());
    }
    if a.count > 0 && !a.count.is_multiple_of(a.clients as u64) {
        return Err("--count must be a multiple of --clients".into());
    }
    if a.pid == 0 {
        return Err("--pid PID (the server's) is required".into());
    }
    Ok(a)
}

/// The server's (user, system) CPU time so far, in clock ticks.
fn cpu_ticks(pid: u32) -> (u64, u64) {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    // Fields after the command name (which is in parentheses).
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // utime and stime are fields 14 and 15 of the whole line: 11 and 12
    // after the state field that follows the name.
    let field = |i: usize| {
        fields
            .get(i)
            .and_then(|f| f.parse::<u64>().ok())
            .unwrap_or(0)
    };
    (field(11), field(12))
}

/// One client's share of a round: when to stop, and the round's counts.
#[derive(Clone)]
struct Tally {
    end: Instant,
    /// Solves this client sends; 0: until `end`.
    count: u64,
    sent: u64,
    solves: Arc<AtomicU64>,
    failed: Arc<AtomicU64>,
}

impl Tally {
    /// Whether to send another solve.
    fn more(&mut self) -> bool {
        self.sent += 1;
        if self.count > 0 {
            self.sent <= self.count
        } else {
            Instant::now() < self.end
        }
    }

    /// Count an answer: a solve, or a failure.
    fn record(&self, ok: bool) {
        let counter = if ok { &self.solves } else { &self.failed };
        counter.fetch_add(1, Ordering::Relaxed);
    }
}

/// A round of `a.clients` tasks, each made by `client` from its tally,
/// and the server's CPU time over it.
async fn round<F, Fut>(a: &Args, client: F) -> Round
where
    F: Fn(Tally) -> Fut,
    Fut: Future<Output = ()> + Send + 'static,
{
    let tally = Tally {
        end: Instant::now() + Duration::from_secs(a.secs),
        count: a.count / a.clients as u64,
        sent: 0,
        solves: Arc::new(AtomicU64::new(0)),
        failed: Arc::new(AtomicU64::new(0)),
    };
    let before = cpu_ticks(a.pid);
    let started = Instant::now();
    let tasks: Vec<_> = (0..a.clients)
        .map(|_| tokio::spawn(client(tally.clone())))
        .collect();
    for t in tasks {
        let _ = t.await;
    }
    Round {
        solves: tally.solves.load(Ordering::Relaxed),
        failed: tally.failed.load(Ordering::Relaxed),
        cpu: Cpu::since(a.pid, before),
        wall: started.elapsed(),
    }
}

/// The server's CPU time over a round, in seconds.
struct Cpu {
    total: f64,
    system: f64,
}

impl Cpu {
    fn since(pid: u32, (user, system): (u64, u64)) -> Cpu {
        let now = cpu_ticks(pid);
        Cpu {
            total: (now.0 + now.1 - user - system) as f64 / TICKS_PER_SEC,
            system: (now.1 - system) as f64 / TICKS_PER_SEC,
        }
    }
}

/// Clock ticks per second (`getconf CLK_TCK`): 100 on Linux.
const TICKS_PER_SEC: f64 = 100.0;

struct Round {
    solves: u64,
    failed: u64,
    cpu: Cpu,
    wall: Duration,
}

async fn http_round(a: &Args, body: &serde_json::Value) -> Round {
    let url = format!("http://{}/solve", a.http);
    round(a, |mut tally| {
        let (url, body) = (url.clone(), body.clone());
        async move {
            let client = reqwest::Client::new();
            while tally.more() {
                let ok = match client.post(&url).json(&body).send().await {
                    Ok(res) if res.status().is_success() => res.bytes().await.is_ok(),
                    _ => false,
                };
                tally.record(ok);
            }
        }
    })
    .await
}

async fn grpc_round(a: &Args, problem: &proto::Problem) -> Round {
    let endpoint = format!("http://{}", a.grpc);
    round(a, |mut tally| {
        let (endpoint, problem) = (endpoint.clone(), problem.clone());
        async move {
            let channel = match tonic::transport::Endpoint::from_shared(endpoint) {
                Ok(endpoint) => endpoint.connect().await.ok(),
                Err(_) => None,
            };
            // A client that cannot connect counts one failure.
            let Some(channel) = channel else {
                return tally.record(false);
            };
            let mut client = TrajectoryOptimizerClient::new(channel);
            while tally.more() {
                let request = proto::SolveRequest {
                    problem: Some(problem.clone()),
                };
                tally.record(client.solve(request).await.is_ok());
            }
        }
    })
    .await
}

fn report(name: &str, r: &Round) -> (f64, f64) {
    let per_sec = r.solves as f64 / r.wall.as_secs_f64();
    let per_solve = |secs: f64| secs * 1e3 / r.solves.max(1) as f64;
    let cpu_ms = per_solve(r.cpu.total);
    println!(
        "{name:5} {:8.1} solves/s  server CPU {cpu_ms:.3} ms/solve, {:.3} of it system  ({} solves, {} failed, {:.2} s CPU in {:.2} s)",
        per_sec,
        per_solve(r.cpu.system),
        r.solves,
        r.failed,
        r.cpu.total,
        r.wall.as_secs_f64()
    );
    (per_sec, cpu_ms)
}

fn main() {
    let a = match args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(2);
        }
    };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("a runtime");
    let output = if a.full {
        serde_json::json!({"solver": {"multi_start": false}})
    } else {
        serde_json::json!({"solver": {"multi_start": false}, "output": {"gains": false, "trace": false}})
    };
    // The seed's single solve, the figures' subject since before the search.
    let problem = proto::Problem {
        output: (!a.full).then_some(proto::OutputOptions {
            gains: Some(false),
            trace: Some(false),
        }),
        solver: Some(proto::SolverOptions {
            multi_start: Some(false),
            ..Default::default()
        }),
        ..Default::default()
    };
    println!(
        "{} clients, {} s rounds, {} rounds per transport, {} body",
        a.clients,
        a.secs,
        a.rounds,
        if a.full { "full" } else { "lean" }
    );
    let (mut http, mut grpc) = (Vec::new(), Vec::new());
    runtime.block_on(async {
        for _ in 0..a.rounds {
            if a.only.as_deref() != Some("grpc") {
                http.push(report("http", &http_round(&a, &output).await));
            }
            if a.only.as_deref() != Some("http") {
                grpc.push(report("grpc", &grpc_round(&a, &problem).await));
            }
        }
    });
    if http.is_empty() || grpc.is_empty() {
        return;
    }
    // Medians over the rounds: a round the host's other tenants slowed
    // moves a mean, not a median.
    let median = |v: &[(f64, f64)], f: fn(&(f64, f64)) -> f64| {
        let mut xs: Vec<f64> = v.iter().map(f).collect();
        xs.sort_by(f64::total_cmp);
        let n = xs.len();
        (xs[(n - 1) / 2] + xs[n / 2]) / 2.0
    };
    let (h_rate, h_cpu) = (median(&http, |x| x.0), median(&http, |x| x.1));
    let (g_rate, g_cpu) = (median(&grpc, |x| x.0), median(&grpc, |x| x.1));
    println!(
        "median: http {h_rate:.1} solves/s, {h_cpu:.3} ms CPU/solve; grpc {g_rate:.1} solves/s, {g_cpu:.3} ms CPU/solve; grpc/http CPU per solve {:.3}, throughput {:.3}",
        g_cpu / h_cpu,
        g_rate / h_rate
    );
}
