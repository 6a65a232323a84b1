"""The planner's modes besides paths: braking along a straight line (`stop` off a path), the
streamed set-point limiter and velocity input (behaviour: the package docstring)."""

from __future__ import annotations

import math
from collections.abc import Sequence

from .queue import _PathQueue
from .speeds import _HOLD, _MOVE, _STOP, _STREAM, _VELOCITY, _ZERO, Vec3, _finite3, clamp_velocity


class _Modes(_PathQueue):
    """`MotionPlanner`'s stop off a path, stream and velocity modes."""

    def stream(self, target_m: Sequence[float]) -> None:
        """Chase `target_m` (latest wins) under the speed and acceleration limits.

        Replaces any move, path or stop in progress; the current velocity is kept, so the
        hand-over is smooth. Raises ValueError on a non-finite target.
        """
        self._stream_target = _finite3(target_m, "target_m")
        self._clear_path()
        self._mode = _STREAM

    def command_velocity(self, velocity_mps: Sequence[float]) -> bool:
        """Fly at `velocity_mps` (one velocity-input sample; see the module docstring).

        The norm is clamped to max speed (`clamp_velocity`; below `MIN_SPEED_MPS` it is zero)
        and the dead-man timer restarts. A non-zero sample enters velocity mode from any mode,
        keeping the current velocity; a zero sample brakes to a hold in velocity mode and is
        ignored in any other. Returns True if the sample was taken, False if ignored.
        Raises ValueError for a non-finite or malformed vector (the planner is unchanged).
        """
        v = clamp_velocity(velocity_mps, self.max_speed_mps)
        if self._mode != _VELOCITY:
            if v == _ZERO:
                return False
            self._clear_path()
            self._mode = _VELOCITY
        self._vel_cmd = v
        self._vel_age_s = 0.0
        if v == _ZERO and self._v == _ZERO:
            self._mode = _HOLD  # at rest already: nothing to brake
        return True

    def _begin_stop(self) -> None:
        s = self._speed()
        v = self._v
        self._q.clear()
        self._staged.clear()
        self._staged_points = 0
        self._staged_s = 0.0
        self._queued_points = 0
        self._queued_s = 0.0
        self._queued_m = 0.0
        self._open = False
        self._stop_start = self._p
        self._stop_unit = (v[0] / s, v[1] / s, v[2] / s)
        self._stop_speed = s
        self._t_s = 0.0
        self._mode = _STOP

    def _advance_stop(self, dt_s: float) -> None:
        a = self.max_accel_mps2
        t = self._t_s + dt_s
        s0 = self._stop_speed
        t_end = s0 / a
        if t >= t_end:
            self._p = self._stop_point()
            self._v = _ZERO
            self._t_s = 0.0
            if self._next_path:  # a path that arrived while moving starts from the stop point
                self._start_next()
                leftover = t - t_end
                if self._mode == _MOVE and leftover > 0.0:
                    self._advance_move(leftover)
            else:
                self._mode = _HOLD
            return
        self._t_s = t
        d = s0 * t - 0.5 * a * t * t
        s = s0 - a * t
        u = self._stop_unit
        p = self._stop_start
        self._p = (p[0] + u[0] * d, p[1] + u[1] * d, p[2] + u[2] * d)
        self._v = (u[0] * s, u[1] * s, u[2] * s)

    def _advance_stream(self, dt_s: float) -> None:
        a = self.max_accel_mps2
        p = self._p
        v = self._v
        g = self._stream_target
        ex = g[0] - p[0]
        ey = g[1] - p[1]
        ez = g[2] - p[2]
        d = math.hypot(ex, ey, ez)
        # Desired velocity: toward the target at the fastest speed from which the discrete
        # braking sequence (speeds k*a*dt, k = n..1, semi-implicit Euler) still stops on it, and
        # never more than d/dt (land exactly) or max speed.
        if d > 0.0:
            x2 = 2.0 * d / (a * dt_s * dt_s)
            n = x2 / (math.sqrt(0.25 + x2) + 0.5)  # = sqrt(1/4 + x2) - 1/2 without cancellation
            want = min(self.max_speed_mps, n * a * dt_s, d / dt_s)
            k = want / d
            wx, wy, wz = ex * k, ey * k, ez * k
        else:
            wx = wy = wz = 0.0
        # Move the velocity toward the desired one by at most a*dt (keeps |v| <= max speed
        # because the new velocity lies on the segment between two vectors within the ball).
        cx, cy, cz = wx - v[0], wy - v[1], wz - v[2]
        c = math.hypot(cx, cy, cz)
        dv_max = a * dt_s
        clipped = c > dv_max
        if clipped:
            k = dv_max / c
            cx, cy, cz = cx * k, cy * k, cz * k
        nv = (v[0] + cx, v[1] + cy, v[2] + cz)
        if d > 0.0 and not clipped and want == d / dt_s:
            self._p = g  # lands exactly this tick (removes rounding residue)
        else:
            self._p = (p[0] + nv[0] * dt_s, p[1] + nv[1] * dt_s, p[2] + nv[2] * dt_s)
        self._v = nv

    def _advance_velocity(self, dt_s: float) -> None:
        a = self.max_accel_mps2
        age = self._vel_age_s + dt_s
        self._vel_age_s = age
        w = self._vel_cmd
        if age > self.velocity_timeout_s and w != _ZERO:
            w = self._vel_cmd = _ZERO  # dead-man: no fresh sample, brake to a hold
            self.deadman_stops += 1
        p = self._p
        v = self._v
        dv_max = a * dt_s
        # The velocity moves toward the command by at most a*dt (stays within the ball of
        # radius max speed: both ends of the segment are in it).
        cx, cy, cz = w[0] - v[0], w[1] - v[1], w[2] - v[2]
        c = math.hypot(cx, cy, cz)
        if c > dv_max:
            k = dv_max / c
            cx, cy, cz = cx * k, cy * k, cz * k
        nv: Vec3 = (v[0] + cx, v[1] + cy, v[2] + cz)
        check = self._check_segment
        if check is not None and nv != _ZERO:
            s = math.hypot(nv[0], nv[1], nv[2])
            np_ = (p[0] + nv[0] * dt_s, p[1] + nv[1] * dt_s, p[2] + nv[2] * dt_s)
            k = s / (2.0 * a)  # braking distance / speed
            rest = (np_[0] + nv[0] * k, np_[1] + nv[1] * k, np_[2] + nv[2] * k)
            if check(np_, rest) is not None:
                # Brake along the current velocity: stays on the segment checked last tick.
                self.boundary_brakes += 1
                s0 = math.hypot(v[0], v[1], v[2])
                if s0 <= dv_max:
                    nv = _ZERO
                else:
                    f = 1.0 - dv_max / s0
                    nv = (v[0] * f, v[1] * f, v[2] * f)
        if nv == _ZERO:
            self._v = _ZERO
            if w == _ZERO:
                self._mode = _HOLD  # at rest with nothing commanded: velocity mode ends
            return
        self._p = (p[0] + nv[0] * dt_s, p[1] + nv[1] * dt_s, p[2] + nv[2] * dt_s)
        self._v = nv
