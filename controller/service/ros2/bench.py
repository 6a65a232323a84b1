"""What publishing ROS 2 beside JSON costs, per published tick: `measure_publish_cost()`.

For the benchmark (`cablebot bench` may print it). Measured in one run, interleaved, so the
ratios hold on a noisy machine:

- `json_encode_us`: `PoseSample.to_json_bytes` (what the JSON publisher thread does per sample);
- `ros2_encode_us`: the ROS 2 node's publisher-thread work per sample, without the puts: the
  PoseStamped and JointState payloads (cable velocities included) and their two attachments;
- `rosbags_encode_us`: the same two messages serialized by rosbags (when it is installed), the
  library the hand-written encoder is checked against; None without it;
- `tick_handoff_us`: what the tick pays for the ROS 2 node beside the JSON interface: the
  fan-out and the node's one-slot hand-off (its thread runs, but puts nothing);
- the ratios `ros2_vs_json` and `rosbags_vs_ros2`.

Medians over `samples` samples per figure (microseconds; a median is robust to the
pre-emptions of a loaded machine). No network, no files.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from controller.service.pose import FanOutPublisher, NullPublisher, PoseSample
from controller.service.ros2 import node as ros2_node
from controller.service.ros2.node import Endpoint, SampleEncoder


def _samples(n: int, n_cables: int) -> list[PoseSample]:
    t0 = time.time_ns()
    return [
        PoseSample(
            seq=i,
            stamp_ns=t0 + i * 2_000_000,
            position_m=(0.1 + 1e-4 * i, -0.2, 2.0 - 1e-5 * i),
            cable_lengths_m=tuple(30.0 + 0.01 * k + 1e-4 * i for k in range(n_cables)),
            residual_m=1e-6,
            valid=True,
            state="MOVING",
            tensions_n=tuple(20.0 + k for k in range(n_cables)),
        )
        for i in range(n)
    ]


class _QuietNode:
    """The hand-off's consumer, minus the network."""

    def put_sample(self, sample: Any) -> None:
        """Drop the sample."""

    def put_state(self, data: bytes) -> None:
        """Drop the state."""


def measure_publish_cost(samples: int = 2000, n_cables: int = 4) -> dict[str, float | None]:
    """Median cost in microseconds per published sample of the JSON encoding, the ROS 2 encoding
    (hand-written CDR, and rosbags when installed) and the tick's ROS 2 hand-off, with their
    ratios. Raises ValueError if `samples` < 1."""
    if samples < 1:
        raise ValueError("samples must be at least 1")
    batch = _samples(samples, n_cables)
    enc = SampleEncoder("world")
    eps = [
        Endpoint(
            "MP",
            i,
            f"/cablebot/{name}",
            t,
            domain_id=0,
            zid="0" * 32,
            namespace="/cablebot",
            node_name="cablebot",
        )
        for i, (name, t) in enumerate(
            (("pose", ros2_node.POSE_STAMPED), ("cables", ros2_node.JOINT_STATE)), start=1
        )
    ]
    rosbags = _rosbags_encoder(n_cables)
    handoff = ros2_node._Handoff(_QuietNode())  # type: ignore[arg-type]

    class _Offer:
        def publish_pose(self, sample: PoseSample) -> None:
            handoff.offer(sample)

        def publish_state(self, state: str, reason: str | None, stamp_ns: int) -> None:
            pass

    fan = FanOutPublisher(NullPublisher(), _Offer())
    times = np.zeros((4, samples), dtype=np.int64)  # json, ros2, rosbags, handoff
    try:
        for i, s in enumerate(batch):
            t0 = time.perf_counter_ns()
            s.to_json_bytes()
            t1 = time.perf_counter_ns()
            enc.pose(s)
            eps[0].attachment()
            enc.cables(s)
            eps[1].attachment()
            t2 = time.perf_counter_ns()
            if rosbags is not None:
                rosbags(s)
            t3 = time.perf_counter_ns()
            fan.publish_pose(s)
            t4 = time.perf_counter_ns()
            times[:, i] = (t1 - t0, t2 - t1, t3 - t2, t4 - t3)
    finally:
        handoff.close()
    med = np.median(times, axis=1) / 1e3
    us = {"json": med[0], "ros2": med[1], "rosbags": med[2], "handoff": med[3]}
    return {
        "json_encode_us": float(us["json"]),
        "ros2_encode_us": float(us["ros2"]),
        "rosbags_encode_us": float(us["rosbags"]) if rosbags is not None else None,
        "tick_handoff_us": float(us["handoff"]),
        "ros2_vs_json": float(us["ros2"] / us["json"]) if us["json"] > 0 else None,
        "rosbags_vs_ros2": (
            float(us["rosbags"] / us["ros2"]) if rosbags is not None and us["ros2"] > 0 else None
        ),
    }


def _rosbags_encoder(n_cables: int) -> Any:
    """A function serializing a sample's two messages with rosbags, or None without it."""
    try:
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        return None
    ts = get_typestore(Stores.ROS2_JAZZY)
    t = ts.types
    names = [f"cable{i}" for i in range(n_cables)]

    def encode(s: PoseSample) -> None:
        sec, nanosec = divmod(s.stamp_ns, 1_000_000_000)
        header = t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id="world"
        )
        p = s.position_m or (0.0, 0.0, 0.0)
        pose = t["geometry_msgs/msg/PoseStamped"](
            header=header,
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
                orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            ),
        )
        ts.serialize_cdr(pose, "geometry_msgs/msg/PoseStamped")
        js = t["sensor_msgs/msg/JointState"](
            header=header,
            name=names,
            position=np.array(s.cable_lengths_m),
            velocity=np.zeros(n_cables),
            effort=np.array([], dtype=np.float64),
        )
        ts.serialize_cdr(js, "sensor_msgs/msg/JointState")

    return encode
