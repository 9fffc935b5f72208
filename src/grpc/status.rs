//! The service's errors as gRPC statuses, and the call's deadline.
//!
//! Each error keeps the HTTP API's wording (its problem document's
//! `detail`) and carries the standard details of `google/rpc/error_details.proto`:
//!
//! | error | code | details |
//! |---|---|---|
//! | invalid problem | `INVALID_ARGUMENT` | `BadRequest`: a field violation per error |
//! | overloaded (queue full, expected wait too long) | `RESOURCE_EXHAUSTED` | `RetryInfo` |
//! | expired in the queue | `RESOURCE_EXHAUSTED` | `RetryInfo` |
//! | shutting down | `UNAVAILABLE` | |
//! | a bug | `INTERNAL` | |
//!
//! and on every one `ErrorInfo` (domain `ilqr-service`, reason the HTTP
//! problem's kind in capitals: `VALIDATION`, `OVERLOADED`,
//! `EXPIRED_IN_QUEUE`, `SHUTTING_DOWN`, `INTERNAL`; metadata `type`, the
//! problem's `type` URI) and `RequestInfo` (the call's `x-request-id`).

use std::time::{Duration, Instant};

use serde_json::Value;
use tonic::metadata::MetadataMap;
use tonic::{Code, Status};
use tonic_types::{ErrorDetails, StatusExt};

use super::convert::{Flat, flat_note};
use crate::problem::Invalid;
use crate::server::ApiError;
use crate::service::SolveError;

/// The status of a problem with these invalid values.
pub fn invalid(invalid: Invalid, flat: &Flat, request_id: &str) -> Status {
    error(&ApiError::Validation(invalid), flat, request_id)
}

/// The status of a solve that gave no answer.
pub fn solve_error(e: SolveError, flat: &Flat, request_id: &str) -> Status {
    error(&ApiError::from(e), flat, request_id)
}

fn error(e: &ApiError, flat: &Flat, request_id: &str) -> Status {
    let problem = e.problem();
    let code = match e {
        ApiError::Validation(_) => Code::InvalidArgument,
        ApiError::Overloaded { .. } | ApiError::ExpiredInQueue { .. } => Code::ResourceExhausted,
        ApiError::ShuttingDown => Code::Unavailable,
        _ => Code::Internal,
    };
    let kind = problem
        .kind
        .strip_prefix("urn:ilqr-service:")
        .unwrap_or(&problem.kind)
        .replace('-', "_")
        .to_ascii_uppercase();
    let mut details = ErrorDetails::new();
    details
        .set_error_info(
            kind,
            "ilqr-service",
            [("type".to_owned(), problem.kind.clone())],
        )
        .set_request_info(request_id, "");
    if let Some(secs) = problem.retry_after {
        details.set_retry_info(Some(Duration::from_secs(secs)));
    }
    let message = match e {
        ApiError::Validation(invalid) => {
            for f in &invalid.errors {
                let description = match flat_note(&f.pointer, flat) {
                    Some(note) => format!("{} {note}", f.detail),
                    None => f.detail.clone(),
                };
                details.add_bad_request_violation(field_path(&f.pointer), description);
            }
            validation_message(invalid)
        }
        ApiError::Internal => {
            "the call failed unexpectedly; its request id (google.rpc.RequestInfo, and the \
             x-request-id metadata) identifies it in the logs"
                .to_owned()
        }
        _ => problem.detail,
    };
    Status::with_error_details(code, message, details)
}

/// The status message of an invalid problem: the one error, or how many
/// there are.
fn validation_message(invalid: &Invalid) -> String {
    let mut message = match (invalid.errors.as_slice(), invalid.unlisted) {
        ([one], 0) => format!(
            "{}: {}",
            crate::problem::elide(field_path(&one.pointer)),
            one.detail
        ),
        (many, 0) => format!(
            "{} invalid fields; the google.rpc.BadRequest details describe each",
            many.len()
        ),
        (listed, unlisted) => format!(
            "{} invalid values; the google.rpc.BadRequest details describe the first {}",
            listed.len() + unlisted,
            listed.len()
        ),
    };
    if invalid.incomplete {
        message.push_str(ApiError::INCOMPLETE);
    }
    message
}

/// A JSON pointer into the problem document written as a field path, as
/// `google.rpc.BadRequest` has them: `/obstacles/1/center` →
/// `obstacles[1].center`, `/initial_controls/3/1` →
/// `initial_controls[3][1]`, `/model/mass` → `model.mass`. An array index
/// is `[n]`; a key that is not an identifier (a parameter named `a.b`, or
/// `1`) is `["…"]`, quoted as a JSON string. The empty pointer (the
/// problem itself) is the empty path.
pub fn field_path(pointer: &str) -> String {
    let mut path = String::new();
    let mut parent = "";
    for (i, raw) in pointer.split('/').skip(1).enumerate() {
        let token = raw.replace("~1", "/").replace("~0", "~");
        // The members of `model` are names (its parameters), never indices.
        let key = i == 1 && parent == "model";
        let identifier = token
            .chars()
            .next()
            .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
            && token.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
        if !key && !token.is_empty() && token.bytes().all(|b| b.is_ascii_digit()) {
            path.push_str(&format!("[{token}]"));
        } else if identifier {
            if !path.is_empty() {
                path.push('.');
            }
            path.push_str(&token);
        } else {
            path.push_str(&format!("[{}]", Value::from(token.as_str())));
        }
        if i == 0 {
            parent = raw;
        }
    }
    path
}

/// What is kept back from the call's deadline for the answer: a tenth of
/// the call's timeout, at most [`MAX_MARGIN`], plus [`SEND_MARGIN`], and
/// never more than half the timeout. The answer is encoded (a 10000-step
/// result with gains, 1.8 MB of protobuf, in 0.3 ms) and sent in it; the
/// solver overruns its budget by at most about 256 knots of work.
pub fn margin(timeout: Duration) -> Duration {
    ((timeout / 10).min(MAX_MARGIN) + SEND_MARGIN).min(timeout / 2)
}

/// The most [`margin`] keeps back in proportion to the timeout.
pub const MAX_MARGIN: Duration = Duration::from_millis(250);

/// Kept back from every deadline, for decoding the request before the
/// handler reads the clock and sending the answer.
pub const SEND_MARGIN: Duration = Duration::from_millis(5);

/// The end of the solve's budget for a call that arrived at `now`: its
/// deadline (`grpc-timeout`) less the [`margin`]. `None` without a
/// deadline, or with a `grpc-timeout` that is not one (which tonic's own
/// deadline ignores too).
pub fn budget_end(metadata: &MetadataMap, now: Instant) -> Option<Instant> {
    let timeout = timeout_of(metadata.get("grpc-timeout")?.to_str().ok()?)?;
    now.checked_add(timeout - margin(timeout))
}

/// A `grpc-timeout` value: up to 8 digits and a unit, `H`, `M`, `S`, `m`
/// (ms), `u` (µs) or `n` (ns), as gRPC over HTTP/2 defines it.
pub fn timeout_of(value: &str) -> Option<Duration> {
    let split = value.len().checked_sub(1)?;
    let (digits, unit) = (value.get(..split)?, value.get(split..)?);
    if digits.is_empty() || digits.len() > 8 || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let n: u64 = digits.parse().ok()?;
    Some(match unit {
        "H" => Duration::from_secs(n * 3600),
        "M" => Duration::from_secs(n * 60),
        "S" => Duration::from_secs(n),
        "m" => Duration::from_millis(n),
        "u" => Duration::from_micros(n),
        "n" => Duration::from_nanos(n),
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pointers_become_field_paths() {
        for (pointer, path) in [
            ("", ""),
            ("/dt", "dt"),
            ("/obstacles/1/center", "obstacles[1].center"),
            ("/obstacles/1/center/0", "obstacles[1].center[0]"),
            ("/model/mass", "model.mass"),
            ("/model/type", "model.type"),
            ("/model/1", "model[\"1\"]"),
            ("/model/a.b", "model[\"a.b\"]"),
            ("/model/a~1b", "model[\"a/b\"]"),
            ("/model/parameters/type", "model.parameters.type"),
            ("/initial_controls/3/1", "initial_controls[3][1]"),
            ("/warm_start/controls/0", "warm_start.controls[0]"),
            ("/solver/time_limit_ms", "solver.time_limit_ms"),
        ] {
            assert_eq!(field_path(pointer), path, "{pointer}");
        }
    }

    #[test]
    fn grpc_timeouts_are_read_as_the_protocol_writes_them() {
        assert_eq!(timeout_of("1H"), Some(Duration::from_secs(3600)));
        assert_eq!(timeout_of("2M"), Some(Duration::from_secs(120)));
        assert_eq!(timeout_of("3S"), Some(Duration::from_secs(3)));
        assert_eq!(timeout_of("250m"), Some(Duration::from_millis(250)));
        assert_eq!(
            timeout_of("99999999u"),
            Some(Duration::from_micros(99_999_999))
        );
        assert_eq!(timeout_of("7n"), Some(Duration::from_nanos(7)));
        for bad in ["", "m", "123456789m", "12x", "-1S", "1.5S", "1 S", "é"] {
            assert_eq!(timeout_of(bad), None, "{bad:?}");
        }
    }

    #[test]
    fn the_margin_is_a_tenth_capped_plus_a_little() {
        let ms = Duration::from_millis;
        assert_eq!(margin(ms(1000)), ms(105));
        assert_eq!(margin(ms(10_000)), ms(255));
        assert_eq!(margin(ms(3_600_000)), ms(255));
        // Never more than half: a tiny deadline still leaves the solve
        // time for its initial rollout.
        assert_eq!(margin(ms(8)), ms(4));
    }
}
