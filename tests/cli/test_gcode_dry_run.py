"""`cablebot gcode --dry-run`: the whole job planned offline with the robot's limits."""

from __future__ import annotations

import gzip
import io
import json
import re
from pathlib import Path

import pytest

from controller.cli import exitcodes, main

VASE = Path(__file__).resolve().parents[1] / "data" / "vase.gcode.gz"
SLICER_ESTIMATE_RE = re.compile(
    r"; estimated printing time \(normal mode\) = (?:(\d+)h )?(\d+)m (\d+)s"
)


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def slicer_estimate_s(text: str) -> float:
    m = SLICER_ESTIMATE_RE.search(text)
    assert m is not None
    h, mi, s = (int(g) if g else 0 for g in m.groups())
    return 3600.0 * h + 60.0 * mi + s


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_sliced_vase_plans_within_10_percent_of_the_slicer(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The built-in robot's 1 m/s^2 is the slicer's (M201/M204 1000 mm/s^2); the file's M203
    lowers the speed to the slicer's 200 mm/s; no retraction and no Z-only moves in it."""
    text = gzip.decompress(VASE.read_bytes()).decode()
    estimate = slicer_estimate_s(text)
    assert estimate == 2657.0
    moves = sum(
        1
        for ln in text.splitlines()
        if re.match(r"G[0-3] ", ln) and re.search(r" [XYZ][-.\d]", ln.split(";")[0])
    )
    code, out, err = run(["gcode", str(VASE), "--dry-run", "--json"], capsys)
    assert code == exitcodes.OK, err
    s = json.loads(out)
    assert s["moves"] == moves == 65798
    assert abs(s["duration_s"] - estimate) <= 0.10 * estimate, s["duration_s"]
    lo, hi = s["bbox_m"]
    # centred on 0,0 (radius 25 mm at most with the skirt a little wider), 90 mm tall, 5 mm lift
    assert -0.04 < lo[0] < -0.02 and 0.02 < hi[0] < 0.04
    assert lo[2] == 0.0 and hi[2] == pytest.approx(0.09)
    assert s["unsupported"] == {}
    assert s["not_driven"]["E"] > 60000 and s["not_driven"]["M104"] == 2


def test_a_job_out_of_the_workspace_is_refused_naming_the_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    f = tmp_path / "out.gcode"
    f.write_text("G21\nG90\nG1 Z2000 F6000\nG1 X1000\nG1 Z-1 ; below the floor\nG1 Z100\n")
    code, out, err = run(["gcode", str(f), "--dry-run"], capsys)
    assert code == exitcodes.REFUSED
    assert f"{f}: line 5: refused: point [1.0000, 0.0000, -0.0010]" in err
    assert "floor_z_m" in err and out == ""


def test_a_job_out_of_the_tension_region_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the built-in robot carries 5 kg: 6.5 m up the cables would pull more than 495 N
    f = tmp_path / "high.gcode"
    f.write_text("G1 Z2000 F6000\nG1 Z6500\n")
    code, _, err = run(["gcode", str(f), "--dry-run"], capsys)
    assert code == exitcodes.REFUSED
    assert "line 2: refused" in err and "above 495 N" in err


def test_syntax_errors_name_the_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "bad.gcode"
    f.write_text("G1 X1 F600\nG1 X#2\n")
    code, _, err = run(["gcode", str(f), "--dry-run"], capsys)
    assert code == exitcodes.REFUSED
    assert f"{f}: line 2: column 5: cannot read '#2'" in err


def test_stdin_from_and_the_summary(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    job = "G21 G91\nM104 S200\nG1 X100 F6000\nG2 X100 Y0 R50\nG4 P500\nM999\nM999\nG29\n"
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(job.encode())))
    code, out, err = run(["gcode", "-", "--dry-run", "--json", "--from", "1", "2", "3"], capsys)
    assert code == exitcodes.OK, err
    s = json.loads(out)
    assert s["start_m"] == [1.0, 2.0, 3.0]
    assert s["moves"] == 2 and s["lines"] == 8
    assert s["path_m"] == pytest.approx(0.1 + 0.05 * 3.141592653589793, rel=1e-3)  # chords
    assert s["start_from"] == "--from"
    # the box of the job's motions (its start, the --from point, is not where it goes)
    assert s["bbox_m"][0] == pytest.approx([1.1, 2.0, 3.0])
    assert s["bbox_m"][1] == pytest.approx([1.2, 2.05, 3.0], abs=1e-4)
    assert s["unsupported"] == {"G29": 1, "M999": 2}
    assert s["not_driven"] == {"M104": 1}
    # 0.257 m at 0.1 m/s with 1 m/s^2 (a stop at the dwell and at the end) plus 0.5 s
    assert 0.5 + 0.257 / 0.1 < s["duration_s"] < 0.5 + 0.257 / 0.1 + 0.5
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(job.encode())))
    code, out, _ = run(["gcode", "-", "--dry-run", "--from", "1", "2", "3"], capsys)
    assert "unsupported G29 (1), M999 (2)" in out


def test_a_marlin_job_on_a_reprapfirmware_robot_is_told_its_m203(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The sliced vase is Marlin's (`M203 X200 Y200` in mm/s); a robot file from
    `cablebot import-rrf` reads M203 as RepRapFirmware does, in mm/min: 3.3 mm/s, 36 times
    below the job's own feeds. The dry run says so, naming the line and the dialect; the
    same job on the Marlin dialect is not warned about."""
    from tests.service.test_config_layouts import HP4

    with gzip.open(VASE, "rt") as fh:
        lines = fh.read().splitlines()[:400]
    job = tmp_path / "vase.gcode"
    job.write_text("\n".join(lines) + "\n")
    rrf = tmp_path / "hp4-rrf.toml"
    rrf.write_text(HP4.read_text().replace("[gcode]\n", '[gcode]\ndialect = "reprapfirmware"\n'))
    code, out, err = run(["gcode", str(job), "--dry-run", "--config", str(rrf), "--json"], capsys)
    assert code == exitcodes.OK, err
    (warning,) = json.loads(out)["warnings"]
    assert warning.startswith("line 13: M203 limits the job to 3.333 mm/s (read in mm/min), 36")
    assert 'was it written in mm/s? ([gcode] dialect = "marlin" reads it so)' in warning
    assert "cablebot: warning: line 13: M203" in err
    code, out, err = run(["gcode", str(job), "--dry-run", "--config", str(HP4), "--json"], capsys)
    assert code == exitcodes.OK, err
    assert json.loads(out)["warnings"] == [] and "warning" not in err
