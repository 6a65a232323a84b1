"""Today's control loop, unchanged, driving simulated CiA 402 drives through CiA402Reels.

Controller + CiA402Reels on one `virtual` bus object, SimCiA402Bank on another on the same
channel. The loop runs in its own thread at 250 Hz (the machine is shared); the driver is
configured before the loop starts, as the daemon will do. Every wait has a deadline.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from controller.core.commands import Arm, Estop, Move, Reset
from controller.core.states import State
from controller.service.loop import Controller
from drivers.bus import open_bus
from drivers.cia402 import CiA402Reels
from drivers.cia402.sim import SimCiA402Bank
from tests.fakes import RecordingPublisher, make_config, power_up_turns

RATE_HZ = 250.0
CPR = 131072


class Rig:
    def __init__(self) -> None:
        channel = f"test-cia402-loop-{uuid.uuid4().hex[:8]}"
        base = make_config(
            bus={"interface": "virtual", "channel": channel},
            loop={"rate_hz": RATE_HZ, "realtime": False},
            faults={"stale_timeout_s": 0.5, "heartbeat_timeout_s": 1.0},
        )
        reels = tuple(dataclasses.replace(r, node_id=i + 1) for i, r in enumerate(base.reels))
        self.cfg = make_config(
            top={"reels": reels},
            bus={"interface": "virtual", "channel": channel},
            loop={"rate_hz": RATE_HZ, "realtime": False},
            faults={"stale_timeout_s": 0.5, "heartbeat_timeout_s": 1.0},
        )
        self.sim_bus = open_bus("virtual", channel)
        self.bus = open_bus("virtual", channel)
        self.bank = SimCiA402Bank(
            self.sim_bus,
            self.cfg.node_ids,
            initial_position_rev=power_up_turns(self.cfg),
            counts_per_rev=CPR,
            max_velocity_rps=float(self.cfg.sim.max_velocity_rps),
            max_accel_rps2=float(self.cfg.sim.max_accel_rps2),
        ).start()
        self.driver = CiA402Reels(
            self.bus, self.cfg.node_ids, counts_per_rev=CPR, period_s=1.0 / RATE_HZ
        )
        self.driver.configure()
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

    def wait(self, pred: Callable[[], bool], timeout_s: float, what: str) -> None:
        deadline = time.monotonic() + timeout_s
        while not pred():
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out waiting for {what}: {self.ctl.status()}")
            time.sleep(0.005)

    def arm(self) -> None:
        self.wait(lambda: self.ctl.pose_valid, 3.0, "a valid pose")
        self.ctl.submit(Arm()).result(timeout=2.0)
        self.wait(lambda: self.ctl.state is State.HOLDING, 5.0, "HOLDING")

    @property
    def start(self) -> tuple[float, float, float]:
        p = self.cfg.homing.power_up_position_m
        return (float(p[0]), float(p[1]), float(p[2]))


@pytest.fixture
def rig() -> Iterator[Rig]:
    r = Rig()
    yield r
    r.close()


def test_arm_and_move_half_a_metre_arrives_within_1mm(rig: Rig) -> None:
    rig.arm()
    assert all(x.ready and x.state_name == "Operation enabled" for x in rig.driver.read())
    assert math.dist(rig.ctl.pose_m, rig.start) < 1e-3  # type: ignore[arg-type]
    target = (rig.start[0] + 0.5, rig.start[1] - 0.2, rig.start[2])
    rig.ctl.submit(Move(target, speed_mps=0.5)).result(timeout=2.0)
    rig.wait(lambda: rig.ctl.state is State.MOVING, 1.0, "MOVING")
    rig.wait(lambda: rig.ctl.state is not State.MOVING, 10.0, "the end of the move")
    assert rig.ctl.state is State.HOLDING, rig.ctl.reason
    rig.wait(
        lambda: math.dist(rig.ctl.pose_m, target) < 1e-3,  # type: ignore[arg-type]
        2.0,
        "the FPK pose within 1 mm of the target",
    )
    st: dict[str, Any] = rig.ctl.status()
    assert st["bus"]["decode_errors"] == 0 and st["bus"]["bus_errors"] == 0
    assert rig.pub.state_names()[:4] == ["ARMING", "HOLDING", "MOVING", "HOLDING"]


def test_emcy_faults_the_loop_and_reset_arm_recovers(rig: Rig) -> None:
    rig.arm()
    rig.bank.axis(2).set_error(0x2310)
    rig.wait(lambda: rig.ctl.state is State.FAULT, 2.0, "FAULT")
    assert rig.ctl.reason in (
        "axis_error: node 2 EMCY 0x2310 Continuous over-current (Current)",
        "axis_error: node 2 Fault (no EMCY received)",  # the statusword came before the EMCY
    ), rig.ctl.reason
    assert rig.driver.reading(2).fault == "EMCY 0x2310 Continuous over-current (Current)"
    rig.ctl.submit(Reset()).result(timeout=2.0)
    assert rig.ctl.state is State.DISARMED
    rig.arm()  # the driver's arm resets the drive's fault
    assert rig.driver.reading(2).fault is None


def test_estop_is_confirmed_by_every_drive(rig: Rig) -> None:
    rig.arm()
    rig.ctl.submit(Estop()).result(timeout=1.0)
    assert rig.ctl.state is State.ESTOPPED
    rig.wait(lambda: rig.ctl.status()["estop"]["confirmed"], 2.0, "the e-stop confirmed")
    assert all(d.state.value != "Operation enabled" for d in rig.bank.drives)
    assert rig.ctl.status()["estop"]["repeats"] == 0


def test_silent_drive_gives_stale_fault(rig: Rig) -> None:
    rig.arm()
    rig.bank.axis(3).silence(True)
    rig.wait(lambda: rig.ctl.state is State.FAULT, 2.0, "FAULT")
    assert str(rig.ctl.reason).startswith("stale_encoder: node 3"), rig.ctl.reason
