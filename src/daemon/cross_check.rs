//! Our velocity against the autopilot's own: a divergence check that needs
//! no tracks at all (README §9, D4).
//!
//! When the autopilot has a position source of its own (a 3D GNSS fix), its
//! EKF's velocity is independent of ours, and good to a few decimetres a
//! second. A filter of ours whose velocity stays metres per second away
//! from it, far beyond both sigmas, has diverged, however few tracks it sees
//! and whatever its innovations say. Without a fix of its own the
//! autopilot's velocity may be the echo of ours (external navigation as its
//! only source): nothing is judged then.

use nalgebra::{Matrix3, Vector3};

/// The autopilot's velocity is taken as this good, one sigma per axis
/// (m/s): a GNSS-aided EKF's.
const AUTOPILOT_VELOCITY_SIGMA_MPS: f64 = 0.5;
/// A disagreement counts beyond this many sigmas of the difference, and
/// never below [`DISAGREE_FLOOR_MPS`].
const DISAGREE_SIGMAS: f64 = 5.0;
const DISAGREE_FLOOR_MPS: f64 = 2.0;
/// It must last this long (s) before it is a divergence: a gust, a late
/// message or a take-off's first second are not.
const DISAGREE_FOR_S: f64 = 2.0;
/// The autopilot's velocity is used only this fresh (s).
const FRESH_S: f64 = 0.5;

/// Tracks how long our velocity has disagreed with the autopilot's own.
#[derive(Debug, Default)]
pub(super) struct VelocityCrossCheck {
    since_s: Option<f64>,
}

impl VelocityCrossCheck {
    /// Judges our velocity at IMU time `t_s` against the autopilot's
    /// `(v, t)`, given only when it has a fix of its own: `Err(reason)` once
    /// they have disagreed for [`DISAGREE_FOR_S`]. `ours` gives our velocity
    /// (m/s, NED) and its covariance, asked for only when there is an
    /// autopilot velocity to judge it against.
    pub(super) fn judge(
        &mut self,
        t_s: f64,
        autopilot: Option<(Vector3<f64>, f64)>,
        ours: impl FnOnce() -> (Vector3<f64>, Matrix3<f64>),
    ) -> Result<(), String> {
        let fresh = |(v, t): &(Vector3<f64>, f64)| (t_s - t).abs() < FRESH_S && v.iter().all(|c| c.is_finite());
        let Some((v_ap, _)) = autopilot.filter(fresh) else {
            self.since_s = None;
            return Ok(());
        };
        let (v_ours, cov_v) = ours();
        let diff_mps = (v_ours - v_ap).norm();
        // σ of |Δv|: both covariances, summed over the axes.
        let sigma_mps = (cov_v.trace().max(0.0) + 3.0 * AUTOPILOT_VELOCITY_SIGMA_MPS.powi(2)).sqrt();
        // (A NaN difference disagrees with nothing.)
        let disagrees = diff_mps > DISAGREE_FLOOR_MPS.max(DISAGREE_SIGMAS * sigma_mps);
        if !disagrees {
            self.since_s = None;
            return Ok(());
        }
        let since = *self.since_s.get_or_insert(t_s);
        if t_s - since >= DISAGREE_FOR_S {
            self.since_s = None;
            return Err(format!(
                "divergence: velocity {diff_mps:.1} m/s off the autopilot's own (GNSS) for {DISAGREE_FOR_S} s"
            ));
        }
        Ok(())
    }

    /// A new filter starts with no disagreement behind it.
    pub(super) fn reset(&mut self) {
        self.since_s = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lasting_disagreement_with_a_fix_is_a_divergence_and_nothing_else_is() {
        let cov = Matrix3::identity() * 0.01;
        let ap = |v: f64, t: f64| Some((Vector3::new(v, 0.0, 0.0), t));
        let mut c = VelocityCrossCheck::default();
        // Agreeing within a metre a second: never.
        for k in 0..500 {
            let t = k as f64 * 0.01;
            assert!(c.judge(t, ap(10.0, t), || (Vector3::new(10.5, 0.0, 0.0), cov)).is_ok());
        }
        // 8 m/s off, but the autopilot has no fix of its own (its velocity
        // may be our echo), or its message is stale: never.
        for k in 0..500 {
            let t = 5.0 + k as f64 * 0.01;
            assert!(c.judge(t, None, || (Vector3::new(18.0, 0.0, 0.0), cov)).is_ok());
            assert!(c
                .judge(t, ap(10.0, t - 1.0), || (Vector3::new(18.0, 0.0, 0.0), cov))
                .is_ok());
        }
        // 8 m/s off for a second (a gust, a late message): not yet.
        let mut c = VelocityCrossCheck::default();
        for k in 0..100 {
            let t = 10.0 + k as f64 * 0.01;
            assert!(c.judge(t, ap(10.0, t), || (Vector3::new(18.0, 0.0, 0.0), cov)).is_ok());
        }
        assert!(c
            .judge(11.0, ap(10.0, 11.0), || (Vector3::new(10.0, 0.0, 0.0), cov))
            .is_ok());
        // 8 m/s off for 2 s with a fix: a divergence, said once.
        let mut fired = None;
        for k in 0..300 {
            let t = 12.0 + k as f64 * 0.01;
            if let Err(e) = c.judge(t, ap(10.0, t), || (Vector3::new(18.0, 0.0, 0.0), cov)) {
                assert!(e.contains("off the autopilot's own"), "{e}");
                fired = Some(t);
                break;
            }
        }
        let t = fired.expect("a lasting disagreement is a divergence");
        assert!((t - 14.0).abs() < 0.02, "fired at {t}");
        // Our own sigma of 3 m/s covers an 8 m/s difference (5σ > 8): not a
        // divergence, the filter knows it is unsure.
        let mut c = VelocityCrossCheck::default();
        let wide = Matrix3::identity() * 3.0;
        for k in 0..500 {
            let t = 20.0 + k as f64 * 0.01;
            assert!(c.judge(t, ap(10.0, t), || (Vector3::new(18.0, 0.0, 0.0), wide)).is_ok());
        }
    }
}
