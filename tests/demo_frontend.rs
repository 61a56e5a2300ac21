//! `cmsckf demo --frontend` end to end, as a user runs it: the SITL renders
//! the camera's images through a lens that differs from the calibration the
//! daemon is given (as a real one does) and serves them on a Unix socket,
//! cmsckf-frontend's loop tracks them and writes the daemon's feature
//! socket, the daemon flies on them and answers the SITL autopilot over
//! loopback UDP. A short racetrack (15 s, real time) with the default
//! config, the front-end's σ taken: every rendered frame reaches the front-end and every tracked
//! frame the daemon, which never resets and keeps its 30 Hz output; its
//! accuracy stays within a bound measured on this flight. Each feature
//! comes with the tracker's own σ, and with `camera.frontend_sigma` on
//! (off by default: docs/frontend.md) the filter weighs each feature by it: the NIS per degree of freedom is inside [0.5, 2] (0.65
//! on this flight; 0.027 with every feature weighed with 1 px), and the
//! log keeps the σ (its schema says so), so a replay of it is the flight bit
//! for bit.

use std::process::Command;

mod common;

#[test]
fn the_demo_flies_on_rendered_images_through_the_front_end() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("front.mcap");
    // The default config, as a user starts with, with the front-end's σ
    // taken (`camera.frontend_sigma`, off by default).
    let default = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/default.toml")).unwrap();
    assert!(
        default.contains("\nfrontend_sigma = false "),
        "the default config's frontend_sigma"
    );
    let config = dir.path().join("sigma.toml");
    std::fs::write(
        &config,
        default.replace("\nfrontend_sigma = false ", "\nfrontend_sigma = true  "),
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_cmsckf"))
        .args(["demo", "--frontend", "--duration-s", "15", "--json", "--config"])
        .arg(&config)
        .arg("--log")
        .arg(&log)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "demo failed: {stderr}");
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON report");
    eprintln!("{report}");
    assert_eq!(report["daemon_alive"], true);
    // Seen through a lens off its calibration (seed 1's: 0.16 px RMS).
    let lens = report["lens_rms_px"].as_f64().unwrap();
    assert!(lens > 0.05, "lens {lens} px off its calibration");
    assert_eq!(report["reset_count"], 0);
    // 15 s at 20 Hz, less what the camera's latency leaves past the end.
    let sent = report["frames_sent"].as_u64().unwrap();
    assert!(sent >= 290, "{sent} frames rendered and sent");
    let front = &report["frontend"];
    assert_eq!(front["frames"].as_u64().unwrap(), sent, "every frame tracked");
    assert_eq!(front["frames_not_delivered"], 0);
    assert_eq!(front["frames_out_of_order"], 0);
    assert!(front["features_detected"].as_u64().unwrap() > 1000);
    assert!(report["output_rate_hz"].as_f64().unwrap() > 25.0);
    let ate = report["ate_m"].as_f64().unwrap();
    assert!(ate.is_finite() && ate < 2.0, "ATE {ate} m");
    assert!(log.exists(), "flight log written");

    // Consistency: the NIS per dof in its band, and the χ² gate refusing
    // the tail of mis-tracks (10–12 % of tracks over 30 and 70 s, 16–18 %
    // in these 15 s of take-off and first turns) but never most of them.
    let nis = report["nis_per_dof"].as_f64().unwrap();
    assert!((0.5..=2.0).contains(&nis), "NIS per dof {nis}");
    let counters = &report["daemon_counters"];
    let used = counters["tracks_used"].as_u64().unwrap();
    let refused = counters["track_rejected_chi2"].as_u64().unwrap_or(0);
    assert!(used > 1000, "{used} tracks used");
    assert!(
        refused * 10 < (used + refused) * 3,
        "{refused} tracks refused by χ², {used} used"
    );

    // The log carries each feature's σ ...
    let messages = |p: &std::path::Path, topic: &str| -> Vec<serde_json::Value> {
        let b = std::fs::read(p).unwrap();
        mcap::MessageStream::new(&b)
            .unwrap()
            .map(|m| m.unwrap())
            .filter(|m| m.channel.topic == topic)
            .map(|m| {
                let mut v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
                if let Some(o) = v.as_object_mut() {
                    o.remove("elapsed_us");
                }
                v
            })
            .collect()
    };
    let frames = messages(&log, "/input/features");
    let (mut with_sigma, mut all) = (0, 0);
    for f in &frames {
        for feat in f["features"].as_array().unwrap() {
            all += 1;
            with_sigma += usize::from(feat.as_array().unwrap().len() == 4);
        }
    }
    assert!(
        with_sigma * 10 >= all * 9,
        "{with_sigma} of {all} logged features with a σ"
    );
    // ... every record as its channel's schema says (Python's `jsonschema`)
    let out = common::read_mcap(&[std::ffi::OsStr::new("--validate"), log.as_os_str()]);
    assert!(
        out.status.success(),
        "schema validation: {} {}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    // ... and a replay with the logged config weighs them the same.
    let replayed = dir.path().join("replay.mcap");
    cmsckf::replay::replay(&log, &replayed, None, None, false, |_, _| {}).unwrap();
    for topic in ["/filter/update/vision", "/filter/state"] {
        let (a, b) = (messages(&log, topic), messages(&replayed, topic));
        assert!(!a.is_empty(), "{topic} empty");
        assert!(a == b, "{topic}: replay differs ({} vs {} messages)", a.len(), b.len());
    }
}
