//! IMU gaps (README §2, eq. N3): a second without IMU samples in flight is
//! bridged with the motion it hides in the covariance, so the frames after
//! it do not trip the monitor and no restart carries its error on.

use cmsckf::config::Config;
use cmsckf::estimator::Mode;
use cmsckf::eval;
use cmsckf_sitl::dataset::Dataset;

/// A racetrack flight with vision only (no GNSS), with `gaps` 1 s IMU gaps
/// 5 s apart from 14 s: the largest position error, and the position NEES
/// 0.2 s after each gap's end (3 dof). Panics if the monitor trips.
fn fly_with_gaps(seed: u64, gaps: usize) -> (f64, Vec<f64>) {
    let cfg = Config::default();
    let sim = eval::sim_config_for(&cfg);
    let mut ds = Dataset::generate("racetrack", seed, Some(50.0), &sim).unwrap();
    let windows: Vec<(f64, f64)> = (0..7).map(|k| (14.0 + 5.0 * k as f64, 15.0 + 5.0 * k as f64)).collect();
    ds.imu
        .retain(|s| !windows[..gaps].iter().any(|(a, b)| s.t_s > *a && s.t_s < *b));
    let mut run = eval::Runner::new(&ds, &cfg, Mode::Compressed, seed);
    let mut checks = windows.iter().map(|(_, b)| b + 0.2).peekable();
    let (mut max_error_m, mut nees_after): (f64, Vec<f64>) = (0.0, Vec::new());
    for k in 0..ds.frames.len() {
        run.step_frame(k);
        let t = run.est.time_s();
        if let Err(e) = run.est.check_health() {
            panic!("seed {seed}, {gaps} gaps: the monitor tripped at {t:.2} s: {e}");
        }
        let e = run.est.imu_state().p_B_in_W - ds.trajectory.sample(t).p_B_in_W;
        max_error_m = max_error_m.max(e.norm());
        if checks.peek().is_some_and(|c| t >= *c) {
            checks.next();
            let p = run.est.imu_covariance().fixed_view::<3, 3>(6, 6).into_owned();
            let nees = e.dot(&(p.try_inverse().unwrap() * e));
            eprintln!(
                "seed {seed}, {gaps} gaps, t {t:.2}: error {:.2} m, sigma {:.2} m, position NEES {nees:.2}",
                e.norm(),
                p.trace().sqrt()
            );
            nees_after.push(nees);
        }
    }
    (max_error_m, nees_after)
}

/// The issue-37 reproducer's IMU side: seven 1 s gaps in a racetrack flight
/// with the GNSS out. Before N3 each gap left 6–10° of tilt under a 0.25°
/// sigma, the monitor reset the filter after each, and the restarts carried
/// the error on (position NEES 30 to 2000 at the restarts, hundreds of
/// metres). Now no gap trips the monitor, the first gap ends inside its 95%
/// position bound, and the flight ends within three times (and 2 m) the
/// error of the same flight without gaps.
#[test]
fn one_second_imu_gaps_are_bridged_honestly() {
    for seed in [3, 4] {
        let (max_gapless_m, _) = fly_with_gaps(seed, 0);
        let (max_error_m, nees) = fly_with_gaps(seed, 7);
        eprintln!("seed {seed}: largest error {max_error_m:.2} m with gaps, {max_gapless_m:.2} m without");
        assert!(
            nees[0] < 7.81,
            "seed {seed}: position NEES {:.2} after the first gap",
            nees[0]
        );
        assert!(
            max_error_m < 3.0 * max_gapless_m + 2.0,
            "seed {seed}: {max_error_m:.2} m with gaps, {max_gapless_m:.2} m without"
        );
    }
}

/// Short IMU gaps, however many, never hold the monitor off, and longer
/// ones hold off only its vision checks: a state knocked 20 m and 5 m/s off
/// behind the covariance's back amid a train of gaps every 1.5 s is caught
/// (a train of 60 ms gaps once kept the whole monitor in grace while an IMU
/// spike drove the estimate 384 m off). With 80 ms gaps the tracks catch it
/// within 3 s (0.53 s); with 0.3 s gaps, whose tracks wait their grace, the
/// GNSS does, within its five epochs (4.4 s).
#[test]
fn gaps_never_hide_a_divergence() {
    for gap_s in [0.08, 0.3] {
        let cfg = Config::default();
        let sim = eval::sim_config_for(&cfg);
        let mut ds = Dataset::generate("racetrack", 5, Some(25.0), &sim).unwrap();
        let in_gap = |t: f64| t > 5.0 && (t - 5.0) % 1.5 < gap_s;
        ds.imu.retain(|s| !in_gap(s.t_s));
        let mut run = eval::Runner::new(&ds, &cfg, Mode::Compressed, 5).with_gnss();
        let (mut knocked_at, mut detected_after) = (None, None);
        for k in 0..ds.frames.len() {
            let t = ds.frames[k].t_s;
            if knocked_at.is_none() && t >= 15.0 {
                let x = run.est.imu_state_mut();
                x.p_B_in_W += nalgebra::Vector3::new(20.0, 0.0, 0.0);
                x.v_B_in_W += nalgebra::Vector3::new(0.0, 5.0, 0.0);
                knocked_at = Some(t);
            }
            run.step_frame(k);
            match (knocked_at, run.est.check_health()) {
                (None, Err(e)) => panic!("{gap_s} s gaps: a healthy flight flagged at {t:.2} s: {e}"),
                (Some(t0), Err(e)) => {
                    eprintln!("{gap_s} s gaps: caught {:.2} s after the knock: {e}", t - t0);
                    detected_after = Some(t - t0);
                    break;
                }
                _ => {}
            }
        }
        let dt = detected_after.unwrap_or_else(|| panic!("{gap_s} s gaps: the divergence was never caught"));
        // The tracks within 3 s; the GNSS (D2: most codes of its last 5
        // epochs, at 1 Hz and 0.2–0.6 s late) within 5 s.
        let bound_s = if gap_s < 0.25 { 3.0 } else { 5.0 };
        assert!(dt <= bound_s, "{gap_s} s gaps: caught {dt:.2} s after the knock");
    }
}
