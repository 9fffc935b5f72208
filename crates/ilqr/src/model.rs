//! What a model says about itself beyond its equations: the names and
//! units of its state and controls, its physical parameters with their
//! ranges, where its position in the plane is, and the controls that hold
//! it at rest. `ilqr-service` builds its wire format, validation, schema and
//! `GET /models` from this, so a new model is a new implementation of
//! [`Model`] (one file) plus one registration in the service.
//!
//! The solver itself never reads any of it: it sees only
//! [`ContinuousDynamics`] through an integrator.

use nalgebra::SVector;

use crate::dynamics::ContinuousDynamics;

/// One component of a state or control vector.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Quantity {
    /// Short name, as in the equations (`x`, `θ`, `u1`, `v`).
    pub name: &'static str,
    /// SI unit (`m`, `rad`, `m/s`, `N`).
    pub unit: &'static str,
    /// What it is, in a few words.
    pub description: &'static str,
}

/// A physical parameter of a model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Parameter {
    /// Name on the wire (`mass`).
    pub name: &'static str,
    /// SI unit.
    pub unit: &'static str,
    /// What it is, in a few words.
    pub description: &'static str,
    /// Value when the caller gives none.
    pub default: f64,
    /// Smallest accepted value.
    pub minimum: f64,
    /// Largest accepted value.
    pub maximum: f64,
}

/// A continuous-time model with the metadata a caller needs to use it.
///
/// The bounds on [`Model::PARAMETERS`] are the model's promise: every
/// parameter vector inside them gives finite dynamics, so a caller that
/// checks them (as `ilqr-service` does) may build the model with
/// [`Model::from_parameters`] without further checks.
pub trait Model<const NX: usize, const NU: usize>:
    ContinuousDynamics<NX, NU> + Clone + Sized
{
    /// Name on the wire, `snake_case` (`quadrotor_2d`).
    const NAME: &'static str;
    /// One paragraph: what the model is, its frame and its equations.
    const DESCRIPTION: &'static str;
    /// The state's components, in order.
    const STATE: [Quantity; NX];
    /// The controls, in order.
    const CONTROL: [Quantity; NU];
    /// The physical parameters, in the order [`Model::from_parameters`]
    /// takes them; empty for a model without any.
    const PARAMETERS: &'static [Parameter];
    /// The state indices of the position in the plane `(x, y)`, m: where
    /// obstacles are measured from.
    const POSITION: (usize, usize);

    /// The least each control can physically be, where the hardware has
    /// a floor the equations do not (a rotor pushes but cannot pull: 0 N
    /// of thrust); `None` where there is none. The equations accept any
    /// control, so a solve may go below it unless a bound forbids it; a
    /// service can warn when it does.
    const CONTROL_MINIMUM: Option<[f64; NU]> = None;

    /// The model with `values`, one per [`Model::PARAMETERS`] entry in that
    /// order, each within its bounds.
    fn from_parameters(values: &[f64]) -> Self;

    /// The controls that hold the model still (hover thrust, zero speed):
    /// the default initial guess of a solve.
    fn rest_controls(&self) -> SVector<f64, NU>;
}
