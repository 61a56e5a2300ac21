//! GLONASS broadcast ephemerides (L1/L2 FDMA navigation message, RTCM 1020):
//! the satellite state they give and the Moscow-time reference epoch.
//!
//! GLONASS does not broadcast Kepler elements: each ephemeris is a position,
//! velocity and lunisolar acceleration at the epoch t_b in the rotating PZ-90
//! frame, which the user integrates to the wanted time (GLONASS ICD Edition
//! 5.1, A.3.1.2). The frame is taken as WGS-84: PZ-90.11 and ITRF/WGS-84 agree
//! to a few centimetres (PZ-90.02 to decimetres), below the broadcast's own
//! metre-level error, so no transformation is applied (as in RTKLIB). t_b is a
//! time of day in Moscow time (UTC(SU) + 3 h); [`glonass_tb_to_gps`] puts it
//! on the GPS week and time of week every other ephemeris here uses.
//!
//! The equations are checked against the worked example of the GLONASS CDMA
//! ICD (2016, Appendix J) and against the IGS final GLONASS orbit, in this
//! module's tests.

use nalgebra::Vector3;

use super::{gps_utc_leap_s, SatState, WEEK_S};

/// PZ-90 gravitational constant (m³/s²), RTKLIB's; PZ-90.02's
/// 398 600.4418e9 moves a satellite by about a millimetre over 15 min.
pub const MU_GLO_M3PS2: f64 = 398_600.44e9;
/// PZ-90 equatorial radius of the Earth (m).
pub const AE_GLO_M: f64 = 6_378_136.0;
/// Second zonal harmonic of the geopotential (PZ-90), unnormalised (the
/// ICD's J₀²).
pub const J2_GLO: f64 = 1_082_625.7e-9;
/// Earth rotation rate used by GLONASS (rad/s).
pub const OMEGA_E_GLO_RADPS: f64 = 7.292_115e-5;
/// Largest Runge-Kutta step (s): RTKLIB's 60 s, which the tests show to agree
/// with 10 s steps to under a millimetre over the ±15 min an ephemeris serves.
pub const GLO_MAX_STEP_S: f64 = 60.0;
/// L1 FDMA carrier: 1602 MHz + k · 562.5 kHz (GLONASS ICD 5.1).
pub const GLO_L1_BASE_HZ: f64 = 1_602.0e6;
pub const GLO_L1_STEP_HZ: f64 = 562.5e3;
/// L2 FDMA carrier: 1246 MHz + k · 437.5 kHz.
pub const GLO_L2_BASE_HZ: f64 = 1_246.0e6;
pub const GLO_L2_STEP_HZ: f64 = 437.5e3;
/// Orbit-and-clock error of a GLONASS broadcast ephemeris (m, 1σ): RTKLIB's
/// `ERREPH_GLO`. The comparison with the IGS final orbit in the tests shows
/// 2–5 m of orbit error alone.
pub const GLO_EPH_SIGMA_M: f64 = 5.0;
/// Moscow time − UTC (s).
pub const MOSCOW_UTC_S: f64 = 10_800.0;

const DAY_S: f64 = 86_400.0;
/// Integration stops at ±1 day from t_b: an ephemeris serves ±15 min, and
/// this bounds the work for a wild time argument.
const MAX_SPAN_S: f64 = DAY_S;

/// A GLONASS broadcast ephemeris (RTCM 1020), in SI units on the GPS time
/// scale. Position, velocity and acceleration are in the rotating PZ-90 frame
/// (= WGS-84 to the centimetres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GlonassEphemeris {
    /// Orbital slot number, 1..=24.
    pub slot: u8,
    /// Frequency channel number k, −7..=6.
    pub freq_channel: i8,
    /// Full GPS week of t_b.
    pub week: u32,
    /// GPS time of week of t_b (s).
    pub toe_s: f64,
    pub r_m: Vector3<f64>,
    pub v_mps: Vector3<f64>,
    /// Lunisolar acceleration at t_b, held constant over the integration.
    pub a_mps2: Vector3<f64>,
    /// τn: GLONASS time − satellite time at t_b (s).
    pub tau_n_s: f64,
    /// γn: relative frequency offset of the satellite clock.
    pub gamma_n: f64,
    /// 0 = healthy. Bit 0: MSB of Bn; bit 1: ln of string 3; bit 2: ln of
    /// string 5; bit 3: almanac Cn says non-operational (see
    /// `rtcm_eph::glonass_from_1020`). RTKLIB looks at bit 0 only.
    pub health: u8,
    /// En: age of the ephemeris data (days).
    pub age_days: u8,
}

impl GlonassEphemeris {
    /// t − t_b (s) for the GPS time `week`, `tow_s`.
    pub fn since_tb_s(&self, week: u32, tow_s: f64) -> f64 {
        (week as f64 - self.week as f64) * WEEK_S + (tow_s - self.toe_s)
    }

    /// Satellite state at the GPS time `week`, `tow_s`: position and velocity
    /// by RK4 integration from t_b in steps of at most 60 s (the last one
    /// shortened), and the clock `t_sv − t_GLO = −τn + γn·(t − t_b)`, which
    /// follows from the ICD 5.1 definitions of τn (t_GLO − t_sv at t_b) and γn
    /// in the immediate data (RTKLIB `geph2pos`; no relativistic or
    /// group-delay term: the ICD's clock model has none).
    ///
    /// The clock is relative to GLONASS time: GLONASS − GPS system time (τc,
    /// τGPS, up to a few hundred ns) is left to the receiver's GLONASS clock
    /// offset, as RTKLIB does.
    pub fn state(&self, week: u32, tow_s: f64) -> SatState {
        let dt = self.since_tb_s(week, tow_s);
        let (r, v) = self.propagate(dt, GLO_MAX_STEP_S);
        SatState {
            r_ecef_m: r,
            v_ecef_mps: v,
            dt_s: -self.tau_n_s + self.gamma_n * dt,
            ddt: self.gamma_n,
        }
    }

    /// L1 carrier frequency of this satellite's channel (Hz).
    pub fn l1_frequency_hz(&self) -> f64 {
        GLO_L1_BASE_HZ + self.freq_channel as f64 * GLO_L1_STEP_HZ
    }

    /// L2 carrier frequency of this satellite's channel (Hz).
    pub fn l2_frequency_hz(&self) -> f64 {
        GLO_L2_BASE_HZ + self.freq_channel as f64 * GLO_L2_STEP_HZ
    }

    /// Orbit-and-clock σ (m): a fixed 5 m, RTKLIB's GLONASS ephemeris error.
    /// The broadcast accuracy index F_T is not carried.
    pub fn accuracy_m(&self) -> f64 {
        GLO_EPH_SIGMA_M
    }

    /// Acceleration in the rotating PZ-90 frame (ICD 5.1 A.3.1.2):
    ///
    /// ẍ = −μ/r³·x − 3/2·J2·μ·a_e²/r⁵·x·(1 − 5z²/r²) + ω²x + 2ω·ẏ + ẍ_ls
    /// ÿ = −μ/r³·y − 3/2·J2·μ·a_e²/r⁵·y·(1 − 5z²/r²) + ω²y − 2ω·ẋ + ÿ_ls
    /// z̈ = −μ/r³·z − 3/2·J2·μ·a_e²/r⁵·z·(3 − 5z²/r²) + z̈_ls
    ///
    /// (central body, J2, centrifugal and Coriolis terms, and the broadcast
    /// lunisolar acceleration held constant).
    fn acceleration(&self, r: &Vector3<f64>, v: &Vector3<f64>) -> Vector3<f64> {
        let r2 = r.norm_squared();
        if r2 <= 0.0 {
            return Vector3::zeros();
        }
        let r3 = r2 * r2.sqrt();
        let j2_term = 1.5 * J2_GLO * MU_GLO_M3PS2 * AE_GLO_M * AE_GLO_M / (r2 * r3);
        let z2_r2 = 5.0 * r.z * r.z / r2;
        let radial = -MU_GLO_M3PS2 / r3 - j2_term * (1.0 - z2_r2);
        let w = OMEGA_E_GLO_RADPS;
        Vector3::new(
            (radial + w * w) * r.x + 2.0 * w * v.y,
            (radial + w * w) * r.y - 2.0 * w * v.x,
            (radial - 2.0 * j2_term) * r.z,
        ) + self.a_mps2
    }

    /// One classical fourth-order Runge-Kutta step of `h` seconds on
    /// (r, v) with (ṙ, v̇) = (v, acceleration(r, v)).
    fn rk4_step(&self, r: &Vector3<f64>, v: &Vector3<f64>, h: f64) -> (Vector3<f64>, Vector3<f64>) {
        let k1r = *v;
        let k1v = self.acceleration(r, v);
        let (r2, v2) = (r + k1r * (h / 2.0), v + k1v * (h / 2.0));
        let k2r = v2;
        let k2v = self.acceleration(&r2, &v2);
        let (r3, v3) = (r + k2r * (h / 2.0), v + k2v * (h / 2.0));
        let k3r = v3;
        let k3v = self.acceleration(&r3, &v3);
        let (r4, v4) = (r + k3r * h, v + k3v * h);
        let k4r = v4;
        let k4v = self.acceleration(&r4, &v4);
        (
            r + (k1r + k2r * 2.0 + k3r * 2.0 + k4r) * (h / 6.0),
            v + (k1v + k2v * 2.0 + k3v * 2.0 + k4v) * (h / 6.0),
        )
    }

    /// Position and velocity `dt_s` from t_b (either sign): whole steps of
    /// `max_step_s`, then the remainder. A non-finite `dt_s` leaves the state
    /// at t_b; |dt_s| is capped at one day.
    fn propagate(&self, dt_s: f64, max_step_s: f64) -> (Vector3<f64>, Vector3<f64>) {
        let (mut r, mut v) = (self.r_m, self.v_mps);
        if !dt_s.is_finite() {
            return (r, v);
        }
        let dt_s = dt_s.clamp(-MAX_SPAN_S, MAX_SPAN_S);
        let step = if max_step_s.is_finite() && max_step_s > 1e-3 {
            max_step_s
        } else {
            GLO_MAX_STEP_S
        };
        let n_full = (dt_s.abs() / step).floor();
        let h = step.copysign(dt_s);
        for _ in 0..n_full as usize {
            (r, v) = self.rk4_step(&r, &v, h);
        }
        let rest = dt_s - n_full * h;
        if rest.abs() > 1e-9 {
            (r, v) = self.rk4_step(&r, &v, rest);
        }
        (r, v)
    }
}

/// GPS week and time of week of a GLONASS t_b: `tb_min` is the minute of the
/// Moscow day (RTCM DF110, its 15-minute units already multiplied out). The
/// day is the one that puts t_b nearest the reference `ref_week`, `ref_tow_s`
/// (the receiver's current GPS time): within ±12 h. Moscow time is UTC + 3 h
/// and UTC is GPS time − 18 s (RTKLIB `decode_type1020`, which does the same
/// through UTC days).
pub fn glonass_tb_to_gps(tb_min: f64, ref_week: u32, ref_tow_s: f64) -> (u32, f64) {
    // A continuous Moscow-time count from the GPS epoch (1980-01-06 00:00
    // UTC): t_MSK = t_GPS − (GPS − UTC) + 3 h, whose whole days are Moscow
    // midnights.
    let leap_s = gps_utc_leap_s(ref_week, ref_tow_s);
    let ref_msk_s = ref_week as f64 * WEEK_S + ref_tow_s - leap_s + MOSCOW_UTC_S;
    let midnight_s = (ref_msk_s / DAY_S).floor() * DAY_S;
    let mut tb_msk_s = midnight_s + tb_min * 60.0;
    if tb_msk_s - ref_msk_s > DAY_S / 2.0 {
        tb_msk_s -= DAY_S;
    } else if tb_msk_s - ref_msk_s < -DAY_S / 2.0 {
        tb_msk_s += DAY_S;
    }
    let tb_gps_s = (tb_msk_s - MOSCOW_UTC_S + leap_s).max(0.0);
    let week = (tb_gps_s / WEEK_S).floor();
    (week as u32, tb_gps_s - week * WEEK_S)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn km(x: f64, y: f64, z: f64) -> Vector3<f64> {
        Vector3::new(x, y, z) * 1e3
    }

    /// The GLONASS CDMA ICD (Edition 1.0, 2016) Appendix J example: the
    /// state at t_b = 11 700 s, propagated to t_i = 12 300 s. Values as
    /// quoted from the ICD by the INSTINCT (`GLONASSEphemerisTests.cpp`) and
    /// ninja-scan-light (`ICD_CDMA_2016_Appendix_J`) test suites.
    fn icd_example() -> GlonassEphemeris {
        GlonassEphemeris {
            slot: 1,
            freq_channel: 0,
            week: 1704,
            toe_s: 11_700.0,
            r_m: km(7_003.008_789, -12_206.626_953, 21_280.765_625),
            v_mps: km(0.783_541_7, 2.804_253_0, 1.352_515_0),
            a_mps2: km(0.0, 1.7e-9, -5.41e-9),
            tau_n_s: 0.0,
            gamma_n: 0.0,
            health: 0,
            age_days: 0,
        }
    }

    /// Against the ICD's worked example (times enter only through t − t_b):
    /// - J.1, the ICD's precise algorithm (lunisolar terms from Sun and Moon
    ///   models): the broadcast-acceleration integration lands 0.53 m and
    ///   1.8 mm/s away, the simplified model's expected level;
    /// - J.2, the simplified algorithm this module implements: its printed
    ///   result matches to 1.1 cm and 0.04 mm/s when the lunisolar term is
    ///   left out (with it, the difference is ½·a·Δt² ≈ 1.0 m, which is the
    ///   1.03 m margin INSTINCT carries), so the printed J.2 numbers evidently
    ///   omit that term.
    #[test]
    #[allow(clippy::inconsistent_digit_grouping)] // values as published
    fn icd_cdma_appendix_j_example() {
        let eph = icd_example();
        let st = eph.state(1704, 12_300.0);
        let r_j1 = km(7_523.174_819, -10_506.961_965, 21_999.239_413);
        let v_j1 = km(0.950_126_007, 2.855_687_825, 1.040_679_862);
        assert!((st.r_ecef_m - r_j1).norm() < 1.0, "{:?}", st.r_ecef_m - r_j1);
        assert!((st.v_ecef_mps - v_j1).norm() < 0.01, "{:?}", st.v_ecef_mps - v_j1);

        let no_ls = GlonassEphemeris {
            a_mps2: Vector3::zeros(),
            ..eph
        };
        let st = no_ls.state(1704, 12_300.0);
        let r_j2 = km(7_523.174_853, -10_506.962_176, 21_999.239_866);
        let v_j2 = km(0.950_126_09, 2.855_687_10, 1.040_681_37);
        assert!((st.r_ecef_m - r_j2).norm() < 0.05, "{:?}", st.r_ecef_m - r_j2);
        assert!((st.v_ecef_mps - v_j2).norm() < 1e-3, "{:?}", st.v_ecef_mps - v_j2);
    }

    /// Against the IGS final GLONASS orbit: R02's broadcast ephemeris of
    /// 2009-04-01 00:15:00 UTC and IGS `igl15253.sp3` at 00:00, 00:15 and
    /// 00:30 GPST, both from RTKLIB's test data (`test/data/rinex/
    /// brdc0910.09g`, `test/data/sp3/igl15253.sp3`; RTKLIB's own
    /// `t_gloeph.c` asserts < 10 m). GPS − UTC was 15 s then, so t_b is
    /// 00:15:15 GPST (GPS week 1525, Wednesday). The orbit agrees to
    /// 2.2–2.5 m (a broadcast's accuracy; the IGS orbit is ITRF2005 centre of
    /// mass); mistaking t_b's UTC for GPST would cost 50 km.
    #[test]
    #[allow(clippy::inconsistent_digit_grouping)] // values as published
    fn broadcast_matches_igs_final_orbit() {
        let eph = GlonassEphemeris {
            slot: 2,
            freq_channel: 1,
            week: 1525,
            toe_s: 3.0 * 86_400.0 + 915.0,
            r_m: km(9_364.739_257_81, -15_908.797_363_3, -17_614.389_648_4),
            v_mps: km(-0.267_867_088_318, 2.398_531_913_76, -2.307_656_288_15),
            a_mps2: km(0.0, 0.186_264_514_923e-8, 0.186_264_514_923e-8),
            // RINEX stores −τn.
            tau_n_s: -0.206_762_924_790e-4,
            gamma_n: -0.272_848_410_532e-11,
            health: 0,
            age_days: 0,
        };
        let igs = [
            (259_200.0, km(9_675.793_281, -17_954.197_593, -15_333.306_358)),
            (260_100.0, km(9_368.778_117, -15_944.739_619, -17_579.727_654)),
            (261_000.0, km(9_202.065_639, -13_662.928_005, -19_485.006_754)),
        ];
        for (tow, want) in igs {
            let err = (eph.state(1525, tow).r_ecef_m - want).norm();
            assert!(err < 3.0, "tow {tow}: {err} m");
        }
    }

    /// 60 s steps against 10 s steps over ±15 min: positions within 1 mm
    /// (0.6 mm), velocities within 1 µm/s.
    #[test]
    fn step_size_independence() {
        let eph = icd_example();
        for dt in [900.0, -900.0, 437.5] {
            let (r60, v60) = eph.propagate(dt, 60.0);
            let (r10, v10) = eph.propagate(dt, 10.0);
            assert!((r60 - r10).norm() < 1e-3, "{dt}: {}", (r60 - r10).norm());
            assert!((v60 - v10).norm() < 1e-6, "{dt}: {}", (v60 - v10).norm());
        }
        // 437.5 s exercises the shortened last step (7 × 60 s + 17.5 s
        // against 43 × 10 s + 7.5 s). No time, no step:
        let (r, _) = eph.propagate(0.0, 60.0);
        assert_eq!(r, eph.r_m);
    }

    /// Without the lunisolar term, the equations conserve the Jacobi integral
    /// of the rotating frame, C = v²/2 − ω²(x² + y²)/2 − U with
    /// U = μ/r·(1 − J2·(a_e/r)²·(3z²/r² − 1)/2): over ±1 h it drifts by at
    /// most 5e-4 m²/s² of 1.1e7 (the integration error), where a J2 term of
    /// the wrong sign drifts by 300 m²/s². (Coriolis does no work, so its
    /// sign is checked by the two orbit comparisons above, not here.)
    #[test]
    fn jacobi_integral_is_conserved() {
        let eph = GlonassEphemeris {
            a_mps2: Vector3::zeros(),
            ..icd_example()
        };
        let jacobi = |r: &Vector3<f64>, v: &Vector3<f64>| {
            let rn = r.norm();
            let p2 = 0.5 * (3.0 * r.z * r.z / (rn * rn) - 1.0);
            let u = MU_GLO_M3PS2 / rn * (1.0 - J2_GLO * (AE_GLO_M / rn).powi(2) * p2);
            let w = OMEGA_E_GLO_RADPS;
            0.5 * v.norm_squared() - 0.5 * w * w * (r.x * r.x + r.y * r.y) - u
        };
        let c0 = jacobi(&eph.r_m, &eph.v_mps);
        for dt in [600.0, 1800.0, 3600.0, -3600.0] {
            let (r, v) = eph.propagate(dt, GLO_MAX_STEP_S);
            let dc = jacobi(&r, &v) - c0;
            assert!(dc.abs() < 2e-3, "{dt}: {dc}");
        }
        // The broadcast acceleration does work on the orbit: over the hour
        // the integral changes by ∫a·v dt ≈ 10 m²/s².
        let (r, v) = icd_example().propagate(3600.0, GLO_MAX_STEP_S);
        assert!((jacobi(&r, &v) - c0).abs() > 1.0);
    }

    /// Clock: −τn + γn·(t − t_b), across a week boundary, and γn as drift.
    #[test]
    fn clock_model() {
        let eph = GlonassEphemeris {
            week: 2300,
            toe_s: WEEK_S - 300.0,
            tau_n_s: 2.5e-5,
            gamma_n: -3.0e-12,
            ..icd_example()
        };
        // 600 s later is 300 s into the next week.
        let st = eph.state(2301, 300.0);
        assert!((st.dt_s - (-2.5e-5 - 3.0e-12 * 600.0)).abs() < 1e-18, "{}", st.dt_s);
        assert_eq!(st.ddt, -3.0e-12);
        assert!((eph.since_tb_s(2301, 300.0) - 600.0).abs() < 1e-9);
        // At t_b the state is the broadcast one.
        let st = eph.state(2300, WEEK_S - 300.0);
        assert_eq!(st.r_ecef_m, eph.r_m);
        assert_eq!(st.v_ecef_mps, eph.v_mps);
        assert_eq!(st.dt_s, -2.5e-5);
    }

    /// t_b in Moscow time to GPS time, nearest the reference (GPS − UTC =
    /// 18 s), across Moscow and UTC day and GPS week boundaries.
    #[test]
    fn moscow_time_to_gps() {
        let day = 86_400.0;
        let check = |tb_min: f64, ref_week: u32, ref_tow: f64, week: u32, tow: f64| {
            let (w, t) = glonass_tb_to_gps(tb_min, ref_week, ref_tow);
            assert_eq!(w, week, "tb {tb_min} ref {ref_week}/{ref_tow}");
            assert!((t - tow).abs() < 1e-6, "tb {tb_min}: {t} vs {tow}");
        };
        // Wednesday 21:00 UTC = Thursday 00:00 MSK. t_b 00:15 MSK Thursday is
        // Wednesday 21:15 UTC; 23:45 MSK is Wednesday's, 20:45 UTC.
        let wed_21h = 3.0 * day + 75_600.0 + 18.0;
        check(15.0, 2300, wed_21h, 2300, 3.0 * day + 76_500.0 + 18.0);
        check(1_425.0, 2300, wed_21h + 1_800.0, 2300, 3.0 * day + 74_700.0 + 18.0);
        // Midday MSK: t_b 12:15 MSK is 09:15 UTC the same day.
        check(735.0, 2300, 3.0 * day + 36_000.0, 2300, 3.0 * day + 33_300.0 + 18.0);
        // GPS week start: tow 10 s is Saturday 23:59:52 UTC, Sunday 02:59:52
        // MSK. t_b 02:45 MSK is Saturday 23:45 UTC, the previous GPS week.
        check(165.0, 2300, 10.0, 2299, WEEK_S - 900.0 + 18.0);
        // t_b 21:00 MSK is 6 h before the reference, so Saturday's.
        check(1_260.0, 2300, 10.0, 2299, WEEK_S - 6.0 * 3_600.0 + 18.0);
        // t_b 03:15 MSK just after the reference is 00:15 UTC Sunday.
        check(195.0, 2300, 10.0, 2300, 900.0 + 18.0);
    }

    #[test]
    fn carrier_frequencies() {
        let mut eph = icd_example();
        eph.freq_channel = -7;
        assert!((eph.l1_frequency_hz() - 1_598.062_5e6).abs() < 1e-3);
        eph.freq_channel = 6;
        assert!((eph.l1_frequency_hz() - 1_605.375e6).abs() < 1e-3);
        assert!((eph.l2_frequency_hz() - 1_248.625e6).abs() < 1e-3);
        assert_eq!(eph.accuracy_m(), 5.0);
    }

    /// Bad times neither hang nor panic.
    #[test]
    fn wild_times_are_bounded() {
        let eph = icd_example();
        let st = eph.state(1704, f64::NAN);
        assert_eq!(st.r_ecef_m, eph.r_m);
        let st = eph.state(1704, f64::INFINITY);
        assert_eq!(st.r_ecef_m, eph.r_m);
        let _ = eph.state(u32::MAX, 0.0);
        let _ = glonass_tb_to_gps(f64::NAN, 0, f64::NAN);
    }
}
