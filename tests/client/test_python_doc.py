"""Every example of docs/python.md runs as written against the built-in simulated robot: each
Python block of the page is a script, run in a process of its own, in the page's order, on one
daemon of the built-in robot (its Zenoh on a loopback port of this test's, given to the scripts
the way the page says, `CABLEBOT_ENDPOINT`)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.client.client_daemon import START_S
from tests.daemon_procs import CABLEBOT, REPO, Proc, to_toml

PAGE = REPO / "docs" / "python.md"
BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)

# What each example prints that shows it did what the page says (in the page's order).
EXPECTED = [
    r"^HOLDING default \(\S+, \S+, \S+\)\nseq \d+  state HOLDING  x=\+0\.000 y=\+0\.000",
    r"arrived: seq \d+  state HOLDING  x=\+5\.000 y=\+3\.000 z=\+2\.500 m[\s\S]*refused: z=90 m",
    r"3142/3142 points sent",
    r"line 7: X:0\.000 Y:0\.000 Z:2000\.000[\s\S]*done: 5 moves",
    r"^$",
    r"state HOLDING  x=\+1\.000 y=\+1\.000 z=\+2\.000 m",
]


def examples() -> list[str]:
    """The Python blocks of docs/python.md, in order."""
    return BLOCK.findall(PAGE.read_text())


@pytest.fixture(scope="module")
def builtin_robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """`cablebot run` on the built-in robot (name "default", prefix cablebot/default), listening
    on a free loopback port; yields the endpoint. The fault timeouts are relaxed for a loaded
    machine: the examples exercise the client, not fault detection."""
    from controller.service.config import paper_robot_data
    from controller.service.zenoh_io import free_tcp_port

    data = paper_robot_data("default")
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    data["zenoh"] = {"listen": [endpoint], "multicast_scouting": False}
    data["faults"] = {**data["faults"], "stale_timeout_s": 2.0, "heartbeat_timeout_s": 4.0}
    data["sim"] = {**data.get("sim", {}), "watchdog_timeout_s": 2.0}
    path = tmp_path_factory.mktemp("builtin") / "builtin.toml"
    path.write_text(to_toml(data))
    proc = Proc([*CABLEBOT, "run", "--config", str(path), "--status-every", "0"], "daemon")
    try:
        proc.wait_line("ready: HOLDING", START_S, stderr=True)
        yield endpoint
    finally:
        assert proc.terminate(10.0) == 0, proc.log()


def test_the_page_has_its_examples() -> None:
    assert len(examples()) == len(EXPECTED)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_every_example_runs_as_written(builtin_robot: str, tmp_path: Path) -> None:
    env = {**os.environ, "CABLEBOT_ENDPOINT": builtin_robot, "PYTHONUNBUFFERED": "1"}
    env.pop("CABLEBOT_PREFIX", None)
    for i, (code, expected) in enumerate(zip(examples(), EXPECTED, strict=True), start=1):
        script = tmp_path / f"example{i}.py"
        script.write_text(code)
        done = subprocess.run(
            [sys.executable, str(script)],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=240,
            check=False,
        )
        shown = f"example {i}:\n{code}\nstdout:\n{done.stdout}\nstderr:\n{done.stderr}"
        assert done.returncode == 0, shown
        assert done.stderr == "", shown
        assert re.search(expected, done.stdout, re.M), shown
