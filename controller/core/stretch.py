"""Cable stretch: the paid-out (unstretched) length of an elastic cable under its tension.

Pure module (``math``; the kinematics and statics of this package), no I/O, no threads.

Model
-----
Cable ``i`` runs straight from its anchor ``A_i`` to the effector ``P`` with the geometric length
``L_i = |A_i - P|``.  Under the tension ``t_i`` an elastic cable of axial stiffness ``EA_i``
(newtons) is longer than what its reel has paid out, ``L0_i``: Hooke's law ``t = EA (L - L0) /
L0`` gives

    L0_i = L_i * EA_i / (EA_i + t_i)        L_i = L0_i * (EA_i + t_i) / EA_i

A cable without an EA is rigid (``L0 = L``).  Quasi-static stretch: the tensions are those the
controller plans (``controller.core.statics``, the distribution farthest from the tension
limits, plus the payload's m a while it accelerates: ``controller.core.inertia``) or, where the
caller has them, measured ones; cable mass, sag and the effector's vibration are not modelled
(``docs/cable-stretch.md``).

* IPK (``CableStretch.ipk`` / ``paid_out_m``): the geometric lengths at the set-point, then the
  paid-out lengths under the planned tensions there.  With these commanded, the cables at rest
  pull the planned tensions and hold the effector at the set-point.
* FPK (``CableStretch.fpk``): the pose whose planned tensions stretch the cables to the measured
  paid-out lengths, i.e. the least-squares solution of ``r_i(P) = |A_i - P| * EA_i / (EA_i +
  t_i(P)) - L0_i = 0``.  A fixed point "pose -> tensions -> stretch -> pose" diverges where the
  tensions change fast with the pose (close under the anchor plane the stretch's derivative
  outgrows the geometric one), so this is Gauss-Newton on the joint equations.  A statics
  solve costs over ten times the cable lengths, so each pass linearises the tensions about a
  point P0, ``t(P) = t(P0) + T' (P - P0)`` (``t(P0)`` reused while the warm start is within
  ``TENSIONS_REUSE_M``; its derivative ``T'`` analytic for up to four cables, taken with the
  statics solve by ``CableStatics.solve_with_derivative``, and kept between calls while
  within ``JACOBIAN_REUSE_M``) and solves the smooth equations that gives
  with the analytic Jacobian; a pass that ends farther than ``RELINEARISE_M`` from P0 is
  followed by one linearised at its result.  The linearisation's error grows with the square
  of the distance to P0 and with the tensions' curvature, largest close under the anchors with
  soft cables: on the paper robot with EA 2e5 N near (0, 0, 6) m it stays below 20 um while
  the pose moves 8 mm per call (2 m/s at 250 Hz), 10 um at 4 mm, and below 2 um at rest
  (``tests/core/test_stretch.py``).
  Warm-started from the last pose a tick earlier, one pass and at most one statics solve; the
  loop also hands in its set-point and the tensions it planned there (solved anyway for the
  tension check), which linearise the pass while the pose is within ``PLANNED_REUSE_M``, and
  the derivative its solve there takes when ``wants_derivative`` says the FPK needs one
  (``take_derivative``): then the call solves no statics and takes no derivative.
* FPK with measured tensions (``fpk_measured``): the geometric lengths follow directly from the
  paid-out ones and the tensions; one rigid FPK, no iteration.

Errors: ``KinematicsError`` (and ``StretchError``, a subclass, for what is specific to stretch:
no tensions at an iterate, no convergence) for bad inputs and for lengths no pose explains;
``StaticsError`` subclasses never escape ``fpk``.  Nothing returns NaN or inf.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from controller.core.kinematics import Geometry, KinematicsError, fpk, ipk_point
from controller.core.statics import StaticsError, TensionCheck

__all__ = [
    "COLD_START_STRAINS",
    "FD_STEP_M",
    "JACOBIAN_REUSE_M",
    "MAX_ITERATIONS",
    "MAX_PASSES",
    "MAX_STEP_M",
    "PLANNED_REUSE_M",
    "RELINEARISE_M",
    "STALL_TOL_M",
    "STEP_TOL_M",
    "TENSIONS_REUSE_M",
    "CableStretch",
    "StretchError",
    "StretchFpk",
]

STEP_TOL_M = 1e-5
"""A pass has converged when its Gauss-Newton step is shorter than this, and the step is taken:
the steps shrink quadratically (each about 0.03 / m times the square of the one before on the
paper robot, ``tests/core/test_stretch.py``), so the next would be shorter than 1e-11 m."""
STALL_TOL_M = 1e-4
"""A step shorter than this that no longer lowers the residual ends the pass too (lengths no
pose meets exactly: the rounding of the residual, not the pose, moves then)."""
MAX_ITERATIONS = 30
"""Most Gauss-Newton steps of one pass of the FPK (no statics solve in a step)."""
MAX_PASSES = 20
"""Most passes (statics solve, linearised tensions, Gauss-Newton) of one FPK."""
TENSIONS_REUSE_M = 0.002
"""The statics solve of the last linearisation is reused by later solves whose warm start is
within this distance of it (the loop's poses a tick apart); farther, the statics is solved at
the warm start."""
RELINEARISE_M = 0.01
"""A pass whose result lies farther than this from its linearisation point is followed by one
linearised at its result (the tensions' curvature makes the linearisation's error grow with
the square of the distance)."""
MAX_STEP_M = 0.5
"""Longest Gauss-Newton step (a cold start far from the solution)."""
FD_STEP_M = 1e-5
"""Finite-difference step of the tension derivative where statics has no analytic one (more
than four cables, a degenerate pose): forward differences, one statics solve per axis."""
JACOBIAN_REUSE_M = 0.05
"""A tension derivative is reused by later solves within this distance of where it was
taken."""
PLANNED_REUSE_M = 0.025
"""Tensions handed in with a point (the loop's set-point and the tensions it planned there)
linearise the first pass when the warm start is within this distance of that point: no
statics solve in the FPK (``CableStretch.fpk``'s `planned`).  The warm start is the last
pose, a tick behind (8 mm at 2 m/s and 250 Hz, plus the set-point's lead); the pass's end,
not the warm start, decides whether the linearisation holds (``RELINEARISE_M``)."""
COLD_START_STRAINS = (0.0, 1e-3, 3e-3, 1e-2, 3e-2, 0.1)
"""Strains tried in turn for the first pose of a cold FPK (see ``CableStretch._cold_start``)."""


class StretchError(KinematicsError):
    """The stretch model cannot explain the lengths: no tensions at an iterate (a singular pose),
    or the solve did not converge."""


@dataclass(frozen=True, slots=True)
class StretchFpk:
    """One FPK with stretch: the pose, the RMS of the paid-out length mismatch (m), the tensions
    the stretch was computed with (N) and the Gauss-Newton steps taken (0 for measured ones)."""

    position_m: tuple[float, float, float]
    residual_m: float
    tensions_n: tuple[float, ...]
    iterations: int


def _compliances(ea_n: Sequence[float | None], n: int) -> tuple[float, ...]:
    if len(ea_n) != n:
        raise KinematicsError(f"cable EA has {len(ea_n)} values for {n} cables")
    out = []
    for i, ea in enumerate(ea_n):
        if ea is None:
            out.append(0.0)
            continue
        v = float(ea)
        if not (math.isfinite(v) and v > 0.0):
            raise KinematicsError(f"cable {i + 1}: EA must be finite and > 0 N, got {ea!r}")
        out.append(1.0 / v)
    return tuple(out)


class CableStretch:
    """The stretch model of one robot: its geometry, each cable's EA (None = rigid) and the
    payload's tension rule (`TensionCheck`, whose distribution gives the planned tensions).

    Holds the FPK's cached linearisation: one owner (the control loop) per instance.  Raises
    ``KinematicsError`` for a wrong count of EA values or an EA not finite and > 0, and when the
    tension rule's anchors are not the geometry's.
    """

    __slots__ = (
        "_anchors",
        "_c",
        "_dt",
        "_jac_at",
        "_lin_at",
        "_lin_t",
        "check",
        "ea_n",
        "geometry",
        "n",
        "rigid",
    )

    def __init__(
        self, geometry: Geometry, ea_n: Sequence[float | None], check: TensionCheck
    ) -> None:
        n = geometry.n_cables
        self.geometry = geometry
        self.n = n
        self._c = _compliances(ea_n, n)
        self.ea_n: tuple[float | None, ...] = tuple(None if e is None else float(e) for e in ea_n)
        self.rigid = all(c == 0.0 for c in self._c)
        if check.statics.anchors_m.shape != geometry.anchors_m.shape or not bool(
            (check.statics.anchors_m == geometry.anchors_m).all()
        ):
            raise KinematicsError("the tension rule's anchors are not the geometry's")
        self.check = check
        self._anchors: tuple[tuple[float, float, float], ...] = tuple(
            (float(a[0]), float(a[1]), float(a[2])) for a in geometry.anchors_m.tolist()
        )
        self._dt: tuple[tuple[float, float, float], ...] | None = None
        self._jac_at: tuple[float, float, float] = (math.inf, math.inf, math.inf)
        self._lin_at: tuple[float, float, float] = (math.inf, math.inf, math.inf)
        self._lin_t: tuple[float, ...] = ()

    def reset(self) -> None:
        """Forget the FPK's cached linearisation (the last statics solve and tension
        derivative): the next ``fpk`` solves both afresh.  Raises nothing."""
        self._dt = None
        self._jac_at = (math.inf, math.inf, math.inf)
        self._lin_at = (math.inf, math.inf, math.inf)
        self._lin_t = ()

    # ------------------------------------------------------------------ IPK

    def paid_out_m(
        self, lengths_m: Sequence[float], tensions_n: Sequence[float]
    ) -> tuple[float, ...]:
        """Paid-out lengths ``L * EA / (EA + t)`` of cables of geometric lengths `lengths_m`
        under `tensions_n` (a negative tension counts as none: a cable cannot push).

        The per-tick IPK step after ``ipk_point``; raises ``KinematicsError`` for a wrong count
        or a non-finite result.
        """
        c = self._c
        if len(lengths_m) != self.n or len(tensions_n) != self.n:
            raise KinematicsError(
                f"need {self.n} lengths and tensions, got {len(lengths_m)} and {len(tensions_n)}"
            )
        out = tuple(
            [
                lengths_m[i] / (1.0 + c[i] * t) if (t := tensions_n[i]) > 0.0 else lengths_m[i]
                for i in range(self.n)
            ]
        )
        s = sum(out)
        if s - s != 0.0:
            raise KinematicsError(f"paid-out lengths are not finite: {out!r}")
        return out

    def stretched_m(
        self, paid_m: Sequence[float], tensions_n: Sequence[float]
    ) -> tuple[float, ...]:
        """Geometric lengths ``L0 * (EA + t) / EA`` of cables paid out by `paid_m` under
        `tensions_n` (negative: none).  Raises ``KinematicsError`` for a wrong count or a
        non-finite result."""
        c = self._c
        if len(paid_m) != self.n or len(tensions_n) != self.n:
            raise KinematicsError(
                f"need {self.n} lengths and tensions, got {len(paid_m)} and {len(tensions_n)}"
            )
        out = tuple(
            [
                paid_m[i] * (1.0 + c[i] * t) if (t := tensions_n[i]) > 0.0 else paid_m[i]
                for i in range(self.n)
            ]
        )
        s = sum(out)
        if s - s != 0.0:
            raise KinematicsError(f"stretched lengths are not finite: {out!r}")
        return out

    def tensions_n(self, position_m: Sequence[float]) -> tuple[float, ...]:
        """The planned tensions at `position_m` (the tension rule's distribution, whether or
        not it keeps the limits).  Raises ``StretchError`` where statics has none."""
        try:
            return self.check.solve(position_m).tensions_n
        except StaticsError as exc:
            raise StretchError(f"no cable tensions at {_fmt(position_m)}: {exc}") from None

    def ipk(self, position_m: Sequence[float]) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """(paid-out lengths, planned tensions) that hold the payload at rest at `position_m`.

        Raises ``KinematicsError`` for a non-finite position, ``StretchError`` where statics
        has no tensions."""
        lengths = ipk_point(self.geometry, position_m)
        tensions = self.tensions_n(position_m)
        return self.paid_out_m(lengths, tensions), tensions

    # ------------------------------------------------------------------ FPK

    def _linearise(
        self, p: tuple[float, float, float], fresh: bool
    ) -> tuple[tuple[float, ...], tuple[tuple[float, float, float], ...]]:
        """The planned tensions at `p` and their derivative d t_i / d P, cached as the FPK's
        linearisation.  The derivative is kept while within ``JACOBIAN_REUSE_M`` of where it
        was taken unless `fresh`; a new one comes analytically with the tensions
        (``CableStatics.solve_with_derivative``: one statics solve), or where statics has none
        (more than four cables, a degenerate pose) by forward differences.  Raises
        ``StretchError`` where statics has no tensions."""
        d = self._dt
        try:
            if d is not None and not fresh and math.dist(self._jac_at, p) <= JACOBIAN_REUSE_M:
                t = self.check.solve(p).tensions_n
            else:
                t, d = self.check.statics.solve_with_derivative(p, self.check.mass_kg)
                if d is None:
                    d = self._fd_tension_jacobian(p, t)
                self._jac_at = p
        except StaticsError as exc:
            raise StretchError(f"no cable tensions at {_fmt(p)}: {exc}") from None
        self._lin_at, self._lin_t, self._dt = p, t, d
        return t, d

    def wants_derivative(self, position_m: Sequence[float]) -> bool:
        """True when the FPK near `position_m` (a set-point being planned) would take the
        tension derivative again: none kept, or the one kept is farther than
        ``JACOBIAN_REUSE_M``.  The loop then asks the statics solve it makes there for the
        derivative too and hands it over (``take_derivative``).  Raises nothing."""
        if self.rigid or self._dt is None:
            return not self.rigid
        return not math.dist(self._jac_at, position_m) <= JACOBIAN_REUSE_M

    def take_derivative(
        self,
        position_m: Sequence[float],
        derivative: Sequence[tuple[float, float, float]] | None,
    ) -> None:
        """Keep `derivative` (d t_i / d P of the planned tensions at `position_m`, N/m, from
        ``CableStatics.solve(..., derivative=True)``) for the FPK's next calls; None (no
        analytic one there) or a wrong count keeps what was kept.  Raises nothing."""
        if derivative is None or len(derivative) != self.n:
            return
        self._dt = tuple((float(g[0]), float(g[1]), float(g[2])) for g in derivative)
        self._jac_at = (float(position_m[0]), float(position_m[1]), float(position_m[2]))

    def _adopt(
        self, p: tuple[float, float, float], t: tuple[float, ...]
    ) -> tuple[tuple[float, ...], tuple[tuple[float, float, float], ...]]:
        """Tensions `t` planned at `p` (by the caller, with this model's tension rule) as the
        FPK's linearisation, with the derivative kept while within ``JACOBIAN_REUSE_M`` of
        where it was taken, else taken at `p` from those tensions (no statics solve).  Raises
        ``StretchError`` where statics has no derivative there."""
        d = self._dt
        if d is None or math.dist(self._jac_at, p) > JACOBIAN_REUSE_M:
            try:
                d = self.check.statics.tension_derivative(p, t)
                if d is None:
                    d = self._fd_tension_jacobian(p, t)
            except StaticsError as exc:
                raise StretchError(f"no cable tensions at {_fmt(p)}: {exc}") from None
            self._jac_at = p
        self._lin_at, self._lin_t, self._dt = p, t, d
        return t, d

    def _fd_tension_jacobian(
        self, p: tuple[float, float, float], t0: Sequence[float]
    ) -> tuple[tuple[float, float, float], ...]:
        """d t_i / d P by forward differences of the statics (three solves)."""
        h = FD_STEP_M
        cols = []
        for k in range(3):
            q = [p[0], p[1], p[2]]
            q[k] += h
            tk = self.tensions_n((q[0], q[1], q[2]))
            cols.append([(tk[i] - t0[i]) / h for i in range(self.n)])
        return tuple((cols[0][i], cols[1][i], cols[2][i]) for i in range(self.n))

    def _cold_start(self, paid: list[float]) -> tuple[float, float, float]:
        """A first pose without a last one: the rigid FPK of the paid-out lengths, or where
        those cannot meet (paid-out lengths shorter than any pose's: stretched cables close
        under the anchors), of the lengths stretched by a growing guess of the strain."""
        for strain in COLD_START_STRAINS:
            try:
                g = fpk(self.geometry, [v * (1.0 + strain) for v in paid]).position_m
            except KinematicsError:
                if strain == COLD_START_STRAINS[-1]:
                    raise
                continue
            break
        return (float(g[0]), float(g[1]), float(g[2]))

    def fpk(
        self,
        paid_m: Sequence[float],
        guess_m: Sequence[float] | None = None,
        planned: tuple[Sequence[float], Sequence[float]] | None = None,
    ) -> StretchFpk:
        """The pose whose planned tensions stretch the cables paid out by `paid_m` to reach
        it (module docstring), warm-started from `guess_m` (the last pose; None: the rigid FPK
        of the paid-out lengths).  `planned` is (a point, the tensions this model's tension
        rule plans there): the loop's set-point and its tensions, already solved for the
        tension check; within ``PLANNED_REUSE_M`` of the warm start they linearise the first
        pass, so the call solves no statics (at most the tension derivative there).

        Each pass linearises the tensions about a point P0, ``t(P) = t(P0) + T' (P - P0)``
        (``t(P0)`` by statics, reused while the warm start is within ``TENSIONS_REUSE_M`` of
        P0; ``T'`` analytic with a statics solve, or by finite differences where statics has
        none, kept while within ``JACOBIAN_REUSE_M``), then fits P
        by Gauss-Newton on the paid-out lengths with that smooth model; a pass that ends
        farther than ``RELINEARISE_M`` from P0 is followed by another linearised at its result.
        Warm-started a tick from the last pose: one pass, at most one statics solve.
        Raises ``KinematicsError`` for bad lengths (what ``kinematics.fpk`` raises when there is
        no guess) or a non-finite guess, ``StretchError`` when statics has no tensions at a
        pass's start or a solve does not converge.
        """
        n = self.n
        if len(paid_m) != n:
            raise KinematicsError(f"need {n} cable lengths, got {len(paid_m)}")
        paid = [float(v) for v in paid_m]
        for i, v in enumerate(paid):
            if not (0.0 < v < math.inf):
                raise KinematicsError(f"cable {i + 1}: length must be finite and > 0, got {v!r}")
        if self.rigid:
            res = fpk(self.geometry, paid, guess_m)
            g = res.position_m
            return StretchFpk((float(g[0]), float(g[1]), float(g[2])), res.residual_m, (), 0)
        if guess_m is None:
            p = self._cold_start(paid)
        else:
            p = (float(guess_m[0]), float(guess_m[1]), float(guess_m[2]))
            if not (math.isfinite(p[0]) and math.isfinite(p[1]) and math.isfinite(p[2])):
                raise KinematicsError(f"guess must be finite, got {tuple(guess_m)!r}")
        at: tuple[float, float, float] | None = None
        at_t: tuple[float, ...] = ()
        if planned is not None and len(planned[1]) == n:
            a = planned[0]
            at = (float(a[0]), float(a[1]), float(a[2]))
            at_t = tuple([float(v) for v in planned[1]])
            s = sum(at_t)
            if not (math.dist(at, p) <= PLANNED_REUSE_M and s - s == 0.0):  # far, or not finite
                at = None
        total = 0
        prev_move = math.inf
        best: tuple[float, tuple[float, float, float], tuple[float, ...]] | None = None
        for k in range(MAX_PASSES):
            pe, te, dt = self._lin_at, self._lin_t, self._dt
            if k == 0 and at is not None:
                if at != pe or dt is None:
                    te, dt = self._adopt(at, at_t)
                    pe = at
            elif k > 0 or dt is None or math.dist(pe, p) > TENSIONS_REUSE_M:
                # A later pass is a Newton step on the full equations: its tension derivative
                # is taken where it linearises.
                te, dt = self._linearise(p, k > 0)
                pe = p
            if k > 0:
                ss_p = self._sum_squares(p, te, paid)
                if best is None or ss_p < best[0]:
                    best = (ss_p, p, te)
            q, ss, t, its = self._pass(p, pe, te, dt, paid)
            total += its
            move = math.dist(pe, q)
            if move <= RELINEARISE_M:
                return StretchFpk(q, math.sqrt(ss / n), t, total)
            if move >= prev_move:  # not contracting: half the way
                q = (0.5 * (p[0] + q[0]), 0.5 * (p[1] + q[1]), 0.5 * (p[2] + q[2]))
                move = math.dist(p, q)
            prev_move = move
            p = q
        # The passes did not settle: the tensions' distribution has a kink there (the cable
        # that limits it changes) and the lengths disagree (a large residual), so the passes
        # step across the kink.  The best pose seen, by its exact residual.
        if best is None:
            raise StretchError(f"FPK with stretch did not settle at {_fmt(p)}")
        ss_b, p_b, t_b = best
        return StretchFpk(p_b, math.sqrt(ss_b / n), tuple(max(0.0, v) for v in t_b), total)

    def _sum_squares(
        self, p: tuple[float, float, float], t: Sequence[float], paid: Sequence[float]
    ) -> float:
        """Sum of squared paid-out length mismatches at `p` with tensions `t` there."""
        c = self._c
        x, y, z = p
        ss = 0.0
        for i, (ax, ay, az) in enumerate(self._anchors):
            length = math.sqrt((ax - x) ** 2 + (ay - y) ** 2 + (az - z) ** 2)
            ti = t[i]
            ri = (length / (1.0 + c[i] * ti) if ti > 0.0 else length) - paid[i]
            ss += ri * ri
        return ss

    def _pass(
        self,
        start: tuple[float, float, float],
        p0: tuple[float, float, float],
        t0: Sequence[float],
        dt: Sequence[tuple[float, float, float]],
        paid: Sequence[float],
    ) -> tuple[tuple[float, float, float], float, tuple[float, ...], int]:
        """Gauss-Newton from `start` with the tensions linearised about `p0` (``t0`` there):
        (pose, sum of squared residuals, tensions there, steps). Raises ``StretchError``
        without convergence."""
        c = self._c
        anchors = self._anchors
        n = self.n
        x0, y0, z0 = p0
        x, y, z = start
        prev_ss = math.inf
        for it in range(MAX_ITERATIONS):
            ex, ey, ez = x - x0, y - y0, z - z0
            # The normal equations J^T J d = -J^T r, accumulated row by row.
            a11 = a12 = a13 = a22 = a23 = a33 = 0.0
            b1 = b2 = b3 = 0.0
            ss = 0.0
            for i in range(n):
                ax, ay, az = anchors[i]
                dx, dy, dz = ax - x, ay - y, az - z
                length = math.sqrt(dx * dx + dy * dy + dz * dz)
                gx, gy, gz = dt[i]
                ti = t0[i] + gx * ex + gy * ey + gz * ez
                ci = c[i]
                if ti > 0.0 and ci > 0.0:
                    s = 1.0 / (1.0 + ci * ti)
                    k = length * ci * s * s
                    inv = s / length
                    j1, j2, j3 = -dx * inv - k * gx, -dy * inv - k * gy, -dz * inv - k * gz
                    ri = length * s - paid[i]
                else:
                    inv = 1.0 / length
                    j1, j2, j3 = -dx * inv, -dy * inv, -dz * inv
                    ri = length - paid[i]
                a11 += j1 * j1
                a12 += j1 * j2
                a13 += j1 * j3
                a22 += j2 * j2
                a23 += j2 * j3
                a33 += j3 * j3
                b1 -= j1 * ri
                b2 -= j2 * ri
                b3 -= j3 * ri
                ss += ri * ri
            step = _normal_step(a11, a12, a13, a22, a23, a33, b1, b2, b3)
            if step is None:
                raise StretchError(f"the cables do not fix the pose at {_fmt((x, y, z))}")
            sx, sy, sz = step
            size = math.sqrt(sx * sx + sy * sy + sz * sz)
            if size <= STEP_TOL_M or (ss >= prev_ss and size <= STALL_TOL_M):
                # Take the last step; the residual and tensions reported are the end's.
                q = (x + sx, y + sy, z + sz)
                ex, ey, ez = q[0] - x0, q[1] - y0, q[2] - z0
                t = tuple(
                    [
                        v
                        if (v := t0[i] + dt[i][0] * ex + dt[i][1] * ey + dt[i][2] * ez) > 0.0
                        else 0.0
                        for i in range(n)
                    ]
                )
                return q, self._sum_squares(q, t, paid), t, it
            if size > MAX_STEP_M:  # far from the solution: no longer than the model holds
                f = MAX_STEP_M / size
                sx, sy, sz = sx * f, sy * f, sz * f
            prev_ss = ss
            x, y, z = x + sx, y + sy, z + sz
        raise StretchError(
            f"FPK with stretch did not converge in {MAX_ITERATIONS} steps (at {_fmt((x, y, z))})"
        )

    def fpk_measured(
        self,
        paid_m: Sequence[float],
        tensions_n: Sequence[float],
        guess_m: Sequence[float] | None = None,
    ) -> StretchFpk:
        """The pose of cables paid out by `paid_m` stretched by measured `tensions_n`: one rigid
        FPK of the stretched lengths (seeded by `guess_m`, the last pose, where the effector
        works among its anchors).  Raises what ``stretched_m`` and ``kinematics.fpk``
        raise."""
        res = fpk(self.geometry, self.stretched_m(paid_m, tensions_n), guess_m)
        g = res.position_m
        return StretchFpk(
            (float(g[0]), float(g[1]), float(g[2])),
            float(res.residual_m),
            tuple(float(v) for v in tensions_n),
            0,
        )


def _normal_step(
    a11: float,
    a12: float,
    a13: float,
    a22: float,
    a23: float,
    a33: float,
    b1: float,
    b2: float,
    b3: float,
) -> tuple[float, float, float] | None:
    """The step d solving the normal equations A d = b (A = J^T J symmetric, b = -J^T r;
    3x3, Cramer), or None when A is singular."""
    c11 = a22 * a33 - a23 * a23
    c12 = a13 * a23 - a12 * a33
    c13 = a12 * a23 - a13 * a22
    det = a11 * c11 + a12 * c12 + a13 * c13
    scale = a11 * a22 * a33
    if not (abs(det) > 1e-14 * scale and scale > 0.0):
        return None
    c22 = a11 * a33 - a13 * a13
    c23 = a12 * a13 - a11 * a23
    c33 = a11 * a22 - a12 * a12
    d1 = (c11 * b1 + c12 * b2 + c13 * b3) / det
    d2 = (c12 * b1 + c22 * b2 + c23 * b3) / det
    d3 = (c13 * b1 + c23 * b2 + c33 * b3) / det
    if not (math.isfinite(d1) and math.isfinite(d2) and math.isfinite(d3)):
        return None
    return (d1, d2, d3)


def _fmt(p: Sequence[float]) -> str:
    return "(" + ", ".join(f"{float(v):.4g}" for v in p) + ") m"
