"""The effector's modes measured from the cables' tensions after an excitation (`cablebot
resonance`): frequencies and damping ratios fitted to the free ringing. Pure (numpy; scipy's
least squares, imported where it is used), no I/O.

After a short move the effector rings in its modes, and every cable's tension rings with it:
the force the cables put on the effector, ``F(t) = sum_i t_i(t) u_i`` (``u_i`` the unit vector
to anchor i at the pose), is ``F_rest - K x(t)`` for a displacement x from rest, so it carries
each mode with that mode's frequency and decay. A motor's current is a tension sensor on
every cable (the drives' torque telemetry), so no accelerometer is needed.

`fit_modes` takes the force's samples after the motion has ended and fits the free response of
three damped modes, ``F_c(t) = o_c + sum_j exp(-zeta_j w_j t) (a_cj cos(wd_j t) + b_cj
sin(wd_j t))`` on each of the three components c, with the frequencies and damping ratios shared
by the components (variable projection: for each trial of the six nonlinear parameters the
amplitudes are a linear least-squares fit). The force is first turned into the guessed mode
directions (the model's, or the principal directions of its variation), and each mode's start
value is the strongest spectral peak of its own component, near the model's frequency when
there is one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

Vec3 = tuple[float, float, float]

MIN_SAMPLES = 64
"""Fewer samples than this after the motion are no measurement."""
SEARCH_BAND = (0.5, 2.0)
"""A mode's spectral peak is searched between these multiples of its model frequency."""
FIT_RANGE = (0.7, 1.3)
"""The fit keeps each frequency between these multiples of its spectral peak."""
SEEN_SHARE = 0.02
"""A mode ringing less than this share of the strongest is not seen."""
MAX_SEEN_DAMPING = 0.5
"""A fitted damping ratio above this is no mode seen (a fit of noise or of a neighbour)."""


class ResonanceError(ValueError):
    """Too few or non-finite samples, or no ringing to fit."""


@dataclass(frozen=True, slots=True)
class FittedMode:
    """One measured mode: natural frequency (Hz), damping ratio, direction (unit vector), the
    amplitude of its force at the start of the record (N), and whether it was seen: it rang
    at least `SEEN_SHARE` of the strongest mode, its damping below `MAX_SEEN_DAMPING` and its
    frequency off the search's bounds (two modes of one frequency look like one)."""

    frequency_hz: float
    damping_ratio: float
    direction: Vec3
    amplitude_n: float
    seen: bool = True


def cable_force(
    anchors_m: Sequence[Sequence[float]], position_m: Sequence[float], tensions_n: np.ndarray
) -> np.ndarray:
    """The force (N, one row per sample) the cables of `tensions_n` (one row per sample, one
    column per cable) put on an effector at `position_m`. Raises ResonanceError for a bad
    shape or an effector on an anchor."""
    a = np.asarray(anchors_m, dtype=np.float64)
    t = np.asarray(tensions_n, dtype=np.float64)
    if t.ndim != 2 or t.shape[1] != a.shape[0]:
        raise ResonanceError(f"tensions must be (samples, {a.shape[0]}), got {t.shape}")
    d = a - np.asarray(position_m, dtype=np.float64)
    length = np.sqrt(np.einsum("ij,ij->i", d, d))
    if not (length > 0.0).all():
        raise ResonanceError("the effector is on an anchor")
    result: np.ndarray = t @ (d / length[:, None])
    return result


def _peak_hz(t: np.ndarray, y: np.ndarray, lo_hz: float, hi_hz: float) -> float | None:
    """The strongest spectral peak of `y` (sampled at `t`, resampled evenly) in [lo, hi] Hz,
    refined by a parabola through its neighbours; None when the band holds no bin."""
    n = len(t)
    dt = (t[-1] - t[0]) / (n - 1)
    even = np.interp(t[0] + dt * np.arange(n), t, y)
    even = (even - even.mean()) * np.hanning(n)
    pad = 1 << (max(8 * n, 4096) - 1).bit_length()
    spec = np.abs(np.fft.rfft(even, pad))
    freqs = np.fft.rfftfreq(pad, dt)
    band = np.flatnonzero((freqs >= lo_hz) & (freqs <= hi_hz))
    if band.size == 0:
        return None
    k = int(band[np.argmax(spec[band])])
    if 0 < k < len(spec) - 1:
        y0, y1, y2 = spec[k - 1], spec[k], spec[k + 1]
        den = y0 - 2.0 * y1 + y2
        shift = 0.5 * (y0 - y2) / den if den != 0.0 else 0.0
        return float(freqs[k] + shift * (freqs[1] - freqs[0]))
    return float(freqs[k])


def _basis(t: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Columns: 1, then each mode's damped cosine and sine at (w, zeta) = params pairs."""
    cols = [np.ones_like(t)]
    for j in range(0, len(params), 2):
        w, z = params[j], params[j + 1]
        env = np.exp(-z * w * t)
        wd = w * math.sqrt(max(1e-12, 1.0 - z * z))
        cols.append(env * np.cos(wd * t))
        cols.append(env * np.sin(wd * t))
    return np.stack(cols, axis=1)


def fit_modes(
    times_s: Sequence[float],
    force_n: np.ndarray,
    guesses: Sequence[tuple[float, Vec3]] | None = None,
    modes: int = 3,
) -> list[FittedMode]:
    """The modes of the free ringing in `force_n` (one row per sample, N) at `times_s`
    (ascending; the motion has ended at the first), ascending in frequency. `guesses` are
    (frequency in Hz, direction) of the expected modes (the model's); without them the
    directions are the force's principal directions and the peaks are searched from 1/T to
    the Nyquist frequency. Raises ResonanceError for fewer than `MIN_SAMPLES` samples,
    non-finite values, times that do not increase, or a signal with no peak to fit."""
    from scipy.optimize import least_squares

    t = np.asarray(times_s, dtype=np.float64)
    f = np.asarray(force_n, dtype=np.float64)
    if t.ndim != 1 or f.shape != (t.size, 3):
        raise ResonanceError(f"need one force [x, y, z] per time, got {f.shape} for {t.size}")
    if t.size < MIN_SAMPLES:
        raise ResonanceError(f"{t.size} samples after the motion: at least {MIN_SAMPLES} needed")
    if not (np.isfinite(t).all() and np.isfinite(f).all()):
        raise ResonanceError("the samples must be finite")
    if not (np.diff(t) > 0.0).all():
        raise ResonanceError("the sample times must increase")
    t = t - t[0]
    span = float(t[-1])
    nyquist = 0.5 * (t.size - 1) / span
    centred = f - f.mean(axis=0)
    if guesses:
        dirs = np.array([g[1] for g in guesses], dtype=np.float64)
        bands = [(g[0] * SEARCH_BAND[0], min(g[0] * SEARCH_BAND[1], nyquist)) for g in guesses]
    else:
        _, _, vt = np.linalg.svd(centred, full_matrices=False)
        dirs = vt[:modes]
        bands = [(2.0 / span, nyquist)] * len(dirs)
    proj = centred @ dirs.T  # one column per guessed mode
    starts = []
    for j, (lo, hi) in enumerate(bands):
        peak = _peak_hz(t, proj[:, j], lo, hi)
        if peak is None or not peak > 0.0:
            raise ResonanceError(f"no spectral peak between {lo:.3g} and {hi:.3g} Hz")
        starts.append(peak)
    x0 = np.array([v for f0 in starts for v in (2.0 * math.pi * f0, 0.02)])
    lower = np.array([v for f0 in starts for v in (2.0 * math.pi * f0 * FIT_RANGE[0], 0.0)])
    upper = np.array([v for f0 in starts for v in (2.0 * math.pi * f0 * FIT_RANGE[1], 0.9)])
    scale = float(np.abs(proj).max()) or 1.0

    def residual(params: np.ndarray) -> np.ndarray:
        basis = _basis(t, params)
        coef, *_ = np.linalg.lstsq(basis, proj / scale, rcond=None)
        out: np.ndarray = (basis @ coef - proj / scale).ravel()
        return out

    sol = least_squares(residual, x0, bounds=(lower, upper), x_scale="jac")
    basis = _basis(t, sol.x)
    coef, *_ = np.linalg.lstsq(basis, proj, rcond=None)
    amps = [float(np.sqrt((coef[1 + 2 * j : 3 + 2 * j, :] ** 2).sum())) for j in range(len(starts))]
    strongest = max(amps)
    out = []
    for j in range(len(starts)):
        w, z = float(sol.x[2 * j]), float(sol.x[2 * j + 1])
        amp = coef[1 + 2 * j : 3 + 2 * j, :]  # cos and sin amplitudes on every component
        # the direction: the guessed one of the component the mode rings most in
        d = dirs[int(np.argmax((amp * amp).sum(axis=0)))]
        at_bound = not (1.001 * lower[2 * j] < w < 0.999 * upper[2 * j])
        seen = amps[j] >= SEEN_SHARE * strongest and z < MAX_SEEN_DAMPING and not at_bound
        out.append(
            FittedMode(
                w / (2.0 * math.pi),
                z,
                (float(d[0]), float(d[1]), float(d[2])),
                amps[j],
                seen,
            )
        )
    return sorted(out, key=lambda m: m.frequency_hz)
