//! The command line as a user meets it: completions generated from the
//! commands themselves, `--fault` help that names every fault the SITL has,
//! `--version`, and output with no terminal control codes and whole counts
//! when it goes to a file or a journal.

use std::process::Command;

fn cmsckf(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_cmsckf")).args(args).output().unwrap()
}

#[test]
fn completions_version_and_fault_help() {
    let out = cmsckf(&["completions", "bash"]);
    assert!(out.status.success());
    let script = String::from_utf8_lossy(&out.stdout);
    // Every subcommand, the newest included.
    for sub in ["evaluate", "replay", "review", "recover", "gnss", "completions"] {
        assert!(script.contains(sub), "bash completion lacks {sub}");
    }
    assert!(!cmsckf(&["completions", "tcsh"]).status.success());

    let v = String::from_utf8_lossy(&cmsckf(&["--version"]).stdout).into_owned();
    // The version, the commit it was built from and the build date.
    assert_eq!(v.trim(), format!("cmsckf {}", env!("CMSCKF_BUILD")));
    let commit = std::process::Command::new("git")
        .args(["rev-parse", "--short=12", "HEAD"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string());
    if let Some(commit) = commit {
        assert!(v.contains(&format!("({commit}, built 20")), "{v}");
    }

    let help = String::from_utf8_lossy(&cmsckf(&["demo", "--help"]).stdout).into_owned();
    for k in cmsckf_sitl::serve::FaultKind::ALL {
        assert!(help.contains(k.name()), "--fault help lacks {}", k.name());
    }
}

#[test]
fn evaluate_output_off_a_terminal_is_plain() {
    let out = cmsckf(&[
        "evaluate",
        "--scenario",
        "racetrack",
        "--duration-s",
        "8",
        "--seeds",
        "1",
        "--modes",
        "compressed",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    );
    assert!(
        !stdout.contains('\u{1b}') && !stderr.contains('\u{1b}'),
        "control codes: {stderr:?}"
    );
    // One plain progress line per flight.
    assert!(stderr.contains("[1/1] seed 1: compressed"), "{stderr}");
    // Counts are whole numbers, and nothing prints as -0.
    assert!(!stdout.contains("-0.0") && !stdout.contains("-0 "), "{stdout}");
    let row = stdout.lines().find(|l| l.starts_with("compressed ")).unwrap();
    let kf = row.split_whitespace().nth(6).unwrap();
    assert!(kf.parse::<u64>().is_ok(), "keyframes column {kf:?} in {row}");
}
