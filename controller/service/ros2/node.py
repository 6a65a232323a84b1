"""cablebot as a ROS 2 node on the daemon's Zenoh session, as rmw_zenoh declares one.

With `[ros2] enabled`, `Ros2Node` declares on the Zenoh interface's session (no bridge, no ROS
installation), for node `<namespace>/<node_name>` in domain `domain_id`:

- publisher `<namespace>/pose`      geometry_msgs/msg/PoseStamped, the estimated pose in
  `frame_id` (identity orientation), one per published tick while the pose is valid
- publisher `<namespace>/cables`    sensor_msgs/msg/JointState, one joint `cable<i>` per cable:
  position = length (m), velocity = its rate between encoder readings (m/s; empty on the
  first), effort = measured tension (N; empty unless every cable's is known)
- publisher `<namespace>/state`     std_msgs/msg/String, the JSON of `<prefix>/state`
  (`{"state", "reason", "stamp_ns"}`) on every change and again every second
- subscription `<namespace>/goal_pose` geometry_msgs/msg/PoseStamped: a `move` to its position
- subscription `<namespace>/cmd_vel`   geometry_msgs/msg/Twist: velocity input (its linear part,
  in `frame_id`), with the controller's dead-man

and the liveliness tokens (node, each publisher and subscription) under `@ros2_lv`. A goal
pose or twist goes through exactly what the JSON `move` and `<prefix>/velocity` go through
(the workspace pre-check and `Controller.submit`); a refusal or a malformed message is logged
(rate limited) and counted in the status (`ros2`), never raised and never moves anything.

Publishing: the tick hands the sample to this node's thread (one-slot, latest wins, like the
JSON publisher thread); that thread encodes (CDR, attachment) and puts.
"""

from __future__ import annotations

import concurrent.futures
import logging
import threading
import time
from collections.abc import Sequence
from typing import Any

import zenoh

from controller.core.commands import CommandRefused, Move, Velocity, clip
from controller.service.ros2 import cdr, wire
from controller.service.ros2.typehash import dds_type_name, type_hash
from controller.service.zenoh_io import _RateLimitedLog, dumps

log = logging.getLogger(__name__)

POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
JOINT_STATE = "sensor_msgs/msg/JointState"
STRING = "std_msgs/msg/String"
TWIST = "geometry_msgs/msg/Twist"
STATE_REPEAT_S = 1.0
"""The state is published again this often, so a late `ros2 topic echo` sees it."""


def _get(cfg: Any, name: str, default: Any) -> Any:
    value = getattr(cfg, name, default) if cfg is not None else default
    return default if value is None else value


class Endpoint:
    """One topic of the node: its key expression, liveliness token, GID and sequence number."""

    def __init__(
        self,
        kind: str,
        entity_id: int,
        topic: str,
        type_name: str,
        *,
        domain_id: int,
        zid: str,
        namespace: str,
        node_name: str,
    ) -> None:
        dds, th = dds_type_name(type_name), type_hash(type_name)
        self.topic = topic
        self.key = wire.topic_key(domain_id, topic, dds, th)
        self.token = wire.endpoint_token(
            kind, domain_id, zid, 0, entity_id, namespace, node_name, topic, dds, th, wire.Qos()
        )
        self.gid = wire.gid(self.token)
        self.seq = 0

    def attachment(self) -> bytes:
        """The next sample's attachment (sequence numbers start at 1, as rmw_zenoh's)."""
        self.seq += 1
        return wire.encode_attachment(self.seq, time.time_ns(), self.gid)


class SampleEncoder:
    """PoseSample -> CDR payloads of the pose and cables topics. No I/O; one instance per
    publishing thread (it keeps the previous lengths for the cable velocities)."""

    def __init__(self, frame_id: str) -> None:
        self.frame_id = frame_id
        self._pose = cdr.PoseStampedEncoder(frame_id)
        self._joints: cdr.JointStateEncoder | None = None
        self._prev: tuple[int, Sequence[float]] | None = None
        self._vel: list[float] = []
        self._vel_known = False

    def pose(self, sample: Any) -> bytes | None:
        """PoseStamped payload, or None when the pose is not valid (nothing is published)."""
        pos = sample.position_m
        if pos is None or not sample.valid:
            return None
        try:
            return self._pose.encode(sample.stamp_ns, pos)
        except cdr.CdrError:
            return None

    def cables(self, sample: Any) -> bytes | None:
        """JointState payload, or None when a length is not finite (nothing is published)."""
        lengths = sample.cable_lengths_m
        n = len(lengths)
        if self._joints is None or len(self._vel) != n:
            self._joints = cdr.JointStateEncoder(self.frame_id, [f"cable{i}" for i in range(n)])
            self._vel = [0.0] * n
            self._prev = None
            self._vel_known = False
        stamp = int(sample.stamp_ns)
        velocity: list[float] | None = None
        prev = self._prev
        if prev is not None and stamp > prev[0]:
            dt_s = (stamp - prev[0]) * 1e-9
            vel = self._vel
            for i in range(n):
                vel[i] = (lengths[i] - prev[1][i]) / dt_s
            velocity = vel
            self._vel_known = True
        elif prev is not None and stamp == prev[0] and self._vel_known:
            velocity = self._vel  # the same encoder reading as the last sample: its rate
        else:
            self._vel_known = False
        measured = sample.measured_tensions_n
        effort = None
        if measured is not None and len(measured) == n and None not in measured:
            effort = measured
        try:
            data = self._joints.encode(stamp, lengths, velocity, effort)
        except cdr.CdrError:
            try:  # a non-finite velocity or effort: the lengths alone
                data = self._joints.encode(stamp, lengths)
            except cdr.CdrError:
                return None
        if prev is None or stamp != prev[0]:
            self._prev = (stamp, lengths)
        return data


class _Handoff:
    """Latest pose wins; states queue; the thread also repeats the last state every
    STATE_REPEAT_S."""

    def __init__(self, node: Ros2Node) -> None:
        self._node = node
        self._cond = threading.Condition()
        self._item: Any = None
        self._states: list[bytes] = []
        self._closed = False
        self.overwritten = 0
        self._thread = threading.Thread(target=self._run, name="cablebot-ros2-pub", daemon=True)
        self._thread.start()

    def offer(self, sample: Any) -> None:
        with self._cond:
            if self._item is not None:
                self.overwritten += 1
            self._item = sample
            self._cond.notify()

    def offer_state(self, data: bytes) -> None:
        with self._cond:
            if len(self._states) < 64:
                self._states.append(data)
            self._cond.notify()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._thread.join(timeout=1.0)

    def _run(self) -> None:
        node = self._node
        last_state: bytes | None = None
        next_repeat = time.monotonic() + STATE_REPEAT_S
        while True:
            with self._cond:
                while self._item is None and not self._states and not self._closed:
                    remaining = next_repeat - time.monotonic()
                    if remaining <= 0.0:
                        break
                    self._cond.wait(remaining)
                item, self._item = self._item, None
                states, self._states = self._states, []
                closed = self._closed
            if closed:
                return
            try:  # never let the publisher thread die
                now = time.monotonic()
                if states:
                    for data in states:
                        node.put_state(data)
                    last_state = states[-1]
                    next_repeat = now + STATE_REPEAT_S
                elif now >= next_repeat:
                    if last_state is not None:
                        node.put_state(last_state)
                    next_repeat = now + STATE_REPEAT_S
                if item is not None:
                    node.put_sample(item)
            except Exception as exc:
                log.warning("ROS 2 publisher thread: %s", exc)


class Ros2Node:
    """The ROS 2 node on an open `ZenohInterface` (`iface`: its `session`, `controller` and
    `precheck`). `rcfg` is a `Ros2Config`-like object (domain_id, namespace, node_name,
    frame_id). Nothing is declared until `open()`. A `Publisher` for the loop."""

    def __init__(self, rcfg: Any, iface: Any) -> None:
        self.iface = iface
        self.controller = iface.controller
        self.domain_id = int(_get(rcfg, "domain_id", 0))
        ns = str(_get(rcfg, "namespace", "/cablebot"))
        self.namespace = ns.rstrip("/") or "/"
        self.node_name = str(_get(rcfg, "node_name", "cablebot"))
        self.frame_id = str(_get(rcfg, "frame_id", "world"))
        self._session: zenoh.Session | None = None
        self._declared: list[Any] = []
        self._pubs: dict[str, Any] = {}
        self._ep: dict[str, Endpoint] = {}
        self._handoff: _Handoff | None = None
        self._encoder = SampleEncoder(self.frame_id)
        self._lock = threading.Lock()
        self.counts: dict[str, dict[str, int]] = {
            "goal_pose": {"ok": 0, "refused": 0, "malformed": 0},
            "cmd_vel": {"ok": 0, "refused": 0, "malformed": 0},
        }
        self.published = {"pose": 0, "cables": 0, "state": 0, "skipped": 0, "put_errors": 0}
        self._log = _RateLimitedLog(1.0)

    def topic(self, name: str) -> str:
        """The absolute ROS name of this node's topic `name`."""
        return f"{self.namespace}/{name}" if self.namespace != "/" else f"/{name}"

    # ---------------------------------------------------------------- lifecycle

    def open(self) -> None:
        """Declare the publishers, subscribers and liveliness tokens on the interface's session.
        Raises RuntimeError if the session is not open, zenoh.ZError if a declaration fails
        (after undeclaring what was declared)."""
        session = self.iface.session
        if session is None:
            raise RuntimeError("the Zenoh interface is not open")
        self._session = session
        zid = str(session.zid())
        plan = [
            ("pose", wire.PUBLISHER, POSE_STAMPED),
            ("cables", wire.PUBLISHER, JOINT_STATE),
            ("state", wire.PUBLISHER, STRING),
            ("goal_pose", wire.SUBSCRIPTION, POSE_STAMPED),
            ("cmd_vel", wire.SUBSCRIPTION, TWIST),
        ]
        try:
            liveliness = session.liveliness()
            node_token = wire.node_token(self.domain_id, zid, 0, self.namespace, self.node_name)
            self._declared.append(liveliness.declare_token(node_token))
            for entity_id, (name, kind, type_name) in enumerate(plan, start=1):
                ep = Endpoint(
                    kind,
                    entity_id,
                    self.topic(name),
                    type_name,
                    domain_id=self.domain_id,
                    zid=zid,
                    namespace=self.namespace,
                    node_name=self.node_name,
                )
                self._ep[name] = ep
                if kind == wire.PUBLISHER:
                    self._pubs[name] = session.declare_publisher(
                        ep.key, congestion_control=zenoh.CongestionControl.DROP
                    )
                else:
                    handler = self._on_goal_pose if name == "goal_pose" else self._on_cmd_vel
                    self._declared.append(session.declare_subscriber(ep.key, handler))
                self._declared.append(liveliness.declare_token(ep.token))
            self._handoff = _Handoff(self)
        except Exception:
            self.close()
            raise
        log.info(
            "ROS 2 (rmw_zenoh) node %s in domain %d: %s",
            self.topic(self.node_name),
            self.domain_id,
            ", ".join(ep.topic for ep in self._ep.values()),
        )

    def close(self) -> None:
        """Stop the publisher thread and undeclare everything (idempotent, never raises)."""
        if self._handoff is not None:
            self._handoff.close()
            self._handoff = None
        objs = [*self._declared, *self._pubs.values()]
        self._declared, self._pubs = [], {}
        for obj in reversed(objs):
            try:
                obj.undeclare()
            except Exception as exc:
                log.debug("undeclare: %s", exc)
        self._session = None

    # ---------------------------------------------------------------- Publisher (loop thread)

    def publish_pose(self, sample: Any) -> None:
        """Hand the sample to the publisher thread (never blocks on the network)."""
        if self._handoff is not None:
            self._handoff.offer(sample)

    def publish_state(self, state: str, reason: str | None, stamp_ns: int) -> None:
        """Queue a state change for `<namespace>/state`."""
        if self._handoff is not None:
            data = dumps({"state": str(state), "reason": reason, "stamp_ns": int(stamp_ns)})
            self._handoff.offer_state(cdr.encode_string(data.decode()))

    # ---------------------------------------------------------------- publisher thread

    def _put(self, name: str, payload: bytes) -> bool:
        pub, ep = self._pubs.get(name), self._ep.get(name)
        if pub is None or ep is None:
            return False
        try:
            pub.put(payload, attachment=ep.attachment())
        except Exception as exc:
            self.published["put_errors"] += 1
            self._log.warning("ROS 2 %s put failed: %s", name, exc)
            return False
        self.published[name] += 1
        return True

    def put_sample(self, sample: Any) -> None:
        """Encode and put one pose sample on the pose and cables topics (publisher thread)."""
        pose = self._encoder.pose(sample)
        if pose is None:
            self.published["skipped"] += 1
        else:
            self._put("pose", pose)
        cables = self._encoder.cables(sample)
        if cables is not None:
            self._put("cables", cables)

    def put_state(self, data: bytes) -> None:
        """Put one std_msgs/String payload on the state topic (publisher thread)."""
        self._put("state", data)

    # ---------------------------------------------------------------- statistics

    def stats(self) -> dict[str, Any]:
        """Counters: messages published per topic, and per subscription ok/refused/malformed."""
        with self._lock:
            counts = {k: dict(v) for k, v in self.counts.items()}
        return {
            "node": self.topic(self.node_name),
            "domain_id": self.domain_id,
            "published": dict(self.published),
            "pose_overwritten": self._handoff.overwritten if self._handoff is not None else 0,
            **counts,
        }

    def _count(self, topic: str, outcome: str, reason: str | None = None) -> None:
        with self._lock:
            self.counts[topic][outcome] += 1
        if reason is not None:
            self._log.warning("ROS 2 %s %s: %s", topic, outcome, clip(reason, 200))

    # ---------------------------------------------------------------- subscriptions

    def _sample_bytes(self, name: str, sample: zenoh.Sample, max_bytes: int) -> bytes | None:
        """The payload of a sample on exactly this topic's key, or None (counted)."""
        key = self._ep[name].key
        if str(sample.key_expr) != key:
            # A put on a wildcard must not drive every robot that hears it.
            self._count(name, "malformed", f"needs the exact key {key}, not a wildcard")
            return None
        size = len(sample.payload)
        if size > max_bytes:  # before any copy
            self._count(name, "malformed", f"payload of {size} bytes, at most {max_bytes}")
            return None
        return sample.payload.to_bytes()

    def _on_goal_pose(self, sample: zenoh.Sample) -> None:
        try:
            data = self._sample_bytes("goal_pose", sample, cdr.MAX_POSE_STAMPED_BYTES)
            if data is None:
                return
            try:
                msg = cdr.decode_pose_stamped(data)
            except cdr.CdrError as exc:
                self._count("goal_pose", "malformed", str(exc))
                return
            if msg.frame_id not in ("", self.frame_id):
                self._count(
                    "goal_pose",
                    "refused",
                    f"frame_id {msg.frame_id!r}: goals must be in {self.frame_id!r}",
                )
                return
            cmd = Move(msg.position_m)
            reason = self.iface.precheck(cmd)
            if reason is not None:
                self._count("goal_pose", "refused", reason)
                return
            fut = self.controller.submit(cmd)
            fut.add_done_callback(self._goal_done)
        except Exception as exc:  # a bug here must not reach Zenoh
            log.exception("ROS 2 goal_pose failed")
            self._count("goal_pose", "malformed", f"internal error: {exc}")

    def _goal_done(self, fut: concurrent.futures.Future[dict[str, Any]]) -> None:
        try:
            fut.result(timeout=0)
        except CommandRefused as exc:
            self._count("goal_pose", "refused", str(exc))
            return
        except Exception as exc:
            self._count("goal_pose", "refused", f"{type(exc).__name__}: {exc}")
            return
        self._count("goal_pose", "ok")

    def _on_cmd_vel(self, sample: zenoh.Sample) -> None:
        try:
            data = self._sample_bytes("cmd_vel", sample, cdr.TWIST_BYTES + 3)
            if data is None:
                return
            try:
                msg = cdr.decode_twist(data)
            except cdr.CdrError as exc:
                self._count("cmd_vel", "malformed", str(exc))
                return
            fut = self.controller.submit(Velocity(msg.linear))
            fut.add_done_callback(self._vel_done)
        except Exception as exc:  # a bug here must not reach Zenoh
            log.exception("ROS 2 cmd_vel failed")
            self._count("cmd_vel", "malformed", f"internal error: {exc}")

    def _vel_done(self, fut: concurrent.futures.Future[dict[str, Any]]) -> None:
        try:
            fut.result(timeout=0)
        except CommandRefused as exc:
            self._count("cmd_vel", "refused", str(exc))
            return
        except Exception as exc:
            self._count("cmd_vel", "refused", f"{type(exc).__name__}: {exc}")
            return
        self._count("cmd_vel", "ok")
