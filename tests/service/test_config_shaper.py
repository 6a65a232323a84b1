"""`[shaper]` and the simulator's damping keys: defaults where the modes are known, named errors
(with a did-you-mean) for a type, a frequency, a damping ratio or a scale out of range."""

from __future__ import annotations

from typing import Any

import pytest

from controller.service.config import ConfigError, paper_robot_data, parse_config


def data(
    shaper: dict[str, Any] | None = None, ea: float | None = None, **sim: Any
) -> dict[str, Any]:
    d = paper_robot_data("t")
    if ea is not None:
        for r in d["reels"]:
            r["cable_ea_n"] = ea
    if shaper is not None:
        d["shaper"] = shaper
    if sim:
        d["sim"] = {**d["sim"], **sim}
    return d


def test_the_default_shapes_where_the_modes_are_known() -> None:
    assert parse_config(data(), "t").shaper.type == "off"  # rigid cables: no model
    sc = parse_config(data(ea=4.5e5), "t").shaper
    assert (sc.type, sc.damping_ratio, sc.frequency_hz, sc.frequency_scale) == (
        "2hump_ei",
        0.02,
        None,
        1.0,
    )
    sc = parse_config(data({"frequency_hz": 3.5}), "t").shaper
    assert (sc.type, sc.frequency_hz) == ("2hump_ei", 3.5)
    sc = parse_config(data({"type": "off"}, ea=4.5e5), "t").shaper
    assert not sc.enabled
    sc = parse_config(
        data({"type": "zvd", "damping_ratio": 0.05, "frequency_scale": 0.9}, ea=4.5e5), "t"
    ).shaper
    assert (sc.type, sc.damping_ratio, sc.frequency_scale) == ("zvd", 0.05, 0.9)
    assert sc.passes == 1
    assert parse_config(data({"passes": 2}, ea=4.5e5), "t").shaper.passes == 2


@pytest.mark.parametrize(
    ("shaper", "ea", "message"),
    [
        (
            {"type": "2hump-ei"},
            4.5e5,
            r"shaper.type: unknown shaper type '2hump-ei' \(did you mean '2hump_ei'\?\)",
        ),
        ({"type": "EI"}, 4.5e5, r"shaper.type: unknown shaper type 'EI' \(did you mean 'ei'\?\)"),
        ({"type": "ei"}, None, r"shaper.type: 'ei' needs the modes: give shaper.frequency_hz"),
        ({"frequency_hz": 0.0}, None, r"shaper.frequency_hz: must be >= 0.05, got 0.0"),
        ({"frequency_hz": 5000}, None, r"shaper.frequency_hz: must be <= 1000"),
        ({"damping_ratio": 0.5}, 4.5e5, r"shaper.damping_ratio: must be <= 0.3"),
        ({"damping_ratio": -0.1}, 4.5e5, r"shaper.damping_ratio: must be >= 0"),
        ({"frequency_scale": 10}, 4.5e5, r"shaper.frequency_scale: must be <= 5"),
        ({"frequncy_hz": 3.0}, 4.5e5, r"shaper.frequncy_hz.*frequency_hz"),
        ({"passes": 0}, 4.5e5, r"shaper.passes: must be >= 1, got 0"),
        ({"passes": 4}, 4.5e5, r"shaper.passes: must be <= 3, got 4"),
        ({"passes": 1.5}, 4.5e5, r"shaper.passes: must be an integer, got 1.5"),
        ({"passes": "2"}, 4.5e5, r"shaper.passes: must be an integer, got '2'"),
    ],
)
def test_bad_shapers_are_named_errors(
    shaper: dict[str, Any], ea: float | None, message: str
) -> None:
    with pytest.raises(ConfigError, match=message):
        parse_config(data(shaper, ea=ea), "t.toml")


def test_the_simulators_damping_keys() -> None:
    cfg = parse_config(data(), "t")
    assert cfg.sim.cable_damping_ratio == 0.02 and cfg.sim.effector_damping_n_s_per_m is None
    cfg = parse_config(data(cable_damping_ratio=1.0, effector_damping_n_s_per_m=3.0), "t")
    assert cfg.sim.cable_damping_ratio == 1.0 and cfg.sim.effector_damping_n_s_per_m == 3.0
    with pytest.raises(ConfigError, match=r"sim.cable_damping_ratio: must be <= 1"):
        parse_config(data(cable_damping_ratio=2.0), "t")
    with pytest.raises(ConfigError, match=r"sim.effector_damping_n_s_per_m: must be >= 0"):
        parse_config(data(effector_damping_n_s_per_m=-1.0), "t")
