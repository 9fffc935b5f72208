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
//!   returns [`Full`] at once, and the HTTP layer answers 503;
//! * a job is withdrawn from the queue when its [`Ticket`] is dropped before
//!   a worker took it (the client went away), so an abandoned request frees
//!   its slot at once instead of holding it until a worker gets there;
//! * a caller may also take its job back out of the queue to run it on a
//!   thread of its own ([`Ticket::claim`]; the HTTP layer does so when a
//!   solve's time budget runs out while it waits). The job keeps its slot
//!   until it has run, so the limit above still holds;
//! * a panicking job is caught with `catch_unwind` and reported to its caller
//!   as [`Panicked`]; the worker thread lives on.
//!
//! The queue is short (its capacity is a configuration value in the tens),
//! so withdrawing by a linear search under the lock costs nothing next to a
//! solve.

use std::collections::VecDeque;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use tokio::sync::oneshot;

type Job = Box<dyn FnOnce() + Send + 'static>;

/// The queue was full.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Full;

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

struct State {
    queue: VecDeque<(u64, Job)>,
    running: usize,
    /// Workers blocked on `wake`. `Condvar::notify_one` is a system call
    /// even with nobody waiting; under load every worker is busy and the
    /// next job is taken from the queue without one.
    idle: usize,
    next_id: u64,
    closed: bool,
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
                running: 0,
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
                .spawn(move || worker(&shared))?;
        }
        Ok(Self {
            shared,
            workers,
            capacity,
        })
    }

    /// Queue `f`, which receives the time it waited for a worker. Fails at
    /// once with [`Full`] when `workers + capacity` jobs are already admitted.
    pub fn submit<T, F>(&self, f: F) -> Result<Ticket<T>, Full>
    where
        T: Send + 'static,
        F: FnOnce(Duration) -> T + Send + 'static,
    {
        let (done_tx, done_rx) = oneshot::channel();
        let submitted = Instant::now();
        let shared = Arc::clone(&self.shared);
        let job: Job = Box::new(move || {
            let waited = submitted.elapsed();
            let outcome = catch_unwind(AssertUnwindSafe(|| f(waited)))
                .map_err(|p| Panicked(panic_message(&p)));
            // Free the slot before answering, so a caller that submits again
            // as soon as it has its answer finds the slot free.
            shared.lock().running -= 1;
            // The caller may have left while the job ran; nothing to do then.
            let _ = done_tx.send(Done {
                outcome,
                queued: waited,
            });
        });
        let mut st = self.shared.lock();
        if st.closed || st.running + st.queue.len() >= self.workers + self.capacity {
            return Err(Full);
        }
        let id = st.next_id;
        st.next_id += 1;
        st.queue.push_back((id, job));
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

    /// Jobs waiting for a worker.
    pub fn queue_depth(&self) -> usize {
        self.shared.lock().queue.len()
    }

    /// `(running, waiting)`, read under one lock so that a job moving from
    /// the queue to a worker is not counted in both. Running includes jobs
    /// claimed by their caller ([`Ticket::claim`]), which run (or wait to
    /// run) on a thread of their own, so it can exceed [`Pool::workers`]
    /// (up to `workers + capacity`).
    pub fn counts(&self) -> (usize, usize) {
        let st = self.shared.lock();
        (st.running, st.queue.len())
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
        match st.queue.iter().position(|(id, _)| *id == self.id) {
            Some(pos) => {
                st.queue.remove(pos);
                true
            }
            None => false,
        }
    }

    /// Take the job out of the queue, if it is still waiting there, to run
    /// it elsewhere ([`Claimed::run`] does what a worker would; the outcome
    /// arrives through [`Ticket::done`]). Until it has run the job counts
    /// as running, so it keeps its slot.
    pub fn claim(&self) -> Option<Claimed> {
        let mut st = self.shared.lock();
        let pos = st.queue.iter().position(|(id, _)| *id == self.id)?;
        let (_, job) = st.queue.remove(pos)?;
        // The job gives the slot back when it ends, as under a worker.
        st.running += 1;
        Some(Claimed {
            job: Some(job),
            shared: Arc::clone(&self.shared),
        })
    }
}

/// A job taken back from the queue by [`Ticket::claim`]. Dropped without
/// having run (its caller left first, or the thread meant for it never
/// started), it gives its slot back, and [`Ticket::done`] returns `None`.
pub struct Claimed {
    job: Option<Job>,
    shared: Arc<Shared>,
}

impl Claimed {
    /// Run the job here, as a worker would (panics caught, slot returned).
    pub fn run(mut self) {
        if let Some(job) = self.job.take() {
            job();
        }
    }
}

impl Drop for Claimed {
    fn drop(&mut self) {
        if self.job.is_some() {
            self.shared.lock().running -= 1;
        }
    }
}

impl<T> Drop for Ticket<T> {
    fn drop(&mut self) {
        self.withdraw();
    }
}

fn worker(shared: &Shared) {
    loop {
        let job = {
            let mut st = shared.lock();
            loop {
                if let Some((_, job)) = st.queue.pop_front() {
                    st.running += 1;
                    break job;
                }
                if st.closed {
                    return;
                }
                st.idle += 1;
                st = shared.wake.wait(st).unwrap_or_else(|p| p.into_inner());
                st.idle -= 1;
            }
        };
        // The job itself catches panics and gives its slot back.
        job();
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

    /// Occupy a worker until the returned sender is used (or dropped); the
    /// worker has started when this returns.
    fn block_a_worker(pool: &Pool) -> (Ticket<()>, mpsc::Sender<()>) {
        let (release_tx, release_rx) = mpsc::channel::<()>();
        let (started_tx, started_rx) = mpsc::channel::<()>();
        let ticket = pool
            .submit(move |_| {
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
        let mut t = pool.submit(|_| -> u32 { panic!("boom") }).unwrap();
        assert_eq!(
            t.done().await.unwrap().outcome,
            Err(Panicked("boom".into()))
        );
        // The only worker must still be alive to run this.
        let mut t = pool.submit(|_| 7).unwrap();
        assert_eq!(t.done().await.unwrap().outcome, Ok(7));
    }

    #[tokio::test]
    async fn a_full_queue_rejects_at_once() {
        let pool = Pool::new(1, 1).unwrap();
        let (mut busy, release) = block_a_worker(&pool);
        let mut queued = pool.submit(|waited| waited).unwrap(); // takes the one slot
        assert_eq!(pool.queue_depth(), 1);
        assert_eq!(pool.counts(), (1, 1)); // one running, one waiting
        assert!(matches!(pool.submit(|_| ()), Err(Full)));
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
        let (mut blocker, release) = block_a_worker(&pool);
        let r = Arc::clone(&ran);
        let abandoned = pool
            .submit(move |_| r.fetch_add(1, Ordering::SeqCst))
            .unwrap();
        assert!(matches!(pool.submit(|_| 0), Err(Full)));
        drop(abandoned);
        // The slot is free while the worker is still busy.
        assert_eq!(pool.queue_depth(), 0);
        let r = Arc::clone(&ran);
        let mut next = pool.submit(move |_| r.load(Ordering::SeqCst)).unwrap();
        release.send(()).unwrap();
        blocker.done().await.unwrap().outcome.unwrap();
        assert_eq!(next.done().await.unwrap().outcome, Ok(0));
        assert_eq!(ran.load(Ordering::SeqCst), 0, "the withdrawn job never ran");
    }

    #[tokio::test]
    async fn a_claimed_job_runs_on_the_callers_thread_and_keeps_its_slot() {
        let pool = Pool::new(1, 1).unwrap();
        let (mut blocker, release) = block_a_worker(&pool);
        let mut queued = pool
            .submit(|_| std::thread::current().name().map(str::to_owned))
            .unwrap();
        let claimed = queued.claim().expect("still queued");
        assert!(queued.claim().is_none(), "claimed once only");
        assert_eq!(pool.queue_depth(), 0);
        // Taken out of the queue but not yet run: its slot is still taken.
        assert!(matches!(pool.submit(|_| ()), Err(Full)));
        std::thread::Builder::new()
            .name("claimer".into())
            .spawn(|| claimed.run())
            .unwrap()
            .join()
            .unwrap();
        let done = queued.done().await.unwrap();
        assert_eq!(done.outcome, Ok(Some("claimer".to_owned())));
        // Run and answered: the slot is free again, with the worker busy.
        let mut next = pool.submit(|_| None::<String>).unwrap();
        release.send(()).unwrap();
        blocker.done().await.unwrap().outcome.unwrap();
        assert_eq!(next.done().await.unwrap().outcome, Ok(None));
    }

    #[tokio::test]
    async fn a_claimed_job_dropped_unrun_gives_its_slot_back() {
        let pool = Pool::new(1, 1).unwrap();
        let (mut blocker, release) = block_a_worker(&pool);
        let mut queued = pool.submit(|_| ()).unwrap();
        let claimed = queued.claim().expect("still queued");
        assert!(matches!(pool.submit(|_| ()), Err(Full)));
        drop(claimed);
        assert!(queued.done().await.is_none(), "no outcome: it never ran");
        let mut next = pool.submit(|_| 5).unwrap();
        release.send(()).unwrap();
        blocker.done().await.unwrap().outcome.unwrap();
        assert_eq!(next.done().await.unwrap().outcome, Ok(5));
    }

    #[tokio::test]
    async fn a_running_job_cannot_be_withdrawn() {
        let pool = Pool::new(1, 0).unwrap();
        let (mut t, release) = block_a_worker(&pool);
        assert!(!t.withdraw());
        release.send(()).unwrap();
        assert_eq!(t.done().await.unwrap().outcome, Ok(()));
    }
}
