//! Yaw about gravity stays unobservable (README §3d): a camera and an IMU
//! cannot tell where north is, so without GNSS or a compass the yaw's σ may
//! only grow, in every mode, however precise the pixels. A measurement
//! linearised where the unobservable directions look observed gains yaw
//! information that does not exist, and the filter then claims a yaw it
//! does not have (issue 37: a zero-velocity update linearised at a velocity
//! off zero, and a keyframe's rotation Jacobian taken at its latest
//! estimate, shrank a 4.8° σ to 2.3° at a take-off, 3.5° off the truth).
//!
//! The flights: the racetrack (standing 6 s, then a take-off to 15 m/s),
//! and the hover (hovers and yaw turns between short translations, where
//! most tracks are used at their landmark's remembered depth, README §3e),
//! their pixels at 0.05 px in the simulator and the filter (so a leak,
//! multiplied by precise measurements, cannot hide), the yaw started 5°
//! uncertain, GNSS off.

use cmsckf::config::Config;
use cmsckf::estimator::Mode;
use cmsckf::eval;
use cmsckf_sitl::dataset::Dataset;

#[test]
fn the_yaw_sigma_never_shrinks_without_a_heading_reference() {
    let mut cfg = Config::default();
    cfg.camera.pixel_noise_px = 0.05;
    cfg.init.sigma_yaw_deg = 5.0;
    let sim = eval::sim_config_for(&cfg);
    for (scenario, seed) in [("racetrack", 3), ("racetrack", 5), ("hover", 3)] {
        let ds = Dataset::generate(scenario, seed, Some(45.0), &sim).unwrap();
        for mode in [Mode::Msckf, Mode::Compressed, Mode::Full] {
            let r = eval::run(&ds, &cfg, mode, seed, false);
            let sigma_deg: Vec<f64> = r.cov_pose.iter().map(|c| c[(2, 2)].sqrt().to_degrees()).collect();
            // Against the prior itself, not the first frame's (already a
            // zero-velocity update).
            let first = cfg.init.sigma_yaw_deg;
            let least = sigma_deg.iter().copied().fold(f64::INFINITY, f64::min);
            let k = sigma_deg.len() - 1;
            let err_deg = (r.q_est[k] * r.q_true[k].inverse()).scaled_axis().z.to_degrees();
            let st = &r.stats;
            eprintln!(
                "{scenario} seed {seed} {mode:?}: yaw σ {first:.3}° at the start, least {least:.3}°, last {:.3}°; yaw error at \
                 the end {err_deg:.2}°; resets {}; zero-velocity updates {}, tracks {} ({} at their remembered depth), \
                 loop-closure updates {}, global updates {}",
                sigma_deg[k],
                r.resets,
                st.zupt_updates,
                st.tracks_used,
                st.low_parallax_tracks,
                st.loop_closure_updates,
                st.global_updates
            );
            assert_eq!(r.resets, 0, "{scenario} seed {seed} {mode:?}");
            // Every kind of row that leaked ran: the standing's zero-velocity
            // updates, the camera's tracks, in compressed mode keyframes
            // observed again (through the global part on the racetrack), and
            // in the hover tracks at their remembered depth.
            assert!(
                st.zupt_updates > 50 && st.tracks_used > 5000,
                "{scenario} seed {seed} {mode:?}: {st:?}"
            );
            if mode == Mode::Compressed {
                assert!(st.loop_closure_updates > 0, "{scenario} seed {seed}: {st:?}");
            }
            if scenario == "racetrack" && mode == Mode::Compressed {
                assert!(st.global_updates > 0, "{scenario} seed {seed}: {st:?}");
            }
            // The hover's low-parallax rows (§3e).
            if scenario == "hover" {
                assert!(st.low_parallax_tracks > 1000, "{scenario} seed {seed}: {st:?}");
            }
            // The gyro's noise only adds. The start's velocity and position,
            // drawn off the truth by their σ (0.2 m/s, 5 cm), tie about 1 %
            // of the yaw to them through N_v = −[v̂]×g, N_p = −[p̂]×g: that
            // much may go, no more.
            assert!(
                least > 0.98 * first,
                "{scenario} seed {seed} {mode:?}: yaw σ {first:.3}° shrank to {least:.3}°"
            );
        }
    }
}
