"""cablebot as a ROS 2 node (rmw_zenoh wire format) in the real daemon process.

A separate Zenoh session plays the ROS 2 side: it finds the node, publishers and subscriptions
by their liveliness tokens, decodes every published message with rosbags and compares it with
the JSON pose of the same tick, and writes goal poses and twists serialized by rosbags (an
independent CDR implementation) that must move the robot within its limits; malformed CDR is
refused and counted and moves nothing.
"""

from __future__ import annotations

import math
import queue
import random
import time
import tomllib
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import zenoh
from rosbags.typesys import Stores, get_typestore

from controller.service.ros2 import typehash, wire
from tests.daemon_procs import CABLEBOT, Proc, to_toml, zenoh_session
from tests.service.test_zenoh_daemon import Daemon, ensure_state, strict_json
from tests.service.test_zenoh_daemon import write_config as zenoh_config

pytestmark = pytest.mark.slow

TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types
POSE_T, JOINT_T = "geometry_msgs/msg/PoseStamped", "sensor_msgs/msg/JointState"
STRING_T, TWIST_T = "std_msgs/msg/String", "geometry_msgs/msg/Twist"
MAX_SPEED_MPS = 2.0  # the paper robot's limits.max_speed_mps


@dataclass
class Ros:
    d: Daemon
    domain_id: int
    namespace: str
    frame_id: str
    pose_q: queue.Queue[tuple[Any, bytes, str]]
    cables_q: queue.Queue[tuple[Any, bytes, str]]
    state_q: queue.Queue[tuple[Any, bytes, str]]
    json_poses: dict[int, dict[str, Any]]

    def key(self, name: str, type_name: str) -> str:
        return wire.topic_key(
            self.domain_id,
            f"{self.namespace}/{name}",
            typehash.dds_type_name(type_name),
            typehash.type_hash(type_name),
        )

    def put(self, name: str, type_name: str, payload: bytes) -> None:
        att = wire.encode_attachment(1, time.time_ns(), bytes(16))
        self.d.session.put(self.key(name, type_name), payload, attachment=att)

    def ros2_stats(self) -> dict[str, Any]:
        st = self.d.status()["ros2"]
        assert isinstance(st, dict)
        return st


def _queue_sub(session: Any, key: str) -> queue.Queue[tuple[Any, bytes, str]]:
    q: queue.Queue[tuple[Any, bytes, str]] = queue.Queue()

    def on(sample: zenoh.Sample) -> None:
        att = sample.attachment.to_bytes() if sample.attachment is not None else b""
        q.put((att, sample.payload.to_bytes(), str(sample.key_expr)))

    session.declare_subscriber(key, on)
    return q


@pytest.fixture(scope="module")
def ros(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Ros]:
    tmp = tmp_path_factory.mktemp("ros2")
    path, endpoint, prefix = zenoh_config(tmp)
    data = tomllib.loads(Path(path).read_text())
    domain_id = random.randint(1, 200)
    namespace = f"/cb{uuid.uuid4().hex[:6]}"
    data["ros2"] = {
        "enabled": True,
        "domain_id": domain_id,
        "namespace": namespace,
        "node_name": "rig",
        "frame_id": "stage",
    }
    path.write_text(to_toml(data))
    proc = Proc([*CABLEBOT, "run", "--config", str(path), "--status-every", "0"], "daemon")
    session = None
    try:
        session = zenoh_session(endpoint, 30.0)
        poses: queue.Queue[dict[str, Any]] = queue.Queue()
        json_poses: dict[int, dict[str, Any]] = {}

        def on_json(s: zenoh.Sample) -> None:
            p = strict_json(s.payload.to_bytes())
            poses.put(p)
            json_poses[p["stamp_ns"]] = p

        session.declare_subscriber(f"{prefix}/pose", on_json)
        d = Daemon(proc, endpoint, prefix, session, poses, queue.Queue())
        r = Ros(d, domain_id, namespace, "stage", queue.Queue(), queue.Queue(), queue.Queue(), {})
        r.json_poses = json_poses
        r.pose_q = _queue_sub(session, r.key("pose", POSE_T))
        r.cables_q = _queue_sub(session, r.key("cables", JOINT_T))
        r.state_q = _queue_sub(session, r.key("state", STRING_T))
        d.wait_state("HOLDING", 30.0)
        yield r
    finally:
        if session is not None:
            session.close()
        rc = proc.terminate(10.0)
        assert rc == 0, proc.log()


def _pose_cdr(p: tuple[float, float, float], frame: str) -> bytes:
    msg = T[POSE_T](
        header=T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=2), frame_id=frame
        ),
        pose=T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
            orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        ),
    )
    return bytes(TS.serialize_cdr(msg, POSE_T))


def _twist_cdr(v: tuple[float, float, float]) -> bytes:
    v3 = T["geometry_msgs/msg/Vector3"]
    msg = T[TWIST_T](linear=v3(x=v[0], y=v[1], z=v[2]), angular=v3(x=0.0, y=0.0, z=0.0))
    return bytes(TS.serialize_cdr(msg, TWIST_T))


def _wait(pred: Any, timeout_s: float, what: str, log: Any) -> None:
    deadline = time.monotonic() + timeout_s
    while not pred():
        assert time.monotonic() < deadline, f"{what}\n{log()}"
        time.sleep(0.02)


# ------------------------------------------------------------------------------ the graph


def test_liveliness_tokens_declare_the_node_and_its_topics(ros: Ros) -> None:
    keys = sorted(
        str(r.ok.key_expr)
        for r in ros.d.session.liveliness().get(f"@ros2_lv/{ros.domain_id}/**", timeout=10.0)
        if r.ok is not None
    )
    nodes = [k for k in keys if k.split("/")[5] == "NN"]
    assert len(nodes) == 1, keys
    zid = nodes[0].split("/")[2]
    ns = ros.namespace[1:]
    assert nodes[0] == f"@ros2_lv/{ros.domain_id}/{zid}/0/0/NN/%/%{ns}/rig"
    qos = "::,10:,:,:,,"
    want = {
        nodes[0],
        *(
            f"@ros2_lv/{ros.domain_id}/{zid}/0/{i}/{kind}/%/%{ns}/rig/%{ns}%{topic}/"
            f"{typehash.dds_type_name(t)}/{typehash.type_hash(t)}/{qos}"
            for i, kind, topic, t in (
                (1, "MP", "pose", POSE_T),
                (2, "MP", "cables", JOINT_T),
                (3, "MP", "state", STRING_T),
                (4, "MS", "goal_pose", POSE_T),
                (5, "MS", "cmd_vel", TWIST_T),
            )
        ),
    }
    assert set(keys) == want


# ------------------------------------------------------------------------------ publishing


def test_published_messages_decode_with_rosbags_to_the_json_pose(ros: Ros) -> None:
    ensure_state(ros.d, "HOLDING")
    for q in (ros.pose_q, ros.cables_q):
        while not q.empty():
            q.get_nowait()
    matched = 0
    seqs: list[int] = []
    pose_gid = None
    deadline = time.monotonic() + 20.0
    while matched < 20:
        assert time.monotonic() < deadline, ros.d.proc.log()
        att, payload, key = ros.pose_q.get(timeout=10.0)
        assert key == ros.key("pose", POSE_T)
        seq, src_ns, gid = wire.decode_attachment(att)
        assert abs(src_ns - time.time_ns()) < 60 * 10**9
        assert pose_gid in (None, gid)
        pose_gid = gid
        seqs.append(seq)
        msg = TS.deserialize_cdr(payload, POSE_T)
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        assert msg.header.frame_id == "stage"
        o = msg.pose.orientation
        assert (o.x, o.y, o.z, o.w) == (0.0, 0.0, 0.0, 1.0)
        j = ros.json_poses.get(stamp)
        if j is None:
            continue  # the JSON sample of that tick has not arrived (or was overwritten)
        assert j["valid"] is True
        p = msg.pose.position
        assert [p.x, p.y, p.z] == j["position_m"]
        matched += 1
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)

    matched = 0
    deadline = time.monotonic() + 20.0
    while matched < 20:
        assert time.monotonic() < deadline, ros.d.proc.log()
        att, payload, _ = ros.cables_q.get(timeout=10.0)
        wire.decode_attachment(att)
        js = TS.deserialize_cdr(payload, JOINT_T)
        assert list(js.name) == ["cable0", "cable1", "cable2", "cable3"]
        assert js.header.frame_id == "stage"
        assert len(js.velocity) in (0, 4) and all(map(math.isfinite, js.velocity))
        assert len(js.effort) == 0  # the kinematic simulator measures no tension
        stamp = js.header.stamp.sec * 10**9 + js.header.stamp.nanosec
        j = ros.json_poses.get(stamp)
        if j is None:
            continue
        assert list(js.position) == j["cable_lengths_m"]
        matched += 1


def test_state_is_published_as_a_string_and_repeated(ros: Ros) -> None:
    while not ros.state_q.empty():
        ros.state_q.get_nowait()
    _, payload, _ = ros.state_q.get(timeout=10.0)  # repeated every second
    text = TS.deserialize_cdr(payload, STRING_T).data
    st = strict_json(text)
    assert st["state"] in ("HOLDING", "MOVING") and "stamp_ns" in st


# ------------------------------------------------------------------------------ commands


def test_goal_pose_written_by_rosbags_moves_the_robot(ros: Ros) -> None:
    ensure_state(ros.d, "HOLDING")
    before = ros.ros2_stats()["goal_pose"]
    start = ros.d.status()["pose"]["position_m"]
    target = (round(start[0] + 0.15, 3), round(start[1] - 0.1, 3), round(start[2] - 0.1, 3))
    ros.put("goal_pose", POSE_T, _pose_cdr(target, "stage"))

    def arrived() -> bool:
        st = ros.d.status()
        pos = st["pose"]["position_m"]
        return st["state"] == "HOLDING" and pos is not None and math.dist(pos, target) < 1e-3

    _wait(arrived, 30.0, "the goal pose was not reached", ros.d.proc.log)
    after = ros.ros2_stats()["goal_pose"]
    assert after["ok"] == before["ok"] + 1
    assert after["refused"] == before["refused"]
    assert after["malformed"] == before["malformed"]


def test_goal_pose_out_of_the_workspace_or_frame_is_refused_and_counted(ros: Ros) -> None:
    ensure_state(ros.d, "HOLDING")
    before = ros.ros2_stats()["goal_pose"]
    start = ros.d.status()["setpoint_m"]
    ros.put("goal_pose", POSE_T, _pose_cdr((500.0, 0.0, 2.0), "stage"))
    ros.put("goal_pose", POSE_T, _pose_cdr((0.0, 0.0, 2.0), "map"))
    _wait(
        lambda: ros.ros2_stats()["goal_pose"]["refused"] == before["refused"] + 2,
        10.0,
        "refusals not counted",
        ros.d.proc.log,
    )
    st = ros.d.status()
    assert st["state"] == "HOLDING"
    assert st["setpoint_m"] == start


def test_twist_flies_within_the_speed_limit_and_the_dead_man_stops_it(ros: Ros) -> None:
    ensure_state(ros.d, "HOLDING")
    before = ros.ros2_stats()["cmd_vel"]
    x0 = ros.d.status()["pose"]["position_m"][0]
    t0_ns = time.time_ns()
    sent = 0
    t_end = time.monotonic() + 1.5
    while time.monotonic() < t_end:
        ros.put("cmd_vel", TWIST_T, _twist_cdr((50.0, 0.0, 0.0)))  # far above the limit
        sent += 1
        time.sleep(0.05)  # the sender's rate (20 Hz), not synchronisation

    def at_rest() -> bool:
        a = ros.d.status()
        if a["state"] != "HOLDING":
            return False
        p1 = ros.d.latest_pose()["position_m"]
        p2 = ros.d.latest_pose()["position_m"]
        return math.dist(p1, p2) < 1e-4

    _wait(at_rest, 15.0, "the dead-man did not bring the robot to rest", ros.d.proc.log)
    x1 = ros.d.status()["pose"]["position_m"][0]
    assert x1 - x0 > 0.05, (x0, x1)
    speeds = []
    prev = None
    window = sorted(
        (p for stamp, p in list(ros.json_poses.items()) if stamp >= t0_ns),
        key=lambda p: int(p["stamp_ns"]),
    )
    for p in window:
        if prev is not None and p["valid"] and prev["valid"]:
            dt = (p["stamp_ns"] - prev["stamp_ns"]) * 1e-9
            if dt > 0.005:
                speeds.append(math.dist(p["position_m"], prev["position_m"]) / dt)
        prev = p
    assert speeds and max(speeds) <= MAX_SPEED_MPS * 1.1, max(speeds)
    after = ros.ros2_stats()["cmd_vel"]
    assert after["ok"] >= before["ok"] + sent // 2
    assert after["malformed"] == before["malformed"]


def test_malformed_cdr_is_refused_counted_and_moves_nothing(ros: Ros) -> None:
    ensure_state(ros.d, "HOLDING")
    before = ros.ros2_stats()
    start = ros.d.status()["setpoint_m"]
    nan_twist = b"\x00\x01\x00\x00" + bytes(16) + b"\x00" * 6 + b"\xf8\x7f" + bytes(24)
    bad_goals = [
        b"",
        b"\x00\x01",
        b"\x07\x07\x00\x00" + bytes(80),
        _pose_cdr((0.1, 0.1, 1.9), "stage")[:-9],
        _pose_cdr((0.1, 0.1, 1.9), "stage") + bytes(16),
        bytes(5000),
        _pose_cdr((0.1, 0.1, 1.9), "stage")[:-8] + b"\x00" * 6 + b"\xf8\x7f",  # w = NaN
    ]
    bad_twists = [b"", b"\x00\x01\x00\x00" + bytes(20), bytes(4096), nan_twist]
    for b in bad_goals:
        ros.put("goal_pose", POSE_T, b)
    for b in bad_twists:
        ros.put("cmd_vel", TWIST_T, b)
    # a wildcard put reaches the subscriber too, and is refused
    ros.d.session.put(
        f"{ros.domain_id}/{ros.namespace[1:]}/cmd_vel/*/*", _twist_cdr((0.3, 0.0, 0.0))
    )

    def counted() -> bool:
        st = ros.ros2_stats()
        return (
            st["goal_pose"]["malformed"] == before["goal_pose"]["malformed"] + len(bad_goals)
            and st["cmd_vel"]["malformed"] == before["cmd_vel"]["malformed"] + len(bad_twists) + 1
        )

    _wait(counted, 10.0, "malformed messages not counted", ros.d.proc.log)
    st = ros.ros2_stats()
    assert st["goal_pose"]["ok"] == before["goal_pose"]["ok"]
    assert st["cmd_vel"]["ok"] == before["cmd_vel"]["ok"]
    status = ros.d.status()
    assert status["state"] == "HOLDING"
    assert status["setpoint_m"] == start
