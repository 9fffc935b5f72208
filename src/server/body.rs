//! Reading request bodies: each within `--max-body-bytes` and the read
//! timeout, and all of them together within `--max-inflight-body-bytes`.
//!
//! A body is held whole until it is parsed (the parser needs all of it to
//! point at every bad value), and the number of connections is not limited.
//! Without a shared cap, memory grows with the number of clients uploading
//! at once (a hundred 4 MB bodies are 400 MB), so a few hundred would
//! exhaust a container. [`BodyBudget`] counts the bytes of
//! every body being read or parsed, and a body that would take the total
//! past the cap is answered 503 `overloaded` with `Retry-After`, as a full
//! solver queue is: the same back-pressure, for the same kind of client.
//!
//! A body over `--max-body-bytes` is refused 413 before it is read when it
//! says so: by its `Content-Length`, or, chunked, by its chunk-size lines,
//! which `chunks` reads off the wire as they arrive, so a client that
//! declares a huge chunk and sends nothing more is not held until the read
//! timeout.
//!
//! Bytes are counted as they arrive: a body holds the buffer it has grown
//! into (doubling, up to its declared length), never more than twice what
//! its client has sent. (Reserving a declared length up front let 16
//! clients that sent only headers, 100 bytes each, hold the whole default
//! budget for the read timeout.) A body whose declared length does not fit
//! in what is free is still refused before a byte is read (and before
//! `Expect: 100-continue` is answered), so a refused client has not sent it.
//! What a body holds is returned when it is dropped, after parsing.
//!
//! Not counted: the parse itself. [`crate::problem::parse`] builds a
//! `serde_json::Value` of the document first, up to ~25 times the text for
//! a body that is one long array of short numbers (a 4 MB body: 112 MB at
//! its peak), and takes about 0.1 s for 4 MB. (Objects cost more, ~650
//! bytes each however small, which is why a document may hold at most
//! [`crate::problem::MAX_OBJECTS`] of them.) A body over
//! [`INLINE_PARSE_BYTES`] is therefore parsed off the runtime's thread
//! (`block_in_place`: the runtime moves its other tasks to another thread
//! meanwhile), so a client sending megabytes does not stall every other
//! connection, and one at a time ([`BodyBudget`]'s parse lane), so that
//! peak is one parse's whatever the number of clients. Smaller bodies, a
//! problem without `initial_controls` among them, parse in place.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use tokio::runtime::{Handle, RuntimeFlavor};
use tokio::sync::Semaphore;

use axum::extract::Request;
use axum::http::header;
use http_body_util::BodyExt;

use super::chunks::Declared;
use super::error::{ApiError, Overload};

/// A count of bytes held against a limit, shared by threads: the bodies
/// being read ([`BodyBudget`]) and the answers being sent
/// ([`super::stall::AnswerBudget`]) each have one.
#[derive(Debug)]
pub(crate) struct ByteBudget {
    limit: usize,
    used: AtomicUsize,
}

impl ByteBudget {
    pub(crate) fn new(limit: usize) -> Self {
        Self {
            limit,
            used: AtomicUsize::new(0),
        }
    }

    /// Bytes held now.
    pub(crate) fn used(&self) -> usize {
        self.used.load(Ordering::Relaxed)
    }

    /// Bytes not held.
    pub(crate) fn free(&self) -> usize {
        self.limit.saturating_sub(self.used.load(Ordering::Acquire))
    }

    /// Take `bytes` more, or nothing if they do not fit. With
    /// `past_limit_when_empty`, an empty budget takes any amount (one
    /// holder larger than the limit may go ahead alone).
    pub(crate) fn take(&self, bytes: usize, past_limit_when_empty: bool) -> bool {
        self.used
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |used| {
                used.checked_add(bytes)
                    .filter(|&total| total <= self.limit || (past_limit_when_empty && used == 0))
            })
            .is_ok()
    }

    /// Return `bytes` taken before.
    pub(crate) fn give_back(&self, bytes: usize) {
        self.used.fetch_sub(bytes, Ordering::AcqRel);
    }
}

/// Bytes that all bodies being read may hold together.
#[derive(Debug)]
pub(crate) struct BodyBudget {
    bytes: ByteBudget,
    /// One permit: the parse of a body over [`INLINE_PARSE_BYTES`].
    parse_lane: Semaphore,
}

/// Bodies up to this size are parsed on the runtime's thread, in well under
/// a millisecond; larger ones in the parse lane (see the module's doc).
/// The largest valid problem, 10000 steps of `initial_controls`, is about
/// 0.4 MB.
pub(crate) const INLINE_PARSE_BYTES: usize = 64 * 1024;

impl BodyBudget {
    pub(crate) fn new(limit: usize) -> Self {
        Self {
            bytes: ByteBudget::new(limit),
            parse_lane: Semaphore::new(1),
        }
    }

    /// Bytes held now, over all bodies.
    pub(crate) fn used(&self) -> usize {
        self.bytes.used()
    }

    /// Bytes not held by any body.
    fn free(&self) -> usize {
        self.bytes.free()
    }

    /// Take `bytes` more from the budget, or nothing if they do not fit.
    fn take(&self, bytes: usize) -> bool {
        self.bytes.take(bytes, false)
    }
}

/// Bytes one body holds in a [`BodyBudget`], returned when it is dropped.
struct Held<'a> {
    budget: &'a BodyBudget,
    bytes: usize,
}

impl Held<'_> {
    /// Hold `bytes` in all, taking the difference from the budget.
    fn grow_to(&mut self, bytes: usize) -> bool {
        if bytes <= self.bytes {
            return true;
        }
        let ok = self.budget.take(bytes - self.bytes);
        if ok {
            self.bytes = bytes;
        }
        ok
    }
}

impl Drop for Held<'_> {
    fn drop(&mut self) {
        self.budget.bytes.give_back(self.bytes);
    }
}

/// How a body is read: its size limit, read timeout and shared budget.
pub(crate) struct BodyRules<'a> {
    pub limit: usize,
    pub timeout: Duration,
    pub budget: &'a BodyBudget,
    /// `Retry-After` of a refusal for lack of budget, in s.
    pub retry_after: u64,
}

/// Read `req`'s body whole and hand it to `parse` while it is still
/// counted in the budget.
pub(crate) async fn read_with<T>(
    req: Request,
    rules: &BodyRules<'_>,
    parse: impl FnOnce(&[u8]) -> Result<T, ApiError>,
) -> Result<T, ApiError> {
    let full = || ApiError::Overloaded {
        retry_after: rules.retry_after,
        cause: Overload::Bodies,
    };
    // A declared length over the limit is refused before reading a byte
    // (and before hyper answers `Expect: 100-continue`).
    let declared = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    if declared.is_some_and(|n| n > rules.limit as u64) {
        return Err(ApiError::PayloadTooLarge(rules.limit));
    }
    // At most `limit`, checked above.
    let declared = declared.map(|n| n as usize);
    // Refused before the client sends it if it cannot fit now; nothing is
    // reserved until bytes arrive.
    if declared.is_some_and(|n| n > rules.budget.free()) {
        return Err(full());
    }
    // hyper ends a body at its declared length.
    let ceiling = declared.unwrap_or(rules.limit);
    // A chunked body is refused as soon as its chunks declare more than
    // the limit, without waiting for the bytes (see `chunks`).
    let chunks = req.extensions().get::<Declared>().cloned();
    let declared_over = async {
        match &chunks {
            Some(chunks) => chunks.over(rules.limit).await,
            None => std::future::pending().await,
        }
    };
    let mut declared_over = std::pin::pin!(declared_over);
    let mut held = Held {
        budget: rules.budget,
        bytes: 0,
    };
    let mut buf: Vec<u8> = Vec::new();
    let mut body = req.into_body();
    // Bounded in time as well as size: a client that stalls mid-body would
    // otherwise hold its connection, its share of the budget and a
    // shutdown indefinitely.
    let read = async {
        loop {
            let frame = tokio::select! {
                biased;
                () = &mut declared_over => return Err(ApiError::PayloadTooLarge(rules.limit)),
                frame = body.frame() => frame,
            };
            let Some(frame) = frame else { break };
            let frame = frame.map_err(|e| {
                if ended_by_client(&e) {
                    ApiError::ClientLeft
                } else {
                    ApiError::UnreadableBody(chain(&e))
                }
            })?;
            let Ok(data) = frame.into_data() else {
                continue; // trailers
            };
            let need = buf.len() + data.len();
            if need > rules.limit {
                return Err(ApiError::PayloadTooLarge(rules.limit));
            }
            if need > buf.capacity() {
                // Grow as Vec would (doubling), but take it from the budget
                // first, so the budget counts the allocation rather than the
                // length; if the doubling does not fit, what the bytes need
                // may.
                let doubled = need.max(buf.capacity() * 2).min(ceiling.max(need));
                let cap = if held.grow_to(doubled) {
                    doubled
                } else if held.grow_to(need) {
                    need
                } else {
                    return Err(full());
                };
                buf.try_reserve_exact(cap - buf.len()).map_err(|_| full())?;
            }
            buf.extend_from_slice(&data);
        }
        Ok(())
    };
    let secs = rules.timeout.as_secs();
    tokio::time::timeout(rules.timeout, read)
        .await
        .map_err(|_| ApiError::RequestTimeout(secs))??;
    let multi_thread =
        Handle::try_current().is_ok_and(|h| h.runtime_flavor() == RuntimeFlavor::MultiThread);
    if buf.len() <= INLINE_PARSE_BYTES || !multi_thread {
        // (A current-thread runtime, as in unit tests, cannot hand its
        // tasks over: it parses in place.)
        return parse(&buf);
    }
    // The lane is never closed, so this waits for its turn; its permit is
    // returned when `_turn` drops, after the parse.
    let _turn = rules.budget.parse_lane.acquire().await;
    tokio::task::block_in_place(|| parse(&buf))
}

/// Whether a body's read error is the client closing its connection
/// before the body's end (an end of file inside the body, a reset), rather
/// than a body that cannot be read (broken chunked framing).
fn ended_by_client(e: &(dyn std::error::Error + 'static)) -> bool {
    use std::io::ErrorKind;
    let mut next = Some(e);
    while let Some(err) = next {
        if err
            .downcast_ref::<hyper::Error>()
            .is_some_and(hyper::Error::is_incomplete_message)
        {
            return true;
        }
        if let Some(io) = err.downcast_ref::<std::io::Error>()
            && matches!(
                io.kind(),
                ErrorKind::UnexpectedEof
                    | ErrorKind::ConnectionReset
                    | ErrorKind::ConnectionAborted
                    | ErrorKind::BrokenPipe
            )
        {
            return true;
        }
        next = err.source();
    }
    false
}

/// `e` with its causes, as "outer: inner: …": hyper's outermost error says
/// only "error reading a body from connection".
fn chain(e: &dyn std::error::Error) -> String {
    let mut out = e.to_string();
    let mut next = e.source();
    while let Some(cause) = next {
        let text = cause.to_string();
        if !out.ends_with(&text) {
            out.push_str(": ");
            out.push_str(&text);
        }
        next = cause.source();
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::body::Body;

    fn request(body: &'static [u8], length: Option<usize>) -> Request {
        let mut req = Request::new(Body::from(body));
        if let Some(n) = length {
            req.headers_mut()
                .insert(header::CONTENT_LENGTH, header::HeaderValue::from(n));
        }
        req
    }

    fn rules(budget: &BodyBudget) -> BodyRules<'_> {
        BodyRules {
            limit: 8,
            timeout: Duration::from_secs(5),
            budget,
            retry_after: 3,
        }
    }

    /// Bodies over INLINE_PARSE_BYTES are parsed one at a time, off the
    /// runtime's thread; smaller ones in place, side by side.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn large_bodies_are_parsed_one_at_a_time() {
        use std::sync::Arc;
        let budget = Arc::new(BodyBudget::new(16 * INLINE_PARSE_BYTES));
        let (now, most) = (Arc::new(AtomicUsize::new(0)), Arc::new(AtomicUsize::new(0)));
        let parses = |size: usize| {
            (0..3)
                .map(|_| {
                    let (budget, now, most) = (budget.clone(), now.clone(), most.clone());
                    tokio::spawn(async move {
                        let rules = BodyRules {
                            limit: 4 * INLINE_PARSE_BYTES,
                            ..rules(&budget)
                        };
                        let req = Request::new(Body::from(vec![b' '; size]));
                        read_with(req, &rules, |b| {
                            let inside = now.fetch_add(1, Ordering::SeqCst) + 1;
                            most.fetch_max(inside, Ordering::SeqCst);
                            std::thread::sleep(Duration::from_millis(100));
                            now.fetch_sub(1, Ordering::SeqCst);
                            Ok(b.len())
                        })
                        .await
                    })
                })
                .collect::<Vec<_>>()
        };
        for task in parses(INLINE_PARSE_BYTES + 1) {
            assert_eq!(task.await.unwrap(), Ok(INLINE_PARSE_BYTES + 1));
        }
        assert_eq!(most.load(Ordering::SeqCst), 1, "one large parse at a time");
        for task in parses(INLINE_PARSE_BYTES) {
            assert_eq!(task.await.unwrap(), Ok(INLINE_PARSE_BYTES));
        }
        // Two runtime threads: small parses overlap, in place.
        assert_eq!(most.load(Ordering::SeqCst), 2);
    }

    /// What a body holds is returned however its read ends, and a body
    /// that does not fit beside the others is refused as overload.
    #[tokio::test]
    async fn the_budget_is_shared_and_returned() {
        let budget = BodyBudget::new(10);
        let rules = rules(&budget);

        // The parser runs while the body is still counted.
        let seen = read_with(request(b"12345678", Some(8)), &rules, |b| {
            Ok((b.to_vec(), budget.used()))
        })
        .await;
        assert_eq!(seen, Ok((b"12345678".to_vec(), 8)));
        assert_eq!(budget.used(), 0);

        // Another body holds 6 of the 10 bytes: a declared 8 does not fit
        // and is refused before it is read; a declared 4 does.
        assert!(budget.take(6));
        let refused = read_with(request(b"12345678", Some(8)), &rules, |_| Ok(())).await;
        assert_eq!(
            refused,
            Err(ApiError::Overloaded {
                retry_after: 3,
                cause: Overload::Bodies
            })
        );
        let fits = read_with(request(b"1234", Some(4)), &rules, |b| Ok(b.len())).await;
        assert_eq!(fits, Ok(4));
        // Without a length, the buffer it grows into is what counts.
        let fits = read_with(request(b"1234", None), &rules, |b| Ok(b.len())).await;
        assert_eq!(fits, Ok(4));
        let refused = read_with(request(b"12345", None), &rules, |b| Ok(b.len())).await;
        assert!(
            matches!(refused, Err(ApiError::Overloaded { .. })),
            "{refused:?}"
        );
        assert_eq!(budget.used(), 6, "only the other body's bytes are held");

        // Errors return what the body held too.
        let too_large = read_with(request(b"123456789", None), &rules, |_| Ok(())).await;
        assert_eq!(too_large, Err(ApiError::PayloadTooLarge(8)));
        let invalid = read_with(request(b"1234", Some(4)), &rules, |_| {
            Err::<(), _>(ApiError::MalformedJson("x".into()))
        })
        .await;
        assert!(invalid.is_err());
        assert_eq!(budget.used(), 6);
    }

    /// A body in frames, as a chunked upload arrives.
    struct Frames(std::collections::VecDeque<&'static [u8]>);

    impl hyper::body::Body for Frames {
        type Data = axum::body::Bytes;
        type Error = std::convert::Infallible;

        fn poll_frame(
            mut self: std::pin::Pin<&mut Self>,
            _: &mut std::task::Context<'_>,
        ) -> std::task::Poll<Option<Result<hyper::body::Frame<Self::Data>, Self::Error>>> {
            let next = self.0.pop_front();
            std::task::Poll::Ready(
                next.map(|b| Ok(hyper::body::Frame::data(axum::body::Bytes::from_static(b)))),
            )
        }
    }

    /// Where doubling the buffer does not fit but the bytes do, the bytes
    /// are taken: a body is refused only when what it has sent cannot fit.
    #[tokio::test]
    async fn a_chunked_body_is_counted_by_what_it_needs() {
        let budget = BodyBudget::new(10);
        assert!(budget.take(3));
        let frames = Frames([&b"1234"[..], &b"56"[..]].into());
        let req = Request::new(Body::new(frames));
        let read = read_with(req, &rules(&budget), |b| Ok((b.len(), budget.used()))).await;
        // 4 bytes, then 6: doubling to 8 would need 4 more than the 3 free.
        assert_eq!(read, Ok((6, 9)));
        assert_eq!(budget.used(), 3);
    }

    /// A body whose connection ends early.
    struct Cut(std::io::ErrorKind);

    impl hyper::body::Body for Cut {
        type Data = axum::body::Bytes;
        type Error = std::io::Error;

        fn poll_frame(
            self: std::pin::Pin<&mut Self>,
            _: &mut std::task::Context<'_>,
        ) -> std::task::Poll<Option<Result<hyper::body::Frame<Self::Data>, Self::Error>>> {
            std::task::Poll::Ready(Some(Err(self.0.into())))
        }
    }

    /// A client that leaves mid-body is told apart from a body that cannot
    /// be read, so that it is counted as 499, not as a 400 nobody received.
    #[tokio::test]
    async fn a_cut_connection_is_a_client_that_left() {
        use std::io::ErrorKind;
        let budget = BodyBudget::new(10);
        for (kind, left) in [
            (ErrorKind::UnexpectedEof, true),
            (ErrorKind::ConnectionReset, true),
            (ErrorKind::InvalidData, false),
        ] {
            let req = Request::new(Body::new(Cut(kind)));
            let read = read_with(req, &rules(&budget), |_| Ok(())).await;
            match read {
                Err(ApiError::ClientLeft) => assert!(left, "{kind:?}"),
                Err(ApiError::UnreadableBody(_)) => assert!(!left, "{kind:?}"),
                other => panic!("{kind:?}: {other:?}"),
            }
        }
    }

    #[test]
    fn the_budget_never_overflows() {
        let budget = BodyBudget::new(usize::MAX);
        assert!(budget.take(usize::MAX));
        assert!(!budget.take(1));
        assert_eq!(budget.used(), usize::MAX);
    }
}
