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
use crate::geodesy::{ecef_to_llh, elevation_azimuth, NedFrame, C_MPS, MU_GAL_M3PS2, MU_GPS_M3PS2, OMEGA_E_RADPS};
use crate::trajectory::TruthSample;

/// Seconds in a GPS week.
pub const WEEK_S: f64 = 604_800.0;
/// Relativistic clock constant F (s/√m), IS-GPS-200 20.3.3.3.3.1.
pub const REL_F: f64 = -4.442_807_633e-10;

/// Constellations.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub enum System {
    #[default]
    Gps,
    Galileo,
}

impl System {
    /// The RINEX letter.
    pub fn letter(self) -> char {
        match self {
            System::Gps => 'G',
            System::Galileo => 'E',
        }
    }

    /// The gravitational constant the constellation's ephemerides use (m³/s²).
    pub fn gm_m3ps2(self) -> f64 {
        match self {
            System::Gps => MU_GPS_M3PS2,
            System::Galileo => MU_GAL_M3PS2,
        }
    }
}

/// A Keplerian broadcast ephemeris and clock: GPS LNAV (RTCM 1019) or
/// Galileo I/NAV and F/NAV (RTCM 1046, 1045), in SI units and radians
/// (RTCM's semicircles are converted at the wire boundary). Galileo's weeks
/// and times of week are stored on the GPS scale (GST week + 1024; GST and
/// GPS time share the second of week).
#[derive(Clone, Debug, PartialEq)]
pub struct BroadcastEphemeris {
    pub system: System,
    pub prn: u8,
    /// Full GPS week of `toe`.
    pub week: u32,
    /// IODE (GPS) or IODnav (Galileo, 10 bits).
    pub iode: u16,
    pub iodc: u16,
    pub toc_s: f64,
    pub af0_s: f64,
    pub af1: f64,
    pub af2_per_s: f64,
    pub toe_s: f64,
    pub sqrt_a: f64,
    pub e: f64,
    pub m0_rad: f64,
    pub delta_n_radps: f64,
    pub omega0_rad: f64,
    pub omega_dot_radps: f64,
    pub i0_rad: f64,
    pub idot_radps: f64,
    pub omega_rad: f64,
    pub cuc_rad: f64,
    pub cus_rad: f64,
    pub crc_m: f64,
    pub crs_m: f64,
    pub cic_rad: f64,
    pub cis_rad: f64,
    /// Group delay for the single-frequency user: GPS TGD (L1 C/A), Galileo
    /// BGD(E1, E5b) for I/NAV or BGD(E1, E5a) for F/NAV (s).
    pub tgd_s: f64,
    /// 0 = healthy (GPS SV health; Galileo signal health and data validity).
    pub health: u8,
    /// GPS URA index, or Galileo SISA index.
    pub ura_index: u8,
    pub fit_interval_4h: bool,
}

/// Satellite state at one time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SatState {
    /// ECEF position at transmission (m).
    pub r_ecef_m: Vector3<f64>,
    /// ECEF velocity (m/s).
    pub v_ecef_mps: Vector3<f64>,
    /// Satellite clock offset for L1 C/A, with relativity and TGD (s).
    pub dt_s: f64,
    /// Satellite clock drift (s/s).
    pub ddt: f64,
}

/// Time difference `t − t_ref` with the week crossover handled
/// (IS-GPS-200: bring it into ±302 400 s).
pub fn tk(t_tow_s: f64, t_ref_s: f64) -> f64 {
    let mut d = t_tow_s - t_ref_s;
    if d > WEEK_S / 2.0 {
        d -= WEEK_S;
    } else if d < -WEEK_S / 2.0 {
        d += WEEK_S;
    }
    d
}

/// GPS URA index → metres (IS-GPS-200 20.3.3.3.1.3).
const URA_M: [f64; 15] = [
    2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0, 3072.0, 6144.0,
];

impl BroadcastEphemeris {
    /// The broadcast signal-in-space accuracy (m): GPS URA, or Galileo SISA
    /// (OS SIS ICD 5.1.11: 0–49 in 1 cm steps, 50–74 from 0.5 m in 2 cm,
    /// 75–99 from 1 m in 4 cm, 100–125 from 2 m in 16 cm; else "no accuracy
    /// prediction", taken as 6144 m like GPS's worst URA).
    pub fn accuracy_m(&self) -> f64 {
        let i = self.ura_index as f64;
        match (self.system, self.ura_index) {
            (System::Gps, k) => URA_M.get(k as usize).copied().unwrap_or(6144.0),
            (System::Galileo, 0..=49) => i * 0.01,
            (System::Galileo, 50..=74) => 0.5 + (i - 50.0) * 0.02,
            (System::Galileo, 75..=99) => 1.0 + (i - 75.0) * 0.04,
            (System::Galileo, 100..=125) => 2.0 + (i - 100.0) * 0.16,
            (System::Galileo, _) => 6144.0,
        }
    }

    /// Position and eccentric anomaly at GPS time of week `t` (IS-GPS-200
    /// Table 20-IV; Galileo OS SIS ICD Table 58, the same with its own GM).
    fn position(&self, t_tow_s: f64) -> (Vector3<f64>, f64) {
        let a = self.sqrt_a * self.sqrt_a;
        let n = (self.system.gm_m3ps2() / (a * a * a)).sqrt() + self.delta_n_radps;
        let dt = tk(t_tow_s, self.toe_s);
        let m = self.m0_rad + n * dt;
        let mut e_anom = m;
        for _ in 0..30 {
            let next = m + self.e * e_anom.sin();
            if (next - e_anom).abs() < 1e-15 {
                e_anom = next;
                break;
            }
            e_anom = next;
        }
        let nu = ((1.0 - self.e * self.e).sqrt() * e_anom.sin()).atan2(e_anom.cos() - self.e);
        let phi = nu + self.omega_rad;
        let (s2, c2) = (2.0 * phi).sin_cos();
        let u = phi + self.cus_rad * s2 + self.cuc_rad * c2;
        let r = a * (1.0 - self.e * e_anom.cos()) + self.crs_m * s2 + self.crc_m * c2;
        let i = self.i0_rad + self.cis_rad * s2 + self.cic_rad * c2 + self.idot_radps * dt;
        let (xp, yp) = (r * u.cos(), r * u.sin());
        let om = self.omega0_rad + (self.omega_dot_radps - OMEGA_E_RADPS) * dt - OMEGA_E_RADPS * self.toe_s;
        let (so, co) = om.sin_cos();
        let (si, ci) = i.sin_cos();
        (
            Vector3::new(xp * co - yp * ci * so, xp * so + yp * ci * co, yp * si),
            e_anom,
        )
    }

    /// Clock offset for the single-frequency code (GPS L1 C/A, Galileo E1)
    /// at `t`: `af0 + af1·Δt + af2·Δt² + F e √A sin E − TGD` (IS-GPS-200
    /// 20.3.3.3.3.1-2; Galileo OS SIS ICD 5.1.4-5 with BGD for TGD).
    fn clock(&self, t_tow_s: f64, e_anom: f64) -> f64 {
        let d = tk(t_tow_s, self.toc_s);
        self.af0_s + self.af1 * d + self.af2_per_s * d * d + REL_F * self.e * self.sqrt_a * e_anom.sin() - self.tgd_s
    }

    /// Full satellite state; velocity and drift by central differences
    /// (±1 ms), accurate to ~1e-6 m/s.
    pub fn state(&self, t_tow_s: f64) -> SatState {
        let (r, e) = self.position(t_tow_s);
        let h = 1e-3;
        let (ra, ea) = self.position(t_tow_s - h);
        let (rb, eb) = self.position(t_tow_s + h);
        SatState {
            r_ecef_m: r,
            v_ecef_mps: (rb - ra) / (2.0 * h),
            dt_s: self.clock(t_tow_s, e),
            ddt: (self.clock(t_tow_s + h, eb) - self.clock(t_tow_s - h, ea)) / (2.0 * h),
        }
    }
}

/// Saastamoinen zenith delay with the standard atmosphere, mapped by
/// `1/cos(z)` (RTKLIB's model: 15 °C at sea level, 70% relative humidity).
pub fn saastamoinen_m(lat_rad: f64, h_m: f64, el_rad: f64) -> f64 {
    if !(-100.0..=1e4).contains(&h_m) || el_rad <= 0.0 {
        return 0.0;
    }
    let hgt = h_m.max(0.0);
    let pres = 1013.25 * (1.0 - 2.2557e-5 * hgt).powf(5.2568);
    let temp = 15.0 - 6.5e-3 * hgt + 273.16;
    let humi = 0.7;
    let e = 6.108 * humi * ((17.15 * temp - 4684.0) / (temp - 38.45)).exp();
    let z = std::f64::consts::FRAC_PI_2 - el_rad;
    let trph = 0.0022768 * pres / (1.0 - 0.00266 * (2.0 * lat_rad).cos() - 0.00028 * hgt / 1e3) / z.cos();
    let trpw = 0.002277 * (1255.0 / temp + 0.05) * e / z.cos();
    trph + trpw
}

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
                .map(|e| crate::rtcm_out::quantise(&e))
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

    /// An ephemeris from RINEX-style values (radians, s), toe = toc.
    #[allow(clippy::too_many_arguments)]
    fn eph(system: System, week: u32, toe_s: f64, k: [f64; 16], clk: [f64; 3], tgd_s: f64) -> BroadcastEphemeris {
        let [sqrt_a, e, m0, dn, om0, omd, i0, idot, w, cuc, cus, crc, crs, cic, cis, _] = k;
        BroadcastEphemeris {
            system,
            prn: 1,
            week,
            iode: 0,
            iodc: 0,
            toc_s: toe_s,
            af0_s: clk[0],
            af1: clk[1],
            af2_per_s: clk[2],
            toe_s,
            sqrt_a,
            e,
            m0_rad: m0,
            delta_n_radps: dn,
            omega0_rad: om0,
            omega_dot_radps: omd,
            i0_rad: i0,
            idot_radps: idot,
            omega_rad: w,
            cuc_rad: cuc,
            cus_rad: cus,
            crc_m: crc,
            crs_m: crs,
            cic_rad: cic,
            cis_rad: cis,
            tgd_s,
            health: 0,
            ura_index: 0,
            fit_interval_4h: false,
        }
    }

    /// Satellite positions and clocks against published third-party values:
    /// - GPS: GNSSTk's `OrbitDataKepler_T.cpp` (week 1854, toe 14 384 s,
    ///   evaluated at 7 235 s, tk = −7 149 s); its clock excludes relativity,
    ///   reported separately;
    /// - GPS G01 and Galileo E01: Safran Skydel simulator truth shipped with
    ///   INSTINCT (`test/data/GNSS/Skydel_static_duration-4h_rate-5min_sys-GERCQIS`,
    ///   week 2244, toe 36 000 s), at the transmission time of the 36 300 s
    ///   epoch; GPS's clock includes −TGD, Galileo's E1 clock no BGD
    ///   (BGD(E1,E5b) = 0 there). Galileo's GM matters here: GPS's would
    ///   move E01 by about 8 cm.
    #[test]
    #[allow(clippy::inconsistent_digit_grouping, clippy::excessive_precision)] // values as published
    fn satellite_positions_match_published_values() {
        let gnsstk = eph(
            System::Gps,
            1854,
            14_384.0,
            [
                0.515360180473e4,
                0.422249664553e-2,
                0.218771233916e1,
                0.511592738462e-8,
                -0.189462874179e1,
                -0.823034282681e-8,
                0.946122987969,
                0.492877673191e-9,
                0.374892043461,
                0.200793147087e-5,
                0.823289155960e-5,
                0.214593750000e3,
                0.369375000000e2,
                -0.175088644028e-6,
                0.335276126862e-7,
                0.0,
            ],
            [-0.216379296035e-3, 0.432009983342e-11, 0.0],
            0.0,
        );
        let st = gnsstk.state(7_235.0);
        let want = Vector3::new(9_345_531.527_473_377, -12_408_177.088_141_857, 21_486_320.848_036_297);
        assert!((st.r_ecef_m - want).norm() < 1e-4, "{:?}", st.r_ecef_m - want);
        let clk = -0.000_216_410_180_428_709_13 + -8.819_775_810_155_175_8e-9;
        assert!((st.dt_s - clk).abs() < 1e-15, "{} vs {clk}", st.dt_s);

        let g01 = eph(
            System::Gps,
            2244,
            36_000.0,
            [
                5.153651281357e3,
                1.217794988770e-2,
                -9.548443013955e-1,
                4.114099940205e-9,
                -1.509330417236,
                -8.193912737927e-9,
                9.889942806558e-1,
                2.285809498855e-11,
                9.377089341753e-1,
                2.561137080193e-6,
                1.572072505951e-6,
                3.624375e2,
                4.684375e1,
                9.685754776001e-8,
                2.831220626831e-7,
                0.0,
            ],
            [2.268739044666e-4, -4.774847184308e-12, 0.0],
            4.656612873077e-9,
        );
        let st = g01.state(36_300.0 - 21_798_545.43521 / C_MPS);
        let want = Vector3::new(-14_003_758.55706, 22_337_614.79252, 158_355.233286);
        assert!((st.r_ecef_m - want).norm() < 1e-3, "{:?}", st.r_ecef_m - want);
        assert!((st.dt_s - 2.268900132388e-4).abs() < 1e-14, "{}", st.dt_s);

        let e01 = eph(
            System::Galileo,
            2244,
            36_000.0,
            [
                5.440603010178e3,
                2.660002792254e-4,
                1.933279858556,
                3.161917420838e-9,
                2.601494513871,
                -5.389510209019e-9,
                9.711716272708e-1,
                -5.753811097899e-10,
                2.837511411568e-1,
                -7.543712854385e-7,
                7.875263690948e-6,
                1.76125e2,
                -1.65625e1,
                -7.450580596924e-9,
                -1.862645149231e-9,
                0.0,
            ],
            [-5.921604611103e-4, -5.542233338929e-12, 0.0],
            0.0,
        );
        let st = e01.state(36_300.0 - 25_051_040.06839 / C_MPS);
        let want = Vector3::new(-18_095_039.56013, 13_787_149.45726, 18_942_912.59133);
        assert!((st.r_ecef_m - want).norm() < 1e-3, "{:?}", st.r_ecef_m - want);
        assert!((st.dt_s - -5.921627155452e-4).abs() < 1e-14, "{}", st.dt_s);
        // The same orbit with GPS's constant lands centimetres away.
        let wrong = BroadcastEphemeris {
            system: System::Gps,
            ..e01.clone()
        };
        assert!((wrong.state(36_300.0 - 25_051_040.06839 / C_MPS).r_ecef_m - want).norm() > 0.02);
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

    #[test]
    fn week_crossover() {
        assert_eq!(tk(10.0, WEEK_S - 10.0), 20.0);
        assert_eq!(tk(WEEK_S - 10.0, 10.0), -20.0);
    }
}
