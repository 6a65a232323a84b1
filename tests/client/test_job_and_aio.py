"""G-code jobs and the asyncio form of the client library, against a real daemon: a job checked
whole against the daemon's robot, streamed with its progress as an iterator or a callback, its
M114 report; a bad line refused before anything moves; cancelling brakes to a hold."""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from controller.client import Refused, Robot, StreamProgress
from controller.client.aio import AsyncRobot
from controller.client.gcode import JobInputError
from controller.client.job import JobProgress, iter_job, load_gcode, run_job
from tests.client.client_daemon import ClientDaemon, client_daemon, ready

pytestmark = pytest.mark.slow

START = (0.0, 0.0, 2.0)


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ClientDaemon]:
    with client_daemon(tmp_path_factory.mktemp("jobs")) as d:
        yield d


@pytest.fixture
def robot(daemon: ClientDaemon) -> Iterator[Robot]:
    with daemon.robot() as r:
        ready(r)
        yield r


def _job(tmp_path: Path, lines: list[str]) -> str:
    f = tmp_path / "job.gcode"
    f.write_text("\n".join(lines) + "\n")
    return str(f)


def test_a_job_runs_to_its_end_with_progress_and_its_m114_report(
    robot: Robot, tmp_path: Path
) -> None:
    circle = [
        f"G1 X{500 * math.cos(k / 50):.3f} Y{500 * math.sin(k / 50):.3f} Z2000" for k in range(315)
    ]
    lines = ["G21", "G90", "G1 X500 Y0 Z2000 F60000", *circle, "G4 P100", "M114", "G1 X0 Y0"]
    job = load_gcode(robot, _job(tmp_path, lines))
    assert job.lines == len(lines) and job.moves == 317 and job.planned_s > 1.0
    assert job.warnings == ()
    seen: list[JobProgress] = []
    result = run_job(robot, job, wait=True, wait_timeout_s=120.0, on_progress=seen.append)
    assert result.done and result.lines == len(lines) and result.moves == 317
    reports = [p.report for p in seen if p.report is not None]
    assert len(reports) == 1 and reports[0].startswith("X:")
    assert [p.line for p in seen] == sorted(p.line for p in seen)
    st = robot.status()
    assert st.state == "HOLDING" and st.setpoint_m == pytest.approx((0.0, 0.0, 2.0), abs=1e-9)


def test_a_job_with_a_line_out_of_the_workspace_moves_nothing(robot: Robot, tmp_path: Path) -> None:
    before = robot.status().raw["zenoh"]["commands"]
    path = _job(tmp_path, ["G21", "G1 X100 Y0 Z2000 F6000", "G1 Z90000", "G1 X0"])
    with pytest.raises(JobInputError, match="line 3: refused"):
        load_gcode(robot, path)
    assert robot.status().raw["zenoh"]["commands"] == before


def test_a_job_starts_only_from_holding(robot: Robot, tmp_path: Path) -> None:
    path = _job(tmp_path, ["G1 X100 Y0 Z2000 F6000"])
    robot.estop()
    try:
        with pytest.raises(Refused, match="a job starts from HOLDING"):
            load_gcode(robot, path)
    finally:
        ready(robot)


def test_leaving_a_job_early_brakes_the_robot(robot: Robot, tmp_path: Path) -> None:
    job = load_gcode(robot, _job(tmp_path, ["G1 X0 Y0 Z2000 F30000", "G1 X12000", "G1 X0"]))
    for progress in iter_job(robot, job):
        if progress.moves > 0:
            break  # the job is sent: the robot flies 12 m out at 0.5 m/s
    deadline = time.monotonic() + 20.0
    while (st := robot.status()).state != "HOLDING":
        assert time.monotonic() < deadline, st
        time.sleep(0.05)
    assert st.setpoint_m is not None and st.setpoint_m[0] < 11.0


def test_the_asyncio_form_moves_streams_and_reads(daemon: ClientDaemon) -> None:
    async def main() -> tuple[float, StreamProgress, int]:
        async with await AsyncRobot.connect(daemon.endpoint, daemon.prefix) as robot:
            assert (await robot.status()).state == "HOLDING"
            await robot.move((0.5, 0.0, 2.0), speed_mps=1.0)
            pose = await robot.wait(60.0)
            assert pose.position_m is not None
            pts = [(0.5 - 0.0005 * k, 0.0, 2.0) for k in range(1001)]
            prog = await robot.stream_path(pts, speed_mps=1.0)
            await robot.wait(60.0)
            seqs = []
            async for p in robot.poses():
                seqs.append(p.seq)
                if len(seqs) == 5:
                    break
            return pose.position_m[0], prog, len(set(seqs))

    with daemon.robot() as r:
        ready(r)
    x, prog, n = asyncio.run(main())
    assert abs(x - 0.5) <= 1e-3 and prog.sent == 1001 and prog.commands == 2 and n == 5


def test_a_cancelled_async_wait_brakes_the_robot(daemon: ClientDaemon) -> None:
    target = (10.0, 0.0, 2.0)

    async def main() -> None:
        async with await AsyncRobot.connect(daemon.endpoint, daemon.prefix) as robot:
            await robot.move(target, speed_mps=0.5)
            task = asyncio.create_task(robot.wait(60.0))
            await asyncio.sleep(0.5)
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task

    with daemon.robot() as r:
        ready(r)
    t0 = time.monotonic()
    asyncio.run(main())
    assert time.monotonic() - t0 < 20.0
    with daemon.robot() as r:
        deadline = time.monotonic() + 20.0
        while (st := r.status()).state != "HOLDING":
            assert time.monotonic() < deadline, st
            time.sleep(0.05)
        assert st.setpoint_m is not None and math.dist(st.setpoint_m, target) > 1.0
        ready(r)


def test_the_asyncio_form_runs_a_job(daemon: ClientDaemon, tmp_path: Path) -> None:
    path = _job(tmp_path, ["G21 G90", "G1 X0 Y0 Z2000 F60000", "G1 X300", "M114", "G1 X0"])

    async def main() -> tuple[int, list[str]]:
        async with await AsyncRobot.connect(daemon.endpoint, daemon.prefix) as robot:
            job = await robot.load_gcode(path)
            reports: list[str] = []
            result = await robot.run_job(
                job, wait=True, on_progress=lambda p: p.report and reports.append(p.report)
            )
            return result.moves, reports

    with daemon.robot() as r:
        ready(r)
    moves, reports = asyncio.run(main())
    assert moves == 3 and len(reports) == 1 and reports[0].startswith("X:300.000")
