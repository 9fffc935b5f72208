//! Routes, handlers and the OpenAPI document generated from them.

use std::sync::Arc;
use std::time::Duration;

use axum::Json;
use axum::extract::{FromRequest, Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use tower::ServiceBuilder;
use tower_http::catch_panic::CatchPanicLayer;
use tower_http::compression::{CompressionLayer, CompressionLevel};
use tower_http::request_id::{MakeRequestUuid, PropagateRequestIdLayer, SetRequestIdLayer};
use tower_http::trace::{OnResponse, TraceLayer};
use tracing::Instrument;
use utoipa::{OpenApi, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;
use utoipa_swagger_ui::SwaggerUi;

use super::body::{BodyRules, read_with};
use super::error::{ApiError, LoggedProblem, Overload, Problem};
use super::{AppState, metrics};
use crate::problem::wire::{ProblemDoc, WeightsDoc};
use crate::problem::{OutputSpec, ParseError, ProblemSpec, SolverSpec, clip, parse};
use crate::service::{Encoding, SolveRequest, Transport, count_rejection};
use crate::solve::SolveResult;

/// The OpenAPI document's fixed parts; paths come from the router.
#[derive(OpenApi)]
#[openapi(
    info(
        title = "ilqr-service",
        description = "Trajectory optimisation with iLQR for a planar quadrotor. POST a problem \
                       (every field optional: `{}` is the seed scenario) and get back the optimal \
                       trajectory, the time-varying feedback gains and the iteration trace. \
                       Errors are RFC 9457 problem documents (`application/problem+json`), \
                       on every route: an unknown path is 404 and a wrong method 405. \
                       Only requests the HTTP layer itself cannot parse get an empty body \
                       and a closed connection: broken framing (a malformed request line or \
                       `Content-Length`, or a Transfer-Encoding that does not end in \
                       `chunked`) is 400; a request target (path and query) of \
                       65535 bytes or more is 414; more than 100 header fields, or a request \
                       head over about 400 KiB, is 431."
    ),
    // Referenced only through `schema::object_or_null`, which utoipa does
    // not follow to collect them as it does a field's own type.
    components(schemas(
        WeightsDoc,
        SolverSpec,
        OutputSpec,
        crate::problem::Obstacle,
        crate::problem::ObstacleShape,
        crate::problem::ConstraintsSpec,
        crate::problem::Bounds
    )),
    tags(
        (name = "solve", description = "Trajectory solves"),
        (name = "operations", description = "Health, readiness, metrics and this documentation")
    )
)]
pub struct ApiDoc;

fn api_router() -> OpenApiRouter<Arc<AppState>> {
    OpenApiRouter::with_openapi(ApiDoc::openapi())
        .routes(routes!(solve))
        .routes(routes!(solve_stream))
        .routes(routes!(default_problem))
        .routes(routes!(list_models))
        .routes(routes!(healthz))
        .routes(routes!(readyz))
        .routes(routes!(metrics_text))
}

/// The OpenAPI document (no server state needed).
pub fn openapi() -> utoipa::openapi::OpenApi {
    with_docs_routes(api_router().split_for_parts().1)
}

/// Adds the two routes Swagger UI serves to the spec. They are not handlers
/// of ours, so utoipa cannot derive them; without this a reader of the spec
/// would not learn that the service documents itself.
fn with_docs_routes(mut spec: utoipa::openapi::OpenApi) -> utoipa::openapi::OpenApi {
    use utoipa::openapi::path::{HttpMethod, OperationBuilder};
    use utoipa::openapi::schema::{ObjectBuilder, Type};
    use utoipa::openapi::{Content, ResponseBuilder};
    // Swagger UI shows a summary as plain text (Markdown only in the
    // description), so summaries are one short sentence without code marks.
    let get = |id: &str,
               [summary, details]: [&str; 2],
               content_type: &str,
               description: &str,
               schema: Type| {
        OperationBuilder::new()
            .tag("operations")
            .operation_id(Some(id))
            .summary(Some(summary))
            .description(Some(details))
            .response(
                "200",
                ResponseBuilder::new().description(description).content(
                    content_type,
                    Content::new(Some(ObjectBuilder::new().schema_type(schema))),
                ),
            )
            .build()
    };
    spec.paths.add_path_operation(
        "/openapi.json",
        vec![HttpMethod::Get],
        get(
            "openapi_json",
            [
                "This OpenAPI 3.1 document.",
                "With this server's limits on `horizon` and `time_limit_ms` \
                 (`ilqr-service openapi` prints the code's).",
            ],
            "application/json",
            "The OpenAPI document",
            Type::Object,
        ),
    );
    spec.paths.add_path_operation(
        "/docs/",
        vec![HttpMethod::Get],
        get(
            "docs",
            [
                "Swagger UI for this document.",
                "Served from the binary (no internet needed); `/docs` redirects here.",
            ],
            "text/html",
            "The Swagger UI page",
            Type::String,
        ),
    );
    with_request_id_header(for_generators(spec))
}

/// What code generators need beyond what utoipa derives (found by
/// generating clients with openapi-python-client, datamodel-code-generator
/// and openapi-generator):
///
/// * a 404 and a 405 problem on every operation: any route answers them (a
///   wrong base URL or path prefix, a wrong method), and a generated client
///   dropped the problem document of an undeclared status (`None`);
/// * no object `default` on a property that is a `$ref`: utoipa
///   writes the whole default object there, which openapi-generator turns
///   into Go that does not compile, while the referenced schema already has
///   a default per field;
/// * `Retry-After`'s schema says at least 1, as its description does
///   (utoipa's response headers take a description only).
fn for_generators(spec: utoipa::openapi::OpenApi) -> utoipa::openapi::OpenApi {
    use serde_json::{Value, json};
    let Ok(mut doc) = serde_json::to_value(&spec) else {
        return spec;
    };
    let problem = |description: &str| {
        json!({
            "description": description,
            "content": {super::error::PROBLEM_JSON: {"schema": {"$ref": "#/components/schemas/Problem"}}}
        })
    };
    if let Some(paths) = doc.get_mut("paths").and_then(Value::as_object_mut) {
        for item in paths.values_mut().filter_map(Value::as_object_mut) {
            for operation in item.values_mut() {
                let Some(responses) = operation
                    .get_mut("responses")
                    .and_then(Value::as_object_mut)
                else {
                    continue;
                };
                responses.entry("404").or_insert_with(|| {
                    problem("No such route: a wrong path, or a wrong base URL or path prefix")
                });
                let answer = responses
                    .entry("405")
                    .or_insert_with(|| problem("A method this path does not answer"));
                answer["headers"]["Allow"] = json!({
                    "description": "The methods this path answers, e.g. `GET,HEAD`",
                    "schema": {"type": "string"}
                });
            }
        }
    }
    if let Some(schemas) = doc
        .pointer_mut("/components/schemas")
        .and_then(Value::as_object_mut)
    {
        for schema in schemas.values_mut() {
            let Some(properties) = schema.get_mut("properties").and_then(Value::as_object_mut)
            else {
                continue;
            };
            for property in properties.values_mut().filter_map(Value::as_object_mut) {
                if property.contains_key("$ref")
                    && property.get("default").is_some_and(Value::is_object)
                {
                    property.remove("default");
                }
            }
        }
    }
    if let Some(retry_after) = doc
        .pointer_mut("/paths/~1solve/post/responses/503/headers/Retry-After/schema")
        .and_then(Value::as_object_mut)
    {
        retry_after.insert("minimum".into(), 1.into());
    }
    serde_json::from_value(doc).unwrap_or(spec)
}

/// Declares `x-request-id` on every response of every operation, since the
/// middleware sets it on all of them: a generated client can then read it
/// without knowing it from the prose. Not on 414 and 431, which the HTTP
/// layer answers before any middleware runs (nor on its framing 400s, which
/// share the 400 entry with ours). Responses given by reference (none
/// today) are left alone.
fn with_request_id_header(mut spec: utoipa::openapi::OpenApi) -> utoipa::openapi::OpenApi {
    use utoipa::openapi::RefOr;
    use utoipa::openapi::header::HeaderBuilder;
    let header = HeaderBuilder::new()
        .description(Some(
            "The request's id, for finding it in the logs: the client's own \
             `x-request-id` if it sent a usable one (1 to 128 visible ASCII \
             characters), otherwise a new UUID",
        ))
        .build();
    for item in spec.paths.paths.values_mut() {
        for operation in [
            &mut item.get,
            &mut item.put,
            &mut item.post,
            &mut item.delete,
            &mut item.options,
            &mut item.head,
            &mut item.patch,
            &mut item.trace,
        ]
        .into_iter()
        .flatten()
        {
            for (status, response) in &mut operation.responses.responses {
                if let (false, RefOr::T(response)) = (is_http_layer_status(status), response) {
                    response
                        .headers
                        .insert("x-request-id".into(), header.clone().into());
                }
            }
        }
    }
    spec
}

/// The statuses hyper answers itself, before any middleware or route runs
/// (empty body, no `x-request-id`, not in `/metrics`).
fn is_http_layer_status(status: &str) -> bool {
    matches!(status, "414" | "431")
}

/// The spec as this server serves it: the limits its configuration sets
/// (`--max-horizon`, `--max-time-limit-ms`) in place of the code's
/// defaults, and with `--default-time-limit-ms` in the budget's
/// description, so that a client validating against the served spec gets
/// this server's bounds; and a relative `servers` entry. The committed
/// `openapi/openapi.json` and `ilqr-service openapi` keep the defaults.
fn with_limits(
    config: &super::Config,
) -> impl FnOnce(utoipa::openapi::OpenApi) -> utoipa::openapi::OpenApi + use<> {
    let (max_horizon, max_ms, default_ms) = (
        config.max_horizon,
        config.max_time_limit_ms,
        config.default_time_limit_ms,
    );
    move |spec| {
        let Ok(mut doc) = serde_json::to_value(&spec) else {
            return spec;
        };
        // Each limit and this server's default budget in the description
        // too: a generated client shows descriptions, not the code's. The
        // budget's default stays null ("the service's default"): a default
        // of 10000 in the schema made a generated client send it, overriding
        // a server configured differently (a 422 where its maximum was 5000).
        let append = |doc: &mut serde_json::Value, pointer: &str, text: String| {
            if let Some(serde_json::Value::String(description)) = doc.pointer_mut(pointer) {
                description.push_str(&text);
            }
        };
        if let Some(horizon) =
            doc.pointer_mut("/components/schemas/ProblemSpec/properties/horizon/maximum")
        {
            *horizon = max_horizon.into();
        }
        append(
            &mut doc,
            "/components/schemas/ProblemSpec/properties/horizon/description",
            format!(" This server's maximum: {max_horizon}."),
        );
        if let Some(ms) = doc
            .pointer_mut("/components/schemas/SolverSpec/properties/time_limit_ms")
            .and_then(serde_json::Value::as_object_mut)
        {
            ms.insert("maximum".into(), max_ms.into());
        }
        append(
            &mut doc,
            "/components/schemas/SolverSpec/properties/time_limit_ms/description",
            format!(" This server's default: {default_ms} ms; its maximum: {max_ms} ms."),
        );
        // The example is the seed problem as GET /problems/default gives
        // it, with this server's budget filled in (an example is not sent
        // by generated clients, unlike a default).
        if let Some(ms) =
            doc.pointer_mut("/components/schemas/ProblemSpec/example/solver/time_limit_ms")
        {
            *ms = default_ms.into();
        }
        // Without `servers`, OpenAPI's default is `/`, the host's root:
        // Swagger UI's "Try it out" behind a proxy that adds a path prefix
        // then posts to `host/solve`, outside the prefix. `.` is relative
        // to where this document is served, prefix included. (The
        // committed file, which is not served from anywhere, has none.)
        if let Some(doc) = doc.as_object_mut() {
            doc.insert(
                "servers".into(),
                serde_json::json!([{
                    "url": ".",
                    "description": "this server: the directory this document is served from"
                }]),
            );
        }
        serde_json::from_value(doc).unwrap_or(spec)
    }
}

/// The OpenAPI document as pretty JSON, as committed in `openapi/openapi.json`.
pub fn openapi_json() -> String {
    openapi()
        .to_pretty_json()
        .unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
}

/// The whole application: routes, docs and middleware.
pub fn app(state: Arc<AppState>) -> axum::Router {
    let gzip_level = state.config.gzip_level;
    let limits = with_limits(&state.config);
    let (router, spec) = api_router().with_state(state).split_for_parts();
    let spec = limits(with_docs_routes(spec));
    let router = router
        .merge(
            // The page fetches the spec by a relative URL, so /docs/ still
            // finds it behind a proxy that adds a path prefix
            // (/ilqr/docs/ → /ilqr/openapi.json).
            axum::Router::from(
                SwaggerUi::new("/docs").url("/openapi.json", spec).config(
                    utoipa_swagger_ui::Config::new(["../openapi.json"])
                        // Swagger UI's default sends the spec's URL to
                        // validator.swagger.io for a badge, from any
                        // host but localhost: offline a broken image,
                        // online a leak of an internal address.
                        .validator_url("none"),
                ),
            )
            .layer(axum::middleware::from_fn(docs_fixes)),
        )
        .fallback(not_found)
        .method_not_allowed_fallback(method_not_allowed)
        .layer(axum::middleware::from_fn(metrics::track));
    router.layer(
        ServiceBuilder::new()
            .map_request(drop_unusable_request_id)
            .layer(SetRequestIdLayer::x_request_id(MakeRequestUuid))
            .layer(
                TraceLayer::new_for_http()
                    // Every request leaves one line at `info` or above, in its
                    // span (so with its request id), and no more: a solve
                    // logs "solve finished", an error answer logs here.
                    // Other successes, and 503 overloaded, log at `debug`.
                    .on_response(AccessLog)
                    // Not tower-http's line per 5xx: it said only
                    // "response failed" with a classification string, and
                    // under overload it wrote a warning per 503 (12 MB/s
                    // of log at saturation). AccessLog covers 5xx too.
                    .on_failure(())
                    .make_span_with(|req: &Request| {
                        let id = req
                            .headers()
                            .get("x-request-id")
                            .and_then(|v| v.to_str().ok())
                            .unwrap_or("-");
                        // The URI may be as long as the head limit (400 KiB),
                        // and every line of the request's span repeats it. (A
                        // long request id was replaced already.)
                        tracing::info_span!(
                            "request",
                            request_id = %id,
                            method = %req.method(),
                            uri = %clip(&req.uri().to_string(), MAX_LOGGED_URI_CHARS),
                        )
                    }),
            )
            .layer(PropagateRequestIdLayer::x_request_id())
            .map_request(move |req| canonical_accept_encoding(req, gzip_level))
            // Small documents only (`/openapi.json`, `/metrics`, errors):
            // `/solve` answers are gzipped on the solver pool, see
            // [`encode`], and this layer leaves encoded bodies alone.
            .layer(CompressionLayer::new().quality(CompressionLevel::Precise(gzip_level as i32)))
            .layer(CatchPanicLayer::custom(|_| {
                ApiError::Internal.into_response()
            })),
    )
}

/// The per-response log line of the trace layer (see [`app`] for which
/// level each status gets).
#[derive(Clone, Copy)]
struct AccessLog;

impl<B> OnResponse<B> for AccessLog {
    fn on_response(self, res: &axum::http::Response<B>, latency: Duration, _: &tracing::Span) {
        let status = res.status().as_u16();
        let latency_ms = crate::solve::millis(latency);
        if !res.status().is_client_error() && !res.status().is_server_error() {
            tracing::debug!(status, latency_ms, "response");
            return;
        }
        // The reason, which an error's body gives the client, for whoever
        // reads the log; every ApiError carries it.
        let Some(p) = res.extensions().get::<LoggedProblem>() else {
            if res.status().is_server_error() {
                tracing::warn!(status, latency_ms, "response");
            } else {
                tracing::info!(status, latency_ms, "response");
            }
            return;
        };
        // A string, so the text format quotes it (it has spaces).
        let (problem_type, title, detail) = (p.kind.as_str(), p.title, p.detail.as_str());
        if p.overloaded {
            // Back-pressure working, counted in
            // solve_rejections_total{reason="queue_full", "body_budget" or
            // "answer_budget"}; a line each
            // would flood the log exactly when the service is busiest.
            tracing::debug!(status, latency_ms, problem_type, title, detail, "response");
        } else if res.status().is_server_error() && problem_type != "urn:ilqr-service:shutting-down"
        {
            tracing::warn!(status, latency_ms, problem_type, title, detail, "response");
        } else {
            // A 4xx, or a 503 shutting-down: expected during a drain (every
            // readiness probe gets one), so not a warning.
            tracing::info!(status, latency_ms, problem_type, title, detail, "response");
        }
    }
}

/// A JSON problem body: checks the content type, honours the body limit and
/// maps every failure to a problem document with a pointer.
pub struct ProblemJson(pub ProblemSpec);

impl FromRequest<Arc<AppState>> for ProblemJson {
    type Rejection = ApiError;

    async fn from_request(req: Request, state: &Arc<AppState>) -> Result<Self, Self::Rejection> {
        read_problem(req, state).await.map(Self).map_err(reject)
    }
}

async fn read_problem(req: Request, state: &Arc<AppState>) -> Result<ProblemSpec, ApiError> {
    let headers = req.headers();
    if let Some(detail) = chunked_more_than_once(headers) {
        return Err(ApiError::UnreadableBody(detail));
    }
    unsupported_media_type(headers)
        .map_or(Ok(()), |detail| Err(ApiError::UnsupportedMediaType(detail)))?;
    let rules = BodyRules {
        limit: state.config.max_body_bytes,
        timeout: Duration::from_secs(state.config.read_timeout_secs),
        budget: &state.bodies,
        retry_after: state.config.retry_after_secs,
    };
    read_with(req, &rules, |bytes| match parse(bytes) {
        Ok(spec) => Ok(spec),
        Err(ParseError::Syntax(msg)) => Err(ApiError::MalformedJson(msg)),
        Err(ParseError::Shape(shapes)) => Err(ApiError::Validation(
            shapes.with_range_errors(&state.config.limits()),
        )),
    })
    .await
}

/// Why the body's framing cannot be trusted when `Transfer-Encoding` names
/// `chunked` more than once (`chunked, chunked`, or on two field lines):
/// RFC 9112 §6.1 forbids a sender to apply it twice. hyper undoes one
/// layer and passes the rest on as the body, where a proxy in front may
/// have read the framing differently.
fn chunked_more_than_once(headers: &HeaderMap) -> Option<String> {
    let chunked = headers
        .get_all(header::TRANSFER_ENCODING)
        .iter()
        .flat_map(|v| v.as_bytes().split(|&b| b == b','))
        .filter(|c| c.trim_ascii().eq_ignore_ascii_case(b"chunked"))
        .count();
    (chunked > 1).then(|| {
        let all: Vec<&[u8]> = headers
            .get_all(header::TRANSFER_ENCODING)
            .iter()
            .map(HeaderValue::as_bytes)
            .collect();
        format!(
            "its Transfer-Encoding applies chunked {chunked} times ({}), which RFC 9112 \
             forbids (a sender applies it once); send it with `Transfer-Encoding: chunked` \
             or a Content-Length",
            shown(&all.join(&b", "[..]))
        )
    })
}

/// Why the body cannot be read as a problem, going by its headers (the
/// detail of a 415), or `None` if it can: uncompressed JSON in UTF-8.
/// Each cause is told apart and what was received is echoed, since the
/// fix differs: `curl -d` without `-H` sends a form's media type, a
/// client library may add a charset or compress the body.
fn unsupported_media_type(headers: &HeaderMap) -> Option<String> {
    // Every field line and every list member counts: the first line alone
    // let `identity` then `gzip` through to a "not UTF-8" 400.
    let other_than = |name: header::HeaderName, plain: &'static [u8]| {
        headers.get_all(name).iter().find(|v| {
            v.as_bytes()
                .split(|&b| b == b',')
                .map(<[u8]>::trim_ascii)
                .any(|coding| !coding.is_empty() && !coding.eq_ignore_ascii_case(plain))
        })
    };
    if let Some(coding) = other_than(header::CONTENT_ENCODING, b"identity") {
        return Some(format!(
            "the body is compressed (Content-Encoding: {}); send it uncompressed, \
             as this service reads no compressed requests",
            shown(coding.as_bytes())
        ));
    }
    // hyper undoes `chunked` only, and answers an empty 400 itself unless
    // `chunked` comes last; a coding before it (`gzip, chunked`) would
    // reach the parser undone.
    if let Some(coding) = other_than(header::TRANSFER_ENCODING, b"chunked") {
        return Some(format!(
            "the body has a transfer coding besides chunked (Transfer-Encoding: {}); \
             send it with `chunked` alone or a Content-Length, as this service \
             undoes no other transfer coding",
            shown(coding.as_bytes())
        ));
    }
    const SEND: &str = "send the problem as UTF-8 JSON with `Content-Type: application/json`";
    let mut types = headers.get_all(header::CONTENT_TYPE).iter();
    let Some(value) = types.next() else {
        return Some(format!("the request has no Content-Type; {SEND}"));
    };
    // RFC 9110 §5.3: Content-Type is a singleton; which of two different
    // ones to believe is a guess (the first was taken, `text/plain` after
    // it ignored). The same one repeated says the same thing.
    if types.any(|other| other != value) {
        return Some(format!(
            "the request has {} different Content-Type header fields: send one, \
             `Content-Type: application/json`, with the problem as UTF-8 JSON",
            headers.get_all(header::CONTENT_TYPE).iter().count()
        ));
    }
    let Ok(ct) = value.to_str() else {
        return Some(format!(
            "the Content-Type {} is not plain ASCII text; {SEND}",
            shown(value.as_bytes())
        ));
    };
    let mut parts = split_params(ct);
    let essence = parts.next().unwrap_or("").trim().to_ascii_lowercase();
    // `application/*+json` too (RFC 6839 structured syntax suffix), as
    // axum's `Json` takes it.
    let json = essence == "application/json"
        || essence
            .strip_prefix("application/")
            .and_then(|subtype| subtype.strip_suffix("+json"))
            .is_some_and(|name| !name.is_empty());
    if essence == "application/x-www-form-urlencoded" {
        return Some(format!(
            "the Content-Type is {}, a form, which is what `curl -d` sends unless \
             told otherwise: add -H 'content-type: application/json'",
            shown(ct.as_bytes())
        ));
    }
    if !json {
        return Some(format!(
            "the Content-Type is {}, which is not JSON (application/json or \
             application/*+json); {SEND}",
            shown(ct.as_bytes())
        ));
    }
    // The body is read as UTF-8, JSON's only encoding (RFC 8259 §8.1): a
    // charset that says otherwise would be misread, so it is refused.
    let other_charset = parts.find_map(|param| match param.split_once('=') {
        Some((name, value)) if name.trim().eq_ignore_ascii_case("charset") => {
            let charset = value.trim().trim_matches('"');
            // `utf8` is a common label of UTF-8 too (WHATWG Encoding), and
            // ASCII is a subset of it.
            let utf8 = ["utf-8", "utf8", "us-ascii"]
                .iter()
                .any(|c| charset.eq_ignore_ascii_case(c));
            (!utf8).then_some(charset)
        }
        _ => None,
    });
    other_charset.map(|charset| {
        format!(
            "the Content-Type names the charset {}, but the body is read as UTF-8 \
             JSON (its only encoding): send UTF-8, with charset=utf-8 or no charset",
            shown(charset.as_bytes())
        )
    })
}

/// Longest piece of a request (a header, a path) echoed in a problem's
/// `detail`, in characters.
const MAX_ECHOED_CHARS: usize = 100;

/// Longest URI a log line carries, in characters.
const MAX_LOGGED_URI_CHARS: usize = 200;

/// A header value or path as echoed in a `detail`, in backquotes: at most
/// [`MAX_ECHOED_CHARS`] characters of it (a header may be 400 KiB long), a
/// byte that is not UTF-8 as U+FFFD and a control character as `?`, so
/// the line stays one readable line. JSON escaping is serde_json's.
fn shown(bytes: &[u8]) -> String {
    let text = String::from_utf8_lossy(bytes);
    let out: String = clip(&text, MAX_ECHOED_CHARS)
        .chars()
        .map(|c| if c.is_control() { '?' } else { c })
        .collect();
    format!("`{out}`")
}

/// Splits a media type at the `;` that are outside quoted strings (RFC 9110
/// §5.6.4), so a parameter such as `foo="a;charset=latin1"` stays whole
/// instead of yielding a charset. Whitespace around the pieces is left for
/// the caller to trim.
fn split_params(media_type: &str) -> impl Iterator<Item = &str> {
    let (mut quoted, mut escaped) = (false, false);
    media_type.split(move |c: char| {
        if escaped {
            escaped = false;
            return false;
        }
        match c {
            '\\' if quoted => escaped = true,
            '"' => quoted = !quoted,
            ';' => return !quoted,
            _ => {}
        }
        false
    })
}

/// Solve a trajectory-optimisation problem.
///
/// Every field is optional and defaults to the seed scenario, so `{}` solves
/// the paper's problem. The solve runs on the worker pool within its time
/// budget, which runs from admission (time spent queued counts); how it
/// ended is `status` in a 200 answer. Only invalid input is an error, and
/// overload a 503: a solve that could not start before its budget is spent
/// is refused at once, or, if its wait was underestimated, answered when
/// its budget runs out in the queue.
#[utoipa::path(
    post,
    path = "/solve",
    tag = "solve",
    request_body(content = ProblemDoc, content_type = "application/json"),
    responses(
        (status = 200, description = "Solved (see `status` for how the solve ended)", body = SolveResult,
            headers(("Server-Timing" = String, description = "Milliseconds spent queued, solving, and serialising plus compressing the answer (all three within the time budget), e.g. `queue;dur=0.02, solve;dur=0.35, encode;dur=0.61`"))),
        (status = 400, description = "The body is not JSON, or could not be read (broken chunked encoding, a Transfer-Encoding that applies `chunked` more than once, connection lost)", body = Problem, content_type = "application/problem+json"),
        (status = 408, description = "The body did not arrive within the read timeout", body = Problem, content_type = "application/problem+json"),
        (status = 405, description = "A method other than POST", body = Problem, content_type = "application/problem+json"),
        (status = 413, description = "The body is over the size limit: refused before it is read when its Content-Length or, chunked, its chunk-size lines declare more", body = Problem, content_type = "application/problem+json"),
        (status = 415, description = "Content-Type is missing, given twice, not JSON (`application/json` or `application/*+json`) or names a charset other than UTF-8; or the body is compressed (a Content-Encoding other than `identity`, or a transfer coding before `chunked`)", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "Invalid problem; `errors` has a JSON pointer per field", body = Problem, content_type = "application/problem+json"),
        (status = 414, description = "A request target (path and query) of 65535 bytes or more: answered by the HTTP layer with an empty body, then the connection closes"),
        (status = 431, description = "More than 100 header fields, or a request head over about 400 KiB: answered by the HTTP layer with an empty body, then the connection closes"),
        (status = 500, description = "A bug (never caused by input)", body = Problem, content_type = "application/problem+json"),
        (status = 503, description = "Overloaded (`overloaded`, with Retry-After, refused at once and nothing solved unless said: the solver queue is full; the solves queued ahead would take longer, by the measured time per solve, than this solve's time budget allows it to wait; the request bodies being received hold the server's memory budget for bodies; or the answers still being sent to slow readers hold the budget for answers: refused before solving when they hold all of it, otherwise the solve ran and its answer was dropped), expired in the queue (`expired-in-queue`, with Retry-After: admitted, but its time budget ran out while it waited for a worker, because the solves ahead took longer than estimated; it never ran) or shutting down (`shutting-down`: also a solve still queued when the shutdown's grace period ends)", body = Problem, content_type = "application/problem+json",
            headers(("Retry-After" = u64, description = "Whole seconds to wait before retrying, at least 1 (`--retry-after-secs`, default 1): for a solve that could not have started in time, or one that expired in the queue, how late it would start by the current queue, if that is more. Sent with `overloaded` and `expired-in-queue`: a `shutting-down` answer has none and closes the connection (retry on a new one, which a load balancer sends to another instance)"))),
    )
)]
async fn solve(
    State(st): State<Arc<AppState>>,
    headers: HeaderMap,
    ProblemJson(spec): ProblemJson,
) -> Result<Response, ApiError> {
    // Canonical by now (see `canonical_accept_encoding`): `gzip`, set only
    // when the client admits gzip and the level is not 0, or absent.
    let gzip = headers
        .contains_key(header::ACCEPT_ENCODING)
        .then_some(st.config.gzip_level);
    // Answers to slow readers fill the budget for answers: nothing solved
    // now could be sent, so the service refuses before spending a solve.
    let answers = Arc::clone(&st.answers);
    let request = SolveRequest::new(spec, Transport::Http)
        .encoding(if gzip.is_some() {
            Encoding::JsonGzip
        } else {
            Encoding::Json
        })
        .refuse_if("answer_budget", move || answers.is_full());
    // Serialised and compressed on the worker: a long horizon's result is
    // megabytes of JSON, CPU work the async runtime should not do. The
    // service keeps its time back from the budget; Server-Timing reports
    // it.
    let solved = st
        .service
        .solve(request, move |r| Ok(encode(r.to_json()?, gzip)))
        .await
        .map_err(ApiError::from)?;
    let timing = format!(
        "queue;dur={}, solve;dur={}, encode;dur={}",
        solved.queue_ms, solved.solve_ms, solved.encode_ms
    );
    let Encoded { bytes, gzip } = solved.answer;
    let Ok(bytes) = st.answers.hold(bytes) else {
        return Err(reject(ApiError::Overloaded {
            retry_after: st.config.retry_after_secs,
            cause: Overload::Answers,
        }));
    };
    let mut res = (
        [
            (
                header::CONTENT_TYPE,
                HeaderValue::from_static("application/json"),
            ),
            (header::VARY, HeaderValue::from_static("accept-encoding")),
        ],
        axum::body::Body::from(bytes),
    )
        .into_response();
    if gzip {
        res.headers_mut()
            .insert(header::CONTENT_ENCODING, HeaderValue::from_static("gzip"));
    }
    // Digits, letters and punctuation only: always a valid value.
    if let Ok(timing) = HeaderValue::from_str(&timing) {
        res.headers_mut().insert("server-timing", timing);
    }
    Ok(res)
}

/// An event of `/solve/stream`, for the OpenAPI document only
/// ([`crate::schema::stream_event`]).
struct StreamEventDoc;

impl utoipa::PartialSchema for StreamEventDoc {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        crate::schema::stream_event().into()
    }
}

impl utoipa::ToSchema for StreamEventDoc {
    fn name() -> std::borrow::Cow<'static, str> {
        "StreamEvent".into()
    }
}

/// Solve, streaming progress as Server-Sent Events.
///
/// The same problem, validation and solve as `POST /solve`, answered as
/// `text/event-stream`: one `iteration` event per iteration as it ends
/// (its data a trace row, as in the result's `trace`), then one `result`
/// event (its data the whole result, as `/solve` answers it), or one
/// `error` event (its data a problem document) if the solve could not be
/// answered after the stream began (its budget ran out while queued, the
/// service shut down, a bug). What is refused before the stream begins
/// (invalid input, overload, a draining service) is answered as by
/// `/solve`: a problem document with its status. A client that closes
/// the stream cancels the solve. Works with `curl -N` and with
/// `EventSource`-style readers that can POST.
#[utoipa::path(
    post,
    path = "/solve/stream",
    tag = "solve",
    request_body(content = ProblemDoc, content_type = "application/json"),
    responses(
        (status = 200, description = "A stream of `iteration` events (data: a TraceEntry), then one `result` event (data: a SolveResult) or one `error` event (data: a Problem)", content_type = "text/event-stream", body = StreamEventDoc),
        (status = 400, description = "The body is not JSON, or could not be read", body = Problem, content_type = "application/problem+json"),
        (status = 408, description = "The body did not arrive within the read timeout", body = Problem, content_type = "application/problem+json"),
        (status = 413, description = "The body is over the size limit", body = Problem, content_type = "application/problem+json"),
        (status = 415, description = "Content-Type is not JSON, or the body is compressed", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "Invalid problem; `errors` has a JSON pointer per field", body = Problem, content_type = "application/problem+json"),
        (status = 500, description = "A bug (never caused by input)", body = Problem, content_type = "application/problem+json"),
        (status = 503, description = "Overloaded (with Retry-After) or shutting down, as for /solve", body = Problem, content_type = "application/problem+json",
            headers(("Retry-After" = u64, description = "Seconds to wait before retrying, with `overloaded`"))),
    )
)]
async fn solve_stream(
    State(st): State<Arc<AppState>>,
    ProblemJson(spec): ProblemJson,
) -> Result<Response, ApiError> {
    use axum::response::sse::{KeepAlive, Sse};
    let (events, stream) = tokio::sync::mpsc::unbounded_channel::<StreamEvent>();
    let rows = events.clone();
    let answers = Arc::clone(&st.answers);
    let request = SolveRequest::new(spec, Transport::Http)
        .refuse_if("answer_budget", move || answers.is_full())
        .progress(move |row| {
            // A closed stream (the client left) drops the row; the
            // solve is being cancelled.
            let _ = rows.send(StreamEvent::Iteration(row.clone()));
        });
    let pending = st
        .service
        .submit(request, |r| Ok(r.to_json()?))
        .map_err(ApiError::from)?;
    // The pending solve lives in a task of its own, until its answer is
    // sent or the client closes the stream (its receiver dropped): then
    // `pending` is dropped, which cancels the solve.
    tokio::spawn(
        async move {
            tokio::select! {
                done = pending.finish() => {
                    let last = match done {
                        Ok(solved) => StreamEvent::Result(solved.answer),
                        Err(e) => StreamEvent::Error(ApiError::from(e).problem()),
                    };
                    let _ = events.send(last);
                }
                () = events.closed() => {}
            }
        }
        .instrument(tracing::Span::current()),
    );
    Ok(Sse::new(EventStream(stream))
        .keep_alive(KeepAlive::default())
        .into_response())
}

/// What `/solve/stream` sends.
enum StreamEvent {
    Iteration(crate::solve::TraceEntry),
    /// The result, as JSON.
    Result(Vec<u8>),
    Error(Problem),
}

/// The events of one `/solve/stream`, as axum's SSE stream.
struct EventStream(tokio::sync::mpsc::UnboundedReceiver<StreamEvent>);

impl futures_core::Stream for EventStream {
    type Item = Result<axum::response::sse::Event, std::convert::Infallible>;

    fn poll_next(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Option<Self::Item>> {
        use axum::response::sse::Event;
        self.0.poll_recv(cx).map(|next| {
            next.map(|event| {
                // Serialising plain data types does not fail; if it ever
                // did, the event says so rather than the stream ending.
                let json = |value: serde_json::Result<String>| {
                    value.unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
                };
                Ok(match event {
                    StreamEvent::Iteration(row) => Event::default()
                        .event("iteration")
                        .data(json(serde_json::to_string(&row))),
                    StreamEvent::Result(bytes) => Event::default()
                        .event("result")
                        .data(String::from_utf8_lossy(&bytes)),
                    StreamEvent::Error(problem) => Event::default()
                        .event("error")
                        .data(json(serde_json::to_string(&problem))),
                })
            })
        })
    }
}

/// Whether a request's `Accept-Encoding` admits gzip (RFC 9110 §12.5.3):
/// named with a non-zero `q`, or not named while `*` has a non-zero `q`, and
/// not below `identity`'s `q` where that is named or `*` gives one
/// (`gzip;q=0.5, identity` and `gzip;q=0.5, *` prefer the answer
/// uncompressed; a tie goes to gzip). An item whose `q` is not a valid
/// qvalue (`0`–`1`, at most three decimals) is ignored, and the first of
/// repeated codings counts, as in tower-http's own parser.
fn admits_gzip(headers: &HeaderMap) -> bool {
    let (mut gzip, mut any, mut identity) = (None, None, None);
    for value in headers.get_all(header::ACCEPT_ENCODING) {
        let Ok(value) = value.to_str() else { continue };
        for item in value.split(',') {
            let mut parts = item.split(';');
            let coding = parts.next().unwrap_or("").trim();
            let mut q = Some(1.0);
            for param in parts {
                if let Some((name, v)) = param.split_once('=')
                    && name.trim().eq_ignore_ascii_case("q")
                {
                    q = qvalue(v.trim());
                }
            }
            let Some(q) = q else { continue };
            let slot =
                if coding.eq_ignore_ascii_case("gzip") || coding.eq_ignore_ascii_case("x-gzip") {
                    &mut gzip
                } else if coding == "*" {
                    &mut any
                } else if coding.eq_ignore_ascii_case("identity") {
                    &mut identity
                } else {
                    continue;
                };
            slot.get_or_insert(q);
        }
    }
    // Identity not named takes `*`'s q (RFC 9110 §12.5.3).
    gzip.or(any)
        .is_some_and(|q| q > 0.0 && identity.or(any).is_none_or(|i| q >= i))
}

/// RFC 9110 §12.4.2: `0` to `1` with at most three decimals.
fn qvalue(s: &str) -> Option<f32> {
    let (int, frac) = s.split_once('.').unwrap_or((s, ""));
    let valid = match int {
        "0" => frac.len() <= 3 && frac.bytes().all(|b| b.is_ascii_digit()),
        "1" => frac.len() <= 3 && frac.bytes().all(|b| b == b'0'),
        _ => false,
    };
    if valid { s.parse().ok() } else { None }
}

/// Longest client-supplied `x-request-id` kept.
const MAX_REQUEST_ID_LEN: usize = 128;

/// A client's `x-request-id` is echoed and written into every log line of the
/// request, so it must be usable there: 1 to 128 visible ASCII characters.
/// Anything else (empty, binary, a 70 kB value) is removed, and the request
/// gets a generated UUID instead, like a request that sent none.
pub(crate) fn drop_unusable_request_id<B>(
    mut req: axum::http::Request<B>,
) -> axum::http::Request<B> {
    let usable = |v: &axum::http::HeaderValue| {
        let b = v.as_bytes();
        !b.is_empty() && b.len() <= MAX_REQUEST_ID_LEN && b.iter().all(|c| c.is_ascii_graphic())
    };
    // Exactly one usable value is kept; none, a bad one or several give way
    // to a generated id.
    let mut ids = req.headers().get_all("x-request-id").iter();
    let keep = match (ids.next(), ids.next()) {
        (Some(id), None) => usable(id),
        (None, _) => true,
        (Some(_), Some(_)) => false,
    };
    if !keep {
        req.headers_mut().remove("x-request-id");
    }
    req
}

/// Rewrites `Accept-Encoding` to what this service will do: `gzip` if the
/// request admits it and `gzip_level` is not 0, otherwise no header
/// (identity). The `/solve` handler
/// and tower-http's compression layer then decide from the same value, and
/// a request that admits neither gzip nor identity (`*;q=0`) is answered in
/// identity. RFC 9110 allows a 406 instead, and tower-http's layer sends
/// one, but only after the handler has run (a whole solve for nothing) and
/// with the handler's body under it; a readable answer serves such a client
/// better.
fn canonical_accept_encoding(mut req: Request, gzip_level: u32) -> Request {
    let gzip = gzip_level > 0 && admits_gzip(req.headers());
    let headers = req.headers_mut();
    headers.remove(header::ACCEPT_ENCODING);
    if gzip {
        headers.insert(header::ACCEPT_ENCODING, HeaderValue::from_static("gzip"));
    }
    req
}

/// A `/solve` answer as it goes on the wire.
struct Encoded {
    bytes: Vec<u8>,
    gzip: bool,
}

/// Gzip `json` at `level` if there is one, i.e. if the client accepts gzip
/// (the level is `Config::gzip_level`, 3 by default: on result JSON, mostly 17-digit
/// floats, flate2's zlib-rs backend compresses the seed answer 2.1× in
/// 0.6 ms and a 4.4 MB answer in 59 ms at 3; level 6 is 2.1× too but 85 ms on
/// the large one, level 1 only 1.4×; miniz_oxide, flate2's default backend,
/// took 2.6 ms and 351 ms at level 6). Runs on the solver pool, where CPU
/// work belongs: on the async runtime a large answer held up every other
/// request (`/healthz` took up to 380 ms behind one 4.4 MB answer).
fn encode(json: Vec<u8>, level: Option<u32>) -> Encoded {
    use flate2::{Compression, write::GzEncoder};
    use std::io::Write;
    let Some(level) = level else {
        return Encoded {
            bytes: json,
            gzip: false,
        };
    };
    let mut encoder = GzEncoder::new(Vec::with_capacity(json.len() / 2), Compression::new(level));
    // Writing into a Vec does not fail; if it somehow did, send plain JSON.
    match encoder.write_all(&json).and_then(|()| encoder.finish()) {
        Ok(bytes) => Encoded { bytes, gzip: true },
        Err(_) => Encoded {
            bytes: json,
            gzip: false,
        },
    }
}

/// Count a request this transport refused itself (its body, its answer
/// budget) by reason, and pass the error on. The solve service counts its
/// own refusals.
fn reject(e: ApiError) -> ApiError {
    // A client that left is counted as status 499 in http_requests_total,
    // as when it leaves during its solve; nothing was answered to reject.
    if e != ApiError::ClientLeft {
        count_rejection(Transport::Http, e.reason());
    }
    e
}

/// The query of `GET /problems/default`.
#[derive(Debug, Default, serde::Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
struct DefaultQuery {
    /// The model whose default problem to return (`GET /models` lists
    /// them). Default `quadrotor_2d`, the seed scenario.
    model: Option<String>,
    /// `true`: indented JSON, for reading and editing. Default `false`.
    pretty: Option<bool>,
}

/// A model's default problem, every field expanded.
///
/// Fetch it, edit it, post it back to `/solve`. `solver.time_limit_ms` is
/// this service's default budget; `initial_controls` is left out (its
/// default, the model's rest controls, is N rows that would no longer fit
/// once the horizon is edited).
#[utoipa::path(
    get,
    path = "/problems/default",
    tag = "solve",
    params(DefaultQuery),
    responses(
        (status = 200, description = "The model's default problem, with this service's default time budget", body = ProblemDoc),
        (status = 400, description = "A query parameter this route does not take, or a value it cannot read", body = Problem, content_type = "application/problem+json"),
        (status = 404, description = "No model of that name", body = Problem, content_type = "application/problem+json"),
    )
)]
async fn default_problem(
    State(st): State<Arc<AppState>>,
    query: Result<axum::extract::Query<DefaultQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<Response, ApiError> {
    let query = query
        .map_err(|e| {
            ApiError::BadQuery(format!(
                "{}; it takes `model` (a model's name) and `pretty` (true or false)",
                e.body_text()
            ))
        })?
        .0;
    let model = match &query.model {
        None => crate::models::default_model(),
        Some(name) => crate::models::find(name).ok_or_else(|| {
            ApiError::NotFound(format!(
                "no model {}: the models are {} (GET /models describes them)",
                shown(name.as_bytes()),
                crate::models::names()
            ))
        })?,
    };
    let mut problem = ProblemSpec::default_for(model);
    problem.solver.time_limit_ms = Some(st.config.default_time_limit_ms);
    Ok(json_answer(&problem, query.pretty.unwrap_or(false)))
}

/// `value` as a JSON answer, indented when `pretty`.
fn json_answer(value: &impl Serialize, pretty: bool) -> Response {
    let body = if pretty {
        serde_json::to_vec_pretty(value).map(|mut v| {
            v.push(b'\n');
            v
        })
    } else {
        serde_json::to_vec(value)
    };
    match body {
        Ok(bytes) => (
            [(
                header::CONTENT_TYPE,
                HeaderValue::from_static("application/json"),
            )],
            bytes,
        )
            .into_response(),
        Err(_) => ApiError::Internal.into_response(),
    }
}

/// The models this service solves for.
///
/// Each with its state and control components (names and units), its
/// parameters (units, ranges, defaults), which state entries are its
/// position in the plane, and its default problem.
#[utoipa::path(
    get,
    path = "/models",
    tag = "solve",
    responses((status = 200, description = "Every model", body = crate::models::ModelList))
)]
async fn list_models(State(st): State<Arc<AppState>>) -> Response {
    let mut list = crate::models::ModelList::new();
    for m in &mut list.models {
        m.default_problem.solver.time_limit_ms = Some(st.config.default_time_limit_ms);
    }
    json_answer(&list, false)
}

/// Liveness or readiness answer.
#[derive(Debug, Serialize, ToSchema)]
pub struct Health {
    /// `ok` (`/healthz`) or `ready` (`/readyz`).
    pub status: &'static str,
}

/// Liveness: 200 while the process serves HTTP.
#[utoipa::path(
    get,
    path = "/healthz",
    tag = "operations",
    responses((status = 200, description = "Alive", body = Health))
)]
async fn healthz() -> Json<Health> {
    Json(Health { status: "ok" })
}

/// Readiness: 200 while the service admits solves.
///
/// 503 while it drains for shutdown.
#[utoipa::path(
    get,
    path = "/readyz",
    tag = "operations",
    responses(
        (status = 200, description = "Admitting solves", body = Health),
        (status = 503, description = "Draining", body = Problem, content_type = "application/problem+json"),
    )
)]
async fn readyz(State(st): State<Arc<AppState>>) -> Result<Json<Health>, ApiError> {
    if !st.service.is_ready() {
        Err(ApiError::ShuttingDown)
    } else {
        Ok(Json(Health { status: "ready" }))
    }
}

/// Prometheus metrics in the text exposition format.
#[utoipa::path(
    get,
    path = "/metrics",
    tag = "operations",
    responses((status = 200, description = "Prometheus text format", body = String, content_type = "text/plain"))
)]
async fn metrics_text(State(st): State<Arc<AppState>>) -> Response {
    let service = &st.service;
    let (running, waiting) = service.counts();
    ::metrics::gauge!("solve_queue_depth").set(waiting as f64);
    ::metrics::gauge!("solves_running").set(running as f64);
    ::metrics::gauge!("solve_workers").set(service.workers() as f64);
    ::metrics::gauge!("solve_queue_capacity").set(service.queue_capacity() as f64);
    if let Some(held) = service.service_time() {
        ::metrics::gauge!("solve_worker_seconds_estimate").set(held.as_secs_f64());
    }
    ::metrics::gauge!("request_body_bytes_held").set(st.bodies.used() as f64);
    ::metrics::gauge!("answer_bytes_held").set(st.answers.used() as f64);
    let mut body = metrics::handle().render();
    body.push_str(&metrics::process_text());
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("text/plain; version=0.0.4"),
        )],
        body,
    )
        .into_response()
}

/// Where a 404 or 405 sends its reader: in words, since under a proxy's
/// path prefix an absolute link such as `/docs` leads out of the service.
const ROUTES_ARE_LISTED: &str = "The routes are listed in openapi.json and on the docs/ \
                                 page, both at the service's root.";

/// The routes of the API, for the 404's suggestion: the OpenAPI
/// document's paths, so the list cannot drift from the router.
static ROUTES: std::sync::LazyLock<Vec<String>> =
    std::sync::LazyLock::new(|| openapi().paths.paths.keys().cloned().collect());

/// 404 for `method` and `path`: what was asked for, and the route it
/// probably meant when it differs only by trailing slashes or case
/// (`/solve/`, `/Solve`). Behind a proxy that adds a path prefix the
/// service sees the path without it, so the suggestion is a path from the
/// service's root, and the pointer to the documentation says so in words
/// rather than as a link that would leave the prefix.
fn not_found_error(method: &axum::http::Method, path: &str) -> ApiError {
    let trimmed = path.trim_end_matches('/');
    let meant = ROUTES
        .iter()
        .find(|r| r.trim_end_matches('/') == trimmed)
        .or_else(|| {
            ROUTES
                .iter()
                .find(|r| r.trim_end_matches('/').eq_ignore_ascii_case(trimmed))
        })
        .filter(|r| r.as_str() != path);
    let mut detail = format!("no route for {method} {}.", shown(path.as_bytes()));
    if let Some(route) = meant {
        detail.push_str(&format!(" Did you mean {route}?"));
    }
    detail.push(' ');
    detail.push_str(ROUTES_ARE_LISTED);
    ApiError::NotFound(detail)
}

async fn not_found(method: axum::http::Method, uri: axum::http::Uri) -> ApiError {
    not_found_error(&method, uri.path())
}

/// Four fixes to Swagger UI's routes. Its files all sit directly under
/// `/docs/`, but its `/docs/{*rest}` route serves the page for `/docs//`
/// too, where the page's relative link to the spec (`../openapi.json`)
/// resolves to `/docs/openapi.json`, a 404: any further `/` is a 404 here
/// (for `/docs//`, "did you mean /docs/"). The same route answers an
/// unknown file with an empty 404 of its own, before the router's fallback
/// can; make it ours (with the request's method and path, as the
/// fallback's). Its `/docs` redirect says `Location: /docs/`,
/// which behind a proxy that adds a path prefix leads out of it
/// (`/ilqr/docs` → `/docs/`); `docs/` is the same place relative to
/// `/docs`, and stays under any prefix. And its page's title is "Swagger
/// UI", which says nothing in a row of browser tabs.
async fn docs_fixes(req: Request, next: axum::middleware::Next) -> Response {
    let (method, path) = (req.method().clone(), req.uri().path().to_owned());
    if path
        .strip_prefix("/docs/")
        .is_some_and(|file| file.contains('/'))
    {
        return not_found_error(&method, &path).into_response();
    }
    let mut res = next.run(req).await;
    if res.status() == StatusCode::NOT_FOUND {
        return not_found_error(&method, &path).into_response();
    }
    if res.status().is_redirection()
        && res.headers().get(header::LOCATION) == Some(&HeaderValue::from_static("/docs/"))
    {
        res.headers_mut()
            .insert(header::LOCATION, HeaderValue::from_static("docs/"));
    }
    let is_html = res
        .headers()
        .get(header::CONTENT_TYPE)
        .is_some_and(|v| v.as_bytes().starts_with(b"text/html"));
    // The page is 740 bytes; anything much larger is not the page this
    // rewrite knows, and passes through untouched.
    const PAGE_LIMIT: usize = 64 * 1024;
    let small = axum::body::HttpBody::size_hint(res.body())
        .upper()
        .is_some_and(|n| n <= PAGE_LIMIT as u64);
    if res.status() == StatusCode::OK && is_html && small {
        // The page names the service in its tab, not "Swagger UI".
        let (mut parts, body) = res.into_parts();
        let Ok(page) = axum::body::to_bytes(body, PAGE_LIMIT).await else {
            return ApiError::Internal.into_response();
        };
        let page = String::from_utf8_lossy(&page).replacen(
            "<title>Swagger UI</title>",
            "<title>ilqr-service API</title>",
            1,
        );
        parts.headers.remove(header::CONTENT_LENGTH);
        return Response::from_parts(parts, axum::body::Body::from(page));
    }
    res
}

async fn method_not_allowed(method: axum::http::Method, uri: axum::http::Uri) -> ApiError {
    ApiError::MethodNotAllowed(format!(
        "{} does not take {method} (the Allow header lists what it takes). \
         {ROUTES_ARE_LISTED}",
        shown(uri.path().as_bytes())
    ))
}
