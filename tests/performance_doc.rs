//! docs/performance.md's criterion table cannot drift from the benches
//! silently: every bench the sources define (`benches/*.rs`,
//! `frontend/benches/*.rs`: each `bench_function` with a literal id, each
//! `benchmark_group`) has a row between the table's markers, and every row
//! names a bench that still exists. The figures themselves come from
//! `scripts/bench-table.py`, which writes them from criterion's results of
//! one run; this test holds the table's coverage, which no run can.

use std::path::Path;

/// The quoted ids after each `needle(` in `src` (`needle("id"`).
fn quoted_after(src: &str, needle: &str) -> Vec<String> {
    let mut ids = Vec::new();
    let mut rest = src;
    while let Some(i) = rest.find(needle) {
        rest = &rest[i + needle.len()..];
        let trimmed = rest.trim_start();
        if let Some(body) = trimmed.strip_prefix('"') {
            if let Some(end) = body.find('"') {
                ids.push(body[..end].to_string());
            }
        }
    }
    ids
}

/// (literal bench ids, group names) over every bench source.
fn benches() -> (Vec<String>, Vec<String>) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let (mut functions, mut groups) = (Vec::new(), Vec::new());
    for dir in [root.join("benches"), root.join("frontend/benches")] {
        let entries = std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
        for entry in entries {
            let path = entry.expect("a directory entry").path();
            if path.extension().is_some_and(|e| e == "rs") {
                let src = std::fs::read_to_string(&path).expect("a bench source");
                functions.extend(quoted_after(&src, "bench_function("));
                groups.extend(quoted_after(&src, "benchmark_group("));
            }
        }
    }
    (functions, groups)
}

/// The bench ids of the table's rows (`` | `id` | ... ``).
fn table_rows() -> Vec<String> {
    let doc = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/performance.md"))
        .expect("docs/performance.md");
    let start = doc
        .find("<!-- bench-table:start -->")
        .expect("the table's start marker");
    let end = doc.find("<!-- bench-table:end -->").expect("the table's end marker");
    assert!(start < end, "the table's markers are out of order");
    doc[start..end]
        .lines()
        .filter_map(|l| l.trim().strip_prefix("| `"))
        .filter_map(|l| l.split_once('`').map(|(id, _)| id.to_string()))
        .collect()
}

#[test]
fn every_bench_has_a_row_and_every_row_a_bench() {
    let (functions, groups) = benches();
    assert!(
        functions.iter().any(|f| f == "propagate") && groups.iter().any(|g| g == "mode_scaling"),
        "the bench sources were not read: {functions:?} {groups:?}"
    );
    let rows = table_rows();
    for f in &functions {
        assert!(
            rows.contains(f),
            "bench `{f}` has no row in docs/performance.md's criterion table: run it and \
             `python3 scripts/bench-table.py` (docs/performance.md, criterion)"
        );
    }
    for g in &groups {
        assert!(
            rows.iter().any(|r| r.starts_with(&format!("{g}/"))),
            "bench group `{g}` has no row in docs/performance.md's criterion table: run it and \
             `python3 scripts/bench-table.py`"
        );
    }
    for r in &rows {
        let defined = functions.contains(r) || groups.iter().any(|g| r.starts_with(&format!("{g}/")));
        assert!(
            defined,
            "docs/performance.md's row `{r}` names no bench in benches/ or frontend/benches/"
        );
    }
}
