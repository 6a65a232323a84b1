"""The control loop's input shaper, built from the configuration's `[shaper]`: the trains of
`controller.core.motion.shaper` at the frequencies of the effector's modes, which follow the
set-point (`controller.core.vibration.ModeTracker`, scaled by `frequency_scale`) or are one
fixed `frequency_hz`; and the range of the model's modes over the workspace (for the shaper's
frequency floor and `cablebot check-config`).

The loop asks `LoopShaper.shape` once per tick with the planner's set-point and velocity, the
last shaped set-point and the tensions planned there; `reset` whenever the planner holds.
`change` swaps the train, frequency and damping at run time (M593, the `shaper` command) at the
next moment the set-point is at rest.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from controller.core.motion.shaper import InputShaper, ShaperError, check_shaper
from controller.core.statics import TensionCheck
from controller.core.vibration import ModesError, ModeTracker, effector_modes
from controller.core.workspace import Workspace

Vec3 = tuple[float, float, float]

FLOOR_MARGIN = 0.7
"""The shaper's lowest frequency is this fraction of the lowest the model gives anywhere in
the workspace (the grid between its samples, a payload's swing)."""
RANGE_STEPS = (9, 9, 5)
"""Grid of the workspace box sampled for the modes' range (x, y, z)."""


@dataclass(frozen=True, slots=True)
class ModeRange:
    """The model's modes over the workspace: each mode's lowest and highest frequency (Hz) and
    lowest and highest damping ratio, over `points` sampled poses (those where statics holds
    the payload); `skipped` poses had no modes (a slack cable)."""

    low_hz: tuple[float, float, float]
    high_hz: tuple[float, float, float]
    low_damping: tuple[float, float, float]
    high_damping: tuple[float, float, float]
    points: int
    skipped: int


def model_ea(cfg: Any) -> list[float | None]:
    """Each reel's `cable_ea_n` (None: rigid). Raises nothing."""
    return [r.cable_ea_n for r in cfg.reels]


def mode_range(
    cfg: Any,
    check: TensionCheck,
    damping_ratio: float,
    steps: Sequence[int] = RANGE_STEPS,
) -> ModeRange | None:
    """The model's modes over a grid of the workspace box (inside the workspace, where statics
    holds the payload), with the ropes' `damping_ratio`; None when no pose gives modes. Raises
    ModesError for a rigid model, WorkspaceError for no workspace."""
    ea = model_ea(cfg)
    if None in ea:
        raise ModesError("a rigid model (no `[[reels]] cable_ea_n`) has no modes")
    low = [math.inf] * 3
    high = [0.0] * 3
    dlow = [math.inf] * 3
    dhigh = [0.0] * 3
    points = skipped = 0
    for p, t in _holding_poses(cfg, check, steps):
        try:
            m = effector_modes(
                cfg.anchors_m, p, t, ea, check.mass_kg, cable_damping_ratio=damping_ratio
            )
        except ModesError:
            skipped += 1
            continue
        points += 1
        for j in range(3):
            low[j] = min(low[j], m.frequencies_hz[j])
            high[j] = max(high[j], m.frequencies_hz[j])
            dlow[j] = min(dlow[j], m.damping_ratios[j])
            dhigh[j] = max(dhigh[j], m.damping_ratios[j])
    if points == 0:
        return None
    return ModeRange(
        (low[0], low[1], low[2]),
        (high[0], high[1], high[2]),
        (dlow[0], dlow[1], dlow[2]),
        (dhigh[0], dhigh[1], dhigh[2]),
        points,
        skipped,
    )


def lowest_frequency_hz(cfg: Any, check: TensionCheck, steps: Sequence[int] = RANGE_STEPS) -> float:
    """The model's lowest natural frequency over the grid `mode_range` samples (the scalar
    `ModeTracker`: a few microseconds a pose); inf where no pose has modes. Raises ModesError
    for a rigid model, WorkspaceError for no workspace."""
    tracker = ModeTracker(cfg.anchors_m, model_ea(cfg), check.mass_kg)
    lowest = math.inf
    for p, t in _holding_poses(cfg, check, steps):
        f = tracker.frequencies_hz(p, t)
        if f is not None and f[0] < lowest:
            lowest = f[0]
    return lowest


def _holding_poses(
    cfg: Any, check: TensionCheck, steps: Sequence[int]
) -> list[tuple[list[float], list[float]]]:
    """(pose, tensions) on a grid of the workspace box, inside the workspace, where statics
    holds the payload within the tension rule."""
    ws = Workspace.from_limits(cfg.limits, cfg.geometry)
    (x0, x1), (y0, y1), (z0, z1) = ws.box()
    grid = np.stack(
        np.meshgrid(
            np.linspace(x0, x1, steps[0]),
            np.linspace(y0, y1, steps[1]),
            np.linspace(z0, z1, steps[2]),
            indexing="ij",
        ),
        axis=-1,
    ).reshape(-1, 3)
    inside = grid[ws.inside_points(grid)]
    tensions, margin, _, _ = check.statics.solve_batch(inside, check.mass_kg)
    return [
        (p, t)
        for p, t, mg in zip(inside.tolist(), tensions.tolist(), margin.tolist(), strict=True)
        if mg >= check.margin_n
    ]


class LoopShaper:
    """The shaper of the robot `cfg` (its `[shaper]`; type "off" passes the set-point through)
    for a loop of period `period_s`, with the payload's tension rule `check` (needed for the
    model's modes).

    Raises ShaperError for a shaper the configuration should have refused, ModesError when the
    model's modes are wanted but cannot be had (a rigid cable, no payload, no pose with modes).
    Not thread-safe: the loop owns it (`change` included, which the loop calls).
    """

    __slots__ = (
        "_fixed",
        "_floor_hz",
        "_pending",
        "_period_s",
        "_raw_a",
        "_raw_v",
        "_tracker",
        "settings",
        "shaper",
    )

    def __init__(self, cfg: Any, period_s: float, check: TensionCheck | None) -> None:
        sc = cfg.shaper
        self._period_s = float(period_s)
        self._tracker: ModeTracker | None = None
        self._floor_hz = math.inf
        if check is not None and None not in model_ea(cfg):
            self._tracker = ModeTracker(
                cfg.anchors_m, model_ea(cfg), check.mass_kg, sc.frequency_scale
            )
            lowest = lowest_frequency_hz(cfg, check)
            if lowest < math.inf:
                self._floor_hz = FLOOR_MARGIN * lowest * sc.frequency_scale
            else:
                self._tracker = None
        self._check(sc.type, sc.frequency_hz, sc.damping_ratio)
        self.settings = sc
        self._pending: Any = None
        self._fixed: tuple[float, ...] | None = None
        self._raw_v: Vec3 = (0.0, 0.0, 0.0)
        self._raw_a: Vec3 = (0.0, 0.0, 0.0)
        self.shaper = self._build(sc)

    def _check(self, kind: str, frequency_hz: float | None, damping_ratio: float) -> None:
        """ShaperError for a bad value, ModesError for the model's modes without a model."""
        reason = check_shaper(kind, frequency_hz, damping_ratio)
        if reason is not None:
            raise ShaperError(reason)
        if kind != "off" and frequency_hz is None and self._tracker is None:
            raise ModesError(
                "no model of the modes (reels without cable_ea_n, or no [payload], or no pose "
                "with modes): give a frequency"
            )

    def _build(self, sc: Any) -> InputShaper | None:
        """The shaper of settings `sc` (checked): none for "off", one stage at a fixed
        frequency, three following the model."""
        self._fixed = None
        if sc.type == "off":
            return None
        passes = int(sc.passes)
        if sc.frequency_hz is not None:
            f = float(sc.frequency_hz)
            self._fixed = (f,) * passes
            return InputShaper(
                sc.type,
                sc.damping_ratio,
                stages=passes,
                min_frequency_hz=f,
                period_s=self._period_s,
            )
        return InputShaper(
            sc.type,
            sc.damping_ratio,
            stages=3 * passes,
            min_frequency_hz=self._floor_hz,
            period_s=self._period_s,
        )

    @property
    def enabled(self) -> bool:
        """True while a train shapes the set-point."""
        return self.shaper is not None

    @property
    def follows_model(self) -> bool:
        """True when the frequencies are the model's at the set-point."""
        return self.shaper is not None and self._fixed is None

    def describe(self) -> dict[str, Any]:
        """The shaper as status reports it: type, damping ratio, the frequencies of the last
        tick, the delay it adds, whether a change waits for the next rest."""
        sc = self.settings
        sh = self.shaper
        return {
            "type": sc.type,
            "damping_ratio": sc.damping_ratio,
            "frequency_hz": sc.frequency_hz,
            "frequency_scale": sc.frequency_scale,
            "passes": sc.passes,
            "frequencies_hz": []
            if sh is None
            else [f for f in sh.frequencies_hz[: sh.stages // sc.passes] if f < math.inf],
            "delay_s": 0.0 if sh is None else sh.duration_s,
            "pending": None if self._pending is None else self._pending.type,
        }

    def reset(self, position_m: Vec3) -> None:
        """The set-point holds at `position_m`: forget the past (and take a pending change)."""
        if self._pending is not None:
            self._apply_pending()
        self._raw_v = self._raw_a = (0.0, 0.0, 0.0)
        if self.shaper is not None:
            self.shaper.reset(position_m)

    def shape(
        self,
        position_m: Vec3,
        velocity_mps: Vec3,
        dt_s: float,
        at_m: Vec3 | None,
        tensions_n: Sequence[float] | None,
    ) -> Vec3:
        """The shaped set-point for the planner's `position_m` and `velocity_mps`, `dt_s` after
        the last tick; the modes are the model's at `at_m` (the last shaped set-point) with
        the `tensions_n` planned there, or the fixed frequency. Raises nothing for finite
        inputs."""
        sh = self.shaper
        if sh is None:
            pv = self._raw_v
            self._raw_a = (
                (
                    (velocity_mps[0] - pv[0]) / dt_s,
                    (velocity_mps[1] - pv[1]) / dt_s,
                    (velocity_mps[2] - pv[2]) / dt_s,
                )
                if dt_s > 0.0
                else (0.0, 0.0, 0.0)
            )
            self._raw_v = velocity_mps
            return position_m
        if self._fixed is not None:
            freqs: Sequence[float] | None = self._fixed
        elif self._tracker is not None and at_m is not None and tensions_n is not None:
            # where the shaped set-point is now (the last one moved on by its velocity): the
            # frequencies then change smoothly in time whatever the ticks' lengths (a tick
            # late, a tick's jitter would shake the delays, and the set-point with them)
            v = sh.velocity_mps
            now = (at_m[0] + v[0] * dt_s, at_m[1] + v[1] * dt_s, at_m[2] + v[2] * dt_s)
            modes = self._tracker.frequencies_hz(now, tensions_n)
            passes = self.settings.passes
            # with more passes each mode's train comes again, in cascade
            freqs = modes if modes is None or passes == 1 else modes * passes
        else:
            freqs = None
        return sh.shape(position_m, velocity_mps, dt_s, freqs)

    @property
    def velocity_mps(self) -> Vec3:
        """The shaped set-point's velocity at the last tick."""
        sh = self.shaper
        return self._raw_v if sh is None else sh.velocity_mps

    @property
    def acceleration_mps2(self) -> Vec3:
        """The set-point's acceleration at the last tick (the shaped one's, or the change of
        the planner's velocity over the tick)."""
        sh = self.shaper
        return self._raw_a if sh is None else sh.acceleration_mps2

    @property
    def settled(self) -> bool:
        """True when the shaped set-point has arrived where the planner's is."""
        sh = self.shaper
        return sh is None or sh.settled

    def change(
        self,
        kind: str,
        frequency_hz: float | None,
        damping_ratio: float | None,
        at_m: Vec3,
    ) -> str:
        """Take a new train (`kind`, "off" for none), frequency (None: the model's) and damping
        ratio (None: keep); applied at once when the set-point (`at_m`) is at rest
        (`settled`), else when it next is (`take_pending`). Returns "now" or "at rest". Raises
        ShaperError for a bad value, ModesError for the model's frequency without a model
        (nothing changes then)."""
        damping = self.settings.damping_ratio if damping_ratio is None else float(damping_ratio)
        self._check(kind, frequency_hz, damping)
        self._pending = replace(
            self.settings, type=kind, frequency_hz=frequency_hz, damping_ratio=damping
        )
        if self.take_pending(at_m):
            return "now"
        return "at rest"

    def take_pending(self, at_m: Vec3) -> bool:
        """Apply a change that waited for the set-point to come to rest, if it is at rest now
        at `at_m`; True if one was applied. The loop calls it when a motion ends."""
        if self._pending is None or not self.settled:
            return False
        self._apply_pending()
        self._raw_v = self._raw_a = (0.0, 0.0, 0.0)
        if self.shaper is not None:
            self.shaper.reset(at_m)
        return True

    def _apply_pending(self) -> None:
        sc = self._pending
        self._pending = None
        self.settings = sc
        self.shaper = self._build(sc)

    def max_delay_s(self) -> float:
        """The longest delay the shaper may add to a move (every stage at its lowest
        frequency; 0 when off)."""
        return 0.0 if self.shaper is None else self.shaper.max_duration_s
