"""`cablebot modes`: the effector's modes at a pose from the model (or the simulator's plant),
said instead of NaN where there are none; check-config's range of the modes and the shaper."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from controller.cli import main
from controller.core.vibration import effector_modes
from controller.service.config import load_config, tension_check

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def paper_ea(tmp_path: Path) -> Path:
    text = (REPO / "config" / "paper-acre.toml").read_text()
    text = text.replace(
        "mechanical_advantage = 1.0", "mechanical_advantage = 1.0\ncable_ea_n = 4.5e5"
    )
    path = tmp_path / "paper-ea.toml"
    path.write_text(text)
    return path


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_modes_json_is_the_models(capsys: pytest.CaptureFixture[str], paper_ea: Path) -> None:
    code, out, err = run(capsys, "modes", "10", "-5", "3", "--config", str(paper_ea), "--json")
    assert code == 0, err
    data = json.loads(out)
    cfg = load_config(paper_ea)
    t = tension_check(cfg.payload, cfg.tension, cfg.geometry).solve((10.0, -5.0, 3.0)).tensions_n
    want = effector_modes(
        cfg.anchors_m, (10.0, -5.0, 3.0), t, [4.5e5] * 4, 5.0, cable_damping_ratio=0.02
    )
    assert data["frequencies_hz"] == pytest.approx(list(want.frequencies_hz), rel=1e-12)
    assert data["frequencies_hz"] == sorted(data["frequencies_hz"])
    assert data["damping_ratios"] == pytest.approx(list(want.damping_ratios), rel=1e-12)
    for d in data["directions"]:
        assert math.hypot(*d) == pytest.approx(1.0)
    assert data["problem"] is None and data["source"] == "model"
    # the shaper's delay: 1.5 periods of each mode for the default two-hump EI
    assert data["shaper"]["type"] == "2hump_ei"
    assert data["shaper"]["delay_s"] == pytest.approx(sum(1.5 / f for f in data["frequencies_hz"]))


def test_modes_text(capsys: pytest.CaptureFixture[str], paper_ea: Path) -> None:
    code, out, err = run(capsys, "modes", "0", "0", "2", "--config", str(paper_ea))
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0].startswith("position x=+0.0000 y=+0.0000 z=+2.0000 m, payload 5 kg")
    assert lines[1].startswith(
        "mode 1     1.633 Hz  damping ratio 0.0198  direction (+0.000, +0.000, +1.000)"
    )
    assert lines[4].startswith("shaper  2hump_ei: delays a move by")
    assert "nan" not in out.lower()


def test_two_passes_double_the_delay_everywhere_it_is_said(
    capsys: pytest.CaptureFixture[str], paper_ea: Path, tmp_path: Path
) -> None:
    from controller.cli.shaper_cmd import describe

    twice = tmp_path / "paper-ea-2.toml"
    twice.write_text(paper_ea.read_text() + "\n[shaper]\npasses = 2\n")
    code, out, err = run(capsys, "modes", "0", "0", "2", "--config", str(twice), "--json")
    assert code == 0, err
    data = json.loads(out)
    assert data["shaper"]["passes"] == 2
    assert data["shaper"]["delay_s"] == pytest.approx(sum(3.0 / f for f in data["frequencies_hz"]))
    code, out, err = run(capsys, "modes", "0", "0", "2", "--config", str(twice))
    assert "shaper  2hump_ei x2: delays a move by" in out
    code, out, err = run(capsys, "check-config", "--config", str(twice))
    assert code == 0, err
    assert "shaper     2hump_ei x2 on the model's three modes" in out
    # the line `status` and `shaper` print for a running robot's shaper
    line = describe(
        {
            "type": "2hump_ei",
            "passes": 2,
            "damping_ratio": 0.02,
            "frequency_hz": None,
            "frequencies_hz": [1.6, 7.2, 11.7],
            "delay_s": 2.5,
        }
    )
    assert line.startswith("2hump_ei x2 on the model's modes at the set-point, damping ratio 0.02")


def test_a_rigid_model_or_a_pose_outside_is_said(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "modes", "0", "0", "2")  # the built-in robot: rigid cables
    assert code == 1 and out == ""
    assert "no modes: cables 1, 2, 3, 4 have no EA" in err and "--sim" in err
    code, out, err = run(capsys, "modes", "0", "0", "2", "--json")
    assert code == 1
    data = json.loads(out)
    assert data["frequencies_hz"] is None and "rigid model" in data["problem"]
    code, out, err = run(capsys, "modes", "0", "0", "90")
    assert code == 1 and "outside the workspace" in err
    # the simulator's plant has its cables' EA: modes
    code, out, err = run(capsys, "modes", "0", "0", "2", "--sim", "--json")
    assert code == 0, err
    data = json.loads(out)
    assert data["source"] == "sim" and data["cable_ea_n"] == [1e6] * 4
    assert np.all(np.diff(data["frequencies_hz"]) > 0.0)


def test_check_config_prints_the_range_of_the_modes_and_the_shaper(
    capsys: pytest.CaptureFixture[str], paper_ea: Path
) -> None:
    code, out, err = run(capsys, "check-config", str(paper_ea))
    assert code == 0, err
    modes = [ln for ln in out.splitlines() if ln.startswith("modes ")]
    shaper = [ln for ln in out.splitlines() if ln.startswith("shaper ")]
    assert len(modes) == 1 and "Hz over" in modes[0] and "poses of the workspace (5 kg)" in modes[0]
    assert len(shaper) == 1 and "2hump_ei on the model's three modes" in shaper[0]
    code, out, err = run(capsys, "check-config", str(paper_ea), "--json")
    assert code == 0, err
    data = json.loads(out)
    lo, hi = data["modes"]["low_hz"], data["modes"]["high_hz"]
    assert all(0.0 < a <= b for a, b in zip(lo, hi, strict=True))
    assert lo == sorted(lo)
    assert (
        data["shaper"]["type"] == "2hump_ei"
        and data["shaper"]["delay_s"][0] <= data["shaper"]["delay_s"][1]
    )
    code, out, err = run(capsys, "check-config", str(REPO / "config" / "desk.toml"))
    assert code == 0, err
    assert "modes      rigid cables" in out and "shaper     off" in out
