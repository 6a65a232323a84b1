"""`cablebot replay FILE.mcap`: republish a recording over Zenoh with its timing.

Every recorded pose, state change and other published key is put again on its key, with the
recorded payload bytes (same `seq`, same positions, same `stamp_ns`) and the recorded spacing
in time (`log_time`, divided by `--rate`). Any subscriber (`cablebot pose`, `cablebot view`,
your own) sees the recorded run as if it were live. The status replies are not put: replay
answers `<prefix>/status` queries with the latest recorded status at the current replay time,
so tools that read the robot's geometry from the status work too.

Replay never commands a robot: command keys (`<prefix>/setpoint`, `<prefix>/velocity`,
`<prefix>/cmd/**`) are not republished, no command queryable is declared, and replay refuses to
start when a live daemon's liveliness token (`<prefix>/alive`) is present on the Zenoh network
it joins (replay under another `--prefix` then).

Zenoh: by default replay is a peer listening on `tcp/127.0.0.1:7447` like the daemon (so run it
instead of the daemon, or give `--listen`), with multicast scouting off; `--connect` joins a
router or another peer instead or as well.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

from controller.cli.record import RecordedMessage, Recording, positive_number

EXIT_OK = 0
EXIT_REFUSED = 1
COMMAND_SUFFIXES = ("setpoint", "velocity", "cmd")
"""Keys under the prefix that command the robot: never republished."""
NOT_PUT_SUFFIXES = ("status", "alive")
"""Recorded keys that are answered (status) or only informative (alive), not put."""


@dataclass(frozen=True, slots=True)
class ReplayItem:
    """One message to republish: when (seconds after the first message, at rate 1), the key
    to put it on (prefix mapped), whether it is a status reply, and the payload."""

    at_s: float
    key: str
    is_status: bool
    data: bytes


def replay_items(
    messages: Iterator[RecordedMessage], recorded_prefix: str | None, prefix: str | None
) -> Iterator[ReplayItem]:
    """The messages of a recording as replay items: command and liveliness keys dropped,
    keys moved from `recorded_prefix` to `prefix` (when both are given)."""
    t0: int | None = None
    for m in messages:
        key = m.topic
        if recorded_prefix and key.startswith(recorded_prefix + "/"):
            suffix = key[len(recorded_prefix) + 1 :]
            if suffix.split("/", 1)[0] in COMMAND_SUFFIXES or suffix == "alive":
                continue
            if prefix:
                key = f"{prefix}/{suffix}"
            is_status = suffix == "status"
        else:
            is_status = False
        if t0 is None:
            t0 = m.log_time_ns
        yield ReplayItem((m.log_time_ns - t0) * 1e-9, key, is_status, m.data)


class Replayer:
    """Puts replay items on a Zenoh session at their times and answers status queries.

    `run(items, stop)` returns the number of samples put; it stops early when `stop` is set
    (then `ended` is False: the items were not all read).
    """

    def __init__(self, session: Any, rate: float) -> None:
        self.session = session
        self.rate = rate
        self._publishers: dict[str, Any] = {}
        self._status: dict[str, bytes] = {}
        self._queryables: dict[str, Any] = {}
        self.put = 0
        self.ended = False

    def _publisher(self, key: str) -> Any:
        pub = self._publishers.get(key)
        if pub is None:
            import zenoh

            # BLOCK: a replay delivers every recorded sample rather than dropping under load.
            pub = self.session.declare_publisher(
                key,
                encoding=zenoh.Encoding.APPLICATION_JSON,
                congestion_control=zenoh.CongestionControl.BLOCK,
            )
            self._publishers[key] = pub
        return pub

    def _answer_status(self, key: str) -> Any:
        import zenoh

        def on_query(query: Any) -> None:
            data = self._status.get(key)
            try:
                if data is not None:
                    query.reply(key, data, encoding=zenoh.Encoding.APPLICATION_JSON)
            finally:
                query.drop()

        return self.session.declare_queryable(key, on_query, complete=True)

    def wait_subscriber(self, key: str, timeout_s: float) -> bool:
        """Wait (at most `timeout_s`) until a subscriber matches `key`; True if one does."""
        pub = self._publisher(key)
        deadline = time.monotonic() + timeout_s
        while not pub.matching_status.matching:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.02)
        return True

    def run(self, items: Iterator[ReplayItem], stop: threading.Event) -> int:
        """Republish `items` at their times (scaled by 1/rate); returns how many were put."""
        start = time.monotonic()
        self.ended = False
        for item in items:
            due = start + item.at_s / self.rate
            delay = due - time.monotonic()
            if delay > 0 and stop.wait(delay):
                return self.put
            if stop.is_set():
                return self.put
            if item.is_status:
                self._status[item.key] = item.data
                if item.key not in self._queryables:
                    self._queryables[item.key] = self._answer_status(item.key)
                continue
            self._publisher(item.key).put(item.data)
            self.put += 1
        self.ended = True
        return self.put

    def close(self) -> None:
        """Undeclare the publishers and queryables."""
        for obj in [*self._publishers.values(), *self._queryables.values()]:
            try:
                obj.undeclare()
            except Exception as exc:  # closing anyway
                print(f"cablebot replay: undeclare: {exc}", file=sys.stderr)
        self._publishers.clear()
        self._queryables.clear()


def live_daemon(session: Any, prefix: str, timeout_s: float = 1.0) -> bool:
    """True when a daemon's liveliness token `<prefix>/alive` is visible to `session`."""
    replies = session.liveliness().get(f"{prefix}/alive", timeout=timeout_s)
    return any(r.ok is not None for r in replies)


def replay_open_problem(listen: list[str], connect: list[str], exc: BaseException) -> str:
    """What to tell the user when replay's Zenoh session did not open: Zenoh's reason on one
    line and, when a listen address is taken, what to do about it."""
    from controller.cli.session import clean_zenoh_error
    from controller.service.zenoh_io import address_in_use

    text = clean_zenoh_error(str(exc))
    if address_in_use(exc):
        return (
            f"cannot listen on {', '.join(listen)}: the address is taken (is a cablebot daemon "
            "or another replay running there?); give --listen tcp/127.0.0.1:PORT with a free "
            f"port, or --connect ENDPOINT to join that network under another --prefix ({text})"
        )
    where = ", ".join([*(f"listen {e}" for e in listen), *(f"connect {e}" for e in connect)])
    return f"cannot open Zenoh ({where}): {text}"


def cmd_replay(args: argparse.Namespace) -> int:
    """Entry point of `cablebot replay`: 0 when replayed to the end (or stopped), 2 a bad
    endpoint, 1 otherwise."""
    import zenoh

    from controller.cli.client import EXIT_USAGE
    from controller.cli.session import UsageError, normalize_endpoint
    from controller.service.zenoh_io import DEFAULT_ENDPOINT, session_config

    path = Path(args.file)
    recording = Recording(path)
    head = recording.messages()
    try:
        first = next(head, None)
    except Exception as exc:  # no such file, not an MCAP file, mcap missing
        print(f"cablebot replay: cannot read {path}: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    finally:
        head.close()
    if first is None:
        print(f"cablebot replay: {path} holds no messages", file=sys.stderr)
        return EXIT_REFUSED
    recorded_prefix = recording.recorded_prefix()
    prefix = (args.prefix or recorded_prefix or "").rstrip("/")
    if not prefix:
        print(f"cablebot replay: {path} does not say its prefix; give --prefix", file=sys.stderr)
        return EXIT_REFUSED
    try:
        connect = [normalize_endpoint(e, "--connect") for e in args.connect]
        listen = (
            [normalize_endpoint(e, "--listen") for e in args.listen]
            if args.listen is not None
            else ([] if connect else [DEFAULT_ENDPOINT])
        )
    except UsageError as exc:
        print(f"cablebot replay: {exc}", file=sys.stderr)
        return EXIT_USAGE
    zcfg = argparse.Namespace(
        mode="peer",
        listen=listen,
        connect=connect,
        multicast_scouting=False,
        config_file=args.zenoh_config,
    )
    try:
        session = zenoh.open(session_config(zcfg))
    except (zenoh.ZError, OSError) as exc:
        print(f"cablebot replay: {replay_open_problem(listen, connect, exc)}", file=sys.stderr)
        return EXIT_REFUSED
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    replayer = Replayer(session, args.rate)
    try:
        if live_daemon(session, prefix):
            print(
                f"cablebot replay: a live cablebot daemon runs under {prefix}; "
                "replay under another --prefix",
                file=sys.stderr,
            )
            return EXIT_REFUSED
        where = ", ".join(listen + connect)
        print(f"replaying {path} as {prefix} on {where} at {args.rate:g}x", flush=True)
        if args.wait_subscriber > 0 and not replayer.wait_subscriber(
            f"{prefix}/pose", args.wait_subscriber
        ):
            print(
                f"cablebot replay: no subscriber within {args.wait_subscriber:g} s",
                file=sys.stderr,
            )
            return EXIT_REFUSED
        while True:
            n = replayer.run(replay_items(recording.messages(), recorded_prefix, prefix), stop)
            if not args.loop or stop.is_set():
                break
        if not replayer.ended:  # a signal: the file was not read to its end
            print(f"replay stopped after {n} samples", flush=True)
            return EXIT_OK
        cut = "" if recording.complete else " (the file ends early: the recorder was stopped)"
        print(f"replayed {n} samples{cut}", flush=True)
        return EXIT_OK
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
        replayer.close()
        session.close()  # type: ignore[no-untyped-call]


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `cablebot replay`."""
    from controller.service.zenoh_io import DEFAULT_ENDPOINT

    p = sub.add_parser(
        "replay",
        help="republish a recording over Zenoh with its timing",
        description=(
            "Put every recorded pose and state change (and other published keys) again on its "
            "key, with the recorded payloads and timing, and answer status queries with the "
            "recorded status. Command keys are never republished; refuses to run where a live "
            "daemon uses the prefix."
        ),
    )
    p.add_argument("file", metavar="FILE.mcap", help="a recording made by `cablebot record`")
    p.add_argument(
        "--rate", type=positive_number, default=1.0, metavar="X", help="speed factor (default 1)"
    )
    p.add_argument(
        "--prefix", default=None, help="publish under this prefix (default: the recorded one)"
    )
    p.add_argument(
        "--listen",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help=f"Zenoh endpoint to listen on, PROTO/HOST:PORT or HOST:PORT (repeatable; default"
        f" {DEFAULT_ENDPOINT} unless --connect is given)",
    )
    p.add_argument(
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to connect to, PROTO/HOST:PORT or HOST:PORT (repeatable)",
    )
    p.add_argument("--zenoh-config", default=None, metavar="FILE", help="Zenoh JSON5 configuration")
    p.add_argument(
        "--wait-subscriber",
        type=float,
        default=0.0,
        metavar="S",
        help="before starting, wait up to S s for a subscriber to the pose (default: start now)",
    )
    p.add_argument("--loop", action="store_true", help="start again at the end, until Ctrl-C")
    p.set_defaults(func=cmd_replay)
