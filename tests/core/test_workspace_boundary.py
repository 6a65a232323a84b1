"""The workspace's solid as drawn (`Workspace.boundary_m`): the faces of the true shape.

For the shipped robots (the paper robot hanging, the Hangprinter v4 and five-anchor files
among their anchors, cut by their print radius) and an eight-anchor box: every corner and
every face's centre lies on the boundary of the workspace that `point_violation` enforces (in
it, and out of it 3 mm along the face's outward normal), each face is flat, and the
volume the faces enclose is the volume `inside_points` finds by sampling.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from controller.cli.configs import find_example
from controller.core.kinematics import Geometry
from controller.core.workspace import Workspace
from controller.service.config import default_config, load_config

Vec3 = tuple[float, float, float]


def workspace(name: str) -> Workspace:
    if name == "cube-8":
        anchors = [[x, y, z] for x in (-1.2, 1.2) for y in (-1.0, 1.0) for z in (-0.1, 2.1)]
        return Workspace(
            Geometry(anchors, hanging=False),
            xy_margin_m=0.15,
            floor_z_m=0.0,
            top_margin_m=0.2,
            min_cable_m=0.05,
            max_cable_m=10.0,
            max_cable_speed_mps=1.0,
        )
    cfg = default_config() if name == "paper" else load_config(find_example(name))
    return Workspace.from_limits(cfg.limits, cfg.geometry)


NAMES = ["paper", "hangprinter-v4.toml", "hangprinter-5.toml", "cube-8"]


def normal_and_centre(
    face: tuple[Vec3, ...],
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """The face's unit normal (from its vector area: outward for a counter-clockwise face),
    its vertices' mean and its area."""
    p = np.array(face, dtype=np.float64)
    area_vec = np.zeros(3)
    for k in range(1, len(p) - 1):
        area_vec += 0.5 * np.cross(p[k] - p[0], p[k + 1] - p[0])
    area = float(np.linalg.norm(area_vec))
    return area_vec / area, p.mean(axis=0), area


@pytest.mark.parametrize("name", NAMES)
def test_corners_and_faces_lie_on_the_enforced_boundary(name: str) -> None:
    """Each corner and each face's centre is in the workspace (to a micrometre) and 3 mm out
    along the face's outward normal is not; every face is flat."""
    ws = workspace(name)
    faces = ws.boundary_m()
    assert len(faces) >= 5
    middle = np.mean([p for f in faces for p in f], axis=0)
    assert ws.point_violation(middle.tolist()) is None
    for face in faces:
        n, centre, area = normal_and_centre(face)
        assert area > 1e-6
        offsets = (np.array(face) - centre) @ n
        assert np.max(np.abs(offsets)) < 1e-9  # flat
        for p in [*face, tuple(centre)]:
            q = np.asarray(p)
            # on the boundary to rounding: a micrometre toward the middle is in
            inward = q + 1e-6 * (middle - q) / np.linalg.norm(middle - q)
            assert ws.point_violation(inward.tolist()) is None, (name, p)
            # 3 mm out is out (the print radius is drawn as its inscribed 64-gon, whose
            # sides' middles lie 1.4 mm inside a 1.2 m circle)
            assert ws.point_violation((q + 3e-3 * n).tolist()) is not None, (name, p)


@pytest.mark.parametrize("name", NAMES)
def test_the_faces_enclose_the_sampled_volume(name: str) -> None:
    """The volume inside the faces (divergence theorem) is the fraction of random points of
    the bounding box that the workspace takes, to 2 %."""
    ws = workspace(name)
    volume = 0.0
    for face in ws.boundary_m():
        n, centre, area = normal_and_centre(face)
        volume += float(centre @ n) * area / 3.0
    (x0, x1), (y0, y1), (z0, z1) = ws.box()
    pts = np.random.default_rng(3).uniform([x0, y0, z0], [x1, y1, z1], (200_000, 3))
    sampled = float(np.mean(ws.inside_points(pts, lengths=False))) * (
        (x1 - x0) * (y1 - y0) * (z1 - z0)
    )
    assert volume == pytest.approx(sampled, rel=0.02)
    assert math.isfinite(volume) and volume > 0.0


def test_a_hanging_robot_is_a_prism_and_a_hangprinter_is_not() -> None:
    """The paper robot's workspace is its plan-view polygon between floor and top (every
    corner at one of the two heights); the Hangprinter v4's has corners between them (the
    hull's sloping faces)."""
    paper = workspace("paper")
    zs = {round(p[2], 9) for f in paper.boundary_m() for p in f}
    assert zs == {round(paper.floor_z_m, 9), round(paper.top_z_m, 9)}
    hp4 = workspace("hangprinter-v4.toml")
    lo, hi = hp4.floor_z_m, hp4.top_z_m
    assert any(lo + 0.01 < p[2] < hi - 0.01 for f in hp4.boundary_m() for p in f)
