"""The key layout of a robot on Zenoh, under its prefix (`cablebot/<robot name>`): one place for
the daemon that declares the keys (`controller.service.zenoh_io`, the simulator's truth) and
every client that uses them (`controller.client`). docs/zenoh.md describes each key's payload.

No imports: a client reads these names without loading Zenoh or the daemon.
"""

from __future__ import annotations

POSE = "pose"
"""The pose, one JSON sample per published tick."""
STATE = "state"
"""Every change of state."""
STATUS = "status"
"""The status queryable."""
ROBOT = "robot"
"""The robot description queryable (the daemon's robot file as loaded)."""
COMMAND = "cmd"
"""The command queryables: `cmd/<verb>` for every verb of `controller.core.commands.VERBS`."""
SETPOINT = "setpoint"
"""Streamed set-points (subscriber)."""
VELOCITY = "velocity"
"""Velocity-input samples (subscriber)."""
ALIVE = "alive"
"""The liveliness token, while the daemon's interface is open."""
TRUTH = "sim/truth"
"""The simulator's ground truth (its physical plant only)."""


def command(verb: str) -> str:
    """The key suffix of a verb's queryable: `cmd/<verb>`."""
    return f"{COMMAND}/{verb}"
