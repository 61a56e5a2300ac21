//! `cmsckf gnss`: decodes a recorded RTCM3 file in stream order and prints
//! one single-point solution per epoch (text or CSV), then the decoder's and
//! the receiver's counts. The same receiver model as the daemon's, without
//! the filter: a check of the GNSS path on real data.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{bail, Context};

use cmsckf::gnss::{rtcm, spp, Epoch, Receiver, ReceiverStats};

// The arguments of `cmsckf gnss` (a plain comment: a doc comment here would
// replace the subcommand's own help line).
#[derive(clap::Args)]
pub struct GnssArgs {
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
}

/// The header of the `--csv` rows.
const CSV_HEADER: &str =
    "gps_week,gps_tow_s,n_sats,ecef_x_m,ecef_y_m,ecef_z_m,lat_deg,lon_deg,height_m,pdop,residual_rms_m";

/// Runs `cmsckf gnss`: decodes the file in stream order and solves each
/// epoch, prints the solutions, then the counts (on stderr with `--csv`).
pub fn gnss(args: &GnssArgs) -> anyhow::Result<()> {
    let opts = spp_options(args.elevation_mask_deg, &args.iono, &args.systems)?;
    let file = &args.file;
    let bytes = std::fs::read(file).with_context(|| format!("reading {}", file.display()))?;
    let week = args.week_hint.unwrap_or_else(cmsckf::gnss::gps_week_now);
    let mut rx = Receiver::new(opts, week, args.station_id);
    let mut dec = rtcm::RtcmDecoder::new();
    let results = decode_and_solve(&bytes, &mut dec, &mut rx);
    let mut out = std::io::stdout().lock();
    if args.csv {
        writeln!(out, "{CSV_HEADER}")?;
    }
    for r in &results {
        let Ok(s) = &r.fix else { continue };
        if args.csv {
            write_csv_row(&mut out, s)?;
        } else {
            write_text_row(&mut out, s)?;
        }
    }
    let report = counts_report(&dec.stats, &rx.stats);
    if args.csv {
        eprintln!("{report}");
    } else {
        writeln!(out, "{report}")?;
    }
    Ok(())
}

/// The solver's options from `--elevation-mask-deg`, `--iono` and
/// `--systems`, checked in that order.
fn spp_options(mask_deg: f64, iono: &str, systems: &str) -> anyhow::Result<spp::SppOptions> {
    if !(mask_deg.is_finite() && (0.0..=60.0).contains(&mask_deg)) {
        bail!("--elevation-mask-deg {mask_deg}: give degrees in [0, 60]");
    }
    let iono: cmsckf::gnss::IonoMode = iono.parse().map_err(anyhow::Error::msg)?;
    let systems = cmsckf::gnss::parse_systems(systems).map_err(anyhow::Error::msg)?;
    Ok(spp::SppOptions {
        elevation_mask_deg: mask_deg,
        iono,
        systems,
    })
}

/// Decodes all of `bytes` with `dec`, feeds the messages to `rx` in stream
/// order and flushes it: every epoch, solved or not.
fn decode_and_solve(bytes: &[u8], dec: &mut rtcm::RtcmDecoder, rx: &mut Receiver) -> Vec<Epoch> {
    let mut msgs = Vec::new();
    dec.push(bytes, &mut msgs);
    let mut results = Vec::new();
    for m in msgs {
        rx.push(m, &mut results);
    }
    rx.flush(&mut results);
    results
}

/// One solution as a `--csv` row.
fn write_csv_row(out: &mut impl Write, s: &spp::SppSolution) -> std::io::Result<()> {
    let (lat, lon, h) = cmsckf_models::geodesy::ecef_to_llh(&s.r_ecef_m);
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
    )
}

/// One solution as a line of text, with its RAIM outcome.
fn write_text_row(out: &mut impl Write, s: &spp::SppSolution) -> std::io::Result<()> {
    let (lat, lon, h) = cmsckf_models::geodesy::ecef_to_llh(&s.r_ecef_m);
    let raim = match &s.raim {
        spp::Raim::Passed => "raim ok".to_string(),
        spp::Raim::NotPossible => "raim not possible (no redundant satellite)".to_string(),
        spp::Raim::Excluded(sys, p) => format!("raim excluded {}{p:02}", sys.letter()),
    };
    writeln!(
        out,
        "week {} tow {:>10.3}  {} sats  lat {:>13.8} lon {:>13.8} h {:>9.3} m  PDOP {:>5.2}  rms {:>6.3} m  {}{}",
        s.week,
        s.tow_s,
        s.sats.len(),
        lat.to_degrees(),
        lon.to_degrees(),
        h,
        s.pdop,
        s.residual_rms_m,
        raim,
        if s.iono_free { "  iono-free" } else { "" }
    )
}

/// The decoder's and the receiver's counts, as printed after the solutions.
fn counts_report(dec: &rtcm::DecodeStats, rx: &ReceiverStats) -> String {
    let mut counts = String::new();
    for (t, n) in &dec.frames_by_type {
        counts += &format!(" {t}:{n}");
    }
    format!(
        "frames by type:{counts}
CRC failures: {}  undecodable: {}  bytes skipped: {}  truncated tail bytes: {}
epochs: {}  solved: {}  skipped: {:?}  ephemerides: {}  MSMs of unselected systems: {:?}",
        dec.crc_failures,
        dec.undecodable,
        dec.bytes_skipped,
        dec.trailing_bytes,
        rx.epochs,
        rx.solved,
        rx.skipped,
        rx.ephemerides,
        rx.skipped_system
    )
}
