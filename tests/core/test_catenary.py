"""The elastic catenary: its end forces against an independent solution of Irvine's equations
(scipy on the textbook closed form) and a lumped-mass chain, the massless limit equal to the
straight elastic cable, the forms that stay exact as w -> 0 and H -> 0, and slack cables as a
named error, never NaN."""

from __future__ import annotations

import decimal
import math
import warnings

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.optimize import fsolve

from controller.core import catenary
from controller.core.catenary import CatenaryError, SlackCableError

FAST = settings(max_examples=150, deadline=None, derandomize=True)
G = 9.80665
DYNEEMA_N_PER_M = 0.0083 * G
STEEL_N_PER_M = 0.036 * G


def textbook(h: float, v0: float, l0: float, w: float, c: float) -> tuple[float, float]:
    """Irvine's span and rise as printed (asinh differences over w): the independent form."""
    v1 = v0 + w * l0
    span = c * h * l0 + h / w * (math.asinh(v1 / h) - math.asinh(v0 / h))
    rise = c * (v0 * l0 + w * l0 * l0 / 2) + (math.hypot(h, v1) - math.hypot(h, v0)) / w
    return span, rise


def scipy_ends(
    span: float, rise: float, l0: float, w: float, c: float, start: tuple[float, float]
) -> tuple[float, float]:
    """(H, V0) by scipy's fsolve (MINPACK) on the textbook equations, H through its log and
    both scaled by the start."""
    h_s = start[0]
    t_s = math.hypot(start[0], start[1])

    def f(x: np.ndarray) -> list[float]:
        s, r = textbook(h_s * math.exp(x[0]), x[1] * t_s, l0, w, c)
        return [(s - span) / l0, (r - rise) / l0]

    with warnings.catch_warnings():  # "not making good progress" at the rounding limit
        warnings.simplefilter("ignore", RuntimeWarning)
        x = fsolve(f, [0.0, start[1] / t_s], xtol=1e-13)
    return h_s * math.exp(float(x[0])), float(x[1]) * t_s


spans = st.floats(5.0, 90.0)
rises = st.floats(-8.0, 10.0)
weights = st.sampled_from([DYNEEMA_N_PER_M, STEEL_N_PER_M, 0.5 * G])
eas = st.sampled_from([1e5, 4.5e5, 1e7])


@FAST
@given(span=spans, rise=rises, w=weights, ea=eas, ratio=st.floats(0.997, 1.03))
def test_end_forces_agree_with_scipy_on_the_textbook_equations(
    span: float, rise: float, w: float, ea: float, ratio: float
) -> None:
    chord = math.hypot(span, rise)
    l0 = chord * ratio
    ends = catenary.from_length(span, rise, l0, w, 1.0 / ea)
    # the solution meets the printed equations (well conditioned here: w is not tiny)
    s, r = textbook(ends.h_n, ends.v0_n, l0, w, 1.0 / ea)
    assert math.hypot(s - span, r - rise) < 1e-9 * chord
    # and scipy, started 30 % off either way, finds the same forces
    for f in (1.3, 0.7):
        start = (f * ends.h_n, (2.0 - f) * ends.v0_n)
        h, v0 = scipy_ends(span, rise, l0, w, 1.0 / ea, start)
        assert h == pytest.approx(ends.h_n, rel=1e-6)
        assert v0 == pytest.approx(ends.v0_n, rel=1e-6, abs=1e-6 * ends.t0_n)
    assert ends.v1_n == pytest.approx(ends.v0_n + w * l0, rel=1e-12, abs=1e-12)
    assert ends.t1_n == pytest.approx(math.hypot(ends.h_n, ends.v1_n), rel=1e-12)


def chain_ends(
    span: float, rise: float, l0: float, w: float, ea: float, segments: int
) -> tuple[float, float]:
    """A lumped-mass chain of `segments` elastic links between the two ends (its nodes carry
    the links' weight, half a link at each end), at rest by Newton on its energy: (H, V0) of
    the first link at the effector end, the force it pulls the effector with."""
    n = segments - 1
    ls = l0 / segments
    k = ea / ls
    end = np.array([span, rise])
    # start on a parabola of the sag's depth (the rest is the chain's own: Newton on its energy)
    chord = float(np.hypot(*end))
    depth = math.sqrt(max(0.0, 3.0 * chord * (l0 - chord) / 8.0)) + 0.01 * chord
    x = np.array(
        [end * f - [0.0, 4.0 * depth * f * (1.0 - f)] for f in np.arange(1, n + 1) / segments]
    ).ravel()  # inner nodes (x, z)

    def nodes(v: np.ndarray) -> np.ndarray:
        return np.vstack([[0.0, 0.0], v.reshape(n, 2), end])

    def energy(v: np.ndarray) -> float:
        d = np.diff(nodes(v), axis=0)
        stretch = np.hypot(d[:, 0], d[:, 1]) - ls
        return float(0.5 * k * (stretch @ stretch) + w * ls * v[1::2].sum())

    for _ in range(100):
        p = nodes(x)
        grad = np.zeros(2 * n)
        hess = np.zeros((2 * n, 2 * n))
        grad[1::2] += w * ls  # weight of the inner nodes
        for s in range(segments):
            d = p[s + 1] - p[s]
            length = float(np.hypot(*d))
            u = d / length
            t = k * (length - ls)
            kb = k * np.outer(u, u) + t / length * (np.eye(2) - np.outer(u, u))
            for node, sign in ((s - 1, -1.0), (s, 1.0)):  # inner indices of the two ends
                if 0 <= node < n:
                    grad[2 * node : 2 * node + 2] += sign * t * u
            a, b = s - 1, s
            for i, j, m in ((a, a, kb), (b, b, kb), (a, b, -kb), (b, a, -kb)):
                if 0 <= i < n and 0 <= j < n:
                    hess[2 * i : 2 * i + 2, 2 * j : 2 * j + 2] += m
        step = np.linalg.solve(hess, -grad)
        alpha = 1.0
        while energy(x + alpha * step) > energy(x) + 1e-12 * abs(energy(x)) and alpha > 1e-6:
            alpha *= 0.5  # a line search on the energy keeps Newton from overshooting
        x = x + alpha * step
        if np.abs(step).max() < 1e-13 * l0:
            break
    p = nodes(x)
    d = p[1] - p[0]
    length = float(np.hypot(*d))
    t = k * (length - ls)
    # the first link pulls the effector along it; the effector node carries half a link
    return t * d[0] / length, t * d[1] / length - 0.5 * w * ls


@pytest.mark.parametrize(
    ("span", "rise", "ratio", "w"),
    [
        (47.5, 5.62, 1.0005, STEEL_N_PER_M),  # the paper robot's cable at (0, 0, 2)
        (75.0, 6.6, 1.003, STEEL_N_PER_M),  # a long, lightly loaded one: deep sag
        (60.0, 2.0, 0.9995, DYNEEMA_N_PER_M),
        (20.0, -3.0, 1.01, 0.5 * G),  # anchor below the effector (a Hangprinter's)
    ],
)
def test_end_forces_agree_with_a_lumped_mass_chain(
    span: float, rise: float, ratio: float, w: float
) -> None:
    ea = 4.5e5
    l0 = math.hypot(span, rise) * ratio
    ends = catenary.from_length(span, rise, l0, w, 1.0 / ea)
    coarse = chain_ends(span, rise, l0, w, ea, 40)
    fine = chain_ends(span, rise, l0, w, ea, 80)
    # the chain converges as 1 / segments^2: Richardson's extrapolation of the two
    h = fine[0] + (fine[0] - coarse[0]) / 3.0
    v0 = fine[1] + (fine[1] - coarse[1]) / 3.0
    assert abs(fine[0] - ends.h_n) < 1e-3 * ends.t0_n
    assert h == pytest.approx(ends.h_n, rel=1e-6)
    assert v0 == pytest.approx(ends.v0_n, abs=1e-6 * ends.t0_n)


@FAST
@given(span=spans, rise=rises, ea=eas, ratio=st.floats(0.95, 0.9999))
def test_without_weight_the_catenary_is_the_straight_elastic_cable(
    span: float, rise: float, ea: float, ratio: float
) -> None:
    chord = math.hypot(span, rise)
    l0 = chord * ratio
    c = 1.0 / ea
    tension = (chord / l0 - 1.0) / c  # Hooke: the straight model of controller.core.stretch
    straight = catenary.from_length(span, rise, l0, 0.0, c)
    assert straight.t0_n == pytest.approx(tension, rel=1e-12)
    assert straight.h_n == pytest.approx(tension * span / chord, rel=1e-12)
    # the forms stay exact as w -> 0: a nanogram per metre is the straight cable to 1e-9
    light = catenary.from_length(span, rise, l0, 1e-12 * G, c, (straight.h_n, straight.v0_n))
    assert light.h_n == pytest.approx(straight.h_n, rel=1e-9)
    assert light.v0_n == pytest.approx(straight.v0_n, rel=1e-9, abs=1e-9 * tension)
    s, r = catenary.reach(straight.h_n, straight.v0_n, l0, 0.0, c)
    assert s == pytest.approx(span, rel=1e-12, abs=1e-12)
    assert r == pytest.approx(rise, rel=1e-12, abs=1e-12)
    # the inverse with that horizontal force gives the same length
    back = catenary.from_horizontal_force(span, rise, straight.h_n, 0.0, c)
    assert back.unstretched_m == pytest.approx(l0, rel=1e-12)


def textbook_decimal(h: float, v0: float, l0: float, w: float, c: float) -> tuple[float, float]:
    """The textbook equations in 60-digit decimal arithmetic (asinh as a logarithm): an exact
    reference where floats cancel."""
    with decimal.localcontext() as ctx:
        ctx.prec = 60
        dh, dv0, dl0, dw, dc = (decimal.Decimal(v) for v in (h, v0, l0, w, c))
        dv1 = dv0 + dw * dl0

        def asinh(x: decimal.Decimal) -> decimal.Decimal:
            return (x + (x * x + 1).sqrt()).ln()

        span = dc * dh * dl0 + dh / dw * (asinh(dv1 / dh) - asinh(dv0 / dh))
        rise = (
            dc * (dv0 * dl0 + dw * dl0 * dl0 / 2)
            + ((dh * dh + dv1 * dv1).sqrt() - (dh * dh + dv0 * dv0).sqrt()) / dw
        )
        return float(span), float(rise)


@pytest.mark.parametrize("w", [1e-12, 1e-9, 1e-6, DYNEEMA_N_PER_M])
@pytest.mark.parametrize("v0", [11.0, -3.0, 0.0])
def test_the_forms_stay_exact_where_the_printed_one_loses_its_digits(w: float, v0: float) -> None:
    """w -> 0: the printed form divides a difference of nearly equal terms by w."""
    h, l0, c = 100.0, 47.8, 1.0 / 4.5e5
    exact = textbook_decimal(h, v0, l0, w, c)
    ours = math.dist(catenary.reach(h, v0, l0, w, c), exact)
    assert ours < 1e-13
    if w <= 1e-9:
        assert math.dist(textbook(h, v0, l0, w, c), exact) > 1e3 * max(ours, 1e-15)


@FAST
@given(
    span=spans,
    rise=rises,
    w=weights,
    ea=eas,
    h=st.floats(5.0, 2000.0),
)
def test_from_horizontal_force_inverts_from_length(
    span: float, rise: float, w: float, ea: float, h: float
) -> None:
    assume(w * span / (2.0 * h) < 5.0)
    ends = catenary.from_horizontal_force(span, rise, h, w, 1.0 / ea)
    assert ends.h_n == h
    back = catenary.from_length(span, rise, ends.unstretched_m, w, 1.0 / ea)
    assert back.h_n == pytest.approx(h, rel=1e-7)
    assert back.v0_n == pytest.approx(ends.v0_n, rel=1e-7, abs=1e-7 * ends.t0_n)


def test_vertical_and_horizontal_limits() -> None:
    """H -> 0 (a nearly vertical cable) and V0 = 0 stay finite and continuous."""
    w, c, l0 = STEEL_N_PER_M, 1.0 / 4.5e5, 10.0
    vertical = catenary.reach(0.0, 50.0, l0, w, c)
    assert vertical[0] == 0.0
    assert vertical[1] == pytest.approx(l0 * (1.0 + c * (50.0 + 0.5 * w * l0)), rel=1e-14)
    near = catenary.reach(1e-9, 50.0, l0, w, c)
    assert near[0] > 0.0 and near[0] < 1e-9
    assert near[1] == pytest.approx(vertical[1], rel=1e-14)
    # the lowest point at the effector (V0 = 0), and just either side of it
    mid = catenary.reach(100.0, 0.0, l0, w, c)
    for v0 in (-1e-12, 1e-12):
        assert catenary.reach(100.0, v0, l0, w, c) == pytest.approx(mid, rel=1e-12)
    # a straight vertical cable from the forward solve
    up = catenary.from_length(0.0, 10.001, l0, w, c)
    assert up.h_n == 0.0 and up.v0_n > 0.0


@pytest.mark.parametrize("h", [50.0, 0.0, 1e-12])
def test_reach_derivatives_match_finite_differences(h: float) -> None:
    w, c, l0, v0 = STEEL_N_PER_M, 1.0 / 4.5e5, 48.0, 20.0
    r = catenary.reach_derivatives(h, v0, l0, w, c)
    eps_f, eps_l = 1e-4, 1e-6
    base = catenary.reach(h, v0, l0, w, c)
    dh = [
        (a - b) / eps_f for a, b in zip(catenary.reach(h + eps_f, v0, l0, w, c), base, strict=True)
    ]
    dv = [
        (a - b) / eps_f for a, b in zip(catenary.reach(h, v0 + eps_f, l0, w, c), base, strict=True)
    ]
    dl = [
        (a - b) / eps_l for a, b in zip(catenary.reach(h, v0, l0 + eps_l, w, c), base, strict=True)
    ]
    assert (r.span_m, r.rise_m) == pytest.approx(base, rel=1e-15)
    if h > 1e-6:
        assert r.ds_dh == pytest.approx(dh[0], rel=1e-4)
        assert r.dr_dh == pytest.approx(dh[1], rel=1e-4)
    assert r.ds_dv == pytest.approx(dv[0], rel=1e-4, abs=1e-12)
    assert r.dr_dv == pytest.approx(dv[1], rel=1e-4)
    assert r.ds_dl == pytest.approx(dl[0], rel=1e-4, abs=1e-12)
    assert r.dr_dl == pytest.approx(dl[1], rel=1e-4)
    assert r.ds_dv == r.dr_dh  # the flexibility is symmetric


def test_sag_of_a_shallow_cable_is_the_parabolas() -> None:
    """Mid-span drop w' l^2 / (8 H) (w' the weight per horizontal metre), extra length
    w'^2 l^3 / (24 H^2) plus the stretch, for a shallow inextensible and elastic cable."""
    span, rise, w = 47.5, 5.62, DYNEEMA_N_PER_M
    chord = math.hypot(span, rise)
    ends = catenary.from_horizontal_force(span, rise, 100.0, w, 0.0)
    drop, extra = catenary.sag(ends, span, rise, w, 0.0)
    wh = w * chord / span
    assert drop == pytest.approx(wh * span**2 / (8.0 * 100.0), rel=0.01)
    assert extra == pytest.approx(
        wh**2 * span**3 / (24.0 * 100.0**2) * (span / chord) ** 2, rel=0.05
    )
    assert extra == pytest.approx(ends.unstretched_m - chord, rel=1e-9)
    elastic = catenary.from_horizontal_force(span, rise, 100.0, w, 1.0 / 4.5e5)
    _, extra_e = catenary.sag(elastic, span, rise, w, 1.0 / 4.5e5)
    assert extra_e == pytest.approx(extra, rel=1e-3)  # the shape is the tension's, not EA's


def test_slack_cables_are_a_named_error() -> None:
    c = 1.0 / 4.5e5
    with pytest.raises(SlackCableError, match="slack"):
        catenary.from_length(40.0, 3.0, 41.0, 0.0, c)  # massless and longer than the distance
    with pytest.raises(SlackCableError):
        catenary.from_horizontal_force(40.0, 3.0, 0.0, STEEL_N_PER_M, c)
    with pytest.raises(SlackCableError):
        catenary.from_horizontal_force(40.0, 3.0, -5.0, STEEL_N_PER_M, c)
    with pytest.raises(SlackCableError, match="hangs slack"):
        catenary.from_horizontal_force(80.0, 3.0, 1e-3, STEEL_N_PER_M, c)
    with pytest.raises(SlackCableError):
        catenary.reach(0.0, -1.0, 10.0, STEEL_N_PER_M, c)  # doubled under the effector
    with pytest.raises(SlackCableError):
        catenary.from_length(0.0, -5.0, 10.0, STEEL_N_PER_M, c)
    with pytest.raises(CatenaryError, match="cannot reach"):
        catenary.from_length(40.0, 3.0, 39.0, STEEL_N_PER_M, 0.0)
    for bad in (math.nan, math.inf, -1.0):
        with pytest.raises(CatenaryError):
            catenary.from_length(bad, 3.0, 41.0, STEEL_N_PER_M, c)
        with pytest.raises(CatenaryError):
            catenary.from_length(40.0, 3.0, 41.0, bad, c)
    with pytest.raises(CatenaryError):
        catenary.from_length(40.0, math.nan, 41.0, STEEL_N_PER_M, c)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(
    span=st.floats(0.0, 1e4, allow_subnormal=False),
    rise=st.floats(-1e4, 1e4, allow_subnormal=False),
    l0=st.floats(1e-6, 2e4, allow_subnormal=False),
    w=st.floats(0.0, 1e3, allow_subnormal=False),
    ea=st.floats(1.0, 1e12),
)
def test_never_nan_a_solution_or_a_named_error(
    span: float, rise: float, l0: float, w: float, ea: float
) -> None:
    try:
        ends = catenary.from_length(span, rise, l0, w, 1.0 / ea)
        assert all(map(math.isfinite, ends[:6]))
        assert ends.h_n >= 0.0 and ends.unstretched_m == l0
    except CatenaryError:
        pass
    try:  # the same numbers as a horizontal force
        ends = catenary.from_horizontal_force(span, rise, l0, w, 1.0 / ea)
        assert all(map(math.isfinite, ends[:6]))
        assert ends.unstretched_m > 0.0
    except CatenaryError:
        pass
