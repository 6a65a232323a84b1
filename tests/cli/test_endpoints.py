"""Every verb that talks Zenoh reads an endpoint the same way (`client.normalize_endpoint`):
`HOST:PORT` works for view, record and replay as for status; a bad one is one line, exit 2;
replay on a taken port says what to do."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from controller.cli import exitcodes, main
from controller.cli.record import McapRecorder
from controller.service.zenoh_io import free_tcp_port


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("verb", [["view", "--port", "0"], ["record", "x.mcap"], ["status"]])
def test_host_port_form_is_taken_by_every_verb(
    verb: list[str],
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.chdir(tmp_path)
    port = free_tcp_port()
    code, _, err = run(capsys, *verb, "--connect", f"127.0.0.1:{port}", "--timeout", "1")
    assert code == exitcodes.NO_DAEMON, err
    assert "no cablebot daemon answered" in err
    assert f"tcp/127.0.0.1:{port}" in err
    assert "Traceback" not in err and "Json5" not in err and ".rs:" not in err


@pytest.mark.parametrize("verb", [["view", "--port", "0"], ["record", "x.mcap"], ["status"]])
def test_bad_endpoint_is_one_usage_line(
    verb: list[str],
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.chdir(tmp_path)
    code, _, err = run(capsys, *verb, "--connect", "127.0.0.1")
    assert code == exitcodes.USAGE
    assert err.strip().endswith("--connect: expected tcp/HOST:PORT or HOST:PORT, got '127.0.0.1'")
    assert len(err.strip().splitlines()) == 1


def _recording(tmp_path: Path) -> Path:
    path = tmp_path / "r.mcap"
    with open(path, "wb") as f:
        rec = McapRecorder(f, "cablebot/x")
        rec.add("cablebot/x/pose", b'{"seq": 1, "stamp_ns": 5}', 10)
        rec.close()
    return path


def test_replay_takes_host_port_and_names_a_bad_listen(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    rec = _recording(tmp_path)
    port = free_tcp_port()
    code, out, err = run(
        capsys, "replay", str(rec), "--prefix", "cablebot/x", "--listen", f"127.0.0.1:{port}"
    )
    assert code == exitcodes.OK, err
    assert f"on tcp/127.0.0.1:{port}" in out
    code, _, err = run(capsys, "replay", str(rec), "--prefix", "cablebot/x", "--listen", "nowhere")
    assert code == exitcodes.USAGE
    assert "--listen: expected tcp/HOST:PORT or HOST:PORT, got 'nowhere'" in err


def test_replay_on_a_taken_port_says_what_to_do(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    rec = _recording(tmp_path)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code, _, err = run(
            capsys, "replay", str(rec), "--prefix", "cablebot/x", "--listen", f"127.0.0.1:{port}"
        )
    assert code == exitcodes.REFUSED
    assert "the address is taken" in err
    assert "give --listen tcp/127.0.0.1:PORT" in err
    assert ".rs:" not in err and len(err.strip().splitlines()) == 1
