//! The MAVLink link's two tasks: the receive task turns autopilot messages
//! into [`FusionMsg`]s (reassembling `GPS_RTCM_DATA` fragments and keeping
//! the TIMESYNC clock offset), and the send task writes every outbound
//! message. Rejections are counted by reason and the link goes on.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicI64, AtomicU8, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use nalgebra::Vector3;
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use super::{signing_key, DaemonError, FusionMsg, RtcmStream};
use crate::config::{Config, GnssSource, ImuMessageChoice};
use crate::counters::{Counter, Counters};
use crate::estimator::ImuMeas;
use crate::gnss::reassembly::{Reassembled, Reassembler};
use crate::io::mavlink::{self as mav, Link};
use crate::io::messages::{AutopilotKind, ImuMessage, Inbound, Outbound, Source};

/// Opens the link to the autopilot (warning when it listens on an open
/// network without signing).
pub(super) async fn connect(cfg: &Config) -> Result<Arc<Link>, DaemonError> {
    if open_network_unsigned(cfg) {
        tracing::warn!(
            address = %cfg.mavlink.address,
            "listening beyond loopback without MAVLink signing: anyone on this network can speak as the \
             autopilot before it does; set mavlink.signing_key_file, or use a loopback or serial link"
        );
    }
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

/// `udpin:`/`tcpin:` on an address other than loopback, without a signing
/// key.
fn open_network_unsigned(cfg: &Config) -> bool {
    let a = &cfg.mavlink.address;
    let host = a
        .strip_prefix("udpin:")
        .or_else(|| a.strip_prefix("tcpin:"))
        .and_then(|rest| rest.rsplit_once(':').map(|(h, _)| h));
    let loopback = |h: &str| h == "localhost" || h.parse::<std::net::IpAddr>().is_ok_and(|ip| ip.is_loopback());
    cfg.mavlink.signing_key_file.is_empty() && host.is_some_and(|h| !loopback(h.trim_matches(['[', ']'])))
}

/// What the receive task needs besides the link.
pub(super) struct Receive {
    /// The IMU message taken ([`ImuMessage::to_u8`]), set here when the
    /// autopilot's HEARTBEAT says what it is.
    pub imu_message: Arc<AtomicU8>,
    pub counters: Counters,
    pub fusion_tx: mpsc::Sender<FusionMsg>,
    /// Companion monotonic → autopilot boot clock offset (µs), from TIMESYNC.
    pub mono_offset_us: Arc<AtomicI64>,
    pub start: Instant,
    pub stop: watch::Receiver<bool>,
    /// For the replies to the autopilot's TIMESYNC requests.
    pub out_tx: mpsc::Sender<Outbound>,
}

/// Most RTCM sources (MAVLink system and component) reassembled at once;
/// fragments from more are dropped and counted (`rtcm_sources_full`).
const MAX_RTCM_SOURCES: usize = 8;

/// Per-link state of the receive task.
struct RxState {
    /// One reassembler per sender: a ground station's corrections and the
    /// rover's own stream interleave their fragments on one link.
    reasm: BTreeMap<Source, Reassembler>,
    /// Whether `GPS_RTCM_DATA` is read: with any GNSS source, since a base
    /// station's corrections come that way even when the rover's receiver
    /// has its own port.
    rtcm_from_mavlink: bool,
    vehicle: u32,
    /// The autopilot: sensor and time messages are taken from it alone.
    autopilot: Source,
    /// IMU time after which the next magnetometer reading is passed on (µs).
    next_mag_us: u64,
    /// The field directions read since the last one passed on, summed, and
    /// how many.
    mag_sum_B: Vector3<f64>,
    mag_n: u32,
    /// `mavlink.imu_message`, resolved at each autopilot HEARTBEAT.
    imu_choice: ImuMessageChoice,
    /// What the autopilot's HEARTBEAT says it is.
    kind: Option<AutopilotKind>,
    /// When a `HIGHRES_IMU` last came (taken or not): with `auto`, an
    /// autopilot other than PX4 that sends none (ArduPilot on a 1 MB board)
    /// has its `RAW_IMU` or `SCALED_IMU` taken instead.
    last_highres: Instant,
    /// When a `HIGHRES_IMU` last came within [`HIGHRES_MAX_INTERVAL`] of
    /// the one before: a stream at an IMU's rate. A trickle (a link that
    /// lets 1 or 2.5 of them through a second) never sets it, so `auto`
    /// does not stay on, or go back to, a message that starves the filter.
    last_highres_flowing: Instant,
    /// Since when `HIGHRES_IMU` has come without a pause of
    /// [`HIGHRES_MAX_INTERVAL`]: `auto` goes back to it only once it has
    /// flowed for [`HIGHRES_STEADY_FOR`], so a stream in bursts, or a
    /// trickle, does not flap the message taken.
    highres_since: Option<Instant>,
    /// The last IMU sample taken: PX4 sends its last `SCALED_IMU` again,
    /// the same sample, when only its magnetometer has a new reading.
    last_imu: Option<(u64, Vector3<f64>, Vector3<f64>)>,
    /// `SCALED_IMU`'s, `LOCAL_POSITION_NED`'s, `SCALED_PRESSURE`'s and
    /// `SYSTEM_TIME`'s `time_boot_ms`, unwrapped: a u32 of milliseconds wraps after 49.7
    /// days of uptime, which would otherwise read as a reboot (a filter
    /// restart in flight), and shift GNSS time by the wrap.
    scaled_imu_clock: BootMsClock,
    local_position_clock: BootMsClock,
    pressure_clock: BootMsClock,
    system_time_clock: BootMsClock,
    /// The journal's limit on rejection warnings, shared by the link's
    /// rejections and the IMU's.
    warn: WarnLimit,
}

/// A `time_boot_ms` stream made continuous across its u32 wrap, without
/// a reference clock: each time is read on the turn that puts it nearest
/// the stream's last, and only a time within [`BOOT_MS_NEAR`] of it
/// moves the stream on. Anything further (a reboot, a stray or forged
/// stamp, a stream back after a long silence) is passed on as it came, on
/// the first turn, for the daemon's time guard to judge, and changes
/// nothing here: one bad stamp never becomes the reference.
#[derive(Clone, Copy, Debug, Default)]
struct BootMsClock {
    /// The latest time taken (ms, unwrapped).
    last_ms: Option<u64>,
}

/// How near the stream's last time a new one must be to move it on (ms).
const BOOT_MS_NEAR: u64 = 60_000;

impl BootMsClock {
    /// `raw_ms` on a clock that does not wrap (ms since boot).
    fn unwrap(&mut self, raw_ms: u32) -> u64 {
        const TURN: u64 = 1 << 32;
        let raw = u64::from(raw_ms);
        let Some(last) = self.last_ms else {
            self.last_ms = Some(raw);
            return raw;
        };
        // The turn that puts it nearest the last time (never before the
        // first turn).
        let turn = (last.saturating_sub(raw) + TURN / 2) / TURN;
        let t = turn * TURN + raw;
        if t.abs_diff(last) > BOOT_MS_NEAR {
            return raw;
        }
        self.last_ms = Some(last.max(t));
        t
    }
}

/// Magnetometer readings reach the fusion loop at most this often (µs),
/// each the mean of the readings of its period: they give the first yaw,
/// and the mean that refines it while the vehicle stands (`compass.rs`,
/// whose steps and settling count 100 ms readings).
const MAG_PERIOD_US: u64 = 100_000;

/// The magnetic field's direction of the IMU messages, the mean of each
/// [`MAG_PERIOD_US`] (a reboot's earlier clock starts the period again):
/// every reading counts, none is dropped for the rate (PX4's SITL sends
/// one with each of its 50 Hz `HIGHRES_IMU`, each 2.5° off in heading, and
/// the start's 1 s of them had been 10 readings). It is the field as
/// the autopilot calibrated it, `HIGHRES_IMU`'s, whichever IMU message is
/// taken: PX4's `SCALED_IMU` carries its magnetometer's raw reading
/// (`sensor_mag`, in the sensor's own frame, before calibration), which
/// put the first yaw 3° off on PX4's SITL. Another message's field counts
/// only while no `HIGHRES_IMU` comes.
fn magnetometer(msg: &Inbound, st: &mut RxState) -> Option<FusionMsg> {
    let Inbound::Imu {
        t_us,
        kind,
        mag_B: Some(mag_B),
        ..
    } = msg
    else {
        return None;
    };
    if *kind != ImuMessage::Highres && st.last_highres.elapsed() <= HIGHRES_FALLBACK_AFTER {
        return None;
    }
    let dir_B = mag_B.try_normalize(0.0)?;
    st.mag_sum_B += dir_B;
    st.mag_n += 1;
    if *t_us < st.next_mag_us && st.next_mag_us - t_us < 2 * MAG_PERIOD_US {
        return None;
    }
    st.next_mag_us = t_us + MAG_PERIOD_US;
    let mean_B = st.mag_sum_B / f64::from(st.mag_n);
    (st.mag_sum_B, st.mag_n) = (Vector3::zeros(), 0);
    Some(FusionMsg::Magnetometer { mag_B: mean_B })
}

/// The receive task: every message from the link, until `stop`.
pub(super) fn spawn_receiver(cfg: &Config, link: Arc<Link>, mut r: Receive) -> JoinHandle<()> {
    let mut st = RxState {
        reasm: BTreeMap::new(),
        rtcm_from_mavlink: cfg.gnss.source != GnssSource::Off,
        vehicle: cfg.mavlink.system_id as u32,
        autopilot: Source {
            system: cfg.mavlink.system_id as u32,
            component: cfg.mavlink.autopilot_component_id,
        },
        next_mag_us: 0,
        mag_sum_B: Vector3::zeros(),
        mag_n: 0,
        imu_choice: cfg.mavlink.imu_message,
        kind: None,
        last_highres: Instant::now(),
        last_highres_flowing: Instant::now(),
        highres_since: None,
        last_imu: None,
        scaled_imu_clock: BootMsClock::default(),
        local_position_clock: BootMsClock::default(),
        pressure_clock: BootMsClock::default(),
        system_time_clock: BootMsClock::default(),
        warn: WarnLimit::default(),
    };
    tokio::spawn(async move {
        loop {
            let got = tokio::select! {
                got = link.recv() => got,
                _ = r.stop.changed() => return,
            };
            let (src, msg, gap) = match got {
                Ok(mav::Received::Message { src, msg, lost }) => (src, msg, lost),
                Ok(mav::Received::Ignored(why)) => {
                    r.counters.add(why, 1);
                    continue;
                }
                Ok(mav::Received::Reconnected) => {
                    r.counters.add(Counter::MavlinkReconnected, 1);
                    tracing::warn!("MAVLink link opened again");
                    continue;
                }
                Ok(mav::Received::PeerLearned(addr)) => {
                    r.counters.add(Counter::MavlinkAutopilotAddressLearned, 1);
                    tracing::info!(%addr, "autopilot's address learned from its HEARTBEAT");
                    continue;
                }
                Err(mav::LinkError::Io(e)) => {
                    r.counters.add(Counter::MavlinkIoError, 1);
                    tracing::warn!(error = %e, "MAVLink link error");
                    tokio::time::sleep(Duration::from_millis(200)).await;
                    continue;
                }
                Err(mav::LinkError::Parse(e)) => {
                    r.counters.add(Counter::MavlinkUndecodable, 1);
                    if st.warn.allow() {
                        tracing::warn!(reason = "mavlink_undecodable", "{e}");
                    }
                    continue;
                }
                Err(mav::LinkError::Rejected(why)) => {
                    r.counters.add(why, 1);
                    if st.warn.allow() {
                        tracing::warn!(reason = %why, "MAVLink message rejected");
                    }
                    continue;
                }
            };
            if gap > 0 {
                r.counters.add(Counter::MavlinkFramesLostOrCorrupt, gap as u64);
                tracing::warn!(
                    frames = gap,
                    reason = "mavlink_frames_lost_or_corrupt",
                    "sequence gap: frames lost or dropped as corrupt (bad CRC, unknown id)"
                );
            }
            r.counters.add(Counter::MavlinkMessages, 1);
            if src != st.autopilot {
                if let Some(why) = foreign_rejection(&msg) {
                    // Sensor and time messages from anyone but the autopilot
                    // are never acted on.
                    r.counters.add(why, 1);
                    tracing::warn!(
                        reason = %why,
                        system = src.system,
                        component = src.component,
                        "MAVLink message rejected"
                    );
                    continue;
                }
            }
            if let Some(m) = magnetometer(&msg, &mut st) {
                if r.fusion_tx.try_send(m).is_err() {
                    r.counters.add(Counter::FusionQueueFull, 1);
                }
            }
            if let Some(m) = to_fusion(msg, src, &mut st, &r) {
                if r.fusion_tx.try_send(m).is_err() {
                    r.counters.add(Counter::FusionQueueFull, 1);
                }
            }
        }
    })
}

/// The counter of a link rejection (static names: a flood of rejected
/// frames allocates nothing).
/// At most `WARN_PER_S` rejection warnings a second in the journal (a flood
/// is counted whole, but not written out line by line); how many were held
/// back is said with the next one let through.
#[derive(Default)]
struct WarnLimit {
    window: Option<Instant>,
    in_window: u32,
    held_back: u64,
}

const WARN_PER_S: u32 = 10;

impl WarnLimit {
    fn allow(&mut self) -> bool {
        let now = Instant::now();
        if self
            .window
            .is_none_or(|w| now.duration_since(w) >= Duration::from_secs(1))
        {
            if self.held_back > 0 {
                tracing::warn!(
                    held_back = self.held_back,
                    "MAVLink rejections not written out (all counted)"
                );
            }
            self.window = Some(now);
            self.in_window = 0;
            self.held_back = 0;
        }
        self.in_window += 1;
        if self.in_window > WARN_PER_S {
            self.held_back += 1;
            false
        } else {
            true
        }
    }
}

/// Why a message from someone other than the autopilot is not taken: the
/// sensor and time messages only the autopilot may send (`None`: anyone may
/// send it, such as a ground station's RTCM corrections or HEARTBEAT).
fn foreign_rejection(msg: &Inbound) -> Option<Counter> {
    Some(match msg {
        Inbound::Imu { .. } => Counter::MavlinkRejectedForeignImu,
        Inbound::Attitude { .. } => Counter::MavlinkRejectedForeignAttitude,
        Inbound::LocalPosition { .. } => Counter::MavlinkRejectedForeignLocalPosition,
        Inbound::Pressure { .. } => Counter::MavlinkRejectedForeignPressure,
        Inbound::GpsAccuracy { .. } => Counter::MavlinkRejectedForeignGps,
        Inbound::SystemTime { .. } => Counter::MavlinkRejectedForeignSystemTime,
        Inbound::Timesync { .. } => Counter::MavlinkRejectedForeignTimesync,
        Inbound::GpsGlobalOrigin { .. } => Counter::MavlinkRejectedForeignOrigin,
        Inbound::Heartbeat { .. } => Counter::MavlinkHeartbeatOther,
        Inbound::AutopilotText { .. } => Counter::MavlinkStatusTextOther,
        Inbound::LandedState { .. } => Counter::MavlinkRejectedForeignLandedState,
        Inbound::SimState(_) => Counter::MavlinkRejectedForeignSimState,
        Inbound::EstimatorStatus(_) => Counter::MavlinkRejectedForeignEstimatorStatus,
        // Another component's parameter list (a gimbal's, downloaded by a
        // ground station) is not ours: only one of our names is rejected.
        Inbound::ParamValue(p) if !super::nav_params::is_asked(&p.name) => return None,
        Inbound::ParamValue(_) => Counter::MavlinkRejectedForeignParam,
        Inbound::RtcmFragment { .. } | Inbound::Other(_) => return None,
    })
}

/// How long `auto` waits for `HIGHRES_IMU` from an autopilot other than PX4
/// before it takes another IMU message that does come: well inside the
/// 2 s gap that restarts the filter (`MAX_IMU_GAP_S`), so the other
/// message fills the gap instead.
const HIGHRES_FALLBACK_AFTER: Duration = Duration::from_millis(500);

/// How long `HIGHRES_IMU` must flow again before `auto` goes back to it.
const HIGHRES_STEADY_FOR: Duration = Duration::from_secs(3);

/// The longest interval between two `HIGHRES_IMU` of a stream that flows
/// (10 Hz, a fifth of the slowest rate an autopilot streams it at): any
/// longer and it is a trickle, no IMU for the filter.
const HIGHRES_MAX_INTERVAL: Duration = Duration::from_millis(100);

/// Whether an IMU sample that came in `kind` is taken: the message taken
/// (`Receive::imu_message`) is, another is not. With `auto` beside an
/// autopilot other than PX4, `HIGHRES_IMU` is taken while it flows, another
/// IMU message once it has not flowed (two within [`HIGHRES_MAX_INTERVAL`])
/// for [`HIGHRES_FALLBACK_AFTER`], and `HIGHRES_IMU` again once it has
/// flowed for [`HIGHRES_STEADY_FOR`] (each switch logged and counted).
fn take_imu(kind: ImuMessage, st: &mut RxState, r: &Receive) -> bool {
    let now = Instant::now();
    if kind == ImuMessage::Highres {
        if now.duration_since(st.last_highres) > HIGHRES_MAX_INTERVAL {
            st.highres_since = None;
        } else {
            st.last_highres_flowing = now;
            st.highres_since.get_or_insert(st.last_highres);
        }
        st.last_highres = now;
    }
    let taken = ImuMessage::from_u8(r.imu_message.load(Ordering::Relaxed));
    if kind == taken {
        return true;
    }
    let auto_not_px4 = st.imu_choice == ImuMessageChoice::Auto && st.kind.is_some_and(|k| k != AutopilotKind::Px4);
    let switch = auto_not_px4
        && if kind == ImuMessage::Highres {
            st.highres_since
                .is_some_and(|since| now.duration_since(since) >= HIGHRES_STEADY_FOR)
        } else {
            taken == ImuMessage::Highres && now.duration_since(st.last_highres_flowing) > HIGHRES_FALLBACK_AFTER
        };
    if switch {
        r.imu_message.store(kind.to_u8(), Ordering::Relaxed);
        r.counters.add(Counter::ImuMessageSwitched, 1);
        tracing::warn!(
            from = ?taken,
            to = ?kind,
            "IMU samples now taken from this message (mavlink.imu_message = \"auto\": HIGHRES_IMU when it comes)"
        );
    }
    switch
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
            ..
        } => {
            counters.add(kind.counter(), 1);
            // SCALED_IMU's time is a u32 of milliseconds (decoded as µs).
            let t_us = if kind == ImuMessage::Scaled {
                st.scaled_imu_clock.unwrap((t_us / 1000) as u32) * 1000
            } else {
                t_us
            };
            // One IMU message is taken: the same samples in two messages
            // would come twice, and PX4's HIGHRES_IMU carries EKF2's bias
            // estimates (ImuMessage::auto_for).
            if !take_imu(kind, st, r) {
                counters.add(Counter::ImuMessageIgnored, 1);
                return None;
            }
            // The same sample sent again is no new measurement, and no
            // time going back either.
            let sample = (t_us, accel_mps2, gyro_radps);
            if st.last_imu == Some(sample) {
                counters.add(Counter::ImuDuplicate, 1);
                return None;
            }
            // Another sample at the same time: one of the two is wrong,
            // and the first has been fused. Refused as what it is, not as
            // a time going back.
            if st.last_imu.is_some_and(|(t_last_us, ..)| t_last_us == t_us) {
                counters.add(Counter::ImuConflictingDuplicate, 1);
                if st.warn.allow() {
                    tracing::warn!(
                        reason = "imu_conflicting_duplicate",
                        t_us,
                        "IMU sample rejected: another sample had this time with other values"
                    );
                }
                return None;
            }
            st.last_imu = Some(sample);
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
            counters.add(Counter::Attitude, 1);
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
            counters.add(Counter::LocalPosition, 1);
            Some(FusionMsg::LocalPosition {
                t_s: st.local_position_clock.unwrap(t_boot_ms) as f64 * 1e-3,
                p_ned_m,
                v_ned_mps,
            })
        }
        Inbound::Pressure {
            t_boot_ms,
            p_abs_pa,
            temperature_c,
        } => {
            counters.add(Counter::Pressure, 1);
            Some(FusionMsg::Pressure(crate::io::mcap_log::input::PressureRecord {
                t_s: st.pressure_clock.unwrap(t_boot_ms) as f64 * 1e-3,
                p_abs_pa,
                temperature_c,
            }))
        }
        Inbound::GpsAccuracy { h_acc_m, v_acc_m } => {
            counters.add(Counter::GpsAccuracy, 1);
            Some(FusionMsg::GpsAccuracy { h_acc_m, v_acc_m })
        }
        Inbound::SimState(truth) => {
            counters.add(Counter::SimState, 1);
            Some(FusionMsg::SimState(truth))
        }
        Inbound::EstimatorStatus(s) => {
            counters.add(Counter::EstimatorStatus, 1);
            Some(FusionMsg::EstimatorStatus(s))
        }
        // Only the parameters we ask for go to the fusion loop and the log:
        // a ground station downloading all of them (a thousand and more,
        // each broadcast) would otherwise fill both.
        Inbound::ParamValue(p) if super::nav_params::is_asked(&p.name) => Some(FusionMsg::AutopilotParam(p)),
        Inbound::ParamValue(_) => None,
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
        Inbound::Heartbeat { armed, kind, mode } => {
            counters.add(Counter::HeartbeatIn, 1);
            // The message taken follows the autopilot's kind, once it is
            // known (or changes): a fallback taken since is kept.
            if st.kind != Some(kind) {
                st.kind = Some(kind);
                let imu = st.imu_choice.resolve(Some(kind));
                r.imu_message.store(imu.to_u8(), Ordering::Relaxed);
                tracing::info!(
                    autopilot = ?kind,
                    message = ?imu,
                    "IMU samples taken from this message alone (mavlink.imu_message)"
                );
            }
            Some(FusionMsg::VehicleState {
                armed: Some(armed),
                on_ground: None,
                kind: Some(kind),
                mode: Some(mode),
            })
        }
        Inbound::AutopilotText { severity, text } => {
            counters.add(Counter::StatusTextIn, 1);
            Some(FusionMsg::AutopilotText { severity, text })
        }
        Inbound::LandedState { on_ground } => {
            counters.add(Counter::ExtendedSysState, 1);
            Some(FusionMsg::VehicleState {
                armed: None,
                on_ground,
                kind: None,
                mode: None,
            })
        }
        Inbound::SystemTime { unix_us, boot_ms } => {
            counters.add(Counter::SystemTime, 1);
            // Unix time 0: the autopilot does not know the time yet (no
            // GPS); its boot time alone maps nothing.
            if unix_us == 0 {
                counters.add(Counter::SystemTimeUnset, 1);
                return None;
            }
            Some(FusionMsg::SystemTime {
                unix_us,
                boot_ms: st.system_time_clock.unwrap(boot_ms),
            })
        }
        Inbound::GpsGlobalOrigin {
            lat_deg,
            lon_deg,
            alt_m,
        } => {
            counters.add(Counter::GpsGlobalOrigin, 1);
            Some(FusionMsg::Origin {
                lat_deg,
                lon_deg,
                alt_m,
            })
        }
        Inbound::Other(_) => None,
    }
}

/// TIMESYNC, both ways (MAVLink's time synchronisation protocol v2).
///
/// - Our request came back (`tc1` ≠ 0): offset = tc1 − the midpoint of our
///   clock around the round trip.
/// - The autopilot asks (`tc1` = 0): we answer with `tc1` = our time in the
///   clock our outputs are stamped in, the autopilot's boot clock as our own
///   requests measured it. PX4 maps the stamps of external vision through the
///   offset it learns from these replies (`sync_stamp`), so it learns ≈ 0 and
///   leaves our stamps as they are. Until our own offset is known there is
///   no answer (`timesync_request_unanswered`): a reply in another clock
///   would teach it an offset that moves every estimate.
fn on_timesync(tc1_ns: i64, ts1_ns: i64, r: &Receive) {
    let now_ns = r.start.elapsed().as_nanos() as i64;
    if tc1_ns != 0 {
        let rtt = now_ns - ts1_ns;
        if (0..1_000_000_000).contains(&rtt) {
            let offset_us = (tc1_ns - (ts1_ns + now_ns) / 2) / 1000;
            r.mono_offset_us.store(offset_us, Ordering::Relaxed);
            r.counters.add(Counter::Timesync, 1);
        }
        return;
    }
    r.counters.add(Counter::TimesyncRequestIn, 1);
    let offset_us = r.mono_offset_us.load(Ordering::Relaxed);
    if offset_us == i64::MIN {
        r.counters.add(Counter::TimesyncRequestUnanswered, 1);
        return;
    }
    let reply = Outbound::TimesyncReply {
        tc1_ns: now_ns.saturating_add(offset_us.saturating_mul(1000)),
        ts1_ns,
    };
    if r.out_tx.try_send(reply).is_ok() {
        r.counters.add(Counter::TimesyncReply, 1);
    } else {
        r.counters.add(Counter::OutputQueueFull, 1);
    }
}

/// Reassembles `GPS_RTCM_DATA` fragments (MAVLink spec), one reassembler
/// per sender, and forwards each whole RTCM3 message with its stream (the
/// station id inside tells rover from base further on).
fn on_rtcm_fragment(flags: u8, data: &[u8], src: Source, st: &mut RxState, r: &Receive) {
    let counters = &r.counters;
    if !st.reasm.contains_key(&src) && st.reasm.len() >= MAX_RTCM_SOURCES {
        counters.add(Counter::RtcmSourcesFull, 1);
        return;
    }
    let mut got = st.reasm.entry(src).or_default().push(flags, data);
    loop {
        match got {
            Reassembled::Message(m) => {
                counters.add(Counter::RtcmMessages, 1);
                counters.add(Counter::RtcmBytes, m.len() as u64);
                // Every stream goes on, told apart: only the vehicle's own
                // may hold the rover's observations (by their station id).
                let stream = if src.system == st.vehicle {
                    RtcmStream::LinkVehicle
                } else {
                    counters.add(Counter::RtcmOtherSource, 1);
                    RtcmStream::LinkOther
                };
                if r.fusion_tx.try_send(FusionMsg::Rtcm { bytes: m, stream }).is_err() {
                    counters.add(Counter::FusionQueueFull, 1);
                }
                break;
            }
            Reassembled::Pending => break,
            Reassembled::Rejected(why) => {
                counters.add(why, 1);
                tracing::warn!(reason = %why, "RTCM fragment rejected");
                break;
            }
            Reassembled::Dropped { reason, then } => {
                counters.add(reason, 1);
                tracing::warn!(reason = %reason, "RTCM sequence dropped: a fragment is missing");
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
                Ok(true) => {
                    if m.is_estimate() {
                        counters.add(Counter::EstimatesSent, 1);
                    }
                }
                Ok(false) => counters.add(Counter::MavlinkSendNoAutopilot, 1),
                Err(e) => {
                    counters.add(Counter::MavlinkSendError, 1);
                    tracing::debug!(error = %e, "send failed");
                }
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_boot_ms_runs_on_across_its_wrap() {
        let turn = 1u64 << 32;
        let mut c = BootMsClock::default();
        let near = u32::MAX - 15;
        assert_eq!(c.unwrap(near), u64::from(near));
        assert_eq!(c.unwrap(near + 10), u64::from(near) + 10);
        // Past 2³² − 1 ms: on, not back to 4 ms.
        assert_eq!(c.unwrap(4), turn + 4);
        // One from before the wrap, late: where it was, not 49.7 days on.
        assert_eq!(c.unwrap(near + 12), u64::from(near) + 12);
        assert_eq!(c.unwrap(24), turn + 24);
        // A reboot after the wrap (its first stamps over a minute from the
        // wrap's): back on the first turn, for the time guard to judge, and
        // the rebooted clock stays there. (One whose stamps land within a
        // minute of the wrap's is read as the wrap's: no reference tells.)
        assert_eq!(c.unwrap(300_000), 300_000);
        assert_eq!(c.unwrap(300_020), 300_020);
        assert_eq!(c.unwrap(3_600_000), 3_600_000);
        // A reboot far from the wrap stays a step back, and so does a step
        // back within one turn.
        let mut c = BootMsClock::default();
        assert_eq!(c.unwrap(3_600_000), 3_600_000);
        assert_eq!(c.unwrap(1_000), 1_000);
        assert_eq!(c.unwrap(900), 900);
    }

    /// One stray stamp near the top of the u32 (a firmware's "unknown", or
    /// a forged packet) is passed on as it came and moves nothing: the next
    /// genuine sample is on the first turn still.
    #[test]
    fn one_stray_stamp_near_the_wrap_moves_nothing() {
        let mut c = BootMsClock::default();
        assert_eq!(c.unwrap(10_000), 10_000);
        assert_eq!(c.unwrap(u32::MAX), u64::from(u32::MAX));
        assert_eq!(c.unwrap(10_020), 10_020);
        assert_eq!(c.unwrap(u32::MAX - 5), u64::from(u32::MAX - 5));
        assert_eq!(c.unwrap(10_040), 10_040);
        // And a stray small stamp just after a real wrap is not a second
        // wrap.
        let mut c = BootMsClock::default();
        c.unwrap(u32::MAX - 20);
        assert_eq!(c.unwrap(0), 1 << 32);
        assert_eq!(c.unwrap(3), (1 << 32) + 3);
        assert_eq!(c.unwrap(u32::MAX - 2_000_000), u64::from(u32::MAX - 2_000_000));
        assert_eq!(c.unwrap(23), (1 << 32) + 23);
    }

    #[test]
    fn an_open_unsigned_listener_is_recognised() {
        let mut cfg = Config::default();
        for (address, open) in [
            ("udpin:127.0.0.1:14550", false),
            ("udpin:localhost:14550", false),
            ("udpin:[::1]:14550", false),
            ("udpin:0.0.0.0:14550", true),
            ("tcpin:192.168.1.5:5760", true),
            ("udpout:10.0.0.1:14550", false),
            ("serial:/dev/ttyAMA0:921600", false),
        ] {
            cfg.mavlink.address = address.into();
            assert_eq!(open_network_unsigned(&cfg), open, "{address}");
        }
        cfg.mavlink.address = "udpin:0.0.0.0:14550".into();
        cfg.mavlink.signing_key_file = "/etc/cmsckf/key".into();
        assert!(!open_network_unsigned(&cfg));
    }

    fn imu_with_field(kind: ImuMessage, t_us: u64, mag: [f64; 3]) -> Inbound {
        Inbound::Imu {
            t_us,
            accel_mps2: Vector3::new(0.0, 0.0, -9.81),
            gyro_radps: Vector3::zeros(),
            kind,
            mag_B: Some(Vector3::from(mag)),
        }
    }

    /// The first yaw's field is HIGHRES_IMU's, calibrated, while it comes;
    /// PX4's SCALED_IMU carries the raw sensor's. Without HIGHRES_IMU for
    /// 2 s (ArduPilot on a 1 MB board), the field of what does come.
    #[test]
    fn the_field_is_highres_imus_while_it_comes() {
        let mut st = RxState {
            reasm: BTreeMap::new(),
            rtcm_from_mavlink: false,
            vehicle: 1,
            autopilot: Source {
                system: 1,
                component: 1,
            },
            next_mag_us: 0,
            mag_sum_B: Vector3::zeros(),
            mag_n: 0,
            imu_choice: ImuMessageChoice::Auto,
            kind: Some(AutopilotKind::Px4),
            last_highres: Instant::now(),
            last_highres_flowing: Instant::now(),
            highres_since: None,
            last_imu: None,
            scaled_imu_clock: BootMsClock::default(),
            local_position_clock: BootMsClock::default(),
            pressure_clock: BootMsClock::default(),
            system_time_clock: BootMsClock::default(),
            warn: WarnLimit::default(),
        };
        let field = |m: Option<FusionMsg>| match m {
            Some(FusionMsg::Magnetometer { mag_B }) => Some(mag_B.x),
            _ => None,
        };
        let raw = imu_with_field(ImuMessage::Scaled, 1_000_000, [-1.0, 0.0, 0.0]);
        assert_eq!(field(magnetometer(&raw, &mut st)), None);
        let calibrated = imu_with_field(ImuMessage::Highres, 1_000_000, [1.0, 0.0, 0.0]);
        assert_eq!(field(magnetometer(&calibrated, &mut st)), Some(1.0));
        // Within a period the readings are summed, never dropped: the next
        // one passed on is their mean direction (any length: a direction).
        for (t_us, m) in [(1_020_000, [0.0, 2.0, 0.0]), (1_040_000, [3.0, 0.0, 0.0])] {
            assert_eq!(
                field(magnetometer(&imu_with_field(ImuMessage::Highres, t_us, m), &mut st)),
                None
            );
        }
        let mean = magnetometer(
            &imu_with_field(ImuMessage::Highres, 1_100_000, [1.0, 0.0, 0.0]),
            &mut st,
        );
        let Some(FusionMsg::Magnetometer { mag_B }) = mean else {
            panic!("a period's mean is passed on");
        };
        assert!(
            (mag_B - Vector3::new(2.0 / 3.0, 1.0 / 3.0, 0.0)).norm() < 1e-12,
            "{mag_B}"
        );
        // No HIGHRES_IMU for longer than the fallback's wait.
        st.last_highres = Instant::now() - HIGHRES_FALLBACK_AFTER - Duration::from_millis(10);
        let raw = imu_with_field(ImuMessage::Raw, 2_000_000, [-1.0, 0.0, 0.0]);
        assert_eq!(field(magnetometer(&raw, &mut st)), Some(-1.0));
    }
}
