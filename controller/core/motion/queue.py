"""The path queue: staging, planning points into pieces with their blends, the backward
(look-ahead) pass, the head's speed profile, flying the head, braking along the path
(behaviour: the package docstring)."""

from __future__ import annotations

import itertools
import math
from collections import deque

from .corners import _Piece, _point_at, _State
from .speeds import _HOLD, _MOVE, _STOP, _ZERO, MAX_LEGS_PER_ADVANCE, PLAN_POINTS_PER_CALL, Vec3

QUEUE_FULL = "path queue full"
"""How a `QueueError` for a full queue begins (a client that streams a job waits and retries)."""


class QueueError(ValueError):
    """An append the path queue refuses: no path in progress to append to, or the queue would
    hold more than its bound of points. The planner is unchanged."""


class _PathQueue(_State):
    """The path queue of `MotionPlanner` (its pieces, their planning and flying)."""

    # ----------------------------------------------------------------------------- the queue
    def _clear_path(self) -> None:
        self._q.clear()
        self._staged.clear()
        self._open = False
        self._stopping = False
        self._next_path = []
        self._next_points = 0
        self._staged_points = 0
        self._staged_s = 0.0
        self._queued_points = 0
        self._queued_s = 0.0
        self._queued_m = 0.0

    def _stage(self, pts: tuple[Vec3, ...], speed: float) -> None:
        self._staged.append((pts, 0, speed))
        self._staged_points += len(pts)
        # seconds at the requested speed (the straight legs' length: an estimate until planned)
        prev = self._staged[-2][0][-1] if len(self._staged) > 1 else self._last_point()
        length = 0.0
        for p in pts:
            length += math.dist(prev, p)
            prev = p
        self._staged_s += length / speed

    def _last_point(self) -> Vec3:
        if self._mode == _STOP:
            return self._stop_point()
        return self._last if self._q else self._p

    def _after_plan(self) -> None:
        if self._mode == _MOVE and not self._q and not self._staged:
            self._mode = _HOLD  # nothing to fly (every point repeats the set-point)
            self._v = _ZERO

    def _plan(self, max_points: int, force: bool = False) -> int:
        """Plan staged points into pieces (at most `max_points`, and unless `force` only while
        the planned distance is short of the look-ahead horizon), then run the backward pass
        and re-plan the head. Returns the number of points taken."""
        staged = self._staged
        if not staged:
            return 0
        if not force and self._q and self._queued_m - self._q[0].length >= self._horizon_m:
            return 0
        q = self._q
        if not q:  # starting from rest at the set-point
            self._last = self._p
            self._t_s = self._s0 = self._v0 = 0.0
        taken = 0
        fresh0 = len(q)
        undo: tuple[_Piece, Vec3, float, _Piece | None, _Piece] | None = None
        first = True
        while staged and taken < max_points:
            pts, i, speed = staged[0]
            take = min(len(pts) - i, max_points - taken)
            for j in range(i, i + take):
                if first and pts[j] != self._last:
                    # the first point added: its blend may trim a line planned before
                    undo = self._add_point(pts[j], speed)
                    first = False
                else:
                    self._add_point(pts[j], speed)
            taken += take
            seg_s = 0.0  # the staged estimate of what was just planned
            prev = pts[i - 1] if i > 0 else None
            for j in range(i, i + take):
                if prev is not None:
                    seg_s += math.dist(prev, pts[j])
                prev = pts[j]
            self._staged_points -= take
            self._staged_s = max(0.0, self._staged_s - seg_s / speed)
            if i + take >= len(pts):
                staged.popleft()
            else:
                staged[0] = (pts, i + take, speed)
        if not staged:
            self._staged_s = 0.0
            self._staged_points = 0
        fresh = len(q) - fresh0
        self._backward(fresh)
        if not self._head_feasible() and undo is not None:
            self._undo_blend(undo)
            self._backward(fresh)
            self.blends_dropped += 1
        self._replan_head()
        return taken

    def _add_point(
        self, p: Vec3, speed: float
    ) -> tuple[_Piece, Vec3, float, _Piece | None, _Piece] | None:
        """Queue the line to `p` (and the blend at the previous last point). Returns what
        `_undo_blend` needs if a blend trimmed a line that was already queued, else None."""
        last = self._last
        if p == last:
            return None
        dx, dy, dz = p[0] - last[0], p[1] - last[1], p[2] - last[2]
        l2 = math.hypot(dx, dy, dz)
        d2: Vec3 = (dx / l2, dy / l2, dz / l2)
        cap2 = min(speed, self._line_cable_cap(last, p, d2))
        a = self.max_accel_mps2
        q = self._q
        start = last
        start_off = 0.0
        trimmed: tuple[_Piece, Vec3, float, _Piece] | None = None
        if q:
            prev = q[-1]  # the line to `last`
            arc, lt = self._blend(prev, last, d2, l2, min(prev.cap, cap2))
            if arc is None and lt < 0.0:
                prev.jcap = 0.0  # a reversal: stop at the point
            elif arc is not None:
                old_end, old_len = prev.end, prev.length
                d1 = prev.d
                prev.length -= lt
                self._queued_m -= lt
                prev.end = (last[0] - d1[0] * lt, last[1] - d1[1] * lt, last[2] - d1[2] * lt)
                self._retime(prev)
                self._push(arc)
                start = arc.end
                start_off = lt
                trimmed = (prev, old_end, old_len, arc)
        line = _Piece(False, start, d2, p, l2 - start_off, cap2, a)
        line.seg = l2
        line.point = True
        self._push(line)
        self._queued_points += 1
        self._last = p
        if trimmed is not None:
            return (*trimmed, line)
        return None

    def _push(self, piece: _Piece) -> None:
        self._q.append(piece)
        self._queued_s += piece.tn
        self._queued_m += piece.length

    def _retime(self, piece: _Piece) -> None:
        """Update `piece.tn` and the queued seconds after its length or cap changed (the
        caller updates the queued length)."""
        old_tn = piece.tn
        tn = piece.length / piece.cap if piece.cap > 0.0 else 0.0
        piece.tn = tn
        self._queued_s += tn - old_tn

    def _undo_blend(self, undo: tuple[_Piece, Vec3, float, _Piece | None, _Piece]) -> None:
        """Fly the first corner of the last plan as a stop (no blend): restore the trimmed
        line, make the arc an empty piece at the corner and start the next line there."""
        prev, old_end, old_len, arc, line = undo
        self._queued_m += old_len - prev.length
        prev.end = old_end
        prev.length = old_len
        self._retime(prev)
        prev.jcap = 0.0
        if arc is not None:
            self._queued_m -= arc.length
            arc.length = 0.0
            self._retime(arc)
            arc.cap = 0.0
            arc.p0 = arc.end = old_end
            arc.vexit = 0.0
            # The line starts at the corner again; its end keeps any trim a later blend made
            # (a chunk of several points blends at each of them before this check).
            grow = math.dist(old_end, line.p0)
            self._queued_m += grow
            line.p0 = old_end
            line.length += grow
            self._retime(line)

    def _backward(self, fresh: int) -> None:
        """The backward pass: every piece's exit speed bound so that the set-point can stop at
        the end of the queue; walks back over the `fresh` new pieces, the trimmed line before
        them and then only while bounds change (amortised O(1) per point)."""
        nxt: _Piece | None = None
        for k, piece in enumerate(reversed(self._q)):
            if nxt is None:
                new = 0.0
            else:
                v2 = nxt.vexit * nxt.vexit + 2.0 * nxt.acc * nxt.length
                new = min(piece.cap, nxt.cap, piece.jcap, math.sqrt(v2))
            if k > fresh and new == piece.vexit:
                break
            piece.vexit = new
            nxt = piece

    def _head_state(self) -> tuple[float, float]:
        """Distance into the head piece and speed at the profile time `_t_s`."""
        t = self._t_s
        if t <= 0.0:
            return self._s0, self._v0
        if t < self._ta:
            return self._s0 + self._v0 * t + 0.5 * self._acc * t * t, self._v0 + self._acc * t
        t2 = t - self._ta
        if t2 < self._tc:
            return self._s0 + self._da + self._vp * t2, self._vp
        tau = self._dur - t
        if tau <= 0.0:
            return self._s0 + self._span, self._v1
        return (
            self._s0 + self._span - (self._v1 * tau + 0.5 * self._dec * tau * tau),
            self._v1 + self._dec * tau,
        )

    def _head_feasible(self) -> bool:
        q = self._q
        if not q or self._mode != _MOVE:
            return True
        head = q[0]
        s, v = self._head_state()
        rem = head.length - s
        if rem < -1e-12 * max(1.0, head.length):
            return False
        need = v * v - head.vexit * head.vexit
        return need <= 2.0 * head.acc * max(rem, 0.0) * (1.0 + 1e-9) + 1e-18

    def _replan_head(self) -> None:
        """The head's speed profile again from where the set-point is on it now."""
        q = self._q
        if not q:
            return
        if self._mode == _MOVE:
            s, v = self._head_state()
        else:
            s, v = 0.0, 0.0
        self._set_profile(q[0], s, v)

    def _set_profile(self, piece: _Piece, s0: float, v0: float) -> None:
        """The fastest profile over the rest of `piece` from speed `v0`, accelerating at most
        at `piece.acc`, never above its cap, ending at the highest speed <= `piece.vexit`."""
        d = max(0.0, piece.length - s0)
        acc = piece.acc
        v1 = min(piece.vexit, math.sqrt(v0 * v0 + 2.0 * acc * d))
        self._t_s = 0.0
        self._s0 = s0
        self._span = d
        self._v0 = v0
        self._v1 = v1
        self._acc = acc
        if d <= 0.0:
            self._v1 = v0 if v1 < v0 else v1
            self._vp = v0
            self._dec = acc
            self._ta = self._tc = self._td = self._da = self._dur = 0.0
            return
        if v0 * v0 - v1 * v1 >= 2.0 * acc * d:
            # only by rounding (the backward pass leaves room to brake): brake a hair harder
            self._vp = v0
            self._dec = (v0 * v0 - v1 * v1) / (2.0 * d)
            self._ta = self._tc = self._da = 0.0
            self._td = 2.0 * d / (v0 + v1)
            self._dur = self._td
            return
        vp2 = min(piece.cap * piece.cap, 0.5 * (2.0 * acc * d + v0 * v0 + v1 * v1))
        vp = max(math.sqrt(vp2), v0, v1)
        da = (vp * vp - v0 * v0) / (2.0 * acc)
        dd = (vp * vp - v1 * v1) / (2.0 * acc)
        dc = max(0.0, d - da - dd)
        self._vp = vp
        self._dec = acc
        self._da = da
        self._ta = (vp - v0) / acc
        self._td = (vp - v1) / acc
        self._tc = dc / vp if vp > 0.0 else 0.0
        self._dur = self._ta + self._tc + self._td

    def _start_path(self, chunks: list[tuple[tuple[Vec3, ...], float]]) -> None:
        """Start a path from the set-point at rest."""
        self._clear_path()
        self._open = True
        self._v = _ZERO
        self._last = self._p
        self._mode = _MOVE
        for pts, speed in chunks:
            self._stage(pts, speed)
        self._plan(PLAN_POINTS_PER_CALL)
        self._after_plan()

    def _advance_move(self, dt_s: float) -> None:
        q = self._q
        if not q:
            self._dry()
            return
        t = self._t_s + dt_s
        crossed = 0
        while t >= self._dur:
            t -= self._dur
            piece = q.popleft()
            self._queued_s -= piece.tn
            self._queued_m -= piece.length
            if piece.point:
                self._queued_points -= 1
            self._p = piece.end
            v1 = self._v1
            if not q:
                self._queued_s = self._queued_m = 0.0
                self._v = _ZERO
                self._t_s = 0.0
                if not self._staged:
                    self._dry()
                return
            self._set_profile(q[0], 0.0, v1)
            crossed += 1
            if crossed >= MAX_LEGS_PER_ADVANCE:
                t = 0.0  # the rest of this step is dropped: the path runs a little late
                break
        self._t_s = t
        self._sample(q[0])

    def _dry(self) -> None:
        """The queue ran dry: at rest at its last point, the path still takes appends (unless
        it was stopped; a path that arrived meanwhile starts now)."""
        self._v = _ZERO
        self._t_s = 0.0
        self._mode = _HOLD
        if self._next_path:
            self._start_next()
        elif self._stopping:
            self._clear_path()

    def _start_next(self) -> None:
        chunks = self._next_path
        self._next_path = []
        self._next_points = 0
        self._start_path(chunks)

    def _path_brake(self) -> tuple[int, float]:
        """Where braking along the queued pieces, each at its own acceleration limit, ends:
        (index of the piece, distance into it). Walks only the pieces within braking distance."""
        s, v = self._head_state()
        v2 = v * v
        q = self._q
        for k, piece in enumerate(q):
            start = s if k == 0 else 0.0
            rem = max(0.0, piece.length - start)
            room = 2.0 * piece.acc * rem
            if v2 <= room:
                return k, start + (v2 / (2.0 * piece.acc) if v2 > 0.0 else 0.0)
            v2 -= room
        return len(q) - 1, q[-1].length  # only by rounding: the end of the queue

    def _stop_on_path(self) -> None:
        """Cut the queue where braking along the path ends and brake there (at any depth)."""
        k, dist = self._path_brake()
        q = self._q
        if k + 1 < len(q):
            self._q = q = deque(itertools.islice(q, k + 1))
        piece = q[k]
        if dist < piece.length:
            piece.end = _point_at(piece, dist)
            piece.length = dist
        self._staged.clear()
        self._staged_points = 0
        self._staged_s = 0.0
        self._queued_points = 0
        self._queued_s = self._queued_m = 0.0
        for p in q:
            p.point = False
            p.tn = p.length / p.cap if p.cap > 0.0 else 0.0
            self._queued_s += p.tn
            self._queued_m += p.length
        self._last = piece.end
        self._backward(len(q))
        self._replan_head()
        self._stopping = True
        self._open = False

    def _sample(self, piece: _Piece) -> None:
        s, v = self._head_state()
        d = piece.d
        p = piece.p0
        if not piece.arc:
            self._p = (p[0] + d[0] * s, p[1] + d[1] * s, p[2] + d[2] * s)
            self._v = (d[0] * v, d[1] * v, d[2] * v)
            return
        r = piece.r
        psi = s / r
        sn = math.sin(psi)
        cs = math.cos(psi)
        a = r * sn
        b = 2.0 * r * math.sin(0.5 * psi) ** 2  # r (1 - cos psi)
        n = piece.n
        self._p = (
            p[0] + d[0] * a + n[0] * b,
            p[1] + d[1] * a + n[1] * b,
            p[2] + d[2] * a + n[2] * b,
        )
        self._v = (
            v * (d[0] * cs + n[0] * sn),
            v * (d[1] * cs + n[1] * sn),
            v * (d[2] * cs + n[2] * sn),
        )
