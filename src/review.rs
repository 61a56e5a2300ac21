//! `cmsckf review`: a flight log's summary, its plots, and a TUM export.
//!
//! Reads a log in file order and stops at the first unreadable record, so a
//! log whose writer was killed (no summary section) is reviewed up to its
//! last complete chunk, and says so. Plots are PNG through `plotters` with a
//! bundled font (DejaVu Sans), so no system font libraries are needed:
//! 1. `trajectory.png`: the estimate from above, with the keyframes and the
//!    autopilot's local position (in SITL logs, the ground truth);
//! 2. `figure1.png`: the paper's Figure 1, the position σ of every keyframe
//!    over time, and a zoom on one keyframe with the vision updates, the GNSS
//!    corrections and the global (compressed) updates marked;
//! 3. `nis.png`: per-update NIS/dof with its 95% χ² band;
//! 4. `timing.png`: a histogram of the estimator time per update.

use std::collections::BTreeMap;
use std::path::Path;

use plotters::prelude::*;
use serde::Serialize;
use serde_json::Value;

use cmsckf_models::stats::chi2_quantile;

/// Errors of a review.
#[derive(Debug, thiserror::Error)]
pub enum ReviewError {
    #[error("cannot read '{0}': {1}")]
    Io(String, std::io::Error),
    #[error("'{0}' is not an MCAP log: {1}")]
    Mcap(String, String),
    #[error("plotting '{0}': {1}")]
    Plot(String, String),
}

/// The summary `review --json` prints.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ReviewSummary {
    pub duration_s: f64,
    pub messages: u64,
    /// The log ended early (no summary): read up to the last whole chunk.
    pub truncated: bool,
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
}

#[derive(Default)]
struct Data {
    track: Vec<(f64, f64, f64, [f64; 4], f64)>, // t, n, e, q(wxyz), d
    kf_pos: Vec<(f64, f64)>,
    /// The autopilot's local position (in SITL, the ground truth).
    autopilot: Vec<(f64, f64)>,
    kf_sigma: BTreeMap<u64, Vec<(f64, f64)>>,
    vision_t: Vec<f64>,
    gnss_t: Vec<f64>,
    global_t: Vec<f64>,
    nis: Vec<(f64, f64, usize)>,
    elapsed: Vec<f64>,
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    v[((v.len() - 1) as f64 * p).round() as usize]
}

fn push_sigmas(d: &mut Data, t: f64, v: &Value) {
    if let Some(a) = v["keyframe_sigma_m"].as_array() {
        for e in a {
            if let (Some(id), Some(s)) = (e[0].as_u64(), e[1].as_f64()) {
                d.kf_sigma.entry(id).or_default().push((t, s));
            }
        }
    }
}

/// Reviews `log`; writes the plots to `plots` and the TUM trajectory to
/// `tum` if given. `keyframe` picks the zoomed keyframe of Figure 1.
pub fn review(
    log: &Path,
    plots: Option<&Path>,
    tum: Option<&Path>,
    keyframe: Option<u64>,
) -> Result<ReviewSummary, ReviewError> {
    let name = log.display().to_string();
    let bytes = std::fs::read(log).map_err(|e| ReviewError::Io(name.clone(), e))?;
    let stream = mcap::MessageStream::new(&bytes).map_err(|e| ReviewError::Mcap(name.clone(), e.to_string()))?;
    let mut s = ReviewSummary::default();
    let mut d = Data::default();
    let mut counts: BTreeMap<String, u64> = BTreeMap::new();
    let (mut t0, mut t1) = (f64::INFINITY, f64::NEG_INFINITY);
    for m in stream {
        let Ok(m) = m else {
            s.truncated = true;
            break;
        };
        s.messages += 1;
        let t = m.log_time as f64 * 1e-9;
        if t > 0.0 {
            t0 = t0.min(t);
            t1 = t1.max(t);
        }
        *counts.entry(m.channel.topic.clone()).or_default() += 1;
        let Ok(v) = serde_json::from_slice::<Value>(&m.data) else {
            continue;
        };
        match m.channel.topic.as_str() {
            "/filter/state" => {
                let p = &v["p_B_in_W"];
                let q = &v["q_W_B_wxyz"];
                let f = |x: &Value| x.as_f64().unwrap_or(f64::NAN);
                d.track.push((
                    t,
                    f(&p[0]),
                    f(&p[1]),
                    [f(&q[0]), f(&q[1]), f(&q[2]), f(&q[3])],
                    f(&p[2]),
                ));
            }
            "/filter/keyframes" => {
                let p = &v["p_B_in_W"];
                d.kf_pos
                    .push((p[0].as_f64().unwrap_or(0.0), p[1].as_f64().unwrap_or(0.0)));
                s.keyframes += 1;
            }
            "/filter/update/vision" => {
                s.vision_updates += 1;
                s.tracks_used += v["tracks_used"].as_u64().unwrap_or(0);
                if let Some(r) = v["rejected"].as_object() {
                    for (k, n) in r {
                        *s.rejected.entry(k.clone()).or_default() += n.as_u64().unwrap_or(0);
                    }
                }
                if let Some(a) = v["nis"].as_array() {
                    for e in a {
                        if let (Some(nis), Some(dof)) = (e[0].as_f64(), e[1].as_u64()) {
                            d.nis.push((t, nis, dof as usize));
                        }
                    }
                }
                if let Some(us) = v["elapsed_us"].as_f64() {
                    d.elapsed.push(us);
                }
                if v["tracks_used"].as_u64().unwrap_or(0) > 0 {
                    d.vision_t.push(t);
                }
                push_sigmas(&mut d, t, &v);
            }
            "/filter/update/gnss" => {
                s.gnss_updates += 1;
                d.gnss_t.push(t);
                push_sigmas(&mut d, t, &v);
            }
            "/filter/update/global" => {
                if v["reason"] == "Promotion" {
                    s.promotions += 1;
                } else {
                    s.global_updates += 1;
                    d.global_t.push(t);
                }
            }
            "/output/vision_position_estimate" => s.estimates += 1,
            "/input/mavlink/autopilot" => {
                if let Some(p) = v["local_position"]["p_ned_m"].as_array() {
                    if let (Some(n), Some(e)) = (p[0].as_f64(), p[1].as_f64()) {
                        d.autopilot.push((n, e));
                    }
                }
            }
            _ => {}
        }
    }
    s.duration_s = if t1 > t0 { t1 - t0 } else { 0.0 };
    for (k, n) in &counts {
        if k.starts_with("/input/") && s.duration_s > 0.0 {
            s.input_rates_hz.insert(k.clone(), *n as f64 / s.duration_s);
        }
    }
    if !d.nis.is_empty() {
        s.nis_per_dof_mean = d.nis.iter().map(|x| x.1 / x.2 as f64).sum::<f64>() / d.nis.len() as f64;
        let inside = d
            .nis
            .iter()
            .filter(|x| (chi2_quantile(0.025, x.2)..=chi2_quantile(0.975, x.2)).contains(&x.1))
            .count();
        s.nis_in_95 = inside as f64 / d.nis.len() as f64;
    }
    let mut el = d.elapsed.clone();
    s.update_us_p50 = percentile(&mut el, 0.5);
    s.update_us_p99 = percentile(&mut el, 0.99);
    s.update_us_max = el.last().copied().unwrap_or(0.0);

    if let Some(path) = tum {
        let mut out = String::from("# t x y z qx qy qz qw (world NED, body FRD)\n");
        for (t, n, e, q, dn) in &d.track {
            out += &format!("{t:.6} {n} {e} {dn} {} {} {} {}\n", q[1], q[2], q[3], q[0]);
        }
        std::fs::write(path, out).map_err(|e| ReviewError::Io(path.display().to_string(), e))?;
    }
    if let Some(dir) = plots {
        std::fs::create_dir_all(dir).map_err(|e| ReviewError::Io(dir.display().to_string(), e))?;
        // The bundled font; registering twice is harmless.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular());
        plot_all(dir, &d, keyframe).map_err(|e| ReviewError::Plot(dir.display().to_string(), e))?;
    }
    Ok(s)
}

fn range(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for x in v.filter(|x| x.is_finite()) {
        lo = lo.min(x);
        hi = hi.max(x);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-3);
    (lo - pad, hi + pad)
}

fn plot_all(dir: &Path, d: &Data, keyframe: Option<u64>) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Display| x.to_string();
    // 1. Trajectory from above (east right, north up).
    {
        let p = dir.join("trajectory.png");
        let root = BitMapBackend::new(&p, (900, 700)).into_drawing_area();
        root.fill(&WHITE).map_err(|x| e(&x))?;
        let (xl, xh) = range(d.track.iter().map(|t| t.2));
        let (yl, yh) = range(d.track.iter().map(|t| t.1));
        let mut c = ChartBuilder::on(&root)
            .caption("Trajectory from above (estimate)", ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(xl..xh, yl..yh)
            .map_err(|x| e(&x))?;
        c.configure_mesh()
            .x_desc("east (m)")
            .y_desc("north (m)")
            .draw()
            .map_err(|x| e(&x))?;
        c.draw_series(LineSeries::new(d.track.iter().map(|t| (t.2, t.1)), &BLUE))
            .map_err(|x| e(&x))?
            .label("estimate")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE));
        if !d.autopilot.is_empty() {
            c.draw_series(LineSeries::new(d.autopilot.iter().map(|p| (p.1, p.0)), GREEN.mix(0.8)))
                .map_err(|x| e(&x))?
                .label("autopilot local position (SITL: ground truth)")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], GREEN));
        }
        c.draw_series(d.kf_pos.iter().map(|k| Circle::new((k.1, k.0), 4, RED.filled())))
            .map_err(|x| e(&x))?
            .label("keyframes")
            .legend(|(x, y)| Circle::new((x + 10, y), 4, RED.filled()));
        c.configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE)
            .draw()
            .map_err(|x| e(&x))?;
        root.present().map_err(|x| e(&x))?;
    }
    // 2. Figure 1: keyframe σ over time, and a zoom on one keyframe.
    {
        let p = dir.join("figure1.png");
        let root = BitMapBackend::new(&p, (1400, 600)).into_drawing_area();
        root.fill(&WHITE).map_err(|x| e(&x))?;
        let (left, right) = root.split_horizontally(700);
        let all = d.kf_sigma.values().flatten();
        let (tl, th) = range(all.clone().map(|x| x.0));
        let (_, sh) = range(all.map(|x| x.1));
        let mut c = ChartBuilder::on(&left)
            .caption("Keyframe position σ", ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(tl..th, 0.0..sh)
            .map_err(|x| e(&x))?;
        c.configure_mesh()
            .x_desc("time (s)")
            .y_desc("σ (m)")
            .draw()
            .map_err(|x| e(&x))?;
        for (i, series) in d.kf_sigma.values().enumerate() {
            let col = Palette99::pick(i).to_rgba();
            c.draw_series(LineSeries::new(series.iter().copied(), col))
                .map_err(|x| e(&x))?;
        }
        let ids: Vec<u64> = d.kf_sigma.keys().copied().collect();
        let pick = keyframe
            .filter(|k| d.kf_sigma.contains_key(k))
            .or_else(|| ids.get(ids.len().min(5).saturating_sub(1)).copied());
        if let Some(id) = pick {
            let series = &d.kf_sigma[&id];
            let (tl, th) = range(series.iter().map(|x| x.0));
            let (sl, sh) = range(series.iter().map(|x| x.1));
            let mut c = ChartBuilder::on(&right)
                .caption(
                    format!("Keyframe {id}: vision, GNSS and global updates"),
                    ("sans-serif", 22),
                )
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(60)
                .build_cartesian_2d(tl..th, sl..sh)
                .map_err(|x| e(&x))?;
            c.configure_mesh()
                .x_desc("time (s)")
                .y_desc("σ (m)")
                .draw()
                .map_err(|x| e(&x))?;
            for (ts, col, label) in [(&d.gnss_t, GREEN, "GNSS update"), (&d.global_t, RED, "global update")] {
                c.draw_series(
                    ts.iter()
                        .filter(|t| (tl..=th).contains(*t))
                        .map(|t| PathElement::new(vec![(*t, sl), (*t, sh)], col.mix(0.5))),
                )
                .map_err(|x| e(&x))?
                .label(label)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], col));
            }
            c.draw_series(LineSeries::new(series.iter().copied(), &BLACK))
                .map_err(|x| e(&x))?
                .label("σ")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK));
            c.draw_series(series.iter().map(|p| Circle::new(*p, 2, BLUE.filled())))
                .map_err(|x| e(&x))?
                .label("after an update")
                .legend(|(x, y)| Circle::new((x + 10, y), 2, BLUE.filled()));
            c.configure_series_labels()
                .border_style(BLACK)
                .background_style(WHITE)
                .draw()
                .map_err(|x| e(&x))?;
        }
        root.present().map_err(|x| e(&x))?;
    }
    // 3. NIS per degree of freedom with the 95% band of the mean dof.
    {
        let p = dir.join("nis.png");
        let root = BitMapBackend::new(&p, (900, 500)).into_drawing_area();
        root.fill(&WHITE).map_err(|x| e(&x))?;
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
        let mut c = ChartBuilder::on(&root)
            .caption(
                format!("NIS / dof per track (95% band for dof {dof})"),
                ("sans-serif", 22),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(tl..th, 0.0..top)
            .map_err(|x| e(&x))?;
        c.configure_mesh()
            .x_desc("time (s)")
            .y_desc("NIS / dof")
            .draw()
            .map_err(|x| e(&x))?;
        c.draw_series(
            d.nis
                .iter()
                .map(|x| Circle::new((x.0, (x.1 / x.2 as f64).min(top)), 1, BLUE.mix(0.4).filled())),
        )
        .map_err(|x| e(&x))?;
        for b in [lo, hi] {
            c.draw_series(LineSeries::new(vec![(tl, b), (th, b)], &RED))
                .map_err(|x| e(&x))?;
        }
        root.present().map_err(|x| e(&x))?;
    }
    // 4. Histogram of the estimator time per update.
    {
        let p = dir.join("timing.png");
        let root = BitMapBackend::new(&p, (900, 500)).into_drawing_area();
        root.fill(&WHITE).map_err(|x| e(&x))?;
        let mut v = d.elapsed.clone();
        let hi = percentile(&mut v, 0.995).max(1.0);
        let bins = 60usize;
        let w = hi / bins as f64;
        let mut h = vec![0u32; bins];
        for x in &d.elapsed {
            h[((x / w) as usize).min(bins - 1)] += 1;
        }
        let top = h.iter().copied().max().unwrap_or(1).max(1);
        let mut c = ChartBuilder::on(&root)
            .caption("Estimator time per camera-frame update", ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..hi, 0u32..top + top / 10)
            .map_err(|x| e(&x))?;
        c.configure_mesh()
            .x_desc("µs")
            .y_desc("updates")
            .draw()
            .map_err(|x| e(&x))?;
        c.draw_series(
            h.iter()
                .enumerate()
                .map(|(i, n)| Rectangle::new([(i as f64 * w, 0), ((i + 1) as f64 * w, *n)], BLUE.mix(0.6).filled())),
        )
        .map_err(|x| e(&x))?;
        root.present().map_err(|x| e(&x))?;
    }
    Ok(())
}
