//! The problem document as it arrives: every member optional, vectors of
//! any length (the model decides the length, and validation checks it),
//! and its resolution into a [`ProblemSpec`] with the model's defaults.
//!
//! The serde helpers here keep the document's shapes strict: a nested
//! object must be an object (or null for its defaults), a name must be a
//! string, a count an integer; what each expects is said in JSON's words.

use std::borrow::Cow;
use std::fmt;

use serde::de::Visitor;
use serde::{Deserialize, Deserializer, Serialize};
use utoipa::ToSchema;

use super::recover::num;
use super::{
    ConstraintsSpec, Integrator, Limits, ModelSpec, Obstacle, OutputSpec, ProblemSpec, SolverSpec,
    Weights,
};
use crate::models::{self, ServedModel};
use crate::schema;

/// A trajectory-optimisation problem.
///
/// Minimise `Σ_k [(x_k − x_goal)ᵀQ(x_k − x_goal) + u_kᵀRu_k + Σ_j q_j·exp(−‖p_k − c_j‖)]`
/// plus `(x_N − x_goal)ᵀQ_f(x_N − x_goal)`, subject to the model's dynamics
/// discretised by the integrator, from `initial_state`; `p_k` is the
/// model's position in the plane. Every member is optional: one left out
/// takes the model's default (`GET /models` lists them), so `{}` is the
/// planar quadrotor's seed scenario.
#[derive(Debug, Clone, Default, PartialEq, Deserialize, ToSchema)]
#[serde(default, deny_unknown_fields)]
#[schema(as = ProblemSpec, example = json!(ProblemSpec::default()))]
pub struct ProblemDoc {
    /// The model and its parameters.
    #[serde(deserialize_with = "de_object")]
    #[schema(schema_with = schema::model)]
    pub model: Option<ModelDoc>,
    /// How the continuous dynamics are discretised: `euler` (default) or
    /// `rk4`.
    #[serde(deserialize_with = "de_some_name")]
    #[schema(schema_with = schema::integrator)]
    pub integrator: Option<Integrator>,
    /// Time step in seconds.
    #[serde(deserialize_with = "de_some")]
    #[schema(schema_with = schema::dt)]
    pub dt: Option<f64>,
    /// Number of control steps N.
    #[serde(deserialize_with = "de_horizon")]
    #[schema(schema_with = schema::horizon)]
    pub horizon: Option<usize>,
    /// Initial state, one entry per state component of the model.
    #[serde(deserialize_with = "de_some")]
    #[schema(schema_with = schema::initial_state)]
    pub initial_state: Option<Vec<f64>>,
    /// Target state.
    #[serde(deserialize_with = "de_some")]
    #[schema(schema_with = schema::goal_state)]
    pub goal_state: Option<Vec<f64>>,
    /// Diagonal cost weights.
    #[serde(deserialize_with = "de_object")]
    #[schema(schema_with = schema::weights)]
    pub weights: Option<WeightsDoc>,
    /// Obstacles: points, circles or rectangles, soft (`weight`), hard
    /// (`clearance`) or both.
    #[serde(deserialize_with = "de_objects")]
    #[schema(schema_with = schema::obstacles)]
    pub obstacles: Option<Vec<Obstacle>>,
    /// Hard constraints: control and state bounds, and a goal tolerance.
    #[serde(deserialize_with = "de_object")]
    #[schema(schema_with = schema::constraints)]
    pub constraints: Option<ConstraintsSpec>,
    /// Initial guess for the controls: N rows, one entry per control.
    #[schema(schema_with = schema::initial_controls)]
    pub initial_controls: Option<Vec<Vec<f64>>>,
    /// A previous result to start from.
    #[serde(deserialize_with = "de_object")]
    #[schema(schema_with = schema::warm_start)]
    pub warm_start: Option<WarmStart>,
    /// Termination settings.
    #[serde(deserialize_with = "de_object")]
    #[schema(schema_with = schema::solver)]
    pub solver: Option<SolverSpec>,
    /// Which optional parts of the result to return.
    #[serde(deserialize_with = "de_object")]
    #[schema(schema_with = schema::output)]
    pub output: Option<OutputSpec>,
}

/// `model`: `{"type": <name>, <parameter>: <number>, ...}`. Which
/// parameters a model takes is its own (see [`crate::models`]), so they
/// are read as numbers by name here and checked against the model by
/// validation.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ModelDoc {
    /// `type`; the default model when left out.
    pub kind: Option<String>,
    /// Every other member, in the order given.
    pub parameters: Vec<(String, f64)>,
}

impl<'de> Deserialize<'de> for ModelDoc {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Members;

        impl<'de> Visitor<'de> for Members {
            type Value = ModelDoc;

            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a JSON object")
            }

            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> Result<ModelDoc, A::Error> {
                let mut out = ModelDoc::default();
                while let Some(key) = map.next_key::<String>()? {
                    if key == "type" {
                        out.kind = Some(map.next_value::<Name>()?.0);
                    } else {
                        let value = map.next_value::<f64>()?;
                        // A repeated key keeps its last value, as elsewhere
                        // (it is reported as repeated while reading).
                        out.parameters.retain(|(name, _)| *name != key);
                        out.parameters.push((key, value));
                    }
                }
                Ok(out)
            }
        }

        d.deserialize_map(Members)
    }
}

/// A JSON string (a name from a set the registry or an enum decides).
struct Name(String);

impl<'de> Deserialize<'de> for Name {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        String::deserialize(d).map(Name)
    }
}

/// `weights`, each member defaulting to the model's.
#[derive(Debug, Clone, Default, PartialEq, Deserialize, ToSchema)]
#[serde(default, deny_unknown_fields)]
#[schema(as = Weights)]
pub struct WeightsDoc {
    /// Diagonal of Q, the stage state weight: one entry per state
    /// component, each from 0 to 1e12.
    #[serde(deserialize_with = "de_some")]
    #[schema(schema_with = schema::state_weights)]
    pub state: Option<Vec<f64>>,
    /// Diagonal of R, the control weight: one entry per control.
    #[serde(deserialize_with = "de_some")]
    #[schema(schema_with = schema::control_weights)]
    pub control: Option<Vec<f64>>,
    /// Diagonal of Q_f, the terminal state weight.
    #[serde(deserialize_with = "de_some")]
    #[schema(schema_with = schema::terminal_weights)]
    pub terminal: Option<Vec<f64>>,
}

/// A previous result to start from (`POST /solve`'s answer, whole or in
/// part): its `controls` become the initial guess. Every other member of
/// the result is accepted and ignored, except `model`, which must be the
/// problem's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WarmStart {
    /// The controls to start from, N rows: they set the horizon when the
    /// problem gives none.
    pub controls: Vec<Vec<f64>>,
    /// The model the result was solved for, if it says.
    #[serde(
        default,
        deserialize_with = "de_some",
        skip_serializing_if = "Option::is_none"
    )]
    pub model: Option<String>,
}

impl ProblemDoc {
    /// The problem with every member left out filled in from the model's
    /// defaults. A model this service does not have (an error validation
    /// reports) takes the default model's defaults.
    pub fn resolve(self) -> ProblemSpec {
        let kind = self
            .model
            .as_ref()
            .and_then(|m| m.kind.clone())
            .unwrap_or_else(|| models::DEFAULT_MODEL.to_owned());
        let model: &dyn ServedModel = models::find(&kind).unwrap_or(models::default_model());
        let given = self.model.map(|m| m.parameters).unwrap_or_default();
        let mut parameters: Vec<(String, f64)> = model
            .parameters()
            .iter()
            .map(|p| {
                let value = given
                    .iter()
                    .find(|(n, _)| n == p.name)
                    .map_or(p.default, |&(_, v)| v);
                (p.name.to_owned(), value)
            })
            .collect();
        parameters.extend(
            given
                .into_iter()
                .filter(|(n, _)| !model.parameters().iter().any(|p| p.name == n)),
        );
        let d = model.defaults();
        let weights = self.weights.unwrap_or_default();
        let horizon = self
            .horizon
            .or(self.warm_start.as_ref().map(|w| w.controls.len()))
            .unwrap_or(d.horizon);
        ProblemSpec {
            model: ModelSpec { kind, parameters },
            integrator: self.integrator.unwrap_or_default(),
            dt: self.dt.unwrap_or(d.dt),
            horizon,
            initial_state: self
                .initial_state
                .unwrap_or_else(|| d.initial_state.to_vec()),
            goal_state: self.goal_state.unwrap_or_else(|| d.goal_state.to_vec()),
            weights: Weights {
                state: weights.state.unwrap_or_else(|| d.state_weights.to_vec()),
                control: weights
                    .control
                    .unwrap_or_else(|| d.control_weights.to_vec()),
                terminal: weights
                    .terminal
                    .unwrap_or_else(|| d.terminal_weights.to_vec()),
            },
            obstacles: self.obstacles.unwrap_or_else(|| d.obstacles.to_vec()),
            constraints: self.constraints.unwrap_or_default(),
            initial_controls: self.initial_controls,
            warm_start: self.warm_start,
            solver: self.solver.unwrap_or_default(),
            output: self.output.unwrap_or_default(),
        }
    }
}

/// A member that may be left out but not null: `Some` of the value. serde
/// gives `Option` members null as `None`, which here would be a silent
/// default; a null number is a wrong type, as it is everywhere else.
pub(crate) fn de_some<'de, D, T>(d: D) -> Result<Option<T>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    T::deserialize(d).map(Some)
}

/// [`de_name`], as `Some`.
fn de_some_name<'de, D, T>(d: D) -> Result<Option<T>, D::Error>
where
    D: Deserializer<'de>,
    T: serde::de::DeserializeOwned,
{
    de_name(d).map(Some)
}

/// Accept a count written as an integer or as an integral float (`100.0`):
/// JSON Schema calls both integers, and clients that build JSON from floats
/// should not get a type error for it. Anything else is an error that says
/// which integers the field takes (`"x"`, `-3`, `2.5`); the range check
/// itself is [`ProblemSpec::validate`]'s, against the configured limits.
fn de_horizon<'de, D: Deserializer<'de>>(d: D) -> Result<Option<usize>, D::Error> {
    de_count(d, HORIZON_EXPECTED).map(Some)
}

pub(crate) fn de_iterations<'de, D: Deserializer<'de>>(d: D) -> Result<usize, D::Error> {
    de_count(d, ITERATIONS_EXPECTED)
}

pub(crate) fn de_starts<'de, D: Deserializer<'de>>(d: D) -> Result<usize, D::Error> {
    de_count(d, STARTS_EXPECTED)
}

pub(crate) fn de_millis<'de, D: Deserializer<'de>>(d: D) -> Result<Option<u64>, D::Error> {
    d.deserialize_option(OptCount(Count(MILLIS_EXPECTED)))
}

const HORIZON_EXPECTED: &str =
    "an integer from 1 to the maximum horizon (10000 unless configured lower)";
const ITERATIONS_EXPECTED: &str = "an integer from 0 to 10000";
const STARTS_EXPECTED: &str = "an integer from 1 to 32";
const MILLIS_EXPECTED: &str =
    "a positive integer (ms; a service takes at most 60000 unless configured), or null";

/// What the count field at `pointer` takes, if it is one. Without
/// `limits`, in general: what a type error says while reading, before the
/// limits are known (and a number too large for f64 there gets the field's
/// own expectation, not the float one). With them, the configured range,
/// as the range check says it.
pub(crate) fn count_expected(pointer: &str, limits: Option<&Limits>) -> Option<Cow<'static, str>> {
    match (pointer, limits) {
        ("/horizon", None) => Some(HORIZON_EXPECTED.into()),
        ("/horizon", Some(l)) => Some(format!("an integer from 1 to {}", l.max_horizon).into()),
        ("/solver/max_iterations", _) => Some(ITERATIONS_EXPECTED.into()),
        ("/solver/max_starts", _) => Some(STARTS_EXPECTED.into()),
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
            // message writes it (serde writes -1e30 as `-1e+30`).
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
fn de_object<'de, D, T>(d: D) -> Result<Option<T>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    struct ObjectOrNull<T>(std::marker::PhantomData<T>);

    impl<'de, T: Deserialize<'de>> Visitor<'de> for ObjectOrNull<T> {
        type Value = Option<T>;

        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            f.write_str(OBJECT_OR_NULL)
        }

        fn visit_none<E: serde::de::Error>(self) -> Result<Option<T>, E> {
            Ok(None)
        }

        fn visit_unit<E: serde::de::Error>(self) -> Result<Option<T>, E> {
            Ok(None)
        }

        fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<Option<T>, D::Error> {
            T::deserialize(ObjectOnly {
                inner: d,
                expected: OBJECT_OR_NULL,
            })
            .map(Some)
        }
    }

    d.deserialize_option(ObjectOrNull(std::marker::PhantomData))
}

/// What [`de_object`]'s members take, for error messages.
const OBJECT_OR_NULL: &str = "a JSON object, or null for the defaults";

/// An array of nested structs, each a JSON object (see [`de_object`]).
fn de_objects<'de, D, T>(d: D) -> Result<Option<Vec<T>>, D::Error>
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
        .map(Some)
}

/// A deserializer that gives struct visitors only maps; anything else is
/// an error that says it `expected` this.
pub(crate) struct ObjectOnly<D> {
    pub(crate) inner: D,
    pub(crate) expected: &'static str,
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
pub(crate) fn de_name<'de, D, T>(d: D) -> Result<T, D::Error>
where
    D: Deserializer<'de>,
    T: serde::de::DeserializeOwned,
{
    use serde::de::IntoDeserializer;
    let name = String::deserialize(d)?;
    T::deserialize(name.as_str().into_deserializer())
}
