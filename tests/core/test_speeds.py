"""Commanded speeds: one minimum (`MIN_SPEED_MPS`) at every boundary, and a speed limited to the
maximum is said so in the reply and by the CLI."""

from __future__ import annotations

import argparse
import json

import pytest

from controller.cli import client, main
from controller.client.model import Reply
from controller.core.commands import CommandError, Move, parse_command
from controller.core.motion import MIN_SPEED_MPS
from controller.service.zenoh_io import free_tcp_port


@pytest.mark.parametrize("v", [5e-324, 1e-9, 0.5 * MIN_SPEED_MPS])
def test_the_parser_refuses_speeds_below_the_minimum(v: float) -> None:
    body = json.dumps({"position_m": [0, 0, 1], "speed_mps": v})
    with pytest.raises(CommandError, match=r"speed_mps: must be at least 0\.001 m/s"):
        parse_command("move", body)
    with pytest.raises(CommandError, match="speed_mps"):
        parse_command("path", json.dumps({"points_m": [[0, 0, 1]], "speed_mps": v}))


def test_the_parser_takes_the_minimum_and_any_speed_above() -> None:
    for v in (MIN_SPEED_MPS, 1.0, 50.0):
        body = json.dumps({"position_m": [0, 0, 1], "speed_mps": v})
        assert parse_command("move", body) == Move((0.0, 0.0, 1.0), v)


def test_the_cli_refuses_a_speed_below_the_minimum_before_sending(
    capsys: pytest.CaptureFixture[str],
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"  # nothing listens: it must not get that far
    code = main(["move", "0", "0", "1", "--speed", "5e-324", "--connect", endpoint])
    out, err = capsys.readouterr()
    assert code == 1 and out == ""
    assert "--speed must be at least 0.001 m/s (the minimum speed)" in err, err


def test_the_cli_says_when_the_speed_was_limited(capsys: pytest.CaptureFixture[str]) -> None:
    args = argparse.Namespace(json=False)
    reply = {"ok": True, "target_m": [1.0, 0.0, 2.0], "speed_mps": 2.0, "speed_limited_to_mps": 2.0}
    client._print_reply("move", Reply.from_reply("move", reply), args)
    lines = capsys.readouterr().out.splitlines()
    assert lines == [
        "move: to x=+1.000 y=+0.000 z=+2.000 m at 2.000 m/s "
        "(speed limited to the robot's maximum, 2.000 m/s)"
    ]
    client._print_reply("move", Reply.from_reply("move", {"ok": True, "speed_mps": 1.0}), args)
    assert "limited" not in capsys.readouterr().out
    client._print_reply("path", Reply.from_reply("path", reply), argparse.Namespace(json=True))
    assert json.loads(capsys.readouterr().out) == reply
