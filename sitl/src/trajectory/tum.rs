//! TUM trajectories (`t x y z qx qy qz qw`, as TUM and OpenVINS write
//! them): read, checked row by row with errors that name the file and the
//! line, resampled at the knot spacing and turned into the same splines as
//! the analytic scenarios.

use std::path::Path;

use nalgebra::{UnitQuaternion, Vector3};

use super::{unwrap_quaternions, Trajectory, TrajectoryError, KNOT_DT_S};
use crate::spline::{PositionSpline, RotationSpline};

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
    from_rows(format!("tum:{}", path.display()), path, &rows, duration_s)
}

/// The trajectory through `rows` (poses in a z-up world, times in s), read
/// from `path` (named in errors), over `duration_s` or their whole span:
/// time 0 is the first pose.
pub(crate) fn from_rows(
    name: String,
    path: &Path,
    rows: &[TumRow],
    duration_s: Option<f64>,
) -> Result<Trajectory, TrajectoryError> {
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
    let (t0, pctrl, qctrl) = tum_control_points(rows, duration);
    Ok(Trajectory {
        name,
        duration_s: duration,
        pos: PositionSpline::new(t0, KNOT_DT_S, pctrl),
        rot: RotationSpline::new(t0, KNOT_DT_S, unwrap_quaternions(qctrl)),
    })
}

/// One pose of a TUM file: time, position and orientation in the file's world.
pub(crate) type TumRow = (f64, Vector3<f64>, UnitQuaternion<f64>);

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
        assert!(
            Trajectory::from_scenario("zigzag", None, 5.0, &crate::trajectory::GustField::default())
                .unwrap_err()
                .to_string()
                .contains("zigzag")
        );
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
