//! The International Standard Atmosphere's troposphere (ICAO Doc 7488):
//! pressure and height, one for the other. Why it exists: the autopilot's
//! barometer gives a pressure, the review and the simulator's barometer
//! need its height, and both must use the same law.

/// Sea-level pressure (Pa).
pub const P0_PA: f64 = 101_325.0;
/// `T₀ / L`: sea-level temperature over the lapse rate (m).
const T0_OVER_L_M: f64 = 44_330.77;
/// `R · L / g` (dimensionless).
const EXPONENT: f64 = 0.190_263;

/// Height above the standard sea level (m) of pressure `p_pa`:
/// `h = T₀/L · (1 − (p / p₀)^(R·L/g))`.
pub fn isa_height_m(p_pa: f64) -> f64 {
    T0_OVER_L_M * (1.0 - (p_pa / P0_PA).powf(EXPONENT))
}

/// Pressure (Pa) at height `h_m` above the standard sea level, the inverse
/// of [`isa_height_m`]: `p = p₀ · (1 − h · L/T₀)^(g/(R·L))`.
pub fn isa_pressure_pa(h_m: f64) -> f64 {
    P0_PA * (1.0 - h_m / T0_OVER_L_M).powf(1.0 / EXPONENT)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// ICAO's table: 1013.25 hPa at 0 m, 1000 hPa at 110.9 m, 900 hPa at
    /// 988.5 m, 500 hPa at 5 574 m; and the two functions invert each other.
    #[test]
    fn the_standard_atmospheres_heights_and_pressures() {
        assert!(isa_height_m(P0_PA).abs() < 1e-9);
        for (p_pa, h_m, tol_m) in [
            (100_000.0, 110.9, 0.1),
            (90_000.0, 988.5, 0.2),
            (50_000.0, 5_574.0, 1.0),
        ] {
            assert!(
                (isa_height_m(p_pa) - h_m).abs() < tol_m,
                "{p_pa} Pa: {}",
                isa_height_m(p_pa)
            );
        }
        for h_m in [-400.0, 0.0, 536.6, 4_000.0] {
            assert!((isa_height_m(isa_pressure_pa(h_m)) - h_m).abs() < 1e-6, "{h_m}");
        }
    }
}
