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
    assert!(String::from_utf8_lossy(&twice.stderr).contains("seed 1 is given twice"));
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
    assert!(String::from_utf8_lossy(&junk.stderr).contains("not a file of `cmsckf evaluate --flights-out`"));
    let missing = cmsckf(&["evaluate", "--merge", "absent.cbor"], d);
    assert!(String::from_utf8_lossy(&missing.stderr).contains("absent.cbor"));
    let no_seed = cmsckf(&[&["evaluate", "--flights-out", "x.cbor"][..], &FLIGHT].concat(), d);
    assert!(!no_seed.status.success());
    assert!(String::from_utf8_lossy(&no_seed.stderr).contains("--flights-out needs --seed K"));
}
