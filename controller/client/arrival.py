"""Following a motion to its end: when the robot has arrived, when it stopped short, how far it
still has to go.

`Arrival` is the rule, fed one pose sample at a time and free of I/O (so the threaded and the
asyncio clients drive the same rule); `follow_arrival` drives it from a source of samples with
its deadlines.

Arrival is a HOLDING pose within `ARRIVED_TOL_M` of the last point, once the motion has been
seen (a MOVING sample, or the robot no longer MOVING when the follow began: poses published
before the daemon took the command may stand HOLDING where a path also ends). A robot that
goes FAULT, ESTOPPED or DISARMED ends the follow (`Failed`); so does one that holds away from
the end with a set-point elsewhere (the motion was stopped, or replaced by another command):
the first HOLDING sample away from the end asks for the daemon's status once to tell that from
settling onto the end.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from controller.client.errors import Cancelled, DaemonAbsent, Failed, WaitTimeout
from controller.client.model import Pose, Status, Vec3, xyz_text

ARRIVED_TOL_M = 1e-3
"""How close to the end point a HOLDING pose counts as arrived (m)."""
STOPPED_STATES = frozenset({"FAULT", "ESTOPPED", "DISARMED"})
"""States in which a followed motion has ended without arriving."""
SAMPLE_POLL_S = 0.5
"""The longest a follow waits for one sample before it checks its deadlines again (s)."""


@dataclass(frozen=True, slots=True)
class ArrivalProgress:
    """How far a followed motion is: the distance still to travel along its points, the state
    and position of the newest sample, the time since the follow began, and that sample."""

    remaining_m: float
    state: str
    position_m: Vec3
    elapsed_s: float
    pose: Pose


def path_remaining_m(
    legs: Sequence[tuple[Sequence[float], Sequence[float]]], pos: Sequence[float], leg: int
) -> tuple[int, float]:
    """Distance (m) still to travel along `legs` from `pos`, and the leg it is on now.

    `leg` is the leg the effector was on before; it only moves forward (to the nearest of this
    leg and the next two), so a path that crosses itself is followed in order. The distance is
    from `pos` to the end of its leg plus the lengths of the legs after it.
    """
    best, best_d = leg, math.inf
    for k in range(leg, min(leg + 3, len(legs))):
        d = _point_segment_m(pos, legs[k][0], legs[k][1])
        if d < best_d - 1e-9:
            best, best_d = k, d
    rest = sum(math.dist(a, b) for a, b in legs[best + 1 :])
    return best, math.dist(pos, legs[best][1]) + rest


def _point_segment_m(p: Sequence[float], a: Sequence[float], b: Sequence[float]) -> float:
    ab = [b[i] - a[i] for i in range(3)]
    ap = [p[i] - a[i] for i in range(3)]
    den = sum(v * v for v in ab)
    t = 0.0 if den <= 0.0 else max(0.0, min(1.0, sum(ab[i] * ap[i] for i in range(3)) / den))
    return math.dist(p, [a[i] + t * ab[i] for i in range(3)])


class Arrival:
    """The arrival rule for a motion through `points` (its end is the last), fed pose samples.

    `update(pose)` returns True on arrival and raises Failed when the robot went FAULT,
    ESTOPPED or DISARMED; after it, `needs_status` says the daemon's status should be given to
    `check_status` (a hold away from the end: settling, or ended elsewhere).
    `remaining_m` is the distance still to travel (None before the first valid pose).
    `seen_moving` False: HOLDING samples count only after a MOVING one.
    """

    def __init__(self, points: Sequence[Sequence[float]], *, seen_moving: bool = True) -> None:
        if not points:
            raise ValueError("a motion to follow needs at least one point")
        self.points = [[float(v) for v in p] for p in points]
        self.end = self.points[-1]
        self.seen_moving = seen_moving
        self.needs_status = False
        self.last: Pose | None = None
        self.remaining_m: float | None = None
        self._asked = False
        self._legs: list[tuple[list[float], list[float]]] | None = None
        self._leg = 0

    def update(self, pose: Pose) -> bool:
        """Take one sample; True when the robot has arrived. Raises Failed when it went FAULT,
        ESTOPPED or DISARMED."""
        self.last = pose
        self.needs_status = False
        state = pose.state
        if state in STOPPED_STATES:
            raise Failed(f"the robot went {state} during the motion: {pose.text()}")
        pos = pose.position_m
        if pos is None:
            return False
        if state == "MOVING":
            self.seen_moving = True
            self._asked = False
        if state == "HOLDING" and self.seen_moving and math.dist(pos, self.end) <= ARRIVED_TOL_M:
            self.remaining_m = 0.0
            return True
        if state == "HOLDING" and self.seen_moving and not self._asked:
            self._asked = True
            self.needs_status = True
        if self._legs is None:
            starts = [list(pos), *self.points[:-1]]
            self._legs = list(zip(starts, self.points, strict=True))
        self._leg, self.remaining_m = path_remaining_m(self._legs, pos, self._leg)
        return False

    def check_status(self, st: Status) -> None:
        """Raise Failed when the status `st` holds a set-point away from the end: the motion
        ended there (stopped, or replaced by another command), not at its end."""
        self.needs_status = False
        if st.state != "HOLDING" or st.setpoint_m is None:
            return
        if math.dist(st.setpoint_m, self.end) <= ARRIVED_TOL_M:
            return  # settling on the end point
        why = st.reason or "another command took over"
        last = self.last
        pos = st.setpoint_m if last is None or last.position_m is None else last.position_m
        where = "" if last is None else f"; {last.text()}"
        raise Failed(
            f"the motion ended {math.dist(pos, self.end):.3f} m short of {xyz_text(self.end)}:"
            f" {why}{where}"
        )

    def timeout_error(self, wait_timeout_s: float) -> WaitTimeout:
        """The error of a follow that ran out of time (the robot goes on)."""
        where = "" if self.last is None else f"; last {self.last.text()}"
        return WaitTimeout(
            f"not at the target after {wait_timeout_s:g} s{where}; the robot goes on"
            " with the motion (`cablebot stop` stops it)"
        )


def follow_arrival(
    next_pose: Callable[[float], Pose | None],
    arrival: Arrival,
    *,
    wait_timeout_s: float,
    sample_timeout_s: float,
    status: Callable[[], Status] | None = None,
    on_progress: Callable[[ArrivalProgress], None] | None = None,
    cancelled: Callable[[], bool] | None = None,
    clock: Callable[[], float] = time.monotonic,
) -> Pose:
    """Feed `arrival` the samples `next_pose(timeout_s)` gives (None: none within timeout_s)
    until the robot arrives; returns the arrival sample. `on_progress` gets every sample that
    is not the arrival; `status()` is asked when the rule needs it.

    Raises WaitTimeout after `wait_timeout_s`, DaemonAbsent when no sample came for
    `sample_timeout_s`, Failed when the robot stopped or the motion ended short of its end,
    Cancelled when `cancelled()` says so (asked at least every `SAMPLE_POLL_S`).
    """
    t0 = clock()
    deadline = t0 + wait_timeout_s
    last_rx = t0
    while True:
        if cancelled is not None and cancelled():
            raise Cancelled("the wait was cancelled")
        now = clock()
        if now >= deadline:
            raise arrival.timeout_error(wait_timeout_s)
        pose = next_pose(min(SAMPLE_POLL_S, deadline - now))
        if pose is None:
            if clock() - last_rx > sample_timeout_s:
                raise DaemonAbsent(f"no pose sample for {sample_timeout_s:g} s")
            continue
        last_rx = clock()
        if arrival.update(pose):
            return pose
        if arrival.needs_status and status is not None:
            arrival.check_status(status())
        if on_progress is not None and arrival.remaining_m is not None:
            assert pose.position_m is not None
            elapsed_s = last_rx - t0
            pos = pose.position_m
            on_progress(ArrivalProgress(arrival.remaining_m, pose.state, pos, elapsed_s, pose))
