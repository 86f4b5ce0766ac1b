//! The daemon's accept loop: HTTP/1.1 connections (with WebSocket upgrades) served by a router,
//! each held to a header read timeout, and a graceful shutdown on SIGINT or SIGTERM (README.md
//! "The capture daemon": every WebSocket client gets its close frame and requests in hand finish,
//! for at most [`SHUTDOWN_GRACE`]).
//!
//! It is hyper's own loop rather than `axum::serve`, which sets no timer and so no
//! [`HEADER_READ_TIMEOUT`], without which connections that trickle in a header, or open and say
//! nothing, pile up.
//!
//! At most `--max-connections` connections are open at once: the loop takes a slot before each
//! accept and, when none is free, stops accepting, so further connections wait in the kernel's
//! listen backlog (and beyond it, are refused by the kernel) rather than costing descriptors.
//! The slot travels with the socket ([`Counted`]), so an upgraded WebSocket connection, which
//! hyper no longer tracks, holds it until the client's loop drops the socket.

use crate::daemon::Hub;
use crate::metrics::Metrics;
use std::io;
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::Ordering::Relaxed;
use std::task::{Context, Poll};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::TcpStream;
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio_util::task::TaskTracker;

/// How long open requests and WebSocket clients get to finish once shutdown has begun.
pub const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);

/// A connection must send a request's whole header within this time (and an idle kept-alive
/// connection is closed after it), so that connections that trickle in headers or say nothing
/// cannot pile up ([`AppState::header_read_timeout`](super::AppState::header_read_timeout)).
pub const HEADER_READ_TIMEOUT: Duration = Duration::from_secs(10);

/// Serves `router` on `listener` over HTTP/1.1 (with WebSocket upgrades) until `shutdown`
/// resolves, each connection held to `header_read_timeout` and holding one of `slots` for as long
/// as its socket is open (no slot free: no accept); then shuts `hub` down (streams get a close
/// frame, the pipeline stops) and returns once open requests have finished and every WebSocket
/// client in `ws_clients` has gone, or after [`SHUTDOWN_GRACE`].
///
/// Every connection gets TCP_NODELAY: a LightSet is written as a few
/// small frames, and Nagle's algorithm would hold them back for the peer's delayed ACK
/// (measured: p99 delivery 9 ms on loopback without it).
pub async fn serve(
    listener: tokio::net::TcpListener,
    router: axum::Router,
    hub: Arc<Hub>,
    ws_clients: TaskTracker,
    slots: Arc<Semaphore>,
    header_read_timeout: Duration,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    use hyper_util::rt::{TokioIo, TokioTimer};
    let service = hyper_util::service::TowerToHyperService::new(router);
    let stop = hub.shutdown_token();
    let metrics = hub.metrics.clone();
    let mut connections = tokio::task::JoinSet::new();
    tokio::pin!(shutdown);
    let mut paused = false;
    loop {
        // A slot first: while none is free, nothing is accepted.
        let slot = match slots.clone().try_acquire_owned() {
            Ok(slot) => slot,
            Err(_) => {
                if !paused {
                    paused = true;
                    Metrics::inc(&metrics.accept_paused);
                    tracing::debug!("connection cap reached: accepting paused until one closes");
                }
                tokio::select! {
                    slot = slots.clone().acquire_owned() => match slot {
                        Ok(slot) => slot,
                        Err(_) => break, // never closed; ends the loop rather than spin
                    },
                    Some(_) = connections.join_next(), if !connections.is_empty() => continue,
                    () = &mut shutdown => break,
                }
            }
        };
        paused = false;
        let (tcp, _) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok(a) => a,
                Err(e) => {
                    // Out of file descriptors, say: let open connections finish some.
                    tracing::warn!("cannot accept a connection: {e}");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            },
            Some(_) = connections.join_next(), if !connections.is_empty() => continue,
            () = &mut shutdown => break,
        };
        if let Err(e) = tcp.set_nodelay(true) {
            tracing::debug!("cannot set TCP_NODELAY: {e}");
        }
        let service = service.clone();
        let stop = stop.clone();
        let tcp = Counted::new(tcp, slot, metrics.clone());
        connections.spawn(async move {
            let conn = hyper::server::conn::http1::Builder::new()
                .timer(TokioTimer::new())
                .header_read_timeout(header_read_timeout)
                // A client that sends its request and then shuts its side (`nc -N`) still gets
                // the answer.
                .half_close(true)
                .serve_connection(TokioIo::new(tcp), service)
                .with_upgrades();
            tokio::pin!(conn);
            tokio::select! {
                _ = conn.as_mut() => return,
                () = stop.cancelled() => {}
            }
            // Finish the request in hand, then close.
            conn.as_mut().graceful_shutdown();
            let _ = conn.await;
        });
    }
    drop(listener);
    hub.shutdown();
    let deadline = tokio::time::Instant::now() + SHUTDOWN_GRACE;
    let finished = tokio::time::timeout_at(deadline, async {
        while connections.join_next().await.is_some() {}
    });
    if finished.await.is_err() {
        tracing::warn!(
            "{} connections still open {SHUTDOWN_GRACE:?} after shutdown began: closing them",
            connections.len()
        );
        connections.abort_all();
    }
    // Upgraded connections are no longer hyper's: wait for the clients' loops, which send their
    // close frame and end.
    ws_clients.close();
    if tokio::time::timeout_at(deadline, ws_clients.wait())
        .await
        .is_err()
    {
        tracing::warn!(
            "{} WebSocket clients still open {SHUTDOWN_GRACE:?} after shutdown began",
            ws_clients.len()
        );
    }
    Ok(())
}

/// A connection's socket with its slot, counted in `vemlight_connections_open`: dropped together,
/// whoever ends up holding the socket (hyper, or an upgraded WebSocket).
struct Counted {
    tcp: TcpStream,
    _slot: OwnedSemaphorePermit,
    metrics: Arc<Metrics>,
}

impl Counted {
    fn new(tcp: TcpStream, slot: OwnedSemaphorePermit, metrics: Arc<Metrics>) -> Self {
        metrics.connections_open.fetch_add(1, Relaxed);
        Counted {
            tcp,
            _slot: slot,
            metrics,
        }
    }
}

impl Drop for Counted {
    fn drop(&mut self) {
        self.metrics.connections_open.fetch_sub(1, Relaxed);
    }
}

impl AsyncRead for Counted {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        Pin::new(&mut self.tcp).poll_read(cx, buf)
    }
}

impl AsyncWrite for Counted {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.tcp).poll_write(cx, buf)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.tcp).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.tcp.is_write_vectored()
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.tcp).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.tcp).poll_shutdown(cx)
    }
}

/// Resolves when SIGINT or SIGTERM arrives.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let terminate = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let terminate = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {},
        _ = terminate => {},
    }
}
