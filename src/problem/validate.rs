//! Validation of a resolved problem: every value in range, every vector
//! of the model's length, every parameter one the model has. All errors
//! are collected (up to a cap), each with its JSON pointer, so a caller can
//! fix them in one go.

use std::fmt;

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use super::recover::{is_at_or_under, num};
use super::{
    Limits, MAX_CONTROL, MAX_DT, MAX_ITERATIONS, MAX_OBSTACLES, MAX_STARTS, MAX_STATE, MAX_WEIGHT,
    ProblemSpec,
};
use crate::models::{self, ServedModel};
use ilqr::Quantity;

/// One invalid value: where it is and what was expected.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct FieldError {
    /// RFC 6901 JSON pointer to the field, e.g. `/weights/state/2`.
    pub pointer: String,
    /// What was wrong and what is expected.
    pub detail: String,
}

/// At most this many field errors are listed; [`Invalid::unlisted`] counts
/// the rest. A 4 MiB body of bad control rows would otherwise produce
/// ~760 000 errors, an 80 MB answer built on the async runtime.
pub const MAX_REPORTED_ERRORS: usize = 100;

/// The listed errors' pointers and messages hold at most this many bytes
/// together, the first error apart (always listed; its pointer is at most
/// the body's size); the rest are counted in [`Invalid::unlisted`]. A key
/// of a megabyte is in the pointer of every error under it: with a hundred
/// of them, a 4 MiB body would make a 400 MB answer.
pub const MAX_REPORTED_BYTES: usize = 64 * 1024;

/// Why a problem was rejected: its invalid values, listed up to a cap.
///
/// The count of the rest is kept apart from the list, so that every entry
/// of `errors` names a field a client can point at.
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
pub(crate) struct Checker {
    pub(crate) found: Invalid,
    /// Members taken out of the document as wrong shapes, and values stood
    /// in for: no error is reported at or under them (they hold defaults
    /// or stand-ins now).
    pub(crate) skip: Vec<String>,
    /// Keys given twice, already reported: no second error at exactly
    /// these pointers (the values under them are checked as usual). Only
    /// those listed in `found.errors`, so at most [`MAX_REPORTED_ERRORS`]
    /// of them and [`MAX_REPORTED_BYTES`] past the first: the memory stays
    /// small and a lookup cheap on a hostile document. Repeats past those
    /// are only counted (and another error at exactly such a pointer is
    /// counted too: a count past the list can be one high per repeat).
    pub(crate) repeated: Vec<String>,
    /// Bytes of pointers and messages in `found.errors`.
    pub(crate) listed_bytes: usize,
}

impl Checker {
    /// A key given twice in its object. The scan calls this once per key
    /// and object however often the key repeats, and before anything is
    /// taken out (so nothing is skipped yet).
    pub(crate) fn repeat(&mut self, pointer: &str) {
        // While errors are still listed, once per pointer too (a repeated
        // parent key holds two objects with the same pointers). Past the
        // list only counted, without comparing: under a megabyte key each
        // comparison reads the megabyte, and 150 000 repeated keys under
        // one would take 5.7 s of parsing.
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
    pub(crate) fn skips(&self, pointer: &str) -> bool {
        self.skip.iter().any(|r| is_at_or_under(pointer, r))
    }

    /// An error, unless it is under a taken-out member or at a repeated
    /// key's pointer (already reported).
    pub(crate) fn push(&mut self, pointer: &str, detail: String) {
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

    pub(crate) fn finish(self) -> Result<(), Invalid> {
        if self.found.errors.is_empty() {
            Ok(())
        } else {
            Err(self.found)
        }
    }
}

impl ProblemSpec {
    /// Check every value; returns the problems found (the first
    /// [`MAX_REPORTED_ERRORS`] of them, and a count of the rest), or nothing.
    pub fn validate(&self, limits: &Limits) -> Result<(), Invalid> {
        let mut v = Checker::default();
        self.check(limits, &mut v);
        v.finish()
    }

    pub(crate) fn check(&self, limits: &Limits, v: &mut Checker) {
        // The model decides the vectors' lengths and the parameters. One
        // this service does not have, or a `model` taken out as a wrong
        // shape (its values read as the default model's), says nothing of
        // what the caller meant, so neither is checked then.
        let model = if v.skips("/model/type") {
            None
        } else {
            let found = self.model.served();
            if found.is_none() {
                v.push(
                    "/model/type",
                    format!(
                        "unknown model `{}`: expected one of {} (GET /models describes them)",
                        super::clip(&self.model.kind, 100),
                        models::names()
                    ),
                );
            }
            found
        };
        if let Some(m) = model {
            check_parameters(m, &self.model.parameters, v);
        }
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
        let states = model.map(|m| m.state());
        let controls = model.map(|m| m.control());
        let state = (-MAX_STATE, MAX_STATE);
        let vectors: [Vector<'_>; 5] = [
            (
                "/initial_state",
                &self.initial_state,
                state,
                states,
                Unit::Own,
            ),
            ("/goal_state", &self.goal_state, state, states, Unit::Own),
            (
                "/weights/state",
                &self.weights.state,
                (0.0, MAX_WEIGHT),
                states,
                Unit::Weight,
            ),
            (
                "/weights/control",
                &self.weights.control,
                (0.0, MAX_WEIGHT),
                controls,
                Unit::Weight,
            ),
            (
                "/weights/terminal",
                &self.weights.terminal,
                (0.0, MAX_WEIGHT),
                states,
                Unit::Weight,
            ),
        ];
        for (pointer, xs, (lo, hi), names, unit) in vectors {
            if let (Some(m), Some(names)) = (model, names) {
                v.length(pointer, xs.len(), m, names);
            }
            v.range_vector(&pointer, xs, (lo, hi), names, unit);
        }
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
            v.range(
                &format_args!("/obstacles/{j}/weight"),
                o.weight,
                0.0,
                MAX_WEIGHT,
                "cost units",
            );
            check_shape(j, o, v);
        }
        self.check_constraints(model, v);
        if let (Some(_), Some(_)) = (&self.initial_controls, &self.warm_start) {
            v.push(
                "/warm_start",
                "give initial_controls or warm_start, not both: warm_start's controls are \
                 the initial guess"
                    .to_owned(),
            );
        }
        if let Some(us) = &self.initial_controls {
            self.check_rows("/initial_controls", us, limits, model, v);
        }
        if let Some(w) = &self.warm_start {
            if let (Some(given), Some(m)) = (&w.model, model)
                && given != m.name()
            {
                v.push(
                    "/warm_start/model",
                    format!(
                        "the result is of model `{}` but the problem is of `{}`: set the \
                         problem's model.type to the result's",
                        super::clip(given, 100),
                        m.name()
                    ),
                );
            }
            self.check_rows("/warm_start/controls", &w.controls, limits, model, v);
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
        if !(1..=MAX_STARTS).contains(&s.max_starts) {
            v.push(
                "/solver/max_starts",
                format!(
                    "must be an integer from 1 to {MAX_STARTS}, got {}",
                    s.max_starts
                ),
            );
        }
        if !(s.constraint_tolerance.is_finite() && (1e-12..=1.0).contains(&s.constraint_tolerance))
        {
            v.push(
                "/solver/constraint_tolerance",
                format!(
                    "must be a number from 1e-12 to 1 (the constraints' own units), got {}",
                    num(s.constraint_tolerance)
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

    /// `constraints`: lengths the model's, values finite and in range,
    /// each lower bound at most its upper bound, tolerances at least 0.
    fn check_constraints(&self, model: Option<&dyn ServedModel>, v: &mut Checker) {
        let c = &self.constraints;
        let sides = [
            (
                "control",
                &c.control,
                model.map(|m| m.control()),
                MAX_CONTROL,
            ),
            ("state", &c.state, model.map(|m| m.state()), MAX_STATE),
        ];
        for (name, bounds, names, max) in sides {
            let Some(b) = bounds else { continue };
            for (side, xs) in [("lower", &b.lower), ("upper", &b.upper)] {
                let Some(xs) = xs else { continue };
                let pointer = format!("/constraints/{name}/{side}");
                if let (Some(m), Some(names)) = (model, names) {
                    v.length(&pointer, xs.len(), m, names);
                }
                for (i, x) in xs.iter().enumerate() {
                    if let Some(x) = x {
                        let unit = names.and_then(|n| n.get(i)).map_or("its unit", |q| q.unit);
                        v.range(&format_args!("{pointer}/{i}"), *x, -max, max, unit);
                    }
                }
            }
            if let (Some(lower), Some(upper)) = (&b.lower, &b.upper) {
                for (i, (lo, hi)) in lower.iter().zip(upper).enumerate() {
                    if let (Some(lo), Some(hi)) = (lo, hi)
                        && lo > hi
                    {
                        v.push(
                            &format!("/constraints/{name}/lower/{i}"),
                            format!(
                                "must be at most the upper bound {} (no value satisfies both), \
                                 got {}",
                                num(*hi),
                                num(*lo)
                            ),
                        );
                    }
                }
            }
        }
        if let Some(t) = &c.goal_tolerance {
            let states = model.map(|m| m.state());
            if let (Some(m), Some(names)) = (model, states) {
                v.length("/constraints/goal_tolerance", t.len(), m, names);
            }
            v.range_vector(
                &"/constraints/goal_tolerance",
                t,
                (0.0, MAX_STATE),
                states,
                Unit::Own,
            );
        }
    }

    /// An initial guess at `pointer`: one row per step, each with one
    /// entry per control, in range.
    fn check_rows(
        &self,
        pointer: &str,
        us: &[Vec<f64>],
        limits: &Limits,
        model: Option<&dyn ServedModel>,
        v: &mut Checker,
    ) {
        // Only against a valid horizon: one taken out as a wrong shape
        // reads as the default, not what was sent, and matching one out of
        // range (0, 20000) would not make the problem valid.
        let horizon_valid = (1..=limits.max_horizon).contains(&self.horizon);
        let controls = model.map(|m| m.control());
        if us.len() != self.horizon && horizon_valid && !v.skips("/horizon") {
            let row = controls.map_or_else(|| "control".to_owned(), names_of);
            v.push(
                pointer,
                format!(
                    "must have one {row} row per step: expected {} rows (the horizon), got {}",
                    self.horizon,
                    us.len()
                ),
            );
        }
        for (k, u) in us.iter().enumerate() {
            if let (Some(m), Some(names)) = (model, controls)
                && u.len() != names.len()
            {
                v.length(&format!("{pointer}/{k}"), u.len(), m, names);
            }
            v.range_vector(
                &format_args!("{pointer}/{k}"),
                u,
                (-MAX_CONTROL, MAX_CONTROL),
                controls,
                Unit::Own,
            );
        }
    }
}

/// An obstacle's shape members: each one its shape's, in range, and the
/// ones its shape needs given.
fn check_shape(j: usize, o: &super::Obstacle, v: &mut Checker) {
    use super::ObstacleShape;
    let shape = o.shape.as_str();
    let needs = |v: &mut Checker, member: &str, given: bool, wanted: bool, what: &str| {
        let pointer = format!("/obstacles/{j}/{member}");
        if given && !wanted {
            v.push(
                &pointer,
                format!("`{member}` is only for a {what}; this obstacle is a {shape}"),
            );
        } else if !given && wanted && !v.skips(&pointer) {
            v.push(
                &pointer,
                format!("a {shape} needs `{member}` ({})", member_expected(member)),
            );
        }
    };
    let circle = o.shape == ObstacleShape::Circle;
    let rectangle = o.shape == ObstacleShape::Rectangle;
    needs(v, "radius", o.radius.is_some(), circle, "circle");
    needs(v, "size", o.size.is_some(), rectangle, "rectangle");
    if o.angle.is_some() && !rectangle {
        needs(v, "angle", true, false, "rectangle");
    }
    if let Some(r) = o.radius {
        v.range(
            &format_args!("/obstacles/{j}/radius"),
            r,
            0.0,
            MAX_STATE,
            "m",
        );
    }
    if let Some(size) = &o.size {
        v.range_all(
            &format_args!("/obstacles/{j}/size"),
            size,
            (0.0, MAX_STATE),
            "m",
        );
    }
    if let Some(a) = o.angle {
        v.range(
            &format_args!("/obstacles/{j}/angle"),
            a,
            -MAX_STATE,
            MAX_STATE,
            "rad",
        );
    }
    if let Some(c) = o.clearance {
        v.range(
            &format_args!("/obstacles/{j}/clearance"),
            c,
            -MAX_STATE,
            MAX_STATE,
            "m",
        );
    }
}

/// What a shape member takes, for the error that it is missing.
fn member_expected(member: &str) -> &'static str {
    match member {
        "radius" => "a number of m from 0 to 1e6",
        _ => "[width, height] in m, each from 0 to 1e6",
    }
}

/// A vector of the problem: its pointer, values, range, components (when
/// the model is known) and the unit its range errors name.
type Vector<'a> = (&'a str, &'a [f64], (f64, f64), Option<&'a [Quantity]>, Unit);

/// What unit a vector's range error names.
#[derive(Clone, Copy)]
enum Unit {
    /// Each component's own (m, rad, N).
    Own,
    /// A cost weight's.
    Weight,
}

/// `[x, y, θ]`: the components' names.
fn names_of(names: &[Quantity]) -> String {
    let list: Vec<&str> = names.iter().map(|q| q.name).collect();
    format!("[{}]", list.join(", "))
}

/// The model's parameters: each given one known to the model and in its
/// range.
fn check_parameters(m: &dyn ServedModel, given: &[(String, f64)], v: &mut Checker) {
    for (name, value) in given {
        let pointer = format!("/model/{}", super::recover::escape_token(name));
        match m.parameters().iter().find(|p| p.name == name) {
            Some(p) => v.range(&pointer, *value, p.minimum, p.maximum, p.unit),
            None if m.parameters().is_empty() => v.push(
                &pointer,
                format!(
                    "unknown field `{}`: model `{}` has no parameters, only `type`",
                    super::clip(name, 100),
                    m.name()
                ),
            ),
            None => {
                let known: Vec<String> = m
                    .parameters()
                    .iter()
                    .map(|p| format!("`{}`", p.name))
                    .collect();
                v.push(
                    &pointer,
                    format!(
                        "unknown field `{}`: model `{}` takes `type`, {}",
                        super::clip(name, 100),
                        m.name(),
                        known.join(", ")
                    ),
                );
            }
        }
    }
}

impl Checker {
    /// A vector whose length is not the model's: names the model, the
    /// length and the components.
    fn length(&mut self, pointer: &str, len: usize, m: &dyn ServedModel, names: &[Quantity]) {
        if len != names.len() {
            let units: Vec<&str> = names.iter().map(|q| q.unit).collect();
            self.push(
                pointer,
                format!(
                    "must have {} entries for model `{}`, {} in {}: got {len}",
                    names.len(),
                    m.name(),
                    names_of(names),
                    units.join(", ")
                ),
            );
        }
    }

    /// Each entry of `xs` in `[lo, hi]`, named by its component's unit.
    fn range_vector(
        &mut self,
        pointer: &dyn fmt::Display,
        xs: &[f64],
        (lo, hi): (f64, f64),
        names: Option<&[Quantity]>,
        unit: Unit,
    ) {
        for (i, x) in xs.iter().enumerate() {
            let unit = match (unit, names.and_then(|n| n.get(i))) {
                (Unit::Weight, _) => "weight",
                (Unit::Own, Some(q)) => q.unit,
                (Unit::Own, None) => "the component's unit",
            };
            self.range(&format_args!("{pointer}/{i}"), *x, lo, hi, unit);
        }
    }
}
