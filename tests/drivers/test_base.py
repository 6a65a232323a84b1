"""The driver contract's counters: one way to count what a receive path does not take."""

from __future__ import annotations

from drivers.base import BusStats


def test_bus_stats_count_by_kind() -> None:
    s = BusStats()
    s.count("length", decode_error=True)
    s.count("unknown_node")
    s.count("unknown_node")
    s.count("not_for_host")  # host traffic heard: neither lost nor broken
    s.count_bus_error("tx buffer full")
    assert (s.decode_errors, s.dropped, s.commands_heard) == (1, 2, 1)
    assert s.errors_by_kind == {"length": 1, "unknown_node": 2, "not_for_host": 1}
    assert (s.bus_errors, s.last_error) == (1, "tx buffer full")
    copy = s.snapshot()
    s.count("length", decode_error=True)
    assert copy.errors_by_kind["length"] == 1 and copy.decode_errors == 1
