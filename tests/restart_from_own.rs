//! A restart starts from our own estimate, at once: never from the
//! autopilot's echo of it, and without a gap in the outputs.
//!
//! Flown on ArduPilot with external navigation as its only source, each
//! restart took ArduPilot's ATTITUDE and LOCAL_POSITION_NED, which were only
//! the echo of the daemon's last output: the error grew across restarts (a
//! 1.6 km fly-away in one run), and each restart left 0.96 s without
//! estimates, which fails ArduPilot's VisOdom health check. Here the fusion
//! loop flies the simulated racetrack while the "autopilot" reports a
//! position 30 m off and a yaw 40° off (no GNSS fix of its own), and one
//! second of corrupt camera frames makes the filter diverge.

mod common;

use cmsckf::config::{Config, GnssSource};
use cmsckf::counters::{Counter, Counters};
use cmsckf::daemon::{Fusion, FusionMsg};
use cmsckf::estimator::frontend::Normaliser;
use cmsckf::estimator::ImuMeas;
use cmsckf::io::feature_pipe::FeatureFrame;
use cmsckf::io::messages::Outbound;
use cmsckf_models::feature_wire::PixelFeature;
use cmsckf_sitl::dataset::Dataset;
use nalgebra::Vector3;

/// The echo's error: what the autopilot reports, against the truth.
const ECHO_OFFSET_M: [f64; 3] = [30.0, 0.0, 0.0];
const ECHO_YAW_OFFSET_RAD: f64 = 0.7;
/// Camera frames in this window are corrupt: every feature 40 px off in a
/// direction of its own (a shift common to all would be a rotation).
const CORRUPT_S: (f64, f64) = (18.0, 19.0);

/// What one flight gave: the counters, and each estimate's time and
/// position.
struct Flight {
    counters: Counters,
    estimates: Vec<(f64, Vector3<f64>, Vector3<f64>)>,
}

/// Flies the racetrack through the fusion loop, its frames corrupt in
/// [`CORRUPT_S`] if `corrupt`.
fn fly(ds: &Dataset, cfg: &Config, corrupt_frames: bool) -> Flight {
    let (ctx, mut out_rx) = common::fusion_ctx();
    let mut f = Fusion::new(cfg.clone(), None);
    let normaliser = Normaliser::new(&cfg.camera);
    // The autopilot's view: right until the filter starts (its own compass
    // and origin), then the echo, off by the offsets above.
    let autopilot = |t: f64, echo: bool| {
        let s = ds.trajectory.sample(t);
        let (r, p, y) = s.q_W_B.euler_angles();
        let off = if echo {
            Vector3::from(ECHO_OFFSET_M)
        } else {
            Vector3::zeros()
        };
        let yaw_off = if echo { ECHO_YAW_OFFSET_RAD } else { 0.0 };
        [
            FusionMsg::Attitude {
                roll: r,
                pitch: p,
                yaw: y + yaw_off,
            },
            FusionMsg::LocalPosition {
                t_s: t,
                p_ned_m: s.p_B_in_W + off,
                v_ned_mps: s.v_B_in_W,
            },
        ]
    };
    // (autopilot time, position) of each estimate sent.
    let mut estimates: Vec<(f64, Vector3<f64>, Vector3<f64>)> = Vec::new();
    let mut frames = ds.frames.iter().peekable();
    let mut next_autopilot_t = 0.0;
    for m in &ds.imu {
        if m.t_s >= next_autopilot_t {
            next_autopilot_t += 0.1;
            for msg in autopilot(m.t_s, !estimates.is_empty()) {
                f.handle(msg, &ctx);
            }
        }
        while let Some(fr) = frames.next_if(|fr| fr.t_delivered_s <= m.t_s) {
            let corrupt = corrupt_frames && (CORRUPT_S.0..CORRUPT_S.1).contains(&fr.t_s);
            let features: Vec<PixelFeature> = fr
                .features
                .iter()
                .map(|o| {
                    let a = o.landmark_id as f64;
                    let k = if corrupt { 40.0 } else { 0.0 };
                    PixelFeature::new(o.landmark_id, o.u_px + k * a.sin(), o.v_px + k * a.cos())
                })
                .collect();
            let norm = normaliser.frame(&features);
            let frame = FeatureFrame {
                t_us: (fr.t_s * 1e6).round() as u64,
                cam: 0,
                features,
            };
            f.handle(FusionMsg::Frame(frame, norm), &ctx);
        }
        f.handle(
            FusionMsg::Imu(ImuMeas {
                t_s: m.t_s,
                accel_mps2: m.accel_mps2,
                gyro_radps: m.gyro_radps,
            }),
            &ctx,
        );
        while let Ok(o) = out_rx.try_recv() {
            match o {
                Outbound::Odometry {
                    t_us,
                    p_ned_m,
                    pose_covariance,
                    ..
                } => {
                    let sigma_m = [0, 6, 11].map(|i| (pose_covariance[i] as f64).sqrt());
                    estimates.push((t_us as f64 * 1e-6, p_ned_m, Vector3::from(sigma_m)))
                }
                Outbound::StatusText { text, .. } if corrupt_frames => eprintln!("{:.2} s: {text}", m.t_s),
                _ => {}
            }
        }
    }
    Flight {
        counters: ctx.counters,
        estimates,
    }
}

/// The largest error against the truth after `t0_s`.
fn worst_after(ds: &Dataset, estimates: &[(f64, Vector3<f64>, Vector3<f64>)], t0_s: f64) -> f64 {
    estimates
        .iter()
        .filter(|(t, ..)| *t > t0_s)
        .map(|(t, p, _)| (p - ds.trajectory.sample(*t).p_B_in_W).norm())
        .fold(0.0, f64::max)
}

/// The largest per-axis error in sigmas (the output's own pose covariance)
/// after `t0_s`.
fn worst_sigmas_after(ds: &Dataset, estimates: &[(f64, Vector3<f64>, Vector3<f64>)], t0_s: f64) -> f64 {
    estimates
        .iter()
        .filter(|(t, ..)| *t > t0_s)
        .map(|(t, p, sigma)| (p - ds.trajectory.sample(*t).p_B_in_W).component_div(sigma).amax())
        .fold(0.0, f64::max)
}

#[test]
fn a_restart_starts_from_our_own_estimate_without_a_gap() {
    let mut cfg = Config::default();
    cfg.gnss.source = GnssSource::Off;
    cfg.compressed.rebase_thread = false;
    let sim = cmsckf::eval::sim_config_for(&cfg);
    for seed in 1..=6 {
        let ds = Dataset::generate("racetrack", seed, Some(30.0), &sim).unwrap();
        // The same flight undisturbed: its visual-inertial drift (no GNSS).
        let calm = fly(&ds, &cfg, false);
        let Flight { counters, estimates } = fly(&ds, &cfg, true);
        let c = |k: &str| counters.get_by_name(k);

        let resets = c("filter_reset");
        let t_reset = estimates
            .windows(2)
            .map(|w| (w[1].0, (w[1].0 - w[0].0)))
            .fold((0.0, 0.0f64), |a, b| if b.1 > a.1 { b } else { a });
        // The error after the restart, against the truth (and the
        // undisturbed flight's), against its own sigma, and against the echo.
        let worst = worst_after(&ds, &estimates, CORRUPT_S.1);
        let calm_worst = worst_after(&ds, &calm.estimates, CORRUPT_S.1);
        let worst_sigmas = worst_sigmas_after(&ds, &estimates, CORRUPT_S.1);
        let nearest_echo = estimates
            .iter()
            .filter(|(t, ..)| *t > CORRUPT_S.1)
            .map(|(t, p, _)| (p - ds.trajectory.sample(*t).p_B_in_W - Vector3::from(ECHO_OFFSET_M)).norm())
            .fold(f64::INFINITY, f64::min);
        let after = estimates.iter().filter(|(t, ..)| *t > CORRUPT_S.1).count();
        eprintln!(
            "seed {seed}: resets {resets}, starts from a carried estimate {}, largest output gap {:.3} s (at {:.2} s); \
             after the restart: worst error {worst:.2} m (undisturbed {calm_worst:.2} m), {worst_sigmas:.2} sigma at \
             most on an axis, nearest approach to the echo {nearest_echo:.1} m; {} estimates",
            c("init_from_carried_estimate"),
            t_reset.1,
            t_reset.0,
            estimates.len()
        );
        assert!(
            resets >= 1,
            "seed {seed}: the corrupt frames never made the filter restart"
        );
        assert_eq!(
            c("init_from_carried_estimate"),
            resets,
            "seed {seed}: every restart from our own estimate"
        );
        assert_eq!(c("init_static") + c("init_in_flight"), 1 + resets);
        assert!(
            t_reset.1 < 0.1,
            "seed {seed}: an output gap of {:.3} s at {:.2} s",
            t_reset.1,
            t_reset.0
        );
        assert!(after > 200, "seed {seed}: no estimates after the restart");
        assert_eq!(calm.counters.get(Counter::FilterReset), 0);
        // After the restart the filter flies on visual-inertial alone (no
        // GNSS), from the carried estimate and its covariance: where it ends
        // depends on what the corrupt second left (2.96–18.95 m worst over
        // these seeds, against 1.39–6.04 m undisturbed), and what must hold
        // is that the covariance it reports says so (0.3–1.8 sigma at most
        // on an axis), and that it never takes the echo 30 m off.
        assert!(
            worst_sigmas < 3.0,
            "seed {seed}: {worst:.2} m off the truth after the restart, {worst_sigmas:.2} sigma"
        );
        assert!(
            nearest_echo > 20.0,
            "seed {seed}: the estimate went to the echo ({nearest_echo} m)"
        );
    }
}
