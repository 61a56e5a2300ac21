//! The MAVLink link's two tasks: the receive task turns autopilot messages
//! into [`FusionMsg`]s (reassembling `GPS_RTCM_DATA` fragments and keeping
//! the TIMESYNC clock offset), and the send task writes every outbound
//! message. Rejections are counted by reason and the link goes on.

use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use super::{signing_key, DaemonError, FusionMsg};
use crate::config::{Config, GnssSource};
use crate::estimator::ImuMeas;
use crate::gnss::reassembly::{Reassembled, Reassembler};
use crate::io::mavlink::{self as mav, Link};
use crate::io::messages::{Inbound, Outbound, Source};
use crate::io::Counters;

/// Opens the link to the autopilot.
pub(super) async fn connect(cfg: &Config) -> Result<Arc<Link>, DaemonError> {
    let link = Link::connect(
        &cfg.mavlink.address,
        cfg.mavlink.system_id,
        cfg.mavlink.component_id,
        cfg.mavlink.system_id,
        cfg.mavlink.autopilot_component_id,
        signing_key(cfg)?.map(|k| (k, cfg.mavlink.signing_link_id)),
    )
    .await
    .map_err(|source| DaemonError::Link {
        address: cfg.mavlink.address.clone(),
        source,
    })?;
    Ok(Arc::new(link))
}

/// What the receive task needs besides the link.
pub(super) struct Receive {
    pub counters: Counters,
    pub fusion_tx: mpsc::Sender<FusionMsg>,
    /// Companion monotonic → autopilot boot clock offset (µs), from TIMESYNC.
    pub mono_offset_us: Arc<AtomicI64>,
    pub start: Instant,
    pub stop: watch::Receiver<bool>,
}

/// Per-link state of the receive task.
struct RxState {
    reasm: Reassembler,
    rtcm_from_mavlink: bool,
    /// Without a rover station id, RTCM counts as the rover's only when it
    /// comes from the configured vehicle.
    rover_id: u16,
    vehicle: u32,
}

/// The receive task: every message from the link, until `stop`.
pub(super) fn spawn_receiver(cfg: &Config, link: Arc<Link>, mut r: Receive) -> JoinHandle<()> {
    let mut st = RxState {
        reasm: Reassembler::new(),
        rtcm_from_mavlink: cfg.gnss.source == GnssSource::Mavlink,
        rover_id: cfg.gnss.rover_station_id,
        vehicle: cfg.mavlink.system_id as u32,
    };
    tokio::spawn(async move {
        loop {
            let got = tokio::select! {
                got = link.recv() => got,
                _ = r.stop.changed() => return,
            };
            let (src, msg, gap) = match got {
                Ok(v) => v,
                Err(mav::LinkError::Io(e)) => {
                    r.counters.add("mavlink_io_error", 1);
                    tracing::warn!(error = %e, "MAVLink link error");
                    tokio::time::sleep(Duration::from_millis(200)).await;
                    continue;
                }
                Err(mav::LinkError::Parse(e)) => {
                    r.counters.add("mavlink_undecodable", 1);
                    tracing::warn!(reason = "mavlink_undecodable", "{e}");
                    continue;
                }
                Err(mav::LinkError::Rejected(why)) => {
                    r.counters.add(&format!("mavlink_rejected_{why}"), 1);
                    tracing::warn!(reason = why, "MAVLink message rejected");
                    continue;
                }
            };
            if gap > 0 {
                r.counters.add("mavlink_frames_lost_or_corrupt", gap as u64);
                tracing::warn!(
                    frames = gap,
                    reason = "mavlink_frames_lost_or_corrupt",
                    "sequence gap: frames lost or dropped as corrupt (bad CRC, unknown id)"
                );
            }
            r.counters.add("mavlink_messages", 1);
            if let Some(m) = to_fusion(msg, src, &mut st, &r) {
                if r.fusion_tx.try_send(m).is_err() {
                    r.counters.add("fusion_queue_full", 1);
                }
            }
        }
    })
}

/// One inbound message as the fusion loop takes it, if it takes it;
/// TIMESYNC replies and RTCM fragments are handled here.
fn to_fusion(msg: Inbound, src: Source, st: &mut RxState, r: &Receive) -> Option<FusionMsg> {
    let counters = &r.counters;
    match msg {
        Inbound::Imu {
            t_us,
            accel_mps2,
            gyro_radps,
            kind,
        } => {
            counters.add(
                match kind {
                    "highres" => "imu_highres",
                    "scaled" => "imu_scaled",
                    _ => "imu_raw",
                },
                1,
            );
            Some(FusionMsg::Imu(ImuMeas {
                t_s: t_us as f64 * 1e-6,
                accel_mps2,
                gyro_radps,
            }))
        }
        Inbound::Attitude {
            roll_rad,
            pitch_rad,
            yaw_rad,
            ..
        } => {
            counters.add("attitude", 1);
            Some(FusionMsg::Attitude {
                roll: roll_rad,
                pitch: pitch_rad,
                yaw: yaw_rad,
            })
        }
        Inbound::LocalPosition {
            t_boot_ms,
            p_ned_m,
            v_ned_mps,
        } => {
            counters.add("local_position", 1);
            Some(FusionMsg::LocalPosition {
                t_s: t_boot_ms as f64 * 1e-3,
                p_ned_m,
                v_ned_mps,
            })
        }
        Inbound::GpsAccuracy { h_acc_m, v_acc_m } => {
            counters.add("gps_accuracy", 1);
            Some(FusionMsg::GpsAccuracy { h_acc_m, v_acc_m })
        }
        Inbound::Timesync { tc1_ns, ts1_ns } => {
            on_timesync(tc1_ns, ts1_ns, r);
            None
        }
        Inbound::RtcmFragment { flags, data } => {
            if st.rtcm_from_mavlink {
                on_rtcm_fragment(flags, &data, src, st, r);
            }
            None
        }
        Inbound::Heartbeat => {
            counters.add("heartbeat_in", 1);
            None
        }
        Inbound::SystemTime { unix_us, boot_ms } => {
            counters.add("system_time", 1);
            Some(FusionMsg::SystemTime { unix_us, boot_ms })
        }
        Inbound::GpsGlobalOrigin {
            lat_deg,
            lon_deg,
            alt_m,
        } => {
            counters.add("gps_global_origin", 1);
            Some(FusionMsg::Origin {
                lat_deg,
                lon_deg,
                alt_m,
            })
        }
        Inbound::Other(_) => None,
    }
}

/// Our TIMESYNC request came back: offset = tc1 − midpoint of our clock.
fn on_timesync(tc1_ns: i64, ts1_ns: i64, r: &Receive) {
    if tc1_ns != 0 {
        let now_ns = r.start.elapsed().as_nanos() as i64;
        let rtt = now_ns - ts1_ns;
        if (0..1_000_000_000).contains(&rtt) {
            let offset_us = (tc1_ns - (ts1_ns + now_ns) / 2) / 1000;
            r.mono_offset_us.store(offset_us, Ordering::Relaxed);
            r.counters.add("timesync", 1);
        }
    }
}

/// Reassembles `GPS_RTCM_DATA` fragments (MAVLink spec) and forwards each
/// whole RTCM3 message from the rover.
fn on_rtcm_fragment(flags: u8, data: &[u8], src: Source, st: &mut RxState, r: &Receive) {
    let counters = &r.counters;
    let mut got = st.reasm.push(flags, data);
    loop {
        match got {
            Reassembled::Message(m) => {
                counters.add("rtcm_messages", 1);
                counters.add("rtcm_bytes", m.len() as u64);
                if !(st.rover_id != 0 || src.system == st.vehicle) {
                    counters.add("rtcm_other_source", 1);
                } else if r.fusion_tx.try_send(FusionMsg::Rtcm(m)).is_err() {
                    counters.add("fusion_queue_full", 1);
                }
                break;
            }
            Reassembled::Pending => break,
            Reassembled::Rejected(why) => {
                counters.add(why, 1);
                tracing::warn!(reason = why, "RTCM fragment rejected");
                break;
            }
            Reassembled::Dropped { reason, then } => {
                counters.add(reason, 1);
                tracing::warn!(reason, "RTCM sequence dropped: a fragment is missing");
                got = *then;
            }
        }
    }
}

/// The send task: every outbound message goes through here.
pub(super) fn spawn_sender(
    link: Arc<Link>,
    mut out_rx: mpsc::Receiver<Outbound>,
    counters: Counters,
) -> JoinHandle<()> {
    tokio::spawn(async move {
        while let Some(m) = out_rx.recv().await {
            match link.send(&m).await {
                Ok(()) => {
                    if matches!(m, Outbound::VisionPositionEstimate { .. }) {
                        counters.add("vpe_sent", 1);
                    }
                }
                Err(e) => {
                    counters.add("mavlink_send_error", 1);
                    tracing::debug!(error = %e, "send failed");
                }
            }
        }
    })
}
