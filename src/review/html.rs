//! `review --html`: one self-contained page to look at after a flight. Why
//! it exists: a summary in JSON and four loose PNGs are for scripts; a
//! person reviewing a flight wants one file to open (or mail) that needs no
//! network at view time. The page holds the summary table, the plots as
//! inline PNG (`data:` URIs, base64), the input rates, every rejection with
//! its reason, and every counter of the daemon.

use std::fmt::Write as _;
use std::path::Path;

use super::ReviewSummary;

/// Standard base64 (RFC 4648, with padding), for the inline images.
fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let n =
            (u32::from(c[0]) << 16) | (u32::from(*c.get(1).unwrap_or(&0)) << 8) | u32::from(*c.get(2).unwrap_or(&0));
        for k in 0..4 {
            if k <= c.len() {
                out.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// Text made safe for HTML.
fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A two-column table of `rows`.
fn table(title: &str, rows: &[(String, String)]) -> String {
    let mut t = format!("<section><h2>{}</h2><table>", esc(title));
    if rows.is_empty() {
        t += "<tr><td colspan=2><i>none</i></td></tr>";
    }
    for (k, v) in rows {
        let _ = write!(t, "<tr><th>{}</th><td>{}</td></tr>", esc(k), esc(v));
    }
    t + "</table></section>"
}

/// The page for the log `name` with summary `s`, the plots read from
/// `plots_dir` (the four PNGs of [`super::plots`]).
pub(super) fn page(name: &str, s: &ReviewSummary, plots_dir: &Path) -> std::io::Result<String> {
    let summary = [
        ("log", name.to_string()),
        ("duration", format!("{:.1} s", s.duration_s)),
        ("messages", s.messages.to_string()),
        (
            "complete",
            if s.truncated {
                "no: the writer was killed; read to its last whole chunk (cmsckf log recover repairs the file)".into()
            } else {
                "yes".into()
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
    ]
    .map(|(k, v)| (k.to_string(), v));
    let rates: Vec<(String, String)> = s
        .input_rates_hz
        .iter()
        .map(|(k, v)| (k.clone(), format!("{v:.1} Hz")))
        .collect();
    let rejected: Vec<(String, String)> = s.rejected.iter().map(|(k, v)| (k.clone(), v.to_string())).collect();
    let counters: Vec<(String, String)> = s.counters.iter().map(|(k, v)| (k.clone(), v.to_string())).collect();

    let mut figures = String::new();
    for (file, caption) in [
        ("trajectory.png", "Trajectory from above, to scale: the estimate, its keyframes and the autopilot's own position (in SITL, the truth)"),
        ("figure1.png", "The paper's Figure 1: each keyframe's position σ over time; right, one keyframe with the vision, GNSS and global updates marked"),
        ("nis.png", "NIS per update against its 95 % χ² band"),
        ("timing.png", "Estimator time per camera frame"),
    ] {
        let png = std::fs::read(plots_dir.join(file))?;
        let _ = write!(
            figures,
            "<figure><img alt=\"{file}\" src=\"data:image/png;base64,{}\"><figcaption>{}</figcaption></figure>",
            base64(&png),
            esc(caption)
        );
    }
    Ok(format!(
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>cmsckf review: {title}</title>\
<style>body{{font-family:sans-serif;margin:2em;max-width:1400px;color:#222}}h1{{font-size:1.6em}}\
h2{{font-size:1.2em;margin-top:1.5em}}table{{border-collapse:collapse;margin:0.5em 0}}\
th,td{{border:1px solid #ccc;padding:3px 10px;text-align:left;font-size:0.9em}}th{{background:#f4f4f4;font-weight:normal}}\
.cols{{display:flex;flex-wrap:wrap;gap:2em}}figure{{margin:1em 0}}img{{max-width:100%;border:1px solid #ddd}}\
figcaption{{font-size:0.9em;color:#555}}</style></head><body>\
<h1>cmsckf flight review: {title}</h1>{summary}<h2>Plots</h2>{figures}\
<div class=\"cols\">{rates}{rejected}{counters}</div></body></html>\n",
        title = esc(name),
        summary = table("Summary", &summary),
        figures = figures,
        rates = table("Input rates", &rates),
        rejected = table("Rejections, by reason", &rejected),
        counters = table("Every counter at the end of the log", &counters),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_rfc4648() {
        // RFC 4648 §10's test vectors.
        for (i, o) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(i.as_bytes()), o);
        }
    }
}
