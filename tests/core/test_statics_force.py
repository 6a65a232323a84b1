"""The statics' core API: tensions from the cable directions and the force the cables supply.

`CableStatics.solve_force` (straight cables from a point, any force) and `solve_directions`
(any unit directions, any force) are the core every solve runs through; `solve` is the weight
of a mass at rest. Checked against scipy's linprog (an independent reference) on layouts with
cables pulling in every direction (a Hangprinter's low anchors pull down) and on forces that
are not vertical (an accelerating payload).
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from controller.core.statics import (
    G_MPS2,
    CableStatics,
    SingularConfiguration,
    StaticsInputError,
    TensionCheck,
)
from controller.core.tension_many import REGULARISE

linprog = pytest.importorskip("scipy.optimize").linprog

FAST = settings(max_examples=150, deadline=None, derandomize=True)

# The Hangprinter v4 reference anchors (m): three low, one on the ceiling.
HP4 = np.array(
    [
        [0.0, -1.61098, -0.13153],
        [1.31422, 1.26814, -0.12128],
        [-1.41573, 0.70761, -0.12182],
        [0.0, 0.0, 2.29983],
    ]
)


def units(anchors: NDArray[np.float64], p: NDArray[np.float64]) -> NDArray[np.float64]:
    """U, the (3, N) matrix of unit vectors from p toward each anchor."""
    d = np.asarray(anchors, dtype=np.float64) - np.asarray(p, dtype=np.float64)
    return (d / np.linalg.norm(d, axis=1)[:, None]).T


def lp_reference(u: NDArray[np.float64], f: NDArray[np.float64], lo: float, hi: float) -> float:
    """The largest smallest distance to a limit over U t = f, by linprog (unknowns t, s)."""
    n = u.shape[1]
    c = np.r_[np.zeros(n), -1.0]
    a_ub = np.block([[-np.eye(n), np.ones((n, 1))], [np.eye(n), np.ones((n, 1))]])
    b_ub = np.r_[np.full(n, -lo), np.full(n, hi)] / hi
    a_eq = np.c_[u, np.zeros(3)]
    res: Any = linprog(
        c, A_ub=a_ub, b_ub=b_ub, A_eq=a_eq, b_eq=f / hi, bounds=[(None, None)] * (n + 1)
    )
    assert res.status == 0, res.message
    return float(res.x[-1]) * hi


@st.composite
def layout_point_force(
    draw: st.DrawFn,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """3 to 6 anchors anywhere in a 10 m cube (some above P, some below), P near the middle,
    and a force of up to 200 N in any direction."""
    n = draw(st.integers(3, 6))
    coord = st.floats(-5.0, 5.0)
    pts = [(draw(coord), draw(coord), draw(coord)) for _ in range(n)]
    assume(all(math.dist(a, b) > 1.0 for a, b in itertools.combinations(pts, 2)))
    p = np.array([draw(st.floats(-1.0, 1.0)) for _ in range(3)])
    a = np.array(pts)
    assume(bool(np.all(np.linalg.norm(a - p, axis=1) > 0.5)))
    f = np.array([draw(st.floats(-200.0, 200.0)) for _ in range(3)])
    return a, p, f


@FAST
@given(layout_point_force(), st.tuples(st.floats(0.0, 20.0), st.floats(50.0, 2000.0)))
def test_any_force_is_supplied_farthest_from_the_limits(
    lpf: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
    lim: tuple[float, float],
) -> None:
    """U t = f to rounding, and the margin is linprog's (three cables: the unique solution;
    five and more: within `REGULARISE` of it, see tests/core/test_statics_many.py)."""
    anchors, p, f = lpf
    lo, hi = lim
    s = CableStatics(anchors, lo, hi)
    try:
        r = s.solve_force(p, f)
    except SingularConfiguration:
        assume(False)
        raise
    t = np.array(r.tensions_n)
    u = units(anchors, p)
    scale = max(float(np.linalg.norm(f)), float(np.max(np.abs(t))), 1.0)
    assert np.max(np.abs(u @ t - f)) <= 1e-9 * scale
    ref = lp_reference(u, f, lo, hi)
    if len(anchors) <= 4:
        assert r.margin_n == pytest.approx(ref, abs=1e-6 * scale)
    else:  # the max-min made strictly convex (tension_many.REGULARISE)
        half = 0.5 * (hi - lo)
        rho = half - ref
        slack = REGULARISE * rho * max(1.0, rho / half) + 1e-6 * scale
        assert ref - slack <= r.margin_n <= ref + 1e-6 * scale
    # the core on the same directions gives the same distribution
    same = s.solve_directions([tuple(c) for c in u.T], f)
    assert np.max(np.abs(np.array(same.tensions_n) - t)) <= 1e-9 * scale


@FAST
@given(
    st.sampled_from([3, 4, 5, 6]),
    st.tuples(st.floats(-8.0, 8.0), st.floats(-5.0, 5.0), st.floats(0.0, 6.0)),
    st.floats(0.1, 30.0),
)
def test_the_weight_through_the_force_api_is_solve(
    n: int, xyz: tuple[float, float, float], mass: float
) -> None:
    """`solve(P, m)` is `solve_force(P, (0, 0, m g))`, to the last bit, on hanging layouts."""
    ring = np.array(
        [
            (10.0 * math.cos(2 * math.pi * k / n), 7.0 * math.sin(2 * math.pi * k / n), 8.0)
            for k in range(n)
        ]
    )
    ring[:, 2] += np.arange(n) * 0.3  # not level: the general seed of every count
    s = CableStatics(ring, 2.0, 900.0)
    a = s.solve(xyz, mass, derivative=True)
    b = s.solve_force(xyz, (0.0, 0.0, mass * G_MPS2), derivative=True)
    assert a == b


def test_hangprinter_low_cables_pull_down_and_the_top_one_carries_them() -> None:
    """At the middle of the Hangprinter v4 volume the three low cables pull down and sideways;
    the top cable carries the weight plus their downward pull, every tension as far from the
    limits as linprog finds, and the weight's solve is the force's."""
    s = CableStatics(HP4, 2.0, 120.0)
    p = np.array([0.0, 0.0, 0.8])
    r = s.solve(p, 1.0)
    u = units(HP4, p)
    t = np.array(r.tensions_n)
    assert r.feasible and r.method == "closed-form"
    assert (u[2, :3] < 0.0).all() and u[2, 3] > 0.0  # low cables point down, D up
    down = float(-(u[2, :3] * t[:3]).sum())
    assert t[3] * u[2, 3] == pytest.approx(G_MPS2 + down, rel=1e-12)
    assert r.margin_n == pytest.approx(lp_reference(u, np.array([0, 0, G_MPS2]), 2.0, 120.0))
    # inside the tetrahedron every force can be supplied: sideways too
    side = s.solve_force(p, (30.0, -20.0, 5.0))
    assert side.feasible
    assert np.allclose(u @ np.array(side.tensions_n), [30.0, -20.0, 5.0], atol=1e-9)


def test_an_accelerating_payload_changes_the_tensions() -> None:
    """m (g + a): accelerating up loads every cable of a hanging robot more; the tension
    check judges the force's distribution with the payload's rule."""
    anchors = np.array([[-2.0, -2.0, 3.0], [-2.0, 2.0, 3.0], [2.0, 2.0, 3.0], [2.0, -2.0, 3.0]])
    chk = TensionCheck(anchors, 2.0, 1.0, 60.0, 1.0)
    rest = chk.solve((0.0, 0.0, 1.0))
    up = chk.solve_force((0.0, 0.0, 1.0), (0.0, 0.0, 2.0 * (G_MPS2 + 3.0)))
    assert all(b > a for a, b in zip(rest.tensions_n, up.tensions_n, strict=True))
    assert sum(up.tensions_n) == pytest.approx(sum(rest.tensions_n) * (G_MPS2 + 3.0) / G_MPS2)
    assert chk.reason(rest) is None
    hard = chk.solve_force((0.0, 0.0, 1.0), (0.0, 0.0, 2.0 * (G_MPS2 + 80.0)))
    reason = chk.reason(hard)
    assert reason is not None and "above" in reason and "max_tension_n" in reason


def test_force_api_errors() -> None:
    s = CableStatics(HP4, 2.0, 120.0)
    p = (0.0, 0.0, 0.8)
    good = [tuple(c) for c in units(HP4, np.array(p)).T]
    with pytest.raises(StaticsInputError, match="3 components"):
        s.solve_force(p, (1.0, 2.0))
    with pytest.raises(StaticsInputError, match="not finite"):
        s.solve_force(p, (0.0, math.nan, 9.8))
    with pytest.raises(StaticsInputError, match="need 4 cable directions"):
        s.solve_directions(good[:3], (0.0, 0.0, 9.8))
    with pytest.raises(StaticsInputError, match=r"cable 2: direction .* not a unit vector"):
        s.solve_directions([good[0], (0.5, 0.5, 0.5), good[2], good[3]], (0.0, 0.0, 9.8))
    with pytest.raises(StaticsInputError, match="cable 3: direction"):
        s.solve_directions([good[0], good[1], (math.inf, 0.0, 0.0), good[3]], (0, 0, 9.8))
    # a hanging layout cannot pull the effector down: no cable pulls along the force
    hang = CableStatics([[-1, -1, 3], [-1, 1, 3], [1, 1, 3], [1, -1, 3]], 1.0, 100.0)
    with pytest.raises(SingularConfiguration, match="no cable pulls along the force"):
        hang.solve_force((0.0, 0.0, 1.0), (0.0, 0.0, -20.0))
    # and the weight's solve keeps its own words
    with pytest.raises(SingularConfiguration, match="at or above every anchor"):
        hang.solve((0.0, 0.0, 3.5), 1.0)


def test_no_force_is_pure_internal_tension() -> None:
    """No force: a layout enclosing P pulls its cables against each other (all taut); a
    hanging one cannot (every distribution leaves a cable at or below zero)."""
    s = CableStatics(HP4, 2.0, 120.0)
    r = s.solve_force((0.0, 0.0, 0.8), (0.0, 0.0, 0.0))
    assert r.feasible and min(r.tensions_n) > 2.0
    hang = CableStatics([[-1, -1, 3], [-1, 1, 3], [1, 1, 3], [1, -1, 3]], 1.0, 100.0)
    assert not hang.solve_force((0.3, 0.1, 1.0), (0.0, 0.0, 0.0)).feasible
