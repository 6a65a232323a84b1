"""Motion: trapezoidal straight-line moves, paths flown through their points with rounded
corners and look-ahead, a queue for jobs of any length, stop-to-hold, streamed set-points,
velocity input.

Everything here is deterministic and clock-free: the control loop calls
`MotionPlanner.advance(dt_s)` once per tick with the tick's time step and gets the new position
set-point. The per-tick path uses plain Python floats and 3-tuples (no numpy, no allocation
beyond a few tuples), so it costs a few microseconds, whatever the length of the path.

Behaviour:

* `TrapezoidMove`: rest-to-rest straight line, accelerate at `max_accel_mps2`, cruise at
  `max_speed_mps`, decelerate; a triangular profile when the distance is too short to reach the
  cruise speed. Its duration is the minimum possible under both limits.
* Paths (`MotionPlanner.follow_path`, `append_points`; `move_to` is a one-point path) are flown
  through their points, not stopped at each (how paths are flown, for users: docs/motion.md):

  - Corners are rounded. Printer firmware (Grbl, Marlin, Klipper) limits a corner's speed by
    "junction deviation" (Sonny Jeon's method in Grbl's planner: the speed at which a circle
    tangent to both segments, passing `delta` from the corner, has centripetal acceleration
    `a`) and then turns the velocity instantly, a jump that makes a hanging effector swing.
    cablebot flies that circle: each corner is an arc of radius
    R = delta * sin(theta/2) / (1 - sin(theta/2)), tangent to both segments, with theta the
    angle between the segments as Grbl defines it (180 degrees = straight on), and delta =
    `junction_deviation_m` (default `DEFAULT_JUNCTION_DEVIATION_M`). On it the speed is at most
    v = sqrt(a * R) * sqrt(CORNER_ACCEL_FRACTION): Grbl's junction speed
    v = sqrt(a * delta * sin(theta/2) / (1 - sin(theta/2))) scaled by sqrt(0.95) = 0.975, so a
    printer user's settings carry over; the 5 % of centripetal acceleration held back leaves 31 %
    of `max_accel_mps2` to change speed along the arc (|a| = hypot(v^2 / R, tangential) stays
    within `max_accel_mps2`), so a path made only of arcs (a finely sampled circle) can still
    speed up and slow down. `junction_speed_mps` is the formula.
  - The arc's tangent points lie R * tan(turn/2) from the corner; that length is capped at half
    of each adjoining segment, so consecutive blends never overlap. Where it is capped, the arc
    is smaller than delta allows (it passes closer to the corner) and its speed lower. A turn
    below `STRAIGHT_RAD` is straight on (no arc); a full reversal is a stop.
  - Speed limits: each straight piece at most its path's speed (clamped to `max_speed_mps`);
    with `anchors_m` every cable's speed |u . v| (u: the unit vector to the anchor) within
    `max_cable_speed_mps` along every piece. Along a straight line the angle to a fixed anchor
    changes monotonically, so the extreme of |u . d| is at an end of the segment; on an arc the
    tangent is c1 d1 + c2 d2 with c1, c2 >= 0, c1 + c2 <= 1 / cos(turn/2), and every arc point
    lies within the tangent length L of the corner (which turns u by at most 2 L / D for an
    anchor D away), so |u . t| <= max(|u . d1|, |u . d2|) / cos(turn/2) + 2 L / D bounds it
    safely.
  - Look-ahead over everything queued (a backward pass as in Grbl's and Klipper's planners):
    each junction's speed is at most what lets the set-point brake, at the pieces' own
    acceleration limits, to rest at the last queued point. So an empty queue never overshoots:
    the set-point comes to rest exactly at the last point and continues when more arrives
    (`append_points`). Each piece's profile is the fastest trapezoid from its entry speed under
    its cap, ending at the highest speed the pass allows; it is built when the set-point enters
    the piece (and rebuilt from the current state when an append raises its exit speed), so the
    velocity is continuous everywhere, corners included, and |acceleration| <= `max_accel_mps2`.
  - Incremental: appending points plans their pieces and walks back only over the tail whose
    speeds change (those within braking distance of the old end; Klipper's lookahead queue in
    `toolhead.py` flushes the same way), amortised O(1) per point. A blend at the previous last
    point is decided when the next point arrives; if the set-point is already braking for that
    point too hard to slow to the blend's speed, the corner is flown as a stop instead
    (counted in `blends_dropped`), so a late append never breaks a limit.
  - Cost: `advance` samples the head piece (a few arithmetic operations, a sine and a cosine on
    an arc) and plans at most `PLAN_POINTS_PER_CALL` staged points, only while the planned
    distance ahead is shorter than twice the braking distance from max speed (further points
    cannot change the speeds flown now). So neither a path nor an append costs the tick in
    proportion to its length, and a tick's cost does not depend on how much is queued. One
    `advance` crosses at most `MAX_LEGS_PER_ADVANCE` pieces: a path of pieces so short that
    more of them fit in one tick runs slower than planned (the rest of the tick is dropped:
    the trajectory is sampled late, which keeps every limit).
  - The queue holds at most `max_queued_points` points (`queued_points`, `queued_s`,
    `queue_full`); an append beyond it, or with no path in progress, raises `QueueError`.
  - A new move or path that arrives while the effector is moving first brakes to a stop (along
    the path on a path, as `stop` does; else along the current direction at `max_accel_mps2`),
    then starts from the stop point (appends made meanwhile join the new path). Zero-length
    segments are dropped.
* `MotionPlanner.stop`: brake to a hold at any queue depth and close the path (appends are
  refused until a new path). On a path it brakes along the path, through corners: the queue is
  cut where braking at each piece's own limit ends (`max_accel_mps2` on a straight piece, the
  tangential share, 31 % of it at the arc's speed limit, on a corner arc: a stop through a
  corner takes longer), and that point is `rest_point_m`; the look-ahead guarantees it is not
  beyond the last queued point. Otherwise (stream, velocity input) it brakes along the current
  velocity direction at `max_accel_mps2`; the stop point is `position + v^2/(2 a)` along it.
* `MotionPlanner.stream`: the set-point chases the latest target with speed <= max speed and
  |change of velocity| <= max accel * dt per tick (a vector bang-bang limiter along the error
  direction with a discrete-time braking curve, so it lands on a fixed target without
  overshoot and holds there exactly).
* `MotionPlanner.command_velocity`: velocity input (a joystick, an RC stick). The commanded
  velocity's norm is clamped to `max_speed_mps`; every tick the set-point velocity moves toward
  it by at most `max_accel_mps2 * dt` (semi-implicit: the position advances by the new velocity),
  so speed and acceleration stay within the limits whatever the input. Dead-man: once a sample
  is older than `velocity_timeout_s` of planner time, the command becomes zero. A zero command
  (or one slower than `MIN_SPEED_MPS`) brakes at `max_accel_mps2` along the current velocity to
  a hold, and the planner then leaves velocity mode. A zero sample outside velocity mode is
  ignored (`command_velocity` returns False): a centred stick that keeps streaming zeros never
  stops a move; a non-zero sample takes over from any mode (hold, move, path, stop, stream) with
  the current velocity kept, like `stream`. A move, path, stream or stop replaces velocity mode.
* Workspace in velocity mode (`check_segment`, the workspace's straight-segment check): before
  a tick's new set-point is taken, the planner looks ahead by the braking distance |v|^2/(2 a)
  along the new velocity; if the segment from the new set-point to that rest point leaves the
  workspace, it brakes along the current velocity instead. Braking stays on the segment checked
  on the previous tick (its discrete rest point is never beyond the continuous one), so by
  induction every set-point, and every braking path, stays inside: pushing into a boundary
  stops just short of it. The induction needs the hand-over state's braking path inside, which
  a move or path guarantees (its legs are checked); a stream does not, and the control loop's
  own check of every set-point stays the last guard.
* Speeds: `check_speed` is the rule for a commanded speed (finite and at least `MIN_SPEED_MPS`;
  the command boundary and the control loop refuse others with its reason). Speeds above
  `max_speed_mps` given to `move_to`/`follow_path` are clamped to it; the control loop says so in
  its reply.
"""

from __future__ import annotations

from .circle import circle_path
from .corners import junction_speed_mps
from .planner import MotionPlanner
from .queue import QUEUE_FULL, QueueError
from .speeds import (
    BRAKE_ACCEL_SHARE,
    CORNER_ACCEL_FRACTION,
    DEFAULT_JUNCTION_DEVIATION_M,
    DEFAULT_MAX_QUEUED_POINTS,
    DEFAULT_VELOCITY_TIMEOUT_S,
    MAX_LEGS_PER_ADVANCE,
    MIN_SPEED_MPS,
    PLAN_POINTS_PER_CALL,
    STRAIGHT_RAD,
    SegmentCheck,
    TrapezoidMove,
    Vec3,
    check_speed,
    clamp_velocity,
    dedupe_path,
)

__all__ = [
    "BRAKE_ACCEL_SHARE",
    "CORNER_ACCEL_FRACTION",
    "DEFAULT_JUNCTION_DEVIATION_M",
    "DEFAULT_MAX_QUEUED_POINTS",
    "DEFAULT_VELOCITY_TIMEOUT_S",
    "MAX_LEGS_PER_ADVANCE",
    "MIN_SPEED_MPS",
    "PLAN_POINTS_PER_CALL",
    "QUEUE_FULL",
    "STRAIGHT_RAD",
    "MotionPlanner",
    "QueueError",
    "SegmentCheck",
    "TrapezoidMove",
    "Vec3",
    "check_speed",
    "circle_path",
    "clamp_velocity",
    "dedupe_path",
    "junction_speed_mps",
]
