//! The tightly coupled GNSS update, whole: pseudoranges and range rates
//! against satellite states from broadcast ephemerides (README.md §8): the
//! clock states' initialisation from the first epochs, the robust pre-screen
//! and χ² gate of each measurement, and their Jacobians; the update itself
//! goes through [`Estimator::ekf_update`].
//!
//! What a satellite measures, and its Jacobians with the antenna's lever
//! arm, is `gnss_model.rs`'s.
//!
//! Epochs arrive late (0.1–0.6 s on real hardware, §8b). The filter clones
//! the states a GNSS row involves at each instant an epoch is expected (a
//! grid learnt from the epochs themselves), keeps the clone until its epoch
//! arrives, and fuses the epoch against the clone: exactly at its own time.
//! An epoch later than `gnss_max_delay_s`, or with no clone at its instant,
//! is refused and counted as `gnss_late`. Everything here involves only
//! local states, so in compressed mode it is a local update.

use crate::counters::Counter;
use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector, SMatrix, Vector3};

use cmsckf_models::geodesy::NedFrame;
use cmsckf_models::gnss::{SatMeas, System};

pub use super::gnss_model::{predict_sat, pseudorange, range_rate, GnssNominal, SatPrediction, GNSS_CLONE_DIM};
use super::gnss_model::{GNSS_COLS, G_B, G_D};
use super::propagate::{integrate, transition, ImuMeas};
use super::{
    isb_slot, math, ClockVec, Estimator, GnssClone, GnssGrid, InputError, Stats, CLK_B, CLK_D, CLK_E, ISB_SYSTEMS,
    OUTLIER_SIGMAS,
};

/// What one GNSS epoch did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GnssReport {
    pub pseudoranges_used: usize,
    pub range_rates_used: usize,
    pub rejected: BTreeMap<Counter, u64>,
    /// `(prn, pseudorange residual m, range-rate residual m/s)` before the update.
    pub residuals: Vec<(u8, Option<f64>, Option<f64>)>,
    pub clock_initialised: bool,
    /// How far behind the filter the epoch arrived (s; 0 when on time).
    pub late_s: f64,
    /// The codes were differential (corrected by a base station).
    pub differential: bool,
}

/// Shortest epoch period the grid takes (s): 20 Hz, beyond any receiver's
/// raw-measurement rate on a drone.
const MIN_GNSS_PERIOD_S: f64 = 0.05;
/// Spacings in a row longer than the learnt period by half again that make
/// it theirs (a stray early epoch once fixed a 1 Hz receiver's period at
/// 50 ms for the rest of the flight).
const GNSS_PERIOD_RELEARN: u32 = 5;
/// Farthest ahead of the filter an epoch may be and still set the grid (s).
const MAX_GNSS_LEAD_S: f64 = 2.0;

/// The transition of a clone's states to its epoch's time.
type ShiftF = SMatrix<f64, GNSS_CLONE_DIM, GNSS_CLONE_DIM>;

/// One whitened measurement row and its residual: its columns over the
/// GNSS row order, and over the range-bias block (eq. DG5′) the zenith
/// troposphere's `m(el)` and the satellite's own bias's 1, by their index
/// in the block.
#[derive(Clone, Copy, Debug)]
struct GnssRow {
    h: [f64; GNSS_CLONE_DIM],
    block: BlockCols,
    r: f64,
}

/// A row's columns over the range-bias block: `(index in the block,
/// coefficient)`, at most `T_z`'s and `b_i`'s.
type BlockCols = [Option<(usize, f64)>; 2];

/// A single-point code's range-bias part of the prediction (m), and its
/// columns (eq. DG5′).
type BiasModel = (f64, BlockCols);

/// The median of the finite values (upper median), if any.
fn median(mut v: Vec<f64>) -> Option<f64> {
    v.retain(|x| x.is_finite());
    v.sort_by(|a, b| a.total_cmp(b));
    v.get(v.len() / 2).copied()
}

/// Counts a rejected GNSS measurement in the epoch's report and the stats.
fn reject(rep: &mut GnssReport, st: &mut Stats, why: Counter) {
    *rep.rejected.entry(why).or_default() += 1;
    *st.rejected.entry(why).or_default() += 1;
}

/// Whitens one scalar measurement row and gates it on `r² / (h P hᵀ + σ²)`,
/// `P` the covariance of the epoch's columns: the GNSS row order's, then the
/// range-bias block's, which `block` addresses.
///
/// The gate takes the measurement's sigma for one epoch, `gate_sigma`; the
/// row is whitened with `sigma`, which may be wider (eq. DG6: an error that
/// holds over many epochs is believed once per window).
fn gated(
    h: &[f64; GNSS_CLONE_DIM],
    block: BlockCols,
    r: f64,
    gate_sigma: f64,
    sigma: f64,
    p: &DMatrix<f64>,
    gate: f64,
) -> Option<GnssRow> {
    let mut hv = DVector::zeros(p.nrows());
    hv.rows_mut(0, GNSS_CLONE_DIM).copy_from_slice(h);
    for (k, c) in block.iter().flatten() {
        hv[GNSS_CLONE_DIM + k] += c;
    }
    let s = (hv.transpose() * p * &hv)[0] + gate_sigma * gate_sigma;
    if !(r.is_finite() && s > 0.0 && sigma > 0.0) || r * r / s > gate {
        return None;
    }
    let mut w = *h;
    for x in w.iter_mut() {
        *x /= sigma;
    }
    Some(GnssRow {
        h: w,
        block: block.map(|e| e.map(|(k, c)| (k, c / sigma))),
        r: r / sigma,
    })
}

/// The clone's states moved by `dt_s` to the epoch's own time (§8b, eq.
/// D2): the instant the grid expected and the epoch's tag differ by the
/// time map's jitter (milliseconds). One IMU step at the clone's measured
/// rates: `x(t_e) = f(x_c)`, so a row `H` at `x(t_e)` is `H F` on the
/// clone, with `F` the step's transition in the GNSS row order (the
/// accelerometer bias's effect over milliseconds is below a micrometre and
/// left out, as is the step's process noise).
fn shift_clone(
    c: &GnssClone,
    dt_s: f64,
    g_W: &Vector3<f64>,
    imu: &cmsckf_models::sensors::ImuConfig,
) -> (GnssNominal, ShiftF) {
    let mut f = SMatrix::<f64, GNSS_CLONE_DIM, GNSS_CLONE_DIM>::identity();
    if dt_s == 0.0 {
        return (c.nom, f);
    }
    let m1 = ImuMeas {
        t_s: c.meas.t_s + dt_s,
        ..c.meas
    };
    let x = integrate(&c.nom.imu, &c.meas, &m1, g_W);
    let (f15, _) = transition(&c.nom.imu, &c.meas, &m1, imu);
    // [θ, v, p, b_g] are the IMU error state's first twelve, in order.
    f.fixed_view_mut::<12, 12>(0, 0)
        .copy_from(&f15.fixed_view::<12, 12>(0, 0));
    f[(G_B, G_D)] = dt_s;
    let mut nom = c.nom;
    nom.imu = x;
    nom.clock.x += c.nom.clock.y * dt_s;
    (nom, f)
}

/// Where an epoch's states come from.
#[derive(Clone, Copy)]
enum EpochStates {
    /// The live state, propagated to the epoch.
    Live,
    /// The GNSS clone at this index.
    Clone(usize),
}

impl Estimator {
    /// The receiver clock `[c·δt_G (m), c·δṫ (m/s), isb_E, isb_R, isb_C (m)]`
    /// and its variances.
    pub fn clock(&self) -> (ClockVec, ClockVec) {
        (self.clock, ClockVec::from_fn(|k, _| self.P[(CLK_B + k, CLK_B + k)]))
    }

    /// Whether an epoch of `system` has set its inter-system bias yet
    /// (always for GPS and QZSS, which have none).
    pub fn isb_initialised(&self, system: System) -> bool {
        isb_slot(system).is_none_or(|k| self.isb_initialised[k])
    }

    /// The live states a GNSS row involves.
    fn live_gnss_nominal(&self) -> GnssNominal {
        GnssNominal {
            imu: self.imu,
            gyro_radps: self.last_meas.map_or(Vector3::zeros(), |m| m.gyro_radps),
            clock: self.clock,
        }
    }

    /// One GNSS epoch at `t_s` (its instant on the IMU clock, §8): the
    /// pseudoranges and range rates of the satellites in `sats`, against the
    /// world origin `frame`. An epoch in the filter's past is fused at its
    /// own time through the clone taken at its instant (§8b); one later
    /// than `gnss_max_delay_s`, or with no clone, is refused
    /// ([`InputError::GnssLate`], counted as `gnss_late`).
    ///
    /// GPS is the reference clock: the first epoch with GPS pseudoranges
    /// sets the bias and drift from the median residuals, and the first
    /// with Galileo ones sets the inter-system bias the same way.
    pub(super) fn update_with_gnss(
        &mut self,
        t_s: f64,
        frame: &NedFrame,
        sats: &[SatMeas],
    ) -> Result<GnssReport, InputError> {
        let mut rep = GnssReport::default();
        // Before propagating: an on-time epoch needs no clone at its own
        // instant. An epoch far ahead of the filter (a bad tag) would move
        // the grid past every real epoch to come: it teaches nothing.
        if t_s.is_finite() && t_s <= self.t_s + MAX_GNSS_LEAD_S {
            self.learn_gnss_grid(t_s);
        }
        // A clone at the epoch's instant is its state, however late the
        // epoch (the filter may also stand exactly at that instant).
        let clone = if t_s.is_finite() { self.gnss_clone_at(t_s) } else { None };
        let states = if let Some(i) = clone {
            self.sync();
            rep.late_s = (self.t_s - t_s).max(0.0);
            EpochStates::Clone(i)
        } else if !t_s.is_finite() || t_s >= self.t_s {
            self.advance_to(t_s, Counter::GnssTimeInvalid)?;
            EpochStates::Live
        } else if !self.clock_initialised && self.t_s - t_s <= self.s.gnss_max_delay_s {
            // The very first epoch has no clone (no grid yet): it only sets
            // the clock, from the live state; the variance it is given
            // (30 m) covers the motion since the epoch.
            self.learn_gnss_grid(t_s);
            self.sync();
            let nom = self.live_gnss_nominal();
            rep.late_s = self.t_s - t_s;
            self.init_clock_states(frame, sats, &nom, &mut rep);
            return Ok(rep);
        } else {
            *self.stats.rejected.entry(Counter::GnssLate).or_default() += 1;
            self.stats.gnss_epochs_late += 1;
            return Err(InputError::GnssLate {
                t_s,
                late_s: self.t_s - t_s,
                max_s: self.s.gnss_max_delay_s,
            });
        };
        let fused = self.fuse_epoch(frame, sats, states, t_s, &mut rep);
        if let EpochStates::Clone(i) = states {
            // The clone has served its epoch.
            let o = self.gnss_clones_offset() + GNSS_CLONE_DIM * i;
            self.remove_block(o, GNSS_CLONE_DIM);
            self.gnss_clones.remove(i);
            if fused {
                self.stats.gnss_epochs_fused_late += 1;
            }
        }
        if fused {
            self.stats.gnss_epochs_fused += 1;
        }
        Ok(rep)
    }

    /// The states of an epoch at `t_s`, the columns of `P` they occupy, and
    /// for a clone its shift to the epoch's time.
    fn epoch_states(&self, states: EpochStates, t_s: f64) -> (GnssNominal, Vec<usize>, Option<ShiftF>) {
        match states {
            EpochStates::Live => (self.live_gnss_nominal(), GNSS_COLS.to_vec(), None),
            EpochStates::Clone(i) => {
                let c = self.gnss_clones[i];
                let (nom, f) = shift_clone(&c, t_s - c.t_s, &self.g_W, &self.s.imu);
                let o = self.gnss_clones_offset() + GNSS_CLONE_DIM * i;
                (nom, (o..o + GNSS_CLONE_DIM).collect(), Some(f))
            }
        }
    }

    /// The clock initialisation, the rows and the update of one epoch at
    /// `t_s` from `states`. Whether it updated.
    fn fuse_epoch(
        &mut self,
        frame: &NedFrame,
        sats: &[SatMeas],
        states: EpochStates,
        t_s: f64,
        rep: &mut GnssReport,
    ) -> bool {
        let (nom, _, _) = self.epoch_states(states, t_s);
        let differential = sats.iter().any(|s| s.differential());
        if self.clock_initialised && differential != self.gnss_differential {
            // DG4: differential codes see the clock less the base
            // corrections' common part, a few metres from the raw codes'
            // one: the bias and inter-system bias start again from this
            // epoch's median residuals; the drift, which a Doppler sees the
            // same either way, is kept.
            self.rebase_clock_bias(frame, sats, &nom);
            rep.clock_initialised = true;
        } else if self.clock_initialised && differential {
            let station = sats.iter().find_map(|s| s.correction.map(|c| c.base_station_id));
            if self.gnss_base.is_some_and(|(id, _)| Some(id) != station) {
                // Another base: its corrections' common part is another
                // station's clock and satellite set (DG4 again).
                self.rebase_clock_bias(frame, sats, &nom);
                rep.clock_initialised = true;
            } else {
                self.follow_base_reference(sats, &nom, frame);
            }
        }
        self.gnss_differential = differential;
        self.gnss_base = sats
            .iter()
            .find_map(|s| s.correction.map(|c| (c.base_station_id, c.base_tow_s)));
        if !self.init_clock_states(frame, sats, &nom, rep) {
            return false;
        }
        // Again: the clock may just have been set.
        let (nom, mut cols, f) = self.epoch_states(states, t_s);
        // DG5′: the range-bias block's random walks up to the epoch, and its
        // states for this epoch's single-point satellites; its columns
        // follow the epoch's.
        self.add_range_bias_noise(t_s);
        let preds = self.prepare_range_biases(frame, sats, &nom, t_s, rep);
        let block_o = self.range_bias_offset();
        cols.extend(block_o..block_o + self.range_bias.dim());
        let mut rows = self.gnss_rows(sats, &preds, &cols, rep);
        let pr_rejected = rep.rejected.get(&Counter::GnssPseudorangeChi2).copied().unwrap_or(0)
            + rep.rejected.get(&Counter::GnssPseudorangeOutlier).copied().unwrap_or(0);
        // D2 judges the filter by its own receiver's codes only: refused
        // differential codes may be the base's fault, and the daemon sets
        // such a base aside (single point then shows whether the filter
        // itself is wrong). A base never resets the filter.
        if !differential {
            self.monitor.push_gnss(rep.pseudoranges_used, pr_rejected as usize);
        }
        rep.differential = differential;
        if rows.is_empty() {
            self.finish_range_biases(t_s, rep);
            return false;
        }
        if let Some(f) = f {
            // A row at the epoch's time is H F on the clone (D2); the block
            // does not move in milliseconds.
            for row in rows.iter_mut() {
                let hf = nalgebra::SVector::<f64, GNSS_CLONE_DIM>::from_column_slice(&row.h).transpose() * f;
                row.h.copy_from_slice(hf.as_slice());
            }
        }
        let mut h = DMatrix::zeros(rows.len(), cols.len());
        let mut r = DVector::zeros(rows.len());
        for (i, row) in rows.iter().enumerate() {
            for k in 0..GNSS_CLONE_DIM {
                h[(i, k)] = row.h[k];
            }
            for (k, c) in row.block.iter().flatten() {
                h[(i, GNSS_CLONE_DIM + k)] += c;
            }
            r[i] = row.r;
        }
        self.ekf_update(&h, &cols, &r, false);
        // The satellites whose codes were fused keep their states.
        let first = self.range_bias.first_sat();
        for row in &rows {
            if let Some((k, _)) = row.block[1] {
                let b = &mut self.range_bias.sats[k - first];
                b.last_used_s = b.last_used_s.max(t_s);
            }
        }
        self.finish_range_biases(t_s, rep);
        self.stats.updates += 1;
        true
    }

    /// After an epoch (DG5′): the states of satellites the gate kept
    /// refusing start again, counted as `gnss_range_bias_restart`; those
    /// unused for the timeout leave.
    fn finish_range_biases(&mut self, t_s: f64, rep: &mut GnssReport) {
        for _ in 0..self.restart_refused_range_biases(t_s) {
            reject(rep, &mut self.stats, Counter::GnssRangeBiasRestart);
        }
        self.drop_stale_range_biases(t_s);
    }

    /// The epoch's predictions, and with range-bias states on (DG5′) the
    /// block's states for it: the zenith troposphere's once, and each
    /// single-point code's satellite above the mask its own, created with
    /// their priors when new.
    fn prepare_range_biases(
        &mut self,
        frame: &NedFrame,
        sats: &[SatMeas],
        nom: &GnssNominal,
        t_s: f64,
        rep: &mut GnssReport,
    ) -> Vec<SatPrediction> {
        let preds: Vec<SatPrediction> = sats
            .iter()
            .map(|s| predict_sat(frame, nom, &self.s.p_A_in_B_m, s))
            .collect();
        if !self.s.range_bias_states {
            return preds;
        }
        let mask_rad = self.s.elevation_mask_deg.to_radians();
        for (s, pred) in sats.iter().zip(&preds) {
            let single_point = s.correction.is_none() && s.pseudorange_m.is_some_and(f64::is_finite);
            if single_point && pred.elevation_rad >= mask_rad {
                self.ensure_troposphere_state(t_s);
                if self.ensure_range_bias_state(s.system, s.prn, t_s).is_none() {
                    reject(rep, &mut self.stats, Counter::GnssRangeBiasFull);
                }
            }
        }
        preds
    }

    /// The clone taken at the instant of an epoch at `t_s`, if any: within
    /// a quarter period (at most 50 ms) of it.
    fn gnss_clone_at(&self, t_s: f64) -> Option<usize> {
        let tol = self.gnss_grid.map_or(0.05, |g| (g.period_s / 4.0).min(0.05));
        self.gnss_clones
            .iter()
            .enumerate()
            .filter(|(_, c)| (c.t_s - t_s).abs() <= tol)
            .min_by(|a, b| (a.1.t_s - t_s).abs().total_cmp(&(b.1.t_s - t_s).abs()))
            .map(|(i, _)| i)
    }

    /// Learns the epoch grid from an epoch at `t_s` (§8b, see
    /// [`GnssGrid::learn`]); the next clone is due one period after the
    /// epoch, or the first instant of the grid still ahead of the filter.
    pub(super) fn learn_gnss_grid(&mut self, t_s: f64) {
        let mut g = self.gnss_grid.unwrap_or(GnssGrid::new(self.s.gnss_period_s));
        g.learn(t_s);
        // Clones already taken cover the instants up to the filter time.
        let k = ((self.t_s - g.last_epoch_s) / g.period_s).floor().max(0.0) + 1.0;
        g.next_s = g.last_epoch_s + k * g.period_s;
        self.gnss_grid = Some(g);
    }

    /// Clones the states a GNSS row involves at `t_s`, the filter's time
    /// (§8b, eq. D1): the body pose, velocity, gyro bias and clock.
    pub(super) fn take_gnss_clone(&mut self, t_s: f64) {
        let Some(meas) = self.last_meas else {
            return;
        };
        self.sync();
        // Before the range-bias block, which stays last.
        let at = self.range_bias_offset();
        self.augment(at, &GNSS_COLS, None);
        self.gnss_clones.push_back(GnssClone {
            t_s,
            nom: self.live_gnss_nominal(),
            meas,
        });
    }

    /// Marginalises the clones whose epochs are later than the delay bound.
    pub(super) fn drop_stale_gnss_clones(&mut self) {
        while self
            .gnss_clones
            .front()
            .is_some_and(|c| self.t_s - c.t_s > self.s.gnss_max_delay_s)
        {
            let at = self.gnss_clones_offset();
            self.remove_block(at, GNSS_CLONE_DIM);
            self.gnss_clones.pop_front();
        }
    }

    /// Sets the clock states the first time an epoch can (§8, eq. K4): GPS's
    /// bias and the drift from the median residuals of the first epoch with
    /// GPS codes, Galileo's inter-system bias from the first with Galileo
    /// ones. `false`: no GPS code yet, the epoch waits.
    fn init_clock_states(
        &mut self,
        frame: &NedFrame,
        sats: &[SatMeas],
        nom: &GnssNominal,
        rep: &mut GnssReport,
    ) -> bool {
        let lever = self.s.p_A_in_B_m;
        let residuals = |sys: Option<System>, bias: f64| -> Vec<f64> {
            sats.iter()
                .filter(|s| sys.is_none_or(|y| s.system == y))
                .filter_map(|s| {
                    let mut n = *nom;
                    n.clock = ClockVec::zeros();
                    n.clock[0] = bias;
                    let p = predict_sat(frame, &n, &lever, s);
                    match sys {
                        Some(_) => s.pseudorange_m.map(|z| z - p.pseudorange_m),
                        None => s.range_rate_mps.map(|z| z - p.range_rate_mps),
                    }
                })
                .collect()
        };
        if !self.clock_initialised {
            let Some(b) = median(residuals(Some(System::Gps), 0.0)) else {
                return false;
            };
            let d = median(residuals(None, 0.0)).unwrap_or(0.0);
            self.reset_clock_states(&[CLK_B, CLK_D], &[b, d], &[30.0f64.powi(2), 1.0]);
            self.clock_initialised = true;
            rep.clock_initialised = true;
        }
        for (k, &system) in ISB_SYSTEMS.iter().enumerate() {
            if self.isb_initialised[k] {
                continue;
            }
            if let Some(isb) = median(residuals(Some(system), self.clock.x)) {
                self.reset_clock_states(&[CLK_E + k], &[isb], &[30.0f64.powi(2)]);
                self.isb_initialised[k] = true;
            }
        }
        true
    }

    /// Moves the clock bias by the median GPS code residual `Δ` of this
    /// epoch, live and in every GNSS clone alike, and adds `Δ² + (1 m)²` of
    /// common variance to them; the Galileo inter-system bias is
    /// initialised again (§8c, DG4). The drift and every correlation are kept.
    fn rebase_clock_bias(&mut self, frame: &NedFrame, sats: &[SatMeas], nom: &GnssNominal) {
        let lever = self.s.p_A_in_B_m;
        let res: Vec<f64> = sats
            .iter()
            .filter(|s| s.system == System::Gps)
            .filter_map(|s| Some(s.pseudorange_m? - predict_sat(frame, nom, &lever, s).pseudorange_m))
            .collect();
        if let Some(d) = median(res) {
            self.shift_clock_bias(d, d * d + 1.0);
        }
        self.isb_initialised = [false; ISB_SYSTEMS.len()];
    }

    /// DG8: a new base epoch moves the differential codes' common part (each
    /// constellation's median correction, DG1′) by its noise and by any
    /// change of the base's satellite set, which no clock random walk
    /// explains. The step `d_X` of constellation X, seen on the satellites
    /// both base epochs share, moves every corrected code of X by `−d_X`: the
    /// clock bias takes `−d_G` and each inter-system bias `−(d_X − d_G)`,
    /// live and in every clone (as DG4), and, for the noise of the two
    /// medians it was measured with, a common variance `2·(π/2)·mean(σ_b,i²)/n`.
    fn follow_base_reference(&mut self, sats: &[SatMeas], nom: &GnssNominal, frame: &NedFrame) {
        let Some(c) = sats.iter().find_map(|s| s.correction) else {
            return;
        };
        if self.gnss_base == Some((c.base_station_id, c.base_tow_s)) {
            return;
        }
        let lever = self.s.p_A_in_B_m;
        let base_vars: Vec<f64> = sats
            .iter()
            .filter(|s| s.differential() && s.pseudorange_m.is_some())
            .map(|s| {
                let sin_el = predict_sat(frame, nom, &lever, s).elevation_rad.sin().max(0.1);
                (self.s.pseudorange_sigma_m * s.noise_scale / sin_el).powi(2)
            })
            .collect();
        if base_vars.is_empty() {
            return;
        }
        let n = base_vars.len() as f64;
        let var = 2.0 * std::f64::consts::FRAC_PI_2 * base_vars.iter().sum::<f64>() / n / n;
        let step = |system: System| {
            sats.iter()
                .filter(|s| s.system == system)
                .find_map(|s| s.correction.map(|c| c.reference_step_m))
                .filter(|d| d.is_finite())
        };
        let d_gps = step(System::Gps).unwrap_or(0.0);
        self.shift_clock_bias(-d_gps, var);
        for (k, &system) in ISB_SYSTEMS.iter().enumerate() {
            if let Some(d) = step(system) {
                self.shift_clock_state(CLK_E + k, -(d - d_gps));
            }
            self.add_clock_state_variance(CLK_E + k, var);
        }
    }

    /// A single-point code's range-bias columns and their part of the
    /// prediction (eq. DG5′): `b̂_i + m(el) T̂_z`, with `∂h/∂T_z = m(el)` and
    /// `∂h/∂b_i = 1` by their index in the block. `None` for a differential
    /// code, which has neither error (DG3), and for a satellite without a
    /// state (states off, or the block full), which DG6's weights cover.
    fn range_bias_model(&self, s: &SatMeas, pred: &SatPrediction) -> Option<BiasModel> {
        if s.correction.is_some() {
            return None;
        }
        let k = self.range_bias.slot(s.system, s.prn)?;
        let first = self.range_bias.first_sat();
        let b = self.range_bias.sats[k - first].value_m;
        // Without a troposphere state (`troposphere_sigma_m = 0`) the model
        // is taken as exact.
        Some(match self.range_bias.tropo_zenith_m {
            Some(t_z) => (b + pred.tropo_map * t_z, [Some((0, pred.tropo_map)), Some((k, 1.0))]),
            None => (b, [None, Some((k, 1.0))]),
        })
    }

    /// The gated, whitened rows of an epoch's measurements predicted by
    /// `preds`, gated with the covariance of the columns `cols` (the GNSS
    /// row order's, then the range-bias block's). Robust pre-screen (K5):
    /// each constellation's median code residual stands for its clock
    /// error, so a code far from it is an outlier whatever the clock's
    /// variance (the χ² gate alone lets a 30 m multipath code through while
    /// the clock is still uncertain).
    fn gnss_rows(
        &mut self,
        sats: &[SatMeas],
        preds: &[SatPrediction],
        cols: &[usize],
        rep: &mut GnssReport,
    ) -> Vec<GnssRow> {
        let models: Vec<_> = sats
            .iter()
            .zip(preds)
            .map(|(s, p)| self.range_bias_model(s, p))
            .collect();
        let median_res = |sys: System| {
            median(
                sats.iter()
                    .zip(preds)
                    .zip(&models)
                    .filter(|((s, _), _)| s.system == sys)
                    .filter_map(|((s, p), m)| s.pseudorange_m.map(|z| z - p.pseudorange_m - m.map_or(0.0, |m| m.0)))
                    .collect(),
            )
        };
        let medians = [
            (System::Gps, median_res(System::Gps)),
            (System::Galileo, median_res(System::Galileo)),
        ];
        let mut p_sub = DMatrix::zeros(cols.len(), cols.len());
        math::gather_block(&self.P, cols, &mut p_sub);
        let gate = cmsckf_models::stats::chi2_quantile(0.99, 1);
        let mut rows: Vec<GnssRow> = Vec::new();
        for ((s, pred), model) in sats.iter().zip(preds).zip(&models) {
            let median = medians.iter().find(|m| m.0 == s.system).and_then(|m| m.1);
            self.sat_rows(s, pred, *model, median, &p_sub, gate, rep, &mut rows);
        }
        rows
    }

    /// One satellite's pseudorange and range-rate rows (K2, K3), gated;
    /// its residuals go to the report. `model`: its range-bias part (DG5′).
    #[allow(clippy::too_many_arguments)]
    fn sat_rows(
        &mut self,
        s: &SatMeas,
        pred: &SatPrediction,
        model: Option<BiasModel>,
        median: Option<f64>,
        p_sub: &DMatrix<f64>,
        gate: f64,
        rep: &mut GnssReport,
        rows: &mut Vec<GnssRow>,
    ) {
        if pred.elevation_rad < self.s.elevation_mask_deg.to_radians() {
            reject(rep, &mut self.stats, Counter::GnssBelowMask);
            return;
        }
        let sin_el = pred.elevation_rad.sin().max(0.1);
        // DG6: errors that hold for the flight, fused once per epoch, are
        // believed `w` times per window of `correlation_window_s`: their
        // variance is scaled by the epochs in the window, at least 1.
        let period_s = self.gnss_grid.map_or(self.s.gnss_period_s, |g| g.period_s);
        let w = (self.s.gnss_correlation_window_s / period_s).max(1.0);
        let mut res = (s.prn, None, None);
        if let Some(z) = s.pseudorange_m.filter(|z| z.is_finite()) {
            // σ² = (σ_P·k / sin el)² + σ_I² [+ σ_eph² + (σ_T / sin el)²] (§8c):
            // the bracket only for a single-point code without a range-bias
            // state (DG6); with one, those errors are in h P hᵀ (DG5′), and a
            // base station's corrections remove them (DG3).
            let code_var_m2 = (self.s.pseudorange_sigma_m * s.noise_scale / sin_el).powi(2);
            let white_var_m2 = code_var_m2;
            // DG6′: the ionosphere a single-frequency code leaves (σ_I²,
            // `extra_var_m2`: unmodelled, or Klobuchar's residual) holds
            // for tens of minutes along each line of sight, and is metres:
            // it counts once per `ionosphere_window_s`.
            let w_iono = (self.s.ionosphere_window_s / period_s).max(1.0);
            let broadcast_var_m2 = self.s.broadcast_sigma_m.powi(2) + (self.s.troposphere_sigma_m / sin_el).powi(2);
            let (common_var_m2, w, screen_var_m2) = match (s.correction, model) {
                // DG5′: the broadcast and troposphere errors are states, in
                // h P hᵀ; the screen, which has no h P hᵀ, keeps one
                // epoch's share of them.
                (None, Some(_)) => (s.extra_var_m2 * w_iono / w, w, broadcast_var_m2),
                (None, None) => (broadcast_var_m2 + s.extra_var_m2 * w_iono / w, w, 0.0),
                // DG2′: a held correction carries the base's code noise
                // (the rover's own, at the same elevation over a short
                // baseline) and its drift over its age, σ_ċ² a². DG7: every
                // rover epoch it corrects shares that error, so it is
                // believed `shared_by` times, at most the window's epochs.
                // DG9′: the base's announced position is known to σ_A,
                // moving every corrected code (and so the rover) by as much
                // for the whole flight: windowed like DG6's terms.
                (Some(c), _) => {
                    let w_b = c.shared_by.clamp(1.0, w);
                    (
                        code_var_m2
                            + (self.s.dgnss_correction_rate_sigma_mps * c.age_s).powi(2)
                            + self.s.base_position_sigma_m.powi(2) * w / w_b,
                        w_b,
                        0.0,
                    )
                }
            };
            // One epoch's sigma screens and gates (a 30 m multipath code
            // stays an outlier at any rate); DG6's weighs.
            let epoch_sigma = (white_var_m2 + common_var_m2).sqrt();
            let screen_sigma = (white_var_m2 + common_var_m2 + screen_var_m2).sqrt();
            let sigma = (white_var_m2 + w * common_var_m2).sqrt();
            let (model_m, block) = model.unwrap_or((0.0, [None, None]));
            let r = z - pred.pseudorange_m - model_m;
            res.1 = Some(r);
            // The satellite's range-bias state, if any, counts the gate's
            // refusals in a row (a step of its error, DG5′).
            let first = self.range_bias.first_sat();
            let bias = block[1].map(|(k, _)| k - first);
            if median.is_some_and(|m| (r - m).abs() > OUTLIER_SIGMAS * screen_sigma) {
                reject(rep, &mut self.stats, Counter::GnssPseudorangeOutlier);
            } else if let Some(row) = gated(&pred.h_pseudorange, block, r, epoch_sigma, sigma, p_sub, gate) {
                rows.push(row);
                rep.pseudoranges_used += 1;
                if let Some(i) = bias {
                    self.range_bias.sats[i].refused_in_a_row = 0;
                }
            } else {
                reject(rep, &mut self.stats, Counter::GnssPseudorangeChi2);
                if let Some(i) = bias {
                    self.range_bias.sats[i].refused_in_a_row += 1;
                }
            }
        }
        if let Some(z) = s.range_rate_mps.filter(|z| z.is_finite()) {
            // σ² = (σ_D / sin el)² + w (σ_Dc / sin el)² (DG6).
            let white_var = (self.s.range_rate_sigma_mps / sin_el).powi(2);
            let corr_var = (self.s.range_rate_correlated_sigma_mps / sin_el).powi(2);
            let epoch_sigma = (white_var + corr_var).sqrt();
            let sigma = (white_var + w * corr_var).sqrt();
            let r = z - pred.range_rate_mps;
            res.2 = Some(r);
            if let Some(row) = gated(&pred.h_range_rate, [None, None], r, epoch_sigma, sigma, p_sub, gate) {
                rows.push(row);
                rep.range_rates_used += 1;
            } else {
                reject(rep, &mut self.stats, Counter::GnssRangeRateChi2);
            }
        }
        rep.residuals.push(res);
    }
}

impl GnssGrid {
    /// A grid of `default_period_s` until two epochs are seen.
    fn new(default_period_s: f64) -> Self {
        GnssGrid {
            last_epoch_s: f64::NEG_INFINITY,
            period_s: default_period_s,
            measured: false,
            longer: 0,
            longer_min_s: f64::INFINITY,
            next_s: f64::INFINITY,
        }
    }

    /// Learns from an epoch at `t_s`: the period is the smallest spacing
    /// seen (a dropped epoch doubles one spacing, never halves it), until
    /// [`GNSS_PERIOD_RELEARN`] spacings in a row are all longer by half again
    /// (a stray early epoch, or a receiver that slowed down: the period is
    /// then the shortest of them).
    fn learn(&mut self, t_s: f64) {
        let spacing = t_s - self.last_epoch_s;
        if spacing.is_finite() && spacing > 1e-3 {
            // At most 20 Hz: a bogus tag cannot make the grid dense.
            let spacing = spacing.max(MIN_GNSS_PERIOD_S);
            if self.measured && spacing > 1.5 * self.period_s {
                self.longer += 1;
                self.longer_min_s = self.longer_min_s.min(spacing);
                if self.longer >= GNSS_PERIOD_RELEARN {
                    self.period_s = self.longer_min_s;
                    (self.longer, self.longer_min_s) = (0, f64::INFINITY);
                }
            } else {
                self.period_s = if self.measured {
                    self.period_s.min(spacing)
                } else {
                    spacing
                };
                (self.longer, self.longer_min_s) = (0, f64::INFINITY);
            }
            self.measured = true;
        }
        if t_s > self.last_epoch_s {
            self.last_epoch_s = t_s;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimator::gnss_model::tests::sat_of;
    use crate::estimator::propagate::tests::state;

    /// §8c, eq. DG5′: the block columns of a single-point code's row
    /// against central differences of the filter's own model of it
    /// (`range_bias_model`), the block's estimates moved through the
    /// correction path (`inject`), for every constellation; a differential
    /// code has none.
    #[test]
    fn range_bias_columns_match_finite_differences_of_the_model() {
        let s = crate::config::Config::default().estimator_settings();
        let mut est = Estimator::new(s, 0.0, state(), &(crate::estimator::Mat15::identity() * 0.01));
        let nom = GnssNominal {
            imu: state(),
            gyro_radps: Vector3::new(0.1, -0.2, 0.3),
            clock: ClockVec::zeros(),
        };
        let lever = Vector3::new(0.2, -0.1, -0.2);
        est.ensure_troposphere_state(0.0);
        for (i, system) in [System::Gps, System::Galileo, System::Glonass, System::BeiDou]
            .into_iter()
            .enumerate()
        {
            let (frame, mut sat) = sat_of(system);
            sat.prn = 3 + i as u8;
            est.ensure_range_bias_state(system, sat.prn, 0.0);
            let n = est.P.nrows();
            let o = est.range_bias_offset();
            // Estimates away from zero, as in flight.
            let mut dx = DVector::zeros(n);
            dx[o] = 0.15;
            dx[n - 1] = 0.4;
            est.inject_range_bias(&dx);
            let pred = predict_sat(&frame, &nom, &lever, &sat);
            let (_, cols) = est
                .range_bias_model(&sat, &pred)
                .expect("a single-point code with its state");
            let h = 1e-3;
            for (k, c) in cols.iter().flatten() {
                let mut step = DVector::zeros(n);
                step[o + k] = h;
                let mut plus = est.clone();
                plus.inject_range_bias(&step);
                step[o + k] = -h;
                let mut minus = est.clone();
                minus.inject_range_bias(&step);
                let model = |e: &Estimator| e.range_bias_model(&sat, &pred).map_or(f64::NAN, |m| m.0);
                let fd = (model(&plus) - model(&minus)) / (2.0 * h);
                assert!((fd - c).abs() < 1e-9, "{system:?} block column {k}: fd {fd} vs {c}");
            }
            assert_eq!(cols.iter().flatten().count(), 2, "{system:?}: T_z and b_i");
            let mut differential = sat;
            differential.correction = Some(cmsckf_models::gnss::CodeCorrection {
                base_station_id: 1,
                base_tow_s: 0.0,
                age_s: 0.5,
                shared_by: 1.0,
                reference_step_m: 0.0,
            });
            assert!(est.range_bias_model(&differential, &pred).is_none());
        }
    }

    #[test]
    fn the_epoch_period_is_learnt_and_relearnt() {
        // A 1 Hz receiver: the period is 1 s, and a dropped epoch (one 2 s
        // spacing) leaves it so.
        let mut g = GnssGrid::new(1.0);
        for t in [10.0, 11.0, 12.0, 14.0, 15.0, 16.0] {
            g.learn(t);
        }
        assert_eq!(g.period_s, 1.0);
        // A stray epoch 50 ms after another: the period is 50 ms at once
        // (the grid must not miss a faster receiver's epochs) ...
        g.learn(16.05);
        assert!((g.period_s - 0.05).abs() < 1e-9);
        // ... and 1 s again after five 1 s spacings in a row.
        for k in 1..=4 {
            g.learn(16.05 + k as f64);
            assert!((g.period_s - 0.05).abs() < 1e-9, "after {k}");
        }
        g.learn(21.05);
        assert!((g.period_s - 1.0).abs() < 1e-9, "{}", g.period_s);
        // A receiver that goes from 10 Hz to 2 Hz is followed.
        let mut g = GnssGrid::new(1.0);
        for k in 0..20 {
            g.learn(k as f64 * 0.1);
        }
        assert!((g.period_s - 0.1).abs() < 1e-9);
        for k in 1..=5 {
            g.learn(1.9 + k as f64 * 0.5);
        }
        assert!((g.period_s - 0.5).abs() < 1e-9, "{}", g.period_s);
    }
}
