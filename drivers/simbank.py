"""The serving thread of a bank of simulated drives, shared by every drive family.

A family's bank (`drivers.odrive.sim.SimODriveBank`, `drivers.cia402.sim.SimCiA402Bank`) says
what one serving run is (`_serve`: answer frames and step the nodes until the stop event is
set); this class starts it once in a daemon thread, stops and joins it, and makes the bank a
context manager. The bank does not own the bus: the caller shuts it down after `stop()`.
Only the standard library is imported here.
"""

from __future__ import annotations

import threading
from types import TracebackType
from typing import Self


class ThreadedSimBank:
    """Start-once, stop-and-join lifecycle of a simulated bank's serving thread."""

    thread_name = "sim"
    """The serving thread's name (shown by ps, py-spy, the daemon's log)."""

    def __init__(self) -> None:
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _serve(self, stop: threading.Event) -> None:
        """Serve the nodes until `stop` is set (the family's run loop)."""
        raise NotImplementedError

    @property
    def started(self) -> bool:
        """True once `start` has run."""
        return self._thread is not None

    def start(self) -> Self:
        """Start the serving thread (once). Returns self. Raises RuntimeError if started."""
        if self._thread is not None:
            raise RuntimeError(f"{type(self).__name__} already started")
        self._thread = threading.Thread(
            target=self._serve, args=(self._stop,), name=self.thread_name, daemon=True
        )
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 2.0) -> bool:
        """Stop the thread and join it within `timeout_s`; return True if it has ended."""
        self._stop.set()
        if self._thread is None:
            return True
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    @property
    def thread(self) -> threading.Thread | None:
        """The serving thread once started, else None."""
        return self._thread

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()
