//! Scoring of a served flight: accuracy, rate, latency, resets and
//! covariance of the daemon's estimates against the truth, and how it came
//! through each injected fault.

use std::time::Instant;

use cmsckf_models::stats::percentile;
use mavlink::dialects::ardupilotmega as apm;
use serde::Serialize;

use super::fault::Fault;
use super::receive::{Heartbeat, Inbox, Received};
use super::{ServeOptions, BOOT0_S};
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
    pub imu_sent: usize,
    pub frames_sent: usize,
    pub speedup: f64,
    pub odometry_received: usize,
    pub gps_origin_set: bool,
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
    report.faults = opts.faults.iter().map(|f| fault_report(ds, &rec, &hbs, f)).collect();
    report.status_texts = inbox.status_texts.lock().map(|v| v.clone()).unwrap_or_default();
    if let Ok(e) = inbox.extras.lock() {
        report.odometry_received = e.0;
        report.gps_origin_set = e.1 > 0;
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
    for r in rec {
        let t = r.t_s;
        est.push(r.p);
        truth.push(ds.trajectory.sample(t).p_B_in_W);
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
        imu_sent,
        frames_sent,
        speedup,
        odometry_received: 0,
        gps_origin_set: false,
        faults: Vec::new(),
        status_texts: Vec::new(),
    }
}

/// Error, peak and recovery around one fault (see [`FaultReport`]).
fn fault_report(ds: &Dataset, rec: &[Received], heartbeats: &[Heartbeat], f: &Fault) -> FaultReport {
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
    // Recovered at the first time after the end from which every estimate
    // for a second stays under the threshold.
    let after: Vec<&(f64, f64, u8)> = err.iter().filter(|e| e.0 >= end).collect();
    let exceeded = window.iter().any(|e| e.1 > threshold);
    let recovery_s = if !exceeded {
        0.0
    } else {
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
    };
    FaultReport {
        name: f.kind.name().to_string(),
        start_s: f.start_s,
        end_s: end,
        recovery_s,
        peak_error_m: peak,
        resets,
        degraded_reported,
    }
}

/// Flight times of the estimates, in arrival order: their boot-clock stamps
/// mapped back through [`super::clock::boot_us`], switching to the post-reboot clock at
/// the first stamp that falls back by more than 2 s.
pub(super) fn flight_times(rec: &mut [Received], reboot_s: Option<f64>) {
    let mut after = false;
    let mut max_boot_s = f64::NEG_INFINITY;
    for r in rec {
        let boot_s = r.t_us as f64 * 1e-6;
        if reboot_s.is_some() && boot_s < max_boot_s - 2.0 {
            after = true;
        }
        max_boot_s = max_boot_s.max(boot_s);
        r.t_s = match reboot_s {
            Some(rb) if after => boot_s + rb - 1.0,
            _ => boot_s - BOOT0_S,
        };
    }
}
