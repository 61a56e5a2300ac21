//! GPS and Galileo constellations (`constellation.rs`) and the receiver model.
//!
//! GPS is 31 satellites in six planes (55° inclination, semi-major axis
//! 26 559.7 km); Galileo is a Walker 24/3/1 (56°, 29 600 km). Both are
//! described by broadcast-ephemeris parameters, the fields RTCM 1019 and 1046
//! carry, computed per IS-GPS-200 Table 20-IV, which the Galileo OS SIS ICD
//! §5.1.1 repeats with Galileo's own GM. The broadcast orbits and clocks are
//! not perfect: each satellite's range carries a constant error `E_sv`
//! (`gnss.broadcast_error_m`, 0.6 m σ by default, GPS's signal-in-space
//! range error), the same for every receiver, so a base station nearby sees
//! it too and differential GNSS removes it.
//!
//! The receiver measures at its antenna `A`, not at the IMU: a real antenna
//! sits on a mast, `p_A_in_B` away (config `gnss.p_A_in_B_m`), so
//! `r_A = p_B_in_W + R_W_B p_A_in_B` and `v_A = v_B_in_W + R_W_B (ω_B × p_A_in_B)`
//! (in the world frame, then ECEF).
//!
//! Pseudorange at reception time `t_rx` (GPS time):
//! `P = ρ + c·δt_rx − c·δt_sv(t_tx) + E_sv + T (1 + f_T) + I + ε (+ multipath)`,
//! `f_T` the fraction of the troposphere a receiver's model misses
//! (`gnss.troposphere_error_frac`, 5 %), with the
//! geometric range `ρ = |Rz(ωe τ) r_sat(t_tx) − r_A|`, `t_tx = t_rx − τ` and
//! `τ = ρ/c` the signal flight time: `Rz(ωe τ)` carries the satellite's
//! position at transmission into the ECEF frame of reception (the Sagnac
//! correction). `δt_sv` includes the relativistic term and `−TGD` (L1 C/A),
//! `T` is the Saastamoinen troposphere and `I` an optional ionospheric delay.
//! Galileo pseudoranges also carry the receiver's inter-system bias
//! (GPS–Galileo time offset plus receiver hardware delays), a constant of the
//! flight.
//!
//! Pseudorange rate: the exact time derivative of that model,
//! `Ṗ = ρ̇ + c·δṫ_rx − c·δṫ_sv·(1 − τ̇) + Ṫ − İ + ε̇`. Differentiating ρ
//! through τ(t) gives, with `u` the unit vector from antenna to satellite,
//! `ρ̇ = u·(Rz v_sat − v_A) / (1 − u·(ωe Rz′ r_sat − Rz v_sat)/c)`: the
//! denominator holds the flight-time and Sagnac-rate terms (several mm/s),
//! which `u·(Rz v_sat − v_A)` alone misses. `Ṫ` and `İ` are central
//! differences along the geometry's motion. The ionosphere enters with the
//! carrier-phase sign (`−İ`), because a receiver's range rate is a Doppler,
//! a phase rate, and MSM7 sends it as one.
//!
//! A base station (`gnss.base`) is a second receiver of the same kind at a
//! fixed point, with its own clock and noise and an open sky; an urban
//! canyon (`gnss.canyon_s`) leaves the rover only its highest few
//! satellites for a while.
//!
//! A receiver reports an epoch some time after it: [`GnssEpoch::t_s`] is
//! the epoch's instant and [`GnssEpoch::t_delivered_s`] when it reaches the
//! host, both on the IMU clock ([`GnssEpoch::delivered`] sets the latency;
//! [`crate::dataset`] draws it per epoch).

use nalgebra::{Matrix3, Vector3};
use rand::Rng;
use rand_distr::StandardNormal;

mod constellation;

pub use constellation::{constellation, galileo_constellation};

use crate::config::GnssSimConfig;
use crate::trajectory::TruthSample;
use cmsckf_models::geodesy::{ecef_to_llh, elevation_azimuth, NedFrame, C_MPS, OMEGA_E_RADPS};
use cmsckf_models::gnss::rtcm_eph::quantise;
use cmsckf_models::gnss::{saastamoinen_m, BroadcastEphemeris, SatState, System, WEEK_S};

/// One satellite's observation.
#[derive(Clone, Debug, PartialEq)]
pub struct SatObs {
    pub system: System,
    pub prn: u8,
    /// L1 C/A (GPS) or E1 (Galileo) pseudorange (m).
    pub pseudorange_m: f64,
    /// Pseudorange rate (m/s); positive when the range grows.
    pub pseudorange_rate_mps: f64,
    /// Carrier-to-noise density (dB-Hz).
    pub cn0_dbhz: f64,
    /// True elevation (deg), for inspection only.
    pub elevation_deg: f64,
    /// Whether a multipath outlier was added (truth, for tests).
    pub multipath: bool,
    /// The broadcast orbit and clock error on this line of sight (m, truth
    /// for tests: what a filter's range-bias state estimates).
    pub broadcast_error_m: f64,
}

/// One receiver epoch.
#[derive(Clone, Debug, PartialEq)]
pub struct GnssEpoch {
    /// The epoch's instant: the true reception time, on the IMU clock (s).
    pub t_s: f64,
    /// When the epoch reaches the host, on the IMU clock (s): `t_s` plus the
    /// receiver's and the link's latency.
    pub t_delivered_s: f64,
    pub week: u32,
    pub tow_s: f64,
    pub sats: Vec<SatObs>,
    /// True receiver clock bias `c·δt` (m) and drift `c·δṫ` (m/s). The
    /// epoch's `tow_s` is the receiver's tag, GPS time + δt.
    pub clock_bias_m: f64,
    pub clock_drift_mps: f64,
    /// True Galileo − GPS inter-system bias (m).
    pub isb_galileo_m: f64,
}

impl GnssEpoch {
    /// This epoch as delivered `latency_s` after its instant.
    pub fn delivered(mut self, latency_s: f64) -> Self {
        self.t_delivered_s = self.t_s + latency_s;
        self
    }
}

/// Per-satellite breakdown of a simulated pseudorange (for tests).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RangeTerms {
    pub geometric_m: f64,
    pub sat_clock_m: f64,
    pub troposphere_m: f64,
    pub ionosphere_m: f64,
}

/// Receiver model: clock random walk and measurement noise.
pub struct GnssModel {
    pub cfg: GnssSimConfig,
    pub frame: NedFrame,
    pub ephemerides: Vec<BroadcastEphemeris>,
    clock_bias_m: f64,
    clock_drift_mps: f64,
    last_t_s: Option<f64>,
    /// Noise for Galileo's measurements, its own stream so that GPS's draws
    /// do not depend on whether Galileo is simulated.
    gal_rng: rand_chacha::ChaCha8Rng,
    /// Each satellite's broadcast orbit and clock error on the line of sight
    /// (m), in `ephemerides`' order: the same for every receiver.
    sis_error_m: Vec<f64>,
    /// A base station's receiver: open sky (no canyon).
    open_sky: bool,
}

impl GnssModel {
    pub fn new<R: Rng>(cfg: &GnssSimConfig, rng: &mut R) -> Self {
        let frame = NedFrame::from_llh_deg(cfg.origin_llh[0], cfg.origin_llh[1], cfg.origin_llh[2]);
        Self {
            cfg: cfg.clone(),
            frame,
            // Quantised through RTCM 1019 and 1046, so decoders see the true
            // orbits.
            ephemerides: constellation(cfg.start_week, cfg.start_tow_s, rng)
                .into_iter()
                .chain(if cfg.galileo {
                    galileo_constellation(cfg.start_week, cfg.start_tow_s)
                } else {
                    Vec::new()
                })
                .map(|e| quantise(&e))
                .collect(),
            clock_bias_m: cfg.clock_bias0_m,
            clock_drift_mps: cfg.clock_drift0_mps,
            last_t_s: None,
            gal_rng: rand::SeedableRng::seed_from_u64(cfg.start_week as u64 ^ 0x6a1),
            sis_error_m: Vec::new(),
            open_sky: false,
        }
        .with_broadcast_errors()
    }

    /// Draws each satellite's broadcast error from its own stream, seeded by
    /// the week; a simulated flight (`Dataset`) draws its own instead
    /// ([`GnssModel::for_flight`]).
    fn with_broadcast_errors(self) -> Self {
        let seed = self.cfg.start_week as u64 ^ 0x515e;
        self.with_broadcast_errors_from(seed)
    }

    /// This receiver on the flight `seed`: each flight draws its own
    /// broadcast errors and Galileo noise, as flights on different days
    /// meet different errors (drawn from the week alone, every seed of an
    /// evaluation shared one draw, and a mean over seeds averaged nothing
    /// of them). The GPS noise and the orbits come from the flight's stream
    /// already; a base station beside this receiver keeps its errors.
    pub fn for_flight(mut self, seed: u64) -> Self {
        let mixed = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ self.cfg.start_week as u64;
        self.gal_rng = rand::SeedableRng::seed_from_u64(mixed ^ 0x6a1);
        self.with_broadcast_errors_from(mixed ^ 0x515e)
    }

    fn with_broadcast_errors_from(mut self, seed: u64) -> Self {
        let mut rng: rand_chacha::ChaCha8Rng = rand::SeedableRng::seed_from_u64(seed);
        self.sis_error_m = self
            .ephemerides
            .iter()
            .map(|_| rng.sample::<f64, _>(StandardNormal) * self.cfg.broadcast_error_m)
            .collect();
        self
    }

    /// The broadcast (orbit and clock) range error of a satellite (m).
    pub fn broadcast_error_m(&self, system: System, prn: u8) -> f64 {
        self.ephemerides
            .iter()
            .position(|e| (e.system, e.prn) == (system, prn))
            .map_or(0.0, |i| self.sis_error_m[i])
    }

    /// A base station's receiver beside this one: the same satellites and
    /// broadcast errors, its own clock (`clock0`: bias m, drift m/s) and
    /// noise streams, open sky.
    pub fn base_station(&self, clock0: (f64, f64), noise_seed: u64) -> Self {
        Self {
            cfg: self.cfg.clone(),
            frame: self.frame,
            ephemerides: self.ephemerides.clone(),
            clock_bias_m: clock0.0,
            clock_drift_mps: clock0.1,
            last_t_s: None,
            gal_rng: rand::SeedableRng::seed_from_u64(noise_seed ^ 0x6a1),
            sis_error_m: self.sis_error_m.clone(),
            open_sky: true,
        }
    }

    /// The epoch a static receiver at `p_in_W_m` (NED, m) tags `t_tag_s`.
    pub fn static_epoch_at<R: Rng>(&mut self, p_in_W_m: &Vector3<f64>, t_tag_s: f64, rng: &mut R) -> GnssEpoch {
        self.advance_clock(t_tag_s, rng);
        let t_s = t_tag_s - self.clock_bias_m / C_MPS;
        let r = self.frame.to_ecef(p_in_W_m);
        let mut ep = self.measure_at(t_s, &r, &Vector3::zeros(), rng);
        let (week, tow) = self.gps_time(t_tag_s);
        ep.week = week;
        ep.tow_s = tow;
        ep
    }

    /// GPS week and time of week at simulation time `t_s`.
    pub fn gps_time(&self, t_s: f64) -> (u32, f64) {
        let tow = self.cfg.start_tow_s + t_s;
        let weeks = (tow / WEEK_S).floor();
        (self.cfg.start_week + weeks as u32, tow - weeks * WEEK_S)
    }

    /// The terms of the pseudorange from `r_rx` to `eph` received at `tow`:
    /// signal flight time solved by fixed-point iteration with the Sagnac
    /// rotation applied to the satellite position.
    pub fn range_terms(
        &self,
        eph: &BroadcastEphemeris,
        tow_rx_s: f64,
        r_rx: &Vector3<f64>,
    ) -> (RangeTerms, SatState, Vector3<f64>) {
        let mut tau = 0.075;
        let mut st = eph.state(tow_rx_s - tau);
        let mut r_sat = st.r_ecef_m;
        for _ in 0..5 {
            st = eph.state(tow_rx_s - tau);
            r_sat = rot_z(OMEGA_E_RADPS * tau) * st.r_ecef_m;
            tau = (r_sat - r_rx).norm() / C_MPS;
        }
        let (troposphere_m, ionosphere_m) = self.atmosphere_m(r_rx, &r_sat);
        (
            RangeTerms {
                geometric_m: (r_sat - r_rx).norm(),
                sat_clock_m: C_MPS * st.dt_s,
                troposphere_m,
                ionosphere_m,
            },
            st,
            r_sat,
        )
    }

    /// Tropospheric and ionospheric delays (m) between the antenna at `r_rx`
    /// and the satellite at `r_sat` (both ECEF).
    fn atmosphere_m(&self, r_rx: &Vector3<f64>, r_sat: &Vector3<f64>) -> (f64, f64) {
        let (lat, _, h) = ecef_to_llh(r_rx);
        let (el, _) = elevation_azimuth(r_rx, r_sat);
        let iono = if self.cfg.ionosphere {
            // Klobuchar-like obliquity on a 5 m vertical daytime delay.
            let el_sc = el / std::f64::consts::PI;
            5.0 * (1.0 + 16.0 * (0.53 - el_sc).powi(3))
        } else {
            0.0
        };
        (saastamoinen_m(lat, h, el), iono)
    }

    /// Position and velocity of the antenna in ECEF (m, m/s) for the body
    /// truth `truth`: `p_B + R_W_B p_A_in_B` and `v_B + R_W_B (ω_B × p_A_in_B)`.
    pub fn antenna_ecef(&self, truth: &TruthSample) -> (Vector3<f64>, Vector3<f64>) {
        let p_A_in_B = Vector3::from(self.cfg.p_A_in_B_m);
        let p_A_in_W = truth.p_B_in_W + truth.q_W_B * p_A_in_B;
        let v_A_in_W = truth.v_B_in_W + truth.q_W_B * truth.w_B.cross(&p_A_in_B);
        (self.frame.to_ecef(&p_A_in_W), self.frame.R_ecef_ned * v_A_in_W)
    }

    /// The rate of the pseudorange of [`Self::range_terms`] without the
    /// receiver's clock (m/s): the exact derivative of the geometric range
    /// through the flight time and the Sagnac rotation, the satellite clock's
    /// drift at transmission, and the atmosphere's change, the ionosphere
    /// with the carrier-phase sign (see the module doc). `st` and `r_sat` are
    /// what `range_terms` returned for the antenna at `r_rx` moving at `v_rx`.
    pub fn range_rate_mps(
        &self,
        terms: &RangeTerms,
        st: &SatState,
        r_sat: &Vector3<f64>,
        r_rx: &Vector3<f64>,
        v_rx: &Vector3<f64>,
    ) -> f64 {
        let rho = terms.geometric_m;
        let u = (r_sat - r_rx) / rho;
        let rz = rot_z(OMEGA_E_RADPS * rho / C_MPS);
        let v_sat_rot = rz * st.v_ecef_mps;
        // d/dτ of Rz(ωe τ) r_sat: ωe Rz (r_y, −r_x, 0).
        let r = &st.r_ecef_m;
        let sagnac_rate = rz * Vector3::new(r.y, -r.x, 0.0) * OMEGA_E_RADPS;
        let rho_dot = u.dot(&(v_sat_rot - v_rx)) / (1.0 - u.dot(&(sagnac_rate - v_sat_rot)) / C_MPS);
        let tau_dot = rho_dot / C_MPS;
        // The satellite's apparent velocity in the frame of reception.
        let s_dot = sagnac_rate * tau_dot + v_sat_rot * (1.0 - tau_dot);
        let h = 0.5;
        let (ta, ia) = self.atmosphere_m(&(r_rx - v_rx * h), &(r_sat - s_dot * h));
        let (tb, ib) = self.atmosphere_m(&(r_rx + v_rx * h), &(r_sat + s_dot * h));
        let (t_dot, i_dot) = ((tb - ta) / (2.0 * h), (ib - ia) / (2.0 * h));
        rho_dot - C_MPS * st.ddt * (1.0 - tau_dot) + t_dot * (1.0 + self.cfg.troposphere_error_frac) - i_dot
    }

    /// Advances the receiver clock to `t_s` (two-state random walk).
    fn advance_clock<R: Rng>(&mut self, t_s: f64, rng: &mut R) {
        if let Some(t0) = self.last_t_s {
            let dt = (t_s - t0).max(0.0);
            let nb: f64 = rng.sample(StandardNormal);
            let nd: f64 = rng.sample(StandardNormal);
            self.clock_bias_m += self.clock_drift_mps * dt + nb * self.cfg.clock_bias_rw_m_per_sqrt_s * dt.sqrt();
            self.clock_drift_mps += nd * self.cfg.clock_drift_rw_mps_per_sqrt_s * dt.sqrt();
        }
        self.last_t_s = Some(t_s);
    }

    /// The epoch a receiver tags `t_tag_s` (receiver time, a whole number of
    /// milliseconds): measured at the true time `t_tag − δt`.
    pub fn epoch_at<R: Rng>(&mut self, traj: &crate::trajectory::Trajectory, t_tag_s: f64, rng: &mut R) -> GnssEpoch {
        self.advance_clock(t_tag_s, rng);
        let truth = traj.sample(t_tag_s - self.clock_bias_m / C_MPS);
        let mut ep = self.measure(&truth, rng);
        let (week, tow) = self.gps_time(t_tag_s);
        ep.week = week;
        ep.tow_s = tow;
        ep
    }

    /// Observes all satellites above the mask from `truth`, the receiver
    /// clock advanced to the truth's time.
    pub fn epoch<R: Rng>(&mut self, truth: &TruthSample, rng: &mut R) -> GnssEpoch {
        self.advance_clock(truth.t_s, rng);
        self.measure(truth, rng)
    }

    fn measure<R: Rng>(&mut self, truth: &TruthSample, gps_rng: &mut R) -> GnssEpoch {
        let (r_rx, v_rx) = self.antenna_ecef(truth);
        self.measure_at(truth.t_s, &r_rx, &v_rx, gps_rng)
    }

    /// The satellites a receiver at `r_rx` sees at `t_s`: those above the
    /// mask, and inside the urban canyon (`canyon_s`) only the
    /// `canyon_keep` highest.
    fn visible(&self, t_s: f64, tow: f64, r_rx: &Vector3<f64>) -> Vec<usize> {
        let mut v: Vec<(usize, f64)> = self
            .ephemerides
            .iter()
            .enumerate()
            .filter_map(|(i, eph)| {
                let (_, _, r_sat) = self.range_terms(eph, tow, r_rx);
                let (el, _) = elevation_azimuth(r_rx, &r_sat);
                (el.to_degrees() >= self.cfg.elevation_mask_deg).then_some((i, el))
            })
            .collect();
        let c = &self.cfg.canyon_s;
        if !self.open_sky && c.len() == 2 && (c[0]..c[1]).contains(&t_s) {
            v.sort_by(|a, b| b.1.total_cmp(&a.1));
            v.truncate(self.cfg.canyon_keep);
            v.sort_by_key(|x| x.0);
        }
        v.into_iter().map(|(i, _)| i).collect()
    }

    fn measure_at<R: Rng>(&mut self, t_s: f64, r_rx: &Vector3<f64>, v_rx: &Vector3<f64>, gps_rng: &mut R) -> GnssEpoch {
        let (week, tow) = self.gps_time(t_s);
        let (r_rx, v_rx) = (*r_rx, *v_rx);
        let mut sats = Vec::new();
        for i in self.visible(t_s, tow, &r_rx) {
            let eph = &self.ephemerides[i];
            let (terms, st, r_sat) = self.range_terms(eph, tow, &r_rx);
            let (el, _) = elevation_azimuth(&r_rx, &r_sat);
            let (rng, isb): (&mut dyn rand::RngCore, f64) = match eph.system {
                System::Galileo => (&mut self.gal_rng, self.cfg.isb_galileo_m),
                // The simulator flies GPS and Galileo only.
                System::Gps | System::Glonass | System::BeiDou | System::Qzss => (&mut *gps_rng, 0.0),
            };
            let sin_el = el.sin().max(0.1);
            let n_pr: f64 = rng.sample(StandardNormal);
            let n_prr: f64 = rng.sample(StandardNormal);
            let multipath = rng.random::<f64>() < self.cfg.multipath_prob;
            let mp = if multipath {
                self.cfg.multipath_m * if rng.random::<bool>() { 1.0 } else { -1.0 }
            } else {
                0.0
            };
            let rate = self.range_rate_mps(&terms, &st, &r_sat, &r_rx, &v_rx);
            sats.push(SatObs {
                system: eph.system,
                prn: eph.prn,
                pseudorange_m: terms.geometric_m + self.clock_bias_m + isb - terms.sat_clock_m
                    + terms.troposphere_m * (1.0 + self.cfg.troposphere_error_frac)
                    + self.sis_error_m[i]
                    + terms.ionosphere_m
                    + mp
                    + n_pr * self.cfg.pseudorange_noise_m / sin_el,
                pseudorange_rate_mps: rate
                    + self.clock_drift_mps
                    + n_prr * self.cfg.pseudorange_rate_noise_mps / sin_el,
                cn0_dbhz: (35.0 + 15.0 * sin_el).round(),
                elevation_deg: el.to_degrees(),
                multipath,
                broadcast_error_m: self.sis_error_m[i],
            });
        }
        GnssEpoch {
            t_s,
            t_delivered_s: t_s,
            week,
            // A receiver tags epochs with its own clock: GPS time + δt.
            tow_s: tow + self.clock_bias_m / C_MPS,
            sats,
            clock_bias_m: self.clock_bias_m,
            clock_drift_mps: self.clock_drift_mps,
            isb_galileo_m: self.cfg.isb_galileo_m,
        }
    }
}

/// Rotation about the ECEF z axis by `a` (rad), applied to a vector expressed
/// in the ECEF frame of an earlier time (Sagnac correction).
pub fn rot_z(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0)
}

#[cfg(test)]
mod tests;
