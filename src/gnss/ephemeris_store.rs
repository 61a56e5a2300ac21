//! The broadcast ephemerides a receiver has heard, by satellite, with
//! their weeks resolved: why it exists is that the single-point and
//! differential solvers and the filter's measurements all look a
//! satellite's orbit up here, at the epoch's time.

use std::collections::BTreeMap;

use cmsckf_models::gnss::{BroadcastEphemeris, GlonassEphemeris, SatState};

use super::rtcm::System;

/// Largest `|t − toe|` for an ephemeris to be used (s).
const MAX_AGE_S: f64 = 7200.0;

/// Largest `|t − t_b|` for a GLONASS ephemeris to be used (s): they are
/// broadcast every 30 min (RTKLIB's limit).
const MAX_AGE_GLONASS_S: f64 = 1800.0;

/// Broadcast ephemerides by satellite, with resolved weeks.
#[derive(Clone, Debug, Default)]
pub struct EphStore {
    by_sat: BTreeMap<(System, u8), Vec<BroadcastEphemeris>>,
    /// GLONASS's, by slot.
    glonass: BTreeMap<u8, Vec<GlonassEphemeris>>,
    /// Week and toe of the latest ephemeris, to place a time of week.
    last: Option<(u32, f64)>,
    /// Satellites whose ephemerides came only from another station's
    /// stream (a ground station's): the rover's own replace them.
    from_others: std::collections::BTreeSet<(System, u8)>,
}

/// A satellite's broadcast orbit and clock: a Kepler ephemeris (GPS,
/// Galileo, BeiDou, QZSS) or a GLONASS state vector.
#[derive(Clone, Copy, Debug)]
pub enum Orbit<'a> {
    Kepler(&'a BroadcastEphemeris),
    Glonass(&'a GlonassEphemeris),
}

impl Orbit<'_> {
    /// Position, velocity and clock at GPS time `week`/`tow_s`.
    pub fn state(&self, week: u32, tow_s: f64) -> SatState {
        match self {
            Orbit::Kepler(e) => e.state(tow_s),
            Orbit::Glonass(g) => g.state(week, tow_s),
        }
    }

    /// The single-frequency user's group delay (s): GPS TGD, Galileo BGD,
    /// BeiDou TGD1; GLONASS none.
    pub fn tgd_s(&self) -> f64 {
        match self {
            Orbit::Kepler(e) => e.tgd_s,
            Orbit::Glonass(_) => 0.0,
        }
    }

    /// The broadcast accuracy (m): URA, SISA, or GLONASS's fixed 5 m.
    pub fn accuracy_m(&self) -> f64 {
        match self {
            Orbit::Kepler(e) => e.accuracy_m(),
            Orbit::Glonass(g) => g.accuracy_m(),
        }
    }
}

impl EphStore {
    /// Adds a GLONASS ephemeris, replacing one with the same `t_b`.
    pub fn insert_glonass(&mut self, eph: GlonassEphemeris) {
        self.last = Some((eph.week, eph.toe_s));
        let v = self.glonass.entry(eph.slot).or_default();
        v.retain(|e| !(e.toe_s == eph.toe_s && e.week == eph.week));
        v.push(eph);
        if v.len() > 8 {
            v.remove(0);
        }
    }

    /// The satellite's orbit at the time: the healthy ephemeris nearest to
    /// it ([`Self::select`]; GLONASS's within 30 min of `t_b`).
    pub fn orbit(&self, system: System, prn: u8, week: u32, tow_s: f64) -> Option<Orbit<'_>> {
        if system != System::Glonass {
            return self.select(system, prn, week, tow_s).map(Orbit::Kepler);
        }
        self.glonass
            .get(&prn)?
            .iter()
            .filter(|e| e.health == 0)
            .map(|e| (e, e.since_tb_s(week, tow_s).abs()))
            .filter(|(_, d)| *d <= MAX_AGE_GLONASS_S)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(e, _)| Orbit::Glonass(e))
    }
    /// Adds an ephemeris from another station's stream (a ground station
    /// relaying a base): only for a satellite the rover's own stream has
    /// given none, which a hostile or wrong one cannot then displace.
    /// Whether it was taken.
    pub fn insert_from_other(&mut self, eph: BroadcastEphemeris) -> bool {
        let key = (eph.system, eph.prn);
        if self.by_sat.contains_key(&key) && !self.from_others.contains(&key) {
            return false;
        }
        self.from_others.insert(key);
        self.insert_kept(eph);
        true
    }

    /// Adds an ephemeris of the rover's own, replacing one with the same
    /// `toe` and IODE, and any another station gave for the satellite.
    pub fn insert(&mut self, eph: BroadcastEphemeris) {
        if self.from_others.remove(&(eph.system, eph.prn)) {
            self.by_sat.remove(&(eph.system, eph.prn));
        }
        self.insert_kept(eph);
    }

    fn insert_kept(&mut self, eph: BroadcastEphemeris) {
        self.last = Some((eph.week, eph.toe_s));
        let v = self.by_sat.entry((eph.system, eph.prn)).or_default();
        v.retain(|e| !(e.toe_s == eph.toe_s && e.week == eph.week && e.iode == eph.iode));
        v.push(eph);
        // Bounded: keep the newest 8 per satellite.
        if v.len() > 8 {
            v.remove(0);
        }
    }

    /// The healthy ephemeris with `toe` nearest to the time (RTKLIB's rule).
    pub fn select(&self, system: System, prn: u8, week: u32, tow_s: f64) -> Option<&BroadcastEphemeris> {
        self.by_sat
            .get(&(system, prn))?
            .iter()
            .filter(|e| e.health == 0)
            .map(|e| (e, ((week as f64 - e.week as f64) * 604_800.0 + tow_s - e.toe_s).abs()))
            .filter(|(_, d)| *d <= MAX_AGE_S)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(e, _)| e)
    }

    /// Resolves the GPS and QZSS ephemerides' 10-bit weeks again near
    /// `hint_week` (the hint they were stored with was wrong).
    pub fn resolve_gps_weeks(&mut self, hint_week: u32) {
        for ((system, _), v) in self.by_sat.iter_mut() {
            if matches!(system, System::Gps | System::Qzss) {
                for e in v.iter_mut() {
                    e.week = super::rtcm::resolve_week((e.week % 1024) as u16, hint_week);
                }
            }
        }
        if let Some((w, toe)) = self.last {
            self.last = Some((super::rtcm::resolve_week((w % 1024) as u16, hint_week), toe));
        }
    }

    /// The full week of a time of week near the latest ephemeris.
    pub fn week_for_tow(&self, tow_s: f64) -> Option<u32> {
        let (w, toe) = self.last?;
        let d = tow_s - toe;
        Some(if d < -302_400.0 {
            w + 1
        } else if d > 302_400.0 {
            w.saturating_sub(1)
        } else {
            w
        })
    }

    pub fn len(&self) -> usize {
        self.by_sat.values().map(Vec::len).sum::<usize>() + self.glonass.values().map(Vec::len).sum::<usize>()
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}
