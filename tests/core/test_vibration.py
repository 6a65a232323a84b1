"""The effector's modes from the model (`controller.core.vibration`), checked against the
physical plant (the truth: excited and fitted), numpy's eigenvalues and a hand derivation."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import curve_fit

from controller.core.plant import CablePlant, PlantParams
from controller.core.statics import CableStatics
from controller.core.vibration import (
    ModesError,
    ModeTracker,
    _sym3_eigenvalues,
    effector_modes,
    rope_damping,
    stiffness_matrices,
)
from controller.service.config import load_config

CONFIG = Path(__file__).resolve().parents[2] / "config"
PAPER = load_config(CONFIG / "paper-acre.toml").anchors_m
DESK = load_config(CONFIG / "desk.toml").anchors_m
FAST = settings(max_examples=60, deadline=None, derandomize=True)


def tensions(anchors: object, p: tuple[float, float, float], mass_kg: float) -> tuple[float, ...]:
    return CableStatics(anchors, 1.0, 1e5).solve(p, mass_kg).tensions_n


def ring(
    params: PlantParams,
    p: tuple[float, float, float],
    t: tuple[float, ...],
    d: np.ndarray,
    f: float,
) -> tuple[float, float]:
    """Kick the plant at rest at `p` along `d`, fit a damped sine to its motion along `d`:
    (frequency in Hz, damping ratio)."""
    rest = CablePlant.at_pose(params, p, t)
    zeta = params.cable_damping_ratio
    plant = CablePlant(params, p, rest.unstretched_m, velocity_mps=tuple(1e-3 * d))
    dt = min(1e-3, 0.02 / f)
    n = round(min(15.0, 4.0 / (zeta * 2.0 * math.pi * f), 60.0 / f) / dt)
    xs = np.empty(n)
    for k in range(n):
        plant.step(rest.unstretched_m, dt)
        xs[k] = float(np.dot(np.subtract(plant.position_m, p), d))
    ts = np.arange(1, n + 1) * dt

    def model(t: np.ndarray, a: float, w: float, z: float, ph: float) -> np.ndarray:
        return a * np.exp(-z * w * t) * np.sin(w * math.sqrt(1.0 - z * z) * t + ph)

    (_, w, z, _), _ = curve_fit(
        model, ts, xs, p0=[float(np.abs(xs).max()), 2 * math.pi * f, 0.02, 0]
    )
    return w / (2.0 * math.pi), z


@pytest.mark.parametrize(
    ("anchors", "p", "mass_kg", "ea_n", "zeta", "drag"),
    [
        (PAPER, (0.0, 0.0, 2.0), 5.0, 4.5e5, 0.02, 0.5),
        (PAPER, (20.0, -10.0, 4.0), 20.0, 4.5e5, 0.02, 2.0),
        (PAPER, (35.0, 20.0, 1.0), 5.0, 1e6, 0.005, 0.0),
        (DESK, (0.1, -0.2, 0.3), 0.5, 1e5, 0.05, 0.05),
    ],
    ids=["paper-centre", "paper-20kg", "paper-corner", "desk"],
)
def test_the_models_modes_are_the_plants(
    anchors: object,
    p: tuple[float, float, float],
    mass_kg: float,
    ea_n: float,
    zeta: float,
    drag: float,
) -> None:
    t = tensions(anchors, p, mass_kg)
    modes = effector_modes(
        anchors,
        p,
        t,
        [ea_n] * 4,
        mass_kg,
        cable_damping_ratio=zeta,
        effector_damping_n_s_per_m=drag,
    )
    params = PlantParams(
        anchors, ea_n, mass_kg, cable_damping_ratio=zeta, effector_damping_n_s_per_m=drag
    )
    assert modes.frequencies_hz == tuple(sorted(modes.frequencies_hz))
    for f, z, d in zip(modes.frequencies_hz, modes.damping_ratios, modes.directions, strict=True):
        assert np.linalg.norm(d) == pytest.approx(1.0)
        f_plant, z_plant = ring(params, p, t, np.asarray(d), f)
        assert f_plant == pytest.approx(f, rel=5e-3)
        assert z_plant == pytest.approx(z, rel=0.05)
    # the directions are orthogonal (K / m is symmetric)
    dirs = np.asarray(modes.directions)
    assert dirs @ dirs.T == pytest.approx(np.eye(3), abs=1e-9)


def test_the_vertical_mode_under_four_symmetric_anchors_by_hand() -> None:
    # Centre of the paper robot: by symmetry z is a mode. Each cable pulls t along u with
    # u_z = h / L; k = (EA + t) / L (EA / L0), g = t / L; K_zz = sum (k - g) u_z^2 + sum g.
    p = (0.0, 0.0, 2.0)
    m, ea = 5.0, 4.5e5
    t = tensions(PAPER, p, m)
    a = PAPER[0]
    length = math.dist(a, p)
    uz = (a[2] - p[2]) / length
    k = (ea + t[0]) / length
    g = t[0] / length
    kzz = 4.0 * ((k - g) * uz * uz + g)
    f_hand = math.sqrt(kzz / m) / (2.0 * math.pi)
    modes = effector_modes(PAPER, p, t, [ea] * 4, m)
    j = int(np.argmax([abs(d[2]) for d in modes.directions]))
    assert modes.frequencies_hz[j] == pytest.approx(f_hand, rel=1e-12)
    assert modes.directions[j] == pytest.approx((0.0, 0.0, 1.0), abs=1e-12)
    assert modes.damping_ratios == (0.0, 0.0, 0.0)  # no damping given


@FAST
@given(
    a=st.lists(st.floats(-1e3, 1e3), min_size=6, max_size=6),
)
def test_closed_form_eigenvalues_match_numpy(a: list[float]) -> None:
    """The trigonometric closed form agrees with LAPACK to about the square root of the
    rounding error at a (near) double root, where any root of the characteristic polynomial
    loses half its digits (2e-8 of the largest entry, the worst of 200,000 matrices with
    near-double roots): 1e-7 of it here, far below what a mode's frequency needs."""
    m = np.array([[a[0], a[1], a[2]], [a[1], a[3], a[4]], [a[2], a[4], a[5]]])
    ref = np.linalg.eigvalsh(m)
    got = _sym3_eigenvalues(a[0], a[1], a[2], a[3], a[4], a[5])
    scale = max(1.0, float(np.abs(m).max()))
    assert got == pytest.approx(tuple(ref), abs=1e-7 * scale)


def test_closed_form_eigenvalues_near_a_double_root() -> None:
    """The matrix Hypothesis found: two roots 2e-7 apart on a scale of 21."""
    a = (0.0, 0.0, 0.0, 0.0, 0.001953125, 21.0)
    ref = np.linalg.eigvalsh(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, a[4]], [0.0, a[4], 21.0]]))
    assert _sym3_eigenvalues(*a) == pytest.approx(tuple(ref), abs=1e-7 * 21.0)


@FAST
@given(
    x=st.floats(-30.0, 30.0),
    y=st.floats(-18.0, 18.0),
    z=st.floats(0.2, 5.5),
    mass_kg=st.floats(1.0, 30.0),
    log_ea=st.floats(5.0, 7.0),
    scale=st.floats(0.5, 2.0),
)
def test_the_trackers_frequencies_are_the_modes(
    x: float, y: float, z: float, mass_kg: float, log_ea: float, scale: float
) -> None:
    p = (x, y, z)
    ea = 10.0**log_ea
    t = tensions(PAPER, p, mass_kg)
    modes = effector_modes(PAPER, p, t, [ea] * 4, mass_kg)
    got = ModeTracker(PAPER, [ea] * 4, mass_kg, scale).frequencies_hz(p, t)
    assert got is not None
    assert got == pytest.approx(tuple(f * scale for f in modes.frequencies_hz), rel=1e-9)


def test_the_ropes_damp_every_axial_mode_at_their_ratio() -> None:
    k_axial, _ = stiffness_matrices(
        PAPER, (10.0, 5.0, 3.0), tensions(PAPER, (10.0, 5.0, 3.0), 5.0), [4.5e5] * 4
    )
    m, zeta = 5.0, 0.03
    c, g = rope_damping(k_axial, m, zeta)
    lam, vec = np.linalg.eigh(k_axial / m)
    for j in range(3):
        phi = vec[:, j]
        assert phi @ c @ phi / (2.0 * m * math.sqrt(lam[j])) == pytest.approx(zeta, rel=1e-9)
    # G K_a is C: the gain turns stiffness-weighted strain rates into the damping force
    assert g @ k_axial == pytest.approx(c, rel=1e-9, abs=1e-9 * float(np.abs(c).max()))
    # two taut cables stiffen their plane only: no gain, no damping out of it, nothing infinite
    u = np.array([[0.6, 0.0, 0.8], [-0.6, 0.0, 0.8]])
    c2, g2 = rope_damping((u.T * 1e4) @ u, m, zeta)
    normal = np.array([0.0, 1.0, 0.0])
    assert np.isfinite(g2).all() and np.isfinite(c2).all()
    assert g2 @ normal == pytest.approx([0.0] * 3, abs=1e-12)
    assert c2 @ normal == pytest.approx([0.0] * 3, abs=1e-9)


def test_a_rigid_model_or_a_slack_cable_is_said_never_nan() -> None:
    p = (0.0, 0.0, 2.0)
    t = tensions(PAPER, p, 5.0)
    with pytest.raises(ModesError, match=r"cables 1, 2, 3, 4 have no EA .* rigid model"):
        effector_modes(PAPER, p, t, [None] * 4, 5.0)
    with pytest.raises(ModesError, match=r"cable 3 has no EA"):
        effector_modes(PAPER, p, t, [1e6, 1e6, None, 1e6], 5.0)
    with pytest.raises(ModesError, match=r"cable 2 is slack at"):
        effector_modes(PAPER, p, (t[0], 0.0, t[2], t[3]), [1e6] * 4, 5.0)
    with pytest.raises(ModesError, match="finite"):
        effector_modes(PAPER, (math.nan, 0.0, 2.0), t, [1e6] * 4, 5.0)
    with pytest.raises(ModesError, match="mass"):
        effector_modes(PAPER, p, t, [1e6] * 4, 0.0)
    with pytest.raises(ModesError, match="on an anchor"):
        effector_modes(PAPER, PAPER[0], t, [1e6] * 4, 5.0)
    tracker = ModeTracker(PAPER, [1e6] * 4, 5.0)
    assert tracker.frequencies_hz(p, (t[0], 0.0, t[2], t[3])) is None  # slack: none, not NaN
    assert tracker.frequencies_hz(PAPER[0], t) is None
    with pytest.raises(ModesError, match="cable_ea_n"):
        ModeTracker(PAPER, [1e6, None, 1e6, 1e6], 5.0)
