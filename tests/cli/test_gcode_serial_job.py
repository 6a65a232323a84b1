"""The serial link's job (`gcode_serial.SerialJob`) against a fake daemon: after a refused chunk
halts the job, `M999` takes motion lines again from where the robot rests, the job's modal
state kept as a firmware keeps it."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import pytest

from controller.cli.client import Refused
from controller.cli.gcode_serial import SerialJob
from controller.service.config import default_config

Vec3 = tuple[float, float, float]


class Robot:
    """Holds at `at`; takes a path whose points stay within 10 m in x, moving `at` to its end;
    refuses any other as the daemon refuses a point outside the workspace."""

    def __init__(self) -> None:
        self.at: Vec3 = (0.0, 0.0, 2.0)
        self.paths: list[tuple[list[Vec3], float, bool]] = []
        self.verbs: list[str] = []

    def status(self) -> dict[str, Any]:
        return {"state": "HOLDING", "setpoint_m": list(self.at)}

    def path(self, points_m: Sequence[Vec3], speed_mps: float, append: bool) -> Any:
        if any(abs(p[0]) > 10.0 for p in points_m):
            raise Refused("points_m[0]: (x, y) = (100, 0) m is outside the workspace")
        self.paths.append(([tuple(p) for p in points_m], speed_mps, append))
        self.at = tuple(points_m[-1])  # type: ignore[assignment]
        return {"ok": True}

    def command(self, verb: str) -> Any:
        self.verbs.append(verb)
        return {"ok": True, "state": "HOLDING"}


def test_m999_resumes_from_the_rest_point_with_the_jobs_units_mode_and_feed() -> None:
    robot = Robot()
    out: list[str] = []
    job = SerialJob(robot, default_config(), out.append)
    for line in ("G21", "G91", "G1 X100 F6000"):  # relative millimetres at 0.1 m/s
        job.line(line)
    job.flush()
    assert robot.paths[-1][0] == [pytest.approx((0.1, 0.0, 2.0))]
    job.line("G1 X100000")  # 100 m further: refused, the job halts
    job.flush()
    assert job.halted is not None and robot.verbs == ["stop"]
    assert any(o.startswith("Error:refused: ") for o in out)
    job.line("G1 X10")  # while halted: answered with an error, not flown
    assert out[-2].startswith("Error:job halted") and len(robot.paths) == 1
    job.line("M999")
    job.line("G1 X50")  # no F: the feed, the unit and G91 of the job still hold
    job.flush()
    assert job.halted is None, out
    points, speed, append = robot.paths[-1]
    assert points == [pytest.approx((0.15, 0.0, 2.0))]  # 50 mm on from where it rested
    assert speed == pytest.approx(0.1) and append is False
