//! Hand-written OpenAPI schemas for nested arrays.
//!
//! utoipa derives `[f64; 6]` as an array of numbers with no length bounds and
//! cannot put bounds on the inner arrays of `Vec<[f64; 6]>`. These builders
//! state the lengths, so the spec says exactly what serde accepts.

use utoipa::openapi::schema::{ArrayBuilder, ArrayItems, ObjectBuilder, Schema, Type};
use utoipa::openapi::{KnownFormat, SchemaFormat};

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

/// Rows of `[u1, u2]`.
pub fn rows_of_2() -> Schema {
    ArrayBuilder::new()
        .items(fixed(2, number()))
        .description(Some(
            "One [u1, u2] row per step (N rows), rotor thrusts in N.",
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
