//! `cmsckf-frontend`: tracks the features of a camera's images and writes
//! them, one protocol line a frame, to the daemon's feature socket (or a
//! file). Image source today: a EuRoC/ASL dataset folder.

use std::io::Write;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use clap::Parser;

use cmsckf_frontend::tracker::{Tracker, TrackerParams};
use cmsckf_frontend::{euroc, output};
use cmsckf_models::camera::Camera;
use cmsckf_models::check::Validate;
use cmsckf_models::sensors::CameraConfig;

/// Track a camera's features and feed them to the cmsckf daemon.
#[derive(Parser)]
#[command(version)]
struct Args {
    /// A EuRoC/ASL dataset folder (the one holding `mav0/`).
    #[arg(long)]
    euroc: PathBuf,
    /// Which camera of the dataset (`mav0/cam<N>`).
    #[arg(long, default_value_t = 0)]
    cam: u32,
    /// The daemon's config file: its [camera] section is the camera model
    /// (intrinsics, distortion) used to reject outliers.
    #[arg(long)]
    config: Option<PathBuf>,
    /// The daemon's feature socket (`features.socket`).
    #[arg(long, conflicts_with = "out")]
    socket: Option<PathBuf>,
    /// Write the protocol's lines to this file instead.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Pace the frames by their time stamps (else as fast as they track).
    #[arg(long)]
    realtime: bool,
    /// Features kept per frame, at most.
    #[arg(long, default_value_t = 150)]
    max_features: usize,
    /// Pyramid levels.
    #[arg(long, default_value_t = 4)]
    pyramid_levels: usize,
    /// Shortest distance between two features (px).
    #[arg(long, default_value_t = 15.0)]
    min_distance_px: f32,
    /// Do not re-identify old landmarks.
    #[arg(long)]
    no_reid: bool,
}

fn camera(path: &Option<PathBuf>) -> anyhow::Result<Option<Camera>> {
    let Some(path) = path else { return Ok(None) };
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read '{}'", path.display()))?;
    let doc: toml::Value = toml::from_str(&text).with_context(|| format!("'{}' is not TOML", path.display()))?;
    let Some(table) = doc.get("camera") else {
        bail!(
            "'{}' has no [camera] section: add the camera's model, intrinsics and distortion",
            path.display()
        );
    };
    let cfg: CameraConfig = table
        .clone()
        .try_into()
        .with_context(|| format!("'{}', [camera]", path.display()))?;
    cfg.validate("camera")
        .map_err(|e| anyhow::anyhow!("'{}': {e}", path.display()))?;
    Ok(Some(Camera::from_config(&cfg)))
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let cam = camera(&args.config)?;
    let frames = euroc::frames(&args.euroc, args.cam)?;
    if frames.is_empty() {
        bail!("'{}' lists no frames", args.euroc.display());
    }
    let mut sink: Box<dyn Write> = match (&args.socket, &args.out) {
        (Some(s), _) => Box::new(
            std::os::unix::net::UnixStream::connect(s)
                .with_context(|| format!("cannot connect to the daemon's socket '{}'", s.display()))?,
        ),
        (None, Some(o)) => Box::new(std::io::BufWriter::new(
            std::fs::File::create(o).with_context(|| format!("cannot create '{}'", o.display()))?,
        )),
        (None, None) => bail!("give --socket (the daemon's features.socket) or --out FILE"),
    };
    let mut prm = TrackerParams {
        max_features: args.max_features,
        pyramid_levels: args.pyramid_levels,
        ..TrackerParams::default()
    };
    prm.detect.min_distance_px = args.min_distance_px;
    if args.no_reid {
        prm.reid = None;
    }
    let mut tracker = Tracker::new(prm, cam);
    let (start, t0_ns) = (Instant::now(), frames[0].t_ns);
    let mut busy = Duration::ZERO;
    for f in &frames {
        if args.realtime {
            let due = Duration::from_nanos(f.t_ns - t0_ns);
            if let Some(wait) = due.checked_sub(start.elapsed()) {
                std::thread::sleep(wait);
            }
        }
        let img = euroc::read_png(&f.path)?;
        let t = Instant::now();
        let feats = tracker.process(&img);
        busy += t.elapsed();
        output::write_frame(&mut sink, f.t_ns / 1000, args.cam, feats).context("writing a frame")?;
    }
    sink.flush()?;
    let s = tracker.stats;
    eprintln!(
        "{} frames, {:.2} ms a frame tracking; features detected {}, lost by Lucas–Kanade {}, by RANSAC {}, re-identified {}",
        frames.len(),
        busy.as_secs_f64() * 1e3 / frames.len() as f64,
        s.detected,
        s.lost_klt,
        s.lost_ransac,
        s.reidentified
    );
    Ok(())
}
