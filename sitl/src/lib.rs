//! `cmsckf-sitl`: the simulator that every cmsckf test, evaluation and demo
//! runs on.
//!
//! The sensor models are pure functions of the truth plus a seeded RNG. They
//! return plain measurement types and never call the estimator, so the same
//! data can feed offline evaluation, the mock autopilot and the tests.
//!
//! - [`trajectory`]: smooth ground truth (racetrack, figure8, hover, TUM files)
//! - [`imu`], [`camera`], [`features`], [`gnss`]: the sensor models
//! - [`dataset`]: a whole flight, and its CSV export
//! - [`metrics`]: ATE, rotation RMSE, NEES and χ² bounds
//! - [`serve`]: the mock autopilot and camera front end, with its scoring
#![allow(non_snake_case)] // names carry frames: p_B_in_W, R_W_B, T_B_C
#![allow(clippy::needless_range_loop)] // index loops mirror the equations

pub mod camera;
pub mod config;
pub mod dataset;
pub mod features;
pub mod geodesy;
pub mod gnss;
pub mod imu;
pub mod metrics;
pub mod rtcm_out;
pub mod serve;
pub mod spline;
pub mod trajectory;

/// The shared reference data directory (`../shared/data` beside the
/// checkout), for tests.
pub fn shared_data_dir() -> std::path::PathBuf {
    let here = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let p = here.join("../../shared/data");
    assert!(p.is_dir(), "the shared reference data is expected at {}", p.display());
    p
}
