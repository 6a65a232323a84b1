"""The configuration reference (docs/configuration.md) is the schema's, and the schema is true.

The committed file is exactly what the generator prints; every key the parser accepts (every
table it reads, recorded while it parses) has a row in the reference; and the defaults the
reference shows are the ones the parser applies when a key is absent.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from controller.service.config import (
    SECTIONS,
    ConfigError,
    Key,
    paper_robot_data,
    parse_config,
    tables,
)
from controller.service.config import reference as ref

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "configuration.md"
HEADING = re.compile(r"^## (?:Top level|`\[\[?([a-z0-9_]+)\]\]?`)\s*$")
ROW = re.compile(r"^\| `([A-Za-z0-9_.]+)` \|")


def documented_keys(text: str) -> dict[str, set[str]]:
    """The keys of each section's table in the reference text ("" = the top level)."""
    out: dict[str, set[str]] = {}
    section: str | None = None
    for line in text.splitlines():
        m = HEADING.match(line)
        if m:
            section = m.group(1) or ""
            out.setdefault(section, set())
            continue
        if line.startswith("## "):
            section = None
        row = ROW.match(line)
        if row and section is not None:
            out[section].add(row.group(1))
    return out


def accepted_keys(monkeypatch: pytest.MonkeyPatch, data: dict[str, Any]) -> dict[str, set[str]]:
    """The keys the parser allows in each table while it parses `data` (`_Table.finish`)."""
    seen: dict[str, set[str]] = {}
    original = tables._Table.finish

    def spy(self: tables._Table, allowed: tuple[str, ...]) -> None:
        section = re.sub(r"\[\d+\]$", "", self.path)
        seen.setdefault(section, set()).update(allowed)
        original(self, allowed)

    monkeypatch.setattr(tables._Table, "finish", spy)
    parse_config(data, "<test>")
    return seen


def missing_from(doc: dict[str, set[str]], accepted: dict[str, set[str]]) -> list[str]:
    """Accepted keys without a row in the reference, as `section.key`."""
    missing = []
    for section, keys in accepted.items():
        documented = doc.get(section, set())
        for k in sorted(keys):
            # The top level's sections are documented as headings, not rows.
            if section == "" and k in doc:
                continue
            if k not in documented:
                missing.append(f"{section}.{k}" if section else k)
    return missing


def test_the_committed_reference_is_what_the_generator_prints() -> None:
    assert DOC.read_text(encoding="utf-8") == ref.render(), (
        "docs/configuration.md is out of date: run make docs"
    )
    assert ref.main(["--check"]) == 0


def test_the_check_finds_a_key_missing_from_the_reference(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    text = "\n".join(
        line for line in ref.render().splitlines() if not line.startswith("| `gear_ratio` |")
    )
    accepted = accepted_keys(monkeypatch, paper_robot_data("ref"))
    assert missing_from(documented_keys(text), accepted) == ["reels.gear_ratio"]


def test_the_reference_has_one_row_per_schema_key() -> None:
    doc = documented_keys(ref.render())
    for s in SECTIONS:
        assert {k.name for k in s.keys} <= doc[s.name], s.name


PLAIN_DEFAULTS = [
    (s.name, k) for s in SECTIONS if s.name not in ("", "reels") for k in s.keys if k.shown is None
]


@pytest.mark.parametrize("section,k", PLAIN_DEFAULTS, ids=lambda v: getattr(v, "name", v))
def test_an_absent_key_takes_the_default_the_reference_shows(section: str, k: Key) -> None:
    data = paper_robot_data("ref")
    table = data.get(section, {})
    if "." in k.name:  # a [bus.options] key: python-can's default, documented in words
        pytest.skip("not a key of the section's dataclass")
    table.pop(k.name, None)
    data[section] = table
    cfg = parse_config(data, "<test>")
    assert getattr(getattr(cfg, section), k.name) == k.default


REEL_MODEL_KEYS = [
    k
    for s in SECTIONS
    if s.name == "reels"
    for k in s.keys
    if k.shown is None and k.default is not None
]


@pytest.mark.parametrize("k", REEL_MODEL_KEYS, ids=lambda k: k.name)
def test_an_absent_reel_key_takes_the_default_the_reference_shows(k: Key) -> None:
    data = paper_robot_data("ref")
    data["reels"][0].pop(k.name, None)
    cfg = parse_config(data, "<test>")
    model = cfg.reels[0].reel
    if hasattr(model, k.name):
        assert getattr(model, k.name) == k.default
    else:  # cable_diameter_m / turns_per_layer: no build-up without a cable diameter
        assert model.spool_buildup_m_per_rev2 == 0.0


REQUIRED_LIMITS = [
    k.name for s in SECTIONS if s.name == "limits" for k in s.keys if k.shown == "required"
]


@pytest.mark.parametrize("name", REQUIRED_LIMITS)
def test_a_limit_the_reference_calls_required_is_required(name: str) -> None:
    data = paper_robot_data("ref")
    del data["limits"][name]
    with pytest.raises(ConfigError, match=rf"limits\.{name}: missing \(required\)"):
        parse_config(data, "<test>")
