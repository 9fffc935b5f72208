//! `POST /solve/stream` over a real socket: one `iteration` event per
//! iteration, the rows of the result's own trace, then the `result` event
//! equal to `/solve`'s answer; refusals before the stream as problem
//! documents; an `error` event for a solve that expires in the queue; and a
//! client that closes the stream cancels its solve.

use std::time::{Duration, Instant};

use ilqr_service::server::Config;

use crate::common::{Server, slow};
use reqwest::StatusCode;
use serde_json::{Value, json};

/// The events of a whole stream, as `(event, data)`.
async fn events(res: reqwest::Response) -> Vec<(String, Value)> {
    assert_eq!(res.status(), StatusCode::OK);
    assert_eq!(res.headers()["content-type"], "text/event-stream");
    parse(&res.text().await.unwrap())
}

/// SSE text as `(event, data)` pairs; comments (keep-alives) skipped.
fn parse(text: &str) -> Vec<(String, Value)> {
    text.split("\n\n")
        .filter_map(|block| {
            let mut event = None;
            let mut data = String::new();
            for line in block.lines() {
                if let Some(name) = line.strip_prefix("event: ") {
                    event = Some(name.to_owned());
                } else if let Some(part) = line.strip_prefix("data: ") {
                    data.push_str(part);
                }
            }
            Some((event?, serde_json::from_str(&data).unwrap()))
        })
        .collect()
}

/// One `iteration` event per iteration of every start, each the start's
/// own trace row (tagged with its start in a search), then one `result`
/// event: the answer `/solve` gives for the same problem (the same
/// iterations and cost; solving is deterministic), whose trace is the
/// chosen start's rows.
#[tokio::test]
async fn a_stream_gives_each_iteration_then_the_result() {
    let s = Server::start(Config::default()).await;
    for doc in [
        json!({}),
        json!({"solver": {"multi_start": false}}),
        json!({"model": {"type": "unicycle"}, "integrator": "rk4", "output": {"trace": false}}),
    ] {
        let got = events(s.post_to("/solve/stream", &doc).await).await;
        let (last, rest) = got.split_last().unwrap();
        assert_eq!(last.0, "result", "{doc}");
        let result = &last.1;
        assert_eq!(result["status"], "converged");
        let starts = result["starts"].as_array().unwrap();
        let mut by_start = vec![Vec::new(); starts.len()];
        for (event, row) in rest {
            assert_eq!(event, "iteration");
            // A single solve's rows are the trace's, untagged.
            let start = row.get("start").map_or(0, |i| i.as_u64().unwrap() as usize);
            assert_eq!(row.get("start").is_some(), starts.len() > 1, "{doc}");
            let mut row = row.clone();
            row.as_object_mut().unwrap().remove("start");
            by_start[start].push(row);
        }
        for (i, rows) in by_start.iter().enumerate() {
            assert_eq!(
                rows.len() as u64,
                starts[i]["iterations"],
                "{doc}: start {i}"
            );
            for (k, row) in rows.iter().enumerate() {
                assert_eq!(row["iteration"], k + 1);
            }
            if starts[i]["chosen"] == true {
                assert_eq!(rows.len() as u64, result["iterations"], "{doc}");
                if let Some(trace) = result["trace"].as_array() {
                    assert_eq!(rows, trace, "{doc}: the chosen start's rows");
                }
            }
        }
        let plain: Value = s.post_to("/solve", &doc).await.json().await.unwrap();
        for member in ["iterations", "cost", "states", "controls", "status"] {
            assert_eq!(plain[member], result[member], "{member} of {doc}");
        }
    }
}

/// What is refused before the stream begins is answered as `/solve`
/// answers it: a problem document with its status.
#[tokio::test]
async fn an_invalid_problem_is_refused_before_the_stream() {
    let s = Server::start(Config::default()).await;
    let res = s
        .post_to(
            "/solve/stream",
            &json!({"model": {"type": "unicycle"}, "initial_state": [0, 0]}),
        )
        .await;
    assert_eq!(res.status(), StatusCode::UNPROCESSABLE_ENTITY);
    assert_eq!(res.headers()["content-type"], "application/problem+json");
    let p: Value = res.json().await.unwrap();
    assert_eq!(p["errors"][0]["pointer"], "/initial_state");
}

/// Behind a long solve on the one worker (before any solve has ended, so
/// admission has no estimate to refuse it by), a stream whose budget runs
/// out in the queue ends with an `error` event holding the problem
/// document `/solve` would answer, and no iteration.
#[tokio::test]
async fn a_solve_that_expires_in_the_queue_ends_the_stream_with_an_error_event() {
    let s = Server::start(Config {
        workers: std::num::NonZeroUsize::new(1),
        ..Config::default()
    })
    .await;
    let url = s.url("/solve");
    let busy = tokio::spawn(async move {
        reqwest::Client::new()
            .post(url)
            .json(&slow(3000))
            .send()
            .await
            .unwrap()
    });
    tokio::time::sleep(Duration::from_millis(300)).await;
    let got = events(
        s.post_to("/solve/stream", &json!({"solver": {"time_limit_ms": 200}}))
            .await,
    )
    .await;
    assert_eq!(got.len(), 1, "{got:?}");
    let (event, problem) = &got[0];
    assert_eq!(event, "error");
    assert_eq!(problem["type"], "urn:ilqr-service:expired-in-queue");
    assert_eq!(problem["status"], 503);
    assert_eq!(busy.await.unwrap().status(), StatusCode::OK);
}

/// A client that closes the stream after its first events cancels the
/// solve: the worker is free again long before the solve's budget.
#[tokio::test]
async fn closing_the_stream_cancels_the_solve() {
    let s = Server::start(Config {
        workers: std::num::NonZeroUsize::new(1),
        ..Config::default()
    })
    .await;
    let before = cancelled(&s).await;
    let mut res = s.post_to("/solve/stream", &slow(20_000)).await;
    assert_eq!(res.status(), StatusCode::OK);
    // The first iteration's event arrives, then the client hangs up.
    let mut seen = String::new();
    while !seen.contains("event: iteration") {
        let chunk = res.chunk().await.unwrap().expect("the stream goes on");
        seen.push_str(&String::from_utf8_lossy(&chunk));
    }
    drop(res);
    let started = Instant::now();
    // The one worker takes the next solve as soon as the cancelled one
    // stops: well within the 20 s budget of the first.
    let next: Value = s
        .post_to(
            "/solve",
            &json!({"output": {"gains": false, "trace": false}}),
        )
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(next["status"], "converged");
    assert!(
        started.elapsed() < Duration::from_secs(5),
        "the worker was held {:?}",
        started.elapsed()
    );
    // Counted as cancelled (the counter is the process's, shared with
    // other tests running at the same time: at least one more).
    assert!(cancelled(&s).await > before, "no cancelled solve counted");
}

/// `solves_total{status="cancelled",transport="http"}` as `/metrics` says.
async fn cancelled(s: &Server) -> u64 {
    let text = s.get("/metrics").await.text().await.unwrap();
    text.lines()
        .find_map(|l| l.strip_prefix(r#"solves_total{status="cancelled",transport="http"} "#))
        .and_then(|n| n.trim().parse().ok())
        .unwrap_or(0)
}
