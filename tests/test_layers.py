"""The layers' import rule: core is pure, the service does not use the client library or the
tools, the client library does not use the tools (nor argparse), drivers stand alone.

Read from the source with `ast` (every import, including those inside functions), so a lazy
import cannot slip past.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

FORBIDDEN = {
    "controller/core": (
        "controller.service",
        "controller.client",
        "controller.cli",
        "drivers",
        "can",
        "zenoh",
        "threading",
        "socket",
        "subprocess",
    ),
    "controller/service": ("controller.client", "controller.cli"),
    "controller/client": ("controller.cli", "argparse"),
    "drivers": ("controller",),
}


def imports(path: Path) -> set[str]:
    """Every module name a file imports (absolute names; relative imports are not used)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_imports_point_down(layer: str) -> None:
    bad = []
    for path in sorted((ROOT / layer).rglob("*.py")):
        for name in imports(path):
            if any(name == f or name.startswith(f + ".") for f in FORBIDDEN[layer]):
                bad.append(f"{path.relative_to(ROOT)} imports {name}")
    assert not bad, "\n".join(bad)


def test_the_rule_sees_a_forbidden_import(tmp_path: Path) -> None:
    probe = tmp_path / "probe.py"
    probe.write_text("def f():\n    from controller.service import loop\n")
    assert "controller.service" in imports(probe)
