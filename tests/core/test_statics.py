"""Tests of controller.core.statics: cable tensions of a hanging point mass, batch form, workspace.

The closed form for four cables is checked against an LP written here (scipy's linprog) on
thousands of points; the properties (equilibrium, limits, margin, scaling) run under
hypothesis on the paper robot, the desk rig and random layouts.
"""

from __future__ import annotations

import itertools
import math
import sys
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from controller.core.feasible import feasible_workspace
from controller.core.statics import (
    G_MPS2,
    SINGULAR_MARGIN_N,
    SINGULAR_ROW,
    CableStatics,
    SingularConfiguration,
    SolverUnavailable,
    StaticsError,
    StaticsInputError,
    Tensions,
    solve_tensions,
    tensions_batch,
)

linprog = pytest.importorskip("scipy.optimize").linprog

CONFIG_DIR = Path(__file__).resolve().parents[2] / "config"
FAST = settings(max_examples=200, deadline=None, derandomize=True)


def config_anchors(name: str) -> NDArray[np.float64]:
    """The anchors of config/<name>.toml, in reel order."""
    with open(CONFIG_DIR / f"{name}.toml", "rb") as f:
        cfg = tomllib.load(f)
    return np.array([r["anchor_m"] for r in cfg["reels"]], dtype=np.float64)


PAPER = config_anchors("paper-acre")  # 80.9 m x 50 m, anchors 7.62 m up
DESK = config_anchors("desk")  # 1 m x 1 m, anchors 0.8 m up
# Geometric workspace boxes from the configs' [limits] (the footprints are rectangles).
PAPER_BOX = ((-38.45, 38.45), (-23.0, 23.0), (0.0, 6.62))
DESK_BOX = ((-0.45, 0.45), (-0.45, 0.45), (0.01, 0.7))


def units(anchors: NDArray[np.float64], p: NDArray[np.float64]) -> NDArray[np.float64]:
    """U, the (3, N) matrix of unit vectors from p to each anchor."""
    d = np.asarray(anchors, dtype=np.float64) - np.asarray(p, dtype=np.float64)
    return (d / np.linalg.norm(d, axis=1)[:, None]).T


def distance_to_limits(t: NDArray[np.float64], lo: float, hi: float) -> float:
    return float(np.min(np.minimum(t - lo, hi - t)))


def lp_margin(
    anchors: NDArray[np.float64], p: NDArray[np.float64], w: float, lo: float, hi: float
) -> tuple[float, NDArray[np.float64]]:
    """Reference: max over U t = w e_z of the smallest distance to a limit, by linprog.

    Unknowns (t, s) in newtons scaled by 1/hi; maximise s subject to t_i - s >= lo and
    t_i + s <= hi.
    """
    u = units(anchors, p)
    n = u.shape[1]
    k = hi
    c = np.r_[np.zeros(n), -1.0]
    a_ub = np.block([[-np.eye(n), np.ones((n, 1))], [np.eye(n), np.ones((n, 1))]])
    b_ub = np.r_[np.full(n, -lo / k), np.full(n, hi / k)]
    a_eq = np.c_[u, np.zeros(3)]
    b_eq = np.array([0.0, 0.0, w / k])
    res: Any = linprog(
        c, A_ub=a_ub, b_ub=b_ub, A_eq=a_eq, b_eq=b_eq, bounds=[(None, None)] * (n + 1)
    )
    assert res.status == 0, res.message
    return float(res.x[-1]) * k, np.asarray(res.x[:n]) * k


def check_result(
    r: Tensions, anchors: NDArray[np.float64], p: NDArray[np.float64], mass: float
) -> None:
    """Equilibrium, limits, margin and limiting cable of one result."""
    t = np.array(r.tensions_n)
    assert np.isfinite(t).all() and math.isfinite(r.margin_n)
    assert t.shape == (len(anchors),)
    w = mass * G_MPS2
    scale = max(w, float(np.max(np.abs(t))))
    resid = units(anchors, p) @ t - np.array([0.0, 0.0, w])
    assert np.max(np.abs(resid)) <= 1e-12 * scale
    lo, hi = r.t_min_n, r.t_max_n
    assert r.margin_n == distance_to_limits(t, lo, hi)
    i = r.limiting_cable
    at = t[i] - lo if r.limiting_bound == "min" else hi - t[i]
    assert at == r.margin_n
    assert r.feasible == (r.margin_n >= 0.0)
    if r.feasible:
        assert (t >= lo).all() and (t <= hi).all()
        assert r.reason() is None
    else:
        assert not lo <= t[i] <= hi
        reason = r.reason()
        assert reason is not None and f"cable {i + 1} " in reason


# -- strategies ------------------------------------------------------------------------------


def box_points(box: tuple[tuple[float, float], ...]) -> st.SearchStrategy[NDArray[np.float64]]:
    return st.tuples(*(st.floats(a, b) for a, b in box)).map(lambda x: np.array(x))


@st.composite
def layout_and_point(
    draw: st.DrawFn, n_min: int = 3, n_max: int = 6
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Random anchors (plan-view spread out, heights 2..12 m) and a point at least 0.5 m below
    the lowest anchor, within (about) the anchors' plan-view extent."""
    n = draw(st.integers(n_min, n_max))
    coord = st.floats(-30.0, 30.0)
    pts = [(draw(coord), draw(coord), draw(st.floats(8.0, 12.0))) for _ in range(n)]
    plan = [p[:2] for p in pts]
    assume(all(math.dist(a, b) > 3.0 for a, b in itertools.combinations(plan, 2)))
    a = np.array(pts)
    x = draw(st.floats(float(a[:, 0].min()), float(a[:, 0].max())))
    y = draw(st.floats(float(a[:, 1].min()), float(a[:, 1].max())))
    z = draw(st.floats(0.0, float(a[:, 2].min()) - 0.5))
    return a, np.array([x, y, z])


limits = st.tuples(st.floats(0.0, 20.0), st.floats(50.0, 2000.0))
masses = st.floats(0.1, 50.0)


def solve_or_skip(
    anchors: NDArray[np.float64], p: NDArray[np.float64], mass: float, lo: float, hi: float
) -> Tensions:
    """Solve, rejecting (hypothesis) the rare random pose that is singular."""
    try:
        return solve_tensions(anchors, p, mass, lo, hi)
    except SingularConfiguration:
        assume(False)
        raise


# -- worked examples -------------------------------------------------------------------------


def test_paper_centre_four_equal_tensions() -> None:
    """At the centre of the rectangle the four cables share the weight equally:
    t = m g / (4 u_z), u_z = 5.62 / |(40.45, 25, 5.62)|."""
    r = solve_tensions(PAPER, (0.0, 0.0, 2.0), 5.0, 5.0, 500.0)
    uz = 5.62 / math.sqrt(40.45**2 + 25.0**2 + 5.62**2)
    expect = 5.0 * G_MPS2 / (4.0 * uz)
    assert r.tensions_n == pytest.approx([expect] * 4, rel=1e-12)
    assert r.feasible and r.method == "closed-form"
    assert r.margin_n == pytest.approx(expect - 5.0, rel=1e-12)
    assert r.limiting_bound == "min"


def test_paper_top_of_workspace_exceeds_500_n() -> None:
    """1 m below the anchors at the centre 5 kg needs 583 N per cable: infeasible for
    t_max 500 N, and the reason says so."""
    r = solve_tensions(PAPER, (0.0, 0.0, 6.62), 5.0, 5.0, 500.0)
    assert not r.feasible
    assert r.tensions_n[0] == pytest.approx(583.04, abs=0.01)
    assert r.margin_n == pytest.approx(500.0 - 583.037, abs=0.01)
    assert r.limiting_bound == "max"
    reason = r.reason()
    assert reason is not None and "above t_max 500 N" in reason


def test_desk_corner_slack_side_cable_limits() -> None:
    """Near a corner of the desk rig the far cables carry little: a 0.5 kg effector with
    t_min 1 N cannot keep them taut, and the limiting cable is one of the far ones."""
    r = solve_tensions(DESK, (-0.45, -0.45, 0.05), 0.5, 1.0, 30.0)
    check_result(r, DESK, np.array([-0.45, -0.45, 0.05]), 0.5)
    assert r.limiting_cable != 0  # cable 1 is the anchor above the corner: it carries most
    assert r.tensions_n[0] == max(r.tensions_n)


def test_three_cables_unique_solution() -> None:
    """A symmetric tripod: each cable carries m g / (3 u_z); general poses match
    numpy.linalg.solve, and the tension is proportional to the mass."""
    h, rad = 5.0, 4.0
    anchors = np.array([(rad * math.cos(a), rad * math.sin(a), h) for a in (0.0, 2.0944, 4.18879)])
    r = solve_tensions(anchors, (0.0, 0.0, 2.0), 3.0, 0.0, 1000.0)
    uz = 3.0 / math.hypot(rad, 3.0)
    assert r.tensions_n == pytest.approx([3.0 * G_MPS2 / (3.0 * uz)] * 3, rel=1e-4)
    assert r.method == "unique"
    rng = np.random.default_rng(3)
    for _ in range(200):
        p = np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(-3, 4)])
        w = 7.0 * G_MPS2
        expect = np.linalg.solve(units(anchors, p), [0.0, 0.0, w])
        r = solve_tensions(anchors, p, 7.0, 1.0, 100.0)
        assert np.allclose(r.tensions_n, expect, rtol=1e-10, atol=1e-9 * w)
        check_result(r, anchors, p, 7.0)
        r2 = solve_tensions(anchors, p, 14.0, 1.0, 100.0)
        assert np.allclose(np.array(r2.tensions_n), 2.0 * np.array(r.tensions_n), rtol=1e-12)


def test_three_cables_outside_footprint_needs_pushing() -> None:
    """Outside the anchors' triangle one cable would have to push: infeasible at t_min 0 and
    the limiting cable is the negative one, at its lower limit."""
    anchors = np.array([(0.0, 0.0, 5.0), (4.0, 0.0, 5.0), (0.0, 4.0, 5.0)])
    r = solve_tensions(anchors, (5.0, 5.0, 1.0), 1.0, 0.0, 100.0)
    assert not r.feasible
    assert r.tensions_n[r.limiting_cable] < 0.0
    assert r.limiting_bound == "min"
    assert r.limiting_cable == 0  # the anchor opposite the point


# -- N = 4 closed form against an LP ---------------------------------------------------------


def _random_layout4(rng: np.random.Generator) -> NDArray[np.float64]:
    while True:
        a = np.c_[rng.uniform(-30, 30, (4, 2)), rng.uniform(5.0, 15.0, 4)]
        plan = a[:, :2]
        if min(math.dist(p, q) for p, q in itertools.combinations(plan, 2)) > 5.0:
            return a


@pytest.mark.slow
def test_four_cables_closed_form_matches_linprog() -> None:
    """On 3000 points (paper robot, desk rig with its own limits, random tilted layouts; in
    and outside the footprints, feasible and not) the closed form's margin is the LP optimum
    within 1e-6 relative, and its feasibility agrees wherever the margin is not ~0."""
    rng = np.random.default_rng(20240601)
    cases: list[tuple[NDArray[np.float64], float, float, float, NDArray[np.float64]]] = []
    lo_p, hi_p = PAPER_BOX[0], PAPER_BOX[1]
    cases.append(
        (
            PAPER,
            5.0,
            5.0,
            500.0,
            np.c_[
                rng.uniform(lo_p[0] - 10, lo_p[1] + 10, 1000),
                rng.uniform(hi_p[0] - 10, hi_p[1] + 10, 1000),
                rng.uniform(0.0, 6.62, 1000),
            ],
        )
    )
    cases.append(
        (
            DESK,
            0.5,
            0.5,
            20.0,
            np.c_[
                rng.uniform(-0.6, 0.6, 1000),
                rng.uniform(-0.6, 0.6, 1000),
                rng.uniform(0, 0.7, 1000),
            ],
        )
    )
    for _ in range(10):
        a = _random_layout4(rng)
        pts = np.c_[
            rng.uniform(-30, 30, 100),
            rng.uniform(-30, 30, 100),
            rng.uniform(0, a[:, 2].min() - 1, 100),
        ]
        cases.append((a, float(rng.uniform(1, 20)), float(rng.uniform(0, 10)), 800.0, pts))
    checked = 0
    n_feasible = 0
    for anchors, mass, lo, hi, pts in cases:
        statics = CableStatics(anchors, lo, hi)
        w = mass * G_MPS2
        for p in pts:
            r = statics.solve(p, mass)
            ref, _ = lp_margin(anchors, p, w, lo, hi)
            tol = 1e-6 * max(abs(ref), w, hi - lo)
            assert abs(r.margin_n - ref) <= tol, (anchors, p, r, ref)
            if abs(ref) > tol:
                assert r.feasible == (ref > 0.0)
            n_feasible += r.feasible
            checked += 1
    assert checked == 3000
    assert 500 < n_feasible < 2900  # both kinds were exercised


# Anchor 3 (0-based 2) is low: the plane of anchors 0, 1, 2 (z = 5 - y) crosses the workspace.
# On it cable 3 carries a fixed tension (its null-vector component is zero).
LOW_ANCHOR = np.array([(-5.0, -5.0, 10.0), (5.0, -5.0, 10.0), (0.0, 5.0, 0.0), (0.0, 5.0, 12.0)])


@pytest.mark.parametrize("dz", [0.0, 1e-15, -1e-15, 1e-14, -1e-14, 1e-13, -1e-13, 1e-8, -1e-8])
@pytest.mark.parametrize(("dlo", "hi"), [(-1.0, 1000.0), (-1.0, 100.0), (0.5, 1000.0)])
def test_four_cables_flat_cable_binds(dz: float, dlo: float, hi: float) -> None:
    """On (or within rounding of) the plane of three anchors the fourth cable's tension does
    not depend on lambda; when it binds, the optimum is an interval of lambda.  The margin
    still matches the LP (a nearly flat line must not turn rounding into a wrong lambda), the
    batch agrees, and on the plane lambda is the middle of the interval: every other cable is
    well away from its limits, not tied with the binding one."""
    p = np.array([0.0, 0.0, 5.0 + dz])
    t3 = solve_tensions(LOW_ANCHOR, p, 2.0, 0.0, 1000.0).tensions_n[3]
    assert t3 == pytest.approx(2.0 * G_MPS2 / math.sqrt(2.0) / (12.0 / math.sqrt(74.0 * 2.0)))
    lo = t3 + dlo
    r = solve_tensions(LOW_ANCHOR, p, 2.0, lo, hi)
    check_result(r, LOW_ANCHOR, p, 2.0)
    ref, _ = lp_margin(LOW_ANCHOR, p, 2.0 * G_MPS2, lo, hi)
    assert abs(r.margin_n - ref) <= 1e-9 * hi
    _, margin, _, _ = tensions_batch(LOW_ANCHOR, p[None, :], 2.0, lo, hi)
    assert abs(margin[0] - ref) <= 1e-9 * hi
    if dz == 0.0:
        assert r.limiting_cable == 3 and r.margin_n == pytest.approx(-dlo, abs=1e-9)
        t = np.array(r.tensions_n)
        others = np.sort(np.minimum(t - lo, hi - t))[1:]
        assert others[0] > r.margin_n + 10.0


@FAST
@given(box_points(PAPER_BOX), st.floats(0.5, 30.0), limits)
def test_four_cables_no_better_lambda(
    p: NDArray[np.float64], mass: float, lim: tuple[float, float]
) -> None:
    """Moving along the null vector either way never increases the margin (it is a maximum)."""
    lo, hi = lim
    r = solve_tensions(PAPER, p, mass, lo, hi)
    t = np.array(r.tensions_n)
    n = np.linalg.svd(units(PAPER, p))[2][-1]
    for step in (1e-3, 1e-1, 10.0):
        for sgn in (1.0, -1.0):
            assert distance_to_limits(t + sgn * step * n, lo, hi) <= r.margin_n + 1e-9 * hi


# -- N > 4 -----------------------------------------------------------------------------------


def hexagon(radius_m: float, height_m: float) -> NDArray[np.float64]:
    return np.array(
        [
            (radius_m * math.cos(k * math.pi / 3), radius_m * math.sin(k * math.pi / 3), height_m)
            for k in range(6)
        ]
    )


@pytest.mark.parametrize(
    "anchors",
    [hexagon(10.0, 6.0), np.vstack([hexagon(10.0, 6.0)[:4], [(-3.0, -9.0, 7.0)]])],
    ids=["hexagon", "five-tilted"],
)
def test_more_than_four_cables_by_lp(anchors: NDArray[np.float64]) -> None:
    """Five and six anchors: the LP answer balances the weight, respects the limits, matches
    the reference LP's margin, and no random equilibrium in the (N-3)-dimensional null space
    beats it."""
    statics = CableStatics(anchors, 5.0, 300.0)
    rng = np.random.default_rng(7)
    n = len(anchors)
    for _ in range(40):
        p = np.array([rng.uniform(-7, 7), rng.uniform(-7, 7), rng.uniform(0, 5)])
        r = statics.solve(p, 10.0)
        assert r.method == "lp"
        check_result(r, anchors, p, 10.0)
        ref, _ = lp_margin(anchors, p, 10.0 * G_MPS2, 5.0, 300.0)
        assert abs(r.margin_n - ref) <= 1e-6 * 300.0
        null = np.linalg.svd(units(anchors, p))[2][3:]  # (N - 3, N) basis of the null space
        t = np.array(r.tensions_n)
        for c in rng.normal(size=(200, n - 3)):
            other = t + (c * rng.uniform(0.0, 20.0)) @ null
            assert distance_to_limits(other, 5.0, 300.0) <= r.margin_n + 1e-6 * 300.0


def test_six_cables_centre_shares_equally() -> None:
    """At the centre of a level hexagon the load is shared equally; the margin is to t_min."""
    r = solve_tensions(hexagon(10.0, 6.0), (0.0, 0.0, 2.0), 10.0, 5.0, 300.0)
    uz = 4.0 / math.hypot(10.0, 4.0)
    expect = 10.0 * G_MPS2 / (6.0 * uz)
    assert r.tensions_n == pytest.approx([expect] * 6, rel=1e-6)
    assert r.margin_n == pytest.approx(expect - 5.0, rel=1e-6)


def test_more_than_four_cables_without_scipy(monkeypatch: pytest.MonkeyPatch) -> None:
    """Without scipy, N > 4 gives the same answers (single and batch): the pair solve needs
    none; only a degenerate tie it cannot settle needs the linear program, and then says so."""
    statics = CableStatics(hexagon(10.0, 6.0), 5.0, 300.0)
    pts = np.array([[0.0, 0.0, 2.0], [3.0, -2.0, 1.0], [-6.0, 4.0, 4.5]])
    with_scipy = [statics.solve(q, 10.0).tensions_n for q in pts]
    batch_with = statics.solve_batch(pts, 10.0)[0]
    monkeypatch.setitem(sys.modules, "scipy.optimize", None)  # import now raises ImportError
    fresh = CableStatics(hexagon(10.0, 6.0), 5.0, 300.0)
    assert [fresh.solve(q, 10.0).tensions_n for q in pts] == with_scipy
    assert np.array_equal(fresh.solve_batch(pts, 10.0)[0], batch_with)
    assert solve_tensions(PAPER, (0.0, 0.0, 2.0), 5.0, 5.0, 500.0).feasible
    # a tie the pairs cannot settle (none of them optimal): the fallback names scipy
    monkeypatch.setattr("controller.core.statics.pivot_solve", lambda *a: None)
    monkeypatch.setattr("controller.core.statics.pair_solution", lambda *a: None)
    with pytest.raises(SolverUnavailable, match="scipy"):
        CableStatics(hexagon(10.0, 6.0), 5.0, 300.0).solve((1.0, 2.0, 3.0), 10.0)


# -- properties (hypothesis) -----------------------------------------------------------------


@FAST
@given(box_points(PAPER_BOX), masses, limits)
def test_props_paper(p: NDArray[np.float64], mass: float, lim: tuple[float, float]) -> None:
    check_result(solve_tensions(PAPER, p, mass, *lim), PAPER, p, mass)


@FAST
@given(box_points(DESK_BOX), st.floats(0.01, 2.0), st.tuples(st.floats(0, 1), st.floats(2, 50)))
def test_props_desk(p: NDArray[np.float64], mass: float, lim: tuple[float, float]) -> None:
    check_result(solve_tensions(DESK, p, mass, *lim), DESK, p, mass)


@settings(max_examples=150, deadline=None, derandomize=True)
@given(layout_and_point(), masses, limits)
def test_props_random_layouts(
    lp: tuple[NDArray[np.float64], NDArray[np.float64]], mass: float, lim: tuple[float, float]
) -> None:
    anchors, p = lp
    check_result(solve_or_skip(anchors, p, mass, *lim), anchors, p, mass)


@settings(max_examples=150, deadline=None, derandomize=True)
@given(layout_and_point(3, 5), masses, limits, st.floats(0.1, 10.0))
def test_props_scaling(
    lp: tuple[NDArray[np.float64], NDArray[np.float64]],
    mass: float,
    lim: tuple[float, float],
    k: float,
) -> None:
    """Scaling the mass and both limits by k scales the tensions and the margin by k; for
    three cables the tensions scale with the mass whatever the limits."""
    anchors, p = lp
    lo, hi = lim
    r = solve_or_skip(anchors, p, mass, lo, hi)
    rk = solve_tensions(anchors, p, k * mass, k * lo, k * hi)
    tol = 1e-6 * k * max(hi, mass * G_MPS2, float(np.max(np.abs(r.tensions_n))))
    assert abs(rk.margin_n - k * r.margin_n) <= tol
    if len(anchors) <= 4:  # unique optimum: the tensions themselves scale
        assert np.max(np.abs(np.array(rk.tensions_n) - k * np.array(r.tensions_n))) <= tol
    if len(anchors) == 3:
        r3 = solve_tensions(anchors, p, k * mass, lo, hi)
        assert np.allclose(r3.tensions_n, k * np.array(r.tensions_n), rtol=1e-12, atol=0.0)


# -- singular configurations and bad input ---------------------------------------------------


def test_singular_configurations_are_named() -> None:
    s4 = CableStatics(PAPER, 5.0, 500.0)
    with pytest.raises(SingularConfiguration, match="at anchor 3"):
        s4.solve((40.45, 25.0, 7.62), 5.0)
    with pytest.raises(SingularConfiguration, match="no cable pulls upward"):
        s4.solve((0.0, 0.0, 7.62), 5.0)  # in the plane of the level anchors
    with pytest.raises(SingularConfiguration, match="no cable pulls upward"):
        s4.solve((3.0, -2.0, 9.0), 5.0)  # above every anchor
    # Four anchors on one line: the directions span a plane only.
    line4 = [(x, 0.0, 5.0) for x in (-3.0, -1.0, 1.0, 3.0)]
    with pytest.raises(SingularConfiguration, match="do not span space"):
        solve_tensions(line4, (0.0, 2.0, 1.0), 1.0, 0.0, 100.0)
    # Three anchors on one line (the point below it is in their plane), coincident anchors.
    line3 = [(x, 0.0, 5.0) for x in (-3.0, 0.0, 3.0)]
    with pytest.raises(SingularConfiguration, match="coplanar"):
        solve_tensions(line3, (0.0, 2.0, 1.0), 1.0, 0.0, 100.0)
    twin = [(0.0, 0.0, 5.0), (0.0, 0.0, 5.0), (3.0, 0.0, 5.0)]
    with pytest.raises(SingularConfiguration, match="coplanar"):
        solve_tensions(twin, (1.0, 1.0, 1.0), 1.0, 0.0, 100.0)
    # Six anchors on one line: the LP path refuses too (before calling the solver).
    line6 = [(x, 0.0, 5.0) for x in range(6)]
    with pytest.raises(SingularConfiguration, match="do not span space"):
        solve_tensions(line6, (2.0, 3.0, 1.0), 1.0, 0.0, 100.0)
    assert issubclass(SingularConfiguration, StaticsError)


def test_tilted_anchors_below_some_is_not_singular() -> None:
    """With anchors at different heights a point above one of them is still a regular
    (maybe infeasible) pose: that cable pulls down."""
    anchors = np.array([(-5.0, -5.0, 2.0), (-5.0, 5.0, 8.0), (5.0, 5.0, 8.0), (5.0, -5.0, 8.0)])
    r = solve_tensions(anchors, (0.0, 0.0, 3.0), 2.0, 0.0, 500.0)
    check_result(r, anchors, np.array([0.0, 0.0, 3.0]), 2.0)


@pytest.mark.parametrize(
    ("anchors", "point", "mass", "lo", "hi", "match"),
    [
        (PAPER, (0.0, math.nan, 1.0), 5.0, 5.0, 500.0, "not finite"),
        (PAPER, (0.0, math.inf, 1.0), 5.0, 5.0, 500.0, "not finite"),
        (PAPER, (0.0, 1.0), 5.0, 5.0, 500.0, "3 coordinates"),
        (PAPER, (0.0, 0.0, 1.0), 0.0, 5.0, 500.0, "mass_kg"),
        (PAPER, (0.0, 0.0, 1.0), math.nan, 5.0, 500.0, "mass_kg"),
        (PAPER, (0.0, 0.0, 1.0), 5.0, 500.0, 5.0, "t_min_n < t_max_n"),
        (PAPER, (0.0, 0.0, 1.0), 5.0, -1.0, 5.0, "0 <= t_min_n"),
        (PAPER, (0.0, 0.0, 1.0), 5.0, 5.0, math.inf, "finite"),
        (PAPER[:2], (0.0, 0.0, 1.0), 5.0, 5.0, 500.0, "N >= 3"),
        (PAPER[:, :2], (0.0, 0.0, 1.0), 5.0, 5.0, 500.0, r"\(N, 3\)"),
        ([(0, 0, 1), (1, 0, math.nan), (0, 1, 1)], (0.0, 0.0, 0.0), 5.0, 5.0, 500.0, "non-finite"),
        ("abc", (0.0, 0.0, 1.0), 5.0, 5.0, 500.0, "anchors_m"),
    ],
)
def test_bad_input_is_named(
    anchors: Any, point: Any, mass: float, lo: float, hi: float, match: str
) -> None:
    with pytest.raises(StaticsInputError, match=match):
        solve_tensions(anchors, point, mass, lo, hi)


# -- batch -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("anchors", "box", "mass", "lo", "hi"),
    [
        (PAPER, PAPER_BOX, 5.0, 5.0, 500.0),
        (DESK, DESK_BOX, 0.5, 0.5, 20.0),
        (PAPER[:3], PAPER_BOX, 5.0, 0.0, 500.0),
        (
            np.array([(-5.0, -5.0, 9.0), (-4.0, 6.0, 7.0), (5.0, 5.0, 8.0), (6.0, -5.0, 10.0)]),
            ((-6.0, 6.0), (-6.0, 6.0), (0.0, 6.0)),
            3.0,
            2.0,
            300.0,
        ),
        (hexagon(10.0, 6.0), ((-8.0, 8.0), (-8.0, 8.0), (0.0, 5.5)), 10.0, 5.0, 300.0),
    ],
)
def test_batch_matches_single(
    anchors: NDArray[np.float64],
    box: tuple[tuple[float, float], ...],
    mass: float,
    lo: float,
    hi: float,
) -> None:
    rng = np.random.default_rng(5)
    m = 60 if len(anchors) > 4 else 3000
    pts = np.c_[tuple(rng.uniform(a, b, m) for a, b in box)]
    tens, margin, feasible, limiting = tensions_batch(anchors, pts, mass, lo, hi)
    assert tens.shape == (m, len(anchors)) and margin.shape == feasible.shape == (m,)
    assert limiting.dtype == np.int64 and feasible.dtype == np.bool_
    statics = CableStatics(anchors, lo, hi)
    for k in range(m):
        r = statics.solve(pts[k], mass)
        scale = max(mass * G_MPS2, float(np.max(np.abs(r.tensions_n))))
        assert np.max(np.abs(tens[k] - r.tensions_n)) <= 1e-9 * scale
        assert abs(margin[k] - r.margin_n) <= 1e-9 * scale
        if abs(r.margin_n) > 1e-9 * scale:
            assert feasible[k] == r.feasible
        # the limiting cable is at the margin (at the optimum several cables usually are, and
        # the two paths may name different ones)
        tl = tens[k, limiting[k]]
        assert min(tl - lo, hi - tl) == margin[k]


def test_batch_garbage_rows_never_nan() -> None:
    """Non-finite, huge, at-anchor, in-plane and above-anchor rows get the documented
    sentinel; good rows in between are unaffected; nothing is NaN or inf."""
    good = [(0.0, 0.0, 2.0), (30.0, 20.0, 1.0)]
    bad = [
        (math.nan, 0.0, 1.0),
        (0.0, math.inf, 1.0),
        (-math.inf, math.nan, math.inf),
        (1e300, 1e300, -1e300),
        (1e308, 0.0, 0.0),
        tuple(PAPER[2]),
        (0.0, 0.0, 7.62),
        (0.0, 0.0, 50.0),
    ]
    pts = np.array([good[0], *bad, good[1]])
    for anchors in (PAPER, PAPER[:3], np.vstack([PAPER, [(0.0, 30.0, 7.62)]])):
        tens, margin, feasible, limiting = tensions_batch(anchors, pts, 5.0, 5.0, 500.0)
        assert np.isfinite(tens).all() and np.isfinite(margin).all()
        rows = slice(1, 1 + len(bad))
        assert (limiting[rows] == SINGULAR_ROW).all()
        assert (margin[rows] == SINGULAR_MARGIN_N).all()
        assert not feasible[rows].any()
        assert (tens[rows] == 0.0).all()
        for k, p in ((0, good[0]), (len(pts) - 1, good[1])):
            r = solve_tensions(anchors, p, 5.0, 5.0, 500.0)
            assert margin[k] == pytest.approx(r.margin_n, rel=1e-9)


def test_batch_near_plane_is_finite() -> None:
    """A nanometre below the level anchors: finite (huge or singular-flagged), never NaN."""
    zs = 7.62 - np.logspace(-12, -1, 50)
    pts = np.c_[np.full(50, 3.0), np.full(50, -2.0), zs]
    tens, margin, feasible, limiting = tensions_batch(PAPER, pts, 5.0, 5.0, 500.0)
    assert np.isfinite(tens).all() and np.isfinite(margin).all()
    assert not feasible.any()
    for k in np.nonzero(limiting != SINGULAR_ROW)[0]:
        r = solve_tensions(PAPER, pts[k], 5.0, 5.0, 500.0)
        assert margin[k] == pytest.approx(r.margin_n, rel=1e-6)


def test_batch_bad_shapes() -> None:
    with pytest.raises(StaticsInputError, match=r"\(M, 3\)"):
        tensions_batch(PAPER, np.zeros((4, 2)), 5.0, 5.0, 500.0)
    with pytest.raises(StaticsInputError, match="mass_kg"):
        tensions_batch(PAPER, np.zeros((4, 3)), -1.0, 5.0, 500.0)
    tens, margin, feasible, limiting = tensions_batch(PAPER, np.zeros((0, 3)), 5.0, 5.0, 500.0)
    assert tens.shape == (0, 4) and margin.shape == feasible.shape == limiting.shape == (0,)


# -- workspace -------------------------------------------------------------------------------


def test_workspace_whole_box_when_limits_are_loose() -> None:
    """t_min 0 and a huge t_max: every point strictly inside the level anchors' rectangle and
    below them is feasible, so the volume is the box and the uncertainty zero."""
    ws = feasible_workspace(DESK, *DESK_BOX, 0.05, 0.5, 0.0, 1e9)
    assert ws.n_feasible == ws.feasible.size
    assert ws.volume_m3 == pytest.approx(0.9 * 0.9 * 0.69, rel=1e-12)
    assert ws.box_volume_m3 == pytest.approx(ws.volume_m3, rel=1e-12)
    assert ws.uncertainty_m3 == 0.0 and ws.n_boundary == 0


def test_workspace_half_outside_footprint() -> None:
    """A box twice as wide as the rectangle in x: outside it a cable would have to push, so
    the feasible volume is half the box, within the stated accuracy."""
    ws = feasible_workspace(DESK, (-1.0, 1.0), (-0.45, 0.45), (0.01, 0.7), 0.03, 0.5, 0.0, 1e9)
    exact = 1.0 * 0.9 * 0.69
    assert abs(ws.volume_m3 - exact) <= ws.uncertainty_m3
    # the two walls x = +/-0.5 m, a cell on each side of each
    assert ws.n_boundary == 2 * 2 * ws.ys_m.size * ws.zs_m.size
    assert ws.uncertainty_m3 == ws.n_boundary * ws.cell_volume_m3
    assert ws.feasible.shape == (ws.xs_m.size, ws.ys_m.size, ws.zs_m.size)
    # the cells tile the box exactly
    assert ws.cell_m[0] * ws.xs_m.size == pytest.approx(2.0)
    assert np.isfinite(ws.margin_n).all()


def test_workspace_refinement_within_stated_accuracy() -> None:
    """Halving the step changes the paper robot's 5 kg / 5..500 N volume by less than the
    coarse grid's stated uncertainty, and the finer uncertainty is smaller."""
    coarse = feasible_workspace(PAPER, *PAPER_BOX, 1.0, 5.0, 5.0, 500.0)
    fine = feasible_workspace(PAPER, *PAPER_BOX, 0.5, 5.0, 5.0, 500.0)
    assert 0 < coarse.n_feasible < coarse.feasible.size
    # a grid whose centres are all feasible still states the surface it cannot resolve
    tall = feasible_workspace(PAPER, *PAPER_BOX, 2.0, 5.0, 5.0, 500.0)
    assert tall.n_feasible == tall.feasible.size
    assert abs(fine.volume_m3 - tall.volume_m3) <= tall.uncertainty_m3
    assert abs(fine.volume_m3 - coarse.volume_m3) <= coarse.uncertainty_m3
    assert fine.uncertainty_m3 < coarse.uncertainty_m3
    # 22430.6 m^3: columns of 0.5 m x 0.5 m sampled every 0.01 m in z (and 0.25 m x 0.02 m)
    assert abs(fine.volume_m3 - 22430.6) <= fine.uncertainty_m3
    assert abs(coarse.volume_m3 - 22430.6) <= coarse.uncertainty_m3
    # the infeasible part is at the top (cables too flat for t_max)
    top = fine.feasible[:, :, -1].mean()
    bottom = fine.feasible[:, :, 0].mean()
    assert top < bottom


def test_workspace_bad_input() -> None:
    with pytest.raises(StaticsInputError, match="step_m"):
        feasible_workspace(DESK, *DESK_BOX, 0.0, 0.5, 0.0, 10.0)
    with pytest.raises(StaticsInputError, match="x_range_m"):
        feasible_workspace(DESK, (1.0, -1.0), (0, 1), (0, 1), 0.1, 0.5, 0.0, 10.0)
    with pytest.raises(StaticsInputError, match="too many"):
        feasible_workspace(DESK, *DESK_BOX, 1e-7, 0.5, 0.0, 10.0)


# -- the tension rule and the workspace inside a region ----------------------------------------


def test_tension_check_applies_the_margin_and_names_the_cable() -> None:
    from controller.core.statics import TensionCheck

    check = TensionCheck(PAPER, 5.0, 5.0, 500.0, 5.0, "limits.max_tension_n")
    assert check.check((0.0, 0.0, 2.0)) is None  # 104.4 N each
    res = check.solve((0.0, 0.0, 6.6))  # 571.6 N each
    assert check.reason(res) == (
        f"cable {res.limiting_cable + 1} tension 571.6 N above 495 N (limits.max_tension_n "
        "500 N - tension_margin_n 5 N) holding 5 kg"
    )
    # 0.35 kg: 7.3 N each, inside 5..500 but not 5 N inside
    light = TensionCheck(PAPER, 0.35, 5.0, 500.0, 5.0)
    res = light.solve((0.0, 0.0, 2.0))
    assert res.feasible and res.margin_n < 5.0
    assert (light.check((0.0, 0.0, 2.0)) or "").endswith(
        "below 10 N (min_tension_n 5 N + tension_margin_n 5 N) holding 0.35 kg"
    )
    assert TensionCheck(PAPER, 0.35, 5.0, 500.0, 2.0).check((0.0, 0.0, 2.0)) is None
    assert "no cable pulls upward" in (check.check((0.0, 0.0, 9.0)) or "")
    assert "not finite" in (check.check((math.nan, 0.0, 1.0)) or "")
    with pytest.raises(StaticsInputError, match="margin_n"):
        TensionCheck(PAPER, 5.0, 5.0, 500.0, -1.0)
    with pytest.raises(StaticsInputError, match="leaves no range"):
        TensionCheck(PAPER, 5.0, 5.0, 500.0, 250.0)
    with pytest.raises(StaticsInputError, match="mass_kg"):
        TensionCheck(PAPER, 0.0, 5.0, 500.0)


def test_feasible_workspace_inside_a_region() -> None:
    # the region: a cylinder of radius 0.3 m about the z axis, inside the desk box
    def cylinder(pts: NDArray[np.float64]) -> NDArray[np.bool_]:
        return np.asarray(pts[:, 0] ** 2 + pts[:, 1] ** 2 <= 0.09, dtype=np.bool_)

    whole = feasible_workspace(DESK, *DESK_BOX, 0.03, 0.5, 0.0, 1e9)
    ws = feasible_workspace(DESK, *DESK_BOX, 0.03, 0.5, 0.0, 1e9, inside=cylinder)
    assert whole.region_volume_m3 == whole.box_volume_m3
    # nothing limits the tensions here: the volume is the cylinder's, within the bound
    exact = math.pi * 0.09 * (0.7 - 0.01)
    assert abs(ws.region_volume_m3 - exact) <= ws.uncertainty_m3
    assert ws.volume_m3 == ws.region_volume_m3
    # the bound counts the cells on both sides of the surface: 2 x area x step
    assert abs(ws.volume_m3 - exact) <= ws.uncertainty_m3 <= 2.2 * 1.3 * 0.03
    assert ws.n_feasible == ws.n_region < whole.n_feasible


# -- the tensions' derivative with respect to the pose ---------------------------------------


def central_derivative(
    s: CableStatics, p: NDArray[np.float64], mass: float, h: float = 1e-6
) -> tuple[NDArray[np.float64], float]:
    """(d t / d P by central differences, the largest gap between the forward and backward
    differences: large where the binding pair changes within h, a kink)."""
    t0 = np.array(s.solve(p, mass).tensions_n)
    cols = []
    gap = 0.0
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        tp = np.array(s.solve(p + e, mass).tensions_n)
        tm = np.array(s.solve(p - e, mass).tensions_n)
        cols.append((tp - tm) / (2 * h))
        gap = max(gap, float(np.max(np.abs((tp - t0) - (t0 - tm)))) / h)
    return np.array(cols).T, gap


@FAST
@given(layout_and_point(3, 4), masses, limits)
def test_tension_derivative_is_the_statics_derivative(
    lp: tuple[NDArray[np.float64], NDArray[np.float64]],
    mass: float,
    lim: tuple[float, float],
) -> None:
    anchors, p = lp
    s = CableStatics(anchors, *lim)
    try:
        t = s.solve(p, mass).tensions_n
        fd, gap = central_derivative(s, p, mass)
    except SingularConfiguration:
        assume(False)
        raise
    scale = max(1.0, float(np.max(np.abs(fd))))
    assume(gap < 1e-3 * scale)  # not at a kink of the distribution
    # where the cables hold the payload (the loop plans no other set-point): below the least
    # tension the solve's best effort ties cables that part at once, a kink at the point.
    # Within a millinewton of the least tension the distribution is not the max-min one the
    # derivative follows (three cables at about 0.2 mN under a fourth, Hypothesis found): the
    # derivative is off there by up to 2e-4 of its scale, which the FPK's Newton steps absorb.
    assume(min(t) >= lim[0] + 1e-3)
    d = s.tension_derivative(p, t)
    assume(d is not None)  # a degenerate tie (checked below to be rare)
    assert d is not None
    assert np.max(np.abs(np.array(d) - fd)) < 1e-4 * scale
    both = s.solve_with_derivative(p, mass)
    assert both[0] == t and both[1] == d


@FAST
@given(layout_and_point(3, 4), masses, limits)
def test_solve_gives_the_derivative_when_asked(
    lp: tuple[NDArray[np.float64], NDArray[np.float64]],
    mass: float,
    lim: tuple[float, float],
) -> None:
    """`solve(..., derivative=True)` (the loop's plan for the stretch FPK) is the solve and
    `tension_derivative` in one call, and gives no derivative unless asked."""
    anchors, p = lp
    s = CableStatics(anchors, *lim)
    try:
        plain = s.solve(p, mass)
        asked = s.solve(p, mass, derivative=True)
    except SingularConfiguration:
        assume(False)
        raise
    assert plain.derivative is None
    assert asked.tensions_n == plain.tensions_n and asked.margin_n == plain.margin_n
    assert asked.derivative == s.tension_derivative(p, plain.tensions_n)


def test_tension_derivative_on_the_paper_robot() -> None:
    """Close under the anchors the tensions change fast: the analytic derivative there."""
    s = CableStatics(PAPER, 5.0, 2000.0)
    for p in ([0.0, 0.0, 6.0], [20.0, 10.0, 2.0], [-30.0, -18.0, 1.0], [35.0, 20.0, 3.0]):
        pt = np.array(p)
        d = s.tension_derivative(pt, s.solve(pt, 5.0).tensions_n)
        fd, gap = central_derivative(s, pt, 5.0)
        assert gap < 1e-3 * float(np.max(np.abs(fd)))
        assert d is not None
        assert np.max(np.abs(np.array(d) - fd)) < 1e-5 * float(np.max(np.abs(fd)))
    # a random path through the workspace: a derivative nearly everywhere
    rng = np.random.default_rng(7)
    pts = rng.uniform([-38.0, -23.0, 0.0], [38.0, 23.0, 6.6], size=(300, 3))
    none = sum(s.tension_derivative(q, s.solve(q, 5.0).tensions_n) is None for q in pts)
    assert none == 0
    # at the centre, 6 m up: the four tensions rise with the height by hundreds of N/m
    d = s.tension_derivative([0.0, 0.0, 6.0], s.solve([0.0, 0.0, 6.0], 5.0).tensions_n)
    assert d is not None and all(row[2] > 100.0 for row in d)


def test_tension_derivative_errors() -> None:
    s = CableStatics(PAPER, 5.0, 2000.0)
    with pytest.raises(StaticsInputError):
        s.tension_derivative([0.0, 0.0, 2.0], [1.0, 2.0])
    with pytest.raises(StaticsInputError):
        s.tension_derivative([0.0, math.nan, 2.0], [1.0, 1.0, 1.0, 1.0])
    with pytest.raises(SingularConfiguration):
        s.tension_derivative(PAPER[0], [1.0, 1.0, 1.0, 1.0])
    with pytest.raises(SingularConfiguration):
        s.solve_with_derivative([0.0, 0.0, 9.0], 5.0)
    six = np.vstack([PAPER, [[0.0, 30.0, 7.62], [0.0, -30.0, 7.62]]])
    assert CableStatics(six, 5.0, 2000.0).tension_derivative([0.0, 0.0, 2.0], [1.0] * 6) is None
