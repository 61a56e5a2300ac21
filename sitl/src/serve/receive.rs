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
use super::{Link, HEADER};

/// One estimate received from the daemon.
#[derive(Clone, Debug)]
pub(super) struct Received {
    pub(super) wall: Instant,
    pub(super) t_us: u64,
    /// Flight time of `t_us` (see [`super::clock::flight_times`]).
    pub(super) t_s: f64,
    pub(super) p: Vector3<f64>,
    pub(super) cov: [f32; 21],
    pub(super) reset_counter: u8,
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
    /// VISION_POSITION_ESTIMATEs, in arrival order.
    pub(super) received: Arc<Mutex<Vec<Received>>>,
    /// HEARTBEATs: the state, the flight time of arrival, and how many
    /// estimates had arrived before it (the daemon's own clock: see
    /// [`Heartbeat`]).
    pub(super) heartbeats: Arc<Mutex<Vec<Heartbeat>>>,
    /// STATUSTEXTs, with flight times.
    pub(super) status_texts: Arc<Mutex<Vec<(f64, String)>>>,
    /// Counts of (ODOMETRY, SET_GPS_GLOBAL_ORIGIN).
    pub(super) extras: Arc<Mutex<(usize, usize)>>,
}

/// Spawns the task that receives until `stop_rx` changes: it answers
/// COMMAND_LONG and TIMESYNC, and records the rest in `inbox`. `started`
/// runs the boot clock; flight time is `t_start`'s elapsed time × `speedup`.
pub(super) fn spawn_receiver(
    conn: Arc<Link>,
    inbox: Inbox,
    started: Instant,
    t_start: Instant,
    speedup: f64,
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
    /// Records an estimate, heartbeat, status text, odometry or origin;
    /// ignores anything else.
    fn record(&self, msg: apm::MavMessage, flight_t: &impl Fn() -> f64) {
        match msg {
            apm::MavMessage::VISION_POSITION_ESTIMATE(d) => {
                if let Ok(mut v) = self.received.lock() {
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
            apm::MavMessage::ODOMETRY(_) => {
                if let Ok(mut e) = self.extras.lock() {
                    e.0 += 1;
                }
            }
            #[allow(deprecated)]
            apm::MavMessage::SET_GPS_GLOBAL_ORIGIN(_) => {
                if let Ok(mut e) = self.extras.lock() {
                    e.1 += 1;
                }
            }
            _ => {}
        }
    }
}
