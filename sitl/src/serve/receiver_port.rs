//! The rover receiver's own TCP port: why it exists is that a receiver
//! wired to the companion sends its RTCM3 straight to it, not through the
//! autopilot; the served flight writes the receiver's bytes here.

use std::sync::Arc;
use std::time::Duration;

use tokio::io::AsyncWriteExt;
use tokio::sync::Mutex;

/// The rover receiver's own port: a TCP listener whose latest client gets
/// every byte the receiver sends. Nothing waits for a client: bytes sent
/// while none is connected are lost, as on a serial line nobody reads.
pub struct ReceiverPort {
    client: Arc<Mutex<Option<tokio::net::TcpStream>>>,
    _accept: tokio::task::JoinHandle<()>,
}

impl ReceiverPort {
    /// Listens on `addr` (`host:port`) and keeps accepting clients.
    pub async fn listen(addr: &str) -> std::io::Result<Self> {
        let listener = tokio::net::TcpListener::bind(addr).await?;
        let client = Arc::new(Mutex::new(None));
        let c = client.clone();
        let accept = tokio::spawn(async move {
            while let Ok((s, _)) = listener.accept().await {
                let _ = s.set_nodelay(true);
                *c.lock().await = Some(s);
            }
        });
        Ok(Self {
            client,
            _accept: accept,
        })
    }

    /// Writes `bytes` to the client, if any (dropped on an error or after
    /// 100 ms).
    pub(super) async fn write(&self, bytes: &[u8]) {
        let mut guard = self.client.lock().await;
        if let Some(s) = guard.as_mut() {
            let ok = tokio::time::timeout(Duration::from_millis(100), s.write_all(bytes)).await;
            if !matches!(ok, Ok(Ok(()))) {
                *guard = None;
            }
        }
    }
}
