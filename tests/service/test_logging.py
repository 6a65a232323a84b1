"""The daemon's log lines: under journald each carries its syslog priority."""

from __future__ import annotations

import logging

import pytest

from controller.service.daemon import JournalFormatter, setup_logging


def _record(level: int, msg: str) -> logging.LogRecord:
    return logging.LogRecord("cablebot.loop", level, __file__, 1, msg, None, None)


def test_journal_lines_carry_the_syslog_priority() -> None:
    f = JournalFormatter()
    assert f.format(_record(logging.ERROR, "state MOVING -> FAULT: slack")) == (
        "<3>ERROR cablebot.loop: state MOVING -> FAULT: slack"
    )
    assert f.format(_record(logging.WARNING, "w")).startswith("<4>WARNING")
    assert f.format(_record(logging.INFO, "i")).startswith("<6>INFO")
    assert f.format(_record(logging.DEBUG, "d")).startswith("<7>DEBUG")
    # every line of a multi-line message keeps the priority (journald splits on newlines)
    assert f.format(_record(logging.ERROR, "a\nb")) == "<3>ERROR cablebot.loop: a\n<3>b"


def test_setup_logging_picks_the_journal_format_under_journald(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    root = logging.getLogger()
    saved = root.handlers[:], root.level
    try:
        monkeypatch.setenv("JOURNAL_STREAM", "8:12345")
        setup_logging("info")
        assert isinstance(root.handlers[0].formatter, JournalFormatter)
        monkeypatch.delenv("JOURNAL_STREAM")
        setup_logging("info")
        assert not isinstance(root.handlers[0].formatter, JournalFormatter)
        assert "%(asctime)s" in str(root.handlers[0].formatter._fmt)
    finally:
        root.handlers[:], level = saved
        root.setLevel(level)
