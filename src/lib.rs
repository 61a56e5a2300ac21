//! cmsckf: a Compressed-MSCKF visual-inertial-GNSS estimator for drone
//! companion computers.
//!
//! Layout:
//! - [`estimator`]: the pure filter (no I/O, no clock); maths in
//!   `src/estimator/README.md`
//! - [`config`]: the configuration, matching `config/default.toml`
//! - [`eval`]: offline evaluation on the simulator (`cmsckf evaluate`)
//!
//! The simulator lives in the `cmsckf-sitl` crate (`sitl/`).
#![allow(non_snake_case)] // names carry frames: p_B_in_W, R_W_B, P_LG
#![allow(clippy::needless_range_loop)] // index loops mirror the equations

pub mod config;
pub mod estimator;
pub mod eval;
