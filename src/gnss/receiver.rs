//! The stream-order receiver model: why it exists is that a live stream
//! interleaves ephemerides and observations, so ephemerides are stored as
//! they come, observations grouped into epochs, and each epoch solved
//! (single-point, and differential with a base) once it is complete.

use std::collections::BTreeMap;

use super::dgnss::{self, BaseStation, DgnssError};
use super::ephemeris_store::EphStore;
use super::epoch_assembly::EpochAssembler;
use super::rtcm::{self, GnssMessage, MsmEpoch, SatObs};
use super::spp::{self, SppError, SppOptions, SppSolution};

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
    /// Times a Galileo ephemeris's full week overruled the week hint.
    pub week_from_galileo: u64,
    /// Ephemerides from another station's stream left out: the rover's own
    /// stream gives that satellite's.
    pub ephemerides_from_others_ignored: u64,
}

/// A stream-order GNSS receiver model: ephemerides, epochs and solutions.
pub struct Receiver {
    pub opts: SppOptions,
    /// Full GPS week near the data, for the 10-bit weeks.
    pub week_hint: u32,
    /// The week hint comes from a clock that knows the date (the
    /// autopilot's GNSS time): an ephemeris does not overrule it.
    pub week_from_clock: bool,
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
    /// What a base must satisfy for a differential solution.
    pub base_limits: dgnss::BaseLimits,
    pub stats: ReceiverStats,
}

impl Receiver {
    pub fn new(opts: SppOptions, week_hint: u32, station_id: u16) -> Self {
        Self {
            opts,
            week_hint,
            week_from_clock: false,
            station_id,
            ephs: EphStore::default(),
            assembler: EpochAssembler::default(),
            last_time: None,
            pending_glonass: Vec::new(),
            base: None,
            base_limits: dgnss::BaseLimits::default(),
            stats: ReceiverStats::default(),
        }
    }

    /// Feeds one message; returns the epochs it completed.
    pub fn push(&mut self, m: GnssMessage, out: &mut Vec<Epoch>) {
        match m {
            GnssMessage::Eph(raw) => {
                // Galileo's 12-bit week is unambiguous for 78 years: it
                // settles a hint that is 1024 weeks off.
                if raw.eph.system == rtcm::System::Galileo && !self.week_from_clock {
                    let week = raw.full_week(self.week_hint);
                    if week.abs_diff(self.week_hint) >= 512 {
                        self.set_week_hint(week);
                        self.stats.week_from_galileo += 1;
                    }
                }
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

    /// An ephemeris from another station's stream (a ground station's):
    /// it fills in a satellite the rover's own stream has not given, and
    /// never replaces or outvotes the rover's (a wrong or hostile one would
    /// move every code of that satellite). Its week never overrules the
    /// hint. GLONASS's are kept as the rover's.
    pub fn push_other_ephemeris(&mut self, m: GnssMessage) {
        match m {
            GnssMessage::Eph(raw) => {
                let mut eph = raw.eph.clone();
                eph.week = raw.full_week(self.week_hint);
                if self.ephs.insert_from_other(eph) {
                    self.stats.ephemerides += 1;
                } else {
                    self.stats.ephemerides_from_others_ignored += 1;
                }
            }
            GnssMessage::GlonassEph(_) => self.push(m, &mut Vec::new()),
            _ => {}
        }
    }

    /// Sets the full week near the data (from the autopilot's clock or a
    /// Galileo ephemeris): the GPS ephemerides already stored, whose 10-bit
    /// weeks were resolved with the old hint, are resolved again.
    pub fn set_week_hint(&mut self, week: u32) {
        if week == self.week_hint {
            return;
        }
        self.week_hint = week;
        self.ephs.resolve_gps_weeks(week);
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
                let kept = base.push_msm(e, &self.opts.systems, |tow| ephs.week_for_tow(tow).unwrap_or(hint));
                // Each epoch's own single-point fix checks the base's
                // announced antenna position.
                for ep in kept {
                    if let Ok(fix) = spp::solve(&ep.sats, ep.week, ep.tow_s, &self.ephs, &self.opts) {
                        base.record_fix(ep.station_id, &fix.r_ecef_m);
                    }
                }
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
            let r = dgnss::solve(&sats, week, tow_s, b, &self.ephs, &self.opts, self.base_limits);
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
