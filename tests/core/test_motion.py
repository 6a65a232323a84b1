"""Motion: the trapezoid and the planner respect speed and acceleration limits (hypothesis)."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.core.motion import MotionPlanner, TrapezoidMove, Vec3, circle_path

REL = 1e-9  # relative tolerance on the limits (rounding only)

coord = st.floats(-100.0, 100.0, allow_nan=False, allow_infinity=False)
point = st.tuples(coord, coord, coord)
speed = st.floats(0.01, 10.0)
accel = st.floats(0.01, 20.0)
# the planner tests run tick by tick: keep them to a few thousand ticks
small = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
spoint = st.tuples(small, small, small)
pspeed = st.floats(0.5, 10.0)
paccel = st.floats(0.5, 20.0)
dt = st.sampled_from([0.001, 0.002, 0.01, 0.05])
MAX_TICKS = 2000


def norm(v: Vec3) -> float:
    return math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)


def sub(a: Vec3, b: Vec3) -> Vec3:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def minimal_time(d: float, v: float, a: float) -> float:
    if d == 0.0:
        return 0.0
    if d >= v * v / a:
        return d / v + v / a
    return 2.0 * math.sqrt(d / a)


@settings(max_examples=300, deadline=None)
@given(point, point, speed, accel)
def test_trapezoid_respects_limits_ends_exactly_and_is_minimal(
    a: Vec3, b: Vec3, vmax: float, amax: float
) -> None:
    mv = TrapezoidMove(a, b, vmax, amax)
    d = math.dist(a, b)
    assert mv.duration_s == pytest.approx(minimal_time(d, vmax, amax), rel=1e-12, abs=1e-12)
    # the profile saturates a limit: the triangle reaches exactly sqrt(d a) <= vmax, the
    # trapezoid reaches vmax (a faster profile would have to exceed one of them)
    if d > 0:
        assert mv.peak_speed_mps == pytest.approx(min(vmax, math.sqrt(d * amax)), rel=1e-12)
    p0, v0 = mv.sample(0.0)
    assert p0 == pytest.approx(a, abs=1e-12)
    assert v0 == (0.0, 0.0, 0.0)
    assert mv.sample(mv.duration_s) == (tuple(map(float, b)), (0.0, 0.0, 0.0))
    assert mv.sample(mv.duration_s + 5.0)[0] == tuple(map(float, b))
    n = 400
    h = mv.duration_s / n if mv.duration_s > 0 else 0.0
    prev_p, prev_v = p0, v0
    for k in range(1, n + 1):
        p, v = mv.sample(k * h)
        assert all(math.isfinite(c) for c in p + v)
        assert norm(v) <= vmax * (1 + REL) + 1e-12
        # velocity is continuous and piecewise linear: difference quotient bounded by amax
        assert norm(sub(v, prev_v)) <= amax * h * (1 + 1e-7) + 1e-12
        # position never moves faster than vmax between samples
        assert norm(sub(p, prev_p)) <= vmax * h * (1 + 1e-7) + 1e-9
        # stays on the segment
        assert math.dist(a, p) <= d + 1e-9
        prev_p, prev_v = p, v


def test_trapezoid_known_values() -> None:
    # 10 m at 2 m/s, 1 m/s^2: 2 s accelerate (2 m), 3 s cruise (6 m), 2 s brake (2 m) = 7 s
    mv = TrapezoidMove((0, 0, 2), (10, 0, 2), 2.0, 1.0)
    assert mv.duration_s == pytest.approx(7.0)
    p, v = mv.sample(1.0)
    assert p == pytest.approx((0.5, 0, 2))
    assert v == pytest.approx((1.0, 0, 0))
    assert mv.sample(3.5)[0] == pytest.approx((5.0, 0, 2))
    p, v = mv.sample(6.0)
    assert p == pytest.approx((9.5, 0, 2))
    assert v == pytest.approx((1.0, 0, 0))
    # 1 m: triangle, peak sqrt(1) = 1 m/s at 1 s, 2 s total
    tri = TrapezoidMove((0, 0, 0), (0, 1, 0), 2.0, 1.0)
    assert tri.duration_s == pytest.approx(2.0)
    assert tri.peak_speed_mps == pytest.approx(1.0)


def test_trapezoid_zero_length_and_bad_limits() -> None:
    mv = TrapezoidMove((1, 2, 3), (1, 2, 3), 1.0, 1.0)
    assert mv.duration_s == 0.0
    assert mv.sample(0.0) == ((1.0, 2.0, 3.0), (0.0, 0.0, 0.0))
    assert mv.sample(-1.0) == ((1.0, 2.0, 3.0), (0.0, 0.0, 0.0))
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="max_speed_mps"):
            TrapezoidMove((0, 0, 0), (1, 0, 0), bad, 1.0)
        with pytest.raises(ValueError, match="max_accel_mps2"):
            TrapezoidMove((0, 0, 0), (1, 0, 0), 1.0, bad)
    with pytest.raises(ValueError, match="end_m"):
        TrapezoidMove((0, 0, 0), (math.nan, 0, 0), 1.0, 1.0)


class Recorder:
    """Runs a planner tick by tick and checks the limits on every tick."""

    def __init__(self, planner: MotionPlanner, dt_s: float) -> None:
        self.pl = planner
        self.dt = dt_s
        self.prev_v = planner.velocity_mps
        self.trace: list[Vec3] = [planner.position_m]

    def tick(self, n: int = 1) -> None:
        pl = self.pl
        for _ in range(n):
            p_before = pl.position_m
            p = pl.advance(self.dt)
            v = pl.velocity_mps
            assert all(math.isfinite(c) for c in p + v)
            vmax, amax = pl.max_speed_mps, pl.max_accel_mps2
            assert norm(v) <= vmax * (1 + REL) + 1e-12
            assert norm(sub(v, self.prev_v)) <= amax * self.dt * (1 + 1e-7) + 1e-12
            assert norm(sub(p, p_before)) <= vmax * self.dt * (1 + 1e-7) + 1e-9
            self.prev_v = v
            self.trace.append(p)

    def run_until_still(self, max_ticks: int) -> int:
        for k in range(max_ticks):
            if not self.pl.moving:
                return k
            self.tick()
        raise AssertionError(f"still moving after {max_ticks} ticks: {self.pl.mode}")


@settings(max_examples=40, deadline=None)
@given(spoint, st.lists(spoint, min_size=1, max_size=4), pspeed, paccel, dt)
def test_planner_path_respects_limits_and_passes_its_points(
    start: Vec3, pts: list[Vec3], vmax: float, amax: float, dt_s: float
) -> None:
    jd = 0.01
    pl = MotionPlanner(vmax, amax, junction_deviation_m=jd)
    pl.hold(start)
    pl.follow_path(pts)
    assert pl.target_m == pts[-1]
    total = sum(
        minimal_time(math.dist(a, b), vmax, amax) for a, b in zip([start, *pts], pts, strict=False)
    )
    # A rounded corner may be slower than a stop at a sharp turn (it is flown at the corner
    # speed); the bound only keeps the run finite.
    dt_s = max(dt_s, 2 * total / MAX_TICKS)
    rec = Recorder(pl, dt_s)
    rec.run_until_still(int((2 * total + len(pts)) / dt_s) + 5)
    assert pl.position_m == pts[-1]  # exactly
    assert pl.velocity_mps == (0.0, 0.0, 0.0)
    for p in pts:  # every point is passed within the junction deviation (+ a tick's travel)
        assert min(math.dist(p, q) for q in rec.trace) <= jd + vmax * dt_s + 1e-9


@settings(max_examples=40, deadline=None)
@given(spoint, spoint, spoint, pspeed, paccel, dt, st.floats(0.05, 0.95))
def test_new_move_while_moving_brakes_first_within_limits(
    start: Vec3, a: Vec3, b: Vec3, vmax: float, amax: float, dt_s: float, frac: float
) -> None:
    pl = MotionPlanner(vmax, amax)
    pl.hold(start)
    pl.move_to(a)
    first = TrapezoidMove(start, a, vmax, amax)
    dt_s = max(dt_s, (first.duration_s + minimal_time(70.0, vmax, amax)) / MAX_TICKS)
    rec = Recorder(pl, dt_s)
    rec.tick(int(frac * first.duration_s / dt_s))
    pl.move_to(b)  # replaces the first move mid-way
    assert pl.target_m == b
    # brake (<= vmax/a) + a trapezoid over at most 35 + v^2/2a metres
    bound = first.duration_s + vmax / amax + minimal_time(35.0 + vmax**2 / amax, vmax, amax)
    rec.run_until_still(int(bound / dt_s) + 10)
    assert pl.position_m == b


@settings(max_examples=40, deadline=None)
@given(spoint, spoint, pspeed, paccel, dt, st.floats(0.05, 0.95))
def test_stop_decelerates_to_hold_on_the_segment(
    start: Vec3, end: Vec3, vmax: float, amax: float, dt_s: float, frac: float
) -> None:
    pl = MotionPlanner(vmax, amax)
    pl.hold(start)
    pl.move_to(end)
    mv = TrapezoidMove(start, end, vmax, amax)
    dt_s = max(dt_s, 2 * mv.duration_s / MAX_TICKS)
    rec = Recorder(pl, dt_s)
    rec.tick(int(frac * mv.duration_s / dt_s))
    s0 = norm(pl.velocity_mps)
    pl.stop()
    predicted = pl.target_m
    speeds = []
    ticks = rec.run_until_still(int(s0 / amax / dt_s) + 3)
    assert ticks <= int(s0 / amax / dt_s) + 2
    for _ in range(3):
        rec.tick()
        speeds.append(norm(pl.velocity_mps))
    assert pl.position_m == predicted
    assert speeds == [0.0, 0.0, 0.0]
    # the stop point lies on the segment (never beyond the move's end)
    d = math.dist(start, end)
    assert math.dist(start, predicted) + math.dist(predicted, end) == pytest.approx(d, abs=1e-6)


def test_stop_is_exact_braking_distance() -> None:
    pl = MotionPlanner(2.0, 1.0)
    pl.hold((0, 0, 2))
    pl.move_to((20, 0, 2))
    for _ in range(2500):  # 5 s at 2 ms: cruising at 2 m/s, at x = 8 m
        pl.advance(0.002)
    assert pl.velocity_mps == pytest.approx((2.0, 0, 0))
    x0 = pl.position_m[0]
    assert pl.rest_point_m == pytest.approx((x0 + 2.0, 0, 2))
    pl.stop()
    assert pl.target_m == pytest.approx((x0 + 2.0, 0, 2))  # v^2 / 2a = 2 m
    n = 0
    while pl.moving:
        pl.advance(0.002)
        n += 1
    assert n == pytest.approx(1000, abs=1)  # 2 s
    assert pl.position_m == pytest.approx((x0 + 2.0, 0, 2), abs=1e-12)


@settings(max_examples=40, deadline=None)
@given(
    spoint,
    st.lists(st.tuples(spoint, st.integers(1, 400)), min_size=1, max_size=6),
    pspeed,
    paccel,
    dt,
)
def test_stream_limits_speed_and_accel_and_lands_exactly(
    start: Vec3, targets: list[tuple[Vec3, int]], vmax: float, amax: float, dt_s: float
) -> None:
    pl = MotionPlanner(vmax, amax)
    pl.hold(start)
    rec = Recorder(pl, dt_s)
    for target, n in targets:
        pl.stream(target)
        rec.tick(n)
    final = targets[-1][0]
    # from any state: brake (<= vmax/a) then a trapezoid over the remaining distance
    bound = vmax / amax + minimal_time(math.dist(pl.position_m, final) + vmax**2 / amax, vmax, amax)
    rec.run_until_still(int(bound / dt_s) + 20)
    assert pl.position_m == final
    assert pl.velocity_mps == (0.0, 0.0, 0.0)
    rec.tick(5)  # holds there
    assert pl.position_m == final


command = st.one_of(
    st.tuples(st.just("move"), spoint),
    st.tuples(st.just("stream"), spoint),
    st.tuples(st.just("velocity"), spoint),  # m/s here: clamped to the max speed
    st.tuples(st.just("zero"), st.just((0.0, 0.0, 0.0))),
    st.tuples(st.just("stop"), st.just((0.0, 0.0, 0.0))),
)


@settings(max_examples=60, deadline=None)
@given(
    spoint,
    st.lists(st.tuples(command, st.integers(1, 300)), min_size=1, max_size=10),
    pspeed,
    paccel,
    dt,
)
def test_any_mix_of_moves_streams_stops_and_velocity_input_keeps_the_limits(
    start: Vec3,
    commands: list[tuple[tuple[str, Vec3], int]],
    vmax: float,
    amax: float,
    dt_s: float,
) -> None:
    # Every hand-over (move -> velocity, velocity -> stream, stop -> velocity, ...) keeps the
    # velocity continuous: speed and acceleration stay within the limits on every tick.
    pl = MotionPlanner(vmax, amax, velocity_timeout_s=0.2)
    pl.hold(start)
    rec = Recorder(pl, dt_s)
    for (kind, vec), n in commands:
        if kind == "move":
            pl.move_to(vec)
        elif kind == "stream":
            pl.stream(vec)
        elif kind in ("velocity", "zero"):
            pl.command_velocity(vec)
        else:
            pl.stop()
        rec.tick(n)
    pl.stop()
    rec.run_until_still(int(vmax / amax / dt_s) + 5)
    assert pl.velocity_mps == (0.0, 0.0, 0.0)


def test_stream_time_is_close_to_the_trapezoid() -> None:
    pl = MotionPlanner(2.0, 1.0)
    pl.hold((0, 0, 2))
    pl.stream((10, 0, 2))
    n = 0
    while pl.moving:
        pl.advance(0.002)
        n += 1
        assert n < 10_000
    assert pl.position_m == (10.0, 0.0, 2.0)
    assert n * 0.002 == pytest.approx(7.0, abs=0.05)  # the trapezoid takes exactly 7 s


def test_no_nan_on_degenerate_input() -> None:
    pl = MotionPlanner(1.0, 1.0)
    pl.hold((1, 1, 1))
    pl.move_to((1, 1, 1))  # zero-length move: nothing to do
    assert not pl.moving
    assert pl.advance(0.0) == (1.0, 1.0, 1.0)
    assert pl.advance(-1.0) == (1.0, 1.0, 1.0)
    assert pl.advance(math.nan) == (1.0, 1.0, 1.0)
    pl.stop()  # stop while holding
    assert pl.advance(0.01) == (1.0, 1.0, 1.0)
    pl.stream((1, 1, 1))
    assert pl.advance(0.01) == (1.0, 1.0, 1.0)
    assert not pl.moving
    with pytest.raises(ValueError):
        pl.move_to((math.inf, 0, 0))
    with pytest.raises(ValueError):
        pl.stream((0, math.nan, 0))
    with pytest.raises(ValueError):
        pl.follow_path([])
    with pytest.raises(ValueError):
        pl.move_to((0, 0, 0), speed_mps=0.0)
    assert pl.position_m == (1.0, 1.0, 1.0)


def test_speed_is_clamped_and_default_used() -> None:
    pl = MotionPlanner(2.0, 1.0, default_speed_mps=0.5)
    pl.hold((0, 0, 0))
    pl.move_to((100, 0, 0))
    peak = 0.0
    for _ in range(100_000):
        pl.advance(0.01)
        peak = max(peak, norm(pl.velocity_mps))
        if not pl.moving:
            break
    assert peak == pytest.approx(0.5)
    pl.move_to((0, 0, 0), speed_mps=50.0)
    peak = 0.0
    while pl.moving:
        pl.advance(0.01)
        peak = max(peak, norm(pl.velocity_mps))
    assert peak == pytest.approx(2.0)


def test_circle_path_is_the_papers_example_c() -> None:
    pts = circle_path()
    assert len(pts) == 73  # 72 legs, the last point closes the circle
    assert pts[0] == pts[-1] == (20.0, 0.0, 2.0)
    for p in pts:
        assert math.hypot(p[0], p[1]) == pytest.approx(20.0)
        assert p[2] == 2.0
    for a, b in itertools.pairwise(pts):
        assert math.dist(a, b) == pytest.approx(2 * 20.0 * math.sin(math.radians(2.5)))
    assert pts[18] == pytest.approx((0.0, 20.0, 2.0), abs=1e-12)  # 90 degrees, CCW
    small = circle_path(1.0, (5.0, -3.0), 0.5, steps=4)
    expected = [(6, -3, 0.5), (5, -2, 0.5), (4, -3, 0.5), (5, -4, 0.5), (6, -3, 0.5)]
    assert [c for p in small for c in p] == pytest.approx([c for p in expected for c in p])
    with pytest.raises(ValueError):
        circle_path(steps=2)
    with pytest.raises(ValueError):
        circle_path(radius_m=-1.0)


def test_speed_below_the_minimum_is_refused_by_the_planner() -> None:
    from controller.core.motion import MIN_SPEED_MPS, check_speed

    assert check_speed(MIN_SPEED_MPS) is None and check_speed(1e9) is None
    for bad in (5e-324, 1e-9, 0.999 * MIN_SPEED_MPS, 0.0, -1.0, math.nan, math.inf):
        assert check_speed(bad) is not None, bad
    pl = MotionPlanner(2.0, 1.0)
    pl.hold((0, 0, 0))
    for bad in (5e-324, 0.5 * MIN_SPEED_MPS):
        with pytest.raises(ValueError, match="minimum"):
            pl.move_to((1, 0, 0), speed_mps=bad)
        assert not pl.moving
    pl.move_to((0.01, 0, 0), speed_mps=MIN_SPEED_MPS)
    assert pl.moving


def test_points_are_planned_as_they_are_needed() -> None:
    from controller.core.motion import PLAN_POINTS_PER_CALL

    # Starting a path of any length plans a bounded number of points; the rest are planned a
    # bounded number per tick, ahead of the set-point (the look-ahead horizon).
    pts = tuple((0.01 * (i + 1), 0.0, 0.0) for i in range(50_000))
    pl = MotionPlanner(2.0, 1.0)
    pl.hold((0, 0, 0))
    pl.follow_points(pts, 1.0)
    assert pl.target_m == pts[-1] and pl.queued_points == len(pts)
    assert len(pl._q) <= PLAN_POINTS_PER_CALL
    for _ in range(3):
        pl.advance(0.1)
    assert len(pl._q) <= 4 * PLAN_POINTS_PER_CALL
    assert pl.queued_points < len(pts)


def test_one_advance_crosses_a_bounded_number_of_legs() -> None:
    from controller.core.motion import MAX_LEGS_PER_ADVANCE

    # Legs of 1e-12 m last 2 us each: thousands would fit in one 2 ms tick.
    n = 10 * MAX_LEGS_PER_ADVANCE
    pts = [(1e-12 * (i + 1), 0.0, 0.0) for i in range(n)]
    pl = MotionPlanner(2.0, 1.0)
    pl.hold((0, 0, 0))
    pl.follow_path(pts)
    ticks = 0
    last = pl.position_m
    while pl.moving:
        p = pl.advance(0.002)
        ticks += 1
        assert p[0] >= last[0] and p[0] - last[0] <= 1e-12 * MAX_LEGS_PER_ADVANCE * (1 + 1e-9)
        assert norm(pl.velocity_mps) <= 2.0
        last = p
        assert ticks <= 100
    assert ticks >= n // MAX_LEGS_PER_ADVANCE
    assert pl.position_m == pts[-1]


def test_repeated_points_are_dropped_and_targets_kept() -> None:
    from controller.core.motion import dedupe_path

    assert dedupe_path([(0, 0, 1), (0, 0, 1), (1, 0, 1), (1, 0, 1), (0, 0, 1)]) == (
        (0.0, 0.0, 1.0),
        (1.0, 0.0, 1.0),
        (0.0, 0.0, 1.0),
    )
    with pytest.raises(ValueError, match=r"points_m\[1\]"):
        dedupe_path([(0, 0, 1), (0, math.nan, 1)])
    with pytest.raises(ValueError):
        dedupe_path([])
    pl = MotionPlanner(1.0, 1.0)
    pl.hold((0, 0, 1))
    pl.follow_path([(0, 0, 1), (0, 0, 1), (0.5, 0, 1), (0.5, 0, 1)])
    assert pl.moving and pl.target_m == (0.5, 0.0, 1.0)
    while pl.moving:
        pl.advance(0.01)
    assert pl.position_m == (0.5, 0.0, 1.0)
