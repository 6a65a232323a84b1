"""Input shaping in the control loop, on the simulated physical plant (the truth) through the
real control step (`PlantRig`: deterministic, no threads): a shaped move rings far less and
arrives exactly, the state stays MOVING until the shaped set-point has arrived, and the
`shaper` command changes the shaper at rest."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.cli.bench.vibration import PAPER_EA_N, PlantRig, robot_config, robot_data
from controller.core.commands import CommandRefused, Move, Shaper
from controller.core.motion.shaper import duration_periods
from controller.core.states import State
from controller.service.loop import Controller
from tests.fakes import FakeClock, FakeDriver, make_config

START = (0.0, 0.0, 2.0)


def paper(shaper: dict[str, object] | None, mass_kg: float = 5.0) -> PlantRig:
    return PlantRig(
        robot_config(
            robot_data("paper"),
            mass_kg=mass_kg,
            plant_ea_n=PAPER_EA_N,
            model_ea_n=PAPER_EA_N,
            start_m=START,
            shaper=shaper,
        )
    )


def test_a_shaped_move_rings_twenty_times_less_for_no_more_than_the_shapers_delay() -> None:
    # The case: a 2 m vertical move from (0, 0, 2) at 1 m/s and 1 m/s^2, 5 kg on EA
    # 4.5e5 N ropes damped at 2 %. Paid out for the tensions with m a, the unshaped move leaves
    # about 1 mm of bounce (26 mm with the held tensions alone); shaped, micrometres.
    off = paper(None).move((0.0, 0.0, 4.0), 1.0)
    rig = paper({"type": "2hump_ei"})
    on = rig.move((0.0, 0.0, 4.0), 1.0)
    assert 5e-4 < off.residual_m < 2e-3
    assert on.residual_m * 20.0 < off.residual_m
    assert on.off_line_m < 1e-9  # a vertical move stays on its line
    assert on.duration_s - off.duration_s <= on.shaper_delay_s + 2.0 * rig.period_s
    assert rig.ctl.setpoint_m == (0.0, 0.0, 4.0)  # arrived exactly


def test_shaping_survives_uneven_ticks_on_drives_with_a_position_loop() -> None:
    # The same move through the simulated ODrive's position loop, every tick up to 30 % longer
    # or shorter at random: the shaper reads its past by the ticks' own times, so the shaped
    # move still rings far less (unshaped about 8 mm here, shaped about 0.05 mm).
    def rig(shaper: dict[str, object] | None) -> PlantRig:
        cfg = robot_config(
            robot_data("paper"),
            mass_kg=5.0,
            plant_ea_n=PAPER_EA_N,
            model_ea_n=PAPER_EA_N,
            start_m=START,
            shaper=shaper,
        )
        return PlantRig(cfg, odrive_loop=True, jitter=0.3)

    off = rig(None).move((0.0, 0.0, 4.0), 1.0)
    on = rig({"type": "2hump_ei"}).move((0.0, 0.0, 4.0), 1.0)
    assert off.residual_m > 2e-3
    assert on.residual_m * 20.0 < off.residual_m


def test_two_passes_ring_ten_times_less_where_a_wrong_ea_defeats_one() -> None:
    # The paper robot's worst move with the controller's EA 30 % low (its frequencies 16 % low,
    # its stretch off too): 5 kg from (0, -9, 4.5) 2 m up. One pass of 2-hump EI leaves about a
    # quarter of the unshaped bounce; the train applied twice (the square of its residual
    # curve, twice the delay) under a tenth.
    def rig(shaper: dict[str, object] | None) -> PlantRig:
        cfg = robot_config(
            robot_data("paper"),
            mass_kg=5.0,
            plant_ea_n=PAPER_EA_N,
            model_ea_n=PAPER_EA_N * 0.7,
            start_m=(0.0, -9.0, 4.5),
            shaper=shaper,
            max_tension_n=2500.0,
        )
        return PlantRig(cfg)

    target = (0.0, -9.0, 6.5)
    off = rig(None).move(target, 1.0)
    one = rig({"type": "2hump_ei"}).move(target, 1.0)
    two_rig = rig({"type": "2hump_ei", "passes": 2})
    two = two_rig.move(target, 1.0)
    assert off.residual_m > 5e-3
    assert one.residual_m * 10.0 > off.residual_m  # one pass: not ten times less here
    assert two.residual_m * 10.0 < off.residual_m
    # twice the train: twice the delay, and the move takes no longer than that
    assert two.shaper_delay_s == pytest.approx(2.0 * one.shaper_delay_s, rel=0.05)
    assert two.duration_s - off.duration_s <= two.shaper_delay_s + 2.0 * two_rig.period_s
    assert two.off_line_m < 1e-9
    assert two_rig.ctl.shaping.describe()["passes"] == 2
    assert len(two_rig.ctl.shaping.describe()["frequencies_hz"]) == 3  # one per mode


def test_two_passes_at_a_fixed_frequency_are_the_train_convolved_with_itself() -> None:
    # A step of the planner's set-point through `passes = 2` at a fixed frequency is the step
    # through the train's impulses convolved with themselves (every pair of impulses).
    from controller.core.motion.shaper import impulses
    from controller.service.shaping import LoopShaper

    f_hz = 2.0
    cfg = make_config(shaper={"type": "zvd", "frequency_hz": f_hz, "passes": 2})
    period = 1e-3
    ls = LoopShaper(cfg, period, None)
    amps, times = impulses("zvd", f_hz, 0.02)
    ls.reset((0.0, 0.0, 0.0))
    got = []
    for _ in range(1, 1600):
        got.append(ls.shape((1.0, 0.0, 0.0), (0.0, 0.0, 0.0), period, None, None)[0])
    t = np.arange(1, 1600) * period
    want = np.zeros_like(t)
    for a, ta in zip(amps, times, strict=True):
        for b, tb in zip(amps, times, strict=True):
            want += a * b * (t >= ta + tb - 1e-9)
    # the step reaches the rings one tick in: compare away from the impulses' edges
    edges = np.array([ta + tb for ta in times for tb in times])
    away = np.min(np.abs(t[:, None] - edges[None, :]), axis=1) > 2.5 * period
    assert np.max(np.abs(np.array(got)[away] - want[away])) < 1e-9
    assert ls.describe()["delay_s"] == pytest.approx(2.0 * times[-1], rel=1e-9)
    assert ls.max_delay_s() == pytest.approx(2.0 * times[-1], rel=1e-9)


def test_moving_lasts_until_the_shaped_set_point_has_arrived() -> None:
    rig = paper({"type": "zvd"})
    fut = rig.ctl.submit(Move((1.0, 0.0, 2.0), 1.0))
    rig.tick(1)
    assert fut.result(timeout=0)["ok"] is True
    while rig.ctl.planner.moving:
        rig.tick(1)
    assert rig.ctl.state is State.MOVING  # the planner is there, the shaped set-point not yet
    sp = rig.ctl.setpoint_m
    assert sp is not None and sp[0] < 1.0
    lowest = rig.ctl.shaping.shaper.frequencies_hz[0]
    rig.tick(round(duration_periods("zvd") * 3 / lowest / rig.period_s) + 5)
    assert rig.ctl.state is State.HOLDING
    assert rig.ctl.setpoint_m == (1.0, 0.0, 2.0)


def test_the_shaper_command_applies_at_rest_and_waits_for_the_end_of_a_move() -> None:
    rig = paper({"type": "2hump_ei"})
    ctl = rig.ctl

    def submit(cmd: object) -> dict[str, object]:
        fut = ctl.submit(cmd)  # type: ignore[arg-type]
        rig.tick(1)
        result: dict[str, object] = fut.result(timeout=0)
        return result

    assert submit(Move((0.0, 3.0, 2.0), 1.0))["ok"] is True
    reply = submit(Shaper("zvd", 2.0, 0.05))
    assert reply["applies"] == "at rest"
    st = ctl.status()["shaper"]
    assert st["type"] == "2hump_ei" and st["pending"] == "zvd"
    for _ in range(round(30.0 / rig.period_s)):
        rig.tick(1)
        if ctl.state is State.HOLDING:
            break
    st = ctl.status()["shaper"]
    assert (st["type"], st["frequency_hz"], st["damping_ratio"], st["pending"]) == (
        "zvd",
        2.0,
        0.05,
        None,
    )
    assert submit(Shaper("off"))["applies"] == "now"
    assert ctl.status()["shaper"]["type"] == "off"
    assert submit(Shaper("ei"))["applies"] == "now"  # the model's modes, damping kept
    st = ctl.status()["shaper"]
    assert (st["type"], st["frequency_hz"], st["damping_ratio"]) == ("ei", None, 0.05)


def test_without_a_model_the_shaper_needs_a_frequency() -> None:
    cfg = make_config()  # the built-in robot: rigid cables
    assert cfg.shaper.type == "off"
    clock = FakeClock()
    ctl = Controller(cfg, FakeDriver(cfg.node_ids, clock), clock=clock)
    fut = ctl.submit(Shaper("ei"))
    ctl.tick(1000.0)
    exc = fut.exception(timeout=0)
    assert isinstance(exc, CommandRefused)
    assert "shaper: no model of the modes" in str(exc) and "give a frequency" in str(exc)
    fut = ctl.submit(Shaper("zvd", 1.5))
    ctl.tick(1000.002)
    assert fut.result(timeout=0)["shaper"]["frequencies_hz"] == []  # not shaped a tick yet
    assert ctl.status()["shaper"]["type"] == "zvd"
    assert math.isfinite(ctl.brake_time_s())


def test_a_bad_shaper_configuration_is_refused_by_the_loop() -> None:
    from dataclasses import replace

    cfg = make_config()
    bad = replace(cfg, shaper=replace(cfg.shaper, type="ei"))  # no model, no frequency
    with pytest.raises(ValueError, match="shaper: no model of the modes"):
        Controller(bad, FakeDriver(cfg.node_ids, FakeClock()))


def test_the_planned_tensions_accelerate_the_payload() -> None:
    # Unshaped, the set-point accelerates at 1 m/s^2 along +x: the cables pull m (g + a).
    from controller.core.statics import G_MPS2

    rig = paper(None)
    fut = rig.ctl.submit(Move((2.0, 0.0, 2.0), 1.0))
    rig.tick(5)
    assert fut.result(timeout=0)["ok"] is True
    st = rig.ctl.status()
    t = np.asarray(st["tensions"]["planned_n"])
    p = np.asarray(st["setpoint_m"])
    d = np.asarray(rig.cfg.anchors_m) - p
    u = d / np.linalg.norm(d, axis=1)[:, None]
    assert t @ u == pytest.approx([5.0 * 1.0, 0.0, 5.0 * G_MPS2], abs=1e-6)
    while rig.ctl.state is State.MOVING:
        rig.tick(1)
    rig.tick(2)
    st = rig.ctl.status()  # at rest: the weight alone
    t = np.asarray(st["tensions"]["planned_n"])
    d = np.asarray(rig.cfg.anchors_m) - np.asarray(st["setpoint_m"])
    u = d / np.linalg.norm(d, axis=1)[:, None]
    assert t @ u == pytest.approx([0.0, 0.0, 5.0 * G_MPS2], abs=1e-9)
