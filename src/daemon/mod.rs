//! The daemon: the tasks of `cmsckf run`, their bounded channels, and the
//! fusion loop, one room per concern:
//!
//! - this file: the wiring ([`run`]) and the messages the rooms exchange;
//! - `link.rs`: the MAVLink receive and send tasks; `watchdog.rs`: a
//!   silent autopilot said so, and a long silence made an exit;
//! - `features.rs`: the feature socket and its forwarder;
//! - `gnss_input.rs`: a receiver's RTCM3 stream, and RTCM to GNSS epochs;
//! - `heartbeat.rs`: HEARTBEAT and STATUSTEXT, stream requests, TIMESYNC;
//! - `fusion.rs`: the fusion loop on its own thread;
//! - `autopilot.rs`: what the autopilot tells of itself, and our origin;
//!   `nav_params.rs`: its navigation parameters, read and judged;
//! - `measurements.rs`: fusing the GNSS epochs and frames IMU covers;
//! - `init.rs`: starting the filter, and the one restart path (from our
//!   own estimate, never the autopilot's echo); `output.rs`: the estimates sent;
//! - `rebase.rs`: compressed mode's global updates on a worker thread;
//! - `records.rs`: the log records written at IMU and camera rate;
//! - `time_guard.rs`: time sanity, one bad stamp rejected, jumps confirmed;
//! - `service.rs`: systemd's READY and watchdog.
//!
//! The estimator is CPU work and must never stall the I/O tasks, so it runs
//! on its own OS thread. Every channel is bounded; when one is full the
//! newest item is dropped and counted. [`run`] returns when its `shutdown`
//! future completes.

mod autopilot;
mod base_use;
mod compass;
mod cross_check;
mod estimate_message;
mod features;
mod flight_log;
mod frames;
mod fusion;
mod gnss_input;
mod heartbeat;
mod init;
mod link;
mod measurements;
mod nav_params;
mod output;
mod rebase;
mod records;
mod service;
mod time_guard;
mod watchdog;

use std::future::Future;
use std::path::PathBuf;
use std::sync::atomic::{AtomicI64, AtomicU64, AtomicU8, AtomicUsize};
use std::sync::Arc;
use std::time::Instant;

use nalgebra::Vector3;
use tokio::sync::{mpsc, watch};

use crate::config::{Config, GnssSource};
use crate::counters::Counters;
use crate::estimator::frontend::NormFrame;
use crate::estimator::ImuMeas;
use crate::io::feature_pipe::{self, FeatureFrame};
use crate::io::mavlink as mav;
use crate::io::mcap_log::{LogAlarm, McapLogger};
pub use crate::io::messages::RtcmStream;
use crate::io::messages::{AutopilotKind, Outbound};
use crate::status::Status;

pub use estimate_message::{outputs, upper21};
pub use fusion::{Ctx, Fusion};

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
    #[error("cannot start the fusion thread: {0}")]
    Thread(std::io::Error),
    #[error("MAVLink link lost: {0}")]
    LinkLost(String),
}

/// Handles the fusion thread shares with the I/O tasks.
pub(super) struct Shared {
    pub(super) counters: Counters,
    pub(super) status: Arc<Status>,
    pub(super) mono_offset_us: Arc<AtomicI64>,
    pub(super) start: Instant,
    /// Camera frames in the fusion queue (`FRAMES_IN_FLIGHT`).
    pub(super) frames_queued: Arc<AtomicUsize>,
    /// Inputs the fusion thread has taken (for the service watchdog).
    pub(super) fusion_progress: Arc<AtomicU64>,
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
    /// A simulator's truth (`SIM_STATE`): logged for review, never fused.
    SimState(crate::io::messages::SimTruth),
    /// The autopilot EKF's test ratios of our estimates: only logged.
    EstimatorStatus(crate::io::messages::EstimatorStatus),
    LocalPosition {
        /// Autopilot boot time of the sample (s).
        t_s: f64,
        p_ned_m: Vector3<f64>,
        v_ned_mps: Vector3<f64>,
    },
    /// The autopilot's barometer: logged, and fused as a height with
    /// `barometer.fuse` (estimator README §3g).
    Pressure(crate::io::mcap_log::input::PressureRecord),
    /// The autopilot's magnetometer: the field in the body frame, its
    /// direction only (for the compass yaw of the first start).
    Magnetometer {
        mag_B: Vector3<f64>,
    },
    /// What the autopilot says of itself: armed (its `HEARTBEAT`), on the
    /// ground (`EXTENDED_SYS_STATE`); each `None` when this message does
    /// not say. Zero-velocity updates are for a vehicle on the ground: a
    /// hover is never still.
    VehicleState {
        armed: Option<bool>,
        on_ground: Option<bool>,
        kind: Option<AutopilotKind>,
        /// Its flight mode (`HEARTBEAT.custom_mode`).
        mode: Option<u32>,
    },
    /// One of the autopilot's parameters (`PARAM_VALUE`): its navigation
    /// parameters are judged (`nav_params.rs`), and logged for replay.
    AutopilotParam(crate::io::messages::ParamValue),
    /// A `STATUSTEXT` from the autopilot: only logged.
    AutopilotText {
        severity: u8,
        text: String,
    },
    /// Today, in Unix days, by the companion computer's clock when the
    /// daemon starts (for the declination; logged so replay uses the same).
    Date {
        unix_days: i64,
    },
    /// The autopilot's GNSS accuracy (m, one sigma).
    GpsAccuracy {
        h_acc_m: f64,
        v_acc_m: f64,
    },
    /// A camera frame as received (logged as such) and its features
    /// normalised where it arrived, off the fusion thread.
    Frame(FeatureFrame, NormFrame),
    /// RTCM3 bytes and the stream they came by (which decides whether their
    /// observations may be the rover's).
    Rtcm {
        bytes: Vec<u8>,
        stream: RtcmStream,
    },
    SystemTime {
        unix_us: u64,
        /// The autopilot's boot time (ms), unwrapped past its u32.
        boot_ms: u64,
    },
    Origin {
        lat_deg: f64,
        lon_deg: f64,
        alt_m: f64,
    },
    /// The link to the autopilot went down (`up` false, after `silent_s`
    /// of silence) or came back: a line in the log.
    LinkState {
        up: bool,
        silent_s: f64,
    },
    /// Replay only: the daemon installed rebase `seq` at this point.
    RebaseInstalled {
        seq: u64,
    },
}

/// Bound of the fusion input channel (≈ 8 s of 1 kHz IMU).
pub(super) const FUSION_QUEUE: usize = 8192;
/// Frames waiting for IMU to cover them.
pub(super) const PENDING_FRAMES: usize = 32;
/// Camera frames allowed in the fusion queue at once. A frame there holds
/// its raw and its normalised features (up to `features.max_features` of
/// each); beyond the `PENDING_FRAMES` that can wait for IMU, more would only
/// hold memory, so the forwarder drops them (`fusion_frames_full`).
pub(super) const FRAMES_IN_FLIGHT: usize = 2 * PENDING_FRAMES;
/// An IMU time this far behind the last one is an autopilot reboot (s).
pub(super) const REBOOT_JUMP_S: f64 = 2.0;
/// A longer IMU gap restarts the filter: the motion in between is unknown
/// (s; a 1 s gap is bridged, with a degraded status).
pub(super) const MAX_IMU_GAP_S: f64 = 2.0;

/// Why the filter is restarted (see `Fusion::restart`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Restart {
    /// The autopilot's clock went back.
    Reboot,
    /// Longer than `MAX_IMU_GAP_S` without IMU.
    Gap,
    /// A health check failed (divergence, covariance, state).
    Unhealthy,
    /// The world origin came while standing, after a start without it: a
    /// fresh start (a static window, the compass with its declination),
    /// nothing of the autopilot's forgotten.
    Located,
}

/// The MAVLink signing key, if one is configured (validated with the config;
/// read again here, so a file changed since is still checked).
pub(super) fn signing_key(cfg: &Config) -> Result<Option<[u8; 32]>, DaemonError> {
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
    let link = link::connect(&cfg).await?;
    let listener = feature_pipe::bind(&PathBuf::from(&cfg.features.socket)).await?;
    tracing::info!(address = %cfg.mavlink.address, socket = %cfg.features.socket, mode = cfg.estimator.mode.name(), "cmsckf running");
    if cfg.gnss.source == GnssSource::Mavlink && cfg.gnss.rover_station_id == 0 {
        tracing::warn!(
            "gnss.rover_station_id = 0: RTCM in GPS_RTCM_DATA is taken as a base station's and kept apart, so no \
             GNSS is fused; set gnss.rover_station_id to your receiver's RTCM station id, or gnss.source = \"stream\" \
             for a receiver on the companion"
        );
    }

    let (stop_tx, stop_rx) = watch::channel(false);
    let (fusion_tx, fusion_rx) = mpsc::channel::<FusionMsg>(FUSION_QUEUE);
    let (out_tx, out_rx) = mpsc::channel::<Outbound>(256);
    let status = Arc::new(Status::default());
    // Companion monotonic → autopilot boot clock offset (µs), from TIMESYNC.
    let mono_offset_us = Arc::new(AtomicI64::new(i64::MIN));
    let start = Instant::now();
    let frames_queued = Arc::new(AtomicUsize::new(0));

    // Today's date, for the declination of a compass yaw (the first message:
    // it is logged, so a replay uses the same date).
    if let Ok(since_epoch) = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH) {
        let _ = fusion_tx.try_send(FusionMsg::Date {
            unix_days: (since_epoch.as_secs() / 86_400) as i64,
        });
    }
    let (feat_task, fwd) = features::spawn(&cfg, listener, &fusion_tx, &counters, &stop_rx, frames_queued.clone());
    // The IMU message taken (`mavlink.imu_message`): the receive task sets it
    // when the autopilot says what it is, the stream requests ask for it.
    let imu_message = Arc::new(AtomicU8::new(cfg.mavlink.imu_message.resolve(None).to_u8()));
    let receive = link::Receive {
        imu_message: imu_message.clone(),
        counters: counters.clone(),
        fusion_tx: fusion_tx.clone(),
        mono_offset_us: mono_offset_us.clone(),
        start,
        stop: stop_rx.clone(),
        out_tx: out_tx.clone(),
    };
    let rx_task = link::spawn_receiver(&cfg, link.clone(), receive);
    let (fatal_tx, mut fatal_rx) = watch::channel::<Option<String>>(None);
    let watchdog = watchdog::spawn_watchdog(
        &cfg,
        link.clone(),
        watchdog::Watch {
            counters: counters.clone(),
            status: status.clone(),
            fusion_tx: fusion_tx.clone(),
            fatal: fatal_tx,
            start,
            stop: stop_rx.clone(),
        },
    );
    let stream_task = gnss_input::spawn_stream(&cfg, &fusion_tx, &counters, &stop_rx)?;
    let fusion_weak = fusion_tx.downgrade();
    drop(fusion_tx);
    let tx_task = link::spawn_sender(link, out_rx, counters.clone());
    let status_task = heartbeat::spawn_status(out_tx.clone(), status.clone(), start, stop_rx.clone());
    let periodic = heartbeat::spawn_periodic(
        out_tx.clone(),
        counters.clone(),
        imu_message,
        cfg.mavlink.imu_rate_hz,
        start,
        stop_rx.clone(),
    );
    let fusion_progress = Arc::new(AtomicU64::new(0));

    let shared = Shared {
        counters: counters.clone(),
        status,
        mono_offset_us,
        start,
        frames_queued,
        fusion_progress: fusion_progress.clone(),
    };
    // The log's writer raises a write failure (a full disk) at once: status
    // bit, counters and a STATUSTEXT of its own.
    let log_alarm = LogAlarm {
        status: shared.status.clone(),
        counters: counters.clone(),
        out: out_tx.clone(),
    };
    // The live view (off by default): the log's records, streamed.
    let live = if cfg.live_view.enabled {
        let address = cfg.live_view.address.parse().map_err(|_| {
            DaemonError::Config(format!(
                "live_view.address: '{}' is not HOST:PORT; use e.g. 127.0.0.1:8765",
                cfg.live_view.address
            ))
        })?;
        Some(
            crate::io::live_view::LiveView::start(address)
                .await
                .map_err(|e| DaemonError::Config(e.to_string()))?,
        )
    } else {
        None
    };
    let tap = live
        .as_ref()
        .map(|l| Box::new(l.sink()) as Box<dyn crate::io::mcap_log::RecordTap>);
    let log = open_log(&cfg, log_alarm, tap)?;
    let fusion = fusion::spawn(cfg.clone(), fusion_rx, out_tx, shared, log).map_err(DaemonError::Thread)?;
    let notifier = service::spawn_notifier(fusion_progress, fusion_weak, counters.clone(), stop_rx);

    // Until asked to stop, or until the link is lost for good.
    let fatal = tokio::select! {
        _ = shutdown => None,
        f = fatal_rx.wait_for(|f| f.is_some()) => f.ok().and_then(|f| f.clone()),
    };
    tracing::info!("cmsckf shutting down");
    let _ = stop_tx.send(true);
    for t in [rx_task, fwd, periodic, status_task, feat_task, watchdog, notifier] {
        let _ = t.await;
    }
    if let Some((a, b)) = stream_task {
        let _ = a.await;
        let _ = b.await;
    }
    // The fusion thread ends when its input channel closes (all senders gone).
    let _ = tokio::task::spawn_blocking(move || fusion.join()).await;
    let _ = tx_task.await;
    if let Some(l) = live {
        l.stop().await;
    }
    // The feature socket removed itself as its task ended, if the path was
    // still our socket.
    if let Some(why) = fatal {
        return Err(DaemonError::LinkLost(why));
    }
    Ok(RunSummary {
        counters: counters.snapshot(),
    })
}

/// The MCAP flight log, if `log.path` is set. A log that cannot be created
/// (a read-only card, a missing mount) does not stop the daemon: it flies,
/// with the alarm raised at the first write, and the file is tried again
/// every second.
fn open_log(
    cfg: &Config,
    alarm: LogAlarm,
    live: Option<Box<dyn crate::io::mcap_log::RecordTap>>,
) -> Result<Option<McapLogger>, DaemonError> {
    if cfg.log.path.is_empty() {
        return Ok(None);
    }
    let limits = crate::io::mcap_log::LogLimits {
        max_file_bytes: cfg.log.max_file_mb.saturating_mul(1 << 20),
        max_total_bytes: cfg.log.max_total_mb.saturating_mul(1 << 20),
    };
    let (l, opened) = McapLogger::for_flight(&cfg.log.path, limits, &cfg.log_header(), alarm, live)?;
    let path = match opened {
        Ok(p) => {
            tracing::info!(path = %p.display(), "logging to MCAP");
            p
        }
        Err(e) => {
            tracing::error!(pattern = %cfg.log.path, error = %e,
                "ALARM: the MCAP log cannot be created; flying without it, keeping records in memory and retrying \
                 every second (check log.path and its disk)");
            return Ok(Some(l));
        }
    };
    // A log the last run left unfinished (killed, or the power went) has
    // no summary: say so, and how to recover it, before it is forgotten.
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    for old in crate::io::mcap_log::unfinished_logs(&dir, &path, 3) {
        tracing::warn!(
            log = %old.display(),
            "a previous flight log was left unfinished (the daemon was killed or lost power); \
             `cmsckf log recover {} OUT.mcap` rewrites it with indexes and a summary",
            old.display()
        );
    }
    Ok(Some(l))
}
