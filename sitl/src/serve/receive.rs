//! The receiving side of the MAVLink link: a task that answers the daemon's
//! commands and time sync, and gathers its estimates, heartbeats and status
//! texts for the scoring.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use mavlink::dialects::ardupilotmega as apm;
use mavlink::{AsyncMavConnection, MavHeader};
use nalgebra::Vector3;
use tokio::sync::watch;
use tokio::task::JoinHandle;

use super::clock::boot_ns;
use super::fault::{Active, Fault, FaultKind};
use super::{Link, HEADER};

/// One estimate received from the daemon: a `VISION_POSITION_ESTIMATE` or
/// an `ODOMETRY`, whichever it sends (`output.message`): both carry the
/// position in our NED frame (ODOMETRY's `MAV_FRAME_LOCAL_FRD` is the
/// daemon's NED, as it sends it), the covariance of `[x y z roll pitch yaw]`
/// as an upper triangle, and `reset_counter`.
#[derive(Clone, Debug)]
pub(super) struct Received {
    pub(super) wall: Instant,
    pub(super) t_us: u64,
    /// Flight time of `t_us` (see [`super::clock::flight_times`]).
    pub(super) t_s: f64,
    pub(super) p: Vector3<f64>,
    pub(super) cov: [f32; 21],
    pub(super) reset_counter: u8,
    /// `ODOMETRY.quality` (VISION_POSITION_ESTIMATE has none).
    pub(super) quality: Option<i8>,
}

impl Received {
    /// The position's 1σ per axis (m) as ArduPilot reduces the pose
    /// covariance (GCS_Common.cpp, before PR #32084; measured on its SITL):
    /// `cbrt(c₀² + c₆² + c₁₁²)` from the diagonal of the upper-triangular
    /// layout (x 0, y 6, z 11), the same for every axis.
    pub(super) fn ardupilot_position_sigma_m(&self) -> f64 {
        ((self.cov[0] as f64).powi(2) + (self.cov[6] as f64).powi(2) + (self.cov[11] as f64).powi(2)).cbrt()
    }
}

/// One HEARTBEAT from the daemon.
///
/// Its wall-clock arrival alone does not say which part of the flight the
/// daemon was in: on a loaded machine the daemon may run a few hundred
/// milliseconds behind the stream, seconds of flight at a 10× speed-up. The
/// estimates that came before it do: the last one is the daemon's own clock.
#[derive(Clone, Copy, Debug)]
pub(super) struct Heartbeat {
    pub(super) state: apm::MavState,
    /// Flight time by the wall clock at arrival.
    pub(super) t_arrival_s: f64,
    /// Estimates received before it (an index into the received estimates).
    pub(super) estimates_before: usize,
}

/// What the daemon sent, shared with the receiving task.
#[derive(Clone, Default)]
pub(super) struct Inbox {
    /// Estimates (VISION_POSITION_ESTIMATE or ODOMETRY), in arrival order.
    pub(super) received: Arc<Mutex<Vec<Received>>>,
    /// HEARTBEATs: the state, the flight time of arrival, and how many
    /// estimates had arrived before it (the daemon's own clock: see
    /// [`Heartbeat`]).
    pub(super) heartbeats: Arc<Mutex<Vec<Heartbeat>>>,
    /// STATUSTEXTs, with flight times.
    pub(super) status_texts: Arc<Mutex<Vec<(f64, String)>>>,
    /// Counts per message.
    pub(super) counts: Arc<Mutex<Counts>>,
}

/// How many of each message the daemon sent.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Counts {
    pub(super) vision_position_estimate: usize,
    pub(super) vision_speed_estimate: usize,
    pub(super) odometry: usize,
    /// ODOMETRYs with a `quality` outside −1..=100 or a non-finite
    /// velocity covariance.
    pub(super) odometry_malformed: usize,
    pub(super) set_gps_global_origin: usize,
}

/// Spawns the task that receives until `stop_rx` changes: it answers
/// COMMAND_LONG, TIMESYNC and PARAM_REQUEST_READ, and records the rest in
/// `inbox`. `started` runs the boot clock; flight time is `t_start`'s
/// elapsed time × `speedup`; `faults` may change a parameter's answer.
pub(super) fn spawn_receiver(
    conn: Arc<Link>,
    inbox: Inbox,
    started: Instant,
    t_start: Instant,
    speedup: f64,
    faults: Vec<Fault>,
    mut stop_rx: watch::Receiver<bool>,
) -> JoinHandle<()> {
    let flight_t = move || t_start.elapsed().as_secs_f64() * speedup;
    tokio::spawn(async move {
        loop {
            let r = tokio::select! { r = conn.recv() => r, _ = stop_rx.changed() => return };
            let Ok((h, msg)) = r else {
                tokio::time::sleep(Duration::from_millis(10)).await;
                continue;
            };
            match msg {
                apm::MavMessage::COMMAND_LONG(c) => {
                    let _ = conn.send(&HEADER, &command_ack(&h, &c)).await;
                }
                apm::MavMessage::TIMESYNC(t) if t.tc1 == 0 => {
                    let _ = conn.send(&HEADER, &timesync_reply(&h, &t, started)).await;
                }
                apm::MavMessage::PARAM_REQUEST_READ(r) => {
                    let viso_off = Active::at(&faults, flight_t()).has(FaultKind::VisoOff);
                    if let Some(reply) = param_value(&r, viso_off) {
                        let _ = conn.send(&HEADER, &reply).await;
                    }
                }
                msg => inbox.record(msg, &flight_t),
            }
        }
    })
}

/// Accepts any command.
fn command_ack(h: &MavHeader, c: &apm::COMMAND_LONG_DATA) -> apm::MavMessage {
    apm::MavMessage::COMMAND_ACK(apm::COMMAND_ACK_DATA {
        command: c.command,
        result: apm::MavResult::MAV_RESULT_ACCEPTED,
        target_system: h.system_id as u8,
        target_component: h.component_id,
        ..Default::default()
    })
}

/// ArduPilot's parameters for external navigation as docs/setup-ardupilot.md
/// sets them (`VISO_TYPE` 1: MAVLink; EKF3 with ExternalNav as its first
/// source of horizontal position and yaw, the barometer for height), each
/// `INT8` as ArduPilot sends it (the value cast to the float).
const PARAMS: [(&str, f32); 5] = [
    ("VISO_TYPE", 1.0),
    ("AHRS_EKF_TYPE", 3.0),
    ("EK3_SRC1_POSXY", 6.0),
    ("EK3_SRC1_POSZ", 1.0),
    ("EK3_SRC1_YAW", 6.0),
];

/// The `PARAM_VALUE` answering a read by name (`viso_off`: `VISO_TYPE` 0);
/// none for a parameter it does not hold, as ArduPilot stays silent.
fn param_value(r: &apm::PARAM_REQUEST_READ_DATA, viso_off: bool) -> Option<apm::MavMessage> {
    let name = r.param_id.to_str().ok()?;
    let index = PARAMS.iter().position(|(n, _)| *n == name)?;
    let value = if viso_off && name == "VISO_TYPE" {
        0.0
    } else {
        PARAMS[index].1
    };
    Some(apm::MavMessage::PARAM_VALUE(apm::PARAM_VALUE_DATA {
        param_value: value,
        param_count: PARAMS.len() as u16,
        param_index: index as u16,
        param_id: r.param_id,
        param_type: apm::MavParamType::MAV_PARAM_TYPE_INT8,
    }))
}

/// Answers a TIMESYNC request with the boot clock now.
fn timesync_reply(h: &MavHeader, t: &apm::TIMESYNC_DATA, started: Instant) -> apm::MavMessage {
    apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
        tc1: boot_ns(started),
        ts1: t.ts1,
        target_system: h.system_id as u8,
        target_component: h.component_id,
    })
}

impl Inbox {
    /// Counts a message.
    fn count(&self, f: impl FnOnce(&mut Counts)) {
        if let Ok(mut c) = self.counts.lock() {
            f(&mut c);
        }
    }

    /// Records an estimate.
    fn estimate(&self, t_us: u64, p: Vector3<f64>, cov: [f32; 21], reset_counter: u8, quality: Option<i8>) {
        if let Ok(mut v) = self.received.lock() {
            v.push(Received {
                wall: Instant::now(),
                t_us,
                t_s: f64::NAN,
                p,
                cov,
                reset_counter,
                quality,
            });
        }
    }

    /// Records an estimate (VISION_POSITION_ESTIMATE or ODOMETRY),
    /// heartbeat, status text or origin, and counts each message; ignores
    /// anything else.
    fn record(&self, msg: apm::MavMessage, flight_t: &impl Fn() -> f64) {
        match msg {
            apm::MavMessage::VISION_POSITION_ESTIMATE(d) => {
                self.count(|c| c.vision_position_estimate += 1);
                let p = Vector3::new(d.x as f64, d.y as f64, d.z as f64);
                self.estimate(d.usec, p, d.covariance, d.reset_counter, None);
            }
            apm::MavMessage::ODOMETRY(d) => {
                let malformed =
                    !(-1..=100).contains(&d.quality) || !d.velocity_covariance.iter().all(|c| c.is_finite());
                self.count(|c| {
                    c.odometry += 1;
                    c.odometry_malformed += malformed as usize;
                });
                let p = Vector3::new(d.x as f64, d.y as f64, d.z as f64);
                self.estimate(d.time_usec, p, d.pose_covariance, d.reset_counter, Some(d.quality));
            }
            apm::MavMessage::VISION_SPEED_ESTIMATE(_) => self.count(|c| c.vision_speed_estimate += 1),
            apm::MavMessage::HEARTBEAT(hb) => {
                let estimates_before = self.received.lock().map_or(0, |v| v.len());
                if let Ok(mut v) = self.heartbeats.lock() {
                    v.push(Heartbeat {
                        state: hb.system_status,
                        t_arrival_s: flight_t(),
                        estimates_before,
                    });
                }
            }
            apm::MavMessage::STATUSTEXT(st) => {
                if let Ok(mut v) = self.status_texts.lock() {
                    let text = st
                        .text
                        .to_str()
                        .unwrap_or("(not UTF-8)")
                        .trim_end_matches('\0')
                        .to_string();
                    v.push((flight_t(), text));
                }
            }
            #[allow(deprecated)]
            apm::MavMessage::SET_GPS_GLOBAL_ORIGIN(_) => self.count(|c| c.set_gps_global_origin += 1),
            _ => {}
        }
    }
}
