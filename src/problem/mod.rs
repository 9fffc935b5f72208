//! The problem document: what a caller sends to `POST /solve`, the CLI reads
//! from a file and the Python client builds.
//!
//! Every member is optional. `model.type` picks the model
//! ([`crate::models`]), and every member left out takes that model's
//! default, so `{}` is the seed scenario of the paper and
//! `{"model": {"type": "unicycle"}}` the unicycle's own default problem.
//! Unknown members are rejected rather than ignored, so a typo
//! (`"horizn"`) is an error and not a silent default.
//!
//! Three parts, by concern:
//!
//! * [`wire`]: the document as it arrives ([`wire::ProblemDoc`], every
//!   member optional) and its resolution into a [`ProblemSpec`], every
//!   member filled in from the model's defaults;
//! * `validate`: [`ProblemSpec::validate`], which checks every value
//!   against the model (lengths, parameter names and ranges) and reports
//!   *all* problems at once, each with the JSON pointer of its member;
//! * `recover`: [`parse`], which reads the bytes and, where values have the
//!   wrong shape, takes them out and reads on, so one answer lists every
//!   error.

use std::time::Duration;

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use crate::models::{self, ServedModel};

mod recover;
mod validate;
pub mod wire;

pub(crate) use recover::escape_token;
pub use recover::{MAX_OBJECTS, ParseError, RETRY_BYTES, Shapes, clip, elide, num, parse};
pub use validate::{FieldError, Invalid, MAX_REPORTED_BYTES, MAX_REPORTED_ERRORS};

/// Largest accepted horizon unless the service is configured otherwise.
pub const DEFAULT_MAX_HORIZON: usize = 10_000;
/// The longest default horizon of any model (the seed's): a service must
/// accept at least this many steps, or it would refuse its own defaults.
pub const DEFAULT_HORIZON: usize = 100;
/// Largest accepted `solver.max_iterations`.
pub const MAX_ITERATIONS: usize = 10_000;
/// Largest accepted number of obstacles.
pub const MAX_OBSTACLES: usize = 100;
/// Largest magnitude of a state component (initial and goal state, obstacle
/// centres), in the component's unit. With this bound, the models'
/// parameter ranges and controls within [`MAX_CONTROL`], no rollout of up
/// to 10000 steps can overflow an f64, so every valid problem has a finite
/// initial cost.
pub const MAX_STATE: f64 = 1e6;
/// Largest magnitude of a control in an initial guess, in the control's
/// unit. Far above any control a valid problem needs (hover at the
/// quadrotor's largest mass and gravity is 5e9 N), so a result's
/// `controls` can be posted back as a warm start; a problem that asks for
/// more (near-zero control weights with a tiny `dt`) can still exceed it.
pub const MAX_CONTROL: f64 = 1e12;
/// Largest cost weight.
pub const MAX_WEIGHT: f64 = 1e12;
/// Largest time step, s.
pub const MAX_DT: f64 = 10.0;

/// The seed obstacle's weight, also what an obstacle without one gets.
pub const SEED_OBSTACLE_WEIGHT: f64 = 1000.0;

/// A problem with every member filled in: what [`parse`] makes of a
/// document, and what `GET /problems/default` serves.
///
/// Minimise `Σ_k [(x_k − x_goal)ᵀQ(x_k − x_goal) + u_kᵀRu_k + Σ_j q_j·exp(−‖p_k − c_j‖)]`
/// plus `(x_N − x_goal)ᵀQ_f(x_N − x_goal)` over the model's discretised
/// dynamics from `initial_state`, where `p_k` is the model's position in
/// the plane. Vectors have the model's lengths once [`ProblemSpec::validate`]
/// has accepted it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ProblemSpec {
    /// The model and its parameters.
    pub model: ModelSpec,
    /// How the continuous dynamics are discretised.
    pub integrator: Integrator,
    /// Time step, s.
    pub dt: f64,
    /// Number of control steps N.
    pub horizon: usize,
    /// Initial state.
    pub initial_state: Vec<f64>,
    /// Target state.
    pub goal_state: Vec<f64>,
    /// Diagonal cost weights.
    pub weights: Weights,
    /// Obstacles, soft or hard.
    pub obstacles: Vec<Obstacle>,
    /// Hard constraints.
    pub constraints: ConstraintsSpec,
    /// Initial guess for the controls, N rows; `None` for the model's rest
    /// controls (or the warm start's).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub initial_controls: Option<Vec<Vec<f64>>>,
    /// A previous result to start from: its controls are the initial guess.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub warm_start: Option<wire::WarmStart>,
    /// Termination settings.
    pub solver: SolverSpec,
    /// Which optional parts of the result to return.
    pub output: OutputSpec,
}

/// The model of a problem: its name and parameter values.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelSpec {
    /// The model's name (`model.type`); one of [`crate::models::MODELS`]
    /// once validated.
    pub kind: String,
    /// Every parameter of the model with its value, in the model's order,
    /// then any name given that the model does not have (an error).
    pub parameters: Vec<(String, f64)>,
}

impl ModelSpec {
    /// The model, if this service has one of that name.
    pub fn served(&self) -> Option<&'static dyn ServedModel> {
        models::find(&self.kind)
    }

    /// The value of every parameter of `model`, in its order (its default
    /// where none is given).
    pub fn values(&self, model: &dyn ServedModel) -> Vec<f64> {
        model
            .parameters()
            .iter()
            .map(|p| self.get(p.name).unwrap_or(p.default))
            .collect()
    }

    /// The value given for the parameter `name`.
    pub fn get(&self, name: &str) -> Option<f64> {
        self.parameters
            .iter()
            .find(|(n, _)| n == name)
            .map(|&(_, v)| v)
    }
}

/// `{"type": ..., <parameter>: <value>, ...}`.
impl Serialize for ModelSpec {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut map = s.serialize_map(Some(1 + self.parameters.len()))?;
        map.serialize_entry("type", &self.kind)?;
        for (name, value) in &self.parameters {
            map.serialize_entry(name, value)?;
        }
        map.end()
    }
}

/// Discretisation of the continuous dynamics, for every model.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Integrator {
    /// Explicit Euler, `x_{k+1} = x_k + dt·f(x_k, u_k)` (the paper's eq. 9):
    /// first-order accurate.
    #[default]
    Euler,
    /// The classical fourth-order Runge–Kutta step, controls held over the
    /// step: four evaluations of the model per step, with exact Jacobians.
    Rk4,
}

impl Integrator {
    /// The wire name.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Euler => "euler",
            Self::Rk4 => "rk4",
        }
    }
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
    /// large costates: the seed with R = 90·I takes 483 iLQR iterations
    /// and 7 DDP ones), and may reach another local optimum (the seed:
    /// 5418.30 against iLQR's 5520.21).
    Ddp,
}

/// Diagonal weights of the quadratic cost terms (no ½ factors).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Weights {
    /// Diagonal of Q, the stage state weight.
    pub state: Vec<f64>,
    /// Diagonal of R, the control weight.
    pub control: Vec<f64>,
    /// Diagonal of Q_f, the terminal state weight.
    pub terminal: Vec<f64>,
}

/// An obstacle: a point, circle or rectangle in the plane of the model's
/// position `p`. `d` is the signed distance from `p` to it (to the centre
/// for a point; negative inside a circle or rectangle). With `weight` it
/// adds `weight·exp(−d)` to every stage cost (soft; for a point, eq. 13
/// of the paper); with `clearance` it is hard: `d ≥ clearance` at every
/// state after the initial one. It can be both.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Obstacle {
    /// `point` (default), `circle` (with `radius`) or `rectangle` (with
    /// `size` and `angle`).
    #[serde(default, skip_serializing_if = "ObstacleShape::is_point")]
    #[schema(default = "point")]
    pub shape: ObstacleShape,
    /// Centre `[x, y]` in m. No default: an obstacle is where it is.
    #[schema(schema_with = crate::schema::obstacle_center)]
    pub center: [f64; 2],
    /// A circle's radius, m, from 0 to 1e6; required for a circle, and
    /// only for one.
    #[serde(
        default,
        deserialize_with = "wire::de_some",
        skip_serializing_if = "Option::is_none"
    )]
    #[schema(nullable = false, minimum = 0.0, maximum = 1e6)]
    pub radius: Option<f64>,
    /// A rectangle's `[width, height]`, m, each from 0 to 1e6; required
    /// for a rectangle, and only for one. Width is along the rectangle's
    /// own x axis.
    #[serde(
        default,
        deserialize_with = "wire::de_some",
        skip_serializing_if = "Option::is_none"
    )]
    #[schema(schema_with = crate::schema::obstacle_size)]
    pub size: Option<[f64; 2]>,
    /// A rectangle's rotation, rad, counter-clockwise about its centre.
    /// Default 0; only for a rectangle.
    #[serde(
        default,
        deserialize_with = "wire::de_some",
        skip_serializing_if = "Option::is_none"
    )]
    #[schema(nullable = false, default = 0.0, minimum = -1e6, maximum = 1e6)]
    pub angle: Option<f64>,
    /// Weight q of the soft term `q·exp(−d)` (cost units, from 0 to 1e12).
    /// Default 1000, the seed obstacle's; 0 for a hard obstacle only.
    #[serde(default = "default_obstacle_weight")]
    #[schema(default = 1000.0, minimum = 0.0, maximum = 1e12)]
    pub weight: f64,
    /// Hard: the smallest signed distance `d` allowed at every state after
    /// the initial one, m (negative lets the position that far inside).
    /// Default: none, the obstacle is soft only.
    #[serde(
        default,
        deserialize_with = "wire::de_some",
        skip_serializing_if = "Option::is_none"
    )]
    #[schema(nullable = false, minimum = -1e6, maximum = 1e6)]
    pub clearance: Option<f64>,
}

impl Obstacle {
    /// A soft point obstacle: the seed's kind.
    pub const fn point(center: [f64; 2], weight: f64) -> Self {
        Self {
            shape: ObstacleShape::Point,
            center,
            radius: None,
            size: None,
            angle: None,
            weight,
            clearance: None,
        }
    }
}

/// The shape of an obstacle.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum ObstacleShape {
    /// A point at `center`: `d` is the distance to it.
    #[default]
    Point,
    /// A disc of `radius` about `center`.
    Circle,
    /// A `size` rectangle about `center`, turned by `angle`.
    Rectangle,
}

impl ObstacleShape {
    fn is_point(&self) -> bool {
        *self == Self::Point
    }

    /// The wire name.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Point => "point",
            Self::Circle => "circle",
            Self::Rectangle => "rectangle",
        }
    }
}

/// Hard constraints. Each member is optional; one left out constrains
/// nothing. Lengths follow the model (`GET /models`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(default, deny_unknown_fields)]
pub struct ConstraintsSpec {
    /// Bounds on the controls at every step, in the controls' units. They
    /// hold exactly in the result.
    #[serde(
        default,
        deserialize_with = "wire::de_some",
        skip_serializing_if = "Option::is_none"
    )]
    #[schema(nullable = false)]
    pub control: Option<Bounds>,
    /// Bounds on the state at every step after the initial one, in the
    /// state's units.
    #[serde(
        default,
        deserialize_with = "wire::de_some",
        skip_serializing_if = "Option::is_none"
    )]
    #[schema(nullable = false)]
    pub state: Option<Bounds>,
    /// `|x_N − goal_state|` at most this, per state component, in its
    /// unit; 0 makes the component an equality. Each at least 0.
    #[serde(
        default,
        deserialize_with = "wire::de_some",
        skip_serializing_if = "Option::is_none"
    )]
    #[schema(nullable = false, schema_with = crate::schema::goal_tolerance)]
    pub goal_tolerance: Option<Vec<f64>>,
}

impl ConstraintsSpec {
    /// Whether it constrains nothing.
    pub fn is_empty(&self) -> bool {
        self.control.is_none() && self.state.is_none() && self.goal_tolerance.is_none()
    }
}

/// Lower and upper bounds, one entry per component; `null` (or a missing
/// list) is no bound. Each lower bound at most its upper bound.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(default, deny_unknown_fields)]
pub struct Bounds {
    /// Lower bounds; `null` for none.
    #[serde(
        default,
        deserialize_with = "wire::de_some",
        skip_serializing_if = "Option::is_none"
    )]
    #[schema(nullable = false, schema_with = crate::schema::bound_list)]
    pub lower: Option<Vec<Option<f64>>>,
    /// Upper bounds; `null` for none.
    #[serde(
        default,
        deserialize_with = "wire::de_some",
        skip_serializing_if = "Option::is_none"
    )]
    #[schema(nullable = false, schema_with = crate::schema::bound_list)]
    pub upper: Option<Vec<Option<f64>>>,
}

impl Bounds {
    /// The bounds as numbers, `±∞` for none, `n` of each.
    pub fn resolved(&self, n: usize) -> (Vec<f64>, Vec<f64>) {
        let side = |xs: &Option<Vec<Option<f64>>>, none: f64| {
            (0..n)
                .map(|i| {
                    xs.as_ref()
                        .and_then(|v| v.get(i).copied().flatten())
                        .unwrap_or(none)
                })
                .collect()
        };
        (
            side(&self.lower, f64::NEG_INFINITY),
            side(&self.upper, f64::INFINITY),
        )
    }
}

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
    #[serde(deserialize_with = "wire::de_iterations")]
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
    /// of it. It is checked every iteration and every 128 knots inside the
    /// linearisation, backward pass and rollouts, so a solve overruns it by
    /// at most about 256 knots of work; the initial rollout always completes,
    /// since without it there is no trajectory to return. The solve stops
    /// early by the time the result's report and the answer's encoding
    /// will take, and a search runs only the starts that still fit, so the
    /// encoded answer is due within the budget plus 5% (at least 5 ms). At
    /// most the service's maximum (60000 unless
    /// configured). Unset: the service's default (10000 unless configured;
    /// the CLI has none).
    #[serde(deserialize_with = "wire::de_millis")]
    // The service's default maximum (`--max-time-limit-ms`); the served
    // spec puts the configured one here (tests/openapi.rs checks the two
    // agree).
    #[schema(minimum = 1, maximum = 60000)]
    pub time_limit_ms: Option<u64>,
    /// `ilqr` (default: the paper's algorithm) or `ddp` (the dynamics'
    /// second derivatives kept in the backward pass; fewer iterations where
    /// iLQR crawls, see docs/solver.md).
    #[serde(deserialize_with = "wire::de_name")]
    #[schema(default = "ilqr")]
    pub method: Method,
    /// With hard constraints: the largest violation a `converged` result
    /// may have, in each constraint's own units (m, rad, …). Default 1e-6;
    /// from 1e-12 to 1.
    #[schema(default = 1e-6, minimum = 1e-12, maximum = 1.0)]
    pub constraint_tolerance: f64,
    /// Search over the ways around the obstacles: besides the plain start
    /// (the model's rest controls, or the given ones), solve from detour
    /// starts that pass each obstacle in the way on the side the plain
    /// start's answer does not take, and return the best answer (see
    /// docs/solver.md, "Searching over routes"; each start is listed in the
    /// result's `starts`). Default: true, unless
    /// `initial_controls` or `warm_start` is given, when the solve is the
    /// single local solve from them. False: the single local solve from
    /// the plain start, as the paper does it.
    #[serde(
        default,
        deserialize_with = "wire::de_some",
        skip_serializing_if = "Option::is_none"
    )]
    #[schema(nullable = false)]
    pub multi_start: Option<bool>,
    /// The most starts a search solves from, the plain start included:
    /// detours beyond it are left out, those of the obstacles least in the
    /// way first. Default 7 (the plain start and a detour round each of six
    /// obstacles; both sides of three when the plain start does not
    /// converge); from 1 to 32.
    #[serde(deserialize_with = "wire::de_starts")]
    #[schema(default = 7, minimum = 1, maximum = 32)]
    pub max_starts: usize,
}

/// `solver.max_starts` unless given.
pub const DEFAULT_MAX_STARTS: usize = 7;
/// The largest `solver.max_starts`.
pub const MAX_STARTS: usize = 32;

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

impl ProblemSpec {
    /// The default problem of `model`, every member filled in.
    pub fn default_for(model: &dyn ServedModel) -> Self {
        let d = model.defaults();
        Self {
            model: ModelSpec {
                kind: model.name().to_owned(),
                parameters: model
                    .parameters()
                    .iter()
                    .map(|p| (p.name.to_owned(), p.default))
                    .collect(),
            },
            integrator: Integrator::default(),
            dt: d.dt,
            horizon: d.horizon,
            initial_state: d.initial_state.to_vec(),
            goal_state: d.goal_state.to_vec(),
            weights: Weights {
                state: d.state_weights.to_vec(),
                control: d.control_weights.to_vec(),
                terminal: d.terminal_weights.to_vec(),
            },
            obstacles: d.obstacles.to_vec(),
            constraints: ConstraintsSpec::default(),
            initial_controls: None,
            warm_start: None,
            solver: SolverSpec::default(),
            output: OutputSpec::default(),
        }
    }

    /// The time budget the problem asks for (`solver.time_limit_ms`), or
    /// `default` when it sets none.
    pub fn time_limit(&self, default: Option<Duration>) -> Option<Duration> {
        self.solver
            .time_limit_ms
            .map(Duration::from_millis)
            .or(default)
    }

    /// Whether the solve searches over routes (`solver.multi_start`, or
    /// its default: only without given controls).
    pub fn searches(&self) -> bool {
        self.solver
            .multi_start
            .unwrap_or(self.given_controls().is_none())
    }

    /// The initial guess given, from `initial_controls` or a warm start.
    pub fn given_controls(&self) -> Option<&[Vec<f64>]> {
        self.initial_controls
            .as_deref()
            .or(self.warm_start.as_ref().map(|w| w.controls.as_slice()))
    }
}

/// The seed scenario of the paper: the default model's default problem.
impl Default for ProblemSpec {
    fn default() -> Self {
        Self::default_for(models::default_model())
    }
}

impl Default for SolverSpec {
    fn default() -> Self {
        Self {
            max_iterations: 500,
            tolerance: 1e-9,
            time_limit_ms: None,
            method: Method::Ilqr,
            constraint_tolerance: 1e-6,
            multi_start: None,
            max_starts: DEFAULT_MAX_STARTS,
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A service configured with the smallest maximum horizon still takes
    /// every model's default problem.
    #[test]
    fn the_default_horizon_is_the_longest_default() {
        let longest = models::MODELS
            .iter()
            .map(|m| m.defaults().horizon)
            .max()
            .unwrap_or(0);
        assert_eq!(DEFAULT_HORIZON, longest);
    }
}
