"""A client verb's threads that call Zenoh are never daemon threads, whichever thread starts
them: Zenoh runs a callback on a Python thread started by the declaring thread, and a daemon
thread inside Zenoh's native code at exit aborts the process (test_record.py shows it end to
end)."""

from __future__ import annotations

import threading

from controller.cli.zenoh_threads import start_zenoh_thread


def test_a_zenoh_thread_started_from_a_daemon_thread_is_not_a_daemon() -> None:
    seen: dict[str, bool] = {}
    done = threading.Event()

    def inner() -> None:
        seen["inner_daemon"] = threading.current_thread().daemon
        done.set()

    def outer() -> None:
        seen["outer_daemon"] = threading.current_thread().daemon
        start_zenoh_thread(inner, name="zenoh-child").join(10.0)

    t = threading.Thread(target=outer, daemon=True)
    t.start()
    t.join(10.0)
    assert done.is_set()
    assert seen == {"outer_daemon": True, "inner_daemon": False}


def test_the_thread_runs_its_target_with_its_arguments_and_name() -> None:
    got: list[tuple[str, int, str]] = []
    t = start_zenoh_thread(
        lambda a, b: got.append((a, b, threading.current_thread().name)), "x", 2, name="poller"
    )
    t.join(10.0)
    assert got == [("x", 2, "poller")] and not t.daemon
