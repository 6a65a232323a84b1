"""`move/path --wait`: arrival counts only once the commanded motion has been seen."""

from __future__ import annotations

import argparse
import json
import queue

from controller.cli import client


def _sample(seq: int, state: str, x: float) -> bytes:
    return json.dumps(
        {"seq": seq, "state": state, "position_m": [x, 0.0, 2.0], "valid": True}
    ).encode()


def _args() -> argparse.Namespace:
    return argparse.Namespace(json=True, wait_timeout=5.0, timeout=1.0)


def test_stale_holding_samples_where_a_path_ends_are_not_arrival() -> None:
    # A path from (20, 0, 2) out to (21, 0, 2) and back: poses published before the daemon took
    # it stand HOLDING exactly where the path ends.
    poses: queue.Queue[bytes] = queue.Queue()
    for seq, (state, x) in enumerate(
        [
            ("HOLDING", 20.0),
            ("HOLDING", 20.0),
            ("MOVING", 20.5),
            ("MOVING", 20.4),
            ("HOLDING", 20.0),
        ]
    ):
        poses.put(_sample(seq, state, x))
    points = [[21.0, 0.0, 2.0], [20.0, 0.0, 2.0]]
    rc = client._wait_arrival(_args(), "path", poses, points, seen_moving=False)
    assert rc == client.EXIT_OK
    assert poses.empty()  # it waited through the motion to the last sample


def test_a_motion_already_over_is_arrival_at_once() -> None:
    poses: queue.Queue[bytes] = queue.Queue()
    poses.put(_sample(1, "HOLDING", 20.0))
    poses.put(_sample(2, "HOLDING", 20.0))
    rc = client._wait_arrival(_args(), "move", poses, [[20.0, 0.0, 2.0]], seen_moving=True)
    assert rc == client.EXIT_OK
    assert poses.qsize() == 1
