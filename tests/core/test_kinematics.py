"""Tests of controller.core.kinematics: the paper's examples, failure cases, validation, batch."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.core import kinematics as kin
from controller.core.kinematics import (
    FpkBatchResult,
    FpkResult,
    Geometry,
    KinematicsError,
    SingularGeometryError,
    UnreachableError,
    fpk,
    fpk_batch,
    ipk,
    ipk_point,
    paper_anchors,
    spheres,
    three_spheres,
    three_spheres_equal_height,
)
from controller.core.kinematics.fit import SEED_MISS_FIT_RMS_M

# The paper's constants (section 6): W = 50.0 m, L = 80.9 m, h = 7.62 m; printed anchors.
H = 7.62
B1 = (-40.46, -25.0, H)
B2 = (-40.46, 25.0, H)
B3 = (40.46, 25.0, H)
B4 = (40.46, -25.0, H)


@pytest.fixture
def paper() -> Geometry:
    return Geometry([B1, B2, B3, B4])


# ------------------------------------------------------------------ paper example (a)


def test_example_a_three_radii_48() -> None:
    # The paper's spheres: B1, B2 and (40.46, -25, 7.62) = B4, all radii 48 m.
    x, y, z = three_spheres_equal_height(B1, B2, B4, 48.0, 48.0, 48.0)
    exact_z = H - math.sqrt(48.0**2 - 40.46**2 - 25.0**2)  # = 7.62 - sqrt(41.9884)
    assert exact_z == pytest.approx(1.140154322825, abs=1e-12)
    assert (x, y, z) == pytest.approx((0.0, 0.0, exact_z), abs=1e-12)
    # Printed value (0, 0, 1.16): within 0.05 m, but not a rounding of 1.140.
    assert (x, y, z) == pytest.approx((0.0, 0.0, 1.16), abs=0.05)
    assert abs(z - 1.16) > 0.019
    # Both printed heights are what h = 7.64 m gives (see the module docstring).
    h1, h2, h4 = ((c[0], c[1], 7.64) for c in (B1, B2, B4))
    assert three_spheres_equal_height(h1, h2, h4, 48.0, 48.0, 48.0)[2] == pytest.approx(
        1.16, abs=5e-4
    )
    # Fourth cable (B3) for checking: 48 m.
    assert math.dist((x, y, z), B3) == pytest.approx(48.0, abs=1e-12)


def test_example_a_through_fpk(paper: Geometry) -> None:
    res = fpk(paper, [48.0, 48.0, 48.0, 48.0])
    assert res.position_m == pytest.approx((0.0, 0.0, 1.140154322825), abs=1e-11)
    assert res.residual_m < 1e-12
    assert res.seed_triple == (0, 1, 2)


# ------------------------------------------------------------------ paper example (b)


def test_example_b_printed_third_centre_does_not_give_printed_result() -> None:
    # Reading 1: the centres exactly as printed, third = (40.46, -25, 7.62).
    p = three_spheres_equal_height(B1, B2, B4, 38.0, 48.0, 58.0)
    assert p == pytest.approx((-11.863569, -8.6, -11.281961), abs=1e-6)
    assert math.dist(p, (-6.55, -8.60, 2.63)) > 10.0
    # The remaining anchor (40.46, 25) would then be 64.99 m, not 50.04 m.
    assert math.dist(p, B3) == pytest.approx(64.992307, abs=1e-6)


def test_example_b_third_centre_at_plus_25_reproduces_paper() -> None:
    # Reading 2: third centre (40.46, +25, 7.62) reproduces the printed P ...
    p = three_spheres_equal_height(B1, B2, B3, 38.0, 48.0, 58.0)
    assert p == pytest.approx((-6.55, -8.60, 2.63), abs=0.05)
    assert p == pytest.approx((-6.549678695, -8.6, 2.607005985), abs=1e-8)
    # ... and the "fourth cable 50.04 m" is the anchor at (40.46, -25, 7.62).
    assert math.dist(p, B4) == pytest.approx(50.04, abs=0.005)
    assert math.dist(p, B4) == pytest.approx(50.039984013, abs=1e-8)
    # The general algorithm agrees.
    assert three_spheres(B1, B2, B3, 38.0, 48.0, 58.0) == pytest.approx(p, abs=1e-12)


def test_example_b_through_fpk(paper: Geometry) -> None:
    l4 = math.dist((-6.549678695007414, -8.6, 2.6070059852253893), B4)
    res = fpk(paper, [38.0, 48.0, 58.0, l4])
    assert res.position_m == pytest.approx((-6.549678695, -8.6, 2.607005985), abs=1e-8)
    assert res.residual_m < 1e-12
    # With the paper's rounded 50.04 the fit is a hair off and says so.
    rounded = fpk(paper, [38.0, 48.0, 58.0, 50.04])
    assert rounded.position_m == pytest.approx((-6.55, -8.60, 2.61), abs=0.01)
    assert 1e-6 < rounded.residual_m < 1e-4


# ------------------------------------------------------------------ paper example (c)


def _circle() -> np.ndarray:
    t = np.arange(72) * (2.0 * math.pi / 72)
    return np.column_stack([20.0 * np.cos(t), 20.0 * np.sin(t), np.full(72, 2.0)])


def test_example_c_circle_single(paper: Geometry) -> None:
    pts = _circle()
    lengths = ipk(paper, pts)
    assert lengths.shape == (72, 4)
    for p, ln in zip(pts, lengths, strict=True):
        assert np.max(np.abs(np.array(fpk(paper, ln).position_m) - p)) < 1e-9
        # The bare simplified algorithm on the first three cables, as in the paper.
        q = three_spheres_equal_height(B1, B2, B3, *ln[:3].tolist())
        assert np.max(np.abs(np.array(q) - p)) < 1e-9
        assert ipk_point(paper, tuple(p)) == pytest.approx(tuple(ln), abs=1e-12)


def test_example_c_circle_batch(paper: Geometry) -> None:
    pts = _circle()
    res = fpk_batch(paper, ipk(paper, pts))
    assert res.valid.all()
    assert np.max(np.abs(res.position_m - pts)) < 1e-9
    assert np.max(res.residual_m) < 1e-12


# ------------------------------------------------------------------ failure cases


def test_singular_layout_refused_at_construction() -> None:
    # Three anchors collinear in plan view (eq. 14), even at different heights.
    with pytest.raises(SingularGeometryError, match=r"eq\. 14"):
        Geometry([(0.0, 0.0, 5.0), (10.0, 5.0, 5.0), (20.0, 10.0, 5.0)])
    with pytest.raises(SingularGeometryError):
        Geometry([(0.0, 0.0, 5.0), (10.0, 0.0, 7.0), (20.0, 0.0, 9.0), (30.0, 0.0, 5.0)])
    # The bare functions refuse too.
    with pytest.raises(SingularGeometryError):
        three_spheres_equal_height((0, 0, 5), (1, 1, 5), (2, 2, 5), 3.0, 3.0, 3.0)
    with pytest.raises(SingularGeometryError):
        three_spheres((0, 0, 5), (1, 1, 6), (2, 2, 7), 3.0, 3.0, 3.0)


def test_rectangle_is_not_singular_but_collinear_triples_are_dropped() -> None:
    # Paper eq. 16: a centred rectangle is never singular.
    assert len(Geometry(paper_anchors()).triples) == 4
    # A fifth anchor on an edge's midpoint makes the triples along that edge unusable.
    g = Geometry([B1, B2, B3, B4, (0.0, 25.0, H)])
    assert (1, 2, 4) not in g.triples
    assert len(g.triples) == 10 - 1


def test_too_short_cable_raises_naming_it(paper: Geometry) -> None:
    good = ipk(paper, (5.0, -3.0, 1.0))
    bad = good.copy()
    bad[2] = 20.0  # cable 3 far too short
    with pytest.raises(UnreachableError, match="cable 3 is too short") as ei:
        fpk(paper, bad)
    assert ei.value.cable == 3
    assert ei.value.shortfall_m > 1.0
    # Lengthening cable 3 by the reported shortfall makes the seed triple just meet ...
    just = bad.copy()
    just[2] += ei.value.shortfall_m + 1e-9
    tangent = three_spheres_equal_height(B1, B2, B3, *just[:3].tolist())
    assert tangent[2] == pytest.approx(H, abs=1e-2)
    # (the least-squares fit then pulls P down, and its residual says cable 4 disagrees)
    res = fpk(paper, just)
    assert res.position_m[2] < H - 1.0
    assert res.residual_m > 0.1
    # ... and a little less does not.
    bad[2] += ei.value.shortfall_m - 1e-6
    with pytest.raises(UnreachableError) as ei2:
        fpk(paper, bad)
    assert 0.0 < ei2.value.shortfall_m < 2e-6


def test_a_seed_triple_missed_by_noise_near_the_anchors_plane_is_fitted_over_every_cable() -> None:
    # Five anchors at one height, the effector 0.5 m below them: the seed triple's spheres meet
    # at a grazing angle, and cable 1 a centimetre long makes them miss each other (the control
    # loop faulted "fpk_unreachable" on such noise). The other cables say where the effector is.
    g = Geometry(
        [(0.0, -14.0, 2.0), (3.0, 0.0, 2.0), (3.0, 13.0, 2.0), (0.0, 0.0, 2.0), (1.0, 3.0, 2.0)]
    )
    assert 0 in g.seed_triple
    p = (2.0, 8.0, 1.5)
    lengths = ipk(g, p)
    lengths[0] += 0.01
    sd = g.seed_triple
    with pytest.raises(UnreachableError):
        three_spheres_equal_height(*(g.anchors_m[i] for i in sd), *(lengths[i] for i in sd))
    res = fpk(g, lengths)
    assert res.seed_triple != g.seed_triple
    # the least-squares point, found by an independent solver
    from scipy.optimize import least_squares

    ref = least_squares(
        lambda q: np.linalg.norm(q - g.anchors_m, axis=1) - lengths,
        np.array(p),
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
    ).x
    # (z is poorly determined this close to the anchors' plane: the cost is flat along it)
    assert res.position_m == pytest.approx(ref.tolist(), abs=1e-6)
    at = np.linalg.norm(np.array(res.position_m) - g.anchors_m, axis=1) - lengths
    at_ref = np.linalg.norm(ref - g.anchors_m, axis=1) - lengths
    assert res.residual_m == pytest.approx(math.sqrt(float(np.mean(at**2))), abs=1e-12)
    assert res.residual_m == pytest.approx(math.sqrt(float(np.mean(at_ref**2))), rel=1e-9)
    assert 1e-3 < res.residual_m < SEED_MISS_FIT_RMS_M
    batch = fpk_batch(g, np.vstack([lengths, lengths]))
    assert batch.valid.all()
    assert batch.position_m[0] == pytest.approx(res.position_m, abs=1e-12)
    # A cable far too long is still named: no point explains the lengths.
    lengths[0] += 1.0
    with pytest.raises(UnreachableError, match="cable 1 is too long"):
        fpk(g, lengths)


def test_too_long_cable_is_named_as_such(paper: Geometry) -> None:
    good = ipk(paper, (5.0, -3.0, 1.0))
    bad = good.copy()
    bad[1] = 120.0  # cable 2 longer than cables 1 and 3 can allow
    with pytest.raises(UnreachableError, match="cable 2 is too long") as ei:
        fpk(paper, bad)
    assert ei.value.shortfall_m < -1.0
    bad[1] += ei.value.shortfall_m - 1e-9
    assert three_spheres(B1, B2, B3, *bad[:3].tolist())[2] == pytest.approx(H, abs=1e-2)


def _meets(fn: object, cs: list[tuple[float, float, float]], r: list[float]) -> bool:
    try:
        fn(*cs, *r)  # type: ignore[operator]
    except UnreachableError:
        return False
    return True


@pytest.mark.parametrize("fn", [three_spheres_equal_height, three_spheres])
@pytest.mark.parametrize(("k", "value"), [(1, 20.0), (0, 15.0), (2, 200.0), (1, 70.0)])
def test_bare_functions_name_the_smallest_single_fix(fn: object, k: int, value: float) -> None:
    cs = [B1, B2, B3]
    r = [math.dist((5.0, -3.0, 1.0), c) for c in cs]
    r[k] = value
    with pytest.raises(UnreachableError, match=r"r[123] is too (short|long)") as ei:
        fn(*cs, *r)  # type: ignore[operator]
    named, change = ei.value.cable - 1, ei.value.shortfall_m
    assert ("short" in str(ei.value)) == (change > 0.0)
    # The reported change of the named sphere makes the three meet (tangent) ...
    fixed = list(r)
    fixed[named] += change + math.copysign(1e-9, change)
    assert _meets(fn, cs, fixed)
    # ... and no single sphere changed by 99.9 % of that amount, either way, does.
    for j in range(3):
        for sign in (1.0, -1.0):
            trial = list(r)
            trial[j] += sign * 0.999 * abs(change)
            assert not _meets(fn, cs, trial)


def test_tangent_is_accepted() -> None:
    # All three cables exactly reaching the circumcentre in the anchor plane.
    r = math.dist((0.0, 0.0), (40.46, 25.0))
    x, y, z = three_spheres_equal_height(B1, B2, B3, r, r, r)
    # z = H - sqrt(rounding): the square root magnifies 1e-12 m^2 to 1e-6 m.
    assert (x, y, z) == pytest.approx((0.0, 0.0, H), abs=1e-5)
    assert three_spheres(B1, B2, B3, r, r, r) == pytest.approx((0.0, 0.0, H), abs=1e-5)


def test_bad_lengths(paper: Geometry) -> None:
    with pytest.raises(KinematicsError, match="expected 4"):
        fpk(paper, [48.0, 48.0, 48.0])
    for v in (math.nan, math.inf, -1.0, 0.0):
        with pytest.raises(KinematicsError, match="cable 2"):
            fpk(paper, [48.0, v, 48.0, 48.0])
    with pytest.raises(KinematicsError):
        fpk(paper, np.ones((2, 2, 4)))
    with pytest.raises(KinematicsError):
        ipk(paper, (1.0, math.nan, 0.0))
    with pytest.raises(KinematicsError):
        ipk_point(paper, (1.0, math.inf, 0.0))
    with pytest.raises(KinematicsError):
        ipk(paper, (1.0, 2.0))


def test_unequal_heights_refused_by_simplified() -> None:
    with pytest.raises(KinematicsError, match="three_spheres"):
        three_spheres_equal_height(B1, B2, (40.46, 25.0, 7.0), 40.0, 40.0, 40.0)


# ------------------------------------------------------------------ geometry validation


@pytest.mark.parametrize(
    "anchors",
    [
        [(0, 0, 1), (1, 0, 1)],  # N < 3
        [(0, 0), (1, 0), (0, 1)],  # wrong shape
        [[(0, 0, 1)] * 3],  # 3-D
        [(0, 0, 1), (1, 0, math.nan), (0, 1, 1)],
        [(0, 0, 1), (1, 0, math.inf), (0, 1, 1)],
        [(0, 0, 1), (1, 0, "a"), (0, 1, 1)],
    ],
)
def test_geometry_rejects_bad_input(anchors: object) -> None:
    with pytest.raises(KinematicsError):
        Geometry(anchors)


def test_geometry_rejects_coincident() -> None:
    with pytest.raises(SingularGeometryError, match="anchors 2 and 4 coincide"):
        Geometry([B1, B2, B3, B2])


def test_geometry_properties() -> None:
    g = Geometry([B1, B2, B3, (40.46, -25.0, 9.0)])
    assert g.n_cables == 4
    assert not g.equal_heights
    assert g.anchor_height_min_m == H
    assert g.anchor_height_max_m == 9.0
    # The best triples all have the same area; the equal-height one is preferred.
    assert g.seed_triple == (0, 1, 2)
    assert g.seed_uses_simplified
    assert Geometry(paper_anchors()).equal_heights
    assert Geometry([B1, B2, (40.46, 25.0, H + 1e-12)]).equal_heights
    assert not Geometry([B1, B2, (40.46, 25.0, H + 1e-6)]).equal_heights
    with pytest.raises(ValueError, match="read-only"):
        g.anchors_m[0, 0] = 1.0


def test_general_seed_when_no_equal_triple() -> None:
    g = Geometry([(-10, -10, 5), (-10, 10, 6), (10, 10, 7), (10, -10, 8.5)])
    assert not g.seed_uses_simplified
    p = (1.5, -2.0, 0.5)
    res = fpk(g, ipk(g, p))
    assert res.position_m == pytest.approx(p, abs=1e-10)


# ------------------------------------------------------------------ general algorithm


def test_general_equals_simplified_for_equal_heights() -> None:
    for r in [(38.0, 48.0, 58.0), (48.0, 48.0, 48.0), (55.0, 50.0, 47.0)]:
        a = three_spheres_equal_height(B1, B2, B3, *r)
        b = three_spheres(B1, B2, B3, *r)
        assert b == pytest.approx(a, abs=1e-10)


def test_general_unequal_heights_hits_the_point() -> None:
    cs = [(-30.0, -20.0, 9.0), (-25.0, 22.0, 6.0), (35.0, 18.0, 12.0)]
    for p in [(0.0, 0.0, 0.0), (10.0, -5.0, 5.9), (-20.0, 10.0, -30.0)]:
        r = [math.dist(p, c) for c in cs]
        assert three_spheres(cs[0], cs[1], cs[2], *r) == pytest.approx(p, abs=1e-10)


def test_point_above_a_tilted_seed_plane_is_found_by_the_other_cables() -> None:
    # Found by hypothesis: the seed triple (anchors 1, 3, 4) is tilted, and P, 0.5 m below
    # the lowest anchor, lies above its plane.  The three spheres' lower solution is then P's
    # mirror image; the fourth cable tells them apart.
    geom = Geometry([[0.0, 1.0, 2.0], [3.0, 0.0, 2.0], [1.0, -1.0, 2.0], [-3.0, 0.0, 3.0]])
    p = (3.0, 0.0, 1.5)
    a = geom.anchors_m[list(geom.seed_triple)].tolist()
    r = [math.dist(p, c) for c in a]
    mirror = three_spheres(a[0], a[1], a[2], *r)
    assert math.dist(mirror, p) > 0.3
    assert mirror[2] < p[2]
    lengths = ipk(geom, p)
    assert fpk(geom, lengths).position_m == pytest.approx(p, abs=1e-9)
    batch = fpk_batch(geom, np.vstack([lengths, lengths + 1e-4]))
    assert batch.valid.all()
    assert batch.position_m[0] == pytest.approx(p, abs=1e-9)
    assert batch.position_m[1] == pytest.approx(fpk(geom, lengths + 1e-4).position_m, abs=1e-9)


def test_lower_solution_is_below_a_tilted_centre_plane() -> None:
    # Steeply tilted centre plane: the other intersection is the mirror image.
    cs = [(0.0, 0.0, 0.0), (10.0, 0.0, 10.0), (0.0, 10.0, 0.0)]
    p = (3.0, 4.0, -2.0)
    r = [math.dist(p, c) for c in cs]
    assert three_spheres(cs[0], cs[1], cs[2], *r) == pytest.approx(p, abs=1e-10)


# ------------------------------------------------------------------ ipk / footprint


def test_ipk_shapes(paper: Geometry) -> None:
    one = ipk(paper, (0.0, 0.0, 1.140154322825))
    assert one.shape == (4,)
    assert one == pytest.approx([48.0] * 4, abs=1e-9)
    many = ipk(paper, [[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])
    assert many.shape == (2, 4)
    assert many[1] == pytest.approx(ipk_point(paper, (1.0, 2.0, 3.0)), abs=1e-12)


# ------------------------------------------------------------------ fpk result types, batch


def test_fpk_types(paper: Geometry) -> None:
    p = (3.0, -4.0, 2.0)
    ln = ipk(paper, p)
    single = fpk(paper, ln)
    assert isinstance(single, FpkResult)
    assert isinstance(single.position_m, tuple)
    assert all(type(v) is float for v in single.position_m)
    assert fpk(paper, tuple(ln.tolist())) == single
    # One pose, one type: many poses at once are fpk_batch's, and fpk refuses them.
    with pytest.raises(KinematicsError, match=r"shape \(N,\).*fpk_batch"):
        fpk(paper, ln[None, :])
    batch = fpk_batch(paper, ln[None, :])
    assert isinstance(batch, FpkBatchResult)
    assert batch.position_m.shape == (1, 3)
    assert tuple(batch.position_m[0]) == pytest.approx(single.position_m, abs=1e-12)


def test_fpk_returns_one_result_type_for_one_pose(paper: Geometry) -> None:
    p = (-7.0, 5.0, 1.5)
    ln = ipk(paper, p)
    for lengths in (ln, ln.tolist(), tuple(ln.tolist()), ln.astype(np.float32)):
        res = fpk(paper, lengths)
        assert type(res) is FpkResult
        assert res.position_m == pytest.approx(p, abs=1e-5)
    # Several poses (even one, as a (1, N) array) are fpk_batch's: fpk refuses them, whatever
    # their number, rather than answering with another type.
    for many in (ln[None, :], np.vstack([ln, ln, ln])):
        with pytest.raises(KinematicsError, match="fpk_batch"):
            fpk(paper, many)
        rows = fpk_batch(paper, many)
        assert type(rows) is FpkBatchResult
        for k in range(many.shape[0]):
            assert tuple(rows.position_m[k]) == pytest.approx(
                fpk(paper, many[k]).position_m, abs=1e-12
            )


def test_fpk_three_cables() -> None:
    g = Geometry([B1, B2, B3])
    p = (-3.0, 4.0, -1.0)
    res = fpk(g, ipk(g, p))
    assert res.position_m == pytest.approx(p, abs=1e-10)
    assert res.residual_m == 0.0


def test_batch_reports_invalid_rows(paper: Geometry) -> None:
    pts = np.array([[0.0, 0.0, 1.0], [5.0, 5.0, 2.0], [-5.0, 3.0, 0.0], [1.0, 1.0, 1.0]])
    lens = ipk(paper, pts)
    lens = np.vstack([lens, lens[:2]])
    lens[1, 2] = 20.0  # cable 3 too short
    lens[2, 0] = math.nan
    lens[3, 3] = -1.0
    lens[4, 1] = math.inf
    res = fpk_batch(paper, lens)
    assert res.valid.tolist() == [True, False, False, False, False, True]
    assert np.all(np.isfinite(res.position_m))
    assert np.all(np.isfinite(res.residual_m))
    assert np.all(res.position_m[~res.valid] == 0.0)
    assert res.short_cable.tolist() == [0, 3, 0, 0, 0, 0]
    assert res.shortfall_m[1] > 1.0
    with pytest.raises(UnreachableError) as ei:
        fpk(paper, lens[1])
    assert ei.value.shortfall_m == pytest.approx(res.shortfall_m[1], rel=1e-9)
    assert res.position_m[0] == pytest.approx(pts[0], abs=1e-9)
    assert res.position_m[5] == pytest.approx(pts[1], abs=1e-9)


def _assert_batch_is_single(geom: Geometry, lens: np.ndarray) -> FpkBatchResult:
    """Every row of fpk_batch equals fpk on that row (or its UnreachableError / refusal)."""
    batch = fpk_batch(geom, lens)
    for k in range(lens.shape[0]):
        try:
            one = fpk(geom, lens[k])
        except UnreachableError as exc:
            assert not batch.valid[k]
            assert batch.short_cable[k] == exc.cable
            assert batch.shortfall_m[k] == pytest.approx(exc.shortfall_m, rel=1e-6, abs=1e-9)
            continue
        except KinematicsError:
            assert not batch.valid[k]
            assert batch.short_cable[k] == 0
            continue
        assert batch.valid[k], k
        assert batch.position_m[k] == pytest.approx(one.position_m, abs=1e-9), k
        assert batch.residual_m[k] == pytest.approx(one.residual_m, rel=1e-6, abs=1e-12), k
    return batch


def test_batch_matches_single_with_noise(paper: Geometry) -> None:
    rng = np.random.default_rng(1)
    pts = np.column_stack(
        [rng.uniform(-35, 35, 300), rng.uniform(-20, 20, 300), rng.uniform(-10, 5, 300)]
    )
    lens = ipk(paper, pts) + rng.normal(0.0, 2e-3, (300, 4))
    batch = _assert_batch_is_single(paper, lens)
    assert batch.valid.all()
    # And the fit is a true least-squares minimum: the gradient J^T r vanishes (to the batch's
    # stopping rule, a predicted remaining step of 1e-10 m).
    d = batch.position_m[:, None, :] - paper.anchors_m[None]
    dist = np.linalg.norm(d, axis=2)
    grad = np.einsum("ijk,ij->ik", d / dist[..., None], dist - lens)
    assert np.max(np.abs(grad)) < 1e-10


def test_planar_batch_every_kind_of_row_across_a_chunk_boundary(paper: Geometry) -> None:
    # Four anchors at one height take the batch's planar path (the single-pose multiplier
    # fit, vectorised); rows it cannot vouch for go to the single-pose code.
    assert paper._p4 is not None
    rng = np.random.default_rng(7)
    m = kin.BATCH_CHUNK + 40
    pts = np.column_stack(
        [rng.uniform(-38, 38, m), rng.uniform(-23, 23, m), rng.uniform(-30.0, 7.0, m)]
    )
    lens = ipk(paper, pts)
    lens[::2] += rng.normal(0.0, 1e-3, (len(lens[::2]), 4))  # noisy; odd rows consistent
    lens[3, 3] += 0.5  # a slack cable: the multiplier fit still vouches for it
    lens[9, 3] += 3.0  # too slack for two Newton steps: the single-pose fit
    lens[5, 1] = 5.0  # far too short: the seed triple cannot meet
    lens[7, 0] = math.nan
    lens[m - 1, 2] = -2.0  # the last, partial chunk has an invalid row too
    lens[m - 3, 3] += 2e-2
    # Only a sample of rows through the scalar fpk (it is the slow side of this test).
    rows = np.r_[0:60, kin.BATCH_CHUNK - 30 : m]
    batch = _assert_batch_is_single(paper, lens[rows])
    assert batch.valid.sum() == rows.size - 3
    full = fpk_batch(paper, lens)
    assert np.array_equal(full.position_m[rows], batch.position_m)
    assert np.array_equal(full.residual_m[rows], batch.residual_m)
    good = full.valid & (np.arange(m) % 2 == 1)
    good[[3, 5, 7, 9, m - 1, m - 3]] = False  # the rows made inconsistent above
    assert np.max(np.abs(full.position_m[good] - pts[good])) < 1e-9


def test_planar_fit_is_the_least_squares_minimum_on_an_irregular_quad() -> None:
    from scipy.optimize import least_squares

    geom = Geometry([(-31.0, -12.0, 9.5), (3.0, 27.0, 9.5), (44.0, 8.0, 9.5), (17.0, -30.0, 9.5)])
    assert geom._p4 is not None and geom._p4.m0 != 0.0
    assert max(abs(c) for c in geom._p4.c) != 1.0
    rng = np.random.default_rng(3)
    pts = np.column_stack(
        [rng.uniform(-10, 20, 50), rng.uniform(-10, 10, 50), rng.uniform(-20.0, 8.0, 50)]
    )
    lens = ipk(geom, pts) + rng.normal(0.0, 5e-3, (50, 4))
    batch = _assert_batch_is_single(geom, lens)
    assert batch.valid.all()
    for k in range(50):

        def res(q: np.ndarray, k: int = k) -> np.ndarray:
            out: np.ndarray = np.linalg.norm(q - geom.anchors_m, axis=1) - lens[k]
            return out

        # The minimum to rounding: the gradient J^T r vanishes.  (scipy stops earlier, with
        # gradients near 1e-9, hence the looser comparison with its point.)
        d = batch.position_m[k] - geom.anchors_m
        dist = np.linalg.norm(d, axis=1)
        assert np.max(np.abs((d / dist[:, None]).T @ (dist - lens[k]))) < 1e-12
        sol = least_squares(res, pts[k], xtol=1e-15, ftol=1e-15, gtol=1e-15)
        assert batch.position_m[k] == pytest.approx(sol.x, abs=1e-7)
        assert batch.residual_m[k] == pytest.approx(math.sqrt(float(np.mean(sol.fun**2))), rel=1e-6)


def test_residual_grows_with_one_perturbed_cable(paper: Geometry) -> None:
    ln = ipk(paper, (2.0, 3.0, 1.0))
    base = fpk(paper, ln).residual_m
    assert base < 1e-12
    prev = base
    for delta in (1e-4, 1e-3, 1e-2, 1e-1):
        bumped = ln.copy()
        bumped[3] += delta
        r = fpk(paper, bumped).residual_m
        assert r > prev
        prev = r


def test_module_has_no_numpy_in_scalar_fast_path() -> None:
    import inspect

    from controller.core.kinematics import fit

    for fn in (
        kin.three_spheres_equal_height,
        kin.three_spheres,
        spheres._seed_equal,
        spheres._equal_xy,
        fit._planar4_solve,
        fit._fit_planar4,
    ):
        assert "np." not in inspect.getsource(fn)
