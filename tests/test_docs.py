"""The documents describe the tree as it is, and the product speaks of itself.

Every repository path the README, CONTRIBUTING.md and docs/*.md name in backticks exists, every
relative link among them resolves (the file, and the heading of a `#anchor`), every `cablebot`
command their shell blocks show parses with the real argument parser, every configuration key
is in the configuration reference, and no product file (code, configs, docs) talks about how
the product was made (issue numbers, process words, machine paths).
"""

from __future__ import annotations

import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

from controller.cli import build_parser
from controller.service.config import paper_robot_data
from drivers import registry
from tests.service.test_config_reference import accepted_keys, documented_keys, missing_from

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


# ------------------------------------------------------------------------------ links
LINK = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(([^()\s]+)(?:\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^\s*(```|~~~)")


def prose_lines(text: str) -> list[str]:
    """The lines of a Markdown text outside fenced code blocks, code spans blanked."""
    out, fenced = [], False
    for line in text.splitlines():
        if FENCE.match(line):
            fenced = not fenced
            out.append("")
            continue
        out.append("" if fenced else re.sub(r"`[^`]*`", "``", line))
    return out


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: links reduced to their text, lower case, punctuation but
    `-` and `_` dropped, spaces to hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading).strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Every heading anchor of a Markdown file (a repeated heading gets -1, -2, ...)."""
    found: set[str] = set()
    fenced = False
    for line in path.read_text().splitlines():
        if FENCE.match(line):
            fenced = not fenced
        m = None if fenced else re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if m:
            base, n = slug(m.group(1)), 0
            name = base
            while name in found:
                n += 1
                name = f"{base}-{n}"
            found.add(name)
    return found


def broken_links(doc: Path, text: str) -> list[str]:
    """The relative links of `text` (a document at `doc`) whose file or heading is missing."""
    broken = []
    for target in LINK.findall("\n".join(prose_lines(text))):  # link texts may wrap lines
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # https:, mailto:, ...
            continue
        path_part, _, anchor = target.partition("#")
        path = doc if not path_part else (doc.parent / path_part).resolve()
        if not path.exists():
            broken.append(f"{target}: no such file")
        elif anchor and (path.suffix != ".md" or anchor not in anchors(path)):
            broken.append(f"{target}: no heading #{anchor} in {path.name}")
    return broken


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_every_relative_link_resolves(doc: Path) -> None:
    broken = broken_links(doc, doc.read_text())
    assert not broken, f"{doc.name}: " + "; ".join(broken)


def test_the_link_check_finds_a_missing_file_and_a_missing_heading() -> None:
    doc = ROOT / "README.md"
    text = (
        "[ok](docs/operating.md#exit-codes) [gone](docs/nothing.md) "
        "[bad](docs/operating.md#no-such-heading) [wrapped\ntext](docs/gone.md)\n"
        "`[code](docs/nothing.md)`\n"
        "```\n[fenced](docs/nothing.md)\n```\n![pic](docs/img/circle-3d.png)"
    )
    assert broken_links(doc, text) == [
        "docs/nothing.md: no such file",
        "docs/operating.md#no-such-heading: no heading #no-such-heading in operating.md",
        "docs/gone.md: no such file",
    ]


def test_slugs_are_githubs() -> None:
    assert slug("Flying it: velocity input and jog") == "flying-it-velocity-input-and-jog"
    assert slug("CiA 402 drives (CANopen)") == "cia-402-drives-canopen"
    assert slug("`[[reels]]`") == "reels"
    assert slug("udp_multicast stays on this host") == "udp_multicast-stays-on-this-host"


# ------------------------------------------------------------------------------ commands
SHELL_FENCES = {"", "sh", "bash", "shell", "console"}
OPERATORS = {";", "&&", "||", "|", "&", ">", ">>", "<", "2>", "2>&1"}


def shown_commands(text: str) -> list[list[str]]:
    """Every `cablebot ...` command in the shell code blocks of a Markdown text, as its
    arguments (after `cablebot`), a prompt `$ ` and comments removed, one per command of a
    `;`/`&&`/`|`/`&` list; a line that is output (`cablebot: ...`, `cablebot jog: ...`) is not
    a command."""
    commands: list[list[str]] = []
    lang: str | None = None
    for line in text.splitlines():
        m = FENCE.match(line)
        if m:
            lang = None if lang is not None else line.strip()[3:].strip().lower()
            continue
        if lang not in SHELL_FENCES:
            continue
        shown = line.strip().removeprefix("$ ")
        if not shown.startswith("cablebot "):
            continue
        lexer = shlex.shlex(shown, posix=True, punctuation_chars=True)
        lexer.whitespace_split = True
        lexer.commenters = "#"
        words: list[str] = []
        for token in [*lexer, ";"]:
            if token in OPERATORS or set(token) <= set("();<>|&"):
                if len(words) > 1 and words[0] == "cablebot" and not words[1].endswith(":"):
                    commands.append(words[1:])
                words = []
                if token not in (";", "&&", "||", "|", "&"):
                    words = ["redirect"]  # the rest of the command is a redirection
            elif words != ["redirect"]:
                words.append(token)
    return commands


def parse_problem(argv: list[str]) -> str | None:
    """Why the real `cablebot` argument parser refuses `argv` (parse only), or None."""
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            build_parser().parse_args(argv)
    except SystemExit as exc:
        return f"exit {exc.code}: {err.getvalue().strip().splitlines()[-1:]}"
    return None


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_every_command_shown_parses(doc: Path) -> None:
    problems = []
    for argv in shown_commands(doc.read_text()):
        problem = parse_problem(argv)
        if problem is not None:
            problems.append(f"cablebot {shlex.join(argv)}: {problem}")
    assert not problems, f"{doc.name}:\n" + "\n".join(problems)


def test_the_docs_show_commands_and_the_check_finds_a_bad_one() -> None:
    shown = [a for doc in DOCS for a in shown_commands(doc.read_text())]
    assert len(shown) > 50 and ["pose", "--count", "3"] in shown
    text = (
        "```sh\n$ cablebot move 1 2 --wait   # one coordinate short\n"
        "cablebot estop ; cablebot reset && cablebot pose | head\n```\n"
        "```text\ncablebot: refused: ...\n```\n```\ncablebot jog: arrows/WASD\n```"
    )
    assert shown_commands(text) == [["move", "1", "2", "--wait"], ["estop"], ["reset"], ["pose"]]
    assert parse_problem(["move", "1", "2", "--wait"]) is not None
    assert parse_problem(["move", "1", "2", "3", "--wait"]) is None


# ------------------------------------------------------------------------------ config keys
def test_every_config_key_is_documented(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every key the configuration parser accepts (recorded while it parses the built-in
    robot) and every `[drive]` option of every family has a row in docs/configuration.md."""
    doc = documented_keys((ROOT / "docs" / "configuration.md").read_text())
    accepted = accepted_keys(monkeypatch, paper_robot_data("docs"))
    assert set(accepted) >= {"", "bus", "loop", "limits", "payload", "faults", "homing"}
    assert set(accepted) >= {"zenoh", "sim", "reels"}
    assert missing_from(doc, accepted) == []
    for family in registry.FAMILIES.values():
        for option in family.options:
            assert option.name in doc["drive"], f"[drive] {option.name} ({family.name})"
    assert "kind" in doc["drive"]
