"""ODriveReels on a python-can `virtual` bus: receive path, faults, transmit path, throughput."""

from __future__ import annotations

import math
import time
import uuid
from collections.abc import Iterator
from typing import Any, cast

import can
import pytest

from controller.cli import bench_rx as rx_bench
from drivers.base import NEVER_S, BusError, ReelDriver, TorqueDriver
from drivers.bus import BusOpenError, open_bus
from drivers.odrive import cansimple as cs
from drivers.odrive.driver import ODriveReels

NODES = (0, 1, 2, 3)


class FakeClock:
    def __init__(self) -> None:
        self.now_s = 100.0

    def __call__(self) -> float:
        return self.now_s


@pytest.fixture
def buses() -> Iterator[tuple[can.BusABC, can.BusABC]]:
    """(driver bus, peer bus) on a private virtual channel."""
    channel = f"test-odrive-{uuid.uuid4().hex}"
    a = open_bus("virtual", channel)
    b = open_bus("virtual", channel)
    yield a, b
    a.shutdown()
    b.shutdown()


def send(bus: can.BusABC, frame: cs.Frame) -> None:
    arb_id, data, rtr = frame
    bus.send(
        can.Message(arbitration_id=arb_id, data=data, is_extended_id=False, is_remote_frame=rtr)
    )


def drain(bus: can.BusABC, timeout_s: float = 0.05) -> list[cs.Message | cs.DecodeError]:
    out: list[cs.Message | cs.DecodeError] = []
    while (msg := bus.recv(timeout_s)) is not None:
        out.append(cs.decode(msg.arbitration_id, msg.data, msg.is_remote_frame))
    return out


def test_is_a_reel_driver(buses: tuple[can.BusABC, can.BusABC]) -> None:
    assert isinstance(ODriveReels(buses[0], NODES), ReelDriver)


def test_readings_from_encoder_and_heartbeat(buses: tuple[can.BusABC, can.BusABC]) -> None:
    bus, peer = buses
    clock = FakeClock()
    d = ODriveReels(bus, NODES, clock=clock, wall_clock_ns=lambda: 123)
    r = d.read()
    assert [x.node_id for x in r] == list(NODES)
    assert r[1].stamp_s == NEVER_S and r[1].stamp_ns == 0
    send(peer, cs.encode_encoder_estimates(1, 12.5, -0.25))
    send(peer, cs.encode_heartbeat(1, 0, 8))
    send(peer, cs.encode_heartbeat(2, 0x20, 1))
    time.sleep(0.01)
    assert d.poll() == 3
    assert (r[1].position_rev, r[1].velocity_rps, r[1].stamp_s, r[1].stamp_ns) == (
        12.5,
        -0.25,
        100.0,
        123,
    )
    assert (r[1].axis_state, r[1].axis_error, r[1].heartbeat_stamp_s) == (8, 0, 100.0)
    assert (r[2].axis_state, r[2].axis_error) == (1, 0x20)
    assert r[0].stamp_s == NEVER_S
    assert d.stats.frames_rx == 3 and d.stats.decode_errors == 0
    assert d.poll() == 0  # nothing more: no blocking, no frames


def test_heartbeats_give_the_generic_status(buses: tuple[can.BusABC, can.BusABC]) -> None:
    bus, peer = buses
    d = ODriveReels(bus, NODES)
    r = d.read()
    assert [(x.ready, x.fault, x.state_name) for x in r] == [(False, None, "unknown")] * 4
    # The first heartbeat names the state even when it equals the reading's initial 0.
    send(peer, cs.encode_heartbeat(0, 0, 0))
    send(peer, cs.encode_heartbeat(1, 0, 8))
    send(peer, cs.encode_heartbeat(2, 0x2000000 | 0x20, 1))
    time.sleep(0.01)
    d.poll()
    assert (r[0].ready, r[0].fault, r[0].state_name) == (False, None, "UNDEFINED")
    assert (r[1].ready, r[1].fault, r[1].state_name) == (True, None, "CLOSED_LOOP_CONTROL")
    assert (r[2].ready, r[2].fault, r[2].state_name) == (
        False,
        "DRV_FAULT|ESTOP_REQUESTED (0x2000020)",
        "IDLE",
    )
    # Closed loop with an error bit set is not ready; an unknown state is named by number.
    send(peer, cs.encode_heartbeat(1, 0x8, 8))
    send(peer, cs.encode_heartbeat(2, 0, 99))
    time.sleep(0.01)
    d.poll()
    assert (r[1].ready, r[1].fault) == (False, "MISSING_ESTIMATE (0x8)")
    assert (r[2].ready, r[2].fault, r[2].state_name) == (False, None, "state 99")
    send(peer, cs.encode_heartbeat(1, 0, 8))
    time.sleep(0.01)
    d.poll()
    assert (r[1].ready, r[1].fault, r[1].state_name) == (True, None, "CLOSED_LOOP_CONTROL")


def test_bad_frames_are_counted_named_and_never_corrupt_readings(
    buses: tuple[can.BusABC, can.BusABC],
) -> None:
    bus, peer = buses
    d = ODriveReels(bus, NODES)
    send(peer, cs.encode_encoder_estimates(2, 3.0, 0.0))
    enc2 = cs.arbitration_id(2, cs.GET_ENCODER_ESTIMATES)
    send(peer, (enc2, b"\x00\x00\x80\x3f\x00", False))  # wrong length
    send(peer, (enc2, bytes.fromhex("0000c07f00000000"), False))  # NaN position
    send(peer, (enc2, bytes.fromhex("0000807f00000000"), False))  # +inf position
    send(peer, (cs.arbitration_id(2, 0x14), bytes(8), False))  # Get_Iq: unknown to the codec
    send(peer, cs.encode_encoder_estimates(9, 1.0, 0.0))  # node 9 is not ours
    send(peer, cs.encode_set_input_pos(1, 5.0))  # a command (echo / other master)
    peer.send(can.Message(arbitration_id=0x1234, is_extended_id=True, data=bytes(8)))
    time.sleep(0.01)
    assert d.poll() == 8
    r = d.read()[2]
    assert r.position_rev == 3.0 and math.isfinite(r.position_rev)
    s = d.stats
    assert s.decode_errors == 5
    assert s.dropped == 1  # the unknown node's frame; the echoed command is not a loss
    assert s.commands_heard == 1
    assert s.errors_by_kind == {
        "length": 1,
        "non_finite": 2,
        "unknown_command": 1,
        "extended_id": 1,
        "unknown_node": 1,
        "not_for_host": 1,
    }
    last = d.last_decode_error(2)
    assert last is not None and last.kind is cs.DecodeErrorKind.UNKNOWN_COMMAND
    faults = {(f.node_id, f.kind) for f in d.check(1.0, 1.0)}
    assert (2, "bad_frames") in faults
    # the per-axis bad-frame count is reset by check()
    assert (2, "bad_frames") not in {(f.node_id, f.kind) for f in d.check(1.0, 1.0)}


def test_check_names_silent_axes_and_axis_errors(buses: tuple[can.BusABC, can.BusABC]) -> None:
    bus, peer = buses
    clock = FakeClock()
    d = ODriveReels(bus, (0, 1), clock=clock)
    for n in (0, 1):
        send(peer, cs.encode_encoder_estimates(n, 0.0, 0.0))
        send(peer, cs.encode_heartbeat(n, 0, 8))
    send(peer, cs.encode_heartbeat(1, int(cs.ODriveError.DRV_FAULT), 1))
    time.sleep(0.01)
    d.poll()
    assert [(f.node_id, f.kind) for f in d.check(0.05, 0.5)] == [(1, "axis_error")]
    assert "DRV_FAULT" in d.check(0.05, 0.5)[0].detail
    clock.now_s += 0.2
    send(peer, cs.encode_encoder_estimates(0, 0.0, 0.0))
    time.sleep(0.01)
    d.poll()
    kinds = [(f.node_id, f.kind) for f in d.check(0.05, 0.5)]
    assert kinds == [(1, "silent"), (1, "axis_error")]
    clock.now_s += 1.0
    kinds = [(f.node_id, f.kind) for f in d.check(0.05, 0.5)]
    assert (0, "silent") in kinds and (0, "no_heartbeat") in kinds and (1, "no_heartbeat") in kinds


def test_poll_is_bounded(buses: tuple[can.BusABC, can.BusABC]) -> None:
    bus, peer = buses
    d = ODriveReels(bus, NODES, max_frames_per_poll=10)
    for i in range(25):
        send(peer, cs.encode_encoder_estimates(0, float(i), 0.0))
    time.sleep(0.01)
    assert [d.poll(), d.poll(), d.poll(), d.poll()] == [10, 10, 5, 0]
    assert d.read()[0].position_rev == 24.0


def test_readings_are_stamped_with_their_arrival_not_with_the_poll(
    buses: tuple[can.BusABC, can.BusABC],
) -> None:
    # Frames that waited in the receive queue while the loop stalled are as old as they are.
    bus, peer = buses
    d = ODriveReels(bus, NODES)
    sent_s = time.monotonic()
    sent_ns = time.time_ns()
    send(peer, cs.encode_encoder_estimates(1, 2.0, 0.0))
    send(peer, cs.encode_heartbeat(1, 0, 8))
    time.sleep(0.3)  # the loop stalls
    polled_s = time.monotonic()
    assert d.poll() == 2
    r = d.read()[1]
    assert sent_s - 0.05 <= r.stamp_s <= sent_s + 0.05, (r.stamp_s - sent_s, polled_s - sent_s)
    assert sent_s - 0.05 <= r.heartbeat_stamp_s <= sent_s + 0.05
    assert r.encoder_age_s(polled_s) > 0.25
    assert abs(r.stamp_ns - sent_ns) < 50_000_000
    assert d.stats.untimed_frames == 0


def test_frame_timestamps_are_clamped_and_foreign_clocks_fall_back_to_poll_time() -> None:
    channel = f"test-odrive-ts-{uuid.uuid4().hex}"
    bus = open_bus("virtual", channel)
    # The peer keeps the timestamps it is given, as an interface with its own clock would.
    peer = open_bus("virtual", channel, preserve_timestamps=True)
    wall_s = 1_700_000_000.0
    clock = FakeClock()
    try:
        d = ODriveReels(bus, NODES, clock=clock, wall_clock_ns=lambda: int(wall_s * 1e9))

        def arrive(node: int, timestamp: float) -> None:
            arb_id, data, _ = cs.encode_encoder_estimates(node, 1.0, 0.0)
            peer.send(
                can.Message(
                    arbitration_id=arb_id, data=data, is_extended_id=False, timestamp=timestamp
                )
            )

        arrive(0, wall_s - 0.25)  # waited 250 ms in the queue
        arrive(1, wall_s + 0.5)  # a little ahead (clock skew): clamped to now
        arrive(2, 0.0)  # not a wall-clock reading: stamped at poll time, counted
        arrive(3, wall_s + 30.0)  # far ahead: the same
        deadline = time.monotonic() + 2.0
        while d.stats.frames_rx < 4 and time.monotonic() < deadline:
            d.poll()
        r = d.read()
        assert r[0].stamp_s == pytest.approx(100.0 - 0.25)
        assert r[0].stamp_ns == pytest.approx(int((wall_s - 0.25) * 1e9), abs=1000)
        assert [x.stamp_s for x in r[1:]] == [100.0, 100.0, 100.0]
        assert d.stats.untimed_frames == 2
    finally:
        bus.shutdown()
        peer.shutdown()


def test_a_backlog_after_a_stall_is_read_through_but_a_flood_is_not() -> None:
    channel = f"test-odrive-backlog-{uuid.uuid4().hex}"
    bus = open_bus("virtual", channel)
    peer = open_bus("virtual", channel, preserve_timestamps=True)
    try:
        d = ODriveReels(bus, NODES, max_frames_per_poll=10, catch_up_age_s=0.05)

        def queue(count: int, age_s: float) -> None:
            for i in range(count):
                arb_id, data, _ = cs.encode_encoder_estimates(0, float(i), 0.0)
                peer.send(
                    can.Message(
                        arbitration_id=arb_id,
                        data=data,
                        is_extended_id=False,
                        timestamp=time.time() - age_s,
                    )
                )

        queue(25, 0.5)  # frames that waited half a second: read to the newest at once
        time.sleep(0.01)
        assert d.poll() == 25
        assert d.read()[0].position_rev == 24.0
        assert d.stats.catch_up_polls == 1
        queue(100, 0.5)  # a bigger backlog: still bounded, at 8 x the cap
        time.sleep(0.01)
        assert [d.poll(), d.poll()] == [80, 20]
        queue(25, 0.0)  # fresh frames: a flood, kept to the cap
        time.sleep(0.01)
        assert d.poll() == 10
    finally:
        bus.shutdown()
        peer.shutdown()


class ExplodingBus:
    """A bus whose every operation fails, as a broken adapter would."""

    def __init__(self) -> None:
        self.sent: list[can.Message] = []

    def recv(self, timeout: float | None = None) -> can.Message | None:
        raise can.CanOperationError("adapter unplugged")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sent.append(msg)
        if (msg.arbitration_id >> 5) == 1:
            raise can.CanOperationError("tx buffer full")


def test_receive_error_never_escapes_poll() -> None:
    d = ODriveReels(cast(Any, ExplodingBus()), NODES)
    assert d.poll() == 0
    assert d.stats.bus_errors == 1
    assert d.stats.last_error is not None and "adapter unplugged" in d.stats.last_error


def test_can_error_frame_is_a_bus_error(buses: tuple[can.BusABC, can.BusABC]) -> None:
    drv_bus, peer = buses
    d = ODriveReels(drv_bus, NODES)
    # SocketCAN reports bus-off as an error frame with CAN_ERR_BUSOFF (0x40) in its id.
    peer.send(can.Message(arbitration_id=0x40, is_error_frame=True, dlc=8, data=bytes(8)))
    deadline = time.monotonic() + 2.0
    while d.stats.bus_errors == 0 and time.monotonic() < deadline:
        d.poll()
    assert d.stats.bus_errors == 1
    assert d.stats.last_error is not None and "error frame 0x40" in d.stats.last_error
    assert d.stats.errors_by_kind.get("error_frame") == 1
    assert d.stats.decode_errors == 0


def test_send_error_raises_bus_error_after_trying_every_axis() -> None:
    fake = ExplodingBus()
    d = ODriveReels(cast(Any, fake), NODES)
    with pytest.raises(BusError, match=r"node 1.*tx buffer full"):
        d.estop()
    assert [m.arbitration_id >> 5 for m in fake.sent] == [0, 1, 2, 3]
    assert d.stats.bus_errors == 1 and d.stats.frames_tx == 3
    with pytest.raises(BusError):
        d.command([0.0, 0.0, 0.0, 0.0])
    assert d.stats.bus_errors == 2


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_command_refuses_non_finite_and_sends_nothing(
    buses: tuple[can.BusABC, can.BusABC], bad: float
) -> None:
    bus, peer = buses
    d = ODriveReels(bus, NODES)
    with pytest.raises(ValueError, match="node 2"):
        d.command([0.0, 1.0, bad, 3.0])
    with pytest.raises(ValueError, match="feed-forward"):
        d.command([0.0, 1.0, 2.0, 3.0], [0.0, bad, 0.0, 0.0])
    with pytest.raises(ValueError, match="4 positions"):
        d.command([0.0, 1.0])
    with pytest.raises(ValueError, match="float32"):
        d.command([0.0, 1.0, 1e39, 3.0])
    assert drain(peer) == []
    assert d.stats.frames_tx == 0


def test_command_frames_and_feed_forward_clamp(buses: tuple[can.BusABC, can.BusABC]) -> None:
    bus, peer = buses
    d = ODriveReels(bus, NODES)
    d.command([1.5, -2.0, 3.25, 1000.0], [0.5, -100.0, 40.0, 0.0])
    got = drain(peer)
    assert got == [
        cs.SetInputPos(0, 1.5, 0.5, 0.0),
        cs.SetInputPos(1, -2.0, -32.767, 0.0),
        cs.SetInputPos(2, 3.25, 32.767, 0.0),
        cs.SetInputPos(3, 1000.0, 0.0, 0.0),
    ]
    assert d.stats.ff_clamped == 2 and d.stats.frames_tx == 4


def test_arm_disarm_estop_sequences(buses: tuple[can.BusABC, can.BusABC]) -> None:
    bus, peer = buses
    d = ODriveReels(bus, (4, 5))
    send(peer, cs.encode_encoder_estimates(5, 7.25, 0.0))
    time.sleep(0.01)
    d.poll()
    d.arm()
    assert drain(peer) == [
        cs.ClearErrors(4, 0),
        cs.SetControllerMode(4, 3, 1),
        cs.SetAxisState(4, 8),
        cs.ClearErrors(5, 0),
        cs.SetControllerMode(5, 3, 1),
        cs.SetInputPos(5, 7.25, 0.0, 0.0),  # hold where the reel is
        cs.SetAxisState(5, 8),
    ]
    d.disarm()
    assert drain(peer) == [cs.SetAxisState(4, 1), cs.SetAxisState(5, 1)]
    d.estop()
    assert drain(peer) == [cs.Estop(4), cs.Estop(5)]
    d.set_limits(20.0, 10.0)
    assert drain(peer) == [cs.SetLimits(4, 20.0, 10.0), cs.SetLimits(5, 20.0, 10.0)]


def test_encoder_rtr_polling(buses: tuple[can.BusABC, can.BusABC]) -> None:
    bus, peer = buses
    d = ODriveReels(bus, (0, 1), encoder_rtr=True)
    d.poll()
    assert drain(peer) == [cs.RemoteRequest(0, 9), cs.RemoteRequest(1, 9)]
    d.request_errors()
    assert drain(peer) == [cs.RemoteRequest(0, 3), cs.RemoteRequest(1, 3)]
    clock = FakeClock()
    d2 = ODriveReels(bus, (0,), encoder_rtr=True, encoder_rtr_period_s=0.01, clock=clock)
    d2.poll()
    d2.poll()  # same clock time: rate-limited, nothing sent
    clock.now_s += 0.01
    d2.poll()
    assert drain(peer) == [cs.RemoteRequest(0, 9), cs.RemoteRequest(0, 9)]
    send(peer, cs.encode_get_error(1, 0x20, 0x20))
    time.sleep(0.01)
    d.poll()
    assert d.last_get_error(1) == cs.GetError(1, 0x20, 0x20)


def test_constructor_validation(buses: tuple[can.BusABC, can.BusABC]) -> None:
    bus = buses[0]
    with pytest.raises(ValueError, match="at least one"):
        ODriveReels(bus, [])
    with pytest.raises(ValueError, match="duplicate"):
        ODriveReels(bus, [1, 1])
    with pytest.raises(ValueError, match="outside"):
        ODriveReels(bus, [64])
    with pytest.raises(ValueError, match="encoder_rtr_period_s"):
        ODriveReels(bus, [1], encoder_rtr_period_s=-1.0)
    with pytest.raises(ValueError, match="catch_up_age_s"):
        ODriveReels(bus, [1], catch_up_age_s=0.0)


def test_open_bus_errors_are_named() -> None:
    with pytest.raises(BusOpenError, match="no_such_interface"):
        open_bus("no_such_interface", "x")
    with pytest.raises(ValueError, match="interface"):
        open_bus({"channel": "x"})
    bus = open_bus({"interface": "virtual", "channel": "cfg-test", "bitrate": 1_000_000})
    bus.shutdown()


def test_rx_bench_runs() -> None:
    assert rx_bench.pure_decode_rate(2000) > 0.0
    assert rx_bench.poll_rate(2000) > 0.0


def test_receive_path_throughput() -> None:
    """Full receive path (python-can virtual bus + Message objects + decode + update).

    Best of three runs, so a burst of load from other processes on the machine does not decide.
    """
    rate = 0.0
    for _ in range(3):
        rate = max(rate, rx_bench.poll_rate(20_000))
        if rate > 20_000:
            break
    print(f"ODriveReels.poll on virtual bus: {rate:,.0f} frames/s")
    assert rate > 20_000


# --- torque mode (the pre-tension before homing) ---------------------------------------------


def _heartbeats(d: ODriveReels, peer: can.BusABC, states: dict[int, tuple[int, int]]) -> None:
    """Give the driver a heartbeat (state, error) per node and wait until it has read them."""
    for node, (state, error) in states.items():
        send(peer, cs.encode_heartbeat(node, error, state))
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline:
        d.poll()
        if all(d.reading(n).heartbeat_stamp_s > NEVER_S for n in states):
            return
    raise AssertionError("heartbeats not received")


def test_odrive_reels_is_a_torque_driver(buses: tuple[can.BusABC, can.BusABC]) -> None:
    assert isinstance(ODriveReels(buses[0], NODES), TorqueDriver)


def test_enter_torque_mode_frames(buses: tuple[can.BusABC, can.BusABC]) -> None:
    bus, peer = buses
    d = ODriveReels(bus, (4, 5, 6), velocity_limit_rps=20.0, current_limit_a=10.0)
    # 4 idle, 5 already holding in closed loop, 6 in closed loop with an error bit
    _heartbeats(d, peer, {4: (1, 0), 5: (8, 0), 6: (8, 0x8)})
    assert d.enter_torque_mode([-0.8, 0.7, -0.9], [2.0, 3.0, 4.0]) is True
    torque, passthrough = cs.ControlMode.TORQUE_CONTROL, cs.InputMode.PASSTHROUGH
    assert (torque, passthrough) == (1, 1)
    assert drain(peer) == [
        cs.ClearErrors(4, 0),
        cs.SetLimits(4, 2.0, 10.0),
        cs.SetInputTorque(4, pytest.approx(-0.8)),  # the torque first: never zero in between
        cs.SetControllerMode(4, torque, passthrough),
        cs.SetAxisState(4, 8),
        # already in closed loop: no Clear_Errors, no state request (nothing to re-enter)
        cs.SetLimits(5, 3.0, 10.0),
        cs.SetInputTorque(5, pytest.approx(0.7)),
        cs.SetControllerMode(5, torque, passthrough),
        cs.ClearErrors(6, 0),
        cs.SetLimits(6, 4.0, 10.0),
        cs.SetInputTorque(6, pytest.approx(-0.9)),
        cs.SetControllerMode(6, torque, passthrough),
        cs.SetAxisState(6, 8),
    ]
    d.command_torque([-0.5, 0.25, 0.0])
    assert drain(peer) == [
        cs.SetInputTorque(4, -0.5),
        cs.SetInputTorque(5, 0.25),
        cs.SetInputTorque(6, 0.0),
    ]
    d.leave_torque_mode([1.5, -2.0, 3.25])
    position = cs.ControlMode.POSITION_CONTROL
    assert drain(peer) == [
        cs.SetInputPos(4, 1.5, 0.0, 0.0),
        cs.SetControllerMode(4, position, passthrough),
        cs.SetInputPos(4, 1.5, 0.0, 0.0),
        cs.SetInputPos(5, -2.0, 0.0, 0.0),
        cs.SetControllerMode(5, position, passthrough),
        cs.SetInputPos(5, -2.0, 0.0, 0.0),
        cs.SetInputPos(6, 3.25, 0.0, 0.0),
        cs.SetControllerMode(6, position, passthrough),
        cs.SetInputPos(6, 3.25, 0.0, 0.0),
        # the configured limits come back
        cs.SetLimits(4, 20.0, 10.0),
        cs.SetLimits(5, 20.0, 10.0),
        cs.SetLimits(6, 20.0, 10.0),
    ]
    # restored once: leaving again (or arming) sends no Set_Limits
    d.leave_torque_mode([1.5, -2.0, 3.25])
    assert not any(isinstance(m, cs.SetLimits) for m in drain(peer))


@pytest.mark.parametrize(
    ("velocity_limit_rps", "current_limit_a"), [(None, None), (20.0, None), (None, 10.0)]
)
def test_torque_mode_leaves_the_limits_alone_without_both_configured_values(
    buses: tuple[can.BusABC, can.BusABC],
    velocity_limit_rps: float | None,
    current_limit_a: float | None,
) -> None:
    bus, peer = buses
    d = ODriveReels(
        bus, (1,), velocity_limit_rps=velocity_limit_rps, current_limit_a=current_limit_a
    )
    assert d.enter_torque_mode([-0.5], [2.0]) is False  # a limit that could not be restored
    assert drain(peer) == [  # is not set
        cs.ClearErrors(1, 0),  # never heard from: not ready
        cs.SetInputTorque(1, -0.5),
        cs.SetControllerMode(1, 1, 1),
        cs.SetAxisState(1, 8),
    ]
    d.leave_torque_mode([0.5])
    assert drain(peer) == [
        cs.SetInputPos(1, 0.5, 0.0, 0.0),
        cs.SetControllerMode(1, 3, 1),
        cs.SetInputPos(1, 0.5, 0.0, 0.0),
    ]


def test_enter_torque_mode_without_limits_sends_none(buses: tuple[can.BusABC, can.BusABC]) -> None:
    bus, peer = buses
    d = ODriveReels(bus, (1,), velocity_limit_rps=20.0, current_limit_a=10.0)
    assert d.enter_torque_mode([0.0]) is False
    assert not any(isinstance(m, cs.SetLimits) for m in drain(peer))
    d.leave_torque_mode([0.0])
    assert not any(isinstance(m, cs.SetLimits) for m in drain(peer))


def test_arm_restores_limits_a_torque_mode_lowered(buses: tuple[can.BusABC, can.BusABC]) -> None:
    # An e-stop during the pre-tension: the torque mode is never left, the next arm restores.
    bus, peer = buses
    d = ODriveReels(bus, (2,), velocity_limit_rps=20.0, current_limit_a=10.0)
    assert d.enter_torque_mode([0.0], [1.0])
    d.estop()
    drain(peer)
    d.arm()
    got = drain(peer)
    assert got[0] == cs.SetLimits(2, 20.0, 10.0)
    assert got[1:] == [cs.ClearErrors(2, 0), cs.SetControllerMode(2, 3, 1), cs.SetAxisState(2, 8)]
    d.arm()
    assert not any(isinstance(m, cs.SetLimits) for m in drain(peer))


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 1e39])
def test_torque_mode_refuses_bad_values_and_sends_nothing(
    buses: tuple[can.BusABC, can.BusABC], bad: float
) -> None:
    bus, peer = buses
    d = ODriveReels(bus, NODES, velocity_limit_rps=20.0, current_limit_a=10.0)
    with pytest.raises(ValueError, match="velocity limit for node 2"):
        d.enter_torque_mode([0.0] * 4, [1.0, 1.0, bad, 1.0])
    with pytest.raises(ValueError, match="torque for node 0"):
        d.enter_torque_mode([bad, 0.0, 0.0, 0.0], [1.0] * 4)
    with pytest.raises(ValueError, match="torque for node 1"):
        d.command_torque([0.0, bad, 0.0, 0.0])
    with pytest.raises(ValueError, match="position for node 3"):
        d.leave_torque_mode([0.0, 0.0, 0.0, bad])
    assert drain(peer) == []
    assert d.stats.frames_tx == 0


def test_torque_mode_refuses_wrong_counts_and_non_positive_limits(
    buses: tuple[can.BusABC, can.BusABC],
) -> None:
    bus, peer = buses
    d = ODriveReels(bus, NODES, velocity_limit_rps=20.0, current_limit_a=10.0)
    for limits in ([1.0, 1.0, 0.0, 1.0], [1.0, -2.0, 1.0, 1.0]):
        with pytest.raises(ValueError, match="must be > 0"):
            d.enter_torque_mode([0.0] * 4, limits)
    with pytest.raises(ValueError, match="needs 4 values, got 3"):
        d.enter_torque_mode([0.0] * 4, [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="needs 4 values, got 2"):
        d.enter_torque_mode([0.0] * 2, [1.0] * 4)
    with pytest.raises(ValueError, match="needs 4 values, got 5"):
        d.command_torque([0.0] * 5)
    with pytest.raises(ValueError, match="needs 4 values, got 0"):
        d.leave_torque_mode([])
    with pytest.raises(ValueError, match="not a finite float32"):
        d.command_torque(cast(Any, [0.0, "x", 0.0, 0.0]))
    assert drain(peer) == []
    # a refused limit did not count as lowered: leaving sends no Set_Limits
    d.leave_torque_mode([0.0] * 4)
    assert not any(isinstance(m, cs.SetLimits) for m in drain(peer))


def test_torque_mode_send_errors_raise_bus_error_after_trying_every_axis() -> None:
    fake = ExplodingBus()  # node 1's frames fail
    d = ODriveReels(cast(Any, fake), NODES, velocity_limit_rps=20.0, current_limit_a=10.0)
    with pytest.raises(BusError, match=r"torque mode to node 1.*tx buffer full"):
        d.enter_torque_mode([0.1] * 4, [1.0] * 4)
    assert {m.arbitration_id >> 5 for m in fake.sent} == {0, 1, 2, 3}
    fake.sent.clear()
    with pytest.raises(BusError, match=r"Set_Input_Torque to node 1"):
        d.command_torque([0.1] * 4)
    assert [m.arbitration_id >> 5 for m in fake.sent] == [0, 1, 2, 3]
    fake.sent.clear()
    # leaving still restores the limits the failed enter may have lowered on the other axes
    with pytest.raises(BusError, match=r"position mode to node 1"):
        d.leave_torque_mode([0.0] * 4)
    limits = [m for m in fake.sent if m.arbitration_id & 0x1F == cs.SET_LIMITS]
    assert [m.arbitration_id >> 5 for m in limits] == [0, 1, 2, 3]
    assert d.stats.bus_errors >= 3


def test_constructor_validates_the_configured_limits(buses: tuple[can.BusABC, can.BusABC]) -> None:
    bus = buses[0]
    for bad in (0.0, -1.0, math.nan, math.inf, 1e39):
        with pytest.raises(ValueError, match="velocity_limit_rps"):
            ODriveReels(bus, [1], velocity_limit_rps=bad)
        with pytest.raises(ValueError, match="current_limit_a"):
            ODriveReels(bus, [1], current_limit_a=bad)
    d = ODriveReels(bus, [1], velocity_limit_rps=15, current_limit_a=8.5)
    assert (d.velocity_limit_rps, d.current_limit_a) == (15.0, 8.5)


def test_open_driver_takes_the_configured_limits(buses: tuple[can.BusABC, can.BusABC]) -> None:
    from drivers.odrive.driver import open_driver
    from drivers.registry import LoopSettings

    bus, peer = buses
    loop = LoopSettings(0.001, 0.08)
    d = open_driver(bus, (0,), {"velocity_limit_rps": 25.0, "current_limit_a": 12.0}, loop)
    assert (d.velocity_limit_rps, d.current_limit_a) == (25.0, 12.0)
    assert d.enter_torque_mode([0.0], [2.0]) is True
    d.leave_torque_mode([0.0])
    assert drain(peer)[-1] == cs.SetLimits(0, 25.0, 12.0)
    d = open_driver(bus, (0,), {"current_limit_a": 12.0}, loop)
    assert (d.velocity_limit_rps, d.current_limit_a) == (None, 12.0)
    with pytest.raises(ValueError, match="current_limit_a"):
        open_driver(bus, (0,), {"current_limit_a": -1.0}, loop)
    with pytest.raises(ValueError, match=r"named \['vel_limit'\]"):
        open_driver(bus, (0,), {"vel_limit": 1.0}, loop)


def test_after_a_state_changing_command_the_status_is_fresh_only_on_a_later_heartbeat(
    buses: tuple[can.BusABC, can.BusABC],
) -> None:
    bus, peer = buses
    d = ODriveReels(bus, NODES)
    r = d.read()
    estop = int(cs.ODriveError.ESTOP_REQUESTED)
    for n in NODES:
        send(peer, cs.encode_heartbeat(n, estop, cs.AxisState.IDLE))
    time.sleep(0.01)
    d.poll()
    assert all(x.fault is not None and x.status_fresh() for x in r)
    # A heartbeat that arrived before the command, read after it, is still from before.
    send(peer, cs.encode_heartbeat(0, estop, cs.AxisState.IDLE))
    time.sleep(0.01)
    d.enter_torque_mode([0.1] * len(NODES))  # clears the errors of the axes not in closed loop
    d.poll()
    assert all(x.command_stamp_s > x.status_stamp_s for x in r)
    assert not any(x.status_fresh() for x in r)
    assert r[0].fault is not None  # what the drive said before it took the Clear_Errors
    # The answer to the command: fresh, and without the error.
    for n in NODES:
        send(peer, cs.encode_heartbeat(n, 0, cs.AxisState.CLOSED_LOOP_CONTROL))
    time.sleep(0.01)
    d.poll()
    assert all(x.status_fresh() and x.ready and x.fault is None for x in r)
    snap = r[0].snapshot()
    assert (snap.command_stamp_s, snap.status_stamp_s) == (
        r[0].command_stamp_s,
        r[0].status_stamp_s,
    )
    # disarm, estop and arm are state-changing commands too
    for command in (d.disarm, d.estop, d.arm):
        command()
        assert not any(x.status_fresh() for x in r), command
        for n in NODES:
            send(peer, cs.encode_heartbeat(n, 0, cs.AxisState.IDLE))
        time.sleep(0.01)
        d.poll()
        assert all(x.status_fresh() for x in r), command
