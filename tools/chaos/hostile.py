"""A hostile Zenoh client, as a process of its own (a client on another machine shares no CPU
time with the test equipment): `python -m chaos.hostile ENDPOINT PREFIX`.

It connects once and stays connected; for each line "flood SECONDS SEED" on stdin it floods the
daemon with malformed and oversized commands for that long and prints "sent N"; "flood_new
SECONDS SEED" does the same from a new session, closed after it. It ends at the end of stdin.
"""

from __future__ import annotations

import json
import random
import sys
import time
from typing import Any

FLOOD: list[tuple[str, bytes]] = [
    ("cmd/move", b"{not json"),
    ("cmd/move", b'{"position_m": [NaN, 0, 0.3]}'),
    ("cmd/move", b'{"position_m": [1e999, 0, 0.3]}'),
    ("cmd/move", b'{"position_m": "here"}'),
    ("cmd/move", b"[" * 64),
    ("cmd/path", b'{"points_m": [[0, 0, 0.3]]' + b" " * 200_000 + b"}"),
    ("cmd/path", json.dumps({"points_m": [[0.0, 0.0, 0.3]] * 1500}).encode()),
    ("cmd/home", b'{"position_m": [0, 0]}'),
    ("cmd/arm", b"\xff\xfe\x00garbage"),
    ("cmd/nosuchverb", b"{}"),
    ("setpoint", b'{"position_m": [NaN, NaN, NaN]}'),
    ("setpoint", b"\x00" * 8192),
    ("velocity", b'{"velocity_mps": [1e308, 0, 0]}'),
    ("velocity", b'{"velocity_mps": "fast"}'),
]
"""Bad JSON, NaN, 1e999, 64 levels of nesting, a 200 KB path, 1,500 points, a short home, bytes
that are no text, an unknown verb, garbage set-points and velocities."""


def flood(session: Any, prefix: str, seconds: float, rng: random.Random) -> int:
    """Send random entries of FLOOD for `seconds`; how many were sent."""
    sent = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        key, payload = rng.choice(FLOOD)
        full = f"{prefix}/{key}"
        try:
            if key.startswith("cmd/"):
                for _ in session.get(full, payload=payload, timeout=0.5):
                    pass
            else:
                session.put(full, payload)
        except Exception:  # a daemon restarting meanwhile: go on
            time.sleep(0.05)
        sent += 1
    return sent


def main() -> int:
    """Serve flood requests from stdin until it ends."""
    import zenoh

    from controller.service.zenoh_io import client_config

    endpoint, prefix = sys.argv[1], sys.argv[2]

    def connect() -> Any:
        deadline = time.monotonic() + 30.0
        while True:
            try:
                return zenoh.open(client_config([endpoint]))
            except Exception:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)

    session = connect()
    for line in sys.stdin:
        verb, seconds, seed = line.split()
        rng = random.Random(int(seed))
        if verb == "flood_new":
            fresh = connect()
            try:
                n = flood(fresh, prefix, float(seconds), rng)
            finally:
                fresh.close()
        else:
            n = flood(session, prefix, float(seconds), rng)
        print(f"sent {n}", flush=True)
    session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
