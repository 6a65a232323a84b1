"""The Zenoh interface of the controller daemon.

Key space, under a configurable prefix (default `cablebot/default`; the names are
`controller.service.keys`):

- `<prefix>/pose`      publisher, one JSON sample per published tick (`PoseSample.to_json_bytes`)
- `<prefix>/state`     publisher, `{"state", "reason", "stamp_ns"}` on every state change
- `<prefix>/status`    queryable, `Controller.status()` plus this interface's statistics
- `<prefix>/robot`     queryable, the robot description: `{"name", "source", "digest", "toml"}`
  (the robot file's TOML text as loaded; `controller.service.config.robot_description`), which
  clients take as the authority on the robot they drive
- `<prefix>/cmd/<verb>` one queryable per verb of `controller.core.commands.VERBS`;
  JSON in, JSON out;
  a refusal is an error reply `{"error": reason}` (encoding application/json)
- `<prefix>/setpoint`  subscriber, `{"position_m": [x, y, z]}` handed to `submit_setpoint`
- `<prefix>/velocity`  subscriber, `{"velocity_mps": [vx, vy, vz]}` handed to `submit_velocity`
  (velocity input: joysticks, RC sticks, `cablebot jog`)
- `<prefix>/alive`     liveliness token while the interface is open

Only the exact keys drive the robot: a query on `<prefix>/cmd/*` or a put on `cablebot/**`
reaches the queryables and the subscribers too, and is refused (counted, never executed).

Threads: zenoh-python runs each declared callback on its own Python thread, so every verb has
its own thread. A command waits there (bounded) for the loop's reply; a slow `home` never delays
an `estop`.

Bounded cost per message, so that no client holds the interpreter (the GIL) long enough to
delay the loop or an e-stop: the payload's size is read from Zenoh's buffer and checked against
`commands.MAX_PAYLOAD_BYTES` before it is copied or decoded; `commands.parse_command` then caps
the nesting; refusals and log lines quote at most `commands.QUOTE_CHARS` characters of the
input, and no reply reason is longer than `MAX_REASON_CHARS`; payloads over 16 KiB (paths) are
decoded by an interruptible scanner, so no message holds the GIL for more than about a
millisecond. E-stop takes the same checks (its cap is 1 KiB: microseconds) on its own thread,
so it never waits behind another verb's parsing, and `Controller.submit` hands it to the next
tick through a flag, never through the command queue. `cablebot bench` measures its latency
while another process floods the daemon (`estop_latency_flood_ms`).

Publishing: the pose publisher uses congestion control DROP, so a put never waits on the
network. But a put releases the GIL and must take it back, and in the daemon other Python
threads (simulated nodes, Zenoh callbacks) hold it: measured in the daemon at 200 Hz on a loaded
2-core machine, a put from the tick cost p50 80-180 us and p99 2.6-5.5 ms. So by default the
tick only hands the sample to a publisher thread through a one-slot "latest wins" hand-off
(tick cost p50 ~20 us, p99 ~0.75-1 ms, which is GIL pre-emption that any Python code sees); the
thread encodes and puts it. A sample overwritten before the thread ran is counted
(`pose_overwritten`), not queued. `publish_thread=False` (or the environment variable
CABLEBOT_ZENOH_PUBLISH_THREAD=0) puts directly from the tick. `stats()` reports both costs.
"""

from __future__ import annotations

import collections
import concurrent.futures
import json
import logging
import math
import os
import socket
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol

import numpy as np
import zenoh

from controller.core.commands import (
    VERBS,
    Command,
    CommandError,
    CommandRefused,
    Move,
    Path,
    Setpoint,
    Velocity,
    check_payload_size,
    clip,
    parse_command,
)
from controller.service import keys

log = logging.getLogger(__name__)

DEFAULT_PREFIX = "cablebot/default"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
JSON = zenoh.Encoding.APPLICATION_JSON
MAX_REASON_CHARS = 300
"""The longest reason an error reply carries (longer ones are cut)."""
_FIELD_KEYS = ("mode", "listen/endpoints", "connect/endpoints", "scouting/multicast/enabled")


class PoseLike(Protocol):
    """What the loop hands to `publish_pose` (controller.service.pose.PoseSample)."""

    def to_json_bytes(self) -> bytes:
        """The `<prefix>/pose` JSON encoding of this sample."""
        ...


class WorkspaceLike(Protocol):
    """The part of controller.core.workspace.Workspace the command pre-check uses."""

    def path_failure(
        self,
        points: Sequence[Sequence[float]],
        start_m: Sequence[float] | None = None,
        *,
        legs: bool = True,
    ) -> tuple[int, str] | None:
        """The first point (0-based index, reason) that breaks a limit, or None."""
        ...


class ControllerLike(Protocol):
    """The part of controller.service.loop.Controller this interface uses (and, if it has
    one, its `workspace`, a `WorkspaceLike`, for the command pre-check)."""

    def submit(self, cmd: Command) -> concurrent.futures.Future[dict[str, Any]]:
        """Queue a command; the future resolves with a reply dict or CommandRefused."""
        ...

    def submit_setpoint(self, position_m: Sequence[float]) -> None:
        """Stream a target position (latest wins)."""
        ...

    def submit_velocity(self, velocity_mps: Sequence[float]) -> None:
        """Velocity input: fly at this velocity (latest wins; dead-man in the controller)."""
        ...

    def status(self) -> dict[str, Any]:
        """A JSON-ready snapshot of the controller."""
        ...


# --------------------------------------------------------------------------------------------
# Configuration


def _get(cfg: Any, name: str, default: Any) -> Any:
    value = getattr(cfg, name, default) if cfg is not None else default
    return default if value is None else value


def session_config(zcfg: Any) -> zenoh.Config:
    """Build the daemon's zenoh.Config from a `ZenohConfig`-like object.

    Fields used: `mode` (default "peer"), `listen` (default [tcp/127.0.0.1:7447]), `connect`
    (default []), `multicast_scouting` (default False), `config_file` (default None). When
    `config_file` is set it is loaded first and wins: the fields above only fill in what the
    file leaves at Zenoh's defaults (mode unset, listen endpoints default, connect empty,
    multicast scouting unset). Raises zenoh.ZError (or OSError) for an unreadable or invalid
    file or endpoint.
    """
    mode = str(_get(zcfg, "mode", "peer"))
    listen = [str(e) for e in _get(zcfg, "listen", [DEFAULT_ENDPOINT])]
    connect = [str(e) for e in _get(zcfg, "connect", [])]
    scouting = bool(_get(zcfg, "multicast_scouting", False))
    config_file = _get(zcfg, "config_file", None)
    if config_file:
        conf = zenoh.Config.from_file(str(config_file))
        defaults = zenoh.Config()
        keep = {
            key: conf.get_json(key) != defaults.get_json(key)
            for key in (
                "mode",
                "listen/endpoints",
                "connect/endpoints",
                "scouting/multicast/enabled",
            )
        }
    else:
        conf = zenoh.Config()
        keep = {}
    if not keep.get("mode"):
        conf.insert_json5("mode", json.dumps(mode))
    if not keep.get("listen/endpoints"):
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    if not keep.get("connect/endpoints"):
        conf.insert_json5("connect/endpoints", json.dumps(connect))
    if not keep.get("scouting/multicast/enabled"):
        conf.insert_json5("scouting/multicast/enabled", json.dumps(scouting))
    return conf


def client_config(
    connect: Sequence[str] = (DEFAULT_ENDPOINT,),
    *,
    mode: str = "client",
    config_file: str | None = None,
) -> zenoh.Config:
    """A zenoh.Config for a client tool: connect only, listen nowhere, no multicast scouting.

    Client mode fails at `zenoh.open` when nothing listens on `connect` (a clear "daemon
    absent"); several tools can run at once since none listens. `config_file` (JSON5, e.g.
    TLS certificates) is loaded first; `connect` and `mode` are then applied. Raises
    zenoh.ZError for an invalid file or endpoint.
    """
    conf = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


# --------------------------------------------------------------------------------------------
# Helpers


def address_in_use(error: BaseException | str) -> bool:
    """True when a Zenoh error (from `zenoh.open`) says a listen address is taken by another
    process."""
    text = str(error).lower()
    return "in use" in text or "os error 98" in text


def free_tcp_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago, never Zenoh's default 7447 (for a
    private loopback endpoint of a bench, demo or test daemon). Raises OSError if none is."""
    for _ in range(20):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.bind(("127.0.0.1", 0))
            port = int(s.getsockname()[1])
        if port != 7447:
            return port
    raise OSError("no free TCP port on 127.0.0.1")


def json_safe(value: Any) -> Any:
    """Return `value` with every non-finite float replaced by None (so JSON never has NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return value


def dumps(value: Any) -> bytes:
    """Compact JSON bytes of `value`, non-finite floats as null; raises TypeError if not JSON."""
    return json.dumps(json_safe(value), separators=(",", ":"), allow_nan=False).encode()


def error_payload(reason: str) -> bytes:
    """The JSON body of an error reply; the reason is cut to MAX_REASON_CHARS characters."""
    return dumps({"error": clip(reason, MAX_REASON_CHARS)})


class _Timings:
    """A fixed-size ring of durations in nanoseconds (written by one thread).

    numpy storage: the summary (status query thread) partitions with the GIL released
    instead of holding it for a Python sort while the loop wants it.
    """

    def __init__(self, size: int = 2048) -> None:
        self._buf = np.zeros(size, dtype=np.int64)
        self._n = 0

    def add(self, ns: int) -> None:
        self._buf[self._n % self._buf.shape[0]] = ns
        self._n += 1

    def summary_us(self) -> dict[str, float | None]:
        data = self._buf[: min(self._n, self._buf.shape[0])].copy()
        if data.shape[0] == 0:
            return {"p50_us": None, "p99_us": None, "max_us": None}
        p50, p99 = np.percentile(data, [50.0, 99.0])
        return {
            "p50_us": float(p50) / 1e3,
            "p99_us": float(p99) / 1e3,
            "max_us": float(data.max()) / 1e3,
        }


class _RateLimitedLog:
    """Log at most one message per `period_s` (the rest are counted, not lost)."""

    def __init__(self, period_s: float = 1.0) -> None:
        self._period_s = period_s
        self._last = -math.inf
        self._suppressed = 0

    def warning(self, msg: str, *args: Any) -> None:
        now = time.monotonic()
        if now - self._last >= self._period_s:
            if self._suppressed:
                msg += f" ({self._suppressed} similar suppressed)"
            log.warning(msg, *args)
            self._last = now
            self._suppressed = 0
        else:
            self._suppressed += 1


class _LatestSlot:
    """Hand-off from the loop to a publisher thread: poses "latest wins", state changes queued.

    State changes are rare and each one matters, so they queue (bounded) and are put before
    the pending pose, keeping their order relative to the poses.
    """

    _MAX_STATES = 64

    def __init__(self, put_pose: Callable[[bytes], None], put_state: Callable[[bytes], None]):
        self._put_pose = put_pose
        self._put_state = put_state
        self._cond = threading.Condition(threading.Lock())
        self._item: PoseLike | None = None
        self._states: collections.deque[bytes] = collections.deque(maxlen=self._MAX_STATES)
        self._closed = False
        self.overwritten = 0
        self._thread = threading.Thread(target=self._run, name="cablebot-zenoh-pub", daemon=True)
        self._thread.start()

    def offer(self, sample: PoseLike) -> None:
        with self._cond:
            if self._item is not None:
                self.overwritten += 1
            self._item = sample
            self._cond.notify()

    def offer_state(self, data: bytes) -> None:
        with self._cond:
            self._states.append(data)
            self._cond.notify()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._thread.join(timeout=1.0)

    def _run(self) -> None:
        while True:
            with self._cond:
                while self._item is None and not self._states and not self._closed:
                    self._cond.wait()
                item, self._item = self._item, None
                states = list(self._states)
                self._states.clear()
                closed = self._closed
            try:  # never let the publisher thread die
                for data in states:
                    self._put_state(data)
                if item is not None and not closed:
                    self._put_pose(item.to_json_bytes())
            except Exception as exc:
                log.warning("publisher thread: put failed: %s", exc)
            if closed:
                return


# --------------------------------------------------------------------------------------------
# The interface


class ZenohInterface:
    """The daemon's Zenoh session: a `Publisher` for the loop, and the command side.

    `zcfg` is a `controller.service.config.ZenohConfig`-like object (prefix, mode, listen, connect,
    multicast_scouting, config_file); `controller` a `Controller`-like object. Nothing happens
    until `open()`. `reply_timeout_s` bounds how long a command waits for the loop.
    `publish_thread` (default: the environment variable CABLEBOT_ZENOH_PUBLISH_THREAD if set,
    else `zcfg.publish_thread` if present, else True) selects the publisher-thread hand-off.
    `robot` is the robot description served on `<prefix>/robot`
    (`controller.service.config.robot_description`; None: no such queryable).
    """

    def __init__(
        self,
        zcfg: Any,
        controller: ControllerLike,
        *,
        reply_timeout_s: float = 2.0,
        publish_thread: bool | None = None,
        robot: Mapping[str, Any] | None = None,
    ) -> None:
        self.zcfg = zcfg
        self._robot_reply: bytes | None = None if robot is None else dumps(dict(robot))
        """The answer of `<prefix>/robot`, encoded once (None: not declared)."""
        self.controller = controller
        self.prefix = str(_get(zcfg, "prefix", DEFAULT_PREFIX)).rstrip("/")
        self.reply_timeout_s = reply_timeout_s
        if publish_thread is None:
            env = os.environ.get("CABLEBOT_ZENOH_PUBLISH_THREAD")
            if env is not None:
                publish_thread = env.strip().lower() not in ("", "0", "false", "no")
            else:
                publish_thread = bool(_get(zcfg, "publish_thread", True))
        self.publish_thread = publish_thread
        self.session: zenoh.Session | None = None
        self._pose_pub: zenoh.Publisher | None = None
        self._state_pub: zenoh.Publisher | None = None
        self._declared: list[Any] = []
        self._slot: _LatestSlot | None = None
        self._put_ns = _Timings()  # the put alone
        self._tick_ns = _Timings()  # what publish_pose costs the tick (encode + put or hand-off)
        self._lock = threading.Lock()  # counters written from several Zenoh threads
        self.poses_published = 0
        self.pose_put_errors = 0
        self.states_published = 0
        self.commands: dict[str, int] = {"ok": 0, "refused": 0, "malformed": 0, "timeout": 0}
        self.setpoints_ok = 0
        self.setpoints_bad = 0
        self.velocity_ok = 0
        self.velocity_bad = 0
        self._bad_velocity_log = _RateLimitedLog(1.0)
        self._bad_setpoint_log = _RateLimitedLog(1.0)
        self._put_error_log = _RateLimitedLog(1.0)
        self.status_extras: dict[str, Callable[[], dict[str, Any]]] = {}
        """More sections of the status reply, by name (e.g. "ros2": the ROS 2 node's stats)."""

    # ---------------------------------------------------------------- lifecycle

    def open(self) -> None:
        """Open the session and declare publishers, queryables, subscriber and liveliness token.

        Raises zenoh.ZError (e.g. the listen endpoint is in use) after closing what was opened.
        """
        session = zenoh.open(session_config(self.zcfg))
        self.session = session
        try:
            p = self.prefix
            self._pose_pub = session.declare_publisher(
                f"{p}/{keys.POSE}",
                encoding=JSON,
                congestion_control=zenoh.CongestionControl.DROP,
                priority=zenoh.Priority.DATA_HIGH,
            )
            self._state_pub = session.declare_publisher(
                f"{p}/{keys.STATE}",
                encoding=JSON,
                congestion_control=zenoh.CongestionControl.DROP,
                priority=zenoh.Priority.INTERACTIVE_HIGH,
            )
            self._declared.append(
                session.declare_queryable(f"{p}/{keys.STATUS}", self._on_status, complete=True)
            )
            if self._robot_reply is not None:
                self._declared.append(
                    session.declare_queryable(f"{p}/{keys.ROBOT}", self._on_robot, complete=True)
                )
            for verb in VERBS:
                self._declared.append(
                    session.declare_queryable(
                        f"{p}/{keys.command(verb)}", self._command_handler(verb), complete=True
                    )
                )
            self._declared.append(
                session.declare_subscriber(f"{p}/{keys.SETPOINT}", self._on_setpoint)
            )
            self._declared.append(
                session.declare_subscriber(f"{p}/{keys.VELOCITY}", self._on_velocity)
            )
            self._declared.append(session.liveliness().declare_token(f"{p}/{keys.ALIVE}"))
            if self.publish_thread:
                self._slot = _LatestSlot(self._put_pose_bytes, self._put_state_bytes)
        except Exception:
            self.close()
            raise
        log.info(
            "Zenoh: %s on %s, prefix %s", _get(self.zcfg, "mode", "peer"), self._endpoints(), p
        )

    def close(self) -> None:
        """Undeclare everything and close the session (idempotent, never raises)."""
        if self._slot is not None:
            self._slot.close()
            self._slot = None
        session, self.session = self.session, None
        declared, self._declared = self._declared, []
        pubs = [x for x in (self._pose_pub, self._state_pub) if x is not None]
        self._pose_pub = self._state_pub = None
        for obj in [*declared, *pubs]:
            try:
                obj.undeclare()
            except Exception as exc:
                log.debug("undeclare: %s", exc)
        if session is not None:
            try:
                session.close()  # type: ignore[no-untyped-call]
            except Exception as exc:
                log.warning("closing the Zenoh session: %s", exc)

    def json_publisher(self, suffix: str) -> Callable[[bytes], None]:
        """Declare a JSON publisher on `<prefix>/<suffix>` (undeclared by `close`) and return
        its put (e.g. the simulator's ground truth, `controller.service.simulated.TRUTH_KEY`).
        Raises RuntimeError before `open`, zenoh.ZError if the declaration fails."""
        if self.session is None:
            raise RuntimeError("the Zenoh session is not open")
        pub = self.session.declare_publisher(
            f"{self.prefix}/{suffix}",
            encoding=JSON,
            congestion_control=zenoh.CongestionControl.DROP,
        )
        self._declared.append(pub)
        return pub.put

    def _endpoints(self) -> list[str]:
        return [str(e) for e in _get(self.zcfg, "listen", [DEFAULT_ENDPOINT])]

    # ---------------------------------------------------------------- Publisher (loop thread)

    def publish_pose(self, sample: PoseLike) -> None:
        """Publish one pose; never blocks on the network (congestion control DROP)."""
        t0 = time.perf_counter_ns()
        if self._slot is not None:
            self._slot.offer(sample)
        else:
            self._put_pose_bytes(sample.to_json_bytes())
        self._tick_ns.add(time.perf_counter_ns() - t0)

    def _put_pose_bytes(self, data: bytes) -> None:
        pub = self._pose_pub
        if pub is None:
            return
        t0 = time.perf_counter_ns()
        try:
            pub.put(data)
        except Exception as exc:
            self.pose_put_errors += 1
            self._put_error_log.warning("pose put failed: %s", exc)
            return
        self._put_ns.add(time.perf_counter_ns() - t0)
        self.poses_published += 1

    def publish_state(self, state: str, reason: str | None, stamp_ns: int) -> None:
        """Publish a state change as `{"state", "reason", "stamp_ns"}` on `<prefix>/state`."""
        data = dumps({"state": str(state), "reason": reason, "stamp_ns": int(stamp_ns)})
        if self._slot is not None:
            self._slot.offer_state(data)
        else:
            self._put_state_bytes(data)

    def _put_state_bytes(self, data: bytes) -> None:
        pub = self._state_pub
        if pub is None:
            return
        try:
            pub.put(data)
            self.states_published += 1
        except Exception as exc:
            self._put_error_log.warning("state put failed: %s", exc)

    # ---------------------------------------------------------------- statistics

    def stats(self) -> dict[str, Any]:
        """This interface's counters and the measured cost of a pose put (microseconds)."""
        with self._lock:
            commands = dict(self.commands)
            setpoints = {"ok": self.setpoints_ok, "bad": self.setpoints_bad}
            velocity = {"ok": self.velocity_ok, "bad": self.velocity_bad}
        return {
            "prefix": self.prefix,
            "mode": str(_get(self.zcfg, "mode", "peer")),
            "listen": self._endpoints(),
            "connect": [str(e) for e in _get(self.zcfg, "connect", [])],
            "config_file": _get(self.zcfg, "config_file", None),
            "poses_published": self.poses_published,
            "pose_put_errors": self.pose_put_errors,
            "pose_put": self._put_ns.summary_us(),
            "pose_publish_tick": self._tick_ns.summary_us(),
            "pose_overwritten": self._slot.overwritten if self._slot is not None else 0,
            "publish_thread": self.publish_thread,
            "states_published": self.states_published,
            "commands": commands,
            "setpoints": setpoints,
            "velocity": velocity,
        }

    def _count(self, key: str) -> None:
        with self._lock:
            self.commands[key] = self.commands.get(key, 0) + 1

    # ---------------------------------------------------------------- queryables (Zenoh threads)

    def _on_status(self, query: zenoh.Query) -> None:
        key = f"{self.prefix}/{keys.STATUS}"
        try:
            status = dict(self.controller.status())
            status["zenoh"] = self.stats()
            for name, section in self.status_extras.items():
                status[name] = section()
            query.reply(key, dumps(status), encoding=JSON)
        except Exception as exc:
            log.exception("status query failed")
            _reply_err(query, f"internal error: {clip(str(exc))}")
        finally:
            _finish(query)

    def _on_robot(self, query: zenoh.Query) -> None:
        try:
            if self._robot_reply is not None:
                query.reply(f"{self.prefix}/{keys.ROBOT}", self._robot_reply, encoding=JSON)
        except Exception as exc:
            log.warning("robot query failed: %s", exc)
        finally:
            _finish(query)

    def _command_handler(self, verb: str) -> Callable[[zenoh.Query], None]:
        key = f"{self.prefix}/{keys.command(verb)}"

        def handler(query: zenoh.Query) -> None:
            try:
                self._handle_command(verb, key, query)
            except Exception as exc:  # a bug here must still answer the client
                log.exception("command %s failed", verb)
                _reply_err(query, f"internal error: {clip(str(exc))}")
            finally:
                _finish(query)

        return handler

    def _handle_command(self, verb: str, key: str, query: zenoh.Query) -> None:
        if str(query.key_expr) != key:
            # `z_get cablebot/**` must not arm, disarm and e-stop the robot all at once.
            self._count("malformed")
            _reply_err(query, f"commands need the exact key {key}, not a wildcard")
            return
        zbytes = query.payload
        try:
            # The size first, from Zenoh's buffer: an oversized payload is never copied.
            check_payload_size(verb, len(zbytes) if zbytes is not None else 0)
            cmd = parse_command(verb, zbytes.to_bytes() if zbytes is not None else None)
        except CommandError as exc:
            self._count("malformed")
            _reply_err(query, str(exc))
            return
        reason = self._precheck(cmd)
        if reason is not None:
            self._count("refused")
            _reply_err(query, reason)
            return
        fut = self.controller.submit(cmd)
        try:
            reply = fut.result(timeout=self.reply_timeout_s)
        except CommandRefused as exc:
            self._count("refused")
            _reply_err(query, str(exc))
            return
        except concurrent.futures.TimeoutError:
            self._count("timeout")
            if fut.cancel():  # the loop skips a cancelled future: the command will not run
                _reply_err(query, "timeout: the control loop did not answer; command cancelled")
                return
            # The loop took it just now: its outcome is worth a short wait.
            try:
                reply = fut.result(timeout=self.reply_timeout_s)
            except CommandRefused as exc:
                _reply_err(query, str(exc))
                return
            except concurrent.futures.TimeoutError:
                _reply_err(query, "timeout: the control loop took the command but did not answer")
                return
        self._count("ok")
        query.reply(key, dumps(reply), encoding=JSON)

    def precheck(self, cmd: Command) -> str | None:
        """Why `cmd` is refused before it reaches the controller (see `_precheck`), or None."""
        return self._precheck(cmd)

    def _precheck(self, cmd: Command) -> str | None:
        """Refuse here, on the Zenoh thread, a move or path with a point the robot may not go to.

        The controller's `workspace` (a `controller.core.workspace.Workspace`: immutable, so
        safe from this thread) checks every point, vectorised, against the workspace and the
        cable lengths; the legs are left to the controller, which knows where the motion
        starts. A controller without `workspace` is not pre-checked. Raises nothing.
        """
        workspace: WorkspaceLike | None = getattr(self.controller, "workspace", None)
        if workspace is None:
            return None
        if isinstance(cmd, Move):
            failure = workspace.path_failure((cmd.position_m,), legs=False)
            return None if failure is None else failure[1]
        if isinstance(cmd, Path):
            failure = workspace.path_failure(cmd.points_m, legs=False)
            return None if failure is None else f"points_m[{failure[0]}]: {failure[1]}"
        return None

    # ---------------------------------------------------------------- set-points (Zenoh thread)

    def _on_setpoint(self, sample: zenoh.Sample) -> None:
        try:
            key = f"{self.prefix}/{keys.SETPOINT}"
            if str(sample.key_expr) != key:
                # A put on `cablebot/**` must not drive every robot that hears it.
                raise CommandError(f"set-points need the exact key {key}, not a wildcard")
            check_payload_size("setpoint", len(sample.payload))  # before any copy
            cmd = parse_command("setpoint", sample.payload.to_bytes())
            assert isinstance(cmd, Setpoint)
            self.controller.submit_setpoint(cmd.position_m)
        except Exception as exc:  # counted and logged, never raised into Zenoh
            with self._lock:
                self.setpoints_bad += 1
            self._bad_setpoint_log.warning("bad set-point ignored: %s", clip(str(exc), 200))
            return
        with self._lock:
            self.setpoints_ok += 1

    def _on_velocity(self, sample: zenoh.Sample) -> None:
        try:
            key = f"{self.prefix}/{keys.VELOCITY}"
            if str(sample.key_expr) != key:
                # A put on `cablebot/**` must not fly every robot that hears it.
                raise CommandError(f"velocity samples need the exact key {key}, not a wildcard")
            check_payload_size("velocity", len(sample.payload))  # before any copy
            cmd = parse_command("velocity", sample.payload.to_bytes())
            assert isinstance(cmd, Velocity)
            self.controller.submit_velocity(cmd.velocity_mps)
        except Exception as exc:  # counted and logged, never raised into Zenoh
            with self._lock:
                self.velocity_bad += 1
            self._bad_velocity_log.warning("bad velocity sample ignored: %s", clip(str(exc), 200))
            return
        with self._lock:
            self.velocity_ok += 1


def _reply_err(query: zenoh.Query, reason: str) -> None:
    """Send `{"error": reason}` as an error reply; never raises."""
    try:
        query.reply_err(error_payload(reason), encoding=JSON)
    except Exception as exc:
        log.warning("error reply failed: %s", exc)


def _finish(query: zenoh.Query) -> None:
    """Tell the querier that no more replies come.

    Zenoh sends the final message when the Query is dropped; a reference cycle (an exception's
    traceback holding this frame) could delay that until garbage collection and make the
    client wait for its timeout, so drop it explicitly.
    """
    try:
        query.drop()  # type: ignore[no-untyped-call]
    except Exception as exc:
        log.debug("query drop: %s", exc)
