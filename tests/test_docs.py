"""The documents describe the tree as it is, and the product speaks of itself.

Every repository path the README, CONTRIBUTING.md and docs/*.md name in backticks exists, and no
product file (code, configs, docs) talks about how the product was made (issue numbers, process
words, machine paths).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *sorted((ROOT / "docs").glob("*.md"))]
TOP = ("controller/", "drivers/", "config/", "docs/", "tests/", "tools/", ".ci/")
PATH = re.compile(r"`([A-Za-z0-9_.@/-]+)`")
PROCESS = re.compile(r"\bissue[ -]?#?\d+|\bissue's\b|agreed API|\bthe lead\b|/work/", re.I)


def named_paths(text: str) -> set[str]:
    """Repository paths written in backticks (the first word of each code span)."""
    found = set()
    for span in PATH.findall(text):
        if span.startswith(TOP) and "*" not in span and "<" not in span:
            found.add(span.rstrip("/"))
    return found


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_every_path_a_document_names_exists(doc: Path) -> None:
    missing = sorted(p for p in named_paths(doc.read_text()) if not (ROOT / p).exists())
    assert not missing, f"{doc.name} names paths that do not exist: {missing}"


def test_the_layout_table_names_every_package() -> None:
    readme = named_paths((ROOT / "README.md").read_text())
    for package in ("controller/core", "controller/service", "controller/cli", "drivers"):
        assert any(p == package or p.startswith(package + "/") for p in readme), package


def product_files() -> list[Path]:
    """Code, configs and documents that ship or describe the product (not the tests)."""
    files = [
        ROOT / "README.md",
        ROOT / "CONTRIBUTING.md",
        ROOT / "Makefile",
        ROOT / "pyproject.toml",
    ]
    for folder in ("controller", "drivers", "config", "docs", "tools", ".ci"):
        files += [p for p in (ROOT / folder).rglob("*") if p.is_file() and p.suffix != ".png"]
    return [p for p in files if "__pycache__" not in p.parts]


def test_no_product_file_speaks_of_how_it_was_made() -> None:
    hits = []
    for path in product_files():
        for n, line in enumerate(path.read_text(errors="replace").splitlines(), start=1):
            if PROCESS.search(line):
                hits.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert not hits, "\n".join(hits)
