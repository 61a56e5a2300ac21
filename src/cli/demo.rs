//! `cmsckf demo`: the daemon and the SITL autopilot in one process, talking
//! over real loopback UDP and a real Unix socket, so that a whole flight can
//! be watched without hardware. Needs the `sim` feature.
//!
//! With `--frontend`, the SITL renders the camera's images instead of
//! writing the feature oracle's tracks, and `cmsckf-frontend`'s own loop
//! (on a thread of this process) tracks them from the camera socket and
//! writes the daemon's feature socket: images → front-end → socket →
//! daemon → autopilot, each link a real Unix socket or UDP.

use std::path::PathBuf;

use anyhow::bail;

use cmsckf::config::Config;
use cmsckf::counters::Counter;
use cmsckf::daemon::RunSummary;
use cmsckf::eval;

// The arguments of `cmsckf demo` (a plain comment: a doc comment here would
// replace the subcommand's own help line).
#[derive(clap::Args)]
pub struct DemoArgs {
    #[arg(long, default_value_t = 70.0)]
    duration_s: f64,
    /// Replay speed of the SITL autopilot [default: 10, or 1 with --frontend].
    #[arg(long)]
    speedup: Option<f64>,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    #[arg(long, default_value = "racetrack")]
    scenario: String,
    #[arg(long, default_value = "compressed")]
    mode: String,
    #[arg(long)]
    config: Option<PathBuf>,
    /// Simulator settings (TOML), e.g. config/sim-calibrated.toml (a
    /// calibrated IMU instead of the default armed multirotor's biased,
    /// vibrating one); the camera and IMU noise stay the config's.
    #[arg(long)]
    sim_config: Option<PathBuf>,
    /// MCAP log path.
    #[arg(long)]
    log: Option<PathBuf>,
    /// Print the SITL report as JSON.
    #[arg(long)]
    json: bool,
    /// Fly on rendered images tracked by cmsckf-frontend instead of the
    /// feature oracle (camera at 20 Hz at most; speed-up 1 unless given).
    #[arg(long)]
    frontend: bool,
    // The help names every fault from the fault list itself.
    #[arg(long = "fault", help = fault_help())]
    faults: Vec<cmsckf_sitl::serve::Fault>,
}

/// `--fault`'s help: the syntax and every fault's name, from
/// [`cmsckf_sitl::serve::FaultKind::ALL`].
fn fault_help() -> String {
    let names: Vec<&str> = cmsckf_sitl::serve::FaultKind::ALL.iter().map(|k| k.name()).collect();
    format!(
        "Inject a fault in the SITL: NAME@START+DURATION (s), repeatable. Names: {} (docs/reliability.md says what each does)",
        names.join(", ")
    )
}

/// Runs `cmsckf demo`: builds the daemon's config for loopback, generates
/// the flight, flies it, and prints the SITL report.
pub fn demo(args: DemoArgs) -> anyhow::Result<()> {
    let DemoArgs {
        duration_s,
        speedup,
        seed,
        scenario,
        mode,
        config,
        sim_config,
        log,
        json,
        frontend,
        faults,
    } = args;
    // Rendering runs faster than real time, not ten times faster.
    let speedup = speedup.unwrap_or(if frontend { 1.0 } else { 10.0 });
    super::init_tracing(if json { "error" } else { "info" });
    super::check_duration(Some(duration_s))?;
    if !(speedup.is_finite() && speedup > 0.0 && speedup <= 1000.0) {
        bail!("--speedup {speedup}: give a factor in (0, 1000]");
    }
    // The feature socket lives in this directory: keep it to the end.
    let (mut cfg, socket_dir, port) = loopback_config(&config, &mode, &log)?;
    if frontend && cfg.camera.rate_hz > 20.0 {
        // The renderer keeps up with 752x480 at 20 Hz on two cores, beside
        // the front-end and the daemon.
        cfg.camera.rate_hz = 20.0;
    }
    let mut sim = eval::sim_config_for(&cfg);
    if let Some(p) = sim_config {
        // The daemon's config describes the sensors; the simulator's, how
        // they and the world behave.
        sim = super::load_sim_config(&p, &sim)?;
        sim.camera = cfg.camera.clone();
        sim.imu = cfg.imu.clone();
    }
    // The antenna's place on the airframe is measured and configured; the
    // camera's time offset is not (the filter estimates it).
    cfg.gnss.p_A_in_B_m = sim.gnss.p_A_in_B_m;
    if !sim.gnss.ionosphere {
        // The simulated sky has no ionosphere: do not inflate for one.
        cfg.gnss.iono = cmsckf::gnss::IonoMode::Off;
    }
    let ds = cmsckf_sitl::dataset::Dataset::generate(&scenario, seed, Some(duration_s), &sim)?;
    if !json {
        eprintln!(
            "cmsckf demo: {scenario}, {duration_s} s at {speedup}x, seed {seed}, mode {}; daemon on {} and {}",
            cfg.estimator.mode.name(),
            cfg.mavlink.address,
            cfg.features.socket
        );
    }
    // Dropped only at the end, after the printing, with whatever the daemon
    // left running.
    let rt = tokio::runtime::Runtime::new()?;
    let camera_socket = frontend.then(|| socket_dir.path().join("camera.sock"));
    let (out, _) = fly(&rt, &cfg, port, speedup, faults, &ds, camera_socket)?;
    if json {
        println!("{out}");
    } else {
        print!("{}", human_report(&out, speedup));
        if !cfg.log.path.is_empty() {
            println!("  flight log: {} (cmsckf review {0})", cfg.log.path);
        }
        println!("  every figure and the daemon's counters: --json");
    }
    Ok(())
}

/// The demo's report for a person: the key figures, each with its unit and
/// a one-line reading (`--json` gives all of them).
fn human_report(out: &serde_json::Value, speedup: f64) -> String {
    let f = |k: &str| out[k].as_f64().unwrap_or(f64::NAN);
    let mut r = String::from("cmsckf demo report\n");
    let mut line = |what: &str, value: String, reading: &str| {
        r.push_str(&format!("  {what:<24} {value:<34} {reading}\n"));
    };
    line(
        "estimates received",
        format!("{:.0} at {:.1} Hz", f("estimates_received"), f("output_rate_hz")),
        &format!("the first {:.2} s into the flight", f("time_to_first_estimate_s")),
    );
    line(
        "position error (ATE)",
        format!("{:.2} m; {:.2} m aligned", f("ate_m"), f("ate_aligned_m")),
        "RMS against the simulator's truth; aligned: after the best yaw and shift (4-DoF)",
    );
    let (nees, in95) = (f("position_nees_mean"), f("position_nees_in95"));
    let reading = if !nees.is_finite() {
        "no estimate to judge"
    } else if nees > 7.8 || in95 < 0.8 {
        "OVERCONFIDENT: the error is larger than the covariance the autopilot is told"
    } else if nees < 1.0 {
        "honest, on the cautious side (3 is exact)"
    } else {
        "honest (3 is exact)"
    };
    line(
        "confidence (NEES)",
        format!("{nees:.2} mean; {:.0} % inside 95 %", 100.0 * in95),
        reading,
    );
    let nis = f("nis_per_dof");
    line(
        "tracks' NIS per dof",
        format!("{nis:.2}"),
        if (0.5..=2.0).contains(&nis) {
            "the pixel noise fits the tracks (1 is exact)"
        } else if nis < 0.5 {
            "the tracks err less than the pixel noise they are weighed with (1 is exact): safe, not tight"
        } else {
            "the tracks err more than the pixel noise says (1 is exact): OVERCONFIDENT"
        },
    );
    let resets = out["reset_count"].as_u64().unwrap_or(0);
    let alive = out["daemon_alive"].as_bool().unwrap_or(false);
    line(
        "filter resets",
        resets.to_string(),
        match (resets, alive) {
            (_, false) => "THE DAEMON DID NOT FINISH CLEANLY",
            (0, _) => "none: the filter ran through",
            _ => "the filter restarted: see status_texts in --json",
        },
    );
    let latency_reading = if speedup > 1.0 {
        format!("at {speedup}x the machine runs {speedup} times a flight's load; --speedup 1 for a flight's figure")
    } else {
        "at 1x, as in flight".to_string()
    };
    line(
        "latency, IMU to estimate",
        format!("p50 {:.2} ms; p99 {:.2} ms", f("latency_ms_p50"), f("latency_ms_p99")),
        &latency_reading,
    );
    let ap = &out["autopilot"];
    if let Some(rms) = ap["position_error_rms_m"].as_f64() {
        line(
            "the autopilot's position",
            format!(
                "{rms:.2} m RMS; {:.2} m max",
                ap["position_error_max_m"].as_f64().unwrap_or(f64::NAN)
            ),
            "the SITL autopilot's EKF, fed with our estimates, against the truth",
        );
    }
    if let Some(faults) = out["faults"].as_array().filter(|a| !a.is_empty()) {
        line(
            "faults injected",
            faults.len().to_string(),
            "per-fault recovery in --json",
        );
    }
    r
}

/// The daemon's config for the demo, checked: `--config` (or the defaults)
/// with `--mode` and `--log`, listening on a free loopback UDP port, its
/// feature socket in a fresh temporary directory. Returns the config, that
/// directory and the port.
fn loopback_config(
    config: &Option<PathBuf>,
    mode: &str,
    log: &Option<PathBuf>,
) -> anyhow::Result<(Config, tempfile::TempDir, u16)> {
    let mut cfg = super::load_config(config)?;
    cfg.estimator.mode = mode.parse().map_err(anyhow::Error::msg)?;
    if let Some(l) = log {
        cfg.log.path = l.display().to_string();
    }
    cfg.log.path = cmsckf::io::mcap_log::expand_path(&cfg.log.path);
    // The daemon never writes over a log (it would take `NAME-1.mcap`), so
    // a name that exists is refused here, where the demo says which file it
    // wrote.
    if std::path::Path::new(&cfg.log.path).exists() {
        anyhow::bail!(
            "--log {}: the file exists; give another name (a flight log is never written over)",
            cfg.log.path
        );
    }
    let dir = tempfile::Builder::new().prefix("cmsckf-demo-").tempdir()?;
    let port = free_udp_port()?;
    cfg.mavlink.address = format!("udpin:127.0.0.1:{port}");
    // The SITL autopilot relays its receiver's RTCM in GPS_RTCM_DATA as
    // station 7: without a configured rover id, that is the rover.
    if cfg.gnss.rover_station_id == 0 {
        cfg.gnss.rover_station_id = cmsckf_sitl::serve::ROVER_STATION_ID;
    }
    cfg.features.socket = dir.path().join("features.sock").display().to_string();
    cfg.validate().map_err(|e| anyhow::anyhow!("{e}"))?;
    Ok((cfg, dir, port))
}

/// A free loopback UDP port (bound and released; the daemon binds it next).
fn free_udp_port() -> anyhow::Result<u16> {
    let s = std::net::UdpSocket::bind("127.0.0.1:0")?;
    Ok(s.local_addr()?.port())
}

/// Flies `ds` on `rt`: starts the daemon, lets the SITL autopilot serve the flight to
/// it on `port` and the feature socket, then stops the daemon. Returns the
/// SITL report (as JSON, with `daemon_alive`) and the daemon's summary.
fn fly(
    rt: &tokio::runtime::Runtime,
    cfg: &Config,
    port: u16,
    speedup: f64,
    faults: Vec<cmsckf_sitl::serve::Fault>,
    ds: &cmsckf_sitl::dataset::Dataset,
    camera_socket: Option<PathBuf>,
) -> anyhow::Result<(serde_json::Value, RunSummary)> {
    let front = camera_socket
        .as_ref()
        .map(|cam_sock| spawn_frontend(cam_sock.clone(), cfg.features.socket.clone().into(), &cfg.camera));
    let (report, summary) = rt.block_on(async {
        let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
        let daemon = tokio::spawn(cmsckf::daemon::run(cfg.clone(), async move {
            let _ = stop_rx.await;
        }));
        // Give the daemon a moment to bind its sockets.
        tokio::time::sleep(std::time::Duration::from_millis(200)).await;
        let opts = cmsckf_sitl::serve::ServeOptions {
            mavlink: format!("udpout:127.0.0.1:{port}"),
            feature_socket: cfg.features.socket.clone().into(),
            speedup,
            faults,
            gnss_stream: None,
            camera_socket,
        };
        let report = cmsckf_sitl::serve::serve(&opts, ds).await;
        let _ = stop_tx.send(());
        let summary = daemon.await;
        (report, summary)
    });
    let report = report?;
    let summary = summary?;
    let mut out = serde_json::to_value(&report)?;
    out["daemon_alive"] = serde_json::Value::Bool(summary.is_ok());
    // How far the simulated lens puts each pixel from where the daemon's
    // calibration does (RMS over the image, px); null for a recorded
    // flight, whose lens is unknown.
    out["lens_rms_px"] = ds.lens_rms_px().into();
    if let Ok(s) = &summary {
        out["daemon_counters"] = serde_json::to_value(&s.counters)?;
        let count = |c: Counter| s.counters.get(c.as_str()).copied().unwrap_or(0);
        out["zupt_updates"] = count(Counter::ZuptUpdates).into();
        // The accepted tracks' NIS per degree of freedom: 1 when the pixel
        // noise fits the front-end's.
        let dof = count(Counter::TrackNisDof);
        out["nis_per_dof"] = if dof > 0 {
            (count(Counter::TrackNisMilli) as f64 / 1000.0 / dof as f64).into()
        } else {
            serde_json::Value::Null
        };
    }
    if let Some(handle) = front {
        let r = handle
            .join()
            .map_err(|_| anyhow::anyhow!("the front-end's thread panicked"))??;
        out["frontend"] = serde_json::json!({
            "frames": r.frames,
            "frames_not_delivered": r.frames_dropped,
            "frames_out_of_order": r.frames_out_of_order,
            "ms_per_frame": r.ms_per_frame(),
            "features_detected": r.tracks.detected,
            "lost_klt": r.tracks.lost_klt,
            "lost_anchor": r.tracks.lost_anchor,
            "lost_warp": r.tracks.lost_warp,
            "lost_ransac": r.tracks.lost_ransac,
            "reidentified": r.tracks.reidentified,
            "reid_refused": r.tracks.reid_refused,
            "reacquired": r.tracks.reacquired,
        });
    }
    let summary = summary?;
    Ok((out, summary))
}

/// Starts `cmsckf-frontend`'s loop on a thread: it connects to the SITL's
/// camera socket (waiting for it to come up) and to the daemon's feature
/// socket, and tracks until the camera's stream ends.
fn spawn_frontend(
    camera_socket: PathBuf,
    feature_socket: PathBuf,
    camera: &cmsckf_models::sensors::CameraConfig,
) -> std::thread::JoinHandle<anyhow::Result<cmsckf_frontend::run::RunReport>> {
    use cmsckf_frontend::run::{run, SocketSink};
    use cmsckf_frontend::source::{SocketSource, Stamp};
    use cmsckf_frontend::tracker::{Tracker, TrackerParams};
    let cam = cmsckf_models::camera::Camera::from_config(camera);
    std::thread::spawn(move || {
        let size = (cam.width_px as usize, cam.height_px as usize);
        let mut source = SocketSource::connect(&camera_socket, std::time::Duration::from_secs(10), Some(size))?;
        let mut sink = SocketSink::connect(&feature_socket)?;
        let mut tracker = Tracker::new(TrackerParams::default(), Some(cam));
        Ok(run(&mut source, &mut tracker, &mut sink, 0, Stamp::Source)?)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_human_report_reads_each_figure_and_flags_overconfidence() {
        let mut out = serde_json::json!({
            "estimates_received": 2073, "output_rate_hz": 30.0, "time_to_first_estimate_s": 0.92,
            "ate_m": 0.75, "ate_aligned_m": 0.39, "position_nees_mean": 2.9, "position_nees_in95": 0.95,
            "nis_per_dof": 0.96, "reset_count": 0, "daemon_alive": true,
            "latency_ms_p50": 0.28, "latency_ms_p99": 2.86, "faults": [],
        });
        let r = human_report(&out, 10.0);
        assert!(
            r.contains("2073 at 30.0 Hz") && r.contains("0.75 m; 0.39 m aligned"),
            "{r}"
        );
        assert!(r.contains("honest (3 is exact)") && r.contains("at 10x"), "{r}");
        assert!(!r.contains("OVERCONFIDENT"), "{r}");
        out["position_nees_mean"] = serde_json::json!(25.0);
        assert!(human_report(&out, 1.0).contains("OVERCONFIDENT"));
    }
}
