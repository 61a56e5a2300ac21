//! Broadcast orbits and clocks: GPS LNAV and Galileo I/NAV and F/NAV
//! Keplerian ephemerides and the satellite state they give (IS-GPS-200
//! Table 20-IV; Galileo OS SIS ICD §5.1.1, the same with Galileo's GM).
//!
//! One implementation serves the simulator's truth and the receiver's
//! decoded satellite states; it is checked against GNSSTk and Skydel values
//! in this module's tests and against RTKLIB through the single-point
//! solutions.

use nalgebra::Vector3;

use super::{System, WEEK_S};
use crate::geodesy::OMEGA_E_RADPS;

/// Relativistic clock constant F (s/√m), IS-GPS-200 20.3.3.3.3.1.
pub const REL_F: f64 = -4.442_807_633e-10;

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
            // BeiDou's URA index uses GPS's table; GLONASS has no Kepler
            // ephemeris (its own accuracy comes with its orbit model).
            (System::Gps | System::Qzss | System::BeiDou | System::Glonass, k) => {
                URA_M.get(k as usize).copied().unwrap_or(6144.0)
            }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geodesy::C_MPS;

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
    fn week_crossover() {
        assert_eq!(tk(10.0, WEEK_S - 10.0), 20.0);
        assert_eq!(tk(WEEK_S - 10.0, 10.0), -20.0);
    }
}
