"""The pre-tension in real time against simulated ODrives carrying the payload (physical
plant): cables that slipped while the robot was disarmed are taken up in torque control, and
the home pose is declared where the effector really is; then the robot moves as usual."""

from __future__ import annotations

import math
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import replace

import pytest

from controller.core.commands import Move, Pretension
from controller.core.states import State
from controller.service.config import tension_check
from controller.service.loop import Controller
from controller.service.simulated import start_sim_bank
from drivers.bus import open_bus
from drivers.odrive.driver import ODriveReels
from tests.fakes import RecordingPublisher, make_config

RATE_HZ = 250.0


class PhysicalRig:
    def __init__(self) -> None:
        channel = f"test-loop-pretension-{uuid.uuid4().hex[:8]}"
        cfg = make_config(
            bus={"interface": "virtual", "channel": channel},
            loop={"rate_hz": RATE_HZ, "realtime": False, "torque_telemetry": "cyclic"},
            # a shared host: generous staleness (see test_loop_sim.py)
            faults={
                "stale_timeout_s": 0.5,
                "heartbeat_timeout_s": 1.0,
                "slack_tension_n": 1.0,
                "slack_time_s": 0.1,
            },
            sim={
                "plant": "physical",
                "torque_period_s": 0.004,
                "cable_ea_n": 2e5,
                "watchdog_timeout_s": 1.0,
            },
        )
        # Stillness to 0.2 mm/s of cable for 3 s: the effector's vertical bounce on the paper
        # robot's long flat cables (period about 5 s) shows in the cables at an eighth of it.
        self.cfg = replace(
            cfg,
            homing=replace(
                cfg.homing,
                pretension_still_mps=0.0002,
                pretension_settle_s=3.0,
                pretension_timeout_s=60.0,
            ),
        )
        self.sim_bus = open_bus("virtual", channel)
        self.bus = open_bus("virtual", channel)
        self.bank = start_sim_bank(self.cfg, self.sim_bus)
        self.driver = ODriveReels(self.bus, [r.node_id for r in self.cfg.reels])
        self.pub = RecordingPublisher()
        self.ctl = Controller(self.cfg, self.driver, self.pub)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.ctl.run, args=(self.stop,), daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.stop.set()
        self.thread.join(2.0)
        self.bank.stop()
        self.bus.shutdown()
        self.sim_bus.shutdown()

    def wait(self, pred: Callable[[], bool], timeout_s: float, what: str) -> float:
        t0 = time.monotonic()
        while not pred():
            if time.monotonic() - t0 > timeout_s:
                raise AssertionError(f"timed out waiting for {what}: {self.ctl.status()}")
            time.sleep(0.01)
        return time.monotonic() - t0


@pytest.fixture
def rig() -> Iterator[PhysicalRig]:
    r = PhysicalRig()
    yield r
    r.close()


def test_slipped_cables_are_taken_up_and_the_home_is_declared_where_the_effector_is(
    rig: PhysicalRig,
) -> None:
    home = tuple(float(v) for v in rig.cfg.homing.power_up_position_m)
    rig.wait(lambda: rig.ctl.pose_valid, 3.0, "a valid pose")
    plant = rig.bank.coupling
    statics = tension_check(rig.cfg.payload, rig.cfg.tension, rig.cfg.geometry)
    want = statics.solve(home).tensions_n
    # Disarmed (the reels braked), cables 2 and 4 slip 5 and 3 cm off their drums: the
    # effector drops onto the others, and the encoders see nothing.
    plant.slip(1, 0.05)
    plant.slip(3, 0.03)
    rig.wait(
        lambda: (
            math.dist(plant.position_m, home) > 0.01
            and math.hypot(*plant.plant.velocity_mps) < 0.01
            and min(plant.tensions_n) < 1.0
        ),
        10.0,
        "the effector fallen onto the other cables, a slack one",
    )
    assert rig.ctl.pose_m is not None and math.dist(rig.ctl.pose_m, home) < 1e-6
    print(f"after the slips the effector is at {plant.position_m}, tensions {plant.tensions_n}")

    reply = rig.ctl.submit(Pretension(home)).result(timeout=2.0)
    assert reply["tensions_n"] == pytest.approx(want, rel=1e-9)
    assert rig.ctl.state is State.PRETENSIONING
    took = rig.wait(lambda: rig.ctl.state is not State.PRETENSIONING, 60.0, "the pre-tension")
    assert rig.ctl.state is State.HOLDING, rig.ctl.reason
    assert rig.ctl.home_source == "pretension"
    result = rig.ctl.status()["pretension"]["result"]
    assert result["ok"] is True
    # the slipped cables were wound in and the effector drawn back to the home pose
    assert math.dist(plant.position_m, home) < 0.002, plant.position_m
    assert list(plant.tensions_n) == pytest.approx(want, rel=0.02)
    rig.wait(lambda: rig.ctl.pose_valid, 1.0, "a valid pose")
    assert rig.ctl.pose_m is not None and math.dist(rig.ctl.pose_m, home) < 0.002
    assert rig.ctl.residual_m is not None and rig.ctl.residual_m < 0.002
    print(f"pre-tension: still after {result['still_after_s']:.2f} s ({took:.2f} s wall)")

    # and the robot moves as usual: the cables stay taut, no slack fault
    target = (home[0] + 1.0, home[1] + 0.5, home[2] + 0.3)
    rig.ctl.submit(Move(target, speed_mps=0.5)).result(timeout=2.0)
    rig.wait(lambda: rig.ctl.state is State.MOVING, 1.0, "MOVING")
    rig.wait(lambda: rig.ctl.state is not State.MOVING, 15.0, "the end of the move")
    assert rig.ctl.state is State.HOLDING, rig.ctl.reason
    rig.wait(lambda: math.dist(plant.position_m, target) < 0.005, 5.0, "the effector at target")
    planned = rig.ctl.status()["tensions"]["planned_n"]
    rig.wait(
        lambda: list(plant.tensions_n) == pytest.approx(planned, rel=0.05),
        5.0,
        "the tensions of the plan",
    )


def test_a_reel_with_nothing_on_it_winds_until_the_travel_limit_faults(
    rig: PhysicalRig,
) -> None:
    home = tuple(float(v) for v in rig.cfg.homing.power_up_position_m)
    rig.wait(lambda: rig.ctl.pose_valid, 3.0, "a valid pose")
    plant = rig.bank.coupling
    plant.slip(2, 5.0)  # cable 3 is off its drum: its reel turns and nothing pulls back
    rig.ctl.submit(Pretension(home)).result(timeout=2.0)
    rig.wait(lambda: rig.ctl.state is not State.PRETENSIONING, 60.0, "the end of the pre-tension")
    assert rig.ctl.state is State.FAULT
    reason = rig.ctl.reason or ""
    assert reason.startswith("pretension: cable 3 moved 0.5"), reason
    # the drives hold where the reels are, in position control
    axes = [rig.bank.axis(n) for n in rig.ctl.node_ids]
    rig.wait(lambda: all(a.control_mode == 3 for a in axes), 1.0, "position control on every axis")
