//! GNSS models: time systems, constellations, broadcast orbits and clocks,
//! the atmosphere, and the mapping between broadcast ephemerides and their
//! RTCM messages.
//!
//! The simulator generates its truth with these, and the receiver decodes and
//! solves with them, so the truth's model and the filter's are one model.

pub mod atmosphere;
pub mod ephemeris;
pub mod rtcm_eph;

pub use atmosphere::{saastamoinen_m, Klobuchar};
pub use ephemeris::{tk, BroadcastEphemeris, SatState, REL_F};

use nalgebra::Vector3;

use crate::geodesy::{MU_GAL_M3PS2, MU_GPS_M3PS2};

/// Seconds in a GPS week.
pub const WEEK_S: f64 = 604_800.0;
/// GPS − UTC (s), in force since 2017-01-01 (no leap second announced since).
pub const GPS_UTC_LEAP_S: f64 = 18.0;
/// Unix time of the GPS epoch, 1980-01-06 00:00:00 UTC (s).
pub const GPS_EPOCH_UNIX_S: f64 = 315_964_800.0;

/// GPS week and time of week → Unix time (s), through the leap seconds.
pub fn gps_to_unix_s(week: u32, tow_s: f64) -> f64 {
    GPS_EPOCH_UNIX_S + week as f64 * WEEK_S + tow_s - GPS_UTC_LEAP_S
}

/// Constellations.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub enum System {
    #[default]
    Gps,
    Galileo,
}

impl System {
    /// The RINEX letter.
    pub fn letter(self) -> char {
        match self {
            System::Gps => 'G',
            System::Galileo => 'E',
        }
    }

    /// The gravitational constant the constellation's ephemerides use (m³/s²).
    pub fn gm_m3ps2(self) -> f64 {
        match self {
            System::Gps => MU_GPS_M3PS2,
            System::Galileo => MU_GAL_M3PS2,
        }
    }
}

/// One satellite's measurements with its state at transmission time: what
/// the receiver hands the filter's GNSS update.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SatMeas {
    pub system: System,
    pub prn: u8,
    pub r_sat_ecef_m: Vector3<f64>,
    pub v_sat_ecef_mps: Vector3<f64>,
    /// Satellite clock offset × c for the code used (m), and its rate (m/s).
    pub dts_m: f64,
    pub ddts_mps: f64,
    pub pseudorange_m: Option<f64>,
    pub range_rate_mps: Option<f64>,
    /// Pseudorange noise multiplier (3 for the ionosphere-free combination).
    pub noise_scale: f64,
    /// Added pseudorange variance (m²): an unmodelled ionosphere.
    pub extra_var_m2: f64,
}
