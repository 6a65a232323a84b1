"""The serving thread of a bank of simulated drives, shared by every drive family.

A family's bank (`drivers.odrive.sim.SimODriveBank`, `drivers.cia402.sim.SimCiA402Bank`) says
what one serving run is (`_serve`: answer frames and step the nodes until the stop event is
set); this class starts it once in a daemon thread, stops and joins it, and makes the bank a
context manager. The bank does not own the bus: the caller shuts it down after `stop()`.

`take_queued` is the families' rule for a tick that falls due late: the frames already received
are handled before the tick is stepped (a real drive handles each frame as it arrives), for at
most one tick's time.

`add_bus_arguments` and `serve_process` are the shared part of the families' command lines
(`python -m drivers.odrive.sim`, `python -m drivers.cia402.sim`): the bus options, and serving
until SIGTERM/SIGINT (or `--duration-s`) with "READY <nodes>" on stdout once the bus is open.
"""

from __future__ import annotations

import argparse
import math
import signal
import threading
import time
from collections.abc import Callable, Sequence
from types import FrameType, TracebackType
from typing import TYPE_CHECKING, Any, Self

if TYPE_CHECKING:
    import can


def take_queued(bus: can.BusABC, handle: Callable[[can.Message], None], budget_s: float) -> int:
    """Hand the frames already waiting on `bus` to `handle` without blocking, for at most
    `budget_s` seconds (one tick's time); returns how many were taken.

    A serving loop calls it when a tick is due, before stepping: a loop that is late on its
    ticks (a loaded host, a slow physical plant) would otherwise step tick after tick without
    reading the bus, and its drives would miss the host's set-points and feeds (an axis watchdog
    expiring on a host that is sending). The budget keeps the reverse from happening: on a host
    too slow for the traffic, handling and ticks alternate, so the drives still step and send
    their heartbeats. Receive errors end the drain; nothing raises.
    """
    taken = 0
    end_s = time.monotonic() + budget_s
    while True:
        try:
            msg = bus.recv(timeout=0.0)
        except Exception:  # a simulated node survives a broken bus
            break
        if msg is None:
            break
        taken += 1
        handle(msg)
        if time.monotonic() >= end_s:
            break
    return taken


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


# --------------------------------------------------------------------------------------------
# The simulators' command lines


def floats_arg(text: str, n: int) -> list[float]:
    """`n` finite numbers from "a,b,..." (one value stands for all `n`). Raises
    argparse.ArgumentTypeError otherwise."""
    values = [float(v) for v in text.split(",")] if text else [0.0]
    if len(values) == 1:
        values = values * n
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"need 1 or {n} finite values, got {text!r}")
    return values


def option_arg(text: str) -> tuple[str, Any]:
    """A python-can keyword from "KEY=VALUE" (integers, floats and true/false parsed). Raises
    SystemExit without a KEY or "="."""
    key, sep, raw = text.partition("=")
    if not sep or not key:
        raise SystemExit(f"--option needs KEY=VALUE, got {text!r}")
    value: Any = raw
    if raw.lower() in ("true", "false"):
        value = raw.lower() == "true"
    else:
        for conv in (int, float):
            try:
                value = conv(raw)
                break
            except ValueError:
                pass
    return key, value


def add_bus_arguments(p: argparse.ArgumentParser) -> None:
    """The bus options every simulator process takes, and `--tick-s`, `--duration-s`."""
    p.add_argument("--interface", required=True, help="python-can interface, e.g. socketcan")
    p.add_argument("--channel", required=True, help="channel, e.g. vcan0 or a multicast group")
    p.add_argument("--bitrate", type=int, default=None)
    p.add_argument("--port", type=int, default=None, help="udp_multicast port")
    p.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="further python-can interface keyword (repeatable); numbers and true/false parsed",
    )
    p.add_argument("--tick-s", type=float, default=0.001)
    p.add_argument("--duration-s", type=float, default=None, help="exit after this long")


def serve_process(
    args: argparse.Namespace,
    nodes: Sequence[int],
    serve: Callable[[can.BusABC, threading.Event], None],
) -> int:
    """Open the bus of `add_bus_arguments`' options, say "READY <nodes>", and run
    `serve(bus, stop)` until SIGTERM/SIGINT or `--duration-s`; shut the bus down. Returns 0."""
    from drivers.bus import open_bus

    options: dict[str, Any] = dict(option_arg(o) for o in args.option)
    if args.port is not None:
        options["port"] = args.port
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    if args.duration_s is not None:
        timer = threading.Timer(args.duration_s, stop.set)
        timer.daemon = True
        timer.start()
    bus = open_bus(args.interface, args.channel, args.bitrate, **options)
    try:
        print("READY " + ",".join(str(n) for n in nodes), flush=True)
        serve(bus, stop)
    finally:
        bus.shutdown()
    return 0
