//! `gnss.source = "stream"`: the daemon reads a receiver's raw RTCM3 or UBX
//! from TCP, decodes it, counts a corrupted frame, and reconnects after the
//! receiver drops the connection.
mod common;

use std::time::Duration;

use tokio::io::AsyncWriteExt;

use cmsckf::config::GnssSource;

/// A reference file of `tests/data`.
fn data(name: &str) -> Vec<u8> {
    std::fs::read(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data")
            .join(name),
    )
    .unwrap()
}

/// Serves `bytes` on a TCP port `passes` times (a connection each, closed
/// after it: a receiver that drops the link), with a daemon reading it as
/// its receiver (`week_hint` for the ephemerides' week); the daemon's
/// counters once it has read them, as a lookup.
async fn counters_after_stream(bytes: Vec<u8>, passes: usize, week_hint: u32) -> impl Fn(&str) -> u64 {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let server = tokio::spawn(async move {
        for _ in 0..passes {
            let (mut s, _) = listener.accept().await.unwrap();
            for piece in bytes.chunks(4096) {
                s.write_all(piece).await.unwrap();
            }
            s.shutdown().await.unwrap();
        }
    });
    let dir = tempfile::tempdir().unwrap();
    let (mut cfg, _port) = common::loopback_config(dir.path());
    cfg.gnss.source = GnssSource::Stream;
    cfg.gnss.stream = format!("tcp:{addr}");
    cfg.gnss.week_hint = week_hint;
    let (stop_tx, daemon) = common::spawn_daemon(cfg);
    tokio::time::timeout(Duration::from_secs(10), server)
        .await
        .unwrap()
        .unwrap();
    tokio::time::sleep(Duration::from_millis(500)).await;
    let _ = stop_tx.send(());
    let counters = daemon.await.unwrap().unwrap().counters;
    eprintln!("{counters:#?}");
    move |k: &str| counters.get(k).copied().unwrap_or(0)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn daemon_reads_a_tcp_rtcm_stream() {
    let mut bytes = data("3040_msm7.rtcm3");
    let second = bytes
        .iter()
        .enumerate()
        .skip(1)
        .find(|(_, b)| **b == 0xD3)
        .map(|(i, _)| i)
        .unwrap();
    bytes[second + 12] ^= 0xFF; // one bad CRC
                                // Two connections: the daemon reconnects after the first closes.
    let c = counters_after_stream(bytes, 2, 1316).await;
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
    let mut bytes = data("ubx_20080526.ubx");
    let sync = bytes.windows(2).position(|w| w == [0xB5, 0x62]).unwrap();
    bytes[sync + 10] ^= 0xFF; // one bad checksum
    let c = counters_after_stream(bytes, 1, 1481).await;
    assert_eq!(c("ubx_checksum_failure"), 1);
    assert_eq!(c("rtcm_crc_failure"), 0);
    assert!(c("gnss_epochs") >= 240, "epochs {}", c("gnss_epochs"));
    assert!(c("gnss_rover_msm_from_receiver") >= 240);
}
