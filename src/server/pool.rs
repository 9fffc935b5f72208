//! The solver pool: a fixed set of worker threads behind a bounded queue.
//!
//! Solves are CPU-bound and take milliseconds to seconds, so they must not
//! run on the async runtime. `tokio::task::spawn_blocking` would grow to 512
//! threads, and rayon aborts the process when a job panics unless a handler
//! is installed; a small pool of our own states its limits plainly:
//!
//! * `workers` threads take jobs from one FIFO queue; at most
//!   `workers + capacity` jobs are admitted at once (running or waiting);
//! * [`Pool::submit`] never waits: when every slot is taken it returns
//!   [`Full`] at once, and the HTTP layer answers 503. Slots are counted
//!   with an atomic, not by the channel, so the answer does not depend on
//!   whether a worker happens to be parked in `recv` at that instant;
//! * a job whose caller has gone away before it starts (its result receiver
//!   was dropped) is skipped;
//! * a panicking job is caught with `catch_unwind` and reported to its caller
//!   as [`Panicked`]; the worker thread lives on.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, Sender, channel};
use std::sync::{Arc, Mutex};
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
    tx: Sender<Job>,
    /// Jobs submitted and not yet started.
    queued: Arc<AtomicUsize>,
    /// Free admission slots: `workers + capacity` minus jobs admitted and
    /// not yet finished.
    free: Arc<AtomicUsize>,
    workers: usize,
    capacity: usize,
}

impl Pool {
    /// Start `workers` threads (at least 1) behind a queue of `capacity`
    /// waiting jobs. The threads end when the pool is dropped and the queue
    /// drains.
    pub fn new(workers: usize, capacity: usize) -> std::io::Result<Self> {
        let workers = workers.max(1);
        let (tx, rx) = channel::<Job>();
        let rx = Arc::new(Mutex::new(rx));
        for i in 0..workers {
            let rx = Arc::clone(&rx);
            std::thread::Builder::new()
                .name(format!("solver-{i}"))
                .spawn(move || worker(&rx))?;
        }
        Ok(Self {
            tx,
            queued: Arc::new(AtomicUsize::new(0)),
            free: Arc::new(AtomicUsize::new(workers + capacity)),
            workers,
            capacity,
        })
    }

    /// Queue `f`; the receiver yields its outcome. Fails at once with [`Full`]
    /// when `capacity` jobs are already waiting.
    pub fn submit<T, F>(&self, f: F) -> Result<oneshot::Receiver<Done<T>>, Full>
    where
        T: Send + 'static,
        F: FnOnce() -> T + Send + 'static,
    {
        // Take a slot or fail at once.
        self.free
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| n.checked_sub(1))
            .map_err(|_| Full)?;
        let (done_tx, done_rx) = oneshot::channel();
        let queued = Arc::clone(&self.queued);
        let slot = SlotGuard(Arc::clone(&self.free));
        let submitted = Instant::now();
        let job: Job = Box::new(move || {
            let _slot = slot; // freed when the job ends, panic or not
            queued.fetch_sub(1, Ordering::Relaxed);
            if done_tx.is_closed() {
                return; // the caller left while we were queued
            }
            let waited = submitted.elapsed();
            let outcome =
                catch_unwind(AssertUnwindSafe(f)).map_err(|p| Panicked(panic_message(&p)));
            let _ = done_tx.send(Done {
                outcome,
                queued: waited,
            });
        });
        self.queued.fetch_add(1, Ordering::Relaxed);
        // Sending fails only if every worker thread is gone; the job (and
        // its slot) is dropped with the error.
        self.tx.send(job).map_err(|_| {
            self.queued.fetch_sub(1, Ordering::Relaxed);
            Full
        })?;
        Ok(done_rx)
    }

    /// Jobs waiting for a worker.
    pub fn queue_depth(&self) -> usize {
        self.queued.load(Ordering::Relaxed)
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

/// Returns its admission slot when dropped.
struct SlotGuard(Arc<AtomicUsize>);

impl Drop for SlotGuard {
    fn drop(&mut self) {
        self.0.fetch_add(1, Ordering::AcqRel);
    }
}

fn worker(rx: &Mutex<Receiver<Job>>) {
    loop {
        // Hold the lock only while taking a job, not while running it.
        let job = match rx.lock() {
            Ok(guard) => guard.recv(),
            Err(poisoned) => poisoned.into_inner().recv(),
        };
        match job {
            Ok(job) => job(),
            Err(_) => return, // pool dropped
        }
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

    #[tokio::test]
    async fn a_panicking_job_is_reported_and_the_worker_survives() {
        let pool = Pool::new(1, 4).unwrap();
        let rx = pool.submit(|| -> u32 { panic!("boom") }).unwrap();
        let done = rx.await.unwrap();
        assert_eq!(done.outcome, Err(Panicked("boom".into())));
        // The only worker must still be alive to run this.
        let rx = pool.submit(|| 7).unwrap();
        assert_eq!(rx.await.unwrap().outcome, Ok(7));
    }

    #[tokio::test]
    async fn a_full_queue_rejects_at_once() {
        let pool = Pool::new(1, 1).unwrap();
        let (release_tx, release_rx) = std::sync::mpsc::channel::<()>();
        let (started_tx, started_rx) = std::sync::mpsc::channel::<()>();
        let busy = pool
            .submit(move || {
                started_tx.send(()).unwrap();
                release_rx.recv().unwrap();
            })
            .unwrap();
        started_rx.recv().unwrap(); // the worker is busy
        let queued = pool.submit(|| ()).unwrap(); // takes the one slot
        assert_eq!(pool.queue_depth(), 1);
        assert!(matches!(pool.submit(|| ()), Err(Full)));
        release_tx.send(()).unwrap();
        busy.await.unwrap().outcome.unwrap();
        queued.await.unwrap().outcome.unwrap();
        assert_eq!(pool.queue_depth(), 0);
    }

    #[tokio::test]
    async fn a_job_whose_caller_left_is_skipped() {
        let pool = Pool::new(1, 2).unwrap();
        let ran = Arc::new(AtomicUsize::new(0));
        let (release_tx, release_rx) = std::sync::mpsc::channel::<()>();
        let blocker = pool.submit(move || release_rx.recv().unwrap()).unwrap();
        let r = Arc::clone(&ran);
        drop(
            pool.submit(move || r.fetch_add(1, Ordering::SeqCst))
                .unwrap(),
        );
        release_tx.send(()).unwrap();
        blocker.await.unwrap().outcome.unwrap();
        let r = Arc::clone(&ran);
        pool.submit(move || r.load(Ordering::SeqCst))
            .unwrap()
            .await
            .unwrap()
            .outcome
            .unwrap();
        assert_eq!(ran.load(Ordering::SeqCst), 0);
    }
}
