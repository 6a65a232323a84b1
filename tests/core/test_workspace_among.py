"""The workspace among the anchors (a Hangprinter's pyramid), the ceiling and the print radius.

The anchors' hull with every face moved in by `xy_margin_m` across the plan view, between the
floor and the highest anchor minus `top_margin_m`; each refusal names its rule, the face's
cables and the value; the vectorised checks agree with the scalar ones; `effector_hangs`
decides which shape a robot file gets.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.core.kinematics import Geometry
from controller.core.workspace import Workspace, WorkspaceError, effector_hangs

HP4 = [
    (0.0, -1.61098, -0.13153),
    (1.31422, 1.26814, -0.12128),
    (-1.41573, 0.70761, -0.12182),
    (0.0, 0.0, 2.29983),
]
LEVEL = [(-2.0, -2.0, 3.0), (-2.0, 2.0, 3.0), (2.0, 2.0, 3.0), (2.0, -2.0, 3.0)]


def among(**kw: float | None) -> Workspace:
    limits: dict[str, float | None] = {
        "xy_margin_m": 0.08,
        "floor_z_m": 0.0,
        "top_margin_m": 0.4,
        "min_cable_m": 0.1,
        "max_cable_m": 3.5,
        "max_cable_speed_mps": 0.5,
    }
    limits.update(kw)
    return Workspace(Geometry(HP4, hanging=False), **limits)  # type: ignore[arg-type]


def test_the_pyramid_and_its_refusals() -> None:
    ws = among(print_radius_m=0.9, ceiling_z_m=1.7)
    assert not ws.hanging and ws.top_z_m == 1.7
    assert ws.check_point((0.0, 0.0, 0.5)) is None
    assert ws.check_point((0.2, -0.3, 0.0)) is None  # on the bed
    assert ws.check_point((1.0, 0.0, 0.1)) == (
        "(1, 0, 0.1) m is 0.3691 m outside the anchors' hull (the face of cables 1, 2, 4) "
        "shrunk by xy_margin_m (0.08 m)"
    )
    assert "(the face of cables 2, 3, 4)" in (ws.check_point((0.5, 0.5, 1.5)) or "")
    assert ws.check_point((0.0, 0.0, -0.01)) == "z=-0.01 m below the floor (floor_z_m 0 m)"
    assert ws.check_point((0.0, 0.0, 1.75)) == "z=1.75 m above the ceiling (ceiling_z_m 1.7 m)"
    assert ws.check_point((0.0, -0.95, 0.05)) == (
        "(x, y) = (0, -0.95) m is 0.95 m from the origin, beyond print_radius_m (0.9 m)"
    )
    assert ws.check_point((math.nan, 0.0, 0.5)) == "position (nan, 0.0, 0.5) is not finite"
    top = among()
    assert top.check_point((0.0, 0.0, 1.95)) == (
        "z=1.95 m above the highest anchor minus top_margin_m (1.9 m)"
    )
    v = top.point_violation((0.0, 0.0, 1.95))
    assert v is not None and (v.limit, v.value) == ("top_margin_m", 1.95)
    assert v.bound == pytest.approx(2.29983 - 0.4)


def test_the_faces_are_moved_in_across_the_plan_view() -> None:
    """At every height the cross-section is the hull's shrunk by the margin: a point on the
    bed 0.08 m (horizontally) inside the A-B-D face is on the boundary."""
    ws = among()
    wide = among(xy_margin_m=0.0)
    # walk outward from the middle of the bed toward the A-B edge until the unshrunk
    # workspace ends, then step back 0.08 m horizontally
    a, b = np.array(HP4[0][:2]), np.array(HP4[1][:2])
    mid = 0.5 * (a + b)
    edge = mid / np.linalg.norm(mid)
    lo, hi = 0.0, 2.0
    for _ in range(60):
        r = 0.5 * (lo + hi)
        p = (*(r * edge), 0.0)
        lo, hi = (r, hi) if wide.check_point(p) is None else (lo, r)
    face = next(f for f in Geometry(HP4, hanging=False).hull_faces if f[4] == (0, 1, 3))
    normal = np.array(face[:2]) / math.hypot(face[0], face[1])  # its horizontal direction
    back = 0.08 / float(edge @ normal)
    assert ws.check_point((*((lo - back - 1e-4) * edge), 0.0)) is None
    assert ws.check_point((*((lo - back + 1e-2) * edge), 0.0)) is not None


def test_vectorised_checks_agree_with_the_scalar_ones() -> None:
    ws = among(print_radius_m=0.8, ceiling_z_m=1.6)
    rng = np.random.default_rng(3)
    pts = rng.uniform([-1.6, -1.7, -0.2], [1.4, 1.4, 2.4], (4000, 3))
    inside = ws.inside_points(pts)
    scalar = np.array([ws.check_target(tuple(p)) is None for p in pts])
    assert np.array_equal(inside, scalar)
    assert 0.03 < inside.mean() < 0.6
    path = [tuple(p) for p in pts[:300]]
    first = next(i for i, p in enumerate(path) if ws.check_target(p) is not None)
    failure = ws.path_failure(path, legs=False)
    assert failure is not None and failure[0] == first
    (x_lo, x_hi), (y_lo, y_hi), (z_lo, z_hi) = ws.box()
    kept = pts[inside]
    assert (kept[:, 0] >= x_lo - 1e-9).all() and (kept[:, 0] <= x_hi + 1e-9).all()
    assert (kept[:, 1] >= y_lo - 1e-9).all() and (kept[:, 1] <= y_hi + 1e-9).all()
    assert z_lo == 0.0 and z_hi == 1.6
    assert all(ws.contains_xy(p[0], p[1]) for p in kept)


def test_a_hanging_robot_gets_the_ceiling_and_the_radius_too() -> None:
    ws = Workspace(
        Geometry(LEVEL),
        xy_margin_m=0.2,
        floor_z_m=0.0,
        top_margin_m=0.5,
        min_cable_m=0.1,
        max_cable_m=10.0,
        max_cable_speed_mps=1.0,
        ceiling_z_m=2.0,
        print_radius_m=1.5,
    )
    assert ws.hanging and ws.top_z_m == 2.0
    assert ws.check_point((0.0, 0.0, 2.1)) == "z=2.1 m above the ceiling (ceiling_z_m 2 m)"
    assert ws.check_point((1.2, 1.2, 1.0)) == (
        "(x, y) = (1.2, 1.2) m is 1.697 m from the origin, beyond print_radius_m (1.5 m)"
    )
    # a ceiling above the anchors' own top changes nothing
    high = Workspace(
        Geometry(LEVEL),
        xy_margin_m=0.2,
        floor_z_m=0.0,
        top_margin_m=0.5,
        min_cable_m=0.1,
        max_cable_m=10.0,
        max_cable_speed_mps=1.0,
        ceiling_z_m=9.0,
    )
    assert high.top_z_m == 2.5
    assert high.check_point((0, 0, 2.6)) == "z=2.6 m above the anchor plane minus margin (2.5 m)"


def test_limits_that_leave_nothing_are_refused_by_name() -> None:
    with pytest.raises(WorkspaceError, match=r"^floor_z_m: 2 m must be below the highest anchor"):
        among(floor_z_m=2.0)
    with pytest.raises(WorkspaceError, match=r"^xy_margin_m: 2 m leaves no workspace inside"):
        among(xy_margin_m=2.0)
    with pytest.raises(WorkspaceError, match=r"^ceiling_z_m: 0 m must be above floor_z_m"):
        among(ceiling_z_m=0.0)
    with pytest.raises(WorkspaceError, match=r"^print_radius_m: must be > 0"):
        among(print_radius_m=0.0)
    with pytest.raises(WorkspaceError, match=r"^print_radius_m: must be a finite number"):
        among(print_radius_m=math.inf)


def test_which_shape_a_robot_file_gets() -> None:
    assert effector_hangs(LEVEL, 0.0, 0.5)  # the floor below every anchor: hanging
    assert not effector_hangs(HP4, 0.0, 0.4)  # the bed above the low anchors: among them
    assert effector_hangs(HP4, -1.0, 0.4)  # a floor below them all: hanging below them
    # anchors in one plane with the floor above them: nothing to work in among them, so the
    # hanging rule decides (and refuses the floor, in its own words)
    assert effector_hangs(LEVEL, 2.9, 0.5)
    with pytest.raises(WorkspaceError, match=r"^floor_z_m: 2.9 m must be below the lowest"):
        Workspace(
            Geometry(LEVEL),
            xy_margin_m=0.2,
            floor_z_m=2.9,
            top_margin_m=0.5,
            min_cable_m=0.1,
            max_cable_m=10.0,
            max_cable_speed_mps=1.0,
        )
