"""`build_stack` for each drive family, with the simulated drives in-process (`[sim] enabled`).

The daemon's builder takes the family from `[drive] kind` through the registry: its driver,
its simulated drives, and for CiA 402 the SDO set-up of every drive before the loop runs (a
drive that does not answer is a start-up error naming it). The loop then arms, moves and
e-stops the drives reading only their generic status. One process, a `virtual` bus; every wait
is a poll with a deadline.
"""

from __future__ import annotations

import math
import threading
import time
import tomllib
import uuid
from collections.abc import Callable
from typing import Any

import pytest

from controller.core.commands import Arm, Estop, Move
from controller.core.states import State
from controller.service.config import RobotConfig, paper_robot_data, parse_config
from controller.service.daemon import build_stack
from tests.service.test_daemon import CIA402_SIM, READY_STATE


def _config(kind: str, **drive: Any) -> RobotConfig:
    """The paper robot (ODrive) or config/cia402-sim.toml (CiA 402) on a private virtual bus,
    simulated in-process, with fault windows for a loaded shared host."""
    if kind == "odrive":
        data = paper_robot_data("t")
    else:
        data = tomllib.loads(CIA402_SIM.read_text())
        data["sim"]["enabled"] = True
    data["drive"] = {**data.get("drive", {}), **drive}
    data["bus"] = {"interface": "virtual", "channel": f"test-drives-{uuid.uuid4().hex}"}
    data["loop"] = {"rate_hz": 250.0, "realtime": False, "gc_freeze": False}
    data["faults"] = {**data["faults"], "stale_timeout_s": 0.25, "tracking_max_m": 0.05}
    return parse_config(data, f"<{kind} test robot>")


def _wait(pred: Callable[[], bool], timeout_s: float, what: str, ctl: Any) -> None:
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}: {ctl.status()}")
        time.sleep(0.005)


@pytest.mark.parametrize("kind", ["odrive", "cia402"])
def test_build_stack_runs_each_family_on_its_simulated_drives(kind: str) -> None:
    cfg = _config(kind)
    stack = build_stack(cfg, zenoh=False)
    stop = threading.Event()
    thread: threading.Thread | None = None
    try:
        driver, ctl = stack.driver, stack.controller
        assert type(driver).__name__ == {"odrive": "ODriveReels", "cia402": "CiA402Reels"}[kind]
        if kind == "cia402":
            # Configured by build_stack, before any loop ran.
            assert all(driver.drive_status(n).configured for n in cfg.node_ids)
        thread = threading.Thread(target=ctl.run, args=(stop,), daemon=True)
        thread.start()
        _wait(lambda: ctl.pose_valid, 5.0, "a valid pose", ctl)
        ctl.submit(Arm()).result(timeout=2.0)
        _wait(lambda: ctl.state is State.HOLDING, 5.0, "HOLDING", ctl)
        axes = ctl.status()["axes"]
        assert [(a["ready"], a["fault"], a["state"]) for a in axes] == [
            (True, None, READY_STATE[kind])
        ] * 4, axes
        start = ctl.pose_m
        assert start is not None
        target = (start[0] + 0.1, start[1], start[2])
        ctl.submit(Move(target, speed_mps=0.2)).result(timeout=2.0)
        _wait(lambda: ctl.state is State.MOVING, 2.0, "MOVING", ctl)
        _wait(lambda: ctl.state is not State.MOVING, 10.0, "the end of the move", ctl)
        assert ctl.state is State.HOLDING, ctl.reason
        _wait(
            lambda: math.dist(ctl.pose_m, target) < 1e-3,  # type: ignore[arg-type]
            2.0,
            "the pose within 1 mm of the target",
            ctl,
        )
        ctl.submit(Estop()).result(timeout=2.0)
        _wait(lambda: ctl.status()["estop"]["confirmed"], 3.0, "the e-stop confirmed", ctl)
        assert not any(a["ready"] for a in ctl.status()["axes"])
    finally:
        stop.set()
        if thread is not None:
            thread.join(2.0)
        stack.close()


def test_build_stack_fails_naming_the_cia402_drive_that_does_not_answer() -> None:
    cfg = _config("cia402", sdo_timeout_s=0.05)
    from dataclasses import replace

    cfg = replace(cfg, sim=replace(cfg.sim, enabled=False))  # nobody answers on the bus
    t0 = time.monotonic()
    with pytest.raises(RuntimeError) as exc:
        build_stack(cfg, zenoh=False)
    assert time.monotonic() - t0 < 2.0  # the first unanswered SDO ends it
    text = str(exc.value)
    assert text.startswith("configuring the CiA 402 drives failed: node 1: 0x1005 COB-ID SYNC:")
    assert "No SDO response" in text
