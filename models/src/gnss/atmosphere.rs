//! Signal delays in the atmosphere: the Saastamoinen troposphere (with
//! `1/cos z`, or its dry part with Niell's hydrostatic mapping, as code
//! differential GNSS uses it) and the broadcast (Klobuchar) ionosphere.

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

/// Saastamoinen's zenith hydrostatic delay (m) in the standard atmosphere
/// at latitude `lat_rad` and height `h_m`: the formula above with 0%
/// humidity and `z = 0`, `0.0022768 P / (1 − 0.00266 cos 2φ − 0.00028 h/km)`.
pub fn saastamoinen_zenith_hydrostatic_m(lat_rad: f64, h_m: f64) -> f64 {
    if !(-100.0..=1e4).contains(&h_m) {
        return 0.0;
    }
    let hgt = h_m.max(0.0);
    let pres = 1013.25 * (1.0 - 2.2557e-5 * hgt).powf(5.2568);
    0.0022768 * pres / (1.0 - 0.00266 * (2.0 * lat_rad).cos() - 0.00028 * hgt / 1e3)
}

/// Niell's (1996) hydrostatic mapping function at elevation `el_rad` for a
/// receiver at `lat_rad`, `h_m`, on day of year `doy` (1.0 = 1 January
/// 00:00): Marini's continued fraction
/// `m(a,b,c) = (1 + a/(1 + b/(1 + c))) / (sin e + a/(sin e + b/(sin e + c)))`
/// with `a, b, c` interpolated in |latitude| between 15° and 75° (average
/// minus amplitude × cos 2π(doy − 28)/365.25, half a year later in the south),
/// plus the height correction `(1/sin e − m(a_h, b_h, c_h)) · h/km`.
pub fn niell_hydrostatic_mapping(lat_rad: f64, h_m: f64, el_rad: f64, doy: f64) -> f64 {
    if el_rad <= 0.0 {
        return 0.0;
    }
    // Rows: a, b, c averages, then a, b, c amplitudes; columns 15°..75°.
    const COEF: [[f64; 5]; 6] = [
        [1.2769934e-3, 1.2683230e-3, 1.2465397e-3, 1.2196049e-3, 1.2045996e-3],
        [2.9153695e-3, 2.9152299e-3, 2.9288445e-3, 2.9022565e-3, 2.9024912e-3],
        [62.610505e-3, 62.837393e-3, 63.721774e-3, 63.824265e-3, 64.258455e-3],
        [0.0, 1.2709626e-5, 2.6523662e-5, 3.4000452e-5, 4.1202191e-5],
        [0.0, 2.1414979e-5, 3.0160779e-5, 7.2562722e-5, 11.723375e-5],
        [0.0, 9.0128400e-5, 4.3497037e-5, 84.795348e-5, 170.37206e-5],
    ];
    const HEIGHT: [f64; 3] = [2.53e-5, 5.49e-3, 1.14e-3];
    let lat_deg = lat_rad.to_degrees();
    let interp = |row: &[f64; 5]| {
        let i = ((lat_deg.abs() - 15.0) / 15.0).clamp(0.0, 4.0);
        let k = (i.floor() as usize).min(3);
        row[k] + (row[k + 1] - row[k]) * (i - k as f64)
    };
    let phase = (doy - 28.0) / 365.25 + if lat_deg < 0.0 { 0.5 } else { 0.0 };
    let cos_y = (2.0 * std::f64::consts::PI * phase).cos();
    let abc: [f64; 3] = std::array::from_fn(|k| interp(&COEF[k]) - interp(&COEF[k + 3]) * cos_y);
    let sin_el = el_rad.sin();
    let marini =
        |a: f64, b: f64, c: f64| (1.0 + a / (1.0 + b / (1.0 + c))) / (sin_el + a / (sin_el + b / (sin_el + c)));
    let dm = (1.0 / sin_el - marini(HEIGHT[0], HEIGHT[1], HEIGHT[2])) * h_m / 1e3;
    marini(abc[0], abc[1], abc[2]) + dm
}

/// Klobuchar's broadcast ionosphere model (IS-GPS-200, 20.3.3.5.2.5).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Klobuchar {
    pub alpha: [f64; 4],
    pub beta: [f64; 4],
}

impl Klobuchar {
    /// L1 ionospheric delay (m) seen from geodetic `(lat, lon)` (rad) toward
    /// azimuth/elevation `(az, el)` (rad) at GPS time of week `tow_s`.
    pub fn delay_m(&self, lat: f64, lon: f64, az: f64, el: f64, tow_s: f64) -> f64 {
        let pi = std::f64::consts::PI;
        let e = el / pi; // semicircles
        let psi = 0.0137 / (e + 0.11) - 0.022;
        let phi_i = (lat / pi + psi * az.cos()).clamp(-0.416, 0.416);
        let lam_i = lon / pi + psi * az.sin() / (phi_i * pi).cos();
        let phi_m = phi_i + 0.064 * ((lam_i - 1.617) * pi).cos();
        let t = (43_200.0 * lam_i + tow_s).rem_euclid(86_400.0);
        let f = 1.0 + 16.0 * (0.53 - e).powi(3);
        let poly = |c: &[f64; 4]| c[0] + phi_m * (c[1] + phi_m * (c[2] + phi_m * c[3]));
        let amp = poly(&self.alpha).max(0.0);
        let per = poly(&self.beta).max(72_000.0);
        let x = 2.0 * pi * (t - 50_400.0) / per;
        let delay_s = if x.abs() < 1.57 {
            f * (5e-9 + amp * (1.0 - x * x / 2.0 + x.powi(4) / 24.0))
        } else {
            f * 5e-9
        };
        delay_s * crate::geodesy::C_MPS
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Niell's hydrostatic mapping against values computed separately from
    /// the published coefficients (RTKLIB's implementation, evaluated
    /// by hand in a short script): zenith is 1, low elevations grow, the
    /// southern hemisphere is half a year apart.
    #[test]
    fn niell_hydrostatic_mapping_values() {
        let m = |lat: f64, h: f64, el: f64| niell_hydrostatic_mapping(lat.to_radians(), h, el.to_radians(), 92.0);
        assert!((m(45.0, 0.0, 90.0) - 1.0).abs() < 1e-6);
        assert!((m(45.0, 0.0, 10.0) - 5.5535120).abs() < 1e-6, "{}", m(45.0, 0.0, 10.0));
        assert!(
            (m(35.0, 100.0, 30.0) - 1.9926278).abs() < 1e-6,
            "{}",
            m(35.0, 100.0, 30.0)
        );
        assert!(
            (m(-35.0, 100.0, 30.0) - 1.9925365).abs() < 1e-6,
            "{}",
            m(-35.0, 100.0, 30.0)
        );
        assert!((m(10.0, 0.0, 5.0) - 10.1003469).abs() < 1e-6, "{}", m(10.0, 0.0, 5.0));
        assert_eq!(m(45.0, 0.0, -1.0), 0.0);
    }

    /// The hydrostatic zenith delay at sea level on the equator (2.3131 m,
    /// 0.0022768 × 1013.25 / (1 − 0.00266)) and Saastamoinen's full model
    /// with 0 % humidity at zenith being the same number.
    #[test]
    fn zenith_hydrostatic_delay() {
        let zhd = saastamoinen_zenith_hydrostatic_m(0.0, 0.0);
        assert!((zhd - 0.0022768 * 1013.25 / (1.0 - 0.00266)).abs() < 1e-12);
        assert!((zhd - 2.3131).abs() < 1e-4, "{zhd}");
        assert_eq!(saastamoinen_zenith_hydrostatic_m(0.0, 2e4), 0.0);
    }
}
