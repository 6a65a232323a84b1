"""CiA402Reels against simulated CiA 402 drives on a python-can `virtual` bus, in one process.

Three bus objects on one private channel: the driver's, the simulated drives' and an observer
that hears every frame both send (a virtual bus does not hear its own frames). Every wait is a
poll with a deadline.
"""

from __future__ import annotations

import math
import struct
import time
import uuid
from collections.abc import Callable, Iterator
from typing import Any, cast

import can
import pytest

from drivers.base import NEVER_S, ArmRefused, BusError, ReelDriver
from drivers.bus import open_bus
from drivers.cia402 import CiA402Reels, ConfigureError, busload
from drivers.cia402.profile import DriveState
from drivers.cia402.sim import SimCiA402Bank

NODES = (1, 2, 3, 4)
CPR = 4096
PERIOD_S = 0.002
INITIAL_REV = (0.0, 0.5, -1.25, 2.0)


def poll_until(driver: CiA402Reels, cond: Callable[[], bool], timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        driver.poll()
        if cond():
            return True
        time.sleep(0.001)
    return False


def drain(bus: can.BusABC, quiet_s: float = 0.05, max_s: float = 1.0) -> list[can.Message]:
    """What `bus` receives until it is quiet for `quiet_s` (heartbeats may never pause that
    long: at most `max_s`)."""
    out = []
    deadline = time.monotonic() + max_s
    while time.monotonic() < deadline and (msg := bus.recv(quiet_s)) is not None:
        out.append(msg)
    return out


def frames(msgs: list[can.Message]) -> list[tuple[int, str]]:
    return [(m.arbitration_id, m.data.hex()) for m in msgs]


class Rig:
    def __init__(self, nodes: tuple[int, ...] = NODES, **driver_options: Any) -> None:
        channel = f"test-cia402-{uuid.uuid4().hex}"
        self.sim_bus = open_bus("virtual", channel)
        self.bus = open_bus("virtual", channel)
        self.observer = open_bus("virtual", channel)
        initial = [INITIAL_REV[i % len(INITIAL_REV)] for i in range(len(nodes))]
        self.bank = SimCiA402Bank(
            self.sim_bus, nodes, initial_position_rev=initial, counts_per_rev=CPR
        ).start()
        options: dict[str, Any] = {"counts_per_rev": CPR, "period_s": PERIOD_S}
        options.update(driver_options)
        self.driver = CiA402Reels(self.bus, nodes, **options)
        self.r = self.driver.read()

    def close(self) -> None:
        assert self.bank.stop(timeout_s=2.0)
        for bus in (self.sim_bus, self.bus, self.observer):
            bus.shutdown()

    def start(self) -> None:
        """Configure, then wait for a fresh TPDO and a heartbeat of every drive."""
        self.driver.configure()
        assert poll_until(
            self.driver,
            lambda: all(x.stamp_ns and x.heartbeat_stamp_s > NEVER_S for x in self.r),
        ), [str(x) for x in self.r]

    def armed(self) -> None:
        self.start()
        self.driver.arm()
        assert poll_until(self.driver, lambda: all(x.ready for x in self.r)), [
            x.state_name for x in self.r
        ]


@pytest.fixture
def rig() -> Iterator[Rig]:
    r = Rig()
    yield r
    r.close()


def test_is_a_reel_driver(rig: Rig) -> None:
    assert isinstance(rig.driver, ReelDriver)


def test_constructor_refuses_bad_arguments() -> None:
    bus = cast(Any, object())
    with pytest.raises(ValueError, match=r"1\.\.127"):
        CiA402Reels(bus, [0], counts_per_rev=CPR, period_s=PERIOD_S)
    with pytest.raises(ValueError, match="duplicate"):
        CiA402Reels(bus, [1, 1], counts_per_rev=CPR, period_s=PERIOD_S)
    with pytest.raises(ValueError, match="at least one"):
        CiA402Reels(bus, [], counts_per_rev=CPR, period_s=PERIOD_S)
    with pytest.raises(ValueError, match="counts_per_rev"):
        CiA402Reels(bus, [1], counts_per_rev=math.nan, period_s=PERIOD_S)
    with pytest.raises(ValueError, match="interpolation"):
        CiA402Reels(bus, [1], counts_per_rev=CPR, period_s=1 / 3)
    with pytest.raises(ValueError, match="heartbeat"):
        CiA402Reels(bus, [1], counts_per_rev=CPR, period_s=PERIOD_S, heartbeat_period_s=100.0)


# --- golden frames -----------------------------------------------------------------------------

# Everything the driver sends to configure node 5 (SDO requests 0x605 and NMT 0x000), in order,
# against a drive with the EDS's delivery defaults (RPDO1 and TPDO1/TPDO2 valid, others not).
GOLDEN_STARTUP_NODE_5 = [
    (0x000, "8005"),  # NMT: enter PRE-OPERATIONAL, node 5
    (0x605, "2305100080000000"),  # 0x1005 COB-ID SYNC := 0x80 (consumer)
    (0x605, "2b17100064000000"),  # 0x1017 heartbeat producer time := 100 ms
    (0x605, "2f60600008000000"),  # 0x6060 modes of operation := 8 (CSP)
    (0x605, "2fc2600102000000"),  # 0x60C2:1 interpolation period value := 2
    (0x605, "2fc26002fd000000"),  # 0x60C2:2 interpolation time index := -3 (2 ms)
    (0x605, "4000140100000000"),  # read RPDO1 COB-ID (0x205, valid: same COB-ID, no move)
    (0x605, "2300140105020080"),  # RPDO1 invalid
    (0x605, "2f00140201000000"),  # RPDO1 transmission type 1 (synchronous)
    (0x605, "2f00160000000000"),  # RPDO1 mapping count := 0
    (0x605, "2300160110004060"),  # RPDO1 map 0x6040:00, 16 bits (controlword)
    (0x605, "2300160220007a60"),  # RPDO1 map 0x607A:00, 32 bits (target position)
    (0x605, "2f00160002000000"),  # RPDO1 mapping count := 2
    (0x605, "2300140105020000"),  # RPDO1 valid at 0x205
    (0x605, "4001140100000000"),  # read RPDO2 COB-ID (invalid)
    (0x605, "2301140105030080"),  # RPDO2 COB-ID 0x305, invalid
    (0x605, "2f01140201000000"),  # RPDO2 transmission type 1
    (0x605, "2f01160000000000"),  # RPDO2 mapping count := 0
    (0x605, "230116012000b160"),  # RPDO2 map 0x60B1:00, 32 bits (velocity offset)
    (0x605, "2f01160001000000"),  # RPDO2 mapping count := 1
    (0x605, "2301140105030000"),  # RPDO2 valid at 0x305
    (0x605, "4002140100000000"),  # read RPDO3 COB-ID (invalid: left so)
    (0x605, "4003140100000000"),  # read RPDO4 COB-ID (invalid: left so)
    (0x605, "4000180100000000"),  # read TPDO1 COB-ID (0x185, valid)
    (0x605, "23001801850100c0"),  # TPDO1 invalid, no RTR
    (0x605, "2f00180201000000"),  # TPDO1 transmission type 1 (every SYNC)
    (0x605, "2f001a0000000000"),  # TPDO1 mapping count := 0
    (0x605, "23001a0110004160"),  # TPDO1 map 0x6041:00, 16 bits (statusword)
    (0x605, "23001a0220006460"),  # TPDO1 map 0x6064:00, 32 bits (position actual)
    (0x605, "23001a0310007760"),  # TPDO1 map 0x6077:00, 16 bits (torque actual)
    (0x605, "2f001a0003000000"),  # TPDO1 mapping count := 3
    (0x605, "2300180185010040"),  # TPDO1 valid at 0x185, no RTR
    (0x605, "4001180100000000"),  # read TPDO2 COB-ID (0x285, valid: an event-timer PDO)
    (0x605, "2301180185020080"),  # TPDO2 invalid
    (0x605, "4002180100000000"),  # read TPDO3 COB-ID (invalid)
    (0x605, "4003180100000000"),  # read TPDO4 COB-ID (invalid)
    (0x605, "4061600000000000"),  # read 0x6061 modes of operation display (8)
    (0x000, "0105"),  # NMT: start, node 5
]


def test_golden_startup_sdo_sequence() -> None:
    rig = Rig(nodes=(5,))
    try:
        assert poll_until(rig.driver, lambda: True)  # the boot-up is on the bus
        drain(rig.observer)
        rig.driver.configure()
        sent = [f for f in frames(drain(rig.observer)) if f[0] in (0x000, 0x605)]
        assert sent == GOLDEN_STARTUP_NODE_5
        sim = rig.bank.axis(5)
        assert sim.nmt_state == "OPERATIONAL" and sim.mode == 8
        assert rig.driver.drive_status(5).configured
        # the drive now answers each SYNC with the configured TPDO1 and nothing else
        assert poll_until(rig.driver, lambda: rig.driver.reading(5).stamp_ns != 0)
        later = {f[0] for f in frames(drain(rig.observer, 0.05, 0.3))}
        assert later <= {0x080, 0x185, 0x205, 0x305, 0x705}, later
    finally:
        rig.close()


def test_golden_tick(rig: Rig) -> None:
    rig.armed()
    held = [round(x * CPR) for x in INITIAL_REV]
    assert [round(x.position_rev * CPR) for x in rig.r] == held
    assert poll_until(rig.driver, lambda: all(x.velocity_rps == 0.0 for x in rig.r))
    time.sleep(0.01)
    drain(rig.observer)
    # one tick: the held positions with feed-forward (which the drives apply at this SYNC)
    rig.driver.command([c / CPR for c in held], [0.5, -0.25, 0.0, 1.0])
    got: list[can.Message] = []
    deadline = time.monotonic() + 5.0
    while sum(1 for m in got if 0x181 <= m.arbitration_id <= 0x184) < 4:
        assert time.monotonic() < deadline, frames(got)
        msg = rig.observer.recv(0.1)
        if msg is not None and msg.arbitration_id < 0x700:  # heartbeats aside
            got.append(msg)
    host = [f for f in frames(got) if not 0x181 <= f[0] <= 0x184]
    assert host == [
        (0x201, "0f00" + "00000000"),  # RPDO1 node 1: controlword 0x000F, target 0
        (0x301, "00080000"),  # RPDO2 node 1: velocity offset 2048 (0.5 rev/s)
        (0x202, "0f00" + "00080000"),  # target 2048 (0.5 rev)
        (0x302, "00fcffff"),  # -1024
        (0x203, "0f00" + "00ecffff"),  # target -5120 (-1.25 rev)
        (0x303, "00000000"),
        (0x204, "0f00" + "00200000"),  # target 8192 (2 rev)
        (0x304, "00100000"),  # 4096
        (0x080, ""),  # SYNC
    ]
    drives = sorted(f for f in frames(got) if 0x181 <= f[0] <= 0x184)
    # statusword 0x1237 (Operation enabled, following the target), position, torque 0
    assert drives == [
        (0x181, "3712" + "00000000" + "0000"),
        (0x182, "3712" + "00080000" + "0000"),
        (0x183, "3712" + "00ecffff" + "0000"),
        (0x184, "3712" + "00200000" + "0000"),
    ]


def test_frames_per_tick_and_bus_load(rig: Rig, vcan_report: list[str]) -> None:
    rig.armed()
    targets = [x.position_rev for x in rig.r]
    rig.driver.command(targets)  # the loop's rhythm: poll, command, poll, command, ...
    drain(rig.observer)
    ticks = 200
    for _ in range(ticks):
        rig.driver.poll()
        rig.driver.command(targets, [0.0] * len(NODES))
        time.sleep(PERIOD_S)
    assert poll_until(rig.driver, lambda: True, 0.05)
    seen = drain(rig.observer, 0.2)
    per_kind: dict[str, list[can.Message]] = {"rpdo": [], "sync": [], "tpdo": [], "other": []}
    for m in seen:
        a = m.arbitration_id
        kind = (
            "sync"
            if a == 0x080
            else "rpdo"
            if 0x201 <= a <= 0x304
            else "tpdo"
            if 0x181 <= a <= 0x184
            else "other"
        )
        per_kind[kind].append(m)
    n = len(NODES)
    # command() runs one cycle each; poll() adds none while the loop commands every tick
    assert len(per_kind["sync"]) == ticks
    assert len(per_kind["rpdo"]) == 2 * n * ticks
    assert len(per_kind["tpdo"]) == n * ticks
    assert all(0x701 <= m.arbitration_id <= 0x704 for m in per_kind["other"])  # heartbeats
    frames_per_tick = (len(seen) - len(per_kind["other"])) / ticks
    assert frames_per_tick == 13
    bits = sum(
        busload.frame_bits(m.arbitration_id, bytes(m.data))
        for k in ("rpdo", "sync", "tpdo")
        for m in per_kind[k]
    )
    bits_per_tick = bits / ticks
    worst = n * (busload.worst_case_bits(6) + busload.worst_case_bits(4))
    worst += busload.worst_case_bits(0) + n * busload.worst_case_bits(8)
    assert 9 * 47 + n * (48 + 32 + 64) <= bits_per_tick <= worst
    for rate in (500.0, 1000.0):
        vcan_report.append(
            f"cia402 {n} drives: {frames_per_tick:g} frames/tick, {bits_per_tick:.0f} bits/tick "
            f"(worst case {worst}), bus load at 1 Mbit/s and {rate:g} Hz: "
            f"{100 * busload.bus_load(bits_per_tick, rate):.0f} % "
            f"(worst {100 * busload.bus_load(worst, rate):.0f} %)"
        )


# --- behaviour ---------------------------------------------------------------------------------


def test_arm_holds_then_command_arrives_within_1e_3_rev(rig: Rig) -> None:
    rig.start()
    assert [x.position_rev for x in rig.r] == list(INITIAL_REV)
    assert all(x.state_name == "Switch on disabled" and not x.ready for x in rig.r)
    assert all(x.axis_state == 1 and x.axis_error == 0 and x.fault is None for x in rig.r)
    rig.driver.arm()
    assert poll_until(rig.driver, lambda: all(x.ready for x in rig.r))
    assert all(x.axis_state == 8 and x.state_name == "Operation enabled" for x in rig.r)
    # enabling held every reel where it was
    assert [a.position_rev for a in rig.bank.drives] == list(INITIAL_REV)
    targets = [1.0, -0.75, 0.3, 2.5]
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        rig.driver.poll()
        rig.driver.command(targets)
        if all(abs(x.position_rev - t) < 1e-3 for x, t in zip(rig.r, targets, strict=True)):
            break
        time.sleep(PERIOD_S)
    assert all(abs(x.position_rev - t) < 1e-3 for x, t in zip(rig.r, targets, strict=True)), [
        x.position_rev for x in rig.r
    ]
    # and settles on the count the target rounds to
    assert poll_until(
        rig.driver,
        lambda: all(
            round(a.position_rev * CPR) == round(t * CPR)
            for a, t in zip(rig.bank.drives, targets, strict=True)
        ),
    )
    assert rig.driver.stats.decode_errors == 0 and rig.driver.stats.bus_errors == 0
    rig.driver.disarm()
    assert poll_until(rig.driver, lambda: all(x.state_name == "Switch on disabled" for x in rig.r))
    assert all(not x.ready and x.axis_state == 1 for x in rig.r)


def test_feed_forward_reaches_the_drive(rig: Rig) -> None:
    rig.armed()
    held = [x.position_rev for x in rig.r]
    rig.driver.command(held, [1.5, -2.25, 0.0, 0.001])
    assert poll_until(rig.driver, lambda: rig.bank.axis(2).velocity_offset_units != 0)
    assert [d.velocity_offset_units for d in rig.bank.drives] == [6144, -9216, 0, 4]
    rig.driver.command(held)
    assert poll_until(rig.driver, lambda: rig.bank.axis(2).velocity_offset_units == 0)


def test_estop_quick_stops_every_drive_in_one_cycle(rig: Rig) -> None:
    rig.armed()
    targets = [x.position_rev + 5.0 for x in rig.r]

    def moving() -> bool:  # the set-points stream every period until a reel turns
        rig.driver.command(targets)
        return any(abs(d.velocity_rps) > 1.0 for d in rig.bank.drives)

    assert poll_until(rig.driver, moving, 30.0), [d.velocity_rps for d in rig.bank.drives]
    drain(rig.observer, 0.0, max_s=30.0)  # everything sent before the e-stop
    rig.driver.estop()
    sent = frames(drain(rig.observer, 0.02))
    host = [f for f in sent if f[0] == 0x080 or 0x201 <= f[0] <= 0x304]
    rpdo1 = [f for f in host if 0x201 <= f[0] <= 0x204]
    assert [f[0] for f in rpdo1] == [0x201, 0x202, 0x203, 0x204]
    assert all(f[1].startswith("0200") for f in rpdo1)  # controlword quick stop
    assert host[-1] == (0x080, "")  # one SYNC after every RPDO
    assert poll_until(
        rig.driver,
        lambda: all(x.state_name in ("Quick stop active", "Switch on disabled") for x in rig.r),
        10.0,
    )
    assert all(x.axis_state == 1 and not x.ready for x in rig.r)
    # the drives brake to a stop (quick stop option code 2 then leaves them switch-on-disabled)
    assert poll_until(
        rig.driver, lambda: all(x.state_name == "Switch on disabled" for x in rig.r), 10.0
    )
    assert all(d.velocity_rps == 0.0 for d in rig.bank.drives)
    # the e-stop holds: polls keep sending quick stop, nothing re-enables
    t_end = time.monotonic() + 0.1
    while time.monotonic() < t_end:
        rig.driver.poll()
    assert all(x.state_name == "Switch on disabled" for x in rig.r)
    rig.driver.disarm()
    rig.driver.arm()
    assert poll_until(rig.driver, lambda: all(x.ready for x in rig.r))


def test_emcy_fault_is_named_and_arm_resets_it(rig: Rig) -> None:
    rig.armed()
    rig.bank.axis(2).set_error(0x8611)
    r2 = rig.driver.reading(2)
    assert poll_until(rig.driver, lambda: r2.fault is not None)
    assert r2.fault == "EMCY 0x8611 Following error (Monitoring)"
    assert (r2.state_name, r2.ready, r2.axis_state, r2.axis_error) == ("Fault", False, 1, 0x8611)
    status = rig.driver.drive_status(2)
    assert status.state is DriveState.FAULT and status.emcy_code == 0x8611
    assert status.emcy_register == 0x01
    assert all(x.ready for x in rig.r if x.node_id != 2)
    rig.driver.arm()  # one fault-reset edge, then the state machine up to Operation enabled
    assert poll_until(rig.driver, lambda: r2.ready)
    assert r2.fault is None and r2.axis_error == 0 and r2.state_name == "Operation enabled"
    assert rig.driver.drive_status(2).emcy_code is None  # the drive sent "error reset"
    # an error whose cause stays: the reset edge does not clear it, the fault stays named
    rig.bank.axis(3).set_error(0x4310, persistent=True)
    r3 = rig.driver.reading(3)
    assert poll_until(rig.driver, lambda: r3.fault is not None)
    rig.driver.arm()
    t_end = time.monotonic() + 0.2
    while time.monotonic() < t_end:
        rig.driver.poll()
    assert r3.fault == "EMCY 0x4310 Excess temperature drive (Temperature)" and not r3.ready


def test_silent_drive_heartbeat_and_position_stamps_age(rig: Rig) -> None:
    rig.start()
    rig.bank.axis(3).silence(True)
    time.sleep(0.05)
    poll_until(rig.driver, lambda: False, 0.05)
    r1, r3 = rig.driver.reading(1), rig.driver.reading(3)
    hb3, stamp3 = r3.heartbeat_stamp_s, r3.stamp_s
    hb1 = r1.heartbeat_stamp_s
    poll_until(rig.driver, lambda: False, 0.35)
    assert r3.heartbeat_stamp_s == hb3 and r3.stamp_s == stamp3
    assert r1.heartbeat_stamp_s > hb1  # the others keep beating every 0.1 s
    now = time.monotonic()
    assert r3.heartbeat_age_s(now) > 0.3 and r3.encoder_age_s(now) > 0.3
    rig.bank.axis(3).silence(False)
    assert poll_until(rig.driver, lambda: r3.heartbeat_stamp_s > hb3 and r3.stamp_s > stamp3)


def test_restarted_drive_is_a_fault_until_arm_configures_it_again(rig: Rig) -> None:
    rig.armed()
    rig.bank.axis(4).power_cycle()
    r4 = rig.driver.reading(4)
    assert poll_until(rig.driver, lambda: r4.fault is not None)
    assert r4.fault is not None and r4.fault.startswith("restarted")
    assert (r4.ready, r4.axis_state, r4.axis_error) == (False, 1, 0x1000)
    assert not rig.driver.drive_status(4).configured
    rig.driver.disarm()
    with pytest.raises(ArmRefused, match="node 4 restarted"):
        rig.driver.arm()  # configures node 4 again beside the loop; refused until done
    assert poll_until(rig.driver, lambda: rig.driver.drive_status(4).configured)
    rig.driver.arm()  # enables every drive
    assert poll_until(rig.driver, lambda: all(x.ready for x in rig.r))
    assert r4.fault is None and r4.position_rev == 0.0  # its encoder counts from 0 again


def test_bad_frames_counted_and_never_change_readings(rig: Rig) -> None:
    rig.start()
    r2 = rig.driver.reading(2)
    before = r2.position_rev
    rig.bank.axis(2).send_corrupt(3)
    assert poll_until(rig.driver, lambda: rig.driver.stats.errors_by_kind.get("length", 0) >= 3)
    assert rig.driver.bad_frames(2) == 3 and rig.driver.stats.decode_errors == 3
    assert r2.position_rev == before
    # a heartbeat without its byte, an EMCY of the wrong length, a stranger, an extended id
    for arb, data, ext in (
        (0x702, b"", False),
        (0x082, b"\x10\x43", False),
        (0x7F, b"\x00", False),
        (0x1234, bytes(8), True),
    ):
        rig.observer.send(can.Message(arbitration_id=arb, data=data, is_extended_id=ext))
    assert poll_until(rig.driver, lambda: rig.driver.stats.decode_errors >= 6)
    kinds = rig.driver.stats.errors_by_kind
    assert kinds["length"] == 5 and kinds["extended_id"] == 1
    assert kinds["unknown_cob_id"] >= 1
    assert r2.fault is None and math.isfinite(r2.position_rev)


def test_another_master_stopping_a_drive_makes_it_not_ready(rig: Rig) -> None:
    rig.armed()
    rig.observer.send(can.Message(arbitration_id=0x000, data=[0x80, 3], is_extended_id=False))
    r3 = rig.driver.reading(3)
    assert poll_until(rig.driver, lambda: r3.state_name == "NMT PRE-OPERATIONAL", 2.0)
    assert not r3.ready and r3.axis_state == 1
    assert rig.driver.stats.errors_by_kind.get("not_for_host", 0) >= 1  # the NMT command


def test_command_refuses_bad_values_and_sends_nothing(rig: Rig) -> None:
    rig.start()
    drain(rig.observer, 0.02)
    tx = rig.driver.stats.frames_tx
    with pytest.raises(ValueError, match="4 positions"):
        rig.driver.command([0.0, 0.0])
    with pytest.raises(ValueError, match="feed-forwards"):
        rig.driver.command([0.0] * 4, [0.0])
    with pytest.raises(ValueError, match="node 3"):
        rig.driver.command([0.0, 0.0, math.nan, 0.0])
    with pytest.raises(ValueError, match="32-bit"):
        rig.driver.command([0.0, 1e6, 0.0, 0.0])  # 4.1e9 counts
    with pytest.raises(ValueError, match="not finite"):
        rig.driver.command([0.0] * 4, [0.0, math.inf, 0.0, 0.0])
    assert rig.driver.stats.frames_tx == tx
    assert [m for m in drain(rig.observer, 0.02) if m.arbitration_id < 0x700] == []
    rig.driver.command([0.0] * 4, [1e6, 0.0, 0.0, 0.0])  # 4e9 units/s: clamped, counted
    assert rig.driver.stats.ff_clamped == 1


def test_poll_keeps_readings_fresh_without_commands(rig: Rig) -> None:
    rig.start()
    drain(rig.observer, 0.0)
    stamps = [x.stamp_s for x in rig.r]
    polls = 0
    t_end = time.monotonic() + 0.2
    while time.monotonic() < t_end:
        rig.driver.poll()
        polls += 1
        time.sleep(0.0005)
    syncs = [m for m in drain(rig.observer, 0.02) if m.arbitration_id == 0x080]
    assert all(x.stamp_s > s for x, s in zip(rig.r, stamps, strict=True))
    # at most one cycle per poll, at most one per half period
    assert 0.2 / PERIOD_S / 4 <= len(syncs) <= min(polls, 0.2 / (0.5 * PERIOD_S) + 2)
    assert all(x.velocity_rps == 0.0 for x in rig.r)


def test_configure_names_the_silent_drive_within_bounded_time(rig: Rig) -> None:
    rig.bank.axis(3).silence(True)
    # 0.3 s: a live simulated drive on a loaded host was seen answering later than 50 ms
    sdo_timeout_s = 0.3
    driver = CiA402Reels(
        rig.bus, NODES, counts_per_rev=CPR, period_s=PERIOD_S, sdo_timeout_s=sdo_timeout_s
    )
    t0 = time.monotonic()
    with pytest.raises(ConfigureError, match=r"node 3: 0x1005 COB-ID SYNC: .*No SDO response"):
        driver.configure()
    assert time.monotonic() - t0 < 40 * sdo_timeout_s  # bounded (it was < 2 s at 0.05 s)
    assert driver.drive_status(1).configured and driver.drive_status(2).configured
    assert not driver.drive_status(3).configured


class ExplodingBus:
    """A bus whose receive fails and whose sends to node 2 (and SYNC) fail."""

    def __init__(self) -> None:
        self.sent: list[can.Message] = []

    def recv(self, timeout: float | None = None) -> can.Message | None:
        raise can.CanOperationError("adapter unplugged")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sent.append(msg)
        if msg.arbitration_id == 0x080 or bytes(msg.data[1:2]) == b"\x02":
            raise can.CanOperationError("tx buffer full")


def test_bus_errors_counted_and_raised_after_trying_every_frame() -> None:
    fake = ExplodingBus()
    d = CiA402Reels(cast(Any, fake), [1, 2, 3], counts_per_rev=CPR, period_s=PERIOD_S)
    assert d.poll() == 0
    assert d.stats.bus_errors == 1 and "adapter unplugged" in str(d.stats.last_error)
    with pytest.raises(BusError, match=r"node 2 NMT Stop.*SYNC"):
        d.estop()  # nothing configured yet: NMT Stop to each drive, then the SYNC
    assert [(m.arbitration_id, bytes(m.data)) for m in fake.sent] == [
        (0x000, b"\x02\x01"),
        (0x000, b"\x02\x02"),
        (0x000, b"\x02\x03"),
        (0x080, b""),
    ]
    assert d.stats.bus_errors == 3 and d.stats.frames_tx == 2


def test_poll_is_bounded(rig: Rig) -> None:
    d = CiA402Reels(rig.bus, NODES, counts_per_rev=CPR, period_s=PERIOD_S, max_frames_per_poll=5)
    for _ in range(12):
        rig.observer.send(can.Message(arbitration_id=0x7F, data=b"", is_extended_id=False))
    time.sleep(0.02)
    counts = [d.poll(), d.poll(), d.poll()]
    assert counts[:2] == [5, 5] and counts[2] >= 2


def test_tpdo_layout_without_torque_and_feed_forward() -> None:
    rig = Rig(nodes=(1, 2), velocity_offset=False, torque=False)
    try:
        rig.armed()
        time.sleep(0.01)
        drain(rig.observer)
        rig.driver.command([x.position_rev for x in rig.r])
        got = frames(drain(rig.observer, 0.05))
        cycle = [f for f in got if f[0] < 0x700]
        assert sorted(cycle) == [
            (0x080, ""),
            (0x181, "3712" + "00000000"),
            (0x182, "3712" + "00080000"),
            (0x201, "0f00" + "00000000"),
            (0x202, "0f00" + "00080000"),
        ]
        assert rig.driver.drive_status(1).torque_permille is None
        assert struct.unpack("<Hi", bytes.fromhex("0f0000080000"))[1] == 2048
    finally:
        rig.close()
