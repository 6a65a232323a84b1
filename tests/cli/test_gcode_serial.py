"""`cablebot gcode --serial PATH`: a real printer host (Printrun's printcore, over pyserial)
streams a job through the pseudo-terminal to a real daemon on the simulated robot; the line
protocol's answers (Resend, M105, M115, M114) as a host reads them through pyserial.

Printrun is not a declared dependency (its install pulls a GUI toolkit): install it with
`make venv` installs it (`pip install --no-deps printrun`); without it that test is skipped, and
under CI=true a skip is a failure."""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

import pytest
import serial

from tests.daemon_procs import CABLEBOT, Proc
from tests.live_daemon import Daemon, live_daemon, wait_holding_at_rest


def _serve(d: Daemon, cfg: Path, link: Path) -> Proc:
    cli = Proc(
        [
            *CABLEBOT,
            "gcode",
            "--serial",
            str(link),
            "--config",
            str(cfg),
            "--connect",
            d.endpoint,
            "--prefix",
            d.prefix,
        ],
        "gcode-serial",
    )
    cli.wait_line("gcode: serial port", 60.0)
    assert link.is_symlink()
    return cli


def _poll(pred, timeout_s: float, what: str) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout_s
    while not pred():
        assert time.monotonic() < deadline, what
        time.sleep(0.05)


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_printcore_streams_a_job_to_the_end(tmp_path: Path) -> None:
    if os.environ.get("CI") == "true":  # `make venv` installs printrun: under CI it must run
        import printrun.gcoder as gcoder
        import printrun.printcore as printcore_mod
    else:
        printcore_mod = pytest.importorskip("printrun.printcore")
        gcoder = pytest.importorskip("printrun.gcoder")
    n = 400
    lines = ["G21", "G90", "G1 X200 Y0 Z2000 F30000"]
    lines += [
        f"G1 X{200 * math.cos(2 * math.pi * k / n):.3f} Y{200 * math.sin(2 * math.pi * k / n):.3f}"
        for k in range(n + 1)
    ]
    lines += ["G4 P100", "G1 X0 Y0 Z2050", "M400"]
    link = tmp_path / "cablebot-tty"
    with live_daemon(tmp_path) as (d, cfg):
        cli = _serve(d, cfg, link)
        host = printcore_mod.printcore()
        sent: list[str] = []
        host.sendcb = lambda command, gline: sent.append(command)
        host.connect(str(link), 115200)
        try:
            _poll(lambda: host.online, 30.0, "printcore never saw the robot online")
            assert host.startprint(gcoder.LightGCode(lines))
            _poll(lambda: not host.printing, 180.0, f"the print did not end\n{cli.log()}")
            st = wait_holding_at_rest(d, 60.0)
            assert st["setpoint_m"] == pytest.approx([0.0, 0.0, 2.05], abs=1e-9)
            numbered_lines = [c for c in sent if c.startswith("N") and "*" in c]
            assert len(numbered_lines) >= len(lines) + 1, sent[:5]  # M110 and every line
        finally:
            host.disconnect()
            cli.terminate()
        assert not link.exists()


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_resend_and_answers_as_hosts_read_them(tmp_path: Path) -> None:
    from controller.core.gcode import numbered

    link = tmp_path / "tty"
    with live_daemon(tmp_path) as (d, cfg):
        cli = _serve(d, cfg, link)
        port = serial.Serial(str(link), 115200, timeout=10.0)
        try:

            def say(text: str) -> list[str]:
                port.write((text + "\n").encode())
                out = []
                while True:
                    got = port.readline().decode().strip()
                    assert got, f"no answer to {text!r}\n{cli.log()}"
                    out.append(got)
                    if got.startswith("ok"):
                        return out

            assert say("M105") == ["ok T:0.0 /0.0"]
            assert say("M115")[0].startswith("FIRMWARE_NAME:cablebot PROTOCOL_VERSION:1.0")
            assert say(numbered(-1, "M110")) == ["ok"]
            body, cs = numbered(0, "G1 X10 Z2000 F6000").rsplit("*", 1)
            bad = say(f"{body}*{(int(cs) + 1) % 256}")
            assert bad == ["Error:checksum mismatch, Last Line: -1", "Resend: 0", "ok"]
            assert say(numbered(0, "G1 X10 Z2000 F6000")) == ["ok"]
            assert say(numbered(2, "G1 X20"))[-2] == "Resend: 1"
            m114 = say(numbered(1, "M114"))
            assert m114[-2] == "X:10.000 Y:0.000 Z:2000.000 E:0.000", m114
        finally:
            port.close()
            cli.terminate()
