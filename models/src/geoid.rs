//! Heights above mean sea level and above the ellipsoid: MAVLink's
//! `GPS_GLOBAL_ORIGIN` and `SET_GPS_GLOBAL_ORIGIN` carry the altitude above
//! mean sea level, while GNSS solutions and our world frame use the WGS84
//! ellipsoid. The two differ by the geoid undulation N (−107 m to +85 m),
//! from the EGM96 model (the `egm96` crate's spherical-harmonic synthesis,
//! no data files): h_ellipsoid = H_msl + N.

/// Points closer than this (degrees, in latitude and in longitude; about
/// 110 m) share one undulation: EGM96's synthesis costs ~0.3 ms, and a
/// simulator's truth at 10 Hz made it a quarter of a replay's time. N
/// changes by under 2 cm over such a step (checked below).
const REUSE_DEG: f64 = 1e-3;

thread_local! {
    /// The last point synthesised on this thread and its N.
    static LAST: std::cell::Cell<Option<(f64, f64, f64)>> = const { std::cell::Cell::new(None) };
}

/// The EGM96 geoid undulation N at a point (m; degrees in), reusing the last
/// one computed on this thread within [`REUSE_DEG`].
pub fn undulation_m(lat_deg: f64, lon_deg: f64) -> f64 {
    if let Some((lat, lon, n_m)) = LAST.get() {
        if (lat - lat_deg).abs() < REUSE_DEG && (lon - lon_deg).abs() < REUSE_DEG {
            return n_m;
        }
    }
    let n_m = egm96::egm96_compute_altitude_offset(lat_deg, lon_deg);
    if n_m.is_finite() {
        LAST.set(Some((lat_deg, lon_deg, n_m)));
    }
    n_m
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
        // Reuse within REUSE_DEG: under 2 cm off, even where the geoid is
        // steepest (the Sri Lanka low's flank, the Puerto Rico trench, the
        // Andes, the Himalaya).
        for (lat, lon) in [(4.7, 78.8), (8.0, 80.0), (19.5, -66.0), (-22.0, -68.0), (28.0, 86.9)] {
            for (dlat, dlon) in [(1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (-1.0, 1.0)] {
                let exact = egm96::egm96_compute_altitude_offset(lat + dlat * 0.999e-3, lon + dlon * 0.999e-3);
                let _ = undulation_m(lat, lon);
                let reused = undulation_m(lat + dlat * 0.999e-3, lon + dlon * 0.999e-3);
                assert!(
                    (reused - exact).abs() < 0.02,
                    "N at ({lat}, {lon}) + step: {reused} against {exact}"
                );
            }
        }
        assert!((msl_from_ellipsoid(47.4, 8.5, h) - 400.0).abs() < 1e-9);
        assert!((h - 400.0 - undulation_m(47.4, 8.5)).abs() < 1e-12);
    }
}
