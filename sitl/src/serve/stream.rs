//! The flight on the wire: one loop that sends every IMU sample, camera
//! frame, GNSS epoch and slow telemetry message in time order, paced by the
//! wall clock, and the state it keeps while doing so. What each kind of
//! message looks like lives in the sibling modules.
//!
//! Camera frames and GNSS epochs go out when a real camera and receiver
//! would deliver them, at their `t_delivered_s`, not at their exposure or
//! epoch: a frame carries its camera-clock stamp `t_s` and arrives 30–60 ms
//! after its exposure, an epoch's RTCM 0.2–0.6 s after its instant (by the
//! default simulator settings). Each stream goes out in delivery order;
//! anything due after the end of the flight is not sent.

use std::sync::Arc;
use std::time::{Duration, Instant};

use mavlink::dialects::ardupilotmega as apm;
use mavlink::AsyncMavConnection;

use super::autopilot::AutopilotEkf;
use super::clock::{boot_us, FlightClock};
use super::fault::{Active, FaultKind};
use super::feature_socket::{feature_line, FeatureSocket};
use super::receive::Inbox;
use super::{Link, ServeOptions, HEADER};
use crate::dataset::Dataset;
use crate::features::CameraFrame;
use crate::gnss::GnssEpoch;
use crate::rng::rng_for;

/// The sending side of a served flight.
pub(super) struct Streamer<'a> {
    pub(super) conn: Arc<Link>,
    pub(super) opts: &'a ServeOptions,
    pub(super) ds: &'a Dataset,
    /// Flight time of the autopilot's reboot, if one is injected.
    pub(super) reboot_s: Option<f64>,
    /// Wall time at which each IMU sample first went out (never for a
    /// NaN-corrupted one).
    pub(super) sent_wall: Vec<Option<Instant>>,
    /// The connection to the daemon's feature socket.
    pub(super) feat: FeatureSocket<'a>,
    /// The rendered camera, when a front-end tracks images instead of the
    /// oracle writing features.
    pub(super) camera: Option<super::camera::CameraServer>,
    /// Next IMU sample to send.
    pub(super) k_imu: usize,
    /// Camera frames and GNSS epochs (indices into the dataset's) in
    /// delivery order, and the next of each to send.
    pub(super) cam_order: Vec<usize>,
    pub(super) k_cam: usize,
    pub(super) gnss_order: Vec<usize>,
    pub(super) k_gnss: usize,
    /// The base station's epochs in delivery order, and the next to send.
    pub(super) base_order: Vec<usize>,
    pub(super) k_base: usize,
    /// The rover receiver's own port, when it is wired to the companion.
    pub(super) receiver_port: Option<super::receiver_port::ReceiverPort>,
    /// Flight time of the next 10 Hz attitude / position.
    pub(super) next_slow: f64,
    /// Flight time of the next 1 Hz heartbeat, system time and origin.
    pub(super) next_1hz: f64,
    /// Sequence number of the next RTCM message (MAVLink fragment flags).
    pub(super) rtcm_seq: u8,
    /// Frames written to the feature socket.
    pub(super) frames_sent: usize,
    /// The autopilot's own EKF, what its attitude and position report.
    pub(super) ekf: AutopilotEkf,
    /// Its barometer (`SCALED_PRESSURE` at 10 Hz).
    pub(super) baro: crate::barometer::Barometer,
    /// What the daemon sent, and how many of its estimates the EKF has seen.
    pub(super) inbox: Inbox,
    pub(super) estimates_seen: usize,
    /// The daemon's stamps back to flight time.
    pub(super) vpe_clock: FlightClock,
}

impl<'a> Streamer<'a> {
    pub(super) fn new(
        conn: Arc<Link>,
        opts: &'a ServeOptions,
        ds: &'a Dataset,
        reboot_s: Option<f64>,
        inbox: Inbox,
        receiver_port: Option<super::receiver_port::ReceiverPort>,
        camera: Option<super::camera::CameraServer>,
    ) -> Self {
        Self {
            camera,
            conn,
            opts,
            ds,
            reboot_s,
            sent_wall: vec![None; ds.imu.len()],
            feat: FeatureSocket::new(&opts.feature_socket),
            k_imu: 0,
            cam_order: delivery_order(ds.frames.iter().map(|f| f.t_delivered_s)),
            k_cam: 0,
            gnss_order: delivery_order(ds.gnss.iter().map(|e| e.t_delivered_s)),
            k_gnss: 0,
            base_order: delivery_order(ds.base_gnss.iter().map(|e| e.t_delivered_s)),
            k_base: 0,
            receiver_port,
            next_slow: 0.0,
            next_1hz: 0.0,
            rtcm_seq: 0,
            frames_sent: 0,
            ekf: AutopilotEkf::new(&ds.cfg.autopilot, rng_for(ds.seed, 7)),
            baro: crate::barometer::Barometer::new(rng_for(ds.seed, 13)),
            inbox,
            estimates_seen: 0,
            vpe_clock: FlightClock::new(reboot_s),
        }
    }

    /// Sends one message to the daemon (errors are the link's problem).
    pub(super) async fn send(&self, m: apm::MavMessage) {
        let _ = self.conn.send(&HEADER, &m).await;
    }

    /// The autopilot's boot clock (µs) at flight time `t`.
    pub(super) fn boot(&self, t: f64) -> u64 {
        boot_us(t, self.reboot_s)
    }

    /// The next camera frame to deliver.
    pub(super) fn next_frame(&self) -> Option<&'a CameraFrame> {
        self.cam_order.get(self.k_cam).map(|&i| &self.ds.frames[i])
    }

    /// The next GNSS epoch to deliver.
    pub(super) fn next_epoch(&self) -> Option<&'a GnssEpoch> {
        self.gnss_order.get(self.k_gnss).map(|&i| &self.ds.gnss[i])
    }

    /// The next base-station epoch to deliver.
    pub(super) fn next_base_epoch(&self) -> Option<&'a GnssEpoch> {
        self.base_order.get(self.k_base).map(|&i| &self.ds.base_gnss[i])
    }

    /// Streams the whole flight, flight time 0 being `t_start` on the wall
    /// clock divided by the speed-up. Frames and epochs go out at their
    /// delivery times. At equal times, GNSS goes first, then the 1 Hz, the
    /// 10 Hz, the IMU and last the camera.
    pub(super) async fn run(&mut self, t_start: Instant) {
        let ds = self.ds;
        loop {
            let t_imu = ds.imu.get(self.k_imu).map_or(f64::INFINITY, |m| m.t_s);
            let t_cam = self.next_frame().map_or(f64::INFINITY, |f| f.t_delivered_s);
            let t_gnss = self.next_epoch().map_or(f64::INFINITY, |e| e.t_delivered_s.max(0.0));
            let t_base = self
                .next_base_epoch()
                .map_or(f64::INFINITY, |e| e.t_delivered_s.max(0.0));
            let t = t_imu
                .min(t_cam)
                .min(self.next_slow)
                .min(self.next_1hz)
                .min(t_gnss)
                .min(t_base);
            if !t.is_finite() || t > ds.duration_s + 1e-9 {
                break;
            }
            let target = t_start + Duration::from_secs_f64(t.max(0.0) / self.opts.speedup);
            tokio::time::sleep_until(target.into()).await;
            let active = Active::at(&self.opts.faults, t);
            if t == t_gnss {
                self.send_gnss_epoch(&active).await;
            } else if t == t_base {
                self.send_base_epoch(&active).await;
            } else if active.link_down() && (t == t_imu || t == self.next_1hz || t == self.next_slow) {
                // Nothing from the autopilot gets through (the camera, on its
                // own socket, still does); its EKF runs on, unheard.
                self.skip(t, t_imu, &active);
            } else if t == self.next_1hz {
                self.send_1hz(t, &active).await;
            } else if t == self.next_slow {
                self.send_10hz(t, &active).await;
            } else if t == t_imu {
                self.send_imu(&active).await;
            } else {
                self.send_frame(&active).await;
            }
        }
    }

    /// Drops the autopilot's message due at `t` while the link is down (its
    /// EKF still steps at the 10 Hz ticks).
    fn skip(&mut self, t: f64, t_imu: f64, active: &Active<'_>) {
        if t == t_imu {
            self.k_imu += 1;
        } else if t == self.next_1hz {
            self.next_1hz += 1.0;
        } else {
            self.next_slow += 0.1;
            self.step_ekf(t, active);
        }
    }
}

/// Indices of `times` in increasing time order (ties in index order).
pub(super) fn delivery_order(times: impl Iterator<Item = f64>) -> Vec<usize> {
    let mut v: Vec<(f64, usize)> = times.enumerate().map(|(i, t)| (t, i)).collect();
    v.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    v.into_iter().map(|(_, i)| i).collect()
}

impl Streamer<'_> {
    /// Delivers the next camera frame, stamped with its camera-clock time
    /// `t_s`, unless the front end is down or the camera out.
    pub(super) async fn send_frame(&mut self, active: &Active<'_>) {
        let Some(f) = self.next_frame() else { return };
        self.k_cam += 1;
        if let Some(cam) = self.camera.as_mut() {
            // The camera's own faults: no frames in an outage; a front-end
            // crash is its connection dropped.
            if active.has(FaultKind::FrontendRestart) {
                cam.disconnect();
            }
            let deliver = !active.has(FaultKind::CameraOutage) && !active.has(FaultKind::FrontendRestart);
            let t_us = boot_us(f.t_s, self.reboot_s);
            if cam.send_next(t_us, deliver).await {
                self.frames_sent += 1;
            }
            return;
        }
        if active.has(FaultKind::FrontendRestart) {
            // The front end has crashed: no connection, no frames.
            self.feat.disconnect();
            return;
        }
        if active.has(FaultKind::CameraOutage) {
            return;
        }
        let line = feature_line(self.boot(f.t_s), f);
        if self.feat.write(line.repeat(active.copies()).as_bytes()).await {
            self.frames_sent += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn delivery_order_sorts_by_time_then_index() {
        assert_eq!(delivery_order([0.3, 0.1, 0.2, 0.1].into_iter()), vec![1, 3, 2, 0]);
        assert!(delivery_order(std::iter::empty()).is_empty());
    }
}
