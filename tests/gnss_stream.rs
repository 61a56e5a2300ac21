//! `gnss.source = "stream"`: the daemon reads raw RTCM3 from a TCP receiver,
//! decodes it, counts a corrupted frame, and reconnects after the receiver
//! drops the connection.
mod common;

use std::time::Duration;

use tokio::io::AsyncWriteExt;

use cmsckf::config::GnssSource;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn daemon_reads_a_tcp_rtcm_stream() {
    let mut bytes = std::fs::read(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data")
            .join("3040_msm7.rtcm3"),
    )
    .unwrap();
    let second = bytes
        .iter()
        .enumerate()
        .skip(1)
        .find(|(_, b)| **b == 0xD3)
        .map(|(i, _)| i)
        .unwrap();
    bytes[second + 12] ^= 0xFF; // one bad CRC
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let server = tokio::spawn(async move {
        // Two connections: the daemon reconnects after the first closes.
        for _ in 0..2 {
            let (mut s, _) = listener.accept().await.unwrap();
            s.write_all(&bytes).await.unwrap();
            s.shutdown().await.unwrap();
        }
    });

    let dir = tempfile::tempdir().unwrap();
    let (mut cfg, _port) = common::loopback_config(dir.path());
    cfg.gnss.source = GnssSource::Stream;
    cfg.gnss.stream = format!("tcp:{addr}");
    cfg.gnss.week_hint = 1316;
    let (stop_tx, daemon) = common::spawn_daemon(cfg);
    tokio::time::timeout(Duration::from_secs(10), server)
        .await
        .unwrap()
        .unwrap();
    tokio::time::sleep(Duration::from_millis(500)).await;
    let _ = stop_tx.send(());
    let summary = daemon.await.unwrap().unwrap();
    let c = |k: &str| summary.counters.get(k).copied().unwrap_or(0);
    eprintln!("{:#?}", summary.counters);
    assert_eq!(c("gnss_stream_connected"), 2);
    assert_eq!(c("rtcm_crc_failure"), 2, "one per pass");
    assert!(c("gnss_epochs") >= 230, "epochs {}", c("gnss_epochs"));
    // No SYSTEM_TIME from an autopilot here: epochs cannot be placed in
    // autopilot time, and say so.
    assert_eq!(c("gnss_no_system_time"), c("gnss_epochs"));
}

/// A u-blox receiver on a serial-like stream: UBX among NMEA, one frame
/// with a bad checksum. The daemon recognises UBX from the bytes, builds
/// its orbits from the receiver's own subframes and completes its epochs;
/// the NMEA and UBX bytes are not reported as RTCM CRC failures.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn daemon_reads_a_ubx_stream() {
    let mut bytes = std::fs::read(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data")
            .join("ubx_20080526.ubx"),
    )
    .unwrap();
    let sync = bytes.windows(2).position(|w| w == [0xB5, 0x62]).unwrap();
    bytes[sync + 10] ^= 0xFF; // one bad checksum
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let server = tokio::spawn(async move {
        let (mut s, _) = listener.accept().await.unwrap();
        for piece in bytes.chunks(4096) {
            s.write_all(piece).await.unwrap();
        }
        s.shutdown().await.unwrap();
    });
    let dir = tempfile::tempdir().unwrap();
    let (mut cfg, _port) = common::loopback_config(dir.path());
    cfg.gnss.source = GnssSource::Stream;
    cfg.gnss.stream = format!("tcp:{addr}");
    cfg.gnss.week_hint = 1481;
    let (stop_tx, daemon) = common::spawn_daemon(cfg);
    tokio::time::timeout(Duration::from_secs(10), server)
        .await
        .unwrap()
        .unwrap();
    tokio::time::sleep(Duration::from_millis(500)).await;
    let _ = stop_tx.send(());
    let summary = daemon.await.unwrap().unwrap();
    let c = |k: &str| summary.counters.get(k).copied().unwrap_or(0);
    eprintln!("{:#?}", summary.counters);
    assert_eq!(c("ubx_checksum_failure"), 1);
    assert_eq!(c("rtcm_crc_failure"), 0);
    assert!(c("gnss_epochs") >= 240, "epochs {}", c("gnss_epochs"));
    assert!(c("gnss_rover_msm_from_receiver") >= 240);
}
