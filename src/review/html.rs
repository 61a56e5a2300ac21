//! `review --html`: one self-contained page to look at after a flight. Why
//! it exists: a summary in JSON and four loose PNGs are for scripts; a
//! person reviewing a flight wants one file to open (or mail) that needs no
//! network at view time. The page holds the summary table, the interactive
//! plots and the event timeline (`interactive.rs`, drawn by the inlined
//! uPlot: zoom and hover values), the static figures as inline PNG (`data:`
//! URIs, base64), the input rates, every rejection with its reason, every
//! counter of the daemon, and the configuration in force.

use std::fmt::Write as _;
use std::path::Path;

use super::reader::Data;
use super::{interactive, ReviewSummary};
use crate::io::base64::encode as base64;

/// uPlot (MIT; `assets/README.md`), its style, and the page's own script.
const UPLOT_JS: &str = include_str!("assets/uPlot.iife.min.js");
const UPLOT_CSS: &str = include_str!("assets/uPlot.min.css");
const REVIEW_JS: &str = include_str!("assets/review.js");

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
pub(super) fn page(
    name: &str,
    s: &ReviewSummary,
    plots_dir: &Path,
    d: &Data,
    config_toml: Option<&str>,
) -> std::io::Result<String> {
    let mut summary = vec![("log".to_string(), name.to_string())];
    summary.extend(s.rows());
    let rates = s.rate_rows();
    let rejected = s.rejected_rows();
    let counters = s.counter_rows();

    let mut figures = String::new();
    for (file, caption) in [
        ("trajectory.png", "Trajectory from above, to scale: the estimate, its keyframes, the GNSS single-point fixes, the autopilot's own position and, from a simulator, the truth"),
        ("figure1.png", "The paper's Figure 1: each keyframe's position σ over time; right, one keyframe with the vision, GNSS and global updates marked"),
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
figcaption{{font-size:0.9em;color:#555}}pre{{background:#f8f8f8;padding:1em;font-size:0.8em;overflow:auto;max-height:30em}}\
.cmsckf-timeline tr[data-t]{{cursor:pointer}}.cmsckf-timeline tr[data-t]:hover{{background:#eef}}\
.plot{{margin:1em 0}}.plot h3{{font-size:1em;margin:0.3em 0}}{uplot_css}</style></head><body>\
<h1>cmsckf flight review: {title}</h1>{summary}<h2>Over time</h2>\
<p>Drag to zoom, double-click to zoom out; the values under the cursor are in each legend. Vertical lines are the \
timeline's events.</p>{plots}{timeline}<h2>Figures</h2>{figures}\
<div class=\"cols\">{rates}{rejected}{counters}</div>\
<section><h2>Configuration in force</h2><pre>{config}</pre></section>\
<script>{uplot_js}</script><script>{review_js}</script></body></html>\n",
        title = esc(name),
        uplot_css = UPLOT_CSS,
        summary = table("Summary", &summary),
        figures = figures,
        rates = table("Input rates", &rates),
        rejected = table("Rejections, by reason", &rejected),
        counters = table("Every counter at the end of the log", &counters),
        plots = interactive::plots(d),
        timeline = interactive::timeline(&d.events, esc),
        config = esc(config_toml.unwrap_or("(not in the log)")),
        uplot_js = UPLOT_JS,
        review_js = REVIEW_JS,
    ))
}
