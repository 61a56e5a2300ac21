//! The daemon: tasks, bounded channels and the fusion loop.
//!
//! - the MAVLink receive task turns autopilot messages into [`FusionMsg`]s;
//! - the feature-socket task does the same for camera frames;
//! - the fusion loop runs on its own thread (the estimator is CPU work and
//!   must never stall the I/O tasks), merges IMU and frames in time order,
//!   waits for IMU to cover each frame, and emits the outputs;
//! - the send task writes outputs and the periodic messages to the link.
//!
//! Every channel is bounded; when one is full the newest item is dropped and
//! counted. [`run`] returns when its `shutdown` future completes.

use std::collections::VecDeque;
use std::future::Future;
use std::path::PathBuf;
use std::sync::atomic::{AtomicI64, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector3};
use serde_json::json;
use tokio::sync::{mpsc, watch};

use crate::io::mcap_log::Topic;

use crate::config::{Config, FeatureClock, GnssSource};
use crate::estimator::frontend::{NormFrame, Normaliser};
use crate::estimator::{attitude_from_static, Estimator, ImuMeas, ImuState};
use crate::gnss::reassembly::{Reassembled, Reassembler};
use crate::io::feature_pipe::{self, FeatureFrame};
use crate::io::mavlink::{self as mav, Inbound, Link, Outbound};
use crate::io::Counters;
use crate::status::{self, Degraded, Status};

/// Errors that stop the daemon from starting.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    #[error("mavlink.address '{address}': {source}")]
    Link { address: String, source: mav::LinkError },
    #[error(transparent)]
    Socket(#[from] feature_pipe::SocketError),
    #[error("config: {0}")]
    Config(String),
    #[error(transparent)]
    Log(#[from] crate::io::mcap_log::LogError),
}

/// Handles the fusion thread shares with the I/O tasks.
struct Shared {
    counters: Counters,
    status: Arc<Status>,
    mono_offset_us: Arc<AtomicI64>,
    start: Instant,
    /// Camera frames in the fusion queue (`FRAMES_IN_FLIGHT`).
    frames_queued: Arc<AtomicUsize>,
}

/// What the daemon did, returned at shutdown.
#[derive(Clone, Debug, Default)]
pub struct RunSummary {
    pub counters: std::collections::BTreeMap<String, u64>,
}

/// Input to the fusion loop.
#[derive(Debug)]
pub enum FusionMsg {
    Imu(ImuMeas),
    Attitude {
        roll: f64,
        pitch: f64,
        yaw: f64,
    },
    LocalPosition {
        /// Autopilot boot time of the sample (s).
        t_s: f64,
        p_ned_m: Vector3<f64>,
        v_ned_mps: Vector3<f64>,
    },
    /// A camera frame as received (logged as such) and its features
    /// normalised where it arrived, off the fusion thread.
    Frame(FeatureFrame, NormFrame),
    /// One reassembled RTCM3 message from the rover.
    Rtcm(Vec<u8>),
    SystemTime {
        unix_us: u64,
        boot_ms: u32,
    },
    Origin {
        lat_deg: f64,
        lon_deg: f64,
        alt_m: f64,
    },
    /// Replay only: the daemon installed rebase `seq` at this point.
    RebaseInstalled {
        seq: u64,
    },
}

/// What the rebase thread is asked to do.
enum RebaseWork {
    /// Compute this job for the estimator of this generation.
    Run(u64, Arc<crate::estimator::RebaseJob>),
    /// Free an installed job's inputs (the old base, hundreds of MB at 1000
    /// keyframes) here rather than on the fusion thread.
    Free(Arc<crate::estimator::RebaseJob>),
}

/// Where compressed-mode rebase jobs run (estimator README §5 R4).
enum RebaseExec {
    /// In the estimator, at once.
    Inline,
    /// On a worker thread, off the IMU and camera path; results come back
    /// tagged with the estimator generation that asked.
    Thread {
        tx: std::sync::mpsc::Sender<RebaseWork>,
        /// `(generation, result, compute time ms)`.
        rx: std::sync::mpsc::Receiver<(u64, crate::estimator::RebaseResult, f64)>,
    },
    /// Replay: computed at once, installed where the log says the daemon
    /// installed it, so a replay reproduces the flight bit for bit.
    Logged {
        held: Option<crate::estimator::RebaseResult>,
    },
}

impl RebaseExec {
    fn for_config(cfg: &Config) -> Self {
        if cfg.estimator.mode != crate::estimator::Mode::Compressed || !cfg.compressed.rebase_thread {
            return RebaseExec::Inline;
        }
        let (tx, job_rx) = std::sync::mpsc::channel::<RebaseWork>();
        let (res_tx, rx) = std::sync::mpsc::channel();
        let spawned = std::thread::Builder::new().name("cmsckf-rebase".into()).spawn(move || {
            // Ends when the fusion loop drops its sender.
            while let Ok(work) = job_rx.recv() {
                let (gen, job) = match work {
                    RebaseWork::Run(gen, job) => (gen, job),
                    RebaseWork::Free(job) => {
                        drop(job);
                        continue;
                    }
                };
                let started = Instant::now();
                let res = job.run();
                if res_tx.send((gen, res, started.elapsed().as_secs_f64() * 1e3)).is_err() {
                    break;
                }
            }
        });
        match spawned {
            Ok(_) => RebaseExec::Thread { tx, rx },
            Err(e) => {
                tracing::error!(error = %e, "no rebase thread: global updates run on the fusion thread");
                RebaseExec::Inline
            }
        }
    }
}

/// A measurement waiting for IMU to cover its time.
#[derive(Debug)]
enum Pending {
    Frame(NormFrame),
    Gnss(Vec<cmsckf_models::gnss::SatMeas>),
}

/// Bound of the fusion input channel (≈ 8 s of 1 kHz IMU).
const FUSION_QUEUE: usize = 8192;
/// Frames waiting for IMU to cover them.
const PENDING_FRAMES: usize = 32;
/// Camera frames allowed in the fusion queue at once. A frame there holds
/// its raw and its normalised features (up to `features.max_features` of
/// each); beyond the `PENDING_FRAMES` that can wait for IMU, more would only
/// hold memory, so the forwarder drops them (`fusion_frames_full`).
const FRAMES_IN_FLIGHT: usize = 2 * PENDING_FRAMES;
/// An IMU time this far behind the last one is an autopilot reboot (s).
const REBOOT_JUMP_S: f64 = 2.0;
/// A longer IMU gap restarts the filter: the motion in between is unknown
/// (s; a 1 s gap is bridged, with a degraded status).
const MAX_IMU_GAP_S: f64 = 2.0;

/// Why the filter is restarted (see `Fusion::restart`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Restart {
    /// The autopilot's clock went back.
    Reboot,
    /// Longer than `MAX_IMU_GAP_S` without IMU.
    Gap,
    /// A health check failed (divergence, covariance, state).
    Unhealthy,
}

/// The MAVLink signing key, if one is configured (validated with the config;
/// read again here, so a file changed since is still checked).
fn signing_key(cfg: &Config) -> Result<Option<[u8; 32]>, DaemonError> {
    if cfg.mavlink.signing_key_file.is_empty() {
        return Ok(None);
    }
    crate::config::load_signing_key(std::path::Path::new(&cfg.mavlink.signing_key_file))
        .map(Some)
        .map_err(|(problem, fix)| DaemonError::Config(format!("mavlink.signing_key_file: {problem}; {fix}")))
}

/// Runs the daemon until `shutdown` completes.
pub async fn run(cfg: Config, shutdown: impl Future<Output = ()>) -> Result<RunSummary, DaemonError> {
    let counters = Counters::default();
    let link = Arc::new(
        Link::connect(
            &cfg.mavlink.address,
            cfg.mavlink.system_id,
            cfg.mavlink.component_id,
            cfg.mavlink.system_id,
            cfg.mavlink.autopilot_component_id,
            signing_key(&cfg)?.map(|k| (k, cfg.mavlink.signing_link_id)),
        )
        .await
        .map_err(|source| DaemonError::Link {
            address: cfg.mavlink.address.clone(),
            source,
        })?,
    );
    let listener = feature_pipe::bind(&PathBuf::from(&cfg.features.socket)).await?;
    tracing::info!(address = %cfg.mavlink.address, socket = %cfg.features.socket, mode = cfg.estimator.mode.name(), "cmsckf running");

    let (stop_tx, stop_rx) = watch::channel(false);
    let (fusion_tx, fusion_rx) = mpsc::channel::<FusionMsg>(FUSION_QUEUE);
    let (out_tx, mut out_rx) = mpsc::channel::<Outbound>(256);
    let status = Arc::new(Status::default());
    // Companion monotonic → autopilot boot clock offset (µs), from TIMESYNC.
    let mono_offset_us = Arc::new(AtomicI64::new(i64::MIN));
    let start = Instant::now();

    // Feature socket.
    let (frame_tx, mut frame_rx) = mpsc::channel::<FeatureFrame>(64);
    let feat_task = tokio::spawn(feature_pipe::serve(
        listener,
        cfg.features.max_line_bytes,
        cfg.features.max_features,
        frame_tx,
        counters.clone(),
        stop_rx.clone(),
    ));
    let frames_queued = Arc::new(AtomicUsize::new(0));
    let fwd = {
        let fusion_tx = fusion_tx.clone();
        let counters = counters.clone();
        let mut stop = stop_rx.clone();
        let queued = frames_queued.clone();
        // Frames are normalised here, beside the socket, not on the fusion thread.
        let normaliser = Normaliser::new(&cfg.camera);
        tokio::spawn(async move {
            loop {
                tokio::select! {
                    f = frame_rx.recv() => match f {
                        Some(f) => {
                            if queued.load(Ordering::Relaxed) >= FRAMES_IN_FLIGHT {
                                counters.add("fusion_frames_full", 1);
                                continue;
                            }
                            let norm = normaliser.frame(&f.features);
                            queued.fetch_add(1, Ordering::Relaxed);
                            if fusion_tx.try_send(FusionMsg::Frame(f, norm)).is_err() {
                                queued.fetch_sub(1, Ordering::Relaxed);
                                counters.add("fusion_queue_full", 1);
                            }
                        }
                        None => return,
                    },
                    _ = stop.changed() => return,
                }
            }
        })
    };

    // MAVLink receive.
    let rx_task = {
        let link = link.clone();
        let counters = counters.clone();
        let fusion_tx = fusion_tx.clone();
        let mono_offset_us = mono_offset_us.clone();
        let mut stop = stop_rx.clone();
        let rtcm_from_mavlink = cfg.gnss.source == GnssSource::Mavlink;
        // Without a rover station id, RTCM counts as the rover's only when it
        // comes from the configured vehicle.
        let (rover_id, vehicle) = (cfg.gnss.rover_station_id, cfg.mavlink.system_id as u32);
        let rover_src_ok = move |src: mav::Source| rover_id != 0 || src.system == vehicle;
        tokio::spawn(async move {
            let mut reasm = Reassembler::new();
            loop {
                let r = tokio::select! {
                    r = link.recv() => r,
                    _ = stop.changed() => return,
                };
                let (src, msg, gap) = match r {
                    Ok(v) => v,
                    Err(mav::LinkError::Io(e)) => {
                        counters.add("mavlink_io_error", 1);
                        tracing::warn!(error = %e, "MAVLink link error");
                        tokio::time::sleep(Duration::from_millis(200)).await;
                        continue;
                    }
                    Err(mav::LinkError::Parse(e)) => {
                        counters.add("mavlink_undecodable", 1);
                        tracing::warn!(reason = "mavlink_undecodable", "{e}");
                        continue;
                    }
                    Err(mav::LinkError::Rejected(why)) => {
                        counters.add(&format!("mavlink_rejected_{why}"), 1);
                        tracing::warn!(reason = why, "MAVLink message rejected");
                        continue;
                    }
                };
                if gap > 0 {
                    counters.add("mavlink_frames_lost_or_corrupt", gap as u64);
                    tracing::warn!(
                        frames = gap,
                        reason = "mavlink_frames_lost_or_corrupt",
                        "sequence gap: frames lost or dropped as corrupt (bad CRC, unknown id)"
                    );
                }
                counters.add("mavlink_messages", 1);
                let fm = match msg {
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
                    Inbound::Timesync { tc1_ns, ts1_ns } => {
                        if tc1_ns != 0 {
                            // Our request came back: offset = tc1 − midpoint of our clock.
                            let now_ns = start.elapsed().as_nanos() as i64;
                            let rtt = now_ns - ts1_ns;
                            if (0..1_000_000_000).contains(&rtt) {
                                let offset_us = (tc1_ns - (ts1_ns + now_ns) / 2) / 1000;
                                mono_offset_us.store(offset_us, Ordering::Relaxed);
                                counters.add("timesync", 1);
                            }
                        }
                        None
                    }
                    Inbound::RtcmFragment { flags, data } => {
                        if rtcm_from_mavlink {
                            let mut r = reasm.push(flags, &data);
                            loop {
                                match r {
                                    Reassembled::Message(m) => {
                                        counters.add("rtcm_messages", 1);
                                        counters.add("rtcm_bytes", m.len() as u64);
                                        if !rover_src_ok(src) {
                                            counters.add("rtcm_other_source", 1);
                                        } else if fusion_tx.try_send(FusionMsg::Rtcm(m)).is_err() {
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
                                        r = *then;
                                    }
                                }
                            }
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
                };
                if let Some(m) = fm {
                    if fusion_tx.try_send(m).is_err() {
                        counters.add("fusion_queue_full", 1);
                    }
                }
            }
        })
    };

    // A receiver wired to the companion computer: raw RTCM3.
    let stream_task = if cfg.gnss.source == GnssSource::Stream {
        let spec = crate::gnss::stream::parse(&cfg.gnss.stream)
            .map_err(|e| DaemonError::Config(format!("gnss.stream {e}")))?;
        let (tx, mut rx) = mpsc::channel::<Vec<u8>>(64);
        let fwd_tx = fusion_tx.clone();
        let counters2 = counters.clone();
        let mut stop = stop_rx.clone();
        let fwd = tokio::spawn(async move {
            loop {
                tokio::select! {
                    b = rx.recv() => match b {
                        Some(b) => if fwd_tx.try_send(FusionMsg::Rtcm(b)).is_err() { counters2.add("fusion_queue_full", 1) },
                        None => return,
                    },
                    _ = stop.changed() => return,
                }
            }
        });
        Some((
            tokio::spawn(crate::gnss::stream::run(spec, tx, counters.clone(), stop_rx.clone())),
            fwd,
        ))
    } else {
        None
    };

    drop(fusion_tx);

    // Send task: every outbound message goes through here.
    let tx_task = {
        let link = link.clone();
        let counters = counters.clone();
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
    };

    // Status: HEARTBEAT at 1 Hz and at once on a change, with the reasons
    // for a degraded state as STATUSTEXT.
    let status_task = {
        let out_tx = out_tx.clone();
        let status = status.clone();
        let mut stop = stop_rx.clone();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_millis(50));
            let mut last: Option<(bool, u32)> = None;
            let mut last_sent = Instant::now();
            loop {
                tokio::select! { _ = tick.tick() => {}, _ = stop.changed() => return }
                let initialised = status.initialised.load(Ordering::Relaxed);
                let mut degraded = status.degraded();
                let since_imu_ms = (start.elapsed().as_millis() as u64)
                    .saturating_sub(status.last_imu_wall_ms.load(Ordering::Relaxed));
                if initialised && since_imu_ms > 500 {
                    degraded |= Degraded::ImuGap.bit();
                }
                let now = (initialised, degraded);
                if last == Some(now) && last_sent.elapsed() < Duration::from_secs(1) {
                    continue;
                }
                if last.map(|l| l.1) != Some(degraded) && (degraded != 0 || last.is_some()) {
                    let text = if degraded == 0 {
                        "cmsckf: nominal".to_string()
                    } else {
                        format!("cmsckf degraded: {}", status::describe(degraded))
                    };
                    tracing::warn!(degraded = %status::describe(degraded), "status changed");
                    let severity = if degraded == 0 { 6 } else { 4 };
                    let _ = out_tx.try_send(Outbound::StatusText { severity, text });
                }
                let _ = out_tx.try_send(Outbound::Heartbeat {
                    initialised,
                    degraded: degraded != 0,
                });
                last = Some(now);
                last_sent = Instant::now();
            }
        })
    };

    // Periodic: stream requests, timesync, counters.
    let periodic = {
        let out_tx = out_tx.clone();
        let counters = counters.clone();
        let mut stop = stop_rx.clone();
        let imu_interval_us = 1e6 / cfg.mavlink.imu_rate_hz as f32;
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_secs(1));
            let mut n: u64 = 0;
            loop {
                tokio::select! { _ = tick.tick() => {}, _ = stop.changed() => return }
                n += 1;
                // Ask for the streams until they arrive.
                let wanted = [
                    ("imu_highres", mav::MSG_ID_HIGHRES_IMU, imu_interval_us),
                    ("attitude", mav::MSG_ID_ATTITUDE, 100_000.0),
                    ("system_time", mav::MSG_ID_SYSTEM_TIME, 1_000_000.0),
                    ("local_position", mav::MSG_ID_LOCAL_POSITION_NED, 100_000.0),
                ];
                for (counter, id, interval) in wanted {
                    if counters.get(counter) == 0 {
                        let _ = out_tx.try_send(Outbound::SetMessageInterval {
                            message_id: id,
                            interval_us: interval,
                        });
                    }
                }
                let _ = out_tx.try_send(Outbound::TimesyncRequest {
                    ts1_ns: start.elapsed().as_nanos() as i64,
                });
                if n.is_multiple_of(10) {
                    tracing::info!(counters = ?counters.snapshot(), "cmsckf counters");
                }
            }
        })
    };

    // Fusion on its own thread.
    let logger = if cfg.log.path.is_empty() {
        None
    } else {
        let path = PathBuf::from(crate::io::mcap_log::expand_path(&cfg.log.path));
        let header = crate::io::mcap_log::LogHeader {
            version: env!("CARGO_PKG_VERSION").to_string(),
            mode: cfg.estimator.mode.name().to_string(),
            config_toml: toml::to_string(&cfg).unwrap_or_default(),
        };
        let l = crate::io::mcap_log::McapLogger::create(&path, &header)?;
        tracing::info!(path = %path.display(), "logging to MCAP");
        Some(l)
    };
    let fusion = {
        let shared = Shared {
            counters: counters.clone(),
            status: status.clone(),
            mono_offset_us: mono_offset_us.clone(),
            start,
            frames_queued,
        };
        let cfg = cfg.clone();
        let out_tx = out_tx.clone();
        std::thread::Builder::new()
            .name("cmsckf-fusion".into())
            .spawn(move || fusion_loop(cfg, fusion_rx, out_tx, shared, logger))
            .expect("spawning the fusion thread")
    };
    drop(out_tx);

    shutdown.await;
    tracing::info!("cmsckf shutting down");
    let _ = stop_tx.send(true);
    for t in [rx_task, fwd, periodic, status_task] {
        let _ = t.await;
    }
    let _ = feat_task.await;
    if let Some((a, b)) = stream_task {
        let _ = a.await;
        let _ = b.await;
    }
    // The fusion thread ends when its input channel closes (all senders gone).
    let _ = tokio::task::spawn_blocking(move || fusion.join()).await;
    let _ = tx_task.await;
    let _ = std::fs::remove_file(&cfg.features.socket);
    Ok(RunSummary {
        counters: counters.snapshot(),
    })
}

/// GNSS input of the fusion loop: RTCM decoding, the receiver model, the
/// world origin and the GPS-time → autopilot-time map.
struct GnssIn {
    dec: crate::gnss::rtcm::RtcmDecoder,
    rx: crate::gnss::Receiver,
    frame: Option<cmsckf_models::geodesy::NedFrame>,
    /// Unix time minus autopilot boot time (s), from SYSTEM_TIME.
    unix_minus_boot_s: Option<f64>,
    msgs: Vec<crate::gnss::rtcm::GnssMessage>,
    epochs: Vec<crate::gnss::Epoch>,
    klobuchar: Option<cmsckf_models::gnss::Klobuchar>,
}

/// State of the fusion loop.
pub struct Fusion {
    log: Option<crate::io::mcap_log::McapLogger>,
    rebase: RebaseExec,
    /// Counts estimators started, so a rebase result of a filter since
    /// restarted is recognised and dropped.
    est_gen: u64,
    next_state_log: f64,
    /// Next autopilot time to log the counters at (`/diagnostics`).
    next_diag_t: f64,
    cfg: Config,
    est: Option<Estimator>,
    static_buf: VecDeque<ImuMeas>,
    attitude: Option<(f64, f64, f64)>,
    /// The autopilot's local position and velocity (NED) and their time (s).
    local: Option<(Vector3<f64>, Vector3<f64>, f64)>,
    pending: VecDeque<(f64, Pending)>,
    gnss: GnssIn,
    origin_sent: bool,
    last_imu_t: f64,
    last_frame_t: f64,
    next_output_t: f64,
    reset_counter: u8,
    /// Degraded-state reasons, in autopilot time.
    tracker: status::Tracker,
}

fn fusion_loop(
    cfg: Config,
    mut rx: mpsc::Receiver<FusionMsg>,
    out: mpsc::Sender<Outbound>,
    shared: Shared,
    log: Option<crate::io::mcap_log::McapLogger>,
) {
    let Shared {
        counters,
        status,
        mono_offset_us,
        start,
        frames_queued,
    } = shared;
    let mut f = Fusion::new(cfg, log);
    let ctx = Ctx {
        counters,
        out,
        status,
        mono_offset_us,
        start,
    };
    while let Some(msg) = rx.blocking_recv() {
        if matches!(msg, FusionMsg::Frame(..)) {
            let _ = frames_queued.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |n| Some(n.saturating_sub(1)));
        }
        f.handle(msg, &ctx);
    }
    let counters = ctx.counters;
    f.finish_log(&counters);
}

/// What the fusion loop writes to: counters, the outbound channel and the
/// flags and clock offset shared with the I/O tasks.
pub struct Ctx {
    pub counters: Counters,
    pub out: mpsc::Sender<Outbound>,
    pub status: Arc<Status>,
    pub mono_offset_us: Arc<AtomicI64>,
    /// The daemon's start (wall clock), for the IMU's wall-time age.
    pub start: Instant,
}

impl Fusion {
    /// Finishes the log (on shutdown: `Drop` would swallow its errors),
    /// counting its messages and raising an alarm for dropped records.
    pub fn finish_log(&mut self, counters: &Counters) {
        if self.last_imu_t.is_finite() {
            self.log_diagnostics(self.last_imu_t, counters, 0);
        }
        // The log is finished here, on shutdown: `Drop` would swallow its errors.
        if let Some(l) = self.log.take() {
            let dropped = l.dropped();
            match l.finish() {
                Ok(s) => {
                    counters.add("log_messages", s.messages);
                    counters.add("log_chunks", s.chunks);
                }
                Err(e) => {
                    counters.add("log_error", 1);
                    tracing::error!(error = %e, "the MCAP log could not be finished");
                }
            }
            if dropped > 0 {
                counters.add("log_dropped", dropped);
                tracing::error!(
                    dropped,
                    "ALARM: MCAP log records were dropped (writer could not keep up)"
                );
            }
        }
    }

    /// For `cmsckf replay`: rebases are installed where the log says.
    pub fn for_replay(mut self) -> Self {
        if !matches!(self.rebase, RebaseExec::Inline) {
            self.rebase = RebaseExec::Logged { held: None };
        }
        self
    }

    /// Installs the results the rebase thread has finished (logging where,
    /// for replay); results of a filter since restarted are dropped.
    fn poll_rebase(&mut self, counters: &Counters) {
        let RebaseExec::Thread { rx, tx } = &self.rebase else {
            return;
        };
        while let Ok((gen, res, compute_ms)) = rx.try_recv() {
            let seq = res.seq;
            match self.est.as_mut() {
                Some(est) if gen == self.est_gen => match est.install_rebase(res) {
                    Ok(job) => {
                        counters.add("rebases_installed", 1);
                        if let Some(job) = job {
                            // If the worker is gone the job is freed here.
                            let _ = tx.send(RebaseWork::Free(job));
                        }
                        if let Some(l) = &self.log {
                            // With the worker's wall time for the job (replay
                            // reads only the sequence number).
                            l.log(
                                Topic::InputRebase,
                                self.last_imu_t,
                                &json!({"seq": seq, "compute_ms": compute_ms, "global_keyframes": est.n_global_keyframes()}),
                            );
                        }
                    }
                    Err(e) => {
                        counters.add("rebase_stale", 1);
                        tracing::warn!(error = %e, "rebase result not installed");
                    }
                },
                _ => counters.add("rebase_stale", 1),
            }
        }
    }

    /// A fusion loop for `cfg`, logging to `log` if given.
    pub fn new(cfg: Config, log: Option<crate::io::mcap_log::McapLogger>) -> Self {
        Fusion {
            log,
            rebase: RebaseExec::for_config(&cfg),
            est_gen: 0,
            next_state_log: f64::NEG_INFINITY,
            next_diag_t: f64::NEG_INFINITY,
            est: None,
            static_buf: VecDeque::with_capacity(4096),
            attitude: None,
            local: None,
            pending: VecDeque::with_capacity(PENDING_FRAMES),
            origin_sent: false,
            gnss: GnssIn {
                dec: crate::gnss::rtcm::RtcmDecoder::new(),
                rx: crate::gnss::Receiver::new(
                    crate::gnss::spp::SppOptions {
                        elevation_mask_deg: cfg.gnss.elevation_mask_deg,
                        iono: cfg.gnss.iono,
                        // Validated with the config: the fallback is never taken.
                        systems: crate::gnss::parse_systems(&cfg.gnss.systems)
                            .unwrap_or(vec![crate::gnss::rtcm::System::Gps]),
                    },
                    if cfg.gnss.week_hint != 0 {
                        cfg.gnss.week_hint
                    } else {
                        crate::gnss::gps_week_now()
                    },
                    cfg.gnss.rover_station_id,
                ),
                frame: (cfg.gnss.origin_llh.len() == 3).then(|| {
                    let o = &cfg.gnss.origin_llh;
                    cmsckf_models::geodesy::NedFrame::from_llh_deg(o[0], o[1], o[2])
                }),
                unix_minus_boot_s: None,
                msgs: Vec::new(),
                epochs: Vec::new(),
                klobuchar: (cfg.gnss.klobuchar_alpha.len() == 4 && cfg.gnss.klobuchar_beta.len() == 4).then(|| {
                    let a = &cfg.gnss.klobuchar_alpha;
                    let b = &cfg.gnss.klobuchar_beta;
                    cmsckf_models::gnss::Klobuchar {
                        alpha: [a[0], a[1], a[2], a[3]],
                        beta: [b[0], b[1], b[2], b[3]],
                    }
                }),
            },
            last_imu_t: f64::NEG_INFINITY,
            last_frame_t: f64::NEG_INFINITY,
            next_output_t: f64::NEG_INFINITY,
            reset_counter: 0,
            tracker: status::Tracker::default(),
            cfg,
        }
    }

    /// Handles one input, in the order the fusion loop received it (replay
    /// feeds the logged inputs through here in the same order).
    pub fn handle(&mut self, msg: FusionMsg, ctx: &Ctx) {
        self.poll_rebase(&ctx.counters);
        match msg {
            FusionMsg::RebaseInstalled { seq } => {
                if let RebaseExec::Logged { held } = &mut self.rebase {
                    if let (Some(res), Some(est)) = (held.take(), self.est.as_mut()) {
                        if let Some(l) = &self.log {
                            l.log(Topic::InputRebase, self.last_imu_t, &json!({ "seq": seq }));
                        }
                        if est.install_rebase(res).is_ok() {
                            ctx.counters.add("rebases_installed", 1);
                        }
                    }
                }
            }
            FusionMsg::Attitude { roll, pitch, yaw } => {
                self.log(
                    Topic::InputAutopilot,
                    self.last_imu_t,
                    &json!({"attitude_rad": [roll, pitch, yaw]}),
                );
                self.attitude = Some((roll, pitch, yaw))
            }
            FusionMsg::LocalPosition {
                t_s,
                p_ned_m,
                v_ned_mps,
            } => {
                self.log(
                    Topic::InputAutopilot,
                    self.last_imu_t,
                    &json!({"local_position": {"t_s": t_s, "p_ned_m": p_ned_m.as_slice(), "v_ned_mps": v_ned_mps.as_slice()}}),
                );
                self.local = Some((p_ned_m, v_ned_mps, t_s))
            }
            FusionMsg::SystemTime { unix_us, boot_ms } => {
                self.log(
                    Topic::InputSystemTime,
                    boot_ms as f64 * 1e-3,
                    &json!({"unix_us": unix_us, "boot_ms": boot_ms}),
                );
                self.gnss.unix_minus_boot_s = Some(unix_us as f64 * 1e-6 - boot_ms as f64 * 1e-3);
            }
            FusionMsg::Origin {
                lat_deg,
                lon_deg,
                alt_m,
            } => {
                self.log(
                    Topic::InputAutopilot,
                    self.last_imu_t,
                    &json!({"origin": [lat_deg, lon_deg, alt_m]}),
                );
                if self.gnss.frame.is_none() {
                    // MAVLink gives the origin's altitude above mean sea level;
                    // the geoid separation (tens of metres) is a constant
                    // height offset that the clock bias cannot absorb, so
                    // `gnss.origin_llh` is the precise way to set it.
                    self.gnss.frame = Some(cmsckf_models::geodesy::NedFrame::from_llh_deg(lat_deg, lon_deg, alt_m));
                    ctx.counters.add("gnss_origin_from_autopilot", 1);
                }
            }
            FusionMsg::Rtcm(bytes) => {
                self.log(Topic::InputRtcm, self.last_imu_t, &json!({ "bytes": bytes }));
                self.on_rtcm(&bytes, &ctx.counters)
            }
            FusionMsg::Frame(fr, norm) => {
                let t_ap_us = match self.cfg.features.clock {
                    FeatureClock::Autopilot => fr.t_us as i64,
                    FeatureClock::Monotonic => {
                        let off = ctx.mono_offset_us.load(Ordering::Relaxed);
                        if off == i64::MIN {
                            ctx.counters.add("feature_no_timesync", 1);
                            return;
                        }
                        fr.t_us as i64 + off
                    }
                };
                let t = t_ap_us as f64 * 1e-6;
                self.log(
                    Topic::InputFeatures,
                    t,
                    &records::Features {
                        t_us: fr.t_us,
                        t_ap_us,
                        cam: fr.cam,
                        features: &fr.features,
                    },
                );
                if t <= self.last_frame_t {
                    ctx.counters.add("feature_time_backwards", 1);
                    tracing::warn!(
                        reason = "feature_time_backwards",
                        t_s = t,
                        prev_s = self.last_frame_t,
                        "frame rejected"
                    );
                    return;
                }
                self.last_frame_t = t;
                self.enqueue(t, Pending::Frame(norm), &ctx.counters);
            }
            FusionMsg::Imu(m) => {
                if m.t_s < self.last_imu_t - REBOOT_JUMP_S {
                    // The autopilot's boot clock restarted (a reboot): start
                    // over rather than reject its samples forever.
                    ctx.counters.add("autopilot_clock_reset", 1);
                    tracing::error!(
                        from_s = self.last_imu_t,
                        to_s = m.t_s,
                        "autopilot clock jumped back: resetting the filter"
                    );
                    self.restart(m.t_s, "autopilot reboot seen", Restart::Reboot, &ctx.out);
                } else if self.est.is_some() && m.t_s - self.last_imu_t > MAX_IMU_GAP_S {
                    // Seconds without IMU: the motion in between is unknown.
                    ctx.counters.add("imu_gap_restart", 1);
                    tracing::error!(
                        gap_s = m.t_s - self.last_imu_t,
                        "IMU gap too long: resetting the filter"
                    );
                    self.restart(m.t_s, "IMU gap", Restart::Gap, &ctx.out);
                }
                if m.t_s <= self.last_imu_t {
                    ctx.counters.add("imu_time_backwards", 1);
                    return;
                }
                if self.last_imu_t.is_finite() && m.t_s - self.last_imu_t > 0.2 {
                    self.tracker.hold(Degraded::ImuGap, m.t_s);
                    if m.t_s - self.last_imu_t > 0.5 {
                        ctx.counters.add("imu_gap", 1);
                        tracing::warn!(reason = "imu_gap", gap_s = m.t_s - self.last_imu_t, "IMU gap");
                    }
                }
                self.last_imu_t = m.t_s;
                ctx.counters.add("imu_samples", 1);
                self.log(
                    Topic::InputImu,
                    m.t_s,
                    &records::Imu {
                        t_us: (m.t_s * 1e6).round() as u64,
                        accel_mps2: m.accel_mps2.as_slice(),
                        gyro_radps: m.gyro_radps.as_slice(),
                    },
                );
                self.on_imu(m, &ctx.counters, &ctx.out);
                let st = &ctx.status;
                // An unhealthy filter was restarted in `on_imu`: a running
                // filter is a healthy one.
                st.initialised.store(self.est.is_some(), Ordering::Relaxed);
                st.last_imu_wall_ms
                    .store(ctx.start.elapsed().as_millis() as u64, Ordering::Relaxed);
                self.tracker.update(m.t_s, self.est.is_some(), &ctx.counters, st);
                if m.t_s >= self.next_diag_t {
                    self.next_diag_t = m.t_s + 1.0;
                    self.log_diagnostics(m.t_s, &ctx.counters, st.degraded());
                }
            }
        }
    }

    fn log<T: serde::Serialize>(&self, topic: Topic, t_s: f64, v: &T) {
        if let Some(l) = &self.log {
            l.log(topic, t_s, v);
        }
    }

    /// The counters and degraded-state reasons, to `/diagnostics`.
    fn log_diagnostics(&self, t_s: f64, counters: &Counters, degraded: u32) {
        if self.log.is_some() {
            self.log(
                Topic::Diagnostics,
                t_s,
                &json!({"t_s": t_s, "counters": counters.snapshot(), "degraded": status::describe(degraded),
                    "reset_counter": self.reset_counter}),
            );
        }
    }

    /// A `foxglove.Log` line (level: 2 info, 3 warning, 4 error).
    fn log_text(&self, level: u8, t_s: f64, message: &str) {
        let t = t_s.max(0.0);
        self.log(
            Topic::Log,
            t,
            &json!({"timestamp": {"sec": t.floor() as u64, "nsec": ((t - t.floor()) * 1e9) as u64},
                "level": level, "message": message, "name": "cmsckf", "file": file!(), "line": 0}),
        );
    }

    /// Queues a measurement in time order (bounded; the oldest is dropped).
    fn enqueue(&mut self, t: f64, item: Pending, counters: &Counters) {
        if self.pending.len() == PENDING_FRAMES {
            self.pending.pop_front();
            counters.add("pending_overflow", 1);
        }
        let at = self.pending.partition_point(|(u, _)| *u <= t);
        self.pending.insert(at, (t, item));
    }

    /// Decodes RTCM, completes epochs, and queues each as a GNSS update at
    /// its autopilot time: GPS tag → Unix (leap seconds) → boot clock
    /// (SYSTEM_TIME), less the receiver clock offset.
    fn on_rtcm(&mut self, bytes: &[u8], counters: &Counters) {
        let g = &mut self.gnss;
        let before = g.dec.stats.crc_failures;
        g.dec.push(bytes, &mut g.msgs);
        if g.dec.stats.crc_failures > before {
            counters.add("rtcm_crc_failure", g.dec.stats.crc_failures - before);
            tracing::warn!(reason = "rtcm_crc_failure", "RTCM frame with a bad CRC skipped");
        }
        for m in g.msgs.drain(..) {
            g.rx.push(m, &mut g.epochs);
        }
        let epochs: Vec<_> = g.epochs.drain(..).collect();
        for ep in epochs {
            counters.add("gnss_epochs", 1);
            let Some(offset) = self.gnss.unix_minus_boot_s else {
                counters.add("gnss_no_system_time", 1);
                continue;
            };
            let clock_m = ep.fix.as_ref().map_or(0.0, |f| f.clock_bias_m);
            let t = cmsckf_models::gnss::gps_to_unix_s(ep.week, ep.tow_s) - offset - clock_m / cmsckf_models::geodesy::C_MPS;
            if let Ok(fix) = &ep.fix {
                let (lat, lon, h) = cmsckf_models::geodesy::ecef_to_llh(&fix.r_ecef_m);
                let tt = t.max(0.0);
                // Variance approximated from the residuals and the PDOP.
                let var = (fix.residual_rms_m.max(1.0) * fix.pdop).powi(2) / 3.0;
                self.log(
                    Topic::GnssFix,
                    t,
                    &json!({"timestamp": {"sec": tt.floor() as u64, "nsec": ((tt - tt.floor()) * 1e9) as u64},
                        "frame_id": "gnss", "latitude": lat.to_degrees(), "longitude": lon.to_degrees(), "altitude": h,
                        "position_covariance": [var, 0.0, 0.0, 0.0, var, 0.0, 0.0, 0.0, var], "position_covariance_type": 1,
                        "satellites": fix.sats.len(), "raim": format!("{:?}", fix.raim)}),
                );
            }
            if self.gnss.frame.is_none() {
                // No configured or autopilot origin: anchor the world frame so
                // that the current estimate sits at the first fix.
                if let (Ok(fix), Some(est)) = (&ep.fix, self.est.as_ref()) {
                    let (lat, lon, _) = cmsckf_models::geodesy::ecef_to_llh(&fix.r_ecef_m);
                    let r = cmsckf_models::geodesy::R_ecef_ned(lat, lon);
                    let origin = fix.r_ecef_m - r * est.imu_state().p_B_in_W;
                    self.gnss.frame = Some(cmsckf_models::geodesy::NedFrame::from_ecef(&origin));
                    counters.add("gnss_origin_from_fix", 1);
                }
            }
            let obs = ep.sats.iter().map(crate::gnss::RawSat::from_obs);
            let policy = crate::gnss::IonoPolicy {
                mode: self.cfg.gnss.iono,
                klobuchar: self.gnss.klobuchar.as_ref(),
                rx_ecef_m: ep.fix.as_ref().ok().map(|f| f.r_ecef_m),
            };
            let sats = crate::gnss::sat_measurements(&self.gnss.rx.ephs, ep.week, ep.tow_s, policy, obs);
            if !sats.is_empty() {
                self.enqueue(t, Pending::Gnss(sats), counters);
            }
        }
    }

    /// Drops the filter so that the next IMU samples start a fresh one (the
    /// one reset path): `reset_counter` moves on, the autopilot gets a
    /// `STATUSTEXT`, the log a `/log` line, and the status shows
    /// `filter_reset` for 2 s. After a reboot or a long IMU gap the
    /// autopilot's attitude and position are stale, so the restart waits for
    /// fresh ones (and, after a reboot, for SYSTEM_TIME to map GPS time).
    fn restart(&mut self, t_s: f64, why: &str, kind: Restart, out: &mpsc::Sender<Outbound>) {
        self.log_text(4, t_s, &format!("filter reset: {why}"));
        let _ = out.try_send(Outbound::StatusText {
            severity: if kind == Restart::Unhealthy { 2 } else { 4 },
            text: format!("cmsckf reset: {why}"),
        });
        self.est = None;
        self.reset_counter = self.reset_counter.wrapping_add(1);
        self.static_buf.clear();
        if kind != Restart::Unhealthy {
            self.attitude = None;
            self.local = None;
        }
        if kind == Restart::Reboot {
            self.tracker.restart_clock();
            self.gnss.unix_minus_boot_s = None;
            self.pending.clear();
            self.last_frame_t = f64::NEG_INFINITY;
            self.next_output_t = f64::NEG_INFINITY;
            self.next_state_log = f64::NEG_INFINITY;
            self.last_imu_t = f64::NEG_INFINITY;
        }
        self.tracker.hold(Degraded::FilterReset, t_s);
    }

    fn on_imu(&mut self, m: ImuMeas, counters: &Counters, out: &mpsc::Sender<Outbound>) {
        // Tell the autopilot our origin once it is known (output.set_gps_origin).
        if self.cfg.output.set_gps_origin && !self.origin_sent {
            if let Some(frame) = self.gnss.frame {
                let (lat, lon, h) = cmsckf_models::geodesy::ecef_to_llh(&frame.origin_ecef);
                let msg = Outbound::SetGpsGlobalOrigin {
                    lat_deg: lat.to_degrees(),
                    lon_deg: lon.to_degrees(),
                    alt_m: h,
                };
                if out.try_send(msg).is_ok() {
                    self.origin_sent = true;
                    counters.add("gps_origin_sent", 1);
                }
            }
        }
        if self.est.is_none() {
            self.try_init(m, counters);
            return;
        }
        let Some(est) = self.est.as_mut() else { return };
        if est.add_imu(m).is_err() {
            counters.add("imu_rejected", 1);
        }
        self.emit_output(m, counters, out);
        let Some(est) = self.est.as_mut() else { return };
        // Measurements now covered by IMU, in time order.
        while let Some((t, _)) = self.pending.front() {
            if *t > m.t_s {
                break;
            }
            let Some((t, item)) = self.pending.pop_front() else {
                break;
            };
            if t < est.time_s() {
                counters.add(
                    if matches!(item, Pending::Frame(_)) {
                        "feature_late"
                    } else {
                        "gnss_late"
                    },
                    1,
                );
                continue;
            }
            let fr = match item {
                Pending::Frame(fr) => fr,
                Pending::Gnss(sats) => {
                    let Some(frame) = self.gnss.frame else { continue };
                    match est.process_gnss(t, &frame, &sats) {
                        Ok(rep) => {
                            if let Some(l) = &self.log {
                                let (clock, clock_var) = est.clock();
                                l.log(
                                    Topic::FilterGnss,
                                    t,
                                    &json!({
                                        "t_s": t, "pseudoranges_used": rep.pseudoranges_used, "range_rates_used": rep.range_rates_used,
                                        "rejected": rep.rejected, "residuals": rep.residuals, "clock": clock.as_slice(),
                                        "clock_var": clock_var.as_slice(),
                                        "keyframe_sigma_m": est.keyframe_sigmas().into_iter().take(200).collect::<Vec<_>>(),
                                    }),
                                );
                            }
                            counters.add("gnss_epochs_fused", 1);
                            self.tracker.gnss_fused(t);
                            let codes_rejected = ["gnss_pseudorange_chi2", "gnss_pseudorange_outlier"]
                                .iter()
                                .filter_map(|k| rep.rejected.get(k))
                                .sum::<u64>();
                            self.tracker.gnss_codes_rejected(t, codes_rejected);
                            counters.add("gnss_pseudoranges_used", rep.pseudoranges_used as u64);
                            counters.add("gnss_range_rates_used", rep.range_rates_used as u64);
                            for (k, v) in &rep.rejected {
                                counters.add(k, *v);
                            }
                        }
                        Err(e) => {
                            counters.add("gnss_rejected", 1);
                            tracing::warn!(error = %e, "GNSS epoch rejected");
                        }
                    }
                    continue;
                }
            };
            let rej = fr.rejects;
            for (name, n) in [
                ("feature_non_finite", rej.non_finite),
                ("feature_outside_image", rej.outside_image),
                ("feature_undistort_failed", rej.undistort_failed),
                ("feature_duplicate_id", rej.duplicate_id),
            ] {
                if n > 0 {
                    counters.add(name, n);
                }
            }
            let started = std::time::Instant::now();
            let result = est.process_frame(t, &fr.obs);
            let elapsed_us = started.elapsed().as_secs_f64() * 1e6;
            if let Some(job) = est.take_rebase_job() {
                counters.add("rebases_started", 1);
                // A job not handed to the worker runs here and now.
                let here = match &mut self.rebase {
                    RebaseExec::Thread { tx, .. } => match tx.send(RebaseWork::Run(self.est_gen, job)) {
                        Ok(()) => None,
                        Err(std::sync::mpsc::SendError(work)) => {
                            // The worker is gone: compute it here rather than never.
                            counters.add("rebase_thread_lost", 1);
                            match work {
                                RebaseWork::Run(_, job) => Some(job),
                                RebaseWork::Free(_) => None,
                            }
                        }
                    },
                    RebaseExec::Logged { held } => {
                        *held = Some(job.run());
                        None
                    }
                    RebaseExec::Inline => Some(job),
                };
                if let Some(job) = here {
                    let _ = est.install_rebase(job.run());
                }
            }
            match result {
                Ok(rep) => {
                    if let Some(l) = &self.log {
                        l.log(
                            Topic::FilterVision,
                            t,
                            &json!({
                                "t_s": t, "features": fr.obs.len(), "tracks_used": rep.tracks_used,
                                "rejected": rep.rejected, "nis": rep.nis, "residual_rms": rep.residual_rms,
                                "keyframe_created": rep.keyframe_created, "loop_closure_tracks": rep.loop_closure_tracks,
                                "global_updates": rep.global_updates, "elapsed_us": elapsed_us,
                                "local_dim": est.local_dim(), "global_keyframes": est.n_global_keyframes(),
                                "keyframe_sigma_m": est.keyframe_sigmas().into_iter().take(200).collect::<Vec<_>>(),
                            }),
                        );
                        for ev in &rep.events {
                            match ev {
                                crate::estimator::FilterEvent::GlobalUpdate { reason, global_before, local_after } => l.log(
                                    Topic::FilterGlobal,
                                    t,
                                    &json!({"t_s": t, "reason": format!("{reason:?}"), "global_before": global_before, "local_after": local_after}),
                                ),
                                crate::estimator::FilterEvent::KeyframeCreated { id } => {
                                    if let Some(kf) = est.keyframes().find(|k| k.id == *id) {
                                        let cov = est.keyframe_covariance(*id).map(|c| c.diagonal().as_slice().to_vec());
                                        let q = kf.q_W_B();
                                        l.log(
                                            Topic::FilterKeyframes,
                                            t,
                                            &json!({"t_s": t, "id": id, "p_B_in_W": kf.p_B_in_W.as_slice(), "q_W_B_wxyz": [q.w, q.i, q.j, q.k], "cov_diag": cov}),
                                        );
                                    }
                                }
                                crate::estimator::FilterEvent::Promoted { keyframes } => l.log(
                                    Topic::FilterGlobal,
                                    t,
                                    &json!({"t_s": t, "reason": "Promotion", "promoted": keyframes}),
                                ),
                                crate::estimator::FilterEvent::Update { .. } => {}
                            }
                        }
                    }
                    counters.add("frames_processed", 1);
                    self.tracker.frame_processed(t);
                    counters.add("tracks_used", rep.tracks_used as u64);
                    counters.add("global_updates", rep.global_updates as u64);
                    if rep.promoted > 0 {
                        counters.add("keyframes_promoted", rep.promoted as u64);
                    }
                    if rep.deferred > 0 {
                        // Loop-closure observations left for a later track while
                        // a rebase was computing the global part.
                        counters.add("loop_closure_deferred", rep.deferred as u64);
                    }
                    for (k, v) in &rep.rejected {
                        counters.add(&format!("track_rejected_{k}"), *v);
                    }
                }
                Err(e) => {
                    counters.add("frame_rejected", 1);
                    tracing::warn!(error = %e, "frame rejected");
                }
            }
        }
        // Once per IMU sample, after this sample's measurements (a GNSS-only
        // divergence is caught as soon as a vision one).
        if let Err(why) = est.check_health() {
            counters.add("filter_reset", 1);
            tracing::error!(reason = %why, "filter unhealthy: resetting");
            self.restart(m.t_s, &why, Restart::Unhealthy, out);
        }
    }

    /// Sends the estimate at the configured rate of autopilot time, predicted
    /// to the latest IMU sample from the filter as it stands (before this
    /// sample's measurements: no update, and no global update, ever delays it).
    fn emit_output(&mut self, m: ImuMeas, counters: &Counters, out: &mpsc::Sender<Outbound>) {
        let Some(est) = self.est.as_ref() else { return };
        // Output at the configured rate of autopilot time, propagated to the
        // latest IMU sample.
        if m.t_s >= self.next_output_t {
            let period = 1.0 / self.cfg.output.rate_hz;
            self.next_output_t = if self.next_output_t.is_finite() && m.t_s - self.next_output_t < period {
                self.next_output_t + period
            } else {
                m.t_s + period
            };
            let x = est.predict(m.t_s);
            let cov = est.pose_covariance();
            if let Some(l) = &self.log {
                let q = x.q_W_B.coords;
                let (sec, nsec) = (m.t_s.floor() as u64, ((m.t_s - m.t_s.floor()) * 1e9) as u64);
                let timestamp = records::Stamp { sec, nsec };
                let position = records::Xyz {
                    x: x.p_B_in_W.x,
                    y: x.p_B_in_W.y,
                    z: x.p_B_in_W.z,
                };
                let orientation = records::Quat {
                    x: q.x,
                    y: q.y,
                    z: q.z,
                    w: q.w,
                };
                l.log(
                    Topic::Pose,
                    m.t_s,
                    &records::Pose {
                        timestamp,
                        frame_id: "ned",
                        pose: records::PoseBody { position, orientation },
                    },
                );
                l.log(
                    Topic::Transform,
                    m.t_s,
                    &records::Transform {
                        timestamp,
                        parent_frame_id: "ned",
                        child_frame_id: "body_frd",
                        translation: position,
                        rotation: orientation,
                    },
                );
                if m.t_s >= self.next_state_log {
                    self.next_state_log = m.t_s + 0.1;
                    let (clock, _) = est.clock();
                    l.log(
                        Topic::FilterState,
                        m.t_s,
                        &json!({"t_s": m.t_s, "q_W_B_wxyz": [q.w, q.x, q.y, q.z], "v_B_in_W": x.v_B_in_W.as_slice(),
                            "p_B_in_W": x.p_B_in_W.as_slice(), "b_g": x.b_g.as_slice(), "b_a": x.b_a.as_slice(),
                            "clock": clock.as_slice(), "cov_diag": est.imu_covariance().diagonal().as_slice()}),
                    );
                }
            }
            for o in outputs(&x, &cov, m.t_s, self.reset_counter, self.cfg.output.odometry) {
                if let (
                    Some(l),
                    Outbound::VisionPositionEstimate {
                        t_us,
                        p_ned_m,
                        rpy_rad,
                        covariance,
                        reset_counter,
                    },
                ) = (&self.log, &o)
                {
                    l.log(
                        Topic::OutputVpe,
                        m.t_s,
                        &records::Vpe {
                            usec: *t_us,
                            p_ned_m: p_ned_m.as_slice(),
                            rpy_rad: rpy_rad.as_slice(),
                            covariance: covariance.as_slice(),
                            reset_counter: *reset_counter,
                        },
                    );
                }
                if out.try_send(o).is_err() {
                    counters.add("output_queue_full", 1);
                }
            }
        }
    }

    /// Starts the filter: static (roll, pitch and gyro bias from the IMU,
    /// yaw from the autopilot) when the vehicle is still, otherwise from the
    /// autopilot's attitude and local velocity (an in-flight start).
    fn try_init(&mut self, m: ImuMeas, counters: &Counters) {
        self.static_buf.push_back(m);
        let window = self.cfg.init.static_window_s;
        while self.static_buf.front().is_some_and(|f| m.t_s - f.t_s > window) {
            self.static_buf.pop_front();
        }
        let Some((roll, pitch, yaw)) = self.attitude else {
            return;
        };
        if self.static_buf.len() < 10 || m.t_s - self.static_buf[0].t_s < 0.9 * window {
            return;
        }
        let n = self.static_buf.len() as f64;
        let acc = self.static_buf.iter().map(|s| s.accel_mps2).sum::<Vector3<f64>>() / n;
        let gyr = self.static_buf.iter().map(|s| s.gyro_radps).sum::<Vector3<f64>>() / n;
        let gyr_var = self
            .static_buf
            .iter()
            .map(|s| (s.gyro_radps - gyr).norm_squared())
            .sum::<f64>()
            / n;
        // Constant velocity looks static to an IMU: trust the autopilot's
        // velocity when it has one.
        let is_static = gyr.norm() < 0.05
            && gyr_var < 1e-3
            && (acc.norm() - self.cfg.imu.gravity_mps2).abs() < 0.3
            && self.local.is_none_or(|(_, v, _)| v.norm() < 0.3);
        // The autopilot's position, carried to this sample's time (its
        // LOCAL_POSITION_NED comes at 10 Hz: 1.5 m old at 15 m/s otherwise).
        let (p, v) = match self.local {
            Some((p, v, t)) if (m.t_s - t).abs() < 1.0 => (p + v * (m.t_s - t), v),
            Some((p, v, _)) => (p, v),
            None => (Vector3::zeros(), Vector3::zeros()),
        };
        let mut p0 = self.cfg.initial_covariance();
        let (q, b_g, v) = if is_static {
            match attitude_from_static(&acc, yaw) {
                Some(q) => (q, gyr, Vector3::zeros()),
                None => return,
            }
        } else {
            if self.local.is_none() {
                return;
            }
            // In flight: the autopilot's attitude, looser.
            for k in 0..3 {
                p0[(k, k)] *= 4.0;
                p0[(3 + k, 3 + k)] = 0.2f64.powi(2);
            }
            (UnitQuaternion::from_euler_angles(roll, pitch, yaw), Vector3::zeros(), v)
        };
        let x0 = ImuState {
            q_W_B: q,
            v_B_in_W: v,
            p_B_in_W: p,
            b_g,
            b_a: Vector3::zeros(),
        };
        let mut est = Estimator::new(self.cfg.estimator_settings(), m.t_s, x0, &p0);
        est.set_async_rebase(!matches!(self.rebase, RebaseExec::Inline));
        self.est_gen += 1;
        let _ = est.add_imu(m);
        self.est = Some(est);
        self.static_buf.clear();
        self.pending.retain(|(t, _)| *t >= m.t_s);
        let _ = counters;
        counters.add(if is_static { "init_static" } else { "init_in_flight" }, 1);
        self.log_text(
            2,
            m.t_s,
            if is_static {
                "filter initialised (static start)"
            } else {
                "filter initialised in flight"
            },
        );
        tracing::info!(static_start = is_static, t_s = m.t_s, "filter initialised");
    }
}

/// Euler (ZYX) angles of `q` and the map `M` from `[droll, dpitch, dyaw]` to
/// the world-frame rotation error: `δθ = dyaw ẑ + dpitch Rz ŷ + droll Rz Ry x̂`.
fn euler_and_map(q: &UnitQuaternion<f64>) -> (Vector3<f64>, Matrix3<f64>) {
    let (r, p, y) = q.euler_angles();
    let rz = UnitQuaternion::from_euler_angles(0.0, 0.0, y);
    let rzy = UnitQuaternion::from_euler_angles(0.0, p, y);
    let m = Matrix3::from_columns(&[rzy * Vector3::x(), rz * Vector3::y(), Vector3::z()]);
    (Vector3::new(r, p, y), m)
}

/// Upper triangle, row-major, of a 6×6 matrix (MAVLink's 21-float layout).
pub fn upper21(c: &Matrix6<f64>) -> [f32; 21] {
    let mut out = [0.0f32; 21];
    let mut k = 0;
    for i in 0..6 {
        for j in i..6 {
            out[k] = c[(i, j)] as f32;
            k += 1;
        }
    }
    out
}

/// The messages for one output instant: `VISION_POSITION_ESTIMATE` (and
/// `ODOMETRY` if asked). `cov` is the pose covariance `[δθ, δp]`.
pub fn outputs(x: &ImuState, cov: &Matrix6<f64>, t_s: f64, reset_counter: u8, odometry: bool) -> Vec<Outbound> {
    let (rpy, m) = euler_and_map(&x.q_W_B);
    let minv = m.try_inverse().unwrap_or_else(Matrix3::identity);
    // Covariance of [x y z roll pitch yaw] from that of [δθ, δp].
    let mut t = Matrix6::zeros();
    t.fixed_view_mut::<3, 3>(0, 3).copy_from(&Matrix3::identity());
    t.fixed_view_mut::<3, 3>(3, 0).copy_from(&minv);
    let c = t * cov * t.transpose();
    let t_us = (t_s * 1e6).round() as u64;
    let mut v = vec![Outbound::VisionPositionEstimate {
        t_us,
        p_ned_m: x.p_B_in_W,
        rpy_rad: rpy,
        covariance: upper21(&c),
        reset_counter,
    }];
    if odometry {
        // ODOMETRY wants its pose covariance in the same [x y z r p y] order.
        let q = x.q_W_B.coords;
        v.push(Outbound::Odometry {
            t_us,
            p_ned_m: x.p_B_in_W,
            q_wxyz: [q.w as f32, q.x as f32, q.y as f32, q.z as f32],
            v_body_mps: x.q_W_B.inverse_transform_vector(&x.v_B_in_W),
            w_body_radps: Vector3::zeros(),
            pose_covariance: upper21(&c),
            velocity_covariance: [f32::NAN; 21],
            reset_counter,
        });
    }
    v
}

/// The log records of the channels written at IMU or camera rate, serialised
/// straight from borrowed data: building a `serde_json::Value` first costs
/// an allocation per field and per feature. The JSON is that of the
/// channels' schemas (`io::mcap_log`).
mod records {
    use serde::Serialize;

    #[derive(Serialize)]
    pub struct Imu<'a> {
        pub t_us: u64,
        pub accel_mps2: &'a [f64],
        pub gyro_radps: &'a [f64],
    }

    #[derive(Serialize)]
    pub struct Features<'a> {
        pub t_us: u64,
        pub t_ap_us: i64,
        pub cam: u32,
        /// `[landmark_id, u_px, v_px]` each.
        pub features: &'a [(u64, f64, f64)],
    }

    #[derive(Clone, Copy, Serialize)]
    pub struct Stamp {
        pub sec: u64,
        pub nsec: u64,
    }

    #[derive(Clone, Copy, Serialize)]
    pub struct Xyz {
        pub x: f64,
        pub y: f64,
        pub z: f64,
    }

    #[derive(Clone, Copy, Serialize)]
    pub struct Quat {
        pub x: f64,
        pub y: f64,
        pub z: f64,
        pub w: f64,
    }

    #[derive(Serialize)]
    pub struct PoseBody {
        pub position: Xyz,
        pub orientation: Quat,
    }

    /// foxglove.PoseInFrame.
    #[derive(Serialize)]
    pub struct Pose<'a> {
        pub timestamp: Stamp,
        pub frame_id: &'a str,
        pub pose: PoseBody,
    }

    /// foxglove.FrameTransform.
    #[derive(Serialize)]
    pub struct Transform<'a> {
        pub timestamp: Stamp,
        pub parent_frame_id: &'a str,
        pub child_frame_id: &'a str,
        pub translation: Xyz,
        pub rotation: Quat,
    }

    #[derive(Serialize)]
    pub struct Vpe<'a> {
        pub usec: u64,
        pub p_ned_m: &'a [f64],
        pub rpy_rad: &'a [f64],
        /// Upper triangle of the 6×6 covariance, as sent.
        pub covariance: &'a [f32],
        pub reset_counter: u8,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Euler-angle map against finite differences.
    #[test]
    fn euler_map_matches_finite_differences() {
        let q = UnitQuaternion::from_euler_angles(0.2, -0.3, 1.2);
        let (rpy, m) = euler_and_map(&q);
        let h = 1e-6;
        for k in 0..3 {
            let mut d = rpy;
            d[k] += h;
            let qp = UnitQuaternion::from_euler_angles(d.x, d.y, d.z);
            let dth = (qp * q.inverse()).scaled_axis() / h;
            assert!((dth - m.column(k)).norm() < 1e-5, "{k}: {dth} vs {}", m.column(k));
        }
        let o = outputs(
            &ImuState {
                q_W_B: q,
                v_B_in_W: Vector3::zeros(),
                p_B_in_W: Vector3::new(1.0, 2.0, 3.0),
                b_g: Vector3::zeros(),
                b_a: Vector3::zeros(),
            },
            &(Matrix6::identity() * 0.01),
            1.5,
            2,
            false,
        );
        let Outbound::VisionPositionEstimate {
            t_us,
            covariance,
            reset_counter,
            ..
        } = &o[0]
        else {
            panic!()
        };
        assert_eq!(*t_us, 1_500_000);
        assert_eq!(*reset_counter, 2);
        // Position variances come first.
        assert!((covariance[0] - 0.01).abs() < 1e-9 && covariance.iter().all(|v| v.is_finite()));
    }
}
