//! `cmsckf-models`: the sensor and Earth models at the bottom of cmsckf.
//!
//! Both the estimator and the simulator stand on this crate, so the truth
//! and the filter use one camera, one geodesy and one set of GNSS models, and
//! a reader can tell them apart from what is the simulator's alone (truth and
//! noise, in `cmsckf-sitl`) and what is the filter's alone (in `cmsckf`).
//! Nothing here does I/O, keeps a clock or draws random numbers.
//!
//! - [`atmosphere`]: the standard atmosphere's pressure and height
//! - [`check`]: configuration checks that name the field and the fix
//! - [`sensors`]: the IMU's and the camera's descriptions (units in the names)
//! - [`camera`]: pinhole projection with radial-tangential or equidistant
//!   distortion, and its inverse
//! - [`geodesy`]: WGS-84, ECEF ↔ geodetic, the local NED frame
//! - [`gnss`]: GPS time, constellations, broadcast orbits and clocks, the
//!   troposphere and ionosphere, ephemerides on the RTCM wire
//! - [`image_wire`]: raw grey images on a byte stream, camera to front-end
//! - [`feature_wire`]: one tracked feature as the socket and the log carry it
//! - [`magnetic`]: heading from a magnetometer and the WMM declination
//! - [`stats`]: normal and χ² quantiles for gates and consistency bounds
#![allow(non_snake_case)] // names carry frames: p_B_in_W, R_W_B, T_B_C

pub mod atmosphere;
pub mod camera;
pub mod check;
pub mod feature_wire;
pub mod geodesy;
pub mod geoid;
pub mod gnss;
pub mod image_wire;
pub mod magnetic;
pub mod sensors;
pub mod stats;
