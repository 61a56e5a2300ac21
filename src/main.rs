//! The `cmsckf` command line: `run` (the daemon), `demo` (the daemon and the
//! SITL autopilot over loopback) and `evaluate` (offline accuracy table).

use std::path::PathBuf;

use anyhow::{bail, Context};
use clap::{Parser, Subcommand};

use cmsckf::config::Config;
use cmsckf::estimator::Mode;
use cmsckf::eval;

#[derive(Parser)]
#[command(name = "cmsckf", version, about = "Compressed-MSCKF visual-inertial-GNSS estimator")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run simulated flights through every mode and print the accuracy table.
    Evaluate {
        /// racetrack | figure8 | hover | tum:<path>
        #[arg(long, default_value = "racetrack")]
        scenario: String,
        /// Comma-separated modes: msckf,schmidt,full,compressed.
        #[arg(long, default_value = "msckf,schmidt,full,compressed")]
        modes: String,
        /// Seeds 1..=N.
        #[arg(long, default_value_t = 10)]
        seeds: u64,
        /// Flight length (s); a TUM file defaults to its own span.
        #[arg(long)]
        duration_s: Option<f64>,
        /// Config file (TOML); the defaults otherwise.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Simulator settings (TOML) overriding the defaults.
        #[arg(long)]
        sim_config: Option<PathBuf>,
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
        /// Also write the per-mode rows as CSV.
        #[arg(long)]
        csv: Option<PathBuf>,
        /// Fuse the simulated GNSS pseudoranges and range rates: on | off.
        #[arg(long, default_value = "off")]
        gnss: String,
    },
    /// Decode a recorded RTCM3 file and print one single-point solution per epoch.
    Gnss {
        file: PathBuf,
        /// off | klobuchar | iono-free | auto (RTCM carries no Klobuchar
        /// parameters: klobuchar without them is off with inflated variance).
        #[arg(long, default_value = "auto")]
        iono: String,
        #[arg(long, default_value_t = 10.0)]
        elevation_mask_deg: f64,
        /// Constellations: G (GPS), E (Galileo), or G,E.
        #[arg(long, default_value = "G,E")]
        systems: String,
        /// Full GPS week near the data (resolves MT1019's 10-bit week);
        /// default: today's week.
        #[arg(long)]
        week_hint: Option<u32>,
        /// Only observations of this RTCM station id.
        #[arg(long, default_value_t = 0)]
        station_id: u16,
        /// CSV rows on stdout (counts go to stderr).
        #[arg(long)]
        csv: bool,
    },
    /// Re-run the filter on a flight log's inputs and write a new log.
    Replay {
        input: PathBuf,
        #[arg(long)]
        out: PathBuf,
        /// Another mode (msckf, full, schmidt, compressed).
        #[arg(long)]
        mode: Option<String>,
        /// Another config (the log's own otherwise).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Print {"messages_in","estimates_out","flight_s","wall_s","realtime_factor"}.
        #[arg(long)]
        json: bool,
    },
    /// Summarise a flight log, draw its plots, export its trajectory.
    Review {
        input: PathBuf,
        /// Write trajectory.png, figure1.png, nis.png and timing.png here.
        #[arg(long)]
        plots: Option<PathBuf>,
        /// Export the estimated trajectory in TUM format.
        #[arg(long)]
        tum: Option<PathBuf>,
        /// The keyframe zoomed in Figure 1 (default: the fifth).
        #[arg(long)]
        keyframe: Option<u64>,
        #[arg(long)]
        json: bool,
    },
    /// Run the daemon beside the autopilot until SIGINT or SIGTERM.
    Run {
        #[arg(long, default_value = "config/default.toml")]
        config: PathBuf,
    },
    /// Start the daemon and the SITL autopilot over real loopback UDP and a
    /// real Unix socket, fly the scenario, and print the SITL report.
    Demo {
        #[arg(long, default_value_t = 70.0)]
        duration_s: f64,
        /// Replay speed of the SITL autopilot.
        #[arg(long, default_value_t = 10.0)]
        speedup: f64,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long, default_value = "racetrack")]
        scenario: String,
        #[arg(long, default_value = "compressed")]
        mode: String,
        #[arg(long)]
        config: Option<PathBuf>,
        /// MCAP log path (logging arrives with the logging issue; accepted now).
        #[arg(long)]
        log: Option<PathBuf>,
        /// Print the SITL report as JSON.
        #[arg(long)]
        json: bool,
        /// Inject a fault in the SITL: NAME@START+DURATION (s), repeatable.
        /// Names: link_drop, gnss_outage, camera_outage, imu_gap, nan_imu,
        /// frontend_restart, rtcm_bad_crc, pr_outlier.
        #[arg(long = "fault")]
        faults: Vec<cmsckf_sitl::serve::Fault>,
    },
}

fn init_tracing(default: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}

/// Completes on SIGINT or SIGTERM.
async fn termination() {
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        _ = term => {}
    }
}

/// A free loopback UDP port (bound and released; the daemon binds it next).
fn free_udp_port() -> anyhow::Result<u16> {
    let s = std::net::UdpSocket::bind("127.0.0.1:0")?;
    Ok(s.local_addr()?.port())
}

fn load_config(path: &Option<PathBuf>) -> anyhow::Result<Config> {
    Ok(match path {
        Some(p) => Config::load(p)?,
        None => Config::default(),
    })
}

fn check_duration(d: Option<f64>) -> anyhow::Result<()> {
    if let Some(d) = d {
        if !(d.is_finite() && d > 1.0 && d <= 86_400.0) {
            bail!("--duration-s {d}: give a number of seconds in (1, 86400]");
        }
    }
    Ok(())
}

/// `cmsckf gnss`: decodes a file in stream order and solves each epoch.
fn gnss_file(
    file: &std::path::Path,
    iono: &str,
    mask: f64,
    systems: &str,
    week_hint: Option<u32>,
    station_id: u16,
    csv: bool,
) -> anyhow::Result<()> {
    use cmsckf::gnss::{rtcm, spp, Receiver};
    if !(mask.is_finite() && (0.0..=60.0).contains(&mask)) {
        bail!("--elevation-mask-deg {mask}: give degrees in [0, 60]");
    }
    let iono: cmsckf::gnss::IonoMode = iono.parse().map_err(anyhow::Error::msg)?;
    let systems = cmsckf::gnss::parse_systems(systems).map_err(anyhow::Error::msg)?;
    let bytes = std::fs::read(file).with_context(|| format!("reading {}", file.display()))?;
    let week = week_hint.unwrap_or_else(cmsckf::gnss::gps_week_now);
    let mut rx = Receiver::new(
        spp::SppOptions {
            elevation_mask_deg: mask,
            iono,
            systems,
        },
        week,
        station_id,
    );
    let mut dec = rtcm::RtcmDecoder::new();
    let mut msgs = Vec::new();
    dec.push(&bytes, &mut msgs);
    let mut results = Vec::new();
    for m in msgs {
        rx.push(m, &mut results);
    }
    rx.flush(&mut results);
    use std::io::Write as _;
    let mut out = std::io::stdout().lock();
    if csv {
        writeln!(
            out,
            "gps_week,gps_tow_s,n_sats,ecef_x_m,ecef_y_m,ecef_z_m,lat_deg,lon_deg,height_m,pdop,residual_rms_m"
        )?;
    }
    for r in &results {
        let Ok(s) = &r.fix else { continue };
        let (lat, lon, h) = cmsckf_models::geodesy::ecef_to_llh(&s.r_ecef_m);
        if csv {
            writeln!(
                out,
                "{},{:.3},{},{:.4},{:.4},{:.4},{:.9},{:.9},{:.4},{:.3},{:.4}",
                s.week,
                s.tow_s,
                s.sats.len(),
                s.r_ecef_m.x,
                s.r_ecef_m.y,
                s.r_ecef_m.z,
                lat.to_degrees(),
                lon.to_degrees(),
                h,
                s.pdop,
                s.residual_rms_m
            )?;
        } else {
            let raim = match &s.raim {
                spp::Raim::Passed => "raim ok".to_string(),
                spp::Raim::NotPossible => "raim not possible (no redundant satellite)".to_string(),
                spp::Raim::Excluded(sys, p) => format!("raim excluded {}{p:02}", sys.letter()),
            };
            writeln!(
                out,
                "week {} tow {:>10.3}  {} sats  lat {:>13.8} lon {:>13.8} h {:>9.3} m  PDOP {:>5.2}  rms {:>6.3} m  {}{}",
                s.week, s.tow_s, s.sats.len(), lat.to_degrees(), lon.to_degrees(), h, s.pdop, s.residual_rms_m, raim,
                if s.iono_free { "  iono-free" } else { "" }
            )?;
        }
    }
    let mut counts = String::new();
    for (t, n) in &dec.stats.frames_by_type {
        counts += &format!(" {t}:{n}");
    }
    let report = format!(
        "frames by type:{counts}
CRC failures: {}  undecodable: {}  bytes skipped: {}  truncated tail bytes: {}
epochs: {}  solved: {}  skipped: {:?}  ephemerides: {}  MSMs of unselected systems: {:?}",
        dec.stats.crc_failures,
        dec.stats.undecodable,
        dec.stats.bytes_skipped,
        dec.stats.trailing_bytes,
        rx.stats.epochs,
        rx.stats.solved,
        rx.stats.skipped,
        rx.stats.ephemerides,
        rx.stats.skipped_system
    );
    if csv {
        eprintln!("{report}");
    } else {
        writeln!(out, "{report}")?;
    }
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.cmd {
        Cmd::Evaluate {
            scenario,
            modes,
            seeds,
            duration_s,
            config,
            sim_config,
            json,
            csv,
            gnss,
        } => {
            check_duration(duration_s)?;
            let gnss = match gnss.as_str() {
                "on" => true,
                "off" => false,
                other => bail!("--gnss {other}: use on or off"),
            };
            if seeds == 0 {
                bail!("--seeds must be at least 1");
            }
            let cfg = load_config(&config)?;
            let modes: Vec<Mode> = modes
                .split(',')
                .map(|m| m.trim().parse::<Mode>().map_err(anyhow::Error::msg))
                .collect::<anyhow::Result<_>>()?;
            let mut sim = eval::sim_config_for(&cfg);
            if let Some(p) = sim_config {
                let text = std::fs::read_to_string(&p).with_context(|| format!("reading {}", p.display()))?;
                let over = cmsckf_sitl::config::SimConfig::from_toml(&text)
                    .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
                sim = over;
            }
            let quiet = json;
            let spec = eval::EvalSpec {
                scenario,
                modes,
                seeds,
                duration_s,
                gnss,
            };
            let ev = eval::evaluate(&spec, &cfg, &sim, |msg| {
                if !quiet {
                    eprintln!("{msg}");
                }
            })?;
            if json {
                println!("{}", serde_json::to_string(&ev)?);
            } else {
                print!("{}", ev.table());
            }
            if let Some(p) = csv {
                let mut s = String::from("mode,ate_unaligned_m,ate_aligned_m,rot_rmse_deg,nees_mean,nees_in_bounds,keyframes,loop_closure_updates,global_updates,frame_us_mean,frame_us_p99,max_rel_diff_vs_full\n");
                for (m, r) in &ev.modes {
                    s += &format!(
                        "{m},{},{},{},{},{},{},{},{},{},{},{}\n",
                        r.ate_unaligned_m,
                        r.ate_aligned_m,
                        r.rot_rmse_deg,
                        r.nees_mean,
                        r.nees_in_bounds,
                        r.keyframes,
                        r.loop_closure_updates,
                        r.global_updates,
                        r.frame_us_mean,
                        r.frame_us_p99,
                        r.max_rel_diff_vs_full.map_or(String::new(), |d| d.to_string())
                    );
                }
                std::fs::write(&p, s).with_context(|| format!("writing {}", p.display()))?;
            }
        }
        Cmd::Gnss {
            file,
            iono,
            elevation_mask_deg,
            systems,
            week_hint,
            station_id,
            csv,
        } => gnss_file(&file, &iono, elevation_mask_deg, &systems, week_hint, station_id, csv)?,
        Cmd::Replay {
            input,
            out,
            mode,
            config,
            json,
        } => {
            let mode = mode
                .map(|m| m.parse::<Mode>())
                .transpose()
                .map_err(anyhow::Error::msg)?;
            let cfg = config.map(|p| Config::load(&p)).transpose()?;
            let bar = if json {
                indicatif::ProgressBar::hidden()
            } else {
                let b = indicatif::ProgressBar::new_spinner();
                b.set_style(
                    indicatif::ProgressStyle::with_template("{spinner} replaying: {pos} inputs ({per_sec}) {elapsed}")
                        .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
                );
                b
            };
            let r = cmsckf::replay::replay(&input, &out, mode, cfg, |n| bar.set_position(n))?;
            bar.finish_and_clear();
            if json {
                println!("{}", serde_json::to_string(&r)?);
            } else {
                println!(
                    "{} inputs, {} estimates, {:.1} s of flight in {:.2} s: {:.0}x real time -> {}",
                    r.messages_in,
                    r.estimates_out,
                    r.flight_s,
                    r.wall_s,
                    r.realtime_factor,
                    out.display()
                );
            }
        }
        Cmd::Review {
            input,
            plots,
            tum,
            keyframe,
            json,
        } => {
            let s = cmsckf::review::review(&input, plots.as_deref(), tum.as_deref(), keyframe)?;
            if json {
                println!("{}", serde_json::to_string(&s)?);
            } else {
                if s.truncated {
                    println!("note: the log ends early (no summary): reviewed up to its last complete chunk");
                }
                println!("{}", serde_json::to_string_pretty(&s)?);
                if let Some(p) = plots {
                    println!("plots in {}", p.display());
                }
            }
        }
        Cmd::Run { config } => {
            init_tracing("info");
            let cfg = Config::load(&config)?;
            let rt = tokio::runtime::Runtime::new()?;
            let summary = rt.block_on(cmsckf::daemon::run(cfg, termination()))?;
            tracing::info!(counters = ?summary.counters, "cmsckf stopped");
        }
        Cmd::Demo {
            duration_s,
            speedup,
            seed,
            scenario,
            mode,
            config,
            log,
            json,
            faults,
        } => {
            init_tracing(if json { "error" } else { "info" });
            check_duration(Some(duration_s))?;
            if !(speedup.is_finite() && speedup > 0.0 && speedup <= 1000.0) {
                bail!("--speedup {speedup}: give a factor in (0, 1000]");
            }
            let mut cfg = load_config(&config)?;
            cfg.estimator.mode = mode.parse().map_err(anyhow::Error::msg)?;
            if let Some(l) = &log {
                cfg.log.path = l.display().to_string();
            }
            cfg.log.path = cmsckf::io::mcap_log::expand_path(&cfg.log.path);
            let dir = tempfile::Builder::new().prefix("cmsckf-demo-").tempdir()?;
            let port = free_udp_port()?;
            cfg.mavlink.address = format!("udpin:127.0.0.1:{port}");
            cfg.features.socket = dir.path().join("features.sock").display().to_string();
            cfg.validate().map_err(|e| anyhow::anyhow!("{e}"))?;
            let sim = eval::sim_config_for(&cfg);
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
            let rt = tokio::runtime::Runtime::new()?;
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
                };
                let report = cmsckf_sitl::serve::serve(&opts, &ds).await;
                let _ = stop_tx.send(());
                let summary = daemon.await;
                (report, summary)
            });
            let report = report?;
            let summary = summary?;
            let mut out = serde_json::to_value(&report)?;
            out["daemon_alive"] = serde_json::Value::Bool(summary.is_ok());
            let summary = summary?;
            if json {
                println!("{out}");
            } else {
                println!("{}", serde_json::to_string_pretty(&out)?);
                eprintln!("daemon counters: {:?}", summary.counters);
                if !cfg.log.path.is_empty() {
                    eprintln!("flight log: {}", cfg.log.path);
                }
            }
        }
    }
    Ok(())
}
