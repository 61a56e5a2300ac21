//! What the filter refuses and what it notices: degenerate tracks and
//! inputs are rejected and counted, never a panic; a state knocked off the
//! truth behind the covariance's back is caught from the innovations
//! (README §9).

use nalgebra::Vector3;

use cmsckf::estimator::{frontend, ImuMeas, Mode, NormObs};
use cmsckf::eval;
use cmsckf_models::feature_wire::PixelFeature;

mod common;
use common::flights::racetrack;

/// Degenerate inputs are rejected and counted, never a panic.
#[test]
fn degenerate_tracks_and_inputs_are_rejected_and_counted() {
    let (ds, cfg) = racetrack(3, 3.0);
    let mut run = eval::Runner::new(&ds, &cfg, Mode::Full, 3);
    for k in 0..30 {
        run.step_frame(k);
    }
    let est = &mut run.est;
    let t0 = est.time_s();
    // (The simulated camera stamps its first frame before the first IMU
    // sample: already refused once.)
    let backwards_before = est
        .stats
        .rejected
        .get(&cmsckf::counters::Counter::FrameTimeBackwards)
        .copied()
        .unwrap_or(0);
    let obs = |id: u64, x: f64, y: f64| NormObs {
        landmark_id: id,
        xn: nalgebra::Vector2::new(x, y),
        W: nalgebra::Matrix2::identity() * 400.0,
    };
    // A landmark seen once, then lost: too few observations.
    est.process_frame(t0 + 0.001, &[obs(900_001, 0.1, 0.1)]).unwrap();
    // Parallel rays: a landmark at the same pixel from (almost) the same pose.
    est.process_frame(t0 + 0.002, &[obs(900_002, 0.0, 0.0)]).unwrap();
    est.process_frame(t0 + 0.003, &[obs(900_002, 0.0, 0.0)]).unwrap();
    est.process_frame(t0 + 0.004, &[obs(900_002, 0.0, 0.0)]).unwrap();
    let rep = est.process_frame(t0 + 0.005, &[]).unwrap();
    assert!(
        est.stats
            .rejected
            .get(&cmsckf::counters::Counter::TrackRejectedTooFewObservations)
            .copied()
            .unwrap_or(0)
            >= 1,
        "{:?}",
        est.stats.rejected
    );
    assert!(
        rep.rejected.contains_key(&cmsckf::estimator::Reject::PoorParallax)
            || rep.rejected.contains_key(&cmsckf::estimator::Reject::BadDepth),
        "{:?}",
        rep.rejected
    );
    // Points behind the camera: pixels of a track that moves the wrong way.
    for (i, x) in [-0.5, 0.0, 0.5].iter().enumerate() {
        est.process_frame(t0 + 0.006 + 0.001 * i as f64, &[obs(900_003, *x, 0.0)])
            .unwrap();
    }
    est.process_frame(t0 + 0.01, &[]).unwrap();
    // NaN pixels never reach the filter: the front end drops them.
    let cam = cmsckf_models::camera::Camera::from_config(&cfg.camera);
    let mut out = Vec::new();
    let rej = frontend::normalise(
        &cam,
        frontend::PixelNoise {
            default_px: 1.0,
            model_px: None,
        },
        [
            PixelFeature::new(1, f64::NAN, 3.0),
            PixelFeature::new(2, 10.0, f64::INFINITY),
            PixelFeature::new(3, 100.0, 100.0),
        ],
        &mut out,
    );
    assert_eq!(rej.non_finite, 2);
    assert_eq!(out.len(), 1);
    // Time going backwards and non-finite IMU samples are refused.
    assert!(est.process_frame(t0 - 1.0, &[]).is_err());
    assert!(est
        .add_imu(ImuMeas {
            t_s: t0 + 1.0,
            accel_mps2: Vector3::new(f64::NAN, 0.0, 0.0),
            gyro_radps: Vector3::zeros()
        })
        .is_err());
    assert!(est
        .add_imu(ImuMeas {
            t_s: t0 - 5.0,
            accel_mps2: Vector3::zeros(),
            gyro_radps: Vector3::zeros()
        })
        .is_err());
    assert_eq!(
        est.stats.rejected.get(&cmsckf::counters::Counter::ImuNonFinite),
        Some(&1)
    );
    assert_eq!(
        est.stats.rejected.get(&cmsckf::counters::Counter::ImuTimeBackwards),
        Some(&1)
    );
    assert_eq!(
        est.stats.rejected.get(&cmsckf::counters::Counter::FrameTimeBackwards),
        Some(&(backwards_before + 1))
    );
    est.check_health().unwrap();
}

/// Divergence detection (§9): a healthy flight never trips the monitor; a
/// state knocked 20 m and 5 m/s off the truth behind the covariance's back
/// is caught within a second or two by the innovations alone.
#[test]
fn a_diverged_state_is_detected_from_its_innovations() {
    let (ds, cfg) = racetrack(5, 25.0);
    let mut run = eval::Runner::new(&ds, &cfg, Mode::Compressed, 5).with_gnss();
    let mut knocked_at = None;
    let mut detected_at = None;
    for k in 0..ds.frames.len() {
        let t = ds.frames[k].t_s;
        if knocked_at.is_none() && t >= 15.0 {
            let knocked = run.est.imu_state_mut();
            knocked.p_B_in_W += Vector3::new(20.0, 0.0, 0.0);
            knocked.v_B_in_W += Vector3::new(0.0, 5.0, 0.0);
            knocked_at = Some(t);
        }
        run.step_frame(k);
        match (knocked_at, run.est.check_health()) {
            (None, Err(e)) => panic!("healthy flight flagged at {t:.2} s: {e}"),
            (Some(t0), Err(e)) => {
                assert!(e.contains("divergence"), "{e}");
                detected_at = Some(t - t0);
                break;
            }
            _ => {}
        }
    }
    let dt = detected_at.expect("divergence detected");
    assert!(dt <= 3.0, "detected {dt:.2} s after the knock");
}

/// How a filter started 16σ off in gyro bias fared: when its monitor first
/// failed (s after the start), and, if it never did, its largest position
/// error and its last gyro-bias error in sigmas.
struct BiasStart {
    flagged_after_s: Option<f64>,
    max_error_m: f64,
    bias_error_sigmas: f64,
}

/// Starts a filter with a gyro bias 0.08 rad/s off on x under the static
/// prior's 0.005 rad/s (16σ: what an in-flight start with a static prior
/// did to a real IMU), on an armed multirotor (200 Hz, vibrating) seen by
/// a real front-end's few tracks (`per_frame` = 20), standing for
/// `standstill_s` and then flying, for 20 s.
fn start_16_sigma_off(seed: u64, standstill_s: f64, knock_radps: f64) -> BiasStart {
    let cfg = cmsckf::config::Config::default();
    let mut sim = eval::sim_config_for(&cfg);
    // The gyro's true bias stays a calibrated IMU's: the knock below is
    // the 16σ error.
    sim.gyro_bias0_sigma = common::flights::calibrated_sim(&cfg).gyro_bias0_sigma;
    sim.features.per_frame = 20;
    sim.standstill_s = standstill_s;
    let ds = cmsckf_sitl::dataset::Dataset::generate("racetrack", seed, Some(20.0), &sim).unwrap();
    let mut run = eval::Runner::new(&ds, &cfg, Mode::Compressed, seed);
    run.est.imu_state_mut().b_g += Vector3::new(knock_radps, 0.0, 0.0);
    let t0 = run.est.time_s();
    let mut max_error_m: f64 = 0.0;
    for k in 0..ds.frames.len() {
        run.step_frame(k);
        let t = run.est.time_s();
        if let Err(e) = run.est.check_health() {
            assert!(e.contains("divergence"), "{e}");
            eprintln!(
                "seed {seed}, standing {standstill_s} s: flagged {:.2} s after the start: {e}",
                t - t0
            );
            return BiasStart {
                flagged_after_s: Some(t - t0),
                max_error_m,
                bias_error_sigmas: f64::NAN,
            };
        }
        max_error_m = max_error_m.max((run.est.imu_state().p_B_in_W - ds.trajectory.sample(t).p_B_in_W).norm());
    }
    let bias_error_sigmas = common::flights::gyro_bias_error_sigmas(&run.est, &ds).max();
    eprintln!(
        "seed {seed}, standing {standstill_s} s: never flagged; largest error {max_error_m:.2} m, gyro bias {bias_error_sigmas:.1} σ off at the end"
    );
    BiasStart {
        flagged_after_s: None,
        max_error_m,
        bias_error_sigmas,
    }
}

/// Issue 37: a start 16σ off in gyro bias, with the 20 tracks a frame a
/// real front-end gives, is caught by its monitor within 3 s of the start
/// (the 2 s grace and one window), or it recovers: the bias learnt to
/// within 3σ and the position never further off than 1.5 times (and
/// 0.5 m) what the same flight started on the truth's bias was. Standing first (no parallax:
/// only the refused zero-velocity updates can tell, D3) and in flight (D1
/// over as long a window as it takes to hold 20 tracks). It never flies on
/// unflagged while wrong.
#[test]
fn a_start_16_sigma_off_in_gyro_bias_is_caught_or_recovers_within_3_s() {
    for seed in [1, 2, 3] {
        for standstill_s in [5.0, 0.0] {
            let r = start_16_sigma_off(seed, standstill_s, 0.08);
            match r.flagged_after_s {
                Some(dt) => assert!(dt <= 3.0, "seed {seed}: flagged {dt:.2} s after the start"),
                None => assert!(
                    r.max_error_m < 1.5 * start_16_sigma_off(seed, standstill_s, 0.0).max_error_m + 0.5
                        && r.bias_error_sigmas < 3.0,
                    "seed {seed}, standing {standstill_s} s: unflagged with {:.1} m of error, bias {:.1} σ off",
                    r.max_error_m,
                    r.bias_error_sigmas
                ),
            }
        }
    }
}

/// A long hover with its few tracks (gusts, yaw turns, 3 s holds: about 7
/// tracks a second judged) never trips the monitor: D1's longer window
/// judges only 40 tracks or more, and only by the gate. With 20, the hover
/// of seed 2 was flagged at 188 s ("90% of 21 tracks refused by the gate in
/// 3.0 s") on a filter 0.13 m from the truth.
///
/// The same on an armed vehicle's vibrating, biased 200 Hz IMU, 70 s: its
/// hovers look still to the IMU's means, their zero-velocity updates are
/// refused for the hover's drift, and D3 counted those as a divergence
/// (seed 1 was reset at 10.5 s) until only the gyro rows' refusals counted.
/// Without the autopilot's landed state, so that the hovers are offered
/// as still at all.
#[test]
fn a_long_hover_never_trips_the_monitor() {
    let cfg = cmsckf::config::Config::default();
    let quiet = common::flights::calibrated_sim(&cfg);
    let armed = eval::sim_config_for(&cfg);
    for (sim, seed, duration_s) in [
        (&quiet, 1, 200.0),
        (&quiet, 2, 200.0),
        (&armed, 1, 70.0),
        (&armed, 2, 70.0),
    ] {
        let ds = cmsckf_sitl::dataset::Dataset::generate("hover", seed, Some(duration_s), sim).unwrap();
        let mut run = eval::Runner::new(&ds, &cfg, Mode::Compressed, seed).without_landed_state();
        for k in 0..ds.frames.len() {
            run.step_frame(k);
            if let Err(e) = run.est.check_health() {
                panic!(
                    "seed {seed}, {} Hz IMU: a healthy hover flagged at {:.2} s: {e}",
                    sim.imu_rate_hz,
                    run.est.time_s()
                );
            }
        }
    }
}
