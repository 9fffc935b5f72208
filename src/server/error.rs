//! RFC 9457 problem documents: every error the service returns.
//!
//! Each variant of [`ApiError`] is one kind of failure with one HTTP status
//! and one `type` URI, so clients can branch on either. Validation errors
//! carry `errors`, a list of JSON pointers into the request with what was
//! expected at each. Internal failures are logged with their cause but shown
//! to the client only as "internal error" with the request id.

use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use crate::problem::{FieldError, Invalid};
use crate::service::{OverloadCause, SolveError};

/// Media type of problem documents.
pub const PROBLEM_JSON: &str = "application/problem+json";

/// An RFC 9457 problem document.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct Problem {
    /// A URI naming the kind of problem, `urn:ilqr-service:` and one of
    /// `validation` (422), `malformed-json` (400), `unreadable-body` (400),
    /// `request-timeout` (408), `payload-too-large` (413),
    /// `unsupported-media-type` (415), `not-found` (404),
    /// `method-not-allowed` (405), `overloaded` (503, retry after
    /// `retry_after`), `expired-in-queue` (503: the time budget ran out
    /// while the solve waited for a worker, nothing was solved; retry after
    /// `retry_after`), `shutting-down` (503, retry on another instance) or
    /// `internal` (500). A string, not an enum: kinds may be added.
    #[serde(rename = "type")]
    pub kind: String,
    /// Short summary of the kind of problem.
    pub title: String,
    /// The HTTP status code.
    #[schema(minimum = 400, maximum = 599)]
    pub status: u16,
    /// What went wrong in this request.
    pub detail: String,
    /// For validation errors: every offending field, up to the first 100
    /// (and 64 KiB of pointers and messages after the first, which counts
    /// when a key is huge); keys given twice first, then wrong types, lengths and unknown
    /// fields, then values out of range. A wrong type inside an array
    /// element can hide other errors in the same array. When `detail` ends
    /// with "(checking stopped here: …)", the document was not checked to
    /// its end and more values may be invalid.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub errors: Vec<FieldError>,
    /// For validation errors past that cap: how many more invalid values
    /// were found than `errors` lists. Absent when `errors` lists them all.
    // Left out when None, never `null` (as `retry_after`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(nullable = false, minimum = 1)]
    pub unlisted_errors: Option<u64>,
    /// Seconds to wait before retrying (`overloaded` and
    /// `expired-in-queue` only; also sent as the `Retry-After` header).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(nullable = false, minimum = 1)]
    pub retry_after: Option<u64>,
}

/// What a 503 `overloaded` ran out of.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Overload {
    /// Every worker is busy and the queue is full.
    Queue,
    /// The solves ahead in the queue would take longer, by the measured
    /// service time, than the solve's budget allows it to wait.
    Wait {
        /// The estimated wait, in ms.
        wait_ms: u64,
        /// The solve's time budget, in ms.
        budget_ms: u64,
    },
    /// The bodies being read hold `--max-inflight-body-bytes`.
    Bodies,
    /// The answers being sent hold as many bytes (clients reading slowly
    /// or not at all); the solve ran, its answer is dropped.
    Answers,
    /// The answers being sent hold the whole budget already: refused
    /// before solving.
    AnswersFull,
}

/// Every way a request can fail.
#[derive(Debug, Clone, PartialEq)]
pub enum ApiError {
    /// The body is not JSON (400).
    MalformedJson(String),
    /// The body is JSON but not a valid problem (422).
    Validation(Invalid),
    /// `Content-Type` is missing, not JSON or not UTF-8, or the body is
    /// compressed (415); the detail says which, and what was received.
    UnsupportedMediaType(String),
    /// The body exceeds the configured limit (413).
    PayloadTooLarge(usize),
    /// The body did not arrive within the read timeout, in s (408).
    RequestTimeout(u64),
    /// The body could not be read: the connection broke, or its framing
    /// (chunked encoding) is invalid (400).
    UnreadableBody(String),
    /// The client closed its connection before its body arrived (499,
    /// nginx's code; nobody receives the answer, which exists for the
    /// access log and `http_requests_total`).
    ClientLeft,
    /// The solver queue is full, or the request bodies being received take
    /// all of their memory budget (503 with `Retry-After`).
    Overloaded { retry_after: u64, cause: Overload },
    /// Admitted, but the time budget ran out while the solve waited for a
    /// worker, so nothing was solved (503 with `Retry-After`).
    ExpiredInQueue {
        /// Time it waited, in ms.
        waited_ms: u64,
        /// Its time budget, in ms.
        budget_ms: u64,
        /// Seconds to wait before retrying, at least 1.
        retry_after: u64,
    },
    /// The service is shutting down (503).
    ShuttingDown,
    /// A bug: a solver panic or a lost worker (500).
    Internal,
    /// No such route (404): the detail echoes the request's method and
    /// path, and suggests the route a near miss meant.
    NotFound(String),
    /// Wrong method for the route (405): the detail echoes the request's
    /// method and path.
    MethodNotAllowed(String),
    /// A query parameter the route does not take, or a value it cannot
    /// read (400); the detail names the parameter and what it takes.
    BadQuery(String),
}

impl ApiError {
    fn parts(&self) -> (StatusCode, &'static str, &'static str) {
        match self {
            Self::MalformedJson(_) => (StatusCode::BAD_REQUEST, "malformed-json", "Malformed JSON"),
            Self::Validation(_) => (
                StatusCode::UNPROCESSABLE_ENTITY,
                "validation",
                "Invalid problem",
            ),
            Self::UnsupportedMediaType(_) => (
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
                "unsupported-media-type",
                "Unsupported media type",
            ),
            Self::PayloadTooLarge(_) => (
                StatusCode::PAYLOAD_TOO_LARGE,
                "payload-too-large",
                "Request body too large",
            ),
            Self::RequestTimeout(_) => (
                StatusCode::REQUEST_TIMEOUT,
                "request-timeout",
                "Request body too slow",
            ),
            Self::UnreadableBody(_) => (
                StatusCode::BAD_REQUEST,
                "unreadable-body",
                "Request body unreadable",
            ),
            Self::Overloaded { .. } => (
                StatusCode::SERVICE_UNAVAILABLE,
                "overloaded",
                "Service overloaded",
            ),
            Self::ExpiredInQueue { .. } => (
                StatusCode::SERVICE_UNAVAILABLE,
                "expired-in-queue",
                "Time budget spent in the queue",
            ),
            Self::ClientLeft => (
                StatusCode::from_u16(499).unwrap_or(StatusCode::BAD_REQUEST),
                "client-left",
                "Client closed request",
            ),
            Self::ShuttingDown => (
                StatusCode::SERVICE_UNAVAILABLE,
                "shutting-down",
                "Service shutting down",
            ),
            Self::Internal => (
                StatusCode::INTERNAL_SERVER_ERROR,
                "internal",
                "Internal error",
            ),
            Self::NotFound(_) => (StatusCode::NOT_FOUND, "not-found", "Not found"),
            Self::BadQuery(_) => (
                StatusCode::BAD_REQUEST,
                "bad-query",
                "Invalid query parameter",
            ),
            Self::MethodNotAllowed(_) => (
                StatusCode::METHOD_NOT_ALLOWED,
                "method-not-allowed",
                "Method not allowed",
            ),
        }
    }

    /// The `reason` label of `solve_rejections_total` for this error.
    pub fn reason(&self) -> &'static str {
        match self {
            Self::MalformedJson(_) => "malformed_json",
            Self::Validation(_) => "invalid",
            Self::UnsupportedMediaType(_) => "unsupported_media_type",
            Self::PayloadTooLarge(_) => "too_large",
            Self::RequestTimeout(_) => "body_timeout",
            Self::UnreadableBody(_) => "unreadable_body",
            Self::Overloaded {
                cause: Overload::Queue,
                ..
            } => "queue_full",
            Self::Overloaded {
                cause: Overload::Wait { .. },
                ..
            } => "queue_wait",
            Self::Overloaded {
                cause: Overload::Bodies,
                ..
            } => "body_budget",
            Self::Overloaded {
                cause: Overload::Answers | Overload::AnswersFull,
                ..
            } => "answer_budget",
            Self::ExpiredInQueue { .. } => "expired_in_queue",
            Self::ClientLeft => "client_left",
            Self::ShuttingDown => "shutting_down",
            Self::Internal => "internal",
            Self::NotFound(_) => "not_found",
            Self::MethodNotAllowed(_) => "method_not_allowed",
            Self::BadQuery(_) => "bad_query",
        }
    }

    /// Appended to a validation error's `detail` when the parser's budget for
    /// re-reading the document ran out (see `problem::parse`).
    pub const INCOMPLETE: &str = " (checking stopped here: more values may be invalid; \
                              fix these and send it again)";

    /// The problem document for this error.
    pub fn problem(&self) -> Problem {
        let (status, slug, title) = self.parts();
        let (detail, errors, retry_after) = match self {
            Self::MalformedJson(msg) => {
                (format!("the body is not valid JSON: {msg}"), vec![], None)
            }
            Self::Validation(invalid) => {
                let mut detail = match (invalid.errors.as_slice(), invalid.unlisted) {
                    // The pointer is given whole in `errors`; here at most
                    // a few hundred characters of it, so that a huge key is
                    // not echoed twice.
                    ([one], 0) => format!(
                        "{}: {}",
                        crate::problem::elide(label(&one.pointer).to_owned()),
                        one.detail
                    ),
                    (many, 0) => format!("{} invalid fields; see `errors`", many.len()),
                    (listed, unlisted) => format!(
                        "{} invalid values; `errors` lists the first {} and \
                         `unlisted_errors` counts the other {unlisted}",
                        listed.len() + unlisted,
                        listed.len(),
                    ),
                };
                if invalid.incomplete {
                    detail.push_str(Self::INCOMPLETE);
                }
                (detail, invalid.errors.clone(), None)
            }
            Self::UnsupportedMediaType(detail) => (detail.clone(), vec![], None),
            Self::PayloadTooLarge(limit) => (
                format!("the body exceeds the limit of {limit} bytes"),
                vec![],
                None,
            ),
            Self::RequestTimeout(secs) => (
                format!("the body did not arrive within {secs} s"),
                vec![],
                None,
            ),
            Self::UnreadableBody(msg) => {
                (format!("the body could not be read: {msg}"), vec![], None)
            }
            Self::Overloaded { retry_after, cause } => (
                match cause {
                    Overload::Queue => format!(
                        "every worker is busy and the queue is full; retry in {retry_after} s"
                    ),
                    Overload::Wait { wait_ms, budget_ms } => format!(
                        "the solves queued ahead would take about {wait_ms} ms (by the measured \
                         time per solve) before a worker could start this one, too long for its \
                         time budget of {budget_ms} ms; nothing was solved; retry in \
                         {retry_after} s, or with a larger solver.time_limit_ms"
                    ),
                    Overload::Bodies => format!(
                        "too many request bodies are being received at once; \
                         retry in {retry_after} s"
                    ),
                    Overload::Answers => format!(
                        "the answers still being sent to other clients hold the memory \
                         budget for answers (clients reading slowly); the solve ran but \
                         its answer was dropped; retry in {retry_after} s"
                    ),
                    Overload::AnswersFull => format!(
                        "the answers still being sent to other clients hold the whole \
                         memory budget for answers (clients reading slowly); nothing was \
                         solved; retry in {retry_after} s"
                    ),
                },
                vec![],
                Some(*retry_after),
            ),
            Self::ExpiredInQueue {
                waited_ms,
                budget_ms,
                retry_after,
            } => (
                format!(
                    "the solve waited {waited_ms} ms for a worker and its time budget of \
                     {budget_ms} ms ran out before it could start (the solves ahead took longer \
                     than estimated); nothing was solved; retry in {retry_after} s"
                ),
                vec![],
                Some(*retry_after),
            ),
            Self::ClientLeft => (
                "the client closed the connection before its body arrived".into(),
                vec![],
                None,
            ),
            Self::ShuttingDown => (
                "the service is draining before shutdown; retry on another replica".into(),
                vec![],
                None,
            ),
            Self::Internal => (
                "the solve failed unexpectedly; the x-request-id header identifies it in the logs"
                    .into(),
                vec![],
                None,
            ),
            Self::NotFound(detail) | Self::MethodNotAllowed(detail) | Self::BadQuery(detail) => {
                (detail.clone(), vec![], None)
            }
        };
        let unlisted_errors = match self {
            Self::Validation(invalid) if invalid.unlisted > 0 => Some(invalid.unlisted as u64),
            _ => None,
        };
        Problem {
            kind: format!("urn:ilqr-service:{slug}"),
            title: title.into(),
            status: status.as_u16(),
            detail,
            errors,
            unlisted_errors,
            retry_after,
        }
    }

    /// The HTTP status.
    pub fn status(&self) -> StatusCode {
        self.parts().0
    }
}

fn label(pointer: &str) -> &str {
    if pointer.is_empty() {
        "(body)"
    } else {
        pointer
    }
}

/// Longest `detail` the access log keeps, in characters: a validation
/// detail can quote a few hundred characters of a key, and a log line is
/// read in a terminal or paid for by the byte.
const MAX_LOGGED_DETAIL_CHARS: usize = 300;

/// What the access log says of an error answer, carried to it in the
/// response's extensions (never sent): without it the line for a 4xx said
/// only `status=422`, and the reason was in the body, which is not logged.
#[derive(Debug, Clone)]
pub(crate) struct LoggedProblem {
    /// The problem's `type`.
    pub kind: String,
    /// The problem's `title`.
    pub title: &'static str,
    /// The problem's `detail`, cut to [`MAX_LOGGED_DETAIL_CHARS`]. It says
    /// what was wrong and may quote a short value; the body itself is never
    /// logged.
    pub detail: String,
    /// A 503 for overload: logged at `debug` only (see `AccessLog`).
    pub overloaded: bool,
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let problem = self.problem();
        let body = serde_json::to_vec(&problem).unwrap_or_default();
        let mut res = (self.status(), body).into_response();
        let headers = res.headers_mut();
        headers.insert(header::CONTENT_TYPE, HeaderValue::from_static(PROBLEM_JSON));
        if let Some(secs) = problem.retry_after {
            headers.insert(header::RETRY_AFTER, HeaderValue::from(secs));
        }
        if matches!(self, Self::ShuttingDown) {
            // hyper closes the connection after this answer: a pooled
            // client (requests.Session, a proxy's upstream pool) would
            // otherwise send its next request down the same connection to
            // this draining instance until it exits, where the detail says
            // to retry on another replica.
            headers.insert(header::CONNECTION, HeaderValue::from_static("close"));
        }
        let detail = crate::problem::clip(&problem.detail, MAX_LOGGED_DETAIL_CHARS).into_owned();
        res.extensions_mut().insert(LoggedProblem {
            kind: problem.kind,
            title: self.parts().2,
            detail,
            overloaded: matches!(self, Self::Overloaded { .. } | Self::ExpiredInQueue { .. }),
        });
        res
    }
}

/// Whole milliseconds of `d`, for a problem's detail.
fn whole_ms(d: std::time::Duration) -> u64 {
    u64::try_from(d.as_millis()).unwrap_or(u64::MAX)
}

impl From<SolveError> for ApiError {
    fn from(e: SolveError) -> Self {
        match e {
            SolveError::Invalid(invalid) => Self::Validation(invalid),
            SolveError::Overloaded { retry_after, cause } => Self::Overloaded {
                retry_after,
                cause: match cause {
                    OverloadCause::QueueFull => Overload::Queue,
                    OverloadCause::Wait { wait, budget } => Overload::Wait {
                        wait_ms: whole_ms(wait),
                        budget_ms: whole_ms(budget),
                    },
                    // The one check the HTTP transport passes
                    // (`SolveRequest::refuse_if`): its answer budget.
                    OverloadCause::Transport { .. } => Overload::AnswersFull,
                },
            },
            SolveError::ExpiredInQueue {
                waited,
                budget,
                retry_after,
            } => Self::ExpiredInQueue {
                waited_ms: whole_ms(waited),
                budget_ms: whole_ms(budget),
                retry_after,
            },
            SolveError::ShuttingDown => Self::ShuttingDown,
            SolveError::Internal => Self::Internal,
        }
    }
}
