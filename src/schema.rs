//! Hand-written OpenAPI schemas for nested arrays, and for the nested
//! objects that also take null.
//!
//! utoipa derives `[f64; 6]` as an array of numbers with no length bounds and
//! cannot put bounds on the inner arrays of `Vec<[f64; 6]>` or on the items
//! of an array. These builders state the lengths and the value ranges, so
//! the spec says exactly what validation accepts. (A `schema_with` replaces
//! the field's doc comment, so each builder carries its own description.)

use utoipa::ToSchema;
use utoipa::openapi::schema::{
    AnyOfBuilder, ArrayBuilder, ArrayItems, ObjectBuilder, Ref, Schema, SchemaType, Type,
};
use utoipa::openapi::{KnownFormat, SchemaFormat};

use crate::problem::{
    MAX_CONTROL, MAX_STATE, MAX_WEIGHT, ModelSpec, OutputSpec, ProblemSpec, SolverSpec, Weights,
};

fn number() -> ObjectBuilder {
    ObjectBuilder::new()
        .schema_type(Type::Number)
        .format(Some(SchemaFormat::KnownFormat(KnownFormat::Double)))
}

fn fixed(len: usize, items: impl Into<ArrayItems>) -> ArrayBuilder {
    ArrayBuilder::new()
        .items(items)
        .min_items(Some(len))
        .max_items(Some(len))
}

/// A number from `lo` to `hi`.
fn number_in(lo: f64, hi: f64) -> ObjectBuilder {
    number().minimum(Some(lo)).maximum(Some(hi))
}

/// A fixed-length vector of numbers from `lo` to `hi`, with its default
/// taken from [`ProblemSpec::default`] so the spec cannot drift from it.
fn vector(len: usize, lo: f64, hi: f64, default: &[f64], description: &str) -> Schema {
    fixed(len, number_in(lo, hi))
        .description(Some(description))
        .default(Some(serde_json::json!(default)))
        .build()
        .into()
}

/// `initial_state`.
pub fn initial_state() -> Schema {
    vector(
        6,
        -MAX_STATE,
        MAX_STATE,
        &ProblemSpec::default().initial_state,
        "Initial state [x, y, θ, ẋ, ẏ, θ̇] in m, m, rad, m/s, m/s, rad/s, each of magnitude \
         at most 1e6. Default [5, 0, 0, 0, 0, 0]. θ is not taken modulo 2π: the cost \
         compares it with the goal's as a number, so give it within π of the goal's θ \
         (2π would be flown as a full turn back).",
    )
}

/// `goal_state`.
pub fn goal_state() -> Schema {
    vector(
        6,
        -MAX_STATE,
        MAX_STATE,
        &ProblemSpec::default().goal_state,
        "Target state, same units and bounds as initial_state. Default [4, 9, 0, 0, 0, 0]: \
         the initial state reflected through the default obstacle.",
    )
}

/// `weights.state`.
pub fn state_weights() -> Schema {
    vector(
        6,
        0.0,
        MAX_WEIGHT,
        &Weights::default().state,
        "Diagonal of Q, the stage state weight (0 to 1e12). Default all 1.",
    )
}

/// `weights.control`.
pub fn control_weights() -> Schema {
    vector(
        2,
        0.0,
        MAX_WEIGHT,
        &Weights::default().control,
        "Diagonal of R, the control weight (0 to 1e12). Default [0.1, 0.1].",
    )
}

/// `weights.terminal`.
pub fn terminal_weights() -> Schema {
    vector(
        6,
        0.0,
        MAX_WEIGHT,
        &Weights::default().terminal,
        "Diagonal of Q_f, the terminal state weight (0 to 1e12). Default all 50000.",
    )
}

/// `obstacles[].center`.
pub fn obstacle_center() -> Schema {
    // Required, so no default.
    fixed(2, number_in(-MAX_STATE, MAX_STATE))
        .description(Some("Centre [x, y] in m, each of magnitude at most 1e6."))
        .build()
        .into()
}

/// A nested object of the problem that null leaves at its defaults, as
/// leaving it out does (see `de_object` in `problem.rs`). `anyOf` of the
/// reference and null, the form FastAPI writes for an optional model and so
/// the one code generators read best; written here because utoipa's
/// `nullable` gives a `oneOf` with the description inside the reference,
/// and an object default beside it (which openapi-generator's Go output
/// does not compile).
fn object_or_null<T: ToSchema>(description: &str) -> Schema {
    AnyOfBuilder::new()
        .item(Ref::from_schema_name(T::name()))
        .item(ObjectBuilder::new().schema_type(Type::Null))
        .description(Some(format!(
            "{description} Null: the defaults, as when left out."
        )))
        .build()
        .into()
}

/// `model`.
pub fn model() -> Schema {
    object_or_null::<ModelSpec>("The dynamics model and its physical parameters.")
}

/// `weights`.
pub fn weights() -> Schema {
    object_or_null::<Weights>("Diagonal cost weights.")
}

/// `solver`.
pub fn solver() -> Schema {
    object_or_null::<SolverSpec>("Termination settings.")
}

/// `output`.
pub fn output() -> Schema {
    object_or_null::<OutputSpec>("Which optional parts of the result to return.")
}

/// `initial_controls`: rows of `[u1, u2]`, or null for the default.
pub fn initial_controls() -> Schema {
    ArrayBuilder::new()
        .schema_type(SchemaType::from_iter([Type::Array, Type::Null]))
        .items(fixed(2, number_in(-MAX_CONTROL, MAX_CONTROL)))
        .description(Some(
            "Initial guess for the controls: one [u1, u2] row per step, rotor thrusts in N \
             of magnitude at most 1e12. Exactly horizon rows: checked by the service (a \
             422 at /initial_controls), since a schema cannot tie an array's length to \
             another member. Absent or null: hover thrust m·g/2 on both rotors.",
        ))
        .build()
        .into()
}

/// Rows of full states.
pub fn states() -> Schema {
    ArrayBuilder::new()
        .items(fixed(6, number()))
        .description(Some(
            "States x_0..x_N (N + 1 rows) of [x, y, θ, ẋ, ẏ, θ̇] in m, m, rad, m/s, m/s, rad/s.",
        ))
        .build()
        .into()
}

/// Rows of controls.
pub fn controls() -> Schema {
    ArrayBuilder::new()
        .items(fixed(2, number()))
        .description(Some(
            "Controls u_0..u_{N−1} (N rows) of [u1, u2], rotor thrusts in N.",
        ))
        .build()
        .into()
}

/// Feedback gains: N matrices of 2 rows × 6 columns, row-major.
pub fn feedback() -> Schema {
    ArrayBuilder::new()
        .items(fixed(2, fixed(6, number())))
        .description(Some(
            "Feedback gains K_0..K_{N−1}: N matrices of 2 rows (controls) × 6 columns (states), \
             row-major, in N per state unit. The closed-loop policy is u_k = ū_k + K_k (x_k − x̄_k).",
        ))
        .build()
        .into()
}

/// Feedforward terms.
pub fn feedforward() -> Schema {
    ArrayBuilder::new()
        .items(fixed(2, number()))
        .description(Some(
            "Feedforward terms d_0..d_{N−1} (N rows of 2, N) of the last backward pass: \
             the control change the solver would take next (near zero at convergence).",
        ))
        .build()
        .into()
}
