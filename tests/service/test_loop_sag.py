"""The control step with heavy cables on an in-memory driver (no bus, a fake clock): a move,
velocity input up against the tension limit, and a held set-point, the pose always the
set-point's when the drives follow exactly."""

from __future__ import annotations

import math

import pytest

from controller.cli.bench.compute import EchoDriver, _Clock
from controller.cli.sag_bench import sag_config
from controller.core import kinematics
from controller.core.commands import Arm, Move
from controller.core.states import State
from controller.service.loop import Controller

PERIOD_S = 0.002


def armed_controller() -> tuple[Controller, _Clock]:
    cfg = sag_config()  # the built-in robot's cables as 3 mm steel rope
    assert cfg.homing.power_up_position_m is not None
    lengths = kinematics.ipk_point(cfg.geometry, cfg.homing.power_up_position_m)
    turns = [r.reel.position_rev(L) for r, L in zip(cfg.reels, lengths, strict=True)]
    clock = _Clock()
    ctl = Controller(cfg, EchoDriver([r.node_id for r in cfg.reels], turns, clock), clock=clock)
    step(ctl, clock, 2)
    ctl.submit(Arm())
    step(ctl, clock, 50)
    assert ctl.state is State.HOLDING, ctl.reason
    return ctl, clock


def step(ctl: Controller, clock: _Clock, n: int) -> None:
    for _ in range(n):
        clock.now_s += PERIOD_S
        ctl.tick(clock.now_s)


def test_a_move_ends_on_the_exact_plan_and_the_pose_is_the_set_point() -> None:
    ctl, clock = armed_controller()
    fut = ctl.submit(Move((3.0, -2.0, 2.5), 1.0))
    step(ctl, clock, 1)
    assert fut.result(timeout=0)["ok"]
    for _ in range(3000):
        step(ctl, clock, 1)
        if ctl.state is State.HOLDING:
            break
    step(ctl, clock, 5)
    assert ctl.state is State.HOLDING, ctl.reason
    assert ctl.setpoint_m == (3.0, -2.0, 2.5)
    assert ctl.pose_m is not None
    assert math.dist(ctl.pose_m, ctl.setpoint_m) < 1e-6
    planner = ctl.cables.sag
    assert planner is not None
    held = planner.planned(position_m=ctl.setpoint_m)
    assert held is not None and held.iterations > 0  # the held set-point's plan is exact
    assert ctl.planned_tensions_n is not None and len(ctl.planned_tensions_n) == 4


def test_velocity_input_brakes_short_of_the_tension_limit() -> None:
    """Flying up under the anchors with a stick held: the look-ahead's tension check with the
    cables' weight brakes the robot to a hold before any cable carries 495 N at its anchor."""
    ctl, clock = armed_controller()
    for _ in range(3000):  # 6 s of stick: up at 1 m/s
        ctl.submit_velocity((0.0, 0.0, 1.0))
        step(ctl, clock, 1)
        assert ctl.state in (State.HOLDING, State.MOVING), ctl.reason
    sp = ctl.setpoint_m
    assert sp is not None and 5.0 < sp[2] < 5.7  # 607 N at (0, 0, 6) m: short of it
    assert ctl.tension is not None and ctl.tension.check(sp) is None
    assert ctl.planned_tensions_n is not None and max(ctl.planned_tensions_n) < 495.0


def test_heavy_cables_plan_the_payloads_m_a_share_while_the_set_point_accelerates() -> None:
    """While the set-point accelerates the planned tensions are the heavy cables' plan at the
    anchors plus the least-norm share of m a (what the shaping's inertia adds for any cable),
    the reels still commanded the plan's paid-out lengths; once held, the plan's tensions
    alone."""
    from controller.core.inertia import inertial_share, with_inertia

    ctl, clock = armed_controller()
    planner = ctl.cables.sag
    assert planner is not None and ctl.tension is not None
    ctl.submit(Move((3.0, -2.0, 2.5), 1.0))
    seen = 0
    for _ in range(400):
        step(ctl, clock, 1)
        acc = ctl.shaping.acceleration_mps2
        sp = ctl.setpoint_m
        lengths = ctl.setpoint_lengths_m
        if sp is None or lengths is None or max(map(abs, acc)) < 0.1:
            continue
        plan = planner.planned(chords_m=lengths)
        assert plan is not None
        share = inertial_share(ctl.geometry.anchors_m, sp, ctl.tension.mass_kg, acc)
        assert share is not None and max(map(abs, share)) > 0.01
        want = with_inertia(plan.anchor_tensions_n, share)
        assert ctl.planned_tensions_n == pytest.approx(want, rel=1e-12, abs=1e-9)
        rev = [r.position_rev(L) for r, L in zip(ctl.reels, plan.paid_out_m, strict=True)]
        assert ctl.commanded_rev == pytest.approx(rev, abs=1e-12)
        seen += 1
    assert seen > 10  # the move accelerated over many ticks
    for _ in range(3000):
        step(ctl, clock, 1)
        if ctl.state is State.HOLDING:
            break
    step(ctl, clock, 5)
    held = planner.planned(position_m=ctl.setpoint_m)
    assert held is not None
    assert max(map(abs, ctl.shaping.acceleration_mps2)) == 0.0
    # no share left; the tensions are the held set-point's plan as made before it was refined
    # to exact (micronewtons apart)
    assert ctl.planned_tensions_n == pytest.approx(held.anchor_tensions_n, abs=1e-3)
