"""Finding the robot: `cablebot list` names every live daemon, and a verb sent to a silent
prefix names the live ones in its error. Against in-process Zenoh interfaces (two "daemons"
on one network) with fake controllers."""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest

from controller.cli import exitcodes, main
from controller.service import zenoh_io
from controller.service.zenoh_io import free_tcp_port
from tests.fakes_zenoh import FakeController, ZCfg


@pytest.fixture
def two_daemons() -> Iterator[str]:
    """Two interfaces, cablebot/acre and cablebot/desk, on one loopback network; yields the
    endpoint the first listens on."""
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    second = f"tcp/127.0.0.1:{free_tcp_port()}"
    opened = []
    try:
        for prefix, cfg in (
            ("cablebot/acre", ZCfg(prefix="cablebot/acre", listen=(endpoint,))),
            ("cablebot/desk", ZCfg(prefix="cablebot/desk", listen=(second,), connect=(endpoint,))),
        ):
            fake = FakeController(rate_hz=50.0)
            iface = zenoh_io.ZenohInterface(cfg, fake, reply_timeout_s=1.0)
            iface.open()
            fake.publisher = iface
            opened.append((prefix, iface))
        yield endpoint
    finally:
        for _, iface in opened:
            iface.close()


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_list_names_every_live_daemon(two_daemons: str, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "list", "--connect", two_daemons, "--json")
    assert code == exitcodes.OK
    rows = json.loads(out)
    assert [r["prefix"] for r in rows] == ["cablebot/acre", "cablebot/desk"]
    assert all(r["state"] == "DISARMED" for r in rows)
    assert two_daemons in rows[0]["listen"]
    code, out, _ = run(capsys, "list", "--connect", two_daemons)
    assert code == exitcodes.OK
    lines = out.splitlines()
    assert lines[0].split() == ["PREFIX", "NAME", "STATE", "ENDPOINT"]
    assert lines[1].startswith("cablebot/acre ") and "DISARMED" in lines[1]
    assert two_daemons in lines[1]
    assert lines[2].startswith("cablebot/desk ")


def test_silent_prefix_names_the_live_ones(
    two_daemons: str, capsys: pytest.CaptureFixture[str]
) -> None:
    for verb in (["status"], ["arm"], ["move", "0", "0", "1"]):
        code, _, err = run(capsys, *verb, "--connect", two_daemons, "--timeout", "1")
        assert code == exitcodes.NO_DAEMON, verb
        assert "no cablebot daemon answered on cablebot/default" in err
        assert "live daemons there: cablebot/acre, cablebot/desk" in err, err
        assert "give --prefix cablebot/acre" in err


def test_list_without_daemons_exits_no_daemon(capsys: pytest.CaptureFixture[str]) -> None:
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    code, out, err = run(capsys, "list", "--connect", endpoint)
    assert code == exitcodes.NO_DAEMON
    assert out == "" and "no cablebot daemon answered" in err
