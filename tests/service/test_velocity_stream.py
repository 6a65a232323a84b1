"""Velocity input in the control loop (fake driver and clock) and on the Zenoh key.

The loop: samples fly the robot under the speed and acceleration limits, the dead-man brakes
to a hold, samples sent while not armed (or in an earlier armed session) are discarded and
counted, the workspace boundary is never crossed, moves and velocity input hand over. The Zenoh
key: only the exact `<prefix>/velocity` key is taken; wildcard puts, oversized, deep and
non-finite payloads are refused and counted.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Iterator, Sequence
from typing import Any

import pytest
import zenoh

from controller.core.commands import MAX_PAYLOAD_BYTES, Disarm, Estop, Move, Reset, Velocity
from controller.core.states import State
from controller.service import zenoh_io
from controller.service.config import ConfigError, paper_robot_data, parse_config
from controller.service.zenoh_io import free_tcp_port
from tests.fakes import make_config
from tests.fakes_zenoh import FakeController, ZCfg
from tests.service.test_loop import DT, RATE_HZ, Rig, _armed_rig, _dist

SAMPLE_TICKS = int(RATE_HZ / 20)  # a joystick at 20 Hz


def _fly(rig: Rig, v: Sequence[float], seconds: float) -> None:
    """Send `v` at 20 Hz for `seconds` (ticking in between)."""
    for _ in range(int(seconds * 20)):
        rig.ctl.submit_velocity(v)
        rig.tick(SAMPLE_TICKS)


def _speeds(points: list[tuple[float, float, float]]) -> list[float]:
    return [_dist(a, b) / DT for a, b in itertools.pairwise(points)]


# ------------------------------------------------------------------------ the loop


def test_velocity_samples_fly_the_robot_and_the_deadman_brakes_to_a_hold() -> None:
    rig = _armed_rig()
    lim = rig.cfg.limits
    names = len(rig.pub.states)
    rig.setpoints.clear()
    _fly(rig, (0.5, 0.0, 0.0), 2.0)
    assert rig.state() is State.MOVING and rig.ctl.reason == "velocity"
    assert rig.pub.state_names()[names:] == ["MOVING"]
    assert rig.ctl.planner.velocity_mps == pytest.approx((0.5, 0.0, 0.0))
    assert rig.ctl.status()["velocity"]["command_mps"] == [0.5, 0.0, 0.0]
    # The client goes quiet: on for the timeout, then braking at max accel to a hold.
    rig.setpoints.clear()
    x0 = rig.ctl.setpoint_m[0]  # type: ignore[index]
    ticks = rig.until(lambda: rig.ctl.state is State.HOLDING, 10_000)
    left_s = lim.velocity_timeout_s - SAMPLE_TICKS * DT  # the last sample was a period ago
    expected_s = left_s + 0.5 / lim.max_accel_mps2
    assert expected_s - 3 * DT <= ticks * DT <= expected_s + 3 * DT
    travelled = rig.ctl.setpoint_m[0] - x0  # type: ignore[index]
    expected = 0.5 * left_s + 0.5**2 / (2 * lim.max_accel_mps2)
    assert travelled == pytest.approx(expected, abs=0.01)
    speeds = _speeds(rig.setpoints)
    assert max(speeds) <= 0.5 * (1 + 1e-6)
    assert all(b <= a + 1e-9 for a, b in itertools.pairwise(speeds))  # never speeds up again
    status = rig.ctl.status()["velocity"]
    assert status["deadman_stops"] == 1 and status["command_mps"] == [0.0, 0.0, 0.0]
    # Held still afterwards, with no feed-forward
    hold = rig.ctl.setpoint_m
    rig.tick(100)
    assert rig.ctl.setpoint_m == hold and rig.driver.ffs[-1] == (0.0,) * 4


def test_the_configured_deadman_timeout_is_used() -> None:
    rig = Rig(make_config(loop={"rate_hz": RATE_HZ}, limits={"velocity_timeout_s": 0.05}))
    rig.arm()
    _fly(rig, (0.0, 0.4, 0.0), 1.0)
    ticks = rig.until(lambda: rig.ctl.state is State.HOLDING, 10_000)
    assert ticks * DT <= 0.05 + 0.4 / rig.cfg.limits.max_accel_mps2 + 3 * DT


def test_speed_and_acceleration_stay_within_the_limits() -> None:
    rig = _armed_rig()
    lim = rig.cfg.limits
    rig.setpoints.clear()
    # Full stick one way, then the other: 50 m/s asked, the robot's maximum given.
    _fly(rig, (50.0, 0.0, 0.0), 3.0)
    _fly(rig, (-50.0, 20.0, 0.0), 4.0)
    pts = rig.setpoints
    vel = [tuple((b[i] - a[i]) / DT for i in range(3)) for a, b in itertools.pairwise(pts)]
    assert max(math.hypot(*v) for v in vel) <= lim.max_speed_mps * (1 + 1e-6)
    assert max(math.hypot(*v) for v in vel) >= 0.99 * lim.max_speed_mps  # it did reach it
    acc = [math.dist(a, b) / DT for a, b in itertools.pairwise(vel)]
    assert max(acc) <= lim.max_accel_mps2 * (1 + 1e-6)
    assert rig.state() is State.MOVING


def test_a_zero_sample_brakes_to_a_hold() -> None:
    rig = _armed_rig()
    _fly(rig, (0.0, -0.6, 0.0), 1.0)
    rig.ctl.submit_velocity((0.0, 0.0, 0.0))
    ticks = rig.until(lambda: rig.ctl.state is State.HOLDING, 10_000)
    assert ticks * DT <= 0.6 / rig.cfg.limits.max_accel_mps2 + 3 * DT
    assert rig.ctl.status()["velocity"]["deadman_stops"] == 0
    # A centred stick keeps streaming zeros: the robot stays HOLDING, no state flicker.
    names = len(rig.pub.states)
    _fly(rig, (0.0, 0.0, 0.0), 1.0)
    assert rig.state() is State.HOLDING and rig.pub.state_names()[names:] == []


def test_velocity_samples_before_arm_are_discarded_and_counted() -> None:
    rig = Rig()
    rig.tick(2)
    assert rig.state() is State.DISARMED
    rig.ctl.submit_velocity((1.0, 0.0, 0.0))
    fut = rig.ctl.submit(Velocity((1.0, 0.0, 0.0)))
    exc = fut.exception(timeout=0)
    assert exc is not None and "not allowed in DISARMED" in str(exc)
    assert rig.ctl.status()["velocity"]["discarded"] == 2
    # While ARMING too
    rig.ctl.submit(__import__("controller.core.commands", fromlist=["Arm"]).Arm())
    rig.tick()
    assert rig.state() is State.ARMING
    rig.ctl.submit_velocity((1.0, 0.0, 0.0))
    rig.until(lambda: rig.ctl.state is State.HOLDING, 100)
    rig.tick(int(RATE_HZ))
    assert rig.state() is State.HOLDING and "MOVING" not in rig.pub.state_names()
    assert _dist(rig.ctl.setpoint_m, rig.start) < 1e-9
    assert rig.ctl.status()["velocity"]["discarded"] == 3


@pytest.mark.parametrize("how", ["fault", "estop", "disarm"])
def test_a_sample_sent_while_not_armed_never_moves_the_robot_after_arm(how: str) -> None:
    rig = _armed_rig()
    if how == "fault":
        rig.driver.axis_error[rig.ctl.node_ids[0]] = 0x800
        rig.tick()
        rig.driver.axis_error.clear()
    elif how == "estop":
        rig.ctl.submit(Estop())
        rig.tick()
    else:
        rig.do(Disarm())
    assert rig.state() in (State.FAULT, State.ESTOPPED, State.DISARMED)
    rig.ctl.submit_velocity((1.0, 0.0, 0.0))
    if rig.state() is not State.DISARMED:
        rig.do(Reset())
    rig.ctl.submit_velocity((1.0, 0.0, 0.0))
    names = len(rig.pub.states)
    rig.arm()
    hold = rig.ctl.setpoint_m
    rig.tick(int(RATE_HZ))
    assert rig.state() is State.HOLDING
    assert "MOVING" not in rig.pub.state_names()[names:]
    assert rig.ctl.setpoint_m == hold
    assert rig.ctl.status()["velocity"]["discarded"] == 2


def test_a_sample_from_an_earlier_armed_session_is_discarded() -> None:
    # Stored by a submitting thread that read HOLDING in a session that has ended since.
    rig = _armed_rig()
    stale_epoch = rig.ctl._arm_epoch
    rig.do(Disarm())
    rig.arm()
    rig.ctl._velocity_cmd = ((1.0, 0.0, 0.0), stale_epoch)
    rig.tick(50)
    assert rig.state() is State.HOLDING
    assert _dist(rig.ctl.setpoint_m, rig.start) < 1e-9
    assert rig.ctl.velocity_discarded == 1


def test_non_finite_samples_are_refused_before_the_tick() -> None:
    rig = _armed_rig()
    for bad in ((math.nan, 0.0, 0.0), (0.0, math.inf, 0.0)):
        with pytest.raises(ValueError, match="finite"):
            rig.ctl.submit_velocity(bad)
        fut = rig.ctl.submit(Velocity(bad))
        assert "finite" in str(fut.exception(timeout=0))
    rig.tick(10)
    assert rig.state() is State.HOLDING and _dist(rig.ctl.setpoint_m, rig.start) < 1e-9


@pytest.mark.parametrize(
    ("v", "axis", "sign"),
    [
        ((0.0, 0.0, -2.0), 2, -1.0),  # the floor
        ((0.0, 0.0, 2.0), 2, 1.0),  # below the anchors
        ((2.0, 0.0, 0.0), 0, 1.0),  # the polygon's +x edge
        ((0.0, -2.0, 0.0), 1, -1.0),  # the polygon's -y edge
    ],
)
def test_the_workspace_boundary_is_never_crossed(
    v: tuple[float, float, float], axis: int, sign: float
) -> None:
    # Geometry alone: without a payload no tension limit stops the robot first (that one is
    # tested in test_loop_statics.py).
    rig = Rig(make_config(loop={"rate_hz": RATE_HZ}, top={"payload": None, "tension": None}))
    rig.arm()
    rig.tick(5)
    lim = rig.ctl.workspace
    rig.setpoints.clear()
    _fly(rig, v, 45.0)  # long enough to reach any edge at full speed, then keep pushing
    assert rig.state() is State.MOVING, rig.ctl.reason  # pushing: no fault
    assert all(lim.check_target(p) is None for p in rig.setpoints)
    p = rig.ctl.setpoint_m
    assert p is not None
    beyond = list(p)
    beyond[axis] += sign * 1e-3
    assert lim.check_target(beyond) is not None  # within a millimetre of the boundary
    assert rig.ctl.status()["velocity"]["boundary_brakes"] > 0
    # Released: brakes to a hold inside.
    rig.until(lambda: rig.ctl.state is State.HOLDING, 10_000)
    assert all(lim.check_target(p) is None for p in rig.setpoints)


def test_a_move_replaces_velocity_input_and_a_deflected_stick_takes_over_a_move() -> None:
    rig = _armed_rig()
    _fly(rig, (0.8, 0.0, 0.0), 1.0)
    s = rig.start
    target = (s[0], s[1] + 2.0, s[2])
    reply = rig.do(Move(target))
    assert reply["ok"] is True
    assert rig.ctl.planner.mode == "stop"  # braking out of velocity mode first
    # A centred stick streaming zeros does not stop the move...
    for _ in range(20):
        rig.ctl.submit_velocity((0.0, 0.0, 0.0))
        rig.tick(SAMPLE_TICKS)
    assert rig.ctl.planner.mode == "move" and rig.state() is State.MOVING
    # ...a deflected one takes over (smoothly: the speed changes by at most a * dt a tick).
    rig.setpoints.clear()
    rig.ctl.submit_velocity((0.0, 0.0, 0.3))
    rig.tick(SAMPLE_TICKS)
    assert rig.ctl.planner.mode == "velocity"
    vel = [
        tuple((b[i] - a[i]) / DT for i in range(3)) for a, b in itertools.pairwise(rig.setpoints)
    ]
    acc = [math.dist(a, b) / DT for a, b in itertools.pairwise(vel)]
    assert max(acc) <= rig.cfg.limits.max_accel_mps2 * (1 + 1e-6)
    rig.until(lambda: rig.ctl.state is State.HOLDING, 10_000)  # dead-man
    assert _dist(rig.ctl.setpoint_m, target) > 0.1  # the move was given up


def test_velocity_input_is_ignored_once_shutting_down() -> None:
    rig = _armed_rig()
    _fly(rig, (0.5, 0.0, 0.0), 0.5)
    rig.ctl.begin_shutdown()
    rig.tick()
    for _ in range(40):
        rig.ctl.submit_velocity((0.5, 0.0, 0.0))
        rig.tick(SAMPLE_TICKS)
    assert rig.state() is State.HOLDING


def test_velocity_timeout_is_validated_like_other_keys() -> None:
    data = paper_robot_data("v")
    assert parse_config(data, "v.toml").limits.velocity_timeout_s == 0.25  # the default
    data["limits"]["velocity_timeout_s"] = 0.1
    assert parse_config(data, "v.toml").limits.velocity_timeout_s == 0.1
    for bad, why in ((0, "must be > 0"), (-1.0, "must be > 0"), ("0.2 s", "in seconds")):
        data["limits"]["velocity_timeout_s"] = bad
        with pytest.raises(ConfigError, match=f"limits.velocity_timeout_s: .*{why}"):
            parse_config(data, "v.toml")


# ------------------------------------------------------------------------ the Zenoh key


class VelocityFake(FakeController):
    """The fake controller, recording velocity samples."""

    def __init__(self, **kw: Any) -> None:
        super().__init__(**kw)
        self.velocities: list[tuple[float, ...]] = []

    def submit_velocity(self, velocity_mps: Sequence[float]) -> None:
        self.velocities.append(tuple(velocity_mps))


@pytest.fixture
def zrig() -> Iterator[tuple[VelocityFake, zenoh_io.ZenohInterface, Any]]:
    port = free_tcp_port()
    fake = VelocityFake(rate_hz=100.0)
    iface = zenoh_io.ZenohInterface(
        ZCfg(listen=(f"tcp/127.0.0.1:{port}",)), fake, reply_timeout_s=1.0
    )
    iface.open()
    fake.publisher = iface
    fake.start()
    client = zenoh.open(zenoh_io.client_config([f"tcp/127.0.0.1:{port}"]))
    try:
        yield fake, iface, client
    finally:
        client.close()  # type: ignore[no-untyped-call]
        fake.stop()
        iface.close()


def _wait(cond: Any, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.01)


def _counts(iface: zenoh_io.ZenohInterface) -> tuple[int, int]:
    v = iface.stats()["velocity"]
    return int(v["ok"]), int(v["bad"])


@pytest.mark.parametrize("key", ["cablebot/test/*", "cablebot/test/**", "cablebot/**", "**"])
def test_only_the_exact_velocity_key_is_taken(
    zrig: tuple[VelocityFake, zenoh_io.ZenohInterface, Any], key: str
) -> None:
    fake, iface, client = zrig
    client.put(key, b'{"velocity_mps": [1.5, 0, 0]}')
    client.put("cablebot/test/velocity", b'{"velocity_mps": [0.1, -0.2, 0.3]}')  # exact key
    _wait(lambda: sum(_counts(iface)) == 2)
    assert fake.velocities == [(0.1, -0.2, 0.3)]
    assert _counts(iface) == (1, 1)
    assert fake.setpoints == []  # the wildcard put reached the set-point subscriber: refused


def test_oversized_deep_and_non_finite_samples_are_refused(
    zrig: tuple[VelocityFake, zenoh_io.ZenohInterface, Any], caplog: pytest.LogCaptureFixture
) -> None:
    fake, iface, client = zrig
    # BLOCK: the client must not drop the small samples queued behind the 10 MB one.
    pub = client.declare_publisher(
        "cablebot/test/velocity", congestion_control=zenoh.CongestionControl.BLOCK
    )
    time.sleep(0.3)  # let the publisher meet the subscriber
    cap = MAX_PAYLOAD_BYTES["velocity"]
    bad = [
        b'{"velocity_mps": [1, 0, 0]}' + b" " * cap,  # over the byte cap
        b"[" * 10_000_000,  # 10 MB: refused by its size, never copied
        b'{"velocity_mps": ' + b"[" * 100 + b"]" * 100 + b"}",  # too deep
        b'{"velocity_mps": [NaN, 0, 0]}',
        b'{"velocity_mps": [0, 1e999, 0]}',
        b'{"velocity_mps": [0, 0]}',
        b'{"position_m": [0, 0, 1]}',
        b"{",
    ]
    for data in bad:
        pub.put(data)
    pub.put(b'{"velocity_mps": [0.25, 0, 0]}')
    try:
        _wait(lambda: sum(_counts(iface)) == len(bad) + 1, 15.0)
    except AssertionError:
        raise AssertionError(f"counts {_counts(iface)}, taken {fake.velocities}") from None
    assert fake.velocities == [(0.25, 0.0, 0.0)]
    assert _counts(iface) == (1, len(bad))
    messages = [r.getMessage() for r in caplog.records if "bad velocity" in r.getMessage()]
    assert messages and all(len(m) <= 300 for m in messages)
    assert len(messages) <= 2  # rate-limited: not one line per bad sample
