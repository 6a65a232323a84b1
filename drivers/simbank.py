"""The serving thread of a bank of simulated drives, shared by every drive family.

A family's bank (`drivers.odrive.sim.SimODriveBank`, `drivers.cia402.sim.SimCiA402Bank`) says
what one serving run is (`_serve`: answer frames and step the nodes until the stop event is
set); this class starts it once in a daemon thread, stops and joins it, and makes the bank a
context manager. The bank does not own the bus: the caller shuts it down after `stop()`.

`SimLink` is a bank's side of its bus, for every family's serving loop: frames in (each handed
on with SocketCAN's flags, its data and its time) and frames out, through python-can one frame
at a time, or on SocketCAN through the fast path's batches. Its `serve` is also the families'
rule for a tick that falls due late: the frames already received are handled before the tick is
stepped (a real drive handles each frame as it arrives), within a time budget.

`add_bus_arguments` and `serve_process` are the shared part of the families' command lines
(`python -m drivers.odrive.sim`, `python -m drivers.cia402.sim`): the bus options, and serving
until SIGTERM/SIGINT (or `--duration-s`) with "READY <nodes>" on stdout once the bus is open.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import signal
import threading
import time
from collections.abc import Callable, Sequence
from types import FrameType, TracebackType
from typing import Any, Self

import can

from drivers.bus import frame_message
from drivers.socketcan_fast import FastSocketCan, flagged_id, open_fast_path

SimFrame = tuple[int, bytes, bool]
"""A frame a simulated node sends: (11-bit id, data, is_remote)."""


class SimLink:
    """A simulated bank's side of its bus: the frames it receives and sends.

    On every bus python-can's `recv` and `send`, one frame at a time. On a python-can SocketCAN
    bus (with `fast_path`; a `FastSocketCan` given is used as it is) the fast path instead
    (`drivers.socketcan_fast`): frames come off the kernel socket in batches, every one (no
    kernel filter) but the bank's own, and a batch's answers leave in one system call. Reading
    one `can.Message` at a time, a bank fell behind a controller's bursts on a slow machine (the
    emulated VM under load), and its socket's full receive queue then dropped the tail of each
    burst: for CiA 402 drives the cycle's SYNC, which they answer. Not thread-safe: the serving
    thread calls every method.
    """

    def __init__(self, bus: can.BusABC, *, fast_path: bool | FastSocketCan = True) -> None:
        """Use `bus` (owned by the caller). Raises OSError if a SocketCAN socket refuses the
        fast path's options."""
        self._bus = bus
        self.fast = open_fast_path(bus, None, fast_path=fast_path)
        """The fast path in use, or None (python-can's path)."""

    def serve(
        self,
        handle: Callable[[int, bytes | bytearray, float], None],
        wait_s: float,
        budget_s: float,
        max_frames: int = 10_000,
    ) -> int:
        """Wait up to `wait_s` (0: not at all) for a frame; then hand it and the frames received
        after it to `handle(can_id, data, stamp)` (`can_id` with SocketCAN's EFF/RTR/ERR flags,
        `stamp` the wall-clock receive time) until none is left, `budget_s` has passed since the
        first, or `max_frames` were handed. Returns how many. A receive error ends it (the
        serving loop goes on ticking); raises only what `handle` raises.

        A serving loop calls it with no wait when a tick is due, before stepping: a loop late
        on its ticks (a loaded host, a slow physical plant) would otherwise step tick after tick
        without reading the bus, and its drives would miss the host's set-points and feeds (an
        axis watchdog expiring on a host that is sending). The budget keeps the reverse from
        happening: on a host too slow for the traffic, handling and ticks alternate, so the
        drives still step and send their heartbeats.
        """
        fast = self.fast
        if fast is None:
            return self._serve_stock(handle, wait_s, budget_s, max_frames)
        try:
            if not fast.wait_readable(wait_s):
                return 0
        except OSError:  # the bus was shut down under the serving loop
            time.sleep(min(max(wait_s, 0.0), 0.001))
            return 0
        end_s = time.monotonic() + budget_s
        handed = 0
        frame = fast.frame
        while handed < max_frames:
            try:
                n = fast.recv_batch(max_frames - handed)
            except OSError:
                break
            for i in range(n):
                can_id, length, data, stamp = frame(i)
                handle(can_id, data[:length], stamp)
            handed += n
            if n == 0 or time.monotonic() >= end_s:
                break
        return handed

    def _serve_stock(
        self,
        handle: Callable[[int, bytes | bytearray, float], None],
        wait_s: float,
        budget_s: float,
        max_frames: int,
    ) -> int:
        recv = self._bus.recv
        timeout_s = max(wait_s, 0.0)
        end_s = math.inf
        handed = 0
        while handed < max_frames:
            try:
                msg = recv(timeout=timeout_s)
            except Exception:  # a simulated node survives a broken bus
                if handed == 0:
                    time.sleep(min(timeout_s, 0.001))
                break
            if msg is None:
                break
            if handed == 0:
                end_s = time.monotonic() + budget_s
                timeout_s = 0.0
            handed += 1
            handle(flagged_id(msg), msg.data, msg.timestamp)
            if time.monotonic() >= end_s:
                break
        return handed

    def send(self, frames: Sequence[SimFrame]) -> None:
        """Send `frames` in order (one system call on the fast path). A frame that cannot be
        sent is dropped: a simulated node survives a broken bus. Raises nothing."""
        if not frames:
            return
        fast = self.fast
        if fast is not None:
            with contextlib.suppress(Exception):
                fast.send_frames(frames)
            return
        send = self._bus.send
        for arb_id, data, remote in frames:
            with contextlib.suppress(Exception):
                send(frame_message(arb_id, data, remote), timeout=0.01)


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
