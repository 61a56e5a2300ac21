//! What the two autopilot-SITL flights (`tests/ardupilot_sitl.rs`,
//! `tests/px4_sitl.rs`) share: the test's ground station on UDP, the
//! simulator's truth as a smoothed, interpolable track, the synthetic camera
//! that follows it into the daemon's socket, and the error statistics of a
//! flight phase. What differs between the autopilots (how the truth comes,
//! modes, arming, the EKF's acceptance) stays in each test.
#![allow(non_snake_case)]

use std::collections::VecDeque;
use std::fs::File;
use std::io::Write;
use std::net::{SocketAddr, UdpSocket};
use std::os::unix::net::UnixStream;
use std::path::PathBuf;
use std::time::Duration;

use cmsckf::config::Config;
use cmsckf_models::camera::Camera;
use cmsckf_models::geodesy::NedFrame;
use cmsckf_sitl::features::FeatureSim;
use cmsckf_sitl::trajectory::TruthSample;
use mavlink::dialects::ardupilotmega as apm;
use mavlink::{MavHeader, MavlinkVersion};
use nalgebra::{UnitQuaternion, Vector3};
use rand::SeedableRng;

/// The flight's folder (its log, the SITL's files): deleted after the test,
/// unless `CMSCKF_KEEP_TEST_LOGS` is set, when it is kept for `cmsckf
/// review` (its path printed) with the truth beside it in `truth.csv`.
pub struct FlightDir {
    pub path: PathBuf,
    /// With `CMSCKF_KEEP_TEST_LOGS`: autopilot time (s), NED position (m),
    /// attitude quaternion (w, x, y, z), NED velocity (m/s), a line per
    /// truth sample.
    pub truth_csv: Option<File>,
    _temp: Option<tempfile::TempDir>,
}

impl FlightDir {
    pub fn new() -> Self {
        let temp = tempfile::tempdir().unwrap();
        let path = temp.path().to_path_buf();
        let keep = std::env::var_os("CMSCKF_KEEP_TEST_LOGS").is_some();
        let truth_csv = keep.then(|| File::create(path.join("truth.csv")).unwrap());
        let _temp = if keep {
            eprintln!("keeping the flight log in {}", temp.keep().display());
            None
        } else {
            Some(temp)
        };
        Self { path, truth_csv, _temp }
    }

    /// A file of this name beside the log, when the folder is kept.
    pub fn kept_file(&self, name: &str) -> Option<File> {
        self.truth_csv.as_ref()?;
        Some(File::create(self.path.join(name)).unwrap())
    }
}

/// The autopilot's positions, each scored against the truth of its instant
/// once that has come, in the flight phase it was reported in.
pub struct Scoring<P> {
    queue: VecDeque<(f64, Vector3<f64>, P)>,
}

impl<P: Copy> Scoring<P> {
    pub fn new() -> Self {
        Self { queue: VecDeque::new() }
    }

    pub fn push(&mut self, t_s: f64, p_ned_m: Vector3<f64>, phase: P) {
        self.queue.push_back((t_s, p_ned_m, phase));
    }

    /// Each position whose truth has come, with its error (m), to `add`;
    /// those from before the truth began are never scored.
    pub fn score(&mut self, truth: &Truth, mut add: impl FnMut(P, f64)) {
        while let Some(&(t_s, p, phase)) = self.queue.front() {
            if truth.first_t_s().is_none_or(|t0| t_s < t0) {
                self.queue.pop_front();
                continue;
            }
            let Some(p_true) = truth.at(t_s) else { break };
            self.queue.pop_front();
            add(phase, (p - p_true).norm());
        }
    }
}

/// A free loopback UDP port.
pub fn free_udp_port() -> u16 {
    UdpSocket::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// The test's ground station: MAVLink 2 as system 255.
pub struct Gcs {
    sock: UdpSocket,
    /// The autopilot's system id (1 unless told).
    pub target_system: u8,
    /// Where the autopilot spoke from (learnt from its first datagram).
    pub peer: Option<SocketAddr>,
    seq: u8,
    buf: Vec<u8>,
}

impl Gcs {
    pub fn bind(port: u16) -> Self {
        let sock = UdpSocket::bind(("127.0.0.1", port))
            .unwrap_or_else(|e| panic!("the ground station's port 127.0.0.1:{port}: {e}"));
        sock.set_read_timeout(Some(Duration::from_millis(20))).unwrap();
        Self {
            sock,
            target_system: 1,
            peer: None,
            seq: 0,
            buf: vec![0; 65536],
        }
    }

    /// The messages of one datagram (none after 20 ms of quiet).
    pub fn recv(&mut self) -> Vec<(MavHeader, apm::MavMessage)> {
        let Ok((len, from)) = self.sock.recv_from(&mut self.buf) else {
            return Vec::new();
        };
        self.peer = Some(from);
        // Autopilots pack several messages into a datagram; one this
        // dialect does not know must not lose the rest.
        let mut r = mavlink::MavlinkReader::new(&self.buf[..len]);
        let mut out = Vec::new();
        loop {
            match r.read_any_message::<apm::MavMessage>() {
                Ok(m) => out.push(m),
                Err(mavlink::error::MessageReadError::Io(_)) => break,
                Err(_) => continue,
            }
        }
        out
    }

    pub fn send(&mut self, msg: &apm::MavMessage) {
        let Some(peer) = self.peer else { return };
        let h = MavHeader {
            system_id: 255,
            component_id: 190,
            sequence: self.seq,
        };
        self.seq = self.seq.wrapping_add(1);
        let mut frame = Vec::new();
        mavlink::write_versioned_msg(&mut frame, MavlinkVersion::V2, h, msg).unwrap();
        let _ = self.sock.send_to(&frame, peer);
    }

    pub fn command(&mut self, command: apm::MavCmd, p: [f32; 7]) {
        self.send(&apm::MavMessage::COMMAND_LONG(apm::COMMAND_LONG_DATA {
            target_system: self.target_system,
            target_component: 1,
            command,
            param1: p[0],
            param2: p[1],
            param3: p[2],
            param4: p[3],
            param5: p[4],
            param6: p[5],
            param7: p[6],
            confirmation: 0,
        }));
    }

    /// A message stream at `hz` (MAV_CMD_SET_MESSAGE_INTERVAL).
    pub fn stream(&mut self, id: u32, hz: f32) {
        self.command(
            apm::MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
            [id as f32, 1e6 / hz, 0.0, 0.0, 0.0, 0.0, 0.0],
        );
    }

    /// A position target in the autopilot's local NED frame, position only
    /// (velocity, acceleration, yaw and yaw rate ignored).
    pub fn goto(&mut self, p_ned: [f32; 3]) {
        self.send(&apm::MavMessage::SET_POSITION_TARGET_LOCAL_NED(
            apm::SET_POSITION_TARGET_LOCAL_NED_DATA {
                target_system: self.target_system,
                target_component: 1,
                coordinate_frame: apm::MavFrame::MAV_FRAME_LOCAL_NED,
                type_mask: apm::PositionTargetTypemask::from_bits_truncate(0x0DF8),
                x: p_ned[0],
                y: p_ned[1],
                z: p_ned[2],
                ..Default::default()
            },
        ));
    }
}

/// Error statistics of one phase (m).
#[derive(Default, Debug)]
pub struct Errors {
    pub n: usize,
    pub max_m: f64,
    sum_sq: f64,
}

impl Errors {
    pub fn add(&mut self, e: f64) {
        self.n += 1;
        self.max_m = self.max_m.max(e);
        self.sum_sq += e * e;
    }
    pub fn rms_m(&self) -> f64 {
        (self.sum_sq / self.n.max(1) as f64).sqrt()
    }
}

/// The simulator's truth: (autopilot time, NED position) about the start.
pub struct Truth {
    pub frame: NedFrame,
    hist: VecDeque<(f64, Vector3<f64>)>,
    /// The smoothed position, its velocity and time (see [`Truth::push`]).
    last: Option<(f64, Vector3<f64>, Vector3<f64>)>,
}

impl Truth {
    /// Truth in the NED frame at `llh` (degrees, degrees, metres).
    pub fn new(llh: [f64; 3]) -> Self {
        Self {
            frame: NedFrame::from_llh_deg(llh[0], llh[1], llh[2]),
            hist: VecDeque::new(),
            last: None,
        }
    }

    /// Takes one truth sample; returns the position kept.
    ///
    /// Simulators send their position in 1e-7° steps (1.1 cm north, 0.7-0.9
    /// cm east): a camera fed that staircase sees every pose jitter by up
    /// to a centimetre, all its features together, which no real camera
    /// does. Their velocity is finer: integrate it (trapezoid) and pull the
    /// sum towards the quantised position with a 1 s time constant, so the
    /// steps average out and nothing drifts.
    pub fn push(&mut self, t_s: f64, p_quantised: Vector3<f64>, v: Vector3<f64>) -> Vector3<f64> {
        const TAU_S: f64 = 1.0;
        // A second sample paired with the same stamp (or an older one)
        // changes nothing: restarting the smoother there would bring the
        // steps back.
        if let Some((t0, p0, _)) = self.last {
            if t_s <= t0 {
                return p0;
            }
        }
        let p = match self.last {
            Some((t0, p0, v0)) if t_s > t0 && t_s - t0 < 0.5 => {
                let dt_s = t_s - t0;
                let predicted = p0 + (v0 + v) * (0.5 * dt_s);
                predicted + (p_quantised - predicted) * (dt_s / TAU_S)
            }
            _ => p_quantised,
        };
        self.last = Some((t_s, p, v));
        if self.hist.back().is_none_or(|(u, _)| t_s > *u) {
            self.hist.push_back((t_s, p));
        }
        // 20 s at SIH's 250 Hz.
        if self.hist.len() > 5000 {
            self.hist.pop_front();
        }
        p
    }

    /// The first sample's time kept, if any.
    pub fn first_t_s(&self) -> Option<f64> {
        self.hist.front().map(|(t, _)| *t)
    }

    /// The position at `t_s`, interpolated; `None` before the first sample
    /// or after the last.
    pub fn at(&self, t_s: f64) -> Option<Vector3<f64>> {
        interpolate_at(&self.hist, t_s)
    }
}

/// The position at `t_s` in `(t, position)` samples in time order,
/// interpolated; `None` before the first sample or after the last.
pub fn interpolate_at(samples: &VecDeque<(f64, Vector3<f64>)>, t_s: f64) -> Option<Vector3<f64>> {
    let i = samples.partition_point(|(u, _)| *u <= t_s);
    let (t1, p1) = samples.get(i)?;
    let (t0, p0) = samples.get(i.checked_sub(1)?)?;
    let w = if t1 > t0 { (t_s - t0) / (t1 - t0) } else { 0.0 };
    Some(p0 + (p1 - p0) * w)
}

/// When a camera of `rate_hz` takes its next frame from a stream of truth
/// samples: at the first sample a frame's period (less 1 %) after the last
/// frame (with a simulator's 4 ms steps and 30 Hz, one each 36 ms).
struct FrameClock {
    frame_dt_s: f64,
    last_frame_t_s: f64,
}

impl FrameClock {
    fn new(rate_hz: f64) -> Self {
        Self {
            frame_dt_s: 1.0 / rate_hz,
            last_frame_t_s: f64::NEG_INFINITY,
        }
    }

    /// The frame's truth sample, if the pose at `t_s` is one.
    fn due(
        &mut self,
        t_s: f64,
        p_B_in_W: Vector3<f64>,
        v_B_in_W: Vector3<f64>,
        q_W_B: UnitQuaternion<f64>,
    ) -> Option<TruthSample> {
        if t_s - self.last_frame_t_s < self.frame_dt_s * 0.99 {
            return None;
        }
        self.last_frame_t_s = t_s;
        Some(TruthSample {
            t_s,
            p_B_in_W,
            v_B_in_W,
            a_B_in_W: Vector3::zeros(),
            q_W_B,
            w_B: Vector3::zeros(),
        })
    }
}

/// A synthetic camera on the simulator's truth: the daemon's simulated
/// landmarks, seen at the configured rate and pixel noise, written to the
/// daemon's feature socket (reconnecting when it is not there yet).
pub struct TruthCamera {
    sim: FeatureSim,
    rng: rand_chacha::ChaCha8Rng,
    socket_path: String,
    socket: Option<UnixStream>,
    clock: FrameClock,
}

/// The camera's true lens: drawn around the calibration the daemon is
/// given, as a real lens differs from its calibration
/// (`cmsckf_sitl::lens`), from a fixed seed (these flights have none).
fn true_lens(cfg: &Config) -> cmsckf_models::sensors::CameraConfig {
    cmsckf::eval::sim_config_for(cfg)
        .lens
        .draw(&cfg.camera, &mut rand_chacha::ChaCha8Rng::seed_from_u64(12))
}

impl TruthCamera {
    pub fn new(cfg: &Config) -> Self {
        let sim = cmsckf::eval::sim_config_for(cfg);
        let lens = true_lens(cfg);
        Self {
            sim: FeatureSim::new(&sim.features, Camera::from_config(&lens), cfg.camera.pixel_noise_px),
            rng: rand_chacha::ChaCha8Rng::seed_from_u64(7),
            socket_path: cfg.features.socket.clone(),
            socket: None,
            clock: FrameClock::new(cfg.camera.rate_hz),
        }
    }

    /// A frame of the pose at `t_s` (autopilot time), if one is due.
    pub fn see(&mut self, t_s: f64, p_B_in_W: Vector3<f64>, v_B_in_W: Vector3<f64>, q_W_B: UnitQuaternion<f64>) {
        let Some(sample) = self.clock.due(t_s, p_B_in_W, v_B_in_W, q_W_B) else {
            return;
        };
        let frame = self.sim.frame(&sample, &mut self.rng);
        let feats: Vec<String> = frame
            .features
            .iter()
            .map(|f| format!("[{},{:.3},{:.3}]", f.landmark_id, f.u_px, f.v_px))
            .collect();
        let line = super::autopilot::line(t_s, &feats.join(","));
        if self.socket.is_none() {
            self.socket = UnixStream::connect(&self.socket_path).ok();
        }
        if let Some(sock) = self.socket.as_mut() {
            if sock.write_all(line.as_bytes()).is_err() {
                self.socket = None;
            }
        }
    }
}

/// The camera as a drone carries it: the simulator's truth rendered as
/// images of a textured world (`cmsckf_sitl::render`, through the true
/// lens) and tracked by the real front-end (`cmsckf-frontend`'s tracker,
/// each feature with its σ, given the calibration) into the daemon's
/// socket. Rendering and tracking run on a thread of their own, as the
/// front-end is a process of its own on a drone: the test's loop hands it
/// a pose per frame and never waits. When the thread falls behind, it
/// renders the newest pose waiting and skips the older ones, and a pose
/// that finds the queue full is dropped (a camera driver that drops
/// frames); both are counted. A frame is taken at the first truth sample
/// a frame's period (less 1 %) after the last: with SIH's 4 ms steps and
/// a 30 Hz camera, one each 36 ms (28 Hz).
///
/// Each tracked position is also scored against the truth: the world
/// point under the first pixel of its id that lands on a surface (not the
/// sky), projected at each later frame's true pose through the true lens,
/// as `frontend/tests/rendered.rs` scores tracks. This is the tracker's
/// own error: the lens's offset from its calibration, which the daemon's
/// residuals also hold, is not in it. With `scores` given, each goes to
/// that CSV, no header: `t_s,id,age,u_px,v_px,du_px,dv_px,sigma_px,depth_m`.
pub struct RenderedCamera {
    tx: Option<std::sync::mpsc::SyncSender<TruthSample>>,
    worker: Option<std::thread::JoinHandle<anyhow::Result<RenderedReport>>>,
    clock: FrameClock,
    /// Poses not handed over because the thread's queue was full.
    pub queue_full: u64,
}

/// What the rendered camera did over a flight.
#[derive(Debug, Default)]
pub struct RenderedReport {
    pub frames: u64,
    /// Frames whose line could not be written to the daemon.
    pub frames_not_delivered: u64,
    /// Poses skipped because a newer one was waiting.
    pub skipped: u64,
    pub tracks: cmsckf_frontend::tracker::TrackStats,
    /// Tracked positions scored against their world point, and how many
    /// of them erred by more than 3 σ (σ the one the daemon weighs them
    /// with: `pixel_noise_px`, or with `camera.frontend_sigma` the
    /// tracker's with `model_noise_px` added).
    pub scored: u64,
    pub beyond_3_sigma: u64,
    /// Positions reported where their world point cannot be seen (behind
    /// the camera or out of the image): a track that outlived its point,
    /// or a re-identification of the wrong one.
    pub unseen: u64,
    /// Milliseconds spent tracking (the tracker alone) over all frames.
    pub tracking_ms: f64,
    /// Milliseconds spent rendering over all frames.
    pub rendering_ms: f64,
    /// Milliseconds spent scoring the positions against the truth.
    pub scoring_ms: f64,
}

impl RenderedCamera {
    /// A camera over a world built around `path_ne` (the planned route's
    /// horizontal points in the truth's NED frame, m), writing to the
    /// socket `cfg.features.socket` at `cfg.camera.rate_hz`.
    pub fn new(cfg: &Config, path_ne: &[[f64; 2]], world_seed: u64, scores: Option<File>) -> Self {
        use cmsckf_frontend::image::Gray;
        use cmsckf_frontend::output::frame_line_into;
        use cmsckf_frontend::run::{Sink, SocketSink};
        use cmsckf_frontend::tracker::{Tracker, TrackerParams};
        use cmsckf_sitl::render::{RenderConfig, Renderer, World};
        let mut renderer = Renderer::new(
            World::around_path(path_ne, world_seed),
            Camera::from_config(&true_lens(cfg)),
            RenderConfig::default(),
        );
        let calibration = Camera::from_config(&cfg.camera);
        // The σ the daemon weighs each position with, by its own rule.
        let noise = cmsckf::estimator::frontend::Normaliser::new(&cfg.camera).noise;
        let socket = PathBuf::from(&cfg.features.socket);
        let (tx, rx) = std::sync::mpsc::sync_channel::<TruthSample>(8);
        let worker = std::thread::spawn(move || {
            let mut tracker = Tracker::new(TrackerParams::default(), Some(calibration));
            let mut sink = SocketSink::lazy(&socket);
            let mut scores = scores.map(std::io::BufWriter::new);
            let mut report = RenderedReport::default();
            let (mut poses, mut bytes, mut img, mut line) = (Vec::new(), Vec::new(), Gray::new(1, 1), String::new());
            // Each id's world point (the first pixel's).
            let mut points = std::collections::HashMap::<u64, Vector3<f64>>::new();
            while let Ok(mut sample) = rx.recv() {
                while let Ok(newer) = rx.try_recv() {
                    sample = newer;
                    report.skipped += 1;
                }
                let T_W_C = renderer.camera_pose(&sample);
                poses.clear();
                poses.push(T_W_C);
                report.frames += 1;
                let start = std::time::Instant::now();
                renderer.render(&poses, report.frames, &mut bytes);
                report.rendering_ms += start.elapsed().as_secs_f64() * 1e3;
                anyhow::ensure!(
                    img.set_from_u8(renderer.width(), renderer.height(), &bytes),
                    "the rendered image does not fit its size"
                );
                let start = std::time::Instant::now();
                let feats = tracker.process(&img);
                report.tracking_ms += start.elapsed().as_secs_f64() * 1e3;
                let t_us = (sample.t_s * 1e6).round() as u64;
                frame_line_into(&mut line, t_us, 0, feats);
                if !sink.send(line.as_bytes()) {
                    report.frames_not_delivered += 1;
                }
                let start = std::time::Instant::now();
                for f in feats {
                    let uv = [f64::from(f.u_px), f64::from(f.v_px)];
                    let Some(p_in_W) = points.get(&f.id).copied() else {
                        if let Some(hit) = renderer.surface_point(&T_W_C, uv) {
                            points.insert(f.id, hit.p_in_W);
                        }
                        continue;
                    };
                    let Some(q) = renderer.project(&T_W_C, &p_in_W) else {
                        report.unseen += 1;
                        continue;
                    };
                    let (du, dv) = (uv[0] - q[0], uv[1] - q[1]);
                    // As the line carries it: no σ when the tracker has none (0).
                    let sigma = noise.sigma_px(&cmsckf_models::feature_wire::PixelFeature {
                        landmark_id: f.id,
                        u_px: uv[0],
                        v_px: uv[1],
                        sigma_px: (f.sigma_px > 0.0).then_some(f64::from(f.sigma_px)),
                    });
                    report.scored += 1;
                    report.beyond_3_sigma += u64::from(du.hypot(dv) > 3.0 * sigma);
                    if let Some(w) = scores.as_mut() {
                        let depth_m = T_W_C.inverse_transform_point(&p_in_W.into()).z;
                        let written = writeln!(
                            w,
                            "{},{},{},{:.3},{:.3},{:.4},{:.4},{:.4},{:.2}",
                            sample.t_s, f.id, f.age, uv[0], uv[1], du, dv, f.sigma_px, depth_m
                        );
                        if let Err(e) = written {
                            // The scores are for reading afterwards; the
                            // flight goes on without them.
                            eprintln!("tracks.csv: {e}: no more scores written");
                            scores = None;
                        }
                    }
                }
                report.scoring_ms += start.elapsed().as_secs_f64() * 1e3;
            }
            if let Some(mut w) = scores {
                let _ = w.flush();
            }
            let _ = sink.flush();
            report.tracks = tracker.stats;
            Ok(report)
        });
        Self {
            tx: Some(tx),
            worker: Some(worker),
            clock: FrameClock::new(cfg.camera.rate_hz),
            queue_full: 0,
        }
    }

    /// A frame of the pose at `t_s` (autopilot time), if one is due.
    pub fn see(&mut self, t_s: f64, p_B_in_W: Vector3<f64>, v_B_in_W: Vector3<f64>, q_W_B: UnitQuaternion<f64>) {
        let Some(sample) = self.clock.due(t_s, p_B_in_W, v_B_in_W, q_W_B) else {
            return;
        };
        if let Some(tx) = &self.tx {
            match tx.try_send(sample) {
                Ok(()) => {}
                Err(std::sync::mpsc::TrySendError::Full(_)) => self.queue_full += 1,
                // The thread ended: fail now rather than fly blind.
                Err(std::sync::mpsc::TrySendError::Disconnected(_)) => {
                    let why = self.worker.take().map(|w| w.join());
                    panic!("the rendered camera's thread ended mid-flight: {why:?}");
                }
            }
        }
    }

    /// Ends the stream and gives what the front-end did.
    pub fn finish(mut self) -> anyhow::Result<RenderedReport> {
        self.tx = None;
        match self.worker.take() {
            Some(w) => w
                .join()
                .map_err(|_| anyhow::anyhow!("the rendered camera's thread panicked"))?,
            None => anyhow::bail!("the rendered camera already finished"),
        }
    }
}

impl Drop for RenderedCamera {
    fn drop(&mut self) {
        // Closing the queue ends the front-end's loop.
        self.tx = None;
    }
}
