"""The fit of an effector among its anchors (`controller.core.kinematics.fit`): the tick's
Gauss-Newton (J^T J taken once, its sums written out) against the general one (J^T J at every
point, ``_normal_eq``), and against scipy's least squares, from the last pose and from the
linearised trilateration, on random well-conditioned layouts of 4 to 8 anchors with noisy
lengths: the same point to a tenth of a micrometre; and the fit written out for the layout
(``fitgen``) against that loop: the same point to 1e-9 m, the cases it hands back to the loop
(a start on an anchor or far off) still solved.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from scipy.optimize import least_squares

from controller.core.kinematics import Geometry, SingularGeometryError, fpk
from controller.core.kinematics.fit import (
    RETRY_RMS_M,
    _gauss_newton,
    _gauss_newton_among,
)
from controller.core.kinematics.fitgen import AmongFit

FAST = settings(max_examples=200, deadline=None, derandomize=True)


CORNERS = [(x, y, z) for z in (-0.2, 2.2) for x in (-1.5, 1.5) for y in (-1.5, 1.5)]


@st.composite
def among(
    draw: st.DrawFn,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """4 to 8 anchors near the corners of a 3 m box (some low, some high, each moved up to
    0.4 m), a point inside where the cables pin it down well (J^T J's smallest eigenvalue at
    least 0.3), its lengths with up to 2 mm of noise, and a last pose up to 5 mm away."""
    n = draw(st.integers(4, 8))
    pick = draw(st.permutations(range(8)))[:n]
    assume(min(pick) < 4 <= max(pick))  # some low, some high
    move = st.floats(-0.4, 0.4)
    a = np.array([[c + draw(move) for c in CORNERS[k]] for k in pick])
    mid = st.floats(-0.5, 0.5)
    p = np.array([draw(mid), draw(mid), draw(st.floats(0.3, 1.7))])
    u = (a - p) / np.linalg.norm(a - p, axis=1)[:, None]
    assume(float(np.linalg.eigvalsh(u.T @ u)[0]) >= 0.3)
    noise = np.array([draw(st.floats(-0.002, 0.002)) for _ in range(n)])
    last = p + np.array([draw(st.floats(-0.005, 0.005)) for _ in range(3)])
    return a, p, noise, last


@FAST
@given(among())
def test_the_tick_fit_is_the_general_fit_and_scipys(
    case: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
) -> None:
    """From the last pose: the tick's fit, the general Gauss-Newton and scipy's least squares
    reach the same point (to 1e-7 m) and the same RMS residual."""
    anchors, p, noise, last = case
    try:
        geom = Geometry(anchors, hanging=False)
    except SingularGeometryError:
        assume(False)
        raise
    lengths = (np.linalg.norm(anchors - p, axis=1) + noise).tolist()
    pts = tuple((float(x), float(y), float(z)) for x, y, z in anchors.tolist())
    lx, ly, lz = (float(v) for v in last)
    fast = _gauss_newton_among(pts, lengths, lx, ly, lz)
    slow = _gauss_newton(pts, lengths, lx, ly, lz, None, 1e-20)
    ref = least_squares(
        lambda q: np.linalg.norm(anchors - q, axis=1) - lengths, last, xtol=1e-15, ftol=1e-15
    )
    assert math.dist(fast[:3], slow[:3]) <= 1e-7
    assert math.dist(fast[:3], ref.x.tolist()) <= 1e-7
    assert abs(fast[3] - slow[3]) <= 1e-9
    got = fpk(geom, lengths, last.tolist())
    assert math.dist(got.position_m, ref.x.tolist()) <= 1e-7


def _written_out(geom: Geometry) -> AmongFit:
    """The geometry's written-out fit (``fitgen``)."""
    fit = geom._among
    assert fit is not None
    return fit


def _linear_seed(geom: Geometry, lengths: list[float]) -> tuple[float, float, float]:
    """The linearised trilateration, as the loop's caller computes it."""
    lin = geom._lin
    assert lin is not None
    x, y, z = lin.p0
    for (wx, wy, wz), ln in zip(lin.w, lengths, strict=True):
        x -= wx * ln * ln
        y -= wy * ln * ln
        z -= wz * ln * ln
    return x, y, z


@FAST
@given(among())
def test_the_written_out_fit_is_the_loops(
    case: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
) -> None:
    """The fit written out for the layout (``fitgen``) reaches the loop's point to 1e-9 m and
    its RMS residual to 1e-12 m, from the last pose and from the linearised trilateration;
    where it hands the case back (None) ``fpk`` still returns the loop's point."""
    anchors, p, noise, last = case
    try:
        geom = Geometry(anchors, hanging=False)
    except SingularGeometryError:
        assume(False)
        raise
    lengths = (np.linalg.norm(anchors - p, axis=1) + noise).tolist()
    pts = geom._anchors_t
    fit = _written_out(geom)
    lx, ly, lz = (float(v) for v in last)
    for start, got in (
        ((lx, ly, lz), fit(lengths, lx, ly, lz)),
        (_linear_seed(geom, lengths), fit(lengths, None, 0.0, 0.0)),
    ):
        loop = _gauss_newton_among(pts, lengths, *start)
        if got is not None:
            assert math.dist(got[:3], loop[:3]) <= 1e-9
            assert abs(got[3] - loop[3]) <= 1e-12
    got_fpk = fpk(geom, lengths, last.tolist())
    loop = _gauss_newton_among(pts, lengths, lx, ly, lz)
    if loop[3] <= RETRY_RMS_M:
        assert math.dist(got_fpk.position_m, loop[:3]) <= 1e-9


def test_the_written_out_fit_fits_the_bench_layout_without_the_loop() -> None:
    """On the eight corners of a box with 1 mm of noise the written-out fit settles every
    case itself (the speed it is there for) and agrees with scipy's least squares."""
    corners = np.array([[x, y, z] for x in (-1.2, 1.2) for y in (-1.0, 1.0) for z in (-0.1, 2.1)])
    geom = Geometry(corners, hanging=False)
    fit = _written_out(geom)
    rng = np.random.default_rng(5)
    pts = rng.uniform([-0.9, -0.7, 0.2], [0.9, 0.7, 1.8], (300, 3))
    for p in pts:
        lengths = (np.linalg.norm(corners - p, axis=1) + rng.normal(0.0, 1e-3, 8)).tolist()
        got = fit(lengths, None, 0.0, 0.0)
        assert got is not None
        ref = least_squares(
            lambda q, ln=lengths: np.linalg.norm(corners - q, axis=1) - ln,
            p,
            xtol=1e-15,
            ftol=1e-15,
        )
        assert math.dist(got[:3], ref.x.tolist()) <= 1e-7
        assert fpk(geom, lengths).position_m == got[:3]


def test_a_start_on_an_anchor_or_far_away_is_handed_to_the_loop() -> None:
    """A last pose on an anchor (a division by zero) or half a metre off (a step that must be
    halved) is not the written-out fit's case: it returns None and ``fpk`` still finds the
    pose."""
    corners = np.array([[x, y, z] for x in (-1.2, 1.2) for y in (-1.0, 1.0) for z in (-0.1, 2.1)])
    geom = Geometry(corners, hanging=False)
    fit = _written_out(geom)
    p = np.array([0.3, -0.2, 0.9])
    lengths = np.linalg.norm(corners - p, axis=1).tolist()
    on_anchor = tuple(corners[3].tolist())
    assert fit(lengths, *on_anchor) is None
    assert math.dist(fpk(geom, lengths, on_anchor).position_m, p.tolist()) <= 1e-9
    far = (0.3 + 0.5, -0.2 - 0.5, 0.9 + 0.5)
    assert fit(lengths, *far) is None
    assert math.dist(fpk(geom, lengths, far).position_m, p.tolist()) <= 1e-9
