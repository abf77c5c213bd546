//! A blocking HTTP/1.1 GET on loopback, one connection per request: enough for the service's
//! `/metrics` and dashboard API and for Prometheus' query API, without an HTTP crate.
//!
//! Owns the request and the response's framing (a length or chunks); knows nothing of what the
//! bodies mean.

use std::io::{Read as _, Write as _};
use std::net::{SocketAddr, TcpStream};
use std::time::Duration;

use thiserror::Error;

/// Why a GET failed.
#[derive(Debug, Error)]
pub enum HttpError {
    /// Connecting, writing or reading failed.
    #[error("GET {path}: {source}")]
    Io {
        /// The path asked for.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The answer was not an HTTP response.
    #[error("GET {path}: malformed response")]
    Malformed {
        /// The path asked for.
        path: String,
    },
}

/// A response: its status and body.
#[derive(Debug, Clone)]
pub struct Response {
    /// 200, 404, …
    pub status: u16,
    /// The body, chunks joined.
    pub body: Vec<u8>,
}

/// `GET path` from `address`, each step bounded by `timeout`.
pub fn get(address: SocketAddr, path: &str, timeout: Duration) -> Result<Response, HttpError> {
    let io = |source| HttpError::Io {
        path: path.to_owned(),
        source,
    };
    let mut stream = TcpStream::connect_timeout(&address, timeout).map_err(io)?;
    stream.set_read_timeout(Some(timeout)).map_err(io)?;
    stream.set_write_timeout(Some(timeout)).map_err(io)?;
    write!(
        stream,
        "GET {path} HTTP/1.1\r\nHost: {address}\r\nConnection: close\r\n\r\n"
    )
    .map_err(io)?;
    let mut raw = Vec::new();
    stream.read_to_end(&mut raw).map_err(io)?;
    parse(&raw).ok_or_else(|| HttpError::Malformed {
        path: path.to_owned(),
    })
}

fn parse(raw: &[u8]) -> Option<Response> {
    let split = raw.windows(4).position(|w| w == b"\r\n\r\n")?;
    let head = std::str::from_utf8(&raw[..split]).ok()?;
    let body = &raw[split + 4..];
    let mut lines = head.split("\r\n");
    let status = lines.next()?.split_whitespace().nth(1)?.parse().ok()?;
    let chunked = lines.any(|line| {
        line.split_once(':').is_some_and(|(name, value)| {
            name.eq_ignore_ascii_case("transfer-encoding") && value.trim() == "chunked"
        })
    });
    let body = if chunked {
        dechunk(body)?
    } else {
        body.to_vec()
    };
    Some(Response { status, body })
}

/// The body of a `Transfer-Encoding: chunked` response.
fn dechunk(mut rest: &[u8]) -> Option<Vec<u8>> {
    let mut body = Vec::new();
    loop {
        let line_end = rest.windows(2).position(|w| w == b"\r\n")?;
        let size_text = std::str::from_utf8(&rest[..line_end]).ok()?;
        let size_hex = size_text.split(';').next()?.trim();
        let size = usize::from_str_radix(size_hex, 16).ok()?;
        rest = &rest[line_end + 2..];
        if size == 0 {
            return Some(body);
        }
        body.extend_from_slice(rest.get(..size)?);
        rest = rest.get(size + 2..)?;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_a_sized_and_a_chunked_body() {
        let sized = parse(b"HTTP/1.1 200 OK\r\ncontent-length: 5\r\n\r\nhello").expect("sized");
        assert_eq!((sized.status, sized.body.as_slice()), (200, &b"hello"[..]));
        let chunked = parse(
            b"HTTP/1.1 404 Not Found\r\nTransfer-Encoding: chunked\r\n\r\n3\r\nhel\r\n2;x=y\r\nlo\r\n0\r\n\r\n",
        )
        .expect("chunked");
        assert_eq!(
            (chunked.status, chunked.body.as_slice()),
            (404, &b"hello"[..])
        );
        assert!(parse(b"garbage").is_none());
    }
}
