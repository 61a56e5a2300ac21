//! `cmsckf-sitl`: generate simulated flights (and, later, act as the mock
//! autopilot).

use std::path::PathBuf;

use anyhow::Context;
use clap::{Parser, Subcommand};
use cmsckf_sitl::config::SimConfig;
use cmsckf_sitl::dataset::Dataset;

#[derive(Parser)]
#[command(name = "cmsckf-sitl", version, about = "Simulator and mock autopilot for cmsckf")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Write a simulated flight as CSV: truth.csv, imu.csv, features.csv, gnss.csv.
    Generate {
        /// racetrack | figure8 | hover | tum:<path>
        #[arg(long, default_value = "racetrack")]
        scenario: String,
        /// Flight length (s); a TUM file defaults to its own span.
        #[arg(long)]
        duration_s: Option<f64>,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        /// Simulator settings (TOML); defaults apply to anything left out.
        #[arg(long)]
        config: Option<PathBuf>,
    },
    /// Render the camera's images of a simulated flight as PGM files, and
    /// time the rendering.
    Render {
        /// racetrack | figure8 | hover | tum:<path>
        #[arg(long, default_value = "racetrack")]
        scenario: String,
        #[arg(long, default_value_t = 10.0)]
        duration_s: f64,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output directory (frames are timed, not written, without it).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Write every N-th frame.
        #[arg(long, default_value_t = 1)]
        every: usize,
        #[arg(long)]
        config: Option<PathBuf>,
    },
    /// Act as the autopilot and the camera front end for a running daemon,
    /// then print the score of its estimates.
    Serve {
        /// MAVLink address of the daemon, e.g. udpout:127.0.0.1:14550.
        #[arg(long, default_value = "udpout:127.0.0.1:14550")]
        mavlink: String,
        /// The daemon's feature socket.
        #[arg(long)]
        features: PathBuf,
        #[arg(long, default_value = "racetrack")]
        scenario: String,
        #[arg(long, default_value_t = 70.0)]
        duration_s: f64,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Replay speed (1 = real time).
        #[arg(long, default_value_t = 1.0)]
        speedup: f64,
        #[arg(long)]
        config: Option<PathBuf>,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
        /// Fail (exit 1) if the unaligned ATE is above this (m).
        #[arg(long)]
        max_ate_m: Option<f64>,
        /// Fail if the output rate is below this (Hz).
        #[arg(long)]
        min_rate_hz: Option<f64>,
        /// Fail if the p99 latency is above this (ms).
        #[arg(long)]
        max_latency_ms: Option<f64>,
        /// Serve the rover receiver's RTCM on a TCP listener at HOST:PORT
        /// (the daemon's `gnss.stream = "tcp:HOST:PORT"`) instead of in
        /// GPS_RTCM_DATA.
        #[arg(long)]
        gnss_stream: Option<String>,
        /// Render the camera's images and serve them on a Unix listener at
        /// this path (raw grey, docs/design.md "Camera images") for
        /// `cmsckf-frontend --camera-socket`, instead of writing the oracle's
        /// features to the daemon's socket.
        #[arg(long)]
        camera_socket: Option<PathBuf>,
        /// Inject a fault: NAME@START+DURATION (s of flight), repeatable.
        #[arg(long = "fault")]
        faults: Vec<cmsckf_sitl::serve::Fault>,
    },
}

fn load_sim(config: &Option<PathBuf>) -> anyhow::Result<SimConfig> {
    Ok(match config {
        Some(p) => {
            let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            SimConfig::from_toml(&text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?
        }
        None => SimConfig::new(),
    })
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.cmd {
        Cmd::Generate {
            scenario,
            duration_s,
            seed,
            out,
            config,
        } => {
            if let Some(d) = duration_s {
                anyhow::ensure!(
                    d.is_finite() && d > 0.0 && d <= 86_400.0,
                    "--duration-s {d} must be in (0, 86400]"
                );
            }
            let cfg = match config {
                Some(p) => {
                    let text = std::fs::read_to_string(&p).with_context(|| format!("reading {}", p.display()))?;
                    SimConfig::from_toml(&text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?
                }
                None => SimConfig::new(),
            };
            let ds = Dataset::generate(&scenario, seed, duration_s, &cfg)?;
            ds.write_csv(&out)
                .with_context(|| format!("writing {}", out.display()))?;
            for line in ds.summary() {
                println!("{line}");
            }
            println!("wrote {}", out.display());
        }
        Cmd::Render {
            scenario,
            duration_s,
            seed,
            out,
            every,
            config,
        } => render(&scenario, duration_s, seed, out, every.max(1), &load_sim(&config)?)?,
        Cmd::Serve {
            mavlink,
            features,
            scenario,
            duration_s,
            seed,
            speedup,
            config,
            json,
            max_ate_m,
            min_rate_hz,
            max_latency_ms,
            gnss_stream,
            camera_socket,
            faults,
        } => {
            anyhow::ensure!(
                duration_s.is_finite() && duration_s > 1.0,
                "--duration-s {duration_s} must be > 1"
            );
            anyhow::ensure!(
                speedup.is_finite() && speedup > 0.0 && speedup <= 1000.0,
                "--speedup {speedup} must be in (0, 1000]"
            );
            let cfg = load_sim(&config)?;
            let ds = Dataset::generate(&scenario, seed, Some(duration_s), &cfg)?;
            let rt = tokio::runtime::Runtime::new()?;
            let opts = cmsckf_sitl::serve::ServeOptions {
                mavlink,
                feature_socket: features,
                speedup,
                faults,
                gnss_stream,
                camera_socket,
            };
            let report = rt.block_on(cmsckf_sitl::serve::serve(&opts, &ds))?;
            if json {
                println!("{}", serde_json::to_string(&report)?);
            } else {
                println!("{}", serde_json::to_string_pretty(&report)?);
            }
            let m = report.misses(max_ate_m, min_rate_hz, max_latency_ms);
            if !m.is_empty() {
                anyhow::bail!("thresholds missed: {}", m.join("; "));
            }
        }
    }
    Ok(())
}

/// `cmsckf-sitl render`: every camera frame of the flight rendered, every
/// `every`-th written to `out` as `<t_us>.pgm`; prints the mean time.
fn render(
    scenario: &str,
    duration_s: f64,
    seed: u64,
    out: Option<PathBuf>,
    every: usize,
    cfg: &SimConfig,
) -> anyhow::Result<()> {
    use std::io::Write;
    anyhow::ensure!(
        duration_s.is_finite() && duration_s > 0.0 && duration_s <= 86_400.0,
        "--duration-s {duration_s} must be in (0, 86400]"
    );
    let ds = Dataset::generate(scenario, seed, Some(duration_s), cfg)?;
    let mut r = cmsckf_sitl::render::Renderer::for_dataset(&ds);
    if let Some(dir) = &out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let (mut poses, mut img) = (Vec::new(), Vec::new());
    let start = std::time::Instant::now();
    for (i, f) in ds.frames.iter().enumerate() {
        r.exposure_poses(&ds.trajectory, f.t_exposure_s, &mut poses);
        r.render(&poses, i as u64, &mut img);
        if let (Some(dir), 0) = (&out, i % every) {
            let path = dir.join(format!("{:010}.pgm", (f.t_exposure_s * 1e6).round() as u64));
            let mut file = std::io::BufWriter::new(
                std::fs::File::create(&path).with_context(|| format!("creating {}", path.display()))?,
            );
            write!(file, "P5\n{} {}\n255\n", r.width(), r.height())?;
            file.write_all(&img)?;
        }
    }
    let n = ds.frames.len().max(1);
    println!(
        "{} frames of {}x{} in {:.1} s: {:.1} ms a frame ({} blocks in the world)",
        ds.frames.len(),
        r.width(),
        r.height(),
        start.elapsed().as_secs_f64(),
        start.elapsed().as_secs_f64() * 1e3 / n as f64,
        r.world.blocks.len()
    );
    Ok(())
}
