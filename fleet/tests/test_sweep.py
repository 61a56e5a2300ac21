"""`cmsckf-fleet sweep` gives what `cmsckf evaluate` gives: on embedded Ray
with 2 workers, on a 3-node cluster simulated on this machine, and with a
worker killed mid-sweep. A failing seed is reported by name with the
binary's stderr."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

from conftest import GRID, assert_same_answers, env, evaluate, fleet


def test_sweep_on_local_ray_equals_evaluate(cmsckf, tmp_path):
    done = fleet(cmsckf, "sweep", "--workers", "2", *GRID, "--json", "--out", tmp_path / "sweep")
    got = json.loads(done.stdout)
    assert got["seed_numbers"] == [1, 2, 3]
    assert_same_answers(got, evaluate(cmsckf, *GRID))
    # The flights are kept, one file per seed, and the grid point's summary.
    point = tmp_path / "sweep" / "point-1"
    assert sorted(p.name for p in point.glob("seed-*.cbor")) == ["seed-1.cbor", "seed-2.cbor", "seed-3.cbor"]
    assert json.loads((point / "evaluate.json").read_text()) == got


def test_sweep_on_a_three_node_cluster_equals_evaluate(cmsckf):
    from ray.cluster_utils import Cluster

    def node(n: int) -> dict:
        # Each simulated node unpacks the job's files into a directory of its
        # own, as a real node does on its own disk: sharing one, a node that
        # joins later unpacks them afresh under another node's running task.
        # (The head keeps Ray's default name, where the driver stages uploads.)
        args = {"num_cpus": 1, "object_store_memory": 200 * 1024 * 1024}
        if n:
            args["runtime_env_dir_name"] = f"runtime_resources_node{n}"
        return args

    cluster = Cluster(initialize_head=True, head_node_args=node(0))
    try:
        for n in (1, 2):
            cluster.add_node(**node(n))
        cluster.wait_for_nodes()
        done = fleet(cmsckf, "sweep", "--address", cluster.address, *GRID, "--json")
    finally:
        cluster.shutdown()
    assert_same_answers(json.loads(done.stdout), evaluate(cmsckf, *GRID))


def _processes() -> dict[int, tuple[int, list[str]]]:
    """pid -> (parent pid, argv) for every process we can read."""
    out = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                argv = [a.decode(errors="replace") for a in f.read().split(b"\0") if a]
            with open(f"/proc/{entry}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        out[int(entry)] = (ppid, argv)
    return out


def _busy_seed(driver: int, skip: set[int]) -> tuple[int, int] | None:
    """(pid of a running `cmsckf evaluate --seed` task, pid of its Ray worker),
    among the descendants of our sweep's driver only."""
    procs = _processes()
    for pid, (ppid, argv) in procs.items():
        if pid in skip or "evaluate" not in argv or "--flights-out" not in argv:
            continue
        up, seen = ppid, 0
        while up > 1 and up != driver and seen < 20:
            up, seen = procs.get(up, (0, []))[0], seen + 1
        if up == driver:
            return pid, ppid
    return None


def test_a_worker_killed_mid_sweep_changes_nothing(cmsckf):
    grid = ["--scenario", "racetrack", "--modes", "msckf,compressed,full", "--seeds", "6", "--duration-s", "30"]
    argv = [sys.executable, "-m", "cmsckf_fleet", "sweep", "--workers", "2", *grid, "--json"]
    sweep = subprocess.Popen(argv, env=env(cmsckf), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    killed_worker = killed_binary = orphan = None
    try:
        deadline = time.monotonic() + 120
        while (killed_worker is None or killed_binary is None) and time.monotonic() < deadline:
            if sweep.poll() is not None:
                break
            busy = _busy_seed(sweep.pid, skip={orphan, killed_binary})
            if busy is None:
                time.sleep(0.01)
                continue
            child, worker = busy
            if killed_worker is None:
                # The Ray worker running a seed dies (a node lost, the OOM
                # killer): Ray runs the task again (max_retries).
                os.kill(worker, signal.SIGKILL)
                os.kill(child, signal.SIGKILL)  # its orphan would only burn a CPU
                killed_worker, orphan = worker, child
            elif worker != killed_worker:
                # The binary itself is killed by a signal: the task raises
                # CmsckfKilled, which Ray retries (retry_exceptions).
                os.kill(child, signal.SIGKILL)
                killed_binary = child
        out, err = sweep.communicate(timeout=240)
    finally:
        if sweep.poll() is None:
            sweep.kill()
    assert killed_worker, f"no busy worker was found to kill:\n{err}"
    assert killed_binary, f"no second busy seed was found to kill:\n{err}"
    assert sweep.returncode == 0, err
    assert_same_answers(json.loads(out), evaluate(cmsckf, *grid))


def test_a_failing_seed_is_named_with_the_binarys_stderr(cmsckf, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[camera]\nno_such_field = 1\n")
    done = fleet(cmsckf, "sweep", "--workers", "2", *GRID, "--config", bad, "--json", check=False)
    assert done.returncode == 1
    assert done.stdout == ""
    assert "seed " in done.stderr and "scenario racetrack" in done.stderr and str(bad) in done.stderr
    assert "no_such_field" in done.stderr  # the binary's own words
