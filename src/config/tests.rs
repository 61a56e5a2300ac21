//! The configuration's own tests: the shipped default.toml, field errors
//! and file errors.

use super::*;

fn default_toml() -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/default.toml")).unwrap()
}

#[test]
fn default_file_equals_the_defaults_and_documents_every_field() {
    let text = default_toml();
    let cfg = Config::from_toml(&text, "default.toml").unwrap();
    assert_eq!(cfg, Config::default());
    // Every key of every section appears in the file with a comment.
    let v = toml::Value::try_from(Config::default()).unwrap();
    for (section, table) in v.as_table().unwrap() {
        assert!(text.contains(&format!("[{section}]")), "section [{section}] missing");
        for key in table.as_table().unwrap().keys() {
            let line = text
                .lines()
                .find(|l| l.trim_start().starts_with(&format!("{key} =")))
                .unwrap_or_else(|| panic!("{section}.{key} missing from default.toml"));
            assert!(line.contains('#'), "{section}.{key} has no comment: {line}");
        }
    }
}

#[test]
fn errors_name_the_field_and_the_fix() {
    let e = Config::from_toml("[estimator]\nmode = \"fast\"\n", "x")
        .unwrap_err()
        .to_string();
    assert!(e.contains("mode") && e.contains("fast"), "{e}");
    let e = Config::from_toml("[keyframe]\nintervall_s = 5\n", "x")
        .unwrap_err()
        .to_string();
    assert!(e.contains("intervall_s"), "{e}");
    let e = Config::from_toml("[compressed]\nlocal_radius_m = nan\n", "x")
        .unwrap_err()
        .to_string();
    assert!(e.contains("compressed.local_radius_m") && e.contains("finite"), "{e}");
    let e = Config::from_toml("[compressed]\nmax_local_keyframes = 1\n", "x")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("compressed.max_local_keyframes") && e.contains("2..10000"),
        "{e}"
    );
    let e = Config::from_toml("[imu]\ngyro_noise_density = -1.0\n", "x")
        .unwrap_err()
        .to_string();
    assert!(e.contains("imu.gyro_noise_density"), "{e}");
    let e = Config::from_toml("[mavlink]\naddress = \"http://x\"\n", "x")
        .unwrap_err()
        .to_string();
    assert!(e.contains("mavlink.address") && e.contains("udpin:"), "{e}");
    // Every constellation the filter has a clock for is taken.
    assert!(Config::from_toml("[gnss]\nsystems = \"G,R,C\"\n", "x").is_ok());
    let e = Config::from_toml("[gnss]\nsystems = \"G,X\"\n", "x")
        .unwrap_err()
        .to_string();
    assert!(e.contains("gnss.systems") && e.contains("G, E, R, C, J"), "{e}");
    let e = Config::from_toml("[output]\nrate_hz = 0.5\n", "x")
        .unwrap_err()
        .to_string();
    assert!(e.contains("output.rate_hz"), "{e}");
    // The real-sensor fields: each error names its field.
    for (toml, field) in [
        ("[zupt]\nsigma_mps = 0.0\n", "zupt.sigma_mps"),
        ("[zupt]\nmax_disparity_px = nan\n", "zupt.max_disparity_px"),
        ("[gnss]\nmax_delay_s = -1.0\n", "gnss.max_delay_s"),
        ("[gnss]\np_A_in_B_m = [0.0, 20.0, 0.0]\n", "gnss.p_A_in_B_m[1]"),
        ("[gnss]\nepoch_rate_hz = 0.0\n", "gnss.epoch_rate_hz"),
        (
            "[estimator]\ntime_offset_sigma_s = 0.0\n",
            "estimator.time_offset_sigma_s",
        ),
        (
            "[init]\nsigma_yaw_autopilot_deg = -5.0\n",
            "init.sigma_yaw_autopilot_deg",
        ),
    ] {
        let e = Config::from_toml(toml, "x").unwrap_err().to_string();
        assert!(e.contains(field), "{toml}: {e}");
    }
    let e = Config::load(Path::new("/nonexistent/cmsckf.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("/nonexistent/cmsckf.toml"), "{e}");
}

#[test]
fn signing_key_file_must_be_private_and_hex() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("key");
    std::fs::write(&path, format!("{}\n", "0f".repeat(32))).unwrap();
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o644)).unwrap();
    let toml = format!("[mavlink]\nsigning_key_file = \"{}\"\n", path.display());
    let e = Config::from_toml(&toml, "x").unwrap_err().to_string();
    assert!(e.contains("mavlink.signing_key_file") && e.contains("chmod 600"), "{e}");
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).unwrap();
    assert!(Config::from_toml(&toml, "x").is_ok());
    assert_eq!(load_signing_key(&path).unwrap(), [0x0f; 32]);
    std::fs::write(&path, "not hex").unwrap();
    let e = Config::from_toml(&toml, "x").unwrap_err().to_string();
    assert!(e.contains("64 hex digits"), "{e}");
    let e = Config::from_toml("[mavlink]\nsigning_key_file = \"/nonexistent/key\"\n", "x")
        .unwrap_err()
        .to_string();
    assert!(e.contains("cannot read"), "{e}");
}

/// `config/px4-sih.toml` (the sensors beside PX4's SIH, read by
/// tests/px4_sitl.rs and given to `cmsckf evaluate --config`) is the
/// defaults but for the keys it names: the camera 30° below the nose at
/// 20 Hz, and SIH's IMU noise.
#[test]
fn the_px4_sih_file_changes_only_the_camera_mount_its_rate_and_the_imu_noise() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/px4-sih.toml");
    let cfg = Config::load(&path).unwrap();
    let mut want = Config::default();
    want.camera.q_B_C_xyzw = cfg.camera.q_B_C_xyzw;
    want.camera.rate_hz = 20.0;
    want.imu.accel_noise_density = 0.12;
    want.imu.gyro_noise_density = 0.008;
    assert_eq!(cfg, want);
    let axis = cmsckf_models::camera::Camera::from_config(&cfg.camera).T_B_C.rotation * nalgebra::Vector3::z();
    let down_30 = nalgebra::Vector3::new(30f64.to_radians().cos(), 0.0, 30f64.to_radians().sin());
    assert!((axis - down_30).norm() < 1e-12, "optical axis {axis:?}");
}
