"""The example files the README points at load and fit the robot they are written for."""

from __future__ import annotations

from pathlib import Path

from controller.cli.client import load_path_file
from controller.core.workspace import Workspace
from controller.service.config import default_config

ROOT = Path(__file__).resolve().parents[2]


def test_square_path_example_loads_and_fits_the_built_in_robot() -> None:
    payload = load_path_file(str(ROOT / "config" / "square-path.csv"))
    points = payload["points_m"]
    assert len(points) == 5 and points[-1] == [0.0, 0.0, 2.0]
    cfg = default_config()
    limits = Workspace.from_limits(cfg.limits, cfg.geometry)
    start = (0.0, 0.0, 2.0)
    assert limits.check_path([tuple(p) for p in points], start_m=start) is None


def test_readme_names_the_example_path_file() -> None:
    assert "cablebot path config/square-path.csv" in (ROOT / "README.md").read_text()
