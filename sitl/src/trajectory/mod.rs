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

mod tum;
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
    #[error("unknown scenario '{0}': expected racetrack, figure8, hover or tum:<path>")]
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
mod tests {
    use super::*;

    #[test]
    fn racetrack_is_about_a_kilometre_at_fifteen_mps() {
        let tr = racetrack(&RacetrackParams::default(), 200.0, 0.0, &GustField::default());
        let mut len = 0.0;
        let mut prev = tr.sample(0.0).p_B_in_W;
        let mut speeds = Vec::new();
        let mut t = 0.0;
        while t < 200.0 {
            t += 0.05;
            let s = tr.sample(t);
            len += (s.p_B_in_W - prev).xy().norm();
            prev = s.p_B_in_W;
            speeds.push(s.v_B_in_W.norm());
        }
        let lap_s = 992.0 / 15.0;
        assert!(
            (len / (200.0 / lap_s) - 992.0).abs() < 15.0,
            "lap length {}",
            len / (200.0 / lap_s)
        );
        let (lo, hi) = speeds
            .iter()
            .fold((f64::MAX, 0.0f64), |(l, h), &v| (l.min(v), h.max(v)));
        assert!(lo > 14.5 && hi < 15.5, "speed range {lo}..{hi}");
        // It revisits the start after one lap.
        let again = tr.sample(lap_s).p_B_in_W;
        assert!(again.xy().norm() < 3.0, "{again}");
    }

    #[test]
    fn banked_turns_and_level_start_for_hover() {
        let tr = hover(30.0, 0.0, &GustField::default());
        let s = tr.sample(1.0);
        assert!(s.v_B_in_W.norm() < 1e-9 && s.w_B.norm() < 1e-9);
        let z_b = s.q_W_B * Vector3::z();
        assert!((z_b - Vector3::z()).norm() < 1e-9);
        let rt = racetrack(&RacetrackParams::default(), 70.0, 0.0, &GustField::default());
        // In a turn the body tilts into it (the thrust has a horizontal part).
        let mut max_tilt: f64 = 0.0;
        for k in 0..700 {
            let s = rt.sample(k as f64 * 0.1);
            let z = s.q_W_B * Vector3::z();
            max_tilt = max_tilt.max(z.z.acos());
        }
        assert!(
            max_tilt.to_degrees() > 10.0 && max_tilt.to_degrees() < 40.0,
            "{}",
            max_tilt.to_degrees()
        );
    }

    /// Samples of the scenarios as they were before the standstill existed
    /// (printed by the previous code at full precision).
    #[rustfmt::skip]
    #[allow(clippy::type_complexity, clippy::excessive_precision)]
    const BEFORE_STANDSTILL: [(&str, f64, [f64; 3], [f64; 3], [f64; 3], [f64; 4], [f64; 3]); 18] = [
        ("racetrack", 0.0, [0.010140584890256727, 0.0012118611914621186, -5.000193146606438], [14.999960839551193, 0.00032768193415933823, -0.2857026056647767], [-1.0589328724108782e-5, 0.48470736576836093, 3.158259389124396e-6], [0.024682836983249152, 9.57721604673112e-6, 0.000387809625538451, 0.9996952571010979], [2.9445590001843758e-5, 0.0007974636153889338, 0.016137764627715115]),
        ("racetrack", 0.37, [5.559993091205634, 0.03451556753804944, -5.105863450579064], [14.99888415076434, 0.1797152195684478, -0.2853815962213446], [-0.0058125159355526534, 0.48507822804426004, 0.0017323675863778476], [0.0247074628800635, 0.00014804809036303426, 0.005988984307570548, 0.9996767734756854], [0.0002463300602674454, 0.001597861843539416, 0.03230245147134805]),
        ("racetrack", 3.3, [49.4136251386594, 2.6687075961345212, -5.9147472915952415], [14.910787776787974, 1.6331145745322189, -0.2598488668199219], [-0.056464623941451464, 0.5155032933097843, 0.01591767204581629], [0.026408358343853838, 0.0014422204489690485, 0.054501127808316154, 0.9981633862636823], [0.0022301499325698576, 0.0018283932984384601, 0.03452548682894321]),
        ("racetrack", 12.9, [183.8409034341901, 49.0891488618597, -6.692178620861613], [11.600876124657077, 9.507887357595486, 0.24368155059313956], [-1.2600380269436755, 1.536798309723622, 0.11247024516542581], [0.09502488887498801, 0.03400164710409268, 0.3349098288322362, 0.9368295282707877], [0.058548305869827164, 0.026658637033748347, 0.12983714255695775]),
        ("racetrack", 41.7, [-127.1932584949134, 170.58998259985097, -6.927657114980656], [-14.182486803001488, -4.884031178950565, -0.09038396562368778], [0.2648478136406993, -0.7689845813192733, 0.05140199752631247], [-0.006864211164943227, 0.04099761316287122, 0.9854284073933055, -0.16493311438981534], [0.011491179189076413, 0.004506528325761782, 0.054040016787257616]),
        ("racetrack", 69.9, [55.814680423527314, 3.418239268720146, -6.024855847958492], [14.884622837741414, 1.8565036264129025, -0.25253160468593894], [-0.06543176224579383, 0.5245670042200601, 0.01815313329937851], [-0.02691322657576131, -0.0016723133669577176, -0.06198249296377397, -0.9977129106958974], [0.002593414047064228, 0.0019002745146731242, 0.03519242469243521]),
        ("figure8", 0.0, [2.0816681711721685e-17, 2.2551405187698492e-17, -6.0], [6.282496314069229, 6.280429757803897, -0.15707532630727128], [7.105427357601002e-15, 3.552713678800501e-15, 8.526512829121202e-14], [-0.001085120290294982, 0.0008037574905413125, 0.3825656667024976, 0.9239273170267917], [-0.029785434222208335, 0.04961379918621198, -0.0020928022827667856]),
        ("figure8", 0.37, [2.3221978328573467, 2.3144672309713252, -6.0581033299930365], [6.263642223920045, 6.205151331534978, -0.15695743431002052], [-0.10186299533467746, -0.4060955724756852, 0.0006371743126862839], [-0.017151526247262072, 0.012656584799221472, 0.3801575936450558, 0.9246760730129281], [-0.059072651835797026, 0.09775280897060294, -0.026781224835113478]),
        ("figure8", 3.3, [19.12062275890339, 14.727846892749906, -6.508092950507538], [4.840746607680401, 1.1768351841806055, -0.1477891537997138], [-0.8387243670365478, -2.58414263347575, 0.005571862689635054], [-0.12274665145744312, 0.055485439573013905, 0.10947893569561343, 0.9848192667643796], [-0.01444632340221065, 0.024399909985810597, -0.45845372914208576]),
        ("figure8", 12.9, [12.771978060911417, -11.552629905376243, -7.463835010453373], [-5.684572621987894, 4.00329659355576, -0.034264920824090606], [-0.5602416485079402, 2.027020221261978, 0.016052747179898574], [-0.05699500030186637, 0.08879906780420989, -0.9496921673276847, -0.2948746900195714], [0.04261350121372491, 0.05894189946551206, -0.20000002103678008]),
        ("figure8", 41.7, [19.120622758903373, -14.727846892749904, -4.588717538244383], [-4.840746607680355, 1.1768351841805922, 0.053207369355177336], [-0.8387243670350699, 2.584142633475466, -0.015476443995410705], [-0.055376363617902456, 0.12249642377982849, -0.9848524411173649, -0.10951599763859934], [0.014395523567405607, 0.024340552800548833, -0.45847599611049916]),
        ("figure8", 69.9, [26.28631761542549, -12.659364564532504, -7.291077644361699], [-3.026615681833375, -3.365222548214846, -0.07995784648290716], [-1.153046915974926, 2.2212074801015262, 0.014158250668160122], [-0.008159275211325487, 0.12445114352059183, -0.9084839985193325, 0.398876125556254], [-0.02852549397873504, 0.0514063363503258, -0.5077351740575724]),
        ("hover", 0.0, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0]),
        ("hover", 0.37, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0]),
        ("hover", 3.3, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0]),
        ("hover", 12.9, [2.270636492800005, 0.0, -3.0], [2.6603880960000126, 0.0, 0.0], [1.0828799999996548, 0.0, 4.973799150320701e-14], [-0.0038751217377371123, -0.05465938978757232, 0.07121188434415819, 0.9959549196965305], [0.02269783749706254, 0.1574028532965399, 0.16479177438958928]),
        ("hover", 41.7, [0.0, 0.0, -3.0], [0.0, 0.0, 3.774758283725532e-15], [0.0, 0.0, 4.973799150320701e-14], [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0]),
        ("hover", 69.9, [0.0, 2.116643558399994, -3.0], [0.0, -2.13295507200002, 0.0], [0.0, 0.5598720000016364, 4.973799150320701e-14], [0.025775869665832833, -0.011987060566264127, 0.4262767860572406, 0.904146015083106], [0.0853394259016436, -0.10379284072152167, -0.8926330819828099]),
    ];

    #[test]
    fn no_standstill_is_the_historical_trajectory_bit_for_bit() {
        for (name, t, p, v, a, q, w) in BEFORE_STANDSTILL {
            let s = Trajectory::from_scenario(name, Some(70.0), 0.0, &GustField::default())
                .unwrap()
                .sample(t);
            let c = s.q_W_B.coords;
            let got = [
                s.p_B_in_W.as_slice(),
                s.v_B_in_W.as_slice(),
                s.a_B_in_W.as_slice(),
                &[c.x, c.y, c.z, c.w][..],
                s.w_B.as_slice(),
            ]
            .concat();
            let want = [&p[..], &v[..], &a[..], &q[..], &w[..]].concat();
            assert_eq!(got, want, "{name} at {t} s");
        }
    }

    #[test]
    fn standstill_is_exactly_at_rest_level_on_the_ground_then_takes_off() {
        let standstill_s = 5.0;
        for name in ["racetrack", "figure8", "hover"] {
            let tr = Trajectory::from_scenario(name, Some(40.0), standstill_s, &GustField::default()).unwrap();
            let mut t = -0.3;
            while t < standstill_s {
                let s = tr.sample(t);
                assert_eq!(s.p_B_in_W.norm(), 0.0, "{name} at {t}: {}", s.p_B_in_W);
                assert_eq!(s.v_B_in_W.norm(), 0.0, "{name} at {t}: {}", s.v_B_in_W);
                assert_eq!(s.a_B_in_W.norm(), 0.0, "{name} at {t}: {}", s.a_B_in_W);
                assert_eq!(s.w_B.norm(), 0.0, "{name} at {t}: {}", s.w_B);
                let z_b = s.q_W_B * Vector3::z();
                assert!((z_b - Vector3::z()).norm() < 1e-12, "{name} not level at {t}");
                t += 0.01;
            }
            // It has left the ground a few seconds after the take-off.
            let s = tr.sample(takeoff_start_s(standstill_s) + 2.0);
            assert!(s.p_B_in_W.z < -0.5 && s.v_B_in_W.norm() > 0.3, "{name}: {s:?}");
        }
        // The racetrack reaches its 15 m/s and its 5 m height after the
        // take-off, and keeps them.
        let tr = Trajectory::from_scenario("racetrack", Some(70.0), standstill_s, &GustField::default()).unwrap();
        let t_full = takeoff_start_s(standstill_s) + TAKEOFF_S;
        let mut t = t_full;
        while t < 70.0 {
            let s = tr.sample(t);
            let v = s.v_B_in_W.norm();
            assert!(v > 14.5 && v < 15.5, "speed {v} at {t}");
            assert!(
                s.p_B_in_W.z < -2.5 && s.p_B_in_W.z > -7.5,
                "height at {t}: {}",
                s.p_B_in_W
            );
            t += 0.1;
        }
        let s = tr.sample(t_full);
        assert!((s.v_B_in_W.xy().norm() - 15.0).abs() < 0.05, "{}", s.v_B_in_W);
    }

    /// The take-off goes through the same quintic splines: acceleration and
    /// body rate have no jumps (their steps over 1 ms stay within a
    /// multirotor's jerk), and the yaw does not snap when it starts moving.
    #[test]
    fn takeoff_is_smooth() {
        let dt = 1e-3;
        for name in ["racetrack", "figure8", "hover"] {
            let tr = Trajectory::from_scenario(name, Some(25.0), 5.0, &GustField::default()).unwrap();
            let (mut max_jerk, mut max_w_dot, mut max_w) = (0.0f64, 0.0f64, 0.0f64);
            let mut prev = tr.sample(0.0);
            let mut t = dt;
            while t < 25.0 {
                let s = tr.sample(t);
                max_jerk = max_jerk.max((s.a_B_in_W - prev.a_B_in_W).norm() / dt);
                max_w_dot = max_w_dot.max((s.w_B - prev.w_B).norm() / dt);
                max_w = max_w.max(s.w_B.norm());
                prev = s;
                t += dt;
            }
            assert!(max_jerk < 5.0, "{name}: jerk {max_jerk} m/s³");
            assert!(max_w_dot < 5.0, "{name}: angular acceleration {max_w_dot} rad/s²");
            assert!(max_w < 1.5, "{name}: body rate {max_w} rad/s");
        }
    }
}
