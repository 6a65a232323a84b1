"""The control step sees axes only through their generic status (`ready`, `fault`,
`state_name`): a drive family whose raw numbers mean nothing to the loop arms, faults with its
own names, and confirms an e-stop; the status names every axis's state and fault.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from controller.core.commands import Arm, Estop
from controller.core.states import State
from controller.service.loop import Controller
from drivers.base import AxisReading
from tests.fakes import FakeClock, FakeDriver, RecordingPublisher, make_config, power_up_turns

RATE_HZ = 500.0
DT = 1.0 / RATE_HZ


class GenericDriver(FakeDriver):
    """A FakeDriver for a family of its own: its raw `axis_state` / `axis_error` stay 0 (they
    mean nothing outside that family), only the generic status says how each axis is."""

    def __init__(self, *args: Any, **kw: Any) -> None:
        super().__init__(*args, **kw)
        self.faults: dict[int, str] = {}
        self.not_enabled: set[int] = set()
        """Nodes that report not ready while armed (they left operation on their own)."""
        self.keep_enabled: set[int] = set()
        """Nodes that stay enabled through an e-stop."""
        self.enabled: set[int] = set()

    def read(self) -> Sequence[AxisReading]:
        for r in self.readings:
            r.axis_state = r.axis_error = 0
            r.fault = self.faults.get(r.node_id)
            r.ready = r.node_id in self.enabled and r.fault is None
            r.state_name = "Operation enabled" if r.ready else "Switch on disabled"
        return self.readings

    def poll(self) -> int:
        handled = super().poll()
        if self.armed:
            self.enabled = {n for n in self.node_ids if n not in self.not_enabled}
        return handled

    def arm(self) -> None:
        super().arm()
        self.faults.clear()

    def estop(self) -> None:
        super().estop()
        self.enabled &= self.keep_enabled

    def disarm(self) -> None:
        super().disarm()
        self.enabled = set()


class Rig:
    def __init__(self) -> None:
        self.cfg = make_config(loop={"rate_hz": RATE_HZ})
        self.clock = FakeClock()
        ids = list(self.cfg.node_ids)
        self.driver = GenericDriver(ids, self.clock, power_up_turns(self.cfg))
        self.pub = RecordingPublisher()
        self.ctl = Controller(
            self.cfg, self.driver, self.pub, clock=self.clock, wall_clock_ns=self.clock.wall_ns
        )

    def tick(self, n: int = 1) -> None:
        for _ in range(n):
            self.clock.advance(DT)
            self.ctl.tick(self.clock())

    def arm(self) -> None:
        self.tick(2)
        self.ctl.submit(Arm())
        self.tick(5)
        assert self.ctl.state is State.HOLDING, self.ctl.reason


def test_a_family_known_only_by_its_generic_status_arms_and_holds() -> None:
    rig = Rig()
    rig.arm()
    axes = rig.ctl.status()["axes"]
    assert [(a["ready"], a["fault"], a["state"]) for a in axes] == [
        (True, None, "Operation enabled")
    ] * 4
    assert all((a["axis_state"], a["axis_error"]) == (0, 0) for a in axes)
    rig.tick(50)
    assert rig.ctl.state is State.HOLDING


def test_a_fault_is_named_as_the_drive_names_it() -> None:
    rig = Rig()
    rig.arm()
    node = rig.ctl.node_ids[1]
    rig.driver.faults[node] = "EMCY 0x2310 Continuous over-current (Current)"
    rig.tick()
    assert rig.ctl.state is State.FAULT
    assert rig.ctl.reason == (
        f"axis_error: node {node} EMCY 0x2310 Continuous over-current (Current)"
    )
    st = rig.ctl.status()["axes"][1]
    assert (st["ready"], st["fault"]) == (False, "EMCY 0x2310 Continuous over-current (Current)")


def test_an_axis_that_is_no_longer_ready_names_its_state() -> None:
    rig = Rig()
    rig.arm()
    node = rig.ctl.node_ids[2]
    rig.driver.not_enabled = {node}
    rig.driver.enabled.discard(node)
    rig.tick()
    assert rig.ctl.state is State.FAULT
    assert rig.ctl.reason == f"axis_state: node {node} left closed loop (Switch on disabled)"


def test_arming_times_out_naming_the_state_and_fault_of_each_axis() -> None:
    rig = Rig()
    a, b = rig.ctl.node_ids[0], rig.ctl.node_ids[3]
    rig.driver.not_enabled = {a, b}
    rig.tick(2)
    rig.ctl.submit(Arm())
    rig.tick(3)
    rig.driver.faults[b] = "Fault (no EMCY received)"
    rig.tick(int(rig.cfg.faults.arm_timeout_s * RATE_HZ) + 5)
    assert rig.ctl.state is State.FAULT
    assert rig.ctl.reason == (
        f"arm_timeout: node {a} (Switch on disabled), "
        f"node {b} (Switch on disabled, Fault (no EMCY received))"
    )


def test_estop_is_confirmed_by_readiness_and_a_drive_that_stays_enabled_is_named() -> None:
    rig = Rig()
    rig.arm()
    rig.ctl.submit(Estop())
    rig.tick(3)
    assert rig.ctl.status()["estop"] == {"confirmed": True, "unconfirmed_nodes": [], "repeats": 0}
    rig = Rig()
    rig.arm()
    bad = rig.ctl.node_ids[2]
    rig.driver.keep_enabled = {bad}
    rig.ctl.submit(Estop())
    rig.tick(int(0.25 * RATE_HZ))
    reasons = [str(why) for _, why, _ in rig.pub.states]
    assert any(f"node {bad} still in closed loop (Operation enabled)" in r for r in reasons), (
        reasons
    )
    # The IDLE request sent with the repeated Estop disables it: confirmed, late, by readiness.
    assert rig.ctl.reason == (
        f"estop (confirmed: node {bad} left closed loop only after 1 repeat(s) of Estop and IDLE)"
    )
