"""`cablebot monitor` in a real terminal (tmux) against a real daemon, and its drawing.

The tmux test starts `cablebot run` (the paper robot, simulated ODrives in-process, Zenoh on a
free loopback port), runs the monitor in a detached tmux session of a private tmux server,
reads the screen with `capture-pane`, and presses keys: `s` brakes a slow move to a hold,
`e` e-stops the robot (the daemon's status says ESTOPPED), `q` quits with exit 0.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from controller.service.config import paper_robot_data
from tests.conftest import running_under_ci
from tests.daemon_procs import CABLEBOT, REPO, Proc, free_tcp_port, to_toml, zenoh_session, zquery

pytest.importorskip("rich")

CAPTURE_FILE = os.environ.get("CABLEBOT_MONITOR_CAPTURE")
"""Set to a path to keep the last screen of the tmux test (the README's capture)."""


class Tmux:
    """A private tmux server (its own socket) with one session running a command.

    The pane's shell stays after the command (its exit status goes to a file): the screen
    keeps what the command left, as a user's terminal does. A pane whose shell ended would
    print tmux's "Pane is dead" on its last row, scrolling the top line out of the screen: a
    command whose last words are on the first row would seem to have printed nothing.
    """

    def __init__(self, command: list[str], width: int = 110, height: int = 40) -> None:
        exe = shutil.which("tmux")
        assert exe is not None
        self.exe = exe
        self.socket = f"cablebot-test-{uuid.uuid4().hex[:8]}"
        self.status_file = Path(tempfile.mkdtemp(prefix="cablebot-tmux-")) / "exit-status"
        self._tmux(
            "-f",
            "/dev/null",
            "new-session",
            "-d",
            "-s",
            "mon",
            "-x",
            str(width),
            "-y",
            str(height),
            "-c",
            str(REPO),
            # GNU readline, once loaded in this process, exports COLUMNS/LINES (80x24 without a
            # terminal); they would fix the monitor's width: the pane's own size must count.
            # The shell writes the command's exit status to a file (tmux 3.3 does not always
            # fill #{pane_dead_status}), then stays (see the class docstring).
            "--",
            "sh",
            "-c",
            'env -u COLUMNS -u LINES "$@"; echo $? > "$0"; exec sleep 86400',
            str(self.status_file),
            *command,
        )
        self._tmux("set-option", "-t", "mon", "remain-on-exit", "on")

    def _tmux(self, *args: str) -> str:
        proc = subprocess.run(
            [self.exe, "-L", self.socket, *args],
            capture_output=True,
            text=True,
            timeout=20,
            check=False,
        )
        assert proc.returncode == 0, f"tmux {args}: {proc.stderr}"
        return proc.stdout

    def screen(self, *, escapes: bool = False) -> str:
        """The visible pane as text (with colour escapes if `escapes`)."""
        return self._tmux("capture-pane", "-p", *(["-e"] if escapes else []), "-t", "mon")

    def keys(self, *keys: str) -> None:
        """Type keys into the pane."""
        self._tmux("send-keys", "-t", "mon", *keys)

    def dead_status(self) -> int | None:
        """The exit status of the pane's command, or None while it runs."""
        try:
            text = self.status_file.read_text().strip()
        except FileNotFoundError:
            return None
        return int(text) if text else None

    def wait_for(self, what: str, pred: Callable[[str], bool], timeout_s: float = 30.0) -> str:
        """Poll the screen until `pred(screen)`; AssertionError with the screen after timeout."""
        deadline = time.monotonic() + timeout_s
        while True:
            text = self.screen()
            if pred(text):
                return text
            if time.monotonic() > deadline:
                size = self._tmux(
                    "display-message", "-p", "-t", "mon", "#{pane_width}x#{pane_height}"
                )
                raise AssertionError(f"screen ({size.strip()}) never showed {what}:\n{text}")
            time.sleep(0.1)

    def kill(self) -> None:
        """Stop this test's tmux server (only the one on its private socket)."""
        subprocess.run(
            [self.exe, "-L", self.socket, "kill-server"],
            capture_output=True,
            timeout=20,
            check=False,
        )


def _write_config(tmp_path: Path) -> tuple[Path, str, str]:
    name = f"m{uuid.uuid4().hex[:8]}"
    data = paper_robot_data(name)
    data["bus"] = {"interface": "virtual", "channel": f"monitor-test-{name}"}
    data["loop"] = {"rate_hz": 100.0, "realtime": False, "publish_every": 1}
    data["sim"] = {"enabled": True}
    # This tests the monitor, not fault detection: a starved simulator must not fault here.
    data["faults"] = {**data["faults"], "stale_timeout_s": 0.5, "heartbeat_timeout_s": 2.0}
    data["homing"] = {"power_up_position_m": [0.0, 0.0, 2.0]}
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    prefix = f"cablebot/{name}"
    data["zenoh"] = {"prefix": prefix, "listen": [endpoint], "multicast_scouting": False}
    path = tmp_path / f"{name}.toml"
    path.write_text(to_toml(data))
    return path, endpoint, prefix


@pytest.fixture
def tmux_available() -> None:
    if shutil.which("tmux") is None:
        if running_under_ci():
            pytest.fail("tmux is not installed: CI must run the monitor in a real terminal")
        pytest.skip("tmux is not installed (.ci/run installs it)")


def test_a_command_s_last_line_stays_on_the_screen_after_it_ends(tmux_available: None) -> None:
    """The capture shows what a user sees once a command is over: here its one line, on the
    first row, for seconds after it ended."""
    term = Tmux([sys.executable, "-c", "print('gcode: done: 3 lines')"])
    try:
        deadline = time.monotonic() + 30.0
        while term.dead_status() is None:
            assert time.monotonic() < deadline, term.screen()
            time.sleep(0.02)
        assert term.dead_status() == 0
        for _ in range(20):  # 2 s: long after tmux has handled the command's end
            screen = term.screen()
            assert screen.splitlines()[0] == "gcode: done: 3 lines", screen
            time.sleep(0.1)
    finally:
        term.kill()


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[tuple[str, str]]:
    cfg, endpoint, prefix = _write_config(tmp_path)
    proc = Proc([*CABLEBOT, "run", "--config", str(cfg), "--status-every", "0"], "daemon")
    try:
        yield endpoint, prefix
    finally:
        assert proc.terminate(10.0) == 0, proc.log()


def _shows_state(screen: str, state: str) -> bool:
    return re.search(rf"^state\s+{state}\b", screen, re.M) is not None


def _state(session: object, prefix: str) -> str:
    return str(zquery(session, f"{prefix}/status").get("state"))


@pytest.mark.slow
@pytest.mark.timeout(150)
def test_monitor_in_tmux_shows_the_robot_and_its_keys_stop_and_estop(
    tmux_available: None, daemon: tuple[str, str]
) -> None:
    endpoint, prefix = daemon
    session = zenoh_session(endpoint, 30.0)
    deadline = time.monotonic() + 30.0
    while _state(session, prefix) != "HOLDING":  # the daemon arms itself at the power-up pose
        assert time.monotonic() < deadline, "the daemon did not reach HOLDING"
        time.sleep(0.1)
    term = Tmux(
        [
            sys.executable,
            "-m",
            "controller.cli",
            "monitor",
            "--connect",
            endpoint,
            "--prefix",
            prefix,
        ]
    )
    try:
        screen = term.wait_for(
            "the holding robot",
            lambda s: _shows_state(s, "HOLDING") and "CLOSED_LOOP_CONTROL" in s and "+0.0000" in s,
        )
        assert "x   +0.0000  y   +0.0000  z  +2.0000 m" in screen
        assert re.search(r"set-point\s+x\s+\+0\.0000", screen)
        assert len(re.findall(r"^\s*[0-3]\s+CLOSED_LOOP_CONTROL\s+none\s", screen, re.M)) == 4
        assert "keys: s stop  e/space E-STOP  q quit" in screen
        assert re.search(r"loop\s+100 Hz", screen)

        # `s` brakes a slow move to a hold short of its target
        reply = zquery(
            session, f"{prefix}/cmd/move", {"position_m": [3.0, 0.0, 2.0], "speed_mps": 0.3}
        )
        assert reply.get("ok"), reply
        term.wait_for("MOVING", lambda s: _shows_state(s, "MOVING"))
        term.keys("s")
        term.wait_for("the stop reply", lambda s: "stop: braking to a hold" in s)
        while _state(session, prefix) != "HOLDING":
            assert time.monotonic() < deadline + 60.0
            time.sleep(0.05)
        x = zquery(session, f"{prefix}/status")["pose"]["position_m"][0]
        assert x < 2.5, x
        term.wait_for("HOLDING again", lambda s: _shows_state(s, "HOLDING") and "MOVING" in s)

        # `e` e-stops the robot: the daemon says so, and the screen cannot be missed
        term.keys("e")
        t0 = time.monotonic()
        while _state(session, prefix) != "ESTOPPED":
            assert time.monotonic() - t0 < 10.0, "e did not e-stop the robot"
            time.sleep(0.05)
        screen = term.wait_for("ESTOPPED", lambda s: "ESTOPPED: estop" in s)
        assert _shows_state(screen, "ESTOPPED")
        assert "estop: ok, state ESTOPPED" in screen
        coloured = term.screen(escapes=True)
        state_line = next(ln for ln in coloured.splitlines() if "state" in ln and "ESTOPPED" in ln)
        assert "41m" in state_line or "41;" in state_line, repr(state_line)  # red background
        # the recent state changes: newest first
        recent = screen[screen.index("recent state changes") :]
        order = re.findall(r"\d\d:\d\d:\d\d\s+(\w+)", recent)
        assert order[:3] == ["ESTOPPED", "HOLDING", "MOVING"], recent
        if CAPTURE_FILE:
            Path(CAPTURE_FILE).write_text(screen)

        term.keys("q")
        t0 = time.monotonic()
        while (status := term.dead_status()) is None:
            assert time.monotonic() - t0 < 15.0, term.screen()
            time.sleep(0.1)
        assert status == 0
    finally:
        term.kill()
        session.close()  # type: ignore[attr-defined]


def test_render_puts_a_fault_in_red_with_what_to_do() -> None:
    from rich.console import Console

    from controller.cli.monitor import Snapshot, render

    snap = Snapshot(
        pose={"seq": 9, "state": "FAULT", "position_m": None},
        pose_rx_s=100.0,
        received=9,
        missed=2,
        status={
            "state": "FAULT",
            "reason": "stale_encoder: node 2 age 0.081 s",
            "axes": [
                {
                    "node_id": 2,
                    "ready": False,
                    "state": "IDLE",
                    "fault": "ESTOP_REQUESTED (0x2000000)",
                    "axis_state": 1,
                    "axis_error": 0x2000000,
                    "age_s": 0.081,
                },
            ],
            "tensions_n": [412.5],
        },
        states=[(1_700_000_000 * 10**9, "FAULT", "stale_encoder: node 2 age 0.081 s")],
    )
    console = Console(record=True, width=110, force_terminal=True, color_system="standard")
    console.print(render(snap, 100.5, 100.0, "cablebot/x via tcp/127.0.0.1:1"))
    text = console.export_text(clear=False)
    assert "FAULT: stale_encoder: node 2 age 0.081 s" in text
    assert "`cablebot reset` clears it" in text
    assert "ESTOP_REQUESTED (0x2000000)" in text and "IDLE" in text
    assert "412.5 N" in text
    assert "2 missed" in text
    ansi = console.export_text(styles=True)
    line = next(ln for ln in ansi.splitlines() if "FAULT: stale_encoder" in ln)
    assert "\x1b[1;31m" in line  # bold red


def test_render_shows_a_running_pretension() -> None:
    from rich.console import Console

    from controller.cli.monitor import Snapshot, render

    status = {
        "state": "PRETENSIONING",
        "reason": "pretension: the reels pull in torque control",
        "pretension": {
            "active": True,
            "position_m": [0.3, 0.0, 2.0],
            "elapsed_s": 4.25,
            "fastest_cable_mps": 0.00312,
        },
    }
    snap = Snapshot(pose={"state": "PRETENSIONING"}, pose_rx_s=1.0, status=status)
    console = Console(record=True, width=120)
    console.print(render(snap, 1.1, 50.0, "t"))
    text = console.export_text()
    assert "PRETENSIONING" in text and "(pretension: the reels pull in torque control)" in text
    assert "pretension  4.2 s, fastest cable 3.12 mm/s; home at x   +0.3000" in text
    status["pretension"] = {"active": False, "result": None}
    console = Console(record=True, width=120)
    console.print(render(snap, 1.1, 50.0, "t"))
    assert "fastest cable" not in console.export_text()


def test_render_says_when_no_pose_arrives() -> None:
    from rich.console import Console

    from controller.cli.monitor import Snapshot, render

    console = Console(record=True, width=110)
    console.print(render(Snapshot(), 5.0, None, "t", keys=False))
    text = console.export_text()
    assert "no pose sample yet" in text
    assert "no keys (input is not a terminal): Ctrl-C quits" in text
    console = Console(record=True, width=110)
    console.print(render(Snapshot(pose={"state": "HOLDING"}, pose_rx_s=1.0), 5.0, None, "t"))
    assert "no pose sample for 4.0 s" in console.export_text()


def test_monitor_without_rich_says_how_to_get_it(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from controller.cli import main

    monkeypatch.setitem(sys.modules, "rich.console", None)
    assert main(["monitor", "--connect", "127.0.0.1:1"]) == 1
    assert "pip install 'cablebot[monitor]'" in capsys.readouterr().err


def test_render_shows_pose_and_set_point_from_the_same_sample() -> None:
    """At 1 m/s the pose stream runs ahead of the polled status: the pose shown beside the
    set-point is the status's own, taken with it."""
    from rich.console import Console

    from controller.cli.monitor import Snapshot, render

    status = {
        "state": "MOVING",
        "pose": {"valid": True, "position_m": [1.0, 0.0, 2.0], "residual_m": 1e-4},
        "setpoint_m": [1.0005, 0.0, 2.0],
    }
    stream = {"seq": 50, "state": "MOVING", "position_m": [1.4, 0.0, 2.0], "residual_m": 2e-4}
    snap = Snapshot(pose=stream, pose_rx_s=1.0, status=status, status_rx_s=0.6)
    console = Console(record=True, width=120)
    console.print(render(snap, 1.05, 100.0, "t"))
    text = console.export_text()
    assert re.search(r"pose\s+x\s+\+1\.0000", text), text
    assert not re.search(r"pose\s+x\s+\+1\.4000", text)
    assert re.search(r"set-point\s+x\s+\+1\.0005", text)
    assert "residual 0.10 mm" in text
