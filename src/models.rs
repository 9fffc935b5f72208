//! The models this service offers, and each one's default problem.
//!
//! A model is a type of the `ilqr` crate implementing [`ilqr::Model`]: its
//! equations, its state and control names and units, its parameters and
//! their ranges. Offering it here is one entry in [`MODELS`]: a [`Served`]
//! of the type with its default problem. Everything else (the wire format,
//! validation, the OpenAPI description, `GET /models`, the solve itself)
//! reads the entry through the [`ServedModel`] trait, so nothing else
//! changes when a model is added. `docs/models.md` walks through it.

use std::marker::PhantomData;

use ilqr::{Model, Parameter, Quadrotor2D, Quantity, Unicycle};

use crate::problem::{Obstacle, ProblemSpec};
use crate::solve::{Call, SolveResult, Unsolvable};

/// Every model, the default (`{}`'s, [`DEFAULT_MODEL`]) first.
pub static MODELS: [&dyn ServedModel; 2] = [
    &Served::<Quadrotor2D, 6, 2>::new(DefaultProblem {
        // The seed scenario of the paper: around the obstacle from (5, 0)
        // to (4, 9), the start reflected through the obstacle.
        dt: 0.05,
        horizon: 100,
        initial_state: &[5.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        goal_state: &[4.0, 9.0, 0.0, 0.0, 0.0, 0.0],
        state_weights: &[1.0; 6],
        control_weights: &[0.1; 2],
        terminal_weights: &[50000.0; 6],
        obstacles: &[Obstacle::point(
            [4.5, 4.5],
            crate::problem::SEED_OBSTACLE_WEIGHT,
        )],
    }),
    &Served::<Unicycle, 3, 2>::new(DefaultProblem {
        // From the origin heading east to (4, 0) heading east, around an
        // obstacle just off the straight line: 6 s in steps of 0.1 s. The
        // goal is weighted at the end only, so the path does not rush past
        // it and back.
        dt: 0.1,
        horizon: 60,
        initial_state: &[0.0, 0.0, 0.0],
        goal_state: &[4.0, 0.0, 0.0],
        state_weights: &[0.0; 3],
        control_weights: &[1.0; 2],
        terminal_weights: &[1000.0; 3],
        obstacles: &[Obstacle::point([2.0, 0.3], 5.0)],
    }),
];

/// The model of a problem that names none: the planar quadrotor.
pub const DEFAULT_MODEL: &str = "quadrotor_2d";

/// The model named `name`, if this service has it.
pub fn find(name: &str) -> Option<&'static dyn ServedModel> {
    MODELS.iter().copied().find(|m| m.name() == name)
}

/// The default model's entry.
pub fn default_model() -> &'static dyn ServedModel {
    MODELS[0]
}

/// The names of every model, as `` `a`, `b` `` for messages.
pub fn names() -> String {
    MODELS
        .iter()
        .map(|m| format!("`{}`", m.name()))
        .collect::<Vec<_>>()
        .join(", ")
}

/// What a problem that gives nothing else holds for a model: its own
/// documented scenario (units as the model's state and controls).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DefaultProblem {
    /// Time step, s.
    pub dt: f64,
    /// Number of control steps.
    pub horizon: usize,
    /// Initial state, one entry per state component.
    pub initial_state: &'static [f64],
    /// Goal state.
    pub goal_state: &'static [f64],
    /// Diagonal of `Q`.
    pub state_weights: &'static [f64],
    /// Diagonal of `R`.
    pub control_weights: &'static [f64],
    /// Diagonal of `Q_f`.
    pub terminal_weights: &'static [f64],
    /// Soft obstacles.
    pub obstacles: &'static [Obstacle],
}

/// A model as the service sees it: its description and its solve, with
/// the dimensions hidden behind slices.
pub trait ServedModel: Send + Sync {
    /// Wire name (`model.type`).
    fn name(&self) -> &'static str;
    /// What the model is.
    fn description(&self) -> &'static str;
    /// The state's components.
    fn state(&self) -> &'static [Quantity];
    /// The controls.
    fn control(&self) -> &'static [Quantity];
    /// The parameters, in order.
    fn parameters(&self) -> &'static [Parameter];
    /// The state indices of the position in the plane.
    fn position(&self) -> (usize, usize);
    /// Its default problem.
    fn defaults(&self) -> &DefaultProblem;
    /// The least each control can physically be, if the hardware has a
    /// floor ([`Model::CONTROL_MINIMUM`]).
    fn control_minimum(&self) -> Option<&'static [f64]>;
    /// The controls that hold it at rest for the given parameter values
    /// (one per [`ServedModel::parameters`] entry): the default initial
    /// guess.
    fn rest_controls(&self, parameters: &[f64]) -> Vec<f64>;
    /// Solve a validated problem of this model (see
    /// [`crate::solve::solve_observed`]).
    fn solve(&self, call: Call<'_>) -> Result<SolveResult, Unsolvable>;
}

/// The [`ServedModel`] of the `ilqr` model `M`, with `NX` states and `NU`
/// controls.
pub struct Served<M, const NX: usize, const NU: usize> {
    defaults: DefaultProblem,
    // `fn() -> M`: the entry holds no `M`, and is `Sync` whatever `M` is.
    model: PhantomData<fn() -> M>,
}

impl<M, const NX: usize, const NU: usize> Served<M, NX, NU> {
    /// The entry of `M` with its default problem.
    pub const fn new(defaults: DefaultProblem) -> Self {
        Self {
            defaults,
            model: PhantomData,
        }
    }
}

impl<M, const NX: usize, const NU: usize> ServedModel for Served<M, NX, NU>
where
    M: Model<NX, NU> + 'static,
{
    fn name(&self) -> &'static str {
        M::NAME
    }

    fn description(&self) -> &'static str {
        M::DESCRIPTION
    }

    fn state(&self) -> &'static [Quantity] {
        const { &M::STATE }
    }

    fn control(&self) -> &'static [Quantity] {
        const { &M::CONTROL }
    }

    fn parameters(&self) -> &'static [Parameter] {
        M::PARAMETERS
    }

    fn position(&self) -> (usize, usize) {
        M::POSITION
    }

    fn defaults(&self) -> &DefaultProblem {
        &self.defaults
    }

    fn control_minimum(&self) -> Option<&'static [f64]> {
        const { M::CONTROL_MINIMUM.as_ref() }.map(|m| m.as_slice())
    }

    fn rest_controls(&self, parameters: &[f64]) -> Vec<f64> {
        M::from_parameters(parameters)
            .rest_controls()
            .as_slice()
            .to_vec()
    }

    fn solve(&self, call: Call<'_>) -> Result<SolveResult, Unsolvable> {
        crate::solve::solve_model::<M, NX, NU>(call)
    }
}

/// `GET /models`: every model this service solves for.
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
pub struct ModelList {
    /// The models, the default one first.
    pub models: Vec<ModelInfo>,
}

impl ModelList {
    /// Every model's description.
    pub fn new() -> Self {
        Self {
            models: MODELS.iter().map(|m| ModelInfo::of(*m)).collect(),
        }
    }
}

impl Default for ModelList {
    fn default() -> Self {
        Self::new()
    }
}

/// One model: what `model.type` names and what its problems hold.
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
pub struct ModelInfo {
    /// The name `model.type` takes.
    #[serde(rename = "type")]
    pub kind: &'static str,
    /// What the model is, its frame and its equations.
    pub description: &'static str,
    /// The state's components, in order: the entries of `initial_state`,
    /// `goal_state`, `weights.state`, `weights.terminal` and each row of a
    /// result's `states`.
    pub state: Vec<QuantityInfo>,
    /// The controls, in order: the entries of `weights.control`, each row
    /// of `initial_controls` and of a result's `controls`.
    pub control: Vec<QuantityInfo>,
    /// The parameters `model` takes beside `type`.
    pub parameters: Vec<ParameterInfo>,
    /// The state entries of the position in the plane `[x, y]`: where
    /// obstacles are measured from.
    pub position: [usize; 2],
    /// The problem `{"model": {"type": <this>}}` stands for, every member
    /// filled in.
    #[schema(value_type = crate::problem::wire::ProblemDoc)]
    pub default_problem: ProblemSpec,
}

impl ModelInfo {
    fn of(m: &dyn ServedModel) -> Self {
        let (x, y) = m.position();
        Self {
            kind: m.name(),
            description: m.description(),
            state: m.state().iter().map(QuantityInfo::from).collect(),
            control: m.control().iter().map(QuantityInfo::from).collect(),
            parameters: m.parameters().iter().map(ParameterInfo::from).collect(),
            position: [x, y],
            default_problem: ProblemSpec::default_for(m),
        }
    }
}

/// A state or control component.
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
pub struct QuantityInfo {
    /// Its name in the equations (`θ`, `u1`).
    pub name: &'static str,
    /// Its SI unit.
    pub unit: &'static str,
    /// What it is.
    pub description: &'static str,
}

impl From<&Quantity> for QuantityInfo {
    fn from(q: &Quantity) -> Self {
        Self {
            name: q.name,
            unit: q.unit,
            description: q.description,
        }
    }
}

/// A model parameter.
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
pub struct ParameterInfo {
    /// The member of `model` that sets it.
    pub name: &'static str,
    /// Its SI unit.
    pub unit: &'static str,
    /// What it is.
    pub description: &'static str,
    /// Its value when left out.
    pub default: f64,
    /// Smallest accepted value.
    pub minimum: f64,
    /// Largest accepted value.
    pub maximum: f64,
}

impl From<&Parameter> for ParameterInfo {
    fn from(p: &Parameter) -> Self {
        Self {
            name: p.name,
            unit: p.unit,
            description: p.description,
            default: p.default,
            minimum: p.minimum,
            maximum: p.maximum,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each default problem fits its model: every vector has the model's
    /// length, which validation would otherwise refuse on `{"model": ...}`
    /// alone.
    #[test]
    fn default_problems_fit_their_models() {
        for m in MODELS {
            let (d, nx, nu) = (m.defaults(), m.state().len(), m.control().len());
            assert_eq!(d.initial_state.len(), nx, "{}", m.name());
            assert_eq!(d.goal_state.len(), nx, "{}", m.name());
            assert_eq!(d.state_weights.len(), nx, "{}", m.name());
            assert_eq!(d.terminal_weights.len(), nx, "{}", m.name());
            assert_eq!(d.control_weights.len(), nu, "{}", m.name());
        }
        assert_eq!(default_model().name(), DEFAULT_MODEL);
        // Names are unique.
        for (i, a) in MODELS.iter().enumerate() {
            for b in &MODELS[i + 1..] {
                assert_ne!(a.name(), b.name());
            }
        }
    }
}
