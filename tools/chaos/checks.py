"""The invariants of the chaos run, checked all along from what the daemon publishes (pose and
state over Zenoh), what the tap hears on the bus and what the simulated drives know (the truth).

`Checker` collects the violations (kind, text, time). The bus invariants are the tap's
(`equipment.Tap`); here: every number on Zenoh finite (a strict JSON parser), every fault and
e-stop named, the pose sequence without gaps beyond what a stall explains, the truth within the
tracking limit of the set-point while the daemon says it is tracking, and the daemon's memory.
"""

from __future__ import annotations

import json
import math
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from chaos.equipment import fpk

NAMED = re.compile(r"^[a-z][a-z0-9_]*(: \S|$)")
"""A named fault: "kind: what happened" (the daemon's convention: `stale_encoder: node 3 ...`),
or the kind alone (`estop`)."""
TRACKING_STATES = ("HOLDING", "MOVING")


def _no_constant(text: str) -> float:
    raise ValueError(f"non-finite number {text} in JSON")


def strict_json(data: bytes) -> Any:
    """JSON that refuses NaN and Infinity (Python's parser takes them by default)."""
    return json.loads(data, parse_constant=_no_constant)


def _finite_tree(value: Any) -> bool:
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, dict):
        return all(_finite_tree(v) for v in value.values())
    if isinstance(value, list):
        return all(_finite_tree(v) for v in value)
    return True


@dataclass
class Violation:
    kind: str
    text: str
    at_s: float


@dataclass
class Checker:
    """The invariants of one worker's run (thread-safe: Zenoh callbacks and the main loop)."""

    anchors: np.ndarray
    tracking_max_m: float
    started_s: float = field(default_factory=time.monotonic)
    violations: list[Violation] = field(default_factory=list)
    poses: int = 0
    seq_lost: int = 0
    seq_lost_in_stalls: int = 0
    seq_restarts: int = 0
    state: str = "?"
    reason: str | None = None
    transitions: list[tuple[float, str, str | None]] = field(default_factory=list)
    last_pose: dict[str, Any] | None = None
    pose_t: float = 0.0
    state_t: float = 0.0
    last_tracking_pose_m: list[float] | None = None
    rss: list[tuple[float, int, int]] = field(default_factory=list)
    tracking_checks: int = 0
    tracking_worst_m: float = 0.0
    tracking_excused: list[str] = field(default_factory=list)
    _last_seq: int | None = None
    _stalls: list[tuple[float, float]] = field(default_factory=list)
    _off_since_s: float | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock)
    on_state: Callable[[str, str | None], None] | None = None

    def violation(self, kind: str, text: str) -> None:
        """Record one broken invariant."""
        with self._lock:
            self.violations.append(Violation(kind, text, time.monotonic() - self.started_s))

    # --- stalls: the daemon stopped, starved or restarted (the pose sequence may jump) -------

    def stall(self, start_s: float, end_s: float) -> None:
        """The daemon could not run (or publish) between these monotonic times."""
        with self._lock:
            self._stalls.append((start_s, end_s))
            self._stalls = [s for s in self._stalls if s[1] > time.monotonic() - 30.0]

    def _in_stall(self, t: float, slack_s: float = 1.0) -> bool:
        return any(a - slack_s <= t <= b + slack_s for a, b in self._stalls)

    # --- Zenoh ---------------------------------------------------------------------------------

    def pose_sample(self, data: bytes) -> None:
        """A `<prefix>/pose` sample: finite, sequence kept."""
        now = time.monotonic()
        try:
            pose = strict_json(data)
        except ValueError as exc:
            self.violation("nan_on_zenoh", f"pose: {exc}: {data[:120]!r}")
            return
        if not _finite_tree(pose):
            self.violation("nan_on_zenoh", f"pose: {data[:120]!r}")
            return
        with self._lock:
            self.poses += 1
            seq = int(pose.get("seq", -1))
            last = self._last_seq
            if last is not None:
                if seq <= last:
                    self.seq_restarts += 1  # a new daemon counts from the start
                elif seq > last + 1:
                    if self._in_stall(now):
                        self.seq_lost_in_stalls += seq - last - 1
                    else:
                        self.seq_lost += seq - last - 1
            self._last_seq = seq
            self.last_pose = pose
            self.pose_t = now
            if (
                pose.get("state") in TRACKING_STATES
                and pose.get("position_m")
                and pose.get("valid")
            ):
                self.last_tracking_pose_m = list(pose["position_m"])

    def state_sample(self, data: bytes) -> None:
        """A `<prefix>/state` sample: finite, every FAULT and ESTOPPED named."""
        try:
            msg = strict_json(data)
        except ValueError as exc:
            self.violation("nan_on_zenoh", f"state: {exc}: {data[:120]!r}")
            return
        state = str(msg.get("state"))
        reason = msg.get("reason")
        named = isinstance(reason, str) and NAMED.match(reason) and "unknown" not in reason
        if state in ("FAULT", "ESTOPPED") and not named:
            self.violation("unnamed_fault", f"{state} with reason {reason!r}")
        with self._lock:
            self.state = state
            self.reason = reason
            self.state_t = time.monotonic()
            self.transitions.append((time.monotonic(), state, reason))
        if self.on_state is not None:
            self.on_state(state, reason)

    def current_state(self) -> str:
        """The daemon's state as the newer of its latest pose sample and state message says."""
        pose = self.last_pose
        if pose is not None and self.pose_t >= self.state_t:
            return str(pose.get("state"))
        return self.state

    # --- the truth against the set-point -------------------------------------------------------

    def tracking(
        self,
        truth_lengths: np.ndarray,
        commanded: np.ndarray | None,
        daemon_ran: bool,
        machine_stalls: Callable[[float, float], list[tuple[float, float]]] = lambda a, b: [],
    ) -> None:
        """One tracking check: while the daemon says HOLDING or MOVING (and has run for the
        last half second: a stopped daemon says what it said last), the true pose within the
        tracking limit of the commanded one, allowing for the tap's and the drives' sampling
        skew (the commanded speed times 50 ms); broken only when it lasts half a second."""
        now = time.monotonic()
        if commanded is None or self.state not in TRACKING_STATES or not daemon_ran:
            self._off_since_s = None
            return
        guess = np.array(self.last_tracking_pose_m or [0.0, 0.0, 0.3])
        truth, _ = fpk(self.anchors, truth_lengths, guess)
        sp, _ = fpk(self.anchors, commanded, guess)
        err = float(np.linalg.norm(truth - sp))
        self.tracking_checks += 1
        allowed = self.tracking_max_m + 0.3 * 0.05
        if err <= allowed:
            self._off_since_s = None
            return
        self.tracking_worst_m = max(self.tracking_worst_m, err)
        if self._off_since_s is None:
            self._off_since_s = now
        elif now - self._off_since_s > 0.5:
            what = (
                f"truth {err * 1e3:.1f} mm from the set-point for "
                f"{now - self._off_since_s:.2f} s while {self.state}"
            )
            # The truth is the simulated drives in this process: stalled with the machine, they
            # stood still while the daemon moved on. Not the robot's doing: noted.
            if machine_stalls(self._off_since_s - 0.5, now):
                self.tracking_excused.append(what)
            else:
                self.violation("tracking", what)
            self._off_since_s = None

    # --- memory --------------------------------------------------------------------------------

    def sample_rss(self, rss: int | None, daemon_start: int) -> None:
        """One sample of the daemon's RSS."""
        if rss is not None:
            self.rss.append((time.monotonic() - self.started_s, rss, daemon_start))

    def check_memory(
        self, max_growth_mib: float = 64.0, max_slope_mib_per_min: float = 1.0
    ) -> None:
        """RSS bounded: the longest-running daemon grew at most `max_growth_mib` after it
        settled, and (runs of 5 minutes or more) its second half's slope is at most
        `max_slope_mib_per_min`."""
        s = self.rss_summary()
        if s.get("settled_mib") is not None and s["end_mib"] - s["settled_mib"] > max_growth_mib:
            self.violation(
                "memory", f"RSS grew {s['end_mib'] - s['settled_mib']:.1f} MiB after settling: {s}"
            )
        half = s.get("second_half_slope_mib_per_min")
        if half is not None and s["span_s"] >= 300.0 and half > max_slope_mib_per_min:
            self.violation(
                "memory", f"RSS still growing {half:.2f} MiB/min in the second half: {s}"
            )

    def rss_summary(self) -> dict[str, Any]:
        """RSS at the start and end of the longest-running daemon, and the slope of a line
        fitted to its samples after the first 20 s (bytes per minute)."""
        if not self.rss:
            return {"start_mib": None, "end_mib": None, "slope_mib_per_min": None}
        runs: dict[int, list[tuple[float, int]]] = {}
        for t, rss, start in self.rss:
            runs.setdefault(start, []).append((t, rss))
        longest = max(runs.values(), key=lambda r: r[-1][0] - r[0][0])
        t0 = longest[0][0]
        settled = [(t, r) for t, r in longest if t - t0 >= 20.0]
        slope = half = None
        if len(settled) >= 5:
            ts = np.array([t for t, _ in settled])
            rs = np.array([r for _, r in settled], dtype=float)
            slope = float(np.polyfit(ts, rs, 1)[0]) * 60.0 / 2**20
            late = ts >= ts[0] + 0.5 * (ts[-1] - ts[0])
            if int(late.sum()) >= 5:
                half = float(np.polyfit(ts[late], rs[late], 1)[0]) * 60.0 / 2**20
        return {
            "start_mib": round(longest[0][1] / 2**20, 1),
            "settled_mib": round(settled[0][1] / 2**20, 1) if settled else None,
            "end_mib": round(longest[-1][1] / 2**20, 1),
            "span_s": round(longest[-1][0] - t0, 1),
            "slope_mib_per_min": None if slope is None else round(slope, 3),
            "second_half_slope_mib_per_min": None if half is None else round(half, 3),
        }
