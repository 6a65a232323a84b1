"""The client library against a real daemon (the built-in robot, simulated drives in the
daemon's process, Zenoh on a loopback port of its own): reading, every verb, waiting for
arrival, refusals and bad input told apart, streams of any length, braking when cancelled."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from controller.client import (
    DaemonAbsent,
    Failed,
    InputError,
    Refused,
    Robot,
    StateChange,
    Status,
    WaitTimeout,
    discover,
)
from controller.core.commands import MAX_PATH_POINTS_SENT
from controller.service.zenoh_io import free_tcp_port
from tests.client.client_daemon import ClientDaemon, client_daemon, ready

pytestmark = pytest.mark.slow

START = (0.0, 0.0, 2.0)


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ClientDaemon]:
    with client_daemon(tmp_path_factory.mktemp("client")) as d:
        yield d


@pytest.fixture
def robot(daemon: ClientDaemon) -> Iterator[Robot]:
    with daemon.robot() as r:
        ready(r)
        yield r


def _counters(robot: Robot) -> dict[str, Any]:
    commands = robot.status().raw["zenoh"]["commands"]
    assert isinstance(commands, dict)
    return dict(commands)


def _wait_state(robot: Robot, state: str, timeout_s: float = 20.0) -> Status:
    deadline = time.monotonic() + timeout_s
    while True:
        st = robot.status()
        if st.state == state:
            return st
        assert time.monotonic() < deadline, st
        time.sleep(0.05)


# ------------------------------------------------------------------------------ reading
def test_status_and_pose_are_typed_and_say_where_the_robot_is(robot: Robot) -> None:
    st = robot.status()
    assert st.state == "HOLDING" and st.homed
    assert st.position_m is not None and math.dist(st.position_m, START) < 0.05
    assert st.node_ids == (0, 1, 2, 3) and len(st.axes) == 4
    assert all(ax.ready and ax.fault is None for ax in st.axes)
    assert st.max_speed_mps is not None and st.max_speed_mps > 0.0
    assert st.path.queued_points == 0 and not st.path.queue_full
    assert st.raw["state"] == "HOLDING"  # the reply as sent, for what is not typed
    pose = robot.pose()
    assert pose.valid and pose.position_m is not None
    assert math.dist(pose.position_m, st.position_m) < 1e-3
    assert pose.state == "HOLDING" and len(pose.cable_lengths_m) == 4
    assert all(isinstance(v, float) and math.isfinite(v) for v in pose.cable_lengths_m)
    assert pose.as_dict()["seq"] == pose.seq


def test_pose_stream_and_callback_get_every_sample_in_order(robot: Robot) -> None:
    got: list[int] = []
    sub = robot.on_pose(lambda p: got.append(p.seq))
    try:
        with robot.poses() as stream:
            seqs = [next(stream).seq for _ in range(20)]
    finally:
        sub.close()
    assert seqs == sorted(seqs) and len(set(seqs)) == 20
    assert seqs[-1] - seqs[0] < 40  # 100 Hz: a few lost at most on a busy machine
    assert got and got == sorted(got)
    n = len(got)
    time.sleep(0.3)
    assert len(got) == n  # closed: no more calls


def test_discover_lists_the_daemon_by_its_prefix(daemon: ClientDaemon) -> None:
    found = {d.prefix: d for d in discover(daemon.endpoint)}
    assert daemon.prefix in found
    info = found[daemon.prefix]
    assert info.name == daemon.prefix.split("/")[1] and info.state is not None
    assert info.listen == (daemon.endpoint,)


def test_the_robot_description_is_the_daemons(robot: Robot, daemon: ClientDaemon) -> None:
    desc = robot.description()
    assert desc.name == daemon.prefix.split("/")[1]
    assert desc.config.limits.max_speed_mps == robot.status().max_speed_mps
    assert desc.text == daemon.config.read_text()
    assert robot.description() is desc  # fetched once


def test_no_truth_without_the_physical_plant(robot: Robot) -> None:
    assert robot.truth(0.5) is None


# ------------------------------------------------------------------------------ moving
def test_move_wait_arrives_at_the_target(robot: Robot) -> None:
    target = (1.0, -0.5, 2.2)
    reply = robot.move(target, speed_mps=1.0)
    assert reply.verb == "move" and reply.target_m == target and reply.speed_mps == 1.0
    assert robot.moving
    seen: list[float] = []
    pose = robot.wait(60.0, on_progress=lambda p: seen.append(p.remaining_m))
    assert pose.state == "HOLDING" and pose.position_m is not None
    assert math.dist(pose.position_m, target) <= 1e-3
    assert seen and seen[0] > seen[-1]  # the distance left shrank
    assert not robot.moving
    with pytest.raises(InputError, match="nothing to wait for"):
        robot.wait(1.0)
    robot.move(START)
    robot.wait(60.0)


def test_a_refusal_carries_the_daemons_reason_and_nothing_moves(robot: Robot) -> None:
    before = robot.status().setpoint_m
    with pytest.raises(Refused, match=r"z=90 m above the anchor plane"):
        robot.move((0.0, 0.0, 90.0))
    assert not robot.moving
    assert robot.status().setpoint_m == before


def test_bad_input_is_caught_before_anything_is_sent(robot: Robot) -> None:
    before = _counters(robot)
    with pytest.raises(InputError, match="three finite numbers"):
        robot.move((0.0, 0.0, math.nan))
    with pytest.raises(InputError, match="speed_mps"):
        robot.move((1.0, 0.0, 2.0), speed_mps=0.0)
    with pytest.raises(InputError, match=r"points_m\[1\]"):
        robot.path([(1.0, 0.0, 2.0), (1.0, math.inf, 2.0)])
    with pytest.raises(InputError, match="position_m"):
        robot.command("home", {"position_m": [0.0, "x", 2.0]})
    with pytest.raises(InputError, match="unknown command"):
        robot.command("fly")
    with pytest.raises(InputError, match="velocity"):
        robot.velocity((math.nan, 0.0, 0.0))
    assert _counters(robot) == before  # not one command reached the daemon


def test_a_speed_above_the_robots_maximum_is_refused_before_sending(robot: Robot) -> None:
    vmax = robot.status().max_speed_mps
    assert vmax is not None
    before = _counters(robot)
    with pytest.raises(InputError, match=r"above the robot's limits.max_speed_mps"):
        robot.move((1.0, 0.0, 2.0), speed_mps=vmax * 2)
    assert _counters(robot) == before


def test_a_path_is_checked_whole_before_its_first_point_moves(robot: Robot) -> None:
    before = _counters(robot)
    pts = [(1.0, 0.0, 2.0), (2.0, 0.0, 2.0), (3.0, 0.0, 90.0), (0.0, 0.0, 2.0)]
    with pytest.raises(InputError, match=r"points_m point 3: refused: .*nothing was sent"):
        robot.path(pts)
    long = [(0.001 * k, 0.0, 2.0) for k in range(3000)] + [(0.0, 0.0, 90.0)]
    with pytest.raises(InputError, match="point 3001"):
        robot.iter_path(long)
    assert _counters(robot) == before


def test_no_daemon_and_wrong_prefix_are_daemon_absent(daemon: ClientDaemon) -> None:
    with pytest.raises(DaemonAbsent, match="cannot connect"):
        Robot(f"tcp/127.0.0.1:{free_tcp_port()}")
    with Robot(daemon.endpoint, "cablebot/nobody", timeout_s=1.0) as robot:
        with pytest.raises(DaemonAbsent, match="no reply"):
            robot.status()
        with pytest.raises(DaemonAbsent, match=r"no pose sample within 0\.5 s"):
            robot.pose(timeout_s=0.5)


def test_wait_times_out_and_the_robot_goes_on(robot: Robot) -> None:
    robot.move((5.0, 0.0, 2.0), speed_mps=0.5)
    with pytest.raises(WaitTimeout, match="goes on with the motion"):
        robot.wait(0.5)
    assert robot.status().state == "MOVING" and robot.moving
    robot.stop()
    assert not robot.moving
    _wait_state(robot, "HOLDING")


def test_path_and_append_then_wait(robot: Robot) -> None:
    square = [(1.0, 0.0, 2.0), (1.0, 1.0, 2.0), (0.0, 1.0, 2.0)]
    reply = robot.path(square, speed_mps=1.5)
    assert reply.points == 3 and reply.queue is not None
    reply = robot.path([START], append=True)
    assert reply.points == 1
    pose = robot.wait(60.0)
    assert pose.position_m is not None and math.dist(pose.position_m, START) <= 1e-3


def test_a_long_path_streams_with_the_daemons_flow_control(robot: Robot) -> None:
    n = 2 * MAX_PATH_POINTS_SENT + 500
    pts = [(0.5 * math.sin(k / 400.0), 0.5 * (1 - math.cos(k / 400.0)), 2.0) for k in range(n)]
    pts.append(START)
    seen: list[tuple[int, int]] = []
    prog = robot.stream_path(
        pts, speed_mps=2.0, on_progress=lambda p: seen.append((p.sent, p.commands))
    )
    assert prog.sent == prog.total == n + 1 and prog.commands == 3
    assert seen == sorted(seen) and seen[-1] == (n + 1, 3)
    pose = robot.wait(120.0)
    assert pose.position_m is not None and math.dist(pose.position_m, START) <= 1e-3


def test_estop_reset_arm_and_arm_again(robot: Robot) -> None:
    assert robot.estop().state == "ESTOPPED"
    with pytest.raises(Refused, match="ESTOPPED"):
        robot.move((1.0, 0.0, 2.0))
    assert robot.reset().state == "DISARMED"
    reply = robot.arm()
    assert reply.state == "ARMING" and not reply.already_armed
    assert robot.wait_armed(20.0).state == "HOLDING"
    again = robot.arm()
    assert again.already_armed and again.state == "HOLDING"


def test_home_declares_the_pose(robot: Robot) -> None:
    here = robot.status().position_m
    assert here is not None
    reply = robot.home(here)
    assert reply.position_m is not None and math.dist(reply.position_m, here) < 1e-9
    assert reply.offsets_rev is not None and sorted(reply.offsets_rev) == [0, 1, 2, 3]


def test_pretension_is_refused_by_name_on_the_kinematic_simulator(robot: Robot) -> None:
    with pytest.raises(Refused, match="pre"):
        robot.pretension(START)


def test_velocity_samples_fly_and_zero_brakes(robot: Robot) -> None:
    x0 = robot.pose().position_m
    assert x0 is not None
    deadline = time.monotonic() + 1.0
    while time.monotonic() < deadline:
        robot.velocity((0.2, 0.0, 0.0))
        time.sleep(0.05)
    robot.velocity((0.0, 0.0, 0.0))
    st = _wait_state(robot, "HOLDING")
    assert st.position_m is not None and st.position_m[0] - x0[0] > 0.05
    robot.move(START)
    robot.wait(60.0)


def _setpoints_taken(robot: Robot) -> int:
    taken = robot.status().raw["zenoh"]["setpoints"]["ok"]
    assert isinstance(taken, int)
    return taken


def test_streamed_setpoints_are_followed(robot: Robot) -> None:
    target = (0.02, 0.0, 2.0)
    before = _setpoints_taken(robot)
    sent = 0
    deadline = time.monotonic() + 20.0
    while True:
        robot.setpoint(target)
        sent += 1
        pose = robot.pose(max_age_s=0.0)
        if pose.position_m is not None and math.dist(pose.position_m, target) < 1e-3:
            break
        assert time.monotonic() < deadline, pose
        time.sleep(0.05)
    # every sample taken before the move goes: a late one (latest wins) would replace it
    while _setpoints_taken(robot) < before + sent:
        assert time.monotonic() < deadline
        time.sleep(0.05)
    robot.move(START)
    robot.wait(60.0)


def test_state_changes_are_heard(robot: Robot) -> None:
    changes: list[StateChange] = []
    sub = robot.on_state(changes.append)
    try:
        robot.move((0.5, 0.0, 2.0))
        robot.wait(60.0)
        deadline = time.monotonic() + 10.0  # the state's own sample may come after the pose's
        while "HOLDING" not in [c.state for c in changes]:
            assert time.monotonic() < deadline, changes
            time.sleep(0.02)
    finally:
        sub.close()
    assert [c.state for c in changes][:2] == ["MOVING", "HOLDING"]
    assert all(c.stamp_ns > 0 for c in changes)


def test_a_robot_is_shared_between_threads(robot: Robot) -> None:
    errors: list[BaseException] = []
    states: list[str] = []

    def ask() -> None:
        try:
            for _ in range(10):
                states.append(robot.status().state)
                robot.pose()
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=ask) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60.0)
    assert not errors and states == ["HOLDING"] * 40


# ------------------------------------------------------------------------------ cancelling
def _stopped_short(robot: Robot, target: tuple[float, float, float]) -> Status:
    st = _wait_state(robot, "HOLDING")
    assert st.setpoint_m is not None and math.dist(st.setpoint_m, target) > 1.0, st
    return st


def test_an_exception_leaving_the_with_block_brakes_the_robot(daemon: ClientDaemon) -> None:
    target = (10.0, 0.0, 2.0)
    with daemon.robot() as r:
        ready(r)
    with pytest.raises(RuntimeError) as info, daemon.robot() as robot:
        robot.move(target, speed_mps=0.5)
        assert robot.status().state == "MOVING"
        raise RuntimeError("the operator's script failed")
    assert any("braked to a hold" in note for note in info.value.__notes__)
    with daemon.robot() as robot:
        _stopped_short(robot, target)
        ready(robot)


def test_keyboard_interrupt_in_a_wait_brakes_the_robot(robot: Robot) -> None:
    target = (10.0, 0.0, 2.0)
    robot.move(target, speed_mps=0.5)

    def ctrl_c(_: Any) -> None:
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        robot.wait(60.0, on_progress=ctrl_c)
    assert not robot.moving
    _stopped_short(robot, target)


def test_leaving_a_stream_early_brakes_the_robot(robot: Robot) -> None:
    pts = [(0.001 * k, 0.0, 2.0) for k in range(4 * MAX_PATH_POINTS_SENT)]
    target = pts[-1]
    for prog in robot.iter_path(pts, speed_mps=0.5):
        assert prog.sent > 0
        break
    assert not robot.moving
    st = _wait_state(robot, "HOLDING")
    assert st.setpoint_m is not None and math.dist(st.setpoint_m, target) > 1.0


def test_a_wait_cancelled_from_another_thread_brakes(robot: Robot) -> None:
    from controller.client.errors import Cancelled

    target = (10.0, 0.0, 2.0)
    robot.move(target, speed_mps=0.5)
    cancel = threading.Event()
    threading.Timer(0.5, cancel.set).start()
    t0 = time.monotonic()
    with pytest.raises(Cancelled):
        robot.wait(60.0, cancel=cancel)
    assert time.monotonic() - t0 < 10.0
    _stopped_short(robot, target)


def test_a_motion_another_client_stops_fails_the_wait_at_once(
    robot: Robot, daemon: ClientDaemon
) -> None:
    target = (10.0, 0.0, 2.0)
    robot.move(target, speed_mps=0.5)
    with daemon.robot() as other:
        threading.Timer(0.5, other.stop).start()
        t0 = time.monotonic()
        with pytest.raises(Failed, match=r"short of x=\+10\.000"):
            robot.wait(120.0)
        assert time.monotonic() - t0 < 30.0


def test_a_robot_made_on_a_session_of_ones_own_leaves_it_open(daemon: ClientDaemon) -> None:
    from controller.client.transport import open_session

    with open_session(daemon.endpoint) as session:
        with Robot(session=session, prefix=daemon.prefix) as robot:
            assert robot.status().state == "HOLDING"
        with Robot(session=session, prefix=daemon.prefix) as robot:
            assert robot.pose().valid


def test_the_default_endpoint_and_prefix_come_from_the_environment(
    daemon: ClientDaemon, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("CABLEBOT_ENDPOINT", daemon.endpoint)
    monkeypatch.setenv("CABLEBOT_PREFIX", daemon.prefix)
    with Robot() as robot:
        assert robot.endpoint == daemon.endpoint and robot.prefix == daemon.prefix
        assert robot.status().state == "HOLDING"


def test_a_physical_plant_publishes_its_truth(tmp_path: Path) -> None:
    sim = {"plant": "physical", "cable_ea_n": 2e5}
    with client_daemon(tmp_path, sim=sim) as d, d.robot() as robot:
        truth = robot.truth(10.0)
        assert truth is not None and truth.position_m is not None
        assert len(truth.tensions_n) == 4
        assert all(t is not None and 50.0 < t < 200.0 for t in truth.tensions_n)
        pose = robot.pose()
        assert pose.position_m is not None
        assert math.dist(pose.position_m, truth.position_m) < 1e-2
