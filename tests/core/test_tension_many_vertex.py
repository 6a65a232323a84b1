"""The pair vertex shortcut of five to eight cables (`controller.core.tension_many`).

Where the strictly convex answer frees two cables and binds the rest, it is the max-min
vertex itself: ``settles`` says so from the vertex's own numbers and ``vertex_tensions``
returns it, without the active-set solve.  Checked against the active-set solve
(``regularised``, started from the vertex's bound cables, then ``project``: the path every pose
took before the shortcut) on random layouts, forces and limits: wherever ``settles`` says yes
the active set is the vertex's and the tensions agree to rounding, and ``CableStatics`` gives
the active-set answer cold and a tick later.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from controller.core.statics import CableStatics, SingularConfiguration
from controller.core.tension_many import (
    MANY_TOL,
    REGULARISE,
    PairSolution,
    Vec3,
    freest_pair,
    pivot_solve,
    project,
    regularised,
    settles,
    vertex_tensions,
)

FAST = settings(max_examples=300, deadline=None, derandomize=True)

CUBE = np.array([[x, y, z] for x in (-1.2, 1.2) for y in (-1.0, 1.0) for z in (0.0, 2.0)])


@st.composite
def layout(draw: st.DrawFn) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """5 to 8 anchors anywhere in a 10 m cube, P near its middle, a force up to 300 N."""
    n = draw(st.integers(5, 8))
    coord = st.floats(-5.0, 5.0)
    pts = [(draw(coord), draw(coord), draw(coord)) for _ in range(n)]
    assume(all(math.dist(a, b) > 1.0 for a, b in itertools.combinations(pts, 2)))
    a = np.array(pts)
    p = np.array([draw(st.floats(-1.5, 1.5)) for _ in range(3)])
    assume(bool(np.all(np.linalg.norm(a - p, axis=1) > 0.5)))
    f = np.array([draw(st.floats(-300.0, 300.0)) for _ in range(3)])
    return a, p, f


def unit_list(anchors: NDArray[np.float64], p: NDArray[np.float64]) -> list[Vec3]:
    d = anchors - p
    d /= np.linalg.norm(d, axis=1)[:, None]
    return [(float(x), float(y), float(z)) for x, y, z in d.tolist()]


def problem(
    u: list[Vec3], f: NDArray[np.float64], lo: float, hi: float
) -> tuple[Vec3, float, float, float, float, float]:
    """g, the middle c, the half range r, eps, the scale and the tolerance of the solve."""
    c = 0.5 * (lo + hi)
    r = 0.5 * (hi - lo)
    su = np.sum(np.array(u), axis=0)
    g = f - c * su
    mag = float(np.linalg.norm(f))
    scale = hi + mag
    return (
        (float(g[0]), float(g[1]), float(g[2])),
        c,
        r,
        2.0 * REGULARISE / (len(u) * r),
        scale,
        MANY_TOL * scale,
    )


def active_set_answer(
    u: list[Vec3], f: Vec3, g: Vec3, c: float, r: float, eps: float, tol: float, v: PairSolution
) -> list[float]:
    """The planned tensions by the active-set solve from the vertex's bound cables (the
    vertex itself where that answer leaves the limits and the vertex keeps them)."""
    res = regularised(u, g, eps, v.signs, tol, 4 * len(u))
    if res is None or (res[1] > r >= v.rho):
        return project(u, f, c, v.d)
    return project(u, f, c, res[0])


@FAST
@given(layout(), st.tuples(st.floats(0.0, 20.0), st.floats(50.0, 2000.0)))
def test_a_settled_vertex_is_the_active_set_answer(
    lpf: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
    lim: tuple[float, float],
) -> None:
    """Wherever ``settles`` accepts the max-min vertex, the active-set solve from it keeps
    its bound cables and gives its tensions to rounding."""
    anchors, p, f = lpf
    lo, hi = lim
    u = unit_list(anchors, p)
    g, c, _r, eps, scale, tol = problem(u, f, lo, hi)
    a, b = freest_pair(u, g)
    v = pivot_solve(u, g, a, b, scale, 2 * len(u))
    assume(v is not None)
    assert v is not None
    assume(settles(u, v, eps))
    res = regularised(u, g, eps, v.signs, tol, 4 * len(u))
    assert res is not None
    assert res[2] == v.signs
    fv = (float(f[0]), float(f[1]), float(f[2]))
    fast = vertex_tensions(u, g, c, v)
    ref = project(u, fv, c, res[0])
    assert max(abs(x - y) for x, y in zip(fast, ref, strict=True)) <= 1e-9 * scale


@FAST
@given(
    layout(),
    st.tuples(st.floats(0.0, 20.0), st.floats(50.0, 2000.0)),
    st.tuples(st.floats(-0.001, 0.001), st.floats(-0.001, 0.001), st.floats(-0.001, 0.001)),
)
def test_the_solve_gives_the_active_set_answer_cold_and_a_tick_later(
    lpf: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
    lim: tuple[float, float],
    step: tuple[float, float, float],
) -> None:
    """``CableStatics.solve_force`` at a pose and then a tick away (up to 1 mm) gives the
    active-set answer at both to rounding."""
    anchors, p, f = lpf
    lo, hi = lim
    statics = CableStatics(anchors, lo, hi)
    fv = (float(f[0]), float(f[1]), float(f[2]))
    for q in (p, p + np.array(step)):
        try:
            got = statics.solve_force(q.tolist(), fv).tensions_n
        except SingularConfiguration:
            assume(False)
            raise
        u = unit_list(anchors, q)
        g, c, r, eps, scale, tol = problem(u, f, lo, hi)
        v = pivot_solve(u, g, *freest_pair(u, g), scale, 2 * len(u))
        assume(v is not None)
        assert v is not None
        ref = active_set_answer(u, fv, g, c, r, eps, tol, v)
        assert max(abs(x - y) for x, y in zip(got, ref, strict=True)) <= 1e-8 * scale


def test_the_shortcut_is_taken_on_an_eight_cable_cube() -> None:
    """At most poses of the eight-cable cube holding a kilogram the vertex settles (the
    shortcut is the tick's path, not a rarity)."""
    rng = np.random.default_rng(5)
    pts = rng.uniform([-0.8, -0.6, 0.4], [0.8, 0.6, 1.6], (200, 3))
    f = np.array([0.0, 0.0, 9.80665])
    settled = 0
    for p in pts:
        u = unit_list(CUBE, p)
        g, _c, _r, eps, scale, _tol = problem(u, f, 2.0, 120.0)
        v = pivot_solve(u, g, *freest_pair(u, g), scale, 16)
        assert v is not None
        settled += settles(u, v, eps)
    assert settled >= 150
