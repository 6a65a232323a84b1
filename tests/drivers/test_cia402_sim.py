"""The simulated CiA 402 drive on its own (no bus): NMT, SDO-side PDO rules, SYNC-driven
PDOs, the state machine, motion and fault injection."""

from __future__ import annotations

import itertools
import struct

import pytest
from canopen.sdo.exceptions import SdoAbortedError

from drivers.cia402.profile import DriveState
from drivers.cia402.sim import Frame, SimCiA402Drive

S = DriveState
DT = 0.001
NODE = 3
CPR = 4096


def booted(node_id: int = NODE, **options: object) -> SimCiA402Drive:
    """A drive past its boot-up message."""
    drive = SimCiA402Drive(node_id, **options)  # type: ignore[arg-type]
    assert drive.step(0.0) == [(0x700 + node_id, b"\x00")]
    return drive


def run(drive: SimCiA402Drive, seconds: float) -> list[Frame]:
    out: list[Frame] = []
    for _ in range(round(seconds / DT)):
        out.extend(drive.step(DT))
    return out


def sdo_write(drive: SimCiA402Drive, index: int, sub: int, value: int, fmt: str) -> None:
    """Write as the SDO server does (writability checked)."""
    drive.node.set_data(index, sub, struct.pack(fmt, value), check_writable=True)


def cw(drive: SimCiA402Drive, word: int) -> None:
    sdo_write(drive, 0x6040, 0, word, "<H")


def enable(drive: SimCiA402Drive) -> None:
    for word in (0x06, 0x07, 0x0F):
        cw(drive, word)
    assert drive.state is S.OPERATION_ENABLED


def start(drive: SimCiA402Drive) -> list[Frame]:
    return drive.handle(0x000, bytes([0x01, NODE]))


def map_pdo(drive: SimCiA402Drive, comm: int, cob: int, tt: int, entries: list[int]) -> None:
    """Configure one PDO in the order CiA 301 asks for."""
    mapping = comm + 0x200
    sdo_write(drive, comm, 1, cob | 0x80000000, "<I")
    sdo_write(drive, comm, 2, tt, "<B")
    sdo_write(drive, mapping, 0, 0, "<B")
    for i, e in enumerate(entries, 1):
        sdo_write(drive, mapping, i, e, "<I")
    sdo_write(drive, mapping, 0, len(entries), "<B")
    sdo_write(drive, comm, 1, cob, "<I")


def test_power_up_boot_up_then_pre_operational() -> None:
    drive = SimCiA402Drive(NODE)
    assert drive.step(DT) == [(0x700 + NODE, b"\x00")]  # boot-up
    assert drive.nmt_state == "PRE-OPERATIONAL"
    assert drive.state is S.SWITCH_ON_DISABLED and drive.statusword == 0x0240
    assert run(drive, 1.0) == []  # heartbeat producer time defaults to 0: off
    sdo_write(drive, 0x1017, 0, 100, "<H")
    beats = [f for f in run(drive, 1.0) if f[0] == 0x700 + NODE]
    assert 9 <= len(beats) <= 11 and beats[0] == (0x700 + NODE, b"\x7f")
    start(drive)
    assert [f for f in run(drive, 0.2) if f[0] == 0x700 + NODE][-1] == (0x703, b"\x05")


def test_sdo_requests_answered_through_canopen() -> None:
    drive = booted()
    # expedited upload of 0x6041 (statusword) and download of 0x6060 = 8
    assert drive.handle(0x600 + NODE, bytes.fromhex("4041600000000000")) == [
        (0x580 + NODE, bytes.fromhex("4b41600040020000"))
    ]
    assert drive.handle(0x600 + NODE, bytes.fromhex("2f60600008000000")) == [
        (0x580 + NODE, bytes.fromhex("6060600000000000"))
    ]
    assert drive.mode == 8
    # a mode the drive does not support is refused: value range exceeded
    (answer,) = drive.handle(0x600 + NODE, bytes.fromhex("2f60600009000000"))
    assert answer == (0x580 + NODE, bytes.fromhex("8060600030000906"))
    assert drive.mode == 8
    # frames for another node are not ours
    assert drive.handle(0x600 + NODE + 1, bytes.fromhex("4041600000000000")) == []


def test_pdo_mapping_rules_of_a_drive() -> None:
    drive = SimCiA402Drive(NODE)
    # the mapping of a valid PDO cannot change
    with pytest.raises(SdoAbortedError) as exc:
        sdo_write(drive, 0x1A00, 0, 0, "<B")
    assert exc.value.code == 0x08000022
    sdo_write(drive, 0x1800, 1, 0x80000183, "<I")
    # entries only while the count is 0
    with pytest.raises(SdoAbortedError) as exc:
        sdo_write(drive, 0x1A00, 1, 0x60640020, "<I")
    assert exc.value.code == 0x08000022
    sdo_write(drive, 0x1A00, 0, 0, "<B")
    with pytest.raises(SdoAbortedError) as exc:  # the heartbeat time is not mappable
        sdo_write(drive, 0x1A00, 1, 0x10170010, "<I")
    assert exc.value.code == 0x06040041
    with pytest.raises(SdoAbortedError) as exc:  # wrong length for 0x6064 (32 bits)
        sdo_write(drive, 0x1A00, 1, 0x60640010, "<I")
    assert exc.value.code == 0x06040041
    for i in range(1, 4):
        sdo_write(drive, 0x1A00, i, 0x60640020, "<I")
    with pytest.raises(SdoAbortedError) as exc:  # 96 bits
        sdo_write(drive, 0x1A00, 0, 3, "<B")
    assert exc.value.code == 0x06040042
    sdo_write(drive, 0x1A00, 0, 2, "<B")
    # a valid PDO keeps its COB-ID
    sdo_write(drive, 0x1800, 1, 0x183, "<I")
    with pytest.raises(SdoAbortedError) as exc:
        sdo_write(drive, 0x1800, 1, 0x190, "<I")
    assert exc.value.code == 0x08000022
    # an RPDO maps only what can be written
    sdo_write(drive, 0x1400, 1, 0x80000203, "<I")
    sdo_write(drive, 0x1600, 0, 0, "<B")
    with pytest.raises(SdoAbortedError) as exc:
        sdo_write(drive, 0x1600, 1, 0x60410010, "<I")
    assert exc.value.code == 0x06040041


def test_sync_applies_rpdos_then_answers_with_tpdos() -> None:
    drive = booted(counts_per_rev=CPR, initial_position_rev=0.5)
    map_pdo(drive, 0x1400, 0x203, 1, [0x60400010, 0x607A0020])
    map_pdo(drive, 0x1800, 0x183, 1, [0x60410010, 0x60640020, 0x60770010])
    sdo_write(drive, 0x1801, 1, 0x80000283, "<I")  # the default TPDO2 off
    sdo_write(drive, 0x6060, 0, 8, "<b")
    sync = (0x080, b"")
    assert drive.handle(*sync) == []  # PRE-OPERATIONAL: no PDOs
    start(drive)
    assert drive.handle(*sync) == [(0x183, struct.pack("<Hih", 0x0240, 2048, 0))]
    # an RPDO waits for the next SYNC; the statusword answers it in the same cycle
    assert drive.handle(0x203, struct.pack("<Hi", 0x06, 2048)) == []
    assert drive.state is S.SWITCH_ON_DISABLED
    assert drive.handle(*sync) == [(0x183, struct.pack("<Hih", 0x0231, 2048, 0))]
    drive.handle(0x203, struct.pack("<Hi", 0x0F, 2048))
    assert drive.handle(*sync) == [(0x183, struct.pack("<Hih", 0x1237, 2048, 0))]
    assert drive.rpdos_applied == 2
    # a short RPDO is not processed: EMCY 0x8210
    drive.handle(0x203, b"\x0f\x00")
    assert (0x080 + NODE, struct.pack("<HB5s", 0x8210, 0x11, b"")) in drive.handle(*sync)
    assert drive.rpdos_applied == 2
    # the drive's own event-timer TPDO, when enabled, runs every 10 ms in OPERATIONAL
    sdo_write(drive, 0x1801, 1, 0x283, "<I")
    tpdo2 = [f for f in run(drive, 0.1) if f[0] == 0x283]
    assert 9 <= len(tpdo2) <= 11


def _configured(sync_cob: int) -> SimCiA402Drive:
    drive = booted(counts_per_rev=CPR)
    map_pdo(drive, 0x1400, 0x203, 1, [0x60400010, 0x607A0020])
    map_pdo(drive, 0x1800, 0x183, 1, [0x60410010, 0x60640020])
    sdo_write(drive, 0x1005, 0, sync_cob, "<I")
    sdo_write(drive, 0x6060, 0, 8, "<b")
    start(drive)
    return drive


def _observed(drive: SimCiA402Drive) -> tuple[object, ...]:
    return (
        drive.state,
        drive.nmt_state,
        drive.target_counts,
        drive.velocity_offset_units,
        drive.syncs_received,
        drive.rpdos_applied,
        drive.mode,
        drive.statusword,
        drive.position_rev,
    )


def test_a_drive_hears_its_frames_and_every_frame_it_does_not_hear_does_nothing() -> None:
    """`hears` lets a bank skip a drive for a frame: it must be True for every frame that could
    change the drive or draw an answer. Checked on every 11-bit id against a twin drive."""
    drive, twin = _configured(0x085), _configured(0x085)
    for heard in (0x085, 0x203, 0x600 + NODE, 0x000):
        assert drive.hears(heard), hex(heard)
    for other in (0x080, 0x204, 0x183, 0x700 + NODE, 0x601, 0x580 + NODE):
        assert not drive.hears(other), hex(other)
    before = _observed(twin)
    payload = struct.pack("<Hi", 0x0F, 4096)
    for arb_id in range(0x800):
        if not drive.hears(arb_id):
            assert twin.handle(arb_id, payload) == [], hex(arb_id)
            assert twin.handle(arb_id, b"") == [], hex(arb_id)
    assert _observed(twin) == before
    twin.handle(0x203, payload)
    drive.handle(0x203, payload)
    assert twin.handle(0x085, b"") == drive.handle(0x085, b"") != []
    assert _observed(twin) == _observed(drive)


def test_state_machine_transitions() -> None:
    drive = SimCiA402Drive(NODE)
    cw(drive, 0x0F)  # enable from switch on disabled: not a transition
    assert drive.state is S.SWITCH_ON_DISABLED
    cw(drive, 0x06)
    assert drive.state is S.READY_TO_SWITCH_ON
    cw(drive, 0x0F)  # 3 + 4
    assert drive.state is S.OPERATION_ENABLED
    cw(drive, 0x07)  # 5: disable operation
    assert drive.state is S.SWITCHED_ON
    cw(drive, 0x06)  # 6
    assert drive.state is S.READY_TO_SWITCH_ON
    cw(drive, 0x02)  # 7: quick stop
    assert drive.state is S.SWITCH_ON_DISABLED
    enable(drive)
    cw(drive, 0x06)  # 8
    assert drive.state is S.READY_TO_SWITCH_ON
    enable(drive)
    cw(drive, 0x00)  # 9
    assert drive.state is S.SWITCH_ON_DISABLED


def test_quick_stop_brakes_then_option_code_decides() -> None:
    drive = SimCiA402Drive(NODE, max_velocity_rps=10.0, max_accel_rps2=50.0, counts_per_rev=CPR)
    sdo_write(drive, 0x6060, 0, 8, "<b")
    enable(drive)
    sdo_write(drive, 0x607A, 0, 100 * CPR, "<i")
    run(drive, 0.5)
    assert drive.velocity_rps == pytest.approx(10.0)
    cw(drive, 0x02)  # 11
    assert drive.state is S.QUICK_STOP_ACTIVE and drive.statusword == 0x0217
    run(drive, 0.1)
    assert drive.velocity_rps == pytest.approx(5.0, abs=0.06)  # braking at 50 rev/s^2
    assert drive.torque_permille == -1000
    run(drive, 0.2)
    assert drive.velocity_rps == 0.0
    assert drive.state is S.SWITCH_ON_DISABLED  # option code 2 (the default)
    # option code 6: stay in quick stop active, holding; enable operation resumes (16)
    sdo_write(drive, 0x605A, 0, 6, "<h")
    enable(drive)
    cw(drive, 0x02)
    run(drive, 0.5)
    assert drive.state is S.QUICK_STOP_ACTIVE
    cw(drive, 0x0F)
    assert drive.state is S.OPERATION_ENABLED


def test_csp_follows_target_within_limits_and_feed_forward() -> None:
    vmax, amax = 10.0, 50.0
    drive = SimCiA402Drive(NODE, counts_per_rev=CPR, max_velocity_rps=vmax, max_accel_rps2=amax)
    sdo_write(drive, 0x6060, 0, 8, "<b")
    enable(drive)
    sdo_write(drive, 0x607A, 0, 20 * CPR, "<i")
    velocities = []
    t = 0.0
    while not (drive.position_rev == 20.0 and drive.velocity_rps == 0.0) and t < 10.0:
        drive.step(DT)
        t += DT
        velocities.append(drive.velocity_rps)
    assert drive.position_rev == 20.0 and drive.encoder_estimate_rev == 20.0
    assert 2.2 < t < 4.0
    assert max(abs(v) for v in velocities) <= vmax + 1e-9
    accel = [(b - a) / DT for a, b in itertools.pairwise(velocities)]
    assert max(abs(a) for a in accel) <= amax + 1e-6
    # a ramp with the velocity offset as feed-forward trails by about one period's motion
    v, period = 5.0, 0.002
    p = 20.0
    for _ in range(500):
        p += v * period
        sdo_write(drive, 0x607A, 0, round(p * CPR), "<i")
        sdo_write(drive, 0x60B1, 0, round(v * CPR), "<i")
        run(drive, period)
    assert abs(p - drive.position_rev) <= v * period + 1e-3


def test_other_modes_and_disabled_power_stage_hold_position() -> None:
    drive = SimCiA402Drive(NODE, counts_per_rev=CPR, initial_position_rev=1.0)
    enable(drive)  # mode 1 (the default): cablebot's sim moves only in mode 8
    sdo_write(drive, 0x607A, 0, 5 * CPR, "<i")
    run(drive, 0.2)
    assert drive.position_rev == 1.0
    sdo_write(drive, 0x6060, 0, 8, "<b")
    cw(drive, 0x00)
    run(drive, 0.2)
    assert drive.position_rev == 1.0


def test_error_emcy_fault_and_reset() -> None:
    drive = booted()
    sdo_write(drive, 0x6060, 0, 8, "<b")
    enable(drive)
    drive.set_error(0x4310)
    frames = drive.step(DT)
    assert frames == [(0x080 + NODE, struct.pack("<HB5s", 0x4310, 0x09, b""))]
    assert drive.state is S.FAULT and drive.statusword == 0x0208
    assert drive.node.get_data(0x603F, 0) == b"\x10\x43"
    cw(drive, 0x0F)  # no edge of bit 7: still faulted
    assert drive.state is S.FAULT
    cw(drive, 0x80)  # rising edge: reset (15), EMCY "error reset"
    assert drive.state is S.SWITCH_ON_DISABLED
    assert drive.step(DT) == [(0x080 + NODE, bytes(8))]
    # a persistent error survives the reset
    drive.set_error(0x7305, persistent=True)
    drive.step(DT)
    cw(drive, 0x00)
    cw(drive, 0x80)
    assert drive.state is S.FAULT
    with pytest.raises(ValueError, match="EMCY"):
        drive.set_error(0x0042)


def test_silence_corrupt_drift_and_power_cycle() -> None:
    drive = booted(counts_per_rev=CPR, initial_position_rev=2.0)
    sdo_write(drive, 0x1017, 0, 50, "<H")
    drive.step(DT)
    drive.send_corrupt(2)
    frames = drive.step(DT)
    assert frames.count((0x180 + NODE, b"\x37\x02\x00\x00\x00")) == 2
    drive.drift(0.5)
    run(drive, 1.0)
    assert drive.position_rev == 2.0
    assert drive.encoder_estimate_rev == pytest.approx(2.5, abs=1e-9)
    drive.silence(True)
    assert run(drive, 0.5) == []
    assert drive.handle(0x600 + NODE, bytes.fromhex("4041600000000000")) == []
    drive.silence(False)
    assert run(drive, 0.1) != []
    drive.drift(0.0)
    sdo_write(drive, 0x6060, 0, 8, "<b")
    enable(drive)
    drive.power_cycle()
    assert drive.step(DT) == [(0x700 + NODE, b"\x00")]
    assert drive.state is S.SWITCH_ON_DISABLED and drive.nmt_state == "PRE-OPERATIONAL"
    assert drive.mode == 1  # the dictionary is back to its defaults
    assert run(drive, 0.5) == []  # ... heartbeat off again
    assert drive.position_rev == 2.0 and drive.encoder_estimate_rev == 0.0


def test_nmt_reset_and_leaving_operational() -> None:
    drive = booted()
    sdo_write(drive, 0x6060, 0, 8, "<b")
    start(drive)
    enable(drive)
    drive.handle(0x000, bytes([0x80, 0]))  # all nodes: pre-operational
    assert drive.nmt_state == "PRE-OPERATIONAL"
    assert drive.state is S.QUICK_STOP_ACTIVE
    assert drive.handle(0x000, bytes([0x82, NODE])) == [(0x700 + NODE, b"\x00")]
    assert drive.mode == 8  # reset communication keeps the application's objects
    assert drive.handle(0x000, bytes([0x81, NODE])) == [(0x700 + NODE, b"\x00")]
    assert drive.mode == 1


def test_drive_validation() -> None:
    with pytest.raises(ValueError, match="node id"):
        SimCiA402Drive(0)
    with pytest.raises(ValueError, match="node id"):
        SimCiA402Drive(128)
    with pytest.raises(ValueError, match="counts_per_rev"):
        SimCiA402Drive(1, counts_per_rev=0)
    with pytest.raises(ValueError, match="initial_position_rev"):
        SimCiA402Drive(1, initial_position_rev=float("nan"))
