"""Pre-tension before homing: every reel winds at a set torque until the reels are still.

Pure module (no I/O, no threads). A robot's cables may hang slack or unevenly tight before it
is homed: encoder turns then say little about where the effector is. The pre-tension puts every
reel in torque control, each pulling with the tension statics gives its cable at the home pose
(`controller.core.statics`), so the effector is drawn to that pose: with fixed tensions t_i,
the potential ``sum_i t_i |A_i - P| + m g z`` is convex in P whatever the layout (a
Hangprinter's low lines pull down, and their terms are convex all the same), and its one
minimum is where ``sum_i t_i u_i = m g e_z``, the home pose itself. Slack cables are wound
in, tight ones eased out, and when every reel has been still for a while the home pose is
declared there (the offsets that make the encoders say it), as Hangprinter users home with
their motors in torque mode.

`PretensionRun` is one such run, fed by the control loop every tick (which turns its tensions
into motor torques through the reel model at the reels' turns of that tick, so a spool that
builds up still pulls the tension, not the torque, of the start). The reels pull the full
tensions from the first tick: a lower start would let a reel that carries the payload pay out
and the effector drop, and the drives' velocity limit keeps the take-up of a slack line gentle.
It says when every cable has been slower than
`still_mps` for `settle_s` (done), or why the run failed: a cable that moved more than
`max_travel_m` (a reel that spins free, a cable that slips or is not anchored) or no stillness
within `timeout_s`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["PretensionRun", "PretensionSettings"]


@dataclass(frozen=True, slots=True)
class PretensionSettings:
    """How a pre-tension runs (`[homing]` keys `pretension_*`). Raises ValueError on
    construction if a value is not finite and positive."""

    still_mps: float = 0.001
    """A cable slower than this (m/s) is still."""
    settle_s: float = 2.0
    """Every cable must be still for this long before the home pose is declared: longer than
    half the slowest swing of the effector (on long, flat cables its vertical bounce changes
    the cable lengths by only a fraction of its motion, so a short window sees a turning point
    as stillness)."""
    timeout_s: float = 30.0
    """The run fails if the reels are not still by then."""
    max_travel_m: float = 0.5
    """The run fails if a cable's length changes by more than this."""
    speed_mps: float = 0.05
    """The drives turn no faster than this much cable per second while in torque control."""

    def __post_init__(self) -> None:
        for name in ("still_mps", "settle_s", "timeout_s", "max_travel_m", "speed_mps"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0.0):
                raise ValueError(f"PretensionSettings.{name} must be finite and > 0, got {v!r}")


class PretensionRun:
    """One pre-tension in progress (see the module docstring); the loop calls `update` every
    tick. Not thread-safe: the loop thread owns it.

    `tensions_n` are the full tensions (one per cable, N), `start_lengths_m` the cable
    lengths from the encoders when the run starts (only their changes matter, so an unhomed
    reel model serves), `start_s` the clock time it starts.
    Raises ValueError on a non-finite value or mismatched lengths.
    """

    __slots__ = (
        "_still_since_s",
        "settings",
        "start_lengths_m",
        "start_s",
        "still_after_s",
        "tensions_n",
        "worst_mps",
    )

    def __init__(
        self,
        settings: PretensionSettings,
        tensions_n: Sequence[float],
        start_lengths_m: Sequence[float],
        start_s: float,
    ) -> None:
        tensions = tuple(float(t) for t in tensions_n)
        lengths = [float(v) for v in start_lengths_m]
        if len(tensions) != len(lengths) or not tensions:
            raise ValueError(
                f"one tension per cable length needed, got {len(tensions)} and {len(lengths)}"
            )
        if not all(map(math.isfinite, [*tensions, *lengths, start_s])):
            raise ValueError("pre-tension tensions, lengths and start time must be finite")
        self.settings = settings
        self.tensions_n = tensions
        """The tensions to pull with (N)."""
        self.start_lengths_m = lengths
        self.start_s = float(start_s)
        self._still_since_s: float | None = None
        self.still_after_s: float | None = None
        """Seconds from the start until the reels were declared still (None: not yet)."""
        self.worst_mps = math.inf
        """The fastest cable's speed at the last update (m/s)."""

    def update(
        self, now_s: float, lengths_m: Sequence[float], rates_mps: Sequence[float]
    ) -> str | None:
        """Take the cables' lengths (m) and length rates (m/s) from the encoders at `now_s`.

        Returns why the run failed (a cable travelled too far, or not still in time; the
        text names the cable and the `[homing]` key), else None; `done` tells whether the
        reels have been still long enough. A non-finite value counts as moving. Raises
        nothing.
        """
        s = self.settings
        worst = 0.0
        worst_i = 0
        for i, (length, rate) in enumerate(zip(lengths_m, rates_mps, strict=True)):
            moved = abs(length - self.start_lengths_m[i])
            if not moved <= s.max_travel_m:
                return (
                    f"cable {i + 1} moved {moved:.3f} m without coming still "
                    f"(homing.pretension_max_travel_m {s.max_travel_m:g} m): is it on its "
                    "reel and fixed at both ends?"
                )
            speed = abs(rate) if math.isfinite(rate) else math.inf
            if speed > worst or i == 0:
                worst = speed
                worst_i = i
        self.worst_mps = worst
        elapsed = now_s - self.start_s
        if worst < s.still_mps:
            if self._still_since_s is None:
                self._still_since_s = now_s
            if now_s - self._still_since_s >= s.settle_s:
                self.still_after_s = elapsed
                return None
        else:
            self._still_since_s = None
        if elapsed > s.timeout_s:
            return (
                f"not still after {s.timeout_s:g} s (homing.pretension_timeout_s): cable "
                f"{worst_i + 1} at {worst * 1e3:.3g} mm/s (still below "
                f"{s.still_mps * 1e3:g} mm/s, homing.pretension_still_mps)"
            )
        return None

    @property
    def done(self) -> bool:
        """True once every cable has been still for `settle_s`."""
        return self.still_after_s is not None
