//! Between the protobuf messages of `proto/ilqr/v1/ilqr.proto` and the
//! service's own types.
//!
//! A problem that arrives over gRPC is written as the JSON problem document,
//! member for member, and read by [`crate::problem::parse`], as a body of
//! `POST /solve` is: the same defaults, the same validation and the same
//! JSON pointers in its errors, so that the two transports cannot disagree.
//! What JSON cannot hold is handled here:
//!
//! * a flat `initial_controls` or `warm_start_controls` is split into rows
//!   of the model's number of controls (NU, from the registry); with a model
//!   this service does not have, the whole array is one row (the validation
//!   then reports the model);
//! * a member left out (proto3 `optional` unset, an empty repeated field,
//!   `*_UNSPECIFIED`) is left out of the document;
//! * a value JSON has no number for (NaN, ±infinity) or an enum value the
//!   contract does not define is written as `null`, which the parser reports
//!   as a wrong type at its pointer and takes out, so the rest is still
//!   checked; that error's detail is then replaced by one that says what
//!   was sent ([`Document::replaced`]);
//! * a model parameter named `type`, which the document's `model` object
//!   cannot hold beside the model's name, is an error of its own at
//!   `/model/parameters/type`.

use std::collections::BTreeMap;

use serde_json::{Map, Value, json};

use super::proto;
use crate::models::{self, ModelInfo};
use crate::problem::{
    FieldError, Integrator, Invalid, Limits, MAX_REPORTED_ERRORS, Method, ObstacleShape,
    ParseError, ProblemSpec, escape_token, num,
};
use crate::solve::{SolveResult, SolveStatus, TraceEntry};

/// A problem message written as the JSON problem document.
#[derive(Debug)]
pub struct Document {
    /// The document, as JSON text.
    pub json: Vec<u8>,
    /// The pointers written as `null` because JSON cannot hold what was
    /// sent, each with the detail its error gets.
    pub replaced: BTreeMap<String, String>,
    /// Errors found in the message itself, before the document is read.
    pub errors: Vec<FieldError>,
    /// How the flat arrays were split into rows.
    pub flat: Flat,
}

/// How the flat arrays of a problem were split into rows, for the
/// descriptions of their errors.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Flat {
    /// `initial_controls`, if given.
    pub initial_controls: Option<Split>,
    /// `warm_start_controls`, if given.
    pub warm_start_controls: Option<Split>,
}

/// One flat array split into rows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Split {
    /// Its entries.
    pub len: usize,
    /// Entries per row: NU, or `len` when the model is unknown.
    pub width: usize,
    /// Whether the model is one this service has (else one row).
    pub model_known: bool,
}

impl Split {
    fn rows(&self) -> usize {
        self.len.div_ceil(self.width.max(1))
    }
}

/// Why a problem message is not a problem: every invalid value, with the
/// flat arrays' split for the descriptions.
#[derive(Debug, Clone, PartialEq)]
pub struct Rejected {
    /// The invalid values, as the HTTP API lists them.
    pub invalid: Invalid,
    /// How the flat arrays were split.
    pub flat: Flat,
}

/// The problem of a `SolveRequest` (none: the default problem, as `{}`
/// over HTTP), converted, parsed and checked for wrong shapes; its ranges
/// are checked by the solve service, as for HTTP. `Err(None)` is a bug:
/// the document written here was not JSON.
pub fn spec_of(
    problem: Option<proto::Problem>,
    limits: &Limits,
) -> Result<(ProblemSpec, Flat), Option<Rejected>> {
    let doc = document(problem.unwrap_or_default());
    let parsed = crate::problem::parse(&doc.json);
    let invalid = match parsed {
        Ok(spec) if doc.errors.is_empty() => return Ok((spec, doc.flat)),
        // The rest of the problem is checked too, so that one answer lists
        // everything.
        Ok(spec) => spec.validate(limits).err().unwrap_or_default(),
        Err(ParseError::Shape(shapes)) => shapes.with_range_errors(limits),
        Err(ParseError::Syntax(message)) => {
            tracing::error!(%message, "the JSON written from a problem message is not JSON");
            return Err(None);
        }
    };
    Err(Some(Rejected {
        invalid: merge(invalid, doc.errors, &doc.replaced),
        flat: doc.flat,
    }))
}

/// `found` with the conversion's own `errors` first and the details of
/// the values written as `null` replaced, within the list's cap.
fn merge(
    mut found: Invalid,
    errors: Vec<FieldError>,
    replaced: &BTreeMap<String, String>,
) -> Invalid {
    for e in &mut found.errors {
        if let Some(detail) = replaced.get(&e.pointer) {
            e.detail.clone_from(detail);
        }
    }
    let mut all = errors;
    all.append(&mut found.errors);
    if all.len() > MAX_REPORTED_ERRORS {
        found.unlisted += all.len() - MAX_REPORTED_ERRORS;
        all.truncate(MAX_REPORTED_ERRORS);
    }
    found.errors = all;
    found
}

/// The JSON problem document of `p`, member for member.
pub fn document(p: proto::Problem) -> Document {
    let mut w = Writer::default();
    let mut doc = Map::new();
    let kind = p.model.as_ref().and_then(|m| m.r#type.clone());
    let served = models::find(kind.as_deref().unwrap_or(models::DEFAULT_MODEL));
    if let Some(model) = p.model {
        let mut members = Map::new();
        if let Some(kind) = model.r#type {
            members.insert("type".into(), Value::String(kind));
        }
        for (name, value) in model.parameters {
            if name == "type" {
                w.errors.push(FieldError {
                    pointer: "/model/parameters/type".into(),
                    detail: "`type` is not a parameter of any model: the model's name is \
                             Model.type"
                        .into(),
                });
                continue;
            }
            let pointer = format!("/model/{}", escape_token(&name));
            members.insert(name, w.number(&pointer, value));
        }
        doc.insert("model".into(), Value::Object(members));
    }
    match integrator_of(p.integrator) {
        Ok(None) => {}
        Ok(Some(i)) => {
            doc.insert("integrator".into(), i.as_str().into());
        }
        Err(n) => {
            doc.insert("integrator".into(), Value::Null);
            w.replace(
                "/integrator",
                format!(
                    "unknown Integrator value {n}: expected INTEGRATOR_EULER (1) or \
                     INTEGRATOR_RK4 (2), or INTEGRATOR_UNSPECIFIED (0) for the default"
                ),
            );
        }
    }
    if let Some(dt) = p.dt {
        doc.insert("dt".into(), w.number("/dt", dt));
    }
    if let Some(horizon) = p.horizon {
        doc.insert("horizon".into(), horizon.into());
    }
    w.vector(
        &mut doc,
        "initial_state",
        "/initial_state",
        &p.initial_state,
    );
    w.vector(&mut doc, "goal_state", "/goal_state", &p.goal_state);
    if let Some(weights) = p.weights {
        let mut members = Map::new();
        w.vector(&mut members, "state", "/weights/state", &weights.state);
        w.vector(
            &mut members,
            "control",
            "/weights/control",
            &weights.control,
        );
        w.vector(
            &mut members,
            "terminal",
            "/weights/terminal",
            &weights.terminal,
        );
        doc.insert("weights".into(), Value::Object(members));
    }
    if let Some(obstacles) = p.obstacles {
        let items = obstacles
            .items
            .into_iter()
            .enumerate()
            .map(|(j, o)| {
                let mut members = Map::new();
                // Always written, empty too: the centre has no default, and
                // the parser says what it takes.
                let center = w.numbers(&format!("/obstacles/{j}/center"), &o.center);
                members.insert("center".into(), center);
                if let Some(weight) = o.weight {
                    let pointer = format!("/obstacles/{j}/weight");
                    members.insert("weight".into(), w.number(&pointer, weight));
                }
                match shape_of(o.shape) {
                    Ok(None) => {}
                    Ok(Some(shape)) => {
                        members.insert("shape".into(), shape.into());
                    }
                    Err(n) => {
                        members.insert("shape".into(), Value::Null);
                        w.replace(
                            &format!("/obstacles/{j}/shape"),
                            format!(
                                "unknown ObstacleShape value {n}: expected OBSTACLE_SHAPE_POINT \
                                 (1), OBSTACLE_SHAPE_CIRCLE (2) or OBSTACLE_SHAPE_RECTANGLE (3)"
                            ),
                        );
                    }
                }
                for (name, x) in [
                    ("radius", o.radius),
                    ("angle", o.angle),
                    ("clearance", o.clearance),
                ] {
                    if let Some(x) = x {
                        let value = w.number(&format!("/obstacles/{j}/{name}"), x);
                        members.insert(name.into(), value);
                    }
                }
                w.vector(
                    &mut members,
                    "size",
                    &format!("/obstacles/{j}/size"),
                    &o.size,
                );
                Value::Object(members)
            })
            .collect();
        doc.insert("obstacles".into(), Value::Array(items));
    }
    let nu = served.map(|m| m.control().len());
    let mut flat = Flat::default();
    if !p.initial_controls.is_empty() {
        let (rows, split) = w.rows("/initial_controls", &p.initial_controls, nu);
        doc.insert("initial_controls".into(), rows);
        flat.initial_controls = Some(split);
    }
    if !p.warm_start_controls.is_empty() {
        let (rows, split) = w.rows("/warm_start/controls", &p.warm_start_controls, nu);
        doc.insert("warm_start".into(), json!({ "controls": rows }));
        flat.warm_start_controls = Some(split);
    }
    if let Some(s) = p.solver {
        let mut members = Map::new();
        if let Some(n) = s.max_iterations {
            members.insert("max_iterations".into(), n.into());
        }
        if let Some(t) = s.tolerance {
            members.insert("tolerance".into(), w.number("/solver/tolerance", t));
        }
        if let Some(ms) = s.time_limit_ms {
            members.insert("time_limit_ms".into(), ms.into());
        }
        if let Some(t) = s.constraint_tolerance {
            let value = w.number("/solver/constraint_tolerance", t);
            members.insert("constraint_tolerance".into(), value);
        }
        if let Some(b) = s.multi_start {
            members.insert("multi_start".into(), b.into());
        }
        if let Some(n) = s.max_starts {
            members.insert("max_starts".into(), n.into());
        }
        match method_of(s.method) {
            Ok(None) => {}
            Ok(Some(m)) => {
                members.insert("method".into(), m.into());
            }
            Err(n) => {
                members.insert("method".into(), Value::Null);
                w.replace(
                    "/solver/method",
                    format!(
                        "unknown Method value {n}: expected METHOD_ILQR (1) or METHOD_DDP (2), \
                         or METHOD_UNSPECIFIED (0) for the default"
                    ),
                );
            }
        }
        doc.insert("solver".into(), Value::Object(members));
    }
    if let Some(c) = p.constraints {
        let mut members = Map::new();
        for (name, bounds) in [("control", c.control), ("state", c.state)] {
            let Some(b) = bounds else { continue };
            let mut sides = Map::new();
            for (side, xs, none) in [
                ("lower", &b.lower, f64::NEG_INFINITY),
                ("upper", &b.upper, f64::INFINITY),
            ] {
                if xs.is_empty() {
                    continue;
                }
                let pointer = format!("/constraints/{name}/{side}");
                let values = xs
                    .iter()
                    .enumerate()
                    .map(|(i, &x)| {
                        if x == none {
                            Value::Null
                        } else {
                            w.number(&format!("{pointer}/{i}"), x)
                        }
                    })
                    .collect();
                sides.insert(side.into(), Value::Array(values));
            }
            members.insert(name.into(), Value::Object(sides));
        }
        w.vector(
            &mut members,
            "goal_tolerance",
            "/constraints/goal_tolerance",
            &c.goal_tolerance,
        );
        doc.insert("constraints".into(), Value::Object(members));
    }
    if let Some(o) = p.output {
        let mut members = Map::new();
        if let Some(gains) = o.gains {
            members.insert("gains".into(), gains.into());
        }
        if let Some(trace) = o.trace {
            members.insert("trace".into(), trace.into());
        }
        doc.insert("output".into(), Value::Object(members));
    }
    Document {
        // Writing a `Value` to a Vec fails only for a map with non-string
        // keys, which a `Value` cannot have.
        json: serde_json::to_vec(&Value::Object(doc)).unwrap_or_default(),
        replaced: w.replaced,
        errors: w.errors,
        flat,
    }
}

/// Collects what the document could not hold while it is written.
#[derive(Default)]
struct Writer {
    replaced: BTreeMap<String, String>,
    errors: Vec<FieldError>,
}

impl Writer {
    fn replace(&mut self, pointer: &str, detail: String) {
        self.replaced.insert(pointer.to_owned(), detail);
    }

    /// `x` as a JSON number, or `null` with the detail its error gets.
    fn number(&mut self, pointer: &str, x: f64) -> Value {
        match serde_json::Number::from_f64(x) {
            Some(n) => Value::Number(n),
            None => {
                self.replace(pointer, format!("got {}: expected a finite number", num(x)));
                Value::Null
            }
        }
    }

    fn numbers(&mut self, pointer: &str, xs: &[f64]) -> Value {
        Value::Array(
            xs.iter()
                .enumerate()
                .map(|(i, &x)| self.number(&format!("{pointer}/{i}"), x))
                .collect(),
        )
    }

    /// A vector member, left out when empty.
    fn vector(&mut self, members: &mut Map<String, Value>, name: &str, pointer: &str, xs: &[f64]) {
        if !xs.is_empty() {
            let value = self.numbers(pointer, xs);
            members.insert(name.into(), value);
        }
    }

    /// A flat array as rows of `width` (NU) entries, the last one short if
    /// the length is not a multiple; one row when the width is unknown.
    fn rows(&mut self, pointer: &str, xs: &[f64], width: Option<usize>) -> (Value, Split) {
        let split = Split {
            len: xs.len(),
            width: width.filter(|&w| w > 0).unwrap_or(xs.len()),
            model_known: width.is_some(),
        };
        let rows = xs
            .chunks(split.width.max(1))
            .enumerate()
            .map(|(k, row)| self.numbers(&format!("{pointer}/{k}"), row))
            .collect();
        (Value::Array(rows), split)
    }
}

/// What a description of an error at `pointer` adds when the value is in
/// a flat array: where the row or entry is in the array as sent.
pub fn flat_note(pointer: &str, flat: &Flat) -> Option<String> {
    let (rest, split, member) = if let Some(rest) = pointer.strip_prefix("/initial_controls") {
        (rest, flat.initial_controls?, "initial_controls")
    } else if let Some(rest) = pointer.strip_prefix("/warm_start/controls") {
        (rest, flat.warm_start_controls?, "warm_start_controls")
    } else if pointer == "/warm_start" {
        return Some("(warm_start is warm_start_controls here)".into());
    } else {
        return None;
    };
    if !split.model_known {
        return Some(format!(
            "({member} is flat; with an unknown model its {} entries were read as one row)",
            split.len
        ));
    }
    let w = split.width;
    let mut tokens = rest.split('/').skip(1).map(str::parse::<usize>);
    Some(match (tokens.next(), tokens.next()) {
        (None, _) => format!(
            "({member} is flat, rows of NU = {w} one after another: its {} entries are {} \
             rows{})",
            split.len,
            split.rows(),
            if split.len % w == 0 {
                String::new()
            } else {
                format!(", the last of {}", split.len % w)
            }
        ),
        (Some(Ok(k)), None) => {
            let first = k * w;
            let last = (first + w).min(split.len).saturating_sub(1);
            if first == last {
                format!("(row {k} of the flat {member}: its entry {first})")
            } else {
                format!("(row {k} of the flat {member}: its entries {first} to {last})")
            }
        }
        (Some(Ok(k)), Some(Ok(i))) => format!(
            "(entry {} of the flat {member}: row {k}, column {i}, rows of NU = {w})",
            k * w + i
        ),
        _ => return None,
    })
}

/// The message's integrator: `Ok(None)` for unspecified (the default),
/// `Err` with the value for one the contract does not define.
fn integrator_of(value: i32) -> Result<Option<Integrator>, i32> {
    match proto::Integrator::try_from(value) {
        Ok(proto::Integrator::Unspecified) => Ok(None),
        Ok(proto::Integrator::Euler) => Ok(Some(Integrator::Euler)),
        Ok(proto::Integrator::Rk4) => Ok(Some(Integrator::Rk4)),
        Err(_) => Err(value),
    }
}

/// The message's method, as [`integrator_of`], by its JSON name.
fn method_of(value: i32) -> Result<Option<&'static str>, i32> {
    match proto::Method::try_from(value) {
        Ok(proto::Method::Unspecified) => Ok(None),
        Ok(proto::Method::Ilqr) => Ok(Some("ilqr")),
        Ok(proto::Method::Ddp) => Ok(Some("ddp")),
        Err(_) => Err(value),
    }
}

fn shape_of(value: i32) -> Result<Option<&'static str>, i32> {
    match proto::ObstacleShape::try_from(value) {
        Ok(proto::ObstacleShape::Unspecified) => Ok(None),
        Ok(proto::ObstacleShape::Point) => Ok(Some("point")),
        Ok(proto::ObstacleShape::Circle) => Ok(Some("circle")),
        Ok(proto::ObstacleShape::Rectangle) => Ok(Some("rectangle")),
        Err(_) => Err(value),
    }
}

fn shape(s: ObstacleShape) -> proto::ObstacleShape {
    match s {
        ObstacleShape::Point => proto::ObstacleShape::Point,
        ObstacleShape::Circle => proto::ObstacleShape::Circle,
        ObstacleShape::Rectangle => proto::ObstacleShape::Rectangle,
    }
}

fn integrator(i: Integrator) -> proto::Integrator {
    match i {
        Integrator::Euler => proto::Integrator::Euler,
        Integrator::Rk4 => proto::Integrator::Rk4,
    }
}

fn method(m: Method) -> proto::Method {
    match m {
        Method::Ilqr => proto::Method::Ilqr,
        Method::Ddp => proto::Method::Ddp,
    }
}

fn status(s: SolveStatus) -> proto::SolveStatus {
    match s {
        SolveStatus::Converged => proto::SolveStatus::Converged,
        SolveStatus::MaxIterations => proto::SolveStatus::MaxIterations,
        SolveStatus::TimeLimit => proto::SolveStatus::TimeLimit,
        SolveStatus::Cancelled => proto::SolveStatus::Cancelled,
        SolveStatus::NoProgress => proto::SolveStatus::NoProgress,
        SolveStatus::Infeasible => proto::SolveStatus::Infeasible,
    }
}

/// A count as the contract's `uint32` (counts here are at most 10000).
fn u32_of(n: usize) -> u32 {
    u32::try_from(n).unwrap_or(u32::MAX)
}

/// A problem with every member filled in, as a message (`GetDefaultProblem`,
/// `ListModels`).
pub fn problem_message(spec: &ProblemSpec) -> proto::Problem {
    let flat = |rows: &[Vec<f64>]| rows.iter().flatten().copied().collect();
    proto::Problem {
        model: Some(proto::Model {
            r#type: Some(spec.model.kind.clone()),
            parameters: spec.model.parameters.iter().cloned().collect(),
        }),
        integrator: integrator(spec.integrator).into(),
        dt: Some(spec.dt),
        horizon: Some(u32_of(spec.horizon)),
        initial_state: spec.initial_state.clone(),
        goal_state: spec.goal_state.clone(),
        weights: Some(proto::Weights {
            state: spec.weights.state.clone(),
            control: spec.weights.control.clone(),
            terminal: spec.weights.terminal.clone(),
        }),
        obstacles: Some(proto::Obstacles {
            items: spec
                .obstacles
                .iter()
                .map(|o| proto::Obstacle {
                    center: o.center.to_vec(),
                    weight: Some(o.weight),
                    shape: shape(o.shape).into(),
                    radius: o.radius,
                    size: o.size.map_or_else(Vec::new, |s| s.to_vec()),
                    angle: o.angle,
                    clearance: o.clearance,
                })
                .collect(),
        }),
        initial_controls: spec.initial_controls.as_deref().map_or_else(Vec::new, flat),
        warm_start_controls: spec
            .warm_start
            .as_ref()
            .map_or_else(Vec::new, |w| flat(&w.controls)),
        solver: Some(proto::SolverOptions {
            max_iterations: Some(u32_of(spec.solver.max_iterations)),
            tolerance: Some(spec.solver.tolerance),
            time_limit_ms: spec.solver.time_limit_ms,
            method: method(spec.solver.method).into(),
            constraint_tolerance: Some(spec.solver.constraint_tolerance),
            multi_start: spec.solver.multi_start,
            max_starts: Some(u32_of(spec.solver.max_starts)),
        }),
        constraints: (!spec.constraints.is_empty()).then(|| {
            let c = &spec.constraints;
            let bounds = |b: &crate::problem::Bounds| {
                let side = |xs: &Option<Vec<Option<f64>>>, none: f64| {
                    xs.iter().flatten().map(|x| x.unwrap_or(none)).collect()
                };
                proto::Bounds {
                    lower: side(&b.lower, f64::NEG_INFINITY),
                    upper: side(&b.upper, f64::INFINITY),
                }
            };
            proto::Constraints {
                control: c.control.as_ref().map(bounds),
                state: c.state.as_ref().map(bounds),
                goal_tolerance: c.goal_tolerance.clone().unwrap_or_default(),
            }
        }),
        output: Some(proto::OutputOptions {
            gains: Some(spec.output.gains),
            trace: Some(spec.output.trace),
        }),
    }
}

/// A model's description as a message.
pub fn model_message(m: &ModelInfo) -> proto::ModelInfo {
    proto::ModelInfo {
        r#type: m.kind.into(),
        description: m.description.into(),
        state: m.state.iter().map(quantity_message).collect(),
        control: m.control.iter().map(quantity_message).collect(),
        parameters: m
            .parameters
            .iter()
            .map(|p| proto::Parameter {
                name: p.name.into(),
                unit: p.unit.into(),
                description: p.description.into(),
                default: p.default,
                minimum: p.minimum,
                maximum: p.maximum,
            })
            .collect(),
        position: m.position.iter().map(|&i| u32_of(i)).collect(),
        default_problem: Some(problem_message(&m.default_problem)),
    }
}

/// A state or control component as a message.
fn quantity_message(q: &models::QuantityInfo) -> proto::Quantity {
    proto::Quantity {
        name: q.name.into(),
        unit: q.unit.into(),
        description: q.description.into(),
    }
}

/// A trace row as a message.
pub fn trace_message(t: &TraceEntry) -> proto::TraceEntry {
    proto::TraceEntry {
        iteration: u32_of(t.iteration),
        cost: t.cost,
        expected_reduction: t.expected_reduction,
        actual_reduction: t.actual_reduction,
        step_size: t.step_size,
        regularization: t.regularization,
        feedforward_norm: t.feedforward_norm,
        convex_model: t.convex_model,
        elapsed_ms: t.elapsed_ms,
        outer_iteration: t.outer_iteration.map(u32_of),
        constraint_violation: t.constraint_violation,
        penalty: t.penalty,
        start: t.start.map(u32_of),
    }
}

/// A result as a message: matrices flat and row-major, the gains' `K_k`
/// one after another.
pub fn result_message(r: &SolveResult) -> proto::SolveResult {
    proto::SolveResult {
        model: r.model.clone(),
        integrator: integrator(r.integrator).into(),
        status: status(r.status).into(),
        cost: r.cost,
        initial_cost: r.initial_cost,
        iterations: u32_of(r.iterations),
        goal_distance: r.goal_distance,
        closest_approach: r.closest_approach.clone(),
        states: r.states.flat().to_vec(),
        controls: r.controls.flat().to_vec(),
        state_dim: u32_of(r.states.width()),
        control_dim: u32_of(r.controls.width()),
        gains: r.gains.as_ref().map(|g| proto::Gains {
            feedback: g
                .feedback
                .iter()
                .flat_map(|k| k.flat().iter().copied())
                .collect(),
            feedforward: g.feedforward.flat().to_vec(),
            regularization: g.regularization,
            about_previous_iterate: g.about_previous_iterate,
        }),
        trace: r
            .trace
            .as_deref()
            .unwrap_or_default()
            .iter()
            .map(trace_message)
            .collect(),
        convexified_after_iteration: r.convexified_after_iteration.map(u32_of),
        convex_model_at_end: r.convex_model_at_end,
        solve_time_ms: r.solve_time_ms,
        queue_time_ms: r.queue_time_ms,
        constraint_violation: r.constraint_violation,
        constraint_report: r.constraint_report.as_ref().map(|c| {
            let status = |s: &crate::solve::ConstraintStatus| proto::ConstraintStatus {
                max_violation: s.max_violation,
                active_steps: u32_of(s.active_steps),
            };
            proto::ConstraintReport {
                outer_iterations: u32_of(c.outer_iterations),
                control: c.control.as_ref().map(status),
                state: c.state.as_ref().map(status),
                goal: c.goal.as_ref().map(status),
                obstacles: c
                    .obstacles
                    .iter()
                    .map(|o| proto::ObstacleStatus {
                        obstacle: u32_of(o.obstacle),
                        max_violation: o.max_violation,
                        active_steps: u32_of(o.active_steps),
                        smallest_distance: o.smallest_distance,
                    })
                    .collect(),
            }
        }),
        warnings: r
            .warnings
            .iter()
            .map(|w| proto::Warning {
                code: w.code.as_str().into(),
                message: w.message.clone(),
            })
            .collect(),
        starts: r
            .starts
            .iter()
            .map(|s| proto::Start {
                label: s.label.clone(),
                obstacle: s.obstacle.map(u32_of),
                side: s.side.map(|d| d.as_str().into()),
                passes: s.passes.map(|d| d.as_str().into()),
                status: status(s.status).into(),
                cost: s.cost,
                iterations: u32_of(s.iterations),
                guide_iterations: s.guide_iterations.map(u32_of),
                constraint_violation: s.constraint_violation,
                solve_time_ms: s.solve_time_ms,
                chosen: s.chosen,
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn json(p: proto::Problem) -> Value {
        serde_json::from_slice(&document(p).json).unwrap()
    }

    /// Members left out stay out; the rest are written by their JSON names.
    #[test]
    fn a_problem_is_written_member_for_member() {
        assert_eq!(json(proto::Problem::default()), json!({}));
        let p = proto::Problem {
            model: Some(proto::Model {
                r#type: Some("quadrotor_2d".into()),
                parameters: [("mass".to_owned(), 2.0)].into(),
            }),
            integrator: proto::Integrator::Rk4.into(),
            horizon: Some(3),
            initial_controls: vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
            obstacles: Some(proto::Obstacles { items: vec![] }),
            solver: Some(proto::SolverOptions {
                method: proto::Method::Ddp.into(),
                ..Default::default()
            }),
            ..Default::default()
        };
        assert_eq!(
            json(p),
            json!({
                "model": {"type": "quadrotor_2d", "mass": 2.0},
                "integrator": "rk4",
                "horizon": 3,
                "initial_controls": [[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]],
                "obstacles": [],
                "solver": {"method": "ddp"},
            })
        );
    }

    /// An unknown model's flat controls are one row.
    #[test]
    fn an_unknown_models_controls_are_one_row() {
        let p = proto::Problem {
            model: Some(proto::Model {
                r#type: Some("blimp".into()),
                ..Default::default()
            }),
            warm_start_controls: vec![1.0, 2.0, 3.0],
            ..Default::default()
        };
        let doc = document(p);
        assert_eq!(
            serde_json::from_slice::<Value>(&doc.json).unwrap()["warm_start"],
            json!({"controls": [[1.0, 2.0, 3.0]]})
        );
        assert_eq!(
            doc.flat.warm_start_controls,
            Some(Split {
                len: 3,
                width: 3,
                model_known: false
            })
        );
    }

    /// What JSON cannot hold is written as null, with the detail its error
    /// gets, and the rest of the problem is still checked.
    #[test]
    fn values_json_cannot_hold_are_errors_at_their_pointers() {
        let p = proto::Problem {
            dt: Some(f64::NAN),
            horizon: Some(0),
            initial_state: vec![0.0, f64::INFINITY, 0.0, 0.0, 0.0, 0.0],
            integrator: 7,
            model: Some(proto::Model {
                r#type: None,
                parameters: [("type".to_owned(), 1.0)].into(),
            }),
            ..Default::default()
        };
        let rejected = spec_of(Some(p), &Limits::default()).unwrap_err().unwrap();
        let found: Vec<(&str, &str)> = rejected
            .invalid
            .errors
            .iter()
            .map(|e| (e.pointer.as_str(), e.detail.as_str()))
            .collect();
        let has = |pointer: &str, starts: &str| {
            assert!(
                found
                    .iter()
                    .any(|(p, d)| *p == pointer && d.starts_with(starts)),
                "{pointer}: {starts} not in {found:?}"
            );
        };
        has("/model/parameters/type", "`type` is not a parameter");
        has("/dt", "got NaN: expected a finite number");
        has("/initial_state/1", "got inf: expected a finite number");
        has("/integrator", "unknown Integrator value 7");
        has("/horizon", "must be an integer from 1 to 10000, got 0");
        assert_eq!(found.len(), 5, "{found:?}");
    }

    /// Where a flat array's row or entry is, as sent.
    #[test]
    fn flat_notes_locate_rows_and_entries() {
        let flat = Flat {
            initial_controls: Some(Split {
                len: 7,
                width: 2,
                model_known: true,
            }),
            warm_start_controls: None,
        };
        let note = |p: &str| flat_note(p, &flat);
        assert_eq!(
            note("/initial_controls").unwrap(),
            "(initial_controls is flat, rows of NU = 2 one after another: its 7 entries are 4 \
             rows, the last of 1)"
        );
        assert_eq!(
            note("/initial_controls/1").unwrap(),
            "(row 1 of the flat initial_controls: its entries 2 to 3)"
        );
        assert_eq!(
            note("/initial_controls/3").unwrap(),
            "(row 3 of the flat initial_controls: its entry 6)"
        );
        assert_eq!(
            note("/initial_controls/2/1").unwrap(),
            "(entry 5 of the flat initial_controls: row 2, column 1, rows of NU = 2)"
        );
        assert_eq!(note("/warm_start/controls/0"), None);
        assert_eq!(note("/dt"), None);
    }

    mod arbitrary {
        use proptest::collection::{btree_map, vec};
        use proptest::prelude::*;

        use super::*;

        /// Numbers a caller may send: ordinary, extreme and not numbers.
        fn number() -> impl Strategy<Value = f64> {
            prop_oneof![
                4 => -20.0..20.0f64,
                1 => Just(0.0),
                1 => Just(f64::NAN),
                1 => Just(f64::INFINITY),
                1 => Just(f64::NEG_INFINITY),
                1 => Just(f64::MAX),
                1 => Just(-f64::MIN_POSITIVE),
            ]
        }

        fn numbers(max: usize) -> impl Strategy<Value = Vec<f64>> {
            vec(number(), 0..max)
        }

        fn model() -> impl Strategy<Value = Option<proto::Model>> {
            let name = prop_oneof![
                Just(None),
                Just(Some("quadrotor_2d".to_owned())),
                Just(Some("unicycle".to_owned())),
                Just(Some(String::new())),
                "[a-z/~\"]{0,8}".prop_map(Some),
            ];
            let parameter = prop_oneof![
                Just("mass".to_owned()),
                Just("type".to_owned()),
                Just("arm_length".to_owned()),
                "[a-z/~]{0,6}",
            ];
            proptest::option::of((name, btree_map(parameter, number(), 0..4)).prop_map(
                |(r#type, parameters)| proto::Model {
                    r#type,
                    parameters: parameters.into_iter().collect(),
                },
            ))
        }

        prop_compose! {
            fn problem()(
                model in model(),
                integrator in -1..4i32,
                method in -1..4i32,
                dt in proptest::option::of(number()),
                horizon in proptest::option::of(prop_oneof![0..8u32, Just(u32::MAX)]),
                initial_state in numbers(8),
                goal_state in numbers(8),
                weights in proptest::option::of((numbers(8), numbers(4), numbers(8))),
                obstacles in proptest::option::of(vec((
                    numbers(4),
                    proptest::option::of(number()),
                    -1..5i32,
                    proptest::option::of(number()),
                    numbers(3),
                    proptest::option::of(number()),
                ), 0..4)),
                constraints in proptest::option::of((
                    proptest::option::of((numbers(4), numbers(4))),
                    proptest::option::of((numbers(8), numbers(8))),
                    numbers(8),
                )),
                initial_controls in numbers(20),
                warm_start_controls in numbers(20),
                solver in proptest::option::of((
                    proptest::option::of(any::<u32>()),
                    proptest::option::of(number()),
                    proptest::option::of(any::<u64>()),
                    proptest::option::of(any::<bool>()),
                    proptest::option::of(prop_oneof![0..40u32, Just(u32::MAX)]),
                )),
            ) -> proto::Problem {
                proto::Problem {
                    model,
                    integrator,
                    dt,
                    horizon,
                    initial_state,
                    goal_state,
                    weights: weights.map(|(state, control, terminal)| proto::Weights { state, control, terminal }),
                    obstacles: obstacles.map(|items| proto::Obstacles {
                        items: items
                            .into_iter()
                            .map(|(center, weight, shape, radius, size, clearance)| proto::Obstacle {
                                center,
                                weight,
                                shape,
                                radius,
                                size,
                                angle: radius.map(|r| r * 0.5),
                                clearance,
                            })
                            .collect(),
                    }),
                    initial_controls,
                    warm_start_controls,
                    solver: solver.map(|(max_iterations, tolerance, time_limit_ms, multi_start, max_starts)| proto::SolverOptions {
                        max_iterations,
                        tolerance,
                        time_limit_ms,
                        method,
                        constraint_tolerance: tolerance,
                        multi_start,
                        max_starts,
                    }),
                    output: None,
                    constraints: constraints.map(|(control, state, goal_tolerance)| proto::Constraints {
                        control: control.map(|(lower, upper)| proto::Bounds { lower, upper }),
                        state: state.map(|(lower, upper)| proto::Bounds { lower, upper }),
                        goal_tolerance,
                    }),
                }
            }
        }

        proptest! {
            #![proptest_config(ProptestConfig::with_cases(2000))]

            /// Whatever a message holds, converting and validating it ends
            /// in a problem or in field violations that each name a field,
            /// never in a panic or an internal error.
            #[test]
            fn any_message_is_a_problem_or_field_violations(p in problem()) {
                let limits = Limits::default();
                let status = match spec_of(Some(p), &limits) {
                    Ok((spec, flat)) => match spec.validate(&limits) {
                        Ok(()) => return Ok(()),
                        Err(invalid) => crate::grpc::status::invalid(invalid, &flat, "id"),
                    },
                    Err(None) => return Err(TestCaseError::fail("an internal error")),
                    Err(Some(rejected)) => {
                        prop_assert!(!rejected.invalid.errors.is_empty());
                        crate::grpc::status::invalid(rejected.invalid, &rejected.flat, "id")
                    }
                };
                prop_assert_eq!(status.code(), tonic::Code::InvalidArgument);
                let details = tonic_types::StatusExt::get_error_details(&status);
                let violations = details.bad_request().map(|b| b.field_violations.clone());
                prop_assert!(violations.as_ref().is_some_and(|v| !v.is_empty()), "{:?}", status);
                for v in violations.unwrap_or_default() {
                    prop_assert!(!v.field.is_empty() && !v.description.is_empty(), "{:?}", v);
                }
            }
        }
    }
}
