"""`cablebot statics` / `cablebot workspace`: offline statics tools (no daemon)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from controller.cli import main
from controller.cli.offline import workspace_problem
from controller.core.statics import G_MPS2
from controller.service.config import default_config, load_config, paper_robot_data

REPO = Path(__file__).resolve().parents[2]
DESK = REPO / "config" / "desk.toml"


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_statics_json_holds_the_payload_at_the_power_up_pose(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, out, err = run(capsys, "statics", "0", "0", "2", "--json")
    assert code == 0, err
    data = json.loads(out)
    assert data["tensions_n"] == pytest.approx([104.4422] * 4, abs=1e-4)
    assert data["feasible"] is True and data["within_margin"] is True
    assert data["margin_n"] == pytest.approx(104.4422 - 5.0, abs=1e-4)
    assert data["limiting_bound"] == "min"
    assert data["limiting_cable"] in (1, 2, 3, 4)
    assert data["node_ids"] == [0, 1, 2, 3]
    assert data["problem"] is None and data["in_workspace"] is True


def test_statics_tensions_balance_the_weight_off_centre(capsys: pytest.CaptureFixture[str]) -> None:
    p = (12.0, -7.5, 3.3)
    code, out, err = run(capsys, "statics", *map(str, p), "--json")
    assert code == 0, err
    data = json.loads(out)
    t = np.asarray(data["tensions_n"])
    anchors = np.asarray(default_config().anchors_m)
    u = anchors - np.asarray(p)
    u /= np.linalg.norm(u, axis=1)[:, None]
    assert t @ u == pytest.approx([0.0, 0.0, 5.0 * G_MPS2], abs=1e-9)
    i = data["limiting_cable"] - 1  # 1-based in the output
    assert min(t - 5.0) == pytest.approx(data["margin_n"]) == pytest.approx(t[i] - 5.0)


def test_statics_refuses_where_the_controller_would(capsys: pytest.CaptureFixture[str]) -> None:
    # 1 m under the anchors each cable needs 571.6 N: above 500 - 5 N
    code, out, err = run(capsys, "statics", "0", "0", "6.6", "--json")
    assert code == 1
    data = json.loads(out)
    assert data["feasible"] is False and data["within_margin"] is False
    assert data["margin_n"] == pytest.approx(500.0 - 571.6104, abs=1e-3)
    assert data["limiting_bound"] == "max"
    assert f"cable {data['limiting_cable']} tension 571.6 N above 495 N" in err, err
    # inside the limits (7.3 N each) but not by the 5 N margin
    code, out, err = run(capsys, "statics", "0", "0", "2", "--mass-kg", "0.35", "--json")
    data = json.loads(out)
    assert code == 1 and data["feasible"] is True and data["within_margin"] is False
    assert "below 10 N (min_tension_n 5 N + tension_margin_n 5 N)" in err, err
    # no distribution at all above the anchors; outside the workspace unless --no-limits
    code, out, err = run(capsys, "statics", "0", "0", "9", "--json", "--no-limits")
    data = json.loads(out)
    assert code == 1 and data["tensions_n"] is None and data["margin_n"] is None
    assert "no cable pulls upward" in err
    code, out, err = run(capsys, "statics", "39.9", "0", "1")
    assert code == 1 and "outside the workspace" in err


def test_statics_text_and_a_config_without_payload(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    code, out, err = run(capsys, "statics", "--config", str(DESK), "0", "0", "0.1")
    assert code == 0, err
    assert "cable 3  node  2      1.7424 N" in out, out
    assert "margin 1.2424 N" in out
    toml = DESK.read_text()
    start = toml.index("# Cable tensions")
    end = toml.index("mass_kg = 0.5")
    bare = tmp_path / "bare.toml"
    bare.write_text(toml[:start] + toml[end:].replace("mass_kg = 0.5", "", 1))
    bare.write_text(bare.read_text().replace("[payload]", ""))
    assert load_config(bare).payload is None
    code, _, err = run(capsys, "statics", "--config", str(bare), "0", "0", "0.1")
    assert code == 1 and "has no [payload] mass_kg" in err, err
    code, _, err = run(capsys, "statics", "--config", str(bare), "0", "0", "0.1", "--mass-kg", "1")
    assert code == 1 and "has no [payload]" in err


def test_workspace_volume_agrees_with_random_poses_within_its_uncertainty(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, out, err = run(capsys, "workspace", "--config", str(DESK), "--step", "0.03", "--json")
    assert code == 0, err
    data = json.loads(out)
    vol, unc, geo = data["volume_m3"], data["uncertainty_m3"], data["geometric_volume_m3"]
    assert 0.0 < vol < geo and 0.0 < unc < vol
    assert data["step_m"] == 0.03 and all(abs(c - 0.03) < 0.005 for c in data["cell_m"])
    # the geometric workspace of the desk: 0.9 x 0.9 m x (0.7 - 0.01) m
    assert geo == pytest.approx(0.9 * 0.9 * 0.69, rel=0.02)
    # independent estimate: uniform random poses in the box, each checked as the loop would
    cfg = load_config(DESK)
    from controller.cli.statics_cmd import tension_check_of

    check = tension_check_of(cfg, None)
    rng = np.random.default_rng(7)
    lo = np.array([data["x_m"][0], data["y_m"][0], data["z_m"][0]])
    hi = np.array([data["x_m"][1], data["y_m"][1], data["z_m"][1]])
    pts = lo + (hi - lo) * rng.random((4000, 3))
    ok = [
        workspace_problem(cfg, tuple(p)) is None and check.check(tuple(p)) is None
        for p in pts.tolist()
    ]
    box = float(np.prod(hi - lo))
    mc = box * float(np.mean(ok))
    mc_sigma = box * math.sqrt(np.mean(ok) * (1 - np.mean(ok)) / len(ok))
    assert abs(mc - vol) <= unc + 3 * mc_sigma, (mc, vol, unc)
    # a finer grid stays within both bounds
    code, out, _ = run(capsys, "workspace", "--config", str(DESK), "--step", "0.015", "--json")
    fine = json.loads(out)
    assert abs(fine["volume_m3"] - vol) <= unc + fine["uncertainty_m3"]
    assert fine["uncertainty_m3"] < unc


def test_paper_robot_feasible_volume(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "workspace", "--step", "1.0", "--json")
    assert code == 0, err
    data = json.loads(out)
    assert data["mass_kg"] == 5.0 and data["tension_margin_n"] == 5.0
    # 76.9 m x 46 m x 6.62 m of geometric workspace; only a layer under the anchors is lost
    assert data["geometric_volume_m3"] == pytest.approx(76.9 * 46 * 6.62, rel=1e-6)
    assert 0.9 < data["feasible_fraction"] < 0.99
    assert abs(data["volume_m3"] - 22200.0) < data["uncertainty_m3"]
    # a heavier payload loses more of it
    code, out, _ = run(capsys, "workspace", "--step", "1.0", "--json", "--mass-kg", "10")
    assert json.loads(out)["volume_m3"] < data["volume_m3"]


def test_workspace_png_and_text(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    png = tmp_path / "slices.png"
    code, out, err = run(
        capsys, "workspace", "--config", str(DESK), "--step", "0.05", "--png", str(png)
    )
    assert code == 0, err
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    assert "tension-feasible" in out and "m³ ±" in out
    # six slices from the lowest cell centre (0.01 + 0.0493 / 2) to the highest
    assert "slices at z = 0.0346, 0.183, 0.281, 0.429, 0.527, 0.675 m" in out, out


def test_workspace_refuses_too_fine_a_step_and_an_unwritable_png(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    code, _, err = run(capsys, "workspace", "--step", "0.01")
    assert code == 1 and "use a larger step" in err
    code, _, err = run(
        capsys,
        "workspace",
        "--config",
        str(DESK),
        "--step",
        "0.1",
        "--png",
        str(tmp_path / "no" / "such" / "dir.png"),
    )
    assert code == 1 and "cannot write" in err
    with pytest.raises(SystemExit):
        main(["workspace", "--step", "-1"])
    data = paper_robot_data("t")
    assert data["payload"] == {"mass_kg": 5.0}
