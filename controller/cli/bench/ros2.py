"""The ROS 2 section: what publishing ROS 2 beside JSON costs per published sample
(`controller.service.ros2.bench.measure_publish_cost`): the encodings, done on the publishers'
threads, and the tick's own added cost, the hand-off to the ROS 2 node.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from controller.cli.bench.settings import ROS2_KEYS, BenchError, Plan
from controller.cli.bench.table import Row


def bench_ros2(samples: int) -> dict[str, float | None]:
    """Median microseconds per sample of the JSON, ROS 2 and rosbags encodings and the tick's
    ROS 2 hand-off, with their ratios (`measure_publish_cost`); `rosbags_encode_us` and
    `rosbags_vs_ros2` are None without rosbags. Raises BenchError if a figure of `ROS2_KEYS`
    is missing or not finite and positive."""
    from controller.service.ros2.bench import measure_publish_cost

    got = measure_publish_cost(samples=samples)
    for key in ROS2_KEYS:
        v = got.get(key)
        if v is None or not (math.isfinite(v) and v > 0.0):
            raise BenchError(f"ROS 2 publishing: {key} is {v!r}")
    return got


def measure_ros2(p: Plan, log: Callable[[str], None]) -> tuple[dict[str, Any], list[Row]]:
    """The ROS 2 section's JSON figures (`ROS2_KEYS`) and table rows. Raises BenchError."""
    log(f"ROS 2 publishing beside JSON ({p.ros2_samples:,} samples) ...")
    f = {key: float(v) for key, v in bench_ros2(p.ros2_samples).items() if v is not None}
    rep = f"median of {p.ros2_samples:,} samples"
    rb = f.get("rosbags_encode_us")
    rows = [
        Row(
            "ros2_publish_us.tick_handoff_us",
            f["tick_handoff_us"],
            "us",
            "",
            None,
            f"{rep}; the tick's added cost (fan-out + hand-off)",
        ),
        Row(
            "ros2_publish_us.json_encode_us",
            f["json_encode_us"],
            "us",
            "",
            None,
            f"{rep}; JSON publisher thread",
        ),
        Row(
            "ros2_publish_us.ros2_encode_us",
            f["ros2_encode_us"],
            "us",
            "",
            None,
            f"{rep}; ROS 2 node's thread: PoseStamped + JointState",
        ),
        Row(
            "ros2_publish_us.ros2_vs_json",
            f["ros2_vs_json"],
            "ratio",
            "",
            None,
            (
                "rosbags not installed"
                if rb is None
                else f"rosbags encodes the same in {rb:.3g} us "
                f"({rb / f['ros2_encode_us']:.3g}x the ROS 2 node)"
            ),
        ),
    ]
    return {key: f[key] for key in ROS2_KEYS}, rows
