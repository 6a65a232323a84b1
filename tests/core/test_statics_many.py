"""Five to eight cables (`controller.core.tension_many`): the max-min rule made strictly convex.

Checked against scipy's linprog (an independent solver of the max-min linear program) on
random layouts with anchors above and below the effector and random forces: the planned
distribution's margin is the max-min's to within `REGULARISE` of its distance from the middle,
and it keeps the limits wherever linprog can; the answer does not depend on where the solve
starts (the tick's warm start); it moves continuously along paths (the max-min vertex alone
jumps by tens of newtons on an eight-cable cube); the batch is the single-pose solve;
symmetric poses give the symmetric answer.
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

from controller.core.statics import G_MPS2, CableStatics, SingularConfiguration
from controller.core.tension_many import REGULARISE

linprog = pytest.importorskip("scipy.optimize").linprog

FAST = settings(max_examples=200, deadline=None, derandomize=True)

CUBE = np.array([[x, y, z] for x in (-1.2, 1.2) for y in (-1.0, 1.0) for z in (0.0, 2.0)])
# Four low anchors and one on the ceiling (a five-anchor Hangprinter).
HP5 = np.array(
    [[-1.5, -1.5, -0.1], [1.5, -1.5, -0.12], [1.5, 1.5, -0.1], [-1.5, 1.5, -0.11], [0, 0, 2.5]]
)


def units(anchors: NDArray[np.float64], p: NDArray[np.float64]) -> NDArray[np.float64]:
    d = np.asarray(anchors, dtype=np.float64) - np.asarray(p, dtype=np.float64)
    return (d / np.linalg.norm(d, axis=1)[:, None]).T


def lp_margin(u: NDArray[np.float64], f: NDArray[np.float64], lo: float, hi: float) -> float:
    """linprog's largest smallest distance to a limit over U t = f."""
    n = u.shape[1]
    res: Any = linprog(
        np.r_[np.zeros(n), -1.0],
        A_ub=np.block([[-np.eye(n), np.ones((n, 1))], [np.eye(n), np.ones((n, 1))]]),
        b_ub=np.r_[np.full(n, -lo), np.full(n, hi)] / hi,
        A_eq=np.c_[u, np.zeros(3)],
        b_eq=f / hi,
        bounds=[(None, None)] * (n + 1),
    )
    assert res.status == 0, res.message
    return float(res.x[-1]) * hi


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


@FAST
@given(layout(), st.tuples(st.floats(0.0, 20.0), st.floats(50.0, 2000.0)))
def test_the_margin_is_linprogs(
    lpf: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
    lim: tuple[float, float],
) -> None:
    """Equilibrium to rounding; the margin at most linprog's and at most `REGULARISE` of the
    max-min's distance from the middle below it (where the limits can be kept); within the
    limits wherever linprog is."""
    anchors, p, f = lpf
    lo, hi = lim
    try:
        r = CableStatics(anchors, lo, hi).solve_force(p, f)
    except SingularConfiguration:
        assume(False)
        raise
    t = np.array(r.tensions_n)
    u = units(anchors, p)
    scale = max(hi, float(np.linalg.norm(f)))
    assert np.max(np.abs(u @ t - f)) <= 1e-9 * scale
    ref = lp_margin(u, f, lo, hi)
    half = 0.5 * (hi - lo)
    rho = half - ref  # the max-min's largest distance from the middle
    assert r.margin_n <= ref + 1e-7 * scale
    # within REGULARISE of rho (of rho^2 / half where no distribution keeps the limits)
    assert r.margin_n >= ref - REGULARISE * rho * max(1.0, rho / half) - 1e-7 * scale
    if ref >= 1e-7 * scale:
        assert r.feasible
    assert r.method == "lp"


@pytest.mark.parametrize("anchors", [CUBE, HP5], ids=["cube", "hangprinter-5"])
def test_the_answer_does_not_depend_on_where_the_solve_starts(
    anchors: NDArray[np.float64],
) -> None:
    """One solver kept along a path (each solve starts from the last pose's bound cables)
    and a fresh solver per pose agree to rounding, and the tensions along a smooth path move
    smoothly (no jump between neighbouring poses)."""
    warm = CableStatics(anchors, 2.0, 120.0)
    s = np.linspace(0.0, 1.0, 400)
    path = np.column_stack([0.6 * np.cos(6 * s), 0.5 * np.sin(4 * s), 0.3 + 1.2 * s])
    prev = None
    for p in path:
        ra = warm.solve(p, 1.0)
        a = np.array(ra.tensions_n)
        b = np.array(CableStatics(anchors, 2.0, 120.0).solve(p, 1.0).tensions_n)
        assert np.max(np.abs(a - b)) <= 1e-7 * 120.0
        if prev is not None and ra.margin_n > 0.0:
            assert np.max(np.abs(a - prev)) < 10.0  # 9 mm steps: no vertex jump
        prev = a


def test_tensions_move_continuously_on_an_eight_cable_cube() -> None:
    """Straight paths through the cube at 0.5 mm steps: no planned tension changes by more
    than 1 N in a step where the payload can be held (the max-min vertex alone changes by up
    to tens of newtons where its optimal pair switches)."""
    s = CableStatics(CUBE, 2.0, 120.0)
    rng = np.random.default_rng(1)
    worst = 0.0
    for _ in range(15):
        a, b = rng.uniform([-1.0, -0.8, 0.2], [1.0, 0.8, 1.8], (2, 3))
        steps = int(np.linalg.norm(b - a) / 0.0005)
        res = [s.solve(a + k / steps * (b - a), 1.0) for k in range(steps + 1)]
        t = np.array([r.tensions_n for r in res])
        held = np.array([r.margin_n > 0.0 for r in res])
        jump = np.abs(np.diff(t, axis=0)).max(axis=1)[held[1:] & held[:-1]]
        worst = max(worst, float(jump.max(initial=0.0)))
    assert worst < 1.0


@pytest.mark.parametrize("anchors", [CUBE, HP5], ids=["cube", "hangprinter-5"])
def test_batch_is_the_single_pose_solve(anchors: NDArray[np.float64]) -> None:
    rng = np.random.default_rng(11)
    pts = rng.uniform([-1.0, -1.0, 0.1], [1.0, 1.0, 1.8], (500, 3))
    pts[0] = anchors[0]  # on an anchor: singular
    pts[1] = [math.nan, 0.0, 1.0]
    pts[2] = [0.0, 0.0, 1.0]  # the middle: symmetric for the cube
    s = CableStatics(anchors, 2.0, 120.0)
    t, margin, feasible, limiting = s.solve_batch(pts, 1.0)
    assert np.isfinite(t).all() and np.isfinite(margin).all()
    assert limiting[0] == -1 and limiting[1] == -1 and not feasible[:2].any()
    for k in range(2, len(pts)):
        r = s.solve(pts[k], 1.0)
        assert np.max(np.abs(t[k] - np.array(r.tensions_n))) <= 1e-9 * 120.0, k
        assert margin[k] == pytest.approx(r.margin_n, abs=1e-9 * 120.0)
        assert feasible[k] == r.feasible


def test_symmetric_poses_have_the_symmetric_answer() -> None:
    """At a cube's centre every pair's plane holds two more cables (a degenerate max-min
    vertex the pairs settle among themselves, no linear program): the top four share the
    weight's excess equally, and the margin is linprog's."""
    s = CableStatics(CUBE, 2.0, 120.0)
    p = np.array([0.0, 0.0, 1.0])
    r = s.solve(p, 1.0)
    top = [r.tensions_n[i] for i in range(8) if CUBE[i, 2] > 1.0]
    low = [r.tensions_n[i] for i in range(8) if CUBE[i, 2] < 1.0]
    assert max(top) - min(top) < 1e-9 and max(low) - min(low) < 1e-9
    assert top[0] > low[0]
    u = units(CUBE, p)
    assert r.margin_n == pytest.approx(lp_margin(u, np.array([0, 0, G_MPS2]), 2.0, 120.0))
    # on the vertical line through the centre: the same pattern all the way up
    for z in (0.4, 0.8, 1.5):
        t = np.array(s.solve((0.0, 0.0, z), 1.0).tensions_n)
        assert np.ptp(t[CUBE[:, 2] > 1.0]) < 1e-9 and np.ptp(t[CUBE[:, 2] < 1.0]) < 1e-9


def test_hangprinter_5_holds_a_kilogram_across_its_volume() -> None:
    """Four low cables and the top one: the top cable carries the weight and the low cables'
    pull; every pose inside the pyramid can hold 1 kg within 2..120 N."""
    s = CableStatics(HP5, 2.0, 120.0)
    rng = np.random.default_rng(2)
    pts = rng.uniform([-0.6, -0.6, 0.1], [0.6, 0.6, 1.2], (2000, 3))
    _, margin, feasible, _ = s.solve_batch(pts, 1.0)
    assert feasible.all() and margin.min() > 0.0
    r = s.solve((0.0, 0.0, 0.6), 1.0)
    assert r.tensions_n[4] == max(r.tensions_n)
