//! Heading from a magnetometer: the yaw a filter can start from when the
//! autopilot's own yaw is not a real one (ArduPilot with external
//! navigation as its yaw source reports a placeholder 0 until the first
//! estimate, and without GPS never sets its declination).
//!
//! The magnetic field in the world (NED) points to magnetic north, which is
//! the declination D east of true north: its horizontal part is
//! H·(cos D, sin D). Seen from a body with yaw ψ and tilt R_tilt
//! (R_W_B = R_z(ψ)·R_tilt), the field levelled by the tilt alone is
//! m_L = R_tilt·m_B = R_z(ψ)ᵀ·m_W = (H cos(D − ψ), H sin(D − ψ), Z), so
//!
//! ψ = D − atan2(m_L,y, m_L,x).                                    (M1)
//!
//! Only the field's direction is used: ArduPilot's `HIGHRES_IMU` carries it
//! 1000× too large (µG, not G), `RAW_IMU` in mG. The declination comes from
//! the World Magnetic Model (NOAA/BGS, public domain; the
//! `world_magnetic_model` crate).

use nalgebra::{UnitQuaternion, Vector3};
use world_magnetic_model::time::Date;
use world_magnetic_model::uom::si::angle::degree;
use world_magnetic_model::uom::si::f32::{Angle, Length};
use world_magnetic_model::uom::si::length::meter;
use world_magnetic_model::GeomagneticField;

/// The WMM declination (deg, east positive) and its 1σ uncertainty (deg)
/// at a point (degrees, metres above the ellipsoid) on a day given as Unix
/// days (days since 1970-01-01), or `None` outside the model's range of
/// dates, heights or latitudes.
pub fn declination_deg(lat_deg: f64, lon_deg: f64, h_m: f64, unix_days: i64) -> Option<(f64, f64)> {
    let date = Date::from_julian_day(i32::try_from(unix_days.checked_add(2_440_588)?).ok()?).ok()?;
    let field = GeomagneticField::new(
        Length::new::<meter>(h_m as f32),
        Angle::new::<degree>(lat_deg as f32),
        Angle::new::<degree>(lon_deg as f32),
        date,
    )
    .ok()?;
    Some((
        field.declination().get::<degree>() as f64,
        field.declination_uncertainty().get::<degree>() as f64,
    ))
}

/// The true heading (rad, from north towards east) of a body whose
/// rotation without yaw is `tilt` (R_tilt, body → level frame), from the
/// magnetic field `mag_B` it measures and the declination (eq. M1), or
/// `None` when the field is too short or too close to vertical to give one.
pub fn heading_rad(tilt: &UnitQuaternion<f64>, mag_B: &Vector3<f64>, declination_rad: f64) -> Option<f64> {
    let m_L = tilt * mag_B;
    let horizontal = m_L.xy().norm();
    // Within ~6° of vertical (or no field at all) the heading is noise.
    if !(horizontal.is_finite() && horizontal > 0.1 * m_L.norm()) {
        return None;
    }
    let psi = declination_rad - m_L.y.atan2(m_L.x);
    Some(psi.sin().atan2(psi.cos()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against an independent model: ArduPilot's declination table (which
    /// its SITL simulates the compass from) gives 12.80° at its SITL home
    /// (CMAC, Canberra). And the sign: east of true north in eastern
    /// Australia and the US north-west, west of it in the US north-east.
    #[test]
    fn declination_matches_ardupilot_and_its_sign() {
        let dec_2026 = 20789; // 2026-12-02 in Unix days
        for (lat, lon, sign) in [(47.6, -122.3, 1.0), (40.7, -74.0, -1.0)] {
            let (d, _) = declination_deg(lat, lon, 0.0, dec_2026).unwrap();
            assert!(d * sign > 8.0 && d * sign < 20.0, "D({lat}, {lon}) = {d}°");
        }
        let (d, sigma) = declination_deg(-35.363261, 149.165230, 604.0, dec_2026).unwrap();
        assert!((d - 12.80).abs() < 0.5, "Canberra: {d}°");
        assert!(sigma > 0.0 && sigma < 1.0, "σ {sigma}°");
        // Outside the model's dates.
        assert!(declination_deg(0.0, 0.0, 0.0, 0).is_none());
    }

    /// Eq. M1 on a field made from a known yaw, tilt and declination, and
    /// on ArduPilot SITL's own reading (RAW_IMU mag (217, −97, −528) mG,
    /// level, at a true heading of 37° where its declination is 12.80°).
    #[test]
    fn heading_from_the_field() {
        let d = 12.8f64.to_radians();
        let m_W = Vector3::new(d.cos(), d.sin(), -1.6) * 0.3;
        for (roll, pitch, yaw) in [(0.0, 0.0, 0.7), (0.2, -0.15, -2.5), (-0.3, 0.25, 3.1)] {
            let q = UnitQuaternion::from_euler_angles(roll, pitch, yaw);
            let tilt = UnitQuaternion::from_euler_angles(roll, pitch, 0.0);
            let m_B = q.inverse() * m_W;
            let psi = heading_rad(&tilt, &(m_B * 1000.0), d).unwrap();
            let err = (psi - yaw).sin().atan2((psi - yaw).cos());
            assert!(err.abs() < 1e-12, "yaw {yaw}: {psi}");
        }
        let psi = heading_rad(&UnitQuaternion::identity(), &Vector3::new(217.0, -97.0, -528.0), d).unwrap();
        assert!((psi.to_degrees() - 37.0).abs() < 0.3, "{}°", psi.to_degrees());
        assert!(heading_rad(&UnitQuaternion::identity(), &Vector3::new(0.0, 0.0, -1.0), d).is_none());
        assert!(heading_rad(&UnitQuaternion::identity(), &Vector3::zeros(), d).is_none());
    }
}
