"""`move/path --wait`: arrival counts only once the commanded motion has been seen."""

from __future__ import annotations

import argparse
import json
import os
import queue
import signal
import time
from pathlib import Path
from typing import Any

import pytest

from controller.cli import client, exitcodes, main


def _sample(seq: int, state: str, x: float) -> bytes:
    return json.dumps(
        {"seq": seq, "state": state, "position_m": [x, 0.0, 2.0], "valid": True}
    ).encode()


def _args() -> argparse.Namespace:
    return argparse.Namespace(json=True, wait_timeout=5.0, timeout=1.0)


def test_stale_holding_samples_where_a_path_ends_are_not_arrival() -> None:
    # A path from (20, 0, 2) out to (21, 0, 2) and back: poses published before the daemon took
    # it stand HOLDING exactly where the path ends.
    poses: queue.Queue[bytes] = queue.Queue()
    for seq, (state, x) in enumerate(
        [
            ("HOLDING", 20.0),
            ("HOLDING", 20.0),
            ("MOVING", 20.5),
            ("MOVING", 20.4),
            ("HOLDING", 20.0),
        ]
    ):
        poses.put(_sample(seq, state, x))
    points = [[21.0, 0.0, 2.0], [20.0, 0.0, 2.0]]
    rc = client._wait_arrival(_args(), "path", poses, points, seen_moving=False)
    assert rc == client.EXIT_OK
    assert poses.empty()  # it waited through the motion to the last sample


def test_a_motion_already_over_is_arrival_at_once() -> None:
    poses: queue.Queue[bytes] = queue.Queue()
    poses.put(_sample(1, "HOLDING", 20.0))
    poses.put(_sample(2, "HOLDING", 20.0))
    rc = client._wait_arrival(_args(), "move", poses, [[20.0, 0.0, 2.0]], seen_moving=True)
    assert rc == client.EXIT_OK
    assert poses.qsize() == 1


def test_a_hold_short_of_the_end_after_another_clients_stop_fails_at_once() -> None:
    poses: queue.Queue[bytes] = queue.Queue()
    for seq, (state, x) in enumerate([("MOVING", 20.5), ("MOVING", 20.9), ("HOLDING", 21.0)]):
        poses.put(_sample(seq, state, x))
    asked: list[int] = []

    def status() -> dict[str, Any]:
        asked.append(1)
        return {
            "state": "HOLDING",
            "reason": "stopped by a `stop` command",
            "setpoint_m": [21.0, 0.0, 2.0],
        }

    args = _args()
    args.wait_timeout = 120.0
    t0 = time.monotonic()
    with pytest.raises(client.Failed) as info:
        client._wait_arrival(args, "move", poses, [[30.0, 0.0, 2.0]], status=status)
    assert time.monotonic() - t0 < 5.0
    assert str(info.value).startswith(
        "the motion ended 9.000 m short of x=+30.000 y=+0.000 z=+2.000 m: "
        "stopped by a `stop` command; "
    )
    assert asked == [1]


def test_a_hold_settling_on_the_end_asks_once_and_arrives() -> None:
    poses: queue.Queue[bytes] = queue.Queue()
    for seq, (state, x) in enumerate(
        [("MOVING", 20.5), ("HOLDING", 20.995), ("HOLDING", 20.998), ("HOLDING", 21.0)]
    ):
        poses.put(_sample(seq, state, x))
    asked: list[int] = []

    def status() -> dict[str, Any]:
        asked.append(1)
        return {"state": "HOLDING", "reason": None, "setpoint_m": [21.0, 0.0, 2.0]}

    rc = client._wait_arrival(_args(), "move", poses, [[21.0, 0.0, 2.0]], status=status)
    assert rc == client.EXIT_OK and asked == [1]


def test_a_motion_replaced_by_another_command_fails_naming_it() -> None:
    poses: queue.Queue[bytes] = queue.Queue()
    for seq, (state, x) in enumerate([("MOVING", 20.5), ("HOLDING", 5.0)]):
        poses.put(_sample(seq, state, x))

    def status() -> dict[str, Any]:
        return {"state": "HOLDING", "reason": None, "setpoint_m": [5.0, 0.0, 2.0]}

    with pytest.raises(client.Failed, match=r"short of .*: another command took over"):
        client._wait_arrival(_args(), "move", poses, [[21.0, 0.0, 2.0]], status=status)


class _NoSub:
    def undeclare(self) -> None:
        pass


class _FakeSession:
    def declare_subscriber(self, key: str, handler: Any) -> _NoSub:
        return _NoSub()


def _fake_daemon(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """client's session and queries faked: returns the list of keys queried."""
    sent: list[str] = []

    def fake_query(session: Any, key: str, payload: Any, timeout_s: float) -> Any:
        sent.append(key.split("/", 2)[-1])
        if key.endswith("/status"):
            return {"state": "MOVING"}
        return {"ok": True, "state": "MOVING"}

    monkeypatch.setattr(client, "query", fake_query)
    monkeypatch.setattr(client, "_run", lambda args, body: body(_FakeSession()))
    return sent


@pytest.mark.parametrize("signame", ["SIGTERM", "SIGHUP"])
def test_sigterm_or_sighup_during_move_wait_brakes_to_a_hold(
    signame: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The terminal closed or `kill` while a move is waited on: stop is sent, exit 130, and
    the signal's previous handler is back afterwards."""
    sig = getattr(signal, signame)
    sent = _fake_daemon(monkeypatch)

    def killed_while_waiting(*_a: Any, **_k: Any) -> int:
        os.kill(os.getpid(), sig)
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:  # the handler raises here
            time.sleep(0.01)
        raise AssertionError("no KeyboardInterrupt from the signal")

    monkeypatch.setattr(client, "_wait_arrival", killed_while_waiting)
    before = signal.getsignal(sig)
    rc = main(["move", "1", "0", "2", "--wait"])
    err = capsys.readouterr().err
    assert rc == exitcodes.INTERRUPTED, err
    assert "interrupted: braking to a hold" in err
    assert sent[-1] == "cmd/stop", sent
    assert signal.getsignal(sig) == before


def test_detached_wait_leaves_sigterm_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    _fake_daemon(monkeypatch)
    seen: list[Any] = []
    monkeypatch.setattr(
        client, "_wait_arrival", lambda *a, **k: seen.append(signal.getsignal(signal.SIGTERM)) or 0
    )
    before = signal.getsignal(signal.SIGTERM)
    assert main(["move", "1", "0", "2", "--wait", "--detach"]) == 0
    assert seen == [before]


@pytest.mark.parametrize("value", ["0", "-1", "nan"])
def test_wait_timeout_not_positive_is_refused_before_sending(
    value: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    sent = _fake_daemon(monkeypatch)
    rc = main(["move", "1", "0", "2", "--wait", "--wait-timeout", value])
    assert rc == exitcodes.USAGE
    assert "--wait-timeout must be a number of seconds > 0" in capsys.readouterr().err
    assert sent == []


def test_wait_timeout_says_the_motion_goes_on() -> None:
    poses: queue.Queue[bytes] = queue.Queue()
    args = argparse.Namespace(json=True, wait_timeout=0.05, timeout=5.0)
    with pytest.raises(client.WaitTimeout, match=r"goes on with the motion.*cablebot stop"):
        client._wait_arrival(args, "move", poses, [[1.0, 0.0, 2.0]])


@pytest.mark.parametrize("n_points", [3, client.MAX_PATH_POINTS_SENT + 5])
def test_path_file_append_is_sent_as_an_append(
    n_points: int, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`{"points_m": ..., "append": true}`: the first `path` command sent appends, short or
    streamed."""
    from controller.cli import pathstream

    payloads: list[Any] = []

    def fake_query(session: Any, key: str, payload: Any, timeout_s: float) -> Any:
        if key.endswith("cmd/path"):
            payloads.append(payload)
        return {"ok": True, "state": "HOLDING"}

    def one_chunk(points: Any, send: Any, *_a: Any, **_k: Any) -> Any:
        send(points[:2], False)
        raise KeyboardInterrupt

    monkeypatch.setattr(client, "query", fake_query)
    monkeypatch.setattr(client, "_run", lambda args, body: body(_FakeSession()))
    monkeypatch.setattr(pathstream, "stream_points", one_chunk)
    # no robot description to check the file against: the fake serves commands only
    monkeypatch.setattr(client, "check_with_robot", lambda *_a, **_k: None)
    f = tmp_path / "more.json"
    pts = [[0.1 * (i % 7), 0.0, 2.0] for i in range(n_points)]
    f.write_text(json.dumps({"points_m": pts, "append": True}))
    main(["path", str(f)])
    assert payloads and payloads[0]["append"] is True, payloads


@pytest.mark.parametrize("signame", ["SIGTERM", "SIGHUP"])
def test_sigterm_or_sighup_while_a_long_path_streams_brakes_to_a_hold(
    signame: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """`kill` or the terminal closed while a long path file streams (no --wait): the path
    would be cut where the sender died, so the robot brakes to a hold, as `gcode` does."""
    from controller.cli import pathstream
    from controller.core.commands import MAX_PATH_POINTS_SENT

    sig = getattr(signal, signame)
    sent = _fake_daemon(monkeypatch)
    monkeypatch.setattr(client, "check_with_robot", lambda *_a, **_k: None)

    def killed_while_streaming(points: Any, send: Any, *_a: Any, **_k: Any) -> Any:
        send(points[:MAX_PATH_POINTS_SENT], False)
        os.kill(os.getpid(), sig)
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:  # the handler raises here
            time.sleep(0.01)
        raise AssertionError("no KeyboardInterrupt from the signal")

    monkeypatch.setattr(pathstream, "stream_points", killed_while_streaming)
    f = tmp_path / "long.csv"
    f.write_text("".join(f"{0.001 * k!r},0,2\n" for k in range(1, 2 * MAX_PATH_POINTS_SENT)))
    before = signal.getsignal(sig)
    rc = main(["path", str(f)])
    err = capsys.readouterr().err
    assert rc == exitcodes.INTERRUPTED, err
    assert "interrupted: braking to a hold" in err
    assert sent[-1] == "cmd/stop", sent
    assert signal.getsignal(sig) == before
