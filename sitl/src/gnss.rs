//! GPS and Galileo constellations and the receiver model.
//!
//! GPS is 31 satellites in six planes (55° inclination, semi-major axis
//! 26 559.7 km); Galileo is a Walker 24/3/1 (56°, 29 600 km). Both are
//! described by broadcast-ephemeris parameters, the fields RTCM 1019 and 1046
//! carry. The satellites' true orbits are exactly those ephemerides (no
//! ephemeris error is simulated), computed per IS-GPS-200 Table 20-IV, which
//! the Galileo OS SIS ICD §5.1.1 repeats with Galileo's own GM.
//!
//! Pseudorange at reception time `t_rx` (GPS time):
//! `P = |Rz(ωe τ) r_sat(t_rx − τ) − r_rx| + c·δt_rx − c·δt_sv(t_tx) + T + I + ε (+ multipath)`
//! where τ is the signal flight time, `Rz(ωe τ)` is the Sagnac (earth
//! rotation) correction, `δt_sv` includes the relativistic term and `−TGD`
//! (L1 C/A), `T` is the Saastamoinen troposphere and `I` an optional
//! ionospheric delay. Galileo pseudoranges also carry the receiver's
//! inter-system bias (GPS–Galileo time offset plus receiver hardware
//! delays), a constant of the flight. Pseudorange rate:
//! `Ṗ = (v_sat − v_rx)·u + c·δṫ_rx − c·δṫ_sv + ε̇` with `u` the unit vector
//! from receiver to satellite.

use nalgebra::{Matrix3, Vector3};
use rand::Rng;
use rand_distr::StandardNormal;

use crate::config::GnssSimConfig;
use crate::trajectory::TruthSample;
use cmsckf_models::geodesy::{ecef_to_llh, elevation_azimuth, NedFrame, C_MPS, OMEGA_E_RADPS};
use cmsckf_models::gnss::rtcm_eph::quantise;
use cmsckf_models::gnss::{saastamoinen_m, BroadcastEphemeris, SatState, System, WEEK_S};

/// Generates the 31-satellite constellation valid around `tow_s` of `week`.
pub fn constellation<R: Rng>(week: u32, tow_s: f64, rng: &mut R) -> Vec<BroadcastEphemeris> {
    // toe on the 2-hour grid, as the control segment uploads.
    let toe = (tow_s / 7200.0).round() * 7200.0;
    let toe = toe.min(WEEK_S - 7200.0);
    let slots_per_plane = [6, 5, 5, 5, 5, 5];
    let mut out = Vec::new();
    let mut prn = 1u8;
    for (plane, &n) in slots_per_plane.iter().enumerate() {
        let raan = (plane as f64 * 60.0 + 17.0).to_radians() + rng.random_range(-0.02..0.02);
        for slot in 0..n {
            let u_deg = slot as f64 * 360.0 / n as f64 + plane as f64 * 15.0;
            let normal = |rng: &mut R| -> f64 { rng.sample(StandardNormal) };
            let e = rng.random_range(0.002..0.02);
            let omega = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
            out.push(BroadcastEphemeris {
                system: System::Gps,
                prn,
                week,
                iode: prn as u16 * 7 % 256,
                iodc: prn as u16 * 7 % 256,
                toc_s: toe,
                af0_s: normal(rng) * 2e-4,
                af1: normal(rng) * 3e-12,
                af2_per_s: 0.0,
                toe_s: toe,
                sqrt_a: 5153.65 + normal(rng) * 0.3,
                e,
                m0_rad: wrap_pi(u_deg.to_radians() - omega),
                delta_n_radps: 4.5e-9 + normal(rng) * 5e-10,
                omega0_rad: wrap_pi(raan),
                omega_dot_radps: -8.1e-9 + normal(rng) * 2e-10,
                i0_rad: (55.0f64 + normal(rng) * 0.8).to_radians(),
                idot_radps: normal(rng) * 2e-10,
                omega_rad: omega,
                cuc_rad: normal(rng) * 2e-6,
                cus_rad: normal(rng) * 2e-6,
                crc_m: 200.0 + normal(rng) * 40.0,
                crs_m: normal(rng) * 40.0,
                cic_rad: normal(rng) * 1e-7,
                cis_rad: normal(rng) * 1e-7,
                tgd_s: normal(rng) * 5e-9,
                health: 0,
                ura_index: 0,
                fit_interval_4h: false,
            });
            prn += 1;
        }
    }
    out
}

/// The 24-satellite Galileo constellation (Walker 24/3/1: three planes at
/// 56°, eight slots each, a = 29 600 km) valid around `tow_s` of GPS week
/// `week`. It is deterministic: no random draws, so adding Galileo leaves
/// every GPS draw of a seed unchanged.
pub fn galileo_constellation(week: u32, tow_s: f64) -> Vec<BroadcastEphemeris> {
    // Galileo uploads on a 10-minute grid; RTCM carries toe in 60 s units.
    let toe = ((tow_s / 600.0).round() * 600.0).min(WEEK_S - 600.0);
    let mut out = Vec::with_capacity(24);
    for plane in 0..3u8 {
        for slot in 0..8u8 {
            let k = plane * 8 + slot;
            // A fixed pseudo-random spread per satellite, in [−1, 1].
            let wob = |j: u8| ((k as f64 * 12.9898 + j as f64 * 78.233).sin() * 43_758.545).fract();
            let u_deg = slot as f64 * 45.0 + plane as f64 * 15.0;
            let omega = wob(1) * std::f64::consts::PI;
            out.push(BroadcastEphemeris {
                system: System::Galileo,
                prn: k + 1,
                week,
                iode: (k as u16 * 11 + 3) % 1024,
                iodc: 0,
                toc_s: toe,
                af0_s: wob(2) * 3e-4,
                af1: wob(3) * 5e-12,
                af2_per_s: 0.0,
                toe_s: toe,
                sqrt_a: 5440.6 + wob(4) * 0.2,
                e: 2e-4 + 3e-4 * wob(5).abs(),
                m0_rad: wrap_pi(u_deg.to_radians() - omega),
                delta_n_radps: 3.0e-9 + wob(6) * 3e-10,
                omega0_rad: wrap_pi((plane as f64 * 120.0 + 40.0).to_radians()),
                omega_dot_radps: -5.5e-9 + wob(7) * 1e-10,
                i0_rad: (56.0 + wob(8) * 0.3f64).to_radians(),
                idot_radps: wob(9) * 2e-10,
                omega_rad: omega,
                cuc_rad: wob(10) * 2e-6,
                cus_rad: wob(11) * 2e-6,
                crc_m: 150.0 + wob(12) * 40.0,
                crs_m: wob(13) * 40.0,
                cic_rad: wob(14) * 1e-7,
                cis_rad: wob(15) * 1e-7,
                tgd_s: wob(16) * 3e-9,
                health: 0,
                // SISA index 107: 3.12 m.
                ura_index: 107,
                fit_interval_4h: false,
            });
        }
    }
    out
}

fn wrap_pi(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    (a + std::f64::consts::PI).rem_euclid(t) - std::f64::consts::PI
}

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
}

/// One receiver epoch.
#[derive(Clone, Debug, PartialEq)]
pub struct GnssEpoch {
    pub t_s: f64,
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
        }
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
        let (lat, _, h) = ecef_to_llh(r_rx);
        let (el, _) = elevation_azimuth(r_rx, &r_sat);
        let iono = if self.cfg.ionosphere {
            // Klobuchar-like obliquity on a 5 m vertical daytime delay.
            let el_sc = el / std::f64::consts::PI;
            5.0 * (1.0 + 16.0 * (0.53 - el_sc).powi(3))
        } else {
            0.0
        };
        (
            RangeTerms {
                geometric_m: (r_sat - r_rx).norm(),
                sat_clock_m: C_MPS * st.dt_s,
                troposphere_m: saastamoinen_m(lat, h, el),
                ionosphere_m: iono,
            },
            st,
            r_sat,
        )
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
        let (week, tow) = self.gps_time(truth.t_s);
        let r_rx = self.frame.to_ecef(&truth.p_B_in_W);
        let v_rx = self.frame.R_ecef_ned * truth.v_B_in_W;
        let mut sats = Vec::new();
        for eph in &self.ephemerides {
            let (terms, st, r_sat) = self.range_terms(eph, tow, &r_rx);
            let (el, _) = elevation_azimuth(&r_rx, &r_sat);
            if el.to_degrees() < self.cfg.elevation_mask_deg {
                continue;
            }
            let (rng, isb): (&mut dyn rand::RngCore, f64) = match eph.system {
                System::Gps => (&mut *gps_rng, 0.0),
                System::Galileo => (&mut self.gal_rng, self.cfg.isb_galileo_m),
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
            let u = (r_sat - r_rx) / terms.geometric_m;
            let v_sat_rot = rot_z(OMEGA_E_RADPS * terms.geometric_m / C_MPS) * st.v_ecef_mps;
            sats.push(SatObs {
                system: eph.system,
                prn: eph.prn,
                pseudorange_m: terms.geometric_m + self.clock_bias_m + isb - terms.sat_clock_m
                    + terms.troposphere_m
                    + terms.ionosphere_m
                    + mp
                    + n_pr * self.cfg.pseudorange_noise_m / sin_el,
                pseudorange_rate_mps: (v_sat_rot - v_rx).dot(&u) + self.clock_drift_mps - C_MPS * st.ddt
                    + n_prr * self.cfg.pseudorange_rate_noise_mps / sin_el,
                cn0_dbhz: (35.0 + 15.0 * sin_el).round(),
                elevation_deg: el.to_degrees(),
                multipath,
            });
        }
        GnssEpoch {
            t_s: truth.t_s,
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
mod tests {
    use super::*;
    use cmsckf_models::gnss::REL_F;
    use rand::SeedableRng;

    #[test]
    fn satellites_at_orbital_radius_with_consistent_clock() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let c = constellation(2443, 345_600.0, &mut rng);
        assert_eq!(c.len(), 31);
        for eph in &c {
            for dt in [-3600.0, 0.0, 1800.0, 7000.0] {
                let st = eph.state(eph.toe_s + dt);
                let r = st.r_ecef_m.norm();
                // 26 559.7 km ± e·a (≤ 2%) ± harmonic terms.
                assert!((r - 26_559_700.0).abs() < 0.021 * 26_559_700.0, "radius {r}");
                // Inertial speed ≈ 3.87 km/s; ECEF speed is lower, 1.5–4 km/s.
                assert!(st.v_ecef_mps.norm() > 1000.0 && st.v_ecef_mps.norm() < 4500.0);
                // Clock drift equals the derivative of the clock model: af1 +
                // the derivative of the relativistic term (|·| < 1e-11 s/s).
                assert!((st.ddt - eph.af1).abs() < 1e-11, "{} vs {}", st.ddt, eph.af1);
            }
            // The relativistic term peaks at F e √A (≤ 46 ns for e = 0.02).
            let st0 = eph.state(eph.toe_s);
            let no_rel = eph.af0_s - eph.tgd_s;
            assert!((st0.dt_s - no_rel).abs() <= REL_F.abs() * eph.e * eph.sqrt_a + 1e-15);
        }
    }

    #[test]
    fn pseudorange_minus_range_is_the_modelled_terms() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let cfg = GnssSimConfig {
            pseudorange_noise_m: 1e-9,
            pseudorange_rate_noise_mps: 1e-9,
            multipath_prob: 0.0,
            ionosphere: true,
            ..Default::default()
        };
        let mut m = GnssModel::new(&cfg, &mut rng);
        let truth = TruthSample {
            t_s: 0.0,
            p_B_in_W: Vector3::new(10.0, 20.0, -5.0),
            v_B_in_W: Vector3::new(15.0, 0.0, 0.0),
            a_B_in_W: Vector3::zeros(),
            q_W_B: Default::default(),
            w_B: Vector3::zeros(),
        };
        let ep = m.epoch(&truth, &mut rng);
        assert!(ep.sats.len() >= 6, "{} satellites in view", ep.sats.len());
        let r_rx = m.frame.to_ecef(&truth.p_B_in_W);
        assert!(ep.sats.iter().any(|s| s.system == System::Galileo));
        for s in &ep.sats {
            let eph = m
                .ephemerides
                .iter()
                .find(|e| e.system == s.system && e.prn == s.prn)
                .unwrap();
            let (t, _, _) = m.range_terms(eph, m.gps_time(ep.t_s).1, &r_rx);
            let isb = if s.system == System::Galileo {
                ep.isb_galileo_m
            } else {
                0.0
            };
            let modelled = ep.clock_bias_m + isb - t.sat_clock_m + t.troposphere_m + t.ionosphere_m;
            assert!((s.pseudorange_m - t.geometric_m - modelled).abs() < 1e-6);
            assert!(t.troposphere_m > 2.3 && t.troposphere_m < 2.3 / (10f64.to_radians().sin()) + 1.0);
            assert!(t.ionosphere_m >= 5.0 && t.ionosphere_m < 16.0);
            // Flight time is 67–90 ms (GPS), 77–97 ms (Galileo).
            assert!(
                t.geometric_m > 1.95e7 && t.geometric_m < 2.9e7,
                "range {} el {}",
                t.geometric_m,
                s.elevation_deg
            );
        }
        // Pseudorange rate against a numerical derivative of the range.
        let dt = 0.01;
        let r_rx2 = m.frame.to_ecef(&(truth.p_B_in_W + truth.v_B_in_W * dt));
        for s in &ep.sats {
            let eph = m
                .ephemerides
                .iter()
                .find(|e| e.system == s.system && e.prn == s.prn)
                .unwrap();
            let tow = m.gps_time(ep.t_s).1;
            let (a, sa, _) = m.range_terms(eph, tow, &r_rx);
            let (b, sb, _) = m.range_terms(eph, tow + dt, &r_rx2);
            let rate = (b.geometric_m - a.geometric_m) / dt - (sb.dt_s - sa.dt_s) * C_MPS / dt + ep.clock_drift_mps;
            assert!(
                (rate - s.pseudorange_rate_mps).abs() < 0.01,
                "{rate} vs {}",
                s.pseudorange_rate_mps
            );
        }
    }

    #[test]
    fn galileo_constellation_geometry() {
        let c = galileo_constellation(2443, 345_600.0);
        assert_eq!(c.len(), 24);
        for e in &c {
            let r = e.state(e.toe_s + 1234.0).r_ecef_m.norm();
            assert!((r - 29_600_000.0).abs() < 0.01 * 29_600_000.0, "{r}");
            assert!((e.accuracy_m() - 3.12).abs() < 1e-12);
        }
    }
}
