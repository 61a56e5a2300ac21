//! `docs/foxglove-layout.json` is what `scripts/foxglove_layout.py` writes
//! with Foxglove's own layout types (PyPI `foxglove-sdk`, installed if
//! missing): the committed file cannot drift from its source, and every key
//! in it is one Foxglove's SDK defines. That its topics and message paths
//! exist in a real log is checked by `daemon_sitl` (`read_mcap.py --layout`).

mod common;

use std::process::Command;

#[test]
fn the_layout_is_what_the_foxglove_sdk_writes() {
    common::python_modules(&["foxglove=foxglove-sdk"]);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("layout.json");
    let root = env!("CARGO_MANIFEST_DIR");
    let st = Command::new("python3")
        .arg(format!("{root}/scripts/foxglove_layout.py"))
        .arg(&out)
        .status()
        .expect("python3 is needed for this test");
    assert!(st.success());
    let written: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    let committed: serde_json::Value =
        serde_json::from_slice(&std::fs::read(format!("{root}/docs/foxglove-layout.json")).unwrap()).unwrap();
    assert_eq!(
        written, committed,
        "docs/foxglove-layout.json is stale: run python3 scripts/foxglove_layout.py"
    );
    // The panels the issue asks for: 3D, Map, three Plots and the Log.
    let text = committed.to_string();
    for panel in ["\"ThreeDee\"", "\"Map\"", "\"Plot\"", "\"Log\""] {
        assert!(text.contains(panel), "no {panel} panel");
    }
    assert_eq!(text.matches("\"panelType\":\"Plot\"").count(), 3);
}
