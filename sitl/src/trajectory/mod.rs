//! Ground-truth trajectories for the simulator.
//!
//! Each scenario (`racetrack`, `figure8`, `hover`, `tum:<path>`) is reduced to
//! the same thing: a quintic position spline and a cumulative quintic rotation
//! spline (see [`crate::spline`]). The truth at any time, including the
//! acceleration and body rate that the IMU model needs, then comes from one
//! place with exact derivatives. The TUM loader is `tum.rs`.
//!
//! Frames: world `W` is local NED, body `B` is FRD. For the analytic scenarios
//! the attitude follows a multirotor's differential flatness: the body z axis
//! points against the specific force (thrust), and yaw follows the heading.
//!
//! A real multirotor starts on the ground, and that is where a filter
//! initialises (still, level, its biases observable only through gravity).
//! So the analytic scenarios take a `standstill_s`: for `t < standstill_s`
//! the body is exactly at rest, level, at the origin with height 0
//! (`p = 0`, `v = 0`, `ω = 0`), then it takes off along minimum-jerk ramps
//! (racetrack and figure8: speed or phase rate, and height, over
//! [`TAKEOFF_S`]; hover: its first climb). `standstill_s = 0` gives the
//! historical scenarios exactly: racetrack and figure8 airborne at full speed
//! from t = 0, hover with its 4 s wait.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};

use crate::spline::{PositionSpline, RotationSpline};

pub(crate) mod tum;
pub mod wind;

pub use tum::from_tum;
pub use wind::{GustField, WindConfig};

/// Gravity in the NED world frame (m/s²), positive down.
pub fn gravity_w(g_mps2: f64) -> Vector3<f64> {
    Vector3::new(0.0, 0.0, g_mps2)
}

/// Errors from building a trajectory.
#[derive(Debug, thiserror::Error)]
pub enum TrajectoryError {
    #[error("unknown scenario '{0}': expected racetrack, figure8, hover, tum:<path> or euroc:<dir>")]
    UnknownScenario(String),
    #[error("cannot read TUM trajectory '{path}': {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("TUM trajectory '{path}', line {line}: {reason}")]
    BadRow { path: PathBuf, line: usize, reason: String },
    #[error("TUM trajectory '{path}': {reason}")]
    TooShort { path: PathBuf, reason: String },
}

/// The truth at one instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TruthSample {
    pub t_s: f64,
    pub p_B_in_W: Vector3<f64>,
    pub v_B_in_W: Vector3<f64>,
    pub a_B_in_W: Vector3<f64>,
    pub q_W_B: UnitQuaternion<f64>,
    /// Body angular rate in the body frame (rad/s).
    pub w_B: Vector3<f64>,
}

/// A smooth trajectory over `[0, duration_s]`.
#[derive(Clone, Debug)]
pub struct Trajectory {
    pub name: String,
    pub duration_s: f64,
    pos: PositionSpline,
    rot: RotationSpline,
}

/// Spacing of spline control points (s).
const KNOT_DT_S: f64 = 0.1;

/// Length of the take-off ramps of racetrack and figure8 (s).
pub const TAKEOFF_S: f64 = 6.0;

/// When the commanded motion starts after a standstill of `standstill_s`.
/// A quintic B-spline at `t` is shaped by control points up to 3 knots
/// later, and the attitude's control point at `T` by the position spline's
/// acceleration at `T`, so up to 6 knots ahead. Commanding the motion 6.5
/// knots after `standstill_s` keeps every control point that matters
/// exactly at the rest point until then: the truth is exactly at rest and
/// level for `t < standstill_s`, and starts to move about 0.35 s later.
pub fn takeoff_start_s(standstill_s: f64) -> f64 {
    standstill_s + 6.5 * KNOT_DT_S
}

impl Trajectory {
    /// Builds the named scenario. `duration_s` of `None` takes the natural
    /// length (the file's span for `tum:`; 70 s otherwise, standstill
    /// included). `standstill_s` is the time on the ground before an
    /// analytic scenario takes off (0: the historical airborne start); TUM
    /// files ignore it.
    /// `gusts` disturb the analytic scenarios once airborne
    /// ([`GustField::apply`]); a TUM file is flown as recorded.
    pub fn from_scenario(
        name: &str,
        duration_s: Option<f64>,
        standstill_s: f64,
        gusts: &GustField,
    ) -> Result<Self, TrajectoryError> {
        let d = duration_s.unwrap_or(70.0);
        match name {
            "racetrack" => Ok(racetrack(&RacetrackParams::default(), d, standstill_s, gusts)),
            "figure8" => Ok(figure8(d, standstill_s, gusts)),
            "hover" => Ok(hover(d, standstill_s, gusts)),
            _ => {
                if let Some(path) = name.strip_prefix("tum:") {
                    from_tum(Path::new(path), duration_s)
                } else {
                    Err(TrajectoryError::UnknownScenario(name.to_string()))
                }
            }
        }
    }

    /// The truth at `t_s` (clamped to the spline's range).
    pub fn sample(&self, t_s: f64) -> TruthSample {
        let p = self.pos.eval(t_s);
        let r = self.rot.eval(t_s);
        TruthSample {
            t_s,
            p_B_in_W: p.p,
            v_B_in_W: p.v,
            a_B_in_W: p.a,
            q_W_B: r.q,
            w_B: r.w,
        }
    }

    /// Builds a trajectory from a sampled position function, disturbed by
    /// `gusts`, and an attitude rule. Control points are taken from
    /// `t = -0.2 s` to `duration + 0.3 s` so the spline covers `[0, duration]`.
    fn from_functions(
        name: &str,
        duration_s: f64,
        pos_fn: impl Fn(f64) -> Vector3<f64>,
        attitude: Attitude,
        gusts: &GustField,
    ) -> Self {
        let n = (duration_s / KNOT_DT_S).ceil() as usize + 6;
        let t0 = -2.0 * KNOT_DT_S;
        let ctrl: Vec<_> = (0..n)
            .map(|m| {
                let t = t0 + m as f64 * KNOT_DT_S;
                gusts.apply(t, pos_fn(t))
            })
            .collect();
        let pos = PositionSpline::new(t0, KNOT_DT_S, ctrl);
        // The attitude follows the position spline itself, so the tilt is
        // exactly the one that produces the spline's acceleration.
        let g = gravity_w(cmsckf_models::sensors::DEFAULT_GRAVITY_MPS2);
        let mut last_yaw = 0.0;
        let qctrl: Vec<_> = (0..n)
            .map(|m| {
                let t = t0 + m as f64 * KNOT_DT_S;
                let s = pos.eval(t);
                let yaw = match &attitude {
                    Attitude::FollowHeading { yaw0_rad } => {
                        if m == 0 {
                            last_yaw = *yaw0_rad;
                        }
                        if s.v.xy().norm() > 0.5 {
                            last_yaw = s.v.y.atan2(s.v.x);
                        }
                        last_yaw
                    }
                    Attitude::Yaw(f) => f(t),
                };
                flat_attitude(&(s.a - g), yaw)
            })
            .collect();
        let qctrl = unwrap_quaternions(qctrl);
        let rot = RotationSpline::new(t0, KNOT_DT_S, qctrl);
        Self {
            name: name.to_string(),
            duration_s,
            pos,
            rot,
        }
    }
}

enum Attitude {
    /// Yaw along the horizontal velocity; `yaw0_rad` while slower than
    /// 0.5 m/s before the first heading (on the ground: the heading it will
    /// take off along, so that yaw does not jump when it starts moving).
    FollowHeading {
        yaw0_rad: f64,
    },
    Yaw(Box<dyn Fn(f64) -> f64>),
}

/// Multirotor attitude from the specific force `f_W = a − g` and a yaw:
/// the body z axis (down) is `−f/|f|`, the body x axis is the heading
/// projected onto the plane normal to z.
pub fn flat_attitude(f_W: &Vector3<f64>, yaw_rad: f64) -> UnitQuaternion<f64> {
    let z_b = if f_W.norm() > 1e-6 {
        -f_W.normalize()
    } else {
        Vector3::z()
    };
    let x_c = Vector3::new(yaw_rad.cos(), yaw_rad.sin(), 0.0);
    let y_b = z_b.cross(&x_c).normalize();
    let x_b = y_b.cross(&z_b);
    let r = Matrix3::from_columns(&[x_b, y_b, z_b]);
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r))
}

/// Keeps consecutive quaternions in the same hemisphere (cosmetic; the spline
/// works on relative rotations either way).
fn unwrap_quaternions(mut q: Vec<UnitQuaternion<f64>>) -> Vec<UnitQuaternion<f64>> {
    for i in 1..q.len() {
        if q[i].coords.dot(&q[i - 1].coords) < 0.0 {
            q[i] = UnitQuaternion::new_unchecked(-q[i].into_inner());
        }
    }
    q
}

/// Shape of the racetrack scenario.
#[derive(Clone, Debug)]
pub struct RacetrackParams {
    /// Semi-axis along north (m).
    pub semi_major_m: f64,
    /// Semi-axis along east (m).
    pub semi_minor_m: f64,
    /// Ground speed (m/s).
    pub speed_mps: f64,
    /// Mean height above the origin (m).
    pub height_m: f64,
    /// Amplitude of the gentle climbs (m); two climbs per lap.
    pub climb_m: f64,
    /// Length of the take-off ramps of speed and height after a standstill
    /// (s; at least one knot, 0.1 s, is used).
    pub takeoff_s: f64,
}

impl Default for RacetrackParams {
    fn default() -> Self {
        // ≈ 992 m around: π(3(a+b) − √((3a+b)(a+3b))) with a = 210, b = 95.
        Self {
            semi_major_m: 210.0,
            semi_minor_m: 95.0,
            speed_mps: 15.0,
            height_m: 5.0,
            climb_m: 2.0,
            takeoff_s: TAKEOFF_S,
        }
    }
}

/// An oval flown at constant ground speed. The curve angle θ(t) is the
/// solution of `θ' = v(t) / |dP/dθ|`, integrated with RK4, so the speed is
/// the same on the straights and in the (banked) turns.
///
/// With `standstill_s > 0` it sits at the start point (the origin, height 0)
/// until then; from [`takeoff_start_s`] the speed `v(t)` and the height
/// follow minimum-jerk ramps from 0 to `speed_mps` and `height_m` over
/// `takeoff_s`. With `standstill_s = 0` it flies at full speed and height
/// from t = 0.
pub fn racetrack(p: &RacetrackParams, duration_s: f64, standstill_s: f64, gusts: &GustField) -> Trajectory {
    let (a, b) = (p.semi_major_m, p.semi_minor_m);
    let grounded = standstill_s > 0.0;
    let t_go = takeoff_start_s(standstill_s);
    let takeoff_s = p.takeoff_s.max(KNOT_DT_S);
    // Fraction of full speed and height at `t`: a min-jerk ramp from the
    // take-off, or 1 throughout without a standstill.
    let ramp = move |t: f64| {
        if grounded {
            min_jerk((t - t_go) / takeoff_s)
        } else {
            1.0
        }
    };
    let dtheta = |t: f64, th: f64| p.speed_mps * ramp(t) / (a * a * th.cos().powi(2) + b * b * th.sin().powi(2)).sqrt();
    // Tabulate θ(t) on a fine grid covering the spline's control times.
    let h = KNOT_DT_S / 20.0;
    let t_start = -1.0;
    let n = ((duration_s + 2.0 - t_start) / h).ceil() as usize;
    let mut thetas = Vec::with_capacity(n + 1);
    // θ(0) = 0: t = 0 is at the middle of the west side, heading north. On
    // the ground θ stays exactly 0 until the take-off.
    let mut th = if grounded { 0.0 } else { -dtheta(0.0, 0.0) * (-t_start) };
    thetas.push(th);
    for i in 0..n {
        let t = t_start + i as f64 * h;
        let k1 = dtheta(t, th);
        let k2 = dtheta(t + 0.5 * h, th + 0.5 * h * k1);
        let k3 = dtheta(t + 0.5 * h, th + 0.5 * h * k2);
        let k4 = dtheta(t + h, th + h * k3);
        th += h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
        thetas.push(th);
    }
    let theta_at = move |t: f64| {
        let x = ((t - t_start) / h).clamp(0.0, (thetas.len() - 2) as f64);
        let i = x.floor() as usize;
        let f = x - i as f64;
        thetas[i] * (1.0 - f) + thetas[i + 1] * f
    };
    let (hgt, climb) = (p.height_m, p.climb_m);
    // P(θ) = (a sin θ, b (1 − cos θ)): the origin is the start point.
    let pos = move |t: f64| {
        let th = theta_at(t);
        Vector3::new(
            a * th.sin(),
            b * (1.0 - th.cos()),
            -(hgt * ramp(t) + climb * (2.0 * th).sin()),
        )
    };
    Trajectory::from_functions(
        "racetrack",
        duration_s,
        pos,
        Attitude::FollowHeading { yaw0_rad: 0.0 },
        gusts,
    )
}

/// A lemniscate of Gerono, 60 m × 30 m, one loop every 30 s, with a slow
/// altitude wave.
///
/// With `standstill_s > 0` it sits at the origin (height 0) until then; from
/// [`takeoff_start_s`] the phase rate and the height follow minimum-jerk
/// ramps to full over [`TAKEOFF_S`]. With `standstill_s = 0` it flies at
/// full rate and height from t = 0.
pub fn figure8(duration_s: f64, standstill_s: f64, gusts: &GustField) -> Trajectory {
    let w = 2.0 * std::f64::consts::PI / 30.0;
    let grounded = standstill_s > 0.0;
    let t_go = takeoff_start_s(standstill_s);
    // Phase and height fraction at `t`: the phase is w times the integral
    // of the min-jerk rate ramp, in closed form.
    let phase = move |t: f64| {
        if grounded {
            w * TAKEOFF_S * min_jerk_integral((t - t_go) / TAKEOFF_S)
        } else {
            w * t
        }
    };
    let lift = move |t: f64| {
        if grounded {
            min_jerk((t - t_go) / TAKEOFF_S)
        } else {
            1.0
        }
    };
    let pos = move |t: f64| {
        let th = phase(t);
        Vector3::new(
            30.0 * th.sin(),
            15.0 * (2.0 * th).sin(),
            -(6.0 * lift(t) + 1.5 * (0.5 * th).sin()),
        )
    };
    // It sets off north-east (the lemniscate's tangent at the origin).
    Trajectory::from_functions(
        "figure8",
        duration_s,
        pos,
        Attitude::FollowHeading {
            yaw0_rad: std::f64::consts::FRAC_PI_4,
        },
        gusts,
    )
}

/// Minimum-jerk blend `s(τ)` for τ ∈ [0,1]: 10τ³ − 15τ⁴ + 6τ⁵.
fn min_jerk(tau: f64) -> f64 {
    let t = tau.clamp(0.0, 1.0);
    t * t * t * (10.0 - 15.0 * t + 6.0 * t * t)
}

/// `∫₀^τ s(x) dx` of [`min_jerk`] for any τ: 0 before the ramp,
/// 2.5τ⁴ − 3τ⁵ + τ⁶ on it, and `τ − 1/2` after it.
fn min_jerk_integral(tau: f64) -> f64 {
    if tau <= 0.0 {
        0.0
    } else if tau >= 1.0 {
        tau - 0.5
    } else {
        tau.powi(4) * (2.5 - 3.0 * tau + tau * tau)
    }
}

/// Hover and translate: sits still on the ground (for static
/// initialisation), climbs to 3 m, then moves between waypoints with hovers
/// and slow yaw turns in between. The ground wait is `standstill_s` (the
/// climb is commanded from [`takeoff_start_s`]), or the historical 4 s when
/// `standstill_s` is 0.
pub fn hover(duration_s: f64, standstill_s: f64, gusts: &GustField) -> Trajectory {
    // Every waypoint after the ground wait moves with it.
    let shift = if standstill_s > 0.0 {
        takeoff_start_s(standstill_s) - 4.0
    } else {
        0.0
    };
    // (arrival time, position NED, yaw) — each leg is a min-jerk move.
    let wps: Vec<(f64, Vector3<f64>, f64)> = vec![
        (0.0, Vector3::new(0.0, 0.0, 0.0), 0.0),
        (4.0, Vector3::new(0.0, 0.0, 0.0), 0.0),
        (8.0, Vector3::new(0.0, 0.0, -3.0), 0.0),
        (11.0, Vector3::new(0.0, 0.0, -3.0), 0.0),
        (16.0, Vector3::new(8.0, 0.0, -3.0), 0.5),
        (19.0, Vector3::new(8.0, 0.0, -3.0), 0.5),
        (24.0, Vector3::new(8.0, 6.0, -4.0), 1.5),
        (27.0, Vector3::new(8.0, 6.0, -4.0), 1.5),
        (32.0, Vector3::new(0.0, 6.0, -3.0), 2.5),
        (35.0, Vector3::new(0.0, 6.0, -3.0), 2.5),
        (40.0, Vector3::new(0.0, 0.0, -3.0), 0.0),
        (43.0, Vector3::new(0.0, 0.0, -3.0), 0.0),
    ]
    .into_iter()
    .enumerate()
    .map(|(i, (t, p, y))| (if i == 0 { t } else { t + shift }, p, y))
    .collect();
    let (t_cycle, t_end) = (11.0 + shift, 43.0 + shift);
    let period = t_end - t_cycle;
    let interp = move |t: f64| -> (Vector3<f64>, f64) {
        // After the first cycle, repeat the legs from the first hover.
        let tt = if t > t_end { t_cycle + (t - t_cycle) % period } else { t };
        if tt <= 0.0 {
            return (wps[0].1, wps[0].2);
        }
        for w in wps.windows(2) {
            let (t0, p0, y0) = w[0];
            let (t1, p1, y1) = w[1];
            if tt <= t1 {
                let s = min_jerk((tt - t0) / (t1 - t0));
                return (p0 + (p1 - p0) * s, y0 + (y1 - y0) * s);
            }
        }
        let last = wps[wps.len() - 1];
        (last.1, last.2)
    };
    let interp2 = interp.clone();
    Trajectory::from_functions(
        "hover",
        duration_s,
        move |t| interp(t).0,
        Attitude::Yaw(Box::new(move |t| interp2(t).1)),
        gusts,
    )
}

#[cfg(test)]
mod tests;
