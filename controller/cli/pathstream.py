"""Streaming a path file of any length: the first points as a `path` command, the rest as
chunks with `"append": true`, sent whenever the daemon's queue holds less than a few seconds
of motion (`cablebot path FILE`; the Zenoh calls are handed in, so this runs without them).

One chunk is at most `MAX_PATH_POINTS_SENT` points (what one command carries). The queue's
depth comes from each reply's `queued_s` and, between sends, from `status`'s `path` section
polled every `POLL_S`. A refusal because the queue is full (`QUEUE_FULL`: the daemon's
`[limits] max_queued_points`) is waited out and the chunk sent again; any other refusal (the
path was stopped or replaced, a point outside the limits, the robot left HOLDING/MOVING) ends
the stream with it.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from controller.core.commands import MAX_PATH_POINTS_SENT
from controller.core.motion import QUEUE_FULL

LOW_WATER_S = 3.0
"""Send the next chunk while the daemon's queue holds less than this much motion (s)."""
POLL_S = 0.1
"""How often the queue's depth is asked for (`status`) while it is deep enough."""
MOTION_STATES = frozenset({"HOLDING", "MOVING"})


class StreamRefused(Exception):
    """The daemon refused a chunk (not for a full queue) or left the motion states: the
    stream ends (the message says why and how far it got)."""


@dataclass
class StreamProgress:
    """How far a stream is: points sent of the total, the queue after the last reply or
    status, commands sent, chunks refused for a full queue and sent again."""

    total: int
    sent: int = 0
    commands: int = 0
    retries: int = 0
    queued_points: int = 0
    queued_s: float = 0.0
    queue_full: bool = False

    def text(self, elapsed_s: float) -> str:
        """The progress line: points sent/total, queued, elapsed."""
        return (
            f"path: {self.sent}/{self.total} points sent  queued {self.queued_points} "
            f"({self.queued_s:.1f} s)  {elapsed_s:.1f} s"
        )

    def take(self, path: Any) -> None:
        """Take the queue fields of a reply or of status's `path` section (others ignored)."""
        if not isinstance(path, dict):
            return
        q = path.get("queued_points")
        if isinstance(q, int):
            self.queued_points = q
        s = path.get("queued_s")
        if isinstance(s, int | float):
            self.queued_s = float(s)
        self.queue_full = path.get("queue_full") is True


Send = Callable[[list[list[float]], bool], dict[str, Any]]
"""`send(points, append)`: the `path` command's reply; raises the client's Refused."""


def stream_points(
    points: Sequence[list[float]],
    send: Send,
    status: Callable[[], dict[str, Any]],
    show: Callable[[str, float], None],
    *,
    refused: type[Exception],
    low_water_s: float = LOW_WATER_S,
    chunk: int = MAX_PATH_POINTS_SENT,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    before_last: Callable[[], None] | None = None,
) -> StreamProgress:
    """Send `points` as a path and then appended chunks of at most `chunk` points, each when
    less than `low_water_s` of motion is queued; `show(text, now)` gets the progress line.

    `refused` is the exception `send` raises for a refusal; one for a full queue is waited
    out (polling `status`) and the chunk sent again. `before_last` runs just before the last
    chunk is sent. Returns the final progress. Raises StreamRefused for any other refusal
    (with how far it got) or when the robot leaves HOLDING/MOVING; lets `status`'s and
    `send`'s other errors (the daemon absent) through.
    """
    n = len(points)
    prog = StreamProgress(total=n)
    t0 = clock()
    while prog.sent < n:
        if prog.sent > 0 and (prog.queue_full or prog.queued_s >= low_water_s):
            sleep(POLL_S)
            st = status()
            state = st.get("state")
            if state not in MOTION_STATES:
                raise StreamRefused(
                    f"the robot is {state} ({st.get('reason')}): stopped after "
                    f"{prog.sent}/{n} points"
                )
            prog.take(st.get("path"))
            show(prog.text(clock() - t0), clock())
            continue
        part = [list(p) for p in points[prog.sent : prog.sent + chunk]]
        if prog.sent + len(part) >= n and before_last is not None:
            before_last()
        try:
            reply = send(part, prog.sent > 0)
        except refused as exc:
            if QUEUE_FULL in str(exc):
                prog.retries += 1
                prog.queue_full = True
                continue
            raise StreamRefused(f"{exc} (after {prog.sent}/{n} points)") from None
        prog.sent += len(part)
        prog.commands += 1
        prog.take(reply)
        show(prog.text(clock() - t0), clock())
    return prog
