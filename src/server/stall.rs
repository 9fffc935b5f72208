//! A connection whose client stops reading its answer is closed after the
//! read timeout.
//!
//! hyper has no write timeout: a client that sends a request and then
//! never reads (or reads a few bytes a minute) keeps its connection, and
//! the answer hyper is writing, for as long as the TCP connection lives. A
//! long horizon's answer is megabytes, so a hundred such clients hold
//! hundreds of MB until they close. [`WriteStall`] wraps the socket: once a write
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
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use axum::body::Bytes;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::time::{Instant, Sleep};

use super::body::ByteBudget;

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
    bytes: ByteBudget,
}

impl AnswerBudget {
    pub(crate) fn new(limit: usize) -> Arc<Self> {
        Arc::new(Self {
            bytes: ByteBudget::new(limit),
        })
    }

    /// Bytes held now, over all answers being sent.
    pub(crate) fn used(&self) -> usize {
        self.bytes.used()
    }

    /// Whether no answer could be held now: the budget is used up (or
    /// past it, by one answer larger than the limit).
    pub(crate) fn is_full(&self) -> bool {
        self.bytes.free() == 0
    }

    /// `answer` as a body that holds its size in the budget until its last
    /// reference is dropped, or `answer` back if it does not fit. One
    /// answer always fits into an empty budget, whatever its size, so an
    /// answer larger than the limit is sent when it is the only one.
    pub(crate) fn hold(self: &Arc<Self>, answer: Vec<u8>) -> Result<Bytes, Vec<u8>> {
        // The allocation, not the text: the encoder reserves ahead, about
        // a fifth more than it writes.
        let held = answer.capacity();
        if !self.bytes.take(held, true) {
            return Err(answer);
        }
        Ok(Bytes::from_owner(HeldAnswer {
            answer,
            held,
            budget: Arc::clone(self),
        }))
    }
}

/// An answer's bytes and its share of the [`AnswerBudget`], given back
/// when hyper drops the last reference (written out, or the connection
/// gone).
struct HeldAnswer {
    answer: Vec<u8>,
    /// What was taken from the budget: the allocation's size.
    held: usize,
    budget: Arc<AnswerBudget>,
}

impl AsRef<[u8]> for HeldAnswer {
    fn as_ref(&self) -> &[u8] {
        &self.answer
    }
}

impl Drop for HeldAnswer {
    fn drop(&mut self) {
        self.budget.bytes.give_back(self.held);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    /// A connected pair over loopback with small buffers (a few KiB in
    /// flight instead of megabytes), the writer wrapped with `limit`.
    async fn pair(limit: Duration) -> (WriteStall<tokio::net::TcpStream>, tokio::net::TcpStream) {
        let listener = tokio::net::TcpSocket::new_v4().unwrap();
        listener.set_recv_buffer_size(4096).unwrap();
        listener.bind("127.0.0.1:0".parse().unwrap()).unwrap();
        let listener = listener.listen(1).unwrap();
        let writer = tokio::net::TcpSocket::new_v4().unwrap();
        writer.set_send_buffer_size(4096).unwrap();
        let (writer, reader) = tokio::join!(
            writer.connect(listener.local_addr().unwrap()),
            listener.accept()
        );
        (WriteStall::new(writer.unwrap(), limit), reader.unwrap().0)
    }

    /// A peer that reads nothing: the write fails with `TimedOut` once the
    /// buffers are full and the limit has passed.
    #[tokio::test]
    async fn a_write_nobody_reads_times_out() {
        let (mut writer, _reader) = pair(Duration::from_millis(200)).await;
        let started = std::time::Instant::now();
        let err = writer.write_all(&vec![7; 4 << 20]).await.unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::TimedOut);
        let took = started.elapsed();
        assert!(took >= Duration::from_millis(200), "{took:?}");
        assert!(took < Duration::from_secs(5), "{took:?}");
    }

    /// A peer that reads slowly but steadily (4 KiB every 50 ms, for well
    /// over the 200 ms limit in all) is not cut off: progress restarts the
    /// clock. The wrapper stays vectored, so hyper queues answers without
    /// copying them and the budget follows their bytes.
    #[tokio::test]
    async fn a_slow_steady_reader_is_not_cut_off() {
        let (mut writer, mut reader) = pair(Duration::from_millis(200)).await;
        assert!(writer.is_write_vectored());
        let total = 96 * 1024;
        let read = tokio::spawn(async move {
            let (mut got, mut buf) = (0, vec![0; 4096]);
            while got < total {
                tokio::time::sleep(Duration::from_millis(50)).await;
                got += reader.read(&mut buf).await.unwrap();
            }
            got
        });
        let started = std::time::Instant::now();
        writer.write_all(&vec![7; total]).await.unwrap();
        writer.flush().await.unwrap();
        assert_eq!(read.await.unwrap(), total);
        assert!(
            started.elapsed() > Duration::from_millis(400),
            "the buffers took it all"
        );
    }

    /// Held while any reference lives, given back after the last; one
    /// answer larger than the limit passes an empty budget only.
    #[test]
    fn answers_hold_their_bytes_until_dropped() {
        let budget = AnswerBudget::new(10);
        let a = budget.hold(vec![1; 6]).unwrap();
        let a2 = a.clone();
        assert_eq!(budget.used(), 6);
        assert!(!budget.is_full());
        assert_eq!(budget.hold(vec![2; 5]).unwrap_err().len(), 5);
        drop(a);
        assert_eq!(budget.used(), 6, "a clone still holds the bytes");
        drop(a2);
        assert_eq!(budget.used(), 0);
        let big = budget.hold(vec![3; 50]).unwrap();
        assert_eq!(&big[..2], &[3, 3]);
        assert!(budget.is_full());
        assert!(budget.hold(vec![4; 1]).is_err());
        drop(big);
        assert_eq!(budget.used(), 0);
        // The allocation is what counts, not the text in it.
        let mut reserved = Vec::with_capacity(8);
        reserved.push(1u8);
        let r = budget.hold(reserved).unwrap();
        assert_eq!(budget.used(), 8);
        drop(r);
        assert_eq!(budget.used(), 0);
    }
}
