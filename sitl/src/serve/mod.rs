//! The mock autopilot (`cmsckf-sitl serve`): it stands in for ArduPilot on
//! the MAVLink link and for the camera front end on the feature socket, and
//! scores what the daemon sends back against the truth.
//!
//! Over MAVLink it sends HEARTBEAT (an armed quadrotor), SYSTEM_TIME,
//! HIGHRES_IMU, EXTENDED_SYS_STATE (landed or in the air), SCALED_PRESSURE
//! (a barometer: `crate::barometer`), ATTITUDE and
//! LOCAL_POSITION_NED (its own EKF's view, with a real EKF's
//! errors, following the daemon's estimates as EK3 does: see `autopilot`),
//! answers SET_MESSAGE_INTERVAL and TIMESYNC, and receives
//! VISION_POSITION_ESTIMATE. The flight is replayed at real time or at
//! `speedup`. Times on the wire are the autopilot's boot clock, which starts
//! `BOOT0_S` before the flight.
//!
//! Like a real camera and receiver, the simulated ones are late: each frame
//! reaches the feature socket at its delivery time, stamped with the camera
//! clock's time of its exposure (off the IMU's by the true, unknown offset),
//! and each epoch's RTCM goes out at its delivery time, its MSM7 carrying the
//! epoch's own time.
//!
//! - `stream`: the time-ordered, wall-clock-paced sending loop
//! - `sensors`: the autopilot's own MAVLink streams (IMU, attitude, time)
//! - `autopilot`: the autopilot's own EKF, its errors and how it follows
//!   the daemon
//! - `rtcm`: GNSS observations and ephemerides as `GPS_RTCM_DATA`
//! - `feature_socket`: the camera front end's JSON lines (the oracle)
//! - `camera`: or the camera's rendered images, for a real front-end
//! - `fault`: the injectable faults and what each one does
//! - `receive`: the task answering the daemon and gathering its output
//! - `clock`: the boot clock on the wire and back to flight time
//! - `report`: the scoring

mod autopilot;
mod camera;
mod clock;
mod fault;
mod feature_socket;
mod receive;
mod receiver_port;
mod report;
mod rtcm;
mod sensors;
mod stream;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use mavlink::dialects::ardupilotmega as apm;
use mavlink::{AsyncMavConnection, MavHeader};

use crate::dataset::Dataset;

pub use autopilot::AutopilotReport;
pub use fault::{Fault, FaultKind};
pub use report::{FaultReport, Report};
pub use rtcm::rtcm_fragments;

/// Boot time of the autopilot at the start of the flight (s).
pub const BOOT0_S: f64 = 20.0;
/// RTCM reference-station id of the simulated receiver.
pub const ROVER_STATION_ID: u16 = 7;

/// The MAVLink connection to the daemon.
type Link = mavlink::AsyncConnection<apm::MavMessage>;

/// The header of everything the autopilot sends (system 1, component 1).
const HEADER: MavHeader = MavHeader {
    system_id: 1,
    component_id: 1,
    sequence: 0,
};

/// The header of a ground station injecting a base station's corrections
/// (system 255, component 190, as QGroundControl and Mission Planner do).
const GCS_HEADER: MavHeader = MavHeader {
    system_id: 255,
    component_id: 190,
    sequence: 0,
};

/// A second ground station relaying the same base (`base_doubled`).
const SECOND_GCS_HEADER: MavHeader = MavHeader {
    system_id: 254,
    component_id: 190,
    sequence: 0,
};

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
    /// `Some(address)`: the receiver is wired to the companion rather than
    /// relayed by the autopilot: its RTCM (observations and ephemerides) is
    /// served on a TCP listener at `address` (the daemon's
    /// `gnss.stream = "tcp:…"`), not in `GPS_RTCM_DATA`.
    pub gnss_stream: Option<String>,
    /// `Some(path)`: the camera's images are rendered and served as raw grey
    /// on a Unix listener at `path`, for `cmsckf-frontend` to track and
    /// write to the feature socket; the oracle's features are not sent.
    pub camera_socket: Option<PathBuf>,
}

/// Errors that stop the mock autopilot.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error("MAVLink address '{0}': {1}")]
    Link(String, std::io::Error),
    #[error("GNSS stream listener '{0}': {1}")]
    GnssStream(String, std::io::Error),
    #[error("camera socket '{0}': {1}")]
    Camera(PathBuf, std::io::Error),
}

/// Serves `ds` to the daemon and scores its estimates.
pub async fn serve(opts: &ServeOptions, ds: &Dataset) -> Result<Report, ServeError> {
    let conn = Arc::new(connect(&opts.mavlink).await?);
    let started = Instant::now();
    let reboot_s = fault::reboot_time(&opts.faults);
    let t_start = Instant::now();
    let inbox = receive::Inbox::default();
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    // Receive: answer commands and time sync, collect estimates.
    let rx = receive::spawn_receiver(
        conn.clone(),
        inbox.clone(),
        started,
        t_start,
        opts.speedup,
        opts.faults.clone(),
        stop_rx,
    );
    let receiver_port = match &opts.gnss_stream {
        Some(addr) => Some(
            receiver_port::ReceiverPort::listen(addr)
                .await
                .map_err(|e| ServeError::GnssStream(addr.clone(), e))?,
        ),
        None => None,
    };
    let camera = match &opts.camera_socket {
        Some(path) => {
            let order = stream::delivery_order(ds.frames.iter().map(|f| f.t_delivered_s));
            Some(camera::CameraServer::start(path, ds, &order).map_err(|e| ServeError::Camera(path.clone(), e))?)
        }
        None => None,
    };
    // Stream the flight in time order, paced by the wall clock.
    let mut out = stream::Streamer::new(conn, opts, ds, reboot_s, inbox.clone(), receiver_port, camera);
    out.run(t_start).await;
    // Let the last estimates arrive.
    tokio::time::sleep(Duration::from_millis(300)).await;
    let _ = stop_tx.send(true);
    let _ = rx.await;
    let mut report = report::report(opts, ds, &inbox, reboot_s, &out.sent_wall, out.k_imu, out.frames_sent);
    report.autopilot = out.ekf.report.clone();
    Ok(report)
}

/// Opens the MAVLink link at `address`: MAVLink 2 out, any version in.
async fn connect(address: &str) -> Result<Link, ServeError> {
    let mut conn = mavlink::connect_async::<apm::MavMessage>(address)
        .await
        .map_err(|e| ServeError::Link(address.to_string(), e))?;
    conn.set_protocol_version(mavlink::MavlinkVersion::V2);
    conn.set_allow_recv_any_version(true);
    Ok(conn)
}
