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
//! - DG2′: `P̃_r,i = P_r,i − c_b,i(t_b)`, with `t_b` the newest base epoch at
//!   most [`PAIR_TOLERANCE_S`] after the rover's and at most `max_age_s`
//!   before it: the correction is held, never extrapolated (a rate from two
//!   noisy epochs multiplies the base's code noise by √((1+a)² + a²) at an
//!   age of `a` periods), and the filter grows its variance with the age
//!   instead (estimator README §8c);
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

use cmsckf_models::geodesy::{ecef_to_llh, elevation_azimuth, R_ecef_ned, C_MPS, OMEGA_E_RADPS};
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
/// Base epochs kept: the newest per station for the corrections, and a
/// few before it to tell duplicates and stragglers.
const EPOCHS_KEPT: usize = 4;
/// The base's own single-point fixes the antenna-position check takes its
/// median over, and how many it needs before a base is used at all.
const POSITION_CHECK_FIXES: usize = 5;
const POSITION_CHECK_MIN_FIXES: usize = 3;
/// Base epochs in a row older than the newest held that make the newest a
/// stray, forgotten.
const STRAGGLERS_TO_FORGET: u32 = 3;
/// The vertical limit of the position check, in horizontal limits: a
/// single-frequency base's own fix is biased in height by the ionosphere
/// (metres, mostly vertical).
const VERTICAL_CHECK_FACTOR: f64 = 2.0;

/// One base epoch: its time and each satellite's observations.
#[derive(Clone, Debug, PartialEq)]
pub struct BaseEpoch {
    pub station_id: u16,
    pub week: u32,
    pub tow_s: f64,
    pub sats: Vec<SatObs>,
}

impl BaseEpoch {
    /// Seconds from this epoch to `week`/`tow_s`.
    fn age_s(&self, week: u32, tow_s: f64) -> f64 {
        (week as f64 - self.week as f64) * 604_800.0 + tow_s - self.tow_s
    }
}

/// Counts kept by the base station model.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BaseStats {
    /// Base epochs completed.
    pub epochs: u64,
    /// Antenna positions received (MT1005/1006).
    pub positions: u64,
    /// Antenna positions that moved their station by more than 1 m.
    pub position_changes: u64,
    /// Base epochs dropped as a copy of one already held (a base relayed by
    /// two ground stations).
    pub duplicate_epochs: u64,
    /// Base epochs dropped as older than the newest held of their station.
    pub out_of_order_epochs: u64,
}

/// Whether the announced antenna position agrees with the base's own
/// observations.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PositionCheck {
    /// Fewer than [`POSITION_CHECK_MIN_FIXES`] single-point fixes of the
    /// base since its position was announced.
    Pending,
    /// The median horizontal and vertical distances (m) from the announced
    /// position to the base's own fixes.
    Checked { horizontal_m: f64, vertical_m: f64 },
}

/// Stations kept apart at once: the base, a second ground station's, and
/// strays; the least recently heard is forgotten first.
const MAX_STATIONS: usize = 8;

/// One station as its messages describe it.
#[derive(Default)]
struct Station {
    /// The antenna reference point (ECEF, m) of its last MT1005/1006.
    arp: Option<Vector3<f64>>,
    /// Horizontal and vertical distances (m) from the announced antenna
    /// position to the station's own single-point fixes since it was
    /// announced, newest last.
    fix_distances_m: VecDeque<(f64, f64)>,
    /// Its last few epochs, oldest first.
    epochs: VecDeque<BaseEpoch>,
    /// Epochs in a row older than the newest held.
    stragglers_in_a_row: u32,
    /// When it was last heard, in messages (for forgetting).
    last_heard: u64,
}

impl Station {
    /// The antenna-position check: the median distances from the announced
    /// position to the station's own recent fixes, once there are enough.
    fn position_check(&self) -> PositionCheck {
        if self.arp.is_none() || self.fix_distances_m.len() < POSITION_CHECK_MIN_FIXES {
            return PositionCheck::Pending;
        }
        let median = |f: fn(&(f64, f64)) -> f64| {
            let mut v: Vec<f64> = self.fix_distances_m.iter().map(f).collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        PositionCheck::Checked {
            horizontal_m: median(|d| d.0),
            vertical_m: median(|d| d.1),
        }
    }
}

/// The base a rover epoch uses: its station, announced position (ECEF, m),
/// newest usable epoch and the one before it.
pub(crate) struct ChosenBase<'a> {
    pub station_id: u16,
    pub arp: Vector3<f64>,
    pub newest: &'a BaseEpoch,
    pub before: Option<&'a BaseEpoch>,
}

/// The base stations as their RTCM streams describe them: each station's
/// antenna reference point, the checks on it and its last few epochs, kept
/// apart by id, so that a second ground station or another station's
/// epochs never displace a good base. The base used is the lowest-numbered
/// station whose announced position checks out and that has a recent epoch.
#[derive(Default)]
pub struct BaseStation {
    stations: std::collections::BTreeMap<u16, Station>,
    assembler: EpochAssembler,
    heard: u64,
    pub stats: BaseStats,
}

/// Why an epoch has no differential solution.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum DgnssError {
    #[error("no base antenna position (MT1005/1006) yet")]
    NoBasePosition,
    #[error("no base epoch within the maximum age")]
    NoBaseEpoch,
    #[error("the base's antenna position is not checked yet against its own fixes")]
    BasePositionUnchecked,
    #[error(
        "the base's announced antenna position is {horizontal_m:.1} m horizontally and {vertical_m:.1} m \
         vertically from its own fixes (limits {limit_m} m and twice that)"
    )]
    BasePositionWrong {
        horizontal_m: f64,
        vertical_m: f64,
        limit_m: f64,
    },
    #[error(transparent)]
    Solve(#[from] SppError),
}

/// What a base must satisfy for its corrections to be used.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BaseLimits {
    /// Oldest base epoch (s) a rover epoch may use.
    pub max_age_s: f64,
    /// Farthest (m) the announced antenna position may be from the base's
    /// own single-point fixes horizontally; twice this vertically.
    pub max_position_error_m: f64,
}

impl Default for BaseLimits {
    fn default() -> Self {
        BaseLimits {
            max_age_s: 10.0,
            max_position_error_m: 10.0,
        }
    }
}

/// The base's corrections for one rover epoch (DG2′), by satellite, and
/// what their errors depend on.
#[derive(Clone, Debug, PartialEq)]
pub struct BaseCorrections {
    /// The station they come from.
    pub station_id: u16,
    /// The base epoch they come from, and its age at the rover epoch (s).
    pub base_tow_s: f64,
    pub age_s: f64,
    /// Spacing of the base's last two epochs (s; `None` with one).
    pub base_period_s: Option<f64>,
    /// How far each constellation's common part moved since the previous
    /// base epoch (m, signed; DG8).
    pub reference_steps_m: Vec<(System, f64)>,
    pub values: Corrections,
    /// Corrections left out as non-finite.
    pub non_finite: u64,
}

impl BaseStation {
    /// The station `id`, made if new (forgetting the least recently heard
    /// beyond [`MAX_STATIONS`]).
    fn station(&mut self, id: u16) -> &mut Station {
        self.heard += 1;
        if !self.stations.contains_key(&id) && self.stations.len() >= MAX_STATIONS {
            if let Some(oldest) = self.stations.iter().min_by_key(|(_, s)| s.last_heard).map(|(k, _)| *k) {
                self.stations.remove(&oldest);
            }
        }
        let heard = self.heard;
        let st = self.stations.entry(id).or_default();
        st.last_heard = heard;
        st
    }

    /// Every station that announced a position: id and antenna reference
    /// point (ECEF, m).
    pub fn positions(&self) -> Vec<(u16, Vector3<f64>)> {
        self.stations.iter().filter_map(|(id, s)| Some((*id, s.arp?))).collect()
    }

    /// A reference station's antenna position (MT1005/1006). A position
    /// moved by more than 1 m is checked afresh.
    pub fn set_position(&mut self, station_id: u16, arp_ecef_m: [f64; 3]) {
        let arp = Vector3::from(arp_ecef_m);
        self.stats.positions += 1;
        let st = self.station(station_id);
        let moved = st.arp.is_some_and(|old| (old - arp).norm() > 1.0);
        if moved {
            st.fix_distances_m.clear();
        }
        st.arp = Some(arp);
        if moved {
            self.stats.position_changes += 1;
        }
    }

    /// One base MSM; `week_of` resolves a time of week to its full week.
    /// The epochs it completed and kept (not duplicates or stragglers).
    pub fn push_msm(&mut self, e: MsmEpoch, systems: &[System], week_of: impl Fn(f64) -> u32) -> Vec<BaseEpoch> {
        let mut done = Vec::new();
        self.assembler
            .push(e, systems, |id, tow_s, sats| done.push((id, tow_s, sats)));
        done.into_iter()
            .filter_map(|(id, tow_s, sats)| self.push_epoch(id, tow_s, sats, &week_of))
            .collect()
    }

    /// Closes a pending base epoch (at the end of a stream).
    pub fn flush(&mut self, week_of: impl Fn(f64) -> u32) {
        if let Some((id, tow_s, sats)) = self.assembler.take() {
            self.push_epoch(id, tow_s, sats, &week_of);
        }
    }

    /// Keeps a completed epoch, unless its station already has one at the
    /// same time (a copy: counted) or a newer one (a straggler: counted).
    fn push_epoch(
        &mut self,
        station_id: u16,
        tow_s: f64,
        sats: Vec<SatObs>,
        week_of: impl Fn(f64) -> u32,
    ) -> Option<BaseEpoch> {
        if !(0.0..604_800.0).contains(&tow_s) {
            self.stats.out_of_order_epochs += 1;
            return None;
        }
        let e = BaseEpoch {
            station_id,
            week: week_of(tow_s),
            tow_s,
            sats,
        };
        let st = self.station(station_id);
        let newest_age = st.epochs.back().map(|o| e.age_s(o.week, o.tow_s));
        match newest_age {
            Some(a) if a.abs() < 1e-3 => {
                self.stats.duplicate_epochs += 1;
                return None;
            }
            Some(a) if a > 0.0 => {
                // A held epoch that every later one is older than was the
                // stray (a time tag far ahead): forget it rather than refuse
                // the base for the rest of the flight.
                st.stragglers_in_a_row += 1;
                if st.stragglers_in_a_row < STRAGGLERS_TO_FORGET {
                    self.stats.out_of_order_epochs += 1;
                    return None;
                }
                st.epochs.clear();
            }
            _ => {}
        }
        st.stragglers_in_a_row = 0;
        st.epochs.push_back(e.clone());
        while st.epochs.len() > EPOCHS_KEPT {
            st.epochs.pop_front();
        }
        self.stats.epochs += 1;
        Some(e)
    }

    /// Records a single-point fix (ECEF, m) of station `station_id`'s own
    /// epoch, once it has announced a position.
    pub fn record_fix(&mut self, station_id: u16, r_ecef_m: &Vector3<f64>) {
        if !r_ecef_m.iter().all(|v| v.is_finite()) {
            return;
        }
        let Some(st) = self.stations.get_mut(&station_id) else {
            return;
        };
        let Some(arp) = st.arp else { return };
        let (lat, lon, _) = ecef_to_llh(&arp);
        let d_ned = R_ecef_ned(lat, lon).transpose() * (r_ecef_m - arp);
        st.fix_distances_m.push_back((d_ned.x.hypot(d_ned.y), d_ned.z.abs()));
        while st.fix_distances_m.len() > POSITION_CHECK_FIXES {
            st.fix_distances_m.pop_front();
        }
    }

    /// The antenna-position check of the base in use, else of the station
    /// that announced a position last.
    pub fn position_check(&self) -> PositionCheck {
        self.stations
            .values()
            .filter(|s| s.arp.is_some())
            .max_by_key(|s| (s.position_check() != PositionCheck::Pending, s.last_heard))
            .map_or(PositionCheck::Pending, Station::position_check)
    }

    /// The base for a rover epoch at `week`/`tow_s`: the lowest-numbered
    /// station whose announced position checks out within `limits` and
    /// that has an epoch at most [`PAIR_TOLERANCE_S`] after the rover's and
    /// at most `max_age_s` before it, with the epoch before that (for the
    /// reference step and the period); else why there is none (the most
    /// telling reason over the stations).
    pub(crate) fn base_for(&self, week: u32, tow_s: f64, limits: BaseLimits) -> Result<ChosenBase<'_>, DgnssError> {
        let mut why = DgnssError::NoBasePosition;
        for (id, st) in &self.stations {
            let Some(arp) = st.arp else { continue };
            match st.position_check() {
                PositionCheck::Pending => {
                    if why == DgnssError::NoBasePosition {
                        why = DgnssError::BasePositionUnchecked;
                    }
                    continue;
                }
                PositionCheck::Checked {
                    horizontal_m,
                    vertical_m,
                } if horizontal_m > limits.max_position_error_m
                    || vertical_m > VERTICAL_CHECK_FACTOR * limits.max_position_error_m =>
                {
                    if matches!(why, DgnssError::NoBasePosition | DgnssError::BasePositionUnchecked) {
                        why = DgnssError::BasePositionWrong {
                            horizontal_m,
                            vertical_m,
                            limit_m: limits.max_position_error_m,
                        };
                    }
                    continue;
                }
                PositionCheck::Checked { .. } => {}
            }
            let mut own = st
                .epochs
                .iter()
                .rev()
                .filter(|e| e.age_s(week, tow_s) >= -PAIR_TOLERANCE_S);
            match own.next().filter(|e| e.age_s(week, tow_s) <= limits.max_age_s) {
                Some(newest) => {
                    return Ok(ChosenBase {
                        station_id: *id,
                        arp,
                        newest,
                        before: own.next(),
                    })
                }
                None => why = DgnssError::NoBaseEpoch,
            }
        }
        Err(why)
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
        .filter_map(|obs| {
            let s = RawSat::from_obs(obs);
            let orbit = ephs.orbit(s.system, s.prn, week, tow_s)?;
            Some(((s.system, s.prn), correction_at(e, &s, arp, orbit, mask, model)?))
        })
        .collect();
    let mut systems: Vec<System> = out.iter().map(|(k, _)| k.0).collect();
    systems.sort_by_key(|s| s.letter());
    systems.dedup();
    for sys in systems {
        let mut v: Vec<f64> = out
            .iter()
            .filter(|(k, c)| k.0 == sys && c.is_finite())
            .map(|(_, c)| *c)
            .collect();
        v.sort_by(f64::total_cmp);
        let Some(&median) = v.get(v.len() / 2) else { continue };
        out.iter_mut()
            .filter(|(k, _)| k.0 == sys)
            .for_each(|(_, c)| *c -= median);
    }
    out
}

/// How far each constellation's common part moved from `before` to
/// `now` (DG8): the median over its shared satellites of the change of each
/// one's correction (m, signed), by constellation.
fn reference_steps(now: &Corrections, before: &Corrections) -> Vec<(System, f64)> {
    let mut systems: Vec<System> = now.iter().map(|(k, _)| k.0).collect();
    systems.sort_by_key(|s| s.letter());
    systems.dedup();
    systems
        .into_iter()
        .filter_map(|sys| {
            let mut d: Vec<f64> = now
                .iter()
                .filter(|(k, _)| k.0 == sys)
                .filter_map(|(k, c)| Some(c - before.iter().find(|(b, _)| b == k)?.1))
                .filter(|d| d.is_finite())
                .collect();
            d.sort_by(f64::total_cmp);
            d.get(d.len() / 2).map(|m| (sys, *m))
        })
        .collect()
}

/// The base's corrections at the rover epoch `week`/`tow_s` (DG2′), by
/// satellite: the newest base epoch's, held, within `limits`, with the
/// troposphere of `model` (the one the corrected codes will be predicted
/// with).
pub fn corrections(
    week: u32,
    tow_s: f64,
    base: &BaseStation,
    ephs: &EphStore,
    mask: f64,
    limits: BaseLimits,
    model: CodeModel,
) -> Result<BaseCorrections, DgnssError> {
    let ChosenBase {
        station_id,
        arp,
        newest,
        before,
    } = base.base_for(week, tow_s, limits)?;
    let mut values = epoch_corrections(newest, &arp, ephs, (week, tow_s), mask, model);
    let before_filter = values.len();
    values.retain(|(_, c)| c.is_finite());
    let non_finite = (before_filter - values.len()) as u64;
    let steps = before.map_or(Vec::new(), |b| {
        reference_steps(&values, &epoch_corrections(b, &arp, ephs, (week, tow_s), mask, model))
    });
    Ok(BaseCorrections {
        station_id,
        base_tow_s: newest.tow_s,
        age_s: newest.age_s(week, tow_s),
        base_period_s: before.map(|b| b.age_s(newest.week, newest.tow_s)),
        reference_steps_m: steps,
        values,
        non_finite,
    })
}

/// The differential solution (DG1–DG3) of a rover epoch `sats` at
/// `week`/`tow_s` against `base`, within `limits`.
/// The first-frequency codes are used whatever `opt.iono` says: the
/// ionosphere cancels in the difference.
pub fn solve(
    sats: &[SatObs],
    week: u32,
    tow_s: f64,
    base: &BaseStation,
    ephs: &EphStore,
    opt: &SppOptions,
    limits: BaseLimits,
) -> Result<SppSolution, DgnssError> {
    let mask = opt.elevation_mask_deg.to_radians();
    let model = CodeModel::Differential {
        doy: gps_day_of_year(week, tow_s),
    };
    let corr = corrections(week, tow_s, base, ephs, mask, limits, model)?.values;
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
