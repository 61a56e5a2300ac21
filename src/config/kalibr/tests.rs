//! Unit tests of the private helpers: Kalibr key mapping and number printing.
//! The end-to-end import is tested in `tests/calib_kalibr.rs`.

use super::convert::{camera_key, imu_key};
use super::print::num;

#[test]
fn keys_map_back_to_kalibr() {
    assert_eq!(camera_key("cam1", "camera.distortion[2]"), "cam1.distortion_coeffs[2]");
    assert_eq!(camera_key("cam0", "camera.width_px"), "cam0.resolution[0]");
    assert_eq!(camera_key("cam0", "camera.p_C_in_B_m[1]"), "cam0.T_cam_imu");
    assert_eq!(imu_key("imu0.", "imu.gyro_random_walk"), "imu0.gyroscope_random_walk");
}

#[test]
fn numbers_print_back_to_the_same_bits() {
    for x in [
        0.1,
        1.76187114e-05,
        -0.0,
        752.0,
        std::f64::consts::FRAC_1_SQRT_2,
        1e-300,
    ] {
        let t: toml::Value = toml::from_str(&format!("x = {}", num(x))).unwrap();
        assert_eq!(t["x"].as_float().unwrap().to_bits(), (x + 0.0).to_bits(), "{x}");
    }
}
