"""Ending a program by signal as Ctrl-C ends it, so motion it follows brakes to a hold.

Python turns Ctrl-C (SIGINT) into KeyboardInterrupt, which the client library answers by
braking; SIGTERM (`kill`, a service manager) and SIGHUP (the terminal closed) end the process
without it. Within `signals_interrupt()` they raise KeyboardInterrupt too.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

WAIT_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name)
)
"""Signals that, while motion is followed, count as Ctrl-C (the terminal closed, `kill`)."""


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


@contextmanager
def signals_interrupt(enabled: bool = True) -> Iterator[None]:
    """Within the block SIGTERM and SIGHUP raise KeyboardInterrupt (as Ctrl-C does), so a
    followed motion is stopped however the program is ended; the previous handlers come back
    after. A no-op when not `enabled` or off the main thread (only it may set handlers).
    Raises nothing itself."""
    if not enabled or threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {sig: signal.signal(sig, _raise_interrupt) for sig in WAIT_SIGNALS}
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
