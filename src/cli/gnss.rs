//! `cmsckf gnss`: decodes a recorded RTCM3 or UBX file (recognised from its
//! bytes) in stream order and prints
//! one single-point solution per epoch (text or CSV), then the decoder's and
//! the receiver's counts. With `--base`, a base station's stream is merged
//! in by time and each epoch also gets its differential solution. The same
//! receiver model as the daemon's, without the filter: a check of the GNSS
//! path on real data.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{bail, Context};

use cmsckf::gnss::rtcm::GnssMessage;
use cmsckf::gnss::{dgnss, rtcm, spp, ubx, Epoch, Receiver, ReceiverStats, StreamDecoder};

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
    /// Constellations, any of G (GPS), E (Galileo), R (GLONASS), C (BeiDou), J (QZSS).
    #[arg(long, default_value = "G,E,R,C,J")]
    systems: String,
    /// Full GPS week near the data (resolves MT1019's 10-bit week);
    /// default: today's week.
    #[arg(long)]
    week_hint: Option<u32>,
    /// Only observations of this RTCM station id.
    #[arg(long, default_value_t = 0)]
    station_id: u16,
    /// A base station's RTCM3 stream (with its MT1005/1006 antenna
    /// position): each epoch also gets the differential solution, and
    /// `--csv` writes that one.
    #[arg(long)]
    base: Option<PathBuf>,
    /// Oldest base epoch a differential solution may use (s).
    #[arg(long, default_value_t = 10.0, allow_negative_numbers = true)]
    base_max_age_s: f64,
    /// The antenna's surveyed ECEF position `X,Y,Z` (m): the distances of
    /// the solutions from it are summarised after them.
    #[arg(long, value_parser = parse_ecef, allow_hyphen_values = true)]
    surveyed_ecef_m: Option<[f64; 3]>,
    /// CSV rows on stdout (counts go to stderr).
    #[arg(long)]
    csv: bool,
}

/// `X,Y,Z` in metres.
fn parse_ecef(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>().map_err(|e| format!("'{x}': {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([x, y, z]),
        _ => Err("give three finite ECEF coordinates in metres: X,Y,Z".into()),
    }
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
    if !(args.base_max_age_s.is_finite() && args.base_max_age_s > 0.0) {
        bail!(
            "--base-max-age-s {}: give a positive number of seconds",
            args.base_max_age_s
        );
    }
    rx.base_limits.max_age_s = args.base_max_age_s;
    let mut dec = StreamDecoder::default();
    let mut base_dec = StreamDecoder::default();
    let base_bytes = match &args.base {
        Some(f) => Some(std::fs::read(f).with_context(|| format!("reading {}", f.display()))?),
        None => None,
    };
    let results = decode_and_solve(&bytes, base_bytes.as_deref(), &mut dec, &mut base_dec, &mut rx);
    let mut out = std::io::stdout().lock();
    if args.csv {
        writeln!(out, "{CSV_HEADER}")?;
    }
    for r in &results {
        let dgnss = r.dgnss.as_ref().and_then(|d| d.as_ref().ok());
        if args.csv {
            // The differential solution when a base is given, else the
            // single-point one.
            let row = if args.base.is_some() {
                dgnss
            } else {
                r.fix.as_ref().ok()
            };
            if let Some(s) = row {
                write_csv_row(&mut out, s)?;
            }
            continue;
        }
        if let Ok(s) = &r.fix {
            write_text_row(&mut out, "SPP  ", s)?;
        }
        if let Some(s) = dgnss {
            write_text_row(&mut out, "DGNSS", s)?;
        }
    }
    let mut report = counts_report(&dec, &rx.stats);
    if let Some(b) = &rx.base {
        report += &base_report(&base_dec, b, &rx.stats);
    }
    if let Some(truth) = args.surveyed_ecef_m {
        report += &surveyed_report(&results, &nalgebra::Vector3::from(truth));
    }
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

/// Decodes all of `bytes` with `dec` (and the base's `base` with
/// `base_dec`), feeds the messages to `rx` in stream order, the two streams
/// merged by time ([`merge_by_time`]), and flushes it: every epoch, solved
/// or not.
fn decode_and_solve(
    bytes: &[u8],
    base: Option<&[u8]>,
    dec: &mut StreamDecoder,
    base_dec: &mut StreamDecoder,
    rx: &mut Receiver,
) -> Vec<Epoch> {
    // In pieces, as a port delivers them: RTCM3 and UBX frames of one
    // stream then stay in their order.
    let mut msgs = Vec::new();
    for piece in bytes.chunks(256) {
        dec.push(piece, &mut msgs);
    }
    let mut base_msgs = Vec::new();
    for piece in base.unwrap_or_default().chunks(256) {
        base_dec.push(piece, &mut base_msgs);
    }
    let mut results = Vec::new();
    for (from_base, m) in merge_by_time(msgs, base_msgs) {
        if from_base {
            rx.push_base(m);
        } else {
            rx.push(m, &mut results);
        }
    }
    rx.flush(&mut results);
    results
}

/// Interleaves a rover stream and a base stream as they would arrive
/// together: each message is stamped with the time of the MSM epoch it
/// follows (its own, for an MSM), and a base message goes first when its
/// stamp is at most [`dgnss::PAIR_TOLERANCE_S`] after the rover's, so a base
/// epoch is there when the rover's epoch of the same instant is solved.
/// Returns `(from the base?, message)` in arrival order.
fn merge_by_time(rover: Vec<GnssMessage>, base: Vec<GnssMessage>) -> Vec<(bool, GnssMessage)> {
    let (r, b) = (stamped(rover), stamped(base));
    let mut out = Vec::with_capacity(r.len() + b.len());
    let (mut r, mut b) = (r.into_iter().peekable(), b.into_iter().peekable());
    loop {
        let take_base = match (r.peek(), b.peek()) {
            (Some((tr, _)), Some((tb, _))) => *tb <= *tr + dgnss::PAIR_TOLERANCE_S,
            (None, Some(_)) => true,
            (Some(_), None) => false,
            (None, None) => break,
        };
        let next = if take_base {
            b.next().map(|(_, m)| (true, m))
        } else {
            r.next().map(|(_, m)| (false, m))
        };
        out.extend(next);
    }
    out
}

/// Each message with the time (s, unwrapped over week ends) of the MSM
/// epoch it follows: its own for an MSM, −∞ before the stream's first.
fn stamped(msgs: Vec<GnssMessage>) -> Vec<(f64, GnssMessage)> {
    let mut t = f64::NEG_INFINITY;
    let mut wraps = 0.0;
    msgs.into_iter()
        .map(|m| {
            if let GnssMessage::Msm(e) = &m {
                let tow = e.tow_s + wraps;
                // A time of week that falls by more than half a week is the next week.
                if tow < t - 302_400.0 {
                    wraps += 604_800.0;
                }
                t = e.tow_s + wraps;
            }
            (t, m)
        })
        .collect()
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

/// One solution as a line of text, with its kind and RAIM outcome.
fn write_text_row(out: &mut impl Write, kind: &str, s: &spp::SppSolution) -> std::io::Result<()> {
    let (lat, lon, h) = cmsckf_models::geodesy::ecef_to_llh(&s.r_ecef_m);
    let raim = match &s.raim {
        spp::Raim::Passed => "raim ok".to_string(),
        spp::Raim::NotPossible => "raim not possible (no redundant satellite)".to_string(),
        spp::Raim::Excluded(sys, p) => format!("raim excluded {}{p:02}", sys.letter()),
    };
    writeln!(
        out,
        "{kind} week {} tow {:>10.3}  {} sats  lat {:>13.8} lon {:>13.8} h {:>9.3} m  PDOP {:>5.2}  rms {:>6.3} m  {}{}",
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

/// The decoders' and the receiver's counts, as printed after the solutions:
/// RTCM3's always, UBX's when the stream has UBX frames.
fn counts_report(dec: &StreamDecoder, rx: &ReceiverStats) -> String {
    format!(
        "format: {}{}{}
epochs: {}  solved: {}  skipped: {:?}  ephemerides: {}  MSMs of unselected systems: {:?}",
        dec.formats(),
        if dec.rtcm_in_use() {
            rtcm_counts(&dec.rtcm.stats)
        } else {
            String::new()
        },
        ubx_counts(&dec.ubx.stats),
        rx.epochs,
        rx.solved,
        rx.skipped,
        rx.ephemerides,
        rx.skipped_system
    )
}

/// RTCM3 frame counts.
fn rtcm_counts(dec: &rtcm::DecodeStats) -> String {
    let mut counts = String::new();
    for (t, n) in &dec.frames_by_type {
        counts += &format!(" {t}:{n}");
    }
    format!(
        "
frames by type:{counts}
CRC failures: {}  undecodable: {}  bytes skipped: {}  truncated tail bytes: {}",
        dec.crc_failures, dec.undecodable, dec.bytes_skipped, dec.trailing_bytes
    )
}

/// UBX frame counts, when there are UBX frames.
fn ubx_counts(u: &ubx::UbxStats) -> String {
    if u.frames_by_id.is_empty() && u.checksum_failures == 0 {
        return String::new();
    }
    let mut counts = String::new();
    for ((c, i), n) in &u.frames_by_id {
        counts += &format!(" {c:02X}-{i:02X}:{n}");
    }
    format!(
        "
UBX frames by class-id:{counts}
UBX checksum failures: {}  oversize: {}  malformed: {}  bytes skipped: {}  truncated tail bytes: {}
UBX measurements of unused systems by gnssId: {:?}  navigation frames not decoded by gnssId: {:?}  \
GPS subframes without preamble: {}  subframe sets of mixed issues: {}",
        u.checksum_failures,
        u.oversize,
        u.malformed,
        u.bytes_skipped,
        u.trailing_bytes,
        u.unused_measurements,
        u.nav_not_decoded,
        u.bad_subframes,
        u.mismatched_issues
    )
}

/// The base stream's counts and the differential solutions'.
fn base_report(dec: &StreamDecoder, b: &dgnss::BaseStation, rx: &ReceiverStats) -> String {
    let positions = b.positions();
    let arp = if positions.is_empty() {
        "no antenna position (MT1005/1006)".to_string()
    } else {
        positions
            .iter()
            .map(|(id, p)| format!("station {id} at ECEF {:.4}, {:.4}, {:.4} m", p.x, p.y, p.z))
            .collect::<Vec<_>>()
            .join("; ")
    };
    format!(
        "
base format: {}{}
base: {arp}  epochs: {}  positions: {} (changes: {})  duplicate epochs: {}  out of order: {}
base position check: {}
differential solutions: {}  skipped: {:?}",
        dec.formats(),
        (rtcm_counts(&dec.rtcm.stats) + &ubx_counts(&dec.ubx.stats)).replace('\n', "\nbase "),
        b.stats.epochs,
        b.stats.positions,
        b.stats.position_changes,
        b.stats.duplicate_epochs,
        b.stats.out_of_order_epochs,
        match b.position_check() {
            dgnss::PositionCheck::Pending => "pending (fewer than 3 fixes of the base)".to_string(),
            dgnss::PositionCheck::Checked {
                horizontal_m,
                vertical_m,
            } => format!(
                "the announced position is {horizontal_m:.2} m horizontally and {vertical_m:.2} m vertically from \
                 the base's own fixes (median of the last 5)"
            ),
        },
        rx.dgnss_solved,
        rx.dgnss_skipped
    )
}

/// The 3-D distances of the single-point and the differential solutions
/// from the antenna's surveyed position: count, median, RMS and maximum.
fn surveyed_report(results: &[Epoch], truth: &nalgebra::Vector3<f64>) -> String {
    let line = |name: &str, mut d: Vec<f64>| {
        if d.is_empty() {
            return format!("\n{name}: no solution");
        }
        d.sort_by(f64::total_cmp);
        let rms = (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt();
        format!(
            "\n{name}: {} epochs, distance from the surveyed position: median {:.3} m, RMS {:.3} m, max {:.3} m",
            d.len(),
            d[d.len() / 2],
            rms,
            d[d.len() - 1]
        )
    };
    let spp = results
        .iter()
        .filter_map(|r| r.fix.as_ref().ok())
        .map(|s| (s.r_ecef_m - truth).norm())
        .collect();
    let dgnss = results
        .iter()
        .filter_map(|r| r.dgnss.as_ref()?.as_ref().ok())
        .map(|s| (s.r_ecef_m - truth).norm())
        .collect();
    let mut out = line("SPP", spp);
    if results.iter().any(|r| r.dgnss.is_some()) {
        out += &line("DGNSS", dgnss);
    }
    out
}
