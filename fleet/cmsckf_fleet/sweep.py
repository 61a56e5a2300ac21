"""`cmsckf-fleet sweep`: `cmsckf evaluate` over a grid, one Ray task per seed.

Why this module exists: the paper's comparison (Schmidt, compressed, full)
over thousands of seeds, scenarios and settings is too long for one machine.
Each task is one `cmsckf evaluate --seed K --flights-out F` over one seed of
one grid point (scenario x configuration); its flights (CBOR) come back as
bytes and are written to the output directory as they arrive. Then
`cmsckf evaluate --merge` summarises each grid point's files exactly as one
`cmsckf evaluate` over those seeds would: the summary is computed by the
Rust binary, never here, so the two commands can be swapped.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass

import ray

from . import cluster
from .binary import CmsckfError, CmsckfKilled, executable, run
from .progress import Progress

# The flags passed through to every `cmsckf evaluate` task as given.
PASS_THROUGH = ("modes", "duration_s", "gnss", "landed_state")


@ray.remote(num_cpus=1, max_retries=3, retry_exceptions=[CmsckfKilled])
def fly_seed(binary: str, flags: list[str], seed: int, label: str) -> bytes:
    """One seed of one grid point: the `--flights-out` file's bytes.

    Retried by Ray when its worker dies (max_retries) or when the binary is
    killed by a signal; an error exit of the binary is an answer, not retried.
    """
    binary = executable(binary)
    with tempfile.TemporaryDirectory(prefix="cmsckf-fleet-seed-") as tmp:
        out = os.path.join(tmp, "flights.cbor")
        run(label, [binary, "evaluate", *flags, "--seed", str(seed), "--flights-out", out, "--json"])
        with open(out, "rb") as f:
            return f.read()


@dataclass
class Point:
    """One grid point: a scenario under one configuration."""

    index: int
    scenario: str
    config: str | None
    flags: list[str]

    @property
    def name(self) -> str:
        return f"point-{self.index}"

    def describe(self) -> str:
        return f"scenario {self.scenario}, config {self.config or 'the defaults'}"


def split_list(values: list[str] | None) -> list[str]:
    """`--scenario a,b --scenario c` -> [a, b, c]."""
    out: list[str] = []
    for v in values or []:
        out.extend(x for x in v.split(",") if x)
    return out


def grid(args, shipment: cluster.Shipment) -> list[Point]:
    """The grid points, each with the `evaluate` flags its tasks run with
    (shipped files named by their path inside the job's working_dir)."""
    scenarios = split_list(args.scenario) or [None]
    configs = args.config or [None]
    common: list[str] = []
    for name in PASS_THROUGH:
        value = getattr(args, name)
        if value is not None:
            common += ["--" + name.replace("_", "-"), str(value)]
    if args.sim_config:
        common += ["--sim-config", shipment.add(args.sim_config)]
    points = []
    for scenario in scenarios:
        flags = list(common)
        if scenario is not None:
            if scenario.startswith("tum:"):
                flags += ["--scenario", "tum:" + shipment.add(scenario[4:])]
            else:
                flags += ["--scenario", scenario]
        for config in configs:
            point_flags = list(flags)
            if config:
                point_flags += ["--config", shipment.add(config)]
            points.append(Point(len(points) + 1, scenario or "racetrack", config, point_flags))
    return points


def prepare_out(out: str | None) -> tuple[str, bool]:
    """The output directory, and whether it is a temporary one to remove."""
    if out is None:
        return tempfile.mkdtemp(prefix="cmsckf-fleet-sweep-"), True
    if os.path.exists(out) and not os.path.isdir(out):
        raise SystemExit(f"cmsckf-fleet: --out {out} is a file: give a new folder")
    if os.path.exists(out) and os.listdir(out):
        raise SystemExit(f"cmsckf-fleet: {out} exists and is not empty: give a new --out directory")
    os.makedirs(out, exist_ok=True)
    return out, False


def merge(binary: str, point: Point, out: str, seeds: list[int], as_json: bool, csv: str | None) -> bytes:
    """`cmsckf evaluate --merge` over one grid point's folder of seed files
    (run here, on the driver, where the files are; a folder, so that 10^5
    seeds need no command line of 10^5 names). `seeds` are all there: the
    sweep stops at the first task that fails."""
    argv = [binary, "evaluate", "--merge", "."]
    if as_json:
        argv.append("--json")
    if csv:
        argv += ["--csv", os.path.abspath(csv)]
    return run(f"merging {point.describe()} ({len(seeds)} seeds)", argv, cwd=os.path.join(out, point.name))


def csv_for(csv: str | None, point: Point, many: bool) -> str | None:
    if not csv or not many:
        return csv
    stem, ext = os.path.splitext(csv)
    return f"{stem}-{point.name}{ext or '.csv'}"


def sweep(args) -> int:
    if args.seeds < 1:
        raise SystemExit("cmsckf-fleet: --seeds must be at least 1")
    binary = cluster.find_binary(args.cmsckf)
    out, temporary = prepare_out(args.out)
    shipment = cluster.Shipment()
    try:
        points = grid(args, shipment)
        shipped = shipment.add(binary)
        seeds = list(range(1, args.seeds + 1))
        for p in points:
            os.makedirs(os.path.join(out, p.name), exist_ok=True)
            with open(os.path.join(out, p.name, "grid.json"), "w") as f:
                json.dump({"scenario": p.scenario, "config": p.config, "flags": p.flags, "seeds": seeds}, f)
        with cluster.running(args.address, args.workers, shipment):
            flown = fly(args, points, seeds, shipped, out)
        if not flown:
            return 1
        return summarise(args, binary, points, seeds, out)
    finally:
        shipment.remove()
        if temporary:
            shutil.rmtree(out, ignore_errors=True)


def fly(args, points: list[Point], seeds: list[int], shipped: str, out: str) -> bool:
    """Every (point, seed) as a task; each result written as it arrives."""
    memory = args.task_memory_mb * 1024 * 1024
    task = fly_seed.options(memory=memory)

    def jobs():
        for p in points:
            for k in seeds:
                label = f"seed {k} of {p.describe()}"
                yield (p, k, label), (lambda p=p, k=k, label=label: task.remote(shipped, p.flags, k, label))

    progress = Progress(len(points) * len(seeds), "sweep", quiet=args.quiet)
    try:
        for (p, k, label), data, error in cluster.stream(jobs(), args.max_in_flight):
            if error is not None:
                print(f"cmsckf-fleet sweep: {label} failed; stopping the sweep\n{error}", file=sys.stderr)
                return False
            path = os.path.join(out, p.name, f"seed-{k}.cbor")
            with open(path + ".part", "wb") as f:
                f.write(data)
            os.replace(path + ".part", path)  # a merge never sees half a file
            progress.step(label)
    finally:
        progress.close()
    return True


def summarise(args, binary: str, points: list[Point], seeds: list[int], out: str) -> int:
    """Merge each grid point and print what `cmsckf evaluate` would print."""
    many = len(points) > 1
    results = []
    for p in points:
        try:
            summary = merge(binary, p, out, seeds, True, csv_for(args.csv, p, many))
            with open(os.path.join(out, p.name, "evaluate.json"), "wb") as f:
                f.write(summary)
            if not many:
                text = summary if args.json else merge(binary, p, out, seeds, False, None)
                sys.stdout.buffer.write(text)
                sys.stdout.flush()
            elif args.json:
                results.append({"scenario": p.scenario, "config": p.config, "evaluate": json.loads(summary)})
            else:
                print(f"== {p.name}: {p.describe()}", flush=True)
                sys.stdout.buffer.write(merge(binary, p, out, seeds, False, None))
                sys.stdout.flush()
        except CmsckfError as e:
            print(f"cmsckf-fleet sweep: {e}", file=sys.stderr)
            return 1
    if many and args.json:
        json.dump({"grid": results}, sys.stdout)
        print()
    return 0
