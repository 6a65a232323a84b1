"""The control step takes a path's appends (`"append": true`): the path in progress goes on
through the new points; an append without a path, with a leg out of the limits, or to a full
queue is refused and changes nothing."""

from __future__ import annotations

import math

from controller.core.commands import Path, Stop
from controller.core.states import State
from tests.service.test_loop import Rig, _target


def test_appends_continue_the_path_in_progress() -> None:
    rig = Rig()
    rig.arm()
    rig.do(Path((_target(rig, 0.2),), speed_mps=0.5))
    assert rig.ctl.state is State.MOVING
    reply = rig.do(Path((_target(rig, 0.4), _target(rig, 0.4, 0.2)), speed_mps=0.5, append=True))
    assert reply["ok"] and reply["points"] == 2 and reply["queued_points"] >= 2
    rig.until(lambda: rig.ctl.state is State.HOLDING)
    assert math.dist(rig.ctl.setpoint_m, _target(rig, 0.4, 0.2)) < 1e-9
    # a path that ran dry takes appends: the robot moves on from where it rests
    rig.do(Path((_target(rig, 0.0, 0.2),), speed_mps=0.5, append=True))
    assert rig.ctl.state is State.MOVING
    rig.until(lambda: rig.ctl.state is State.HOLDING)
    assert math.dist(rig.ctl.setpoint_m, _target(rig, 0.0, 0.2)) < 1e-9


def test_append_without_a_path_or_after_a_stop_is_refused() -> None:
    rig = Rig()
    rig.arm()
    reason = rig.refused(Path((_target(rig, 0.2),), append=True))
    assert "no path in progress" in reason
    rig.do(Path((_target(rig, 2.0),), speed_mps=0.5))
    rig.tick(50)
    rig.do(Stop())
    reason = rig.refused(Path((_target(rig, 0.2),), append=True))
    assert "no path in progress" in reason


def test_append_leg_out_of_the_workspace_is_refused() -> None:
    rig = Rig()
    rig.arm()
    rig.do(Path((_target(rig, 0.2),), speed_mps=0.5))
    below = _target(rig, 0.2, 0.0, -rig.start[2] - 1.0)  # 1 m under the floor
    reason = rig.refused(Path((below,), append=True))
    assert reason.startswith("points_m") or "floor_z_m" in reason, reason
    rig.until(lambda: rig.ctl.state is State.HOLDING)
    assert math.dist(rig.ctl.setpoint_m, _target(rig, 0.2)) < 1e-9  # the path went on alone


def test_append_to_a_full_queue_is_refused_and_taken_later() -> None:
    rig = Rig()
    rig.arm()
    rig.ctl.planner.max_queued_points = 3
    rig.do(Path(tuple(_target(rig, 0.1 * k) for k in range(1, 4)), speed_mps=0.5))
    reason = rig.refused(Path((_target(rig, 0.4),), append=True))
    assert "path queue full" in reason
    rig.until(lambda: rig.ctl.planner.queued_points < 3)
    rig.do(Path((_target(rig, 0.4),), append=True))
    rig.until(lambda: rig.ctl.state is State.HOLDING)
    assert math.dist(rig.ctl.setpoint_m, _target(rig, 0.4)) < 1e-9
