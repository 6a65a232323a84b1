"""The client side of a daemon's Zenoh interface, for every verb that talks to a daemon: the
endpoint a user gives, the session, one query, the live daemons, the CLI's error handling and
the connection options.

Exit codes: `controller.cli.exitcodes`.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from controller.cli import exitcodes

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
DEFAULT_PREFIX = "cablebot/default"

# Zenoh link protocols a client may name in an endpoint; those with HOST:PORT addresses are
# checked here so that a typo gets a one-line answer instead of a connection attempt.
_PORT_PROTOCOLS = frozenset({"tcp", "udp", "tls", "quic", "ws"})
_OTHER_PROTOCOLS = frozenset({"unixsock-stream", "unixpipe", "serial", "vsock"})
_HOST_PORT = re.compile(r"(\[[0-9A-Fa-f:.%a-zA-Z]+\]|[A-Za-z0-9_.-]+):([0-9]{1,5})")
_RUST_LOCATION = re.compile(r" at /\S+\.rs:\d+\.?")


class DaemonAbsent(RuntimeError):
    """No daemon answered: nothing listening on the endpoint, wrong prefix, or no reply in time.

    `live` names the prefixes of the daemons that are alive on the same network (filled in by
    `run_with_session`), for the error message."""

    live: tuple[str, ...] = ()


class Refused(RuntimeError):
    """The daemon answered with an error reply; the message is its reason."""


class Failed(Refused):
    """The daemon accepted the command, which then did not complete: the robot went FAULT,
    ESTOPPED or DISARMED, or the motion ended short of its end (stopped, replaced), while the
    CLI followed it; the message says what happened. (A
    `Refused` for the handlers that only need "it did not work"; printed as
    "accepted, then ...", not as a refusal.)"""


class InputError(ValueError):
    """The user's input (numbers, path file) is invalid; nothing was sent."""


class UsageError(ValueError):
    """A command-line value that cannot be used (e.g. `--connect`); nothing was sent."""


class WaitTimeout(RuntimeError):
    """`--wait`: the robot did not reach the end point in time."""


# --------------------------------------------------------------------------------------------
# Session and queries


def normalize_endpoint(text: str, option: str = "--connect") -> str:
    """The Zenoh endpoint for an endpoint option's value: `HOST:PORT` becomes `tcp/HOST:PORT`.

    The one reading of an endpoint given on the command line (`--connect` of every verb,
    `replay --listen`). Accepts `PROTO/ADDRESS` for Zenoh's link protocols (`tcp`, `udp`,
    `tls`, `quic`, `ws` need `HOST:PORT` with a port 1..65535). Raises UsageError (one line,
    naming `option`) for anything else.
    """
    t = text.strip()
    bad = UsageError(f"{option}: expected tcp/HOST:PORT or HOST:PORT, got {text!r}")
    if "/" in t:
        proto, _, address = t.partition("/")
        if proto in _OTHER_PROTOCOLS and address:
            return t
        if proto not in _PORT_PROTOCOLS:
            raise bad
        host_port = re.split(r"[?#]", address, maxsplit=1)[0]
    else:
        host_port = t
    m = _HOST_PORT.fullmatch(host_port)
    if m is None or not 1 <= int(m.group(2)) <= 65535:
        raise bad
    return t if "/" in t else f"tcp/{t}"


def clean_zenoh_error(text: str) -> str:
    """A Zenoh error message on one line, without the Rust source locations."""
    one = " ".join(text.split())
    return _RUST_LOCATION.sub("", one)


@contextmanager
def open_session(endpoint: str, *, config_file: str | None = None) -> Iterator[Any]:
    """Open a client-mode Zenoh session connected to `endpoint` (any form `normalize_endpoint`
    takes, e.g. `HOST:PORT`); close it on exit.

    Raises UsageError for an endpoint or `--zenoh-config` file that Zenoh rejects, and
    DaemonAbsent when nothing accepts the connection.
    """
    import zenoh

    from controller.service.zenoh_io import client_config

    endpoint = normalize_endpoint(endpoint)
    try:
        conf = client_config([endpoint], config_file=config_file)
    except zenoh.ZError as exc:
        what = f"--zenoh-config {config_file}" if config_file else f"--connect {endpoint}"
        raise UsageError(f"{what}: {clean_zenoh_error(str(exc))}") from None
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        raise DaemonAbsent(f"cannot connect to {endpoint}: {clean_zenoh_error(str(exc))}") from None
    try:
        yield session
    finally:
        session.close()  # type: ignore[no-untyped-call]


def query(session: Any, key: str, payload: dict[str, Any] | None, timeout_s: float) -> Any:
    """Send one query to `key` with a JSON `payload`; return the decoded JSON reply.

    Raises Refused with the daemon's reason for an error reply, DaemonAbsent when no reply
    arrives within `timeout_s` (no queryable on that key, or a Zenoh timeout).
    """
    import zenoh

    body = None if payload is None else json.dumps(payload, allow_nan=False).encode()
    replies = session.get(
        key,
        payload=body,
        encoding=zenoh.Encoding.APPLICATION_JSON if body is not None else None,
        timeout=timeout_s,
    )
    for reply in replies:
        if reply.ok is not None:
            return json.loads(reply.ok.payload.to_bytes())
        err = reply.err.payload.to_bytes().decode(errors="replace")
        try:
            decoded = json.loads(err)
        except ValueError:
            decoded = None
        if isinstance(decoded, dict) and "error" in decoded:
            raise Refused(str(decoded["error"]))
        if err.strip().lower() == "timeout":
            raise DaemonAbsent(f"no reply on {key} within {timeout_s:g} s")
        raise Refused(err)
    raise DaemonAbsent(f"no reply on {key}")


LIVELINESS_TIMEOUT_S = 1.0
"""How long `live_prefixes` waits for the daemons' liveliness tokens."""


def live_prefixes(session: Any, timeout_s: float = LIVELINESS_TIMEOUT_S) -> list[str]:
    """The key prefixes of every daemon alive on the session's network (each daemon declares
    the liveliness token `<prefix>/alive` while its Zenoh interface is open), sorted.

    Raises nothing: a failed lookup is an empty list."""
    found: set[str] = set()
    try:
        for reply in session.liveliness().get("**/alive", timeout=timeout_s):
            if reply.ok is not None:
                key = str(reply.ok.key_expr)
                if key.endswith("/alive"):
                    found.add(key.removesuffix("/alive"))
    except Exception:  # a closing session: nothing to name
        return []
    return sorted(found)


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
