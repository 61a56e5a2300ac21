//! The binary end to end on a EuRoC-layout folder: frames of a textured
//! ground plane seen through the default config's camera (EuRoC's cam0,
//! with its radtan distortion) from 3 m up, moving sideways 4 cm and
//! turning 0.2° a frame, written as PNGs with their `data.csv`, tracked by
//! `cmsckf-frontend --euroc … --config … --out …`. Every line of its output
//! is the daemon's protocol; ids persist across frames; and each track stays
//! on its ground point (the truth through the same camera model).

use std::process::Command;

use cmsckf_frontend::euroc::write_png;
use cmsckf_frontend::synthetic::{pixel_rays, plane_point, Texture};
use cmsckf_models::camera::Camera;
use cmsckf_models::sensors::CameraConfig;
use nalgebra::{Matrix3, Rotation3, Vector3};

/// The camera's pose at frame `k`: looking straight down from 3 m.
fn pose(k: u64) -> (Matrix3<f64>, Vector3<f64>) {
    let down = Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0);
    let yaw = Rotation3::from_axis_angle(&Vector3::z_axis(), 0.0035 * k as f64);
    (yaw.matrix() * down, Vector3::new(0.04 * k as f64, 0.01 * k as f64, 3.0))
}

#[test]
fn tracks_a_euroc_folder_into_protocol_lines() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("mav0/cam0/data");
    std::fs::create_dir_all(&data).unwrap();
    let tex = Texture::new(4, 1500.0);
    let cam = Camera::from_config(&CameraConfig::default());
    let rays = pixel_rays(&cam);
    // 100 texture units a metre: the blobs are 2–6 cm (3–9 px) across.
    let px_per_m = 100.0;
    let mut csv = String::from("#timestamp [ns],filename\n");
    for k in 0..8u64 {
        let (r, p) = pose(k);
        let t_ns = 1_403_636_579_763_555_584 + k * 50_000_000;
        write_png(
            &data.join(format!("{t_ns}.png")),
            &tex.render_plane(&cam, &rays, &r, &p, px_per_m),
        )
        .unwrap();
        csv += &format!("{t_ns},{t_ns}.png\n");
    }
    std::fs::write(dir.path().join("mav0/cam0/data.csv"), csv).unwrap();
    let out = dir.path().join("tracks.jsonl");
    let config = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/default.toml");
    let st = Command::new(env!("CARGO_BIN_EXE_cmsckf-frontend"))
        .args(["--euroc", dir.path().to_str().unwrap(), "--config", config, "--out"])
        .arg(&out)
        .output()
        .unwrap();
    eprintln!("{}", String::from_utf8_lossy(&st.stderr));
    assert!(st.status.success());
    let text = std::fs::read_to_string(&out).unwrap();
    let lines: Vec<serde_json::Value> = text.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), 8);
    let ids = |v: &serde_json::Value| -> std::collections::BTreeSet<u64> {
        v["features"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f[0].as_u64().unwrap())
            .collect()
    };
    for (k, l) in lines.iter().enumerate() {
        assert_eq!(l["v"], 1);
        assert_eq!(
            l["t_us"].as_u64().unwrap(),
            (1_403_636_579_763_555_584 + k as u64 * 50_000_000) / 1000
        );
        assert!(l["features"].as_array().unwrap().len() >= 140);
    }
    // Most features of the first frame are still tracked, same ids, at the last.
    let kept = ids(&lines[0]).intersection(&ids(&lines[7])).count();
    assert!(kept >= 120, "{kept} ids kept over 8 frames");
    // Each track on its ground point: within 1 px (3 m / fx on the ground)
    // of where it was first seen, for at least 95 % of the tracks.
    let one_px_m = 3.0 / cam.fx;
    let mut first: std::collections::BTreeMap<u64, ([f64; 2], f64)> = Default::default();
    for (k, l) in lines.iter().enumerate() {
        let (r, p) = pose(k as u64);
        for f in l["features"].as_array().unwrap() {
            let uv = [f[1].as_f64().unwrap(), f[2].as_f64().unwrap()];
            let g = plane_point(&cam, &r, &p, uv).unwrap();
            let e = first.entry(f[0].as_u64().unwrap()).or_insert((g, 0.0));
            e.1 = e.1.max(((g[0] - e.0[0]).powi(2) + (g[1] - e.0[1]).powi(2)).sqrt());
        }
    }
    let good = first.values().filter(|v| v.1 < one_px_m).count();
    eprintln!("{good} of {} tracks within 1 px of their ground point", first.len());
    assert!(good as f64 >= 0.95 * first.len() as f64);
    // A folder without data.csv is an error that names the file.
    let bad = Command::new(env!("CARGO_BIN_EXE_cmsckf-frontend"))
        .args(["--euroc", "/nonexistent", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("data.csv"));
}
