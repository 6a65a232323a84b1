"""Simulated ODrive: the axis state object alone, then a bank + ODriveReels on a virtual bus."""

from __future__ import annotations

import itertools
import math
import time
import uuid
from collections.abc import Callable, Iterator

import can
import pytest

from drivers import cansimple as cs
from drivers.bus import open_bus
from drivers.odrive import ODriveReels
from drivers.sim_odrive import SimODriveAxis, SimODriveBank

DT = 0.001


def decoded(frames: list[cs.Frame]) -> list[cs.Message | cs.DecodeError]:
    return [cs.decode(a, d, r) for a, d, r in frames]


def run(axis: SimODriveAxis, seconds: float) -> list[cs.Message | cs.DecodeError]:
    out: list[cs.Message | cs.DecodeError] = []
    for _ in range(round(seconds / DT)):
        out.extend(decoded(axis.step(DT)))
    return out


def arm(axis: SimODriveAxis) -> None:
    axis.handle(cs.ClearErrors(axis.node_id, 0))
    axis.handle(cs.SetControllerMode(axis.node_id, 3, 1))
    axis.handle(cs.SetAxisState(axis.node_id, 8))


def test_broadcast_rates() -> None:
    axis = SimODriveAxis(2, encoder_period_s=0.01, heartbeat_period_s=0.1)
    msgs = run(axis, 1.0)
    enc = [m for m in msgs if isinstance(m, cs.EncoderEstimates)]
    hb = [m for m in msgs if isinstance(m, cs.Heartbeat)]
    assert 99 <= len(enc) <= 101
    assert 9 <= len(hb) <= 11
    assert all(m.node_id == 2 for m in enc + hb)
    assert hb[0].axis_state == cs.AxisState.IDLE and hb[0].axis_error == 0


def test_state_machine_and_hold_on_entry() -> None:
    axis = SimODriveAxis(0, initial_position_rev=3.0)
    axis.handle(cs.SetInputPos(0, 10.0, 0.0, 0.0))  # stored but IDLE: nothing moves
    run(axis, 0.2)
    assert axis.position_rev == 3.0 and axis.axis_state == cs.AxisState.IDLE
    arm(axis)
    assert axis.axis_state == cs.AxisState.CLOSED_LOOP_CONTROL
    assert axis.input_pos_rev == 3.0  # entering closed loop holds the current position
    run(axis, 0.2)
    assert axis.position_rev == 3.0
    axis.handle(cs.SetAxisState(0, 1))
    assert axis.axis_state == cs.AxisState.IDLE


def test_trapezoidal_motion_respects_limits_and_arrives() -> None:
    vmax, amax = 10.0, 50.0
    axis = SimODriveAxis(1, max_velocity_rps=vmax, max_accel_rps2=amax)
    arm(axis)
    axis.handle(cs.SetInputPos(1, 20.0, 0.0, 0.0))
    positions = [axis.position_rev]
    velocities = [axis.velocity_rps]
    t = 0.0
    while axis.position_rev != 20.0 and t < 5.0:
        axis.step(DT)
        t += DT
        positions.append(axis.position_rev)
        velocities.append(axis.velocity_rps)
    assert axis.position_rev == 20.0 and axis.velocity_rps == 0.0
    # theory: d/vmax + vmax/a = 2.0 + 0.2 s
    assert t == pytest.approx(2.2, abs=0.005)
    assert max(abs(v) for v in velocities) <= vmax + 1e-9
    accel = [(b - a) / DT for a, b in itertools.pairwise(velocities)]
    assert max(abs(x) for x in accel) <= amax + 1e-6
    assert all(b >= a for a, b in itertools.pairwise(positions))  # no overshoot


def test_estop_latches_error_and_blocks_closed_loop_until_cleared() -> None:
    axis = SimODriveAxis(3)
    arm(axis)
    axis.handle(cs.Estop(3))
    assert axis.axis_state == cs.AxisState.IDLE
    assert axis.axis_error & cs.ODriveError.ESTOP_REQUESTED
    axis.handle(cs.SetAxisState(3, 8))
    assert axis.axis_state == cs.AxisState.IDLE  # refused while the error is active
    hb = [m for m in run(axis, 0.2) if isinstance(m, cs.Heartbeat)]
    assert hb[-1].axis_error == cs.ODriveError.ESTOP_REQUESTED
    arm(axis)
    assert axis.axis_state == cs.AxisState.CLOSED_LOOP_CONTROL and axis.axis_error == 0


def test_remote_requests_and_other_nodes() -> None:
    axis = SimODriveAxis(5, initial_position_rev=1.25)
    assert decoded(axis.handle(cs.RemoteRequest(5, cs.GET_ENCODER_ESTIMATES))) == [
        cs.EncoderEstimates(5, 1.25, 0.0)
    ]
    assert decoded(axis.handle(cs.RemoteRequest(5, cs.GET_ERROR))) == [cs.GetError(5, 0, 0)]
    hb = decoded(axis.handle(cs.RemoteRequest(5, cs.HEARTBEAT)))
    assert isinstance(hb[0], cs.Heartbeat) and hb[0].axis_state == 1
    assert axis.handle(cs.SetAxisState(4, 8)) == []
    assert axis.axis_state == cs.AxisState.IDLE


def test_fault_injection_frames() -> None:
    axis = SimODriveAxis(1, initial_position_rev=2.0)
    axis.send_corrupt()
    axis.send_nan()
    msgs = decoded(axis.step(DT))
    kinds = [m.kind for m in msgs if isinstance(m, cs.DecodeError)]
    assert kinds == [cs.DecodeErrorKind.LENGTH, cs.DecodeErrorKind.NON_FINITE]
    axis.set_axis_error(int(cs.ODriveError.DRV_FAULT))
    hb = [m for m in run(axis, 0.2) if isinstance(m, cs.Heartbeat)]
    assert hb[-1].axis_error == cs.ODriveError.DRV_FAULT
    axis.drift(0.5)
    run(axis, 1.0)
    assert axis.position_rev == 2.0
    assert axis.encoder_estimate_rev == pytest.approx(2.5, abs=1e-9)
    axis.silence(True)
    assert run(axis, 0.5) == []
    assert axis.handle(cs.RemoteRequest(1, cs.GET_ENCODER_ESTIMATES)) == []
    axis.silence(False)
    assert run(axis, 0.05) != []


def test_axis_validation() -> None:
    with pytest.raises(ValueError, match="node id"):
        SimODriveAxis(64)
    with pytest.raises(ValueError, match="max_velocity_rps"):
        SimODriveAxis(0, max_velocity_rps=0.0)
    with pytest.raises(ValueError, match="initial_position_rev"):
        SimODriveAxis(0, initial_position_rev=math.nan)


# --- bank + driver on a virtual bus ----------------------------------------------------------


@pytest.fixture
def rig() -> Iterator[tuple[SimODriveBank, ODriveReels]]:
    channel = f"test-sim-{uuid.uuid4().hex}"
    sim_bus = open_bus("virtual", channel)
    drv_bus = open_bus("virtual", channel)
    axes = [SimODriveAxis(n, initial_position_rev=0.5 * n) for n in range(4)]
    bank = SimODriveBank(sim_bus, axes).start()
    driver = ODriveReels(drv_bus, range(4))
    yield bank, driver
    assert bank.stop(timeout_s=2.0)
    sim_bus.shutdown()
    drv_bus.shutdown()


def poll_until(driver: ODriveReels, cond: Callable[[], bool], timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        driver.poll()
        if cond():
            return True
        time.sleep(0.002)
    return False


def test_in_process_arm_command_read_back(rig: tuple[SimODriveBank, ODriveReels]) -> None:
    bank, driver = rig
    r = driver.read()
    assert poll_until(driver, lambda: all(x.heartbeat_stamp_s > -math.inf for x in r))
    assert poll_until(driver, lambda: all(x.stamp_ns for x in r))
    assert [x.position_rev for x in r] == [0.0, 0.5, 1.0, 1.5]
    assert all(x.axis_state == cs.AxisState.IDLE for x in r)
    driver.arm()
    assert poll_until(driver, lambda: all(x.axis_state == 8 for x in r))
    targets = [2.0, -1.5, 3.25, 0.75]
    driver.command(targets)
    assert poll_until(
        driver,
        lambda: all(
            x.position_rev == t and x.velocity_rps == 0.0 for x, t in zip(r, targets, strict=True)
        ),
    )
    assert [a.position_rev for a in bank.axes] == targets
    assert driver.stats.decode_errors == 0 and driver.stats.bus_errors == 0
    driver.disarm()
    assert poll_until(driver, lambda: all(x.axis_state == 1 for x in r))


def test_in_process_faults_detected_and_named(rig: tuple[SimODriveBank, ODriveReels]) -> None:
    bank, driver = rig
    r = driver.read()
    assert poll_until(driver, lambda: all(x.stamp_ns and x.heartbeat_stamp_s > 0 for x in r))
    driver.arm()
    assert poll_until(driver, lambda: all(x.axis_state == 8 for x in r))
    bank.axis(0).silence(True)
    bank.axis(1).set_axis_error(int(cs.ODriveError.MOTOR_OVER_TEMP))
    bank.axis(2).send_corrupt(3)
    bank.axis(3).send_nan(2)
    assert poll_until(
        driver,
        lambda: (
            driver.stats.errors_by_kind.get("length", 0) >= 3
            and driver.stats.errors_by_kind.get("non_finite", 0) >= 2
            and r[1].axis_error != 0
        ),
    )
    time.sleep(0.3)  # let node 0's silence exceed the staleness limit below
    driver.poll()
    faults = driver.check(max_encoder_age_s=0.2, max_heartbeat_age_s=0.25)
    named = {(f.node_id, f.kind) for f in faults}
    assert {
        (0, "silent"),
        (0, "no_heartbeat"),
        (1, "axis_error"),
        (2, "bad_frames"),
        (3, "bad_frames"),
    } <= named
    assert "MOTOR_OVER_TEMP" in next(f.detail for f in faults if f.kind == "axis_error")
    assert r[1].axis_state == cs.AxisState.IDLE
    assert all(math.isfinite(x.position_rev) and math.isfinite(x.velocity_rps) for x in r)
    # the reader still works: the healthy axes keep reporting
    before = r[3].stamp_s
    assert poll_until(driver, lambda: r[3].stamp_s > before)


def test_estop_over_the_bus(rig: tuple[SimODriveBank, ODriveReels]) -> None:
    _bank, driver = rig
    r = driver.read()
    assert poll_until(driver, lambda: all(x.stamp_ns for x in r))
    driver.arm()
    assert poll_until(driver, lambda: all(x.axis_state == 8 for x in r))
    driver.estop()
    assert poll_until(
        driver,
        lambda: all(x.axis_state == 1 and x.axis_error & cs.ODriveError.ESTOP_REQUESTED for x in r),
    )


def test_bank_stops_within_bound() -> None:
    bus = can.Bus(interface="virtual", channel=f"stop-{uuid.uuid4().hex}")
    bank = SimODriveBank(bus, [SimODriveAxis(0)])
    with bank:
        time.sleep(0.05)
    t0 = time.monotonic()
    assert bank.stop(timeout_s=2.0)
    assert time.monotonic() - t0 < 2.0
    bus.shutdown()


def test_process_option_parsing() -> None:
    from drivers.sim_odrive import _option

    assert _option("tty_baudrate=115200") == ("tty_baudrate", 115200)
    assert _option("receive_own_messages=false") == ("receive_own_messages", False)
    assert _option("hop_limit=1.5") == ("hop_limit", 1.5)
    assert _option("serial=ABC") == ("serial", "ABC")
    with pytest.raises(SystemExit):
        _option("novalue")
