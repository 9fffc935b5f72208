//! The gRPC front end: `ilqr.v1.TrajectoryOptimizer`
//! (`proto/ilqr/v1/ilqr.proto`), with the standard health and reflection
//! services, over the same [`SolveService`] as the HTTP API.
//!
//! # Mechanisms
//!
//! * **One service, two transports.** A problem message is converted into
//!   the JSON problem document and read by the parser the HTTP API uses
//!   ([`convert`]), then solved through the solve service with the
//!   [`Transport::Grpc`] label: the same validation, admission, queue,
//!   time budgets, cancellation and drain. Errors are statuses with the
//!   standard details ([`status`]).
//! * **Deadlines.** A call's `grpc-timeout` ends the solve's budget a
//!   margin before the deadline ([`status::margin`]: a tenth, at most
//!   250 ms, plus 5 ms), so the caller gets the best trajectory so far with
//!   status `SOLVE_STATUS_TIME_LIMIT` rather than `DEADLINE_EXCEEDED`. tonic's
//!   server also enforces `grpc-timeout` on a unary call: at the deadline it
//!   drops the handler (which cancels its solve) and answers `CANCELLED`
//!   ("Timeout expired"); the margin keeps the answer ahead of that. It does
//!   not time a stream's messages: `SolveStream`'s result comes before the
//!   deadline because the solve ends before it.
//! * **Cancellation.** A caller that cancels (or whose connection drops)
//!   has its handler dropped by the HTTP/2 server; the handler owns its
//!   solve ([`crate::service::Pending`]), which is then withdrawn from the
//!   queue or cancelled. `SolveStream`'s solve lives in a task that ends
//!   when the stream's receiver is dropped.
//! * **CPU work on the pool.** The result message is built by the encoder
//!   the worker runs after the solve. Its protobuf encoding is left to
//!   tonic, on the async runtime: packed doubles are copied, not formatted
//!   (0.3 ms for the largest answer, 10000 steps with gains, 1.8 MB, where
//!   its JSON takes tens of ms).
//! * **Health.** `grpc.health.v1.Health` answers `SERVING` for the server
//!   (`""`) and `ilqr.v1.TrajectoryOptimizer`, and `NOT_SERVING` for both
//!   from the moment a drain begins ([`Health::draining`]), as `/readyz`.
//! * **Reflection.** `grpc.reflection.v1` and `v1alpha` list and describe
//!   the services, with the contract's comments, and the types of
//!   `google.rpc`'s error details, so `grpcurl` and `grpcui` need no proto
//!   file to call the service or to print its errors.
//! * **Request ids.** Every call has an `x-request-id` (the caller's own
//!   if usable, as over HTTP, else a new UUID), echoed in the response
//!   metadata, in its log lines and in `google.rpc.RequestInfo` of an
//!   error.
//!
//! # Limits
//!
//! A request message may be as large as `--max-body-bytes` (larger:
//! `OUT_OF_RANGE`, from tonic). The messages being received are not
//! counted against `--max-inflight-body-bytes`, nor the answers being sent
//! against the answers' budget, as HTTP's are: HTTP/2 flow control holds a
//! slow reader's answer at the sender, but a server with many callers
//! sending large problems at once holds each until it is read.
//! Connections are pinged every `--read-timeout-secs` and closed when a
//! ping goes unanswered for 20 s; an idle connection that answers pings
//! stays open, as gRPC clients expect.

pub mod convert;
pub mod status;

use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::net::TcpListener;
use tonic::{Code, Request, Response, Status};
use tonic_health::server::{HealthReporter, HealthService};
use tracing::Instrument;

use crate::models::{self, ModelList};
use crate::problem::{Limits, ProblemSpec};
use crate::service::{
    Encoding, SolveError, SolveRequest, SolveService, Transport, count_rejection,
};
use convert::Flat;
use proto::trajectory_optimizer_server::{TrajectoryOptimizer, TrajectoryOptimizerServer};

/// The code generated from `proto/ilqr/v1/ilqr.proto` (by `build.rs`):
/// the messages, the server trait and a client (without tonic's transport:
/// bring a channel).
#[allow(missing_docs, clippy::all, clippy::pedantic)]
pub mod proto {
    tonic::include_proto!("ilqr.v1");
}

/// The compiled contract, comments included, as reflection serves it.
pub const FILE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/ilqr_v1_descriptor.bin"));

/// The service's name, as health checks and reflection know it.
pub const SERVICE_NAME: &str = "ilqr.v1.TrajectoryOptimizer";

/// What the gRPC front end takes from the configuration.
#[derive(Debug, Clone)]
pub struct Settings {
    /// What a problem may ask for (for the conversion's range checks).
    pub limits: Limits,
    /// The budget a problem without one gets, in ms: shown in the default
    /// problems, as `GET /problems/default` shows it.
    pub default_time_limit_ms: u64,
    /// The largest request message, in bytes (`--max-body-bytes`).
    pub max_message_bytes: usize,
    /// How often a connection is pinged (`--read-timeout-secs`).
    pub keepalive: Duration,
}

/// The gRPC server: the optimizer, health and reflection services.
pub struct Server {
    optimizer: Optimizer,
    health: HealthReporter,
}

/// The health of the gRPC server, for the drain to report.
#[derive(Clone)]
pub struct Health(HealthReporter);

impl Health {
    /// `NOT_SERVING` for the server and the optimizer: a drain has begun.
    pub async fn draining(&self) {
        use tonic_health::ServingStatus::NotServing;
        self.0.set_service_status("", NotServing).await;
        self.0.set_service_status(SERVICE_NAME, NotServing).await;
    }
}

impl Server {
    /// The server of `service`.
    pub fn new(service: Arc<SolveService>, settings: Settings) -> Self {
        Self {
            optimizer: Optimizer { service, settings },
            health: HealthReporter::new(),
        }
    }

    /// Its health, for [`Health::draining`].
    pub fn health(&self) -> Health {
        Health(self.health.clone())
    }

    /// Serve on `listener` until `stop` resolves, then stop accepting, let
    /// every connection finish its calls (HTTP/2 GOAWAY) and return when
    /// all are closed. A caller that must not wait for a connection that
    /// stays open (a health `Watch` stream never ends) bounds this with a
    /// timeout.
    ///
    /// # Errors
    ///
    /// The reflection service's, if the compiled contract cannot be read
    /// (a build fault), or tonic's.
    pub async fn serve(
        self,
        listener: TcpListener,
        stop: impl Future<Output = ()>,
    ) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
        use tower_http::request_id::{MakeRequestUuid, PropagateRequestIdLayer, SetRequestIdLayer};
        let Self { optimizer, health } = self;
        let keepalive = optimizer.settings.keepalive;
        let max_message_bytes = optimizer.settings.max_message_bytes;
        // Reported before the first call can be accepted.
        health
            .set_service_status(SERVICE_NAME, tonic_health::ServingStatus::Serving)
            .await;
        let reflection = || {
            tonic_reflection::server::Builder::configure()
                .register_encoded_file_descriptor_set(FILE_DESCRIPTOR_SET)
                .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
                // google.rpc's error details, so that a reflection client
                // can decode them (grpcurl prints them as JSON).
                .register_encoded_file_descriptor_set(tonic_types::pb::FILE_DESCRIPTOR_SET)
        };
        let layers = tower::ServiceBuilder::new()
            .map_request(crate::server::drop_unusable_request_id)
            .layer(SetRequestIdLayer::x_request_id(MakeRequestUuid))
            .layer(PropagateRequestIdLayer::x_request_id())
            .layer(tower_http::catch_panic::CatchPanicLayer::custom(
                |_| -> axum::http::Response<tonic::body::Body> {
                    Status::internal("the call failed unexpectedly (a panic, logged)").into_http()
                },
            ));
        let incoming =
            tonic::transport::server::TcpIncoming::from(listener).with_nodelay(Some(true));
        tonic::transport::Server::builder()
            .http2_keepalive_interval(Some(keepalive))
            .http2_keepalive_timeout(Some(KEEPALIVE_TIMEOUT))
            .layer(layers)
            .add_service(tonic_health::pb::health_server::HealthServer::new(
                HealthService::from_health_reporter(health),
            ))
            .add_service(reflection().build_v1()?)
            .add_service(reflection().build_v1alpha()?)
            .add_service(
                TrajectoryOptimizerServer::new(optimizer)
                    .max_decoding_message_size(max_message_bytes),
            )
            .serve_with_incoming_shutdown(incoming, stop)
            .await?;
        Ok(())
    }
}

/// How long a keepalive ping may go unanswered before the connection is
/// closed.
const KEEPALIVE_TIMEOUT: Duration = Duration::from_secs(20);

/// `ilqr.v1.TrajectoryOptimizer`.
struct Optimizer {
    service: Arc<SolveService>,
    settings: Settings,
}

impl Optimizer {
    /// The problem of a solve request, or the status of why it is none.
    fn spec(
        &self,
        problem: Option<proto::Problem>,
        request_id: &str,
    ) -> Result<(ProblemSpec, Flat), Status> {
        convert::spec_of(problem, &self.settings.limits).map_err(|rejected| {
            let Some(rejected) = rejected else {
                count_rejection(Transport::Grpc, "internal");
                return status::solve_error(SolveError::Internal, &Flat::default(), request_id);
            };
            count_rejection(Transport::Grpc, "invalid");
            status::invalid(rejected.invalid, &rejected.flat, request_id)
        })
    }

    /// The solve request of a call that arrived at `arrived`, its budget
    /// ending before the call's deadline.
    fn request(
        spec: ProblemSpec,
        metadata: &tonic::metadata::MetadataMap,
        arrived: Instant,
    ) -> SolveRequest {
        let request = SolveRequest::new(spec, Transport::Grpc).encoding(Encoding::Protobuf);
        match status::budget_end(metadata, arrived) {
            Some(end) => request.deadline(end),
            None => request,
        }
    }
}

#[tonic::async_trait]
impl TrajectoryOptimizer for Optimizer {
    async fn solve(
        &self,
        request: Request<proto::SolveRequest>,
    ) -> Result<Response<proto::SolveResponse>, Status> {
        let arrived = Instant::now();
        let mut call = Call::start("Solve", request.metadata());
        let id = call.request_id.clone();
        let answer = async {
            let (metadata, _, message) = request.into_parts();
            let (spec, flat) = self.spec(message.problem, &id)?;
            let request = Self::request(spec, &metadata, arrived);
            // Built on the worker, after the solve.
            let solved = self
                .service
                .solve(request, |r| {
                    Ok(proto::SolveResponse {
                        result: Some(convert::result_message(r)),
                    })
                })
                .await
                .map_err(|e| status::solve_error(e, &flat, &id))?;
            let mut response = Response::new(solved.answer);
            let timing = format!(
                "queue;dur={}, solve;dur={}, encode;dur={}",
                solved.queue_ms, solved.solve_ms, solved.encode_ms
            );
            if let Ok(timing) = timing.parse() {
                response.metadata_mut().insert("server-timing", timing);
            }
            Ok(response)
        }
        .instrument(call.span.clone())
        .await;
        call.end(answer.as_ref().err());
        answer
    }

    type SolveStreamStream = Events;

    async fn solve_stream(
        &self,
        request: Request<proto::SolveRequest>,
    ) -> Result<Response<Events>, Status> {
        let arrived = Instant::now();
        let mut call = Call::start("SolveStream", request.metadata());
        let span = call.span.clone();
        let id = call.request_id.clone();
        let (metadata, _, message) = request.into_parts();
        let started = span.in_scope(|| -> Result<_, Status> {
            let (spec, flat) = self.spec(message.problem, &id)?;
            let (events, stream) = tokio::sync::mpsc::unbounded_channel();
            let rows = events.clone();
            let request = Self::request(spec, &metadata, arrived).progress(move |row| {
                // A closed stream (the caller left) drops the row; the
                // solve is being cancelled.
                let _ = rows.send(Ok(proto::SolveEvent {
                    event: Some(proto::solve_event::Event::Iteration(
                        convert::trace_message(row),
                    )),
                }));
            });
            let pending = self
                .service
                .submit(request, |r| Ok(convert::result_message(r)))
                .map_err(|e| status::solve_error(e, &flat, &id))?;
            Ok((pending, events, stream, flat))
        });
        let (pending, events, stream, flat) = match started {
            Ok(started) => started,
            Err(refused) => {
                call.end(Some(&refused));
                return Err(refused);
            }
        };
        // The pending solve lives in a task of its own until its result is
        // sent or the caller drops the stream: then `pending` is dropped,
        // which cancels the solve, and the call counts as cancelled.
        tokio::spawn(
            async move {
                tokio::select! {
                    done = pending.finish() => {
                        let last = done
                            .map(|solved| proto::SolveEvent {
                                event: Some(proto::solve_event::Event::Result(solved.answer)),
                            })
                            .map_err(|e| status::solve_error(e, &flat, &id));
                        call.end(last.as_ref().err());
                        let _ = events.send(last);
                    }
                    () = events.closed() => {}
                }
            }
            .instrument(span),
        );
        Ok(Response::new(Events(stream)))
    }

    async fn get_default_problem(
        &self,
        request: Request<proto::GetDefaultProblemRequest>,
    ) -> Result<Response<proto::Problem>, Status> {
        let mut call = Call::start("GetDefaultProblem", request.metadata());
        let answer = match request.into_inner().model {
            None => Ok(models::default_model()),
            Some(name) => models::find(&name).ok_or_else(|| {
                Status::not_found(format!(
                    "no model `{}`: the models are {} (ListModels describes them)",
                    crate::problem::clip(&name, 100),
                    models::names()
                ))
            }),
        }
        .map(|model| {
            let mut problem = ProblemSpec::default_for(model);
            problem.solver.time_limit_ms = Some(self.settings.default_time_limit_ms);
            Response::new(convert::problem_message(&problem))
        });
        call.end(answer.as_ref().err());
        answer
    }

    async fn list_models(
        &self,
        request: Request<proto::ListModelsRequest>,
    ) -> Result<Response<proto::ListModelsResponse>, Status> {
        let mut call = Call::start("ListModels", request.metadata());
        let mut list = ModelList::new();
        for m in &mut list.models {
            m.default_problem.solver.time_limit_ms = Some(self.settings.default_time_limit_ms);
        }
        let models = list.models.iter().map(convert::model_message).collect();
        call.end(None);
        Ok(Response::new(proto::ListModelsResponse { models }))
    }
}

/// The messages of one `SolveStream`: the iterations, then the result or
/// the status the solve ended with.
pub struct Events(tokio::sync::mpsc::UnboundedReceiver<Result<proto::SolveEvent, Status>>);

impl futures_core::Stream for Events {
    type Item = Result<proto::SolveEvent, Status>;

    fn poll_next(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Option<Self::Item>> {
        self.0.poll_recv(cx)
    }
}

/// One call of the optimizer: its span (with its request id), counted in
/// `grpc_requests_total{method, code}` and timed in
/// `grpc_request_duration_seconds{method}` when it ends, and logged when
/// it ends in an error. A call dropped before it ended (the caller
/// cancelled, its deadline passed, or it closed its stream) counts as
/// `CANCELLED`.
struct Call {
    method: &'static str,
    request_id: String,
    span: tracing::Span,
    started: Instant,
    ended: bool,
}

impl Call {
    fn start(method: &'static str, metadata: &tonic::metadata::MetadataMap) -> Self {
        // Set by the request-id layer on every call.
        let request_id = metadata
            .get("x-request-id")
            .and_then(|v| v.to_str().ok())
            .unwrap_or("-")
            .to_owned();
        let span = tracing::info_span!(
            "request",
            request_id = %request_id,
            rpc = %format_args!("{SERVICE_NAME}/{method}"),
        );
        Self {
            method,
            request_id,
            span,
            started: Instant::now(),
            ended: false,
        }
    }

    /// Count and time the call, and log an error answer (at the levels the
    /// HTTP access log uses for the same errors).
    fn end(&mut self, error: Option<&Status>) {
        self.ended = true;
        let code = error.map_or(Code::Ok, Status::code);
        metrics::counter!(
            "grpc_requests_total",
            "method" => self.method,
            "code" => code_name(code)
        )
        .increment(1);
        metrics::histogram!("grpc_request_duration_seconds", "method" => self.method)
            .record(self.started.elapsed().as_secs_f64());
        let _in_call = self.span.enter();
        let latency_ms = crate::solve::millis(self.started.elapsed());
        let name = code_name(code);
        let Some(e) = error else {
            tracing::debug!(code = name, latency_ms, "response");
            return;
        };
        // The status message, as the HTTP access log's `detail`: it says
        // what was wrong and may quote a short value, never the request.
        let clipped = crate::problem::clip(e.message(), 300);
        let detail: &str = &clipped;
        match code {
            // Back-pressure working: a line each would flood the log when
            // the service is busiest (counted in solve_rejections_total).
            Code::ResourceExhausted => tracing::debug!(code = name, detail, latency_ms, "response"),
            Code::Internal | Code::Unknown => {
                tracing::warn!(code = name, detail, latency_ms, "response");
            }
            _ => tracing::info!(code = name, detail, latency_ms, "response"),
        }
    }
}

impl Drop for Call {
    fn drop(&mut self) {
        if !self.ended {
            self.end(Some(&Status::cancelled(
                "the caller left before the answer",
            )));
        }
    }
}

/// A status code's name, as gRPC writes it (`INVALID_ARGUMENT`).
fn code_name(code: Code) -> &'static str {
    match code {
        Code::Ok => "OK",
        Code::Cancelled => "CANCELLED",
        Code::Unknown => "UNKNOWN",
        Code::InvalidArgument => "INVALID_ARGUMENT",
        Code::DeadlineExceeded => "DEADLINE_EXCEEDED",
        Code::NotFound => "NOT_FOUND",
        Code::AlreadyExists => "ALREADY_EXISTS",
        Code::PermissionDenied => "PERMISSION_DENIED",
        Code::ResourceExhausted => "RESOURCE_EXHAUSTED",
        Code::FailedPrecondition => "FAILED_PRECONDITION",
        Code::Aborted => "ABORTED",
        Code::OutOfRange => "OUT_OF_RANGE",
        Code::Unimplemented => "UNIMPLEMENTED",
        Code::Internal => "INTERNAL",
        Code::Unavailable => "UNAVAILABLE",
        Code::DataLoss => "DATA_LOSS",
        Code::Unauthenticated => "UNAUTHENTICATED",
    }
}
