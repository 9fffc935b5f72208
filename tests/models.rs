//! Every model and integrator through the service: the answers' shapes
//! follow the model, the states are the rollout of the controls under the
//! core's dynamics, known answers of independent solvers (Crocoddyl's
//! unicycle, IPOPT on an RK4 transcription), `GET /models`,
//! `GET /problems/default?model=`, wrong lengths, and `warm_start`.

use std::sync::atomic::AtomicBool;

use ilqr::{DiscreteDynamics, Euler, Model, Quadrotor2D, Rk4, Unicycle};
use ilqr_service::models::MODELS;
use ilqr_service::problem::{Integrator, Limits, ParseError, ProblemSpec, parse};
use ilqr_service::solve::{SolveResult, SolveStatus, solve};
use nalgebra::SVector;
use reqwest::StatusCode;
use serde_json::{Value, json};

use crate::common::Server;

/// Parse, validate and solve a document.
fn solved(doc: &Value) -> SolveResult {
    let spec = parse(doc.to_string().as_bytes()).unwrap_or_else(|e| panic!("{doc}: {e:?}"));
    spec.validate(&Limits::default())
        .unwrap_or_else(|e| panic!("{doc}: {e:?}"));
    solve(&spec, None, &AtomicBool::new(false)).unwrap()
}

/// The pointers and details of a document's errors.
fn invalid(doc: &Value) -> Vec<(String, String)> {
    let found = match parse(doc.to_string().as_bytes()) {
        Ok(spec) => spec.validate(&Limits::default()).err().unwrap_or_default(),
        Err(ParseError::Shape(s)) => s.with_range_errors(&Limits::default()),
        Err(e) => panic!("{doc}: {e:?}"),
    };
    found
        .errors
        .into_iter()
        .map(|e| (e.pointer, e.detail))
        .collect()
}

/// One step of the discrete dynamics, `(x, u) ↦ x_{k+1}`.
type Step<'a> = Box<dyn Fn(&[f64], &[f64]) -> Vec<f64> + 'a>;

/// `x_{k+1} = F(x_k, u_k)` of `model` under `integrator`, from the core.
fn step_of(spec: &ProblemSpec) -> impl Fn(&[f64], &[f64]) -> Vec<f64> + '_ {
    fn stepped<M: Model<NX, 2> + Clone + 'static, const NX: usize>(
        m: M,
        spec: &ProblemSpec,
    ) -> Step<'_> {
        Box::new(move |x, u| {
            let (x, u) = (
                SVector::<f64, NX>::from_column_slice(x),
                SVector::<f64, 2>::from_column_slice(u),
            );
            let next = match spec.integrator {
                Integrator::Euler => Euler {
                    model: m.clone(),
                    dt: spec.dt,
                }
                .step(&x, &u),
                Integrator::Rk4 => Rk4 {
                    model: m.clone(),
                    dt: spec.dt,
                }
                .step(&x, &u),
            };
            next.as_slice().to_vec()
        })
    }
    let values: Vec<f64> = spec.model.parameters.iter().map(|&(_, v)| v).collect();
    match spec.model.kind.as_str() {
        "quadrotor_2d" => stepped::<_, 6>(Quadrotor2D::from_parameters(&values), spec),
        "unicycle" => stepped::<_, 3>(Unicycle, spec),
        other => panic!("a model this test does not know: {other}"),
    }
}

/// Each model's default problem, under each integrator, converges; its
/// answer has the model's widths, says which model and integrator it was,
/// and its states are the rollout of its controls under the core's
/// dynamics from the initial state.
#[test]
fn every_model_solves_under_every_integrator_with_its_own_widths() {
    for m in &MODELS {
        for integrator in ["euler", "rk4"] {
            let doc = json!({"model": {"type": m.name()}, "integrator": integrator});
            let spec = parse(doc.to_string().as_bytes()).unwrap();
            let r = solved(&doc);
            let (nx, nu, n) = (m.state().len(), m.control().len(), spec.horizon);
            assert_eq!(r.status, SolveStatus::Converged, "{doc}: {r:?}");
            assert_eq!(r.model, m.name());
            assert_eq!(r.integrator.as_str(), integrator);
            assert_eq!((r.states.len(), r.states.width()), (n + 1, nx), "{doc}");
            assert_eq!((r.controls.len(), r.controls.width()), (n, nu), "{doc}");
            let gains = r.gains.as_ref().unwrap();
            assert_eq!(gains.feedback.len(), n);
            assert!(
                gains
                    .feedback
                    .iter()
                    .all(|k| k.len() == nu && k.width() == nx)
            );
            assert_eq!(
                (gains.feedforward.len(), gains.feedforward.width()),
                (n, nu)
            );
            let step = step_of(&spec);
            assert_eq!(&r.states[0], spec.initial_state.as_slice());
            for k in 0..n {
                let next = step(&r.states[k], &r.controls[k]);
                assert_eq!(next.as_slice(), &r.states[k + 1], "{doc}: step {k}");
            }
            assert!(r.cost < r.initial_cost);
        }
    }
}

/// Crocoddyl's `ActionModelUnicycle` costs `½(w_x²‖x‖² + w_u²‖u‖²)` per
/// node and `½w_x²‖x_N‖²` at the end, goal at the origin, Euler: here
/// `Q = Q_f = w_x²/2·I`, `R = w_u²/2·I`. The costs are Crocoddyl 3.2.1's
/// `SolverDDP` on the same problems (`bench/crocoddyl_unicycle.py`), from
/// zero controls; both solvers stop within 1e-9 relative of the optimum.
#[test]
fn the_unicycle_reaches_crocoddyls_optimum() {
    for (x0, w_x, w_u, dt, horizon, crocoddyl) in [
        ([-1.0, -1.0, 1.0], 10.0, 1.0, 0.1, 100, 250.039_319_973_201),
        ([-1.0, -1.0, 1.0], 10.0, 1.0, 0.1, 1000, 250.157_804_932_506),
        ([2.0, -1.5, -2.5], 3.0, 2.0, 0.1, 100, 503.831_485_140_596),
    ] {
        let (q, r): (f64, f64) = (w_x * w_x / 2.0, w_u * w_u / 2.0);
        let doc = json!({
            "model": {"type": "unicycle"},
            "dt": dt,
            "horizon": horizon,
            "initial_state": x0,
            "goal_state": [0, 0, 0],
            "weights": {"state": [q, q, q], "control": [r, r], "terminal": [q, q, q]},
            "obstacles": [],
        });
        let result = solved(&doc);
        assert_eq!(result.status, SolveStatus::Converged, "{doc}");
        assert!(
            (result.cost - crocoddyl).abs() <= 1e-6 * crocoddyl,
            "{doc}: {} against Crocoddyl's {crocoddyl}",
            result.cost
        );
    }
}

/// The CLI solves the same unicycle problem to the same optimum, and its
/// summary says which model and integrator it used.
#[test]
fn the_cli_solves_a_unicycle_problem_to_crocoddyls_optimum() {
    use std::io::Write;
    use std::process::{Command, Stdio};
    let doc = json!({
        "model": {"type": "unicycle"},
        "dt": 0.1,
        "horizon": 100,
        "initial_state": [-1, -1, 1],
        "goal_state": [0, 0, 0],
        "weights": {"state": [50, 50, 50], "control": [0.5, 0.5], "terminal": [50, 50, 50]},
        "obstacles": [],
    });
    let mut child = Command::new(env!("CARGO_BIN_EXE_ilqr-service"))
        .args(["solve", "-", "--output", "-"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(doc.to_string().as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success());
    let summary = String::from_utf8(out.stderr).unwrap();
    assert!(
        summary.starts_with("model            unicycle (euler)\nstatus           converged"),
        "{summary}"
    );
    let result: Value = serde_json::from_slice(&out.stdout).unwrap();
    let crocoddyl = 250.039_319_973_201;
    let cost = result["cost"].as_f64().unwrap();
    assert!((cost - crocoddyl).abs() <= 1e-6 * crocoddyl, "{cost}");
}

/// IPOPT's optimum of the seed problem transcribed with the same RK4 step
/// (`bench/casadi_ipopt.py --integrator rk4`): started from its controls,
/// the service's RK4 solve stays at its cost and converges at once.
#[test]
fn an_rk4_solve_from_ipopts_rk4_optimum_stays_there() {
    let fixture: Value = serde_json::from_str(include_str!(
        "../crates/ilqr/tests/fixtures/seed_rk4_ipopt_controls.json"
    ))
    .unwrap();
    let ipopt = fixture["cost"].as_f64().unwrap();
    let r = solved(&json!({
        "integrator": "rk4",
        "initial_controls": fixture["initial_controls"],
    }));
    assert_eq!(r.status, SolveStatus::Converged);
    assert!(r.iterations <= 3, "{} iterations", r.iterations);
    assert!(
        (r.cost - ipopt).abs() <= 1e-7 * ipopt,
        "{} against {ipopt}",
        r.cost
    );
    assert!((r.initial_cost - ipopt).abs() <= 1e-9 * ipopt);
}

/// A vector of the wrong length is named with its pointer, the model and
/// the length it needs, for each model; a parameter the model does not
/// have, and a model the service does not have, are named too.
#[test]
fn wrong_lengths_and_unknown_names_are_told_per_model() {
    for m in &MODELS {
        let (nx, nu) = (m.state().len(), m.control().len());
        let doc = json!({
            "model": {"type": m.name()},
            "horizon": 2,
            "initial_state": vec![0.0; nx + 1],
            "goal_state": vec![0.0; nx - 1],
            "weights": {"control": vec![1.0; nu + 2], "terminal": vec![1.0; 1]},
            "initial_controls": [vec![0.0; nu], vec![0.0; nu + 1]],
        });
        let errors = invalid(&doc);
        let pointers: Vec<&str> = errors.iter().map(|(p, _)| p.as_str()).collect();
        assert_eq!(
            pointers,
            [
                "/initial_state",
                "/goal_state",
                "/weights/control",
                "/weights/terminal",
                "/initial_controls/1"
            ],
            "{doc}"
        );
        for ((pointer, detail), (expected, got)) in errors.iter().zip([
            (nx, nx + 1),
            (nx, nx - 1),
            (nu, nu + 2),
            (nx, 1),
            (nu, nu + 1),
        ]) {
            let wanted = format!("must have {expected} entries for model `{}`", m.name());
            assert!(detail.starts_with(&wanted), "{pointer}: {detail}");
            assert!(
                detail.ends_with(&format!("got {got}")),
                "{pointer}: {detail}"
            );
        }
    }
    let unknown = invalid(&json!({"model": {"type": "cartpole"}, "dt": -1}));
    assert_eq!(unknown[0].0, "/model/type");
    assert!(
        unknown[0].1.contains("`quadrotor_2d`, `unicycle`"),
        "{}",
        unknown[0].1
    );
    // The lengths are not checked against a model nobody asked for; the
    // rest still is.
    assert_eq!(unknown.len(), 2);
    assert_eq!(unknown[1].0, "/dt");
    let parameter = invalid(&json!({"model": {"type": "unicycle", "mass": 2}}));
    assert_eq!(parameter[0].0, "/model/mass");
    assert!(
        parameter[0].1.contains("has no parameters"),
        "{}",
        parameter[0].1
    );
    let typo = invalid(&json!({"model": {"mas": 2}}));
    assert_eq!(typo[0].0, "/model/mas");
    assert!(typo[0].1.contains("`mass`"), "{}", typo[0].1);
}

/// A result's controls as `warm_start` start where the result ended: the
/// same cost, at once; the horizon comes from them when the problem gives
/// none; `initial_controls` beside it, or a result of another model, is
/// refused; and a result posted as a problem is told to use `warm_start`.
#[test]
fn a_result_warm_starts_a_solve_of_its_own_problem() {
    for m in &MODELS {
        let doc = json!({"model": {"type": m.name()}, "horizon": 40, "output": {"trace": false}});
        let first = serde_json::to_value(solved(&doc)).unwrap();
        let again = solved(&json!({
            "model": {"type": m.name()},
            "warm_start": first,
        }));
        assert_eq!(again.states.len(), 41, "the horizon is the warm start's");
        assert_eq!(again.status, SolveStatus::Converged);
        assert!(again.iterations <= 2, "{} iterations", again.iterations);
        let cost = first["cost"].as_f64().unwrap();
        assert!((again.initial_cost - cost).abs() <= 1e-12 * cost);
        assert!(again.cost <= cost);
    }
    let unicycle = serde_json::to_value(solved(&json!({"model": {"type": "unicycle"}}))).unwrap();
    let mismatch = invalid(&json!({"warm_start": unicycle}));
    assert!(
        mismatch
            .iter()
            .any(|(p, d)| p == "/warm_start/model" && d.contains("`unicycle`")),
        "{mismatch:?}"
    );
    let both = invalid(&json!({
        "model": {"type": "unicycle"},
        "warm_start": unicycle,
        "initial_controls": unicycle["controls"],
    }));
    assert!(both.iter().any(|(p, _)| p == "/warm_start"), "{both:?}");
    let posted_back = invalid(&unicycle);
    assert!(
        posted_back
            .iter()
            .any(|(p, d)| p == "/status" && d.contains("send it as the problem's `warm_start`")),
        "{posted_back:?}"
    );
    // Its `model`, a name where a problem has an object, says so too.
    assert!(
        posted_back
            .iter()
            .any(|(p, d)| p == "/model" && d.contains("{\"type\": <name>}")),
        "{posted_back:?}"
    );
}

impl Server {
    async fn solve(&self, body: &Value) -> Value {
        let res = self.post_to("/solve", body).await;
        assert_eq!(res.status(), StatusCode::OK);
        res.json().await.unwrap()
    }
}

/// `GET /models` describes every model as the registry does, with a
/// default problem that is `{"model": {"type": ...}}` expanded: posting
/// either gives the same answer. `GET /problems/default?model=` serves the
/// same document, indented on request; an unknown model is a 404 and an
/// unknown parameter a 400, both problem documents.
#[tokio::test]
async fn the_models_and_their_default_problems_are_served() {
    let s = Server::default().await;
    let listed: Value = s.get("/models").await.json().await.unwrap();
    let listed = listed["models"].as_array().unwrap();
    assert_eq!(listed.len(), MODELS.len());
    for (info, m) in listed.iter().zip(&MODELS) {
        assert_eq!(info["type"], m.name());
        assert_eq!(info["state"].as_array().unwrap().len(), m.state().len());
        assert_eq!(info["control"].as_array().unwrap().len(), m.control().len());
        assert_eq!(
            info["parameters"].as_array().unwrap().len(),
            m.parameters().len()
        );
        let (x, y) = m.position();
        assert_eq!(info["position"], json!([x, y]));
        let path = format!("/problems/default?model={}", m.name());
        let served: Value = s.get(&path).await.json().await.unwrap();
        assert_eq!(served, info["default_problem"]);
        let expanded = s.solve(&served).await;
        let short = s.solve(&json!({"model": {"type": m.name()}})).await;
        for member in ["cost", "iterations", "states", "controls", "model"] {
            assert_eq!(expanded[member], short[member], "{member} of {}", m.name());
        }
        let pretty = s
            .get(&format!("{path}&pretty=true"))
            .await
            .text()
            .await
            .unwrap();
        assert!(pretty.starts_with("{\n  \"model\": {\n"), "{pretty}");
        assert_eq!(serde_json::from_str::<Value>(&pretty).unwrap(), served);
    }
    let plain: Value = s.get("/problems/default").await.json().await.unwrap();
    assert_eq!(plain, listed[0]["default_problem"]);
    let unknown = s.get("/problems/default?model=cartpole").await;
    assert_eq!(unknown.status(), StatusCode::NOT_FOUND);
    let p: Value = unknown.json().await.unwrap();
    assert!(p["detail"].as_str().unwrap().contains("`unicycle`"), "{p}");
    for query in ["?pretty=maybe", "?modle=unicycle"] {
        let bad = s.get(&format!("/problems/default{query}")).await;
        assert_eq!(bad.status(), StatusCode::BAD_REQUEST, "{query}");
        assert_eq!(bad.headers()["content-type"], "application/problem+json");
        let p: Value = bad.json().await.unwrap();
        assert_eq!(p["type"], "urn:ilqr-service:bad-query");
    }
}
