"""The G-code streamer against a fake daemon: path then appends, waiting while the queue is
full, resting at waits, disarm and e-stop, and a refusal or a robot gone from the motion
states ends the job."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import pytest

from controller.cli.client import Refused, WaitTimeout
from controller.cli.gcode import Streamer
from controller.cli.pathstream import (
    LOW_WATER_S,
    MAX_POLL_S,
    POLL_S,
    StreamProgress,
    StreamRefused,
    stream_points,
)
from controller.core.gcode import parse_lines
from controller.core.gcode_job import Chunk, GcodeFrame, chunks, interpret
from controller.core.motion import QUEUE_FULL

Vec3 = tuple[float, float, float]


class FakeRobot:
    """Takes paths; refuses `full` appends with the queue-full text first (MOVING meanwhile);
    its state is MOVING for `moving_polls` status queries after each path, then HOLDING (or
    `state`)."""

    def __init__(self, full: int = 0, moving_polls: int = 2, state: str = "HOLDING") -> None:
        self.sent: list[tuple[int, float, bool]] = []
        self.verbs: list[str] = []
        self.full = full
        self.moving_polls = moving_polls
        self.left = 0
        self.state = state
        self.refused = False

    def path(self, points_m: Sequence[Vec3], speed_mps: float, append: bool) -> Any:
        if append and self.full > 0:
            self.full -= 1
            self.refused = True
            raise Refused(f"append: {QUEUE_FULL}: 100000 + 3 points would exceed 100000")
        self.sent.append((len(points_m), speed_mps, append))
        self.left = self.moving_polls
        return {"ok": True}

    def status(self) -> dict[str, Any]:
        if self.left > 0:
            self.left -= 1
            return {"state": "MOVING"}
        if self.refused and self.state == "HOLDING":
            self.refused = False
            return {"state": "MOVING"}  # a full queue is being flown
        return {"state": self.state}

    def command(self, verb: str) -> Any:
        self.verbs.append(verb)
        return {"ok": True}


def _steps(text: str, max_points: int = 2) -> list[Any]:
    job = interpret(parse_lines(text.strip().splitlines()), GcodeFrame(), (0.0, 0.0, 0.0))
    return list(chunks(job.actions, max_points))


def _run(robot: FakeRobot, text: str) -> Streamer:
    now = [0.0]

    def sleep(s: float) -> None:
        now[0] += s

    st = Streamer(robot, clock=lambda: now[0], sleep=sleep)
    for step in _steps(text):
        st.send(step)
    return st


def test_path_then_appends_then_a_new_path_after_a_wait() -> None:
    robot = FakeRobot(full=3)
    st = _run(robot, "G1 X1 F600\nG1 X2\nG1 X3\nG1 X4 F1200\nG4 P10\nG1 X5\nM84\nM112\n")
    assert robot.sent == [
        (2, pytest.approx(0.01), False),
        (1, pytest.approx(0.01), True),  # after three "queue full" refusals
        (1, pytest.approx(0.02), True),
        (1, pytest.approx(0.02), False),  # the dwell let the robot rest: a new path
    ]
    assert st.full_waits == 3 and st.moves == 5 and st.chunks == 4
    assert robot.verbs == ["disarm", "estop"]


def test_a_refusal_other_than_queue_full_ends_the_job() -> None:
    class Refusing(FakeRobot):
        def path(self, points_m: Sequence[Vec3], speed_mps: float, append: bool) -> Any:
            if append:
                raise Refused("points_m[0] [..]: on the leg to it: z below floor_z_m")
            return super().path(points_m, speed_mps, append)

    with pytest.raises(Refused, match="floor_z_m"):
        _run(Refusing(), "G1 X1 F600\nG1 X2\nG1 X3\n")


def test_a_robot_that_leaves_the_motion_states_ends_the_job() -> None:
    with pytest.raises(Refused, match="the robot went FAULT during the job"):
        _run(FakeRobot(state="FAULT", moving_polls=1), "G1 X1 F600\nM400\n")
    with pytest.raises(Refused, match="went ESTOPPED"):
        _run(FakeRobot(full=1, state="ESTOPPED", moving_polls=0), "G1 X1 F600\nG1 X2\nG1 X3\n")


def test_rest_has_a_deadline() -> None:
    robot = FakeRobot(moving_polls=10**9)
    now = [0.0]

    def sleep(s: float) -> None:
        now[0] += s

    st = Streamer(robot, clock=lambda: now[0], sleep=sleep)
    st.send(_steps("G1 X1 F600\n")[0])
    with pytest.raises(WaitTimeout):
        st.rest(deadline_s=5.0)
    assert 5.0 <= now[0] < 5.5


def test_a_chunk_of_the_widest_points_fits_the_daemons_fast_decoder() -> None:
    import json

    from controller.cli.gcode import SENT_DECIMALS, chunk_points
    from controller.core.commands import C_DECODE_MAX_BYTES, MAX_PATH_POINTS_SENT

    n = chunk_points(MAX_PATH_POINTS_SENT, C_DECODE_MAX_BYTES)
    assert 300 <= n < MAX_PATH_POINTS_SENT
    widest = round(-12345.123456789, SENT_DECIMALS)
    payload = {"points_m": [[widest] * 3] * n, "speed_mps": 0.1234567890123456, "append": True}
    assert len(json.dumps(payload)) <= C_DECODE_MAX_BYTES
    assert chunk_points(5, C_DECODE_MAX_BYTES) == 5 and chunk_points(1000, 10) == 1


# ------------------------------------------------------ one pacing rule with `cablebot path`
class QueueDaemon:
    """A daemon's path queue in seconds of motion, flown at `rate` s per s of the fake clock:
    path replies and status carry its depth as the daemon words them; an append beyond
    `max_points` is refused with the core's queue-full text, or any append with `refuse_with`.
    `at_send` records the depth (s) the client could know of when each append arrived."""

    def __init__(self, s_per_point: float, max_points: int = 10**9) -> None:
        self.k = s_per_point
        self.max_points = max_points
        self.now = 0.0
        self.queued_s = 0.0
        self.at_send: list[float] = []
        self.sent: list[tuple[int, bool]] = []
        self.full_refusals = 0
        self.polls = 0
        self.refuse_with: str | None = None

    def sleep(self, s: float) -> None:
        self.queued_s = max(0.0, self.queued_s - s)
        self.now += s

    def _path(self) -> dict[str, Any]:
        points = round(self.queued_s / self.k)
        return {
            "queued_points": points,
            "queued_s": self.queued_s,
            "queue_full": points >= self.max_points,
        }

    def send(self, n: int, append: bool) -> dict[str, Any]:
        if append and self.refuse_with is not None:
            raise Refused(self.refuse_with)
        if append and round(self.queued_s / self.k) + n > self.max_points:
            self.full_refusals += 1
            raise Refused(f"append: {QUEUE_FULL}: {self.queued_s / self.k:.0f} + {n} points")
        if append:
            self.at_send.append(self.queued_s)
        else:
            self.queued_s = 0.0  # a new path replaces the queue
        self.queued_s += n * self.k
        self.sent.append((n, append))
        return {"ok": True, **self._path()}

    def status(self) -> dict[str, Any]:
        self.polls += 1
        return {"state": "MOVING" if self.queued_s > 0 else "HOLDING", "path": self._path()}


class QueueRobot:
    """`RobotLink` over a `QueueDaemon`."""

    def __init__(self, daemon: QueueDaemon) -> None:
        self.d = daemon

    def path(self, points_m: Sequence[Vec3], speed_mps: float, append: bool) -> Any:
        return self.d.send(len(points_m), append)

    def status(self) -> dict[str, Any]:
        return self.d.status()

    def command(self, verb: str) -> Any:
        return {"ok": True}


def _by_gcode(d: QueueDaemon, chunk_sizes: list[int]) -> Streamer:
    st = Streamer(QueueRobot(d), clock=lambda: d.now, sleep=d.sleep)
    for i, n in enumerate(chunk_sizes):
        st.send(Chunk(((0.0, 0.0, 1.0),) * n, 0.1, i + 1, i + 1, 1))
    return st


def _by_path(d: QueueDaemon, chunk_sizes: list[int]) -> StreamProgress:
    n = chunk_sizes[0]
    assert all(c == n for c in chunk_sizes[:-1])
    return stream_points(
        [[0.0, 0.0, 1.0]] * sum(chunk_sizes),
        lambda pts, more: d.send(len(pts), more),
        d.status,
        lambda text, now: None,
        refused=Refused,
        chunk=n,
        clock=lambda: d.now,
        sleep=d.sleep,
    )


def test_gcode_and_path_streams_send_at_the_same_low_water_mark() -> None:
    sizes = [500] * 30  # 1 s of motion a chunk, 30 s in all
    by_gcode, by_path = QueueDaemon(2e-3), QueueDaemon(2e-3)
    _by_gcode(by_gcode, sizes)
    _by_path(by_path, sizes)
    for d in (by_gcode, by_path):
        assert d.sent == [(500, False)] + [(500, True)] * 29
        # never an append while the daemon said LOW_WATER_S or more was queued ...
        assert max(d.at_send) < LOW_WATER_S
        # ... and the queue kept near the mark, not one chunk at a time: no dry queue
        assert min(d.at_send[3:]) > LOW_WATER_S - 2 * POLL_S - 1.0
        assert d.polls > 0 and d.full_refusals == 0
    assert by_gcode.at_send == by_path.at_send
    assert by_gcode.polls == by_path.polls


def test_gcode_and_path_streams_wait_out_the_same_queue_full_refusal() -> None:
    sizes = [100] * 40  # tiny chunks, a small queue: its bound bites before the mark
    by_gcode, by_path = QueueDaemon(1e-3, max_points=250), QueueDaemon(1e-3, max_points=250)
    st = _by_gcode(by_gcode, sizes)
    prog = _by_path(by_path, sizes)
    assert by_gcode.full_refusals == st.full_waits > 0
    assert by_path.full_refusals == prog.retries == st.full_waits
    assert by_gcode.sent == by_path.sent == [(100, False)] + [(100, True)] * 39
    import controller.cli.gcode as gcode_mod

    assert not hasattr(gcode_mod, "QUEUE_FULL_TEXT")  # one text, the daemon's: no copy


def test_gcode_and_path_streams_end_on_the_same_other_refusal() -> None:
    why = "no path in progress to append to (none sent, or it was stopped)"
    by_gcode, by_path = QueueDaemon(1e-3), QueueDaemon(1e-3)
    by_gcode.refuse_with = by_path.refuse_with = why
    with pytest.raises(Refused, match=r"no path in progress"):
        _by_gcode(by_gcode, [100, 100])
    with pytest.raises(StreamRefused, match=r"no path in progress.*after 100/200 points"):
        _by_path(by_path, [100, 100])
    assert by_gcode.sent == by_path.sent == [(100, False)]


@pytest.mark.parametrize("state", ["HOLDING", "FAULT", "ESTOPPED", "DISARMED"])
def test_gcode_and_path_streams_end_in_the_same_states(state: str) -> None:
    """While a stream waits for room, HOLDING (a path that ran dry holds at its last point; an
    append continues it) goes on and any other state ends both streamers."""

    class Once(QueueDaemon):
        def status(self) -> dict[str, Any]:
            st = super().status()
            return {**st, "state": state, "reason": "why"} if self.polls == 1 else st

    by_gcode, by_path = Once(1e-3), Once(1e-3)
    sizes = [4000, 10]  # 4 s queued: the second chunk waits, polling
    if state == "HOLDING":
        _by_gcode(by_gcode, sizes)
        _by_path(by_path, sizes)
    else:
        with pytest.raises(Refused, match=rf"the robot went {state} \(why\) during the job"):
            _by_gcode(by_gcode, sizes)
        with pytest.raises(StreamRefused, match=rf"robot is {state} \(why\).*after 4000/4010"):
            _by_path(by_path, sizes)
    for d in (by_gcode, by_path):
        assert d.polls >= 1
        assert d.sent == ([(4000, False), (10, True)] if state == "HOLDING" else [(4000, False)])


def test_a_deep_queue_is_polled_until_it_drains_to_the_mark_not_ten_times_a_second() -> None:
    """A chunk of 40 s of motion: both streamers poll status about every `MAX_POLL_S` while
    it drains (not every `POLL_S`: each poll costs the daemon a status), and send the next
    chunk as the queue reaches the low-water mark, not later."""
    for run in (_by_gcode, _by_path):
        d = QueueDaemon(1e-3)
        naps: list[float] = []
        sleep = d.sleep

        def nap(s: float, sleep: Any = sleep, naps: list[float] = naps) -> None:
            naps.append(s)
            sleep(s)

        d.sleep = nap  # type: ignore[method-assign]
        run(d, [40_000, 10])
        assert d.sent == [(40_000, False), (10, True)]
        assert LOW_WATER_S - POLL_S <= d.at_send[0] < LOW_WATER_S
        assert max(naps) <= MAX_POLL_S and d.polls == len(naps)
        assert (40.0 - LOW_WATER_S) / MAX_POLL_S <= d.polls < (40.0 - LOW_WATER_S) / MAX_POLL_S + 5


def test_m593_rests_then_sends_the_shaper_command() -> None:
    class Shaped(FakeRobot):
        def __init__(self) -> None:
            super().__init__()
            self.payloads: list[Any] = []

        def command(self, verb: str, payload: Any = None) -> Any:
            self.payloads.append(payload)
            return super().command(verb)

    robot = Shaped()
    st = _run(robot, 'G1 X1 F600\nM593 P"zvd" F40 S0.1\nG1 X2\n')
    assert robot.verbs == ["shaper"]
    assert robot.payloads == [{"type": "zvd", "frequency_hz": 40.0, "damping_ratio": 0.1}]
    # the move before it was flown to rest: the move after is a new path
    assert [s[2] for s in robot.sent] == [False, False]
    assert st.chunks == 2
