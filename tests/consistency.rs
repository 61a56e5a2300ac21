//! Filter consistency over many seeds: the mean pose NEES of `msckf`,
//! `full` and `compressed` lies in its 95% χ² interval, and Schmidt is never
//! over-confident. Also checks compressed = full on every seed.

use cmsckf::config::Config;
use cmsckf::estimator::Mode;
use cmsckf::eval;
use cmsckf_sitl::metrics::nees_bounds_95;

/// Least fraction of frames at which the seed-averaged pose NEES must lie
/// inside its per-time 95% bounds (0.95 for a perfectly consistent filter;
/// the samples of one flight are correlated, so the fraction scatters).
const PER_TIME_MIN: f64 = 0.8;

#[test]
fn nees_is_consistent_over_ten_seeds() {
    let cfg = Config::default();
    let sim = eval::sim_config_for(&cfg);
    let seeds = 10;
    let ev = eval::evaluate(
        &eval::EvalSpec {
            scenario: "racetrack".into(),
            modes: Mode::ALL.to_vec(),
            seeds: eval::Seeds::UpTo(seeds),
            duration_s: Some(40.0),
            gnss: false,
            landed_state: true,
        },
        &cfg,
        &sim,
        |_| {},
    )
    .unwrap();
    // Each sample is a 6-DoF pose NEES; averaged over the seeds at one time
    // it is χ²(6·seeds)/seeds.
    eprintln!("{}", ev.table());
    let (lo, hi) = nees_bounds_95(6, seeds as usize);
    for m in ["msckf", "full", "compressed"] {
        let r = &ev.modes[m];
        assert!(
            (lo..=hi).contains(&r.nees_mean),
            "{m}: mean NEES {} outside [{lo:.2}, {hi:.2}] (per seed {:?})",
            r.nees_mean,
            r.per_seed_nees_mean
        );
    }
    // Per time, not only on average: at each frame the seed-averaged pose
    // NEES is χ²(6·seeds)/seeds, inside its 95% bounds at most frames.
    for m in ["msckf", "full", "compressed"] {
        let r = &ev.modes[m];
        eprintln!(
            "{m}: per-time fraction in bounds: pose {:.2}, yaw {:.2}, position {:.2}",
            r.nees_pose_in_bounds_per_time, r.nees_yaw_in_bounds_per_time, r.nees_position_in_bounds_per_time
        );
        assert!(
            r.nees_pose_in_bounds_per_time >= PER_TIME_MIN,
            "{m}: the pose NEES is inside its per-time bounds at only {:.2} of the frames",
            r.nees_pose_in_bounds_per_time
        );
    }
    // By part, for every mode that corrects its keyframes: the yaw (1 dof)
    // and the position (3 dof), which first-estimate Jacobians keep
    // unobservable. Their seed means lie in their 95% intervals, over the
    // whole flight and its second half, and the yaw's stays below 1.5: a
    // filter without first-estimate Jacobians gains spurious yaw
    // information and reaches 1.9–2.2 over a flight (issue 37's
    // measurement), which these bounds refuse.
    let (lo1, hi1) = nees_bounds_95(1, seeds as usize);
    let (lo3, hi3) = nees_bounds_95(3, seeds as usize);
    const YAW_NEES_MAX: f64 = 1.5;
    for m in ["msckf", "full", "compressed"] {
        let r = &ev.modes[m];
        for (what, yaw) in [("all", r.nees_yaw_mean), ("2nd half", r.nees_yaw_mean_second_half)] {
            assert!(
                (lo1..=hi1.min(YAW_NEES_MAX)).contains(&yaw),
                "{m}: yaw NEES ({what}) {yaw:.2} outside [{lo1:.2}, {:.2}]",
                hi1.min(YAW_NEES_MAX)
            );
        }
        for (what, pos) in [
            ("all", r.nees_position_mean),
            ("2nd half", r.nees_position_mean_second_half),
        ] {
            assert!(
                (lo3..=hi3).contains(&pos),
                "{m}: position NEES ({what}) {pos:.2} outside [{lo3:.2}, {hi3:.2}]"
            );
        }
        // The tracks' NIS per degree of freedom (evaluate's `nis_per_dof`):
        // the oracle's pixel noise is the filter's, so about 1 (issue 37
        // asks [0.5, 2]).
        assert!(
            (0.5..=2.0).contains(&r.nis_per_dof),
            "{m}: NIS per degree of freedom {:.2}",
            r.nis_per_dof
        );
        assert!(
            r.nees_yaw_in_bounds_per_time >= PER_TIME_MIN && r.nees_position_in_bounds_per_time >= PER_TIME_MIN,
            "{m}: yaw and position NEES inside their per-time bounds at {:.2} and {:.2} of the frames",
            r.nees_yaw_in_bounds_per_time,
            r.nees_position_in_bounds_per_time
        );
    }
    let s = &ev.modes["schmidt"];
    assert!(
        s.nees_mean <= hi,
        "schmidt over-confident: mean NEES {} > {hi:.2}",
        s.nees_mean
    );
    let c = &ev.modes["compressed"];
    let d = c.max_rel_diff_vs_full.expect("lockstep ran");
    // Normalised entry by entry (covariance by √(P_ii P_jj), state by σ):
    // the drift of two nonlinear filters over a flight, a few 1e-9 (the
    // identity itself holds to 1e-12 at each global update; see the
    // estimator's tests).
    assert!(d <= 5e-9, "compressed vs full {d:e}");
    for (a, b) in c
        .per_seed_ate_unaligned_m
        .iter()
        .zip(&ev.modes["full"].per_seed_ate_unaligned_m)
    {
        assert!((a - b).abs() <= 1e-6, "compressed ATE {a} vs full {b}");
    }
}

/// Schmidt over the three-lap flight, where its uncorrected keyframes used
/// to make it over-confident (6-DoF NEES 11.6 before first-estimate
/// Jacobians): its pose NEES averaged over the seeds stays below the top of
/// its 95% interval, in the flight's second half too.
#[test]
fn schmidt_is_not_over_confident_over_three_laps() {
    let cfg = Config::default();
    let sim = eval::sim_config_for(&cfg);
    let seeds = 3;
    let ev = eval::evaluate(
        &eval::EvalSpec {
            scenario: "racetrack".into(),
            modes: vec![Mode::Schmidt],
            seeds: eval::Seeds::UpTo(seeds),
            duration_s: Some(200.0),
            gnss: false,
            landed_state: true,
        },
        &cfg,
        &sim,
        |_| {},
    )
    .unwrap();
    let s = &ev.modes["schmidt"];
    let (_, hi6) = nees_bounds_95(6, seeds as usize);
    let (_, hi1) = nees_bounds_95(1, seeds as usize);
    let (_, hi3) = nees_bounds_95(3, seeds as usize);
    eprintln!(
        "schmidt, 3 laps: NEES {:.2} (≤ {hi6:.2}); yaw {:.2} / {:.2}; position {:.2} / {:.2}; {} loop-closure tracks",
        s.nees_mean,
        s.nees_yaw_mean,
        s.nees_yaw_mean_second_half,
        s.nees_position_mean,
        s.nees_position_mean_second_half,
        s.loop_closure_updates
    );
    assert!(s.loop_closure_updates > 1000.0, "three laps close loops");
    assert!(
        s.nees_mean <= hi6,
        "schmidt over-confident over three laps: {}",
        s.nees_mean
    );
    assert!(s.nees_yaw_mean_second_half <= hi1 && s.nees_position_mean_second_half <= hi3);
}
