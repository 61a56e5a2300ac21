//! docs/performance.md's criterion table cannot drift from the benches
//! silently: every bench the sources define (`benches/*.rs` of the root
//! crate and of each crate beside it, as `scripts/bench-table.py` reads
//! them: each `bench_function` with a literal id, each `benchmark_group`)
//! has a row between the table's markers, and every row names a bench that
//! still exists. A group's members are named at run time (`format!`), so a
//! group is held to at least one row; the script adds a row for every
//! member criterion has a result for, and refuses to write while a row has
//! none. The figures themselves come from the script, from criterion's
//! results; this test holds the table's coverage, which no run can.

use std::path::Path;

/// The quoted ids after each `needle(` in `src` (`needle("id"`), commented-out
/// lines left out.
fn quoted_after(src: &str, needle: &str) -> Vec<String> {
    let code: Vec<&str> = src.lines().filter(|l| !l.trim_start().starts_with("//")).collect();
    let code = code.join("\n");
    let mut ids = Vec::new();
    let mut rest = code.as_str();
    while let Some(i) = rest.find(needle) {
        rest = &rest[i + needle.len()..];
        if let Some(body) = rest.trim_start().strip_prefix('"') {
            if let Some(end) = body.find('"') {
                ids.push(body[..end].to_string());
            }
        }
    }
    ids
}

/// (literal bench ids, group names) over every bench source: `benches/*.rs`
/// of the root crate and of each folder beside it.
fn benches() -> (Vec<String>, Vec<String>) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut dirs = vec![root.join("benches")];
    for entry in std::fs::read_dir(root).expect("the project's folder") {
        let dir = entry.expect("a directory entry").path().join("benches");
        if dir.is_dir() {
            dirs.push(dir);
        }
    }
    let (mut functions, mut groups) = (Vec::new(), Vec::new());
    for dir in dirs {
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

/// The bench ids of the table's rows (`` | `id` | ... ``), between the
/// markers as the script finds them: lines of their own, one each.
fn table_rows() -> Vec<String> {
    let doc = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/performance.md"))
        .expect("docs/performance.md");
    let lines: Vec<&str> = doc.lines().collect();
    let at = |marker: &str| {
        let found: Vec<usize> = (0..lines.len()).filter(|&i| lines[i].trim() == marker).collect();
        assert_eq!(found.len(), 1, "docs/performance.md needs one line `{marker}`");
        found[0]
    };
    let (start, end) = (at("<!-- bench-table:start -->"), at("<!-- bench-table:end -->"));
    assert!(start < end, "the table's markers are out of order");
    lines[start..end]
        .iter()
        .filter_map(|l| l.trim().strip_prefix("| `"))
        .filter_map(|l| l.split_once('`').map(|(id, _)| id.to_string()))
        .collect()
}

#[test]
fn every_bench_has_a_row_and_every_row_a_bench() {
    let (functions, groups) = benches();
    assert!(
        functions.len() >= 5 && groups.len() >= 3,
        "too few benches found in the bench sources ({functions:?}, groups {groups:?}): were they read?"
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
            "docs/performance.md's row `{r}` names no bench in a `benches/` folder"
        );
    }
}

#[test]
fn commented_out_benches_define_nothing() {
    let src = "c.bench_function(\"live\", |b| {});\n// c.bench_function(\"gone\", |b| {});\n    \
               g.bench_function(format!(\"{n}\"), |b| {});";
    assert_eq!(quoted_after(src, "bench_function("), vec!["live".to_string()]);
}
