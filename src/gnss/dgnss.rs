//! Code differential GNSS against a base station: why a base within a few
//! kilometres is worth having. The base's known antenna position (MT1005 or
//! MT1006) turns each of its pseudoranges into a correction, everything the
//! model did not explain: the satellite's orbit and clock errors, the
//! ionosphere, the troposphere's error and the base's own clock. Over a
//! short baseline the rover sees the same errors, so its pseudorange less
//! the base's correction for the same satellite is a single difference in
//! which they cancel (estimator README §8c, eqs. DG1–DG3):
//!
//! - DG1: `c_b,i = P_b,i − (ρ_b,i + sagnac − c·δt_i(t_b) + T_b,i)` at the base's
//!   epoch `t_b`, with the base at its ARP and the rover's ephemeris; DG1′:
//!   less each constellation's median over the epoch (the base's clock);
//! - DG2: `P̃_r,i = P_r,i − c_b,i(t_r)`, with `c_b,i(t_r)` the correction of a
//!   base epoch within [`PAIR_TOLERANCE_S`] of the rover's, else the newest
//!   older one extrapolated linearly from the two before `t_r` (up to
//!   `max_age_s` old);
//! - DG3: `P̃_r,i = ρ_r,i + sagnac − c·δt_i(t_r) + T_r,i + c·(δt_r − δt_b) + ε`,
//!   solved like a single-point epoch for the position and one clock per
//!   constellation, with no ionosphere term and the differential weights of
//!   [`super::spp::CodeModel::Differential`].
//!
//! Least squares on single differences with a common clock is the same
//! estimator as double differences with their correlated covariance (the
//! clock is the nuisance parameter that double differencing eliminates), so
//! the solution is RTKLIB's code DGPS. Like the rest of `gnss`, no I/O.

use std::collections::VecDeque;

use nalgebra::Vector3;

use cmsckf_models::geodesy::{ecef_to_llh, elevation_azimuth, C_MPS, OMEGA_E_RADPS};
use cmsckf_models::gnss::gps_day_of_year;

pub use super::spp::CodeModel;

use super::epoch_assembly::EpochAssembler;
use super::options::IonoMode;
use super::raw_sat::RawSat;
use super::rtcm::{MsmEpoch, SatObs, System};
use super::spp::{self, EphStore, Meas, Orbit, SppError, SppOptions, SppSolution};

/// Code corrections (m) by satellite `(system, prn)`.
pub type Corrections = Vec<((System, u8), f64)>;

/// Base and rover epochs this close (s) are the same epoch: receivers' time
/// tags drift by milliseconds (RTKLIB pairs within 25 ms).
pub const PAIR_TOLERANCE_S: f64 = 0.05;
/// Base epochs kept: enough to extrapolate from the two newest.
const EPOCHS_KEPT: usize = 3;

/// One base epoch: its time and each satellite's first-frequency code.
#[derive(Clone, Debug, PartialEq)]
pub struct BaseEpoch {
    pub station_id: u16,
    pub week: u32,
    pub tow_s: f64,
    pub sats: Vec<RawSat>,
}

/// Counts kept by the base station model.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BaseStats {
    /// Base epochs completed.
    pub epochs: u64,
    /// Antenna positions received (MT1005/1006).
    pub positions: u64,
    /// Antenna positions that moved the base by more than 1 m, or named
    /// another station.
    pub position_changes: u64,
}

/// A base station as its RTCM stream describes it: its antenna reference
/// point and its last few epochs. The base is the station that announced
/// an antenna position; epochs of other stations are kept apart by id.
#[derive(Default)]
pub struct BaseStation {
    /// The station id and antenna reference point (ECEF, m) of the last
    /// MT1005/1006.
    pub arp: Option<(u16, Vector3<f64>)>,
    epochs: VecDeque<BaseEpoch>,
    assembler: EpochAssembler,
    pub stats: BaseStats,
}

/// Why an epoch has no differential solution.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum DgnssError {
    #[error("no base antenna position (MT1005/1006) yet")]
    NoBasePosition,
    #[error("no base epoch within the maximum age")]
    NoBaseEpoch,
    #[error(transparent)]
    Solve(#[from] SppError),
}

impl BaseStation {
    /// A reference station's antenna position (MT1005/1006).
    pub fn set_position(&mut self, station_id: u16, arp_ecef_m: [f64; 3]) {
        let arp = Vector3::from(arp_ecef_m);
        self.stats.positions += 1;
        if self
            .arp
            .is_some_and(|(id, old)| id != station_id || (old - arp).norm() > 1.0)
        {
            self.stats.position_changes += 1;
        }
        self.arp = Some((station_id, arp));
    }

    /// One base MSM; `week_of` resolves a time of week to its full week.
    pub fn push_msm(&mut self, e: MsmEpoch, systems: &[System], week_of: impl Fn(f64) -> u32) {
        let mut done = Vec::new();
        self.assembler
            .push(e, systems, |id, tow_s, sats| done.push((id, tow_s, sats)));
        for (id, tow_s, sats) in done {
            self.push_epoch(id, tow_s, &sats, &week_of);
        }
    }

    /// Closes a pending base epoch (at the end of a stream).
    pub fn flush(&mut self, week_of: impl Fn(f64) -> u32) {
        if let Some((id, tow_s, sats)) = self.assembler.take() {
            self.push_epoch(id, tow_s, &sats, &week_of);
        }
    }

    fn push_epoch(&mut self, station_id: u16, tow_s: f64, sats: &[SatObs], week_of: impl Fn(f64) -> u32) {
        let e = BaseEpoch {
            station_id,
            week: week_of(tow_s),
            tow_s,
            sats: sats.iter().map(RawSat::from_obs).collect(),
        };
        self.stats.epochs += 1;
        self.epochs.push_back(e);
        while self.epochs.len() > EPOCHS_KEPT {
            self.epochs.pop_front();
        }
    }

    /// The base epochs a rover epoch at `week`/`tow_s` uses: the newest of
    /// the base's own station at most [`PAIR_TOLERANCE_S`] after it and at
    /// most `max_age_s` before it, and the one before that (for the rate).
    fn epochs_for(&self, week: u32, tow_s: f64, max_age_s: f64) -> Option<(&BaseEpoch, Option<&BaseEpoch>)> {
        let (id, _) = self.arp?;
        let age = |e: &BaseEpoch| (week as f64 - e.week as f64) * 604_800.0 + tow_s - e.tow_s;
        let mut own = self
            .epochs
            .iter()
            .rev()
            .filter(|e| e.station_id == id && age(e) >= -PAIR_TOLERANCE_S);
        let newest = own.next().filter(|e| age(e) <= max_age_s)?;
        let before = own.next().filter(|e| age(e) - age(newest) <= max_age_s);
        Some((newest, before))
    }
}

/// The base's correction (DG1) for its satellite `raw`, whose orbit is
/// `orbit`, at the base epoch `e`, with the base at `arp` and the
/// troposphere of `model`; `None` below the elevation mask (rad) or without
/// a code.
fn correction_at(
    e: &BaseEpoch,
    raw: &RawSat,
    arp: &Vector3<f64>,
    orbit: Orbit<'_>,
    mask: f64,
    model: CodeModel,
) -> Option<f64> {
    let pr = raw.l1_pseudorange_m.filter(|p| (1.0e7..=4.0e7).contains(p))?;
    let st = spp::state_at_transmission(orbit, e.week, e.tow_s, pr);
    let (el, _) = elevation_azimuth(arp, &st.r_ecef_m);
    if el < mask {
        return None;
    }
    let (lat, _, h) = ecef_to_llh(arp);
    let d = st.r_ecef_m - arp;
    let rho = d.norm() + OMEGA_E_RADPS * (st.r_ecef_m.x * arp.y - st.r_ecef_m.y * arp.x) / C_MPS;
    Some(pr - (rho - st.dt_s * C_MPS + model.troposphere_m(lat, h, el)))
}

/// Every correction (DG1) of base epoch `e`, each constellation's less their
/// median (DG1′): the median is the base's clock (and its inter-system
/// bias), common to all of a constellation's satellites, so it changes no
/// solution, and without it a differential code keeps the rover's own
/// clock rather than the rover's minus the base's, which a Doppler cannot
/// see. Ephemerides are selected at the rover's time, as the rover's are.
fn epoch_corrections(
    e: &BaseEpoch,
    arp: &Vector3<f64>,
    ephs: &EphStore,
    (week, tow_s): (u32, f64),
    mask: f64,
    model: CodeModel,
) -> Corrections {
    let mut out: Corrections = e
        .sats
        .iter()
        .filter_map(|s| {
            let orbit = ephs.orbit(s.system, s.prn, week, tow_s)?;
            Some(((s.system, s.prn), correction_at(e, s, arp, orbit, mask, model)?))
        })
        .collect();
    let mut systems: Vec<System> = out.iter().map(|(k, _)| k.0).collect();
    systems.dedup();
    for sys in systems {
        let mut v: Vec<f64> = out.iter().filter(|(k, _)| k.0 == sys).map(|(_, c)| *c).collect();
        v.sort_by(f64::total_cmp);
        let median = v[v.len() / 2];
        out.iter_mut()
            .filter(|(k, _)| k.0 == sys)
            .for_each(|(_, c)| *c -= median);
    }
    out
}

/// The base's corrections at the rover epoch `week`/`tow_s` (DG2), by
/// satellite: the matched base epoch's, else the newest's extrapolated from
/// the one before it, with base epochs at most `max_age_s` old and the
/// troposphere of `model` (the one the corrected codes will be predicted
/// with).
pub fn corrections(
    week: u32,
    tow_s: f64,
    base: &BaseStation,
    ephs: &EphStore,
    mask: f64,
    max_age_s: f64,
    model: CodeModel,
) -> Result<Corrections, DgnssError> {
    let (_, arp) = base.arp.ok_or(DgnssError::NoBasePosition)?;
    let (newest, before) = base.epochs_for(week, tow_s, max_age_s).ok_or(DgnssError::NoBaseEpoch)?;
    let age = |e: &BaseEpoch| (week as f64 - e.week as f64) * 604_800.0 + tow_s - e.tow_s;
    let c1 = epoch_corrections(newest, &arp, ephs, (week, tow_s), mask, model);
    let c0 = match before {
        Some(b) if age(newest).abs() > PAIR_TOLERANCE_S => {
            let span = age(b) - age(newest);
            Some((span, epoch_corrections(b, &arp, ephs, (week, tow_s), mask, model)))
        }
        _ => None,
    };
    Ok(c1
        .into_iter()
        .map(|(sat, c)| {
            let prior = c0
                .as_ref()
                .and_then(|(span, v)| Some((span, v.iter().find(|(k, _)| *k == sat)?.1)));
            match prior {
                Some((span, c_before)) => (sat, c + (c - c_before) / span * age(newest)),
                None => (sat, c),
            }
        })
        .collect())
}

/// The differential solution (DG1–DG3) of a rover epoch `sats` at
/// `week`/`tow_s` against `base`, with base epochs at most `max_age_s` old.
/// The first-frequency codes are used whatever `opt.iono` says: the
/// ionosphere cancels in the difference.
pub fn solve(
    sats: &[SatObs],
    week: u32,
    tow_s: f64,
    base: &BaseStation,
    ephs: &EphStore,
    opt: &SppOptions,
    max_age_s: f64,
) -> Result<SppSolution, DgnssError> {
    let mask = opt.elevation_mask_deg.to_radians();
    let model = CodeModel::Differential {
        doy: gps_day_of_year(week, tow_s),
    };
    let corr = corrections(week, tow_s, base, ephs, mask, max_age_s, model)?;
    let mut meas = Vec::new();
    for s in sats.iter().filter(|s| opt.systems.contains(&s.system)) {
        let Some((pr, _)) = RawSat::from_obs(s).code(IonoMode::Off) else {
            continue;
        };
        let Some(c) = corr.iter().find(|(k, _)| *k == (s.system, s.prn)).map(|(_, c)| *c) else {
            continue;
        };
        let Some(orbit) = ephs.orbit(s.system, s.prn, week, tow_s) else {
            continue;
        };
        if !(1.0e7..=4.0e7).contains(&pr) {
            continue;
        }
        let st = spp::state_at_transmission(orbit, week, tow_s, pr);
        meas.push(Meas {
            sat: (s.system, s.prn),
            pr_m: pr - c,
            r_sat: st.r_ecef_m,
            dts_m: st.dt_s * C_MPS,
            ura_m: 0.0,
        });
    }
    Ok(spp::solve_meas(&meas, week, tow_s, opt, model)?)
}
