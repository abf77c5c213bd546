//! The dashboard's connections, bounded before anyone has logged in: how many are open at once,
//! how many one peer address holds, how long a TLS handshake and a request's headers may take.
//! A client that opens connections and sends nothing costs the server a socket for
//! [`HEADER_DEADLINE`] at most, and one peer address cannot take every slot.
//!
//! Must not know the twin nor the routes: it serves whatever `Router` it is given, over TLS
//! (`[http] tls_certificate`, `tls_private_key`) or plain TCP.

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use rustls::ServerConfig;
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::net::TcpListener;
use tokio::sync::{Semaphore, watch};
use tokio_rustls::TlsAcceptor;
use tracing::debug;

/// Connections open at once (pages' streams included); more wait in the kernel's backlog.
pub(super) const MAX_CONNECTIONS: usize = 256;
/// Connections one peer address may hold at once; more from it are closed as they come.
pub(super) const MAX_CONNECTIONS_PER_PEER: usize = 32;
/// A TLS handshake that takes longer is dropped.
pub(super) const HANDSHAKE_DEADLINE: Duration = Duration::from_secs(10);
/// A request's headers must have arrived within this of the connection's being ready for them
/// (hyper's header-read timeout, which also closes a kept-alive connection left idle this long).
pub(super) const HEADER_DEADLINE: Duration = Duration::from_secs(10);

/// How many connections each peer address holds now; an entry lives only while its count is
/// above zero, so the table holds at most [`MAX_CONNECTIONS`] entries.
#[derive(Default)]
struct PeerCounts(Mutex<HashMap<IpAddr, usize>>);

/// One connection counted against its peer address until dropped.
struct PeerSlot {
    counts: Arc<PeerCounts>,
    peer: IpAddr,
}

impl PeerCounts {
    /// A slot for `peer`, or `None` when it already holds [`MAX_CONNECTIONS_PER_PEER`].
    fn take(self: &Arc<Self>, peer: IpAddr) -> Option<PeerSlot> {
        let mut counts = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        let count = counts.entry(peer).or_insert(0);
        if *count >= MAX_CONNECTIONS_PER_PEER {
            return None;
        }
        *count += 1;
        Some(PeerSlot {
            counts: Arc::clone(self),
            peer,
        })
    }
}

impl Drop for PeerSlot {
    fn drop(&mut self) {
        let mut counts = self.counts.0.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(count) = counts.get_mut(&self.peer) {
            *count -= 1;
            if *count == 0 {
                counts.remove(&self.peer);
            }
        }
    }
}

/// Serves `app` on `listener` (over TLS with `tls`) until `stop` turns true; then every open
/// connection is closed gracefully, and the task ends when they are (or when aborted).
pub(super) fn serve(
    listener: TcpListener,
    tls: Option<Arc<ServerConfig>>,
    app: Router,
    stop: watch::Receiver<bool>,
) -> tokio::task::JoinHandle<()> {
    let acceptor = tls.map(TlsAcceptor::from);
    tokio::spawn(async move {
        let permits = Arc::new(Semaphore::new(MAX_CONNECTIONS));
        let peers = Arc::new(PeerCounts::default());
        let mut stopping = stop.clone();
        loop {
            let accepted = tokio::select! {
                () = stopped(&mut stopping) => break,
                permit = Arc::clone(&permits).acquire_owned() => match permit {
                    Ok(permit) => tokio::select! {
                        () = stopped(&mut stopping) => break,
                        accepted = listener.accept() => accepted.map(|a| (a, permit)),
                    },
                    Err(_) => break,
                },
            };
            let ((stream, peer), permit) = match accepted {
                Ok(accepted) => accepted,
                Err(e) => {
                    // Out of file descriptors and the like: wait rather than spin.
                    debug!(error = %e, "dashboard accept failed");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            };
            let Some(slot) = peers.take(peer.ip()) else {
                debug!(%peer, "dashboard connection refused: its address holds too many");
                continue;
            };
            let acceptor = acceptor.clone();
            let app = app.clone();
            let stop = stop.clone();
            tokio::spawn(async move {
                let _held = (permit, slot);
                match acceptor {
                    None => serve_connection(stream, peer, app, stop).await,
                    Some(acceptor) => {
                        match tokio::time::timeout(HANDSHAKE_DEADLINE, acceptor.accept(stream))
                            .await
                        {
                            Ok(Ok(tls)) => serve_connection(tls, peer, app, stop).await,
                            // A port scan or a client that distrusts the certificate: not the
                            // service's problem, so not a warning.
                            Ok(Err(e)) => {
                                debug!(%peer, error = %e, "dashboard TLS handshake failed");
                            }
                            Err(_) => debug!(%peer, "dashboard TLS handshake timed out"),
                        }
                    }
                }
            });
        }
        drop(listener);
        // Every connection holds a permit: all of them back means every connection is closed.
        let _ = permits.acquire_many(MAX_CONNECTIONS as u32).await;
    })
}

/// Resolves once `stop` turns true (or its sender is gone).
async fn stopped(stop: &mut watch::Receiver<bool>) {
    let _ = stop.wait_for(|stopping| *stopping).await;
}

/// HTTP/1 on one connection, with the header deadline, closed gracefully when `stop` turns true.
async fn serve_connection<S>(
    stream: S,
    peer: SocketAddr,
    app: Router,
    mut stop: watch::Receiver<bool>,
) where
    S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
{
    let service = TowerToHyperService::new(app);
    let connection = hyper::server::conn::http1::Builder::new()
        .timer(TokioTimer::new())
        .header_read_timeout(HEADER_DEADLINE)
        .serve_connection(TokioIo::new(stream), service);
    let mut connection = std::pin::pin!(connection);
    let served = tokio::select! {
        served = connection.as_mut() => served,
        () = stopped(&mut stop) => {
            connection.as_mut().graceful_shutdown();
            connection.await
        }
    };
    if let Err(e) = served {
        debug!(%peer, error = %e, "dashboard connection ended");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_peer_holds_its_share_and_gets_it_back() {
        let counts = Arc::new(PeerCounts::default());
        let a: IpAddr = [10, 0, 0, 1].into();
        let b: IpAddr = [10, 0, 0, 2].into();
        let held: Vec<PeerSlot> = (0..MAX_CONNECTIONS_PER_PEER)
            .map(|_| counts.take(a).expect("within the share"))
            .collect();
        assert!(counts.take(a).is_none(), "over the share");
        let other = counts.take(b).expect("another address is not starved");
        drop(held);
        assert!(counts.take(a).is_some(), "the share comes back");
        drop(other);
        let table = counts.0.lock().unwrap_or_else(PoisonError::into_inner);
        assert!(
            table.is_empty(),
            "no entry outlives its connections: {table:?}"
        );
    }
}
