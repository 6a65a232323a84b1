"""`python -m controller.cli.bench ROLE ...`: the bench's helper processes."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from controller.cli.bench.estop import role_daemon, role_flood
from controller.cli.bench.helpers import role_sim, role_sub
from controller.cli.bench.loop import role_loop
from controller.cli.bench.settings import ESTOP_FLOOD_THREADS


def _helper_main(argv: Sequence[str]) -> int:
    """`python -m controller.cli.bench ROLE ...`: the bench's helper processes (sim, sub, loop,
    daemon, flood)."""
    p = argparse.ArgumentParser(prog="python -m controller.cli.bench")
    roles = p.add_subparsers(dest="role", required=True)
    s = roles.add_parser("sim")
    s.add_argument("--config", required=True)
    s.add_argument("--log", required=True)
    s.add_argument("--tick-s", type=float, default=0.001)
    z = roles.add_parser("sub")
    z.add_argument("--connect", required=True)
    z.add_argument("--key", required=True)
    z.add_argument("--out", required=True)
    lp = roles.add_parser("loop")
    lp.add_argument("--rate-hz", type=float, required=True)
    lp.add_argument("--seconds", type=float, required=True)
    lp.add_argument("--out", required=True)
    lp.add_argument("--drive", default="odrive", help="drive family (drivers.registry)")
    d = roles.add_parser("daemon")
    d.add_argument("--config", required=True)
    f = roles.add_parser("flood")
    f.add_argument("--connect", required=True)
    f.add_argument("--prefix", required=True)
    f.add_argument("--threads", type=int, default=ESTOP_FLOOD_THREADS)
    a = p.parse_args(argv)
    if a.role == "sim":
        return role_sim(a.config, a.log, a.tick_s)
    if a.role == "sub":
        return role_sub(a.connect, a.key, a.out)
    if a.role == "daemon":
        return role_daemon(a.config)
    if a.role == "flood":
        return role_flood(a.connect, a.prefix, a.threads)
    return role_loop(a.rate_hz, a.seconds, a.out, a.drive)


if __name__ == "__main__":
    sys.exit(_helper_main(sys.argv[1:]))
