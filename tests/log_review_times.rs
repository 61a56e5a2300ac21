//! `cmsckf review` is not fooled by a bad stamp: one far-future record (a
//! stamp that saturates the log's nanoseconds) and one from the past change
//! neither the duration nor the time axes, and an autopilot reboot adds its
//! time instead of folding it into the old clock's.

use cmsckf::io::mcap_log::{LogHeader, McapLogger, Topic};
use serde_json::json;

fn header() -> LogHeader {
    LogHeader {
        version: "test".into(),
        mode: "compressed".into(),
        config_toml: "[estimator]\n".into(),
    }
}

/// IMU at 100 Hz and a state at 10 Hz from `a_s` to `b_s` of sensor time.
fn fly(log: &McapLogger, a_s: f64, b_s: f64) {
    let n = ((b_s - a_s) * 100.0).round() as u64;
    for k in 0..=n {
        let t = a_s + k as f64 * 0.01;
        log.log(Topic::InputImu, t, &json!({"t_us": (t * 1e6) as u64}));
        if k % 10 == 0 {
            log.log(
                Topic::FilterState,
                t,
                &json!({"p_B_in_W": [t, 0.0, 0.0], "q_W_B_wxyz": [1.0, 0.0, 0.0, 0.0]}),
            );
        }
        if k % 200 == 0 {
            // Pace the writer (a real flight's rate).
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
    }
}

#[test]
fn one_far_future_and_one_backwards_record_leave_the_duration_sane() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bad_stamps.mcap");
    let log = McapLogger::create(std::fs::File::create(&p).unwrap(), &p, &header()).unwrap();
    fly(&log, 20.0, 35.0);
    // A far-future line (its ns saturate at u64::MAX: the 18 446 744 053 s
    // of the report) and a state stamped then.
    log.log(
        Topic::InputFeatures,
        1e12,
        &json!({"t_us": 1_000_000_000_000_000_000u64}),
    );
    log.log(
        Topic::FilterState,
        1e12,
        &json!({"p_B_in_W": [9e9, 9e9, 0.0], "q_W_B_wxyz": [1.0, 0.0, 0.0, 0.0]}),
    );
    // And one record from long ago.
    log.log(
        Topic::FilterState,
        1.5,
        &json!({"p_B_in_W": [-9e9, 0.0, 0.0], "q_W_B_wxyz": [1.0, 0.0, 0.0, 0.0]}),
    );
    fly(&log, 35.01, 50.0);
    log.finish().unwrap();

    let tum = dir.path().join("t.tum");
    let plots = dir.path().join("plots");
    let r = cmsckf::review::review(&p, Some(&plots), Some(&tum), None).unwrap();
    eprintln!("duration {} s, rates {:?}", r.duration_s, r.input_rates_hz);
    assert!((r.duration_s - 30.0).abs() < 0.1, "duration {} s", r.duration_s);
    let imu_hz = r.input_rates_hz["/input/imu"];
    assert!((imu_hz - 100.0).abs() < 1.0, "{imu_hz} Hz");
    assert!(!r.truncated);
    // The TUM trajectory (a time axis) holds the flight's poses only.
    let text = std::fs::read_to_string(&tum).unwrap();
    let times: Vec<f64> = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split(' ').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(times.len(), 301, "the 301 poses of 20–50 s, not the stray two");
    assert!(times.iter().all(|t| (20.0..=50.0).contains(t)), "{times:?}");
}

#[test]
fn a_reboot_adds_its_time_and_a_cut_log_never_wraps() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("reboot.mcap");
    let log = McapLogger::create(std::fs::File::create(&p).unwrap(), &p, &header()).unwrap();
    fly(&log, 20.0, 30.0);
    // The autopilot reboots: its boot clock restarts near 1 s.
    fly(&log, 1.0, 11.0);
    log.log(Topic::InputImu, 1e12, &json!({"t_us": 0}));
    fly(&log, 11.01, 16.0);
    log.finish().unwrap();
    let r = cmsckf::review::review(&p, None, None, None).unwrap();
    assert!((r.duration_s - 25.0).abs() < 0.1, "duration {} s", r.duration_s);

    // The same log cut mid-way (a killed writer): a duration, never a wrap.
    let bytes = std::fs::read(&p).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let r = cmsckf::review::review(&cut, None, None, None).unwrap();
    assert!(r.truncated);
    assert!(
        r.duration_s >= 0.0 && r.duration_s < 25.0,
        "duration {} s",
        r.duration_s
    );
}
