"""Cable stretch: paid-out lengths that put the effector where it is asked (checked against the
physical plant's equilibrium), and the pose of paid-out lengths (FPK with stretch)."""

from __future__ import annotations

import itertools
import math
import tomllib
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.core import kinematics
from controller.core.kinematics import Geometry, KinematicsError
from controller.core.plant import PlantParams, equilibrium
from controller.core.statics import TensionCheck
from controller.core.stretch import CableStretch, StretchError

CONFIG = Path(__file__).resolve().parents[2] / "config"
FAST = settings(max_examples=40, deadline=None, derandomize=True)
MASS_KG = 5.0
SIX_POSES = [(0, 0, 2), (20, 10, 2), (-30, -18, 1), (0, 0, 6), (35, 20, 3), (10, -5, 0.5)]


def anchors_of(name: str) -> list[tuple[float, float, float]]:
    with (CONFIG / name).open("rb") as f:
        reels = tomllib.load(f)["reels"]
    return [tuple(r["anchor_m"]) for r in reels]


PAPER = anchors_of("paper-acre.toml")
DESK = anchors_of("desk.toml")


def model(
    ea_n: float | list[float | None],
    anchors: list[tuple[float, float, float]] = PAPER,
    mass_kg: float = MASS_KG,
    t_max_n: float = 2000.0,
) -> CableStretch:
    ea = ea_n if isinstance(ea_n, list) else [ea_n] * len(anchors)
    return CableStretch(Geometry(anchors), ea, TensionCheck(anchors, mass_kg, 5.0, t_max_n))


@pytest.mark.parametrize("ea_n", [1e6, 2e5])
@pytest.mark.parametrize("target", SIX_POSES)
def test_paid_out_lengths_put_the_plant_at_the_target(
    ea_n: float, target: tuple[float, ...]
) -> None:
    m = model(ea_n)
    params = PlantParams(PAPER, ea_n, MASS_KG)
    paid, tensions = m.ipk(target)
    eq = equilibrium(params, paid, guess_m=target)
    assert math.dist(eq.position_m, target) < 1e-6
    assert eq.tensions_n == pytest.approx(tensions, rel=1e-6)
    # the rigid model's lengths put it millimetres to a metre away (the figures of the docs)
    rigid = equilibrium(params, kinematics.ipk_point(m.geometry, target), guess_m=target)
    assert math.dist(rigid.position_m, target) > 5e-3


@pytest.mark.parametrize("ea_n", [1e6, 2e5])
@pytest.mark.parametrize("target", SIX_POSES)
def test_fpk_inverts_ipk_cold_and_warm(ea_n: float, target: tuple[float, ...]) -> None:
    m = model(ea_n)
    paid, tensions = m.ipk(target)
    cold = m.fpk(paid)
    assert math.dist(cold.position_m, target) < 1e-6
    warm = m.fpk(paid, guess_m=(target[0] + 0.01, target[1] - 0.02, target[2] + 0.01))
    assert math.dist(warm.position_m, target) < 1e-9
    assert warm.residual_m < 1e-7  # computed before the last (sub-0.1 um) step
    assert warm.tensions_n == pytest.approx(tensions, rel=1e-6)
    at_rest = m.fpk(paid, guess_m=warm.position_m)
    assert math.dist(at_rest.position_m, target) < 1e-9


def test_fixed_point_iteration_diverges_where_the_fpk_converges() -> None:
    """Near the anchor plane the stretch's derivative outgrows the geometry's: "pose ->
    tensions -> stretch -> rigid FPK" runs away, the Gauss-Newton solve does not."""
    m = model(2e5)
    target = (0.0, 0.0, 6.0)
    paid, _ = m.ipk(target)
    p = (0.0, 0.0, 5.99)
    errors = []
    for _ in range(6):
        try:
            p = kinematics.fpk(m.geometry, m.stretched_m(paid, m.tensions_n(p))).position_m
        except KinematicsError:
            errors.append(math.inf)
            break
        errors.append(math.dist(p, target))
    assert errors[-1] > errors[0] > 1e-3  # it moves away
    assert math.dist(m.fpk(paid, guess_m=(0.0, 0.0, 5.99)).position_m, target) < 1e-9


@FAST
@given(
    x=st.floats(-0.35, 0.35),
    y=st.floats(-0.35, 0.35),
    z=st.floats(0.05, 0.6),
    log_ea=st.floats(4.0, 7.0),
    dx=st.floats(-0.005, 0.005),
)
def test_desk_round_trip(x: float, y: float, z: float, log_ea: float, dx: float) -> None:
    m = model(10.0**log_ea, DESK, mass_kg=0.5, t_max_n=500.0)
    target = (x, y, z)
    try:
        paid, _ = m.ipk(target)
    except StretchError:
        return
    res = m.fpk(paid, guess_m=(x + dx, y - dx, z))
    assert math.dist(res.position_m, target) < 1e-7
    params = PlantParams(DESK, 10.0**log_ea, 0.5)
    eq = equilibrium(params, paid, guess_m=target)
    assert math.dist(eq.position_m, target) < 1e-6


def test_measured_tensions_give_the_pose_in_one_rigid_fpk() -> None:
    m = model(2e5)
    target = (20.0, 10.0, 2.0)
    paid, tensions = m.ipk(target)
    res = m.fpk_measured(paid, tensions)
    assert math.dist(res.position_m, target) < 1e-7
    assert res.iterations == 0
    # a tension 10 % off moves the pose
    off = [t * 1.1 for t in tensions]
    assert math.dist(m.fpk_measured(paid, off).position_m, target) > 1e-3


def test_rigid_cables_are_the_rigid_kinematics() -> None:
    m = model([None, None, None, None])
    target = (3.0, -4.0, 2.5)
    paid, _ = m.ipk(target)
    assert paid == pytest.approx(kinematics.ipk_point(m.geometry, target), abs=0.0)
    assert m.fpk(paid).position_m == pytest.approx(target, abs=1e-9)
    mixed = model([2e5, None, 2e5, None])
    paid, _tensions = mixed.ipk(target)
    assert paid[1] == kinematics.ipk_point(m.geometry, target)[1]
    assert paid[0] < kinematics.ipk_point(m.geometry, target)[0]
    assert math.dist(mixed.fpk(paid).position_m, target) < 1e-6


def test_bad_inputs_raise_named_errors() -> None:
    with pytest.raises(KinematicsError, match="EA"):
        model([1e5, 0.0, 1e5, 1e5])
    with pytest.raises(KinematicsError, match="EA"):
        model([1e5, math.nan, 1e5, 1e5])
    with pytest.raises(KinematicsError, match="4 cables"):
        model([1e5, 1e5, 1e5])
    m = model(1e6)
    with pytest.raises(KinematicsError):
        m.fpk([10.0, math.nan, 10.0, 10.0])
    with pytest.raises(KinematicsError):
        m.fpk([10.0, 10.0, 10.0])
    with pytest.raises(KinematicsError):
        m.fpk([50.0] * 4, guess_m=(math.inf, 0.0, 0.0))
    with pytest.raises(StretchError, match="no cable tensions"):
        m.ipk((0.0, 0.0, 7.62))  # in the anchor plane: nothing pulls up
    with pytest.raises(KinematicsError):
        m.paid_out_m([1.0, 2.0], [1.0, 2.0])


@pytest.mark.parametrize(("step_m", "bound_m"), [(0.0005, 5e-6), (0.004, 1e-5), (0.008, 2e-5)])
def test_warm_started_along_a_path_the_fpk_stays_within_micrometres(
    step_m: float, bound_m: float
) -> None:
    """The loop's use: one call per tick, warm-started from the last pose, statics solves
    reused while close (the linearisation's error is largest close under the anchors, with
    soft cables)."""
    m = model(2e5)
    path = [(0.3 * step_m * k, step_m * k, 6.0 - 0.2 * step_m * k) for k in range(120)]
    last = path[0]
    worst = 0.0
    for p in path:
        res = m.fpk(m.ipk(p)[0], guess_m=last)
        worst = max(worst, math.dist(res.position_m, p))
        last = res.position_m
    assert worst < bound_m
    # at rest: repeated solves of the same lengths settle on the pose
    paid = m.ipk(path[-1])[0]
    for _ in range(3):
        last = m.fpk(paid, guess_m=last).position_m
    assert math.dist(last, path[-1]) < 2e-6


def test_inconsistent_lengths_across_a_kink_of_the_tension_distribution_give_a_pose() -> None:
    """Where the cable that limits the planned distribution changes, the tensions have a kink;
    with lengths that disagree by centimetres (a move on a loaded host) the linearised passes
    step across it. The solve still returns its best pose (the loop's residual check judges
    it), never an error that would fault the loop."""
    m = model(2e5, t_max_n=500.0)  # the paper robot's limits: 5..500 N
    a, b = (0.0, 0.0, 6.0), (35.0, 20.0, 3.0)
    n = int(math.dist(a, b) / 0.004)
    last = None
    for k in range(int(0.25 * n)):
        f = k / n
        p = (a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, a[2] + (b[2] - a[2]) * f)
        paid, _ = m.ipk(p)
        s = math.sin(k * 0.01)
        noisy = [paid[0] + 0.02 * s, paid[1] - 0.01 * s, paid[2] + 0.006, paid[3] - 0.02 * s]
        # (the first call is cold, as after start-up)
        res = m.fpk(noisy, guess_m=last or p)
        assert math.dist(res.position_m, p) < 0.2
        assert res.residual_m < 0.03
        last = res.position_m


def test_a_warm_call_makes_at_most_one_statics_solve(monkeypatch: pytest.MonkeyPatch) -> None:
    """The cost: warm-started a tick from the last pose, a call solves the statics at most once
    (the tension derivative comes analytically with it, no finite differences), however far
    the pose has moved since the derivative was last taken."""
    from controller.core.statics import CableStatics

    m = model(2e5)
    path = [(0.008 * k, 0.002 * k, 6.0 - 0.001 * k) for k in range(80)]  # 8 mm a call, 0.65 m
    paid = [m.ipk(p)[0] for p in path]
    calls = [0]
    units = CableStatics._units

    def counting(self: CableStatics, point_m: Any) -> Any:
        calls[0] += 1
        return units(self, point_m)

    monkeypatch.setattr(CableStatics, "_units", counting)
    last = path[0]
    worst = 0
    for p, lengths in zip(path[1:], paid[1:], strict=True):
        calls[0] = 0
        res = m.fpk(lengths, guess_m=last)
        worst = max(worst, calls[0])
        assert math.dist(res.position_m, p) < 2e-5
        last = res.position_m
    assert worst == 1


def test_the_set_points_tensions_spare_the_fpk_every_statics_solve(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The loop hands the FPK the set-point and the tensions it planned there (solved for the
    tension check): close under the anchors with soft cables, 8 mm a call and the set-point
    2 mm ahead, the FPK solves no statics at all and takes the tension derivative only every
    `JACOBIAN_REUSE_M`, within the accuracy of its own solves."""
    from controller.core.statics import CableStatics
    from controller.core.stretch import JACOBIAN_REUSE_M

    m = model(2e5)
    path = [(0.008 * k, 0.002 * k, 6.0 - 0.001 * k) for k in range(80)]  # 8 mm a call, 0.65 m
    paid = [m.ipk(p)[0] for p in path]
    ahead = []
    for a, b in zip(path[1:], [*path[2:], path[-1]], strict=True):
        sp = (a[0] + 0.25 * (b[0] - a[0]), a[1] + 0.25 * (b[1] - a[1]), a[2] + 0.25 * (b[2] - a[2]))
        ahead.append((sp, m.tensions_n(sp)))
    solves = [0]
    derivatives = [0]
    solve4 = CableStatics._solve4_parts
    derivative = CableStatics.tension_derivative

    def counting_solve(self: CableStatics, *a: Any) -> Any:
        solves[0] += 1
        return solve4(self, *a)

    def counting_derivative(self: CableStatics, *a: Any) -> Any:
        derivatives[0] += 1
        return derivative(self, *a)

    monkeypatch.setattr(CableStatics, "_solve4_parts", counting_solve)
    monkeypatch.setattr(CableStatics, "tension_derivative", counting_derivative)
    last = path[0]
    for p, lengths, planned in zip(path[1:], paid[1:], ahead, strict=True):
        res = m.fpk(lengths, guess_m=last, planned=planned)
        assert math.dist(res.position_m, p) < 2e-5
        last = res.position_m
    assert solves[0] == 0
    travel_m = sum(math.dist(a, b) for a, b in itertools.pairwise(path))
    assert 1 <= derivatives[0] <= travel_m / JACOBIAN_REUSE_M + 2


def test_planned_tensions_far_away_or_not_finite_are_not_used() -> None:
    """Tensions handed in with a point farther than `PLANNED_REUSE_M` from the warm start, not
    finite, or of the wrong count change nothing: the FPK solves the statics itself."""
    from controller.core.stretch import PLANNED_REUSE_M

    p = (20.0, 10.0, 2.0)
    guess = (20.004, 9.997, 2.002)
    paid = model(2e5).ipk(p)[0]
    plain = model(2e5).fpk(paid, guess_m=guess)
    far = (guess[0] + 1.5 * PLANNED_REUSE_M, guess[1], guess[2])
    m = model(2e5)
    wrong = [
        (far, m.tensions_n(far)),  # far: its tensions are right, but for another place
        (guess, (math.nan, 1.0, 1.0, 1.0)),
        (guess, (100.0, 100.0, 100.0)),
    ]
    for planned in wrong:
        m = model(2e5)
        res = m.fpk(paid, guess_m=guess, planned=planned)
        assert math.dist(res.position_m, plain.position_m) < 1e-9, planned
    # close by and right: the same pose
    sp = (p[0] + 0.002, p[1], p[2])
    res = model(2e5).fpk(paid, guess_m=guess, planned=(sp, m.tensions_n(sp)))
    assert math.dist(res.position_m, p) < 1e-6


def test_the_plans_derivative_spares_the_fpk_its_own(monkeypatch: pytest.MonkeyPatch) -> None:
    """The loop asks the statics solve of a new set-point for the tension derivative when the
    FPK would need one there (`wants_derivative`) and hands it over: then the FPK takes no
    derivative of its own, and the poses keep their accuracy."""
    from controller.core.statics import CableStatics
    from controller.core.stretch import JACOBIAN_REUSE_M

    m = model(2e5)
    path = [(0.008 * k, 0.002 * k, 6.0 - 0.001 * k) for k in range(80)]
    paid = [m.ipk(p)[0] for p in path]
    own = [0]
    derivative = CableStatics.tension_derivative

    def counting(self: CableStatics, *a: Any) -> Any:
        own[0] += 1
        return derivative(self, *a)

    monkeypatch.setattr(CableStatics, "tension_derivative", counting)
    last = path[0]
    handed = 0
    for k in range(1, len(path)):
        a, b = path[k], path[min(k + 1, len(path) - 1)]
        sp = (a[0] + 0.25 * (b[0] - a[0]), a[1] + 0.25 * (b[1] - a[1]), a[2] + 0.25 * (b[2] - a[2]))
        want = m.wants_derivative(sp)
        plan = m.check.solve(sp, want)
        if want:
            assert plan.derivative is not None
            m.take_derivative(sp, plan.derivative)
            handed += 1
        res = m.fpk(paid[k], guess_m=last, planned=(sp, plan.tensions_n))
        assert math.dist(res.position_m, path[k]) < 2e-5
        last = res.position_m
    assert own[0] == 0
    travel_m = sum(math.dist(a, b) for a, b in itertools.pairwise(path))
    assert 1 <= handed <= travel_m / JACOBIAN_REUSE_M + 2
    assert not model(2e5).rigid and model(2e5).wants_derivative(path[0])  # none kept yet
    rigid = model([None] * 4)
    assert not rigid.wants_derivative(path[0])
    rigid.take_derivative(path[0], [(0.0, 0.0, 0.0)] * 4)  # kept nowhere, harmless
    assert not rigid.wants_derivative(path[0])


def test_the_same_point_planned_again_with_new_tensions_is_taken() -> None:
    """The loop plans a set-point twice when the payload stops accelerating there (the m a
    share leaves the tensions): the FPK linearises about the tensions handed in last, not the
    ones it kept for the same point (which left the published pose 2.9 mm off at rest)."""
    m = model(2e5)
    sp = (10.0, -5.0, 0.5)
    held = m.tensions_n(sp)
    paid = m.ipk(sp)[0]
    braking = tuple(t + d for t, d in zip(held, (12.0, -7.0, 9.0, -4.0), strict=True))
    m.fpk(paid, guess_m=sp, planned=(sp, braking))
    res = m.fpk(paid, guess_m=(10.0003, -5.0002, 0.4971), planned=(sp, held))
    assert math.dist(res.position_m, sp) < 1e-6
    assert res.tensions_n == pytest.approx(held, rel=1e-6)
