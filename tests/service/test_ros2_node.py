"""The ROS 2 node's pieces without a daemon: sample encoding, fan-out, config, bench figure."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import pytest
from rosbags.typesys import Stores, get_typestore

from controller.service.config import ConfigError, load_config, paper_robot_data
from controller.service.pose import FanOutPublisher, PoseSample
from controller.service.ros2.bench import measure_publish_cost
from controller.service.ros2.node import SampleEncoder, _Handoff
from tests.daemon_procs import to_toml

TS = get_typestore(Stores.ROS2_JAZZY)


def _sample(stamp_ns: int, lengths: tuple[float, ...], **kw: Any) -> PoseSample:
    base: dict[str, Any] = {
        "seq": 1,
        "stamp_ns": stamp_ns,
        "position_m": (0.5, -0.25, 2.0),
        "cable_lengths_m": lengths,
        "residual_m": 0.0,
        "valid": True,
        "state": "HOLDING",
    }
    base.update(kw)
    return PoseSample(**base)


def test_cable_velocity_is_the_length_rate_between_samples() -> None:
    enc = SampleEncoder("world")
    first = TS.deserialize_cdr(
        enc.cables(_sample(10**18, (1.0, 2.0))), "sensor_msgs/msg/JointState"
    )
    assert list(first.position) == [1.0, 2.0]
    assert len(first.velocity) == 0  # unknown on the first sample
    second = enc.cables(_sample(10**18 + 10_000_000, (1.01, 1.98)))
    js = TS.deserialize_cdr(second, "sensor_msgs/msg/JointState")
    assert js.velocity == pytest.approx([1.0, -2.0])
    assert len(js.effort) == 0
    # the next tick saw no new encoder reading (same stamp): the same rate, not an empty one
    again = enc.cables(_sample(10**18 + 10_000_000, (1.01, 1.98)))
    assert list(TS.deserialize_cdr(again, "sensor_msgs/msg/JointState").velocity) == list(
        js.velocity
    )
    third = enc.cables(_sample(10**18 + 20_000_000, (1.03, 1.98)))
    js3 = TS.deserialize_cdr(third, "sensor_msgs/msg/JointState")
    assert js3.velocity == pytest.approx([2.0, 0.0])


def test_effort_is_the_measured_tension_only_when_every_cable_has_one() -> None:
    enc = SampleEncoder("world")
    some = _sample(1, (1.0, 2.0), measured_tensions_n=(10.0, None))
    js = TS.deserialize_cdr(enc.cables(some), "sensor_msgs/msg/JointState")
    assert len(js.effort) == 0
    full = _sample(2, (1.0, 2.0), measured_tensions_n=(10.0, 12.5))
    js = TS.deserialize_cdr(enc.cables(full), "sensor_msgs/msg/JointState")
    assert list(js.effort) == [10.0, 12.5]


def test_an_invalid_or_non_finite_pose_is_not_published() -> None:
    enc = SampleEncoder("world")
    assert enc.pose(_sample(1, (1.0,), valid=False, position_m=None)) is None
    assert enc.pose(_sample(1, (1.0,), position_m=(0.0, math.nan, 1.0))) is None
    assert enc.cables(_sample(1, (1.0, math.inf))) is None
    msg = TS.deserialize_cdr(enc.pose(_sample(5, (1.0,))), "geometry_msgs/msg/PoseStamped")
    p = msg.pose.position
    assert (p.x, p.y, p.z) == (0.5, -0.25, 2.0)


class _Rec:
    def __init__(self, fail: bool = False) -> None:
        self.fail = fail
        self.poses: list[Any] = []
        self.states: list[Any] = []

    def publish_pose(self, sample: Any) -> None:
        self.poses.append(sample)
        if self.fail:
            raise RuntimeError("down")

    def publish_state(self, state: str, reason: str | None, stamp_ns: int) -> None:
        self.states.append(state)
        if self.fail:
            raise RuntimeError("down")


def test_fan_out_reaches_every_publisher_even_after_one_fails() -> None:
    a, b = _Rec(fail=True), _Rec()
    fan = FanOutPublisher(a, b)
    s = _sample(1, (1.0,))
    with pytest.raises(RuntimeError):
        fan.publish_pose(s)
    with pytest.raises(RuntimeError):
        fan.publish_state("HOLDING", None, 1)
    assert a.poses == b.poses == [s]
    assert a.states == b.states == ["HOLDING"]


def _load(tmp_path: Path, ros2: dict[str, Any] | None) -> Any:
    data = paper_robot_data("r2")
    if ros2 is not None:
        data["ros2"] = ros2
    path = tmp_path / "r.toml"
    path.write_text(to_toml(data))
    return load_config(path)


def test_ros2_config_defaults_and_values(tmp_path: Path) -> None:
    cfg = _load(tmp_path, None)
    assert cfg.ros2.enabled is False
    assert (cfg.ros2.domain_id, cfg.ros2.namespace, cfg.ros2.node_name) == (
        0,
        "/cablebot",
        "cablebot",
    )
    cfg = _load(
        tmp_path, {"enabled": True, "domain_id": 7, "namespace": "/lab/rig/", "frame_id": "map"}
    )
    assert (cfg.ros2.enabled, cfg.ros2.domain_id, cfg.ros2.namespace) == (True, 7, "/lab/rig")
    assert cfg.ros2.frame_id == "map"


@pytest.mark.parametrize(
    ("table", "words"),
    [
        ({"namespace": "cablebot"}, "ros2.namespace"),
        ({"namespace": "/a b"}, "ros2.namespace"),
        ({"node_name": "2rig"}, "ros2.node_name"),
        ({"domain_id": -1}, "ros2.domain_id"),
        ({"domain_id": 1000}, "ros2.domain_id"),
        ({"enabled": "yes"}, "ros2.enabled"),
        ({"frame": "map"}, "ros2.frame"),
    ],
)
def test_bad_ros2_config_is_refused_by_key(
    tmp_path: Path, table: dict[str, Any], words: str
) -> None:
    with pytest.raises(ConfigError, match=words.replace(".", r"\.")):
        _load(tmp_path, table)


def test_bench_figure_is_measured() -> None:
    out = measure_publish_cost(samples=50)
    for key in ("json_encode_us", "ros2_encode_us", "tick_handoff_us"):
        value = out[key]
        assert value is not None and value > 0.0, out
    assert out["rosbags_encode_us"] is not None  # rosbags is a test dependency


class _Sink:
    def __init__(self) -> None:
        self.states: list[bytes] = []

    def put_sample(self, sample: Any) -> None:
        pass

    def put_state(self, data: bytes) -> None:
        self.states.append(data)


def test_the_publisher_thread_idles_without_spinning_and_repeats_the_state() -> None:
    sink = _Sink()
    handoff = _Handoff(sink)  # type: ignore[arg-type]
    try:
        cpu0, t0 = time.thread_time(), time.process_time()
        idle_until = time.monotonic() + 2.5  # past the first repeat time, nothing to repeat
        while time.monotonic() < idle_until:
            time.sleep(0.05)
        spent = (time.process_time() - t0) - (time.thread_time() - cpu0)
        handoff.offer_state(b"s")
        deadline = time.monotonic() + 20.0
        while len(sink.states) < 3:  # the change, then a repeat every STATE_REPEAT_S
            assert time.monotonic() < deadline, sink.states
            time.sleep(0.05)
    finally:
        handoff.close()
    assert sink.states[:3] == [b"s", b"s", b"s"]
    # a spinning thread would burn about a CPU-second per idle second
    assert spent < 0.1, spent
