"""`cablebot gcode` on what a user may hand it: empty, comment-only and binary files, a dry
run that starts where the real run does, a bad --from, a job written in metres."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from controller.cli import exitcodes, main

CONFIG = Path(__file__).resolve().parents[2] / "config"


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_an_empty_or_comment_only_file_is_an_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    empty = tmp_path / "empty.gcode"
    empty.write_bytes(b"")
    code, out, err = run(["gcode", str(empty), "--dry-run"], capsys)
    assert code == exitcodes.REFUSED and out == ""
    assert err == f"cablebot: {empty}: no G-code in it (empty): nothing to run\n"
    comments = tmp_path / "comments.gcode"
    comments.write_text("; sliced by nobody\n\n(nothing else)\n")
    code, _, err = run(["gcode", str(comments), "--dry-run"], capsys)
    assert code == exitcodes.REFUSED
    assert err == (
        f"cablebot: {comments}: no G-code in it (only comments and blank lines): nothing to run\n"
    )


def test_a_binary_file_is_refused_as_path_refuses_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    blob = tmp_path / "blob.bin"
    blob.write_bytes(b'G1 X1 F600\n\x7fELF\x02\x01\x01\x00\x00\xf0\x9f\x00 "unterminated\n')
    code, _, g_err = run(["gcode", str(blob), "--dry-run"], capsys)
    assert code == exitcodes.REFUSED
    assert g_err == f"cablebot: {blob}: not UTF-8 text: byte 0xf0 at line 2, column 10\n"
    code, _, p_err = run(["path", str(blob), "--connect", "127.0.0.1:1"], capsys)
    assert code == exitcodes.REFUSED and p_err == g_err  # one reader, one message


def test_the_dry_run_starts_at_the_power_up_pose(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the CiA 402 rig's floor is 1 cm up: from the G-code origin (0, 0, 0) every job was refused
    job = tmp_path / "square.gcode"
    job.write_text("G21\nG90\nG1 X50 Y0 Z100 F3000\nG1 X50 Y50\nG1 X0 Y50\nG1 X0 Y0\n")
    cfg = str(CONFIG / "cia402-sim.toml")
    code, out, err = run(["gcode", str(job), "--dry-run", "--config", cfg, "--json"], capsys)
    assert code == exitcodes.OK, err
    s = json.loads(out)
    assert s["start_m"] == [0.0, 0.0, 0.1] and s["start_from"] == "the robot's power-up pose"
    assert s["bbox_m"] == [[0.0, 0.0, 0.1], [0.05, 0.05, 0.1]] and s["warnings"] == []
    code, out, _ = run(["gcode", str(job), "--dry-run", "--config", cfg], capsys)
    assert out.startswith(
        "start      x=+0.0000  y=+0.0000  z=+0.1000 m (the robot's power-up pose)\n"
    )


def test_a_bad_from_is_blamed_on_from(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    job = tmp_path / "job.gcode"
    job.write_text("G21\nG90\nM104 S200\nG1 X10 Y0 Z2000 F3000\n")
    code, out, err = run(["gcode", str(job), "--dry-run", "--from", "0", "0", "-1"], capsys)
    assert code == exitcodes.REFUSED and out == ""
    assert err.startswith("cablebot: --from 0, 0, -1: the robot cannot start there: z=-1 m")
    assert "line" not in err


def test_a_job_written_in_metres_is_flagged(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    job = tmp_path / "metres.gcode"
    job.write_text("G1 X0.1 Y0.1 Z2.2 F3000\nG1 X0.4 Y0.1\nG1 X0.4 Y0.4\n")  # 0.3 mm, not 0.3 m
    # on the built-in robot (floor at 0) it flies, with a warning
    code, out, err = run(["gcode", str(job), "--dry-run", "--json"], capsys)
    assert code == exitcodes.OK, err
    (warning,) = json.loads(out)["warnings"]
    assert "span only 0.3 mm" in warning and "is the file written in metres?" in warning
    assert err == f"cablebot: warning: {warning}\n"
    # on the desk rig (floor at 1 cm) it is refused, and the refusal says the likely cause
    code, _, err = run(
        ["gcode", str(job), "--dry-run", "--config", str(CONFIG / "desk.toml")], capsys
    )
    assert code == exitcodes.REFUSED
    assert "below the floor" in err and "is the file written in metres?" in err


def test_check_config_refuses_a_top_speed_no_robot_of_that_size_can_mean(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = (CONFIG / "desk.toml").read_text()
    f = tmp_path / "fast.toml"
    f.write_text(text.replace("max_speed_mps = 0.3", "max_speed_mps = 300", 1))
    assert f.read_text() != text
    code, _, err = run(["check-config", str(f)], capsys)
    assert code == exitcodes.REFUSED
    assert (
        f"{f}: limits.max_speed_mps: 300 m/s crosses the workspace's 0.9 m in 3 ms: a speed this"
        " robot cannot mean" in err
    )
