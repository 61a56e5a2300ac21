//! The `cmsckf-sitl generate` command: identical files for the same seed,
//! and clear errors (never a panic) for bad input.

use std::process::Command;

fn sitl() -> Command {
    Command::new(env!("CARGO_BIN_EXE_cmsckf-sitl"))
}

fn generate(out: &std::path::Path, seed: &str, extra: &[&str]) -> std::process::Output {
    sitl()
        .args([
            "generate",
            "--scenario",
            "figure8",
            "--duration-s",
            "4",
            "--seed",
            seed,
            "--out",
        ])
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn same_seed_gives_identical_files_and_a_summary() {
    let dir = tempfile::tempdir().unwrap();
    let a = generate(&dir.path().join("a"), "5", &[]);
    let b = generate(&dir.path().join("b"), "5", &[]);
    assert!(a.status.success(), "{}", String::from_utf8_lossy(&a.stderr));
    assert!(b.status.success(), "{}", String::from_utf8_lossy(&b.stderr));
    let stdout = String::from_utf8_lossy(&a.stdout);
    for sensor in ["imu:", "camera:", "gnss:"] {
        assert!(stdout.contains(sensor), "summary lacks {sensor}: {stdout}");
    }
    for f in ["truth.csv", "imu.csv", "features.csv", "gnss.csv"] {
        let fa = std::fs::read(dir.path().join("a").join(f)).unwrap();
        let fb = std::fs::read(dir.path().join("b").join(f)).unwrap();
        assert!(fa.len() > 100);
        assert_eq!(fa, fb, "{f} differs");
    }
}

#[test]
fn bad_inputs_give_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| {
        let o = sitl().args(args).output().unwrap();
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr).to_string();
        assert!(!err.contains("panicked"), "{err}");
        err
    };
    let out = dir.path().join("o");
    let out = out.to_str().unwrap();
    assert!(run(&["generate", "--scenario", "spiral", "--out", out]).contains("unknown scenario 'spiral'"));
    let e = run(&["generate", "--scenario", "tum:/no/such/file.txt", "--out", out]);
    assert!(e.contains("/no/such/file.txt"), "{e}");
    let broken = dir.path().join("broken.txt");
    std::fs::write(&broken, "0 0 0 0 0 0 0 1\n0.1 0 0 0 0 0 0 1\nnonsense row\n").unwrap();
    let e = run(&[
        "generate",
        "--scenario",
        &format!("tum:{}", broken.display()),
        "--out",
        out,
    ]);
    assert!(e.contains("broken.txt") && e.contains("line 3"), "{e}");
    let cfg = dir.path().join("sim.toml");
    std::fs::write(&cfg, "[gnss]\npseudorange_noise_m = nan\n").unwrap();
    let e = run(&["generate", "--config", cfg.to_str().unwrap(), "--out", out]);
    assert!(e.contains("gnss.pseudorange_noise_m"), "{e}");
    let e = run(&["generate", "--duration-s", "inf", "--out", out]);
    assert!(e.contains("--duration-s"), "{e}");
}
