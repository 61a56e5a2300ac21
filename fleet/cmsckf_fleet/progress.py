"""Progress with an ETA, on stderr.

Why this module exists: a fleet job runs for minutes to hours, and whoever
started it wants to know how far it is and when it ends. On a terminal that
is a tqdm bar; in a log (a RayJob's, CI's) a bar is noise, so each finished
task gets one plain line with the count, the elapsed time and the ETA.
"""

from __future__ import annotations

import sys
import time


class Progress:
    def __init__(self, total: int, what: str, quiet: bool = False, stream=None):
        self.total = total
        self.what = what
        self.done = 0
        self.quiet = quiet
        self.stream = stream or sys.stderr
        self.start = time.monotonic()
        self.bar = None
        if not quiet and self.stream.isatty():
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=what, unit="task", file=self.stream)

    def step(self, label: str) -> None:
        self.done += 1
        if self.quiet:
            return
        if self.bar is not None:
            self.bar.set_postfix_str(label, refresh=False)
            self.bar.update(1)
            return
        elapsed = time.monotonic() - self.start
        left = self.total - self.done
        eta = elapsed / self.done * left
        print(
            f"{self.what} [{self.done}/{self.total}] {label}: "
            f"{elapsed:.1f} s elapsed, ETA {eta:.0f} s",
            file=self.stream,
            flush=True,
        )

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
