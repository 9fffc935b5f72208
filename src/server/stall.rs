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
