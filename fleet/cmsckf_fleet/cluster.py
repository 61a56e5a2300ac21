"""Ray, set up the same way for every command, and results streamed back.

Why this module exists: each command needs the same three things from Ray,
and they are easy to get subtly wrong one command at a time:

- `start` (`running`, for a `with` block): Ray embedded on this machine by default (`address="local"`, so
  that a cluster someone left running here is never joined by accident),
  with `workers` CPUs; or a cluster joined with `--address` or RAY_ADDRESS.
- `Shipment`: the `cmsckf` binary and the config files the tasks need reach
  every worker through Ray's runtime environment (`working_dir`, a directory
  Ray zips, uploads once and unpacks on each node; tasks run inside it, so
  they name shipped files by relative path). This package itself goes as a
  `py_modules` entry, so a cluster need not have it installed.
- `stream`: tasks submitted with at most `max_in_flight` unfinished, and
  each result handed to the caller as soon as it is ready (`ray.wait`), so a
  sweep of 10^5 tasks never holds 10^5 results or task specs in the driver.
  This is Ray's documented pattern for limiting pending tasks, not a
  scheduler: Ray places, runs and retries every task.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import shutil
import sys
import tempfile
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import ray

import cmsckf_fleet


def find_binary(given: str | None) -> str:
    """`--cmsckf PATH`, else CMSCKF_BIN, else `cmsckf` on PATH."""
    name = given or os.environ.get("CMSCKF_BIN") or "cmsckf"
    path = shutil.which(name) if os.sep not in name else name
    if not path or not os.path.isfile(path):
        raise SystemExit(
            f"cmsckf-fleet: no cmsckf binary at {name!r}: give --cmsckf PATH, "
            "set CMSCKF_BIN, or put cmsckf on PATH"
        )
    if not os.access(path, os.X_OK):
        raise SystemExit(f"cmsckf-fleet: {path} is not executable")
    return os.path.abspath(path)


class Shipment:
    """Files that go to every worker in the job's `working_dir`."""

    def __init__(self) -> None:
        self.dir = tempfile.mkdtemp(prefix="cmsckf-fleet-ship-")
        self._names: dict[str, str] = {}

    def add(self, path: str) -> str:
        """Ship the file at `path`; returns the relative path tasks use."""
        path = os.path.abspath(path)
        if path in self._names:
            return self._names[path]
        if not os.path.isfile(path):
            raise SystemExit(f"cmsckf-fleet: {path} is not a file")
        base = os.path.basename(path)
        name = base
        n = 1
        while os.path.exists(os.path.join(self.dir, name)):
            n += 1
            name = f"{n}-{base}"
        target = os.path.join(self.dir, name)
        try:
            os.link(path, target)  # no copy of a 100 MB binary when it can be helped
        except OSError:
            shutil.copy2(path, target)
        self._names[path] = name
        return name

    def runtime_env(self) -> dict[str, Any]:
        return {"working_dir": self.dir, "py_modules": [cmsckf_fleet]}

    def remove(self) -> None:
        shutil.rmtree(self.dir, ignore_errors=True)


def reachable(address: str, timeout_s: float = 5.0) -> None:
    """Refuse at once a cluster address that nothing answers on: Ray itself
    retries an unreachable one for minutes, saying only that it retries."""
    if address == "auto" or address.startswith(("ray://", "local")):
        return
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise SystemExit(f"cmsckf-fleet: {address!r} is no Ray address: give HOST:PORT (the head's GCS, 6379 by default)")
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except OSError as e:
        raise SystemExit(f"cmsckf-fleet: no Ray head answers at {address} (--address or RAY_ADDRESS): {e}")


def start(address: str | None, workers: int | None, shipment: Shipment) -> None:
    """Start embedded Ray, or join the cluster at `address` / RAY_ADDRESS."""
    address = address or os.environ.get("RAY_ADDRESS")
    # Ray warns of every shipped file over 10 MiB; the binary is one on purpose.
    logging.getLogger("ray._private.runtime_env.packaging").setLevel(logging.ERROR)
    common = dict(
        runtime_env=shipment.runtime_env(),
        logging_level=logging.WARNING,
        log_to_driver=True,
    )
    if address:
        if workers:
            logging.getLogger(__name__).warning(
                "--workers is for embedded Ray; the cluster at %s has its own", address
            )
        reachable(address)
        try:
            ray.init(address=address, **common)
        except (ConnectionError, ValueError, RuntimeError) as e:
            raise SystemExit(f"cmsckf-fleet: cannot join the Ray cluster at {address!r} (--address or RAY_ADDRESS): {e}")
    else:
        ray.init(
            address="local",
            num_cpus=workers or os.cpu_count() or 1,
            include_dashboard=False,
            **common,
        )


@contextlib.contextmanager
def running(address: str | None, workers: int | None, shipment: Shipment) -> Iterator[None]:
    """Ray for the length of a `with` block. Whatever Ray prints meanwhile (a
    task's output, the raylet's word that a worker died) goes to stderr:
    stdout carries the command's answer alone, as `cmsckf evaluate`'s does."""
    with contextlib.redirect_stdout(sys.stderr):
        start(address, workers, shipment)
        try:
            yield
        finally:
            ray.shutdown()


def cluster_cpus() -> int:
    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def stream(
    jobs: Iterable[tuple[Any, Callable[[], ray.ObjectRef]]],
    max_in_flight: int | None = None,
) -> Iterator[tuple[Any, Any, BaseException | None]]:
    """Submit `jobs` (key, submit) and yield (key, result, error) as each ends.

    `submit()` starts one task and returns its ObjectRef; it is called only
    when fewer than `max_in_flight` tasks are unfinished (default: twice the
    cluster's CPUs, enough to keep every CPU busy). A task's error, after
    Ray's own retries, is yielded, never raised here: the caller names the
    flight or seed. The result is dropped from the object store once yielded.
    """
    limit = max_in_flight or max(4, 2 * cluster_cpus())
    queue = iter(jobs)
    pending: dict[ray.ObjectRef, Any] = {}

    def fill() -> None:
        while len(pending) < limit:
            try:
                key, submit = next(queue)
            except StopIteration:
                return
            pending[submit()] = key

    fill()
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        ref = ready[0]
        key = pending.pop(ref)
        try:
            result, error = ray.get(ref), None
        except ray.exceptions.RayTaskError as e:
            result, error = None, (e.cause if isinstance(e.cause, BaseException) else e)
        except ray.exceptions.RayError as e:  # the worker or node died past max_retries
            result, error = None, e
        del ref
        fill()
        yield key, result, error
