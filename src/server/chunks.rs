//! The chunk sizes a chunked request body declares, read off the wire.
//!
//! A body with a `Content-Length` over `--max-body-bytes` is refused from
//! its headers (`body::read_with`). A chunked one declares its size chunk
//! by chunk, each on a size line (`ffffff\r\n`), but hyper decodes those
//! lines itself and hands on only the bytes that arrived: from the body
//! alone, a client that declares a 16 MB chunk and then sends nothing more
//! is seen only when the read timeout (30 s by default) ends its read, as
//! a 408.
//!
//! [`Sniff`] wraps a connection's socket and feeds every byte read to a
//! small parser of HTTP/1.1 message framing ([`Framing`]) that follows
//! hyper's: request heads (only where they end, and their
//! `Transfer-Encoding` and `Content-Length`), bodies of a given length, and
//! chunked bodies with hyper's chunk grammar (size, extensions, data,
//! trailers). It counts the requests on the connection and adds up the
//! chunk sizes declared in the body of the latest one. The `/solve`
//! handler knows which request of its connection it is ([`Declared`], set
//! per request when hyper calls the service, in order), and refuses with
//! 413 as soon as its request has declared more than the limit.
//!
//! Limits: it reads framing only, trusting hyper to refuse what is
//! malformed (hyper then closes the connection, so nothing after it
//! matters). Where it cannot follow the framing (a line it does not expect,
//! a `CONNECT`, a head line over [`MAX_LINE`] bytes that names the
//! framing), it stops for the rest of the connection and refuses nothing
//! more: a body is then limited only as it arrives, as without it.

use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::sync::Notify;

/// Longest head line kept whole, in bytes: enough for any
/// `Transfer-Encoding` or `Content-Length` line a client sends. Longer
/// lines are scanned, not kept.
pub(crate) const MAX_LINE: usize = 1024;

/// What one connection's requests have declared, shared by its socket
/// ([`Sniff`]) and its requests ([`Declared`]).
#[derive(Debug, Default)]
pub(crate) struct Watch {
    framing: Mutex<Framing>,
    /// Signalled when the latest request declares another chunk.
    changed: Notify,
}

impl Watch {
    fn feed(&self, bytes: &[u8]) {
        let declared = {
            let mut framing = self.framing.lock().unwrap_or_else(|p| p.into_inner());
            let before = (framing.requests, framing.declared);
            framing.feed(bytes);
            (framing.requests, framing.declared) != before
        };
        if declared {
            self.changed.notify_waiters();
        }
    }

    /// Chunk bytes declared so far by the body of request `request`
    /// (0-based on the connection); `None` once the parser is past it or
    /// has stopped.
    fn declared(&self, request: u64) -> Option<u64> {
        let framing = self.framing.lock().unwrap_or_else(|p| p.into_inner());
        (!framing.lost && framing.requests == request + 1).then_some(framing.declared)
    }
}

/// The `/solve` handler's view: which request of its connection it is.
/// Set per request in `server::run`.
#[derive(Debug, Clone)]
pub(crate) struct Declared {
    pub(crate) watch: Arc<Watch>,
    pub(crate) request: u64,
}

impl Declared {
    /// Resolves once this request's body has declared more than `limit`
    /// bytes of chunks; never, if it does not.
    pub(crate) async fn over(&self, limit: usize) {
        loop {
            let changed = self.watch.changed.notified();
            if self
                .watch
                .declared(self.request)
                .is_some_and(|n| n > limit as u64)
            {
                return;
            }
            changed.await;
        }
    }
}

/// Numbers a connection's requests as hyper hands them to the service.
#[derive(Debug, Clone, Default)]
pub(crate) struct Counter(Arc<AtomicU64>);

impl Counter {
    pub(crate) fn next(&self) -> u64 {
        self.0.fetch_add(1, Ordering::Relaxed)
    }
}

/// Where the parser is in the byte stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
enum At {
    /// Before a request line (empty lines are skipped, as httparse does).
    #[default]
    Start,
    /// In a head, after its request line.
    Head,
    /// In a body of a known length: bytes left.
    Length(u64),
    /// Chunked: the first hex digit of a size line.
    SizeStart,
    /// More hex digits of a size.
    Size,
    /// Whitespace after the size.
    SizeLws,
    /// A chunk extension, up to its CR.
    Extension,
    /// The LF of a size line.
    SizeLf,
    /// Chunk data: bytes left.
    Data(u64),
    DataCr,
    DataLf,
    /// After the last chunk: an empty line or a trailer.
    EndCr,
    Trailer,
    TrailerLf,
    EndLf,
}

/// An HTTP/1.1 request stream's framing (see the module's doc).
#[derive(Debug, Default)]
struct Framing {
    at: At,
    /// The head line being read, up to [`MAX_LINE`] bytes.
    line: Vec<u8>,
    /// Whether the line being read went past [`MAX_LINE`].
    long: bool,
    /// Of the head being read: its last `Transfer-Encoding` names
    /// `chunked` last (`Some(false)` if it names something else).
    chunked: Option<bool>,
    /// Of the head being read: its `Content-Length`.
    length: Option<u64>,
    /// Chunk size being read.
    size: u64,
    /// Heads read so far; the latest is request `requests - 1`.
    requests: u64,
    /// Chunk bytes its body has declared.
    declared: u64,
    /// Could not follow: stopped for good.
    lost: bool,
}

impl Framing {
    fn feed(&mut self, mut bytes: &[u8]) {
        while !self.lost && !bytes.is_empty() {
            // Bulk steps: data whose framing is known.
            match self.at {
                At::Length(left) | At::Data(left) => {
                    let n = bytes.len().min(usize::try_from(left).unwrap_or(usize::MAX));
                    bytes = &bytes[n..];
                    let left = left - n as u64;
                    self.at = match (self.at, left) {
                        (At::Length(_), 0) => At::Start,
                        (At::Length(_), _) => At::Length(left),
                        (_, 0) => At::DataCr,
                        _ => At::Data(left),
                    };
                    continue;
                }
                _ => {}
            }
            let (&b, rest) = bytes.split_first().unwrap_or((&0, &[]));
            bytes = rest;
            self.step(b);
        }
    }

    fn step(&mut self, b: u8) {
        let hex = |b: u8| char::from(b).to_digit(16).map(u64::from);
        self.at = match (self.at, b) {
            (At::Start | At::Head, b'\n') => self.end_of_line(),
            (At::Start | At::Head, _) => {
                if self.line.len() < MAX_LINE {
                    self.line.push(b);
                } else {
                    self.long = true;
                }
                self.at
            }
            (At::SizeStart | At::Size, _) if hex(b).is_some() => {
                match self
                    .size
                    .checked_mul(16)
                    .and_then(|s| s.checked_add(hex(b).unwrap_or(0)))
                {
                    Some(size) => {
                        self.size = size;
                        At::Size
                    }
                    None => return self.lose(), // hyper refuses the overflow
                }
            }
            (At::Size | At::SizeLws, b'\t' | b' ') => At::SizeLws,
            (At::Size | At::SizeLws, b';') | (At::Extension, _) if b != b'\r' && b != b'\n' => {
                At::Extension
            }
            (At::Size | At::SizeLws | At::Extension, b'\r') => At::SizeLf,
            (At::SizeLf, b'\n') => {
                let size = std::mem::take(&mut self.size);
                if size == 0 {
                    At::EndCr
                } else {
                    self.declared = self.declared.saturating_add(size);
                    At::Data(size)
                }
            }
            (At::DataCr, b'\r') => At::DataLf,
            (At::DataLf, b'\n') => At::SizeStart,
            (At::EndCr, b'\r') => At::EndLf,
            (At::Trailer, b'\r') => At::TrailerLf,
            (At::EndCr | At::Trailer, _) => At::Trailer,
            (At::TrailerLf, b'\n') => At::EndCr,
            (At::EndLf, b'\n') => At::Start,
            _ => return self.lose(),
        };
    }

    /// A head line ended (its `\n` read).
    fn end_of_line(&mut self) -> At {
        let mut line = std::mem::take(&mut self.line);
        let long = std::mem::replace(&mut self.long, false);
        if line.last() == Some(&b'\r') {
            line.pop();
        }
        match self.at {
            At::Start if line.is_empty() && !long => At::Start,
            At::Start => {
                // The request line. A CONNECT's bytes after its head are
                // not HTTP: stop.
                if line.starts_with(b"CONNECT ") {
                    return self.lost();
                }
                self.chunked = None;
                self.length = None;
                At::Head
            }
            _ if line.is_empty() && !long => {
                // The head's end: a new request, and its body's framing.
                self.requests += 1;
                self.declared = 0;
                match (self.chunked, self.length) {
                    (Some(true), _) => {
                        self.size = 0;
                        At::SizeStart
                    }
                    (Some(false), _) => self.lost(), // hyper refuses it
                    (None, Some(n)) if n > 0 => At::Length(n),
                    (None, _) => At::Start,
                }
            }
            _ => {
                let Some(colon) = line.iter().position(|&c| c == b':') else {
                    return self.lost();
                };
                let (name, value) = (&line[..colon], line[colon + 1..].trim_ascii());
                let te = name.eq_ignore_ascii_case(b"transfer-encoding");
                let cl = name.eq_ignore_ascii_case(b"content-length");
                if (te || cl) && long {
                    return self.lost();
                }
                if te {
                    // hyper goes by the last field line's last coding.
                    let last = value.rsplit(|&c| c == b',').next().unwrap_or(b"");
                    self.chunked = Some(last.trim_ascii().eq_ignore_ascii_case(b"chunked"));
                } else if cl {
                    let mut values = value.split(|&c| c == b',').map(|v| {
                        std::str::from_utf8(v.trim_ascii())
                            .ok()
                            .and_then(|v| v.parse::<u64>().ok())
                    });
                    let first = values.next().flatten();
                    match first {
                        Some(n)
                            if values.all(|v| v == Some(n))
                                && self.length.is_none_or(|m| m == n) =>
                        {
                            self.length = Some(n);
                        }
                        _ => return self.lost(), // hyper refuses it
                    }
                }
                At::Head
            }
        }
    }

    fn lost(&mut self) -> At {
        self.lost = true;
        self.at
    }

    fn lose(&mut self) {
        self.lost = true;
    }
}

/// A socket whose reads are fed to a [`Watch`].
pub(crate) struct Sniff<T> {
    inner: T,
    watch: Arc<Watch>,
}

impl<T> Sniff<T> {
    pub(crate) fn new(inner: T, watch: Arc<Watch>) -> Self {
        Self { inner, watch }
    }
}

impl<T: AsyncRead + Unpin> AsyncRead for Sniff<T> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        let polled = Pin::new(&mut self.inner).poll_read(cx, buf);
        if let Poll::Ready(Ok(())) = polled
            && let Some(read) = buf.filled().get(before..)
            && !read.is_empty()
        {
            self.watch.feed(read);
        }
        polled
    }
}

impl<T: AsyncWrite + Unpin> AsyncWrite for Sniff<T> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write(cx, buf)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `wire` fed in pieces of `piece` bytes: (requests, declared, lost).
    fn framing(wire: &[u8], piece: usize) -> (u64, u64, bool) {
        let mut f = Framing::default();
        for part in wire.chunks(piece) {
            f.feed(part);
        }
        (f.requests, f.declared, f.lost)
    }

    fn both(wire: &[u8]) -> (u64, u64, bool) {
        let whole = framing(wire, wire.len().max(1));
        assert_eq!(whole, framing(wire, 1), "byte by byte");
        whole
    }

    #[test]
    fn chunk_sizes_are_added_up_per_request() {
        let head = b"POST /solve HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n";
        let mut wire = head.to_vec();
        wire.extend_from_slice(b"4;ext=1\r\nabcd\r\n10 \r\n0123456789abcdef\r\n");
        assert_eq!(both(&wire), (1, 20, false));
        // A huge declaration is counted before its data arrives.
        let mut huge = head.to_vec();
        huge.extend_from_slice(b"FFFFFF\r\n{}");
        assert_eq!(both(&huge), (1, 0xFF_FFFF, false));
        // The end, trailers and all; then a second request on the
        // connection starts its own count.
        wire.extend_from_slice(b"0\r\nX-T: 1\r\n\r\n");
        wire.extend_from_slice(b"\r\nGET /healthz HTTP/1.1\r\nHost: x\r\n\r\n");
        assert_eq!(both(&wire), (2, 0, false));
        wire.extend_from_slice(head);
        wire.extend_from_slice(b"2\r\n{}\r\n0\r\n\r\n");
        assert_eq!(both(&wire), (3, 2, false));
    }

    #[test]
    fn bodies_of_a_given_length_are_skipped() {
        let wire = b"POST /solve HTTP/1.1\nContent-Length: 10\n\n0\r\nffff\r\n\r\n\
                     POST /solve HTTP/1.1\r\ncontent-length: 2, 2\r\n\r\n{}";
        assert_eq!(both(wire), (2, 0, false));
    }

    #[test]
    fn what_hyper_refuses_or_cannot_be_followed_stops_it() {
        for wire in [
            &b"POST / HTTP/1.1\r\nTransfer-Encoding: gzip\r\n\r\n"[..],
            b"POST / HTTP/1.1\r\nContent-Length: 1, 2\r\n\r\n",
            b"POST / HTTP/1.1\r\nno colon here\r\n\r\n",
            b"POST / HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\nzz\r\n",
            b"POST / HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\n1ffffffffffffffff\r\n",
            b"POST / HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\n2\r\n{}X",
            b"CONNECT x:1 HTTP/1.1\r\n\r\n",
        ] {
            assert!(both(wire).2, "{}", String::from_utf8_lossy(wire));
        }
        let mut long = b"POST / HTTP/1.1\r\nTransfer-Encoding: ".to_vec();
        long.extend(std::iter::repeat_n(b' ', MAX_LINE));
        long.extend_from_slice(b"chunked\r\n\r\n");
        assert!(both(&long).2);
        // A long line that does not name the framing is skipped.
        let mut other = b"POST / HTTP/1.1\r\nX-Long: ".to_vec();
        other.extend(std::iter::repeat_n(b'a', 4 * MAX_LINE));
        other.extend_from_slice(b"\r\nTransfer-Encoding: chunked\r\n\r\n5\r\n");
        assert_eq!(both(&other), (1, 5, false));
    }
}
