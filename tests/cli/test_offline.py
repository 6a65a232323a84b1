"""`cablebot ipk` / `cablebot fpk`: offline kinematics tools (no daemon)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.cli import main
from controller.service.config import default_config

DESK = Path(__file__).resolve().parents[2] / "config" / "desk.toml"


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_ipk_prints_one_length_per_node(capsys: pytest.CaptureFixture[str]) -> None:
    cfg = default_config()
    code, out, err = run(capsys, "ipk", "0", "0", "1")
    assert code == 0, err
    lines = [ln for ln in out.splitlines() if ln.startswith("node")]
    assert len(lines) == len(cfg.reels)
    for line, reel in zip(lines, cfg.reels, strict=True):
        node, length = int(line.split()[1]), float(line.split()[2])
        assert node == reel.node_id
        assert length == pytest.approx(math.dist((0.0, 0.0, 1.0), reel.anchor_m), abs=1e-6)


def test_ipk_json(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "ipk", "0.1", "0.2", "1.5", "--json")
    assert code == 0
    data = json.loads(out)
    cfg = default_config()
    assert data["node_ids"] == [r.node_id for r in cfg.reels]
    assert data["cable_lengths_m"] == pytest.approx(
        [math.dist((0.1, 0.2, 1.5), r.anchor_m) for r in cfg.reels], abs=1e-9
    )
    assert data["in_workspace"] is True


def test_ipk_outside_the_workspace_fails_unless_no_limits(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, _, err = run(capsys, "ipk", "500", "0", "1")
    assert code == 1
    assert "outside the workspace" in err
    code, out, err = run(capsys, "ipk", "500", "0", "1", "--no-limits")
    assert code == 0, err
    assert "node" in out


def test_ipk_rejects_nan(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "ipk", "nan", "0", "1")
    assert code == 1
    assert out == ""
    assert "finite" in err


def test_fpk_round_trip_with_a_config_file(capsys: pytest.CaptureFixture[str]) -> None:
    cfg_file = DESK
    code, out, err = run(capsys, "ipk", "--config", str(cfg_file), "0.2", "-0.3", "0.3", "--json")
    assert code == 0, err
    data = json.loads(out)
    assert data["node_ids"] == [0, 1, 2, 3]
    assert data["in_workspace"] is True
    lengths = [str(v) for v in data["cable_lengths_m"]]
    code, out, err = run(capsys, "fpk", "--config", str(cfg_file), *lengths, "--json")
    assert code == 0, err
    res = json.loads(out)
    assert res["position_m"] == pytest.approx([0.2, -0.3, 0.3], abs=1e-9)
    assert res["residual_m"] < 1e-9
    code, out, _ = run(capsys, "fpk", "--config", str(cfg_file), *lengths)
    assert code == 0
    assert out.startswith("position x=+0.200000 y=-0.300000 z=+0.300000 m")


def test_fpk_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "fpk", "1", "2")
    assert code == 1
    assert "expected 4 cable lengths" in err
    code, _, err = run(capsys, "fpk", "0.1", "0.1", "0.1", "0.1")
    assert code == 1
    assert "no position for these lengths" in err
    code, _, err = run(capsys, "fpk", "1", "1", "inf", "1")
    assert code == 1
    assert "finite" in err
    code, _, err = run(
        capsys, "fpk", "--config", str(tmp_path / "missing.toml"), "1", "1", "1", "1"
    )
    assert code == 1
    assert "missing.toml" in err


@settings(max_examples=25, deadline=None)
@given(
    x=st.floats(-30.0, 30.0),
    y=st.floats(-20.0, 20.0),
    z=st.floats(0.5, 6.5),  # anchors at 7.62 m: above them fpk returns the lower mirror point
)
def test_fpk_inverts_ipk_on_the_default_robot(x: float, y: float, z: float) -> None:
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["ipk", "--no-limits", "--json", f"{x:.12f}", f"{y:.12f}", f"{z:.12f}"]) == 0
    lengths = [f"{v:.12f}" for v in json.loads(out.getvalue())["cable_lengths_m"]]
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["fpk", "--json", *lengths]) == 0
    assert json.loads(out.getvalue())["position_m"] == pytest.approx([x, y, z], abs=1e-6)


def test_entry_point_runs_as_a_process() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "controller.cli", "ipk", "0", "0", "1", "--json"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert len(json.loads(proc.stdout)["cable_lengths_m"]) == len(default_config().reels)
