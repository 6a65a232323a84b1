"""The control loop with statics: tension refusals, the per-tick check, planned and measured
tensions in the pose and status, slack and over-tension faults (fake clock, fake driver)."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import pytest

from controller.core.commands import Disarm, Home, Move, Path
from controller.core.states import State
from controller.core.statics import CableStatics, TensionCheck
from controller.service.pose import PoseSample
from tests.fakes import make_config
from tests.service.test_loop import RATE_HZ, FFDriver, Rig

EACH_AT_POWER_UP_N = 104.4422  # 5 kg at (0, 0, 2) m on the paper robot


class TorqueDriver(FFDriver):
    """A fake driver whose axes also report the torque that holds the payload where the
    commanded lengths put it (statics of the commanded pose), scaled per cable by `scale` and
    overridden by `tension_n`; `torque_silent` axes stop reporting."""

    def __init__(self, *args: Any, cfg: Any, **kw: Any) -> None:
        super().__init__(*args, **kw)
        self.cfg = cfg
        self.statics = CableStatics(cfg.anchors_m, 0.0, 1e9)
        self.tension_n: dict[int, float] = {}
        self.torque_silent: set[int] = set()
        self.pose_m: Sequence[float] = cfg.homing.power_up_position_m

    def poll(self) -> int:
        handled = super().poll()
        now = self.clock()
        held = self.statics.solve(self.pose_m, self.cfg.payload.mass_kg).tensions_n
        for i, r in enumerate(self.readings):
            if r.node_id in self.torque_silent:
                continue
            t = self.tension_n.get(i, held[i])
            r.torque_nm = self.cfg.reels[i].reel.torque_nm(r.position_rev, t)
            r.torque_stamp_s = now
        return handled


def telemetry_rig(**faults: Any) -> Rig:
    cfg = make_config(
        loop={"rate_hz": RATE_HZ, "torque_telemetry": "cyclic"},
        faults={"stale_timeout_s": 0.05, "heartbeat_timeout_s": 0.5, **faults},
    )
    rig = Rig(cfg)
    turns = [r.position_rev for r in rig.driver.readings]
    driver = TorqueDriver([r.node_id for r in cfg.reels], rig.clock, turns, cfg=cfg)
    rig.driver = driver
    rig.ctl.driver = driver
    return rig


def test_move_path_stream_and_home_are_refused_where_the_cables_cannot_hold_the_payload() -> None:
    rig = Rig()
    rig.arm()
    # 1 m under the anchors every cable needs 571.6 N (the limit is 500 - 5 N)
    why = rig.refused(Move((0.0, 0.0, 6.6)))
    assert why.startswith("target [0.0000, 0.0000, 6.6000]: cable 1 tension 571.6 N above 495 N"), (
        why
    )
    assert "(limits.max_tension_n 500 N - tension_margin_n 5 N) holding 5 kg" in why
    why = rig.refused(Path(((0.0, 15.0, 6.25), (1.0, 0.0, 2.0))))
    assert why.startswith("points_m[0] [0.0000, 15.0000, 6.2500]: cable 2 tension 596.8 N"), why
    # reaching an infeasible point, a leg crosses the boundary first: the leg is named
    why = rig.refused(Path(((1.0, 0.0, 2.0), (0.0, 15.0, 6.25), (2.0, 0.0, 2.0))))
    assert why.startswith("points_m[1] [0.0000, 15.0000, 6.2500]: on the leg to it: at ["), why
    # both ends can hold it (127 N of margin) but the straight leg between them cannot
    why = rig.refused(Path(((-30.0, 15.0, 6.0), (30.0, 15.0, 6.0))))
    assert why.startswith("points_m[1] [30.0000, 15.0000, 6.0000]: on the leg to it: at ["), why
    assert "above 495 N" in why
    # the first leg, from where the set-point rests, is checked in the tick
    rig.do(Move((-30.0, 15.0, 6.0), speed_mps=2.0))
    rig.until(lambda: rig.state() is State.HOLDING)
    why = rig.refused(Move((30.0, 15.0, 6.0)))
    assert why.startswith("target [30.0000, 15.0000, 6.0000]: on the leg to it from"), why
    assert "above 495 N" in why
    assert rig.state() is State.HOLDING
    # a streamed set-point is refused and counted, with the reason
    rig.ctl.submit_setpoint((0.0, 15.0, 6.25))
    rig.tick()
    assert rig.ctl.stream_refused == 1
    assert (rig.ctl.stream_last_refusal or "").startswith("cable 2 tension 596.8 N above 495 N")
    # home: a pose the cables could not hold the payload at is refused
    why = rig.refused(Home((0.0, 0.0, 6.6)))
    assert why.startswith("home position [0.0000, 0.0000, 6.6000]: cable 1 tension 571.6 N"), why


def test_every_tick_set_point_is_checked_and_a_violation_faults_naming_the_cable() -> None:
    rig = Rig()
    rig.arm()
    rig.do(Move((0.0, 0.0, 5.0), speed_mps=2.0))
    rig.tick(20)
    assert rig.state() is State.MOVING
    # the rule gets stricter under the moving set-point (a heavier load, say): next tick faults
    rig.ctl.tension = TensionCheck(rig.cfg.anchors_m, 25.0, 5.0, 500.0, 5.0, "limits.max_tension_n")
    held = rig.ctl.setpoint_m
    rig.tick()
    assert rig.state() is State.FAULT
    reason = rig.ctl.reason or ""
    assert reason.startswith("tension: set-point ["), reason
    assert "tension" in reason and "above 495 N (limits.max_tension_n 500 N" in reason
    assert "holding 25 kg" in reason
    # FAULT holds the last good set-point
    assert rig.ctl.setpoint_m == held


def test_pose_and_status_carry_the_planned_tensions() -> None:
    rig = Rig()
    rig.arm()
    rig.tick(2)
    sample = rig.pub.poses[-1]
    assert isinstance(sample, PoseSample)
    data = json.loads(sample.to_json_bytes())
    assert data["tensions_n"] == pytest.approx([EACH_AT_POWER_UP_N] * 4, abs=1e-3)
    assert "measured_tensions_n" not in data  # no torque telemetry
    st = rig.ctl.status()["tensions"]
    assert st["planned_n"] == pytest.approx([EACH_AT_POWER_UP_N] * 4, abs=1e-3)
    assert st["planned_margin_n"] == pytest.approx(EACH_AT_POWER_UP_N - 5.0, abs=1e-3)
    assert (st["mass_kg"], st["min_n"], st["max_n"], st["margin_required_n"]) == (
        5.0,
        5.0,
        500.0,
        5.0,
    )
    assert st["measured_n"] is None and st["telemetry"] == "off"
    json.dumps(rig.ctl.status(), allow_nan=False)
    # moving: the planned tensions follow the set-point
    rig.do(Move((10.0, 5.0, 3.0), speed_mps=2.0))
    rig.until(lambda: rig.state() is State.HOLDING)
    rig.tick(2)
    want = CableStatics(rig.cfg.anchors_m, 5.0, 500.0).solve((10.0, 5.0, 3.0), 5.0).tensions_n
    sample = rig.pub.poses[-1]
    assert isinstance(sample, PoseSample)
    assert json.loads(sample.to_json_bytes())["tensions_n"] == pytest.approx(want, rel=1e-9)


def test_without_payload_only_geometry_is_checked() -> None:
    cfg = make_config(loop={"rate_hz": RATE_HZ}, top={"payload": None, "tension": None})
    rig = Rig(cfg)
    rig.arm()
    rig.do(Move((0.0, 0.0, 6.6), speed_mps=2.0))
    rig.until(lambda: rig.state() is State.HOLDING)
    assert rig.ctl.setpoint_m == pytest.approx((0.0, 0.0, 6.6))
    sample = rig.pub.poses[-1]
    assert isinstance(sample, PoseSample)
    assert "tensions_n" not in json.loads(sample.to_json_bytes())
    assert rig.ctl.status()["tensions"] is None


def test_measured_tensions_from_torque_telemetry() -> None:
    rig = telemetry_rig()
    rig.arm()
    rig.tick(3)
    measured = rig.ctl.status()["tensions"]["measured_n"]
    assert measured == pytest.approx([EACH_AT_POWER_UP_N] * 4, abs=1e-3)
    sample = rig.pub.poses[-1]
    assert isinstance(sample, PoseSample)
    data = json.loads(sample.to_json_bytes())
    assert data["measured_tensions_n"] == pytest.approx(measured, rel=1e-12)
    assert rig.state() is State.HOLDING
    # disarmed: the axes are IDLE, no tension is read
    rig.ctl.submit(Disarm())
    rig.tick(2)
    assert rig.ctl.status()["tensions"]["measured_n"] == [None] * 4


def test_a_slack_cable_faults_after_slack_time() -> None:
    rig = telemetry_rig(slack_tension_n=1.0, slack_time_s=0.1)
    rig.arm()
    rig.tick(5)
    assert rig.state() is State.HOLDING
    assert isinstance(rig.driver, TorqueDriver)
    rig.driver.tension_n[1] = 0.3
    rig.tick(round(0.09 * RATE_HZ))  # not yet: shorter than slack_time_s
    assert rig.state() is State.HOLDING
    rig.tick(round(0.02 * RATE_HZ))
    assert rig.state() is State.FAULT
    assert rig.ctl.reason == "slack: cable 2 at 0.3 N"


def test_a_brief_dip_is_no_slack_and_over_tension_faults() -> None:
    rig = telemetry_rig(slack_tension_n=1.0, slack_time_s=0.1)
    rig.arm()
    assert isinstance(rig.driver, TorqueDriver)
    rig.driver.tension_n[2] = 0.2
    rig.tick(round(0.05 * RATE_HZ))
    del rig.driver.tension_n[2]
    rig.tick(round(0.2 * RATE_HZ))
    assert rig.state() is State.HOLDING
    rig.driver.tension_n[0] = 612.0
    rig.tick(round(0.12 * RATE_HZ))
    assert rig.state() is State.FAULT
    assert rig.ctl.reason == "over_tension: cable 1 at 612 N > 500 N"


def test_a_silent_torque_reading_faults_when_armed() -> None:
    rig = telemetry_rig()
    rig.arm()
    rig.tick(30)
    assert isinstance(rig.driver, TorqueDriver)
    node = rig.cfg.reels[3].node_id
    rig.driver.torque_silent.add(node)
    rig.tick(round(0.04 * RATE_HZ))
    assert rig.state() is State.HOLDING
    rig.tick(round(0.02 * RATE_HZ))
    assert rig.state() is State.FAULT
    assert (rig.ctl.reason or "").startswith(f"stale_torque: node {node} age 0.05")


def test_configuration_of_telemetry_and_slack_is_validated() -> None:
    from controller.service.config import paper_robot_data, parse_config

    data = paper_robot_data("t")
    data["faults"]["slack_tension_n"] = 1.0
    data["loop"]["torque_telemetry"] = "poll"
    with pytest.raises(ValueError) as info:
        parse_config(data, "robot.toml")
    msg = str(info.value)
    assert "loop.torque_telemetry: must be one of off, cyclic, rtr, got 'poll'" in msg, msg
    data["loop"]["torque_telemetry"] = "off"
    with pytest.raises(ValueError, match=r"faults\.slack_tension_n: needs measured tensions"):
        parse_config(data, "robot.toml")
    data["loop"]["torque_telemetry"] = "cyclic"  # the built-in robot's sim is kinematic
    with pytest.raises(ValueError, match="with the kinematic simulator"):
        parse_config(data, "robot.toml")
    data["sim"]["plant"] = "physical"
    cfg = parse_config(data, "robot.toml")
    assert (cfg.loop.torque_telemetry, cfg.faults.slack_tension_n) == ("cyclic", 1.0)
    data["faults"]["slack_tension_n"] = 5.0
    with pytest.raises(ValueError, match=r"must be below limits\.min_tension_n"):
        parse_config(data, "robot.toml")
    assert replace(cfg.faults).slack_time_s == 0.1
    assert math.isfinite(cfg.loop.torque_rtr_period_s)


@pytest.mark.parametrize(
    ("start", "v", "axis"),
    [
        ((0.0, 0.0, 2.0), (0.0, 0.0, 2.0), 2),  # straight up: the cables flatten, 495 N first
        ((0.0, 0.0, 6.0), (0.0, 2.0, 0.0), 1),  # along y near the top, into the curved region
    ],
)
def test_velocity_input_stops_short_of_the_tension_limit_without_a_fault(
    start: tuple[float, float, float], v: tuple[float, float, float], axis: int
) -> None:
    rig = Rig()
    rig.arm()
    if math.dist(start, rig.start) > 0.0:
        rig.do(Move(start, speed_mps=2.0))
        rig.until(lambda: rig.state() is State.HOLDING)
    check = rig.ctl.tension
    assert check is not None
    rig.setpoints.clear()
    for _ in range(int(30.0 * 20)):  # a joystick at 20 Hz for 30 s, pushing on
        rig.ctl.submit_velocity(v)
        rig.tick(int(RATE_HZ / 20))
    assert rig.state() is State.MOVING, rig.ctl.reason  # pushing: no fault
    assert all(check.check(p) is None for p in rig.setpoints)
    p = rig.ctl.setpoint_m
    assert p is not None
    assert rig.ctl.workspace.check_target(p) is None
    beyond = list(p)
    beyond[axis] += 0.01
    # stopped by the tensions, within a centimetre of where they forbid it
    assert check.check(beyond) is not None
    assert rig.ctl.workspace.check_target(beyond) is None
    assert rig.ctl.status()["velocity"]["boundary_brakes"] > 0
