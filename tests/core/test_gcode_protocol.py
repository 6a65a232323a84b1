"""The RepRap serial line protocol: numbering, checksums, resends, answers."""

from __future__ import annotations

from controller.core.gcode import numbered
from controller.core.gcode_protocol import LineProtocol


def test_numbered_lines_in_order_are_run_and_acknowledged() -> None:
    p = LineProtocol()
    assert p.receive(numbered(-1, "M110")).line is None  # restart the numbering at 0
    r = p.receive(numbered(0, "G1 X10 F600"))
    assert r.ok and r.replies == () and r.line is not None
    assert r.line.commands[0].params["X"] == 10.0
    assert p.receive(numbered(1, "G1 X20")).line is not None
    assert p.last_number == 1


def test_bad_checksum_asks_for_the_same_line_again() -> None:
    p = LineProtocol()
    p.receive(numbered(-1, "M110"))
    p.receive(numbered(0, "G1 X1 F600"))
    good = numbered(1, "G1 X2")
    body, cs = good.rsplit("*", 1)
    r = p.receive(f"{body}*{(int(cs) + 1) % 256}")
    assert r.line is None and r.ok
    assert r.replies == ("Error:checksum mismatch, Last Line: 0", "Resend: 1")
    assert p.receive(good).line is not None
    assert p.resends == 1


def test_a_skipped_line_number_asks_for_the_missing_one() -> None:
    p = LineProtocol()
    p.receive(numbered(-1, "M110"))
    p.receive(numbered(0, "G1 X1 F600"))
    r = p.receive(numbered(2, "G1 X3"))
    assert r.line is None and r.replies[-1] == "Resend: 1"
    assert "Line Number is not Last Line Number+1" in r.replies[0]


def test_a_number_without_checksum_is_resent() -> None:
    p = LineProtocol()
    r = p.receive("N1 G1 X1")
    assert r.replies[-1] == "Resend: 1" and "No Checksum" in r.replies[0]


def test_m110_with_n_sets_the_number() -> None:
    p = LineProtocol()
    p.receive("M110 N41")
    assert p.receive(numbered(42, "G1 X1 F600")).line is not None


def test_m105_and_m115_answers() -> None:
    p = LineProtocol()
    r = p.receive("M105")
    assert r.replies == ("ok T:0.0 /0.0",) and not r.ok
    r = p.receive(numbered(1, "M115"))
    assert r.ok and r.replies[0].startswith("FIRMWARE_NAME:cablebot PROTOCOL_VERSION:1.0")


def test_unnumbered_lines_and_junk() -> None:
    p = LineProtocol()
    r = p.receive("G1 X1 F600 ; typed")
    assert r.line is not None and r.ok
    r = p.receive("G1 X=3")
    assert r.line is None and r.ok and r.replies[0].startswith("Error:")
    assert p.receive("").line is None
