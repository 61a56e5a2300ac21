//! GNSS models: time systems, constellations, broadcast orbits and clocks,
//! the atmosphere, and the mapping between broadcast ephemerides and their
//! RTCM messages.
//!
//! The simulator generates its truth with these, and the receiver decodes and
//! solves with them, so the truth's model and the filter's are one model.

pub mod atmosphere;
pub mod ephemeris;
pub mod glonass;
pub mod rtcm_eph;

pub use atmosphere::{niell_hydrostatic_mapping, saastamoinen_m, saastamoinen_zenith_hydrostatic_m, Klobuchar};
pub use ephemeris::{bdt_to_gps, tk, BroadcastEphemeris, SatState, REL_F};
pub use glonass::{glonass_tb_to_gps, GlonassEphemeris};

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

/// Days from 1970-01-01 to a civil date (Hinnant's `days_from_civil`).
fn days_from_civil(y: i64, m: i64, d: i64) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let doy = (153 * (m + if m > 2 { -3 } else { 9 }) + 2) / 5 + d - 1;
    era * 146_097 + yoe * 365 + yoe / 4 - yoe / 100 + doy - 719_468
}

/// GPS − UTC (s) at GPS time `week`/`tow_s`: the leap seconds inserted since
/// 1980 (IERS Bulletin C). Old data need the count of their day (16 s in
/// 2012), live data the current [`GPS_UTC_LEAP_S`].
pub fn gps_utc_leap_s(week: u32, tow_s: f64) -> f64 {
    // (UTC date from which it holds, GPS − UTC).
    const LEAPS: [(i64, i64, i64, f64); 18] = [
        (1981, 7, 1, 1.0),
        (1982, 7, 1, 2.0),
        (1983, 7, 1, 3.0),
        (1985, 7, 1, 4.0),
        (1988, 1, 1, 5.0),
        (1990, 1, 1, 6.0),
        (1991, 1, 1, 7.0),
        (1992, 7, 1, 8.0),
        (1993, 7, 1, 9.0),
        (1994, 7, 1, 10.0),
        (1996, 1, 1, 11.0),
        (1997, 7, 1, 12.0),
        (1999, 1, 1, 13.0),
        (2006, 1, 1, 14.0),
        (2009, 1, 1, 15.0),
        (2012, 7, 1, 16.0),
        (2015, 7, 1, 17.0),
        (2017, 1, 1, 18.0),
    ];
    let t = week as f64 * WEEK_S + tow_s;
    let gps_epoch_days = days_from_civil(1980, 1, 6);
    LEAPS
        .iter()
        .rev()
        .find(|(y, m, d, leap)| t >= (days_from_civil(*y, *m, *d) - gps_epoch_days) as f64 * 86_400.0 + leap)
        .map_or(0.0, |l| l.3)
}

/// Day of year of a GPS time (1.0 = 1 January 00:00 GPST), as the
/// troposphere's seasonal terms want it: the civil year is found from the
/// days since 1970 (Hinnant's `civil_from_days`).
pub fn gps_day_of_year(week: u32, tow_s: f64) -> f64 {
    // Days from 1970-01-01 to 1980-01-06: 3657.
    let t_days = week as f64 * 7.0 + tow_s / 86_400.0 + 3657.0;
    let z = t_days.floor() as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy_mar = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy_mar + 2) / 153;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    // Days from 1970-01-01 to 1 January of `year` (days_from_civil).
    let y = year - 1;
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let jan1 = era * 146_097 + yoe * 365 + yoe / 4 - yoe / 100 + 306 - 719_468;
    t_days - jan1 as f64 + 1.0
}

/// Constellations.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub enum System {
    #[default]
    Gps,
    Galileo,
    /// GLONASS: FDMA, its own orbit model (a PZ-90 state vector) and time.
    Glonass,
    /// BeiDou: BDT (GPS time − 14 s), Kepler orbits, GEO satellites.
    BeiDou,
    /// QZSS: GPS time and GPS's Kepler model.
    Qzss,
}

impl System {
    /// The RINEX letter.
    pub fn letter(self) -> char {
        match self {
            System::Gps => 'G',
            System::Galileo => 'E',
            System::Glonass => 'R',
            System::BeiDou => 'C',
            System::Qzss => 'J',
        }
    }

    /// The gravitational constant the constellation's ephemerides use (m³/s²).
    pub fn gm_m3ps2(self) -> f64 {
        match self {
            System::Gps | System::Qzss => MU_GPS_M3PS2,
            // BeiDou's CGCS2000 value equals Galileo's; GLONASS's PZ-90 one
            // (3.9860044e14) is used by its own orbit model, not here.
            System::Galileo | System::BeiDou => MU_GAL_M3PS2,
            System::Glonass => 3.986_004_4e14,
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
    /// `Some` when the code is differential: the rover's less a base
    /// station's correction, so satellite orbit, clock and atmosphere errors
    /// are gone and its clock offset differs from a raw code's by a few
    /// metres. How the correction was taken sets its variance.
    pub correction: Option<CodeCorrection>,
}

impl SatMeas {
    /// Whether the code is differential.
    pub fn differential(&self) -> bool {
        self.correction.is_some()
    }
}

/// How a differential code's base correction was taken: what its error
/// depends on (estimator README §8c, eqs. DG2′, DG7, DG8).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CodeCorrection {
    /// The base station, and its epoch's time of week (s): the codes it
    /// corrects share its errors.
    pub base_station_id: u16,
    pub base_tow_s: f64,
    /// The rover epoch's time less the base epoch's (s): the correction is
    /// held, never extrapolated, and its error grows with this.
    pub age_s: f64,
    /// Rover epochs that share this base epoch's correction (≥ 1): those
    /// corrected by it so far, or the base's period over the rover's,
    /// whichever is more.
    pub shared_by: f64,
    /// How far the corrections' common part of this satellite's
    /// constellation (its median, DG1′) moved at this base epoch, on the
    /// satellites it shares with the previous one (m, signed): a satellite
    /// set change, or the base's noise. Every corrected code of the
    /// constellation moves by its negative.
    pub reference_step_m: f64,
}

#[cfg(test)]
mod tests {
    /// Day of year in GPST: 2005-04-02 00:00 (GPS week 1316, day 6) is day
    /// 92; 1 January 00:00 is 1.0; a leap year's 31 December noon is 366.5.
    /// GPS − UTC: 13 s before 2006, 16 s through 2012-10 (GMSD7), 18 s now.
    #[test]
    fn leap_seconds() {
        assert_eq!(super::gps_utc_leap_s(1316, 518_400.0), 13.0); // 2005-04-02
        assert_eq!(super::gps_utc_leap_s(1709, 604_790.0), 16.0);
        assert_eq!(super::gps_utc_leap_s(2443, 0.0), 18.0);
        // 2017-01-01 00:00:18 GPST is the first instant of 18 s.
        let w = 1930;
        let tow_new_year = 0.0 * 86_400.0; // 2017-01-01 is a Sunday: GPS week 1930 starts then
        assert_eq!(super::gps_utc_leap_s(w, tow_new_year + 17.0), 17.0);
        assert_eq!(super::gps_utc_leap_s(w, tow_new_year + 18.0), 18.0);
    }

    #[test]
    fn day_of_year() {
        assert!((super::gps_day_of_year(1316, 6.0 * 86_400.0) - 92.0).abs() < 1e-9);
        // 2024-01-01 00:00 GPST is GPS week 2295, day 1 (Monday).
        assert!((super::gps_day_of_year(2295, 86_400.0) - 1.0).abs() < 1e-9);
        // 2024-12-31 12:00 GPST: week 2347, day 2 (Tuesday).
        assert!((super::gps_day_of_year(2347, 2.5 * 86_400.0) - 366.5).abs() < 1e-9);
    }
}
