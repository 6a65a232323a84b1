"""Configuration of cable stretch: `[[reels]] cable_ea_n` and `loop.stretch_tensions`, validated
as the rest of the file; `check-config` shows the stretch the file implies."""

from __future__ import annotations

from typing import Any

import pytest

from controller.cli.configs import describe
from controller.service.config import ConfigError, paper_robot_data, parse_config


def data_with(ea: Any = 2e5, **loop: Any) -> dict[str, Any]:
    d = paper_robot_data("stretchy")
    for r in d["reels"]:
        if ea is not None:
            r["cable_ea_n"] = ea
    d["loop"] = {**d["loop"], **loop}
    return d


def test_cable_ea_is_read_per_reel_and_absent_means_rigid() -> None:
    cfg = parse_config(data_with(2e5), "t.toml")
    assert [r.cable_ea_n for r in cfg.reels] == [2e5] * 4
    assert cfg.loop.stretch_tensions == "planned"
    d = data_with(None)
    d["reels"][1]["cable_ea_n"] = 1e6
    cfg = parse_config(d, "t.toml")
    assert [r.cable_ea_n for r in cfg.reels] == [None, 1e6, None, None]
    assert [r.cable_ea_n for r in parse_config(data_with(None), "t.toml").reels] == [None] * 4


@pytest.mark.parametrize(
    ("value", "problem"),
    [
        (0.0, "reels[0].cable_ea_n: must be > 0"),
        (-1e5, "reels[0].cable_ea_n: must be > 0"),
        ("2e5 N", "reels[0].cable_ea_n"),
        (float("inf"), "reels[0].cable_ea_n"),
    ],
)
def test_bad_cable_ea_is_refused_by_name(value: Any, problem: str) -> None:
    d = data_with(None)
    d["reels"][0]["cable_ea_n"] = value
    with pytest.raises(ConfigError, match=problem.replace("[", r"\[").replace("]", r"\]")):
        parse_config(d, "t.toml")


def test_stretch_needs_a_payload() -> None:
    d = data_with(2e5)
    del d["payload"]
    for k in ("min_tension_n", "max_tension_n", "tension_margin_n"):
        del d["limits"][k]
    with pytest.raises(ConfigError, match=r"reels\[3\]\.cable_ea_n: needs \[payload\]"):
        parse_config(d, "t.toml")


def test_tension_source_choice() -> None:
    with pytest.raises(ConfigError, match="stretch_tensions: must be one of planned, measured"):
        parse_config(data_with(2e5, stretch_tensions="guessed"), "t.toml")
    with pytest.raises(ConfigError, match=r"stretch_tensions: .measured. needs loop\.torque"):
        parse_config(data_with(2e5, stretch_tensions="measured"), "t.toml")
    d = data_with(None, stretch_tensions="measured", torque_telemetry="cyclic")
    d["sim"] = {**d["sim"], "plant": "physical"}
    with pytest.raises(ConfigError, match="no reel has cable_ea_n"):
        parse_config(d, "t.toml")
    d = data_with(2e5, stretch_tensions="measured", torque_telemetry="cyclic")
    d["sim"] = {**d["sim"], "plant": "physical"}
    assert parse_config(d, "t.toml").loop.stretch_tensions == "measured"


def test_check_config_shows_the_stretch() -> None:
    lines, _, data = describe(parse_config(data_with(2e5), "t.toml"))
    (line,) = [ln for ln in lines if ln.startswith("stretch")]
    assert "cable EA 200000 N" in line
    # 104.44 N on 47.88 m of EA 2e5 N cable: 25.0 mm at the power-up pose
    assert "25.0 mm at power-up (0, 0, 2)" in line
    assert [p["pose"] for p in data["stretch"]] == ["power-up", "floor", "middle", "top"]
    lines, _, data = describe(parse_config(data_with(None), "t.toml"))
    assert not [ln for ln in lines if ln.startswith("stretch")]
    assert "stretch" not in data


def test_the_shipped_circle_stretch_file_and_its_rigid_twin() -> None:
    """docs/cable-stretch.md flies the circle with config/circle-stretch.toml and with the same
    file without its reels' `cable_ea_n` lines (one grep): the physical plant in both, the
    stretch model in the first only."""
    import tomllib
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "config" / "circle-stretch.toml").read_text()
    stretch = parse_config(tomllib.loads(text), "circle-stretch.toml")
    rigid_text = "".join(
        line.replace("circle-stretch", "circle-rigid")
        for line in text.splitlines(keepends=True)
        if "stretch model" not in line
    )
    rigid = parse_config(tomllib.loads(rigid_text), "circle-rigid.toml")
    for cfg in (stretch, rigid):
        assert cfg.sim.plant == "physical" and cfg.sim.cable_ea_n == 2e5
        assert cfg.payload is not None and cfg.payload.mass_kg == 5.0
    assert [r.cable_ea_n for r in stretch.reels] == [2e5] * 4
    assert [r.cable_ea_n for r in rigid.reels] == [None] * 4
    assert (stretch.zenoh.prefix, rigid.zenoh.prefix) == (
        "cablebot/circle-stretch",
        "cablebot/circle-rigid",
    )
