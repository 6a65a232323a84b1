"""The connection of every verb that talks to a daemon, as the command line gives it: the
connection options (`--connect`, `--prefix`, `--zenoh-config`, `--timeout`), the session opened
with the CLI's error handling (every failure one line, its exit code), the argparse types.

The client side of the daemon's interface itself (endpoints, the session, one query, the live
daemons, the errors) is the client library's, `controller.client.transport` and
`controller.client.errors`; its names are importable from here too.

Exit codes: `controller.cli.exitcodes`.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from controller.cli import exitcodes
from controller.client import transport
from controller.client.errors import (
    DaemonAbsent,
    Failed,
    InputError,
    Refused,
    UsageError,
    WaitTimeout,
)
from controller.client.transport import (
    DEFAULT_ENDPOINT,
    DEFAULT_PREFIX,
    LIVELINESS_TIMEOUT_S,
    clean_zenoh_error,
    live_prefixes,
    query,
)

__all__ = [
    "DEFAULT_ENDPOINT",
    "DEFAULT_PREFIX",
    "LIVELINESS_TIMEOUT_S",
    "DaemonAbsent",
    "Failed",
    "InputError",
    "Refused",
    "UsageError",
    "WaitTimeout",
    "absent_message",
    "add_connection_arguments",
    "clean_zenoh_error",
    "live_prefixes",
    "normalize_endpoint",
    "open_session",
    "positive_count",
    "positive_seconds",
    "query",
    "run_with_session",
    "tcp_port",
]


def normalize_endpoint(text: str, option: str = "--connect") -> str:
    """`controller.client.transport.normalize_endpoint` naming the command line's option.
    Raises UsageError."""
    return transport.normalize_endpoint(text, option)


@contextmanager
def open_session(endpoint: str, *, config_file: str | None = None) -> Iterator[Any]:
    """A client Zenoh session to `endpoint` (`controller.client.transport.open_session`),
    errors naming `--connect` and `--zenoh-config`; closed on exit. Raises UsageError,
    DaemonAbsent."""
    with transport.open_session(
        endpoint,
        config_file=config_file,
        endpoint_option="--connect",
        config_option="--zenoh-config",
    ) as session:
        yield session


def absent_message(args: argparse.Namespace, exc: DaemonAbsent) -> str:
    """The line for "no daemon answered on --prefix", naming the live prefixes (`exc.live`)."""
    text = f"no cablebot daemon answered on {args.prefix} via {args.connect} ({exc})"
    others = [p for p in exc.live if p != args.prefix.rstrip("/")]
    if others:
        text += (
            f"; live daemons there: {', '.join(others)} (give --prefix {others[0]};"
            " `cablebot list` shows them)"
        )
    return text


def run_with_session(args: argparse.Namespace, body: Callable[[Any], int]) -> int:
    """Run `body(session)` with the CLI's error handling; returns the exit code.

    Every failure is one line on stderr: a refusal prints the daemon's reason verbatim, a
    command accepted that then failed says "accepted, then" what happened; when
    no daemon answers on `--prefix`, the line names the prefixes of the daemons that are alive.
    """
    try:
        endpoint = normalize_endpoint(args.connect)
        args.connect = endpoint
        with open_session(endpoint, config_file=args.zenoh_config) as session:
            try:
                code: int = body(session)
            except DaemonAbsent as exc:
                exc.live = tuple(live_prefixes(session))
                raise
            return code
    except UsageError as exc:
        print(f"cablebot: {exc}", file=sys.stderr)
        return exitcodes.USAGE
    except DaemonAbsent as exc:
        print(f"cablebot: {absent_message(args, exc)}", file=sys.stderr)
        return exitcodes.NO_DAEMON
    except Failed as exc:
        print(f"cablebot: accepted, then {exc}", file=sys.stderr)
        return exitcodes.REFUSED
    except Refused as exc:
        print(f"cablebot: refused: {exc}", file=sys.stderr)
        return exitcodes.REFUSED
    except InputError as exc:
        print(f"cablebot: {exc}", file=sys.stderr)
        return exitcodes.REFUSED
    except WaitTimeout as exc:
        print(f"cablebot: {exc}", file=sys.stderr)
        return exitcodes.WAIT_TIMEOUT
    except KeyboardInterrupt:
        return exitcodes.INTERRUPTED


def positive_seconds(text: str) -> float:
    """argparse type: a finite number of seconds > 0; raises ArgumentTypeError otherwise."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not (math.isfinite(value) and value > 0.0):
        raise argparse.ArgumentTypeError(f"must be a number of seconds > 0, got {text}")
    return value


def positive_count(text: str) -> int:
    """argparse type: a whole number >= 1; raises ArgumentTypeError otherwise."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {text}")
    return value


def tcp_port(text: str) -> int:
    """argparse type: a TCP port, 0 (any free port) to 65535; raises ArgumentTypeError
    otherwise."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a port number, got {text!r}") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"a port is 0 (any) to 65535, got {text}")
    return value


def add_connection_arguments(p: argparse.ArgumentParser) -> None:
    """Add `--connect`, `--prefix`, `--zenoh-config` and `--timeout` to a verb's parser."""
    p.add_argument(
        "--connect",
        default=DEFAULT_ENDPOINT,
        metavar="ENDPOINT",
        help=f"the daemon's endpoint, PROTO/HOST:PORT or HOST:PORT (default {DEFAULT_ENDPOINT})",
    )
    p.add_argument(
        "--prefix",
        default=DEFAULT_PREFIX,
        help=f"key prefix of the robot (default {DEFAULT_PREFIX})",
    )
    p.add_argument(
        "--zenoh-config",
        default=None,
        metavar="FILE",
        help="Zenoh JSON5 configuration for this client (e.g. TLS certificates)",
    )
    p.add_argument(
        "--timeout",
        type=positive_seconds,
        default=5.0,
        metavar="S",
        help="seconds to wait for a reply or a sample (default 5)",
    )
