"""The elastic catenary: a heavy, elastic cable hanging between the effector and its anchor.

Pure module (``math`` only), no I/O, no state.

Model (Irvine, *Cable Structures*, 1981, ch. 2; as used by Kozak et al., IEEE T-RO 22(3), 2006)
-----------------------------------------------------------------------------------------------
A cable of unstretched length ``L0`` (what the reel has paid out), weight ``w`` per metre of
unstretched cable (N/m: its mass per metre times g) and compliance ``c = 1 / EA`` (1/N; 0 =
inextensible) hangs in the vertical plane through its ends.  Its effector end is the origin; its
anchor end lies ``span`` metres away horizontally (``span >= 0``) and ``rise`` metres higher
(negative: lower).  The cable pulls the effector with ``H`` horizontally toward the anchor and
``V0`` upward, and the anchor with ``H`` toward the effector and ``V1 = V0 + w L0`` downward;
``H >= 0`` is the same all along it.  ``T0 = hypot(H, V0)`` and ``T1 = hypot(H, V1)`` are the
end tensions (``T1`` is what the reel carries).  Integrating the strained cable along its
unstretched length gives its reach:

    span = c H L0 + (H / w) (asinh(V1 / H) - asinh(V0 / H))
    rise = c L0 (V0 + V1) / 2 + (T1 - T0) / w

Numerical care.  Written so, both lose every digit as ``w -> 0`` (a difference of nearly equal
terms over ``w``) and break down as ``H -> 0``.  This module evaluates forms that stay exact:

* ``(T1 - T0) / w = L0 (V0 + V1) / (T0 + T1)``;
* ``(H / w)(asinh(V1 / H) - asinh(V0 / H)) = H L0 G log1p(w L0 G) / (w L0 G)`` with
  ``G = (1 + (V0 + V1) / (T0 + T1)) / (V0 + T0)`` when ``V0 >= 0``, mirrored when ``V1 <= 0``;
  when the lowest point lies between the ends (``V0 < 0 < V1``) both ``asinh`` have positive
  arguments and ``w L0 > |V0| + V1`` keeps the division by ``w`` exact;
* the derivatives likewise (``(V0 / T0 - V1 / T1) / w`` as ``-H^2 L0 (V0 + V1) / (T0 T1 (V0 T1
  + V1 T0))`` when ``V0`` and ``V1`` have one sign).

At ``w = 0`` they are the straight elastic cable, ``span = L0 (1 + c T) H / T``, to rounding; at
``H = 0`` with ``V0 > 0`` the vertical cable.

Solutions
---------
* ``from_length``: the end forces of a cable of given ``L0`` between its ends (Newton on
  ``(H, V0)``, warm-started, or from the parabolic estimate of an elastic cable's sag, or for a
  deep sag the inextensible catenary).  A massless cable longer than the distance is slack.
* ``from_horizontal_force``: the cable that pulls with horizontal force ``H`` between its ends:
  ``V0`` and ``L0``.  Inextensible it is closed form (``lambda = w span / (2 H)``,
  ``L0 = hypot(rise, span sinh(lambda) / lambda)``, ``V0 = (H rise / span) lambda coth(lambda)
  - w L0 / 2``); elasticity adds a correction of relative size ``c T`` that one or two Newton
  steps find.  This is the inverse the kinematics use: the planned force at the effector and the
  span give the paid-out length.
* ``sag``: the mid-span drop below the chord and the cable's extra length.

Errors: ``CatenaryError`` (a ``ValueError``) for bad input or no convergence; its subclass
``SlackCableError`` where there is no catenary with a positive horizontal force (a massless cable
longer than the distance, a horizontal force too small to hold the cable's weight over its span,
a cable hanging doubled under a point).  Nothing here returns NaN or inf.
"""

from __future__ import annotations

import math
from typing import NamedTuple

__all__ = [
    "MAX_ITERATIONS",
    "MAX_LAMBDA",
    "CatenaryEnds",
    "CatenaryError",
    "Reach",
    "SlackCableError",
    "from_horizontal_force",
    "from_length",
    "from_length_and_reach",
    "least_anchor_tension",
    "reach",
    "reach_derivatives",
    "sag",
]

MAX_ITERATIONS = 60
"""Most Newton steps of one solve."""
MAX_LAMBDA = 40.0
"""Largest ``w span / (2 H)``: a cable sagging so deep (its sag far more than its span) carries
next to no horizontal force; beyond this it counts as slack."""
_TOL = 1e-12
"""Relative tolerance of the solves (of the distance between the ends)."""


class CatenaryError(ValueError):
    """Bad input (not finite, out of range) or a solve that did not converge."""


class SlackCableError(CatenaryError):
    """No catenary with a positive horizontal force joins the ends: the cable is slack."""


class CatenaryEnds(NamedTuple):
    """One hanging cable: the forces at its ends and its unstretched length.

    ``h_n``: horizontal force (toward the other end at each end); ``v0_n``: vertical force on
    the effector (up); ``v1_n``: vertical force on the anchor (down), ``v0_n + w L0``;
    ``t0_n``, ``t1_n``: the tensions at the effector and at the anchor; ``unstretched_m``:
    ``L0``; ``iterations``: Newton steps taken.
    """

    h_n: float
    v0_n: float
    v1_n: float
    t0_n: float
    t1_n: float
    unstretched_m: float
    iterations: int


class Reach(NamedTuple):
    """Where a cable's far end lies and how that moves with the end forces and the length:
    ``span_m``, ``rise_m`` and their derivatives by ``H`` (``ds_dh``, ``dr_dh``), by ``V0``
    (``ds_dv``, ``dr_dv``; the 2x2 flexibility, symmetric) and by ``L0`` (``ds_dl``,
    ``dr_dl``) at fixed end forces."""

    span_m: float
    rise_m: float
    ds_dh: float
    ds_dv: float
    dr_dh: float
    dr_dv: float
    ds_dl: float
    dr_dl: float


def _log1p_ratio(x: float) -> float:
    """log1p(x) / x, exact at and near 0 (x > -1)."""
    return 1.0 if x == 0.0 else math.log1p(x) / x


def _sinhc(x: float) -> float:
    """sinh(x) / x, exact at and near 0."""
    if abs(x) < 1e-4:
        return 1.0 + x * x / 6.0
    return math.sinh(x) / x


def _xcoth(x: float) -> float:
    """x coth(x) = x / tanh(x), exact at and near 0."""
    if abs(x) < 1e-4:
        return 1.0 + x * x / 3.0
    return float(x / math.tanh(x))


def _a_over_h(h: float, v0: float, v1: float, t0: float, t1: float, l0: float, w: float) -> float:
    """(asinh(V1 / H) - asinh(V0 / H)) / w: the horizontal reach of the unstretched cable per
    newton of H (see the module docstring for the forms)."""
    if v0 >= 0.0:
        g = (1.0 + (v0 + v1) / (t0 + t1)) / (v0 + t0)
        return l0 * g * _log1p_ratio(w * l0 * g)
    if v1 <= 0.0:
        g = (1.0 - (v0 + v1) / (t0 + t1)) / (t1 - v1)
        return l0 * g * _log1p_ratio(w * l0 * g)
    return (math.asinh(v1 / h) + math.asinh(-v0 / h)) / w


def _d_sin(h: float, v0: float, v1: float, t0: float, t1: float, l0: float, w: float) -> float:
    """(V0 / T0 - V1 / T1) / w (<= 0), without cancellation."""
    if v0 * v1 > 0.0 or v0 == v1:
        s = v0 * t1 + v1 * t0
        if s == 0.0:  # V0 = V1 = 0: a horizontal massless cable
            return -l0 / h
        return -h * h * l0 * (v0 + v1) / (t0 * t1 * s)
    return (v0 / t0 - v1 / t1) / w


def _check_ends(h: float, v0: float, v1: float) -> None:
    if not (h > 0.0 or (h == 0.0 and (v0 > 0.0 or v1 < 0.0))):
        raise SlackCableError(
            f"no catenary with horizontal force {h:.6g} N and end forces {v0:.6g}, {v1:.6g} N: "
            "the cable hangs slack"
        )


def reach(
    h_n: float, v0_n: float, unstretched_m: float, weight_n_per_m: float, compliance_per_n: float
) -> tuple[float, float]:
    """(span, rise) of the far end of a cable of unstretched length `unstretched_m` pulling its
    near end with (`h_n`, `v0_n`): the closed form of the module docstring.  Also the point of
    a cable `unstretched_m` along it from the near end.  Raises ``SlackCableError`` when
    ``H = 0`` and the cable is not vertical and taut (no shape); inputs are trusted to be
    finite with ``H, L0, w, c >= 0``."""
    h, v0, l0, w, c = h_n, v0_n, unstretched_m, weight_n_per_m, compliance_per_n
    v1 = v0 + w * l0
    _check_ends(h, v0, v1)
    t0 = math.hypot(h, v0)
    t1 = math.hypot(h, v1)
    span = h * (c * l0 + _a_over_h(h, v0, v1, t0, t1, l0, w))
    rise = l0 * (0.5 * c * (v0 + v1) + (v0 + v1) / (t0 + t1))
    return span, rise


def reach_derivatives(
    h_n: float, v0_n: float, unstretched_m: float, weight_n_per_m: float, compliance_per_n: float
) -> Reach:
    """``reach`` with its derivatives by H, V0 and L0 (``Reach``).  Raises as ``reach``."""
    h, v0, l0, w, c = h_n, v0_n, unstretched_m, weight_n_per_m, compliance_per_n
    v1 = v0 + w * l0
    _check_ends(h, v0, v1)
    t0 = math.hypot(h, v0)
    t1 = math.hypot(h, v1)
    a_h = _a_over_h(h, v0, v1, t0, t1, l0, w)
    ratio = (v0 + v1) / (t0 + t1)
    d = _d_sin(h, v0, v1, t0, t1, l0, w) if h > 0.0 else 0.0
    q = -h * l0 * ratio / (t0 * t1)
    return Reach(
        span_m=h * (c * l0 + a_h),
        rise_m=l0 * (0.5 * c * (v0 + v1) + ratio),
        ds_dh=c * l0 + a_h + d,
        ds_dv=q,
        dr_dh=q,
        dr_dv=c * l0 - d,
        ds_dl=h * (c + 1.0 / t1),
        dr_dl=v1 * (c + 1.0 / t1),
    )


def _check(name: str, value: float, positive: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise CatenaryError(f"{name} must be a number, got {value!r}") from None
    if not (math.isfinite(v) and (v > 0.0 if positive else v >= 0.0)):
        raise CatenaryError(f"{name} must be finite and {'>' if positive else '>='} 0, got {v!r}")
    return v


def _inputs(
    span_m: float, rise_m: float, weight_n_per_m: float, compliance_per_n: float
) -> tuple[float, float, float, float, float]:
    span = _check("span_m", span_m)
    try:
        rise = float(rise_m)
    except (TypeError, ValueError):
        raise CatenaryError(f"rise_m must be a number, got {rise_m!r}") from None
    if not math.isfinite(rise):
        raise CatenaryError(f"rise_m must be finite, got {rise!r}")
    w = _check("weight_n_per_m", weight_n_per_m)
    c = _check("compliance_per_n", compliance_per_n)
    chord = math.hypot(span, rise)
    if not chord > 0.0:
        raise CatenaryError("the cable's ends coincide")
    return span, rise, w, c, chord


def _ends(h: float, v0: float, l0: float, w: float, its: int) -> CatenaryEnds:
    v1 = v0 + w * l0
    return CatenaryEnds(h, v0, v1, math.hypot(h, v0), math.hypot(h, v1), l0, its)


def _parabolic_tension(chord: float, span: float, l0: float, w: float, c: float) -> float:
    """The tension of the parabolic estimate: stretched length minus chord equals the sag's
    extra length, ``L0 (1 + c T) - D = wp^2 D^3 / (24 T^2)`` with ``wp = w span / D`` (the
    load across the chord).  The positive root of the cubic ``c L0 T^3 + (L0 - D) T^2 - k``,
    by Newton from an upper bound (the cubic is convex and rising beyond it)."""
    k = (w * span / chord) ** 2 * chord**3 / 24.0
    if c > 0.0:
        base = max(0.0, (chord - l0) / (c * l0))
        t = base + math.cbrt(k / (c * l0))
        if l0 > chord:
            t = min(t, math.sqrt(k / (l0 - chord)))
    else:
        return math.sqrt(k / (l0 - chord))
    for _ in range(60):
        f = t * t * (c * l0 * t + l0 - chord) - k
        df = t * (3.0 * c * l0 * t + 2.0 * (l0 - chord))
        if not (df > 0.0):
            break
        step = f / df
        t -= step
        if abs(step) <= 1e-12 * t:
            break
    return t


def _guess(
    span: float, rise: float, chord: float, l0: float, w: float, c: float
) -> tuple[float, float]:
    """(H, V0) to start the Newton of ``from_length``: the parabolic estimate, or for a deep
    sag (``w span / (2 H) > 0.5``) the inextensible catenary of the same length."""
    t = _parabolic_tension(chord, span, l0, w, c)
    h = t * span / chord
    if l0 > chord and span > 0.0 and w * span > h:
        # sinh(lam) / lam = sqrt(L0^2 - rise^2) / span, solved for lam by Newton on its log
        target = math.log(math.sqrt(l0 * l0 - rise * rise) / span)
        lam = math.sqrt(6.0 * max(target, 1e-12))
        for _ in range(60):
            f = math.log(_sinhc(lam)) - target
            df = _xcoth(lam) / lam - 1.0 / lam if lam > 1e-4 else lam / 3.0
            if not df > 0.0:
                break
            step = f / df
            lam = min(max(0.5 * lam, lam - step), MAX_LAMBDA)
            if abs(step) <= 1e-12 * lam or lam == MAX_LAMBDA:
                break
        lam = min(lam, MAX_LAMBDA)
        h = w * span / (2.0 * lam)
        return h, 0.5 * w * (rise * _xcoth(lam) / lam - l0)
    return h, t * rise / chord - 0.5 * w * l0


def _from_length(
    span_m: float,
    rise_m: float,
    unstretched_m: float,
    weight_n_per_m: float,
    compliance_per_n: float,
    guess: tuple[float, float] | None = None,
) -> tuple[CatenaryEnds, Reach | None]:
    """``from_length`` without the range guard, with the reach at the solution when the
    Newton made it (None for the straight closed forms)."""
    span, rise, w, c, chord = _inputs(span_m, rise_m, weight_n_per_m, compliance_per_n)
    l0 = _check("unstretched_m", unstretched_m, positive=True)
    if w == 0.0 or span == 0.0:
        # Straight: massless, or vertical (H = 0).
        if c == 0.0:
            raise CatenaryError("an inextensible cable's tension is not fixed by its ends alone")
        if span == 0.0:
            if rise <= 0.0:
                raise SlackCableError("a cable hanging straight down from the effector is slack")
            v0 = (rise / l0 - 1.0) / c - 0.5 * w * l0
            if not v0 > 0.0:
                raise SlackCableError(
                    f"a vertical cable of {l0:.6g} m over {rise:.6g} m does not hold its weight"
                )
            return _ends(0.0, v0, l0, w, 0), None
        if not chord > l0:
            raise SlackCableError(
                f"a massless cable of {l0:.6g} m between points {chord:.6g} m apart is slack"
            )
        t = (chord / l0 - 1.0) / c
        return _ends(t * span / chord, t * rise / chord, l0, w, 0), None
    if c == 0.0 and not l0 > chord:
        raise CatenaryError(f"an inextensible cable of {l0:.6g} m cannot reach {chord:.6g} m")
    if guess is not None and guess[0] > 0.0 and math.isfinite(guess[0] + guess[1]):
        h, v0 = float(guess[0]), float(guess[1])
    else:
        h, v0 = _guess(span, rise, chord, l0, w, c)
    tol = _TOL * (chord + l0)
    r = reach_derivatives(h, v0, l0, w, c)
    es, er = r.span_m - span, r.rise_m - rise
    norm = math.hypot(es, er)
    for it in range(MAX_ITERATIONS):
        if norm <= tol:
            return _ends(h, v0, l0, w, it), r
        det = r.ds_dh * r.dr_dv - r.ds_dv * r.dr_dh
        if not (det != 0.0 and math.isfinite(det)):
            break
        dh = -(r.dr_dv * es - r.ds_dv * er) / det
        dv = -(r.ds_dh * er - r.dr_dh * es) / det
        alpha = 1.0
        if h + dh <= 0.0:  # keep H > 0: at most three quarters of the way to zero
            alpha = 0.75 * h / -dh
        for _ in range(40):
            h2 = h + alpha * dh
            v2 = v0 + alpha * dv
            r2 = reach_derivatives(h2, v2, l0, w, c)
            es2, er2 = r2.span_m - span, r2.rise_m - rise
            norm2 = math.hypot(es2, er2)
            if norm2 < norm or norm2 <= tol:
                break
            alpha *= 0.5
        else:
            break
        h, v0, r, es, er, norm = h2, v2, r2, es2, er2, norm2
    if norm <= 1e3 * tol:  # converged to what rounding allows
        return _ends(h, v0, l0, w, MAX_ITERATIONS), r
    raise CatenaryError(
        f"the catenary of {l0:.6g} m over span {span:.6g} m, rise {rise:.6g} m did not converge "
        f"(mismatch {norm:.3g} m)"
    )


def _from_horizontal_force(
    span_m: float,
    rise_m: float,
    h_n: float,
    weight_n_per_m: float,
    compliance_per_n: float,
) -> CatenaryEnds:
    """``from_horizontal_force`` without the range guard."""
    span, rise, w, c, _ = _inputs(span_m, rise_m, weight_n_per_m, compliance_per_n)
    try:
        h = float(h_n)
    except (TypeError, ValueError):
        raise CatenaryError(f"h_n must be a number, got {h_n!r}") from None
    if not (h > 0.0 and math.isfinite(h)):
        raise SlackCableError(
            f"no catenary with horizontal force {h!r} N: a cable only pulls (H > 0)"
        )
    if span == 0.0:
        raise CatenaryError("a vertical cable carries no horizontal force")
    lam = w * span / (2.0 * h)
    if lam > MAX_LAMBDA:
        raise SlackCableError(
            f"a horizontal force of {h:.4g} N cannot hold {w:.4g} N/m of cable over "
            f"{span:.4g} m: the cable hangs slack"
        )
    l0 = math.hypot(rise, span * _sinhc(lam))
    v0 = h * rise / span * _xcoth(lam) - 0.5 * w * l0
    if c == 0.0:
        return _ends(h, v0, l0, w, 0)
    tol = _TOL * (span + abs(rise) + l0)
    # Start the stretch's correction near it: the same curve of unstretched length shorter by
    # the mean strain, its weight (so V0) lighter by the difference; one Newton step then
    # meets the tolerance where the strain is small.
    t_mean = 0.5 * (math.hypot(h, v0) + math.hypot(h, v0 + w * l0))
    shorter = l0 / (1.0 + c * t_mean)
    v0 += 0.5 * w * (l0 - shorter)
    l0 = shorter
    for it in range(MAX_ITERATIONS):
        r = reach_derivatives(h, v0, l0, w, c)
        es, er = r.span_m - span, r.rise_m - rise
        if math.hypot(es, er) <= tol:
            return _ends(h, v0, l0, w, it)
        # unknowns (V0, L0): d span = ds_dv dV0 + ds_dl dL0, d rise = dr_dv dV0 + dr_dl dL0
        det = r.ds_dv * r.dr_dl - r.ds_dl * r.dr_dv
        if not (det != 0.0 and math.isfinite(det)):
            break
        dv = -(r.dr_dl * es - r.ds_dl * er) / det
        dl = -(r.ds_dv * er - r.dr_dv * es) / det
        if l0 + dl <= 0.0:
            dl = -0.5 * l0
        v0 += dv
        l0 += dl
    raise CatenaryError(
        f"the catenary with horizontal force {h:.6g} N over span {span:.6g} m, rise "
        f"{rise:.6g} m did not converge"
    )


def _finite_ends(ends: CatenaryEnds, what: str) -> CatenaryEnds:
    s = ends.h_n + ends.v0_n + ends.v1_n + ends.t0_n + ends.t1_n + ends.unstretched_m
    if s - s != 0.0:
        raise CatenaryError(f"the catenary {what} is not finite")
    return ends


def from_length(
    span_m: float,
    rise_m: float,
    unstretched_m: float,
    weight_n_per_m: float,
    compliance_per_n: float,
    guess: tuple[float, float] | None = None,
) -> CatenaryEnds:
    """The end forces of a cable of unstretched length `unstretched_m` whose far end lies
    `span_m` away horizontally and `rise_m` higher: Newton on ``(H, V0)`` (from `guess`, the
    last solution of a cable that moved a little, or from the parabolic estimate of an elastic
    cable's sag, for a deep sag the inextensible catenary), with a line search that keeps
    ``H > 0``.

    Raises ``CatenaryError`` for non-finite or out-of-range input, coinciding ends, an
    inextensible cable shorter than the distance, no convergence or a result out of the
    floats' range; ``SlackCableError`` for a massless cable no shorter than the distance or a
    vertical one not taut.
    """
    return from_length_and_reach(
        span_m, rise_m, unstretched_m, weight_n_per_m, compliance_per_n, guess
    )[0]


def from_length_and_reach(
    span_m: float,
    rise_m: float,
    unstretched_m: float,
    weight_n_per_m: float,
    compliance_per_n: float,
    guess: tuple[float, float] | None = None,
) -> tuple[CatenaryEnds, Reach]:
    """``from_length`` and the ``reach_derivatives`` at its solution (the Newton's last
    evaluation: the cable's stiffness comes with it).  Raises as ``from_length``."""
    try:
        ends, r = _from_length(
            span_m, rise_m, unstretched_m, weight_n_per_m, compliance_per_n, guess
        )
        if r is None:
            r = reach_derivatives(
                ends.h_n,
                ends.v0_n,
                ends.unstretched_m,
                float(weight_n_per_m),
                float(compliance_per_n),
            )
    except (OverflowError, ZeroDivisionError) as exc:
        raise CatenaryError(f"the catenary of {unstretched_m!r} m is out of range: {exc}") from None
    return _finite_ends(ends, f"of {unstretched_m!r} m"), r


def from_horizontal_force(
    span_m: float,
    rise_m: float,
    h_n: float,
    weight_n_per_m: float,
    compliance_per_n: float,
) -> CatenaryEnds:
    """The cable that pulls with horizontal force `h_n` between its ends (far end `span_m`
    away horizontally, `rise_m` higher): its vertical end forces and unstretched length.

    Closed form for an inextensible cable (module docstring), then Newton on ``(V0, L0)`` for
    the stretch.  Raises ``CatenaryError`` for non-finite or out-of-range input, a horizontal
    force on a vertical span, no convergence or a result out of the floats' range;
    ``SlackCableError`` when `h_n` is not > 0 or too small to hold the cable's weight over
    the span (``w span / (2 H) > MAX_LAMBDA``).
    """
    try:
        ends = _from_horizontal_force(span_m, rise_m, h_n, weight_n_per_m, compliance_per_n)
    except (OverflowError, ZeroDivisionError) as exc:
        raise CatenaryError(f"the catenary with H = {h_n!r} N is out of range: {exc}") from None
    return _finite_ends(ends, f"with H = {h_n!r} N")


def least_anchor_tension(span_m: float, rise_m: float, weight_n_per_m: float) -> float:
    """The least tension the anchor end of an inextensible cable of weight `weight_n_per_m`
    can carry while it spans `span_m` horizontally and `rise_m` up to its anchor, whatever its
    length: the minimum over the horizontal force (golden section on ``log lambda``; 0.7544
    w span for level ends, w rise straight up).  Raises ``CatenaryError`` for bad input."""
    span, rise, w, _, _ = _inputs(span_m, rise_m, weight_n_per_m, 0.0)
    if w == 0.0:
        return 0.0
    if span == 0.0:
        return w * max(rise, 0.0)

    def anchor_tension(log_lam: float) -> float:
        lam = math.exp(log_lam)
        h = w * span / (2.0 * lam)
        l0 = math.hypot(rise, span * _sinhc(lam))
        v1 = h * rise / span * _xcoth(lam) + 0.5 * w * l0
        return math.hypot(h, v1)

    lo, hi = math.log(1e-4), math.log(MAX_LAMBDA)
    g = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = hi - g * (hi - lo), lo + g * (hi - lo)
    fa, fb = anchor_tension(a), anchor_tension(b)
    for _ in range(100):
        if fa < fb:
            hi, b, fb = b, a, fa
            a = hi - g * (hi - lo)
            fa = anchor_tension(a)
        else:
            lo, a, fa = a, b, fb
            b = lo + g * (hi - lo)
            fb = anchor_tension(b)
        if hi - lo < 1e-10:
            break
    return min(fa, fb)


def sag(
    ends: CatenaryEnds, span_m: float, rise_m: float, weight_n_per_m: float, compliance_per_n: float
) -> tuple[float, float]:
    """(mid-span drop, extra length) of the cable `ends` between its ends: how far below the
    chord the cable hangs at half the span (m; vertical), and how much longer it is than the
    chord, stretched (m).  Raises ``CatenaryError`` for a cable with no shape."""
    h, v0, l0 = ends.h_n, ends.v0_n, ends.unstretched_m
    w, c = weight_n_per_m, compliance_per_n
    span, rise = float(span_m), float(rise_m)
    # the unstretched length s at which the cable is half way across (x(s) rises with s)
    lo, hi = 0.0, l0
    s = 0.5 * l0
    for _ in range(200):
        x, _z = reach(h, v0, s, w, c)
        if x < 0.5 * span:
            lo = s
        else:
            hi = s
        s = 0.5 * (lo + hi)
        if hi - lo <= 1e-12 * l0:
            break
    _x, z = reach(h, v0, s, w, c)
    drop = 0.5 * rise - z
    # stretched length: L0 + c * integral of T over the unstretched length
    t0, t1, v1 = ends.t0_n, ends.t1_n, ends.v1_n
    if w > 0.0 and h > 0.0:
        integral = 0.5 / w * (v1 * t1 - v0 * t0 + h * h * w * _a_over_h(h, v0, v1, t0, t1, l0, w))
    else:
        integral = t0 * l0
    extra = l0 + c * integral - math.hypot(span, rise)
    if not (math.isfinite(drop) and math.isfinite(extra)):
        raise CatenaryError("the cable's sag is not finite")
    return drop, extra
