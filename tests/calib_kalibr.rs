//! `cmsckf calib import-kalibr`: Kalibr's camchain-imucam.yaml and imu.yaml
//! into the config.
//!
//! The files in `tests/data/kalibr/` are hand-written in Kalibr's format with
//! rotations whose inverse and quaternion are worked out by hand in
//! `tests/data/kalibr/README.md`; every expected number below comes from
//! there. The printed TOML is merged into `config/default.toml` and must load
//! as a `Config` with those numbers.
#![allow(non_snake_case)] // names carry frames: T_B_C, R_CI

use std::path::{Path, PathBuf};
use std::process::Command;

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};

use cmsckf::config::kalibr::{ImportOptions, ImuFrame, KalibrImport};
use cmsckf::config::Config;
use cmsckf_models::camera::Camera;
use cmsckf_models::sensors::CameraModelKind;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn data(name: &str) -> PathBuf {
    root().join("tests/data/kalibr").join(name)
}

/// Runs the binary from the repository root: (success, stdout, stderr).
fn cmsckf(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_cmsckf"))
        .args(args)
        .current_dir(root())
        .env("RUST_BACKTRACE", "0")
        .output()
        .expect("run cmsckf");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// `config/default.toml` with every key of the printed sections set, loaded
/// (and validated) as a `Config`.
fn merged_into_default(printed: &str) -> Config {
    let text = std::fs::read_to_string(root().join("config/default.toml")).unwrap();
    let mut base: toml::Table = toml::from_str(&text).unwrap();
    let sections: toml::Table = toml::from_str(printed).unwrap_or_else(|e| panic!("{e}\n{printed}"));
    for (name, table) in sections {
        let dst = base
            .get_mut(&name)
            .and_then(|v| v.as_table_mut())
            .unwrap_or_else(|| panic!("[{name}] is not a section of default.toml"));
        for (k, v) in table.as_table().unwrap() {
            assert!(dst.contains_key(k), "{name}.{k} is not a config key");
            dst.insert(k.clone(), v.clone());
        }
    }
    Config::from_toml(&toml::to_string(&base).unwrap(), "merged").unwrap_or_else(|e| panic!("{e}\n{printed}"))
}

fn close(a: &[f64], b: &[f64], tol: f64) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
}

fn assert_close(what: &str, got: &[f64], want: &[f64]) {
    assert!(close(got, want, 1e-12), "{what}: got {got:?}, want {want:?}");
}

/// `T_cam_imu` as written in the camchain file (hand-copied).
fn T_cam_imu(R: [[f64; 3]; 3], t: [f64; 3]) -> Isometry3<f64> {
    let R = Matrix3::from_fn(|r, c| R[r][c]);
    let q = nalgebra::UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(R));
    Isometry3::from_parts(Vector3::from(t).into(), q)
}

const SQRT_HALF: f64 = std::f64::consts::FRAC_1_SQRT_2;

#[test]
fn cam0_and_imu_print_sections_that_load_with_the_hand_computed_numbers() {
    let (ok, out, err) = cmsckf(&[
        "calib",
        "import-kalibr",
        "tests/data/kalibr/camchain-imucam.yaml",
        "tests/data/kalibr/imu.yaml",
        "--imu-frame",
        "frd",
    ]);
    assert!(ok, "{err}");
    assert!(err.is_empty(), "no warning expected: {err}");
    let cfg = merged_into_default(&out);
    let c = &cfg.camera;
    assert_eq!(c.model, CameraModelKind::PinholeRadtan);
    assert_eq!((c.width_px, c.height_px), (752, 480));
    assert_close("intrinsics", &c.intrinsics, &[460.5, 459.25, 376.0, 240.5]);
    assert_close("distortion", &c.distortion, &[-0.2834, 0.07396, 0.000194, -1.76e-05]);
    // T_B_C = T_cam_imu⁻¹: R_B_C = R_CIᵀ (x_C = y_B, y_C = z_B, z_C = x_B),
    // 120° about (1, 1, 1); p_C_in_B = −R_CIᵀ t_CI.
    assert_close("q_B_C_xyzw", &c.q_B_C_xyzw, &[0.5, 0.5, 0.5, 0.5]);
    assert_close("p_C_in_B_m", &c.p_C_in_B_m, &[0.1, 0.02, 0.05]);
    // Not Kalibr's: kept from the defaults.
    assert_eq!(c.pixel_noise_px, 1.0);
    assert_eq!(c.rate_hz, 30.0);
    // Same sign: t_imu = t_cam + timeshift_cam_imu = t_cam + t_d.
    assert_eq!(cfg.estimator.time_offset_s, 0.0125);
    // Continuous-time densities in the same units: unchanged.
    let i = &cfg.imu;
    assert_close(
        "imu",
        &[
            i.accel_noise_density,
            i.accel_random_walk,
            i.gyro_noise_density,
            i.gyro_random_walk,
            i.gravity_mps2,
        ],
        &[2.5e-3, 5.0e-4, 1.5e-4, 3.0e-6, 9.81],
    );
    // Nothing else moved.
    let d = Config::default();
    assert_eq!(cfg.estimator.time_offset_sigma_s, d.estimator.time_offset_sigma_s);
    assert_eq!(cfg.mavlink, d.mavlink);

    // The [camera] and [imu] sections are whole (they can replace the user's).
    let printed: toml::Table = toml::from_str(&out).unwrap();
    let defaults = toml::Value::try_from(Config::default()).unwrap();
    for section in ["camera", "imu"] {
        let mut want: Vec<&String> = defaults[section].as_table().unwrap().keys().collect();
        let mut got: Vec<&String> = printed[section].as_table().unwrap().keys().collect();
        want.sort();
        got.sort();
        assert_eq!(got, want, "[{section}] must hold every key");
    }
    let est: Vec<&String> = printed["estimator"].as_table().unwrap().keys().collect();
    assert_eq!(est, ["time_offset_s"]);

    // The library gives the same config, bit for bit: the print round-trips.
    let base = Config::default();
    let opts = ImportOptions {
        camera: "cam0",
        imu_frame: ImuFrame::Frd,
        base: &base,
        base_origin: "the defaults",
    };
    let import = KalibrImport::load(&data("camchain-imucam.yaml"), Some(&data("imu.yaml")), &opts).unwrap();
    let mut direct = Config::default();
    import.apply(&mut direct);
    assert_eq!(direct, cfg);
    assert_eq!(import.imu.as_ref().unwrap().update_rate_hz, 400.0);
}

#[test]
fn the_imported_pose_maps_points_as_kalibr_does() {
    // A point in the IMU (= body, FRD) frame, taken into cam0 and cam1 by
    // Kalibr's T_cam_imu and by the imported T_B_C⁻¹: the same point.
    let T0 = T_cam_imu(
        [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]],
        [-0.02, -0.05, -0.1],
    );
    let T1 = T_cam_imu(
        [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
        [0.03, 0.05, -0.08],
    );
    let base = Config::default();
    let mut cams = Vec::new();
    for (name, T) in [("cam0", T0), ("cam1", T1)] {
        let opts = ImportOptions {
            camera: name,
            imu_frame: ImuFrame::Frd,
            base: &base,
            base_origin: "the defaults",
        };
        let import = KalibrImport::load(&data("camchain-imucam.yaml"), None, &opts).unwrap();
        let cam = Camera::from_config(&import.camera);
        for p in [[4.0, -0.5, 1.25], [0.3, 2.0, -7.0]] {
            let p_I = Point3::from(p);
            let kalibr = T * p_I;
            let ours = cam.T_B_C.inverse() * p_I;
            assert!((kalibr - ours).norm() < 1e-12, "{name}: {kalibr} vs {ours}");
        }
        cams.push(cam);
    }
    // And Kalibr's own chain: cam1's T_cn_cnm1 = T_c1_c0 = T_c1_B T_B_c0.
    let text = std::fs::read_to_string(data("camchain-imucam.yaml")).unwrap();
    let doc = &yaml_rust2::YamlLoader::load_from_str(&text).unwrap()[0];
    let rows = doc["cam1"]["T_cn_cnm1"].as_vec().unwrap();
    let m = |r: usize, c: usize| rows[r].as_vec().unwrap()[c].as_f64().unwrap();
    let T_c1_c0 = cams[1].T_B_C.inverse() * cams[0].T_B_C;
    let R = T_c1_c0.rotation.to_rotation_matrix();
    for r in 0..3 {
        for c in 0..3 {
            assert!((R[(r, c)] - m(r, c)).abs() < 1e-12, "R_c1_c0[{r}][{c}]");
        }
        assert!((T_c1_c0.translation.vector[r] - m(r, 3)).abs() < 1e-12, "t_c1_c0[{r}]");
    }
}

#[test]
fn camera_flag_picks_cam1_an_equidistant_downward_camera() {
    let (ok, out, err) = cmsckf(&[
        "calib",
        "import-kalibr",
        "tests/data/kalibr/camchain-imucam.yaml",
        "--camera",
        "cam1",
        "--imu-frame",
        "frd",
    ]);
    assert!(ok, "{err}");
    assert!(!out.contains("\n[imu]"), "no imu.yaml, no [imu]:\n{out}");
    let cfg = merged_into_default(&out);
    let c = &cfg.camera;
    assert_eq!(c.model, CameraModelKind::PinholeEquidistant);
    assert_eq!((c.width_px, c.height_px), (640, 480));
    assert_close("intrinsics", &c.intrinsics, &[285.75, 285.5, 320.25, 240.75]);
    assert_close("distortion", &c.distortion, &[-0.0125, 0.0485, -0.0625, 0.0225]);
    // R_B_C = R_CIᵀ: x_C = y_B, y_C = −x_B, z_C = z_B: +90° about z_B.
    assert_close("q_B_C_xyzw", &c.q_B_C_xyzw, &[0.0, 0.0, SQRT_HALF, SQRT_HALF]);
    assert_close("p_C_in_B_m", &c.p_C_in_B_m, &[0.05, -0.03, 0.08]);
    assert_eq!(cfg.estimator.time_offset_s, -0.0042);
    assert_eq!(cfg.imu, Config::default().imu);
}

#[test]
fn flu_imu_data_is_turned_into_the_frd_body_frame() {
    // The same forward camera, calibrated against IMU data in ROS's FLU axes
    // (as MAVROS republishes the autopilot's IMU).
    let (ok, out, err) = cmsckf(&[
        "calib",
        "import-kalibr",
        "tests/data/kalibr/camchain-imucam-flu.yaml",
        "--imu-frame",
        "flu",
    ]);
    assert!(ok, "{err}");
    assert!(err.is_empty(), "{err}");
    let cfg = merged_into_default(&out);
    assert_close("q_B_C_xyzw", &cfg.camera.q_B_C_xyzw, &[0.5, 0.5, 0.5, 0.5]);
    assert_close("p_C_in_B_m", &cfg.camera.p_C_in_B_m, &[0.1, 0.02, 0.05]);

    // The wrong frame either way hangs the camera upside down: a warning,
    // on stderr and in the printed sections, that names the other frame.
    for (file, frame, other) in [
        ("tests/data/kalibr/camchain-imucam-flu.yaml", "frd", "--imu-frame flu"),
        ("tests/data/kalibr/camchain-imucam.yaml", "flu", "--imu-frame frd"),
    ] {
        let (ok, out, err) = cmsckf(&["calib", "import-kalibr", file, "--imu-frame", frame]);
        assert!(ok, "{err}");
        assert!(err.contains("upside down") && err.contains(other), "{frame}: {err}");
        assert!(out.contains("# WARNING") && out.contains(other), "{out}");
        merged_into_default(&out);
    }
}

#[test]
fn other_keys_are_kept_from_the_given_config() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mine.toml");
    std::fs::write(
        &path,
        "[camera]\nrate_hz = 20.0\npixel_noise_px = 0.7\n[imu]\ngravity_mps2 = 9.80\n",
    )
    .unwrap();
    let (ok, out, err) = cmsckf(&[
        "calib",
        "import-kalibr",
        "tests/data/kalibr/camchain-imucam.yaml",
        "tests/data/kalibr/imu.yaml",
        "--imu-frame",
        "frd",
        "--config",
        path.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(out.contains(&format!("kept from {}", path.display())), "{out}");
    let cfg = merged_into_default(&out);
    assert_eq!((cfg.camera.rate_hz, cfg.camera.pixel_noise_px), (20.0, 0.7));
    assert_eq!(cfg.imu.gravity_mps2, 9.80);
    assert_eq!(cfg.imu.gyro_noise_density, 1.5e-4);
}

// ---- errors: each names the file and the key ----

const CAM0: &str = "cam0:
  T_cam_imu:
  - [0.0, 1.0, 0.0, -0.02]
  - [0.0, 0.0, 1.0, -0.05]
  - [1.0, 0.0, 0.0, -0.1]
  - [0.0, 0.0, 0.0, 1.0]
  camera_model: pinhole
  distortion_coeffs: [-0.2834, 0.07396, 0.000194, -1.76e-05]
  distortion_model: radtan
  intrinsics: [460.5, 459.25, 376.0, 240.5]
  resolution: [752, 480]
  rostopic: /cam0/image_raw
  timeshift_cam_imu: 0.0125
";

const IMU: &str = "accelerometer_noise_density: 2.5e-03
accelerometer_random_walk: 5.0e-04
gyroscope_noise_density: 1.5e-04
gyroscope_random_walk: 3.0e-06
rostopic: /imu0
update_rate: 400.0
";

fn import(camchain: &str, imu: Option<&str>, camera: &str) -> Result<KalibrImport, String> {
    let base = Config::default();
    let opts = ImportOptions {
        camera,
        imu_frame: ImuFrame::Frd,
        base: &base,
        base_origin: "the defaults",
    };
    KalibrImport::from_text(camchain, "bad-camchain.yaml", imu.map(|t| (t, "bad-imu.yaml")), &opts)
        .map_err(|e| e.to_string())
}

#[test]
fn the_test_template_itself_imports() {
    let i = import(CAM0, Some(IMU), "cam0").unwrap();
    assert_eq!(i.camera.q_B_C_xyzw, [0.5, 0.5, 0.5, 0.5]);
    // `distortion_model: none` is a radtan camera without distortion.
    let none = CAM0.replace("distortion_model: radtan", "distortion_model: none");
    let none = none.replace(
        "  distortion_coeffs: [-0.2834, 0.07396, 0.000194, -1.76e-05]\n",
        "  distortion_coeffs: []\n",
    );
    let i = import(&none, None, "cam0").unwrap();
    assert_eq!(i.camera.model, CameraModelKind::PinholeRadtan);
    assert_eq!(i.camera.distortion, [0.0; 4]);
    merged_into_default(&i.to_toml());
}

#[test]
fn camchain_errors_name_the_file_and_the_key() {
    let t_rows =
        "  - [0.0, 1.0, 0.0, -0.02]\n  - [0.0, 0.0, 1.0, -0.05]\n  - [1.0, 0.0, 0.0, -0.1]\n  - [0.0, 0.0, 0.0, 1.0]\n";
    let cases: &[(&str, &str, &[&str])] = &[
        // A cameras-only camchain.yaml: no IMU in it.
        (
            &format!("  T_cam_imu:\n{t_rows}"),
            "",
            &["`cam0.T_cam_imu` is missing", "kalibr_calibrate_imu_camera"],
        ),
        (
            "  timeshift_cam_imu: 0.0125\n",
            "",
            &["`cam0.timeshift_cam_imu` is missing"],
        ),
        (
            "  intrinsics: [460.5, 459.25,",
            "  intrinsics: [460.5, .nan,",
            &["`cam0.intrinsics[1]`", "finite"],
        ),
        (
            "timeshift_cam_imu: 0.0125",
            "timeshift_cam_imu: .inf",
            &["`cam0.timeshift_cam_imu`", "finite"],
        ),
        (
            "timeshift_cam_imu: 0.0125",
            "timeshift_cam_imu:",
            &["`cam0.timeshift_cam_imu`", "expected a number"],
        ),
        (
            "timeshift_cam_imu: 0.0125",
            "timeshift_cam_imu: 0.8",
            &["`cam0.timeshift_cam_imu`", "0.5 s"],
        ),
        // A rotation that is not one: a scaled row, a reflection.
        (
            "[0.0, 1.0, 0.0, -0.02]",
            "[0.0, 1.1, 0.0, -0.02]",
            &["`cam0.T_cam_imu`", "orthonormal"],
        ),
        (
            "[1.0, 0.0, 0.0, -0.1]",
            "[-1.0, 0.0, 0.0, -0.1]",
            &["`cam0.T_cam_imu`", "reflection"],
        ),
        (
            "[0.0, 0.0, 0.0, 1.0]",
            "[0.0, 0.0, 0.1, 1.0]",
            &["`cam0.T_cam_imu[3]`", "[0, 0, 0, 1]"],
        ),
        (
            "[0.0, 1.0, 0.0, -0.02]",
            "[0.0, 1.0, 0.0]",
            &["`cam0.T_cam_imu[0]`", "4 numbers"],
        ),
        // A camera 20 m from the IMU: the config's own check, said in Kalibr's terms.
        (
            "[1.0, 0.0, 0.0, -0.1]",
            "[1.0, 0.0, 0.0, -20.0]",
            &["`cam0.T_cam_imu`", "`camera.p_C_in_B_m[0]`, which the config refuses"],
        ),
        (
            "distortion_model: radtan",
            "distortion_model: fov",
            &["`cam0.distortion_model`", "'fov'", "radtan"],
        ),
        (
            "camera_model: pinhole",
            "camera_model: omni",
            &["`cam0.camera_model`", "'omni'", "pinhole"],
        ),
        (
            "intrinsics: [460.5, 459.25, 376.0, 240.5]",
            "intrinsics: [460.5, 459.25, 376.0]",
            &["`cam0.intrinsics`", "4 numbers"],
        ),
        (
            "intrinsics: [460.5,",
            "intrinsics: [abc,",
            &["`cam0.intrinsics[0]`", "'abc' is not a number"],
        ),
        (
            "intrinsics: [460.5,",
            "intrinsics: [0.5,",
            &["`cam0.intrinsics[0]`", "camera.intrinsics[0]"],
        ),
        (
            "resolution: [752, 480]",
            "resolution: [752.5, 480]",
            &["`cam0.resolution[0]`", "whole number"],
        ),
        (
            "resolution: [752, 480]",
            "resolution: 752",
            &["`cam0.resolution`", "[width, height]"],
        ),
        (
            "distortion_coeffs: [-0.2834, 0.07396, 0.000194, -1.76e-05]",
            "distortion_coeffs: [-0.2834, 0.07396, 0.000194, 11.0]",
            &["`cam0.distortion_coeffs[3]`"],
        ),
    ];
    for (from, to, want) in cases {
        assert!(CAM0.contains(from), "bad case: {from}");
        let text = CAM0.replace(from, to);
        let e = import(&text, None, "cam0").expect_err(&format!("{from} -> {to} must fail"));
        assert!(e.contains("'bad-camchain.yaml'"), "{e}");
        for w in *want {
            assert!(e.contains(w), "{from} -> {to}: want '{w}' in: {e}");
        }
    }
    // The camera asked for is not there: the error lists those that are.
    let e = import(CAM0, None, "cam1").unwrap_err();
    assert!(
        e.contains("`cam1` is missing") && e.contains("cam0") && e.contains("bad-camchain.yaml"),
        "{e}"
    );
    // Not YAML, empty, not a mapping.
    for (text, want) in [
        ("cam0: [unclosed\n", "is not YAML"),
        ("", "no YAML document"),
        ("just words\n", "not a mapping"),
        ("cam0: 3\n", "`cam0`: expected a camera's mapping"),
    ] {
        let e = import(text, None, "cam0").unwrap_err();
        assert!(e.contains("'bad-camchain.yaml'") && e.contains(want), "{text:?}: {e}");
    }
}

#[test]
fn imu_errors_name_the_file_and_the_key() {
    let cases: &[(&str, &str, &[&str])] = &[
        (
            "gyroscope_random_walk: 3.0e-06\n",
            "",
            &["`gyroscope_random_walk` is missing"],
        ),
        (
            "accelerometer_random_walk: 5.0e-04",
            "accelerometer_random_walk: 0.0",
            &["`accelerometer_random_walk`", "greater than zero"],
        ),
        (
            "gyroscope_noise_density: 1.5e-04",
            "gyroscope_noise_density: abc",
            &["`gyroscope_noise_density`", "not a number"],
        ),
        (
            "gyroscope_noise_density: 1.5e-04",
            "gyroscope_noise_density: .nan",
            &["`gyroscope_noise_density`", "finite"],
        ),
        (
            "update_rate: 400.0",
            "update_rate: -1",
            &["`update_rate`", "greater than zero"],
        ),
        (
            "accelerometer_noise_density: 2.5e-03",
            "accelerometer_noise_density: 5.0",
            &["`accelerometer_noise_density`", "imu.accel_noise_density"],
        ),
        (
            "accelerometer_noise_density: 2.5e-03\n",
            "",
            &["`accelerometer_noise_density` is missing"],
        ),
    ];
    for (from, to, want) in cases {
        assert!(IMU.contains(from), "bad case: {from}");
        let e = import(CAM0, Some(&IMU.replace(from, to)), "cam0").expect_err(&format!("{from} -> {to}"));
        assert!(e.contains("'bad-imu.yaml'"), "{e}");
        for w in *want {
            assert!(e.contains(w), "{from} -> {to}: want '{w}' in: {e}");
        }
    }
    // Kalibr's results file (imu-*.yaml) holds the same keys under imu0.
    let results = format!(
        "imu0:\n  T_i_b:\n  - [1.0, 0.0, 0.0, 0.0]\n  - [0.0, 1.0, 0.0, 0.0]\n  - [0.0, 0.0, 1.0, 0.0]\n  - [0.0, 0.0, 0.0, 1.0]\n{}  model: calibrated\n  time_offset: 0.0\n",
        IMU.lines().map(|l| format!("  {l}\n")).collect::<String>()
    );
    let i = import(CAM0, Some(&results), "cam0").unwrap();
    assert_eq!(i.imu.as_ref().unwrap().imu.gyro_random_walk, 3.0e-6);
    let e = import(
        CAM0,
        Some(&results.replace("gyroscope_noise_density: 1.5e-04", "gyroscope_noise_density: []")),
        "cam0",
    )
    .unwrap_err();
    assert!(
        e.contains("`imu0.gyroscope_noise_density`") && e.contains("bad-imu.yaml"),
        "{e}"
    );
}

#[test]
fn the_command_line_reports_missing_files_and_a_missing_frame() {
    let (ok, _, err) = cmsckf(&[
        "calib",
        "import-kalibr",
        "/nonexistent/camchain.yaml",
        "--imu-frame",
        "frd",
    ]);
    assert!(
        !ok && err.contains("/nonexistent/camchain.yaml") && err.contains("cannot read"),
        "{err}"
    );
    let (ok, _, err) = cmsckf(&[
        "calib",
        "import-kalibr",
        "tests/data/kalibr/camchain-imucam.yaml",
        "/nonexistent/imu.yaml",
        "--imu-frame",
        "frd",
    ]);
    assert!(!ok && err.contains("/nonexistent/imu.yaml"), "{err}");
    // The frame has no default: the wrong one turns the camera over.
    let (ok, _, err) = cmsckf(&["calib", "import-kalibr", "tests/data/kalibr/camchain-imucam.yaml"]);
    assert!(!ok && err.contains("--imu-frame"), "{err}");
    let (ok, _, err) = cmsckf(&[
        "calib",
        "import-kalibr",
        "tests/data/kalibr/camchain-imucam.yaml",
        "--camera",
        "cam7",
        "--imu-frame",
        "frd",
    ]);
    assert!(
        !ok && err.contains("`cam7` is missing") && err.contains("cam0, cam1"),
        "{err}"
    );
    let (ok, _, err) = cmsckf(&["calib", "import-kalibr", "README.md", "--imu-frame", "frd"]);
    assert!(!ok && err.contains("'README.md' is not YAML"), "{err}");
}
