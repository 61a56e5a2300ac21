//! Divergence detection: the filter judges itself by its innovations.
//!
//! A consistent filter's normalised innovation squared (NIS) has a χ²
//! distribution: per degree of freedom its mean is 1, and the χ² gate
//! rejects only the rare outlier. A diverged filter (a state far from the
//! truth with a covariance that does not know it) sees every measurement as
//! an outlier. So, over a sliding window of measurement time (README.md §9):
//!
//! - **D1 (vision):** with at least `min_tracks` tracks in the window, the
//!   fraction the poses cannot explain (rejected by the χ² gate, or failing
//!   to triangulate to a valid depth or fit) above `max_reject_fraction`, or the
//!   accepted tracks' mean NIS per degree of freedom above `max_nis_per_dof`;
//! - **D2 (GNSS):** over the last `gnss_epochs` epochs, with at least
//!   `min_gnss_codes` pseudoranges gated, the fraction rejected above
//!   `max_reject_fraction`.
//!
//! In a healthy flight the gate rejects a few per cent (outliers, multipath);
//! a position knocked 20 m off makes it reject about half of the tracks and
//! most pseudoranges.
//!
//! Either is a divergence. Outages (no measurements) are not: the window
//! then holds too few to judge. Memory is bounded by the window's length.
//!
//! [`Estimator::check_health`] adds the plain checks: a finite, positive
//! covariance and a state within physical bounds.

use std::collections::VecDeque;

use super::{math, Estimator, ACTIVE_DIM, MAX_ACCEL_BIAS_MPS2, MAX_GYRO_BIAS_RADPS, MAX_SPEED_MPS};

/// Thresholds of the monitor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MonitorSettings {
    pub window_s: f64,
    pub min_tracks: u64,
    pub max_reject_fraction: f64,
    pub max_nis_per_dof: f64,
    pub gnss_epochs: usize,
    pub min_gnss_codes: usize,
}

impl Default for MonitorSettings {
    fn default() -> Self {
        Self {
            window_s: 1.0,
            min_tracks: 60,
            max_reject_fraction: 0.5,
            max_nis_per_dof: 5.0,
            gnss_epochs: 5,
            min_gnss_codes: 20,
        }
    }
}

/// One frame's gate outcome.
#[derive(Clone, Copy, Debug)]
struct FrameGate {
    t_s: f64,
    accepted: u64,
    rejected: u64,
    nis_sum: f64,
    dof_sum: u64,
}

/// The sliding-window NIS monitor.
#[derive(Clone, Debug, Default)]
pub struct NisMonitor {
    pub settings: MonitorSettings,
    frames: VecDeque<FrameGate>,
    /// `(accepted, rejected)` pseudoranges of the last epochs.
    gnss: VecDeque<(usize, usize)>,
}

impl NisMonitor {
    pub fn new(settings: MonitorSettings) -> Self {
        Self {
            settings,
            frames: VecDeque::with_capacity(128),
            gnss: VecDeque::with_capacity(settings.gnss_epochs + 1),
        }
    }

    /// Records a frame: the NIS and degrees of freedom of each accepted
    /// track, and the number of tracks rejected as inconsistent.
    pub fn push_frame(&mut self, t_s: f64, nis: &[(f64, usize)], rejected: u64) {
        while self
            .frames
            .front()
            .is_some_and(|f| f.t_s < t_s - self.settings.window_s)
        {
            self.frames.pop_front();
        }
        // Bounded even if the time stamps stall: at most 1000 frames.
        if self.frames.len() >= 1000 {
            self.frames.pop_front();
        }
        self.frames.push_back(FrameGate {
            t_s,
            accepted: nis.len() as u64,
            rejected,
            nis_sum: nis.iter().map(|n| n.0).sum(),
            dof_sum: nis.iter().map(|n| n.1 as u64).sum(),
        });
    }

    /// Records a GNSS epoch: pseudoranges accepted and rejected by the gate.
    pub fn push_gnss(&mut self, accepted: usize, rejected: usize) {
        if self.gnss.len() >= self.settings.gnss_epochs.max(1) {
            self.gnss.pop_front();
        }
        self.gnss.push_back((accepted, rejected));
    }

    /// `Err(reason)` when the innovations say the filter has diverged.
    pub fn verdict(&self) -> Result<(), String> {
        let s = &self.settings;
        let (acc, rej, nis, dof) = self.frames.iter().fold((0, 0, 0.0, 0), |a, f| {
            (a.0 + f.accepted, a.1 + f.rejected, a.2 + f.nis_sum, a.3 + f.dof_sum)
        });
        let n = acc + rej;
        if n >= s.min_tracks {
            let frac = rej as f64 / n as f64;
            if frac > s.max_reject_fraction {
                return Err(format!(
                    "divergence: {:.0}% of {n} tracks inconsistent in {} s",
                    100.0 * frac,
                    s.window_s
                ));
            }
            if dof > 0 && nis / dof as f64 > s.max_nis_per_dof {
                return Err(format!(
                    "divergence: mean NIS per degree of freedom {:.1} over {acc} tracks in {} s",
                    nis / dof as f64,
                    s.window_s
                ));
            }
        }
        let (acc, rej) = self.gnss.iter().fold((0, 0), |a, g| (a.0 + g.0, a.1 + g.1));
        if acc + rej >= s.min_gnss_codes && rej as f64 > s.max_reject_fraction * (acc + rej) as f64 {
            return Err(format!(
                "divergence: {rej} of {} pseudoranges rejected in {} GNSS epochs",
                acc + rej,
                self.gnss.len()
            ));
        }
        Ok(())
    }
}

impl Estimator {
    /// Health checks (§9): the covariance finite, symmetric, with a positive
    /// diagonal and a positive-definite active block; the state finite and
    /// within physical bounds; and the NIS monitor's verdict. Returns the
    /// first problem found. Allocation-free, so it can run every IMU sample.
    pub(super) fn judge_health(&self) -> Result<(), String> {
        let p = &self.P;
        if !math::all_finite(p.as_slice()) {
            return Err("covariance has non-finite entries".into());
        }
        for i in 0..p.nrows() {
            if p[(i, i)] <= 0.0 {
                return Err(format!("covariance diagonal {i} is {}", p[(i, i)]));
            }
        }
        // Symmetric (updates and propagation keep it exactly so, so any
        // asymmetry is a fault), and
        // the active block positive definite (a Cholesky of 18×18: cheap).
        // |P_ij − P_ji| ≤ 1e-9 √(P_ii P_jj), compared squared (no root).
        let n = p.nrows();
        for i in 0..n.min(ACTIVE_DIM) {
            let pii = p[(i, i)];
            for j in 0..n {
                let d = p[(i, j)] - p[(j, i)];
                if d * d > 1e-18 * pii * p[(j, j)] {
                    return Err(format!("covariance is not symmetric at ({i}, {j})"));
                }
            }
        }
        if p.fixed_view::<ACTIVE_DIM, ACTIVE_DIM>(0, 0)
            .into_owned()
            .cholesky()
            .is_none()
        {
            return Err("the active covariance block is not positive definite".into());
        }
        let i = &self.imu;
        if ![i.v_B_in_W, i.p_B_in_W, i.b_a, i.b_g]
            .iter()
            .all(|v| v.iter().all(|x| x.is_finite()))
        {
            return Err("state has non-finite entries".into());
        }
        // State sanity: a multirotor's envelope, with margin.
        if i.v_B_in_W.norm() > MAX_SPEED_MPS {
            return Err(format!(
                "speed {:.0} m/s is beyond {MAX_SPEED_MPS} m/s",
                i.v_B_in_W.norm()
            ));
        }
        if i.b_a.norm() > MAX_ACCEL_BIAS_MPS2 || i.b_g.norm() > MAX_GYRO_BIAS_RADPS {
            return Err(format!(
                "IMU bias out of range (accel {:.2} m/s², gyro {:.3} rad/s)",
                i.b_a.norm(),
                i.b_g.norm()
            ));
        }
        // A short grace period after the start: the first tracks are short
        // and the prior still settling, so the innovations judge nothing yet.
        if self.t_s - self.t_start_s < self.s.health_grace_s {
            return Ok(());
        }
        self.monitor.verdict()
    }

    /// Starts the monitor's grace period at `t_s` (a filter restarted from
    /// an estimate of a moment ago is new from now, not from that moment).
    pub fn start_health_grace(&mut self, t_s: f64) {
        self.t_start_s = t_s;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn consistent_innovations_pass_and_inconsistent_ones_fail() {
        let mut m = NisMonitor::new(MonitorSettings::default());
        // 90 frames of 50 tracks with NIS ≈ dof and 2% rejected: healthy.
        for k in 0..90 {
            m.push_frame(k as f64 / 30.0, &[(3.8, 4); 49], 1);
            assert!(m.verdict().is_ok());
        }
        // Nothing at all (an outage) is not a divergence.
        let mut quiet = NisMonitor::new(MonitorSettings::default());
        for k in 0..90 {
            quiet.push_frame(k as f64 / 30.0, &[], 0);
        }
        assert!(quiet.verdict().is_ok());
        // Then most tracks fail the gate: diverged within the window.
        let mut fired = None;
        for k in 90..200 {
            m.push_frame(k as f64 / 30.0, &[(3.8, 4); 10], 40);
            if m.verdict().is_err() {
                fired = Some(k);
                break;
            }
        }
        let k = fired.expect("divergence detected");
        assert!(k < 90 + 90, "fired after {} frames", k - 90);
        // Accepted but far too large innovations also count.
        let mut big = NisMonitor::new(MonitorSettings::default());
        for k in 0..30 {
            big.push_frame(k as f64 / 30.0, &[(40.0, 4); 20], 0);
        }
        assert!(big.verdict().unwrap_err().contains("mean NIS"));
    }

    #[test]
    fn gnss_rejecting_most_codes_is_a_divergence() {
        let mut m = NisMonitor::new(MonitorSettings::default());
        // Two outliers in 16 (a multipath-heavy sky) is healthy.
        for _ in 0..10 {
            m.push_gnss(14, 2);
            assert!(m.verdict().is_ok());
        }
        for _ in 0..2 {
            m.push_gnss(4, 12);
        }
        assert!(m.verdict().is_ok(), "two bad epochs of five");
        m.push_gnss(4, 12);
        m.push_gnss(4, 12);
        assert!(m.verdict().unwrap_err().contains("pseudoranges"));
        // Too few satellites to judge never fires.
        let mut few = NisMonitor::new(MonitorSettings::default());
        for _ in 0..20 {
            few.push_gnss(0, 3);
        }
        assert!(few.verdict().is_ok());
    }
}
