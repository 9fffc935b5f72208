//! The problem document: what a caller sends to `POST /solve`, the CLI reads
//! from a file and the Python client builds.
//!
//! Every field is optional and defaults to the seed scenario of the paper, so
//! `{}` is a complete problem. Unknown fields are rejected rather than
//! ignored, so a typo (`"horizn"`) is an error and not a silent default.
//!
//! Room to grow without breaking requests: `model.type` and `integrator` are
//! tagged enums with one variant today, and new obstacle shapes, constraints
//! and warm starts arrive as new optional fields.
//!
//! [`ProblemSpec::validate`] checks every value before anything is solved and
//! reports *all* problems at once, each with the JSON pointer of its field.

use std::borrow::Cow;
use std::fmt;
use std::time::Duration;

use serde::de::Visitor;
use serde::{Deserialize, Deserializer, Serialize};
use utoipa::ToSchema;

use crate::schema;

/// Largest accepted horizon unless the service is configured otherwise.
pub const DEFAULT_MAX_HORIZON: usize = 10_000;
/// Horizon of the default (seed) problem, which `{}` asks for.
pub const DEFAULT_HORIZON: usize = 100;
/// Largest accepted `solver.max_iterations`.
pub const MAX_ITERATIONS: usize = 10_000;
/// Largest accepted number of obstacles.
pub const MAX_OBSTACLES: usize = 100;
/// Largest magnitude of a state component (initial and goal state, obstacle
/// centres): m, rad, m/s or rad/s. With this bound, mass ≥ [`MIN_PARAMETER`]
/// and thrusts ≤ [`MAX_CONTROL`], no rollout of up to 10000 steps can
/// overflow an f64, so every valid problem has a finite initial cost.
pub const MAX_STATE: f64 = 1e6;
/// Largest magnitude of an initial-guess thrust, N. Far above any thrust a
/// valid problem needs (hover at the largest mass and gravity is 5e9 N), so
/// a result's `controls` can be posted back as `initial_controls`: at 1e6 a
/// start 1e6 m from the goal, or a 3e5 kg vehicle, returned thrusts the
/// service then refused. A result can still pass it where a problem asks
/// for such thrusts (near-zero control weights with a tiny `dt`: R = 1e-24
/// at `dt` 1e-4 gave 3e13 N). Even at 1e12 N on the lightest vehicle, the
/// rollout's largest terms stay below 1e90.
pub const MAX_CONTROL: f64 = 1e12;
/// Largest cost weight.
pub const MAX_WEIGHT: f64 = 1e12;
/// Smallest mass (kg), inertia (kg·m²) and arm length (m).
pub const MIN_PARAMETER: f64 = 1e-6;
/// Largest mass, inertia and arm length.
pub const MAX_PARAMETER: f64 = 1e6;
/// Largest gravitational acceleration, m/s².
pub const MAX_GRAVITY: f64 = 1e4;
/// Largest time step, s.
pub const MAX_DT: f64 = 10.0;

/// A trajectory-optimisation problem for the planar quadrotor.
///
/// Minimise `Σ_k [(x_k − x_goal)ᵀQ(x_k − x_goal) + u_kᵀRu_k + Σ_j q_j·exp(−‖p_k − c_j‖)]`
/// plus `(x_N − x_goal)ᵀQ_f(x_N − x_goal)`, subject to the Euler-discretised
/// dynamics, from `initial_state`. All fields are optional; the defaults are
/// the seed scenario.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(default, deny_unknown_fields)]
#[schema(example = json!(ProblemSpec::default()))]
pub struct ProblemSpec {
    /// The dynamics model and its physical parameters.
    #[serde(deserialize_with = "de_object")]
    #[schema(schema_with = schema::model)]
    pub model: ModelSpec,
    /// How the continuous dynamics are discretised.
    #[serde(deserialize_with = "de_name")]
    pub integrator: Integrator,
    /// Time step in seconds, at most 10. Default 0.05.
    #[schema(default = 0.05, exclusive_minimum = 0.0, maximum = 10.0)]
    pub dt: f64,
    /// Number of control steps N (the trajectory has N + 1 states). Default
    /// 100; at most 10000 (the service may be configured lower).
    #[serde(deserialize_with = "de_horizon")]
    #[schema(default = 100, minimum = 1, maximum = 10000)]
    pub horizon: usize,
    /// Initial state `[x, y, θ, ẋ, ẏ, θ̇]` in m, m, rad, m/s, m/s, rad/s.
    /// Default `[5, 0, 0, 0, 0, 0]`. θ is not taken modulo 2π: the cost
    /// compares it with the goal's as a number, so give it within π of the
    /// goal's θ (2π would be flown as a full turn back).
    #[schema(schema_with = schema::initial_state)]
    pub initial_state: [f64; 6],
    /// Target state, same units. Default `[4, 9, 0, 0, 0, 0]`: the initial
    /// state reflected through the default obstacle.
    #[schema(schema_with = schema::goal_state)]
    pub goal_state: [f64; 6],
    /// Diagonal cost weights.
    #[serde(deserialize_with = "de_object")]
    #[schema(schema_with = schema::weights)]
    pub weights: Weights,
    /// Soft obstacles. Default: one at (4.5, 4.5) with weight 1000.
    #[serde(deserialize_with = "de_objects")]
    #[schema(max_items = 100)]
    pub obstacles: Vec<Obstacle>,
    /// Initial guess for the controls: N rows of `[u1, u2]` in N. Default:
    /// hover thrust `m·g/2` on both rotors.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(schema_with = schema::initial_controls)]
    pub initial_controls: Option<Vec<[f64; 2]>>,
    /// Termination settings.
    #[serde(deserialize_with = "de_object")]
    #[schema(schema_with = schema::solver)]
    pub solver: SolverSpec,
    /// Which optional parts of the result to return.
    #[serde(deserialize_with = "de_object")]
    #[schema(schema_with = schema::output)]
    pub output: OutputSpec,
}

/// Dynamics model. Only the planar quadrotor exists today.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(default, deny_unknown_fields)]
pub struct ModelSpec {
    /// Model kind. `quadrotor_2d` (the only one today) is the paper's
    /// planar quadrotor: `x` right, `y` up, θ counter-clockwise from
    /// upright, `u1` the rotor at `+r` along the body's x axis, and
    /// `m·ẍ = −(u1 + u2)·sin θ`, `m·ÿ = (u1 + u2)·cos θ − m·g`,
    /// `I·θ̈ = r·(u1 − u2)`.
    #[serde(rename = "type", deserialize_with = "de_name")]
    pub kind: ModelKind,
    /// Mass m in kg, from 1e-6 to 1e6. Default 1.
    #[schema(default = 1.0, minimum = 1e-6, maximum = 1e6)]
    pub mass: f64,
    /// Moment of inertia I in kg·m², from 1e-6 to 1e6. Default 1.
    #[schema(default = 1.0, minimum = 1e-6, maximum = 1e6)]
    pub inertia: f64,
    /// Distance r from the centre to each rotor in m, from 1e-6 to 1e6.
    /// Default 1.
    #[schema(default = 1.0, minimum = 1e-6, maximum = 1e6)]
    pub arm_length: f64,
    /// Gravitational acceleration g in m/s², from 0 to 1e4. Default 9.81.
    #[schema(default = 9.81, minimum = 0.0, maximum = 1e4)]
    pub gravity: f64,
}

/// Model kinds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum ModelKind {
    /// The planar quadrotor of the paper (eqs. 4–6). State `[x, y, θ, ẋ,
    /// ẏ, θ̇]`, controls `[u1, u2]` (rotor thrusts, N); `x` right, `y` up, θ
    /// counter-clockwise from upright, `u1` the rotor at `+r` along the
    /// body's x axis: `m·ẍ = −(u1 + u2)·sin θ`, `m·ÿ = (u1 + u2)·cos θ − m·g`,
    /// `I·θ̈ = r·(u1 − u2)`.
    #[default]
    #[serde(rename = "quadrotor_2d")]
    Quadrotor2d,
}

/// Discretisation of the continuous dynamics.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Integrator {
    /// Explicit Euler, `x_{k+1} = x_k + dt·f(x_k, u_k)`.
    #[default]
    Euler,
}

/// Which model of the dynamics the backward pass uses.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// The paper's iLQR: the dynamics linearised (eqs. 33–35), their second
    /// derivatives dropped.
    #[default]
    Ilqr,
    /// DDP: the dynamics' second derivatives kept, weighted by the value
    /// gradient. Converges in a few steps where iLQR crawls (optima with
    /// large costates: the seed with R = 90·I took 483 iLQR iterations
    /// and 7 DDP ones), and may reach another local optimum (the seed:
    /// 5418.30 against iLQR's 5520.21).
    Ddp,
}

/// Diagonal weights of the quadratic cost terms (no ½ factors).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(default, deny_unknown_fields)]
pub struct Weights {
    /// Diagonal of Q, the stage state weight. Default all 1.
    #[schema(schema_with = schema::state_weights)]
    pub state: [f64; 6],
    /// Diagonal of R, the control weight. Default `[0.1, 0.1]`.
    #[schema(schema_with = schema::control_weights)]
    pub control: [f64; 2],
    /// Diagonal of Q_f, the terminal state weight. Default all 50000.
    #[schema(schema_with = schema::terminal_weights)]
    pub terminal: [f64; 6],
}

/// A soft obstacle: adds `weight·exp(−‖p − center‖)` to every stage cost,
/// where p is the quadrotor's position.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Obstacle {
    /// Centre `[x, y]` in m.
    #[schema(schema_with = schema::obstacle_center)]
    pub center: [f64; 2],
    /// Weight q (cost units, from 0 to 1e12). Default 1000, the seed
    /// obstacle's. The centre has no default: an obstacle is where it is.
    #[serde(default = "default_obstacle_weight")]
    #[schema(default = 1000.0, minimum = 0.0, maximum = 1e12)]
    pub weight: f64,
}

/// The seed obstacle's weight, also what an obstacle without one gets.
const SEED_OBSTACLE_WEIGHT: f64 = 1000.0;

fn default_obstacle_weight() -> f64 {
    SEED_OBSTACLE_WEIGHT
}

/// When to stop.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(default, deny_unknown_fields)]
pub struct SolverSpec {
    /// Iteration limit, at most 10000. Default 500: the seed converges in
    /// 16, problems with several obstacles can take a few hundred, and the
    /// time budget bounds the cost of a generous limit.
    #[serde(deserialize_with = "de_iterations")]
    #[schema(default = 500, minimum = 0, maximum = 10000)]
    pub max_iterations: usize,
    /// Relative cost change below which the solve has converged (when the
    /// model about the result predicts no more either). Default 1e-9. With
    /// 0 the solve runs until no step helps (`no_progress`),
    /// `max_iterations` or the time budget.
    #[schema(default = 1e-9, minimum = 0.0, exclusive_maximum = 1.0)]
    pub tolerance: f64,
    /// Wall-clock budget in ms. When it runs out the solve stops with status
    /// `time_limit` and returns the best trajectory so far. The service
    /// counts it from admission, so time spent waiting for a worker is part
    /// of it; a solve still waiting when it runs out is answered then, with
    /// 0 iterations and the initial guess. It is checked every iteration and
    /// every 128 knots inside the linearisation, backward pass and
    /// rollouts: at N = 10000, budgets that
    /// fell after the initial rollout were overrun by a median of 0.00–0.85
    /// ms, with 1 or 100 obstacles (measured). The initial rollout always
    /// completes, since without it there is no trajectory to return: 5–11
    /// ms at N = 10000 with 100 obstacles, under 1 ms with one (measured).
    /// Serialising and compressing the answer come after the budget (about
    /// 9 ms, or 80 ms gzipped, for a whole answer at N = 10000; the
    /// `Server-Timing` header reports it). At most the service's maximum
    /// (60000 unless configured). Unset: the service's default (10000
    /// unless configured; the CLI has none).
    #[serde(deserialize_with = "de_millis")]
    // The service's default maximum (`--max-time-limit-ms`); the served
    // spec puts the configured one here (tests/openapi.rs checks the two
    // agree).
    #[schema(minimum = 1, maximum = 60000)]
    pub time_limit_ms: Option<u64>,
    /// `ilqr` (default: the paper's algorithm) or `ddp` (the dynamics'
    /// second derivatives kept in the backward pass; fewer iterations where
    /// iLQR crawls, see the README's Limits).
    #[serde(deserialize_with = "de_name")]
    #[schema(default = "ilqr")]
    pub method: Method,
}

/// Optional parts of the result. Leaving them out shrinks large responses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(default, deny_unknown_fields)]
pub struct OutputSpec {
    /// Include `gains` (feedback and feedforward). Default true.
    #[schema(default = true)]
    pub gains: bool,
    /// Include the per-iteration `trace`. Default true.
    #[schema(default = true)]
    pub trace: bool,
}

impl Default for ProblemSpec {
    fn default() -> Self {
        Self {
            model: ModelSpec::default(),
            integrator: Integrator::Euler,
            dt: 0.05,
            horizon: DEFAULT_HORIZON,
            initial_state: [5.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            goal_state: [4.0, 9.0, 0.0, 0.0, 0.0, 0.0],
            weights: Weights::default(),
            obstacles: vec![Obstacle {
                center: [4.5, 4.5],
                weight: SEED_OBSTACLE_WEIGHT,
            }],
            initial_controls: None,
            solver: SolverSpec::default(),
            output: OutputSpec::default(),
        }
    }
}

impl Default for ModelSpec {
    fn default() -> Self {
        Self {
            kind: ModelKind::Quadrotor2d,
            mass: 1.0,
            inertia: 1.0,
            arm_length: 1.0,
            gravity: 9.81,
        }
    }
}

impl Default for Weights {
    fn default() -> Self {
        Self {
            state: [1.0; 6],
            control: [0.1; 2],
            terminal: [50000.0; 6],
        }
    }
}

impl Default for SolverSpec {
    fn default() -> Self {
        Self {
            max_iterations: 500,
            tolerance: 1e-9,
            time_limit_ms: None,
            method: Method::Ilqr,
        }
    }
}

impl Default for OutputSpec {
    fn default() -> Self {
        Self {
            gains: true,
            trace: true,
        }
    }
}

/// One invalid value: where it is and what was expected.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct FieldError {
    /// RFC 6901 JSON pointer to the field, e.g. `/weights/state/2`.
    pub pointer: String,
    /// What was wrong and what is expected.
    pub detail: String,
}

/// Limits that depend on who is asking (the CLI accepts more than a shared
/// service might).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Largest horizon accepted.
    pub max_horizon: usize,
    /// Largest `solver.time_limit_ms` accepted, if any.
    pub max_time_limit_ms: Option<u64>,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_horizon: DEFAULT_MAX_HORIZON,
            max_time_limit_ms: None,
        }
    }
}

impl ProblemSpec {
    /// The time budget the problem asks for (`solver.time_limit_ms`), or
    /// `default` when it sets none.
    pub fn time_limit(&self, default: Option<Duration>) -> Option<Duration> {
        self.solver
            .time_limit_ms
            .map(Duration::from_millis)
            .or(default)
    }

    /// Check every value; returns the problems found (the first
    /// [`MAX_REPORTED_ERRORS`] of them, and a count of the rest), or nothing.
    pub fn validate(&self, limits: &Limits) -> Result<(), Invalid> {
        let mut v = Checker::default();
        self.check(limits, &mut v);
        v.finish()
    }

    fn check(&self, limits: &Limits, v: &mut Checker) {
        let m = &self.model;
        let (lo, hi) = (MIN_PARAMETER, MAX_PARAMETER);
        v.range(&"/model/mass", m.mass, lo, hi, "kg");
        v.range(&"/model/inertia", m.inertia, lo, hi, "kg·m²");
        v.range(&"/model/arm_length", m.arm_length, lo, hi, "m");
        v.range(&"/model/gravity", m.gravity, 0.0, MAX_GRAVITY, "m/s²");
        if !(self.dt.is_finite() && self.dt > 0.0 && self.dt <= MAX_DT) {
            v.push(
                "/dt",
                format!(
                    "must be a positive number of seconds, at most {MAX_DT}, got {}",
                    num(self.dt)
                ),
            );
        }
        if self.horizon == 0 || self.horizon > limits.max_horizon {
            v.push(
                "/horizon",
                format!(
                    "must be an integer from 1 to {}, got {}",
                    limits.max_horizon, self.horizon
                ),
            );
        }
        let state = (-MAX_STATE, MAX_STATE);
        v.range_all(&"/initial_state", &self.initial_state, state, "state units");
        v.range_all(&"/goal_state", &self.goal_state, state, "state units");
        let weight = (0.0, MAX_WEIGHT);
        v.range_all(&"/weights/state", &self.weights.state, weight, "weight");
        v.range_all(&"/weights/control", &self.weights.control, weight, "weight");
        v.range_all(
            &"/weights/terminal",
            &self.weights.terminal,
            weight,
            "weight",
        );
        if self.obstacles.len() > MAX_OBSTACLES {
            v.push(
                "/obstacles",
                format!(
                    "at most {MAX_OBSTACLES} obstacles, got {}",
                    self.obstacles.len()
                ),
            );
        }
        for (j, o) in self.obstacles.iter().enumerate() {
            v.range_all(
                &format_args!("/obstacles/{j}/center"),
                &o.center,
                state,
                "m",
            );
            let (lo, hi) = weight;
            v.range(
                &format_args!("/obstacles/{j}/weight"),
                o.weight,
                lo,
                hi,
                "cost units",
            );
        }
        if let Some(us) = &self.initial_controls {
            // Only against a valid horizon: one taken out as a wrong shape
            // reads as the default, not what was sent, and matching one
            // out of range (0, 20000) would not make the problem valid.
            let horizon_valid = (1..=limits.max_horizon).contains(&self.horizon);
            if us.len() != self.horizon && horizon_valid && !v.skips("/horizon") {
                v.push(
                    "/initial_controls",
                    format!(
                        "must have one [u1, u2] row per step: expected {} rows (the horizon), got {}",
                        self.horizon,
                        us.len()
                    ),
                );
            }
            for (k, u) in us.iter().enumerate() {
                v.range_all(
                    &format_args!("/initial_controls/{k}"),
                    u,
                    (-MAX_CONTROL, MAX_CONTROL),
                    "N",
                );
            }
        }
        let s = &self.solver;
        if s.max_iterations > MAX_ITERATIONS {
            v.push(
                "/solver/max_iterations",
                format!("must be at most {MAX_ITERATIONS}, got {}", s.max_iterations),
            );
        }
        if !(s.tolerance.is_finite() && (0.0..1.0).contains(&s.tolerance)) {
            v.push(
                "/solver/tolerance",
                format!(
                    "must be a number in [0, 1) (relative cost change), got {}",
                    num(s.tolerance)
                ),
            );
        }
        if let Some(t) = s.time_limit_ms
            && (t == 0 || limits.max_time_limit_ms.is_some_and(|max| t > max))
        {
            let range = match limits.max_time_limit_ms {
                Some(max) => format!("an integer from 1 to {max}"),
                None => "a positive integer".to_owned(),
            };
            v.push(
                "/solver/time_limit_ms",
                format!("must be {range} (ms), got {t}"),
            );
        }
    }
}

/// At most this many field errors are listed; [`Invalid::unlisted`] counts
/// the rest. A 4 MiB body of bad control rows would otherwise produce
/// ~760 000 errors, an 80 MB answer built on the async runtime.
pub const MAX_REPORTED_ERRORS: usize = 100;

/// The listed errors' pointers and messages hold at most this many bytes
/// together, the first error apart (always listed; its pointer is at most
/// the body's size); the rest are counted in [`Invalid::unlisted`]. A key
/// of a megabyte is in the pointer of every error under it: with a hundred
/// of them, a 4 MiB body made a 400 MB answer.
pub const MAX_REPORTED_BYTES: usize = 64 * 1024;

/// Why a problem was rejected: its invalid values, listed up to a cap.
///
/// The count of the rest is kept apart from the list (it used to be one
/// more entry with pointer `""`), so that every entry of `errors` names a
/// field a client can point at.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Invalid {
    /// The first [`MAX_REPORTED_ERRORS`] invalid values: keys given twice
    /// first, then wrong shapes (object keys in alphabetical order, see
    /// [`parse`]), then out-of-range values in schema order.
    pub errors: Vec<FieldError>,
    /// How many more invalid values were found than `errors` lists (past
    /// [`MAX_REPORTED_ERRORS`] of them, or [`MAX_REPORTED_BYTES`]).
    pub unlisted: usize,
    /// The document was not checked to its end: [`parse`]'s budget for
    /// reading it again after wrong shapes ran out (or it took out an
    /// array unchecked to stay within it), so values it did not reach may
    /// be invalid too, uncounted.
    pub incomplete: bool,
}

impl From<FieldError> for Invalid {
    fn from(error: FieldError) -> Self {
        Self {
            errors: vec![error],
            unlisted: 0,
            incomplete: false,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Default)]
struct Checker {
    found: Invalid,
    /// Members taken out of the document as wrong shapes, and values stood
    /// in for: no error is reported at or under them (they hold defaults
    /// or stand-ins now).
    skip: Vec<String>,
    /// Keys given twice, already reported: no second error at exactly
    /// these pointers (the values under them are checked as usual). Only
    /// those listed in `found.errors`, so at most [`MAX_REPORTED_ERRORS`]
    /// of them and [`MAX_REPORTED_BYTES`] past the first: the memory stays
    /// small and a lookup cheap on a hostile document. Repeats past those
    /// are only counted (and another error at exactly such a pointer is
    /// counted too: a count past the list can be one high per repeat).
    repeated: Vec<String>,
    /// Bytes of pointers and messages in `found.errors`.
    listed_bytes: usize,
}

impl Checker {
    /// A key given twice in its object. The scan calls this once per key
    /// and object however often the key repeats, and before anything is
    /// taken out (so nothing is skipped yet).
    fn repeat(&mut self, pointer: &str) {
        // While errors are still listed, once per pointer too (a repeated
        // parent key holds two objects with the same pointers). Past the
        // list only counted, without comparing: under a megabyte key each
        // comparison reads the megabyte, and 150 000 repeated keys under
        // one took 5.7 s of parsing.
        if self.listing_open() && self.repeated.iter().any(|r| r == pointer) {
            return;
        }
        let listed = self.record(
            pointer,
            "this key appears more than once in its object; give it once".into(),
        );
        if listed {
            self.repeated.push(pointer.to_owned());
        }
    }

    /// Whether another error may still be listed (not only counted). Once
    /// one is only counted, so are the rest: `errors` stays the first ones
    /// found.
    fn listing_open(&self) -> bool {
        self.found.unlisted == 0 && self.found.errors.len() < MAX_REPORTED_ERRORS
    }

    /// Whether `pointer` is at or under a taken-out member.
    fn skips(&self, pointer: &str) -> bool {
        self.skip.iter().any(|r| is_at_or_under(pointer, r))
    }

    /// An error, unless it is under a taken-out member or at a repeated
    /// key's pointer (already reported).
    fn push(&mut self, pointer: &str, detail: String) {
        if !(self.skips(pointer) || self.repeated.iter().any(|r| r == pointer)) {
            self.record(pointer, detail);
        }
    }

    /// List the error, or only count it; whether it was listed.
    fn record(&mut self, pointer: &str, detail: String) -> bool {
        let bytes = pointer.len() + detail.len();
        let listed = self.found.errors.is_empty()
            || (self.listing_open() && self.listed_bytes + bytes <= MAX_REPORTED_BYTES);
        if listed {
            self.found.errors.push(FieldError {
                pointer: pointer.to_owned(),
                detail,
            });
            self.listed_bytes += bytes;
        } else {
            self.found.unlisted += 1;
        }
        listed
    }

    /// `lo ≤ x ≤ hi`, and finite. The pointer is a `Display` (a literal or
    /// `format_args!`) written out only for a bad value, so that checking a
    /// valid 10 000-row `initial_controls` allocates nothing.
    fn range(&mut self, pointer: &dyn fmt::Display, x: f64, lo: f64, hi: f64, unit: &str) {
        if !(x.is_finite() && (lo..=hi).contains(&x)) {
            self.push(
                &pointer.to_string(),
                format!(
                    "must be a number from {} to {} ({unit}), got {}",
                    num(lo),
                    num(hi),
                    num(x)
                ),
            );
        }
    }

    fn range_all(
        &mut self,
        pointer: &dyn fmt::Display,
        xs: &[f64],
        (lo, hi): (f64, f64),
        unit: &str,
    ) {
        for (i, x) in xs.iter().enumerate() {
            self.range(&format_args!("{pointer}/{i}"), *x, lo, hi, unit);
        }
    }

    fn finish(self) -> Result<(), Invalid> {
        if self.found.errors.is_empty() {
            Ok(())
        } else {
            Err(self.found)
        }
    }
}

/// Accept a count written as an integer or as an integral float (`100.0`):
/// JSON Schema calls both integers, and clients that build JSON from floats
/// should not get a type error for it. Anything else is an error that says
/// which integers the field takes (`"x"`, `-3`, `2.5`); the range check
/// itself is [`ProblemSpec::validate`]'s, against the configured limits.
fn de_horizon<'de, D: Deserializer<'de>>(d: D) -> Result<usize, D::Error> {
    de_count(d, HORIZON_EXPECTED)
}

fn de_iterations<'de, D: Deserializer<'de>>(d: D) -> Result<usize, D::Error> {
    de_count(d, ITERATIONS_EXPECTED)
}

fn de_millis<'de, D: Deserializer<'de>>(d: D) -> Result<Option<u64>, D::Error> {
    d.deserialize_option(OptCount(Count(MILLIS_EXPECTED)))
}

const HORIZON_EXPECTED: &str =
    "an integer from 1 to the maximum horizon (10000 unless configured lower)";
const ITERATIONS_EXPECTED: &str = "an integer from 0 to 10000";
const MILLIS_EXPECTED: &str =
    "a positive integer (ms; a service takes at most 60000 unless configured), or null";

/// What the count field at `pointer` takes, if it is one. Without
/// `limits`, in general: what a type error says while reading, before the
/// limits are known (and a number too large for f64 there gets the field's
/// own expectation, not the float one). With them, the configured range,
/// as the range check says it.
fn count_expected(pointer: &str, limits: Option<&Limits>) -> Option<Cow<'static, str>> {
    match (pointer, limits) {
        ("/horizon", None) => Some(HORIZON_EXPECTED.into()),
        ("/horizon", Some(l)) => Some(format!("an integer from 1 to {}", l.max_horizon).into()),
        ("/solver/max_iterations", _) => Some(ITERATIONS_EXPECTED.into()),
        (
            "/solver/time_limit_ms",
            Some(Limits {
                max_time_limit_ms: Some(max),
                ..
            }),
        ) => Some(format!("an integer from 1 to {max} (ms), or null").into()),
        ("/solver/time_limit_ms", _) => Some(MILLIS_EXPECTED.into()),
        _ => None,
    }
}

fn de_count<'de, D: Deserializer<'de>>(d: D, expected: &'static str) -> Result<usize, D::Error> {
    let n = d.deserialize_any(Count(expected))?;
    usize::try_from(n).map_err(|_| {
        serde::de::Error::invalid_value(serde::de::Unexpected::Unsigned(n), &Count(expected))
    })
}

/// A non-negative integer, written as `7` or `7.0`; the string says which
/// integers the field takes, for the error message.
#[derive(Clone, Copy)]
struct Count(&'static str);

impl<'de> Visitor<'de> for Count {
    type Value = u64;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(self.0)
    }

    fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<u64, E> {
        Ok(v)
    }

    fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<u64, E> {
        u64::try_from(v).map_err(|_| E::invalid_value(serde::de::Unexpected::Signed(v), &self))
    }

    fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<u64, E> {
        // 2^53: beyond it f64 no longer holds every integer.
        const MAX_EXACT: f64 = 9_007_199_254_740_992.0;
        if v >= 0.0 && v.fract() == 0.0 && v <= MAX_EXACT {
            Ok(v as u64)
        } else if v > MAX_EXACT {
            Err(E::custom(format_args!(
                "{} is too large: expected {}",
                num(v),
                self.0
            )))
        } else {
            // serde's own message, with the number written as every other
            // message writes it (serde wrote -1e30 as `-1e+30`).
            Err(E::custom(format_args!(
                "invalid value: number {}, expected {}",
                num(v),
                self.0
            )))
        }
    }
}

/// [`Count`] or `null`.
struct OptCount(Count);

impl<'de> Visitor<'de> for OptCount {
    type Value = Option<u64>;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(self.0.0)
    }

    fn visit_none<E: serde::de::Error>(self) -> Result<Self::Value, E> {
        Ok(None)
    }

    fn visit_unit<E: serde::de::Error>(self) -> Result<Self::Value, E> {
        Ok(None)
    }

    fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<Self::Value, D::Error> {
        d.deserialize_any(self.0).map(Some)
    }
}

/// A nested struct (`model`, `weights`, `solver`, `output`) must be a JSON
/// object, or null for its defaults. serde's derive also takes an array,
/// filling the fields in order: `{"solver": [5]}` would silently set
/// `max_iterations`. This reads the struct through [`ObjectOnly`], which
/// asks for a map, so an array is an error that says an object was
/// expected, and the error path still reaches into the fields.
///
/// Null is the same as leaving the member out because clients generated
/// from the OpenAPI document send it: datamodel-code-generator's pydantic
/// models type these members `X | None = None`, and a plain
/// `model_dump_json()` writes `"model": null`.
fn de_object<'de, D, T>(d: D) -> Result<T, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de> + Default,
{
    struct ObjectOrNull<T>(std::marker::PhantomData<T>);

    impl<'de, T: Deserialize<'de> + Default> Visitor<'de> for ObjectOrNull<T> {
        type Value = T;

        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            f.write_str(OBJECT_OR_NULL)
        }

        fn visit_none<E: serde::de::Error>(self) -> Result<T, E> {
            Ok(T::default())
        }

        fn visit_unit<E: serde::de::Error>(self) -> Result<T, E> {
            Ok(T::default())
        }

        fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<T, D::Error> {
            T::deserialize(ObjectOnly {
                inner: d,
                expected: OBJECT_OR_NULL,
            })
        }
    }

    d.deserialize_option(ObjectOrNull(std::marker::PhantomData))
}

/// What [`de_object`]'s members take, for error messages.
const OBJECT_OR_NULL: &str = "a JSON object, or null for the defaults";

/// An array of nested structs, each a JSON object (see [`de_object`]).
fn de_objects<'de, D, T>(d: D) -> Result<Vec<T>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    struct Objects<T>(std::marker::PhantomData<T>);

    impl<'de, T: Deserialize<'de>> Visitor<'de> for Objects<T> {
        type Value = Vec<T>;

        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            f.write_str("an array of JSON objects")
        }

        fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Vec<T>, A::Error> {
            // No size hint: the body limit bounds the length, and the
            // validator caps it.
            let mut out = Vec::new();
            while let Some(x) = seq.next_element_seed(ObjectSeed(std::marker::PhantomData))? {
                out.push(x);
            }
            Ok(out)
        }
    }

    struct ObjectSeed<T>(std::marker::PhantomData<T>);

    impl<'de, T: Deserialize<'de>> serde::de::DeserializeSeed<'de> for ObjectSeed<T> {
        type Value = T;

        fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<T, D::Error> {
            // Not de_object: an obstacle has no default, so null is an error.
            T::deserialize(ObjectOnly {
                inner: d,
                expected: "a JSON object",
            })
        }
    }

    d.deserialize_seq(Objects(std::marker::PhantomData))
}

/// A deserializer that gives struct visitors only maps; anything else is
/// an error that says it `expected` this.
struct ObjectOnly<D> {
    inner: D,
    expected: &'static str,
}

impl<'de, D: Deserializer<'de>> Deserializer<'de> for ObjectOnly<D> {
    type Error = D::Error;

    fn deserialize_any<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, D::Error> {
        self.inner.deserialize_map(ObjectVisitor {
            inner: visitor,
            expected: self.expected,
        })
    }

    serde::forward_to_deserialize_any! {
        bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string
        bytes byte_buf option unit unit_struct newtype_struct seq tuple
        tuple_struct map struct enum identifier ignored_any
    }
}

/// Passes a map on to the struct's own visitor; anything else is an error
/// that says what was expected ("a JSON object") rather than a Rust type
/// name.
struct ObjectVisitor<V> {
    inner: V,
    expected: &'static str,
}

impl<'de, V: Visitor<'de>> Visitor<'de> for ObjectVisitor<V> {
    type Value = V::Value;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(self.expected)
    }

    fn visit_map<A: serde::de::MapAccess<'de>>(self, map: A) -> Result<V::Value, A::Error> {
        self.inner.visit_map(map)
    }
}

/// A name from a fixed set (`"euler"`, `"quadrotor_2d"`) must be a JSON
/// string. serde on its own also takes `{"euler": null}` for a unit variant,
/// which the schema does not allow.
fn de_name<'de, D, T>(d: D) -> Result<T, D::Error>
where
    D: Deserializer<'de>,
    T: serde::de::DeserializeOwned,
{
    use serde::de::IntoDeserializer;
    let name = String::deserialize(d)?;
    T::deserialize(name.as_str().into_deserializer())
}

/// Why a request body is not a problem document.
#[derive(Debug, Clone, PartialEq)]
pub enum ParseError {
    /// Not JSON at all (HTTP 400).
    Syntax(String),
    /// JSON of the wrong shape: a wrong type or length, an unknown field
    /// (HTTP 422). Lists the offending fields by pointer; call
    /// [`Shapes::with_range_errors`] to add the out-of-range values among
    /// the rest.
    Shape(Box<Shapes>),
}

/// The wrong-shaped values of a document, and what is left of it once they
/// are taken out.
#[derive(Debug, Clone, PartialEq)]
pub struct Shapes {
    /// The keys given twice, then the wrong shapes (object keys in
    /// alphabetical order); the members taken out and the repeated keys,
    /// so that the range checks of the rest say nothing more about them.
    checker: Checker,
    /// The document read without them (each taken-out member reads as its
    /// default), or `None` when that was not possible: the root is not an
    /// object, or the retry budget ran out (see [`parse`]).
    rest: Option<ProblemSpec>,
}

impl Shapes {
    fn one(error: FieldError) -> Box<Self> {
        Box::new(Self {
            checker: Checker {
                found: error.into(),
                ..Checker::default()
            },
            rest: None,
        })
    }

    /// The first wrong shape (there is always one).
    pub fn first(&self) -> &FieldError {
        &self.checker.found.errors[0]
    }

    /// The wrong shapes, then the out-of-range values among the rest of the
    /// document: every invalid value up to [`MAX_REPORTED_ERRORS`], so a
    /// caller can fix them in one go. A check about a taken-out value is
    /// skipped (it reads as its default, which says nothing about what was
    /// sent): a bad `horizon` does not also make `initial_controls` "the
    /// wrong number of rows for a horizon of 100".
    pub fn with_range_errors(self, limits: &Limits) -> Invalid {
        let Self { mut checker, rest } = self;
        // A count's type error was written without the limits; say the
        // configured ones, as the range check would.
        for e in &mut checker.found.errors {
            if let (Some(generic), Some(configured)) = (
                count_expected(&e.pointer, None),
                count_expected(&e.pointer, Some(limits)),
            ) {
                e.detail = e.detail.replace(&*generic, &configured);
            }
        }
        if let Some(rest) = rest {
            rest.check(limits, &mut checker);
        }
        checker.found
    }
}

/// Parse a problem document, locating shape errors with a JSON pointer.
///
/// Two stages, so the two kinds of failure stay apart: the bytes must be one
/// JSON value (else [`ParseError::Syntax`]), and that value must be an object
/// of the right shape (else [`ParseError::Shape`]). A key given twice in one
/// object is a shape error at its pointer: JSON leaves its meaning open, and
/// a `serde_json::Value` would silently keep the last.
///
/// Every wrong shape is listed, not just the first: after each one the
/// document is read again without it. Inside one of the problem's arrays
/// a valid stand-in takes its place (`stand_in`), so the array's
/// other elements are still checked; anywhere else the member holding it
/// (its nearest enclosing object member) is taken out and reads as its
/// default. Each
/// read covers the whole document, so their number is bounded by
/// [`MAX_REPORTED_ERRORS`] and by [`RETRY_BYTES`]: a document of up to
/// 10 KiB gets 100 reads, one of 100 KiB 10, one over 1 MiB a single
/// read. When they run out with wrong shapes left, or the fix before the
/// last read took out an array a stand-in would have kept, the list is
/// marked [`Invalid::incomplete`].
///
/// A leading UTF-8 byte order mark is skipped.
///
/// Valid JSON that cannot be read into a value is a shape error at the
/// pointer where reading stopped, as the issue asks for NaN: a number beyond
/// the range of f64 (`1e999`, JSON's nearest to Infinity), a string with an
/// unpaired surrogate escape (`"\ud800"`), and nesting 128 levels deep or
/// more (serde_json's limit). So is a bare `NaN` or `Infinity` (not JSON,
/// but what Python's `json.dumps` writes). The document is then checked
/// again for UTF-8 and grammar (with those tokens masked), so that a syntax
/// error anywhere still wins. Such a document is not read further: it
/// reports that one value.
pub fn parse(bytes: &[u8]) -> Result<ProblemSpec, ParseError> {
    // RFC 8259 §8.1 lets a parser ignore a leading byte order mark, and
    // Windows tools often write one; anywhere else it is not JSON.
    const BOM: &[u8] = b"\xEF\xBB\xBF";
    let (bytes, skipped) = match bytes.strip_prefix(BOM) {
        Some(rest) => (rest, BOM.len()),
        None => (bytes, 0),
    };
    // Repeated keys are reported while reading; the value kept is the last
    // one given, checked like any other.
    let mut shapes = Checker::default();
    let mut path = String::new();
    let mut objects = 0;
    let mut json = serde_json::Deserializer::from_slice(bytes);
    let mut value = serde::de::DeserializeSeed::deserialize(
        ValueNoting {
            path: &mut path,
            checker: &mut shapes,
            objects: &mut objects,
        },
        &mut json,
    )
    .and_then(|value| json.end().map(|()| value))
    .map_err(|e| unreadable(bytes, skipped, &path, e))?;
    let reads = (RETRY_BYTES / bytes.len().max(1)).clamp(1, MAX_REPORTED_ERRORS);
    let mut incomplete = true;
    // An array taken out where a stand-in would have gone (see below).
    let mut cut_short = false;
    for read in 0..reads {
        // Through `ObjectOnly` like every nested struct: serde alone would
        // take an array for the document too.
        let error = match serde_path_to_error::deserialize::<_, ProblemSpec>(ObjectOnly {
            inner: &value,
            expected: "a JSON object",
        }) {
            Ok(spec) if shapes.found.errors.is_empty() => return Ok(spec),
            Ok(spec) => {
                shapes.found.incomplete = cut_short;
                return Err(ParseError::Shape(Box::new(Shapes {
                    checker: shapes,
                    rest: Some(spec),
                })));
            }
            Err(e) => shape_error(e),
        };
        // Under a member taken out or stood in for before: a required
        // member taken out and now missing, or a stand-in that does not
        // fit (neither happens with today's schema, whose one required
        // member, an obstacle's `center`, is stood in for). Take out, or
        // stand in for, the value above it instead, without a second error.
        let from = match shapes
            .skip
            .iter()
            .find(|r| is_at_or_under(&error.pointer, r))
        {
            Some(r) => parent(r).to_owned(),
            None => {
                shapes.push(&error.pointer, error.detail);
                error.pointer
            }
        };
        // A stand-in fixes one element per read, taking out the array all
        // of them: so the fix before the last read takes out, and that
        // read can still check the rest's ranges (a large document with
        // many bad rows has few reads; standing in to the end, it had its
        // range errors elsewhere unreported). The array's other elements
        // are then unchecked, and the list says so.
        if read + 2 < reads {
            if stand_in(&mut value, &from) {
                shapes.skip.push(from);
                continue;
            }
        } else if stand_in_for(&from).is_some() {
            cut_short = true;
        }
        match take_out(&mut value, &from) {
            Some(member) => shapes.skip.push(member),
            // The root itself is wrong: there is nothing else to check.
            None => {
                incomplete = false;
                break;
            }
        }
    }
    shapes.found.incomplete = incomplete;
    Err(ParseError::Shape(Box::new(Shapes {
        checker: shapes,
        rest: None,
    })))
}

/// How many document bytes [`parse`] may read, in all, as a typed problem
/// (each read after a wrong shape reads the whole document again). It runs
/// on the async runtime: 1 MiB is about 5 ms there, so a hostile body
/// costs at most that much more than the parse it needs anyway (tens of ms
/// for a 4 MiB body).
pub const RETRY_BYTES: usize = 1 << 20;

/// Most JSON objects a document may hold; reading stops at the next one.
/// A problem holds at most 105 (the document, `model`, `weights`,
/// `solver`, `output` and one per obstacle), so this leaves ten times that
/// for shapes to come. Why a bound at all: `serde_json::Value` stores an
/// object as a B-tree whose first node takes about 650 bytes whatever it
/// holds, so a 4 MB body of `{"a":1}` built 363 MiB (90 times its text,
/// against at most about 25 times for arrays, strings and numbers), and
/// the allocator kept most of it after the answer.
pub const MAX_OBJECTS: usize = 1024;

/// The start of the serde error [`ValueNoting`] raises past
/// [`MAX_OBJECTS`], recognised by [`unreadable`].
const TOO_MANY_OBJECTS: &str = "too many JSON objects";

/// A serde error, as a field error with its pointer and a detail in the
/// schema's words rather than Rust's.
fn shape_error(e: serde_path_to_error::Error<serde_json::Error>) -> FieldError {
    let mut pointer = pointer_of(e.path());
    let mut detail = json_words(e.into_inner().to_string());
    // serde names the Rust type of a plain number field.
    if let Some(head) = detail.strip_suffix("expected f64") {
        detail = format!("{head}expected a number");
    }
    // A too-long fixed-size array: serde_json's `Value` does not say how
    // long it should be (a too-short one does: "an array of length 6").
    if let Some(head) = detail.strip_suffix("expected fewer elements in array")
        && let Some(len) = fixed_length(&pointer)
    {
        detail = format!("{head}expected an array of length {len}");
    }
    // serde places a missing field at its parent object; point at the
    // field itself, which is what the caller has to add.
    if let Some(field) = detail
        .strip_prefix("missing field `")
        .and_then(|rest| rest.strip_suffix('`'))
    {
        pointer = format!("{pointer}/{}", escape_token(field));
        detail = "this field is required".into();
    }
    // serde quotes the offending key or string whole: a 1 MB key would
    // make a 1 MB message, written again in the answer's `detail`.
    let detail = elide(detail);
    FieldError { pointer, detail }
}

/// serde's message in JSON's words: serde names the data model's kinds
/// ("invalid type: sequence, expected a map"), which a client that sent
/// an array where an object belongs has to translate. Only the kind that
/// opens the message and the expectation that closes it are rewritten, so
/// a quoted key or string that happens to hold such a word is left alone.
fn json_words(detail: String) -> String {
    const OPENINGS: [&str; 2] = ["invalid type: ", "invalid value: "];
    // serde's `Unexpected` kinds and how JSON names them; a number or a
    // boolean comes with its value in backquotes, which JSON does not use.
    const KINDS: [(&str, &str); 3] = [
        ("sequence,", "array,"),
        ("map,", "object,"),
        ("unit value,", "null,"),
    ];
    const QUOTED: [(&str, &str); 3] = [
        ("integer `", "number "),
        ("floating point `", "number "),
        ("boolean `", ""),
    ];
    const EXPECTED: [(&str, &str); 2] = [
        ("expected a sequence", "expected an array"),
        ("expected a map", "expected an object"),
    ];
    let mut out = detail;
    if let Some(opening) = OPENINGS.iter().find(|o| out.starts_with(**o)) {
        let (head, rest) = out.split_at(opening.len());
        let rest = if let Some((serde, json)) = KINDS.iter().find(|(k, _)| rest.starts_with(k)) {
            Some(format!("{json}{}", &rest[serde.len()..]))
        } else {
            QUOTED.iter().find_map(|(k, json)| {
                let value = rest.strip_prefix(k)?;
                let (value, tail) = value.split_once('`')?;
                Some(format!("{json}{value}{tail}"))
            })
        };
        if let Some(rest) = rest {
            out = format!("{head}{rest}");
        }
    }
    for (serde, json) in EXPECTED {
        if let Some(head) = out.strip_suffix(serde) {
            out = format!("{head}{json}");
        }
    }
    out
}

/// Longest message kept whole; see [`elide`].
const MAX_DETAIL_CHARS: usize = 400;

/// `text` if it has at most [`MAX_DETAIL_CHARS`] characters, else its head
/// and tail around a note of how much was left out. The tail is kept longer
/// because serde ends its messages with what was expected ("..., expected
/// one of `model`, `dt`, ...") after the quoted input.
pub fn elide(text: String) -> String {
    let chars = text.chars().count();
    if chars <= MAX_DETAIL_CHARS {
        return text;
    }
    let (head, tail) = (100, 250);
    let cut = chars - head - tail;
    // Byte offsets of the head's end and the tail's start, in one pass.
    let mut at = text.char_indices().map(|(i, _)| i);
    let start = at.nth(head).unwrap_or(0);
    let end = at.nth(cut - 1).unwrap_or(text.len());
    format!(
        "{} [... {cut} characters left out ...] {}",
        &text[..start],
        &text[end..]
    )
}

/// `text` cut to its first `max_chars` characters, with `...` after a cut:
/// what a one-line message or log line quotes of a client's input.
pub fn clip(text: &str, max_chars: usize) -> std::borrow::Cow<'_, str> {
    match text.char_indices().nth(max_chars) {
        Some((end, _)) => format!("{}...", &text[..end]).into(),
        None => text.into(),
    }
}

/// Take out of `value` the nearest object member at or above `pointer`
/// that exists, and return its pointer; `None` if there is none (the
/// pointer is the root).
fn take_out(value: &mut serde_json::Value, pointer: &str) -> Option<String> {
    let mut at = pointer;
    while !at.is_empty() {
        let up = parent(at);
        let key = unescape_token(&at[up.len() + 1..]);
        if let Some(object) = value.pointer_mut(up).and_then(|v| v.as_object_mut())
            && object.remove(&key).is_some()
        {
            return Some(at.to_owned());
        }
        at = up;
    }
    None
}

/// Puts a valid value in place of the wrong shape at `pointer` when it lies
/// in one of the problem's arrays (a vector's number, an obstacle, its
/// `center` or a number in it, a row of `initial_controls` or a number in
/// it), so that the array's other elements are still read and checked:
/// [`take_out`] would take out the object member above it, the whole
/// array. The stand-ins (0, `[0, 0]`, an obstacle at the origin) are inside
/// every range, and the caller adds `pointer` to the skipped ones, so they
/// are never reported. Whether it did; elsewhere the member is taken out.
fn stand_in(value: &mut serde_json::Value, pointer: &str) -> bool {
    let Some(with) = stand_in_for(pointer) else {
        return false;
    };
    // A wrong value, an element or a member: replaced where it is.
    if let Some(slot) = value.pointer_mut(pointer) {
        *slot = with;
        return true;
    }
    // A missing one, an obstacle's `center`: set in its object. (A missing
    // element is past the array's end, and an array is never grown.)
    let up = parent(pointer);
    match value.pointer_mut(up) {
        Some(serde_json::Value::Object(members)) => {
            members.insert(unescape_token(&pointer[up.len() + 1..]), with);
            true
        }
        _ => false,
    }
}

/// Whether a pointer token is an array index.
fn is_index(token: &str) -> bool {
    !token.is_empty() && token.bytes().all(|b| b.is_ascii_digit())
}

/// The stand-in for the value at `pointer`, if it is in one of the
/// problem's arrays ([`stand_in`]).
fn stand_in_for(pointer: &str) -> Option<serde_json::Value> {
    use serde_json::json;
    let tokens: Vec<&str> = pointer.split('/').skip(1).collect();
    Some(match tokens.as_slice() {
        ["initial_state" | "goal_state", i] | ["weights", "state" | "control" | "terminal", i]
            if is_index(i) =>
        {
            json!(0.0)
        }
        ["obstacles", i, "center", j] | ["initial_controls", i, j]
            if is_index(i) && is_index(j) =>
        {
            json!(0.0)
        }
        ["obstacles", i, "center"] if is_index(i) => json!([0.0, 0.0]),
        ["initial_controls", i] if is_index(i) => json!([0.0, 0.0]),
        ["obstacles", i] if is_index(i) => json!({"center": [0.0, 0.0]}),
        _ => return None,
    })
}

/// The pointer of the value that holds the one at `pointer` (`""` for a
/// top-level member).
fn parent(pointer: &str) -> &str {
    pointer.rfind('/').map_or("", |i| &pointer[..i])
}

/// Whether `pointer` is `root` or lies inside it.
fn is_at_or_under(pointer: &str, root: &str) -> bool {
    pointer
        .strip_prefix(root)
        .is_some_and(|rest| rest.is_empty() || rest.starts_with('/'))
}

/// Why the first stage of [`parse`] failed with `e`, `path` being the
/// pointer it had reached. Only a document that is valid JSON is told apart
/// from a syntax error: UTF-8 (RFC 8259 requires it; skipping does not check
/// it) and the grammar (checked by skipping over the document, which
/// neither converts numbers, nor decodes escapes, nor limits nesting).
fn unreadable(bytes: &[u8], skipped: usize, path: &str, e: serde_json::Error) -> ParseError {
    if let Err(bad) = std::str::from_utf8(bytes) {
        // Counted in the body as sent, byte order mark included.
        return ParseError::Syntax(format!(
            "invalid UTF-8 at byte {}",
            bad.valid_up_to() + skipped
        ));
    }
    // A bare NaN or Infinity is not JSON, but it is what Python's
    // `json.dumps` writes for a float that is one: a bad value at its
    // pointer, if it is the document's only departure from the grammar.
    // Masked with a number of the same length, so a real syntax error
    // elsewhere keeps its line and column.
    let spans = non_finite_spans(bytes);
    let masked = (!spans.is_empty()).then(|| replace_spans(bytes, &spans, b"0"));
    if let Err(syntax) =
        serde_json::from_slice::<serde::de::IgnoredAny>(masked.as_deref().unwrap_or(bytes))
    {
        return ParseError::Syntax(syntax.to_string());
    }
    let message = e.to_string();
    // A document that is not an object is wrong at its root, whatever is
    // inside; say that, as the second stage would.
    let root = bytes.iter().find(|b| !b.is_ascii_whitespace());
    if root != Some(&b'{') {
        let kind = match root {
            Some(b'[') => "array",
            Some(b'"') => "string",
            _ => "number",
        };
        return ParseError::Shape(Shapes::one(FieldError {
            pointer: String::new(),
            detail: format!("invalid type: {kind}, expected a JSON object"),
        }));
    }
    let (pointer, detail) = if message.starts_with("number out of range") {
        let detail = match count_expected(path, None) {
            Some(expected) => format!("number out of range: expected {expected}"),
            None => "number out of range: JSON numbers here must fit a 64-bit float \
                     (magnitude below 1.8e308)"
                .to_owned(),
        };
        return ParseError::Shape(Shapes::one(FieldError {
            pointer: path.to_owned(),
            detail,
        }));
    } else if masked.is_some()
        && (message.starts_with("expected value") || message.starts_with("invalid number"))
    {
        // The grammar holds once the tokens are masked, so reading stopped
        // at the first of them.
        let token = String::from_utf8_lossy(&bytes[spans[0].clone()]);
        let what = "which is not JSON (Python's json.dumps writes it for a non-finite float)";
        // What the place takes: what a number there is told, the masked
        // document being JSON (and free of these tokens, so this parses
        // once more at most). A number, not null: null is taken where an
        // object is (`model`), and where a number is (`time_limit_ms`).
        enum Told {
            /// A number is taken there.
            Number,
            /// What a number there is told.
            Here(String),
            /// The member holding it is wrong itself (`{"model": [NaN]}`).
            Above(FieldError),
            /// Not known: reading stopped before the whole document was
            /// checked (another value it cannot read, or the re-read budget).
            Unknown,
        }
        let told = match parse(masked.as_deref().unwrap_or(bytes)) {
            Ok(_) => Told::Number,
            Err(ParseError::Shape(s)) => {
                let complete = s.rest.is_some();
                let errors = s.checker.found.errors;
                if let Some(f) = errors.iter().find(|f| f.pointer == path) {
                    Told::Here(f.detail.clone())
                } else if let Some(f) = errors
                    .into_iter()
                    .find(|f| is_at_or_under(path, &f.pointer))
                {
                    Told::Above(f)
                } else if complete {
                    Told::Number
                } else {
                    Told::Unknown
                }
            }
            Err(ParseError::Syntax(_)) => Told::Unknown,
        };
        let detail = match (count_expected(path, None), told) {
            (Some(expected), _) => format!("got {token}, {what}: expected {expected}"),
            (None, Told::Here(told)) => match told.strip_prefix("invalid type: number 0, ") {
                Some(expected) => format!("got {token}, {what}: {expected}"),
                None => format!("got {token}, {what}; and {told}"),
            },
            (None, Told::Above(f)) => {
                format!("got {token}, {what}; and {}: {}", f.pointer, f.detail)
            }
            (None, Told::Number) => format!("got {token}, {what}: expected a finite number"),
            (None, Told::Unknown) => format!("got {token}, {what}"),
        };
        return ParseError::Shape(Shapes::one(FieldError {
            pointer: path.to_owned(),
            detail,
        }));
    } else if message.starts_with("recursion limit exceeded") {
        // The path is over a hundred levels deep by now; point at the
        // document's member that holds the nesting, which is what to fix.
        let member = path
            .split('/')
            .nth(1)
            .map_or(String::new(), |m| format!("/{m}"));
        (
            member,
            "nested 128 levels deep or more (the document is level 1); a problem nests at most 4",
        )
    } else if message.starts_with(TOO_MANY_OBJECTS) {
        // The path is the first object past the bound. Past the hundredth
        // obstacle, too many obstacles is the error to report, as it would
        // be for fewer (with a lower bound on the count, reading having
        // stopped); before it, the surplus objects are elsewhere.
        let obstacle = path
            .strip_prefix("/obstacles/")
            .and_then(|rest| rest.parse::<usize>().ok())
            .filter(|&index| index >= MAX_OBSTACLES);
        let error = match obstacle {
            Some(index) => FieldError {
                pointer: "/obstacles".to_owned(),
                detail: format!(
                    "at most {MAX_OBSTACLES} obstacles, got more than {index} (reading stopped \
                     at obstacle {index}, the document's JSON object number {})",
                    MAX_OBJECTS + 1
                ),
            },
            None => FieldError {
                pointer: path.to_owned(),
                detail: format!(
                    "the document holds more than {MAX_OBJECTS} JSON objects (this is the next \
                     one); a problem holds at most {} (one per obstacle, and the document, \
                     `model`, `weights`, `solver` and `output`)",
                    MAX_OBSTACLES + 5
                ),
            },
        };
        return ParseError::Shape(Shapes::one(error));
    } else if message.starts_with("lone leading surrogate")
        || message.starts_with("unexpected end of hex escape")
    {
        // The grammar held (the re-scan checks `\u` and its four hex
        // digits), so this is an escape of half a UTF-16 surrogate pair:
        // valid JSON, but no Unicode text. In a key, the pointer is the
        // key's object.
        (
            path.to_owned(),
            "a string with an unpaired surrogate escape (\\ud800 to \\udfff): expected Unicode text",
        )
    } else {
        return ParseError::Syntax(message);
    };
    ParseError::Shape(Shapes::one(FieldError {
        pointer,
        detail: detail.to_owned(),
    }))
}

/// The tokens a JSON writer may emit for non-finite floats, longest first
/// where one starts another.
const NON_FINITE: [&[u8]; 2] = [b"NaN", b"Infinity"];

/// Where `bytes` has a bare `NaN` or `Infinity` (with a `-` straight
/// before it, included) in a value's place, outside strings: after `:`, `[`
/// or `,` and whitespace, so `1NaN` stays the syntax error it is.
fn non_finite_spans(bytes: &[u8]) -> Vec<std::ops::Range<usize>> {
    let mut spans = Vec::new();
    let (mut i, mut in_string, mut after) = (0, false, b'\0');
    while let Some(&b) = bytes.get(i) {
        let signed = after == b'-' && i > 0 && bytes[i - 1] == b'-';
        if in_string {
            match b {
                b'\\' => i += 1,
                b'"' => in_string = false,
                _ => {}
            }
        } else if b == b'"' {
            in_string = true;
        } else if (signed || matches!(after, b':' | b'[' | b','))
            && let Some(len) = NON_FINITE
                .iter()
                .find(|t| bytes[i..].starts_with(t))
                .map(|t| t.len())
        {
            spans.push(if signed { i - 1 } else { i }..i + len);
            i += len;
            after = b'0';
            continue;
        }
        if !b.is_ascii_whitespace() {
            // A `-` counts only straight after a value's place.
            after = if b == b'-' && !matches!(after, b':' | b'[' | b',') {
                b'0'
            } else {
                b
            };
        }
        i += 1;
    }
    spans
}

/// `bytes` with each of `spans` replaced by `with`, the rest of the span
/// filled with spaces when `with` is shorter (so every position after it
/// stays where it was) and grown when longer.
fn replace_spans(bytes: &[u8], spans: &[std::ops::Range<usize>], with: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(bytes.len() + spans.len() * with.len());
    let mut from = 0;
    for span in spans {
        out.extend_from_slice(&bytes[from..span.start]);
        out.extend_from_slice(with);
        out.resize(out.len() + span.len().saturating_sub(with.len()), b' ');
        from = span.end;
    }
    out.extend_from_slice(&bytes[from..]);
    out
}

/// Reads a JSON document into a `serde_json::Value`, as `from_slice` does,
/// and reports the keys that repeat within their object to `checker`
/// (`Value` alone keeps the last silently). It reads on after a repeat, so a
/// syntax error anywhere still wins (400 over 422). Nesting is bounded by
/// serde_json's recursion limit (128), like any parse, and the number of
/// objects by [`MAX_OBJECTS`].
struct ValueNoting<'a> {
    /// The pointer of the value being read.
    path: &'a mut String,
    checker: &'a mut Checker,
    /// Objects begun so far in the whole document.
    objects: &'a mut usize,
}

impl<'de> serde::de::DeserializeSeed<'de> for ValueNoting<'_> {
    type Value = serde_json::Value;

    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<serde_json::Value, D::Error> {
        d.deserialize_any(self)
    }
}

impl<'de> Visitor<'de> for ValueNoting<'_> {
    type Value = serde_json::Value;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("any JSON value")
    }

    fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<Self::Value, A::Error> {
        *self.objects += 1;
        if *self.objects > MAX_OBJECTS {
            return Err(serde::de::Error::custom(TOO_MANY_OBJECTS));
        }
        let mut object = serde_json::Map::new();
        // The keys of this object already reported as repeated: each once,
        // however often it repeats ("a" 600 000 times under a megabyte key
        // took 11 s when every repeat compared its whole pointer).
        let mut reported = std::collections::HashSet::new();
        while let Some(key) = map.next_key::<String>()? {
            let len = self.path.len();
            self.path.push('/');
            self.path.push_str(&escape_token(&key));
            let value = map.next_value_seed(ValueNoting {
                path: self.path,
                checker: self.checker,
                objects: self.objects,
            })?;
            if object.contains_key(&key) && reported.insert(key.clone()) {
                self.checker.repeat(self.path);
            }
            object.insert(key, value);
            self.path.truncate(len);
        }
        Ok(serde_json::Value::Object(object))
    }

    fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
        let mut items = Vec::with_capacity(seq.size_hint().unwrap_or(0));
        loop {
            let len = self.path.len();
            // Into the buffer, not a new String per element.
            let _ = fmt::Write::write_fmt(self.path, format_args!("/{}", items.len()));
            let item = seq.next_element_seed(ValueNoting {
                path: self.path,
                checker: self.checker,
                objects: self.objects,
            })?;
            self.path.truncate(len);
            match item {
                Some(item) => items.push(item),
                None => return Ok(serde_json::Value::Array(items)),
            }
        }
    }

    fn visit_bool<E>(self, v: bool) -> Result<Self::Value, E> {
        Ok(v.into())
    }
    fn visit_i64<E>(self, v: i64) -> Result<Self::Value, E> {
        Ok(v.into())
    }
    fn visit_u64<E>(self, v: u64) -> Result<Self::Value, E> {
        Ok(v.into())
    }
    fn visit_f64<E>(self, v: f64) -> Result<Self::Value, E> {
        // As serde_json's own `Value`: the parser yields only finite numbers.
        Ok(v.into())
    }
    fn visit_str<E>(self, v: &str) -> Result<Self::Value, E> {
        Ok(v.into())
    }
    fn visit_string<E>(self, v: String) -> Result<Self::Value, E> {
        Ok(v.into())
    }
    fn visit_unit<E>(self) -> Result<Self::Value, E> {
        Ok(serde_json::Value::Null)
    }
}

/// The length of the fixed-size array at `pointer`, if it is one.
fn fixed_length(pointer: &str) -> Option<usize> {
    let tokens: Vec<&str> = pointer.split('/').skip(1).collect();
    let index = |t: &str| t.parse::<usize>().is_ok();
    match tokens.as_slice() {
        ["initial_state" | "goal_state"] | ["weights", "state" | "terminal"] => Some(6),
        ["weights", "control"] | ["initial_controls", _] => Some(2),
        ["obstacles", i, "center"] if index(i) => Some(2),
        _ => None,
    }
}

/// RFC 6901 escaping of one reference token.
fn escape_token(token: &str) -> String {
    token.replace('~', "~0").replace('/', "~1")
}

/// The inverse of [`escape_token`].
fn unescape_token(token: &str) -> String {
    token.replace("~1", "/").replace("~0", "~")
}

/// RFC 6901 pointer of a serde path (`weights.state[2]` → `/weights/state/2`).
fn pointer_of(path: &serde_path_to_error::Path) -> String {
    use serde_path_to_error::Segment;
    let mut out = String::new();
    for seg in path.iter() {
        out.push('/');
        match seg {
            Segment::Seq { index } => out.push_str(&index.to_string()),
            Segment::Map { key } | Segment::Enum { variant: key } => {
                out.push_str(&escape_token(key))
            }
            Segment::Unknown => out.push('?'),
        }
    }
    out
}

/// A number for an error message: plain where that is short (`0`, `0.05`,
/// `1000000`), in exponent form otherwise (`1e300`, `1e-9`), so that a huge
/// or tiny value never turns into hundreds of digits.
fn num(x: f64) -> String {
    if x == 0.0 || (1e-4..1e7).contains(&x.abs()) || !x.is_finite() {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whole up to the limit; past it, cut at character boundaries (a
    /// multi-byte character is never split) with the count of characters
    /// left out, keeping 100 at the start and 250 at the end.
    #[test]
    fn elide_keeps_head_and_tail_on_character_boundaries() {
        for unit in ["k", "é", "😀", "a€"] {
            for chars in [0, 399, 400, 401, 402, 1000, 100_000] {
                let text: String = unit.chars().cycle().take(chars).collect();
                let out = elide(text.clone());
                if chars <= MAX_DETAIL_CHARS {
                    assert_eq!(out, text);
                    continue;
                }
                let cut = chars - 350;
                let note = format!(" [... {cut} characters left out ...] ");
                let (head, tail) = out.split_once(&note).unwrap();
                assert_eq!(head.chars().count(), 100);
                assert_eq!(tail.chars().count(), 250);
                assert!(text.starts_with(head) && text.ends_with(tail));
            }
        }
    }
}
