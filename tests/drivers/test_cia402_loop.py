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
from typing import Any, cast

import can
import pytest

from controller.core.commands import Arm, Disarm, Estop, Home, Move, Reset
from controller.core.states import State
from controller.service.loop import Controller
from drivers.bus import open_bus
from drivers.cia402 import CiA402Reels
from drivers.cia402.sim import SimCiA402Bank
from tests.conftest import slow_factor_value
from tests.fakes import RecordingPublisher, make_config, power_up_turns

RATE_HZ = 250.0
CPR = 131072


class PausableLink:
    """The simulated drives' side of the bus, pausable as a stopped drive process is: while
    paused their thread stands still at its next receive or send (the host's frames queue up
    for it), and on resume it works through the backlog."""

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self.paused = threading.Event()

    def _hold(self) -> None:
        while self.paused.is_set():  # stopped: nothing runs until it is continued
            time.sleep(0.001)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        self._hold()
        msg = self.bus.recv(timeout)
        if msg is not None and time.time() - msg.timestamp > 0.01:
            time.sleep(0.0002)  # a drive working through a backlog takes its time
        return msg

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._hold()
        self.bus.send(msg, timeout)


FAULTS = {"stale_timeout_s": 1.5, "heartbeat_timeout_s": 3.0, "arm_timeout_s": 10.0}
"""The simulated drives serve from a thread of this process (one GIL with the loop and the
test): on a loaded host they were seen silent for 1 s (stale heartbeats, an arm timing out at
2 s), a stall of the stand-in for hardware. The heartbeat window stays the wider one, so a
silenced drive is named by its encoder first."""
DEADLINE_SCALE = 4.0 * slow_factor_value()
"""`Rig.wait` deadlines are the quiet-host figures times this (a loaded host, the VM)."""


class Rig:
    def __init__(self, heartbeat_period_s: float = 0.1, sdo_timeout_s: float = 0.3) -> None:
        channel = f"test-cia402-loop-{uuid.uuid4().hex[:8]}"
        base = make_config(
            bus={"interface": "virtual", "channel": channel},
            loop={"rate_hz": RATE_HZ, "realtime": False},
            faults=FAULTS,
        )
        reels = tuple(dataclasses.replace(r, node_id=i + 1) for i, r in enumerate(base.reels))
        self.cfg = make_config(
            top={"reels": reels},
            bus={"interface": "virtual", "channel": channel},
            loop={"rate_hz": RATE_HZ, "realtime": False},
            faults=FAULTS,
        )
        self.sim_bus = open_bus("virtual", channel)
        self.bus = open_bus("virtual", channel)
        self.link = PausableLink(self.sim_bus)
        self.bank = SimCiA402Bank(
            cast(can.BusABC, self.link),
            self.cfg.node_ids,
            initial_position_rev=power_up_turns(self.cfg),
            counts_per_rev=CPR,
            max_velocity_rps=float(self.cfg.sim.max_velocity_rps),
            max_accel_rps2=float(self.cfg.sim.max_accel_rps2),
        ).start()
        self.driver = CiA402Reels(
            self.bus,
            self.cfg.node_ids,
            counts_per_rev=CPR,
            period_s=1.0 / RATE_HZ,
            heartbeat_period_s=heartbeat_period_s,
            sdo_timeout_s=sdo_timeout_s,
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
        deadline = time.monotonic() + timeout_s * DEADLINE_SCALE
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
    # every drive obeyed the first Estop: a repeat may follow a heartbeat that came later than
    # the confirmation window on a loaded host, never a drive heard still in closed loop
    reasons = [str(reason) for _, reason, _ in rig.pub.states]
    assert not [r for r in reasons if "still in closed loop" in r], reasons
    if rig.ctl.status()["estop"]["repeats"]:
        assert any("silent (no heartbeat since the Estop)" in r for r in reasons), reasons


def test_silent_drive_gives_stale_fault(rig: Rig) -> None:
    rig.arm()
    rig.bank.axis(3).silence(True)
    rig.wait(lambda: rig.ctl.state is State.FAULT, 2.0, "FAULT")
    assert str(rig.ctl.reason).startswith("stale_encoder: node 3"), rig.ctl.reason


@pytest.fixture
def fast_heartbeat_rig() -> Iterator[Rig]:
    r = Rig(heartbeat_period_s=0.01)
    yield r
    r.close()


def test_an_arm_right_after_a_disarm_is_judged_on_answers_to_it_from_a_late_drive(
    fast_heartbeat_rig: Rig,
) -> None:
    # A drive that answers 150 ms late (its process paused) first sends the statuswords of
    # the cycles before the disarm: the arm must not take them for its confirmation (it would
    # reach HOLDING, then see the drive leave Operation enabled as it works through the
    # disarm, and fault "left closed loop"). Heartbeats every 10 ms: one comes amid the
    # backlog, as a paused drive's overdue heartbeat does.
    rig = fast_heartbeat_rig
    rig.arm()
    ticks = rig.ctl.ticks
    rig.link.paused.set()
    paused_at = time.monotonic()
    rig.wait(lambda: rig.ctl.ticks >= ticks + 3, 2.0, "ticks with the drives paused")
    rig.ctl.submit(Disarm()).result(timeout=2.0)
    ticks = rig.ctl.ticks
    rig.wait(lambda: rig.ctl.ticks >= ticks + 3, 2.0, "cycles carrying the disarm")
    rig.ctl.submit(Arm()).result(timeout=2.0)
    rig.wait(lambda: time.monotonic() - paused_at >= 0.15, 2.0, "a 150 ms pause")
    rig.link.paused.clear()
    rig.wait(lambda: rig.ctl.state is not State.ARMING, 5.0, "the end of arming")
    assert rig.ctl.state is State.HOLDING, rig.ctl.reason
    held_at = time.monotonic()
    while time.monotonic() - held_at < 0.5:  # and it holds on
        assert rig.ctl.state is State.HOLDING, rig.ctl.reason
        time.sleep(0.005)
    assert all(x.ready for x in rig.driver.read())


@pytest.fixture
def patient_rig() -> Iterator[Rig]:
    r = Rig(sdo_timeout_s=10.0)  # a held SDO answer is still awaited when it is released
    yield r
    r.close()


def test_a_restarted_drive_is_configured_beside_the_running_loop(patient_rig: Rig) -> None:
    # The loop keeps ticking (and cycling the other drives) while node 3 is configured again;
    # the arm is refused by name until it is done.
    rig = patient_rig
    rig.arm()
    rig.bank.axis(3).power_cycle()
    rig.wait(lambda: rig.ctl.state is State.FAULT, 2.0, "FAULT")
    assert str(rig.ctl.reason).startswith("axis_error: node 3 restarted"), rig.ctl.reason
    rig.ctl.submit(Reset()).result(timeout=2.0)
    rig.bank.axis(3).hold_sdo(True)
    with pytest.raises(Exception, match=r"not_ready: arm: node 3 restarted .* by SDO beside"):
        rig.ctl.submit(Arm()).result(timeout=2.0)
    ticks = rig.ctl.ticks
    rig.wait(lambda: rig.ctl.ticks >= ticks + 50, 2.0, "ticks while node 3 is configured")
    assert rig.driver.configuring == (3,)
    rig.bank.axis(3).hold_sdo(False)
    rig.wait(lambda: rig.driver.drive_status(3).configured, 5.0, "node 3 configured")
    assert rig.ctl.state is State.DISARMED


def test_another_sync_producer_faults_the_loop_by_name_and_holds_off_the_arm(rig: Rig) -> None:
    rig.arm()
    other = open_bus("virtual", rig.cfg.bus.channel)
    try:
        other.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
        rig.wait(lambda: rig.ctl.state is State.FAULT, 2.0, "FAULT")
        assert str(rig.ctl.reason).startswith("bus_conflict: another SYNC producer"), rig.ctl.reason
        rig.ctl.submit(Reset()).result(timeout=2.0)
        with pytest.raises(Exception, match=r"bus_conflict: another SYNC producer .* s ago"):
            rig.ctl.submit(Arm()).result(timeout=2.0)
        assert rig.ctl.status()["bus"]["conflicts"] == 1
    finally:
        other.shutdown()


def test_a_drive_that_lost_its_count_is_homed_again_before_an_arm(patient_rig: Rig) -> None:
    # The simulated drive's incremental encoder counts from 0 after a restart: the offsets
    # taken before no longer hold. No pose from them, the arm refused by name until `home`.
    rig = patient_rig
    rig.arm()
    held_at = rig.ctl.pose_m
    assert held_at is not None
    rig.bank.axis(3).power_cycle()
    rig.wait(lambda: rig.ctl.state is State.FAULT, 2.0, "FAULT")
    rig.ctl.submit(Reset()).result(timeout=2.0)
    with pytest.raises(Exception, match="not_ready: arm: node 3"):
        rig.ctl.submit(Arm()).result(timeout=2.0)
    rig.wait(lambda: rig.driver.reading(3).count_epoch == 1, 5.0, "node 3's new count")
    rig.wait(lambda: not rig.ctl.pose_valid, 1.0, "no pose from the old offsets")
    with pytest.raises(Exception, match=r"not homed: count_lost: node 3's position count"):
        rig.ctl.submit(Arm()).result(timeout=2.0)
    rig.ctl.submit(Home(held_at)).result(timeout=2.0)
    rig.wait(lambda: rig.ctl.pose_valid, 1.0, "the pose again")
    assert math.dist(rig.ctl.pose_m, held_at) < 1e-6  # type: ignore[arg-type]
    rig.arm()
