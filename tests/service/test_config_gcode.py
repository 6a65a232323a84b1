"""The `[gcode]` table: defaults, values and the errors that name its keys."""

from __future__ import annotations

import pytest

from controller.service.config import ConfigError, GcodeConfig, paper_robot_data, parse_config


def _parse(table: dict[str, object] | None) -> GcodeConfig:
    data = paper_robot_data("t")
    if table is not None:
        data["gcode"] = table
    return parse_config(data, "robot.toml").gcode


def test_defaults_without_the_table() -> None:
    g = _parse(None)
    assert g == GcodeConfig()
    assert g.origin_m == (0.0, 0.0, 0.0) and g.units == "mm" and g.home_m is None
    assert g.arc_tolerance_m == 0.0001 and g.rapid_speed_mps is None and g.dialect == "marlin"


def test_values() -> None:
    g = _parse(
        {
            "origin_m": [1, -2, 0.5],
            "units": "inch",
            "home_m": [0, 0, 2],
            "arc_tolerance_m": 1e-5,
            "rapid_speed_mps": 1.5,
            "dialect": "reprapfirmware",
        }
    )
    assert g == GcodeConfig((1.0, -2.0, 0.5), "inch", (0.0, 0.0, 2.0), 1e-5, 1.5, "reprapfirmware")


@pytest.mark.parametrize(
    ("table", "expected"),
    [
        ({"units": "cm"}, "gcode.units: must be one of mm, inch, got 'cm'"),
        ({"dialect": "grbl"}, "gcode.dialect: must be one of marlin, reprapfirmware"),
        ({"arc_tolerance_m": 0.0}, "gcode.arc_tolerance_m: must be > 0"),
        ({"rapid_speed_mps": 3.0}, "gcode.rapid_speed_mps: 3 m/s exceeds limits.max_speed_mps"),
        ({"origin_m": [0, 0]}, "gcode.origin_m: must be [x, y, z]"),
        ({"orign_m": [0, 0, 0]}, "gcode.orign_m"),
    ],
)
def test_errors_name_the_key(table: dict[str, object], expected: str) -> None:
    with pytest.raises(ConfigError) as info:
        _parse(table)
    assert expected in str(info.value)
