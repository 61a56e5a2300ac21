"""`cmsckf-fleet overhead`: what one task costs Ray, on this machine or a cluster.

Why this module exists: whether a job is worth spreading depends on how its
task length compares with Ray's cost per task. This measures that cost the
way the commands pay it (tasks through `cluster.stream`, the binary shipped
in the runtime environment): tasks per second of a task that does nothing,
and of one that runs `cmsckf --version` (a process start and the binary's
load, no flight). docs/fleet.md gives the figures and the command.
"""

from __future__ import annotations

import json
import time

import ray

from . import cluster
from .binary import executable, run


@ray.remote(num_cpus=1)
def nothing() -> None:
    return None


@ray.remote(num_cpus=1)
def cmsckf_version(binary: str) -> bytes:
    return run("cmsckf --version", [executable(binary), "--version"])


def rate(n: int, submit, max_in_flight: int | None) -> float:
    t0 = time.perf_counter()
    for _, _, error in cluster.stream((((i,), submit) for i in range(n)), max_in_flight):
        if error is not None:
            raise SystemExit(f"cmsckf-fleet overhead: a task failed: {error}")
    return n / (time.perf_counter() - t0)


def overhead(args) -> int:
    binary = cluster.find_binary(args.cmsckf)
    shipment = cluster.Shipment()
    try:
        shipped = shipment.add(binary)
        t0 = time.perf_counter()
        with cluster.running(args.address, args.workers, shipment):
            started = time.perf_counter() - t0
            cpus = cluster.cluster_cpus()
            t0 = time.perf_counter()
            ray.get([cmsckf_version.remote(shipped) for _ in range(cpus)])  # workers up, package unpacked
            first = time.perf_counter() - t0
            result = {
                "cpus": cpus,
                "ray_start_s": started,
                "first_tasks_s": first,
                "noop_tasks_per_s": rate(args.tasks, lambda: nothing.remote(), args.max_in_flight),
                "version_tasks_per_s": rate(args.tasks, lambda: cmsckf_version.remote(shipped), args.max_in_flight),
                "tasks": args.tasks,
            }
    finally:
        shipment.remove()
    print(json.dumps(result))
    return 0
