"""Running `cmsckf` from a task, and saying exactly what failed.

Why this module exists: every command here is a loop over runs of the Rust
binary, and a run that fails must be reported with the flight or seed it was
for and the binary's own stderr, never swallowed. This is the one place that
starts the binary, so it is the one place that turns a failure into such an
error. The errors pickle, so they travel from a Ray worker to the driver
intact (Ray wraps them in `RayTaskError`, whose `cause` is this error).
"""

from __future__ import annotations

import os
import subprocess

# How much of a failing binary's stderr an error message quotes. The whole
# stderr stays on the error (`.stderr`).
_QUOTE_LINES = 40


class CmsckfError(Exception):
    """`cmsckf` exited with an error: `what` names the flight or seed."""

    def __init__(self, what: str, argv: list[str], returncode: int, stderr: str):
        super().__init__(what, argv, returncode, stderr)
        self.what = what
        self.argv = list(argv)
        self.returncode = returncode
        self.stderr = stderr

    def __str__(self) -> str:
        status = (
            f"was killed by signal {-self.returncode}"
            if self.returncode < 0
            else f"exited with status {self.returncode}"
        )
        # The binary by its name: a shipped one's path is a long Ray directory.
        command = " ".join([os.path.basename(self.argv[0]), *self.argv[1:]])
        return f"{self.what}: `{command}` {status}\n{quote_stderr(self.stderr)}"


class CmsckfKilled(CmsckfError):
    """`cmsckf` was killed by a signal (the kernel's OOM killer, a node being
    drained): not an answer of the binary, so the task is worth retrying."""


def quote_stderr(stderr: str) -> str:
    """The part of a Rust error worth reading: its message without the
    backtrace that RUST_BACKTRACE=1 appends, and at most _QUOTE_LINES lines."""
    text = stderr.rstrip()
    cut = text.find("\nStack backtrace:")
    note = ""
    if cut >= 0:
        note = f"\n  (backtrace of {text[cut:].count(chr(10))} lines left out)"
        text = text[:cut]
    lines = text.splitlines()
    if len(lines) > _QUOTE_LINES:
        note = f"\n  ({len(lines) - _QUOTE_LINES} earlier lines left out)" + note
        lines = lines[-_QUOTE_LINES:]
    body = "\n".join("  " + line for line in lines) if lines else "  (no stderr)"
    return body + note


def run(
    what: str, argv: list[str], timeout_s: float | None = None, cwd: str | None = None
) -> bytes:
    """Run `argv` (a `cmsckf` command) in `cwd` and return its stdout.

    `what` names the flight or seed for the error. A non-zero exit raises
    CmsckfError; death by a signal raises CmsckfKilled; a time-out kills the
    process and raises CmsckfError.
    """
    try:
        done = subprocess.run(
            argv,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            timeout=timeout_s,
            cwd=cwd,
        )
    except subprocess.TimeoutExpired as e:
        stderr = (e.stderr or b"").decode("utf-8", "replace")
        raise CmsckfError(what, argv, 124, f"timed out after {timeout_s} s\n{stderr}") from None
    except OSError as e:
        raise CmsckfError(what, argv, 127, f"could not start it: {e}") from None
    stderr = done.stderr.decode("utf-8", "replace")
    if done.returncode < 0:
        raise CmsckfKilled(what, argv, done.returncode, stderr)
    if done.returncode != 0:
        raise CmsckfError(what, argv, done.returncode, stderr)
    return done.stdout


def executable(path: str) -> str:
    """The absolute path of a shipped binary, made executable if the archive
    that carried it lost the mode bit."""
    path = os.path.abspath(path)
    mode = os.stat(path).st_mode
    if not mode & 0o100:
        os.chmod(path, mode | 0o755)
    return path
