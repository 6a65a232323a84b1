"""`cablebot view`: the robot live in 3-D, in Foxglove, from a Zenoh client process.

A Foxglove WebSocket server (the `foxglove-sdk` package: the `foxglove.websocket.v1` protocol,
named `foxglove.sdk.v1` in the handshake) fed by a Zenoh client session, like any other
subscriber: the daemon's loop does not notice it. Open the Foxglove app (desktop or browser),
connect to `ws://HOST:PORT` (default `ws://127.0.0.1:8765`) and import
`docs/foxglove-layout.json` (`layout_config()`).

Topics (Foxglove's own schemas where one fits, so the app draws them without configuration):

- `/robot`  foxglove.SceneUpdate: anchors (labelled B1..Bn), the footprint on the floor and the
  workspace's edges (its true shape: a prism for a hanging robot, the hull's faces moved in
  and cut by floor, top and print radius among the anchors); sent when a client subscribes
  and when the geometry changes.
- `/scene`  foxglove.SceneUpdate, at `--scene-hz`: each cable as a line coloured by its length
  (blue at `min_cable_m`, red at `max_cable_m`; `cable_colour` takes a tension for when the
  daemon reports one) with its length as a label, the effector, the set-point and a fading
  trail of the last `--trail-s` seconds.
- `/tf`     foxglove.FrameTransform `world` -> `effector` (the 3-D panel can follow it).
- `/state`  foxglove.Log: every state change with its reason; the daemon appearing and leaving.
- `/pose`   every pose sample as published (JSON, schema `cablebot.Pose`): per-axis figures
  (`/pose.position_m[0]`), cable lengths, the FPK residual.
- `/status` the status reply at `--status-hz` (JSON, schema `cablebot.Status`).
- `/tracking` at `--status-hz`, from each status reply: its pose, set-point and the tracking
  error |pose - set-point| (`error_m`, `error_mm`) and the residual in millimetres.

The robot's geometry (anchors, limits) comes from the daemon's status (`status["config"]`);
`--config FILE` is used only while the status carries none (e.g. no status answer yet).
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import signal
import sys
import threading
import time
from collections.abc import Sequence
from types import FrameType
from typing import TYPE_CHECKING, Any

from controller.cli.record import KEY_SCHEMAS, positive_number
from controller.cli.shape import RobotShape, ShapeError, length_colour

if TYPE_CHECKING:
    import foxglove
    from foxglove.messages import Color, Point3, SceneEntity, SceneUpdate, Timestamp

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
DEFAULT_SCENE_HZ = 30.0
DEFAULT_STATUS_HZ = 4.0
DEFAULT_TRAIL_S = 20.0
FRAME_WORLD = "world"
FRAME_EFFECTOR = "effector"
TOPICS = {
    "robot": "/robot",
    "scene": "/scene",
    "tf": "/tf",
    "state": "/state",
    "pose": "/pose",
    "status": "/status",
    "tracking": "/tracking",
}
TRACKING_SCHEMA: dict[str, Any] = {
    "title": "cablebot tracking sample",
    "type": "object",
    "properties": {
        "stamp_ns": {"type": "integer"},
        "state": {"type": "string"},
        "position_m": {"type": ["array", "null"], "items": {"type": "number"}},
        "setpoint_m": {"type": ["array", "null"], "items": {"type": "number"}},
        "error_m": {"type": ["number", "null"]},
        "error_mm": {"type": ["number", "null"]},
        "residual_mm": {"type": ["number", "null"]},
    },
}
_ALERT_STATES = ("FAULT", "ESTOPPED")


# --------------------------------------------------------------------------------------------
# Scene building (pure: data in, foxglove messages out)


def _ts(stamp_ns: int) -> Timestamp:
    from foxglove.messages import Timestamp

    return Timestamp(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)


def _pt(p: Sequence[float]) -> Point3:
    from foxglove.messages import Point3

    return Point3(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _rgba(rgb: Sequence[float], a: float = 1.0) -> Color:
    from foxglove.messages import Color

    return Color(r=float(rgb[0]), g=float(rgb[1]), b=float(rgb[2]), a=a)


def _at(p: Sequence[float]) -> Any:
    from foxglove.messages import Pose, Quaternion, Vector3

    return Pose(
        position=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
        orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
    )


def cable_colour(
    length_m: float, shape: RobotShape, tension_n: float | None = None
) -> tuple[float, float, float]:
    """The colour of a cable: by its length between the cable limits (blue short, red long).

    `tension_n` is the hook for a daemon that reports cable tension: it is not drawn yet, so a
    tension changes nothing today.
    """
    return length_colour(length_m, shape.min_cable_m, shape.max_cable_m)


def marker_size_m(shape: RobotShape | None) -> float:
    """The effector's drawn diameter: 1 % of the robot's size, at least 2 cm."""
    return max(0.02, 0.01 * shape.size_m) if shape is not None else 0.05


def robot_scene(shape: RobotShape, stamp_ns: int) -> SceneUpdate:
    """The static scene: anchors with labels, the footprint and the workspace's edges."""
    from foxglove.messages import (
        LinePrimitive,
        LinePrimitiveLineType,
        SceneEntity,
        SceneUpdate,
        SpherePrimitive,
        TextPrimitive,
        Vector3,
    )

    ts = _ts(stamp_ns)
    d = 1.5 * marker_size_m(shape)
    anchors = SceneEntity(
        timestamp=ts,
        frame_id=FRAME_WORLD,
        id="anchors",
        spheres=[
            SpherePrimitive(pose=_at(a), size=Vector3(x=d, y=d, z=d), color=_rgba((0.1, 0.1, 0.1)))
            for a in shape.anchors_m
        ],
        texts=[
            TextPrimitive(
                pose=_at((a[0], a[1], a[2] + 2 * d)),
                billboard=True,
                font_size=14.0,
                scale_invariant=True,
                color=_rgba((1.0, 1.0, 1.0)),
                text=f"B{i + 1}",
            )
            for i, a in enumerate(shape.anchors_m)
        ],
        lines=[
            LinePrimitive(
                type=LinePrimitiveLineType.LineList,
                thickness=2.0,
                scale_invariant=True,
                points=[p for a in shape.anchors_m for p in (_pt((a[0], a[1], 0.0)), _pt(a))],
                color=_rgba((0.45, 0.45, 0.45)),
            )
        ],
    )
    footprint = SceneEntity(
        timestamp=ts,
        frame_id=FRAME_WORLD,
        id="footprint",
        lines=[
            LinePrimitive(
                type=LinePrimitiveLineType.LineLoop,
                thickness=1.5,
                scale_invariant=True,
                points=[_pt((x, y, 0.0)) for x, y in shape.footprint_m],
                color=_rgba((0.6, 0.6, 0.6)),
            )
        ],
    )
    edges = [p for edge in shape.workspace_edges_m for p in edge]
    workspace = SceneEntity(
        timestamp=ts,
        frame_id=FRAME_WORLD,
        id="workspace",
        lines=[
            LinePrimitive(
                type=LinePrimitiveLineType.LineList,
                thickness=1.0,
                scale_invariant=True,
                points=[_pt(p) for p in edges],
                color=_rgba((0.17, 0.63, 0.17), 0.8),
            )
        ],
    )
    return SceneUpdate(entities=[anchors, footprint, workspace])


class Trail:
    """The effector's recent positions (the last `span_s` seconds), for a fading line."""

    def __init__(self, span_s: float) -> None:
        self.span_s = span_s
        self._points: collections.deque[tuple[float, tuple[float, float, float]]] = (
            collections.deque()
        )

    def add(self, t_s: float, p: Sequence[float]) -> None:
        """Append a position at time `t_s` and forget those older than `span_s`."""
        self._points.append((t_s, (float(p[0]), float(p[1]), float(p[2]))))
        while self._points and t_s - self._points[0][0] > self.span_s:
            self._points.popleft()

    def points(self) -> list[tuple[float, float, float]]:
        """The positions, oldest first."""
        return [p for _, p in self._points]


def pose_scene(
    shape: RobotShape | None,
    pose: dict[str, Any],
    setpoint_m: Sequence[float] | None,
    trail: Sequence[Sequence[float]],
    stamp_ns: int,
    tensions_n: Sequence[float] | None = None,
) -> SceneUpdate:
    """The moving scene for one pose: cables (needs `shape`), effector, set-point, trail.

    Entities that have nothing to show (no valid pose, no set-point) are deleted, so the view
    never draws a stale effector.
    """
    from foxglove.messages import (
        LinePrimitive,
        LinePrimitiveLineType,
        SceneEntity,
        SceneEntityDeletion,
        SceneEntityDeletionType,
        SceneUpdate,
        SpherePrimitive,
        TextPrimitive,
        Vector3,
    )

    ts = _ts(stamp_ns)
    d = marker_size_m(shape)
    entities: list[SceneEntity] = []
    deletions: list[str] = []
    pos = pose.get("position_m") if pose.get("valid") else None
    state = str(pose.get("state"))
    if pos is not None:
        colour = (0.85, 0.1, 0.1) if state in _ALERT_STATES else (1.0, 0.55, 0.0)
        entities.append(
            SceneEntity(
                timestamp=ts,
                frame_id=FRAME_WORLD,
                id="effector",
                spheres=[
                    SpherePrimitive(pose=_at(pos), size=Vector3(x=d, y=d, z=d), color=_rgba(colour))
                ],
                texts=[
                    TextPrimitive(
                        pose=_at((pos[0], pos[1], pos[2] + 1.5 * d)),
                        billboard=True,
                        font_size=13.0,
                        scale_invariant=True,
                        color=_rgba((1.0, 1.0, 1.0)),
                        text=f"P {state}",
                    )
                ],
            )
        )
    else:
        deletions.append("effector")
    lengths = pose.get("cable_lengths_m") or []
    if shape is not None and pos is not None and len(lengths) == len(shape.anchors_m):
        lines = []
        texts = []
        for i, (a, length) in enumerate(zip(shape.anchors_m, lengths, strict=True)):
            if length is None:
                continue
            tension = tensions_n[i] if tensions_n is not None else None
            rgb = cable_colour(float(length), shape, tension)
            lines.append(
                LinePrimitive(
                    type=LinePrimitiveLineType.LineStrip,
                    thickness=3.0,
                    scale_invariant=True,
                    points=[_pt(a), _pt(pos)],
                    color=_rgba(rgb),
                )
            )
            mid = [(a[k] + pos[k]) / 2.0 for k in range(3)]
            texts.append(
                TextPrimitive(
                    pose=_at(mid),
                    billboard=True,
                    font_size=12.0,
                    scale_invariant=True,
                    color=_rgba(rgb),
                    text=f"L{i + 1} {float(length):.3f} m",
                )
            )
        entities.append(
            SceneEntity(timestamp=ts, frame_id=FRAME_WORLD, id="cables", lines=lines, texts=texts)
        )
    else:
        deletions.append("cables")
    if setpoint_m is not None:
        s = 0.6 * d
        entities.append(
            SceneEntity(
                timestamp=ts,
                frame_id=FRAME_WORLD,
                id="setpoint",
                spheres=[
                    SpherePrimitive(
                        pose=_at(setpoint_m),
                        size=Vector3(x=s, y=s, z=s),
                        color=_rgba((0.1, 0.8, 0.2), 0.6),
                    )
                ],
            )
        )
    else:
        deletions.append("setpoint")
    if len(trail) >= 2:
        n = len(trail)
        entities.append(
            SceneEntity(
                timestamp=ts,
                frame_id=FRAME_WORLD,
                id="trail",
                lines=[
                    LinePrimitive(
                        type=LinePrimitiveLineType.LineStrip,
                        thickness=2.0,
                        scale_invariant=True,
                        points=[_pt(p) for p in trail],
                        colors=[_rgba((0.2, 0.6, 1.0), (k + 1) / n) for k in range(n)],
                    )
                ],
            )
        )
    return SceneUpdate(
        deletions=[
            SceneEntityDeletion(timestamp=ts, type=SceneEntityDeletionType.MatchingId, id=i)
            for i in deletions
        ],
        entities=entities,
    )


def tracking_sample(status: dict[str, Any]) -> dict[str, Any]:
    """The `/tracking` message of one status reply: its pose, set-point and their distance."""
    pose = status.get("pose") or {}
    pos = pose.get("position_m")
    sp = status.get("setpoint_m")
    err = None
    if isinstance(pos, list) and isinstance(sp, list) and len(pos) == len(sp) == 3:
        err = math.dist(pos, sp)
    res = pose.get("residual_m")
    return {
        "stamp_ns": time.time_ns(),
        "state": status.get("state"),
        "position_m": pos,
        "setpoint_m": sp,
        "error_m": err,
        "error_mm": None if err is None else err * 1e3,
        "residual_mm": None if res is None else float(res) * 1e3,
    }


# --------------------------------------------------------------------------------------------
# The live view


def _json_schema(name: str, schema: dict[str, Any]) -> foxglove.Schema:
    import foxglove

    return foxglove.Schema(name=name, encoding="jsonschema", data=json.dumps(schema).encode())


class LiveView:
    """Foxglove channels fed from Zenoh callbacks (`on_pose`, `on_state`, `on_status`,
    `on_alive`); thread-safe. `context` is the foxglove.Context the channels log to."""

    def __init__(
        self,
        context: foxglove.Context,
        *,
        prefix: str,
        scene_hz: float = DEFAULT_SCENE_HZ,
        trail_s: float = DEFAULT_TRAIL_S,
        fallback_shape: RobotShape | None = None,
    ) -> None:
        import foxglove
        from foxglove.channels import FrameTransformChannel, LogChannel, SceneUpdateChannel

        self.prefix = prefix
        self.scene_period_s = 1.0 / scene_hz
        self.trail = Trail(trail_s)
        self.fallback_shape = fallback_shape
        self.shape: RobotShape | None = fallback_shape
        self._shape_summary: str | None = None
        self._lock = threading.Lock()
        self._last_scene = -math.inf
        self._last_state: str | None = None
        self.setpoint_m: list[float] | None = None
        self.robot = SceneUpdateChannel(TOPICS["robot"], context=context)
        self.scene = SceneUpdateChannel(TOPICS["scene"], context=context)
        self.tf = FrameTransformChannel(TOPICS["tf"], context=context)
        self.log = LogChannel(TOPICS["state"], context=context)
        pose_name, pose_schema = KEY_SCHEMAS["pose"]
        status_name, status_schema = KEY_SCHEMAS["status"]
        self.pose = foxglove.Channel(
            TOPICS["pose"],
            schema=_json_schema(pose_name, pose_schema),
            message_encoding="json",
            context=context,
        )
        self.status = foxglove.Channel(
            TOPICS["status"],
            schema=_json_schema(status_name, status_schema),
            message_encoding="json",
            context=context,
        )
        self.tracking = foxglove.Channel(
            TOPICS["tracking"],
            schema=_json_schema("cablebot.Tracking", TRACKING_SCHEMA),
            message_encoding="json",
            context=context,
        )
        self.poses = 0
        self.scenes = 0

    # ------------------------------------------------------------------ inputs

    def on_pose(self, data: bytes) -> None:
        """A `<prefix>/pose` sample: forwarded as is; the scene redrawn at most at scene_hz."""
        try:
            pose = json.loads(data)
            stamp_ns = int(pose["stamp_ns"])
        except (ValueError, KeyError, TypeError):
            return
        self.pose.log(data, log_time=stamp_ns)
        self.poses += 1
        if self._last_state is None:
            self._log_state(str(pose.get("state")), "at connection", stamp_ns)
        now = time.monotonic()
        with self._lock:
            if now - self._last_scene < self.scene_period_s:
                return
            self._last_scene = now
            pos = pose.get("position_m") if pose.get("valid") else None
            if pos is not None:
                self.trail.add(now, pos)
            trail = self.trail.points()
            shape, setpoint = self.shape, self.setpoint_m
        self.scene.log(pose_scene(shape, pose, setpoint, trail, stamp_ns), log_time=stamp_ns)
        if pos is not None:
            from foxglove.messages import FrameTransform, Quaternion, Vector3

            self.tf.log(
                FrameTransform(
                    timestamp=_ts(stamp_ns),
                    parent_frame_id=FRAME_WORLD,
                    child_frame_id=FRAME_EFFECTOR,
                    translation=Vector3(x=pos[0], y=pos[1], z=pos[2]),
                    rotation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                ),
                log_time=stamp_ns,
            )
        self.scenes += 1

    def on_state(self, data: bytes) -> None:
        """A `<prefix>/state` sample: one Log message."""
        try:
            st = json.loads(data)
            state = str(st["state"])
            stamp_ns = int(st.get("stamp_ns") or time.time_ns())
        except (ValueError, KeyError, TypeError):
            return
        self._log_state(state, st.get("reason"), stamp_ns)

    def _log_state(self, state: str, reason: Any, stamp_ns: int) -> None:
        from foxglove.messages import Log, LogLevel

        self._last_state = state
        level = LogLevel.Error if state in _ALERT_STATES else LogLevel.Info
        text = f"{state}: {reason}" if reason else state
        self.log.log(
            Log(timestamp=_ts(stamp_ns), level=level, message=text, name=self.prefix),
            log_time=stamp_ns,
        )

    def on_alive(self, alive: bool) -> None:
        """The daemon's liveliness token appeared (True) or went (False)."""
        from foxglove.messages import Log, LogLevel

        now = time.time_ns()
        text = "daemon present" if alive else "daemon gone (its liveliness token was dropped)"
        level = LogLevel.Info if alive else LogLevel.Warning
        self.log.log(Log(timestamp=_ts(now), level=level, message=text, name=self.prefix))

    def on_status(self, data: bytes) -> None:
        """A status reply: forwarded, the tracking sample derived, the geometry updated."""
        try:
            status = json.loads(data)
        except ValueError:
            return
        if not isinstance(status, dict):
            return
        now = time.time_ns()
        self.status.log(data, log_time=now)
        track = tracking_sample(status)
        self.tracking.log(json.dumps(track).encode(), log_time=now)
        sp = status.get("setpoint_m")
        with self._lock:
            self.setpoint_m = sp if isinstance(sp, list) and len(sp) == 3 else None
        cfg = status.get("config")
        if isinstance(cfg, dict) and cfg.get("reels"):
            text = json.dumps(cfg, sort_keys=True)
            if text != self._shape_summary:
                self._shape_summary = text
                try:
                    shape = RobotShape.from_summary(cfg)
                except ShapeError as exc:
                    print(f"cablebot view: status geometry unusable: {exc}", file=sys.stderr)
                    return
                with self._lock:
                    self.shape = shape
                self.publish_robot()

    def publish_current_state(self) -> None:
        """Log the last known state again (for a client that just subscribed)."""
        state = self._last_state
        if state is not None:
            self._log_state(state, "current state", time.time_ns())

    def publish_robot(self) -> None:
        """Send the static scene (anchors, footprint, workspace), if the geometry is known."""
        shape = self.shape
        if shape is not None:
            self.robot.log(robot_scene(shape, time.time_ns()))


# --------------------------------------------------------------------------------------------
# The layout


def layout_config() -> dict[str, Any]:
    """The Foxglove layout shipped as docs/foxglove-layout.json: the 3-D view, per-axis
    position plots with the set-point, cable lengths, errors, the state log and the status."""

    def plot(series: list[tuple[str, str]], title: str) -> dict[str, Any]:
        return {
            "paths": [
                {"value": v, "label": label, "enabled": True, "timestampMethod": "receiveTime"}
                for v, label in series
            ],
            "title": title,
            "showXAxisLabels": True,
            "showYAxisLabels": True,
            "showLegend": True,
            "legendDisplay": "floating",
            "isSynced": True,
            "xAxisVal": "timestamp",
            "followingViewWidth": 30,
        }

    axes = {
        f"Plot!{axis}": plot(
            [
                (f"/pose.position_m[{i}]", f"{axis} FPK (m)"),
                (f"/tracking.setpoint_m[{i}]", f"{axis} set-point (m)"),
            ],
            f"{axis} (m)",
        )
        for i, axis in enumerate("xyz")
    }
    config_by_id: dict[str, Any] = {
        "3D!cablebot": {
            "cameraState": {
                "perspective": True,
                "distance": 120,
                "phi": 55,
                "thetaOffset": 35,
                "targetOffset": [0, 0, 0],
                "target": [0, 0, 0],
                "targetOrientation": [0, 0, 0, 1],
                "fovy": 45,
                "near": 0.01,
                "far": 5000,
            },
            "followMode": "follow-none",
            "followTf": FRAME_WORLD,
            "scene": {"transforms": {"showLabel": False, "axisScale": 0.5}},
            "transforms": {},
            "topics": {TOPICS["robot"]: {"visible": True}, TOPICS["scene"]: {"visible": True}},
            "layers": {
                "grid": {
                    "visible": True,
                    "layerId": "foxglove.Grid",
                    "frameId": FRAME_WORLD,
                    "size": 100,
                    "divisions": 20,
                    "lineWidth": 1,
                    "color": "#248eff40",
                    "position": [0, 0, 0],
                    "rotation": [0, 0, 0],
                }
            },
            "publish": {"type": "point"},
        },
        **axes,
        "Plot!lengths": plot(
            [(f"/pose.cable_lengths_m[{i}]", f"cable {i + 1} (m)") for i in range(4)],
            "cable lengths (m)",
        ),
        "Plot!errors": plot(
            [
                ("/tracking.error_mm", "tracking error (mm)"),
                ("/tracking.residual_mm", "FPK residual (mm)"),
            ],
            "errors (mm), at the status rate",
        ),
        "Log!state": {"topicToRender": TOPICS["state"], "minLogLevel": 1, "searchTerms": []},
        "RawMessages!status": {
            "topicPath": TOPICS["status"],
            "diffEnabled": False,
            "diffMethod": "custom",
            "diffTopicPath": "",
            "showFullMessageForDiff": False,
            "expansion": "none",
        },
        "Tab!side": {
            "activeTabIdx": 0,
            "tabs": [
                {
                    "title": "position",
                    "layout": {
                        "first": "Plot!x",
                        "second": {
                            "first": "Plot!y",
                            "second": "Plot!z",
                            "direction": "column",
                            "splitPercentage": 50,
                        },
                        "direction": "column",
                        "splitPercentage": 33.3,
                    },
                },
                {
                    "title": "cables and errors",
                    "layout": {
                        "first": "Plot!lengths",
                        "second": "Plot!errors",
                        "direction": "column",
                        "splitPercentage": 50,
                    },
                },
                {"title": "status", "layout": "RawMessages!status"},
            ],
        },
    }
    return {
        "configById": config_by_id,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1},
        "layout": {
            "first": {
                "first": "3D!cablebot",
                "second": "Log!state",
                "direction": "column",
                "splitPercentage": 78,
            },
            "second": "Tab!side",
            "direction": "row",
            "splitPercentage": 58,
        },
    }


def layout_json() -> str:
    """`layout_config()` as the text of docs/foxglove-layout.json."""
    return json.dumps(layout_config(), indent=2) + "\n"


# --------------------------------------------------------------------------------------------
# The verb


def cmd_view(args: argparse.Namespace) -> int:
    """Entry point of `cablebot view`: runs until Ctrl-C / SIGTERM (exit 0); 1 bad input or the
    WebSocket port is taken; 2 a bad `--connect`; 3 no daemon answered."""
    from controller.cli.client import EXIT_ABSENT, EXIT_OK, EXIT_REFUSED, EXIT_USAGE
    from controller.cli.daemon_robot import check_config_with_daemon
    from controller.cli.session import (
        DaemonAbsent,
        InputError,
        Refused,
        UsageError,
        normalize_endpoint,
        open_session,
    )

    try:
        args.connect = normalize_endpoint(args.connect)
    except UsageError as exc:
        print(f"cablebot view: {exc}", file=sys.stderr)
        return EXIT_USAGE

    try:
        import foxglove
    except ImportError:
        print("cablebot view: foxglove-sdk is missing; install cablebot[view]", file=sys.stderr)
        return EXIT_REFUSED
    fallback: RobotShape | None = None
    if args.config is not None:
        from controller.service.config import ConfigError, load_config

        try:
            fallback = RobotShape.from_summary(load_config(args.config).summary())
        except (ConfigError, OSError, ShapeError) as exc:
            print(f"cablebot view: configuration: {exc}", file=sys.stderr)
            return EXIT_REFUSED
    prefix = args.prefix.rstrip("/")
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with open_session(args.connect, config_file=args.zenoh_config) as session:
            try:
                check_config_with_daemon(session, prefix, args.timeout, args.config)
            except (InputError, Refused) as exc:
                print(f"cablebot view: {exc}", file=sys.stderr)
                return EXIT_REFUSED
            context = foxglove.Context()
            view = LiveView(
                context,
                prefix=prefix,
                scene_hz=args.scene_hz,
                trail_s=args.trail_s,
                fallback_shape=fallback,
            )
            try:
                server = foxglove.start_server(
                    name=f"cablebot {prefix}",
                    host=args.host,
                    port=args.port,
                    context=context,
                    server_listener=_listener(view),
                )
            except Exception as exc:  # the SDK raises its own error type for a taken port
                print(
                    f"cablebot view: cannot serve on {args.host}:{args.port}: {exc}",
                    file=sys.stderr,
                )
                return EXIT_REFUSED
            try:
                _serve(session, view, server, args, prefix, stop)
            finally:
                server.stop()
    except DaemonAbsent as exc:
        print(f"cablebot view: no cablebot daemon answered ({exc})", file=sys.stderr)
        return EXIT_ABSENT
    except UsageError as exc:  # a --zenoh-config file Zenoh rejects
        print(f"cablebot view: {exc}", file=sys.stderr)
        return EXIT_USAGE
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
    return EXIT_OK


def _listener(view: LiveView) -> Any:
    """A foxglove ServerListener that sends the static scene and the current state to a client
    as it subscribes to them."""
    from foxglove.websocket import ChannelView, Client, ServerListener

    class Listener(ServerListener):
        def on_subscribe(self, client: Client, channel: ChannelView) -> None:
            if channel.topic == TOPICS["robot"]:
                view.publish_robot()
            elif channel.topic == TOPICS["state"]:
                view.publish_current_state()

    return Listener()


def _serve(
    session: Any,
    view: LiveView,
    server: Any,
    args: argparse.Namespace,
    prefix: str,
    stop: threading.Event,
) -> None:
    """Subscribe, poll the status, and serve until `stop`."""
    import zenoh

    subs = [
        session.declare_subscriber(f"{prefix}/pose", lambda s: view.on_pose(s.payload.to_bytes())),
        session.declare_subscriber(
            f"{prefix}/state", lambda s: view.on_state(s.payload.to_bytes())
        ),
        session.liveliness().declare_subscriber(
            f"{prefix}/alive",
            lambda s: view.on_alive(s.kind == zenoh.SampleKind.PUT),
            history=True,
        ),
    ]
    warned = False
    period_s = 1.0 / args.status_hz
    print(
        f"Foxglove WebSocket server on ws://{args.host}:{server.port} showing {prefix} "
        f"via {args.connect} (load docs/foxglove-layout.json)",
        flush=True,
    )
    try:
        next_t = time.monotonic()
        while not stop.is_set():
            answered = False
            for reply in session.get(f"{prefix}/status", timeout=args.timeout):
                if reply.ok is not None:
                    answered = True
                    view.on_status(reply.ok.payload.to_bytes())
            if view.shape is None and not warned and answered:
                warned = True
                print(
                    "cablebot view: the status carries no configuration; give --config FILE "
                    "to draw the anchors and the cables",
                    file=sys.stderr,
                )
            next_t = max(next_t + period_s, time.monotonic())
            stop.wait(max(0.0, next_t - time.monotonic()))
    finally:
        for s in subs:
            s.undeclare()


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `cablebot view`."""
    from controller.cli.session import add_connection_arguments, tcp_port

    p = sub.add_parser(
        "view",
        help="show the robot live in 3-D in Foxglove (WebSocket server)",
        description=(
            "Serve the robot's pose, cables, set-point, state and status to the Foxglove app "
            "over the Foxglove WebSocket protocol. Open Foxglove, connect to ws://HOST:PORT and "
            "import docs/foxglove-layout.json. The geometry comes from the daemon's status "
            "(--config is the fallback when the status carries none)."
        ),
    )
    add_connection_arguments(p)
    p.add_argument("--host", default=DEFAULT_HOST, help=f"address to serve on ({DEFAULT_HOST})")
    p.add_argument(
        "--port",
        type=tcp_port,
        default=DEFAULT_PORT,
        help=f"WebSocket port ({DEFAULT_PORT}; 0 = any)",
    )
    p.add_argument(
        "--config",
        default=None,
        metavar="FILE",
        help="robot TOML, if the status carries none (refused if the daemon runs another robot)",
    )
    p.add_argument(
        "--scene-hz",
        type=positive_number,
        default=DEFAULT_SCENE_HZ,
        metavar="HZ",
        help=f"3-D scene updates per second (default {DEFAULT_SCENE_HZ:g})",
    )
    p.add_argument(
        "--status-hz",
        type=positive_number,
        default=DEFAULT_STATUS_HZ,
        metavar="HZ",
        help=f"status queries per second (default {DEFAULT_STATUS_HZ:g})",
    )
    p.add_argument(
        "--trail-s",
        type=positive_number,
        default=DEFAULT_TRAIL_S,
        metavar="S",
        help=f"length of the fading trail in seconds (default {DEFAULT_TRAIL_S:g})",
    )
    p.set_defaults(func=cmd_view)
