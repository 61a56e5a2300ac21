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
ROW = re.compile(r"^\|\s*`([^`]+)`\s*\|(.*?)\|.*\|$")


def fmt_ns(ns):
    """A duration in the unit criterion would print it in, 3 significant digits."""
    for unit, scale in (("s", 1e9), ("ms", 1e6), ("µs", 1e3)):
        if ns >= scale:
            return f"{ns / scale:.3g} {unit}"
    return f"{ns:.3g} ns"


def results(criterion_dir):
    """Every bench result under target/criterion: {full_id: (median, lo, hi, mtime)}."""
    found = {}
    for bench in criterion_dir.rglob("new/benchmark.json"):
        estimates = bench.with_name("estimates.json")
        try:
            meta = json.loads(bench.read_text())
            median = json.loads(estimates.read_text())["median"]
        except (OSError, ValueError, KeyError) as e:
            print(f"skipping {bench.parent}: {e}", file=sys.stderr)
            continue
        ci = median["confidence_interval"]
        found[meta["full_id"]] = (
            median["point_estimate"],
            ci["lower_bound"],
            ci["upper_bound"],
            estimates.stat().st_mtime,
        )
    return found


def bench_names():
    """The benches defined in the sources: (literal function ids, group names)."""
    functions, groups = set(), set()
    for src in list(ROOT.glob("benches/*.rs")) + list(ROOT.glob("*/benches/*.rs")):
        text = src.read_text()
        functions |= set(re.findall(r'bench_function\(\s*"([^"]+)"', text))
        groups |= set(re.findall(r'benchmark_group\(\s*"([^"]+)"', text))
    return functions, groups


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
    args = ap.parse_args()

    names = bench_names()
    found = {k: v for k, v in results(pathlib.Path(args.criterion)).items() if current(k, names)}
    if not found:
        sys.exit(f"no criterion results under {args.criterion}: run the benches first (see --help)")
    text = DOC.read_text()
    try:
        head, rest = text.split(START, 1)
        block, tail = rest.split(END, 1)
    except ValueError:
        sys.exit(f"{DOC}: the markers {START} and {END} are missing")

    # The document's rows, in its order: id -> workload text.
    rows = []
    for line in block.splitlines():
        m = ROW.match(line.strip())
        if m:
            rows.append((m.group(1), m.group(2).strip()))
    known = {r[0] for r in rows}
    # A result the document has no row for gets one, to be described.
    for full_id in sorted(found):
        if full_id not in known:
            rows.append((full_id, "**(new: describe its workload)**"))

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
            at = datetime.datetime.fromtimestamp(mtime, datetime.timezone.utc).strftime("%H:%M")
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
