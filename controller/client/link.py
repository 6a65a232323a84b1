"""`RobotLink`: the connection to one daemon's robot and what it publishes: the session, one
query, the status, the pose (latest, stream, callback), the simulator's truth, the publishers
of set-points and velocity samples. `controller.client.robot.Robot` builds the commands and
the following of motion on it; `list_daemons` and `discover` find the live daemons.

Threads: every method may be called from several threads at once (queries are independent;
the feeds and the lazily declared subscribers and publishers are kept under a lock).
Callbacks (`on_pose`) run on a Zenoh thread: keep them short and call no blocking method from
them. Resources: the session, its subscribers and publishers are released by `close()`; a link
made on a session of the caller's (`session=`) leaves that session open.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import suppress
from typing import Any

import controller.client.inputs as inputs
import controller.client.transport as transport
from controller.client.description import NoDescription, RobotDescription, fetch_description
from controller.client.errors import ClientError, DaemonAbsent, Refused
from controller.client.feed import FOLLOWER_LIMIT, Feed, Follower
from controller.client.model import DaemonInfo, Pose, StateChange, Status, Truth
from controller.core.commands import quote
from controller.service import keys

POSE_MAX_AGE_S = 0.5
"""How old the latest pose may be for `pose()` to return it without waiting for a new one."""

QueryFn = Callable[[Any, str, Any, float], Any]
"""`query(session, key, payload, timeout_s)`: one query, its decoded JSON reply."""


class RobotLink:
    """The robot a daemon runs, reached over Zenoh: its status and what it publishes.

    `endpoint` is where the daemon listens (`tcp/HOST:PORT` or `HOST:PORT`; default
    `$CABLEBOT_ENDPOINT`, else `tcp/127.0.0.1:7447`), `prefix` its key prefix (`cablebot/<robot
    name>`; default `$CABLEBOT_PREFIX`, else `cablebot/default`), `zenoh_config` a Zenoh JSON5
    file for this client (TLS certificates, say), `timeout_s` how long a reply or a pose sample
    may take. With `session`, the Robot uses that open Zenoh session instead of opening one
    (and does not close it); `query` replaces the function that sends one query (tools that
    record or replay the traffic).

    Raises UsageError for an endpoint or configuration file that cannot be used, DaemonAbsent
    when nothing accepts the connection (a daemon that is there but does not answer on
    `prefix` shows at the first query instead), InputError for a `timeout_s` that is not a
    number of seconds > 0.
    """

    def __init__(
        self,
        endpoint: str | None = None,
        prefix: str | None = None,
        *,
        zenoh_config: str | None = None,
        timeout_s: float = transport.DEFAULT_TIMEOUT_S,
        session: Any = None,
        query: QueryFn | None = None,
    ) -> None:
        self.prefix = (transport.default_prefix() if prefix is None else prefix).rstrip("/")
        self.timeout_s = inputs.positive_s(timeout_s, "timeout_s")
        self._query_fn: QueryFn = transport.query if query is None else query
        # Re-entrant: a KeyboardInterrupt landing inside a `with` of this thread must not leave
        # the lock it holds to deadlock the stop that follows.
        self._lock = threading.RLock()
        self._poses: Feed[Pose] | None = None
        self._truths: Feed[Truth] | None = None
        self._states: Feed[StateChange] | None = None
        self._declared: list[Any] = []
        self._publishers: dict[str, Any] = {}
        self._description: RobotDescription | NoDescription | None = None
        self._closed = False
        if session is None:
            given = transport.default_endpoint() if endpoint is None else endpoint
            self.endpoint: str | None = transport.normalize_endpoint(given)
            self._session = transport.open_zenoh(self.endpoint, config_file=zenoh_config)
            self._owns_session = True
        else:
            self.endpoint = None
            self._session = session
            self._owns_session = False

    # ----------------------------------------------------------------------------- lifetime
    def close(self) -> None:
        """Undeclare this Robot's subscribers and publishers and close its session (unless it
        was given one). Idempotent; never raises. Motion in progress goes on."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            declared = [*self._declared, *self._publishers.values()]
            self._declared, self._publishers = [], {}
        for obj in declared:
            with suppress(Exception):
                obj.undeclare()
        if self._owns_session:
            with suppress(Exception):
                self._session.close()

    def __enter__(self) -> RobotLink:
        return self

    def __exit__(self, exc_type: Any, exc: BaseException | None, tb: Any) -> None:
        self.close()

    @property
    def session(self) -> Any:
        """The Zenoh session (for keys this library does not cover)."""
        return self._session

    def key(self, suffix: str) -> str:
        """The full key of `suffix` under this robot's prefix (e.g. "pose")."""
        return f"{self.prefix}/{suffix}"

    def query(self, suffix: str, payload: Any = None) -> Any:
        """One query on `<prefix>/<suffix>` with a JSON `payload`; the decoded reply. Raises
        Refused (an error reply), DaemonAbsent (no reply within `timeout_s`)."""
        return self._query_fn(self._session, self.key(suffix), payload, self.timeout_s)

    # ------------------------------------------------------------------------------ reading
    def status(self) -> Status:
        """The daemon's status. Raises DaemonAbsent, Refused (an error reply or one that is
        not a status)."""
        st = self.query(keys.STATUS)
        if not isinstance(st, Mapping):
            raise Refused(f"unexpected status reply {quote(st)}")
        return Status.from_mapping(st)

    def status_map(self) -> dict[str, Any]:
        """The daemon's status as it sent it ({} if it is not an object), for the stream's
        pacing (`controller.client.stream`). Raises DaemonAbsent, Refused."""
        st = self.query(keys.STATUS)
        return st if isinstance(st, dict) else {}

    def description(self) -> RobotDescription:
        """The robot the daemon runs (`<prefix>/robot`: its name, TOML text and the validated
        configuration), fetched once and kept. Raises NoDescription (a Refused) from a daemon
        that serves none (older than this client), DaemonAbsent, Refused (a description that
        cannot be used)."""
        with self._lock:
            known = self._description
        if known is None:
            try:
                known = fetch_description(
                    self._session, self.prefix, self.timeout_s, self._query_fn
                )
            except NoDescription as exc:
                known = exc
            with self._lock:
                self._description = known
        if isinstance(known, NoDescription):
            raise NoDescription(str(known))
        return known

    def _pose_feed(self) -> Feed[Pose]:
        with self._lock:
            if self._poses is None:
                feed: Feed[Pose] = Feed(lambda data, t: Pose.from_json(data, t))
                self._declared.append(
                    self._session.declare_subscriber(self.key(keys.POSE), feed.on_sample)
                )
                self._poses = feed
            return self._poses

    def pose(self, *, max_age_s: float = POSE_MAX_AGE_S, timeout_s: float | None = None) -> Pose:
        """The latest pose sample: the newest received if it is at most `max_age_s` old, else
        the next to arrive (the first call subscribes to the pose). Its `position_m` is None
        while the pose is not valid. Raises DaemonAbsent when none arrives within `timeout_s`
        (default: the Robot's)."""
        feed = self._pose_feed()
        latest = feed.latest
        if latest is not None and time.monotonic() - latest.received_s <= max_age_s:
            return latest
        wait_s = self.timeout_s if timeout_s is None else timeout_s
        with feed.follow() as follower:
            pose = follower.get(wait_s)
        if pose is None:
            raise DaemonAbsent(f"no pose sample within {wait_s:g} s on {self.key('pose')}")
        return pose

    def latest_pose(self) -> Pose | None:
        """The newest pose sample received, never waiting: None before the first arrives (the
        first call subscribes; check its `received_s` for its age)."""
        return self._pose_feed().latest

    def poses(self, *, timeout_s: float | None = None, limit: int = FOLLOWER_LIMIT) -> PoseStream:
        """Every pose sample from now on, in order, as an iterator (close it, or use it as a
        context manager, when done). Raises (while iterating) DaemonAbsent when no sample
        arrives for `timeout_s` (default: the Robot's). At most `limit` samples wait unread;
        older ones are dropped and counted in `dropped` (gaps in `seq` show them too)."""
        wait_s = self.timeout_s if timeout_s is None else timeout_s
        feed = self._pose_feed()
        return PoseStream(feed.add(Follower(feed, limit)), wait_s, self.key(keys.POSE))

    def on_pose(self, callback: Callable[[Pose], None]) -> Follower[Pose]:
        """Call `callback(pose)` with every pose sample from now on, on Zenoh's thread (keep it
        short; an error in it drops that sample); returns the subscription: `close()` it to
        stop."""
        feed = self._pose_feed()
        return feed.add(Follower(feed, sink=callback))

    def on_state(self, callback: Callable[[StateChange], None]) -> Follower[StateChange]:
        """Call `callback(change)` with every change of state from now on (`<prefix>/state`),
        on Zenoh's thread (keep it short); returns the subscription: `close()` it to stop."""
        with self._lock:
            if self._states is None:
                feed: Feed[StateChange] = Feed(lambda data, t: StateChange.from_json(data, t))
                self._declared.append(
                    self._session.declare_subscriber(self.key(keys.STATE), feed.on_sample)
                )
                self._states = feed
            states = self._states
        return states.add(Follower(states, sink=callback))

    def truth(self, timeout_s: float = 1.0) -> Truth | None:
        """The simulator's latest ground truth (`<prefix>/sim/truth`: the plant's true position
        and tensions), or None when none arrives within `timeout_s` (no simulator with the
        physical plant on this robot). The first call subscribes."""
        with self._lock:
            if self._truths is None:
                feed: Feed[Truth] = Feed(lambda data, t: Truth.from_json(data, t))
                self._declared.append(
                    self._session.declare_subscriber(self.key(keys.TRUTH), feed.on_sample)
                )
                self._truths = feed
            truths = self._truths
        latest = truths.latest
        if latest is not None and time.monotonic() - latest.received_s <= POSE_MAX_AGE_S:
            return latest
        with truths.follow() as follower:
            return follower.get(timeout_s)

    def _publisher(self, suffix: str) -> Any:
        with self._lock:
            pub = self._publishers.get(suffix)
            if pub is None:
                import zenoh

                pub = self._session.declare_publisher(
                    self.key(suffix),
                    encoding=zenoh.Encoding.APPLICATION_JSON,
                    congestion_control=zenoh.CongestionControl.DROP,
                    priority=zenoh.Priority.INTERACTIVE_HIGH,
                    express=True,
                )
                self._publishers[suffix] = pub
            return pub

    def setpoint(self, position_m: Sequence[float]) -> None:
        """Stream one target position (`<prefix>/setpoint`; latest wins, within the speed and
        acceleration limits). No reply: a refused sample shows in `status().raw["stream"]`.
        Raises InputError (nothing sent)."""
        p = inputs.point(position_m, "setpoint")
        self._publisher(keys.SETPOINT).put(json.dumps({"position_m": p}).encode())

    def velocity(self, velocity_mps: Sequence[float]) -> None:
        """Send one velocity-input sample (`<prefix>/velocity`): fly at `velocity_mps` until
        the next; send 10-50 a second while moving (the daemon brakes to a hold when none comes
        for `[limits] velocity_timeout_s`); (0, 0, 0) brakes at once. Raises InputError."""
        v = inputs.point(velocity_mps, "velocity")
        self._publisher(keys.VELOCITY).put(json.dumps({"velocity_mps": v}).encode())


class PoseStream:
    """The pose samples of a Robot from the moment it was made, in order (`Robot.poses`).
    Raises DaemonAbsent (while iterating) when none arrives for `timeout_s`; `dropped` counts
    samples dropped unread."""

    def __init__(self, follower: Follower[Pose], timeout_s: float, key: str) -> None:
        self._follower = follower
        self.timeout_s = timeout_s
        self._key = key

    @property
    def dropped(self) -> int:
        """Samples dropped because too many waited unread."""
        return self._follower.dropped

    def get(self, timeout: float) -> Pose | None:
        """The next sample, waiting at most `timeout` seconds; None when none came."""
        return self._follower.get(timeout)

    def drain(self) -> None:
        """Drop every sample received so far and not read."""
        self._follower.drain()

    def __iter__(self) -> PoseStream:
        return self

    def __next__(self) -> Pose:
        pose = self._follower.get(self.timeout_s)
        if pose is None:
            raise DaemonAbsent(f"no pose sample within {self.timeout_s:g} s")
        return pose

    def close(self) -> None:
        """Stop following the pose (idempotent)."""
        self._follower.close()

    def __enter__(self) -> PoseStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def list_daemons(
    session: Any,
    timeout_s: float = transport.DEFAULT_TIMEOUT_S,
    *,
    query: QueryFn | None = None,
) -> list[DaemonInfo]:
    """Every live daemon on an open session's network: prefix, robot name, state and the
    endpoints it listens on (from its status; None where it did not answer within
    `timeout_s`), sorted by prefix. Raises nothing for a daemon that does not answer."""
    ask = transport.query if query is None else query
    out: list[DaemonInfo] = []
    for prefix in transport.live_prefixes(session):
        try:
            st = ask(session, f"{prefix}/{keys.STATUS}", None, timeout_s)
        except (ClientError, ValueError):
            st = None
        if not isinstance(st, Mapping):
            out.append(DaemonInfo(prefix))
            continue
        cfg, z = st.get("config"), st.get("zenoh")
        listen = z.get("listen") if isinstance(z, Mapping) else None
        out.append(
            DaemonInfo(
                prefix,
                name=cfg.get("name") if isinstance(cfg, Mapping) else None,
                state=st.get("state") if isinstance(st.get("state"), str) else None,
                listen=tuple(str(e) for e in listen) if isinstance(listen, list) else None,
            )
        )
    return out


def discover(
    endpoint: str | None = None,
    *,
    zenoh_config: str | None = None,
    timeout_s: float = transport.DEFAULT_TIMEOUT_S,
) -> list[DaemonInfo]:
    """Every live daemon reachable via `endpoint` (default: `$CABLEBOT_ENDPOINT`, else
    `tcp/127.0.0.1:7447`), by `list_daemons` on a session of its own. Raises UsageError,
    DaemonAbsent (nothing accepts the connection)."""
    given = transport.default_endpoint() if endpoint is None else endpoint
    with transport.open_session(given, config_file=zenoh_config) as session:
        return list_daemons(session, timeout_s)
