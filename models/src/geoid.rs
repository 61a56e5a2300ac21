//! Heights above mean sea level and above the ellipsoid: MAVLink's
//! `GPS_GLOBAL_ORIGIN` and `SET_GPS_GLOBAL_ORIGIN` carry the altitude above
//! mean sea level, while GNSS solutions and our world frame use the WGS84
//! ellipsoid. The two differ by the geoid undulation N (−107 m to +85 m),
//! from the EGM96 model (the `egm96` crate's spherical-harmonic synthesis,
//! no data files): h_ellipsoid = H_msl + N.

/// The EGM96 geoid undulation N at a point (m; degrees in).
pub fn undulation_m(lat_deg: f64, lon_deg: f64) -> f64 {
    egm96::egm96_compute_altitude_offset(lat_deg, lon_deg)
}

/// Height above mean sea level from height above the ellipsoid (m).
pub fn msl_from_ellipsoid(lat_deg: f64, lon_deg: f64, h_ellipsoid_m: f64) -> f64 {
    h_ellipsoid_m - undulation_m(lat_deg, lon_deg)
}

/// Height above the ellipsoid from height above mean sea level (m).
pub fn ellipsoid_from_msl(lat_deg: f64, lon_deg: f64, h_msl_m: f64) -> f64 {
    h_msl_m + undulation_m(lat_deg, lon_deg)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn undulation_matches_published_egm96_values() {
        // NGA's EGM96 values: 17.16 m at (0°, 0°); 13.61 m at the North
        // Pole; −106.99 m, the model's lowest, south of Sri Lanka near
        // (4.7°N, 78.8°E).
        for (lat, lon, n_m, tol_m) in [
            (0.0, 0.0, 17.16, 0.05),
            (90.0, 0.0, 13.61, 0.05),
            (4.7, 78.8, -106.9, 0.5),
        ] {
            let got = undulation_m(lat, lon);
            assert!((got - n_m).abs() < tol_m, "N({lat}, {lon}) = {got} m, expected {n_m} m");
        }
        let h = ellipsoid_from_msl(47.4, 8.5, 400.0);
        assert!((msl_from_ellipsoid(47.4, 8.5, h) - 400.0).abs() < 1e-9);
        assert!((h - 400.0 - undulation_m(47.4, 8.5)).abs() < 1e-12);
    }
}
