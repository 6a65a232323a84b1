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


def test_bus_stats_count_rx_overrun_error_frames_and_send_failures() -> None:
    """One rule each for both drive families: frames the kernel dropped from a full receive
    queue are dropped frames of kind "rx_overrun"; an error frame is a bus error (kind
    "error_frame"), not a dropped frame; a failed send is a bus error named "send <what>:
    <errno name or exception type>: <error>"."""
    s = BusStats()
    s.count_rx_overrun(5)
    assert (s.dropped, s.errors_by_kind) == (5, {"rx_overrun": 5})
    s.count_error_frame(0x40)
    assert (s.dropped, s.bus_errors, s.last_error) == (5, 1, "CAN error frame 0x40")
    assert s.errors_by_kind == {"rx_overrun": 5, "error_frame": 1}
    text = s.count_send_failure("0x202", OSError(105, "No buffer space available"))
    assert text == s.last_error == "send 0x202: ENOBUFS: No buffer space available"
    text = s.count_send_failure("Estop to node 1", ValueError("bad fd"))
    assert text == s.last_error == "send Estop to node 1: ValueError: bad fd"
    assert s.bus_errors == 3 and s.dropped == 5
