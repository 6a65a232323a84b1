"""Simulated ODrive: the axis state object alone, then a bank + ODriveReels on a virtual bus."""

from __future__ import annotations

import itertools
import math
import random
import time
import uuid
from collections.abc import Callable, Iterator
from typing import Any

import can
import pytest

from drivers.bus import open_bus
from drivers.odrive import cansimple as cs
from drivers.odrive.driver import ODriveReels
from drivers.odrive.sim import SimODriveAxis, SimODriveBank

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


def _step_response(
    axis: SimODriveAxis, target_rev: float, limit_s: float = 10.0
) -> tuple[float, list[float], list[float]]:
    """Command `target_rev` (no feed-forward) and step until the axis sits on it."""
    axis.handle(cs.SetInputPos(axis.node_id, target_rev, 0.0, 0.0))
    positions = [axis.position_rev]
    velocities = [axis.velocity_rps]
    t = 0.0
    while not (axis.position_rev == target_rev and axis.velocity_rps == 0.0) and t < limit_s:
        axis.step(DT)
        t += DT
        positions.append(axis.position_rev)
        velocities.append(axis.velocity_rps)
    return t, positions, velocities


def test_position_step_respects_velocity_and_accel_limits_and_arrives() -> None:
    # A big step with the accel limit binding while braking (a > pos_gain * v only below
    # 2.5 rev/s here): the cascaded loop brakes late and overshoots, as a current-limited drive
    # does, then settles exactly on the target.
    vmax, amax = 10.0, 50.0
    axis = SimODriveAxis(1, max_velocity_rps=vmax, max_accel_rps2=amax)
    arm(axis)
    t, positions, velocities = _step_response(axis, 20.0)
    assert axis.position_rev == 20.0 and axis.velocity_rps == 0.0
    assert t > 2.2  # the time-optimal trapezoid (d/vmax + vmax/a) is a lower bound
    assert t < 4.0
    assert max(abs(v) for v in velocities) <= vmax + 1e-9
    accel = [(b - a) / DT for a, b in itertools.pairwise(velocities)]
    assert max(abs(x) for x in accel) <= amax + 1e-6
    overshoot = max(positions) - 20.0
    assert 0.0 < overshoot <= vmax * vmax / (2.0 * amax)


def test_position_loop_is_proportional_without_overshoot_when_braking_is_feasible() -> None:
    # amax >= pos_gain * vmax: the velocity follows pos_gain * error at once, so the approach
    # is the P loop's exponential, error(t) = error(0) * exp(-pos_gain t), with no overshoot.
    gain = 20.0
    axis = SimODriveAxis(1, max_velocity_rps=10.0, max_accel_rps2=400.0, pos_gain=gain)
    arm(axis)
    axis.handle(cs.SetInputPos(1, 0.25, 0.0, 0.0))  # 0.25 rev: gain * error = 5 rev/s < vmax
    run(axis, 0.05)  # the first 0.4 ms are acceleration-limited
    e0 = 0.25 - axis.position_rev
    run(axis, 0.1)
    e1 = 0.25 - axis.position_rev
    assert e1 / e0 == pytest.approx(math.exp(-gain * 0.1), rel=0.05)  # 1 ms integration
    t, positions, _ = _step_response(axis, 0.25)
    assert axis.position_rev == 0.25 and t < 1.5
    assert all(b >= a for a, b in itertools.pairwise(positions))  # no overshoot


def _ramp_lag(vel_ff: bool, v_rps: float = 30.0, period_s: float = 0.002) -> float:
    """Stream a ramp (accelerating at 300 rev/s^2, then cruising at v_rps) as Set_Input_Pos
    every `period_s`, as the control loop does; return the lag at the end of cruise."""
    axis = SimODriveAxis(2, max_velocity_rps=100.0, max_accel_rps2=400.0)
    arm(axis)
    p = v = 0.0
    lag = math.nan
    for _ in range(600):
        v = min(v_rps, v + 300.0 * period_s)
        p += v * period_s
        axis.handle(cs.SetInputPos(2, p, v if vel_ff else 0.0, 0.0))
        for _ in range(round(period_s / DT)):
            axis.step(DT)
        lag = p - axis.position_rev
    return lag


def test_ramp_with_velocity_feed_forward_has_small_steady_lag() -> None:
    v, period = 30.0, 0.002
    with_ff = _ramp_lag(True, v, period)
    without = _ramp_lag(False, v, period)
    # Without feed-forward the P loop needs error = v / pos_gain to run at v.
    assert without == pytest.approx(v / 20.0, rel=0.05)
    # With it, only the set-point's hold between commands remains: within one period of motion.
    assert abs(with_ff) <= v * period
    assert abs(with_ff) < 0.05 * without


def test_feed_forward_without_new_set_points_stops_a_bounded_distance_ahead() -> None:
    # The last set-point keeps its feed-forward (no watchdog, like firmware): the reel runs on
    # until pos_gain * error cancels it, i.e. it stops vel_ff / pos_gain past input_pos.
    axis = SimODriveAxis(0, max_velocity_rps=100.0, max_accel_rps2=400.0)
    arm(axis)
    axis.handle(cs.SetInputPos(0, 0.0, 10.0, 0.0))
    run(axis, 1.0)
    assert axis.position_rev == pytest.approx(10.0 / 20.0, abs=1e-6)
    assert abs(axis.velocity_rps) < 1e-6
    axis.handle(cs.SetInputPos(0, 0.0, 0.0, 0.0))  # feed-forward off: back onto the set-point
    run(axis, 2.0)
    assert axis.position_rev == 0.0 and axis.velocity_rps == 0.0


def test_late_step_is_integrated_stably() -> None:
    # A stalled simulation thread calls step(0.3): pos_gain * dt = 6 would make one explicit
    # step of the P loop diverge; the sub-steps keep it the same motion as 300 steps of 1 ms.
    slow = SimODriveAxis(0, max_velocity_rps=100.0, max_accel_rps2=400.0)
    fast = SimODriveAxis(0, max_velocity_rps=100.0, max_accel_rps2=400.0)
    for axis in (slow, fast):
        arm(axis)
        axis.handle(cs.SetInputPos(0, 1.0, 0.0, 0.0))
    for _ in range(3):
        slow.step(0.3)
    run(fast, 0.9)
    assert slow.position_rev == pytest.approx(fast.position_rev, abs=1e-9)
    assert abs(1.0 - slow.position_rev) < 1e-6


def test_closed_loop_entry_clears_a_stale_feed_forward() -> None:
    axis = SimODriveAxis(0, initial_position_rev=2.0)
    axis.handle(cs.SetInputPos(0, 5.0, 3.0, 0.0))  # while IDLE: stored, nothing moves
    arm(axis)
    assert axis.input_pos_rev == 2.0 and axis.input_vel_rps == 0.0
    run(axis, 0.2)
    assert axis.position_rev == 2.0


def test_velocity_control_mode() -> None:
    axis = SimODriveAxis(0, max_velocity_rps=5.0, max_accel_rps2=50.0)
    axis.handle(cs.SetControllerMode(0, cs.ControlMode.VELOCITY_CONTROL, 1))
    axis.handle(cs.SetAxisState(0, 8))
    axis.handle(cs.SetInputVel(0, 8.0, 0.0))
    run(axis, 0.5)
    assert axis.velocity_rps == pytest.approx(5.0)  # vel_limit
    axis.handle(cs.SetInputVel(0, 0.0, 0.0))
    run(axis, 0.5)
    assert axis.velocity_rps == 0.0


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


def test_watchdog_disarms_an_axis_that_stops_hearing_commands() -> None:
    axis = SimODriveAxis(2, max_velocity_rps=100.0, max_accel_rps2=400.0, watchdog_timeout_s=0.2)
    arm(axis)
    for k in range(100):  # a host streaming a 10 rev/s ramp every 10 ms keeps it fed
        axis.handle(cs.SetInputPos(2, 0.1 * k, 10.0, 0.0))
        run(axis, 0.01)
        assert axis.axis_state == cs.AxisState.CLOSED_LOOP_CONTROL and axis.axis_error == 0
    # The host dies with a 10 rev/s feed-forward outstanding.
    moving_at = axis.position_rev
    assert axis.velocity_rps > 8.0
    run(axis, 0.18)  # 0.19 s since the last command: still running on the feed-forward
    assert axis.axis_state == cs.AxisState.CLOSED_LOOP_CONTROL and axis.velocity_rps > 0.1
    run(axis, 0.03)  # 0.21 s
    assert axis.axis_state == cs.AxisState.IDLE
    assert axis.axis_error == cs.ODriveError.WATCHDOG_TIMER_EXPIRED
    assert axis.velocity_rps == 0.0
    stopped_at = axis.position_rev
    assert 0.0 < stopped_at - moving_at < 10.0 * 0.21
    msgs = run(axis, 0.5)
    assert axis.position_rev == stopped_at
    hb = [m for m in msgs if isinstance(m, cs.Heartbeat)]
    assert hb and hb[-1].axis_state == cs.AxisState.IDLE
    assert hb[-1].axis_error == cs.ODriveError.WATCHDOG_TIMER_EXPIRED
    enc = [m for m in msgs if isinstance(m, cs.EncoderEstimates)]
    assert enc and all(m.vel_estimate_rps == 0.0 for m in enc)
    reply = decoded(axis.handle(cs.RemoteRequest(2, cs.GET_ERROR)))
    assert reply == [cs.GetError(2, 0x1000000, 0x1000000)]
    arm(axis)  # Clear_Errors then closed loop again, as the driver arms
    assert axis.axis_state == cs.AxisState.CLOSED_LOOP_CONTROL and axis.axis_error == 0


def test_watchdog_is_off_by_default_and_only_runs_in_closed_loop() -> None:
    idle = SimODriveAxis(0, watchdog_timeout_s=0.05)
    run(idle, 0.5)
    assert idle.axis_error == 0
    plain = SimODriveAxis(1)
    arm(plain)
    run(plain, 1.0)
    assert plain.axis_state == cs.AxisState.CLOSED_LOOP_CONTROL and plain.axis_error == 0


def test_axis_validation() -> None:
    with pytest.raises(ValueError, match="node id"):
        SimODriveAxis(64)
    with pytest.raises(ValueError, match="max_velocity_rps"):
        SimODriveAxis(0, max_velocity_rps=0.0)
    with pytest.raises(ValueError, match="initial_position_rev"):
        SimODriveAxis(0, initial_position_rev=math.nan)
    with pytest.raises(ValueError, match="pos_gain"):
        SimODriveAxis(0, pos_gain=-1.0)
    with pytest.raises(ValueError, match="watchdog_timeout_s"):
        SimODriveAxis(0, watchdog_timeout_s=-0.1)
    with pytest.raises(ValueError, match="watchdog_timeout_s"):
        SimODriveAxis(0, watchdog_timeout_s=math.inf)


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
    # Set_Input_Pos carries the velocity feed-forward (int16, 0.001 rev/s) to the axis.
    driver.command(targets, [1.5, -2.25, 0.0, 0.001])
    assert poll_until(driver, lambda: bank.axes[1].input_vel_rps != 0.0)
    assert [a.input_vel_rps for a in bank.axes] == pytest.approx([1.5, -2.25, 0.0, 0.001])
    driver.command(targets)
    assert poll_until(driver, lambda: all(a.input_vel_rps == 0.0 for a in bank.axes))
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
    from drivers.simbank import option_arg

    assert option_arg("tty_baudrate=115200") == ("tty_baudrate", 115200)
    assert option_arg("receive_own_messages=false") == ("receive_own_messages", False)
    assert option_arg("hop_limit=1.5") == ("hop_limit", 1.5)
    assert option_arg("serial=ABC") == ("serial", "ABC")
    with pytest.raises(SystemExit):
        option_arg("novalue")


def test_the_configured_simulated_robot_has_its_watchdog_on() -> None:
    from controller.service.config import default_config
    from controller.service.simulated import sim_bank

    cfg = default_config()
    assert cfg.sim.watchdog_timeout_s == 1.0  # the built-in robot's allowance for a busy CPU
    bus = open_bus("virtual", f"test-sim-watchdog-{uuid.uuid4().hex}")
    try:
        bank = sim_bank(cfg, bus)
        assert isinstance(bank, SimODriveBank)
        assert [a.watchdog_timeout_s for a in bank.axes] == [1.0] * 4
        assert bank.thread is None  # built, not started
    finally:
        bus.shutdown()


def test_a_stalled_simulator_does_not_mistake_queued_commands_for_silence() -> None:
    axis = SimODriveAxis(0, watchdog_timeout_s=0.2)
    arm(axis)
    axis.step(0.5)  # the simulation thread stalled; the host's frames waited in the queue
    axis.handle(cs.SetInputPos(0, 0.0, 0.0, 0.0))
    axis.step(DT)
    assert axis.axis_state == cs.AxisState.CLOSED_LOOP_CONTROL and axis.axis_error == 0


def test_a_stall_with_the_backlog_drained_first_counts_from_the_last_frame() -> None:
    # The serving loop handles the frames that queued during a stall of its thread before it
    # steps over the stall: the host was alive, its frames only waited. The stall's time is not
    # held against it, and the host's usual period (10 ms) keeps the axis fed afterwards.
    axis = SimODriveAxis(0, watchdog_timeout_s=0.2)
    arm(axis)
    axis.handle(cs.SetInputPos(0, 0.0, 0.0, 0.0))  # the backlog, drained before the late step
    axis.step(0.5)
    for _ in range(20):
        run(axis, 0.01)
        assert axis.axis_state == cs.AxisState.CLOSED_LOOP_CONTROL and axis.axis_error == 0
        axis.handle(cs.SetInputPos(0, 0.0, 0.0, 0.0))
    # and a host that goes silent after a stall is still caught within the watchdog time
    run(axis, 0.2)
    assert axis.axis_state == cs.AxisState.CLOSED_LOOP_CONTROL
    run(axis, 0.01)
    assert axis.axis_state == cs.AxisState.IDLE
    assert axis.axis_error == cs.ODriveError.WATCHDOG_TIMER_EXPIRED


def test_a_late_step_past_the_watchdog_time_stops_the_axis_at_that_time() -> None:
    # The host dies at 10 rev/s; the simulation thread then stalls 0.5 s (a busy host): the
    # axis runs on for the watchdog time only, as the drive's own timer would stop it.
    axis = SimODriveAxis(0, max_velocity_rps=10.0, max_accel_rps2=400.0, watchdog_timeout_s=0.2)
    arm(axis)
    for _ in range(50):  # far ahead: the axis runs at its velocity limit, 10 rev/s
        axis.handle(cs.SetInputPos(0, 1000.0, 0.0, 0.0))
        run(axis, 0.01)
    axis.handle(cs.SetInputPos(0, 1000.0, 0.0, 0.0))  # the host's last frame
    fed_at = axis.position_rev
    assert axis.velocity_rps == pytest.approx(10.0)
    run(axis, 0.05)
    axis.step(0.5)
    assert axis.axis_state == cs.AxisState.IDLE
    assert axis.axis_error == cs.ODriveError.WATCHDOG_TIMER_EXPIRED
    assert axis.position_rev - fed_at == pytest.approx(10.0 * 0.2, abs=0.02)


def test_the_axis_own_frames_heard_back_do_not_feed_its_watchdog() -> None:
    # udp_multicast loops every frame back to its sender: the simulated node hears its own
    # encoder estimates and heartbeats, which must not count as a host that is alive.
    axis = SimODriveAxis(1, watchdog_timeout_s=0.2)
    arm(axis)
    for _ in range(30):
        for m in run(axis, 0.01):
            if isinstance(m, cs.Heartbeat | cs.EncoderEstimates):
                axis.handle(m)
        axis.handle(cs.GetError(1, 0, 0))
    assert axis.axis_state == cs.AxisState.IDLE
    assert axis.axis_error == cs.ODriveError.WATCHDOG_TIMER_EXPIRED


def test_the_axis_own_torque_broadcasts_heard_back_do_not_feed_its_watchdog() -> None:
    # With torque telemetry on, the axis's Get_Torques broadcasts come back to it too.
    axis = SimODriveAxis(1, watchdog_timeout_s=0.2, torque_period_s=0.01)
    arm(axis)
    heard = 0
    for _ in range(30):
        for m in run(axis, 0.01):
            if isinstance(m, cs.Heartbeat | cs.EncoderEstimates | cs.Torques):
                heard += isinstance(m, cs.Torques)
                axis.handle(m)
    assert heard >= 25
    assert axis.axis_state == cs.AxisState.IDLE
    assert axis.axis_error == cs.ODriveError.WATCHDOG_TIMER_EXPIRED


def test_a_bank_with_torque_telemetry_on_udp_multicast_disarms_once_the_host_goes_silent() -> None:
    # udp_multicast echoes every frame to every member, the bank's own included: after the
    # host stops, only the watchdog stops an axis left in closed loop.
    group = f"239.74.{random.randint(1, 254)}.{random.randint(1, 254)}"
    port = random.randint(40000, 49000)
    sim_bus = open_bus("udp_multicast", group, port=port)
    host_bus = open_bus("udp_multicast", group, port=port)
    axes = [SimODriveAxis(n, watchdog_timeout_s=0.3, torque_period_s=0.01) for n in (0, 1)]
    bank = SimODriveBank(sim_bus, axes).start()
    try:
        driver = ODriveReels(host_bus, (0, 1))
        r = driver.read()
        assert poll_until(driver, lambda: all(x.heartbeat_stamp_s > -math.inf for x in r))
        driver.arm()
        assert poll_until(driver, lambda: all(x.ready for x in r))
        assert poll_until(driver, lambda: all(x.torque_stamp_s > -math.inf for x in r))
        # The host goes silent (nothing sent from now on): the axes disarm by their watchdog.
        deadline = time.monotonic() + 10.0
        while not all(a.axis_state == cs.AxisState.IDLE for a in axes):
            assert time.monotonic() < deadline, [a.axis_state for a in axes]
            time.sleep(0.01)
        assert all(a.axis_error == cs.ODriveError.WATCHDOG_TIMER_EXPIRED for a in axes)
    finally:
        assert bank.stop(timeout_s=2.0)
        sim_bus.shutdown()
        host_bus.shutdown()


# --- TORQUE_CONTROL ---------------------------------------------------------------------------


def torque_axis(**kw: Any) -> SimODriveAxis:
    """An axis in closed loop in TORQUE_CONTROL at zero torque, as enter_torque_mode leaves it."""
    axis = SimODriveAxis(1, **kw)
    axis.handle(cs.SetInputTorque(1, 0.0))
    axis.handle(cs.SetControllerMode(1, cs.ControlMode.TORQUE_CONTROL, cs.InputMode.PASSTHROUGH))
    axis.handle(cs.SetAxisState(1, cs.AxisState.CLOSED_LOOP_CONTROL))
    return axis


def test_free_axis_in_torque_mode_turns_at_mobility_times_torque_up_to_vel_limit() -> None:
    axis = torque_axis(max_velocity_rps=20.0, max_accel_rps2=200.0, torque_mobility_rps_per_nm=5.0)
    axis.step(0.5)
    assert (axis.position_rev, axis.velocity_rps) == (0.0, 0.0)  # zero torque, nothing held
    axis.handle(cs.SetInputTorque(1, -0.8))
    for _ in range(100):
        axis.step(0.001)
    assert axis.velocity_rps == pytest.approx(-4.0)  # G * torque, reached at 200 rev/s^2
    axis.handle(cs.SetInputTorque(1, 10.0))  # G * torque = 50 rev/s: vel_limit holds it to 20
    for _ in range(300):
        axis.step(0.001)
    assert axis.velocity_rps == pytest.approx(20.0)
    axis.handle(cs.SetLimits(1, 7.5, 10.0))  # Set_Limits lowers vel_limit in torque mode too
    for _ in range(100):
        axis.step(0.001)
    assert axis.velocity_rps == pytest.approx(7.5)
    # the axis reports the torque it is told, target and estimate both
    (reply,) = axis.handle(cs.RemoteRequest(1, cs.GET_TORQUES))
    assert cs.decode(*reply) == cs.Torques(1, 10.0, 10.0)


def test_entering_closed_loop_in_torque_mode_starts_from_rest() -> None:
    axis = SimODriveAxis(1, initial_position_rev=3.0, max_accel_rps2=200.0)
    axis.handle(cs.SetControllerMode(1, cs.ControlMode.TORQUE_CONTROL, cs.InputMode.PASSTHROUGH))
    axis.handle(cs.SetInputTorque(1, -1.0))
    axis.step(0.1)  # IDLE: braked, nothing moves, torque 0
    assert (axis.position_rev, axis.velocity_rps, axis.torque_estimate_nm) == (3.0, 0.0, 0.0)
    assert axis.pull_nm is None
    axis.handle(cs.SetAxisState(1, cs.AxisState.CLOSED_LOOP_CONTROL))
    assert axis.torque_estimate_nm == -1.0 and axis.pull_nm == -1.0
    axis.step(0.001)
    # from standstill: one tick of acceleration, not a jump to G * 1 N m
    assert axis.velocity_rps == pytest.approx(-0.2)
    assert axis.position_rev == pytest.approx(3.0 - 0.2 * 0.001)


def test_torque_mode_integrates_where_position_mode_would_rest() -> None:
    # In closed loop the set-point equals the position and the axis is still: the position
    # mode's fast path would skip it, but in torque mode a torque must move a free reel.
    axis = torque_axis()
    assert axis.position_rev == axis.input_pos_rev and axis.velocity_rps == 0.0
    axis.handle(cs.SetInputTorque(1, 0.1))
    axis.step(0.01)
    assert axis.velocity_rps > 0.0 and axis.position_rev > 0.0
    # no torque and at rest: it stays exactly where it is
    idle = torque_axis()
    idle.step(1.0)
    assert (idle.position_rev, idle.velocity_rps) == (0.0, 0.0)


def test_a_coupled_axis_in_torque_mode_is_turned_by_its_load() -> None:
    axis = torque_axis(max_velocity_rps=20.0)
    axis.coupled = True
    axis.handle(cs.SetInputTorque(1, -0.8))
    axis.step(0.5)
    assert (axis.position_rev, axis.velocity_rps) == (0.0, 0.0)  # it does not move itself
    assert axis.pull_nm == -0.8
    axis.follow_load(-0.004, 0.001)  # the plant wound it in 0.004 turns in one tick
    assert (axis.position_rev, axis.velocity_rps) == (-0.004, pytest.approx(-4.0))
    (frame,) = [f for f in axis.step(0.01) if cs.decode(*f).__class__ is cs.EncoderEstimates]
    assert cs.decode(*frame) == cs.EncoderEstimates(1, pytest.approx(-0.004), pytest.approx(-4.0))
    axis.follow_load(math.nan, 0.001)  # ignored
    assert axis.position_rev == -0.004
    # in position control the load does not turn it: pull_nm says so to the bank
    axis.handle(cs.SetControllerMode(1, cs.ControlMode.POSITION_CONTROL, cs.InputMode.PASSTHROUGH))
    assert axis.pull_nm is None


def test_set_load_torque_ignores_bad_values() -> None:
    axis = SimODriveAxis(1)
    axis.set_load_torque(-0.5)
    for bad in (math.nan, math.inf, -math.inf):
        axis.set_load_torque(bad)
    assert axis.load_torque_nm == -0.5
    with pytest.raises(ValueError, match="torque_mobility_rps_per_nm"):
        SimODriveAxis(1, torque_mobility_rps_per_nm=0.0)


def test_set_input_torque_feeds_the_watchdog() -> None:
    axis = torque_axis(watchdog_timeout_s=0.05)
    for _ in range(20):
        axis.step(0.01)
        axis.handle(cs.SetInputTorque(1, 0.0))
    assert axis.axis_state == cs.AxisState.CLOSED_LOOP_CONTROL
    for _ in range(10):
        axis.step(0.01)
    assert axis.axis_state == cs.AxisState.IDLE
    assert axis.axis_error & cs.ODriveError.WATCHDOG_TIMER_EXPIRED
