"""Configuration of heavy cables: `[[reels]] cable_mass_kg_per_m` and `[sim]
cable_mass_kg_per_m`, validated as the rest of the file; a cable too heavy to hang within the
tension limit is refused with the pose; the tension rule and the cable model follow the mass;
`check-config` shows the sag and what it would cost unmodelled."""

from __future__ import annotations

import json
from typing import Any

import pytest

from controller.cli import main
from controller.cli.configs import describe
from controller.core.sag_plan import SagTensionCheck
from controller.core.statics import TensionCheck
from controller.service.cables import CableModel
from controller.service.config import ConfigError, paper_robot_data, parse_config, tension_check
from controller.service.simulated import sim_cable_masses, sim_plant
from tests.daemon_procs import to_toml

STEEL = 0.036


def data_with(mass: Any = STEEL, ea: Any = 4.5e5, **loop: Any) -> dict[str, Any]:
    d = paper_robot_data("heavy")
    for r in d["reels"]:
        if mass is not None:
            r["cable_mass_kg_per_m"] = mass
        if ea is not None:
            r["cable_ea_n"] = ea
    d["loop"] = {**d["loop"], **loop}
    return d


def test_cable_mass_is_read_per_reel_and_absent_means_massless() -> None:
    cfg = parse_config(data_with(), "t.toml")
    assert [r.cable_mass_kg_per_m for r in cfg.reels] == [STEEL] * 4
    assert cfg.summary()["reels"][0]["cable_mass_kg_per_m"] == STEEL
    d = data_with(None)
    d["reels"][2]["cable_mass_kg_per_m"] = 0.01
    assert [r.cable_mass_kg_per_m for r in parse_config(d, "t.toml").reels] == [
        None,
        None,
        0.01,
        None,
    ]
    massless = parse_config(data_with(None), "t.toml")
    assert [r.cable_mass_kg_per_m for r in massless.reels] == [None] * 4
    # massless cables: today's rule and model exactly
    assert massless.payload is not None and massless.tension is not None
    check = tension_check(massless.payload, massless.tension, massless.geometry, massless.reels)
    assert type(check) is TensionCheck
    assert CableModel.from_config(massless, check).sag is None


@pytest.mark.parametrize(
    ("value", "problem"),
    [
        (-0.01, r"reels\[0\]\.cable_mass_kg_per_m: must be >= 0"),
        (float("nan"), r"reels\[0\]\.cable_mass_kg_per_m: must be finite"),
        (float("inf"), r"reels\[0\]\.cable_mass_kg_per_m: must be finite"),
        ("36 g/m", r"reels\[0\]\.cable_mass_kg_per_m: must be a number in kilograms per metre"),
    ],
)
def test_bad_cable_mass_is_refused_by_name(value: Any, problem: str) -> None:
    d = data_with(None)
    d["reels"][0]["cable_mass_kg_per_m"] = value
    with pytest.raises(ConfigError, match=problem):
        parse_config(d, "t.toml")
    d = data_with(None)
    d["sim"] = {**d["sim"], "cable_mass_kg_per_m": value}
    with pytest.raises(ConfigError, match=problem.replace(r"reels\[0\]", "sim")):
        parse_config(d, "t.toml")


def test_a_cable_too_heavy_for_the_tension_limit_is_refused_with_the_pose() -> None:
    d = data_with(8.0)  # 8 kg/m: the cable alone needs thousands of newtons over 95 m
    with pytest.raises(ConfigError) as info:
        parse_config(d, "t.toml")
    text = str(info.value)
    assert "reels[0].cable_mass_kg_per_m: 8 kg/m is too heavy" in text
    assert "the workspace's corner (38.5, 23, 0) m" in text
    assert "needs at least 5777 N at its anchor, above 495 N (limits.max_tension_n 500 N" in text
    # and the power-up pose cannot be held with its weight either
    assert "homing.power_up_position_m: cable 1 tension" in text
    assert "cables' weight" in text


def test_heavy_cables_need_a_payload_and_planned_tensions() -> None:
    d = data_with()
    del d["payload"]
    for k in ("min_tension_n", "max_tension_n", "tension_margin_n"):
        del d["limits"][k]
    with pytest.raises(ConfigError, match=r"reels\[0\]\.cable_mass_kg_per_m: needs \[payload\]"):
        parse_config(d, "t.toml")
    d = data_with(stretch_tensions="measured", torque_telemetry="cyclic")
    d["sim"] = {**d["sim"], "plant": "physical"}
    with pytest.raises(ConfigError, match="not modelled with heavy cables"):
        parse_config(d, "t.toml")


def test_the_power_up_pose_is_checked_with_the_cables_weight() -> None:
    """A power-up pose the straight rule allows and the one with the cables' weight refuses:
    (0, 0, 6) m with 3 mm steel at 5 kg needs 607 N at the anchors."""
    d = data_with()
    d["homing"] = {**d["homing"], "power_up_position_m": [0.0, 0.0, 6.0]}
    with pytest.raises(ConfigError, match=r"homing\.power_up_position_m: cable 1 tension 606\.7 N"):
        parse_config(d, "t.toml")
    assert parse_config(data_with(None) | {"homing": d["homing"]}, "t.toml")


def test_heavy_cables_make_the_tension_rule_and_the_cable_model_sag() -> None:
    cfg = parse_config(data_with(), "t.toml")
    assert cfg.payload is not None and cfg.tension is not None
    check = tension_check(cfg.payload, cfg.tension, cfg.geometry, cfg.reels)
    assert isinstance(check, SagTensionCheck)
    model = CableModel.from_config(cfg, check)
    assert model.sag is check.planner and model.stretch is None
    home = model.home_lengths_m((0.0, 0.0, 2.0))
    plan = check.planner.exact((0.0, 0.0, 2.0))
    assert home == plan.paid_out_m
    # the set-point's plan gives the commanded lengths; the same set-point held is made exact
    sp = (3.0, 2.0, 2.5)
    check.solve(sp)
    planned = check.planner.planned(position_m=sp)
    assert planned is not None
    assert model.commanded_lengths_m(planned.chords_m, None) == planned.paid_out_m
    held = model.commanded_lengths_m(planned.chords_m, None)
    assert held == pytest.approx(check.sag.solve(sp).paid_out_m, abs=1e-9)
    pose, residual = model.pose(held, (3.001, 2.0, 2.5), None, (sp, ()))
    assert max(abs(a - b) for a, b in zip(pose, sp, strict=True)) < 1e-9 and residual < 1e-9
    with pytest.raises(ValueError, match="tension rule with their weight"):
        CableModel.from_config(cfg, TensionCheck(cfg.anchors_m, 5.0, 5.0, 500.0))


def test_the_simulator_takes_the_reels_mass_unless_its_own_is_given() -> None:
    d = data_with()
    d["sim"] = {**d["sim"], "plant": "physical"}
    cfg = parse_config(d, "t.toml")
    assert sim_cable_masses(cfg) == (STEEL,) * 4
    plant = sim_plant(cfg, [0.0] * 4)
    assert plant.plant.params.sags
    assert max(abs(f) for f in plant.plant.net_force_n()) < 1e-6  # at rest at power-up
    d = data_with(None)
    d["sim"] = {**d["sim"], "plant": "physical", "cable_mass_kg_per_m": 0.01}
    cfg = parse_config(d, "t.toml")
    assert sim_cable_masses(cfg) == (0.01,) * 4
    assert all(r.cable_mass_kg_per_m is None for r in cfg.reels)  # the controller's: massless
    d = data_with(None)
    d["sim"] = {**d["sim"], "plant": "physical"}
    assert not sim_plant(parse_config(d, "t.toml"), [0.0] * 4).plant.params.sags


def test_check_config_shows_the_sag_and_the_unmodelled_error(
    tmp_path: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    lines, _, data = describe(parse_config(data_with(), "t.toml"))
    head = [ln for ln in lines if ln.startswith("sag")]
    assert len(head) == 1 and "cables of 0.036 kg/m hang in catenaries" in head[0]
    rows = {ln.split()[0]: ln for ln in lines if ln.startswith("  ")}
    assert "drop 0.574 m (cable 1)" in rows["power-up"]
    assert "unmodelled 0.0 mm off" in rows["power-up"]  # homed there
    assert "unmodelled 100.1 mm off" in rows["floor"]
    assert "beyond the tension limits there" in rows["top"]
    assert "cable 1 would hang slack" in rows["corner"]
    assert [p["pose"] for p in data["sag"]] == ["power-up", "floor", "middle", "top"]
    assert data["sag"][1]["unmodelled_error_m"] == pytest.approx(0.1001, abs=1e-4)
    lines, _, data = describe(parse_config(data_with(None), "t.toml"))
    assert not [ln for ln in lines if ln.startswith("sag")] and "sag" not in data
    path = tmp_path / "heavy.toml"
    path.write_text(to_toml(data_with()))
    assert main(["check-config", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["sag"][0]["pose"] == "power-up"
