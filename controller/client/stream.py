"""Streaming motion to the daemon in chunks, paced by its queue: one rule for every client
that streams (a path of any length, a G-code job, the serial line protocol). The Zenoh calls
are handed in, so this runs without them.

`Pacer` decides when the next chunk goes: the first points go as a `path` command, the rest as
chunks with `"append": true`, each sent while the daemon's queue holds less than
`LOW_WATER_S` of motion. The queue's depth comes from each reply's `queued_s` and, between
sends, from `status`'s `path` section, polled when the queue should have drained to the mark
(every `POLL_S` to `MAX_POLL_S`). A refusal because the queue is full (`QUEUE_FULL`: the
daemon's `[limits] max_queued_points`) is waited out and the chunk sent again; any other refusal
(the path was stopped or replaced, a point outside the limits) is the caller's to report, and so
is the robot leaving HOLDING/MOVING (`RobotLeft`).

`iter_points` streams a list of points with it, at most `MAX_PATH_POINTS_SENT` points a chunk
(what one command carries), yielding its progress after every send and every status poll;
`stream_points` is the same with a progress callback.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

from controller.core.commands import MAX_PATH_POINTS_SENT
from controller.core.motion import QUEUE_FULL

LOW_WATER_S = 3.0
"""Send the next chunk while the daemon's queue holds less than this much motion (s)."""
POLL_S = 0.1
"""The shortest wait between two status polls while the queue is deep enough (s)."""
MAX_POLL_S = 0.5
"""The longest wait between two status polls (s): how stale the progress and the robot's state
may get while a deep queue drains to the low-water mark."""
MOTION_STATES = frozenset({"HOLDING", "MOVING"})
"""The states in which a stream goes on (HOLDING: the path ran dry; an append continues it)."""

R = TypeVar("R")


class StreamRefused(Exception):
    """The daemon refused a chunk (not for a full queue) or left the motion states: the
    stream ends (the message says why and how far it got)."""


class RobotLeft(StreamRefused):
    """The robot left HOLDING/MOVING while a stream waited for room; `status` is the status
    that said so."""

    def __init__(self, status: dict[str, Any]) -> None:
        super().__init__(f"the robot is {status.get('state')} ({status.get('reason')})")
        self.status = status


@dataclass
class StreamProgress:
    """How far a stream is: points sent of the total, the queue after the last reply or
    status, commands sent, chunks refused for a full queue and sent again, and the seconds
    since the stream began (`elapsed_s`, set as it is yielded)."""

    total: int
    sent: int = 0
    commands: int = 0
    retries: int = 0
    queued_points: int = 0
    queued_s: float = 0.0
    queue_full: bool = False
    elapsed_s: float = 0.0

    def text(self, elapsed_s: float) -> str:
        """The progress line: points sent/total, queued, elapsed."""
        return (
            f"path: {self.sent}/{self.total} points sent  queued {self.queued_points} "
            f"({self.queued_s:.1f} s)  {elapsed_s:.1f} s"
        )

    def take(self, path: Any) -> None:
        """Take the queue fields of a reply or of status's `path` section; without one (not a
        dict) the queue's depth is unknown and taken as empty (the next send finds out)."""
        if not isinstance(path, dict):
            self.queued_points, self.queued_s, self.queue_full = 0, 0.0, False
            return
        q = path.get("queued_points")
        if isinstance(q, int):
            self.queued_points = q
        s = path.get("queued_s")
        if isinstance(s, int | float):
            self.queued_s = float(s)
        self.queue_full = path.get("queue_full") is True

    def snapshot(self) -> StreamProgress:
        """A copy that later progress does not change."""
        return dataclasses.replace(self)


def finish(steps: Generator[Any, None, R]) -> R:
    """Run a generator of steps (`Pacer.steps`, `iter_points`) to its end; returns its value."""
    while True:
        try:
            next(steps)
        except StopIteration as stop:
            result: R = stop.value
            return result


class Pacer:
    """When the next chunk of a stream goes to the daemon, and how a full queue is waited out.

    `status()` returns the daemon's status; `refused` is the exception a send raises for a
    refusal; `on_poll()` runs after every status poll (a progress line, a keep-alive).
    `progress` holds the queue's depth as last seen and the count of full-queue retries.
    """

    def __init__(
        self,
        status: Callable[[], dict[str, Any]],
        *,
        refused: type[Exception],
        low_water_s: float = LOW_WATER_S,
        sleep: Callable[[float], None] = time.sleep,
        on_poll: Callable[[], None] = lambda: None,
        progress: StreamProgress | None = None,
    ) -> None:
        self.status = status
        self.refused = refused
        self.low_water_s = low_water_s
        self.sleep = sleep
        self.on_poll = on_poll
        self.progress = StreamProgress(total=0) if progress is None else progress

    def must_wait(self) -> bool:
        """True while the queue is full or holds `low_water_s` of motion or more."""
        p = self.progress
        return p.queue_full or p.queued_s >= self.low_water_s

    def poll(self) -> dict[str, Any]:
        """Sleep until the queue should have drained to the low-water mark (from `POLL_S` to
        `MAX_POLL_S`), then read the daemon's status and take its queue's depth; returns the
        status. Raises RobotLeft when the robot is not HOLDING or MOVING; lets `status`'s
        errors (the daemon absent) through."""
        # queued_s is a lower bound on the time the queue takes to fly: never a late wake-up.
        self.sleep(min(MAX_POLL_S, max(POLL_S, self.progress.queued_s - self.low_water_s)))
        st = self.status()
        if st.get("state") not in MOTION_STATES:
            raise RobotLeft(st)
        self.progress.take(st.get("path"))
        self.on_poll()
        return st

    def steps(self, attempt: Callable[[], R], append: bool) -> Generator[None, None, R]:
        """Send one chunk with `attempt()` (it returns the daemon's reply), yielding after
        every status poll while it waits. An append waits first until less than
        `low_water_s` of motion is queued, and is sent again after a full-queue refusal once
        the queue has room; a new path (`append` false) replaces the queue and goes at once.
        Returns the reply (its queue fields taken).

        Raises RobotLeft when the robot leaves HOLDING/MOVING while the chunk waits; lets
        `attempt`'s other refusals and errors through.
        """
        while True:
            if append:
                while self.must_wait():
                    self.poll()
                    yield
            try:
                reply = attempt()
            except self.refused as exc:
                if not append or QUEUE_FULL not in str(exc):
                    raise
                self.progress.retries += 1
                self.progress.queue_full = True
                continue
            self.progress.take(reply)
            return reply

    def send(self, attempt: Callable[[], R], append: bool) -> R:
        """`steps` run to its end: send one chunk, waiting as it says. Raises as `steps`."""
        return finish(self.steps(attempt, append))


Send = Callable[[list[list[float]], bool], dict[str, Any]]
"""`send(points, append)`: the `path` command's reply; raises the client's Refused."""


def iter_points(
    points: Sequence[Sequence[float]],
    send: Send,
    status: Callable[[], dict[str, Any]],
    *,
    refused: type[Exception],
    low_water_s: float = LOW_WATER_S,
    chunk: int = MAX_PATH_POINTS_SENT,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    before_last: Callable[[], None] | None = None,
    append_first: bool = False,
) -> Generator[StreamProgress, None, StreamProgress]:
    """Send `points` as a path and then appended chunks of at most `chunk` points, paced by a
    `Pacer` (each append when less than `low_water_s` of motion is queued); yields the progress
    (the same object, `elapsed_s` updated) after every reply and every status poll, and
    returns it at the end.

    `refused` is the exception `send` raises for a refusal; one for a full queue is waited
    out (polling `status`) and the chunk sent again. `before_last` runs just before the last
    chunk is sent. With `append_first` the first chunk too is an append (`send` makes it one:
    a file's `"append": true`), its full-queue refusals waited out as the others'. Raises
    StreamRefused for any other refusal (with how far it got) or when the robot leaves
    HOLDING/MOVING; lets `status`'s and `send`'s other errors (the daemon absent) through.
    """
    n = len(points)
    prog = StreamProgress(total=n)
    t0 = clock()
    pacer = Pacer(status, refused=refused, low_water_s=low_water_s, sleep=sleep, progress=prog)
    while prog.sent < n:
        part = [list(p) for p in points[prog.sent : prog.sent + chunk]]
        more = prog.sent > 0
        before = before_last if prog.sent + len(part) >= n else None
        try:
            steps = pacer.steps(_attempt(send, part, more, before), more or append_first)
            while True:
                try:
                    next(steps)
                except StopIteration:
                    break
                prog.elapsed_s = clock() - t0
                yield prog
        except RobotLeft as exc:
            raise StreamRefused(f"{exc}: stopped after {prog.sent}/{n} points") from None
        except refused as exc:
            raise StreamRefused(f"{exc} (after {prog.sent}/{n} points)") from None
        prog.sent += len(part)
        prog.commands += 1
        prog.elapsed_s = clock() - t0
        yield prog
    return prog


def stream_points(
    points: Sequence[Sequence[float]],
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
    append_first: bool = False,
) -> StreamProgress:
    """`iter_points` with `show(text, now)` getting the progress line (`StreamProgress.text`)
    after every reply and status poll; returns the final progress. Raises as `iter_points`."""
    t0 = clock()
    steps = iter_points(
        points,
        send,
        status,
        refused=refused,
        low_water_s=low_water_s,
        chunk=chunk,
        clock=clock,
        sleep=sleep,
        before_last=before_last,
        append_first=append_first,
    )
    while True:
        try:
            prog = next(steps)
        except StopIteration as stop:
            final: StreamProgress = stop.value
            return final
        now = clock()
        show(prog.text(now - t0), now)


def _attempt(
    send: Send, part: list[list[float]], more: bool, before: Callable[[], None] | None
) -> Callable[[], dict[str, Any]]:
    def attempt() -> dict[str, Any]:
        if before is not None:
            before()
        return send(part, more)

    return attempt
