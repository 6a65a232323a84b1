"""The exit codes of the `cablebot` command line: one table, used by every verb.

The exit-code table of docs/operating.md is checked against `TABLE` by a test, so the two
cannot drift.
"""

from __future__ import annotations

from typing import Final

OK: Final = 0
"""Done."""
REFUSED: Final = 1
"""The daemon refused the command (its reason is printed), the input (numbers, a path or
configuration file) is invalid, `run` or `sim` could not start (Zenoh, bus), or the robot stopped
(FAULT/ESTOPPED/DISARMED) or its motion ended short of the end (another client's `stop`, or
another command) while `--wait`ed on."""
USAGE: Final = 2
"""Usage error (argparse: unknown option, missing argument, bad `--connect`); for `run`, `sim`
and `demo` also a configuration error: restarting cannot help."""
NO_DAEMON: Final = 3
"""No daemon answered: nothing listening on the endpoint, wrong prefix, no reply or no pose in
time."""
WAIT_TIMEOUT: Final = 4
"""`--wait`: the robot did not reach the end point within `--wait-timeout`."""
INTERRUPTED: Final = 130
"""Ctrl-C (SIGINT); while a motion is waited on (`--wait`, `calibrate collect --auto`) or a
job or long path streams (`gcode`, `path FILE`) also SIGTERM or SIGHUP, after sending `stop`."""
BROKEN_PIPE: Final = 141
"""The reader of the output went away (`cablebot pose | head`): stopped quietly, as a process
killed by SIGPIPE would be."""

TABLE: Final[tuple[tuple[int, str], ...]] = (
    (OK, "done"),
    (
        REFUSED,
        "refused by the daemon (its reason is printed), invalid input, or `run` or `sim` could not"
        " start (Zenoh, bus);"
        " a `--wait`ed motion ended in FAULT, ESTOPPED or DISARMED, or short of its end (another"
        " client's `stop`, another command)",
    ),
    (
        USAGE,
        "usage error (unknown option, missing argument, bad `--connect`); `run`, `sim`, `demo`:"
        " configuration error (restarting cannot help)",
    ),
    (
        NO_DAEMON,
        "no daemon answered (nothing listening, wrong `--prefix`, no reply or pose in time)",
    ),
    (WAIT_TIMEOUT, "`--wait`: not at the end point within `--wait-timeout`"),
    (
        INTERRUPTED,
        "interrupted (Ctrl-C; while a motion is waited on or a job or long path streams, also"
        " SIGTERM or SIGHUP): the robot brakes to a hold unless `--detach`",
    ),
    (BROKEN_PIPE, "the output's reader went away (e.g. `head` closed the pipe); nothing printed"),
)
"""(code, meaning) rows, in the order of the table in docs/operating.md."""
