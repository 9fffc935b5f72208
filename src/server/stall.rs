//! A connection whose client stops reading its answer is closed after the
//! read timeout.
//!
//! hyper has no write timeout: a client that sends a request and then
//! never reads (or reads a few bytes a minute) keeps its connection, and
//! the answer hyper is writing, for as long as the TCP connection lives. A
//! long horizon's answer is megabytes, so a review's 100 such clients held
//! 433 MB until they closed. [`WriteStall`] wraps the socket: once a write
//! has made no progress (the kernel's send buffer full) for the limit, the
//! write fails with `TimedOut`, hyper drops the connection, and the answer
//! is freed. A slow reader that takes a byte now and then is not stalled:
//! any progress restarts the clock.
//!
//! Limits: it bounds how long an answer is held, not how many are held at
//! once; reads are not covered (hyper's header read timeout and the body
//! read timeout do that).

use std::io;
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::time::{Instant, Sleep};

/// `inner`, whose writes fail once they have been stalled for `limit`.
pub(crate) struct WriteStall<T> {
    inner: T,
    limit: Duration,
    /// Armed when a write first returns `Pending`; rearmed after progress.
    timer: Pin<Box<Sleep>>,
    stalled: bool,
}

impl<T> WriteStall<T> {
    pub(crate) fn new(inner: T, limit: Duration) -> Self {
        Self {
            inner,
            limit,
            timer: Box::pin(tokio::time::sleep(limit)),
            stalled: false,
        }
    }
}

impl<T: AsyncWrite + Unpin> WriteStall<T> {
    /// Runs one write-side poll of the inner socket under the stall clock.
    /// A `Pending` also polls the timer, so the task is woken when the
    /// limit passes even if the socket never becomes writable again.
    fn guard<R>(
        &mut self,
        cx: &mut Context<'_>,
        poll: impl FnOnce(Pin<&mut T>, &mut Context<'_>) -> Poll<io::Result<R>>,
    ) -> Poll<io::Result<R>> {
        match poll(Pin::new(&mut self.inner), cx) {
            Poll::Pending => {
                if !self.stalled {
                    self.stalled = true;
                    let deadline = Instant::now()
                        .checked_add(self.limit)
                        .unwrap_or_else(|| Instant::now() + Duration::from_secs(86_400 * 365));
                    self.timer.as_mut().reset(deadline);
                }
                match self.timer.as_mut().poll(cx) {
                    Poll::Ready(()) => Poll::Ready(Err(io::Error::new(
                        io::ErrorKind::TimedOut,
                        "the client read nothing of the answer for the read timeout",
                    ))),
                    Poll::Pending => Poll::Pending,
                }
            }
            ready => {
                self.stalled = false;
                ready
            }
        }
    }
}

impl<T: AsyncRead + Unpin> AsyncRead for WriteStall<T> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_read(cx, buf)
    }
}

impl<T: AsyncWrite + Unpin> AsyncWrite for WriteStall<T> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        self.guard(cx, |inner, cx| inner.poll_write(cx, buf))
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        self.guard(cx, |inner, cx| inner.poll_write_vectored(cx, bufs))
    }

    /// Forwarded: hyper queues an answer's body without copying it only
    /// on a socket that takes vectored writes.
    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        self.guard(cx, |inner, cx| inner.poll_flush(cx))
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        self.guard(cx, |inner, cx| inner.poll_shutdown(cx))
    }
}

/// Bytes that the answers being sent may hold together: the other half of
/// bounding what slow readers cost. [`WriteStall`] frees a stalled answer
/// after the read timeout; this bounds how many bytes of answers wait
/// meanwhile. An answer is held from when it is encoded until hyper has
/// written its last byte or dropped its connection ([`AnswerBudget::hold`]
/// ties the count to the bytes themselves).
#[derive(Debug)]
pub(crate) struct AnswerBudget {
    limit: usize,
    used: std::sync::atomic::AtomicUsize,
}

impl AnswerBudget {
    pub(crate) fn new(limit: usize) -> std::sync::Arc<Self> {
        std::sync::Arc::new(Self {
            limit,
            used: std::sync::atomic::AtomicUsize::new(0),
        })
    }

    /// Bytes held now, over all answers being sent.
    pub(crate) fn used(&self) -> usize {
        self.used.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// `answer` as a body that holds its length in the budget until its
    /// last reference is dropped, or `answer` back if it does not fit. One
    /// answer always fits into an empty budget, whatever its size, so an
    /// answer larger than the limit is sent when it is the only one.
    pub(crate) fn hold(
        self: &std::sync::Arc<Self>,
        answer: Vec<u8>,
    ) -> Result<axum::body::Bytes, Vec<u8>> {
        use std::sync::atomic::Ordering;
        let len = answer.len();
        let taken = self
            .used
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |used| {
                used.checked_add(len)
                    .filter(|&total| total <= self.limit || used == 0)
            })
            .is_ok();
        if !taken {
            return Err(answer);
        }
        Ok(axum::body::Bytes::from_owner(HeldAnswer {
            answer,
            budget: std::sync::Arc::clone(self),
        }))
    }
}

/// An answer's bytes and its share of the [`AnswerBudget`], given back
/// when hyper drops the last reference (written out, or the connection
/// gone).
struct HeldAnswer {
    answer: Vec<u8>,
    budget: std::sync::Arc<AnswerBudget>,
}

impl AsRef<[u8]> for HeldAnswer {
    fn as_ref(&self) -> &[u8] {
        &self.answer
    }
}

impl Drop for HeldAnswer {
    fn drop(&mut self) {
        self.budget
            .used
            .fetch_sub(self.answer.len(), std::sync::atomic::Ordering::AcqRel);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Held while any reference lives, given back after the last; one
    /// answer larger than the limit passes an empty budget only.
    #[test]
    fn answers_hold_their_bytes_until_dropped() {
        let budget = AnswerBudget::new(10);
        let a = budget.hold(vec![1; 6]).unwrap();
        let a2 = a.clone();
        assert_eq!(budget.used(), 6);
        assert_eq!(budget.hold(vec![2; 5]).unwrap_err().len(), 5);
        drop(a);
        assert_eq!(budget.used(), 6, "a clone still holds the bytes");
        drop(a2);
        assert_eq!(budget.used(), 0);
        let big = budget.hold(vec![3; 50]).unwrap();
        assert_eq!(&big[..2], &[3, 3]);
        assert!(budget.hold(vec![4; 1]).is_err());
        drop(big);
        assert_eq!(budget.used(), 0);
    }
}
