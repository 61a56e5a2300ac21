//! Scoring the flights and summarising them per mode: the rows of the
//! evaluation table, and the table itself as text (`cmsckf evaluate`) and
//! CSV (`--csv`).

use serde::Serialize;

use cmsckf_models::stats::{chi2_quantile, percentile};
use cmsckf_sitl::metrics;

use super::{Evaluation, FlightResult};
use crate::estimator::Mode;

/// The per-mode row of the evaluation table.
#[derive(Clone, Debug, Serialize)]
pub struct ModeSummary {
    pub ate_unaligned_m: f64,
    pub ate_aligned_m: f64,
    /// Inside the simulated urban canyon (`gnss.canyon_s`): the position
    /// RMSE (m, unaligned) and the largest error, mean over seeds, and the
    /// RMSE of each seed.
    pub canyon_rmse_m: Option<f64>,
    pub canyon_max_error_m: Option<f64>,
    pub per_seed_canyon_rmse_m: Vec<f64>,
    pub rot_rmse_deg: f64,
    pub nees_mean: f64,
    pub nees_in_bounds: f64,
    pub keyframes: f64,
    pub loop_closure_updates: f64,
    pub global_updates: f64,
    pub frame_us_mean: f64,
    pub frame_us_p99: f64,
    pub frame_us_p50: f64,
    pub frame_us_max: f64,
    /// Global keyframes brought local for loop closures, per flight.
    pub promotions: f64,
    /// Rebase job time (ms), mean and largest, and every `(global keyframes,
    /// ms)` of the first seed.
    pub rebase_ms_mean: f64,
    pub rebase_ms_max: f64,
    pub rebase_ms: Vec<(usize, f64)>,
    pub per_seed_ate_unaligned_m: Vec<f64>,
    pub per_seed_ate_aligned_m: Vec<f64>,
    pub per_seed_nees_mean: Vec<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_rel_diff_vs_full: Option<f64>,
    /// RMS of the clock-bias error at the GNSS epochs after the first 5 s (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub clock_bias_rmse_m: Option<f64>,
    /// RMS of the Galileo inter-system-bias error, likewise (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub isb_galileo_rmse_m: Option<f64>,
    /// Mean NEES of the range-bias states at the flights' ends, over every
    /// satellite of every seed (1 dof each; §8c, DG5′).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub nees_range_bias_mean: Option<f64>,
    /// Mean NEES of each part of the state over the flight, and over its
    /// second half: tilt (roll and pitch, 2 dof), yaw (1), position (3) and
    /// velocity (3). A consistent filter gives the degrees of freedom.
    pub nees_tilt_mean: f64,
    pub nees_yaw_mean: f64,
    pub nees_position_mean: f64,
    pub nees_velocity_mean: f64,
    pub nees_tilt_mean_second_half: f64,
    pub nees_yaw_mean_second_half: f64,
    pub nees_position_mean_second_half: f64,
    pub nees_velocity_mean_second_half: f64,
    /// The standard error of each of the four whole-flight means above,
    /// `[tilt, yaw, position, velocity]`, from their spread across seeds
    /// (`s/√n`, each seed's mean one sample; absent with one seed): a
    /// mean over a handful of seeds moves by this much with another draw,
    /// so a NEES is judged against its degrees of freedom within it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub nees_parts_se: Option<[f64; 4]>,
    /// The time offset's final |estimate − truth| (ms), mean over seeds.
    pub time_offset_error_ms: f64,
    /// Per seed: the time offset's final estimate − truth, and its σ (ms).
    pub per_seed_time_offset_error_ms: Vec<f64>,
    pub per_seed_time_offset_sigma_ms: Vec<f64>,
    /// GNSS epochs fused, and refused as late, per flight.
    pub gnss_epochs_fused: f64,
    /// Range-bias states created and dropped per flight (§8c, DG5′).
    pub range_bias_states_created: f64,
    pub range_bias_states_dropped: f64,
    pub gnss_epochs_late: f64,
    /// Frames taken as zero-velocity updates, per flight.
    pub zupt_updates: f64,
    /// Tracks used at their landmark's remembered depth for want of
    /// parallax (§3e), per flight.
    pub low_parallax_tracks: f64,
    /// The accepted tracks' NIS per degree of freedom over all seeds: 1
    /// when the pixel noise fits the tracks (NaN with no track).
    pub nis_per_dof: f64,
    /// Health-check failures over all seeds: each would reset the daemon's
    /// filter.
    pub resets: u64,
    /// Per time: the fraction of frames at which the NEES averaged over the
    /// seeds lies inside its 95% bounds (`χ²(k·seeds)/seeds`), for the pose
    /// (6 dof), yaw (1) and position (3). A consistent filter gives about
    /// 0.95.
    pub nees_pose_in_bounds_per_time: f64,
    pub nees_yaw_in_bounds_per_time: f64,
    pub nees_position_in_bounds_per_time: f64,
    /// Compressed only: the largest normalised difference from full in
    /// each quarter of the flight (the drift's growth).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub diff_vs_full_by_quarter: Vec<f64>,
}

/// The NEES of one sample, by part: `[tilt, yaw, position, velocity]`
/// (`None` where a covariance block does not invert).
fn component_sample(r: &FlightResult, i: usize) -> Option<[f64; 4]> {
    let e_th = (r.q_true[i] * r.q_est[i].inverse()).scaled_axis();
    let c = &r.cov_pose[i];
    let ti = c.fixed_view::<2, 2>(0, 0).into_owned().try_inverse()?;
    let pi = c.fixed_view::<3, 3>(3, 3).into_owned().try_inverse()?;
    let vi = r.cov_vel[i].try_inverse()?;
    let e_tilt = e_th.xy();
    let e_p = r.p_true[i] - r.p_est[i];
    let e_v = r.v_true[i] - r.v_est[i];
    Some([
        e_tilt.dot(&(ti * e_tilt)),
        e_th.z * e_th.z / c[(2, 2)],
        e_p.dot(&(pi * e_p)),
        e_v.dot(&(vi * e_v)),
    ])
}

/// The fraction of frame indices at which `nees` averaged over the runs
/// lies inside the 95% bounds of `dof` degrees of freedom and as many runs.
fn in_bounds_per_time(runs: &[FlightResult], dof: usize, nees: impl Fn(&FlightResult, usize) -> Option<f64>) -> f64 {
    let n = runs.iter().map(|r| r.t_s.len()).min().unwrap_or(0);
    let (lo, hi) = cmsckf_sitl::metrics::nees_bounds_95(dof, runs.len());
    let mut inside = 0usize;
    let mut counted = 0usize;
    for i in 0..n {
        let v: Vec<f64> = runs.iter().filter_map(|r| nees(r, i)).collect();
        if v.len() != runs.len() {
            continue;
        }
        counted += 1;
        let m = v.iter().sum::<f64>() / v.len() as f64;
        if (lo..=hi).contains(&m) {
            inside += 1;
        }
    }
    inside as f64 / counted.max(1) as f64
}

/// Mean NEES of each part of the state over the samples `from..`:
/// `[tilt, yaw, position, velocity]`. The attitude error is the world-frame
/// `Log(R_true R̂ᵀ)` of the filter's perturbation, so yaw is its down
/// component.
pub fn component_nees(r: &FlightResult, from: usize) -> [f64; 4] {
    let mut sum = [0.0; 4];
    let mut n = 0usize;
    for i in from..r.t_s.len() {
        if let Some(c) = component_sample(r, i) {
            for k in 0..4 {
                sum[k] += c[k];
            }
            n += 1;
        }
    }
    sum.map(|s| s / n.max(1) as f64)
}

/// The standard error of the mean of each of four per-seed values: the
/// sample standard deviation (`n − 1`) over `√n`; `None` with fewer than
/// two seeds.
fn standard_errors(per_seed: &[[f64; 4]]) -> Option<[f64; 4]> {
    let n = per_seed.len();
    if n < 2 {
        return None;
    }
    let nf = n as f64;
    Some(std::array::from_fn(|k| {
        let mean = per_seed.iter().map(|v| v[k]).sum::<f64>() / nf;
        let var = per_seed.iter().map(|v| (v[k] - mean).powi(2)).sum::<f64>() / (nf - 1.0);
        (var / nf).sqrt()
    }))
}

/// Scores of one flight.
#[derive(Clone, Copy, Debug)]
pub struct FlightScore {
    pub ate: metrics::Ate,
    pub rot_rmse_deg: f64,
    pub nees_mean: f64,
    pub nees_in_bounds: f64,
}

pub fn score(r: &FlightResult) -> FlightScore {
    let ate = metrics::ate(&r.p_est, &r.p_true);
    let rot = metrics::rotation_rmse_deg(&r.q_est, &r.q_true, ate.yaw_rad);
    let (lo, hi) = (chi2_quantile(0.025, 6), chi2_quantile(0.975, 6));
    let mut sum = 0.0;
    let mut n = 0usize;
    let mut inside = 0usize;
    for i in 0..r.t_s.len() {
        if let Some(v) = metrics::nees_pose(&r.q_est[i], &r.p_est[i], &r.q_true[i], &r.p_true[i], &r.cov_pose[i]) {
            sum += v;
            n += 1;
            if (lo..=hi).contains(&v) {
                inside += 1;
            }
        }
    }
    FlightScore {
        ate,
        rot_rmse_deg: rot,
        nees_mean: sum / n.max(1) as f64,
        nees_in_bounds: inside as f64 / n.max(1) as f64,
    }
}

/// Summarises the runs of one mode over seeds.
pub fn summarise(runs: &[FlightResult]) -> ModeSummary {
    let scores: Vec<FlightScore> = runs.iter().map(score).collect();
    let n = runs.len().max(1) as f64;
    let mean = |f: &dyn Fn(&FlightScore) -> f64| scores.iter().map(f).sum::<f64>() / n;
    let mut times: Vec<f64> = runs.iter().flat_map(|r| r.frame_us.iter().copied()).collect();
    let tmean = times.iter().sum::<f64>() / times.len().max(1) as f64;
    let p99 = percentile(&mut times, 0.99).unwrap_or(0.0);
    // Each seed's mean NEES by part, over the whole flight (also the
    // samples of their standard error) and over its second half.
    let per_seed: Vec<[f64; 4]> = runs.iter().map(|r| component_nees(r, 0)).collect();
    let per_seed_half: Vec<[f64; 4]> = runs.iter().map(|r| component_nees(r, r.t_s.len() / 2)).collect();
    let mean_over_seeds =
        |v: &[[f64; 4]]| -> [f64; 4] { std::array::from_fn(|k| v.iter().map(|c| c[k] / n).sum::<f64>()) };
    let (nees_all, nees_half) = (mean_over_seeds(&per_seed), mean_over_seeds(&per_seed_half));
    let diff = runs
        .iter()
        .filter_map(|r| r.max_rel_diff_vs_full)
        .fold(None, |m: Option<f64>, d| Some(m.map_or(d, |x| x.max(d))));
    ModeSummary {
        ate_unaligned_m: mean(&|s| s.ate.unaligned_m),
        ate_aligned_m: mean(&|s| s.ate.aligned_m),
        rot_rmse_deg: mean(&|s| s.rot_rmse_deg),
        nees_mean: mean(&|s| s.nees_mean),
        nees_in_bounds: mean(&|s| s.nees_in_bounds),
        keyframes: runs.iter().map(|r| r.keyframes as f64).sum::<f64>() / n,
        loop_closure_updates: runs.iter().map(|r| r.stats.loop_closure_updates as f64).sum::<f64>() / n,
        global_updates: runs.iter().map(|r| r.stats.global_updates as f64).sum::<f64>() / n,
        frame_us_mean: tmean,
        frame_us_p99: p99,
        frame_us_p50: percentile(&mut times, 0.5).unwrap_or(0.0),
        frame_us_max: times.last().copied().unwrap_or(0.0),
        promotions: runs.iter().map(|r| r.stats.promotions as f64).sum::<f64>() / n,
        rebase_ms_mean: {
            let all: Vec<f64> = runs.iter().flat_map(|r| r.rebase_us.iter().map(|x| x.1)).collect();
            all.iter().sum::<f64>() / all.len().max(1) as f64 / 1e3
        },
        rebase_ms_max: runs
            .iter()
            .flat_map(|r| r.rebase_us.iter().map(|x| x.1))
            .fold(0.0, f64::max)
            / 1e3,
        rebase_ms: runs
            .first()
            .map(|r| r.rebase_us.iter().map(|(n, us)| (*n, us / 1e3)).collect())
            .unwrap_or_default(),
        per_seed_ate_unaligned_m: scores.iter().map(|s| s.ate.unaligned_m).collect(),
        canyon_rmse_m: mean_of(runs.iter().filter_map(|r| canyon_errors(r).map(|c| c.0))),
        canyon_max_error_m: mean_of(runs.iter().filter_map(|r| canyon_errors(r).map(|c| c.1))),
        per_seed_canyon_rmse_m: runs.iter().filter_map(|r| canyon_errors(r).map(|c| c.0)).collect(),
        per_seed_ate_aligned_m: scores.iter().map(|s| s.ate.aligned_m).collect(),
        per_seed_nees_mean: scores.iter().map(|s| s.nees_mean).collect(),
        max_rel_diff_vs_full: diff,
        // RMS of one clock error over the epochs after the first 5 s (NaN:
        // not estimated yet).
        clock_bias_rmse_m: clock_rmse(runs, |c| c.1),
        isb_galileo_rmse_m: clock_rmse(runs, |c| c.2),
        nees_range_bias_mean: mean_of(runs.iter().flat_map(|r| r.range_bias_nees.iter().copied())),
        nees_tilt_mean: nees_all[0],
        nees_yaw_mean: nees_all[1],
        nees_position_mean: nees_all[2],
        nees_velocity_mean: nees_all[3],
        nees_tilt_mean_second_half: nees_half[0],
        nees_yaw_mean_second_half: nees_half[1],
        nees_position_mean_second_half: nees_half[2],
        nees_velocity_mean_second_half: nees_half[3],
        nees_parts_se: standard_errors(&per_seed),
        time_offset_error_ms: runs
            .iter()
            .map(|r| (r.time_offset_s - r.time_offset_true_s).abs() * 1e3)
            .sum::<f64>()
            / n,
        per_seed_time_offset_error_ms: runs
            .iter()
            .map(|r| (r.time_offset_s - r.time_offset_true_s) * 1e3)
            .collect(),
        per_seed_time_offset_sigma_ms: runs.iter().map(|r| r.time_offset_sigma_s * 1e3).collect(),
        gnss_epochs_fused: runs.iter().map(|r| r.stats.gnss_epochs_fused as f64).sum::<f64>() / n,
        range_bias_states_created: runs
            .iter()
            .map(|r| r.stats.range_bias_states_created as f64)
            .sum::<f64>()
            / n,
        range_bias_states_dropped: runs
            .iter()
            .map(|r| r.stats.range_bias_states_dropped as f64)
            .sum::<f64>()
            / n,
        gnss_epochs_late: runs.iter().map(|r| r.stats.gnss_epochs_late as f64).sum::<f64>() / n,
        zupt_updates: runs.iter().map(|r| r.stats.zupt_updates as f64).sum::<f64>() / n,
        low_parallax_tracks: runs.iter().map(|r| r.stats.low_parallax_tracks as f64).sum::<f64>() / n,
        nis_per_dof: runs.iter().map(|r| r.nis_sum).sum::<f64>() / runs.iter().map(|r| r.nis_dof).sum::<u64>() as f64,
        resets: runs.iter().map(|r| r.resets).fold(0, u64::saturating_add),
        nees_pose_in_bounds_per_time: in_bounds_per_time(runs, 6, |r, i| {
            metrics::nees_pose(&r.q_est[i], &r.p_est[i], &r.q_true[i], &r.p_true[i], &r.cov_pose[i])
        }),
        nees_yaw_in_bounds_per_time: in_bounds_per_time(runs, 1, |r, i| component_sample(r, i).map(|c| c[1])),
        nees_position_in_bounds_per_time: in_bounds_per_time(runs, 3, |r, i| component_sample(r, i).map(|c| c[2])),
        diff_vs_full_by_quarter: diff_by_quarter(runs),
    }
}

/// The largest difference from full in each quarter of the flights.
fn diff_by_quarter(runs: &[FlightResult]) -> Vec<f64> {
    let points = || {
        runs.iter()
            .flat_map(|r| r.diff_vs_full.iter().map(|d| (d.0, d.1.max(d.2))))
    };
    match points().map(|p| p.0).reduce(f64::max) {
        Some(t_end) => max_by_quarter(points(), t_end),
        None => Vec::new(),
    }
}

/// The largest value in each quarter of `[0, t_end]` of `(t, value)`
/// points (a point at or past `t_end` counts in the last).
pub fn max_by_quarter(points: impl IntoIterator<Item = (f64, f64)>, t_end: f64) -> Vec<f64> {
    let mut q = vec![0.0f64; 4];
    for (t, v) in points {
        let i = ((t / t_end * 4.0) as usize).min(3);
        q[i] = q[i].max(v);
    }
    q
}

/// RMS of `pick` of the clock errors at the GNSS epochs after the first 5 s,
/// skipping NaN (a state not estimated yet); `None` when there are none.
fn clock_rmse(runs: &[FlightResult], pick: impl Fn(&(f64, f64, f64)) -> f64) -> Option<f64> {
    let e: Vec<f64> = runs
        .iter()
        .flat_map(|r| r.clock_errors.iter().filter(|c| c.0 > 5.0).map(&pick))
        .filter(|x| x.is_finite())
        .collect();
    (!e.is_empty()).then(|| (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt())
}

/// The position RMSE (m) inside a run's urban canyon and its largest
/// error there (m).
fn canyon_errors(r: &FlightResult) -> Option<(f64, f64)> {
    let (a, b) = r.canyon_s?;
    let e: Vec<f64> = (0..r.t_s.len())
        .filter(|&i| (a..b).contains(&r.t_s[i]))
        .map(|i| (r.p_est[i] - r.p_true[i]).norm())
        .collect();
    let max = e.iter().copied().reduce(f64::max)?;
    Some(((e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt(), max))
}

/// A count, or a count's mean over seeds: an integer when it is one (never
/// `-0`), else one decimal.
fn count(x: f64) -> String {
    let x = x + 0.0;
    if (x - x.round()).abs() < 1e-9 {
        format!("{:.0}", x.round() + 0.0)
    } else {
        format!("{x:.1}")
    }
}

/// The mean of some values, `None` without any.
fn mean_of(v: impl Iterator<Item = f64>) -> Option<f64> {
    let v: Vec<f64> = v.collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

impl Evaluation {
    /// The human-readable table.
    pub fn table(&self) -> String {
        let mut s = format!(
            "scenario {} · {} seeds · {:.0} s · GNSS {}{}\n{:<11} {:>9} {:>9} {:>8} {:>7} {:>6} {:>5} {:>6} {:>6} {:>9} {:>9} {:>10}\n",
            self.scenario, self.seeds, self.duration_s, if self.gnss { "on" } else { "off" }, if self.landed_state { "" } else { " · no landed state" }, "mode", "ATE[m]", "ATE4[m]", "rot[deg]", "NEES", "in95", "KF", "loops", "glob", "us/frame", "p99[us]", "vs full"
        );
        for m in Mode::ALL {
            if let Some(r) = self.modes.get(m.name()) {
                s += &format!(
                    "{:<11} {:>9.3} {:>9.3} {:>8.3} {:>7.2} {:>6.2} {:>5} {:>6} {:>6} {:>9.0} {:>9.0} {:>10}\n",
                    m.name(),
                    r.ate_unaligned_m,
                    r.ate_aligned_m,
                    r.rot_rmse_deg,
                    r.nees_mean,
                    r.nees_in_bounds,
                    count(r.keyframes),
                    count(r.loop_closure_updates),
                    count(r.global_updates),
                    r.frame_us_mean,
                    r.frame_us_p99,
                    r.max_rel_diff_vs_full.map_or("-".to_string(), |d| format!("{d:.1e}"))
                );
            }
        }
        for m in Mode::ALL {
            if let (Some(r), Some(rmse), Some(end)) = self
                .modes
                .get(m.name())
                .map_or((None, None, None), |r| (Some(r), r.canyon_rmse_m, r.canyon_max_error_m))
            {
                let per: Vec<String> = r.per_seed_canyon_rmse_m.iter().map(|x| format!("{x:.2}")).collect();
                s += &format!(
                    "{:<11} urban canyon: position RMSE {rmse:.3} m, largest error {end:.3} m; per seed {}\n",
                    m.name(),
                    per.join(" ")
                );
            }
        }
        if let Some(r) = self.modes.get(Mode::Compressed.name()) {
            s += &format!(
                "compressed  frame p50 {:.0} µs, max {:.0} µs · {} promotions · rebase jobs mean {:.2} ms, max {:.2} ms (timed apart: the daemon runs them on a worker thread)\n",
                r.frame_us_p50, r.frame_us_max, count(r.promotions), r.rebase_ms_mean + 0.0, r.rebase_ms_max + 0.0
            );
        }
        s += &format!(
            "{:<11} {:>21} {:>21} {:>21} {:>21} {:>16} {:>9} {:>6} {:>6} {:>6} {:>6}\n",
            "NEES",
            "tilt (2) all/2nd",
            "yaw (1) all/2nd",
            "pos (3) all/2nd",
            "vel (3) all/2nd",
            "in95/t pose/y/p",
            "t_d[ms]",
            "gnss",
            "late",
            "zupt",
            "resets"
        );
        for m in Mode::ALL {
            if let Some(r) = self.modes.get(m.name()) {
                s += &format!(
                    "{:<11} {:>10.2}/{:<10.2} {:>10.2}/{:<10.2} {:>10.2}/{:<10.2} {:>10.2}/{:<10.2} {:>16} {:>9.2} {:>6} {:>6} {:>6} {:>6}\n",
                    m.name(),
                    r.nees_tilt_mean,
                    r.nees_tilt_mean_second_half,
                    r.nees_yaw_mean,
                    r.nees_yaw_mean_second_half,
                    r.nees_position_mean,
                    r.nees_position_mean_second_half,
                    r.nees_velocity_mean,
                    r.nees_velocity_mean_second_half,
                    format!(
                        "{:.2}/{:.2}/{:.2}",
                        r.nees_pose_in_bounds_per_time, r.nees_yaw_in_bounds_per_time, r.nees_position_in_bounds_per_time
                    ),
                    r.time_offset_error_ms,
                    count(r.gnss_epochs_fused),
                    count(r.gnss_epochs_late),
                    count(r.zupt_updates),
                    count(r.resets as f64)
                );
            }
        }
        for m in Mode::ALL {
            if let Some(se) = self.modes.get(m.name()).and_then(|r| r.nees_parts_se) {
                s += &format!(
                    "{:<11} ± standard error across the {} seeds: tilt {:.2} · yaw {:.2} · pos {:.2} · vel {:.2}\n",
                    m.name(),
                    self.seeds,
                    se[0],
                    se[1],
                    se[2],
                    se[3]
                );
            }
        }
        for m in Mode::ALL {
            if let Some(r) = self.modes.get(m.name()) {
                if let (Some(b), Some(e)) = (r.clock_bias_rmse_m, r.isb_galileo_rmse_m) {
                    s += &format!("{:<11} clock-bias RMSE {b:.3} m · Galileo ISB RMSE {e:.3} m", m.name());
                    if let Some(n) = r.nees_range_bias_mean {
                        s += &format!(" · range-bias NEES {n:.2} (1 dof)");
                    }
                    s += "\n";
                }
            }
        }
        s
    }

    /// The CSV of `--csv`: a header and one row per mode.
    pub fn csv(&self) -> String {
        let mut s = String::from("mode,ate_unaligned_m,ate_aligned_m,rot_rmse_deg,nees_mean,nees_in_bounds,keyframes,loop_closure_updates,global_updates,frame_us_mean,frame_us_p99,max_rel_diff_vs_full\n");
        for (m, r) in &self.modes {
            s += &format!(
                "{m},{},{},{},{},{},{},{},{},{},{},{}\n",
                r.ate_unaligned_m,
                r.ate_aligned_m,
                r.rot_rmse_deg,
                r.nees_mean,
                r.nees_in_bounds,
                r.keyframes,
                r.loop_closure_updates,
                r.global_updates,
                r.frame_us_mean,
                r.frame_us_p99,
                r.max_rel_diff_vs_full.map_or(String::new(), |d| d.to_string())
            );
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::standard_errors;

    #[test]
    fn the_standard_error_is_the_seeds_spread_over_root_n() {
        assert_eq!(
            standard_errors(&[[3.0; 4]]),
            None,
            "one seed says nothing of the spread"
        );
        let se = standard_errors(&[[1.0, 3.0, 0.0, 5.0], [2.0, 3.0, 0.0, 5.0], [3.0, 3.0, 6.0, 5.0]]).unwrap();
        // [1, 2, 3]: mean 2, sample variance 1, so 1/√3; [0, 0, 6]: variance 12, so 2.
        assert!((se[0] - 1.0 / 3f64.sqrt()).abs() < 1e-15, "{se:?}");
        assert_eq!(se[1], 0.0);
        assert!((se[2] - 2.0).abs() < 1e-15, "{se:?}");
        assert_eq!(se[3], 0.0);
    }
}
