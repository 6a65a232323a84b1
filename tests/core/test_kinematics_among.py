"""FPK of an effector among its anchors (`Geometry(..., hanging=False)`): Hangprinter layouts.

Three low anchors meet the effector at two points, mirror images in their plane; the lower one
is where a hanging robot is, and the wrong one above low anchors (Klipper's `winch` reports
the Hangprinter v4's origin 0.2 m low). The FPK starts on the hull's side of a hull face and
fits every cable, so it never returns the mirror: checked at 10,000 random poses with 1 mm of
noise on the lengths, at a pose where the three low cables alone admit two solutions, from a
stale last pose, on five- and eight-anchor layouts, and in the batch.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from controller.core.kinematics import (
    Geometry,
    SingularGeometryError,
    fpk,
    fpk_batch,
    ipk,
    three_spheres,
)

# The Hangprinter v4 reference anchors (m): A, B, C low, D on the ceiling.
HP4 = np.array(
    [
        [0.0, -1.61098, -0.13153],
        [1.31422, 1.26814, -0.12128],
        [-1.41573, 0.70761, -0.12182],
        [0.0, 0.0, 2.29983],
    ]
)
# Four low anchors (one plane) and one on the ceiling.
HP5 = np.array(
    [[-1.5, -1.5, -0.1], [1.5, -1.5, -0.1], [1.5, 1.5, -0.1], [-1.5, 1.5, -0.1], [0.0, 0.0, 2.5]]
)
CUBE = np.array([[x, y, z] for x in (-1.2, 1.2) for y in (-1.0, 1.0) for z in (0.0, 2.0)])


def inside(anchors: NDArray[np.float64], n: int, z_min: float, seed: int) -> NDArray[np.float64]:
    """`n` random points of the anchors' hull above `z_min` and 0.05 m inside the low anchors'
    plane or more (random convex combinations of the anchors)."""
    rng = np.random.default_rng(seed)
    out: list[NDArray[np.float64]] = []
    while len(out) < n:
        p = rng.dirichlet(np.ones(len(anchors))) @ anchors
        if p[2] >= z_min:
            out.append(p)
    return np.array(out)


def test_hangprinter_v4_never_the_mirror_at_10000_noisy_poses() -> None:
    g = Geometry(HP4, hanging=False)
    assert g.seed_triple == (0, 1, 2) and g.seed_up
    pts = inside(HP4, 10_000, 0.0, 1)
    exact = ipk(g, pts)
    noisy = exact + np.random.default_rng(2).normal(0.0, 1e-3, exact.shape)
    err = np.array(
        [math.dist(fpk(g, row).position_m, p) for row, p in zip(noisy, pts, strict=True)]
    )
    # 1 mm of length noise through the layout's geometry: millimetres, never the mirror
    # (which is 0.26 m or more away: twice the height above the low anchors' plane)
    assert float(np.median(err)) < 2e-3
    assert float(err.max()) < 1e-2
    clean = [
        math.dist(fpk(g, row).position_m, p) for row, p in zip(exact[:500], pts[:500], strict=True)
    ]
    assert max(clean) < 1e-9


def test_the_origin_of_klippers_example_is_not_reported_low() -> None:
    """At (0, 0, 0) the three low cables meet there and at the mirror image below their plane
    (the lower of the two, what trilateration from A, B, C returns); the fit over all four
    cables returns the origin."""
    g = Geometry(HP4, hanging=False)
    lengths = ipk(g, (0.0, 0.0, 0.0))
    low = three_spheres(HP4[0], HP4[1], HP4[2], *lengths[:3])
    assert low[2] < -0.2  # the mirror image, about 0.25 m below
    assert math.dist(low, (0.0, 0.0, 0.0)) > 0.2
    r = fpk(g, lengths)
    assert r.position_m == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)


def test_poses_just_above_the_low_anchors_plane() -> None:
    """Within millimetres of the low anchors' plane the two solutions nearly meet: still the
    right side, with noise."""
    g = Geometry(HP4, hanging=False)
    rng = np.random.default_rng(4)
    for _ in range(200):
        p = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(-0.12, -0.1)])
        lengths = ipk(g, p) + rng.normal(0.0, 1e-4, 4)
        assert math.dist(fpk(g, lengths).position_m, p) < 5e-3


def test_a_stale_last_pose_does_not_lead_astray() -> None:
    """Seeded by the last pose (the control loop): the same answer; seeded by a pose a metre
    away, or by the mirror image itself, the fit is redone from the three spheres."""
    g = Geometry(HP4, hanging=False)
    p = np.array([0.2, -0.3, 0.7])
    lengths = ipk(g, p) + np.array([3e-4, -2e-4, 1e-4, 0.0])
    cold = fpk(g, lengths)
    near = fpk(g, lengths, seed_m=p + 0.003)
    assert math.dist(cold.position_m, near.position_m) < 1e-9
    mirror = three_spheres(HP4[0], HP4[1], HP4[2], *lengths[:3])
    for seed in ((1.0, 1.0, 2.0), mirror, (0.0, 0.0, -3.0)):
        r = fpk(g, lengths, seed_m=seed)
        assert math.dist(r.position_m, p) < 2e-3
    assert fpk(g, lengths, seed_m=(math.nan, 0.0, 0.0)).position_m == cold.position_m


@pytest.mark.parametrize(
    ("anchors", "z_min"), [(HP5, 0.0), (CUBE, 0.1)], ids=["hangprinter-5", "cube-8"]
)
def test_five_and_eight_anchors(anchors: NDArray[np.float64], z_min: float) -> None:
    g = Geometry(anchors, hanging=False)
    assert g.seed_up
    pts = inside(anchors, 2000, z_min, 5)
    exact = ipk(g, pts)
    noisy = exact + np.random.default_rng(6).normal(0.0, 1e-3, exact.shape)
    err = [math.dist(fpk(g, row).position_m, p) for row, p in zip(noisy, pts, strict=True)]
    assert max(err) < 1e-2
    batch = fpk_batch(g, noisy)
    assert batch.valid.all()
    single = np.array([fpk(g, row).position_m for row in noisy[:200]])
    assert np.max(np.abs(batch.position_m[:200] - single)) < 1e-12


def test_among_the_anchors_needs_a_hull() -> None:
    with pytest.raises(SingularGeometryError, match="at least 4"):
        Geometry(HP4[:3], hanging=False)
    level = [[-1.0, -1.0, 2.0], [-1.0, 1.0, 2.0], [1.0, 1.0, 2.0], [1.0, -1.0, 2.0]]
    with pytest.raises(SingularGeometryError, match="lie in one plane"):
        Geometry(level, hanging=False)
    g = Geometry(level)  # hanging below them: the usual rig
    assert g.hanging and not g.seed_up
    assert "hanging=False" in repr(Geometry(HP4, hanging=False))
