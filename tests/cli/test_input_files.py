"""Files a verb reads: every one that is not UTF-8 is named with the byte, its line and column
(the same words as check-config); a path longer than one command takes is refused in points."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from controller.cli import exitcodes, main
from controller.core.commands import MAX_PATH_POINTS_SENT, MAX_PAYLOAD_BYTES, parse_command
from controller.service.zenoh_io import free_tcp_port

REPO = Path(__file__).resolve().parents[2]
NO_DAEMON = ["--connect", f"127.0.0.1:{free_tcp_port()}", "--timeout", "1"]


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def latin1(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_bytes(text.encode("latin-1"))
    return path


def test_path_file_not_utf8_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = latin1(tmp_path, "latin1.csv", "x,y,z\n0,0,1 # caf\xe9\n")
    code, out, err = run(capsys, "path", str(f), *NO_DAEMON)
    assert code == exitcodes.REFUSED
    assert err == f"cablebot: {f}: not UTF-8 text: byte 0xe9 at line 2, column 12\n"
    assert out == ""


def test_calibrate_solve_files_not_utf8_are_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    samples = latin1(tmp_path, "latin1.csv", "# \xe9chantillons\n")
    code, _, err = run(
        capsys, "calibrate", "solve", str(samples), "--config", str(REPO / "config/desk.toml")
    )
    assert code == exitcodes.REFUSED
    assert f"{samples}: not UTF-8 text: byte 0xe9 at line 1, column 3" in err
    assert "Traceback" not in err
    config = latin1(tmp_path, "robot.toml", 'name = "d\xe9sk"\n')
    code, _, err = run(capsys, "calibrate", "solve", str(samples), "--config", str(config))
    assert code == exitcodes.REFUSED
    assert "not UTF-8 text: byte 0xe9 at line 1, column 10" in err


def test_the_points_limit_fits_the_byte_cap() -> None:
    widest = -2.2250738585072014e-308
    payload = {"points_m": [[widest] * 3] * MAX_PATH_POINTS_SENT, "speed_mps": widest}
    assert len(json.dumps(payload)) <= MAX_PAYLOAD_BYTES["path"]
    ok = {"points_m": [[0.1234567890123, -1.5, 2.000000000001]] * MAX_PATH_POINTS_SENT}
    assert len(parse_command("path", json.dumps(ok)).points_m) == MAX_PATH_POINTS_SENT


def test_a_long_path_is_refused_in_points_with_what_to_do(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    f = tmp_path / "long.csv"
    f.write_text("".join(f"{0.1 + i * 1e-5:.6f},{0.2 - i * 1e-5:.6f},1.5\n" for i in range(10_000)))
    code, _, err = run(capsys, "path", str(f), *NO_DAEMON)
    assert code == exitcodes.REFUSED
    n = MAX_PATH_POINTS_SENT
    assert f"10000 points; one path command takes at most {n} points" in err
    assert f"split it into parts of at most {n} points" in err
    assert "bytes" not in err
