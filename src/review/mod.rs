//! `cmsckf review`: a flight log's summary, its plots, and a TUM export.
//!
//! Reads a log in file order and stops at the first unreadable record, so a
//! log whose writer was killed (no summary section) is reviewed up to its
//! last complete chunk, and says so. Plots are PNG through `plotters` with a
//! bundled font (DejaVu Sans), so no system font libraries are needed:
//! 1. `trajectory.png`: the estimate from above, to scale, with the keyframes, the
//!    GNSS single-point fixes, the autopilot's local position and a
//!    simulator's truth (`SIM_STATE`);
//! 2. `error.png`: the position error against that truth (else the local
//!    position) over time, with the filter's ±3σ (`error.rs`);
//! 3. `figure1.png`: the paper's Figure 1, the position σ of every keyframe
//!    over time, and a zoom on one keyframe with the vision updates, the GNSS
//!    corrections and the global (compressed) updates marked;
//! 4. `nis.png`: per-update NIS/dof with its 95% χ² band;
//! 5. `timing.png`: a histogram of the estimator time per update.
//!
//! With `--html`, [`review_html`] puts all of it on one self-contained page
//! (`html.rs`).
//!
//! [`review`] reads the log (`reader.rs`), derives the NIS and timing
//! statistics, and writes the TUM file and the plots (`plots.rs`).
//!
//! Log time is the autopilot's clock, which a reboot restarts and a bad
//! stamp can put anywhere: the duration is the time the log's clock
//! segments cover, and the time series keep plausible times only
//! (`timeline.rs`), so one far-future or backwards record changes neither.

mod barometer;
mod chart;
mod error;
mod html;
mod interactive;
mod plots;
mod reader;
mod text;
mod timeline;

use std::collections::BTreeMap;
use std::path::Path;

use plotters::style::FontStyle;
use serde::Serialize;

use cmsckf_models::stats::{chi2_quantile, percentile};

pub use barometer::BarometerGap;
use plots::plot_all;
use reader::{Data, LogReader};

/// Errors of a review.
#[derive(Debug, thiserror::Error)]
pub enum ReviewError {
    #[error("cannot read '{0}': {1}")]
    Io(String, std::io::Error),
    #[error("'{0}' is not an MCAP log: {1}")]
    Mcap(String, String),
    #[error("plotting '{0}': {1}")]
    Plot(String, String),
    #[error("'{0}': {1}")]
    Format(String, crate::io::mcap_log::RecordError),
    #[error(transparent)]
    Check(#[from] crate::io::mcap_log::CheckError),
}

/// The summary `review --json` prints.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ReviewSummary {
    /// The time the records cover (s): the sum over the runs of the log's
    /// clock (a reboot starts a new one), ignoring stray stamps and gaps of
    /// more than 10 s without records.
    pub duration_s: f64,
    pub messages: u64,
    /// The log ended early (no summary): read up to the last whole chunk.
    pub truncated: bool,
    /// Records whose log time is before the one before it in the file: written
    /// out of log-time order (later than the writer's reordering, or off
    /// the clock), or a log of format 2 or older, written as records came.
    pub records_out_of_time_order: u64,
    /// What the check of the file left out (damaged chunks, a broken
    /// length), before anything was read.
    pub log_check: crate::io::mcap_log::CheckReport,
    pub input_rates_hz: BTreeMap<String, f64>,
    pub vision_updates: u64,
    pub tracks_used: u64,
    pub rejected: BTreeMap<String, u64>,
    pub nis_per_dof_mean: f64,
    pub nis_in_95: f64,
    pub update_us_p50: f64,
    pub update_us_p99: f64,
    pub update_us_max: f64,
    pub gnss_updates: u64,
    pub global_updates: u64,
    /// Global keyframes made local for a loop closure (promotion records).
    pub promotions: u64,
    pub keyframes: u64,
    pub estimates: u64,
    /// The 3-D RMS of the position error against a simulator's truth
    /// (`SIM_STATE`) or else the autopilot's local position (m), when the
    /// log has either.
    pub position_error_rms_m: Option<f64>,
    /// The share of those samples with every axis inside ±3σ.
    pub position_error_within_3sigma: Option<f64>,
    /// What the error is measured against, or why there is no error figure.
    pub error_reference: String,
    /// The autopilot EKF's position test ratios of our estimates
    /// (`EKF_STATUS_REPORT`, `ESTIMATOR_STATUS`): how many reports, their
    /// largest horizontal and vertical ratios, and the reports over 1 (the
    /// EKF rejected us).
    pub autopilot_ratio_reports: u64,
    pub autopilot_pos_horiz_ratio_max: Option<f64>,
    pub autopilot_pos_vert_ratio_max: Option<f64>,
    pub autopilot_rejected_reports: u64,
    /// Our height's changes against the autopilot's barometer's
    /// (`SCALED_PRESSURE`; `None` without it): our height's drift, and the
    /// barometer's own.
    pub barometer_gap: Option<barometer::BarometerGap>,
    /// The autopilot's navigation parameters as the daemon last read them
    /// (`PARAM_VALUE`, `daemon/nav_params.rs`), by name; `None` for a value
    /// that was not a number. Empty for a log without them.
    pub autopilot_params: BTreeMap<String, Option<f64>>,
    /// Every counter of the daemon at the log's last `/diagnostics` record
    /// (inputs, rejections by reason, drops).
    pub counters: BTreeMap<String, u64>,
    /// Filter restarts: the reset counter of the last `/diagnostics` record.
    pub resets: u64,
    /// Seconds the daemon said it was degraded, by reason (each
    /// `/diagnostics` record's reasons until the next record).
    pub degraded_s: BTreeMap<String, f64>,
}

/// Reviews `log` and writes one self-contained HTML page to `out` (the
/// summary, the plots inline, rates, rejections and counters; `html.rs`).
pub fn review_html(log: &Path, out: &Path, keyframe: Option<u64>) -> Result<ReviewSummary, ReviewError> {
    let dir = tempfile::tempdir().map_err(|e| ReviewError::Io("a temporary folder".into(), e))?;
    let (s, d, config_toml) = review_data(log, Some(dir.path()), None, keyframe)?;
    let name = log
        .file_name()
        .map_or_else(|| log.display().to_string(), |n| n.to_string_lossy().into_owned());
    let page = html::page(&name, &s, dir.path(), &d, config_toml.as_deref())
        .map_err(|e| ReviewError::Io(dir.path().display().to_string(), e))?;
    std::fs::write(out, page).map_err(|e| ReviewError::Io(out.display().to_string(), e))?;
    Ok(s)
}

/// Reviews `log`; writes the plots to `plots` and the TUM trajectory to
/// `tum` if given. `keyframe` picks the zoomed keyframe of Figure 1.
pub fn review(
    log: &Path,
    plots: Option<&Path>,
    tum: Option<&Path>,
    keyframe: Option<u64>,
) -> Result<ReviewSummary, ReviewError> {
    review_data(log, plots, tum, keyframe).map(|r| r.0)
}

/// [`review`], with the series read and the log's config (TOML), for the
/// page.
fn review_data(
    log: &Path,
    plots: Option<&Path>,
    tum: Option<&Path>,
    keyframe: Option<u64>,
) -> Result<(ReviewSummary, reader::Data, Option<String>), ReviewError> {
    let name = log.display().to_string();
    let checked = crate::io::mcap_log::read_checked(log)?;
    checked.report.warn(&name);
    let bytes = checked.bytes;
    let metadata = crate::io::mcap_log::input::cmsckf_metadata(&bytes).ok().flatten();
    crate::io::mcap_log::input::log_format_of(metadata.as_ref()).map_err(|e| ReviewError::Format(name.clone(), e))?;
    let stream = mcap::MessageStream::new_with_options(&bytes, mcap::read::Options::IgnoreEndMagic.into())
        .map_err(|e| ReviewError::Mcap(name.clone(), e.to_string()))?;
    let mut reader = LogReader::new();
    reader.s.log_check = checked.report.clone();
    reader.s.truncated = !checked.report.finished;
    let (mut previous_log_time, mut out_of_order) = (0u64, 0u64);
    for m in stream {
        let Ok(m) = m else {
            reader.s.truncated = true;
            break;
        };
        // Against the record before (one far-future stamp is one record
        // out of order, not every record after it).
        out_of_order += u64::from(m.log_time < previous_log_time);
        previous_log_time = m.log_time;
        reader.on_message(&m);
    }
    let (mut s, d) = reader.finish();
    s.records_out_of_time_order = out_of_order;
    nis_statistics(&mut s, &d);
    timing_statistics(&mut s, &d);
    error::error_statistics(&mut s, &d);
    s.barometer_gap = barometer::gap(&d);

    if let Some(path) = tum {
        write_tum(path, &d)?;
    }
    if let Some(dir) = plots {
        std::fs::create_dir_all(dir).map_err(|e| ReviewError::Io(dir.display().to_string(), e))?;
        // The bundled font; registering twice is harmless.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular());
        plot_all(dir, &d, keyframe).map_err(|e| ReviewError::Plot(dir.display().to_string(), e))?;
    }
    let config_toml = metadata.and_then(|m| m.get("config_toml").cloned());
    Ok((s, d, config_toml))
}

/// The mean NIS per degree of freedom and the share inside its 95% χ² band.
fn nis_statistics(s: &mut ReviewSummary, d: &Data) {
    if !d.nis.is_empty() {
        s.nis_per_dof_mean = d.nis.iter().map(|x| x.1 / x.2 as f64).sum::<f64>() / d.nis.len() as f64;
        let inside = d
            .nis
            .iter()
            .filter(|x| (chi2_quantile(0.025, x.2)..=chi2_quantile(0.975, x.2)).contains(&x.1))
            .count();
        s.nis_in_95 = inside as f64 / d.nis.len() as f64;
    }
}

/// The median, 99th percentile and maximum of the time per update (µs).
fn timing_statistics(s: &mut ReviewSummary, d: &Data) {
    let mut el = d.elapsed.clone();
    s.update_us_p50 = percentile(&mut el, 0.5).unwrap_or(0.0);
    s.update_us_p99 = percentile(&mut el, 0.99).unwrap_or(0.0);
    s.update_us_max = el.last().copied().unwrap_or(0.0);
}

/// Writes the estimated trajectory to `path` in TUM format.
fn write_tum(path: &Path, d: &Data) -> Result<(), ReviewError> {
    let mut out = String::from("# t x y z qx qy qz qw (world NED, body FRD)\n");
    for (t, n, e, q, dn) in &d.track {
        out += &format!("{t:.6} {n} {e} {dn} {} {} {} {}\n", q[1], q[2], q[3], q[0]);
    }
    std::fs::write(path, out).map_err(|e| ReviewError::Io(path.display().to_string(), e))
}
