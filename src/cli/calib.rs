//! `cmsckf calib`: calibration import. `import-kalibr` prints the config
//! sections that Kalibr's `camchain-imucam.yaml` (and `imu.yaml`) give; the
//! parsing, the frame and sign conventions and the checks are in
//! [`cmsckf::config::kalibr`].

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;

use cmsckf::config::kalibr::{ImportOptions, ImuFrame, KalibrImport};
use cmsckf::config::Config;

// The arguments of `cmsckf calib` (a plain comment: a doc comment here would
// replace the subcommand's own help line).
#[derive(clap::Args)]
pub struct CalibArgs {
    #[command(subcommand)]
    cmd: CalibCmd,
}

#[derive(clap::Subcommand)]
enum CalibCmd {
    /// Print the [camera] and [imu] sections and estimator.time_offset_s from
    /// Kalibr's camchain-imucam.yaml (and imu.yaml), as TOML to paste into
    /// the config.
    ImportKalibr(ImportKalibrArgs),
}

#[derive(clap::Args)]
struct ImportKalibrArgs {
    /// Kalibr's camchain-imucam.yaml (from kalibr_calibrate_imu_camera).
    camchain: PathBuf,
    /// Kalibr's imu.yaml (or its imu-*.yaml results): the [imu] noise.
    imu: Option<PathBuf>,
    /// The camera of the chain to import.
    #[arg(long, default_value = "cam0")]
    camera: String,
    /// The axes of the IMU data Kalibr was given: `frd` if the autopilot's
    /// IMU was recorded as it is (HIGHRES_IMU), `flu` if it came through ROS
    /// (MAVROS's /mavros/imu/data_raw is FLU). The IMU must be the
    /// autopilot's: the daemon reads that one.
    #[arg(long, value_enum)]
    imu_frame: FrameArg,
    /// A config whose other [camera] and [imu] keys (pixel_noise_px, model_noise_px, rate_hz,
    /// gravity_mps2) the printed sections keep; default: the defaults.
    #[arg(long)]
    config: Option<PathBuf>,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum FrameArg {
    Frd,
    Flu,
}

/// Runs `cmsckf calib`.
pub fn calib(args: &CalibArgs) -> anyhow::Result<()> {
    match &args.cmd {
        CalibCmd::ImportKalibr(a) => import_kalibr(a),
    }
}

/// Prints the TOML on stdout and any warning on stderr too.
fn import_kalibr(a: &ImportKalibrArgs) -> anyhow::Result<()> {
    let (base, base_origin) = match &a.config {
        Some(p) => (Config::load(p)?, p.display().to_string()),
        None => (Config::default(), "the defaults".to_string()),
    };
    let opts = ImportOptions {
        camera: &a.camera,
        imu_frame: match a.imu_frame {
            FrameArg::Frd => ImuFrame::Frd,
            FrameArg::Flu => ImuFrame::Flu,
        },
        base: &base,
        base_origin: &base_origin,
    };
    let import = KalibrImport::load(&a.camchain, a.imu.as_deref(), &opts)?;
    for w in &import.warnings {
        eprintln!("warning: {w}");
    }
    std::io::stdout()
        .lock()
        .write_all(import.to_toml().as_bytes())
        .context("writing to stdout")?;
    Ok(())
}
