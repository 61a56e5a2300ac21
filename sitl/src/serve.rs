//! The mock autopilot (`cmsckf-sitl serve`): it stands in for ArduPilot on
//! the MAVLink link and for the camera front end on the feature socket, and
//! scores what the daemon sends back against the truth.
//!
//! Over MAVLink it sends HEARTBEAT (quadrotor), SYSTEM_TIME, HIGHRES_IMU,
//! ATTITUDE and LOCAL_POSITION_NED (its own EKF's view: here, the truth),
//! answers SET_MESSAGE_INTERVAL and TIMESYNC, and receives
//! VISION_POSITION_ESTIMATE. The flight is replayed at real time or at
//! `speedup`. Times on the wire are the autopilot's boot clock, which starts
//! `BOOT0_S` before the flight.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use mavlink::dialects::ardupilotmega as apm;
use mavlink::{AsyncMavConnection, MavHeader};
use nalgebra::Vector3;
use serde::Serialize;
use tokio::io::AsyncWriteExt;
use tokio::net::UnixStream;

use crate::dataset::Dataset;
use crate::metrics;
use cmsckf_models::gnss::{GPS_EPOCH_UNIX_S, GPS_UTC_LEAP_S};

/// Boot time of the autopilot at the start of the flight (s).
pub const BOOT0_S: f64 = 20.0;
/// RTCM reference-station id of the simulated receiver.
pub const ROVER_STATION_ID: u16 = 7;

/// Splits an RTCM message into `GPS_RTCM_DATA` fragments (MAVLink spec):
/// flags bit 0 = fragmented, bits 1–2 = fragment id, bits 3–7 = sequence.
pub fn rtcm_fragments(msg: &[u8], seq: u8) -> Vec<apm::GPS_RTCM_DATA_DATA> {
    let chunks: Vec<&[u8]> = msg.chunks(180).collect();
    let fragmented = chunks.len() > 1;
    chunks
        .iter()
        .enumerate()
        .take(4)
        .map(|(i, c)| {
            let mut data = [0u8; 180];
            data[..c.len()].copy_from_slice(c);
            apm::GPS_RTCM_DATA_DATA {
                flags: if fragmented {
                    1 | ((i as u8) << 1) | ((seq & 0x1f) << 3)
                } else {
                    (seq & 0x1f) << 3
                },
                len: c.len() as u8,
                data,
            }
        })
        .collect()
}

/// A fault the mock autopilot injects.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultKind {
    /// Nothing goes over MAVLink.
    LinkDrop,
    /// No RTCM.
    GnssOutage,
    /// No camera frames.
    CameraOutage,
    /// No IMU samples.
    ImuGap,
    /// IMU samples with NaN or absurd (1e5 m/s²) accelerations, alternately.
    NanImu,
    /// A plausible but wrong 50 m/s² added to the x accelerometer (a
    /// saturating vibration): the filter is fooled, diverges and must reset.
    ImuSpike,
    /// The front end disconnects and reconnects at the end.
    FrontendRestart,
    /// RTCM frames corrupted (bad CRC).
    RtcmBadCrc,
    /// 100 m added to two satellites' pseudoranges.
    PrOutlier,
    /// The autopilot reboots at the start: silent for the duration, then
    /// its boot clock restarts from 1 s.
    ClockJump,
    /// IMU samples sent in swapped pairs and twice each; camera lines and
    /// RTCM messages sent twice.
    DupReorder,
}

impl FaultKind {
    pub fn name(self) -> &'static str {
        match self {
            FaultKind::LinkDrop => "link_drop",
            FaultKind::GnssOutage => "gnss_outage",
            FaultKind::CameraOutage => "camera_outage",
            FaultKind::ImuGap => "imu_gap",
            FaultKind::NanImu => "nan_imu",
            FaultKind::FrontendRestart => "frontend_restart",
            FaultKind::RtcmBadCrc => "rtcm_bad_crc",
            FaultKind::PrOutlier => "pr_outlier",
            FaultKind::ClockJump => "clock_jump",
            FaultKind::DupReorder => "dup_reorder",
            FaultKind::ImuSpike => "imu_spike",
        }
    }

    pub const ALL: [FaultKind; 11] = [
        FaultKind::LinkDrop,
        FaultKind::GnssOutage,
        FaultKind::CameraOutage,
        FaultKind::ImuGap,
        FaultKind::NanImu,
        FaultKind::FrontendRestart,
        FaultKind::RtcmBadCrc,
        FaultKind::PrOutlier,
        FaultKind::ClockJump,
        FaultKind::DupReorder,
        FaultKind::ImuSpike,
    ];
}

/// `NAME@START+DURATION` (seconds of flight).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fault {
    pub kind: FaultKind,
    pub start_s: f64,
    pub duration_s: f64,
}

impl Fault {
    fn active(&self, t: f64) -> bool {
        t >= self.start_s && t < self.start_s + self.duration_s
    }
}

impl std::str::FromStr for Fault {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let kinds = FaultKind::ALL;
        let (name, rest) = s
            .split_once('@')
            .ok_or_else(|| format!("fault '{s}': expected NAME@START+DURATION"))?;
        let kind = kinds
            .into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| format!("unknown fault '{name}': use {}", kinds.map(|k| k.name()).join(", ")))?;
        let (a, b) = rest
            .split_once('+')
            .ok_or_else(|| format!("fault '{s}': expected NAME@START+DURATION"))?;
        let start_s: f64 = a
            .parse()
            .map_err(|_| format!("fault '{s}': start '{a}' is not a number"))?;
        let duration_s: f64 = b
            .parse()
            .map_err(|_| format!("fault '{s}': duration '{b}' is not a number"))?;
        if !(start_s.is_finite() && start_s >= 0.0 && duration_s.is_finite() && duration_s > 0.0) {
            return Err(format!("fault '{s}': start ≥ 0 and duration > 0 are needed"));
        }
        Ok(Fault {
            kind,
            start_s,
            duration_s,
        })
    }
}

/// How the daemon came through one fault.
#[derive(Clone, Debug, Serialize)]
pub struct FaultReport {
    pub name: String,
    pub start_s: f64,
    pub end_s: f64,
    /// Seconds after the fault's end until the error is back within twice
    /// its pre-fault median + 0.5 m (0 if it never left; NaN if it never came back).
    pub recovery_s: f64,
    pub peak_error_m: f64,
    pub resets: u32,
    /// A daemon `HEARTBEAT` showed a state other than active between the
    /// fault's start and 3 s after its end.
    pub degraded_reported: bool,
}

/// Settings of one served flight.
#[derive(Clone, Debug)]
pub struct ServeOptions {
    /// Address in the mavlink crate's syntax, e.g. `udpout:127.0.0.1:14550`.
    pub mavlink: String,
    /// The daemon's feature socket.
    pub feature_socket: PathBuf,
    /// Replay speed (1 = real time).
    pub speedup: f64,
    /// Faults to inject.
    pub faults: Vec<Fault>,
}

/// One estimate received from the daemon.
#[derive(Clone, Debug)]
struct Received {
    wall: Instant,
    t_us: u64,
    /// Flight time of `t_us` (see [`flight_times`]).
    t_s: f64,
    p: Vector3<f64>,
    cov: [f32; 21],
    reset_counter: u8,
}

/// The score of a served flight.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub duration_s: f64,
    pub estimates_received: usize,
    /// Estimates per second of flight (autopilot) time.
    pub output_rate_hz: f64,
    pub ate_m: f64,
    pub ate_aligned_m: f64,
    /// Wall time from sending an IMU sample to receiving the estimate stamped
    /// with it.
    pub latency_ms_p50: f64,
    pub latency_ms_p99: f64,
    pub latency_ms_max: f64,
    pub time_to_first_estimate_s: f64,
    pub reset_count: u32,
    pub covariance_ok: bool,
    pub imu_sent: usize,
    pub frames_sent: usize,
    pub speedup: f64,
    pub odometry_received: usize,
    pub gps_origin_set: bool,
    pub faults: Vec<FaultReport>,
    /// The daemon's `STATUSTEXT`s: `(flight time s, text)`.
    pub status_texts: Vec<(f64, String)>,
}

impl Report {
    /// The thresholds this report misses (a NaN figure misses).
    pub fn misses(&self, max_ate_m: Option<f64>, min_rate_hz: Option<f64>, max_latency_ms: Option<f64>) -> Vec<String> {
        let mut v = Vec::new();
        if let Some(m) = max_ate_m {
            if self.ate_m.is_nan() || self.ate_m > m {
                v.push(format!("ATE {:.3} m > {m} m", self.ate_m));
            }
        }
        if let Some(m) = min_rate_hz {
            if self.output_rate_hz.is_nan() || self.output_rate_hz < m {
                v.push(format!("output rate {:.2} Hz < {m} Hz", self.output_rate_hz));
            }
        }
        if let Some(m) = max_latency_ms {
            if self.latency_ms_p99.is_nan() || self.latency_ms_p99 > m {
                v.push(format!("p99 latency {:.2} ms > {m} ms", self.latency_ms_p99));
            }
        }
        v
    }
}

/// Errors that stop the mock autopilot.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error("MAVLink address '{0}': {1}")]
    Link(String, std::io::Error),
}

/// The autopilot's boot clock (µs) at flight time `t_s`: `BOOT0_S` at the
/// start, or 1 s at a reboot at `reboot_s` and counting from there.
fn boot_us(t_s: f64, reboot_s: Option<f64>) -> u64 {
    match reboot_s {
        Some(r) if t_s >= r => ((t_s - r + 1.0) * 1e6).round() as u64,
        _ => ((t_s + BOOT0_S) * 1e6).round() as u64,
    }
}

/// Flight times of the estimates, in arrival order: their boot-clock stamps
/// mapped back through [`boot_us`], switching to the post-reboot clock at
/// the first stamp that falls back by more than 2 s.
fn flight_times(rec: &mut [Received], reboot_s: Option<f64>) {
    let mut after = false;
    let mut max_boot_s = f64::NEG_INFINITY;
    for r in rec {
        let boot_s = r.t_us as f64 * 1e-6;
        if reboot_s.is_some() && boot_s < max_boot_s - 2.0 {
            after = true;
        }
        max_boot_s = max_boot_s.max(boot_s);
        r.t_s = match reboot_s {
            Some(rb) if after => boot_s + rb - 1.0,
            _ => boot_s - BOOT0_S,
        };
    }
}

/// Serves `ds` to the daemon and scores its estimates.
pub async fn serve(opts: &ServeOptions, ds: &Dataset) -> Result<Report, ServeError> {
    let mut conn = mavlink::connect_async::<apm::MavMessage>(&opts.mavlink)
        .await
        .map_err(|e| ServeError::Link(opts.mavlink.clone(), e))?;
    conn.set_protocol_version(mavlink::MavlinkVersion::V2);
    conn.set_allow_recv_any_version(true);
    let conn = Arc::new(conn);
    let header = MavHeader {
        system_id: 1,
        component_id: 1,
        sequence: 0,
    };
    let started = Instant::now();
    let boot_ns = move || ((BOOT0_S * 1e9) as i64) + started.elapsed().as_nanos() as i64;
    let reboot_s = opts
        .faults
        .iter()
        .find(|f| f.kind == FaultKind::ClockJump)
        .map(|f| f.start_s);
    let boot = move |t: f64| boot_us(t, reboot_s);
    let t_start = Instant::now();
    let speedup = opts.speedup;
    // The daemon's HEARTBEAT states and STATUSTEXTs, with flight times.
    let heartbeats: Arc<Mutex<Vec<(f64, apm::MavState)>>> = Arc::default();
    let status_texts: Arc<Mutex<Vec<(f64, String)>>> = Arc::default();
    let received: Arc<Mutex<Vec<Received>>> = Arc::default();
    let extras: Arc<Mutex<(usize, usize)>> = Arc::default(); // (ODOMETRY, SET_GPS_GLOBAL_ORIGIN)
    let (stop_tx, mut stop_rx) = tokio::sync::watch::channel(false);

    // Receive: answer commands and time sync, collect estimates.
    let rx = {
        let conn = conn.clone();
        let received = received.clone();
        let extras = extras.clone();
        let heartbeats = heartbeats.clone();
        let status_texts = status_texts.clone();
        let flight_t = move || t_start.elapsed().as_secs_f64() * speedup;
        tokio::spawn(async move {
            loop {
                let r = tokio::select! { r = conn.recv() => r, _ = stop_rx.changed() => return };
                let Ok((h, msg)) = r else {
                    tokio::time::sleep(Duration::from_millis(10)).await;
                    continue;
                };
                match msg {
                    apm::MavMessage::VISION_POSITION_ESTIMATE(d) => {
                        if let Ok(mut v) = received.lock() {
                            v.push(Received {
                                wall: Instant::now(),
                                t_us: d.usec,
                                t_s: f64::NAN,
                                p: Vector3::new(d.x as f64, d.y as f64, d.z as f64),
                                cov: d.covariance,
                                reset_counter: d.reset_counter,
                            });
                        }
                    }
                    apm::MavMessage::HEARTBEAT(hb) => {
                        if let Ok(mut v) = heartbeats.lock() {
                            v.push((flight_t(), hb.system_status));
                        }
                    }
                    apm::MavMessage::STATUSTEXT(st) => {
                        if let Ok(mut v) = status_texts.lock() {
                            let text = st
                                .text
                                .to_str()
                                .unwrap_or("(not UTF-8)")
                                .trim_end_matches('\0')
                                .to_string();
                            v.push((flight_t(), text));
                        }
                    }
                    apm::MavMessage::ODOMETRY(_) => {
                        if let Ok(mut e) = extras.lock() {
                            e.0 += 1;
                        }
                    }
                    #[allow(deprecated)]
                    apm::MavMessage::SET_GPS_GLOBAL_ORIGIN(_) => {
                        if let Ok(mut e) = extras.lock() {
                            e.1 += 1;
                        }
                    }
                    apm::MavMessage::COMMAND_LONG(c) => {
                        let ack = apm::MavMessage::COMMAND_ACK(apm::COMMAND_ACK_DATA {
                            command: c.command,
                            result: apm::MavResult::MAV_RESULT_ACCEPTED,
                            target_system: h.system_id as u8,
                            target_component: h.component_id,
                            ..Default::default()
                        });
                        let _ = conn.send(&header, &ack).await;
                    }
                    apm::MavMessage::TIMESYNC(t) if t.tc1 == 0 => {
                        let reply = apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
                            tc1: boot_ns(),
                            ts1: t.ts1,
                            target_system: h.system_id as u8,
                            target_component: h.component_id,
                        });
                        let _ = conn.send(&header, &reply).await;
                    }
                    _ => {}
                }
            }
        })
    };

    // Stream the flight in time order, paced by the wall clock.
    let rate_imu = ds.cfg.imu_rate_hz;
    let mut sent_wall: Vec<Option<Instant>> = vec![None; ds.imu.len()];
    let mut feat: Option<UnixStream> = None;
    let (mut k_imu, mut k_cam) = (0usize, 0usize);
    let mut next_slow = 0.0; // 10 Hz attitude / position
    let mut next_1hz = 0.0;
    let mut k_gnss = 0usize;
    let mut rtcm_seq = 0u8;
    let mut frames_sent = 0;
    let send = |m: apm::MavMessage| {
        let conn = conn.clone();
        async move {
            let _ = conn.send(&header, &m).await;
        }
    };
    loop {
        let t_imu = ds.imu.get(k_imu).map_or(f64::INFINITY, |m| m.t_s);
        let t_cam = ds.frames.get(k_cam).map_or(f64::INFINITY, |f| f.t_s);
        let t_gnss = ds.gnss.get(k_gnss).map_or(f64::INFINITY, |e| e.t_s.max(0.0));
        let t = t_imu.min(t_cam).min(next_slow).min(next_1hz).min(t_gnss);
        if !t.is_finite() || t > ds.duration_s + 1e-9 {
            break;
        }
        let target = t_start + Duration::from_secs_f64(t.max(0.0) / opts.speedup);
        tokio::time::sleep_until(target.into()).await;
        let active = |k: FaultKind| opts.faults.iter().any(|f| f.kind == k && f.active(t));
        // A rebooting autopilot is as silent as a dropped link.
        let link_down = active(FaultKind::LinkDrop) || active(FaultKind::ClockJump);
        let copies = if active(FaultKind::DupReorder) { 2 } else { 1 };
        if t == t_gnss {
            // The receiver's MSM7 epoch, as it would relay it.
            let mut ep = ds.gnss[k_gnss].clone();
            if active(FaultKind::PrOutlier) {
                for s in ep.sats.iter_mut().take(2) {
                    s.pseudorange_m += 100.0;
                }
            }
            if !link_down && !active(FaultKind::GnssOutage) {
                if let Ok(mut bytes) = crate::rtcm_out::encode_epoch(&ep, ROVER_STATION_ID) {
                    if active(FaultKind::RtcmBadCrc) && bytes.len() > 10 {
                        bytes[8] ^= 0xFF;
                    }
                    for _ in 0..copies {
                        for f in rtcm_fragments(&bytes, rtcm_seq) {
                            send(apm::MavMessage::GPS_RTCM_DATA(f)).await;
                        }
                    }
                    rtcm_seq = rtcm_seq.wrapping_add(1);
                }
            }
            k_gnss += 1;
        } else if link_down && (t == t_imu || t == next_1hz || t == next_slow) {
            // Nothing from the autopilot gets through (the camera, on its own
            // socket, still does).
            if t == t_imu {
                k_imu += 1;
            } else if t == next_1hz {
                next_1hz += 1.0;
            } else {
                next_slow += 0.1;
            }
        } else if t == next_1hz {
            next_1hz += 1.0;
            send(apm::MavMessage::HEARTBEAT(apm::HEARTBEAT_DATA {
                custom_mode: 0,
                mavtype: apm::MavType::MAV_TYPE_QUADROTOR,
                autopilot: apm::MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
                base_mode: apm::MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                system_status: apm::MavState::MAV_STATE_ACTIVE,
                mavlink_version: 3,
            }))
            .await;
            let g = &ds.cfg.gnss;
            let unix_s = GPS_EPOCH_UNIX_S + g.start_week as f64 * 604_800.0 + g.start_tow_s + t - GPS_UTC_LEAP_S;
            send(apm::MavMessage::SYSTEM_TIME(apm::SYSTEM_TIME_DATA {
                time_unix_usec: (unix_s * 1e6).round() as u64,
                time_boot_ms: (boot(t) / 1000) as u32,
            }))
            .await;
            let o = g.origin_llh;
            #[allow(deprecated)]
            send(apm::MavMessage::GPS_GLOBAL_ORIGIN(apm::GPS_GLOBAL_ORIGIN_DATA {
                latitude: (o[0] * 1e7).round() as i32,
                longitude: (o[1] * 1e7).round() as i32,
                altitude: (o[2] * 1e3).round() as i32,
                time_usec: boot(t),
            }))
            .await;
            // Broadcast ephemerides every 30 s, as receivers repeat them.
            if (t as u64).is_multiple_of(30) {
                for e in &ds.ephemerides {
                    if let Ok(bytes) = cmsckf_models::gnss::rtcm_eph::encode_ephemeris(e) {
                        for f in rtcm_fragments(&bytes, rtcm_seq) {
                            send(apm::MavMessage::GPS_RTCM_DATA(f)).await;
                        }
                        rtcm_seq = rtcm_seq.wrapping_add(1);
                    }
                }
            }
        } else if t == next_slow {
            next_slow += 0.1;
            let s = ds.trajectory.sample(t);
            let (r, p, y) = s.q_W_B.euler_angles();
            let ms = (boot(t) / 1000) as u32;
            send(apm::MavMessage::ATTITUDE(apm::ATTITUDE_DATA {
                time_boot_ms: ms,
                roll: r as f32,
                pitch: p as f32,
                yaw: y as f32,
                rollspeed: s.w_B.x as f32,
                pitchspeed: s.w_B.y as f32,
                yawspeed: s.w_B.z as f32,
            }))
            .await;
            send(apm::MavMessage::LOCAL_POSITION_NED(apm::LOCAL_POSITION_NED_DATA {
                time_boot_ms: ms,
                x: s.p_B_in_W.x as f32,
                y: s.p_B_in_W.y as f32,
                z: s.p_B_in_W.z as f32,
                vx: s.v_B_in_W.x as f32,
                vy: s.v_B_in_W.y as f32,
                vz: s.v_B_in_W.z as f32,
            }))
            .await;
        } else if t == t_imu {
            if active(FaultKind::ImuGap) {
                k_imu += 1;
                continue;
            }
            let nan = active(FaultKind::NanImu);
            let spike = if active(FaultKind::ImuSpike) { 50.0 } else { 0.0 };
            let imu = |k: usize| {
                let m = &ds.imu[k];
                let bad = if k.is_multiple_of(2) { f32::NAN } else { 1e5 };
                apm::MavMessage::HIGHRES_IMU(apm::HIGHRES_IMU_DATA {
                    time_usec: boot(m.t_s),
                    xacc: if nan { bad } else { (m.accel_mps2.x + spike) as f32 },
                    yacc: m.accel_mps2.y as f32,
                    zacc: m.accel_mps2.z as f32,
                    xgyro: m.gyro_radps.x as f32,
                    ygyro: m.gyro_radps.y as f32,
                    zgyro: m.gyro_radps.z as f32,
                    fields_updated: apm::HighresImuUpdatedFlags::from_bits_truncate(0x3f),
                    ..Default::default()
                })
            };
            // Duplicated and out of order: the next sample first, then this
            // one twice.
            let order: &[usize] = if copies > 1 && k_imu + 1 < ds.imu.len() {
                &[1, 0, 0]
            } else {
                &[0]
            };
            for &j in order {
                send(imu(k_imu + j)).await;
                if !nan && sent_wall[k_imu + j].is_none() {
                    sent_wall[k_imu + j] = Some(Instant::now());
                }
            }
            k_imu += order.iter().max().map_or(1, |m| m + 1);
        } else {
            let f = &ds.frames[k_cam];
            k_cam += 1;
            if active(FaultKind::FrontendRestart) {
                // The front end has crashed: no connection, no frames.
                feat = None;
                continue;
            }
            if active(FaultKind::CameraOutage) {
                continue;
            }
            let mut line = format!("{{\"v\":1,\"t_us\":{},\"cam\":0,\"features\":[", boot(f.t_s));
            for (i, o) in f.features.iter().enumerate() {
                if i > 0 {
                    line.push(',');
                }
                line += &format!("[{},{:.3},{:.3}]", o.landmark_id, o.u_px, o.v_px);
            }
            line += "]}\n";
            if feat.is_none() {
                feat = UnixStream::connect(&opts.feature_socket).await.ok();
            }
            if let Some(s) = feat.as_mut() {
                if s.write_all(line.repeat(copies).as_bytes()).await.is_ok() {
                    frames_sent += 1;
                } else {
                    feat = None;
                }
            }
        }
    }
    // Let the last estimates arrive.
    tokio::time::sleep(Duration::from_millis(300)).await;
    let _ = stop_tx.send(true);
    let _ = rx.await;
    let mut rec = received.lock().map(|v| v.clone()).unwrap_or_default();
    flight_times(&mut rec, reboot_s);
    let hbs = heartbeats.lock().map(|v| v.clone()).unwrap_or_default();
    let mut report = score(ds, &rec, &sent_wall, rate_imu, k_imu, frames_sent, opts.speedup);
    report.faults = opts.faults.iter().map(|f| fault_report(ds, &rec, &hbs, f)).collect();
    report.status_texts = status_texts.lock().map(|v| v.clone()).unwrap_or_default();
    if let Ok(e) = extras.lock() {
        report.odometry_received = e.0;
        report.gps_origin_set = e.1 > 0;
    }
    Ok(report)
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    v[((v.len() - 1) as f64 * p).round() as usize]
}

fn score(
    ds: &Dataset,
    rec: &[Received],
    sent_wall: &[Option<Instant>],
    rate_imu: f64,
    imu_sent: usize,
    frames_sent: usize,
    speedup: f64,
) -> Report {
    let mut est = Vec::new();
    let mut truth = Vec::new();
    let mut lat = Vec::new();
    let mut resets = 0;
    let mut cov_ok = true;
    let mut last_reset = rec.first().map(|r| r.reset_counter);
    for r in rec {
        let t = r.t_s;
        est.push(r.p);
        truth.push(ds.trajectory.sample(t).p_B_in_W);
        let k = (t * rate_imu).round();
        if k >= 0.0 {
            if let Some(Some(w)) = sent_wall.get(k as usize) {
                lat.push(r.wall.saturating_duration_since(*w).as_secs_f64() * 1e3);
            }
        }
        if Some(r.reset_counter) != last_reset {
            resets += 1;
            last_reset = Some(r.reset_counter);
        }
        // Diagonal entries of the upper-triangular layout: 0, 6, 11, 15, 18, 20.
        cov_ok &= r.cov.iter().all(|c| c.is_finite()) && [0, 6, 11, 15, 18, 20].iter().all(|&i| r.cov[i] > 0.0);
    }
    let ate = if est.is_empty() {
        None
    } else {
        Some(metrics::ate(&est, &truth))
    };
    let t_first = rec.first().map_or(f64::NAN, |r| r.t_s);
    let t_last = rec.last().map_or(f64::NAN, |r| r.t_s);
    Report {
        duration_s: ds.duration_s,
        estimates_received: rec.len(),
        output_rate_hz: if rec.len() > 1 {
            (rec.len() - 1) as f64 / (t_last - t_first)
        } else {
            0.0
        },
        ate_m: ate.map_or(f64::NAN, |a| a.unaligned_m),
        ate_aligned_m: ate.map_or(f64::NAN, |a| a.aligned_m),
        latency_ms_p50: percentile(&mut lat.clone(), 0.5),
        latency_ms_p99: percentile(&mut lat.clone(), 0.99),
        latency_ms_max: lat.iter().copied().fold(f64::NAN, f64::max),
        time_to_first_estimate_s: t_first,
        reset_count: resets,
        covariance_ok: cov_ok && !rec.is_empty(),
        imu_sent,
        frames_sent,
        speedup,
        odometry_received: 0,
        gps_origin_set: false,
        faults: Vec::new(),
        status_texts: Vec::new(),
    }
}

/// Error, peak and recovery around one fault (see [`FaultReport`]).
fn fault_report(ds: &Dataset, rec: &[Received], heartbeats: &[(f64, apm::MavState)], f: &Fault) -> FaultReport {
    let end = f.start_s + f.duration_s;
    let degraded_reported = heartbeats
        .iter()
        .any(|(t, s)| *t >= f.start_s && *t <= end + 3.0 && *s != apm::MavState::MAV_STATE_ACTIVE);
    let err: Vec<(f64, f64, u8)> = rec
        .iter()
        .map(|r| {
            let t = r.t_s;
            (t, (r.p - ds.trajectory.sample(t).p_B_in_W).norm(), r.reset_counter)
        })
        .collect();
    let mut before: Vec<f64> = err
        .iter()
        .filter(|e| e.0 >= f.start_s - 5.0 && e.0 < f.start_s)
        .map(|e| e.1)
        .collect();
    let baseline = percentile(&mut before, 0.5);
    let threshold = 2.0 * if baseline.is_finite() { baseline } else { 0.0 } + 0.5;
    let window: Vec<&(f64, f64, u8)> = err.iter().filter(|e| e.0 >= f.start_s && e.0 <= end + 5.0).collect();
    let peak = window.iter().map(|e| e.1).fold(0.0, f64::max);
    // Resets: changes of reset_counter from the last estimate before the
    // fault through the window.
    let before_start = err.iter().rev().find(|e| e.0 < f.start_s).map(|e| e.2);
    let counters: Vec<u8> = before_start.into_iter().chain(window.iter().map(|e| e.2)).collect();
    let resets = counters.windows(2).filter(|w| w[0] != w[1]).count() as u32;
    // Recovered at the first time after the end from which every estimate
    // for a second stays under the threshold.
    let after: Vec<&(f64, f64, u8)> = err.iter().filter(|e| e.0 >= end).collect();
    let exceeded = window.iter().any(|e| e.1 > threshold);
    let recovery_s = if !exceeded {
        0.0
    } else {
        after
            .iter()
            .enumerate()
            .find(|(i, e)| {
                after[*i..]
                    .iter()
                    .take_while(|x| x.0 <= e.0 + 1.0)
                    .all(|x| x.1 <= threshold)
            })
            .map_or(f64::NAN, |(_, e)| (e.0 - end).max(0.0))
    };
    FaultReport {
        name: f.kind.name().to_string(),
        start_s: f.start_s,
        end_s: end,
        recovery_s,
        peak_error_m: peak,
        resets,
        degraded_reported,
    }
}
