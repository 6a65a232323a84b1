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


@pytest.mark.parametrize("level", ["info", "WARNING"])
def test_third_party_info_lines_are_held_back_unless_debug_is_asked(
    level: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # canopen logs every SDO at INFO (172 lines at a CiA 402 start-up): they must not bury
    # cablebot's own lines; its warnings still show.
    root = logging.getLogger()
    saved = root.handlers[:], root.level
    monkeypatch.delenv("JOURNAL_STREAM", raising=False)
    try:
        setup_logging(level)
        logging.getLogger("canopen.sdo.client").info("sdo upload 0x6041")
        logging.getLogger("canopen.sdo.client").warning("sdo timeout node 3")
        logging.getLogger("cablebot.daemon").warning("own warning")
        logging.getLogger("cablebot.daemon").info("own info")
        logging.getLogger("controller.service.zenoh_io").info("zenoh info")
        err = capsys.readouterr().err
        assert "sdo upload" not in err
        assert "sdo timeout node 3" in err and "own warning" in err
        assert ("own info" in err) == (level == "info")
        assert ("zenoh info" in err) == (level == "info")
        # Asked for: --log-level DEBUG shows everything.
        setup_logging("DEBUG")
        logging.getLogger("canopen.sdo.client").info("sdo upload 0x6041")
        logging.getLogger("canopen.sdo.client").debug("sdo bytes")
        err = capsys.readouterr().err
        assert "sdo upload 0x6041" in err and "sdo bytes" in err
    finally:
        root.handlers[:], lvl = saved
        root.setLevel(lvl)
