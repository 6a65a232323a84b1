"""A restarted CiA 402 drive is configured again beside the loop: the SYNC and the other drives'
set-points keep their rate while its SDO exchanges go on, and `arm` is refused by name until it
is done. Simulated drives on a python-can `virtual` bus in one process (the rig of
`test_cia402_driver`); a tap on the bus times the SYNCs.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterator

import can
import pytest

from drivers.base import ArmRefused
from drivers.bus import open_bus
from drivers.cia402 import CiA402Reels
from drivers.cia402.sdo_config import local_mapping
from tests.daemon_procs import udp_bus
from tests.drivers.test_cia402_driver import Rig, poll_until


@pytest.fixture
def rig() -> Iterator[Rig]:
    r = Rig()
    yield r
    r.close()


def _sync_stamps(bus: can.BusABC) -> list[float]:
    out = []
    while (msg := bus.recv(0.0)) is not None:
        if msg.arbitration_id == 0x080:
            out.append(msg.timestamp)
    return out


def test_sync_keeps_its_rate_while_a_restarted_drive_is_configured() -> None:
    rig = Rig(sdo_timeout_s=5.0)  # the held SDO answer comes within its timeout
    try:
        _sync_keeps_its_rate(rig)
    finally:
        rig.close()


def _sync_keeps_its_rate(rig: Rig) -> None:
    rig.armed()
    drv = rig.driver
    held = rig.bank.axis(4)
    held.power_cycle()
    r4 = drv.reading(4)
    assert poll_until(drv, lambda: r4.fault is not None and r4.fault.startswith("restarted"))
    drv.disarm()
    # The drive answers no SDO for a second: on the loop's thread its configuration would
    # stop every SYNC for that long (and fail at its first SDO timeout).
    held.hold_sdo(True)
    while rig.observer.recv(0.0) is not None:
        pass
    with pytest.raises(ArmRefused, match=r"node 4 restarted .* being configured by SDO"):
        drv.arm()
    assert drv.configuring == (4,)
    with pytest.raises(ArmRefused, match=r"node 4 still being configured"):
        drv.arm()  # a second arm meanwhile is refused too, and starts nothing new
    held_s = 1.0
    t_end = time.monotonic() + held_s
    cycles = 0
    while time.monotonic() < t_end:  # the loop: 100 Hz of polls and set-points
        drv.poll()
        drv.command([x.position_rev for x in drv.read()])
        cycles += 1
        time.sleep(0.01)
    stamps = _sync_stamps(rig.observer)
    assert drv.configuring == (4,) and not drv.drive_status(4).configured
    # Every cycle's SYNC went out; no gap beyond what a busy machine's scheduler explains
    # (the configuration would have held the loop for the whole second).
    assert len(stamps) >= cycles >= 20
    gaps = [b - a for a, b in itertools.pairwise(stamps)]
    assert max(gaps) < 0.5 * held_s, max(gaps)
    held.hold_sdo(False)
    assert poll_until(drv, lambda: drv.configuring == () and drv.drive_status(4).configured)
    drv.arm()
    assert poll_until(drv, lambda: all(x.ready for x in rig.r)), [x.state_name for x in rig.r]
    assert r4.fault is None


def test_failed_configuration_is_named_by_the_next_arm(rig: Rig) -> None:
    rig.start()
    rig.bank.axis(2).power_cycle()
    r2 = rig.driver.reading(2)
    assert poll_until(rig.driver, lambda: r2.fault is not None)
    rig.bank.axis(2).silence(True)
    with pytest.raises(ArmRefused, match="node 2"):
        rig.driver.arm()
    # 0.3 s per SDO answer by default: the job fails at its first, beside the loop
    assert poll_until(rig.driver, lambda: rig.driver.configuring == (), 10.0)
    rig.bank.axis(2).silence(False)
    with pytest.raises(ArmRefused, match=r"the last try failed: node 2: .*No SDO response"):
        rig.driver.arm()
    assert poll_until(rig.driver, lambda: rig.driver.configuring == ())
    rig.driver.arm()
    assert poll_until(rig.driver, lambda: all(x.ready for x in rig.r))


def test_another_sync_producer_is_a_named_conflict_on_python_cans_path(rig: Rig) -> None:
    rig.armed()
    drv = rig.driver
    for _ in range(20):  # our own SYNCs: a virtual bus does not hand them back
        drv.poll()
        drv.command([x.position_rev for x in drv.read()])
    assert drv.stats.conflicts == 0
    rig.observer.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
    assert poll_until(drv, lambda: drv.stats.conflicts == 1, 2.0)
    assert "another SYNC producer" in str(drv.stats.last_conflict)
    assert drv.stats.snapshot().conflicts == 1


def test_own_syncs_echoed_by_udp_multicast_are_not_a_conflict() -> None:
    # udp_multicast hands a bus its own frames back: no more SYNCs than were sent are ours.
    table = udp_bus()
    mine = open_bus(table["interface"], table["channel"], **table["options"])
    other = open_bus(table["interface"], table["channel"], **table["options"])
    try:
        drv = CiA402Reels(mine, (1,), counts_per_rev=4096, period_s=0.002)
        d = drv._drives[0]
        drv._use_mapping(d, *local_mapping(d.node, 1, velocity_offset=True, torque=True))
        for _ in range(30):
            drv.command([0.0])
            drv.poll()
        deadline = time.monotonic() + 5.0
        while drv._syncs_heard < 30 and time.monotonic() < deadline:
            drv.poll()
            time.sleep(0.005)
        assert drv._syncs_heard == 30 and drv.stats.conflicts == 0
        other.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
        assert poll_until(drv, lambda: drv.stats.conflicts == 1, 5.0)
    finally:
        mine.shutdown()
        other.shutdown()


@pytest.mark.parametrize("kept", [False, True], ids=["incremental", "absolute"])
def test_a_restart_that_loses_the_count_starts_a_new_count_epoch(rig: Rig, kept: bool) -> None:
    rig.armed()
    drv = rig.driver
    r2 = drv.reading(2)
    assert r2.count_epoch == 0
    before = r2.position_rev
    sim = rig.bank.axis(2)
    sim.power_cycle()
    if kept:
        sim._drift_rev = 0.0  # an absolute encoder: the same position after the restart
    assert poll_until(drv, lambda: r2.fault is not None)
    drv.disarm()
    with pytest.raises(ArmRefused):
        drv.arm()
    assert poll_until(drv, lambda: drv.drive_status(2).configured and r2.stamp_s > 0.0)
    assert poll_until(drv, lambda: r2.position_rev != before or kept, 2.0)
    assert r2.count_epoch == (0 if kept else 1), (r2.position_rev, before)
    assert abs(r2.velocity_rps) < 1.0  # no velocity across the restart
