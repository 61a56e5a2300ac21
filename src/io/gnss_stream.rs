//! A raw RTCM3 byte stream straight from a receiver wired to the companion
//! computer (`gnss.source = "stream"`): `serial:/dev/ttyUSB0:115200`,
//! `tcp:host:port` (a client) or `file:path` (read once, for tests).
//!
//! Bytes are forwarded as they come; framing and CRC checks happen in the
//! fusion loop's decoder. A failed or closed source is retried every second.

use std::time::Duration;

use tokio::io::AsyncReadExt;
use tokio::sync::{mpsc, watch};

use crate::counters::{Counter, Counters};

/// A parsed stream address.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum StreamSpec {
    Serial { path: String, baud: u32 },
    Tcp(String),
    File(String),
}

/// Parses `serial:PATH:BAUD`, `tcp:HOST:PORT` or `file:PATH`.
pub fn parse(spec: &str) -> Result<StreamSpec, String> {
    if let Some(rest) = spec.strip_prefix("serial:") {
        let (path, baud) = rest
            .rsplit_once(':')
            .ok_or_else(|| format!("'{spec}': expected serial:PATH:BAUD"))?;
        let baud = baud
            .parse()
            .map_err(|_| format!("'{spec}': baud '{baud}' is not a number"))?;
        return Ok(StreamSpec::Serial {
            path: path.to_string(),
            baud,
        });
    }
    if let Some(rest) = spec.strip_prefix("tcp:") {
        return Ok(StreamSpec::Tcp(rest.to_string()));
    }
    if let Some(rest) = spec.strip_prefix("file:") {
        return Ok(StreamSpec::File(rest.to_string()));
    }
    Err(format!("'{spec}': use serial:PATH:BAUD, tcp:HOST:PORT or file:PATH"))
}

type Reader = Box<dyn tokio::io::AsyncRead + Unpin + Send>;

async fn open(spec: &StreamSpec) -> std::io::Result<Reader> {
    Ok(match spec {
        StreamSpec::Serial { path, baud } => {
            use tokio_serial::SerialPortBuilderExt;
            Box::new(
                tokio_serial::new(path, *baud)
                    .open_native_async()
                    .map_err(std::io::Error::other)?,
            )
        }
        StreamSpec::Tcp(addr) => Box::new(tokio::net::TcpStream::connect(addr).await?),
        StreamSpec::File(path) => Box::new(tokio::fs::File::open(path).await?),
    })
}

/// Reads the stream until `stop`, sending each chunk to `out`.
pub async fn run(spec: StreamSpec, out: mpsc::Sender<Vec<u8>>, counters: Counters, mut stop: watch::Receiver<bool>) {
    let mut buf = vec![0u8; 4096];
    loop {
        let mut r = tokio::select! {
            r = open(&spec) => match r {
                Ok(r) => r,
                Err(e) => {
                    counters.add(Counter::GnssStreamOpenError, 1);
                    tracing::warn!(error = %e, source = ?spec, "cannot open the GNSS stream; retrying");
                    tokio::select! { _ = tokio::time::sleep(Duration::from_secs(1)) => continue, _ = stop.changed() => return }
                }
            },
            _ = stop.changed() => return,
        };
        counters.add(Counter::GnssStreamConnected, 1);
        loop {
            let n = tokio::select! { n = r.read(&mut buf) => n, _ = stop.changed() => return };
            match n {
                Ok(0) => break,
                Ok(n) => {
                    counters.add(Counter::GnssStreamBytes, n as u64);
                    if out.send(buf[..n].to_vec()).await.is_err() {
                        return;
                    }
                }
                Err(e) => {
                    tracing::warn!(error = %e, "GNSS stream read failed");
                    break;
                }
            }
        }
        if matches!(spec, StreamSpec::File(_)) {
            // A file is read once.
            let _ = stop.changed().await;
            return;
        }
        tokio::select! { _ = tokio::time::sleep(Duration::from_secs(1)) => {}, _ = stop.changed() => return }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses() {
        assert_eq!(
            parse("serial:/dev/ttyUSB0:115200").unwrap(),
            StreamSpec::Serial {
                path: "/dev/ttyUSB0".into(),
                baud: 115200
            }
        );
        assert_eq!(
            parse("tcp:127.0.0.1:5000").unwrap(),
            StreamSpec::Tcp("127.0.0.1:5000".into())
        );
        assert_eq!(
            parse("file:/tmp/x.rtcm3").unwrap(),
            StreamSpec::File("/tmp/x.rtcm3".into())
        );
        assert!(parse("serial:/dev/ttyUSB0:fast").unwrap_err().contains("baud"));
        assert!(parse("udp:1").is_err());
    }
}
