//! The service over a real socket on 127.0.0.1:0: the happy path, every
//! error class, overload, time budgets, client disconnects, metrics and a
//! graceful shutdown.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use ilqr_service::server::Config;

use crate::common::{Server, slow};
use reqwest::StatusCode;
use reqwest::header::HeaderValue;
use serde_json::{Value, json};
use tokio::task::JoinHandle;

impl Server {
    /// POST `body` to /solve in a task of its own (a client that waits
    /// while the test goes on).
    fn spawn_post(&self, body: Value) -> JoinHandle<reqwest::Response> {
        let url = self.url("/solve");
        tokio::spawn(async move {
            reqwest::Client::new()
                .post(url)
                .json(&body)
                .send()
                .await
                .unwrap()
        })
    }

    /// POST `body` to /solve and hang up after 300 ms without an answer,
    /// as an impatient client does.
    async fn post_and_give_up(&self, body: &Value) {
        let impatient = reqwest::Client::builder()
            .timeout(Duration::from_millis(300))
            .build()
            .unwrap();
        let gone = impatient.post(self.url("/solve")).json(body).send().await;
        assert!(gone.unwrap_err().is_timeout(), "answered within 300 ms");
    }

    async fn post(&self, body: &Value) -> reqwest::Response {
        reqwest::Client::new()
            .post(self.url("/solve"))
            .json(body)
            .send()
            .await
            .unwrap()
    }

    /// GET `path` with these headers (a name may repeat).
    async fn get_with(&self, path: &str, headers: &[(&str, HeaderValue)]) -> reqwest::Response {
        let mut req = reqwest::Client::new().get(self.url(path));
        for (name, value) in headers {
            req = req.header(*name, value.clone());
        }
        req.send().await.unwrap()
    }
}

fn body_limit(bytes: usize) -> Config {
    Config {
        max_body_bytes: bytes,
        ..Config::default()
    }
}

fn small(workers: usize, queue: usize) -> Config {
    Config {
        workers: std::num::NonZeroUsize::new(workers),
        queue_capacity: queue,
        ..Config::default()
    }
}

async fn problem_of(res: reqwest::Response, status: StatusCode) -> Value {
    assert_eq!(res.status(), status);
    assert_eq!(res.headers()["content-type"], "application/problem+json");
    assert!(res.headers().contains_key("x-request-id"));
    let body: Value = res.json().await.unwrap();
    assert_eq!(body["status"], status.as_u16());
    assert!(
        body["type"]
            .as_str()
            .unwrap()
            .starts_with("urn:ilqr-service:")
    );
    assert!(!body["detail"].as_str().unwrap().is_empty());
    body
}

#[tokio::test]
async fn the_empty_problem_solves_the_seed_scenario() {
    let s = Server::default().await;
    let res = s.post(&json!({})).await;
    assert_eq!(res.status(), 200);
    assert!(res.headers().contains_key("x-request-id"));
    let r: Value = res.json().await.unwrap();
    assert_eq!(r["status"], "converged");
    // The best of the seed's routes: east of the obstacle (the paper's
    // single solve from hover goes west, 5520.212).
    let cost = r["cost"].as_f64().unwrap();
    assert!((cost - 5418.304).abs() / 5418.304 < 1e-6, "{cost}");
    assert_eq!(r["starts"].as_array().unwrap().len(), 2);
    assert_eq!(r["states"].as_array().unwrap().len(), 101);
    assert_eq!(r["controls"].as_array().unwrap().len(), 100);
    let feedback = r["gains"]["feedback"].as_array().unwrap();
    assert_eq!(feedback.len(), 100);
    assert_eq!(feedback[0].as_array().unwrap().len(), 2);
    assert_eq!(feedback[0][0].as_array().unwrap().len(), 6);
    assert_eq!(r["gains"]["feedforward"].as_array().unwrap().len(), 100);
    assert_eq!(
        r["trace"].as_array().unwrap().len() as u64,
        r["iterations"].as_u64().unwrap()
    );
    assert!(r["goal_distance"].as_f64().unwrap() < 0.002);
    assert!(r["queue_time_ms"].as_f64().unwrap() >= 0.0);
    assert!(r["solve_time_ms"].as_f64().unwrap() > 0.0);
}

#[tokio::test]
async fn the_default_problem_round_trips() {
    let s = Server::default().await;
    let spec: Value = s.get("/problems/default").await.json().await.unwrap();
    assert_eq!(spec["horizon"], 100);
    assert_eq!(spec["obstacles"][0]["center"], json!([4.5, 4.5]));
    // Fully expanded: the budget a request without one gets is shown.
    assert_eq!(
        spec["solver"]["time_limit_ms"],
        Config::default().default_time_limit_ms
    );
    let a: Value = s.post(&spec).await.json().await.unwrap();
    let b: Value = s.post(&json!({})).await.json().await.unwrap();
    assert_eq!(a["cost"], b["cost"]);
}

/// All weights zero and no obstacles: the cost is 0 whatever the
/// trajectory, a global optimum, so `converged` at once (it used to take 14
/// iterations to end `no_progress`).
#[tokio::test]
async fn a_zero_cost_problem_is_converged() {
    let s = Server::default().await;
    let zero = json!({
        "weights": {"state": [0, 0, 0, 0, 0, 0], "control": [0, 0], "terminal": [0, 0, 0, 0, 0, 0]},
        "obstacles": [],
    });
    let r: Value = s.post(&zero).await.json().await.unwrap();
    assert_eq!(r["status"], "converged", "{r}");
    assert_eq!(
        (r["iterations"].as_u64(), r["cost"].as_f64()),
        (Some(0), Some(0.0))
    );
}

#[tokio::test]
async fn gains_and_trace_can_be_left_out() {
    let s = Server::default().await;
    let r: Value = s
        .post(&json!({"output": {"gains": false, "trace": false}}))
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(r["status"], "converged");
    assert!(r.get("gains").is_none() && r.get("trace").is_none());
    assert_eq!(r["states"].as_array().unwrap().len(), 101);
}

#[tokio::test]
async fn responses_are_gzipped_when_asked() {
    use std::io::Read;
    let s = Server::default().await;
    let client = reqwest::Client::new();
    // POST a short solve with this Accept-Encoding; its Content-Encoding and
    // the answer (gunzipped if need be) without its wall-clock fields.
    let answer = async |accept: Option<&str>| {
        let mut req = client
            .post(s.url("/solve"))
            .json(&json!({"solver": {"max_iterations": 3}}));
        if let Some(a) = accept {
            req = req.header("accept-encoding", a);
        }
        let res = req.send().await.unwrap();
        assert_eq!(res.status(), 200, "{accept:?}");
        assert_eq!(res.headers()["vary"], "accept-encoding", "{accept:?}");
        let encoding = res
            .headers()
            .get("content-encoding")
            .map(|v| v.to_str().unwrap().to_owned());
        let bytes = res.bytes().await.unwrap();
        let json = if encoding.as_deref() == Some("gzip") {
            let mut json = Vec::new();
            flate2::read::GzDecoder::new(&bytes[..])
                .read_to_end(&mut json)
                .unwrap();
            json
        } else {
            bytes.to_vec()
        };
        let mut v: Value = serde_json::from_slice(&json).unwrap();
        v["solve_time_ms"] = json!(0);
        v["queue_time_ms"] = json!(0);
        for row in v["trace"].as_array_mut().unwrap() {
            row["elapsed_ms"] = json!(0);
        }
        for start in v["starts"].as_array_mut().unwrap() {
            start["solve_time_ms"] = json!(0);
        }
        (encoding, v)
    };

    let (encoding, plain) = answer(None).await;
    assert_eq!(encoding, None);
    for accept in [
        "gzip",
        "deflate, gzip;q=0.5",
        "br;q=1.0, *;q=0.1",
        "GZIP",
        "gzip, identity;q=0",
        "gzip;q=0.001",
        "gzip, gzip;q=0", // the first of repeated codings counts
        "gzip ; Q=1.000",
        "gzip;q=0.5, identity;q=0.5", // a tie goes to the smaller answer
        "identity;q=0.2, *;q=0.3",
    ] {
        let (encoding, v) = answer(Some(accept)).await;
        assert_eq!(encoding.as_deref(), Some("gzip"), "{accept}");
        assert_eq!(v, plain, "{accept}");
    }
    // From "*;q=0" on they admit nothing this service sends: identity, not a
    // 406 after the solve. Items with a malformed q are ignored.
    for accept in [
        "identity",
        "gzip;q=0",
        "gzip;Q=0",
        "gzip;q=0, *;q=1",
        "deflate",
        "gzip;q=2",
        "gzip;q=abc",
        "gzip;q=0.0001",
        "*;q=0",
        "*;Q=0.000",
        "identity;q=0",
        "identity;Q=0",
        // Preferred uncompressed.
        "gzip;q=0.5, identity",
        "identity;q=1, gzip;q=0.999",
        "*;q=0.5, IDENTITY",
        "gzip;q=0.5, *",
    ] {
        let (encoding, v) = answer(Some(accept)).await;
        assert_eq!(encoding, None, "{accept}");
        assert_eq!(v, plain, "{accept}");
    }
    let health = s
        .get_with(
            "/healthz",
            &[("accept-encoding", HeaderValue::from_static("*;q=0"))],
        )
        .await;
    assert_eq!(health.status(), 200);
}

#[tokio::test]
async fn gzip_level_0_sends_everything_uncompressed() {
    let s = Server::start(Config {
        gzip_level: 0,
        ..Config::default()
    })
    .await;
    let client = reqwest::Client::new();
    let solve = client
        .post(s.url("/solve"))
        .header("accept-encoding", "gzip")
        .json(&json!({"solver": {"max_iterations": 2}}))
        .send()
        .await
        .unwrap();
    assert_eq!(solve.status(), 200);
    assert!(solve.headers().get("content-encoding").is_none());
    let v: Value = solve.json().await.unwrap();
    assert_eq!(v["iterations"], 2);
    let doc = s
        .get_with(
            "/openapi.json",
            &[("accept-encoding", HeaderValue::from_static("gzip"))],
        )
        .await;
    assert_eq!(doc.status(), 200);
    assert!(doc.headers().get("content-encoding").is_none());
    let _: Value = doc.json().await.unwrap();
}

#[tokio::test]
async fn every_error_class_is_a_problem_document() {
    let s = Server::start(body_limit(4096)).await;
    let client = reqwest::Client::new();
    let raw = |body: &'static str, ct: Option<&'static str>| {
        let mut req = client.post(s.url("/solve")).body(body);
        if let Some(ct) = ct {
            req = req.header("content-type", ct);
        }
        req.send()
    };

    problem_of(
        raw("{\"dt\": ", Some("application/json")).await.unwrap(),
        StatusCode::BAD_REQUEST,
    )
    .await;

    let p = problem_of(
        raw("{\"dt\": -1}", Some("application/json")).await.unwrap(),
        StatusCode::UNPROCESSABLE_ENTITY,
    )
    .await;
    assert_eq!(p["errors"][0]["pointer"], "/dt");
    // Valid JSON beyond f64 (JSON's nearest to Infinity) is a value at a
    // pointer, not a syntax error; a syntax error after it still wins.
    let p = problem_of(
        raw("{\"model\": {\"mass\": -1e999}}", Some("application/json"))
            .await
            .unwrap(),
        StatusCode::UNPROCESSABLE_ENTITY,
    )
    .await;
    assert_eq!(p["errors"][0]["pointer"], "/model/mass");
    problem_of(
        raw("{\"dt\": 1e999,}", Some("application/json"))
            .await
            .unwrap(),
        StatusCode::BAD_REQUEST,
    )
    .await;
    // So is the bare NaN that Python's json.dumps writes, which JSON lacks.
    let p = problem_of(
        raw("{\"dt\": NaN}", Some("application/json"))
            .await
            .unwrap(),
        StatusCode::UNPROCESSABLE_ENTITY,
    )
    .await;
    assert_eq!(p["errors"][0]["pointer"], "/dt");
    problem_of(
        raw("{\"dt\": NaN,}", Some("application/json"))
            .await
            .unwrap(),
        StatusCode::BAD_REQUEST,
    )
    .await;
    // A key given twice is ambiguous, not last-wins.
    let p = problem_of(
        raw("{\"dt\": 0.05, \"dt\": 10}", Some("application/json"))
            .await
            .unwrap(),
        StatusCode::UNPROCESSABLE_ENTITY,
    )
    .await;
    assert_eq!(p["errors"][0]["pointer"], "/dt");

    let p = problem_of(
        s.post(&json!({"weights": {"state": [1, 2]}})).await,
        StatusCode::UNPROCESSABLE_ENTITY,
    )
    .await;
    assert_eq!(p["errors"][0]["pointer"], "/weights/state");
    let p = problem_of(
        s.post(&json!({"horizn": 5})).await,
        StatusCode::UNPROCESSABLE_ENTITY,
    )
    .await;
    assert_eq!(p["errors"][0]["pointer"], "/horizn");
    let p = problem_of(
        s.post(&json!({"horizon": 10001})).await,
        StatusCode::UNPROCESSABLE_ENTITY,
    )
    .await;
    assert_eq!(p["errors"][0]["pointer"], "/horizon");
    let p = problem_of(
        s.post(&json!({"solver": {"time_limit_ms": 3_600_000}}))
            .await,
        StatusCode::UNPROCESSABLE_ENTITY,
    )
    .await;
    assert_eq!(p["errors"][0]["pointer"], "/solver/time_limit_ms");

    problem_of(
        raw("{}", None).await.unwrap(),
        StatusCode::UNSUPPORTED_MEDIA_TYPE,
    )
    .await;
    problem_of(
        raw("{}", Some("text/plain")).await.unwrap(),
        StatusCode::UNSUPPORTED_MEDIA_TYPE,
    )
    .await;
    // Parameters and +json suffixes are JSON too.
    for ok in [
        "application/json; charset=utf-8",
        "Application/JSON;CHARSET=\"UTF-8\"",
        "application/json; charset=utf8",
        "application/json; charset=US-ASCII",
        "application/vnd.ilqr+json",
        "application/json ; charset=utf-8",
        // A `;` inside a quoted value does not start a parameter.
        "application/json; profile=\"a;charset=latin1\"",
        "application/json; profile=\"a\\\";charset=latin1\"",
    ] {
        assert_eq!(raw("{}", Some(ok)).await.unwrap().status(), 200, "{ok}");
    }
    // The body is read as UTF-8, so another charset would be misread.
    let p = problem_of(
        raw("{}", Some("application/json; charset=latin1"))
            .await
            .unwrap(),
        StatusCode::UNSUPPORTED_MEDIA_TYPE,
    )
    .await;
    assert!(p["detail"].as_str().unwrap().contains("UTF-8 JSON"), "{p}");
    // Every charset counts, after a quoted `;` too.
    for refused in [
        "application/json; profile=\"a;b\"; charset=latin1",
        "application/json; charset=utf-8; charset=latin1",
    ] {
        assert_eq!(
            raw("{}", Some(refused)).await.unwrap().status(),
            415,
            "{refused}"
        );
    }

    let big = json!({"initial_controls": vec![[4.905, 4.905]; 1000], "horizon": 1000});
    let p = problem_of(s.post(&big).await, StatusCode::PAYLOAD_TOO_LARGE).await;
    assert!(p["detail"].as_str().unwrap().contains("4096"));

    problem_of(s.get("/nope").await, StatusCode::NOT_FOUND).await;
    problem_of(s.get("/solve").await, StatusCode::METHOD_NOT_ALLOWED).await;

    // Wrong types, JSON's stand-in for NaN, and values out of range: 422
    // with the pointer of the offending element.
    for (body, pointer) in [
        (json!({"dt": "0.1"}), "/dt"),
        (json!({"dt": "NaN"}), "/dt"),
        (
            json!({"weights": {"state": [1, 1, "a", 1, 1, 1]}}),
            "/weights/state/2",
        ),
        (json!({"model": {"mass": -1}}), "/model/mass"),
        (json!({"goal_state": [2e6, 0, 0, 0, 0, 0]}), "/goal_state/0"),
        (
            json!({"obstacles": [{"center": [1, 1], "weight": 1, "radius": 2}]}),
            "/obstacles/0/radius",
        ),
    ] {
        let p = problem_of(s.post(&body).await, StatusCode::UNPROCESSABLE_ENTITY).await;
        assert_eq!(p["errors"][0]["pointer"], pointer, "{body}");
    }
}

/// Each 415 says what was received and what to change: no Content-Type,
/// a form's (what `curl -d` sends without `-H`), another media type, a
/// charset other than UTF-8, or a compressed body. They all said "send the
/// problem as uncompressed UTF-8 JSON ...", whatever the cause. An echoed
/// header is cut to 100 characters.
#[tokio::test]
async fn a_415_says_what_was_received() {
    let s = Server::default().await;
    let client = reqwest::Client::new();
    let post = |headers: &[(&'static str, String)]| {
        let mut req = client.post(s.url("/solve")).body("{}");
        for (name, value) in headers {
            req = req.header(*name, value.clone());
        }
        req.send()
    };
    let long = format!("text/{}", "a".repeat(5000));
    let compressed = "the body is compressed (Content-Encoding: `gzip`); send it uncompressed, \
                      as this service reads no compressed requests"
        .to_owned();
    for (headers, detail) in [
        (
            vec![],
            "the request has no Content-Type; send the problem as UTF-8 JSON with \
             `Content-Type: application/json`"
                .to_owned(),
        ),
        (
            vec![("content-type", "application/x-www-form-urlencoded".into())],
            "the Content-Type is `application/x-www-form-urlencoded`, a form, which is what \
             `curl -d` sends unless told otherwise: add -H 'content-type: application/json'"
                .to_owned(),
        ),
        (
            vec![("content-type", "text/plain; charset=utf-8".into())],
            "the Content-Type is `text/plain; charset=utf-8`, which is not JSON \
             (application/json or application/*+json); send the problem as UTF-8 JSON with \
             `Content-Type: application/json`"
                .to_owned(),
        ),
        (
            vec![(
                "content-type",
                "application/json; charset=\"latin1\"".into(),
            )],
            "the Content-Type names the charset `latin1`, but the body is read as UTF-8 JSON \
             (its only encoding): send UTF-8, with charset=utf-8 or no charset"
                .to_owned(),
        ),
        (
            vec![
                ("content-type", "application/json".into()),
                ("content-encoding", "gzip".into()),
            ],
            compressed.clone(),
        ),
        (
            // Every field line counts, not only the first.
            vec![
                ("content-type", "application/json".into()),
                ("content-encoding", "identity".into()),
                ("content-encoding", "gzip".into()),
            ],
            compressed.clone(),
        ),
        (
            vec![
                ("content-type", "application/json".into()),
                ("content-type", "text/plain".into()),
            ],
            "the request has 2 different Content-Type header fields: send one, `Content-Type: \
             application/json`, with the problem as UTF-8 JSON"
                .to_owned(),
        ),
        (
            // A structured syntax suffix needs a name before it.
            vec![("content-type", "application/+json".into())],
            "the Content-Type is `application/+json`, which is not JSON (application/json or \
             application/*+json); send the problem as UTF-8 JSON with \
             `Content-Type: application/json`"
                .to_owned(),
        ),
        (
            vec![("content-type", long.clone())],
            format!(
                "the Content-Type is `{}...`, which is not JSON (application/json or \
                 application/*+json); send the problem as UTF-8 JSON with \
                 `Content-Type: application/json`",
                &long[..100]
            ),
        ),
    ] {
        let p = problem_of(
            post(&headers).await.unwrap(),
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
        )
        .await;
        assert_eq!(p["detail"], detail, "{headers:?}");
    }
    // A header value that is not ASCII is shown without its raw bytes.
    let res = client
        .post(s.url("/solve"))
        .header(
            "content-type",
            HeaderValue::from_bytes(b"application/\xffjson").unwrap(),
        )
        .body("{}")
        .send()
        .await
        .unwrap();
    let p = problem_of(res, StatusCode::UNSUPPORTED_MEDIA_TYPE).await;
    assert_eq!(
        p["detail"],
        "the Content-Type `application/\u{fffd}json` is not plain ASCII text; send the \
         problem as UTF-8 JSON with `Content-Type: application/json`"
    );
}

/// A 404 echoes the method and path, and names the route a near miss
/// (a trailing slash, other case) meant; it points at the documentation
/// in words, since behind a path-prefix proxy a link to `/docs` leaves the
/// service. A long path is cut to 100 characters.
#[tokio::test]
async fn a_404_says_what_was_asked_for_and_what_was_meant() {
    let s = Server::default().await;
    const LISTED: &str = "The routes are listed in openapi.json and on the docs/ page, \
                          both at the service's root.";
    let client = reqwest::Client::new();
    let long = format!("/{}", "x".repeat(300));
    for (method, path, detail) in [
        (
            "POST",
            "/solve/".to_owned(),
            format!("no route for POST `/solve/`. Did you mean /solve? {LISTED}"),
        ),
        (
            "GET",
            "/problems/default//".to_owned(),
            format!(
                "no route for GET `/problems/default//`. Did you mean /problems/default? {LISTED}"
            ),
        ),
        (
            "GET",
            "/Healthz".to_owned(),
            format!("no route for GET `/Healthz`. Did you mean /healthz? {LISTED}"),
        ),
        (
            "GET",
            "/nope".to_owned(),
            format!("no route for GET `/nope`. {LISTED}"),
        ),
        (
            "GET",
            "/docs/nope.js".to_owned(),
            format!("no route for GET `/docs/nope.js`. {LISTED}"),
        ),
        // Swagger UI served its page here, where the page's relative link
        // to the spec leads to a 404.
        (
            "GET",
            "/docs//".to_owned(),
            format!("no route for GET `/docs//`. Did you mean /docs/? {LISTED}"),
        ),
        (
            "GET",
            "/docs/a/index.css".to_owned(),
            format!("no route for GET `/docs/a/index.css`. {LISTED}"),
        ),
        (
            "GET",
            long.clone(),
            format!("no route for GET `{}...`. {LISTED}", &long[..100]),
        ),
    ] {
        let res = client
            .request(method.parse().unwrap(), s.url(&path))
            .send()
            .await
            .unwrap();
        let p = problem_of(res, StatusCode::NOT_FOUND).await;
        assert_eq!(p["detail"], detail, "{method} {path}");
    }
    let p = problem_of(s.get("/solve").await, StatusCode::METHOD_NOT_ALLOWED).await;
    assert_eq!(
        p["detail"],
        format!("`/solve` does not take GET (the Allow header lists what it takes). {LISTED}")
    );
}

/// Wrong shapes do not hide the other errors: one 422 lists them all, and
/// the rest is checked against the server's own limits.
#[tokio::test]
async fn one_answer_lists_wrong_types_and_out_of_range_values() {
    let s = Server::start(Config {
        max_horizon: 500,
        ..Config::default()
    })
    .await;
    let body = json!({"dt": "x", "horizon": 501, "output": {"trace": "no"}});
    let p = problem_of(s.post(&body).await, StatusCode::UNPROCESSABLE_ENTITY).await;
    let errors = p["errors"].as_array().unwrap();
    let pointers: Vec<&str> = errors
        .iter()
        .map(|e| e["pointer"].as_str().unwrap())
        .collect();
    assert_eq!(pointers, ["/dt", "/output/trace", "/horizon"], "{p}");
    assert!(
        errors[2]["detail"]
            .as_str()
            .unwrap()
            .contains("from 1 to 500"),
        "{p}"
    );
    assert_eq!(p["detail"], "3 invalid fields; see `errors`");

    // A count of the wrong type is told this server's range too.
    let body = json!({"horizon": "x", "solver": {"time_limit_ms": "y"}});
    let p = problem_of(s.post(&body).await, StatusCode::UNPROCESSABLE_ENTITY).await;
    assert_eq!(
        p["errors"][0]["detail"],
        "invalid type: string \"x\", expected an integer from 1 to 500"
    );
    assert_eq!(
        p["errors"][1]["detail"],
        "invalid type: string \"y\", expected an integer from 1 to 60000 (ms), or null"
    );

    // When the parser's rereading budget runs out, the detail says the
    // list may be incomplete.
    let mut many = serde_json::Map::new();
    for i in 0..150 {
        many.insert(format!("k{i:03}"), json!(i));
    }
    let p = problem_of(
        s.post(&Value::Object(many)).await,
        StatusCode::UNPROCESSABLE_ENTITY,
    )
    .await;
    assert_eq!(p["errors"].as_array().unwrap().len(), 100);
    let detail = p["detail"].as_str().unwrap();
    assert!(
        detail.ends_with(
            "(checking stopped here: more values may be invalid; fix these and send it again)"
        ),
        "{p}"
    );
}

/// A body declared larger than the limit is refused from its headers, before
/// any of it is sent (and before `Expect: 100-continue` is answered); a
/// chunked one as soon as its chunk-size lines declare more than the limit,
/// without waiting for the bytes or the read timeout, on the first request
/// of a connection or a later one.
#[tokio::test]
async fn a_declared_oversized_body_is_refused_at_once() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let s = Server::start(body_limit(4096)).await;
    let head = "POST /solve HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n";
    let small = r#"{"horizon": 20}"#;
    for (first, rest) in [
        (
            String::new(),
            "Content-Length: 100000000\r\nExpect: 100-continue\r\n\r\n",
        ),
        (
            String::new(),
            "Transfer-Encoding: chunked\r\n\r\nFFFFFF\r\n{\"horizon\"",
        ),
        // 4000 bytes declared, then 97 more: 4097, one past the limit.
        (String::new(), "Transfer-Encoding: chunked\r\n\r\nfa0\r\n"),
        // A first request on the same connection, chunked and within the
        // limit, is answered; the second is refused.
        (
            format!(
                "{head}Transfer-Encoding: chunked\r\n\r\n{:x}\r\n{small}\r\n0\r\n\r\n",
                small.len()
            ),
            "Transfer-Encoding: chunked\r\n\r\n100000;x=y\r\n",
        ),
    ] {
        let mut sock = tokio::net::TcpStream::connect(s.addr).await.unwrap();
        let mut request = format!("{first}{head}{rest}").into_bytes();
        if rest.ends_with("fa0\r\n") {
            request.extend(std::iter::repeat_n(b' ', 4000));
            request.extend_from_slice(b"\r\n61\r\n ");
        }
        sock.write_all(&request).await.unwrap();
        let mut answers = Vec::new();
        let mut buf = [0u8; 4096];
        let expected = if first.is_empty() { 1 } else { 2 };
        tokio::time::timeout(Duration::from_secs(2), async {
            while answers.windows(9).filter(|w| *w == b"HTTP/1.1 ").count() < expected
                || !answers.ends_with(b"}")
            {
                let n = sock.read(&mut buf).await.unwrap();
                assert!(n > 0, "closed: {}", String::from_utf8_lossy(&answers));
                answers.extend_from_slice(&buf[..n]);
            }
        })
        .await
        .unwrap_or_else(|_| panic!("not answered at once: {rest:?}"));
        let answers = String::from_utf8_lossy(&answers);
        let last = answers.rsplit("HTTP/1.1 ").next().unwrap();
        assert!(last.starts_with("413"), "{rest:?}: {answers}");
        assert!(
            last.contains("urn:ilqr-service:payload-too-large"),
            "{answers}"
        );
        if !first.is_empty() {
            assert!(answers.starts_with("HTTP/1.1 200"), "{answers}");
        }
    }
}

/// The bodies being received share a memory budget
/// (`--max-inflight-body-bytes`), counted by the bytes they have sent. Past
/// it a new body is refused at once with 503 `overloaded` and
/// `Retry-After`, whether it declares its length or comes in chunks, and a
/// body's share comes back when its read ends.
#[tokio::test]
async fn bodies_being_received_share_a_memory_budget() {
    use tokio::io::AsyncWriteExt;
    let s = Server::start(Config {
        max_body_bytes: 4096,
        max_inflight_body_bytes: Some(8192),
        ..Config::default()
    })
    .await;
    let head = "POST /solve HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n";
    let stall = |sent: usize| {
        let request = format!(
            "{head}Content-Length: 4096\r\n\r\n[{}",
            " ".repeat(sent - 1)
        );
        async move {
            let mut conn = tokio::net::TcpStream::connect(s.addr).await.unwrap();
            conn.write_all(request.as_bytes()).await.unwrap();
            conn
        }
    };
    // Clients that declare the largest body and send (almost) none of it
    // hold (almost) nothing: a problem still gets through.
    let mut idle = Vec::new();
    for _ in 0..4 {
        idle.push(stall(1).await);
    }
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert_eq!(
        s.post(&json!({"solver": {"max_iterations": 1}}))
            .await
            .status(),
        200
    );
    drop(idle);

    // Two clients send all but a byte of the largest body and stall: they
    // hold all but a few bytes of the budget.
    let mut stalled = vec![stall(4095).await, stall(4095).await];
    tokio::time::sleep(Duration::from_millis(300)).await;

    let padded = format!("{{}}{}", " ".repeat(100));
    for (framing, body) in [
        (format!("Content-Length: {}", padded.len()), padded.clone()),
        (
            "Transfer-Encoding: chunked".to_owned(),
            format!("{:x}\r\n{padded}\r\n0\r\n\r\n", padded.len()),
        ),
    ] {
        let t = Instant::now();
        let request = format!("{head}Connection: close\r\n{framing}\r\n\r\n{body}");
        let answer = raw_exchange(s.addr, request.as_bytes()).await;
        assert!(t.elapsed() < Duration::from_secs(1), "{:?}", t.elapsed());
        assert!(answer.starts_with("HTTP/1.1 503"), "{framing}: {answer}");
        assert!(answer.contains("retry-after: 1\r\n"), "{framing}: {answer}");
        assert!(answer.contains("urn:ilqr-service:overloaded"), "{answer}");
        assert!(
            answer.contains("too many request bodies are being received at once"),
            "{answer}"
        );
    }
    assert_eq!(
        counter(
            &s,
            "solve_rejections_total{reason=\"body_budget\",transport=\"http\"}"
        )
        .await,
        2.0
    );

    // One client leaves: its bytes come back, and a problem fits.
    drop(stalled.pop());
    let t = Instant::now();
    loop {
        let status = s
            .post(&json!({"solver": {"max_iterations": 1}}))
            .await
            .status();
        if status == 200 {
            break;
        }
        assert_eq!(status, 503);
        assert!(
            t.elapsed() < Duration::from_secs(3),
            "the budget never came back"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test]
async fn a_full_queue_answers_503_with_retry_after_at_once() {
    let s = Server::start(small(1, 1)).await;
    let busy = s.spawn_post(slow(1500));
    tokio::time::sleep(Duration::from_millis(200)).await;
    let queued = s.spawn_post(json!({}));
    tokio::time::sleep(Duration::from_millis(500)).await;
    let t = Instant::now();
    let res = s.post(&json!({})).await;
    assert!(
        t.elapsed() < Duration::from_millis(300),
        "rejection took {:?}",
        t.elapsed()
    );
    assert_eq!(res.headers()["retry-after"], "1");
    let p = problem_of(res, StatusCode::SERVICE_UNAVAILABLE).await;
    assert_eq!(p["type"], "urn:ilqr-service:overloaded");
    assert_eq!(p["retry_after"], 1);

    let r: Value = busy.await.unwrap().json().await.unwrap();
    assert!(
        r["solve_time_ms"].as_f64().unwrap() > 500.0,
        "the blocker ran while we were rejected"
    );
    let r: Value = queued.await.unwrap().json().await.unwrap();
    assert_eq!(r["status"], "converged");
    assert!(
        r["queue_time_ms"].as_f64().unwrap() > 500.0,
        "{}",
        r["queue_time_ms"]
    );
}

#[tokio::test]
async fn the_time_budget_returns_the_best_trajectory_so_far() {
    let s = Server::default().await;
    let t = Instant::now();
    let res = s.post(&slow(200)).await;
    assert_eq!(res.status(), 200);
    let timing = server_timing(&res);
    let r: Value = res.json().await.unwrap();
    assert_eq!(r["status"], "time_limit");
    // Server-Timing repeats the body's times and adds what the budget does
    // not cover: serialising the 10001 states (and gains and trace).
    assert_eq!(timing["queue"], r["queue_time_ms"].as_f64().unwrap());
    assert_eq!(timing["solve"], r["solve_time_ms"].as_f64().unwrap());
    assert!(timing["encode"] > 0.0, "{timing:?}");
    assert!(r["cost"].as_f64().unwrap() <= r["initial_cost"].as_f64().unwrap());
    assert_eq!(r["states"].as_array().unwrap().len(), 10001);
    assert!(t.elapsed() < Duration::from_secs(3), "{:?}", t.elapsed());

    // The configured default applies when the request sets none.
    let s = Server::start(Config {
        default_time_limit_ms: 150,
        ..Config::default()
    })
    .await;
    let mut body = slow(1);
    body["solver"]
        .as_object_mut()
        .unwrap()
        .remove("time_limit_ms");
    let r: Value = s.post(&body).await.json().await.unwrap();
    assert_eq!(r["status"], "time_limit");
    assert!(r["solve_time_ms"].as_f64().unwrap() < 1000.0);
}

/// `Server-Timing: queue;dur=A, solve;dur=B, encode;dur=C` as a map.
fn server_timing(res: &reqwest::Response) -> std::collections::HashMap<String, f64> {
    let value = res
        .headers()
        .get("server-timing")
        .expect("no Server-Timing header")
        .to_str()
        .unwrap();
    value
        .split(", ")
        .map(|metric| {
            let (name, dur) = metric
                .split_once(";dur=")
                .unwrap_or_else(|| panic!("{value}"));
            (name.to_owned(), dur.parse().unwrap())
        })
        .collect()
}

#[tokio::test]
async fn a_client_that_disconnects_cancels_its_solve() {
    let s = Server::start(small(1, 0)).await;
    let cancelled_before =
        counter(&s, "solves_total{status=\"cancelled\",transport=\"http\"}").await;
    let left = "http_requests_total{route=\"/solve\",status=\"499\"}";
    let left_before = counter(&s, left).await;
    s.post_and_give_up(&slow(20_000)).await;

    // The only worker must be free again well before the 20 s budget.
    let t = Instant::now();
    loop {
        let res = s.post(&json!({"output": {"gains": false}})).await;
        if res.status() == 200 {
            break;
        }
        assert_eq!(res.status(), 503);
        assert!(
            t.elapsed() < Duration::from_secs(3),
            "the abandoned solve kept its worker"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // The worker counted it as cancelled (the metrics recorder is shared by
    // every server in this process, hence the difference).
    let cancelled_after =
        counter(&s, "solves_total{status=\"cancelled\",transport=\"http\"}").await;
    assert!(
        cancelled_after >= cancelled_before + 1.0,
        "{cancelled_before} -> {cancelled_after}"
    );
    // And the request as one whose client left (it used to be in no
    // request metric at all).
    let left_after = counter(&s, left).await;
    assert!(
        left_after >= left_before + 1.0,
        "{left_before} -> {left_after}"
    );
}

/// A client that gives up while its solve is still queued frees the slot at
/// once: the next request is admitted although the worker is still busy.
#[tokio::test]
async fn a_client_that_leaves_the_queue_frees_its_slot_at_once() {
    let s = Server::start(small(1, 1)).await;
    let cancelled_before =
        counter(&s, "solves_total{status=\"cancelled\",transport=\"http\"}").await;
    let busy = s.spawn_post(slow(2000));
    tokio::time::sleep(Duration::from_millis(300)).await;
    s.post_and_give_up(&json!({})).await;
    tokio::time::sleep(Duration::from_millis(100)).await;

    // The worker is still on the 2 s solve, yet there is room in the queue.
    let t = Instant::now();
    let res = s.post(&json!({})).await;
    assert_eq!(
        res.status(),
        200,
        "the abandoned request kept its queue slot"
    );
    let r: Value = res.json().await.unwrap();
    assert_eq!(r["status"], "converged");
    assert!(
        t.elapsed() > Duration::from_millis(500),
        "it queued behind the busy worker"
    );
    let cancelled_after =
        counter(&s, "solves_total{status=\"cancelled\",transport=\"http\"}").await;
    assert!(cancelled_after >= cancelled_before + 1.0);
    assert_eq!(busy.await.unwrap().status(), 200);
}

/// The budget runs from admission: a solve whose budget runs out while it
/// waits in the queue is answered then, 503 `expired-in-queue` with
/// `Retry-After`, not when the solve ahead of it ends, and never runs: no
/// 200 with the unimproved initial guess, and no worker time.
#[tokio::test]
async fn a_solve_whose_budget_runs_out_in_the_queue_is_answered_503_then() {
    let s = Server::start(small(1, 1)).await;
    let expired = "solve_rejections_total{reason=\"expired_in_queue\",transport=\"http\"}";
    let before = counter(&s, expired).await;
    let busy = s.spawn_post(slow(4000));
    tokio::time::sleep(Duration::from_millis(200)).await;
    let sent = Instant::now();
    let res = s.post(&slow(300)).await;
    let waited = sent.elapsed();
    assert!(
        res.headers()["retry-after"]
            .to_str()
            .unwrap()
            .parse::<u64>()
            .unwrap()
            >= 1
    );
    let p = problem_of(res, StatusCode::SERVICE_UNAVAILABLE).await;
    assert_eq!(p["type"], "urn:ilqr-service:expired-in-queue", "{p}");
    assert!(p["retry_after"].as_u64().unwrap() >= 1, "{p}");
    let detail = p["detail"].as_str().unwrap();
    assert!(
        detail.contains("time budget of 300 ms ran out before it could start"),
        "{detail}"
    );
    // Answered at its budget, not when the solve ahead ends (3.8 s later);
    // a generous bound for CI.
    assert!(
        (Duration::from_millis(290)..Duration::from_millis(2000)).contains(&waited),
        "{waited:?}"
    );
    // The worker is still busy with the first solve, so the queue slot
    // came back when the expired solve was answered: another is admitted
    // (and expires in turn).
    let p = problem_of(s.post(&slow(50)).await, StatusCode::SERVICE_UNAVAILABLE).await;
    assert_eq!(p["type"], "urn:ilqr-service:expired-in-queue", "{p}");
    let r: Value = busy.await.unwrap().json().await.unwrap();
    assert_eq!(r["status"], "time_limit");
    assert!(r["iterations"].as_u64().unwrap() > 0);
    assert!(counter(&s, expired).await >= before + 2.0);
}

/// Admission accounts for the wait: with the only worker busy for about
/// another 0.8 s by the measured service time, a solve whose 500 ms budget
/// would run out before it could start is refused at once, 503
/// `overloaded` with `Retry-After`, while one whose budget covers the wait
/// is queued and answered.
#[tokio::test]
async fn a_solve_that_could_not_start_within_its_budget_is_refused_at_once() {
    let s = Server::start(small(1, 4)).await;
    let refused = "solve_rejections_total{reason=\"queue_wait\",transport=\"http\"}";
    let before = counter(&s, refused).await;
    // One solve measures the service time: about 1 s.
    assert_eq!(s.post(&slow(1000)).await.status(), 200);
    let busy = s.spawn_post(slow(3000));
    tokio::time::sleep(Duration::from_millis(200)).await;
    let t = Instant::now();
    let res = s.post(&slow(500)).await;
    assert!(
        t.elapsed() < Duration::from_millis(300),
        "{:?}",
        t.elapsed()
    );
    let retry: u64 = res.headers()["retry-after"]
        .to_str()
        .unwrap()
        .parse()
        .unwrap();
    assert!(retry >= 1, "{retry}");
    let p = problem_of(res, StatusCode::SERVICE_UNAVAILABLE).await;
    assert_eq!(p["type"], "urn:ilqr-service:overloaded", "{p}");
    assert_eq!(p["retry_after"], retry);
    let detail = p["detail"].as_str().unwrap();
    assert!(
        detail.contains("the solves queued ahead would take about"),
        "{detail}"
    );
    assert!(
        detail.contains("too long for its time budget of 500 ms"),
        "{detail}"
    );
    assert!(counter(&s, refused).await >= before + 1.0);
    // A budget that covers the wait is admitted, and solved once the
    // worker is free.
    let res = s.post(&json!({"solver": {"time_limit_ms": 5000}})).await;
    assert_eq!(res.status(), 200);
    let r: Value = res.json().await.unwrap();
    assert_eq!(r["status"], "converged");
    assert!(
        r["queue_time_ms"].as_f64().unwrap() > 1000.0,
        "{}",
        r["queue_time_ms"]
    );
    assert_eq!(busy.await.unwrap().status(), 200);
}

/// A large body is parsed off the runtime's thread: clients sending
/// megabytes of JSON (here invalid, 4 MB each, 0.1 s or more to parse) do
/// not stall the other connections. On one runtime thread, as the service
/// runs by default, /healthz took a median of 300 ms under four such
/// clients when they were parsed in place.
#[tokio::test(flavor = "multi_thread", worker_threads = 1)]
async fn large_bodies_are_parsed_without_stalling_other_requests() {
    let s = Server::default().await;
    let big = format!("{{\"x\": [{}]}}", ["0"; 1_900_000].join(","));
    let until = Instant::now() + Duration::from_secs(3);
    let senders: Vec<_> = (0..2)
        .map(|_| {
            let (url, big) = (s.url("/solve"), big.clone());
            tokio::spawn(async move {
                let client = reqwest::Client::new();
                let mut answered = 0;
                while Instant::now() < until {
                    let res = client
                        .post(&url)
                        .header("content-type", "application/json")
                        .body(big.clone())
                        .send()
                        .await
                        .unwrap();
                    assert_eq!(res.status(), 422);
                    answered += 1;
                }
                answered
            })
        })
        .collect();
    tokio::time::sleep(Duration::from_millis(300)).await;
    let client = reqwest::Client::new();
    let mut took = Vec::new();
    while Instant::now() + Duration::from_millis(300) < until {
        let sent = Instant::now();
        let res = client.get(s.url("/healthz")).send().await.unwrap();
        assert_eq!(res.status(), 200);
        took.push(sent.elapsed());
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let mut answered = 0;
    for sender in senders {
        answered += sender.await.unwrap();
    }
    took.sort();
    let median = took[took.len() / 2];
    assert!(answered >= 4, "{answered} large bodies answered");
    assert!(
        median < Duration::from_millis(60),
        "median /healthz {median:?} over {} probes",
        took.len()
    );
}

/// The value of one Prometheus sample, 0 when absent.
async fn counter(s: &Server, sample: &str) -> f64 {
    let text = s.get("/metrics").await.text().await.unwrap();
    text.lines()
        .find_map(|l| l.strip_prefix(sample).and_then(|v| v.trim().parse().ok()))
        .unwrap_or(0.0)
}

#[tokio::test]
async fn metrics_count_requests_solves_and_rejections() {
    let s = Server::default().await;
    // The recorder is the process's: other tests' requests count too.
    let timed = "http_request_duration_seconds_count{route=\"/solve\"}";
    let timed_before = counter(&s, timed).await;
    assert_eq!(s.post(&json!({})).await.status(), 200);
    assert_eq!(s.post(&json!({"dt": 0})).await.status(), 422);
    let malformed = reqwest::Client::new()
        .post(s.url("/solve"))
        .header("content-type", "application/json")
        .body("{")
        .send()
        .await
        .unwrap();
    assert_eq!(malformed.status(), 400);
    let res = s.get("/metrics").await;
    assert_eq!(res.status(), 200);
    let text = res.text().await.unwrap();
    for needle in [
        "http_requests_total{route=\"/solve\",status=\"200\"}",
        "http_requests_total{route=\"/solve\",status=\"422\"}",
        "solves_total{status=\"converged\",transport=\"http\"}",
        "solve_rejections_total{reason=\"invalid\",transport=\"http\"}",
        "solve_rejections_total{reason=\"malformed_json\",transport=\"http\"}",
        "solve_queue_depth",
        "request_body_bytes_held",
        "solve_queue_wait_seconds_bucket",
        "solve_duration_seconds_bucket",
        "solve_iterations_bucket",
        "solve_starts_bucket{le=\"3\"}",
        concat!("build_info{version=\"", env!("CARGO_PKG_VERSION"), "\"} 1"),
        "http_request_duration_seconds_bucket{route=\"/solve\",le=\"0.001\"}",
        "solve_duration_seconds_bucket{transport=\"http\",le=\"0.00075\"}",
        "solves_running",
        "solve_workers",
        "solve_queue_capacity",
        "http_request_duration_seconds_count{route=\"/solve\"}",
    ] {
        assert!(text.contains(needle), "missing {needle} in\n{text}");
    }
    // Timed: the solve, the invalid problem and the malformed body.
    let timed_after = counter(&s, timed).await;
    assert!(
        timed_after >= timed_before + 3.0,
        "{timed_before} -> {timed_after}"
    );
    // The process metrics, read from /proc: this test process's own.
    #[cfg(target_os = "linux")]
    {
        let sample = |name: &str| -> f64 {
            text.lines()
                .find_map(|l| l.strip_prefix(&format!("{name} ")))
                .and_then(|v| v.parse().ok())
                .unwrap_or_else(|| panic!("no {name} in\n{text}"))
        };
        let rss = sample("process_resident_memory_bytes");
        assert!((1e6..1e10).contains(&rss), "{rss}");
        assert!(sample("process_cpu_seconds_total") >= 0.0); // under 10 ms reads 0
        assert!(sample("process_open_fds") >= 3.0);
        assert!(sample("process_max_fds") >= sample("process_open_fds"));
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_secs_f64();
        let started = sample("process_start_time_seconds");
        assert!(
            (now - 3600.0..now + 1.0).contains(&started),
            "{started} vs now {now}"
        );
    }
    // Every family says what it counts (Prometheus shows it in queries).
    for family in text.lines().filter_map(|l| l.strip_prefix("# TYPE ")) {
        let name = family.split(' ').next().unwrap();
        assert!(
            text.contains(&format!("# HELP {name} ")),
            "no HELP for {name} in\n{text}"
        );
    }
}

/// The served spec carries this server's limits and a relative server URL;
/// everything else is the committed spec, unchanged.
#[tokio::test]
async fn the_served_spec_states_this_servers_limits() {
    let s = Server::start(Config {
        max_horizon: 500,
        max_time_limit_ms: 2000,
        default_time_limit_ms: 1500,
        ..Config::default()
    })
    .await;
    let served: Value = s.get("/openapi.json").await.json().await.unwrap();
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/openapi/openapi.json");
    let mut expected: Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let schemas = &mut expected["components"]["schemas"];
    schemas["ProblemSpec"]["properties"]["horizon"]["maximum"] = json!(500);
    let horizon = &mut schemas["ProblemSpec"]["properties"]["horizon"]["description"];
    *horizon = json!(format!(
        "{} This server's maximum: 500.",
        horizon.as_str().unwrap()
    ));
    let ms = &mut schemas["SolverSpec"]["properties"]["time_limit_ms"];
    ms["maximum"] = json!(2000);
    // The default budget in words only: as a schema default, generated
    // clients sent it, overriding the server's.
    assert!(ms.get("default").is_none(), "{ms}");
    ms["description"] = json!(format!(
        "{} This server's default: 1500 ms; its maximum: 2000 ms.",
        ms["description"].as_str().unwrap()
    ));
    // The example is what GET /problems/default gives, budget included.
    schemas["ProblemSpec"]["example"]["solver"]["time_limit_ms"] = json!(1500);
    // And where it is served from (the committed file is not served).
    expected["servers"] = json!([{
        "url": ".",
        "description": "this server: the directory this document is served from"
    }]);
    assert_eq!(served, expected);
}

#[tokio::test]
async fn docs_and_spec_are_served() {
    let s = Server::default().await;
    let spec: Value = s.get("/openapi.json").await.json().await.unwrap();
    assert!(spec["paths"]["/solve"]["post"].is_object());
    let docs = reqwest::get(s.url("/docs/")).await.unwrap();
    assert_eq!(docs.status(), 200);
    let page = docs.text().await.unwrap();
    assert!(page.contains("swagger-ui-bundle.js"), "{page}");
    // The browser tab names the service.
    assert!(page.contains("<title>ilqr-service API</title>"), "{page}");
    let index = s.get("/docs/index.html").await.text().await.unwrap();
    assert_eq!(index, page);
    // Swagger UI shows summaries as plain text: one short sentence each,
    // no Markdown code marks (those belong in the description).
    for (path, item) in spec["paths"].as_object().unwrap() {
        for (method, op) in item.as_object().unwrap() {
            let summary = op["summary"].as_str().unwrap_or_default();
            assert!(
                !summary.is_empty() && summary.len() <= 60 && !summary.contains(['`', '\n']),
                "{method} {path}: summary {summary:?}"
            );
        }
    }
    // Swagger UI's own files are served, and an unknown one is our 404.
    assert_eq!(s.get("/docs/swagger-ui.css").await.status(), 200);
    problem_of(s.get("/docs/nope.js").await, StatusCode::NOT_FOUND).await;
    // The page asks for the spec by a relative URL, which resolves to the
    // served spec from /docs/ and, behind a proxy's path prefix, to the
    // spec under the same prefix.
    let init = s
        .get("/docs/swagger-initializer.js")
        .await
        .text()
        .await
        .unwrap();
    let url = init
        .split("\"url\": \"")
        .nth(1)
        .and_then(|rest| rest.split('"').next())
        .unwrap_or_else(|| panic!("no spec URL in {init}"));
    let page = reqwest::Url::parse(&s.url("/docs/")).unwrap();
    assert_eq!(page.join(url).unwrap().path(), "/openapi.json");
    // No validator badge: Swagger UI's default would send the spec's URL to
    // validator.swagger.io from any host name but localhost (a broken
    // image offline; found in a headless-browser check, see
    // tests/browser/docs_check.mjs).
    assert!(init.contains("\"validatorUrl\": \"none\""), "{init}");
    let behind_proxy = reqwest::Url::parse("https://example.org/ilqr/docs/").unwrap();
    assert_eq!(behind_proxy.join(url).unwrap().path(), "/ilqr/openapi.json");
    // "Try it out" posts to the spec's server, which also stays under the
    // prefix (it was the host's root, OpenAPI's default).
    let server = spec["servers"][0]["url"].as_str().unwrap();
    let spec_url = reqwest::Url::parse("https://example.org/ilqr/openapi.json").unwrap();
    assert_eq!(spec_url.join(server).unwrap().path(), "/ilqr/");
    // So does the redirect from /docs, which error messages point to.
    let no_follow = reqwest::Client::builder()
        .redirect(reqwest::redirect::Policy::none())
        .build()
        .unwrap();
    let redirect = no_follow.get(s.url("/docs")).send().await.unwrap();
    assert!(redirect.status().is_redirection(), "{}", redirect.status());
    let location = redirect.headers()["location"].to_str().unwrap();
    let docs = reqwest::Url::parse("https://example.org/ilqr/docs").unwrap();
    assert_eq!(docs.join(location).unwrap().path(), "/ilqr/docs/");
    let direct = reqwest::Url::parse(&s.url("/docs")).unwrap();
    assert_eq!(direct.join(location).unwrap().path(), "/docs/");
    assert_eq!(s.get("/healthz").await.status(), 200);
    assert_eq!(s.get("/readyz").await.status(), 200);
}

/// The spec lists every GET route the service serves, its own two included,
/// and each answers with a status and content type the spec documents for
/// it: a reader of the spec finds `/docs` and gets what it promises.
#[tokio::test]
async fn every_documented_get_answers_as_documented() {
    let s = Server::default().await;
    let spec: Value = s.get("/openapi.json").await.json().await.unwrap();
    let paths = spec["paths"].as_object().unwrap();
    let mut gets: Vec<&str> = paths
        .iter()
        .filter(|(_, item)| item.get("get").is_some())
        .map(|(path, _)| path.as_str())
        .collect();
    gets.sort_unstable();
    assert_eq!(
        gets,
        [
            "/docs/",
            "/healthz",
            "/metrics",
            "/models",
            "/openapi.json",
            "/problems/default",
            "/readyz"
        ]
    );
    for path in gets {
        let answer = s.get(path).await;
        let status = answer.status().as_u16().to_string();
        let documented = &paths[path]["get"]["responses"][&status]["content"];
        let content_type = answer.headers()[reqwest::header::CONTENT_TYPE]
            .to_str()
            .unwrap();
        let media = content_type.split(';').next().unwrap().trim();
        assert!(
            documented.get(media).is_some(),
            "GET {path} answered {status} {content_type}; the spec documents {documented}"
        );
    }
}

#[tokio::test]
async fn shutdown_drains_in_flight_solves_then_stops() {
    let mut s = Server::start(Config {
        shutdown_grace_secs: 5,
        ..small(2, 4)
    })
    .await;
    let inflight = s.spawn_post(slow(800));
    tokio::time::sleep(Duration::from_millis(200)).await;
    s.stop.take().unwrap().send(()).unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;

    // Draining: not ready, no new solves, but the running one finishes.
    problem_of(s.get("/readyz").await, StatusCode::SERVICE_UNAVAILABLE).await;
    let refused = s.post(&json!({})).await;
    // Closed after the answer, so a pooled client's next request goes to
    // another replica instead of this one.
    assert_eq!(refused.headers()["connection"], "close");
    let p = problem_of(refused, StatusCode::SERVICE_UNAVAILABLE).await;
    assert_eq!(p["type"], "urn:ilqr-service:shutting-down");
    let r: Value = inflight.await.unwrap().json().await.unwrap();
    assert_eq!(r["status"], "time_limit", "the solve ran to its own budget");
    tokio::time::timeout(Duration::from_secs(3), s.task)
        .await
        .unwrap()
        .unwrap()
        .unwrap();
}

/// At the end of the grace period a running solve answers 200 `cancelled`
/// with what it has, and a queued one, which has nothing, 503
/// `shutting-down` (it used to answer 200 `cancelled` with the initial
/// guess).
#[tokio::test]
async fn shutdown_cancels_what_the_grace_period_cannot_drain() {
    let mut s = Server::start(Config {
        shutdown_grace_secs: 0,
        ..small(1, 1)
    })
    .await;
    let inflight = s.spawn_post(slow(20_000));
    tokio::time::sleep(Duration::from_millis(300)).await;
    let queued = s.spawn_post(json!({}));
    tokio::time::sleep(Duration::from_millis(200)).await;
    let t = Instant::now();
    s.stop.take().unwrap().send(()).unwrap();
    // The running solve stops with what it has.
    let r: Value = inflight.await.unwrap().json().await.unwrap();
    assert_eq!(r["status"], "cancelled");
    assert!(r["iterations"].as_u64().unwrap() > 0, "{}", r["iterations"]);
    // The queued one never started: nothing to return but where to go.
    let res = queued.await.unwrap();
    assert_eq!(res.headers()["connection"], "close");
    let p = problem_of(res, StatusCode::SERVICE_UNAVAILABLE).await;
    assert_eq!(p["type"], "urn:ilqr-service:shutting-down");
    assert!(t.elapsed() < Duration::from_secs(2), "{:?}", t.elapsed());
    tokio::time::timeout(Duration::from_secs(3), s.task)
        .await
        .unwrap()
        .unwrap()
        .unwrap();
}

/// Send raw `request` bytes and read until the server closes the
/// connection, within 5 s: for requests no HTTP client will send.
async fn raw_exchange(addr: SocketAddr, request: &[u8]) -> String {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut conn = tokio::net::TcpStream::connect(addr).await.unwrap();
    conn.write_all(request).await.unwrap();
    let mut answer = Vec::new();
    tokio::time::timeout(Duration::from_secs(5), conn.read_to_end(&mut answer))
        .await
        .expect("the connection was not closed within 5 s")
        .unwrap();
    String::from_utf8_lossy(&answer).into_owned()
}

/// Read from a raw connection until the server closes it; the time it took.
async fn time_until_closed(mut conn: tokio::net::TcpStream, within: Duration) -> Duration {
    use tokio::io::AsyncReadExt;
    let t = Instant::now();
    let mut buf = vec![0u8; 4096];
    tokio::time::timeout(within, async {
        loop {
            match conn.read(&mut buf).await {
                Ok(0) | Err(_) => break,
                Ok(_) => {}
            }
        }
    })
    .await
    .expect("the server kept the stalled connection open");
    t.elapsed()
}

fn read_timeout(secs: u64) -> Config {
    Config {
        read_timeout_secs: secs,
        ..Config::default()
    }
}

/// A client that never finishes its headers is cut off after the read
/// timeout (it used to hold its connection forever: `axum::serve` sets no
/// hyper timer).
#[tokio::test]
async fn a_client_stalled_in_its_headers_is_disconnected() {
    use tokio::io::AsyncWriteExt;
    let s = Server::start(read_timeout(1)).await;
    let mut conn = tokio::net::TcpStream::connect(s.addr).await.unwrap();
    conn.write_all(b"POST /solve HTTP/1.1\r\nHost: x\r\n")
        .await
        .unwrap();
    let took = time_until_closed(conn, Duration::from_secs(5)).await;
    assert!(took >= Duration::from_millis(900), "{took:?}");
}

/// A connection that sends nothing at all, or only the start of an HTTP/2
/// preface, is closed too: both used to stay open forever (hyper-util's
/// HTTP/1-or-2 detection had no timeout), so idle sockets could pile up.
#[tokio::test]
async fn a_silent_or_http2_connection_is_not_kept_open() {
    use tokio::io::AsyncWriteExt;
    let s = Server::start(read_timeout(1)).await;
    let silent = tokio::net::TcpStream::connect(s.addr).await.unwrap();
    let took = time_until_closed(silent, Duration::from_secs(5)).await;
    assert!(took >= Duration::from_millis(900), "{took:?}");
    for preface in [
        &b"PRI * HTTP/2.0\r\n"[..],
        b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n",
    ] {
        let mut conn = tokio::net::TcpStream::connect(s.addr).await.unwrap();
        conn.write_all(preface).await.unwrap();
        let took = time_until_closed(conn, Duration::from_secs(5)).await;
        assert!(took < Duration::from_millis(1500), "{took:?}");
    }
}

/// A problem whose answer (about 4.6 MB: N = 10000 with gains) is larger
/// than what the socket buffers take.
fn large_answer_problem() -> Value {
    json!({"horizon": 10000, "dt": 0.001, "solver": {"max_iterations": 2},
           "output": {"trace": false}})
}

/// POSTs `problem` to /solve from a socket that takes 4 KiB and will not
/// read until the caller does: a client that stops reading its answer.
async fn post_without_reading(addr: SocketAddr, problem: &Value) -> tokio::net::TcpStream {
    use tokio::io::AsyncWriteExt;
    let body = problem.to_string();
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(4096).unwrap();
    let mut conn = socket.connect(addr).await.unwrap();
    conn.write_all(
        format!(
            "POST /solve HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n\
             Content-Length: {}\r\n\r\n{body}",
            body.len()
        )
        .as_bytes(),
    )
    .await
    .unwrap();
    conn
}

/// A client that stops reading its answer loses the connection once the
/// answer has made no progress for the read timeout, and the answer is
/// freed: it used to be held for as long as the client kept the socket (a
/// review's 100 such clients held 433 MB). The answer (about 4.6 MB: N =
/// 10000 with gains) is larger than what the two socket buffers take here
/// (`tcp_wmem` at most 4 MiB, and 4 KiB to receive), so the client that
/// finally reads gets less than the Content-Length.
#[tokio::test]
async fn a_client_that_stops_reading_its_answer_is_disconnected() {
    use tokio::io::AsyncReadExt;
    let s = Server::start(read_timeout(1)).await;
    let mut conn = post_without_reading(s.addr, &large_answer_problem()).await;
    // Not reading: the solve runs, its answer fills the buffers, and the
    // server's write stalls.
    tokio::time::sleep(Duration::from_secs(4)).await;
    let mut answer = Vec::new();
    let read = tokio::time::timeout(Duration::from_secs(10), async {
        let mut buf = vec![0u8; 1 << 16];
        loop {
            match conn.read(&mut buf).await {
                Ok(0) | Err(_) => break,
                Ok(n) => answer.extend_from_slice(&buf[..n]),
            }
        }
    })
    .await;
    assert!(read.is_ok(), "the server kept the connection open");
    let text = String::from_utf8_lossy(&answer[..answer.len().min(4096)]).into_owned();
    assert!(text.starts_with("HTTP/1.1 200"), "{text:.200}");
    let length: usize = text
        .lines()
        .find_map(|l| l.strip_prefix("content-length: "))
        .expect("a content-length")
        .trim()
        .parse()
        .unwrap();
    let head = text.find("\r\n\r\n").unwrap() + 4;
    assert!(length > 4_000_000, "{length}");
    assert!(
        answer.len() < head + length,
        "the whole answer ({length} bytes) was delivered: the server waited"
    );
}

/// A server whose answers (and bodies) may hold `budget` bytes at once,
/// with bodies up to 1 MiB and a read timeout long enough that a stalled
/// reader is not cut off during a test.
async fn answer_budget_server(budget: usize) -> Server {
    Server::start(Config {
        max_body_bytes: 1 << 20,
        max_inflight_body_bytes: Some(budget),
        ..read_timeout(60)
    })
    .await
}

/// The answers being sent hold at most `--max-inflight-body-bytes` (8 MiB
/// here): while a client that does not read holds a 4.6 MB answer, the
/// next large answer is a 503 `overloaded` saying why (its solve ran), a
/// small one still fits, and once the stalled connection is gone the large
/// one is answered again.
#[tokio::test]
async fn answers_waiting_for_slow_readers_are_bounded() {
    let s = answer_budget_server(8 << 20).await;
    let large = large_answer_problem();
    let stalled = post_without_reading(s.addr, &large).await;
    let held = || counter(&s, "answer_bytes_held ");
    let t = Instant::now();
    while held().await <= 4e6 {
        assert!(t.elapsed() < Duration::from_secs(10), "{:?}", held().await);
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    // Counters are process-wide (tests run in parallel): compared, not
    // matched.
    let rejected = || {
        counter(
            &s,
            "solve_rejections_total{reason=\"answer_budget\",transport=\"http\"} ",
        )
    };
    let before = rejected().await;
    let p = problem_of(s.post(&large).await, StatusCode::SERVICE_UNAVAILABLE).await;
    assert_eq!(p["type"], "urn:ilqr-service:overloaded", "{p}");
    assert!(
        p["detail"]
            .as_str()
            .unwrap()
            .contains("hold the memory budget for answers (clients reading slowly); the solve ran"),
        "{p}"
    );
    assert_eq!(rejected().await, before + 1.0);
    assert_eq!(s.post(&json!({})).await.status(), StatusCode::OK);
    drop(stalled);
    // Freed with the connection: the large answer is sent again.
    let t = Instant::now();
    while s.post(&large).await.status() != StatusCode::OK {
        assert!(t.elapsed() < Duration::from_secs(10), "{:?}", held().await);
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// With the answer budget (1 MiB here) used up by one larger answer that a
/// client does not read, a request is refused before its solve: nothing it
/// could solve would be sent.
#[tokio::test]
async fn a_full_answer_budget_refuses_before_solving() {
    let s = answer_budget_server(1 << 20).await;
    let stalled = post_without_reading(s.addr, &large_answer_problem()).await;
    let t = Instant::now();
    loop {
        let res = s.post(&json!({})).await;
        if res.status() == StatusCode::SERVICE_UNAVAILABLE {
            let p = problem_of(res, StatusCode::SERVICE_UNAVAILABLE).await;
            let detail = p["detail"].as_str().unwrap();
            if detail.contains(
                "hold the whole memory budget for answers (clients reading slowly); nothing was solved",
            ) {
                break;
            }
            // Admitted while the large solve was still running, on the
            // other worker, and encoded once its answer held the budget: a
            // loaded machine (CI on a slow host) saw this race.
            assert!(
                detail.contains("the solve ran but its answer was dropped"),
                "{p}"
            );
        }
        assert!(
            t.elapsed() < Duration::from_secs(10),
            "the large answer was never held"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    drop(stalled);
}

/// A client that stalls mid-body gets a 408 problem after the read timeout.
#[tokio::test]
async fn a_client_stalled_in_its_body_gets_408() {
    let s = Server::start(read_timeout(1)).await;
    let answer = raw_exchange(
        s.addr,
        b"POST /solve HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: 100\r\n\r\n{\"dt\":",
    )
    .await;
    assert!(answer.starts_with("HTTP/1.1 408"), "{answer}");
    assert!(answer.contains("application/problem+json"), "{answer}");
    assert!(
        answer.contains("urn:ilqr-service:request-timeout"),
        "{answer}"
    );
}

/// Shutdown is bounded whatever the clients do: a connection stalled in its
/// headers used to keep the server from ever returning.
#[tokio::test]
async fn shutdown_is_not_held_up_by_a_stalled_client() {
    use tokio::io::AsyncWriteExt;
    let mut s = Server::start(Config {
        shutdown_grace_secs: 0,
        read_timeout_secs: 3600,
        ..Config::default()
    })
    .await;
    let mut conn = tokio::net::TcpStream::connect(s.addr).await.unwrap();
    conn.write_all(b"POST /solve HTTP/1.1\r\nHost: x\r\n")
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let t = Instant::now();
    s.stop.take().unwrap().send(()).unwrap();
    tokio::time::timeout(Duration::from_secs(8), s.task)
        .await
        .expect("the server did not return within the grace period + 5 s")
        .unwrap()
        .unwrap();
    assert!(t.elapsed() < Duration::from_secs(7), "{:?}", t.elapsed());
    drop(conn);
}

/// A client's request id is kept when it is usable in logs, and replaced by
/// a generated one when it is empty, binary or too long.
#[tokio::test]
async fn unusable_request_ids_are_replaced() {
    let s = Server::default().await;
    let id_of = |res: &reqwest::Response| {
        res.headers()
            .get("x-request-id")
            .map(|v| v.as_bytes().to_vec())
            .unwrap_or_default()
    };
    let id = |v: HeaderValue| ("x-request-id", v);
    let kept = s
        .get_with("/healthz", &[id(HeaderValue::from_static("trace-42:abc"))])
        .await;
    assert_eq!(id_of(&kept), b"trace-42:abc");
    let long = HeaderValue::from_str(&"a".repeat(129)).unwrap();
    for bad in [
        vec![id(HeaderValue::from_static(""))],
        vec![id(HeaderValue::from_bytes(b"\xff\xfe").unwrap())],
        vec![id(long)],
        vec![id(HeaderValue::from_static("with space"))],
        vec![
            id(HeaderValue::from_static("a")),
            id(HeaderValue::from_static("b")),
        ],
    ] {
        let got = id_of(&s.get_with("/healthz", &bad).await);
        assert_eq!(
            got.len(),
            36,
            "{bad:?} -> {:?}",
            String::from_utf8_lossy(&got)
        );
        assert!(got.iter().all(|c| c.is_ascii_hexdigit() || *c == b'-'));
    }
}

/// However many values are bad, the answer lists the first 100 and counts
/// the rest (a 4 MiB body of bad rows used to produce an 80 MB answer).
#[tokio::test]
async fn a_flood_of_invalid_values_gives_a_bounded_answer() {
    let s = Server::default().await;
    let rows: Vec<Value> = (0..5000).map(|_| json!([1e13, 1e300])).collect();
    let p = problem_of(
        s.post(&json!({"horizon": 5000, "initial_controls": rows}))
            .await,
        StatusCode::UNPROCESSABLE_ENTITY,
    )
    .await;
    let errors = p["errors"].as_array().unwrap();
    assert_eq!(errors.len(), 100);
    assert_eq!(errors[0]["pointer"], "/initial_controls/0/0");
    assert_eq!(
        errors[0]["detail"],
        "must be a number from -1e12 to 1e12 (N), got 1e13"
    );
    assert_eq!(
        errors[1]["detail"],
        "must be a number from -1e12 to 1e12 (N), got 1e300"
    );
    // Every entry names a field; the rest are counted apart (they used to
    // be one more entry, pointer "", which looked like a whole-document error).
    assert!(errors.iter().all(|e| e["pointer"] != ""), "{errors:?}");
    assert_eq!(p["unlisted_errors"], 9900);
    assert_eq!(
        p["detail"],
        "10000 invalid values; `errors` lists the first 100 and `unlisted_errors` counts the other 9900"
    );

    // At the cap exactly, everything is listed and nothing is counted apart.
    let rows: Vec<Value> = (0..50).map(|_| json!([1e13, 1e300])).collect();
    let p = problem_of(
        s.post(&json!({"horizon": 50, "initial_controls": rows}))
            .await,
        StatusCode::UNPROCESSABLE_ENTITY,
    )
    .await;
    assert_eq!(p["errors"].as_array().unwrap().len(), 100);
    assert!(p.get("unlisted_errors").is_none(), "{p}");
    assert_eq!(p["detail"], "100 invalid fields; see `errors`");
}

/// `Content-Encoding: IDENTITY` is identity (codings are case-insensitive),
/// a transfer coding besides `chunked` is a compressed body (hyper undoes
/// only `chunked`: `gzip, chunked` reached the parser as gzip bytes), and
/// a body whose chunked framing is broken is "unreadable", not "not
/// JSON".
#[tokio::test]
async fn body_framing_and_coding_edge_cases() {
    let s = Server::default().await;
    // `Content-Encoding: IDENTITY` is identity, and the same Content-Type
    // twice is one media type: both are read.
    for second in [
        ("content-encoding", "IDENTITY"),
        ("content-type", "application/json"),
    ] {
        let res = reqwest::Client::new()
            .post(s.url("/solve"))
            .header("content-type", "application/json")
            .header(second.0, second.1)
            .body(r#"{"solver": {"max_iterations": 1}}"#)
            .send()
            .await
            .unwrap();
        assert_eq!(res.status(), 200, "{second:?}");
    }

    // hyper answers a coding that does not end in `chunked` itself (an
    // empty 400), so only one before it reaches the service.
    for (coding, status) in [
        ("gzip, chunked", "415"),
        ("Chunked", "200"),
        ("gzip", "400"),
    ] {
        let request = format!(
            "POST /solve HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\
             Content-Type: application/json\r\nTransfer-Encoding: {coding}\r\n\r\n\
             2\r\n{{}}\r\n0\r\n\r\n"
        );
        let answer = raw_exchange(s.addr, request.as_bytes()).await;
        assert!(
            answer.starts_with(&format!("HTTP/1.1 {status}")),
            "{answer}"
        );
        if status == "400" {
            assert!(answer.contains("content-length: 0"), "{answer}");
        }
        if status == "415" {
            assert!(
                answer.contains(
                    "the body has a transfer coding besides chunked \
                     (Transfer-Encoding: `gzip, chunked`)"
                ),
                "{answer}"
            );
        }
    }

    // RFC 9112 §6.1: chunked is applied once. Twice (on one field line or
    // two), hyper would undo one and pass the other on as the body.
    for codings in [
        "Transfer-Encoding: chunked, chunked\r\n",
        "Transfer-Encoding: chunked\r\nTransfer-Encoding: CHUNKED\r\n",
    ] {
        let request = format!(
            "POST /solve HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\
             Content-Type: application/json\r\n{codings}\r\n\
             7\r\n2\r\n{{}}\r\n\r\n0\r\n\r\n"
        );
        let answer = raw_exchange(s.addr, request.as_bytes()).await;
        assert!(answer.starts_with("HTTP/1.1 400"), "{codings}: {answer}");
        assert!(
            answer.contains("urn:ilqr-service:unreadable-body"),
            "{answer}"
        );
        assert!(answer.contains("applies chunked 2 times"), "{answer}");
    }

    let answer = raw_exchange(
        s.addr,
        b"POST /solve HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\nzz\r\n{}\r\n0\r\n\r\n",
    )
    .await;
    assert!(answer.starts_with("HTTP/1.1 400"), "{answer}");
    assert!(
        answer.contains("urn:ilqr-service:unreadable-body"),
        "{answer}"
    );
}

/// What the HTTP layer answers itself, before any route runs, is what the
/// spec says: an empty 400 for broken framing, an empty 414 for a request
/// target of 65535 bytes or more (65534 still reaches the route) and an
/// empty 431 for too many header fields, each followed by a closed connection (so a client never
/// waits on a half-read request).
#[tokio::test]
async fn requests_the_http_layer_rejects_get_the_documented_status() {
    let s = Server::default().await;
    let many: String = (0..120).map(|i| format!("x-h{i}: 1\r\n")).collect();
    for (request, status) in [
        (
            "POST /solve HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: abc\r\n\r\n{}".to_owned(),
            "400",
        ),
        (format!("GET /healthz HTTP/1.1\r\nHost: x\r\n{many}\r\n"), "431"),
        (format!("GET {} HTTP/1.1\r\nHost: x\r\n\r\n", target(65_535)), "414"),
    ] {
        let answer = raw_exchange(s.addr, request.as_bytes()).await;
        assert!(answer.starts_with(&format!("HTTP/1.1 {status}")), "{answer}");
        assert!(answer.contains("content-length: 0"), "{answer}");
    }
    let below = format!(
        "GET {} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n",
        target(65_534)
    );
    let answer = raw_exchange(s.addr, below.as_bytes()).await;
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    let spec: Value = s.get("/openapi.json").await.json().await.unwrap();
    for status in ["414", "431"] {
        assert!(spec["paths"]["/solve"]["post"]["responses"][status].is_object());
    }
    let info = spec["info"]["description"].as_str().unwrap();
    assert!(info.contains("more than 100 header fields"), "{info}");
    assert!(info.contains("65535 bytes or more is 414"), "{info}");
}

/// `/healthz?aaa…`: a request target of exactly `len` bytes.
fn target(len: usize) -> String {
    format!("/healthz?{}", "a".repeat(len - "/healthz?".len()))
}

/// An error answer echoes a huge key or string once (the exact pointer in
/// `errors`), not four times: the messages quote at most a few hundred
/// characters of it.
#[tokio::test]
async fn a_huge_key_or_string_is_not_echoed_many_times() {
    let s = Server::default().await;
    let huge = "k".repeat(1_000_000);
    for (body, pointer) in [
        (json!({ &huge: 1 }), format!("/{huge}")),
        (json!({"dt": &huge}), "/dt".to_owned()),
    ] {
        let p = problem_of(s.post(&body).await, StatusCode::UNPROCESSABLE_ENTITY).await;
        let answer = p.to_string().len();
        assert!(answer < pointer.len() + 2_000, "{answer} bytes");
        assert_eq!(p["errors"][0]["pointer"], *pointer);
        for text in [&p["detail"], &p["errors"][0]["detail"]] {
            let text = text.as_str().unwrap();
            assert!(text.len() < 1_000, "{} bytes", text.len());
            assert!(text.contains("characters left out"), "{text}");
        }
    }
    // What serde puts after the quoted input, what was expected, is kept.
    let p = problem_of(
        s.post(&json!({ &huge: 1 })).await,
        StatusCode::UNPROCESSABLE_ENTITY,
    )
    .await;
    assert!(
        p["errors"][0]["detail"]
            .as_str()
            .unwrap()
            .ends_with("expected one of `model`, `integrator`, `dt`, `horizon`, `initial_state`, `goal_state`, `weights`, `obstacles`, `constraints`, `initial_controls`, `warm_start`, `solver`, `output`"),
        "{p}"
    );
}
