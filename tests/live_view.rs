//! The live view: with `live_view.enabled`, the daemon serves its log's
//! channels over Foxglove's WebSocket protocol while it flies. A client
//! (as Foxglove's app connects: subprotocol `foxglove.sdk.v1`) receives the
//! server's info and the advertised channels with their JSON schemas,
//! subscribes to `/pose` and receives poses (binary frames: opcode 0x01,
//! subscription id, log time, the record's JSON). The flight meanwhile goes
//! on at its rate.

mod common;

use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::HeaderValue;
use tokio_tungstenite::tungstenite::Message;

use cmsckf::eval;
use cmsckf_sitl::dataset::Dataset;

use common::harness;

fn free_tcp_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

#[test]
fn a_websocket_client_receives_the_pose_while_the_vehicle_flies() {
    let dir = tempfile::tempdir().unwrap();
    let (mut cfg, port) = common::loopback_config(dir.path());
    let ws_port = free_tcp_port();
    cfg.live_view.enabled = true;
    cfg.live_view.address = format!("127.0.0.1:{ws_port}");
    cfg.log.path = dir.path().join("live.mcap").display().to_string();
    let ds = Dataset::generate("racetrack", 3, Some(20.0), &eval::sim_config_for(&cfg)).unwrap();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (stop, daemon) = rt.block_on(async { common::spawn_daemon(cfg.clone()) });
    let sitl = harness::fly_in_background(harness::serve_options(&cfg, port, 4.0), ds);

    let poses = rt.block_on(async {
        // The server is up once the daemon started.
        let mut ws = None;
        for _ in 0..100 {
            let mut req = format!("ws://127.0.0.1:{ws_port}/").into_client_request().unwrap();
            req.headers_mut()
                .insert("sec-websocket-protocol", HeaderValue::from_static("foxglove.sdk.v1"));
            if let Ok((s, _)) = tokio_tungstenite::connect_async(req).await {
                ws = Some(s);
                break;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let mut ws = ws.expect("the live view accepts a Foxglove client");
        let mut pose_channel = None;
        let mut server_info = false;
        let mut poses = Vec::new();
        let deadline = tokio::time::Instant::now() + Duration::from_secs(30);
        while poses.len() < 20 {
            let msg = match tokio::time::timeout_at(deadline, ws.next()).await {
                Ok(Some(Ok(m))) => m,
                other => panic!("the stream ended early: {other:?} ({} poses)", poses.len()),
            };
            match msg {
                Message::Text(t) => {
                    let v: serde_json::Value = serde_json::from_str(&t).unwrap();
                    match v["op"].as_str() {
                        Some("serverInfo") => {
                            assert_eq!(v["name"], "cmsckf");
                            server_info = true;
                        }
                        Some("advertise") => {
                            for c in v["channels"].as_array().unwrap() {
                                if c["topic"] == "/pose" && pose_channel.is_none() {
                                    assert_eq!(c["encoding"], "json");
                                    assert_eq!(c["schemaName"], "foxglove.PoseInFrame");
                                    assert_eq!(c["schemaEncoding"], "jsonschema");
                                    let id = c["id"].as_u64().unwrap();
                                    pose_channel = Some(id);
                                    let sub = serde_json::json!({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": id}]});
                                    ws.send(Message::text(sub.to_string())).await.unwrap();
                                }
                            }
                        }
                        _ => {}
                    }
                }
                Message::Binary(b) => {
                    assert_eq!(b[0], 0x01, "message data");
                    assert_eq!(u32::from_le_bytes(b[1..5].try_into().unwrap()), 7, "our subscription");
                    let log_time_ns = u64::from_le_bytes(b[5..13].try_into().unwrap());
                    let pose: serde_json::Value = serde_json::from_slice(&b[13..]).unwrap();
                    assert!(pose["pose"]["position"]["x"].is_number(), "{pose}");
                    poses.push((log_time_ns, pose));
                }
                _ => {}
            }
        }
        assert!(server_info, "serverInfo came first");
        poses
    });
    let report = harness::join(sitl);
    let _ = stop.send(());
    let summary = rt.block_on(daemon).unwrap().expect("the daemon ran");
    eprintln!(
        "live view: {} poses received; the flight: {} estimates at {:.1} Hz, ATE {:.2} m; log {} messages",
        poses.len(),
        report.estimates_received,
        report.output_rate_hz,
        report.ate_m,
        summary.counters.get("log_messages").copied().unwrap_or(0)
    );
    // Poses in time order, stamped like the log (Unix time once known).
    assert!(poses.windows(2).all(|w| w[0].0 <= w[1].0));
    assert!(report.output_rate_hz > 25.0, "the flight kept its rate");
}
