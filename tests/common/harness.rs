//! The daemon binary against the SITL autopilot over loopback: the
//! autopilot's serve options for a daemon's config, a flight served to its
//! end or in the background, and the daemon's end (SIGTERM after the
//! flight, or SIGKILL in the middle of it).
//!
//! The daemon itself starts with [`super::spawn_daemon_binary`] (or its
//! journalled twin) on a [`super::loopback_config`].

use std::process::{Child, ExitStatus};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use cmsckf::config::Config;
use cmsckf_sitl::dataset::Dataset;
use cmsckf_sitl::serve::{serve, Report, ServeOptions};

/// The SITL autopilot's options to fly against the daemon configured by
/// `cfg` (on `port`) at `speedup`: no faults, no GNSS stream, no camera.
pub fn serve_options(cfg: &Config, port: u16, speedup: f64) -> ServeOptions {
    ServeOptions {
        mavlink: format!("udpout:127.0.0.1:{port}"),
        feature_socket: cfg.features.socket.clone().into(),
        speedup,
        faults: Vec::new(),
        gnss_stream: None,
        camera_socket: None,
    }
}

/// Serves `ds` to the end of the flight, on a runtime of its own.
pub fn fly(opts: &ServeOptions, ds: &Dataset) -> Report {
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(serve(opts, ds)).unwrap()
}

/// A flight being served on a thread of its own.
pub struct Background {
    /// When the flight started (wall time).
    pub start: Instant,
    thread: JoinHandle<Report>,
}

/// Starts serving `ds` on a thread of its own.
pub fn fly_in_background(opts: ServeOptions, ds: Dataset) -> Background {
    let start = Instant::now();
    let thread = std::thread::spawn(move || fly(&opts, &ds));
    Background { start, thread }
}

/// Kills the daemon with SIGKILL `after` the flight's start (wall time),
/// waits for it and for the autopilot; returns the flight time of the kill
/// (s): the wall time since the start times `speedup`.
pub fn sigkill_after(daemon: &mut Child, sitl: Background, after: Duration, speedup: f64) -> f64 {
    std::thread::sleep(after);
    let kill_flight_s = sitl.start.elapsed().as_secs_f64() * speedup;
    unsafe {
        libc::kill(daemon.id() as i32, libc::SIGKILL);
    }
    let _ = daemon.wait();
    let _ = sitl.thread.join();
    kill_flight_s
}

/// Stops the daemon with SIGTERM; its exit status.
pub fn sigterm(daemon: &mut Child) -> ExitStatus {
    unsafe {
        libc::kill(daemon.id() as i32, libc::SIGTERM);
    }
    daemon.wait().unwrap()
}

/// Waits for a background flight to end; its report.
#[allow(dead_code)]
pub fn join(b: Background) -> Report {
    b.thread.join().expect("the SITL thread")
}
