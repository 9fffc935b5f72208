//! The in-process cost of a `POST /solve`, minus the network (divan).
//!
//! ```text
//! cargo bench --bench http_path
//! cargo bench --bench http_path -- request   # only the whole-path rows
//! ```
//!
//! The stages the handler runs for a request, on the body the load test
//! (`bench/load.sh`) sends:
//!
//! * `parse_validate`: `problem::parse` + `ProblemSpec::validate`;
//! * `solve`: `solve::solve` (builds the problem, a fresh `Solver`, solves,
//!   converts the trajectory, gains and trace to the wire types);
//! * `serialize`: [`SolveResult::to_json`], what the service's workers do;
//! * `request`: all three in a row, once on 1 thread and once on 2 threads
//!   at the same time. With `t=2`, each thread reports its own time per
//!   request, so the 2-core in-process ceiling is `2 / median` requests per
//!   second; `bench/load.sh` compares it with the HTTP throughput.
//!
//! With `HTTP_PATH_THROUGHPUT_SECS` set, the binary does not run divan but
//! measures requests per second over a fixed time on `HTTP_PATH_THREADS`
//! threads (see [`throughput`]); `bench/load.sh` uses that mode. With
//! `HTTP_PATH_COUNT` set it runs a fixed number of requests after a warm-up
//! (see [`count`]), for `bench/instructions.sh`.
//!
//! Each stage runs on two bodies (the seed's single solve, `multi_start`
//! false in both): `lean` = `{"output":{"gains":false,"trace":false}}`
//! (what `bench/load.sh` posts by default) and `full` = `{}` (the seed with
//! gains and trace in the answer).

use std::fmt;
use std::sync::atomic::AtomicBool;

use divan::{AllocProfiler, Bencher, black_box};
use ilqr_service::problem::{Limits, ProblemSpec, parse};
use ilqr_service::solve::{SolveResult, solve};

#[global_allocator]
static ALLOC: AllocProfiler = AllocProfiler::system();

fn main() {
    if let Ok(n) = std::env::var("HTTP_PATH_COUNT") {
        return count(&n);
    }
    match std::env::var("HTTP_PATH_THROUGHPUT_SECS") {
        Ok(secs) => throughput(&secs),
        Err(_) => divan::main(),
    }
}

/// `HTTP_PATH_BODY`: `lean` (the default) or `full`.
fn body_from_env() -> Body {
    match std::env::var("HTTP_PATH_BODY").as_deref() {
        Ok("full") => Body::Full,
        Ok("lean") | Err(_) => Body::Lean,
        Ok(other) => panic!("HTTP_PATH_BODY is lean or full, not {other}"),
    }
}

/// Count mode, for `bench/instructions.sh`: 5 warm-up requests on this
/// thread (the first builds the thread's solver workspace, as a server
/// worker's first request does), then `n` more inside [`measured`], the
/// one function whose instructions the script counts (callgrind
/// `--toggle-collect`), so the figure per request does not depend on how
/// many requests a timed run happened to finish.
fn count(n: &str) {
    let n: usize = n.parse().expect("HTTP_PATH_COUNT is a count");
    let body = body_from_env();
    let cancel = AtomicBool::new(false);
    for _ in 0..5 {
        black_box(handle(black_box(body.bytes()), &cancel));
    }
    measured(body, n, &cancel);
    println!("COUNT body={body:?} requests={n}");
}

#[inline(never)]
fn measured(body: Body, n: usize, cancel: &AtomicBool) {
    for _ in 0..n {
        black_box(handle(black_box(body.bytes()), cancel));
    }
}

/// Throughput mode, for `bench/load.sh`: `threads` threads run [`handle`]
/// back to back for `secs` seconds, like wrk against the server but without
/// the network, and one line is printed:
/// `THROUGHPUT body=lean threads=2 requests=N duration_s=D per_s=R cpu_s=C`
/// (`cpu_s`: user + system time of the process, from `/proc/self/stat`).
///
/// ```text
/// HTTP_PATH_THROUGHPUT_SECS=15 HTTP_PATH_THREADS=2 HTTP_PATH_BODY=lean \
///     cargo bench --bench http_path
/// ```
fn throughput(secs: &str) {
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::time::{Duration, Instant};

    let secs: f64 = secs.parse().expect("HTTP_PATH_THROUGHPUT_SECS is a number");
    let threads: usize = std::env::var("HTTP_PATH_THREADS")
        .map_or(2, |t| t.parse().expect("HTTP_PATH_THREADS is a count"));
    let body = body_from_env();
    let done = AtomicUsize::new(0);
    let cpu_start = process_cpu_seconds();
    let start = Instant::now();
    let deadline = start + Duration::from_secs_f64(secs);
    std::thread::scope(|scope| {
        for _ in 0..threads {
            scope.spawn(|| {
                let cancel = AtomicBool::new(false);
                let mut n = 0;
                while Instant::now() < deadline {
                    black_box(handle(black_box(body.bytes()), &cancel));
                    n += 1;
                }
                done.fetch_add(n, Ordering::Relaxed);
            });
        }
    });
    let elapsed = start.elapsed().as_secs_f64();
    let cpu = process_cpu_seconds().zip(cpu_start).map(|(b, a)| b - a);
    let n = done.load(Ordering::Relaxed);
    println!(
        "THROUGHPUT body={body:?} threads={threads} requests={n} duration_s={elapsed:.3} \
         per_s={:.2} cpu_s={}",
        n as f64 / elapsed,
        cpu.map_or("nan".to_owned(), |c| format!("{c:.3}"))
    );
}

/// User + system CPU time of this process (Linux `/proc/self/stat`, in
/// ticks of 1/100 s, the value of `getconf CLK_TCK` on Linux).
fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name, which is in parentheses.
    let rest = &stat[stat.rfind(')')? + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // utime and stime are fields 14 and 15 of the line, 12 and 13 here.
    let ticks: f64 = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

#[derive(Clone, Copy)]
enum Body {
    Lean,
    Full,
}

impl Body {
    fn bytes(self) -> &'static [u8] {
        match self {
            Self::Lean => {
                br#"{"solver":{"multi_start":false},"output":{"gains":false,"trace":false}}"#
            }
            Self::Full => br#"{"solver":{"multi_start":false}}"#,
        }
    }

    fn spec(self) -> ProblemSpec {
        let spec = parse(self.bytes()).expect("the body parses");
        spec.validate(&Limits::default())
            .expect("the body is valid");
        spec
    }

    fn result(self) -> SolveResult {
        solve(&self.spec(), None, &AtomicBool::new(false)).expect("the seed solves")
    }
}

impl fmt::Debug for Body {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Lean => "lean",
            Self::Full => "full",
        })
    }
}

const BODIES: [Body; 2] = [Body::Lean, Body::Full];

/// What the handler does with a body, start to finish (no network, no
/// queue): parse, validate, solve, serialise. Returns the response size.
fn handle(body: &[u8], cancel: &AtomicBool) -> usize {
    let spec = parse(body).expect("the body parses");
    spec.validate(&Limits::default())
        .expect("the body is valid");
    let result = solve(&spec, None, cancel).expect("the seed solves");
    result.to_json().expect("serialises").len()
}

#[divan::bench(args = BODIES)]
fn parse_validate(bencher: Bencher, body: Body) {
    let bytes = body.bytes();
    bencher.bench_local(|| {
        let spec = parse(black_box(bytes)).expect("the body parses");
        spec.validate(&Limits::default())
            .expect("the body is valid");
        spec
    });
}

#[divan::bench(args = BODIES)]
fn solve_only(bencher: Bencher, body: Body) {
    let spec = body.spec();
    let cancel = AtomicBool::new(false);
    bencher.bench_local(|| solve(black_box(&spec), None, &cancel).expect("the seed solves"));
}

#[divan::bench(args = BODIES)]
fn serialize(bencher: Bencher, body: Body) {
    let result = body.result();
    bencher.bench_local(|| black_box(&result).to_json().expect("serialises"));
}

/// The whole in-process path; `t=2` runs two requests at a time, one per
/// thread, each thread timing its own.
#[divan::bench(args = BODIES, threads = [1, 2])]
fn request(bencher: Bencher, body: Body) {
    let bytes = body.bytes();
    bencher.bench(|| {
        let cancel = AtomicBool::new(false);
        handle(black_box(bytes), &cancel)
    });
}
