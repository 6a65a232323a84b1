"""Every package of the product ships: a `pip install` of cablebot has the client library (and
every other package the tree holds), since the wheel's package list is written out by hand."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_every_package_of_the_tree_is_in_the_wheel() -> None:
    listed = set(
        tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    found = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for top in ("controller", "drivers")
        for p in (ROOT / top).rglob("__init__.py")
        if "__pycache__" not in p.parts
    }
    assert "controller.client" in found
    assert found <= listed, sorted(found - listed)


def test_the_library_imports_without_zenoh_or_the_configuration() -> None:
    """Importing the library stays cheap: Zenoh, numpy and the robot configuration load when a
    session opens or a description is read, not at import (checked in a fresh interpreter)."""
    import subprocess
    import sys

    code = (
        "import sys, controller.client, controller.client.aio, controller.client.job\n"
        "heavy = [m for m in ('zenoh', 'controller.service.config', 'scipy') if m in sys.modules]\n"
        "print(heavy)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr
