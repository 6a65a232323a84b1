"""`cablebot jog`: its key parsing and hold logic, and a real terminal (tmux) against a real daemon.

The tmux test starts `cablebot run` (the paper robot, simulated ODrives in-process, Zenoh on a
free loopback port), runs `cablebot jog` in a detached tmux session of a private tmux server and
types into it: a held key (the key repeated, as a terminal's key repeat sends it) flies the
robot in that direction, releasing it brakes to a hold, `+` speeds up, `q` sends a zero sample
and exits 0. A jog killed while a key is held stops the robot too: the daemon's dead-man.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from controller.cli.jog import Jog, parse_keys, status_line
from controller.cli.record import RecordedMessage
from controller.cli.replay import replay_items
from tests.cli.test_monitor import Tmux, _write_config, tmux_available
from tests.daemon_procs import CABLEBOT, Proc, zenoh_session, zquery

__all__ = ["tmux_available"]  # a fixture, used by name

# ------------------------------------------------------------------------ keys


def test_keys_and_escape_sequences_become_tokens() -> None:
    tokens, rest = parse_keys(b"wasdWASDrfRF+=-_ q\x03\x04")
    assert tokens == [
        *("y+", "x-", "y-", "x+") * 2,
        *("z+", "z-") * 2,
        "faster",
        "faster",
        "slower",
        "slower",
        "stop",
        "quit",
        "quit",
        "quit",
    ]
    assert rest == b""
    arrows = b"\x1b[A\x1b[B\x1b[C\x1b[D\x1bOA\x1b[5~\x1b[6~"
    assert parse_keys(arrows) == (["y+", "y-", "x+", "x-", "y+", "z+", "z-"], b"")
    # unknown keys and sequences (F5, Home) are skipped; a cut sequence waits for its end
    assert parse_keys(b"x\x1b[15~\x1b[Hd") == (["x+"], b"")
    assert parse_keys(b"d\x1b[") == (["x+"], b"\x1b[")
    assert parse_keys(b"\x1b[" + b"5~") == (["z+"], b"")
    assert parse_keys(b"\x1b") == ([], b"\x1b")


def test_a_key_is_held_until_its_repeats_stop() -> None:
    jog = Jog(speed_mps=0.5, release_s=0.15, first_hold_s=0.5)
    jog.key("x+", 0.0)
    assert jog.velocity(0.4) == (0.5, 0.0, 0.0)  # first press: bridges the repeat delay
    assert jog.velocity(0.51) == (0.0, 0.0, 0.0)  # a tap: a nudge of first_hold_s
    jog.key("x+", 1.0)
    for t in (1.45, 1.48, 1.51, 1.54):  # the terminal's repeats
        jog.key("x+", t)
    assert jog.velocity(1.6) == (0.5, 0.0, 0.0)
    assert jog.velocity(1.70) == (0.0, 0.0, 0.0)  # 0.16 s after the last repeat: released
    # two axes: a diagonal at the same speed
    jog.key("y-", 2.0)
    jog.key("z+", 2.0)
    vx, vy, vz = jog.velocity(2.1)
    assert vx == 0.0 and vy < 0.0 < vz and math.hypot(vx, vy, vz) == pytest.approx(0.5)
    # the opposite key on an axis replaces the direction
    jog.key("y+", 2.2)
    assert jog.velocity(2.3)[1] > 0.0
    assert jog.key("stop", 2.3) == "stop" and jog.velocity(2.3) == (0.0, 0.0, 0.0)
    assert jog.key("quit", 2.4) == "quit"


def test_speed_steps_are_capped_to_the_robots_maximum() -> None:
    jog = Jog(speed_mps=0.1, max_speed_mps=0.7)
    assert jog.speeds() == (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 0.7)
    for _ in range(10):
        jog.key("faster", 0.0)
    assert jog.speed_mps == 0.7
    jog.key("slower", 0.0)
    assert jog.speed_mps == 0.5
    for _ in range(20):
        jog.key("slower", 0.0)
    assert jog.speed_mps == 0.01
    jog = Jog(speed_mps=0.3)  # between two steps: + and - go to the neighbours
    jog.key("faster", 0.0)
    assert jog.speed_mps == 0.5
    jog = Jog(speed_mps=0.3)
    jog.key("slower", 0.0)
    assert jog.speed_mps == 0.2


def test_status_line_shows_state_pose_speed_and_velocity() -> None:
    jog = Jog(speed_mps=0.2)
    pose = {"state": "MOVING", "position_m": [0.5, -1.25, 2.0]}
    line = status_line(pose, 0.1, jog, (0.2, 0.0, 0.0), 200)
    assert line.startswith("MOVING ")
    assert "x   +0.500  y   -1.250  z  +2.000 m" in line
    assert "speed 0.2 m/s" in line and "v [+0.20 +0.00 +0.00]" in line
    assert "no pose for 3.0 s" in status_line(pose, 3.0, jog, (0.0, 0.0, 0.0), 200)
    line = status_line({"state": "DISARMED", "position_m": None}, 0.1, jog, (0, 0, 0), 200)
    assert "not armed" in line
    assert len(status_line(pose, 0.1, jog, (0, 0, 0), 40)) <= 39


def test_jog_needs_a_terminal(capsys: pytest.CaptureFixture[str]) -> None:
    from controller.cli import main

    assert main(["jog", "--connect", "127.0.0.1:1"]) == 2
    assert "terminal" in capsys.readouterr().err


def test_a_recorded_jog_session_is_never_replayed() -> None:
    # Recordings take every key under the prefix; velocity samples must never be put again.
    msgs = [
        RecordedMessage("cablebot/r/pose", 1, 1, 0, b"{}"),
        RecordedMessage("cablebot/r/velocity", 2, 2, 0, b'{"velocity_mps": [1, 0, 0]}'),
        RecordedMessage("cablebot/r/setpoint", 3, 3, 0, b'{"position_m": [1, 0, 2]}'),
    ]
    keys = [item.key for item in replay_items(iter(msgs), "cablebot/r", None)]
    assert keys == ["cablebot/r/pose"]


# ------------------------------------------------------------------------ tmux + daemon


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[tuple[str, str]]:
    cfg, endpoint, prefix = _write_config(tmp_path)
    proc = Proc([*CABLEBOT, "run", "--config", str(cfg), "--status-every", "0"], "daemon")
    try:
        yield endpoint, prefix
    finally:
        assert proc.terminate(10.0) == 0, proc.log()


def _status(session: Any, prefix: str) -> dict[str, Any]:
    st = zquery(session, f"{prefix}/status")
    assert isinstance(st, dict)
    return st


def _pose(session: Any, prefix: str) -> tuple[float, float, float]:
    p = _status(session, prefix)["pose"]["position_m"]
    return (float(p[0]), float(p[1]), float(p[2]))


def _wait_state(session: Any, prefix: str, state: str, timeout_s: float) -> float:
    """Poll until the daemon is in `state`; returns the seconds it took."""
    t0 = time.monotonic()
    while _status(session, prefix)["state"] != state:
        assert time.monotonic() - t0 < timeout_s, f"not {state} within {timeout_s} s"
        time.sleep(0.05)
    return time.monotonic() - t0


def _hold_key(term: Tmux, key: str, seconds: float, every_s: float = 0.04) -> None:
    """Type `key` repeatedly for `seconds`, as a terminal's key repeat does."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        term.keys(key)
        time.sleep(every_s)


def _jog(endpoint: str, prefix: str, *extra: str) -> Tmux:
    return Tmux(
        [
            sys.executable,
            "-m",
            "controller.cli",
            "jog",
            "--connect",
            endpoint,
            "--prefix",
            prefix,
            *extra,
        ]
    )


def _pane_child_pid(term: Tmux) -> int:
    """The pid of the command running in the pane (the child of the pane's shell)."""
    shell = int(term._tmux("display-message", "-p", "-t", "mon", "#{pane_pid}").strip())
    children = Path(f"/proc/{shell}/task/{shell}/children").read_text().split()
    assert len(children) == 1, children
    return int(children[0])


def _shows(screen: str, state: str) -> bool:
    return re.search(rf"^{state}\s+x\s", screen, re.M) is not None


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_jog_in_tmux_flies_the_robot_and_stops_on_release(
    tmux_available: None, daemon: tuple[str, str]
) -> None:
    endpoint, prefix = daemon
    session = zenoh_session(endpoint, 30.0)
    term: Tmux | None = None
    try:
        _wait_state(session, prefix, "HOLDING", 30.0)  # the daemon arms itself at (0, 0, 2)
        term = _jog(endpoint, prefix, "--speed", "0.5")
        screen = term.wait_for("the holding robot", lambda s: _shows(s, "HOLDING"))
        assert "arrows/WASD x-y" in screen and "q quit" in screen
        assert "x   +0.000  y   +0.000  z  +2.000 m" in screen
        assert "speed 0.5 m/s" in screen

        # Hold `d` (+x) for 1.5 s: the robot flies +x at up to 0.5 m/s, nothing else.
        x0, y0, z0 = _pose(session, prefix)
        _hold_key(term, "d", 1.5)
        assert _status(session, prefix)["state"] == "MOVING"
        term.wait_for("MOVING", lambda s: _shows(s, "MOVING") and "v [+0.50 +0.00 +0.00]" in s)
        # Released: the jog sends a zero sample 0.15 s later; braking from 0.5 m/s takes 0.5 s.
        took = _wait_state(session, prefix, "HOLDING", 10.0)
        print(f"HOLDING {took:.2f} s after the last key")
        x1, y1, z1 = _pose(session, prefix)
        assert x1 - x0 > 0.3, (x0, x1)
        assert abs(y1 - y0) < 0.01 and abs(z1 - z0) < 0.01
        st = _status(session, prefix)
        assert st["velocity"]["deadman_stops"] == 0  # the jog's zero sample stopped it
        time.sleep(0.5)
        assert math.dist(_pose(session, prefix), (x1, y1, z1)) < 2e-3  # and it stays

        # `+` speeds up; `r` (+z) flies up; space stops at once.
        term.keys("+")
        term.wait_for("the new speed", lambda s: "speed 1 m/s" in s)
        _hold_key(term, "r", 0.8)
        term.keys("Space")
        _wait_state(session, prefix, "HOLDING", 10.0)
        x2, y2, z2 = _pose(session, prefix)
        assert z2 - z1 > 0.1 and abs(x2 - x1) < 0.01 and abs(y2 - y1) < 0.01

        # Arrow keys too: left is -x.
        _hold_key(term, "Left", 0.8)
        _wait_state(session, prefix, "HOLDING", 10.0)
        assert _pose(session, prefix)[0] < x2 - 0.1

        # `q` quits with exit status 0, sending a zero sample on the way out.
        term.keys("q")
        t0 = time.monotonic()
        while (status := term.dead_status()) is None:
            assert time.monotonic() - t0 < 15.0, term.screen()
            time.sleep(0.1)
        assert status == 0
        assert _status(session, prefix)["state"] == "HOLDING"
    finally:
        if term is not None:
            term.kill()
        session.close()


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_a_killed_jog_stops_the_robot_by_the_deadman(
    tmux_available: None, daemon: tuple[str, str]
) -> None:
    endpoint, prefix = daemon
    session = zenoh_session(endpoint, 30.0)
    term: Tmux | None = None
    try:
        _wait_state(session, prefix, "HOLDING", 30.0)
        term = _jog(endpoint, prefix, "--speed", "0.5")
        term.wait_for("the holding robot", lambda s: _shows(s, "HOLDING"))
        pid = _pane_child_pid(term)
        assert "controller.cli" in Path(f"/proc/{pid}/cmdline").read_text()
        _hold_key(term, "w", 1.0)  # +y
        assert _status(session, prefix)["state"] == "MOVING"
        os.kill(pid, signal.SIGKILL)  # no zero sample: only the dead-man can stop it now
        took = _wait_state(session, prefix, "HOLDING", 10.0)
        print(f"HOLDING {took:.2f} s after the jog was killed")
        st = _status(session, prefix)
        assert st["velocity"]["deadman_stops"] == 1
        cfg_limits = st["config"]["limits"]
        # timeout + v / a, and the status polling and a loaded machine's scheduling on top
        assert took < cfg_limits["velocity_timeout_s"] + 0.5 / cfg_limits["max_accel_mps2"] + 2.0
        assert _pose(session, prefix)[1] > 0.2
    finally:
        if term is not None:
            term.kill()
        session.close()


def test_velocity_samples_from_python_move_the_daemon(daemon: tuple[str, str]) -> None:
    # The key's contract for any client: JSON samples at 20 Hz fly the robot; silence stops it.
    endpoint, prefix = daemon
    session = zenoh_session(endpoint, 30.0)
    try:
        _wait_state(session, prefix, "HOLDING", 30.0)
        x0 = _pose(session, prefix)[0]
        for _ in range(20):
            session.put(f"{prefix}/velocity", json.dumps({"velocity_mps": [-0.4, 0.0, 0.0]}))
            time.sleep(0.05)
        _wait_state(session, prefix, "HOLDING", 10.0)
        assert _pose(session, prefix)[0] < x0 - 0.1
        assert _status(session, prefix)["zenoh"]["velocity"]["ok"] >= 15
    finally:
        session.close()
