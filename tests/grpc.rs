//! The gRPC service over real sockets on 127.0.0.1, beside the HTTP API of
//! the same process: answers equal to HTTP's and the solver's own, the
//! progress stream, every error class with its standard details, deadlines,
//! cancellation, health through a drain, reflection.

use std::time::{Duration, Instant};

use ilqr_service::grpc::proto::trajectory_optimizer_client::TrajectoryOptimizerClient;
use ilqr_service::grpc::proto::{self, solve_event::Event};
use ilqr_service::grpc::status::field_path;
use ilqr_service::server::Config;
use serde_json::{Value, json};
use tonic::transport::Channel;
use tonic::{Code, Request};
use tonic_types::StatusExt;

use crate::common::Server;

type Client = TrajectoryOptimizerClient<Channel>;

impl Server {
    async fn channel(&self) -> Channel {
        let grpc = self.grpc.expect("started with gRPC");
        tonic::transport::Endpoint::from_shared(format!("http://{grpc}"))
            .unwrap()
            .connect()
            .await
            .unwrap()
    }

    async fn client(&self) -> Client {
        Client::new(self.channel().await)
    }

    async fn post_json(&self, path: &str, body: &Value) -> Value {
        self.post_to(path, body).await.json().await.unwrap()
    }

    async fn get_json(&self, path: &str) -> Value {
        self.get(path).await.json().await.unwrap()
    }
}

fn one_worker(queue_capacity: usize) -> Config {
    Config {
        workers: std::num::NonZeroUsize::new(1),
        queue_capacity,
        ..Config::default()
    }
}

fn solve_request(problem: proto::Problem) -> proto::SolveRequest {
    proto::SolveRequest {
        problem: Some(problem),
    }
}

/// A solve that runs until its budget: 10000 steps, no tolerance, 100
/// distant obstacles (about 0.1 s an iteration).
fn slow(time_limit_ms: u64) -> proto::Problem {
    proto::Problem {
        horizon: Some(10000),
        dt: Some(0.0005),
        obstacles: Some(proto::Obstacles {
            items: (0..100)
                .map(|j| proto::Obstacle {
                    center: vec![1000.0 + f64::from(j), 1000.0],
                    weight: Some(1.0),
                    ..Default::default()
                })
                .collect(),
        }),
        solver: Some(proto::SolverOptions {
            tolerance: Some(0.0),
            max_iterations: Some(10000),
            time_limit_ms: Some(time_limit_ms),
            ..Default::default()
        }),
        output: Some(proto::OutputOptions {
            gains: Some(false),
            trace: Some(false),
        }),
        ..Default::default()
    }
}

/// A JSON array of arrays of numbers, flattened.
fn flat(rows: &Value) -> Vec<f64> {
    rows.as_array()
        .unwrap()
        .iter()
        .flat_map(|row| row.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()))
        .collect()
}

fn numbers(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

/// A gRPC result equals an HTTP one, every number to the last bit.
fn assert_same_result(g: &proto::SolveResult, h: &Value) {
    assert_eq!(g.model, h["model"].as_str().unwrap());
    assert_eq!(g.cost, h["cost"].as_f64().unwrap());
    assert_eq!(g.initial_cost, h["initial_cost"].as_f64().unwrap());
    assert_eq!(u64::from(g.iterations), h["iterations"].as_u64().unwrap());
    assert_eq!(g.goal_distance, h["goal_distance"].as_f64().unwrap());
    assert_eq!(g.closest_approach, numbers(&h["closest_approach"]));
    assert_eq!(g.states, flat(&h["states"]));
    assert_eq!(g.controls, flat(&h["controls"]));
    assert_eq!(
        g.state_dim as usize,
        h["states"][0].as_array().unwrap().len()
    );
    assert_eq!(
        g.control_dim as usize,
        h["controls"][0].as_array().unwrap().len()
    );
    match (&g.gains, h.get("gains")) {
        (Some(gains), Some(hg)) => {
            let feedback: Vec<f64> = hg["feedback"]
                .as_array()
                .unwrap()
                .iter()
                .flat_map(flat)
                .collect();
            assert_eq!(gains.feedback, feedback);
            assert_eq!(gains.feedforward, flat(&hg["feedforward"]));
            assert_eq!(gains.regularization, hg["regularization"].as_f64().unwrap());
        }
        (None, None) => {}
        (g, h) => panic!("gains: {g:?} against {h:?}"),
    }
    let trace = h["trace"].as_array().map_or(&[][..], Vec::as_slice);
    assert_eq!(g.trace.len(), trace.len());
    for (row, json) in g.trace.iter().zip(trace) {
        assert_same_row(row, json);
    }
}

fn assert_same_row(g: &proto::TraceEntry, h: &Value) {
    assert_eq!(u64::from(g.iteration), h["iteration"].as_u64().unwrap());
    assert_eq!(g.cost, h["cost"].as_f64().unwrap());
    assert_eq!(
        g.expected_reduction,
        h["expected_reduction"].as_f64().unwrap()
    );
    assert_eq!(g.actual_reduction, h["actual_reduction"].as_f64().unwrap());
    assert_eq!(g.step_size, h["step_size"].as_f64().unwrap());
    assert_eq!(g.regularization, h["regularization"].as_f64().unwrap());
    assert_eq!(g.convex_model, h["convex_model"].as_bool().unwrap());
}

/// `Solve` of an empty request, and of an empty problem, is the seed
/// scenario: the same cost, to the last digit, and the same trajectory as
/// `POST /solve {}` and as the solver called directly.
#[tokio::test]
async fn an_empty_problem_solves_as_over_http_and_in_process() {
    let s = Server::with_grpc(Config::default()).await;
    let mut client = s.client().await;
    let http = s.post_json("/solve", &json!({})).await;
    let direct = ilqr_service::solve::solve(
        &ilqr_service::problem::ProblemSpec::default(),
        None,
        &std::sync::atomic::AtomicBool::new(false),
    )
    .unwrap();
    for request in [
        proto::SolveRequest { problem: None },
        solve_request(proto::Problem::default()),
    ] {
        let response = client.solve(request).await.unwrap();
        assert!(response.metadata().contains_key("x-request-id"));
        let timing = response
            .metadata()
            .get("server-timing")
            .unwrap()
            .to_str()
            .unwrap();
        assert!(timing.starts_with("queue;dur="), "{timing}");
        let r = response.into_inner().result.unwrap();
        assert_eq!(r.status(), proto::SolveStatus::Converged);
        assert_eq!(r.integrator(), proto::Integrator::Euler);
        assert_same_result(&r, &http);
        assert_eq!(r.cost, direct.cost);
        assert_eq!(r.states, direct.states.flat());
        assert_eq!((r.state_dim, r.control_dim), (6, 2));
        assert_eq!(r.states.len(), 101 * 6);
        assert_eq!(r.gains.unwrap().feedback.len(), 100 * 2 * 6);
    }
}

/// A unicycle problem with RK4, its own obstacles and a flat initial
/// guess solves as its JSON document does over HTTP.
#[tokio::test]
async fn a_unicycle_problem_solves_as_its_json_does() {
    let s = Server::with_grpc(Config::default()).await;
    let guess: Vec<f64> = (0..40).flat_map(|k| [0.5, 0.01 * f64::from(k)]).collect();
    let problem = proto::Problem {
        model: Some(proto::Model {
            r#type: Some("unicycle".into()),
            ..Default::default()
        }),
        integrator: proto::Integrator::Rk4.into(),
        horizon: Some(40),
        dt: Some(0.1),
        goal_state: vec![3.0, 1.0, 0.0],
        obstacles: Some(proto::Obstacles {
            items: vec![proto::Obstacle {
                center: vec![1.5, 0.4],
                weight: None,
                ..Default::default()
            }],
        }),
        initial_controls: guess.clone(),
        ..Default::default()
    };
    let rows: Vec<Value> = guess.chunks(2).map(|r| json!(r)).collect();
    let doc = json!({
        "model": {"type": "unicycle"}, "integrator": "rk4", "horizon": 40, "dt": 0.1,
        "goal_state": [3.0, 1.0, 0.0], "obstacles": [{"center": [1.5, 0.4]}],
        "initial_controls": rows,
    });
    let r = s
        .client()
        .await
        .solve(solve_request(problem))
        .await
        .unwrap()
        .into_inner()
        .result
        .unwrap();
    assert_eq!(r.model, "unicycle");
    assert_eq!(r.integrator(), proto::Integrator::Rk4);
    assert_eq!((r.state_dim, r.control_dim), (3, 2));
    assert_eq!(r.states.len(), 41 * 3);
    assert_eq!(r.gains.as_ref().unwrap().feedback.len(), 40 * 2 * 3);
    assert_same_result(&r, &s.post_json("/solve", &doc).await);
}

/// `SolveStream`: one iteration event per iteration, the rows of the
/// result's trace, then the result, which is `Solve`'s answer.
/// ALTRO's Dubins car with its hard circles, bounds (infinite: none) and
/// goal equality solves over gRPC as its JSON does over HTTP, with the
/// same constraint report and warnings; and an unknown shape is a field
/// violation.
#[tokio::test]
async fn a_constrained_problem_solves_as_its_json_does() {
    let s = Server::with_grpc(Config::default()).await;
    let doc: Value =
        serde_json::from_str(include_str!("../examples/dubins_three_obstacles.json")).unwrap();
    let circle = |c: f64| proto::Obstacle {
        center: vec![c, c],
        weight: Some(0.0),
        shape: proto::ObstacleShape::Circle.into(),
        radius: Some(0.425),
        clearance: Some(0.0),
        ..Default::default()
    };
    let problem = proto::Problem {
        model: Some(proto::Model {
            r#type: Some("unicycle".into()),
            ..Default::default()
        }),
        integrator: proto::Integrator::Rk4.into(),
        dt: Some(0.05),
        horizon: Some(100),
        initial_state: vec![0.0, 0.0, 0.0],
        goal_state: vec![3.0, 3.0, 0.0],
        weights: Some(proto::Weights {
            state: vec![1.0; 3],
            control: vec![0.5; 2],
            terminal: vec![10.0; 3],
        }),
        obstacles: Some(proto::Obstacles {
            items: vec![circle(0.75), circle(1.5), circle(2.25)],
        }),
        initial_controls: vec![0.01; 200],
        constraints: Some(proto::Constraints {
            control: Some(proto::Bounds {
                lower: vec![0.0, -3.0],
                upper: vec![3.0, 3.0],
            }),
            state: Some(proto::Bounds {
                lower: vec![f64::NEG_INFINITY; 3],
                upper: vec![],
            }),
            goal_tolerance: vec![0.0; 3],
        }),
        ..Default::default()
    };
    let mut with_state = doc.clone();
    with_state["constraints"]["state"] = json!({"lower": [null, null, null]});
    let http = s.post_json("/solve", &with_state).await;
    let r = s
        .client()
        .await
        .solve(solve_request(problem.clone()))
        .await
        .unwrap()
        .into_inner()
        .result
        .unwrap();
    assert_eq!(r.status(), proto::SolveStatus::Converged);
    assert_eq!(r.cost, http["cost"].as_f64().unwrap());
    assert_eq!(
        r.constraint_violation,
        http["constraint_violation"].as_f64().unwrap()
    );
    let report = r.constraint_report.unwrap();
    assert_eq!(report.obstacles.len(), 3);
    assert_eq!(
        u64::from(report.outer_iterations),
        http["constraint_report"]["outer_iterations"]
            .as_u64()
            .unwrap()
    );
    assert!(r.trace.iter().all(|t| t.outer_iteration.is_some()));

    let mut bad = problem;
    bad.obstacles.as_mut().unwrap().items[1].shape = 9;
    let status = s
        .client()
        .await
        .solve(solve_request(bad))
        .await
        .unwrap_err();
    assert_eq!(status.code(), tonic::Code::InvalidArgument);
    assert!(
        status.message().contains("obstacles[1].shape")
            || format!("{status:?}").contains("obstacles[1].shape"),
        "{status:?}"
    );
}

#[tokio::test]
async fn a_stream_gives_each_iteration_then_the_result() {
    let s = Server::with_grpc(Config::default()).await;
    let mut client = s.client().await;
    let mut stream = client
        .solve_stream(proto::SolveRequest { problem: None })
        .await
        .unwrap()
        .into_inner();
    let mut rows = Vec::new();
    let mut result = None;
    while let Some(event) = stream.message().await.unwrap() {
        assert!(result.is_none(), "an event after the result");
        match event.event.unwrap() {
            Event::Iteration(row) => rows.push(row),
            Event::Result(r) => result = Some(r),
        }
    }
    let result = result.expect("no result event");
    // The seed searches: every start's rows, each tagged with its start;
    // the chosen start's are the trace.
    assert_eq!(result.starts.len(), 2);
    for (i, start) in result.starts.iter().enumerate() {
        let mine: Vec<_> = rows
            .iter()
            .filter(|r| r.start == Some(i as u32))
            .map(|r| proto::TraceEntry { start: None, ..*r })
            .collect();
        assert_eq!(mine.len(), start.iterations as usize, "start {i}");
        for (k, row) in mine.iter().enumerate() {
            assert_eq!(row.iteration as usize, k + 1);
        }
        if start.chosen {
            assert_eq!(mine, result.trace);
            assert_eq!(start.cost, result.cost);
        }
    }
    assert_eq!(
        rows.len(),
        result
            .starts
            .iter()
            .map(|s| s.iterations as usize)
            .sum::<usize>()
    );
    assert!((result.cost - 5418.304).abs() < 1e-3, "{}", result.cost);
    let plain = client
        .solve(proto::SolveRequest { problem: None })
        .await
        .unwrap()
        .into_inner()
        .result
        .unwrap();
    assert_eq!((plain.cost, &plain.states), (result.cost, &result.states));
}

/// `(field, description)` of each field violation of an INVALID_ARGUMENT.
fn violations(status: &tonic::Status) -> Vec<(String, String)> {
    assert_eq!(status.code(), Code::InvalidArgument, "{status:?}");
    let details = status.get_error_details();
    let info = details.error_info().unwrap();
    assert_eq!(
        (info.reason.as_str(), info.domain.as_str()),
        ("VALIDATION", "ilqr-service")
    );
    assert_eq!(info.metadata["type"], "urn:ilqr-service:validation");
    details
        .bad_request()
        .unwrap()
        .field_violations
        .iter()
        .map(|v| (v.field.clone(), v.description.clone()))
        .collect()
}

/// `(field, detail)` of each error of an HTTP 422, the pointers written as
/// paths.
async fn http_errors(s: &Server, doc: &Value) -> Vec<(String, String)> {
    let problem = s.post_json("/solve", doc).await;
    assert_eq!(problem["status"], 422, "{problem}");
    problem["errors"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            let pointer = e["pointer"].as_str().unwrap();
            (
                field_path(pointer),
                e["detail"].as_str().unwrap().to_owned(),
            )
        })
        .collect()
}

/// Invalid input is INVALID_ARGUMENT with a field violation per error,
/// several at once, for each model: the same errors and words as HTTP's 422
/// for the same document (a flat array's violation also says where the row
/// is in it), plus what JSON cannot carry (NaN, an enum value the contract
/// does not have). The caller's request id comes back in RequestInfo.
#[tokio::test]
async fn invalid_problems_list_every_error_as_a_field_violation() {
    let s = Server::with_grpc(Config::default()).await;
    let mut client = s.client().await;

    // The quadrotor: wrong lengths, values out of range, an unknown
    // parameter, a short centre, a flat guess that ends in half a row.
    let guess: Vec<f64> = vec![1.0; 199];
    let problem = proto::Problem {
        model: Some(proto::Model {
            r#type: None,
            parameters: [("mass".to_owned(), -1.0), ("foo".to_owned(), 1.0)].into(),
        }),
        dt: Some(-1.0),
        horizon: Some(100),
        initial_state: vec![0.0; 3],
        goal_state: vec![4.0, 9.0, f64::NAN, 0.0, 0.0, 0.0],
        obstacles: Some(proto::Obstacles {
            items: vec![
                proto::Obstacle {
                    center: vec![1.0, 2.0],
                    weight: None,
                    ..Default::default()
                },
                proto::Obstacle {
                    center: vec![1.0],
                    weight: None,
                    ..Default::default()
                },
            ],
        }),
        initial_controls: guess.clone(),
        solver: Some(proto::SolverOptions {
            time_limit_ms: Some(0),
            ..Default::default()
        }),
        ..Default::default()
    };
    let rows: Vec<Value> = guess.chunks(2).map(|r| json!(r)).collect();
    let doc = json!({
        "model": {"mass": -1.0, "foo": 1.0}, "dt": -1.0, "horizon": 100,
        "initial_state": [0.0, 0.0, 0.0], "goal_state": [4.0, 9.0, 0.0, 0.0, 0.0, 0.0],
        "obstacles": [{"center": [1.0, 2.0]}, {"center": [1.0]}],
        "initial_controls": rows, "solver": {"time_limit_ms": 0},
    });
    let mut request = Request::new(solve_request(problem));
    request
        .metadata_mut()
        .insert("x-request-id", "grpc-test-1".parse().unwrap());
    let status = client.solve(request).await.unwrap_err();
    assert_eq!(
        status
            .get_error_details()
            .request_info()
            .unwrap()
            .request_id,
        "grpc-test-1"
    );
    assert_eq!(
        status.metadata().get("x-request-id").unwrap(),
        "grpc-test-1"
    );
    let mut got = violations(&status);
    assert!(
        status.message().starts_with("8 invalid fields; "),
        "{}",
        status.message()
    );
    let nan = got.remove(
        got.iter()
            .position(|(field, _)| field == "goal_state[2]")
            .expect("no violation for the NaN"),
    );
    assert_eq!(nan.1, "got NaN: expected a finite number");
    let want = http_errors(&s, &doc).await;
    assert_eq!(got.len(), want.len(), "{got:#?}\n{want:#?}");
    for ((field, description), (path, detail)) in got.iter().zip(&want) {
        assert_eq!(field, path);
        assert!(
            description.starts_with(detail.as_str()),
            "{field}: {description} against {detail}"
        );
    }
    let fields: Vec<&str> = got.iter().map(|(f, _)| f.as_str()).collect();
    for field in [
        "model.foo",
        "model.mass",
        "dt",
        "initial_state",
        "obstacles[1].center",
        "initial_controls[99]",
        "solver.time_limit_ms",
    ] {
        assert!(fields.contains(&field), "{field} not in {fields:?}");
    }
    let last_row = &got
        .iter()
        .find(|(f, _)| f == "initial_controls[99]")
        .unwrap()
        .1;
    assert!(
        last_row.ends_with("(row 99 of the flat initial_controls: its entry 198)"),
        "{last_row}"
    );

    // The unicycle: a parameter it does not have, lengths of the
    // quadrotor's, both kinds of initial guess, and an integrator the
    // contract does not define.
    let guess: Vec<f64> = vec![0.0; 120];
    let problem = proto::Problem {
        model: Some(proto::Model {
            r#type: Some("unicycle".into()),
            parameters: [("mass".to_owned(), 1.0)].into(),
        }),
        integrator: 9,
        initial_state: vec![0.0; 6],
        weights: Some(proto::Weights {
            control: vec![1.0; 3],
            ..Default::default()
        }),
        initial_controls: guess.clone(),
        warm_start_controls: guess.clone(),
        solver: Some(proto::SolverOptions {
            tolerance: Some(2.0),
            ..Default::default()
        }),
        ..Default::default()
    };
    let rows: Vec<Value> = guess.chunks(2).map(|r| json!(r)).collect();
    let doc = json!({
        "model": {"type": "unicycle", "mass": 1.0}, "initial_state": [0, 0, 0, 0, 0, 0],
        "weights": {"control": [1, 1, 1]}, "initial_controls": rows,
        "warm_start": {"controls": rows}, "solver": {"tolerance": 2.0},
    });
    let status = client.solve(solve_request(problem)).await.unwrap_err();
    let mut got = violations(&status);
    let integrator = got.remove(0);
    assert_eq!(integrator.0, "integrator");
    assert!(
        integrator
            .1
            .starts_with("unknown Integrator value 9: expected INTEGRATOR_EULER (1)"),
        "{}",
        integrator.1
    );
    let want = http_errors(&s, &doc).await;
    assert_eq!(got.len(), want.len(), "{got:#?}\n{want:#?}");
    for ((field, description), (path, detail)) in got.iter().zip(&want) {
        assert_eq!(field, path);
        assert!(description.starts_with(detail.as_str()), "{description}");
    }
    let both = &got.iter().find(|(f, _)| f == "warm_start").unwrap().1;
    assert!(
        both.ends_with("(warm_start is warm_start_controls here)"),
        "{both}"
    );
    assert!(got.iter().any(|(f, d)| f == "model.mass"
        && d.starts_with("unknown field `mass`: model `unicycle` has no parameters")));

    // One error: the message is that error.
    let status = client
        .solve(solve_request(proto::Problem {
            dt: Some(0.0),
            ..Default::default()
        }))
        .await
        .unwrap_err();
    assert_eq!(violations(&status).len(), 1);
    assert!(
        status
            .message()
            .starts_with("dt: must be a positive number"),
        "{}",
        status.message()
    );
}

/// `solves_total` of `status` for the gRPC transport, as `/metrics` says
/// (the counter is the process's, shared by the tests running at once).
async fn solves_total(s: &Server, status: &str) -> u64 {
    let text = s.get("/metrics").await.text().await.unwrap();
    let series = format!("solves_total{{status=\"{status}\",transport=\"grpc\"}} ");
    text.lines()
        .find_map(|l| l.strip_prefix(series.as_str()))
        .and_then(|n| n.trim().parse().ok())
        .unwrap_or(0)
}

/// Overload is RESOURCE_EXHAUSTED with RetryInfo, at once: a solve whose
/// budget runs out in the queue (behind a long solve on the one worker,
/// admitted before any solve ended gave an estimate), then a full queue.
#[tokio::test]
async fn overload_is_resource_exhausted_with_retry_info() {
    let s = Server::with_grpc(one_worker(1)).await;
    let channel = s.channel().await;
    let running = tokio::spawn({
        let mut client = Client::new(channel.clone());
        async move { client.solve(solve_request(slow(20_000))).await }
    });
    tokio::time::sleep(Duration::from_millis(300)).await;
    let mut client = Client::new(channel.clone());

    let mut short = slow(200);
    short.horizon = Some(100);
    let started = Instant::now();
    let expired = client.solve(solve_request(short)).await.unwrap_err();
    assert_eq!(expired.code(), Code::ResourceExhausted, "{expired:?}");
    assert!(started.elapsed() < Duration::from_secs(2));
    assert!(
        expired.message().contains("ran out before it could start"),
        "{}",
        expired.message()
    );
    let details = expired.get_error_details();
    assert_eq!(details.error_info().unwrap().reason, "EXPIRED_IN_QUEUE");
    let delay = details.retry_info().unwrap().retry_delay.unwrap();
    assert!(delay >= Duration::from_secs(1), "{delay:?}");

    let queued = tokio::spawn({
        let mut client = Client::new(channel.clone());
        async move { client.solve(solve_request(slow(20_000))).await }
    });
    tokio::time::sleep(Duration::from_millis(200)).await;
    let started = Instant::now();
    let full = client
        .solve(proto::SolveRequest { problem: None })
        .await
        .unwrap_err();
    assert!(started.elapsed() < Duration::from_millis(500));
    assert_eq!(full.code(), Code::ResourceExhausted, "{full:?}");
    assert!(
        full.message()
            .starts_with("every worker is busy and the queue is full"),
        "{}",
        full.message()
    );
    let details = full.get_error_details();
    assert_eq!(details.error_info().unwrap().reason, "OVERLOADED");
    assert_eq!(
        details.retry_info().unwrap().retry_delay,
        Some(Duration::from_secs(1))
    );
    // Both callers leave; their solves stop.
    running.abort();
    queued.abort();
}

/// A deadline shorter than the problem's budget ends the solve a margin
/// before it: the caller gets the best trajectory so far, status
/// TIME_LIMIT, in time, on `Solve` and on `SolveStream`.
#[tokio::test]
async fn a_short_deadline_answers_time_limit_before_it() {
    let s = Server::with_grpc(Config::default()).await;
    let mut client = s.client().await;
    let deadline = Duration::from_millis(700);
    let mut request = Request::new(solve_request(slow(20_000)));
    request.set_timeout(deadline);
    let started = Instant::now();
    let r = client.solve(request).await.unwrap().into_inner();
    let took = started.elapsed();
    let r = r.result.unwrap();
    assert_eq!(r.status(), proto::SolveStatus::TimeLimit);
    assert!(took < deadline, "{took:?}");
    assert_eq!(r.states.len(), 10_001 * 6);

    let mut request = Request::new(solve_request(slow(20_000)));
    request.set_timeout(deadline);
    let started = Instant::now();
    let mut stream = client.solve_stream(request).await.unwrap().into_inner();
    let mut last = None;
    while let Some(event) = stream.message().await.unwrap() {
        last = event.event;
    }
    assert!(started.elapsed() < deadline, "{:?}", started.elapsed());
    let Some(Event::Result(r)) = last else {
        panic!("the stream ended with {last:?}")
    };
    assert_eq!(r.status(), proto::SolveStatus::TimeLimit);
}

/// A caller that cancels stops its solve, on `Solve` and on
/// `SolveStream`: the one worker takes the next solve at once, long
/// before the first one's budget, and the solve counts as cancelled.
#[tokio::test]
async fn a_caller_that_cancels_frees_the_worker() {
    let s = Server::with_grpc(one_worker(4)).await;
    let mut client = s.client().await;
    let before = solves_total(&s, "cancelled").await;

    let leaving = tokio::spawn({
        let mut client = client.clone();
        async move { client.solve(solve_request(slow(20_000))).await }
    });
    tokio::time::sleep(Duration::from_millis(300)).await;
    leaving.abort();
    let started = Instant::now();
    let next = client
        .solve(proto::SolveRequest { problem: None })
        .await
        .unwrap()
        .into_inner()
        .result
        .unwrap();
    assert_eq!(next.status(), proto::SolveStatus::Converged);
    assert!(
        started.elapsed() < Duration::from_secs(3),
        "{:?}",
        started.elapsed()
    );

    let mut stream = client
        .solve_stream(solve_request(slow(20_000)))
        .await
        .unwrap()
        .into_inner();
    let first = stream.message().await.unwrap().unwrap();
    assert!(
        matches!(first.event, Some(Event::Iteration(_))),
        "{first:?}"
    );
    drop(stream);
    let started = Instant::now();
    client
        .solve(proto::SolveRequest { problem: None })
        .await
        .unwrap();
    assert!(
        started.elapsed() < Duration::from_secs(3),
        "{:?}",
        started.elapsed()
    );
    assert!(solves_total(&s, "cancelled").await >= before + 2);
}

/// On shutdown the health service turns NOT_SERVING, for the server and
/// for the optimizer, while the drain lets the call in flight finish: it
/// gets its answer; a new call is UNAVAILABLE; then the server returns.
#[tokio::test]
async fn a_drain_turns_health_not_serving_and_finishes_calls_in_flight() {
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::{HealthCheckRequest, health_client::HealthClient};
    let mut s = Server::with_grpc(Config::default()).await;
    let channel = s.channel().await;
    let mut health = HealthClient::new(channel.clone());
    let check = |health: &mut HealthClient<Channel>, service: &str| {
        let mut health = health.clone();
        let request = HealthCheckRequest {
            service: service.into(),
        };
        async move { health.check(request).await.unwrap().into_inner().status() }
    };
    for service in ["", "ilqr.v1.TrajectoryOptimizer"] {
        assert_eq!(check(&mut health, service).await, ServingStatus::Serving);
    }
    let in_flight = tokio::spawn({
        let mut client = Client::new(channel.clone());
        async move { client.solve(solve_request(slow(1500))).await }
    });
    tokio::time::sleep(Duration::from_millis(300)).await;
    let _ = s.stop.take().unwrap().send(());
    tokio::time::sleep(Duration::from_millis(200)).await;
    for service in ["", "ilqr.v1.TrajectoryOptimizer"] {
        assert_eq!(check(&mut health, service).await, ServingStatus::NotServing);
    }
    let refused = Client::new(channel.clone())
        .solve(proto::SolveRequest { problem: None })
        .await
        .unwrap_err();
    assert_eq!(refused.code(), Code::Unavailable, "{refused:?}");
    assert_eq!(
        refused.get_error_details().error_info().unwrap().reason,
        "SHUTTING_DOWN"
    );
    let answered = in_flight
        .await
        .unwrap()
        .unwrap()
        .into_inner()
        .result
        .unwrap();
    assert_eq!(answered.status(), proto::SolveStatus::TimeLimit);
    drop((health, channel));
    tokio::time::timeout(Duration::from_secs(10), &mut s.task)
        .await
        .expect("the server did not stop")
        .unwrap()
        .unwrap();
}

/// Server reflection (v1 and v1alpha) lists the optimizer, health and
/// reflection services, and serves the optimizer's file and that of the
/// error details, so that grpcurl and grpcui need no proto file.
#[tokio::test]
async fn reflection_lists_and_describes_the_services() {
    use tonic::codegen::tokio_stream;
    use tonic_reflection::pb::v1;
    use tonic_reflection::pb::v1::server_reflection_request::MessageRequest;
    use tonic_reflection::pb::v1::server_reflection_response::MessageResponse;
    let s = Server::with_grpc(Config::default()).await;
    let channel = s.channel().await;
    let mut reflection = v1::server_reflection_client::ServerReflectionClient::new(channel.clone());
    let ask = |request: MessageRequest| v1::ServerReflectionRequest {
        host: String::new(),
        message_request: Some(request),
    };
    let mut answers = reflection
        .server_reflection_info(tokio_stream::iter([
            ask(MessageRequest::ListServices(String::new())),
            ask(MessageRequest::FileContainingSymbol(
                "ilqr.v1.TrajectoryOptimizer".into(),
            )),
            // The error details' types, for a client to decode them.
            ask(MessageRequest::FileContainingSymbol(
                "google.rpc.BadRequest".into(),
            )),
        ]))
        .await
        .unwrap()
        .into_inner();
    let Some(MessageResponse::ListServicesResponse(list)) =
        answers.message().await.unwrap().unwrap().message_response
    else {
        panic!("no list of services")
    };
    let names: Vec<&str> = list.service.iter().map(|s| s.name.as_str()).collect();
    for name in [
        "ilqr.v1.TrajectoryOptimizer",
        "grpc.health.v1.Health",
        "grpc.reflection.v1.ServerReflection",
    ] {
        assert!(names.contains(&name), "{name} not in {names:?}");
    }
    let Some(MessageResponse::FileDescriptorResponse(files)) =
        answers.message().await.unwrap().unwrap().message_response
    else {
        panic!("no file for the optimizer")
    };
    use prost::Message as _;
    let file = prost_types::FileDescriptorProto::decode(files.file_descriptor_proto[0].as_slice())
        .unwrap();
    assert_eq!(file.name(), "ilqr/v1/ilqr.proto");
    assert_eq!(file.service[0].method.len(), 4);
    let Some(MessageResponse::FileDescriptorResponse(files)) =
        answers.message().await.unwrap().unwrap().message_response
    else {
        panic!("no file for google.rpc.BadRequest")
    };
    let file = prost_types::FileDescriptorProto::decode(files.file_descriptor_proto[0].as_slice())
        .unwrap();
    assert_eq!(file.package(), "google.rpc");

    use tonic_reflection::pb::v1alpha;
    let mut old = v1alpha::server_reflection_client::ServerReflectionClient::new(channel);
    let mut answers = old
        .server_reflection_info(tokio_stream::iter([v1alpha::ServerReflectionRequest {
            host: String::new(),
            message_request: Some(
                v1alpha::server_reflection_request::MessageRequest::ListServices(String::new()),
            ),
        }]))
        .await
        .unwrap()
        .into_inner();
    let answer = answers.message().await.unwrap().unwrap();
    assert!(
        format!("{answer:?}").contains("ilqr.v1.TrajectoryOptimizer"),
        "{answer:?}"
    );
}

/// A problem message equals an HTTP problem document, member for member.
fn assert_same_problem(g: &proto::Problem, h: &Value) {
    let model = g.model.as_ref().unwrap();
    assert_eq!(model.r#type.as_deref(), h["model"]["type"].as_str());
    let parameters = h["model"].as_object().unwrap();
    assert_eq!(model.parameters.len(), parameters.len() - 1);
    for (name, value) in &model.parameters {
        assert_eq!(Some(*value), parameters[name].as_f64(), "{name}");
    }
    assert_eq!(g.integrator().as_str_name(), "INTEGRATOR_EULER");
    assert_eq!(h["integrator"], "euler");
    assert_eq!(g.dt, h["dt"].as_f64());
    assert_eq!(g.horizon.map(u64::from), h["horizon"].as_u64());
    assert_eq!(g.initial_state, numbers(&h["initial_state"]));
    assert_eq!(g.goal_state, numbers(&h["goal_state"]));
    let w = g.weights.as_ref().unwrap();
    assert_eq!(w.state, numbers(&h["weights"]["state"]));
    assert_eq!(w.control, numbers(&h["weights"]["control"]));
    assert_eq!(w.terminal, numbers(&h["weights"]["terminal"]));
    let obstacles = &g.obstacles.as_ref().unwrap().items;
    assert_eq!(obstacles.len(), h["obstacles"].as_array().unwrap().len());
    for (o, j) in obstacles.iter().zip(h["obstacles"].as_array().unwrap()) {
        assert_eq!(o.center, numbers(&j["center"]));
        assert_eq!(o.weight, j["weight"].as_f64());
    }
    assert!(g.initial_controls.is_empty() && h.get("initial_controls").is_none());
    let solver = g.solver.unwrap();
    assert_eq!(
        solver.max_iterations.map(u64::from),
        h["solver"]["max_iterations"].as_u64()
    );
    assert_eq!(solver.tolerance, h["solver"]["tolerance"].as_f64());
    assert_eq!(solver.time_limit_ms, h["solver"]["time_limit_ms"].as_u64());
    assert_eq!(solver.method().as_str_name(), "METHOD_ILQR");
    assert_eq!(h["solver"]["method"], "ilqr");
    let output = g.output.unwrap();
    assert_eq!(output.gains, h["output"]["gains"].as_bool());
    assert_eq!(output.trace, h["output"]["trace"].as_bool());
}

/// `GetDefaultProblem` and `ListModels` give what `GET /problems/default`
/// and `GET /models` give, with this server's default budget; an unknown
/// model is NOT_FOUND; the default problem solves as over HTTP.
#[tokio::test]
async fn default_problems_and_models_agree_with_http() {
    let s = Server::with_grpc(Config {
        default_time_limit_ms: 7000,
        ..Config::default()
    })
    .await;
    let mut client = s.client().await;
    let seed = client
        .get_default_problem(proto::GetDefaultProblemRequest { model: None })
        .await
        .unwrap()
        .into_inner();
    let http_seed = s.get_json("/problems/default").await;
    assert_same_problem(&seed, &http_seed);
    assert_eq!(seed.solver.unwrap().time_limit_ms, Some(7000));
    let unicycle = client
        .get_default_problem(proto::GetDefaultProblemRequest {
            model: Some("unicycle".into()),
        })
        .await
        .unwrap()
        .into_inner();
    assert_same_problem(
        &unicycle,
        &s.get_json("/problems/default?model=unicycle").await,
    );
    let unknown = client
        .get_default_problem(proto::GetDefaultProblemRequest {
            model: Some("blimp".into()),
        })
        .await
        .unwrap_err();
    assert_eq!(unknown.code(), Code::NotFound);
    assert!(
        unknown
            .message()
            .starts_with("no model `blimp`: the models are `quadrotor_2d`"),
        "{}",
        unknown.message()
    );

    let models = client
        .list_models(proto::ListModelsRequest {})
        .await
        .unwrap()
        .into_inner()
        .models;
    let http_models = s.get_json("/models").await;
    let http_models = http_models["models"].as_array().unwrap();
    assert_eq!(models.len(), http_models.len());
    for (g, h) in models.iter().zip(http_models) {
        assert_eq!(g.r#type, h["type"].as_str().unwrap());
        assert_eq!(g.description, h["description"].as_str().unwrap());
        for (quantities, json) in [(&g.state, &h["state"]), (&g.control, &h["control"])] {
            let json = json.as_array().unwrap();
            assert_eq!(quantities.len(), json.len());
            for (q, j) in quantities.iter().zip(json) {
                assert_eq!(q.name, j["name"].as_str().unwrap());
                assert_eq!(q.unit, j["unit"].as_str().unwrap());
                assert_eq!(q.description, j["description"].as_str().unwrap());
            }
        }
        let parameters = h["parameters"].as_array().unwrap();
        assert_eq!(g.parameters.len(), parameters.len());
        for (p, j) in g.parameters.iter().zip(parameters) {
            assert_eq!(p.name, j["name"].as_str().unwrap());
            assert_eq!(p.unit, j["unit"].as_str().unwrap());
            assert_eq!(p.default, j["default"].as_f64().unwrap());
            assert_eq!(p.minimum, j["minimum"].as_f64().unwrap());
            assert_eq!(p.maximum, j["maximum"].as_f64().unwrap());
        }
        let position: Vec<u64> = g.position.iter().map(|&i| u64::from(i)).collect();
        assert_eq!(json!(position), h["position"]);
        assert_same_problem(g.default_problem.as_ref().unwrap(), &h["default_problem"]);
    }

    // The default problem, as sent back, solves as it does over HTTP.
    let r = client
        .solve(solve_request(seed))
        .await
        .unwrap()
        .into_inner()
        .result
        .unwrap();
    assert_same_result(&r, &s.post_json("/solve", &http_seed).await);
}
