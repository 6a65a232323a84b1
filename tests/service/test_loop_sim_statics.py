"""The loop in real time against simulated ODrives carrying the payload (physical plant):
measured tensions from Get_Torques follow the planned ones; a slipped cable faults as slack
although the encoders see nothing."""

from __future__ import annotations

import math
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Mapping
from dataclasses import replace
from typing import Any

import pytest

from controller.core.commands import Arm, Move
from controller.core.states import State
from controller.service.loop import Controller
from controller.service.simulated import start_sim_bank
from drivers.bus import open_bus
from drivers.odrive.driver import ODriveReels
from tests.conftest import slow_factor_value
from tests.fakes import RecordingPublisher, make_config

RATE_HZ = 250.0
DEADLINE_SCALE = 4.0 * slow_factor_value()
"""`PhysicalRig.wait` deadlines are the quiet-host figures times this (a loaded host, the VM)."""


class PhysicalRig:
    """The controller in its loop thread and simulated ODrives carrying the payload, on a
    virtual bus of their own; `homing` replaces `[homing]` keys. `drive_limits` are the
    drives' configured (velocity_limit_rps, current_limit_a), the `[drive]` options that let
    the pre-tension lower the velocity limit (None: unknown, the reels wind at the simulated
    drives' own limit)."""

    def __init__(
        self,
        telemetry: str,
        homing: Mapping[str, Any] | None = None,
        *,
        drive_limits: tuple[float, float] | None = None,
    ) -> None:
        channel = f"test-loop-phys-{uuid.uuid4().hex[:8]}"
        cfg = make_config(
            bus={"interface": "virtual", "channel": channel},
            loop={"rate_hz": RATE_HZ, "realtime": False, "torque_telemetry": telemetry},
            # a shared host: generous staleness (see test_loop_sim.py). The simulated drives
            # serve from a thread of this process (one GIL with the loop and the test): on a
            # loaded host they were seen silent for 0.69 s mid-move, a stall of the stand-in
            # for hardware, not of the robot's encoders
            faults={
                "stale_timeout_s": 2.0,
                "heartbeat_timeout_s": 2.0,
                "slack_tension_n": 1.0,
                "slack_time_s": 0.1,
            },
            # Soft cables (k = EA / L ~ 4 kN/m on 48 m): on stiff ones the redundant cable's
            # tension follows millimetres of reel lag, and a stall of the simulation thread on a
            # loaded host (a reel falling behind) slackens a cable mid-move.
            # (the axes' watchdog allows a 3 s stall of the loop thread: a loaded host)
            sim={
                "plant": "physical",
                "torque_period_s": 0.004,
                "cable_ea_n": 2e5,
                "watchdog_timeout_s": 3.0,
                # the tests wait for the effector to come to rest: every mode damped critically
                "cable_damping_ratio": 1.0,
                "effector_damping_n_s_per_m": 5.0,
            },
        )
        self.cfg = replace(cfg, homing=replace(cfg.homing, **homing)) if homing else cfg
        self.sim_bus = open_bus("virtual", channel)
        self.bus = open_bus("virtual", channel)
        self.bank = start_sim_bank(self.cfg, self.sim_bus)
        self.driver = ODriveReels(
            self.bus,
            [r.node_id for r in self.cfg.reels],
            torque_rtr=telemetry == "rtr",
            torque_rtr_period_s=0.01,
            velocity_limit_rps=None if drive_limits is None else drive_limits[0],
            current_limit_a=None if drive_limits is None else drive_limits[1],
        )
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
        """Poll `pred` until it holds (at most `timeout_s` times `DEADLINE_SCALE`: the
        simulated plant runs slower than real time on a loaded host); returns the seconds it
        took."""
        t0 = time.monotonic()
        deadline_s = timeout_s * DEADLINE_SCALE
        while not pred():
            if time.monotonic() - t0 > deadline_s:
                raise AssertionError(f"timed out waiting for {what}: {self.ctl.status()}")
            time.sleep(0.005)
        return time.monotonic() - t0

    def measured(self) -> list[float | None]:
        return list(self.ctl.status()["tensions"]["measured_n"])


@pytest.fixture(params=["cyclic", "rtr"])
def rig(request: pytest.FixtureRequest) -> Iterator[PhysicalRig]:
    r = PhysicalRig(request.param)
    yield r
    r.close()


def test_measured_tensions_follow_the_plan_and_a_slipped_cable_faults_as_slack(
    rig: PhysicalRig,
) -> None:
    rig.wait(lambda: rig.ctl.pose_valid, 3.0, "a valid pose")
    rig.ctl.submit(Arm()).result(timeout=2.0)
    rig.wait(lambda: rig.ctl.state is State.HOLDING, 5.0, "HOLDING")
    rig.wait(lambda: None not in rig.measured(), 2.0, "a torque reading from every axis")
    planned = rig.ctl.status()["tensions"]["planned_n"]
    assert planned == pytest.approx([104.4422] * 4, abs=1e-3)
    assert rig.measured() == pytest.approx(planned, rel=1e-3)
    # a move: the measured tensions follow the planned ones (elastic cables, 5 kg)
    target = (3.0, 2.0, 2.5)
    rig.ctl.submit(Move(target, speed_mps=1.0)).result(timeout=2.0)
    rig.wait(lambda: rig.ctl.state is State.MOVING, 1.0, "MOVING")
    rig.wait(lambda: rig.ctl.state is not State.MOVING, 15.0, "the end of the move")
    assert rig.ctl.state is State.HOLDING, rig.ctl.reason
    planned = rig.ctl.status()["tensions"]["planned_n"]
    rig.wait(
        lambda: rig.measured() == pytest.approx(planned, rel=0.05),
        5.0,
        "measured tensions within 5 % of the planned ones",
    )
    # cable 2 slips 0.5 m on its drum: its encoder sees nothing, its torque does
    plant = rig.bank.coupling
    residual = rig.ctl.residual_m
    plant.slip(1, 0.5)
    rig.wait(lambda: rig.ctl.state is State.FAULT, 3.0, "the slack fault")
    reason = rig.ctl.reason or ""
    assert reason.startswith("slack: cable "), reason
    cable = int(reason.split()[2])
    at_n = float(reason.split()[4])
    assert at_n < 1.0 and plant.tensions_n[cable - 1] < 1.0
    # the geometry sees nothing: the encoders and the FPK residual are unchanged
    assert rig.ctl.residual_m is not None and residual is not None
    assert rig.ctl.residual_m < 1e-4 and residual < 1e-4
    assert math.isfinite(at_n)
