"""`cablebot path FILE` streams a file of any length: the chunking and back-pressure logic with
fakes, and a 10,000-point spiral (points 50 um apart) streamed through a real daemon on the
simulated robot, flown without a stop and arriving at its last point."""

from __future__ import annotations

import math
import queue
import time
import tomllib
from pathlib import Path
from typing import Any

import pytest

from controller.cli import client
from controller.cli.pathstream import LOW_WATER_S, StreamRefused, stream_points
from controller.core.commands import MAX_PATH_POINTS_SENT
from controller.core.motion import QUEUE_FULL
from tests.daemon_procs import CABLEBOT, Proc, to_toml, zenoh_session
from tests.service.test_zenoh_daemon import Daemon, strict_json, write_config


class Refused(Exception):
    pass


class FakeDaemon:
    """A queue that drains `drain_s` per status poll; refuses appends beyond `max_points`."""

    def __init__(self, seconds_per_point: float, max_points: int = 10**9) -> None:
        self.k = seconds_per_point
        self.max_points = max_points
        self.queued = 0
        self.sent: list[tuple[int, bool]] = []
        self.full_refusals = 0
        self.refuse_with: str | None = None

    def send(self, pts: list[list[float]], append: bool) -> dict[str, Any]:
        if self.refuse_with is not None and append:
            raise Refused(self.refuse_with)
        if self.queued + len(pts) > self.max_points:
            self.full_refusals += 1
            raise Refused(f"{QUEUE_FULL}: {self.queued} + {len(pts)} points would exceed")
        self.queued += len(pts)
        self.sent.append((len(pts), append))
        return self._path()

    def _path(self) -> dict[str, Any]:
        return {
            "queued_points": self.queued,
            "queued_s": self.queued * self.k,
            "queue_full": self.queued >= self.max_points,
        }

    def status(self) -> dict[str, Any]:
        self.queued = max(0, self.queued - 700)  # the robot flew some
        return {"state": "MOVING", "path": self._path()}


def _points(n: int) -> list[list[float]]:
    return [[0.001 * k, 0.0, 2.0] for k in range(n)]


def test_chunks_are_sent_while_less_than_the_low_water_mark_is_queued() -> None:
    fake = FakeDaemon(seconds_per_point=0.001)  # 1 s per chunk of 1,000
    shown: list[str] = []
    lasts: list[int] = []
    prog = stream_points(
        _points(10_500),
        fake.send,
        fake.status,
        lambda text, now: shown.append(text),
        refused=Refused,
        sleep=lambda s: None,
        before_last=lambda: lasts.append(len(fake.sent)),
    )
    sizes = [n for n, _ in fake.sent]
    assert sum(sizes) == prog.sent == 10_500 and max(sizes) <= MAX_PATH_POINTS_SENT
    assert [a for _, a in fake.sent] == [False] + [True] * (len(sizes) - 1)
    assert prog.commands == len(sizes) == 11
    assert lasts == [10]  # just before the last chunk
    # never more than the low-water mark plus one chunk queued at a send
    assert fake.queued * fake.k <= LOW_WATER_S + MAX_PATH_POINTS_SENT * fake.k
    assert "10500/10500 points sent" in shown[-1]


def test_a_full_queue_is_waited_out_and_other_refusals_end_the_stream() -> None:
    fake = FakeDaemon(seconds_per_point=1e-6, max_points=2500)  # tiny points: queue bound bites
    prog = stream_points(
        _points(6000),
        fake.send,
        fake.status,
        lambda t, n: None,
        refused=Refused,
        sleep=lambda s: None,
    )
    assert prog.sent == 6000 and fake.full_refusals > 0 and prog.retries == fake.full_refusals
    fake = FakeDaemon(seconds_per_point=1e-3)
    fake.refuse_with = "no path in progress to append to"
    with pytest.raises(StreamRefused, match=r"no path in progress.*after 1000/3000 points"):
        stream_points(
            _points(3000),
            fake.send,
            fake.status,
            lambda t, n: None,
            refused=Refused,
            sleep=lambda s: None,
        )


def test_a_file_appended_to_a_full_queue_waits_it_out() -> None:
    """A file with `"append": true` whose first chunk meets a full queue (the path in
    progress) waits it out and sends it again, as any other append."""
    fake = FakeDaemon(seconds_per_point=1e-3, max_points=2500)
    fake.queued = 2500
    prog = stream_points(
        _points(3000),
        lambda pts, more: fake.send(pts, True),
        fake.status,
        lambda t, n: None,
        refused=Refused,
        sleep=lambda s: None,
        append_first=True,
    )
    assert prog.sent == 3000 and fake.full_refusals > 0 and prog.retries == fake.full_refusals
    assert fake.sent[0] == (1000, True)


def test_a_long_file_loads_for_streaming_only(tmp_path: Path) -> None:
    f = tmp_path / "long.csv"
    f.write_text("".join(f"{0.001 * k},0,2\n" for k in range(2500)))
    with pytest.raises(client.InputError, match="split it"):
        client.load_path_file(str(f))
    assert len(client.load_path_file(str(f), stream=True)["points_m"]) == 2500
    f.write_text("".join(f"{0.001 * k},0,2\n" for k in range(2500)) + "1e999,0,2\n")
    with pytest.raises(client.InputError):
        client.load_path_file(str(f), stream=True)


# ------------------------------------------------------------------------------ a real daemon

RATE_HZ = 500.0  # 8 points a tick at most: 4,000 points/s, 0.2 m/s at 50 um
SPACING_M = 50e-6
N_POINTS = 10_000
SPEED_MPS = 0.1


def _spiral(start: tuple[float, float, float]) -> list[tuple[float, float, float]]:
    """An Archimedean spiral through `start`, points `SPACING_M` apart along it."""
    r0 = 0.1
    cx, cy, z = start[0] - r0, start[1], start[2]
    pts = []
    theta = 0.0
    for _ in range(N_POINTS):
        r = r0 + 0.02 * theta / (2 * math.pi)
        pts.append((cx + r * math.cos(theta), cy + r * math.sin(theta), z))
        theta += SPACING_M / r
    return pts


@pytest.mark.slow
def test_a_long_file_streams_through_the_daemon_without_a_stop(tmp_path: Path) -> None:
    cfg, endpoint, prefix = write_config(tmp_path)
    data = tomllib.loads(cfg.read_text())
    data["loop"] = {**data["loop"], "rate_hz": RATE_HZ, "publish_every": 5}
    # This tests streaming, not the drives' watchdog: on a loaded 2-core machine the daemon's
    # process can be starved for longer than the simulated ODrives' default 0.3 s.
    data["sim"] = {**data["sim"], "watchdog_timeout_s": 2.0}
    cfg.write_text(to_toml(data))
    pts = _spiral((0.0, 0.0, 2.0))
    f = tmp_path / "spiral.csv"
    f.write_text("x,y,z\n" + "".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in pts))
    proc = Proc([*CABLEBOT, "run", "--config", str(cfg), "--status-every", "0"], "daemon")
    session = None
    try:
        session = zenoh_session(endpoint, 30.0)
        poses: queue.Queue[dict[str, Any]] = queue.Queue()
        states: queue.Queue[dict[str, Any]] = queue.Queue()
        session.declare_subscriber(
            f"{prefix}/pose", lambda s: poses.put(strict_json(s.payload.to_bytes()))
        )
        d = Daemon(proc, endpoint, prefix, session, poses, states)
        d.wait_state("HOLDING", 30.0)
        with poses.mutex:
            poses.queue.clear()
        t0 = time.monotonic()
        cli = Proc(
            [
                *CABLEBOT,
                "path",
                str(f),
                "--speed",
                str(SPEED_MPS),
                "--wait",
                "--wait-timeout",
                "120",
                "--connect",
                endpoint,
                "--prefix",
                prefix,
            ],
            "path",
        )
        rc = cli.p.wait(180.0)
        elapsed_s = time.monotonic() - t0
        assert rc == 0, cli.log() + proc.log()
        cli.wait_line("arrived:", 5.0)
        cli.wait_line(f"path: {N_POINTS} points sent", 5.0)
        samples = []
        while not poses.empty():
            samples.append(poses.get_nowait())
        moving = [i for i, p in enumerate(samples) if p["state"] == "MOVING"]
        assert moving, samples[-1]
        first, last = moving[0], moving[-1]
        # no stop before its end: MOVING throughout (a dry queue would hold), never at rest
        assert all(p["state"] == "MOVING" for p in samples[first : last + 1])
        assert max(p["queued_points"] for p in samples) > MAX_PATH_POINTS_SENT
        # paced at the low-water mark (a chunk's worth of slack), not filled to the daemon's bound
        mark_points = LOW_WATER_S * SPEED_MPS / SPACING_M
        assert max(p["queued_points"] for p in samples) <= mark_points + 2 * MAX_PATH_POINTS_SENT
        window = 10  # 0.1 s of poses at 100 Hz
        speeds = []
        for i in range(first, last + 1 - window):
            a, b = samples[i], samples[i + window]
            dt = (b["stamp_ns"] - a["stamp_ns"]) * 1e-9
            if dt > 0:
                speeds.append(math.dist(a["position_m"], b["position_m"]) / dt)
        inner = speeds[len(speeds) // 20 : len(speeds) - len(speeds) // 20]
        assert min(inner) > 0.3 * SPEED_MPS, min(inner)
        end = samples[-1]
        assert end["state"] == "HOLDING"
        assert math.dist(end["position_m"], pts[-1]) < 1e-3
        length = sum(math.dist(pts[k - 1], pts[k]) for k in range(1, len(pts)))
        flown_s = (samples[last]["stamp_ns"] - samples[first]["stamp_ns"]) * 1e-9
        print(
            f"streamed {N_POINTS} points, {length:.4f} m at {SPEED_MPS} m/s: flown in "
            f"{flown_s:.2f} s (ideal {length / SPEED_MPS:.2f} s), CLI {elapsed_s:.2f} s, "
            f"min 0.1 s speed {min(inner):.4f} m/s, max queued "
            f"{max(p['queued_points'] for p in samples)}"
        )
    finally:
        if session is not None:
            session.close()
        assert proc.terminate(10.0) == 0, proc.log()


def _at(d: Daemon) -> list[str]:
    return ["--connect", d.endpoint, "--prefix", d.prefix]


@pytest.mark.slow
def test_ctrl_c_while_streaming_brakes_to_a_hold(tmp_path: Path) -> None:
    import signal

    from controller.cli import exitcodes
    from tests.live_daemon import live_daemon, wait_holding_at_rest

    f = tmp_path / "line.csv"
    f.write_text("".join(f"{0.001 * k!r},0,2\n" for k in range(1, 5001)))  # 5 m, 1 mm apart
    with live_daemon(tmp_path) as (d, _cfg):
        cli = Proc(
            [*CABLEBOT, "path", str(f), "--speed", "0.5", "--wait", *_at(d)],
            "path",
        )
        deadline = time.monotonic() + 60.0
        while d.status()["state"] != "MOVING":
            assert time.monotonic() < deadline, cli.log()
            time.sleep(0.05)
        cli.p.send_signal(signal.SIGINT)
        assert cli.p.wait(60.0) == exitcodes.INTERRUPTED, cli.log()
        cli.wait_line("interrupted: braking to a hold", 10.0, stderr=True)
        held = wait_holding_at_rest(d, 30.0)
        assert 0.0 < held["pose"]["position_m"][0] < 4.5, held
        assert held["path"]["queued_points"] == 0 and held["path"]["appendable"] is False
