//! Signal delays in the atmosphere: the Saastamoinen troposphere and the
//! broadcast (Klobuchar) ionosphere.

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
