//! What a small server answers under overload, from clients that ignore
//! `Retry-After`: each of `--clients` connections posts the problem again
//! as soon as any answer arrives, for `--secs`. A single-threaded tokio
//! client, light enough to leave the server its own core
//! (`bench/overload.sh` pins the two apart).
//!
//! ```text
//! cargo bench --bench overload -- --url http://127.0.0.1:8080 --problem FILE \
//!     [--clients 24] [--secs 20] [--budget-ms 500] [--pid PID]
//! ```
//!
//! Prints the answers by status; of the 200s, the share whose own
//! `Server-Timing` total (queue, solve and encoding) is within the budget
//! plus 10%, the share that ran at least one iteration, and the p50 / p99
//! of that total and of the latency the client sees; whether every 503
//! and 504 carried `Retry-After`; and, with `--pid`, the server's peak
//! RSS.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

struct Args {
    url: String,
    problem: String,
    clients: usize,
    secs: u64,
    budget_ms: f64,
    pid: Option<u32>,
}

fn args() -> Result<Args, String> {
    let mut a = Args {
        url: "http://127.0.0.1:8080".into(),
        problem: String::new(),
        clients: 24,
        secs: 20,
        budget_ms: 500.0,
        pid: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        if flag == "--bench" {
            continue;
        }
        let value = it.next().ok_or(format!("{flag} needs a value"))?;
        let bad = |e: &dyn std::fmt::Display| format!("{flag} {value}: {e}");
        match flag.as_str() {
            "--url" => a.url = value,
            "--problem" => a.problem = value,
            "--clients" => a.clients = value.parse().map_err(|e| bad(&e))?,
            "--secs" => a.secs = value.parse().map_err(|e| bad(&e))?,
            "--budget-ms" => a.budget_ms = value.parse().map_err(|e| bad(&e))?,
            "--pid" => a.pid = Some(value.parse().map_err(|e| bad(&e))?),
            _ => return Err(format!("unknown flag {flag}")),
        }
    }
    if a.problem.is_empty() {
        return Err("--problem FILE is required".into());
    }
    Ok(a)
}

/// One answer.
struct Answer {
    status: u16,
    /// Client-side, from sending the request to having the whole body.
    latency_ms: f64,
    /// `Server-Timing`'s total, for a 200.
    server_ms: Option<f64>,
    /// The result's `iterations`, for a 200.
    iterations: Option<u64>,
    retry_after: bool,
    problem_type: Option<String>,
}

async fn client(url: String, body: Arc<Vec<u8>>, until: Instant, answers: Arc<Mutex<Vec<Answer>>>) {
    let http = reqwest::Client::new();
    while Instant::now() < until {
        let t = Instant::now();
        let Ok(res) = http
            .post(format!("{url}/solve"))
            .header("content-type", "application/json")
            .body(body.as_ref().clone())
            .send()
            .await
        else {
            answers.lock().unwrap().push(Answer {
                status: 0,
                latency_ms: t.elapsed().as_secs_f64() * 1e3,
                server_ms: None,
                iterations: None,
                retry_after: false,
                problem_type: None,
            });
            tokio::time::sleep(Duration::from_millis(10)).await;
            continue;
        };
        let status = res.status().as_u16();
        let header = |name: &str| {
            res.headers()
                .get(name)
                .and_then(|v| v.to_str().ok())
                .map(str::to_owned)
        };
        let server_ms = header("server-timing").map(|v| {
            v.split(", ")
                .filter_map(|m| m.split_once(";dur="))
                .filter_map(|(_, d)| d.parse::<f64>().ok())
                .sum()
        });
        let retry_after = header("retry-after").is_some();
        let text = res.text().await.unwrap_or_default();
        let latency_ms = t.elapsed().as_secs_f64() * 1e3;
        // The result's top-level `iterations` is its first.
        let number_after = |key: &str| {
            text.find(key).and_then(|at| {
                text[at + key.len()..]
                    .split(|c: char| !c.is_ascii_digit())
                    .next()
                    .and_then(|n| n.parse().ok())
            })
        };
        let problem_type = text.find("urn:ilqr-service:").map(|at| {
            text[at + 17..]
                .split('"')
                .next()
                .unwrap_or_default()
                .to_owned()
        });
        answers.lock().unwrap().push(Answer {
            status,
            latency_ms,
            server_ms: (status == 200).then_some(server_ms).flatten(),
            iterations: (status == 200)
                .then(|| number_after("\"iterations\":"))
                .flatten(),
            retry_after,
            problem_type,
        });
    }
}

fn percentile(values: &mut [f64], p: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    values[((p * values.len() as f64) as usize).min(values.len() - 1)]
}

fn peak_rss_mib(pid: u32) -> Option<f64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

fn main() {
    let a = match args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(2);
        }
    };
    let body = Arc::new(std::fs::read(&a.problem).expect("the problem file"));
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let answers = Arc::new(Mutex::new(Vec::new()));
    let until = Instant::now() + Duration::from_secs(a.secs);
    runtime.block_on(async {
        let tasks: Vec<_> = (0..a.clients)
            .map(|_| {
                tokio::spawn(client(
                    a.url.clone(),
                    Arc::clone(&body),
                    until,
                    Arc::clone(&answers),
                ))
            })
            .collect();
        for t in tasks {
            let _ = t.await;
        }
    });
    let answers = answers.lock().unwrap();
    let mut by_status = std::collections::BTreeMap::new();
    let mut by_type = std::collections::BTreeMap::new();
    for x in answers.iter() {
        *by_status.entry(x.status).or_insert(0usize) += 1;
        if let Some(t) = &x.problem_type {
            *by_type.entry((x.status, t.clone())).or_insert(0usize) += 1;
        }
    }
    let ok: Vec<&Answer> = answers.iter().filter(|x| x.status == 200).collect();
    let within = ok
        .iter()
        .filter(|x| x.server_ms.is_some_and(|ms| ms <= 1.1 * a.budget_ms))
        .count();
    let optimised = ok
        .iter()
        .filter(|x| x.iterations.is_some_and(|n| n >= 1))
        .count();
    let refused: Vec<&Answer> = answers
        .iter()
        .filter(|x| x.status == 503 || x.status == 504)
        .collect();
    let mut server: Vec<f64> = ok.iter().filter_map(|x| x.server_ms).collect();
    let mut client: Vec<f64> = ok.iter().map(|x| x.latency_ms).collect();
    let share = |n: usize| 100.0 * n as f64 / ok.len().max(1) as f64;
    println!(
        "{} clients, {} s, budget {} ms: {} answers",
        a.clients,
        a.secs,
        a.budget_ms,
        answers.len()
    );
    println!("by status: {by_status:?}");
    println!("refusals by type: {by_type:?}");
    println!(
        "200s within budget + 10% (Server-Timing total): {within}/{} ({:.2}%)",
        ok.len(),
        share(within)
    );
    println!(
        "200s with at least one iteration: {optimised}/{} ({:.2}%)",
        ok.len(),
        share(optimised)
    );
    println!(
        "503/504 with Retry-After: {}/{}",
        refused.iter().filter(|x| x.retry_after).count(),
        refused.len()
    );
    println!(
        "200s, server total p50 / p99 / max: {:.1} / {:.1} / {:.1} ms",
        percentile(&mut server, 0.5),
        percentile(&mut server, 0.99),
        percentile(&mut server, 1.0)
    );
    println!(
        "200s, client latency p50 / p99 / max: {:.1} / {:.1} / {:.1} ms",
        percentile(&mut client, 0.5),
        percentile(&mut client, 0.99),
        percentile(&mut client, 1.0)
    );
    if let Some(rss) = a.pid.and_then(peak_rss_mib) {
        println!("server peak RSS: {rss:.1} MiB");
    }
}
