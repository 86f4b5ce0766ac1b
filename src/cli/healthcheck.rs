//! `vemlight healthcheck`: exits 0 when a daemon answers `GET /healthz` with 200 (the container's
//! health check; it needs no curl in the image).

use super::serve::DEFAULT_BIND;
use anyhow::{Context, bail};
use std::io::Write;

#[derive(clap::Args)]
pub struct HealthcheckArgs {
    /// host:port of the daemon, read as `serve --bind` reads it (an any-interface address is asked
    /// on loopback).
    #[arg(env = "VEMLIGHT_BIND", default_value = DEFAULT_BIND)]
    pub addr: String,
}

/// `vemlight healthcheck`: a plain HTTP/1.0 GET of /healthz.
pub fn run(addr: &str) -> anyhow::Result<()> {
    use std::io::Read;
    use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
    let timeout = std::time::Duration::from_secs(3);
    let sock: SocketAddr = addr
        .to_socket_addrs()
        .with_context(|| format!("'{addr}' is not host:port"))?
        .next()
        .with_context(|| format!("'{addr}' names no address"))?;
    // A daemon listening on every interface is asked on loopback.
    let sock = match sock {
        SocketAddr::V4(a) if a.ip().is_unspecified() => {
            SocketAddr::from((std::net::Ipv4Addr::LOCALHOST, a.port()))
        }
        SocketAddr::V6(a) if a.ip().is_unspecified() => {
            SocketAddr::from((std::net::Ipv6Addr::LOCALHOST, a.port()))
        }
        other => other,
    };
    let mut s = TcpStream::connect_timeout(&sock, timeout)
        .with_context(|| format!("cannot connect to {sock}"))?;
    s.set_read_timeout(Some(timeout))?;
    write!(s, "GET /healthz HTTP/1.0\r\nHost: {addr}\r\n\r\n")?;
    let mut reply = String::new();
    s.read_to_string(&mut reply).map_err(|e| match e.kind() {
        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut => {
            anyhow::anyhow!("{sock} accepted but did not answer /healthz within {timeout:?}")
        }
        _ => anyhow::anyhow!("reading the answer from {sock}: {e}"),
    })?;
    let status = reply.lines().next().unwrap_or("");
    if status.split_whitespace().nth(1) == Some("200") {
        Ok(())
    } else {
        bail!("unhealthy: {status}")
    }
}
