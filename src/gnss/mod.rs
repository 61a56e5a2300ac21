//! Raw GNSS input: reassembly of RTCM3 from MAVLink `GPS_RTCM_DATA`
//! fragments, RTCM3 framing and decoding, broadcast ephemerides and the
//! single-point solution.
//!
//! [`Receiver`] ties them together the way a live stream arrives: messages
//! in order, ephemerides stored as they come, observations grouped into
//! epochs (by time of week and the MSM multiple-message bit) and solved once
//! the epoch is complete.

pub mod reassembly;
pub mod rtcm;
pub mod spp;
pub mod stream;

use std::collections::BTreeMap;

use rtcm::{GnssMessage, MsmEpoch, SatObs, System};
use spp::{EphStore, SppError, SppOptions, SppSolution};

/// GPS − UTC (s), in force since 2017-01-01 (no leap second announced since).
pub const GPS_UTC_LEAP_S: f64 = 18.0;
/// Unix time of the GPS epoch, 1980-01-06 00:00 UTC (s).
pub const GPS_EPOCH_UNIX_S: f64 = 315_964_800.0;

/// Unix time (s) of a GPS week and time of week.
pub fn gps_to_unix_s(week: u32, tow_s: f64) -> f64 {
    GPS_EPOCH_UNIX_S + week as f64 * 604_800.0 + tow_s - GPS_UTC_LEAP_S
}

/// One completed epoch: the rover's observations and its single-point fix.
#[derive(Clone, Debug, PartialEq)]
pub struct Epoch {
    pub week: u32,
    /// Receiver time tag (GPS time of week, s).
    pub tow_s: f64,
    pub sats: Vec<SatObs>,
    pub fix: Result<SppSolution, SppError>,
}

/// Counts kept by the receiver.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReceiverStats {
    pub epochs: u64,
    pub solved: u64,
    pub skipped: BTreeMap<String, u64>,
    pub ephemerides: u64,
    pub other_station: u64,
}

/// A stream-order GNSS receiver model: ephemerides, epochs and solutions.
pub struct Receiver {
    pub opts: SppOptions,
    /// Full GPS week near the data, for the 10-bit weeks.
    pub week_hint: u32,
    /// Accept observations only from this RTCM station (0 = any).
    pub station_id: u16,
    pub ephs: EphStore,
    pending: Option<(u32, Vec<SatObs>)>,
    pub stats: ReceiverStats,
}

impl Receiver {
    pub fn new(opts: SppOptions, week_hint: u32, station_id: u16) -> Self {
        Self {
            opts,
            week_hint,
            station_id,
            ephs: EphStore::default(),
            pending: None,
            stats: ReceiverStats::default(),
        }
    }

    /// Feeds one message; returns the epochs it completed.
    pub fn push(&mut self, m: GnssMessage, out: &mut Vec<Epoch>) {
        match m {
            GnssMessage::GpsEph(raw) => {
                let mut eph = raw.eph;
                eph.week = rtcm::resolve_week(raw.week_mod1024, self.week_hint);
                self.ephs.insert(eph);
                self.stats.ephemerides += 1;
            }
            GnssMessage::Msm(e) => self.push_msm(e, out),
            GnssMessage::Other(_) => {}
        }
    }

    fn push_msm(&mut self, e: MsmEpoch, out: &mut Vec<Epoch>) {
        if self.station_id != 0 && e.station_id != self.station_id {
            self.stats.other_station += 1;
            return;
        }
        if self.pending.as_ref().is_some_and(|(t, _)| *t != e.tow_ms) {
            self.flush(out);
        }
        let entry = self.pending.get_or_insert_with(|| (e.tow_ms, Vec::new()));
        if self.opts.systems.contains(&e.system) && e.system == System::Gps {
            entry.1.extend(e.sats);
        }
        if !e.multiple {
            self.flush(out);
        }
    }

    /// Solves the pending epoch, if any (call at the end of a stream).
    pub fn flush(&mut self, out: &mut Vec<Epoch>) {
        let Some((tow_ms, sats)) = self.pending.take() else {
            return;
        };
        self.stats.epochs += 1;
        let tow_s = tow_ms as f64 * 1e-3;
        // MSMs carry only the time of week: the week is the ephemerides'.
        let week = self.ephs.week_for_tow(tow_s).unwrap_or(self.week_hint);
        let fix = spp::solve(&sats, week, tow_s, &self.ephs, &self.opts);
        match &fix {
            Ok(_) => self.stats.solved += 1,
            Err(error) => *self.stats.skipped.entry(error.to_string()).or_default() += 1,
        }
        out.push(Epoch { week, tow_s, sats, fix });
    }
}

/// Satellite states and L1 measurements for the filter (§8): each satellite
/// with an ephemeris, its state at transmission time, and its clock for L1
/// C/A (with TGD).
pub fn sat_measurements(
    ephs: &EphStore,
    week: u32,
    tow_s: f64,
    obs: impl IntoIterator<Item = (u8, Option<f64>, Option<f64>)>,
) -> Vec<crate::estimator::gnss_update::SatMeas> {
    let c = cmsckf_sitl::geodesy::C_MPS;
    obs.into_iter()
        .filter_map(|(prn, pr, prr)| {
            let eph = ephs.select(prn, week, tow_s)?;
            let st = spp::state_at_transmission(eph, tow_s, pr.unwrap_or(0.075 * c));
            Some(crate::estimator::gnss_update::SatMeas {
                prn,
                r_sat_ecef_m: st.r_ecef_m,
                v_sat_ecef_mps: st.v_ecef_mps,
                dts_m: st.dt_s * c,
                ddts_mps: st.ddt * c,
                pseudorange_m: pr,
                range_rate_mps: prr,
            })
        })
        .collect()
}

/// Parses a `--systems` list such as `G,E`.
pub fn parse_systems(s: &str) -> Result<Vec<System>, String> {
    s.split(',')
        .map(str::trim)
        .filter(|x| !x.is_empty())
        .map(|x| match x {
            "G" => Ok(System::Gps),
            "E" => Ok(System::Galileo),
            "R" | "C" | "J" => Err(format!("system '{x}' is not supported yet (G and E are)")),
            _ => Err(format!("unknown system '{x}': use G, E, R, C or J")),
        })
        .collect()
}

/// The current GPS week from the system clock (leap seconds do not matter
/// at week resolution).
pub fn gps_week_now() -> u32 {
    let unix = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0);
    // GPS epoch: 1980-01-06 = unix 315964800.
    ((unix - 315_964_800.0) / 604_800.0).max(0.0) as u32
}
