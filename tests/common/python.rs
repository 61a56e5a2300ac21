//! The Python the tests run (independent readers and writers: pymavlink,
//! PyPI `mcap`, jsonschema, the Foxglove SDK, numpy): a virtual environment
//! of the tests' own under the target directory, made on first use, so
//! `cargo test --workspace` installs nothing into the system's Python. Stock
//! Debian, Ubuntu and Raspberry Pi OS refuse `pip install` there (PEP 668);
//! all they need is `python3` with its `venv` module (Debian:
//! `apt install python3-venv`).
//!
//! Shared by the workspace's test crates (`#[path]`-included by those
//! outside `tests/common`).

use std::path::{Path, PathBuf};
use std::process::Command;

/// Where the environment lives: one for the whole workspace.
fn venv_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("python-venv")
}

/// The environment's interpreter.
fn interpreter(venv: &Path) -> PathBuf {
    venv.join("bin").join("python3")
}

/// Makes the environment if it is not there: built beside it and renamed,
/// so a test binary killed half-way leaves no half-made one.
fn ensure_venv() -> PathBuf {
    let venv = venv_dir();
    let python = interpreter(&venv);
    if python.exists() {
        return python;
    }
    let parent = venv.parent().expect("the target directory");
    std::fs::create_dir_all(parent).unwrap();
    let building = parent.join(format!("python-venv.{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&building);
    let out = Command::new("python3")
        .args(["-m", "venv"])
        .arg(&building)
        .output()
        .expect("python3 is needed for the tests (Debian: apt install python3 python3-venv)");
    assert!(
        out.status.success(),
        "python3 -m venv failed (Debian: apt install python3-venv): {}",
        String::from_utf8_lossy(&out.stderr)
    );
    // Another test binary may have made it meanwhile: keep theirs.
    if std::fs::rename(&building, &venv).is_err() {
        let _ = std::fs::remove_dir_all(&building);
    }
    python
}

/// The tests' Python, able to import each of `modules` (installed into its
/// environment with pip when missing). An entry is the import name, or
/// `import=pypi` where the two differ (`foxglove=foxglove-sdk`). Run
/// scripts with the interpreter this returns, never `python3`.
pub fn python_with(modules: &[&str]) -> PathBuf {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _guard = LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let python = ensure_venv();
    let importable = |m: &str| {
        Command::new(&python)
            .args(["-c", &format!("import {m}")])
            .output()
            .is_ok_and(|o| o.status.success())
    };
    fn split(m: &str) -> (&str, &str) {
        m.split_once('=').unwrap_or((m, m))
    }
    let missing: Vec<&str> = modules
        .iter()
        .map(|m| split(m))
        .filter(|(m, _)| !importable(m))
        .map(|(_, pypi)| pypi)
        .collect();
    if !missing.is_empty() {
        eprintln!(
            "installing Python modules for the tests into {}: {missing:?}",
            venv_dir().display()
        );
        let ok = Command::new(&python)
            .args(["-m", "pip", "install", "--quiet", "--disable-pip-version-check"])
            .args(&missing)
            .status()
            .is_ok_and(|s| s.success());
        assert!(ok, "pip could not install {missing:?} into {}", venv_dir().display());
    }
    python
}
