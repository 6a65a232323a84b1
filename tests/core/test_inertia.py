"""The payload's inertia in the planned tensions (`controller.core.inertia`): the share supplies
exactly m a, is the least-norm one, and never makes a cable push."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.core.inertia import inertial_share, with_inertia
from controller.service.config import default_config

ANCHORS = tuple(tuple(float(v) for v in a) for a in default_config().anchors_m)
FAST = settings(max_examples=80, deadline=None, derandomize=True)


@FAST
@given(
    p=st.tuples(st.floats(-35, 35), st.floats(-20, 20), st.floats(0.0, 6.5)),
    a=st.tuples(st.floats(-3, 3), st.floats(-3, 3), st.floats(-3, 3)),
    mass=st.floats(0.1, 50.0),
)
def test_the_share_supplies_m_a_with_the_least_norm(
    p: tuple[float, float, float], a: tuple[float, float, float], mass: float
) -> None:
    share = inertial_share(ANCHORS, p, mass, a)
    assert share is not None
    d = np.asarray(ANCHORS) - np.asarray(p)
    u = d / np.linalg.norm(d, axis=1)[:, None]
    force = np.asarray(share) @ u
    assert force == pytest.approx(mass * np.asarray(a), abs=1e-9 * max(1.0, mass * 3.0))
    # least norm: numpy's pseudo-inverse gives the same
    ref = np.linalg.pinv(u.T) @ (mass * np.asarray(a))
    assert share == pytest.approx(tuple(ref), abs=1e-8 * max(1.0, mass))


def test_no_acceleration_no_share_and_no_cable_pushes() -> None:
    assert inertial_share(ANCHORS, (0.0, 0.0, 2.0), 5.0, (0.0, 0.0, 0.0)) == (0.0,) * 4
    held = (104.4, 104.4, 104.4, 104.4)
    down = inertial_share(ANCHORS, (0.0, 0.0, 2.0), 5.0, (0.0, 0.0, -50.0))  # faster than g
    assert down is not None and min(down) < -104.4
    assert with_inertia(held, down) == (0.0,) * 4
    assert with_inertia(held, None) == held
    assert inertial_share(ANCHORS, ANCHORS[0], 5.0, (1.0, 0.0, 0.0)) is None  # on an anchor
    flat = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    assert inertial_share(flat, (0.5, 0.5, 0.0), 1.0, (0.0, 0.0, 1.0)) is None  # a plane
