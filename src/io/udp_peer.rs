//! A UDP socket that talks to one peer: the autopilot.
//!
//! The `mavlink` crate's `udpin` connection replies to whoever sent the
//! last datagram, so any datagram on the port (garbage included) redirected
//! our estimates. Here the peer is either configured (`udpout:`) or learned
//! by the link from the autopilot's first HEARTBEAT and kept (`udpin:`);
//! until it is known nothing is sent. After a long silence the link marks it
//! stale: we still send to it (our HEARTBEAT says the link is down), and the
//! autopilot's next HEARTBEAT, from wherever it comes, is learned again (it
//! may come back on a new port).
//! This file moves bytes only; what a frame is, and whose, is the link's
//! business (`io::mavlink`).

use std::net::SocketAddr;
use std::sync::Mutex;

use tokio::net::UdpSocket;

/// Largest datagram read (bytes): UDP's own limit.
pub const MAX_DATAGRAM: usize = 65_536;

/// How the socket was opened.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UdpMode {
    /// `udpin:HOST:PORT`: bound there; the peer is learned.
    Listen,
    /// `udpout:HOST:PORT`: the peer is that address, for good.
    Send,
}

/// A UDP socket and the one peer it sends to.
#[derive(Debug)]
pub struct UdpPeer {
    socket: UdpSocket,
    mode: UdpMode,
    /// The peer, and whether it is stale (may be learned again).
    peer: Mutex<(Option<SocketAddr>, bool)>,
}

impl UdpPeer {
    /// Opens `udpin:HOST:PORT` or `udpout:HOST:PORT`; `None` for any other
    /// scheme.
    pub async fn open(address: &str) -> Option<std::io::Result<Self>> {
        let (mode, rest) = if let Some(r) = address.strip_prefix("udpin:") {
            (UdpMode::Listen, r)
        } else if let Some(r) = address.strip_prefix("udpout:") {
            (UdpMode::Send, r)
        } else {
            return None;
        };
        Some(Self::open_mode(mode, rest).await)
    }

    async fn open_mode(mode: UdpMode, host_port: &str) -> std::io::Result<Self> {
        let addr = tokio::net::lookup_host(host_port).await?.next().ok_or_else(|| {
            std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!("'{host_port}' resolves to nothing"),
            )
        })?;
        let (socket, peer) = match mode {
            UdpMode::Listen => (UdpSocket::bind(addr).await?, None),
            UdpMode::Send => {
                let any: SocketAddr = if addr.is_ipv4() {
                    ([0, 0, 0, 0], 0).into()
                } else {
                    (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
                };
                (UdpSocket::bind(any).await?, Some(addr))
            }
        };
        Ok(Self {
            socket,
            mode,
            peer: Mutex::new((peer, false)),
        })
    }

    /// The next datagram into `buf`: its length and sender.
    pub async fn recv(&self, buf: &mut [u8]) -> std::io::Result<(usize, SocketAddr)> {
        self.socket.recv_from(buf).await
    }

    /// Sends `bytes` to the peer. `Ok(false)`: no peer known yet, nothing
    /// sent.
    pub async fn send(&self, bytes: &[u8]) -> std::io::Result<bool> {
        let Some(to) = self.peer() else {
            return Ok(false);
        };
        self.socket.send_to(bytes, to).await?;
        Ok(true)
    }

    /// The peer, if known.
    pub fn peer(&self) -> Option<SocketAddr> {
        self.state().0
    }

    /// Whether the peer may be learned again: none is known, or it went
    /// stale (`udpin` only).
    pub fn learning(&self) -> bool {
        let p = self.state();
        self.mode == UdpMode::Listen && (p.0.is_none() || p.1)
    }

    /// Takes `addr` as the peer if it may be learned ([`Self::learning`]).
    /// Returns whether it was learned now.
    pub fn learn(&self, addr: SocketAddr) -> bool {
        let mut p = self.state();
        if self.mode == UdpMode::Listen && (p.0.is_none() || p.1) {
            *p = (Some(addr), false);
            true
        } else {
            false
        }
    }

    /// Marks a learned peer stale (`udpin` only): still sent to, and
    /// replaced by the next one learned. Returns whether it was marked now.
    pub fn forget(&self) -> bool {
        let mut p = self.state();
        if self.mode == UdpMode::Listen && p.0.is_some() && !p.1 {
            p.1 = true;
            true
        } else {
            false
        }
    }

    /// The peer and its staleness, locked (a poisoned lock still holds
    /// them: nothing here can leave them half-written).
    fn state(&self) -> std::sync::MutexGuard<'_, (Option<SocketAddr>, bool)> {
        self.peer.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The local address (for tests and logs).
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.socket.local_addr()
    }

    pub fn mode(&self) -> UdpMode {
        self.mode
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn a_listening_socket_sends_only_to_the_peer_it_learned() {
        let me = UdpPeer::open("udpin:127.0.0.1:0").await.unwrap().unwrap();
        let port = me.local_addr().unwrap().port();
        let autopilot = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let stranger = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        assert!(!me.send(b"x").await.unwrap(), "nothing is sent before a peer is known");
        stranger.send_to(b"junk", ("127.0.0.1", port)).await.unwrap();
        let mut buf = [0u8; 64];
        let (_, from) = me.recv(&mut buf).await.unwrap();
        assert_eq!(from, stranger.local_addr().unwrap());
        // The link learns the autopilot only; a stranger's datagram changes nothing.
        assert!(me.learn(autopilot.local_addr().unwrap()));
        assert!(!me.learn(from), "a learned peer is kept");
        assert!(me.send(b"hello").await.unwrap());
        let (n, _) = autopilot.recv_from(&mut buf).await.unwrap();
        assert_eq!(&buf[..n], b"hello");
        assert!(!me.learning());
        assert!(me.forget());
        assert!(me.learning(), "stale after a silence: learned again");
        assert!(me.send(b"still here").await.unwrap(), "a stale peer is still sent to");
        let (n, _) = autopilot.recv_from(&mut buf).await.unwrap();
        assert_eq!(&buf[..n], b"still here");
        assert!(me.learn(from));
        assert_eq!(me.peer(), Some(from));
    }

    #[tokio::test]
    async fn a_sending_socket_keeps_its_configured_peer() {
        let target = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let addr = format!("udpout:{}", target.local_addr().unwrap());
        let me = UdpPeer::open(&addr).await.unwrap().unwrap();
        assert!(!me.learn("127.0.0.1:9".parse().unwrap()));
        assert!(!me.forget());
        assert_eq!(me.peer(), Some(target.local_addr().unwrap()));
        assert!(UdpPeer::open("tcpout:127.0.0.1:1").await.is_none());
    }
}
