//! The interactive part of `review --html`: why it exists is that a pilot
//! reading a bad flight wants to zoom into the second it went wrong and read
//! the values there, and to see what happened around it. Each plot is a
//! JSON element (`<script type="application/json" class="cmsckf-plot">`)
//! that the page's inlined uPlot draws with zoom and hover values; the
//! events are one filterable table whose rows zoom every plot to their time.
//! Everything is inlined: the page needs no network when it is opened.

use std::fmt::Write as _;

use serde::Serialize;

use super::error::errors;
use super::reader::{Data, Event, EventKind};

/// One series of a plot.
#[derive(Serialize)]
struct Series {
    label: String,
    color: &'static str,
    dash: bool,
}

/// A vertical line at an event's time.
#[derive(Serialize)]
struct Marker {
    t: f64,
    label: String,
    color: &'static str,
}

/// A time plot: `y[i][k]` is series `i` at `x[k]` (`None`: a gap).
#[derive(Serialize)]
struct Plot {
    id: String,
    title: String,
    x_label: &'static str,
    y_label: String,
    series: Vec<Series>,
    x: Vec<f64>,
    y: Vec<Vec<Option<f64>>>,
    markers: Vec<Marker>,
}

const BLUE: &str = "#1f77b4";
const ORANGE: &str = "#ff7f0e";
const GREEN: &str = "#2ca02c";
const RED: &str = "#d62728";
const GREY: &str = "#7f7f7f";

/// At most this many points per plot: a long flight is thinned evenly
/// (every k-th sample), so that the page stays light.
const MAX_POINTS: usize = 20_000;

fn series(label: &str, color: &'static str, dash: bool) -> Series {
    Series {
        label: label.to_string(),
        color,
        dash,
    }
}

/// North, east and down σ: the filter's, and the one the autopilot read.
fn sigma_series() -> Vec<Series> {
    vec![
        series("σ north", BLUE, false),
        series("σ east", ORANGE, false),
        series("σ down", GREEN, false),
    ]
}

fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

/// The plot of `rows` (time first), thinned to [`MAX_POINTS`].
fn plot<const N: usize>(
    id: &str,
    title: &str,
    y_label: &str,
    series: Vec<Series>,
    rows: impl Iterator<Item = (f64, [f64; N])>,
    markers: &[Marker],
) -> Plot {
    let rows: Vec<(f64, [f64; N])> = rows.filter(|r| r.0.is_finite()).collect();
    let step = rows.len().div_ceil(MAX_POINTS).max(1);
    let mut x = Vec::new();
    let mut y = vec![Vec::new(); N];
    let mut prev = f64::NEG_INFINITY;
    for (t, v) in rows.iter().step_by(step) {
        // A gap of over a second (an outage, a restart) is drawn as one.
        if *t - prev > 1.0 && prev.is_finite() {
            x.push(0.5 * (prev + *t));
            for yi in y.iter_mut() {
                yi.push(None);
            }
        }
        prev = *t;
        x.push(*t);
        for i in 0..N {
            y[i].push(finite(v[i]));
        }
    }
    Plot {
        id: id.to_string(),
        title: title.to_string(),
        x_label: "log time (s)",
        y_label: y_label.to_string(),
        series,
        x,
        y,
        markers: markers
            .iter()
            .map(|m| Marker {
                t: m.t,
                label: m.label.clone(),
                color: m.color,
            })
            .collect(),
    }
}

/// The events drawn on every plot: restarts, degraded changes, arming and
/// the autopilot's rejections (not the plain log lines).
fn markers(events: &[Event]) -> Vec<Marker> {
    events
        .iter()
        .filter(|e| !matches!(e.kind, EventKind::Log | EventKind::AutopilotText))
        .take(200)
        .map(|e| Marker {
            t: e.t,
            label: e.text.clone(),
            color: match e.kind {
                EventKind::Filter | EventKind::Autopilot => RED,
                EventKind::Degraded => ORANGE,
                _ => GREY,
            },
        })
        .collect()
}

/// Every interactive plot of the log, as the JSON elements of the page.
pub(super) fn plots(d: &Data) -> String {
    let m = markers(&d.events);
    let mut out = Vec::new();
    let (_, reference) = d.reference();
    let e = errors(d);
    if !e.is_empty() {
        out.push(plot(
            "error",
            &format!("Position error against {reference}, with ±3σ"),
            "m",
            vec![
                series("north", BLUE, false),
                series("east", ORANGE, false),
                series("down", GREEN, false),
                series("+3σ north", BLUE, true),
                series("+3σ east", ORANGE, true),
                series("+3σ down", GREEN, true),
            ],
            e.iter()
                .map(|(t, err, s)| (*t, [err[0], err[1], err[2], 3.0 * s[0], 3.0 * s[1], 3.0 * s[2]])),
            &m,
        ));
    }
    out.push(plot(
        "sigma",
        "Position σ the filter claims",
        "m",
        sigma_series(),
        d.sigma_p.iter().map(|(t, s)| (*t, *s)),
        &m,
    ));
    if !d.sent_sigma_p.is_empty() {
        out.push(plot(
            "sigma_sent",
            "Position σ the autopilot read from what we sent (what it weighs us by, before its own floors)",
            "m",
            sigma_series(),
            d.sent_sigma_p.iter().map(|(t, s)| (*t, *s)),
            &m,
        ));
    }
    if !d.autopilot_ratios.is_empty() {
        out.push(plot(
            "autopilot",
            "The autopilot EKF's test ratios of our position (over 1: it rejected us)",
            "test ratio",
            vec![
                series("horizontal", BLUE, false),
                series("vertical", GREEN, false),
                series("gate", RED, true),
            ],
            d.autopilot_ratios.iter().map(|(t, h, v)| (*t, [*h, *v, 1.0])),
            &m,
        ));
    }
    if !d.sent.is_empty() {
        out.push(plot(
            "sent",
            "What we sent: ODOMETRY quality and speed",
            "quality (−1…100); speed (m/s)",
            vec![series("quality", BLUE, false), series("speed (m/s)", ORANGE, false)],
            d.sent.iter().map(|(t, q, s)| (*t, [*q, *s])),
            &m,
        ));
    }
    if !d.nis.is_empty() {
        out.push(plot(
            "nis",
            "Vision innovations: NIS per degree of freedom of each track (1 when honest)",
            "NIS / dof",
            vec![series("track NIS/dof", BLUE, false)],
            d.nis.iter().map(|(t, nis, dof)| (*t, [nis / (*dof).max(1) as f64])),
            &m,
        ));
    }
    if !d.gnss_residuals.is_empty() {
        out.push(plot(
            "gnss",
            "GNSS innovations: residual RMS per epoch, before the update",
            "m ; m/s",
            vec![
                series("code residual RMS (m)", BLUE, false),
                series("range-rate residual RMS (m/s)", ORANGE, false),
            ],
            d.gnss_residuals.iter().map(|(t, c, r)| (*t, [*c, *r])),
            &m,
        ));
    }
    let mut html = String::new();
    for p in out {
        if let Ok(json) = serde_json::to_string(&p) {
            // No `<` at all inside the script element: `</script` would end
            // it and `<!--` would keep it from ending (a log line can hold
            // either); `\u003c` is the same character to JSON.
            let _ = write!(
                html,
                "<script type=\"application/json\" class=\"cmsckf-plot\">{}</script>",
                json.replace('<', "\\u003c")
            );
        }
    }
    html
}

/// The events as a table: kind, time and text, filterable by kind; a click
/// zooms the plots to the row's time.
pub(super) fn timeline(events: &[Event], esc: impl Fn(&str) -> String) -> String {
    let mut t = String::from(
        "<section><h2>Timeline</h2><p>Starts and restarts, degraded states, arming, flight modes and landing, \
         the autopilot rejecting us, what the autopilot said (STATUSTEXT) and the daemon's log lines. Click a \
         row to zoom every plot to it.</p>\
         <table class=\"cmsckf-timeline\"><tr><th>time (s)</th><th>kind</th><th>event</th></tr>",
    );
    if events.is_empty() {
        t += "<tr><td colspan=3><i>none</i></td></tr>";
    }
    for e in events {
        let _ = write!(
            t,
            "<tr data-kind=\"{k}\" data-t=\"{t:.3}\"><td>{t:.2}</td><td>{k}</td><td>{}</td></tr>",
            esc(&e.text),
            k = e.kind.name(),
            t = e.t,
        );
    }
    t + "</table></section>"
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Red-team 16: a log line holding `<!--<script>` or `</script>` became
    /// a plot marker that kept the page's plots from drawing. No `<` is left
    /// inside the JSON elements; the label survives as JSON's `\u003c`.
    #[test]
    fn log_text_cannot_break_the_plot_elements() {
        let mut d = Data::default();
        d.sigma_p.push((1.0, [1.0, 1.0, 1.0]));
        d.events.push(Event {
            t: 1.0,
            kind: EventKind::Filter,
            text: "filter started <!--<script> </script>".into(),
        });
        let html = plots(&d);
        let body = html
            .strip_prefix("<script type=\"application/json\" class=\"cmsckf-plot\">")
            .and_then(|s| s.strip_suffix("</script>"))
            .expect("one element");
        assert!(!body.contains('<'), "{body}");
        let v: serde_json::Value = serde_json::from_str(body).unwrap();
        assert_eq!(v["markers"][0]["label"], "filter started <!--<script> </script>");
    }
}
