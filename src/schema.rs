//! Hand-written OpenAPI schemas: the members whose shape depends on the
//! model, and the nested objects that also take null.
//!
//! A vector's length is its model's, which a schema cannot tie to
//! `model.type`: the vectors are arrays of numbers with their ranges, and
//! their descriptions list each model's components, units and defaults,
//! written from [`crate::models::MODELS`] so they cannot drift from it.
//! `model` is one object schema per model (`oneOf`), so each model's
//! parameters, ranges and defaults are stated exactly. (A `schema_with`
//! replaces the field's doc comment, so each builder carries its own
//! description.)

use utoipa::ToSchema;
use utoipa::openapi::schema::{
    AdditionalProperties, AnyOfBuilder, ArrayBuilder, ArrayItems, ObjectBuilder, OneOfBuilder, Ref,
    Schema, SchemaType, Type,
};
use utoipa::openapi::{KnownFormat, SchemaFormat};

use crate::models::{DEFAULT_MODEL, MODELS, ServedModel};
use crate::problem::{
    ConstraintsSpec, DEFAULT_MAX_HORIZON, MAX_CONTROL, MAX_DT, MAX_OBSTACLES, MAX_STATE,
    MAX_WEIGHT, Obstacle, OutputSpec, SolverSpec, wire::WeightsDoc,
};
use ilqr::Quantity;

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

/// `[x, y, θ] in m, m, rad`.
fn components(names: &[Quantity]) -> String {
    let list: Vec<&str> = names.iter().map(|q| q.name).collect();
    let units: Vec<&str> = names.iter().map(|q| q.unit).collect();
    format!("[{}] in {}", list.join(", "), units.join(", "))
}

/// `[5, 0, 0.05]`.
fn values(xs: &[f64]) -> String {
    let list: Vec<String> = xs.iter().map(|x| x.to_string()).collect();
    format!("[{}]", list.join(", "))
}

/// `obstacles[].size`.
pub fn obstacle_size() -> Schema {
    fixed(2, number_in(0.0, MAX_STATE))
        .description(Some(
            "A rectangle's [width, height] in m, each from 0 to 1e6; required for a rectangle, \
             and only for one. Width is along the rectangle's own x axis (turned by angle).",
        ))
        .build()
        .into()
}

/// `constraints`.
pub fn constraints() -> Schema {
    object_or_null::<ConstraintsSpec>(
        "Hard constraints: control bounds (held exactly), state bounds (at every state after \
         the initial one) and a goal tolerance (at the final state); none by default.",
    )
}

/// `constraints.goal_tolerance`.
pub fn goal_tolerance() -> Schema {
    vector(
        0.0,
        MAX_STATE,
        format!(
            "|x_N − goal_state| at most this, one entry per state component, each from 0 to \
             1e6 in its unit; 0 makes the component an equality. {}.",
            per_model(|m| components(m.state()))
        ),
    )
}

/// `constraints.control.lower` and the like: numbers or null.
pub fn bound_list() -> Schema {
    ArrayBuilder::new()
        .items(
            ObjectBuilder::new()
                .schema_type(SchemaType::from_iter([Type::Number, Type::Null]))
                .minimum(Some(-MAX_CONTROL))
                .maximum(Some(MAX_CONTROL)),
        )
        .description(Some(format!(
            "One bound per component, in its unit, or null for none; each of magnitude at \
             most 1e6 for a state and 1e12 for a control. Controls: {}. States: {}.",
            per_model(|m| components(m.control())),
            per_model(|m| components(m.state()))
        )))
        .build()
        .into()
}

/// Per model: `name: <what>`, joined by `; `. Plain text: Swagger UI
/// renders descriptions as Markdown.
fn per_model(what: impl Fn(&dyn ServedModel) -> String) -> String {
    MODELS
        .iter()
        .map(|m| format!("{}: {}", m.name(), what(*m)))
        .collect::<Vec<_>>()
        .join("; ")
}

/// A vector of numbers from `lo` to `hi` whose length is the model's.
fn vector(lo: f64, hi: f64, description: String) -> Schema {
    ArrayBuilder::new()
        .items(number_in(lo, hi))
        .description(Some(description))
        .build()
        .into()
}

/// `dt`.
pub fn dt() -> Schema {
    number()
        .exclusive_minimum(Some(0.0))
        .maximum(Some(MAX_DT))
        .description(Some(format!(
            "Time step in seconds, at most 10. Defaults: {}.",
            per_model(|m| m.defaults().dt.to_string())
        )))
        .build()
        .into()
}

/// `horizon`.
pub fn horizon() -> Schema {
    ObjectBuilder::new()
        .schema_type(Type::Integer)
        .minimum(Some(1))
        .maximum(Some(DEFAULT_MAX_HORIZON))
        .description(Some(format!(
            "Number of control steps N (the trajectory has N + 1 states), at most 10000 (the \
             service may be configured lower). Default: the number of rows of \
             warm_start.controls if given, else the model's: {}.",
            per_model(|m| m.defaults().horizon.to_string())
        )))
        .build()
        .into()
}

/// `obstacles`.
pub fn obstacles() -> Schema {
    ArrayBuilder::new()
        .items(Ref::from_schema_name(Obstacle::name()))
        .max_items(Some(MAX_OBSTACLES))
        .description(Some(format!(
            "Obstacles (points, circles, rectangles; soft, hard or both), at most 100. \
             Defaults: {}.",
            per_model(|m| {
                let list: Vec<String> = m
                    .defaults()
                    .obstacles
                    .iter()
                    .map(|o| {
                        format!(
                            "centre ({}, {}) weight {}",
                            o.center[0],
                            o.center[1],
                            crate::problem::num(o.weight)
                        )
                    })
                    .collect();
                if list.is_empty() {
                    "none".to_owned()
                } else {
                    list.join(", ")
                }
            })
        )))
        .build()
        .into()
}

/// `initial_state`.
pub fn initial_state() -> Schema {
    vector(
        -MAX_STATE,
        MAX_STATE,
        format!(
            "Initial state: one entry per state component of the model, each of magnitude \
             at most 1e6 in its unit. {}. Angles are not taken modulo 2π: the cost compares \
             them with the goal's as numbers, so give them within π of the goal's.",
            per_model(|m| format!(
                "{}, default {}",
                components(m.state()),
                values(m.defaults().initial_state)
            ))
        ),
    )
}

/// `goal_state`.
pub fn goal_state() -> Schema {
    vector(
        -MAX_STATE,
        MAX_STATE,
        format!(
            "Target state, same components, units and bounds as initial_state. Defaults: {}.",
            per_model(|m| values(m.defaults().goal_state))
        ),
    )
}

/// `weights.state`.
pub fn state_weights() -> Schema {
    vector(
        0.0,
        MAX_WEIGHT,
        format!(
            "Diagonal of Q, the stage state weight: one entry per state component, each from \
             0 to 1e12. Defaults: {}.",
            per_model(|m| values(m.defaults().state_weights))
        ),
    )
}

/// `weights.control`.
pub fn control_weights() -> Schema {
    vector(
        0.0,
        MAX_WEIGHT,
        format!(
            "Diagonal of R, the control weight: one entry per control, each from 0 to 1e12. \
             Defaults: {}.",
            per_model(|m| values(m.defaults().control_weights))
        ),
    )
}

/// `weights.terminal`.
pub fn terminal_weights() -> Schema {
    vector(
        0.0,
        MAX_WEIGHT,
        format!(
            "Diagonal of Q_f, the terminal state weight: one entry per state component, each \
             from 0 to 1e12. Defaults: {}.",
            per_model(|m| values(m.defaults().terminal_weights))
        ),
    )
}

/// `obstacles[].center`.
pub fn obstacle_center() -> Schema {
    // Required, so no default.
    fixed(2, number_in(-MAX_STATE, MAX_STATE))
        .description(Some(
            "Centre [x, y] in m, each of magnitude at most 1e6: a point in the plane of the \
             model's position.",
        ))
        .build()
        .into()
}

/// One model's `model` object: its `type` and its parameters, each with
/// its range and default. The default model's `type` may be left out.
fn model_variant(m: &dyn ServedModel) -> Schema {
    let mut object = ObjectBuilder::new()
        .schema_type(Type::Object)
        .title(Some(m.name()))
        .description(Some(m.description()))
        .property(
            "type",
            ObjectBuilder::new()
                .schema_type(Type::String)
                .enum_values(Some([m.name()]))
                .description(Some(if m.name() == DEFAULT_MODEL {
                    "The model (may be left out: this is the default one)."
                } else {
                    "The model."
                })),
        )
        .additional_properties(Some(AdditionalProperties::FreeForm(false)));
    if m.name() != DEFAULT_MODEL {
        object = object.required("type");
    }
    for p in m.parameters() {
        object = object.property(
            p.name,
            number_in(p.minimum, p.maximum)
                .default(Some(p.default.into()))
                .description(Some(format!(
                    "{} in {}, from {} to {}. Default {}.",
                    capitalised(p.description),
                    p.unit,
                    crate::problem::num(p.minimum),
                    crate::problem::num(p.maximum),
                    crate::problem::num(p.default)
                ))),
        );
    }
    object.build().into()
}

fn capitalised(text: &str) -> String {
    let mut chars = text.chars();
    chars
        .next()
        .map_or(String::new(), |c| c.to_uppercase().chain(chars).collect())
}

/// `model`: one object per model, or null for the default model.
pub fn model() -> Schema {
    let mut one_of = OneOfBuilder::new();
    for m in MODELS {
        one_of = one_of.item(model_variant(m));
    }
    one_of
        .item(ObjectBuilder::new().schema_type(Type::Null))
        .description(Some(format!(
            "The dynamics model and its parameters: type is one of {} (GET /models describes \
             each), and every other member is one of that model's parameters. Left out or \
             null: {DEFAULT_MODEL} with its default parameters.",
            crate::models::names().replace('`', "")
        )))
        .build()
        .into()
}

/// `integrator`.
pub fn integrator() -> Schema {
    ObjectBuilder::new()
        .schema_type(Type::String)
        .enum_values(Some(["euler", "rk4"]))
        .default(Some("euler".into()))
        .description(Some(
            "How the continuous dynamics are discretised, for every model: euler (default), \
             explicit Euler x_{k+1} = x_k + dt·f(x_k, u_k), the paper's eq. 9, first-order \
             accurate; or rk4, the classical fourth-order Runge–Kutta step with the controls \
             held over the step, four evaluations of the model per step, with exact \
             Jacobians.",
        ))
        .build()
        .into()
}

/// A nested object of the problem that null leaves at its defaults, as
/// leaving it out does (see `de_object` in `problem/wire.rs`). `anyOf` of
/// the reference and null, the form FastAPI writes for an optional model
/// and so the one code generators read best; written here because
/// utoipa's `nullable` gives a `oneOf` with the description inside the
/// reference, and an object default beside it (which openapi-generator's
/// Go output does not compile).
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

/// `weights`.
pub fn weights() -> Schema {
    object_or_null::<WeightsDoc>("Diagonal cost weights; each member left out is the model's.")
}

/// `solver`.
pub fn solver() -> Schema {
    object_or_null::<SolverSpec>("Termination settings.")
}

/// `output`.
pub fn output() -> Schema {
    object_or_null::<OutputSpec>("Which optional parts of the result to return.")
}

/// `initial_controls`: rows of controls, or null for the default.
pub fn initial_controls() -> Schema {
    ArrayBuilder::new()
        .schema_type(SchemaType::from_iter([Type::Array, Type::Null]))
        .items(ArrayBuilder::new().items(number_in(-MAX_CONTROL, MAX_CONTROL)))
        .description(Some(format!(
            "Initial guess for the controls: one row per step, one entry per control of the \
             model, each of magnitude at most 1e12 in its unit ({}). Exactly horizon rows: \
             checked by the service (a 422 at /initial_controls), since a schema cannot tie an \
             array's length to another member. Absent or null: the model's rest controls at \
             every step (hover thrust m·g/2 on both rotors for quadrotor_2d, standing still \
             for unicycle), or warm_start's controls.",
            per_model(|m| components(m.control()))
        )))
        .build()
        .into()
}

/// `warm_start`: a previous result, or null.
pub fn warm_start() -> Schema {
    let object = ObjectBuilder::new()
        .schema_type(Type::Object)
        .property(
            "controls",
            ArrayBuilder::new()
                .items(ArrayBuilder::new().items(number()))
                .description(Some("The result's controls: the initial guess.")),
        )
        .required("controls")
        .property(
            "model",
            ObjectBuilder::new()
                .schema_type(Type::String)
                .description(Some("The result's model: must be the problem's.")),
        )
        .additional_properties(Some(AdditionalProperties::FreeForm(true)));
    AnyOfBuilder::new()
        .item(object)
        .item(ObjectBuilder::new().schema_type(Type::Null))
        .description(Some(
            "A previous result to start from: POST /solve's answer, whole or in part. Its \
             controls become the initial guess, and set the horizon when the problem gives \
             none; its other members are ignored, but model, if given, must be the \
             problem's. Not with initial_controls. Null: none.",
        ))
        .build()
        .into()
}

/// Rows of full states.
pub fn states() -> Schema {
    ArrayBuilder::new()
        .items(ArrayBuilder::new().items(number()))
        .description(Some(format!(
            "States x_0..x_N (N + 1 rows), one entry per state component: {}.",
            per_model(|m| components(m.state()))
        )))
        .build()
        .into()
}

/// Rows of controls.
pub fn controls() -> Schema {
    ArrayBuilder::new()
        .items(ArrayBuilder::new().items(number()))
        .description(Some(format!(
            "Controls u_0..u_{{N−1}} (N rows), one entry per control: {}.",
            per_model(|m| components(m.control()))
        )))
        .build()
        .into()
}

/// Feedback gains: N matrices of (controls) rows × (states) columns,
/// row-major.
pub fn feedback() -> Schema {
    ArrayBuilder::new()
        .items(ArrayBuilder::new().items(ArrayBuilder::new().items(number())))
        .description(Some(
            "Feedback gains K_0..K_{N−1}: N matrices of one row per control × one column per \
             state component, row-major, in control units per state unit. The closed-loop \
             policy is u_k = ū_k + K_k (x_k − x̄_k).",
        ))
        .build()
        .into()
}

/// Feedforward terms.
pub fn feedforward() -> Schema {
    ArrayBuilder::new()
        .items(ArrayBuilder::new().items(number()))
        .description(Some(
            "Feedforward terms d_0..d_{N−1} (N rows, one entry per control) of the last \
             backward pass: the control change the solver would take next (near zero at \
             convergence).",
        ))
        .build()
        .into()
}

/// One Server-Sent Event of `POST /solve/stream`, as OpenAPI 3.1 describes
/// an event stream: `schema` is each event, `{event, data}`, and `data` is
/// JSON text whose schema is `contentSchema`. One variant per event name.
pub fn stream_event() -> Schema {
    let event = |name: &str, data: &str, description: &str| -> Schema {
        ObjectBuilder::new()
            .property(
                "event",
                ObjectBuilder::new()
                    .schema_type(Type::String)
                    .enum_values(Some([name])),
            )
            .property(
                "data",
                ObjectBuilder::new()
                    .schema_type(Type::String)
                    .content_media_type("application/json")
                    .content_schema(Some(Ref::from_schema_name(data)))
                    .description(Some(description)),
            )
            .required("event")
            .required("data")
            .build()
            .into()
    };
    OneOfBuilder::new()
        .item(event(
            "iteration",
            "TraceEntry",
            "One iteration as it ends: a row of the result's `trace`.",
        ))
        .item(event(
            "result",
            "SolveResult",
            "The last event of a stream that was answered: the result, as `POST /solve` answers it.",
        ))
        .item(event(
            "error",
            "Problem",
            "The last event of a stream that could not be answered after it began: a problem document.",
        ))
        .description(Some(
            "An event: an `iteration` per iteration, then one `result` or one `error`. \
             Comment lines (`:`) keep an idle connection open.",
        ))
        .build()
        .into()
}
