//! A client connection as hyper sees it, with hyper's own bare error answers replaced by the
//! service's problem+json (every error answer is problem+json).
//!
//! hyper answers some malformed HTTP/1 requests itself, before any request reaches the router, with
//! an empty body: 414 for a URI longer than 65534 bytes (`MAX_URI_LEN` in hyper's `proto/h1/role.rs`),
//! 431 for a request head larger than its read buffer (`max_buf_size`, ~400 KiB by default, so
//! also for a URI of a megabyte), 400 for an unparsable head. Those answers are written as the last
//! bytes of the connection, a status line and no header but `connection: close`,
//! `content-length: 0` and `date`, which no response of the router has (its errors always have a problem+json body). [`ClientConn`]
//! recognises such a head at the end of a write and writes the service's answer instead: a 414 that
//! states the service's query limit ([`MAX_QUERY_BYTES`]) when the head was too large because of its
//! request line (tracked on the read side), a 431 stating the head limit otherwise, a 400 naming
//! the malformed request. Then, instead of closing with unread request bytes (which makes the
//! kernel reset the connection and can destroy the answer before the client reads it), it reads
//! and discards what the client still sends, at most [`DRAIN_MAX_BYTES`] for at most
//! [`DRAIN_TIMEOUT`] (a "lingering close"), buffering nothing.

use super::extract::MAX_QUERY_BYTES;
use super::problem::problem_json;
use axum::http::StatusCode;
use std::io;
use std::pin::Pin;
use std::task::{ready, Context, Poll};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// Most bytes read and discarded after a replaced error answer.
pub const DRAIN_MAX_BYTES: usize = 16 << 20;
/// Longest wait for the client to stop sending after a replaced error answer.
pub const DRAIN_TIMEOUT: Duration = Duration::from_secs(2);
/// hyper's default HTTP/1 read buffer limit (`DEFAULT_MAX_BUFFER_SIZE`): the largest request head.
pub const MAX_HEAD_BYTES: usize = 8192 + 4096 * 100;

/// Bytes of a line kept to tell a request line (`METHOD SP target`) from a header line.
const PREFIX_BYTES: usize = 16;

/// A connection whose hyper error answers are replaced (see the module documentation).
pub struct ClientConn<IO> {
    inner: IO,
    /// Length of the line being received (bytes since the last `\n`).
    line_len: usize,
    /// Its first bytes.
    line_prefix: Vec<u8>,
    /// The replacement answer and how much of it is written.
    answer: Vec<u8>,
    written: usize,
    /// After a replaced answer: discarding the client's remaining bytes.
    drain: Option<Drain>,
}

struct Drain {
    read: usize,
    deadline: Pin<Box<tokio::time::Sleep>>,
}

impl<IO> ClientConn<IO> {
    pub fn new(inner: IO) -> Self {
        ClientConn {
            inner,
            line_len: 0,
            line_prefix: Vec::with_capacity(PREFIX_BYTES),
            answer: Vec::new(),
            written: 0,
            drain: None,
        }
    }

    /// Follows the lines of what the client sent.
    fn saw(&mut self, bytes: &[u8]) {
        let tail = match bytes.iter().rposition(|&b| b == b'\n') {
            Some(i) => {
                self.line_len = 0;
                self.line_prefix.clear();
                &bytes[i + 1..]
            }
            None => bytes,
        };
        self.line_len += tail.len();
        let room = PREFIX_BYTES - self.line_prefix.len();
        self.line_prefix
            .extend_from_slice(&tail[..tail.len().min(room)]);
    }

    /// Whether the line being received is a request line longer than the service's query limit.
    fn long_request_line(&self) -> bool {
        let method_len = self
            .line_prefix
            .iter()
            .position(|&b| b == b' ')
            .unwrap_or(0);
        self.line_len > MAX_QUERY_BYTES
            && method_len > 0
            && self.line_prefix[..method_len]
                .iter()
                .all(|b| b.is_ascii_uppercase())
    }

    /// The service's answer for hyper's bare `status`.
    fn answer_for(&self, status: u16) -> Vec<u8> {
        let (status, kind, title, detail, parameter) = match status {
            414 => uri_too_long(),
            431 if self.long_request_line() => uri_too_long(),
            431 => (
                StatusCode::REQUEST_HEADER_FIELDS_TOO_LARGE,
                "urn:skybake:problem:too-large",
                "Request exceeds a limit",
                format!("headers: the request head is larger than the service reads (limit {MAX_HEAD_BYTES} bytes)"),
                "headers",
            ),
            _ => (
                StatusCode::BAD_REQUEST,
                "urn:skybake:problem:bad-request",
                "Malformed HTTP request",
                "the request line or a header is not valid HTTP/1.1".to_string(),
                "request",
            ),
        };
        let body = problem_json(status, kind, title, detail, Some(parameter.to_string()));
        let mut out = format!(
            "HTTP/1.1 {} {}\r\ncontent-type: application/problem+json\r\ncontent-length: {}\r\nconnection: close\r\n\r\n",
            status.as_u16(),
            status.canonical_reason().unwrap_or(""),
            body.len()
        )
        .into_bytes();
        out.extend_from_slice(&body);
        out
    }
}

fn uri_too_long() -> (StatusCode, &'static str, &'static str, String, &'static str) {
    (
        StatusCode::URI_TOO_LONG,
        "urn:skybake:problem:too-large",
        "Request exceeds a limit",
        format!("query: the request URI is longer than the service reads (limit {MAX_QUERY_BYTES} bytes of query)"),
        "query",
    )
}

/// Where hyper's bare error head starts in `buf`, and its status, when `buf` ends with one:
/// `HTTP/1.1 400|414|431 <reason>\r\n`, then only `content-length: 0`, `connection` and `date`
/// headers (either case), then the empty line, and nothing after it.
fn hyper_error_head(buf: &[u8]) -> Option<(usize, u16)> {
    const START: &[u8] = b"HTTP/1.1 ";
    if !buf.ends_with(b"\r\n\r\n") {
        return None;
    }
    let at = buf.windows(START.len()).rposition(|w| w == START)?;
    let head = std::str::from_utf8(&buf[at..]).ok()?;
    let mut lines = head.strip_suffix("\r\n\r\n")?.split("\r\n");
    let status: u16 = lines
        .next()?
        .get(START.len()..START.len() + 3)?
        .parse()
        .ok()?;
    if ![400, 414, 431].contains(&status) {
        return None;
    }
    let mut length_zero = false;
    for line in lines {
        let (name, value) = line.split_once(':')?;
        match name.to_ascii_lowercase().as_str() {
            "content-length" if value.trim() == "0" => length_zero = true,
            "date" | "connection" => {}
            _ => return None,
        }
    }
    length_zero.then_some((at, status))
}

impl<IO: AsyncRead + Unpin> AsyncRead for ClientConn<IO> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let before = buf.filled().len();
        ready!(Pin::new(&mut self.inner).poll_read(cx, buf))?;
        let this = &mut *self;
        this.saw(&buf.filled()[before..]);
        Poll::Ready(Ok(()))
    }
}

impl<IO: AsyncRead + AsyncWrite + Unpin> ClientConn<IO> {
    /// Writes the rest of the replacement answer.
    fn poll_answer(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        while self.written < self.answer.len() {
            let n = ready!(Pin::new(&mut self.inner).poll_write(cx, &self.answer[self.written..]))?;
            if n == 0 {
                return Poll::Ready(Err(io::ErrorKind::WriteZero.into()));
            }
            self.written += n;
        }
        Poll::Ready(Ok(()))
    }

    /// Reads and discards the client's remaining bytes, within the drain limits.
    fn poll_drain(&mut self, cx: &mut Context<'_>) -> Poll<()> {
        let Some(drain) = &mut self.drain else {
            return Poll::Ready(());
        };
        let mut scratch = [0u8; 8192];
        while drain.read < DRAIN_MAX_BYTES {
            if drain.deadline.as_mut().poll(cx).is_ready() {
                break;
            }
            let mut buf = ReadBuf::new(&mut scratch);
            match Pin::new(&mut self.inner).poll_read(cx, &mut buf) {
                Poll::Ready(Ok(())) if !buf.filled().is_empty() => drain.read += buf.filled().len(),
                Poll::Ready(_) => break,
                Poll::Pending => return Poll::Pending,
            }
        }
        self.drain = None;
        Poll::Ready(())
    }
}

use std::future::Future;

impl<IO: AsyncRead + AsyncWrite + Unpin> AsyncWrite for ClientConn<IO> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = &mut *self;
        if !this.answer.is_empty() {
            // The connection ends with the replacement answer: nothing more is written.
            ready!(this.poll_answer(cx))?;
            return Poll::Ready(Ok(buf.len()));
        }
        match hyper_error_head(buf) {
            // Write what precedes hyper's error head first (an earlier response's last bytes).
            Some((at, _)) if at > 0 => Pin::new(&mut this.inner).poll_write(cx, &buf[..at]),
            Some((_, status)) => {
                this.answer = this.answer_for(status);
                this.drain = Some(Drain {
                    read: 0,
                    deadline: Box::pin(tokio::time::sleep(DRAIN_TIMEOUT)),
                });
                // Taken whole; the answer is written here or on the next write/flush/shutdown.
                let _ = this.poll_answer(cx)?;
                Poll::Ready(Ok(buf.len()))
            }
            None => Pin::new(&mut this.inner).poll_write(cx, buf),
        }
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let this = &mut *self;
        ready!(this.poll_answer(cx))?;
        Pin::new(&mut this.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let this = &mut *self;
        ready!(this.poll_answer(cx))?;
        if this.drain.is_some() {
            ready!(Pin::new(&mut this.inner).poll_flush(cx))?;
            ready!(this.poll_drain(cx));
        }
        Pin::new(&mut this.inner).poll_shutdown(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recognises_only_hyper_s_bare_error_heads() {
        let date = "date: Wed, 02 Dec 2026 08:00:00 GMT\r\n";
        // As hyper 1.x writes it.
        let bare = format!(
            "HTTP/1.1 414 URI Too Long\r\nconnection: close\r\ncontent-length: 0\r\n{date}\r\n"
        );
        assert_eq!(hyper_error_head(bare.as_bytes()), Some((0, 414)));
        let after = format!("HTTP/1.1 200 OK\r\ncontent-length: 2\r\n\r\nok{bare}");
        assert_eq!(hyper_error_head(after.as_bytes()), Some((40, 414)));
        let ours = "HTTP/1.1 414 URI Too Long\r\ncontent-type: application/problem+json\r\ncontent-length: 0\r\n\r\n";
        assert_eq!(hyper_error_head(ours.as_bytes()), None);
        let ok = format!("HTTP/1.1 200 OK\r\ncontent-length: 0\r\n{date}\r\n");
        assert_eq!(hyper_error_head(ok.as_bytes()), None);
        let with_body = format!("{bare}x");
        assert_eq!(hyper_error_head(with_body.as_bytes()), None);
    }

    #[test]
    fn a_long_request_line_is_told_from_a_long_header() {
        let mut c = ClientConn::new(());
        c.saw(b"GET /v1/sky?a=");
        c.saw(&vec![b'x'; MAX_QUERY_BYTES]);
        assert!(c.long_request_line());
        let mut h = ClientConn::new(());
        h.saw(b"GET / HTTP/1.1\r\nCookie: ");
        h.saw(&vec![b'x'; MAX_QUERY_BYTES + 1]);
        assert!(!h.long_request_line());
        let mut short = ClientConn::new(());
        short.saw(b"GET /v1/sky?a=b HTTP/1.1\r\n");
        assert!(!short.long_request_line());
    }
}
