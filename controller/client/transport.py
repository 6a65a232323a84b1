"""The client side of a daemon's Zenoh interface, below every client: the endpoint a user
gives, the session, one query, the live daemons.

The key layout and payloads are the daemon's (`controller.service.zenoh_io`, docs/zenoh.md);
the commands' schema is `controller.core.commands`. Zenoh is imported when a session is
opened, not before, so that importing the library stays cheap.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from controller.client.errors import DaemonAbsent, Refused, UsageError
from controller.service import keys

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
"""Where a client looks for the daemon unless told otherwise (the daemon's default listen)."""
DEFAULT_PREFIX = "cablebot/default"
"""The key prefix of the built-in robot (`cablebot/<robot name>`)."""
DEFAULT_TIMEOUT_S = 5.0
"""How long a client waits for a reply or a pose sample unless told otherwise."""
ENDPOINT_ENV = "CABLEBOT_ENDPOINT"
"""The environment variable that, when set, replaces `DEFAULT_ENDPOINT` for a program's
`Robot()` (so a script is pointed at another daemon without an edit)."""
PREFIX_ENV = "CABLEBOT_PREFIX"
"""The environment variable that, when set, replaces `DEFAULT_PREFIX` for `Robot()`."""
LIVELINESS_TIMEOUT_S = 1.0
"""How long `live_prefixes` waits for the daemons' liveliness tokens."""

# Zenoh link protocols a client may name in an endpoint; those with HOST:PORT addresses are
# checked here so that a typo gets a one-line answer instead of a connection attempt.
_PORT_PROTOCOLS = frozenset({"tcp", "udp", "tls", "quic", "ws"})
_OTHER_PROTOCOLS = frozenset({"unixsock-stream", "unixpipe", "serial", "vsock"})
_HOST_PORT = re.compile(r"(\[[0-9A-Fa-f:.%a-zA-Z]+\]|[A-Za-z0-9_.-]+):([0-9]{1,5})")
_RUST_LOCATION = re.compile(r" at /\S+\.rs:\d+\.?")


def normalize_endpoint(text: str, option: str = "endpoint") -> str:
    """The Zenoh endpoint for an endpoint a user gives: `HOST:PORT` becomes `tcp/HOST:PORT`.

    The one reading of an endpoint (a `Robot`'s, every verb's `--connect`, `replay --listen`).
    Accepts `PROTO/ADDRESS` for Zenoh's link protocols (`tcp`, `udp`, `tls`, `quic`, `ws` need
    `HOST:PORT` with a port 1..65535). Raises UsageError (one line, naming `option`) for
    anything else.
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


def default_endpoint() -> str:
    """The endpoint a program's client uses when it names none: `$CABLEBOT_ENDPOINT` when set
    and not empty, else `DEFAULT_ENDPOINT`."""
    return os.environ.get(ENDPOINT_ENV) or DEFAULT_ENDPOINT


def default_prefix() -> str:
    """The prefix a program's client uses when it names none: `$CABLEBOT_PREFIX` when set and
    not empty, else `DEFAULT_PREFIX`."""
    return os.environ.get(PREFIX_ENV) or DEFAULT_PREFIX


def clean_zenoh_error(text: str) -> str:
    """A Zenoh error message on one line, without the Rust source locations."""
    one = " ".join(text.split())
    return _RUST_LOCATION.sub("", one)


def open_zenoh(
    endpoint: str,
    *,
    config_file: str | None = None,
    endpoint_option: str = "endpoint",
    config_option: str = "zenoh_config",
) -> Any:
    """A client-mode Zenoh session connected to `endpoint` (any form `normalize_endpoint`
    takes); the caller closes it.

    Raises UsageError for an endpoint or Zenoh configuration file that Zenoh rejects (naming
    `endpoint_option` or `config_option`, as the caller calls them), and DaemonAbsent when
    nothing accepts the connection.
    """
    import zenoh

    from controller.service.zenoh_io import client_config

    endpoint = normalize_endpoint(endpoint, endpoint_option)
    try:
        conf = client_config([endpoint], config_file=config_file)
    except zenoh.ZError as exc:
        what = f"{config_option} {config_file}" if config_file else f"{endpoint_option} {endpoint}"
        raise UsageError(f"{what}: {clean_zenoh_error(str(exc))}") from None
    try:
        return zenoh.open(conf)
    except zenoh.ZError as exc:
        raise DaemonAbsent(f"cannot connect to {endpoint}: {clean_zenoh_error(str(exc))}") from None


@contextmanager
def open_session(
    endpoint: str,
    *,
    config_file: str | None = None,
    endpoint_option: str = "endpoint",
    config_option: str = "zenoh_config",
) -> Iterator[Any]:
    """`open_zenoh` as a context manager: the session is closed on exit. Raises as
    `open_zenoh` does."""
    session = open_zenoh(
        endpoint,
        config_file=config_file,
        endpoint_option=endpoint_option,
        config_option=config_option,
    )
    try:
        yield session
    finally:
        session.close()


def key(prefix: str, suffix: str) -> str:
    """The key `<prefix>/<suffix>` (a trailing `/` of the prefix ignored)."""
    return f"{prefix.rstrip('/')}/{suffix}"


def encode(payload: Any) -> bytes | None:
    """The JSON bytes a query carries (None: no payload). Raises ValueError for a value JSON
    cannot carry (NaN, infinity)."""
    return None if payload is None else json.dumps(payload, allow_nan=False).encode()


def query(session: Any, key: str, payload: Any, timeout_s: float) -> Any:
    """Send one query to `key` with a JSON `payload` (already encoded bytes are sent as they
    are); return the decoded JSON reply.

    Raises Refused with the daemon's reason for an error reply, DaemonAbsent when no reply
    arrives within `timeout_s` (no queryable on that key, or a Zenoh timeout).
    """
    import zenoh

    body = payload if isinstance(payload, bytes) else encode(payload)
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


def live_prefixes(session: Any, timeout_s: float = LIVELINESS_TIMEOUT_S) -> list[str]:
    """The key prefixes of every daemon alive on the session's network (each daemon declares
    the liveliness token `<prefix>/alive` while its Zenoh interface is open), sorted.

    Raises nothing: a failed lookup is an empty list."""
    found: set[str] = set()
    try:
        for reply in session.liveliness().get(f"**/{keys.ALIVE}", timeout=timeout_s):
            if reply.ok is not None:
                name = str(reply.ok.key_expr)
                if name.endswith(f"/{keys.ALIVE}"):
                    found.add(name.removesuffix(f"/{keys.ALIVE}"))
    except Exception:  # a closing session: nothing to name
        return []
    return sorted(found)
