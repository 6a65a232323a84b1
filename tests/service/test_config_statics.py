"""Configuration of statics: `[payload]`, tension limits, reel torque limits, and the checks."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

import pytest

from controller.core.statics import CableStatics
from controller.service.config import (
    ConfigError,
    RobotConfig,
    TensionLimits,
    default_config,
    load_config,
    paper_robot_data,
    parse_config,
    tension_problem,
)

REPO = Path(__file__).resolve().parents[2]
PAPER = REPO / "config" / "paper-acre.toml"
DESK = REPO / "config" / "desk.toml"


def base() -> dict[str, Any]:
    return copy.deepcopy(paper_robot_data("t"))


def parse(data: dict[str, Any]) -> RobotConfig:
    return parse_config(data, "robot.toml")


def err(data: dict[str, Any]) -> str:
    with pytest.raises(ConfigError) as info:
        parse(data)
    return str(info.value)


def test_built_in_robot_carries_five_kilograms_within_5_to_500_newtons() -> None:
    cfg = default_config()
    assert cfg.payload is not None and cfg.payload.mass_kg == 5.0
    assert cfg.tension == TensionLimits(5.0, 500.0, 5.0, "limits.max_tension_n")
    # each of the four cables carries m g / (4 u_z) at the power-up pose (0, 0, 2)
    assert cfg.homing.power_up_position_m is not None
    res = CableStatics(cfg.anchors_m, 5.0, 500.0).solve(cfg.homing.power_up_position_m, 5.0)
    assert res.tensions_n == pytest.approx((104.44,) * 4, abs=0.01)
    summary = cfg.summary()
    assert summary["payload"] == {"mass_kg": 5.0}
    assert summary["tension"]["max_source"] == "limits.max_tension_n"
    json.dumps(summary, allow_nan=False)


@pytest.mark.parametrize(
    ("path", "mass", "limits", "pose"),
    [
        (PAPER, 5.0, (5.0, 500.0, 5.0), (0.0, 0.0, 2.0)),
        # the desk has no power-up pose: homing is at the centre mark (its comment)
        (DESK, 0.5, (0.5, 20.0, 0.5), (0.0, 0.0, 0.1)),
    ],
)
def test_shipped_files_hold_their_payload_at_their_start_pose(
    path: Path, mass: float, limits: tuple[float, float, float], pose: tuple[float, float, float]
) -> None:
    cfg = load_config(path)
    assert cfg.payload is not None and cfg.payload.mass_kg == mass
    assert cfg.tension is not None
    assert (cfg.tension.min_n, cfg.tension.max_n, cfg.tension.margin_n) == limits
    assert tension_problem(cfg.geometry, cfg.payload, cfg.tension, pose) is None
    res = CableStatics(cfg.anchors_m, limits[0], limits[1]).solve(pose, mass)
    assert res.margin_n >= limits[2]


def test_without_payload_there_is_no_statics_and_no_tension_key() -> None:
    data = base()
    del data["payload"]
    for k in ("min_tension_n", "max_tension_n", "tension_margin_n"):
        del data["limits"][k]
    cfg = parse(data)
    assert cfg.payload is None and cfg.tension is None
    json.dumps(cfg.summary(), allow_nan=False)
    data["limits"]["max_tension_n"] = 100.0
    data["reels"][1]["max_torque_nm"] = 1.0
    msg = err(data)
    assert "robot.toml: limits.max_tension_n: needs [payload] mass_kg" in msg, msg
    assert "robot.toml: reels[1].max_torque_nm: needs [payload] mass_kg" in msg, msg


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (("payload", "mass_kg", 0.0), "payload.mass_kg: must be > 0, got 0.0"),
        (("payload", "mass_kg", "5 kg"), "payload.mass_kg: must be a number in kilograms"),
        (("payload", "mass", 5.0), "payload.mass: unknown key; did you mean 'mass_kg'?"),
        (("payload", "mass_kg", None), "payload.mass_kg: missing (required)"),
        (("limits", "min_tension_n", None), "limits.min_tension_n: missing (required with"),
        (("limits", "min_tension_n", -1.0), "limits.min_tension_n: must be >= 0"),
        (("limits", "max_tension_n", "5 N"), "limits.max_tension_n: must be a number in newtons"),
        (("limits", "max_tension_n", None), "limits.max_tension_n: missing (required with"),
        (("limits", "tension_margin_n", -0.1), "limits.tension_margin_n: must be >= 0"),
        (("limits", "max_tension", 1.0), "did you mean 'max_tension_n'?"),
        (("reels[0]", "max_torque_nm", 0.0), "reels[0].max_torque_nm: must be > 0"),
        (
            ("reels[0]", "max_torque_nm", "1 Nm"),
            "reels[0].max_torque_nm: must be a number in newton-metres",
        ),
        (
            ("limits", "tension_margin_n", 250.0),
            "limits.min_tension_n: 5 N + tension_margin_n (250 N) leaves no tension range",
        ),
        (
            ("limits", "max_tension_n", 100.0),
            "homing.power_up_position_m: cable 1 tension 104.4 N above 95 N"
            " (limits.max_tension_n 100 N",
        ),
        (
            ("payload", "mass_kg", 50.0),
            "homing.power_up_position_m: cable 1 tension 1044 N above 495 N"
            " (limits.max_tension_n 500 N",
        ),
    ],
)
def test_statics_keys_are_validated(edit: tuple[str, str, Any], expected: str) -> None:
    data = base()
    section, key, value = edit
    table = data["reels"][0] if section == "reels[0]" else data.setdefault(section, {})
    if value is None:
        del table[key]
    else:
        table[key] = value
    msg = err(data)
    assert expected in msg, msg


def test_reel_torque_limit_lowers_the_maximum_and_the_smaller_wins() -> None:
    # 0.05 m per motor turn: 1 N m holds 2 pi / 0.05 = 125.7 N
    data = base()
    data["reels"][2]["max_torque_nm"] = 2.0
    cfg = parse(data)
    assert cfg.tension is not None
    assert cfg.tension.max_n == pytest.approx(2.0 * 2 * math.pi / 0.05)
    assert cfg.tension.max_source == "reels[2].max_torque_nm"
    data["reels"][2]["max_torque_nm"] = 10.0  # 1257 N: the configured 500 N is smaller
    cfg = parse(data)
    assert cfg.tension is not None
    assert (cfg.tension.max_n, cfg.tension.max_source) == (500.0, "limits.max_tension_n")
    # every reel limited: max_tension_n may be left out
    del data["limits"]["max_tension_n"]
    assert "limits.max_tension_n: missing" in err(data)
    for r in data["reels"]:
        r["max_torque_nm"] = 3.0
    cfg = parse(data)
    assert cfg.tension is not None
    assert cfg.tension.max_n == pytest.approx(3.0 * 2 * math.pi / 0.05)
    assert cfg.tension.max_source == "reels[0].max_torque_nm"
    assert cfg.reels[3].max_torque_nm == 3.0
