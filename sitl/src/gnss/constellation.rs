//! The simulated constellations as broadcast ephemerides: GPS's 31
//! satellites in six planes (55°, 26 559.7 km) and Galileo's Walker 24/3/1
//! (56°, 29 600 km), valid around a given week and time of week.

use rand::Rng;
use rand_distr::StandardNormal;

use cmsckf_models::gnss::{BroadcastEphemeris, System, WEEK_S};

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
