//! The daemon binary and the SITL autopilot over real loopback UDP and a real
//! Unix socket: output rate, accuracy against offline evaluation, a stable
//! reset counter, a sane covariance, and a graceful SIGTERM.

mod common;

use cmsckf::eval;
use cmsckf_sitl::dataset::Dataset;

use common::harness;

/// Runs the daemon binary against the SITL autopilot flying `scenario`
/// (10× real time), then stops it with SIGTERM. The simulated sky has no
/// ionosphere, and the antenna's lever arm is configured as it is
/// measured on the airframe.
fn fly(
    dir: &std::path::Path,
    scenario: &str,
    seed: u64,
    duration: f64,
    tweak: impl FnOnce(&mut cmsckf::config::Config),
) -> (cmsckf_sitl::serve::Report, Dataset, cmsckf::config::Config) {
    let (mut cfg, port) = common::loopback_config(dir);
    cfg.gnss.iono = cmsckf::gnss::IonoMode::Off;
    let sim = eval::sim_config_for(&cfg);
    cfg.gnss.p_A_in_B_m = sim.gnss.p_A_in_B_m;
    tweak(&mut cfg);
    let mut daemon = common::spawn_daemon_binary(&cfg, dir);
    let ds = Dataset::generate(scenario, seed, Some(duration), &sim).unwrap();
    let report = harness::fly(&harness::serve_options(&cfg, port, 10.0), &ds);
    let status = harness::sigterm(&mut daemon);
    assert!(status.success(), "daemon exit {status:?}");
    assert!(!std::path::Path::new(&cfg.features.socket).exists());
    (report, ds, cfg)
}

/// A drone that waits on the ground, climbs, and hovers between legs: its
/// standstills are zero-velocity updates, never a reset.
/// One test of this file at a time: each flies a daemon and the SITL at 10×
/// real time and then does seconds of offline work (an offline run, replay,
/// review, Python's validation). Run side by side on a 2-core machine, one's
/// offline work starved the other's flight (152 of 1199 frames dropped, the
/// IMU-to-output latency at 232 ms in one CI run).
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

#[test]
fn daemon_hovers_without_resets() {
    let _serial = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let (report, ds, cfg) = fly(dir.path(), "hover", 3, 40.0, |_| {});
    let offline = eval::score(&eval::run(&ds, &cfg, cfg.estimator.mode, 3, true));
    eprintln!("{report:?}\noffline ATE {:.3} m", offline.ate.unaligned_m);
    assert_eq!(report.reset_count, 0, "resets in a hover");
    assert!(report.covariance_ok);
    assert!(report.estimates_received as f64 > 0.9 * 30.0 * (40.0 - 2.0));
    // The daemon starts from the autopilot's attitude and position, whose
    // errors (its EKF's yaw bias, σ 2°; the position's prior is σ 3 m) the
    // offline run, started from the truth, does not have. Then the GNSS
    // codes, each satellite's broadcast error a state (estimator README
    // §8c, DG5′), move the standing vehicle's height to single point's:
    // 1.6-1.9 m high within 3 s on this flight's broadcast draw (its
    // /gnss/fix 1.2-2.8 m high), against a claimed σ of 0.75 m (2.4σ; the
    // horizontal 0.1-0.4 m at σ 0.3 m). The aligned ATE removes the constant
    // part and keeps the move. Seed 3: unaligned 1.79 m, aligned 0.47 m,
    // offline 0.105 m (with DG6's windows, whose codes were too weak to move
    // it, and every flight on one week's draw: 0.81, 0.34 and 0.155 m).
    assert!(
        report.ate_aligned_m <= 2.0 * offline.ate.unaligned_m + 0.5,
        "daemon ATE (aligned) {} vs offline {}",
        report.ate_aligned_m,
        offline.ate.unaligned_m
    );
    assert!(report.ate_m < 2.5, "daemon ATE {}", report.ate_m);
}

#[test]
fn daemon_binary_flies_the_racetrack_with_the_sitl_autopilot() {
    let _serial = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let log_path = dir.path().join("flight.mcap");
    let seed = 4;
    let duration = 40.0;
    let (report, ds, cfg) = fly(dir.path(), "racetrack", seed, duration, |cfg| {
        cfg.output.message = cmsckf::config::OutputMessage::Odometry;
        cfg.log.path = log_path.display().to_string();
        cfg.output.set_gps_origin = true;
    });

    // The SITL relays the simulated receiver's RTCM3, so compare with GNSS on.
    let offline = eval::score(&eval::run(&ds, &cfg, cfg.estimator.mode, seed, true));
    eprintln!("{report:?}\noffline ATE {:.3} m", offline.ate.unaligned_m);
    assert!(
        (report.output_rate_hz - 30.0).abs() <= 3.0,
        "rate {}",
        report.output_rate_hz
    );
    assert!(report.estimates_received as f64 > 0.9 * 30.0 * (duration - 1.0));
    // The daemon starts from its own static initialisation and the
    // autopilot's yaw (looser than evaluate's truth start), so allow twice
    // the offline error plus 0.5 m.
    assert!(
        report.ate_m <= 2.0 * offline.ate.unaligned_m + 0.5,
        "daemon ATE {} vs offline {}",
        report.ate_m,
        offline.ate.unaligned_m
    );
    assert_eq!(report.reset_count, 0);
    assert!(report.covariance_ok);
    assert!(report.time_to_first_estimate_s < 2.0);
    assert!(
        report.odometry_received == report.estimates_received
            && report.vpe_received == 0
            && report.odometry_malformed == 0,
        "{report:?}"
    );
    // The SITL autopilot has an origin of its own and says so
    // (GPS_GLOBAL_ORIGIN): the daemon takes it and sends nothing back (an
    // autopilot sets its origin once). Sending ours is flown on ArduPilot's
    // SITL (tests/ardupilot_sitl.rs: gps_origin_confirmed).
    assert!(!report.gps_origin_set, "the autopilot's own origin was sent back to it");

    // The log: finished on SIGTERM, every channel with its schema, inputs complete.
    let bytes = std::fs::read(&log_path).unwrap();
    let summary = mcap::Summary::read(&bytes)
        .unwrap()
        .expect("a finished log has a summary");
    let stats = summary.stats.expect("statistics");
    let mut per_topic = std::collections::BTreeMap::<String, u64>::new();
    for (cid, n) in &stats.channel_message_counts {
        per_topic.insert(summary.channels[cid].topic.clone(), *n);
    }
    eprintln!("{per_topic:?}");
    for ch in summary.channels.values() {
        let schema = ch.schema.as_ref().expect("schema");
        assert_eq!(schema.encoding, "jsonschema");
        assert_eq!(ch.message_encoding, "json");
    }
    assert_eq!(per_topic["/input/imu"], report.imu_sent as u64);
    // No record is stamped at 0: inputs from before the first IMU sample
    // (ephemerides, the autopilot's origin) wait for its time.
    assert!(stats.message_start_time > 0, "a record at t = 0");
    // In log-time order: each chunk after the one before (a viewer seeking
    // by time opens one), and the records in order inside them.
    let mut chunks: Vec<_> = summary.chunk_indexes.iter().collect();
    chunks.sort_by_key(|c| c.chunk_start_offset);
    let overlapping = chunks
        .windows(2)
        .filter(|w| w[1].message_start_time < w[0].message_end_time)
        .count();
    assert_eq!(
        overlapping,
        0,
        "of {} chunks, {overlapping} overlap the one before",
        chunks.len()
    );
    let mut last_log_time = 0;
    let mut backwards = 0;
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        backwards += usize::from(m.log_time < last_log_time);
        last_log_time = last_log_time.max(m.log_time);
    }
    assert_eq!(backwards, 0, "records out of log-time order");
    // Foxglove's z-up tree and the fused estimate on the map.
    assert!(per_topic["/location"] > 100 && per_topic["/tf"] > per_topic["/pose"]);
    let mut links = std::collections::BTreeSet::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        if m.channel.topic == "/tf" {
            let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
            links.insert(format!(
                "{}>{}",
                v["parent_frame_id"].as_str().unwrap(),
                v["child_frame_id"].as_str().unwrap()
            ));
        }
    }
    assert_eq!(
        links.into_iter().collect::<Vec<_>>(),
        ["base_link>camera", "map>ned", "ned>base_link"]
    );
    // Every frame sent is logged, or was dropped by a full queue and counted
    // (a loaded machine running the flight at 10× may fill one).
    let mut last_counters = serde_json::Value::Null;
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        if m.channel.topic == "/diagnostics" {
            let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
            last_counters = v["counters"].clone();
        }
    }
    let dropped: u64 = ["fusion_frames_full", "feature_queue_full"]
        .iter()
        .map(|k| last_counters[k].as_u64().unwrap_or(0))
        .sum();
    assert_eq!(
        per_topic["/input/features"] + dropped,
        report.frames_sent as u64,
        "{last_counters}"
    );
    assert!(dropped * 10 < report.frames_sent as u64, "{dropped} frames dropped");
    assert!(per_topic["/input/rtcm"] > 0 && per_topic["/filter/update/gnss"] > 0);
    assert!(per_topic["/filter/update/vision"] > 0 && per_topic["/filter/update/global"] > 0);
    assert!(per_topic["/filter/keyframes"] > 0 && per_topic["/filter/state"] > 0 && per_topic["/log"] > 0);
    assert_eq!(
        per_topic["/output/vision_position_estimate"],
        report.estimates_received as u64
    );
    assert_eq!(per_topic["/pose"], report.estimates_received as u64);
    // One body transform per estimate, and the two static links beside
    // each /filter/state record.
    assert_eq!(
        per_topic["/tf"],
        report.estimates_received as u64 + 2 * per_topic["/filter/state"]
    );
    assert!(per_topic["/gnss/fix"] > 30);
    // The counters are in the log, once a second and at shutdown.
    assert!(per_topic["/diagnostics"] > 30);
    let bytes = std::fs::read(&log_path).unwrap();
    let last_diag: serde_json::Value = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| m.unwrap())
        .filter(|m| m.channel.topic == "/diagnostics")
        .last()
        .map(|m| serde_json::from_slice(&m.data).unwrap())
        .unwrap();
    assert_eq!(
        last_diag["counters"]["imu_samples"].as_u64(),
        Some(report.imu_sent as u64),
        "{last_diag}"
    );
    let names: Vec<&str> = summary.schemas.values().map(|s| s.name.as_str()).collect();
    for n in [
        "foxglove.PoseInFrame",
        "foxglove.FrameTransform",
        "foxglove.LocationFix",
        "foxglove.Log",
    ] {
        assert!(names.contains(&n), "{n}");
    }
    let meta = summary.metadata_indexes.iter().any(|m| m.name == "cmsckf");
    assert!(meta, "header metadata");
    // Replay with the logged config: estimates and filter events are bit for
    // bit the same (the wall time spent per update is the one field that
    // differs); under Schmidt they differ.
    let replayed = dir.path().join("replay.mcap");
    let r = cmsckf::replay::replay(&log_path, &replayed, None, None, false, |_, _| {}).unwrap();
    eprintln!("{r:?}");
    assert_eq!(r.estimates_out, report.estimates_received as u64);
    let messages = |p: &std::path::Path, topic: &str| -> Vec<Vec<u8>> {
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
                serde_json::to_vec(&v).unwrap()
            })
            .collect()
    };
    for topic in [
        "/output/vision_position_estimate",
        "/filter/state",
        "/filter/update/vision",
        "/filter/update/gnss",
        "/filter/update/global",
        "/filter/keyframes",
    ] {
        let (a, b) = (messages(&log_path, topic), messages(&replayed, topic));
        assert!(!a.is_empty(), "{topic} empty");
        assert!(a == b, "{topic}: replay differs ({} vs {} messages)", a.len(), b.len());
    }
    let schmidt = dir.path().join("schmidt.mcap");
    cmsckf::replay::replay(
        &log_path,
        &schmidt,
        Some(cmsckf::estimator::Mode::Schmidt),
        None,
        false,
        |_, _| {},
    )
    .unwrap();
    assert_ne!(
        messages(&log_path, "/filter/state"),
        messages(&schmidt, "/filter/state")
    );

    // Review: the summary, the four plots, the TUM export.
    let plots = dir.path().join("plots");
    let tum = dir.path().join("traj.tum");
    let rv = cmsckf::review::review(&log_path, Some(&plots), Some(&tum), None).unwrap();
    assert_eq!(
        rv.records_out_of_time_order, 0,
        "review finds the log in log-time order"
    );
    assert!(!rv.truncated);
    assert!((rv.duration_s - 40.0).abs() < 1.0, "{}", rv.duration_s);
    assert!(rv.vision_updates > 1000 && rv.gnss_updates > 30 && rv.global_updates > 10 && rv.keyframes >= 7);
    assert!(rv.nis_in_95 > 0.8, "{}", rv.nis_in_95);
    // The restarts and the time degraded, by reason, as the daemon said.
    assert_eq!(rv.resets, 0);
    assert!(
        rv.degraded_s.values().all(|s| (0.0..=rv.duration_s).contains(s)),
        "{:?}",
        rv.degraded_s
    );
    assert!((rv.input_rates_hz["/input/imu"] - ds.cfg.imu_rate_hz).abs() < 0.02 * ds.cfg.imu_rate_hz);
    // The mock autopilot's navigation parameters (answered as ArduPilot's),
    // as the daemon read them, and none said to be wrong.
    assert_eq!(rv.autopilot_params.len(), 5, "{:?}", rv.autopilot_params);
    assert_eq!(rv.autopilot_params["VISO_TYPE"], Some(1.0));
    assert_eq!(rv.autopilot_params["EK3_SRC1_POSXY"], Some(6.0));
    assert_eq!(
        rv.counters.get("autopilot_param_misconfigured").copied().unwrap_or(0),
        0
    );
    // The error against the simulator's truth (SIM_STATE), inside the
    // filter's own 3σ most of the time.
    let rms = rv.position_error_rms_m.expect("the SITL sends its truth");
    let within = rv.position_error_within_3sigma.unwrap();
    eprintln!(
        "review: position error RMS {rms:.3} m, {:.1} % inside ±3σ",
        100.0 * within
    );
    assert!(rms < 3.0 && within > 0.8, "{rms} {within}");
    for f in ["trajectory.png", "error.png", "figure1.png", "nis.png", "timing.png"] {
        let b = std::fs::read(plots.join(f)).unwrap();
        assert!(b.len() > 10_000 && b.starts_with(b"\x89PNG"), "{f}");
    }
    assert!(std::fs::read_to_string(&tum).unwrap().lines().count() > 300);
    // The HTML report: one self-contained page with every section.
    let page_path = dir.path().join("report.html");
    cmsckf::review::review_html(&log_path, &page_path, None).unwrap();
    let page = std::fs::read_to_string(&page_path).unwrap();
    assert_eq!(page.matches("src=\"data:image/png;base64,").count(), 3);
    for section in [
        "<h2>Summary</h2>",
        "<h2>Over time</h2>",
        "<h2>Timeline</h2>",
        "Input rates",
        "Rejections, by reason",
        "Every counter",
        "Configuration in force",
        "The autopilot EKF's test ratios",
        "What we sent: ODOMETRY quality",
        "Position σ the autopilot read from what we sent",
        "filter initialised",
    ] {
        assert!(page.contains(section), "the report lacks {section}");
    }
    let plots = page.matches("class=\"cmsckf-plot\"").count();
    assert!(plots >= 5, "{plots} interactive plots");
    // The page's script draws every plot (headless Chromium, when the
    // machine has it: .ci/run installs it).
    if let Some(drawn) = common::chromium_plots_drawn(&page_path) {
        assert_eq!(drawn, plots, "the page's script drew {drawn} of {plots} plots");
    }
    // No resource from the network (uPlot's header comment names its home).
    for fetch in ["src=\"http", "href=\"http", "url(http", "fetch(", "XMLHttpRequest"] {
        assert!(!page.contains(fetch), "the report needs no network: {fetch}");
    }
    // A log cut mid-chunk is reviewed up to its last complete chunk.
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let rc = cmsckf::review::review(&cut, None, None, None).unwrap();
    assert!(rc.truncated);
    assert!(
        rc.messages > rv.messages / 3 && rc.messages < rv.messages,
        "{} of {}",
        rc.messages,
        rv.messages
    );

    // An independent reader (PyPI `mcap`, installed if missing) reads it
    // cleanly.
    // Every topic and Plot path of the Foxglove layout is in the log.
    let out = common::read_mcap(&[
        std::ffi::OsStr::new("--validate"),
        "--layout".as_ref(),
        concat!(env!("CARGO_MANIFEST_DIR"), "/docs/foxglove-layout.json").as_ref(),
        log_path.as_os_str(),
    ]);
    assert!(
        out.status.success(),
        "Python mcap reader: {} {}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    // Every message validates against its channel's JSON schema
    // (Python's `jsonschema`; CI installs it).
    let py: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let total: u64 = py["counts"]
        .as_object()
        .unwrap()
        .values()
        .map(|v| v.as_u64().unwrap())
        .sum();
    assert_eq!(py["validated"].as_u64(), Some(total));
    assert!(py["layout_paths"].as_array().is_some_and(|p| p.len() >= 7), "{py}");
    for topic in ["/keyframes", "/landmarks", "/location", "/gnss/fix"] {
        assert!(py["counts"][topic].as_u64().is_some_and(|n| n > 0), "{topic}: {py}");
    }
    assert_eq!(total, per_topic.values().sum::<u64>());
}
