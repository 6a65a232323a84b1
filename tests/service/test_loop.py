"""The control loop with a fake clock and a fake driver: deterministic, no threads, no bus."""

from __future__ import annotations

import itertools
import json
import math
import pathlib
from collections.abc import Callable, Sequence
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.core import kinematics
from controller.core.commands import (
    Arm,
    CommandRefused,
    Disarm,
    Estop,
    Home,
    Move,
    Path,
    Reset,
    Stop,
)
from controller.core.reel import ReelModel
from controller.core.states import State
from controller.service.loop import MAX_PLANNER_DT_PERIODS, Controller
from controller.service.pose import PoseSample
from tests.fakes import FakeClock, FakeDriver, RecordingPublisher, make_config, power_up_turns

RATE_HZ = 500.0
DT = 1.0 / RATE_HZ


class FFDriver(FakeDriver):
    """A FakeDriver that also records the velocity feed-forward sent with every command."""

    def __init__(self, *args: Any, **kw: Any) -> None:
        super().__init__(*args, **kw)
        self.ffs: list[tuple[float, ...] | None] = []

    def command(
        self, positions_rev: Sequence[float], velocity_ff_rps: Sequence[float] | None = None
    ) -> None:
        if velocity_ff_rps is not None:
            assert len(velocity_ff_rps) == len(self.node_ids)
            assert all(math.isfinite(v) for v in velocity_ff_rps)
        super().command(positions_rev, velocity_ff_rps)
        self.ffs.append(None if velocity_ff_rps is None else tuple(velocity_ff_rps))


class Rig:
    """A controller on a fake driver and a fake clock, ticked by hand."""

    def __init__(self, cfg: Any | None = None, *, homed: bool = True, **kw: Any) -> None:
        self.cfg = cfg if cfg is not None else make_config(loop={"rate_hz": RATE_HZ})
        self.clock = FakeClock()
        ids = [r.node_id for r in self.cfg.reels]
        turns = power_up_turns(self.cfg) if homed else [0.0] * len(ids)
        self.driver = FFDriver(ids, self.clock, turns)
        self.pub = RecordingPublisher()
        self.ctl = Controller(
            self.cfg,
            self.driver,
            self.pub,
            clock=self.clock,
            wall_clock_ns=self.clock.wall_ns,
            **kw,
        )
        self.setpoints: list[tuple[float, float, float]] = []

    def tick(self, n: int = 1) -> None:
        for _ in range(n):
            self.clock.advance(DT)
            self.ctl.tick(self.clock())
            if self.ctl.setpoint_m is not None and self.ctl.state in (
                State.HOLDING,
                State.MOVING,
            ):
                self.setpoints.append(self.ctl.setpoint_m)

    def state(self) -> State:
        """The controller's state (a call, so mypy does not narrow it across ticks)."""
        return self.ctl.state

    def do(self, cmd: Any, ticks: int = 1) -> dict[str, Any]:
        fut = self.ctl.submit(cmd)
        self.tick(ticks)
        assert fut.done()
        result: dict[str, Any] = fut.result(timeout=0)
        return result

    def refused(self, cmd: Any) -> str:
        fut = self.ctl.submit(cmd)
        self.tick()
        exc = fut.exception(timeout=0)
        assert isinstance(exc, CommandRefused), exc
        return str(exc)

    def until(self, pred: Callable[[], bool], max_ticks: int = 50_000) -> int:
        for i in range(max_ticks):
            if pred():
                return i
            self.tick()
        raise AssertionError(f"condition not met within {max_ticks} ticks")

    def arm(self) -> None:
        self.tick(2)
        self.do(Arm())
        self.until(lambda: self.ctl.state is State.HOLDING, 100)

    @property
    def start(self) -> tuple[float, float, float]:
        p = self.cfg.homing.power_up_position_m
        return (float(p[0]), float(p[1]), float(p[2]))


def _dist(a: Any, b: Any) -> float:
    return math.dist(tuple(a), tuple(b))


def _target(
    rig: Rig, dx: float = 1.0, dy: float = 0.0, dz: float = 0.0
) -> tuple[float, float, float]:
    s = rig.start
    return (s[0] + dx, s[1] + dy, s[2] + dz)


# ------------------------------------------------------------------------ arming and motion


def test_arming_sequence_holds_current_pose() -> None:
    rig = Rig()
    rig.tick(2)
    assert rig.ctl.homed and rig.ctl.home_source == "power_up"
    assert rig.ctl.pose_valid
    assert _dist(rig.ctl.pose_m, rig.start) < 1e-6
    assert rig.driver.commands == []  # nothing commanded while disarmed
    reply = rig.do(Arm())
    assert reply["ok"] and rig.driver.calls == ["arm"]
    assert rig.ctl.state in (State.ARMING, State.HOLDING)
    rig.until(lambda: rig.ctl.state is State.HOLDING, 10)
    assert rig.pub.state_names() == ["ARMING", "HOLDING"]
    # The hold set-point is the measured pose and the motors are told to stay where they are.
    assert _dist(rig.ctl.setpoint_m, rig.start) < 1e-6
    rig.tick(5)
    for got, want in zip(rig.driver.commands[-1], power_up_turns(rig.cfg), strict=True):
        assert got == pytest.approx(want, abs=1e-9)


def test_arm_timeout_names_the_axis() -> None:
    rig = Rig()
    rig.driver.no_closed_loop = {rig.ctl.node_ids[2]}
    rig.tick(2)
    rig.do(Arm())
    rig.until(lambda: rig.ctl.state is State.FAULT, int(rig.cfg.faults.arm_timeout_s * RATE_HZ) + 5)
    assert rig.ctl.reason is not None
    assert rig.ctl.reason.startswith("arm_timeout: ")
    assert f"node {rig.ctl.node_ids[2]}" in rig.ctl.reason
    assert f"node {rig.ctl.node_ids[0]}" not in rig.ctl.reason


def test_move_arrives_within_1mm_and_respects_limits() -> None:
    rig = Rig()
    rig.arm()
    target = _target(rig, 1.0, 0.5, -0.3)
    reply = rig.do(Move(target))
    assert reply["ok"] and rig.ctl.state is State.MOVING
    rig.setpoints.clear()
    n = rig.until(lambda: rig.ctl.state is State.HOLDING)
    assert n > 10
    rig.tick(3)
    assert _dist(rig.ctl.pose_m, target) < 1e-3
    assert _dist(rig.ctl.setpoint_m, target) < 1e-9
    vmax = rig.cfg.limits.default_speed_mps
    amax = rig.cfg.limits.max_accel_mps2
    pts = rig.setpoints
    speeds = [_dist(a, b) / DT for a, b in itertools.pairwise(pts)]
    assert max(speeds) <= min(vmax, rig.cfg.limits.max_speed_mps) * (1 + 1e-6)
    assert max(speeds) > 0.5 * vmax  # it really moved at speed
    accels = [
        math.dist([(c[i] - 2 * b[i] + a[i]) / DT**2 for i in range(3)], (0, 0, 0))
        for a, b, c in zip(pts, pts[1:], pts[2:], strict=False)
    ]
    assert max(accels) <= amax * (1 + 1e-6)
    # Cable speeds from the commanded motor turns stay under the per-cable limit.
    reels = rig.ctl.reels
    cmds = rig.driver.commands
    for a, b in zip(cmds[-len(pts) :], cmds[-len(pts) + 1 :], strict=False):
        for i, reel in enumerate(reels):
            v = abs(reel.length_m(b[i]) - reel.length_m(a[i])) / DT
            assert v <= rig.cfg.limits.max_cable_speed_mps * (1 + 1e-6)


def test_path_visits_points_and_stop_decelerates_to_hold() -> None:
    rig = Rig()
    rig.arm()
    pts = (_target(rig, 0.5), _target(rig, 0.5, 0.5), _target(rig, 0.0, 0.5))
    rig.do(Path(pts))
    rig.until(lambda: rig.ctl.state is State.HOLDING)
    assert _dist(rig.ctl.pose_m, pts[-1]) < 1e-3
    # A stop mid-move brakes to a hold short of the target, without a jump.
    far = _target(rig, 3.0)
    rig.do(Move(far))
    rig.until(lambda: _dist(rig.ctl.setpoint_m, pts[-1]) > 0.3)
    rig.setpoints.clear()
    rig.do(Stop())
    rig.until(lambda: rig.ctl.state is State.HOLDING)
    assert _dist(rig.ctl.setpoint_m, far) > 0.5
    sp = rig.setpoints
    assert max(_dist(a, b) for a, b in itertools.pairwise(sp)) / DT <= (
        rig.cfg.limits.max_speed_mps * (1 + 1e-6)
    )


def test_a_hold_a_stop_braked_to_carries_the_stop_as_its_reason() -> None:
    """The HOLDING a `stop` braked to says so (a client waiting on the motion reads it); an
    arrival does not, nor does a motion that replaced the braking."""
    rig = Rig()
    rig.arm()
    rig.do(Move(_target(rig, 3.0)))
    rig.tick(250)
    rig.do(Stop())
    rig.until(lambda: rig.ctl.state is State.HOLDING)
    assert rig.ctl.reason == "stopped by a `stop` command"
    assert rig.pub.states[-1][:2] == ("HOLDING", "stopped by a `stop` command")
    # arrival: no reason
    rig.do(Move(_target(rig, 0.5)))
    rig.until(lambda: rig.ctl.state is State.HOLDING)
    assert rig.ctl.reason is None and rig.pub.states[-1][:2] == ("HOLDING", None)
    # a stop while holding changes nothing
    rig.do(Stop())
    rig.tick(5)
    assert rig.ctl.reason is None and rig.pub.states[-1][:2] == ("HOLDING", None)
    # a move taken while the stop brakes replaces the braking: its arrival is no stop
    rig.do(Move(_target(rig, 3.0)))
    rig.tick(250)
    rig.do(Stop())
    rig.tick(2)
    back = _target(rig, 1.0)
    rig.do(Move(back))
    rig.until(lambda: rig.ctl.state is State.HOLDING)
    assert _dist(rig.ctl.setpoint_m, back) < 1e-9
    assert rig.ctl.reason is None
    # the daemon's shutdown brakes a motion the same way, and says so
    rig.do(Move(_target(rig, 3.0)))
    rig.tick(250)
    rig.ctl.begin_shutdown()
    rig.until(lambda: rig.ctl.state is State.HOLDING)
    assert rig.ctl.reason == "stopped by the daemon's shutdown"


def test_streamed_setpoints_are_rate_limited() -> None:
    rig = Rig()
    rig.arm()
    goal = _target(rig, 1.0)
    rig.ctl.submit_setpoint(goal)
    rig.tick()
    assert rig.ctl.state is State.MOVING
    rig.setpoints.clear()
    rig.until(lambda: rig.ctl.state is State.HOLDING)
    sp = rig.setpoints
    assert max(_dist(a, b) for a, b in itertools.pairwise(sp)) / DT <= (
        rig.cfg.limits.max_speed_mps * (1 + 1e-6)
    )
    assert _dist(rig.ctl.pose_m, goal) < 1e-3
    # An out-of-workspace streamed target is dropped and counted, no fault.
    rig.ctl.submit_setpoint((1e6, 0.0, 0.0))
    rig.ctl.submit_setpoint((math.nan, 0.0, 0.0))
    rig.tick(3)
    assert rig.state() is State.HOLDING
    assert rig.ctl.stream_refused == 1  # latest wins: only the NaN one was seen
    assert rig.ctl.stream_last_refusal is not None


def test_a_setpoint_sent_before_a_move_does_not_replace_it() -> None:
    """A set-point and then a move reaching the loop within one tick: the move is the latest,
    the set-point superseded (said in the stream's refusals), the robot flies the move."""
    rig = Rig()
    rig.arm()
    early, goal = _target(rig, 0.2), _target(rig, 0.5)
    rig.ctl.submit_setpoint(early)
    fut = rig.ctl.submit(Move(goal))
    rig.tick()
    assert fut.result(timeout=0)["ok"] is True
    assert rig.ctl.stream_refused == 1
    assert "superseded" in (rig.ctl.stream_last_refusal or "")
    rig.until(lambda: rig.ctl.state is State.HOLDING)
    assert _dist(rig.ctl.pose_m, goal) < 1e-3
    # a set-point sent after the move is the latest again
    rig.ctl.submit_setpoint(early)
    rig.tick()
    rig.until(lambda: rig.ctl.state is State.HOLDING)
    assert _dist(rig.ctl.pose_m, early) < 1e-3


# ------------------------------------------------------------------------ refusals


def test_out_of_workspace_and_state_refusals_leave_state_unchanged() -> None:
    rig = Rig()
    rig.tick(2)
    assert "not allowed in DISARMED" in rig.refused(Move(rig.start))
    rig.arm()
    anchors = rig.cfg.geometry.anchors_m
    top = max(float(a[2]) for a in anchors)
    xs = [float(a[0]) for a in anchors]
    s = rig.start
    bad = [
        (max(xs) + 1.0, s[1], s[2]),  # outside the plan-view polygon
        (s[0], s[1], rig.cfg.limits.floor_z_m - 0.1),  # below the floor
        (s[0], s[1], top - 0.5 * rig.cfg.limits.top_margin_m),  # into the anchor plane margin
    ]
    n_cmds = len(rig.driver.commands)
    for p in bad:
        reason = rig.refused(Move(p))
        assert reason and rig.ctl.state is State.HOLDING, p
    reason = rig.refused(Path((rig.start, bad[0])))
    assert "points_m[1]" in reason
    assert "not allowed in HOLDING" in rig.refused(Arm())
    assert rig.ctl.state is State.HOLDING
    assert _dist(rig.ctl.setpoint_m, s) < 1e-6
    assert len(rig.driver.commands) > n_cmds  # still holding


def test_unhomed_pose_invalid_and_arm_refused() -> None:
    cfg = make_config(loop={"rate_hz": RATE_HZ}, homing={"power_up_position_m": None})
    rig = Rig(cfg, homed=False)
    rig.tick(3)
    assert not rig.ctl.homed and not rig.ctl.pose_valid
    assert "not homed" in rig.refused(Arm())
    sample = rig.pub.poses[-1]
    assert isinstance(sample, PoseSample)
    assert sample.position_m is None and not sample.valid
    assert json.loads(sample.to_json_bytes())["position_m"] is None


def test_queue_full_refuses_busy() -> None:
    rig = Rig()
    futs = [rig.ctl.submit(Stop()) for _ in range(40)]
    busy = [f for f in futs if f.done() and isinstance(f.exception(timeout=0), CommandRefused)]
    assert len(busy) == 40 - 32
    assert "busy" in str(busy[0].exception(timeout=0))
    rig.tick(10)
    assert all(f.done() for f in futs)


# ------------------------------------------------------------------------ faults


def _armed_rig(**faults: Any) -> Rig:
    cfg = make_config(loop={"rate_hz": RATE_HZ}, faults=faults) if faults else None
    rig = Rig(cfg)
    rig.arm()
    rig.tick(5)
    return rig


def _assert_fault_holds(rig: Rig, code: str, hold: tuple[float, ...] | None = None) -> None:
    assert rig.ctl.state is State.FAULT
    assert rig.ctl.reason is not None and rig.ctl.reason.startswith(code + ":"), rig.ctl.reason
    assert rig.pub.states[-1][:2] == ("FAULT", rig.ctl.reason)
    if hold is None:
        return
    n = len(rig.driver.commands)
    rig.tick(20)
    assert len(rig.driver.commands) == n + 20  # the last good set-point is re-sent every tick
    for c in rig.driver.commands[n:]:
        assert c == hold
    assert "estop" not in rig.driver.calls and "disarm" not in rig.driver.calls


def test_stale_encoder_fault_holds() -> None:
    rig = _armed_rig()
    hold = rig.driver.commands[-1]
    rig.driver.silent = {rig.ctl.node_ids[1]}
    rig.until(lambda: rig.ctl.state is State.FAULT, 200)
    _assert_fault_holds(rig, "stale_encoder", hold)
    assert f"node {rig.ctl.node_ids[1]}" in str(rig.ctl.reason)


def test_stale_heartbeat_fault() -> None:
    rig = _armed_rig()
    hold = rig.driver.commands[-1]
    rig.driver.heartbeat_silent = {rig.ctl.node_ids[3]}
    rig.until(lambda: rig.ctl.state is State.FAULT, 1000)
    _assert_fault_holds(rig, "stale_heartbeat", hold)


def test_axis_error_fault() -> None:
    rig = _armed_rig()
    hold = rig.driver.commands[-1]
    rig.driver.axis_error[rig.ctl.node_ids[0]] = 0x800
    rig.tick()
    _assert_fault_holds(rig, "axis_error", hold)
    assert "0x800" in str(rig.ctl.reason)


def test_fpk_unreachable_fault() -> None:
    rig = _armed_rig()
    hold = rig.driver.commands[-1]
    rig.driver.follow = False
    # Wind cable 0 in far beyond what any pose allows: the spheres cannot meet.
    reel = rig.ctl.reels[0]
    rig.driver.readings[0].position_rev = reel.position_rev(0.5)
    rig.driver.readings[1].position_rev = rig.ctl.reels[1].position_rev(0.5)
    rig.tick()
    _assert_fault_holds(rig, "fpk_unreachable", hold)


def test_residual_fault_on_slack_cable() -> None:
    rig = _armed_rig(residual_max_m=0.005, tracking_max_m=1.0)
    hold = rig.driver.commands[-1]
    rig.driver.follow = False
    r = rig.driver.readings[3]
    reel = rig.ctl.reels[3]
    r.position_rev = reel.position_rev(reel.length_m(r.position_rev) + 0.05)  # 5 cm slack
    rig.tick()
    _assert_fault_holds(rig, "residual", hold)


def test_tracking_error_fault() -> None:
    rig = _armed_rig(tracking_max_m=0.02)
    rig.driver.follow = False  # the motors stop following: the pose stays behind
    rig.do(Move(_target(rig, 1.0)))
    rig.until(lambda: rig.ctl.state is State.FAULT, 2000)
    assert _dist(rig.ctl.setpoint_m, rig.start) > 0.02
    _assert_fault_holds(rig, "tracking_error", rig.driver.commands[-1])


def test_tracking_error_allows_what_the_set_point_moved_since_the_readings() -> None:
    """Readings 0.1 s old show the effector where it was 0.1 s ago: at speed v the set-point
    has moved on by v x 0.1 s since, which is no lag of the robot; beyond it is."""
    rig = _armed_rig(tracking_max_m=0.02, stale_timeout_s=0.5)
    rig.driver.reading_age_s = 0.1
    rig.do(Move(_target(rig, 1.0)))
    rig.until(lambda: _norm(rig.ctl.planner.velocity_mps) > 0.3, 2000)
    rig.driver.follow = False  # from here the pose stays behind
    stopped_at = rig.ctl.pose_m
    rig.until(lambda: rig.ctl.state is State.FAULT, 5000)
    assert rig.ctl.reason is not None and rig.ctl.reason.startswith("tracking_error:")
    lag = _dist(rig.ctl.setpoint_m, stopped_at)
    # The set-point flew at 0.3 m/s or more all along: the fault came only past the limit plus
    # its travel over the readings' age (at least 0.03 m), not at the bare 0.02 m.
    assert lag > 0.02 + 0.1 * 0.3 - 1e-3, lag
    assert lag < 0.2, lag  # and it did come


def _norm(v: Any) -> float:
    return math.sqrt(sum(float(x) ** 2 for x in v))


def test_one_lost_frame_is_counted_not_a_fault() -> None:
    rig = _armed_rig()  # faults.bus_error_timeout_s = 0.05 s: 25 ticks at 500 Hz
    rig.driver.fail_bus("ENOBUFS")
    rig.tick()
    rig.driver.raise_on_command = None
    rig.tick(30)
    assert rig.ctl.state is State.HOLDING
    assert rig.ctl.status()["bus"]["bus_errors"] == 1


def test_bus_error_immediate_fault_when_timeout_zero() -> None:
    rig = _armed_rig(bus_error_timeout_s=0.0)
    rig.driver.fail_bus("bus-off")
    rig.tick(2)
    _assert_fault_holds(rig, "bus_error")


def test_bus_error_fault_keeps_trying_to_hold() -> None:
    rig = _armed_rig()
    rig.driver.fail_bus("bus-off")
    rig.tick(20)  # 40 ms of failing sends: still inside the 50 ms window
    assert rig.ctl.state is State.HOLDING
    rig.tick(10)
    _assert_fault_holds(rig, "bus_error")
    assert "bus-off" in str(rig.ctl.reason)
    rig.tick(5)
    assert rig.ctl.hold_failures >= 5
    rig.driver.raise_on_command = None
    n = len(rig.driver.commands)
    rig.tick(3)
    assert len(rig.driver.commands) == n + 3


def test_nan_never_commanded() -> None:
    rig = _armed_rig()
    hold = rig.driver.commands[-1]
    rig.ctl.planner.advance = lambda dt_s: (math.nan, 0.0, 0.0)  # type: ignore[method-assign]
    rig.tick()
    _assert_fault_holds(rig, "nan_setpoint", hold)
    assert all(math.isfinite(v) for c in rig.driver.commands for v in c)


def test_commands_refused_in_fault_until_reset() -> None:
    rig = _armed_rig()
    rig.driver.axis_error[rig.ctl.node_ids[0]] = 1
    rig.tick()
    assert rig.ctl.state is State.FAULT
    for cmd in (Move(rig.start), Arm(), Disarm(), Home(rig.start)):
        assert "reset first" in rig.refused(cmd)
        assert rig.ctl.state is State.FAULT
    rig.driver.axis_error.clear()
    assert rig.do(Reset())["state"] == "DISARMED"
    assert rig.driver.calls[-1] == "disarm"
    rig.arm()
    assert rig.state() is State.HOLDING


def test_estop_disarms_at_once_from_any_state() -> None:
    rig = _armed_rig()
    rig.do(Move(_target(rig, 2.0)))
    rig.tick(50)
    assert rig.ctl.state is State.MOVING
    n = len(rig.driver.commands)
    fut = rig.ctl.submit(Estop())
    rig.tick()
    assert fut.result(timeout=0)["state"] == "ESTOPPED"
    assert rig.state() is State.ESTOPPED and rig.driver.calls[-1] == "estop"
    assert len(rig.driver.commands) == n  # not a single set-point after the e-stop
    rig.tick(10)
    assert len(rig.driver.commands) == n
    assert "not allowed in ESTOPPED" in rig.refused(Arm())
    rig.do(Reset())
    assert rig.state() is State.DISARMED
    # E-stop also works while disarmed and in FAULT.
    rig.ctl.submit(Estop())
    rig.tick()
    assert rig.state() is State.ESTOPPED


def test_estop_is_not_refused_when_the_queue_is_full() -> None:
    rig = _armed_rig()
    for _ in range(40):
        rig.ctl.submit(Stop())
    fut = rig.ctl.submit(Estop())
    rig.tick()
    assert fut.result(timeout=0)["ok"] and rig.ctl.state is State.ESTOPPED


# ------------------------------------------------------------------------ homing


def test_home_sets_offsets_saves_and_reloads(tmp_path: pathlib.Path) -> None:
    state_file = tmp_path / "offsets.json"
    cfg = make_config(
        loop={"rate_hz": RATE_HZ},
        homing={"power_up_position_m": None, "state_file": str(state_file)},
    )
    rig = Rig(cfg, homed=False)
    rig.tick(2)
    assert not rig.ctl.pose_valid
    here = (1.0, 2.0, 1.5)
    fut = rig.ctl.submit(Home(here))
    rig.tick()
    reply = fut.result(timeout=5)
    assert reply["ok"] and reply["saved"], reply
    assert state_file.exists()
    rig.tick()
    assert rig.ctl.pose_valid and _dist(rig.ctl.pose_m, here) < 1e-6
    # A new controller on the same encoders reloads the offsets from the state file.
    again = Controller(cfg, rig.driver, clock=rig.clock, wall_clock_ns=rig.clock.wall_ns)
    assert again.homed and again.home_source == "state_file"
    rig.clock.advance(DT)
    again.tick(rig.clock())
    assert again.pose_valid and _dist(again.pose_m, here) < 1e-6


def test_home_refused_on_a_stale_reading_names_its_age_the_threshold_and_the_key() -> None:
    rig = Rig()
    rig.tick(2)
    node = rig.ctl.node_ids[2]
    rig.driver.silent = {node}
    rig.tick(int(0.2 / DT))  # 0.2 s without an encoder frame from that node
    reason = rig.refused(Home(rig.start))
    assert reason.startswith("stale_encoder: no fresh encoder reading (node 2 0.2"), reason
    assert "s old; faults.stale_timeout_s is 0.05 s" in reason, reason
    assert "raise faults.stale_timeout_s" in reason, reason


def test_home_refused_outside_workspace_and_while_moving() -> None:
    rig = Rig()
    rig.tick(2)
    assert "home position" in rig.refused(Home((1e4, 0.0, 1.0)))
    rig.arm()
    rig.do(Move(_target(rig, 1.0)))
    assert "not allowed in MOVING" in rig.refused(Home(rig.start))


def test_home_while_holding_keeps_the_motors_still() -> None:
    rig = _armed_rig()
    before = rig.driver.commands[-1]
    rig.do(Home(_target(rig, 0.1)))
    rig.tick(5)
    assert rig.ctl.state is State.HOLDING
    for a, b in zip(rig.driver.commands[-1], before, strict=True):
        assert a == pytest.approx(b, abs=1e-9)
    assert _dist(rig.ctl.pose_m, _target(rig, 0.1)) < 1e-6


# ------------------------------------------------------------------------ publishing, stats


def test_pose_json_schema_and_no_nan() -> None:
    s = PoseSample(7, 123, (1.0, -2.5, 0.125), (1.5, 2.0), 0.001, True, "HOLDING")
    assert s.to_json_bytes() == (
        b'{"seq":7,"stamp_ns":123,"position_m":[1.0,-2.5,0.125],'
        b'"cable_lengths_m":[1.5,2.0],"residual_m":0.001,"valid":true,"state":"HOLDING",'
        b'"queued_points":0}'
    )
    deep = PoseSample(9, 5, (0.0, 0.0, 1.0), (1.0,), 0.0, True, "MOVING", queued_points=4321)
    assert deep.to_json_bytes().endswith(b'"state":"MOVING","queued_points":4321}')
    bad = PoseSample(8, 124, (math.nan, 0.0, 0.0), (math.inf, 2.0), math.nan, True, "FAULT")
    obj = json.loads(bad.to_json_bytes())
    assert obj["position_m"] is None and obj["valid"] is False
    assert obj["cable_lengths_m"] == [None, 2.0] and obj["residual_m"] is None


def test_status_dates_the_set_point_by_the_tick_that_computed_it() -> None:
    """A status read between ticks (or answered late) gives the set-point with the wall time
    of its tick, not of the read: a plot of the set-point's speed needs that time."""
    rig = Rig()
    assert rig.ctl.status()["setpoint_stamp_ns"] is None  # no set-point yet
    rig.arm()
    rig.do(Move(_target(rig, 1.0)))
    rig.tick(100)
    tick_ns = rig.clock.wall_ns()
    sp = rig.ctl.setpoint_m
    rig.clock.advance(0.0013)  # the status is read 1.3 ms after the tick
    st = rig.ctl.status()
    assert st["setpoint_m"] == list(sp)  # type: ignore[arg-type]
    assert abs(st["setpoint_stamp_ns"] - tick_ns) <= 1, (st["setpoint_stamp_ns"], tick_ns)
    rig.tick()
    assert abs(rig.ctl.status()["setpoint_stamp_ns"] - rig.clock.wall_ns()) <= 1


def test_published_poses_and_states() -> None:
    cfg = make_config(loop={"rate_hz": RATE_HZ, "publish_every": 5})
    rig = Rig(cfg)
    rig.arm()
    rig.tick(100)
    poses = rig.pub.poses
    assert len(poses) == rig.ctl.ticks // 5
    last = poses[-1]
    assert isinstance(last, PoseSample)
    assert last.valid and last.state == "HOLDING" and _dist(last.position_m, rig.start) < 1e-6
    seqs = [p.seq for p in poses]  # type: ignore[attr-defined]
    assert seqs == list(range(1, len(poses) + 1))
    lengths = kinematics.ipk_point(cfg.geometry, rig.start)
    assert last.cable_lengths_m == pytest.approx(lengths, abs=1e-9)


def test_status_snapshot() -> None:
    rig = _armed_rig()
    st = rig.ctl.status()
    json.dumps(st, allow_nan=False)
    assert st["state"] == "HOLDING" and st["pose"]["valid"]
    assert [a["node_id"] for a in st["axes"]] == list(rig.ctl.node_ids)
    assert all(a["axis_state"] == 8 and a["age_s"] is not None for a in st["axes"])
    assert st["loop"]["rate_hz"] == pytest.approx(RATE_HZ)
    assert st["loop"]["ticks"] == rig.ctl.ticks


# ------------------------------------------------------------------------ the scheduler


class SteppedClock:
    """A clock for the runner: sleeping moves it (by the sleep and a microsecond more)."""

    def __init__(self) -> None:
        self.now_s = 0.0
        self.starts: list[float] = []

    def __call__(self) -> float:
        return self.now_s

    def sleep(self, dt_s: float) -> None:
        self.now_s += max(dt_s, 0.0) + 1e-6


def test_run_keeps_absolute_deadlines_and_skips_missed_ticks() -> None:
    import threading

    cfg = make_config(loop={"rate_hz": 1000.0})
    clk = SteppedClock()
    driver = FakeDriver([r.node_id for r in cfg.reels], FakeClock(), power_up_turns(cfg))
    ctl = Controller(cfg, driver, clock=clk, sleep=clk.sleep)
    stop = threading.Event()
    real_tick = ctl.tick
    period = 1e-3

    def tick(now_s: float) -> None:
        clk.starts.append(now_s)
        real_tick(now_s)
        clk.now_s += 0.0001
        if len(clk.starts) == 10:
            clk.now_s += 2.5 * period  # one slow tick: misses two deadlines
        if len(clk.starts) >= 30:
            stop.set()

    ctl.tick = tick  # type: ignore[method-assign]
    runner = ctl.runner(spin_s=0.0)
    assert runner.period_s == pytest.approx(period) and runner.stats is ctl.loop_stats
    runner.run(stop)
    t0 = clk.starts[0]
    k = [(t - t0) / period for t in clk.starts]
    # Every tick starts on the grid (within the sleep granularity), never bunched.
    for a in k:
        assert abs(a - round(a)) < 0.01
    gaps = [round(b - a) for a, b in itertools.pairwise(k)]
    assert gaps.count(3) == 1 and set(gaps) == {1, 3}
    assert ctl.loop_stats.overruns == 1 and ctl.loop_stats.skipped == 2
    st = ctl.status()["loop"]
    assert st["ticks"] == 30
    assert st["overruns"] == 1 and st["skipped"] == 2
    assert st["compute_max_s"] == pytest.approx(0.0001 + 2.5 * period, rel=1e-6)
    assert st["jitter_p50_s"] < 1e-5


def test_status_loop_figures_keep_their_keys_before_and_after_running() -> None:
    import threading

    keys = [
        "rate_hz",
        "ticks",
        "overruns",
        "skipped",
        "jitter_p50_s",
        "jitter_p99_s",
        "jitter_max_s",
        "compute_p50_s",
        "compute_p99_s",
        "compute_max_s",
        "dt_clamped",
    ]
    cfg = make_config(loop={"rate_hz": 500.0})
    clk = SteppedClock()
    driver = FakeDriver([r.node_id for r in cfg.reels], FakeClock(), power_up_turns(cfg))
    ctl = Controller(cfg, driver, clock=clk, sleep=clk.sleep)
    before = ctl.status()["loop"]
    assert list(before) == keys
    assert before["jitter_p99_s"] is None and before["compute_max_s"] is None
    stop = threading.Event()
    beats: list[float] = []

    def watchdog() -> None:  # every tick (a period shorter than one): stops the runner after 20
        beats.append(clk())
        if len(beats) >= 20:
            stop.set()

    ctl.runner(spin_s=0.0).run(stop, on_watchdog=watchdog, watchdog_period_s=1e-9)
    after = ctl.status()["loop"]
    assert list(after) == keys
    assert after["ticks"] == ctl.ticks == 20
    assert after["rate_hz"] == pytest.approx(500.0)
    assert after["overruns"] == 0 and after["skipped"] == 0
    assert after["jitter_max_s"] is not None and 0.0 <= after["jitter_max_s"] < 1e-5
    assert after["compute_p50_s"] is not None and after["compute_p50_s"] >= 0.0
    json.dumps(after, allow_nan=False)


def test_pose_stamp_is_the_encoder_arrival_time_not_the_publish_time() -> None:
    # The wall clock the controller sees runs 7 s ahead of the readings' stamps: the published
    # stamp must be the newest reading's arrival (the pose schema: "wall-clock time
    # of the encoder readings it came from"), not the moment of publication.
    cfg = make_config(loop={"rate_hz": RATE_HZ})
    clock = FakeClock()
    driver = FakeDriver([r.node_id for r in cfg.reels], clock, power_up_turns(cfg))
    pub = RecordingPublisher()
    ctl = Controller(
        cfg, driver, pub, clock=clock, wall_clock_ns=lambda: clock.wall_ns() + 7_000_000_000
    )
    for _ in range(3):
        clock.advance(DT)
        ctl.tick(clock())
    ctl.tick(clock())
    newest = max(r.stamp_ns for r in driver.readings)
    last = pub.poses[-1]
    assert isinstance(last, PoseSample) and last.valid
    assert last.stamp_ns == newest
    assert abs(last.stamp_ns - clock.wall_ns()) < 1_000_000


# ------------------------------------------------------------------------ feed-forward, stalls


def _zero_ff(ff: tuple[float, ...] | None) -> bool:
    return ff is None or all(v == 0.0 for v in ff)


def test_velocity_feed_forward_is_the_rate_of_the_commanded_turns() -> None:
    rig = _armed_rig()
    drv = rig.driver
    assert drv.ffs and all(_zero_ff(f) for f in drv.ffs)  # arming and holding: none
    target = _target(rig, 8.0, 3.0, 1.0)
    rig.do(Move(target, speed_mps=rig.cfg.limits.max_speed_mps))
    first = len(drv.commands)
    rig.until(lambda: rig.ctl.state is State.HOLDING)
    cmds = drv.commands[first:]
    ffs = drv.ffs[first:]
    assert _zero_ff(ffs[-1])  # arrived: holding again
    peak = 0.0
    for k in range(1, len(cmds) - 2):
        ff = ffs[k]
        assert ff is not None
        for i in range(rig.ctl.n):
            rate = (cmds[k + 1][i] - cmds[k - 1][i]) / (2.0 * DT)  # central difference
            # 0.02 rev/s = 1 mm/s of cable: the difference's error at the trapezoid's corners
            assert ff[i] == pytest.approx(rate, abs=0.02), (k, i)
            peak = max(peak, abs(ff[i]))
    assert peak > 20.0  # really at speed: 2 m/s is 40 rev/s along a cable


def test_feed_forward_is_zero_in_the_fault_hold() -> None:
    rig = _armed_rig()
    rig.do(Move(_target(rig, 5.0), speed_mps=2.0))
    rig.tick(500)
    assert rig.ctl.state is State.MOVING and not _zero_ff(rig.driver.ffs[-1])
    rig.driver.axis_error[rig.ctl.node_ids[2]] = 0x800
    rig.tick()
    n = len(rig.driver.commands)
    _assert_fault_holds(rig, "axis_error", rig.driver.commands[-1])
    assert all(_zero_ff(f) for f in rig.driver.ffs[n - 1 :])
    assert rig.ctl.commanded_ff_rps == [0.0] * rig.ctl.n


def test_cpu_stall_moves_the_set_point_at_most_a_few_periods() -> None:
    rig = _armed_rig()
    vmax = rig.cfg.limits.max_speed_mps
    rig.do(Move(_target(rig, 10.0), speed_mps=vmax))
    rig.until(lambda: math.dist(rig.ctl.planner.velocity_mps, (0, 0, 0)) >= vmax - 1e-9)
    before = rig.ctl.setpoint_m
    rig.clock.advance(0.3 - DT)  # the loop thread did not run for 300 ms
    rig.tick()
    assert rig.ctl.state is State.MOVING, rig.ctl.reason  # no cable_speed or other fault
    step = _dist(rig.ctl.setpoint_m, before)
    assert step == pytest.approx(vmax * MAX_PLANNER_DT_PERIODS * DT, rel=1e-6)
    assert rig.ctl.dt_clamped == 1 and rig.ctl.status()["loop"]["dt_clamped"] == 1
    rig.tick(10)  # ordinary ticks again: one period each
    assert rig.ctl.dt_clamped == 1
    assert _dist(rig.ctl.setpoint_m, before) == pytest.approx(vmax * 14 * DT, rel=1e-6)
    rig.until(lambda: rig.ctl.state is State.HOLDING)
    assert _dist(rig.ctl.pose_m, _target(rig, 10.0)) < 1e-3


_AXIS = st.floats(-30.0, 30.0)
_VEL = st.floats(-2.0, 2.0)


@settings(max_examples=200, deadline=None)
@given(
    p=st.tuples(_AXIS, st.floats(-20.0, 20.0), st.floats(0.5, 6.0)),
    v=st.tuples(_VEL, _VEL, _VEL),
    buildup=st.floats(0.0, 1e-3),
    direction=st.sampled_from([1, -1]),
)
def test_feed_forward_is_the_derivative_of_ipk_through_the_reels(
    p: tuple[float, float, float],
    v: tuple[float, float, float],
    buildup: float,
    direction: int,
) -> None:
    cfg = make_config(loop={"rate_hz": RATE_HZ})
    ctl = Controller(cfg, FakeDriver([r.node_id for r in cfg.reels], FakeClock()))
    ctl.reels = [
        ReelModel(0.5, 10.0, direction, spool_buildup_m_per_rev2=buildup, reference_length_m=40.0)
        for _ in cfg.reels
    ]
    lengths = kinematics.ipk_point(cfg.geometry, p)
    rev = [m.position_rev(L) for m, L in zip(ctl.reels, lengths, strict=True)]
    ff = ctl._velocity_ff(p, v, lengths, rev)
    h = 1e-4  # central difference of turns along the motion (exact to ~h^2)
    ahead = (p[0] + v[0] * h, p[1] + v[1] * h, p[2] + v[2] * h)
    behind = (p[0] - v[0] * h, p[1] - v[1] * h, p[2] - v[2] * h)
    la = kinematics.ipk_point(cfg.geometry, ahead)
    lb = kinematics.ipk_point(cfg.geometry, behind)
    for i, m in enumerate(ctl.reels):
        want = (m.position_rev(la[i]) - m.position_rev(lb[i])) / (2.0 * h)
        assert ff[i] == pytest.approx(want, rel=1e-5, abs=1e-6)
        assert math.isfinite(ff[i])


def test_fpk_is_solved_only_when_the_encoder_lengths_change() -> None:
    rig = _armed_rig()
    solves, ticks = rig.ctl.fpk_solves, rig.ctl.ticks
    rig.tick(50)  # holding: the fake reels report the same turns every tick
    assert rig.ctl.ticks == ticks + 50
    assert rig.ctl.fpk_solves == solves
    pose = rig.ctl.pose_m
    assert pose is not None and _dist(pose, rig.start) < 1e-6
    # A cable that slips is seen at once: new lengths are solved, the residual check faults.
    rig.driver.follow = False
    rig.driver.readings[1].position_rev += 2.0
    rig.tick()
    assert rig.ctl.fpk_solves == solves + 1
    assert rig.ctl.state is State.FAULT
    assert rig.ctl.reason is not None and rig.ctl.reason.startswith("residual:")


def test_a_residual_fault_names_the_reading_that_lags() -> None:
    # A drive gone quiet mid-move: its reading stays while the others move on, and the residual
    # passes its limit before that reading is stale. The fault says which node lags.
    rig = _armed_rig(stale_timeout_s=0.05)
    rig.driver.silent = {rig.driver.node_ids[2]}
    rig.tick(10)  # 20 ms: not stale yet
    rig.driver.follow = False
    rig.driver.readings[1].position_rev += 2.0
    rig.tick()
    assert rig.ctl.state is State.FAULT
    reason = str(rig.ctl.reason)
    assert reason.startswith("residual:") and "slack or slipped cable" in reason, reason
    node = rig.driver.node_ids[2]
    assert f"; node {node}'s reading is 0.022 s old)" in reason, reason


def test_arm_is_refused_while_the_cables_disagree() -> None:
    # Disarmed, a cable slipped: the pose has a residual above the limit. Arming would fault on
    # it at once; the arm is refused by name, and `home` puts it right.
    rig = Rig()
    rig.tick(5)
    assert rig.ctl.state is State.DISARMED and rig.ctl.pose_valid
    rig.driver.readings[1].position_rev += 2.0
    rig.tick()
    assert rig.ctl.residual_m is not None and rig.ctl.residual_m > 0.01
    reason = rig.refused(Arm())
    assert reason.startswith("residual: ") and "home at a known pose" in reason, reason
    assert rig.ctl.state is State.DISARMED
    rig.do(Home(rig.start))
    rig.arm()
    assert rig.ctl.state is State.HOLDING


# ------------------------------------------------------------------------ streamed set-points


def _far(rig: Rig) -> tuple[float, float, float]:
    """A set-point well inside the workspace, metres from the start (like [4, -3, 3])."""
    return _target(rig, 4.0, -3.0, 1.0)


def _assert_holds_start_after_arming(rig: Rig) -> None:
    """Arm and run 1 s: the robot must hold the measured pose, never move."""
    names = len(rig.pub.states)
    rig.arm()
    rig.tick(int(RATE_HZ))
    assert rig.state() is State.HOLDING, rig.ctl.reason
    assert "MOVING" not in rig.pub.state_names()[names:]
    assert _dist(rig.ctl.setpoint_m, rig.start) < 1e-9
    assert _dist(rig.ctl.pose_m, rig.start) < 1e-6


def test_setpoint_while_disarmed_does_not_move_the_robot_after_arm() -> None:
    rig = _armed_rig()
    rig.do(Disarm())
    rig.ctl.submit_setpoint(_far(rig))
    rig.tick(5)
    _assert_holds_start_after_arming(rig)
    assert rig.ctl.status()["stream"]["discarded"] == 1
    # The same set-point once armed is taken: streaming itself still works.
    rig.ctl.submit_setpoint(_target(rig, 0.2))
    rig.tick()
    assert rig.state() is State.MOVING


@pytest.mark.parametrize("how", ["fault", "estop"])
def test_setpoint_before_reset_does_not_move_the_robot_after_arm(how: str) -> None:
    rig = _armed_rig()
    if how == "fault":
        rig.driver.axis_error[rig.ctl.node_ids[0]] = 0x800
        rig.tick()
        rig.driver.axis_error.clear()
    else:
        rig.ctl.submit(Estop())
        rig.tick()
    assert rig.state() in (State.FAULT, State.ESTOPPED)
    rig.ctl.submit_setpoint(_far(rig))
    rig.do(Reset())
    rig.ctl.submit_setpoint(_far(rig))  # and once more while DISARMED
    _assert_holds_start_after_arming(rig)


def test_setpoint_during_arming_is_discarded() -> None:
    rig = Rig()
    rig.tick(2)
    fut = rig.ctl.submit(Arm())
    rig.tick()
    assert fut.result(timeout=0)["state"] == "ARMING" and rig.state() is State.ARMING
    rig.ctl.submit_setpoint(_far(rig))
    rig.until(lambda: rig.ctl.state is State.HOLDING, 10)
    rig.tick(int(RATE_HZ))
    assert rig.state() is State.HOLDING and "MOVING" not in rig.pub.state_names()
    assert _dist(rig.ctl.setpoint_m, rig.start) < 1e-9


def test_setpoint_from_an_earlier_armed_session_is_discarded() -> None:
    # A set-point the submitting thread stored for a session that has ended since (it read
    # HOLDING, then the loop disarmed and re-armed before the store landed).
    rig = _armed_rig()
    stale_epoch = rig.ctl._arm_epoch
    rig.do(Disarm())
    rig.arm()
    rig.ctl._stream_target = (_far(rig), stale_epoch, next(rig.ctl._arrivals))
    rig.tick(50)
    assert rig.state() is State.HOLDING
    assert _dist(rig.ctl.setpoint_m, rig.start) < 1e-9
    assert rig.ctl.stream_refused == 1
    assert "before the last `arm`" in str(rig.ctl.stream_last_refusal)


def test_submitted_setpoint_command_is_refused_when_not_armed() -> None:
    from controller.core.commands import Setpoint

    rig = Rig()
    rig.tick(2)
    fut = rig.ctl.submit(Setpoint(_far(rig)))
    exc = fut.exception(timeout=0)
    assert isinstance(exc, CommandRefused) and "not allowed in DISARMED" in str(exc)
    rig.arm()
    assert rig.ctl.submit(Setpoint(_target(rig, 0.1))).result(timeout=0) == {"ok": True}
    rig.tick()
    assert rig.state() is State.MOVING


# ------------------------------------------------------------------------ speeds


def test_speed_below_the_minimum_is_refused() -> None:
    rig = _armed_rig()
    for v in (5e-324, 1e-9):  # a move at 5e-324 m/s would stay MOVING forever
        reason = rig.refused(Move(_target(rig, 1.0), speed_mps=v))
        assert "speed_mps" in reason and "minimum" in reason, reason
        assert rig.state() is State.HOLDING
    from controller.core.motion import MIN_SPEED_MPS

    assert "minimum" in rig.refused(Move(_target(rig, 1.0), speed_mps=0.5 * MIN_SPEED_MPS))
    reason = rig.refused(Path((_target(rig, 1.0),), speed_mps=0.0))
    assert "speed_mps" in reason
    reply = rig.do(Move(_target(rig, 0.01), speed_mps=MIN_SPEED_MPS))
    assert reply["speed_mps"] == MIN_SPEED_MPS and "speed_limited_to_mps" not in reply
    rig.until(lambda: rig.ctl.state is State.HOLDING, int(30 * RATE_HZ))


def test_speed_above_the_maximum_is_limited_and_the_reply_says_so() -> None:
    rig = _armed_rig()
    vmax = float(rig.cfg.limits.max_speed_mps)
    reply = rig.do(Move(_target(rig, 3.0), speed_mps=50.0))
    assert reply["speed_mps"] == vmax and reply["speed_limited_to_mps"] == vmax
    rig.until(lambda: rig.ctl.state is State.HOLDING)
    reply = rig.do(Path((_target(rig, 1.0),), speed_mps=50.0))
    assert reply["speed_limited_to_mps"] == vmax
    rig.until(lambda: rig.ctl.state is State.HOLDING)
    reply = rig.do(Move(rig.start, speed_mps=vmax))
    assert reply["speed_mps"] == vmax and "speed_limited_to_mps" not in reply


# ------------------------------------------------------------------------ long paths


def _circle(rig: Rig, n: int, radius_m: float = 3.0) -> tuple[tuple[float, float, float], ...]:
    s = rig.start
    return tuple(
        (
            s[0] + radius_m * math.cos(2.0 * math.pi * i / n) - radius_m,
            s[1] + radius_m * math.sin(2.0 * math.pi * i / n),
            s[2],
        )
        for i in range(n)
    )


def test_a_long_path_costs_the_tick_no_per_point_work(monkeypatch: pytest.MonkeyPatch) -> None:
    from controller.core import motion as motion_mod
    from controller.core import workspace as workspace_mod

    rig = _armed_rig()
    pts = _circle(rig, 10_000)
    fut = rig.ctl.submit(Path(pts, 1.0))  # checked and prepared here, in this thread
    calls = {"point": 0, "leg": 0, "ipk": 0}
    lim = workspace_mod.Workspace
    real_point, real_segment = lim.check_point, lim.check_segment
    real_ipk = kinematics.ipk_point

    def check_point(self: Any, p: Any) -> Any:
        calls["point"] += 1
        return real_point(self, p)

    def check_segment(self: Any, a: Any, b: Any) -> Any:
        calls["leg"] += 1
        return real_segment(self, a, b)

    def ipk_point(geom: Any, p: Any) -> Any:
        calls["ipk"] += 1
        return real_ipk(geom, p)

    monkeypatch.setattr(lim, "check_point", check_point)
    monkeypatch.setattr(lim, "check_segment", check_segment)
    monkeypatch.setattr(kinematics, "ipk_point", ipk_point)
    legs = {"n": 0}
    real_init = motion_mod.TrapezoidMove.__init__

    def counting_init(self: Any, *a: Any, **kw: Any) -> None:
        legs["n"] += 1
        real_init(self, *a, **kw)

    monkeypatch.setattr(motion_mod.TrapezoidMove, "__init__", counting_init)
    rig.tick()  # the tick that takes the path
    reply = fut.result(timeout=0)
    assert reply["ok"] and reply["points"] == 10_000
    assert rig.state() is State.MOVING
    # A handful of calls (first leg, this tick's set-point), not one per point.
    assert calls["point"] <= 4 and calls["leg"] <= 2 and calls["ipk"] <= 4, calls
    assert legs["n"] <= 2, legs
    rig.tick(200)
    assert rig.state() is State.MOVING
    assert calls["point"] <= 4 + 3 * 200, calls


def test_a_long_path_is_refused_at_its_first_bad_point() -> None:
    rig = _armed_rig()
    pts = list(_circle(rig, 2_000))
    anchors = rig.cfg.geometry.anchors_m
    pts[1234] = (max(float(a[0]) for a in anchors) + 1.0, 0.0, rig.start[2])
    pts[1500] = (math.nan, 0.0, 0.0)
    reason = rig.refused(Path(tuple(pts)))
    assert reason.startswith("points_m[1234] ") and "plan-view polygon" in reason, reason
    assert rig.state() is State.HOLDING


def test_a_long_path_is_followed_to_its_end() -> None:
    rig = _armed_rig()
    pts = _circle(rig, 400, radius_m=0.5)
    pts = (*pts, pts[-1], pts[-1], rig.start)  # repeated points are dropped
    reply = rig.do(Path(pts, 2.0))
    assert reply["points"] == 403
    rig.until(lambda: rig.ctl.state is State.HOLDING, 200_000)
    assert _dist(rig.ctl.setpoint_m, rig.start) < 1e-12
    assert rig.ctl.status()["state"] == "HOLDING"


# ------------------------------------------------------------------------ e-stop confirmation


class StubbornDriver(FFDriver):
    """A FakeDriver whose nodes in `ignore_estop` stay in closed loop on Estop (a third-party
    node), and those in `ignore_idle` on an IDLE request too."""

    def __init__(self, *args: Any, **kw: Any) -> None:
        super().__init__(*args, **kw)
        self.ignore_estop: set[int] = set()
        self.ignore_idle: set[int] = set()

    def _idle_except(self, keep: set[int]) -> None:
        self.armed = False
        self._pending_cmd = None
        for r in self.readings:
            if r.node_id not in keep:
                r.axis_state = 1

    def estop(self) -> None:
        self.calls.append("estop")
        self._idle_except(self.ignore_estop)

    def disarm(self) -> None:
        self.calls.append("disarm")
        self._idle_except(self.ignore_idle)


def _stubborn_rig() -> Rig:
    rig = Rig()
    rig.driver = StubbornDriver(rig.driver.node_ids, rig.clock, power_up_turns(rig.cfg))
    rig.ctl = Controller(
        rig.cfg, rig.driver, rig.pub, clock=rig.clock, wall_clock_ns=rig.clock.wall_ns
    )
    rig.arm()
    rig.tick(5)
    return rig


def test_estop_is_confirmed_when_every_axis_leaves_closed_loop() -> None:
    rig = _stubborn_rig()
    rig.ctl.submit(Estop())
    rig.tick(3)
    st = rig.ctl.status()["estop"]
    assert st == {"confirmed": True, "unconfirmed_nodes": [], "repeats": 0}
    assert rig.ctl.reason == "estop"
    rig.tick(int(0.5 * RATE_HZ))
    assert rig.driver.calls.count("estop") == 1 and "disarm" not in rig.driver.calls
    assert rig.ctl.status()["estop"]["repeats"] == 0


def test_estop_ignored_by_a_node_is_repeated_idled_and_reported() -> None:
    from controller.service.loop import ESTOP_CONFIRM_S

    rig = _stubborn_rig()
    bad = rig.ctl.node_ids[2]
    assert isinstance(rig.driver, StubbornDriver)
    rig.driver.ignore_estop = {bad}
    rig.ctl.submit(Estop())
    rig.tick()
    assert rig.state() is State.ESTOPPED and rig.ctl.reason == "estop"
    deadline = int(ESTOP_CONFIRM_S * RATE_HZ)
    rig.tick(deadline - 2)
    assert rig.driver.calls.count("estop") == 1  # still inside the confirmation window
    rig.tick(3)
    reason = str(rig.ctl.reason)
    assert reason.startswith("estop_unconfirmed: ") and f"node {bad} still in closed loop" in reason
    assert f"node {rig.ctl.node_ids[0]} " not in reason
    assert rig.pub.states[-1][:2] == ("ESTOPPED", reason)  # published
    assert rig.driver.calls[-2:] == ["estop", "disarm"]  # Estop again, then IDLE
    # The node obeys IDLE: confirmed at the next heartbeat, and the reason says who was late.
    rig.tick(2)
    st = rig.ctl.status()["estop"]
    assert st["confirmed"] and st["repeats"] == 1 and st["unconfirmed_nodes"] == []
    assert f"node {bad}" in str(rig.ctl.reason) and "confirmed" in str(rig.ctl.reason)
    assert rig.state() is State.ESTOPPED


def test_estop_ignored_for_good_keeps_being_repeated_and_reported() -> None:
    from controller.service.loop import ESTOP_CONFIRM_S

    rig = _stubborn_rig()
    bad = rig.ctl.node_ids[1]
    assert isinstance(rig.driver, StubbornDriver)
    rig.driver.ignore_estop = rig.driver.ignore_idle = {bad}
    rig.ctl.submit(Estop())
    rig.tick(int(3.5 * ESTOP_CONFIRM_S * RATE_HZ))
    st = rig.ctl.status()
    assert st["estop"]["confirmed"] is False
    assert st["estop"]["unconfirmed_nodes"] == [bad]
    assert st["estop"]["repeats"] == 3
    assert rig.driver.calls.count("estop") == 4 and rig.driver.calls.count("disarm") == 3
    assert f"node {bad} still in closed loop" in str(st["reason"])
    # Published once per change of the culprits, not at every repeat.
    assert [s for s, r, _ in rig.pub.states if r and "unconfirmed" in r] == ["ESTOPPED"]
    n = len(rig.driver.commands)
    rig.tick(10)
    assert len(rig.driver.commands) == n


def test_estop_with_a_silent_node_is_reported() -> None:
    rig = _stubborn_rig()
    silent = rig.ctl.node_ids[3]
    rig.driver.heartbeat_silent = {silent}
    rig.ctl.submit(Estop())
    rig.tick(int(0.3 * RATE_HZ))
    assert f"node {silent} silent" in str(rig.ctl.reason)
    assert rig.ctl.status()["estop"]["unconfirmed_nodes"] == [silent]


def test_a_state_and_its_reason_are_published_before_the_controller_reports_them() -> None:
    """Whoever reads `state`/`reason` (another thread) finds them already published: at each
    publication the controller still reports what it reported before."""
    cfg = make_config()
    clock = FakeClock()
    driver = FakeDriver([r.node_id for r in cfg.reels], clock, power_up_turns(cfg))
    seen: list[tuple[str, str | None, str, str | None]] = []

    class Pub(RecordingPublisher):
        def publish_state(self, state: str, reason: str | None, stamp_ns: int) -> None:
            seen.append((state, reason, ctl.state.value, ctl.reason))
            super().publish_state(state, reason, stamp_ns)

    ctl = Controller(cfg, driver, Pub(), clock=clock)
    ctl.submit(Estop())
    ctl.tick(clock.advance(0.004))
    assert ctl.state is State.ESTOPPED
    assert [s[:2] for s in seen] == [("ESTOPPED", ctl.reason)]
    assert all(s[2:] != s[:2] for s in seen), seen
