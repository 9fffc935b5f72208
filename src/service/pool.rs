//! The solver pool: a fixed set of worker threads behind a bounded queue.
//!
//! Solves are CPU-bound and take milliseconds to seconds, so they must not
//! run on the async runtime. `tokio::task::spawn_blocking` would grow to 512
//! threads, and rayon aborts the process when a job panics unless a handler
//! is installed; a small pool of our own states its limits plainly:
//!
//! * `workers` threads take jobs from one FIFO queue, a `VecDeque` under a
//!   mutex with a condition variable to wake idle workers;
//! * at most `workers + capacity` jobs are admitted at once (running or
//!   waiting). [`Pool::submit`] never waits: when every slot is taken it
//!   refuses at once with [`Refusal::Full`];
//! * given an [`Estimate`] of the time a job holds a worker, it also
//!   refuses, with [`Refusal::Late`], a job that would not start before its
//!   latest useful start (`start_by`), by a simulation of the queue ahead
//!   of it (see [`Pool::submit`]);
//! * a job is withdrawn from the queue when its [`Ticket`] is dropped before
//!   a worker took it (the client went away, or its caller gave up on it
//!   because it could no longer start in time), so its slot is free at
//!   once instead of held until a worker gets there;
//! * a panicking job is caught with `catch_unwind` and reported to its caller
//!   as [`Panicked`]; the worker thread lives on.
//!
//! The queue is short (its capacity is a configuration value in the tens),
//! so withdrawing by a linear search under the lock costs nothing next to a
//! solve; the admission's simulation walks the queue once, under the lock,
//! and stops as soon as the answer is known.

use std::cmp::Reverse;
use std::collections::{BinaryHeap, VecDeque};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use tokio::sync::oneshot;

/// A queued job, called with the index of the worker that runs it.
type Job = Box<dyn FnOnce(usize) + Send + 'static>;

/// A job lent to an idle worker ([`Pool::lend`]), called with a check that
/// says whether an admitted job is waiting for a worker: a search's
/// helper.
pub use crate::solve::Helper as Lent;

/// Why [`Pool::submit`] refused a job.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// Every slot (`workers + capacity`) is taken, or the pool is closed.
    Full,
    /// By the estimate, a worker would be free for the job only after
    /// `wait`, past its `start_by`.
    Late {
        /// The estimated wait for a worker.
        wait: Duration,
    },
}

/// The job panicked; the message is for logs, not for clients.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Panicked(pub String);

/// What a job's caller gets back.
#[derive(Debug)]
pub struct Done<T> {
    /// The job's value, or its panic.
    pub outcome: Result<T, Panicked>,
    /// Time between submission and the start of the job.
    pub queued: Duration,
}

/// When a job must run, as its submitter knows it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Timing {
    /// The job's time budget ends here: once started, it holds its worker
    /// until then at most (plus what it takes to stop and encode).
    pub deadline: Option<Instant>,
    /// A job that has not started by then is of no use: the admission
    /// refuses one that would start later, and its caller withdraws it then.
    pub start_by: Option<Instant>,
}

/// How long a job holds a worker, as measured by the caller.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Estimate {
    /// Typical time from a job's start to its end, when not cut short by its
    /// deadline.
    pub service: Duration,
}

/// A fixed pool of worker threads with a bounded queue.
pub struct Pool {
    shared: Arc<Shared>,
    workers: usize,
    capacity: usize,
}

struct Shared {
    state: Mutex<State>,
    /// Signalled when a job is queued or the pool closes.
    wake: Condvar,
}

struct Queued {
    id: u64,
    timing: Timing,
    job: Job,
    /// Lent to an admitted request ([`Pool::lend`]), not admitted itself.
    lent: bool,
}

struct State {
    queue: VecDeque<Queued>,
    /// What each worker runs: when it started and its timing; `None` when
    /// idle. Indexed by worker.
    running: Vec<Option<(Instant, Timing)>>,
    /// Whether each worker's job is a lent one. Lent jobs are not counted
    /// as admitted (running or waiting); a worker running one is busy.
    lent: Vec<bool>,
    /// Workers blocked on `wake`. `Condvar::notify_one` is a system call
    /// even with nobody waiting; under load every worker is busy and the
    /// next job is taken from the queue without one.
    idle: usize,
    next_id: u64,
    closed: bool,
}

impl State {
    /// Admitted jobs running (lent ones are not admitted).
    fn running_count(&self) -> usize {
        self.running
            .iter()
            .zip(&self.lent)
            .filter(|(r, lent)| r.is_some() && !**lent)
            .count()
    }

    /// Queue `job` under a new id: a lent one ahead of the queue (only an
    /// idle worker takes it), an admitted one behind it.
    fn enqueue(&mut self, timing: Timing, job: Job, lent: bool) -> u64 {
        let id = self.next_id;
        self.next_id += 1;
        let queued = Queued {
            id,
            timing,
            job,
            lent,
        };
        if lent {
            self.queue.push_front(queued);
        } else {
            self.queue.push_back(queued);
        }
        id
    }

    /// Admitted jobs waiting.
    fn waiting_count(&self) -> usize {
        self.queue.iter().filter(|q| !q.lent).count()
    }

    /// When a worker would be free for a job queued behind everything now
    /// waiting, from `now`, by `estimate`; or `None` once that is known to
    /// be after `give_up` (the walk stops there).
    ///
    /// Each running job is taken to end `estimate.service` after its start
    /// or at its deadline, whichever is first (at `now` if both are past).
    /// The queue is then dealt to the worker free first, in order: a job
    /// that would start after its `start_by` is skipped, as its caller
    /// withdraws it then; one that starts holds its worker for
    /// `estimate.service` or until its deadline.
    fn free_at(
        &self,
        now: Instant,
        estimate: Estimate,
        give_up: Option<Instant>,
    ) -> Option<Instant> {
        let ends = |start: Instant, deadline: Option<Instant>| {
            let end = start.checked_add(estimate.service).unwrap_or(start);
            deadline.map_or(end, |d| end.min(d)).max(now)
        };
        let mut free: BinaryHeap<Reverse<Instant>> = self
            .running
            .iter()
            .map(|r| Reverse(r.map_or(now, |(start, t)| ends(start, t.deadline))))
            .collect();
        // A queued lent job ends at once when its search has nothing left,
        // and gives way to a request after its current start: not counted.
        for queued in self.queue.iter().filter(|q| !q.lent) {
            let Some(Reverse(at)) = free.pop() else {
                return Some(now); // no workers: not reached (at least 1)
            };
            // Free times only grow as jobs are dealt out.
            if give_up.is_some_and(|g| at > g) {
                return None;
            }
            let starts = queued.timing.start_by.is_none_or(|by| at <= by);
            free.push(Reverse(if starts {
                ends(at, queued.timing.deadline)
            } else {
                at
            }));
        }
        let at = free.peek().map_or(now, |Reverse(at)| *at);
        if give_up.is_some_and(|g| at > g) {
            None
        } else {
            Some(at)
        }
    }
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        // A job never runs under the lock, so a poisoned lock means a panic
        // in this module's few lines of bookkeeping; the state is still
        // consistent enough to go on serving.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }
}

impl Pool {
    /// Start `workers` threads (at least 1) behind a queue of `capacity`
    /// waiting jobs. The threads end when the pool is dropped and the queue
    /// has drained.
    pub fn new(workers: usize, capacity: usize) -> std::io::Result<Self> {
        let workers = workers.max(1);
        let shared = Arc::new(Shared {
            state: Mutex::new(State {
                // Room for a typical queue up front, not for the configured
                // maximum: a capacity of thousands is memory never touched.
                queue: VecDeque::with_capacity(capacity.min(64)),
                running: vec![None; workers],
                lent: vec![false; workers],
                idle: 0,
                next_id: 0,
                closed: false,
            }),
            wake: Condvar::new(),
        });
        for i in 0..workers {
            let shared = Arc::clone(&shared);
            std::thread::Builder::new()
                .name(format!("solver-{i}"))
                .spawn(move || worker(&shared, i))?;
        }
        Ok(Self {
            shared,
            workers,
            capacity,
        })
    }

    /// Queue `f`, which receives the time it waited for a worker.
    ///
    /// Refuses at once with [`Refusal::Full`] when `workers + capacity`
    /// jobs are already admitted, and, given an `estimate`, with
    /// [`Refusal::Late`] when a worker would be free for it only after
    /// `timing.start_by` (see `State::free_at` for the model). The check
    /// and the queueing happen under one lock, so concurrent submissions
    /// each see the others.
    pub fn submit<T, F>(
        &self,
        timing: Timing,
        estimate: Option<Estimate>,
        f: F,
    ) -> Result<Ticket<T>, Refusal>
    where
        T: Send + 'static,
        F: FnOnce(Duration) -> T + Send + 'static,
    {
        let (done_tx, done_rx) = oneshot::channel();
        let submitted = Instant::now();
        let shared = Arc::clone(&self.shared);
        let job: Job = Box::new(move |worker| {
            let waited = submitted.elapsed();
            let outcome = catch_unwind(AssertUnwindSafe(|| f(waited)))
                .map_err(|p| Panicked(panic_message(&p)));
            // Free the slot before answering, so a caller that submits again
            // as soon as it has its answer finds the slot free.
            shared.lock().running[worker] = None;
            // The caller may have left while the job ran; nothing to do then.
            let _ = done_tx.send(Done {
                outcome,
                queued: waited,
            });
        });
        let mut st = self.shared.lock();
        if st.closed || st.running_count() + st.waiting_count() >= self.workers + self.capacity {
            return Err(Refusal::Full);
        }
        if let (Some(estimate), Some(start_by)) = (estimate, timing.start_by) {
            let now = Instant::now();
            if st.free_at(now, estimate, Some(start_by)).is_none() {
                // Past `start_by`: the walk stopped; how far past is
                // worked out in full for the caller's Retry-After.
                let at = st.free_at(now, estimate, None).unwrap_or(now);
                return Err(Refusal::Late {
                    wait: at.saturating_duration_since(now),
                });
            }
        }
        let id = st.enqueue(timing, job, false);
        let someone_waits = st.idle > 0;
        drop(st);
        if someone_waits {
            self.shared.wake.notify_one();
        }
        Ok(Ticket {
            rx: done_rx,
            id,
            shared: Arc::clone(&self.shared),
        })
    }

    /// Run `f` on an idle worker now, for a job already admitted (a start
    /// of its search, [`crate::solve::Helpers`]), or hand it back when no
    /// worker is idle: every worker busy, or as many idle as jobs queued
    /// for them. It goes ahead of the queue (only an idle worker takes it)
    /// and is not admitted itself: it takes no slot of the capacity, and
    /// admission's estimate leaves it out. `f` gets a check that says
    /// whether an admitted job is waiting for a worker; a lent job polls it
    /// between its pieces of work and ends, leaving the rest to its owner,
    /// once one is, so that it delays a later request by one piece at most.
    /// A panic in `f` is logged; its owner notices the missing work.
    pub fn lend(&self, timing: Timing, f: Lent) -> Result<(), Lent> {
        let mut st = self.shared.lock();
        if st.closed || st.idle <= st.queue.len() {
            return Err(f);
        }
        let shared = Arc::clone(&self.shared);
        let job: Job = Box::new(move |worker| {
            let waiting = || shared.lock().waiting_count() > 0;
            if let Err(p) = catch_unwind(AssertUnwindSafe(|| f(&waiting))) {
                tracing::error!(panic = %panic_message(&p), "a lent job panicked");
            }
            let mut st = shared.lock();
            st.running[worker] = None;
            st.lent[worker] = false;
        });
        st.enqueue(timing, job, true);
        drop(st);
        self.shared.wake.notify_one();
        Ok(())
    }

    /// The estimated wait for a worker of a job submitted now (see
    /// [`Pool::submit`]).
    pub fn wait(&self, estimate: Estimate) -> Duration {
        let now = Instant::now();
        let at = self.shared.lock().free_at(now, estimate, None);
        at.map_or(Duration::ZERO, |at| at.saturating_duration_since(now))
    }

    /// Admitted jobs waiting for a worker.
    pub fn queue_depth(&self) -> usize {
        self.shared.lock().waiting_count()
    }

    /// Workers waiting for a job. A worker counts only once its thread has
    /// reached its wait, so a pool just built may show fewer for a moment.
    #[cfg(test)]
    pub(crate) fn idle(&self) -> usize {
        self.shared.lock().idle
    }

    /// Workers running a lent job.
    pub fn lent(&self) -> usize {
        self.shared.lock().lent.iter().filter(|l| **l).count()
    }

    /// `(running, waiting)`, read under one lock so that a job moving from
    /// the queue to a worker is not counted in both.
    pub fn counts(&self) -> (usize, usize) {
        let st = self.shared.lock();
        (st.running_count(), st.waiting_count())
    }

    /// Number of worker threads.
    pub fn workers(&self) -> usize {
        self.workers
    }

    /// Queue capacity.
    pub fn capacity(&self) -> usize {
        self.capacity
    }
}

impl Drop for Pool {
    fn drop(&mut self) {
        self.shared.lock().closed = true;
        self.shared.wake.notify_all();
    }
}

/// An admitted job. Await [`Ticket::done`] for its outcome; drop the ticket
/// to withdraw the job if no worker has taken it yet.
pub struct Ticket<T> {
    rx: oneshot::Receiver<Done<T>>,
    id: u64,
    shared: Arc<Shared>,
}

impl<T> Ticket<T> {
    /// The job's outcome. `None` only if the job was lost, which would be a
    /// bug in this module (a worker drops a job only after running it).
    pub async fn done(&mut self) -> Option<Done<T>> {
        (&mut self.rx).await.ok()
    }

    /// Take the job out of the queue if it is still waiting there. Returns
    /// whether it was (so it will never run).
    pub fn withdraw(&self) -> bool {
        let mut st = self.shared.lock();
        match st.queue.iter().position(|q| q.id == self.id) {
            Some(pos) => {
                st.queue.remove(pos);
                true
            }
            None => false,
        }
    }
}

impl<T> Drop for Ticket<T> {
    fn drop(&mut self) {
        self.withdraw();
    }
}

fn worker(shared: &Shared, index: usize) {
    loop {
        let job = {
            let mut st = shared.lock();
            loop {
                if let Some(queued) = st.queue.pop_front() {
                    st.running[index] = Some((Instant::now(), queued.timing));
                    st.lent[index] = queued.lent;
                    break queued.job;
                }
                if st.closed {
                    return;
                }
                st.idle += 1;
                st = shared.wake.wait(st).unwrap_or_else(|p| p.into_inner());
                st.idle -= 1;
            }
        };
        // The job catches its own panics and frees its slot.
        job(index);
    }
}

fn panic_message(p: &Box<dyn std::any::Any + Send>) -> String {
    if let Some(s) = p.downcast_ref::<&str>() {
        (*s).to_owned()
    } else if let Some(s) = p.downcast_ref::<String>() {
        s.clone()
    } else {
        "non-string panic payload".to_owned()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::mpsc;

    /// Any time, no deadline: admitted by capacity alone.
    fn anytime() -> Timing {
        Timing::default()
    }

    /// Occupy a worker until the returned sender is used (or dropped); the
    /// worker has started when this returns.
    fn block_a_worker(pool: &Pool, timing: Timing) -> (Ticket<()>, mpsc::Sender<()>) {
        let (release_tx, release_rx) = mpsc::channel::<()>();
        let (started_tx, started_rx) = mpsc::channel::<()>();
        let ticket = pool
            .submit(timing, None, move |_| {
                started_tx.send(()).unwrap();
                let _ = release_rx.recv();
            })
            .unwrap();
        started_rx.recv().unwrap();
        (ticket, release_tx)
    }

    #[tokio::test]
    async fn a_panicking_job_is_reported_and_the_worker_survives() {
        let pool = Pool::new(1, 4).unwrap();
        let mut t = pool
            .submit(anytime(), None, |_| -> u32 { panic!("boom") })
            .unwrap();
        assert_eq!(
            t.done().await.unwrap().outcome,
            Err(Panicked("boom".into()))
        );
        // The only worker must still be alive to run this.
        let mut t = pool.submit(anytime(), None, |_| 7).unwrap();
        assert_eq!(t.done().await.unwrap().outcome, Ok(7));
        assert_eq!(pool.counts(), (0, 0));
    }

    #[tokio::test]
    async fn a_full_queue_rejects_at_once() {
        let pool = Pool::new(1, 1).unwrap();
        let (mut busy, release) = block_a_worker(&pool, anytime());
        let mut queued = pool.submit(anytime(), None, |waited| waited).unwrap(); // takes the one slot
        assert_eq!(pool.queue_depth(), 1);
        assert_eq!(pool.counts(), (1, 1)); // one running, one waiting
        assert_eq!(
            pool.submit(anytime(), None, |_| ()).err(),
            Some(Refusal::Full)
        );
        std::thread::sleep(Duration::from_millis(20));
        release.send(()).unwrap();
        busy.done().await.unwrap().outcome.unwrap();
        let done = queued.done().await.unwrap();
        // The job is told how long it waited, and so is its caller.
        assert!(done.queued >= Duration::from_millis(20));
        assert_eq!(done.outcome, Ok(done.queued));
        assert_eq!(pool.queue_depth(), 0);
        assert_eq!(pool.counts(), (0, 0));
    }

    #[tokio::test]
    async fn a_dropped_ticket_withdraws_its_job_and_frees_its_slot_at_once() {
        let pool = Pool::new(1, 1).unwrap();
        let ran = Arc::new(AtomicUsize::new(0));
        let (mut blocker, release) = block_a_worker(&pool, anytime());
        let r = Arc::clone(&ran);
        let abandoned = pool
            .submit(anytime(), None, move |_| r.fetch_add(1, Ordering::SeqCst))
            .unwrap();
        assert!(pool.submit(anytime(), None, |_| 0).is_err());
        drop(abandoned);
        // The slot is free while the worker is still busy.
        assert_eq!(pool.queue_depth(), 0);
        let r = Arc::clone(&ran);
        let mut next = pool
            .submit(anytime(), None, move |_| r.load(Ordering::SeqCst))
            .unwrap();
        release.send(()).unwrap();
        blocker.done().await.unwrap().outcome.unwrap();
        assert_eq!(next.done().await.unwrap().outcome, Ok(0));
        assert_eq!(ran.load(Ordering::SeqCst), 0, "the withdrawn job never ran");
    }

    #[tokio::test]
    async fn a_running_job_cannot_be_withdrawn() {
        let pool = Pool::new(1, 0).unwrap();
        let (mut t, release) = block_a_worker(&pool, anytime());
        assert!(!t.withdraw());
        release.send(()).unwrap();
        assert_eq!(t.done().await.unwrap().outcome, Ok(()));
    }

    /// A lent job runs at once on an idle worker, ahead of the queue, and
    /// takes no admission slot; it is told when an admitted job waits; with
    /// no worker idle it is handed back, not queued.
    #[tokio::test]
    async fn a_lent_job_runs_only_on_an_idle_worker_and_gives_way() {
        let pool = Pool::new(2, 0).unwrap();
        // Both workers have reached their wait.
        while pool.idle() < 2 {
            std::thread::sleep(Duration::from_millis(1));
        }
        let (_busy, release) = block_a_worker(&pool, anytime());
        let (told_tx, told_rx) = mpsc::channel();
        let (go_tx, go_rx) = mpsc::channel::<()>();
        let lent = pool.lend(
            anytime(),
            Box::new(move |waiting| {
                told_tx.send(waiting()).unwrap();
                let _ = go_rx.recv();
                told_tx.send(waiting()).unwrap();
            }),
        );
        assert!(lent.is_ok());
        assert_eq!(told_rx.recv_timeout(Duration::from_secs(5)), Ok(false));
        assert_eq!(pool.lent(), 1);
        // Both workers busy, but the lent one holds no slot: a request is
        // admitted (queue capacity 0), and the lent job is told it waits.
        assert_eq!(pool.counts(), (1, 0));
        let mut queued = pool.submit(anytime(), None, |_| 5).unwrap();
        // Nobody idle: handed back, not queued.
        let back = pool.lend(anytime(), Box::new(|_| ()));
        assert!(back.is_err());
        go_tx.send(()).unwrap();
        assert_eq!(told_rx.recv_timeout(Duration::from_secs(5)), Ok(true));
        assert_eq!(queued.done().await.unwrap().outcome, Ok(5));
        assert_eq!(pool.lent(), 0);
        drop(release);
    }

    /// Timing of a job due `budget` from now, of no use unless started by
    /// `start_within`.
    fn due(budget: Duration, start_within: Duration) -> Timing {
        let now = Instant::now();
        Timing {
            deadline: Some(now + budget),
            start_by: Some(now + start_within),
        }
    }

    /// With 100 ms of service per job, one worker busy for another ~100 ms
    /// and two jobs queued, a worker is free for the next one in ~300 ms:
    /// one that must start within 250 ms is refused with that estimate,
    /// one that may start within 400 ms is queued.
    #[tokio::test]
    async fn a_job_that_could_not_start_in_time_is_refused() {
        let pool = Pool::new(1, 8).unwrap();
        let service = Estimate {
            service: Duration::from_millis(100),
        };
        let estimate = Some(service);
        let (_busy, release) = block_a_worker(&pool, anytime());
        let queued: Vec<_> = (0..2)
            .map(|_| pool.submit(anytime(), estimate, |_| ()).unwrap())
            .collect();
        let wait = pool.wait(service);
        assert!(
            (Duration::from_millis(280)..=Duration::from_millis(300)).contains(&wait),
            "{wait:?}"
        );
        let late = pool.submit(
            due(Duration::from_secs(1), Duration::from_millis(250)),
            estimate,
            |_| (),
        );
        match late.err() {
            Some(Refusal::Late { wait }) => assert!(
                (Duration::from_millis(280)..=Duration::from_millis(300)).contains(&wait),
                "{wait:?}"
            ),
            other => panic!("{other:?}"),
        }
        assert_eq!(pool.counts(), (1, 2), "the refused job was not queued");
        assert!(
            pool.submit(
                due(Duration::from_secs(1), Duration::from_millis(400)),
                estimate,
                |_| ()
            )
            .is_ok()
        );
        // Without an estimate only the capacity counts.
        assert!(
            pool.submit(due(Duration::ZERO, Duration::ZERO), None, |_| ())
                .is_ok()
        );
        drop(queued);
        drop(release);
    }

    /// Jobs ahead are counted for what they can still take: one that would
    /// start past its own `start_by` is skipped (its caller withdraws it
    /// then), and one holds its worker until its deadline at most.
    #[tokio::test]
    async fn the_wait_counts_what_the_jobs_ahead_can_still_take() {
        let pool = Pool::new(1, 8).unwrap();
        let estimate = Estimate {
            service: Duration::from_secs(10),
        };
        // The running job's budget ends in 100 ms, well before 10 s.
        let (_busy, release) =
            block_a_worker(&pool, due(Duration::from_millis(100), Duration::ZERO));
        // Would start at ~100 ms, past its start_by of 50 ms: skipped.
        let _expiring = pool
            .submit(
                due(Duration::from_secs(1), Duration::from_millis(50)),
                None,
                |_| (),
            )
            .unwrap();
        // Starts at ~100 ms and holds the worker until its deadline at 300 ms.
        let _short = pool
            .submit(
                due(Duration::from_millis(300), Duration::from_millis(200)),
                None,
                |_| (),
            )
            .unwrap();
        let wait = pool.wait(estimate);
        assert!(
            (Duration::from_millis(280)..=Duration::from_millis(300)).contains(&wait),
            "{wait:?}"
        );
        drop(release);
    }
}
