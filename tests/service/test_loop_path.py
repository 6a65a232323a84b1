"""Continuous paths through the control loop (fake clock, fake driver that follows, built-in
robot and the desk rig): the circle's time and speed, the corner speeds, appends, a queue that
runs dry, stop and e-stop at a deep queue, and the replies', status's and pose's queue fields.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path as FilePath
from typing import Any

import pytest

from controller.core.commands import CommandRefused, Estop, Move, Path, Stop
from controller.core.motion import (
    CORNER_ACCEL_FRACTION,
    DEFAULT_JUNCTION_DEVIATION_M,
    Vec3,
    junction_speed_mps,
)
from controller.core.states import State
from controller.service.config import load_config
from controller.service.pose import PoseSample
from tests.fakes import make_config
from tests.service.test_loop import DT, RATE_HZ, Rig

ROOT = FilePath(__file__).resolve().parents[2]
ACCEL_MPS2 = 1.0
REL = 1e-6  # rounding on the limits


class Track:
    """Runs a rig tick by tick, recording the set-point, its speed and the planner's state."""

    def __init__(self, rig: Rig) -> None:
        self.rig = rig
        self.points: list[Vec3] = []
        self.speeds: list[float] = []
        self.velocities: list[Vec3] = []
        self.states: list[State] = []

    def tick(self, n: int = 1) -> None:
        for _ in range(n):
            self.rig.tick()
            pl = self.rig.ctl.planner
            self.points.append(pl.position_m)
            v = pl.velocity_mps
            self.velocities.append(v)
            self.speeds.append(math.hypot(*v))
            self.states.append(self.rig.ctl.state)

    def do(self, cmd: Any) -> dict[str, Any]:
        """Submit `cmd`, tick once (recorded) and return its reply."""
        fut = self.rig.ctl.submit(cmd)
        self.tick()
        reply: dict[str, Any] = fut.result(timeout=0)
        return reply

    def refused(self, cmd: Any) -> str:
        """Submit `cmd`, tick once and return its refusal."""
        fut = self.rig.ctl.submit(cmd)
        self.tick()
        exc = fut.exception(timeout=0)
        assert isinstance(exc, CommandRefused), exc
        return str(exc)

    def until_holding(self, max_ticks: int) -> int:
        """Ticks until the controller is HOLDING again (after MOVING)."""
        for i in range(max_ticks):
            self.tick()
            if self.rig.ctl.state is State.HOLDING:
                return i + 1
        raise AssertionError(f"still {self.rig.ctl.state} after {max_ticks} ticks")

    def max_accel_mps2(self) -> float:
        v = self.velocities
        return max(math.dist(v[k], v[k - 1]) / DT for k in range(1, len(v)))


def _rig(cfg: Any = None, **limits: Any) -> Rig:
    base = cfg if cfg is not None else make_config(loop={"rate_hz": RATE_HZ})
    if limits:
        base = replace(base, limits=replace(base.limits, **limits))
    rig = Rig(base)
    rig.arm()
    rig.tick(5)
    return rig


def _circle(centre: Vec3, radius_m: float, n: int, start_angle: float = math.pi) -> list[Vec3]:
    """`n` points on a horizontal circle from `start_angle`, the last one closing it."""
    return [
        (
            centre[0] + radius_m * math.cos(start_angle + 2.0 * math.pi * k / (n - 1)),
            centre[1] + radius_m * math.sin(start_angle + 2.0 * math.pi * k / (n - 1)),
            centre[2],
        )
        for k in range(n)
    ]


def _fly_circle(rig: Rig, radius_m: float, speed_mps: float) -> tuple[Track, float, int]:
    """Fly the 1,000-point circle through the rig's start point; (track, length, ticks)."""
    s = rig.start
    centre = (s[0] + radius_m, s[1], s[2])
    pts = _circle(centre, radius_m, 1000)
    length = sum(math.dist(pts[k - 1], pts[k]) for k in range(1, len(pts)))
    tr = Track(rig)
    reply = tr.do(Path(tuple(pts), speed_mps))
    assert reply["ok"] and reply["queued_points"] > 0
    ticks = tr.until_holding(int(3 * length / speed_mps * RATE_HZ))
    assert math.dist(rig.ctl.setpoint_m or (math.inf,) * 3, pts[-1]) < 1e-9
    return tr, length, ticks


def _assert_circle(tr: Track, length: float, ticks: int, speed_mps: float) -> float:
    """The circle's figures: time within 1.10x of length / speed, speed >= 90 % of the
    requested along the middle 80 %, acceleration within the limit. Returns the time ratio."""
    ideal_s = length / speed_mps
    ratio = ticks * DT / ideal_s
    assert ratio <= 1.10, (ratio, ticks * DT, ideal_s)
    n = len(tr.speeds)
    middle = tr.speeds[n // 10 : n - n // 10]
    assert min(middle) >= 0.9 * speed_mps, min(middle)
    assert max(tr.speeds) <= speed_mps * (1 + REL)
    assert tr.max_accel_mps2() <= ACCEL_MPS2 * (1 + 1e-3) + 1e-9
    return ratio


def test_circle_of_1000_points_flies_at_its_speed_on_the_built_in_robot() -> None:
    rig = _rig(max_accel_mps2=ACCEL_MPS2)
    tr, length, ticks = _fly_circle(rig, 0.2, 0.1)
    _assert_circle(tr, length, ticks, 0.1)
    # it never stops on the way: no tick at rest between the start and the end
    moving = tr.speeds[: ticks - 1]
    assert all(v > 0.0 for v in moving[1:]), moving.index(0.0, 1)
    assert rig.ctl.status()["path"]["blends_dropped"] == 0


def test_circle_on_the_desk_rig() -> None:
    cfg = load_config(str(ROOT / "config" / "desk.toml"))
    cfg = replace(
        cfg,
        loop=replace(cfg.loop, rate_hz=RATE_HZ),
        homing=replace(cfg.homing, power_up_position_m=(-0.1, 0.0, 0.3)),
    )
    rig = _rig(cfg)
    # the desk's workspace is 0.9 m wide: a circle of radius 0.1 m, 1,000 points
    tr, length, ticks = _fly_circle(rig, 0.1, 0.1)
    _assert_circle(tr, length, ticks, 0.1)


@pytest.mark.parametrize("delta_m", [DEFAULT_JUNCTION_DEVIATION_M, 0.03])
def test_square_corners_are_flown_at_the_junction_deviation_speed(delta_m: float) -> None:
    rig = _rig(max_accel_mps2=ACCEL_MPS2, junction_deviation_m=delta_m)
    s = rig.start
    side = 0.6
    corners = [
        (s[0] + side, s[1], s[2]),
        (s[0] + side, s[1] + side, s[2]),
        (s[0], s[1] + side, s[2]),
    ]
    pts = (*corners, s)
    tr = Track(rig)
    tr.do(Path(pts, 0.5))
    tr.until_holding(int(20 * RATE_HZ))
    want = junction_speed_mps(math.pi / 2, delta_m, ACCEL_MPS2)
    flown = []
    for c in corners:
        near = [v for p, v in zip(tr.points, tr.speeds, strict=True) if math.dist(p, c) < 0.05]
        flown.append(min(near))
    for v in flown:
        assert v == pytest.approx(want, rel=0.05), (flown, want)
        # the planner holds back 5 % of the centripetal acceleration (sqrt(0.95) = 97.5 %)
        assert v == pytest.approx(want * math.sqrt(CORNER_ACCEL_FRACTION), rel=1e-3)
    assert tr.max_accel_mps2() <= ACCEL_MPS2 * (1 + 1e-3) + 1e-9


def test_a_dry_queue_rests_at_its_last_point_and_continues_on_append() -> None:
    rig = _rig()
    s = rig.start
    first = ((s[0] + 0.2, s[1], s[2]), (s[0] + 0.2, s[1] + 0.2, s[2]))
    tr = Track(rig)
    reply = tr.do(Path(first, 0.5))
    assert reply["queued_points"] == 2 and reply["append"] is False
    assert reply["queued_s"] > 0.0 and reply["queue_full"] is False
    tr.until_holding(int(10 * RATE_HZ))
    assert rig.ctl.setpoint_m == first[-1]  # exactly at its last point: no overshoot
    assert rig.ctl.status()["path"]["appendable"] is True
    more = ((s[0], s[1] + 0.2, s[2]),)
    reply = tr.do(Path(more, 0.5, append=True))
    assert reply["ok"] and reply["append"] is True and reply["queued_points"] == 1
    assert rig.ctl.state is State.MOVING  # HOLDING after the dry queue goes back to MOVING
    tr.until_holding(int(10 * RATE_HZ))
    assert rig.ctl.setpoint_m == more[-1]


def test_appends_join_the_path_without_braking_and_the_pose_carries_the_queue() -> None:
    rig = _rig(max_accel_mps2=ACCEL_MPS2)
    s = rig.start
    pts = [(s[0] + 0.001 * k, s[1], s[2]) for k in range(1, 1001)]
    tr = Track(rig)
    tr.do(Path(tuple(pts[:500]), 0.2))
    tr.tick(int(0.5 * RATE_HZ))
    reply = tr.do(Path(tuple(pts[500:]), 0.2, append=True))
    assert reply["queued_points"] > 500
    published = rig.pub.poses[-1]
    assert isinstance(published, PoseSample) and published.queued_points > 0
    status = rig.ctl.status()["path"]
    assert status["queued_points"] == rig.ctl.planner.queued_points > 0
    tr.until_holding(int(20 * RATE_HZ))
    assert rig.ctl.setpoint_m == pts[-1]
    # one acceleration and one deceleration: the speed never dips where the append joined
    k_max = tr.speeds.index(max(tr.speeds))
    end = len(tr.speeds) - 1
    cruise = tr.speeds[int(0.3 * RATE_HZ) : end - int(0.3 * RATE_HZ)]
    assert min(cruise) == pytest.approx(0.2, rel=1e-6), k_max
    last = rig.pub.poses[-1]
    assert isinstance(last, PoseSample) and last.queued_points == 0


def test_append_refusals_say_why() -> None:
    rig = _rig(max_queued_points=1000)
    s = rig.start
    far = ((s[0] + 0.5, s[1], s[2]),)
    # no path in progress: an append never starts motion on its own
    why = rig.refused(Path(far, 0.2, append=True))
    assert "no path in progress" in why
    assert rig.ctl.state is State.HOLDING
    pts = tuple((s[0] + 0.0005 * k, s[1], s[2]) for k in range(1, 1001))
    reply = rig.do(Path(pts, 0.1))
    assert reply["queue_full"] is True and reply["queued_points"] == 1000
    why = rig.refused(Path(far, 0.2, append=True))
    assert "queue full" in why and "queued; retry" in why, why
    # the leg from the last queued point is checked like any path's
    outside = ((s[0] + 500.0, s[1], s[2]),)
    why = rig.refused(Path(outside, 0.2, append=True))
    assert "points_m[0]" in why
    # after a stop the path takes no appends
    rig.do(Stop())
    why = rig.refused(Path(far, 0.2, append=True))
    assert "no path in progress" in why


def test_stop_and_estop_at_a_deep_queue() -> None:
    rig = _rig(max_accel_mps2=ACCEL_MPS2)
    s = rig.start
    n = 20_000

    def spiral(k: int) -> Vec3:
        ang = 0.01 * k
        r = 0.1 + 1e-5 * k
        return (s[0] + r * math.cos(ang) - 0.1, s[1] + r * math.sin(ang), s[2])

    pts = [spiral(k) for k in range(n)]
    tr = Track(rig)
    tr.do(Path(tuple(pts[:1000]), 0.3))
    for k in range(1000, n, 1000):
        tr.do(Path(tuple(pts[k : k + 1000]), 0.3, append=True))
    assert rig.ctl.planner.queued_points > n - 100
    tr.tick(int(2.0 * RATE_HZ))
    assert rig.ctl.state is State.MOVING
    brake_s = rig.ctl.brake_time_s()
    assert brake_s > 0.0
    tr.do(Stop())
    ticks = tr.until_holding(int(10 * RATE_HZ))
    assert ticks * DT <= brake_s * 1.05 + 2 * DT, (ticks * DT, brake_s)
    assert rig.ctl.planner.queued_points == 0
    assert tr.max_accel_mps2() <= ACCEL_MPS2 * (1 + 1e-3) + 1e-9
    # e-stop at a deep queue
    tr.do(Path(tuple(pts[:1000]), 0.3))
    for k in range(1000, 10_000, 1000):
        tr.do(Path(tuple(pts[k : k + 1000]), 0.3, append=True))
    tr.tick(int(1.0 * RATE_HZ))
    rig.ctl.submit(Estop())
    rig.tick(2)
    assert rig.ctl.state is State.ESTOPPED


def test_brake_time_is_the_planners_and_a_move_replies_as_before() -> None:
    rig = _rig()
    s = rig.start
    reply = rig.do(Move((s[0] + 1.0, s[1], s[2]), 0.5))
    assert "queued_points" not in reply and reply["target_m"] == [s[0] + 1.0, s[1], s[2]]
    rig.tick(int(0.5 * RATE_HZ))
    assert rig.ctl.brake_time_s() == rig.ctl.planner.brake_time_s > 0.0
