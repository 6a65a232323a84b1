"""Continuous paths: rounded corners, look-ahead over the queue, appends, cable speeds."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.core.motion import (
    CORNER_ACCEL_FRACTION,
    MotionPlanner,
    QueueError,
    Vec3,
    circle_path,
    junction_speed_mps,
)

ANCHORS: tuple[Vec3, ...] = (
    (-3.0, -3.0, 3.0),
    (3.0, -3.0, 3.0),
    (3.0, 3.0, 3.0),
    (-3.0, 3.0, 3.0),
)

coord = st.floats(-1.5, 1.5, allow_nan=False, allow_infinity=False)
zcoord = st.floats(0.2, 2.0, allow_nan=False, allow_infinity=False)
point = st.tuples(coord, coord, zcoord)
# the chunked runs tick longer: keep them to a smaller box
near = st.floats(-0.5, 0.5, allow_nan=False, allow_infinity=False)
npoint = st.tuples(near, near, st.floats(0.5, 1.5, allow_nan=False, allow_infinity=False))


def norm(v: Vec3) -> float:
    return math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)


def sub(a: Vec3, b: Vec3) -> Vec3:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def cable_rate(anchor: Vec3, p: Vec3, v: Vec3) -> float:
    u = sub(p, anchor)
    n = norm(u)
    return (u[0] * v[0] + u[1] * v[1] + u[2] * v[2]) / n


class Checker:
    """Ticks a planner and checks every limit on every tick, by differencing its samples."""

    def __init__(self, pl: MotionPlanner, dt_s: float, cable_mps: float | None = None) -> None:
        self.pl = pl
        self.dt = dt_s
        self.cable = cable_mps
        self.prev_p = pl.position_m
        self.prev_v = pl.velocity_mps
        self.trace: list[tuple[Vec3, Vec3]] = []
        self.max_cable = 0.0

    def tick(self) -> None:
        pl, dt = self.pl, self.dt
        p = pl.advance(dt)
        v = pl.velocity_mps
        a = pl.max_accel_mps2
        assert all(math.isfinite(c) for c in p + v)
        assert norm(v) <= pl.max_speed_mps * (1 + 1e-9) + 1e-12
        # velocity continuous, |a| bounded (centripetal and tangential together)
        assert norm(sub(v, self.prev_v)) <= a * dt * (1 + 1e-7) + 1e-12
        # the velocity is the position's derivative: the mean of the two ends matches the
        # difference within the curvature's second-order term
        mean = tuple(0.5 * (x + y) for x, y in zip(v, self.prev_v, strict=True))
        diff = tuple((x - y) / dt for x, y in zip(p, self.prev_p, strict=True))
        assert norm(sub(diff, mean)) <= a * dt + 1e-9  # type: ignore[arg-type]
        if self.cable is not None:
            for anc in ANCHORS:
                rate = abs(cable_rate(anc, p, v))
                self.max_cable = max(self.max_cable, rate)
                assert rate <= self.cable * (1 + 1e-9) + 1e-12
        self.prev_p, self.prev_v = p, v
        self.trace.append((p, v))

    def run_until_still(self, max_ticks: int) -> int:
        for k in range(max_ticks):
            if not self.pl.moving:
                return k
            self.tick()
        raise AssertionError(f"still moving after {max_ticks} ticks")


@settings(max_examples=30, deadline=None)
@given(
    point,
    st.lists(point, min_size=2, max_size=8),
    st.floats(0.5, 2.0),
    st.floats(0.5, 5.0),
    st.floats(0.002, 0.05),
    st.floats(0.05, 1.0),
)
def test_random_paths_keep_speed_accel_and_cable_limits(
    start: Vec3,
    pts: list[Vec3],
    vmax: float,
    amax: float,
    jd: float,
    cable: float,
) -> None:
    pl = MotionPlanner(
        vmax,
        amax,
        junction_deviation_m=jd,
        anchors_m=ANCHORS,
        max_cable_speed_mps=cable,
    )
    pl.hold(start)
    pl.follow_path(pts)
    chk = Checker(pl, 0.002, cable)
    chk.run_until_still(200_000)
    assert pl.position_m == pts[-1]
    assert pl.velocity_mps == (0.0, 0.0, 0.0)


@settings(max_examples=30, deadline=None)
@given(
    npoint,
    st.lists(
        st.tuples(st.lists(npoint, min_size=1, max_size=6), st.integers(0, 400)),
        min_size=1,
        max_size=6,
    ),
    st.floats(0.5, 2.0),
    st.floats(0.5, 5.0),
    st.booleans(),
)
def test_appends_in_chunks_always_stop_at_the_end_of_the_queue(
    start: Vec3,
    chunks: list[tuple[list[Vec3], int]],
    vmax: float,
    amax: float,
    stop_at_end: bool,
) -> None:
    # Chunks arrive while the set-point flies (or after it ran dry); every limit holds on every
    # tick, and with nothing more queued it comes to rest exactly at the last point.
    pl = MotionPlanner(vmax, amax, junction_deviation_m=0.02)
    pl.hold(start)
    chk = Checker(pl, 0.002)
    first, _ = chunks[0]
    pl.follow_path(first)
    last = first[-1]
    for pts, ticks in chunks:
        if pts is not first:
            pl.append_points(pts)
            last = pts[-1]
        assert pl.target_m == last
        for _ in range(ticks):
            chk.tick()
    if stop_at_end:
        pl.stop()
        # braking along a corner arc has only the tangential share of the acceleration
        slowest = amax * math.sqrt(1 - CORNER_ACCEL_FRACTION**2)
        chk.run_until_still(int(vmax / slowest / 0.002) + 5)
        with pytest.raises(QueueError, match="no path"):
            pl.append_points([last])
    else:
        chk.run_until_still(500_000)
        assert pl.position_m == last  # exactly: no overshoot
    assert pl.velocity_mps == (0.0, 0.0, 0.0)
    assert pl.queued_points == 0


def test_a_fine_circle_is_flown_at_the_requested_speed() -> None:
    # 1,000 points on a circle of 0.2 m at 0.1 m/s and 1 m/s^2: stopping at every point took
    # 70.9 s; flown through, it takes about length / speed.
    pts = circle_path(0.2, (0.0, 0.0), 1.0, steps=1000)
    length = sum(math.dist(a, b) for a, b in itertools.pairwise(pts))
    pl = MotionPlanner(1.0, 1.0)
    pl.hold(pts[0])
    pl.follow_path(pts, 0.1)
    dt = 0.002
    chk = Checker(pl, dt)
    ticks = chk.run_until_still(100_000)
    assert ticks * dt <= 1.10 * length / 0.1
    assert pl.position_m == pts[-1]
    travelled = 0.0
    prev = pts[0]
    for p, v in chk.trace:
        travelled += math.dist(prev, p)
        prev = p
        if 0.1 * length <= travelled <= 0.9 * length:
            assert norm(v) >= 0.09
        assert abs(math.hypot(p[0], p[1]) - 0.2) <= 1e-5  # on the circle (chords: 2e-6 m)


@pytest.mark.parametrize("jd", [0.005, 0.01, 0.05])
def test_square_corners_are_flown_at_the_junction_deviation_speed(jd: float) -> None:
    a = 2.0
    sq = [(1.0, 0.0, 1.0), (1.0, 1.0, 1.0), (0.0, 1.0, 1.0), (0.0, 0.0, 1.0)]
    pl = MotionPlanner(1.0, a, junction_deviation_m=jd)
    pl.hold((0.0, 0.0, 1.0))
    pl.follow_path(sq)
    chk = Checker(pl, 0.001)
    chk.run_until_still(100_000)
    want = junction_speed_mps(math.pi / 2, jd, a)
    assert want == pytest.approx(math.sqrt(a * jd * math.sqrt(0.5) / (1 - math.sqrt(0.5))))
    for corner in sq[:3]:
        p, v = min(chk.trace, key=lambda pv: math.dist(pv[0], corner))
        assert norm(v) == pytest.approx(want, rel=0.05)
        assert norm(v) == pytest.approx(want * math.sqrt(CORNER_ACCEL_FRACTION), rel=1e-3)
        assert math.dist(p, corner) <= jd * (1 + 1e-6) + 1e-3 * norm(v)


def test_junction_speed_formula() -> None:
    assert junction_speed_mps(math.pi, 0.01, 1.0) == math.inf  # straight on
    assert junction_speed_mps(0.0, 0.01, 1.0) == 0.0  # reversal
    theta = math.radians(120)
    s = math.sin(theta / 2)
    assert junction_speed_mps(theta, 0.02, 3.0) == pytest.approx(math.sqrt(3 * 0.02 * s / (1 - s)))
    with pytest.raises(ValueError):
        junction_speed_mps(math.nan, 0.01, 1.0)
    with pytest.raises(ValueError):
        junction_speed_mps(1.0, 0.0, 1.0)


def test_short_segments_shrink_the_corner() -> None:
    # Segments of 2 cm: a 90 degree blend may use at most 1 cm of each, so its radius is 1 cm
    # (not the 2.4 cm of a 1 cm deviation) and the corner is slower.
    pl = MotionPlanner(1.0, 1.0, junction_deviation_m=0.01)
    pl.hold((0.0, 0.0, 1.0))
    pl.follow_path([(0.02, 0.0, 1.0), (0.02, 0.02, 1.0), (0.0, 0.02, 1.0)])
    chk = Checker(pl, 0.0005)
    chk.run_until_still(100_000)
    p, v = min(chk.trace, key=lambda pv: math.dist(pv[0], (0.02, 0.0, 1.0)))
    assert norm(v) <= math.sqrt(CORNER_ACCEL_FRACTION * 1.0 * 0.01) * (1 + 1e-6)
    # the blend of radius 1 cm passes (sqrt(2) - 1) cm from the corner
    assert math.dist(p, (0.02, 0.0, 1.0)) == pytest.approx(0.01 * (math.sqrt(2) - 1), abs=2e-4)


def test_a_queue_that_runs_dry_rests_at_its_last_point_and_continues() -> None:
    pl = MotionPlanner(1.0, 1.0)
    pl.hold((0.0, 0.0, 1.0))
    pl.follow_path([(0.5, 0.0, 1.0), (0.5, 0.5, 1.0)], 0.5)
    chk = Checker(pl, 0.002)
    chk.run_until_still(10_000)
    assert pl.position_m == (0.5, 0.5, 1.0) and pl.velocity_mps == (0.0, 0.0, 0.0)
    assert pl.mode == "hold" and pl.appendable and pl.queued_points == 0
    pl.append_points([(0.0, 0.5, 1.0)])
    assert pl.moving and pl.target_m == (0.0, 0.5, 1.0)
    chk.run_until_still(10_000)
    assert pl.position_m == (0.0, 0.5, 1.0)


def test_an_append_before_the_end_flies_on_without_stopping() -> None:
    pl = MotionPlanner(1.0, 1.0)
    pl.hold((0.0, 0.0, 1.0))
    pl.follow_path([(1.0, 0.0, 1.0)], 0.5)
    chk = Checker(pl, 0.002)
    for _ in range(500):  # 1 s: cruising at 0.5 m/s, 0.75 m from the end
        chk.tick()
    pl.append_points([(1.0, 1.0, 1.0)])
    chk.run_until_still(10_000)
    assert pl.position_m == (1.0, 1.0, 1.0)
    speeds = [norm(v) for p, v in chk.trace if p[0] >= 0.9 and p[1] <= 0.1]
    assert min(speeds) >= 0.9 * junction_speed_mps(math.pi / 2, pl.junction_deviation_m, 1.0)


def test_queue_bound_depth_and_stop_at_any_depth() -> None:
    pl = MotionPlanner(1.0, 1.0, max_queued_points=100)
    pl.hold((0.0, 0.0, 1.0))
    with pytest.raises(QueueError, match="no path"):
        pl.append_points([(0.1, 0.0, 1.0)])
    pts = [(0.01 * i, 0.001 * (i % 2), 1.0) for i in range(1, 61)]
    pl.follow_path(pts, 0.5)
    assert pl.queued_points == 60 and not pl.queue_full
    length = sum(math.dist(a, b) for a, b in zip([(0.0, 0.0, 1.0), *pts], pts, strict=False))
    # seconds at the speed limits: at least length / speed, at most the time it takes
    twin = MotionPlanner(1.0, 1.0, max_queued_points=100)
    twin.hold((0.0, 0.0, 1.0))
    twin.follow_path(pts, 0.5)
    took_s = Checker(twin, 0.002).run_until_still(100_000) * 0.002
    assert length / 0.5 * (1 - 1e-9) <= pl.queued_s <= took_s
    with pytest.raises(QueueError, match="full"):
        pl.append_points([(1.0, 0.0, 1.0)] * 1 + [(1.0, 0.1 * i, 1.0) for i in range(1, 41)])
    assert pl.queued_points == 60  # unchanged
    pl.append_points([(1.0, 0.01 * i, 1.0) for i in range(1, 41)])
    assert pl.queued_points == 100 and pl.queue_full
    chk = Checker(pl, 0.002)
    for _ in range(300):
        chk.tick()
    assert 0 < pl.queued_points < 100
    pl.stop()
    assert pl.queued_points == 0 and pl.queued_s == 0.0
    chk.run_until_still(1000)
    assert pl.velocity_mps == (0.0, 0.0, 0.0)


def test_a_new_path_replaces_the_queue_after_braking() -> None:
    pl = MotionPlanner(1.0, 1.0)
    pl.hold((0.0, 0.0, 1.0))
    pl.follow_path([(1.0, 0.0, 1.0), (1.0, 1.0, 1.0)])
    chk = Checker(pl, 0.002)
    for _ in range(300):
        chk.tick()
    rest = pl.rest_point_m
    pl.follow_path([(0.0, 1.0, 1.0), (0.0, 0.0, 1.0)])
    pl.append_points([(0.5, 0.5, 1.0)])  # appends to the new path, waiting for the stop
    assert pl.target_m == (0.5, 0.5, 1.0) and pl.queued_points == 3
    chk.run_until_still(20_000)
    assert pl.position_m == (0.5, 0.5, 1.0)
    k = min(range(len(chk.trace)), key=lambda i: math.dist(chk.trace[i][0], rest))
    assert math.dist(chk.trace[k][0], rest) <= 1e-9  # braked to the rest point
    assert chk.trace[k][1] == (0.0, 0.0, 0.0)
    assert max(p[0] for p, _ in chk.trace[:k]) <= rest[0] + 1e-9  # never past it


def test_cable_speed_limit_slows_a_path_along_a_cable() -> None:
    # Straight at anchor 0: the whole speed goes into that cable's length.
    pl = MotionPlanner(1.0, 1.0, anchors_m=ANCHORS, max_cable_speed_mps=0.2)
    pl.hold((0.0, 0.0, 0.0))
    target = (-1.5, -1.5, 1.5)
    pl.follow_path([target])
    chk = Checker(pl, 0.002, 0.2)
    chk.run_until_still(50_000)
    assert pl.position_m == target
    assert chk.max_cable == pytest.approx(0.2, rel=1e-6)


@pytest.mark.parametrize("repeat_end", [False, True])
def test_a_corner_appended_while_braking_for_it_becomes_a_stop(repeat_end: bool) -> None:
    # Braking toward the end of the queue, the set-point is past the point where it could slow
    # down to the blend's speed: the corner is flown as a stop (every limit still holds).
    pl = MotionPlanner(1.0, 1.0, junction_deviation_m=0.01)
    pl.hold((0.0, 0.0, 1.0))
    pl.follow_path([(1.0, 0.0, 1.0)])
    chk = Checker(pl, 0.001)
    while pl.position_m[0] < 0.98:
        chk.tick()
    assert 0.0 < pl.velocity_mps[0] < 0.25
    # (a chunk may start with the point the queue ends at: the corner is still that point)
    pl.append_points([(1.0, 0.0, 1.0)] * repeat_end + [(1.0, 1.0, 1.0)])
    assert pl.blends_dropped == 1
    chk.run_until_still(20_000)
    assert pl.position_m == (1.0, 1.0, 1.0)
    assert min(math.dist(p, (1.0, 0.0, 1.0)) for p, _ in chk.trace) == 0.0  # stopped there
    # earlier (cruising), the same corner is rounded
    pl.hold((0.0, 0.0, 1.0))
    pl.follow_path([(1.0, 0.0, 1.0)])
    for _ in range(500):
        pl.advance(0.001)
    pl.append_points([(1.0, 1.0, 1.0)])
    assert pl.blends_dropped == 1


def _dist_to_segment(p: Vec3, a: Vec3, b: Vec3) -> float:
    ab = sub(b, a)
    ap = sub(p, a)
    ab2 = norm(ab) ** 2
    if ab2 == 0.0:  # a segment shorter than floats can square: its start
        return math.dist(p, a)
    t = max(0.0, min(1.0, sum(x * y for x, y in zip(ap, ab, strict=True)) / ab2))
    return math.dist(p, (a[0] + ab[0] * t, a[1] + ab[1] * t, a[2] + ab[2] * t))


@pytest.mark.parametrize("before_m", [0.3, 0.05, 0.0, -0.02])
def test_stop_brakes_along_the_path_through_a_corner(before_m: float) -> None:
    # A 30 degree corner flown at 0.5 m/s: braking takes 0.125 m, so a stop just before the
    # corner brakes through its arc (a straight stop would leave the path by centimetres).
    jd = 0.01
    pts: list[Vec3] = [(0.0, 0.0, 1.0), (2.0, 0.0, 1.0)]
    ang = math.radians(30)
    pts.append((2.0 + 2.0 * math.cos(ang), 2.0 * math.sin(ang), 1.0))
    pl = MotionPlanner(0.5, 1.0, junction_deviation_m=jd)
    pl.hold(pts[0])
    pl.follow_path(pts[1:])
    chk = Checker(pl, 0.001)
    while pl.position_m[0] < 2.0 - before_m:
        chk.tick()
    assert norm(pl.velocity_mps) == pytest.approx(0.5)
    rest = pl.rest_point_m
    brake_s = pl.brake_time_s
    pl.stop()
    assert pl.brake_time_s == pytest.approx(brake_s, rel=1e-6)
    assert pl.mode == "stop" and pl.queued_points == 0 and pl.target_m == rest
    with pytest.raises(QueueError):
        pl.append_points([(0.0, 0.0, 1.0)])
    ticks = chk.run_until_still(10_000)
    assert ticks * 0.001 <= 0.5 / (1.0 * math.sqrt(1 - CORNER_ACCEL_FRACTION**2)) + 0.01
    assert ticks * 0.001 == pytest.approx(brake_s, abs=0.0011)
    if before_m <= 0.05:
        assert brake_s > 0.5 / 1.0 + 0.01  # part of it on the arc: longer than v / a
    assert pl.position_m == rest
    assert pl.mode == "hold" and not pl.appendable
    for p, _ in chk.trace:
        near = min(_dist_to_segment(p, a, b) for a, b in itertools.pairwise(pts))
        assert near <= jd + 1e-9


def test_bench_planning_returns_its_figures() -> None:
    from controller.core.motion_bench import bench_planning

    figs = bench_planning(points=300, repeats=1, ticks=20, queued=2_000)
    for key in (
        "plan_us_per_point",
        "append_us_per_point",
        "advance_us_10",
        "advance_us_100k",
        "advance_us_100k_staged",
    ):
        assert math.isfinite(figs[key]) and figs[key] > 0.0, key
    assert figs["circle_ideal_s"] == pytest.approx(2 * math.pi * 0.2 / 0.1, rel=1e-4)
    assert figs["circle_ideal_s"] <= figs["circle_s"] <= 1.10 * figs["circle_ideal_s"]
    with pytest.raises(ValueError):
        bench_planning(points=0)


@settings(max_examples=30, deadline=None)
@given(
    point,
    st.lists(point, min_size=2, max_size=8),
    st.floats(0.2, 2.0),
    st.floats(0.5, 5.0),
    st.floats(0.002, 0.05),
    st.integers(1, 3000),
    st.booleans(),
)
def test_a_stop_or_a_new_path_at_any_moment_brakes_along_the_path(
    start: Vec3,
    pts: list[Vec3],
    vmax: float,
    amax: float,
    jd: float,
    ticks: int,
    new_path: bool,
) -> None:
    pl = MotionPlanner(vmax, amax, junction_deviation_m=jd)
    pl.hold(start)
    pl.follow_path(pts)
    chk = Checker(pl, 0.002)
    for _ in range(ticks):
        if not pl.moving:
            break
        chk.tick()
    rest = pl.rest_point_m
    was_moving = pl.velocity_mps != (0.0, 0.0, 0.0)
    if new_path:
        pl.move_to(start)
        assert pl.target_m == start
    else:
        pl.stop()
        assert pl.target_m == rest
    n = len(chk.trace)
    chk.run_until_still(500_000)
    assert pl.velocity_mps == (0.0, 0.0, 0.0)
    assert pl.position_m == (start if new_path else rest)
    legs = [(a, b) for a, b in itertools.pairwise([start, *pts]) if a != b]
    # until it first comes to rest after the command, it stays on the path (within delta)
    end = next((i for i in range(n, len(chk.trace)) if chk.trace[i][1] == (0.0, 0.0, 0.0)), None)
    if legs and was_moving:
        assert end is not None
        assert chk.trace[end][0] == rest  # where `rest_point_m` said
        for p, _ in chk.trace[: end + 1]:
            assert min(_dist_to_segment(p, a, b) for a, b in legs) <= jd + 1e-9


def test_a_dropped_blend_keeps_the_next_corners_trim() -> None:
    """A chunk of several points appended while the set-point flies the line to the old last
    point: the blend there would leave it no room to brake and is dropped (a stop at the
    corner), while the chunk's next corner keeps its blend. The line between them must end
    where that blend begins: it used to run on to the corner and the set-point then jumped
    3 cm back to the blend's start and stayed there, short of the end."""
    pl = MotionPlanner(1.0, 2.0, junction_deviation_m=0.02)
    pl.hold((0.0, 0.0, 1.0))
    chk = Checker(pl, 0.002)
    pl.follow_path([(0.0, 0.5, 1.0)])
    for _ in range(244):
        chk.tick()
    pl.append_points([(0.0, 0.0, 1.5), (0.0, 0.0, 1.0)])
    chk.run_until_still(20_000)
    assert pl.blends_dropped == 1
    assert pl.position_m == (0.0, 0.0, 1.0)
