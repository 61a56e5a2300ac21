//! `cmsckf-frontend`: tracks the features of a camera's images and writes
//! them, one protocol line a frame, to the daemon's feature socket (or a
//! file). Image sources: a EuRoC/ASL dataset folder, a camera process on a
//! Unix socket (`image_wire` frames; the SITL's renderer is one), or a V4L2
//! camera.
//!
//! With a camera it never gives up: a camera lost (its process gone, the
//! device unplugged, nothing for 2 s) is opened again with backoff, a bad
//! frame is skipped, a glitched or restarted camera clock is guarded, and a
//! daemon that is not there yet is connected to when it comes. It stops on
//! SIGTERM (or SIGINT). A dataset ends when its frames do.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, Context};
use clap::Parser;

use cmsckf_frontend::run::{run, Sink, SocketSink, WriteSink};
use cmsckf_frontend::source::{EurocSource, FrameSource, Reopening, SocketSource, Stamp, FROZEN_AFTER};
use cmsckf_frontend::tracker::{Tracker, TrackerParams};
use cmsckf_models::camera::Camera;
use cmsckf_models::check::Validate;
use cmsckf_models::sensors::CameraConfig;

/// Track a camera's features and feed them to the cmsckf daemon.
#[derive(Parser)]
#[command(version)]
struct Args {
    /// A EuRoC/ASL dataset folder (the one holding `mav0/`).
    #[arg(long, conflicts_with = "camera_socket")]
    euroc: Option<PathBuf>,
    /// A camera process's Unix socket, writing raw grey frames
    /// (docs/design.md, "Camera images"); waited for, and connected to
    /// again whenever it goes away.
    #[arg(long)]
    camera_socket: Option<PathBuf>,
    /// A Video4Linux2 camera, e.g. /dev/video0, read at the camera model's
    /// size in 8-bit grey (or YUYV's luma), stamped with the kernel's
    /// CLOCK_MONOTONIC capture time: run the daemon with
    /// `features.clock = "monotonic"`.
    #[cfg(feature = "v4l2")]
    #[arg(long, conflicts_with_all = ["euroc", "camera_socket"], requires = "config")]
    v4l2: Option<PathBuf>,
    /// Stamp frames with the source's own time, or with CLOCK_MONOTONIC on
    /// arrival (then set the daemon's `features.clock = "monotonic"`).
    #[arg(long, value_enum, default_value_t = Stamp::Source)]
    stamp: Stamp,
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
    let size = cam.as_ref().map(|c| (c.width_px as usize, c.height_px as usize));
    let mut source: Box<dyn FrameSource> = if let Some(root) = &args.euroc {
        let src = EurocSource::open(root, args.cam, args.realtime)?;
        if src.is_empty() {
            bail!("'{}' lists no frames", root.display());
        }
        Box::new(src)
    } else if let Some(path) = args.camera_socket.clone() {
        Box::new(Reopening::new(Box::new(move || {
            let s = SocketSource::connect(&path, Duration::ZERO, size)?.frozen_after(FROZEN_AFTER)?;
            Ok(Box::new(s) as Box<dyn FrameSource>)
        })))
    } else {
        v4l2_source(&args, size)?
    };
    let mut sink: Box<dyn Sink> = match (&args.socket, &args.out) {
        (Some(s), _) => Box::new(SocketSink::lazy(s)),
        // A line a frame, written as it is tracked: a SIGTERM loses none.
        (None, Some(o)) => Box::new(WriteSink(std::io::LineWriter::new(
            std::fs::File::create(o).with_context(|| format!("cannot create '{}'", o.display()))?,
        ))),
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
    let report = run(source.as_mut(), &mut tracker, sink.as_mut(), args.cam, args.stamp)?;
    eprintln!("{report}");
    Ok(())
}

/// The V4L2 camera, opened again whenever it is lost.
#[cfg(feature = "v4l2")]
fn v4l2_source(args: &Args, size: Option<(usize, usize)>) -> anyhow::Result<Box<dyn FrameSource>> {
    let (Some(dev), Some((w, h))) = (args.v4l2.clone(), size) else {
        bail!("give --euroc DIR, --camera-socket PATH or --v4l2 /dev/videoN (with --config for its size)")
    };
    Ok(Box::new(Reopening::new(Box::new(move || {
        let s = cmsckf_frontend::v4l2::V4l2Source::open(&dev, w as u32, h as u32)?;
        Ok(Box::new(s) as Box<dyn FrameSource>)
    }))))
}

#[cfg(not(feature = "v4l2"))]
fn v4l2_source(_: &Args, _: Option<(usize, usize)>) -> anyhow::Result<Box<dyn FrameSource>> {
    bail!("give --euroc DIR or --camera-socket PATH (this build has no V4L2: build with the v4l2 feature)")
}
