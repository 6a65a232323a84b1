"""Input shaping (`controller.core.motion.shaper`): the impulse trains against an independent
simulation of a damped mode (scipy), the online cascade against a direct convolution, and the
guarantees the control loop relies on (straight lines, speed and acceleration bounds, exact
arrival, named errors)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from controller.core.motion import TrapezoidMove
from controller.core.motion.shaper import (
    DEFAULT_SHAPER_TYPE,
    SHAPER_TYPES,
    VIBRATION_TOLERANCE,
    InputShaper,
    ShaperError,
    check_shaper,
    duration_periods,
    impulses,
    residual_vibration,
    unit_train,
)

TYPES = SHAPER_TYPES[1:]
FAST = settings(max_examples=40, deadline=None, derandomize=True)


def lsim_residual(
    amps: tuple[float, ...], times: tuple[float, ...], f: float, zeta: float
) -> float:
    """The residual vibration of a mode (f, zeta) after the train, by scipy: the mode's
    response to the shaped unit step, its amplitude after the last impulse over that of an
    unshaped step's."""
    w = 2.0 * math.pi * f
    mode = signal.lti([w * w], [1.0, 2.0 * zeta * w, w * w])
    dt = 1.0 / (f * 2000.0)
    t = np.arange(0.0, times[-1] + 20.0 / f, dt)

    wd = w * math.sqrt(1.0 - zeta * zeta)
    at = int(np.searchsorted(t, times[-1] + 0.5 / f))

    def swing(u: np.ndarray) -> float:
        # the envelope of the free ringing about 1 at a time after the last impulse: for
        # e = y - 1 = A exp(-zeta w t) sin(wd t + phi), A exp(-zeta w t) is
        # sqrt(e^2 + ((de/dt + zeta w e) / wd)^2)
        _, y, _ = signal.lsim(mode, u, t)
        e = y - 1.0
        de = np.gradient(e, dt)
        return float(math.hypot(e[at], (de[at] + zeta * w * e[at]) / wd))

    shaped = sum(a * (t >= tk - 1e-12) for a, tk in zip(amps, times, strict=True))
    plain = (t >= times[-1] - 1e-12).astype(float)
    return swing(np.asarray(shaped, dtype=float)) / swing(plain)


@pytest.mark.parametrize("kind", TYPES)
@pytest.mark.parametrize("zeta", [0.0, 0.02, 0.1])
def test_trains_sum_to_one_and_cancel_at_their_frequency(kind: str, zeta: float) -> None:
    amps, times = impulses(kind, 2.0, zeta)
    assert sum(amps) == pytest.approx(1.0, abs=1e-15)
    assert all(a > 0.0 for a in amps) and times[0] == 0.0 and list(times) == sorted(times)
    assert times[-1] == pytest.approx(duration_periods(kind) / 2.0 / math.sqrt(1 - zeta * zeta))
    v = residual_vibration(amps, times, 2.0, zeta)
    if kind in ("ei", "3hump_ei"):  # the EI trains leave up to V at their design frequency
        assert 0.02 < v <= VIBRATION_TOLERANCE + 1e-12
        if zeta == 0.0:
            assert v == pytest.approx(VIBRATION_TOLERANCE, rel=1e-9)
    else:
        assert v < 1e-12


@pytest.mark.parametrize("kind", TYPES)
@pytest.mark.parametrize(("ratio", "zeta"), [(1.0, 0.02), (0.85, 0.02), (1.2, 0.05), (0.7, 0.0)])
def test_residual_vibration_is_what_a_damped_mode_does(
    kind: str, ratio: float, zeta: float
) -> None:
    amps, times = impulses(kind, 1.0, zeta)
    ours = residual_vibration(amps, times, ratio, zeta)
    ref = lsim_residual(amps, times, ratio, zeta)
    assert ours == pytest.approx(ref, abs=2e-3)


@pytest.mark.parametrize(
    ("kind", "low", "high"),
    [
        ("zv", 0.97, 1.03),
        ("mzv", 0.953, 1.054),
        ("zvd", 0.86, 1.14),
        ("ei", 0.80, 1.20),
        ("2hump_ei", 0.64, 1.36),
        ("3hump_ei", 0.52, 1.48),
    ],
)
def test_the_bands_docs_shaping_gives(kind: str, low: float, high: float) -> None:
    amps, times = impulses(kind, 1.0, 0.02)
    for r in np.linspace(low, high, 41):
        assert residual_vibration(amps, times, float(r), 0.02) <= VIBRATION_TOLERANCE + 2e-3


def test_the_default_covers_a_model_15_percent_off() -> None:
    amps, times = impulses(DEFAULT_SHAPER_TYPE, 1.0, 0.02)
    for r in (0.85, 1.0, 1.15):
        assert residual_vibration(amps, times, r, 0.02) <= 0.05


def shape_track(
    shaper: InputShaper,
    samples: list[tuple[float, tuple[float, float, float]]],
    freqs: tuple[float, ...],
) -> list[tuple[float, float, float]]:
    out = []
    last_t = 0.0
    prev = samples[0][1]
    for t, p in samples:
        dt = t - last_t
        v = tuple((p[i] - prev[i]) / dt for i in range(3)) if dt > 0 else (0.0, 0.0, 0.0)
        out.append(shaper.shape(p, v, dt, freqs))
        last_t, prev = t, p
    return out


def test_the_cascade_is_the_convolution_of_its_trains() -> None:
    f1, f2, f3, zeta = 1.7, 6.3, 11.0, 0.02
    period = 0.002
    move = TrapezoidMove((0.0, 0.0, 0.0), (3.0, -1.0, 2.0), 1.0, 1.0)
    ts = np.arange(1, round((move.duration_s + 3.0) / period)) * period
    path = np.array([move.sample(float(t))[0] for t in ts])
    shaper = InputShaper("2hump_ei", zeta, stages=3, min_frequency_hz=1.0, period_s=period)
    shaper.reset((0.0, 0.0, 0.0))
    got = np.array(
        shape_track(
            shaper, [(float(t), tuple(p)) for t, p in zip(ts, path, strict=True)], (f1, f2, f3)
        )
    )
    # the direct convolution: every combination of the three trains' impulses
    trains = [impulses("2hump_ei", f, zeta) for f in (f1, f2, f3)]
    ref = np.zeros_like(path)
    for a1, t1 in zip(*trains[0], strict=True):
        for a2, t2 in zip(*trains[1], strict=True):
            for a3, t3 in zip(*trains[2], strict=True):
                delayed = ts - (t1 + t2 + t3)
                ref += (
                    a1
                    * a2
                    * a3
                    * np.stack(
                        [
                            np.interp(
                                delayed,
                                np.concatenate(([0.0], ts)),
                                np.concatenate(([0.0], path[:, i])),
                            )
                            for i in range(3)
                        ],
                        axis=1,
                    )
                )
    assert np.abs(got - ref).max() < 1e-6  # interpolated at every stage: under a micrometre


@FAST
@given(
    d=st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)).filter(
        lambda v: math.hypot(*v) > 0.1
    ),
    length=st.floats(0.01, 5.0),
    f=st.floats(0.5, 40.0),
    kind=st.sampled_from(TYPES),
)
def test_a_straight_move_stays_straight_within_its_limits_and_arrives_exactly(
    d: tuple[float, float, float], length: float, f: float, kind: str
) -> None:
    n = math.hypot(*d)
    start = (1.0, 2.0, 3.0)
    end = tuple(start[i] + length * d[i] / n for i in range(3))
    move = TrapezoidMove(start, end, 1.0, 2.0)  # 1 m/s, 2 m/s^2
    period = 0.002
    shaper = InputShaper(kind, 0.02, stages=1, min_frequency_hz=f, period_s=period)
    shaper.reset(start)
    pts = []
    vels = []
    accs = []
    t = 0.0
    while True:
        t += period
        p, v = move.sample(t)
        pts.append(shaper.shape(p, v, period, (f,)))
        vels.append(shaper.velocity_mps)
        accs.append(shaper.acceleration_mps2)
        if t > move.duration_s and shaper.settled:
            break
        assert t < move.duration_s + 10.0 / f + 1.0
    a = np.array(pts)
    u = np.subtract(end, start) / length
    rel = a - np.array(start)
    off = rel - np.outer(rel @ u, u)
    assert np.abs(off).max() < 1e-9  # on the line
    # between the ends: a weighted average of the move's points, read between two ticks by
    # cubic interpolation, which can pass a stop by a hair (under a micrometre)
    assert (rel @ u).min() >= -1e-6 and (rel @ u).max() <= length + 1e-6
    speed = np.linalg.norm(np.diff(a, axis=0), axis=1) / period
    assert speed.max() <= 1.0 + 1e-3  # the set-point: never faster than the move
    accel = np.linalg.norm(np.diff(a, n=2, axis=0), axis=1) / period**2
    assert accel.max() <= 2.0 * 1.01  # nor accelerating harder
    assert np.linalg.norm(np.array(accs), axis=1).max() <= 2.0 * 1.01
    # the velocity handed to the drives: the change over the tick and half a tick of that
    assert np.linalg.norm(np.array(vels), axis=1).max() <= 1.0 + 2.0 * period / 2.0 + 1e-9
    assert pts[-1] == end  # exactly there once settled
    # it takes the train's duration longer, at most (and the ticks that see it arrive)
    assert t <= move.duration_s + duration_periods(kind) / f / math.sqrt(1 - 0.02**2) + 3 * period


def test_frequencies_that_change_every_tick_never_give_nan_and_the_floor_holds() -> None:
    shaper = InputShaper("ei", 0.02, stages=3, min_frequency_hz=2.0, period_s=0.001)
    shaper.reset((0.0, 0.0, 0.0))
    rng = np.random.default_rng(1)
    p = (0.0, 0.0, 0.0)
    for k in range(5000):
        p = (p[0] + 1e-3, p[1], p[2] - 5e-4)
        freqs = tuple(sorted(rng.uniform(0.1, 50.0, 3)))
        if k % 97 == 0:
            freqs = (math.nan, math.inf, 1.0)  # ignored: the last good ones stay
        out = shaper.shape(p, (1.0, 0.0, -0.5), 0.001 * (0.5 + rng.random()), freqs)
        assert all(math.isfinite(v) for v in out)
    assert min(shaper.frequencies_hz) >= 2.0
    assert shaper.duration_s <= shaper.max_duration_s


def test_bad_shapers_are_named_errors() -> None:
    assert check_shaper("zdv", None, 0.02) == (
        "unknown shaper type 'zdv' (one of off, zv, mzv, zvd, ei, 2hump_ei, 3hump_ei)"
    )
    assert check_shaper("ei", 0.0, 0.02) == "frequency 0.0 Hz out of range (0.05 to 1000 Hz)"
    assert check_shaper("ei", 5.0, -0.1) == "damping ratio -0.1 out of range (0 to 0.3)"
    assert check_shaper("ei", math.nan, 0.02) is not None
    assert check_shaper("ei", None, math.inf) is not None
    with pytest.raises(ShaperError, match="unknown shaper type"):
        unit_train("zdv", 0.02)
    with pytest.raises(ShaperError, match="out of range"):
        impulses("zvd", 2000.0, 0.02)
    with pytest.raises(ShaperError, match="off"):
        InputShaper("off", 0.02, stages=1, min_frequency_hz=1.0, period_s=0.002)
    with pytest.raises(ValueError, match="stages"):
        InputShaper("zv", 0.02, stages=0, min_frequency_hz=1.0, period_s=0.002)
    assert unit_train("off", 0.0) == ((), ())
