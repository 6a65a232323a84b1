"""Reel model: known values, exact inverses (hypothesis), homing, validation."""

from __future__ import annotations

import math

import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from controller.core.reel import ReelModel, spool_buildup, spool_buildup_from_factor

EPS = 2.0**-52


def test_plain_drum_known_values() -> None:
    m = ReelModel.from_drum_radius(0.02)
    assert m.metres_per_rev == pytest.approx(2 * math.pi * 0.02)
    assert m.length_m(0.0) == 0.0
    assert m.length_m(10.0) == pytest.approx(10 * 2 * math.pi * 0.02)
    assert m.position_rev(2 * math.pi * 0.02) == pytest.approx(1.0)


def test_gear_direction_and_mechanical_advantage() -> None:
    m = ReelModel(metres_per_rev=0.1, gear_ratio=5.0, direction=-1, mechanical_advantage=2.0)
    # 10 motor turns = 2 drum turns = 0.2 m spooled, wound in (direction -1), halved by the block
    assert m.length_m(10.0) == pytest.approx(-0.1)
    assert m.position_rev(-0.1) == pytest.approx(10.0)
    assert m.length_rate_mps(0.0, 5.0) == pytest.approx(-0.05)
    assert m.velocity_rps(0.0, -0.05) == pytest.approx(5.0)


def test_spool_buildup_known_value() -> None:
    b = spool_buildup(0.001, turns_per_layer=10.0)
    assert b == pytest.approx(2 * math.pi * 0.0001)
    m = ReelModel(metres_per_rev=0.1, spool_buildup_m_per_rev2=0.01)
    # s(n) = 0.1 n - 0.01 n^2 / 2 ; n = 4 -> 0.4 - 0.08 = 0.32
    assert m.length_m(4.0) == pytest.approx(0.32)
    assert m.position_rev(0.32) == pytest.approx(4.0)
    # winding in (negative n) the radius grows: more metres per turn
    assert m.length_m(-4.0) == pytest.approx(-0.48)
    assert m.position_rev(-0.48) == pytest.approx(-4.0)
    # the spool cannot pay out more than its maximum 0.1^2 / (2*0.01) = 0.5 m
    with pytest.raises(ValueError, match="spool"):
        m.position_rev(0.51)


def test_with_home() -> None:
    m = ReelModel.from_drum_radius(0.03, gear_ratio=3.0, reference_length_m=1.2)
    h = m.with_home(position_rev=123.4, length_m=2.5)
    assert h.length_m(123.4) == pytest.approx(2.5, abs=1e-12)
    assert h.position_rev(2.5) == pytest.approx(123.4, abs=1e-12)
    # homing changes only the offset, not the scale
    assert h.length_m(126.4) - h.length_m(123.4) == pytest.approx(2 * math.pi * 0.03)
    assert h.metres_per_rev == m.metres_per_rev
    with pytest.raises(ValueError):
        m.with_home(math.nan, 1.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"metres_per_rev": 0.0}, "metres_per_rev"),
        ({"metres_per_rev": -0.1}, "metres_per_rev"),
        ({"metres_per_rev": math.nan}, "metres_per_rev"),
        ({"metres_per_rev": 0.1, "gear_ratio": 0.0}, "gear_ratio"),
        ({"metres_per_rev": 0.1, "direction": 0}, "direction"),
        ({"metres_per_rev": 0.1, "direction": 2}, "direction"),
        ({"metres_per_rev": 0.1, "mechanical_advantage": -1.0}, "mechanical_advantage"),
        ({"metres_per_rev": 0.1, "spool_buildup_m_per_rev2": -0.01}, "spool_buildup"),
        ({"metres_per_rev": 0.1, "offset_rev": math.inf}, "offset_rev"),
    ],
)
def test_validation(kwargs: dict[str, float], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        ReelModel(**kwargs)  # type: ignore[arg-type]


def test_from_drum_radius_validation() -> None:
    with pytest.raises(ValueError, match="radius"):
        ReelModel.from_drum_radius(0.0)
    with pytest.raises(ValueError, match="cable_diameter"):
        ReelModel.from_drum_radius(0.02, cable_diameter_m=-1.0)


models = st.builds(
    ReelModel,
    metres_per_rev=st.floats(0.005, 1.0),
    gear_ratio=st.floats(0.1, 100.0),
    direction=st.sampled_from([1, -1]),
    mechanical_advantage=st.floats(1.0, 8.0),
    spool_buildup_m_per_rev2=st.one_of(st.just(0.0), st.floats(0.0, 1e-3)),
    offset_rev=st.floats(-1e4, 1e4),
    reference_length_m=st.floats(0.0, 20.0),
)


def _in_domain(m: ReelModel, p: float) -> bool:
    # the model holds while the metres per drum turn stay clearly positive
    n = m.direction * (p - m.offset_rev) / m.gear_ratio
    return m.metres_per_rev - m.spool_buildup_m_per_rev2 * n > 0.5 * m.metres_per_rev


@given(models, st.floats(-1e4, 1e4))
def test_round_trip_position_length_position(m: ReelModel, p: float) -> None:
    assume(_in_domain(m, p))
    length = m.length_m(p)
    back = m.position_rev(length)
    slope = abs(m.length_rate_mps(p, 1.0))
    # float rounding of length (|L| ulps) mapped through the slope, plus p's own ulps
    tol = 8 * EPS * (abs(length) + m.reference_length_m + 1.0) / slope + 8 * EPS * (
        abs(p) + abs(m.offset_rev)
    )
    assert abs(back - p) <= tol


@given(models, st.floats(-50.0, 50.0))
def test_round_trip_length_position_length(m: ReelModel, length: float) -> None:
    try:
        p = m.position_rev(length)
    except ValueError:
        assume(False)
        return
    assume(_in_domain(m, p))
    assert m.length_m(p) == pytest.approx(length, rel=1e-12, abs=1e-9)


@given(models, st.floats(-1e3, 1e3), st.floats(0.0, 20.0))
def test_with_home_round_trip(m: ReelModel, p_home: float, length_home: float) -> None:
    try:
        h = m.with_home(p_home, length_home)
    except ValueError:
        assume(False)
        return
    assert h.length_m(p_home) == pytest.approx(length_home, rel=1e-9, abs=1e-9)


# --- torque <-> tension ---------------------------------------------------------------------


def test_torque_and_tension_known_values_and_sign() -> None:
    # 15 mm drum, direct drive: 94.2 mm per motor turn; 1 N needs 15 mN m (tension x radius)
    m = ReelModel.from_drum_radius(0.015)
    assert m.torque_nm(3.0, 1.0) == pytest.approx(-0.015)  # holding winds in: negative
    assert m.tension_n(3.0, -0.015) == pytest.approx(1.0)
    mirrored = ReelModel.from_drum_radius(0.015, direction=-1)
    assert mirrored.torque_nm(3.0, 1.0) == pytest.approx(0.015)
    assert mirrored.tension_n(3.0, 0.015) == pytest.approx(1.0)
    # a 10:1 gearbox and a 2:1 block: the motor feels a twentieth of the radius x tension
    geared = ReelModel.from_drum_radius(0.015, gear_ratio=10.0, mechanical_advantage=2.0)
    assert geared.torque_nm(0.0, 100.0) == pytest.approx(-100.0 * 0.015 / 20.0)


def test_torque_work_balances_tension_work_with_buildup() -> None:
    """Over a small turn the motor's work equals minus the cable's: tau dtheta = -T dL."""
    m = ReelModel(metres_per_rev=0.1, gear_ratio=3.0, spool_buildup_m_per_rev2=0.004)
    p, dp, tension = 7.0, 1e-6, 250.0
    tau = m.torque_nm(p + dp / 2, tension)
    d_length = m.length_m(p + dp) - m.length_m(p)
    assert tau * 2 * math.pi * dp == pytest.approx(-tension * d_length, rel=1e-6)
    # build-up: fewer metres per turn further out, so the same torque holds more tension there
    assert m.tension_n(30.0, -1.0) > m.tension_n(0.0, -1.0) > 0.0


def test_max_tension_from_torque_takes_the_steepest_end() -> None:
    m = ReelModel(metres_per_rev=0.5, gear_ratio=10.0)  # 0.05 m per motor turn
    assert m.max_tension_n(4.0, 1.0, 100.0) == pytest.approx(4.0 * 2 * math.pi / 0.05)
    b = ReelModel(metres_per_rev=0.1, spool_buildup_m_per_rev2=0.004)
    # wound in (short cable) the spool is fullest: most metres per turn, least tension
    short_slope = abs(b.length_rate_mps(b.position_rev(-2.0), 1.0))
    assert b.max_tension_n(1.0, -2.0, 0.5) == pytest.approx(2 * math.pi / short_slope)
    with pytest.raises(ValueError, match="max_torque_nm"):
        m.max_tension_n(0.0, 1.0, 2.0)
    with pytest.raises(ValueError, match="max_torque_nm"):
        m.max_tension_n(math.nan, 1.0, 2.0)


@given(models, st.floats(-1e3, 1e3), st.floats(-1e4, 1e4))
def test_round_trip_tension_torque_tension(m: ReelModel, p: float, tension: float) -> None:
    assume(_in_domain(m, p))
    tau = m.torque_nm(p, tension)
    assert math.copysign(1.0, tau) * math.copysign(1.0, tension) * m.direction <= 0 or tau == 0
    assert m.tension_n(p, tau) == pytest.approx(tension, rel=1e-12, abs=1e-9)


@given(models, st.floats(-1e3, 1e3), st.floats(-100.0, 100.0))
def test_round_trip_torque_tension_torque(m: ReelModel, p: float, tau: float) -> None:
    assume(_in_domain(m, p))
    assert m.torque_nm(p, m.tension_n(p, tau)) == pytest.approx(tau, rel=1e-12, abs=1e-12)


# --- the build-up as RepRapFirmware's Hangprinter gives it (area factor) ---------------------


def _rrf_turns(delta_m: float, r_m: float, q_m: float, u: float, o: float, gear: float) -> float:
    """Motor turns for a line `delta_m` longer than at the origin, by RepRapFirmware's
    Hangprinter spool model (HangprinterKinematics.cpp, Recalc and CartesianToMotorSteps):
    k2 = -U*O*Q, k0 = 2*S_r/k2 with S_r = U*J*microsteps*H/(2*pi*L) steps per unit times
    radius, steps = k0*(sqrt(R^2 + k2*delta) - R); turns = steps/(J*microsteps). Written out
    here from that source as the independent reference."""
    k2 = -u * o * q_m
    k0_turns = 2.0 * (u * gear / (2.0 * math.pi)) / k2
    return k0_turns * (math.sqrt(r_m * r_m + k2 * delta_m) - r_m)


def test_buildup_factor_known_value() -> None:
    # 2 pi^2 f: RepRapFirmware's default Q 0.007 mm gives 1.38e-4 m per turn per turn
    assert spool_buildup_from_factor(7e-6) == pytest.approx(2 * math.pi**2 * 7e-6)
    assert spool_buildup_from_factor(0.0) == 0.0
    for bad in (-1e-6, math.nan, math.inf):
        with pytest.raises(ValueError, match="factor_m"):
            spool_buildup_from_factor(bad)


def test_buildup_factor_is_the_radius_squared_falling_with_the_cable_paid_out() -> None:
    """r^2 = r_ref^2 - f * s: the metres per turn at n turns, squared, against the spool."""
    r0, f = 0.075, 1.28e-4
    m = ReelModel.from_drum_radius(r0)
    m = ReelModel(m.metres_per_rev, spool_buildup_m_per_rev2=spool_buildup_from_factor(f))
    for n in (-20.0, -3.0, 0.0, 4.0, 25.0):
        s = m.length_m(n)  # direct drive, no block: cable paid out from the spool
        r = m.length_rate_mps(n, 1.0) / (2 * math.pi)  # metres per drum turn / 2 pi
        assert r * r == pytest.approx(r0 * r0 - f * s, rel=1e-12)


rrf_spools = st.fixed_dictionaries(
    {
        "r_m": st.floats(0.01, 0.2),
        "q_m": st.floats(1e-7, 5e-4),
        "u": st.integers(1, 8).map(float),
        "o": st.integers(1, 4).map(float),
        "gear": st.floats(1.0, 30.0),
        "ref_m": st.floats(0.2, 10.0),
    }
)


def _rrf_model(s: dict[str, float]) -> ReelModel:
    return ReelModel(
        metres_per_rev=2 * math.pi * s["r_m"],
        gear_ratio=s["gear"],
        mechanical_advantage=s["u"],
        spool_buildup_m_per_rev2=spool_buildup_from_factor(s["q_m"] * s["o"]),
        reference_length_m=s["ref_m"],
    )


@given(rrf_spools, st.floats(-1.0, 1.0))
def test_buildup_factor_is_repraps_spool_model(s: dict[str, float], frac: float) -> None:
    """The reel model with the factor turns exactly as RepRapFirmware's formula does, anywhere
    its radius stays above half the origin's (the line on the spool moving 0..75 % of it)."""
    reach = 0.75 * s["r_m"] ** 2 / (s["u"] * s["o"] * s["q_m"])  # r^2 down to a quarter
    delta = frac * min(reach, 5.0 * s["ref_m"])
    m = _rrf_model(s)
    expected = _rrf_turns(delta, s["r_m"], s["q_m"], s["u"], s["o"], s["gear"])
    got = m.position_rev(s["ref_m"] + delta)
    assert got == pytest.approx(expected, rel=1e-9, abs=1e-9)
    assert m.length_m(got) == pytest.approx(s["ref_m"] + delta, rel=1e-12, abs=1e-12)


@given(rrf_spools, st.floats(-1.0, 1.0), st.floats(-1.0, 1.0))
def test_buildup_factor_keeps_the_reel_monotonic(s: dict[str, float], a: float, b: float) -> None:
    """More line out, more turns: position_rev is strictly increasing in the length over the
    spool's reach (direction +1), and so is length_m in the turns."""
    reach = 0.75 * s["r_m"] ** 2 / (s["u"] * s["o"] * s["q_m"])
    span = min(reach, 5.0 * s["ref_m"])
    la, lb = sorted((s["ref_m"] + a * span, s["ref_m"] + b * span))
    assume(lb - la > 1e-9 * (1.0 + span))
    m = _rrf_model(s)
    pa, pb = m.position_rev(la), m.position_rev(lb)
    assert pa < pb
    assert m.length_m(pa) < m.length_m(pb)
    assert m.length_rate_mps(pa, 1.0) > 0.0 and m.length_rate_mps(pb, 1.0) > 0.0


@given(rrf_spools, st.floats(-5.0, 5.0))
def test_zero_buildup_factor_is_the_plain_drum(s: dict[str, float], delta: float) -> None:
    plain = ReelModel(
        metres_per_rev=2 * math.pi * s["r_m"],
        gear_ratio=s["gear"],
        mechanical_advantage=s["u"],
        reference_length_m=s["ref_m"],
    )
    zero = _rrf_model({**s, "q_m": 0.0})
    length = s["ref_m"] + delta
    assert zero.position_rev(length) == plain.position_rev(length)
    assert zero.length_m(delta) == plain.length_m(delta)
    assert zero == plain
