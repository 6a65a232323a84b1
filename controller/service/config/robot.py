"""The built-in robot: the paper's 80.9 m x 50 m x 7.62 m acre robot on four simulated reels."""

from __future__ import annotations

from typing import Any

from controller.service.config.parse import parse_config
from controller.service.config.schema import RobotConfig

PAPER_LENGTH_M = 80.9
PAPER_WIDTH_M = 50.0
PAPER_HEIGHT_M = 7.62


def paper_robot_data(name: str = "default") -> dict[str, Any]:
    """The paper robot as a TOML-shaped mapping (reels B1..B4, node ids 0..3, simulated).

    Reels: 0.5 m of cable per drum turn (80 mm drum radius) behind a 10:1 gearbox, i.e.
    0.05 m per motor turn; the 99 m cable range (1..100 m) is 1980 motor turns, where one
    float32 ULP is 2^-13 turn = 6.1 micrometres of cable (limit 0.1 mm). The gearing cancels
    out: the worst resolution is about range * 2^-23 (12 um for 99 m), so only cable ranges
    beyond ~800 m fail the check. Raises nothing.
    """
    hl, hw, h = PAPER_LENGTH_M / 2.0, PAPER_WIDTH_M / 2.0, PAPER_HEIGHT_M
    anchors = [(-hl, -hw, h), (-hl, hw, h), (hl, hw, h), (hl, -hw, h)]
    return {
        "name": name,
        "bus": {"interface": "virtual", "channel": f"cablebot-{name}"},
        "loop": {"rate_hz": 500.0},
        "limits": {
            "xy_margin_m": 2.0,
            "floor_z_m": 0.0,
            "top_margin_m": 1.0,
            "min_cable_m": 1.0,
            "max_cable_m": 100.0,
            "max_cable_speed_mps": 3.0,
            "max_speed_mps": 2.0,
            "max_accel_mps2": 1.0,
            "default_speed_mps": 1.0,
            "min_tension_n": 5.0,
            "max_tension_n": 500.0,
            "tension_margin_n": 5.0,
        },
        "payload": {"mass_kg": 5.0},
        # Its simulated drives share the CPU with everything else on the machine (a desktop, a
        # laptop running a build): a reading may wait a few hundred ms for a busy scheduler, and
        # a starved simulated reel lags its set-point. A real rig keeps the 50 ms / 0.5 s
        # defaults and a tracking limit near 0.25 m; the simulated robot must not fault on load.
        "faults": {
            "stale_timeout_s": 0.5,
            "heartbeat_timeout_s": 1.0,
            "residual_max_m": 0.02,
            "tracking_max_m": 1.0,
            "arm_timeout_s": 2.0,
            "bus_error_timeout_s": 0.05,
        },
        "homing": {"power_up_position_m": [0.0, 0.0, 2.0]},
        # The simulated drives' axis watchdog (idle when no command came for this long) gets the
        # same allowance for a busy machine as the staleness windows above.
        "sim": {"enabled": True, "watchdog_timeout_s": 1.0},
        "reels": [
            {
                "node_id": i,
                "anchor_m": list(a),
                "metres_per_rev": 0.5,
                "gear_ratio": 10.0,
            }
            for i, a in enumerate(anchors)
        ],
    }


def default_config() -> RobotConfig:
    """The built-in robot: the paper's acre robot on 4 simulated reels on a `virtual` bus.

    Name "default" (Zenoh prefix cablebot/default), power-up pose (0, 0, 2) m, no state file.
    Raises nothing (the data is valid by construction; a test checks it).
    """
    return parse_config(paper_robot_data("default"), "<built-in default>")
