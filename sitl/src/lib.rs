//! `cmsckf-sitl`: the simulator that every cmsckf test, evaluation and demo
//! runs on.
//!
//! The sensor models are pure functions of the truth plus a seeded RNG. They
//! return plain measurement types and never call the estimator, so the same
//! data can feed offline evaluation, the mock autopilot and the tests.
//!
//! - [`trajectory`]: smooth ground truth (racetrack, figure8, hover, TUM files)
//! - [`imu`], [`features`], [`gnss`]: truth and noise of each sensor, on the
//!   shared sensor and Earth models of `cmsckf-models`
//! - [`rtcm_out`]: the simulated receiver's RTCM3 (MSM7)
//! - [`render`]: the camera's images of a textured world, with each
//!   pixel's true world point; [`lens`]: the true lens they are seen
//!   through, which differs from its calibration as a real one does
//! - [`euroc`]: a EuRoC/ASL folder's IMU, images and truth, to serve
//! - [`dataset`]: a whole simulated flight, and its CSV export; [`flight`]:
//!   the record of a flight, simulated or loaded; [`rng`]: its seeded streams
//! - [`metrics`]: ATE, rotation RMSE, NEES and χ² bounds
//! - [`serve`]: the mock autopilot and camera front end, with its scoring
#![allow(non_snake_case)] // names carry frames: p_B_in_W, R_W_B, T_B_C
#![allow(clippy::needless_range_loop)] // index loops mirror the equations

pub mod barometer;
pub mod config;
pub mod dataset;
pub mod euroc;
pub mod features;
pub mod flight;
pub mod gnss;
pub mod imu;
pub mod lens;
pub mod metrics;
pub mod render;
pub mod rng;
pub mod rtcm_out;
pub mod serve;
pub mod spline;
pub mod trajectory;
