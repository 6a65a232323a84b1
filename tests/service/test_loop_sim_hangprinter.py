"""The pre-tension and homing of a Hangprinter, whose low lines pull down: the loop in real time
against simulated ODrives carrying the 1 kg effector of config/hangprinter-v4.toml (physical
plant). A low line that slipped off its spool while disarmed lets the effector rise and drift;
the pre-tension winds it in with the statics' tensions in torque control and declares the home
pose where the effector is drawn back to; then the robot moves with every line taut."""

from __future__ import annotations

import math
import threading
import time
import tomllib
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from controller.core.commands import Move, Pretension
from controller.core.states import State
from controller.service.config import parse_config, tension_check
from controller.service.loop import Controller
from controller.service.simulated import start_sim_bank
from drivers.bus import open_bus
from drivers.odrive.driver import ODriveReels
from tests.conftest import slow_factor_value
from tests.fakes import RecordingPublisher

HP4 = Path(__file__).resolve().parents[2] / "config" / "hangprinter-v4.toml"
DEADLINE_SCALE = 4.0 * slow_factor_value()


class HangprinterLoop:
    """The controller in its loop thread and the Hangprinter's simulated ODrives (physical
    plant, Get_Torques every 4 ms) on a virtual bus of their own."""

    def __init__(self) -> None:
        data = tomllib.loads(HP4.read_text())
        channel = f"test-hp-{uuid.uuid4().hex[:8]}"
        data["bus"] = {"interface": "virtual", "channel": channel}
        data["loop"] = {"rate_hz": 250.0, "realtime": False, "torque_telemetry": "cyclic"}
        data["faults"] = {**data["faults"], "stale_timeout_s": 2.0, "heartbeat_timeout_s": 2.0}
        # The test waits for the effector to come to rest, twice: damped like the other rigs
        # that do (ropes critically, a drag of 1/s per kg). In torque control the reels follow
        # their lines, so the ropes' own damping does not act and the file's light drag alone
        # (0.1/s per kg, a frictionless ideal reel) takes over a minute to still the swing.
        data["sim"] = {
            **data["sim"],
            "torque_period_s": 0.004,
            "watchdog_timeout_s": 3.0,
            "cable_damping_ratio": 1.0,
            "effector_damping_n_s_per_m": 1.0,
        }
        data["homing"] = {
            **data["homing"],
            "pretension_still_mps": 0.0005,
            "pretension_settle_s": 1.0,
            "pretension_timeout_s": 60.0,
        }
        self.cfg = parse_config(data, str(HP4))
        self.sim_bus = open_bus("virtual", channel)
        self.bus = open_bus("virtual", channel)
        self.bank = start_sim_bank(self.cfg, self.sim_bus)
        self.driver = ODriveReels(self.bus, [r.node_id for r in self.cfg.reels])
        self.ctl = Controller(self.cfg, self.driver, RecordingPublisher())
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
            if time.monotonic() - t0 > timeout_s * DEADLINE_SCALE:
                raise AssertionError(f"timed out waiting for {what}: {self.ctl.status()}")
            time.sleep(0.005)
        return time.monotonic() - t0


@pytest.fixture
def rig() -> Iterator[HangprinterLoop]:
    r = HangprinterLoop()
    yield r
    r.close()


def test_a_slipped_low_line_is_wound_in_and_the_home_declared(rig: HangprinterLoop) -> None:
    assert rig.cfg.payload is not None and rig.cfg.tension is not None
    assert rig.cfg.homing.power_up_position_m is not None
    home = tuple(float(v) for v in rig.cfg.homing.power_up_position_m)
    rig.wait(lambda: rig.ctl.pose_valid, 10.0, "a valid pose (disarmed: the reels braked)")
    plant = rig.bank.coupling
    want = tension_check(rig.cfg.payload, rig.cfg.tension, rig.cfg.geometry).solve(home)
    # line A pulls down and sideways: the others must pull against it
    assert rig.cfg.geometry.anchors_m[0][2] < home[2] and want.tensions_n[0] > 3.0
    plant.slip(0, 0.03)  # line A slips 3 cm off its spool (effector length: 1.5 cm)
    rig.wait(
        lambda: (
            math.dist(plant.position_m, home) > 0.005
            and math.hypot(*plant.plant.velocity_mps) < 0.005
        ),
        10.0,
        "the effector drifted and at rest",
    )
    reply = rig.ctl.submit(Pretension(home)).result(timeout=2.0)
    assert reply["tensions_n"] == pytest.approx(want.tensions_n, rel=1e-9)
    rig.wait(lambda: rig.ctl.state is not State.PRETENSIONING, 60.0, "the pre-tension")
    assert rig.ctl.state is State.HOLDING, rig.ctl.reason
    assert rig.ctl.status()["pretension"]["result"]["ok"] is True
    assert math.dist(plant.position_m, home) < 0.002, plant.position_m
    assert list(plant.tensions_n) == pytest.approx(want.tensions_n, rel=0.03)
    rig.wait(lambda: rig.ctl.pose_valid, 1.0, "a valid pose")
    assert rig.ctl.pose_m is not None and math.dist(rig.ctl.pose_m, home) < 0.002
    # and it moves, every line taut
    target = (0.2, -0.1, 0.6)
    rig.ctl.submit(Move(target, speed_mps=0.2)).result(timeout=2.0)
    rig.wait(lambda: rig.ctl.state is State.MOVING, 1.0, "MOVING")
    rig.wait(lambda: rig.ctl.state is not State.MOVING, 20.0, "the end of the move")
    assert rig.ctl.state is State.HOLDING, rig.ctl.reason
    rig.wait(lambda: math.dist(plant.position_m, target) < 0.002, 5.0, "the effector at target")
    assert min(plant.tensions_n) > 3.0
