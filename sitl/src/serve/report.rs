//! Scoring of a served flight: accuracy, rate, latency, resets and
//! covariance of the daemon's estimates against the truth, and how it came
//! through each injected fault.

use std::time::Instant;

use cmsckf_models::stats::percentile;
use mavlink::dialects::ardupilotmega as apm;
use serde::Serialize;

use super::autopilot::AutopilotReport;
use super::clock::FlightClock;
use super::fault::Fault;
use super::receive::{Heartbeat, Inbox, Received};
use super::ServeOptions;
use crate::dataset::Dataset;
use crate::metrics;

/// How the daemon came through one fault.
#[derive(Clone, Debug, Serialize)]
pub struct FaultReport {
    pub name: String,
    pub start_s: f64,
    pub end_s: f64,
    /// Seconds after the fault's end until the error is back within twice
    /// its pre-fault median + 0.5 m (0 if it never left; NaN if it never came back).
    pub recovery_s: f64,
    pub peak_error_m: f64,
    pub resets: u32,
    /// A daemon `HEARTBEAT` showed a state other than active after the
    /// fault's start and before the daemon's estimates had passed 3 s after
    /// its end.
    pub degraded_reported: bool,
    /// Longest interval between consecutive estimates (flight time) that
    /// overlaps `[start_s, end_s + 5 s]`, whole (s; NaN without estimates).
    pub output_gap_max_s: f64,
    /// End of the last fault that overlaps this one, directly or through
    /// others (`end_s` when none does): a camera outage inside a GNSS outage
    /// cannot be undone before the GNSS is back.
    pub overlap_end_s: f64,
    /// As `recovery_s`, counted from `overlap_end_s` (and with the peak
    /// searched up to 5 s after it).
    pub recovery_after_overlap_s: f64,
}

/// The score of a served flight.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub duration_s: f64,
    pub estimates_received: usize,
    /// Estimates per second of flight (autopilot) time.
    pub output_rate_hz: f64,
    pub ate_m: f64,
    pub ate_aligned_m: f64,
    /// Wall time from sending an IMU sample to receiving the estimate stamped
    /// with it.
    pub latency_ms_p50: f64,
    pub latency_ms_p99: f64,
    pub latency_ms_max: f64,
    pub time_to_first_estimate_s: f64,
    pub reset_count: u32,
    pub covariance_ok: bool,
    /// The position error normalised by the covariance as ArduPilot reads
    /// it (one σ per axis, `cbrt(c₀² + c₆² + c₁₁²)`): `|e|²/σ²` per
    /// estimate, whose mean is 3 when our covariance is honest; its mean,
    /// and the fraction of estimates inside its 95% bound (7.81). NaN
    /// without estimates.
    pub position_nees_mean: f64,
    pub position_nees_in95: f64,
    /// The lowest `ODOMETRY.quality` sent (−1 failed … 100 best; `null`
    /// with VISION_POSITION_ESTIMATE, which has none).
    pub quality_min: Option<i8>,
    pub imu_sent: usize,
    pub frames_sent: usize,
    pub speedup: f64,
    /// Messages received per kind: the estimates are whichever the daemon
    /// sends (`output.message`), ODOMETRY or VISION_POSITION_ESTIMATE (with
    /// VISION_SPEED_ESTIMATE), never both.
    pub odometry_received: usize,
    pub vpe_received: usize,
    pub speed_estimates_received: usize,
    /// ODOMETRYs with a `quality` outside −1..=100 or a non-finite velocity
    /// covariance.
    pub odometry_malformed: usize,
    pub gps_origin_set: bool,
    /// Longest interval between consecutive estimates, in flight time, after
    /// the first (s; NaN with fewer than two). Faults are not excluded: a
    /// silent daemon is a blind autopilot whatever the cause. A daemon that
    /// stops for good shows in `estimates_received`, not here.
    pub output_gap_max_s: f64,
    /// Time without estimates beyond the nominal rate: the sum over the
    /// intervals between consecutive estimates of what each lasts beyond
    /// twice the median interval (s).
    pub output_gap_total_s: f64,
    /// The mock autopilot's own EKF: how far it was off, how it took the
    /// daemon's estimates.
    pub autopilot: AutopilotReport,
    pub faults: Vec<FaultReport>,
    /// The daemon's `STATUSTEXT`s: `(flight time s, text)`.
    pub status_texts: Vec<(f64, String)>,
}

impl Report {
    /// The thresholds this report misses (a NaN figure misses).
    pub fn misses(&self, max_ate_m: Option<f64>, min_rate_hz: Option<f64>, max_latency_ms: Option<f64>) -> Vec<String> {
        let mut v = Vec::new();
        if let Some(m) = max_ate_m {
            if self.ate_m.is_nan() || self.ate_m > m {
                v.push(format!("ATE {:.3} m > {m} m", self.ate_m));
            }
        }
        if let Some(m) = min_rate_hz {
            if self.output_rate_hz.is_nan() || self.output_rate_hz < m {
                v.push(format!("output rate {:.2} Hz < {m} Hz", self.output_rate_hz));
            }
        }
        if let Some(m) = max_latency_ms {
            if self.latency_ms_p99.is_nan() || self.latency_ms_p99 > m {
                v.push(format!("p99 latency {:.2} ms > {m} ms", self.latency_ms_p99));
            }
        }
        v
    }
}

/// The report of the flight `ds` served with `opts`, from what `inbox`
/// gathered and what went out: the wall time each IMU sample was first sent,
/// the IMU samples streamed and the frames written.
pub(super) fn report(
    opts: &ServeOptions,
    ds: &Dataset,
    inbox: &Inbox,
    reboot_s: Option<f64>,
    sent_wall: &[Option<Instant>],
    imu_sent: usize,
    frames_sent: usize,
) -> Report {
    let rate_imu = ds.cfg.imu_rate_hz;
    let mut rec = inbox.received.lock().map(|v| v.clone()).unwrap_or_default();
    flight_times(&mut rec, reboot_s);
    let hbs = inbox.heartbeats.lock().map(|v| v.clone()).unwrap_or_default();
    let mut report = score(ds, &rec, sent_wall, rate_imu, imu_sent, frames_sent, opts.speedup);
    report.faults = opts
        .faults
        .iter()
        .map(|f| fault_report(ds, &rec, &hbs, f, overlap_end(&opts.faults, f)))
        .collect();
    report.status_texts = inbox.status_texts.lock().map(|v| v.clone()).unwrap_or_default();
    if let Ok(c) = inbox.counts.lock() {
        report.odometry_received = c.odometry;
        report.vpe_received = c.vision_position_estimate;
        report.speed_estimates_received = c.vision_speed_estimate;
        report.odometry_malformed = c.odometry_malformed;
        report.gps_origin_set = c.set_gps_global_origin > 0;
    }
    report
}

fn score(
    ds: &Dataset,
    rec: &[Received],
    sent_wall: &[Option<Instant>],
    rate_imu: f64,
    imu_sent: usize,
    frames_sent: usize,
    speedup: f64,
) -> Report {
    let mut est = Vec::new();
    let mut truth = Vec::new();
    let mut lat = Vec::new();
    let mut resets = 0;
    let mut cov_ok = true;
    let mut last_reset = rec.first().map(|r| r.reset_counter);
    let mut nees = Vec::with_capacity(rec.len());
    for r in rec {
        let t = r.t_s;
        est.push(r.p);
        let p_true = ds.trajectory.sample(t).p_B_in_W;
        truth.push(p_true);
        let sigma_m = r.ardupilot_position_sigma_m();
        if sigma_m > 0.0 {
            nees.push((r.p - p_true).norm_squared() / (sigma_m * sigma_m));
        }
        let k = (t * rate_imu).round();
        if k >= 0.0 {
            if let Some(Some(w)) = sent_wall.get(k as usize) {
                lat.push(r.wall.saturating_duration_since(*w).as_secs_f64() * 1e3);
            }
        }
        if Some(r.reset_counter) != last_reset {
            resets += 1;
            last_reset = Some(r.reset_counter);
        }
        // Diagonal entries of the upper-triangular layout: 0, 6, 11, 15, 18, 20.
        cov_ok &= r.cov.iter().all(|c| c.is_finite()) && [0, 6, 11, 15, 18, 20].iter().all(|&i| r.cov[i] > 0.0);
    }
    let ate = if est.is_empty() {
        None
    } else {
        Some(metrics::ate(&est, &truth))
    };
    let t_first = rec.first().map_or(f64::NAN, |r| r.t_s);
    let t_last = rec.last().map_or(f64::NAN, |r| r.t_s);
    let (output_gap_max_s, output_gap_total_s) = output_gaps(&output_times(rec));
    Report {
        duration_s: ds.duration_s,
        estimates_received: rec.len(),
        output_rate_hz: if rec.len() > 1 {
            (rec.len() - 1) as f64 / (t_last - t_first)
        } else {
            0.0
        },
        ate_m: ate.map_or(f64::NAN, |a| a.unaligned_m),
        ate_aligned_m: ate.map_or(f64::NAN, |a| a.aligned_m),
        latency_ms_p50: percentile(&mut lat.clone(), 0.5).unwrap_or(f64::NAN),
        latency_ms_p99: percentile(&mut lat.clone(), 0.99).unwrap_or(f64::NAN),
        latency_ms_max: lat.iter().copied().fold(f64::NAN, f64::max),
        time_to_first_estimate_s: t_first,
        reset_count: resets,
        covariance_ok: cov_ok && !rec.is_empty(),
        position_nees_mean: if nees.is_empty() {
            f64::NAN
        } else {
            nees.iter().sum::<f64>() / nees.len() as f64
        },
        position_nees_in95: if nees.is_empty() {
            f64::NAN
        } else {
            // χ²₀.₉₅(3).
            nees.iter().filter(|n| **n <= 7.815).count() as f64 / nees.len() as f64
        },
        quality_min: rec.iter().filter_map(|r| r.quality).min(),
        imu_sent,
        frames_sent,
        speedup,
        odometry_received: 0,
        vpe_received: 0,
        speed_estimates_received: 0,
        odometry_malformed: 0,
        gps_origin_set: false,
        output_gap_max_s,
        output_gap_total_s,
        autopilot: AutopilotReport::default(),
        faults: Vec::new(),
        status_texts: Vec::new(),
    }
}

/// Error, peak and recovery around one fault (see [`FaultReport`]).
fn fault_report(
    ds: &Dataset,
    rec: &[Received],
    heartbeats: &[Heartbeat],
    f: &Fault,
    overlap_end_s: f64,
) -> FaultReport {
    let end = f.start_s + f.duration_s;
    // Sent after the fault began, while the daemon's own clock (its last
    // estimate) was between just before the fault (a silent link stops the
    // estimates) and 3 s after its end.
    let degraded_reported = heartbeats.iter().any(|h| {
        let t_daemon_s = h
            .estimates_before
            .checked_sub(1)
            .and_then(|i| rec.get(i))
            .map_or(f64::NEG_INFINITY, |r| r.t_s);
        h.state != apm::MavState::MAV_STATE_ACTIVE
            && h.t_arrival_s >= f.start_s
            && (f.start_s - 0.5..=end + 3.0).contains(&t_daemon_s)
    });
    let err: Vec<(f64, f64, u8)> = rec
        .iter()
        .map(|r| {
            let t = r.t_s;
            (t, (r.p - ds.trajectory.sample(t).p_B_in_W).norm(), r.reset_counter)
        })
        .collect();
    let mut before: Vec<f64> = err
        .iter()
        .filter(|e| e.0 >= f.start_s - 5.0 && e.0 < f.start_s)
        .map(|e| e.1)
        .collect();
    let baseline = percentile(&mut before, 0.5).unwrap_or(f64::NAN);
    let threshold = 2.0 * if baseline.is_finite() { baseline } else { 0.0 } + 0.5;
    let window: Vec<&(f64, f64, u8)> = err.iter().filter(|e| e.0 >= f.start_s && e.0 <= end + 5.0).collect();
    let peak = window.iter().map(|e| e.1).fold(0.0, f64::max);
    // Resets: changes of reset_counter from the last estimate before the
    // fault through the window.
    let before_start = err.iter().rev().find(|e| e.0 < f.start_s).map(|e| e.2);
    let counters: Vec<u8> = before_start.into_iter().chain(window.iter().map(|e| e.2)).collect();
    let resets = counters.windows(2).filter(|w| w[0] != w[1]).count() as u32;
    FaultReport {
        name: f.kind.name().to_string(),
        start_s: f.start_s,
        end_s: end,
        recovery_s: recovery(&err, f.start_s, end, threshold),
        peak_error_m: peak,
        resets,
        degraded_reported,
        output_gap_max_s: window_gap_max(&output_times(rec), f.start_s, end + 5.0),
        overlap_end_s,
        recovery_after_overlap_s: recovery(&err, f.start_s, overlap_end_s, threshold),
    }
}

/// Seconds after `end` until the error (`(t, error, _)` in time order) is
/// back under `threshold`: the first estimate from `end` on from which
/// every estimate for a second stays under it. 0 if no estimate in
/// `[start, end + 5 s]` exceeded it; NaN if it never came back.
fn recovery(err: &[(f64, f64, u8)], start: f64, end: f64, threshold: f64) -> f64 {
    let exceeded = err.iter().any(|e| e.0 >= start && e.0 <= end + 5.0 && e.1 > threshold);
    if !exceeded {
        return 0.0;
    }
    let after: Vec<&(f64, f64, u8)> = err.iter().filter(|e| e.0 >= end).collect();
    after
        .iter()
        .enumerate()
        .find(|(i, e)| {
            after[*i..]
                .iter()
                .take_while(|x| x.0 <= e.0 + 1.0)
                .all(|x| x.1 <= threshold)
        })
        .map_or(f64::NAN, |(_, e)| (e.0 - end).max(0.0))
}

/// End of the last of `faults` that overlaps `f`, directly or through a
/// chain of overlapping faults.
fn overlap_end(faults: &[Fault], f: &Fault) -> f64 {
    let (mut lo, mut hi) = (f.start_s, f.start_s + f.duration_s);
    loop {
        let (lo0, hi0) = (lo, hi);
        for g in faults {
            let g_end = g.start_s + g.duration_s;
            if g.start_s < hi && g_end > lo {
                lo = lo.min(g.start_s);
                hi = hi.max(g_end);
            }
        }
        if (lo, hi) == (lo0, hi0) {
            return hi;
        }
    }
}

/// Flight times of the estimates, in time order (the non-finite dropped).
fn output_times(rec: &[Received]) -> Vec<f64> {
    let mut t: Vec<f64> = rec.iter().map(|r| r.t_s).filter(|t| t.is_finite()).collect();
    t.sort_by(f64::total_cmp);
    t
}

/// The longest interval between consecutive times `t` (sorted), and the
/// sum of what each interval lasts beyond twice the median one (s; NaN and
/// 0 with fewer than two).
fn output_gaps(t: &[f64]) -> (f64, f64) {
    let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    let Some(median) = percentile(&mut d.clone(), 0.5) else {
        return (f64::NAN, 0.0);
    };
    let max = d.iter().copied().fold(0.0, f64::max);
    d.retain(|x| *x > 2.0 * median);
    (max, d.iter().fold(0.0, |sum, x| sum + x - 2.0 * median))
}

/// The longest interval between consecutive times `t` (sorted) that
/// overlaps `[from, to]`, whole (NaN with no estimates; 0 with a single one).
fn window_gap_max(t: &[f64], from: f64, to: f64) -> f64 {
    if t.is_empty() {
        return f64::NAN;
    }
    t.windows(2)
        .filter(|w| w[1] > from && w[0] < to)
        .map(|w| w[1] - w[0])
        .fold(0.0, f64::max)
}

/// Flight times of the estimates, in arrival order: their boot-clock stamps
/// mapped back through [`super::clock::FlightClock`].
pub(super) fn flight_times(rec: &mut [Received], reboot_s: Option<f64>) {
    let mut clock = FlightClock::new(reboot_s);
    for r in rec {
        r.t_s = clock.flight_s(r.t_us);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::serve::FaultKind;

    fn fault(kind: FaultKind, start_s: f64, duration_s: f64) -> Fault {
        Fault {
            kind,
            start_s,
            duration_s,
        }
    }

    #[test]
    fn output_gaps_measure_silence_beyond_the_rate() {
        // 30 Hz, a 2 s silence from 1.0 s, then 30 Hz again.
        let mut t: Vec<f64> = (0..=30).map(|k| k as f64 / 30.0).collect();
        t.extend((0..=30).map(|k| 3.0 + k as f64 / 30.0));
        let (max, total) = output_gaps(&t);
        assert!((max - 2.0).abs() < 1e-9, "{max}");
        assert!((total - (2.0 - 2.0 / 30.0)).abs() < 1e-9, "{total}");
        // A steady stream has no gap beyond the rate; too few estimates, none.
        let steady: Vec<f64> = (0..90).map(|k| k as f64 / 30.0).collect();
        assert_eq!(output_gaps(&steady).1, 0.0);
        assert!(output_gaps(&[1.0]).0.is_nan());
        // The whole silence counts in any window it overlaps.
        assert!((window_gap_max(&t, 2.5, 4.0) - 2.0).abs() < 1e-9);
        assert!(window_gap_max(&t, 3.5, 4.0) < 0.04);
        assert!(window_gap_max(&[], 0.0, 1.0).is_nan());
    }

    #[test]
    fn overlap_end_follows_a_chain_of_faults() {
        let faults = [
            fault(FaultKind::GnssOutage, 20.0, 40.0),
            fault(FaultKind::CameraOutage, 30.0, 10.0),
            fault(FaultKind::PrOutlier, 58.0, 5.0),
            fault(FaultKind::LinkDrop, 70.0, 5.0),
        ];
        assert_eq!(overlap_end(&faults, &faults[1]), 63.0);
        assert_eq!(overlap_end(&faults, &faults[0]), 63.0);
        assert_eq!(overlap_end(&faults, &faults[3]), 75.0);
    }

    #[test]
    fn recovery_counts_from_the_given_end() {
        // Error 3 m from 30 s to 61 s, 0.2 m otherwise, at 10 Hz.
        let err: Vec<(f64, f64, u8)> = (0..900)
            .map(|k| {
                let t = k as f64 / 10.0;
                (t, if (30.0..61.0).contains(&t) { 3.0 } else { 0.2 }, 0)
            })
            .collect();
        assert!((recovery(&err, 30.0, 40.0, 0.9) - 21.0).abs() < 1e-9);
        assert!((recovery(&err, 30.0, 60.0, 0.9) - 1.0).abs() < 1e-9);
        assert_eq!(recovery(&err, 70.0, 75.0, 0.9), 0.0);
        let never: Vec<(f64, f64, u8)> = err.iter().map(|e| (e.0, 3.0, 0)).collect();
        assert!(recovery(&never, 30.0, 40.0, 0.9).is_nan());
    }
}
