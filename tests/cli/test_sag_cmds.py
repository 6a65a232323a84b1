"""The offline verbs with stretching and heavy cables: `cablebot ipk` says what the reels pay out
(`paid_out_m`), `cablebot fpk --paid-out` takes it back, `cablebot statics` shows the tension
at both ends of heavy cables, `cablebot workspace` maps the rule with their weight beside the
straight cables'."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

from controller.cli import main
from controller.service.config import paper_robot_data
from tests.daemon_procs import to_toml

STEEL = 0.036


def robot_file(
    tmp_path: Path, mass: float | None = STEEL, ea: float | None = 4.5e5, name: str = "heavy"
) -> Path:
    d = paper_robot_data(name)
    for r in d["reels"]:
        if mass is not None:
            r["cable_mass_kg_per_m"] = mass
        if ea is not None:
            r["cable_ea_n"] = ea
    path = tmp_path / f"{name}.toml"
    path.write_text(to_toml(d))
    return path


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def ipk_json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, Any]:
    code, out, err = run(capsys, "ipk", *argv, "--json")
    assert code == 0, err
    data: dict[str, Any] = json.loads(out)
    return data


def test_ipk_says_what_the_reels_pay_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    p = ("20", "10", "2")
    rigid = ipk_json(capsys, "--config", str(robot_file(tmp_path, None, None, "rigid")), *p)
    assert rigid["paid_out_m"] == rigid["cable_lengths_m"]  # rigid and massless: the lines
    stretch = ipk_json(capsys, "--config", str(robot_file(tmp_path, None, 4.5e5, "elastic")), *p)
    assert stretch["cable_lengths_m"] == rigid["cable_lengths_m"]
    # stretched cables pay out less than the lines: 68 N on 70 m of EA 4.5e5 N is 10.5 mm
    short = [a - b for a, b in zip(stretch["cable_lengths_m"], stretch["paid_out_m"], strict=True)]
    assert short[0] == pytest.approx(0.0105, abs=2e-4)
    heavy = ipk_json(capsys, "--config", str(robot_file(tmp_path)), *p)
    # 3 mm steel: the long cables (70 m, 63 m) sag and pay out more than the line
    assert heavy["paid_out_m"][0] - heavy["cable_lengths_m"][0] == pytest.approx(0.114, abs=2e-3)
    assert heavy["problem"] is None
    code, out, err = run(capsys, "ipk", "--config", str(robot_file(tmp_path)), *p)
    assert code == 0, err
    assert "paid out (stretch and sag)" in out
    assert "node  0  70.077007 m     70.191243 m" in out


def test_ipk_where_the_cables_cannot_hold_the_payload_says_why(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run(
        capsys, "ipk", "--config", str(robot_file(tmp_path)), "38.4", "22.9", "0", "--json"
    )
    assert code == 1
    data = json.loads(out)
    assert data["paid_out_m"] is None
    assert "cable 1 would hang slack" in data["problem"] and "cable 1 would hang slack" in err


@pytest.mark.parametrize(("mass", "ea"), [(STEEL, 4.5e5), (None, 4.5e5), (STEEL, None)])
def test_fpk_paid_out_takes_back_what_ipk_pays_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], mass: float | None, ea: float | None
) -> None:
    path = str(robot_file(tmp_path, mass, ea))
    target = (-30.0, -18.0, 1.0)
    paid = ipk_json(capsys, "--config", path, *map(str, target))["paid_out_m"]
    code, out, err = run(capsys, "fpk", "--config", path, "--paid-out", *map(repr, paid), "--json")
    assert code == 0, err
    data = json.loads(out)
    assert data["paid_out"] is True
    assert math.dist(data["position_m"], target) < 1e-6
    # taken as straight lines, the same lengths put the effector elsewhere
    code, out, err = run(capsys, "fpk", "--config", path, *map(repr, paid), "--json")
    assert code == 0, err
    assert math.dist(json.loads(out)["position_m"], target) > 5e-3
    code, out, err = run(capsys, "fpk", "--config", path, "--paid-out", *map(repr, paid))
    assert code == 0, err
    assert "(paid-out lengths, " in out


def test_statics_shows_both_ends_of_heavy_cables(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = str(robot_file(tmp_path))
    code, out, err = run(capsys, "statics", "--config", path, "20", "10", "2", "--json")
    assert code == 0, err
    data = json.loads(out)
    t0, t1 = data["effector_tensions_n"], data["anchor_tensions_n"]
    assert data["tensions_n"] == t1  # what the reels carry
    # the anchor end carries the cable's weight over its rise (5.62 m of 0.353 N/m)
    assert [b - a for a, b in zip(t0, t1, strict=True)] == pytest.approx([1.98] * 4, abs=0.02)
    assert t0 == pytest.approx([115.5051, 132.9057, 216.0301, 115.5051], abs=1e-3)
    code, out, err = run(capsys, "statics", "--config", path, "20", "10", "2")
    assert code == 0, err
    assert "at the effector   at the anchor" in out
    assert "and the cables' weight (0.036 kg/m)" in out
    assert "margin 110.5051 N (cable 4 at the effector, to the min limit)" in out
    code, out, err = run(capsys, "statics", "--config", path, "0", "0", "6")
    assert code == 1
    assert "cable 1 tension 606.7 N at the anchor above 495 N" in err
    # massless cables: one column, both ends the same in the JSON
    plain = str(robot_file(tmp_path, None, None, "plain"))
    code, out, err = run(capsys, "statics", "--config", plain, "20", "10", "2", "--json")
    data = json.loads(out)
    assert data["effector_tensions_n"] == data["anchor_tensions_n"] == data["tensions_n"]


def test_workspace_maps_the_rule_with_the_cables_weight(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = str(robot_file(tmp_path))
    code, out, err = run(capsys, "workspace", "--config", path, "--step", "4", "--json")
    assert code == 0, err
    data = json.loads(out)
    assert data["volume_m3"] < data["straight_volume_m3"]
    assert data["straight_only_m3"] > 0.0
    code, out, err = run(capsys, "workspace", "--config", path, "--step", "4")
    assert code == 0, err
    assert "the straight rule allows, the catenary refuses" in out
