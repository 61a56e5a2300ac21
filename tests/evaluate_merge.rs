//! `cmsckf evaluate --seed K --flights-out F` and `--merge`: seeds flown
//! apart (a sweep's tasks on other machines, `fleet/`) summarise to the same
//! answers as one `cmsckf evaluate` over them all, digit for digit, and a
//! merge refuses what does not belong together, saying why.

use std::path::Path;
use std::process::Command;

/// The fields that are wall-clock timings of the machine that flew, which
/// differ between any two runs (even of one `evaluate`), never answers.
const TIMINGS: [&str; 7] = [
    "frame_us_mean",
    "frame_us_p99",
    "frame_us_p50",
    "frame_us_max",
    "rebase_ms_mean",
    "rebase_ms_max",
    "rebase_ms",
];

const FLIGHT: [&str; 6] = [
    "--scenario",
    "racetrack",
    "--modes",
    "msckf,full,compressed",
    "--duration-s",
    "8",
];

fn cmsckf(args: &[&str], dir: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_cmsckf"))
        .args(args)
        .current_dir(dir)
        .env("RUST_BACKTRACE", "0")
        .output()
        .expect("running cmsckf")
}

fn json_of(out: &std::process::Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "cmsckf failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("evaluate --json prints JSON");
    for (_, m) in v["modes"].as_object_mut().expect("modes").iter_mut() {
        for t in TIMINGS {
            m.as_object_mut().expect("a mode's summary").remove(t);
        }
    }
    v
}

#[test]
fn seeds_flown_apart_and_merged_equal_one_evaluation() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let whole = json_of(&cmsckf(
        &[&["evaluate", "--json", "--seeds", "3"][..], &FLIGHT].concat(),
        d,
    ));
    assert_eq!(whole["seed_numbers"], serde_json::json!([1, 2, 3]));
    // Flown out of order, as a sweep's tasks finish.
    for k in ["3", "1", "2"] {
        let file = format!("seed{k}.cbor");
        let one = json_of(&cmsckf(
            &[
                &["evaluate", "--json", "--seed", k, "--flights-out", &file][..],
                &FLIGHT,
            ]
            .concat(),
            d,
        ));
        assert_eq!(one["seeds"], 1);
        assert!(d.join(&file).is_file(), "--flights-out wrote {file}");
        assert!(
            !d.join(format!("seed{k}.part")).exists(),
            "the part file is renamed away"
        );
    }
    let merged = json_of(&cmsckf(
        &[
            "evaluate",
            "--json",
            "--merge",
            "seed2.cbor",
            "seed3.cbor",
            "seed1.cbor",
        ],
        d,
    ));
    assert_eq!(merged, whole, "a merge of the seeds is the evaluation of them all");
    // A folder of them is the same.
    std::fs::create_dir(d.join("seeds")).expect("mkdir");
    for k in 1..=3 {
        std::fs::copy(d.join(format!("seed{k}.cbor")), d.join(format!("seeds/seed{k}.cbor"))).expect("copy");
    }
    assert_eq!(json_of(&cmsckf(&["evaluate", "--json", "--merge", "seeds"], d)), whole);
    // The merged compressed run still carries its difference from full.
    assert!(merged["modes"]["compressed"]["max_rel_diff_vs_full"].is_number());

    // The table and CSV come from the same summary.
    let table = cmsckf(
        &[
            "evaluate",
            "--merge",
            "seed1.cbor",
            "seed2.cbor",
            "seed3.cbor",
            "--csv",
            "m.csv",
        ],
        d,
    );
    assert!(table.status.success());
    assert!(String::from_utf8_lossy(&table.stdout).contains("3 seeds"));
    assert!(std::fs::read_to_string(d.join("m.csv"))
        .expect("csv")
        .contains("compressed"));

    // What does not belong together is refused, saying why.
    let twice = cmsckf(&["evaluate", "--merge", "seed1.cbor", "seed1.cbor"], d);
    assert!(!twice.status.success());
    assert!(String::from_utf8_lossy(&twice.stderr).contains("seed 1 is in both seed1.cbor and seed1.cbor"));
    // Two files joined into one.
    let mut joined = std::fs::read(d.join("seed1.cbor")).expect("read");
    joined.extend(std::fs::read(d.join("seed2.cbor")).expect("read"));
    std::fs::write(d.join("joined.cbor"), joined).expect("write");
    let joined = cmsckf(&["evaluate", "--merge", "joined.cbor"], d);
    assert!(String::from_utf8_lossy(&joined.stderr).contains("bytes after its seeds"));
    // Cut short.
    let whole = std::fs::read(d.join("seed2.cbor")).expect("read");
    std::fs::write(d.join("cut.cbor"), &whole[..whole.len() / 2]).expect("write");
    let cut = cmsckf(&["evaluate", "--merge", "cut.cbor"], d);
    let why = String::from_utf8_lossy(&cut.stderr);
    assert!(
        why.contains("cut.cbor: not a whole file") && !why.contains("panicked"),
        "{why}"
    );
    // A seed flown with another config is not of this evaluation.
    std::fs::write(d.join("noisy.toml"), "[camera]\npixel_noise_px = 3.0\n").expect("write");
    let noisy = cmsckf(
        &[
            &[
                "evaluate",
                "--seed",
                "4",
                "--flights-out",
                "noisy.cbor",
                "--config",
                "noisy.toml",
            ][..],
            &FLIGHT,
        ]
        .concat(),
        d,
    );
    assert!(noisy.status.success(), "{}", String::from_utf8_lossy(&noisy.stderr));
    let other = cmsckf(&["evaluate", "--merge", "seed1.cbor", "noisy.cbor"], d);
    let why = String::from_utf8_lossy(&other.stderr);
    assert!(
        why.contains("seed 4 was flown with another config") && why.contains("noisy.cbor"),
        "{why}"
    );
    // Flight flags beside --merge would change nothing: refused.
    let flags = cmsckf(&["evaluate", "--merge", "seed1.cbor", "--seeds", "99"], d);
    assert!(String::from_utf8_lossy(&flags.stderr).contains("--merge takes the seeds' files alone"));
    let other = cmsckf(
        &[
            "evaluate",
            "--seed",
            "4",
            "--flights-out",
            "fig8.cbor",
            "--scenario",
            "figure8",
            "--modes",
            "msckf,full,compressed",
            "--duration-s",
            "8",
            "--json",
        ],
        d,
    );
    assert!(other.status.success(), "{}", String::from_utf8_lossy(&other.stderr));
    let mixed = cmsckf(&["evaluate", "--merge", "seed1.cbor", "fig8.cbor"], d);
    assert!(!mixed.status.success());
    let why = String::from_utf8_lossy(&mixed.stderr);
    assert!(why.contains("scenario figure8") && why.contains("racetrack"), "{why}");
    std::fs::write(d.join("junk.cbor"), b"not cbor at all").expect("write");
    let junk = cmsckf(&["evaluate", "--merge", "junk.cbor"], d);
    assert!(!junk.status.success());
    assert!(String::from_utf8_lossy(&junk.stderr)
        .contains("junk.cbor: not a whole file of `cmsckf evaluate --flights-out`"));
    let missing = cmsckf(&["evaluate", "--merge", "absent.cbor"], d);
    assert!(String::from_utf8_lossy(&missing.stderr).contains("absent.cbor"));
    let no_seed = cmsckf(&[&["evaluate", "--flights-out", "x.cbor"][..], &FLIGHT].concat(), d);
    assert!(!no_seed.status.success());
    assert!(String::from_utf8_lossy(&no_seed.stderr).contains("--flights-out needs --seed K"));
}

/// Flights that do not hold together (a series shorter than its times, a
/// mode missing or doubled, no frame) are refused by name, never summarised:
/// the summary would index past a short series and panic.
#[test]
fn flights_that_do_not_hold_together_are_refused() {
    use cmsckf::estimator::Mode;
    use cmsckf::eval;
    let cfg = cmsckf::config::Config::default();
    let sim = eval::sim_config_for(&cfg);
    let spec = eval::EvalSpec {
        scenario: "racetrack".into(),
        modes: vec![Mode::Msckf, Mode::Schmidt],
        seeds: eval::Seeds::One(1),
        duration_s: Some(4.0),
        gnss: false,
        landed_state: true,
    };
    let good = eval::fly_seed(&spec, &cfg, &sim, 1, |_| {}).expect("a flight");
    good.check().expect("a flight as flown holds together");
    let refused = |f: eval::SeedFlights| match eval::merge(vec![f]) {
        Err(e @ eval::MergeError::Malformed { .. }) => e.to_string(),
        other => panic!("not refused: {:?}", other.map(|e| e.seeds)),
    };
    let mut short = good.clone();
    short.flights[0].p_est.truncate(3);
    assert!(refused(short).contains("p_est"));
    let mut doubled = good.clone();
    doubled.flights[1] = doubled.flights[0].clone();
    assert!(refused(doubled).contains("modes"));
    let mut empty = good.clone();
    empty.flights.clear();
    assert!(refused(empty).contains("modes"));
    let mut no_frame = good.clone();
    let f = &mut no_frame.flights[0];
    (f.t_s, f.p_est, f.q_est, f.cov_pose) = (vec![], vec![], vec![], vec![]);
    (f.p_true, f.q_true, f.v_est, f.v_true, f.cov_vel) = (vec![], vec![], vec![], vec![], vec![]);
    assert!(refused(no_frame).contains("no frame"));
}

/// `--sim-config` goes over what `--config` says, not over the simulator's
/// own defaults: a file that names no camera flies the config's. A config
/// whose camera looks 30° down (as beside PX4, tests/px4_sitl.rs) with a
/// simulator file that only removes outliers used to fly the simulator's
/// level camera under a filter told of the tilted one: 15 s of hover came
/// out 7.5° off in attitude at a NEES of 16 (40 s: 20 m, NEES 621), where
/// the config's own camera gives 0.4° and 5.0.
#[test]
fn a_sim_config_that_names_no_camera_flies_the_configs() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let mut cfg = cmsckf::config::Config::default();
    // The default mount (optical axis along the body's nose) turned about
    // the body's y axis so that the axis points 30° down (FRD: +z down).
    let [x, y, z, w] = cfg.camera.q_B_C_xyzw;
    let q = nalgebra::UnitQuaternion::from_axis_angle(&nalgebra::Vector3::y_axis(), -30f64.to_radians())
        * nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
    cfg.camera.q_B_C_xyzw = [q.i, q.j, q.k, q.w];
    std::fs::write(d.join("tilted.toml"), toml::to_string(&cfg).expect("config as TOML")).expect("write config");
    std::fs::write(d.join("sim.toml"), "[features]\noutlier_prob = 0.0\n").expect("write sim config");
    let args = [
        "evaluate",
        "--json",
        "--scenario",
        "hover",
        "--modes",
        "msckf",
        "--seeds",
        "1",
        "--duration-s",
        "15",
        "--config",
        "tilted.toml",
        "--sim-config",
        "sim.toml",
    ];
    let v = json_of(&cmsckf(&args, d));
    let m = &v["modes"]["msckf"];
    let (rot_deg, nees) = (m["rot_rmse_deg"].as_f64(), m["nees_mean"].as_f64());
    assert!(
        rot_deg.is_some_and(|r| r < 1.5) && nees.is_some_and(|n| n < 8.0),
        "attitude {rot_deg:?}° off, NEES {nees:?}: the simulated camera is not the config's"
    );
}
