"""The exit codes: one table in `controller.cli.exitcodes`, distinct; the documented table is it."""

from __future__ import annotations

from pathlib import Path

import pytest

from controller.cli import exitcodes, main

OPERATING = Path(__file__).resolve().parents[2] / "docs" / "operating.md"


def readme_exit_table() -> list[tuple[int, str]]:
    """The rows of the table under the "Exit codes" heading of docs/operating.md."""
    text = OPERATING.read_text()
    start = text.index("## Exit codes")
    rows: list[tuple[int, str]] = []
    in_table = False
    for line in text[start:].splitlines()[1:]:
        if line.startswith("|"):
            in_table = True
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if cells[0].isdigit():
                rows.append((int(cells[0]), cells[1]))
        elif in_table:
            break
    return rows


def test_readme_table_is_the_code_table() -> None:
    assert readme_exit_table() == list(exitcodes.TABLE)


def test_codes_are_distinct_and_named() -> None:
    codes = [code for code, _ in exitcodes.TABLE]
    assert len(set(codes)) == len(codes)
    named = {
        exitcodes.OK,
        exitcodes.REFUSED,
        exitcodes.USAGE,
        exitcodes.NO_DAEMON,
        exitcodes.WAIT_TIMEOUT,
        exitcodes.INTERRUPTED,
        exitcodes.BROKEN_PIPE,
    }
    assert named == set(codes)


def test_argparse_usage_errors_are_the_usage_code(capsys: pytest.CaptureFixture[str]) -> None:
    for argv in (["move", "1", "2"], ["status", "--bogus"], ["no-such-verb"]):
        with pytest.raises(SystemExit) as info:
            main(argv)
        assert info.value.code == exitcodes.USAGE, argv
    capsys.readouterr()
