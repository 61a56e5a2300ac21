//! Heights above mean sea level and above the ellipsoid: MAVLink's
//! `GPS_GLOBAL_ORIGIN` and `SET_GPS_GLOBAL_ORIGIN` carry the altitude above
//! mean sea level, while GNSS solutions and our world frame use the WGS84
//! ellipsoid. The two differ by the geoid undulation N (−107 m to +85 m),
//! from the EGM96 model (the `egm96` crate's spherical-harmonic synthesis,
//! no data files): h_ellipsoid = H_msl + N.

/// The side of the cells N is interpolated in (degrees, in latitude and in
/// longitude; about 1.1 km). EGM96's synthesis costs ~0.3 ms, and a
/// simulator's truth at 10 Hz made it a quarter of a replay's time; within
/// a cell N is bilinear between its corners' synthesised values, under a
/// millimetre off even where the geoid is steepest (checked below), and
/// continuous from cell to cell.
const CELL_DEG: f64 = 1e-2;

/// How many grid points' N are kept per thread: the corners of the 4 cells
/// around a point and then some, so a flight that crosses a cell's edge
/// back and forth synthesises each corner once.
const KEPT: usize = 16;

/// Grid points synthesised (indices, N) and the next slot to replace (the
/// oldest).
type Kept = ([(i64, i64, f64); KEPT], usize);

thread_local! {
    static GRID: std::cell::RefCell<Kept> = const { std::cell::RefCell::new(([(i64::MIN, i64::MIN, 0.0); KEPT], 0)) };
}

/// N at grid point `(i, j)` (`i CELL_DEG` north, `j CELL_DEG` east), kept.
fn grid_n(i: i64, j: i64) -> f64 {
    GRID.with_borrow_mut(|(kept, next)| {
        if let Some(&(_, _, n)) = kept.iter().find(|k| (k.0, k.1) == (i, j)) {
            return n;
        }
        let lat = (i as f64 * CELL_DEG).clamp(-90.0, 90.0);
        let n = egm96::egm96_compute_altitude_offset(lat, j as f64 * CELL_DEG);
        kept[*next] = (i, j, n);
        *next = (*next + 1) % KEPT;
        n
    })
}

/// The EGM96 geoid undulation N at a point (m; degrees in): bilinear in the
/// [`CELL_DEG`] cell that holds it, from its corners' synthesised N (the
/// last [`KEPT`] grid points are kept on each thread).
pub fn undulation_m(lat_deg: f64, lon_deg: f64) -> f64 {
    let (y, x) = (lat_deg / CELL_DEG, lon_deg / CELL_DEG);
    let (i, j) = (y.floor(), x.floor());
    if !(i.is_finite() && j.is_finite()) || i.abs() > 1e6 || j.abs() > 1e6 {
        return egm96::egm96_compute_altitude_offset(lat_deg, lon_deg);
    }
    let (ii, jj) = (i as i64, j as i64);
    let n = [
        grid_n(ii, jj),
        grid_n(ii + 1, jj),
        grid_n(ii, jj + 1),
        grid_n(ii + 1, jj + 1),
    ];
    let (a, b) = (y - i, x - j);
    (1.0 - b) * ((1.0 - a) * n[0] + a * n[1]) + b * ((1.0 - a) * n[2] + a * n[3])
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
        // Interpolated within a cell: under a millimetre off, even where the
        // geoid is steepest (the Sri Lanka low's flank, the Puerto Rico
        // trench, the Andes, the Himalaya), and the same on both sides of a
        // cell's edge.
        let mut worst = 0.0f64;
        for (lat, lon) in [
            (4.7, 78.8),
            (8.0, 80.0),
            (19.5, -66.0),
            (-22.0, -68.0),
            (28.0, 86.9),
            (89.995, 10.0),
        ] {
            for k in 0..40 {
                let (dlat, dlon) = (0.00037 * f64::from(k % 7), 0.00053 * f64::from(k));
                let exact = egm96::egm96_compute_altitude_offset(lat + dlat, lon + dlon);
                let got = undulation_m(lat + dlat, lon + dlon);
                worst = worst.max((got - exact).abs());
            }
            let edge = (lat / CELL_DEG).ceil() * CELL_DEG;
            let (below, above) = (undulation_m(edge - 1e-12, lon), undulation_m(edge + 1e-12, lon));
            assert!(
                (below - above).abs() < 1e-6,
                "N jumps by {} m at {edge}°",
                below - above
            );
        }
        assert!(worst < 1e-3, "interpolated N {worst} m off");
        // What the synthesis itself gives for what it cannot place.
        assert!(undulation_m(f64::NAN, 0.0).is_nan());
        assert!((msl_from_ellipsoid(47.4, 8.5, h) - 400.0).abs() < 1e-9);
        assert!((h - 400.0 - undulation_m(47.4, 8.5)).abs() < 1e-12);
    }
}
