//! Ground-truth trajectories for the simulator.
//!
//! Each scenario (`racetrack`, `figure8`, `hover`, `tum:<path>`) is reduced to
//! the same thing: a quintic position spline and a cumulative quintic rotation
//! spline (see [`crate::spline`]). The truth at any time, including the
//! acceleration and body rate that the IMU model needs, then comes from one
//! place with exact derivatives.
//!
//! Frames: world `W` is local NED, body `B` is FRD. For the analytic scenarios
//! the attitude follows a multirotor's differential flatness: the body z axis
//! points against the specific force (thrust), and yaw follows the heading.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};

use crate::spline::{PositionSpline, RotationSpline};

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

impl Trajectory {
    /// Builds the named scenario. `duration_s` of `None` takes the natural
    /// length (the file's span for `tum:`; 70 s otherwise).
    pub fn from_scenario(name: &str, duration_s: Option<f64>) -> Result<Self, TrajectoryError> {
        let d = duration_s.unwrap_or(70.0);
        match name {
            "racetrack" => Ok(racetrack(&RacetrackParams::default(), d)),
            "figure8" => Ok(figure8(d)),
            "hover" => Ok(hover(d)),
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

    /// Builds a trajectory from a sampled position function and an attitude
    /// rule. Control points are taken from `t = -0.2 s` to `duration + 0.3 s`
    /// so the spline covers `[0, duration]`.
    fn from_functions(name: &str, duration_s: f64, pos_fn: impl Fn(f64) -> Vector3<f64>, attitude: Attitude) -> Self {
        let n = (duration_s / KNOT_DT_S).ceil() as usize + 6;
        let t0 = -2.0 * KNOT_DT_S;
        let ctrl: Vec<_> = (0..n).map(|m| pos_fn(t0 + m as f64 * KNOT_DT_S)).collect();
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
                    Attitude::FollowHeading => {
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
    FollowHeading,
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
        }
    }
}

/// An oval flown at constant ground speed. The curve angle θ(t) is the
/// solution of `θ' = v / |dP/dθ|`, integrated with RK4, so the speed is the
/// same on the straights and in the (banked) turns.
pub fn racetrack(p: &RacetrackParams, duration_s: f64) -> Trajectory {
    let (a, b) = (p.semi_major_m, p.semi_minor_m);
    let dtheta = |th: f64| p.speed_mps / (a * a * th.cos().powi(2) + b * b * th.sin().powi(2)).sqrt();
    // Tabulate θ(t) on a fine grid covering the spline's control times.
    let h = KNOT_DT_S / 20.0;
    let t_start = -1.0;
    let n = ((duration_s + 2.0 - t_start) / h).ceil() as usize;
    let mut thetas = Vec::with_capacity(n + 1);
    // θ(0) = 0: t = 0 is at the middle of the west side, heading north.
    let mut th = -dtheta(0.0) * (-t_start);
    thetas.push(th);
    for _ in 0..n {
        let k1 = dtheta(th);
        let k2 = dtheta(th + 0.5 * h * k1);
        let k3 = dtheta(th + 0.5 * h * k2);
        let k4 = dtheta(th + h * k3);
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
        Vector3::new(a * th.sin(), b * (1.0 - th.cos()), -(hgt + climb * (2.0 * th).sin()))
    };
    Trajectory::from_functions("racetrack", duration_s, pos, Attitude::FollowHeading)
}

/// A lemniscate of Gerono, 60 m × 30 m, one loop every 30 s, with a slow
/// altitude wave.
pub fn figure8(duration_s: f64) -> Trajectory {
    let w = 2.0 * std::f64::consts::PI / 30.0;
    let pos = move |t: f64| {
        let th = w * t;
        Vector3::new(
            30.0 * th.sin(),
            15.0 * (2.0 * th).sin(),
            -(6.0 + 1.5 * (0.5 * th).sin()),
        )
    };
    Trajectory::from_functions("figure8", duration_s, pos, Attitude::FollowHeading)
}

/// Minimum-jerk blend `s(τ)` for τ ∈ [0,1]: 10τ³ − 15τ⁴ + 6τ⁵.
fn min_jerk(tau: f64) -> f64 {
    let t = tau.clamp(0.0, 1.0);
    t * t * t * (10.0 - 15.0 * t + 6.0 * t * t)
}

/// Hover and translate: sits still on the ground for 4 s (for static
/// initialisation), climbs to 3 m, then moves between waypoints with hovers
/// and slow yaw turns in between.
pub fn hover(duration_s: f64) -> Trajectory {
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
    ];
    let period = 43.0 - 11.0;
    let interp = move |t: f64| -> (Vector3<f64>, f64) {
        // After the first cycle, repeat the legs from t = 11 s.
        let tt = if t > 43.0 { 11.0 + (t - 11.0) % period } else { t };
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
    )
}

/// Loads a TUM trajectory (`t x y z qx qy qz qw`, extra columns ignored),
/// with Hamilton quaternions giving the body's orientation in the file's
/// world frame. The file's world is taken as z-up (as TUM and OpenVINS use)
/// and turned into NED by a 180° rotation about x; the body frame is kept.
/// The samples are resampled at the knot spacing (linear / slerp) and
/// smoothed by the quintic splines.
pub fn from_tum(path: &Path, duration_s: Option<f64>) -> Result<Trajectory, TrajectoryError> {
    let text = std::fs::read_to_string(path).map_err(|source| TrajectoryError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let rows = parse_tum_rows(path, &text)?;
    if rows.len() < 10 {
        return Err(TrajectoryError::TooShort {
            path: path.to_path_buf(),
            reason: format!("{} poses; at least 10 are needed", rows.len()),
        });
    }
    let t_first = rows[0].0;
    let span = rows[rows.len() - 1].0 - t_first;
    let duration = duration_s.map_or(span, |d| d.min(span));
    if duration < 1.0 {
        return Err(TrajectoryError::TooShort {
            path: path.to_path_buf(),
            reason: format!("spans {span:.3} s; at least 1 s is needed"),
        });
    }
    let (t0, pctrl, qctrl) = tum_control_points(&rows, duration);
    Ok(Trajectory {
        name: format!("tum:{}", path.display()),
        duration_s: duration,
        pos: PositionSpline::new(t0, KNOT_DT_S, pctrl),
        rot: RotationSpline::new(t0, KNOT_DT_S, unwrap_quaternions(qctrl)),
    })
}

/// One pose of a TUM file: time, position and orientation in the file's world.
type TumRow = (f64, Vector3<f64>, UnitQuaternion<f64>);

/// The poses of a TUM file's `text` (comments and blank lines skipped),
/// checked: 8 finite numbers, a unit quaternion, increasing times.
fn parse_tum_rows(path: &Path, text: &str) -> Result<Vec<TumRow>, TrajectoryError> {
    let bad = |line: usize, reason: String| TrajectoryError::BadRow {
        path: path.to_path_buf(),
        line,
        reason,
    };
    let mut rows: Vec<TumRow> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let vals: Result<Vec<f64>, _> = l.split_whitespace().take(8).map(str::parse::<f64>).collect();
        let vals = vals.map_err(|e| bad(i + 1, format!("not a number ({e})")))?;
        if vals.len() < 8 {
            return Err(bad(
                i + 1,
                format!("expected 8 columns 't x y z qx qy qz qw', found {}", vals.len()),
            ));
        }
        if vals.iter().any(|v| !v.is_finite()) {
            return Err(bad(i + 1, "non-finite value".into()));
        }
        let qv = nalgebra::Quaternion::new(vals[7], vals[4], vals[5], vals[6]);
        let qn = qv.norm();
        if (qn - 1.0).abs() > 1e-3 {
            return Err(bad(i + 1, format!("quaternion norm {qn:.6} is not 1")));
        }
        if let Some(last) = rows.last() {
            if vals[0] <= last.0 {
                return Err(bad(
                    i + 1,
                    format!("time {} does not increase (previous {})", vals[0], last.0),
                ));
            }
        }
        rows.push((
            vals[0],
            Vector3::new(vals[1], vals[2], vals[3]),
            UnitQuaternion::from_quaternion(qv),
        ));
    }
    Ok(rows)
}

/// Resamples `rows` (at least two) at the knot spacing over `duration` s
/// (linear / slerp, clamped at the ends) into the NED world: the first knot
/// time and the position and rotation control points.
fn tum_control_points(rows: &[TumRow], duration: f64) -> (f64, Vec<Vector3<f64>>, Vec<UnitQuaternion<f64>>) {
    let t_first = rows[0].0;
    let span = rows[rows.len() - 1].0 - t_first;
    // z-up world → NED-like z-down world: 180° about x.
    let flip = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
    let at = |t_rel: f64| -> (Vector3<f64>, UnitQuaternion<f64>) {
        let t = t_first + t_rel.clamp(0.0, span);
        let k = rows.partition_point(|r| r.0 <= t).clamp(1, rows.len() - 1);
        let (ta, pa, qa) = rows[k - 1];
        let (tb, pb, qb) = rows[k];
        let f = ((t - ta) / (tb - ta)).clamp(0.0, 1.0);
        let p = pa + (pb - pa) * f;
        let q = qa.slerp(&qb, f);
        (flip * p, flip * q)
    };
    let n = (duration / KNOT_DT_S).ceil() as usize + 6;
    let t0 = -2.0 * KNOT_DT_S;
    let mut pctrl = Vec::with_capacity(n);
    let mut qctrl = Vec::with_capacity(n);
    for m in 0..n {
        let (p, q) = at(t0 + m as f64 * KNOT_DT_S);
        pctrl.push(p);
        qctrl.push(q);
    }
    (t0, pctrl, qctrl)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn racetrack_is_about_a_kilometre_at_fifteen_mps() {
        let tr = racetrack(&RacetrackParams::default(), 200.0);
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
        let tr = hover(30.0);
        let s = tr.sample(1.0);
        assert!(s.v_B_in_W.norm() < 1e-9 && s.w_B.norm() < 1e-9);
        let z_b = s.q_W_B * Vector3::z();
        assert!((z_b - Vector3::z()).norm() < 1e-9);
        let rt = racetrack(&RacetrackParams::default(), 70.0);
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

    #[test]
    fn tum_errors_name_the_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("nope.txt");
        let e = from_tum(&missing, None).unwrap_err().to_string();
        assert!(e.contains("nope.txt"), "{e}");
        let broken = dir.path().join("broken.txt");
        std::fs::write(&broken, "# hdr\n0 0 0 0 0 0 0 1\n0.1 0 0 abc 0 0 0 1\n").unwrap();
        let e = from_tum(&broken, None).unwrap_err().to_string();
        assert!(e.contains("broken.txt") && e.contains("line 3"), "{e}");
        std::fs::write(&broken, "0 0 0 0 0 0 0 1\n0.1 0 0 NaN 0 0 0 1\n").unwrap();
        let e = from_tum(&broken, None).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("non-finite"), "{e}");
        assert!(Trajectory::from_scenario("zigzag", None)
            .unwrap_err()
            .to_string()
            .contains("zigzag"));
    }

    /// A TUM file in the format of OpenVINS's trajectories (`t x y z qx qy
    /// qz qw` and six zero columns, z up), written here from a known motion:
    /// a 4 m circle at 0.5 rad/s (2 m/s), 1 m up, facing along the path.
    #[test]
    fn tum_file_loads_with_its_duration_speed_and_frame() {
        use std::fmt::Write as _;
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("circle.txt");
        let mut text = String::from("# t x y z qx qy qz qw\n");
        for i in 0..=6000 {
            let t = i as f64 * 0.01;
            let a = 0.5 * t;
            let q = UnitQuaternion::from_euler_angles(0.0, 0.0, a + std::f64::consts::FRAC_PI_2).coords;
            let (x, y) = (4.0 * a.cos(), 4.0 * a.sin());
            writeln!(text, "{t} {x} {y} 1.0 {} {} {} {} 0 0 0 0 0 0", q.x, q.y, q.z, q.w).unwrap();
        }
        std::fs::write(&p, text).unwrap();
        let tr = from_tum(&p, None).unwrap();
        assert!((tr.duration_s - 60.0).abs() < 0.5, "{}", tr.duration_s);
        let s = tr.sample(30.0);
        assert!((s.v_B_in_W.norm() - 2.0).abs() < 0.02, "{}", s.v_B_in_W.norm());
        // z up in the file is 1 m above the origin: down = -1 m in NED.
        assert!((s.p_B_in_W.z + 1.0).abs() < 1e-3, "{}", s.p_B_in_W);
        assert!((s.p_B_in_W.xy().norm() - 4.0).abs() < 0.01, "{}", s.p_B_in_W);
    }
}
