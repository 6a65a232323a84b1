"""Input shaping: the set-point convolved with a train of impulses so the motion cancels the
vibration it excites in the effector's modes (users: docs/shaping.md).

A lightly damped mode of natural frequency ``f`` and damping ratio ``zeta`` struck by an
impulse rings at the damped frequency ``f_d = f sqrt(1 - zeta^2)``. A second impulse half a
damped period later, sized to the first's decayed ringing, cancels it: the ZV shaper. Any
command convolved with such a train (impulse amplitudes ``A_k`` summing to 1, at delays
``t_k``) excites no residual vibration in that mode, whatever its shape, at the price of a
delay: the train's duration. The more impulses, the wider the band of frequencies the train
suppresses (robustness to a wrong frequency) and the longer the delay. The trains here (Singer
and Seering's ZV and ZVD; MZV; Singhose, Seering and Singer's extra-insensitive EI with one,
two and three humps), for zeta = 0, with times in damped periods ``T_d = 1 / f_d``:

=========  =======================================  =====================================
type       amplitudes                               times (T_d)
=========  =======================================  =====================================
zv         1/2, 1/2                                 0, 1/2
mzv        (1, sqrt 2, 1) / (2 + sqrt 2)            0, 3/8, 3/4
zvd        1/4, 1/2, 1/4                            0, 1/2, 1
ei         (1+V)/4, (1-V)/2, (1+V)/4                0, 1/2, 1
2hump_ei   a, 1/2-a, 1/2-a, a;                      0, 1/2, 1, 3/2
           a = (3X^2 + 2X + 3V^2) / (16 X),
           X = (V^2 (sqrt(1 - V^2) + 1))^(1/3)
3hump_ei   b, c, 1-2(b+c), c, b;                    0, 1/2, 1, 3/2, 2
           b = (1 + 3V + 2 sqrt(2V(V+1))) / 16,
           c = (1 - V) / 4
=========  =======================================  =====================================

``V`` = `VIBRATION_TOLERANCE` (5 %): the residual the EI trains allow at their humps in
exchange for a band several times wider than ZVD's. With damping, each impulse is scaled by
``exp(-zeta 2 pi f t_k)`` (the ringing of the earlier impulses has decayed by then) and the
amplitudes normalised again: the zero-vibration trains then cancel the damped mode exactly and
the EI trains keep their shape about the design frequency. `residual_vibration` gives the
fraction of a mode's ringing a train leaves (1 = unshaped).

`InputShaper` applies one train per mode in cascade: the set-point goes through the first
mode's train, the result through the second's, and so on (the convolution of the trains, at the
cost of the sum, not the product, of their impulse counts). Every train is one scalar train
applied to all three axes, so a straight move stays on its line and the shaped set-point is a
weighted average of past set-points: its speed and acceleration do not exceed the largest the
unshaped one had, and it stays in the convex hull of where the set-point has been. The
frequencies may change every tick (the modes follow the pose); each stage
keeps the set-points and velocities of the time its longest train can reach back in a ring,
stamped with planner time, and reads them by linear interpolation (O(1) per impulse: each
impulse keeps its place in the ring). The loop wants the shaped set-point's acceleration (the
payload's m a in the planned tensions) and ticks come unevenly: differentiating the shaped
positions would turn the interpolation's error, which changes with where each tick falls
between two samples, into noise. So the rings carry velocities too, the shaped velocity is
their weighted average (exact: the planner's velocity is piecewise linear), each stage's
velocity includes the drift of its delay as the frequency follows the pose (d delay / dt), and
the acceleration is the shaped velocity's change over the tick. The loop asks for the modes
where the shaped set-point is now, not where it was a tick ago.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

Vec3 = tuple[float, float, float]

SHAPER_TYPES: tuple[str, ...] = ("off", "zv", "mzv", "zvd", "ei", "2hump_ei", "3hump_ei")
"""Every shaper type a configuration or M593 may name."""
DEFAULT_SHAPER_TYPE = "2hump_ei"
"""The default: a cable robot's frequencies follow its pose and payload, change along a move,
and the model's may be off by 15 % (an EA 30 % off); the two-hump EI train keeps a mode's
residual within 5 % from 0.64 to 1.36 times its design frequency (EI: 0.80 to 1.20, ZVD: 0.86
to 1.14) and cancels it at the design frequency, for a delay of 1.5 periods (docs/shaping.md
measures it against the others)."""
DEFAULT_DAMPING_RATIO = 0.02
"""The modes' damping ratio the trains assume unless configured: a rope's (0.005 to 0.05)."""
MAX_DAMPING_RATIO = 0.3
"""Above this the shaper's model of a lightly damped mode no longer holds (and there is
little to cancel): refused."""
MAX_PASSES = 3
"""The most times a mode's train may be applied in a row (`[shaper] passes`): each pass
multiplies the residual a wrong frequency leaves by the train's own, and adds its delay."""
MIN_FREQUENCY_HZ = 0.05
"""The lowest frequency a shaper may target (a 20 s period)."""
MAX_FREQUENCY_HZ = 1000.0
"""The highest frequency a shaper may target."""
_TIME_EPS_S = 1e-9
"""Times this close count as equal (the planner's time is a sum of ticks)."""
MAX_FREQUENCY_STEP = 0.005
"""A stage's frequency changes by at most this fraction per loop period (a mode's frequency
follows the pose slowly; a jump would move the shaped set-point at once)."""
VIBRATION_TOLERANCE = 0.05
"""The residual vibration the EI trains allow at their humps (the designs' V)."""


class ShaperError(ValueError):
    """An unknown shaper type, or a frequency or damping ratio out of range."""


def _unit_trains() -> dict[str, tuple[tuple[float, ...], tuple[float, ...]]]:
    """The undamped trains: (amplitudes, times in damped periods) by type (module table)."""
    v = VIBRATION_TOLERANCE
    r2 = math.sqrt(2.0)
    x = (v * v * (math.sqrt(1.0 - v * v) + 1.0)) ** (1.0 / 3.0)
    a2 = (3.0 * x * x + 2.0 * x + 3.0 * v * v) / (16.0 * x)
    b3 = (1.0 + 3.0 * v + 2.0 * math.sqrt(2.0 * v * (v + 1.0))) / 16.0
    c3 = (1.0 - v) / 4.0
    return {
        "zv": ((0.5, 0.5), (0.0, 0.5)),
        "mzv": ((1.0 / (2.0 + r2), r2 / (2.0 + r2), 1.0 / (2.0 + r2)), (0.0, 0.375, 0.75)),
        "zvd": ((0.25, 0.5, 0.25), (0.0, 0.5, 1.0)),
        "ei": (((1.0 + v) / 4.0, (1.0 - v) / 2.0, (1.0 + v) / 4.0), (0.0, 0.5, 1.0)),
        "2hump_ei": ((a2, 0.5 - a2, 0.5 - a2, a2), (0.0, 0.5, 1.0, 1.5)),
        "3hump_ei": (
            (b3, c3, 1.0 - 2.0 * (b3 + c3), c3, b3),
            (0.0, 0.5, 1.0, 1.5, 2.0),
        ),
    }


_UNIT_TRAINS = _unit_trains()


def check_shaper(kind: str, frequency_hz: float | None, damping_ratio: float) -> str | None:
    """None if the shaper is usable, else the reason (naming the value and its range): `kind`
    one of `SHAPER_TYPES`, `frequency_hz` (None: the model's) within `MIN_FREQUENCY_HZ` ..
    `MAX_FREQUENCY_HZ`, `damping_ratio` within 0 .. `MAX_DAMPING_RATIO`. Raises nothing."""
    if kind not in SHAPER_TYPES:
        return f"unknown shaper type {kind!r} (one of {', '.join(SHAPER_TYPES)})"
    if frequency_hz is not None:
        f = _number(frequency_hz)
        if not (MIN_FREQUENCY_HZ <= f <= MAX_FREQUENCY_HZ):
            return (
                f"frequency {frequency_hz!r} Hz out of range "
                f"({MIN_FREQUENCY_HZ:g} to {MAX_FREQUENCY_HZ:g} Hz)"
            )
    z = _number(damping_ratio)
    if not (0.0 <= z <= MAX_DAMPING_RATIO):
        return f"damping ratio {damping_ratio!r} out of range (0 to {MAX_DAMPING_RATIO:g})"
    return None


def _number(value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return math.nan
    return float(value)


def unit_train(kind: str, damping_ratio: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The train of `kind` for modes of `damping_ratio`: (amplitudes summing to 1, times in
    undamped periods 1/f: multiply by 1/f for seconds). Empty for "off". Raises ShaperError for
    an unknown type or a damping ratio out of range."""
    reason = check_shaper(kind, None, damping_ratio)
    if reason is not None:
        raise ShaperError(reason)
    if kind == "off":
        return (), ()
    amps, times = _UNIT_TRAINS[kind]
    z = float(damping_ratio)
    stretch = 1.0 / math.sqrt(1.0 - z * z)  # damped period over undamped
    t = tuple(tk * stretch for tk in times)
    scaled = [a * math.exp(-2.0 * math.pi * z * tk) for a, tk in zip(amps, t, strict=True)]
    total = sum(scaled)
    return tuple(a / total for a in scaled), t


def impulses(
    kind: str, frequency_hz: float, damping_ratio: float
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The train of `kind` for a mode of `frequency_hz` and `damping_ratio`: (amplitudes
    summing to 1, delays in seconds from 0). Raises ShaperError as `check_shaper` says."""
    reason = check_shaper(kind, frequency_hz, damping_ratio)
    if reason is not None:
        raise ShaperError(reason)
    amps, times = unit_train(kind, damping_ratio)
    return amps, tuple(t / float(frequency_hz) for t in times)


def duration_periods(kind: str) -> float:
    """The train's duration in undamped periods at zero damping (0 for "off"). Raises
    ShaperError for an unknown type."""
    if kind == "off":
        return 0.0
    if kind not in _UNIT_TRAINS:
        raise ShaperError(f"unknown shaper type {kind!r} (one of {', '.join(SHAPER_TYPES)})")
    return _UNIT_TRAINS[kind][1][-1]


def residual_vibration(
    amplitudes: Sequence[float],
    times_s: Sequence[float],
    frequency_hz: float,
    damping_ratio: float,
) -> float:
    """The fraction of a mode's ringing the train leaves: the amplitude of the mode's vibration
    after the last impulse over that of one unit impulse at the same time (1 = unshaped; 0 =
    cancelled). Raises ValueError for a damping ratio >= 1 or mismatched sequences."""
    z = float(damping_ratio)
    if not 0.0 <= z < 1.0:
        raise ValueError(f"damping ratio must be in [0, 1), got {damping_ratio!r}")
    if len(amplitudes) != len(times_s) or not amplitudes:
        raise ValueError("one time per amplitude, at least one")
    w = 2.0 * math.pi * float(frequency_hz)
    wd = w * math.sqrt(1.0 - z * z)
    end = max(times_s)
    c = s = 0.0
    for a, t in zip(amplitudes, times_s, strict=True):
        decay = math.exp(-z * w * (end - t))
        c += a * decay * math.cos(wd * t)
        s += a * decay * math.sin(wd * t)
    return math.hypot(c, s)


class _Stage:
    """One mode's train applied to a stream of set-points: a ring of past samples (time,
    position and velocity in flat lists, written in place) and each impulse's place in it.
    Between two samples both are read by linear interpolation."""

    __slots__ = (
        "cap",
        "count",
        "cursor",
        "taps",
        "tt",
        "tu",
        "tv",
        "tw",
        "tx",
        "ty",
        "tz",
        "unit_times",
    )

    def __init__(self, amps: Sequence[float], unit_times: Sequence[float], capacity: int) -> None:
        self.unit_times = tuple(unit_times)
        self.taps = tuple(zip(range(len(amps)), amps, unit_times, strict=True))
        self.cap = capacity
        self.tt = [0.0] * capacity
        self.tx = [0.0] * capacity
        self.ty = [0.0] * capacity
        self.tz = [0.0] * capacity
        self.tu = [0.0] * capacity
        self.tv = [0.0] * capacity
        self.tw = [0.0] * capacity
        self.count = 0
        self.cursor = [0] * len(amps)

    def reset(self, now_s: float, p: Vec3) -> None:
        self.count = 0
        self.push(now_s, p, (0.0, 0.0, 0.0))
        self.cursor = [0] * len(self.cursor)

    def push(self, now_s: float, p: Vec3, v: Vec3) -> None:
        i = self.count & (self.cap - 1)
        self.tt[i] = now_s
        self.tx[i] = p[0]
        self.ty[i] = p[1]
        self.tz[i] = p[2]
        self.tu[i] = v[0]
        self.tv[i] = v[1]
        self.tw[i] = v[2]
        self.count += 1

    def step(
        self, now_s: float, p: Vec3, v: Vec3, period_s: float, inv_f: float, inv_f_rate: float
    ) -> tuple[Vec3, Vec3]:
        """Push `p` moving at `v` at `now_s` and apply the train for a mode of frequency
        1 / `inv_f`, which changes at `inv_f_rate` (1/Hz per s): the weighted samples at the
        impulses' delays; (position, velocity). The velocity is the position's derivative:
        each delayed sample's velocity times (1 - d delay / dt)."""
        m = self.cap - 1  # the capacity is a power of two: an index is a mask away
        count = self.count
        i = count & m
        tt, tx, ty, tz, tu, tv, tw = self.tt, self.tx, self.ty, self.tz, self.tu, self.tv, self.tw
        tt[i] = now_s
        tx[i] = p[0]
        ty[i] = p[1]
        tz[i] = p[2]
        tu[i] = v[0]
        tv[i] = v[1]
        tw[i] = v[2]
        self.count = count + 1
        newest = count
        oldest = count - m if count > m else 0
        cursor = self.cursor
        px = py = pz = vx = vy = vz = 0.0
        for k, w, tk in self.taps:
            delay = tk * inv_f
            wv = w * (1.0 - tk * inv_f_rate)  # the velocity's weight: w (1 - d delay / dt)
            when = now_s - delay
            c = cursor[k]
            if c < oldest or c > newest:
                c = newest - int(delay / period_s)
                c = oldest if c < oldest else newest if c > newest else c
            while c > oldest and tt[c & m] > when:
                c -= 1
            while c < newest and tt[(c + 1) & m] <= when:
                c += 1
            cursor[k] = c
            e = c & m
            t0 = tt[e]
            n = (c + 1) & m
            h = tt[n] - t0
            if c == newest or t0 >= when or not h > 0.0:
                px += w * tx[e]
                py += w * ty[e]
                pz += w * tz[e]
                vx += wv * tu[e]
                vy += wv * tv[e]
                vz += wv * tw[e]
                continue
            s = (when - t0) / h
            b = w * s
            r = w - b
            px += r * tx[e] + b * tx[n]
            py += r * ty[e] + b * ty[n]
            pz += r * tz[e] + b * tz[n]
            b = wv * s
            r = wv - b
            vx += r * tu[e] + b * tu[n]
            vy += r * tv[e] + b * tv[n]
            vz += r * tw[e] + b * tw[n]
        return (px, py, pz), (vx, vy, vz)


class InputShaper:
    """The control loop's input shaper: one train of `kind` per mode, in cascade (module
    docstring), for modes of `damping_ratio`.

    `stages` is the number of modes shaped (1 for a fixed frequency, 3 for the model's);
    `min_frequency_hz` the lowest frequency it will shape for (a lower one is raised to it: the
    rings hold the set-points of `duration_periods(kind) / min_frequency_hz` seconds per
    stage); `period_s` the loop's period (sizes the rings). Call `reset(position)` whenever the
    set-point is put somewhere (a hold), then `shape` once per tick. Raises ShaperError for an
    unknown type or a damping ratio out of range, ValueError for stages < 1 or a
    non-positive frequency floor or period.
    """

    __slots__ = (
        "_floor_hz",
        "_freqs",
        "_inv_f",
        "_now_s",
        "_out_a",
        "_out_p",
        "_out_v",
        "_period_s",
        "_quiet_s",
        "_raw_p",
        "_raw_v",
        "_stages",
        "damping_ratio",
        "kind",
    )

    def __init__(
        self,
        kind: str,
        damping_ratio: float,
        *,
        stages: int,
        min_frequency_hz: float,
        period_s: float,
    ) -> None:
        amps, unit_times = unit_train(kind, damping_ratio)
        if kind == "off":
            raise ShaperError('a shaper of type "off" shapes nothing: build none')
        if isinstance(stages, bool) or not isinstance(stages, int) or stages < 1:
            raise ValueError(f"stages must be an int >= 1, got {stages!r}")
        floor = float(min_frequency_hz)
        period = float(period_s)
        if not (math.isfinite(floor) and floor > 0.0 and math.isfinite(period) and period > 0.0):
            raise ValueError("min_frequency_hz and period_s must be finite and > 0")
        self.kind = kind
        self.damping_ratio = float(damping_ratio)
        longest_s = unit_times[-1] / floor
        # twice the ticks the longest train reaches back (ticks may come early after a late
        # one) and a margin, rounded up to a power of two (an index is then a mask)
        capacity = 1 << (math.ceil(2.0 * longest_s / period) + 64).bit_length()
        self._stages = [_Stage(amps, unit_times, capacity) for _ in range(stages)]
        self._floor_hz = floor
        self._period_s = period
        self._freqs: list[float] = [math.inf] * stages
        self._inv_f: list[float] = [0.0] * stages
        self._now_s = 0.0
        self._quiet_s = 0.0
        self._raw_p: Vec3 = (0.0, 0.0, 0.0)
        self._raw_v: Vec3 = (0.0, 0.0, 0.0)
        self._out_p: Vec3 = (0.0, 0.0, 0.0)
        self._out_v: Vec3 = (0.0, 0.0, 0.0)
        self._out_a: Vec3 = (0.0, 0.0, 0.0)
        self.reset((0.0, 0.0, 0.0))

    @property
    def stages(self) -> int:
        """The number of modes shaped."""
        return len(self._stages)

    @property
    def frequencies_hz(self) -> tuple[float, ...]:
        """The frequencies the stages shaped for at the last tick (after the floor)."""
        return tuple(self._freqs)

    @property
    def duration_s(self) -> float:
        """The cascade's delay at the last tick's frequencies: how long the shaped set-point
        takes to arrive after the unshaped one stops (0 before the first tick)."""
        return sum(
            s.unit_times[-1] / f
            for s, f in zip(self._stages, self._freqs, strict=True)
            if f < math.inf
        )

    @property
    def max_duration_s(self) -> float:
        """The longest delay the cascade can have (every stage at the frequency floor)."""
        return sum(s.unit_times[-1] for s in self._stages) / self._floor_hz

    @property
    def velocity_mps(self) -> Vec3:
        """The shaped set-point's velocity at the last tick: the unshaped velocity through the
        trains, with the delays' drift (the unshaped velocity once settled)."""
        return self._out_v

    @property
    def acceleration_mps2(self) -> Vec3:
        """The shaped set-point's acceleration over the last tick: the change of its velocity
        over the tick's time; zero once settled."""
        return self._out_a

    @property
    def position_m(self) -> Vec3:
        """The shaped set-point at the last tick."""
        return self._out_p

    @property
    def settled(self) -> bool:
        """True when the shaped set-point has arrived: the unshaped one has been still for as
        long as the cascade reaches back (at the current frequencies), so every impulse reads
        where it stopped and both are the same point."""
        return self._now_s - self._quiet_s >= self.duration_s - _TIME_EPS_S

    def reset(self, position_m: Sequence[float]) -> None:
        """Forget the past: the set-point is at rest at `position_m` (a hold). Raises
        nothing for finite coordinates."""
        p = (float(position_m[0]), float(position_m[1]), float(position_m[2]))
        for stage in self._stages:
            stage.reset(self._now_s, p)
        self._raw_p = p
        self._raw_v = (0.0, 0.0, 0.0)
        self._out_p = p
        self._out_v = (0.0, 0.0, 0.0)
        self._out_a = (0.0, 0.0, 0.0)
        self._inv_f = [0.0] * len(self._stages)
        self._quiet_s = self._now_s - 2.0 * self.max_duration_s

    def shape(
        self,
        position_m: Vec3,
        velocity_mps: Vec3,
        dt_s: float,
        frequencies_hz: Sequence[float] | None,
    ) -> Vec3:
        """The shaped set-point for the unshaped `position_m` moving at `velocity_mps`, `dt_s`
        after the last call, with each stage's mode at `frequencies_hz` (ascending; None or a
        short or non-finite tuple keeps the last ones; below the floor: the floor; each moves
        at most `MAX_FREQUENCY_STEP` a period of time from the last). Its velocity
        is `velocity_mps` afterwards. Once settled, exactly `position_m` (and `velocity_mps`,
        zero then). Raises nothing for finite inputs."""
        if dt_s > 0.0:
            self._now_s += dt_s
        now = self._now_s
        if position_m != self._raw_p or velocity_mps != self._raw_v:
            self._quiet_s = now
            self._raw_p = position_m
            self._raw_v = velocity_mps
        if frequencies_hz is not None and len(frequencies_hz) >= len(self._stages):
            floor = self._floor_hz
            freqs = self._freqs
            for k in range(len(self._stages)):
                f = frequencies_hz[k]
                if f == f and f < math.inf:  # finite
                    if f < floor:
                        f = floor
                    old = freqs[k]
                    if old < math.inf:  # no jumps: at most MAX_FREQUENCY_STEP a period
                        step = old * MAX_FREQUENCY_STEP * dt_s / self._period_s
                        f = old - step if f < old - step else old + step if f > old + step else f
                    freqs[k] = f
        if self.settled:
            for stage in self._stages:
                stage.push(now, position_m, velocity_mps)
            self._out_p = position_m
            self._out_v = velocity_mps
            self._out_a = (0.0, 0.0, 0.0)
            return position_m
        p = position_m
        v = velocity_mps
        period = self._period_s
        floor = self._floor_hz
        inv_last = self._inv_f
        for k, (stage, f) in enumerate(zip(self._stages, self._freqs, strict=True)):
            inv = 1.0 / (floor if f == math.inf else f)
            inv_before = inv_last[k]
            rate = (inv - inv_before) / dt_s if dt_s > 0.0 and inv_before > 0.0 else 0.0
            inv_last[k] = inv
            p, v = stage.step(now, p, v, period, inv, rate)
        if dt_s > 0.0:
            # the velocity's change over the tick: exact whatever the ticks' lengths (the
            # velocity of the planner's piecewise quadratic motion is piecewise linear, which
            # the rings read exactly, and the delays' drift is in it)
            before = self._out_v
            self._out_a = (
                (v[0] - before[0]) / dt_s,
                (v[1] - before[1]) / dt_s,
                (v[2] - before[2]) / dt_s,
            )
        self._out_v = v
        self._out_p = p
        return p
