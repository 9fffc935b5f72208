//! The solve service: what happens to a problem between a transport
//! (the HTTP API in [`crate::server`]) and the solver, for every transport
//! alike.
//!
//! A transport reads and parses its request, then calls
//! [`SolveService::solve`] (or [`SolveService::submit`], then
//! [`Pending::finish`]) with the problem, its own [`Transport`] label and an
//! encoder; it gets back the encoded answer or a [`SolveError`], which it
//! maps to its own error answers (HTTP: a problem document; a gRPC front
//! end: a status code). The service does the rest:
//!
//! * **Validation** against the configured [`Limits`].
//! * **Admission.** A draining service refuses at once
//!   ([`SolveError::ShuttingDown`]); so does one whose queue is full, or
//!   whose queue is so long that the solve could not start before its time
//!   budget is spent ([`SolveError::Overloaded`], see "Expected wait"
//!   below). Nothing waits for a slot.
//! * **Time budget.** `solver.time_limit_ms`, or the configured default,
//!   runs from admission, so time spent waiting for a worker is part of it;
//!   a caller's own deadline ([`SolveRequest::deadline`]: gRPC's
//!   `grpc-timeout`) shortens it. The solver checks it every iteration and
//!   every 128 knots inside its passes and returns the best trajectory so
//!   far with status `time_limit`.
//! * **Expiry in the queue.** A solve still queued when it could no longer
//!   start with time for an iteration (its latest useful start, below) is
//!   taken out of the queue and answered [`SolveError::ExpiredInQueue`]
//!   then, without a worker ever running it; a worker that takes it just
//!   past that time answers the same without solving.
//! * **Cancellation** is owned: [`Pending`] (and the future of
//!   [`Pending::finish`] or [`SolveService::solve`]) withdraws its solve
//!   from the queue when dropped, or sets the running solve's cancel flag,
//!   which the solver polls with its budget. A transport drops it when its
//!   client leaves.
//! * **Draining.** [`SolveService::drain`] stops admitting, waits up to a
//!   grace period for the solves in flight, then cancels the rest: a
//!   running one ends with status `cancelled` and its best trajectory so
//!   far, a queued one, which has computed nothing, answers
//!   [`SolveError::ShuttingDown`].
//! * **CPU work stays on the pool.** The encoder runs on the worker right
//!   after the solve (serialising and compressing a long horizon's answer
//!   takes milliseconds), and not at all when the caller has left.
//! * **Metrics and the solve log line**, with a `transport` label.
//!
//! Room is left for a stream of per-iteration progress (a Server-Sent
//! Events front end): [`SolveRequest`] is built by methods, so a progress
//! sink can be added as one more without changing its callers.
//!
//! # Expected wait
//!
//! The service keeps a measured estimate of how long a solve holds a
//! worker: an exponentially weighted moving average (weight
//! [`EWMA_WEIGHT`] for the newest) of the worker time of recent solves,
//! from the start of the solve to the end of its encoding. A solve cut short
//! by its budget or cancelled only tells that it would have taken at least
//! that long, so it can raise the average but not lower it. It keeps the
//! same kind of average of the time per iteration (solve time over
//! iterations + 1, the initial rollout counting as one).
//!
//! A solve's *latest useful start* is its deadline less the time of two
//! iterations (the rollout and one iteration), but at most half its
//! budget, so a small budget that is not queued still runs. On admission
//! the pool simulates the queue ahead with the average service time
//! ([`pool::Pool::submit`]: running solves end after it or at their
//! deadline, queued ones that would start too late are skipped) and
//! refuses a solve that a worker would take only after its latest useful
//! start, with `Retry-After` the whole seconds by which it would be late,
//! at least `--retry-after-secs`.
//!
//! Limits: the average is one number for every kind of problem. Under a
//! mix of short and long solves the wait of any one request is over- or
//! underestimated by the spread of their durations: a few short solves
//! after long ones make the queue look shorter than it is (the
//! underestimated ones then expire in the queue instead of being refused
//! at once; they cost no worker time either way), and the reverse refuses
//! some that would have fitted. It adapts within about ten solves
//! (`1 / EWMA_WEIGHT`) to a change in the mix. Before the first solve ends
//! there is no estimate, and only the queue's capacity limits admission.

pub mod pool;

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::sync::Notify;

use crate::problem::{Invalid, Limits, ProblemSpec};
use crate::solve::{
    Budget, Helpers, SolveResult, SolveStatus, TraceEntry, Unsolvable, millis, solve_shared,
};
use pool::{Estimate, Pool, Refusal, Ticket, Timing};

/// Weight of the newest sample in the service's moving averages.
pub const EWMA_WEIGHT: f64 = 0.1;

/// Which front end a solve came through: the `transport` label of the
/// solve metrics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Transport {
    /// The HTTP/JSON API (`POST /solve`).
    Http,
    /// A gRPC front end.
    Grpc,
}

impl Transport {
    /// The metrics label value: `http`, `grpc`.
    pub fn label(self) -> &'static str {
        match self {
            Self::Http => "http",
            Self::Grpc => "grpc",
        }
    }
}

/// How a transport encodes an answer, for the time the service keeps back
/// from the budget to encode it ([`SolveRequest::encoding`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// JSON text (`/solve`, the result event of `/solve/stream`).
    Json,
    /// JSON, then gzip.
    JsonGzip,
    /// A protobuf message (gRPC; the bytes are written by the runtime).
    Protobuf,
}

impl Encoding {
    /// Seconds per number of the answer before any was measured: about
    /// twice what one took on the benchmark machine (BENCHMARKS.md).
    fn first_guess(self) -> f64 {
        match self {
            Self::Json => 50e-9,
            Self::JsonGzip => 500e-9,
            Self::Protobuf => 10e-9,
        }
    }
}

/// The share of the encoding's measured time kept back on top of it, for
/// its spread on a busy machine.
const ENCODE_MARGIN: f64 = 1.5;

/// Numbers in one trace row of an answer.
const TRACE_ROW_NUMBERS: usize = 14;

/// How the service is set up.
#[derive(Debug, Clone)]
pub struct Settings {
    /// Solver threads (at least 1).
    pub workers: usize,
    /// Solves that may wait for a worker.
    pub queue_capacity: usize,
    /// What a problem may ask for.
    pub limits: Limits,
    /// The budget of a problem that sets none.
    pub default_time_limit: Option<Duration>,
    /// The least `Retry-After` of a refusal, in whole seconds (at least 1):
    /// what a full queue answers, and the floor of one worked out from the
    /// expected wait.
    pub retry_after_secs: u64,
}

/// What a worker is given to run a solve.
struct Job<'a> {
    spec: &'a Arc<ProblemSpec>,
    waited: Duration,
    timing: Timing,
    cancel: &'a Arc<AtomicBool>,
    transport: Transport,
    encoding: Encoding,
}

/// A problem to solve and how it came.
pub struct SolveRequest {
    spec: ProblemSpec,
    transport: Transport,
    encoding: Encoding,
    deadline: Option<Instant>,
    busy: Option<(&'static str, BusyCheck)>,
    progress: Option<Progress>,
}

/// Where a solve reports each iteration's trace row as it ends
/// ([`SolveRequest::progress`]). Called on the worker, inside the solver's
/// loop: it should hand the row on (to a channel) and return.
pub type Progress = Box<dyn FnMut(&TraceEntry) + Send>;

/// A transport's own check before admission ([`SolveRequest::refuse_if`]).
type BusyCheck = Box<dyn FnOnce() -> bool + Send>;

impl SolveRequest {
    /// `spec` as received by `transport`: not yet validated (the service
    /// validates it).
    pub fn new(spec: ProblemSpec, transport: Transport) -> Self {
        Self {
            spec,
            transport,
            encoding: Encoding::Json,
            deadline: None,
            busy: None,
            progress: None,
        }
    }

    /// How the answer will be encoded (JSON by default): the service
    /// keeps the encoding's time back from the budget, so that the
    /// encoded answer, not only the result, is ready by the deadline.
    pub fn encoding(mut self, encoding: Encoding) -> Self {
        self.encoding = encoding;
        self
    }

    /// Report each iteration's trace row to `progress` as the solve runs
    /// (a progress stream: Server-Sent Events, gRPC's `SolveStream`).
    pub fn progress(mut self, progress: impl FnMut(&TraceEntry) + Send + 'static) -> Self {
        self.progress = Some(Box::new(progress));
        self
    }

    /// The caller's own deadline (gRPC's `grpc-timeout`): the solve's
    /// budget ends there if the problem's own budget ends later.
    pub fn deadline(mut self, at: Instant) -> Self {
        self.deadline = Some(at);
        self
    }

    /// Refuse the solve before admission, as [`OverloadCause::Transport`]
    /// with `reason` as its metrics label, if `busy` says so: a
    /// transport's own back-pressure (HTTP: the answers still being sent to
    /// slow readers hold their whole memory budget, so nothing solved now
    /// could be sent). Checked after validation and the drain.
    pub fn refuse_if(
        mut self,
        reason: &'static str,
        busy: impl FnOnce() -> bool + Send + 'static,
    ) -> Self {
        self.busy = Some((reason, Box::new(busy)));
        self
    }
}

/// What an encoder may fail with; logged, and answered as
/// [`SolveError::Internal`].
pub type EncodeError = Box<dyn std::error::Error + Send + Sync>;

/// A solve's encoded answer, with its times.
#[derive(Debug)]
pub struct Solved<T> {
    /// What the encoder made of the result.
    pub answer: T,
    /// Time spent waiting for a worker, in ms (the result's `queue_time_ms`).
    pub queue_ms: f64,
    /// Time spent solving, in ms (the result's `solve_time_ms`).
    pub solve_ms: f64,
    /// Time the encoder took, in ms (kept back from the budget).
    pub encode_ms: f64,
}

/// What ran out, for [`SolveError::Overloaded`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OverloadCause {
    /// Every worker is busy and the queue is full.
    QueueFull,
    /// By the expected wait, a worker would take the solve only after its
    /// latest useful start (see the module's "Expected wait").
    Wait {
        /// The estimated wait for a worker.
        wait: Duration,
        /// The solve's time budget.
        budget: Duration,
    },
    /// The transport's own check ([`SolveRequest::refuse_if`]) refused it.
    Transport {
        /// Its metrics label.
        reason: &'static str,
    },
}

/// Why a solve gave no answer. Each is counted in
/// `solve_rejections_total{reason, transport}` (see [`SolveError::reason`]).
#[derive(Debug, Clone, PartialEq)]
pub enum SolveError {
    /// The problem is invalid (or, found while solving, cannot be solved as
    /// posed).
    Invalid(Invalid),
    /// Refused at once; retry after `retry_after` whole seconds.
    Overloaded {
        /// At least 1.
        retry_after: u64,
        /// What ran out.
        cause: OverloadCause,
    },
    /// Admitted, but its budget ran out while it waited for a worker: it
    /// never ran.
    ExpiredInQueue {
        /// Time it waited.
        waited: Duration,
        /// Its time budget.
        budget: Duration,
        /// Whole seconds to wait before retrying, at least 1.
        retry_after: u64,
    },
    /// The service is draining: refused, or still queued when the grace
    /// period ended.
    ShuttingDown,
    /// A bug: a solver panic, an encoder that failed, a lost job.
    Internal,
}

impl SolveError {
    /// The `reason` label of `solve_rejections_total`.
    pub fn reason(&self) -> &'static str {
        match self {
            Self::Invalid(_) => "invalid",
            Self::Overloaded { cause, .. } => match cause {
                OverloadCause::QueueFull => "queue_full",
                OverloadCause::Wait { .. } => "queue_wait",
                OverloadCause::Transport { reason } => reason,
            },
            Self::ExpiredInQueue { .. } => "expired_in_queue",
            Self::ShuttingDown => "shutting_down",
            Self::Internal => "internal",
        }
    }
}

/// Count a request that got no answer, by reason and transport: the
/// service's own refusals, and a transport's (a body it could not read).
pub fn count_rejection(transport: Transport, reason: &'static str) {
    metrics::counter!("solve_rejections_total", "reason" => reason, "transport" => transport.label())
        .increment(1);
}

fn rejected(transport: Transport, e: SolveError) -> SolveError {
    count_rejection(transport, e.reason());
    e
}

/// The moving averages of the module's "Expected wait", and of the
/// encoding's time per number of an answer, by [`Encoding`].
#[derive(Debug, Default)]
struct Averages {
    /// Worker time per solve, in s.
    service: Option<f64>,
    /// Time per iteration, in s.
    iteration: Option<f64>,
    /// Encoding time per number, in s.
    encode: [Option<f64>; 3],
}

impl Averages {
    fn update(average: &mut Option<f64>, sample: f64, at_least: bool) {
        *average = Some(match *average {
            None => sample,
            Some(a) if at_least && sample <= a => a,
            Some(a) => a + EWMA_WEIGHT * (sample - a),
        });
    }
}

/// The solve service: one per process, shared by every transport.
pub struct SolveService {
    settings: Settings,
    pool: Pool,
    averages: Mutex<Averages>,
    draining: Arc<AtomicBool>,
    /// Cancellation flags of admitted solves, by admission number.
    inflight: Mutex<HashMap<u64, Arc<AtomicBool>>>,
    next_id: AtomicU64,
    /// Signalled whenever an admitted solve finishes.
    finished: Notify,
}

/// What a worker hands back for a solve.
enum Outcome<T> {
    Answer(Solved<T>),
    /// Taken by a worker after its latest useful start: not run.
    Expired,
    /// Cancelled by a shutdown before it started.
    ShutDown,
    /// Its caller left while it ran: nobody reads this.
    Left,
    Unsolvable(Unsolvable),
    EncodeFailed,
}

impl SolveService {
    /// The service for `settings`, starting its worker threads.
    pub fn new(settings: Settings) -> std::io::Result<Arc<Self>> {
        let pool = Pool::new(settings.workers, settings.queue_capacity)?;
        Ok(Arc::new(Self {
            settings,
            pool,
            averages: Mutex::new(Averages::default()),
            draining: Arc::new(AtomicBool::new(false)),
            inflight: Mutex::new(HashMap::new()),
            next_id: AtomicU64::new(0),
            finished: Notify::new(),
        }))
    }

    /// Solve `req`, encoding the result with `encode` on the worker.
    /// Dropping the future withdraws or cancels the solve.
    pub async fn solve<T, F>(
        self: &Arc<Self>,
        req: SolveRequest,
        encode: F,
    ) -> Result<Solved<T>, SolveError>
    where
        T: Send + 'static,
        F: FnOnce(&SolveResult) -> Result<T, EncodeError> + Send + 'static,
    {
        self.submit(req, encode)?.finish().await
    }

    /// Validate and admit `req` (or refuse it, at once), queueing its solve;
    /// [`Pending::finish`] waits for the answer. The solve's log lines and
    /// its worker's work are in the current tracing span.
    pub fn submit<T, F>(
        self: &Arc<Self>,
        req: SolveRequest,
        encode: F,
    ) -> Result<Pending<T>, SolveError>
    where
        T: Send + 'static,
        F: FnOnce(&SolveResult) -> Result<T, EncodeError> + Send + 'static,
    {
        let SolveRequest {
            spec,
            transport,
            encoding,
            deadline: theirs,
            busy,
            progress,
        } = req;
        let refuse = |e| Err(rejected(transport, e));
        if self.is_draining() {
            return refuse(SolveError::ShuttingDown);
        }
        if let Err(e) = spec.validate(&self.settings.limits) {
            return refuse(SolveError::Invalid(e));
        }
        if let Some((reason, busy)) = busy
            && busy()
        {
            return refuse(SolveError::Overloaded {
                retry_after: self.settings.retry_after_secs,
                cause: OverloadCause::Transport { reason },
            });
        }
        let admitted = Instant::now();
        let own = spec
            .time_limit(self.settings.default_time_limit)
            .and_then(|b| admitted.checked_add(b));
        let deadline = match (own, theirs) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        let budget = deadline.map(|d| d.saturating_duration_since(admitted));
        let (estimate, per_iteration) = self.estimates();
        let (encoding_time, _) = self.encode_reserve(&spec, encoding);
        let least_run = match (budget, per_iteration) {
            (Some(b), Some(i)) => (2 * i + encoding_time).min(b / 2),
            _ => Duration::ZERO,
        };
        let timing = Timing {
            deadline,
            start_by: deadline.map(|d| d.checked_sub(least_run).unwrap_or(d)),
        };
        let guard = self.admit();
        let cancel = Arc::clone(&guard.flag);
        let spec = Arc::new(spec);
        let span = tracing::Span::current();
        let service = Arc::clone(self);
        let job_span = span.clone();
        let ticket = self
            .pool
            .submit(timing, estimate, move |waited| {
                let _entered = job_span.enter();
                let job = Job {
                    spec: &spec,
                    waited,
                    timing,
                    cancel: &cancel,
                    transport,
                    encoding,
                };
                service.run(job, progress, encode)
            })
            .map_err(|refusal| {
                let cause = match refusal {
                    Refusal::Full => OverloadCause::QueueFull,
                    Refusal::Late { wait } => OverloadCause::Wait {
                        wait,
                        budget: budget.unwrap_or_default(),
                    },
                };
                let retry_after = match refusal {
                    Refusal::Full => self.settings.retry_after_secs,
                    Refusal::Late { wait } => self.retry_after(
                        wait.saturating_sub(budget.unwrap_or_default().saturating_sub(least_run)),
                    ),
                };
                rejected(transport, SolveError::Overloaded { retry_after, cause })
            })?;
        metrics::gauge!("solve_queue_depth").set(self.pool.queue_depth() as f64);
        Ok(Pending {
            waiting: Waiting {
                ticket,
                span,
                transport,
            },
            _guard: guard,
            service: Arc::clone(self),
            admitted,
            budget,
            least_run,
            start_by: timing.start_by,
        })
    }

    /// Whole seconds to wait before a retry when a solve would start
    /// `late`: at least `--retry-after-secs`.
    fn retry_after(&self, late: Duration) -> u64 {
        let secs = late.as_secs() + u64::from(late.subsec_nanos() > 0);
        secs.max(self.settings.retry_after_secs)
    }

    /// The averages as the pool's estimate and the time of one iteration.
    fn estimates(&self) -> (Option<Estimate>, Option<Duration>) {
        let averages = self.averages.lock().unwrap_or_else(|p| p.into_inner());
        let secs = |s: Option<f64>| s.and_then(|s| Duration::try_from_secs_f64(s).ok());
        (
            secs(averages.service).map(|service| Estimate { service }),
            secs(averages.iteration),
        )
    }

    /// The time to keep back from `spec`'s budget for encoding its answer
    /// with `encoding`: for what every answer holds (states, controls,
    /// gains), and for each trace row.
    fn encode_reserve(&self, spec: &ProblemSpec, encoding: Encoding) -> (Duration, Duration) {
        let per_number = {
            let averages = self.averages.lock().unwrap_or_else(|p| p.into_inner());
            averages.encode[encoding as usize].unwrap_or_else(|| encoding.first_guess())
        } * ENCODE_MARGIN;
        let (nx, nu) = spec
            .model
            .served()
            .map_or((0, 0), |m| (m.state().len(), m.control().len()));
        let n = spec.horizon;
        let gains = if spec.output.gains {
            n * nu * (nx + 1)
        } else {
            0
        };
        let numbers = (n + 1) * nx + n * nu + gains + 10 * spec.obstacles.len();
        let secs = |numbers: usize| Duration::try_from_secs_f64(numbers as f64 * per_number);
        (
            secs(numbers).unwrap_or(Duration::ZERO),
            secs(TRACE_ROW_NUMBERS).unwrap_or(Duration::ZERO),
        )
    }

    /// The measured time a solve holds a worker, if any solve has ended.
    pub fn service_time(&self) -> Option<Duration> {
        self.estimates().0.map(|e| e.service)
    }

    /// On a worker: solve, count, log and encode.
    fn run<T>(
        &self,
        job: Job<'_>,
        mut progress: Option<Progress>,
        encode: impl FnOnce(&SolveResult) -> Result<T, EncodeError>,
    ) -> Outcome<T> {
        let Job {
            spec,
            waited,
            timing,
            cancel,
            transport,
            encoding,
        } = job;
        // Cancelled by a shutdown before a worker took it. Nothing was
        // computed, so the answer says to retry elsewhere rather than
        // holding the initial guess. (A caller that leaves withdraws its
        // queued solve; one that leaves just as a worker takes it gets the
        // solve's own `cancelled`, counted in solves_total.)
        if cancel.load(Ordering::SeqCst) && self.is_draining() {
            return Outcome::ShutDown;
        }
        let started = Instant::now();
        if timing.start_by.is_some_and(|by| started > by) {
            return Outcome::Expired;
        }
        // The answer is due encoded: its encoding's time is kept back.
        let (encoding_time, per_row) = self.encode_reserve(spec, encoding);
        // A cancelled solve is answered only while draining; otherwise its
        // caller has left.
        let draining = Arc::clone(&self.draining);
        let budget = Budget {
            time_limit: timing.deadline.map(|d| {
                d.saturating_duration_since(started)
                    .saturating_sub(encoding_time)
            }),
            per_row,
            unread_if_cancelled: Some(Arc::new(move || !draining.load(Ordering::SeqCst))),
        };
        let mut report = |row: &TraceEntry| {
            if let Some(progress) = &mut progress {
                progress(row);
            }
        };
        // A search's starts also run on idle workers, within the same
        // deadline and cancellation; under load they run here, one after
        // another.
        let lend = |helper| self.pool.lend(timing, helper);
        let helpers = Helpers {
            spec: Arc::clone(spec),
            cancel: Arc::clone(cancel),
            lend: &lend,
        };
        let mut r = match solve_shared(helpers, budget, &mut report) {
            Ok(r) => r,
            Err(e) => return Outcome::Unsolvable(e),
        };
        r.queue_time_ms = millis(waited);
        let label = transport.label();
        // Recorded here, not by the caller, so solves whose caller left are
        // counted too.
        metrics::counter!("solves_total", "status" => r.status.as_str(), "transport" => label)
            .increment(1);
        metrics::histogram!("solve_duration_seconds", "transport" => label)
            .record(r.solve_time_ms / 1e3);
        metrics::histogram!("solve_iterations").record(r.iterations as f64);
        metrics::histogram!("solve_starts").record(r.starts.len() as f64);
        tracing::info!(
            // A target of its own, so that `RUST_LOG` can drop a line per
            // solve (about 1 MB/s at 3000 solves/s) and keep the error lines.
            target: "ilqr_service::solves",
            // Not `status`: the access log's is the HTTP status, a number,
            // and one field of two types breaks typed log stores.
            solve_status = r.status.as_str(),
            iterations = r.iterations,
            cost = r.cost,
            solve_ms = r.solve_time_ms,
            queue_ms = r.queue_time_ms,
            transport = label,
            "solve finished"
        );
        let cut_short = matches!(r.status, SolveStatus::TimeLimit | SolveStatus::Cancelled);
        // The caller left (the flag is set by its guard's drop, or by a
        // shutdown, which still answers): nobody reads the answer, and
        // encoding a long horizon's would hold this worker for
        // milliseconds more.
        if cancel.load(Ordering::SeqCst) && !self.is_draining() {
            self.measured(started.elapsed(), &r, true);
            return Outcome::Left;
        }
        let encoding_began = Instant::now();
        let answer = encode(&r);
        let encoded = encoding_began.elapsed();
        let encode_ms = millis(encoded);
        self.measured(started.elapsed(), &r, cut_short);
        self.encoded(encoding, encoded, &r);
        match answer {
            Ok(answer) => Outcome::Answer(Solved {
                answer,
                queue_ms: r.queue_time_ms,
                solve_ms: r.solve_time_ms,
                encode_ms,
            }),
            Err(e) => {
                tracing::error!(error = %e, "encoding the result failed");
                Outcome::EncodeFailed
            }
        }
    }

    /// Fold a solve that held its worker for `held` into the averages.
    fn measured(&self, held: Duration, r: &SolveResult, cut_short: bool) {
        // Every start's work, its guide's included: a search's wall time
        // over its chosen start's iterations alone would count several
        // starts' time as one start's iterations. (Every result lists at
        // least its one start; `max` keeps an empty list from dividing by 0.)
        let (busy_ms, steps) = r.starts.iter().fold((0.0, 0.0), |(t, n), s| {
            let iterations = s.iterations + s.guide_iterations.unwrap_or(0);
            (t + s.solve_time_ms, n + iterations as f64 + 1.0)
        });
        let per_iteration = busy_ms / 1e3 / f64::max(steps, 1.0);
        let mut averages = self.averages.lock().unwrap_or_else(|p| p.into_inner());
        Averages::update(&mut averages.service, held.as_secs_f64(), cut_short);
        Averages::update(&mut averages.iteration, per_iteration, false);
    }

    /// Fold an encoding of `r` that took `took` into the averages.
    fn encoded(&self, encoding: Encoding, took: Duration, r: &SolveResult) {
        let numbers = r.numbers();
        if numbers == 0 {
            return;
        }
        let mut averages = self.averages.lock().unwrap_or_else(|p| p.into_inner());
        let sample = took.as_secs_f64() / numbers as f64;
        Averages::update(&mut averages.encode[encoding as usize], sample, false);
    }

    /// Whether the service admits solves (not draining).
    pub fn is_ready(&self) -> bool {
        !self.is_draining()
    }

    fn is_draining(&self) -> bool {
        self.draining.load(Ordering::SeqCst)
    }

    /// `(running, waiting)` solves, read together.
    pub fn counts(&self) -> (usize, usize) {
        self.pool.counts()
    }

    /// Solver threads.
    pub fn workers(&self) -> usize {
        self.pool.workers()
    }

    /// Solves that may wait for a worker.
    pub fn queue_capacity(&self) -> usize {
        self.pool.capacity()
    }

    fn inflight_count(&self) -> usize {
        self.inflight.lock().map_or(0, |m| m.len())
    }

    /// Register a solve; the guard cancels and unregisters it when dropped.
    fn admit(self: &Arc<Self>) -> InFlight {
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        let flag = Arc::new(AtomicBool::new(false));
        if let Ok(mut m) = self.inflight.lock() {
            m.insert(id, Arc::clone(&flag));
        }
        InFlight {
            service: Arc::clone(self),
            id,
            flag,
        }
    }

    /// Stop admitting, wait up to `grace` for the solves in flight, then
    /// cancel what is left. Returns at once when none is in flight.
    pub async fn drain(&self, grace: Duration) {
        self.draining.store(true, Ordering::SeqCst);
        tracing::info!(inflight = self.inflight_count(), ?grace, "draining");
        let wait = async {
            loop {
                let notified = self.finished.notified();
                if self.inflight_count() == 0 {
                    return;
                }
                notified.await;
            }
        };
        if tokio::time::timeout(grace, wait).await.is_err() {
            tracing::warn!(
                inflight = self.inflight_count(),
                "grace period over; cancelling in-flight solves"
            );
            if let Ok(m) = self.inflight.lock() {
                for flag in m.values() {
                    flag.store(true, Ordering::SeqCst);
                }
            }
        }
    }
}

/// An admitted solve. Dropping it (its caller left) cancels the solve if it
/// is still running.
struct InFlight {
    service: Arc<SolveService>,
    id: u64,
    flag: Arc<AtomicBool>,
}

impl Drop for InFlight {
    fn drop(&mut self) {
        self.flag.store(true, Ordering::SeqCst);
        if let Ok(mut m) = self.service.inflight.lock() {
            m.remove(&self.id);
        }
        self.service.finished.notify_waiters();
    }
}

/// A queued solve whose caller is waiting. If the caller drops it while
/// the solve is still queued, the solve is withdrawn, its slot freed at
/// once, and it is counted as cancelled. The span is the request's: a drop
/// happens after the caller's future has been abandoned, outside it, and
/// the log line must still carry the request's id.
struct Waiting<T> {
    ticket: Ticket<Outcome<T>>,
    span: tracing::Span,
    transport: Transport,
}

impl<T> Drop for Waiting<T> {
    fn drop(&mut self) {
        let _in_request = self.span.enter();
        if self.ticket.withdraw() {
            metrics::counter!("solves_total", "status" => "cancelled", "transport" => self.transport.label())
                .increment(1);
            tracing::info!("caller left while queued; solve withdrawn");
        }
    }
}

/// An admitted solve, queued or running: [`Pending::finish`] waits for its
/// answer. Dropping it (or the future of `finish`) withdraws the solve
/// from the queue, or sets the running solve's cancel flag.
pub struct Pending<T> {
    waiting: Waiting<T>,
    /// Dropped after `waiting` (fields drop in order), so a queued solve is
    /// withdrawn before its cancel flag is set; the solve counts as in
    /// flight (for the drain) until its caller has its answer or has left.
    _guard: InFlight,
    service: Arc<SolveService>,
    admitted: Instant,
    budget: Option<Duration>,
    least_run: Duration,
    start_by: Option<Instant>,
}

impl<T> Pending<T> {
    /// The encoded answer, or why there is none.
    pub async fn finish(mut self) -> Result<Solved<T>, SolveError> {
        let transport = self.waiting.transport;
        let refuse = |e| Err(rejected(transport, e));
        let start_by = self.start_by;
        let expiry = async move {
            match start_by {
                Some(by) => tokio::time::sleep_until(by.into()).await,
                None => std::future::pending().await, // a budget past Instant's range
            }
        };
        let done = tokio::select! {
            done = self.waiting.ticket.done() => done,
            () = expiry => {
                // Past its latest useful start and still queued: answered
                // now, not when a worker gets to it behind longer solves,
                // and never run. Already taken by a worker, it stops at its
                // budget.
                if self.waiting.ticket.withdraw() {
                    return refuse(self.expired());
                }
                self.waiting.ticket.done().await
            }
        };
        let service = &self.service;
        metrics::gauge!("solve_queue_depth").set(service.pool.queue_depth() as f64);
        let Some(done) = done else {
            tracing::error!("solver worker dropped a job");
            return refuse(SolveError::Internal);
        };
        metrics::histogram!("solve_queue_wait_seconds", "transport" => transport.label())
            .record(done.queued.as_secs_f64());
        match done.outcome {
            Ok(Outcome::Answer(solved)) => Ok(solved),
            Ok(Outcome::Expired) => refuse(self.expired()),
            Ok(Outcome::ShutDown) => refuse(SolveError::ShuttingDown),
            Ok(Outcome::Unsolvable(Unsolvable(field))) => refuse(SolveError::Invalid(field.into())),
            Ok(Outcome::EncodeFailed) => refuse(SolveError::Internal),
            Ok(Outcome::Left) => {
                // Set only when the guard was dropped, which `self` holds.
                tracing::error!("a solve whose caller is waiting was cancelled");
                refuse(SolveError::Internal)
            }
            Err(panic) => {
                tracing::error!(panic = %panic.0, "solver panicked");
                refuse(SolveError::Internal)
            }
        }
    }

    /// The error of a solve whose budget ran out in the queue.
    fn expired(&self) -> SolveError {
        let waited = self.admitted.elapsed();
        if let Some(estimate) = self.service.estimates().0 {
            // What a retry sent now would wait, beyond what its budget
            // allows.
            let wait = self.service.pool.wait(estimate);
            let allowed = self
                .budget
                .unwrap_or_default()
                .saturating_sub(self.least_run);
            return SolveError::ExpiredInQueue {
                waited,
                budget: self.budget.unwrap_or_default(),
                retry_after: self.service.retry_after(wait.saturating_sub(allowed)),
            };
        }
        SolveError::ExpiredInQueue {
            waited,
            budget: self.budget.unwrap_or_default(),
            retry_after: self.service.settings.retry_after_secs,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn service(workers: usize, queue_capacity: usize) -> Arc<SolveService> {
        SolveService::new(Settings {
            workers,
            queue_capacity,
            limits: Limits::default(),
            default_time_limit: Some(Duration::from_secs(10)),
            retry_after_secs: 1,
        })
        .unwrap()
    }

    /// A problem that runs until its budget: 10000 steps, 100 far
    /// obstacles (about 0.1 s per iteration), no tolerance.
    fn slow(time_limit_ms: u64) -> ProblemSpec {
        let obstacles: Vec<String> = (0..100)
            .map(|j| format!(r#"{{"center": [{}, 1000], "weight": 1}}"#, 1000 + j))
            .collect();
        let json = format!(
            r#"{{"horizon": 10000, "dt": 0.0005, "obstacles": [{}],
                "solver": {{"tolerance": 0, "max_iterations": 10000, "time_limit_ms": {time_limit_ms}}},
                "output": {{"gains": false, "trace": false}}}}"#,
            obstacles.join(",")
        );
        crate::problem::parse(json.as_bytes()).unwrap()
    }

    /// The status and iterations of a result, as an encoder a test can read.
    fn status(r: &SolveResult) -> Result<(SolveStatus, usize), EncodeError> {
        Ok((r.status, r.iterations))
    }

    /// A caller's deadline shorter than the problem's budget ends the solve
    /// there.
    #[tokio::test]
    async fn a_callers_deadline_bounds_the_budget() {
        let service = service(1, 0);
        let request = SolveRequest::new(slow(5000), Transport::Grpc)
            .deadline(Instant::now() + Duration::from_millis(300));
        let solved = service.solve(request, status).await.unwrap();
        assert_eq!(solved.answer.0, SolveStatus::TimeLimit);
        assert!(solved.solve_ms < 1500.0, "{}", solved.solve_ms);
    }

    /// Invalid problems, a transport's own refusal and a draining service
    /// are refused before admission, each with its own reason.
    #[tokio::test]
    async fn refusals_before_admission_say_why() {
        let service = service(1, 0);
        let invalid = crate::problem::parse(br#"{"dt": 0}"#).unwrap();
        let e = service
            .solve(SolveRequest::new(invalid, Transport::Http), status)
            .await
            .unwrap_err();
        assert!(matches!(e, SolveError::Invalid(_)), "{e:?}");
        let busy =
            SolveRequest::new(slow(100), Transport::Http).refuse_if("answer_budget", || true);
        let e = service.solve(busy, status).await.unwrap_err();
        assert_eq!(e.reason(), "answer_budget");
        assert!(service.is_ready());
        service.drain(Duration::ZERO).await;
        assert!(!service.is_ready());
        let e = service
            .solve(SolveRequest::new(slow(100), Transport::Http), status)
            .await
            .unwrap_err();
        assert_eq!(e, SolveError::ShuttingDown);
    }

    /// A search spreads over idle workers, and dropping it cancels every
    /// start: both workers are free again long before the budget.
    #[tokio::test]
    async fn dropping_a_search_cancels_every_start() {
        let service = service(2, 0);
        let mut spec = slow(20_000);
        // The seed's obstacle in the way: a detour on either side, one begun
        // beside the plain start (which never ends) once it has run 5 ms.
        spec.obstacles[99] = crate::problem::Obstacle::point([4.5, 4.5], 1000.0);
        // Only a worker already waiting is lent: let both threads get there.
        let t = Instant::now();
        while service.pool.idle() < 2 {
            assert!(t.elapsed() < Duration::from_secs(2), "workers never idle");
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        let pending = service
            .submit(SolveRequest::new(spec, Transport::Http), status)
            .unwrap();
        let t = Instant::now();
        while (service.counts(), service.pool.lent()) != ((1, 0), 1) {
            assert!(
                t.elapsed() < Duration::from_secs(2),
                "no helper took a start"
            );
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        drop(pending);
        let t = Instant::now();
        while (service.counts(), service.pool.lent()) != ((0, 0), 0) {
            assert!(t.elapsed() < Duration::from_secs(2), "still running");
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    }

    /// A plain start that runs past `SPECULATE_AFTER` gets an idle worker
    /// beside it, which begins the west detour before the plain start (it
    /// goes west) rules it out. That detour is dropped, rows and all: the
    /// answer is the one worker's, start for start, and every streamed row
    /// belongs to a listed start, tagged with its place in `starts`.
    #[tokio::test]
    async fn a_detour_begun_before_the_plain_start_decides_is_dropped() {
        // The seed at 10000 steps: a plain start of about 70 ms on a 2.6 GHz
        // EPYC, far past the 5 ms on a faster machine too.
        let spec = crate::problem::parse(
            br#"{"horizon": 10000, "dt": 0.0005, "output": {"gains": false}}"#,
        )
        .unwrap();
        let answer = |r: &SolveResult| -> Result<serde_json::Value, EncodeError> {
            let mut r = r.clone();
            (r.solve_time_ms, r.queue_time_ms) = (0.0, 0.0);
            for row in r.trace.iter_mut().flatten() {
                row.elapsed_ms = 0.0;
            }
            for start in &mut r.starts {
                start.solve_time_ms = 0.0;
            }
            Ok(serde_json::to_value(&r).unwrap())
        };
        let alone = service(1, 0)
            .solve(SolveRequest::new(spec.clone(), Transport::Http), answer)
            .await
            .unwrap()
            .answer;
        let labels: Vec<_> = alone["starts"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| s["label"].as_str().unwrap().to_owned())
            .collect();
        assert_eq!(labels, ["rest controls", "east of obstacle 0"]);
        let service = service(2, 0);
        let t = Instant::now();
        while service.pool.idle() < 2 {
            assert!(t.elapsed() < Duration::from_secs(2), "workers never idle");
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        let rows = Arc::new(std::sync::Mutex::new(Vec::new()));
        let sink = Arc::clone(&rows);
        let request = SolveRequest::new(spec, Transport::Http)
            .progress(move |row| sink.lock().unwrap().push(row.clone()));
        let pending = service.submit(request, answer).unwrap();
        let mut lent = false;
        let t = Instant::now();
        // Until the search ends (nothing running or waiting).
        while !lent && service.counts() != (0, 0) && t.elapsed() < Duration::from_secs(5) {
            lent = service.pool.lent() == 1;
            tokio::time::sleep(Duration::from_micros(200)).await;
        }
        assert!(lent, "no worker was lent while the search ran");
        assert_eq!(pending.finish().await.unwrap().answer, alone);
        let rows = rows.lock().unwrap();
        let starts = alone["starts"].as_array().unwrap();
        for (i, start) in starts.iter().enumerate() {
            let mine: Vec<_> = rows.iter().filter(|r| r.start == Some(i)).collect();
            assert_eq!(mine.len() as u64, start["iterations"], "start {i}");
            assert!(mine.iter().enumerate().all(|(k, r)| r.iteration == k + 1));
        }
        assert_eq!(
            rows.len() as u64,
            starts
                .iter()
                .map(|s| s["iterations"].as_u64().unwrap())
                .sum::<u64>()
        );
    }

    /// Dropping a pending solve cancels it: the only worker is free again
    /// long before the solve's budget.
    #[tokio::test]
    async fn dropping_a_pending_solve_cancels_it() {
        let service = service(1, 0);
        let pending = service
            .submit(SolveRequest::new(slow(20_000), Transport::Http), status)
            .unwrap();
        tokio::time::sleep(Duration::from_millis(200)).await;
        assert_eq!(service.counts(), (1, 0));
        drop(pending);
        let t = Instant::now();
        while service.counts() != (0, 0) {
            assert!(t.elapsed() < Duration::from_secs(2), "still running");
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    }
}
