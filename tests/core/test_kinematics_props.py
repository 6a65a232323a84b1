"""Property tests (hypothesis) of controller.core.kinematics over random anchor layouts."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from controller.core.kinematics import (
    Geometry,
    SingularGeometryError,
    UnreachableError,
    fpk,
    fpk_batch,
    ipk,
    ipk_point,
    three_spheres,
    three_spheres_equal_height,
)
from controller.core.workspace import footprint_contains

FAST = settings(max_examples=200, deadline=None, derandomize=True)

coord = st.floats(-60.0, 60.0, allow_nan=False, allow_infinity=False)


@st.composite
def layouts(draw: st.DrawFn, min_n: int = 3) -> Geometry:
    """A well-conditioned layout of 3..8 anchors, equal or unequal heights.

    Rejected: plan-view pairs closer than 2 m, and layouts whose best triple has a plan-view
    triangle smaller than 5 % of the squared span (near-collinear).  Heights differ by up to
    +/-5 m when unequal.
    """
    n = draw(st.integers(min_n, 8))
    equal = draw(st.booleans())
    h = draw(st.floats(2.0, 30.0))
    pts = []
    for _ in range(n):
        z = h if equal else h + draw(st.floats(-5.0, 5.0))
        pts.append((draw(coord), draw(coord), z))
    plan = [(p[0], p[1]) for p in pts]
    assume(all(math.dist(a, b) > 2.0 for a, b in itertools.combinations(plan, 2)))
    span2 = max(math.dist(a, b) ** 2 for a, b in itertools.combinations(plan, 2))
    best = max(
        abs((c[0] - a[0]) * (c[1] - b[1]) - (c[1] - a[1]) * (c[0] - b[0]))
        for a, b, c in itertools.combinations(plan, 3)
    )
    assume(best > 0.05 * span2)
    geom = Geometry(pts)
    assert geom.equal_heights or not equal
    return geom


@st.composite
def geom_and_point(
    draw: st.DrawFn, min_n: int = 3, min_depth_m: float = 0.01
) -> tuple[Geometry, tuple[float, float, float]]:
    """A layout and a point inside its plan-view footprint, at least min_depth_m below it."""
    geom = draw(layouts(min_n))
    a = geom.anchors_m
    w = np.array(draw(st.lists(st.floats(0.0, 1.0), min_size=len(a), max_size=len(a))))
    assume(w.sum() > 1e-3)
    x, y = (w / w.sum()) @ a[:, :2]
    z = geom.anchor_height_min_m - draw(st.floats(min_depth_m, 40.0))
    assert footprint_contains(geom.footprint_m, float(x), float(y))
    return geom, (float(x), float(y), float(z))


@FAST
@given(geom_and_point())
def test_fpk_inverts_ipk(gp: tuple[Geometry, tuple[float, float, float]]) -> None:
    geom, p = gp
    lengths = ipk(geom, p)
    res = fpk(geom, lengths)
    assert max(abs(u - v) for u, v in zip(res.position_m, p, strict=True)) < 1e-9
    assert res.residual_m < 1e-9
    assert ipk_point(geom, p) == pytest.approx(lengths.tolist(), abs=1e-12)
    batch = fpk_batch(geom, np.vstack([lengths, lengths]))
    assert batch.valid.all()
    assert np.max(np.abs(batch.position_m - np.array(p))) < 1e-9


@FAST
@given(geom_and_point())
def test_bare_three_spheres_invert(gp: tuple[Geometry, tuple[float, float, float]]) -> None:
    geom, p = gp
    i, j, k = geom.seed_triple
    a = [tuple(v) for v in geom.anchors_m[[i, j, k]].tolist()]
    # The bare function returns the solution below the plane of the three centres (the other
    # is its mirror image in that plane).  A point below every anchor can still lie above a
    # tilted triple's plane; that case is fpk's (tests/test_kinematics.py).
    n = np.cross(np.subtract(a[1], a[0]), np.subtract(a[2], a[0]))
    assume(
        float(np.dot(np.subtract(p, a[0]), n * np.sign(n[2]))) < -1e-6 * float(np.linalg.norm(n))
    )
    r = [math.dist(p, c) for c in a]
    q = three_spheres(a[0], a[1], a[2], *r)
    assert max(abs(u - v) for u, v in zip(q, p, strict=True)) < 1e-9
    if geom.seed_uses_simplified and a[0][2] == a[1][2] == a[2][2]:
        s = three_spheres_equal_height(a[0], a[1], a[2], *r)
        assert max(abs(u - v) for u, v in zip(s, p, strict=True)) < 1e-9


@FAST
@given(geom_and_point(min_n=4, min_depth_m=2.0), st.integers(0, 2**32 - 1))
def test_least_squares_beats_every_triple_on_average(
    gp: tuple[Geometry, tuple[float, float, float]], seed: int
) -> None:
    geom, p = gp
    truth = np.array(p)
    clean = ipk(geom, p)
    # Only layouts where the extra cables carry information worth measuring: the linearised
    # mean squared error of the fit, trace((J^T J)^-1), at most 0.8 of the best triple's.
    u = (truth - geom.anchors_m) / clean[:, None]
    ls_pred = float(np.trace(np.linalg.inv(u.T @ u)))
    tri_pred = min(float(np.trace(np.linalg.inv(u[list(t)].T @ u[list(t)]))) for t in geom.triples)
    assume(ls_pred < 0.8 * tri_pred)
    rng = np.random.default_rng(seed)
    noisy = clean + rng.normal(0.0, 1e-3, (300, geom.n_cables))
    fit = fpk_batch(geom, noisy)
    assert fit.valid.all()
    ls_mse = float(np.mean(np.sum((fit.position_m - truth) ** 2, axis=1)))
    assert ls_mse == pytest.approx(ls_pred * 1e-6, rel=0.5)
    for tri in geom.triples:
        # Each triple alone, as a 3-cable robot (vectorised; unreachable rows count as inf).
        alone = fpk_batch(Geometry(geom.anchors_m[list(tri)]), noisy[:, list(tri)])
        sq = np.sum((alone.position_m - truth) ** 2, axis=1)
        errs = np.where(alone.valid, sq, np.inf)
        assert ls_mse < float(np.mean(errs)), tri


@FAST
@given(geom_and_point(min_n=4, min_depth_m=0.5), st.integers(0, 7))
# Found by hypothesis: the residual was the cost before the last Gauss-Newton step (1.4e-7 m
# for consistent lengths), and a high-leverage cable leaves the linearisation at 1 cm.
@example(
    (
        Geometry([[-3.0, 8.0, 2.0], [-2.0, 1.0, 4.0], [-1.0, 6.0, 3.0], [0.0, 0.0, 2.0]]),
        (-1.0, 6.0, 1.0),
    ),
    0,
)
@example(
    (
        Geometry([[-3.0, 11.0, 2.0], [-1.0, 2.0, 5.0], [-1.0, 10.0, 2.0], [0.0, 0.0, 2.0]]),
        (-0.5, 5.0, 1.0),
    ),
    0,
)
def test_residual_zero_when_consistent_and_grows_with_one_bad_cable(
    gp: tuple[Geometry, tuple[float, float, float]], which: int
) -> None:
    geom, p = gp
    k = which % geom.n_cables
    lengths = ipk(geom, p)
    assert fpk(geom, lengths.tolist()).residual_m < 1e-10
    # The linearisation below needs cables much longer than the largest bump (1 cm).
    assume(float(lengths.min()) > 5.0)
    # Linearised prediction: one cable off by delta leaves an RMS residual of
    # delta * sqrt((1 - h_k) / N), h_k the leverage of cable k.
    u = (np.array(p) - geom.anchors_m) / lengths[:, None]
    h = float(u[k] @ np.linalg.solve(u.T @ u, u[k]))
    assume(1.0 - h > 1e-2)
    prev = 0.0
    for delta in (1e-4, 1e-3, 1e-2):
        bumped = lengths.copy()
        bumped[k] += delta
        fit = fpk(geom, bumped.tolist())
        r = fit.residual_m
        assert r > prev
        # Exact: the residual is the RMS mismatch at the returned point, and that point is the
        # least-squares minimum found by an independent solver.
        at_point = np.linalg.norm(np.array(fit.position_m) - geom.anchors_m, axis=1) - bumped
        assert r == pytest.approx(math.sqrt(float(np.mean(at_point**2))), abs=1e-12)
        assert r == pytest.approx(_reference_rms(geom, bumped, p), rel=1e-6, abs=1e-12)
        if delta <= 1e-3:
            # The linearised prediction holds for small bumps (at 1 cm, a cable of leverage
            # near 1 is already outside it: second-order terms grow like delta / (1 - h)).
            assert r == pytest.approx(delta * math.sqrt((1.0 - h) / geom.n_cables), rel=0.05)
        prev = r


def _reference_rms(geom: Geometry, lengths: np.ndarray, start: tuple[float, float, float]) -> float:
    """RMS residual at the least-squares minimum, by scipy (independent of our solver)."""
    from scipy.optimize import least_squares

    def res(q: np.ndarray) -> np.ndarray:
        out: np.ndarray = np.linalg.norm(q - geom.anchors_m, axis=1) - lengths
        return out

    sol = least_squares(res, np.array(start), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return math.sqrt(float(np.mean(sol.fun**2)))


@FAST
@given(layouts())
def test_geometry_keeps_only_nonsingular_triples(geom: Geometry) -> None:
    a = geom.anchors_m
    assert geom.seed_triple in geom.triples
    for t in itertools.combinations(range(geom.n_cables), 3):
        p = a[list(t), :2]
        (ux, uy), (vx, vy) = p[1] - p[0], p[2] - p[0]
        area2 = abs(ux * vy - uy * vx)
        if t not in geom.triples:
            span = max(math.dist(u, v) for u, v in itertools.combinations(a[:, :2].tolist(), 2))
            assert area2 <= 1e-6 * span**2 * (1 + 1e-9)


@FAST
@given(st.lists(coord, min_size=3, max_size=3), st.floats(1.0, 20.0))
def test_collinear_three_refused(xs: list[float], h: float) -> None:
    assume(max(xs) - min(xs) > 1.0)
    pts = [(x, 2.0 * x + 1.0, h + i) for i, x in enumerate(xs)]
    assume(min(math.dist(a, b) for a, b in itertools.combinations(pts, 2)) > 1e-3)
    with pytest.raises(SingularGeometryError):
        Geometry(pts)


@FAST
@given(geom_and_point(), st.floats(0.0, 5.0))
def test_footprint_margin(gp: tuple[Geometry, tuple[float, float, float]], margin: float) -> None:
    geom, (x, y, _) = gp
    inside = footprint_contains(geom.footprint_m, x, y, margin)
    # Brute force: distance from (x, y) to every hull edge of the plan-view points.
    from scipy.spatial import ConvexHull

    plan = geom.anchors_m[:, :2]
    hull = ConvexHull(plan)
    # hull.equations: n . p + c <= 0 inside, n unit outward.
    dist = -(hull.equations[:, :2] @ np.array([x, y]) + hull.equations[:, 2])
    assert inside == bool(np.all(dist >= margin - 1e-9)) or abs(dist.min() - margin) < 1e-9


@FAST
@given(geom_and_point(min_n=4, min_depth_m=0.05), st.integers(0, 2**32 - 1))
def test_batch_agrees_with_single_on_noisy_lengths(
    gp: tuple[Geometry, tuple[float, float, float]], seed: int
) -> None:
    geom, p = gp
    rng = np.random.default_rng(seed)
    noisy = ipk(geom, p) + rng.normal(0.0, 1e-3, (8, geom.n_cables))
    batch = fpk_batch(geom, noisy)
    for k in range(noisy.shape[0]):
        try:
            one = fpk(geom, noisy[k].tolist())
        except UnreachableError as exc:
            assert not batch.valid[k]
            assert batch.short_cable[k] == exc.cable
            assert batch.shortfall_m[k] == pytest.approx(exc.shortfall_m, rel=1e-6, abs=1e-9)
            continue
        assert batch.valid[k]
        assert batch.position_m[k] == pytest.approx(one.position_m, abs=1e-9)
        assert batch.residual_m[k] == pytest.approx(one.residual_m, rel=1e-6, abs=1e-12)
