//! The Foxglove layouts. `docs/foxglove-layout.json` is for the desktop app
//! (Layouts ▸ Import from file): its format is the app's `LayoutData`
//! (`configById`, a mosaic `layout` tree, `globalVariables`, `userNodes`,
//! `playbackConfig`; docs/foxglove.md cites the sources), checked here rule
//! by rule. `docs/foxglove-layout.sdk.json` is for the SDK and notebook
//! viewers: what `scripts/foxglove_layout.py` writes with Foxglove's own
//! layout types (PyPI `foxglove-sdk`), so it cannot drift from them. That
//! every topic and message path of the desktop layout exists in a real log
//! is checked by `daemon_sitl` (`read_mcap.py --layout`).

mod common;

use std::collections::BTreeSet;
use std::process::Command;

use serde_json::Value;

/// The panel ids of a mosaic tree: a leaf is a panel id; a split has
/// `first`, `second`, a `direction` of "row" or "column" and an optional
/// `splitPercentage` in (0, 100).
fn leaves(node: &Value, out: &mut Vec<String>) {
    match node {
        Value::String(id) => out.push(id.clone()),
        Value::Object(o) => {
            assert!(
                matches!(o.get("direction").and_then(Value::as_str), Some("row" | "column")),
                "a split without a row/column direction: {node}"
            );
            if let Some(p) = o.get("splitPercentage") {
                let p = p.as_f64().expect("splitPercentage is a number");
                assert!(p > 0.0 && p < 100.0, "splitPercentage {p}");
            }
            leaves(o.get("first").expect("a split has `first`"), out);
            leaves(o.get("second").expect("a split has `second`"), out);
        }
        other => panic!("a layout node is a panel id or a split, not {other}"),
    }
}

#[test]
fn the_desktop_layout_is_in_the_apps_import_format() {
    let root = env!("CARGO_MANIFEST_DIR");
    let l: Value =
        serde_json::from_slice(&std::fs::read(format!("{root}/docs/foxglove-layout.json")).unwrap()).unwrap();
    let o = l.as_object().expect("a JSON object");
    assert!(
        !o.contains_key("content"),
        "the SDK's format, which the desktop app imports as empty"
    );
    for key in ["configById", "globalVariables", "userNodes", "playbackConfig"] {
        assert!(o.get(key).is_some_and(Value::is_object), "`{key}` is an object");
    }
    assert!(l["playbackConfig"]["speed"].is_number(), "playbackConfig.speed");
    for (id, node) in l["userNodes"].as_object().unwrap() {
        assert!(
            node["name"].is_string() && node["sourceCode"].is_string(),
            "userNodes.{id}"
        );
    }
    if let Some(v) = o.get("version") {
        assert!(v.as_u64().is_some_and(|v| v <= 1), "a version the app refuses: {v}");
    }
    let mut ids = Vec::new();
    leaves(&l["layout"], &mut ids);
    let in_tree: BTreeSet<_> = ids.iter().cloned().collect();
    assert_eq!(in_tree.len(), ids.len(), "a panel twice in the tree");
    let configured: BTreeSet<_> = l["configById"].as_object().unwrap().keys().cloned().collect();
    assert_eq!(
        in_tree, configured,
        "every panel in the tree has a config, and no other"
    );
    let mut types = BTreeSet::new();
    for (id, cfg) in l["configById"].as_object().unwrap() {
        let (kind, suffix) = id.split_once('!').expect("a panel id is `<type>!<suffix>`");
        assert!(!suffix.is_empty() && cfg.is_object(), "{id}");
        types.insert(kind.to_string());
        if kind == "Plot" {
            for p in cfg["paths"].as_array().expect("a Plot has paths") {
                assert!(p["value"].as_str().is_some_and(|v| v.starts_with('/')), "{id}: {p}");
                assert!(p["enabled"].is_boolean(), "{id}: {p}");
                assert!(
                    matches!(p["timestampMethod"].as_str(), Some("receiveTime" | "headerStamp")),
                    "{id}: {p}"
                );
            }
        }
    }
    // The app's own panel type names (its panels/index.ts): 3D, the map,
    // plots, the log (RosOut) and raw messages.
    for t in ["3D", "map", "Plot", "RosOut", "RawMessages"] {
        assert!(types.contains(t), "no {t} panel: {types:?}");
    }
    let text = l.to_string();
    assert!(
        text.contains("estimator_status.pos_horiz_ratio"),
        "the autopilot's ratios are plotted"
    );
}

#[test]
fn the_sdk_layout_is_what_the_foxglove_sdk_writes() {
    let python = common::python_with(&["foxglove=foxglove-sdk"]);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("layout.json");
    let root = env!("CARGO_MANIFEST_DIR");
    let st = Command::new(&python)
        .arg(format!("{root}/scripts/foxglove_layout.py"))
        .arg(&out)
        .status()
        .expect("the tests' Python");
    assert!(st.success());
    let written: Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    let committed: Value =
        serde_json::from_slice(&std::fs::read(format!("{root}/docs/foxglove-layout.sdk.json")).unwrap()).unwrap();
    assert_eq!(
        written, committed,
        "docs/foxglove-layout.sdk.json is stale: run python3 scripts/foxglove_layout.py"
    );
    let text = committed.to_string();
    for panel in ["\"ThreeDee\"", "\"Map\"", "\"Plot\"", "\"Log\""] {
        assert!(text.contains(panel), "no {panel} panel");
    }
}
