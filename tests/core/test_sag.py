"""Statics and kinematics with the cables' weight: the tensions that hold the payload on
catenaries (a rest pose of the physical plant), the paid-out lengths that put it at the target,
the pose of paid-out lengths, the tension rule at both ends of the cables, and the limit of
massless cables equal to today's statics and stretch."""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from controller.core.kinematics import Geometry
from controller.core.plant import PlantParams
from controller.core.sag import SagError, SagStatics
from controller.core.sag_plan import (
    FPK_REUSE_M,
    PLAN_REUSE_M,
    RELINEARISE_M,
    SagPlanner,
    SagTensionCheck,
)
from controller.core.sag_plant import sag_equilibrium
from controller.core.statics import CableStatics, TensionCheck
from controller.core.stretch import CableStretch

G = 9.80665
PAPER = [(-40.45, -25.0, 7.62), (-40.45, 25.0, 7.62), (40.45, 25.0, 7.62), (40.45, -25.0, 7.62)]
SIX_POSES = [(0, 0, 2), (20, 10, 2), (-30, -18, 1), (0, 0, 6), (35, 20, 3), (10, -5, 0.5)]
EA_N = 4.5e5
DYNEEMA = 0.0083
STEEL = 0.036
FAST = settings(max_examples=25, deadline=None, derandomize=True)
points = st.tuples(st.floats(-36.0, 36.0), st.floats(-21.0, 21.0), st.floats(0.0, 6.0))


def sag_statics(per_m: float, mass_kg: float = 5.0, t_max_n: float = 2000.0) -> SagStatics:
    return SagStatics(CableStatics(PAPER, 5.0, t_max_n), mass_kg, [per_m * G] * 4, [EA_N] * 4)


def check(per_m: float, mass_kg: float = 5.0) -> SagTensionCheck:
    return SagTensionCheck(
        PAPER, mass_kg, 5.0, 500.0, 5.0, "max_tension_n", [per_m * G] * 4, [EA_N] * 4
    )


@pytest.mark.parametrize(("per_m", "mass_kg"), [(DYNEEMA, 5.0), (STEEL, 5.0), (STEEL, 20.0)])
@pytest.mark.parametrize("target", SIX_POSES)
def test_paid_out_lengths_put_the_plant_at_the_target(
    per_m: float, mass_kg: float, target: tuple[float, ...]
) -> None:
    sol = sag_statics(per_m, mass_kg).solve(target)
    params = PlantParams(PAPER, EA_N, mass_kg, cable_mass_kg_per_m=per_m)
    rest = sag_equilibrium(params, sol.paid_out_m, guess_m=(target[0], target[1], target[2] + 0.1))
    assert math.dist(rest.position_m, target) < 1e-7
    assert rest.tensions_n == pytest.approx(sol.anchor_tensions_n, rel=1e-6)
    assert sol.iterations <= 6


@FAST
@given(point=points, per_m=st.sampled_from([DYNEEMA, STEEL]))
def test_the_solution_balances_the_weight_along_the_tangents(
    point: tuple[float, float, float], per_m: float
) -> None:
    sag = sag_statics(per_m)
    try:
        sol = sag.solve(point)
    except SagError:
        assume(False)
        raise
    force = [
        sum(t * d[k] for t, d in zip(sol.effector_tensions_n, sol.directions, strict=True))
        for k in range(3)
    ]
    assert force[0] == pytest.approx(0.0, abs=1e-7)
    assert force[1] == pytest.approx(0.0, abs=1e-7)
    assert force[2] == pytest.approx(5.0 * G, rel=1e-9)
    for i, (ax, ay, az) in enumerate(PAPER):
        # the anchor end carries the cable's weight over its rise (less a stretch's worth)
        rise = az - point[2]
        gained = sol.anchor_tensions_n[i] - sol.effector_tensions_n[i]
        assert gained == pytest.approx(per_m * G * rise, rel=2e-3)
        # each tangent lies in its cable's vertical plane, below the chord
        d = sol.directions[i]
        assert (ax - point[0]) * d[1] - (ay - point[1]) * d[0] == pytest.approx(0.0, abs=1e-9)
        chord_z = rise / sol.chords_m[i]
        assert d[2] < chord_z


@FAST
@given(point=points)
def test_without_cable_weight_it_is_todays_statics_and_stretch(
    point: tuple[float, float, float],
) -> None:
    statics = CableStatics(PAPER, 5.0, 500.0)
    try:
        straight = statics.solve(point, 5.0)
    except ValueError:
        assume(False)
        raise
    sol = SagStatics(statics, 5.0, [0.0] * 4, [EA_N] * 4).solve(point)
    assert sol.effector_tensions_n == pytest.approx(straight.tensions_n, rel=1e-9)
    assert sol.anchor_tensions_n == pytest.approx(straight.tensions_n, rel=1e-9)
    stretch = CableStretch(Geometry(PAPER), [EA_N] * 4, TensionCheck(PAPER, 5.0, 5.0, 500.0))
    paid, _ = stretch.ipk(point)
    assert sol.paid_out_m == pytest.approx(paid, rel=1e-12)
    rigid = SagStatics(statics, 5.0, [0.0] * 4, [None] * 4).solve(point)
    assert rigid.paid_out_m == pytest.approx(rigid.chords_m, rel=1e-13)


@pytest.mark.parametrize("point", [(0.0, 0.0, 2.0), (35.0, 20.0, 3.0)])
def test_newton_takes_a_few_steps_where_a_fixed_point_takes_dozens(
    point: tuple[float, float, float],
) -> None:
    """Steel at 5 kg: the sag angle is a large part of the chord's angle, and the fixed point
    "tangents -> tensions -> tangents" contracts slowly (46 to 92 passes to 1e-9 rad at the six
    poses); the Newton solve takes three or four."""
    sag = sag_statics(STEEL)
    sol = sag.solve(point)
    assert sol.iterations <= 4
    px, py, pz = point
    u = [
        ((ax - px) / c, (ay - py) / c, (az - pz) / c)
        for (ax, ay, az), c in zip(PAPER, sol.chords_m, strict=True)
    ]
    passes = 0
    move = math.inf
    while move > 1e-9 and passes < 200:
        t = sag.statics.solve_directions(u, (0.0, 0.0, sag.weight_n)).tensions_n
        new = []
        for i, (ax, ay, az) in enumerate(PAPER):
            dx, dy = ax - px, ay - py
            span = math.hypot(dx, dy)
            e = sag._hang(i, span, az - pz, t[i] * math.hypot(u[i][0], u[i][1]), 0.0, point)
            a = e.h_n / e.t0_n / span
            new.append((dx * a, dy * a, e.v0_n / e.t0_n))
        move = max(abs(a[2] - b[2]) for a, b in zip(new, u, strict=True))
        u = new
        passes += 1
    assert passes > 40
    # both end at the same tangents
    assert [d[2] for d in u] == pytest.approx([d[2] for d in sol.directions], abs=1e-8)


def test_a_cable_that_would_hang_slack_is_a_named_error() -> None:
    heavy = SagStatics(CableStatics(PAPER, 0.0, 5000.0), 0.5, [2.0 * G] * 4, [EA_N] * 4)
    with pytest.raises(SagError, match="slack"):
        heavy.solve((30.0, 18.0, 0.5))  # 2 kg/m of cable and a 0.5 kg payload


@pytest.mark.parametrize(("per_m", "mass_kg"), [(DYNEEMA, 5.0), (STEEL, 5.0), (STEEL, 20.0)])
@pytest.mark.parametrize("base", SIX_POSES)
def test_linearised_plans_are_within_a_tenth_of_a_millimetre(
    per_m: float, mass_kg: float, base: tuple[float, ...]
) -> None:
    sag = sag_statics(per_m, mass_kg)
    planner = SagPlanner(sag, Geometry(PAPER))
    first = planner.plan(base)
    assert first.iterations > 0  # a full solve: the base
    for d in [(1, 0, 0), (0, 1, 0), (0, 0, 1), (-0.6, 0.6, -0.53)]:
        n = math.sqrt(sum(v * v for v in d))
        q = tuple(b + 0.999 * PLAN_REUSE_M * v / n for b, v in zip(base, d, strict=True))
        lin = planner.plan(q)
        assert lin.iterations == 0  # linearised from the base
        exact = sag.solve(q, first)
        err = max(abs(a - b) for a, b in zip(lin.paid_out_m, exact.paid_out_m, strict=True))
        assert err < 0.1e-3
        assert lin.anchor_tensions_n == pytest.approx(exact.anchor_tensions_n, rel=1e-3)
        assert planner.planned(chords_m=exact.chords_m) is lin


@pytest.mark.parametrize(("per_m", "mass_kg"), [(DYNEEMA, 5.0), (STEEL, 5.0), (STEEL, 20.0)])
@pytest.mark.parametrize("target", SIX_POSES)
def test_fpk_inverts_the_plan_cold_and_warm(
    per_m: float, mass_kg: float, target: tuple[float, ...]
) -> None:
    planner = SagPlanner(sag_statics(per_m, mass_kg), Geometry(PAPER))
    sol = planner.plan(target)
    start = (target[0] + 0.008, target[1] - 0.004, target[2] + 0.003)
    warm, residual = planner.fpk(sol.paid_out_m, start, planned_at=target)
    assert math.dist(warm, target) < 1e-9
    assert residual < 1e-9
    cold, _ = planner.fpk(sol.paid_out_m)  # plans of its own on the way: linearised ones
    assert math.dist(cold, target) < 1e-5  # its own solves reused within 2 mm


@pytest.mark.parametrize("per_m", [DYNEEMA, STEEL])
def test_fpk_about_the_set_points_plan_finds_poses_near_it(per_m: float) -> None:
    """The lengths of a pose 5 mm to 2.4 cm from the set-point (the effector lagging or
    leading a moving set-point): the FPK linearised about the set-point's plan finds that pose
    to ten micrometres, with no solve of its own within RELINEARISE_M of it."""
    sag = sag_statics(per_m)
    planner = SagPlanner(sag, Geometry(PAPER))
    target = (20.0, 10.0, 2.0)
    planner.plan(target)
    for offset in [(0.005, 0, 0), (0, -0.012, 0.004), (0.01, 0.01, -0.02)]:
        q = tuple(t + d for t, d in zip(target, offset, strict=True))
        paid = sag.solve(q).paid_out_m
        before = len(planner._plans)
        pose, _ = planner.fpk(paid, q, planned_at=target)
        if math.dist(q, target) <= RELINEARISE_M:
            assert len(planner._plans) == before  # linearised about the set-point's plan
        assert math.dist(pose, q) < 10e-6


def test_tension_rule_refuses_what_the_straight_rule_allows() -> None:
    """At (0, 0, 6) m with 3 mm steel and 5 kg the cables must pull 607 N at the anchors to
    hold the payload and themselves (the straight rule: 360 N)."""
    straight = TensionCheck(PAPER, 5.0, 5.0, 500.0, 5.0)
    assert straight.check((0.0, 0.0, 6.0)) is None
    why = check(STEEL).check((0.0, 0.0, 6.0))
    assert why is not None
    assert "tension 606.7 N at the anchor above 495 N (max_tension_n 500 N" in why
    assert "cables' weight" in why
    assert check(DYNEEMA).check((0.0, 0.0, 6.0)) is None


def test_tension_rule_solve_is_the_plan_with_anchor_tensions() -> None:
    chk = check(STEEL)
    res = chk.solve((20.0, 10.0, 2.0))
    plan = chk.planner.planned(position_m=(20.0, 10.0, 2.0))
    assert plan is not None
    assert res.tensions_n == plan.anchor_tensions_n
    assert res.method == "sag" and res.feasible
    assert res.margin_n == plan.margin_n
    assert chk.reason(res) is None


def test_path_failure_finds_the_first_sample_the_cables_cannot_hold() -> None:
    chk = check(STEEL)
    assert chk.path_failure([(0.0, 0.0, 2.0), (10.0, 5.0, 2.0)], (0.0, 0.0, 2.0), 1.0) is None
    failure = chk.path_failure([(0.0, 0.0, 2.0), (0.0, 0.0, 6.0)], (1.0, 0.0, 2.0), 0.25)
    assert failure is not None
    index, reason = failure
    assert index == 1
    assert reason.startswith("on the leg to it: at [0.0000, 0.0000, 5.7500]: cable ")
    assert "at the anchor above" in reason


@pytest.mark.parametrize("per_m", [DYNEEMA, STEEL])
@pytest.mark.parametrize("point", SIX_POSES)
def test_gradients_match_central_differences_of_full_solves(
    per_m: float, point: tuple[float, ...]
) -> None:
    """The implicit-function gradients of the horizontal forces and of the paid-out lengths
    against central differences of full solves 0.1 mm either side."""
    sag = sag_statics(per_m)
    sol = sag.solve(point)
    dh, dd = sag.gradients(sol)
    step = 1e-4
    for k in range(3):
        up = list(point)
        down = list(point)
        up[k] += step
        down[k] -= step
        a, b = sag.solve(up, sol), sag.solve(down, sol)
        for i in range(4):
            fd_h = (a.horizontal_n[i] - b.horizontal_n[i]) / (2 * step)
            fd_d = ((a.chords_m[i] - a.paid_out_m[i]) - (b.chords_m[i] - b.paid_out_m[i])) / (
                2 * step
            )
            # the planned distribution has kinks (its binding cables change) at symmetric
            # poses: the differences straddle them there
            assert dh[i][k] == pytest.approx(fd_h, rel=1e-3, abs=0.01)
            assert dd[i][k] == pytest.approx(fd_d, abs=2e-5)


def test_a_held_set_points_plan_is_made_exact() -> None:
    """A plan linearised from the base is within micrometres; once the set-point is held the
    planner solves it exactly, and the FPK about it finds that point to rounding."""
    sag = sag_statics(STEEL)
    planner = SagPlanner(sag, Geometry(PAPER))
    planner.plan((35.0, 20.0, 3.0))
    target = (35.006, 20.005, 3.004)
    lin = planner.plan(target)
    assert lin.iterations == 0
    exact = planner.refine(lin.chords_m)
    assert exact is not None and exact.iterations > 0
    assert planner.planned(chords_m=lin.chords_m) is exact
    assert exact.paid_out_m == pytest.approx(sag.solve(target).paid_out_m, abs=1e-9)
    assert max(abs(a - b) for a, b in zip(lin.paid_out_m, exact.paid_out_m, strict=True)) > 1e-9
    pose, _ = planner.fpk(exact.paid_out_m, target, planned_at=target)
    assert math.dist(pose, target) < 1e-9
    assert planner.refine(exact.chords_m) is exact  # exact already: nothing solved
    assert planner.refine((1.0, 2.0, 3.0, 4.0)) is None


@pytest.mark.parametrize("per_m", [DYNEEMA, STEEL])
@pytest.mark.parametrize("sp", [(20, 10, 2), (35, 20, 3), (-30, -18, 1), (0, 0, 5.5)])
def test_fpk_error_while_lagging_a_moving_set_point(
    per_m: float, sp: tuple[float, float, float]
) -> None:
    """The effector lags a moving set-point: the FPK about the set-point's plan, the pose up to
    5 cm behind it, errs by at most 0.15 mm (the figures of FPK_REUSE_M), with no solve of its
    own."""
    sag = sag_statics(per_m)
    planner = SagPlanner(sag, Geometry(PAPER))
    planner.plan(sp)
    lag = 0.95 * FPK_REUSE_M / math.sqrt(3.0)
    p = (sp[0] - lag, sp[1] - lag, sp[2] - lag)
    paid = sag.solve(p).paid_out_m
    pose, _ = planner.fpk(paid, p, planned_at=sp)
    assert planner._own is None
    assert math.dist(pose, p) < 0.15e-3


def test_checks_along_a_braking_path_linearise_from_their_own_solves(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Velocity mode checks points ahead every tick: within PLAN_REUSE_M of a solve the check
    made before, the tensions come from the linearised horizontal forces (no solve), within a
    tenth of a newton of the exact ones; the verdicts are the exact solves'."""
    chk = check(STEEL)
    solves = 0
    solve = SagStatics.solve

    def counting(self: SagStatics, *a: Any, **k: Any) -> Any:
        nonlocal solves
        solves += 1
        return solve(self, *a, **k)

    monkeypatch.setattr(SagStatics, "solve", counting)
    points = [(0.0, 0.0, 5.0 + 0.004 * k) for k in range(200)]  # up through the 495 N limit
    verdicts = [chk.check(p) for p in points]
    monkeypatch.setattr(SagStatics, "solve", solve)
    assert solves <= 200 * 0.004 / PLAN_REUSE_M + 2
    for p, why in zip(points, verdicts, strict=True):
        exact = chk.sag.solve(p)
        if abs(exact.margin_n - chk.margin_n) > 0.1:
            assert (why is None) == (exact.margin_n >= chk.margin_n), (p, why)
    assert verdicts[0] is None and verdicts[-1] is not None


HANGPRINTER = [
    (0.0, -1.61098, -0.13153),
    (1.31422, 1.26814, -0.12128),
    (-1.41573, 0.70761, -0.12182),
    (0.0, 0.0, 2.29983),
]


@pytest.mark.parametrize("target", [(0.0, 0.0, 0.3), (0.3, 0.2, 0.5), (-0.4, 0.1, 1.2)])
def test_a_hangprinter_with_heavy_lines_is_put_where_it_is_asked(
    target: tuple[float, float, float],
) -> None:
    """Anchors below the effector (their cables pull down and sideways) and one above; at
    (0, 0, 0.3) m the top cable hangs straight down its vertical. The paid-out lengths put
    the physical plant at the target and the FPK finds it."""
    per_m, ea, mass = 0.0005, 2.0e4, 1.0
    sag = SagStatics(CableStatics(HANGPRINTER, 3.0, 70.0), mass, [per_m * G] * 4, [ea] * 4)
    sol = sag.solve(target)
    params = PlantParams(HANGPRINTER, ea, mass, cable_mass_kg_per_m=per_m)
    rest = sag_equilibrium(params, sol.paid_out_m, guess_m=(target[0], target[1], target[2]))
    assert math.dist(rest.position_m, target) < 1e-7
    planner = SagPlanner(sag, Geometry(HANGPRINTER))
    planner.plan(target)
    pose, _ = planner.fpk(sol.paid_out_m, target, planned_at=target)
    assert math.dist(pose, target) < 1e-9
    # the low cables pull down: their anchor ends carry less than their effector ends
    assert all(
        t1 < t0
        for t0, t1 in zip(sol.effector_tensions_n[:3], sol.anchor_tensions_n[:3], strict=True)
    )
