//! The tightly coupled GNSS update: pseudoranges and range rates against
//! satellite states from broadcast ephemerides (README.md §8).
//!
//! The receiver is at the body origin, `r = o + R_en p_B_in_W` in ECEF with
//! `o` the world origin and `R_en` the NED→ECEF rotation. Everything here
//! involves only active states (velocity, position, clock), so in compressed
//! mode it is a local update.

use nalgebra::{Matrix3, RowVector3, Vector3};

use cmsckf_sitl::geodesy::{ecef_to_llh, elevation_azimuth, NedFrame, C_MPS, OMEGA_E_RADPS};
use cmsckf_sitl::gnss::saastamoinen_m;

/// One satellite's measurements with its state at transmission time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SatMeas {
    pub system: cmsckf_sitl::gnss::System,
    pub prn: u8,
    pub r_sat_ecef_m: Vector3<f64>,
    pub v_sat_ecef_mps: Vector3<f64>,
    /// Satellite clock offset × c for the code used (m), and its rate (m/s).
    pub dts_m: f64,
    pub ddts_mps: f64,
    pub pseudorange_m: Option<f64>,
    pub range_rate_mps: Option<f64>,
    /// Pseudorange noise multiplier (3 for the ionosphere-free combination).
    pub noise_scale: f64,
    /// Added pseudorange variance (m²): an unmodelled ionosphere.
    pub extra_var_m2: f64,
}

/// Predicted pseudorange (K2): `|r_s − r| + ω_e (x_s y − y_s x)/c + b − c·δt_s + T`,
/// with its Jacobians with respect to the position in the world frame and
/// the clock bias (1). Also returns the elevation.
pub fn pseudorange(
    frame: &NedFrame,
    p_B_in_W: &Vector3<f64>,
    clock_bias_m: f64,
    s: &SatMeas,
) -> (f64, RowVector3<f64>, f64) {
    let r = frame.to_ecef(p_B_in_W);
    let d = s.r_sat_ecef_m - r;
    let rho = d.norm();
    let u = d / rho;
    let sagnac = OMEGA_E_RADPS * (s.r_sat_ecef_m.x * r.y - s.r_sat_ecef_m.y * r.x) / C_MPS;
    let (el, _) = elevation_azimuth(&r, &s.r_sat_ecef_m);
    let (lat, _, h) = ecef_to_llh(&r);
    let trop = saastamoinen_m(lat, h, el);
    // ∂ρ/∂r = −uᵀ + (ω_e/c)(−y_s, x_s, 0); the troposphere varies with height
    // (down = −height), its slope taken by a ±1 m difference of the model; its
    // variation with elevation is below 1e-6 m/m and neglected.
    let drho = -u.transpose() + RowVector3::new(-s.r_sat_ecef_m.y, s.r_sat_ecef_m.x, 0.0) * (OMEGA_E_RADPS / C_MPS);
    let dtrop_dh = (saastamoinen_m(lat, h + 1.0, el) - saastamoinen_m(lat, h - 1.0, el)) / 2.0;
    let h_p = drho * frame.R_ecef_ned + RowVector3::new(0.0, 0.0, -dtrop_dh);
    (rho + sagnac + clock_bias_m - s.dts_m + trop, h_p, el)
}

/// Predicted range rate (K3): `(v_s − v)·u + ḃ − c·δṫ_s`, with Jacobians with
/// respect to the world-frame velocity and position.
pub fn range_rate(
    frame: &NedFrame,
    p_B_in_W: &Vector3<f64>,
    v_B_in_W: &Vector3<f64>,
    clock_drift_mps: f64,
    s: &SatMeas,
) -> (f64, RowVector3<f64>, RowVector3<f64>) {
    let r = frame.to_ecef(p_B_in_W);
    let v = frame.R_ecef_ned * v_B_in_W;
    let d = s.r_sat_ecef_m - r;
    let rho = d.norm();
    let u = d / rho;
    let dv = s.v_sat_ecef_mps - v;
    // ∂u/∂r = −(I − uuᵀ)/ρ.
    let du_dr: Matrix3<f64> = -(Matrix3::identity() - u * u.transpose()) / rho;
    let h_v = -u.transpose() * frame.R_ecef_ned;
    let h_p = dv.transpose() * du_dr * frame.R_ecef_ned;
    (dv.dot(&u) + clock_drift_mps - s.ddts_mps, h_v, h_p)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sat() -> (NedFrame, SatMeas) {
        let frame = NedFrame::from_llh_deg(-33.88, 151.2, 40.0);
        let up = frame.origin_ecef.normalize();
        let east = frame.R_ecef_ned.column(1).into_owned();
        let r_sat = frame.origin_ecef + up * 2.0e7 + east * 8.0e6;
        (
            frame,
            SatMeas {
                system: cmsckf_sitl::gnss::System::Gps,
                prn: 5,
                r_sat_ecef_m: r_sat,
                v_sat_ecef_mps: Vector3::new(1200.0, -2500.0, 1800.0),
                dts_m: 30.0,
                ddts_mps: 0.01,
                pseudorange_m: None,
                range_rate_mps: None,
                noise_scale: 1.0,
                extra_var_m2: 0.0,
            },
        )
    }

    /// Jacobians of the pseudorange and range rate against central
    /// differences.
    #[test]
    fn gnss_jacobians_match_finite_differences() {
        let (frame, s) = sat();
        let p = Vector3::new(120.0, -40.0, -8.0);
        let v = Vector3::new(14.0, 3.0, -0.5);
        let (_, hp, _) = pseudorange(&frame, &p, 100.0, &s);
        let (_, hv, hp_rate) = range_rate(&frame, &p, &v, 2.0, &s);
        let h = 1e-3;
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = h;
            let fd =
                (pseudorange(&frame, &(p + d), 100.0, &s).0 - pseudorange(&frame, &(p - d), 100.0, &s).0) / (2.0 * h);
            assert!((fd - hp[k]).abs() < 1e-5, "pr/p{k}: {fd} vs {}", hp[k]);
            let fd =
                (range_rate(&frame, &p, &(v + d), 2.0, &s).0 - range_rate(&frame, &p, &(v - d), 2.0, &s).0) / (2.0 * h);
            assert!((fd - hv[k]).abs() < 1e-9, "rate/v{k}");
            let hh = 1.0;
            let mut dp = Vector3::zeros();
            dp[k] = hh;
            let fd = (range_rate(&frame, &(p + dp), &v, 2.0, &s).0 - range_rate(&frame, &(p - dp), &v, 2.0, &s).0)
                / (2.0 * hh);
            assert!((fd - hp_rate[k]).abs() < 1e-9, "rate/p{k}: {fd} vs {}", hp_rate[k]);
        }
        // Clock terms enter with unit slope.
        assert!((pseudorange(&frame, &p, 101.0, &s).0 - pseudorange(&frame, &p, 100.0, &s).0 - 1.0).abs() < 1e-9);
        assert!((range_rate(&frame, &p, &v, 3.0, &s).0 - range_rate(&frame, &p, &v, 2.0, &s).0 - 1.0).abs() < 1e-12);
    }
}
