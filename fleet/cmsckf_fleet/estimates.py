"""Comparing the estimates two flight logs carry.

Why this module exists: `regress` must say whether two builds give the same
estimates on a log, and by how much they differ; `review --replay-mode` says
how far a replay is from the flight. Both compare the logs' estimate
channels (docs/flight-logs.md): what was sent to the autopilot
(`/output/vision_position_estimate`), the filter's state at 10 Hz
(`/filter/state`) and the keyframes (`/filter/keyframes`). None of these
carries a wall-clock time, so one build replaying one log twice gives equal
messages, and any difference is the build's (or the config's, or the mode's).

The logs are read with the `mcap` package from PyPI, independently of the
Rust writer. Messages are paired by channel and publish time (the
autopilot's boot time, which replay keeps), streaming both files in time
order, so two one-hour logs never sit in memory whole.
"""

from __future__ import annotations

import heapq
import json
import math
from collections.abc import Iterator

from mcap.reader import make_reader

POSITION_TOPIC = "/output/vision_position_estimate"
TOPICS = (POSITION_TOPIC, "/filter/state", "/filter/keyframes")


def _messages(path: str, side: int) -> Iterator[tuple[int, int, tuple, object]]:
    """(log time, side, pairing key, message) for each estimate message."""
    last: dict[str, tuple[int, int]] = {}
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(topics=TOPICS, log_time_order=True):
            t, n = last.get(channel.topic, (None, -1))
            n = n + 1 if t == message.publish_time else 0
            last[channel.topic] = (message.publish_time, n)
            key = (channel.topic, message.publish_time, n)
            yield message.log_time, side, key, json.loads(message.data)


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


class _Tally:
    def __init__(self) -> None:
        self.compared = 0
        self.differing = 0
        self.largest = None  # (abs diff, topic, field, t_s, first, second)
        self.structural = None  # the first non-numeric difference
        self.position_max = 0.0
        self.position_sq = 0.0
        self.position_n = 0

    def walk(self, a, b, field: str, topic: str, t_s: float) -> bool:
        """Compare two decoded messages leaf by leaf; True if any leaf differs."""
        if isinstance(a, dict) and isinstance(b, dict):
            differ = False
            for k in sorted(set(a) | set(b)):
                sub = f"{field}.{k}" if field else k
                if k not in a or k not in b:
                    self._structural(topic, sub, t_s, a.get(k), b.get(k))
                    differ = True
                elif self.walk(a[k], b[k], sub, topic, t_s):
                    differ = True
            return differ
        if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
            differ = False
            for i, (x, y) in enumerate(zip(a, b)):
                differ |= self.walk(x, y, f"{field}[{i}]", topic, t_s)
            return differ
        if _is_number(a) and _is_number(b):
            if a == b or (math.isnan(a) and math.isnan(b)):
                return False
            d = abs(a - b) if not (math.isnan(a) or math.isnan(b)) else math.inf
            if self.largest is None or d > self.largest[0]:
                self.largest = (d, topic, field, t_s, a, b)
            return True
        if a != b:
            self._structural(topic, field, t_s, a, b)
            return True
        return False

    def _structural(self, topic, field, t_s, a, b) -> None:
        if self.structural is None:
            self.structural = {"topic": topic, "field": field, "t_s": t_s, "first": a, "second": b}

    def pair(self, key: tuple, a, b) -> None:
        topic, publish_time, _ = key
        t_s = publish_time / 1e9
        self.compared += 1
        if self.walk(a, b, "", topic, t_s):
            self.differing += 1
        if topic == POSITION_TOPIC:
            pa, pb = a.get("p_ned_m"), b.get("p_ned_m")
            if isinstance(pa, list) and isinstance(pb, list) and len(pa) == len(pb) == 3:
                d = math.dist(pa, pb)
                self.position_max = max(self.position_max, d)
                self.position_sq += d * d
                self.position_n += 1


def compare(first: str, second: str) -> dict:
    """How the estimates in log `first` differ from those in log `second`.

    `differs` is true when any paired message differs in any field, to the
    last digit, or when a message is in one log only. `largest` is the
    largest difference of any one numeric field, with where and when;
    `max_position_diff_m` the largest distance between the positions sent.
    """
    tally = _Tally()
    pending: tuple[dict, dict] = ({}, {})
    merged = heapq.merge(_messages(first, 0), _messages(second, 1), key=lambda m: m[0])
    for _, side, key, message in merged:
        other = pending[1 - side]
        if key in other:
            theirs = other.pop(key)
            a, b = (message, theirs) if side == 0 else (theirs, message)
            tally.pair(key, a, b)
        else:
            pending[side][key] = message
    only_first, only_second = len(pending[0]), len(pending[1])
    largest = None
    if tally.largest is not None:
        d, topic, field, t_s, a, b = tally.largest
        largest = {"topic": topic, "field": field, "t_s": t_s, "first": a, "second": b, "abs_diff": d}
    return {
        "differs": bool(tally.differing or only_first or only_second),
        "messages_compared": tally.compared,
        "messages_differing": tally.differing,
        "only_in_first": only_first,
        "only_in_second": only_second,
        "largest": largest,
        "first_non_numeric": tally.structural,
        "max_position_diff_m": tally.position_max,
        "position_diff_rms_m": (
            math.sqrt(tally.position_sq / tally.position_n) if tally.position_n else None
        ),
    }
