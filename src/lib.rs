//! cmsckf: a Compressed-MSCKF visual-inertial-GNSS estimator for drone
//! companion computers.
//!
//! Layout:
//! - [`estimator`]: the pure filter (no I/O, no clock); maths in
//!   `src/estimator/README.md`
//! - [`config`]: the configuration, matching `config/default.toml`
//! - [`eval`]: offline evaluation on the simulator (`cmsckf evaluate`)
//! - [`counters`]: every counted reason, as a type
//! - [`daemon`]: the tasks of `cmsckf run`; [`io`]: the MAVLink link and the
//!   feature socket; [`gnss`]: RTCM3 input; [`status`]: the state the
//!   autopilot sees in `HEARTBEAT`
//!
//! The simulator lives in the `cmsckf-sitl` crate (`sitl/`).
#![allow(non_snake_case)] // names carry frames: p_B_in_W, R_W_B, P_LG
#![allow(clippy::needless_range_loop)] // index loops mirror the equations

pub mod config;
pub mod counters;
pub mod daemon;
pub mod estimator;
#[cfg(feature = "sim")]
pub mod eval;
pub mod gnss;
pub mod io;
pub mod replay;
pub mod review;
pub mod status;
