"""The physical plant: rest poses, slack cables, holding still, pay-out, damping, errors."""

from __future__ import annotations

import math
import tomllib
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.core.plant import (
    CablePlant,
    EquilibriumError,
    PlantDivergedError,
    PlantError,
    PlantParams,
    equilibrium,
    unstretched_lengths,
)

CONFIG = Path(__file__).resolve().parents[2] / "config"
FAST = settings(max_examples=60, deadline=None, derandomize=True)


def anchors_of(name: str) -> list[tuple[float, float, float]]:
    """The anchors of a shipped robot configuration."""
    with (CONFIG / name).open("rb") as f:
        reels = tomllib.load(f)["reels"]
    return [tuple(r["anchor_m"]) for r in reels]


DESK = anchors_of("desk.toml")
PAPER = anchors_of("paper-acre.toml")


CRITICAL = 1.0
"""The tests that wait for the effector to come to rest damp every mode critically."""


def desk(ea_n: float = 1e5, mass_kg: float = 0.5, **kw: float) -> PlantParams:
    kw.setdefault("cable_damping_ratio", CRITICAL)
    kw.setdefault("effector_damping_n_s_per_m", 1.0 * mass_kg)
    return PlantParams(DESK, ea_n, mass_kg, **kw)


def paper(ea_n: float = 1e6, mass_kg: float = 10.0) -> PlantParams:
    return PlantParams(
        PAPER, ea_n, mass_kg, cable_damping_ratio=CRITICAL, effector_damping_n_s_per_m=mass_kg
    )


def net_force(params: PlantParams, p: Sequence[float], l0: Sequence[float]) -> np.ndarray:
    """Static force balance computed here, independently of the plant."""
    f = np.array([0.0, 0.0, -params.mass_kg * 9.80665])
    for a, ea, l0_i in zip(params.anchors_m, params.ea_n, l0, strict=True):
        d = np.subtract(a, p)
        length = float(np.linalg.norm(d))
        f += ea / l0_i * max(0.0, length - l0_i) * d / length
    return f


def distances(params: PlantParams, p: Sequence[float]) -> list[float]:
    return [math.dist(a, p) for a in params.anchors_m]


def hold(plant: CablePlant, seconds: float, dt_s: float = 0.001) -> None:
    l0 = plant.unstretched_m
    for _ in range(round(seconds / dt_s)):
        plant.step(l0, dt_s)


# --- equilibrium ------------------------------------------------------------------------------


@FAST
@given(
    x=st.floats(-0.4, 0.4),
    y=st.floats(-0.4, 0.4),
    z=st.floats(0.05, 0.65),
    mass_kg=st.floats(0.1, 5.0),
    log_ea=st.floats(4.0, 6.0),
    payout_m=st.lists(st.sampled_from([0.0, 0.0, 1e-5, 1e-3, 0.02]), min_size=4, max_size=4),
)
def test_equilibrium_balances_forces_and_slack_cables_carry_nothing(
    x: float, y: float, z: float, mass_kg: float, log_ea: float, payout_m: list[float]
) -> None:
    params = desk(10.0**log_ea, mass_kg)
    held = CablePlant.at_pose(params, (x, y, z))
    l0 = [a + b for a, b in zip(held.unstretched_m, payout_m, strict=True)]
    eq = equilibrium(params, l0)  # from the default guess, far below
    assert np.linalg.norm(net_force(params, eq.position_m, l0)) < 1e-6
    assert eq.residual_n < 1e-6
    for t, length, l0_i in zip(eq.tensions_n, distances(params, eq.position_m), l0, strict=True):
        assert t >= 0.0
        assert (t > 0.0) == (length > l0_i)  # taut exactly when stretched


def test_equilibrium_paper_robot_force_balance() -> None:
    params = paper()
    held = CablePlant.at_pose(params, (-6.55, -8.6, 2.63))
    l0 = list(held.unstretched_m)
    l0[2] += 0.5
    eq = equilibrium(params, l0)
    assert np.linalg.norm(net_force(params, eq.position_m, l0)) < 1e-6
    assert eq.tensions_n[2] == 0.0


def test_equilibrium_of_very_stiff_cables_converges_by_continuation() -> None:
    # Steel-stiff for a 0.5 kg effector: Newton alone creeps along the slack/taut kink here.
    params = desk(ea_n=1e9)
    held = CablePlant.at_pose(
        params, (-0.36383098817939963, -0.44644020030303305, 0.2522240819360385)
    )
    l0 = list(held.unstretched_m)
    l0[1] += 0.0015596104969872737
    eq = equilibrium(params, l0)
    # rounding allows about k * |P| * eps per cable at k ~ 1e9 N/m
    assert np.linalg.norm(net_force(params, eq.position_m, l0)) < 1e-3
    assert eq.tensions_n[1] == 0.0


def test_at_pose_holds_the_pose_with_the_given_tensions() -> None:
    params = desk()
    p = (0.1, 0.05, 0.3)
    plant = CablePlant.at_pose(params, p)
    t = plant.tensions_n
    assert np.linalg.norm(net_force(params, p, plant.unstretched_m)) < 1e-9
    assert min(t) > 0.0
    # the same tensions, passed explicitly, give the same lengths; the round trip is exact
    assert unstretched_lengths(params, p, t) == pytest.approx(plant.unstretched_m, abs=1e-15)
    eq = equilibrium(params, plant.unstretched_m)
    assert math.dist(eq.position_m, p) < 1e-9
    assert eq.tensions_n == pytest.approx(t, rel=1e-6)


def test_at_pose_pretension_and_its_limit() -> None:
    params = desk(mass_kg=2.0)
    p = (0.2, 0.1, 0.3)
    free = CablePlant.at_pose(params, p).tensions_n
    lifted = CablePlant.at_pose(params, p, pretension_n=min(free) + 0.3).tensions_n
    assert min(lifted) == pytest.approx(min(free) + 0.3)
    assert np.linalg.norm(net_force(params, p, unstretched_lengths(params, p, lifted))) < 1e-9
    # anchors all above: the null space only trades tension between cables, and the upward
    # pulls sum to the weight, so four cables cannot all pull the weight
    with pytest.raises(EquilibriumError, match="no tension distribution"):
        CablePlant.at_pose(params, p, pretension_n=params.weight_n)


def test_at_pose_three_and_five_cables() -> None:
    tri = PlantParams([(0.0, 1.0, 2.0), (-0.9, -0.5, 2.0), (0.9, -0.5, 2.0)], 1e5, 1.0)
    plant = CablePlant.at_pose(tri, (0.1, 0.0, 1.0))
    assert np.linalg.norm(net_force(tri, (0.1, 0.0, 1.0), plant.unstretched_m)) < 1e-9
    five = PlantParams([*DESK, (0.0, 0.0, 1.0)], 1e5, 1.0)
    with pytest.raises(EquilibriumError, match="redundant"):
        CablePlant.at_pose(five, (0.0, 0.0, 0.3))
    # with a statics solution given it works: the top cable alone holds it
    plant = CablePlant.at_pose(five, (0.0, 0.0, 0.3), (0.0, 0.0, 0.0, 0.0, five.weight_n))
    hold(plant, 0.2)
    assert math.dist(plant.position_m, (0.0, 0.0, 0.3)) < 1e-9


# --- the time step ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("params", "pose"),
    [
        (desk(), (0.1, 0.05, 0.3)),
        (desk(ea_n=1e7), (-0.3, 0.2, 0.1)),
        (paper(), (-6.55, -8.6, 2.63)),
    ],
    ids=["desk", "desk-steel", "paper-acre"],
)
def test_plant_started_at_equilibrium_stays_put(
    params: PlantParams, pose: tuple[float, ...]
) -> None:
    plant = CablePlant.at_pose(params, pose)
    t0 = plant.tensions_n
    hold(plant, 1.0)
    assert plant.time_s == pytest.approx(1.0)
    assert math.dist(plant.position_m, pose) < 1e-6
    assert math.hypot(*plant.velocity_mps) < 1e-6
    assert plant.tensions_n == pytest.approx(t0, rel=1e-6)


@FAST
@given(
    moves=st.lists(
        st.lists(st.floats(-1e-3, 1e-3), min_size=4, max_size=4), min_size=20, max_size=120
    ),
    log_ea=st.floats(4.0, 6.5),
)
def test_tensions_never_negative_and_slack_cables_carry_nothing(
    moves: list[list[float]], log_ea: float
) -> None:
    plant = CablePlant.at_pose(desk(10.0**log_ea), (0.05, -0.1, 0.3))
    l0 = list(plant.unstretched_m)
    for move in moves:
        l0 = [a + b for a, b in zip(l0, move, strict=True)]
        plant.step(l0, 0.001)
        assert all(math.isfinite(v) for v in (*plant.position_m, *plant.velocity_mps))
        for t, length, l0_i in zip(
            plant.tensions_n, distances(plant.params, plant.position_m), l0, strict=True
        ):
            assert t >= 0.0
            if length <= l0_i:
                assert t == 0.0


def test_slack_cable_carries_no_tension() -> None:
    params = desk()
    held = CablePlant.at_pose(params, (0.0, 0.0, 0.3))
    l0 = list(held.unstretched_m)
    l0[3] = math.dist(DESK[3], (0.0, 0.0, 0.3)) + 0.01  # paid out beyond the distance
    plant = CablePlant(params, (0.0, 0.0, 0.3), l0)
    assert plant.tensions_n[3] == 0.0
    assert min(plant.tensions_n[:3]) > 0.0
    for _ in range(100):
        plant.step(l0, 0.001)
        assert plant.tensions_n[3] == 0.0


def pay_out(
    params: PlantParams, pose: tuple[float, float, float], payout_m: float, hold_s: float = 2.0
) -> CablePlant:
    """Hold at `pose`, pay cable 1 out by `payout_m` at 0.1 m/s, then hold `hold_s`."""
    plant = CablePlant.at_pose(params, pose)
    l0 = list(plant.unstretched_m)
    start = l0[0]
    ramp_steps = max(1, round(payout_m / 0.1 / 0.001))
    for k in range(1, ramp_steps + 1):
        l0[0] = start + payout_m * k / ramp_steps
        plant.step(l0, 0.001)
    hold(plant, hold_s)
    return plant


@pytest.mark.parametrize(
    ("params", "pose", "hold_s", "slack"),
    [(desk(), (0.1, 0.05, 0.3), 2.0, 0), (paper(), (-6.55, -8.6, 2.63), 15.0, 2)],
    ids=["desk", "paper-acre"],
)
def test_paying_one_cable_out_5cm_moves_to_a_rest_on_three_cables(
    params: PlantParams, pose: tuple[float, float, float], hold_s: float, slack: int
) -> None:
    # The rest pose is the lowest point the cable lengths allow. On the desk's steep cables the
    # other three keep the effector where it was and cable 1 goes slack. On the paper robot's
    # shallow cables the effector drops (13.5 cm) on cables 1, 2, 4 and cable 3 goes slack.
    before = CablePlant.at_pose(params, pose)
    plant = pay_out(params, pose, 0.05, hold_s)
    l0 = plant.unstretched_m
    assert l0[0] == pytest.approx(before.unstretched_m[0] + 0.05)
    # at rest, at the equilibrium of the new lengths
    assert math.hypot(*plant.velocity_mps) < 1e-6
    rest = equilibrium(params, l0, pose)
    assert math.dist(plant.position_m, rest.position_m) < 1e-6
    assert np.linalg.norm(net_force(params, plant.position_m, l0)) < 1e-3
    assert plant.tensions_n[0] < before.tensions_n[0]
    assert min(before.tensions_n) > 0.0
    for i, (t, length, l0_i) in enumerate(
        zip(plant.tensions_n, distances(params, plant.position_m), l0, strict=True)
    ):
        if i == slack:
            assert t == 0.0
            assert length < l0_i
        else:
            assert t > 0.0


def test_a_small_pay_out_lowers_that_cables_tension() -> None:
    params = desk()
    pose = (0.1, 0.05, 0.3)
    before = CablePlant.at_pose(params, pose)
    stretch_m = distances(params, pose)[0] - before.unstretched_m[0]
    plant = pay_out(params, pose, 0.3 * stretch_m)
    assert 0.0 < plant.tensions_n[0] < before.tensions_n[0] - 0.1
    assert np.linalg.norm(net_force(params, plant.position_m, plant.unstretched_m)) < 1e-6


def test_dropped_effector_settles_and_energy_only_falls() -> None:
    params = desk()
    rest = CablePlant.at_pose(params, (0.1, 0.05, 0.3))
    x, y, z = rest.position_m
    plant = CablePlant(params, (x, y, z + 0.02), rest.unstretched_m)  # 2 cm up: all slack
    assert plant.tensions_n == (0.0, 0.0, 0.0, 0.0)
    energy = plant.energy_j()
    start = energy
    for _ in range(1000):
        plant.step(rest.unstretched_m, 0.001)
        now = plant.energy_j()
        assert now <= energy + 1e-12
        energy = now
    assert start - energy == pytest.approx(params.weight_n * 0.02, rel=1e-3)
    assert math.dist(plant.position_m, rest.position_m) < 1e-6
    assert math.hypot(*plant.velocity_mps) < 1e-6


def test_effector_follows_cables_paid_in_step_with_a_move() -> None:
    # The cable damping acts on the stretch rate only: cables wound in and out with the motion
    # do not drag the effector, and the tensions stay the static ones up to m a + c v.
    params = desk()
    start = (-0.1, 0.0, 0.3)
    plant = CablePlant.at_pose(params, start)
    for k in range(1, 3001):  # 0.2 m along x in 3 s, cosine profile (peak 0.1 m/s)
        target = (start[0] + 0.1 * (1.0 - math.cos(math.pi * k / 3000)), 0.0, 0.3)
        held = CablePlant.at_pose(params, target)
        plant.step(held.unstretched_m, 0.001)
        assert math.dist(plant.position_m, target) < 1e-5
        assert plant.tensions_n == pytest.approx(held.tensions_n, abs=0.02 * params.weight_n)


@pytest.mark.parametrize("ea_n", [1e5, 1e7])
def test_sub_steps_keep_an_undamped_plant_stable(ea_n: float) -> None:
    params = desk(ea_n=ea_n, cable_damping_ratio=0.0, effector_damping_n_s_per_m=0.0)
    rest = CablePlant.at_pose(params, (0.1, 0.05, 0.3))
    x, y, z = rest.position_m
    plant = CablePlant(params, (x, y, z - 1e-4), rest.unstretched_m)
    excess = plant.energy_j() - rest.energy_j()
    hold(plant, 2.0)
    # no damping: the energy neither grows (unstable) nor drains away
    assert 0.5 * excess < plant.energy_j() - rest.energy_j() < 1.5 * excess


def test_sub_steps_grow_with_stiffness() -> None:
    counts = []
    for ea_n in (1e5, 1e7):
        plant = CablePlant.at_pose(desk(ea_n=ea_n), (0.1, 0.05, 0.3))
        plant.step(plant.unstretched_m, 0.001)
        counts.append(plant.substeps)
    assert 1 <= counts[0] < counts[1] <= 100


# --- errors -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"mass_kg": 0.0}, "mass_kg"),
        ({"mass_kg": -1.0}, "mass_kg"),
        ({"mass_kg": math.nan}, "mass_kg"),
        ({"ea_n": math.inf}, "ea_n"),
        ({"ea_n": [1e5, 1e5, 1e5]}, "3 values for 4 cables"),
        ({"ea_n": [1e5, 1e5, -1.0, 1e5]}, "cable 3"),
        ({"anchors_m": [(0.0, 0.0, math.nan)]}, "anchor 1"),
        ({"anchors_m": [(0.0, 0.0)]}, "anchor 1"),
        ({"anchors_m": []}, "at least one cable"),
        ({"cable_damping_ratio": -0.1}, "cable_damping_ratio"),
        ({"effector_damping_n_s_per_m": math.inf}, "effector_damping"),
        ({"gravity_mps2": math.nan}, "gravity"),
        ({"max_substeps": 0}, "max_substeps"),
    ],
)
def test_bad_parameters_are_named_errors(kwargs: dict[str, object], match: str) -> None:
    args: dict[str, object] = {"anchors_m": DESK, "ea_n": 1e5, "mass_kg": 1.0}
    args.update(kwargs)
    with pytest.raises(PlantError, match=match):
        PlantParams(**args)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("l0_change", "dt_s", "match"),
    [
        ((math.nan, 0, 0, 0), 0.001, "cable 1"),
        ((0, math.inf, 0, 0), 0.001, "cable 2"),
        ((0, 0, -10.0, 0), 0.001, "cable 3"),
        ((0, 0, 0, 0), math.nan, "dt_s"),
        ((0, 0, 0, 0), math.inf, "dt_s"),
        ((0, 0, 0, 0), 0.0, "dt_s"),
        ((0, 0, 0, 0), -0.001, "dt_s"),
    ],
)
def test_bad_step_inputs_are_named_errors_and_leave_the_state(
    l0_change: tuple[float, ...], dt_s: float, match: str
) -> None:
    plant = CablePlant.at_pose(desk(), (0.1, 0.05, 0.3))
    state = (plant.position_m, plant.velocity_mps, plant.tensions_n, plant.unstretched_m)
    l0 = [a + b for a, b in zip(plant.unstretched_m, l0_change, strict=True)]
    with pytest.raises(PlantError, match=match):
        plant.step(l0, dt_s)
    with pytest.raises(PlantError, match="3 values for 4 cables"):
        plant.step(plant.unstretched_m[:3], 0.001)
    with pytest.raises(PlantError, match="numbers"):
        plant.step(["x", 1.0, 1.0, 1.0], 0.001)  # type: ignore[list-item]
    assert (plant.position_m, plant.velocity_mps, plant.tensions_n, plant.unstretched_m) == state
    assert plant.time_s == 0.0


def test_bad_poses_lengths_and_tensions_are_named_errors() -> None:
    params = desk()
    l0 = CablePlant.at_pose(params, (0.0, 0.0, 0.3)).unstretched_m
    with pytest.raises(PlantError, match="position_m"):
        CablePlant(params, (0.0, math.nan, 0.3), l0)
    with pytest.raises(PlantError, match="velocity_mps"):
        CablePlant(params, (0.0, 0.0, 0.3), l0, (math.inf, 0.0, 0.0))
    with pytest.raises(PlantError, match="unstretched_m"):
        CablePlant(params, (0.0, 0.0, 0.3), (*l0[:3], 0.0))
    with pytest.raises(PlantError, match="unstretched_m"):
        equilibrium(params, (*l0[:3], math.nan))
    with pytest.raises(PlantError, match="guess_m"):
        equilibrium(params, l0, (0.0, 0.0, math.inf))
    with pytest.raises(PlantError, match="tension of cable 2"):
        unstretched_lengths(params, (0.0, 0.0, 0.3), (1.0, -1.0, 1.0, 1.0))
    with pytest.raises(PlantError, match="tension of cable 4"):
        unstretched_lengths(params, (0.0, 0.0, 0.3), (1.0, 1.0, 1.0, math.nan))
    with pytest.raises(PlantError, match="pretension_n"):
        CablePlant.at_pose(params, (0.0, 0.0, 0.3), pretension_n=math.nan)


def test_divergence_is_a_named_error_not_nan() -> None:
    params = desk()
    l0 = CablePlant.at_pose(params, (0.0, 0.0, 0.3)).unstretched_m
    plant = CablePlant(params, (0.0, 0.0, 0.3), l0, (1e308, 0.0, 0.0))
    with pytest.raises(PlantDivergedError, match="diverged"):
        plant.step(l0, 0.001)
    assert plant.position_m == (0.0, 0.0, 0.3)


def test_effector_on_an_anchor_is_a_named_error() -> None:
    params = desk()
    plant = CablePlant(params, DESK[2], (1.0, 1.0, 1.0, 1.0))
    with pytest.raises(PlantError, match="on anchor 3"):
        plant.step((1.0, 1.0, 1.0, 1.0), 0.001)


def test_too_stiff_for_max_substeps_is_refused() -> None:
    plant = CablePlant.at_pose(desk(ea_n=1e9, max_substeps=50), (0.0, 0.0, 0.3))
    with pytest.raises(PlantError, match="sub-steps"):
        plant.step(plant.unstretched_m, 0.001)
    assert plant.time_s == 0.0


# --- a bank of reels: motor turns in, holding torques out ---------------------------------------


def reel_plant(cfg_name: str, pose: tuple[float, float, float], mass_kg: float, ea_n: float):  # type: ignore[no-untyped-def]
    """A ReelPlant for a shipped robot at `pose`, holding the statics distribution."""
    from controller.core.plant import ReelPlant
    from controller.core.statics import CableStatics
    from controller.service.config import load_config

    cfg = load_config(CONFIG / cfg_name)
    assert cfg.tension is not None
    tensions = CableStatics(cfg.anchors_m, cfg.tension.min_n, cfg.tension.max_n).solve(
        pose, mass_kg
    )
    reels = [r.reel for r in cfg.reels]
    turns = [
        r.position_rev(length) for r, length in zip(reels, distances_to(cfg, pose), strict=True)
    ]
    params = PlantParams(
        cfg.anchors_m,
        ea_n,
        mass_kg,
        cable_damping_ratio=CRITICAL,
        effector_damping_n_s_per_m=mass_kg,
    )
    return cfg, reels, turns, ReelPlant(params, reels, pose, turns, tensions.tensions_n), tensions


def distances_to(cfg, pose):  # type: ignore[no-untyped-def]
    return [math.dist(a, pose) for a in cfg.anchors_m]


@pytest.mark.parametrize(
    ("cfg_name", "pose", "mass_kg", "ea_n"),
    [("paper-acre.toml", (3.0, -2.0, 2.0), 5.0, 1e7), ("desk.toml", (0.1, 0.05, 0.3), 0.5, 1e5)],
)
def test_reel_plant_holds_the_statics_distribution_at_rest(
    cfg_name: str, pose: tuple[float, float, float], mass_kg: float, ea_n: float
) -> None:
    _, reels, turns, rp, statics = reel_plant(cfg_name, pose, mass_kg, ea_n)
    for _ in range(200):
        torques = rp.step(turns, 0.001)
    assert math.dist(rp.position_m, pose) < 1e-9
    assert rp.tensions_n == pytest.approx(statics.tensions_n, rel=1e-6)
    # each motor reports the torque that holds its cable's tension (work balance)
    for reel, p, tau, t in zip(reels, turns, torques, statics.tensions_n, strict=True):
        assert tau == pytest.approx(reel.torque_nm(p, t), rel=1e-6)
        assert reel.tension_n(p, tau) == pytest.approx(t, rel=1e-6)
    assert rp.torques_nm == torques


@pytest.mark.parametrize(
    ("cfg_name", "pose", "mass_kg", "ea_n", "slack", "hold_s"),
    [
        # shallow cables, off-centre: the effector drops on cables 1, 2, 4 and cable 3 goes
        # slack (the swing on them rings down slowly: only the effector's drag damps it)
        ("paper-acre.toml", (-6.55, -8.6, 2.63), 5.0, 1e6, 2, 15.0),
        # at the centre it swings onto the 2-4 diagonal: cable 1 slack, cable 3 at 0.1 N
        ("paper-acre.toml", (0.0, 0.0, 2.0), 5.0, 1e6, 0, 10.0),
        # steep cables: the other three keep the effector in place, cable 1 goes slack
        ("desk.toml", (0.0, 0.0, 0.1), 0.5, 1e5, 0, 4.0),
    ],
)
def test_reel_plant_paying_one_cable_out_5cm_leaves_a_slack_cable_and_statics_on_three(
    cfg_name: str,
    pose: tuple[float, float, float],
    mass_kg: float,
    ea_n: float,
    slack: int,
    hold_s: float,
) -> None:
    from controller.core.statics import CableStatics

    _, reels, turns, rp, _ = reel_plant(cfg_name, pose, mass_kg, ea_n)
    target = list(turns)
    target[0] = reels[0].position_rev(reels[0].length_m(turns[0]) + 0.05)
    steps = 400  # pay out over 0.4 s, then hold
    for k in range(1, steps + 1):
        rp.step([a + (b - a) * k / steps for a, b in zip(turns, target, strict=True)], 0.001)
    for _ in range(round(hold_s / 0.001)):
        torques = rp.step(target, 0.001)
    assert math.hypot(*rp.plant.velocity_mps) < 1e-5
    tensions = [r.tension_n(p, tau) for r, p, tau in zip(reels, target, torques, strict=True)]
    assert tensions[slack] == 0.0
    taut = [i for i in range(4) if i != slack]
    anchors = [rp.plant.params.anchors_m[i] for i in taut]
    three = CableStatics(anchors, 0.0, 1e9).solve(rp.position_m, mass_kg)
    assert [tensions[i] for i in taut] == pytest.approx(three.tensions_n, rel=1e-4)


def test_reel_plant_refuses_bad_inputs_and_keeps_its_state() -> None:
    from controller.core.plant import ReelPlant

    _, reels, turns, rp, _ = reel_plant("desk.toml", (0.0, 0.0, 0.1), 0.5, 1e5)
    before = (rp.position_m, rp.tensions_n)
    with pytest.raises(PlantError, match="4 reels need as many positions"):
        rp.step(turns[:3], 0.001)
    with pytest.raises(PlantError, match="dt_s"):
        rp.step(turns, 0.0)
    assert (rp.position_m, rp.tensions_n) == before
    with pytest.raises(ValueError, match="as many reels"):
        ReelPlant(rp.plant.params, reels[:3], (0.0, 0.0, 0.1), turns)
    with pytest.raises(PlantError, match="finite"):
        ReelPlant(rp.plant.params, reels, (0.0, 0.0, 0.1), [math.nan, 0.0, 0.0, 0.0])


# --- reels in torque control (the pre-tension) ---------------------------------------------


def _pull_until_still(rp, pulls, speeds, dt=0.001, max_s=60.0, still_mps=1e-4):  # type: ignore[no-untyped-def]
    """Step `rp` with every reel in torque control until the effector has been slower than
    `still_mps` for 1 s; returns the simulated seconds it took."""
    still = 0
    steps = 0
    while steps * dt < max_s:
        rp.step(rp.positions_rev, dt, pulls, speeds)
        steps += 1
        still = still + 1 if math.hypot(*rp.plant.velocity_mps) < still_mps else 0
        if still * dt >= 1.0:
            return steps * dt
    raise AssertionError(f"not still after {max_s} s: at {rp.position_m}")


@pytest.mark.parametrize(
    ("cfg_name", "pose", "mass_kg", "ea_n", "slips_m"),
    [
        # the paper robot's 48 m lines stretch 25 mm under their 104 N: a slip must exceed that
        ("paper-acre.toml", (3.0, -2.0, 2.0), 5.0, 2e5, (0.04, 0.03)),
        ("desk.toml", (0.1, 0.05, 0.3), 0.5, 1e5, (0.02, 0.01)),
    ],
)
def test_reels_pulling_the_statics_torques_hold_the_pose_and_draw_the_effector_back_to_it(
    cfg_name: str,
    pose: tuple[float, float, float],
    mass_kg: float,
    ea_n: float,
    slips_m: tuple[float, float],
) -> None:
    _, reels, turns, rp, statics = reel_plant(cfg_name, pose, mass_kg, ea_n)
    pulls = [r.torque_nm(p, t) for r, p, t in zip(reels, turns, statics.tensions_n, strict=True)]
    speeds = [abs(r.velocity_rps(p, 0.05)) for r, p in zip(reels, turns, strict=True)]
    # at the pose, pulling exactly what holds it: nothing moves, the torques are the pulls
    torques = rp.step(turns, 0.001, pulls, speeds)
    assert torques == pytest.approx(pulls, rel=1e-12)
    assert math.dist(rp.position_m, pose) < 1e-9
    assert list(rp.tensions_n) == pytest.approx(statics.tensions_n, rel=1e-6)
    # two cables slip off their drums by more than they stretch: slack, the effector falls onto
    # the others; the reels wind them in (at most 0.05 m/s) and the constant pulls draw it back
    rp.slip(1, slips_m[0])
    rp.slip(3, slips_m[1])
    rp.step(rp.positions_rev, 0.001, pulls, speeds)
    assert rp.tensions_n[1] == 0.0 and rp.tensions_n[3] == 0.0
    took = _pull_until_still(rp, pulls, speeds)
    assert math.dist(rp.position_m, pose) < 1e-3, (rp.position_m, took)
    assert list(rp.tensions_n) == pytest.approx(statics.tensions_n, rel=1e-3)
    # and the reels that slipped are where the geometry wants them again: the slips wound in
    assert rp.positions_rev[1] - turns[1] == pytest.approx(
        -slips_m[0] / reels[1].length_rate_mps(turns[1], 1.0), rel=0.05
    )
    assert rp.positions_rev[3] - turns[3] == pytest.approx(
        -slips_m[1] / reels[3].length_rate_mps(turns[3], 1.0), rel=0.05
    )


def test_a_slack_cable_is_wound_in_no_faster_than_the_speed_limit() -> None:
    _, reels, turns, rp, statics = reel_plant("desk.toml", (0.0, 0.0, 0.1), 0.5, 1e5)
    rp.slip(0, 0.1)  # 10 cm of slack on cable 1
    pulls: list[float | None] = [
        reels[0].torque_nm(turns[0], statics.tensions_n[0]),
        None,
        None,
        None,
    ]
    speed_rps = abs(reels[0].velocity_rps(turns[0], 0.05))  # 0.05 m/s of cable
    start = rp.positions_rev[0]
    for _ in range(100):  # 0.1 s: 5 mm at most, still slack
        rp.step(turns, 0.001, pulls, [speed_rps, 0.0, 0.0, 0.0])
    wound_m = abs(reels[0].length_m(rp.positions_rev[0]) - reels[0].length_m(start))
    assert wound_m == pytest.approx(0.005, rel=1e-6)
    assert rp.tensions_n[0] == 0.0
    assert rp.torques_nm[0] == pulls[0]  # the motor makes its torque, slack or not
    assert rp.positions_rev[1:] == tuple(turns[1:])  # position-controlled reels: as given


def test_a_torque_that_pays_out_lets_the_reel_run_at_the_speed_limit() -> None:
    _, reels, turns, rp, _ = reel_plant("desk.toml", (0.0, 0.0, 0.1), 0.5, 1e5)
    speed_rps = 2.0
    push = -reels[2].torque_nm(turns[2], 1.0)  # the torque of a cable that would push
    for _ in range(10):
        rp.step(turns, 0.001, [None, None, push, None], [0.0, 0.0, speed_rps, 0.0])
    assert abs(rp.positions_rev[2] - turns[2]) == pytest.approx(0.02, rel=1e-9)
    assert reels[2].length_m(rp.positions_rev[2]) > reels[2].length_m(turns[2])  # paid out
    with pytest.raises(PlantError, match="pulls_nm"):
        rp.step(turns, 0.001, [None, None, math.nan, None])
