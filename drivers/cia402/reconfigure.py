"""Configuring CiA 402 drives beside the control loop: a drive that restarted (NMT boot-up) has
lost its PDO set-up and mode, and `CiA402Reels.arm` sets it up again by SDO. Those exchanges
take up to about 36 SDO answers per drive, each waited for up to the SDO timeout: done on the
loop's thread they would stop its SYNC, and every other drive's set-points, for seconds.

`ConfigJob` runs `sdo_config.configure_node` for some drives on a worker thread. The loop's
thread stays the bus's only reader: its `poll` hands the drives' SDO answers to canopen, whose
SDO client (waiting on the worker) takes them from its queue, and sends each cycle as before
(a drive being configured is left out of the cycle). The worker touches nothing the loop
reads: it returns the PDO mappings, and the loop's thread takes them over (`finished`) when
the job is done. A drive that restarts again while the job runs is not taken as configured:
its record's boot count moved (`DriveRecord.boots`).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence

from canopen.pdo import PdoMap

from drivers.base import DriverError
from drivers.cia402.receive import DriveRecord

PdoMapping = tuple[PdoMap, PdoMap | None, PdoMap]
"""RPDO1, RPDO2 (None without the velocity feed-forward) and TPDO1 of one configured drive."""


class ConfigJob:
    """The configuration of `drives` by SDO on a worker thread (started by `start`)."""

    def __init__(
        self, drives: Sequence[DriveRecord], configure: Callable[[DriveRecord], PdoMapping]
    ):
        """Configure each of `drives` in turn with `configure` (which raises a DriverError
        naming the node and the step on failure); the first failure ends the job."""
        self.drives = tuple(drives)
        self.boots = tuple(d.boots for d in self.drives)
        """Each drive's boot count when the job started."""
        self.results: list[tuple[DriveRecord, PdoMapping]] = []
        self.error: str | None = None
        self._configure = configure
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, name="cia402-configure", daemon=True)

    @property
    def node_ids(self) -> list[int]:
        """The node ids of the drives being configured."""
        return [d.node_id for d in self.drives]

    def start(self) -> ConfigJob:
        """Start the worker thread; returns self."""
        self._thread.start()
        return self

    def done(self) -> bool:
        """True once the worker has finished (configured every drive, or failed)."""
        return self._done.is_set()

    def join(self, timeout_s: float) -> bool:
        """Wait up to `timeout_s` for the worker; True if it has finished."""
        return self._done.wait(timeout_s)

    def _run(self) -> None:
        try:
            for d in self.drives:
                self.results.append((d, self._configure(d)))
        except Exception as exc:  # a DriverError names the node and step; anything else too
            name = "" if isinstance(exc, DriverError) else f"{type(exc).__name__}: "
            self.error = f"{name}{exc}"
        finally:
            self._done.set()

    def restarted_since(self, d: DriveRecord) -> bool:
        """True if drive `d` (one of the job's) restarted again after the job started."""
        return d.boots != self.boots[self.drives.index(d)]
