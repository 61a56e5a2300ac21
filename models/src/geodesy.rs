//! WGS-84 geodesy: geodetic ↔ ECEF, and the local NED frame at an origin.

use nalgebra::{Matrix3, Vector3};

/// WGS-84 semi-major axis (m).
pub const WGS84_A_M: f64 = 6_378_137.0;
/// WGS-84 flattening.
pub const WGS84_F: f64 = 1.0 / 298.257_223_563;
/// Earth rotation rate used by GPS (rad/s, IS-GPS-200).
pub const OMEGA_E_RADPS: f64 = 7.292_115_146_7e-5;
/// Earth's gravitational constant used by GPS (m³/s², IS-GPS-200).
pub const MU_GPS_M3PS2: f64 = 3.986_005e14;
/// Earth's gravitational constant used by Galileo (m³/s², OS SIS ICD 5.1.1).
pub const MU_GAL_M3PS2: f64 = 3.986_004_418e14;
/// Speed of light (m/s).
pub const C_MPS: f64 = 299_792_458.0;

fn e2() -> f64 {
    WGS84_F * (2.0 - WGS84_F)
}

/// Geodetic `(lat_rad, lon_rad, h_m)` to ECEF (m).
pub fn llh_to_ecef(lat_rad: f64, lon_rad: f64, h_m: f64) -> Vector3<f64> {
    let (sl, cl) = lat_rad.sin_cos();
    let n = WGS84_A_M / (1.0 - e2() * sl * sl).sqrt();
    Vector3::new(
        (n + h_m) * cl * lon_rad.cos(),
        (n + h_m) * cl * lon_rad.sin(),
        (n * (1.0 - e2()) + h_m) * sl,
    )
}

/// ECEF (m) to geodetic `(lat_rad, lon_rad, h_m)`, by fixed-point iteration
/// on latitude (converges to < 1e-12 rad in a few steps away from the core).
pub fn ecef_to_llh(r: &Vector3<f64>) -> (f64, f64, f64) {
    let p = r.xy().norm();
    let lon = r.y.atan2(r.x);
    let mut lat = r.z.atan2(p * (1.0 - e2()));
    let mut h = 0.0;
    for _ in 0..10 {
        let sl = lat.sin();
        let n = WGS84_A_M / (1.0 - e2() * sl * sl).sqrt();
        h = if lat.cos().abs() > 1e-9 {
            p / lat.cos() - n
        } else {
            r.z.abs() - n * (1.0 - e2())
        };
        lat = r.z.atan2(p * (1.0 - e2() * n / (n + h)));
    }
    (lat, lon, h)
}

/// Rotation from NED at `(lat, lon)` to ECEF: columns are north, east, down.
pub fn R_ecef_ned(lat_rad: f64, lon_rad: f64) -> Matrix3<f64> {
    let (sl, cl) = lat_rad.sin_cos();
    let (so, co) = lon_rad.sin_cos();
    Matrix3::new(-sl * co, -so, -cl * co, -sl * so, co, -cl * so, cl, 0.0, -sl)
}

/// A local NED frame anchored at an ECEF origin.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NedFrame {
    pub origin_ecef: Vector3<f64>,
    pub lat_rad: f64,
    pub lon_rad: f64,
    pub R_ecef_ned: Matrix3<f64>,
}

impl NedFrame {
    pub fn from_llh_deg(lat_deg: f64, lon_deg: f64, h_m: f64) -> Self {
        let (lat, lon) = (lat_deg.to_radians(), lon_deg.to_radians());
        Self {
            origin_ecef: llh_to_ecef(lat, lon, h_m),
            lat_rad: lat,
            lon_rad: lon,
            R_ecef_ned: R_ecef_ned(lat, lon),
        }
    }
    pub fn from_ecef(origin: &Vector3<f64>) -> Self {
        let (lat, lon, _) = ecef_to_llh(origin);
        Self {
            origin_ecef: *origin,
            lat_rad: lat,
            lon_rad: lon,
            R_ecef_ned: R_ecef_ned(lat, lon),
        }
    }
    pub fn to_ecef(&self, p_ned: &Vector3<f64>) -> Vector3<f64> {
        self.origin_ecef + self.R_ecef_ned * p_ned
    }
    pub fn to_ned(&self, r_ecef: &Vector3<f64>) -> Vector3<f64> {
        self.R_ecef_ned.transpose() * (r_ecef - self.origin_ecef)
    }
}

/// Elevation and azimuth (rad) of `r_sat` seen from `r_rx` (both ECEF).
pub fn elevation_azimuth(r_rx: &Vector3<f64>, r_sat: &Vector3<f64>) -> (f64, f64) {
    let (lat, lon, _) = ecef_to_llh(r_rx);
    let d = R_ecef_ned(lat, lon).transpose() * (r_sat - r_rx);
    let el = (-d.z).atan2(d.xy().norm());
    let az = d.y.atan2(d.x);
    (el, az)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips() {
        for (lat, lon, h) in [
            (-33.88, 151.2, 40.0),
            (35.0, 139.0, -20.0),
            (89.9, -10.0, 1000.0),
            (0.0, 0.0, 0.0),
        ] {
            let r = llh_to_ecef(f64::to_radians(lat), f64::to_radians(lon), h);
            let (la, lo, hh) = ecef_to_llh(&r);
            assert!((la.to_degrees() - lat).abs() < 1e-9 && (lo.to_degrees() - lon).abs() < 1e-9);
            assert!((hh - h).abs() < 1e-4, "{hh} vs {h}");
        }
        let f = NedFrame::from_llh_deg(-33.88, 151.2, 40.0);
        let p = Vector3::new(100.0, -50.0, -5.0);
        assert!((f.to_ned(&f.to_ecef(&p)) - p).norm() < 1e-8);
        // Down points toward the Earth's centre (roughly).
        let down = f.R_ecef_ned.column(2).into_owned();
        assert!(down.dot(&(-f.origin_ecef.normalize())) > 0.99);
        assert!((f.R_ecef_ned.determinant() - 1.0).abs() < 1e-12);
    }
}
