"""The log lines of refused and discarded streamed set-points, written off the loop thread.

The control step refuses a streamed set-point (outside the workspace, the cable or tension
limits, from before the last `arm`) with a counter and the last reason only
(`stream_refused`, `stream_last_refusal`); a set-point the state takes none of is discarded
by the Zenoh thread the same way (`stream_discarded`, `stream_last_discard`). `StreamLog`
reads those counters from the daemon's main thread and logs what changed, at most one line
per kind every `period_s`, with how many there were since the last line. Raises nothing.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

log = logging.getLogger("cablebot.stream")

LOG_EVERY_S = 1.0
"""At most one line per kind (refused, discarded) this often, however fast they come."""


class StreamLog:
    """Logs the streamed set-points a controller refused or discarded since the last look."""

    def __init__(
        self,
        controller: Any,
        *,
        period_s: float = LOG_EVERY_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.controller = controller
        self._period_s = period_s
        self._clock = clock
        self._refused = int(controller.stream_refused)
        self._discarded = int(controller.stream_discarded)
        self._next_refused = -float("inf")
        self._next_discarded = -float("inf")

    def step(self) -> None:
        """Log what is new and due (WARNING). Call it often; it costs two reads when idle."""
        ctl = self.controller
        refused = int(ctl.stream_refused)
        if refused != self._refused:
            now = self._clock()
            if now >= self._next_refused:
                self._next_refused = now + self._period_s
                log.warning(
                    "streamed set-point refused: %s%s",
                    ctl.stream_last_refusal,
                    _count(refused - self._refused),
                )
                self._refused = refused
        discarded = int(ctl.stream_discarded)
        if discarded != self._discarded:
            now = self._clock()
            if now >= self._next_discarded:
                self._next_discarded = now + self._period_s
                log.warning(
                    "streamed set-point discarded: %s%s",
                    getattr(ctl, "stream_last_discard", None) or "the state takes none",
                    _count(discarded - self._discarded),
                )
                self._discarded = discarded


def _count(n: int) -> str:
    return "" if n <= 1 else f" (the latest of {n} since the last line)"
