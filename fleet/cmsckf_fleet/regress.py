"""`cmsckf-fleet regress OLD NEW LOGS`: a corpus replayed under two builds.

Why this module exists: before a new build flies, a team replays its corpus
of real flights under the old and the new build and wants every flight whose
estimates changed, with how much. Each task replays one log under both
builds (`cmsckf replay --json --out`) on one node, compares the two output
logs' estimates there (estimates.py) and sends back only the comparison, so
no replayed log crosses the network. One build replays a log bit for bit
(docs/flight-logs.md), so any difference is the builds'.

Exit status: 0 when no flight differs, 1 when some do, 2 when a replay failed.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile

import ray

from . import cluster, estimates
from .binary import CmsckfKilled, executable, run
from .progress import Progress
from .review import find_logs


@ray.remote(num_cpus=1, max_retries=3, retry_exceptions=[CmsckfKilled])
def replay_both(old: str, new: str, log: str, name: str, mode: str | None, config: str | None) -> dict:
    """Replay `log` under both builds and compare their estimates."""
    if not os.path.isfile(log):
        raise FileNotFoundError(f"flight {name}: {log} is not readable on this node")
    outputs, stats = {}, {}
    with tempfile.TemporaryDirectory(prefix="cmsckf-fleet-regress-") as tmp:
        for build, binary in (("old", old), ("new", new)):
            out = os.path.join(tmp, f"{build}.mcap")
            argv = [executable(binary), "replay", log, "--out", out, "--json"]
            if mode:
                argv += ["--mode", mode]
            if config:
                argv += ["--config", os.path.abspath(config)]
            stats[build] = json.loads(run(f"flight {name} under the {build} build", argv))
            outputs[build] = out
        diff = estimates.compare(outputs["old"], outputs["new"])
    return {"old": stats["old"], "new": stats["new"], "diff": diff}


def describe(diff: dict) -> str:
    largest = diff.get("largest")
    parts = []
    if largest:
        parts.append(
            f"{largest['topic']}.{largest['field']} by {largest['abs_diff']:.6g} at t = {largest['t_s']:.3f} s "
            f"({largest['first']!r} -> {largest['second']!r})"
        )
    if diff.get("first_non_numeric"):
        s = diff["first_non_numeric"]
        parts.append(f"{s['topic']}.{s['field']} {s['first']!r} -> {s['second']!r} at t = {s['t_s']:.3f} s")
    if diff["only_in_first"] or diff["only_in_second"]:
        parts.append(f"{diff['only_in_first']} messages only under OLD, {diff['only_in_second']} only under NEW")
    return "; ".join(parts)


def version(binary: str) -> str:
    try:
        return run("version", [binary, "--version"]).decode().strip()
    except Exception as e:  # a wrapper without --version: say so, go on
        return f"{binary} (no --version: {e.__class__.__name__})"


def regress(args) -> int:
    old, new = cluster.find_binary(args.old), cluster.find_binary(args.new)
    logs = find_logs(args.logs)
    shipment = cluster.Shipment()
    try:
        old_rel, new_rel = shipment.add(old), shipment.add(new)
        config = shipment.add(args.config) if args.config else None
        with cluster.running(args.address, args.workers, shipment):
            flights = gather(args, logs, old_rel, new_rel, config)
    finally:
        shipment.remove()
    flights.sort(key=lambda f: (f["error"] is None, -(f.get("max_position_diff_m") or 0.0), f["flight"]))
    differing = [f for f in flights if f.get("differs")]
    failed = [f for f in flights if f["error"]]
    result = {
        "old": version(old),
        "new": version(new),
        "flights": len(flights),
        "differing": len(differing),
        "failed": len(failed),
        "results": flights,
    }
    if args.json:
        json.dump(result, sys.stdout, indent=1)
        print()
    else:
        print(f"OLD {result['old']}\nNEW {result['new']}")
        for f in failed:
            print(f"FAILED   {f['flight']}: {f['error']}")
        for f in differing:
            print(f"DIFFERS  {f['flight']}: position {f['max_position_diff_m']:.6g} m at most; largest {f['largest_difference']}")
        print(f"{len(differing)} of {len(flights)} flights differ, {len(failed)} failed")
    if failed:
        return 2
    return 1 if differing else 0


def gather(args, logs, old: str, new: str, config: str | None) -> list[dict]:
    task = replay_both.options(memory=args.task_memory_mb * 1024 * 1024)
    jobs = (
        ((name, path), lambda name=name, path=path: task.remote(old, new, path, name, args.mode, config))
        for name, path in logs
    )
    flights = []
    progress = Progress(len(logs), "regress", quiet=args.quiet)
    try:
        for (name, path), result, error in cluster.stream(jobs, args.max_in_flight):
            f = {"flight": name, "log": path, "error": None}
            if error is not None:
                f["error"] = str(error)
                print(f"cmsckf-fleet regress: {path}: {error}", file=sys.stderr)
            else:
                d = result["diff"]
                f.update(
                    differs=d["differs"],
                    max_position_diff_m=d["max_position_diff_m"],
                    largest_difference=describe(d),
                    comparison=d,
                    old_replay=result["old"],
                    new_replay=result["new"],
                )
            flights.append(f)
            progress.step(name)
    finally:
        progress.close()
    return flights
