//! The review's four PNG plots (listed in the `review` module's doc),
//! drawn with `plotters` from the [`Data`] read out of the log. Each plot is
//! one function; errors are `plotters`' own, as text.

use std::path::Path;

use plotters::prelude::*;

use cmsckf_models::stats::{chi2_quantile, percentile};

use super::chart::{chart, err, range, Area};
use super::reader::Data;

/// Writes `trajectory.png`, `error.png`, `figure1.png`, `nis.png` and
/// `timing.png` to `dir`; `keyframe` picks Figure 1's zoom.
pub(super) fn plot_all(dir: &Path, d: &Data, keyframe: Option<u64>) -> Result<(), String> {
    plot_trajectory(dir, d)?;
    super::error::plot_error(dir, d)?;
    plot_figure1(dir, d, keyframe)?;
    plot_nis(dir, d)?;
    plot_timing(dir, d)
}

/// Widens the shorter of two spans about its centre so that a metre is as
/// long on both axes of a `w_px` × `h_px` plot, with `top` of the height
/// left free above the data (for the legend).
fn to_scale(x: (f64, f64), y: (f64, f64), w_px: f64, h_px: f64, top: f64) -> ((f64, f64), (f64, f64)) {
    let y = (y.0, y.1 + (y.1 - y.0) * top);
    let m_per_px = ((x.1 - x.0) / w_px).max((y.1 - y.0) / h_px);
    let widen = |(lo, hi): (f64, f64), px: f64| {
        let c = 0.5 * (lo + hi);
        (c - 0.5 * m_per_px * px, c + 0.5 * m_per_px * px)
    };
    (widen(x, w_px), widen(y, h_px))
}

/// `trajectory.png`: the trajectory from above (east right, north up), to
/// scale: a metre is as long east as north.
fn plot_trajectory(dir: &Path, d: &Data) -> Result<(), String> {
    let p = dir.join("trajectory.png");
    let (w, h) = (900u32, 800u32);
    let root = BitMapBackend::new(&p, (w, h)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let x = range(d.track.iter().map(|t| t.2).chain(d.truth.iter().map(|p| p.1[1])));
    let y = range(d.track.iter().map(|t| t.1).chain(d.truth.iter().map(|p| p.1[0])));
    // The plotting area inside `chart`'s margins, label areas and caption.
    let ((xl, xh), (yl, yh)) = to_scale(x, y, f64::from(w) - 84.0, f64::from(h) - 94.0, 0.15);
    let mut c = chart(&root, "Trajectory from above, to scale", xl..xh, yl..yh)?;
    c.configure_mesh()
        .x_desc("east (m)")
        .y_desc("north (m)")
        .draw()
        .map_err(err)?;
    c.draw_series(LineSeries::new(d.track.iter().map(|t| (t.2, t.1)), &BLUE))
        .map_err(err)?
        .label("estimate")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE));
    if !d.truth.is_empty() {
        c.draw_series(LineSeries::new(
            d.truth.iter().map(|p| (p.1[1], p.1[0])),
            BLACK.mix(0.7),
        ))
        .map_err(err)?
        .label("truth (SIM_STATE)")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK));
    }
    if !d.autopilot.is_empty() {
        c.draw_series(LineSeries::new(
            d.autopilot.iter().map(|p| (p.1[1], p.1[0])),
            GREEN.mix(0.8),
        ))
        .map_err(err)?
        .label("autopilot's local position")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], GREEN));
    }
    // The fixes inside the plotted area (a fix kilometres off would only
    // shrink the trajectory to a dot).
    let inside = |e: f64, n: f64| (xl..=xh).contains(&e) && (yl..=yh).contains(&n);
    if !d.fixes_ne.is_empty() {
        let orange = RGBColor(230, 120, 0);
        c.draw_series(
            d.fixes_ne
                .iter()
                .filter(|f| inside(f.1, f.0))
                .map(move |f| Cross::new((f.1, f.0), 3, orange.stroke_width(1))),
        )
        .map_err(err)?
        .label("GNSS single-point fixes")
        .legend(move |(x, y)| Cross::new((x + 10, y), 3, orange.stroke_width(1)));
    }
    c.draw_series(d.kf_pos.iter().map(|k| Circle::new((k.1, k.0), 4, RED.filled())))
        .map_err(err)?
        .label("keyframes")
        .legend(|(x, y)| Circle::new((x + 10, y), 4, RED.filled()));
    // In the band left free above the data.
    c.configure_series_labels()
        .position(SeriesLabelPosition::UpperMiddle)
        .border_style(BLACK)
        .background_style(WHITE)
        .draw()
        .map_err(err)?;
    root.present().map_err(err)
}

/// `figure1.png`, Figure 1: keyframe σ over time (left), and a zoom on one
/// keyframe (right): `keyframe` if it has σ records, else the fifth (or the last).
fn plot_figure1(dir: &Path, d: &Data, keyframe: Option<u64>) -> Result<(), String> {
    let p = dir.join("figure1.png");
    let root = BitMapBackend::new(&p, (1400, 600)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let (left, right) = root.split_horizontally(700);
    plot_keyframe_sigmas(&left, d)?;
    let ids: Vec<u64> = d.kf_sigma.keys().copied().collect();
    let pick = keyframe
        .filter(|k| d.kf_sigma.contains_key(k))
        .or_else(|| ids.get(ids.len().min(5).saturating_sub(1)).copied());
    if let Some(id) = pick {
        plot_keyframe_zoom(&right, d, id)?;
    }
    root.present().map_err(err)
}

/// Figure 1, left: every keyframe's position σ over time.
fn plot_keyframe_sigmas(area: &Area, d: &Data) -> Result<(), String> {
    let all = d.kf_sigma.values().flatten();
    let (tl, th) = range(all.clone().map(|x| x.0));
    let (_, sh) = range(all.map(|x| x.1));
    let mut c = chart(area, "Keyframe position σ", tl..th, 0.0..sh)?;
    c.configure_mesh()
        .x_desc("time (s)")
        .y_desc("σ (m)")
        .draw()
        .map_err(err)?;
    // Each curve labelled directly with its keyframe's id, where it starts.
    for (i, (id, series)) in d.kf_sigma.iter().enumerate() {
        let col = Palette99::pick(i).to_rgba();
        c.draw_series(LineSeries::new(series.iter().copied(), col))
            .map_err(err)?;
        if let Some(&(t, s)) = series.first() {
            let style = TextStyle::from(("sans-serif", 13)).color(&col);
            c.draw_series(std::iter::once(Text::new(format!("kf {id}"), (t, s), style)))
                .map_err(err)?;
        }
    }
    Ok(())
}

/// Figure 1, right: keyframe `id`'s σ, with the GNSS and global updates
/// marked.
fn plot_keyframe_zoom(area: &Area, d: &Data, id: u64) -> Result<(), String> {
    let series = &d.kf_sigma[&id];
    let (tl, th) = range(series.iter().map(|x| x.0));
    let (sl, sh) = range(series.iter().map(|x| x.1));
    let caption = format!("Keyframe {id}: vision, GNSS and global updates");
    let mut c = chart(area, &caption, tl..th, sl..sh)?;
    c.configure_mesh()
        .x_desc("time (s)")
        .y_desc("σ (m)")
        .draw()
        .map_err(err)?;
    // Updates as short ticks in two bands (GNSS along the bottom, global
    // updates along the top), not full-height lines: at 1 Hz GNSS those
    // merged into hatching over the curve.
    let band = 0.06 * (sh - sl);
    for (ts, col, label, y0) in [
        (&d.gnss_t, GREEN, "GNSS update (tick at the bottom)", sl),
        (&d.global_t, RED, "global update (tick at the top)", sh - band),
    ] {
        c.draw_series(
            ts.iter()
                .filter(|t| (tl..=th).contains(*t))
                .map(|t| PathElement::new(vec![(*t, y0), (*t, y0 + band)], col.stroke_width(2))),
        )
        .map_err(err)?
        .label(label)
        .legend(move |(x, y)| PathElement::new(vec![(x + 10, y - 5), (x + 10, y + 5)], col.stroke_width(2)));
    }
    c.draw_series(LineSeries::new(series.iter().copied(), &BLACK))
        .map_err(err)?
        .label("σ")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK));
    c.draw_series(series.iter().map(|p| Circle::new(*p, 2, BLUE.filled())))
        .map_err(err)?
        .label("σ after each update")
        .legend(|(x, y)| Circle::new((x + 10, y), 2, BLUE.filled()));
    c.configure_series_labels()
        .border_style(BLACK)
        .background_style(WHITE)
        .draw()
        .map_err(err)
}

/// `nis.png`: NIS per degree of freedom with the 95% band of the mean dof.
fn plot_nis(dir: &Path, d: &Data) -> Result<(), String> {
    let p = dir.join("nis.png");
    let root = BitMapBackend::new(&p, (900, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let (tl, th) = range(d.nis.iter().map(|x| x.0));
    let dof = (d.nis.iter().map(|x| x.2).sum::<usize>() / d.nis.len().max(1)).max(1);
    let (lo, hi) = (
        chi2_quantile(0.025, dof) / dof as f64,
        chi2_quantile(0.975, dof) / dof as f64,
    );
    let top = d
        .nis
        .iter()
        .map(|x| x.1 / x.2 as f64)
        .fold(hi * 1.5, f64::max)
        .min(10.0 * hi);
    let caption = format!("NIS / dof per track (95% band for dof {dof})");
    let mut c = chart(&root, &caption, tl..th, 0.0..top)?;
    c.configure_mesh()
        .x_desc("time (s)")
        .y_desc("NIS / dof")
        .draw()
        .map_err(err)?;
    c.draw_series(
        d.nis
            .iter()
            .map(|x| Circle::new((x.0, (x.1 / x.2 as f64).min(top)), 1, BLUE.mix(0.4).filled())),
    )
    .map_err(err)?;
    for b in [lo, hi] {
        c.draw_series(LineSeries::new(vec![(tl, b), (th, b)], &RED))
            .map_err(err)?;
    }
    root.present().map_err(err)
}

/// `timing.png`: a histogram of the estimator time per update (60 bins up
/// to the 99.5th percentile; slower updates fall in the last bin).
fn plot_timing(dir: &Path, d: &Data) -> Result<(), String> {
    let p = dir.join("timing.png");
    let root = BitMapBackend::new(&p, (900, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let mut v = d.elapsed.clone();
    let hi = percentile(&mut v, 0.995).unwrap_or(0.0).max(1.0);
    let bins = 60usize;
    let w = hi / bins as f64;
    let mut h = vec![0u32; bins];
    for x in &d.elapsed {
        h[((x / w) as usize).min(bins - 1)] += 1;
    }
    let top = h.iter().copied().max().unwrap_or(1).max(1);
    let mut c = chart(
        &root,
        "Estimator time per camera-frame update",
        0.0..hi,
        0u32..top + top / 10,
    )?;
    c.configure_mesh().x_desc("µs").y_desc("updates").draw().map_err(err)?;
    c.draw_series(
        h.iter()
            .enumerate()
            .map(|(i, n)| Rectangle::new([(i as f64 * w, 0), ((i + 1) as f64 * w, *n)], BLUE.mix(0.6).filled())),
    )
    .map_err(err)?;
    root.present().map_err(err)
}
