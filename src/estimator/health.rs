//! Divergence detection: the filter judges itself by its innovations.
//!
//! A consistent filter's normalised innovation squared (NIS) has a χ²
//! distribution: per degree of freedom its mean is 1, and the χ² gate
//! rejects only the rare outlier. A diverged filter (a state far from the
//! truth with a covariance that does not know it) sees every measurement as
//! an outlier. So, over a sliding window of measurement time (README.md §9):
//!
//! - **D1 (vision):** over the last `window_s` if it holds `min_tracks`
//!   tracks, else over as far back as it takes to hold them, up to
//!   `max_window_s` (a real front-end gives 20–40 tracks a second, not 60),
//!   and with at least `min_tracks_long` there, the fraction the poses
//!   cannot explain (rejected by the χ² gate, or failing to triangulate to a
//!   valid depth or fit) above `max_reject_fraction` (above
//!   `max_reject_fraction_long` over the longer window: a hover's few tracks
//!   fail to triangulate at about half that rate), or the accepted tracks'
//!   mean NIS per degree of freedom above `max_nis_per_dof`;
//! - **D3 (standstill):** over the last `window_s`, with at least
//!   `min_zupts` frames that the IMU and the image call still, and two
//!   thirds of the frames at least (a hover's gusts let a few through), more than
//!   `max_reject_fraction` of their zero-velocity updates refused by the χ²
//!   gate of their gyro rows: a standing vehicle whose filter cannot believe
//!   the rate its gyro measures (a gyro bias far beyond its sigma) sees no
//!   parallax either, so D1 has nothing to judge (a refusal by the velocity
//!   rows, a hover's slow drift, counts for nothing);
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
    /// How far back D1 looks for `min_tracks` when the last `window_s`
    /// holds fewer (s), the fewest it judges there, and the inconsistent
    /// fraction that is a divergence there (few tracks in a hover, with
    /// little parallax, fail to triangulate at half that rate; a diverged
    /// filter loses nearly all).
    pub max_window_s: f64,
    pub min_tracks_long: u64,
    pub max_reject_fraction_long: f64,
    /// Fewest still frames D3 judges in `window_s`.
    pub min_zupts: u64,
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
            max_window_s: 3.0,
            min_tracks_long: 40,
            max_reject_fraction_long: 0.8,
            min_zupts: 10,
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
    /// Tracks the χ² gate refused, and tracks that failed to triangulate to
    /// a valid depth or fit.
    chi2_rejected: u64,
    tri_failed: u64,
    nis_sum: f64,
    dof_sum: u64,
}

/// One still frame's zero-velocity update: taken, or refused by its gate.
#[derive(Clone, Copy, Debug)]
struct ZuptGate {
    t_s: f64,
    rejected: bool,
}

/// The sliding-window NIS monitor.
#[derive(Clone, Debug, Default)]
pub struct NisMonitor {
    pub settings: MonitorSettings,
    frames: VecDeque<FrameGate>,
    zupts: VecDeque<ZuptGate>,
    /// `(accepted, rejected)` pseudoranges of the last epochs.
    gnss: VecDeque<(usize, usize)>,
}

impl NisMonitor {
    pub fn new(settings: MonitorSettings) -> Self {
        Self {
            settings,
            frames: VecDeque::with_capacity(128),
            zupts: VecDeque::with_capacity(128),
            gnss: VecDeque::with_capacity(settings.gnss_epochs + 1),
        }
    }

    /// Records a frame: the NIS and degrees of freedom of each accepted
    /// track, and the numbers of tracks the χ² gate refused and that failed
    /// to triangulate.
    pub fn push_frame(&mut self, t_s: f64, nis: &[(f64, usize)], chi2_rejected: u64, tri_failed: u64) {
        while self
            .frames
            .front()
            .is_some_and(|f| f.t_s < t_s - self.settings.max_window_s.max(self.settings.window_s))
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
            chi2_rejected,
            tri_failed,
            nis_sum: nis.iter().map(|n| n.0).sum(),
            dof_sum: nis.iter().map(|n| n.1 as u64).sum(),
        });
    }

    /// Records a frame that the IMU and the image call still: whether its
    /// zero-velocity update was refused by the χ² gate.
    pub fn push_zupt(&mut self, t_s: f64, rejected: bool) {
        while self.zupts.front().is_some_and(|z| z.t_s < t_s - self.settings.window_s) {
            self.zupts.pop_front();
        }
        if self.zupts.len() >= 1000 {
            self.zupts.pop_front();
        }
        self.zupts.push_back(ZuptGate { t_s, rejected });
    }

    /// Records a GNSS epoch: pseudoranges accepted and rejected by the gate.
    pub fn push_gnss(&mut self, accepted: usize, rejected: usize) {
        if self.gnss.len() >= self.settings.gnss_epochs.max(1) {
            self.gnss.pop_front();
        }
        self.gnss.push_back((accepted, rejected));
    }

    /// `Err(reason)` when the innovations say the filter has diverged:
    /// D2 always, D1 and D3 when `judge_vision` (not in the grace after an
    /// IMU gap, whose tracks meet poses it left off).
    pub fn verdict(&self, judge_vision: bool) -> Result<(), String> {
        if judge_vision {
            self.vision_verdict()?;
        }
        self.gnss_verdict()
    }

    /// D1 and D3.
    fn vision_verdict(&self) -> Result<(), String> {
        let s = &self.settings;
        // D1: the newest frames back to `window_s`, and on past it while
        // they hold fewer than `min_tracks`, up to `max_window_s`.
        let t_last = self.frames.back().map_or(0.0, |f| f.t_s);
        let (mut acc, mut chi2, mut tri, mut nis, mut dof, mut span_s) = (0, 0, 0, 0.0, 0, 0.0);
        for f in self.frames.iter().rev() {
            let age_s = t_last - f.t_s;
            if age_s > s.max_window_s || (age_s > s.window_s && acc + chi2 + tri >= s.min_tracks) {
                break;
            }
            (acc, chi2, tri, nis, dof, span_s) = (
                acc + f.accepted,
                chi2 + f.chi2_rejected,
                tri + f.tri_failed,
                nis + f.nis_sum,
                dof + f.dof_sum,
                age_s,
            );
        }
        let window_s = span_s.max(s.window_s);
        if span_s <= s.window_s {
            // The last second holds enough: all inconsistent tracks count.
            let n = acc + chi2 + tri;
            if n >= s.min_tracks && (chi2 + tri) as f64 > s.max_reject_fraction * n as f64 {
                return Err(format!(
                    "divergence: {:.0}% of {n} tracks inconsistent in {window_s:.1} s",
                    100.0 * (chi2 + tri) as f64 / n as f64
                ));
            }
        } else {
            // Few tracks over a longer window: only the gate's verdicts
            // (a hover's few tracks fail to triangulate for want of
            // parallax, at 80% and more, on a healthy filter).
            let n = acc + chi2;
            if n >= s.min_tracks_long && chi2 as f64 > s.max_reject_fraction_long * n as f64 {
                return Err(format!(
                    "divergence: {:.0}% of {n} tracks refused by the gate in {window_s:.1} s",
                    100.0 * chi2 as f64 / n as f64
                ));
            }
        }
        let judged = acc + chi2 + tri >= s.min_tracks || (span_s > s.window_s && acc >= s.min_tracks_long);
        if judged && dof > 0 && nis / dof as f64 > s.max_nis_per_dof {
            return Err(format!(
                "divergence: mean NIS per degree of freedom {:.1} over {acc} tracks in {window_s:.1} s",
                nis / dof as f64
            ));
        }
        // D3: most frames of the last second still (a standing vehicle's
        // are all; a hover's gusts let a few through), most refused.
        let still = self.zupts.len() as u64;
        let refused = self.zupts.iter().filter(|z| z.rejected).count() as u64;
        let frames = self
            .frames
            .iter()
            .rev()
            .take_while(|f| f.t_s > t_last - s.window_s)
            .count() as u64;
        if still >= s.min_zupts && 3 * still >= 2 * frames && refused as f64 > s.max_reject_fraction * still as f64 {
            return Err(format!(
                "divergence: {refused} of {still} zero-velocity updates refused in {} s while still",
                s.window_s
            ));
        }
        Ok(())
    }

    /// D2.
    fn gnss_verdict(&self) -> Result<(), String> {
        let s = &self.settings;
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
        // After an IMU gap, the tracks across it wait their grace (§2, N3).
        self.monitor
            .verdict(self.t_s - self.vision_grace_from_s >= self.s.health_grace_s)
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
            m.push_frame(k as f64 / 30.0, &[(3.8, 4); 49], 1, 0);
            assert!(m.verdict(true).is_ok());
        }
        // Nothing at all (an outage) is not a divergence.
        let mut quiet = NisMonitor::new(MonitorSettings::default());
        for k in 0..90 {
            quiet.push_frame(k as f64 / 30.0, &[], 0, 0);
        }
        assert!(quiet.verdict(true).is_ok());
        // Then most tracks fail the gate: diverged within the window.
        let mut fired = None;
        for k in 90..200 {
            m.push_frame(k as f64 / 30.0, &[(3.8, 4); 10], 40, 0);
            if m.verdict(true).is_err() {
                fired = Some(k);
                break;
            }
        }
        let k = fired.expect("divergence detected");
        assert!(k < 90 + 90, "fired after {} frames", k - 90);
        // Accepted but far too large innovations also count.
        let mut big = NisMonitor::new(MonitorSettings::default());
        for k in 0..30 {
            big.push_frame(k as f64 / 30.0, &[(40.0, 4); 20], 0, 0);
        }
        assert!(big.verdict(true).unwrap_err().contains("mean NIS"));
    }

    #[test]
    fn gnss_rejecting_most_codes_is_a_divergence() {
        let mut m = NisMonitor::new(MonitorSettings::default());
        // Two outliers in 16 (a multipath-heavy sky) is healthy.
        for _ in 0..10 {
            m.push_gnss(14, 2);
            assert!(m.verdict(true).is_ok());
        }
        for _ in 0..2 {
            m.push_gnss(4, 12);
        }
        assert!(m.verdict(true).is_ok(), "two bad epochs of five");
        m.push_gnss(4, 12);
        m.push_gnss(4, 12);
        assert!(m.verdict(true).unwrap_err().contains("pseudoranges"));
        // Too few satellites to judge never fires.
        let mut few = NisMonitor::new(MonitorSettings::default());
        for _ in 0..20 {
            few.push_gnss(0, 3);
        }
        assert!(few.verdict(true).is_ok());
    }

    #[test]
    fn few_tracks_a_second_are_judged_over_a_longer_window() {
        // 20 tracks a second (a real front-end), 1 a frame at 20 Hz: the
        // 1 s window never holds 60, so the monitor looks back up to 3 s.
        let mut m = NisMonitor::new(MonitorSettings::default());
        for k in 0..200 {
            m.push_frame(k as f64 / 20.0, &[(4.2, 4)], 0, 0);
            assert!(m.verdict(true).is_ok(), "healthy at frame {k}");
        }
        let mut fired = None;
        for k in 200..400 {
            // Then seven tracks of eight fail the gate.
            let accepted: &[(f64, usize)] = if k % 8 == 0 { &[(4.2, 4)] } else { &[] };
            m.push_frame(k as f64 / 20.0, accepted, u64::from(k % 8 != 0), 0);
            if let Err(e) = m.verdict(true) {
                assert!(e.contains("refused by the gate"), "{e}");
                fired = Some(k - 200);
                break;
            }
        }
        let frames = fired.expect("divergence detected with 20 tracks a second");
        assert!(frames <= 60, "fired after {frames} frames (3 s)");
        // A hover's few tracks, half failing to triangulate for want of
        // parallax, are not a divergence.
        let mut hover = NisMonitor::new(MonitorSettings::default());
        for k in 0..200 {
            let accepted: &[(f64, usize)] = if k % 2 == 0 { &[(4.2, 4)] } else { &[] };
            hover.push_frame(k as f64 / 20.0, accepted, 0, u64::from(k % 2 != 0));
            assert!(hover.verdict(true).is_ok(), "hover flagged at frame {k}");
        }
        // 10 tracks in 3 s are too few to judge, whatever they say.
        let mut sparse = NisMonitor::new(MonitorSettings::default());
        for k in 0..200 {
            sparse.push_frame(k as f64 / 20.0, &[], u64::from(k % 6 == 0), 0);
        }
        assert!(sparse.verdict(true).is_ok());
    }

    #[test]
    fn refused_zero_velocity_updates_while_still_are_a_divergence() {
        let mut m = NisMonitor::new(MonitorSettings::default());
        // Standing, one update in ten refused: healthy.
        for k in 0..100 {
            m.push_zupt(k as f64 / 20.0, k % 10 == 0);
            assert!(m.verdict(true).is_ok());
        }
        // A few refused at a take-off's first frames: too few to judge.
        let mut takeoff = NisMonitor::new(MonitorSettings::default());
        for k in 0..5 {
            takeoff.push_zupt(k as f64 / 20.0, true);
        }
        assert!(takeoff.verdict(true).is_ok());
        // Every update refused for a second: the filter cannot believe the
        // vehicle stands.
        for k in 100..120 {
            m.push_zupt(k as f64 / 20.0, true);
        }
        assert!(m.verdict(true).unwrap_err().contains("zero-velocity"));
    }
}
