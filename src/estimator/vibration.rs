//! The armed vehicle's vibration in the camera's poses (README.md §3f).
//!
//! A multirotor's motors shake its IMU at their frequencies (aliased into
//! the sampling band): tens of Hz, far above any flight motion. Integrated,
//! a line of amplitude `A` at `f` Hz swings the attitude by `A / (2π f)`
//! about the true one, bounded and zero-mean, so it never accumulates as
//! the white gyro noise of the propagation does. But the camera's frames
//! catch the swing at its random phases: each view's pose, a clone or a
//! keyframe, is off by a jitter of its own that the propagation's noise
//! does not cover. On the simulator's armed IMU (lines of 0.06 and 0.03
//! rad/s at 37 and 61 Hz) that jitter is 2.0e-4 rad per axis, 0.09 px at a
//! 460 px focal length: more than a precise front-end's σ.
//!
//! The jitter is measured from the gyro samples themselves: over short
//! windows, the integrated attitude less a cubic in time (which takes every
//! flight motion slower than a few Hz) leaves the swing; its variance per
//! axis, the median over five windows, is the jitter's (eq. V1). It is
//! added to each new view's attitude block (eq. V2), as a noise of that
//! view alone.

use std::collections::VecDeque;

use nalgebra::{Matrix4, Vector3, Vector4};

/// Length of one fitting window (s): 3.7 periods of a 37 Hz line, while a
/// 1 Hz manoeuvre of 0.08 rad leaves the cubic 3e-5 rad (its fourth-order
/// term). At least 16 samples long for a slower IMU (0.16 s at 100 Hz, 0.32 s
/// for a 50 Hz `RAW_IMU`, whose aliased lines a shorter window's cubic
/// would take a third of), whose slow motion the cubic then takes less
/// well.
const WINDOW_S: f64 = 0.1;

/// Fewest samples a window spans, however fast the IMU (see [`WINDOW_S`]);
/// also how many of the last intervals give the sampling interval.
const WINDOW_MIN_SPAN: usize = 16;

/// Windows whose median is taken (the last 0.5 s of gyro samples from 160
/// Hz up; 1.6 s at 50 Hz).
const WINDOWS: usize = 5;

/// Fewest samples in a window for its fit to count (four are fitted).
const MIN_SAMPLES: usize = 8;

/// Largest jitter taken (rad, per axis): a swing of 0.1 rad (6°) is no
/// vibration but a wild or broken gyro, which the divergence checks judge;
/// the bound keeps an absurd sample (finite, but 1e200 rad/s) from putting an
/// infinite or NaN variance into the state.
const MAX_JITTER_RAD: f64 = 0.1;

/// A gap between gyro samples longer than this (s) ends the history used.
const MAX_SAMPLE_GAP_S: f64 = 0.05;

/// Least-squares cubic fit of one window, accumulated sample by sample.
struct CubicFit {
    n: usize,
    /// `Σ φ φᵀ`, `φ = [1, u, u², u³]`, `u` the time within the window
    /// scaled to [-1, 1].
    nn: Matrix4<f64>,
    /// `Σ φ θ_a` per axis `a`.
    b: [Vector4<f64>; 3],
    /// `Σ θ_a²` per axis.
    yy: Vector3<f64>,
    /// The first attitude seen in the window, subtracted for conditioning.
    theta_ref: Option<Vector3<f64>>,
}

impl CubicFit {
    fn new() -> Self {
        Self {
            n: 0,
            nn: Matrix4::zeros(),
            b: [Vector4::zeros(); 3],
            yy: Vector3::zeros(),
            theta_ref: None,
        }
    }

    fn add(&mut self, u: f64, theta: &Vector3<f64>) {
        let r = *self.theta_ref.get_or_insert(*theta);
        let y = theta - r;
        let phi = Vector4::new(1.0, u, u * u, u * u * u);
        self.nn += phi * phi.transpose();
        for a in 0..3 {
            self.b[a] += phi * y[a];
        }
        self.yy += y.component_mul(&y);
        self.n += 1;
    }

    /// The residual variance per axis: `RSS / n`, `RSS = Σ θ² − bᵀ (Σ φ
    /// φᵀ)⁻¹ b` (eq. V1). Over `n`, not `n − 4`: the cubic takes almost
    /// nothing of a line of several periods in the window, so the residual
    /// is not white noise that lost four degrees of freedom (`n − 4`
    /// overstated the swing by 25 % at 200 Hz). An overflow (an absurd but
    /// finite rate) is infinite, never NaN or zero, so the bound holds it.
    fn residual_var(&self) -> Option<Vector3<f64>> {
        if self.n < MIN_SAMPLES {
            return None;
        }
        let chol = self.nn.cholesky()?;
        Some(Vector3::from_fn(|a, _| {
            let rss = self.yy[a] - self.b[a].dot(&chol.solve(&self.b[a]));
            if rss.is_finite() {
                rss.max(0.0) / self.n as f64
            } else {
                f64::INFINITY
            }
        }))
    }
}

/// The vibration's attitude jitter (rad², per body axis, eq. V1) from the
/// gyro samples `(t_s, ω_B)` of `history`, oldest first: the variance of the
/// integrated rate about a cubic in time, per window of [`WINDOW_S`] (or 16
/// samples), over up to [`WINDOWS`] whole windows ending at the last
/// sample, their median per axis. `None` without a whole window of
/// [`MIN_SAMPLES`].
///
/// The rate is integrated as the propagation turns the body (eq. N1: the
/// trapezoid of two samples' rates), so the swing measured is the one in the
/// filter's attitude. A constant bias integrates to a line, which the cubic
/// takes; a flight motion slower than a few Hz takes a cubic too. A fast
/// manoeuvre (a flip's 3 rad/s reversed in 0.04 s) leaves a residual in the
/// window or two it falls in, which the median over five passes by. Walks
/// the history from its newest sample; no allocation.
pub(super) fn jitter_var_rad2(history: &VecDeque<(f64, Vector3<f64>)>) -> Option<Vector3<f64>> {
    let &(t_end, _) = history.back()?;
    // The sampling interval, over up to the last WINDOW_MIN_SPAN intervals.
    let k = history.len().saturating_sub(1).min(WINDOW_MIN_SPAN);
    let dt_s = (t_end - history.get(history.len().checked_sub(1 + k)?)?.0) / k.max(1) as f64;
    let window_s = WINDOW_S.max(WINDOW_MIN_SPAN as f64 * dt_s);
    // A window counts whole: at least 80 % of the samples it should hold.
    let min_in_window = MIN_SAMPLES.max((0.8 * window_s / dt_s).floor() as usize);
    let max_gap_s = MAX_SAMPLE_GAP_S.max(2.5 * dt_s);
    let mut theta = Vector3::zeros();
    let mut per_window = [Vector3::zeros(); WINDOWS];
    let mut n_windows = 0usize;
    let mut fit = CubicFit::new();
    let mut window = 0usize;
    let mut next: Option<(f64, Vector3<f64>)> = None;
    let mut close = |fit: &CubicFit, n_windows: &mut usize| {
        if fit.n >= min_in_window {
            if let Some(var) = fit.residual_var() {
                per_window[*n_windows] = var;
                *n_windows += 1;
            }
        }
    };
    for &(t, w) in history.iter().rev() {
        // θ integrated backwards from the newest sample, by the trapezoid
        // of this sample's and the next one's rates over their interval.
        if let Some((t_next, w_next)) = next {
            let dt = t_next - t;
            if !(dt > 0.0 && dt <= max_gap_s) {
                break;
            }
            theta -= (w + w_next) * (0.5 * dt);
        }
        next = Some((t, w));
        let age = t_end - t;
        let k = (age / window_s).floor() as usize;
        if k >= WINDOWS {
            break;
        }
        if k != window {
            close(&fit, &mut n_windows);
            fit = CubicFit::new();
            window = k;
        }
        // u ∈ [-1, 1] across the window.
        let u = 2.0 * (age - k as f64 * window_s) / window_s - 1.0;
        fit.add(u, &theta);
    }
    close(&fit, &mut n_windows);
    if n_windows == 0 {
        return None;
    }
    // The median per axis (of an even count, the mean of the middle two),
    // held to MAX_JITTER_RAD (an overflow's infinity included).
    let w = &per_window[..n_windows];
    let var = Vector3::from_fn(|a, _| {
        let mut v = [0.0; WINDOWS];
        for (x, wi) in v.iter_mut().zip(w.iter()) {
            *x = wi[a];
        }
        let v = &mut v[..n_windows];
        v.sort_by(f64::total_cmp);
        let m = n_windows / 2;
        if n_windows % 2 == 1 {
            v[m]
        } else {
            0.5 * (v[m - 1] + v[m])
        }
    });
    Some(var.map(|v| v.min(MAX_JITTER_RAD * MAX_JITTER_RAD)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::TAU;

    /// Gyro samples at `rate_hz` for `dur_s`: a slow manoeuvre, a bias and
    /// the motor lines `(f Hz, A rad/s)` on every axis, with phases.
    fn history(rate_hz: f64, dur_s: f64, lines: &[(f64, f64)]) -> VecDeque<(f64, Vector3<f64>)> {
        let n = (rate_hz * dur_s) as usize;
        (0..n)
            .map(|i| {
                let t = 3.0 + i as f64 / rate_hz;
                // A 0.5 Hz pitch of ±0.3 rad, a 1 Hz roll of ±0.08 rad, a
                // bias of 0.08 rad/s.
                let mut w = Vector3::new(
                    0.08 * TAU * (TAU * t).cos(),
                    0.3 * TAU * 0.5 * (TAU * 0.5 * t).cos(),
                    0.2,
                ) + Vector3::repeat(0.08);
                for (j, &(f, a)) in lines.iter().enumerate() {
                    for k in 0..3 {
                        w[k] += a * (TAU * f * t + 1.3 * (j + 1) as f64 * (k + 1) as f64).sin();
                    }
                }
                (t, w)
            })
            .collect()
    }

    /// The simulator's armed lines give the swing of the attitude the
    /// filter integrates from their samples, per axis, within 15 % (30 %
    /// under 160 Hz), from a 50 Hz `RAW_IMU` (the lines aliased to 13 and
    /// 11 Hz, windows of 0.32 s) to 1 kHz: the trapezoid of a line sampled
    /// every `dt` swings by `A dt cos(π f dt) / (2 sin(π f dt))`, whose
    /// variance is half its square (`(A / 2πf)² / 2` as `dt → 0`).
    #[test]
    fn armed_lines_give_their_swing() {
        let lines = [(37.0, 0.06), (61.0, 0.03)];
        for rate_hz in [50.0, 100.0, 200.0, 248.0, 400.0, 1000.0] {
            let dt = 1.0 / rate_hz;
            let expect: f64 = lines
                .iter()
                .map(|(f, a)| {
                    let x = std::f64::consts::PI * f * dt;
                    (a * dt * x.cos() / (2.0 * x.sin())).powi(2) / 2.0
                })
                .sum();
            let h = history(rate_hz, 2.0, &lines);
            let v = jitter_var_rad2(&h).unwrap();
            for a in 0..3 {
                let r = v[a] / expect;
                // Two lines beat in a window: at 50 and 100 Hz, where the
                // windows hold 16 samples, the median of five varies more
                // (measured 0.77-1.23; 0.88-0.95 from 200 Hz).
                let band = if rate_hz < 160.0 { 0.7..1.3 } else { 0.85..1.15 };
                assert!(band.contains(&r), "{rate_hz} Hz axis {a}: {:.3e} vs {expect:.3e}", v[a]);
            }
        }
    }

    /// Without vibration, the manoeuvre and the bias leave under 1 % of the
    /// armed swing: the fit does not take flight motion for jitter.
    #[test]
    fn flight_motion_is_not_jitter() {
        let armed = jitter_var_rad2(&history(200.0, 1.0, &[(37.0, 0.06), (61.0, 0.03)])).unwrap();
        let calm = jitter_var_rad2(&history(200.0, 1.0, &[])).unwrap();
        for a in 0..3 {
            assert!(
                calm[a] < 0.01 * armed[a],
                "axis {a}: {:.3e} vs {:.3e}",
                calm[a],
                armed[a]
            );
        }
    }

    /// An absurd but finite rate (1e200 rad/s, 1e30) gives a finite jitter,
    /// at most the bound, never NaN or infinity.
    #[test]
    fn absurd_rates_give_a_bounded_figure() {
        for spike in [1e200, 1e30, 1e3] {
            let mut h = history(200.0, 1.0, &[(37.0, 0.06)]);
            let i = h.len() - 30;
            h[i].1 = Vector3::new(spike, -spike, spike);
            let v = jitter_var_rad2(&h).unwrap();
            assert!(
                v.iter().all(|x| x.is_finite() && *x <= MAX_JITTER_RAD * MAX_JITTER_RAD),
                "{spike}: {v:?}"
            );
        }
    }

    /// A flip (±3 rad/s reversed in 0.04 s) falls in one or two windows;
    /// the median over five passes it by: the still, calm IMU's figure stays
    /// under 1e-8 rad² (the armed lines' is 3e-8), wherever the flip falls.
    #[test]
    fn a_flip_is_no_vibration() {
        for k in 0..20 {
            let t_flip = 4.5 + 0.013 * k as f64;
            let h: VecDeque<_> = (0..400)
                .map(|i| {
                    let t = 3.0 + i as f64 / 200.0;
                    (t, Vector3::new(3.0 * ((t - t_flip) / 0.02).clamp(-1.0, 1.0), 0.0, 0.0))
                })
                .collect();
            let v = jitter_var_rad2(&h).unwrap();
            assert!(v[0] < 1e-8, "flip at {t_flip}: {:.2e}", v[0]);
        }
    }

    /// A 20 Hz IMU (intervals of 0.05 s, some a rounding over) still gives
    /// a figure, its windows 0.8 s long.
    #[test]
    fn a_slow_imu_gives_a_figure() {
        let h: VecDeque<_> = (0..120)
            .map(|i| {
                let t = i as f64 / 20.0;
                (t, Vector3::repeat((7.0 * TAU * t).sin() * 0.06))
            })
            .collect();
        assert!(jitter_var_rad2(&h).is_some());
    }

    /// Too few samples, a gap, or none give no figure, or one from the
    /// samples after the gap only.
    #[test]
    fn short_or_gapped_history() {
        assert!(jitter_var_rad2(&VecDeque::new()).is_none());
        assert!(jitter_var_rad2(&history(200.0, 0.03, &[(37.0, 0.06)])).is_none());
        // A 0.2 s gap 0.15 s before the end: the 30 samples after it hold one
        // whole window (the next is partial, not counted); the armed lines
        // before the gap do not count.
        let mut h = history(200.0, 1.0, &[(37.0, 0.06), (61.0, 0.03)]);
        let t_last = h.back().unwrap().0;
        h.retain(|(t, _)| *t < t_last - 0.35 || *t > t_last - 0.15);
        for (_, w) in h.iter_mut().rev().take(30) {
            *w = Vector3::repeat(0.1);
        }
        let v = jitter_var_rad2(&h).unwrap();
        assert!(v.max() < 1e-12, "{v:?}");
    }
}
