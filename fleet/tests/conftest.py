"""What every test of cmsckf-fleet shares: the binary under test, the command
run as a user runs it, and a few short demo flight logs.

The binary is CMSCKF_BIN (run-tests.sh passes it through; `cargo test` sets
it to the binary it built). Every test drives `python -m cmsckf_fleet` in a
process of its own, on embedded Ray unless it joins a cluster it started.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

# The fields of `cmsckf evaluate --json` that are wall-clock timings of the
# machine that flew: they differ between any two runs, even of `evaluate`
# itself. Every other field must be equal to the last digit.
TIMINGS = {
    "frame_us_mean",
    "frame_us_p99",
    "frame_us_p50",
    "frame_us_max",
    "rebase_ms_mean",
    "rebase_ms_max",
    "rebase_ms",
}

# A small grid: three modes, three seeds, 8 s flights.
GRID = ["--scenario", "racetrack", "--modes", "msckf,compressed,full", "--seeds", "3", "--duration-s", "8"]


@pytest.fixture(scope="session")
def cmsckf() -> str:
    path = os.environ.get("CMSCKF_BIN")
    if not path or not os.access(path, os.X_OK):
        pytest.fail("set CMSCKF_BIN to the cmsckf binary under test (fleet/run-tests.sh passes it through)")
    return os.path.abspath(path)


def env(cmsckf: str) -> dict:
    e = dict(os.environ, CMSCKF_BIN=cmsckf, PYTHONDONTWRITEBYTECODE="1")
    e.pop("RAY_ADDRESS", None)  # embedded Ray unless a test says otherwise
    return e


def fleet(cmsckf: str, *args, check: bool = True, timeout: float = 240) -> subprocess.CompletedProcess:
    """`cmsckf-fleet ARGS`, as a user runs it; on failure, its stderr."""
    argv = [sys.executable, "-m", "cmsckf_fleet", *map(str, args)]
    done = subprocess.run(argv, env=env(cmsckf), capture_output=True, text=True, timeout=timeout)
    if check:
        assert done.returncode == 0, f"{' '.join(argv)} exited {done.returncode}:\n{done.stderr}"
    return done


def evaluate(cmsckf: str, *args) -> dict:
    """What single-process `cmsckf evaluate ARGS --json` prints."""
    done = subprocess.run([cmsckf, "evaluate", *args, "--json"], capture_output=True, text=True, check=True)
    return json.loads(done.stdout)


def without_timings(result: dict) -> dict:
    result = json.loads(json.dumps(result))
    for mode in result["modes"].values():
        for k in TIMINGS:
            mode.pop(k, None)
    return result


def assert_same_answers(got: dict, want: dict) -> None:
    """Equal field by field, digit for digit, except the timings."""
    got, want = without_timings(got), without_timings(want)
    assert set(got) == set(want)
    for key in want:
        if key != "modes":
            assert got[key] == want[key], key
    assert set(got["modes"]) == set(want["modes"])
    for mode, fields in want["modes"].items():
        assert set(got["modes"][mode]) == set(fields), mode
        for field, value in fields.items():
            assert got["modes"][mode][field] == value, f"{mode}.{field}"


@pytest.fixture(scope="session")
def demo_logs(cmsckf, tmp_path_factory) -> Path:
    """Three 10 s demo flights: a clean one, one with a camera outage (degraded
    for a while), and one flown in msckf mode (the others are compressed)."""
    d = tmp_path_factory.mktemp("logs")
    flights = {
        "clean": ["--seed", "1"],
        "outage": ["--seed", "2", "--fault", "camera_outage@4+3"],
        "msckf": ["--seed", "3", "--mode", "msckf"],
    }
    for name, extra in flights.items():
        subprocess.run(
            [cmsckf, "demo", "--duration-s", "10", "--speedup", "50", "--log", str(d / f"{name}.mcap"), "--json", *extra],
            cwd=d,
            capture_output=True,
            check=True,
        )
    return d
