"""`cablebot check-config` names the drive family and its options."""

from __future__ import annotations

from pathlib import Path

from controller.cli import configs
from controller.service.config import load_config

REPO = Path(__file__).resolve().parents[2]


def test_check_config_names_the_drive_family_and_its_options() -> None:
    lines, _notes, data = configs.describe(load_config(REPO / "config" / "cia402-desk.toml"))
    assert (
        "drive      CiA 402 drives (cia402): counts_per_rev = 131072, velocity_offset = true, "
        "torque = true, heartbeat_period_s = 0.1, sdo_timeout_s = 0.3"
    ) in lines
    assert data["config"]["drive"]["kind"] == "cia402"
    lines, _notes, _data = configs.describe(load_config(None))
    assert "drive      ODrives (odrive)" in lines
    assert any(
        line.startswith("bus        virtual") and line.endswith("simulated ODrives in the daemon")
        for line in lines
    ), lines
    lines, _notes, _data = configs.describe(load_config(REPO / "config" / "cia402-sim.toml"))
    assert any(line.startswith("drive      CiA 402 drives (cia402)") for line in lines)
