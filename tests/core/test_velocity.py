"""Velocity input: the planner's velocity mode (hypothesis: speed, acceleration, dead-man,
workspace) and the velocity sample parser (caps: bytes, depth, finite numbers)."""

from __future__ import annotations

import itertools
import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.core.commands import (
    MAX_JSON_DEPTH,
    MAX_PAYLOAD_BYTES,
    CommandError,
    Velocity,
    check_payload_size,
    parse_command,
)
from controller.core.motion import (
    MIN_SPEED_MPS,
    MotionPlanner,
    Vec3,
    clamp_velocity,
)
from controller.core.workspace import Workspace
from controller.service.config import default_config

REL = 1e-9  # relative tolerance on the limits (rounding only)

vcomp = st.floats(-20.0, 20.0, allow_nan=False, allow_infinity=False)
vel = st.tuples(vcomp, vcomp, vcomp)
pspeed = st.floats(0.5, 5.0)
paccel = st.floats(0.5, 10.0)
dt = st.sampled_from([0.001, 0.002, 0.004, 0.01])
# a joystick session: (velocity sample, ticks until the next sample)
samples = st.lists(st.tuples(vel, st.integers(1, 60)), min_size=1, max_size=12)


def norm(v: Vec3) -> float:
    return math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)


def sub(a: Vec3, b: Vec3) -> Vec3:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _paper_limits() -> Workspace:
    cfg = default_config()
    return Workspace.from_limits(cfg.limits, cfg.geometry)


LIMITS = _paper_limits()


# ------------------------------------------------------------------------ clamping


@settings(max_examples=300, deadline=None)
@given(
    st.tuples(
        st.floats(allow_nan=False, allow_infinity=False),
        st.floats(allow_nan=False, allow_infinity=False),
        st.floats(allow_nan=False, allow_infinity=False),
    ),
    pspeed,
)
def test_clamp_keeps_direction_and_bounds_the_norm(v: Vec3, vmax: float) -> None:
    c = clamp_velocity(v, vmax)
    assert all(math.isfinite(x) for x in c)
    n = norm(c)
    assert n <= vmax * (1 + REL)
    m = max(abs(x) for x in v)
    if m == 0.0 or norm(tuple(x / m for x in v)) * m < MIN_SPEED_MPS:  # type: ignore[arg-type]
        assert c == (0.0, 0.0, 0.0)
        return
    # same direction: parallel and pointing the same way
    u = tuple(x / m for x in v)
    dot = sum(a * b for a, b in zip(u, c, strict=True))
    assert dot > 0.0
    assert dot == pytest.approx(norm(u) * n, rel=1e-9)  # type: ignore[arg-type]


def test_clamp_known_values_and_refusals() -> None:
    assert clamp_velocity((3.0, 4.0, 0.0), 10.0) == (3.0, 4.0, 0.0)
    assert clamp_velocity((3.0, 4.0, 0.0), 1.0) == pytest.approx((0.6, 0.8, 0.0))
    big = clamp_velocity((1.7e308, 1.7e308, 1.7e308), 2.0)  # the naive norm overflows
    assert big == pytest.approx((2.0 / math.sqrt(3.0),) * 3)
    assert clamp_velocity((0.5 * MIN_SPEED_MPS, 0.0, 0.0), 2.0) == (0.0, 0.0, 0.0)
    for bad in ((math.nan, 0.0, 0.0), (0.0, math.inf, 0.0), (1.0, 2.0)):
        with pytest.raises(ValueError):
            clamp_velocity(bad, 2.0)


# ------------------------------------------------------------------------ limits


def _run(
    pl: MotionPlanner, session: list[tuple[Vec3, int]], step: float, tail_ticks: int
) -> list[tuple[Vec3, Vec3]]:
    """Feed the samples (each held for its tick count), then `tail_ticks` without any."""
    out = [(pl.position_m, pl.velocity_mps)]
    for v, ticks in session:
        pl.command_velocity(v)
        for _ in range(ticks):
            pl.advance(step)
            out.append((pl.position_m, pl.velocity_mps))
    for _ in range(tail_ticks):
        pl.advance(step)
        out.append((pl.position_m, pl.velocity_mps))
    return out


@settings(max_examples=60, deadline=None)
@given(samples, pspeed, paccel, dt)
def test_velocity_mode_never_exceeds_speed_or_acceleration(
    session: list[tuple[Vec3, int]], vmax: float, amax: float, step: float
) -> None:
    pl = MotionPlanner(vmax, amax, velocity_timeout_s=0.1)
    pl.hold((0.0, 0.0, 0.0))
    trace = _run(pl, session, step, int((0.1 + vmax / amax) / step) + 3)
    for (p0, v0), (p1, v1) in itertools.pairwise(trace):
        assert norm(v1) <= vmax * (1 + REL)
        assert norm(sub(v1, v0)) <= amax * step * (1 + REL) + 1e-12
        # the position follows the velocity (semi-implicit Euler)
        assert p1 == pytest.approx(tuple(p + v * step for p, v in zip(p0, v1, strict=True)))
    # no sample for longer than the dead-man timeout and the braking time: at rest, holding
    assert pl.velocity_mps == (0.0, 0.0, 0.0)
    assert pl.mode == "hold" and not pl.moving


@settings(max_examples=60, deadline=None)
@given(vel, vel, pspeed, paccel, dt, st.floats(0.02, 0.5), st.integers(0, 200))
def test_deadman_brakes_to_rest_within_timeout_plus_v_over_a(
    v_before: Vec3,
    v_last: Vec3,
    vmax: float,
    amax: float,
    step: float,
    timeout_s: float,
    ticks_before: int,
) -> None:
    pl = MotionPlanner(vmax, amax, velocity_timeout_s=timeout_s)
    pl.hold((0.0, 0.0, 0.0))
    pl.command_velocity(v_before)
    for _ in range(ticks_before):
        pl.command_velocity(v_before)  # a client streaming well within the timeout
        pl.advance(step)
    speed_at_last = norm(pl.velocity_mps)
    taken = pl.command_velocity(v_last)  # the last sample before the client goes quiet
    commanded = norm(clamp_velocity(v_last, vmax)) if taken else 0.0
    # While the last sample stands the speed goes toward it, never above the larger of the two;
    # then it brakes at amax. Two ticks of rounding: the timeout and the stop fall on ticks.
    bound_s = timeout_s + max(speed_at_last, commanded) / amax + 2 * step
    t = 0.0
    while pl.moving:
        pl.advance(step)
        t += step
        assert t <= bound_s + 1e-9, (t, bound_s, pl.velocity_mps)
    assert pl.velocity_mps == (0.0, 0.0, 0.0) and pl.mode == "hold"
    # The dead-man fired only if the last sample asked for motion (a zero sample is a stop).
    assert pl.deadman_stops == (1 if commanded > 0.0 else 0)


def test_deadman_waits_for_the_timeout_then_brakes_at_max_accel() -> None:
    pl = MotionPlanner(2.0, 1.0, velocity_timeout_s=0.25)
    pl.hold((0.0, 0.0, 2.0))
    step = 0.002
    for _ in range(500):  # 1 s at 20 Hz samples: reaches 1 m/s
        pl.command_velocity((1.0, 0.0, 0.0))
        for _ in range(25):
            pl.advance(step)
    assert pl.velocity_mps == pytest.approx((1.0, 0.0, 0.0))
    pl.command_velocity((1.0, 0.0, 0.0))  # the last sample
    for _ in range(int(0.25 / step) - 1):  # within the timeout: full speed on
        pl.advance(step)
    assert pl.velocity_mps == pytest.approx((1.0, 0.0, 0.0)) and pl.deadman_stops == 0
    x0 = pl.position_m[0]
    ticks = 0
    while pl.moving:
        pl.advance(step)
        ticks += 1
    assert pl.deadman_stops == 1
    assert ticks * step == pytest.approx(1.0 + step, abs=2 * step)  # v / a, plus the timeout tick
    assert pl.position_m[0] - x0 == pytest.approx(0.5, abs=0.01)  # v^2 / (2 a)


def test_zero_sample_brakes_to_a_hold_and_zero_outside_velocity_mode_is_ignored() -> None:
    pl = MotionPlanner(2.0, 1.0)
    pl.hold((0.0, 0.0, 2.0))
    assert pl.command_velocity((0.0, 0.0, 0.0)) is False  # holding: nothing to do
    assert pl.mode == "hold"
    assert pl.command_velocity((0.0, 0.5, 0.0)) is True and pl.mode == "velocity"
    for _ in range(1000):
        pl.advance(0.002)
    assert pl.velocity_mps == pytest.approx((0.0, 0.0, 0.0))  # the dead-man stopped it
    pl.command_velocity((0.0, 0.5, 0.0))
    for _ in range(100):
        pl.command_velocity((0.0, 0.5, 0.0))
        pl.advance(0.002)
    assert pl.velocity_mps[1] > 0.19
    assert pl.command_velocity((0.0, 0.0, 0.0)) is True
    speeds = []
    while pl.moving:
        pl.advance(0.002)
        speeds.append(norm(pl.velocity_mps))
    assert speeds == sorted(speeds, reverse=True)  # braking only
    assert len(speeds) <= 0.2 / (1.0 * 0.002) + 2
    assert pl.mode == "hold" and pl.deadman_stops == 1  # that one was the earlier stop
    # A move runs: a centred stick streaming zeros does not stop it, a deflected one takes over.
    pl.move_to((3.0, 0.0, 2.0), 1.0)
    for _ in range(200):
        assert pl.command_velocity((0.0, 0.0, 0.0)) is False
        pl.advance(0.002)
    assert pl.mode == "move" and pl.velocity_mps[0] > 0.3
    v_move = pl.velocity_mps
    assert pl.command_velocity((0.0, 0.0, 0.3)) is True and pl.mode == "velocity"
    pl.advance(0.002)
    assert norm(sub(pl.velocity_mps, v_move)) <= 1.0 * 0.002 * (1 + REL)  # smooth hand-over


def test_move_stop_and_stream_replace_velocity_mode() -> None:
    pl = MotionPlanner(2.0, 1.0, velocity_timeout_s=10.0)
    pl.hold((0.0, 0.0, 2.0))
    pl.command_velocity((1.0, 0.0, 0.0))
    for _ in range(250):
        pl.advance(0.002)
    v = pl.velocity_mps
    rest = pl.rest_point_m
    pl.move_to((0.0, 3.0, 2.0))  # brakes first, along the current direction
    assert pl.mode == "stop" and pl.target_m == (0.0, 3.0, 2.0)
    pl.advance(0.002)
    assert norm(sub(pl.velocity_mps, v)) <= 0.002 * (1 + REL)
    while pl.mode == "stop":
        pl.advance(0.002)
    assert pl.position_m == pytest.approx(rest, abs=1e-9)
    pl.command_velocity((0.0, -1.0, 0.0))
    pl.advance(0.002)
    pl.stop()
    assert pl.mode == "stop"
    assert pl.command_velocity((0.0, 0.0, 0.0)) is False and pl.mode == "stop"
    pl.command_velocity((0.0, 0.0, 1.0))
    pl.stream((0.0, 0.0, 2.5))
    assert pl.mode == "stream"
    pl.hold((1.0, 1.0, 1.0))
    assert pl.velocity_command_mps == (0.0, 0.0, 0.0) and not pl.moving


def test_bad_velocity_leaves_the_planner_unchanged() -> None:
    pl = MotionPlanner(2.0, 1.0)
    pl.hold((0.0, 0.0, 2.0))
    pl.command_velocity((0.1, 0.0, 0.0))
    pl.advance(0.01)
    before = (pl.position_m, pl.velocity_mps, pl.mode, pl.velocity_command_mps)
    for bad in ((math.nan, 0.0, 0.0), (0.0, 0.0, -math.inf), (1.0,)):
        with pytest.raises(ValueError):
            pl.command_velocity(bad)
    assert (pl.position_m, pl.velocity_mps, pl.mode, pl.velocity_command_mps) == before
    for bad_dt in (0.0, -1.0, math.nan, math.inf):
        assert pl.advance(bad_dt) == before[0]
    with pytest.raises(ValueError):
        MotionPlanner(2.0, 1.0, velocity_timeout_s=0.0)
    with pytest.raises(ValueError):
        MotionPlanner(2.0, 1.0, velocity_timeout_s=math.nan)


# ------------------------------------------------------------------------ workspace


inside = st.tuples(st.floats(-36.0, 36.0), st.floats(-21.0, 21.0), st.floats(0.2, 6.4))


@settings(max_examples=40, deadline=None)
@given(inside, samples, st.floats(0.5, 3.0), st.floats(0.5, 5.0), dt)
def test_velocity_mode_never_leaves_the_workspace(
    start: Vec3, session: list[tuple[Vec3, int]], vmax: float, amax: float, step: float
) -> None:
    lim = LIMITS
    assert lim.check_target(start) is None
    pl = MotionPlanner(vmax, amax, velocity_timeout_s=10.0, check_segment=lim.check_segment)
    pl.hold(start)
    # Samples held up to ten times longer: long enough to reach any boundary at these speeds.
    long_session = [(v, n * 10) for v, n in session]
    trace = _run(pl, long_session, step, 0)
    for (_, v0), (p1, v1) in itertools.pairwise(trace):
        assert lim.check_target(p1) is None, p1
        assert norm(v1) <= vmax * (1 + REL)
        assert norm(sub(v1, v0)) <= amax * step * (1 + REL) + 1e-12


@pytest.mark.parametrize(
    ("direction", "axis", "bound"),
    [
        ((0.0, 0.0, -1.0), 2, "floor"),
        ((0.0, 0.0, 1.0), 2, "top"),
        ((1.0, 0.0, 0.0), 0, "x"),
        ((0.0, -1.0, 0.0), 1, "y"),
    ],
)
def test_pushing_into_a_boundary_stops_just_inside_it(
    direction: Vec3, axis: int, bound: str
) -> None:
    lim = LIMITS
    pl = MotionPlanner(2.0, 1.0, velocity_timeout_s=1.0, check_segment=lim.check_segment)
    pl.hold((0.0, 0.0, 3.0))
    v = tuple(2.0 * d for d in direction)
    for _ in range(40 * 20):  # 40 s of samples at 20 Hz, 500 Hz ticks
        pl.command_velocity(v)
        for _ in range(25):
            pl.advance(0.002)
            assert lim.check_target(pl.position_m) is None
    assert pl.boundary_brakes > 0
    # Just inside: a millimetre further along the push is outside.
    p = pl.position_m
    beyond = list(p)
    beyond[axis] += 1e-3 * direction[axis]
    assert lim.check_target(tuple(beyond)) is not None, (bound, p)
    # Steering away is taken at once.
    away = tuple(-x for x in v)
    pl.command_velocity(away)
    pl.advance(0.002)
    assert sum(a * b for a, b in zip(pl.velocity_mps, away, strict=True)) > 0.0


def test_braking_look_ahead_starts_before_the_boundary() -> None:
    # At full speed toward the floor the planner must start braking v^2/(2a) above it.
    lim = LIMITS
    pl = MotionPlanner(2.0, 1.0, velocity_timeout_s=100.0, check_segment=lim.check_segment)
    pl.hold((0.0, 0.0, 6.5))
    pl.command_velocity((0.0, 0.0, -2.0))
    first_brake_z = None
    while pl.boundary_brakes == 0:
        pl.advance(0.002)
    first_brake_z = pl.position_m[2]
    vz = -pl.velocity_mps[2]
    assert vz > 1.5  # at speed when it saw the floor coming
    assert first_brake_z == pytest.approx(vz * vz / 2.0, abs=0.01)  # floor at z = 0


# ------------------------------------------------------------------------ the sample parser


@settings(max_examples=200, deadline=None)
@given(
    st.tuples(
        st.floats(allow_nan=False, allow_infinity=False),
        st.floats(allow_nan=False, allow_infinity=False),
        st.floats(allow_nan=False, allow_infinity=False),
    )
)
def test_any_finite_velocity_parses_exactly(v: Vec3) -> None:
    payload = json.dumps({"velocity_mps": list(v)}).encode()
    cmd = parse_command("velocity", payload)
    assert cmd == Velocity(v)
    assert all(type(x) is float for x in cmd.velocity_mps)


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b"", "missing field(s): velocity_mps"),
        (b"{}", "missing field(s): velocity_mps"),
        (b'{"position_m": [0, 0, 1]}', "unknown field(s): position_m"),
        (b'{"velocity_mps": [0, 0, 1], "speed_mps": 1}', "unknown field(s): speed_mps"),
        (b'{"velocity_mps": [0, 0]}', "velocity_mps: expected [x, y, z]"),
        (b'{"velocity_mps": null}', "velocity_mps: expected [x, y, z]"),
        (b'{"velocity_mps": [0, 0, NaN]}', "non-finite number NaN"),
        (b'{"velocity_mps": [-Infinity, 0, 0]}', "non-finite number -Infinity"),
        (b'{"velocity_mps": [0, 1e999, 0]}', "velocity_mps[1]: must be a finite number"),
        (b'{"velocity_mps": [0, 0, true]}', "velocity_mps[2]: expected a number, got bool"),
        (b'{"velocity_mps": ["1", 0, 0]}', "velocity_mps[0]: expected a number, got str"),
        (b"[0, 0, 1]", "expected a JSON object"),
        (b'{"velocity_mps": [0, 0, 1]', "malformed JSON"),
    ],
)
def test_malformed_velocity_samples_are_refused_with_a_reason(payload: bytes, reason: str) -> None:
    with pytest.raises(CommandError) as info:
        parse_command("velocity", payload)
    assert reason in str(info.value)


def test_velocity_samples_have_a_byte_cap_and_a_depth_cap() -> None:
    cap = MAX_PAYLOAD_BYTES["velocity"]
    assert cap == 1024
    valid = b'{"velocity_mps": [0.25, -0.5, 0]}'
    at_cap = valid + b" " * (cap - len(valid))
    assert parse_command("velocity", at_cap) == Velocity((0.25, -0.5, 0.0))
    with pytest.raises(CommandError, match=f"payload too large: {cap + 1} bytes, velocity takes"):
        parse_command("velocity", at_cap + b" ")
    with pytest.raises(CommandError, match="payload too large"):
        check_payload_size("velocity", 10_000_000)  # refused before any copy
    deep = b'{"velocity_mps": ' + b"[" * 400 + b"1" + b"]" * 400 + b"}"
    assert len(deep) <= cap
    with pytest.raises(CommandError, match=f"nested too deeply: at most {MAX_JSON_DEPTH}"):
        parse_command("velocity", deep)
