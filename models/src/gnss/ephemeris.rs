//! Broadcast orbits and clocks: GPS LNAV and Galileo I/NAV and F/NAV
//! Keplerian ephemerides and the satellite state they give (IS-GPS-200
//! Table 20-IV; Galileo OS SIS ICD §5.1.1, the same with Galileo's GM), and
//! BeiDou's and QZSS's, the same model (BDS-SIS-ICD-B1I 3.0 §5.2.4.12, with
//! BeiDou's own Earth rate and a tilted frame for its GEO satellites; QZSS
//! exactly as GPS).
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

/// Earth rotation rate of BeiDou's CGCS2000 (rad/s, BDS-SIS-ICD-B1I 3.0
/// §5.2.4.12); GPS's 7.2921151467e-5 would put a BeiDou satellite 2 m off.
pub const OMEGA_E_BDS_RADPS: f64 = 7.292_115_0e-5;
/// GPS time − BDT (s): BDT started at 2006-01-01 00:00:00 UTC, when GPS −
/// UTC was 14 s, and both count without leap seconds since.
pub const BDT_GPS_OFFSET_S: f64 = 14.0;
/// GPS week of BDT week 0.
pub const BDT_GPS_WEEK_OFFSET: u32 = 1356;
/// The rotation about x from the frame BeiDou's GEO elements are given in
/// to BDCS (BDS-SIS-ICD-B1I 3.0 §5.2.4.12: −5°).
const BDS_GEO_TILT_DEG: f64 = -5.0;

/// A BDT week and time of week on the GPS scale: tow + 14 s, week + 1356,
/// carried into the next GPS week when the 14 s cross it.
pub fn bdt_to_gps(bdt_week: u32, bdt_tow_s: f64) -> (u32, f64) {
    let week = bdt_week.saturating_add(BDT_GPS_WEEK_OFFSET);
    let tow = bdt_tow_s + BDT_GPS_OFFSET_S;
    if tow >= WEEK_S {
        (week.saturating_add(1), tow - WEEK_S)
    } else {
        (week, tow)
    }
}

/// A Keplerian broadcast ephemeris and clock: GPS LNAV (RTCM 1019),
/// Galileo I/NAV and F/NAV (RTCM 1046, 1045), BeiDou D1/D2 (RTCM 1042) or
/// QZSS LNAV (RTCM 1044), in SI units and radians
/// (RTCM's semicircles are converted at the wire boundary). Galileo's weeks
/// and times of week are stored on the GPS scale (GST week + 1024; GST and
/// GPS time share the second of week), and so are BeiDou's (BDT week + 1356,
/// BDT + 14 s: [`bdt_to_gps`]); BeiDou's `prn` is its PRN (1–63).
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

    /// BeiDou's GEO satellites, whose elements are given in a frame tilted by
    /// −5°: PRN 1–5 (BeiDou-2) and 59–63 (BeiDou-3), as RTKLIB 2.4.3 counts
    /// them.
    pub fn is_beidou_geo(&self) -> bool {
        self.system == System::BeiDou && matches!(self.prn, 1..=5 | 59..=63)
    }

    /// Position and eccentric anomaly at GPS time of week `t` (IS-GPS-200
    /// Table 20-IV; Galileo OS SIS ICD Table 58, the same with its own GM;
    /// BDS-SIS-ICD-B1I 3.0 §5.2.4.12 for BeiDou, below).
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
        // BeiDou's Ω0 is referred to the start of the BDT week, so the
        // Earth-rotation term takes toe in BDT (stored on the GPS scale).
        let (omega_e, toe_week_s) = match self.system {
            System::BeiDou => (OMEGA_E_BDS_RADPS, (self.toe_s - BDT_GPS_OFFSET_S).rem_euclid(WEEK_S)),
            _ => (OMEGA_E_RADPS, self.toe_s),
        };
        if self.is_beidou_geo() {
            // BDS ICD §5.2.4.12, GEO: Ω_k = Ω0 + Ω̇·t_k − Ω_e·t_oe (no Earth
            // rotation over t_k yet), the position in the tilted inertial-like
            // frame, then [X Y Z] = Rz(Ω_e·t_k)·Rx(−5°)·[X_GK Y_GK Z_GK] with
            // Rx(φ) = [1 0 0; 0 cos φ sin φ; 0 −sin φ cos φ] and
            // Rz(φ) = [cos φ sin φ 0; −sin φ cos φ 0; 0 0 1].
            let om = self.omega0_rad + self.omega_dot_radps * dt - omega_e * toe_week_s;
            let (so, co) = om.sin_cos();
            let (si, ci) = i.sin_cos();
            let gk = Vector3::new(xp * co - yp * ci * so, xp * so + yp * ci * co, yp * si);
            let (sf, cf) = BDS_GEO_TILT_DEG.to_radians().sin_cos();
            let tilted = Vector3::new(gk.x, cf * gk.y + sf * gk.z, -sf * gk.y + cf * gk.z);
            let (sz, cz) = (omega_e * dt).sin_cos();
            return (
                Vector3::new(cz * tilted.x + sz * tilted.y, -sz * tilted.x + cz * tilted.y, tilted.z),
                e_anom,
            );
        }
        let om = self.omega0_rad + (self.omega_dot_radps - omega_e) * dt - omega_e * toe_week_s;
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

    /// BeiDou C02 (GEO) and C06 (IGSO), the 10:00 BDT ephemerides of BDT
    /// week 888 (toe 36 000 s BDT = 36 014 s GPST, GPS week 2244) from the
    /// Skydel RINEX shipped with INSTINCT
    /// (`test/data/GNSS/Skydel_static_duration-4h_rate-5min_sys-GERCQIS/
    /// SkydelRINEX_S_20238959_3600S_CN.rnx`), stored on the GPS scale.
    #[allow(clippy::inconsistent_digit_grouping, clippy::excessive_precision)] // values as published
    fn beidou_c02_c06() -> (BroadcastEphemeris, BroadcastEphemeris) {
        let c02 = BroadcastEphemeris {
            prn: 2,
            ..eph(
                System::BeiDou,
                2244,
                36_014.0,
                [
                    6.493481067657e3,
                    9.540994651616e-4,
                    -5.156079508322e-1,
                    -2.415814914102e-9,
                    -5.011557524058e-1,
                    3.626579633027e-9,
                    1.125395887542e-1,
                    5.325221816864e-10,
                    -1.175464677199,
                    -2.160156145692e-5,
                    2.393499016762e-7,
                    -4.96875,
                    -6.5725e2,
                    -1.117587089539e-8,
                    9.080395102501e-8,
                    0.0,
                ],
                [-6.993988063186e-5, -1.344755418131e-10, 0.0],
                1.4e-9,
            )
        };
        let c06 = BroadcastEphemeris {
            prn: 6,
            ..eph(
                System::BeiDou,
                2244,
                36_014.0,
                [
                    6.492945194244e3,
                    3.454052493908e-3,
                    1.652985884108e-1,
                    1.575065607805e-9,
                    1.170534452350,
                    -1.890435887100e-9,
                    9.452606977880e-1,
                    1.040043321979e-9,
                    -3.134031840914,
                    3.844499588013e-6,
                    8.593313395977e-6,
                    -2.2421875e1,
                    1.189687500000e2,
                    -7.916241884232e-8,
                    1.089647412300e-7,
                    0.0,
                ],
                [2.073270972147e-4, -3.033129303276e-12, 0.0],
                8.6e-9,
            )
        };
        (c02, c06)
    }

    /// BeiDou satellite states against Skydel's truth (INSTINCT's
    /// `sat_data/B1 02.csv` and `B1 06.csv`, Iono-none_tropo-none), at the
    /// transmission time of the 36 300 s GPST epoch. Skydel's B1I clock
    /// includes relativity and −TGD1, like `dt_s`.
    /// - C06 (IGSO) agrees to 10 µm (with GPS's Earth rate instead of
    ///   BeiDou's it would be 2.2 m off).
    /// - C02 (GEO, the −5° frame) agrees to 1.8 cm, its velocity to the
    ///   truth's 10-minute difference quotient to 1 mm/s. Without the GEO
    ///   rotation it would be 3 600 km off, with toe on the GPS scale in the
    ///   Ω term 43 km, and read on the GPS time scale (no 14 s) 187 m.
    #[test]
    #[allow(clippy::inconsistent_digit_grouping)] // values as published
    fn beidou_positions_match_skydel() {
        let (c02, c06) = beidou_c02_c06();

        let t = 36_300.0 - 37_315_465.53863 / C_MPS;
        let want = Vector3::new(-8_668_440.498344, 40_578_147.42062, -6_599_670.28856);
        let st = c06.state(t);
        assert!((st.r_ecef_m - want).norm() < 1e-3, "{:?}", st.r_ecef_m - want);
        assert!((st.dt_s - 2.073_157_797_571e-4).abs() < 1e-13, "{}", st.dt_s);

        let t = 36_300.0 - 36_948_927.97992 / C_MPS;
        let want = Vector3::new(4_456_433.905018, 41_880_148.90687, -1_054_098.955061);
        let st = c02.state(t);
        assert!((st.r_ecef_m - want).norm() < 0.05, "{:?}", st.r_ecef_m - want);
        assert!((st.dt_s - -6.997_841_600_047e-5).abs() < 1e-13, "{}", st.dt_s);
        // The truth's difference quotient over the 36 000 s and 36 600 s
        // epochs, centred on t.
        let v_truth = (Vector3::new(4_454_568.825513, 41_879_880.10726, -1_057_402.476001)
            - Vector3::new(4_458_281.722593, 41_880_449.18674, -1_050_289.98781))
            / 600.0;
        assert!((st.v_ecef_mps - v_truth).norm() < 0.01, "{:?}", st.v_ecef_mps - v_truth);
        let not_geo = BroadcastEphemeris { prn: 6, ..c02.clone() };
        assert!((not_geo.state(t).r_ecef_m - want).norm() > 1e6);
    }

    /// A GEO stays put: C02's position over toe ± 1 h stays within 100 km of
    /// where it is at toe (87 km at most: an inclined GEO's daily figure
    /// eight), moving at under 50 m/s, where a MEO or IGSO satellite moves
    /// at kilometres per second in ECEF.
    #[test]
    fn beidou_geo_is_near_stationary() {
        let (c02, c06) = beidou_c02_c06();
        assert!(c02.is_beidou_geo() && !c06.is_beidou_geo());
        let at_toe = c02.state(36_014.0).r_ecef_m;
        for k in -60..=60 {
            let st = c02.state(36_014.0 + k as f64 * 60.0);
            assert!((st.r_ecef_m - at_toe).norm() < 100e3, "{k} min");
            assert!(st.v_ecef_mps.norm() < 50.0, "{k} min: {}", st.v_ecef_mps.norm());
            // Geostationary radius, 42 164 km ± 100 km.
            assert!((st.r_ecef_m.norm() - 42_164e3).abs() < 100e3);
        }
        assert!(c06.state(36_014.0).v_ecef_mps.norm() > 1_000.0);
        for prn in [59, 63] {
            assert!(BroadcastEphemeris { prn, ..c02.clone() }.is_beidou_geo());
        }
    }

    /// The BeiDou handling leaves the other constellations alone: a GPS or
    /// QZSS satellite numbered like a BeiDou GEO is an ordinary one.
    #[test]
    fn low_prn_gps_is_not_geo() {
        let (elements, _) = beidou_c02_c06();
        let gps = BroadcastEphemeris {
            system: System::Gps,
            prn: 3,
            ..elements
        };
        let gps30 = BroadcastEphemeris { prn: 30, ..gps.clone() };
        assert!(!gps.is_beidou_geo());
        assert_eq!(gps.state(36_300.0), gps30.state(36_300.0));
        let qzs = BroadcastEphemeris {
            system: System::Qzss,
            ..gps.clone()
        };
        assert_eq!(gps.state(36_300.0), qzs.state(36_300.0));
    }

    /// BDT to the GPS scale, with the week carried when the 14 s cross it.
    #[test]
    fn bdt_on_gps_scale() {
        assert_eq!(bdt_to_gps(888, 36_000.0), (2244, 36_014.0));
        assert_eq!(bdt_to_gps(888, WEEK_S - 8.0), (2245, 6.0));
        assert_eq!(bdt_to_gps(888, WEEK_S - 14.0), (2245, 0.0));
        // A toe of BDT 604 792 s (week 888) is stored as 6 s of GPS week
        // 2245; the Ω term must still see 604 792 s, as it does for the same
        // instant written unwrapped (604 806 s of GPS week 2244).
        let (_, c06) = beidou_c02_c06();
        let late = BroadcastEphemeris {
            week: 2245,
            toe_s: 6.0,
            toc_s: 6.0,
            ..c06.clone()
        };
        let early = BroadcastEphemeris {
            toe_s: WEEK_S + 6.0,
            toc_s: WEEK_S + 6.0,
            ..c06
        };
        let (a, b) = (late.state(106.0).r_ecef_m, early.state(WEEK_S + 106.0).r_ecef_m);
        assert!((a - b).norm() < 1e-6, "{:?}", a - b);
    }
}
