//! The position error over time against a reference, with the filter's own
//! 3σ bounds: why this exists is that an accuracy figure alone cannot tell
//! a lucky filter from a consistent one, and a reviewer after a bad flight
//! wants to see when the error left its bounds. The reference is a
//! simulator's truth where the log has it (`SIM_STATE`, which ArduPilot's
//! SITL and ours send), else the autopilot's local position: beside a real
//! autopilot that fuses our output, that is largely our estimate again, so
//! the plot then shows how far the two parted, not the error.

use std::path::Path;

use plotters::prelude::*;

use cmsckf_models::stats::percentile;

use super::chart::{chart, err, range};
use super::reader::Data;
use super::ReviewSummary;

/// `(t, estimate − reference, σ)` (m, NED) at each `/filter/state` record
/// with a σ and a reference within 0.5 s on both sides
/// ([`Data::reference`]).
pub(super) fn errors(d: &Data) -> Vec<(f64, [f64; 3], [f64; 3])> {
    let (reference, _) = d.reference();
    let mut out = Vec::new();
    let (mut j, mut k) = (0, 0);
    for &(t, n, e, _, dn) in &d.track {
        while j < d.sigma_p.len() && d.sigma_p[j].0 < t {
            j += 1;
        }
        let Some(&(ts, sigma)) = d.sigma_p.get(j) else { break };
        if ts != t {
            continue;
        }
        while k + 1 < reference.len() && reference[k + 1].0 < t {
            k += 1;
        }
        let (Some(a), Some(b)) = (reference.get(k), reference.get(k + 1)) else {
            continue;
        };
        if !(a.0 <= t && t <= b.0 && b.0 - a.0 <= 0.5) {
            continue;
        }
        let f = if b.0 > a.0 { (t - a.0) / (b.0 - a.0) } else { 0.0 };
        let r = [0, 1, 2].map(|i| a.1[i] + f * (b.1[i] - a.1[i]));
        let est = [n, e, dn];
        let error = [0, 1, 2].map(|i| est[i] - r[i]);
        if error.iter().chain(sigma.iter()).all(|x| x.is_finite()) {
            out.push((t, error, sigma));
        }
    }
    out
}

/// The error's RMS (3-D, m) and the share of samples inside ±3σ on every
/// axis, into the summary.
pub(super) fn error_statistics(s: &mut ReviewSummary, d: &Data) {
    s.error_reference = d.reference().1.to_string();
    let r = &d.autopilot_ratios;
    s.autopilot_ratio_reports = r.len() as u64;
    s.autopilot_pos_horiz_ratio_max = r.iter().map(|x| x.1).reduce(f64::max);
    s.autopilot_pos_vert_ratio_max = r.iter().map(|x| x.2).reduce(f64::max);
    s.autopilot_rejected_reports = r.iter().filter(|x| x.1 > 1.0 || x.2 > 1.0).count() as u64;
    let e = errors(d);
    if e.is_empty() {
        return;
    }
    let n = e.len() as f64;
    let ms = e.iter().map(|x| x.1.iter().map(|v| v * v).sum::<f64>()).sum::<f64>() / n;
    s.position_error_rms_m = Some(ms.sqrt());
    let inside = e
        .iter()
        .filter(|x| (0..3).all(|i| x.1[i].abs() <= 3.0 * x.2[i]))
        .count();
    s.position_error_within_3sigma = Some(inside as f64 / n);
}

/// `error.png`: north, east and down error over time, each with ±3σ.
pub(super) fn plot_error(dir: &Path, d: &Data) -> Result<(), String> {
    let p = dir.join("error.png");
    let root = BitMapBackend::new(&p, (900, 780)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let e = errors(d);
    if e.is_empty() {
        let style = TextStyle::from(("sans-serif", 20)).color(&BLACK);
        root.draw(&Text::new(
            "No reference position in this log (no SIM_STATE, no LOCAL_POSITION_NED)",
            (40, 380),
            style,
        ))
        .map_err(err)?;
        return root.present().map_err(err);
    }
    let (tl, th) = range(e.iter().map(|x| x.0));
    let panels = root.split_evenly((3, 1));
    for (i, (area, name)) in panels.iter().zip(["north", "east", "down"]).enumerate() {
        // The scale of the flight, not of its first seconds: the 95th
        // percentile of max(|error|, 3σ); the start's wide bounds are cut.
        let mut span: Vec<f64> = e.iter().map(|x| x.1[i].abs().max(3.0 * x.2[i])).collect();
        let lim = percentile(&mut span, 0.95).unwrap_or(1.0).max(1e-3) * 1.3;
        let caption = format!("{name} error against {}, with ±3σ", d.reference().1);
        let mut c = chart(area, &caption, tl..th, -lim..lim)?;
        c.configure_mesh().x_desc("time (s)").y_desc("m").draw().map_err(err)?;
        for sign in [1.0, -1.0] {
            let s = c
                .draw_series(LineSeries::new(
                    e.iter().map(|x| (x.0, (sign * 3.0 * x.2[i]).clamp(-lim, lim))),
                    RED.mix(0.8),
                ))
                .map_err(err)?;
            if sign > 0.0 {
                s.label("±3σ")
                    .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
            }
        }
        let clip = |v: f64| v.clamp(-lim, lim);
        c.draw_series(LineSeries::new(e.iter().map(|x| (x.0, clip(x.1[i]))), &BLUE))
            .map_err(err)?
            .label("estimate − reference")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE));
        c.configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .border_style(BLACK)
            .background_style(WHITE.mix(0.8))
            .draw()
            .map_err(err)?;
    }
    root.present().map_err(err)
}
