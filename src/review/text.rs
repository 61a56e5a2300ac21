//! The review as a person reads it in a terminal: the rows of the HTML
//! page's tables, aligned in two columns, rather than the JSON that scripts
//! get with `--json`. One list of rows serves both.

use std::fmt::Write as _;

use super::ReviewSummary;
use crate::counters::Counter;

impl ReviewSummary {
    /// The summary table: `(what, value with its unit)`.
    pub fn rows(&self) -> Vec<(String, String)> {
        let s = self;
        [
            ("duration", format!("{:.1} s", s.duration_s)),
            ("messages", s.messages.to_string()),
            (
                "complete",
                if !s.log_check.chunks_dropped.is_empty() {
                    format!(
                        "no: {} damaged chunk(s) left out{}",
                        s.log_check.chunks_dropped.len(),
                        s.log_check
                            .chunks_dropped
                            .first()
                            .map_or(String::new(), |(at, why)| format!(" (first at byte {at}: {why})"))
                    )
                } else if s.log_check.framing_broken_at.is_some() && s.log_check.finished {
                    format!(
                        "no: a damaged length at byte {}; {} chunks after it found through the summary",
                        s.log_check.framing_broken_at.unwrap_or(0),
                        s.log_check.chunks_from_summary
                    )
                } else if s.truncated {
                    "no: the writer was killed; read to its last whole chunk (cmsckf log recover repairs the file)"
                        .into()
                } else {
                    "yes".into()
                },
            ),
            (
                "records in log-time order",
                if s.records_out_of_time_order == 0 {
                    "yes".into()
                } else {
                    format!("{} out of order", s.records_out_of_time_order)
                },
            ),
            ("estimates sent", s.estimates.to_string()),
            ("vision updates", s.vision_updates.to_string()),
            ("tracks used", s.tracks_used.to_string()),
            ("NIS / dof, mean", format!("{:.2}", s.nis_per_dof_mean)),
            ("NIS inside its 95 % χ² band", format!("{:.1} %", 100.0 * s.nis_in_95)),
            (
                "update time p50 / p99 / max",
                format!(
                    "{:.0} / {:.0} / {:.0} µs",
                    s.update_us_p50, s.update_us_p99, s.update_us_max
                ),
            ),
            ("GNSS updates", s.gnss_updates.to_string()),
            ("global updates", s.global_updates.to_string()),
            ("promotions", s.promotions.to_string()),
            ("keyframes", s.keyframes.to_string()),
            (
                "position error, RMS",
                s.position_error_rms_m.map_or_else(
                    || s.error_reference.clone(),
                    |v| format!("{v:.3} m against {}", s.error_reference),
                ),
            ),
            (
                "samples inside ±3σ on every axis",
                s.position_error_within_3sigma
                    .map_or_else(|| "-".into(), |v| format!("{:.1} %", 100.0 * v)),
            ),
            (
                "autopilot EKF's test ratios of our position (max horizontal / vertical)",
                match (s.autopilot_pos_horiz_ratio_max, s.autopilot_pos_vert_ratio_max) {
                    (Some(h), Some(v)) => format!(
                        "{h:.2} / {v:.2} over {} reports; {} over 1 (rejected us)",
                        s.autopilot_ratio_reports, s.autopilot_rejected_reports
                    ),
                    _ => "not in the log (no EKF_STATUS_REPORT or ESTIMATOR_STATUS)".into(),
                },
            ),
            (
                "our height's change against the barometer's (max / at the end)",
                self.barometer_gap.map_or_else(
                    || "not in the log (no SCALED_PRESSURE)".into(),
                    |g| {
                        format!(
                            "{:.2} m at {:.0} s / {:+.2} m over {} s{} (a barometer drifts by decimetres too)",
                            g.max_abs_m,
                            g.max_at_s,
                            g.last_m,
                            g.bins,
                            if g.stopped_at_reboot {
                                ", up to the autopilot's reboot"
                            } else {
                                ""
                            }
                        )
                    },
                ),
            ),
            ("the autopilot's navigation parameters", self.params_row()),
        ]
        .map(|(k, v)| (k.to_string(), v))
        .into_iter()
        .collect()
    }

    /// The navigation parameters read, and how many were said to be wrong
    /// (each said in `/log`, on the timeline, with its fix).
    fn params_row(&self) -> String {
        if self.autopilot_params.is_empty() {
            return "not in the log (none read)".into();
        }
        let values: Vec<String> = self
            .autopilot_params
            .iter()
            .map(|(n, v)| v.map_or_else(|| format!("{n} not a number"), |v| format!("{n} = {v}")))
            .collect();
        let wrong = self
            .counters
            .get(Counter::AutopilotParamMisconfigured.as_str())
            .copied()
            .unwrap_or(0);
        format!("{}; {wrong} said to be wrong (see the log's lines)", values.join(", "))
    }

    /// Each input topic's rate.
    pub fn rate_rows(&self) -> Vec<(String, String)> {
        self.input_rates_hz
            .iter()
            .map(|(k, v)| (k.clone(), format!("{v:.1} Hz")))
            .collect()
    }

    /// Every rejection by reason.
    pub fn rejected_rows(&self) -> Vec<(String, String)> {
        self.rejected.iter().map(|(k, v)| (k.clone(), v.to_string())).collect()
    }

    /// Every counter at the end of the log.
    pub fn counter_rows(&self) -> Vec<(String, String)> {
        self.counters.iter().map(|(k, v)| (k.clone(), v.to_string())).collect()
    }

    /// The whole review as aligned text: the summary, the input rates, the
    /// rejections and the counters.
    pub fn text(&self) -> String {
        let mut out = String::new();
        for (title, rows) in [
            ("Summary", self.rows()),
            ("Input rates", self.rate_rows()),
            ("Rejections, by reason", self.rejected_rows()),
            ("Every counter at the end of the log", self.counter_rows()),
        ] {
            let _ = writeln!(out, "{title}");
            if rows.is_empty() {
                let _ = writeln!(out, "  (none)");
            }
            let w = rows.iter().map(|r| r.0.chars().count()).max().unwrap_or(0);
            for (k, v) in &rows {
                let pad = w - k.chars().count();
                let _ = writeln!(out, "  {k}{}  {v}", " ".repeat(pad));
            }
            out.push('\n');
        }
        out
    }
}
