//! MAVLink 2 message signing: with a key configured, the daemon takes only
//! messages signed with that key, rejects and counts unsigned and badly
//! signed ones by reason, and signs what it sends.
mod common;

use std::os::unix::fs::PermissionsExt;
use std::time::Duration;

use mavlink::dialects::ardupilotmega as apm;
use mavlink::{MavHeader, SigningConfig, SigningData};
use tokio::net::UdpSocket;

const KEY: [u8; 32] = [0x5a; 32];

fn heartbeat() -> apm::MavMessage {
    apm::MavMessage::HEARTBEAT(apm::HEARTBEAT_DATA {
        mavtype: apm::MavType::MAV_TYPE_QUADROTOR,
        autopilot: apm::MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        system_status: apm::MavState::MAV_STATE_ACTIVE,
        mavlink_version: 3,
        ..Default::default()
    })
}

fn frame(seq: u8, signer: Option<&SigningData>) -> Vec<u8> {
    let h = MavHeader {
        system_id: 1,
        component_id: 1,
        sequence: seq,
    };
    let mut buf = Vec::new();
    mavlink::write_v2_msg_signed(&mut buf, h, &heartbeat(), signer).unwrap();
    buf
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn signed_link_rejects_and_counts_unsigned_and_forged_messages() {
    let dir = tempfile::tempdir().unwrap();
    let (mut cfg, port) = common::loopback_config(dir.path());
    let key_path = dir.path().join("signing.key");
    let hex: String = KEY.iter().map(|b| format!("{b:02x}")).collect();
    std::fs::write(&key_path, hex + "\n").unwrap();
    std::fs::set_permissions(&key_path, std::fs::Permissions::from_mode(0o600)).unwrap();
    cfg.mavlink.signing_key_file = key_path.display().to_string();
    let (stop_tx, daemon) = common::spawn_daemon(cfg);
    tokio::time::sleep(Duration::from_millis(200)).await;

    let sock = UdpSocket::bind("127.0.0.1:0").await.unwrap();
    sock.connect(("127.0.0.1", port)).await.unwrap();
    let good = SigningData::from_config(SigningConfig::new(KEY, 1, true, false));
    let forger = SigningData::from_config(SigningConfig::new([0x33; 32], 1, true, false));
    let n = 20;
    for i in 0..n {
        let seq = (3 * i) as u8;
        sock.send(&frame(seq, Some(&good))).await.unwrap();
        sock.send(&frame(seq + 1, None)).await.unwrap();
        sock.send(&frame(seq + 2, Some(&forger))).await.unwrap();
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    // Keep talking (signed) while the daemon's HEARTBEATs come back to us;
    // they must verify against the key and only against it.
    let checker = SigningData::from_config(SigningConfig::new(KEY, 0, false, false));
    let wrong = SigningData::from_config(SigningConfig::new([0x33; 32], 0, false, false));
    let (mut verified, mut verified_wrong_key) = (0, 0);
    let mut buf = [0u8; 2048];
    for i in 0..40 {
        sock.send(&frame((200 + i) as u8, Some(&good))).await.unwrap();
        if let Ok(Ok(len)) = tokio::time::timeout(Duration::from_millis(100), sock.recv(&mut buf)).await {
            let mut r = mavlink::MavlinkReader::new(&buf[..len]);
            if let Ok((_, apm::MavMessage::HEARTBEAT(_))) = r.read_any_message_signed::<apm::MavMessage>(Some(&checker))
            {
                verified += 1;
            }
            let mut r = mavlink::MavlinkReader::new(&buf[..len]);
            if r.read_any_message_signed::<apm::MavMessage>(Some(&wrong)).is_ok() {
                verified_wrong_key += 1;
            }
        }
        if verified >= 2 {
            break;
        }
    }
    let _ = stop_tx.send(());
    let summary = daemon.await.unwrap().unwrap();
    let c = |k: &str| summary.counters.get(k).copied().unwrap_or(0);
    assert_eq!(c("mavlink_rejected_unsigned"), n, "{:?}", summary.counters);
    assert_eq!(c("mavlink_rejected_bad_signature"), n, "{:?}", summary.counters);
    assert!(c("heartbeat_in") >= n, "{:?}", summary.counters);
    // Rejected frames are not counted a second time as lost.
    assert_eq!(c("mavlink_frames_lost_or_corrupt"), 0, "{:?}", summary.counters);
    assert!(verified >= 1, "no signed HEARTBEAT from the daemon");
    assert_eq!(verified_wrong_key, 0, "the daemon's messages verify under another key");
}
