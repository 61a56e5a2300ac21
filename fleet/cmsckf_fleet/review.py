"""`cmsckf-fleet review`: every flight log of a fleet, one Ray task each.

Why this module exists: an operator with hundreds of logs a day wants one
table of what went wrong where, not hundreds of reports. Each task runs
`cmsckf review --json --html` on one log (the Rust binary reads the log and
computes every figure), optionally `cmsckf replay` under another mode or
config with the replay's difference from the flight, and sends back the
summary and the flight's own HTML page. The driver writes each page as it
arrives, then one table (Parquet and CSV, one row per flight) and the fleet
report (report.py), worst flights first.

The filter resets and the time spent degraded, by reason, are
`review --json`'s `resets` and `degraded_s`. The replay's estimates are
compared with the flight's (estimates.py) only in a log that `review` found
whole: a damaged log is left to the Rust reader, which checks every length
before it trusts one (docs/flight-logs.md).
"""

from __future__ import annotations

import json
import os
import socket
import sys
import tempfile

import ray

from . import cluster, estimates, report
from .binary import CmsckfError, CmsckfKilled, executable, run
from .progress import Progress


def log_is_whole(summary: dict) -> bool:
    check = summary.get("log_check") or {}
    return bool(check.get("finished")) and not check.get("chunks_dropped") and not summary.get("truncated")


@ray.remote(num_cpus=1, max_retries=3, retry_exceptions=[CmsckfKilled])
def review_flight(binary: str, log, name: str, replay_mode: str | None, replay_config: str | None) -> dict:
    """One flight: its review summary, its HTML page, its replay.

    `log` is a path every node can read (this machine, a shared filesystem)
    or the log's bytes (`--ship-logs`, through Ray's object store).
    """
    binary = executable(binary)
    what = f"flight {name}"
    with tempfile.TemporaryDirectory(prefix="cmsckf-fleet-review-") as tmp:
        if isinstance(log, bytes):
            path = os.path.join(tmp, "flight.mcap")
            with open(path, "wb") as f:
                f.write(log)
        else:
            path = log
            if not os.path.isfile(path):
                raise FileNotFoundError(
                    f"{what}: {path} is not readable on node {socket.gethostname()}: "
                    "put the logs on a filesystem every node mounts, or give --ship-logs"
                )
        page = os.path.join(tmp, "review.html")
        summary = json.loads(run(what, [binary, "review", "--json", "--html", page, path]))
        with open(page, "rb") as f:
            html = f.read()
        whole = log_is_whole(summary)
        replay = None
        if replay_mode or replay_config:
            out = os.path.join(tmp, "replay.mcap")
            argv = [binary, "replay", path, "--out", out, "--json"]
            if replay_mode:
                argv += ["--mode", replay_mode]
            if replay_config:
                argv += ["--config", os.path.abspath(replay_config)]
            try:
                stats = json.loads(run(f"replaying {what}", argv))
                replayed = json.loads(run(f"reviewing the replay of {what}", [binary, "review", "--json", out]))
            except CmsckfError as e:
                # The flight's own review stands; its row says why the
                # replay failed.
                replay = {"error": str(e)}
            else:
                # The flight's own estimates are read only from a whole log (see above).
                diff = estimates.compare(path, out) if whole else None
                replay = {"stats": stats, "review": replayed, "diff": diff}
    return {"summary": summary, "html": html, "replay": replay}


def find_logs(inputs: list[str]) -> list[tuple[str, str]]:
    """(name, absolute path) for each log given, or each `*.mcap` under a
    directory given; names are unique and safe as file names."""
    found: list[tuple[str, str]] = []
    for given in inputs:
        if os.path.isdir(given):
            for root, dirs, files in os.walk(given):
                dirs.sort()
                for f in sorted(files):
                    if f.endswith(".mcap"):
                        path = os.path.join(root, f)
                        found.append((os.path.relpath(path, given), os.path.abspath(path)))
        elif os.path.isfile(given):
            found.append((os.path.basename(given), os.path.abspath(given)))
        else:
            raise SystemExit(f"cmsckf-fleet: {given} is neither a log nor a directory")
    if not found:
        raise SystemExit("cmsckf-fleet: no .mcap logs in " + " ".join(inputs))
    names: set[str] = set()
    out = []
    for rel, path in found:
        base = rel[:-5] if rel.endswith(".mcap") else rel
        base = base.replace(os.sep, "__")
        name, n = base, 1
        while name in names:
            n += 1
            name = f"{base}-{n}"
        names.add(name)
        out.append((name, path))
    return out


def row(name: str, log: str, result: dict | None, error: BaseException | None, args) -> dict:
    """One flight's row of the fleet table."""
    r: dict = {"flight": name, "log": log, "review_page": None, "error": None}
    if error is not None:
        r["error"] = str(error)
        return r
    s = result["summary"]
    check = s.get("log_check") or {}
    rejected = s.get("rejected") or {}
    reports = s.get("autopilot_ratio_reports")
    refused = s.get("autopilot_rejected_reports")
    truth = "truth" in (s.get("error_reference") or "")
    r.update(
        review_page=f"flights/{name}.html",
        duration_s=s.get("duration_s"),
        messages=s.get("messages"),
        log_finished=check.get("finished"),
        log_truncated=s.get("truncated"),
        chunks_dropped=len(check.get("chunks_dropped") or []),
        resets=s.get("resets"),
        degraded_s=sum((s.get("degraded_s") or {}).values()),
        rejected_total=sum(rejected.values()),
        vision_updates=s.get("vision_updates"),
        tracks_used=s.get("tracks_used"),
        gnss_updates=s.get("gnss_updates"),
        global_updates=s.get("global_updates"),
        promotions=s.get("promotions"),
        keyframes=s.get("keyframes"),
        estimates=s.get("estimates"),
        nis_per_dof_mean=s.get("nis_per_dof_mean"),
        nis_in_95=s.get("nis_in_95"),
        update_us_p50=s.get("update_us_p50"),
        update_us_p99=s.get("update_us_p99"),
        update_us_max=s.get("update_us_max"),
        ate_m=s.get("position_error_rms_m") if truth else None,
        ate_within_3sigma=s.get("position_error_within_3sigma") if truth else None,
        error_reference=s.get("error_reference"),
        autopilot_ratio_reports=reports,
        autopilot_rejected_reports=refused,
        autopilot_acceptance=(1.0 - refused / reports) if reports else None,
        autopilot_pos_horiz_ratio_max=s.get("autopilot_pos_horiz_ratio_max"),
        autopilot_pos_vert_ratio_max=s.get("autopilot_pos_vert_ratio_max"),
    )
    for reason, n in sorted(rejected.items()):
        r[f"rejected_{reason}"] = n
    for reason, secs in sorted((s.get("degraded_s") or {}).items()):
        r[f"degraded_s_{reason}"] = secs
    replay = result.get("replay")
    if replay is not None and "error" in replay:
        r.update(replay_mode=args.replay_mode, replay_config=args.replay_config, replay_error=replay["error"])
    elif replay is not None:
        diff, stats, rs = replay["diff"] or {}, replay["stats"], replay["review"]
        largest = diff.get("largest")
        r.update(
            replay_mode=args.replay_mode,
            replay_config=args.replay_config,
            replay_realtime_factor=stats.get("realtime_factor"),
            replay_estimates_out=stats.get("estimates_out"),
            replay_malformed_inputs=stats.get("malformed_inputs"),
            replay_ate_m=rs.get("position_error_rms_m") if "truth" in (rs.get("error_reference") or "") else None,
            replay_differs=diff.get("differs"),
            replay_max_position_diff_m=diff.get("max_position_diff_m"),
            replay_largest_diff=(
                f"{largest['topic']}.{largest['field']} by {largest['abs_diff']:.3g} at {largest['t_s']:.2f} s"
                if largest
                else None
            ),
        )
    return r


# The table's columns in this order; the by-reason columns follow their totals.
BASE_COLUMNS = [
    "flight", "log", "review_page", "error", "duration_s", "messages", "log_finished", "log_truncated",
    "chunks_dropped", "resets", "degraded_s", "rejected_total", "vision_updates", "tracks_used",
    "gnss_updates", "global_updates", "promotions", "keyframes", "estimates", "nis_per_dof_mean", "nis_in_95",
    "update_us_p50", "update_us_p99", "update_us_max", "ate_m", "ate_within_3sigma", "error_reference",
    "autopilot_ratio_reports", "autopilot_rejected_reports", "autopilot_acceptance",
    "autopilot_pos_horiz_ratio_max", "autopilot_pos_vert_ratio_max",
]  # fmt: skip


def columns(rows: list[dict]) -> list[str]:
    keys = set().union(*(r.keys() for r in rows))
    cols = []
    for c in BASE_COLUMNS:
        cols.append(c)
        if c in ("degraded_s", "rejected_total"):
            prefix = "degraded_s_" if c == "degraded_s" else "rejected_"
            cols += sorted(k for k in keys if k.startswith(prefix) and k != c)
    cols += sorted(k for k in keys if k.startswith("replay_"))
    return cols


def write_table(rows: list[dict], out: str) -> None:
    import pyarrow as pa
    import pyarrow.csv
    import pyarrow.parquet

    cols = columns(rows)
    table = pa.Table.from_pylist([{c: r.get(c) for c in cols} for r in rows])
    pyarrow.parquet.write_table(table, os.path.join(out, "fleet.parquet"))
    pyarrow.csv.write_csv(table, os.path.join(out, "fleet.csv"))


def review(args) -> int:
    binary = cluster.find_binary(args.cmsckf)
    logs = find_logs(args.logs)
    out = args.out
    if os.path.exists(out) and not os.path.isdir(out):
        raise SystemExit(f"cmsckf-fleet: --out {out} is a file: give a folder")
    if os.path.isdir(out) and os.listdir(out) and not args.force:
        raise SystemExit(f"cmsckf-fleet: {out} exists and is not empty: give another --out, or --force")
    os.makedirs(os.path.join(out, "flights"), exist_ok=True)
    shipment = cluster.Shipment()
    try:
        shipped = shipment.add(binary)
        config = shipment.add(args.replay_config) if args.replay_config else None
        with cluster.running(args.address, args.workers, shipment):
            rows = gather(args, logs, shipped, config, out)
    finally:
        shipment.remove()
    rows.sort(key=lambda r: r["flight"])  # equals stay in name order
    rows.sort(key=report.badness, reverse=True)
    write_table(rows, out)
    report.write(rows, os.path.join(out, "report.html"), title=args.title)
    failed = [r for r in rows if r["error"]]
    print(
        f"cmsckf-fleet review: {len(rows)} flights, {len(failed)} failed; "
        f"{os.path.join(out, 'report.html')}, fleet.parquet, fleet.csv",
        file=sys.stderr,
    )
    return 1 if failed else 0


@ray.remote(num_cpus=0)
def unreadable(why: str) -> dict:
    """A log the driver could not read to ship: an error row, like a task's."""
    raise OSError(why)


def gather(args, logs, shipped: str, config: str | None, out: str) -> list[dict]:
    task = review_flight.options(memory=args.task_memory_mb * 1024 * 1024)

    def jobs():
        for name, path in logs:
            def submit(name=name, path=path):
                if not args.ship_logs:
                    return task.remote(shipped, path, name, args.replay_mode, config)
                try:
                    with open(path, "rb") as f:
                        log = f.read()
                except OSError as e:
                    # Its row says why; the other flights go on.
                    return unreadable.remote(f"flight {name}: {path} cannot be read here: {e}")
                return task.remote(shipped, log, name, args.replay_mode, config)
            yield (name, path), submit

    rows = []
    progress = Progress(len(logs), "review", quiet=args.quiet)
    try:
        for (name, path), result, error in cluster.stream(jobs(), args.max_in_flight):
            if error is not None:
                print(f"cmsckf-fleet review: {path}: {error}", file=sys.stderr)
            else:
                with open(os.path.join(out, "flights", f"{name}.html"), "wb") as f:
                    f.write(result["html"])
                with open(os.path.join(out, "flights", f"{name}.json"), "w") as f:
                    json.dump({k: v for k, v in result.items() if k != "html"}, f, indent=1)
            rows.append(row(name, path, result, error, args))
            progress.step(name)
    finally:
        progress.close()
    return rows

