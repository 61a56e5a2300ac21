//! Raw GNSS input: reassembly of RTCM3 from MAVLink `GPS_RTCM_DATA`
//! fragments, RTCM3 framing and decoding, broadcast ephemerides and the
//! single-point solution.
//!
//! [`Receiver`] ties them together the way a live stream arrives: messages
//! in order, ephemerides stored as they come, observations grouped into
//! epochs (by time of week and the MSM multiple-message bit) and solved once
//! the epoch is complete.
//!
//! Like the estimator it does no I/O and keeps no clock (but for
//! [`gps_week_now`], the week hint's fallback): bytes come in from
//! `io::mavlink` or `io::gnss_stream`, and it stands on `cmsckf-models` alone.

pub mod dgnss;
pub mod inav;
pub mod lnav;
pub mod reassembly;
pub mod rtcm;
pub mod spp;
pub mod ubx;

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use cmsckf_models::gnss::Klobuchar;

use dgnss::{BaseStation, DgnssError};
use rtcm::{GnssMessage, MsmEpoch, SatObs, System};
use spp::{EphStore, SppError, SppOptions, SppSolution};

/// Ionosphere handling (`gnss.iono`).
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum IonoMode {
    Off,
    Klobuchar,
    IonoFree,
    Auto,
}

impl std::str::FromStr for IonoMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "off" => Ok(IonoMode::Off),
            "klobuchar" => Ok(IonoMode::Klobuchar),
            "iono-free" => Ok(IonoMode::IonoFree),
            "auto" => Ok(IonoMode::Auto),
            _ => Err(format!(
                "unknown ionosphere mode '{s}': use off, klobuchar, iono-free or auto"
            )),
        }
    }
}

/// A receiver's byte stream in whichever format it speaks, recognised from
/// the bytes: RTCM3 and UBX frames are both looked for in every byte (a
/// u-blox F9 can send both on one port, with NMEA between them), each by
/// its own checksum, so neither can take the other's frames.
#[derive(Default)]
pub struct StreamDecoder {
    pub rtcm: rtcm::RtcmDecoder,
    pub ubx: ubx::UbxDecoder,
}

impl StreamDecoder {
    /// Feeds bytes; returns the messages completed by them, each decoder's
    /// in the order of its frames (feed small pieces, as a port delivers
    /// them, to keep the two formats' frames in stream order too).
    pub fn push(&mut self, bytes: &[u8], out: &mut Vec<GnssMessage>) {
        self.rtcm.push(bytes, out);
        self.ubx.push(bytes, out);
    }

    /// Whether the RTCM3 decoder's counts mean anything: it has found
    /// frames, or nothing has (in a UBX-only stream its CRC failures and
    /// skipped bytes are just UBX and NMEA bytes).
    pub fn rtcm_in_use(&self) -> bool {
        !self.rtcm.stats.frames_by_type.is_empty() || self.ubx.stats.frames_by_id.is_empty()
    }

    /// The formats seen so far, by their good frames.
    pub fn formats(&self) -> &'static str {
        let rtcm = !self.rtcm.stats.frames_by_type.is_empty();
        let ubx = !self.ubx.stats.frames_by_id.is_empty();
        match (rtcm, ubx) {
            (true, true) => "RTCM3 and UBX",
            (true, false) => "RTCM3",
            (false, true) => "UBX",
            (false, false) => "none recognised",
        }
    }
}

/// GLONASS ephemerides held until the receiver knows the time.
const MAX_PENDING_GLONASS: usize = 32;

/// The time of week with the same time of day as `tow_s` nearest to
/// `near_s` (a GLONASS MSM without its day of week).
fn nearest_same_time_of_day(tow_s: f64, near_s: f64) -> f64 {
    let tod = tow_s.rem_euclid(86_400.0);
    let day = (near_s / 86_400.0).floor();
    [day - 1.0, day, day + 1.0]
        .into_iter()
        .map(|d| d * 86_400.0 + tod)
        .min_by(|a, b| (a - near_s).abs().total_cmp(&(b - near_s).abs()))
        .unwrap_or(tod)
        .rem_euclid(604_800.0)
}

/// One completed epoch: the rover's observations and its single-point fix.
#[derive(Clone, Debug, PartialEq)]
pub struct Epoch {
    pub week: u32,
    /// Receiver time tag (GPS time of week, s).
    pub tow_s: f64,
    pub sats: Vec<SatObs>,
    pub fix: Result<SppSolution, SppError>,
    /// The differential solution against the base station, when a base
    /// stream is attached ([`Receiver::push_base`]).
    pub dgnss: Option<Result<SppSolution, DgnssError>>,
}

/// Groups MSMs into epochs: by time of week, closed by the next epoch's
/// time or by an MSM without the multiple-message bit.
#[derive(Default)]
pub struct EpochAssembler {
    /// Station id, time of week (s) and satellites of the open epoch.
    pending: Option<(u16, f64, Vec<SatObs>)>,
}

impl EpochAssembler {
    /// Feeds one MSM, keeping its satellites if its constellation is one of
    /// `systems` (returns whether it was); calls `done` with each epoch it
    /// completes.
    pub fn push(&mut self, e: MsmEpoch, systems: &[System], mut done: impl FnMut(u16, f64, Vec<SatObs>)) -> bool {
        let selected = systems.contains(&e.system);
        // An unselected constellation's MSM may close the open epoch (same
        // time, last message) but never splits one: its time may be
        // mislabelled (GMSD7's BeiDou carries GPS time where BDT belongs).
        if !selected && self.pending.as_ref().is_some_and(|(_, t, _)| *t != e.tow_s) {
            return false;
        }
        if self.pending.as_ref().is_some_and(|(_, t, _)| *t != e.tow_s) {
            if let Some(p) = self.pending.take() {
                done(p.0, p.1, p.2);
            }
        }
        let entry = self.pending.get_or_insert_with(|| (e.station_id, e.tow_s, Vec::new()));
        if selected {
            entry.2.extend(e.sats);
        }
        if !e.multiple {
            if let Some(p) = self.pending.take() {
                done(p.0, p.1, p.2);
            }
        }
        selected
    }

    /// The open epoch, if any (at the end of a stream).
    pub fn take(&mut self) -> Option<(u16, f64, Vec<SatObs>)> {
        self.pending.take()
    }
}

/// Counts kept by the receiver.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReceiverStats {
    pub epochs: u64,
    pub solved: u64,
    pub skipped: BTreeMap<String, u64>,
    pub ephemerides: u64,
    pub other_station: u64,
    /// MSMs of constellations not selected, by system letter.
    pub skipped_system: BTreeMap<char, u64>,
    /// GLONASS ephemerides dropped while waiting for a time, and GLONASS
    /// MSMs without a day of week before any epoch gave one.
    pub glonass_ephemerides_dropped: u64,
    pub glonass_day_unknown: u64,
    /// Differential solutions, and epochs without one by reason.
    pub dgnss_solved: u64,
    pub dgnss_skipped: BTreeMap<String, u64>,
}

/// A stream-order GNSS receiver model: ephemerides, epochs and solutions.
pub struct Receiver {
    pub opts: SppOptions,
    /// Full GPS week near the data, for the 10-bit weeks.
    pub week_hint: u32,
    /// Accept observations only from this RTCM station (0 = any).
    pub station_id: u16,
    pub ephs: EphStore,
    assembler: EpochAssembler,
    /// The GPS week and time of week of the last epoch.
    last_time: Option<(u32, f64)>,
    /// GLONASS ephemerides waiting for the first epoch's time.
    pending_glonass: Vec<rtcm::Msg1020>,
    /// The base station, when a base stream is attached.
    pub base: Option<BaseStation>,
    /// Oldest base epoch (s) a differential solution may use.
    pub dgnss_max_age_s: f64,
    pub stats: ReceiverStats,
}

impl Receiver {
    pub fn new(opts: SppOptions, week_hint: u32, station_id: u16) -> Self {
        Self {
            opts,
            week_hint,
            station_id,
            ephs: EphStore::default(),
            assembler: EpochAssembler::default(),
            last_time: None,
            pending_glonass: Vec::new(),
            base: None,
            dgnss_max_age_s: 10.0,
            stats: ReceiverStats::default(),
        }
    }

    /// Feeds one message; returns the epochs it completed.
    pub fn push(&mut self, m: GnssMessage, out: &mut Vec<Epoch>) {
        match m {
            GnssMessage::Eph(raw) => {
                let week = raw.full_week(self.week_hint);
                let mut eph = raw.eph;
                eph.week = week;
                self.ephs.insert(eph);
                self.stats.ephemerides += 1;
            }
            GnssMessage::GlonassEph(m) => {
                self.pending_glonass.push(*m);
                if self.pending_glonass.len() > MAX_PENDING_GLONASS {
                    self.pending_glonass.remove(0);
                    self.stats.glonass_ephemerides_dropped += 1;
                }
                self.place_glonass();
            }
            GnssMessage::Msm(mut e) => {
                if self.place_in_gps_time(&mut e) {
                    self.push_msm(e, out)
                }
            }
            GnssMessage::Station { .. } | GnssMessage::Other(_) => {}
        }
    }

    /// Puts a GLONASS MSM's UTC time on the GPS scale: GPS − UTC of the day,
    /// and the day itself from the last epoch when the message lacks it.
    /// `false`: it cannot be placed yet (counted).
    fn place_in_gps_time(&mut self, e: &mut MsmEpoch) -> bool {
        if !e.utc {
            return true;
        }
        let near = self.last_time.unwrap_or((self.week_hint, e.tow_s));
        if e.day_unknown {
            if self.last_time.is_none() {
                self.stats.glonass_day_unknown += 1;
                return false;
            }
            e.tow_s = nearest_same_time_of_day(e.tow_s, near.1);
        }
        let week = self.ephs.week_for_tow(e.tow_s).unwrap_or(near.0);
        e.tow_s = (e.tow_s + cmsckf_models::gnss::gps_utc_leap_s(week, e.tow_s)).rem_euclid(604_800.0);
        e.utc = false;
        true
    }

    /// GLONASS ephemerides carry their time as a time of the Moscow day:
    /// they are placed (and stored) once the receiver knows the GPS time.
    fn place_glonass(&mut self) {
        let Some((week, tow)) = self.last_time else { return };
        for m in self.pending_glonass.drain(..) {
            let eph = cmsckf_models::gnss::rtcm_eph::glonass_from_1020(&m, week, tow);
            self.ephs.insert_glonass(eph);
            self.stats.ephemerides += 1;
        }
    }

    /// Feeds one message of the base station's stream: its ephemerides
    /// join the rover's, its antenna position and epochs make the base
    /// (attached at the first call).
    pub fn push_base(&mut self, m: GnssMessage) {
        if matches!(m, GnssMessage::Eph(_) | GnssMessage::GlonassEph(_)) {
            return self.push(m, &mut Vec::new());
        }
        let base = self.base.get_or_insert_with(BaseStation::default);
        match m {
            GnssMessage::Eph(_) | GnssMessage::GlonassEph(_) | GnssMessage::Other(_) => {}
            GnssMessage::Station { station_id, arp_ecef_m } => base.set_position(station_id, arp_ecef_m),
            GnssMessage::Msm(mut e) => {
                if !self.place_in_gps_time(&mut e) {
                    return;
                }
                let (ephs, hint) = (&self.ephs, self.week_hint);
                let base = self.base.get_or_insert_with(BaseStation::default);
                base.push_msm(e, &self.opts.systems, |tow| ephs.week_for_tow(tow).unwrap_or(hint));
            }
        }
    }

    fn push_msm(&mut self, e: MsmEpoch, out: &mut Vec<Epoch>) {
        if self.station_id != 0 && e.station_id != self.station_id {
            self.stats.other_station += 1;
            return;
        }
        let (system, mut done) = (e.system, Vec::new());
        if !self
            .assembler
            .push(e, &self.opts.systems, |_, tow_s, sats| done.push((tow_s, sats)))
        {
            *self.stats.skipped_system.entry(system.letter()).or_default() += 1;
        }
        for (tow_s, sats) in done {
            self.solve(tow_s, sats, out);
        }
    }

    /// Solves the pending epoch, if any (call at the end of a stream).
    pub fn flush(&mut self, out: &mut Vec<Epoch>) {
        if let Some(base) = &mut self.base {
            let (ephs, hint) = (&self.ephs, self.week_hint);
            base.flush(|tow| ephs.week_for_tow(tow).unwrap_or(hint));
        }
        if let Some((_, tow_s, sats)) = self.assembler.take() {
            self.solve(tow_s, sats, out);
        }
    }

    /// The single-point and, with a base, the differential solution of one
    /// completed epoch.
    fn solve(&mut self, tow_s: f64, sats: Vec<SatObs>, out: &mut Vec<Epoch>) {
        self.stats.epochs += 1;
        // MSMs carry only the time of week: the week is the ephemerides'.
        let week = self.ephs.week_for_tow(tow_s).unwrap_or(self.week_hint);
        self.last_time = Some((week, tow_s));
        self.place_glonass();
        let fix = spp::solve(&sats, week, tow_s, &self.ephs, &self.opts);
        match &fix {
            Ok(_) => self.stats.solved += 1,
            Err(error) => *self.stats.skipped.entry(error.to_string()).or_default() += 1,
        }
        let dgnss = self.base.as_ref().map(|b| {
            let r = dgnss::solve(&sats, week, tow_s, b, &self.ephs, &self.opts, self.dgnss_max_age_s);
            match &r {
                Ok(_) => self.stats.dgnss_solved += 1,
                Err(error) => *self.stats.dgnss_skipped.entry(error.to_string()).or_default() += 1,
            }
            r
        });
        out.push(Epoch {
            week,
            tow_s,
            sats,
            fix,
            dgnss,
        });
    }
}

/// One satellite's code and Doppler as they reach [`sat_measurements`] and
/// the single-point solver.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RawSat {
    pub system: System,
    pub prn: u8,
    /// The first-frequency code: GPS L1 C/A, Galileo E1 (m).
    pub l1_pseudorange_m: Option<f64>,
    /// A second-frequency code and its carrier frequency `(m, Hz)`: GPS L2
    /// or L5, Galileo E5a or E5b.
    pub l2_pseudorange: Option<(f64, f64)>,
    pub l1_range_rate_mps: Option<f64>,
}

/// Carrier frequencies (Hz) by RINEX band.
const F_L2_HZ: f64 = 1_227.60e6;
const F_L5_HZ: f64 = 1_176.45e6;
const F_E5B_HZ: f64 = 1_207.14e6;

impl RawSat {
    /// Picks the signals the solver uses: on L1/E1 the C/A or pilot code
    /// (attributes C, then X, then B), and the first second-frequency code in
    /// the message's signal order.
    pub fn from_obs(s: &SatObs) -> Self {
        // The first frequency: L1/E1/G1 (C/A, pilot or data code), and for
        // BeiDou B1I (RINEX band 2, the signal its TGD1 is for).
        let (band, attributes): (u8, &[char]) = match s.system {
            System::BeiDou => (2, &['I', 'X']),
            System::Glonass => (1, &['C', 'P']),
            System::Gps | System::Galileo | System::Qzss => (1, &['C', 'X', 'B']),
        };
        let l1 = attributes
            .iter()
            .find_map(|a| {
                s.signals
                    .iter()
                    .find(|g| g.band == band && g.attribute == *a && g.pseudorange_m.is_some())
            })
            .or_else(|| {
                s.signals
                    .iter()
                    .find(|g| g.band == band && g.attribute == attributes[0])
            });
        let second = |band: u8| match (s.system, band) {
            (System::Gps, 2) => Some(F_L2_HZ),
            (System::Gps | System::Galileo, 5) => Some(F_L5_HZ),
            (System::Galileo, 7) => Some(F_E5B_HZ),
            _ => None,
        };
        Self {
            system: s.system,
            prn: s.prn,
            l1_pseudorange_m: l1.and_then(|g| g.pseudorange_m),
            l2_pseudorange: s.signals.iter().find_map(|g| Some((g.pseudorange_m?, second(g.band)?))),
            l1_range_rate_mps: l1.and_then(|g| g.range_rate_mps),
        }
    }

    /// The code measurement under `iono`: `(pseudorange m, iono-free?)`.
    /// The ionosphere-free combination where a second code exists and the
    /// mode wants it (`iono-free`, `auto`); otherwise L1/E1 unless the mode
    /// is `iono-free`.
    pub fn code(&self, iono: IonoMode) -> Option<(f64, bool)> {
        let want_if = matches!(iono, IonoMode::IonoFree | IonoMode::Auto);
        match (self.l1_pseudorange_m, self.l2_pseudorange) {
            (Some(p1), Some((p2, f2))) if want_if => Some((spp::iono_free(p1, p2, f2), true)),
            (Some(p1), _) if iono != IonoMode::IonoFree => Some((p1, false)),
            _ => None,
        }
    }
}

/// How [`sat_measurements`] treats the ionosphere.
#[derive(Clone, Copy, Debug)]
pub struct IonoPolicy<'a> {
    pub mode: IonoMode,
    /// Broadcast parameters, if known (RTCM carries none: from the config).
    pub klobuchar: Option<&'a Klobuchar>,
    /// An approximate receiver position (ECEF, m) for the Klobuchar geometry.
    pub rx_ecef_m: Option<nalgebra::Vector3<f64>>,
}

/// Satellite states and measurements for the filter (§8), with the
/// ionosphere handled per the policy: the L1/L2 ionosphere-free combination
/// where both codes exist (`iono-free`, `auto`); else L1 C/A corrected by
/// Klobuchar when its parameters and a receiver position are known
/// (`klobuchar`, `auto`; residual variance (0.5·I)²); else, without a model
/// (`auto`, `klobuchar`), L1 with its variance inflated by (5 m)², as RTKLIB
/// does; `off` ignores the ionosphere.
pub fn sat_measurements(
    ephs: &EphStore,
    week: u32,
    tow_s: f64,
    policy: IonoPolicy<'_>,
    sats: impl IntoIterator<Item = RawSat>,
) -> Vec<cmsckf_models::gnss::SatMeas> {
    let iono = policy.mode;
    let c = cmsckf_models::geodesy::C_MPS;
    sats.into_iter()
        .filter_map(|s| {
            let orbit = ephs.orbit(s.system, s.prn, week, tow_s)?;
            let (pr, is_if) = match s.code(iono) {
                Some((p, is_if)) => (Some(p), is_if),
                None => (None, false),
            };
            let st = spp::state_at_transmission(orbit, week, tow_s, pr.unwrap_or(0.075 * c));
            // The iono-free combination sees the clock without TGD (§8).
            let dts = if is_if { st.dt_s + orbit.tgd_s() } else { st.dt_s };
            let klob = match (policy.klobuchar, policy.rx_ecef_m) {
                (Some(k), Some(r)) if !is_if && iono != IonoMode::Off => {
                    let (lat, lon, _) = cmsckf_models::geodesy::ecef_to_llh(&r);
                    let (el, az) = cmsckf_models::geodesy::elevation_azimuth(&r, &st.r_ecef_m);
                    Some(k.delay_m(lat, lon, az, el, tow_s))
                }
                _ => None,
            };
            let (noise_scale, extra_var_m2) = match (is_if, iono, klob) {
                (true, _, _) => (3.0, 0.0),
                (false, IonoMode::Off, _) => (1.0, 0.0),
                (false, _, Some(i)) => (1.0, (0.5 * i).powi(2)),
                (false, _, None) => (1.0, 25.0),
            };
            let pr = pr.map(|p| p - klob.unwrap_or(0.0));
            let noise_scale = noise_scale * spp::code_sigma_factor(s.system);
            Some(cmsckf_models::gnss::SatMeas {
                system: s.system,
                prn: s.prn,
                r_sat_ecef_m: st.r_ecef_m,
                v_sat_ecef_mps: st.v_ecef_mps,
                dts_m: dts * c,
                ddts_mps: st.ddt * c,
                pseudorange_m: pr,
                range_rate_mps: s.l1_range_rate_mps,
                noise_scale,
                extra_var_m2,
                differential: false,
            })
        })
        .collect()
}

/// Parses a `--systems` list such as `G,E,R,C,J`: GPS, Galileo, GLONASS,
/// BeiDou, QZSS.
pub fn parse_systems(s: &str) -> Result<Vec<System>, String> {
    let v = s
        .split(',')
        .map(str::trim)
        .filter(|x| !x.is_empty())
        .map(|x| match x {
            "G" => Ok(System::Gps),
            "E" => Ok(System::Galileo),
            "R" => Ok(System::Glonass),
            "C" => Ok(System::BeiDou),
            "J" => Ok(System::Qzss),
            _ => Err(format!(
                "unknown system '{x}': use G (GPS), E (Galileo), R (GLONASS), C (BeiDou), J (QZSS), e.g. G,E,R"
            )),
        })
        .collect::<Result<Vec<_>, _>>()?;
    if v.is_empty() {
        return Err("no system given: use G, E, R, C or J, e.g. G,E".into());
    }
    Ok(v)
}

/// The receiver clock a constellation's codes share: QZSS keeps GPS time,
/// the others have their own (an inter-system bias from GPS's).
pub fn clock_group(s: System) -> System {
    match s {
        System::Qzss => System::Gps,
        other => other,
    }
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

#[cfg(test)]
mod tests;
