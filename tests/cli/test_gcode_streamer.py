"""The G-code streamer against a fake daemon: path then appends, waiting while the queue is
full, resting at waits, disarm and e-stop, and a refusal or a robot gone from the motion
states ends the job."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import pytest

from controller.cli.client import Refused, WaitTimeout
from controller.cli.gcode import QUEUE_FULL_TEXT, Streamer
from controller.core.gcode import parse_lines
from controller.core.gcode_job import GcodeFrame, chunks, interpret

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
            raise Refused(f"append: {QUEUE_FULL_TEXT}: 100000 + 3 points would exceed 100000")
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
