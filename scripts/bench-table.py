#!/usr/bin/env python3
"""Write the criterion table of docs/performance.md from the last bench run.

Why this exists: the table's figures are only worth what their run is, and a
table kept by hand drifts from the benches (a bench renamed, added, or its
workload changed, its old figure left standing). This reads criterion's own
results (`target/criterion/<id>/new/estimates.json`, the median and its 95 %
interval), keeps each row's workload text from the document, and rewrites the
rows between the `bench-table` markers with the run's date and this machine's
CPU. `tests/performance_doc.rs` fails when a bench in `benches/` or
`frontend/benches/` has no row.

    cargo bench --bench estimator -- --warm-up-time 1 --measurement-time 3
    cargo bench --bench scaling -- --warm-up-time 1 --measurement-time 3
    cargo bench -p cmsckf-frontend --bench tracker -- --warm-up-time 1 --measurement-time 3
    python3 scripts/bench-table.py            # rewrites docs/performance.md
    python3 scripts/bench-table.py --print    # prints the table only

Standard library only: it runs where the benches run.
"""

import argparse
import datetime
import json
import os
import pathlib
import re
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "performance.md"
START = "<!-- bench-table:start -->"
END = "<!-- bench-table:end -->"
# A row: `| `id` | workload | median | interval | run at |`. The workload may
# hold `|` inside code spans, so the last three cells are split off from the
# right.
ROW = re.compile(r"^\|\s*`([^`]+)`\s*\|(.*)\|\s*$")


def fmt_ns(ns):
    """A duration in the unit criterion would print it in, 3 significant digits
    (999.7 µs rounds to 1.00 ms, not to 1e+03 µs)."""
    rounded = float(f"{ns:.3g}")
    for unit, scale in (("s", 1e9), ("ms", 1e6), ("µs", 1e3), ("ns", 1.0)):
        if rounded >= scale or unit == "ns":
            value = rounded / scale
            digits = max(0, 2 - int(f"{value:e}".split("e")[1]))
            return f"{value:.{digits}f} {unit}"


def results(criterion_dir):
    """Every bench result under target/criterion: {full_id: (median, lo, hi, mtime)}."""
    found = {}
    for bench in criterion_dir.rglob("new/benchmark.json"):
        estimates = bench.with_name("estimates.json")
        try:
            meta = json.loads(bench.read_text())
            median = json.loads(estimates.read_text())["median"]
            ci = median["confidence_interval"]
            found[str(meta["full_id"])] = (
                float(median["point_estimate"]),
                float(ci["lower_bound"]),
                float(ci["upper_bound"]),
                estimates.stat().st_mtime,
            )
        except (OSError, ValueError, KeyError, TypeError) as e:
            print(f"skipping {bench.parent}: unreadable result ({e!r})", file=sys.stderr)
    return found


def bench_names():
    """The benches defined in the sources: (literal function ids, group names)."""
    functions, groups = set(), set()
    for src in bench_sources():
        # Commented-out lines define nothing.
        text = "\n".join(l for l in src.read_text().splitlines() if not l.lstrip().startswith("//"))
        functions |= set(re.findall(r'bench_function\(\s*"([^"]+)"', text))
        groups |= set(re.findall(r'benchmark_group\(\s*"([^"]+)"', text))
    return functions, groups


def bench_sources():
    """The bench files `tests/performance_doc.rs` reads too: `benches/*.rs` of
    the root crate and of each crate in a folder beside it."""
    return sorted(ROOT.glob("benches/*.rs")) + sorted(ROOT.glob("*/benches/*.rs"))


def current(full_id, names):
    """Whether a result belongs to a bench the sources still define."""
    functions, groups = names
    return full_id in functions or any(full_id.startswith(g + "/") for g in groups)


def cpu_model():
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown CPU"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--print", action="store_true", help="print the table, change nothing")
    ap.add_argument("--criterion", default=str(ROOT / "target" / "criterion"))
    ap.add_argument(
        "--allow-missing",
        action="store_true",
        help="write the table even when some rows' benches have no result (they say 'not run')",
    )
    args = ap.parse_args()

    names = bench_names()
    found = {k: v for k, v in results(pathlib.Path(args.criterion)).items() if current(k, names)}
    if not found:
        sys.exit(
            f"no results under {args.criterion} for the benches the sources define: "
            "run the benches first (see --help)"
        )
    text = DOC.read_text()
    lines_in = text.split("\n")
    starts = [i for i, l in enumerate(lines_in) if l.strip() == START]
    ends = [i for i, l in enumerate(lines_in) if l.strip() == END]
    if len(starts) != 1 or len(ends) != 1 or starts[0] > ends[0]:
        sys.exit(f"{DOC}: needs one line {START} and, after it, one line {END}")
    head = "\n".join(lines_in[: starts[0]]) + "\n"
    block = lines_in[starts[0] + 1 : ends[0]]
    tail = "\n" + "\n".join(lines_in[ends[0] + 1 :])

    # The document's rows, in its order: id -> workload text. The block is
    # the script's: any other table line in it is an error, not dropped.
    rows = []
    for line in block:
        stripped = line.strip()
        if not stripped.startswith("|") or stripped.startswith("| benchmark |") or stripped.startswith("|---"):
            continue
        m = ROW.match(stripped)
        cells = m.group(2).rsplit("|", 3) if m else []
        if len(cells) != 4:
            sys.exit(f"{DOC}: a table line between the markers is not `| `id` | workload | median | interval | run at |`: {stripped}")
        rows.append((m.group(1), cells[0].strip()))
    known = {r[0] for r in rows}
    # A result the document has no row for gets one, to be described.
    for full_id in sorted(found):
        if full_id not in known:
            rows.append((full_id, "**(new: describe its workload)**"))

    missing = [r[0] for r in rows if r[0] not in found]
    if missing and not args.allow_missing and not args.print:
        sys.exit(
            f"no result for {', '.join(missing)}: run every bench (see --help), "
            "or pass --allow-missing to write 'not run'"
        )
    newest = max(v[3] for v in found.values())
    day = datetime.datetime.fromtimestamp(newest, datetime.timezone.utc).strftime("%Y-%m-%d")
    lines = [
        "",
        f"Run on {day}, {cpu_model()}, {os.cpu_count()} cores (`python3 scripts/bench-table.py` after the",
        "three `cargo bench` commands above; a median over criterion's samples and its 95 % interval). This",
        "machine's speed can move by 1.5–2× within half an hour: compare rows run at the same time.",
        "",
        "| benchmark | workload | median | 95 % interval | run at (UTC) |",
        "|---|---|---|---|---|",
    ]
    for full_id, workload in rows:
        if full_id in found:
            med, lo, hi, mtime = found[full_id]
            at = datetime.datetime.fromtimestamp(mtime, datetime.timezone.utc).strftime("%Y-%m-%d %H:%M")
            lines.append(f"| `{full_id}` | {workload} | {fmt_ns(med)} | {fmt_ns(lo)}–{fmt_ns(hi)} | {at} |")
        else:
            lines.append(f"| `{full_id}` | {workload} | not run | — | — |")
    lines.append("")
    table = "\n".join(lines)
    if args.print:
        print(table)
        return
    DOC.write_text(head + START + table + "\n" + END + tail)
    print(f"{DOC}: {len(rows)} rows, {sum(1 for r in rows if r[0] in found)} from this run")


if __name__ == "__main__":
    main()
