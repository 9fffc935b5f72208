//! Reading a problem document from bytes, with every wrong shape located.
//!
//! [`parse`] reads the bytes into a JSON value (noting keys given twice),
//! then into a [`ProblemDoc`]; where a value has the wrong shape it takes
//! that value out (or stands in a valid one inside an array), notes the
//! error at its JSON pointer, and reads again, so one answer lists every
//! error. What cannot be read at all (not JSON, not UTF-8) is a syntax
//! error.

use std::fmt;

use serde::Deserializer;
use serde::de::Visitor;

use super::validate::{Checker, FieldError, Invalid, MAX_REPORTED_ERRORS};
use super::wire::{ObjectOnly, ProblemDoc, count_expected};
use super::{Limits, MAX_OBSTACLES, ProblemSpec};

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
/// pointer where reading stopped: a number beyond the range of f64 (`1e999`,
/// JSON's nearest to Infinity), a string with an unpaired surrogate escape
/// (`"\ud800"`), and nesting 128 levels deep or more (serde_json's limit). So
/// is a bare `NaN` or `Infinity` (not JSON, but what Python's `json.dumps`
/// writes). The document is then checked again for UTF-8 and grammar (with
/// those tokens masked), so that a syntax error anywhere still wins. Such a
/// document is not read further: it reports that one value.
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
        let error = match serde_path_to_error::deserialize::<_, ProblemDoc>(ObjectOnly {
            inner: &value,
            expected: "a JSON object",
        }) {
            Ok(doc) if shapes.found.errors.is_empty() => return Ok(doc.resolve()),
            Ok(doc) => {
                let spec = doc.resolve();
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
        // fit (neither happens with this schema, whose one required
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
        // many bad rows has few reads; standing in to the end would leave
        // its range errors elsewhere unreported). The array's other elements
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
/// holds, so a 4 MB body of `{"a":1}` would build 363 MiB (90 times its
/// text, against at most about 25 times for arrays, strings and numbers),
/// and the allocator keeps most of such a peak after the answer.
pub const MAX_OBJECTS: usize = 1024;

/// The start of the serde error [`ValueNoting`] raises past
/// [`MAX_OBJECTS`], recognised by [`unreadable`].
const TOO_MANY_OBJECTS: &str = "too many JSON objects";

/// The members of a solve's result that a problem does not have.
const RESULT_MEMBERS: [&str; 14] = [
    "status",
    "cost",
    "initial_cost",
    "iterations",
    "goal_distance",
    "closest_approach",
    "states",
    "controls",
    "gains",
    "trace",
    "convexified_after_iteration",
    "convex_model_at_end",
    "solve_time_ms",
    "queue_time_ms",
];

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
    // A solve's result posted back as a problem: say how to reuse it.
    if let Some(member) = pointer.strip_prefix('/')
        && RESULT_MEMBERS.contains(&member)
        && detail.starts_with("unknown field")
    {
        detail = format!(
            "{detail}; `{member}` is a member of a solve's result, not of a problem: to \
             start from a result, send it as the problem's `warm_start` (its controls \
             become the initial guess)"
        );
    }
    // A result's `model` is its name; a problem's is an object.
    if pointer == "/model" && detail.starts_with("invalid type: string") {
        detail = format!(
            "{detail}: a problem names its model as {{\"type\": <name>}} (a result's `model` \
             is the name alone; to start from a result, send it as the problem's `warm_start`)"
        );
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
        ["obstacles", i, "center", j]
        | ["initial_controls", i, j]
        | ["warm_start", "controls", i, j]
            if is_index(i) && is_index(j) =>
        {
            json!(0.0)
        }
        ["obstacles", i, "center"] if is_index(i) => json!([0.0, 0.0]),
        // A row of no controls: its length is the model's to check, and
        // nothing is reported under a stand-in.
        ["initial_controls", i] | ["warm_start", "controls", i] if is_index(i) => json!([]),
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
pub(crate) fn is_at_or_under(pointer: &str, root: &str) -> bool {
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
        // would take 11 s if every repeat compared its whole pointer).
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

/// The length of the fixed-size array at `pointer`, if it is one: an
/// obstacle's centre (the other vectors' lengths are the model's, checked
/// by validation).
fn fixed_length(pointer: &str) -> Option<usize> {
    let tokens: Vec<&str> = pointer.split('/').skip(1).collect();
    let index = |t: &str| t.parse::<usize>().is_ok();
    match tokens.as_slice() {
        ["obstacles", i, "center"] if index(i) => Some(2),
        _ => None,
    }
}

/// RFC 6901 escaping of one reference token.
pub(crate) fn escape_token(token: &str) -> String {
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
pub fn num(x: f64) -> String {
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
